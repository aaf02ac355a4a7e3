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

``--writer`` measures lidarcat's own writer (:func:`lidarcat.lidar.copc_write.write_copc`)
instead: for each size of ``--writer-points`` it writes a synthetic LAZ tile
(gently rolling ground with trees, written in chunks), then converts it to COPC
in a child process and prints the time, the child's peak resident memory
(``VmHWM``) and its resident memory after the imports, the file size and
the number of hierarchy pages; the COPC file is checked (laspy's CopcReader
counts every point).  Streamed, the peak should not grow with the points.

Usage::

    python benchmarks/bench_copc.py                      # 2 million points, depth 4
    python benchmarks/bench_copc.py --points 1e7 --depth 5
    python benchmarks/bench_copc.py --writer --writer-points 2e6,8e6
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

from lidarcat.lidar.copc import read_hierarchy  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=float, default=2e6, help="points in the tile")
    ap.add_argument("--size-m", type=float, default=1000.0, help="side of the tile, metres")
    ap.add_argument("--depth", type=int, default=4, help="octree depth")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per case (best kept)")
    ap.add_argument("--writer", action="store_true", help="measure lidarcat's COPC writer (time, peak memory)")
    ap.add_argument("--writer-points", default="2e6,8e6", help="comma-separated tile sizes of --writer")
    a = ap.parse_args(argv)
    if a.writer:
        _writer([int(float(v)) for v in a.writer_points.split(",")], a.size_m)
        return
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


_CHILD = r"""
import sys, time
import laspy, lazrs, numpy
from lidarcat.lidar.copc_write import write_copc

def hwm():  # peak resident set of this process since its exec, MB (ru_maxrss would carry the parent's fork)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024

base = hwm()
t = time.perf_counter()
write_copc(sys.argv[1], sys.argv[2], crs="EPSG:31983")
dt = time.perf_counter() - t
print(dt, base, hwm())
"""


def _synthetic_laz(path: Path, n: int, size_m: float, chunk: int = 1_000_000) -> None:
    """A LAZ tile of *n* points over *size_m* squared: rolling ground, 30 % of the pulses on trees."""
    import laspy

    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500000.0, 7500000.0, 0.0])
    rng = np.random.default_rng(0)
    with laspy.open(str(path), mode="w", header=header, do_compress=True) as w:
        for a in range(0, n, chunk):
            m = min(chunk, n - a)
            x = rng.uniform(0, size_m, m)
            y = rng.uniform(0, size_m, m)
            ground = 20 + 5 * np.sin(x / 150) + 3 * np.cos(y / 90)
            tree = rng.random(m) < 0.3
            z = ground + np.where(tree, rng.uniform(2, 25, m), rng.normal(0, 0.03, m))
            rec = laspy.ScaleAwarePointRecord.zeros(m, header=header)
            rec.x, rec.y, rec.z = x + 500000.0, y + 7500000.0, z
            rec.gps_time = a + np.arange(m) * 1e-5
            rec.return_number = np.ones(m, np.uint8)
            rec.number_of_returns = np.ones(m, np.uint8)
            rec.classification = np.where(tree, 5, 2).astype(np.uint8)
            w.write_points(rec)


def _writer(sizes: list[int], size_m: float) -> None:
    import subprocess

    import laspy

    print(f"load: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)")
    print()
    print("| points | LAZ in (MB) | COPC out (MB) | pages | write (s) | RSS after imports (MB) | peak RSS (MB) |")
    print("|---|---|---|---|---|---|---|")
    src_dir = str(Path(__file__).resolve().parents[1] / "src")
    for n in sizes:
        with tempfile.TemporaryDirectory() as tmp:
            laz, out = Path(tmp) / "tile.laz", Path(tmp) / "tile.copc.laz"
            _synthetic_laz(laz, n, size_m)
            env = dict(os.environ, PYTHONPATH=src_dir)
            res = subprocess.run([sys.executable, "-c", _CHILD, str(laz), str(out)], env=env, check=True,
                                 capture_output=True, text=True)
            dt, base, peak = (float(v) for v in res.stdout.split())
            with laspy.CopcReader.open(str(out)) as r:
                assert r.header.point_count == n, "points lost"
            pages = read_hierarchy(out)[1]
            print(f"| {n:,} | {laz.stat().st_size / 1e6:.1f} | {out.stat().st_size / 1e6:.1f} | {pages} | {dt:.1f} | "
                  f"{base:.0f} | {peak:.0f} |", flush=True)
    print(f"load: {' '.join(f'{v:.2f}' for v in os.getloadavg())} (1, 5, 15 min)")


if __name__ == "__main__":
    main()
