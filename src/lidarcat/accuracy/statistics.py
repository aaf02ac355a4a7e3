r"""The statistical tests of the check-point assessment (thesis section 3.3.4, Cavassim et al. 2005).

Each test takes a sample of discrepancies and returns a :class:`TestResult`
(statistic, critical value, verdict, or *not applicable* with the reason; a
test never raises on data).  The formulas are in
:mod:`lidarcat.accuracy.checkpoints`.

What comes from scipy and what does not:

* **Lilliefors**: :func:`scipy.stats.goodness_of_fit` (``norm``, Monte-Carlo
  null from the data's fitted normal) with the statistic of Lilliefors (1967):
  the K-S distance to N(mean, s) with the *sample* sd (divisor n - 1); scipy's
  own ``"ks"`` statistic uses the maximum-likelihood sd (divisor n) and so a
  different D.  The statistic is location-scale invariant, so the null is that
  of Lilliefors; ``seed`` makes it reproducible (:func:`lilliefors_test`).
* **Plain K-S**, **t**, **chi-square**, **F**: :mod:`scipy.stats`
  distributions (``kstwo``, ``t``, ``chi2``, ``f``, ``beta``).
* kept here, because scipy lacks them: the **Filliben (1975) table** of PPCC
  critical values (scipy's ``goodness_of_fit(statistic="filliben")`` gives
  only a Monte-Carlo p-value, and only for Filliben's plotting positions:
  the thesis also uses Hazen's and Blom's, :func:`plotting_positions`);
  **Hotelling's T^2** of a zero mean via its F distribution (scipy has no
  one-sample Hotelling test); the **K-S of generalized squared distances**
  (Cavassim's eq. 03, a Beta null); the **chi-square of the joint covariance**
  (:func:`covariance_consistency_test`); the **exact circular error radius**
  of a biased bivariate normal (:func:`circular_error_radius`: scipy has no
  such quantile).
"""

from __future__ import annotations

import csv
import functools
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

import numpy as np
from scipy import integrate, optimize, stats

from ..errors import AssessmentError

__all__ = [
    "PLOTTING_POSITIONS",
    "TestResult",
    "plotting_positions",
    "filliben_table",
    "filliben_critical_value",
    "filliben_test",
    "ks_test",
    "lilliefors_test",
    "ks_mahalanobis_test",
    "trend_t_test",
    "chi2_precision_test",
    "covariance_consistency_test",
    "hotelling_t2_test",
    "circular_error_radius",
    "ce90",
    "not_applicable",
]

PLOTTING_POSITIONS: tuple[str, ...] = ("filliben", "hazen", "blom")
_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)


# ----------------------------------------------------------------------------- Filliben table


@functools.lru_cache(maxsize=1)
def _filliben_rows() -> tuple[tuple[float, ...], np.ndarray, np.ndarray]:
    text = (resources.files("lidarcat") / "standards_data" / "filliben1975_critical_values.csv").read_text(encoding="utf-8")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    alphas = tuple(float(h.split("_", 1)[1]) for h in rows[0][1:])
    body = np.array([[float(c) for c in r] for r in rows[1:]])
    return alphas, body[:, 0].astype(int), body[:, 1:]


def filliben_table() -> tuple[tuple[float, ...], np.ndarray, np.ndarray]:
    """The Filliben (1975) table: ``(alphas, n (K,), critical (K, len(alphas)))``."""
    alphas, ns, crit = _filliben_rows()
    return alphas, ns.copy(), crit.copy()


def filliben_critical_value(n: int, alpha: float) -> float:
    """Critical PPCC value r(n, alpha) from the Filliben (1975) table.

    Normality is rejected when ``r < value``.  For an *n* between tabulated
    rows the value is interpolated linearly (as normtest does).

    Raises
    ------
    AssessmentError
        *alpha* is not a column of the table (0.005, 0.01, 0.025, 0.05, 0.10,
        0.25, 0.5) or *n* is outside 3..100 (use Monte-Carlo critical values).
    """
    alphas, ns, crit = _filliben_rows()
    col = [i for i, a in enumerate(alphas) if abs(a - alpha) < 1e-12]
    if not col:
        raise AssessmentError(f"alpha={alpha} is not in the Filliben table "
                              f"({', '.join(str(a) for a in alphas)}); use Monte-Carlo critical values")
    if not ns[0] <= n <= ns[-1]:
        raise AssessmentError(f"n={n} is outside the Filliben table (n = {ns[0]}..{ns[-1]}); "
                              "use Monte-Carlo critical values")
    return float(round(np.interp(n, ns, crit[:, col[0]]), 6))


