"""Timing of lidarcat.accuracy.assess and the report for growing check-point sets.

Run: python benchmarks/bench_accuracy.py   (prints a table; BLAS pinned to one thread)
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.accuracy import assess  # noqa: E402
from lidarcat.report import write_report  # noqa: E402


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'n points':>9s} {'assess (s)':>11s} {'report (s)':>11s}")
    for n in (13, 100, 1000, 10000):
        adj = rng.uniform(0, 1000, (n, 3))
        ref = adj + rng.normal(0, [0.1, 0.1, 0.3], (n, 3))
        t0 = time.perf_counter()
        a = assess(adj, ref, scale=2000, contour_interval_m=2)
        t1 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            if n <= 1000:
                write_report(tmp, assessment=a)
        t2 = time.perf_counter()
        rep = f"{t2 - t1:11.2f}" if n <= 1000 else f"{'skipped':>11s}"
        print(f"{n:9d} {t1 - t0:11.2f} {rep}")


if __name__ == "__main__":
    main()
