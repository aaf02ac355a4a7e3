r"""Rays beyond the plain collinearity: a moving projection centre and a camera within a rig.

The plain bundle projects observation ``a`` (photo ``i``, point ``j``) through the photo's
exterior orientation, ``u = M_i (X_j - X0_i)``, ``x = -c u_1 / u_3``, ``y = -c u_2 / u_3``
(thesis eq. 08-09, :mod:`lidarcat.geometry.collinearity`; image frame x right, y up, the
camera looking along ``-z``).  Two generalisations share this module, both *per observation*
and both leaving the unknowns of the block (6 per photo, 3 per point) as they are:

Centre offset (rolling shutter, :mod:`.rolling`)
    The projection centre of the ray is ``X0_i + o_a`` with a known offset ``o_a`` (m): a
    rolling-shutter photo is read out row by row while the camera moves, ``o_a = V_i t_a``
    (velocity times the time of the observation's row).  Then
    ``u = M_i (X_j - o_a - X0_i)``: the plain collinearity of the *shifted point*
    ``X_j - o_a``, with the same Jacobians -- ``du/dX = M``, ``du/dX0 = -M``, the angles at
    the shifted point -- so the reduced camera system, precision and every test built on it
    are unchanged.

Sensor of a rig (:mod:`.rig`)
    The "photo" of the problem is a rig *exposure* (the body pose ``M_i``, ``X0_i``), and the
    ray is seen by sensor ``s`` whose frame is ``u = Q_s u_b + d_s`` with ``u_b = M_i (X -
    X0_i - o_a)`` the body frame (thesis image convention; the reference sensor is the body,
    ``Q = I``, ``d = 0``).  The sensor's photo has ``M = Q_s M_i`` and projection centre
    ``X0_i - M_i^T Q_s^T d_s``.  With ``J_u = dx/du = -c [[1/u_3, 0, -u_1/u_3^2],
    [0, 1/u_3, -u_2/u_3^2]]``::

        dx/dX           = J_u Q_s M_i                 dx/dX0_i = -dx/dX
        dx/d(theta_k)   = J_u Q_s (g_k x u_b)          (g_k: the axial vector of dM/dtheta_k M^T)
        dx/d(eps_s)     = -J_u [Q_s u_b]x J_l(eps_s)   (Q_s = exp([eps_s]x) Q_s0, a rotation of the sensor)
        dx/dd_s         = J_u

    (``J_l`` the left Jacobian of SO(3), :func:`lidarcat.geometry.rolling.left_jacobian`).
    The first three are the blocks the normal equations need (the position part stays
    ``-dx/dX``); the last two border them when the relative poses are estimated.

:class:`ObservationRays` carries the offsets and sensor poses in
:attr:`lidarcat.bundle.BundleProblem.rays`; :func:`observation_parts` and
:func:`observation_project` are what :mod:`.model` (and the bordered adjustment of
:mod:`.selfcal`) call in place of the plain projection.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..geometry.collinearity import project, project_jacobian_parts, rotation_and_derivatives
from ..geometry.rolling import left_jacobian
from .._util.frozen import frozen_array
from ..errors import CameraError

__all__ = ["ObservationRays", "observation_parts", "observation_project", "sensor_jacobians", "skew"]


def skew(a: np.ndarray) -> np.ndarray:
    """``[a]x`` of vectors (..., 3): (..., 3, 3), ``[a]x b = a x b``."""
    z = np.zeros(a.shape[:-1])
    return np.stack([np.stack([z, -a[..., 2], a[..., 1]], -1), np.stack([a[..., 2], z, -a[..., 0]], -1),
                     np.stack([-a[..., 1], a[..., 0], z], -1)], -2)


@dataclasses.dataclass(frozen=True, eq=False)
class ObservationRays:
    """Per-observation ray geometry of a :class:`~lidarcat.bundle.BundleProblem` (module docstring).

    Parameters
    ----------
    centre_offset_m : (n, 3) array, optional
        Offset ``o_a`` of the projection centre of every observation, m (rolling shutter).
    sensor_index : (n,) int array, optional
        Sensor of every observation within its exposure's rig (0 = the body / reference).
    sensor_rotation : (S, 3, 3) array, optional
        ``Q_s``: body image frame to sensor image frame (thesis convention, x right, y up).
    sensor_translation_m : (S, 3) array, optional
        ``d_s``, m.
    sensor_rotation_vector : (S, 3) array, optional
        ``eps_s`` of ``Q_s = exp([eps_s]x) Q_s0`` when the poses are being estimated (for the
        left Jacobian of :func:`sensor_jacobians`); zero by default.
    sensor_focal_mm : (S,) array, optional
        Focal length of every sensor, mm, when the sensors' cameras differ (default: the
        problem's ``focal_length_mm`` of the exposure).
    """

    centre_offset_m: Any = None
    sensor_index: Any = None
    sensor_rotation: Any = None
    sensor_translation_m: Any = None
    sensor_rotation_vector: Any = None
    sensor_focal_mm: Any = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        if self.centre_offset_m is not None:
            off = frozen_array(self.centre_offset_m)
            if off.ndim != 2 or off.shape[1] != 3 or not np.isfinite(off).all():
                raise CameraError("`centre_offset_m` must be a finite (n, 3) array")
            s(self, "centre_offset_m", off)
        have = [v is not None for v in (self.sensor_index, self.sensor_rotation, self.sensor_translation_m)]
        if any(have) and not all(have):
            raise CameraError("`sensor_index`, `sensor_rotation` and `sensor_translation_m` go together")
        if all(have):
            idx = frozen_array(self.sensor_index, dtype=np.int64)
            q = frozen_array(self.sensor_rotation)
            d = frozen_array(self.sensor_translation_m)
            n_s = len(q)
            if q.shape != (n_s, 3, 3) or d.shape != (n_s, 3) or idx.ndim != 1:
                raise CameraError(f"sensor poses must be (S, 3, 3) and (S, 3), indices (n,); got {q.shape}, "
                                 f"{d.shape}, {idx.shape}")
            if len(idx) and (idx.min() < 0 or idx.max() >= n_s):
                raise CameraError(f"`sensor_index` out of range of the {n_s} sensor(s)")
            eps = np.zeros((n_s, 3)) if self.sensor_rotation_vector is None else self.sensor_rotation_vector
            s(self, "sensor_index", idx)
            s(self, "sensor_rotation", q)
            s(self, "sensor_translation_m", d)
            s(self, "sensor_rotation_vector", frozen_array(np.reshape(eps, (n_s, 3))))
            if self.sensor_focal_mm is not None:
                f = frozen_array(np.reshape(self.sensor_focal_mm, (n_s,)))
                if not np.all(f > 0):
                    raise CameraError("`sensor_focal_mm` must be positive")
                s(self, "sensor_focal_mm", f)

    @property
    def has_sensors(self) -> bool:
        return self.sensor_index is not None

    def select(self, keep: Any) -> ObservationRays:
        """The rays of the observations *keep* (a boolean mask or indices), for a reduced problem."""
        k = np.asarray(keep)
        return dataclasses.replace(
            self, centre_offset_m=None if self.centre_offset_m is None else self.centre_offset_m[k],
            sensor_index=None if self.sensor_index is None else self.sensor_index[k])

    def check(self, n: int) -> None:
        """Refuse arrays that do not hold one row per observation (*n* of them)."""
        for name in ("centre_offset_m", "sensor_index"):
            a = getattr(self, name)
            if a is not None and len(a) != n:
                raise CameraError(f"`rays.{name}` has {len(a)} rows for {n} observations")


def _shifted_points(p, pts: np.ndarray) -> np.ndarray:
    x = np.asarray(pts)[p.point_index]
    r = p.rays
    return x if r is None or r.centre_offset_m is None else x - r.centre_offset_m


def _focal(p) -> np.ndarray:
    """Focal length of every observation's camera (n,), mm."""
    r = p.rays
    if r is not None and r.has_sensors and r.sensor_focal_mm is not None:
        return r.sensor_focal_mm[r.sensor_index]
    return np.asarray(p.focal_length_mm)[p.photo_index]


