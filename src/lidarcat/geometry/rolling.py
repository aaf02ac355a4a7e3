r"""Rolling shutter: a photo read out row by row while the camera moves (engine side).

Model (ODM, Metashape, Pix4D: linear motion during the read-out).  The exterior orientation of a
photo holds at the middle of its read-out, ``t = 0``; row ``v`` (pixel-centre origin, so the top
edge of the image is ``v = -0.5``) is exposed at::

    t(v) = T ((v + 0.5) / H - 0.5)              (T: read-out time, s; H: rows)

from ``-T/2`` at the top edge to ``+T/2`` at the bottom.  The camera moves linearly in that time::

    X0(t) = X0 + V t                            (V: velocity, m/s, object frame)
    R(t)  = exp([w t]x) R0                      (w: angular velocity, rad/s, camera axes)
    x_c(t) = R(t) (X - X0(t))                   (the ray of object point X, camera frame)

with ``R0`` the world-to-camera rotation (camera x right, y down, z forward, as
:mod:`lidarcat.geometry.models`) and ``exp`` Rodrigues' formula.  A point's pixel depends on its
row's time, which depends on the pixel: ``v = P_v(x_c(t(v)))``.  Projection solves
``g(v) = P_v(x_c(t(v))) - v = 0`` by Newton's method from the global-shutter row, with

    g'(v) = a_v T / H - 1,     a = dP/dt = J_ray (w x x_c - R(t) V)

(``d exp([w t]x)/dt = [w]x exp([w t]x)``); ``|a_v T / H|`` is the image motion during the
read-out in rows per row, far below 1 for any real flight, so Newton converges in two or three
steps.  It stops when ``|g| <= tol_px``.

Jacobians.  With ``q`` any parameter, ``dP/dq`` the derivative at a *fixed* time and
``tau = T/H`` the time per row, the pixel ``p = P(x_c(t(p_v), q))`` gives
``dp/dq = dP/dq + a tau dp_v/dq``, so::

    dp_v/dq = (dP_v/dq) / (1 - a_v tau),      dp_u/dq = dP_u/dq + a_u tau dp_v/dq

and, at a fixed time, ``dx_c/dX = R(t)``, ``dx_c/dX0 = -R(t)``, ``dx_c/dV = -t R(t)``,
``dx_c/ddelta = -exp([w t]x) [R0 (X - X0(t))]x`` for a rotation increment ``R0 <- exp([delta]x) R0``
(camera axes), ``dx_c/dw = -[x_c]x J_l(w t) t`` with the left Jacobian of SO(3)
``J_l(phi) = I + (1 - cos a)/a^2 [phi]x + (a - sin a)/a^3 [phi]x^2`` (``a = |phi|``), and
``dP/dT = a (t / T)`` (the time of a fixed row scales with T).  The intrinsic parameters enter
through the model's own ``d px / d parameters``.  Everything is vectorised over the points.

A rolling-shutter photo of a camera flying at ``V`` across the rows (along image x) is the
global-shutter photo shifted by ``-f V t(v) / Z`` pixels in each row ``v``: a shear growing
linearly from the top to the bottom of the image (tested).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CameraError
from .models import CameraModel

__all__ = ["RollingShutterPose", "rodrigues", "left_jacobian", "project_rolling", "project_rolling_jacobians"]


def _skew(a: np.ndarray) -> np.ndarray:
    z = np.zeros(a.shape[:-1])
    return np.stack([np.stack([z, -a[..., 2], a[..., 1]], -1), np.stack([a[..., 2], z, -a[..., 0]], -1),
                     np.stack([-a[..., 1], a[..., 0], z], -1)], -2)


def rodrigues(phi: Any) -> np.ndarray:
    """``exp([phi]x)`` for rotation vectors *phi* (N, 3), rad: (N, 3, 3)."""
    p = np.asarray(phi, dtype=float).reshape(-1, 3)
    a = np.linalg.norm(p, axis=1)
    small = a < 1e-8
    a_s = np.where(small, 1.0, a)
    s = np.where(small, 1 - a * a / 6, np.sin(a) / a_s)
    c = np.where(small, 0.5 - a * a / 24, (1 - np.cos(a)) / a_s**2)
    k = _skew(p)
    return np.eye(3)[None] + s[:, None, None] * k + c[:, None, None] * (k @ k)


def left_jacobian(phi: Any) -> np.ndarray:
    """The left Jacobian of SO(3), ``d exp([phi]x) y / d phi = -[exp([phi]x) y]x J_l(phi)``: (N, 3, 3)."""
    p = np.asarray(phi, dtype=float).reshape(-1, 3)
    a = np.linalg.norm(p, axis=1)
    small = a < 1e-6
    a_s = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a * a / 24, (1 - np.cos(a)) / a_s**2)
    c2 = np.where(small, 1 / 6 - a * a / 120, (a - np.sin(a)) / a_s**3)
    k = _skew(p)
    return np.eye(3)[None] + c1[:, None, None] * k + c2[:, None, None] * (k @ k)


@dataclass(frozen=True, eq=False)
class RollingShutterPose:
    """The orientation of the photo of each ray and its motion during the read-out.

    Parameters
    ----------
    rotation : array_like, (N, 3, 3) or (3, 3)
        World-to-camera rotation ``R0`` at the middle of the read-out.
    position_m : array_like, (N, 3) or (3,)
        Projection centre ``X0`` at the middle of the read-out, m.
    velocity_m_s : array_like, (N, 3) or (3,)
        Linear velocity ``V``, m/s, object frame.
    angular_velocity_rad_s : array_like, (N, 3) or (3,)
        Angular velocity ``w``, rad/s, camera axes.
    readout_s : float
        Read-out time ``T`` from the top to the bottom edge of the image, s (>= 0; 0 is a
        global shutter).
    """

    rotation: Any
    position_m: Any
    velocity_m_s: Any
    angular_velocity_rad_s: Any
    readout_s: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.readout_s) and self.readout_s >= 0):
            raise CameraError(f"field 'readout_s': read-out time must be a finite number >= 0 s, "
                              f"got {self.readout_s!r}")

    def arrays(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R0 (n, 3, 3), X0, V, w (n, 3), broadcast to *n* rays."""
        r = np.broadcast_to(np.asarray(self.rotation, dtype=float), (n, 3, 3))
        x0, v, w = (np.broadcast_to(np.asarray(a, dtype=float), (n, 3)) for a in
                    (self.position_m, self.velocity_m_s, self.angular_velocity_rad_s))
        return r, x0, v, w


