"""A vertex whose edges found lie on one image line: located along it where the line bends (measure step 3a).

Synthetic truth, no rendering: a photo split by two roof edges meeting at the vertex from either side at a
bend of a few degrees (two faces of different grey), plus two crossing edges between faces of the same grey
(predicted from the LiDAR, invisible in the photo) -- the case of bench_measured_control seed 6, C0003 on
photo 203.  The edge fits and the intersection are :func:`lidarcat.photocontrol.measure._refine`'s, fed the
predicted edges directly.
"""

from __future__ import annotations

import math
import re
from types import SimpleNamespace

import numpy as np
import pytest

from lidarcat.photocontrol.measure import Measurement, MeasureParams, _refine

VERTEX = np.array([100.3, 99.6])   # true vertex (col, row px)
SIZE = 200


def unit(deg: float) -> np.ndarray:
    return np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])


def _photo(a1_deg: float, a2_deg: float, seed: int = 3) -> np.ndarray:
    """Grey 80 in the wedge from direction a1 counter-clockwise to a2 about VERTEX, 150 elsewhere; 4 x 4
    supersampled, blurred 0.7 px, noise sd 2 grey levels."""
    from scipy.ndimage import gaussian_filter

    ss = 4
    g = (np.arange(SIZE * ss) + 0.5) / ss - 0.5
    cc, rr = np.meshgrid(g, g)
    ang = np.degrees(np.arctan2(rr - VERTEX[1], cc - VERTEX[0]))
    inside = np.mod(ang - a1_deg, 360.0) < np.mod(a2_deg - a1_deg, 360.0)
    hi = np.where(inside, 80.0, 150.0).reshape(SIZE, ss, SIZE, ss).mean(axis=(1, 3))
    img = gaussian_filter(hi, 0.7) + np.random.default_rng(seed).normal(0.0, 2.0, hi.shape)
    return img.astype(np.float32)


def refine_context(dirs_deg: list[float], start: np.ndarray, p: MeasureParams,
                   planes=((2, 3), (0, 1), (0, 3), (1, 2))) -> dict:
    """_refine's context: the predicted edges from the (shifted) vertex, 50 px long, of the plane pairs
    *planes* (also used by test_measure_weak_edge)."""
    units = np.array([unit(d) for d in dirs_deg])
    t0s = []
    for k, u in enumerate(units):
        sin_min = min((abs(u[0] * o[1] - u[1] * o[0]) if u @ o > 0 else 1.0) for j, o in enumerate(units) if j != k)
        t0s.append(max(4.0, (p.band_px + 1.5) / max(sin_min, 0.2)))
    base = Measurement("V1", "P1", np.full(2, np.nan), np.full((2, 2), np.nan), "not_visible",
                       predicted_px=start, predicted_cov_px2=np.eye(2) * 400.0)
    edges = [SimpleNamespace(planes=pl) for pl in planes][:len(dirs_deg)]
    return dict(base=base, edges=edges, units=units, lens=np.full(len(dirs_deg), 50.0), t0s=t0s, vpx=start,
                size=(SIZE, SIZE), m_edge=60)


def _measure(bend_deg: float, start_off=(1.2, -0.8), p: MeasureParams | None = None) -> Measurement:
    """The vertex with its two visible edges at 30 deg and 210 - bend deg (the bend: 180 deg would be one
    straight line), two invisible crossing edges at 115 and 300 deg; searched from VERTEX + start_off."""
    p = p or MeasureParams()
    a1, a2 = 30.0, 210.0 - bend_deg
    img = _photo(a1, a2)
    start = VERTEX + np.asarray(start_off)
    ctx = refine_context([a1, a2, 115.0, 300.0], start, p)
    m = _refine(img, ctx, np.zeros(2), p)
    if m:   # again from the vertex found, as measure_photo does
        m2 = _refine(img, ctx, np.asarray(m.px) - start, p)
        m = m2 if m2 else m
    return m


@pytest.mark.parametrize("bend", [12.0, 6.0])
def test_a_vertex_on_one_bent_line_is_located_along_it_within_its_sd(bend):
    m = _measure(bend)
    assert m.status == "measured", m.reason
    assert m.along_line
    assert any(m.reason.startswith(f"located along one edge: the edges of planes {a} and {b} lie nearly on one "
                                   f"image line, their intersection at {bend:.0f} deg: sd ")
               for a, b in (("3-4", "1-2"), ("1-2", "3-4"))), m.reason
    assert " px across the edge, " in m.reason and " px along it" in m.reason
    cov = np.asarray(m.cov_px2)
    w, v = np.linalg.eigh(cov)
    # elongated along the line (the bisector of the two edge directions), tight across it
    along = unit(30.0 - bend / 2.0)
    assert abs(float(v[:, 1] @ along)) > math.cos(math.radians(2.0))
    assert math.sqrt(w[1]) > 3.0 * math.sqrt(w[0])
    assert math.sqrt(w[0]) < 0.4
    # the two lines' offsets (sd 0.1-0.3 px each) over sin(bend): the larger the bend, the tighter along
    assert 0.1 < math.sqrt(w[1]) * math.sin(math.radians(bend)) < 0.5
    e = np.asarray(m.px) - VERTEX
    assert float(e @ np.linalg.solve(cov, e)) < 13.8    # chi2(2) 99.9 %
    assert abs(float(e @ v[:, 0])) < 0.3                # across the line: a fraction of a pixel
    # written without correlation: both sds are the along-line sd; its two edges go beside it
    assert np.allclose(m.sd_px, math.sqrt(w[1]))
    assert {el.planes for el in m.edge_lines} == {(2, 3), (0, 1)}


