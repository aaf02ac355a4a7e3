"""Prediction of LiDAR vertices in photos: the propagated ellipse, visibility, roof edges (issue 29 step 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.control.vertices import extract_roof
from lidarcat.geometry.camera import Camera
from lidarcat.photocontrol.predict import frame_distance_sigma
from lidarcat.photocontrol import (ellipse_axes, occluded, pixel_jacobians, pixel_positions, predict_edges,
                                   predict_points, roof_edges)
from lidarcat.synthetic.aerial import aerial_camera
from lidarcat.synthetic.roofs import synthetic_roof

EO = np.array([1000.0, 2000.0, 400.0, math.radians(1.0), math.radians(-2.0), math.radians(30.0)])


def test_jacobians_match_finite_differences_of_the_projection_with_distortion():
    cam = aerial_camera((1000, 750))
    x = np.array([[1010.0, 2005.0, 12.0], [985.0, 1990.0, 3.0]])
    jp, jx = pixel_jacobians(cam, EO, x)
    for k, h in ((0, 0.05), (4, 2e-5)):
        eo2 = EO.copy()
        eo2[k] += h
        num = (pixel_positions(cam, eo2, x) - pixel_positions(cam, EO, x)) / h
        np.testing.assert_allclose(jp[:, :, k], num, rtol=2e-3)
    x2 = x.copy()
    x2[:, 2] += 0.05
    np.testing.assert_allclose(jx[:, :, 2], (pixel_positions(cam, EO, x2) - pixel_positions(cam, EO, x)) / 0.05,
                               rtol=2e-3)


def test_ellipse_is_the_covariance_of_monte_carlo_projections():
    """Propagated covariance vs the scatter of 4000 projections with drawn orientation and vertex errors."""
    cam = aerial_camera((1000, 750))
    x = np.array([1012.0, 2008.0, 10.0])
    eo_cov = np.diag([2.0**2, 2.0**2, 2.0**2] + [math.radians(0.5) ** 2] * 3)
    x_cov = np.diag([0.02**2, 0.03**2, 0.05**2])
    pr = predict_points(cam, EO, eo_cov, x[None], x_cov[None], points=["V1"], photo="P1")[0]
    assert pr.status == "visible" and pr.point == "V1" and pr.photo == "P1"
    rng = np.random.default_rng(3)
    eos = EO + rng.multivariate_normal(np.zeros(6), eo_cov, 4000)
    xs = x + rng.multivariate_normal(np.zeros(3), x_cov, 4000)
    px = pixel_positions(cam, eos, xs)
    emp = np.cov(px.T)
    # 4000 draws: the sample variances within ~5 % (3 sigma of sqrt(2/n)), plus the curvature
    np.testing.assert_allclose(np.diag(pr.cov_px2), np.diag(emp), rtol=0.08)
    np.testing.assert_allclose(pr.px, px.mean(axis=0), atol=0.1 * math.sqrt(emp[0, 0]))
    a, b, _ = ellipse_axes(pr.cov_px2)
    assert a >= b > 0 and a == pytest.approx(pr.sd_max_px)


def test_outside_behind_and_margin_are_reported_with_reasons():
    cam = Camera("c", 35.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.036, 0.036, 1000, 750)
    eo = [0.0, 0.0, 200.0, 0.0, 0.0, 0.0]
    pts = np.array([[0.0, 0.0, 0.0], [150.0, 0.0, 0.0], [0.0, 0.0, 300.0], [99.0, 0.0, 0.0]])
    pr = predict_points(cam, eo, np.zeros(6), pts, np.zeros((4, 3, 3)), margin_px=20)
    assert [p.status for p in pr] == ["visible", "outside", "behind", "outside"]
    assert pr[1].reason.startswith("predicted at column") and "off the 1000 x 750 frame" in pr[1].reason
    assert pr[3].reason.endswith("less a 20 px margin")   # 99 m off = column 986.7: inside, but within the margin
    assert not pr[1] and pr[0]


def test_a_wall_between_vertex_and_camera_occludes_it():
    def dsm(e, n):
        e = np.asarray(e, dtype=float)
        return np.where((e > 5.0) & (e < 6.0), 30.0, 0.0)   # a 30 m wall 5-6 m east of the vertex

    x = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 10.0]])
    hidden = occluded(dsm, x[:1], [100.0, 0.0, 110.0])       # camera to the east, 45 deg up: the ray at 15 m
    seen = occluded(dsm, x[1:], [-100.0, 0.0, 110.0])       # camera to the west
    assert hidden.tolist() == [True] and seen.tolist() == [False]
    nan = occluded(lambda e, n: np.full(np.shape(e), np.nan), x[:1], [100.0, 0.0, 110.0])
    assert nan.tolist() == [False]


def test_roof_edges_of_a_hip_end_are_the_ridge_and_two_hips():
    s = synthetic_roof("hip", length_m=14, width_m=9, slope_deg=30, azimuth_deg=17, density_m2=12, noise_h_m=0.02,
                       seed=5)
    v = s.vertices[0]
    cp = extract_roof(s.xyz, v[:2], radius_m=8)
    assert cp.status == "ok" and cp.n_planes == 3
    edges = roof_edges(cp.enh_m, cp.planes, s.xyz)
    assert len(edges) == 3
    dirs = np.array([(e.end_m - e.start_m) / e.length_m for e in edges])
    # the ridge: horizontal, along the building axis (azimuth 17 deg) into the roof
    ridge = dirs[np.argmin(np.abs(dirs[:, 2]))]
    axis = np.array([math.cos(math.radians(17)), math.sin(math.radians(17))])
    assert abs(ridge[2]) < 0.02
    assert abs(abs(float(ridge[:2] @ axis)) - 1.0) < 0.01
    toward_centre = (s.vertices[1][:2] - v[:2]) / np.linalg.norm(s.vertices[1][:2] - v[:2])
    assert float(ridge[:2] @ toward_centre) > 0.99
    # the hips run down (slope of a hip on 30 deg faces: atan(tan 30 / sqrt 2) = 22.2 deg)
    hips = [d for d in dirs if d[2] < -0.1]
    assert len(hips) == 2
    for d in hips:
        assert math.degrees(math.asin(-d[2])) == pytest.approx(22.2, abs=1.5)
    segs = predict_edges(aerial_camera(), [v[0], v[1], v[2] + 150.0, 0, 0, 0], np.zeros(6), edges, cp.cov_m2)
    assert len(segs) == 3 and all(np.isfinite(sg["px1"]).all() for sg in segs)


def test_off_frame_prediction_is_a_candidate_while_its_search_ellipse_reaches_the_frame():
    cam = Camera("c", 35.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.036, 0.036, 1000, 750)
    eo = [0.0, 0.0, 200.0, 0.0, 0.0, 0.0]
    # 1 m of X0 sd = 35 / 200 / 0.036 = 4.861 px; the frame's right side, column 999.5, is 102.86 m
    pts = np.array([[105.0, 0.0, 0.0], [150.0, 0.0, 0.0]])                       # 10.4 px and 229.2 px off
    sd = np.r_[4.0, 0.001, 0.001, 0, 0, 0]                                       # 19.4 px along the columns
    pr = predict_points(cam, eo, sd, pts, np.zeros((2, 3, 3)), search_sigma=3.5)
    assert [p.status for p in pr] == ["visible", "outside"]
    assert pr[0].reason.startswith("predicted at column 1009.9, row 374.5: off the 1000 x 750 frame, 0.5 sigma "
                                   "away: within its 3.5-sigma ellipse"), pr[0].reason
    assert pr[1].reason == "predicted at column 1228.7, row 374.5: off the 1000 x 750 frame"
    # the default (search_sigma 0): the predicted pixel alone
    assert [p.status for p in predict_points(cam, eo, sd, pts, np.zeros((2, 3, 3)))] == ["outside", "outside"]
    # the Mahalanobis distance to the frame with a tilted ellipse: the nearest point of the side, by hand
    cov = np.array([[100.0, 60.0], [60.0, 100.0]])
    w = np.linalg.inv(cov)
    ys = np.linspace(-0.5, 749.5, 75001)
    d = np.zeros((len(ys), 2))                                                   # frame point minus prediction
    d[:, 0] = 999.5 - 1009.5
    d[:, 1] = ys - 300.0
    want = math.sqrt(np.min(np.einsum("ni,ij,nj->n", d, w, d)))
    got = frame_distance_sigma([[1009.5, 300.0]], [cov], (-0.5, 999.5), (-0.5, 749.5))[0]
    assert got == pytest.approx(want, abs=1e-4)


def test_an_undefined_ellipse_off_the_frame_is_outside_not_an_error():
    """A vertex covariance that is not finite (NaN from an upstream fit) made frame_distance_sigma's pinv fail
    ("SVD did not converge") on a real AHN3 block: such a prediction off the frame is outside, one inside stays
    visible, and the rest of the batch is unaffected."""
    cam = Camera("c", 35.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.036, 0.036, 1000, 750)
    eo = [0.0, 0.0, 200.0, 0.0, 0.0, 0.0]
    pts = np.array([[105.0, 0.0, 0.0], [105.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    xc = np.zeros((3, 3, 3))
    xc[1] = np.nan
    xc[2] = np.nan
    sd = np.r_[4.0, 0.001, 0.001, 0, 0, 0]
    pr = predict_points(cam, eo, sd, pts, xc, search_sigma=3.5)
    assert [p.status for p in pr] == ["visible", "outside", "visible"]
    assert np.isinf(frame_distance_sigma([[1009.9, 374.5]], [np.full((2, 2), np.nan)], (-0.5, 999.5),
                                         (-0.5, 749.5))[0])
