"""The Brazilian systematic map index: names, corners, Itaocara's 1:5,000 sheets, cutting, index layers."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from pyproj import Transformer

from lidarcat.cli.main import cli
from lidarcat.production.contours import contour_features, contours
from lidarcat.production.mapindex import (LEVELS, MapSheet, cut_contours_geo, cut_raster_geo, sheet_at, sheet_from_name,
                                     sheet_names, sheet_outline, sheets_covering)
from lidarcat.lidar.raster import GeoTransform
from lidarcat.production.sheets import cut_contours, cut_raster, index_sheets, sheet_index_features
from lidarcat.lidar.tileindex import in_polygon

SEC = 1.0 / 3600.0
# LACTEC report, Tabela 3: control points in SAD69 (resolution 2005 = SAD69(96)) / UTM zone 23S, metres
ITAOCARA = {"AP-01": (744496.559, 7582280.469), "AP-05": (778034.101, 7600102.205),
            "AP-11": (796810.321, 7596257.413)}
SAD69_96_UTM23S = "EPSG:5533"


def _bounds(s: MapSheet) -> tuple[float, float, float, float]:
    return s.west, s.south, s.east, s.north


def test_million_sheets_follow_the_imw_definition():
    # SF-23: southern hemisphere, band F = 6th 4-degree band from the equator (20-24 S), zone 23 (48-42 W)
    assert _bounds(sheet_from_name("SF-23")) == (-48.0, -24.0, -42.0, -20.0)
    assert _bounds(sheet_from_name("NA-19")) == (-72.0, 0.0, -66.0, 4.0)
    assert _bounds(sheet_from_name("SA-22")) == (-54.0, -4.0, -48.0, 0.0)
    assert sheet_names([-43.2], [-22.9], 1_000_000).tolist() == ["SF-23"]      # Rio de Janeiro
    assert sheet_names([-47.9], [-15.8], 1_000_000).tolist() == ["SD-23"]      # Brasilia (12-16 S, 48-42 W)


def test_sheet_sizes_of_every_level():
    """Widths x heights (arc-seconds) from the definition: 1:250,000 is 1d30' x 1d, ... 1:2,000 37.5" x 37.5"."""
    expected = {500_000: (10800, 7200), 250_000: (5400, 3600), 100_000: (1800, 1800), 50_000: (900, 900),
                25_000: (450, 450), 10_000: (225, 150), 5_000: (112.5, 75), 2_000: (37.5, 37.5)}
    name = "SF-23"
    for lv in LEVELS:
        name += "-" + lv.symbols[0]
        s = sheet_from_name(name)
        assert s.scale == lv.scale
        assert (round((s.east - s.west) * 3600, 9), round((s.north - s.south) * 3600, 9)) == expected[lv.scale]


@pytest.mark.parametrize("parent", ["SF-23", "SF-23-X", "SF-23-X-D", "SF-23-X-D-VI", "SF-23-X-D-VI-1",
                                    "SF-23-X-D-VI-1-SE", "SF-23-X-D-VI-1-SE-C", "SF-23-X-D-VI-1-SE-C-II"])
def test_children_tile_their_parent_row_by_row_from_the_north_west(parent):
    p = sheet_from_name(parent)
    lv = LEVELS[len(parent.split("-")) - 2]
    kids = [sheet_from_name(f"{parent}-{sym}") for sym in lv.symbols]
    w, h = (p.east - p.west) / lv.ncols, (p.north - p.south) / lv.nrows
    for k, c in enumerate(kids):
        row, col = divmod(k, lv.ncols)
        np.testing.assert_allclose(_bounds(c), (p.west + col * w, p.north - (row + 1) * h,
                                                p.west + (col + 1) * w, p.north - row * h), atol=1e-12)
    # the centre of each child is named by the child
    lon = [0.5 * (c.west + c.east) for c in kids]
    lat = [0.5 * (c.south + c.north) for c in kids]
    assert sheet_names(lon, lat, lv.scale).tolist() == [c.name for c in kids]


