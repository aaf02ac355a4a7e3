r"""Accuracy assessment by check points: discrepancies, statistical tests, standards.

This is section 3.3.4 of the thesis (Fierro Sanhueza 2007) plus the tests of
Cavassim et al. (2005) and the map-accuracy standards of
:mod:`lidarcat.accuracy.standards`.

Discrepancies
-------------
For each check point ``d = reference - adjusted`` (the thesis convention,
Table 7; ``sign="adjusted_minus_reference"`` gives the ASPRS / NSSDA one; only
the sign of the means changes), per axis E, N, h, and the planimetric
resultant ``dP = sqrt(dE^2 + dN^2)``.  Summary per component: ``n``, mean,
sample standard deviation ``s`` (divisor n - 1), ``RMSE = sqrt(sum d^2 / n)``
and ``max |d|``.

Tests (level ``alpha``, default 0.10 as in the thesis)
-------------------------------------------------------
* **Filliben** PPCC (eq. 42): ``r = corr(x_(i), Phi^-1(m_i))`` with plotting
  positions ``filliben`` (order-statistic medians, the default, matching the
  critical-value table), ``hazen`` ``(i - 0.5)/n`` (the thesis's Z_i) or
  ``blom``; normality rejected when ``r < r_crit(n, alpha)`` (Filliben 1975
  table, or Monte-Carlo values matched to the positions).
* **Kolmogorov-Smirnov**: plain (mean and s plugged in, as published by
  Cavassim et al.; conservative) and **Lilliefors** (Monte-Carlo null
  distribution with estimated parameters).  ``ks["EN"]`` is Cavassim's eq. 03:
  the generalized squared distances ``d_j^2`` of (dE, dN), scaled
  ``n d_j^2 / (n - 1)^2 ~ Beta(1, (n - 3)/2)``.
* **t-Student trend** per axis (eq. 44): ``t = mean / (s / sqrt(n))``, no
  trend when ``|t| <= t_{n-1, 1-alpha/2}``; eq. 43 gives the confidence
  bounds ``mean -/+ t s / sqrt(n)``.
* **Chi-square precision** (eq. 45, 46): ``chi2 = (n - 1) s^2 / sigma0^2``,
  passed when ``chi2 <= chi2_{n-1, 1-alpha}``; ``sigma_bound = sqrt((n - 1)
  s^2 / chi2_{n-1, 1-alpha})`` is eq. 45, the smallest sigma0 the sample
  passes.  sigma0 is the EP of the target PEC class: on the planimetric
  resultant and on h the thesis's reading ("Erro Padrao equivalente ao Desvio
  Padrao", EP_plan = 0.60 m and EP_alt = 0.67 m at 1:2 000, Eq = 2 m); on E
  and N the component reading sigma0 = EP_plan / sqrt(2) (see
  ``docs/accuracy.md``, STANDARDS.md open item 2).
* **Hotelling T^2** on (dE, dN): ``T^2 = n mean^T S^-1 mean``,
  ``F = (n - 2) / (2 (n - 1)) T^2 ~ F(2, n - 2)``.
* **90 % circular error radius**: ``empirical`` (smallest radius holding at
  least 90 % of the points), ``circular`` (``2.1460 sigma_c``,
  ``sigma_c = sqrt((s_E^2 + s_N^2)/2)``), ``bivariate_exact`` (the 90 % disc
  of N(mean, S)); compared with the planimetric PEC of the target class.

A test that cannot be computed (too few points, zero variance, singular
covariance, no scale) is returned as *not applicable* with the reason; it
never raises.

>>> import numpy as np
>>> adjusted = {"1": (0.0, 0.0, 0.0), "2": (1.0, 1.0, 1.0), "3": (2.0, 2.0, 2.0), "4": (3.0, 3.0, 3.0)}
>>> reference = {"1": (0.1, 0.0, 0.2), "2": (1.0, 0.9, 0.9), "3": (2.2, 2.1, 2.0), "4": (2.9, 3.0, 3.3)}
>>> a = assess(adjusted, reference, scale=2000, contour_interval_m=2)
>>> round(a.summary["E"]["mean"], 3), a.summary["E"]["n"]
(0.05, 4)
>>> a.standards["pec"].classes
{'planimetric': 'A', 'altimetric': 'A'}
"""

from __future__ import annotations

