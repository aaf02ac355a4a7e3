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

Session 4 (``--only parallel``): the swath image and the calibration tile by tile on the tile
engine, serial against a local Dask cluster of 2 workers, on the synthetic strips written as
200 m tiles (LAS + SBET + runway CSV) and, for the swath image, on the two AHN3 tiles; and the
calibration's peak memory for 1x and 4x the points (strips 4x as long, the same 200 m tiles),
tile by tile against all points in memory (the way of session 3: every point read, the pulses
rebuilt, :func:`estimate_system_parameters`).  Each run is a child process of its own: wall
seconds, CPU seconds (the child's and its reaped children's, the Dask workers), peak RSS of the
child (the driver, ``VmHWM``) and ``ru_maxrss`` of its largest child (a Dask worker; an upper
bound: Linux keeps the forking process's peak across ``exec``).

Run::

    PYTHONPATH=src python benchmarks/bench_lidarchecks.py [--n 100] [--seeds 3] [--only new|parallel]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lidarcat.lidar.readers import read_points
from lidarcat.production.lidarchecks import (
    estimate_system_parameters,
    lidar_heights_at,
    vertical_accuracy,
)
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
    from lidarcat.production.lidarchecks import (
        georeference,
        lidar_outline_corners,
        planimetric_accuracy,
    )
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


OFF = np.array([680000.0, 7480000.0, 0.0])
CRS = "EPSG:31983"


def write_strip_tiles(folder: Path, length_m: float, seed: int = 1, spacing_m: float = 3.0, tile_m: float = 200.0
                      ) -> tuple[list[Path], Path, Path, int]:
    """Synthetic strips (raw, GPS time in week seconds) as LAS tiles of *tile_m*, an SBET and a runway CSV."""
    from lidarcat.lidar import PointCloud, write_points
    from lidarcat.lidar.trajectory import Trajectory, write_sbet
    from lidarcat.production.lidarchecks import georeference

    folder.mkdir(parents=True, exist_ok=True)
    s = synthetic_strips(seed, length_m=length_m, spacing_m=spacing_m)
    raw = georeference(s.pulses) + OFF
    attrs = {"gps_time": s.gps_time_s, "point_source_id": s.pulses.strip + 1,
             "classification": np.full(len(raw), 2, np.uint8)}
    key = np.floor(raw[:, 0] / tile_m).astype(np.int64) * 100_000 + np.floor(raw[:, 1] / tile_m).astype(np.int64)
    tiles = []
    for k in np.unique(key):
        sel = key == k
        p = folder / f"tile_{k}.las"
        write_points(p, PointCloud(raw[sel], {n: v[sel] for n, v in attrs.items()}, crs=CRS))
        tiles.append(p)
    t = s.trajectory
    sbet = write_sbet(folder / "sbet.out", Trajectory(t.time_s, t.position_m + OFF, t.attitude_rad, crs=CRS))
    ctrl = folder / "runway.csv"
    c = s.control_m + OFF
    ctrl.write_text("id,E,N,H\n" + "".join(f"r{i},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(c)))
    return tiles, sbet, ctrl, len(raw)


def child(spec: dict) -> dict:
    """One measured run (in its own process): returns its numbers."""
    from lidarcat.stages.lidar import swath_check, system_calibration

    d = Path(spec["out"])
    tiles = [Path(p) for p in spec["tiles"]]
    t0 = time.perf_counter()
    out: dict = {}
    if spec["kind"] == "swath":
        rep = swath_check(tiles, d / "sw.tif", crs=spec.get("crs"), cell_m=spec["cell_m"], preview=False,
                          workers=spec.get("workers"))
        st = rep["swath"]
        out = {"points": rep["points"], "rmsdz_cm": 100 * st["rmsdz_m"], "smooth": st["smooth_cells"]}
    elif spec["kind"] == "calib":
        rep = system_calibration(tiles, spec["sbet"], d / "c.json", control=spec["ctrl"], workers=spec.get("workers"))
        out = {"points": rep["points"], "parameters": rep["calibration"]["parameters"], "sd": rep["calibration"]["sd"],
               "strip_obs": rep["observations"]["strip"]}
    else:   # "memory": session 3's way, every point in memory
        from lidarcat.lidar import PointCloud
        from lidarcat.lidar.trajectory import read_trajectory
        from lidarcat.production.lidarchecks import (
            estimate_system_parameters,
            pulses_from_points,
        )

        pc = PointCloud.concat([read_points(t) for t in tiles])
        traj = read_trajectory(spec["sbet"], pc.crs)
        sensor, att = traj.at(pc.attributes["gps_time"])
        pulses, _ = pulses_from_points(pc.xyz, sensor, att, pc.attributes["point_source_id"])
        ctrl = np.loadtxt(spec["ctrl"], delimiter=",", skiprows=1, usecols=(1, 2, 3))
        res = estimate_system_parameters(pulses, ctrl)
        out = {"points": len(pc), "parameters": vars(res.parameters), "sd": vars(res.sd), "strip_obs": res.n_strip}
    wall = time.perf_counter() - t0
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    out.update(wall_s=wall, cpu_s=me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime,
               driver_mb=vm_hwm_mb(), worker_mb=kids.ru_maxrss / 1024)
    return out


def vm_hwm_mb() -> float:
    """Peak RSS of this process's own memory map (``VmHWM``), MB.  Not ``ru_maxrss``: Linux carries that
    across ``exec`` from the forking parent, so a child would report at least its parent's size."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def measure(spec: dict) -> dict:
    """Run :func:`child` in a fresh interpreter (its own peak memory and CPU)."""
    res = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], capture_output=True, text=True,
                         env={**os.environ, "PYTHONWARNINGS": "ignore"}, check=False)
    if res.returncode:
        raise SystemExit(res.stderr[-3000:])
    return json.loads(res.stdout.strip().splitlines()[-1])


def session4(work: Path) -> None:
    """Serial vs Dask (2 workers) and peak memory at 1x / 4x the points (module docstring)."""
    import shutil

    one = write_strip_tiles(work / "x1", 400.0)
    four = write_strip_tiles(work / "x4", 1600.0)
    runs = work / "runs"
    print(f"synthetic strips: 1x {one[3]:,} points in {len(one[0])} tiles; 4x {four[3]:,} points in "
          f"{len(four[0])} tiles (200 m)")
    print()
    print("| data | product | engine | points | wall s | CPU s | driver peak MB | largest worker MB | result |")
    print("|---|---|---|---|---|---|---|---|---|")
    ahn = sorted(HERE.glob("ahn3_cropped_*.laz"))
    name1 = f"synthetic strips 1x ({len(one[0])} tiles)"
    cases = [(name1, "swath 5 m",
              {"kind": "swath", "tiles": [str(p) for p in one[0]], "cell_m": 5.0}),
             ("AHN3 tiles 1+2", "swath 1 m",
              {"kind": "swath", "tiles": [str(p) for p in ahn], "cell_m": 1.0, "crs": "EPSG:7415"}),
             (name1, "calibration",
              {"kind": "calib", "tiles": [str(p) for p in one[0]], "sbet": str(one[1]), "ctrl": str(one[2])})]
    for data, product, spec in cases:
        for workers in (None, 2):
            shutil.rmtree(runs, ignore_errors=True)
            runs.mkdir(parents=True)
            load = os.getloadavg()[0]
            r = measure({**spec, "workers": workers, "out": str(runs)})
            res = (f"RMSDz {r['rmsdz_cm']:.2f} cm, {r['smooth']} smooth cells" if spec["kind"] == "swath" else
                   f"roll {np.degrees(r['parameters']['roll_rad']):+.5f} deg, {r['strip_obs']:,} strip obs")
            print(f"| {data} | {product} | {'serial' if workers is None else 'Dask, 2 workers'} | {r['points']:,} | "
                  f"{r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['driver_mb']:.0f} | "
                  f"{r['worker_mb']:.0f} | {res} (load {load:.1f}) |")
    print()
    print("| points | calibration | wall s | CPU s | peak MB | strip obs | roll dev (sd) | pitch dev (sd) |")
    print("|---|---|---|---|---|---|---|---|")
    truth = {"roll_rad": np.radians(0.05), "pitch_rad": np.radians(-0.08)}
    for name, data in (("1x", one), ("4x", four)):
        for how in ("calib", "memory"):
            shutil.rmtree(runs, ignore_errors=True)
            runs.mkdir(parents=True)
            load = os.getloadavg()[0]
            r = measure({"kind": how, "tiles": [str(p) for p in data[0]], "sbet": str(data[1]),
                         "ctrl": str(data[2]), "out": str(runs)})
            dev = [(r["parameters"][k] - v) / r["sd"][k] for k, v in truth.items()]
            print(f"| {name} ({r['points']:,}) | {'tile by tile' if how == 'calib' else 'all in memory'} | "
                  f"{r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['driver_mb']:.0f} | {r['strip_obs']:,} | "
                  f"{dev[0]:+.2f} | {dev[1]:+.2f} (load {load:.1f}) |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--only", choices=["all", "new", "parallel"], default="all")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child is not None:
        print(json.dumps(child(json.loads(a.child))))
        return
    print(f"load {os.getloadavg()[0]:.2f}")
    if a.only == "parallel":
        import tempfile

        with tempfile.TemporaryDirectory() as d:
            session4(Path(d))
        print(f"load {os.getloadavg()[0]:.2f} at the end")
        return
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
