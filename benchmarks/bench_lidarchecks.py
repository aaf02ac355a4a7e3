"""LiDAR system checks: ASPRS 2023 NVA/VVA on the AHN3 test tiles, and boresight recovery on synthetic strips.

AHN3 has no surveyed check points.  What is measured instead (leave-out
cross-validation, stated in docs/figures.md): per tile, N check points are drawn
(seeded) among the ground points (class 2) and *withheld*; the LiDAR height at
each is the TIN of the remaining ground points (``lidar_heights_at``), and
``dz = z_TIN - z_withheld``.  Non-vegetated: the ground points with no
non-ground point (class 1) within 2 m and a local plane rms (8 neighbours)
below 3 cm (hard, open surfaces: streets, squares); vegetated: ground points
with a class-1 point within 1 m (under trees, hedges, by cars).  This measures
the precision of the ground surface (noise + interpolation), not its absolute
accuracy (that needs an independent survey, the report's runway points).

Also (issue 26, session 3): the calibration through files (synthetic strips written as LAS with
adjusted GPS time + an SBET, ``stages.lidar.system_calibration``), swath separation on the
synthetic strips (raw and calibrated) and on the AHN3 tiles (ground last returns, 1 m), the
planimetric check on synthetic buildings with a planted shift, and the contour review on AHN3.

Run::

    PYTHONPATH=src python benchmarks/bench_lidarchecks.py [--n 100] [--seeds 3] [--only new]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lidarcat.lidar.readers import read_points
from lidarcat.production.lidarchecks import estimate_system_parameters, lidar_heights_at, vertical_accuracy
from lidarcat.synthetic.strips import synthetic_strips

HERE = Path(__file__).resolve().parent.parent / "tests" / "data" / "lidar"


def ahn3(tile: Path, n: int, seed: int) -> dict:
    pc = read_points(tile)
    cls = pc.attributes["classification"]
    g, other = pc.xyz[cls == 2], pc.xyz[cls == 1]
    gtree, otree = cKDTree(g[:, :2]), cKDTree(other[:, :2])
    rng = np.random.default_rng(seed)
    cand = rng.choice(len(g), size=min(len(g), 40 * n), replace=False)
    _, nn = gtree.query(g[cand, :2], k=9)
    nbr = g[nn[:, 1:]]
    c = nbr.mean(axis=1)
    rms = np.sqrt(np.linalg.eigvalsh(np.einsum("mki,mkj->mij", nbr - c[:, None], nbr - c[:, None]) / 8)[:, 0])
    near2 = np.array([len(x) > 0 for x in otree.query_ball_point(g[cand, :2], 2.0)])
    near1 = np.array([len(x) > 0 for x in otree.query_ball_point(g[cand, :2], 1.0)])
    inside = np.all((g[cand, :2] > g[:, :2].min(0) + 5) & (g[cand, :2] < g[:, :2].max(0) - 5), axis=1)
    hard = cand[inside & ~near2 & (rms < 0.03)][:n]
    veg = cand[inside & near1][:n]
    keep = np.ones(len(g), dtype=bool)
    keep[hard] = keep[veg] = False
    z_hard = lidar_heights_at(g[keep], g[hard, :2])
    z_veg = lidar_heights_at(g[keep], g[veg, :2])
    acc = vertical_accuracy(z_hard - g[hard, 2], z_veg - g[veg, 2])
    return {"tile": tile.name, "n_nonveg": acc.n_nonveg, "n_veg": acc.n_veg, "nva_rmse_m": acc.nva_rmse_m,
            "nva_95_m": acc.nva_95_m, "vva_rmse_m": acc.vva_rmse_m, "vva_95_m": acc.vva_95th_percentile_m,
            "class": acc.asprs2023.classes["altimetric"]}


def session3() -> None:
    import tempfile

    from matplotlib.path import Path as MplPath

    from lidarcat.lidar import PointCloud, write_points
    from lidarcat.lidar.trajectory import Trajectory, write_sbet
    from lidarcat.production.contourcheck import sparse_stretches
    from lidarcat.production.contours import contours
    from lidarcat.production.lidarchecks import georeference, lidar_outline_corners, planimetric_accuracy
    from lidarcat.production.swath import swath_separation
    from lidarcat.stages.lidar import swath_check, system_calibration

    off = np.array([680000.0, 7480000.0, 0.0])
    print("| seed | points | roll dev (sd) | pitch dev (sd) | scale dev (sd) | bias dev (sd) | s (LAS+SBET) |")
    print("|---|---|---|---|---|---|---|")
    for seed in range(3):
        s = synthetic_strips(seed, spacing_m=3.0)
        with tempfile.TemporaryDirectory() as d:
            d = Path(d)
            write_points(d / "s.las", PointCloud(georeference(s.pulses) + off, {
                "gps_time": 2000 * 604800 + s.gps_time_s - 1e9, "point_source_id": s.pulses.strip + 1},
                crs="EPSG:31983"))
            t = s.trajectory
            write_sbet(d / "sbet.out", Trajectory(t.time_s, t.position_m + off, t.attitude_rad, crs="EPSG:31983"))
            c = s.control_m + off
            (d / "r.csv").write_text("id,E,N,H\n" + "".join(f"r{i},{x:.4f},{y:.4f},{z:.4f}\n"
                                                             for i, (x, y, z) in enumerate(c)))
            t0 = time.perf_counter()
            rep = system_calibration([d / "s.las"], d / "sbet.out", d / "c.json", control=d / "r.csv")
            dt = time.perf_counter() - t0
        est, sd = rep["calibration"]["parameters"], rep["calibration"]["sd"]
        dev = [(est[k] - v) / sd[k] for k, v in vars(s.truth).items()]
        print(f"| {seed} | {rep['points']} | " + " | ".join(f"{x:+.2f}" for x in dev) + f" | {dt:.1f} |")
    print()
    print("| data | cell | overlap cells | smooth | RMSDz (cm) | max (cm) | p95 (cm) | QL2 | s |")
    print("|---|---|---|---|---|---|---|---|---|")
    s = synthetic_strips(1, spacing_m=2.0)
    for name, par in (("synthetic strips, raw", None), ("synthetic strips, calibrated", s.truth)):
        t0 = time.perf_counter()
        st = swath_separation(georeference(s.pulses, par), s.pulses.strip, 5.0).assess("QL2")
        dt = time.perf_counter() - t0
        print(f"| {name} | 5 m | {st['overlap_cells']} | {st['smooth_cells']} | {100 * st['rmsdz_m']:.1f} | "
              f"{100 * st['max_abs_dz_m']:.1f} | {100 * st['p95_abs_dz_m']:.1f} | {st['pass']} | {dt:.2f} |")
    with tempfile.TemporaryDirectory() as d:
        for tile in sorted(HERE.glob("ahn3_cropped_*.laz")):
            for cls in ("auto", None):
                t0 = time.perf_counter()
                rep = swath_check([tile], Path(d) / "sw.tif", crs="EPSG:7415", classes=cls, preview=False)
                dt = time.perf_counter() - t0
                st = rep["swath"]
                what = "ground" if cls == "auto" else "all last returns"
                print(f"| {tile.name} ({what}) | 1 m | {st['overlap_cells']} | {st['smooth_cells']} | "
                      f"{100 * st['rmsdz_m']:.1f} | {100 * st['max_abs_dz_m']:.1f} | {100 * st['p95_abs_dz_m']:.1f} "
                      f"| {st['pass']} | {dt:.2f} |")
    print()
    outlines = [np.array([[10, 10], [30, 10], [30, 22], [10, 22.0]]),
                np.array([[50, 10], [70, 10], [70, 30], [62, 30], [62, 18], [50, 18.0]])]
    print("| density (pts/m2) | seed | planted (m) | mean dE | mean dN | RMSE_r (m) | corners |")
    print("|---|---|---|---|---|---|---|")
    for dens in (1.0, 4.0, 16.0):
        for seed in range(2):
            rng = np.random.default_rng(seed)
            xy = rng.uniform(0, 80, (int(6400 * dens), 2))
            shift = np.array([0.3, -0.2])
            roof = np.zeros(len(xy), bool)
            for o in outlines:
                roof |= MplPath(o).contains_points(xy - shift)
            p = np.column_stack([xy, np.where(roof, 8.0, 0.0)])
            dd = np.vstack([lidar_outline_corners(o, p[roof], p[~roof]).discrepancies_m for o in outlines])
            acc = planimetric_accuracy(dd)
            print(f"| {dens:g} | {seed} | (+0.30, -0.20) | {acc['mean_dE_m']:+.3f} | {acc['mean_dN_m']:+.3f} | "
                  f"{acc['rmse_r_m']:.3f} | {acc['n_corners']} |")
    print()
    print("| tile | interval | contour length (m) | flagged stretches | flagged length (m) | threshold (m) | s |")
    print("|---|---|---|---|---|---|---|")
    for tile in sorted(HERE.glob("ahn3_cropped_*.laz")):
        pc = read_points(tile)
        g = pc.xyz[pc.attributes["classification"] == 2]
        cs = contours(g, 0.5)
        t0 = time.perf_counter()
        st, thr = sparse_stretches(cs, g)
        dt = time.perf_counter() - t0
        total = sum(float(np.hypot(*np.diff(c.xy, axis=0).T).sum()) for c in cs)
        print(f"| {tile.name} | 0.5 m | {total:,.0f} | {len(st)} | {sum(x.length_m for x in st):,.0f} | "
              f"{thr:.2f} | {dt:.1f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--only", choices=["all", "new"], default="all")
    a = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}")
    if a.only == "new":
        session3()
        print(f"load {os.getloadavg()[0]:.2f} at the end")
        return
    print("| tile | seed | n NVA | n VVA | NVA RMSE_z (cm) | NVA 95 % (cm) | VVA RMSE_z (cm) | VVA 95th pct (cm) "
          "| ASPRS 2023 class |")
    print("|---|---|---|---|---|---|---|---|---|")
    for tile in sorted(HERE.glob("ahn3_cropped_*.laz")):
        for seed in range(a.seeds):
            r = ahn3(tile, a.n, seed)
            print(f"| {r['tile']} | {seed} | {r['n_nonveg']} | {r['n_veg']} | {100 * r['nva_rmse_m']:.2f} | "
                  f"{100 * r['nva_95_m']:.2f} | {100 * r['vva_rmse_m']:.2f} | {100 * r['vva_95_m']:.2f} | "
                  f"{r['class']} |")
    print()
    print("| seed | pulses | roll dev (sd) | pitch dev (sd) | scale dev (sd) | bias dev (sd) | sigma0 | s |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in range(a.seeds):
        t = time.perf_counter()
        s = synthetic_strips(seed, length_m=300.0, spacing_m=2.0)
        res = estimate_system_parameters(s.pulses, s.control_m)
        dev = (res.parameters.as_array() - s.truth.as_array()) / res.sd.as_array()
        print(f"| {seed} | {len(s.pulses)} | " + " | ".join(f"{x:+.2f}" for x in dev)
              + f" | {res.sigma0:.3f} | {time.perf_counter() - t:.1f} |")
    print()
    session3()
    print(f"load {os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
