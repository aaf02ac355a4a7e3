"""Every model's Jacobians calibrate it: a test-field calibration over 20 seeds recovers the truth with honest sds.

A 3-D test field of known points is photographed from 8 convergent stations (rolled by 0, 90,
180, 270 deg); the pixels get N(0, 0.5 px) noise (a random stream of its own, apart from the
geometry's); Gauss-Newton with the models' analytic
Jacobians estimates the 6 pose parameters of every photo and every intrinsic parameter, and
``sigma^2 N^-1`` gives their sds.  Over 20 seeds the standardised errors ``(estimate - truth) /
sd`` of all intrinsic parameters must look like N(0, 1): their rms within 0.8-1.25 (issue 27's
honesty band) and at most 1 % of them beyond 3.  (The bundle integration of the models is the
next session's; this checks the engine it will use.)
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.geometry.camera import Camera
from lidarcat.geometry.models import BrownCamera, FisheyeCamera, FrameModel
from lidarcat.geometry.rolling import rodrigues

SIGMA_PX = 0.5
SEEDS = range(20)


def _look_at(centre: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.array([x, y, z])                        # world -> camera
    return rodrigues([0.0, 0.0, roll])[0] @ r


def _skew(a: np.ndarray) -> np.ndarray:
    z = np.zeros(len(a))
    return np.stack([np.stack([z, -a[:, 2], a[:, 1]], -1), np.stack([a[:, 2], z, -a[:, 0]], -1),
                     np.stack([-a[:, 1], a[:, 0], z], -1)], -2)


def _calibrate(truth, distance: float, seed: int) -> np.ndarray:
    """Standardised errors of the intrinsic parameters of one noisy calibration."""
    rng = np.random.default_rng(seed)              # the geometry
    noise = np.random.default_rng([seed, 1])        # the pixel noise, a stream of its own
    pts = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-5, 5, 300), rng.uniform(0, 3, 300)])
    poses = []
    for k in range(8):
        a = 2 * np.pi * k / 8
        c = np.array([distance * np.cos(a), distance * np.sin(a), distance * 0.8])
        poses.append((_look_at(c, np.array([0.0, 0.0, 1.0]), np.pi / 2 * (k % 4)), c))
    obs = []
    for i, (r, c) in enumerate(poses):
        rays = (pts - c) @ r.T
        angle = np.degrees(np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]))
        rays[angle > (100 if isinstance(truth, FisheyeCamera) else 45)] = [0.0, 0.0, 1.0]  # out of view
        px = truth.project(rays)
        inside = (angle <= (100 if isinstance(truth, FisheyeCamera) else 45)) & ((px[:, 0] > 0) & (px[:, 0] < truth.width_px - 1) & (px[:, 1] > 0)
                  & (px[:, 1] < truth.height_px - 1))
        j = np.flatnonzero(inside)
        obs.append((i, j, px[j] + noise.normal(0, SIGMA_PX, (len(j), 2))))
    m = len(truth.PARAMETERS)
    n_unk = 6 * len(poses) + m
    # start: poses and intrinsics off the truth
    cur_poses = [(rodrigues(rng.normal(0, 0.005, 3))[0] @ r, c + rng.normal(0, 0.05, 3)) for r, c in poses]
    theta = truth.params() * (1 + np.where(np.arange(m) < 2, 0.003, 0.0))
    for _ in range(30):
        cam = truth.with_params(theta)
        N = np.zeros((n_unk, n_unk))
        g = np.zeros(n_unk)
        for i, j, meas in obs:
            r, c = cur_poses[i]
            rays = (pts[j] - c) @ r.T
            px, j_ray, j_par = cam.project_jacobians(rays)
            A = np.zeros((len(j), 2, n_unk))
            A[:, :, 6 * i:6 * i + 3] = -j_ray @ _skew(rays)       # rotation increment
            A[:, :, 6 * i + 3:6 * i + 6] = -j_ray @ r              # centre
            A[:, :, 6 * len(poses):] = j_par
            A = A.reshape(-1, n_unk)
            N += A.T @ A
            g += A.T @ (meas - px).ravel()
        s = 1 / np.sqrt(np.diag(N))
        step = s * np.linalg.solve(N * s[:, None] * s[None, :], g * s)
        for i, (r, c) in enumerate(cur_poses):
            cur_poses[i] = (rodrigues(step[6 * i:6 * i + 3])[0] @ r, c + step[6 * i + 3:6 * i + 6])
        theta = theta + step[6 * len(poses):]
        if np.all(np.abs(step) * np.sqrt(np.diag(N)) < 1e-8):
            break
    s = 1 / np.sqrt(np.diag(N))                                    # equilibrated: k3 is ~1e-10 mm^-6
    cov = SIGMA_PX ** 2 * s[:, None] * np.linalg.inv(N * s[:, None] * s[None, :]) * s[None, :]
    sd = np.sqrt(np.diag(cov))[6 * len(poses):]
    return (theta - truth.params()) / sd


CASES = {
    "brown": (BrownCamera("b", 4000, 3000, fx=3000.0, fy=3005.0, cx=2010.0, cy=1490.0, k1=-0.12, k2=0.09,
                          k3=-0.02, k4=0.003, p1=1e-3, p2=-5e-4, skew=0.5), 5.0),
    "fisheye": (FisheyeCamera("f", 1280, 1024, fx=500.0, fy=501.0, cx=640.0, cy=510.0, k1=0.02, k2=-0.01,
                              k3=0.003, k4=-0.0005), 4.0),
    "frame": (FrameModel(Camera("dcs", 28.0, 0.05, -0.03, -1.2e-4, 2e-7, -1e-10, 3e-6, -2e-6, 0.0, 0.009, 0.009,
                                3000, 2000)), 6.0),
}


@pytest.mark.parametrize("name", CASES)
def test_calibration_recovers_the_truth_with_honest_sds(name):
    truth, distance = CASES[name]
    z = np.array([_calibrate(truth, distance, seed) for seed in SEEDS])      # (20, m)
    rms = float(np.sqrt(np.mean(z ** 2)))
    assert 0.8 <= rms <= 1.25, (name, rms)
    assert np.mean(np.abs(z) > 3) <= 0.01, (name, np.abs(z).max(axis=0))
