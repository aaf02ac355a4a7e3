"""LiDAR access layer: readers, CRS, tile index, clips, rasters (issue 4)."""

from __future__ import annotations

import os
import shutil
import struct
import tempfile
from pathlib import Path

import numpy as np
import pyproj
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import LIDAR_DATA
from lidarcat.errors import ClipError, CRSError, LidarFormatError, TileIOError
from lidarcat.lidar import (
    PointCloud,
    TileIndex,
    clip,
    height_window_mask,
    in_polygon,
    iter_points,
    rasterize,
    read_header,
    read_points,
    transform_points,
    write_geotiff,
    write_points,
)
from lidarcat.lidar.geotiff import read_geotiff
from lidarcat.lidar.raster import write_png_preview

AHN1 = LIDAR_DATA / "ahn3_cropped_1.laz"
AHN2 = LIDAR_DATA / "ahn3_cropped_2.laz"
PDAL = LIDAR_DATA / "pdal_sample_c.las"
RD = "EPSG:7415"
HOUSE = (85000.0, 447472.0)  # gable roof straddling the x = 85000 tile boundary


@pytest.fixture(scope="module")
def ahn_both() -> PointCloud:
    return PointCloud.concat([read_points(AHN1, crs=RD), read_points(AHN2, crs=RD)])


def _classes(pc: PointCloud) -> dict[int, int]:
    u, c = np.unique(pc.attributes["classification"], return_counts=True)
    return dict(zip(u.tolist(), c.tolist()))


# --------------------------------------------------------------------------- real files (README facts)
def test_readme_counts_bounds_classes():
    a = read_points(AHN1)
    assert len(a) == 640_510
    np.testing.assert_allclose(a.bounds[:4], (84808.3, 447412.8, 84999.999, 447641.299), atol=5e-4)
    assert _classes(a) == {1: 196_137, 2: 195_988, 6: 246_753, 9: 267, 26: 1_365}
    assert sorted(np.unique(a.attributes["return_number"]).tolist()) == [1, 2, 3, 4, 5]
    assert set(a.attributes) == {"intensity", "return_number", "number_of_returns", "classification",
                                 "point_source_id", "gps_time"}
    b = read_points(AHN2)
    assert len(b) == 208_432
    np.testing.assert_allclose(b.bounds[:4], (85000.001, 447412.8, 85072.299, 447641.299), atol=5e-4)
    assert set(_classes(b)) == {1, 2, 6, 9, 26}
    c = read_points(PDAL)
    assert len(c) == 14_408
    assert _classes(c)[6] == 12_525
    h = read_header(PDAL)
    assert h.description == "LAS 1.2, point format 3" and h.count == 14_408


def test_header_matches_points_and_no_crs_in_ahn3():
    h = read_header(AHN1)
    assert h.count == 640_510 and h.crs is None and not h.crs_from_file
    h = read_header(AHN1, crs=RD)
    assert h.crs.to_epsg() == 7415 and not h.crs_from_file
    assert read_points(AHN2, crs="EPSG:28992").crs.to_epsg() == 28992


def test_density_as_in_readme():
    from lidarcat.lidar import describe

    f = describe(AHN1)["files"][0]
    np.testing.assert_allclose(f["density_pts_m2"], 15.7, atol=0.1)
    np.testing.assert_allclose(f["first_return_density_pts_m2"], 11.5, atol=0.1)
    assert f["classes"]["6"] == 246_753 and f["returns"]["5"] == 8_010


def test_iter_points_chunks_bounded_and_complete():
    chunks = list(iter_points(AHN2, 50_000))
    assert [len(c) for c in chunks[:-1]] == [50_000] * (len(chunks) - 1)
    assert sum(len(c) for c in chunks) == 208_432
    whole = read_points(AHN2)
    np.testing.assert_array_equal(PointCloud.concat(chunks).xyz, whole.xyz)
    # a tile index streams a tile too big for its memory budget in chunks of chunk_size
    idx = TileIndex.build([AHN2], crs=RD, max_cached_points=0, chunk_size=50_000)
    assert [len(c) for c in idx.iter_points()] == [50_000] * 4 + [8_432]


# --------------------------------------------------------------------------- clip across the tile boundary
def test_clip_straddling_house_is_union_of_both_tiles(ahn_both):
    idx = TileIndex.build([AHN1, AHN2], crs=RD)
    got = clip(idx, HOUSE, 6.0)
    ref = clip(ahn_both, HOUSE, 6.0)
    np.testing.assert_array_equal(got.xyz, ref.xyz)
    for k in ref.attributes:
        np.testing.assert_array_equal(got.attributes[k], ref.attributes[k])
    west, east = int((got.x < 85000).sum()), int((got.x > 85000).sum())
    assert west > 200 and east > 200
    # union of the two files' own circles, before any filter
    parts = [read_points(p, crs=RD) for p in (AHN1, AHN2)]
    n_union = sum(int((np.hypot(p.x - HOUSE[0], p.y - HOUSE[1]) <= 6.0).sum()) for p in parts)
    assert len(clip(idx, HOUSE, 6.0, height_filter=None)) == n_union
    # from paths (indexed on the fly), the same points
    np.testing.assert_array_equal(clip([AHN1, AHN2], HOUSE, 6.0, crs=RD).xyz, ref.xyz)


