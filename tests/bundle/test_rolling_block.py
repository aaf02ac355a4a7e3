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
    from lidarcat.geometry.camera import Camera, load_cameras

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
