"""Contour verification over sparse ground (report 13.2), its profile, filled bands and 3-D lines."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.production.contourcheck import (
    contour_bands,
    contour_features_3d,
    sparse_stretches,
    stretch_features,
    stretch_profile,
    write_profile_png,
)
from lidarcat.production.contours import contours, tin_mask


def _terrain(x, y):
    return 100 + 0.05 * x + 3 * np.sin(y / 40)


@pytest.fixture(scope="module")
def wood():
    """120 x 120 m of ground at 2 pts/m2 with a 40 x 40 m wood where 1 in 16 pulses reaches the ground."""
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 120, (28800, 2))
    inside = (np.abs(xy[:, 0] - 60) < 20) & (np.abs(xy[:, 1] - 60) < 20)
    keep = ~inside | (rng.uniform(size=len(xy)) < 1 / 16)
    g = np.column_stack([xy[keep], _terrain(*xy[keep].T)])
    canopy = xy[inside & ~keep][:400]
    veg = np.column_stack([canopy, _terrain(*canopy.T) + rng.uniform(2, 15, len(canopy))])
    return g, veg


def _length_in_box(cs, lo, hi):
    total = 0.0
    for c in cs:
        m = np.all((c.xy > lo) & (c.xy < hi), axis=1)
        total += np.hypot(*np.diff(c.xy, axis=0).T)[m[1:] & m[:-1]].sum()
    return total


def test_stretches_over_the_wood_are_flagged_and_little_else(wood):
    g, _ = wood
    cs = contours(g, 0.5)
    st, thr = sparse_stretches(cs, g)
    # median TIN edge at 2 pts/m2 is about 0.78 m: the default threshold 3 x that
    assert 2.0 < thr < 2.8
    in_wood = sum(s.length_m for s in st if np.all((s.xy > 37) & (s.xy < 83)))
    flagged = sum(s.length_m for s in st)
    assert in_wood >= 0.9 * _length_in_box(cs, 40, 80)
    total = sum(np.hypot(*np.diff(c.xy, axis=0).T).sum() for c in cs)
    outside = total - _length_in_box(cs, 37, 83)
    assert flagged - in_wood < 0.01 * outside
    f = stretch_features(st)
    assert f[0]["properties"]["review"] is True and f[0]["geometry"]["type"] == "LineString"
    assert {x["properties"]["level_m"] for x in f} <= {c.level_m for c in cs}


def test_even_ground_has_no_sparse_stretch_above_a_threshold(wood):
    g, _ = wood
    even = g[~((np.abs(g[:, 0] - 60) < 22) & (np.abs(g[:, 1] - 60) < 22))]
    cs = contours(even, 0.5)
    st, _ = sparse_stretches(cs, even, sparse_edge_m=3.0)
    # the hole left by removing the wood is sparse ground; elsewhere (a sliver at the hull) under 1 m in all
    assert sum(s.length_m for s in st if np.all((s.xy > 35) & (s.xy < 85))) > 100
    assert sum(s.length_m for s in st if not np.all((s.xy > 35) & (s.xy < 85))) < 1.0


def test_profile_crosses_the_contour_at_its_level(wood, tmp_path):
    g, veg = wood
    cs = contours(g, 0.5)
    st, _ = sparse_stretches(cs, g, min_length_m=5.0)
    s = max(st, key=lambda x: x.length_m)
    pts = np.vstack([g, veg])
    gm = np.r_[np.ones(len(g), bool), np.zeros(len(veg), bool)]
    prof = stretch_profile(s, pts, gm, corridor_m=2.0)
    mid = len(prof.tin_height_m) // 2
    assert prof.tin_distance_m[mid] == pytest.approx(prof.crossing_m)
    assert prof.tin_height_m[mid] == pytest.approx(s.level_m, abs=1e-6)   # the contour lies on the TIN
    assert prof.ground.any() and (~prof.ground).any()
    out = write_profile_png(tmp_path / "p.png", prof)
    import matplotlib.image

    assert matplotlib.image.imread(out).shape[2] in (3, 4)


def test_bands_tile_the_contoured_tin_and_hold_holes():
    rng = np.random.default_rng(2)
    xy = rng.uniform(-50, 50, (6000, 2))
    g = np.column_stack([xy, 120 - 0.2 * np.hypot(*xy.T)])      # a cone: every band but the top is a ring
    bands = contour_bands(g, 2.0, edge_peel=3)
    import matplotlib.tri as mtri

    t = mtri.Triangulation(*(xy - xy.min(axis=0)).T)
    keep = ~tin_mask(xy - xy.min(axis=0), t.triangles, 50.0, 3)
    p = xy[t.triangles[keep]]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum()
    assert sum(b["properties"]["area_m2"] for b in bands) == pytest.approx(area, rel=1e-6)
    assert [b["properties"]["upper_m"] for b in bands] == sorted(b["properties"]["upper_m"] for b in bands)
    rings = [len(poly) for b in bands for poly in b["geometry"]["coordinates"]]
    assert max(rings) == 2 and rings.count(1) >= 1       # annuli have one hole; the top band has none


def test_3d_lines_and_geopackage_types(tmp_path, wood):
    pyogrio = pytest.importorskip("pyogrio")
    from lidarcat.production.contours import write_layers

    g, _ = wood
    cs = contours(g, 1.0)
    f3 = contour_features_3d(cs)
    c0 = np.asarray(f3[0]["geometry"]["coordinates"])
    assert c0.shape[1] == 3 and np.all(c0[:, 2] == cs[0].level_m)
    bands = contour_bands(g, 1.0)
    path = write_layers(tmp_path / "c.gpkg", {"contours": f3, "contour_bands": bands}, "EPSG:31983")
    info = pyogrio.read_info(path, layer="contours")
    assert info["geometry_type"] == "LineString Z" and info["crs"] == "EPSG:31983"
    assert info["features"] == len(cs)
    assert pyogrio.read_info(path, layer="contour_bands")["geometry_type"] == "MultiPolygon"


def test_contours_command_review_profiles_polygons_3d(tmp_path):
    """AHN3 tile 2 (EPSG:7415): GeoJSON outputs beside the contours, and the refusal for a DTM raster."""
    import json
    from pathlib import Path

    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    tile = Path(__file__).resolve().parents[1] / "data" / "lidar" / "ahn3_cropped_2.laz"
    out = tmp_path / "c.geojson"
    res = CliRunner().invoke(cli, ["lidar", "contours", str(tile), "--crs", "EPSG:7415", "-o", str(out),
                                   "--interval-m", "0.5", "--review", "--profiles", "1", "--polygons", "--3d"])
    assert res.exit_code == 0, res.output
    review = json.loads((tmp_path / "c_review.geojson").read_text())
    assert review["crs"]["properties"]["name"].endswith("7415") and review["features"]
    assert all(f["properties"]["review"] for f in review["features"])
    bands = json.loads((tmp_path / "c_bands.geojson").read_text())
    assert {f["geometry"]["type"] for f in bands["features"]} == {"MultiPolygon"}
    lines = json.loads(out.read_text())["features"]
    assert all(len(v) == 3 and v[2] == f["properties"]["level_m"] for f in lines for v in f["geometry"]["coordinates"])
    assert len(list((tmp_path / "c_profiles").glob("*.png"))) == 1
    dtm = tmp_path / "dtm.tif"
    from lidarcat.lidar.geotiff import GeoTransform, write_geotiff

    write_geotiff(dtm, np.zeros((4, 4), np.float32), GeoTransform(0, 4, 1), "EPSG:7415")
    res = CliRunner().invoke(cli, ["lidar", "contours", str(dtm), "-o", str(tmp_path / "d.geojson"), "--review"])
    assert res.exit_code != 0 and "--review and --polygons need the ground points" in res.output
