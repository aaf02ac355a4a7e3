"""The heap policy of the bundle engine (lidarcat.bundle._heap): freed arrays are reused, not faulted in again."""

from __future__ import annotations

import resource
import sys

import numpy as np
import pytest

from lidarcat.bundle import _heap

pytestmark = pytest.mark.skipif(_heap._glibc() is None, reason="glibc only (elsewhere heap_reuse does nothing)")


def _faults_of_arrays(count: int = 50) -> int:
    """Minor page faults of *count* 1 MiB arrays made and freed in turn (1 MiB: above glibc's
    initial mmap threshold, below the 4 MiB from which numpy asks for transparent huge pages)."""
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(count):
        a = np.ones(131072)
        del a
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0


def test_freed_arrays_are_reused_inside_and_returned_after():
    pages = 256                            # 4 KiB pages of one 1 MiB array
    with _heap.heap_reuse():
        inside = _faults_of_arrays()
        with _heap.heap_reuse():           # nested: the outer exit restores
            pass
        assert _heap._depth == 1
    assert _heap._depth == 0
    after = _faults_of_arrays()
    # inside: the first array faults its pages in once, the others reuse them
    assert inside < 5 * pages
    # after: glibc's initial thresholds are back: every array is mmapped and faulted in again
    assert after > 40 * pages


def test_decorator_keeps_name_signature_and_exceptions():
    @_heap.reusing_heap
    def f(x: int, *, y: int = 2) -> int:
        """Doc."""
        if x < 0:
            raise ValueError("negative")
        return _heap._depth + x + y

    assert f.__name__ == "f" and f.__doc__ == "Doc."
    assert f(1) == 4                       # depth 1 inside
    with pytest.raises(ValueError, match="negative"):
        f(-1)
    assert _heap._depth == 0
    assert sys.platform.startswith("linux")
