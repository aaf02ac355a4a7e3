r"""Variance components: one variance factor per observation group, estimated from the block itself.

Why
---
A bundle adjustment weighs each observation by ``1 / sd^2``; the sds come from the survey
(``image_sd_mm``, the control sds, the GNSS/INS sds of photos.csv).  When one sd is wrong for a
whole group, the adjustment is still unbiased but every figure derived from the weights is not:
the variance factor, the global chi-square test, the w-tests of data snooping and the sds of the
orientations.  The case that asked for this: automatic tie points matched to 0.07 px weighed with
the 0.3 px of hand-measured GPS targets -- sigma0 0.31-0.37, the chi-square test rejecting every
block, and a wrong tie point had to be 1.5-2 px off before its w-test saw it.

The model
---------
Observations in groups ``g`` (tie-point image coordinates, control-point image coordinates,
control coordinates, GNSS positions, IMU attitudes, image observations of control lines: below),
uncorrelated between groups,

.. math::  D(l) = \sum_g \sigma_g^2 \, Q_g ,

with ``Q_g`` the a priori cofactors (the sds the survey gives, squared) and ``sigma_g^2`` unknown
factors, 1 when the survey's sds are right.  Förstner's (1979) estimator: with ``P = (sum_g Q_g)^-1``
(block diagonal), residuals ``v`` and the redundancy numbers ``r_k = (Q_vv P)_kk`` of every scalar
observation,

.. math::  \hat\sigma_g^2 = \frac{v_g^T P_g v_g}{r_g}, \qquad r_g = \sum_{k \in g} r_k ,

since ``E(v_g^T P_g v_g) = sigma_g^2 r_g`` when the factors are right (``E(v v^T) = Q_vv``, and
``E(v_g^T P_g v_g) = tr(P_g Q_vv,g) = r_g``).  The estimate is unbiased only at the true weights,
so it is iterated: ``Q_g <- sigma_g^2 Q_g``, adjust again, until every ``sigma_g^2`` is 1 within
*tol*.  The fixed point is the iterated MINQUE / best invariant quadratic unbiased estimate, which
for normal observations is the restricted maximum-likelihood estimate (Koch, *Parameter estimation
and hypothesis testing in linear models*, 1999, sec. 3.6); it converges in a few rounds when the
groups are well separated by the geometry.  Because ``sum_g r_g`` is the degrees of freedom, the
global ``sigma0^2 = v^T P v / dof`` of the last round is the redundancy-weighted mean of the
``sigma_g^2`` and therefore ~1: the chi-square test then checks only that the factors have
converged, so the per-group factors -- reported, with the a priori sd each implies -- are the
figures to judge.

Precision.  ``v_g^T P_g v_g / sigma_g^2`` is about ``chi^2(r_g)``, so ``sd(sigma_g^2) ~
sigma_g^2 sqrt(2 / r_g)``: a group of 4 control points (redundancy ~ 5) gives its factor to
+-60 %.  Groups with less than :data:`MIN_REDUNDANCY` are therefore not estimated: their factor
stays 1 (the survey's sds are trusted) and they are reported with ``estimated = False``.  The
weighted orientations (GNSS positions, IMU attitudes) need more, :data:`MIN_DATUM_REDUNDANCY`
(their factor to +-20 %): without a control set they are the datum, and a factor known to +-40 %
would rescale the datum itself (the six-photo matched block: GNSS redundancy 13.8, estimated
factor 0.69 against the true 1, the constraints tightened by 17 %; the four NGI frames: 5.4 and
4.6, not estimated at either threshold; a 24-photo block: about 72, estimated).

Blunders.  A gross error inflates its group's ``v^T P v``, and not only by its own square: the
other rays of its point and the observations of its photos take up part of it.  The estimate
therefore always comes from the adjustment *without* what data snooping named
(:func:`snoop_with_components` runs every round with snooping ``remove``, whatever mode was asked;
a group named but kept -- not removable, or a GNSS/INS group that is the datum -- is left out of
the sums), and the snooping is repeated in every
round with the new weights -- the tighter weights of a precise group let its tests see smaller
errors.  Only then, with the converged factors, does ``report`` mode adjust every observation once
more and name the blunders in it.  Measured on the six-photo matched block with 19 planted gross
matches (3.4-50 px): estimating from the ``report`` adjustment (blunders kept, only their own
squares left out) gave the tie points a factor of 61 (their sds x 7.8) -- the blunders' shares in
their neighbours' residuals -- and four planted matches of 3.4-6.1 px went unnamed; from the
cleaned adjustment the factor is 0.63 (sds x 0.79) and all 19 are named.

Line observations.  The image observations of control lines (:mod:`lidarcat.bundle.lines`) are the
group ``lines``.  Each is a pair of residuals with a full 2 x 2 covariance ``Sigma_r = Sigma_img +
J_L Sigma_AB J_L^T``, the measured edge's part and the 3-D line's (the plane fits'), so its share of
the sums is ``r^T Sigma_r^-1 r`` and ``tr(Q_vv P)``, the redundancy numbers of
:func:`lidarcat.bundle.line_tests.line_tests` (exact: the observation depends on one photo, ``Q_vv =
Sigma_r - A C_i A^T``).  They are not rows of the point statistics (:func:`group_labels`): the group is
summed from the line tests of the result.  Its factor scales the *image* part only -- the edge sds
``sd_mm`` a measurement writes (floors such as ``MeasureParams.line_sd_px`` included) -- and leaves the
3-D line's covariance, propagated from the LiDAR plane fits and shared with the point control, as
given.  The group's model is then ``D(r) = sigma_lines^2 Sigma_img + J_L Sigma_AB J_L^T``, not a
multiple of one cofactor, but the iteration is the same: ``v^T P v`` of the group has expectation
``r_g`` exactly when ``sigma_lines^2`` is right, and each round moves the factor by the ratio, so the
fixed point is that ``sigma_lines^2`` (a little slower to converge, and its sd a little larger than
``sqrt(2 / r_g)``, the smaller the image part's share of ``Sigma_r``).  A line observation its test
rejects (``w`` above the critical value of ``line_tests``) is left out of the sums in the rounds of
:func:`snoop_with_components` (the line snooping of ``lidarcat adjust --snooping remove`` removes it
after them).  Measured on :func:`lidarcat.synthetic.lines.line_block` (edges measured to 4 um,
declared 8 um): the factor comes out 0.25 within its sd (tests/bundle/test_variance_lines.py).

The module is the engine: arrays in, arrays out; :func:`iterate_components` takes the adjustment
to run as a callable, :func:`snoop_with_components` is it with Baarda's data snooping
(:func:`lidarcat.bundle.reliability.snoop`), what ``lidarcat adjust --variance-components`` runs
(:func:`lidarcat.survey.adjustment.adjust_survey_into`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from .problem import BundleProblem
from .redundancy import reliability
from .reliability import snoop
from .result import BundleResult

__all__ = ["GROUPS", "MIN_REDUNDANCY", "MIN_DATUM_REDUNDANCY", "VarianceComponent", "VarianceComponents",
           "group_labels", "line_group", "estimate_components", "scaled_problem", "iterate_components",
           "snoop_with_components"]

log = logging.getLogger(__name__)

#: the observation groups: image coordinates of tie points, image coordinates of control and check
#: points (targets), control coordinates, GNSS positions (X0, Y0, Z0), IMU attitudes (omega, phi, kappa), image
#: observations of control lines (their image part; module docstring, "Line observations")
GROUPS = ("tie", "target", "control", "gnss", "imu", "lines")
#: a group with less redundancy keeps its a priori factor (sd of the estimate ~ sqrt(2 / r) = 45 %)
MIN_REDUNDANCY = 10.0
#: the weighted orientations (GNSS, IMU groups), possibly the datum: estimated with at least this redundancy
#: (sd of the factor sqrt(2 / 50) = 20 %)
MIN_DATUM_REDUNDANCY = 50.0
#: groups that need :data:`MIN_DATUM_REDUNDANCY`
DATUM_GROUPS = ("gnss", "imu")
#: factors are kept within these bounds (an sd scaled by 1/100 .. 100)
FACTOR_BOUNDS = (1e-4, 1e4)


@dataclasses.dataclass(frozen=True)
class VarianceComponent:
    """The variance factor of one observation group.

    Attributes
    ----------
    group : str
        One of :data:`GROUPS`.
    n : int
        Scalar observations in the sums (those of rejected groups left out).
    redundancy : float
        ``r_g``, the sum of their redundancy numbers.
    vtpv : float
        ``v_g^T P_g v_g`` with the weights of the adjustment it was estimated from.
    sigma0_sq : float
        ``vtpv / redundancy`` of the last round (~1 when the iteration converged); NaN when empty.
    factor : float
        The variance factor applied to the group's a priori variances (product over the rounds):
        its sds are the survey's times ``sqrt(factor)``.
    estimated : bool
        False: too little redundancy (:data:`MIN_REDUNDANCY`); the factor stays 1.
    """

    group: str
    n: int
    redundancy: float
    vtpv: float
    sigma0_sq: float
    factor: float
    estimated: bool

    @property
    def sd_scale(self) -> float:
        """Factor of the group's a priori sds, ``sqrt(factor)``."""
        return math.sqrt(self.factor)

    @property
    def factor_sd(self) -> float:
        """Approximate sd of the estimated factor, ``factor sqrt(2 / redundancy)`` (``v_g^T P_g v_g`` ~
        ``chi^2(r_g)``); NaN when not estimated."""
        if not self.estimated or not (self.redundancy > 0):
            return math.nan
        return self.factor * math.sqrt(2.0 / self.redundancy)

    def to_dict(self) -> dict[str, Any]:
        def num(v: float) -> float | None:
            return None if not math.isfinite(v) else float(v)

        return {"group": self.group, "n": int(self.n), "redundancy": num(self.redundancy), "vtpv": num(self.vtpv),
                "sigma0_sq": num(self.sigma0_sq), "sigma0": num(math.sqrt(self.sigma0_sq))
                if math.isfinite(self.sigma0_sq) else None, "factor": num(self.factor),
                "sd_scale": num(self.sd_scale), "factor_sd": num(self.factor_sd),
                "estimated": bool(self.estimated)}