def test_names_and_corners_round_trip_over_brazil():
    rng = np.random.default_rng(7)
    lon, lat = rng.uniform(-73.9, -34.8, 400), rng.uniform(-33.7, 5.2, 400)
    n2000 = sheet_names(lon, lat, 2000)
    n5000 = sheet_names(lon, lat, 5000)
    for x, y, a, b in zip(lon, lat, n2000, n5000):
        s = sheet_from_name(a)
        assert s.west <= x < s.east and s.south <= y < s.north
        assert a.rsplit("-", 1)[0] == b                 # the 1:2,000 sheet lies in its 1:5,000 sheet
        assert sheet_at(x, y, 2000).name == a


def test_edges_belong_to_the_sheet_east_and_north():
    s = sheet_from_name("SF-23-X-D-VI-1-SE-C-II")
    assert sheet_names([s.west], [0.5 * (s.south + s.north)], 5000)[0] == s.name     # west edge: this sheet
    assert sheet_names([s.east], [0.5 * (s.south + s.north)], 5000)[0] != s.name     # east edge: the next
    assert sheet_names([0.5 * (s.west + s.east)], [s.south], 5000)[0] == s.name      # south edge: this sheet
    assert sheet_names([0.5 * (s.west + s.east)], [s.north], 5000)[0] == "SF-23-X-D-VI-1-SE-A-IV"


def test_bad_names_are_refused_naming_the_part():
    with pytest.raises(ValueError, match=r"'SZ-23': it must start with a 1:1,000,000 sheet"):
        sheet_from_name("SZ-23")
    with pytest.raises(ValueError, match=r"'G' is not a 1:10,000 symbol \(A B C D E F\)"):
        sheet_from_name("SF-23-X-D-VI-1-SE-G")
    with pytest.raises(ValueError, match=r"1:3000"):
        sheet_names([-42.0], [-21.0], 3000)
    with pytest.raises(ValueError, match=r"point 1: longitude -42\.0, latitude 88\.0 deg is outside the index"):
        sheet_names([-42.0, -42.0], [-21.0, 88.0], 5000)


def test_itaocara_control_points_get_their_1_5000_and_1_2000_sheets():
    """The report's points (SAD69 / UTM 23S) named by hand from the definition.

    AP-05 is at 42d18'47" W, 21d40'50" S (pyproj, SAD69(96)):
    SF-23 (48-42 W, 20-24 S) -> X (NE: 45-42 W, 20-22 S) -> D (SE: 43d30'-42 W, 21-22 S)
    -> VI (3rd column 42d30'-42 W, 2nd row 21d30'-22 S) -> 1 (NW: 42d30'-42d15', 21d30'-21d45')
    -> SE (42d22'30"-42d15', 21d37'30"-21d45') -> C (west column 42d22'30"-42d18'45", 2nd row
    21d40'-21d42'30") -> II (east 42d20'37.5"-42d18'45", north 21d40'-21d41'15")
    -> 6 (3rd column 42d19'22.5"-42d18'45", 2nd row 21d40'37.5"-21d41'15").
    AP-01 (42d38'04" W, 21d50'47" S): ...-D-V (2nd column) -4 (SE) -NO -F (east column, 3rd row) -II.
    """
    t = Transformer.from_crs(SAD69_96_UTM23S, "EPSG:5527", always_xy=True)
    lon, lat = t.transform(*np.array(list(ITAOCARA.values())).T)
    got5 = dict(zip(ITAOCARA, sheet_names(lon, lat, 5000).tolist()))
    got2 = dict(zip(ITAOCARA, sheet_names(lon, lat, 2000).tolist()))
    assert got5["AP-05"] == "SF-23-X-D-VI-1-SE-C-II"
    assert got2["AP-05"] == "SF-23-X-D-VI-1-SE-C-II-6"
    assert got5["AP-01"] == "SF-23-X-D-V-4-NO-F-II"
    # the survey's area (the control points' box): the sheets covering it hold every point, and every
    # point of a 100 m lattice over it lies in one of them
    area = (744000.0, 7580000.0, 799000.0, 7606000.0)
    cover = sheets_covering(area, SAD69_96_UTM23S, 5000)
    names = {s.name for s in cover}
    assert set(got5.values()) <= names
    assert all(s.geographic_crs == "EPSG:5527" for s in cover)          # the datum of the survey's CRS
    e, n = np.meshgrid(np.arange(area[0], area[2] + 1, 100.0), np.arange(area[1], area[3] + 1, 100.0))
    lon_g, lat_g = t.transform(e.ravel(), n.ravel())
    lattice = set(sheet_names(lon_g, lat_g, 5000).tolist())
    assert lattice <= names
    for s in cover:   # a sheet no lattice point falls in can only be a sliver along the edge of the area
        if s.name not in lattice:
            ring = sheet_outline(s, SAD69_96_UTM23S)
            inside = ring[(ring[:, 0] >= area[0]) & (ring[:, 0] <= area[2]) & (ring[:, 1] >= area[1])
                          & (ring[:, 1] <= area[3])]
            d = np.minimum.reduce([inside[:, 0] - area[0], area[2] - inside[:, 0], inside[:, 1] - area[1],
                                   area[3] - inside[:, 1]]) if len(inside) else np.zeros(1)
            assert d.max() < 100.0, s.name
    # about 3.2 x 2.3 km sheets: 55 km x 26 km of survey box -> 18 columns x 12 rows, give or take one
    assert 17 * 11 <= len(cover) <= 19 * 13