# ----------------------------------------------------------------------------- circle radius


def circular_error_radius(prob: float, mean: Sequence[float], cov: np.ndarray) -> float:
    """Radius r with ``P(||e|| <= r) = prob`` for ``e ~ N(mean, cov)`` in 2-D.

    Exact: the covariance is rotated to its principal axes, the probability of
    the disc is one numerical integral, and r is found by root bracketing.

    Parameters
    ----------
    prob : float
        Probability in (0, 1), e.g. 0.90 (CE90) or 0.95 (NSSDA).
    mean : (2,) array
        Bias (m).
    cov : (2, 2) array
        Covariance (m^2), symmetric positive semi-definite.

    >>> round(circular_error_radius(0.90, [0, 0], np.eye(2)), 4)
    2.146
    >>> round(circular_error_radius(0.95, [0, 0], np.eye(2)), 4)
    2.4477
    """
    if not 0 < prob < 1:
        raise AssessmentError(f"probability must be in (0, 1), got {prob}")
    cov = np.asarray(cov, dtype=float).reshape(2, 2)
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    lam = np.clip(lam[::-1], 0.0, None)
    vec = vec[:, ::-1]
    m = vec.T @ np.asarray(mean, dtype=float).reshape(2)
    s1, s2 = math.sqrt(lam[0]), math.sqrt(lam[1])
    mnorm = float(np.hypot(*m))
    m0, m1 = float(m[0]), float(m[1])
    if s1 <= 1e-9 * max(mnorm, 1e-6):
        return mnorm  # no spread: every error is the bias
    tiny = 1e-9 * s1

    def p_disc(r: float) -> float:
        if r <= 0:
            return 0.0
        lo, hi = max(-r, m[0] - 12 * s1), min(r, m[0] + 12 * s1)
        if lo >= hi:
            return 0.0

        def f(x: float) -> float:
            half = math.sqrt(max(r * r - x * x, 0.0))
            if s2 <= tiny:
                inner = 1.0 if abs(m1) <= half else 0.0
            else:  # Phi(b) - Phi(a) with math.erfc (scipy.stats is 100x slower per scalar call)
                inner = 0.5 * (math.erfc(-(half - m1) / (s2 * _SQRT2)) - math.erfc(-(-half - m1) / (s2 * _SQRT2)))
            u = (x - m0) / s1
            return math.exp(-0.5 * u * u) / (s1 * _SQRT2PI) * inner

        pts = [p for p in (m[0], -math.sqrt(max(r * r - m[1] ** 2, 0)), math.sqrt(max(r * r - m[1] ** 2, 0)))
               if lo < p < hi]
        val, _ = integrate.quad(f, lo, hi, points=pts or None, limit=200, epsabs=1e-12, epsrel=1e-10)
        return val

    hi = mnorm + 12 * s1
    while p_disc(hi) < prob:  # pragma: no cover - 12 sigma always holds prob < 1 - 1e-30
        hi *= 2
    return float(optimize.brentq(lambda r: p_disc(r) - prob, 0.0, hi, xtol=1e-12, rtol=1e-12))


# ----------------------------------------------------------------------------- tests


@dataclass(frozen=True, eq=False)
class TestResult:
    """Outcome of one statistical test on one component.

    Attributes
    ----------
    test : str
        ``filliben``, ``ks``, ``lilliefors``, ``trend_t``, ``chi2_precision``,
        ``hotelling``, ``ce90``.
    component : str
        ``E``, ``N``, ``h``, ``planimetric``, ``EN`` or a CE90 method.
    statistic_name : str
        Key of the statistic in :meth:`to_dict` (``r``, ``t``, ``chi2``, ``D``,
        ``T2``, ``radius``).
    statistic, critical : float or None
    passed : bool or None
        None when not applicable.
    alpha : float or None
    applicable : bool
    reason : str or None
        Why the test is not applicable.
    details : dict
        Extra numbers (p-value, bounds, n, degrees of freedom, sigma0 ...).
    """

    __test__ = False  # not a pytest class

    test: str
    component: str
    statistic_name: str
    statistic: float | None
    critical: float | None
    passed: bool | None
    alpha: float | None
    applicable: bool = True
    reason: str | None = None
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        """``passed``, ``failed`` or ``not applicable``."""
        if not self.applicable or self.passed is None:
            return "not applicable"
        return "passed" if self.passed else "failed"

    def to_dict(self) -> dict[str, Any]:
        out = {self.statistic_name: self.statistic, "critical": self.critical, "passed": self.passed,
               "alpha": self.alpha, "applicable": self.applicable, "reason": self.reason}
        out.update(self.details)
        return out


