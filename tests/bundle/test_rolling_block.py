"""Rolling shutter in the bundle (issue 27): a drone block at 10 m/s with a 30 ms read-out.

Acceptance: with the model on (velocity from the neighbouring exposures), the orientation and
check-point errors are within 1.2x those of the global-shutter block of the same geometry and
noise (``drone_block(seed, readout_s=0)``); with the model off the read-out-time test flags the
camera with a located warning, and the row-trend pattern is reported per photo.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from lidarcat.bundle import adjust, adjust_with_parameters
from lidarcat.bundle.rays import observation_parts
from lidarcat.bundle.rolling import (ReadoutTime, VelocityCorrections, neighbour_velocities, readout_warning,
                                     row_fractions, row_times, row_trend, with_rolling_shutter)
from lidarcat.errors import CameraError
from lidarcat.geometry.collinearity import rotation_matrix
from lidarcat.geometry.models import BrownCamera
from lidarcat.geometry.rolling import RollingShutterPose, project_rolling
from lidarcat.synthetic.drone import DRONE_CAMERA, drone_block, rolling_pixels


def _errors(block, result) -> np.ndarray:
    """rms position (m), rotation (mrad), check-point (m) error against the truth."""
    dp = np.asarray(result.eo_params)[:, :3] - block.true_eo[:, :3]
    da = np.asarray(result.eo_params)[:, 3:] - block.true_eo[:, 3:]
    dc = np.asarray(result.points_m)[block.check_index] - block.true_points_m[block.check_index]
    return np.array([np.sqrt((dp**2).sum(1).mean()), 1e3 * np.sqrt((da**2).sum(1).mean()),
                     np.sqrt((dc**2).sum(1).mean())])


def _runs(seed: int):
    g = drone_block(seed, readout_s=0.0)
    b = drone_block(seed, readout_s=0.03)
    velocity = neighbour_velocities(b.gnss_m, b.exposure_time_s, b.line)
    on = with_rolling_shutter(b.problem, row_times(b.row_px, b.height_px, b.readout_s), velocity)
    r_g, r_on, r_off = adjust(g.problem), adjust(on), adjust(b.problem)
    assert r_g.success and r_on.success and r_off.success
    return g, b, velocity, r_g, r_on, r_off


def test_row_times_and_neighbour_velocities():
    assert row_times([-0.5, 1499.5, 2999.5], 3000, 0.03) == pytest.approx([-0.015, 0.0, 0.015], abs=1e-15)
    assert row_fractions([-0.5, 2999.5], 3000) == pytest.approx([-0.5, 0.5], abs=1e-15)
    t = np.array([0.0, 2.0, 4.0, 0.0, 3.0])
    x = np.array([[0, 0, 0], [0, 20, 0], [0, 40, 1], [5, 0, 0], [5, -30, 0]], dtype=float)
    v = neighbour_velocities(x, t, ["a", "a", "a", "b", "b"])
    np.testing.assert_allclose(v, [[0, 10, 0], [0, 10, 0.25], [0, 10, 0.5], [0, -10, 0], [0, -10, 0]], atol=1e-12)
    with pytest.raises(CameraError, match="flight line 'a': two exposures at the same time"):
        neighbour_velocities(x[:2], [1.0, 1.0], ["a", "a"])


def test_synthetic_rows_agree_with_the_engine_projection():
    """The drone block's rolling pixels equal geometry.rolling.project_rolling's (the validated engine)."""
    b = drone_block(0, readout_s=0.03)
    c = DRONE_CAMERA
    cam = BrownCamera("drone", c["width_px"], c["height_px"], fx=c["focal_px"], fy=c["focal_px"],
                      cx=(c["width_px"] - 1) / 2, cy=(c["height_px"] - 1) / 2)
    p = b.problem
    sel = np.flatnonzero(p.photo_index == 4)
    px, _ = rolling_pixels(b.true_eo, b.true_velocity_m_s, b.true_points_m, b.focal_mm, b.pitch_mm,
                           b.width_px, b.height_px, 0.03, p.photo_index[sel], p.point_index[sel])
    # thesis image frame (x right, y up, looking along -z) -> COLMAP camera frame: diag(1, -1, -1)
    r0 = np.diag([1.0, -1.0, -1.0]) @ rotation_matrix(b.true_eo[4, 3:])
    pose = RollingShutterPose(r0, b.true_eo[4, :3], b.true_velocity_m_s[4], np.zeros(3), 0.03)
    ref, _ = project_rolling(cam, pose, b.true_points_m[p.point_index[sel]])
    assert np.abs(px - ref).max() < 1e-6
    # the read-out moved the rows by up to f V T / (2 Z) = 4.5 px at the edges
    g, _ = rolling_pixels(b.true_eo, b.true_velocity_m_s, b.true_points_m, b.focal_mm, b.pitch_mm,
                          b.width_px, b.height_px, 0.0, p.photo_index[sel], p.point_index[sel])
    assert 3.5 < np.abs(px - g)[:, 1].max() < 4.6


def test_centre_offsets_keep_the_jacobians():
    """A rolling-shutter offset enters the Jacobians of the shifted point (checked by differences)."""
    b = drone_block(1, readout_s=0.03, photos_per_strip=4, n_points=300)
    on = with_rolling_shutter(b.problem, row_times(b.row_px, b.height_px, 0.03), b.true_velocity_m_s)
    eo, pts = b.true_eo.copy(), b.true_points_m.copy()
    xy, a_pt, a_ang, _ = observation_parts(on, eo, pts)
    h = 1e-6
    for k in range(3):
        e2 = eo.copy()
        e2[:, 3 + k] += h
        assert np.abs((observation_parts(on, e2, pts)[0] - xy) / h - a_ang[:, :, k]).max() < 1e-4
        e2 = eo.copy()
        e2[:, k] += h
        assert np.abs((observation_parts(on, e2, pts)[0] - xy) / h + a_pt[:, :, k]).max() < 1e-4


def test_drone_block_with_the_model_is_as_good_as_a_global_shutter_block():
    """Acceptance (seed 0): model on within 1.2x of the global-shutter block; off: far worse, and
    the read-out-time test names the camera with its t-value; the row-trend pattern per photo."""
    g, b, velocity, r_g, r_on, r_off = _runs(0)
    e_g, e_on, e_off = _errors(g, r_g), _errors(b, r_on), _errors(b, r_off)
    assert np.all(e_on <= 1.2 * e_g), (e_on, e_g)
    assert np.all(e_off >= 2.0 * e_g), (e_off, e_g)
    assert abs(r_on.sigma0_sq - 1) < 0.1 and r_off.sigma0_sq > r_on.sigma0_sq
    # the read-out-time test: estimated from the model-off block, ~30 ms with t > 10
    cams = ["drone"] * b.problem.n_photos
    s = row_fractions(b.row_px, b.height_px)
    res = adjust_with_parameters(b.problem, [ReadoutTime(s, velocity, cams)], without=r_off)
    assert abs(res.estimates[0] - 0.03) < 3 * res.sd[0] and res.sd[0] < 0.002
    (warning,) = readout_warning(res)
    m = re.fullmatch(r"camera 'drone': the image residuals show a rolling shutter: read-out time ([\d.]+) \+- "
                     r"([\d.]+) ms \(t = ([\d.]+); modelled 0 ms\): set readout_time_ms = [\d.]+ in its camera table",
                     warning)
    assert m and float(m.group(3)) > 10
    # the global-shutter block shows none
    gres = adjust_with_parameters(g.problem, [ReadoutTime(row_fractions(g.row_px, g.height_px), velocity, cams)],
                                  without=r_g)
    assert readout_warning(gres) == [] and abs(gres.estimates[0]) < 3 * gres.sd[0]
    # the row-trend pattern: per photo and axis; the image moves along y (the rows): the y residuals
    # of the model-off block trend with the row in every photo alike, the model-on ones do not
    off = row_trend(b.problem, r_off.residuals_mm, b.row_px, b.pitch_mm)
    on = row_trend(on_problem := r_on.problem, r_on.residuals_mm, b.row_px, b.pitch_mm)
    assert off.t.shape == (b.problem.n_photos, 2) and on_problem.rays is not None
    assert off.pooled_t[1] > 2.0 and abs(on.pooled_t[1]) < 1.0
    assert on.warning() == "" and off.chi2 > on.chi2


def test_estimated_velocities_are_honest():
    """Velocity per photo as 3 free unknowns: recovered within their sds (seed 0, 90 values)."""
    b = drone_block(0, readout_s=0.03)
    t = row_times(b.row_px, b.height_px, b.readout_s)
    v0 = neighbour_velocities(b.gnss_m, b.exposure_time_s, b.line)
    res = adjust_with_parameters(with_rolling_shutter(b.problem, t, v0), [VelocityCorrections(t, v0)])
    assert res.bundle.success
    z = (np.reshape(res.estimates, (-1, 3)) + v0 - b.true_velocity_m_s) / np.reshape(res.sd, (-1, 3))
    assert 0.7 < np.sqrt(np.mean(z**2)) < 1.4 and np.abs(z).max() < 4
    assert res.names[:3] == ("D001.vE", "D001.vN", "D001.vh")


@pytest.mark.slow
def test_drone_block_acceptance_over_seeds():
    """Ten seeds: the model on stays within 1.2x of the global shutter (pooled rms of each error);
    the read-out-time test flags every rolling block (t > 10) and its estimates are honest."""
    e_g, e_on, z, t_val = [], [], [], []
    for seed in range(1, 11):
        g, b, velocity, r_g, r_on, r_off = _runs(seed)
        e_g.append(_errors(g, r_g))
        e_on.append(_errors(b, r_on))
        s = row_fractions(b.row_px, b.height_px)
        res = adjust_with_parameters(b.problem, [ReadoutTime(s, velocity, ["drone"] * b.problem.n_photos)],
                                     without=r_off)
        z.append((res.estimates[0] - 0.03) / res.sd[0])
        t_val.append(res.estimates[0] / res.sd[0])
    ratio = np.sqrt(np.mean(np.square(e_on), axis=0) / np.mean(np.square(e_g), axis=0))
    assert np.all(ratio <= 1.2), ratio
    assert min(t_val) > 10
    assert np.sqrt(np.mean(np.square(z))) < 1.6 and np.abs(z).max() < 3.5


def test_camera_readout_time_key(tmp_path):
    """camera.toml's ``readout_time_ms`` (default 0 = global shutter): read, written back, refused
    with the file, line and field when out of range."""
    from lidarcat.errors import SurveyError
    from lidarcat.geometry.camera import Camera
    from lidarcat.survey.cameras import load_cameras

    cam = Camera("drone", 12.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.004, 0.004, 4000, 3000)
    assert cam.readout_time_ms == 0.0 and "readout_time_ms" not in cam.to_toml()
    fast = dataclasses.replace(cam, readout_time_ms=30)
    path = tmp_path / "camera.toml"
    path.write_text(fast.to_toml(), encoding="utf-8")
    assert load_cameras(path)["drone"].readout_time_ms == 30.0
    text = fast.to_toml().replace("readout_time_ms = 30.0", "readout_time_ms = -3")
    path.write_text(text, encoding="utf-8")
    line = text.splitlines().index("readout_time_ms = -3") + 1
    with pytest.raises(SurveyError, match=rf"camera\.toml:{line}: field 'readout_time_ms': .*read-out time must be a "
                                          r"number of ms in 0\.\.1000 \(0: a global shutter\), got -3"):
        load_cameras(path)


def _write_survey(folder, b, readout_ms: float, times: bool = True):
    """The drone block as a survey folder: camera.toml with *readout_ms*, photos.csv with the GNSS
    positions (sd) and exposure times, image_points.csv in pixels; the GNSS positions are the datum."""
    import csv

    folder.mkdir(parents=True)
    (folder / "survey.toml").write_text(
        '[survey]\nname = "drone"\ncrs = "local: synthetic"\n[files]\ncamera = "camera.toml"\n'
        'photos = "photos.csv"\nimage_points = "image_points.csv"\n[adjustment]\nobservations = "pixel"\n'
        f"image_sd_mm = {0.5 * b.pitch_mm}\n", encoding="utf-8")
    (folder / "camera.toml").write_text(
        f"[drone]\nfocal_length_mm = {b.focal_mm}\nprincipal_point_x_mm = 0.0\nprincipal_point_y_mm = 0.0\n"
        "k1 = 0.0\nk2 = 0.0\nk3 = 0.0\np1 = 0.0\np2 = 0.0\nrefraction_eps45 = 0.0\n"
        f"pixel_size_x_mm = {b.pitch_mm}\npixel_size_y_mm = {b.pitch_mm}\ncolumns_px = {b.width_px}\n"
        f"rows_px = {b.height_px}\nreadout_time_ms = {readout_ms}\n", encoding="utf-8")
    p = b.problem
    with open(folder / "photos.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "camera", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg", "sd_X0", "sd_Y0",
                    "sd_Z0"] + (["time_s"] if times else []))
        for i, pid in enumerate(p.photo_ids):
            w.writerow([pid, "drone", *b.gnss_m[i], *np.degrees(p.initial_eo[i, 3:]), 0.03, 0.03, 0.03]
                       + ([b.exposure_time_s[i]] if times else []))
    xy = np.asarray(p.xy_mm)
    col = xy[:, 0] / b.pitch_mm + (b.width_px - 1) / 2
    with open(folder / "image_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "point", "col_px", "row_px"])
        for i, j, c, r in zip(p.photo_index, p.point_index, col, b.row_px):
            w.writerow([p.photo_ids[i], p.point_ids[j], repr(float(c)), repr(float(r))])
    return folder


def test_survey_with_a_rolling_shutter_camera(tmp_path):
    """camera.toml readout_time_ms + photos.csv time_s: the survey's bundle models the read-out (the
    same problem as the engine's), and lidarcat adjust writes orientations as good as the model's."""
    from lidarcat.errors import SurveyError
    from lidarcat.survey import Survey, adjust_survey, problem_from_survey
    from lidarcat.survey.motion import with_survey_motion

    b = drone_block(0, readout_s=0.03)
    s = Survey.load(_write_survey(tmp_path / "on", b, 30.0))
    pe = with_survey_motion(s, problem_from_survey(s, eo_constraints=True))
    assert pe.info["rolling_shutter"] == ["drone"]
    on = with_rolling_shutter(b.problem, row_times(b.row_px, b.height_px, 0.03),
                              neighbour_velocities(b.gnss_m, b.exposure_time_s, b.line))
    np.testing.assert_allclose(pe.rays.centre_offset_m, on.rays.centre_offset_m, atol=1e-9)
    res, out = adjust_survey(s, eo_constraints=True, snooping="off", outdir=tmp_path / "out_on")
    off, _ = adjust_survey(Survey.load(_write_survey(tmp_path / "off", b, 0.0)), eo_constraints=True,
                           snooping="off", outdir=tmp_path / "out_off")
    err_on = np.sqrt(np.mean((np.asarray(res.eo_params)[:, :3] - b.true_eo[:, :3]) ** 2))
    err_off = np.sqrt(np.mean((np.asarray(off.eo_params)[:, :3] - b.true_eo[:, :3]) ** 2))
    assert res.problem.rays is not None and off.problem.rays is None
    assert err_on < 0.5 * err_off
    # a rolling-shutter photo without its exposure time: the file, line and field
    bad = Survey.load(_write_survey(tmp_path / "bad", b, 30.0, times=False))
    with pytest.raises(SurveyError, match=r"photos\.csv:2: field 'time_s': photo 'D001' of camera 'drone' "
                                          r"\(readout_time_ms = 30\) has no time_s: the rolling shutter needs its "
                                          r"exposure time for the velocity from its neighbours"):
        with_survey_motion(bad, problem_from_survey(bad, eo_constraints=True))


def test_velocity_and_readout_components_report_their_start_values():
    """SelfCalResult.calibrated holds the start of every rolling-shutter unknown (value = start + estimate)."""
    b = drone_block(2, readout_s=0.03, photos_per_strip=5, n_points=600)
    t = row_times(b.row_px, b.height_px, b.readout_s)
    v0 = neighbour_velocities(b.gnss_m, b.exposure_time_s, b.line)
    on = with_rolling_shutter(b.problem, t, v0)
    res = adjust_with_parameters(on, [ReadoutTime(row_fractions(b.row_px, b.height_px), v0,
                                                  ["drone"] * on.n_photos, readout_s={"drone": 0.03})])
    assert res.calibrated == {"drone.readout_s": 0.03} and abs(res.estimates[0]) < 3 * res.sd[0]
    vel = adjust_with_parameters(on, [VelocityCorrections(t, v0, sd_m_s=0.5, photos=[0, 3])])
    assert vel.names == ("D001.vE", "D001.vN", "D001.vh", "D004.vE", "D004.vN", "D004.vh")
    assert vel.calibrated["D004.vN"] == pytest.approx(v0[3, 1])
    assert np.all(np.isfinite(vel.prior_sd)) and vel.prior_sd[0] == 0.5


def test_lidarcat_adjust_tests_a_camera_without_its_rolling_shutter(tmp_path, caplog):
    """A drone survey whose camera says readout_time_ms = 0 while the photos carry exposure times:
    `lidarcat adjust` estimates the read-out time once more and names the camera (~30 ms, the truth);
    the global-shutter block of the same geometry passes the test (summary.json keeps both)."""
    import json
    import logging

    from lidarcat.survey import Survey, adjust_survey

    b = drone_block(0, readout_s=0.03)
    with caplog.at_level(logging.WARNING):
        adjust_survey(Survey.load(_write_survey(tmp_path / "off", b, 0.0)), eo_constraints=True, snooping="off",
                      outdir=tmp_path / "out_off")
    test = json.loads((tmp_path / "out_off" / "summary.json").read_text())["rolling_shutter_test"]
    cam = test["cameras"]["drone"]
    assert abs(cam["readout_ms"] - 30.0) < 3 * cam["sd_ms"] and cam["t"] > 10
    (warning,) = test["warnings"]
    assert warning.startswith("camera 'drone': the image residuals show a rolling shutter: read-out time ")
    assert warning in caplog.text
    g = drone_block(0, readout_s=0.0)
    adjust_survey(Survey.load(_write_survey(tmp_path / "gs", g, 0.0)), eo_constraints=True, snooping="off",
                  outdir=tmp_path / "out_gs")
    test = json.loads((tmp_path / "out_gs" / "summary.json").read_text())["rolling_shutter_test"]
    assert test["warnings"] == [] and abs(test["cameras"]["drone"]["t"]) < 3.29