def test_projected_outline_is_a_densified_polygon_on_the_sheet_edges():
    s = sheet_from_name("SF-23-X-D-VI-1-SE-C-II")
    ring = sheet_outline(s, "EPSG:31983", per_edge=16)
    assert ring.shape == (65, 2) and np.all(ring[0] == ring[-1])
    area2 = np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1])
    assert area2 > 0                                                     # counter-clockwise
    lon, lat = Transformer.from_crs("EPSG:31983", "EPSG:4674", always_xy=True).transform(ring[:, 0], ring[:, 1])
    np.testing.assert_allclose(lat[:16], s.south, atol=1e-10)            # south edge stays on its parallel
    np.testing.assert_allclose(lon[16:32], s.east, atol=1e-10)           # east edge on its meridian
    # the parallel is a curve in UTM: its middle vertex leaves the chord between the corners
    a, m, b = ring[0], ring[8], ring[16]
    d, e = b - a, m - a
    off = abs(d[0] * e[1] - d[1] * e[0]) / np.hypot(*d)
    assert 1e-4 < off < 1.0


def _utm_grid(sheet_names_, crs="EPSG:31983", cell=10.0):
    """A DTM-like grid (h = E/1000) in *crs* covering the given sheets with a margin."""
    rings = np.vstack([sheet_outline(sheet_from_name(n), crs) for n in sheet_names_])
    x0, y1 = np.floor(rings.min(axis=0)[0] / cell) * cell - 50, np.ceil(rings.max(axis=0)[1] / cell) * cell + 50
    x1, y0 = rings.max(axis=0)[0] + 50, rings.min(axis=0)[1] - 50
    cols, rows = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    t = GeoTransform(float(x0), float(y1), cell)
    xc = x0 + (np.arange(cols) + 0.5) * cell
    return np.tile(xc / 1000.0, (rows, 1)), t