def test_clip_position_given_in_another_crs(ahn_both):
    lonlat = transform_points(HOUSE, "EPSG:28992", "EPSG:4326")
    got = clip(ahn_both, lonlat, 6.0, crs="EPSG:4326", height_filter=None)
    ref = clip(ahn_both, HOUSE, 6.0, height_filter=None)
    assert abs(len(got) - len(ref)) <= 2  # the round trip through lon/lat moves the centre by < 1 mm


def test_thesis_vs_robust_height_filter_on_roof_with_ground():
    rng = np.random.default_rng(7)
    xy = rng.uniform(-5, 5, (3000, 2))
    on_roof = np.hypot(xy[:, 0], xy[:, 1]) < 3.0
    h = np.where(on_roof, 9.0 + 0.05 * xy[:, 0], 0.0) + rng.normal(0, 0.02, len(xy))
    pc = PointCloud(np.column_stack([xy, h]))
    thesis = clip(pc, (0, 0), 5.0, height_filter="thesis", min_points=0)
    robust = clip(pc, (0, 0), 5.0, height_filter="robust")
    in_circle = np.hypot(xy[:, 0], xy[:, 1]) <= 5.0
    # ground is ~64 % of the circle: the mean falls between ground and roof and cuts the roof
    assert (thesis.z > 5).sum() < 0.1 * (on_roof & in_circle).sum()
    assert (robust.z > 5).all() and len(robust) == int((on_roof & in_circle).sum())


def test_height_window_thesis_definition():
    h = np.array([10.0, 10.5, 11.0, 12.9, 13.1, 7.0])
    # mean 10.75 m: 12.9 (2.15 m above), 13.1 and 7.0 fall outside the 2 m window
    assert height_window_mask(h, "thesis", 2.0).tolist() == [True, True, True, False, False, False]
    assert height_window_mask(h, "thesis", 2.2).tolist() == [True, True, True, True, False, False]


def test_clip_first_returns_and_class_filters(ahn_both):
    base = clip(ahn_both, HOUSE, 6.0, height_filter=None)
    first = clip(ahn_both, HOUSE, 6.0, height_filter=None, first_returns_only=True)
    assert len(first) == int((base.attributes["return_number"] == 1).sum())
    bld = clip(ahn_both, HOUSE, 6.0, height_filter=None, classes=[6])
    assert len(bld) == int((base.attributes["classification"] == 6).sum())
    assert set(np.unique(bld.attributes["classification"]).tolist()) == {6}


def test_clip_errors_name_position_radius_and_count(ahn_both):
    with pytest.raises(ClipError, match=r"no LiDAR points within 5 m of E=90000\.000 N=447500\.000"):
        clip(ahn_both, (90000.0, 447500.0), 5.0)
    with pytest.raises(ClipError) as ex:
        clip(ahn_both, HOUSE, 0.3, min_points=10)
    msg = str(ex.value)
    assert "E=85000.000 N=447472.000" in msg and "radius 0.3 m" in msg and "at least 10" in msg
    n = int((np.hypot(ahn_both.x - HOUSE[0], ahn_both.y - HOUSE[1]) <= 0.3).sum())
    assert f"{n} within 0.3 m" in msg
    with pytest.raises(ClipError, match=r"clip position must be two finite numbers \(E, N\) in metres, "
                                        r"got \(85000\.0,\)"):
        clip(ahn_both, (85000.0,), 5.0)
    with pytest.raises(ClipError, match=r"clip position must be two finite numbers .* got \[nan, 447472\.0\]"):
        clip(ahn_both, [float("nan"), 447472.0], 5.0)
    with pytest.raises(ClipError, match=r"clip radius must be positive, got 0 m"):
        clip(ahn_both, HOUSE, 0)


# --------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("suffix", [".las", ".laz", ".xyz", ".csv", ".txt"])
def test_write_read_round_trip_real_points(tmp_path, suffix):
    pc = read_points(AHN2, crs=RD).select(slice(0, 20_000))
    out = write_points(tmp_path / f"part{suffix}", pc)
    back = read_points(out, crs=None if suffix in (".las", ".laz") else RD)
    np.testing.assert_array_equal(back.xyz, pc.xyz)
    assert set(back.attributes) == set(pc.attributes)
    for k, v in pc.attributes.items():
        np.testing.assert_array_equal(back.attributes[k], v)
        assert back.attributes[k].dtype == v.dtype
    assert back.crs.to_epsg() == 7415


