"""``--find`` near the search area's edge: a candidate's clips hold all its points (:mod:`lidarcat.control.search`).

Known truth: a pyramid with faces that sag (``k u^2``, as in tests/control/test_stability.py), 24 m square, its
apex 1 m inside the east edge of the searched area.  The radius-stability check extracts the vertex again from
clips of up to 1.5 x 8 = 12 m about it; the search used to read only ``radius_m`` = 8 m beyond the area
(``search_points``; the CLI only the area), so the 10 and 12 m clips lost the roof's points 9-12 m east of the
apex and the check tested other clips than ``extract --at`` there would.  Now every clip the search cuts holds
every point of the cloud within its radius, and the seed's verdict (status and reason, with the moves and their
Mahalanobis distances) is exactly that of :func:`~lidarcat.control.vertices.extract_roof` on the whole cloud.
With the local refit of the vertex (``fit_radius_m``, the default) the roof is accepted; without it, refused.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import lidarcat.control.vertices as vertices
from lidarcat.control.params import get_params
from lidarcat.control.search import find_candidates_tiles, search_area
from lidarcat.control.vertices import extract_roof, find_candidates, search_margin_m

APEX = np.array([1000.0, 2000.0, 10.0])
# cells of 20 m; the apex 1 m inside the east edge
AREA = (APEX[0] - 39.0, APEX[1] - 20.0, APEX[0] + 1.0, APEX[1] + 20.0)


def _sagging_pyramid(seed: int = 1, k: float = 0.004, half_m: float = 12.0, density_m2: float = 8.0):
    rng = np.random.default_rng(seed)
    m = int(density_m2 * (2 * half_m) ** 2)
    e, n = rng.uniform(-half_m, half_m, (2, m))
    u = np.maximum(np.abs(e), np.abs(n))
    h = APEX[2] - np.tan(np.radians(35.0)) * u - k * u * u + rng.normal(0.0, 0.02, m)
    return np.column_stack([e + APEX[0], n + APEX[1], h])


class _Spy:
    """Records every extract_roof call of the search: its points, position and params, and its result."""

    def __init__(self, monkeypatch):
        self.calls: list = []
        self._orig = vertices.extract_roof

        def spy(points, center_en, **kw):
            cp = self._orig(points, center_en, **kw)
            self.calls.append((np.asarray(points), np.asarray(center_en, dtype=float)[:2], kw, cp))
            return cp

        monkeypatch.setattr(vertices, "extract_roof", spy)

    def near_apex(self):
        """(check clips about the apex: (points, at, radius), the seeds' calls near the apex: (at, result))."""
        checks, seeds = [], []
        for pts, at, kw, cp in self.calls:
            if np.hypot(*(at - APEX[:2])) > 1.0:
                continue
            p = kw.get("params")
            if p is not None and not p.stability_scales:  # a check clip (the check runs with the check off)
                checks.append((pts, at, p.radius_m))
            else:
                seeds.append((at, cp))
        return checks, seeds


def _assert_whole(checks, xyz):
    radii = sorted({r for _, _, r in checks})
    assert radii == [4.0, 5.0, 6.0, 10.0, 12.0]    # 0.5, 0.625, 0.75, 1.25, 1.5 x 8 m
    for pts, at, r in checks:
        got = int(np.sum(np.sum((pts[:, :2] - at) ** 2, axis=1) <= r * r))
        assert got == int(np.sum(np.sum((xyz[:, :2] - at) ** 2, axis=1) <= r * r)), r


def _assert_verdict_of_whole_cloud(seeds, xyz, params=None):
    assert seeds
    for at, cp in seeds:
        whole = extract_roof(xyz, at, params=params)
        assert (cp.status, cp.reason) == (whole.status, whole.reason)
        np.testing.assert_array_equal(cp.enh_m, whole.enh_m)
    return {cp.status for _, cp in seeds}


def test_margin_covers_the_check():
    p = get_params()
    assert search_margin_m(p, 20.0) == 14.0  # 8 m x 1.5 + 1 m (vertex to seed) + 1 m
    assert search_margin_m(p.replace(stability_scales=()), 20.0) == 13.0  # as before the check
    assert search_margin_m(p.replace(radius_m=10.0), 20.0) == 17.0
    # the local extraction's largest clip (lidarcat.control.localfit.LADDER: 1.6 x fit_radius_m) about the vertex
    assert search_margin_m(p.replace(fit_radius_m=10.0, stability_scales=()), 20.0) == 18.0
    assert search_area(AREA) == (AREA[0] - 14, AREA[1] - 14, AREA[2] + 14, AREA[3] + 14)


@pytest.mark.parametrize("local", [True, False])
def test_a_candidate_at_the_area_edge_is_checked_with_all_its_points(monkeypatch, local):
    """Default (local refit of the vertex, ``fit_radius_m``), and the search clip's vertex: the sagging
    roof's vertex then moves with the clip and is refused, the reason (moves, distances) exactly --at's."""
    xyz = _sagging_pyramid()
    p = get_params() if local else get_params().replace(fit_radius_m=None)
    spy = _Spy(monkeypatch)
    find_candidates(xyz, box=AREA, params=p)
    checks, seeds = spy.near_apex()
    _assert_whole(checks, xyz)
    statuses = _assert_verdict_of_whole_cloud(seeds, xyz, p)
    if not local:
        assert "unstable" in statuses


def test_tiles_serial_and_blocks_read_beyond_the_area(monkeypatch, tmp_path):
    """The CLI's serial read (the area plus the margin) and the blocks give the same whole clips."""
    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.lidar import PointCloud, TileIndex, write_points

    xyz = _sagging_pyramid()
    tile = tmp_path / "t.las"
    write_points(str(tile), PointCloud(xyz, crs="EPSG:25832"))
    index = TileIndex.build([str(tile)])
    spy = _Spy(monkeypatch)
    got = find_candidates_tiles(index, AREA, block_cells=1, work_dir=tmp_path / "blocks")
    checks, seeds = spy.near_apex()
    # the points as written (LAS scale 1 mm)
    whole = np.asarray(index.query_box(AREA[0] - 50, AREA[1] - 50, AREA[2] + 50, AREA[3] + 50).xyz)
    _assert_whole(checks, whole)
    _assert_verdict_of_whole_cloud(seeds, whole)
    spy.calls.clear()
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", str(tile), "--box", *(str(v) for v in AREA),
                                 "--json"])
    assert r.exit_code == 0, r.output
    checks, seeds = spy.near_apex()
    _assert_whole(checks, whole)
    _assert_verdict_of_whole_cloud(seeds, whole)
    assert len(json.loads(r.output)["candidates"]) == len(got)