import functools
import logging
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from . import standards as _std
from .._util.frozen import frozen_array
from .._util import read_csv_table
from ..errors import AssessmentError

__all__ = [
    "COMPONENTS",
    "PLOTTING_POSITIONS",
    "SIGNS",
    "PointSet",
    "TestResult",
    "Assessment",
    "read_points",
    "discrepancies",
    "summarize",
    "plotting_positions",
    "filliben_test",
    "ks_test",
    "covariance_consistency_test",
    "lilliefors_test",
    "ks_mahalanobis_test",
    "trend_t_test",
    "chi2_precision_test",
    "hotelling_t2_test",
    "ce90",
    "assess",
]

log = logging.getLogger(__name__)

#: summary components, in report order
COMPONENTS: tuple[str, ...] = ("E", "N", "h", "planimetric")
PLOTTING_POSITIONS: tuple[str, ...] = ("filliben", "hazen", "blom")
SIGNS: tuple[str, ...] = ("reference_minus_adjusted", "adjusted_minus_reference")
_CONTROL_ROLES = {"control", "fixed", "fixo"}


# ----------------------------------------------------------------------------- inputs


@dataclass(frozen=True, eq=False)
class PointSet:
    """Point coordinates with ids, as read from a CSV file, dict or array.

    Attributes
    ----------
    ids : tuple of str
    xyz : (N, 3) float64 array
        E, N, h in metres.
    sd : (N, 3) float64 array or None
        sd_E, sd_N, sd_h (m) when the input has them.
    roles : tuple of str or None
        ``role`` column (control / check / tie ...) when present.
    source : str
        Where the points came from (file path or a label), for messages.
    """

    ids: tuple[str, ...]
    xyz: np.ndarray
    sd: np.ndarray | None = None
    roles: tuple[str, ...] | None = None
    source: str = "<points>"

    def __post_init__(self) -> None:
        xyz = frozen_array(np.reshape(self.xyz, (-1, 3)))
        object.__setattr__(self, "xyz", xyz)
        if self.sd is not None:
            object.__setattr__(self, "sd", frozen_array(np.reshape(self.sd, (-1, 3))))
        if len(self.ids) != xyz.shape[0]:
            raise AssessmentError(f"{self.source}: {len(self.ids)} ids for {xyz.shape[0]} coordinate rows")
        seen: set[str] = set()
        dup = sorted({i for i in self.ids if i in seen or seen.add(i)})
        if dup:
            raise AssessmentError(f"{self.source}: duplicate point id(s) {', '.join(dup)}")

    def index(self) -> dict[str, int]:
        return {p: k for k, p in enumerate(self.ids)}


