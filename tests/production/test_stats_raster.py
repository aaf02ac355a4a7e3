"""Point statistics rasters (min, max, mean, count, stdev bands), their mosaic and the VRT of tile outputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarcat.lidar.geotiff import write_bands, write_vrt
from lidarcat.lidar.raster import STAT_BANDS, GeoTransform, point_statistics

DATA = Path(__file__).resolve().parent.parent / "data" / "lidar"
TILES = [DATA / "ahn3_cropped_1.laz", DATA / "ahn3_cropped_2.laz"]


def test_point_statistics_of_known_cells():
    rng = np.random.default_rng(0)
    z = rng.normal(10.0, 2.0, 1000)
    pts = np.column_stack([rng.uniform(0, 1, 1000), rng.uniform(0, 1, 1000), z])
    pts = np.vstack([pts, [[2.5, 0.5, 4.0]]])
    bands, t = point_statistics(pts, 1.0, (0.0, 0.0, 3.0, 1.0))
    assert bands.shape == (5, 1, 3) and t == GeoTransform(0.0, 1.0, 1.0)
    first = bands[:, 0, 0]
    np.testing.assert_allclose(first, [z.min(), z.max(), z.mean(), 1000, z.std()], rtol=1e-12)
    assert np.isnan(bands[[0, 1, 2, 4], 0, 1]).all() and bands[3, 0, 1] == 0   # the empty cell
    np.testing.assert_array_equal(bands[:, 0, 2], [4.0, 4.0, 4.0, 1.0, 0.0])
    # statistics of another attribute
    b2, _ = point_statistics(pts, 1.0, (0.0, 0.0, 3.0, 1.0), values=np.ones(len(pts)))
    assert b2[2, 0, 0] == 1.0 and b2[4, 0, 0] == 0.0


def test_stdev_has_no_cancellation_far_from_zero():
    pts = np.array([[0.5, 0.5, 1e6 + 0.001], [0.5, 0.5, 1e6 - 0.001]])
    bands, _ = point_statistics(pts, 1.0, (0.0, 0.0, 1.0, 1.0))
    assert bands[4, 0, 0] == pytest.approx(0.001, rel=1e-6)


def test_stats_of_two_tiles_mosaic_and_vrt_agree_and_count_every_point(tmp_path):
    import rasterio

    from lidarcat.lidar import read_points
    from lidarcat.stages.lidar import statistics_raster

    n = sum(len(read_points(f, crs="EPSG:7415")) for f in TILES)
    one = statistics_raster(TILES, tmp_path / "stats.tif", crs="EPSG:7415", cell_m=4.0, resume=False)
    folder = statistics_raster(TILES, tmp_path / "stats", crs="EPSG:7415", cell_m=4.0, resume=False)
    assert [Path(p).name for p in folder] == ["ahn3_cropped_1.tif", "ahn3_cropped_2.tif", "mosaic.vrt"]
    with rasterio.open(one[0]) as a, rasterio.open(folder[-1]) as b:
        assert a.descriptions == STAT_BANDS == b.descriptions
        assert a.crs.to_epsg() == 7415 and b.crs.to_epsg() == 7415
        assert a.transform == b.transform and a.shape == b.shape
        ga, gb = a.read(), b.read()
    np.testing.assert_array_equal(np.nan_to_num(ga, nan=-1), np.nan_to_num(gb, nan=-1))
    assert ga[3].sum() == n   # each point counted once, seams included (848,942 points)
    for f in folder[:2]:
        with rasterio.open(f) as ds:
            assert ds.crs.to_epsg() == 7415 and ds.count == 5


def test_vrt_refuses_sources_on_different_lattices(tmp_path):
    g = np.zeros((1, 2, 2))
    a = write_bands(tmp_path / "a.tif", g, GeoTransform(0.0, 2.0, 1.0), "EPSG:31983", ["z"])
    b = write_bands(tmp_path / "b.tif", g, GeoTransform(0.0, 2.0, 0.5), "EPSG:31983", ["z"])
    with pytest.raises(ValueError, match="not on the lattice of"):
        write_vrt(tmp_path / "m.vrt", [a, b])
    with pytest.raises(ValueError, match="a VRT needs at least one source GeoTIFF"):
        write_vrt(tmp_path / "m.vrt", [])
    assert not (tmp_path / "m.vrt").exists()


def test_cli_stats_and_dtm_vrt(tmp_path):
    import rasterio
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    r = CliRunner().invoke(cli, ["lidar", "stats", str(TILES[1]), "-o", str(tmp_path / "s.tif"), "--crs", "EPSG:7415",
                                 "--cell-m", "5", "--classes", "2,6"])
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "s.tif") as ds:
        assert ds.count == 5 and ds.crs.to_epsg() == 7415
    r = CliRunner().invoke(cli, ["lidar", "stats", str(TILES[1]), "-o", str(tmp_path / "x.tif"), "--classes", "a"])
    assert r.exit_code == 2 and "'a' is not a comma-separated list of class codes" in r.output
    r = CliRunner().invoke(cli, ["lidar", "dsm", *map(str, TILES), "-o", str(tmp_path / "dsm"), "--crs", "EPSG:7415",
                                 "--cell-m", "5", "--vrt"])
    assert r.exit_code == 0, r.output
    with rasterio.open(tmp_path / "dsm" / "mosaic.vrt") as ds:
        assert ds.crs.to_epsg() == 7415 and ds.count == 1 and np.isfinite(ds.read(1)).mean() > 0.9