@dataclasses.dataclass(frozen=True)
class VarianceComponents:
    """Outcome of :func:`iterate_components`.

    Attributes
    ----------
    components : tuple of VarianceComponent
        One per group present in the problem (order of :data:`GROUPS`).
    rounds : int
        Adjustments run.
    converged : bool
        Every estimated factor's last estimate within *tol* of 1.
    history : tuple of dict
        ``{group: sigma0_sq}`` of every round.
    payload : Any
        What the last call of the adjustment callable returned (its third element).
    """

    components: tuple[VarianceComponent, ...]
    rounds: int
    converged: bool
    history: tuple[dict[str, float], ...]
    payload: Any = None

    def factors(self) -> dict[str, float]:
        return {c.group: c.factor for c in self.components}

    def summary(self) -> dict[str, Any]:
        """The ``variance_components`` entry of summary.json."""
        return {"method": "Förstner (iterated, redundancy numbers)", "rounds": self.rounds,
                "converged": self.converged, "min_redundancy": MIN_REDUNDANCY,
                "min_datum_redundancy": MIN_DATUM_REDUNDANCY,
                "groups": [c.to_dict() for c in self.components],
                "history": [{k: (None if not math.isfinite(v) else round(v, 6)) for k, v in h.items()}
                            for h in self.history]}