def test_cut_raster_geo_gives_every_cell_to_exactly_one_sheet():
    parent = "SF-23-X-D-VI-1-SE-C-II"
    kids = [f"{parent}-{k}" for k in "123456"]
    grid, t = _utm_grid([parent])
    fwd = Transformer.from_crs("EPSG:31983", "EPSG:4674", always_xy=True)
    count = np.zeros(grid.shape, int)
    for name in kids:
        s = sheet_from_name(name)
        sub, st = cut_raster(grid, t, s, "EPSG:31983")
        assert st.cell_m == t.cell_m
        r0, c0 = round((t.y0 - st.y0) / t.cell_m), round((st.x0 - t.x0) / t.cell_m)
        ok = np.isfinite(sub)
        np.testing.assert_array_equal(sub[ok], grid[r0:r0 + sub.shape[0], c0:c0 + sub.shape[1]][ok])
        count[r0:r0 + sub.shape[0], c0:c0 + sub.shape[1]] += ok
        rows, cols = np.nonzero(ok)
        lon, lat = fwd.transform(st.x0 + (cols + 0.5) * st.cell_m, st.y0 - (rows + 0.5) * st.cell_m)
        assert np.all((lon >= s.west) & (lon < s.east) & (lat >= s.south) & (lat < s.north))
    # the six 1:2,000 sheets hold each cell centre of their 1:5,000 parent exactly once
    sub, st = cut_raster_geo(grid, t, sheet_from_name(parent), "EPSG:31983")
    r0, c0 = round((t.y0 - st.y0) / t.cell_m), round((st.x0 - t.x0) / t.cell_m)
    in_parent = np.zeros(grid.shape, bool)
    in_parent[r0:r0 + sub.shape[0], c0:c0 + sub.shape[1]] = np.isfinite(sub)
    np.testing.assert_array_equal(count, in_parent.astype(int))
    with pytest.raises(ValueError, match="needs the grid's CRS"):
        cut_raster(grid, t, sheet_from_name(parent))


def test_cut_contours_geo_ends_on_the_sheet_edges():
    s = sheet_from_name("SF-23-X-D-VI-1-SE-C-II-5")
    ring = sheet_outline(s, "EPSG:31983")
    c = ring[:-1].mean(axis=0)
    rng = np.random.default_rng(1)
    xy = c + rng.uniform(-900, 900, (4000, 2))
    cone = np.column_stack([xy, 100 - 0.05 * np.hypot(*(xy - c).T)])     # rings around the sheet's centre
    feats = contour_features(contours(cone, 5.0, max_edge_m=200.0))
    back = Transformer.from_crs("EPSG:31983", "EPSG:4674", always_xy=True)
    part = cut_contours(feats, s, "EPSG:31983")
    assert part and part == cut_contours_geo(feats, s, "EPSG:31983")
    tol = 2e-8    # deg (~2 mm): the 3-decimal rounding of the output
    edge_ends = 0
    for f in part:
        xy_ = np.asarray(f["geometry"]["coordinates"])
        lon, lat = back.transform(xy_[:, 0], xy_[:, 1])
        assert np.all((lon >= s.west - tol) & (lon <= s.east + tol) & (lat >= s.south - tol) & (lat <= s.north + tol))
        for k in (0, -1):
            on = min(abs(lon[k] - s.west), abs(lon[k] - s.east), abs(lat[k] - s.south), abs(lat[k] - s.north))
            if not f["properties"]["closed"]:
                assert on < tol
                edge_ends += 1
        assert in_polygon(xy_[1:-1], ring[:-1]).all() if len(xy_) > 2 else True
    assert edge_ends > 0
    with pytest.raises(ValueError, match="needs the lines' CRS"):
        cut_contours(feats, s)


def test_index_sheets_and_index_layer():
    area = (778000.0, 7600000.0, 779000.0, 7600500.0)
    sheets = index_sheets(area, "brazil-2000", crs="EPSG:31983")
    assert sheets == sheets_covering(area, "EPSG:31983", 2000)
    feats = sheet_index_features(sheets, "EPSG:31983")
    assert [f["properties"]["name"] for f in feats] == [s.name for s in sheets]
    assert all(f["properties"]["scale"] == 2000 and len(f["geometry"]["coordinates"][0]) == 65 for f in feats)
    with pytest.raises(ValueError, match="unknown sheet index 'brazil-3000'"):
        index_sheets(area, "brazil-3000", crs="EPSG:31983")
    assert [s.name for s in index_sheets(area, "grid", size_m=1000)] == ["E778000_N7600000"]
    from lidarcat.errors import CRSError

    with pytest.raises(CRSError, match="'SIRGAS 2000 / UTM zone 23S' is not a geographic CRS"):
        sheets_covering(area, "EPSG:31983", 5000, geographic_crs="EPSG:31983")
    with pytest.raises(CRSError, match="unknown geographic CRS 'EPSG:999999'"):
        sheets_covering(area, "EPSG:31983", 5000, geographic_crs="EPSG:999999")
    in_sad69 = sheets_covering(area, "EPSG:31983", 5000, geographic_crs="EPSG:4618")    # another datum: its frame
    assert all(s.geographic_crs == "EPSG:4618" for s in in_sad69)


