r"""Tests of the line observations of one adjustment: residuals, redundancy, w-tests, snooping.

The statistics of :mod:`lidarcat.bundle.lines` (its docstring derives them): every line
observation depends on one photo's orientation only, so its residual cofactor is exact from
that photo's 6 x 6 covariance, ``Q_vv = Sigma_r - A C_i A^T``; redundancy numbers
from ``Q_vv P`` (below); the 2-D group test ``T = e^T Q_vv^-1 e ~ chi2(2)`` at the B-method level of
:mod:`lidarcat.bundle.redundancy` (q = 2, the power of the 1-D test); data snooping removes the
worst rejected observation and re-adjusts until none rejects.

Redundancy numbers of a correlated pair
---------------------------------------
The two residuals of one observation are correlated (``Sigma_r`` is full: both depend on the
same measured ``p1, p2``; when the projected end points lie far outside the measured segment,
``s_A, s_B`` >> 1, the correlation approaches 1).  Then the diagonal of ``Q_vv P`` is no
redundancy at all: only its trace ``r = tr(Q_vv P)`` and its eigenvalues (in [0, 1], those of
the projector ``I - A N^-1 A^T P``) are invariant, and a single diagonal element can be any
number -- seed 4 of the measured-control benchmark gave -1.66 and 2.42 (sum 0.77) on one
observation.  The per-residual numbers reported here are the diagonal of the symmetric form
``R = P^{1/2} Q_vv P^{1/2}`` (the same trace and eigenvalues; the diagonal of a symmetric matrix
with eigenvalues in [0, 1] lies in [0, 1]), rounding clipped to [0, 1], so they add with the
other observations' numbers to the degrees of freedom.  An observation is untestable when the
smallest eigenvalue of ``R`` is below 1e-3 (``Q_vv`` singular: its photo's orientation rests on
it in that direction); ``untestable`` names the reason.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from ..errors import DatumError
from .lines import line_terms
from .redundancy import critical_values, family_alpha
from .solve import adjust

__all__ = ["LineSnooping", "LineTests", "MIN_REDUNDANCY", "line_tests", "snoop_lines", "symmetric_redundancy"]


# ---------------------------------------------------------------------------
# tests of the line observations
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class LineTests:
    """Residuals, redundancy numbers and group tests of every line observation of one adjustment.

    Attributes
    ----------
    labels : (m,) str
        ``line L on photo P``.
    line_ids, photo_ids : (m,) str
    residuals_mm : (m, 2)
        Residuals (adjusted - observed, mm) at the end points A, B.
    residuals_px : (m, 2)
        The same in pixels when a pixel size was given, else NaN.
    sd_mm : (m, 2)
        A priori sds of the two residuals (square roots of the diagonal of ``Sigma_r``).
    redundancy : (m, 2)
        The diagonal of ``P^1/2 Q_vv P^1/2`` (in [0, 1], summing to ``tr(Q_vv P)``; module docstring).
    w : (m,)
        ``sqrt(e^T Q_vv^-1 e)`` of the 2-D group test; NaN where untestable.
    w_components : (m, 2)
        ``e_k / sqrt(q_vv,kk)``.
    untestable : (m,) str
        Why ``w`` is NaN (empty where tested).
    critical_w : float
        ``sqrt(chi2_{1-alpha_2}(2))`` of the B-method at the given level.
    """

    labels: np.ndarray
    line_ids: np.ndarray
    photo_ids: np.ndarray
    residuals_mm: np.ndarray
    residuals_px: np.ndarray
    sd_mm: np.ndarray
    redundancy: np.ndarray
    w: np.ndarray
    w_components: np.ndarray
    critical_w: float
    alpha_1: float
    untestable: np.ndarray | None = None

    @property
    def rejected(self) -> np.ndarray:
        """Indices of the observations whose test rejects, worst first."""
        bad = np.flatnonzero(np.nan_to_num(self.w, nan=0.0) > self.critical_w)
        return bad[np.argsort(-self.w[bad])]

    def rows(self) -> list[list[Any]]:
        """One row per observation: line, photo, residuals A, B (mm, px), redundancy A, B, w, rejected."""
        out = []
        for k in range(len(self.labels)):
            out.append([self.line_ids[k], self.photo_ids[k], *self.residuals_mm[k], *self.residuals_px[k],
                        *self.redundancy[k], self.w[k], bool(self.w[k] > self.critical_w)])
        return out

    #: header of :meth:`rows`
    HEADER = ("line", "photo", "v_a_mm", "v_b_mm", "v_a_px", "v_b_px", "redundancy_a", "redundancy_b",
              "w", "rejected")


def line_tests(result: Any, *, level: float | None = 0.001, power: float = 0.80,
               pixel_mm: float | None = None) -> LineTests:
    """Residuals, redundancy numbers and 2-D group tests of the line observations of *result*.

    Parameters
    ----------
    result : BundleResult
        Of a problem with ``lines``, adjusted with ``precision`` ``all`` or ``photos``.
    level : float or None
        alpha_1 of the B-method; None: the family-wise level of
        :func:`lidarcat.bundle.redundancy.family_alpha` over the line tests.
    power : float
    pixel_mm : float, optional
        Pixel size (mm) for the residuals in pixels; default: the observations' own
        ``LineControl.pixel_mm`` (NaN where unknown).

    Raises
    ------
    DatumError
        The result has no line observations or no photo covariances.
    """
    p = result.problem
    if getattr(p, "lines", None) is None:
        raise DatumError("the adjusted problem has no line observations")
    L = p.lines
    if not np.isfinite(result.eo_cov).all():
        raise DatumError("line tests need the photos' covariances: adjust with precision 'all' or 'photos'")
    T = line_terms(L, result.eo_params, p.focal_length_mm)
    C = np.asarray(result.eo_cov)[L.photo_index] / result.variance_factor          # cofactors
    qvv = T.cov - T.A @ C @ np.transpose(T.A, (0, 2, 1))
    red, lam_min = symmetric_redundancy(qvv, T.P)
    e = -T.r
    m = len(e)
    testable = lam_min > MIN_REDUNDANCY
    why = np.array([""] * m, dtype=object)
    for k in np.flatnonzero(~testable):
        why[k] = (f"smallest redundancy eigenvalue {lam_min[k]:.2g} < {MIN_REDUNDANCY:g}: the orientation of "
                  f"photo {p.photo_ids[L.photo_index[k]]} rests on this observation")
    w = np.full(m, np.nan)
    if testable.any():
        w[testable] = np.sqrt(np.einsum("ki,kij,kj->k", e[testable], np.linalg.inv(qvv[testable]), e[testable]))
    with np.errstate(invalid="ignore", divide="ignore"):
        wc = e / np.sqrt(np.diagonal(qvv, axis1=1, axis2=2))
    alpha = family_alpha({2: max(m, 1)}, power=power) if level is None else level
    crit = math.sqrt(critical_values(alpha, power, 2)[1])
    px = T.r / (L.pixel_mm[:, None] if pixel_mm is None else pixel_mm)
    return LineTests(
        labels=frozen_array(L.observation_labels(p.photo_ids), dtype=object),
        line_ids=frozen_array(L.line_ids[L.line_index], dtype=object),
        photo_ids=frozen_array(np.asarray(p.photo_ids)[L.photo_index], dtype=object),
        residuals_mm=frozen_array(T.r), residuals_px=frozen_array(px),
        sd_mm=frozen_array(np.sqrt(np.diagonal(T.cov, axis1=1, axis2=2))),
        redundancy=frozen_array(red), w=frozen_array(w), w_components=frozen_array(wc),
        critical_w=crit, alpha_1=alpha, untestable=frozen_array(why, dtype=object))


#: an observation whose smallest redundancy eigenvalue is below this is not tested
MIN_REDUNDANCY = 1e-3


def symmetric_redundancy(qvv: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(diag R (m, 2), smallest eigenvalue of R (m,))`` of ``R = P^{1/2} Q_vv P^{1/2}`` per observation.

    *qvv*, *P* (m, 2, 2): residual cofactors and weights.  The eigenvalues are clipped to [0, 1]
    (rounding) before the diagonal is formed, so each number is in [0, 1] and the pair sums to
    ``tr(Q_vv P)`` (module docstring).
    """
    m = len(qvv)
    if not m:
        return np.zeros((0, 2)), np.zeros(0)
    lp, vp = np.linalg.eigh(P)
    half = vp @ (np.sqrt(np.clip(lp, 0.0, None))[:, :, None] * np.transpose(vp, (0, 2, 1)))
    R = half @ qvv @ half
    R = 0.5 * (R + np.transpose(R, (0, 2, 1)))
    lr, vr = np.linalg.eigh(R)
    lr = np.clip(lr, 0.0, 1.0)
    diag = np.einsum("kij,kj->ki", vr**2, lr)
    return diag, lr[:, 0]


