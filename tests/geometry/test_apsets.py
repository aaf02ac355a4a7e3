"""Self-calibration parameter sets: their sizes, Ebner's printed form, orthogonality over the grids, Jacobians."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lidarcat.errors import CameraError
from lidarcat.geometry.apsets import PARAMETER_SETS, orientation_functions, parameter_set


def test_sets_and_their_sizes():
    assert {k: len(v.parameters) for k, v in PARAMETER_SETS.items()} == {
        "thesis": 8, "brown": 11, "ebner": 12, "gruen": 44}
    assert parameter_set("brown").parameters == ("c", "x0", "y0", "k1", "k2", "k3", "p1", "p2", "k4", "b1", "b2")
    assert parameter_set("Ebner").extra[-1] == "e12"


def test_unknown_set_is_refused():
    with pytest.raises(CameraError, match=re.escape(
            "unknown self-calibration parameter set 'fraser'; known: thesis, brown, ebner, gruen")):
        parameter_set("fraser")
    with pytest.raises(CameraError, match=re.escape("parameter set 'ebner': 12 values expected (e1, e2")):
        parameter_set("ebner").corrections([[0.0, 0.0]], np.zeros(3), 1.0)


@pytest.mark.parametrize("name,grid", [("ebner", 3), ("gruen", 5)])
def test_polynomials_and_orientation_terms_are_an_orthogonal_basis_over_the_grid(name, grid):
    s = parameter_set(name)
    b = 7.5  # mm: any spacing
    k = np.arange(grid) - (grid - 1) // 2
    pts = np.stack(np.meshgrid(k * b, k * b), axis=-1).reshape(-1, 2)
    f = s.jacobian(pts, b)                                            # (N, 2, m)
    u = pts / b
    orient = np.array([[np.ones(len(u)), np.zeros(len(u))], [np.zeros(len(u)), np.ones(len(u))],
                       [u[:, 0], u[:, 1]], [-u[:, 1], u[:, 0]], [u[:, 0] ** 2, u[:, 0] * u[:, 1]],
                       [u[:, 0] * u[:, 1], u[:, 1] ** 2]]).transpose(2, 1, 0)   # (N, 2, 6)
    assert orientation_functions(grid).shape[:2] == (6, 2)
    a = np.concatenate([f, orient], axis=2).reshape(-1, s.coef.shape[0] + 6)
    gram = a.T @ a
    off = gram - np.diag(np.diag(gram))
    m = s.coef.shape[0]
    assert np.abs(off[:m]).max() <= 1e-9 * np.abs(gram).max()          # orthogonal to each other and to EO
    assert np.linalg.matrix_rank(a) == 2 * grid * grid                 # with the six: a basis of the grid


def test_ebner_matches_his_printed_form():
    s = parameter_set("ebner")
    b = 12.0
    rng = np.random.default_rng(3)
    th = rng.normal(size=12)
    xy = rng.uniform(-b, b, size=(50, 2))
    x, y = xy[:, 0], xy[:, 1]
    deg = np.array([1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4])
    bb = th / b ** deg                                                 # his b_i
    q = 2 * b * b / 3
    dx = (bb[0] * x + bb[1] * y - bb[2] * (2 * x * x - 4 * b * b / 3) + bb[3] * x * y + bb[4] * (y * y - q)
          + bb[6] * x * (y * y - q) + bb[8] * y * (x * x - q) + bb[10] * (x * x - q) * (y * y - q))
    dy = (-bb[0] * y + bb[1] * x + bb[2] * x * y - bb[3] * (2 * y * y - 4 * b * b / 3) + bb[5] * (x * x - q)
          + bb[7] * y * (x * x - q) + bb[9] * x * (y * y - q) + bb[11] * (x * x - q) * (y * y - q))
    np.testing.assert_allclose(s.corrections(xy, th, b), np.column_stack([dx, dy]), rtol=1e-12, atol=1e-12)


def test_brown_extras_are_k4_and_the_affinity():
    s = parameter_set("brown")
    xy = np.array([[3.0, -2.0], [-1.5, 4.0]])
    r8 = (xy ** 2).sum(axis=1) ** 4
    got = s.corrections(xy, [2e-9, 1e-4, -3e-4], s.scale_mm(36.0, 24.0))
    want = np.column_stack([2e-9 * xy[:, 0] * r8 + 1e-4 * xy[:, 0] - 3e-4 * xy[:, 1], 2e-9 * xy[:, 1] * r8])
    np.testing.assert_allclose(got, want, rtol=1e-13)


@pytest.mark.parametrize("name", ["brown", "ebner", "gruen"])
def test_jacobian_xy_matches_finite_differences(name):
    s = parameter_set(name)
    b = s.scale_mm(36.0, 24.0)
    rng = np.random.default_rng(5)
    th = rng.normal(size=len(s.extra)) * (1e-3 if name != "brown" else np.array([1e-9, 1e-4, 1e-4]))
    xy = rng.uniform(-18, 18, size=(20, 2))
    j = s.jacobian_xy(xy, th, b)
    for k in range(2):
        d = np.zeros(2)
        d[k] = 1e-5
        fd = (s.corrections(xy + d, th, b) - s.corrections(xy - d, th, b)) / 2e-5
        np.testing.assert_allclose(j[:, :, k], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())


# ---------------------------------------------------------------- the bundle hook-up, in miniature
def _dist(cam, fot):
    d = cam.distortion_corrections(fot)
    return np.column_stack([d["dx_ra"] + d["dx_des"] + d["dx_ref"], d["dy_ra"] + d["dy_des"] + d["dy_ref"]])


def _i_minus_dd(cam, fot):
    """I - dD/dx_fot from the public pixel Jacobian (eq. 01: d x_fot / d px = diag(t_x, -t_y))."""
    px = cam.image_centre_to_pixel(fot + np.array([cam.principal_point_x_mm, cam.principal_point_y_mm]))
    return cam.pixel_to_photo_jacobian(px) / np.array([cam.pixel_size_x_mm, -cam.pixel_size_y_mm])[None, None, :]


def _set_calibration(name, seeds, *, design_at_truth=False):
    """Standardised errors (seeds, m) of the set's parameters in the test-field calibration of
    :func:`test_additional_parameters_calibrate_with_honest_sds` (docstring there).  *design_at_truth*
    evaluates the set's functions (the design columns ``f_i``) at the error-free coordinates instead
    of the measured ones (a diagnostic: the data and the residuals stay the same)."""
    from lidarcat.geometry.camera import Camera
    from lidarcat.geometry.rolling import rodrigues

    cam = Camera("dcs", 28.0, 0.05, -0.03, -1.2e-4, 2e-7, 0.0, 3e-6, -2e-6, 0.0, 0.009, 0.009, 3000, 2000)
    s = parameter_set(name)
    b = s.scale_mm(*cam.frame_size_mm)
    m = len(s.extra)
    sigma = 0.005
    z_all = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        noise = np.random.default_rng([seed, 1])
        theta_true = rng.normal(0, 0.003, m)                          # mm at the grid unit
        pts = np.column_stack([rng.uniform(-5, 5, 400), rng.uniform(-5, 5, 400), rng.uniform(0, 3, 400)])
        poses = []
        for k in range(12):
            a = 2 * np.pi * k / 12
            c = np.array([6 * np.cos(a), 6 * np.sin(a), 5.0 + (k % 3)])
            zax = np.array([0.0, 0.0, 1.0]) - c
            zax /= np.linalg.norm(zax)
            xax = np.cross([0.0, 0.0, 1.0], zax)
            xax /= np.linalg.norm(xax)
            poses.append((rodrigues([0.0, 0.0, np.pi / 2 * (k % 4)])[0] @ np.array([xax, np.cross(zax, xax), zax]),
                          c))
        obs = []
        for i, (r, c) in enumerate(poses):
            xc = (pts - c) @ r.T
            target = 28.0 * np.column_stack([xc[:, 0] / xc[:, 2], -xc[:, 1] / xc[:, 2]])
            w, h = cam.frame_size_mm
            j = np.flatnonzero((np.abs(target[:, 0]) < w / 2 - 0.3) & (np.abs(target[:, 1]) < h / 2 - 0.3)
                               & (xc[:, 2] > 0))
            fot = target[j].copy()                                     # invert x_fot - D - A = target
            for _ in range(30):
                f = fot - _dist(cam, fot) - s.corrections(fot, theta_true, b) - target[j]
                if np.abs(f).max() < 1e-13:
                    break
                jac = _i_minus_dd(cam, fot) - s.jacobian_xy(fot, theta_true, b)
                fot -= np.linalg.solve(jac, f[:, :, None])[:, :, 0]
            obs.append((i, j, fot + noise.normal(0, sigma, fot.shape), fot.copy()))
        nu = 6 * len(poses) + 3 + m
        cur = [(rodrigues(rng.normal(0, 0.002, 3))[0] @ r, c + rng.normal(0, 0.01, 3)) for r, c in poses]
        g = np.zeros(3 + m)                                           # dc, dx0, dy0, theta
        for _ in range(10):
            N = np.zeros((nu, nu))
            rhs = np.zeros(nu)
            for i, j, fot_meas, fot_true in obs:
                r, c = cur[i]
                xc = (pts[j] - c) @ r.T
                cc = 28.0 + g[0]
                pred = cc * np.column_stack([xc[:, 0] / xc[:, 2], -xc[:, 1] / xc[:, 2]])
                fot = fot_meas - g[1:3]
                xf = fot - _dist(cam, fot) - s.corrections(fot, g[3:], b)
                dpred = np.zeros((len(j), 2, 3))
                dpred[:, 0, 0], dpred[:, 0, 2] = cc / xc[:, 2], -cc * xc[:, 0] / xc[:, 2] ** 2
                dpred[:, 1, 1], dpred[:, 1, 2] = -cc / xc[:, 2], cc * xc[:, 1] / xc[:, 2] ** 2
                A = np.zeros((len(j), 2, nu))
                A[:, :, 6 * i:6 * i + 3] = -dpred @ np.stack([np.stack([np.zeros(len(j)), -xc[:, 2], xc[:, 1]], -1),
                                                            np.stack([xc[:, 2], np.zeros(len(j)), -xc[:, 0]], -1),
                                                            np.stack([-xc[:, 1], xc[:, 0], np.zeros(len(j))], -1)], -2)
                A[:, :, 6 * i + 3:6 * i + 6] = -dpred @ r
                o = 6 * len(poses)
                A[:, :, o] = pred / cc
                A[:, :, o + 1:o + 3] = _i_minus_dd(cam, fot) - s.jacobian_xy(fot, g[3:], b)
                A[:, :, o + 3:] = s.jacobian(fot_true if design_at_truth else fot, b)
                A = A.reshape(-1, nu)
                N += A.T @ A
                rhs -= A.T @ (pred - xf).ravel()
            sc = 1 / np.sqrt(np.diag(N))
            step = sc * np.linalg.solve(N * sc[:, None] * sc[None, :], rhs * sc)
            cur = [(rodrigues(step[6 * i:6 * i + 3])[0] @ r, c + step[6 * i + 3:6 * i + 6]) for i, (r, c) in
                   enumerate(cur)]
            g = g + step[6 * len(poses):]
            if np.abs(step * np.sqrt(np.diag(N))).max() < 1e-8:
                break
        sc = 1 / np.sqrt(np.diag(N))
        sd = sigma * np.sqrt(np.diag(np.linalg.inv(N * sc[:, None] * sc[None, :]))) * sc
        z_all.append((g[3:] - theta_true) / sd[6 * len(poses) + 3:])
    return np.array(z_all)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ebner"])
def test_additional_parameters_calibrate_with_honest_sds(name):
    """The hook-up of docs/cameras.md, as the bundle will do it: observations x_fotc = x_fot - D - A(theta),
    v = c (X/Z, -Y/Z) - x_fotc, dv/dtheta_i = f_i(x_fot), dv/dx0 = (I - dD - dA) e_x; c, x0, y0 and the
    set's parameters with 6 pose unknowns per photo; 12 photos of a 3-D test field, 0.005 mm noise on x_fot,
    20 seeds: the standardised errors of the set's parameters have rms 0.8-1.25 (measured: Ebner 0.985,
    largest 2.5).  Grün's set is not asserted: its x components odd in u are over-dispersed (rms
    1.4-2.0 over seeds 0-19 and again over 20-39, pooled 1.10 and 1.27); the cause is
    :func:`test_gruen_over_dispersion_is_errors_in_variables` (docs/cameras.md)."""
    z = _set_calibration(name, range(20))
    assert 0.8 <= np.sqrt(np.mean(z ** 2)) <= 1.25, np.sqrt(np.mean(z ** 2, axis=0))
    assert np.mean(np.abs(z) > 3) <= 0.01



@pytest.mark.slow
def test_gruen_over_dispersion_is_errors_in_variables():
    """The cause of Grün's over-dispersion (docs/cameras.md): the set's functions are evaluated at the
    *measured* coordinates, which carry the noise ``e`` the residuals carry, so ``E[f_i(x + e)^T e] =
    sigma^2 div f_i``: a bias of the normal equations' right-hand side wherever the divergence does not
    average out -- the x-terms odd in u and even in v (g1, g7, g11, g27, g31, g41: ``d/dx P_odd(u)`` is
    even) -- and they are correlated 0.74-1.00 with each other (nearly one direction with c), so the six
    move together.  Over the same 10 seeds: with the measured coordinates the six standardised errors
    average -1.3 (18 of 20 seeds negative over seeds 0-19); with the design evaluated at the error-free
    coordinates (same data, same residuals) the bias is gone and the six are honest."""
    names = parameter_set("gruen").extra
    cls = [names.index(q) for q in ("g1", "g7", "g11", "g27", "g31", "g41")]
    measured = _set_calibration("gruen", range(10))[:, cls]
    at_truth = _set_calibration("gruen", range(10), design_at_truth=True)[:, cls]
    assert measured.mean() < -0.8
    assert abs(at_truth.mean()) < 0.4
    assert 0.8 <= np.sqrt(np.mean(at_truth ** 2)) <= 1.25
