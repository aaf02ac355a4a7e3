r"""Redundancy numbers, group tests (w-tests) and reliability of one adjustment.

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

Line observations
-----------------
An observation of line control (``problem.lines``, :mod:`lidarcat.bundle.lines`) is one more
2-D group: the signed distances ``r`` of the projected end points of a 3-D line from the
measured image line, with the full 2 x 2 covariance ``Sigma_r`` (its two residuals are
correlated) and one photo's orientation as its only unknowns, so ``Q_vv = Sigma_r - A C_i A^T``
with ``C_i`` that photo's 6 x 6 block of the same selected inverse.  Whitened with the
symmetric ``W = P^{1/2}`` (``e_w = W e``, cofactor ``W Q_vv W``, unit sds) it is tested as every
other group: ``T = e_w^T (W Q_vv W)^{-1} e_w = e^T Q_vv^{-1} e``, the redundancy numbers are the
diagonal of ``P^{1/2} Q_vv P^{1/2}`` (in [0, 1], summing to ``tr(Q_vv P)``;
:mod:`lidarcat.bundle.line_tests`), a direction without redundancy drops out of the test as for
an image point of two rays.  Its estimated error is returned to mm (``Sigma^{1/2} nabla_w``),
its MDB is the whitened one times each residual's own sd.  Its rows follow the GNSS/INS groups
(``kind`` ``line``, the line id in ``point``, components ``a``, ``b``), and its test is part of
the family the level is derived from.

Data snooping and robust re-weighting, which remove the groups these tests reject,
live in :mod:`lidarcat.bundle.reliability` (which also re-exports the names of this module).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import numpy as np
from scipy import optimize, stats

from .rays import observation_parts
from ..errors import DatumError
from .linear import SingularSystem
from .model import NormalSystem
from .lines import line_terms
from .precision import observation_blocks
from .problem import BundleProblem
from .result import BundleResult

__all__ = ["Blunder", "Reliability", "FAMILY_LEVEL", "MIN_REDUNDANCY", "COMPONENTS", "RELIABILITY_COLUMNS",
           "noncentrality", "critical_values", "family_alpha", "check_level", "reliability"]

#: names of the components of each kind of observation group, and their units
COMPONENTS = {"image": ("x", "y"), "control": ("E", "N", "h"),
              "eo": ("X0", "Y0", "Z0", "omega", "phi", "kappa"), "line": ("a", "b")}
#: a group whose smallest redundancy is below this cannot be tested (its error would not show)
MIN_REDUNDANCY = 1e-3
#: default family-wise level: probability that a block without blunders has any test rejecting
FAMILY_LEVEL = 0.05


# ---------------------------------------------------------------------------
# levels of the B-method
# ---------------------------------------------------------------------------


@functools.lru_cache(maxsize=64)
def noncentrality(alpha: float = 0.001, power: float = 0.80) -> float:
    """lambda0 of the one-dimensional w-test: P(chi2(1, lambda0) > chi2_{1-alpha}(1)) = power.

    >>> round(noncentrality(0.001, 0.80), 2)
    17.07
    """
    check_level(alpha, power)
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
    check_level(family, power)
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


def check_level(alpha: float, power: float) -> None:
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
        ``image`` (photo and point), ``control`` (point), ``eo`` (photo) or ``line`` (an
        observation of line control: its photo, and its line id in ``point``).
    photo, point : str or None
        Ids; ``photo`` is None for control, ``point`` None for eo, the line id for line.
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
        return {"image": "mm", "control": "m", "eo": "m, rad", "line": "mm"}[self.kind]

    def label(self) -> str:
        """``image photo 3 point 405`` / ``control point 619`` / ``eo photo 2`` / ``line R1 on photo 3``."""
        if self.kind == "image":
            return f"image observation photo {self.photo} point {self.point}"
        if self.kind == "line":
            return f"line {self.point} on photo {self.photo}"
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
    control points, then the GNSS/INS constraints, then the observations of line
    control (``problem.lines``, in their order; ``point`` holds the line id).
    Per-component arrays have ``width = 6`` columns, NaN beyond the group's
    components (2 for image and line, 3 for control, 6 for eo) and on free axes.

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
                unit = "mm" if kind in ("image", "line") else ("deg" if ang else "m")
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
        check_level(level, power)
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
    _, a_pt, a_ang, _ = observation_parts(p, eo, pts)
    a_eo = np.concatenate([-a_pt, a_ang], axis=2)
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

    # observations of line control (module docstring, "Line observations")
    L = getattr(p, "lines", None)
    if L is not None and len(L.line_index):
        parts.append(_line_part(p, L, eo, S, first_obs_ph, lam0))

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


def _line_part(p: BundleProblem, L: Any, eo: np.ndarray, S: np.ndarray, first_obs_ph: np.ndarray,
               lam0: float) -> dict[str, Any]:
    """The tests of the line observations as one more part of :func:`reliability` (module docstring,
    "Line observations"): whitened with the symmetric ``P^1/2`` of each observation, so that the
    group test of :func:`_group_tests` (unit sds) is ``e^T Q_vv^-1 e`` and its redundancy numbers are
    the diagonal of ``P^1/2 Q_vv P^1/2``; the estimated error and the MDB are returned to mm."""
    T = line_terms(L, eo, p.focal_length_mm)
    ph = L.photo_index
    m = len(ph)
    has = first_obs_ph[ph] >= 0                     # a photo with image observations (its 6 x 6 block in S)
    C = np.zeros((m, 6, 6))
    C[has] = S[first_obs_ph[ph[has]], :6, :6]
    lp, vp = np.linalg.eigh(T.P)
    root = np.sqrt(np.clip(lp, 0.0, None))
    W = vp @ (root[:, :, None] * np.transpose(vp, (0, 2, 1)))              # P^1/2
    Wi = vp @ ((1.0 / np.where(root > 0, root, 1.0))[:, :, None] * np.transpose(vp, (0, 2, 1)))  # Sigma^1/2
    qy = W @ T.A @ C @ np.transpose(T.A, (0, 2, 1)) @ W
    qy[~has] = np.eye(2)                            # no block: Q_vv 0, untestable
    e = np.einsum("kij,kj->ki", W, -T.r)
    r, w_comp, Tst, nab, mdb, bnr, qdim = _group_tests(e, np.ones((m, 2)), qy, lam0)
    nab = np.einsum("kij,kj->ki", Wi, nab)                                 # mm
    # external: the whitened MDB of the component with the largest BNR, back in mm (Sigma^1/2), moves
    # the photo by C A^T P nabla
    rows = np.arange(m)
    best = _best_component(bnr)
    white = np.zeros((m, 2))
    white[rows, best] = np.nan_to_num(mdb[rows, best], posinf=0.0)
    g = np.einsum("kji,kjl,kl->ki", T.A, T.P, np.einsum("kij,kj->ki", Wi, white))   # A^T P nabla (6,)
    eff = np.einsum("kij,kj->ki", C, g)
    mdb = mdb * np.sqrt(np.diagonal(T.cov, axis1=1, axis2=2))   # in the residual's own sd (mm)
    return dict(kind="line", photo=p.photo_ids[ph], point=np.asarray(L.line_ids, dtype=object)[L.line_index],
                out=(r, w_comp, Tst, nab, mdb, bnr, qdim), eff=eff, eff_photo=p.photo_ids[ph])


def _dense_cofactor(result: BundleResult) -> tuple[np.ndarray, np.ndarray]:
    """Dense ``Q_vv = Q_ll - A N^-1 A^T`` of the image observations and control points, and ``diag Q_ll``.

    A reference for checks on small blocks only (``(2n + 3k)^2`` memory, a dense solve): the
    tests compare :func:`reliability` with it, the benchmark draws residuals from it.  Rows:
    x, y of every image observation, then E, N, h of every control point.
    """
    p = result.problem
    eo, pts = np.asarray(result.eo_params), np.asarray(result.points_m)
    ei, pj = p.photo_index, p.point_index
    _, a_pt, a_ang, _ = observation_parts(p, eo, pts)
    a_eo = np.concatenate([-a_pt, a_ang], axis=2)
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