def test_cli_sheets_brazil_index_as_geopackage(tmp_path):
    """lidarcat lidar sheets --index brazil-2000 --layer-format gpkg: the index and the cut contours open in
    geopandas with their CRS; the DTM is cut into one GeoTIFF per sheet."""
    gpd = pytest.importorskip("geopandas")
    pytest.importorskip("rasterio")
    from lidarcat.production.contours import write_geojson
    from lidarcat.production.terrain import write_product

    parent = "SF-23-X-D-VI-1-SE-C-II"
    grid, t = _utm_grid([parent], cell=20.0)
    write_product(tmp_path / "dtm.tif", grid, t, "EPSG:31983")
    ring = sheet_outline(sheet_from_name(parent), "EPSG:31983")
    c = ring[:-1].mean(axis=0)
    xy = c + np.random.default_rng(2).uniform(-1500, 1500, (3000, 2))
    feats = contour_features(contours(np.column_stack([xy, xy[:, 0] / 100.0]), 50.0, max_edge_m=400.0,
                                               edge_peel=0))   # contours up to the data edge (the corner sheet)
    write_geojson(tmp_path / "curvas.geojson", feats, "EPSG:31983")
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / "dtm.tif"), str(tmp_path / "curvas.geojson"),
                                   "-o", str(tmp_path / "folhas"), "--index", "brazil-2000",
                                   "--layer-format", "gpkg"])
    assert res.exit_code == 0, res.output
    idx = gpd.read_file(tmp_path / "folhas" / "sheets.gpkg", layer="sheets")
    assert idx.crs.to_epsg() == 31983
    assert set(idx["name"]) >= {f"{parent}-{k}" for k in "123456"}
    assert set(idx["name"]) == {p.name for p in (tmp_path / "folhas").iterdir() if p.is_dir()}
    assert (idx["scale"] == 2000).all()
    one = gpd.read_file(tmp_path / "folhas" / f"{parent}-1" / "curvas.gpkg", layer="contours")
    assert one.crs.to_epsg() == 31983 and len(one) > 0
    assert set(one["level_m"]) <= {f["properties"]["level_m"] for f in feats}
    assert (tmp_path / "folhas" / f"{parent}-1" / "dtm.tif").is_file()
    # contours given as GeoPackage (the CRS read from the layer), cut to GeoJSON
    from lidarcat.production.contours import write_layers

    write_layers(tmp_path / "curvas.gpkg", {"contours": feats}, "EPSG:31983")
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / "curvas.gpkg"), "-o", str(tmp_path / "f3"),
                                   "--index", "brazil-5000"])
    assert res.exit_code == 0, res.output
    idx = json.loads((tmp_path / "f3" / "sheets.geojson").read_text())
    assert idx["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31983"
    assert parent in [f["properties"]["name"] for f in idx["features"]]
    cut = json.loads((tmp_path / "f3" / parent / "curvas.geojson").read_text())["features"]
    assert cut and cut == cut_contours(feats, sheet_from_name(parent), "EPSG:31983")
    # no CRS anywhere: the Brazilian index cannot be placed
    write_geojson(tmp_path / "nocrs.geojson", feats, None)
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / "nocrs.geojson"), "-o",
                                   str(tmp_path / "f2"), "--index", "brazil-5000"])
    assert res.exit_code == 2 and "needs the products' CRS: give --crs" in res.output


