"""Benchmark of the production chain: ground classification and rasters, serial vs Dask workers.

Generates the synthetic tile set of ``bench_lidar.py`` (terrain + gable-roof
houses + returns, 10 pts/m2) and runs, each mode in a fresh subprocess,

``ground``  SMRF classification into LAZ copies (overlap 80 m, two SMRF windows)
``dsm``     1 m DSM GeoTIFF per tile (overlap 50 m)
``dtm``     1 m TIN DTM GeoTIFF per tile from the tiles' class 2 (overlap 50 m)

on the serial path, then on a LocalCluster of 1 and 2 single-threaded workers,
printing points/s (wall clock), the CPU seconds of the process (serial) or of
each worker and the points per CPU-second (what the code costs, whatever the
load of a shared machine), and the peak resident memory of the process or of
each worker (Dask: VmHWM read on the workers); the 1-minute load average is
printed after each row.  Wall times include starting the cluster's work
(not the cluster) and the edge-buffer pass (:mod:`lidarcat.lidar.jobs`).

Usage::

    python benchmarks/bench_production.py                  # 2 million points in 4 tiles (minutes)
    python benchmarks/bench_production.py --full           # the 50 M-point set of bench_lidar --full
    python benchmarks/bench_production.py --points 1e7 --tiles 9
    python benchmarks/bench_production.py --kernels         # in memory, one 1 M-point tile, no I/O

``--kernels`` times the computations alone on one tile of the same synthetic
survey (points already in memory): SMRF, the TIN DTM (OpenCV triangulation,
triangles rasterised) beside its peer, the same TIN from Qhull with every cell
centre located (:func:`lidarcat.production.terrain.tin_heights`), and the DSM.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).parent))
from bench_lidar import _peak_mb, generate  # noqa: E402

KINDS = {"ground": ({"method": "smrf"}, 80.0, ".laz"), "dsm": ({"cell_m": 1.0}, 50.0, ".tif"),
         "dtm": ({"cell_m": 1.0}, 50.0, ".tif")}


def _mode(folder: Path, kind: str, workers: int) -> dict:
    from lidarcat.lidar.jobs import run_jobs
    from lidarcat.production.tiles import product_jobs

    params, overlap, suffix = KINDS[kind]
    tiles = sorted(folder.glob("tile_*.laz"))
    out = folder / f"out_{kind}_{workers}"
    jobs = product_jobs(kind, tiles, out, params=params, overlap_m=overlap, suffix=suffix)
    t = time.perf_counter()
    if workers == 0:
        c = time.process_time()
        run_jobs(jobs, resume=False)
        peaks = [_peak_mb()]
        cpu = [time.process_time() - c]
    else:
        from dask.distributed import Client, LocalCluster

        from lidarcat.lidar import jobs as parallel

        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
        t = time.perf_counter()
        c0 = client.run(time.process_time)
        parallel.run_on_client(client, jobs)
        peaks = list(client.run(_peak_mb).values())
        c1 = client.run(time.process_time)
        cpu = [c1[w] - c0[w] for w in c1 if w in c0]
        client.close()
        cluster.close()
    dt = time.perf_counter() - t
    shutil.rmtree(out, ignore_errors=True)
    return {"seconds": dt, "peak_mb": peaks, "cpu_s": cpu}


def _kernels(points: int) -> None:
    import math

    import numpy as np

    from bench_lidar import _tile_cloud
    from lidarcat.production.ground import smrf_ground
    from lidarcat.lidar.raster import grid_for
    from lidarcat.production.terrain import dsm_grid, tin_grid, tin_heights

    pc = _tile_cloud(0, 0, math.sqrt(points / 10.0), points, 1)
    a = pc.attributes
    g = a["classification"] == 2
    b = pc.bounds[:4]

    def qhull_dtm():
        t, nr, nc = grid_for(b, 1.0)
        rr, cc = np.mgrid[0:nr, 0:nc]
        return tin_heights(pc.xyz[g], np.column_stack(t.xy(rr.ravel(), cc.ravel())), 50.0)

    runs = [("SMRF ground", lambda: smrf_ground(pc.xyz, a["return_number"], a["number_of_returns"])),
            ("TIN DTM 1 m (OpenCV, rasterised)", lambda: tin_grid(pc.xyz[g], 1.0, b)),
            ("TIN DTM 1 m (Qhull + walk, peer)", qhull_dtm),
            ("DSM 1 m", lambda: dsm_grid(pc, 1.0, b))]
    smrf_ground(pc.xyz[:2000], a["return_number"][:2000], a["number_of_returns"][:2000])  # imports
    tin_grid(pc.xyz[:2000], 1.0)
    print(f"{len(pc):,} points in memory ({int(g.sum()):,} ground); load average "
          f"{' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    print(f"{'kernel':34} {'wall s':>7} {'CPU s':>7} {'points/CPU-s':>13}")
    for name, fn in runs:
        t, c = time.perf_counter(), time.process_time()
        fn()
        dt, dc = time.perf_counter() - t, time.process_time() - c
        print(f"{name:34} {dt:7.2f} {dc:7.2f} {len(pc) / dc:13,.0f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=float, default=2e6)
    ap.add_argument("--tiles", type=int, default=4)
    ap.add_argument("--full", action="store_true", help="50 million points in 25 tiles")
    ap.add_argument("--kinds", default="ground,dsm,dtm")
    ap.add_argument("--kernels", action="store_true", help="time the computations in memory (--points, 1 tile)")
    ap.add_argument("--mode", help=argparse.SUPPRESS)
    ap.add_argument("--dir", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.mode:
        kind, workers = args.mode.split(":")
        print(json.dumps(_mode(args.dir, kind, int(workers))))
        return
    if args.kernels:
        _kernels(int(args.points) if args.points != 2e6 else 1_000_000)
        return
    points, tiles = (50_000_000, 25) if args.full else (int(args.points), args.tiles)
    with tempfile.TemporaryDirectory(prefix="bench_production_") as tmp:
        folder = Path(tmp)
        info = generate(folder, points, tiles, "laz")
        n = info["points"]
        load = os.getloadavg()
        print(f"{n:,} points in {info['tiles']} LAZ tiles of {info['tile_side_m']:.0f} m; "
              f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} on {os.cpu_count()} cores")
        print(f"{'task':8} {'mode':10} {'seconds':>9} {'points/s':>12} {'CPU s':>14} {'pts/CPU-s':>10} "
              f"{'peak MB per process/worker':>28}  load")
        for kind in args.kinds.split(","):
            for workers, label in ((0, "serial"), (1, "1 worker"), (2, "2 workers")):
                r = subprocess.run([sys.executable, __file__, "--mode", f"{kind}:{workers}", "--dir", str(folder)],
                                   capture_output=True, text=True, check=True)
                res = json.loads(r.stdout.strip().splitlines()[-1])
                peaks = ", ".join(f"{p:.0f}" for p in res["peak_mb"])
                cpus = ", ".join(f"{c:.1f}" for c in res["cpu_s"])
                print(f"{kind:8} {label:10} {res['seconds']:9.1f} {n / res['seconds']:12,.0f} {cpus:>14} "
                      f"{n / max(sum(res['cpu_s']), 1e-9):10,.0f} {peaks:>28}  {os.getloadavg()[0]:.1f}",
                      flush=True)
        print(f"load average after: {' '.join(f'{v:.1f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
