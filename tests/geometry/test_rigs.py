"""Rigs: projection through sensor_from_rig * rig_from_world, Jacobians, a rig calibration over 20 seeds, bad input."""

from __future__ import annotations

import re

import numpy as np
import pytest

from lidarcat.errors import CameraError
from lidarcat.geometry.models import BrownCamera, FisheyeCamera
from lidarcat.geometry.rigs import Rig, project_rig
from lidarcat.geometry.rolling import rodrigues


def _rig() -> Rig:
    cams = [BrownCamera("front", 2000, 1500, fx=1500.0, fy=1500.0, cx=999.5, cy=749.5, k1=-0.05, p1=1e-4),
            BrownCamera("left", 2000, 1500, fx=1480.0, fy=1482.0, cx=1003.0, cy=751.0, k1=-0.04),
            FisheyeCamera("down", 1280, 1024, fx=500.0, fy=500.0, cx=640.0, cy=512.0, k1=0.01)]
    rot = np.array([np.eye(3), rodrigues([0.0, -0.5, 0.02])[0], rodrigues([0.4, 0.0, 0.0])[0]])
    return Rig("r", cams, rot, np.array([[0.0, 0.0, 0.0], [0.12, 0.0, -0.03], [0.0, 0.08, 0.05]]))


def _look(c, target):
    z = target - c
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    return np.array([x, np.cross(z, x), z])


def _observations(rig, pts, poses):
    """(sensor, frame, point index) of every point in view of every sensor of every exposure."""
    s_all, f_all, j_all = [], [], []
    for f, (r, c) in enumerate(poses):
        for k, cam in enumerate(rig.cameras):
            x = (np.einsum("ij,nj->ni", rig.rotation[k] @ r, pts - c) + rig.translation_m[k])
            ang = np.degrees(np.arctan2(np.hypot(x[:, 0], x[:, 1]), x[:, 2]))
            ok = ang < (80 if isinstance(cam, FisheyeCamera) else 35)
            px = np.full((len(pts), 2), -1.0)
            px[ok] = cam.project(x[ok])
            ok &= (px[:, 0] > 0) & (px[:, 0] < cam.width_px - 1) & (px[:, 1] > 0) & (px[:, 1] < cam.height_px - 1)
            j = np.flatnonzero(ok)
            s_all.append(np.full(len(j), k))
            f_all.append(np.full(len(j), f))
            j_all.append(j)
    return np.concatenate(s_all), np.concatenate(f_all), np.concatenate(j_all)


def test_projection_is_the_composition_and_jacobians_match_differences():
    rig = _rig()
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-4, 4, 60), rng.uniform(-4, 4, 60), rng.uniform(0, 2, 60)])
    rr = rodrigues([0.1, -0.05, 0.3])[0] @ _look(np.array([6.0, 1.0, 3.0]), np.zeros(3))
    cr = np.array([6.0, 1.0, 3.0])
    s, _, j = _observations(rig, pts, [(rr, cr)])
    assert set(s) == {0, 1, 2}
    px, jac = project_rig(rig, s, rr, cr, pts[j])
    for k in range(3):
        sel = s == k
        x = (rig.rotation[k] @ rr @ (pts[j][sel] - cr).T).T + rig.translation_m[k]
        np.testing.assert_allclose(px[sel], rig.cameras[k].project(x), atol=1e-9)
    h = 1e-6
    for k in range(3):
        d = np.zeros(3)
        d[k] = h
        pairs = {
            "point": lambda e: project_rig(rig, s, rr, cr, pts[j] + e)[0],
            "rig_position": lambda e: project_rig(rig, s, rr, cr + e, pts[j])[0],
            "rig_rotation": lambda e: project_rig(rig, s, rodrigues(e)[0] @ rr, cr, pts[j])[0],
            "sensor_rotation": lambda e: project_rig(Rig("r", rig.cameras, np.array(
                [rig.rotation[0]] + [rodrigues(e)[0] @ r for r in rig.rotation[1:]]), rig.translation_m),
                s, rr, cr, pts[j])[0],
            "sensor_translation": lambda e: project_rig(Rig("r", rig.cameras, rig.rotation, np.vstack(
                [rig.translation_m[:1], rig.translation_m[1:] + e])), s, rr, cr, pts[j])[0],
        }
        for name, f in pairs.items():
            fd = (f(d) - f(-d)) / (2 * h)
            np.testing.assert_allclose(jac[name][:, :, k], fd, rtol=1e-5, atol=1e-5 * np.abs(fd).max(), err_msg=name)


