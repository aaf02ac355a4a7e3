"""Delivery formats (production.delivery): TFW world files, Shapefile layers, DXF layers of Figure 27."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import ProductError
from lidarcat.lidar.geotiff import GeoTransform, write_geotiff
from lidarcat.production.contours import contour_features, contours, spot_features, spot_heights
from lidarcat.production.delivery import write_dxf, write_shapefile, write_world_file
from lidarcat.production.sheets import sheet_grid, sheet_index_features

CRS = "EPSG:31983"


@pytest.fixture(scope="module")
def layers():
    rng = np.random.default_rng(2)
    x = rng.uniform(500_000, 500_400, 3000)
    y = rng.uniform(7_500_000, 7_500_300, 3000)
    g = np.column_stack([x, y, 100 + 8 * np.sin((x - 500_000) / 80) + 0.01 * (y - 7_500_000)])
    return contour_features(contours(g, 1.0, master_every=5)), spot_heights(g, 100.0)


def test_world_file_agrees_with_the_geotiff_transform(tmp_path):
    import rasterio

    write_geotiff(tmp_path / "dtm.tif", np.arange(12.0).reshape(3, 4), GeoTransform(680000.0, 7184000.0, 0.45), CRS)
    tfw = write_world_file(tmp_path / "dtm.tif")
    assert tfw.name == "dtm.tfw"
    a, d, b, e, c, f = map(float, tfw.read_text().split())
    with rasterio.open(tmp_path / "dtm.tif") as ds:
        # the centre of pixel (col 2, row 1) by the world file and by rasterio
        assert (a * 2 + b * 1 + c, d * 2 + e * 1 + f) == pytest.approx(ds.xy(1, 2), abs=1e-9)
    assert (a, d, b, e) == (0.45, 0.0, 0.0, -0.45) and c == pytest.approx(680000.225)


def test_shapefile_layers_read_back_with_crs_and_fields(layers, tmp_path):
    import pyogrio

    feats, spots = layers
    write_shapefile(tmp_path / "curvas.shp", feats, CRS)
    write_shapefile(tmp_path / "pontos.shp", spot_features(spots), CRS)
    assert sorted(p.suffix for p in tmp_path.glob("curvas.*")) == [".cpg", ".dbf", ".prj", ".shp", ".shx"]
    df = pyogrio.read_dataframe(tmp_path / "curvas.shp")
    assert len(df) == len(feats) and df.crs.to_epsg() == 31983
    assert sorted(set(df["type"])) == ["intermediate", "master"]
    np.testing.assert_allclose(df["level_m"], [f["properties"]["level_m"] for f in feats])
    pts = pyogrio.read_dataframe(tmp_path / "pontos.shp")
    np.testing.assert_allclose(pts["h_m"], spots[:, 2], atol=1e-3)
    with pytest.raises(ProductError, match=r"empty\.shp: no feature to write; an empty Shapefile is not written"):
        write_shapefile(tmp_path / "empty.shp", [], CRS)
    assert not list(tmp_path.glob("empty.*"))


def test_dxf_layers_follow_the_conventions_and_keep_heights(layers, tmp_path):
    ezdxf = pytest.importorskip("ezdxf")
    feats, spots = layers
    sheets = sheet_index_features(sheet_grid((500_000, 7_500_000, 500_400, 7_500_300), 200), CRS)
    write_dxf(tmp_path / "c.dxf", contours=feats, spots=spots, sheets=sheets,
              area=(500_000, 7_500_000, 500_400, 7_500_300))
    doc = ezdxf.readfile(tmp_path / "c.dxf")
    msp = doc.modelspace()
    names = {lay.dxf.name for lay in doc.layers}
    assert {"Curvas Mestras", "Curvas Intermediárias", "Pontos Cotados", "Cotas", "Prancha",
            "Limite de Restituição"} <= names
    assert doc.layers.get("Curvas Mestras").dxf.color == 30
    assert doc.layers.get("Limite de Restituição").dxf.color == 1
    master = msp.query('LWPOLYLINE[layer=="Curvas Mestras"]')
    inter = msp.query('LWPOLYLINE[layer=="Curvas Intermediárias"]')
    n_master = sum(f["properties"]["type"] == "master" for f in feats)
    assert len(master) == n_master and len(inter) == len(feats) - n_master
    assert sorted({e.dxf.elevation for e in master}) == sorted(
        {f["properties"]["level_m"] for f in feats if f["properties"]["type"] == "master"})
    assert all(e.dxf.elevation % 5 == 0 for e in master)
    pts = msp.query('POINT[layer=="Pontos Cotados"]')
    np.testing.assert_allclose(sorted(p.dxf.location.z for p in pts), sorted(spots[:, 2]))
    assert len(msp.query('TEXT[layer=="Cotas"]')) == len(spots)
    assert len(msp.query('LWPOLYLINE[layer=="Prancha"]')) == len(sheets) == 4


def test_dxf_of_nothing_is_refused(tmp_path):
    pytest.importorskip("ezdxf")
    with pytest.raises(ProductError, match=r"empty\.dxf: nothing to draw \(no contour, spot height, sheet or "
                                           r"area\); an empty DXF is not written"):
        write_dxf(tmp_path / "empty.dxf", contours=[], spots=np.zeros((0, 4)))
    assert not (tmp_path / "empty.dxf").exists()


def test_deliver_command(layers, tmp_path):
    pytest.importorskip("ezdxf")
    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.production.contours import write_geojson

    feats, spots = layers
    write_geojson(tmp_path / "curvas.geojson", feats, CRS)
    write_geojson(tmp_path / "pontos.geojson", spot_features(spots), CRS)
    write_geotiff(tmp_path / "dtm.tif", np.ones((3, 4)), GeoTransform(500000.0, 7500300.0, 1.0), CRS)
    r = CliRunner().invoke(cli, ["deliver", str(tmp_path / "dtm.tif"), str(tmp_path / "curvas.geojson"),
                                 str(tmp_path / "pontos.geojson"), "-o", str(tmp_path / "out"), "--format", "tfw",
                                 "--format", "shp", "--format", "dxf"])
    assert r.exit_code == 0, r.output
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == sorted(["dtm.tif", "dtm.tfw", "products.dxf"] + [f"{s}.{x}" for s in ("curvas", "pontos")
                                                                    for x in ("shp", "shx", "dbf", "prj", "cpg")])
    (tmp_path / "empty.geojson").write_text('{"type": "FeatureCollection", "features": []}')
    r = CliRunner().invoke(cli, ["deliver", str(tmp_path / "empty.geojson"), "-o", str(tmp_path / "bad"),
                                 "--format", "dxf", "--crs", CRS])
    assert r.exit_code == 2 and "products.dxf: nothing to draw" in r.output
    assert not (tmp_path / "bad").exists()


@pytest.mark.parametrize("text,message", [
    ('{"type": "FeatureCollection", "features": ' + "[" * 100 + "]" * 100 + "}",
     "pontos.geojson:1: arrays/objects nested deeper than 64 levels (column 106)"),
    ('[1, 2]', "pontos.geojson: not a GeoJSON FeatureCollection (no 'features' list)"),
    ('{"features": [{"geometry": {"type": "Point", "coordinates": [1, "x"]}}]}',
     "pontos.geojson: feature 0: a Point needs coordinates [E, N] or [E, N, h] of finite numbers within 1e9 m"),
    ('{"features": [{"geometry": {"type": "Point", "coordinates": [1, 2]}, "properties": {"h_m": "high"}}]}',
     "pontos.geojson: feature 0: property 'h_m' is not a finite number: 'high'"),
])
def test_deliver_refuses_a_broken_spot_layer_by_location(tmp_path, text, message):
    """A mutated spot-height layer (the command fuzz run found a RecursionError on deep nesting) is one
    located error, and nothing is delivered."""
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    (tmp_path / "pontos.geojson").write_text(text)
    r = CliRunner().invoke(cli, ["deliver", str(tmp_path / "pontos.geojson"), "-o", str(tmp_path / "out"),
                                 "--format", "shp", "--crs", CRS])
    assert r.exit_code == 2, r.output
    assert message in r.output
    assert not (tmp_path / "out").exists()


def test_deliver_command_and_the_stage_run_one_action(layers, tmp_path, monkeypatch):
    """``lidarcat deliver`` calls the action of ``[products] delivery`` (stages.products.deliver), whose
    in-memory layers and product files give the same Shapefile."""
    import pyogrio
    from click.testing import CliRunner

    import lidarcat.stages.products as sp
    from lidarcat.cli.main import cli
    from lidarcat.production.contours import write_geojson

    feats, _ = layers
    write_geojson(tmp_path / "contours.geojson", feats, CRS)
    (tmp_path / "mem").mkdir()
    out = sp.deliver(tmp_path / "mem", ["shp"], layers={"contours": feats}, crs=CRS)
    assert out["files"] == [f"shp/contours.{x}" for x in ("cpg", "dbf", "prj", "shp", "shx")]
    calls = []
    action = sp.deliver
    monkeypatch.setattr(sp, "deliver", lambda *a, **k: calls.append(k) or action(*a, **k))
    r = CliRunner().invoke(cli, ["deliver", str(tmp_path / "contours.geojson"), "-o", str(tmp_path / "out"),
                                 "--format", "shp"])
    assert r.exit_code == 0, r.output
    assert len(calls) == 1 and calls[0]["products"] == [tmp_path / "contours.geojson"]
    a = pyogrio.read_dataframe(tmp_path / "mem" / "shp" / "contours.shp")
    b = pyogrio.read_dataframe(tmp_path / "out" / "contours.shp")
    assert a.sort_index(axis=1).equals(b.sort_index(axis=1)) and len(a) == len(feats)