def read_points(obj: Any, label: str = "points") -> PointSet:
    """Read points from a CSV path, a mapping, an ``(ids, xyz)`` pair or an array.

    Accepted forms:

    * path to a CSV file with columns ``point, E, N, h`` and optionally
      ``sd_E, sd_N, sd_h, role`` (other columns such as ``source`` are
      ignored): the ``points.csv`` of ``lidarcat adjust`` and a survey's
      ``ground_points.csv`` both qualify;
    * ``{"point": [...], "E": [...], "N": [...], "h": [...]}`` (columns);
    * ``{id: (E, N, h), ...}``;
    * ``(ids, xyz)`` with xyz of shape (N, 3);
    * an (N, 3) array (ids ``"1"..."N"``, paired by position);
    * a :class:`PointSet`.

    Raises
    ------
    AssessmentError, SurveyError
        Unreadable file, missing columns, duplicate ids, NaN coordinates.
    """
    if isinstance(obj, PointSet):
        return obj
    if isinstance(obj, (str, os.PathLike)):
        path = Path(obj)
        if path.is_dir():
            path = path / "points.csv"
        table = read_csv_table(path, ("point", "E", "N", "h"), allow_extra=True)
        xyz = np.column_stack([table.floats(c) for c in ("E", "N", "h")])
        sd = None
        if all(table.has(c) for c in ("sd_E", "sd_N", "sd_h")):
            sd = np.column_stack([table.floats(c, required=False) for c in ("sd_E", "sd_N", "sd_h")])
        roles = tuple(r.lower() for r in table.column("role")) if table.has("role") else None
        return PointSet(tuple(table.column("point")), xyz, sd, roles, str(path))
    if isinstance(obj, Mapping):
        if "point" in obj and all(k in obj for k in ("E", "N", "h")):
            ids = tuple(str(p) for p in obj["point"])

            def cols(names: Sequence[str]) -> np.ndarray:
                out = []
                for c in names:
                    v = _floats(obj[c], f"{label}: column {c!r}").ravel()
                    if v.size != len(ids):
                        raise AssessmentError(f"{label}: column {c!r} has {v.size} values for {len(ids)} points")
                    out.append(v)
                return np.column_stack(out)

            xyz = cols(("E", "N", "h"))
            sd = cols(("sd_E", "sd_N", "sd_h")) if all(k in obj for k in ("sd_E", "sd_N", "sd_h")) else None
            roles = tuple(str(r).lower() for r in obj["role"]) if "role" in obj else None
            ps = PointSet(ids, xyz, sd, roles, label)
        else:
            ids = tuple(str(k) for k in obj)
            rows = []
            for k, v in obj.items():
                arr = _floats(v, f"{label}: point {k!r}").ravel()
                if arr.size < 3:
                    raise AssessmentError(f"{label}: point {k!r} has {arr.size} values, expected E, N, h")
                rows.append(arr[:3])
            ps = PointSet(ids, np.array(rows).reshape(-1, 3), source=label)
    elif isinstance(obj, tuple) and len(obj) == 2:
        ids = tuple(str(p) for p in obj[0])
        arr = _floats(obj[1], label)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise AssessmentError(f"{label}: expected an (N, 3) array of E, N, h, got shape {arr.shape}")
        ps = PointSet(ids, arr, source=label)
    else:
        arr = _floats(obj, label)
        if arr.ndim != 2 or arr.shape[1] != 3:
            raise AssessmentError(f"{label}: expected an (N, 3) array of E, N, h, got shape {arr.shape}")
        ps = PointSet(tuple(str(i + 1) for i in range(arr.shape[0])), arr, source=label)
    if not np.all(np.isfinite(ps.xyz)):
        bad = [ps.ids[i] for i in np.nonzero(~np.all(np.isfinite(ps.xyz), axis=1))[0]]
        raise AssessmentError(f"{ps.source}: non-finite coordinates for point(s) {', '.join(bad)}")
    return ps


def _floats(values: Any, where: str) -> np.ndarray:
    try:
        return np.asarray(values, dtype=float)
    except (TypeError, ValueError) as ex:
        raise AssessmentError(f"{where}: not a number ({ex})") from None


def _select(adj: PointSet, ref: PointSet, points: Iterable[str] | None) -> list[str]:
    aidx, ridx = adj.index(), ref.index()
    if points is not None:
        sel = [str(p) for p in points]
        if not sel:
            raise AssessmentError("the list of points to assess is empty")
        miss_a = [p for p in sel if p not in aidx]
        miss_r = [p for p in sel if p not in ridx]
        if miss_a or miss_r:
            parts = []
            if miss_a:
                parts.append(f"not in the adjusted points ({adj.source}): {', '.join(miss_a)}")
            if miss_r:
                parts.append(f"not in the reference ({ref.source}): {', '.join(miss_r)}")
            raise AssessmentError("requested check point(s) " + "; ".join(parts))
        return list(dict.fromkeys(sel))
    if adj.roles is not None and any(r == "check" for r in adj.roles):
        sel = [p for p, r in zip(adj.ids, adj.roles) if r == "check"]
        miss = [p for p in sel if p not in ridx]
        if miss:
            raise AssessmentError(f"check point(s) {', '.join(miss)} of {adj.source} are not in the reference "
                                  f"{ref.source}; add them there or choose points with --points")
        return sel
    sel = list(ref.ids)
    if adj.roles is not None:
        role = dict(zip(adj.ids, adj.roles))
        sel = [p for p in sel if role.get(p, "") not in _CONTROL_ROLES]
    miss = [p for p in sel if p not in aidx]
    if miss:
        common = [p for p in sel if p in aidx]
        hint = (f"; {len(common)} ids are common, choose them with --points" if common
                else "; no id is common to both files: are they the right files?")
        raise AssessmentError(f"reference point(s) {', '.join(miss)} of {ref.source} are missing in the "
                              f"adjusted points {adj.source}{hint}")
    if not sel:
        raise AssessmentError(f"no check points: every reference point of {ref.source} is a control point "
                              f"in {adj.source}")
    return sel


