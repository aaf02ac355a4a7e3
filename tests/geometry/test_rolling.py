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
