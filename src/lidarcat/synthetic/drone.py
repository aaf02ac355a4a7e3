r"""Synthetic drone blocks with known truth: a rolling-shutter camera, and a rig of cameras.

:func:`drone_block`: a frame pinhole camera (``f`` px, ``W x H`` px of ``pitch`` mm) flown in
``n_strips`` strips at ``height_m`` above a hilly ground at ``speed_m_s``, the top of the image
forward (strips alternate in direction, kappa 0 or pi), exposures ``base / speed`` apart.  Each
photo is read out row by row in ``readout_s`` while the camera moves linearly (the truth's
exterior orientation at the middle of the read-out): the row of a point solves
``v = P_v(X0 + V t(v))`` by fixed-point iteration (contraction ``f V T / (Z H)``, 0.003 here),
to 1e-9 px.  The noise (``image_sd_px`` on the pixels, ``gnss_sd_m`` on the camera positions,
``control_sd_m`` on the control) is drawn from a stream that does not depend on ``readout_s``:
the same seed with ``readout_s = 0`` is the global-shutter block of the same geometry and
the same noise -- the acceptance's reference.  Control: a few ground control points, the
camera positions (GNSS) as weighted constraints, and check points (unconstrained, with truth).

:func:`rig_block`: a rig of a nadir camera (the body) and two cameras tilted forward and
backward (``tilt_deg``) with lever arms of a decimetre, flown in strips; the problem's photos
are the rig's *exposures* (body poses), each observation carries its sensor
(:class:`lidarcat.bundle.rays.ObservationRays`), and the sensors' relative poses start from a
perturbed calibration (``pose_error_deg``, ``pose_error_m``) for
:class:`lidarcat.bundle.rig.RigRelativePoses` to recover.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._util.frozen import frozen_array
from ..bundle import BundleProblem
from ..bundle.rays import ObservationRays
from ..geometry.collinearity import project, rotation_matrix
from ..geometry.rolling import rodrigues

__all__ = ["DroneBlock", "drone_block", "rolling_pixels", "RigBlock", "rig_block", "DRONE_CAMERA"]

#: the drone camera: focal length (px), image size (px), pixel pitch (mm)
DRONE_CAMERA = {"focal_px": 3000.0, "width_px": 4000, "height_px": 3000, "pitch_mm": 0.004}


@dataclasses.dataclass(frozen=True, eq=False)
class DroneBlock:
    """A synthetic drone block (module docstring).

    Attributes
    ----------
    problem : BundleProblem
        The block as a global-shutter model sees it (no rays): image coordinates (mm),
        GNSS-constrained positions, control points; ``point_role`` marks the check points.
    true_eo : (P, 6) array
        Exterior orientation at the middle of every read-out (m, rad).
    true_points_m : (Q, 3) array
    true_velocity_m_s : (P, 3) array
    row_px : (n,) array
        Measured row of every observation (noise included).
    exposure_time_s : (P,) array
    line : tuple of str, (P,)
        Flight line of every photo.
    gnss_m : (P, 3) array
        Observed camera positions.
    readout_s, focal_mm, pitch_mm : float
    width_px, height_px : int
    check_index : (c,) int array
        The check points.
    """

    problem: BundleProblem
    true_eo: np.ndarray
    true_points_m: np.ndarray
    true_velocity_m_s: np.ndarray
    row_px: np.ndarray
    exposure_time_s: np.ndarray
    line: tuple
    gnss_m: np.ndarray
    readout_s: float
    focal_mm: float
    pitch_mm: float
    width_px: int
    height_px: int
    check_index: np.ndarray

    def __post_init__(self) -> None:
        for name in ("true_eo", "true_points_m", "true_velocity_m_s", "row_px", "exposure_time_s", "gnss_m",
                     "check_index"):
            object.__setattr__(self, name, frozen_array(getattr(self, name), dtype=None))


def _ground(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    return 8.0 * np.sin(e / 60.0) * np.cos(n / 45.0) + 3.0 * np.sin((e + n) / 23.0)


def rolling_pixels(eo, vel, pts, focal_mm, pitch, w_px, h_px, readout_s, ei, pj):
    """Exact rolling-shutter pixels (n, 2) (column, row) and u3 (n,) of observations (photo *ei*, point *pj*)
    through *eo* (P, 6) moving at *vel* (P, 3) m/s, the row solved (module docstring)."""
    c = np.full(len(ei), focal_mm)
    v_row = None
    for _ in range(30):
        t = np.zeros(len(ei)) if v_row is None else readout_s * ((v_row + 0.5) / h_px - 0.5)
        xy, u3 = project(eo[ei], pts[pj] - vel[ei] * t[:, None], c)
        new = (h_px - 1) / 2 - xy[:, 1] / pitch
        if v_row is not None and np.abs(new - v_row).max() < 1e-9:
            v_row = new
            break
        v_row = new
    return np.stack([xy[:, 0] / pitch + (w_px - 1) / 2, v_row], axis=1), u3


def drone_block(seed: int = 0, *, readout_s: float = 0.03, speed_m_s: float = 10.0, n_strips: int = 3,
                photos_per_strip: int = 10, height_m: float = 100.0, forward_overlap: float = 0.8,
                side_overlap: float = 0.6, n_points: int = 1500, image_sd_px: float = 0.5,
                gnss_sd_m: float = 0.03, control_sd_m: float = 0.01, n_check: int = 12) -> DroneBlock:
    """A drone block flown at *speed_m_s* with a read-out of *readout_s* (module docstring).

    Parameters
    ----------
    seed : int
        The truth and the noise (independent of *readout_s*).
    readout_s : float
        Read-out time from the top to the bottom row, s (0: global shutter).
    speed_m_s, n_strips, photos_per_strip, height_m, forward_overlap, side_overlap
        The flight.
    n_points : int
        Ground points drawn uniformly over the block (tie, control and check points).
    image_sd_px, gnss_sd_m, control_sd_m : float
        Noise of the pixels, the camera positions and the ground control (also their sds).
    n_check : int
        Check points (unconstrained, spread over the block).
    """
    cam = DRONE_CAMERA
    f_px, w_px, h_px, pitch = cam["focal_px"], cam["width_px"], cam["height_px"], cam["pitch_mm"]
    focal_mm = f_px * pitch
    rng = np.random.default_rng(seed)
    noise = np.random.default_rng([seed, 1])
    gsd = height_m / f_px
    along, across = h_px * gsd, w_px * gsd
    base = (1 - forward_overlap) * along
    gap = (1 - side_overlap) * across
    e0, n0 = 400000.0, 5500000.0
    eo, vel, times, line = [], [], [], []
    for s in range(n_strips):
        sign = 1.0 if s % 2 == 0 else -1.0
        # a straight line with a slow wander (0.5 m, periods 15-30 s): position and velocity consistent
        amp = rng.uniform(0.2, 0.5, 3)
        omega = 2 * np.pi / rng.uniform(15.0, 30.0, 3)
        phase = rng.uniform(0, 2 * np.pi, 3)
        for k in range(photos_per_strip):
            tk = k * base / speed_m_s
            kk = k if sign > 0 else photos_per_strip - 1 - k
            wander = amp * np.sin(omega * tk + phase)
            om, ph = np.radians(rng.normal(0, 0.5, 2))
            kap = (0.0 if sign > 0 else np.pi) + np.radians(rng.normal(0, 0.5))
            eo.append([e0 + s * gap + wander[0], n0 + kk * base + wander[1], height_m + wander[2], om, ph, kap])
            vel.append(np.array([0.0, sign * speed_m_s, 0.0]) + amp * omega * np.cos(omega * tk + phase))
            times.append(1000.0 * s + tk)
            line.append(f"L{s + 1}")
    eo = np.array(eo)
    eo[:, 5] = (eo[:, 5] + np.pi) % (2 * np.pi) - np.pi
    vel = np.array(vel)
    n_ph = len(eo)
    x_lo, x_hi = -across / 2 - 0.0, (n_strips - 1) * gap + across / 2
    y_lo, y_hi = -along / 2, (photos_per_strip - 1) * base + along / 2
    pe = rng.uniform(x_lo, x_hi, n_points)
    pn = rng.uniform(y_lo, y_hi, n_points)
    pts = np.stack([pe + e0, pn + n0, _ground(pe, pn)], axis=1)
    # visibility at the global-shutter geometry, with a margin of 2 % of the frame
    ph_all = np.repeat(np.arange(n_ph), n_points)
    pt_all = np.tile(np.arange(n_points), n_ph)
    xy, u3 = project(eo[ph_all], pts[pt_all], np.full(len(ph_all), focal_mm))
    half = np.array([w_px, h_px]) * pitch / 2 * 0.96
    inside = (np.abs(xy[:, 0]) < half[0]) & (np.abs(xy[:, 1]) < half[1]) & (u3 < 0)
    ei, pj = ph_all[inside], pt_all[inside]
    rays = np.bincount(pj, minlength=n_points)
    keep = rays >= 2
    new = np.cumsum(keep) - 1
    sel = keep[pj]
    ei, pj = ei[sel], new[pj[sel]]
    pts = pts[keep]
    q = len(pts)
    px, _ = rolling_pixels(eo, vel, pts, focal_mm, pitch, w_px, h_px, readout_s, ei, pj)
    px = px + noise.normal(0, image_sd_px, px.shape)
    xy_obs = np.stack([(px[:, 0] - (w_px - 1) / 2) * pitch, ((h_px - 1) / 2 - px[:, 1]) * pitch], axis=1)
    # control at the four corners and the middle, check points spread over the rest
    rel = (pts[:, :2] - [e0, n0] - [x_lo, y_lo]) / [x_hi - x_lo, y_hi - y_lo]
    many = np.bincount(pj, minlength=q) >= 3
    ctrl = []
    for tx, ty in ((0.12, 0.1), (0.88, 0.1), (0.12, 0.9), (0.88, 0.9), (0.5, 0.5)):
        d = np.hypot(rel[:, 0] - tx, rel[:, 1] - ty) + 10.0 * ~many
        ctrl.append(int(np.argmin(d)))
    ctrl = np.array(sorted(set(ctrl)))
    cand = np.setdiff1d(np.flatnonzero(many), ctrl)
    check = np.sort(rng.choice(cand, size=min(n_check, len(cand)), replace=False))
    role = np.full(q, "tie", dtype=object)
    role[ctrl] = "control"
    role[check] = "check"
    cobs = pts[ctrl] + noise.normal(0, control_sd_m, (len(ctrl), 3))
    gnss = eo[:, :3] + noise.normal(0, gnss_sd_m, (n_ph, 3))
    initial = np.concatenate([gnss, np.zeros((n_ph, 2)), np.where(np.abs(eo[:, 5:]) < 1, 0.0, np.pi)], axis=1)
    problem = BundleProblem(
        photo_ids=[f"D{i + 1:03d}" for i in range(n_ph)], point_ids=[f"G{j + 1:04d}" for j in range(q)],
        focal_length_mm=np.full(n_ph, focal_mm), photo_index=ei, point_index=pj, xy_mm=xy_obs,
        sd_mm=image_sd_px * pitch, constraint_point_index=ctrl, constraint_enh_m=cobs,
        constraint_sd_m=np.full((len(ctrl), 3), control_sd_m),
        eo_constraint_photo_index=np.arange(n_ph),
        eo_constraint_params=np.concatenate([gnss, np.zeros((n_ph, 3))], axis=1),
        eo_constraint_sd=np.concatenate([np.full((n_ph, 3), gnss_sd_m), np.full((n_ph, 3), np.inf)], axis=1),
        initial_eo=initial, point_role=role, info={"synthetic": "drone_block", "seed": seed})
    return DroneBlock(problem, eo, pts, vel, px[:, 1], np.array(times), tuple(line), gnss, float(readout_s),
                      focal_mm, pitch, w_px, h_px, check)


@dataclasses.dataclass(frozen=True, eq=False)
class RigBlock:
    """A synthetic rig block (module docstring).

    Attributes
    ----------
    problem : BundleProblem
        Photos = exposures (body poses); ``rays`` holds every observation's sensor and the
        *start* relative poses (the perturbed calibration).
    true_eo : (P, 6) array
        Body pose of every exposure (the reference camera's exterior orientation).
    true_points_m : (Q, 3) array
    true_rotation, true_translation_m : (S, 3, 3), (S, 3) arrays
        The sensors' relative poses (thesis image frame; ``u_s = Q u_body + d``).
    sensor_names : tuple of str
    """

    problem: BundleProblem
    true_eo: np.ndarray
    true_points_m: np.ndarray
    true_rotation: np.ndarray
    true_translation_m: np.ndarray
    sensor_names: tuple


def rig_block(seed: int = 0, *, n_strips: int = 3, exposures_per_strip: int = 8, height_m: float = 100.0,
              tilt_deg: float = 30.0, n_points: int = 2500, image_sd_px: float = 0.5, gnss_sd_m: float = 0.03,
              control_sd_m: float = 0.01, pose_error_deg: float = 0.5, pose_error_m: float = 0.05) -> RigBlock:
    """A block of a three-camera rig (module docstring).  The sensors share the drone camera
    (:data:`DRONE_CAMERA`); the nadir one is the body."""
    cam = DRONE_CAMERA
    f_px, w_px, h_px, pitch = cam["focal_px"], cam["width_px"], cam["height_px"], cam["pitch_mm"]
    focal_mm = f_px * pitch
    rng = np.random.default_rng(seed)
    noise = np.random.default_rng([seed, 2])
    tilt = np.radians(tilt_deg)
    q_true = np.stack([np.eye(3), rotation_matrix([tilt, 0.02, -0.01]), rotation_matrix([-tilt, -0.015, 0.01])])
    d_true = np.array([[0.0, 0.0, 0.0], [0.02, 0.12, -0.03], [-0.03, -0.11, 0.02]])
    gsd = height_m / f_px
    along, across = h_px * gsd, w_px * gsd
    base, gap = 0.3 * along, 0.45 * across
    e0, n0 = 400000.0, 5500000.0
    eo = []
    for s in range(n_strips):
        for k in range(exposures_per_strip):
            kk = k if s % 2 == 0 else exposures_per_strip - 1 - k
            om, ph = np.radians(rng.normal(0, 0.5, 2))
            kap = (0.0 if s % 2 == 0 else np.pi) + np.radians(rng.normal(0, 0.5))
            eo.append([e0 + s * gap + rng.normal(0, 0.5), n0 + kk * base + rng.normal(0, 0.5),
                       height_m + rng.normal(0, 0.5), om, ph, kap])
    eo = np.array(eo)
    eo[:, 5] = (eo[:, 5] + np.pi) % (2 * np.pi) - np.pi
    n_ex = len(eo)
    reach = height_m * np.tan(tilt) + along
    x_lo, x_hi = -across / 2, (n_strips - 1) * gap + across / 2
    y_lo, y_hi = -reach, (exposures_per_strip - 1) * base + reach
    pe, pn = rng.uniform(x_lo, x_hi, n_points), rng.uniform(y_lo, y_hi, n_points)
    pts = np.stack([pe + e0, pn + n0, _ground(pe, pn)], axis=1)
    n_s = len(q_true)
    ex_all = np.repeat(np.arange(n_ex), n_points * n_s)
    s_all = np.tile(np.repeat(np.arange(n_s), n_points), n_ex)
    pt_all = np.tile(np.arange(n_points), n_ex * n_s)
    full = BundleProblem(photo_ids=[str(i) for i in range(n_ex)], point_ids=[str(j) for j in range(n_points)],
                         focal_length_mm=np.full(n_ex, focal_mm), photo_index=ex_all, point_index=pt_all,
                         xy_mm=np.zeros((len(ex_all), 2)), sd_mm=1.0, constraint_point_index=[],
                         constraint_enh_m=np.zeros((0, 3)), constraint_sd_m=np.zeros((0, 3)),
                         rays=ObservationRays(sensor_index=s_all, sensor_rotation=q_true, sensor_translation_m=d_true))
    from ..bundle.rays import observation_project
    xy, u3 = observation_project(full, eo, pts)
    half = np.array([w_px, h_px]) * pitch / 2 * 0.96
    inside = (np.abs(xy[:, 0]) < half[0]) & (np.abs(xy[:, 1]) < half[1]) & (u3 < 0)
    keep_pt = np.bincount(pt_all[inside], minlength=n_points) >= 2
    sel = inside & keep_pt[pt_all]
    new = np.cumsum(keep_pt) - 1
    ei, sj, pj = ex_all[sel], s_all[sel], new[pt_all[sel]]
    pts = pts[keep_pt]
    q = len(pts)
    xy_obs = xy[sel] + noise.normal(0, image_sd_px * pitch, (int(sel.sum()), 2))
    rel = (pts[:, :2] - [e0, n0] - [x_lo, y_lo]) / [x_hi - x_lo, y_hi - y_lo]
    many = np.bincount(pj, minlength=q) >= 3
    ctrl = sorted({int(np.argmin(np.hypot(rel[:, 0] - tx, rel[:, 1] - ty) + 10.0 * ~many))
                   for tx, ty in ((0.15, 0.15), (0.85, 0.15), (0.15, 0.85), (0.85, 0.85), (0.5, 0.5))})
    ctrl = np.array(ctrl)
    cobs = pts[ctrl] + noise.normal(0, control_sd_m, (len(ctrl), 3))
    gnss = eo[:, :3] + noise.normal(0, gnss_sd_m, (n_ex, 3))
    # the start calibration: the truth perturbed
    q0 = np.array(q_true)
    d0 = np.array(d_true)
    for s in range(1, n_s):
        q0[s] = rodrigues(noise.normal(0, np.radians(pose_error_deg), 3))[0] @ q_true[s]
        d0[s] = d_true[s] + noise.normal(0, pose_error_m, 3)
    initial = np.concatenate([gnss, np.zeros((n_ex, 2)), np.where(np.abs(eo[:, 5:]) < 1, 0.0, np.pi)], axis=1)
    problem = BundleProblem(
        photo_ids=[f"X{i + 1:03d}" for i in range(n_ex)], point_ids=[f"G{j + 1:04d}" for j in range(q)],
        focal_length_mm=np.full(n_ex, focal_mm), photo_index=ei, point_index=pj, xy_mm=xy_obs,
        sd_mm=image_sd_px * pitch, constraint_point_index=ctrl, constraint_enh_m=cobs,
        constraint_sd_m=np.full((len(ctrl), 3), control_sd_m), eo_constraint_photo_index=np.arange(n_ex),
        eo_constraint_params=np.concatenate([gnss, np.zeros((n_ex, 3))], axis=1),
        eo_constraint_sd=np.concatenate([np.full((n_ex, 3), gnss_sd_m), np.full((n_ex, 3), np.inf)], axis=1),
        initial_eo=initial, info={"synthetic": "rig_block", "seed": seed},
        rays=ObservationRays(sensor_index=sj, sensor_rotation=q0, sensor_translation_m=d0))
    return RigBlock(problem, eo, pts, q_true, d_true, ("nadir", "forward", "backward"))