def discrepancies(adjusted: np.ndarray, reference: np.ndarray, sign: str = "reference_minus_adjusted"
                  ) -> np.ndarray:
    """Discrepancies (N, 3) between two (N, 3) coordinate arrays.

    >>> discrepancies(np.array([[1.0, 2.0, 3.0]]), np.array([[1.5, 2.0, 2.0]]))
    array([[ 0.5,  0. , -1. ]])
    """
    if sign not in SIGNS:
        raise AssessmentError(f"sign must be one of {', '.join(SIGNS)}, got {sign!r}")
    a = np.asarray(adjusted, dtype=float)
    r = np.asarray(reference, dtype=float)
    return r - a if sign == "reference_minus_adjusted" else a - r


def summarize(x: np.ndarray) -> dict[str, Any]:
    """n, mean, sample sd (n - 1), RMSE, max |x|, min and max of a 1-D sample.

    >>> s = summarize(np.array([1.0, -1.0, 2.0]))
    >>> s["n"], round(s["mean"], 4), round(s["std"], 4), round(s["rmse"], 4), s["max_abs"]
    (3, 0.6667, 1.5275, 1.4142, 2.0)
    """
    x = np.asarray(x, dtype=float).ravel()
    n = int(x.size)
    if n == 0:
        return {"n": 0, "mean": None, "std": None, "rmse": None, "max_abs": None, "min": None, "max": None}
    return {"n": n, "mean": float(np.mean(x)), "std": float(np.std(x, ddof=1)) if n > 1 else None,
            "rmse": float(np.sqrt(np.mean(x * x))), "max_abs": float(np.max(np.abs(x))),
            "min": float(np.min(x)), "max": float(np.max(x))}


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


def _na(test: str, comp: str, name: str, alpha: float | None, reason: str, **details: Any) -> TestResult:
    return TestResult(test, comp, name, None, None, None, alpha, False, reason, dict(details))


def _sample(x: Any) -> np.ndarray:
    return np.asarray(x, dtype=float).ravel()


def _zero_var(x: np.ndarray) -> bool:
    return x.size > 0 and float(np.ptp(x)) <= 1e-12 * max(1.0, float(np.max(np.abs(x))))


def _precheck(test: str, comp: str, name: str, alpha: float, x: np.ndarray, min_n: int) -> TestResult | None:
    """The *not applicable* result of a 1-D test on *x*, or None when it can be computed."""
    n = x.size
    if n < min_n:
        return _na(test, comp, name, alpha, f"needs at least {min_n} points, got {n}", n=n)
    if _zero_var(x):
        return _na(test, comp, name, alpha, "zero variance: all discrepancies are equal", n=n)
    return None