def test_round_trip_synthetic_full_precision_text(tmp_path):
    rng = np.random.default_rng(3)
    xyz = rng.uniform([677000, 7183000, 890], [678000, 7184000, 930], (500, 3))  # full float64
    pc = PointCloud(xyz, {"intensity": rng.integers(0, 255, 500), "classification": rng.integers(1, 7, 500)},
                    crs=pyproj.CRS("EPSG:31982"))
    for name in ("a.xyz", "a.csv"):
        back = read_points(write_points(tmp_path / name, pc), crs="EPSG:31982")
        np.testing.assert_array_equal(back.xyz, pc.xyz)
        np.testing.assert_array_equal(back.attributes["classification"], pc.attributes["classification"])


@pytest.mark.parametrize("suffix", [".laz", ".xyz"])
def test_write_refuses_non_finite_coordinates(tmp_path, suffix):
    pc = PointCloud(np.array([[1.0, 2.0, 3.0], [4.0, np.nan, 6.0], [7.0, 8.0, np.inf]]))
    with pytest.raises(LidarFormatError, match=r"bad\.\w+: point 1 \(counting from 0\) has a non-finite "
                                               r"coordinate \[4\.0, nan, 6\.0\] \(2 such points\)"):
        write_points(tmp_path / f"bad{suffix}", pc)
    assert not list(tmp_path.iterdir())


def test_las_crs_written_and_read_back(tmp_path):
    pc = read_points(PDAL).select(slice(0, 100)).with_crs(pyproj.CRS("EPSG:31982"))
    back = read_points(write_points(tmp_path / "c.laz", pc))
    assert back.crs.to_epsg() == 31982
    assert read_header(tmp_path / "c.laz").crs_from_file
    with pytest.raises(CRSError, match=r"c\.laz: the file says its CRS is EPSG:31982"):
        read_points(tmp_path / "c.laz", crs="EPSG:29192")


# --------------------------------------------------------------------------- ASCII dialects
def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def test_ascii_thesis_strip_decimal_comma_whitespace(tmp_path):
    p = _write(tmp_path, "faixa.xyz", "# Optech ALTM 2050\n\n677757,80 7183482,00 905,12 118\n"
                                      "677758,10 7183482,40 905,20 121\n")
    pc = read_points(p, crs="EPSG:29192")
    np.testing.assert_array_equal(pc.xyz, [[677757.8, 7183482.0, 905.12], [677758.1, 7183482.4, 905.2]])
    assert pc.attributes["intensity"].tolist() == [118, 121]


def test_ascii_semicolon_header_aliases_decimal_comma(tmp_path):
    p = _write(tmp_path, "p.csv", "Este;Norte;Altitude;Int;Classe\n677757,8;7183482,0;905,1;12;6\n"
                                  "677758,8;7183483,0;906,1;13;2\n")
    pc = read_points(p)
    np.testing.assert_array_equal(pc.xyz[1], [677758.8, 7183483.0, 906.1])
    assert pc.attributes["classification"].tolist() == [6, 2]
    assert pc.attributes["classification"].dtype == np.uint8


def test_ascii_comma_header_and_columns_override(tmp_path):
    p = _write(tmp_path, "p.txt", "x,y,z,r,gpstime,red\n1.5,2.5,3.5,1,100.25,200\n")
    pc = read_points(p)
    assert pc.attributes["return_number"].tolist() == [1]
    assert pc.attributes["gps_time"].tolist() == [100.25] and pc.attributes["red"].tolist() == [200.0]
    q = _write(tmp_path, "q.pts", "2.5 1.5 3.5 9 77\n")
    pc = read_points(q, columns="N E H - class")
    np.testing.assert_array_equal(pc.xyz, [[1.5, 2.5, 3.5]])
    assert pc.attributes["classification"].tolist() == [77] and "intensity" not in pc.attributes


def test_ascii_chunked_reading_matches_whole(tmp_path):
    rng = np.random.default_rng(1)
    pc = PointCloud(np.round(rng.uniform(0, 100, (1001, 3)), 3), {"intensity": rng.integers(0, 999, 1001)})
    p = write_points(tmp_path / "s.asc", pc)
    chunks = list(iter_points(p, 100))
    assert len(chunks) == 11
    np.testing.assert_array_equal(PointCloud.concat(chunks).xyz, pc.xyz)


# --------------------------------------------------------------------------- bad input
def test_truncated_laz_names_file(tmp_path):
    p = tmp_path / "trunc.laz"
    data = AHN2.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(LidarFormatError, match=r"trunc\.laz: truncated or corrupt point data"):
        read_points(p)


def test_truncated_las_names_file_and_counts(tmp_path):
    p = tmp_path / "trunc.las"
    data = PDAL.read_bytes()
    p.write_bytes(data[: len(data) - 1000])
    with pytest.raises(LidarFormatError, match=r"trunc\.las: truncated: the header announces 14408 points"):
        read_points(p)
    with pytest.raises(LidarFormatError, match=r"trunc\.las"):
        TileIndex.build([p])


