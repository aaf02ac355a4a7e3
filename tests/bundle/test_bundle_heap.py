"""The heap policy of the bundle engine (lidarcat.bundle._heap): while an adjustment runs, big
arrays come from the heap (their freed pages are reused), after it glibc's defaults are back."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from lidarcat.bundle import _heap

pytestmark = pytest.mark.skipif(_heap._glibc() is None, reason="glibc only (elsewhere heap_reuse does nothing)")

# In a fresh process (the heap of a test worker holds whatever earlier tests freed): bytes of
# mmapped blocks (glibc mallinfo2().hblkhd) while one 64 MiB array lives, inside heap_reuse and
# after it (a 128 MiB array then: larger than anything the heap holds free).
_PROBE = r"""
import ctypes, numpy as np
from lidarcat.bundle import _heap

class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in
                ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
                 "fordblks", "keepcost")]

libc = _heap._glibc()
libc.mallinfo2.restype = MallInfo2

def mapped(mib):
    base = libc.mallinfo2().hblkhd
    a = np.ones(mib * 131072)
    out = (libc.mallinfo2().hblkhd - base) >> 20
    del a
    return out

before = mapped(64)
with _heap.heap_reuse():
    inside = [mapped(64) for _ in range(3)]
after = mapped(128)
print(before, *inside, after, _heap._depth)
"""


def test_big_arrays_come_from_the_heap_inside_and_from_mmap_after():
    if not hasattr(_heap._glibc(), "mallinfo2"):
        pytest.skip("glibc < 2.33 has no mallinfo2")
    env = {k: v for k, v in os.environ.items() if k != "LIDARCAT_HEAP_REUSE"}
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True,
                         env=env).stdout
    before, in1, in2, in3, after, depth = (int(v) for v in out.split())
    assert before >= 64                       # glibc's default: a 64 MiB block is mmapped
    assert (in1, in2, in3) == (0, 0, 0)       # inside: from the heap, the same pages each time
    assert after >= 128                       # defaults back
    assert depth == 0
    # LIDARCAT_HEAP_REUSE=0: the policy is off, inside is like outside
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, check=True,
                         env={**env, "LIDARCAT_HEAP_REUSE": "0"}).stdout
    assert all(int(v) >= 64 for v in out.split()[1:4])


def test_nesting_counts_and_decorator_keeps_name_and_exceptions():
    @_heap.heap_reuse()
    def f(x: int, *, y: int = 2) -> int:
        """Doc."""
        if x < 0:
            raise ValueError("negative")
        return _heap._depth + x + y

    assert f.__name__ == "f" and f.__doc__ == "Doc."
    with _heap.heap_reuse():
        assert f(1) == 5                      # depth 2 inside the nested use
        assert _heap._depth == 1
    assert f(1) == 4
    with pytest.raises(ValueError, match="negative"):
        f(-1)
    assert _heap._depth == 0


def test_numpy_asks_for_no_huge_pages_inside_and_as_before_after():
    switch = _heap._hugepage_switch()
    if switch is None:
        pytest.skip("this numpy has no huge-page switch")
    original = switch(True)
    for setting in (True, False):
        switch(setting)
        try:
            with _heap.heap_reuse():
                with _heap.heap_reuse():
                    inner = switch(False)         # returns the setting in force
                after_inner = switch(False)
            assert (inner, after_inner) == (False, False)   # off inside, nested exits keep it off
            assert switch(setting) is setting               # the caller's setting back after
        finally:
            switch(original)
