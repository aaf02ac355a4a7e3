"""Issue 23 acceptance: ``lidar dsm`` -> ``ortho`` -> ``monoplot`` on the compressed DSM it writes, and DEMs
written by another program (rasterio/GDAL directly: DEFLATE, LZW, tiled) read with their values and transform."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rasterio
from click.testing import CliRunner
from rasterio.transform import Affine

from lidarcat.cli.main import cli
from lidarcat.lidar import rasterize, read_points
from lidarcat.lidar.geotiff import GeoTransform, read_geotiff
from lidarcat.mapping.monoplot import GridSurface, monoplot
from lidarcat.mapping.ortho import PhotoModel, orthophoto

from test_cli_mapping import CRS, _px, survey  # noqa: F401,I001  (the fixture survey: camera, photos A and B, LiDAR, DSM)
from ortho_scene import CAM, E0, EO_A, N0, rendered  # noqa: I001

BOUNDS = [E0 - 60, N0 - 40, E0 + 60, N0 + 40]


def _run(*args):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r.output


def _monoplot_csv(root, surface, px, out):
    """Run ``lidarcat monoplot`` on photo A with *surface*; E, N, h of the rows."""
    (out.parent / "f.csv").write_text("feature,class,col_px,row_px\n"
                                      + "".join(f"P{i},x,{c},{r}\n" for i, (c, r) in enumerate(px)))
    _run("monoplot", root, "--photo", "A", "--features", out.parent / "f.csv", "--surface", surface, "-o", out)
    rows = [ln.split(",") for ln in out.read_text().splitlines()[1:]]
    return np.array([[float(v) if v else np.nan for v in r[5:8]] for r in rows]), [r[-1] for r in rows]


def test_lidar_dsm_then_ortho_then_monoplot_on_the_compressed_dsm(survey, tmp_path):  # noqa: F811
    root, scene, verts = survey
    dsm = tmp_path / "dsm.tif"
    _run("lidar", "dsm", root / "lidar" / "tile.laz", "-o", dsm, "--cell-m", "0.5", "--crs", CRS)
    with rasterio.open(dsm) as d:     # what `lidar dsm` writes: compressed, tiled (ortho/monoplot refused it)
        assert d.profile["compress"] == "deflate" and d.profile["tiled"] and d.crs.to_epsg() == 31982
    grid, t, crs = read_geotiff(dsm)
    mem, tm = rasterize(read_points(root / "lidar" / "tile.laz", crs=CRS), 0.5, "dsm")
    np.testing.assert_array_equal(grid, mem)
    assert t == tm and crs.to_epsg() == 31982

    # ortho on it: the true orthophoto of the file is the one of the in-memory DSM, and matches the texture
    out = tmp_path / "o"
    summary = json.loads(_run("ortho", root, "--photo", "A", "--dsm", dsm, "--gsd", "0.5", "--bounds", *BOUNDS,
                              "-o", out, "--json"))
    assert summary["orthophotos"][0]["true_ortho"] and summary["orthophotos"][0]["n_valid"] > 0
    with rasterio.open(out / "ortho_A.tif") as src:
        assert src.profile["compress"] == "deflate" and src.profile["tiled"] and src.crs.to_epsg() == 31982
        ortho = src.read(1, masked=True).astype(np.float32).filled(np.nan)   # uint8 + internal mask
    photo = PhotoModel("A", rendered("A"), CAM, EO_A)
    same = orthophoto(photo, GridSurface(mem, tm), 0.5, bounds=BOUNDS, true_ortho=True).array[:, :, 0]
    np.testing.assert_array_equal(np.isnan(ortho), np.isnan(same))
    np.testing.assert_allclose(np.nan_to_num(ortho), np.nan_to_num(same), atol=0.5)   # 8-bit photo, re-read
    ref, _ = scene.grid(BOUNDS, 0.5, "texture")
    assert np.nanmedian(np.abs(ortho - ref)) < 1.0          # measured 0.57 grey levels

    # monoplot on it: the CLI's points are the library's on the in-memory DSM, and near the scene's surface
    rng = np.random.default_rng(5)
    en = np.column_stack([rng.uniform(BOUNDS[0] + 5, BOUNDS[2] - 5, 40), rng.uniform(BOUNDS[1] + 5, BOUNDS[3] - 5, 40)])
    truth = GridSurface.from_geotiff(root / "dsm.tif")           # the scene's exact surface, 0.25 m
    xyz = np.column_stack([en, truth.height(en[:, 0], en[:, 1])])
    px = _px(xyz, EO_A)
    got, status = _monoplot_csv(root, dsm, px, tmp_path / "m.csv")
    lib = monoplot(px, CAM, EO_A, GridSurface(mem, tm))
    np.testing.assert_allclose(got, lib.enh, atol=1e-3)
    assert status == list(lib.status)
    ok = np.array(status) == "ok"
    err = np.hypot(*(got[ok, :2] - xyz[ok, :2]).T)
    assert ok.sum() >= 35 and np.median(err) < 0.05     # measured 38 and 5 mm (edges of roofs: up to 1.3 m)


@pytest.mark.parametrize("name, opts", [
    ("deflate.tif", dict(compress="DEFLATE", predictor=3, nodata=-9999.0)),
    ("lzw_tiled.tif", dict(compress="LZW", tiled=True, blockxsize=256, blockysize=256, nodata=-9999.0)),
])
def test_dem_of_another_program_is_read_by_ortho_and_monoplot(survey, tmp_path, name, opts):  # noqa: F811
    """A DEM written by GDAL directly (its own nodata value, not NaN) gives ortho and monoplot the values
    and the transform of the grid it holds."""
    root, scene, _ = survey
    grid, t = scene.grid([E0 - 80, N0 - 60, E0 + 80, N0 + 60], 0.5, "dsm")
    grid = grid.astype(np.float32)
    grid[:6, :9] = np.nan                     # a hole, written as the program's nodata value
    a = np.where(np.isnan(grid), np.float32(-9999.0), grid)
    with rasterio.open(tmp_path / name, "w", driver="GTiff", width=a.shape[1], height=a.shape[0], count=1,
                       dtype="float32", crs=CRS, transform=Affine(0.5, 0.0, t.x0, 0.0, -0.5, t.y0),
                       **opts) as dst:
        dst.write(a, 1)
    surface = GridSurface.from_geotiff(tmp_path / name)
    np.testing.assert_array_equal(surface.grid, grid.astype(np.float64))
    assert surface.transform == GeoTransform(t.x0, t.y0, 0.5)
    out = tmp_path / "o"
    _run("ortho", root, "--photo", "A", "--dsm", tmp_path / name, "--gsd", "0.5", "--bounds", *BOUNDS, "-o", out)
    photo = PhotoModel("A", rendered("A"), CAM, EO_A)
    same = orthophoto(photo, GridSurface(grid, t), 0.5, bounds=BOUNDS, true_ortho=True).array[:, :, 0]
    got, ot, _ = read_geotiff(out / "ortho_A.tif")
    assert ot == GeoTransform(BOUNDS[0], BOUNDS[3], 0.5)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(same))
    np.testing.assert_allclose(np.nan_to_num(got), np.nan_to_num(same), atol=0.5)
    en = np.array([[E0 - 20.0, N0 + 5.0], [E0 + 10.0, N0 - 12.0], [E0 + 33.0, N0 + 21.0]])
    xyz = np.column_stack([en, surface.height(en[:, 0], en[:, 1])])
    got_m, status = _monoplot_csv(root, tmp_path / name, _px(xyz, EO_A), tmp_path / "m.csv")
    assert status == ["ok"] * 3
    np.testing.assert_allclose(got_m, xyz, atol=0.02)


def test_surface_in_another_crs_is_refused_when_a_crs_is_expected(tmp_path):
    from lidarcat.lidar.geotiff import write_geotiff
    from lidarcat.mapping.monoplot import MonoplotError

    g = np.ones((4, 4), np.float32)
    write_geotiff(tmp_path / "rd.tif", g, GeoTransform(85000.0, 447500.0, 1.0), "EPSG:7415")
    assert GridSurface.from_geotiff(tmp_path / "rd.tif", crs="EPSG:28992").transform.x0 == 85000.0  # RD New + NAP
    with pytest.raises(MonoplotError, match=r"rd\.tif: the surface model is in EPSG:7415 .*, not in EPSG:31982 "
                                            r".*; reproject it"):
        GridSurface.from_geotiff(tmp_path / "rd.tif", crs=CRS)
    write_geotiff(tmp_path / "rgb.tif", np.zeros((4, 4, 3), np.uint8), GeoTransform(0.0, 4.0, 1.0), CRS)
    with pytest.raises(MonoplotError, match=r"rgb\.tif: 3 bands; a surface model has one band of heights"):
        GridSurface.from_geotiff(tmp_path / "rgb.tif")
