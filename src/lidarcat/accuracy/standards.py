"""Map-accuracy standards: PEC (Decreto 89.817), PEC-PCD, ASPRS 2014 / 2023, NSSDA.

The class tables are versioned data files in ``lidarcat/standards_data/``
(one JSON file per standard, each with ``version``, ``sources``,
``confidence`` and ``open_items``) and the Filliben (1975) critical values in
``filliben1975_critical_values.csv``.  Nothing here hard-codes a class value.

Every classifier takes check-point discrepancies ``d`` (N, 3) in metres,
columns (dE, dN, dh), and returns a :class:`StandardResult` whose ``classes``
hold the planimetric (horizontal) and altimetric (vertical) class and whose
``evidence`` holds every number the decision used.  Open items of the
specification are repeated in ``notes`` so that a report states them.

Rules (details and sources in ``docs/accuracy.md``):

* **PEC / PEC-PCD**: a class passes when at least 90 % of the points have
  ``|d| <= PEC`` (planimetry on the resultant ``dP = hypot(dE, dN)``,
  altimetry on ``|dh|``) and the RMS is ``<= EP``.  The best passing class is
  reported, otherwise ``"none"`` with the EP found (Art. 10).
* **NSSDA**: ``Accuracy_r = 1.7308 RMSE_r`` (equal axes), ``2.4477 * 0.5 *
  (RMSE_x + RMSE_y)`` when ``RMSE_min / RMSE_max >= 0.6``, the exact 95 %
  circle of the bivariate normal below; ``Accuracy_z = 1.96 RMSE_z``.
* **ASPRS 2014**: horizontal class X-cm needs ``RMSE_x, RMSE_y <= X``,
  vertical ``RMSE_z <= X``.  **ASPRS 2023**: ``RMSE_H = hypot(RMSE_x, RMSE_y)``
  plus the check-point survey error, ``RMSE = sqrt(fit^2 + survey^2)``.

>>> tol = pec_tolerances("pec", 10000)
>>> tol["A"]["plan_pec_m"], tol["A"]["plan_ep_m"]
(5.0, 3.0)
>>> round(asprs2023_product_rmse(1.00, 2.0), 2)
2.24
>>> filliben_critical_value(21, 0.10)
0.961
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from .._util.formatting import format_number
from ..errors import AssessmentError
from .statistics import chi2_precision_test, circular_error_radius, filliben_critical_value, filliben_table

__all__ = [
    "STANDARD_NAMES",
    "StandardResult",
    "load_standard",
    "pec_tolerances",
    "filliben_critical_value",
    "filliben_table",
    "circular_error_radius",
    "asprs2023_product_rmse",
    "nssda_horizontal_accuracy",
    "ce90_le90",
    "classify_pec",
    "classify_nssda",
    "classify_asprs2014",
    "classify_asprs2023",
    "classify",
    "CONFIDENCE_LABELS",
    "notes_path",
]

#: standard names accepted by :func:`classify` (and ``lidarcat assess --standard``)
STANDARD_NAMES: tuple[str, ...] = ("pec", "pec-pcd", "asprs2014", "asprs2023", "nssda")

_FILES = {"pec": "pec_decreto_89817.json", "pec-pcd": "pec_pcd.json",
          "asprs2014": "asprs.json", "asprs2023": "asprs.json", "nssda": "nssda.json"}
_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)
_EPS = 1e-9  # tolerance for "<=" against printed table values (metres)


#: the confidence labels of the standards' rules (``StandardResult.confidence``, ``[K]`` in notes)
CONFIDENCE_LABELS: dict[str, str] = {
    "P": "primary text of the standard read",
    "S": "secondary source (implementation, article) agrees; the standard itself not seen",
    "K": "domain knowledge, not confirmed against the standard: check before relying on it",
    "V": "computed or verified by the project",
}


def notes_path() -> Path:
    """STANDARDS.md, the notes the reports cite (rules, sources, confidence labels, open items).

    In an installed wheel ``lidarcat/standards_data/STANDARDS.md``; in a source checkout
    ``docs/standards.md`` (the same file).
    """
    shipped = Path(str(resources.files("lidarcat") / "standards_data" / "STANDARDS.md"))
    if shipped.is_file():
        return shipped
    return Path(__file__).resolve().parents[3] / "docs" / "standards.md"


# ----------------------------------------------------------------------------- data


def _data_text(name: str) -> str:
    return (resources.files("lidarcat") / "standards_data" / name).read_text(encoding="utf-8")


@functools.lru_cache(maxsize=None)
def _load_json(name: str) -> str:
    return _data_text(name)


def load_standard(name: str) -> dict[str, Any]:
    """Return the data table of standard *name* (a fresh dict).

    Raises
    ------
    AssessmentError
        Unknown name (the message lists the known names).
    """
    key = name.lower()
    if key not in _FILES:
        raise AssessmentError(f"unknown standard {name!r}; choose from {', '.join(STANDARD_NAMES)}")
    data = json.loads(_load_json(_FILES[key]))
    if key.startswith("asprs"):
        data = data[key]
    return data


# ----------------------------------------------------------------------------- tolerances


def _frac(text: str | float) -> float:
    return float(Fraction(str(text))) if isinstance(text, str) else float(text)


def pec_tolerances(standard: str, scale: float, contour_interval_m: float | None = None
                   ) -> dict[str, dict[str, Any]]:
    """Ground tolerances (m) of every class of ``"pec"`` or ``"pec-pcd"``.

    Parameters
    ----------
    standard : {"pec", "pec-pcd"}
    scale : float
        Scale denominator (2000 for 1:2 000).  Any positive value.
    contour_interval_m : float, optional
        Contour interval Eq (m).  ``None``: the per-scale default of the data
        table when the scale is tabulated (the result says so in
        ``eq_source``), otherwise the altimetric values are ``None``.

    Returns
    -------
    dict
        ``{class: {plan_pec_m, plan_ep_m, alt_pec_m, alt_ep_m, eq_m, eq_source}}``.

    >>> t = pec_tolerances("pec-pcd", 25000, 10)
    >>> t["A"]["plan_pec_m"], t["A"]["plan_ep_m"], t["A"]["alt_pec_m"], round(t["A"]["alt_ep_m"], 3)
    (7.0, 4.25, 2.7, 1.667)
    """
    data = load_standard(standard)
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise AssessmentError(f"scale must be a positive scale denominator (e.g. 2000), got {scale!r}")
    eq = contour_interval_m
    eq_source = "given"
    if eq is None:
        key = str(int(scale)) if float(scale).is_integer() else str(scale)
        default = data.get("default_contour_interval_m", {}).get(key)
        if default is not None:
            eq, eq_source = float(default), f"default for 1:{key} ({data.get('default_contour_interval_note', '')})"
        else:
            eq_source = "none (give a contour interval for altimetry)"
    elif not (math.isfinite(eq) and eq > 0):
        raise AssessmentError(f"contour interval must be positive (m), got {eq!r}")
    out: dict[str, dict[str, Any]] = {}
    for cls, row in data["classes"].items():
        out[cls] = {
            "plan_pec_m": round(row["plan_pec_mm"] * scale / 1000.0, 9),
            "plan_ep_m": round(row["plan_ep_mm"] * scale / 1000.0, 9),
            "alt_pec_m": None if eq is None else round(_frac(row["alt_pec_eq"]) * eq, 9),
            "alt_ep_m": None if eq is None else round(_frac(row["alt_ep_eq"]) * eq, 9),
            "eq_m": eq,
            "eq_source": eq_source,
        }
    return out


# ----------------------------------------------------------------------------- results


@dataclass(frozen=True, eq=False)
class StandardResult:
    """Classification by one standard.

    Attributes
    ----------
    name : str
        ``pec``, ``pec-pcd``, ``asprs2014``, ``asprs2023`` or ``nssda``.
    title, version : str
        From the data file.
    classes : dict
        ``{"planimetric": str | None, "altimetric": str | None}``; ``"none"``
        when no class is met, ``None`` when not evaluated (reason in notes).
    label : str
        One-line statement in the standard's wording.
    evidence : dict
        Every number used (tolerances, fractions, RMS, statistics).
    notes : tuple of str
        Open items of the specification and warnings (sample size...).
    """

    name: str
    title: str
    version: str
    classes: dict[str, str | None]
    label: str
    evidence: dict[str, Any]
    notes: tuple[str, ...] = ()
    sources: tuple[str, ...] = ()
    confidence: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"class": dict(self.classes), "label": self.label, "evidence": self.evidence,
                "notes": list(self.notes), "title": self.title, "version": self.version,
                "sources": list(self.sources), "confidence": self.confidence}


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def _check_d(d: np.ndarray) -> np.ndarray:
    d = np.asarray(d, dtype=float)
    if d.ndim != 2 or d.shape[1] != 3:
        raise AssessmentError(f"discrepancies must be an (N, 3) array of dE, dN, dh; got shape {d.shape}")
    if d.shape[0] == 0:
        raise AssessmentError("no check points: at least one discrepancy is needed")
    if not np.all(np.isfinite(d)):
        raise AssessmentError("discrepancies contain NaN or infinite values")
    return d


def _result(name: str, data: Mapping[str, Any], classes: dict[str, str | None], label: str,
            evidence: dict[str, Any], notes: Sequence[str]) -> StandardResult:
    return StandardResult(name, data["title"], data["version"], classes, label, evidence, tuple(notes),
                          tuple(data.get("sources", ())), data.get("confidence", ""))


def _chi2_row(x: np.ndarray, sigma0: float | None, alpha: float) -> dict[str, Any]:
    """The thesis chi-square precision test (eq. 46) as PEC evidence; None values when not applicable."""
    t = chi2_precision_test(x, sigma0, alpha)
    return {"chi2": t.statistic, "chi2_critical": t.critical, "chi2_passed": t.passed}


def classify_pec(d: np.ndarray, scale: float, contour_interval_m: float | None = None, *,
                 standard: str = "pec", alpha: float = 0.10) -> StandardResult:
    """Classify by the Decreto 89.817 PEC (``standard="pec"``) or the PEC-PCD.

    The class (``classes``) follows the 90 % + RMS rule.  The evidence also
    lists, per class, the thesis chi-square test (eq. 46 with sigma0 = EP on
    the planimetric resultant and on h) and the best class it would give
    (``chi2_class``), because the literature mixes the two rules.

    Parameters
    ----------
    d : (N, 3) array
        Discrepancies dE, dN, dh (m).
    scale : float
        Scale denominator.
    contour_interval_m : float, optional
        Contour interval (m) for the altimetric classes.
    standard : {"pec", "pec-pcd"}
    alpha : float
        Level of the chi-square evidence.

    >>> d = np.array([[0.1, 0.0, 0.2], [0.0, -0.2, -0.1], [0.3, 0.1, 0.0]])
    >>> classify_pec(d, 2000, 2.0).classes
    {'planimetric': 'A', 'altimetric': 'A'}
    """
    d = _check_d(d)
    data = load_standard(standard)
    tol = pec_tolerances(standard, scale, contour_interval_m)
    dp = np.hypot(d[:, 0], d[:, 1])
    dh = d[:, 2]
    frac_needed = float(data["pass_fraction"])
    rows = []
    best = {"planimetric": "none", "altimetric": "none"}
    best_chi = {"planimetric": "none", "altimetric": "none"}
    rms_p, rms_h = _rms(dp), _rms(dh)
    for cls, t in tol.items():
        row: dict[str, Any] = {"class": cls}
        for comp, err, rms, pec, ep in (("planimetric", dp, rms_p, t["plan_pec_m"], t["plan_ep_m"]),
                                        ("altimetric", np.abs(dh), rms_h, t["alt_pec_m"], t["alt_ep_m"])):
            if pec is None:
                row[comp] = None
                continue
            frac = float(np.mean(err <= pec + _EPS))
            ok90 = frac >= frac_needed - 1e-12
            okep = rms <= ep + _EPS
            chi = _chi2_row(dp if comp == "planimetric" else dh, ep, alpha)
            row[comp] = {"pec_m": pec, "ep_m": ep, "fraction_within_pec": frac, "rms_m": rms,
                         "passed_90_percent": ok90, "passed_ep": okep, "passed": ok90 and okep,
                         "sigma0_m": ep, **chi}
            if ok90 and okep and best[comp] == "none":
                best[comp] = cls
            if chi["chi2_passed"] and best_chi[comp] == "none":
                best_chi[comp] = cls
        rows.append(row)
    eq = next(iter(tol.values()))
    classes: dict[str, str | None] = dict(best)
    notes = []
    lft = data.get("lftools_class_a_altimetric_m", {})
    for item in data.get("open_items", ()):
        # the PEC-PCD class-A item only matters at the scales where LFTools differs
        if "open item 1" in item and str(int(scale) if float(scale).is_integer() else scale) not in lft:
            continue
        notes.append(item)
    if eq["eq_m"] is None:
        classes["altimetric"] = None
        best_chi["altimetric"] = None
        notes.append("altimetric class not evaluated: no contour interval given for this scale")
    elif eq["eq_source"] != "given":
        notes.append(f"contour interval {eq['eq_m']:g} m assumed: {eq['eq_source']}")
    n = d.shape[0]
    if n < 20:
        notes.append(f"only {n} check points; the 90 % rule is coarse for small samples "
                     f"(one point is {100 / n:.1f} % of the sample)")
    label_parts = []
    for comp, rms in (("planimetric", rms_p), ("altimetric", rms_h)):
        c = classes[comp]
        if c is None:
            continue
        if c == "none":
            label_parts.append(f"{comp}: no class (EP found {rms:.3f} m)")
        else:
            label_parts.append(f"{comp}: class {c}")
    label = f"1:{scale:g} " + "; ".join(label_parts)
    evidence = {"scale": scale, "contour_interval_m": eq["eq_m"], "contour_interval_source": eq["eq_source"],
                "n": n, "rms_planimetric_m": rms_p, "rms_h_m": rms_h, "pass_fraction": frac_needed,
                "classes": rows, "chi2_class": best_chi, "alpha": alpha}
    return _result(standard, data, classes, label, evidence, notes)


def nssda_horizontal_accuracy(rmse_x: float, rmse_y: float) -> tuple[float, str]:
    """NSSDA horizontal accuracy at 95 % and the formula used.

    >>> acc, how = nssda_horizontal_accuracy(1.0, 1.0)
    >>> round(acc, 4), how
    (2.4477, 'case 1: 1.7308 RMSE_r')
    >>> round(nssda_horizontal_accuracy(1.0, 0.7)[0], 4)
    2.0805
    """
    data = load_standard("nssda")
    big, small = max(rmse_x, rmse_y), min(rmse_x, rmse_y)
    rmse_r = math.hypot(rmse_x, rmse_y)
    if big == 0:
        return 0.0, "case 1: 1.7308 RMSE_r"
    if math.isclose(rmse_x, rmse_y, rel_tol=1e-9):
        return data["horizontal_factor_rmse_r"] * rmse_r, "case 1: 1.7308 RMSE_r"
    if small / big >= data["ratio_switch"]:
        return data["horizontal_factor_sigma"] * 0.5 * (rmse_x + rmse_y), \
            "case 2: 2.4477 * 0.5 * (RMSE_x + RMSE_y) (ratio >= 0.6)"
    r = circular_error_radius(0.95, (0.0, 0.0), np.diag([rmse_x ** 2, rmse_y ** 2]))
    return r, "ratio < 0.6: exact 95 % circle of N(0, diag(RMSE_x^2, RMSE_y^2))"


def ce90_le90(d: Any) -> dict[str, Any]:
    """CE90 and LE90 of check-point discrepancies: the 90 % circular (plan) and linear (height) errors.

    Two readings, as the NGA/ASPRS practice reports them (CE90/LE90 of MIL-STD-600001):

    * **empirical**: the 90th percentile of the radial errors ``sqrt(dE^2 + dN^2)`` and of
      ``|dh|`` (numpy's linear interpolation between order statistics);
    * **from the RMSE** under normal errors with zero mean: LE90 = 1.6449 RMSE_h (the
      two-sided 90 % point of N(0, 1)); CE90 the radius of the 90 % circle of
      N(0, diag(RMSE_E^2, RMSE_N^2)), which is 2.1460 RMSE_E (= 1.5174 RMSE_r) when the two
      RMSEs are equal (:func:`circular_error_radius`, exact for any ratio).

    Parameters
    ----------
    d : (n, 3) array
        dE, dN, dh of the check points, m.

    Returns
    -------
    dict
        ``n``, ``ce90_m``, ``le90_m`` (from the RMSE), ``ce90_empirical_m``, ``le90_empirical_m``.

    >>> r = ce90_le90(np.array([[1.0, 0, 1], [-1, 0, -1], [0, 1, 1], [0, -1, -1]]))
    >>> round(r["ce90_m"], 4), round(r["le90_m"], 4), r["ce90_empirical_m"], r["le90_empirical_m"]
    (1.5174, 1.6449, 1.0, 1.0)
    """
    d = _check_d(np.asarray(d, dtype=np.float64))
    rx, ry, rh = _axis_rmse(d)
    if rx == 0 and ry == 0:
        ce = 0.0
    else:
        ce = circular_error_radius(0.90, (0.0, 0.0), np.diag([rx ** 2, ry ** 2]))
    return {"n": int(len(d)), "ce90_m": float(ce), "le90_m": float(1.6448536269514722 * rh),
            "ce90_empirical_m": float(np.percentile(np.hypot(d[:, 0], d[:, 1]), 90)),
            "le90_empirical_m": float(np.percentile(np.abs(d[:, 2]), 90))}


def _axis_rmse(d: np.ndarray) -> tuple[float, float, float]:
    return _rms(d[:, 0]), _rms(d[:, 1]), _rms(d[:, 2])


def classify_nssda(d: np.ndarray) -> StandardResult:
    """NSSDA (FGDC-STD-007.3-1998) horizontal and vertical accuracy at 95 %."""
    d = _check_d(d)
    data = load_standard("nssda")
    rx, ry, rz = _axis_rmse(d)
    acc_r, how = nssda_horizontal_accuracy(rx, ry)
    acc_z = data["vertical_factor"] * rz
    n = d.shape[0]
    notes = list(data.get("open_items", ())) if how.startswith("ratio < 0.6") else []
    if n < data["min_check_points"]:
        notes.append(f"NSSDA asks for at least {data['min_check_points']} check points; {n} used")
    classes = {"planimetric": f"{acc_r:.3f} m", "altimetric": f"{acc_z:.3f} m"}
    label = (f"Tested {acc_r:.3f} (m) horizontal accuracy at 95% confidence level; "
             f"tested {acc_z:.3f} (m) vertical accuracy at 95% confidence level")
    ev = {"n": n, "rmse_x_m": rx, "rmse_y_m": ry, "rmse_r_m": math.hypot(rx, ry), "rmse_z_m": rz,
          "ratio_min_max": (min(rx, ry) / max(rx, ry)) if max(rx, ry) > 0 else None,
          "accuracy_r_95_m": acc_r, "horizontal_formula": how, "accuracy_z_95_m": acc_z}
    return _result("nssda", data, classes, label, ev, notes)


def _target_evidence(ev: dict[str, Any], target_cm: Mapping[str, float] | None, rmse_h_m: float,
                     rmse_v_m: float, standard: str) -> None:
    """Add ``target_<comp>_cm`` and ``target_<comp>_passed`` to *ev* for each requested ASPRS class."""
    for comp, x in (target_cm or {}).items():
        if comp not in ("planimetric", "altimetric"):
            raise AssessmentError(f"{standard} target class {comp!r}: use 'planimetric' and/or 'altimetric' "
                                  "(e.g. {'planimetric': 5.0, 'altimetric': 10.0}, in cm)")
        ev[f"target_{comp}_cm"] = x
        ev[f"target_{comp}_passed"] = bool((rmse_h_m if comp == "planimetric" else rmse_v_m) * 100 <= x + 1e-9)


def _class_cm(rmse_m: float, step_cm: float) -> float:
    cm = rmse_m * 100.0
    return round(math.ceil(cm / step_cm - 1e-9) * step_cm, 6)


def _fmt_cm(x: float) -> str:
    """An ASPRS class name: ``7.5-cm``, ``0.05-cm`` (shortest form below 0.1 cm)."""
    return format_number(x, 1 if x >= 0.1 else None, unit="-cm")


def classify_asprs2014(d: np.ndarray, *, target_cm: Mapping[str, float] | None = None) -> StandardResult:
    """ASPRS 2014 (Ed. 1) horizontal and vertical accuracy classes.

    Classes are unlimited ("X-cm"); the smallest X (step 0.1 cm) the data meet
    is reported.  With *target_cm* (``{"planimetric": X, "altimetric": Y}``)
    the evidence also says whether those classes are met.
    """
    d = _check_d(d)
    data = load_standard("asprs2014")
    rx, ry, rz = _axis_rmse(d)
    step = data["class_step_cm"]
    xh = _class_cm(max(rx, ry), step)
    xv = _class_cm(rz, step)
    n = d.shape[0]
    mean = np.mean(d, axis=0)
    notes = list(data.get("open_items", ()))
    if n < data["min_check_points"]:
        notes.append(f"ASPRS 2014 asks for at least {data['min_check_points']} check points; {n} used")
    lim = data["max_mean_error_fraction"]
    bias_h = bool(max(abs(mean[0]), abs(mean[1])) > lim * max(rx, ry)) if max(rx, ry) > 0 else False
    bias_v = bool(abs(mean[2]) > lim * rz) if rz > 0 else False
    if bias_h or bias_v:
        notes.append("mean error exceeds 25 % of the RMSE (report the bias; ASPRS 2014 section 7.2)")
    ev: dict[str, Any] = {
        "n": n, "rmse_x_m": rx, "rmse_y_m": ry, "rmse_r_m": math.hypot(rx, ry), "rmse_z_m": rz,
        "horizontal_accuracy_95_m": data["horizontal_95_factor"] * math.hypot(rx, ry),
        "nva_95_m": data["vertical_95_factor"] * rz,
        "horizontal_class_cm": xh, "vertical_class_cm": xv,
        "mean_m": mean.tolist(), "mean_exceeds_25_percent": {"horizontal": bias_h, "vertical": bias_v},
    }
    _target_evidence(ev, target_cm, max(rx, ry), rz, "asprs2014")
    classes = {"planimetric": _fmt_cm(xh), "altimetric": _fmt_cm(xv)}
    label = (f"horizontal accuracy class {_fmt_cm(xh)} (RMSE_x {rx * 100:.2f} cm, RMSE_y {ry * 100:.2f} cm); "
             f"vertical (NVA) class {_fmt_cm(xv)} (RMSE_z {rz * 100:.2f} cm)")
    return _result("asprs2014", data, classes, label, ev, notes)


def asprs2023_product_rmse(fit: float, checkpoint: float) -> float:
    """ASPRS Ed. 2 product accuracy ``sqrt(fit^2 + checkpoint^2)`` (section 7.11).

    For horizontal use RMSE_H values (``checkpoint = RMSE_H2``, i.e. sqrt(2)
    times the per-axis survey RMSE when E and N are alike).

    >>> round(asprs2023_product_rmse(1.00, 2.0), 2)
    2.24
    """
    return math.hypot(fit, checkpoint)


def classify_asprs2023(d: np.ndarray, *, checkpoint_sd_m: np.ndarray | None = None,
                       target_cm: Mapping[str, float] | None = None) -> StandardResult:
    """ASPRS Edition 2 (2023) classes including the check-point survey error.

    Parameters
    ----------
    d : (N, 3) array
        Discrepancies (m).
    checkpoint_sd_m : (N, 3) or (3,) array, optional
        Survey standard deviations of the check points (sd_E, sd_N, sd_h, m);
        the per-axis survey RMSE is ``sqrt(mean(sd^2))``.  ``None``: unknown,
        the product accuracy is the fit alone and the notes say so.
    target_cm : dict, optional
        ``{"planimetric": X, "altimetric": Y}`` classes (cm) to test.

    Raises
    ------
    AssessmentError
        Bad discrepancies, sds of the wrong shape or negative, or a target
        key other than ``planimetric`` / ``altimetric``.
    """
    d = _check_d(d)
    data = load_standard("asprs2023")
    rx, ry, rz = _axis_rmse(d)
    h1 = math.hypot(rx, ry)
    notes = list(data.get("open_items", ()))
    if checkpoint_sd_m is None:
        e2 = n2 = v2 = 0.0
        notes.append("check-point survey accuracy unknown: product accuracy = fit to check points only "
                     "(give the reference sd_E, sd_N, sd_h columns to include it)")
    else:
        sd = np.asarray(checkpoint_sd_m, dtype=float)
        if sd.shape not in ((3,), d.shape):
            raise AssessmentError(f"check-point sds must be (3,) or ({d.shape[0]}, 3) (sd_E, sd_N, sd_h in m), "
                                  f"got shape {sd.shape}")
        if not np.all(np.isfinite(sd) & (sd >= 0)):
            raise AssessmentError("check-point sds must be finite and >= 0 (sd_E, sd_N, sd_h in m)")
        sd = np.broadcast_to(sd, d.shape)
        e2, n2, v2 = (float(np.sqrt(np.mean(np.square(sd[:, k])))) for k in range(3))
    h2 = math.hypot(e2, n2)
    rh = asprs2023_product_rmse(h1, h2)
    rv = asprs2023_product_rmse(rz, v2)
    step = data["class_step_cm"]
    xh, xv = _class_cm(rh, step), _class_cm(rv, step)
    n = d.shape[0]
    if n < data["min_check_points"]:
        notes.append(f"ASPRS 2023 asks for at least {data['min_check_points']} check points; {n} used")
    mean = np.mean(d, axis=0)
    lim = data["max_mean_error_fraction"]
    blunder = data["blunder_factor"]
    dp = np.hypot(d[:, 0], d[:, 1])
    n_blunder_h = int(np.sum(dp > blunder * rh)) if rh > 0 else 0
    n_blunder_v = int(np.sum(np.abs(d[:, 2]) > blunder * rv)) if rv > 0 else 0
    if n_blunder_h or n_blunder_v:
        notes.append(f"{n_blunder_h} horizontal / {n_blunder_v} vertical errors exceed 3 x RMSE: investigate "
                     "(ASPRS 2023 section 7.2; do not drop them silently)")
    ratio = data["checkpoint_accuracy_ratio"]
    if h2 > 0 and h2 * ratio > h1:
        notes.append("check points are not 2x more accurate than the horizontal fit (section 7.12)")
    if v2 > 0 and v2 * ratio > rz:
        notes.append("check points are not 2x more accurate than the vertical fit (section 7.12)")
    ev: dict[str, Any] = {
        "n": n, "rmse_x_m": rx, "rmse_y_m": ry, "rmse_h1_m": h1, "rmse_h2_m": h2, "rmse_h_m": rh,
        "rmse_v1_m": rz, "rmse_v2_m": v2, "rmse_v_m": rv, "rmse_3d_m": math.hypot(rh, rv),
        "horizontal_class_cm": xh, "vertical_class_cm": xv, "mean_m": mean.tolist(),
        "mean_exceeds_25_percent": {
            "horizontal": bool(max(abs(mean[0]), abs(mean[1])) > lim * h1 / math.sqrt(2)) if h1 > 0 else False,
            "vertical": bool(abs(mean[2]) > lim * rz) if rz > 0 else False},
        "blunders_over_3x_rmse": {"horizontal": n_blunder_h, "vertical": n_blunder_v},
    }
    _target_evidence(ev, target_cm, rh, rv, "asprs2023")
    classes = {"planimetric": _fmt_cm(xh), "altimetric": _fmt_cm(xv)}
    label = (f"horizontal class {_fmt_cm(xh)} (RMSE_H {rh * 100:.2f} cm incl. check-point error "
             f"{h2 * 100:.2f} cm); vertical NVA class {_fmt_cm(xv)} (RMSE_V {rv * 100:.2f} cm)")
    return _result("asprs2023", data, classes, label, ev, notes)


def classify(name: str, d: np.ndarray, *, scale: float | None = None, contour_interval_m: float | None = None,
             alpha: float = 0.10, checkpoint_sd_m: np.ndarray | None = None,
             target_cm: Mapping[str, float] | None = None) -> StandardResult:
    """Dispatch to the classifier of standard *name* (see :data:`STANDARD_NAMES`).

    Raises
    ------
    AssessmentError
        Unknown standard, or a PEC standard without a scale.
    """
    key = name.lower()
    if key in ("pec", "pec-pcd"):
        if scale is None:
            raise AssessmentError(f"standard {name!r} needs a map scale (e.g. scale=2000)")
        return classify_pec(d, scale, contour_interval_m, standard=key, alpha=alpha)
    if key == "nssda":
        return classify_nssda(d)
    if key == "asprs2014":
        return classify_asprs2014(d, target_cm=target_cm)
    if key == "asprs2023":
        return classify_asprs2023(d, checkpoint_sd_m=checkpoint_sd_m, target_cm=target_cm)
    raise AssessmentError(f"unknown standard {name!r}; choose from {', '.join(STANDARD_NAMES)}")

