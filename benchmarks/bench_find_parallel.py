"""Roof-vertex search (extract --find) serially and on a LocalCluster of 2 workers; prints a table.

    python benchmarks/bench_find_parallel.py

Both AHN3 crops of tests/data/lidar in full, classes 6; checks the candidates are identical.
"""

import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

if __name__ == "__main__":
    from lidarcat.control.vertices import find_candidates
    from lidarcat.control.search import find_candidates_tiles
    from lidarcat.lidar import TileIndex

    lid = Path(__file__).resolve().parent.parent / "tests" / "data" / "lidar"
    tiles = [str(lid / "ahn3_cropped_1.laz"), str(lid / "ahn3_cropped_2.laz")]
    idx = TileIndex.build(tiles, crs="EPSG:7415")
    idx.verify_bounds()
    b = idx.bounds
    area = (b.xmin, b.ymin, b.xmax, b.ymax)
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    t = time.perf_counter()
    s = find_candidates(idx.query_box(*area), box=area, classes=[6])
    ts = time.perf_counter() - t
    t = time.perf_counter()
    p = find_candidates_tiles(idx, area, classes=[6], crs="EPSG:7415", workers=2)
    tp = time.perf_counter() - t

    def key(c):
        return (c.point.point_id, c.score, tuple(c.point.enh_m), tuple(c.point.cov_m2.ravel()))

    same = [key(c) for c in s] == [key(c) for c in p]
    print(f"| mode | seconds | candidates | identical |\n|---|---:|---:|---|\n"
          f"| serial | {ts:.1f} | {len(s)} | - |\n| Dask 2 workers | {tp:.1f} | {len(p)} | {same} |")
    print(f"load average after: {os.getloadavg()[0]:.2f}")
