"""Orthophotos against orthority on the same photos and DEM, in the same run: seconds, file sizes, valid cells.

    python benchmarks/bench_ortho.py                   # synthetic 24 MP pair + the NGI frames (when present)
    python benchmarks/bench_ortho.py --repeat 3        # more alternated pairs (the minimum is reported)
    python benchmarks/bench_ortho.py --quick           # a 6 MP pair (smoke run)

Data
----
* **synthetic 24 MP pair**: two overlapping 6000 x 4000 RGB photos (36 x 24 mm,
  c = 35 mm, 700 m above the demo scene: 0.12 m pixels; rendered at 1500 x 1000
  by :meth:`lidarcat.synthetic.scene.Scene.render` and upsampled, stored as
  JPEG, quality 90), over the scene's DSM at 0.5 m with 4.3 % of its cells
  emptied at random (what a 0.5 m DSM of 4 points/m^2 keeps empty), float32
  GeoTIFF, NaN nodata.  No lens distortion: orthority's pinhole camera skips
  its distortion step while lidarcat still goes through its distortion table
  (the comparison is conservative for lidarcat).
* **NGI frames** (``/work/shared/data/frames/ngi``, orthority's own test data,
  read only when present): four 640 x 1152 RGB aerial frames (Intergraph DMC,
  c = 120 mm, pinhole), their positions and omega/phi/kappa, and a 24 m DEM.

Both programs get the same files, produce a standard orthophoto (no
occlusion masking: orthority has none) with bilinear resampling at the same
cell size, in the photo's data type (uint8) with overviews, DEFLATE and JPEG,
using every core (lidarcat: ``workers`` = CPU count; orthority: its thread
pool).  Each photo is orthorectified by lidarcat and by orthority in turn,
the order alternated between repeats (the machine is shared: the load is
printed), and the fastest of the repeats of each is reported; the time
includes reading the photo and the DEM.  "valid" is the share of valid cells
in the cells both outputs cover, "|diff|" the mean absolute difference
(grey levels, first band) over the cells both hold (the two agree on the
geometry).  Peer: ``pip install orthority`` (AGPL; benchmark only; skipped
when absent).
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from lidarcat.geometry.camera import Camera
from lidarcat.lidar.geotiff import write_geotiff
from lidarcat.mapping.monoplot import GridSurface
from lidarcat.mapping.ortho import PhotoModel, orthophoto

NGI = Path("/work/shared/data/frames/ngi")
E0, N0 = 680_400.0, 7_184_200.0
CRS = "EPSG:31982"


def _camera(cid: str, c_mm: float, pix_mm: float, cols: int, rows: int) -> Camera:
    return Camera(cid, c_mm, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, pix_mm, pix_mm, cols, rows)


def synthetic(tmp: Path, cols: int, rows: int) -> list[dict]:
    """Two JPEG photos and a DSM GeoTIFF with 4.3 % holes; one job per photo."""
    import cv2

    from lidarcat.synthetic.scene import demo_scene

    scene = demo_scene()
    pix = 36.0 / cols
    small = _camera("s", 35.0, 36.0 / (cols // 4), cols // 4, rows // 4)
    eos = [np.array([E0 - 110.0, N0, 1610.0, math.radians(0.8), math.radians(-0.6), math.radians(2.0)]),
           np.array([E0 + 110.0, N0, 1612.0, math.radians(-0.5), math.radians(0.7), math.radians(-1.0)])]
    half = 0.62 * 36 / 35 * 700
    box = (E0 - half - 120, N0 - half, E0 + half + 120, N0 + half)
    grid, t = scene.grid(box, 0.5, "dsm")
    grid = grid.astype(np.float32)
    rng = np.random.default_rng(0)
    grid[rng.random(grid.shape) < 0.043] = np.nan
    write_geotiff(tmp / "dsm.tif", grid, t, CRS)
    jobs = []
    for i, eo in enumerate(eos):
        g = cv2.resize(scene.render(small, eo), (cols, rows), interpolation=cv2.INTER_CUBIC)
        bgr = np.stack([cv2.GaussianBlur(g, (0, 0), 2.0), g, np.clip(g.astype(np.int16) * 4 // 5 + 30, 0, 255)
                        .astype(np.uint8)], axis=2)
        path = tmp / f"photo_{i + 1}.jpg"
        cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
        jobs.append(dict(data=f"synthetic {cols}x{rows}", photo=path, dem=tmp / "dsm.tif",
                         camera=_camera("syn", 35.0, pix, cols, rows), eo=eo, crs=CRS, gsd=0.15,
                         oty_cam=("pinhole", (cols, rows), 35.0, (36.0, 24.0))))
    return jobs


def ngi() -> list[dict]:
    """The four NGI frames over their DEM (orthority's test data)."""
    import csv

    import rasterio

    jobs = []
    with open(NGI / "ngi_xyz_opk.csv") as fh:
        for r in csv.DictReader(fh):
            path = NGI / f"{r['filename']}.tif"
            with rasterio.open(path) as src:
                crs = src.crs.to_wkt()
            eo = np.array([float(r[k]) for k in ("x", "y", "z")] + [math.radians(float(r[k]))
                                                                    for k in ("omega", "phi", "kappa")])
            jobs.append(dict(data="NGI 640x1152", photo=path, dem=NGI / "dem.tif",
                             camera=_camera("dmc", 120.0, 92.16 / 640, 640, 1152), eo=eo, crs=crs, gsd=5.0,
                             oty_cam=("pinhole", (640, 1152), 120.0, (92.16, 165.888))))
    return jobs


def _read_photo(path: Path) -> np.ndarray:
    if path.suffix.lower() in (".jpg", ".jpeg", ".png"):
        import cv2

        return np.ascontiguousarray(cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, :, ::-1])
    import rasterio

    with rasterio.open(path) as src:
        return np.ascontiguousarray(np.moveaxis(src.read(), 0, 2))


