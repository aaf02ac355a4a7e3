"""Roof extraction speed: roofs per second for single extractions, and --find over AHN3.

Run:  python benchmarks/bench_extract.py [--quick]
Prints a table. BLAS is pinned to one thread.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.control.vertices import extract_roof, find_candidates  # noqa: E402
from lidarcat.synthetic.roofs import synthetic_roof  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LIDAR = ROOT / "tests" / "data" / "lidar"


def _rate(fn, n):
    t = time.perf_counter()
    ok = sum(bool(fn(i)) for i in range(n))
    dt = time.perf_counter() - t
    return n / dt, ok


def main(quick: bool = False) -> None:
    n = 20 if quick else 100
    print(f"{'case':<46} {'points/clip':>11} {'roofs/s':>8} {'ok':>6}")
    for kind, dens, preset, radius in [("hip", 2, "default", 6), ("hip", 10, "default", 6),
                                       ("pyramid", 16, "default", 8), ("pyramid", 1.5, "thesis", 5)]:
        scenes = [synthetic_roof(kind, density_m2=dens, noise_h_m=0.05, seed=i,
                                 width_m=16 if preset == "thesis" else 9,
                                 slope_deg=20 if preset == "thesis" else 35) for i in range(n)]
        npts = np.mean([np.sum(np.hypot(*(s.xyz[:, :2] - s.vertices[0, :2]).T) <= radius) for s in scenes])
        rate, ok = _rate(lambda i: extract_roof(scenes[i].xyz, scenes[i].vertices[0, :2] + 0.5,
                                                radius_m=radius, params=preset), n)
        print(f"{kind + f' {dens} pts/m2, r={radius} m, preset ' + preset:<46} {npts:11.0f} {rate:8.1f} {ok:>3}/{n}")
    try:
        import laspy  # noqa: F401  (LAZ support)
    except ImportError:  # pragma: no cover
        return
    files = [LIDAR / "ahn3_cropped_1.laz", LIDAR / "ahn3_cropped_2.laz"]
    if not all(f.exists() for f in files):
        print("AHN3 tiles not found in tests/data/lidar; skipping")
        return
    from lidarcat.lidar import read_points

    t = time.perf_counter()
    clouds = [read_points(f, crs="EPSG:7415") for f in files]
    from lidarcat.lidar import PointCloud

    cloud = PointCloud.concat(clouds)
    t_read = time.perf_counter() - t
    xyz = cloud.xyz
    import csv

    rows = [r for r in csv.DictReader(l for l in open(ROOT / "tests/data/extract/ahn3_vertices.csv")
                                      if not l.startswith("#"))]
    for radius in (6, 12):
        reps = 2 if quick else 5
        rate, ok = _rate(lambda i: extract_roof(xyz, (float(rows[i % len(rows)]["approx_E"]),
                                                     float(rows[i % len(rows)]["approx_N"])),
                                                radius_m=radius), reps * len(rows))
        print(f"{f'AHN3 listed vertices, r={radius} m (whole tiles)':<46} {'':>11} {rate:8.1f} "
              f"{ok:>3}/{reps * len(rows)}")
    print(f"\nread both AHN3 tiles ({len(xyz)} points): {t_read:.1f} s")
    for label, classes in (("building class 6", [6]), ("all classes", None)):
        if quick and classes is None:
            continue
        t = time.perf_counter()
        c = find_candidates(cloud, classes=classes)
        dt = time.perf_counter() - t
        print(f"--find over both AHN3 tiles ({label}): {dt:.1f} s, {len(c)} candidates, "
              f"{sum(x.score >= 0.5 for x in c)} with score >= 0.5")


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
