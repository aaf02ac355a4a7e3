"""The one raster I/O (lidarcat.lidar.geotiff): one profile for every writer, any GeoTIFF read, CRS as given."""

from __future__ import annotations

import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import Affine

from lidarcat.errors import LidarFormatError
from lidarcat.lidar.geotiff import GeoTiffWriter, GeoTransform, read_geotiff, write_geotiff
from lidarcat.lidar.raster import write_raster
from lidarcat.mapping.ortho import GeoTiffStream
from lidarcat.production.terrain import write_product

T = GeoTransform(84800.0, 447650.0, 0.5)


def _grid(shape=(700, 900)):
    g = np.random.default_rng(0).normal(50.0, 5.0, shape).astype(np.float32)
    g[5:50, 7:90] = np.nan
    return g


def _profile(path):
    """What a user's GIS sees of a GeoTIFF: layout, compression, tiling, type, nodata, CRS, transform."""
    with rasterio.open(path) as d:
        nodata = d.nodata
        return {"structure": d.tags(ns="IMAGE_STRUCTURE"), "tiled": d.profile["tiled"],
                "block": (d.profile["blockxsize"], d.profile["blockysize"]), "dtypes": d.dtypes,
                "nodata": "nan" if nodata is not None and np.isnan(nodata) else nodata,
                "epsg": d.crs.to_epsg(), "transform": tuple(d.transform)[:6], "count": d.count,
                "colorinterp": [c.name for c in d.colorinterp], "overviews": d.overviews(1)}


def _stream(path, array, transform, crs, block_rows):
    a = np.asarray(array)
    with GeoTiffWriter(path, a.shape[:2], 1 if a.ndim == 2 else a.shape[2], transform, crs) as w:
        for r in range(0, a.shape[0], block_rows):
            w.write_rows(a[r:r + block_rows])
    return path


def test_every_writer_gives_the_same_file(tmp_path):
    """write_geotiff, write_raster (lidar raster, mapping stage), write_product (lidar dtm/dsm, products stage)
    and the streaming writer of ortho/mosaic write one profile, byte for byte the same file."""
    g = _grid()
    paths = [write_geotiff(tmp_path / "a.tif", g, T, "EPSG:7415"),
             write_raster(tmp_path / "b.tif", g, T, "EPSG:7415", "dsm", preview=False)[0],
             write_product(tmp_path / "c.tif", g, T, "EPSG:7415"),
             _stream(tmp_path / "d.tif", g, T, "EPSG:7415", 123)]
    expected = {"structure": {"LAYOUT": "COG", "COMPRESSION": "DEFLATE", "INTERLEAVE": "BAND", "PREDICTOR": "2"},
                "tiled": True, "block": (512, 512), "dtypes": ("float32",), "nodata": "nan", "epsg": 7415,
                "transform": (0.5, 0.0, 84800.0, 0.0, -0.5, 447650.0), "count": 1, "colorinterp": ["gray"],
                "overviews": [2]}
    for p in paths:
        assert _profile(p) == expected, p
    assert len({p.read_bytes() for p in paths}) == 1
    back, t, crs = read_geotiff(paths[3])
    np.testing.assert_array_equal(back, g)
    assert t == T and crs == pyproj.CRS.from_epsg(7415)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.tif", "b.tif", "c.tif", "d.tif"]


def test_float64_grids_are_written_as_float32_by_every_writer(tmp_path):
    g = _grid((40, 30)).astype(np.float64)
    a = write_product(tmp_path / "a.tif", g, T, "EPSG:31982")
    b = _stream(tmp_path / "b.tif", g, T, "EPSG:31982", 7)
    assert _profile(a) == _profile(b) and _profile(a)["dtypes"] == ("float32",)
    assert a.read_bytes() == b.read_bytes()


def test_three_band_images_same_profile_streamed_or_whole(tmp_path):
    rgb = np.random.default_rng(1).uniform(0, 255, (300, 200, 3)).astype(np.float32)
    rgb[:10] = np.nan
    a = write_geotiff(tmp_path / "a.tif", rgb, T, "EPSG:31982")
    b = _stream(tmp_path / "b.tif", rgb, T, "EPSG:31982", 64)
    assert _profile(a) == _profile(b)
    assert _profile(a)["colorinterp"] == ["red", "green", "blue"] and _profile(a)["nodata"] == "nan"
    back, _, _ = read_geotiff(b)
    np.testing.assert_array_equal(back, rgb)
    u8 = np.arange(300 * 200 * 3, dtype=np.uint8).reshape(300, 200, 3)
    c = write_product(tmp_path / "c.tif", u8, T, "EPSG:31982")
    assert _profile(c)["dtypes"] == ("uint8",) * 3 and _profile(c)["nodata"] is None
    np.testing.assert_array_equal(read_geotiff(c, raw=True)[0], u8)


