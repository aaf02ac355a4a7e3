"""Contours from the ground TIN: vertices on the TIN at their level, closed rings, valid lines, GeoJSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.lidar import read_points
from lidarcat.production.contours import contour_features, contours, spot_features, spot_heights, write_geojson
from lidarcat.production.ground import smrf_ground
from lidarcat.production.terrain import tin_heights

from pathlib import Path

AHN2 = Path(__file__).parents[1] / "data" / "lidar" / "ahn3_cropped_2.laz"


def _segments_cross(xy: np.ndarray) -> bool:
    """Any two non-adjacent segments of a polyline properly intersect (vectorised)."""
    a, b = xy[:-1], xy[1:]
    n = len(a)
    i, j = np.triu_indices(n, 2)
    closed = np.all(xy[0] == xy[-1])
    keep = ~(closed & (i == 0) & (j == n - 1))
    i, j = i[keep], j[keep]

    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))
    d1 = orient(a[i], b[i], a[j])
    d2 = orient(a[i], b[i], b[j])
    d3 = orient(a[j], b[j], a[i])
    d4 = orient(a[j], b[j], b[i])
    return bool(np.any((d1 * d2 < 0) & (d3 * d4 < 0)))


def test_ahn3_contours_lie_on_the_tin_at_their_level(tmp_path):
    pc = read_points(AHN2, crs="EPSG:7415")
    a = pc.attributes
    g = smrf_ground(pc.xyz, a["return_number"], a["number_of_returns"])
    ground = pc.xyz[g]
    ground = ground[(ground[:, 0] < 85040) & (ground[:, 1] < 447480)]   # a 40 m x 68 m crop keeps it quick
    cs = contours(ground, 0.5, master_every=5, max_edge_m=None)
    assert len(cs) > 5
    xy = np.vstack([c.xy for c in cs])
    lev = np.concatenate([np.full(len(c.xy), c.level_m) for c in cs])
    h = tin_heights(ground, xy)
    ok = np.isfinite(h)
    assert ok.mean() > 0.999
    assert np.max(np.abs(h[ok] - lev[ok])) < 0.05           # within 0.05 m of the level on the TIN
    for c in cs:
        assert c.closed == bool(np.all(c.xy[0] == c.xy[-1]))
        assert c.master == (round(c.level_m / 0.5) % 5 == 0)
        assert not _segments_cross(c.xy)
    p = write_geojson(tmp_path / "c.geojson", contour_features(cs), "EPSG:7415")
    fc = json.loads(p.read_text())
    assert fc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::7415"
    assert len(fc["features"]) == len(cs) and fc["features"][0]["geometry"]["type"] == "LineString"


def test_smoothing_keeps_rings_closed_and_ends_fixed():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-10, 10, (3000, 2))
    hill = np.column_stack([xy, 10 - np.hypot(*xy.T) + 0.2 * xy[:, 0]])
    plain = contours(hill, 1.0)
    smooth = contours(hill, 1.0, smooth_iterations=2)
    assert len(plain) == len(smooth)
    for p, s in zip(plain, smooth):
        assert s.closed == p.closed
        if s.closed:
            assert np.all(s.xy[0] == s.xy[-1])
        else:
            np.testing.assert_array_equal(s.xy[[0, -1]], p.xy[[0, -1]])
    with pytest.raises(ValueError, match="interval_m must be positive"):
        contours(hill, 0.0)


def test_spot_heights_highest_and_lowest_per_square():
    pts = np.array([[1, 1, 5.0], [2, 2, 9.0], [3, 3, 1.0], [150, 1, 4.0]])
    s = spot_heights(pts, 100.0)
    highs = s[s[:, 3] == 1]
    lows = s[s[:, 3] == 0]
    assert sorted(highs[:, 2].tolist()) == [4.0, 9.0] and sorted(lows[:, 2].tolist()) == [1.0, 4.0]
    f = spot_features(s)
    assert f[0]["geometry"]["type"] == "Point" and {"h_m", "kind"} <= set(f[0]["properties"])
