"""Whether a frame camera's distortion can be inverted over its frame (private to :mod:`lidarcat.geometry`).

A calibration is accepted only if the inverse, corrected photo coordinates -> pixel, exists over the
image format (:mod:`lidarcat.geometry.camera`'s docstring derives the conditions).  With ``u = r^2``
and ``R`` the distance from the principal point to the farthest frame corner::

    rho(r) = r (1 - g(u)),   g(u) = eps45 + (K1 + eps45 / c^2) u + K2 u^2 + K3 u^3
    rho'(r) = 1 - eps45 - 3 (K1 + eps45 / c^2) u - 5 K2 u^2 - 7 K3 u^3

``rho'`` must stay positive on ``[0, R]`` and on to ``rho(R)``; ``|g|`` at most
:data:`MAX_RADIAL_SHARE`; the decentering Jacobian's largest eigenvalue magnitude over the frame below
half of ``min rho'``.  Both radial conditions are cubics in ``u``: their extremes are found exactly (end
points and roots of the derivative, :func:`numpy.roots`; where the companion matrix fails, the sign
changes of 4097 samples).  :func:`distortion_fault` returns the coefficient to blame and the message;
:class:`~lidarcat.geometry.camera.Camera` raises them as a :class:`~lidarcat.errors.CameraError`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["MAX_RADIAL_SHARE", "distortion_fault"]

#: the largest radial correction accepted, as a share of the radius (see the module docstring)
MAX_RADIAL_SHARE = 0.5


def distortion_fault(frame_mm: tuple[float, float], principal_point_mm: tuple[float, float],
                     focal_length_mm: float, k1: float, k2: float, k3: float, p1: float, p2: float,
                     refraction_eps45: float) -> tuple[str, str] | None:
    """Why the distortion (eq. 03-06) cannot be inverted over the frame *frame_mm* (width, height), as
    ``(the key to blame, the message)``; None when it can.  Lengths in mm, coefficients in the units of a
    camera table (``k1`` mm^-2 .. ``k3`` mm^-6, ``p1``, ``p2`` mm^-1)."""
    radial = {"k1": k1, "k2": k2, "k3": k3}
    w, h = frame_mm
    cx = np.array([-w / 2, w / 2]) - principal_point_mm[0]
    cy = np.array([-h / 2, h / 2]) - principal_point_mm[1]
    big_r = math.hypot(np.abs(cx).max(), np.abs(cy).max())
    big_u = big_r * big_r
    e, c2 = refraction_eps45, focal_length_mm ** 2
    k1e = k1 + e / c2
    # coefficients of u^0..u^3: rho'(u) and g(u)
    slope = np.array([1.0 - e, -3.0 * k1e, -5.0 * k2, -7.0 * k3])
    share = np.array([e, k1e, k2, k3])
    coeffs = "k1 = {:.6g}, k2 = {:.6g}, k3 = {:.6g}".format(k1, k2, k3)
    if e:
        coeffs += f", refraction_eps45 = {e:.6g}"
    units = "check the values and their units (mm^-2, mm^-4, mm^-6)"
    if not (np.isfinite(slope).all() and np.isfinite(share).all()):
        return (max(("k1", "k2", "k3"), key=lambda k: abs(radial[k])),
                f"radial distortion {coeffs} is beyond any lens; {units}")

    def culprit(u: float) -> str:  # the radial coefficient with the largest term at u
        terms = {"k1": abs(k1) * u, "k2": abs(k2) * u * u, "k3": abs(k3) * u ** 3,
                 "refraction_eps45": abs(e) * (1 + u / c2)}
        return max(terms, key=terms.__getitem__)

    lo_u, lo = _cubic_extreme(slope, big_u, min)
    if not lo > 0:
        u0 = _first_root(slope, big_u)
        return (culprit(u0), (
            f"radial distortion {coeffs} folds over within the frame: the corrected radius stops "
            f"increasing at r = {math.sqrt(u0):.4g} mm from the principal point (the frame "
            f"reaches {big_r:.4g} mm), so no pixel can be found for a corrected coordinate; {units}"))
    hi_u, hi = _cubic_extreme(share, big_u, lambda v: max(v, key=abs))
    if not abs(hi) <= MAX_RADIAL_SHARE:
        r = math.sqrt(hi_u)
        return (culprit(hi_u), (
            f"radial distortion {coeffs} moves a point {r:.4g} mm from the principal point by "
            f"{abs(hi) * r:.4g} mm, {abs(hi):.3g} times its radius (at most {MAX_RADIAL_SHARE:g} "
            f"within the {w:.4g} x {h:.4g} mm frame): not a lens distortion; {units}"))
    # the inverse starts from the corrected coordinate, which reaches rho(R): monotonic up to there too
    rho_r = big_r * (1.0 - _polyval(share, big_u))
    if rho_r > big_r:
        if not _cubic_extreme(slope, rho_r * rho_r, min)[1] > 0:
            u0 = _first_root(slope, rho_r * rho_r)
            return (culprit(u0), (
                f"radial distortion {coeffs} folds over just outside the frame: the corrected radius "
                f"stops increasing at r = {math.sqrt(u0):.4g} mm, where corrected coordinates of the "
                f"frame reach {rho_r:.4g} mm (the frame {big_r:.4g} mm), so the inverse finds no unique "
                f"pixel; {units}"))
    x, y = np.meshgrid(cx, cy)
    a, b, d = 6 * p1 * x + 2 * p2 * y, 2 * p1 * y + 2 * p2 * x, 6 * p2 * y + 2 * p1 * x
    eig = np.abs((a + d) / 2) + np.hypot((a - d) / 2, b)  # largest |eigenvalue|, symmetric 2 x 2
    if not eig.max() < lo / 2:
        return ("p1" if abs(p1) >= abs(p2) else "p2", (
            f"decentering distortion p1 = {p1:.6g}, p2 = {p2:.6g} changes by {eig.max():.3g} mm per mm "
            f"at a frame corner, not small against the radial d rho / dr >= {lo:.3g}: the correction cannot "
            f"be inverted; check the values and their unit (mm^-1)"))
    return None


def _polyval(coef: np.ndarray, u: float) -> float:
    return float(coef[0] + u * (coef[1] + u * (coef[2] + u * coef[3])))


def _cubic_extreme(coef: np.ndarray, u_max: float, pick: Any) -> tuple[float, float]:
    """(u, value) of the cubic ``coef[0] + coef[1] u + ... + coef[3] u^3`` on ``[0, u_max]`` chosen
    by *pick* (``min``, or the largest magnitude) among the end points and stationary points."""
    cands = [0.0, u_max] + [u for u in _real_roots([coef[1], 2 * coef[2], 3 * coef[3]], u_max) if 0 < u < u_max]
    vals = {_polyval(coef, u): u for u in cands}
    v = pick(vals)
    return vals[v], v


def _first_root(coef: np.ndarray, u_max: float) -> float:
    """The smallest u in ``[0, u_max]`` where the cubic *coef* is <= 0 (u_max if none is found)."""
    inside = [u for u in _real_roots(coef, u_max) if 0 <= u <= u_max]
    return min(inside) if inside else u_max


def _real_roots(coef: Any, u_max: float) -> list[float]:
    """Real roots of ``coef[0] + coef[1] u + ...``; where the companion matrix fails (coefficients
    spanning more than the float range), the sign changes of 4097 samples on ``[0, u_max]``."""
    if not np.any(coef[1:]):
        return []
    try:
        return [float(z.real) for z in np.roots(np.asarray(coef, dtype=float)[::-1])
                if abs(z.imag) <= 1e-9 * max(1.0, abs(z.real))]
    except (np.linalg.LinAlgError, ValueError):
        u = np.linspace(0.0, u_max, 4097)
        v = np.polynomial.polynomial.polyval(u, coef)
        return [float(x) for x in u[1:][np.sign(v[1:]) != np.sign(v[:-1])]]

