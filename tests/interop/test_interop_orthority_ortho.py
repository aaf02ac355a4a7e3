"""Issue 25 acceptance: orthority's orthophoto of a photo, made from lidarcat's export
(``lidarcat export opk --flavour orthority``: orientations, ``.prj`` and the camera with its
distortion converted), agrees with lidarcat's own orthophoto (:mod:`lidarcat.mapping.ortho`) to
0.05 m (median displacement).

The scene is the synthetic one of ``tests/ortho_scene.py``: a 1200 x 800 px photo rendered with a
distorted camera (up to ~9 px of radial distortion at the corners) 250 m above a terrain with
buildings, and the scene's DSM (0.25 m cells) as the DEM of both.  Both orthophotos are standard
(orthority has no occlusion mask) on the same 0.25 m grid; the displacement between them is
measured by phase correlation in 64 x 64 cell windows (those with texture), in metres: median
0.011 m, 95th percentile 0.032 m.  The cameras themselves agree to 0.002 px (orthority's
projection of ground points against lidarcat's: the Brown fit of the distortion and the
pixel-centre origin), so the residue is the two resamplings (bilinear photo, DEM) and the
correlation's own noise.  The same orthority run with the distortion left out of the camera
(what the export wrote before issue 25) is off by 0.11 m median, 0.47 m at the 95th percentile: the
measure sees what the converted distortion is for.
orthority is an optional, test-only dependency (AGPL-3.0); the test skips without it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner
from ortho_scene import CAM, EO_A, GSD, MODEL_BOUNDS, rendered

from lidarcat.cli.main import cli
from lidarcat.interop.block import Block, write_survey
from lidarcat.lidar.geotiff import write_geotiff
from lidarcat.mapping.monoplot import GridSurface
from lidarcat.mapping.ortho import PhotoModel, orthophoto
from lidarcat.synthetic.scene import demo_scene

oty = pytest.importorskip("orthority")
param_io = pytest.importorskip("orthority.param_io")
rasterio = pytest.importorskip("rasterio")
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore::DeprecationWarning",
                                        "ignore::rasterio.errors.NotGeoreferencedWarning")

CRS = "EPSG:31982"
WIN = 64      # cells of a correlation window (16 m)


def _survey(tmp_path: Path) -> Path:
    """A one-photo survey of the scene's camera and orientation (no observations: orientations only)."""
    e = np.empty(0, dtype=str)
    blk = Block(name="ortho", crs=CRS, height_system="ellipsoidal", cameras={CAM.id: CAM},
                photo_ids=np.array(["A"]), photo_camera=np.array([CAM.id]), eo=EO_A[None, :].copy(),
                obs_photo=e, obs_point=e, obs_px=np.empty((0, 2)), obs_mm=np.empty((0, 2)),
                point_ids=e, points_m=np.empty((0, 3)), ground_ids=e, ground_m=np.empty((0, 3)),
                ground_sd_m=np.empty((0, 3)), ground_source=e)
    return write_survey(blk, tmp_path / "survey")


def window_shifts_m(a: np.ndarray, b: np.ndarray, gsd_m: float, win: int = WIN) -> np.ndarray:
    """Displacement (m, east and north) of *b* relative to *a* in each *win* x *win* window where
    both are valid and textured (grey sd > 5), by phase correlation; (k, 2)."""
    han = cv2.createHanningWindow((win, win), cv2.CV_64F)
    out = []
    for r in range(0, a.shape[0] - win + 1, win):
        for c in range(0, a.shape[1] - win + 1, win):
            wa, wb = a[r:r + win, c:c + win], b[r:r + win, c:c + win]
            if not (np.isfinite(wa).all() and np.isfinite(wb).all()) or wa.std() < 5:
                continue
            (dx, dy), resp = cv2.phaseCorrelate(wa.astype(np.float64), wb.astype(np.float64), han)
            if resp > 0.2:
                out.append((dx * gsd_m, -dy * gsd_m))    # columns east, rows south
    return np.array(out).reshape(-1, 2)


def _export(tmp_path: Path) -> tuple[dict, object]:
    """``lidarcat export opk --flavour orthority`` of the one-photo survey, read as orthority reads it:
    the interior parameters and the CSV reader (exterior parameters, CRS from the .prj)."""
    csv = tmp_path / "ext.csv"
    res = CliRunner().invoke(cli, ["export", "opk", str(_survey(tmp_path)), "--flavour", "orthority",
                                   "-o", str(csv)])
    assert res.exit_code == 0, res.output
    reader = param_io.CsvReader(csv)
    assert reader.crs.to_epsg() == 31982
    return param_io.read_oty_int_param(csv.with_name(csv.stem + "_int_param.yaml")), reader


