r"""Camera models as a family: frame (thesis eq. 01-07), normalised Brown, fisheye (Kannala-Brandt).

Every model maps a *ray in the camera frame* to a *pixel* and back.  Camera frame (OpenCV,
COLMAP, OpenSfM): x right, y down, z forward along the optical axis.  Pixels: column ``u``
right, row ``v`` down, (0, 0) the *centre* of the top-left pixel (as
:mod:`lidarcat.geometry.camera` and OpenCV; COLMAP's and Metashape's corner origin is half a
pixel off, handled in :mod:`lidarcat.geometry.conversion`).

Normalised Brown (OpenCV ``OPENCV``/``FULL_OPENCV`` with k4..k6 = 0, OpenSfM/ODM ``brown``,
Metashape ``frame`` with its k4, b1, b2)::

    x = X / Z,  y = Y / Z,  r^2 = x^2 + y^2                                      (Z > 0)
    q(r^2) = 1 + k1 r^2 + k2 r^4 + k3 r^6 + k4 r^8
    x' = x q + 2 p1 x y + p2 (r^2 + 2 x^2)
    y' = y q + p1 (r^2 + 2 y^2) + 2 p2 x y
    u  = fx x' + skew y' + cx,     v = fy y' + cy

(Metashape writes ``u = w/2 + cx + x'(f + b1) + y' b2``: ``fx = f + b1``, ``skew = b2`` and
its P1, P2 are OpenCV's p2, p1.)  With ``q' = dq/d(r^2) = k1 + 2 k2 r^2 + 3 k3 r^4 + 4 k4 r^6``
the 2 x 2 Jacobian of the distortion is::

    dx'/dx = q + 2 x^2 q' + 2 p1 y + 6 p2 x      dx'/dy = 2 x y q' + 2 p1 x + 2 p2 y
    dy'/dx = 2 x y q' + 2 p1 x + 2 p2 y          dy'/dy = q + 2 y^2 q' + 6 p1 y + 2 p2 x

and ``d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]``.  The parameters enter
linearly: ``du/dfx = x'``, ``dv/dfy = y'``, ``du/dskew = y'``, ``du/dcx = dv/dcy = 1``,
``d(x', y')/dk_i = (x, y) r^(2i)``, ``d(x', y')/dp1 = (2 x y, r^2 + 2 y^2)``,
``d(x', y')/dp2 = (r^2 + 2 x^2, 2 x y)``, each mapped through ``[[fx, skew], [0, fy]]``.

Fisheye, equidistant Kannala-Brandt (OpenCV ``cv::fisheye``, COLMAP ``OPENCV_FISHEYE``,
OpenSfM ``fisheye_opencv``)::

    rho = sqrt(X^2 + Y^2),   theta = atan2(rho, Z)       (angle from the optical axis, 0..180 deg)
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    x' = theta_d X / rho,    y' = theta_d Y / rho
    u  = fx x' + cx,         v = fy y' + cy

``atan2`` instead of ``atan(rho / Z)`` carries the model past 90 deg (lenses of more than 180 deg
field); COLMAP's and OpenCV's ``atan(r)`` of ``X/Z`` agree for Z > 0.  With ``s = theta_d / rho``,
``dtheta/d(X, Y, Z) = (Z X / rho, Z Y / rho, -rho) / (rho^2 + Z^2)`` and
``ds = theta_d'(theta) dtheta / rho - theta_d drho / rho^2``, ``x' = s X``, ``y' = s Y``; on the
axis (rho -> 0) the limit is the pinhole ``s = 1 / Z``, ``ds/dZ = -1 / Z^2``.

Frame (:class:`FrameModel`): the thesis camera (:class:`lidarcat.geometry.camera.Camera`)
unchanged: the corrected photo coordinate of a ray is ``(x_fotc, y_fotc) = c (X/Z, -Y/Z)`` (mm,
y up) and the pixel is :meth:`Camera.photo_to_pixel` of it.  Its Jacobians follow from the
implicit function ``F(px, theta) = x_fotc(px; theta) - c (X/Z, -Y/Z) = 0`` of eq. 01-07:
``dpx/d(.) = -(dF/dpx)^-1 dF/d(.)`` with ``dF/dpx`` = :meth:`Camera.pixel_to_photo_jacobian`.

Inverse (pixel -> ray).  Brown: Newton's method on ``distort(x, y) = (x', y')`` with the 2 x 2
Jacobian above, vectorised, from ``(x, y) = (x', y')``; fisheye: Newton on the scalar
``theta_d(theta) = |(x', y')|``; both stop when the forward residual, in pixels (``f`` times the
normalised residual), is at most ``tol_px`` (default 1e-11 px) on every point, and raise a
:class:`~lidarcat.errors.CameraError` naming the camera and the pixel otherwise.  Frame: eq. 01-07
are the inverse in closed form.

Valid range.  A model is accepted only if its distortion is invertible over the image: the
radial map ``r -> r q(r^2)`` (Brown) or ``theta -> theta_d(theta)`` (fisheye) must increase
from the axis out to the image corners (else the image folds over).  The *valid field* is the
part of the increasing branch (and, for the fisheye, at most 180 deg from the axis); a ray
outside it (or behind a Brown/frame camera, Z <= 0) is refused with the camera and the ray
named.  Checks sample the radial map densely (4097 points from the axis to the bound).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import CameraError
from .camera import Camera

__all__ = ["CameraModel", "BrownCamera", "FisheyeCamera", "FrameModel", "MODELS", "camera_model",
           "as_rays", "as_pixels", "TOL_PX"]

#: default convergence tolerance of the inverses, pixels
TOL_PX = 1e-11


def as_rays(rays: Any) -> np.ndarray:
    """*rays* as a float64 (N, 3) array (a single (3,) ray becomes (1, 3))."""
    a = np.asarray(rays, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == 3:
        a = a.reshape(1, 3)
    if a.ndim != 2 or a.shape[1] != 3:
        raise CameraError(f"rays must have shape (N, 3) or (3,), got {a.shape}")
    return a


def as_pixels(px: Any) -> np.ndarray:
    """*px* as a float64 (N, 2) array (a single (2,) pixel becomes (1, 2))."""
    a = np.asarray(px, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == 2:
        a = a.reshape(1, 2)
    if a.ndim != 2 or a.shape[1] != 2:
        raise CameraError(f"pixels must have shape (N, 2) or (2,), got {a.shape}")
    return a


def _number(cam_id: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CameraError(f"camera {cam_id!r}: field {name!r}: must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise CameraError(f"camera {cam_id!r}: field {name!r}: must be finite, got {v!r}")
    return v


def _size(cam_id: str, name: str, value: Any) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= 1_000_000:
        raise CameraError(f"camera {cam_id!r}: field {name!r}: must be a whole number of pixels "
                          f"1..1,000,000, got {value!r}")
    return int(value)


class CameraModel:
    """What every camera model offers (a mixin of the frozen model dataclasses).

    Attributes of a model: ``id`` (str), ``width_px``, ``height_px`` (int), the parameters
    :attr:`PARAMETERS` (floats) and :attr:`KIND` (the model name of :data:`MODELS`).
    """

    KIND: ClassVar[str] = ""
    PARAMETERS: ClassVar[tuple[str, ...]] = ()
    id: str
    width_px: int
    height_px: int

    # -- parameters ------------------------------------------------------------------
    def params(self) -> np.ndarray:
        """The parameter values in :attr:`PARAMETERS` order, shape (m,)."""
        return np.array([getattr(self, p) for p in self.PARAMETERS], dtype=float)

    def with_params(self, values: Any) -> CameraModel:
        """A copy with the parameters *values* (shape (m,), :attr:`PARAMETERS` order), checked again."""
        v = np.asarray(values, dtype=float).ravel()
        if v.shape != (len(self.PARAMETERS),):
            raise CameraError(f"camera {self.id!r}: {len(self.PARAMETERS)} parameters expected "
                              f"({', '.join(self.PARAMETERS)}), got {v.size}")
        return dataclasses.replace(self, **dict(zip(self.PARAMETERS, map(float, v))))  # type: ignore[type-var]

    def corners_px(self) -> np.ndarray:
        """The four outer image corners (pixel-centre origin: -0.5 .. size - 0.5), shape (4, 2)."""
        w, h = self.width_px - 0.5, self.height_px - 0.5
        return np.array([[-0.5, -0.5], [w, -0.5], [-0.5, h], [w, h]])

    def grid_px(self, n: int = 41) -> np.ndarray:
        """An n x n grid of pixels over the whole image, border included, shape (n*n, 2)."""
        u = np.linspace(-0.5, self.width_px - 0.5, n)
        v = np.linspace(-0.5, self.height_px - 0.5, n)
        return np.stack(np.meshgrid(u, v), axis=-1).reshape(-1, 2)

    # -- to be provided ----------------------------------------------------------------
    def project(self, rays: Any) -> np.ndarray:  # pragma: no cover - interface
        """Rays (N, 3), camera frame -> pixels (N, 2); refuses rays outside the valid field."""
        return self.project_jacobians(rays)[0]

    def project_jacobians(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
        """Pixels (N, 2), d px / d ray (N, 2, 3) and d px / d parameters (N, 2, m)."""
        raise NotImplementedError

    def unproject(self, px: Any, *, tol_px: float = TOL_PX, max_iter: int = 50) -> np.ndarray:  # pragma: no cover
        """Pixels (N, 2) -> unit rays (N, 3), camera frame."""
        raise NotImplementedError

    def _not_converged(self, px: np.ndarray, failed: np.ndarray, max_iter: int) -> CameraError:
        i = int(np.flatnonzero(failed)[0])
        return CameraError(f"camera {self.id!r}: pixel index {i} ({px[i, 0]:.6g}, {px[i, 1]:.6g}) did not "
                           f"converge to a ray within {max_iter} iterations ({int(failed.sum())} pixel(s) "
                           f"failed); it lies outside the model's valid field")


# ---------------------------------------------------------------------------------------
# helpers shared by the radial checks
# ---------------------------------------------------------------------------------------


def _first_fold(slope: Any, hi: float, n: int = 4097) -> float:
    """The first point in (0, hi] where the function *slope* (vectorised) is <= 0, else inf."""
    t = np.linspace(0.0, hi, n)
    with np.errstate(all="ignore"):
        s = slope(t)
    bad = ~(s > 0)
    if not bad.any():
        return math.inf
    k = int(np.argmax(bad))
    if k == 0:
        return 0.0
    lo_t, hi_t = t[k - 1], t[k]
    for _ in range(60):  # bisection to the fold
        mid = 0.5 * (lo_t + hi_t)
        if slope(np.array([mid]))[0] > 0:
            lo_t = mid
        else:
            hi_t = mid
    return float(lo_t)


def _invert_increasing(f: Any, df: Any, target: np.ndarray, start: np.ndarray, tol: np.ndarray,
                       max_iter: int) -> tuple[np.ndarray, np.ndarray]:
    """Newton on the scalar increasing f(t) = target, vectorised: (t, converged mask)."""
    t = start.copy()
    ok = np.zeros(t.shape, dtype=bool)
    with np.errstate(all="ignore"):
        for _ in range(max_iter):
            res = f(t) - target
            ok = np.abs(res) <= tol
            if ok.all():
                break
            t = np.where(ok, t, t - res / df(t))
    return t, ok & np.isfinite(t)


# ---------------------------------------------------------------------------------------
# normalised Brown
# ---------------------------------------------------------------------------------------


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
        _check_common(self)
        # the radial map rho(r) = r q(r^2) must increase out to the image corners
        corner = np.abs(self._normalised_distorted(self.corners_px()))
        rd = float(np.hypot(corner[:, 0], corner[:, 1]).max())
        fold = _first_fold(self._radial_slope, max(10.0 * rd, 5.67))  # to 80 deg at least
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
        _check_front(self, r, self._fold_r)  # type: ignore[attr-defined]
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
        _check_front(self, r, self._fold_r)  # type: ignore[attr-defined]
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


def _check_common(cam: Any) -> None:
    """Id, size and parameter values of a Brown or fisheye camera (names the field)."""
    if not isinstance(cam.id, str) or not cam.id.strip():
        raise CameraError(f"camera id must be a non-empty string, got {cam.id!r}")
    for name in ("width_px", "height_px"):
        object.__setattr__(cam, name, _size(cam.id, name, getattr(cam, name)))
    for name in cam.PARAMETERS:
        object.__setattr__(cam, name, _number(cam.id, name, getattr(cam, name)))
    for name in ("fx", "fy"):
        if getattr(cam, name) <= 0:
            raise CameraError(f"camera {cam.id!r}: field {name!r}: focal length must be positive, "
                              f"got {getattr(cam, name)!r} px")
    for name, size in (("cx", cam.width_px), ("cy", cam.height_px)):
        if not -0.5 <= getattr(cam, name) <= size - 0.5:
            raise CameraError(f"camera {cam.id!r}: field {name!r}: principal point {getattr(cam, name)!r} px "
                              f"lies outside the image (-0.5 .. {size - 0.5:g} px)")


def _check_front(cam: Any, r: np.ndarray, fold_r: float) -> None:
    """Refuse rays behind the camera or beyond the radial fold (normalised radius *fold_r*)."""
    with np.errstate(all="ignore"):
        rr = np.hypot(r[:, 0], r[:, 1]) / r[:, 2]
    bad = ~(r[:, 2] > 0) | ~np.isfinite(r).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise CameraError(f"camera {cam.id!r}: ray index {i} ({r[i, 0]:.6g}, {r[i, 1]:.6g}, {r[i, 2]:.6g}) "
                          f"is not in front of the camera (Z must be > 0)")
    far = rr > fold_r
    if far.any():
        i = int(np.flatnonzero(far)[0])
        raise CameraError(f"camera {cam.id!r}: ray index {i} at {math.degrees(math.atan(rr[i])):.4g} deg from "
                          f"the optical axis is beyond the model's valid field (the radial distortion folds "
                          f"over at {math.degrees(math.atan(fold_r)):.4g} deg)")


# ---------------------------------------------------------------------------------------
# fisheye (Kannala-Brandt equidistant)
# ---------------------------------------------------------------------------------------


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
        _check_common(self)
        fold = min(_first_fold(self._theta_slope, math.pi), math.pi)
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
        theta, ok = _invert_increasing(self._theta_d, self._theta_slope, td, np.minimum(td, self._fold), tol,
                                       max_iter)
        failed = ~ok | (theta > self._fold) | (theta < 0)  # type: ignore[attr-defined]
        if failed.any():
            if on_fail == "raise":
                raise self._not_converged(p, failed, max_iter)
            theta[failed] = np.nan
        with np.errstate(all="ignore"):
            unit = np.where((td > 0)[:, None], d / np.where(td > 0, td, 1.0)[:, None], 0.0)
        return np.column_stack([np.sin(theta)[:, None] * unit, np.cos(theta)])


# ---------------------------------------------------------------------------------------
# frame: the thesis camera
# ---------------------------------------------------------------------------------------

#: the frame model's parameters and the Camera fields they are
_FRAME_FIELDS = {"c": "focal_length_mm", "x0": "principal_point_x_mm", "y0": "principal_point_y_mm",
                 "k1": "k1", "k2": "k2", "k3": "k3", "p1": "p1", "p2": "p2"}


@dataclass(frozen=True)
class FrameModel(CameraModel):
    """The thesis frame camera (:class:`~lidarcat.geometry.camera.Camera`, unchanged) as a model.

    Parameters
    ----------
    camera : Camera
        The calibration; the model's parameters are ``c, x0, y0, k1, k2, k3, p1, p2``
        (mm, mm^-2.., mm^-1; refraction and pixel pitch stay as calibrated).
    """

    KIND: ClassVar[str] = "frame"
    PARAMETERS: ClassVar[tuple[str, ...]] = tuple(_FRAME_FIELDS)

    camera: Camera

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera):
            raise CameraError(f"a frame model wraps a Camera, got {type(self.camera).__name__}")

    @property
    def id(self) -> str:  # type: ignore[override]
        return self.camera.id

    @property
    def width_px(self) -> int:  # type: ignore[override]
        return self.camera.columns_px

    @property
    def height_px(self) -> int:  # type: ignore[override]
        return self.camera.rows_px

    def params(self) -> np.ndarray:
        return np.array([getattr(self.camera, f) for f in _FRAME_FIELDS.values()], dtype=float)

    def with_params(self, values: Any) -> FrameModel:
        v = np.asarray(values, dtype=float).ravel()
        if v.shape != (len(self.PARAMETERS),):
            raise CameraError(f"camera {self.id!r}: {len(self.PARAMETERS)} parameters expected "
                              f"({', '.join(self.PARAMETERS)}), got {v.size}")
        return FrameModel(dataclasses.replace(self.camera, **dict(zip(_FRAME_FIELDS.values(), map(float, v)))))

    def _photo(self, rays: Any) -> np.ndarray:
        r = as_rays(rays)
        _check_front(self, r, math.inf)
        c = self.camera.focal_length_mm
        return np.column_stack([c * r[:, 0] / r[:, 2], -c * r[:, 1] / r[:, 2]])

    def project(self, rays: Any) -> np.ndarray:
        """Rays (N, 3) -> pixels (N, 2) through eq. 01-07 inverted (Newton, 1e-12 mm)."""
        return np.asarray(self.camera.photo_to_pixel(self._photo(rays), tol_mm=1e-12)).reshape(-1, 2)

    def project_jacobians(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (N, 2), d px / d ray (N, 2, 3), d px / d (c, x0, y0, k1, k2, k3, p1, p2) (N, 2, 8)."""
        r = as_rays(rays)
        cam = self.camera
        px = self.project(r)
        jinv = np.linalg.inv(np.asarray(cam.pixel_to_photo_jacobian(px)).reshape(-1, 2, 2))  # d px / d x_fotc
        X, Y, Z = r[:, 0], r[:, 1], r[:, 2]
        c = cam.focal_length_mm
        dphoto = np.zeros((len(r), 2, 3))
        dphoto[:, 0, 0], dphoto[:, 0, 2] = c / Z, -c * X / Z**2
        dphoto[:, 1, 1], dphoto[:, 1, 2] = -c / Z, c * Y / Z**2
        j_ray = jinv @ dphoto
        fot = np.asarray(cam.pixel_to_fot(px)).reshape(-1, 2)
        x, y = fot[:, 0], fot[:, 1]
        r2 = x * x + y * y
        dF = np.zeros((len(r), 2, 8))                        # dF/dtheta, F = x_fotc(px; theta) - target
        dF[:, 0, 0], dF[:, 1, 0] = -X / Z, Y / Z             # target = c (X/Z, -Y/Z)
        e = cam.refraction_eps45
        if e:                                                # refraction term depends on c too
            dF[:, 0, 0] += 2 * x * r2 * e / c**3
            dF[:, 1, 0] += 2 * y * r2 * e / c**3
        # d x_fotc / d x_fot = (d x_fotc / d px) (d px / d x_fot), d x_fot / d px = diag(t_x, -t_y) (eq. 01)
        jd = np.asarray(cam.pixel_to_photo_jacobian(px)).reshape(-1, 2, 2) / np.array(
            [cam.pixel_size_x_mm, -cam.pixel_size_y_mm])[None, None, :]
        dF[:, :, 1] = -jd[:, :, 0]                           # x_fot = pfid - x0
        dF[:, :, 2] = -jd[:, :, 1]
        for i in range(3):
            p = r2 ** (i + 1)
            dF[:, 0, 3 + i], dF[:, 1, 3 + i] = -x * p, -y * p
        dF[:, 0, 6], dF[:, 1, 6] = -(r2 + 2 * x * x), -2 * x * y
        dF[:, 0, 7], dF[:, 1, 7] = -2 * x * y, -(r2 + 2 * y * y)
        return px, j_ray, -jinv @ dF

    def unproject(self, px: Any, *, tol_px: float = TOL_PX, max_iter: int = 50,
                  on_fail: str = "raise") -> np.ndarray:
        """Pixels (N, 2) -> unit rays (N, 3): eq. 01-07 in closed form (the tolerances are unused)."""
        xy = np.asarray(self.camera.pixel_to_photo(as_pixels(px))).reshape(-1, 2)
        rays = np.column_stack([xy[:, 0], -xy[:, 1], np.full(len(xy), self.camera.focal_length_mm)])
        return rays / np.linalg.norm(rays, axis=1)[:, None]


#: model name -> class
MODELS: dict[str, type] = {"frame": FrameModel, "brown": BrownCamera, "fisheye": FisheyeCamera}


def camera_model(kind: str, *args: Any, **kwargs: Any) -> CameraModel:
    """Build a camera model by name (``frame``, ``brown``, ``fisheye``).

    >>> camera_model("brown", "c", 100, 80, fx=90.0, fy=90.0, cx=49.5, cy=39.5).project([0, 0, 1])
    array([[49.5, 39.5]])

    Raises
    ------
    CameraError
        An unknown model name (with the known ones), or invalid parameters.
    """
    if kind not in MODELS:
        raise CameraError(f"unknown camera model {kind!r}; known: {', '.join(MODELS)}")
    return MODELS[kind](*args, **kwargs)

