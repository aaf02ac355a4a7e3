r"""Keep freed arrays in the process heap, and no huge pages, while an adjustment runs (glibc only).

Why: every iteration builds arrays of the size of the block (the Jacobian
parts and W of every ray, the fronts of the factor, the selected inverse): at
5,000 photos about 40 MB each, at 10,000 about 80 MB.  glibc's ``malloc``
serves requests above its mmap threshold (at most 32 MiB, whatever the
dynamic adjustment does) with fresh ``mmap`` pages and gives them back to the
kernel on ``free``; the next iteration's array of the same size gets fresh
pages again, which the kernel must fault in and zero (numpy asks for 2 MiB
transparent huge pages for arrays of 4 MiB and more, so the fault count says
little: 56.7 thousand minor faults inside one 5,000-photo adjustment without
the policy, 40.5 thousand with it).  Measured, 10,010 photos, policy off /
on (``LIDARCAT_HEAP_REUSE=0`` switches it off), two runs each, load 1.2-1.5:
15.29 / 14.32 s and 15.56 / 14.58 s, of it the model phase 3.5 / 2.9 and
4.4 / 3.0 s; peak memory at 5,000 photos 731 / 697 MB.

What: while :func:`heap_reuse` is active, ``mallopt(M_MMAP_MAX, 0)`` makes
glibc take every block from the heap and ``M_TRIM_THRESHOLD`` (2 GiB) keeps
freed space there, so the next iteration reuses the same pages.  Peak memory
is unchanged (the arrays are freed and reused, not kept); on exit the glibc
defaults are set back (``M_MMAP_MAX`` 65536, thresholds 128 KiB: the initial
values -- glibc's dynamic raising of the mmap threshold stays off for the
rest of the process, a documented side effect of any ``mallopt`` call) and
``malloc_trim(0)`` returns the free heap to the kernel.  Nested and
concurrent uses count: the defaults come back when the last one exits.
Elsewhere (macOS, Windows, musl), or with the environment variable
``LIDARCAT_HEAP_REUSE=0``, it does nothing.

No huge pages asked for either.  numpy ``madvise``\ s 2 MiB transparent huge
pages for every array of 4 MiB and more; where the kernel answers such a
fault by compacting memory first (``/sys/kernel/mm/transparent_hugepage/defrag``
= ``madvise``, the default of many distributions and of this machine), the
fault stalls in the kernel.  Inside :func:`heap_reuse` numpy's switch for it
(``_set_madvise_hugepage``) is off and set back on exit.  Measured before it
was built in -- ``adjust`` from saved approximations in a fresh process, the
switch on / off for the whole process, times and ``getrusage`` of ``adjust``
alone, five alternating runs each: 10,010 photos system time 1.83-1.95 ->
0.70-0.84 s, wall median 13.40 -> 12.77 s; 5,000 photos system time
0.72-1.01 -> 0.32-0.38 s, wall median 5.74 -> 5.57 s (more 4 KiB faults,
each cheap: 52-61 thousand -> 306-323 thousand at 10,010 photos).
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import os
import sys
import threading
from collections.abc import Iterator

__all__: list[str] = []

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
_M_MMAP_MAX = -4
_DEFAULT_MMAP_MAX = 65536
_DEFAULT_THRESHOLD = 128 * 1024
_KEEP_BYTES = 2**31 - 1

_lock = threading.Lock()
_depth = 0
_libc: ctypes.CDLL | None | bool = False     # False: not looked up yet
_hugepage_before: bool | None = None          # numpy's huge-page setting when the outermost use began


def _hugepage_switch():
    """numpy's ``_set_madvise_hugepage(enabled) -> previous``, or None (private numpy API: a numpy
    without it makes :func:`heap_reuse` leave huge pages as they are)."""
    try:
        from numpy._core import multiarray           # numpy >= 2
    except ImportError:  # pragma: no cover - numpy 1.26
        from numpy.core import multiarray
    return getattr(multiarray, "_set_madvise_hugepage", None)


def _glibc() -> ctypes.CDLL | None:
    global _libc
    if _libc is False:
        lib = None
        if sys.platform.startswith("linux"):
            try:
                cand = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
                gnu = getattr(cand, "gnu_get_libc_version", None)
                if gnu is not None and hasattr(cand, "mallopt") and hasattr(cand, "malloc_trim"):
                    cand.mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
                    cand.malloc_trim.argtypes = [ctypes.c_size_t]
                    lib = cand
            except OSError:  # pragma: no cover - no loadable libc
                lib = None
        _libc = lib
    return _libc  # type: ignore[return-value]


@contextlib.contextmanager
def heap_reuse() -> Iterator[None]:
    """Freed blocks stay in the heap for reuse inside the block (module docstring).

    Also a decorator (``@heap_reuse()``: a context manager made by
    :func:`contextlib.contextmanager` decorates functions).
    """
    global _depth, _hugepage_before
    lib = _glibc() if os.environ.get("LIDARCAT_HEAP_REUSE", "1") != "0" else None
    if lib is None:
        yield
        return
    hugepage = _hugepage_switch()
    with _lock:
        if _depth == 0:
            lib.mallopt(_M_TRIM_THRESHOLD, _KEEP_BYTES)
            lib.mallopt(_M_MMAP_MAX, 0)
            if hugepage is not None:
                _hugepage_before = bool(hugepage(False))
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                lib.mallopt(_M_MMAP_MAX, _DEFAULT_MMAP_MAX)
                lib.mallopt(_M_MMAP_THRESHOLD, _DEFAULT_THRESHOLD)
                lib.mallopt(_M_TRIM_THRESHOLD, _DEFAULT_THRESHOLD)
                lib.malloc_trim(0)
                if hugepage is not None and _hugepage_before is not None:
                    hugepage(_hugepage_before)
                    _hugepage_before = None

