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

import logging
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import standards as _std
from .statistics import (
    PLOTTING_POSITIONS,  # noqa: F401  (importable from here, as before the split)
    TestResult,
    ce90,
    chi2_precision_test,
    covariance_consistency_test,
    filliben_test,
    hotelling_t2_test,
    ks_mahalanobis_test,
    ks_test,
    lilliefors_test,
    not_applicable,
    plotting_positions,
    trend_t_test,
)
from .._util.frozen import frozen_array
from .._util import read_csv_table
from ..errors import AssessmentError, location

__all__ = [
    "COMPONENTS",
    "SIGNS",
    "PointSet",
    "Assessment",
    "read_points",
    "discrepancies",
    "summarize",
    "assess",
]

log = logging.getLogger(__name__)

#: summary components, in report order
COMPONENTS: tuple[str, ...] = ("E", "N", "h", "planimetric")
SIGNS: tuple[str, ...] = ("reference_minus_adjusted", "adjusted_minus_reference")
_CONTROL_ROLES = {"control", "fixed", "fixo"}
#: the largest standard deviation of a point accepted, m (the survey's own bound, survey.schema.SD_BOUNDS)
MAX_SD_M = 1e3
#: the largest coordinate magnitude accepted, m (ten times the Earth's circumference: any projected
#: or geocentric coordinate, any local frame; beyond it squares and sums lose all digits)
MAX_COORDINATE_M = 4e8


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
        _check_range(table, xyz, ("E", "N", "h"), -MAX_COORDINATE_M, MAX_COORDINATE_M, "a coordinate")
        sd = None
        if all(table.has(c) for c in ("sd_E", "sd_N", "sd_h")):
            sd = np.column_stack([table.floats(c, required=False) for c in ("sd_E", "sd_N", "sd_h")])
            _check_range(table, sd, ("sd_E", "sd_N", "sd_h"), 0.0, MAX_SD_M, "a standard deviation")
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


def _check_range(table: Any, arr: np.ndarray, names: Sequence[str], lo: float, hi: float, what: str) -> None:
    """Refuse a value of the columns *names* outside ``[lo, hi]`` m, naming file, line and field
    (NaN, an empty optional cell, passes)."""
    with np.errstate(invalid="ignore"):
        bad = np.argwhere((arr < lo) | (arr > hi))
    if len(bad):
        i, k = (int(v) for v in bad[0])
        raise AssessmentError(f"{location(table.path, table.lines[i], names[k])}: {float(arr[i, k])!r} m is not "
                              f"{what} (sane values lie in {lo:g}..{hi:g} m)")


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
        return not_applicable("consistency", "ENh", "chi2", alpha,
                   f"no adjusted covariance for check point(s) {', '.join(missing[:5])}")
    if ref_sd is None or not np.all(np.isfinite(ref_sd)):
        return not_applicable("consistency", "ENh", "chi2", alpha, "the reference has no sd_E, sd_N, sd_h columns")
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
