r"""A weak edge of a vertex tested against its strong edges before it enters the point (measure step 3b), and
the line that goes when a vertex's lines do not meet at one point (step 3c).

A line is *weak* when its gradient is less than ``two_line_ratio`` times the texture's (two such
lines alone are not accepted: no check).  With two or more *strong* lines meeting at ``min_angle_deg``
or more, the strong lines alone fix the point :math:`x_S` with covariance :math:`N_S^{-1}`
(:func:`~lidarcat.photocontrol._along.intersect_lines`).  A weak line :math:`m_i^T x = c_i`, independent
of them, has the offset :math:`r_i = m_i^T x_S - c_i` with variance
:math:`m_i^T N_S^{-1} m_i + v_i` (:math:`v_i` its own offset variance at :math:`x_S`, step 3), so
:math:`w_i = r_i / \sqrt{m_i^T N_S^{-1} m_i + v_i}` is standard normal when it is right.  It is
dropped when :math:`|w_i|` exceeds ``weak_edge_w``.  See the measure module docstring (step 3b) for
the level.

When the lines of a vertex fail the chi2 check, :func:`worst_line` names the line that goes: the largest
:math:`|w_i|` of each line against the point of the others (same statistic) with two or more
redundancies; with one (three lines) every :math:`|w_i|` is the same and the weakest line goes (the
derivation is in the measure module docstring, step 3c).
"""

from __future__ import annotations

import math

import numpy as np

from ._along import intersect_lines, line_offset_variance

__all__ = ["weak_edge_tests", "worst_line"]


def weak_edge_tests(fits: list, mm: np.ndarray, cc: np.ndarray, covs: list, use: list, origin: np.ndarray, *,
                    two_line_ratio: float, min_angle_deg: float, sd_px: float, texture_px: float
                    ) -> list[tuple[int, float]]:
    """w of each weak line in *use* against the point of the strong lines in *use* (px, measure step 3b).

    Parameters
    ----------
    fits : list of ``(u (2,), fit)``
        The edge fits (``fit[1]`` the direction-observed covariance, ``fit[3]`` the gradient ratio).
    mm : (n, 2) float
        Unit normals of the lines.
    cc : (n,) float
        Offsets, :math:`m_i^T x = c_i` (px).
    covs : list of ``(cov (2, 2), b)``
        Each fit's covariance of (offset, slope) and its slope.
    use : list of int
        The lines still in the point.
    origin : (2,) float
        The shifted prediction the fits are relative to (px).
    two_line_ratio, min_angle_deg, sd_px, texture_px : float
        As in :class:`~lidarcat.photocontrol.measure.MeasureParams`.

    Returns
    -------
    list of (int, float)
        ``(line, w)`` for every weak line; empty when fewer than two strong lines, or when they meet at
        less than *min_angle_deg* (then there is no point to test against).
    """
    strong = [i for i in use if float(fits[i][1][3]) >= two_line_ratio]
    weak = [i for i in use if float(fits[i][1][3]) < two_line_ratio]
    if len(strong) < 2 or not weak:
        return []
    angs = [math.degrees(math.acos(min(1.0, abs(float(mm[i] @ mm[j]))))) for i in strong for j in strong if i < j]
    if max(angs) < min_angle_deg:
        return []
    xs, n_s, _ = intersect_lines([fits[i] for i in strong], mm[strong], cc[strong], [covs[i] for i in strong],
                                 origin, sd_px, texture_px)
    c_s = np.linalg.inv(n_s)
    out = []
    for i in weak:
        u, fit = fits[i]
        cov, b = covs[i]
        v_i = line_offset_variance(u, fit, cov, b, xs, origin, sd_px, texture_px)
        r = float(mm[i] @ xs) - float(cc[i])
        out.append((i, r / math.sqrt(float(mm[i] @ c_s @ mm[i]) + v_i)))
    return out


def worst_line(fits: list, mm: np.ndarray, cc: np.ndarray, covs: list, use: list, origin: np.ndarray, *,
               sd_px: float, texture_px: float) -> tuple[int, float, float]:
    """The line of *use* (three or more) that goes when they do not meet at one point (measure step 3c).

    Each line's offset from the point of the others, ``r_i = m_i^T x_-i - c_i`` (px), and its
    w-statistic ``r_i / sqrt(m_i^T N_-i^-1 m_i + v_i)`` (exact: the line is independent of the others).
    With four or more lines the largest ``|w|`` goes; with three, where every ``|w|`` is the same (one
    redundancy), the weakest line (smallest gradient ratio ``fit[3]``) goes.

    Parameters
    ----------
    fits, mm, cc, covs, use, origin
        As in :func:`weak_edge_tests`.
    sd_px, texture_px : float
        ``MeasureParams.vertex_sd_px`` and ``vertex_texture_px``.

    Returns
    -------
    (int, float, float)
        The line, its offset r (px) and its w.
    """
    offs, ws = [], []
    for i in use:
        rest = [j for j in use if j != i]
        xr, n_r, _ = intersect_lines([fits[j] for j in rest], mm[rest], cc[rest], [covs[j] for j in rest],
                                     origin, sd_px, texture_px)
        u, fit = fits[i]
        cov, b = covs[i]
        v_i = line_offset_variance(u, fit, cov, b, xr, origin, sd_px, texture_px)
        offs.append(float(mm[i] @ xr) - float(cc[i]))
        ws.append(offs[-1] / math.sqrt(float(mm[i] @ np.linalg.solve(n_r, mm[i])) + v_i))
    k = int(np.argmin([float(fits[i][1][3]) for i in use])) if len(use) == 3 else int(np.argmax(np.abs(ws)))
    return use[k], offs[k], ws[k]