def _state(model: CameraModel, pose: RollingShutterPose, X: np.ndarray, t: np.ndarray):
    r0, x0, v, w = pose.arrays(len(X))
    e = rodrigues(w * t[:, None])
    y = np.einsum("nij,nj->ni", r0, X - x0 - v * t[:, None])      # R0 (X - X0(t))
    xc = np.einsum("nij,nj->ni", e, y)
    rt = e @ r0
    dxc_dt = np.cross(w, xc) - np.einsum("nij,nj->ni", rt, v)
    return xc, rt, e, y, dxc_dt


def _times(model: CameraModel, readout_s: float, row: np.ndarray) -> np.ndarray:
    return readout_s * ((row + 0.5) / model.height_px - 0.5)


def project_rolling(model: CameraModel, pose: RollingShutterPose, points_m: Any, *, tol_px: float = 1e-10,
                    max_iter: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of object points seen by a rolling-shutter camera, the row time solved (module docstring).

    Parameters
    ----------
    model : CameraModel
        The camera (:mod:`lidarcat.geometry.models`).
    pose : RollingShutterPose
        Orientation and motion of the photo of every point.
    points_m : array_like, (N, 3)
        Object points, m.
    tol_px, max_iter
        Newton's stopping rule on the row, pixels, and its iteration limit.

    Returns
    -------
    px : ndarray, (N, 2)
        Column, row (pixel-centre origin).
    t_s : ndarray, (N,)
        Exposure time of each point's row relative to the middle of the read-out, s.

    Raises
    ------
    CameraError
        A point behind the camera or outside the model's field (from the model), or a row that
        does not converge (names the point index).
    """
    X = np.asarray(points_m, dtype=float).reshape(-1, 3)
    T = float(pose.readout_s)
    xc, *_ = _state(model, pose, X, np.zeros(len(X)))
    row = model.project(xc)[:, 1]
    tau = T / model.height_px
    done = np.zeros(len(X), dtype=bool)
    for _ in range(max_iter):
        t = _times(model, T, row)
        xc, _, _, _, dxc_dt = _state(model, pose, X, t)
        px, j_ray, _ = model.project_jacobians(xc)
        g = px[:, 1] - row
        done = np.abs(g) <= tol_px
        if done.all():
            return px, t
        a_v = np.einsum("nk,nk->n", j_ray[:, 1, :], dxc_dt)
        row = np.where(done, row, row - g / (a_v * tau - 1.0))
    i = int(np.flatnonzero(~done)[0])
    raise CameraError(f"camera {model.id!r}: point index {i} ({X[i, 0]:.6g}, {X[i, 1]:.6g}, {X[i, 2]:.6g}): "
                      f"the rolling-shutter row did not converge within {max_iter} iterations (the image "
                      f"moves faster than the read-out)")


def project_rolling_jacobians(model: CameraModel, pose: RollingShutterPose, points_m: Any, *,
                              tol_px: float = 1e-10) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Pixels (N, 2) and their derivatives, the row time solved (module docstring).

    Returns
    -------
    px : ndarray, (N, 2)
    jac : dict of ndarray
        ``point`` (N, 2, 3) per m, ``position`` (N, 2, 3) per m, ``rotation`` (N, 2, 3) per rad
        (increment in camera axes), ``velocity`` (N, 2, 3) per m/s, ``angular_velocity``
        (N, 2, 3) per rad/s, ``readout`` (N, 2) per s, ``intrinsics`` (N, 2, m) per unit of the
        model's :attr:`PARAMETERS`.
    """
    X = np.asarray(points_m, dtype=float).reshape(-1, 3)
    px, t = project_rolling(model, pose, X, tol_px=tol_px)
    T = float(pose.readout_s)
    r0, x0, v, w = pose.arrays(len(X))
    xc, rt, e, y, dxc_dt = _state(model, pose, X, t)
    _, j_ray, j_par = model.project_jacobians(xc)
    a = np.einsum("nik,nk->ni", j_ray, dxc_dt)                          # dP/dt, (N, 2)
    tau = T / model.height_px
    parts = {
        "point": j_ray @ rt,
        "position": -(j_ray @ rt),
        "velocity": -(j_ray @ rt) * t[:, None, None],
        "rotation": -(j_ray @ e @ _skew(y)),
        "angular_velocity": -(j_ray @ _skew(xc) @ left_jacobian(w * t[:, None])) * t[:, None, None],
        "intrinsics": j_par,
    }
    s = (px[:, 1] + 0.5) / model.height_px - 0.5                     # t = T s at a fixed row
    parts["readout"] = (a * s[:, None])[:, :, None]
    out: dict[str, np.ndarray] = {}
    denom = (1.0 - a[:, 1] * tau)[:, None]
    for k, d in parts.items():
        dv = d[:, 1, :] / denom
        du = d[:, 0, :] + (a[:, 0] * tau)[:, None] * dv
        out[k] = np.stack([du, dv], axis=1)
    out["readout"] = out["readout"][:, :, 0]
    return px, out