def group_labels(problem: BundleProblem) -> np.ndarray:
    """Group index (into :data:`GROUPS`) of every scalar observation, in the row order of
    :class:`lidarcat.bundle.redundancy.Reliability` (image observations, control points, GNSS/INS
    constraints; 6 columns), -1 where there is no observation (free axes, unused columns).  The line
    observations (group ``lines``) are not among these rows: :func:`line_group` sums them.

    Returns
    -------
    (m, 6) int
    """
    p = problem
    n = len(p.photo_index)
    k = len(p.constraint_point_index)
    e = 0 if p.eo_constraint_photo_index is None else len(p.eo_constraint_photo_index)
    lab = np.full((n + k + e, 6), -1, dtype=np.int64)
    role = np.asarray(p.point_role, dtype=str)[p.point_index]
    lab[:n, :2] = np.where(np.isin(role, ("control", "check")), GROUPS.index("target"), GROUPS.index("tie"))[:, None]
    if k:
        lab[n:n + k, :3] = np.where(np.isfinite(p.constraint_sd_m), GROUPS.index("control"), -1)
    if e:
        sd = np.asarray(p.eo_constraint_sd, float)
        ok = np.isfinite(sd) & (sd > 0)
        lab[n + k:, :3] = np.where(ok[:, :3], GROUPS.index("gnss"), -1)
        lab[n + k:, 3:] = np.where(ok[:, 3:], GROUPS.index("imu"), -1)
    return lab


