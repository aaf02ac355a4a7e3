"""Benchmark of the LiDAR access layer: read and clip throughput, peak memory.

Generates a synthetic survey (terrain + box houses with gable roofs + noise;
intensity, returns, classes, GPS time) as square LAZ (or LAS) tiles in a
temporary folder, then measures, each phase in a fresh subprocess so that its
peak resident memory (VmHWM of /proc/self/status) is its own:

``index``    TileIndex.build over all tiles (headers only)
``stream``   every point of the survey streamed chunk by chunk (bounded memory)
``clip``     random 5 m roof clips through the TileIndex: "cold" (no tile cache,
             every clip decodes the tiles it touches: ``decode="whole"``),
             "cold, blocks" (no cache, block index from the JSON cache: only the
             LAZ chunks whose box meets the clip are decoded) and "cached" (jobs
             grouped by tile, decoded tiles kept in memory, as a batch
             extraction does) plus "hot" clips in a tile already in memory
             (cell-grid lookup) and clips of a plain PointCloud (linear scan)
``ascii``    read_points of one tile written as a text .xyz file

Point order inside the tiles (``--order``): ``random`` (default; points drawn
uniformly, so every LAZ chunk spans the whole tile and the block index cannot
help) or ``scan`` (the same kind of points stored in acquisition order: flight
strips 60 m wide along x, alternate directions, as airborne files are).
``--order both`` runs every phase on the random tiles and the clip phase on
scan-ordered tiles too.

Usage::

    python benchmarks/bench_lidar.py                 # 5 million points (about a minute)
    python benchmarks/bench_lidar.py --full          # 50 million points in 25 tiles (several minutes)
    python benchmarks/bench_lidar.py --points 2e7 --tiles 16 --format las
    python benchmarks/bench_lidar.py --full --order both   # cold clips: whole tile vs blocks
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import resource  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

CRS = "EPSG:31982"  # SIRGAS 2000 / UTM 22S
E0, N0 = 677000.0, 7183000.0
DENSITY = 10.0  # points per m^2
STRIP_M = 60.0  # width of a flight strip in the scan-ordered tiles


def _peak_mb() -> float:
    """Peak resident memory of this process, MB (VmHWM: unlike ru_maxrss it is not
    inherited from the parent across fork + exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _tile_cloud(i: int, j: int, side_m: float, n: int, seed: int, order: str = "random"):
    from lidarcat.lidar import PointCloud

    rng = np.random.default_rng(seed)
    x0, y0 = E0 + i * side_m, N0 + j * side_m
    x = np.round(rng.uniform(x0, x0 + side_m, n), 3)
    y = np.round(rng.uniform(y0, y0 + side_m, n), 3)
    ground = 900.0 + 0.01 * (x - E0) + 5.0 * np.sin((y - N0) / 300.0)
    # houses: 12 x 10 m blocks on a 30 m grid, gable roofs, 6 m eaves, 35 deg pitch
    u = np.mod(x - E0, 30.0)
    v = np.mod(y - N0, 30.0)
    house = (u > 9) & (u < 21) & (v > 10) & (v < 20)
    roof = 6.0 + np.tan(np.radians(35)) * (5.0 - np.abs(v - 15.0))
    h = np.round(ground + np.where(house, roof, 0.0) + rng.normal(0, 0.03, n), 3)
    nret = np.where(house, 1, rng.integers(1, 4, n)).astype(np.uint8)
    ret = np.minimum(rng.integers(1, 4, n), nret).astype(np.uint8)
    cls = np.where(house, 6, np.where(ret == nret, 2, 1)).astype(np.uint8)
    attrs = {"intensity": rng.integers(20, 300, n).astype(np.uint16), "return_number": ret,
             "number_of_returns": nret, "classification": cls,
             "point_source_id": np.full(n, 1 + (j % 3), np.uint16),
             "gps_time": np.round(1e5 + (i * 1000 + j) * 100 + np.sort(rng.uniform(0, 100, n)), 6)}
    import pyproj

    xyz = np.column_stack([x, y, h])
    if order == "scan":  # acquisition order: strip by strip, along x, alternate flight directions
        strip = np.floor((y - y0) / STRIP_M)
        along = np.where(strip % 2 == 0, x, -x)
        perm = np.lexsort((along, strip))
        xyz = xyz[perm]
        attrs = {k: (v if k == "gps_time" else v[perm]) for k, v in attrs.items()}  # time follows file order
    return PointCloud(xyz, attrs, pyproj.CRS(CRS))


def generate(folder: Path, points: int, tiles: int, fmt: str, order: str = "random",
             prefix: str = "tile") -> dict:
    from lidarcat.lidar import write_points

    per_side = int(round(math.sqrt(tiles)))
    tiles = per_side * per_side
    n_tile = int(math.ceil(points / tiles))
    side = math.sqrt(n_tile / DENSITY)
    t = time.perf_counter()
    for i in range(per_side):
        for j in range(per_side):
            write_points(folder / f"{prefix}_{i:02d}_{j:02d}.{fmt}",
                         _tile_cloud(i, j, side, n_tile, 1000 * i + j, order))
    return {"tiles": tiles, "points": n_tile * tiles, "points_per_tile": n_tile, "tile_side_m": side,
            "generate_s": time.perf_counter() - t,
            "bytes": sum(p.stat().st_size for p in folder.glob(f"{prefix}_*.{fmt}"))}


# ----------------------------------------------------------------------------- phases (subprocess)
def phase_index(folder: Path, args) -> dict:
    from lidarcat.lidar import TileIndex

    t = time.perf_counter()
    idx = TileIndex.build(str(folder / "tile_*"), cache_path=folder / "index.json")
    dt = time.perf_counter() - t
    t = time.perf_counter()
    TileIndex.build(str(folder / "tile_*"), cache_path=folder / "index.json")
    return {"tiles": len(idx), "points": idx.count, "build_s": dt, "cached_build_s": time.perf_counter() - t,
            **_block_index(folder, "tile")}


def _block_index(folder: Path, prefix: str) -> dict:
    """Build the block index of every tile (one full read each) into blocks_<prefix>.json."""
    from lidarcat.lidar import TileIndex

    cache = folder / f"blocks_{prefix}.json"
    t = time.perf_counter()
    idx = TileIndex.build(str(folder / f"{prefix}_*"), cache_path=cache, blocks=True, max_cached_points=0)
    dt = time.perf_counter() - t
    t = time.perf_counter()
    again = TileIndex.build(str(folder / f"{prefix}_*"), cache_path=cache, max_cached_points=0)
    dt2 = time.perf_counter() - t
    assert all(again.block_index(tl) is not None for tl in again.tiles)
    return {"blocks_build_s": dt, "blocks_cached_build_s": dt2, "blocks_json_bytes": cache.stat().st_size,
            "blocks_per_tile": len(idx.block_index(idx.tiles[0])),
            "cells_per_tile": len(idx.block_index(idx.tiles[0]).boxes)}


def phase_stream(folder: Path, args) -> dict:
    from lidarcat.lidar import TileIndex

    idx = TileIndex.build(str(folder / "tile_*"), max_cached_points=0, chunk_size=args.chunk)
    t = time.perf_counter()
    n = 0
    zmax = -np.inf
    for c in idx.iter_points():
        n += len(c)
        zmax = max(zmax, float(c.z.max()))
    dt = time.perf_counter() - t
    return {"points": n, "seconds": dt, "points_per_s": n / dt, "chunk": args.chunk}


def phase_clip(folder: Path, args) -> dict:
    from lidarcat.lidar import TileIndex, clip

    prefix = args.prefix
    rng = np.random.default_rng(5)
    out = {}
    if prefix != "tile":  # the index phase made the random tiles' block index; make this one's
        out["blocks_index"] = _block_index(folder, prefix)
    batch_centers = None
    for mode, cache in (("cold", 0), ("cold_blocks", 0), ("cached", 8_000_000), ("cached_blocks", 8_000_000)):
        if mode in ("cold_blocks", "cached_blocks"):  # block index read from the JSON cache, no full pass here
            idx = TileIndex.build(str(folder / f"{prefix}_*"), cache_path=folder / f"blocks_{prefix}.json",
                                  max_cached_points=cache)
            assert all(idx.block_index(tl) is not None for tl in idx.tiles)
        else:
            idx = TileIndex.build(str(folder / f"{prefix}_*"), max_cached_points=cache,
                                  decode="whole" if mode == "cold" else "auto")
            # header bounds are never trusted: measure them once (as `lidar index` does), untimed
            idx.verify_bounds()
            idx.clear_cache()
            idx.decoded_points = 0
        b = idx.bounds
        nclip = args.clips if mode.startswith("cached") else max(5, args.clips // 10)
        if mode == "cached_blocks":  # the same batch, the block index known: blocks kept in memory
            centers = batch_centers
        else:
            # cold_blocks: the very clips of "cold" (same generator state)
            r = np.random.default_rng(5) if mode == "cold_blocks" else rng
            # roof vertices on the house grid (ridge ends), so the height filter has roofs to keep
            gx = r.integers(0, int((b.xmax - b.xmin) // 30) - 1, nclip)
            gy = r.integers(0, int((b.ymax - b.ymin) // 30) - 1, nclip)
            centers = np.column_stack([E0 + 30 * gx + 9.0, N0 + 30 * gy + 15.0])
        if mode == "cached":  # jobs grouped by tile, as a batch extraction should order them
            side = idx.tiles[0].bounds.xmax - idx.tiles[0].bounds.xmin
            tile_ij = np.floor((centers - [b.xmin, b.ymin]) / side)
            centers = batch_centers = centers[np.lexsort((tile_ij[:, 1], tile_ij[:, 0]))]
        t = time.perf_counter()
        kept = 0
        for c in centers:
            kept += len(clip(idx, c, 5.0, height_filter="robust", min_points=1))
        dt = time.perf_counter() - t
        out[mode] = {"clips": nclip, "seconds": dt, "clips_per_s": nclip / dt,
                     "points_kept_per_clip": kept / nclip,
                     "survey_points_per_s": None, "decoded_per_clip": idx.decoded_points / nclip,
                     "tile_points": idx.tiles[0].count}
        if mode == "cold":  # each clip decodes its tile(s): survey points handled per second
            per_tile = idx.tiles[0].count
            out[mode]["survey_points_per_s"] = nclip * per_tile / dt
    # hot: clips inside one tile already decoded and kept in memory (the query cost alone)
    idx = TileIndex.build(str(folder / f"{prefix}_*"), max_cached_points=8_000_000)
    idx.verify_bounds()
    t0 = idx.tiles[0]
    idx.query_radius(((t0.bounds.xmin + t0.bounds.xmax) / 2, (t0.bounds.ymin + t0.bounds.ymax) / 2), 5.0)
    gx = rng.integers(0, int((t0.bounds.xmax - t0.bounds.xmin) // 30) - 1, args.clips)
    gy = rng.integers(0, int((t0.bounds.ymax - t0.bounds.ymin) // 30) - 1, args.clips)
    centers = np.column_stack([t0.bounds.xmin + 30 * gx + 9.0, t0.bounds.ymin + 30 * gy + 15.0])
    t = time.perf_counter()
    for c in centers:
        clip(idx, c, 5.0, height_filter="robust", min_points=1)
    dt = time.perf_counter() - t
    out["hot"] = {"clips": len(centers), "clips_per_s": len(centers) / dt}
    # in-memory clip of one decoded tile: points scanned per second
    from lidarcat.lidar import read_points

    pc = read_points(idx.tiles[0].path)
    b = pc.bounds
    t = time.perf_counter()
    reps = 50
    for k in range(reps):
        x = (b.xmin + b.xmax) / 2 + k * (b.xmax - b.xmin) / (2 * reps)  # inside the tile, whatever its size
        clip(pc, (x, (b.ymin + b.ymax) / 2), 5.0, height_filter=None, min_points=0)
    dt = time.perf_counter() - t
    out["in_memory"] = {"points": len(pc), "clips_per_s": reps / dt, "points_scanned_per_s": reps * len(pc) / dt}
    return out


def phase_ascii(folder: Path, args) -> dict:
    from lidarcat.lidar import read_points, write_points

    src = sorted(folder.glob("tile_*.la[sz]"))[0]
    pc = read_points(src).select(slice(0, args.ascii_points))
    p = folder / "ascii_tile.xyz"
    t = time.perf_counter()
    write_points(p, pc)
    wt = time.perf_counter() - t
    t = time.perf_counter()
    back = read_points(p, crs=CRS)
    dt = time.perf_counter() - t
    assert np.array_equal(back.xyz, pc.xyz)
    return {"points": len(pc), "read_s": dt, "read_points_per_s": len(pc) / dt,
            "write_points_per_s": len(pc) / wt, "bytes": p.stat().st_size}


PHASES = {"index": phase_index, "stream": phase_stream, "clip": phase_clip, "ascii": phase_ascii}


def _run_phase(name: str, folder: Path, args, prefix: str = "tile") -> dict:
    cmd = [sys.executable, __file__, "--phase", name, "--dir", str(folder), "--chunk", str(args.chunk),
           "--clips", str(args.clips), "--ascii-points", str(args.ascii_points), "--prefix", prefix]
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise SystemExit(f"phase {name} failed:\n{res.stderr}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=float, default=5e6, help="survey size (default 5e6)")
    ap.add_argument("--full", action="store_true", help="50 million points in 25 tiles")
    ap.add_argument("--tiles", type=int, default=25, help="number of tiles (a square number)")
    ap.add_argument("--format", choices=["laz", "las"], default="laz")
    ap.add_argument("--chunk", type=int, default=2_000_000, help="streaming chunk, points")
    ap.add_argument("--clips", type=int, default=200, help="clips in the cached clip phase")
    ap.add_argument("--ascii-points", type=int, default=1_000_000)
    ap.add_argument("--keep", type=Path, default=None, help="generate into (and keep) this folder")
    ap.add_argument("--order", choices=["random", "scan", "both"], default="random",
                    help="point order in the tiles (see above; default random)")
    ap.add_argument("--prefix", default="tile", help=argparse.SUPPRESS)
    ap.add_argument("--phase", choices=sorted(PHASES), help=argparse.SUPPRESS)
    ap.add_argument("--dir", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.phase:
        out = PHASES[args.phase](args.dir, args)
        out["peak_rss_mb"] = _peak_mb()
        print(json.dumps(out))
        return
    points = 50_000_000 if args.full else int(args.points)
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench_lidar_"))
    folder.mkdir(parents=True, exist_ok=True)
    try:
        first = "scan" if args.order == "scan" else "random"
        gen = generate(folder, points, args.tiles, args.format, first)
        print(f"survey: {gen['points']:,} points in {gen['tiles']} {args.format.upper()} tiles of "
              f"{gen['points_per_tile']:,} ({gen['tile_side_m']:.0f} m side, {DENSITY:g} pts/m2), "
              f"{gen['bytes'] / 1e6:,.0f} MB, points in {first} order; generated in {gen['generate_s']:.0f} s")
        res = {name: _run_phase(name, folder, args) for name in ("index", "stream", "clip", "ascii")}
        if args.order == "both":
            gen2 = generate(folder, points, args.tiles, args.format, "scan", prefix="scan")
            print(f"same survey in scan order: {gen2['bytes'] / 1e6:,.0f} MB; generated in "
                  f"{gen2['generate_s']:.0f} s")
            res["clip_scan"] = _run_phase("clip", folder, args, prefix="scan")
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    i, s, c, a = res["index"], res["stream"], res["clip"], res["ascii"]
    rows = [
        ("index build (headers)", f"{i['build_s']:.2f} s", f"cached: {i['cached_build_s']:.3f} s", i["peak_rss_mb"]),
        ("stream whole survey", f"{s['points_per_s'] / 1e6:.2f} M pts/s",
         f"{s['points']:,} pts in {s['seconds']:.1f} s (chunk {s['chunk']:,})", s["peak_rss_mb"]),
        ("clip r=5 m, cold", f"{c['cold']['clips_per_s']:.2f} clips/s",
         f"{c['cold']['survey_points_per_s'] / 1e6:.2f} M survey pts/s decoded (whole tile)", None),
        ("clip r=5 m, cold, blocks", f"{c['cold_blocks']['clips_per_s']:.2f} clips/s",
         f"{c['cold_blocks']['decoded_per_clip']:,.0f} of {c['cold_blocks']['tile_points']:,} pts decoded "
         f"per clip", None),
        ("  block index (full read)", f"{i['blocks_build_s']:.1f} s",
         f"{i['blocks_per_tile']} blocks, {i['cells_per_tile']} cells/tile; cached: "
         f"{i['blocks_cached_build_s']:.3f} s, "
         f"JSON {i['blocks_json_bytes'] / 1e3:.0f} kB", None),
        ("clip r=5 m, batch", f"{c['cached']['clips_per_s']:.1f} clips/s",
         f"{c['cached']['clips']} clips grouped by tile, each tile decoded once", c["peak_rss_mb"]),
        ("clip r=5 m, batch, blocks", f"{c['cached_blocks']['clips_per_s']:.1f} clips/s",
         f"same, block index known: {c['cached_blocks']['decoded_per_clip']:,.0f} pts decoded per clip",
         None),
        ("clip r=5 m, tile in memory", f"{c['hot']['clips_per_s']:.0f} clips/s",
         f"{c['cached']['points_kept_per_clip']:.0f} pts kept per clip (robust filter)", None),
        ("clip of a PointCloud", f"{c['in_memory']['points_scanned_per_s'] / 1e6:.0f} M pts/s",
         f"linear scan: {c['in_memory']['clips_per_s']:.1f} clips/s over {c['in_memory']['points']:,} pts",
         None),
        ("ASCII .xyz read", f"{a['read_points_per_s'] / 1e6:.2f} M pts/s",
         f"{a['points']:,} pts, write {a['write_points_per_s'] / 1e6:.2f} M pts/s", a["peak_rss_mb"]),
    ]
    if "clip_scan" in res:
        cs = res["clip_scan"]
        bi = cs["blocks_index"]
        rows += [
            ("scan order: clip, cold", f"{cs['cold']['clips_per_s']:.2f} clips/s", "whole-tile decode", None),
            ("scan order: clip, blocks", f"{cs['cold_blocks']['clips_per_s']:.2f} clips/s",
             f"{cs['cold_blocks']['decoded_per_clip']:,.0f} of {cs['cold_blocks']['tile_points']:,} pts "
             f"decoded per clip", None),
            ("scan order: block index", f"{bi['blocks_build_s']:.1f} s",
             f"{bi['blocks_per_tile']} blocks, {bi['cells_per_tile']} cells/tile; cached: "
             f"{bi['blocks_cached_build_s']:.3f} s", None),
            ("scan order: clip, batch", f"{cs['cached']['clips_per_s']:.1f} clips/s",
             "grouped by tile, tiles kept in memory", cs["peak_rss_mb"]),
            ("scan order: batch, blocks", f"{cs['cached_blocks']['clips_per_s']:.1f} clips/s",
             f"block index known: {cs['cached_blocks']['decoded_per_clip']:,.0f} pts decoded per clip", None),
        ]
    print(f"{'phase':<28} {'throughput':<18} {'detail':<58} peak RSS")
    for name, thr, detail, mem in rows:
        print(f"{name:<28} {thr:<18} {detail:<58} {'' if mem is None else f'{mem:,.0f} MB'}")
    print(f"(load average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
