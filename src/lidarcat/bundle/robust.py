r"""A robust start: screening, then iteratively re-weighted least squares with a graduated loss.

Least squares with data snooping needs a converged adjustment to test; a block of automatic
matches with a few gross observations never gets there (a point intersected behind a camera,
a step that a 700-px residual dominates).  :func:`robust_start` runs before any plain
least-squares step:

1. approximate values (:func:`lidarcat.bundle.approx.approximations`: the given GNSS/INS
   orientation, or the planimetric block);
2. :func:`lidarcat.bundle.screening.screen` flags the rays that do not meet the other rays of
   their point at those orientations; they leave the adjustment;
3. least squares on the rest; when that does not converge (``loss="auto"``), or always with a
   loss named, iteratively re-weighted least squares (IRLS).  With the normalised residual of
   an observation ``u = |v / sd| / sqrt(2)`` (v its 2-D residual, the root mean square of the two
   standardised coordinates) the weight is multiplied by ``f(u / c_t)``:

   ==========  ====================================  ======================
   ``cauchy``  ``f(t) = 1 / (1 + t^2)``               c = 2.385 (95 % efficiency)
   ``huber``   ``f(t) = min(1, 1 / |t|)``             c = 1.345
   ``tukey``   ``f(t) = (1 - t^2)^2`` for ``|t| < 1``  c = 4.685
   ==========  ====================================  ======================

   and the scale is *graduated* (graduated non-convexity): ``c_t = c max(s, 2^(G - t))``
   halves from ``2^G`` times the final value, so the first re-weightings are nearly least
   squares (convex, no local minimum to fall into) and the loss only sharpens once the
   orientation has settled; ``s = max(1, 1.4826 median(u))`` is the block's robust scale (the
   MAD; never below the a priori sds).  Each re-weighting runs a few Levenberg-Marquardt
   iterations from the previous estimate (:func:`lidarcat.bundle.adjust`, no covariances);
   the loop ends when ``c_t`` is final and no weight changes by more than 1e-3;
4. observations whose final factor is below :data:`REJECT_BELOW` are rejected; a two-ray
   point loses both rays (no test tells which of the two is wrong).

The observations of line control (``problem.lines``) are re-weighted with the image points:
``u = sqrt(r^T P r / 2)`` of their residual pair (:func:`line_normalised`), the same loss and
scale, the factor applied to the whole weight matrix (:func:`with_line_weights`: the 3-D line's
share of the covariance too, or a line of a few mm could never be weighted down), rejected
below :data:`REJECT_BELOW` (``RobustStart.keep_lines``) and put back like an image point
(:func:`put_back_lines`).  A roof edge measured 60 px off on a block held by 2 m GNSS otherwise
pulled its photo until the re-weighting cut the one correct LiDAR vertex of the block.

Data snooping with the original weights then tests the survivors
(:func:`lidarcat.bundle.reliability.snoop`), and a rejected observation whose residual
against the final solution passes the test of a good observation is put back.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from .approx import approximations
from .problem import BundleProblem, check_datum
from .screening import SCREEN_K, Screening, screen
from .solve import adjust

__all__ = ["RobustStart", "robust_start", "LOSSES", "loss_weight", "REJECT_BELOW", "predicted_errors",
           "start_blunders", "put_back", "START_MODES", "line_normalised", "with_line_weights",
           "line_start_blunders", "put_back_lines"]

log = logging.getLogger(__name__)

#: robust losses and their tuning constants (in units of the normalised residual)
LOSSES: dict[str, float] = {"cauchy": 2.385, "huber": 1.345, "tukey": 4.685}
#: values of the ``start`` switch of :func:`lidarcat.bundle.reliability.snoop`
START_MODES = ("robust", "plain")
#: observations whose final weight factor is below this are rejected after the re-weighting
REJECT_BELOW = 0.01
#: the first scale is 2^GRADUATION times the final one
GRADUATION = 4
#: smallest weight factor kept in a re-weighted adjustment (a regular normal-equation block)
WEIGHT_FLOOR = 1e-6


def loss_weight(loss: str, t: np.ndarray) -> np.ndarray:
    """Weight factor ``f(t)`` of *loss* at the scaled residual *t* (>= 0), (n,).

    >>> loss_weight("cauchy", np.array([0.0, 1.0, 3.0])).tolist()
    [1.0, 0.5, 0.1]
    >>> loss_weight("tukey", np.array([0.0, 0.5, 1.0])).tolist()
    [1.0, 0.5625, 0.0]
    """
    t = np.abs(np.asarray(t, dtype=float))
    if loss == "cauchy":
        return 1.0 / (1.0 + t**2)
    if loss == "huber":
        with np.errstate(divide="ignore"):
            return np.where(t <= 1.0, 1.0, 1.0 / np.maximum(t, 1e-300))
    if loss == "tukey":
        return np.where(t < 1.0, (1.0 - t**2) ** 2, 0.0)
    raise ValueError(f"`loss` must be one of {', '.join(LOSSES)}, got {loss!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class RobustStart:
    """Outcome of :func:`robust_start`.

    Attributes
    ----------
    keep : (n,) bool
        Observations of the problem kept for the least-squares adjustment.
    found_by : (n,) str
        ``screening``, the loss name, or empty (kept).
    reason : (n,) str
        The screening's reason, or ``weight f`` of the re-weighting; ``two-ray point`` for the
        partner of a rejected ray of a point seen on two photos.
    weight : (n,) float
        Final weight factor of the re-weighting (0 for screened observations).
    eo : (P, 6), points_m : (Q, 3)
        The re-weighted estimate (NaN for points with fewer than two kept rays): the warm
        start of the least squares.
    screening : Screening or None
    n_reweightings : int
    scale : float
        The block's robust scale ``s`` at the end.
    converged : bool
        The re-weighting settled (weights stable at the final scale).
    keep_lines : (m,) bool or None
        Observations of line control (``problem.lines``) kept; None when the problem has none.
    line_found_by : (m,) str or None
        The loss name for a line observation the re-weighting rejected, else empty.
    line_weight : (m,) float or None
        Their final weight factors.
    """

    keep: np.ndarray
    found_by: np.ndarray
    reason: np.ndarray
    weight: np.ndarray
    eo: np.ndarray
    points_m: np.ndarray
    screening: Screening | None
    n_reweightings: int
    scale: float
    converged: bool
    keep_lines: np.ndarray | None = None
    line_found_by: np.ndarray | None = None
    line_weight: np.ndarray | None = None

    def __post_init__(self) -> None:
        for f in ("keep", "found_by", "reason", "weight", "eo", "points_m", "keep_lines", "line_found_by",
                  "line_weight"):
            if getattr(self, f) is not None:
                object.__setattr__(self, f, frozen_array(getattr(self, f), dtype=None))

    @property
    def n_rejected(self) -> int:
        """Image and line observations rejected."""
        return int((~self.keep).sum()) + (0 if self.keep_lines is None else int((~self.keep_lines).sum()))


def _reduced(p: BundleProblem, keep: np.ndarray) -> tuple[BundleProblem, np.ndarray]:
    """*p* with the observations *keep* only (points without rays dropped); the kept point positions."""
    has = np.zeros(p.n_points, dtype=bool)
    has[p.point_index[keep]] = True
    new = np.cumsum(has) - 1
    ci = p.constraint_point_index
    con = has[ci]
    sub = dataclasses.replace(
        p, point_ids=p.point_ids[has], photo_index=p.photo_index[keep], point_index=new[p.point_index[keep]],
        xy_mm=p.xy_mm[keep], sd_mm=p.sd_mm[keep], constraint_point_index=new[ci[con]],
        constraint_enh_m=p.constraint_enh_m[con], constraint_sd_m=p.constraint_sd_m[con],
        point_role=p.point_role[has], rays=None if p.rays is None else p.rays.select(keep))
    return sub, np.flatnonzero(has)


def _u(res_mm: np.ndarray, sd_mm: np.ndarray) -> np.ndarray:
    """Normalised residual per observation: RMS of the two standardised coordinates."""
    return np.sqrt(0.5 * np.sum((res_mm / sd_mm) ** 2, axis=1))


def line_normalised(lines: Any, eo: np.ndarray, focal_length_mm: np.ndarray) -> np.ndarray:
    """``r^T P r`` (m,) of every observation of line control *lines* at *eo* (P, 6), with the weights
    of *lines* (its residual pair whitened: the line's counterpart of an image point's
    ``sum (v / sd)^2``); NaN for an end point behind the camera."""
    from .lines import line_terms

    T = line_terms(lines, np.asarray(eo, dtype=float), focal_length_mm, jacobians=False)
    q = np.einsum("ki,kij,kj->k", T.r, T.P, T.r)
    q[np.any(T.u3 >= 0, axis=1)] = np.nan
    return q


def with_line_weights(lines: Any, factor: np.ndarray, floor: float = 0.0) -> Any:
    """*lines* with the weight of every observation multiplied by *factor* (m,) (at least *floor*)."""
    return dataclasses.replace(lines, weight=np.asarray(lines.weight) * np.maximum(factor, floor))


def _two_ray_partners(p: BundleProblem, keep: np.ndarray, rejected: np.ndarray) -> np.ndarray:
    """Kept observations left alone on their point (a free point with one ray) after *rejected*."""
    left = np.bincount(p.point_index[keep & ~rejected], minlength=p.n_points)
    full = np.zeros(p.n_points, dtype=bool)
    fc = np.isfinite(p.constraint_sd_m).all(axis=1)
    full[p.constraint_point_index[fc]] = True
    return keep & ~rejected & (left[p.point_index] == 1) & ~full[p.point_index]


def robust_start(
    problem: BundleProblem,
    *,
    initial: tuple[np.ndarray, np.ndarray | None] | None = None,
    screening: bool = True,
    k: float = SCREEN_K,
    loss: str = "auto",
    max_reweightings: int = 20,
    iterations_per_weighting: int = 5,
    **adjust_kwargs: Any,
) -> RobustStart:
    """Screen, then re-weight: the observations a least-squares adjustment can start from.

    Parameters
    ----------
    problem : BundleProblem
    initial : (eo (P, 6), points or None), optional
        Approximate orientations; default :func:`lidarcat.bundle.approx.approximations`.
    screening : bool
        Run :func:`lidarcat.bundle.screening.screen` first.
    k : float
        Its threshold (sds of a ray).
    loss : {"auto", "cauchy", "huber", "tukey", "none"}
        Loss of the re-weighting; ``none`` skips it; ``auto`` (the default) re-weights with
        ``cauchy`` only when least squares on the screened observations does not converge
        (a block whose gross errors the screening took costs one adjustment, not a dozen).
    max_reweightings, iterations_per_weighting : int
        Limits of the IRLS loop (re-weightings, Levenberg-Marquardt iterations in each).
    **adjust_kwargs
        Passed to :func:`lidarcat.bundle.adjust` (``tol_m``, ``tol_rad``, ``solver``).

    Returns
    -------
    RobustStart

    Raises
    ------
    DatumError
        From the approximations, or when the screening leaves a photo with fewer than 3
        points (the message names it).
    """
    if loss not in ("none", "auto") and loss not in LOSSES:
        raise ValueError(f"`loss` must be one of none, auto, {', '.join(LOSSES)}, got {loss!r}")
    p = problem
    n = len(p.photo_index)
    check_datum(p)   # a block short of points before any screening: the datum check's own message
    if initial is None:
        eo, _ = approximations(p)
    else:
        eo = np.array(initial[0], dtype=float).reshape(p.n_photos, 6)
    keep = np.ones(n, dtype=bool)
    found = np.full(n, "", dtype=object)
    reason = np.full(n, "", dtype=object)
    scr = None
    if screening:
        scr = screen(p, eo, k=k)
        keep &= ~scr.flagged
        found[scr.flagged] = "screening"
        reason[scr.flagged] = scr.reason[scr.flagged]
        if scr.n_flagged:
            log.info("screening: %d observation(s) flagged", scr.n_flagged)
    weight = keep.astype(float)
    sub, kept_pts = _reduced(p, keep)
    from .approx import intersect_points
    from ..errors import DatumError

    per_photo = np.bincount(sub.photo_index, minlength=p.n_photos)
    if np.any(per_photo < 3):
        i = int(np.flatnonzero(per_photo < 3)[0])
        raise DatumError(f"photo {p.photo_ids[i]!r}: {per_photo[i]} point(s) left after screening the tie "
                         f"points ({int((~keep & (p.photo_index == i)).sum())} flagged); its orientation "
                         "cannot be determined: check its approximate orientation or its matches")
    pts = intersect_points(sub, eo)
    scale = 1.0
    n_rw = 0
    if loss == "auto":      # re-weight only when least squares on the screened block does not converge
        kw = {k2: v for k2, v in adjust_kwargs.items() if k2 in ("tol_m", "tol_rad", "tol_vtpv", "solver")}
        r = adjust(sub, initial=(eo, pts), check=False, precision="none", **kw)
        n_rw = 1
        if r.success:
            eo, pts, loss = np.array(r.eo_params), np.array(r.points_m), "none"
        else:
            loss = "cauchy"
            log.info("robust start: least squares on the screened block %s; re-weighting (cauchy)", r.status)
    converged = loss == "none"
    L = getattr(p, "lines", None)
    m = 0 if L is None else len(L.line_index)
    w_line = np.ones(m)
    line_found = np.full(m, "", dtype=object)
    if loss != "none":
        c = LOSSES[loss]
        w_sub = np.ones(len(sub.photo_index))
        kwargs = {k2: v for k2, v in adjust_kwargs.items() if k2 in ("tol_m", "tol_rad", "tol_vtpv", "solver")}
        for t in range(max_reweightings):
            grad = 2.0 ** max(GRADUATION - t, 0)
            cur = dataclasses.replace(sub, sd_mm=sub.sd_mm / np.sqrt(np.maximum(w_sub, WEIGHT_FLOOR))[:, None])
            if m:       # the line observations re-weighted with the image points (their 2-D u the same way)
                cur = dataclasses.replace(cur, lines=with_line_weights(L, w_line, WEIGHT_FLOOR))
            r = adjust(cur, initial=(eo, pts), max_iter=iterations_per_weighting, check=False, precision="none",
                       **kwargs)
            n_rw += 1
            if math.isfinite(r.vtpv):
                eo, pts = np.array(r.eo_params), np.array(r.points_m)
            u = _u(np.asarray(r.residuals_mm), sub.sd_mm)
            u_l = np.sqrt(0.5 * line_normalised(L, eo, p.focal_length_mm)) if m else np.zeros(0)
            u_l = np.where(np.isfinite(u_l), u_l, np.inf)
            scale = max(1.0, 1.4826 * float(np.median(np.r_[u, u_l])))
            new = loss_weight(loss, u / (c * max(scale, grad)))
            new_l = loss_weight(loss, u_l / (c * max(scale, grad)))
            change = float(np.max(np.abs(np.r_[new - w_sub, new_l - w_line]), initial=0.0))
            w_sub, w_line = new, new_l
            log.debug("robust %s: re-weighting %d, scale %.3g, graduation %g, max change %.3g", loss, t + 1,
                      scale, grad, change)
            if grad <= 1.0 and change < 1e-3 and r.status in ("converged", "max_iterations"):
                converged = True
                break
        idx = np.flatnonzero(keep)
        weight[idx] = w_sub
        low = np.zeros(n, dtype=bool)
        low[idx] = w_sub < REJECT_BELOW
        if low.any():
            keep &= ~low
            found[low] = loss
            reason[low] = [f"weight {v:.1e}" for v in weight[low]]
            log.info("robust %s: %d observation(s) weighted below %g", loss, int(low.sum()), REJECT_BELOW)
        low_l = w_line < REJECT_BELOW
        if low_l.any():
            line_found[low_l] = loss
            log.info("robust %s: %d line observation(s) weighted below %g", loss, int(low_l.sum()), REJECT_BELOW)
        pts_full = np.full((p.n_points, 3), np.nan)
        pts_full[kept_pts] = pts
    else:
        pts_full = np.full((p.n_points, 3), np.nan)
        pts_full[kept_pts] = pts
    # a free point left with one ray: that ray goes too (it cannot be tested)
    lone = _two_ray_partners(p, np.ones(n, dtype=bool), ~keep)
    if lone.any():
        keep &= ~lone
        for i in np.flatnonzero(lone):
            others = np.flatnonzero(~keep & (p.point_index == p.point_index[i]) & (found != ""))
            found[i] = found[others[0]] if len(others) else "screening"
            reason[i] = "its other ray rejected"
    has = np.zeros(p.n_points, dtype=bool)
    has[p.point_index[keep]] = True
    pts_full[~has] = np.nan
    return RobustStart(keep=keep, found_by=found, reason=reason, weight=weight, eo=eo, points_m=pts_full,
                       screening=scr, n_reweightings=n_rw, scale=scale, converged=converged,
                       keep_lines=None if L is None else w_line >= REJECT_BELOW,
                       line_found_by=None if L is None else line_found, line_weight=None if L is None else w_line)


def predicted_errors(problem: BundleProblem, eo: np.ndarray, point_ids: np.ndarray, points_m: np.ndarray,
                     which: np.ndarray) -> np.ndarray:
    """Observed minus predicted photo coordinates (len(which), 2), mm, of the observations *which*
    of *problem* at an adjusted solution (orientations *eo* (P, 6), points *point_ids* at *points_m*);
    a point not in the solution is intersected from all its rays at *eo* (a two-ray point: half its
    y-parallax on each ray)."""
    from ..geometry.collinearity import project
    from .screening import intersect_rays

    p = problem
    which = np.asarray(which, dtype=np.int64)
    pos = {str(q): i for i, q in enumerate(point_ids)}
    X = np.full((p.n_points, 3), np.nan)
    inside = np.array([str(q) in pos for q in p.point_ids])
    X[inside] = np.asarray(points_m)[[pos[str(q)] for q in p.point_ids[inside]]]
    need = np.zeros(p.n_points, dtype=bool)
    need[p.point_index[which]] = True
    need &= ~inside
    if need.any():
        X[need] = intersect_rays(p, eo, active=need[p.point_index])[need]
    ei, pj = p.photo_index[which], p.point_index[which]
    xy, u3 = project(np.asarray(eo, dtype=float), X[pj], p.focal_length_mm[ei], ei)
    e = p.xy_mm[which] - xy
    e[~np.isfinite(xy).all(axis=1) | (u3 >= 0)] = np.nan
    return e


def start_blunders(problem: BundleProblem, rs: RobustStart, eo: np.ndarray, point_ids: np.ndarray,
                   points_m: np.ndarray, w_critical: float, *, removed: bool = True, note: str = "") -> list:
    """:class:`lidarcat.bundle.redundancy.Blunder` records of the observations *rs* rejected, judged at
    an adjusted solution: ``w = sqrt(sum (e / sd)^2)`` of the predicted error e
    (:func:`predicted_errors`), ``redundancy`` NaN (the observation is not in the adjustment)."""
    from .redundancy import Blunder

    p = problem
    rej = np.flatnonzero(~rs.keep)
    if not len(rej):
        return []
    e = predicted_errors(p, eo, point_ids, points_m, rej)
    w = np.sqrt(np.sum((e / p.sd_mm[rej]) ** 2, axis=1))
    out = []
    for i, k in enumerate(rej):
        why = str(rs.reason[k])
        two = np.sum(p.point_index == p.point_index[k]) == 2
        text = why + ("; a point on two photos: its two rays cannot be told apart, both rejected"
                      if two else "")
        out.append(Blunder(kind="image", photo=str(p.photo_ids[p.photo_index[k]]),
                           point=str(p.point_ids[p.point_index[k]]),
                           w=float(w[i]) if np.isfinite(w[i]) else math.nan, w_critical=float(w_critical),
                           redundancy=math.nan, estimated_error=tuple(float(v) for v in e[i]),
                           removed=removed, found_by=str(rs.found_by[k]), iteration=0,
                           note="; ".join(x for x in (text, note) if x)))
    return out


def line_start_blunders(problem: BundleProblem, rs: RobustStart, eo: np.ndarray, w_critical: float, *,
                        removed: bool = True, note: str = "") -> list:
    """:class:`lidarcat.bundle.redundancy.Blunder` records (kind ``line``) of the line observations *rs*
    rejected, judged at the adjusted orientations *eo*: ``w = sqrt(r^T P r)`` of their residual pair,
    the estimated error ``-r`` (mm, at the end points A, B), redundancy NaN."""
    from .lines import line_terms
    from .redundancy import Blunder

    p = problem
    if rs.keep_lines is None or p.lines is None or rs.keep_lines.all():
        return []
    L = p.lines
    rej = np.flatnonzero(~rs.keep_lines)
    T = line_terms(L.select(rej), np.asarray(eo, dtype=float), p.focal_length_mm, jacobians=False)
    w = np.sqrt(np.einsum("ki,kij,kj->k", T.r, T.P, T.r))
    out = []
    for i, k in enumerate(rej):
        out.append(Blunder(kind="line", photo=str(p.photo_ids[L.photo_index[k]]),
                           point=str(L.line_ids[L.line_index[k]]), w=float(w[i]) if np.isfinite(w[i]) else math.nan, w_critical=float(w_critical),
                           redundancy=math.nan, estimated_error=tuple(float(v) for v in -T.r[i]),
                           removed=removed, found_by=str(rs.line_found_by[k]), iteration=0,
                           note="; ".join(x for x in (f"weight {rs.line_weight[k]:.1e}", note) if x)))
    return out


def put_back_lines(problem: BundleProblem, rejected: np.ndarray, eo: np.ndarray, w_critical: float) -> np.ndarray:
    """Of the line observations *rejected* (m,) bool, those whose residual pair at the orientations
    *eo* passes the test of a good observation (``sqrt(r^T P r) < w_critical``): the re-weighting
    judged them at a worse orientation.  Returns an (m,) bool mask."""
    out = np.zeros(len(rejected), dtype=bool)
    rej = np.flatnonzero(rejected)
    if not len(rej):
        return out
    q = line_normalised(problem.lines.select(rej), eo, problem.focal_length_mm)
    out[rej] = np.isfinite(q) & (np.sqrt(np.nan_to_num(q, nan=np.inf)) < w_critical)
    return out


def put_back(problem: BundleProblem, rejected: np.ndarray, eo: np.ndarray, point_ids: np.ndarray,
             points_m: np.ndarray, w_critical: float) -> np.ndarray:
    """Of the observations *rejected* (n,) bool, those whose predicted error at the solution passes the
    test of a good observation (``w < w_critical``; for a two-ray point both rays must pass): the
    screening or the re-weighting judged them at a worse orientation.  Returns an (n,) bool mask."""
    p = problem
    rej = np.flatnonzero(rejected)
    out = np.zeros(len(p.photo_index), dtype=bool)
    if not len(rej):
        return out
    e = predicted_errors(p, eo, point_ids, points_m, rej)
    w = np.sqrt(np.sum((e / p.sd_mm[rej]) ** 2, axis=1))
    ok = np.isfinite(w) & (w < w_critical)
    out[rej[ok]] = True
    # a point must come back with at least two rays (or keep its others)
    kept = ~rejected | out
    n_rays = np.bincount(p.point_index[kept], minlength=p.n_points)
    out &= n_rays[p.point_index] >= 2
    return out
