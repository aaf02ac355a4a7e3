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
