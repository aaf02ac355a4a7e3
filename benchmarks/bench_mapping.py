"""Mapping throughput: orthophoto output megapixels/s and monoplot points/s, with peak memory.

    python benchmarks/bench_mapping.py            # 4500 x 3000 photo, 0.2 m output
    python benchmarks/bench_mapping.py --quick    # 1500 x 1000 photo (a smoke run)

A 4500 x 3000 px photo (36 x 24 mm frame, c = 35 mm, 700 m above the demo
scene: 0.16 m photo pixels) is orthorectified at 0.2 m over the scene's DSM
(0.5 m cells): a standard orthophoto (no z-buffer) beside the true orthophoto
(z-buffer occlusions), written as a GeoTIFF in 1024-row bands.  Monoplot:
random pixels over the photo intersected with the LiDAR points of the scene
(4 points/m^2) as a TIN and by nearest neighbour, and with the DSM grid
(bilinear): the exact first hit beside the paper's height iteration.  Peak
memory is the largest traced Python/numpy allocation during the stage
(``tracemalloc``), photo and surface excluded (they are allocated before).
BLAS is pinned to one thread.  Note ``uptime`` next to the figures.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.geometry.camera import Camera  # noqa: E402
from lidarcat.mapping.monoplot import GridSurface, PointSurface, monoplot  # noqa: E402
from lidarcat.mapping.ortho import PhotoModel, orthophoto  # noqa: E402
from lidarcat.synthetic.scene import demo_scene  # noqa: E402

E0, N0 = 680_400.0, 7_184_200.0


def _measure(fn):
    tracemalloc.start()
    t = time.perf_counter()
    out = fn()
    dt = time.perf_counter() - t
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return out, dt, peak / 2**20


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1500 x 1000 photo")
    ap.add_argument("--points", type=int, default=20000, help="monoplot pixels")
    args = ap.parse_args()
    cols, rows = (1500, 1000) if args.quick else (4500, 3000)
    pix = 36.0 / cols
    cam = Camera("bench", 35.0, 0.01, -0.02, -2.5e-5, 1e-8, 0.0, 2e-6, -1e-6, 0.0, pix, pix, cols, rows)
    scene = demo_scene()
    eo = np.array([E0, N0, 910 + 700.0, math.radians(0.8), math.radians(-0.6), math.radians(15.0)])
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (rows, cols), dtype=np.uint8)   # content does not change the cost
    photo = PhotoModel("1", image, cam, eo)
    half_w, half_h = 0.55 * 36 / 35 * 700, 0.55 * 24 / 35 * 700
    box = (E0 - half_w, N0 - half_w, E0 + half_w, N0 + half_w)
    dsm = GridSurface(*scene.grid(box, 0.5, "dsm"))
    out_box = (E0 - 0.45 * 36 / 35 * 700, N0 - 0.45 * 24 / 35 * 700, E0 + 0.45 * 36 / 35 * 700,
               N0 + 0.45 * 24 / 35 * 700)
    rows_out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, true in (("ortho standard (no z-buffer)", False), ("ortho true (z-buffer)", True)):
            res, dt, peak = _measure(lambda: orthophoto(photo, dsm, 0.2, Path(tmp) / "o.tif", bounds=out_box,
                                                        true_ortho=true, preview=False))
            mp = res.shape[0] * res.shape[1] / 1e6
            rows_out.append((name, f"{mp:.1f} MP out", dt, f"{mp / dt:.2f} MP/s", peak))
    lid = scene.lidar_points((E0 - 100, N0 - 100, E0 + 100, N0 + 100), 4.0, seed=1)
    from lidarcat.geometry.collinearity import project

    pts = np.column_stack([rng.uniform(E0 - 95, E0 + 95, args.points), rng.uniform(N0 - 95, N0 + 95, args.points)])
    pts = np.column_stack([pts, scene.dsm(pts[:, 0], pts[:, 1])])
    xy, _ = project(np.broadcast_to(eo, (len(pts), 6)), pts, np.full(len(pts), cam.focal_length_mm))
    px = cam.photo_to_pixel(xy)
    surfaces = {}
    for name, make in (("TIN of LiDAR points", lambda: PointSurface(lid["xyz"], "tin")),
                       ("nearest LiDAR point", lambda: PointSurface(lid["xyz"], "nearest"))):
        s, dt, peak = _measure(make)
        surfaces[name] = s
        rows_out.append((f"build {name}", f"{len(lid['xyz'])} pts", dt, f"{len(lid['xyz']) / dt / 1e3:.0f} k pts/s",
                         peak))
    surfaces["DSM grid bilinear"] = dsm
    for name, s in surfaces.items():
        for method in ("exact", "iterate"):
            res, dt, peak = _measure(lambda: monoplot(px, cam, eo, s, method=method))
            rows_out.append((f"monoplot {method}, {name}", f"{len(px)} pts, {res.counts().get('ok', 0)} ok", dt,
                             f"{len(px) / dt:,.0f} pts/s", peak))
    load = os.getloadavg()[0]
    print(f"photo {cols} x {rows} px, output 0.2 m; load average {load:.2f} (2 cores shared)")
    print(f"{'stage':<44} {'size':<22} {'time (s)':>9} {'throughput':>16} {'peak MB':>8}")
    for r in rows_out:
        print(f"{r[0]:<44} {r[1]:<22} {r[2]:>9.2f} {r[3]:>16} {r[4]:>8.0f}")


if __name__ == "__main__":
    main()