def test_corrupt_las_header_names_file(tmp_path):
    data = bytearray(PDAL.read_bytes())
    data[94:96] = struct.pack("<H", 17)  # header size
    p = tmp_path / "badhdr.las"
    p.write_bytes(bytes(data))
    with pytest.raises(LidarFormatError, match=r"badhdr\.las: corrupt LAS header: header size 17 bytes \(at least 227"):
        read_points(p)
    q = tmp_path / "notlas.laz"
    q.write_bytes(b"hello world" * 50)
    with pytest.raises(LidarFormatError, match=r"notlas\.laz: not a valid LAS/LAZ file"):
        read_header(q)


def test_ascii_wrong_field_count_names_file_and_line(tmp_path):
    p = _write(tmp_path, "bad.xyz", "1 2 3 4\n# comment\n5 6 7 8\n9 10 11\n")
    with pytest.raises(LidarFormatError) as ex:
        read_points(p)
    assert str(ex.value) == f"{p}:4: 3 fields, expected 4 (E N H intensity)"


def test_ascii_non_number_names_file_line_field(tmp_path):
    p = _write(tmp_path, "bad.csv", "E,N,H\n1,2,3\n4,x5,6\n")
    with pytest.raises(LidarFormatError) as ex:
        read_points(p)
    assert str(ex.value) == f"{p}:3: field 'N': 'x5' is not a number"
    q = _write(tmp_path, "bad2.xyz", "1 2 3 1\n4 5 6 2.5\n")
    with pytest.raises(LidarFormatError, match=r"bad2\.xyz:2: field 'return_number': 2\.5 is not an integer"):
        read_points(q, columns="E N H return")
    r = _write(tmp_path, "bad3.xyz", "1 2 nan\n")
    with pytest.raises(LidarFormatError, match=r"bad3\.xyz:1: field 'H': 'nan' is not a finite number"):
        read_points(r)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(TileIOError, match=r"nope\.laz: file not found"):
        read_points(tmp_path / "nope.laz")
    with pytest.raises(TileIOError, match=r"nope\.xyz: file not found"):
        read_points(tmp_path / "nope.xyz")
    (tmp_path / "dir.laz").mkdir()
    (tmp_path / "dir.xyz").mkdir()
    with pytest.raises(TileIOError, match=r"dir\.laz: is a folder, expected a LAS/LAZ file"):
        read_header(tmp_path / "dir.laz")
    with pytest.raises(TileIOError, match=r"dir\.xyz: is a folder, expected a point file"):
        read_points(tmp_path / "dir.xyz")
    with pytest.raises(LidarFormatError, match=r"x\.shp: unsupported point file type '\.shp'"):
        read_points(tmp_path / "x.shp")
    with pytest.raises(TileIOError, match=r"no LiDAR files match"):
        TileIndex.build([str(tmp_path / "*.laz")])


def test_unknown_crs_string_names_it():
    with pytest.raises(CRSError, match=r"unknown CRS 'EPSG:999999'"):
        read_points(PDAL, crs="EPSG:999999")
    with pytest.raises(CRSError, match=r"unknown source CRS 'SAD69 please'"):
        transform_points([0.0, 0.0], "SAD69 please", "EPSG:31982")


# --------------------------------------------------------------------------- CRS
def test_transform_sad69_to_sirgas_matches_pyproj():
    pts = np.array([[677757.8, 7183482.0], [677140.008, 7183495.116]])
    got = transform_points(pts, "EPSG:29192", "EPSG:31982")
    tr = pyproj.Transformer.from_crs("EPSG:29192", "EPSG:31982", always_xy=True)
    ref = np.column_stack(tr.transform(pts[:, 0], pts[:, 1]))
    np.testing.assert_allclose(got, ref, atol=1e-6)
    # the SAD69 -> SIRGAS 2000 shift in Curitiba is tens of metres
    assert 30 < np.hypot(*(got[0] - pts[0])) < 100
    back = transform_points(got, "EPSG:31982", "EPSG:29192")
    np.testing.assert_allclose(back, pts, atol=1e-6)


def test_index_refuses_mixed_crs(tmp_path):
    a = read_points(PDAL).select(slice(0, 50))
    write_points(tmp_path / "a.las", a.with_crs(pyproj.CRS("EPSG:29192")))
    write_points(tmp_path / "b.las", a.with_crs(pyproj.CRS("EPSG:31982")))
    with pytest.raises(CRSError, match=r"cannot mix coordinate systems: .*a\.las is EPSG:29192.*b\.las is EPSG:31982"):
        TileIndex.build(str(tmp_path / "*.las"))
    with pytest.raises(CRSError):
        PointCloud.concat([read_points(tmp_path / "a.las"), read_points(tmp_path / "b.las")])
    # a file with a CRS and one without (given 28992) cannot be merged silently either
    write_points(tmp_path / "c.las", a)
    with pytest.raises(CRSError, match="cannot mix"):
        TileIndex.build([tmp_path / "a.las", tmp_path / "c.las"])


