"""Orthophoto files (the photo's data type, internal mask, DEFLATE/JPEG, overviews), DSM hole filling,
the separable DSM interpolation and the photos of a survey found by their image column."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import rasterio
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.lidar import PointCloud, rasterize, resolve_crs, write_points
from lidarcat.lidar.geotiff import GeoTransform, read_geotiff
from lidarcat.mapping.inputs import photo_image
from lidarcat.mapping.monoplot import GridSurface
from lidarcat.mapping.ortho import OrthoError, PhotoModel, fill_holes, grid_heights, orthophoto
from lidarcat.synthetic.scene import demo_scene
from lidarcat.errors import SurveyError

from ortho_scene import CAM, E0, EO_A, MODEL_BOUNDS, N0, rendered  # noqa: I001  (tests/ortho_scene.py)

CRS = "EPSG:31982"
B = (E0 - 40, N0 - 30, E0 + 40, N0 + 30)


@pytest.fixture(scope="module")
def scene():
    return demo_scene()


@pytest.fixture(scope="module")
def image(scene):
    return rendered("A")


@pytest.fixture(scope="module")
def dsm(scene):
    return GridSurface(*scene.grid(MODEL_BOUNDS, 0.25, "dsm"))


def _read(path):
    with rasterio.open(path) as src:
        return src.read(), src.dataset_mask() > 0, src.profile, src.overviews(1), src.mask_flag_enums


def test_uint8_file_keeps_the_values_with_an_internal_mask_and_overviews(tmp_path, image, dsm):
    photo = PhotoModel("A", image, CAM, EO_A)
    res = orthophoto(photo, dsm, 0.1, tmp_path / "o.tif", bounds=B, true_ortho=True, crs=CRS)
    data, valid, prof, ovr, flags = _read(tmp_path / "o.tif")
    assert prof["dtype"] == "uint8" and prof["compress"] == "deflate" and prof["nodata"] is None
    assert prof["tiled"] and (prof["blockxsize"], prof["blockysize"]) == (512, 512)
    assert [f.name for f in flags[0]] == ["per_dataset"]
    assert ovr == [2]                                   # 800 x 600 cells: one level down to a tile
    mem = orthophoto(photo, dsm, 0.1, bounds=B, true_ortho=True).array[:, :, 0]
    np.testing.assert_array_equal(valid, np.isfinite(mem))
    np.testing.assert_array_equal(data[0][valid], mem[valid])   # the same 8-bit values, not rounded again
    assert int(valid.sum()) == res.n_valid and res.n_occluded > 0
    grid, _, _ = read_geotiff(tmp_path / "o.tif")                 # the project's reader: NaN off the mask
    np.testing.assert_array_equal(np.isnan(grid), ~valid)


def test_black_cells_stay_values_and_uint16_stays_uint16(tmp_path, dsm):
    black = PhotoModel("K", np.zeros((CAM.rows_px, CAM.columns_px), np.uint8), CAM, EO_A)
    res = orthophoto(black, dsm, 0.5, tmp_path / "k.tif", bounds=B)
    data, valid, _, _, _ = _read(tmp_path / "k.tif")
    assert int(valid.sum()) == res.n_valid == valid.size and not data.any()   # 0 is a value, not nodata
    ramp = (np.arange(CAM.columns_px, dtype=np.uint16) * 50)[None, :].repeat(CAM.rows_px, 0)
    p16 = PhotoModel("W", ramp, CAM, EO_A)
    orthophoto(p16, dsm, 0.5, tmp_path / "w.tif", bounds=B)
    data, valid, prof, _, _ = _read(tmp_path / "w.tif")
    assert prof["dtype"] == "uint16" and data.max() > 255 * 50
    mem = orthophoto(p16, dsm, 0.5, bounds=B).array[:, :, 0]
    np.testing.assert_array_equal(data[0][valid], mem[valid])
    with pytest.raises(OrthoError, match=r"photo 'W': JPEG compression takes 8-bit photos; this one is uint16"):
        orthophoto(p16, dsm, 0.5, tmp_path / "j.tif", bounds=B, compress="jpeg")
    with pytest.raises(OrthoError, match=r"compression must be one of deflate, jpeg, got 'lzw'"):
        orthophoto(p16, dsm, 0.5, bounds=B, compress="lzw")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["k.png", "k.tif", "w.png", "w.tif"]


def test_jpeg_rgb_is_ycbcr_close_to_the_lossless_one_and_smaller(tmp_path, image, dsm):
    rgb = np.stack([image, image // 2 + 60, 255 - image], axis=2)
    photo = PhotoModel("A", rgb, CAM, EO_A)
    orthophoto(photo, dsm, 0.1, tmp_path / "d.tif", bounds=B)
    orthophoto(photo, dsm, 0.1, tmp_path / "j.tif", bounds=B, compress="jpeg")
    d, vd, _, _, _ = _read(tmp_path / "d.tif")
    j, vj, prof, ovr, _ = _read(tmp_path / "j.tif")
    assert prof["compress"] == "jpeg" and prof["photometric"] == "ycbcr" and ovr == [2]
    np.testing.assert_array_equal(vd, vj)               # the mask is lossless
    err = np.abs(d.astype(np.int16) - j)[:, vd]
    assert err.mean() < 4.0              # measured 2.6 (bands 2.3, 1.4, 4.2 grey levels) at quality 75
    assert (tmp_path / "j.tif").stat().st_size < 0.5 * (tmp_path / "d.tif").stat().st_size   # measured 0.16


def test_cog_layout_on_request(tmp_path, image, dsm):
    photo = PhotoModel("A", image, CAM, EO_A)
    orthophoto(photo, dsm, 0.1, tmp_path / "c.tif", bounds=B, cog=True, preview=False)
    orthophoto(photo, dsm, 0.1, tmp_path / "t.tif", bounds=B, preview=False)
    with rasterio.open(tmp_path / "c.tif") as c:
        assert c.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG" and c.overviews(1) == [2]
        cd = c.read()
    with rasterio.open(tmp_path / "t.tif") as t:
        assert t.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") != "COG"
        np.testing.assert_array_equal(cd, t.read())


def test_grid_heights_are_the_bilinear_surface(dsm):
    g = np.array(dsm.grid)
    g[100:103, 200:210] = np.nan
    s = GridSurface(g, dsm.transform)
    t = s.transform
    e = t.x0 - 0.3 + 0.137 * np.arange(1200)              # crosses the west edge and the hole
    n = t.y0 - 20.0 - 0.093 * np.arange(400)
    got = grid_heights(s, e, n)
    ee, nn = np.meshgrid(e, n)
    want = s.height(ee, nn)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[np.isfinite(got)], want[np.isfinite(want)], rtol=0, atol=1e-9)
    assert np.isnan(got).any() and np.isfinite(got).mean() > 0.9


def test_fill_holes_keeps_heights_fills_near_holes_only():
    t = GeoTransform(1000.0, 2000.0, 0.5)
    rr, cc = np.mgrid[0:200, 0:300]
    plane = 50.0 + 0.1 * cc - 0.05 * rr
    g = plane.copy()
    g[50, 60] = g[120:123, 200:203] = np.nan              # small holes
    g[:, 250:] = np.nan                                   # 25 m of no data at the east edge
    s, n = fill_holes(GridSurface(g, t), 5.0)
    f = s.grid
    known = np.isfinite(g)
    np.testing.assert_array_equal(f[known], g[known])                      # known heights untouched
    assert np.isfinite(f[50, 60]) and np.isfinite(f[120:123, 200:203]).all()
    # inverse distance is not linear: off a tilted plane by less than the plane's change over one cell
    # (0.112 m; measured 0.037 m for one empty cell, 0.086 m inside a 3 x 3 hole)
    assert abs(f[50, 60] - plane[50, 60]) < 0.05
    assert np.abs(f[120:123, 200:203] - plane[120:123, 200:203]).max() < np.hypot(0.1, 0.05)
    assert np.isfinite(f[:, 250:260]).all() and np.isnan(f[:, 260:]).all()  # 5 m reach: 10 cells, no more
    assert n == 1 + 9 + int(np.isfinite(f[:, 250:]).sum())
    same, zero = fill_holes(s, 5.0)
    assert zero == 0 or same is not s
    assert fill_holes(GridSurface(g, t), 0.0)[1] == 0


def test_dsm_holes_do_not_speckle_the_orthophoto(scene, image):
    """A 0.5 m DSM from 4 points/m^2 keeps empty cells (after rasterize's own small-hole fill: issue 26's
    case); filled, the orthophoto keeps >= 99 % of its footprint."""
    pts = scene.lidar_points(MODEL_BOUNDS, 4.0, seed=3)
    grid, t = rasterize(PointCloud(pts["xyz"]), 0.5, "dsm", bounds=MODEL_BOUNDS)
    holes = float(np.isnan(grid).mean())
    assert holes > 0.02                                 # measured 4.5 % of the cells
    photo = PhotoModel("A", image, CAM, EO_A)
    exact = GridSurface(*scene.grid(MODEL_BOUNDS, 0.5, "dsm"))
    footprint = orthophoto(photo, exact, 0.25, bounds=B).n_valid          # cells the photo covers
    filled = orthophoto(photo, GridSurface(grid, t), 0.25, bounds=B)
    raw = orthophoto(photo, GridSurface(grid, t), 0.25, bounds=B, fill_m=0)
    assert filled.n_filled > 0 and raw.n_filled == 0
    assert filled.n_valid / footprint >= 0.99            # measured 100.0 %
    assert raw.n_valid / footprint < 0.95                # measured 90.3 %: the speckle of the holes
    true_filled = orthophoto(photo, GridSurface(grid, t), 0.25, bounds=B, true_ortho=True)
    true_exact = orthophoto(photo, exact, 0.25, bounds=B, true_ortho=True)
    assert true_filled.n_valid / true_exact.n_valid >= 0.99   # measured 99.999 % (90.4 % unfilled)


def test_photo_image_takes_a_file_or_a_folder_with_upper_case_suffixes(tmp_path, image):
    cv2.imwrite(str(tmp_path / "A.JPG"), image, [cv2.IMWRITE_JPEG_QUALITY, 100])
    a = photo_image("A", tmp_path, CAM)
    b = photo_image("A", tmp_path / "A.JPG", CAM)
    assert a.shape == (CAM.rows_px, CAM.columns_px) and np.array_equal(a, b)
    assert np.abs(a.astype(int) - image).mean() < 2
    with pytest.raises(SurveyError, match=r"no image of photo 'B'"):
        photo_image("B", tmp_path, CAM)


def test_ortho_command_reads_the_image_column_of_an_init_survey(tmp_path, scene, image):
    """Photos outside the survey folder, named by photos.csv's image column, with an upper-case suffix."""
    root = tmp_path / "survey"
    (tmp_path / "photos").mkdir()
    root.mkdir()
    cv2.imwrite(str(tmp_path / "photos" / "IMG_A.JPG"), image, [cv2.IMWRITE_JPEG_QUALITY, 100])
    (root / "camera.toml").write_text(CAM.to_toml())
    (root / "photos.csv").write_text("photo,camera,image\nA,small,../photos/IMG_A.JPG\n")
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\n")
    (root / "survey.toml").write_text(f'[survey]\nname = "init"\ncrs = "{CRS}"\n\n[files]\ncamera = "camera.toml"\n'
                                      f'photos = "photos.csv"\nimage_points = "image_points.csv"\n'
                                      f'lidar = ["lidar/*.laz"]\n\n[lidar]\ncrs = "{CRS}"\n')
    (root / "lidar").mkdir()
    pts = scene.lidar_points((E0 - 50, N0 - 40, E0 + 50, N0 + 40), 1.0, seed=1)
    write_points(root / "lidar" / "t.laz", PointCloud(pts["xyz"], crs=resolve_crs(CRS)))
    eop = tmp_path / "eop.csv"
    eop.write_text("photo,X0,Y0,Z0,omega,phi,kappa\nA," + ",".join(
        [*(f"{v:.6f}" for v in EO_A[:3]), *(f"{v:.8f}" for v in np.degrees(EO_A[3:]))]) + "\n")
    grid, t = scene.grid(MODEL_BOUNDS, 0.5, "dsm")
    grid[::7, ::5] = np.nan                               # holes: filled by default
    from lidarcat.lidar.geotiff import write_geotiff

    write_geotiff(tmp_path / "dsm.tif", grid, t, CRS)
    out = tmp_path / "o"
    r = CliRunner().invoke(cli, ["ortho", str(root), "--photo", "A", "--dsm", str(tmp_path / "dsm.tif"), "--eop",
                                 str(eop), "--gsd", "0.5", "--bounds", *map(str, B), "--compress", "jpeg",
                                 "--threads", "2", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    o = json.loads(r.output)["orthophotos"][0]
    assert o["surface_filled"] > 0 and o["n_valid"] > 0.95 * o["rows"] * o["cols"]
    data, valid, prof, _, _ = _read(out / "ortho_A.tif")
    assert prof["compress"] == "jpeg" and prof["dtype"] == "uint8" and int(valid.sum()) == o["n_valid"]
    ref, _ = scene.grid(B, 0.5, "texture")
    assert np.median(np.abs(data[0][valid] - ref[valid])) < 6.0
