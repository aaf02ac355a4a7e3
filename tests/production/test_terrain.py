"""DTM/DSM/nDSM, hillshade, hypsometric image, text grid, and the raster --bounds cell count."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.lidar import PointCloud, rasterize
from lidarcat.lidar.raster import GeoTransform
from lidarcat.production.terrain import (dtm_grid, hillshade, hypsometric_image, ndsm, tin_grid, write_product,
                                    write_text_grid)


def test_raster_bounds_give_exactly_the_cells_asked():
    """Issue 16: --bounds 0 0 10 10 at 1 m gave 11 x 11 cells; it is 10 x 10, edge points kept."""
    pc = PointCloud(np.array([[0.5, 0.5, 1.0], [10.0, 0.0, 2.0], [9.5, 9.5, 3.0]]))
    grid, t = rasterize(pc, 1.0, "dsm", bounds=(0, 0, 10, 10), fill=None)
    assert grid.shape == (10, 10) and t == (0.0, 10.0, 1.0)
    assert grid[9, 9] == 2.0 and grid[0, 9] == 3.0 and grid[9, 0] == 1.0
    grid, _ = rasterize(pc, 1.0, "dsm", bounds=(0, 0, 10.2, 9.8), fill=None)
    assert grid.shape == (10, 11)


def test_tin_dtm_reproduces_a_plane_and_reports_gaps():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (4000, 2))
    keep = ~((abs(xy[:, 0] - 50) < 30) & (abs(xy[:, 1] - 50) < 30))   # a 60 m hole
    z = 0.1 * xy[:, 0] - 0.05 * xy[:, 1] + 20
    cls = np.where(keep, 2, 6).astype(np.uint8)
    pc = PointCloud(np.column_stack([xy, z]), {"classification": cls})
    res = dtm_grid(pc, 2.0, (0, 0, 100, 100), max_edge_m=20.0)
    r, c = np.indices(res.grid.shape)
    e, n = res.transform.xy(r, c)
    fin = np.isfinite(res.grid)
    np.testing.assert_allclose(res.grid[fin], (0.1 * e - 0.05 * n + 20)[fin], atol=1e-4)
    centre = res.grid[(abs(e - 50) < 20) & (abs(n - 50) < 20)]
    assert np.isnan(centre).all()                         # the hole is a gap, not invented
    assert res.gap_cells == int((~fin).sum()) and res.gap_cells >= centre.size
    full = dtm_grid(pc, 2.0, (0, 0, 100, 100), max_edge_m=None)
    assert np.isfinite(full.grid[(abs(e - 50) < 20) & (abs(n - 50) < 20)]).all()
    with pytest.raises(ValueError, match="no ground points"):
        dtm_grid(PointCloud(np.column_stack([xy, z]), {"classification": np.ones(len(xy), np.uint8)}), 2.0)


def test_hillshade_of_a_known_slope():
    # plane rising 1 m per metre to the east: slope 45 deg, facing west (aspect 270)
    g = np.tile(np.arange(5.0), (5, 1))
    hs = hillshade(g, 1.0, azimuth_deg=270.0, altitude_deg=45.0)
    assert hs[2, 2] == pytest.approx(1.0, abs=1e-6)       # sun perpendicular to the slope
    hs = hillshade(g, 1.0, azimuth_deg=90.0, altitude_deg=45.0)
    assert hs[2, 2] == pytest.approx(0.0, abs=1e-6)       # grazing from behind
    hs = hillshade(g, 1.0, azimuth_deg=0.0, altitude_deg=45.0)
    assert hs[2, 2] == pytest.approx(math.cos(math.radians(45)) ** 2, abs=1e-6)


def test_hypsometric_colours_and_intensity():
    h = np.array([[0.0, 10.0], [10.0, np.nan]])
    i = np.array([[100.0, 100.0], [0.0, 50.0]])
    img = hypsometric_image(h, i, 0.0, 10.0, shade_floor=0.5)
    assert img.shape == (2, 2, 3) and img.dtype == np.uint8
    assert (img[1, 1] == 0).all()                         # no height: black
    np.testing.assert_allclose(img[1, 0], np.round(img[0, 1] * 0.5), atol=1)  # dark intensity halves


def test_ndsm_and_outputs(tmp_path):
    dsm = np.array([[5.0, 7.0]], dtype=np.float32)
    dtm = np.array([[1.0, np.nan]], dtype=np.float32)
    out = ndsm(dsm, dtm)
    assert out[0, 0] == 4.0 and np.isnan(out[0, 1])
    t = GeoTransform(85000.0, 447500.0, 0.5)
    p = write_product(tmp_path / "n.tif", out, t, "EPSG:7415")
    rasterio = pytest.importorskip("rasterio")
    with rasterio.open(p) as d:
        assert d.crs.to_epsg() in (7415, None) and "7415" in d.crs.to_wkt() or "RD New" in d.crs.to_wkt()
        assert d.transform.c == 85000.0 and d.transform.f == 447500.0 and d.transform.a == 0.5
        assert d.profile["compress"] == "deflate" and d.profile["tiled"]
        np.testing.assert_array_equal(d.read(1), out)
    txt = write_text_grid(tmp_path / "mdt.txt", out, t)
    assert txt.read_text().splitlines() == ["E N H", "85000.250 447499.750 4.000"]


def test_rgb_product_is_an_rgb_geotiff_whatever_is_installed(tmp_path):
    """One writer (rasterio, a core dependency): an RGB image is written, uint8, 3 bands, CRS kept."""
    import rasterio

    rgb = np.arange(18, dtype=np.uint8).reshape(2, 3, 3)
    p = write_product(tmp_path / "h.tif", rgb, GeoTransform(0.0, 2.0, 1.0), "EPSG:7415")
    with rasterio.open(p) as d:
        assert (d.count, d.dtypes, d.crs.to_epsg(), d.nodata) == (3, ("uint8",) * 3, 7415, None)
        assert [c.name for c in d.colorinterp] == ["red", "green", "blue"]
        np.testing.assert_array_equal(np.moveaxis(d.read(), 0, 2), rgb)
    assert [q.name for q in tmp_path.iterdir()] == ["h.tif"]


def test_tin_grid_needs_points():
    with pytest.raises(ValueError, match="empty point set"):
        tin_grid(np.zeros((0, 3)), 1.0)


def test_tin_grid_rasterised_equals_the_qhull_tin_at_cell_centres():
    """The OpenCV triangles rasterised give the heights of the Qhull TIN located cell by cell."""
    from lidarcat.lidar.raster import grid_for as _grid_for
    from lidarcat.production.terrain import tin_heights

    rng = np.random.default_rng(11)
    xy = rng.uniform(0, 120, (6000, 2))
    xyz = np.column_stack([xy + 500_000.0, 30 + 0.2 * xy[:, 0] + 3 * np.sin(xy[:, 1] / 9)])
    bounds = (500_000.0, 500_000.0, 500_120.0, 500_120.0)
    grid = tin_grid(xyz, 0.5, bounds, max_edge_m=10.0)
    t, nr, nc = _grid_for(bounds, 0.5)
    rr, cc = np.mgrid[0:nr, 0:nc]
    ref = tin_heights(xyz, np.column_stack(t.xy(rr.ravel(), cc.ravel())), 10.0).reshape(nr, nc)
    both = np.isfinite(ref) & np.isfinite(grid.grid)
    assert both.sum() > 0.97 * ref.size
    assert np.abs(grid.grid[both] - ref[both]).max() < 1e-4  # float32 grid
    # cells valued in one and not the other: only slivers along the hull (within 3 m of the edge)
    odd = np.argwhere(np.isfinite(ref) != np.isfinite(grid.grid))
    assert len(odd) < 0.01 * ref.size
    if len(odd):
        dist_cells = np.minimum.reduce([odd[:, 0], odd[:, 1], nr - 1 - odd[:, 0], nc - 1 - odd[:, 1]])
        assert dist_cells.max() * 0.5 <= 3.0
    assert grid.gap_cells == int(np.isnan(grid.grid).sum())


def test_text_grid_carries_its_crs_in_a_prj(tmp_path):
    """Issue 25: the E N H text grid keeps the CRS as given (a ``.prj`` beside it, as for XYZ grids)."""
    from pyproj import CRS

    from lidarcat.production.terrain import GeoTransform, write_text_grid

    p = write_text_grid(tmp_path / "dtm.txt", np.array([[1.0, np.nan]]), GeoTransform(100.0, 200.0, 2.0),
                        crs="EPSG:28992")
    assert p.read_text().splitlines() == ["E N H", "101.000 199.000 1.000"]
    prj = CRS.from_wkt((tmp_path / "dtm.prj").read_text())
    assert prj.equals(CRS.from_epsg(28992), ignore_axis_order=True)
    assert prj.to_epsg(min_confidence=70) == 28992
    write_text_grid(tmp_path / "none.txt", np.array([[1.0]]), GeoTransform(100.0, 200.0, 2.0))
    assert not (tmp_path / "none.prj").exists()
