"""Contours: the edge of the triangulation, contours of a DTM GeoTIFF, fixed levels, the small-ring filter."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.lidar.geotiff import GeoTransform, write_geotiff
from lidarcat.production.contours import contours, edge_fraction, raster_contours


def _length(c):
    return float(np.hypot(*np.diff(c.xy, axis=0).T).sum())


@pytest.fixture(scope="module")
def ground():
    """A tilted, waved 300 x 300 m ground with a 40 m lake (a gap rim inside), 0.5 pts/m^2 after the gap."""
    rng = np.random.default_rng(5)
    x, y = rng.uniform(0, 300, 40000), rng.uniform(0, 300, 40000)
    keep = np.hypot(x - 150, y - 150) > 40
    x, y = x[keep], y[keep]
    return np.column_stack([x, y, 50 + 0.05 * x + 3 * np.sin(y / 30) + rng.normal(0, 0.05, len(x))])


def test_contours_stay_off_the_edge_of_the_triangulation(ground):
    raw = contours(ground, 0.5, max_edge_m=10.0, edge_peel=0)
    cs = contours(ground, 0.5, max_edge_m=10.0)                   # default: 3 rings of triangles peeled
    f_raw = edge_fraction(raw, ground, max_edge_m=10.0, tol_m=0.1)
    f = edge_fraction(cs, ground, max_edge_m=10.0, tol_m=0.1)
    assert f_raw > 0.0003 and f <= 0.002 and f < f_raw / 10
    # what is lost is a rim: at least 90 % of the length is kept
    assert sum(map(_length, cs)) > 0.9 * sum(map(_length, raw))


def test_fixed_levels_and_master_flags(ground):
    cs = contours(ground, 1.0, master_every=5, levels=[55.0, 57.5, 1000.0])
    assert sorted({c.level_m for c in cs}) == [55.0, 57.5]         # 1000 m is above the ground
    assert all(c.master == (c.level_m == 55.0) for c in cs)        # 57.5 is off the 1 m grid: intermediate


def test_small_rings_are_filtered_by_length():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 100, (20000, 2))
    bumps = [(30, 30, 1.5), (70, 70, 6.0)]                         # two cones: narrow and wide
    h = np.zeros(len(xy))
    for cx, cy, r in bumps:
        h = np.maximum(h, 2.0 * (1 - np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) / r))
    g = np.column_stack([xy, h])
    rings = [c for c in contours(g, 1.0, edge_peel=0) if c.closed]
    kept = [c for c in contours(g, 1.0, edge_peel=0, min_ring_m=5.0) if c.closed]
    assert sorted(map(_length, kept)) == sorted(L for L in map(_length, rings) if L >= 5.0)
    assert len(kept) < len(rings)


def test_contours_of_a_dtm_raster_lie_at_their_level(tmp_path):
    t = GeoTransform(1000.0, 2000.0, 2.0)
    rows, cols = 40, 50
    x = t.x0 + (np.arange(cols) + 0.5) * t.cell_m
    grid = np.tile(0.1 * (x - 1000.0), (rows, 1))                  # h = 0.1 (E - 1000): levels at E = 1000 + 10 h
    grid[10:20, 20:30] = np.nan                                    # a gap
    cs = raster_contours(grid, t, 1.0, master_every=5)
    assert sorted({c.level_m for c in cs}) == [float(k) for k in range(1, 10)]
    for c in cs:
        np.testing.assert_allclose(c.xy[:, 0], 1000.0 + 10 * c.level_m, atol=1e-9)
        assert c.master == (c.level_m == 5.0)
    assert len([c for c in cs if c.level_m == 5.0]) == 2           # E 1050 crosses the gap: two lines
    # the command: a .tif input is a DTM
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    write_geotiff(tmp_path / "dtm.tif", grid, t, "EPSG:31983")
    r = CliRunner().invoke(cli, ["lidar", "contours", str(tmp_path / "dtm.tif"), "-o", str(tmp_path / "c.geojson"),
                                 "--levels", "2.5,7"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "c.geojson").read_text())
    assert sorted({f["properties"]["level_m"] for f in doc["features"]}) == [2.5, 7.0]
    assert "31983" in json.dumps(doc["crs"])
    r = CliRunner().invoke(cli, ["lidar", "contours", str(tmp_path / "dtm.tif"), "-o", str(tmp_path / "d.geojson"),
                                 "--levels", "2,x"])
    assert r.exit_code == 2 and "'2,x': give numbers separated by commas" in r.output
