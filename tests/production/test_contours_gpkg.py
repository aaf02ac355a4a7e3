"""Contours and spot heights as GeoPackage (optional ``gis`` extra): layers, levels and CRS as GIS tools read them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import LIDAR_DATA
from lidarcat.cli.main import cli
from lidarcat.errors import CRSError
from lidarcat.production.contours import contours, spot_heights, write_contours, write_layers

gpd = pytest.importorskip("geopandas")
pyogrio = pytest.importorskip("pyogrio")


def _cone():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-10, 10, (2000, 2))
    return np.column_stack([xy + [500000.0, 7500000.0], 10 - np.hypot(*xy.T)])


def test_contours_geopackage_has_both_layers_levels_and_crs(tmp_path):
    cone = _cone()
    cs = contours(cone, 2.0, master_every=2)
    spots = spot_heights(cone, 5.0)
    out = write_contours(tmp_path / "curvas.gpkg", cs, spots, "EPSG:31983")
    assert out == [tmp_path / "curvas.gpkg"]
    assert [list(x) for x in pyogrio.list_layers(out[0])] == [["contours", "LineString"], ["spot_heights", "Point"]]
    lines = gpd.read_file(out[0], layer="contours")
    assert lines.crs.to_epsg() == 31983
    assert lines["level_m"].tolist() == [c.level_m for c in cs]
    assert lines["type"].tolist() == ["master" if c.master else "intermediate" for c in cs]
    assert lines["closed"].tolist() == [c.closed for c in cs]
    for geom, c in zip(lines.geometry, cs):       # vertices as written (3 decimals), closed rings closed
        np.testing.assert_allclose(np.asarray(geom.coords), np.round(c.xy, 3), atol=1e-9)
        assert geom.is_valid and geom.is_simple
    pts = gpd.read_file(out[0], layer="spot_heights")
    assert pts.crs.to_epsg() == 31983 and len(pts) == len(spots)
    np.testing.assert_allclose(pts["h_m"], np.round(spots[:, 2], 3))
    assert sorted(set(pts["kind"])) == ["high", "low"]
    assert not list(tmp_path.glob(".*part*"))                           # nothing left half-written


def test_geojson_output_is_unchanged_and_bad_suffix_or_missing_crs_refused(tmp_path):
    cone = _cone()
    cs = contours(cone, 2.0)
    out = write_contours(tmp_path / "c.geojson", cs, spot_heights(cone, 5.0), "EPSG:31983")
    assert out == [tmp_path / "c.geojson", tmp_path / "c_spots.geojson"]
    assert json.loads(out[0].read_text())["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31983"
    with pytest.raises(ValueError, match=r"c\.shp: contour output must end in \.geojson, \.json, \.gpkg"):
        write_contours(tmp_path / "c.shp", cs, np.zeros((0, 4)), "EPSG:31983")
    with pytest.raises(CRSError, match=r"c\.gpkg: a GeoPackage needs the CRS"):
        write_contours(tmp_path / "c.gpkg", cs, np.zeros((0, 4)), None)
    with pytest.raises(ValueError, match="a GeoJSON file holds one layer, got 2"):
        write_layers(tmp_path / "x.geojson", {"a": [], "b": []}, "EPSG:31983")


def test_cli_contours_to_geopackage_on_ahn3(tmp_path):
    """lidarcat lidar contours TILE -o curvas.gpkg: AHN3's class 2 contoured, levels on the 1 m interval,
    master every 5th, CRS EPSG:7415's horizontal part (RD New, 28992) readable by geopandas."""
    res = CliRunner().invoke(cli, ["lidar", "contours", str(LIDAR_DATA / "ahn3_cropped_2.laz"), "-o",
                                   str(tmp_path / "curvas.gpkg"), "--crs", "EPSG:7415", "--spots-m", "50"])
    assert res.exit_code == 0, res.output
    lines = gpd.read_file(tmp_path / "curvas.gpkg", layer="contours")
    assert len(lines) > 0
    assert lines.crs is not None and lines.crs.equals(gpd.read_file(tmp_path / "curvas.gpkg", layer="spot_heights").crs)
    assert "Amersfoort / RD New" in lines.crs.to_wkt()
    lv = lines["level_m"].to_numpy()
    np.testing.assert_allclose(lv, np.round(lv))                        # 1 m interval from 0
    np.testing.assert_array_equal(lines["type"] == "master", np.round(lv) % 5 == 0)
    assert (tmp_path / "curvas.gpkg").is_file() and not (tmp_path / "curvas_spots.gpkg").exists()
    res = CliRunner().invoke(cli, ["lidar", "contours", str(LIDAR_DATA / "ahn3_cropped_2.laz"), "-o",
                                   str(tmp_path / "curvas.dxf"), "--crs", "EPSG:7415"])
    assert res.exit_code == 2 and "give a file ending in .geojson, .json, .gpkg" in res.output


def test_read_line_layer_round_trips_and_refuses_a_file_without_lines(tmp_path):
    from lidarcat.errors import FormatError
    from lidarcat.production.contours import contour_features, read_line_layer, spot_features

    cone = _cone()
    feats = contour_features(contours(cone, 2.0, master_every=2))
    write_layers(tmp_path / "c.gpkg", {"spot_heights": spot_features(spot_heights(cone, 5.0)), "contours": feats},
                 "EPSG:31983")
    got, crs = read_line_layer(tmp_path / "c.gpkg")
    assert crs.to_epsg() == 31983 and got == feats                      # the contours layer, exactly
    write_layers(tmp_path / "p.gpkg", {"spot_heights": spot_features(spot_heights(cone, 5.0))}, "EPSG:31983")
    with pytest.raises(FormatError, match=r"p\.gpkg: no LineString layer \(layers: spot_heights\)"):
        read_line_layer(tmp_path / "p.gpkg")
    (tmp_path / "bad.geojson").write_text("{not json")
    with pytest.raises(FormatError, match=r"bad\.geojson: not a readable GeoJSON FeatureCollection"):
        read_line_layer(tmp_path / "bad.geojson")
