"""Issue 24: grids sized from the points actually read, not from header claims or one displaced point.

``lidar dtm``/``dsm`` trusted the header's bounds (min_x -1e308 or inf: an internal error; a header
box 1 m wide away from the points, like laspy's simple1_3.las: an empty 1 x 1 grid, exit 0), and one
far-away point made ``lidar raster`` ask for a grid of billions of cells.  Now: the grid covers the
bulk of the points, far points are left out with a warning that counts them and names the farthest,
and an absurd grid is a one-line error with the escapes (--bounds, --max-cells, a coarser cell).
"""

from __future__ import annotations

import struct
from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import ProductError
from lidarcat.lidar.geotiff import read_geotiff
from lidarcat.lidar.raster import MAX_CELLS, bulk_box, grid_for, robust_extent

from conftest import assert_one_line_error

CRS = "EPSG:28992"


def _tile(path: Path, *, far: tuple[float, float] | None = None, header: tuple[float, ...] | None = None,
          n: int = 4000) -> tuple[Path, np.ndarray]:
    """A 50 m x 50 m classified tile (all ground); optionally one point moved to *far* (offset, metres)
    and the header's (max_x, min_x, max_y, min_y) overwritten."""
    rng = np.random.default_rng(24)
    xyz = np.column_stack([85000 + rng.random(n) * 50, 447000 + rng.random(n) * 50, 400 + rng.random(n)])
    if far is not None:
        xyz[17, :2] = [85000 + far[0], 447000 + far[1]]
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = [0.01] * 3, [85000, 447000, 0]
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz.T
    las.intensity = rng.integers(1, 255, n)
    las.classification = np.full(n, 2, np.uint8)
    las.write(path)
    if header is not None:
        data = bytearray(path.read_bytes())
        struct.pack_into("<4d", data, 179, *header)   # max_x, min_x, max_y, min_y
        path.write_bytes(bytes(data))
    return path, xyz


def _run(*args: str):
    return CliRunner().invoke(cli, list(args))


# --------------------------------------------------------------------------- header bounds
@pytest.mark.parametrize("kind", ["dtm", "dsm"])
@pytest.mark.parametrize("header,warned", [
    ((1.0, 0.0, 1.0, 0.0), True),                          # simple1_3.las: a 1 m box away from the points
    ((85050.0, -1e308, 447050.0, 447000.0), False),        # holds the points, but absurd
    ((85050.0, float("-inf"), 447050.0, 447000.0), True),  # not a number of metres at all
    ((float("nan"), 85000.0, 447050.0, 447000.0), True),
], ids=["1m-box", "min_x=-1e308", "min_x=-inf", "max_x=nan"])
def test_terrain_grid_follows_the_points_not_the_header(tmp_path, kind, header, warned):
    p, xyz = _tile(tmp_path / "a.las", header=header)
    out = tmp_path / f"{kind}.tif"
    r = _run("lidar", kind, str(p), "-o", str(out), "--crs", CRS)
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output and "internal error" not in r.output
    assert ("the header's bounds" in r.output and "do not hold the points" in r.output) == warned, r.output
    grid, t, _ = read_geotiff(out)
    # the grid is the points' 50 m x 50 m (snapped to the 1 m cell), mostly valued
    assert t.x0 == 85000.0 and t.y0 == 447050.0
    assert grid.shape in ((50, 50), (51, 51), (50, 51), (51, 50))
    assert np.isfinite(grid).mean() > 0.9
    assert np.nanmin(grid) >= 400 - 1e-3 and np.nanmax(grid) <= 401 + 1e-3


# --------------------------------------------------------------------------- one far point
@pytest.mark.parametrize("cmd", [
    ["lidar", "raster", "--cell", "0.5"],
    ["lidar", "dsm"],
    ["lidar", "dtm"],
], ids=["raster", "dsm", "dtm"])
def test_one_displaced_point_is_left_out_with_a_warning(tmp_path, cmd):
    p, _ = _tile(tmp_path / "a.las", far=(100_000.0, 100_000.0))
    out = tmp_path / "out.tif"
    r = _run(*cmd, str(p), "-o", str(out), "--crs", CRS)
    assert r.exit_code == 0, r.output
    assert "1 point" in r.output and "lies far outside the bulk of the data" in r.output, r.output
    assert "the farthest at E 185000 N 547000" in r.output
    assert "give --bounds to grid them" in r.output
    grid, t, _ = read_geotiff(out)
    assert max(grid.shape) * t.cell_m <= 52        # the 50 m tile, not 100 km
    assert out.stat().st_size < 200_000            # not the 117-204 MB of the issue


def test_points_far_out_in_numbers_are_counted(tmp_path):
    rng = np.random.default_rng(1)
    x = np.r_[rng.random(1000) * 50, 1e6, -1e6, np.nan]
    y = np.r_[rng.random(1000) * 50, 0.0, 5.0, 1.0]
    ext = robust_extent(x, y, 1.0)
    assert ext.n_out == 3
    assert ext.farthest in ((1e6, 0.0), (-1e6, 5.0))
    assert 0 <= ext.bounds[0] and ext.bounds[2] <= 50
    assert "3 points lie far outside the bulk of the data" in ext.describe_outliers()