def test_compound_and_horizontal_crs_are_compatible(tmp_path):
    a = read_points(PDAL).select(slice(0, 50))
    write_points(tmp_path / "a.las", a.with_crs(pyproj.CRS("EPSG:28992")))
    idx = TileIndex.build([tmp_path / "a.las", AHN1], crs=RD)
    assert idx.crs.to_epsg() == 7415


# --------------------------------------------------------------------------- tile index
def test_index_cache_reused_and_refreshed(tmp_path, monkeypatch):
    tiles = tmp_path / "lidar"
    tiles.mkdir()
    shutil.copy(AHN2, tiles / "t2.laz")
    pc = read_points(PDAL)
    write_points(tiles / "t1.las", pc.select(slice(0, 1000)))
    cache = tmp_path / "lidar_index.json"
    idx = TileIndex.build("lidar/*", crs=RD, cache_path=cache, root=tmp_path)
    assert [t.count for t in idx.tiles] == [1000, 208_432] and cache.exists()
    assert '"path": "lidar/t1.las"' in cache.read_text()
    import lidarcat.lidar.tileindex as ti

    def boom(*a, **k):
        raise AssertionError("tile re-read although unchanged")

    monkeypatch.setattr(ti, "read_header", boom)
    again = TileIndex.build("lidar/*", crs=RD, cache_path=cache, root=tmp_path)
    assert [t.count for t in again.tiles] == [1000, 208_432]
    monkeypatch.undo()
    write_points(tiles / "t1.las", pc.select(slice(0, 700)))
    os.utime(tiles / "t1.las", ns=(1, 1))  # make sure the mtime differs even on coarse clocks
    fresh = TileIndex.build("lidar/*", crs=RD, cache_path=cache, root=tmp_path)
    assert [t.count for t in fresh.tiles] == [700, 208_432]
    # a tile changed after indexing is refused, not silently misread
    write_points(tiles / "t1.las", pc.select(slice(0, 600)))
    os.utime(tiles / "t1.las", ns=(2, 2))
    fresh.clear_cache()
    with pytest.raises(TileIOError, match=r"t1\.las: the file changed since it was indexed"):
        fresh.query_box(*pc.bounds[:4])


def test_unwritable_index_cache_named(tmp_path):
    blocker = tmp_path / "survey.toml"
    blocker.write_text("")  # a file where the cache's folder should be
    with pytest.raises(TileIOError, match=r"survey\.toml/lidar_index\.json: cannot write the tile index"):
        TileIndex.build([AHN2], crs=RD, cache_path=blocker / "lidar_index.json")


def test_query_touches_only_needed_tiles(monkeypatch):
    idx = TileIndex.build([AHN1, AHN2], crs=RD)
    assert not any(t.bounds_verified for t in idx.tiles)   # header bounds: a claim, not used to skip
    assert idx.verify_bounds() == 2 and all(t.bounds_verified for t in idx.tiles)
    assert idx.tiles[1].bounds.xmin == pytest.approx(85000.001, abs=5e-4)
    idx.clear_cache()
    opened = []
    import lidarcat.lidar.tileindex as ti

    real = ti.iter_points

    def spy(path, *a, **k):
        opened.append(Path(path).name)
        return real(path, *a, **k)

    monkeypatch.setattr(ti, "iter_points", spy)
    idx.query_radius((84900.0, 447500.0), 5.0)
    assert opened == ["ahn3_cropped_1.laz"]
    idx.query_box(85010, 447500, 85020, 447510)
    assert opened == ["ahn3_cropped_1.laz", "ahn3_cropped_2.laz"]


def test_in_polygon_concave():
    poly = np.array([[0, 0], [4, 0], [4, 4], [2, 1], [0, 4]], float)  # a V-shaped notch from the top
    pts = np.array([[1, 1], [2, 3], [3, 1], [2, 0.5], [5, 1]], float)
    assert in_polygon(pts, poly).tolist() == [True, False, True, True, False]


_tiling = st.tuples(st.integers(1, 4), st.integers(1, 4), st.integers(0, 10_000))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_tiling, st.lists(st.tuples(st.floats(0, 100), st.floats(0, 100), st.floats(0.5, 40)), min_size=1,
                         max_size=4))
