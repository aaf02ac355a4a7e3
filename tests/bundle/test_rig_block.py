"""Rigs in the bundle (issue 27): one body pose per exposure, the sensors' relative poses estimated.

Acceptance: a block of a three-camera rig (nadir body, two cameras tilted 30 deg forward and
backward, lever arms of a decimetre) from a calibration perturbed by 0.5 deg and 5 cm: the
relative poses are recovered within 3 sd (seed 0 fast, 20 seeds slow with the sds' honesty).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle import adjust, adjust_with_parameters
from lidarcat.bundle.rays import observation_parts, observation_project, sensor_jacobians
from lidarcat.bundle.rig import (RigRelativePoses, angles_from_matrix, photo_poses, rig_initial_points,
                                 rig_sensor_poses, rotation_log, with_rig)
from lidarcat.errors import CameraError, DatumError
from lidarcat.geometry.collinearity import project, rotation_matrix
from lidarcat.geometry.models import BrownCamera
from lidarcat.geometry.rigs import Rig, project_rig
from lidarcat.geometry.rolling import rodrigues
from lidarcat.synthetic.drone import DRONE_CAMERA, rig_block

D = np.diag([1.0, -1.0, -1.0])


def _relative_pose_z(block, res) -> np.ndarray:
    """Standardised errors of the estimated relative poses (rotation vector, translation) of the
    non-reference sensors, in the order of ``res.names``."""
    rays = res.bundle.problem.rays
    er = rotation_log(rays.sensor_rotation[1:] @ np.transpose(block.true_rotation[1:], (0, 2, 1)))
    ed = rays.sensor_translation_m[1:] - block.true_translation_m[1:]
    return np.concatenate([er, ed], axis=1).ravel() / res.sd


def _adjust(block):
    p = block.problem
    without = adjust(p, initial=(p.initial_eo, rig_initial_points(p, p.initial_eo)))
    return adjust_with_parameters(p, [RigRelativePoses(block.sensor_names)], without=without)


def test_the_bundle_projects_a_rig_as_geometry_rigs_does():
    """Thesis-frame sensor poses from a COLMAP-convention Rig give the pixels of project_rig; the
    composed photo poses (body o relative) give them through the plain collinearity."""
    c = DRONE_CAMERA
    w, h, f, pitch = c["width_px"], c["height_px"], c["focal_px"], c["pitch_mm"]
    cams = [BrownCamera(k, w, h, fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2) for k in ("a", "b", "c")]
    r_s = np.stack([np.eye(3), rodrigues([0.5, 0.05, -0.02])[0], rodrigues([-0.4, 0.03, 0.1])[0]])
    t_s = np.array([[0, 0, 0], [0.1, -0.2, 0.05], [-0.15, 0.1, 0.0]])
    rig = Rig("r", cams, r_s, t_s)
    q, d = rig_sensor_poses(rig)
    rng = np.random.default_rng(3)
    body = np.array([[1000.0, 2000.0, 100.0, 0.02, -0.01, 0.3], [1010.0, 2005.0, 101.0, -0.01, 0.02, 3.0]])
    n = 60
    ex, sensor = rng.integers(0, 2, n), rng.integers(0, 3, n)
    # points in front of each sensor: along its viewing ray at 80-120 m
    eo_s = photo_poses(body, q, d, ex, sensor)
    m_s = rotation_matrix(eo_s[:, 3:])
    ray = np.einsum("nji,nj->ni", m_s, np.c_[rng.uniform(-3, 3, (n, 2)), -np.full(n, 6.0)])
    X = eo_s[:, :3] + ray / np.linalg.norm(ray, axis=1)[:, None] * rng.uniform(80, 120, (n, 1))
    from lidarcat.bundle import BundleProblem
    p = BundleProblem(photo_ids=["0", "1"], point_ids=[str(j) for j in range(n)], focal_length_mm=f * pitch,
                      photo_index=ex, point_index=np.arange(n), xy_mm=np.zeros((n, 2)), sd_mm=1.0,
                      constraint_point_index=[], constraint_enh_m=np.zeros((0, 3)), constraint_sd_m=np.zeros((0, 3)))
    p = with_rig(p, sensor, q, d)
    xy, u3 = observation_project(p, body, X)
    assert np.all(u3 < 0)
    px = np.stack([xy[:, 0] / pitch + (w - 1) / 2, (h - 1) / 2 - xy[:, 1] / pitch], axis=1)
    ref, _ = project_rig(rig, sensor, D @ rotation_matrix(body[ex, 3:]), body[ex, :3], X)
    assert np.abs(px - ref).max() < 1e-9
    plain, _ = project(eo_s, X, np.full(n, f * pitch))
    assert np.abs(plain - xy).max() < 1e-12
    a = np.array([[0.1, -0.2, 2.5], [-0.3, 0.4, -3.0]])
    np.testing.assert_allclose(angles_from_matrix(rotation_matrix(a)), a, atol=1e-13)
    np.testing.assert_allclose(rotation_log(rodrigues([[0.1, -0.2, 0.3]])), [[0.1, -0.2, 0.3]], atol=1e-13)


def test_rig_jacobians_match_differences():
    b = rig_block(1, n_strips=2, exposures_per_strip=3, n_points=400)
    p, eo, pts = b.problem, b.true_eo, b.true_points_m
    xy, a_pt, a_ang, _ = observation_parts(p, eo, pts)
    h = 1e-6
    for k in range(3):
        e2 = eo.copy()
        e2[:, 3 + k] += h
        assert np.abs((observation_parts(p, e2, pts)[0] - xy) / h - a_ang[:, :, k]).max() < 1e-4
        e2 = eo.copy()
        e2[:, k] += h
        assert np.abs((observation_parts(p, e2, pts)[0] - xy) / h + a_pt[:, :, k]).max() < 1e-4
    J = sensor_jacobians(p, eo, pts)
    other = p.rays.sensor_index > 0
    for k in range(6):
        q, d = np.array(p.rays.sensor_rotation), np.array(p.rays.sensor_translation_m)
        if k < 3:
            q[1:] = rodrigues(np.eye(3)[k] * h)[0] @ q[1:]
        else:
            d[1:, k - 3] += h
        p2 = dataclasses.replace(p, rays=dataclasses.replace(p.rays, sensor_rotation=q, sensor_translation_m=d))
        fd = (observation_parts(p2, eo, pts)[0] - xy) / h
        assert np.abs(fd[other] - J[other, :, k]).max() < 1e-4 * max(1.0, np.abs(J[:, :, k]).max())


def test_a_point_seen_by_two_sensors_of_one_exposure_has_exact_normal_equations():
    """The reduced camera system with a point seen twice on one exposure: covariances equal the
    dense inverse of the normal equations."""
    b = rig_block(0, n_strips=2, exposures_per_strip=3, n_points=300)
    p = b.problem
    key = p.photo_index * p.n_points + p.point_index
    assert len(np.unique(key)) < len(key)                        # there are such points
    r = adjust(p, initial=(p.initial_eo, rig_initial_points(p, p.initial_eo)))
    assert r.success
    _, a_pt, a_ang, _ = observation_parts(p, r.eo_params, r.points_m)
    ei, pj, n = p.photo_index, p.point_index, len(p.photo_index)
    P, Q = p.n_photos, p.n_points
    A = np.zeros((2 * n, 6 * P + 3 * Q))
    for dd in range(2):
        rows = 2 * np.arange(n) + dd
        for k in range(3):
            A[rows, 6 * ei + k] = -a_pt[:, dd, k]
            A[rows, 6 * ei + 3 + k] = a_ang[:, dd, k]
            A[rows, 6 * P + 3 * pj + k] = a_pt[:, dd, k]
    N = A.T @ (A / np.repeat(p.sd_mm[:, 0] ** 2, 2)[:, None])
    for k, i in enumerate(p.constraint_point_index):
        N[6 * P + 3 * i + np.arange(3), 6 * P + 3 * i + np.arange(3)] += 1 / p.constraint_sd_m[k] ** 2
    for k, i in enumerate(p.eo_constraint_photo_index):
        N[6 * i + np.arange(3), 6 * i + np.arange(3)] += 1 / p.eo_constraint_sd[k, :3] ** 2
    C = np.linalg.inv(N)
    eo_cov = np.array([C[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(P)])
    pt_cov = np.array([C[6 * P + 3 * j:6 * P + 3 * j + 3, 6 * P + 3 * j:6 * P + 3 * j + 3] for j in range(Q)])
    assert np.abs(r.eo_cov - eo_cov).max() < 1e-9 * np.abs(eo_cov).max()
    assert np.abs(r.point_cov - pt_cov).max() < 1e-9 * np.abs(pt_cov).max()


def test_rig_block_recovers_the_relative_poses_within_3_sd():
    b = rig_block(0)
    res = _adjust(b)
    assert res.bundle.success and res.singular == ""
    assert res.names[:6] == tuple(f"rig.forward.{c}" for c in ("rx", "ry", "rz", "tx", "ty", "tz"))
    start = b.problem.rays.sensor_translation_m
    assert res.calibrated["rig.forward.rx"] == 0.0 and res.calibrated["rig.backward.tz"] == start[2, 2]
    z = _relative_pose_z(b, res)
    assert np.abs(z).max() < 3
    # the start calibration was 0.5 deg / 5 cm off; the estimate is within 0.01 deg / 1 cm
    assert res.sd[:3].max() < np.radians(0.01) and res.sd[3:6].max() < 0.01
    dp = np.asarray(res.bundle.eo_params)[:, :3] - b.true_eo[:, :3]
    assert np.sqrt((dp**2).sum(axis=1).mean()) < 0.03
    assert abs(res.bundle.sigma0_sq - 1) < 0.1


def test_rig_bad_input_is_refused():
    b = rig_block(0, n_strips=2, exposures_per_strip=3, n_points=300)
    p = b.problem
    q = np.array(p.rays.sensor_rotation)
    with pytest.raises(CameraError, match="rig: sensor 0 is the body: its relative pose must be the identity"):
        with_rig(p, p.rays.sensor_index, q[::-1], p.rays.sensor_translation_m)
    with pytest.raises(CameraError, match=r"rig 'rig': estimated sensors must be 1\.\.2 \(sensor 0, 'nadir', is the "
                                          r"body\)"):
        RigRelativePoses(b.sensor_names, estimate=[0, 1]).bind(p)
    with pytest.raises(CameraError, match="rig 'rig': 2 sensor name"):
        RigRelativePoses(b.sensor_names[:2]).bind(p)
    # the same sensor twice on one exposure is still a duplicate measurement
    i = int(np.flatnonzero(p.rays.sensor_index == 1)[0])
    dup = dataclasses.replace(
        p, photo_index=np.r_[p.photo_index, p.photo_index[i]], point_index=np.r_[p.point_index, p.point_index[i]],
        xy_mm=np.r_[p.xy_mm, p.xy_mm[i:i + 1]], sd_mm=np.r_[p.sd_mm, p.sd_mm[i:i + 1]],
        rays=dataclasses.replace(p.rays, sensor_index=np.r_[p.rays.sensor_index, 1]))
    from lidarcat.bundle import check_datum
    with pytest.raises(DatumError, match=f"point '{p.point_ids[p.point_index[i]]}' is measured twice on photo"):
        check_datum(dup)


@pytest.mark.slow
def test_rig_relative_poses_are_honest_over_seeds():
    """20 seeds: every relative-pose parameter within 3.5 sd, and the pooled standardised errors
    with an rms within 0.8-1.25 (240 values)."""
    z = np.concatenate([_relative_pose_z(b, _adjust(b)) for b in (rig_block(s) for s in range(20))])
    rms = float(np.sqrt(np.mean(z**2)))
    assert 0.8 < rms < 1.25, rms
    assert np.abs(z).max() < 3.5


def test_exposure_problem_from_photos_gives_the_rig_block():
    """A block of photos (one per sensor and exposure, as a survey lists them) turned into the
    block of exposures equals the rig block; two photos of one sensor in an exposure are refused."""
    from lidarcat.bundle import BundleProblem
    from lidarcat.bundle.rig import exposure_problem

    b = rig_block(2, n_strips=2, exposures_per_strip=4, n_points=800)
    p = b.problem
    r = p.rays
    n_s = len(r.sensor_rotation)
    pairs, inv = np.unique(p.photo_index * n_s + r.sensor_index, return_inverse=True)
    ex, sensor = pairs // n_s, pairs % n_s
    eo = photo_poses(p.initial_eo, r.sensor_rotation, r.sensor_translation_m, ex, sensor)
    ref = np.flatnonzero(sensor == 0)
    photos = BundleProblem(
        photo_ids=[f"{p.photo_ids[e]}_{b.sensor_names[s]}" for e, s in zip(ex, sensor)], point_ids=p.point_ids,
        focal_length_mm=p.focal_length_mm[ex], photo_index=inv, point_index=p.point_index, xy_mm=p.xy_mm,
        sd_mm=p.sd_mm, constraint_point_index=p.constraint_point_index, constraint_enh_m=p.constraint_enh_m,
        constraint_sd_m=p.constraint_sd_m, eo_constraint_photo_index=ref,
        eo_constraint_params=p.eo_constraint_params[ex[ref]], eo_constraint_sd=p.eo_constraint_sd[ex[ref]],
        initial_eo=eo)
    out, index = exposure_problem(photos, [p.photo_ids[e] for e in ex], sensor, r.sensor_rotation,
                                  r.sensor_translation_m, sensor_names=b.sensor_names)
    np.testing.assert_array_equal(index, ex)
    assert tuple(out.photo_ids) == tuple(p.photo_ids)
    np.testing.assert_array_equal(out.photo_index, p.photo_index)
    np.testing.assert_array_equal(out.rays.sensor_index, r.sensor_index)
    np.testing.assert_allclose(out.initial_eo, p.initial_eo, atol=1e-9)
    np.testing.assert_array_equal(out.eo_constraint_photo_index, p.eo_constraint_photo_index)
    a = adjust(out, initial=(out.initial_eo, rig_initial_points(out, out.initial_eo)))
    c = adjust(p, initial=(p.initial_eo, rig_initial_points(p, p.initial_eo)))
    assert a.success and np.abs(np.asarray(a.eo_params) - np.asarray(c.eo_params)).max() < 1e-9
    twice = list(ex)
    twice[ref[1]] = twice[ref[0]]
    with pytest.raises(CameraError, match=rf"rig exposure '{p.photo_ids[ex[ref[0]]]}': photos "
                                          rf"'{photos.photo_ids[ref[0]]}' and '{photos.photo_ids[ref[1]]}' are both "
                                          r"of sensor 'nadir'"):
        exposure_problem(photos, [p.photo_ids[e] for e in twice], sensor, r.sensor_rotation, r.sensor_translation_m,
                         sensor_names=b.sensor_names)


def test_adjust_starts_a_rig_block_from_its_body_poses():
    """adjust() on a rig block without initial values: the body poses of initial_eo and the points
    intersected through the sensors; without body poses, a DatumError says what is needed."""
    b = rig_block(3, n_strips=2, exposures_per_strip=3, n_points=400)
    given = with_rig(b.problem, b.problem.rays.sensor_index, b.true_rotation, b.true_translation_m)
    r = adjust(given)
    assert r.success and abs(r.sigma0_sq - 1) < 0.15
    assert np.sqrt(np.mean((np.asarray(r.eo_params)[:, :3] - b.true_eo[:, :3]) ** 2)) < 0.05
    # the start calibration (0.5 deg, 5 cm off) taken as given: the block absorbs it badly
    assert adjust(b.problem).sigma0_sq > 2
    with pytest.raises(DatumError, match="a rig block needs approximate body poses of every exposure"):
        adjust(dataclasses.replace(b.problem, initial_eo=None))
