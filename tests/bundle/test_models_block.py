"""Self-calibration of every camera model in the bundle (issue 27): frame, Brown, fisheye.

A synthetic block with known truth per model: the 3 x 8 block of
:func:`lidarcat.synthetic.block.synthetic_block` flown 300 m above a terrain of 30 m relief with a
wide lens (c = 12 mm on a 36 x 24 mm frame: 61 deg from the axis to the corner), GNSS camera
positions (5 cm), 5 cm control.  The true camera differs from its certificate (every parameter
switched on is off by a known amount); the pixels are the true camera's projections of the true
points plus N(0, 0.5 px) noise, drawn from a stream of their own.  The survey path is followed:
the pixels become photo coordinates and per-axis sds through the *certificate*
(:meth:`Camera.pixel_to_photo`, :meth:`Camera.photo_sd`), the bundle estimates the corrections
(:class:`~lidarcat.bundle.SelfCalibration`, no priors).

Accepted: every correction within 3 sd of its truth (one seed, fast) and, over 20 seeds, the
standardised errors ``(estimate - truth) / sd`` of all parameters with rms in 0.8-1.25 (slow).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle.additional import AdditionalParameterError, SelfCalibration, parse_parameters
from lidarcat.bundle.selfcal import adjust_with_parameters
from lidarcat.geometry.brown import BrownCamera
from lidarcat.geometry.camera import Camera
from lidarcat.geometry.collinearity import project
from lidarcat.geometry.fisheye import FisheyeCamera
from lidarcat.synthetic.block import synthetic_block

SIGMA_PX = 0.5
PITCH_MM = 0.006
FOCAL_MM = 12.0

#: certificate and truth of every model, and the parameters switched on
FRAME_CERT = Camera("cam", FOCAL_MM, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, PITCH_MM, PITCH_MM, 6000, 4000)
FRAME_TRUTH = dataclasses.replace(FRAME_CERT, focal_length_mm=12.02, principal_point_x_mm=0.03,
                                  principal_point_y_mm=-0.02, k1=6e-6, k2=-5e-9, p1=1e-5, p2=-8e-6)
BROWN_CERT = BrownCamera("cam", 6000, 4000, fx=2000.0, fy=2000.0, cx=2999.5, cy=1999.5)
BROWN_TRUTH = BrownCamera("cam", 6000, 4000, fx=2004.0, fy=2003.0, cx=3010.0, cy=1992.0, k1=-0.02, k2=0.004,
                          p1=2e-4, p2=-1e-4)
FISHEYE_CERT = FisheyeCamera("cam", 6000, 4600, fx=2600.0, fy=2600.0, cx=2999.5, cy=2299.5)
FISHEYE_TRUTH = FisheyeCamera("cam", 6000, 4600, fx=2604.0, fy=2603.0, cx=3008.0, cy=2293.0, k1=0.01, k2=-0.002)
CASES = {
    "frame": (FRAME_CERT, FRAME_TRUTH, "c,x0,y0,k1,k2,p1,p2"),
    "brown": (BROWN_CERT, BROWN_TRUTH, "fx,fy,cx,cy,k1,k2,p1,p2"),
    "fisheye": (FISHEYE_CERT, FISHEYE_TRUTH, "fx,fy,cx,cy,k1,k2"),
}
_FRAME_FIELD = {"c": "focal_length_mm", "x0": "principal_point_x_mm", "y0": "principal_point_y_mm"}


def model_block(kind: str, seed: int):
    """(problem, certificate Camera, true corrections by parameter name) of one seed."""
    cert, truth, names = CASES[kind]
    base = synthetic_block(3, 8, seed=seed, noise=False, focal_mm=FOCAL_MM, flying_height_m=300.0,
                           point_spacing_m=60.0, tilt_sd_deg=2.0, control_sd_m=(0.05, 0.05, 0.05))
    p = base.problem
    ei, pj = p.photo_index, p.point_index
    eo, pts = base.true_eo, base.true_points_m
    xy, _ = project(eo[ei], pts[pj], np.full(len(ei), FOCAL_MM))          # pinhole photo coordinates
    if kind == "frame":
        true_cam = truth
        px = true_cam.photo_to_pixel(xy * truth.focal_length_mm / FOCAL_MM)
        cam = cert
        delta = {q: getattr(truth, _FRAME_FIELD.get(q, q)) - getattr(cert, _FRAME_FIELD.get(q, q))
                 for q in parse_parameters(names)}
    else:
        rays = np.column_stack([xy[:, 0] / FOCAL_MM, -xy[:, 1] / FOCAL_MM, np.ones(len(xy))])
        px = truth.project(rays)
        cam = Camera.from_model(cert, pixel_size_mm=PITCH_MM)
        delta = {q: getattr(truth, q) - getattr(cert, q) for q in parse_parameters(names)}
    assert ((px > 0) & (px < [cert.width_px if kind != "frame" else cert.columns_px,
                              cert.height_px if kind != "frame" else cert.rows_px])).all()
    noise = np.random.default_rng([seed, 27])
    px_obs = px + noise.normal(0.0, SIGMA_PX, px.shape)
    xy_obs = cam.pixel_to_photo(px_obs)
    sd = cam.photo_sd(px_obs, SIGMA_PX)
    n_ph = p.n_photos
    gnss = eo.copy()
    gnss[:, :3] += noise.normal(0.0, 0.05, (n_ph, 3))
    enh = pts[p.constraint_point_index] + noise.normal(0.0, 0.05, (len(p.constraint_point_index), 3))
    problem = dataclasses.replace(
        p, focal_length_mm=np.full(n_ph, cam.focal_length_mm), xy_mm=xy_obs, sd_mm=sd, constraint_enh_m=enh,
        eo_constraint_photo_index=np.arange(n_ph), eo_constraint_params=gnss,
        eo_constraint_sd=np.tile([0.05, 0.05, 0.05, np.inf, np.inf, np.inf], (n_ph, 1)))
    return problem, cam, delta


def standardised_errors(kind: str, seed: int) -> tuple[np.ndarray, object]:
    problem, cam, delta = model_block(kind, seed)
    comp = SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, CASES[kind][2], use_priors=False)
    res = adjust_with_parameters(problem, [comp], precision="none")
    truth = np.array([delta[n.split(".", 1)[1]] for n in res.names])
    return (res.estimates - truth) / res.sd, res


@pytest.mark.parametrize("kind", list(CASES))
def test_model_self_calibration_recovers_the_truth_within_3_sd(kind):
    z, res = standardised_errors(kind, 0)
    assert res.bundle.status == "converged", res.bundle.status
    order = CASES[kind][0].PARAMETERS if kind != "frame" else parse_parameters("all")     # the model's order
    assert list(res.names) == [f"cam.{q}" for q in order if q in CASES[kind][2].split(",")]
    assert np.all(np.abs(z) < 3), dict(zip(res.names, np.round(z, 2)))
    # the misfit the parameters remove: sigma0^2 near 1 with them, far above without
    assert 0.8 < res.bundle.sigma0_sq < 1.2
    assert res.without.sigma0_sq > 2


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(CASES))
def test_model_self_calibration_sds_honest_over_20_seeds(kind):
    z = np.array([standardised_errors(kind, seed)[0] for seed in range(20)])
    rms = float(np.sqrt(np.mean(z**2)))
    print(kind, "rms", round(rms, 3), "max", round(float(np.abs(z).max()), 2),
          "per parameter", np.round(np.sqrt(np.mean(z**2, axis=0)), 2))
    assert 0.8 <= rms <= 1.25
    assert np.mean(np.abs(z) > 3) <= 0.01


def test_brown_priors_hold_a_parameter_the_block_cannot_see():
    """``sd_<parameter>`` of the camera are weighted priors: k3 (r^6; the block's corners reach r = 1.7)
    with sd 1e-4 and certificate 0 is pulled to about 0 +- its prior, the others still recovered."""
    problem, cam, delta = model_block("brown", 0)
    cam = Camera.from_model(cam.lens, pixel_size_mm=PITCH_MM, sd={"sd_k3": 1e-4})
    comp = SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "fx,fy,cx,cy,k1,k2,k3,p1,p2")
    res = adjust_with_parameters(problem, [comp], precision="none")
    i = res.index("cam.k3")
    assert res.prior_sd[i] == 1e-4 and np.isinf(np.delete(res.prior_sd, i)).all()
    assert res.sd[i] < 1e-4 and abs(res.estimates[i]) < 3 * res.sd[i]
    for name, est, sd in zip(res.names, res.estimates, res.sd):
        q = name.split(".", 1)[1]
        assert abs(est - delta.get(q, 0.0)) < 3 * sd, (q, est, sd)
    s = res.summary()["additional_parameters"]["cam.k3"]
    assert s["prior_sd"] == 1e-4 and s["calibrated"] == 0.0 and s["unit"] == "1"
    assert res.summary()["additional_parameters"]["cam.fx"]["unit"] == "px"


def test_lens_parameter_names_are_checked_per_camera():
    problem, cam, _ = model_block("fisheye", 0)
    with pytest.raises(AdditionalParameterError) as ei:
        adjust_with_parameters(problem, [SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "fx,p1")])
    assert str(ei.value) == ("self-calibration parameter 'p1' is no parameter of the block's cameras ('cam' "
                             "(fisheye): fx, fy, cx, cy, k1, k2, k3, k4), or 'all'")
    frame_problem, frame_cam, _ = model_block("frame", 0)
    with pytest.raises(AdditionalParameterError) as ei:
        adjust_with_parameters(frame_problem, [SelfCalibration({"cam": frame_cam}, ["cam"] * frame_problem.n_photos,
                                                               "c,fx")])
    assert str(ei.value) == ("self-calibration parameter 'fx' belongs to Brown/fisheye cameras; camera 'cam' is a "
                             "frame camera (c, x0, y0, k1, k2, k3, p1, p2, or a set)")
    assert parse_parameters("fisheye") == ("k1", "k2", "k3", "k4", "fx", "fy", "cx", "cy")
    assert parse_parameters("fx,cx,cy,k1,k2,p1,p2") == ("k1", "k2", "p1", "p2", "fx", "cx", "cy")
    assert parse_parameters("c,x0,k1") == ("c", "x0", "k1")                       # the frame path unchanged


def test_frame_and_lens_cameras_are_not_calibrated_in_one_adjustment():
    problem, cam, _ = model_block("brown", 0)
    frame = dataclasses.replace(FRAME_CERT, id="old")
    photo_cam = ["cam"] * (problem.n_photos - 1) + ["old"]
    with pytest.raises(AdditionalParameterError, match="self-calibration of frame camera 'old' beside brown camera "
                                                       "'cam' is not supported in one adjustment"):
        SelfCalibration({"cam": cam, "old": frame}, photo_cam, "all").bind(problem)


def test_why_a_brown_radial_pair_is_not_determinable():
    """k1 and k2 of the acceptance block correlate at r = -0.96: the warning says why, with the field measured."""
    problem, cam, _ = model_block("brown", 0)
    comp = SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "fx,fy,cx,cy,k1,k2,p1,p2", use_priors=False)
    res = adjust_with_parameters(problem, [comp], precision="none")
    why = res.why("cam.k1", "cam.k2", False)
    assert why.startswith("over the measured rays (up to ") and "the radial terms k1 and k2 change the image nearly" in why
    assert any("cam.k1" in w and "Why: over the measured rays" in w for w in res.warnings())
    assert res.why("cam.fx", "Z0", True).startswith("fx scales the image as the flying height does")