def _precheck_en(test: str, name: str, alpha: float, x: np.ndarray, min_n: int) -> TestResult | None:
    """The *not applicable* result of a test on (dE, dN) rows *x* (n, 2), or None when it can be computed."""
    n = x.shape[0]
    if n < min_n:
        return _na(test, "EN", name, alpha, f"needs at least {min_n} points, got {n}", n=n)
    if not _nonsingular(np.cov(x, rowvar=False, ddof=1)):
        return _na(test, "EN", name, alpha,
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
            crit = _std.filliben_critical_value(n, alpha)
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


def _lilliefors_d(z: np.ndarray) -> np.ndarray:
    """Row-wise K-S distance to N(mean, s) with estimated parameters; z (M, n)."""
    n = z.shape[1]
    zs = np.sort(z, axis=1)
    u = (zs - zs.mean(axis=1, keepdims=True)) / zs.std(axis=1, ddof=1, keepdims=True)
    f = stats.norm.cdf(u)
    i = np.arange(1, n + 1)
    return np.maximum(np.max(i / n - f, axis=1), np.max(f - (i - 1) / n, axis=1))


@functools.lru_cache(maxsize=64)
def _lilliefors_null(n: int, n_sim: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    sim = np.concatenate([_lilliefors_d(rng.standard_normal((m, n))) for m in _chunks(n_sim, n)])
    sim.setflags(write=False)
    return sim


def lilliefors_test(x: Any, alpha: float = 0.10, *, n_sim: int = 20000, seed: int = 0,
                    component: str = "x") -> TestResult:
    """Lilliefors (K-S with estimated mean and sd) normality test.

    The null distribution of D is simulated (``n_sim`` seeded normal samples of
    the same size), giving the critical value (1 - alpha quantile) and the
    p-value; deterministic for a given seed.
    """
    x = _sample(x)
    n = x.size
    na = _precheck("lilliefors", component, "D", alpha, x, 4)
    if na is not None:
        return na
    d = float(_lilliefors_d(x[None, :])[0])
    sim = _lilliefors_null(n, n_sim, seed)
    crit = float(np.quantile(sim, 1 - alpha))
    p = float((1 + np.sum(sim >= d - 1e-15)) / (n_sim + 1))
    return TestResult("lilliefors", component, "D", d, crit, bool(d <= crit), alpha, details={
        "n": n, "p_value": p, "method": f"Lilliefors, Monte-Carlo null ({n_sim} samples, seed {seed})"})


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
        return _na("chi2_precision", component, "chi2", alpha,
                   "no expected standard deviation: give the map scale (and contour interval for h)", n=n)
    if not sigma0 > 0:
        return _na("chi2_precision", component, "chi2", alpha, f"sigma0 must be positive, got {sigma0}", n=n)
    if n < 2:
        return _na("chi2_precision", component, "chi2", alpha, f"needs at least 2 points, got {n}", n=n)
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
        return _na("consistency", "ENh", "chi2", alpha,
                   f"covariance has shape {c.shape}, expected ({n}, {n})")
    if n == 0 or not np.all(np.isfinite(c)) or not np.all(np.isfinite(x)):
        return _na("consistency", "ENh", "chi2", alpha, "no discrepancies or a non-finite covariance")
    try:
        L = np.linalg.cholesky(0.5 * (c + c.T))
    except np.linalg.LinAlgError:
        return _na("consistency", "ENh", "chi2", alpha, "covariance of the discrepancies is not positive definite")
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
        return _na("ce90", method, "radius", None, f"needs at least {need[method]} points, got {n}", n=n)
    if method != "empirical" and _zero_var(x[:, 0]) and _zero_var(x[:, 1]):
        return _na("ce90", method, "radius", None, "zero variance of dE and dN", n=n)
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
        r = _std.circular_error_radius(prob, x.mean(axis=0), np.cov(x, rowvar=False, ddof=1))
        details["mean"] = x.mean(axis=0).tolist()
    details["fraction_within"] = float(np.mean(dp <= r + 1e-12))
    if limit_m is None:
        return TestResult("ce90", method, "radius", r, None, None, None, True, None, details)
    details["critical_source"] = limit_source
    return TestResult("ce90", method, "radius", r, limit_m, bool(r <= limit_m + 1e-9), None, True, None, details)


# ----------------------------------------------------------------------------- assessment


def _consistency(sel: Sequence[str], adjusted_cov: Any, d: np.ndarray, ref_sd: np.ndarray | None,
                 alpha: float) -> TestResult:
    try:
        ids, c = adjusted_cov
        c = np.asarray(c, dtype=float)
    except (TypeError, ValueError) as ex:
        raise AssessmentError(f"adjusted_cov must be (ids, (3k, 3k) covariance array) ({ex})") from None
    if c.shape != (3 * len(ids), 3 * len(ids)):
        raise AssessmentError(f"adjusted_cov: covariance of shape {c.shape} for {len(ids)} point ids; "
                              f"expected ({3 * len(ids)}, {3 * len(ids)}) (E, N, h of each point)")
    pos = {str(q): i for i, q in enumerate(ids)}
    missing = [q for q in sel if q not in pos]
    if missing:
        return _na("consistency", "ENh", "chi2", alpha,
                   f"no adjusted covariance for check point(s) {', '.join(missing[:5])}")
    if ref_sd is None or not np.all(np.isfinite(ref_sd)):
        return _na("consistency", "ENh", "chi2", alpha, "the reference has no sd_E, sd_N, sd_h columns")
    idx = np.array([[3 * pos[q] + k for k in range(3)] for q in sel]).ravel()
    c = c[np.ix_(idx, idx)] + np.diag(np.asarray(ref_sd, dtype=float).ravel() ** 2)
    return covariance_consistency_test(d, c, alpha, source="joint covariance of the adjusted check "
                                       "points + reference sds (independent)")


@dataclass(frozen=True, eq=False)
class Assessment:
    """Result of :func:`assess`.

    Attributes
    ----------
    points : tuple of str
        Check-point ids, in order.
    adjusted, reference : (N, 3) arrays
        Coordinates (m).
    d : (N, 3) array
        Discrepancies dE, dN, dh (m) with the ``sign`` convention.
    planimetric : (N,) array
        Resultants dP (m).
    reference_sd : (N, 3) array or None
    summary : dict
        ``{component: summarize(...)}`` for E, N, h, planimetric.
    tests : dict
        ``{test: {component: TestResult}}``.
    standards : dict
        ``{name: StandardResult}``.
    settings : dict
        The options used (sign, scale, contour interval, alpha, ...).
    notes : tuple of str
        Warnings and the open items the results depend on.
    """

    points: tuple[str, ...]
    adjusted: np.ndarray
    reference: np.ndarray
    d: np.ndarray
    planimetric: np.ndarray
    reference_sd: np.ndarray | None
    summary: dict[str, dict[str, Any]]
    tests: dict[str, dict[str, TestResult]]
    standards: dict[str, _std.StandardResult]
    settings: dict[str, Any]
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("adjusted", "reference", "d", "planimetric", "reference_sd"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, frozen_array(v))

    @property
    def n(self) -> int:
        return len(self.points)

    def point_rows(self) -> list[dict[str, Any]]:
        """Per-point table: id, reference and adjusted E, N, h, dE, dN, dh, dP."""
        rows = []
        for k, p in enumerate(self.points):
            rows.append({"point": p,
                         "E_ref": float(self.reference[k, 0]), "N_ref": float(self.reference[k, 1]),
                         "h_ref": float(self.reference[k, 2]),
                         "E_adj": float(self.adjusted[k, 0]), "N_adj": float(self.adjusted[k, 1]),
                         "h_adj": float(self.adjusted[k, 2]),
                         "dE": float(self.d[k, 0]), "dN": float(self.d[k, 1]), "dh": float(self.d[k, 2]),
                         "dP": float(self.planimetric[k])})
        return rows

    def to_dict(self) -> dict[str, Any]:
        """The JSON layout of ``lidarcat assess --json``.

        Keys: ``summary`` {E, N, h, planimetric: {n, mean, std, rmse, max_abs,
        min, max}}, ``tests`` {test: {component: {statistic, critical, passed,
        ...}}}, ``standards`` {name: {class, label, evidence, notes, ...}},
        ``points`` (per-point table), ``settings``, ``notes``.
        """
        return {
            "summary": {k: dict(v) for k, v in self.summary.items()},
            "tests": {t: {c: r.to_dict() for c, r in comps.items()} for t, comps in self.tests.items()},
            "standards": {k: v.to_dict() for k, v in self.standards.items()},
            "points": self.point_rows(),
            "settings": dict(self.settings),
            "notes": list(self.notes),
        }


def assess(adjusted: Any, reference: Any, *, points: Iterable[str] | None = None,
           sign: str = "reference_minus_adjusted", scale: float | None = 2000,
           contour_interval_m: float | None = None,
           standards: Sequence[str] = ("pec", "pec-pcd", "asprs2014", "asprs2023", "nssda"),
           alpha: float = 0.10, plotting_position: str = "filliben", filliben_critical: str = "table",
           pec_class: str = "A", checkpoint_sd_m: Any = None,
           asprs_target_cm: Mapping[str, float] | None = None, lilliefors_n_sim: int = 20000,
           seed: int = 0, adjusted_cov: Any = None, consistency: TestResult | None = None) -> Assessment:
    """Assess adjusted coordinates against reference (check-point) coordinates.

    Parameters
    ----------
    adjusted, reference
        Points as accepted by :func:`read_points` (CSV path with ``point, E, N,
        h``, mapping, ``(ids, xyz)`` or (N, 3) array).
    points : iterable of str, optional
        Check-point ids.  Default: the ``role == check`` points of *adjusted*
        when it has a role column, otherwise every reference point that is not
        a control point of *adjusted*.
    sign : {"reference_minus_adjusted", "adjusted_minus_reference"}
        Discrepancy convention; the thesis uses reference minus adjusted.
    scale : float or None
        Map scale denominator for PEC classes, the chi-square sigma0 and the
        CE90 limit (2000 in the thesis).  None: those are not applicable.
    contour_interval_m : float, optional
        Contour interval for the altimetric PEC (2 m in the thesis).  None:
        the standard's default for the scale, when it has one (said in notes).
    standards : sequence of str
        Any of ``pec``, ``pec-pcd``, ``asprs2014``, ``asprs2023``, ``nssda``.
    alpha : float
        Level of every test (0.10 in the thesis).
    plotting_position : {"filliben", "hazen", "blom"}
        Filliben test positions; ``hazen`` reproduces the thesis's Z_i.
    filliben_critical : {"table", "montecarlo"}
    pec_class : str
        Decreto class whose EP is sigma0 of the chi-square test and whose PEC
        limits the CE90 radius ("A" in the thesis).
    checkpoint_sd_m : (N, 3) or (3,) array, optional
        Check-point survey sds for ASPRS 2023; default: the reference's
        ``sd_E, sd_N, sd_h`` columns when present.
    asprs_target_cm : dict, optional
        ``{"planimetric": X, "altimetric": Y}`` ASPRS classes to test.
    lilliefors_n_sim, seed : int
        Monte-Carlo size and seed of the Lilliefors null distribution.
    adjusted_cov : (ids, (3k, 3k) array), optional
        Joint covariance of the adjusted check points (m^2; the
        ``check_covariance.csv`` of an adjustment, see
        :func:`lidarcat.bundle.read_point_covariance`).  With it, and the
        reference sds, the ``consistency`` test compares the discrepancies with
        the precision claimed (:func:`covariance_consistency_test`).
    consistency : TestResult, optional
        That test already computed (or not applicable, with its reason) where
        the joint covariance was at hand but not written (``lidarcat run``
        above :data:`lidarcat.bundle.MAX_JOINT_COVARIANCE_POINTS` check
        points); used when *adjusted_cov* is not given.

    Returns
    -------
    Assessment

    Raises
    ------
    AssessmentError
        Unreadable input, mismatched point ids (the message names them),
        invalid options.  Tests that cannot be computed are *not applicable*
        in the result, not errors.
    """
    if sign not in SIGNS:
        raise AssessmentError(f"sign must be one of {', '.join(SIGNS)}, got {sign!r}")
    if not 0 < alpha < 1:
        raise AssessmentError(f"alpha must be in (0, 1), got {alpha}")
    plotting_positions(3, plotting_position)
    std_names = [s.lower() for s in standards]
    for s in std_names:
        if s not in _std.STANDARD_NAMES:
            raise AssessmentError(f"unknown standard {s!r}; choose from {', '.join(_std.STANDARD_NAMES)}")
    adj = read_points(adjusted, "adjusted")
    ref = read_points(reference, "reference")
    sel = _select(adj, ref, points)
    ai, ri = adj.index(), ref.index()
    ia = np.array([ai[p] for p in sel])
    ir = np.array([ri[p] for p in sel])
    a_xyz, r_xyz = adj.xyz[ia], ref.xyz[ir]
    d = discrepancies(a_xyz, r_xyz, sign)
    dp = np.hypot(d[:, 0], d[:, 1])
    ref_sd = ref.sd[ir] if ref.sd is not None else None
    notes: list[str] = []
    n = len(sel)

    summary = {"E": summarize(d[:, 0]), "N": summarize(d[:, 1]), "h": summarize(d[:, 2]),
               "planimetric": summarize(dp)}

    # tolerances of the target Decreto class (thesis: class A at 1:2000, Eq 2 m)
    tol = None
    if scale is not None:
        tol_all = _std.pec_tolerances("pec", scale, contour_interval_m)
        if pec_class not in tol_all:
            raise AssessmentError(f"pec_class must be one of {', '.join(tol_all)}, got {pec_class!r}")
        tol = tol_all[pec_class]
    else:
        notes.append("no map scale given: PEC classes, the chi-square test and the CE90 limit are not applicable")

    comps = {"E": d[:, 0], "N": d[:, 1], "h": d[:, 2], "planimetric": dp}
    tests: dict[str, dict[str, TestResult]] = {}
    tests["filliben"] = {c: filliben_test(comps[c], alpha, plotting_position, critical=filliben_critical,
                                          component=c) for c in COMPONENTS}
    tests["ks"] = {c: ks_test(comps[c], alpha, component=c) for c in COMPONENTS}
    tests["ks"]["EN"] = ks_mahalanobis_test(d[:, :2], alpha)
    tests["lilliefors"] = {c: lilliefors_test(comps[c], alpha, n_sim=lilliefors_n_sim, seed=seed, component=c)
                           for c in COMPONENTS}
    tests["trend_t"] = {c: trend_t_test(comps[c], alpha, component=c) for c in ("E", "N", "h")}
    ep_p = tol["plan_ep_m"] if tol else None
    ep_h = tol["alt_ep_m"] if tol else None
    cls_txt = f"Decreto 89.817 class {pec_class} at 1:{scale:g}" if tol else ""
    tests["chi2_precision"] = {
        "planimetric": chi2_precision_test(dp, ep_p, alpha, component="planimetric",
                                           sigma0_source=f"EP planimetric, {cls_txt} (thesis 3.3.4)"),
        "h": chi2_precision_test(d[:, 2], ep_h, alpha, component="h",
                                 sigma0_source=f"EP altimetric, {cls_txt}, Eq {tol['eq_m']:g} m (thesis 3.3.4)"
                                 if tol and tol["eq_m"] else ""),
        "E": chi2_precision_test(d[:, 0], ep_p / math.sqrt(2) if ep_p else None, alpha, component="E",
                                 sigma0_source=f"EP planimetric / sqrt(2), {cls_txt}"),
        "N": chi2_precision_test(d[:, 1], ep_p / math.sqrt(2) if ep_p else None, alpha, component="N",
                                 sigma0_source=f"EP planimetric / sqrt(2), {cls_txt}"),
    }
    tests["hotelling"] = {"EN": hotelling_t2_test(d[:, :2], alpha)}
    if adjusted_cov is not None:
        tests["consistency"] = {"ENh": _consistency(sel, adjusted_cov, d, ref_sd, alpha)}
    elif consistency is not None:  # computed where the joint covariance was at hand, not written
        tests["consistency"] = {"ENh": consistency}
    lim = tol["plan_pec_m"] if tol else None
    lim_src = f"planimetric PEC, {cls_txt}" if tol else ""
    tests["ce90"] = {m: ce90(d[:, :2], m, limit_m=lim, limit_source=lim_src)
                     for m in ("empirical", "circular", "bivariate_exact")}

    if checkpoint_sd_m is None and ref_sd is not None and np.all(np.isfinite(ref_sd)):
        checkpoint_sd_m = ref_sd
    std_results: dict[str, _std.StandardResult] = {}
    for s in std_names:
        if s in ("pec", "pec-pcd") and scale is None:
            continue
        std_results[s] = _std.classify(s, d, scale=scale, contour_interval_m=contour_interval_m, alpha=alpha,
                                       checkpoint_sd_m=checkpoint_sd_m, target_cm=asprs_target_cm)
    if plotting_position != "filliben" and filliben_critical == "table":
        notes.append(f"Filliben test with {plotting_position} plotting positions against the Filliben (1975) "
                     "table (thesis mode): the real size differs slightly from alpha (about 9.5 % instead of "
                     "10 % at n = 21 for hazen)")
    notes.append("chi-square sigma0: the thesis takes the Erro Padrao (EP) as the standard deviation "
                 "(section 3.3.4); applied to the planimetric resultant and to h; E and N use EP/sqrt(2) "
                 "(STANDARDS.md open item 2)")
    if n < 20:
        notes.append(f"{n} check points: NSSDA asks for >= 20, ASPRS 2023 for >= 30")
    settings = {"sign": sign, "scale": scale, "contour_interval_m": contour_interval_m, "alpha": alpha,
                "plotting_position": plotting_position, "filliben_critical": filliben_critical,
                "pec_class": pec_class, "standards": std_names, "n": n,
                "adjusted_source": adj.source, "reference_source": ref.source,
                "lilliefors_n_sim": lilliefors_n_sim, "seed": seed}
    log.info("assessed %d check points (%s)", n, sign)
    return Assessment(tuple(sel), a_xyz, r_xyz, d, dp, ref_sd, summary, tests, std_results, settings,
                      tuple(notes))