def not_applicable(test: str, comp: str, name: str, alpha: float | None, reason: str, **details: Any) -> TestResult:
    """The *not applicable* :class:`TestResult` of *test* on component *comp*, with the reason."""
    return TestResult(test, comp, name, None, None, None, alpha, False, reason, dict(details))


def _sample(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=float).ravel()


def _zero_var(x: np.ndarray) -> bool:
    return x.size > 0 and float(np.ptp(x)) <= 1e-12 * max(1.0, float(np.max(np.abs(x))))


def _precheck(test: str, comp: str, name: str, alpha: float, x: np.ndarray, min_n: int) -> TestResult | None:
    """The *not applicable* result of a 1-D test on *x*, or None when it can be computed."""
    n = x.size
    if n < min_n:
        return not_applicable(test, comp, name, alpha, f"needs at least {min_n} points, got {n}", n=n)
    if _zero_var(x):
        return not_applicable(test, comp, name, alpha, "zero variance: all discrepancies are equal", n=n)
    return None


def _precheck_en(test: str, name: str, alpha: float, x: np.ndarray, min_n: int) -> TestResult | None:
    """The *not applicable* result of a test on (dE, dN) rows *x* (n, 2), or None when it can be computed."""
    n = x.shape[0]
    if n < min_n:
        return not_applicable(test, "EN", name, alpha, f"needs at least {min_n} points, got {n}", n=n)
    if not _nonsingular(np.cov(x, rowvar=False, ddof=1)):
        return not_applicable(test, "EN", name, alpha,
                   "singular covariance of (dE, dN): zero variance or collinear discrepancies", n=n)
    return None


def plotting_positions(n: int, kind: str = "filliben") -> np.ndarray:
    """Plotting positions m_i (probabilities) for i = 1..n.

    ``filliben``: order-statistic medians ``m_n = 0.5^(1/n)``, ``m_1 = 1 - m_n``,
    ``m_i = (i - 0.3175)/(n + 0.365)``; ``hazen``: ``(i - 0.5)/n``;
    ``blom``: ``(i - 0.375)/(n + 0.25)``.

    >>> plotting_positions(4, "hazen")
    array([0.125, 0.375, 0.625, 0.875])
    """
    i = np.arange(1, n + 1, dtype=float)
    if kind == "filliben":
        m = (i - 0.3175) / (n + 0.365)
        m[-1] = 0.5 ** (1.0 / n)
        m[0] = 1.0 - m[-1]
        return m
    if kind == "hazen":
        return (i - 0.5) / n
    if kind == "blom":
        return (i - 0.375) / (n + 0.25)
    raise AssessmentError(f"plotting_position must be one of {', '.join(PLOTTING_POSITIONS)}, got {kind!r}")


