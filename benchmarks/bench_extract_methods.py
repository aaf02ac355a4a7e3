"""Grouping methods compared (docs/extraction.md, "when each grouping method wins").

Run:  python benchmarks/bench_extract_methods.py
Prints a Markdown table: success rate (3+ planes, within 0.5 m plan / 0.2 m
height of the truth), plan RMSE of the successes and seconds per roof, for the
thesis preset, the thesis preset with a 4-65 deg window, region growing
(default) and RANSAC, on Curitiba-like and steep synthetic roofs and on the 14
listed AHN3 vertices. Takes about a minute on one core (35 s CPU measured).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import csv  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.control.vertices import extract_roof  # noqa: E402
from lidarcat.control.facets import get_params  # noqa: E402
from lidarcat.synthetic.roofs import synthetic_roof  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _run(gen, params, n=40):
    ok, err, t = 0, [], time.perf_counter()
    for i in range(n):
        s, c, v = gen(i)
        cp = extract_roof(s.xyz, c, params=params)
        if cp and np.all(np.abs(cp.enh_m - v) < [0.5, 0.5, 0.2]):
            ok += 1
            err.append(np.hypot(*(cp.enh_m[:2] - v[:2])))
    rmse = float(np.sqrt(np.mean(np.square(err)))) if err else float("nan")
    return ok / n, rmse, (time.perf_counter() - t) / n


def _curitiba(i, noise):
    rng = np.random.default_rng(300 + i)
    kind = ("hip", "pyramid")[i % 2]
    s = synthetic_roof(kind, length_m=24 if kind == "hip" else 16, width_m=16, slope_deg=rng.uniform(15, 25),
                       density_m2=rng.uniform(1, 2), noise_h_m=noise, noise_plan_m=0.05, chimney=True,
                       walls=True, seed=300 + i, azimuth_deg=rng.uniform(0, 90))
    v = s.vertices[0]
    return s, v[:2] + rng.uniform(-0.7, 0.7, 2), v


def _steep(i):
    rng = np.random.default_rng(500 + i)
    kind = ("hip", "pyramid", "lgable")[i % 3]
    s = synthetic_roof(kind, slope_deg=rng.uniform(35, 55), density_m2=rng.uniform(4, 16), noise_h_m=0.03,
                       chimney=True, dormer=(kind == "hip"), seed=500 + i, azimuth_deg=rng.uniform(0, 90),
                       strips=2)
    v = s.vertices[0]
    return s, v[:2] + rng.uniform(-0.7, 0.7, 2), v


METHODS = [
    ("thesis preset", lambda **kw: get_params("thesis", max_sd_m=5, **kw)),
    ("thesis preset, window 4-65", lambda **kw: get_params("thesis", slope_max_deg=65, height_filter=None,
                                                          max_sd_m=5, **kw)),
    ("region (default)", lambda **kw: get_params("default", **kw)),
    ("ransac", lambda **kw: get_params("default", method="ransac", **kw)),
]


def main() -> None:
    print("| scene | method/preset | success | plan RMSE (m) | s per roof |")
    print("|---|---|---|---|---|")
    scenes = [("Curitiba-like, 0.05 m noise", lambda i: _curitiba(i, 0.05)),
              ("Curitiba-like, 0.15 m noise", lambda i: _curitiba(i, 0.15)),
              ("steep 35-55 deg, 4-16 pts/m2, 2 strips, details", _steep)]
    for label, gen in scenes:
        for name, make in METHODS:
            extra = {} if name.startswith("thesis") else {"sd_en_m": 0.05}
            sr, rm, tt = _run(gen, make(**extra))
            print(f"| {label} | {name} | {sr:.2f} | {rm:.3f} | {tt:.3f} |")
    import laspy

    xyz = []
    for f in ("ahn3_cropped_1.laz", "ahn3_cropped_2.laz"):
        las = laspy.read(ROOT / "tests" / "data" / "lidar" / f)
        xyz.append(np.column_stack([las.x, las.y, las.z]))
    xyz = np.vstack(xyz)
    with open(ROOT / "tests" / "data" / "extract" / "ahn3_vertices.csv", newline="") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    for name, make in METHODS:
        ok, e = 0, []
        for r in rows:
            v = np.array([float(r[k]) for k in "ENh"])
            for rad in (6, 12):
                cp = extract_roof(xyz, (float(r["approx_E"]), float(r["approx_N"])), params=make(radius_m=rad))
                if cp and np.hypot(*(cp.enh_m[:2] - v[:2])) < 0.15 and abs(cp.enh_m[2] - v[2]) < 0.1:
                    ok += 1
                    e.append(np.hypot(*(cp.enh_m[:2] - v[:2])))
        rm = float(np.sqrt(np.mean(np.square(e)))) if e else float("nan")
        print(f"| AHN3 {len(rows)} listed vertices x radius 6, 12 m | {name} | {ok}/{2 * len(rows)} | {rm:.3f} | |")


if __name__ == "__main__":
    main()
