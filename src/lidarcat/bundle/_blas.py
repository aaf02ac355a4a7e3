r"""BLAS threads per dense kernel: one for the small fronts, all configured for the big ones.

The supernodal factor (:mod:`.cholesky`) calls BLAS/LAPACK on hundreds of
dense fronts per factorisation, from 6 x 6 up to about 900 x 1,400 at 10,000
photos.  Multithreaded BLAS stalls on the small ones (measured: two threads
everywhere made a 5,000-photo adjustment 30 % slower) and pays on the big ones
(on this 2-core machine a 468 x 900 front's trsm 6.8 -> 3.7 ms, syrk 7.7 ->
4.2 ms, symm 15.7 -> 8.2 ms with two threads).  So the factor and its selected
inverse -- and the whole adjustment (``@pinned()``: numpy's batched small
products call BLAS too) -- run with BLAS pinned to one thread, and a kernel of at least
:data:`BIG_KERNEL_FLOPS` floating-point operations runs with the number of
threads the BLAS libraries were configured with when the factor started
(``OPENBLAS_NUM_THREADS`` and friends, or their default, the number of cores):
with one configured thread -- what the benchmarks pin -- nothing changes.

The thread counts are process-wide (BLAS has no other kind): adjustments
running concurrently in threads of one process stay correct but may lose the
pinning while another one exits.

The libraries are driven through ``threadpoolctl`` (the package scikit-learn and
numpy's own test suite use to set BLAS threads at run time: OpenBLAS, MKL and
BLIS under every symbol prefix numpy and scipy wheels ship); without it
everything runs as configured.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__: list[str] = []

#: a dense kernel with at least this many flops runs on all configured BLAS threads
BIG_KERNEL_FLOPS = 2.0e6

_libs: list | None = None
_big: int | None = None          # threads for big kernels while pinned() is active



def _controllers() -> list:
    global _libs
    if _libs is None:
        try:
            import scipy.linalg  # noqa: F401  (load the BLAS the kernels use before looking)
            from threadpoolctl import ThreadpoolController
        except ImportError:  # pragma: no cover - threadpoolctl is a dependency
            _libs = []
        else:
            ctl = ThreadpoolController().select(user_api="blas")
            _libs = list(ctl.lib_controllers)
    return _libs


def configured() -> int:
    """Threads the BLAS libraries are set to now (1 without threadpoolctl)."""
    libs = _controllers()
    return max((int(lc.num_threads) for lc in libs), default=1)


@contextlib.contextmanager
def threads(n: int) -> Iterator[None]:
    """Every BLAS library on *n* threads inside, back to its setting on exit."""
    libs = _controllers()
    before = [int(lc.num_threads) for lc in libs]
    if all(b == n for b in before):
        yield
        return
    for lc in libs:
        lc.set_num_threads(n)
    try:
        yield
    finally:
        for lc, b in zip(libs, before):
            lc.set_num_threads(b)


def big() -> int:
    """Threads for a big kernel: the configured number (as found when :func:`pinned` began)."""
    return _big if _big is not None else configured()


@contextlib.contextmanager
def pinned() -> Iterator[None]:
    """BLAS on one thread inside (big kernels excepted: :func:`big`), as configured after.

    Also a decorator (``@pinned()``).
    """
    global _big
    outer = _big
    _big = big()
    try:
        with threads(1):
            yield
    finally:
        _big = outer