def test_split_survey_answers_queries_like_unsplit_cloud(tiling, circles):
    nx, ny, seed = tiling
    rng = np.random.default_rng(seed)
    n = 3000
    xyz = np.round(rng.uniform([0, 0, -2], [100, 100, 30], (n, 3)), 3)
    xyz[:50, 0] = np.round(rng.integers(0, 5, 50) * 25.0, 3)  # points exactly on tile edges
    pc = PointCloud(xyz, {"gps_time": np.arange(n, dtype=float), "intensity": rng.integers(0, 4000, n)},
                    crs=pyproj.CRS("EPSG:31982"))
    xs = np.linspace(0, 100, nx + 1)
    ys = np.linspace(0, 100, ny + 1)
    ix = np.clip(np.searchsorted(xs, xyz[:, 0], side="right") - 1, 0, nx - 1)
    iy = np.clip(np.searchsorted(ys, xyz[:, 1], side="right") - 1, 0, ny - 1)
    with tempfile.TemporaryDirectory() as d:
        for i in range(nx):
            for j in range(ny):
                m = (ix == i) & (iy == j)
                if m.any():
                    suffix = ".laz" if (i + j) % 3 == 0 else ".las" if (i + j) % 3 == 1 else ".xyz"
                    write_points(Path(d) / f"t{i}_{j}{suffix}", pc.select(m))
        idx = TileIndex.build(str(Path(d) / "t*"), crs="EPSG:31982", max_cached_points=1000)

        def same(got: PointCloud, mask: np.ndarray) -> None:
            order = np.argsort(got.attributes["gps_time"])
            ref = pc.select(mask)
            np.testing.assert_array_equal(got.xyz[order], ref.xyz)
            np.testing.assert_array_equal(got.attributes["intensity"][order], ref.attributes["intensity"])

        for cx, cy, r in circles:
            same(idx.query_radius((cx, cy), r), (xyz[:, 0] - cx) ** 2 + (xyz[:, 1] - cy) ** 2 <= r * r)
            box = (cx - r, cy - r / 2, cx + r / 3, cy + r)
            same(idx.query_box(*box), (xyz[:, 0] >= box[0]) & (xyz[:, 0] <= box[2]) &
                 (xyz[:, 1] >= box[1]) & (xyz[:, 1] <= box[3]))
            poly = np.array([[cx - r, cy - r], [cx + r, cy - r / 2], [cx, cy], [cx + r / 2, cy + r],
                             [cx - r, cy + r / 3]])
            same(idx.query_polygon(poly), in_polygon(xyz, poly))


# --------------------------------------------------------------------------- rasters
def _grid_cloud() -> PointCloud:
    # 4 x 3 m area, 1 m cells; two returns per cell centre: a first return at 10 + col, a last at row
    pts, attrs = [], {"intensity": [], "return_number": [], "number_of_returns": [], "classification": []}
    for row in range(3):
        for col in range(4):
            if (row, col) == (1, 2):
                continue  # a one-cell hole
            x, y = 100 + col + 0.5, 203 - row - 0.5
            pts += [(x, y, 10.0 + col), (x, y, float(row))]
            attrs["intensity"] += [10 * col, 999]
            attrs["return_number"] += [1, 2]
            attrs["number_of_returns"] += [2, 2]
            attrs["classification"] += [1, 2 if col != 3 else 1]
    return PointCloud(np.array(pts), attrs, crs=pyproj.CRS("EPSG:31982"))


def test_rasterize_dsm_dtm_intensity_known_grid():
    pc = _grid_cloud()
    dsm, t = rasterize(pc, 1.0, "dsm", fill=None)
    assert t == (100.0, 203.0, 1.0) and dsm.shape == (3, 4)
    expect = np.array([[10, 11, 12, 13]] * 3, dtype=np.float32)
    expect[1, 2] = np.nan
    np.testing.assert_array_equal(dsm, expect)
    inten, _ = rasterize(pc, 1.0, "intensity", fill=None)
    np.testing.assert_array_equal(inten[0], [0, 10, 20, 30])  # first returns only, not the 999s
    dtm, _ = rasterize(pc, 1.0, "dtm", fill=None)
    np.testing.assert_array_equal(dtm[:, 0], [0, 1, 2])
    assert np.isnan(dtm[:, 3]).all()  # column 3 has no ground class: not terrain
    dsm_f, _ = rasterize(pc, 1.0, "dsm", fill="small")
    np.testing.assert_allclose(dsm_f[1, 2], 12.0, atol=1e-6)  # the hole takes its neighbours' mean
    dtm_i, _ = rasterize(pc, 1.0, "dtm")
    np.testing.assert_allclose(dtm_i[1, 2], 1.0, atol=1e-6)
    assert np.isnan(dtm_i[:, 3]).all()  # no extrapolation beyond the ground points


def test_dtm_interpolates_ground_under_a_building():
    g = np.arange(20) + 0.5
    x, y = np.meshgrid(g, g)
    x, y = x.ravel(), y.ravel()
    building = (x > 6) & (x < 13) & (y > 5) & (y < 14)
    h = np.where(building, 8.0, 2.0 + 0.1 * x + 0.05 * y)
    pc = PointCloud(np.column_stack([x, y, h]), {"classification": np.where(building, 6, 2)})
    dtm, t = rasterize(pc, 1.0, "dtm")
    assert np.isfinite(dtm).all()
    cx, cy = t.xy(*np.indices(dtm.shape))
    np.testing.assert_allclose(dtm, 2.0 + 0.1 * cx + 0.05 * cy, atol=1e-4)  # a plane stays a plane