def test_compound_crs_keeps_its_epsg_code(tmp_path):
    """EPSG:7415 (RD New + NAP height) is written by its code: GDAL and lidarcat read 7415 back, from any
    spelling that is that CRS (a code, 'EPSG:28992+5709', its WKT with the ID)."""
    rd = pyproj.CRS.from_epsg(7415)
    for k, spelling in enumerate(["EPSG:7415", 7415, "EPSG:28992+5709", rd, rd.to_wkt()]):
        p = write_geotiff(tmp_path / f"{k}.tif", np.ones((3, 4), np.float32), T, spelling)
        with rasterio.open(p) as d:
            assert d.crs.to_epsg() == 7415 and d.crs == rasterio.crs.CRS.from_epsg(7415), spelling
        crs = read_geotiff(p)[2]
        assert crs.to_epsg() == 7415 and crs.equals(rd) and crs.is_compound, spelling


def test_reads_dems_of_other_programs(tmp_path):
    """DEFLATE and LZW, tiled and stripped, BigTIFF, big-endian, float64 and int16 with a nodata value."""
    rng = np.random.default_rng(3)
    h = rng.uniform(10, 60, (260, 330))
    aff = Affine(0.25, 0.0, 680000.0, 0.0, -0.25, 7185000.0)
    cases = [
        ("deflate.tif", np.float32, dict(compress="DEFLATE", predictor=3, tiled=True, blockxsize=128,
                                         blockysize=128, nodata=-9999.0)),
        ("lzw.tif", np.float64, dict(compress="LZW", predictor=2, tiled=True, blockxsize=256, blockysize=256)),
        ("big.tif", np.float32, dict(compress="DEFLATE", BIGTIFF="YES", ENDIANNESS="BIG", nodata=-32768.0)),
        ("int16.tif", np.int16, dict(compress="LZW", nodata=-32768)),
    ]
    for name, dtype, opts in cases:
        a = h.astype(dtype)
        nodata = opts.get("nodata")
        if nodata is not None:
            a[100:110, 50:70] = nodata
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=330, height=260, count=1, dtype=a.dtype,
                           crs="EPSG:31982", transform=aff, **opts) as dst:
            dst.write(a, 1)
        grid, t, crs = read_geotiff(tmp_path / name)
        want = a.astype(np.float64 if dtype == np.float64 else np.float32)
        if nodata is not None:
            want[100:110, 50:70] = np.nan
        np.testing.assert_array_equal(grid, want, err_msg=name)
        assert grid.dtype == want.dtype and t == GeoTransform(680000.0, 7185000.0, 0.25), name
        assert crs.to_epsg() == 31982, name
    assert (tmp_path / "big.tif").read_bytes()[:4] == b"MM\x00+"      # really a big-endian BigTIFF
    raw, _, _ = read_geotiff(tmp_path / "int16.tif", raw=True)
    assert raw.dtype == np.int16 and raw[100, 50] == -32768


def test_reader_refuses_what_is_not_a_north_up_square_grid(tmp_path):
    for name, aff, msg in [
        ("rot.tif", Affine(0.5, 0.1, 0.0, 0.1, -0.5, 10.0), r"rot\.tif: not a north-up georeferenced grid"),
        ("rect.tif", Affine(0.5, 0.0, 0.0, 0.0, -0.25, 10.0),
         r"rect\.tif: cells of 0\.5 x 0\.25 are not square; resample the grid to square cells"),
    ]:
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                           transform=aff) as dst:
            dst.write(np.zeros((1, 4, 4), np.float32))
        with pytest.raises(LidarFormatError, match=msg):
            read_geotiff(tmp_path / name)


def test_streaming_writer_is_atomic_and_checks_its_rows(tmp_path):
    g = _grid((100, 40))
    with pytest.raises(KeyboardInterrupt):
        with GeoTiffWriter(tmp_path / "x.tif", g.shape, 1, T, "EPSG:7415") as w:
            w.write_rows(g[:30])
            raise KeyboardInterrupt
    with pytest.raises(ValueError, match=r"x\.tif: only 30 of 100 rows written"):
        with GeoTiffWriter(tmp_path / "x.tif", g.shape, 1, T) as w:
            w.write_rows(g[:30])
    with pytest.raises(ValueError, match=r"x\.tif: row block of shape \(80, 40, 1\) does not fit a 100 x 40 x 1 "
                                         r"grid at row 30"):
        with GeoTiffWriter(tmp_path / "x.tif", g.shape, 1, T) as w:
            w.write_rows(g[:30])
            w.write_rows(g[:80])
    assert list(tmp_path.iterdir()) == []
    assert GeoTiffStream is GeoTiffWriter     # the orthophoto's writer, by its old name