def run_lidarcat(job: dict, out: Path, compress: str) -> float:
    t = time.perf_counter()
    surface = GridSurface.from_geotiff(job["dem"])
    photo = PhotoModel("p", _read_photo(job["photo"]), job["camera"], job["eo"])
    orthophoto(photo, surface, job["gsd"], out, crs=job["crs"], compress=compress, preview=False)
    return time.perf_counter() - t


def run_orthority(job: dict, out: Path, compress: str) -> float:
    import orthority as oty

    t = time.perf_counter()
    kind, size, focal, sensor = job["oty_cam"]
    cam = oty.camera.create_camera(kind, size, focal, sensor, xyz=tuple(job["eo"][:3]), opk=tuple(job["eo"][3:]))
    oty.Ortho(job["photo"], job["dem"], cam, crs=job["crs"]).process(
        out, resolution=(job["gsd"], job["gsd"]), interp="bilinear", compress=compress, overwrite=True,
        aligned_pixels=True)
    return time.perf_counter() - t


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float]]:
    import rasterio

    with rasterio.open(path) as src:
        return src.read(1), src.dataset_mask() > 0, (src.transform.c, src.transform.f, src.transform.a)


def compare(a: Path, b: Path) -> tuple[float, float, float]:
    """Valid share of each in the cells both grids cover, and the mean |difference| where both are valid."""
    va, ma, (xa, ya, ca) = _read(a)
    vb, mb, (xb, yb, _) = _read(b)
    dc, dr = int(round((xb - xa) / ca)), int(round((ya - yb) / ca))   # b's origin in a's cells
    r0, c0 = max(0, dr), max(0, dc)
    r1, c1 = min(va.shape[0], dr + vb.shape[0]), min(va.shape[1], dc + vb.shape[1])
    sa, sb = (slice(r0, r1), slice(c0, c1)), (slice(r0 - dr, r1 - dr), slice(c0 - dc, c1 - dc))
    both = ma[sa] & mb[sb]
    either = ma[sa] | mb[sb]
    diff = float(np.abs(va[sa][both].astype(np.float64) - vb[sb][both]).mean()) if both.any() else math.nan
    return float(ma[sa][either].mean()), float(mb[sb][either].mean()), diff


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2, help="alternated pairs per photo and compression")
    ap.add_argument("--quick", action="store_true", help="3000 x 2000 synthetic photos")
    ap.add_argument("--no-ngi", action="store_true", help="skip the NGI frames")
    args = ap.parse_args()
    try:
        import orthority  # noqa: F401
        peer = True
    except ImportError:
        peer = False
        print("orthority is not installed: lidarcat only (pip install orthority)")
    rows_out = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        jobs = synthetic(tmp, *((3000, 2000) if args.quick else (6000, 4000)))
        if NGI.is_dir() and not args.no_ngi:
            jobs += ngi()
        print(f"load before: {os.getloadavg()[0]:.1f} (CPUs {os.cpu_count()})", flush=True)
        for compress in ("deflate", "jpeg"):
            for j, job in enumerate(jobs):
                tools = [("lidarcat", run_lidarcat)] + ([("orthority", run_orthority)] if peer else [])
                best: dict[str, float] = {}
                for rep in range(args.repeat):
                    for name, fn in (tools if rep % 2 == 0 else tools[::-1]):
                        out = tmp / f"{name}_{j}_{compress}.tif"
                        best[name] = min(best.get(name, math.inf), fn(job, out, compress))
                lc = tmp / f"lidarcat_{j}_{compress}.tif"
                row = dict(data=job["data"], photo=Path(job["photo"]).stem[-12:], compress=compress,
                           lc_s=best["lidarcat"], lc_mb=lc.stat().st_size / 1e6, load=os.getloadavg()[0])
                if peer:
                    oc = tmp / f"orthority_{j}_{compress}.tif"
                    va, vb, diff = compare(lc, oc)
                    row.update(oty_s=best["orthority"], oty_mb=oc.stat().st_size / 1e6, lc_valid=va, oty_valid=vb,
                               diff=diff)
                rows_out.append(row)
                print(row, flush=True)
    print()
    print("| data | photo | compression | lidarcat s | orthority s | time ratio | lidarcat MB | orthority MB "
          "| size ratio | valid lidarcat / orthority | mean abs diff | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows_out:
        if "oty_s" in r:
            print(f"| {r['data']} | {r['photo']} | {r['compress']} | {r['lc_s']:.2f} | {r['oty_s']:.2f} | "
                  f"{r['lc_s'] / r['oty_s']:.2f} | {r['lc_mb']:.2f} | {r['oty_mb']:.2f} | "
                  f"{r['lc_mb'] / r['oty_mb']:.2f} | {100 * r['lc_valid']:.1f} / {100 * r['oty_valid']:.1f} % | "
                  f"{r['diff']:.2f} | {r['load']:.1f} |")
        else:
            print(f"| {r['data']} | {r['photo']} | {r['compress']} | {r['lc_s']:.2f} | - | - | {r['lc_mb']:.2f} "
                  f"| - | - | - | - | {r['load']:.1f} |")
    tot = {k: sum(r[k] for r in rows_out if "oty_s" in r) for k in ("lc_s", "oty_s")} if peer else {}
    if tot:
        print(f"\ntotal: lidarcat {tot['lc_s']:.1f} s, orthority {tot['oty_s']:.1f} s "
              f"({tot['lc_s'] / tot['oty_s']:.2f}x)")


if __name__ == "__main__":
    main()
