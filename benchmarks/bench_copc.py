"""Benchmark of COPC box queries (lidarcat.lidar.copc) against a whole-file read + filter.

Writes one synthetic COPC tile (uniform points over ``--size-m`` squared,
octree of ``--depth`` levels, written with copc-lib from the test extra, as
``tests/copc_fixture.py`` does) and, for plan boxes covering 0.25 %, 1 %,
10 % and 100 % of the tile, times

``whole + filter``   the peer: ``read_points`` of the whole file (the LAS/LAZ
                     path, all chunks) and a numpy box mask;
``COPC octree``      ``read_copc_box`` (laspy's COPC reader, only the nodes
                     whose cube meets the box);

and prints the nodes and points decoded and the bytes read.  Both must return
the same points (checked).  BLAS is pinned to one thread; note ``uptime``.

Usage::

    python benchmarks/bench_copc.py                      # 2 million points, depth 4
    python benchmarks/bench_copc.py --points 1e7 --depth 5
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=float, default=2e6, help="points in the tile")
    ap.add_argument("--size-m", type=float, default=1000.0, help="side of the tile, metres")
    ap.add_argument("--depth", type=int, default=4, help="octree depth")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case (best kept)")
    a = ap.parse_args(argv)
    from copc_fixture import write_copc

    from lidarcat.lidar import read_points
    from lidarcat.lidar.copc import read_copc_box

    n = int(a.points)
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(500000, 500000 + a.size_m, n),
                           rng.uniform(7500000, 7500000 + a.size_m, n), rng.uniform(10, 60, n)])
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "tile.copc.laz"
        t0 = time.perf_counter()
        fx = write_copc(path, xyz, depth=a.depth)
        print(f"wrote {n:,} points, {len(fx.nodes)} nodes, depth {a.depth}, {path.stat().st_size / 1e6:.1f} MB "
              f"in {time.perf_counter() - t0:.1f} s")
        del xyz
        print(f"load: {os.getloadavg()[0]:.2f} (1 min)")
        print()
        print("| box (% of tile) | method | time (s) | nodes | points decoded | MB read | points returned |")
        print("|---|---|---|---|---|---|---|")
        for frac in (0.0025, 0.01, 0.1, 1.0):
            side = a.size_m * np.sqrt(frac)
            x0, y0 = 500000 + 0.37 * (a.size_m - side), 7500000 + 0.61 * (a.size_m - side)
            box = (x0, y0, x0 + side, y0 + side)
            best_w, best_c = np.inf, np.inf
            for _ in range(a.repeat):
                t = time.perf_counter()
                whole = read_points(path, crs="EPSG:31983")
                m = ((whole.xyz[:, 0] >= box[0]) & (whole.xyz[:, 0] <= box[2]) & (whole.xyz[:, 1] >= box[1])
                     & (whole.xyz[:, 1] <= box[3]))
                ref = whole.xyz[m]
                best_w = min(best_w, time.perf_counter() - t)
                del whole
                t = time.perf_counter()
                res = read_copc_box(path, box, crs="EPSG:31983")
                best_c = min(best_c, time.perf_counter() - t)
            assert np.array_equal(res.cloud.xyz, ref), "COPC query and whole read differ"
            size_mb = path.stat().st_size / 1e6
            print(f"| {100 * frac:g} | whole + filter | {best_w:.3f} | {len(fx.nodes)} | {n:,} | {size_mb:.1f} | "
                  f"{len(ref):,} |")
            print(f"| {100 * frac:g} | COPC octree | {best_c:.3f} | {res.nodes_read} | {res.points_decoded:,} | "
                  f"{res.bytes_read / 1e6:.1f} | {len(res.cloud):,} |")


if __name__ == "__main__":
    main()