def test_rasterize_stream_equals_whole(ahn_both):
    idx = TileIndex.build([AHN1, AHN2], crs=RD, max_cached_points=0)
    box = idx.bounds[:4]
    a, ta = rasterize(idx.iter_points(), 2.0, "dsm", box)
    b, tb = rasterize(ahn_both, 2.0, "dsm", box)
    assert ta == tb
    np.testing.assert_array_equal(a, b)


def test_geotiff_round_trip_and_tags(tmp_path):
    grid = np.arange(12, dtype=np.float32).reshape(3, 4)
    grid[1, 1] = np.nan
    from lidarcat.lidar import GeoTransform

    t = GeoTransform(84800.0, 447650.0, 0.5)
    p = write_geotiff(tmp_path / "g.tif", grid, t, RD)
    back, tb, crs = read_geotiff(p)
    np.testing.assert_array_equal(back, grid)
    assert tb == t and crs.to_epsg() == 7415
    assert not (tmp_path / "g.tif.aux.xml").exists()
    PIL = pytest.importorskip("PIL.Image")
    im = PIL.open(p)  # an independent TIFF reader
    assert im.size == (4, 3) and im.mode == "F"
    assert tuple(im.tag_v2[33550]) == (0.5, 0.5, 1.0)   # GDAL: Z scale 1 with a vertical CRS (was 0)
    assert tuple(im.tag_v2[33922]) == (0.0, 0.0, 0.0, 84800.0, 447650.0, 0.0)
    keys = list(im.tag_v2[34735])
    assert [3072, 0, 1, 28992] == keys[keys.index(3072):keys.index(3072) + 4]
    assert [4096, 0, 1, 5709] == keys[keys.index(4096):keys.index(4096) + 4]
    np.testing.assert_array_equal(np.asarray(im)[2], grid[2])


def test_geotiff_without_epsg_keeps_the_crs_in_its_geokeys(tmp_path):
    """A CRS without an EPSG code round-trips (GDAL's user-defined GeoKeys; no sidecar needed any more)."""
    crs = pyproj.CRS.from_proj4("+proj=tmerc +lat_0=0 +lon_0=-51 +k=0.9996 +x_0=500000 +y_0=10000000 "
                                "+ellps=GRS80 +units=m +no_defs")
    from lidarcat.lidar import GeoTransform

    p = write_geotiff(tmp_path / "u.tif", np.ones((2, 2), np.float32), GeoTransform(0, 10, 1), crs)
    assert not (tmp_path / "u.tif.aux.xml").exists()
    assert read_geotiff(p)[2].equals(crs)


def test_read_geotiff_bad_files_named(tmp_path):
    from lidarcat.lidar import GeoTransform

    with pytest.raises(TileIOError, match=r"none\.tif: file not found"):
        read_geotiff(tmp_path / "none.tif")
    p = write_geotiff(tmp_path / "g.tif", np.ones((40, 30), np.float32), GeoTransform(0, 10, 1), RD)
    data = p.read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[:len(data) - 200])  # the tag directory is at the end
    with pytest.raises(LidarFormatError, match=r"cut\.tif: truncated or incomplete GeoTIFF"):
        read_geotiff(tmp_path / "cut.tif")
    (tmp_path / "png.tif").write_bytes(b"\x89PNG\r\n\x1a\n")
    with pytest.raises(LidarFormatError, match=r"png\.tif: not a little-endian TIFF"):
        read_geotiff(tmp_path / "png.tif")


def test_png_preview_written(tmp_path):
    pc = _grid_cloud()
    grid, t = rasterize(pc, 1.0, "dsm")
    p = write_png_preview(tmp_path / "g.png", grid, t, "dsm")
    data = p.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    # 7.5 in wide, 6 in x (3 rows / 4 cols) + 0.6 in for the title, at 120 dpi
    assert struct.unpack(">II", data[16:24]) == (900, 612)
    assert not list(tmp_path.glob(".*part"))


# --------------------------------------------------------------------------- PointCloud
def test_pointcloud_is_immutable_and_validates():
    pc = PointCloud(np.zeros((2, 3)), {"intensity": [1, 2]})
    with pytest.raises(ValueError, match="read-only"):
        pc.xyz[0, 0] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        pc.attributes["intensity"][0] = 7
    with pytest.raises(TypeError):
        pc.attributes["gps_time"] = np.zeros(2)  # the mapping itself is read-only
    with pytest.raises(ValueError, match=r"attribute 'intensity' has shape \(3,\), expected \(2,\)"):
        PointCloud(np.zeros((2, 3)), {"intensity": [1, 2, 3]})
    with pytest.raises(ValueError, match=r"xyz must have shape \(N, 3\)"):
        PointCloud(np.zeros((2, 2)))
    # a slice or an index array gives an independent, read-only copy
    part = pc.select(slice(1, 2))
    assert len(part) == 1 and part.xyz.base is None and not part.xyz.flags.writeable
    assert pc.select(np.array([1, 1])).attributes["intensity"].tolist() == [2, 2]
    with pytest.raises(ValueError, match=r"mask has shape \(3,\), expected \(2,\)"):
        pc.select(np.ones(3, bool))
    a = PointCloud(np.ones((1, 3)), {"intensity": [5], "gps_time": [1.0]})
    both = PointCloud.concat([pc, a])
    assert len(both) == 3 and list(both.attributes) == ["intensity"]


