"""Vertices near the frame: predicted off it but truly inside, truly outside, at the border (issue 29).

A rendered photo (:mod:`lidarcat.synthetic.aerial`, as in test_measure.py) is cropped on one
side (the principal point moved with it) so that a LiDAR vertex lies a chosen
number of pixels inside (or outside) the new frame, on a side two of its roof edges do not point to;
the approximate orientation is the true one moved in X0, Y0 so that the vertex is predicted 44 px
further out (with the 2 m / 0.5 deg covariance of ``EO_COV`` its sd is ~20 px: bench seed 6's
vertex C0003 on photo 202 was predicted 15 px off the frame and was 29 px inside).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from lidarcat.control.vertices import extract_roof
from lidarcat.photocontrol import MeasureParams, measure_vertex, pixel_jacobians, predict_points, roof_edges
from lidarcat.photocontrol.predict import frame_distance_sigma
from lidarcat.synthetic.aerial import aerial_survey

EO_COV = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
#: the frame-edge handling (MeasureParams.border 'fit', predict_points' search_sigma 3.5)
FIT = MeasureParams(border="fit")
#: inward direction (column, row) of the four sides of the frame
SIDES = {"left": (1.0, 0.0), "right": (-1.0, 0.0), "top": (0.0, 1.0), "bottom": (0.0, -1.0)}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    import cv2

    s = aerial_survey(tmp_path_factory.mktemp("edge") / "s", n_strips=1, photos_per_strip=2, gsd_m=0.1,
                      image_size_px=(1200, 900), lidar_density_m2=0, n_gps_points=0, seed=0, supersample=4)
    sc = s.scene
    rng = np.random.default_rng(1)
    cam = s.camera
    W, H = cam.columns_px, cam.rows_px
    for k, pid in enumerate(s.photo_ids):
        img = cv2.imread(str(s.image_paths()[pid]), cv2.IMREAD_UNCHANGED)
        eo = s.true_eo[k]
        for b, bld in enumerate(sc.buildings):
            for v in bld.vertices(sc.base_height(b)):
                c = s.project(pid, v[None])[0]
                if not (80 < c[0] < W - 80 and 80 < c[1] < H - 80):
                    continue
                e, n = v[0] + rng.uniform(-9, 9, 3900), v[1] + rng.uniform(-9, 9, 3900)
                xyz = np.column_stack([e, n, sc.surface(e, n)[0] + rng.normal(0, 0.03, len(e))])
                cp = extract_roof(xyz, v[:2] + rng.normal(0, 0.3, 2))
                if not cp:
                    continue
                ends = s.project(pid, np.array([ed.end_m for ed in roof_edges(cp.enh_m, cp.planes, xyz)]))
                u = (ends - c) / np.linalg.norm(ends - c, axis=1)[:, None]
                pos = {"left": c[0], "right": W - 1 - c[0], "top": c[1], "bottom": H - 1 - c[1]}
                for side, inward in SIDES.items():
                    # a near side (the principal point stays on the cropped frame), two of its edges not
                    # pointing to it (the others are cut by the border)
                    dim = W if side in ("left", "right") else H
                    if pos[side] > dim / 2 - 100 or int(np.sum(u @ np.array(inward) > -0.2)) < 2:
                        continue
                    # measurable on the whole photo from the same approximate orientation: only the frame differs
                    approx = _approx_eo(cam, eo, v, side, 44.0)
                    pr = predict_points(cam, approx, EO_COV, cp.enh_m[None], cp.cov_m2[None], search_sigma=3.5)[0]
                    m = measure_vertex(img, cam, approx, cp.enh_m, cp.planes, xyz, pr, FIT)
                    if m and float(np.hypot(*(np.asarray(m.px) - c))) < 1.0:
                        return s, k, img, v, cp, xyz, c, side
    pytest.fail("no vertex measurable on the whole photo with two edges not pointing to a side of the frame")


def _cropped(s, img, c, side, inside_px):
    """Camera, image and the vertex's true pixel with the frame cut *inside_px* from the vertex on *side*.

    Cutting ``d`` columns off the left moves the frame's centre ``d / 2`` px right: the principal
    point (from the centre, x right, y up) moves ``d / 2`` px left; the pixels keep their photo
    coordinates."""
    cam = s.camera
    W, H = cam.columns_px, cam.rows_px
    pos = {"left": c[0], "right": W - 1 - c[0], "top": c[1], "bottom": H - 1 - c[1]}[side]
    d = int(round(pos - inside_px))
    half = {"left": -0.5, "right": 0.5, "top": 0.5, "bottom": -0.5}[side] * d
    if side in ("left", "right"):
        cam2 = replace(cam, columns_px=W - d, principal_point_x_mm=cam.principal_point_x_mm + half * cam.pixel_size_x_mm)
    else:
        cam2 = replace(cam, rows_px=H - d, principal_point_y_mm=cam.principal_point_y_mm + half * cam.pixel_size_y_mm)
    img2 = {"left": img[:, d:], "right": img[:, :W - d], "top": img[d:], "bottom": img[:H - d]}[side]
    shift = {"left": (d, 0.0), "right": (0.0, 0.0), "top": (0.0, d), "bottom": (0.0, 0.0)}[side]
    return cam2, np.ascontiguousarray(img2), c - np.array(shift)


def _approx_eo(cam, eo, v, side, out_px):
    """The true orientation moved in X0, Y0 so that *v* is predicted *out_px* further out of *side*."""
    jp, _ = pixel_jacobians(cam, eo, v[None])
    want = -out_px * np.array(SIDES[side])
    delta = np.linalg.solve(jp[0][:, :2], want)
    return np.asarray(eo, dtype=np.float64) + np.r_[delta, 0, 0, 0, 0]


def test_a_vertex_predicted_off_the_frame_but_inside_is_measured_within_a_pixel(scene):
    s, k, img, v, cp, xyz, c, side = scene
    cam, img2, truth = _cropped(s, img, c, side, 29)
    eo = s.true_eo[k]
    # the crop keeps the principal point: the true vertex projects 29 px inside the new frame
    np.testing.assert_allclose(predict_points(cam, eo, EO_COV, v[None], np.zeros((1, 3, 3)))[0].px, truth,
                               atol=1e-6)
    approx = _approx_eo(cam, eo, v, side, 44.0)
    pr = predict_points(cam, approx, EO_COV, cp.enh_m[None], cp.cov_m2[None], points=["V"], photo="p", search_sigma=3.5)[0]
    assert not cam.contains(pr.px[None])[0]                      # predicted off the frame ...
    assert pr.status == "visible" and "within its 3.5-sigma ellipse" in pr.reason, pr.reason   # ... a candidate
    m = measure_vertex(img2, cam, approx, cp.enh_m, cp.planes, xyz, pr, FIT)
    assert m.status == "measured", m.reason
    assert float(np.hypot(*(np.asarray(m.px) - truth))) < 1.0


def test_a_vertex_truly_outside_stays_outside_with_the_reason(scene):
    s, k, img, v, cp, xyz, c, side = scene
    cam, _, truth = _cropped(s, img, c, side, -60)
    approx = _approx_eo(cam, s.true_eo[k], v, side, 60.0)
    pr = predict_points(cam, approx, EO_COV, cp.enh_m[None], cp.cov_m2[None], points=["V"], photo="p", search_sigma=3.5)[0]
    assert pr.sd_max_px < 120 / 3.6                              # 120 px off is more than 3.5 sd
    assert pr.status == "outside" and not pr
    assert pr.reason == f"predicted at column {pr.px[0]:.1f}, row {pr.px[1]:.1f}: off the {cam.columns_px} x " \
                        f"{cam.rows_px} frame"
    assert frame_distance_sigma(pr.px[None], pr.cov_px2[None], (-0.5, cam.columns_px - 0.5),
                                (-0.5, cam.rows_px - 0.5))[0] > 3.5


def test_a_vertex_at_the_border_is_not_measured_and_says_why(scene):
    s, k, img, v, cp, xyz, c, side = scene
    cam, img2, truth = _cropped(s, img, c, side, 3)
    approx = _approx_eo(cam, s.true_eo[k], v, side, 10.0)
    pr = predict_points(cam, approx, EO_COV, cp.enh_m[None], cp.cov_m2[None], points=["V"], photo="p", search_sigma=3.5)[0]
    assert pr.status == "visible"
    m = measure_vertex(img2, cam, approx, cp.enh_m, cp.planes, xyz, pr, FIT)
    # the search is clipped to the photo 8 px inside: the vertex, 3 px inside, is not found there, and what is
    # found there is no vertex (its edges do not fit): nothing measured at a wrong place
    assert m.status in ("near_border", "no_edges", "weak_geometry"), (m.status, m.reason)
    assert m.reason


def test_the_default_keeps_the_edges_rule_off_frame_predictions_outside(scene):
    s, k, img, v, cp, xyz, c, side = scene
    cam, img2, truth = _cropped(s, img, c, side, 29)
    approx = _approx_eo(cam, s.true_eo[k], v, side, 44.0)
    pr = predict_points(cam, approx, EO_COV, cp.enh_m[None], cp.cov_m2[None], points=["V"], photo="p")[0]
    assert pr.status == "outside"                                # the predicted pixel alone
    near = _approx_eo(cam, s.true_eo[k], v, side, 0.0)           # predicted right, 29 px inside
    pr = predict_points(cam, near, EO_COV, cp.enh_m[None], cp.cov_m2[None], points=["V"], photo="p")[0]
    m = measure_vertex(img2, cam, near, cp.enh_m, cp.planes, xyz, pr)
    assert m.status == "near_border" and m.reason.endswith("reach past the photo's border"), m.reason
    with pytest.raises(ValueError, match="border must be 'edges' or 'fit'"):
        measure_vertex(img2, cam, near, cp.enh_m, cp.planes, xyz, pr, MeasureParams(border="clip"))