def _rig_state(p, eo: np.ndarray, pts: np.ndarray):
    """u_b (n, 3), u (n, 3), Q of each ray (n, 3, 3), J_u (n, 2, 3), M per photo, dM per photo."""
    r = p.rays
    ei = p.photo_index
    m, dm = rotation_and_derivatives(np.asarray(eo, dtype=float)[:, 3:6])
    diff = _shifted_points(p, pts) - np.asarray(eo)[ei, :3]
    ub = np.einsum("nij,nj->ni", m[ei], diff)
    q = r.sensor_rotation[r.sensor_index]
    u = np.einsum("nij,nj->ni", q, ub) + r.sensor_translation_m[r.sensor_index]
    c = _focal(p)
    inv = 1.0 / u[:, 2]
    ju = np.zeros((len(u), 2, 3))
    ju[:, 0, 0] = ju[:, 1, 1] = -c * inv
    ju[:, 0, 2] = c * u[:, 0] * inv**2
    ju[:, 1, 2] = c * u[:, 1] * inv**2
    return ub, u, q, ju, m, dm


def observation_parts(p, eo: np.ndarray, pts: np.ndarray):
    """Photo coordinates and Jacobians of every observation of problem *p* (module docstring).

    Returns ``(xy (n, 2) mm, a_pt (n, 2, 3), a_ang (n, 2, 3), u3 (n,))`` as
    :func:`lidarcat.geometry.collinearity.project_jacobian_parts` (``u3 < 0`` in front of the
    camera); the position part of the exterior orientation is ``-a_pt``.
    """
    ei = p.photo_index
    if p.rays is None or not p.rays.has_sensors:
        return project_jacobian_parts(eo, _shifted_points(p, pts), p.focal_length_mm[ei], ei)
    ub, u, q, ju, m, dm = _rig_state(p, eo, pts)
    c = _focal(p)
    xy = -c[:, None] * u[:, :2] / u[:, 2:3]
    jq = ju @ q
    a_pt = jq @ m[ei]
    G = dm @ np.transpose(m, (0, 2, 1))[:, None]                            # (P, 3, 3, 3) skew
    g = np.stack([G[:, :, 2, 1], G[:, :, 0, 2], G[:, :, 1, 0]], axis=2)     # (P, angle, 3)
    a_ang = np.einsum("nij,nkj->nik", jq, np.cross(g[ei], ub[:, None, :]))
    return xy, a_pt, a_ang, u[:, 2]


def observation_project(p, eo: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Photo coordinates (n, 2) mm and ``u3`` (n,) of every observation of *p* (no Jacobians)."""
    ei = p.photo_index
    if p.rays is None or not p.rays.has_sensors:
        return project(eo, _shifted_points(p, pts), p.focal_length_mm[ei], ei)
    _, u, _, _, _, _ = _rig_state(p, eo, pts)
    c = _focal(p)
    return -c[:, None] * u[:, :2] / u[:, 2:3], u[:, 2]


def sensor_jacobians(p, eo: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """``dx/d(eps_s, d_s)`` of every observation, (n, 2, 6): the rotation vector of its sensor
    (rad) and its translation (m), thesis image frame (module docstring)."""
    r = p.rays
    ub, u, q, ju, _, _ = _rig_state(p, eo, pts)
    jl = left_jacobian(r.sensor_rotation_vector)[r.sensor_index]
    qub = np.einsum("nij,nj->ni", q, ub)
    return np.concatenate([-(ju @ skew(qub) @ jl), ju], axis=2)
