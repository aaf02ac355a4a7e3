"""Rolling shutter: the row-dependent shift of a drone photo, the row time solved, Jacobians by finite differences."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lidarcat.errors import CameraError
from lidarcat.geometry.models import BrownCamera, FisheyeCamera
from lidarcat.geometry.rolling import RollingShutterPose, project_rolling, project_rolling_jacobians, rodrigues

F, W, H, Z = 3000.0, 4000, 3000, 100.0          # px, px, rows, m above the ground
#: a nadir camera: x east, y south, z down (world E, N, h)
NADIR = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
PINHOLE = BrownCamera("drone", W, H, fx=F, fy=F, cx=(W - 1) / 2, cy=(H - 1) / 2)


def _ground(n: int = 15) -> np.ndarray:
    e, nn = np.meshgrid(np.linspace(-60, 60, n), np.linspace(-45, 45, n))
    return np.column_stack([e.ravel(), nn.ravel(), np.zeros(n * n)])


def _pose(v, readout=0.030, w=(0.0, 0.0, 0.0)) -> RollingShutterPose:
    return RollingShutterPose(NADIR, [0.0, 0.0, Z], v, w, readout)


def test_flight_across_the_rows_shears_each_row_by_f_v_t_over_z():
    pts = _ground()
    gs, _ = project_rolling(PINHOLE, _pose([10.0, 0.0, 0.0], readout=0.0), pts)
    rs, t = project_rolling(PINHOLE, _pose([10.0, 0.0, 0.0]), pts)
    np.testing.assert_allclose(t, 0.030 * ((rs[:, 1] + 0.5) / H - 0.5), rtol=0, atol=1e-15)
    assert np.abs(rs[:, 1] - gs[:, 1]).max() <= 1e-9                 # flying along x: rows unchanged
    shift = rs[:, 0] - gs[:, 0]
    assert np.abs(shift - (-F * 10.0 * t / Z)).max() <= 1e-9         # the known shear, px
    # the points 45 m north lie on row 149.5 (t = -13.5 ms): 4.05 px east; 45 m south 4.05 px west
    assert (shift.max(), shift.min()) == pytest.approx((4.05, -4.05), abs=1e-9)
    assert np.polyfit(rs[:, 1], shift, 1)[0] == pytest.approx(-F * 10.0 * 0.030 / Z / H, rel=1e-9)


def test_flight_along_the_rows_solves_the_row_time():
    pts = _ground()
    gs, _ = project_rolling(PINHOLE, _pose([0.0, 10.0, 0.0], readout=0.0), pts)
    rs, _ = project_rolling(PINHOLE, _pose([0.0, 10.0, 0.0]), pts)
    # row = row_gs + (F V / Z) t(row), t(row) = T ((row + 0.5)/H - 0.5): linear, solved in closed form
    k = F * 10.0 / Z * 0.030
    want = (gs[:, 1] + k * (0.5 / H - 0.5)) / (1 - k / H)
    assert np.abs(rs[:, 1] - want).max() <= 1e-9
    assert np.abs(rs[:, 0] - gs[:, 0]).max() <= 1e-9


@pytest.mark.parametrize("model", [PINHOLE, BrownCamera("b", W, H, fx=F, fy=F * 1.001, cx=2010.0, cy=1490.0, k1=-0.1,
                                                        k2=0.03, p1=1e-4, skew=0.3),
                                   FisheyeCamera("f", W, H, fx=1500.0, fy=1500.0, cx=1999.5, cy=1499.5, k1=0.01)],
                         ids=["pinhole", "brown", "fisheye"])
def test_jacobians_match_finite_differences(model):
    pts = _ground(7) + np.array([3.0, -2.0, 5.0])
    r0 = rodrigues([0.05, -0.03, 0.4])[0] @ NADIR
    base = dict(rotation=r0, position_m=np.array([1.0, 2.0, Z]), velocity_m_s=np.array([9.0, 4.0, -0.5]),
                angular_velocity_rad_s=np.array([0.2, -0.3, 0.5]), readout_s=0.03)
    px, jac = project_rolling_jacobians(model, RollingShutterPose(**base), pts)

    def proj(**kw):
        return project_rolling(model, RollingShutterPose(**{**base, **kw}), pts, tol_px=1e-12)[0]

    for name, field in (("position", "position_m"), ("velocity", "velocity_m_s"),
                        ("angular_velocity", "angular_velocity_rad_s")):
        for k in range(3):
            h = 1e-5
            d = np.zeros(3)
            d[k] = h
            fd = (proj(**{field: base[field] + d}) - proj(**{field: base[field] - d})) / (2 * h)
            np.testing.assert_allclose(jac[name][:, :, k], fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max(), err_msg=name)
    for k in range(3):
        d = np.zeros(3)
        d[k] = 1e-6
        fd = (proj(rotation=rodrigues(d)[0] @ r0) - proj(rotation=rodrigues(-d)[0] @ r0)) / 2e-6
        np.testing.assert_allclose(jac["rotation"][:, :, k], fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())
        fd = (project_rolling(model, RollingShutterPose(**base), pts + d * 10, tol_px=1e-12)[0]
              - project_rolling(model, RollingShutterPose(**base), pts - d * 10, tol_px=1e-12)[0]) / 2e-5
        np.testing.assert_allclose(jac["point"][:, :, k], fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())
    fd = (proj(readout_s=0.03 + 1e-6) - proj(readout_s=0.03 - 1e-6)) / 2e-6
    np.testing.assert_allclose(jac["readout"], fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max())
    p0 = model.params()
    for k, name in enumerate(model.PARAMETERS):
        h = 1e-4 * max(abs(p0[k]), 1e-2 if name[0] in "kps" else 1.0)
        up, dn = p0.copy(), p0.copy()
        up[k] += h
        dn[k] -= h
        fd = (project_rolling(model.with_params(up), RollingShutterPose(**base), pts, tol_px=1e-12)[0]
              - project_rolling(model.with_params(dn), RollingShutterPose(**base), pts, tol_px=1e-12)[0]) / (2 * h)
        np.testing.assert_allclose(jac["intrinsics"][:, :, k], fd, rtol=1e-5, atol=1e-5 * max(np.abs(fd).max(), 1e-9),
                                   err_msg=name)


def test_bad_readout_is_refused():
    with pytest.raises(CameraError, match=re.escape("field 'readout_s': read-out time must be a finite number >= 0 s, "
                                                    "got -0.01")):
        _pose([10.0, 0.0, 0.0], readout=-0.01)


def _resect(model, pts, meas, readout, start, estimate_velocity):
    """Gauss-Newton resection: rotation increment, position (and velocity); returns pose, residuals, cov."""
    r0, c, v = start
    for _ in range(20):
        pose = RollingShutterPose(r0, c, v, [0.0, 0.0, 0.0], readout)
        px, jac = project_rolling_jacobians(model, pose, pts)
        blocks = [jac["rotation"], jac["position"]] + ([jac["velocity"]] if estimate_velocity else [])
        A = np.concatenate(blocks, axis=2).reshape(-1, 3 * len(blocks))
        res = (meas - px).ravel()
        N = A.T @ A
        step = np.linalg.solve(N, A.T @ res)
        r0 = rodrigues(step[:3])[0] @ r0
        c = c + step[3:6]
        if estimate_velocity:
            v = v + step[6:9]
        if np.abs(step).max() < 1e-12:
            break
    return (r0, c, v), meas - project_rolling(model, RollingShutterPose(r0, c, v, [0.0] * 3, readout), pts)[0], N


def _rotation_error_mrad(a, b):
    return 1e3 * np.linalg.norm(np.array([a[2, 1] - b[2, 1], a[0, 2] - b[0, 2], a[1, 0] - b[1, 0]]))


def test_resection_with_the_model_is_as_good_as_a_global_shutter_and_without_it_leaves_a_row_trend():
    """20 seeds of a drone photo at 10 m/s, 30 ms read-out, 0.5 px noise, 120 control points 0-20 m high.

    ``rs_given``: the model on, the velocity from the neighbouring exposures (truth + N(0, 0.1 m/s):
    RTK/PPK positions of the exposures 2 s apart; with N(0, 0.3 m/s) the rotation error is 1.22x
    the global shutter's, measured);
    ``rs_est``: the model on, the velocity estimated from the photo alone; ``rs_off``: no model.
    """
    v_true = np.array([10.0, 0.0, 0.0])
    err: dict[str, list] = {"gs": [], "rs_given": [], "rs_est": [], "rs_off": []}
    slopes_t, v_z = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        pts = np.column_stack([rng.uniform(-60, 60, 120), rng.uniform(-45, 45, 120), rng.uniform(0, 20, 120)])
        truth = (NADIR, np.array([0.0, 0.0, Z]))
        noise = rng.normal(0, 0.5, (len(pts), 2))
        v_given = v_true + rng.normal(0, 0.1, 3)
        gs_meas = project_rolling(PINHOLE, _pose(v_true, readout=0.0), pts)[0] + noise
        rs_meas = project_rolling(PINHOLE, _pose(v_true), pts)[0] + noise
        cases = {"gs": (gs_meas, 0.0, np.zeros(3), False), "rs_given": (rs_meas, 0.030, v_given, False),
                 "rs_est": (rs_meas, 0.030, np.zeros(3), True), "rs_off": (rs_meas, 0.0, np.zeros(3), False)}
        for name, (meas, readout, v0, est_v) in cases.items():
            start = (rodrigues([0.002, -0.001, 0.003])[0] @ NADIR, np.array([0.3, -0.2, Z + 0.5]), v0)
            (r, c, v), res, N = _resect(PINHOLE, pts, meas, readout, start, est_v)
            err[name].append((np.linalg.norm(c - truth[1]), _rotation_error_mrad(r, truth[0])))
            if est_v:
                v_z.append((v - v_true) / (0.5 * np.sqrt(np.diag(np.linalg.inv(N))[6:])))
            if name == "rs_off":
                # the residual pattern: column residuals trend with the row (t-test of the slope)
                row = meas[:, 1] - meas[:, 1].mean()
                slope = (row @ res[:, 0]) / (row @ row)
                resid = res[:, 0] - slope * row
                slopes_t.append(slope / np.sqrt(resid @ resid / (len(row) - 2) / (row @ row)))
    rms = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in err.items()}   # (position m, rotation mrad)
    assert np.all(rms["rs_given"] <= 1.2 * rms["gs"]), rms
    assert np.all(rms["rs_est"] <= 3.0 * rms["gs"]), rms          # one photo alone: the velocity costs 2-2.5x
    assert 0.7 <= np.sqrt(np.mean(np.square(v_z))) <= 1.3 and np.abs(v_z).max() < 3.5, v_z
    assert np.all(rms["rs_off"] > 5 * rms["gs"]), rms
    assert min(np.abs(slopes_t)) > 5, slopes_t