def _normalised_squares(problem: BundleProblem, result: BundleResult) -> np.ndarray:
    """(m, 6) squared residual / sd of every scalar observation (NaN where none)."""
    p = problem
    parts = [np.pad((np.asarray(result.residuals_mm) / p.sd_mm) ** 2, ((0, 0), (0, 4)), constant_values=np.nan)]
    if len(p.constraint_point_index):
        sd = np.asarray(p.constraint_sd_m, float)
        v = np.asarray(result.constraint_residuals_m) / np.where(np.isfinite(sd), sd, np.nan)
        parts.append(np.pad(v ** 2, ((0, 0), (0, 3)), constant_values=np.nan))
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        sd = np.asarray(p.eo_constraint_sd, float)
        v = np.asarray(result.eo_constraint_residuals) / np.where(np.isfinite(sd) & (sd > 0), sd, np.nan)
        parts.append(v ** 2)
    return np.concatenate(parts)


def line_group(result: BundleResult, *, reject: bool = False) -> tuple[int, float, float] | None:
    """The line observations' share of the sums: ``(n, r_g, v_g^T P_g v_g)`` (module docstring, "Line
    observations").

    Parameters
    ----------
    result : BundleResult
        Its problem's ``lines`` (their sds the weights).
    reject : bool
        Leave out the observations whose 2-D test rejects (``w`` above the critical value of
        :func:`lidarcat.bundle.line_tests.line_tests`, alpha_1 0.001).

    Returns
    -------
    (int, float, float) or None
        Scalar observations summed (2 per line observation), the sum of their redundancy numbers
        (NaN when the result has no photo covariances: adjusted with ``precision`` ``none``) and of
        ``r^T Sigma_r^-1 r``; None when the problem has no line observations.
    """
    # line_tests imports solve: kept out of the module's imports
    from .line_tests import line_tests
    from .lines import line_terms

    L = getattr(result.problem, "lines", None)
    if L is None or not len(L.line_index):
        return None
    T = line_terms(L, result.eo_params, result.problem.focal_length_mm, jacobians=False)
    sq = np.einsum("ki,kij,kj->k", T.r, T.P, T.r)
    if not np.isfinite(np.asarray(result.eo_cov)).all():
        return 2 * len(sq), math.nan, float(sq.sum())
    t = line_tests(result)
    use = np.isfinite(t.redundancy).all(axis=1) & np.isfinite(sq)
    if reject:
        use &= ~(np.nan_to_num(t.w, nan=0.0) > t.critical_w)
    return 2 * int(use.sum()), float(t.redundancy[use].sum()), float(sq[use].sum())


