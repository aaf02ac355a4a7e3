r"""Rigs in the bundle: one body pose per exposure, the sensors' relative poses given or estimated.

A rig exposure is one "photo" of the :class:`~lidarcat.bundle.BundleProblem`: its exterior
orientation is the *body* pose (the reference sensor's), and every observation carries the
sensor that made it (:class:`lidarcat.bundle.rays.ObservationRays`).  The sensor's photo is
the composition ``photo = body o relative``:

    u_s = Q_s u_b + d_s,   u_b = M_b (X - X0_b)
    =>  M_s = Q_s M_b,     X0_s = X0_b - M_b^T Q_s^T d_s

in the thesis image frame (x right, y up, the camera looking along ``-z``).  A
:class:`lidarcat.geometry.rigs.Rig` holds COLMAP's ``sensor_from_rig`` (x right, y down,
z forward): with ``D = diag(1, -1, -1)`` (the thesis frame of a COLMAP frame,
``u = D x``), ``Q_s = D R_s D`` and ``d_s = D t_s`` (:func:`rig_sensor_poses`).

Unknowns: 6 per exposure (body) and 3 per point, as a plain block of that many photos; with
the relative poses estimated, 6 more per non-reference sensor (:class:`RigRelativePoses`, a
component of :func:`lidarcat.bundle.adjust_with_parameters`): ``Q_s = exp([eps_s]x) Q_s0``,
``d_s = d_s0 + delta_s``, starting at the given calibration (``eps = delta = 0``) with prior
sds (free by default) and the Jacobians of :func:`lidarcat.bundle.rays.sensor_jacobians`.
The datum of the relative poses is the body: the reference sensor has none.

From photos to exposures: :func:`exposure_problem` turns a block of photos (one per sensor and
exposure, as a survey lists them) into the block of exposures: the observations keep their
photo's sensor, the body pose starts from the reference photo (or from another sensor's photo
through the inverse, ``M_b = Q_s^T M_s``, ``X0_b = X0_s + M_s^T d_s``), the GNSS constraints of
the reference photos constrain the body, and the sensors' focal lengths ride along.

Approximations: :func:`rig_initial_points` intersects the points from the sensors' photos
composed from approximate body poses (GNSS and the nominal attitude) -- the data alone.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import CameraError
from ..geometry.collinearity import rotation_matrix
from ..geometry.rolling import rodrigues
from .approx import intersect_points
from .problem import BundleProblem
from .rays import ObservationRays, sensor_jacobians

__all__ = ["rig_sensor_poses", "with_rig", "exposure_problem", "angles_from_matrix", "photo_poses", "body_poses",
           "rig_initial_points", "RigRelativePoses", "rotation_log"]

_D = np.diag([1.0, -1.0, -1.0])


def rig_sensor_poses(rig) -> tuple[np.ndarray, np.ndarray]:
    """``Q_s`` (S, 3, 3) and ``d_s`` (S, 3) m of a :class:`lidarcat.geometry.rigs.Rig` in the thesis
    image frame (module docstring)."""
    r = np.asarray(rig.rotation, dtype=float)
    t = np.asarray(rig.translation_m, dtype=float)
    return _D @ r @ _D, t @ _D


def with_rig(problem: BundleProblem, sensor_index: Any, rotation: Any, translation_m: Any) -> BundleProblem:
    """*problem* (photos = exposures) with the sensor of every observation and the sensors'
    relative poses ``Q_s`` (S, 3, 3), ``d_s`` (S, 3) (thesis frame; sensor 0 the body)."""
    q = np.asarray(rotation, dtype=float)
    if np.abs(q[0] - np.eye(3)).max() > 1e-12 or np.abs(np.asarray(translation_m, dtype=float)[0]).max() > 0:
        raise CameraError("rig: sensor 0 is the body: its relative pose must be the identity")
    old = problem.rays
    rays = ObservationRays(centre_offset_m=None if old is None else old.centre_offset_m,
                           sensor_index=sensor_index, sensor_rotation=q, sensor_translation_m=translation_m)
    return dataclasses.replace(problem, rays=rays)


def angles_from_matrix(m: Any) -> np.ndarray:
    """omega, phi, kappa (n, 3) rad of rotations ``M = R3(kappa) R2(phi) R1(omega)`` (n, 3, 3):
    ``M[2] = (sin phi, -sin omega cos phi, cos omega cos phi)``, ``M[0, 0] = cos phi cos kappa``,
    ``M[1, 0] = -cos phi sin kappa``.

    >>> a = np.array([[0.1, -0.2, 2.5]])
    >>> np.allclose(angles_from_matrix(rotation_matrix(a)), a)
    True
    """
    m = np.asarray(m, dtype=float).reshape(-1, 3, 3)
    phi = np.arcsin(np.clip(m[:, 2, 0], -1, 1))
    omega = np.arctan2(-m[:, 2, 1], m[:, 2, 2])
    kappa = np.arctan2(-m[:, 1, 0], m[:, 0, 0])
    return np.stack([omega, phi, kappa], axis=1)


def rotation_log(r: Any) -> np.ndarray:
    """The rotation vector ``phi`` of ``R = exp([phi]x)`` (n, 3), |phi| < pi."""
    r = np.asarray(r, dtype=float).reshape(-1, 3, 3)
    c = np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1, 1)
    a = np.arccos(c)
    w = np.stack([r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1)
    s = np.where(a < 1e-8, 0.5, a / (2 * np.sin(np.where(a < 1e-8, 1.0, a))))
    return w * s[:, None]


def photo_poses(body_eo: Any, rotation: Any, translation_m: Any, exposure: Any, sensor: Any) -> np.ndarray:
    """Exterior orientation (k, 6) of the photos of sensors *sensor* (k,) at exposures *exposure* (k,):
    ``M_s = Q_s M_b``, ``X0_s = X0_b - M_b^T Q_s^T d_s`` (module docstring)."""
    b = np.asarray(body_eo, dtype=float).reshape(-1, 6)[np.asarray(exposure)]
    s = np.asarray(sensor)
    q = np.asarray(rotation, dtype=float)[s]
    d = np.asarray(translation_m, dtype=float)[s]
    mb = rotation_matrix(b[:, 3:])
    x0 = b[:, :3] - np.einsum("nji,nj->ni", mb, np.einsum("nji,nj->ni", q, d))
    return np.concatenate([x0, angles_from_matrix(q @ mb)], axis=1)


def body_poses(photo_eo: Any, rotation: Any, translation_m: Any, sensor: Any) -> np.ndarray:
    """Body poses (k, 6) from the photos (k, 6) of sensors *sensor* (k,): the inverse of
    :func:`photo_poses`, ``M_b = Q_s^T M_s``, ``X0_b = X0_s + M_s^T d_s``."""
    e = np.asarray(photo_eo, dtype=float).reshape(-1, 6)
    s = np.asarray(sensor)
    q = np.asarray(rotation, dtype=float)[s]
    d = np.asarray(translation_m, dtype=float)[s]
    ms = rotation_matrix(e[:, 3:])
    x0 = e[:, :3] + np.einsum("nji,nj->ni", ms, d)
    return np.concatenate([x0, angles_from_matrix(np.transpose(q, (0, 2, 1)) @ ms)], axis=1)


def exposure_problem(problem: BundleProblem, exposure_of_photo: Sequence[Any], sensor_of_photo: Any,
                     rotation: Any, translation_m: Any, *, sensor_focal_mm: Any = None,
                     sensor_names: Sequence[str] | None = None) -> tuple[BundleProblem, np.ndarray]:
    """The block of rig exposures from a block of photos (module docstring).

    Parameters
    ----------
    problem : BundleProblem
        One photo per sensor and exposure (as read from a survey).
    exposure_of_photo : sequence, (P,)
        Exposure label of every photo (e.g. photos.csv ``rig_exposure``).
    sensor_of_photo : (P,) int array
        Sensor of every photo (0 = the body).
    rotation, translation_m : (S, 3, 3), (S, 3) arrays
        The sensors' relative poses (thesis frame, :func:`rig_sensor_poses`).
    sensor_focal_mm : (S,) array, optional
        The sensors' focal lengths (default: the problem's, which must then agree per exposure).
    sensor_names : sequence of str, optional
        For the errors.

    Returns
    -------
    problem : BundleProblem
        Photos = exposures (ids the labels), ``rays`` with every observation's sensor.
    exposure_index : (P,) int array
        The exposure of every photo of *problem*.

    Raises
    ------
    CameraError
        Two photos of one sensor in one exposure (names the exposure and the photos).
    """
    p = problem
    labels = [str(x) for x in exposure_of_photo]
    sensor = np.asarray(sensor_of_photo, dtype=np.int64)
    if len(labels) != p.n_photos or sensor.shape != (p.n_photos,):
        raise CameraError(f"rig: {len(labels)} exposure label(s) and {sensor.shape[0]} sensor(s) for "
                          f"{p.n_photos} photos")
    names = list(sensor_names) if sensor_names is not None else [str(k) for k in range(len(rotation))]
    ids = list(dict.fromkeys(labels))
    ex = np.array([ids.index(x) for x in labels], dtype=np.int64)
    seen: dict[tuple[int, int], int] = {}
    for i, key in enumerate(zip(ex.tolist(), sensor.tolist())):
        if key in seen:
            raise CameraError(f"rig exposure {ids[key[0]]!r}: photos {p.photo_ids[seen[key]]!r} and "
                              f"{p.photo_ids[i]!r} are both of sensor {names[key[1]]!r}")
        seen[key] = i
    n_ex = len(ids)
    # the body pose's approximation and constraints: the reference photo, else the first photo's inverse
    rep = np.full(n_ex, -1)
    for i in np.argsort(sensor, kind="stable"):
        if rep[ex[i]] < 0:
            rep[ex[i]] = i
    initial = None
    if p.initial_eo is not None:
        initial = body_poses(p.initial_eo[rep], rotation, translation_m, sensor[rep])
    kw: dict[str, Any] = {}
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        keep = sensor[p.eo_constraint_photo_index] == 0
        kw = {"eo_constraint_photo_index": ex[p.eo_constraint_photo_index[keep]],
              "eo_constraint_params": p.eo_constraint_params[keep], "eo_constraint_sd": p.eo_constraint_sd[keep]}
    focal = np.asarray(p.focal_length_mm)
    if sensor_focal_mm is None:
        fs = np.full(len(rotation), np.nan)
        for s_ in range(len(rotation)):
            f_s = focal[sensor == s_]
            if len(f_s) and np.ptp(f_s) > 0:
                raise CameraError(f"rig: sensor {names[s_]!r}: its photos have different focal lengths")
            if len(f_s):
                fs[s_] = f_s[0]
        sensor_focal_mm = np.where(np.isfinite(fs), fs, np.nanmax(fs))
    out = dataclasses.replace(
        p, photo_ids=ids, focal_length_mm=np.asarray(sensor_focal_mm, dtype=float)[sensor[rep]],
        photo_index=ex[p.photo_index], initial_eo=initial, **kw,
        rays=ObservationRays(sensor_index=sensor[p.photo_index], sensor_rotation=rotation,
                             sensor_translation_m=translation_m, sensor_focal_mm=sensor_focal_mm))
    return out, ex


def rig_initial_points(problem: BundleProblem, body_eo: Any) -> np.ndarray:
    """Points (Q, 3) m intersected from the rays of every sensor photo composed from *body_eo* (P, 6)."""
    p = problem
    r = p.rays
    if r is None or not r.has_sensors:
        return intersect_points(p, np.asarray(body_eo, dtype=float))
    n_s = len(r.sensor_rotation)
    key = p.photo_index * n_s + r.sensor_index
    pairs, inv = np.unique(key, return_inverse=True)
    eo = photo_poses(body_eo, r.sensor_rotation, r.sensor_translation_m, pairs // n_s, pairs % n_s)
    focal = (p.focal_length_mm[pairs // n_s] if r.sensor_focal_mm is None else r.sensor_focal_mm[pairs % n_s])
    plain = BundleProblem(photo_ids=[str(k) for k in pairs], point_ids=p.point_ids,
                          focal_length_mm=focal, photo_index=inv, point_index=p.point_index,
                          xy_mm=p.xy_mm, sd_mm=p.sd_mm, constraint_point_index=p.constraint_point_index,
                          constraint_enh_m=p.constraint_enh_m, constraint_sd_m=p.constraint_sd_m)
    return intersect_points(plain, eo)


@dataclasses.dataclass(frozen=True, eq=False)
class RigRelativePoses:
    """The relative poses of a rig's sensors as additional unknowns (module docstring).

    Parameters
    ----------
    sensor_names : sequence of str, (S,)
        Names of the sensors (sensor 0 the body), for the parameter names.
    estimate : sequence of int, optional
        The sensors whose pose is estimated (default: every sensor but the body).
    sd_rad, sd_m : float
        Prior sds of the rotation vector (rad) and the translation (m) about the given
        calibration (inf: free, the default).
    rig_id : str
    """

    sensor_names: Sequence[str]
    estimate: Sequence[int] | None = None
    sd_rad: float = np.inf
    sd_m: float = np.inf
    rig_id: str = "rig"

    def bind(self, problem: BundleProblem) -> _BoundRig:
        return _BoundRig(self, problem)


class _BoundRig:
    group_kind = "rig"

    def __init__(self, spec: RigRelativePoses, problem: BundleProblem):
        r = problem.rays
        if r is None or not r.has_sensors:
            raise CameraError(f"rig {spec.rig_id!r}: the problem has no sensors (BundleProblem.rays)")
        n_s = len(r.sensor_rotation)
        if len(spec.sensor_names) != n_s:
            raise CameraError(f"rig {spec.rig_id!r}: {len(spec.sensor_names)} sensor name(s) for {n_s} sensors")
        est = list(range(1, n_s)) if spec.estimate is None else sorted({int(s) for s in spec.estimate})
        if 0 in est or any(s < 0 or s >= n_s for s in est):
            raise CameraError(f"rig {spec.rig_id!r}: estimated sensors must be 1..{n_s - 1} (sensor 0, "
                              f"{spec.sensor_names[0]!r}, is the body)")
        self.est = np.array(est, dtype=np.int64)
        self.col_of_sensor = np.full(n_s, -1)
        self.col_of_sensor[self.est] = np.arange(len(est))
        self.q0 = np.array(r.sensor_rotation)
        self.d0 = np.array(r.sensor_translation_m)
        self.rows = np.flatnonzero(self.col_of_sensor[r.sensor_index] >= 0)
        self.sensor_of_row = r.sensor_index[self.rows]
        self.m = 6
        self.n = 6 * len(est)
        comp = ("rx", "ry", "rz", "tx", "ty", "tz")
        self.names = [f"{spec.rig_id}.{spec.sensor_names[s]}.{c}" for s in est for c in comp]
        self.units = ["rad", "rad", "rad", "m", "m", "m"] * len(est)
        self.groups = [f"rig {spec.rig_id} sensor {spec.sensor_names[s]}" for s in est for _ in comp]
        sd = [spec.sd_rad] * 3 + [spec.sd_m] * 3
        self.prior_sd = np.tile(np.where(np.asarray(sd, float) > 0, sd, np.inf), len(est))
        # the start: rotation vector 0 about Q_s0, translation d_s0 (the result's "value" = start + estimate)
        self.calibrated = np.concatenate([np.r_[np.zeros(3), self.d0[s]] for s in est]) if est else np.zeros(0)
        self.notes: list[str] = []

    def poses(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``Q`` (S, 3, 3), ``d`` (S, 3) and ``eps`` (S, 3) at the corrections *theta*."""
        th = np.reshape(theta, (-1, 6))
        q, d, eps = self.q0.copy(), self.d0.copy(), np.zeros_like(self.d0)
        eps[self.est] = th[:, :3]
        q[self.est] = rodrigues(th[:, :3]) @ self.q0[self.est]
        d[self.est] += th[:, 3:]
        return q, d, eps

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        q, d, eps = self.poses(theta)
        fields["rays"] = dataclasses.replace(fields["rays"], sensor_rotation=q, sensor_translation_m=d,
                                             sensor_rotation_vector=eps)

    def jacobians(self, theta: np.ndarray, state) -> list:
        J = sensor_jacobians(state.problem, state.eo, state.pts)[self.rows]
        cols = (6 * self.col_of_sensor[self.sensor_of_row])[:, None] + np.arange(6)[None, :]
        return [("obs", self.rows, J, cols)]
