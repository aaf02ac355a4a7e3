"""Throughput of the interior orientation (eq. 01-07) and its Newton inverse.

Run: ``python benchmarks/bench_camera.py`` (prints a table; BLAS pinned to 1 thread).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.survey.folder import Survey, example_camera_path  # noqa: E402
from lidarcat.survey.cameras import load_camera  # noqa: E402


def _best(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main() -> None:
    cams = {"thesis dcs14n": Survey.load().cameras["dcs14n"],
            "lactec 35 mm": load_camera(example_camera_path())}
    rng = np.random.default_rng(0)
    print(f"{'camera':<15} {'points':>9} {'pixel->photo s':>15} {'photo->pixel s':>15} "
          f"{'Mpts/s fwd':>11} {'Mpts/s inv':>11} {'max round trip px':>18}")
    for name, cam in cams.items():
        for n in (10_000, 1_000_000):
            px = rng.uniform([-0.5, -0.5], [cam.columns_px - 0.5, cam.rows_px - 0.5], (n, 2))
            xy = cam.pixel_to_photo(px)
            tf = _best(lambda: cam.pixel_to_photo(px))
            ti = _best(lambda: cam.photo_to_pixel(xy))
            err = np.abs(cam.photo_to_pixel(xy) - px).max()
            print(f"{name:<15} {n:>9} {tf:>15.4f} {ti:>15.4f} {n / tf / 1e6:>11.2f} "
                  f"{n / ti / 1e6:>11.2f} {err:>18.2e}")


if __name__ == "__main__":
    main()