@pytest.mark.parametrize("version,point_format", [("1.0", 0), ("1.1", 1), ("1.2", 3), ("1.3", 1),
                                                  ("1.4", 6), ("1.4", 8)])
def test_las_versions_and_point_formats(tmp_path, version, point_format):
    import laspy

    write_version = "1.1" if version == "1.0" else version
    h = laspy.LasHeader(version=write_version, point_format=point_format)
    h.scales = [0.01, 0.01, 0.01]
    h.offsets = [677000.0, 7183000.0, 0.0]
    las = laspy.LasData(h)
    las.X, las.Y, las.Z = np.array([1, 2]), np.array([3, 4]), np.array([90512, 90520])
    las.classification = np.array([2, 40 if point_format >= 6 else 6])
    las.intensity = np.array([7, 8])
    p = tmp_path / "v.las"
    las.write(p)
    if version == "1.0":  # laspy writes 1.1 at the oldest; the 1.0 header differs only in reserved fields
        data = bytearray(p.read_bytes())
        data[25] = 0
        p.write_bytes(bytes(data))
    assert read_header(p).description == f"LAS {version}, point format {point_format}"
    pc = read_points(p)
    np.testing.assert_array_equal(pc.xyz, [[677000.01, 7183000.03, 905.12], [677000.02, 7183000.04, 905.2]])
    assert pc.attributes["classification"].tolist() == [2, 40 if point_format >= 6 else 6]
    assert pc.attributes["intensity"].tolist() == [7, 8]
    # written back (LAS 1.4 format 6 when a class exceeds 31) and read again: identical
    back = read_points(write_points(tmp_path / "w.laz", pc))
    np.testing.assert_array_equal(back.xyz, pc.xyz)
    np.testing.assert_array_equal(back.attributes["classification"], pc.attributes["classification"])


def test_repeated_clips_from_a_text_file_parse_it_once(tmp_path, monkeypatch):
    rng = np.random.default_rng(2)
    xy = np.round(rng.uniform(0, 50, (5000, 2)), 2)
    pc = PointCloud(np.column_stack([xy, np.full(5000, 900.0)]), {"intensity": rng.integers(0, 200, 5000)})
    p = write_points(tmp_path / "faixa.xyz", pc)
    import lidarcat.lidar.tileindex as ti

    calls = []
    real = ti.iter_points
    monkeypatch.setattr(ti, "iter_points", lambda *a, **k: calls.append(1) or real(*a, **k))
    for c in [(10, 10), (20, 30), (40, 5)]:
        got = clip(p, c, 5.0, crs="EPSG:29192")
        assert len(got) == int(np.sum(((xy - c) ** 2).sum(axis=1) <= 25.0))
    assert len(calls) == 1


def test_pointcloud_crs_string_is_resolved():
    pc = PointCloud(np.zeros((1, 3)), crs="EPSG:7415")
    assert isinstance(pc.crs, pyproj.CRS) and pc.crs.to_epsg() == 7415
    with pytest.raises(CRSError, match="unknown CRS 'EPSG:0'"):
        PointCloud(np.zeros((1, 3)), crs="EPSG:0")
    assert pc.with_crs("EPSG:28992").crs.to_epsg() == 28992
    with pytest.raises(CRSError, match="unknown CRS 'EPSG:0'"):
        pc.with_crs("EPSG:0")


def test_query_outside_every_tile_keeps_the_attribute_schema(tmp_path):
    # found by the split-survey property test: a circle touching no tile lost the attributes
    pc = PointCloud(np.array([[1.0, 1.0, 0.0], [2.0, 2.0, 0.0]]),
                    {"gps_time": np.array([0.0, 1.0]), "intensity": np.array([5, 6])},
                    crs=pyproj.CRS("EPSG:31982"))
    write_points(tmp_path / "t.las", pc)
    got = TileIndex.build(str(tmp_path / "t.las"), crs="EPSG:31982").query_radius((50.0, 50.0), 1.0)
    assert len(got) == 0
    assert {"gps_time", "intensity"} <= set(got.attributes)


def test_query_box_with_swapped_corners_is_a_clip_error():
    from lidarcat.errors import ClipError
    from lidarcat.lidar import TileIndex

    idx = TileIndex.build([str(LIDAR_DATA / "ahn3_cropped_1.laz")], crs="EPSG:7415")
    with pytest.raises(ClipError, match=r"^empty box: x 85010.0..85000.0, y 447470.0..447480.0; "
                                        r"give xmin <= xmax and ymin <= ymax \(metres\)$"):
        idx.query_box(85010.0, 447470.0, 85000.0, 447480.0)
