r"""Normalised Brown-Conrady camera (OpenCV, COLMAP OPENCV/FULL_OPENCV, OpenSfM/ODM ``brown``, Metashape).

The projection, its Jacobians and its Newton inverse are derived in :mod:`lidarcat.geometry.models`
(the family's docstring); this module holds the class.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import CameraError
from .modelbase import TOL_PX, CameraModel, as_pixels, as_rays, check_common, check_front, first_fold

__all__ = ["BrownCamera"]



@dataclass(frozen=True)
class BrownCamera(CameraModel):
    """Normalised Brown-Conrady camera (OpenCV, COLMAP OPENCV/FULL_OPENCV, OpenSfM/ODM, Metashape).

    Parameters
    ----------
    id : str
        Camera id (named in every error).
    width_px, height_px : int
        Image size, pixels.
    fx, fy : float
        Focal lengths, pixels (> 0).
    cx, cy : float
        Principal point, pixels (pixel-centre origin), inside the image.
    k1, k2, k3, k4 : float
        Radial coefficients of ``r^2 .. r^8`` (normalised coordinates, dimensionless).
    p1, p2 : float
        Tangential coefficients (OpenCV order; Metashape's P1, P2 swapped).
    skew : float
        Affinity/skew term ``u += skew y'``, pixels (Metashape's b2).

    Raises
    ------
    CameraError
        A value is not finite, a focal length not positive, the principal point outside the
        image, or the radial distortion folds over inside the image (names camera and field).
    """

    KIND: ClassVar[str] = "brown"
    PARAMETERS: ClassVar[tuple[str, ...]] = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4", "p1", "p2",
                                             "skew")

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
    p1: float = 0.0
    p2: float = 0.0
    skew: float = 0.0

    def __post_init__(self) -> None:
        check_common(self)
        # the radial map rho(r) = r q(r^2) must increase out to the image corners
        corner = np.abs(self._normalised_distorted(self.corners_px()))
        rd = float(np.hypot(corner[:, 0], corner[:, 1]).max())
        fold = first_fold(self._radial_slope, max(10.0 * rd, 5.67))  # to 80 deg at least
        object.__setattr__(self, "_fold_r", fold)
        if math.isfinite(fold) and self._radial(np.array([fold]))[0] <= rd:
            coeffs = ", ".join(f"{k} = {getattr(self, k):.6g}" for k in ("k1", "k2", "k3", "k4"))
            culprit = max(("k1", "k2", "k3", "k4"), key=lambda k: abs(getattr(self, k)) * fold ** (2 * int(k[1])))
            raise CameraError(
                f"camera {self.id!r}: field {culprit!r}: radial distortion {coeffs} folds over inside the "
                f"image: the distorted radius stops increasing at r = {fold:.4g} (normalised, "
                f"{math.degrees(math.atan(fold)):.4g} deg from the axis) before it reaches the image corner "
                f"({rd:.4g}); no ray can be found for the corner pixels")

    def _radial(self, r: np.ndarray) -> np.ndarray:
        u = r * r
        return r * (1 + u * (self.k1 + u * (self.k2 + u * (self.k3 + u * self.k4))))

    def _radial_slope(self, r: np.ndarray) -> np.ndarray:
        u = r * r
        return 1 + u * (3 * self.k1 + u * (5 * self.k2 + u * (7 * self.k3 + u * 9 * self.k4)))

    @property
    def valid_angle_deg(self) -> float:
        """The largest angle from the optical axis the model projects (the radial fold), deg (< 90)."""
        return math.degrees(math.atan(self._fold_r))  # type: ignore[attr-defined]

    def _normalised_distorted(self, px: np.ndarray) -> np.ndarray:
        yd = (px[:, 1] - self.cy) / self.fy
        xd = (px[:, 0] - self.cx - self.skew * yd) / self.fx
        return np.column_stack([xd, yd])

    def _distort(self, x: np.ndarray, y: np.ndarray):
        r2 = x * x + y * y
        q = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * (self.k3 + r2 * self.k4)))
        xd = x * q + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * q + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return xd, yd, r2, q

    def _distort_jacobian(self, x: np.ndarray, y: np.ndarray, r2: np.ndarray, q: np.ndarray) -> np.ndarray:
        dq = self.k1 + r2 * (2 * self.k2 + r2 * (3 * self.k3 + r2 * 4 * self.k4))
        j = np.empty(x.shape + (2, 2))
        off = 2 * x * y * dq + 2 * self.p1 * x + 2 * self.p2 * y
        j[..., 0, 0] = q + 2 * x * x * dq + 2 * self.p1 * y + 6 * self.p2 * x
        j[..., 0, 1] = off
        j[..., 1, 0] = off
        j[..., 1, 1] = q + 2 * y * y * dq + 6 * self.p1 * y + 2 * self.p2 * x
        return j

    def project_jacobians(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (N, 2), d px / d ray (N, 2, 3), d px / d :attr:`PARAMETERS` (N, 2, 11).

        Raises
        ------
        CameraError
            A ray behind the camera (Z <= 0) or beyond the valid field (names its index).
        """
        r = as_rays(rays)
        X, Y, Z = r[:, 0], r[:, 1], r[:, 2]
        check_front(self, r, self._fold_r)  # type: ignore[attr-defined]
        x, y = X / Z, Y / Z
        xd, yd, r2, q = self._distort(x, y)
        px = np.column_stack([self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy])
        a = np.array([[self.fx, self.skew], [0.0, self.fy]])
        jd = a @ self._distort_jacobian(x, y, r2, q)                       # d px / d (x, y)
        jn = np.zeros((len(r), 2, 3))
        jn[:, 0, 0] = jn[:, 1, 1] = 1 / Z
        jn[:, 0, 2], jn[:, 1, 2] = -x / Z, -y / Z
        j_ray = jd @ jn
        dd = np.zeros((len(r), 2, 11))                                   # d (x', y') / d params
        p = r2.copy()
        for i in range(4):                                               # k1..k4
            dd[:, 0, 4 + i], dd[:, 1, 4 + i] = x * p, y * p
            p = p * r2
        dd[:, 0, 8], dd[:, 1, 8] = 2 * x * y, r2 + 2 * y * y            # p1
        dd[:, 0, 9], dd[:, 1, 9] = r2 + 2 * x * x, 2 * x * y            # p2
        j_par = np.einsum("ij,njk->nik", a, dd)
        j_par[:, 0, 0] = xd
        j_par[:, 1, 1] = yd
        j_par[:, 0, 2] = 1.0
        j_par[:, 1, 3] = 1.0
        j_par[:, 0, 10] = yd
        return px, j_ray, j_par

    def project(self, rays: Any) -> np.ndarray:
        """Rays (N, 3) -> pixels (N, 2) (see :meth:`project_jacobians`)."""
        r = as_rays(rays)
        check_front(self, r, self._fold_r)  # type: ignore[attr-defined]
        xd, yd, _, _ = self._distort(r[:, 0] / r[:, 2], r[:, 1] / r[:, 2])
        return np.column_stack([self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy])

    def unproject(self, px: Any, *, tol_px: float = TOL_PX, max_iter: int = 50,
                  on_fail: str = "raise") -> np.ndarray:
        """Pixels (N, 2) -> unit rays (N, 3) by Newton's method (module docstring).

        Parameters
        ----------
        px : array_like, (N, 2)
            Column, row (pixel-centre origin).
        tol_px : float
            Convergence: the forward residual ``|distort(x) - x'|`` times the focal length <= tol_px.
        max_iter : int
            Newton iterations before giving up.
        on_fail : {"raise", "nan"}
            A pixel that does not converge: raise, or NaN rays.
        """
        p = as_pixels(px)
        target = self._normalised_distorted(p)
        xy = target.copy()
        tol = tol_px / max(self.fx, self.fy)
        done = np.zeros(len(p), dtype=bool)
        with np.errstate(all="ignore"):
            for _ in range(max_iter + 1):
                todo = np.flatnonzero(~done)
                if not len(todo):
                    break
                x, y = xy[todo, 0], xy[todo, 1]
                xd, yd, r2, q = self._distort(x, y)
                res = np.column_stack([xd, yd]) - target[todo]
                ok = (np.abs(res) <= tol).all(axis=1)
                done[todo[ok]] = True
                j = self._distort_jacobian(x, y, r2, q)[~ok]
                res, todo = res[~ok], todo[~ok]
                det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
                xy[todo, 0] -= (j[:, 1, 1] * res[:, 0] - j[:, 0, 1] * res[:, 1]) / det
                xy[todo, 1] -= (j[:, 0, 0] * res[:, 1] - j[:, 1, 0] * res[:, 0]) / det
        failed = ~done | ~np.isfinite(xy).all(axis=1)
        failed |= np.hypot(xy[:, 0], xy[:, 1]) > self._fold_r  # type: ignore[attr-defined]
        if failed.any():
            if on_fail == "raise":
                raise self._not_converged(p, failed, max_iter)
            xy[failed] = np.nan
        rays = np.column_stack([xy, np.ones(len(p))])
        return rays / np.linalg.norm(rays, axis=1)[:, None]