def estimate_components(result: BundleResult, redundancy: np.ndarray, *, exclude: np.ndarray | None = None,
                        factors: dict[str, float] | None = None,
                        min_redundancy: float = MIN_REDUNDANCY,
                        reject_lines: bool = False) -> tuple[VarianceComponent, ...]:
    """One Förstner estimate ``sigma_g^2 = v_g^T P_g v_g / r_g`` per group (module docstring).

    Parameters
    ----------
    result : BundleResult
        A converged adjustment (its problem's sds are the weights P).
    redundancy : (m, 6) float
        Redundancy numbers of *result* in the row order of :func:`group_labels`
        (:attr:`lidarcat.bundle.redundancy.Reliability.redundancy`).
    exclude : (m,) bool, optional
        Rows left out of the sums (groups rejected by data snooping but kept in the adjustment).
    factors : dict, optional
        The factors already applied to the group's sds (reported as the component's ``factor``
        times the new estimate); default 1.
    min_redundancy : float
        Groups with less are not estimated (``estimated=False``, factor unchanged); the GNSS and IMU
        groups need at least :data:`MIN_DATUM_REDUNDANCY` as well.
    reject_lines : bool
        Leave the line observations whose test rejects out of the ``lines`` sums (:func:`line_group`).

    Returns
    -------
    tuple of VarianceComponent
        Groups present in the problem, in :data:`GROUPS` order; ``factor`` is the new factor
        (old factor times the estimate, within :data:`FACTOR_BOUNDS`) for estimated groups.
    """
    p = result.problem
    lab = group_labels(p)
    red = np.asarray(redundancy, float)
    if red.ndim == 2 and len(red) > len(lab):     # Reliability's line rows follow: line_group sums those
        red = red[:len(lab)]
        exclude = None if exclude is None else np.asarray(exclude, bool)[:len(lab)]
    red = np.broadcast_to(red, lab.shape)   # (m, 6): Reliability's rows
    sq = _normalised_squares(p, result)
    use = (lab >= 0) & np.isfinite(sq) & np.isfinite(red)
    if exclude is not None:
        use &= ~np.asarray(exclude, bool)[:, None]
    lines = line_group(result, reject=reject_lines)
    out = []
    for g, name in enumerate(GROUPS):
        if name == "lines":
            if lines is None:
                continue
            n_g, r_g, vtpv = lines
        else:
            present = lab == g
            if not present.any():
                continue
            m = use & present
            n_g, r_g, vtpv = int(m.sum()), float(red[m].sum()), float(sq[m].sum())
        s2 = vtpv / r_g if r_g > 0 else math.nan
        old = 1.0 if factors is None else float(factors.get(name, 1.0))
        need = max(min_redundancy, MIN_DATUM_REDUNDANCY) if name in DATUM_GROUPS else min_redundancy
        est = r_g >= need and math.isfinite(s2) and s2 > 0
        new = float(np.clip(old * s2, *FACTOR_BOUNDS)) if est else old
        out.append(VarianceComponent(name, n_g, r_g, vtpv, s2, new, bool(est)))
    return tuple(out)


def scaled_problem(problem: BundleProblem, factors: dict[str, float]) -> BundleProblem:
    """*problem* with the sds of each group multiplied by ``sqrt(factors[group])`` (missing: 1); of the
    line observations the image sds ``lines.sd_mm`` (the 3-D lines' covariance stays)."""
    p = problem
    if not factors or all(v == 1.0 for v in factors.values()):
        return p
    s = {g: math.sqrt(float(factors.get(g, 1.0))) for g in GROUPS}
    lab = group_labels(p)
    n = len(p.photo_index)
    img = np.where(lab[:n, 0] == GROUPS.index("target"), s["target"], s["tie"])
    kw: dict[str, Any] = {"sd_mm": np.asarray(p.sd_mm) * img[:, None]}
    if len(p.constraint_point_index):
        kw["constraint_sd_m"] = np.asarray(p.constraint_sd_m) * s["control"]
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        sd = np.array(p.eo_constraint_sd, float)
        sd[:, :3] *= s["gnss"]
        sd[:, 3:] *= s["imu"]
        kw["eo_constraint_sd"] = sd
    if getattr(p, "lines", None) is not None and s["lines"] != 1.0:
        kw["lines"] = dataclasses.replace(p.lines, sd_mm=np.asarray(p.lines.sd_mm) * s["lines"])
    return dataclasses.replace(p, **kw)