@dataclasses.dataclass(frozen=True, eq=False)
class LineSnooping:
    """Outcome of :func:`snoop_lines`: the final adjustment, its line tests and the removed
    line observations (labels, in the order found, with their w)."""

    result: Any
    tests: LineTests
    removed: tuple[str, ...]
    removed_w: tuple[float, ...]


def snoop_lines(result: Any, *, level: float | None = 0.001, power: float = 0.80, max_removed: int = 10,
                adjust_kwargs: dict | None = None) -> LineSnooping:
    """Data snooping over the line observations: remove the worst rejected one, re-adjust, repeat.

    Starts from *result* (its solution as the approximations of each re-adjustment); stops when no
    line test rejects or after *max_removed* removals.  Image points and constraints are not
    tested here: :func:`lidarcat.bundle.reliability.snoop` tests the line observations together
    with them in one worst-first loop (what ``lidarcat adjust`` runs); this is the line group
    alone, at a fixed level.
    """
    kw = {"precision": "photos", **(adjust_kwargs or {})}
    res = result
    removed, removed_w = [], []
    tests = line_tests(res, level=level, power=power)
    while len(tests.rejected) and len(removed) < max_removed:
        k = int(tests.rejected[0])
        removed.append(str(tests.labels[k]))
        removed_w.append(float(tests.w[k]))
        p = res.problem
        keep = np.ones(len(p.lines.line_index), dtype=bool)
        keep[k] = False
        nxt = dataclasses.replace(p, lines=p.lines.select(keep))
        res = adjust(nxt, initial=(res.eo_params, res.points_m), **kw)
        tests = line_tests(res, level=level, power=power)
    return LineSnooping(result=res, tests=tests, removed=tuple(removed), removed_w=tuple(removed_w))