@pytest.mark.parametrize("name, text, args, message", [
    ("bad.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, '
                    '"geometry": {"type": "LineString", "coordinates": [[1, 2], [3]]}}]}', [],
     "bad.geojson: feature 0: not a 2-D LineString (coordinates must be two or more [E, N] pairs of finite numbers)"),
    ("nan.geojson", '{"type": "FeatureCollection", "features": [{"type": "Point"}, {"type": "Feature", '
                    '"properties": {}, "geometry": {"type": "LineString", "coordinates": [[1, 2], [NaN, 4]]}}]}', [],
     "nan.geojson: feature 1: not a 2-D LineString"),
    ("empty.tif", "", [], "empty.tif: not a readable GeoTIFF ("),
    ("c.geojson", None, ["--size-m", "-5"], "Error: Invalid value for '--size-m': -5.0 is not in the range x>0."),
    ("c.geojson", None, ["--height-m", "nan"], "Error: Invalid value for '--height-m': nan is not a finite number."),
    ("c.geojson", None, ["--index", "brazil-5000", "--crs", "EPSG:4326"],
     "Error: point 0: longitude 744000.0"),  # E, N taken for degrees: outside the index
])
def test_cli_sheets_bad_products_and_sizes_are_one_line_errors(tmp_path, name, text, args, message):
    """A malformed line, an unreadable GeoTIFF, a bad sheet size or a wrong --crs: exit 2, no traceback, no output."""
    from lidarcat.production.contours import write_geojson

    if text is None:
        write_geojson(tmp_path / name, [{"type": "Feature", "properties": {"level_m": 1.0},
                                         "geometry": {"type": "LineString",
                                                      "coordinates": [[744000.0, 7580000.0], [744500.0, 7580400.0]]}}],
                      "EPSG:31983")
    else:
        (tmp_path / name).write_text(text)
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / name), "-o", str(tmp_path / "out"), *args])
    assert res.exit_code == 2 and message in res.output, res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert not (tmp_path / "out").exists()


def test_sheet_grid_refuses_a_size_that_is_not_positive_and_finite():
    from lidarcat.production.sheets import sheet_grid

    for w, h in ((0.0, None), (100.0, -1.0), (math.inf, None), (100.0, math.nan)):
        with pytest.raises(ValueError, match=r"sheet size must be positive and finite, got "):
            sheet_grid((0, 0, 10, 10), w, h)


def test_cli_sheets_failing_midway_leaves_no_folder(tmp_path, monkeypatch):
    """The sheets and the index are written into a temporary sibling: a full disk at the index leaves nothing."""
    import errno

    import lidarcat.production.contours as contours_mod

    feats = [{"type": "Feature", "properties": {"level_m": 1.0},
              "geometry": {"type": "LineString", "coordinates": [[744000.0, 7580000.0], [746500.0, 7580400.0]]}}]
    contours_mod.write_geojson(tmp_path / "c.geojson", feats, "EPSG:31983")
    real = contours_mod.write_layers

    def full_disk_at_the_index(path, layers, crs):
        if "sheets" in layers:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(path, layers, crs)

    monkeypatch.setattr(contours_mod, "write_layers", full_disk_at_the_index)
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / "c.geojson"), "-o", str(tmp_path / "out"),
                                   "--size-m", "1000"])
    # issue 24: one Error line naming the file (it was an escaping OSError, a traceback)
    assert res.exit_code == 2, res.output
    assert res.output == f"Error: {tmp_path / 'out' / 'sheets.geojson'}: No space left on device\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.geojson"]  # no out/, no .out.*.part
    monkeypatch.setattr(contours_mod, "write_layers", real)
    res = CliRunner().invoke(cli, ["lidar", "sheets", str(tmp_path / "c.geojson"), "-o", str(tmp_path / "out"),
                                   "--size-m", "1000"])
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["E744000_N7580000", "E745000_N7580000",
                                                                   "E746000_N7580000", "sheets.geojson"]
