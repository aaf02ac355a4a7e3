r"""Forward distortion models of other programs and their numerical inverse.

COLMAP, OpenCV, OpenSfM and Metashape *distort* ideal normalised coordinates
``(x, y) = (X_c/Z_c, Y_c/Z_c)`` (camera y down):

``brown`` (OpenCV/COLMAP ``OPENCV``/``FULL_OPENCV``, OpenSfM ``brown``)::

    r2 = x^2 + y^2
    radial = (1 + k1 r2 + k2 r2^2 + k3 r2^3) / (1 + k4 r2 + k5 r2^2 + k6 r2^3)
    x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y radial + p1 (r2 + 2 y^2) + 2 p2 x y

(``SIMPLE_RADIAL``, ``RADIAL`` and OpenSfM ``perspective`` are special cases.)
Metashape uses ``k1..k4`` radial (up to r^8) and swaps the roles of p1 and p2
(``x_d = x radial + p1 (r2 + 2 x^2) + 2 p2 x y``); pass ``metashape=True``.

lidarcat's camera (eq. 03-07) is the *inverse* kind of model (the correction is a
polynomial of the distorted coordinate), so a block read from these programs
keeps the source model: observations are undistorted here exactly (Newton's
method, 2x2 Jacobian, vectorised, to 1e-15) and enter lidarcat as corrected
photo coordinates.
"""

from __future__ import annotations

import numpy as np

from ..errors import CameraError

__all__ = ["distort", "undistort", "is_identity"]

_KEYS = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")


def is_identity(params: dict) -> bool:
    """True when every distortion coefficient is zero."""
    return all(float(params.get(k, 0.0)) == 0.0 for k in _KEYS)


def _parts(xy: np.ndarray, p: dict, metashape: bool):
    x, y = xy[:, 0], xy[:, 1]
    k = [float(p.get(n, 0.0)) for n in _KEYS]
    r2 = x * x + y * y
    if metashape:
        num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * (k[2] + r2 * k[3])))
        den = np.ones_like(r2)
        p1, p2 = k[7], k[6]  # Metashape's p1 multiplies (r2 + 2x^2): OpenCV's p2
    else:
        num = 1 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]))
        den = 1 + r2 * (k[3] + r2 * (k[4] + r2 * k[5]))
        p1, p2 = k[6], k[7]
    return x, y, r2, num / den, p1, p2


def distort(xy, params: dict, *, metashape: bool = False) -> np.ndarray:
    """Ideal normalised (n, 2) -> distorted normalised (n, 2) coordinates."""
    a = np.asarray(xy, dtype=float).reshape(-1, 2)
    x, y, r2, rad, p1, p2 = _parts(a, params, metashape)
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([xd, yd])


def undistort(xy_d, params: dict, *, metashape: bool = False, tol: float = 1e-15,
              max_iter: int = 50) -> np.ndarray:
    """Distorted normalised (n, 2) -> ideal normalised (n, 2) by Newton's method.

    The Jacobian is taken by central differences (step 1e-7); the iteration stops
    when the largest correction is below *tol* (normalised units).

    Raises
    ------
    CameraError
        No convergence within *max_iter* (a point far outside the calibrated field; names
        the worst point's index and normalised coordinates).
    """
    d = np.asarray(xy_d, dtype=float).reshape(-1, 2)
    if is_identity(params) or len(d) == 0:
        return d.copy()
    u = d.copy()
    h = 1e-7
    for _ in range(max_iter):
        f = distort(u, params, metashape=metashape) - d
        jx = (distort(u + [h, 0.0], params, metashape=metashape)
              - distort(u - [h, 0.0], params, metashape=metashape)) / (2 * h)
        jy = (distort(u + [0.0, h], params, metashape=metashape)
              - distort(u - [0.0, h], params, metashape=metashape)) / (2 * h)
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        du = np.column_stack([(jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det,
                              (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det])
        u = u - du
        if np.max(np.abs(du)) < tol:
            return u
    miss = np.abs(distort(u, params, metashape=metashape) - d).max(axis=1)
    if np.max(miss) < 1e-12:
        return u
    i = int(np.argmax(miss))  # a NaN counts as the worst
    raise CameraError(f"undistortion did not converge at point index {i} (normalised {d[i, 0]:.6g}, {d[i, 1]:.6g}): "
                      f"a point outside the calibrated field?")
