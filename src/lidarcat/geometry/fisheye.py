r"""Equidistant fisheye, Kannala-Brandt polynomial (OpenCV ``cv::fisheye``, COLMAP OPENCV_FISHEYE, OpenSfM).

The projection, its Jacobians and its inverse are derived in :mod:`lidarcat.geometry.models`
(the family's docstring); this module holds the class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import CameraError
from .modelbase import TOL_PX, CameraModel, as_pixels, as_rays, check_common, first_fold, invert_increasing

__all__ = ["FisheyeCamera"]



@dataclass(frozen=True)
class FisheyeCamera(CameraModel):
    """Equidistant fisheye with Kannala-Brandt polynomial (OpenCV fisheye, COLMAP OPENCV_FISHEYE).

    Parameters
    ----------
    id : str
        Camera id.
    width_px, height_px : int
        Image size, pixels.
    fx, fy : float
        Focal lengths, pixels per radian of ``theta_d`` (> 0).
    cx, cy : float
        Principal point, pixels (pixel-centre origin), inside the image.
    k1, k2, k3, k4 : float
        Coefficients of ``theta^3 .. theta^9`` (angles in radians).

    Raises
    ------
    CameraError
        A value out of range, ``theta_d`` folding over inside the image, or an image corner
        that would lie more than 180 deg from the optical axis (names camera and field).
    """

    KIND: ClassVar[str] = "fisheye"
    PARAMETERS: ClassVar[tuple[str, ...]] = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4")

    id: str
    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0

    def __post_init__(self) -> None:
        check_common(self)
        fold = min(first_fold(self._theta_slope, math.pi), math.pi)
        object.__setattr__(self, "_fold", fold)
        corners = self.corners_px()
        d = np.column_stack([(corners[:, 0] - self.cx) / self.fx, (corners[:, 1] - self.cy) / self.fy])
        td = np.hypot(d[:, 0], d[:, 1])
        k = int(np.argmax(td))
        reach = float(self._theta_d(np.array([fold]))[0])
        if not td[k] < reach:
            c = corners[k]
            if fold >= math.pi:
                raise CameraError(
                    f"camera {self.id!r}: field 'fx': the image corner ({c[0]:g}, {c[1]:g}) px lies beyond 180 deg "
                    f"from the optical axis (theta_d = {td[k]:.4g} rad, the model reaches {reach:.4g} rad at "
                    f"180 deg); check fx, fy (px per radian) and k1..k4")
            culprit = max(("k1", "k2", "k3", "k4"), key=lambda n: abs(getattr(self, n)) * fold ** (2 * int(n[1])))
            raise CameraError(
                f"camera {self.id!r}: field {culprit!r}: the fisheye polynomial folds over at "
                f"{math.degrees(fold):.4g} deg from the optical axis (theta_d stops increasing at {reach:.4g} rad) "
                f"before the image corner ({c[0]:g}, {c[1]:g}) px (theta_d = {td[k]:.4g} rad)")

    @property
    def valid_angle_deg(self) -> float:
        """The largest angle from the optical axis the model projects, deg (<= 180)."""
        return math.degrees(self._fold)  # type: ignore[attr-defined]

    def _theta_d(self, t: np.ndarray) -> np.ndarray:
        u = t * t
        return t * (1 + u * (self.k1 + u * (self.k2 + u * (self.k3 + u * self.k4))))

    def _theta_slope(self, t: np.ndarray) -> np.ndarray:
        u = t * t
        return 1 + u * (3 * self.k1 + u * (5 * self.k2 + u * (7 * self.k3 + u * 9 * self.k4)))

    def _angles(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r = as_rays(rays)
        rho = np.hypot(r[:, 0], r[:, 1])
        theta = np.arctan2(rho, r[:, 2])
        bad = ~np.isfinite(r).all(axis=1) | ~(np.linalg.norm(r, axis=1) > 0)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise CameraError(f"camera {self.id!r}: ray index {i} ({r[i, 0]:.6g}, {r[i, 1]:.6g}, {r[i, 2]:.6g}) "
                              f"is no direction")
        far = (theta > self._fold) | (theta >= math.pi * (1 - 1e-12))  # type: ignore[attr-defined]
        if far.any():
            i = int(np.flatnonzero(far)[0])
            raise CameraError(f"camera {self.id!r}: ray index {i} at {math.degrees(theta[i]):.4g} deg from the "
                              f"optical axis is beyond the model's valid field ({self.valid_angle_deg:.4g} deg)")
        return r, rho, theta

    def project(self, rays: Any) -> np.ndarray:
        """Rays (N, 3) -> pixels (N, 2); refuses rays beyond the valid field."""
        r, rho, theta = self._angles(rays)
        with np.errstate(all="ignore"):
            s = np.where(rho > 1e-12 * np.abs(r[:, 2]), self._theta_d(theta) / rho, 1 / r[:, 2])
        return np.column_stack([self.fx * s * r[:, 0] + self.cx, self.fy * s * r[:, 1] + self.cy])

    def project_jacobians(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (N, 2), d px / d ray (N, 2, 3), d px / d :attr:`PARAMETERS` (N, 2, 8)."""
        r, rho, theta = self._angles(rays)
        X, Y, Z = r[:, 0], r[:, 1], r[:, 2]
        axis = ~(rho > 1e-12 * np.abs(Z))                      # on the axis, in front (180 deg is refused)
        rho_s = np.where(axis, 1.0, rho)
        td = self._theta_d(theta)
        s = np.where(axis, 1 / Z, td / rho_s)
        n2 = rho * rho + Z * Z
        dth = np.column_stack([Z * X / rho_s, Z * Y / rho_s, -rho]) / n2[:, None]
        drho = np.column_stack([X / rho_s, Y / rho_s, np.zeros(len(r))])
        ds = (self._theta_slope(theta) / rho_s)[:, None] * dth - (td / rho_s**2)[:, None] * drho
        ds[axis] = np.column_stack([np.zeros((int(axis.sum()), 2)), -1 / Z[axis] ** 2])
        xp, yp = s * X, s * Y
        j_ray = np.empty((len(r), 2, 3))
        j_ray[:, 0, :] = X[:, None] * ds
        j_ray[:, 1, :] = Y[:, None] * ds
        j_ray[:, 0, 0] += s
        j_ray[:, 1, 1] += s
        j_ray[:, 0] *= self.fx
        j_ray[:, 1] *= self.fy
        j_par = np.zeros((len(r), 2, 8))
        j_par[:, 0, 0], j_par[:, 1, 1] = xp, yp
        j_par[:, 0, 2] = j_par[:, 1, 3] = 1.0
        with np.errstate(all="ignore"):
            unit = np.where(axis[:, None], 0.0, np.column_stack([X, Y]) / rho_s[:, None])
        p = theta ** 3
        for i in range(4):                                        # d theta_d / d k_i = theta^(2i+3)
            j_par[:, 0, 4 + i] = self.fx * p * unit[:, 0]
            j_par[:, 1, 4 + i] = self.fy * p * unit[:, 1]
            p = p * theta * theta
        px = np.column_stack([self.fx * xp + self.cx, self.fy * yp + self.cy])
        return px, j_ray, j_par

    def unproject(self, px: Any, *, tol_px: float = TOL_PX, max_iter: int = 50,
                  on_fail: str = "raise") -> np.ndarray:
        """Pixels (N, 2) -> unit rays (N, 3): Newton on ``theta_d(theta) = |(x', y')|``.

        Convergence: ``|theta_d(theta) - |x'|| * max(fx, fy) <= tol_px``.  A pixel beyond the
        valid field (or not converging) raises, or gives NaN with ``on_fail="nan"``.
        """
        p = as_pixels(px)
        d = np.column_stack([(p[:, 0] - self.cx) / self.fx, (p[:, 1] - self.cy) / self.fy])
        td = np.hypot(d[:, 0], d[:, 1])
        tol = np.full(len(p), tol_px / max(self.fx, self.fy))
        theta, ok = invert_increasing(self._theta_d, self._theta_slope, td, np.minimum(td, self._fold), tol,
                                       max_iter)
        failed = ~ok | (theta > self._fold) | (theta < 0)  # type: ignore[attr-defined]
        if failed.any():
            if on_fail == "raise":
                raise self._not_converged(p, failed, max_iter)
            theta[failed] = np.nan
        with np.errstate(all="ignore"):
            unit = np.where((td > 0)[:, None], d / np.where(td > 0, td, 1.0)[:, None], 0.0)
        return np.column_stack([np.sin(theta)[:, None] * unit, np.cos(theta)])
