r"""Reliability of the adjustment: redundancy numbers, data snooping, robust re-weighting.

Gross errors (a mis-measured image point, a swapped point id, a control point
with a wrong digit) are found by testing every observation against the model
(Baarda 1968; Teunissen, *Testing theory*, 2006).  Notation: observations
``l`` with cofactor ``Q_ll`` (``sigma0^2 = 1`` a priori, so ``P = Q_ll^-1``),
design ``A``, ``Q_xx = N^-1``; residuals ``e = l - A x`` (observed minus
adjusted; the result files hold ``v = -e``).

Cofactor of the residuals, blockwise
------------------------------------
``Q_vv = Q_ll - A Q_xx A^T``.  Only its diagonal blocks are needed, one per
observation group ``a``:

* image point (photo i, point j), 2 x 2:  ``Q_ll,a - A_a S_a A_a^T`` with
  ``A_a = [A_eo (2x6), A_pt (2x3)]`` the collinearity Jacobian and ``S_a`` the
  9 x 9 covariance of ``[eo_i, X_j]``
  (:func:`lidarcat.bundle.precision.observation_blocks`: the selected inverse of
  the sparse factorisation, never a dense inverse);
* control point j (its constrained axes, up to 3 x 3):  ``diag(sd^2) - Cov(X_j)``;
* GNSS/INS constraint of photo i (its constrained parameters, up to 6 x 6):
  ``diag(sd^2) - Cov(eo_i)``.

The redundancy number of a scalar observation is ``r_k = (Q_vv P)_kk =
q_vv,kk / sd_k^2`` (0 <= r <= 1; their sum over all observations and
constraints is the degrees of freedom): the share of an error in ``l_k`` that
shows in its own residual.  ``r ~ 0`` means an error cannot be seen at all
(e.g. a control axis no image ray checks).

The test: multi-dimensional, per observation group
--------------------------------------------------
A 2-D image observation and a 3-D control point are each *one* measurement
event: a mis-identified point or a wrong coordinate moves the whole group in an
unknown direction.  The alternative hypothesis is therefore a bias ``nabla``
(q-vector) in group ``a`` only, ``H_a: E(l) = A x + C_a nabla``, and the
uniformly most powerful invariant test statistic is (P block diagonal)

.. math::  T_a = e_a^T Q_{vv,a}^{-1} e_a \sim \chi^2(q, \lambda),
           \qquad \lambda = \nabla^T P_a Q_{vv,a} P_a \nabla

(for q = 1 this is ``w^2``, Baarda's w-test).  We report ``w = sqrt(T_a)`` and
its critical value ``sqrt(chi2_{1-alpha_q}(q))``, and the per-component
``w_k = e_k / sqrt(q_vv,kk)`` for orientation.  The per-component test alone
was not used because it tests a bias along one axis only: the bias of a
swapped point has both components and would be split between two tests of
lower power.

Levels: Baarda's B-method.  A one-dimensional level ``alpha_1`` and the power
``beta0`` (default 0.80) fix the noncentrality ``lambda0`` with
``P(chi2(1, lambda0) > chi2_{1-alpha_1}(1)) = beta0`` (``lambda0 = 17.07`` for
alpha_1 = 0.001); each q-dimensional test uses the ``alpha_q`` with the same
power at the same ``lambda0`` (for alpha_1 = 0.001: ``alpha_2 = 0.0028``,
``alpha_3 = 0.0055``, ``alpha_6 = 0.0177``, critical ``w`` 3.29, 3.42, 3.55 and
3.92), so every test detects the same size of error with the same probability.

Levels of a family of tests.  A block without blunders and ``n_q`` tests of
dimension q, each at ``alpha_q``, has on average ``sum n_q alpha_q`` rejections
(0.28 % of its image points at alpha_1 = 0.001: 9 on the clean 200-photo demo
block, 201 on a clean block of 85,834 observations).  So by default ``alpha_1`` is chosen from the
number of tests (:func:`family_alpha`): the probability that *any* test of a
clean block rejects is ``alpha_F`` (``family_level``, 0.05),

.. math::  1 - \prod_q (1 - \alpha_q(\alpha_1))^{n_q} = \alpha_F

(Sidak; the tests of one block are positively correlated, which makes the true
family-wise rate smaller: 3.7 % measured over 350 simulated clean copies of the
thesis block).  This is
Bonferroni's ``alpha_F / n`` for large n.  The B-method then fixes ``lambda0`` from
that ``alpha_1``, so the minimal detectable bias grows slowly with the block:
``lambda0`` 22.3 for the thesis block (159 tests, alpha_1 = 1.04e-4, critical w
4.00 for an image point), 30.2 for the 5,086 tests of the 200-photo demo, 36.8
for a 1,000-photo block (alpha_1 = 1.73e-7; MDB x 1.14, 1.33, 1.47 against
alpha_1 = 0.001).  The level is computed once, from
the tests of the first adjustment, and kept for every re-adjustment.

Estimated error, internal and external reliability
--------------------------------------------------
The least-squares estimate of the bias is ``nabla_a = Q_ll,a Q_vv,a^-1 e_a``
(with one blunder ``e_a = Q_vv,a P_a nabla``, so it recovers ``nabla`` exactly).
The minimal detectable bias (internal reliability) along component k is

.. math::  \mathrm{MDB}_k = \sqrt{\lambda_0 / (P Q_{vv} P)_{kk}}
                          = \sigma_k \sqrt{\lambda_0 / r_k}

and its effect on the unknowns (external reliability) is ``dx = Q_xx A_a^T
P_a nabla``.  Its size for any function of the unknowns is bounded by the
bias-to-noise ratio ``sqrt(lambda_x) = sqrt(lambda0 (1 - r_k) / r_k)`` (in
units of that function's own sd); the shift of the orientation of the photo
itself (image observation, GNSS/INS constraint) or of the photos that see the
point (control), in metres and radians, comes from the same 9 x 9 blocks.

Data snooping and robust re-weighting
-------------------------------------
:func:`snoop` adjusts, tests, removes the single group with the largest test
ratio ``T_a / chi2_{1-alpha_q}(q)`` when it exceeds 1, re-adjusts from the
previous solution, and repeats (Baarda: one rejection per iteration, because
one blunder raises the w of its neighbours).  On large blocks a round also
removes every other rejected group that is *separate* from those already picked
(:func:`_round_picks`: no photo that sees its point is, or shares a point with,
such a photo of a picked group), because a blunder raises the tests of the
groups that share its photo, its point or a neighbouring photo, not of groups
far away; on the thesis block no two groups are separate, so it is the classic
one per round.  A backward step then puts back a
rejected observation when every test passes with it, or exchanges it for
another ray of its point when that lowers v'Pv (the tests of the rays of one
point are correlated), and snooping resumes.  ``robust="danish"`` or
``"huber"`` first runs iteratively re-weighted least squares: the weight of
group a is multiplied by ``f(w_a / c_a)`` with ``c_a`` its critical value,
``f(u) = 1`` for ``u <= 1`` and ``exp(1 - u^2)`` (Danish type) or ``1 / u``
(Huber) beyond; groups whose factor falls below 0.1 are removed together and
snooping cleans what is left, so the final result and its covariance come from
the original weights.  All tests use the a priori variance factor (sigma0 = 1:
the sigmas are trusted, which the global chi-square test checks).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import optimize, stats

from ..geometry.collinearity import project_with_jacobians
from ..errors import DatumError
from .linear import SingularSystem
from .model import NormalSystem
from .precision import observation_blocks
from .problem import BundleProblem
from .result import BundleResult
from .solve import adjust

__all__ = ["Blunder", "Reliability", "SnoopingResult", "SNOOPING_MODES", "ROBUST_METHODS",
           "FAMILY_LEVEL", "noncentrality", "critical_values", "family_alpha", "reliability", "snoop"]

log = logging.getLogger(__name__)

#: values of the ``snooping`` switch
SNOOPING_MODES = ("off", "report", "remove")
#: values of the ``robust`` switch
ROBUST_METHODS = ("none", "danish", "huber")
#: names of the components of each kind of observation group, and their units
COMPONENTS = {"image": ("x", "y"), "control": ("E", "N", "h"),
              "eo": ("X0", "Y0", "Z0", "omega", "phi", "kappa")}
#: a group whose smallest redundancy is below this cannot be tested (its error would not show)
MIN_REDUNDANCY = 1e-3
#: IRLS: groups whose weight factor ends below this are removed before snooping
ROBUST_CUT = 0.1
#: default family-wise level: probability that a block without blunders has any test rejecting
FAMILY_LEVEL = 0.05
#: snooping stops (blunders remain) after this share of the tested groups is rejected, or 100
MAX_REJECTED_SHARE = 0.05
#: IRLS: stop when the set of groups below ROBUST_CUT is the same after this many re-weightings
ROBUST_STABLE = 2
#: IRLS: smallest weight factor (sigma x 100: a point keeps a regular normal-equation block)
ROBUST_FLOOR = 1e-4


# ---------------------------------------------------------------------------
# levels of the B-method
# ---------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def noncentrality(alpha: float = 0.001, power: float = 0.80) -> float:
    """lambda0 of the one-dimensional w-test: P(chi2(1, lambda0) > chi2_{1-alpha}(1)) = power.

    >>> round(noncentrality(0.001, 0.80), 2)
    17.07
    """
    _check_level(alpha, power)
    k = stats.chi2.isf(alpha, 1)
    return float(optimize.brentq(lambda lam: stats.ncx2.sf(k, 1, lam) - power, 1e-9, 1e4, xtol=1e-12))


@functools.lru_cache(maxsize=64)
def critical_values(alpha: float = 0.001, power: float = 0.80, q: int = 1) -> tuple[float, float]:
    """``(alpha_q, chi2_{1-alpha_q}(q))`` of the q-dimensional test with the power of the 1-D one.

    Baarda's B-method: the same noncentrality :func:`noncentrality` is detected
    with the same *power* whatever the dimension.

    >>> a, k = critical_values(0.001, 0.80, 1)
    >>> a, round(k, 3)
    (0.001, 10.828)
    >>> round(critical_values(0.001, 0.80, 2)[0], 4)
    0.0028
    """
    lam = noncentrality(alpha, power)
    if q == 1:
        return alpha, float(stats.chi2.isf(alpha, 1))

    def gap(log_a: float) -> float:
        return stats.ncx2.sf(stats.chi2.isf(math.exp(log_a), q), q, lam) - power

    a = math.exp(optimize.brentq(gap, math.log(1e-100), math.log(0.5), xtol=1e-12))
    return a, float(stats.chi2.isf(a, q))


def family_alpha(n_tests: dict[int, int], family: float = FAMILY_LEVEL, power: float = 0.80) -> float:
    """alpha_1 of the B-method whose tests together reject a block without blunders with probability *family*.

    Sidak over the tests: with ``n_q`` tests of dimension q, each at the B-method level
    ``alpha_q(alpha_1)`` of :func:`critical_values`, ``1 - prod_q (1 - alpha_q)^n_q = family``
    is solved for ``alpha_1``.  The tests of one block are positively correlated, so the
    true family-wise rate is at most *family* (exactly *family* for independent tests).

    Parameters
    ----------
    n_tests : dict q -> number of q-dimensional tests
    family : float
        Family-wise level, in (0, 0.5).
    power : float

    >>> a = family_alpha({2: 1000}, 0.05)
    >>> round(1 - (1 - critical_values(a, 0.80, 2)[0]) ** 1000, 6)
    0.05
    """
    _check_level(family, power)
    n_tests = {int(q): int(n) for q, n in n_tests.items() if n > 0 and q > 0}
    if not n_tests:
        return family
    target = -math.log1p(-family)

    def gap(log_a: float) -> float:
        a = math.exp(log_a)
        return sum(n * -math.log1p(-critical_values(a, power, q)[0]) for q, n in n_tests.items()) - target

    hi = math.log(min(family, 0.49))
    if gap(hi) <= 0:               # a single 1-D test: alpha_1 = family
        return min(family, 0.49)
    return math.exp(optimize.brentq(gap, math.log(1e-14), hi, xtol=1e-10))


def _check_level(alpha: float, power: float) -> None:
    if not 0 < alpha < 0.5:
        raise ValueError(f"`level` (alpha of the w-test) must be in (0, 0.5), got {alpha!r}")
    if not 0.5 < power < 1:
        raise ValueError(f"`power` must be in (0.5, 1), got {power!r}")


# ---------------------------------------------------------------------------
# value types
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Blunder:
    """One observation group flagged by data snooping (or removed by the robust step).

    Attributes
    ----------
    kind : str
        ``image`` (photo and point), ``control`` (point) or ``eo`` (photo).
    photo, point : str or None
        Ids; ``photo`` is None for control, ``point`` None for eo.
    w : float
        ``sqrt(T)`` of the q-dimensional test when it was found (= |w| for q = 1); for a
        group removed by the robust step, sqrt of its sum of squared normalised residuals
        (original sigmas) in the re-weighted adjustment.
    w_critical : float
        Its critical value.
    redundancy : float
        Mean redundancy number of the group's components (0..1).
    estimated_error : tuple of float
        Estimated bias of each component (observed minus true): mm for image,
        m for control, m and rad for eo.
    removed : bool
        Removed from the final adjustment.
    found_by : str
        ``snooping`` or the robust method.
    iteration : int
        Snooping iteration (1 = the first test).
    note : str
        Why it was not removed, when it was not.
    """

    kind: str
    photo: str | None
    point: str | None
    w: float
    w_critical: float
    redundancy: float
    estimated_error: tuple[float, ...]
    removed: bool
    found_by: str = "snooping"
    iteration: int = 1
    note: str = ""

    @property
    def unit(self) -> str:
        return {"image": "mm", "control": "m", "eo": "m, rad"}[self.kind]

    def label(self) -> str:
        """``image photo 3 point 405`` / ``control point 619`` / ``eo photo 2``."""
        if self.kind == "image":
            return f"image observation photo {self.photo} point {self.point}"
        if self.kind == "control":
            return f"control point {self.point}"
        return f"GNSS/INS constraint of photo {self.photo}"

    def to_dict(self) -> dict[str, Any]:
        comps = COMPONENTS[self.kind]
        return {"kind": self.kind, "photo": self.photo, "point": self.point, "w": self.w,
                "w_critical": self.w_critical, "redundancy": self.redundancy,
                "estimated_error": dict(zip(comps, self.estimated_error)), "unit": self.unit,
                "removed": self.removed, "found_by": self.found_by, "iteration": self.iteration,
                **({"note": self.note} if self.note else {})}


@dataclasses.dataclass(frozen=True, eq=False)
class Reliability:
    """Tests and reliability of every observation group of one adjustment.

    Groups are the image observations (in the problem's order), then the
    control points, then the GNSS/INS constraints.  Per-component arrays have
    ``width = 6`` columns, NaN beyond the group's components (2 for image, 3
    for control, 6 for eo) and on free axes.

    Attributes
    ----------
    kind : (m,) str
    photo, point : (m,) str ('' where not applicable)
    q : (m,) int
        Dimension of the test (components with a finite sigma).
    redundancy : (m, 6)
        Redundancy numbers r_k.
    w_component : (m, 6)
        Per-component w_k = e_k / sqrt(q_vv,kk).
    w : (m,)
        sqrt(T) of the group test; NaN when untestable.
    w_critical : (m,)
    estimated_error : (m, 6)
        Estimated bias (observed minus true), mm / m / m and rad.
    mdb : (m, 6)
        Minimal detectable bias per component (same units).
    bnr : (m, 6)
        Bias-to-noise ratio sqrt(lambda0 (1 - r) / r) of that MDB.
    eo_effect : (m, 6)
        Shift of X0, Y0, Z0 (m), omega, phi, kappa (rad) of photo
        ``eo_effect_photo`` by the component MDB with the largest BNR.
    eo_effect_photo : (m,) str
    alpha, power, lam0 : float
        Level of the 1-D test, power and noncentrality (B-method).
    dof : int
    family_level : float
        The family-wise level *alpha* was derived from (:func:`family_alpha`); NaN when
        *alpha* was given.
    family_tests : int
        Number of tests of that family (0 when *alpha* was given).
    """

    kind: np.ndarray
    photo: np.ndarray
    point: np.ndarray
    q: np.ndarray
    redundancy: np.ndarray
    w_component: np.ndarray
    w: np.ndarray
    w_critical: np.ndarray
    estimated_error: np.ndarray
    mdb: np.ndarray
    bnr: np.ndarray
    eo_effect: np.ndarray
    eo_effect_photo: np.ndarray
    alpha: float
    power: float
    lam0: float
    dof: int
    family_level: float = math.nan
    family_tests: int = 0

    @property
    def ratio(self) -> np.ndarray:
        """(m,) T / critical value; > 1 is rejected, NaN untestable."""
        return (self.w / self.w_critical) ** 2

    @property
    def testable(self) -> np.ndarray:
        return np.isfinite(self.w)

    @property
    def n_rejected(self) -> int:
        """Groups whose test rejects (several of them may be caused by one blunder)."""
        return int(np.sum(np.nan_to_num(self.ratio) > 1))

    def worst(self) -> int | None:
        """Index of the group with the largest test ratio, or None when none is testable."""
        r = np.where(self.testable, self.ratio, -np.inf)
        return int(np.argmax(r)) if len(r) and np.isfinite(r.max()) else None

    def blunder(self, g: int, *, removed: bool, iteration: int = 1, found_by: str = "snooping",
                note: str = "") -> Blunder:
        kind = str(self.kind[g])
        nc = len(COMPONENTS[kind])
        return Blunder(kind=kind, photo=str(self.photo[g]) if kind != "control" else None,
                       point=str(self.point[g]) if kind != "eo" else None, w=float(self.w[g]),
                       w_critical=float(self.w_critical[g]),
                       redundancy=float(np.nanmean(self.redundancy[g, :nc])),
                       estimated_error=tuple(float(v) for v in self.estimated_error[g, :nc]),
                       removed=removed, found_by=found_by, iteration=iteration, note=note)

    def rows(self) -> list[list[Any]]:
        """One row per scalar observation for ``reliability.csv`` (:data:`RELIABILITY_COLUMNS`)."""
        out: list[list[Any]] = []
        for g in range(len(self.kind)):
            kind = str(self.kind[g])
            rejected = bool(np.nan_to_num(self.ratio[g]) > 1)
            for k, comp in enumerate(COMPONENTS[kind]):
                ang = kind == "eo" and k >= 3
                scale = math.degrees(1.0) if ang else 1.0
                unit = "mm" if kind == "image" else ("deg" if ang else "m")
                if not np.isfinite(self.redundancy[g, k]) and kind != "image":
                    continue                                   # a free axis: no observation
                eff = self.eo_effect[g]
                out.append([kind, self.photo[g], self.point[g], comp, unit, self.redundancy[g, k],
                            self.w_component[g, k], self.estimated_error[g, k] * scale,
                            self.mdb[g, k] * scale, self.bnr[g, k], self.w[g], self.w_critical[g], rejected,
                            self.eo_effect_photo[g], *eff[:3], *np.degrees(eff[3:])])
        return out


#: columns of ``reliability.csv``
RELIABILITY_COLUMNS = ("kind", "photo", "point", "component", "unit", "redundancy", "w_component",
                       "estimated_error", "mdb", "bnr", "w", "w_critical", "rejected", "effect_photo",
                       "effect_X0_m", "effect_Y0_m", "effect_Z0_m", "effect_omega_deg", "effect_phi_deg",
                       "effect_kappa_deg")


@dataclasses.dataclass(frozen=True, eq=False)
class SnoopingResult:
    """Outcome of :func:`snoop`.

    Attributes
    ----------
    result : BundleResult
        The final adjustment: all observations (``report``, ``off``) or
        without the removed ones (``remove``).
    reliability : Reliability or None
        Tests of *result* (None for ``off`` or when it did not converge).
    blunders : tuple of Blunder
        In the order found.
    mode, robust : str
    more_remain : bool
        Snooping stopped (rejection limit, datum, non-convergence) with a
        rejected test left.
    n_adjustments : int
    """

    result: BundleResult
    reliability: Reliability | None
    blunders: tuple[Blunder, ...]
    mode: str
    robust: str
    more_remain: bool
    n_adjustments: int

    @property
    def blunders_remain(self) -> bool:
        """Blunders are left in the final result (reported only, or not removable)."""
        return self.more_remain or any(not b.removed for b in self.blunders)

    def summary(self) -> dict[str, Any]:
        """``snooping`` and ``blunders`` of ``summary.json``."""
        rel = self.reliability
        snoop_info: dict[str, Any] = {"mode": self.mode, "robust": self.robust,
                                      "n_adjustments": self.n_adjustments,
                                      "n_blunders": len(self.blunders),
                                      "n_removed": sum(b.removed for b in self.blunders),
                                      "blunders_remain": self.blunders_remain}
        if rel is not None:
            snoop_info.update({
                "level": rel.alpha, "power": rel.power, "noncentrality": rel.lam0,
                "family_level": None if math.isnan(rel.family_level) else rel.family_level,
                "n_tests": int(np.sum(rel.testable)),
                "family_tests": rel.family_tests or None,
                "critical_w": {str(q): math.sqrt(critical_values(rel.alpha, rel.power, q)[1])
                               for q in sorted(set(int(v) for v in rel.q if v > 0))},
                "test": "multi-dimensional chi-square per observation group (B-method), a priori "
                        "variance factor",
                "n_untestable": int(np.sum(~rel.testable)),
                "sum_redundancy": float(np.nansum(rel.redundancy)),
                "min_redundancy_image": float(np.nanmin(rel.redundancy[rel.kind == "image"]))
                if np.any(rel.kind == "image") else math.nan,
                "max_mdb_image_mm": float(np.nanmax(rel.mdb[rel.kind == "image"]))
                if np.any(rel.kind == "image") else math.nan,
                "max_bnr": float(np.nanmax(rel.bnr)) if np.isfinite(rel.bnr).any() else math.nan,
            })
        return {"snooping": snoop_info, "blunders": [b.to_dict() for b in self.blunders]}


# ---------------------------------------------------------------------------
# the tests of one adjustment
# ---------------------------------------------------------------------------


def _observation_covariance(system: NormalSystem) -> np.ndarray:
    """(n, 9, 9) a priori covariance of [eo_i, X_j] of every image observation (selected inverse)."""
    return observation_blocks(system)


def _group_tests(e: np.ndarray, sd: np.ndarray, qy: np.ndarray, lam0: float):
    """Tests of m groups of q components (free components: sd inf).

    Parameters
    ----------
    e : (m, q) residuals observed minus adjusted.
    sd : (m, q) sigmas (inf where free).
    qy : (m, q, q) covariance of the adjusted observations A S A^T.

    Returns
    -------
    r, w_comp, T, nabla, mdb, bnr, qdim : arrays; T is NaN for untestable groups.
    """
    m, q = e.shape
    free = ~np.isfinite(sd)
    sd1 = np.where(free, 1.0, sd)
    e = np.where(free, 0.0, e)
    qvv = -qy.copy()
    idx = np.arange(q)
    qvv[:, idx, idx] += sd1**2
    both = free[:, :, None] | free[:, None, :]
    qvv[both] = 0.0
    qvv[:, idx, idx] = np.where(free, -1.0, qvv[:, idx, idx])     # eigenvalue -1: outside the test
    dq = np.diagonal(qvv, axis1=1, axis2=2)
    r = np.where(free, np.nan, dq / sd1**2)
    dq = np.where(free, np.nan, dq)
    # whitened cofactor P^1/2 Qvv P^1/2 = U diag(lam) U^T: the test lives in the span of the
    # eigenvectors with lam > MIN_REDUNDANCY (an error along the others does not show at all, e.g.
    # the x-parallax of a point on two photos); T = sum (u^T P^1/2 e)^2 / lam over that span
    white = qvv / (sd1[:, :, None] * sd1[:, None, :])
    lam, U = np.linalg.eigh(white) if m else (np.zeros((0, q)), np.zeros((0, q, q)))
    keep = lam > MIN_REDUNDANCY
    ew = e / sd1
    proj = np.einsum("mji,mj->mi", U, ew)                  # u_i^T P^1/2 e
    inv_lam = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    T = np.sum(proj**2 * inv_lam, axis=1)
    qdim = keep.sum(axis=1)
    T[qdim == 0] = np.nan
    nabla = sd1 * np.einsum("mij,mj->mi", U, proj * inv_lam)
    nabla[free | (qdim == 0)[:, None]] = np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        w_comp = np.where(free, np.nan, e / np.sqrt(np.clip(dq, 0, None)))
        rc = np.clip(r, 0, 1)
        mdb = sd1 * np.sqrt(lam0 / rc)
        bnr = np.sqrt(lam0 * (1 - rc) / rc)
    mdb[free] = np.nan
    bnr[free] = np.nan
    return r, w_comp, T, nabla, mdb, bnr, qdim


def reliability(result: BundleResult, *, level: float | None = None, power: float = 0.80,
                family_level: float = FAMILY_LEVEL) -> Reliability:
    """Redundancy numbers, tests and reliability of every observation group of *result*.

    Parameters
    ----------
    result : BundleResult
        A converged adjustment.
    level : float, optional
        alpha of the one-dimensional w-test (two-sided); the q-dimensional
        tests use the B-method levels of :func:`critical_values`.  Default:
        :func:`family_alpha` of this block's tests at *family_level*.
    power : float
        beta0, power of the tests against the noncentrality lambda0.
    family_level : float
        Family-wise level used when *level* is None.

    Returns
    -------
    Reliability

    Raises
    ------
    DatumError
        The normal equations at the solution are singular.
    """
    if level is not None:
        _check_level(level, power)
    p = result.problem
    lam0 = 1.0                         # MDB and BNR scale with sqrt(lambda0): set once the level is known
    eo, pts = np.asarray(result.eo_params), np.asarray(result.points_m)
    system = NormalSystem(p, eo, pts)
    try:
        S = _observation_covariance(system)                 # (n, 9, 9), a priori
    except SingularSystem as ex:
        raise DatumError(f"reliability: {ex}") from ex
    ei, pj = p.photo_index, p.point_index
    n = len(ei)
    _, a_eo, a_pt, _ = project_with_jacobians(eo, pts[pj], p.focal_length_mm[ei], ei)
    A = np.concatenate([a_eo, a_pt], axis=2)                # (n, 2, 9)
    parts: list[dict[str, Any]] = []

    # image observations
    e_img = -np.asarray(result.residuals_mm)
    out = _group_tests(e_img, p.sd_mm, A @ S @ np.transpose(A, (0, 2, 1)), lam0)
    # external: effect of the component MDBs on [eo_i, X_j]
    eff = _effects(S, A, p.sd_mm, out[4], out[5])           # (n, 6)
    parts.append(dict(kind="image", photo=p.photo_ids[ei], point=p.point_ids[pj], out=out, eff=eff,
                      eff_photo=p.photo_ids[ei]))

    # covariances of points and photos from the observation blocks
    first_obs_pt = np.full(p.n_points, -1)
    first_obs_pt[pj[::-1]] = np.arange(n)[::-1]
    first_obs_ph = np.full(p.n_photos, -1)
    first_obs_ph[ei[::-1]] = np.arange(n)[::-1]

    # control points
    ci = p.constraint_point_index
    if len(ci):
        cov_pt = S[first_obs_pt[ci], 6:, 6:]
        e_con = -np.asarray(result.constraint_residuals_m)
        out = _group_tests(e_con, p.constraint_sd_m, cov_pt, lam0)
        eff, eff_ph = _control_effects(p, S, ci, out[4], out[5])
        parts.append(dict(kind="control", photo=np.full(len(ci), "", dtype=object), point=p.point_ids[ci],
                          out=out, eff=eff, eff_photo=eff_ph))
    # GNSS/INS constraints
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        k = p.eo_constraint_photo_index
        cov_eo = S[first_obs_ph[k], :6, :6]
        out = _group_tests(-np.asarray(result.eo_constraint_residuals), p.eo_constraint_sd, cov_eo, lam0)
        sd = p.eo_constraint_sd
        best = _best_component(out[5])
        nab = np.zeros((len(k), 6))
        rows = np.arange(len(k))
        nab[rows, best] = np.nan_to_num(out[4][rows, best])
        pw = np.where(np.isfinite(sd), 1.0 / np.where(np.isfinite(sd), sd, 1.0) ** 2, 0.0)
        eff = np.einsum("mij,mj->mi", cov_eo, pw * nab)
        parts.append(dict(kind="eo", photo=p.photo_ids[k], point=np.full(len(k), "", dtype=object), out=out,
                          eff=eff, eff_photo=p.photo_ids[k]))

    qdim = np.concatenate([part["out"][6] for part in parts]).astype(int)
    family, n_family = math.nan, 0
    if level is None:
        family, n_family = float(family_level), int(np.sum(qdim > 0))
        level = family_alpha(dict(zip(*np.unique(qdim[qdim > 0], return_counts=True))), family, power)
    lam0 = noncentrality(level, power)
    scale = math.sqrt(lam0)

    def cat(i: int, width: int = 6) -> np.ndarray:
        blocks = []
        for part in parts:
            a = part["out"][i] * (scale if i in (4, 5) else 1.0)
            if a.ndim == 2:
                a = np.pad(a, ((0, 0), (0, width - a.shape[1])), constant_values=np.nan)
            blocks.append(a)
        return np.concatenate(blocks)

    T = cat(2)
    crit = np.array([math.sqrt(critical_values(level, power, int(q))[1]) if q > 0 else math.nan
                     for q in qdim])
    return Reliability(
        kind=np.concatenate([np.full(len(part["photo"]), part["kind"], dtype=object) for part in parts]),
        photo=np.concatenate([np.asarray(part["photo"], dtype=object) for part in parts]),
        point=np.concatenate([np.asarray(part["point"], dtype=object) for part in parts]),
        q=qdim, redundancy=cat(0), w_component=cat(1), w=np.sqrt(T), w_critical=crit,
        estimated_error=cat(3), mdb=cat(4), bnr=cat(5),
        eo_effect=scale * np.concatenate([part["eff"] for part in parts]),
        eo_effect_photo=np.concatenate([np.asarray(part["eff_photo"], dtype=object) for part in parts]),
        alpha=float(level), power=float(power), lam0=lam0, dof=int(p.dof), family_level=family,
        family_tests=n_family)


def _dense_cofactor(result: BundleResult) -> tuple[np.ndarray, np.ndarray]:
    """Dense ``Q_vv = Q_ll - A N^-1 A^T`` of the image observations and control points, and ``diag Q_ll``.

    A reference for checks on small blocks only (``(2n + 3k)^2`` memory, a dense solve): the
    tests compare :func:`reliability` with it, the benchmark draws residuals from it.  Rows:
    x, y of every image observation, then E, N, h of every control point.
    """
    p = result.problem
    eo, pts = np.asarray(result.eo_params), np.asarray(result.points_m)
    ei, pj = p.photo_index, p.point_index
    _, a_eo, a_pt, _ = project_with_jacobians(eo, pts[pj], p.focal_length_mm[ei], ei)
    n, k = len(ei), len(p.constraint_point_index)
    u = 6 * p.n_photos + 3 * p.n_points
    A = np.zeros((2 * n + 3 * k, u))
    rows = np.arange(n)[:, None] * 2 + np.arange(2)
    for c in range(6):
        A[rows, (6 * ei + c)[:, None]] = a_eo[:, :, c]
    for c in range(3):
        A[rows, (6 * p.n_photos + 3 * pj + c)[:, None]] = a_pt[:, :, c]
    ci = p.constraint_point_index
    for c in range(3):
        A[2 * n + 3 * np.arange(k) + c, 6 * p.n_photos + 3 * ci + c] = 1.0
    qll = np.r_[p.sd_mm.ravel() ** 2, p.constraint_sd_m.ravel() ** 2]
    keep = np.isfinite(qll)
    w = np.where(keep, 1.0 / np.where(keep, qll, 1.0), 0.0)
    N = A.T @ (A * w[:, None])
    return np.diag(np.where(keep, qll, 0.0)) - A @ np.linalg.solve(N, A.T), qll


def _best_component(bnr: np.ndarray) -> np.ndarray:
    """Index of the component with the largest finite BNR of every group."""
    return np.argmax(np.where(np.isfinite(bnr), bnr, -1.0), axis=1)


def _effects(S: np.ndarray, A: np.ndarray, sd: np.ndarray, mdb: np.ndarray, bnr: np.ndarray) -> np.ndarray:
    """(n, 6) shift of the photo's orientation by the image MDB of the component with the largest BNR:
    dx = S_a A_a^T P_a nabla."""
    n = len(A)
    best = _best_component(bnr)
    rows = np.arange(n)
    nab = np.zeros((n, 2))
    nab[rows, best] = np.nan_to_num(mdb[rows, best], posinf=0.0)
    g = np.einsum("nki,nk->ni", A, nab / sd**2)              # A^T P nabla, (n, 9)
    return np.einsum("nij,nj->ni", S[:, :6, :], g)


def _control_effects(p: BundleProblem, S: np.ndarray, ci: np.ndarray, mdb: np.ndarray, bnr: np.ndarray):
    """Shift of the orientation of the photo (among those seeing the point) moved most by the control
    MDB with the largest BNR: dx_i = Cov(eo_i, X_j) P nabla."""
    k = len(ci)
    sd = p.constraint_sd_m
    best = _best_component(bnr)
    rows = np.arange(k)
    nab = np.zeros((k, 3))
    nab[rows, best] = np.nan_to_num(mdb[rows, best], posinf=0.0)
    pw = np.where(np.isfinite(sd), 1.0 / np.where(np.isfinite(sd), sd, 1.0) ** 2, 0.0)
    row_of = np.full(p.n_points, -1)
    row_of[ci] = rows
    obs = np.flatnonzero(row_of[p.point_index] >= 0)
    r_obs = row_of[p.point_index[obs]]
    d = np.einsum("nij,nj->ni", S[obs, :6, 6:], (pw * nab)[r_obs])     # (n_obs_ctrl, 6)
    size = np.linalg.norm(d[:, :3], axis=1)
    eff = np.zeros((k, 6))
    eff_ph = np.full(k, "", dtype=object)
    best_size = np.full(k, -1.0)
    for t in range(len(obs)):                               # a few rays per control point
        r = r_obs[t]
        if size[t] > best_size[r]:
            best_size[r] = size[t]
            eff[r] = d[t]
            eff_ph[r] = p.photo_ids[p.photo_index[obs[t]]]
    return eff, eff_ph


# ---------------------------------------------------------------------------
# removing observation groups
# ---------------------------------------------------------------------------


@dataclasses.dataclass
class _Subset:
    """Which observation groups of the original problem are still in."""

    obs: np.ndarray       # (n,) bool
    con: np.ndarray       # (k,) bool
    eo: np.ndarray        # (e,) bool

    def problem(self, p: BundleProblem) -> tuple[BundleProblem, np.ndarray, np.ndarray]:
        """The reduced problem, its photo and point positions in *p* (points with no ray dropped)."""
        keep_pt = np.zeros(p.n_points, dtype=bool)
        keep_pt[p.point_index[self.obs]] = True
        pt_new = np.cumsum(keep_pt) - 1
        ci = p.constraint_point_index
        con = self.con & keep_pt[ci]
        eo_kw: dict[str, Any] = {}
        if p.eo_constraint_photo_index is not None and self.eo.any():
            eo_kw = dict(eo_constraint_photo_index=p.eo_constraint_photo_index[self.eo],
                         eo_constraint_params=p.eo_constraint_params[self.eo],
                         eo_constraint_sd=p.eo_constraint_sd[self.eo])
        sub = BundleProblem(
            photo_ids=p.photo_ids, point_ids=p.point_ids[keep_pt], focal_length_mm=p.focal_length_mm,
            photo_index=p.photo_index[self.obs], point_index=pt_new[p.point_index[self.obs]],
            xy_mm=p.xy_mm[self.obs], sd_mm=p.sd_mm[self.obs],
            constraint_point_index=pt_new[ci[con]], constraint_enh_m=p.constraint_enh_m[con],
            constraint_sd_m=p.constraint_sd_m[con], initial_eo=p.initial_eo,
            point_role=p.point_role[keep_pt], info=p.info, **eo_kw)
        return sub, np.arange(p.n_photos), np.flatnonzero(keep_pt)

    def remove(self, p: BundleProblem, kind: str, photo: str | None, point: str | None) -> list[str]:
        """Remove one group.  A free point left with one ray loses it too: the two rays of a point
        seen on two photos cannot be told apart by any test.  Returns the photos of such rays."""
        partners = []
        if kind == "image":
            hit = self.obs & (p.photo_ids[p.photo_index] == photo) & (p.point_ids[p.point_index] == point)
            self.obs &= ~hit
            j = int(np.flatnonzero(p.point_ids == point)[0])
            rays = self.obs & (p.point_index == j)
            con_j = self.con & (p.constraint_point_index == j)
            full = bool(con_j.any() and np.isfinite(p.constraint_sd_m[con_j][0]).all())
            if rays.sum() == 1 and not full:
                self.obs &= ~rays
                partners.append(str(p.photo_ids[p.photo_index[rays]][0]))
        elif kind == "control":
            self.con &= p.point_ids[p.constraint_point_index] != point
            j = int(np.flatnonzero(p.point_ids == point)[0])
            rays = self.obs & (p.point_index == j)
            if rays.sum() == 1:              # a control point on one photo: nothing left to fix it
                self.obs &= ~rays
                partners.append(str(p.photo_ids[p.photo_index[rays]][0]))
        else:
            self.eo &= p.photo_ids[p.eo_constraint_photo_index] != photo
        return partners


# ---------------------------------------------------------------------------
# data snooping
# ---------------------------------------------------------------------------


def snoop(
    problem: BundleProblem,
    *,
    mode: str = "remove",
    level: float | None = None,
    power: float = 0.80,
    family_level: float = FAMILY_LEVEL,
    robust: str = "none",
    max_rejections: int | None = None,
    backward: bool = True,
    multiple: bool = True,
    on_rejection: Callable[[Blunder], None] | None = None,
    **adjust_kwargs: Any,
) -> SnoopingResult:
    """Adjust *problem* with blunder detection (Baarda's data snooping).

    Parameters
    ----------
    problem : BundleProblem
    mode : {"off", "report", "remove"}
        ``off``: adjust only.  ``report``: find the blunders as ``remove`` does
        but return the adjustment of all observations, the blunders listed with
        ``removed=False``.  ``remove``: return the adjustment without them.
    level : float, optional
        alpha of the one-dimensional w-test (B-method, see the module docstring);
        e.g. 0.001 gives critical w 3.29 (q = 1), 3.42 (q = 2), 3.55 (q = 3), 3.92
        (q = 6).  Default: :func:`family_alpha` of the tests of the first adjustment
        at *family_level*, kept for every re-adjustment (the family is the block's
        tests); on the thesis block (159 tests) alpha_1 = 1.04e-4, critical w 4.00
        for q = 2.
    power : float
        Power of the tests (0.80).
    family_level : float
        Probability that a block without blunders has any test rejecting, when *level*
        is None (0.05).
    robust : {"none", "danish", "huber"}
        Run iteratively re-weighted least squares first and remove the groups
        it weights down below :data:`ROBUST_CUT` in one go (large blocks with
        many blunders); snooping then tests the rest.
    max_rejections : int, optional
        Stop after this many rejections (``more_remain`` tells).  Default: 100, or
        :data:`MAX_REJECTED_SHARE` of the groups tested in the first adjustment when that is
        more (a large block with several rejections per round).
    multiple : bool
        Remove in one round, besides the group with the largest test ratio, every other
        rejected group that is *separate* from those already picked in that round: no
        photo that sees its point is, or shares a point with, such a photo of a picked
        group (:func:`_round_picks`).  On a block whose photos all share points (the thesis
        block) this is the classic one rejection per round.
    backward : bool
        After snooping stops, put back a rejected image observation when every test passes
        with it, or exchange it for another ray of its point when that lowers v'Pv
        (:func:`_refine`), and snoop again; costs up to (rays + 1) adjustments per rejection.
    on_rejection : callable(Blunder), optional
        Called after every rejection.
    **adjust_kwargs
        Passed to every :func:`lidarcat.bundle.adjust` (``variance_factor``,
        ``chi2_level``, ``max_iter``, ``progress``, ``precision`` -- the
        intermediate adjustments skip the covariances).

    Returns
    -------
    SnoopingResult

    Raises
    ------
    ValueError
        An unknown *mode* or *robust*, a bad *level* or *power*.
    DatumError
        From the first adjustment.
    """
    if mode not in SNOOPING_MODES:
        raise ValueError(f"`snooping` must be one of {', '.join(SNOOPING_MODES)}, got {mode!r}")
    if robust not in ROBUST_METHODS:
        raise ValueError(f"`robust` must be one of {', '.join(ROBUST_METHODS)}, got {robust!r}")
    if level is not None:
        _check_level(level, power)
    _check_level(family_level, power)
    final_precision = adjust_kwargs.pop("precision", "all")
    first = adjust(problem, precision=final_precision, **adjust_kwargs)
    if mode == "off":
        return SnoopingResult(first, None, (), mode, robust, False, 1)
    p = problem
    n_adj = 1
    sub = _Subset(np.ones(len(p.photo_index), bool), np.ones(len(p.constraint_point_index), bool),
                  np.ones(0 if p.eo_constraint_photo_index is None else len(p.eo_constraint_photo_index), bool))
    blunders: list[Blunder] = []
    res, cur = first, p
    rel_first = reliability(first, level=level, power=power, family_level=family_level) if first.success else None
    if rel_first is not None:
        level = rel_first.alpha          # the family is the first adjustment's tests
    if max_rejections is None:
        n_groups = 0 if rel_first is None else int(np.sum(rel_first.testable))
        max_rejections = max(100, math.ceil(MAX_REJECTED_SHARE * n_groups))
    rel = rel_first
    more = False
    if robust != "none" and first.success:
        res, cur, rel, found, k = _robust(p, sub, first, rel, robust, level, power, adjust_kwargs)
        blunders += found
        n_adj += k
    iteration = n_rej = 0
    near = _Neighbours(p) if multiple else None
    single = False                 # after a failed multiple round: one group at a time
    for _round in range(20):
        while rel is not None:
            g = rel.worst()
            if g is None or rel.ratio[g] <= 1:
                break
            if n_rej >= max_rejections:
                more = True
                log.warning("data snooping stopped after %d rejections; tests still reject", n_rej)
                break
            picks = [g] if near is None or single else _round_picks(rel, near, max_rejections - n_rej)
            iteration += 1
            saved = dataclasses.replace(sub, obs=sub.obs.copy(), con=sub.con.copy(), eo=sub.eo.copy())
            found: list[Blunder] = []
            for gg in picks:
                found += _remove_group(p, sub, rel, gg, iteration)
            try:
                nxt, _, _ = sub.problem(p)
                warm = (np.asarray(res.eo_params), _warm_points(res, nxt))
                res_new = _readjust(nxt, warm, adjust_kwargs)
                n_adj += 1
                if not res_new.success:
                    raise DatumError(f"the adjustment without it did not converge ({res_new.status})")
                rel_new = reliability(res_new, level=level, power=power)
            except (DatumError, ValueError) as ex:
                sub = saved
                if len(picks) > 1:          # try again with the largest ratio alone
                    iteration -= 1
                    single = True
                    continue
                blunders.append(dataclasses.replace(found[0], removed=False, note=f"not removed: {ex}"))
                more = True
                log.warning("data snooping: %s not removed: %s", found[0].label(), ex)
                break
            single = False
            blunders += found
            n_rej += len(picks)
            for bl in found:
                log.info("data snooping: rejected %s (w %.2f > %.2f)", bl.label(), bl.w, bl.w_critical)
                if on_rejection is not None:
                    on_rejection(bl)
            res, cur, rel = res_new, nxt, rel_new
        if more or rel is None or not backward:
            break
        # backward step: re-insert or exchange a rejected observation when the data prefer it
        changed, sub, res, cur, rel, blunders, k = _refine(p, sub, blunders, res, cur, rel, level, power,
                                                            adjust_kwargs)
        n_adj += k
        if not changed:
            break
    if mode == "report" or res is first:
        final, final_rel = first, rel_first
        blunders = [dataclasses.replace(b, removed=False) for b in blunders] if mode == "report" else blunders
    else:  # the intermediate adjustments skipped the covariances: once more with them
        final = adjust(cur, initial=(np.asarray(res.eo_params), np.asarray(res.points_m)),
                       precision=final_precision, **adjust_kwargs)
        final_rel = rel
        n_adj += 1
    if final_rel is not None and rel_first is not None:
        final_rel = dataclasses.replace(final_rel, family_level=rel_first.family_level,
                                        family_tests=rel_first.family_tests)
    return SnoopingResult(final, final_rel, tuple(blunders), mode, robust, more, n_adj)


def _remove_group(p: BundleProblem, sub: _Subset, rel: Reliability, g: int, iteration: int) -> list[Blunder]:
    """Remove group *g* of *rel* from *sub*; its :class:`Blunder` records (two for a two-ray point)."""
    bl = rel.blunder(g, removed=True, iteration=iteration)
    partners = sub.remove(p, bl.kind, bl.photo, bl.point)
    out = [bl]
    for ph in partners if bl.kind == "control" else ():
        out[0] = dataclasses.replace(bl, note=f"its only ray (photo {ph}) removed with it")
    for ph in partners if bl.kind == "image" else ():   # a two-ray point: the rays are not separable
        other = np.flatnonzero((rel.kind == "image") & (rel.photo == ph) & (rel.point == bl.point))
        note = (f"point {bl.point} is on two photos only: its rays on photos {bl.photo} and {ph} "
                "cannot be told apart; both removed")
        out[0] = dataclasses.replace(bl, note=note)
        if len(other):
            out.append(rel.blunder(int(other[0]), removed=True, iteration=iteration, note=note))
    return out


class _Neighbours:
    """Photos of the original problem that share a point (or are the same photo), and the photos of
    every point: the footprint of a group for :func:`_round_picks`."""

    def __init__(self, p: BundleProblem) -> None:
        from scipy import sparse

        inc = sparse.csr_matrix((np.ones(len(p.photo_index)), (p.photo_index, p.point_index)),
                                shape=(p.n_photos, p.n_points))
        self.adj = (inc @ inc.T + sparse.identity(p.n_photos, format="csr")).tocsr()
        self.of_point = inc.T.tocsr()
        self.photo_pos = {str(q): i for i, q in enumerate(p.photo_ids)}
        self.point_pos = {str(q): i for i, q in enumerate(p.point_ids)}

    def footprint(self, kind: str, photo: str, point: str) -> np.ndarray:
        """Photos whose unknowns the group's test depends on most: every photo that sees its point
        (image observation, control point), or its photo (GNSS/INS constraint)."""
        if kind != "eo":
            j = self.point_pos[point]
            return self.of_point.indices[self.of_point.indptr[j]:self.of_point.indptr[j + 1]]
        return np.array([self.photo_pos[photo]])

    def around(self, photos: np.ndarray) -> np.ndarray:
        return np.unique(np.concatenate([self.adj.indices[self.adj.indptr[i]:self.adj.indptr[i + 1]]
                                         for i in photos])) if len(photos) else photos


def _round_picks(rel: Reliability, near: _Neighbours, limit: int) -> list[int]:
    """Rejected groups removed together in one round, largest test ratio first.

    Rule: a group is picked when none of its photos (an image observation or a control
    point: every photo that sees its point; a GNSS/INS constraint: its photo) is a photo of
    a group picked before it in this round or shares a point with one.  Two such groups
    share no unknown and no observation, and neither do the other rays of their points, so
    their residuals are correlated only through the rest of the network (weakly): one
    cannot be the reason the other's test rejects, and both are what one-at-a-time snooping
    would find in two rounds.
    """
    ratio = np.where(rel.testable, np.nan_to_num(rel.ratio, nan=-np.inf), -np.inf)
    cand = np.flatnonzero(ratio > 1)
    cand = cand[np.argsort(-ratio[cand], kind="stable")]
    blocked = np.zeros(near.adj.shape[0], dtype=bool)
    picks: list[int] = []
    for g in cand:
        if len(picks) >= limit:
            break
        fp = near.footprint(str(rel.kind[g]), str(rel.photo[g]), str(rel.point[g]))
        if blocked[fp].any():
            continue
        picks.append(int(g))
        blocked[near.around(fp)] = True
    return picks


def _refine(p, sub, blunders, res, cur, rel, level, power, adjust_kwargs):
    """One backward step after snooping stopped; returns ``(changed, sub, res, cur, rel, blunders, n_adj)``.

    For each image observation removed by snooping (not a two-ray point): adjust with it put back;
    when every test then passes it was a false rejection (its w was raised by a blunder removed
    later) and it is re-inserted.  Otherwise try removing, instead of it, each other ray of its
    point: the w-tests of the rays of one point are correlated and the largest w can sit on a good
    ray; the exchange is kept when it lowers v'Pv (the same number of observations removed, so
    the likelihood decides).  At most one change per call.
    """
    n_adj = 0
    pid, qid = p.photo_ids[p.photo_index], p.point_ids[p.point_index]
    for k, b in enumerate(blunders):
        if b.kind != "image" or b.found_by != "snooping" or not b.removed or b.note:
            continue
        a = int(np.flatnonzero((pid == b.photo) & (qid == b.point))[0])
        others = np.flatnonzero(sub.obs & (p.point_index == p.point_index[a]))
        best = back = None
        for h in [None, *(int(o) for o in others)]:
            trial = dataclasses.replace(sub, obs=sub.obs.copy(), con=sub.con.copy(), eo=sub.eo.copy())
            trial.obs[a] = True
            if h is not None:
                trial.obs[h] = False
            try:
                prob, _, _ = trial.problem(p)
                r = _readjust(prob, (np.asarray(res.eo_params), _warm_points(res, prob)), adjust_kwargs)
                n_adj += 1
                if not r.success:
                    continue
                if h is None:
                    relt = back = reliability(r, level=level, power=power)
                    g = relt.worst()
                    if g is None or relt.ratio[g] <= 1:
                        best = (None, trial, r, prob, relt)
                        break
                elif r.vtpv < res.vtpv - 1e-9 * max(1.0, res.vtpv) and (best is None or r.vtpv < best[2].vtpv):
                    best = (h, trial, r, prob, None)
            except (DatumError, ValueError, KeyError):
                continue
        if best is None:
            continue
        h, trial, r, prob, relt = best
        relt = relt if relt is not None else reliability(r, level=level, power=power)
        out = list(blunders)
        if h is None:
            log.info("data snooping: %s put back (every test passes with it)", b.label())
            del out[k]
        else:
            # its test in the adjustment with both rays in (where the choice was made)
            src = back if back is not None else rel
            g = int(np.flatnonzero((src.kind == "image") & (src.photo == pid[h]) & (src.point == qid[h]))[0])
            out[k] = src.blunder(g, removed=True, iteration=b.iteration,
                                 note=f"exchanged for photo {b.photo} (same point): lower v'Pv")
            log.info("data snooping: %s exchanged for photo %s (lower v'Pv)", b.label(), pid[h])
        return True, trial, r, prob, relt, out, n_adj
    return False, sub, res, cur, rel, blunders, n_adj


def _readjust(problem: BundleProblem, initial: tuple[np.ndarray, np.ndarray], adjust_kwargs: dict) -> BundleResult:
    """Re-adjustment from a nearby solution, without covariances: plain Gauss-Newton first (it
    converges in a few steps from there; the damped path took about twice as many), the damped
    one when that fails or when the caller chose ``damping``."""
    if "damping" not in adjust_kwargs:
        r = adjust(problem, initial=initial, precision="none", damping=False, **adjust_kwargs)
        if r.success:
            return r
    return adjust(problem, initial=initial, precision="none", **adjust_kwargs)


def _warm_points(res: BundleResult, nxt: BundleProblem) -> np.ndarray:
    """Adjusted coordinates of *res* for the points of *nxt* (by id)."""
    pos = {str(q): i for i, q in enumerate(res.point_ids)}
    return np.asarray(res.points_m)[[pos[str(q)] for q in nxt.point_ids]]


def _robust(p, sub, res, rel, method, level, power, adjust_kwargs, max_iter: int = 20):
    """IRLS with the Danish or Huber weight function on the group tests; returns the state after
    removing the groups weighted below :data:`ROBUST_CUT`."""
    n_img = len(p.photo_index)
    k_con = len(p.constraint_point_index)
    factor = np.ones(len(rel.kind))
    cur = p
    n_adj = 0
    r_cur, rel_cur = res, rel
    crit = {q: critical_values(level, power, q)[1] for q in (1, 2, 3, 6)}
    kq = np.array([crit[{"image": 2, "control": 3, "eo": 6}[str(k)]] for k in rel.kind])
    same_cut = 0
    for _ in range(max_iter):
        # normalised residuals with the original sigmas (not the re-weighted ones: a group weighted
        # down must keep its large residual, or it would get its weight back the next time)
        u = np.sqrt(_normalised_sq(p, r_cur) / kq)
        new = np.ones_like(u)
        big = u > 1
        new[big] = np.maximum(np.exp(1 - u[big] ** 2) if method == "danish" else 1.0 / u[big], ROBUST_FLOOR)
        if np.allclose(new, factor, rtol=1e-3, atol=1e-6):
            break
        # only the groups cut below ROBUST_CUT leave the re-weighting (snooping with the original weights
        # tests the rest): stop when that set has not changed in ROBUST_STABLE re-weightings
        same_cut = same_cut + 1 if np.array_equal(new < ROBUST_CUT, factor < ROBUST_CUT) else 0
        if same_cut >= ROBUST_STABLE:
            factor = new
            break
        factor = new
        cur = _reweighted(p, factor, n_img, k_con)
        prev = r_cur
        r_cur = _readjust(cur, (np.asarray(r_cur.eo_params), np.asarray(r_cur.points_m)), adjust_kwargs)
        n_adj += 1
        if not r_cur.success:
            r_cur = prev
            log.warning("robust %s: the re-weighted adjustment did not converge; stopped", method)
            break
    try:
        rel_cur = reliability(r_cur, level=level, power=power)
    except DatumError:
        rel_cur = rel
    # remove the groups weighted down (tests of the original weights follow in snooping)
    found: list[Blunder] = []
    cut = np.flatnonzero(factor < ROBUST_CUT)
    for g in cut:
        kind = str(rel_cur.kind[g])
        photo = str(rel_cur.photo[g]) if kind != "control" else None
        point = str(rel_cur.point[g]) if kind != "eo" else None
        b = rel_cur.blunder(int(g), removed=True, iteration=0, found_by=method)
        # w and the estimated error of the original weights: e / sd relative to the critical value
        partners = sub.remove(p, kind, photo, point)
        found.append(dataclasses.replace(b, w=float(math.sqrt(u[g] ** 2 * kq[g])),
                                         note="; ".join([f"weight factor {factor[g]:.1e}",
                                                         *(f"the other ray (photo {ph}) removed with it"
                                                           for ph in partners)])))
    if not found:
        return res, p, rel, [], n_adj
    try:
        nxt, _, _ = sub.problem(p)
        r2 = _readjust(nxt, (np.asarray(r_cur.eo_params), _warm_points(r_cur, nxt)), adjust_kwargs)
    except (DatumError, ValueError) as ex:
        log.warning("robust %s: removing the %d down-weighted group(s) leaves %s; snooping alone", method,
                    len(found), ex)
        sub.obs[:], sub.con[:], sub.eo[:] = True, True, True
        return res, p, rel, [], n_adj
    n_adj += 1
    rel2 = reliability(r2, level=level, power=power) if r2.success else None
    log.info("robust %s: %d group(s) removed", method, len(found))
    return r2, nxt, rel2, found, n_adj


def _normalised_sq(p: BundleProblem, res: BundleResult) -> np.ndarray:
    """Sum of (residual / original sigma)^2 of every group, in the order of :class:`Reliability`."""
    parts = [np.sum((np.asarray(res.residuals_mm) / p.sd_mm) ** 2, axis=1)]
    if len(p.constraint_point_index):
        w = np.where(np.isfinite(p.constraint_sd_m), 1.0 / p.constraint_sd_m, 0.0)
        parts.append(np.sum((np.asarray(res.constraint_residuals_m) * w) ** 2, axis=1))
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        w = np.where(np.isfinite(p.eo_constraint_sd), 1.0 / p.eo_constraint_sd, 0.0)
        parts.append(np.sum((np.asarray(res.eo_constraint_residuals) * w) ** 2, axis=1))
    return np.concatenate(parts)


def _reweighted(p: BundleProblem, factor: np.ndarray, n_img: int, k_con: int) -> BundleProblem:
    """*p* with the sigmas of every group divided by sqrt(factor)."""
    s = 1.0 / np.sqrt(factor)
    kw: dict[str, Any] = {}
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        kw = dict(eo_constraint_sd=p.eo_constraint_sd * s[n_img + k_con:, None])
    return dataclasses.replace(p, sd_mm=p.sd_mm * s[:n_img, None],
                               constraint_sd_m=p.constraint_sd_m * s[n_img:n_img + k_con, None], **kw)