def test_bulk_box_keeps_every_point_of_ordinary_data():
    """A tile, a strip, two flight lines side by side, a sparse corner: no point is an outlier."""
    rng = np.random.default_rng(2)
    tile = rng.random((10_000, 2)) * 1000
    strip = np.column_stack([rng.random(10_000) * 5000, rng.random(10_000) * 20])
    corner = np.r_[rng.random((9_950, 2)) * 100, 100 + rng.random((50, 2)) * 100]
    for xy in (tile, strip, corner):
        assert robust_extent(xy[:, 0], xy[:, 1], 0.5).n_out == 0
    b = bulk_box(tile[:, 0], tile[:, 1], 1.0)
    assert b[0] < 0 and b[2] > 1000


# --------------------------------------------------------------------------- absurd grids: one Error line
def test_raster_bounds_asking_for_an_absurd_grid_is_refused_before_reading(tmp_path):
    p, _ = _tile(tmp_path / "a.las", far=(100_000.0, 100_000.0))
    out = tmp_path / "r.tif"
    r = _run("lidar", "raster", str(p), "-o", str(out), "--crs", CRS, "--bounds", "85000", "447000", "185001",
             "547001", "--cell", "0.005")
    assert_one_line_error(r, "the data ask for a grid of 20,000,200 x 20,000,200 cells over E 85000..185001 "
                             "N 447000..547001 at 0.005 m, more than the limit of 100,000,000",
                          "--bounds XMIN YMIN XMAX YMAX", "--max-cells")
    assert sorted(f.name for f in tmp_path.iterdir()) == ["a.las"]


def test_raster_bounds_take_the_far_point_in(tmp_path):
    p, _ = _tile(tmp_path / "a.las", far=(1000.0, 0.0))
    out = tmp_path / "r.tif"
    r = _run("lidar", "raster", str(p), "-o", str(out), "--crs", CRS, "--bounds", "85000", "447000", "86001",
             "447050", "--cell", "1", "--what", "dsm", "--no-preview")
    assert r.exit_code == 0, r.output
    assert "far outside" not in r.output
    grid, t, _ = read_geotiff(out)
    assert grid.shape[1] == 1001 and np.isfinite(grid[:, -2:]).any()


@pytest.mark.parametrize("kind", ["dtm", "dsm"])
def test_terrain_max_cells_is_an_error_naming_the_tile(tmp_path, kind):
    p, _ = _tile(tmp_path / "a.las")
    out = tmp_path / f"{kind}.tif"
    r = _run("lidar", kind, str(p), "-o", str(out), "--crs", CRS, "--max-cells", "1000")
    assert_one_line_error(r, f"{p}: the data ask for a grid of 51 x 51 cells over E 85000..85050 "
                             "N 447000..447050 at 1 m, more than the limit of 1,000",
                          "--bounds XMIN YMIN XMAX YMAX", "--max-cells")
    assert not out.exists()
    r = _run("lidar", kind, str(p), "-o", str(out), "--crs", CRS, "--max-cells", "10000")
    assert r.exit_code == 0, r.output


@pytest.mark.parametrize("kind", ["dtm", "dsm"])
def test_terrain_bounds_clip_the_grid(tmp_path, kind):
    p, _ = _tile(tmp_path / "a.las")
    out = tmp_path / f"{kind}.tif"
    r = _run("lidar", kind, str(p), "-o", str(out), "--crs", CRS, "--bounds", "85010", "447010", "85020", "447030")
    assert r.exit_code == 0, r.output
    grid, t, _ = read_geotiff(out)
    assert (t.x0, t.y0) == (85010.0, 447030.0) and grid.shape == (20, 10)
    r = _run("lidar", kind, str(p), "-o", str(tmp_path / "x.tif"), "--crs", CRS,
             "--bounds", "0", "0", "10", "10")
    assert_one_line_error(r, "no tile lies in the bounds E 0.000..10.000 N 0.000..10.000")
    r = _run("lidar", kind, str(p), "-o", str(tmp_path / "x.tif"), "--crs", CRS,
             "--bounds", "10", "0", "0", "10")
    assert_one_line_error(r, "bounds 10 0 0 10 are not an area (give XMIN YMIN XMAX YMAX, finite, min < max)")


def test_grid_for_refuses_non_finite_and_huge_areas():
    with pytest.raises(ProductError, match=r"cannot grid the area E -inf\.\.1 N 0\.\.1: it is not a finite box"):
        grid_for((float("-inf"), 0, 1, 1), 1.0)
    with pytest.raises(ProductError, match="the data ask for a grid of .* cells over E -1e\\+308"):
        grid_for((-1e308, 0, 1, 1), 1.0)
    _, nr, nc = grid_for((0, 0, 10_000, 10_000), 1.0)
    assert nr * nc == MAX_CELLS