def test_rig_calibration_recovers_the_relative_poses_with_honest_sds():
    """6 exposures of one rig body over a test field, 0.5 px noise: the sensor_from_rig of the two
    non-reference sensors (12 unknowns) beside 6 unknowns per exposure; 20 seeds."""
    rig = _rig()
    z_all = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        noise_rng = np.random.default_rng([seed, 1])
        pts = np.column_stack([rng.uniform(-6, 6, 250), rng.uniform(-6, 6, 250), rng.uniform(0, 3, 250)])
        poses = []
        for f in range(6):
            a = 2 * np.pi * f / 6
            c = np.array([7 * np.cos(a), 7 * np.sin(a), 3.0 + f % 2])
            poses.append((_look(c, np.array([0.0, 0.0, 1.0])), c))
        s, fr, j = _observations(rig, pts, poses)
        rr = np.array([poses[f][0] for f in fr])
        cr = np.array([poses[f][1] for f in fr])
        meas = project_rig(rig, s, rr, cr, pts[j])[0] + noise_rng.normal(0, 0.5, (len(j), 2))
        # start off the truth; unknowns: 6 per exposure, 6 per non-reference sensor
        cur_r = [rodrigues(rng.normal(0, 0.003, 3))[0] @ r for r, _ in poses]
        cur_c = [c + rng.normal(0, 0.02, 3) for _, c in poses]
        cur_rig = Rig("r", rig.cameras, np.array([np.eye(3)] + [rodrigues(rng.normal(0, 0.003, 3))[0] @ r
                                                                for r in rig.rotation[1:]]),
                      np.vstack([np.zeros(3), rig.translation_m[1:] + rng.normal(0, 0.005, (2, 3))]))
        nf, nu = len(poses), 6 * len(poses) + 12
        for _ in range(15):
            px, jac = project_rig(cur_rig, s, np.array([cur_r[f] for f in fr]), np.array([cur_c[f] for f in fr]),
                                  pts[j])
            A = np.zeros((len(j), 2, nu))
            rows = np.arange(len(j))
            for q in range(3):
                A[rows, :, 6 * fr + q] = jac["rig_rotation"][:, :, q]
                A[rows, :, 6 * fr + 3 + q] = jac["rig_position"][:, :, q]
                sens = s > 0
                A[rows[sens], :, 6 * nf + 6 * (s[sens] - 1) + q] = jac["sensor_rotation"][sens, :, q]
                A[rows[sens], :, 6 * nf + 6 * (s[sens] - 1) + 3 + q] = jac["sensor_translation"][sens, :, q]
            A = A.reshape(-1, nu)
            N = A.T @ A
            step = np.linalg.solve(N, A.T @ (meas - px).ravel())
            cur_r = [rodrigues(step[6 * f:6 * f + 3])[0] @ cur_r[f] for f in range(nf)]
            cur_c = [cur_c[f] + step[6 * f + 3:6 * f + 6] for f in range(nf)]
            rot = [np.eye(3)] + [rodrigues(step[6 * nf + 6 * k:6 * nf + 6 * k + 3])[0] @ cur_rig.rotation[k + 1]
                                 for k in range(2)]
            tr = [np.zeros(3)] + [cur_rig.translation_m[k + 1] + step[6 * nf + 6 * k + 3:6 * nf + 6 * k + 6]
                                  for k in range(2)]
            cur_rig = Rig("r", rig.cameras, np.array(rot), np.array(tr))
            if np.abs(step).max() < 1e-11:
                break
        sd = 0.5 * np.sqrt(np.diag(np.linalg.inv(N)))[6 * nf:]
        err = []
        for k in (1, 2):
            d = cur_rig.rotation[k] @ rig.rotation[k].T                # small rotation: its vector
            err += [d[2, 1], d[0, 2], d[1, 0]] + list(cur_rig.translation_m[k] - rig.translation_m[k])
        z_all.append(np.array(err) / sd)
    z = np.array(z_all)
    assert 0.8 <= np.sqrt(np.mean(z ** 2)) <= 1.25, np.sqrt(np.mean(z ** 2, axis=0))
    assert np.abs(z).max() < 3.5


def test_bad_rigs_are_refused():
    rig = _rig()
    with pytest.raises(CameraError, match=re.escape("rig 'x': the reference sensor (camera 'front') is the rig frame: "
                                                    "its sensor_from_rig must be the identity")):
        Rig("x", rig.cameras, rig.rotation, rig.translation_m + 0.1)
    with pytest.raises(CameraError, match=re.escape("rig 'x': camera 'front' is sensor 0 and 1")):
        Rig("x", [rig.cameras[0], rig.cameras[0]], rig.rotation[:2], rig.translation_m[:2])
    with pytest.raises(CameraError, match=re.escape("rig 'x': sensor 1 (camera 'left'): rotation is no rotation")):
        Rig("x", rig.cameras, rig.rotation * np.array([1, 1.01, 1])[:, None, None], rig.translation_m)
    with pytest.raises(CameraError, match=re.escape(
            "rig 'r': image 'img7.jpg' is 1920 x 1080 px, its camera 'left' 2000 x 1500 px: the rig's cameras "
            "disagree in size")):
        rig.check_image_sizes({"img1.jpg": ("front", 2000, 1500), "img7.jpg": ("left", 1920, 1080)})
    with pytest.raises(CameraError, match=re.escape("rig 'r': image 'a' is of camera 'rear', which is not in the rig "
                                                    "(cameras: front, left, down)")):
        rig.check_image_sizes({"a": ("rear", 10, 10)})
    with pytest.raises(CameraError, match=re.escape("rig 'r': sensor indices must be 1 integers 0..2")):
        project_rig(rig, [3], np.eye(3), np.zeros(3), [[0.0, 0.0, 5.0]])