def test_a_straight_line_leaves_the_vertex_unlocated_with_the_reason():
    m = _measure(0.5)
    assert m.status == "weak_geometry"
    assert not m.along_line and not np.isfinite(m.px).any()
    # the angle is the fitted lines' (the predicted 0.5 deg, the fits' directions within a fraction of it)
    assert re.match(r"the edges found lie on one image line: the edges on either side of the vertex meet at "
                    r"[01]\.\d deg \(< 2\): not located along the line \(", m.reason), m.reason
    # the strong edge is still a line observation
    assert len(m.edge_lines) == 1


def test_a_bend_too_small_for_the_sd_limit_is_weak_geometry():
    m = _measure(6.0, p=MeasureParams(along_max_sd_px=1.0))
    assert m.status == "weak_geometry"
    assert "meet at 6 deg: along the line to " in m.reason and "px only (> 1)" in m.reason, m.reason


def test_switched_off_the_old_outcome_stays():
    m = _measure(12.0, p=MeasureParams(along_max_sd_px=0.0))
    assert m.status == "weak_geometry"
    assert m.reason.startswith("the edges found lie on one image line"), m.reason


def test_two_lines_at_a_small_angle_give_the_closed_form_covariance():
    """var across = v1, var along = (v2 + v1 cos^2 b) / sin^2 b, cov = -v1 cos b / sin b (measure step 3a)."""
    from lidarcat.photocontrol._along import intersect_lines

    b = math.radians(12.0)
    m1, m2 = np.array([0.0, 1.0]), np.array([-math.sin(b), math.cos(b)])
    x_true = np.array([3.0, -2.0])
    # no fit covariance: each line's offset variance is sd^2 + (texture / ratio)^2
    fits = [(np.array([1.0, 0.0]), (None, None, None, 4.0)), (np.array([-1.0, 0.0]), (None, None, None, 8.0))]
    covs = [(np.zeros((2, 2)), 0.0), (np.zeros((2, 2)), 0.0)]
    x, n_mat, chi2 = intersect_lines(fits, np.array([m1, m2]), np.array([m1 @ x_true, m2 @ x_true]), covs,
                                     np.zeros(2), 0.1, 1.0)
    v1, v2 = 0.1**2 + (1.0 / 4.0) ** 2, 0.1**2 + (1.0 / 8.0) ** 2
    c = np.linalg.inv(n_mat)
    d = np.array([1.0, 0.0])
    assert np.allclose(x, x_true) and chi2 < 1e-12
    assert math.isclose(m1 @ c @ m1, v1, rel_tol=1e-6)
    assert math.isclose(d @ c @ d, (v2 + v1 * math.cos(b) ** 2) / math.sin(b) ** 2, rel_tol=1e-6)
    assert math.isclose(abs(m1 @ c @ d), v1 * math.cos(b) / math.sin(b), rel_tol=1e-6)


def test_a_fed_back_along_one_edge_point_is_not_taken_for_its_edges_fits(tmp_path):
    """decisions.csv fed back: an accepted point "located along one edge" may stand beside its written edges
    (stages._control_review tells it from a point intersected from its edges, which may not)."""
    from lidarcat.stages._control_review import read_decisions

    p = tmp_path / "decisions.csv"
    p.write_text("photo,point,status,reason,col_px,row_px,sd_col_px,sd_row_px,decision\n"
                 "101,C1,measured,\"located along one edge: the edges of planes 3-4 and 1-2 lie nearly on one image "
                 "line, their intersection at 12 deg: sd 0.26 px across the edge, 1.79 px along it\","
                 "604.8,637.5,1.8,1.8,accept\n"
                 "101,C2,measured,,624.9,459.4,0.5,0.27,accept\n")
    survey = SimpleNamespace(photo_ids=["101"], ground_points=SimpleNamespace(point=np.array(["C1", "C2"])))
    rows = read_decisions(p, survey)
    assert [(d["point"], d["status"], d["accept"]) for d in rows] == [("C1", "measured_along", True),
                                                                       ("C2", "measured", True)]
