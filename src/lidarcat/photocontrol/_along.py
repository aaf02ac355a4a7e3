r"""The vertex from its image lines (:mod:`lidarcat.photocontrol.measure`, steps 3 and 3a).

:func:`intersect_lines`: the weighted least-squares point of the edge lines :math:`m_i^T x = c_i`,
each line's offset variance its fit's at the point plus the floor of step 3 (``vertex_sd_px``,
``vertex_texture_px`` over the edge's contrast ratio).  :func:`locate_along`: the edges found lie on
one image line -- two of them on either side of the vertex bend there by a few degrees and their
intersection locates it along the line (step 3a: the derivation of the covariance, tight across,
about :math:`\sqrt{v_1 + v_2}/\beta` along, and the limits are in the measure module docstring).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["line_offset_variance", "intersect_lines", "locate_along"]


def locate_along(fits: list, mm: np.ndarray, cc: np.ndarray, covs: list, k: int, dropped: list, origin: np.ndarray,
                 *, min_angle_deg: float, max_sd_px: float, two_line_ratio: float, sd_px: float,
                 texture_px: float) -> Any:
    """The vertex on the one image line *k* found, located along it where it bends (measure step 3a).

    *fits* ``(u, fit)``, lines :math:`m^T x = c` (*mm* (n, 2), *cc* (n,)) and ``(cov, b)`` *covs* of the
    edges found (px); *dropped*: the edges dropped as found on *k*'s line.  Of those on the other side
    of the vertex (opposite half-lines) meeting *k* at *min_angle_deg* or more, the one at the largest
    angle is intersected with *k* (:func:`intersect_lines` with *sd_px*, *texture_px*); both must be
    *two_line_ratio* times the texture, the sd along the line at most *max_sd_px*, the point between
    the two fitted stretches.  Returns ``(x (2,), cov (2, 2), other edge, how)`` or the reason (str)
    why the vertex cannot be located along the line."""
    uk = fits[k][0]
    cand = [(math.degrees(math.acos(min(1.0, abs(float(mm[k] @ mm[o]))))), o) for o in dropped
            if float(fits[o][0] @ uk) < 0]
    if not cand:
        return "no edge of the vertex on the other side of it, not located along the line"
    ang, o = max(cand)
    if ang < min_angle_deg:
        return (f"the edges on either side of the vertex meet at {ang:.1f} deg (< {min_angle_deg:g}): "
                f"not located along the line")
    weak = [i for i in (k, o) if float(fits[i][1][3]) < two_line_ratio]
    if weak:
        return (f"of the two edges meeting at {ang:.0f} deg one is weak (gradient {float(fits[weak[0]][1][3]):.1f} x "
                f"the texture's, < {two_line_ratio:g}): not located along the line")
    x, n_mat, _ = intersect_lines([fits[k], fits[o]], mm[[k, o]], cc[[k, o]], [covs[k], covs[o]], origin,
                                  sd_px, texture_px)
    d = np.array([mm[k][1], -mm[k][0]])
    t = np.array([mm[k], d])
    ct = t @ np.linalg.inv(n_mat) @ t.T
    sd_across, sd_along = math.sqrt(ct[0, 0]), math.sqrt(ct[1, 1])
    if sd_along > max_sd_px:
        return (f"the edges on either side of the vertex meet at {ang:.0f} deg: along the line to "
                f"{sd_along:.1f} px only (> {max_sd_px:g})")
    # the point must lie between the two fitted stretches (the stations start t0 from the vertex)
    s_x = float(uk @ (x - origin))
    lo, hi = -float(fits[o][1][2][0]) - 2.0 * sd_along, float(fits[k][1][2][0]) + 2.0 * sd_along
    if not lo <= s_x <= hi:
        return (f"the edges on either side of the vertex meet {s_x:+.1f} px along the line from where they "
                f"were fitted, inside a fitted stretch: not located along the line")
    cov_x = t.T @ ct @ t
    return x, 0.5 * (cov_x + cov_x.T), o, (f"their intersection at {ang:.0f} deg: sd {sd_across:.2f} px "
                                           f"across the edge, {sd_along:.2f} px along it")


def line_offset_variance(u: np.ndarray, fit: tuple, cov: np.ndarray, b: float, x: np.ndarray, origin: np.ndarray,
                         sd_px: float, texture_px: float = 0.0) -> float:
    """A fitted line's offset variance at the point *x* (px^2, measure step 3): its fit's (offset, slope)
    covariance *cov* propagated to *x* (direction *u*, slope *b*, relative to *origin*), plus
    ``sd_px^2 + (texture_px / ratio)^2`` (ratio: the edge's gradient over the texture's, ``fit[3]``)."""
    jv = np.array([1.0, float((x - origin) @ u)])
    extra = sd_px**2 + (texture_px / max(float(fit[3]), 1e-9)) ** 2
    return max(float(jv @ cov @ jv), 1e-8) / (1.0 + b * b) + extra


def intersect_lines(fits: list, mm: np.ndarray, cc: np.ndarray, covs: list, origin: np.ndarray, sd_px: float,
                    texture_px: float = 0.0) -> tuple[np.ndarray, np.ndarray, float]:
    """Weighted least-squares point of lines m^T x = c (measure step 3): point (2,), normal matrix (2, 2), chi2.

    Each line's offset variance: its fit's at the point, plus ``sd_px^2 + (texture_px / ratio)^2``
    (ratio: the edge's gradient over the texture's, ``fit[3]``)."""
    x = origin.copy()
    for _ in range(3):
        w = np.array([1.0 / line_offset_variance(u, fit, cov, b, x, origin, sd_px, texture_px)
                      for (u, fit), (cov, b) in zip(fits, covs)])
        n_mat = (mm * w[:, None]).T @ mm
        x = np.linalg.solve(n_mat, (mm * w[:, None]).T @ cc)
    r = mm @ x - cc
    return x, n_mat, float(np.sum(w * r * r))
