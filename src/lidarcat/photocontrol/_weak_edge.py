r"""A weak edge of a vertex tested against its strong edges before it enters the point (measure step 3b).

A line is *weak* when its gradient is less than ``two_line_ratio`` times the texture's (two such
lines alone are not accepted: no check).  With two or more *strong* lines meeting at ``min_angle_deg``
or more, the strong lines alone fix the point :math:`x_S` with covariance :math:`N_S^{-1}`
(:func:`~lidarcat.photocontrol._along.intersect_lines`).  A weak line :math:`m_i^T x = c_i`, independent
of them, has the offset :math:`r_i = m_i^T x_S - c_i` with variance
:math:`m_i^T N_S^{-1} m_i + v_i` (:math:`v_i` its own offset variance at :math:`x_S`, step 3), so
:math:`w_i = r_i / \sqrt{m_i^T N_S^{-1} m_i + v_i}` is standard normal when it is right.  It is
dropped when :math:`|w_i|` exceeds ``weak_edge_w``.  See the measure module docstring (step 3b) for
the level.
"""

from __future__ import annotations

import math

import numpy as np

from ._along import intersect_lines, line_offset_variance

__all__ = ["weak_edge_tests"]


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