def _orthority(tmp_path: Path, name: str, int_param: dict, reader) -> tuple[np.ndarray, object]:
    """orthority's orthophoto of A.png over dsm.tif (bilinear, 0.25 m cells aligned to the grid):
    the grey values (NaN outside) and the bounds."""
    cams = oty.FrameCameras(int_param, reader.read_ext_param())
    oty.Ortho(tmp_path / "A.png", tmp_path / "dsm.tif", cams.get("A"), crs=reader.crs).process(
        tmp_path / name, resolution=(GSD, GSD), interp="bilinear", dem_interp="bilinear", dtype="float32",
        compress="deflate", build_ovw=False, aligned_pixels=True)
    with rasterio.open(tmp_path / name) as src:
        img = src.read(1).astype(np.float64)
        img[src.read_masks(1) == 0] = np.nan
        assert src.crs.to_epsg() == 31982 and src.res == (GSD, GSD)
        return img, src.bounds


def test_orthority_camera_from_export_projects_as_lidarcat(tmp_path):
    """The geometry alone (fast): orthority's camera from the export projects ground points where
    lidarcat's orthophoto model does, to 0.01 px (the Brown fit of the distortion, the pixel-centre
    origin, the angles and the CRS)."""
    int_param, reader = _export(tmp_path)
    photo = PhotoModel("A", np.zeros((CAM.rows_px, CAM.columns_px), np.uint8), CAM, EO_A)
    rng = np.random.default_rng(0)
    enh = np.vstack([rng.uniform(EO_A[0] - 120, EO_A[0] + 120, 5000), rng.uniform(EO_A[1] - 80, EO_A[1] + 80, 5000),
                     np.full(5000, 910.0)])
    col, row, _ = photo.project(*enh)
    ok = photo.inside(col, row)
    px = oty.FrameCameras(int_param, reader.read_ext_param()).get("A").world_to_pixel(enh[:, ok])
    d = np.hypot(px[0] - col[ok], px[1] - row[ok])
    print(f"orthority vs lidarcat projection: median {np.median(d):.4f} px, max {d.max():.4f} px")
    assert ok.sum() > 4000 and d.max() < 0.01


def test_orthority_orthophoto_from_export_agrees_with_lidarcat(tmp_path):
    scene = demo_scene()
    image = rendered("A")
    dsm, t = scene.grid(MODEL_BOUNDS, 0.25, "dsm")
    write_geotiff(tmp_path / "dsm.tif", dsm, t, CRS)
    cv2.imwrite(str(tmp_path / "A.png"), image)
    int_param, reader = _export(tmp_path)
    theirs, b = _orthority(tmp_path, "oty.tif", int_param, reader)    # as its user would run it

    # lidarcat's own, on the same grid
    mine = orthophoto(PhotoModel("A", image, CAM, EO_A), GridSurface(dsm, t), GSD,
                      bounds=(b.left, b.bottom, b.right, b.top)).array[:, :, 0].astype(np.float64)
    assert mine.shape == theirs.shape
    both = np.isfinite(mine) & np.isfinite(theirs)
    assert both.sum() > 0.8 * np.isfinite(mine).sum()     # the same footprint

    d = window_shifts_m(mine, theirs, GSD)
    dist = np.hypot(d[:, 0], d[:, 1])
    med, p95 = float(np.median(dist)), float(np.percentile(dist, 95))
    grey = float(np.nanmedian(np.abs(mine - theirs)[both]))
    print(f"orthority vs lidarcat orthophoto: {len(d)} windows, displacement median {med:.4f} m, "
          f"95th percentile {p95:.4f} m, mean (E, N) ({d[:, 0].mean():+.4f}, {d[:, 1].mean():+.4f}) m; "
          f"median |grey difference| {grey:.2f}")
    assert len(d) >= 50
    assert med <= 0.05 and p95 <= 0.1

    # the measure sees what the export's distortion is for: the same camera without it is off
    bare = {k: {**v, **{c: 0.0 for c in ("k1", "k2", "k3", "p1", "p2")}} for k, v in int_param.items()}
    plain, b2 = _orthority(tmp_path, "oty_bare.tif", bare, reader)      # its footprint differs a little
    same = np.full_like(mine, np.nan)                                   # on the grid of the others
    r0, c0 = round((b.top - b2.top) / GSD), round((b2.left - b.left) / GSD)
    rs, cs = slice(max(r0, 0), min(r0 + plain.shape[0], mine.shape[0])), \
        slice(max(c0, 0), min(c0 + plain.shape[1], mine.shape[1]))
    same[rs, cs] = plain[rs.start - r0:rs.stop - r0, cs.start - c0:cs.stop - c0]
    d0 = np.hypot(*window_shifts_m(mine, same, GSD).T)
    print(f"without the distortion: displacement median {np.median(d0):.4f} m, "
          f"95th percentile {np.percentile(d0, 95):.4f} m")
    assert np.median(d0) > 0.08 and np.percentile(d0, 95) > 0.3
