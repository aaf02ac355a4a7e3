"""Orthophoto charts drawn serially and on the tile runner's Dask cluster (``production.charts.render_charts``).

A synthetic block of ``--sheets`` sheets of 500 m in a row (contours every 1 m of a smooth
terrain, an RGB uint8 mosaic of 1 m cells, spot heights); the same charts are drawn with
``workers=None`` (serially, in this process) and ``workers=N`` (a Dask ``LocalCluster`` of N
processes, started inside the timing), alternately, and the files compared byte for byte.  Timings depend on the load of the machine: it is printed.

Run::

    PYTHONPATH=src python benchmarks/bench_charts.py [--sheets 8] [--workers 2] [--dpi 60]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from lidarcat.lidar.geotiff import GeoTransform
from lidarcat.production.charts import TitleBlock, render_charts
from lidarcat.production.contours import contour_features, contours, spot_heights
from lidarcat.production.sheets import sheet_grid

E0, N0 = 500_000.0, 7_500_000.0


def block(n_sheets: int):
    rng = np.random.default_rng(0)
    w = 500.0 * n_sheets
    x, y = rng.uniform(E0, E0 + w, 1500 * n_sheets), rng.uniform(N0, N0 + 500, 1500 * n_sheets)
    z = 100 + 10 * np.sin((x - E0) / 120) + 5 * np.cos((y - N0) / 90)
    g = np.column_stack([x, y, z])
    feats = contour_features(contours(g, 1.0, master_every=5))
    cols = int(w)
    img = np.zeros((500, cols, 3), np.uint8)
    img[..., 0] = (np.arange(cols) % 256).astype(np.uint8)[None, :]
    img[..., 1] = (np.arange(500) % 256).astype(np.uint8)[:, None]
    img[..., 2] = 120
    return feats, spot_heights(g, 100.0), img, GeoTransform(E0, N0 + 500, 1.0), sheet_grid((E0, N0, E0 + w, N0 + 500),
                                                                                           500)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sheets", type=int, default=8)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dpi", type=int, default=60)
    ap.add_argument("--repeats", type=int, default=1)
    a = ap.parse_args()
    feats, spots, img, t, sheets = block(a.sheets)
    title = TitleBlock("bench", 5000, "SIRGAS 2000 / UTM zone 23S (EPSG:31983)", -21.5, "2009-06-01", "2026-11-28",
                       1.0, 5)
    names = [s.name for s in sheets]
    print(f"{len(sheets)} sheets, {len(feats)} contour lines, cpu_count {os.cpu_count()}, "
          f"load {os.getloadavg()[0]:.2f} at the start")
    print("| run | workers | s | s per chart | load |")
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        outs = {}
        for r in range(a.repeats):
            for w in (None, a.workers):
                out = Path(d) / f"w{w}"
                out.mkdir(exist_ok=True)
                t0 = time.perf_counter()
                render_charts(sheets, names, title, out, image=img, image_transform=t, contours=feats, spots=spots,
                              sheets=sheets, area=(E0, N0, E0 + 500.0 * a.sheets, N0 + 500), dpi=a.dpi, workers=w)
                dt = time.perf_counter() - t0
                outs[w] = out
                print(f"| {r + 1} | {w or 'serial'} | {dt:.1f} | {dt / len(sheets):.2f} | {os.getloadavg()[0]:.2f} |")
        same = all((outs[None] / f"{n}.{e}").read_bytes() == (outs[a.workers] / f"{n}.{e}").read_bytes()
                   for n in names for e in ("pdf", "png"))
        print(f"serial and parallel charts byte-identical: {same}")


if __name__ == "__main__":
    main()
