"""GIS layer set of the adjusted thesis block: opens in GeoPandas/pyogrio with the survey CRS;
footprints, ellipses and discrepancies checked against their definitions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarcat.geometry.collinearity import project
from lidarcat.survey import adjust_survey
from lidarcat.errors import FormatError
from lidarcat.interop import gis
from lidarcat.interop.gis import LAYER_NAMES, gis_layers, write_gis
from lidarcat.survey.folder import Survey

gpd = pytest.importorskip("geopandas")
pyogrio = pytest.importorskip("pyogrio")


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    out = tmp_path_factory.mktemp("adj") / "gps"
    adjust_survey(None, outdir=out)
    return out


def test_geopackage_layers_open_with_crs(tmp_path, adjusted):
    layers, crs, hs = gis_layers(None, adjusted)
    write_gis(layers, crs, tmp_path / "g", fmt="gpkg")
    gpkg = tmp_path / "g" / "block.gpkg"
    assert [n for n, _ in pyogrio.list_layers(gpkg)] == list(LAYER_NAMES)
    for name in LAYER_NAMES:
        df = gpd.read_file(gpkg, layer=name)
        assert df.crs.to_epsg() == 29192, name
    pts = gpd.read_file(gpkg, layer="object_points")
    assert len(pts) == 54 and set(pts.role) == {"control", "check", "tie"}
    assert set(pts.height_system) == {"orthometric"}
    assert len(gpd.read_file(gpkg, layer="check_discrepancies")) == 13
    assert len(gpd.read_file(gpkg, layer="residual_vectors")) == 8


def test_geojson_fallback(tmp_path, adjusted, monkeypatch):
    monkeypatch.setattr(gis, "_have_pyogrio", lambda: False)
    layers, crs, _ = gis_layers(None, adjusted)
    write_gis(layers, crs, tmp_path / "j")
    files = sorted(p.name for p in (tmp_path / "j").iterdir())
    assert files == sorted(f"block_{n}.geojson" for n in LAYER_NAMES)
    df = gpd.read_file(tmp_path / "j" / "block_photo_centres.geojson")
    assert df.crs.to_epsg() == 29192 and len(df) == 6
    with pytest.raises(FormatError, match="GeoPackage output needs pyogrio"):
        write_gis(layers, crs, tmp_path / "k", fmt="gpkg")


def test_footprints_project_to_the_image_corners(adjusted):
    layers, _, _ = gis_layers(None, adjusted)
    lay = {x.name: x for x in layers}
    s = Survey.load()
    cam = s.cameras["dcs14n"]
    eo = np.array([[*lay["photo_centres"].fields[k]] for k in ("X0", "Y0", "Z0")]).T
    ang = np.radians(np.array([lay["photo_centres"].fields[k] for k in ("omega_deg", "phi_deg", "kappa_deg")]).T)
    h = lay["footprints"].fields["plane_h_m"][0]
    want = np.asarray(cam.pixel_to_photo([[-0.5, -0.5], [2999.5, -0.5], [2999.5, 4499.5], [-0.5, 4499.5]]))
    for i, ring in enumerate(lay["footprints"].geoms):
        xyz = np.column_stack([ring[:4], np.full(4, h)])
        xy, _ = project(np.tile(np.concatenate([eo[i], ang[i]]), (4, 1)), xyz, np.full(4, cam.focal_length_mm))
        np.testing.assert_allclose(xy, want, rtol=0, atol=1e-9)


def test_ellipses_and_discrepancies(adjusted):
    layers, _, _ = gis_layers(None, adjusted, ellipse_scale=100.0, vector_scale=10.0)
    lay = {x.name: x for x in layers}
    pts = lay["object_points"].fields
    ell = lay["error_ellipses"]
    for i, ring in enumerate(ell.geoms):
        if not ell.fields["correlated"][i]:  # axis-aligned: semi-axes are the sds
            assert sorted([ell.fields["semi_major_m"][i], ell.fields["semi_minor_m"][i]]) == pytest.approx(
                sorted([pts["sd_E"][i], pts["sd_N"][i]]), rel=1e-12)
        x, y = ring[:-1, 0], ring[:-1, 1]
        area = 0.5 * abs(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1)))
        a, b = ell.fields["semi_major_m"][i] * 100, ell.fields["semi_minor_m"][i] * 100
        assert area == pytest.approx(np.pi * a * b, rel=2e-3)  # 72-gon inscribed in the ellipse
    assert sum(ell.fields["correlated"]) == 13  # the check points: full covariance from check_covariance.csv
    s = Survey.load()
    d = lay["check_discrepancies"]
    for q, de, dn, dh, line in zip(d.fields["point"], d.fields["dE_m"], d.fields["dN_m"], d.fields["dh_m"], d.geoms):
        k = pts["point"].index(q)
        ref = s.ground_points.enh_m[s.ground_points.index(q)][0]
        assert [de, dn, dh] == pytest.approx([pts["E"][k] - ref[0], pts["N"][k] - ref[1], pts["h"][k] - ref[2]], abs=1e-12)
        np.testing.assert_allclose(line[1] - line[0], [10 * de, 10 * dn], atol=1e-9)


def test_local_frame_refused(tmp_path):
    from lidarcat.interop.block import write_survey
    from lidarcat.interop.colmap import read_colmap

    d = Path(__file__).parents[1] / "data" / "interop" / "colmap" / "kapture_maupertuis"
    write_survey(read_colmap(d), tmp_path / "s", control_sd_m=0.01)
    res, out = adjust_survey(tmp_path / "s", outdir=tmp_path / "a")
    with pytest.raises(FormatError, match="is no CRS pyproj knows .* GIS layers need a georeferenced block"):
        gis_layers(tmp_path / "s", out)