def _chunks(n_sim: int, n: int) -> list[int]:
    # simulate in blocks of about 2e6 numbers to bound memory for large n
    step = max(1, 2_000_000 // max(n, 1))
    return [min(step, n_sim - i) for i in range(0, n_sim, step)]


@functools.lru_cache(maxsize=64)
def _ppcc_null(n: int, kind: str, n_sim: int = 20000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = stats.norm.ppf(plotting_positions(n, kind))
    qc = q - q.mean()
    out = []
    for m in _chunks(n_sim, n):
        z = np.sort(rng.standard_normal((m, n)), axis=1)
        zc = z - z.mean(axis=1, keepdims=True)
        out.append((zc @ qc) / np.sqrt(np.sum(zc * zc, axis=1) * np.sum(qc * qc)))
    r = np.concatenate(out)
    r.setflags(write=False)
    return r


def _ppcc_mc_critical(n: int, alpha: float, kind: str, n_sim: int = 20000, seed: int = 0) -> float:
    return float(np.quantile(_ppcc_null(n, kind, n_sim, seed), alpha))


def filliben_test(x: Any, alpha: float = 0.10, plotting_position: str = "filliben", *,
                  critical: str = "table", component: str = "x") -> TestResult:
    """Filliben probability-plot correlation test of normality (thesis eq. 42).

    Parameters
    ----------
    x : (N,) array
    alpha : float
        Level (a column of the Filliben table when ``critical="table"``).
    plotting_position : {"filliben", "hazen", "blom"}
    critical : {"table", "montecarlo"}
        Critical value from the Filliben (1975) table, or by a seeded
        Monte-Carlo simulation with the chosen plotting positions (2e4
        samples).  Outside the table (n > 100, other alpha) Monte-Carlo is
        used and ``details["critical_source"]`` says so.

    >>> t = filliben_test(np.array([-1.2, -0.4, 0.1, 0.3, 0.9, 1.5]))
    >>> round(t.statistic, 4), t.critical, t.passed
    (0.9957, 0.911, True)
    """
    x = _sample(x)
    n = x.size
    plotting_positions(3, plotting_position)  # validates the name
    na = _precheck("filliben", component, "r", alpha, x, 3)
    if na is not None:
        return na
    q = stats.norm.ppf(plotting_positions(n, plotting_position))
    r = float(np.corrcoef(np.sort(x), q)[0, 1])
    source = "Filliben (1975) table"
    crit: float
    if critical == "table":
        try:
            crit = filliben_critical_value(n, alpha)
        except AssessmentError as ex:
            crit = _ppcc_mc_critical(n, alpha, plotting_position)
            source = f"Monte-Carlo, 20000 samples, {plotting_position} positions ({ex})"
    elif critical == "montecarlo":
        crit = _ppcc_mc_critical(n, alpha, plotting_position)
        source = f"Monte-Carlo, 20000 samples, {plotting_position} positions"
    else:
        raise AssessmentError(f"critical must be 'table' or 'montecarlo', got {critical!r}")
    return TestResult("filliben", component, "r", r, crit, bool(r >= crit), alpha, details={
        "n": n, "plotting_position": plotting_position, "critical_source": source})


def ks_test(x: Any, alpha: float = 0.10, *, component: str = "x") -> TestResult:
    """Plain Kolmogorov-Smirnov test against N(mean, s) with the sample's own mean and s.

    This is the test as published (Cavassim et al. 2005, via Statgraphics); it
    is conservative because the parameters are estimated (prefer
    :func:`lilliefors_test`).  Passed when ``D <= D_crit`` (``kstwo``).
    """
    x = _sample(x)
    n = x.size
    na = _precheck("ks", component, "D", alpha, x, 3)
    if na is not None:
        return na
    res = stats.kstest(x, "norm", args=(float(np.mean(x)), float(np.std(x, ddof=1))))
    crit = float(stats.kstwo.ppf(1 - alpha, n))
    return TestResult("ks", component, "D", float(res.statistic), crit, bool(res.statistic <= crit), alpha,
                      details={"n": n, "p_value": float(res.pvalue),
                               "method": "plain K-S with estimated mean and sd (as published)"})


def _lilliefors_d(dist: Any, data: np.ndarray, axis: int = -1) -> np.ndarray:
    """K-S distance of each sample (along *axis*) to N(its mean, its sd with divisor n - 1).

    The statistic of Lilliefors (1967), in the signature of a
    :func:`scipy.stats.goodness_of_fit` statistic; *dist* (scipy's fit, whose
    scale has divisor n) is not used.
    """
    z = np.moveaxis(np.asarray(data, dtype=float), axis, -1)
    n = z.shape[-1]
    zs = np.sort(z, axis=-1)
    u = (zs - zs.mean(axis=-1, keepdims=True)) / zs.std(axis=-1, ddof=1, keepdims=True)
    f = stats.norm.cdf(u)
    i = np.arange(1, n + 1)
    return np.maximum(np.max(i / n - f, axis=-1), np.max(f - (i - 1) / n, axis=-1))


def lilliefors_test(x: Any, alpha: float = 0.10, *, n_sim: int = 20000, seed: int = 0,
                    component: str = "x") -> TestResult:
    """Lilliefors (K-S with estimated mean and sd) normality test.

    :func:`scipy.stats.goodness_of_fit` against ``norm`` with the Lilliefors
    statistic (:func:`_lilliefors_d`: the sample sd, divisor n - 1, as
    Lilliefors 1967; scipy's ``"ks"`` uses divisor n): ``n_sim`` seeded normal
    samples of the same size give the null distribution, its 1 - alpha
    quantile the critical value, and the p-value ``(1 + #{D_sim >= D}) /
    (n_sim + 1)``; deterministic for a given seed.  The null samples are drawn
    at once (``n_sim`` x n numbers: 160 MB at the default and n = 1000).

    >>> t = lilliefors_test(np.array([-1.2, -0.4, 0.1, 0.3, 0.9, 1.5]))
    >>> round(t.statistic, 4), round(t.details["p_value"], 4), t.passed
    (0.1248, 0.9937, True)
    """
    x = _sample(x)
    n = x.size
    na = _precheck("lilliefors", component, "D", alpha, x, 4)
    if na is not None:
        return na
    res = stats.goodness_of_fit(stats.norm, x, statistic=_lilliefors_d, n_mc_samples=n_sim,
                                rng=np.random.default_rng(seed))
    d = float(res.statistic)
    crit = float(np.quantile(res.null_distribution, 1 - alpha))
    return TestResult("lilliefors", component, "D", d, crit, bool(d <= crit), alpha, details={
        "n": n, "p_value": float(res.pvalue),
        "method": f"Lilliefors, Monte-Carlo null ({n_sim} samples, seed {seed})"})


def ks_mahalanobis_test(den: Any, alpha: float = 0.10) -> TestResult:
    """K-S test of the generalized squared distances of (dE, dN) (Cavassim eq. 03).

    ``d_j^2 = (x_j - mean)^T S^-1 (x_j - mean)``; under bivariate normality
    ``u_j = n d_j^2 / (n - 1)^2`` follows Beta(1, (n - 3)/2) (Johnson and
    Wichern), which is the reference distribution here.
    """
    x = np.asarray(den, dtype=float).reshape(-1, 2)
    n = x.shape[0]
    na = _precheck_en("ks", "D", alpha, x, 4)
    if na is not None:
        return na
    s = np.cov(x, rowvar=False, ddof=1)
    c = x - x.mean(axis=0)
    d2 = np.einsum("ij,jk,ik->i", c, np.linalg.inv(s), c)
    u = n * d2 / (n - 1) ** 2
    dist = stats.beta(1.0, (n - 3) / 2.0)
    res = stats.kstest(u, dist.cdf)
    crit = float(stats.kstwo.ppf(1 - alpha, n))
    return TestResult("ks", "EN", "D", float(res.statistic), crit, bool(res.statistic <= crit), alpha, details={
        "n": n, "p_value": float(res.pvalue),
        "method": "K-S of n d_j^2/(n-1)^2 against Beta(1, (n-3)/2) (generalized distances, Cavassim eq. 03)"})


def trend_t_test(x: Any, alpha: float = 0.10, *, mu0: float = 0.0, component: str = "x") -> TestResult:
    """Two-sided t-Student trend test (eq. 44) with the eq. 43 confidence bounds.

    ``t = (mean - mu0) / (s / sqrt(n))``; no trend (passed) when
    ``|t| <= t_{n-1, 1 - alpha/2}``.  ``details`` has ``mean_lower`` and
    ``mean_upper`` = ``mean -/+ t_crit s / sqrt(n)`` (eq. 43).

    >>> r = trend_t_test(np.arange(21.0) - 9.0)
    >>> round(r.critical, 4), r.passed
    (1.7247, True)
    """
    x = _sample(x)
    n = x.size
    na = _precheck("trend_t", component, "t", alpha, x, 2)
    if na is not None:
        return na
    mean, s = float(np.mean(x)), float(np.std(x, ddof=1))
    se = s / math.sqrt(n)
    t = (mean - mu0) / se
    crit = float(stats.t.ppf(1 - alpha / 2, n - 1))
    return TestResult("trend_t", component, "t", t, crit, bool(abs(t) <= crit), alpha, details={
        "n": n, "df": n - 1, "mean": mean, "std": s, "mu0": mu0,
        "p_value": float(2 * stats.t.sf(abs(t), n - 1)),
        "mean_lower": mean - crit * se, "mean_upper": mean + crit * se})


def chi2_precision_test(x: Any, sigma0: float | None, alpha: float = 0.10, *, component: str = "x",
                        sigma0_source: str = "") -> TestResult:
    """One-sided chi-square precision test (eq. 46) and the eq. 45 bound.

    ``chi2 = (n - 1) s^2 / sigma0^2``; passed when ``chi2 <= chi2_{n-1, 1-alpha}``.
    ``sigma_bound = sqrt((n - 1) s^2 / chi2_{n-1, 1-alpha})`` (eq. 45) is the
    smallest sigma0 (EP) that the sample passes.

    >>> r = chi2_precision_test(np.linspace(-1, 1, 21), 1.0)
    >>> round(r.critical, 3), r.passed
    (28.412, True)
    """
    x = _sample(x)
    n = x.size
    if sigma0 is None:
        return not_applicable("chi2_precision", component, "chi2", alpha,
                   "no expected standard deviation: give the map scale (and contour interval for h)", n=n)
    if not sigma0 > 0:
        return not_applicable("chi2_precision", component, "chi2", alpha, f"sigma0 must be positive, got {sigma0}", n=n)
    if n < 2:
        return not_applicable("chi2_precision", component, "chi2", alpha, f"needs at least 2 points, got {n}", n=n)
    s = float(np.std(x, ddof=1))
    chi = (n - 1) * s * s / sigma0 ** 2
    crit = float(stats.chi2.ppf(1 - alpha, n - 1))
    return TestResult("chi2_precision", component, "chi2", chi, crit, bool(chi <= crit), alpha, details={
        "n": n, "df": n - 1, "std": s, "sigma0": sigma0, "sigma0_source": sigma0_source,
        "sigma_bound": math.sqrt((n - 1) * s * s / crit),
        "p_value": float(stats.chi2.sf(chi, n - 1))})


def covariance_consistency_test(d: Any, cov: Any, alpha: float = 0.10, *,
                                source: str = "") -> TestResult:
    """Do the discrepancies agree with the precision the adjustment claims?

    ``chi2 = d^T C^-1 d`` over all coordinates of all check points, with ``C``
    the covariance of the discrepancies: the joint covariance of the adjusted
    points (cross-covariances included, :func:`lidarcat.bundle.joint_point_covariance`)
    plus that of the reference coordinates.  Under the model it follows
    chi-square with ``3 n`` degrees of freedom; passed when inside the two-sided
    ``1 - alpha`` interval (above: errors larger than the stated precision, a
    blunder or a model error; below: the precision is pessimistic;
    ``details["side"]`` says which).  Summing ``d_i^2 / sigma_i^2`` instead
    ignores the correlation of points that share the block's orientation
    errors and is *not* chi-square distributed.

    Parameters
    ----------
    d : (n, 3) array
        Discrepancies E, N, h (m), either sign convention.
    cov : (3n, 3n) array
        Their covariance (m^2), point after point.
    alpha : float
    source : str
        Where the covariance came from (carried into the details).

    >>> r = covariance_consistency_test(np.array([[0.1, -0.1, 0.2]]), np.diag([0.01, 0.01, 0.04]))
    >>> round(r.statistic, 6), r.details["df"], r.passed
    (3.0, 3, True)
    """
    x = np.asarray(d, dtype=float).reshape(-1)
    c = np.asarray(cov, dtype=float)
    n = x.size
    if c.shape != (n, n):
        return not_applicable("consistency", "ENh", "chi2", alpha,
                   f"covariance has shape {c.shape}, expected ({n}, {n})")
    with np.errstate(over="ignore", invalid="ignore"):
        sym = 0.5 * c + 0.5 * c.T  # halves first: no overflow for entries near the float maximum
    if n == 0 or not np.all(np.isfinite(sym)) or not np.all(np.isfinite(x)):
        return not_applicable("consistency", "ENh", "chi2", alpha, "no discrepancies or a non-finite covariance")
    try:
        L = np.linalg.cholesky(sym)
    except np.linalg.LinAlgError:
        return not_applicable("consistency", "ENh", "chi2", alpha, "covariance of the discrepancies is not positive definite")
    from scipy.linalg import solve_triangular

    w = solve_triangular(L, x, lower=True)
    chi = float(w @ w)
    lo, hi = (float(v) for v in stats.chi2.ppf([alpha / 2, 1 - alpha / 2], n))
    p_two = float(2 * min(stats.chi2.cdf(chi, n), stats.chi2.sf(chi, n)))
    worst = np.sum(w.reshape(-1, 3) ** 2, axis=1) if n % 3 == 0 else None
    return TestResult("consistency", "ENh", "chi2", chi, hi, bool(lo <= chi <= hi), alpha, details={
        "n": n // 3 if n % 3 == 0 else n, "df": n, "lower": lo, "upper": hi, "p_value": p_two,
        "ratio": chi / n, "covariance_source": source,
        "side": "below" if chi < lo else "above" if chi > hi else "inside",
        "diagonal_statistic": float(np.sum(x * x / np.diag(c))),
        "largest_point_share": float(worst.max() / chi) if worst is not None and chi > 0 else None})


def _nonsingular(s: np.ndarray) -> bool:
    scale = float(np.trace(s))
    return scale > 0 and float(np.linalg.det(s)) > 1e-12 * scale * scale


def hotelling_t2_test(den: Any, alpha: float = 0.10) -> TestResult:
    """Hotelling's T^2 test of H0: E[(dE, dN)] = (0, 0) (Cavassim eq. 04).

    ``T^2 = n mean^T S^-1 mean`` (S with divisor n - 1); passed (no 2-D trend)
    when ``T^2 <= 2 (n - 1)/(n - 2) F_{2, n-2, 1-alpha}``.
    """
    x = np.asarray(den, dtype=float).reshape(-1, 2)
    n, p = x.shape
    na = _precheck_en("hotelling", "T2", alpha, x, 3)
    if na is not None:
        return na
    s = np.cov(x, rowvar=False, ddof=1)
    m = x.mean(axis=0)
    t2 = float(n * m @ np.linalg.solve(s, m))
    f = (n - p) / (p * (n - 1)) * t2
    fcrit = float(stats.f.ppf(1 - alpha, p, n - p))
    crit = p * (n - 1) / (n - p) * fcrit
    return TestResult("hotelling", "EN", "T2", t2, crit, bool(t2 <= crit), alpha, details={
        "n": n, "F": f, "F_critical": fcrit, "df1": p, "df2": n - p,
        "p_value": float(stats.f.sf(f, p, n - p)), "mean_E": float(m[0]), "mean_N": float(m[1])})


def ce90(den: Any, method: str = "empirical", *, prob: float = 0.90, limit_m: float | None = None,
         limit_source: str = "") -> TestResult:
    """Circular error radius at ``prob`` (90 %) of the planimetric discrepancies.

    Methods: ``empirical`` (smallest radius holding at least ``prob`` of the
    points: the ceil(prob n)-th smallest dP), ``circular``
    (``sigma_c sqrt(-2 ln(1 - prob))``, ``sigma_c = sqrt((s_E^2 + s_N^2)/2)``,
    bias ignored) and ``bivariate_exact`` (the disc holding ``prob`` of
    N(mean, S), bias and correlation included).  With *limit_m* (a PEC) the
    result passes when ``radius <= limit_m``.
    """
    x = np.asarray(den, dtype=float).reshape(-1, 2)
    n = x.shape[0]
    dp = np.hypot(x[:, 0], x[:, 1])
    need = {"empirical": 1, "circular": 2, "bivariate_exact": 3}
    if method not in need:
        raise AssessmentError(f"CE90 method must be one of {', '.join(need)}, got {method!r}")
    if n < need[method]:
        return not_applicable("ce90", method, "radius", None, f"needs at least {need[method]} points, got {n}", n=n)
    if method != "empirical" and _zero_var(x[:, 0]) and _zero_var(x[:, 1]):
        return not_applicable("ce90", method, "radius", None, "zero variance of dE and dN", n=n)
    details: dict[str, Any] = {"n": n, "probability": prob}
    if method == "empirical":
        k = max(1, math.ceil(prob * n - 1e-9))
        r = float(np.sort(dp)[k - 1])
        details["order_statistic"] = k
        details["percentile_linear"] = float(np.quantile(dp, prob))
    elif method == "circular":
        sc = math.sqrt((np.var(x[:, 0], ddof=1) + np.var(x[:, 1], ddof=1)) / 2)
        r = sc * math.sqrt(-2 * math.log(1 - prob))
        details["sigma_c"] = sc
    else:
        r = circular_error_radius(prob, x.mean(axis=0), np.cov(x, rowvar=False, ddof=1))
        details["mean"] = x.mean(axis=0).tolist()
    details["fraction_within"] = float(np.mean(dp <= r + 1e-12))
    if limit_m is None:
        return TestResult("ce90", method, "radius", r, None, None, None, True, None, details)
    details["critical_source"] = limit_source
    return TestResult("ce90", method, "radius", r, limit_m, bool(r <= limit_m + 1e-9), None, True, None, details)
