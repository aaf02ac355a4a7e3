"""Issue 29 step 3 figures: line control in the bundle adjustment over seeds (docs/figures.md, docs/lines.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_lines.py [--seeds 20]

On :func:`lidarcat.synthetic.lines.line_block` (2 strips x 6 photos, f = 50 mm, 1000 m, image sd
5 um, 12 roof lines seen on 2-3 photos each, GNSS 2 m / IMU 0.5 deg as weak constraints) prints per
configuration, pooled over the seeds: rms errors of the camera positions (m) and rotations (mrad),
of the tie points (plan, height, m), the sd of the normalised orientation errors, the share within
3 sd, and the mean of the line tests' chi2(2) statistic; then the data-snooping hit rate of one line
observation moved 3 px (18 um) across its edge.  The tests (tests/bundle/test_line_control.py)
assert the same quantities on fewer seeds.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from lidarcat.bundle import adjust
from lidarcat.bundle.line_tests import line_tests, snoop_lines
from lidarcat.synthetic.lines import line_block

PIXEL_MM = 0.006
CONFIGS = {
    "GNSS/IMU only (2 m, 0.5 deg)": dict(n_control_points=0, lines=False),
    "+ 3 control points": dict(n_control_points=3, lines=False),
    "+ 3 control points + 12 lines": dict(n_control_points=3, lines=True),
    "+ 12 lines (no control point)": dict(n_control_points=0, lines=True),
}


def _run(seed: int, n_control_points: int, lines: bool):
    b = line_block(seed=seed, n_control_points=n_control_points)
    p = b.problem if lines else dataclasses.replace(b.problem, lines=None)
    r = adjust(p, initial=(b.initial_eo, None))
    d = r.eo_params - b.true_eo
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    z = (d / r.eo_sd).ravel()
    dpos = d[:, :3]
    drot = d[:, 3:] * 1e3
    dpt = r.points_m - b.true_points_m
    t = line_tests(r).w ** 2 if lines else np.zeros(0)
    return dpos, drot, dpt, z, t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"{'configuration':34s} {'pos m':>7s} {'rot mrad':>8s} {'tie E,N m':>9s} {'tie h m':>8s} "
          f"{'sd(z)':>6s} {'|z|<3':>6s} {'mean T':>7s}")
    for name, cfg in CONFIGS.items():
        out = [_run(s, **cfg) for s in range(args.seeds)]
        pos = np.concatenate([o[0] for o in out])
        rot = np.concatenate([o[1] for o in out])
        pt = np.concatenate([o[2] for o in out])
        z = np.concatenate([o[3] for o in out])
        t = np.concatenate([o[4] for o in out])
        print(f"{name:34s} {np.sqrt(np.mean(pos**2)):7.3f} {np.sqrt(np.mean(rot**2)):8.3f} "
              f"{np.sqrt(np.mean(pt[:, :2]**2)):9.3f} {np.sqrt(np.mean(pt[:, 2]**2)):8.3f} {z.std():6.3f} "
              f"{np.mean(np.abs(z) < 3):6.3f} {np.mean(t) if len(t) else float('nan'):7.2f}")
    hits, first = 0, 0
    for s in range(args.seeds):
        b = line_block(seed=s)
        L = b.problem.lines
        k = int(np.flatnonzero(L.line_index == np.argmax(np.bincount(L.line_index)))[0])
        d = L.xy2_mm[k] - L.xy1_mm[k]
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        xy1, xy2 = L.xy1_mm.copy(), L.xy2_mm.copy()
        xy1[k] += 3 * PIXEL_MM * n
        xy2[k] += 3 * PIXEL_MM * n
        bad = dataclasses.replace(b.problem, lines=dataclasses.replace(L, xy1_mm=xy1, xy2_mm=xy2))
        label = L.observation_labels(b.problem.photo_ids)[k]
        res = adjust(bad, initial=(b.initial_eo, None))
        out = snoop_lines(res)
        hits += label in out.removed
        if label not in out.removed:
            t = line_tests(res)
            print(f"  seed {s}: {label} not named: w {t.w[k]:.2f} (critical {t.critical_w:.2f}), "
                  f"redundancy {t.redundancy[k].round(2)}, largest w {np.nanmax(t.w):.2f}")
        first += bool(out.removed) and out.removed[0] == label
    print(f"snooping, one line observation 3 px off: named in {hits}/{args.seeds} seeds, "
          f"first in {first}/{args.seeds}")
    print(f"{time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
