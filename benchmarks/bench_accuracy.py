"""Timing of lidarcat.accuracy.checkpoints.assess and the report for growing check-point sets.

Run: python benchmarks/bench_accuracy.py   (prints a table; BLAS pinned to one thread)

``assess`` includes the Lilliefors null distribution (20 000 simulated samples of size n) and, above
n = 100 (the end of the Filliben table), the Monte-Carlo Filliben critical value: both grow with n.
The report is four matplotlib figures; its time hardly depends on n.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.accuracy.checkpoints import assess  # noqa: E402
from lidarcat.report.document import write_report  # noqa: E402


def main() -> None:
    rng = np.random.default_rng(0)
    # warm-up: the first report of a process imports matplotlib and builds its font cache, which would
    # otherwise be charged to the first row; the Monte-Carlo null distributions are cached per n (not warmed)
    with tempfile.TemporaryDirectory() as tmp:
        write_report(tmp, assessment=assess(rng.uniform(0, 1000, (5, 3)), rng.uniform(0, 1000, (5, 3)),
                                            scale=2000, contour_interval_m=2, lilliefors_n_sim=100))
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
