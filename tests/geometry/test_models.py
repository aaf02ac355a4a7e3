"""Camera models (frame, Brown, fisheye): round trips, Jacobians, pycolmap's projection, conversions, bad input."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lidarcat.errors import CameraError
from lidarcat.geometry.camera import Camera
from lidarcat.geometry.conversion import (convert, exact_conversion, from_colmap, from_metashape,
                                          image_plane_observations, to_colmap, to_metashape)
from lidarcat.geometry.models import BrownCamera, FisheyeCamera, FrameModel, camera_model

pycolmap = pytest.importorskip("pycolmap")

THESIS_LIKE = Camera("dcs", 28.0, 0.05, -0.03, -1.2e-4, 2e-7, -1e-10, 3e-6, -2e-6, 0.0, 0.009, 0.009, 3000, 2000)


def _brown() -> BrownCamera:
    return BrownCamera("b", 4000, 3000, fx=3200.0, fy=3190.0, cx=2010.0, cy=1490.0, k1=-0.12, k2=0.09,
                       k3=-0.02, k4=0.003, p1=1e-3, p2=-5e-4, skew=0.5)


def _fisheye() -> FisheyeCamera:
    return FisheyeCamera("f", 1280, 1024, fx=500.0, fy=501.0, cx=640.0, cy=510.0, k1=0.02, k2=-0.01, k3=0.003,
                         k4=-0.0005)


MODELS = {
    "frame": lambda: FrameModel(THESIS_LIKE),
    "frame-refraction": lambda: FrameModel(Camera("r", 28.0, 0.05, -0.03, -1.2e-4, 2e-7, 0.0, 3e-6, -2e-6, 1e-4,
                                                  0.009, 0.009, 3000, 2000)),
    "brown": _brown,
    "fisheye": _fisheye,
}


@pytest.mark.parametrize("name", MODELS)
def test_round_trip_over_the_image_is_below_1e9_px(name):
    cam = MODELS[name]()
    px = cam.grid_px(41)
    rays = cam.unproject(px)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-14)
    assert np.abs(cam.project(rays) - px).max() <= 1e-9


@pytest.mark.parametrize("name", MODELS)
def test_jacobians_match_finite_differences(name):
    cam = MODELS[name]()
    rays = cam.unproject(cam.grid_px(7)) * np.linspace(2.0, 50.0, 49)[:, None]
    rays = np.vstack([rays, [[0.0, 0.0, 3.0]]])  # the optical axis (fisheye limit)
    px, j_ray, j_par = cam.project_jacobians(rays)
    np.testing.assert_allclose(px, cam.project(rays), atol=1e-9)
    for k in range(3):
        h = 1e-6 * np.abs(rays).max(axis=1)
        d = np.zeros_like(rays)
        d[:, k] = h
        fd = (cam.project(rays + d) - cam.project(rays - d)) / (2 * h[:, None])
        np.testing.assert_allclose(j_ray[:, :, k], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())
    p0 = cam.params()
    for k, name_k in enumerate(cam.PARAMETERS):
        h = 1e-6 * max(abs(p0[k]), 1e-3 if name_k[0] in "kp" else 1.0)
        if isinstance(cam, FrameModel) and name_k[0] in "kp":
            h = 1e-4 * max(abs(p0[k]), 1e-9)
        up, dn = p0.copy(), p0.copy()
        up[k] += h
        dn[k] -= h
        fd = (cam.with_params(up).project(rays) - cam.with_params(dn).project(rays)) / (2 * h)
        np.testing.assert_allclose(j_par[:, :, k], fd, rtol=1e-5, atol=1e-6 * max(np.abs(fd).max(), 1e-9),
                                   err_msg=name_k)


# ---------------------------------------------------------------- against pycolmap
COLMAP_CASES = [
    ("SIMPLE_RADIAL", 4000, 3000, [3100.0, 2000.5, 1500.5, -0.08]),
    ("RADIAL", 4000, 3000, [3100.0, 2000.5, 1500.5, -0.08, 0.02]),
    ("OPENCV", 4000, 3000, [3200.0, 3190.0, 2010.0, 1490.0, -0.12, 0.09, 1e-3, -5e-4]),
    ("FULL_OPENCV", 4000, 3000, [3200.0, 3190.0, 2010.0, 1490.0, -0.12, 0.09, 1e-3, -5e-4, -0.02, 0.0, 0.0, 0.0]),
    ("OPENCV_FISHEYE", 1280, 1024, [500.0, 501.0, 640.5, 510.5, 0.02, -0.01, 0.003, -0.0005]),
    ("RADIAL_FISHEYE", 1280, 1024, [520.0, 640.5, 510.5, 0.02, -0.01]),
    ("SIMPLE_RADIAL_FISHEYE", 1280, 1024, [520.0, 640.5, 510.5, 0.02]),
]


@pytest.mark.parametrize("model,w,h,params", COLMAP_CASES, ids=[c[0] for c in COLMAP_CASES])
def test_projection_agrees_with_pycolmap(model, w, h, params):
    ours = from_colmap("1", model, w, h, params)
    theirs = pycolmap.Camera(model=model, width=w, height=h, params=params)
    px = ours.grid_px(25)
    rays = ours.unproject(px)
    front = rays[:, 2] > 1e-3  # COLMAP's fisheyes project through X/Z: the front half only
    assert front.sum() >= (621 if "FISHEYE" in model else 625)
    px, rays = px[front], rays[front]
    # COLMAP pixels have their origin at the image corner: ours + 0.5
    assert np.abs(np.asarray(theirs.img_from_cam(rays)) - (px + 0.5)).max() <= 1e-6
    xy = np.asarray(theirs.cam_from_img(px + 0.5))
    assert np.abs(xy - rays[:, :2] / rays[:, 2:]).max() * max(params[0], 1.0) <= 1e-6
    if model in ("OPENCV", "FULL_OPENCV", "OPENCV_FISHEYE"):
        name, back = to_colmap(ours)
        assert name == model and np.array_equal(back, params)


def test_full_opencv_with_a_rational_part_is_refused_and_fitted():
    p = [3200.0, 3190.0, 2010.0, 1490.0, -0.12, 0.09, 1e-3, -5e-4, -0.02, 0.01, 0.0, 0.0]
    with pytest.raises(CameraError, match=re.escape(
            "camera '7': FULL_OPENCV with a rational part (k4 = 0.01) has no exact Brown equivalent; "
            "fit one with geometry.conversion.convert")):
        from_colmap("7", "FULL_OPENCV", 4000, 3000, p)


# ---------------------------------------------------------------- Metashape
def test_metashape_parameters_convert_exactly_and_project_as_metashape_writes():
    ms = dict(f=3150.0, cx=12.5, cy=-9.25, b1=2.5, b2=-0.75, k1=-0.1, k2=0.05, k3=-0.01, k4=0.002,
              p1=4e-4, p2=-2e-4)
    cam = from_metashape("m", 4000, 3000, **ms)
    assert to_metashape(cam) == pytest.approx(ms, rel=0, abs=1e-12)
    rays = cam.unproject(cam.grid_px(9))
    x, y = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
    r2 = x * x + y * y
    q = 1 + ms["k1"] * r2 + ms["k2"] * r2**2 + ms["k3"] * r2**3 + ms["k4"] * r2**4
    # Metashape manual, frame cameras: P1 goes with (r^2 + 2x^2), corner origin
    xd = x * q + ms["p1"] * (r2 + 2 * x * x) + 2 * ms["p2"] * x * y
    yd = y * q + ms["p2"] * (r2 + 2 * y * y) + 2 * ms["p1"] * x * y
    u = 4000 * 0.5 + ms["cx"] + xd * (ms["f"] + ms["b1"]) + yd * ms["b2"]
    v = 3000 * 0.5 + ms["cy"] + yd * ms["f"]
    assert np.abs(cam.project(rays) + 0.5 - np.column_stack([u, v])).max() <= 1e-9


# ---------------------------------------------------------------- conversions
def test_frame_and_brown_without_distortion_convert_exactly():
    cam = Camera("p", 28.0, 0.05, -0.03, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.009, 0.008, 3000, 2000)
    conv = convert(FrameModel(cam), "brown")
    assert conv.exact and conv.max_residual_px <= 1e-9
    b = conv.model
    assert (b.fx, b.fy) == pytest.approx((28.0 / 0.009, 28.0 / 0.008), rel=1e-15)
    assert (b.cx, b.cy) == pytest.approx((1499.5 + 0.05 / 0.009, 999.5 + 0.03 / 0.008), rel=1e-15)
    back = convert(b, "frame", pixel_size_mm=0.009)
    assert back.exact and back.max_residual_px <= 1e-9
    assert back.model.camera.focal_length_mm == pytest.approx(28.0, rel=1e-14)
    assert exact_conversion(FrameModel(THESIS_LIKE), "brown") is None


def test_fitted_conversion_reports_its_residual():
    conv = convert(FrameModel(THESIS_LIKE), "brown")
    assert not conv.exact
    # an independent residual: the source's rays of a fresh 57 x 57 grid through the fitted camera
    px = THESIS_LIKE and FrameModel(THESIS_LIKE).grid_px(57)
    d = conv.model.project(FrameModel(THESIS_LIKE).unproject(px)) - px
    assert np.hypot(d[:, 0], d[:, 1]).max() <= conv.max_residual_px * 1.01
    assert 1e-6 < conv.max_residual_px < 0.01   # the corner of a 3000 x 2000 px frame: a few thousandths
    narrow = FisheyeCamera("n", 1000, 800, fx=1500.0, fy=1500.0, cx=499.5, cy=399.5, k1=0.01)
    fit = convert(narrow, "brown")
    assert fit.max_residual_px < 0.05 and fit.rms_residual_px <= fit.max_residual_px


def test_fisheye_wider_than_a_brown_camera_is_refused():
    with pytest.raises(CameraError, match=re.escape(
            "camera 'f': its image reaches 92.68 deg from the optical axis; a brown camera sees less than 90 deg")):
        convert(_fisheye(), "brown")


# ---------------------------------------------------------------- bad input
def test_unknown_model_name():
    with pytest.raises(CameraError, match=re.escape("unknown camera model 'pinhole'; known: frame, brown, fisheye")):
        camera_model("pinhole", "c", 10, 10)
    with pytest.raises(CameraError, match=re.escape("camera '3': unknown COLMAP camera model 'FOV'; known: ")):
        from_colmap("3", "FOV", 10, 10, [1.0])


def test_parameters_out_of_range():
    with pytest.raises(CameraError, match=re.escape("camera 'b': field 'fy': focal length must be positive, "
                                                    "got -5.0 px")):
        BrownCamera("b", 100, 80, fx=90.0, fy=-5.0, cx=49.5, cy=39.5)
    with pytest.raises(CameraError, match=re.escape("camera 'b': field 'cx': principal point 120.0 px lies outside "
                                                    "the image (-0.5 .. 99.5 px)")):
        BrownCamera("b", 100, 80, fx=90.0, fy=90.0, cx=120.0, cy=39.5)
    with pytest.raises(CameraError, match=re.escape("camera 'b': field 'k1': must be finite, got nan")):
        BrownCamera("b", 100, 80, fx=90.0, fy=90.0, cx=49.5, cy=39.5, k1=float("nan"))
    with pytest.raises(CameraError, match=r"^camera 'b': field 'k1': radial distortion k1 = -0\.5, k2 = 0, k3 = 0, "
                                          r"k4 = 0 folds over inside the image: the distorted radius stops "
                                          r"increasing at r = 0\.8165 "):
        BrownCamera("b", 4000, 3000, fx=2000.0, fy=2000.0, cx=1999.5, cy=1499.5, k1=-0.5)


def test_fisheye_beyond_180_degrees_is_refused():
    with pytest.raises(CameraError, match=re.escape(
            "camera 'wide': field 'fx': the image corner (-0.5, -0.5) px lies beyond 180 deg from the optical axis "
            "(theta_d = 3.2 rad, the model reaches 3.142 rad at 180 deg); check fx, fy (px per radian) and k1..k4")):
        FisheyeCamera("wide", 1000, 1000, fx=221.0, fy=221.0, cx=499.5, cy=499.5)
    with pytest.raises(CameraError, match=re.escape(
            "camera 'f': field 'k3': the fisheye polynomial folds over at 126.4 deg")):
        FisheyeCamera("f", 1280, 1024, fx=400.0, fy=401.0, cx=640.0, cy=510.0, k1=0.02, k2=-0.01, k3=0.003,
                      k4=-0.0005)


def test_rays_outside_the_valid_field_are_named():
    with pytest.raises(CameraError, match=re.escape("camera 'b': ray index 1 (0, 0, -1) is not in front of the "
                                                    "camera (Z must be > 0)")):
        _brown().project([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    with pytest.raises(CameraError, match=re.escape("camera 'f': ray index 0 at 180 deg from the optical axis is "
                                                    "beyond the model's valid field (126.4 deg)")):
        _fisheye().project([[0.0, 0.0, -1.0]])
    fe = FisheyeCamera("g", 1280, 1024, fx=600.0, fy=600.0, cx=640.0, cy=510.0, k1=-0.05)
    with pytest.raises(CameraError, match=re.escape("camera 'g': ray index 0 at 170 deg from the optical axis is "
                                                    "beyond the model's valid field (147.9 deg)")):
        fe.project([[np.sin(np.radians(170)), 0.0, np.cos(np.radians(170))]])
    with pytest.raises(CameraError, match=re.escape("camera 'g': pixel index 0 (5000, 0) did not converge to a ray")):
        fe.unproject([[5000.0, 0.0]])
    assert np.isnan(fe.unproject([[5000.0, 0.0]], on_fail="nan")).all()


def test_models_are_frozen_values():
    b = _brown()
    with pytest.raises(AttributeError):
        b.fx = 1.0  # type: ignore[misc]
    assert b == _brown() and b.with_params(b.params()) == b


@pytest.mark.parametrize("name", MODELS)
def test_image_plane_observations_and_their_derivatives(name):
    cam = MODELS[name]()
    px = cam.grid_px(9)
    if isinstance(cam, FisheyeCamera):
        px = px[np.hypot(px[:, 0] - cam.cx, px[:, 1] - cam.cy) < 600]   # within 90 deg
    n, dn_dt, dn_dpx = image_plane_observations(cam, px)
    rays = cam.unproject(px)
    np.testing.assert_allclose(n, rays[:, :2] / rays[:, 2:], rtol=1e-12, atol=1e-14)
    p0 = cam.params()
    for k, name_k in enumerate(cam.PARAMETERS):
        h = 1e-5 * max(abs(p0[k]), 1e-3 if name_k[0] in "kps" else 1.0)
        if isinstance(cam, FrameModel) and name_k[0] in "kp":
            h = 1e-4 * max(abs(p0[k]), 1e-9)
        up, dn = p0.copy(), p0.copy()
        up[k] += h
        dn[k] -= h
        fd = (image_plane_observations(cam.with_params(up), px)[0]
              - image_plane_observations(cam.with_params(dn), px)[0]) / (2 * h)
        np.testing.assert_allclose(dn_dt[:, :, k], fd, rtol=1e-5, atol=1e-6 * max(np.abs(fd).max(), 1e-12),
                                   err_msg=name_k)
    for k in range(2):
        d = np.zeros(2)
        d[k] = 1e-3
        fd = (image_plane_observations(cam, px + d)[0] - image_plane_observations(cam, px - d)[0]) / 2e-3
        np.testing.assert_allclose(dn_dpx[:, :, k], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    if isinstance(cam, FisheyeCamera):
        with pytest.raises(CameraError, match=re.escape("camera 'f': pixel index 0 sees a ray 92.37 deg from the "
                                                        "optical axis; the image plane holds rays within 90 deg only")):
            image_plane_observations(cam, cam.corners_px()[[1]])
