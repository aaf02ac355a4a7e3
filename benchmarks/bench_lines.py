"""Issue 29 step 3 figures: line control in the bundle adjustment over seeds (docs/figures.md, docs/lines.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_lines.py [--seeds 20]
    PYTHONPATH=src python benchmarks/bench_lines.py --measured [--seeds 2] [--size 1000 750] [--keep DIR]

On :func:`lidarcat.synthetic.lines.line_block` (2 strips x 6 photos, f = 50 mm, 1000 m, image sd
5 um, 12 roof lines seen on 2-3 photos each, GNSS 2 m / IMU 0.5 deg as weak constraints) prints per
configuration, pooled over the seeds: rms errors of the camera positions (m) and rotations (mrad),
of the tie points (plan, height, m), the sd of the normalised orientation errors, the share within
3 sd, and the mean of the line tests' chi2(2) statistic; then the data-snooping hit rate of one line
observation moved 3 px (18 um) across its edge.  The tests (tests/bundle/test_line_control.py)
assert the same quantities on fewer seeds.

``--measured``: the lines *measured automatically* in rendered photos (``lidarcat measure-control``)
instead of simulated observations.  Per seed the block of ``benchmarks/bench_measured_control.py``
(two strips of three photos, 0.1 m GSD, GNSS/IMU 2 m / 0.5 deg, the LiDAR vertices from ``lidarcat
extract --find``), ``lidarcat match``, then three variants of ``measure-control`` into copies of the
survey, each adjusted with ``lidarcat adjust --control lidar --eo-constraints --snooping remove``:
``--lines none`` (the vertices as points only), ``--lines add`` (plus the roof edges of the photos
where a vertex's point was not measured: the block's roofs give few usable corners) and ``--lines
only`` (every photo's edges as lines, no point).  Printed per variant, pooled over the seeds: the
orientation's rms errors (position m, attitude deg) against truth, the sd and max of the normalised
errors, the line observations written and their errors against the true projection of the LiDAR
line (median px across, rms of the normalised error: honest near 1).
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


def _line_errors(s, root) -> tuple[np.ndarray, np.ndarray]:
    """Per written line observation of *root*/line_control.csv: the true projections of its 3-D end points'
    distances from the measured image line (px) and over their sds (normalised)."""
    import csv

    with open(root / "line_control.csv", newline="") as fh:
        rows = list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))
    lines = {r["line"]: np.array([[float(r[c]) for c in ("e1_m", "n1_m", "h1_m")],
                                  [float(r[c]) for c in ("e2_m", "n2_m", "h2_m")]]) for r in rows if not r["photo"]}
    dist, z = [], []
    for r in rows:
        if not r["photo"]:
            continue
        p1 = np.array([float(r["col1_px"]), float(r["row1_px"])])
        p2 = np.array([float(r["col2_px"]), float(r["row2_px"])])
        sd = float(r["sd_px"])
        t = (p2 - p1) / np.linalg.norm(p2 - p1)
        n = np.array([-t[1], t[0]])
        for x in s.project(r["photo"], lines[r["line"]]):
            sa = float((x - p1) @ t) / float(np.linalg.norm(p2 - p1))
            d = float((x - p1) @ n)
            dist.append(d)
            z.append(d / (sd * np.sqrt((1 - sa) ** 2 + sa**2)))
    return np.array(dist), np.array(z)


def measured(seeds: list[int], size: tuple[int, int], keep=None) -> None:
    """The ``--measured`` rows (module docstring)."""
    import json
    import os
    import shutil
    import sys
    import tempfile
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_measured_control as mc

    base = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench_lines_measured_"))
    load0 = os.getloadavg()[0]
    variants = {"points (vertices measured), no lines": "none",
                "+ roof edges where the vertex's point was not measured": "add",
                "roof edges instead of points": "only"}
    acc: dict[str, dict[str, list]] = {v: {"d": [], "z": [], "ld": [], "lz": [], "n": []} for v in variants}
    for seed in seeds:
        d = base / f"seed{seed}"
        shutil.rmtree(d, ignore_errors=True)
        s, _ = mc.build(d / "survey", seed, size)
        r = mc._cli("match", str(d / "survey"), "-o", str(d / "match"))
        assert r.returncode == 0, r.stderr[-2000:]
        for name, mode in variants.items():
            root = d / f"survey-{mode}"
            shutil.copytree(d / "survey", root)
            r = mc._cli("measure-control", str(root), "--lines", mode, "--no-gallery", "-o", str(d / f"mc-{mode}"))
            assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
            r = mc._cli("adjust", str(root), "--control", "lidar", "--eo-constraints", "--snooping", "remove",
                        "-o", str(d / f"adjust-{mode}"))
            assert r.returncode in (0, 3), r.stdout[-2000:] + r.stderr[-2000:]
            sc = mc.score(s, root / "truth" / "points.csv", d / f"adjust-{mode}")
            eop = {q["photo"]: q for q in mc._rows(d / f"adjust-{mode}" / "eop.csv")}
            truth = np.asarray(s.true_eo, float).copy()
            truth[:, 3:] = np.degrees(truth[:, 3:])
            est = np.array([[float(eop[p][c]) for c in mc.EO_NAMES] for p in s.photo_ids])
            sd = np.array([[float(eop[p]["sd_" + c]) for c in mc.EO_NAMES] for p in s.photo_ids])
            dd = est - truth
            dd[:, 3:] = (dd[:, 3:] + 180.0) % 360.0 - 180.0
            acc[name]["d"].append(dd)
            acc[name]["z"].append((dd / sd).ravel())
            acc[name]["n"].append(sc["line_observations"])
            if (root / "line_control.csv").is_file():
                ld, lz = _line_errors(s, root)
                acc[name]["ld"].append(ld)
                acc[name]["lz"].append(lz)
            print(json.dumps({"seed": seed, "variant": mode, **sc}, default=float), flush=True)
    print(f"{'variant':56s} {'pos m':>6s} {'att deg':>7s} {'rms z':>6s} {'max|z|':>6s} {'lines':>5s} "
          f"{'line px':>7s} {'line z':>6s}")
    for name, a in acc.items():
        dd = np.concatenate(a["d"])
        z = np.concatenate(a["z"])
        ld = np.abs(np.concatenate(a["ld"])) if a["ld"] else np.zeros(0)
        lz = np.concatenate(a["lz"]) if a["lz"] else np.zeros(0)
        print(f"{name:56s} {np.sqrt(np.mean(dd[:, :3] ** 2)):6.3f} {np.sqrt(np.mean(dd[:, 3:] ** 2)):7.4f} "
              f"{np.sqrt(np.mean(z**2)):6.2f} {np.abs(z).max():6.2f} {sum(a['n']):5d} "
              f"{np.median(ld) if len(ld) else float('nan'):7.2f} "
              f"{np.sqrt(np.mean(lz**2)) if len(lz) else float('nan'):6.2f}")
    print(f"# seeds {seeds}, load {load0:.1f} -> {os.getloadavg()[0]:.1f}; folders in {base}")


if __name__ == "__main__":
    import sys as _sys

    if "--measured" in _sys.argv:
        _ap = argparse.ArgumentParser()
        _ap.add_argument("--measured", action="store_true")
        _ap.add_argument("--seeds", default="1")
        _ap.add_argument("--size", nargs=2, type=int, default=(1000, 750))
        _ap.add_argument("--keep", default=None)
        _a = _ap.parse_args()
        measured([int(x) for x in str(_a.seeds).split(",")], tuple(_a.size), _a.keep)
    else:
        main()