def iterate_components(
    problem: BundleProblem,
    fit: Callable[[BundleProblem], tuple[BundleResult, np.ndarray | None, np.ndarray | None, Any]],
    *,
    max_rounds: int = 8,
    tol: float = 0.03,
    tol_min: float = 0.002,
    min_redundancy: float = MIN_REDUNDANCY,
    factors: dict[str, float] | None = None,
    reject_lines: bool = False,
) -> VarianceComponents:
    """Iterate the variance factors of the groups to their fixed point (module docstring).

    Parameters
    ----------
    problem : BundleProblem
        With the a priori sds.
    fit : callable
        ``fit(problem) -> (result, redundancy, exclude, payload)``: adjust the problem (with
        data snooping, say); *redundancy* (m, 6) of ``result.problem`` in :func:`group_labels`
        order (None: the adjustment failed and the iteration stops), *exclude* (m,) bool rows to
        leave out of the sums or None; *payload* is kept for the caller.
    max_rounds : int
        Adjustments at most.
    tol, tol_min : float
        Converged when every estimated ``|sigma_g^2 - 1|`` is at most a quarter of the estimate's own
        sd ``sqrt(2 / r_g)``, within ``[tol_min, tol]``: a group of 14,000 redundancy converges to
        0.3 % (the global chi-square test of that block accepts sigma0^2 within about +-2.3 %), one
        of 40 to 3 %.
    factors : dict, optional
        Starting factors (default 1).
    reject_lines : bool
        Leave rejected line observations out of the ``lines`` sums (:func:`estimate_components`).

    Returns
    -------
    VarianceComponents
        ``payload`` of the last adjustment, which used the factors reported.
    """
    cur = dict(factors or {})
    history: list[dict[str, float]] = []
    comps: tuple[VarianceComponent, ...] = ()
    payload = None
    converged = False
    rounds = 0
    for rounds in range(1, max_rounds + 1):
        result, red, exclude, payload = fit(scaled_problem(problem, cur))
        if red is None or not result.success:
            log.warning("variance components: round %d did not converge; factors of round %d kept", rounds,
                        rounds - 1)
            break
        est = estimate_components(result, red, exclude=exclude, factors=cur, min_redundancy=min_redundancy,
                                  reject_lines=reject_lines)
        history.append({c.group: c.sigma0_sq for c in est})
        # the factors this adjustment used, with the estimate of this round
        comps = tuple(dataclasses.replace(c, factor=float(cur.get(c.group, 1.0))) for c in est)
        log.info("variance components, round %d: %s", rounds,
                 ", ".join(f"{c.group} {c.sigma0_sq:.3f}" + ("" if c.estimated else " (not estimated)")
                           for c in est))
        if all(abs(c.sigma0_sq - 1.0) <= max(tol_min, min(tol, 0.25 * math.sqrt(2.0 / c.redundancy)))
               for c in est if c.estimated):
            converged = True
            break
        if rounds < max_rounds:
            cur.update({c.group: c.factor for c in est if c.estimated})
    return VarianceComponents(comps, rounds, converged, tuple(history), payload)


def snoop_with_components(problem: BundleProblem, *, mode: str = "remove", **snoop_kw: Any) -> VarianceComponents:
    """Data snooping with the variance factors of the groups estimated (module docstring, "Blunders").

    Every round runs :func:`lidarcat.bundle.reliability.snoop` with ``mode="remove"`` (``"off"`` when
    *mode* is off) at the factors of the round before, and the factors are estimated from the
    adjustment without the observations it named (a blunder kept in the adjustment spreads into the
    residuals of its neighbours and would be taken for the group's noise).  With ``mode="report"``
    one more snooping in ``report`` mode at the converged factors gives the adjustment of every
    observation, its blunders named and kept.

    Parameters
    ----------
    problem : BundleProblem
        With the a priori sds.
    mode : {"off", "report", "remove"}
        The snooping mode of the result (see :func:`lidarcat.bundle.reliability.snoop`).
    **snoop_kw
        Passed to every :func:`lidarcat.bundle.reliability.snoop`.

    Returns
    -------
    VarianceComponents
        ``payload``: the :class:`~lidarcat.bundle.reliability.SnoopingResult` in *mode* at the
        factors reported.
    """
    round_mode = "off" if mode == "off" else "remove"

    def one(prob: BundleProblem):
        sres = snoop(prob, mode=round_mode, **snoop_kw)
        res = sres.result
        if res is None or not res.success:
            return res, None, None, sres
        rel = sres.reliability if sres.reliability is not None else reliability(res)
        kept = {(b.kind, b.photo or "", b.point or "") for b in sres.blunders if not b.removed}
        exclude = None
        if kept:     # named but kept (not removable, or a GNSS/INS group of the datum): out of the sums
            keys = zip(rel.kind.tolist(), [str(x) for x in rel.photo], [str(x) for x in rel.point])
            exclude = np.array([k in kept for k in keys], dtype=bool)
        return res, np.asarray(rel.redundancy), exclude, sres

    vc = iterate_components(problem, one, reject_lines=mode != "off")
    if mode == "report":    # every observation, at the factors of the last round that converged
        vc = dataclasses.replace(vc, payload=snoop(scaled_problem(problem, vc.factors()), mode="report",
                                                   **snoop_kw))
    return vc
