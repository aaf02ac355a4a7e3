"""Contours along the edge of the ground TIN and small rings, on the AHN3 tiles (skipped when absent).

For each tile (its class-2 ground points, contours every 0.5 m, max_edge_m 50 m as the products stage):
the share of contour length within 0.1 m of the TIN's boundary (lidarcat.production.contours.edge_fraction)
with edge_peel 0 (the previous contours) and 1 (the default), the number of closed rings and of rings
shorter than 5 m, and what min_ring_m = 5 keeps.

    PYTHONPATH=src python benchmarks/bench_contour_edges.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from lidarcat.lidar import read_points
from lidarcat.production.contours import contours, edge_fraction

DATA = Path("/work/shared/data/lidar")   # evaluation data outside the project; skipped when absent
PEELS = (0, 1, 2, 3)


def main() -> None:
    tiles = sorted(DATA.glob("ahn3_cropped_*.laz")) if DATA.is_dir() else []
    if not tiles:
        print("AHN3 tiles not found: skipped")
        return
    print("| tile | ground pts | edge_peel | lines | length m | along TIN edge | rings | rings < 5 m | "
          "lines with min_ring_m 5 | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for t in tiles:
        pc = read_points(t, crs="EPSG:7415")
        g = pc.xyz[np.asarray(pc.attributes["classification"]) == 2]
        for peel in PEELS:
            t0 = time.perf_counter()
            cs = contours(g, 0.5, max_edge_m=50.0, edge_peel=peel)
            dt = time.perf_counter() - t0
            length = sum(float(np.hypot(*np.diff(c.xy, axis=0).T).sum()) for c in cs)
            rings = [c for c in cs if c.closed]
            short = sum(float(np.hypot(*np.diff(c.xy, axis=0).T).sum()) < 5.0 for c in rings)
            kept = len(contours(g, 0.5, max_edge_m=50.0, edge_peel=peel, min_ring_m=5.0))
            frac = edge_fraction(cs, g, max_edge_m=50.0, tol_m=0.1)
            print(f"| {t.name} | {len(g):,} | {peel} | {len(cs):,} | {length:,.0f} | {100 * frac:.3f} % | "
                  f"{len(rings):,} | {short:,} | {kept:,} | {dt:.1f} |")


if __name__ == "__main__":
    main()
