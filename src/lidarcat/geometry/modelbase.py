r"""What every camera model shares: the :class:`CameraModel` interface, array shapes, value checks.

The models themselves: :mod:`.brown` (normalised Brown), :mod:`.fisheye` (Kannala-Brandt),
:mod:`.models` (the frame model, the registry :data:`~lidarcat.geometry.models.MODELS`; the
conventions and the mathematics of the family are derived in its docstring).  The helpers here
are shared by the model modules: the radial-fold search (:func:`first_fold`), the scalar
Newton inverse (:func:`invert_increasing`) and the checks of ids, sizes, parameters and rays.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, ClassVar

import numpy as np

from ..errors import CameraError

__all__ = ["CameraModel", "as_rays", "as_pixels", "TOL_PX", "check_number", "check_size", "first_fold",
           "invert_increasing", "check_common", "check_front"]

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


def check_number(cam_id: str, name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise CameraError(f"camera {cam_id!r}: field {name!r}: must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise CameraError(f"camera {cam_id!r}: field {name!r}: must be finite, got {v!r}")
    return v


def check_size(cam_id: str, name: str, value: Any) -> int:
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


def first_fold(slope: Any, hi: float, n: int = 4097) -> float:
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


def invert_increasing(f: Any, df: Any, target: np.ndarray, start: np.ndarray, tol: np.ndarray,
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


def check_common(cam: Any) -> None:
    """Id, size and parameter values of a Brown or fisheye camera (names the field)."""
    if not isinstance(cam.id, str) or not cam.id.strip():
        raise CameraError(f"camera id must be a non-empty string, got {cam.id!r}")
    for name in ("width_px", "height_px"):
        object.__setattr__(cam, name, check_size(cam.id, name, getattr(cam, name)))
    for name in cam.PARAMETERS:
        object.__setattr__(cam, name, check_number(cam.id, name, getattr(cam, name)))
    for name in ("fx", "fy"):
        if getattr(cam, name) <= 0:
            raise CameraError(f"camera {cam.id!r}: field {name!r}: focal length must be positive, "
                              f"got {getattr(cam, name)!r} px")
    for name, size in (("cx", cam.width_px), ("cy", cam.height_px)):
        if not -0.5 <= getattr(cam, name) <= size - 0.5:
            raise CameraError(f"camera {cam.id!r}: field {name!r}: principal point {getattr(cam, name)!r} px "
                              f"lies outside the image (-0.5 .. {size - 0.5:g} px)")


def check_front(cam: Any, r: np.ndarray, fold_r: float) -> None:
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
