"""Which line goes when a vertex's three (or four) image edges do not meet: counts on planted synthetic vertices.

The vertex measurement's chi2 check (:mod:`lidarcat.photocontrol.measure`, steps 3-3c) drops one line while
the lines miss one point.  This counts, over seeds, the vertices lost (not measured) and measured more than
3.7 sd off truth (squared Mahalanobis distance in the point's own covariance > 13.82, chi2_2 99.9 %), plus
the normalised rms, on three kinds of planted photos (no rendering; ``_refine`` fed the predicted edges as
``measure_photo`` calls it, both passes):

``weak``    tests/photocontrol/test_measure_weak_edge.py's vertex: three faces, the weak edge of planes 1-3
            (150/136 grey, texture sd 10) moved 0 / 1.2 / 2.5 px across.
``strong``  the same vertex with the *strong* edge of planes 1-2 (150/80) moved instead (the adverse case
            for a rule that trusts strong edges).
``four``    four faces (edges at 0, 90, 135, 225 deg: two or more redundancies), edge EDGE moved 0 / 1.5 / 3 px.

Run it on two checkouts to compare rules (it measures whatever ``lidarcat`` is on the path).

Usage::

    PYTHONPATH=src python benchmarks/bench_three_lines.py --case weak --seeds 140:240
    PYTHONPATH=src python benchmarks/bench_three_lines.py --case strong --seeds 100:200
    PYTHONPATH=src python benchmarks/bench_three_lines.py --case four --edge 2 --seeds 100:140
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "photocontrol"))

import test_measure_weak_edge as W  # noqa: E402
from test_measure_along import refine_context, unit  # noqa: E402

from lidarcat.photocontrol.measure import MeasureParams, _refine  # noqa: E402

CHI2_2_999 = 13.815510557964274
FOUR_DIRS = (0.0, 90.0, 135.0, 225.0)
FOUR_GREYS = (150.0, 80.0, 136.0, 105.0)   # face k between FOUR_DIRS[k] and FOUR_DIRS[k + 1]


def _texture(hi: np.ndarray, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    tex = gaussian_filter(rng.normal(0.0, 1.0, hi.shape), 1.5)
    return (gaussian_filter(hi, 0.7) + tex * (10.0 / tex.std()) + rng.normal(0.0, 1.0, hi.shape)).astype(np.float32)


def _grid():
    ss = 4
    g = (np.arange(W.SIZE * ss) + 0.5) / ss - 0.5
    cc, rr = np.meshgrid(g, g)
    ang = np.mod(np.degrees(np.arctan2(rr - W.VERTEX[1], cc - W.VERTEX[0])), 360.0)
    return ss, cc, rr, ang


def _shade(lab: np.ndarray, greys, ss: int) -> np.ndarray:
    return np.asarray(greys)[lab].reshape(W.SIZE, ss, W.SIZE, ss).mean(axis=(1, 3))


def photo_strong(off_px: float, seed: int) -> np.ndarray:
    """test_measure_weak_edge's vertex with the strong edge of planes 1-2 (90 deg) moved *off_px* across."""
    ss, cc, rr, ang = _grid()
    u = unit(90.0)
    n = np.array([-u[1], u[0]])
    s = (cc - W.VERTEX[0] - off_px * n[0]) * n[0] + (rr - W.VERTEX[1] - off_px * n[1]) * n[1]
    in2 = ((ang >= 30.0) & (ang < 150.0) & (s > 0)) | ((ang >= 150.0) & (ang < 210.0))
    in1 = ~in2 & ((ang >= 330.0) | (ang < 150.0))
    return _texture(_shade(np.where(in2, 1, np.where(in1, 0, 2)), W.GREYS, ss), seed)


def photo_four(edge: int, off_px: float, seed: int) -> np.ndarray:
    """Four faces meeting at the vertex, the edge *edge* moved *off_px* across."""
    ss, cc, rr, ang = _grid()
    a = np.where(ang < FOUR_DIRS[0], ang + 360.0, ang)
    lab = np.zeros(ang.shape, int)
    for k in range(4):
        hi = FOUR_DIRS[(k + 1) % 4] + (360.0 if k == 3 else 0.0)
        lab[(a >= FOUR_DIRS[k]) & (a < hi)] = k
    u = unit(FOUR_DIRS[edge])
    n = np.array([-u[1], u[0]])
    s = (cc - W.VERTEX[0] - off_px * n[0]) * n[0] + (rr - W.VERTEX[1] - off_px * n[1]) * n[1]
    d = np.mod(ang - FOUR_DIRS[edge] + 180.0, 360.0) - 180.0
    widths = [(FOUR_DIRS[(k + 1) % 4] - FOUR_DIRS[k]) % 360.0 for k in range(4)]
    win = np.abs(d) < 0.5 * min(widths[edge], widths[(edge - 1) % 4])
    lab[win & (s > 0)] = edge
    lab[win & (s <= 0)] = (edge - 1) % 4
    return _texture(_shade(lab, FOUR_GREYS, ss), seed)


def measure(img: np.ndarray, dirs, planes, p: MeasureParams):
    start = W.VERTEX + np.array([1.2, -0.8])
    ctx = refine_context(list(dirs), start, p, planes=planes)
    first = _refine(img, ctx, np.zeros(2), replace(p, band_px=p.wide_band_px))
    return first, (_refine(img, ctx, np.asarray(first.px) - start, p) if first else first)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--case", choices=("weak", "strong", "four"), default="weak")
    ap.add_argument("--edge", type=int, default=2, help="--case four: the edge moved (0-3)")
    ap.add_argument("--seeds", default="100:140", help="first:stop")
    a = ap.parse_args(argv)
    seeds = range(*map(int, a.seeds.split(":")))
    p = MeasureParams()
    offs = (0.0, 1.5, 3.0) if a.case == "four" else (0.0, 1.2, 2.5)
    print(f"case {a.case}{f' edge {a.edge}' if a.case == 'four' else ''}, seeds {a.seeds}")
    print("offset_px  n  lost  >3.7sd  rms_normalised")
    for off in offs:
        lost, bad, m2s = 0, 0, []
        for seed in seeds:
            if a.case == "four":
                first, second = measure(photo_four(a.edge, off, seed), FOUR_DIRS, ((3, 0), (0, 1), (1, 2), (2, 3)), p)
            else:
                img = W._photo(off, seed) if a.case == "weak" else photo_strong(off, seed)
                first, second = measure(img, W.DIRS, ((0, 1), (1, 2), (0, 2)), p)
            m = second if first else first
            if not m:
                lost += 1
                continue
            d = np.asarray(m.px) - W.VERTEX
            m2s.append(float(d @ np.linalg.solve(np.asarray(m.cov_px2), d)))
            bad += m2s[-1] > CHI2_2_999
        rms = math.sqrt(np.mean(m2s) / 2.0) if m2s else float("nan")
        print(f"{off:9.1f} {len(seeds):3d} {lost:5d} {bad:7d} {rms:15.2f}")


if __name__ == "__main__":
    main()
