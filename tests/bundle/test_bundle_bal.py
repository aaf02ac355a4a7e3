"""BAL camera model over the engine (issue 11): Jacobians, a synthetic problem with known truth,
the Ladybug file's first steps, reader errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarcat.bundle.bal import BalFormatError, BalProblem, bal_project, read_bal, solve_bal

LADYBUG = Path(__file__).resolve().parents[2] / "benchmarks" / "data" / "problem-49-7776-pre.txt"


def _synthetic_bal(seed: int = 0, n_cam: int = 8, n_pt: int = 300, noise_px: float = 0.0):
    """Cameras on a circle looking at a cloud of points (BAL convention: looking along -z of the
    camera frame); observations exact or with Gaussian noise; truth returned."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(0, 1.0, (n_pt, 3))
    cams = np.zeros((n_cam, 9))
    for i in range(n_cam):
        a = 2 * np.pi * i / n_cam
        centre = np.array([6 * np.cos(a), 6 * np.sin(a), 0.5 * rng.normal()])
        back = centre / np.linalg.norm(centre)           # camera z axis points away from the cloud
        x = np.cross([0, 0, 1.0], back)
        x /= np.linalg.norm(x)
        y = np.cross(back, x)
        R = np.stack([x, y, back])
        from scipy.spatial.transform import Rotation

        cams[i, :3] = Rotation.from_matrix(R).as_rotvec()
        cams[i, 3:6] = -R @ centre
        cams[i, 6:9] = [500.0 + 20 * i, -0.05, 0.01]
    ci = np.repeat(np.arange(n_cam), n_pt)
    pj = np.tile(np.arange(n_pt), n_cam)
    obs = bal_project(cams, pts, ci, pj) + rng.normal(0, noise_px, (len(ci), 2))
    return BalProblem(ci, pj, obs, cams, pts), cams, pts


def test_bal_jacobians_equal_finite_differences():
    prob, cams, pts = _synthetic_bal(1)
    cams = cams + np.random.default_rng(2).normal(0, 0.01, cams.shape)
    sel = np.arange(0, len(prob.camera_index), 37)
    ci, pj = prob.camera_index[sel], prob.point_index[sel]
    x, jc, jp = bal_project(cams, pts, ci, pj, jacobians=True)
    for k in range(9):
        h = 1e-6 * max(1.0, abs(cams[:, k]).max())
        c2 = cams.copy()
        c2[:, k] += h
        c1 = cams.copy()
        c1[:, k] -= h
        num = (bal_project(c2, pts, ci, pj) - bal_project(c1, pts, ci, pj)) / (2 * h)
        np.testing.assert_allclose(jc[:, :, k], num, rtol=0, atol=1e-6 * np.abs(num).max())
    for k in range(3):
        q2, q1 = pts.copy(), pts.copy()
        q2[:, k] += 1e-6
        q1[:, k] -= 1e-6
        num = (bal_project(cams, q2, ci, pj) - bal_project(cams, q1, ci, pj)) / 2e-6
        np.testing.assert_allclose(jp[:, :, k], num, rtol=0, atol=1e-6 * np.abs(num).max())


def test_bal_solver_recovers_exact_synthetic_truth():
    """Exact observations: from perturbed cameras and points the cost falls to rounding level and
    the reprojections equal the observations (the gauge is free, so compare images, not parameters)."""
    prob, cams, pts = _synthetic_bal(3)
    rng = np.random.default_rng(4)
    start_c = cams + np.c_[rng.normal(0, 0.01, (len(cams), 6)), rng.normal(0, 1.0, (len(cams), 1)),
                           np.zeros((len(cams), 2))]
    start = BalProblem(prob.camera_index, prob.point_index, prob.observations_px, start_c,
                       pts + rng.normal(0, 0.02, pts.shape))
    r = solve_bal(start, function_tolerance=1e-12, max_iter=100)
    assert r.initial_cost > 1e2
    assert r.final_cost < 1e-12
    pred = bal_project(r.cameras, r.points, prob.camera_index, prob.point_index)
    np.testing.assert_allclose(pred, prob.observations_px, rtol=0, atol=1e-6)


def test_bal_noise_gives_chi_square_cost():
    """With 0.5 px noise the minimum cost is 0.5 sigma^2 (n - u + gauge) within 4 sd of the chi-square."""
    prob, cams, pts = _synthetic_bal(5, noise_px=0.5)
    r = solve_bal(BalProblem(prob.camera_index, prob.point_index, prob.observations_px, cams, pts),
                  function_tolerance=1e-10)
    n = 2 * len(prob.camera_index)
    dof = n - (9 * len(cams) + 3 * len(pts)) + 7           # the 7 gauge freedoms (similarity)
    expected = 0.5 * 0.25 * dof
    assert abs(r.final_cost - expected) < 4 * 0.5 * 0.25 * np.sqrt(2 * dof)


def test_ladybug_first_steps_decrease_the_cost_towards_the_published_minimum():
    """The BAL Ladybug file: 5 steps take the cost from 850,912 to within a few percent of the published
    minimum 13,344.3 and never below it (the full run is `python -m benchmarks.bal`)."""
    prob = read_bal(LADYBUG)
    assert (prob.n_cameras, prob.n_points, len(prob.camera_index)) == (49, 7776, 31843)
    r = solve_bal(prob, max_iter=5)
    assert abs(r.initial_cost - 850912.46) < 0.01
    assert 13344.3 * (1 - 1e-4) < r.final_cost < 13344.3 * 1.25


@pytest.mark.parametrize(("text", "message"), [
    ("2 1 x\n", r"bad.txt:1: expected 'cameras points observations'"),
    ("1 -1 1\n", r"bad.txt:1: expected 'cameras points observations'"),
    ("1 1 1\n0 0 1.0 2.0\n" + "0 " * 5, r"bad.txt: 9 values after line 1, the header announces 16"),
    ("1 1 1\n0 3 1.0 2.0\n" + "0 " * 12, r"bad.txt:2: point index 3 out of range \(there are 1\)"),
    ("1 1 1\n0 0 1.0 2.0\n" + "0\n" * 6 + "1x\n" + "0\n" * 5, r"bad.txt:9: '1x' is not a finite number"),
    ("1 1 1\n0 0 nan 2.0\n" + "0\n" * 12, r"bad.txt:2: 'nan' is not a finite number"),
    (None, r"bad.txt: file not found"),
])
def test_read_bal_errors(tmp_path, text, message):
    bad = tmp_path / "bad.txt"
    if text is not None:
        bad.write_text(text)
    with pytest.raises(BalFormatError, match=message):
        read_bal(bad)
