"""Accuracy report: one self-contained HTML file, plus Markdown and JSON.

:func:`write_report` combines what is available of

* an adjustment output folder (``eop.csv``, ``points.csv``, ``summary.json``
  as written by ``lidarcat adjust``) or the equivalent dicts,
* an :class:`~lidarcat.accuracy.checkpoints.Assessment` (check-point discrepancies,
  tests, standards),
* survey information (camera format and focal length, for photo footprints),
* an optional second run to compare with,

into the sections of the thesis's analysis: block layout (photo footprints,
control / check / tie points; thesis Figures 8, 16, 17), adjustment summary
(Appendix 2), exterior orientation table (Table 6), discrepancy table
(Table 7), the planimetric vector plot and the height plot (Figures 20, 21),
the Q-Q plots (Figure 22), every test with its verdict, and the class by each
standard.  Sections whose inputs are missing (an *assess-only* run has no
adjustment) say so instead of failing; tests that could not be computed are
shown as *not applicable* with the reason.

The HTML embeds its figures as base64 PNG and uses no external resource, so
it opens offline.  The Markdown refers to the same figures written as PNG
files next to it.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..geometry.collinearity import rotation_matrix
from .._util import atomic_dir, dumps_json, read_csv_table
from .._util.formatting import format_number
from ..errors import AssessmentError, LidarcatError
from .figures import height_figure, layout_figure, qq_figure, vector_figure
from .model import Document, Figure, Paragraph, Table
from .render import figure_files, to_html, to_markdown

__all__ = ["SECTIONS", "load_adjustment", "footprints", "write_report"]

log = logging.getLogger(__name__)

#: (html id, heading) of every report section, in order
SECTIONS: tuple[tuple[str, str], ...] = (
    ("overview", "Overview"),
    ("block-layout", "Block layout"),
    ("adjustment-summary", "Adjustment summary"),
    ("exterior-orientation", "Exterior orientation"),
    ("discrepancies", "Check-point discrepancies"),
    ("discrepancy-plots", "Discrepancy plots"),
    ("qq-plots", "Q-Q plots"),
    ("tests", "Statistical tests"),
    ("standards", "Classification by standard"),
    ("comparison", "Comparison of runs"),
    ("notes", "Notes and settings"),
)

_SUMMARY_LABELS = {  # known summary.json keys, in display order
    "status": "status",
    "converged": "converged",
    "n_iterations": "iterations",
    "message": "message",
    "sigma0_sq_a_priori": "variance factor a priori",
    "sigma0_sq": "variance factor a posteriori (sigma0^2)",
    "dof": "degrees of freedom",
    "vtpv": "v^T P v (computed chi-square)",
    "chi2_statistic": "chi-square statistic",
    "chi2_level": "chi-square level",
    "chi2_lower": "chi-square range: lower",
    "chi2_upper": "chi-square range: upper",
    "chi2_lower_fisher": "chi-square range (Fisher approximation): lower",
    "chi2_upper_fisher": "chi-square range (Fisher approximation): upper",
    "chi2_pass": "chi-square test of the variance factor passed",
    "variance_factor": "parameter sds scaled by variance factor",
    "n_photos": "photos",
    "n_points": "points",
    "n_observations": "observations (equations)",
    "n_unknowns": "unknowns",
    "n_constraints": "constraints",
    "observations": "photo coordinates used",
    "elapsed_s": "solver time (s)",
    "rms_control_residuals_m": "RMS control-point residuals",
    "sd_control_residuals_m": "sd of control residuals (Appendix 2 'pontos fixos')",
    "mean_sd_control_m": "mean sd of control points",
    "mean_sd_free_m": "mean sd of free points",
    "rms_sd_points_m": "RMS sd of all points (Appendix 2 'pontos livres')",
}

_TEST_TITLES = {
    "filliben": "Filliben PPCC normality (eq. 42)",
    "ks": "Kolmogorov-Smirnov, plain (as published)",
    "lilliefors": "Kolmogorov-Smirnov with Lilliefors correction",
    "trend_t": "t-Student trend (eq. 43, 44)",
    "chi2_precision": "chi-square precision (eq. 45, 46)",
    "hotelling": "Hotelling T^2 on (dE, dN)",
    "ce90": "90 % circular error radius",
    "consistency": "discrepancies vs claimed precision, d'C^-1 d (joint covariance)",
}


# ----------------------------------------------------------------------------- inputs


def _read_table(path: Path, required: Sequence[str]) -> list[dict[str, str]]:
    t = read_csv_table(path, required, allow_extra=True)
    return [dict(zip(t.header, row)) for row in t.rows]


def _num(v: Any) -> float | None:
    if v is None:
        return None
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        return float(v) if math.isfinite(float(v)) else None
    try:
        x = float(str(v).strip())
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def _rows(obj: Any, required: Sequence[str], what: str) -> list[dict[str, Any]] | None:
    if obj is None:
        return None
    if isinstance(obj, (str, os.PathLike)):
        return _read_table(Path(obj), required)
    if isinstance(obj, Mapping):
        keys = list(obj)
        if keys and all(isinstance(obj[k], (list, tuple, np.ndarray)) for k in keys) and required[0] in obj:
            n = len(obj[required[0]])
            return [{k: obj[k][i] for k in keys} for i in range(n)]
        return [dict(v, **{required[0]: k}) if isinstance(v, Mapping) else {required[0]: k}
                for k, v in obj.items()]
    if isinstance(obj, Sequence):
        return [dict(r) for r in obj]
    raise AssessmentError(f"cannot read the {what} from a {type(obj).__name__}")


def load_adjustment(source: Any) -> dict[str, Any]:
    """Read an adjustment output folder (or the equivalent dicts).

    Parameters
    ----------
    source : path or mapping
        Folder with ``eop.csv`` (photo, X0, Y0, Z0, omega, phi, kappa and
        ``sd_*``; metres and degrees), ``points.csv`` (point, E, N, h,
        sd_E, sd_N, sd_h, role) and ``summary.json``; or a mapping with keys
        ``eop``, ``points``, ``summary`` whose values are paths, row lists,
        column dicts or (summary) a dict.  Missing parts are ``None``.

    Returns
    -------
    dict
        ``{"eop": rows | None, "points": rows | None, "summary": dict | None,
        "source": str}``.

    Raises
    ------
    AssessmentError, SurveyError
        A file exists but cannot be parsed (the message names it).
    """
    out: dict[str, Any] = {"eop": None, "points": None, "summary": None, "source": ""}
    if source is None:
        return out
    if isinstance(source, (str, os.PathLike)):
        folder = Path(source)
        if not folder.is_dir():
            raise AssessmentError(f"{folder}: adjustment output folder not found")
        out["source"] = str(folder)
        parts: dict[str, Any] = {k: folder / f for k, f in (("eop", "eop.csv"), ("points", "points.csv"),
                                                              ("summary", "summary.json"))}
        parts = {k: (p if p.is_file() else None) for k, p in parts.items()}
    elif isinstance(source, Mapping):
        parts = dict(source)
        out["source"] = str(source.get("source", "<adjustment dict>"))
    else:
        raise AssessmentError(f"adjustment must be a folder or a mapping, not {type(source).__name__}")
    out["eop"] = _rows(parts.get("eop"), ("photo", "X0", "Y0", "Z0", "omega", "phi", "kappa"), "exterior orientation")
    out["points"] = _rows(parts.get("points"), ("point", "E", "N", "h"), "adjusted points")
    summ = parts.get("summary")
    if isinstance(summ, (str, os.PathLike)):
        try:
            summ = json.loads(Path(summ).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as ex:
            raise AssessmentError(f"{summ}: cannot read the adjustment summary ({ex})") from ex
    out["summary"] = dict(summ) if isinstance(summ, Mapping) else None
    return out


def _camera_info(survey: Any, camera: Any) -> dict[str, dict[str, float]]:
    """``{photo or "*": {focal_length_mm, width_mm, height_mm}}`` from a survey or a camera."""

    def info(cam: Any) -> dict[str, float] | None:
        get = (lambda k: cam.get(k)) if isinstance(cam, Mapping) else (lambda k: getattr(cam, k, None))
        try:
            f = float(get("focal_length_mm"))
            w = float(get("columns_px")) * float(get("pixel_size_x_mm"))
            h = float(get("rows_px")) * float(get("pixel_size_y_mm"))
        except (TypeError, ValueError):
            return None
        return {"focal_length_mm": f, "width_mm": w, "height_mm": h} if f > 0 and w > 0 and h > 0 else None

    out: dict[str, dict[str, float]] = {}
    if camera is not None:
        c = info(camera)
        if c:
            out["*"] = c
    if survey is None:
        return out
    if isinstance(survey, (str, os.PathLike)):
        try:
            from ..survey.folder import Survey

            survey = Survey.load(survey)
        except (ImportError, LidarcatError) as ex:
            log.warning("survey %s not loaded for footprints: %s", survey, ex)
            return out
    cams = getattr(survey, "cameras", None)
    if isinstance(survey, Mapping):
        cams = survey.get("cameras", cams)
    if isinstance(cams, Mapping):
        cam_infos = {str(k): info(v) for k, v in cams.items()}
    elif isinstance(cams, Sequence):
        cam_infos = {str(getattr(c, "id", i)): info(c) for i, c in enumerate(cams)}
    else:
        cam_infos = {}
    cam_infos = {k: v for k, v in cam_infos.items() if v}
    if len(cam_infos) == 1 and "*" not in out:
        out["*"] = next(iter(cam_infos.values()))
    photos = getattr(survey, "photos", None) or ()
    for ph in photos:
        pid, cid = getattr(ph, "id", None), getattr(ph, "camera", None)
        if pid is not None and str(cid) in cam_infos:
            out[str(pid)] = cam_infos[str(cid)]
    return out


def footprints(eop: Sequence[Mapping[str, Any]], cameras: Mapping[str, Mapping[str, float]],
               terrain_h_m: float) -> dict[str, np.ndarray]:
    """Ground footprints (4, 2) of the photos on the plane ``h = terrain_h_m``.

    Image corners ``(+-width/2, +-height/2)`` are intersected with the plane
    through ``X = X0 + lambda M^T (x, y, -c)``, M = R3(kappa) R2(phi) R1(omega).

    >>> fp = footprints([{"photo": "1", "X0": 0, "Y0": 0, "Z0": 1000, "omega": 0, "phi": 0, "kappa": 0}],
    ...                 {"*": {"focal_length_mm": 50, "width_mm": 20, "height_mm": 10}}, 0.0)
    >>> fp["1"].tolist()
    [[-200.0, -100.0], [200.0, -100.0], [200.0, 100.0], [-200.0, 100.0]]
    """
    out: dict[str, np.ndarray] = {}
    for row in eop:
        pid = str(row.get("photo"))
        cam = cameras.get(pid) or cameras.get("*")
        vals = [_num(row.get(k)) for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")]
        if cam is None or any(v is None for v in vals):
            continue
        x0, y0, z0, om, ph, ka = vals
        m = rotation_matrix(np.radians([om, ph, ka]))
        w, h, c = cam["width_mm"] / 2, cam["height_mm"] / 2, cam["focal_length_mm"]
        corners = []
        for x, y in ((-w, -h), (w, -h), (w, h), (-w, h)):
            ray = m.T @ np.array([x, y, -c])
            if ray[2] >= 0:
                break
            lam = (terrain_h_m - z0) / ray[2]
            corners.append([x0 + lam * ray[0], y0 + lam * ray[1]])
        if len(corners) == 4:
            out[pid] = np.round(np.array(corners), 9)
    return out


# ----------------------------------------------------------------------------- content


def _f(x: Any, nd: int = 3) -> str:
    """A number of the report: *nd* decimals, an em dash when missing."""
    return format_number(x, nd, missing="—")


def _section(doc: Document, sid: str) -> list:
    """The blocks of a new section *sid* of :data:`SECTIONS`."""
    return doc.section(dict(SECTIONS)[sid], sid).blocks


def _para(blocks: list, text: str, cls: str = "") -> None:
    blocks.append(Paragraph(text, cls))


def _table(blocks: list, header: Sequence[str], rows: Sequence[Sequence[Any]], caption: str = "") -> None:
    blocks.append(Table(list(header), [list(r) for r in rows], caption))


def _figure(blocks: list, name: str, png: bytes, caption: str) -> None:
    blocks.append(Figure(caption, name, png, alt=name))


def _verdict_cell(v: str) -> str:
    return {"passed": "PASSED", "failed": "FAILED"}.get(v, "not applicable")


def _overview(doc: Document, a: Any, adj: Mapping[str, Any]) -> None:
    """Overview: versions, inputs, the verdicts and classes at a glance."""
    pts_adj = adj.get("points")
    eop = adj.get("eop")
    summ = adj.get("summary")
    b = _section(doc, "overview")
    _para(b, f"lidarcat {__version__}. Discrepancy convention: "
             f"{a.settings['sign'].replace('_', ' ') if a else 'n/a'}. Units: metres, degrees.")
    avail = []
    avail.append("adjustment output: " + (adj.get("source") or "given") if (eop or pts_adj or summ)
                 else "adjustment output: not given (assess-only report)")
    avail.append(f"check points: {a.n}" if a else "check points: no assessment given")
    _para(b, "; ".join(avail) + ".")
    if a:
        cols: list[str] = []
        for comps in a.tests.values():
            cols += [c for c in comps if c not in cols]
        rows = [[_TEST_TITLES.get(tname, tname)] + [_verdict_cell(comps[c].verdict) if c in comps else ""
                                                    for c in cols] for tname, comps in a.tests.items()]
        _table(b, ["test"] + cols, rows, f"Test verdicts at a glance (alpha = {a.settings['alpha']:g}; "
               "details below). EN: joint (dE, dN); empirical / circular / bivariate_exact: CE90 methods.")
        srows = [[k, v.classes.get("planimetric") or "not evaluated", v.classes.get("altimetric") or "not evaluated"]
                 for k, v in a.standards.items()]
        if srows:
            _table(b, ["standard", "planimetric / horizontal", "altimetric / vertical"], srows,
                   "Classification at a glance.")


def _block_layout(doc: Document, a: Any, adj: Mapping[str, Any], cams: Mapping[str, Any],
                  title: str) -> dict[str, np.ndarray]:
    """Block layout: footprints and points by role (thesis Figures 8, 16, 17); returns the footprints."""
    pts_adj = adj.get("points")
    eop = adj.get("eop")
    b = _section(doc, "block-layout")
    pts: list[dict[str, Any]] = []
    if pts_adj:
        check_ids = set(a.points) if a else set()
        for r in pts_adj:
            e, nn = _num(r.get("E")), _num(r.get("N"))
            if e is None or nn is None:
                continue
            role = str(r.get("role") or ("check" if str(r.get("point")) in check_ids else "point")).lower()
            pts.append({"point": str(r.get("point")), "E": e, "N": nn, "role": role})
    elif a:
        pts = [{"point": p, "E": float(a.reference[k, 0]), "N": float(a.reference[k, 1]), "role": "check"}
               for k, p in enumerate(a.points)]
    heights = [(_num(r.get("h"))) for r in (pts_adj or [])]
    heights = [h for h in heights if h is not None] or ([float(np.mean(a.reference[:, 2]))] if a else [])
    fps: dict[str, np.ndarray] = {}
    if eop and cams and heights:
        fps = footprints(eop, cams, float(np.mean(heights)))
    if pts or fps:
        cap = ("Photo footprints on the mean terrain height "
               f"({np.mean(heights):.1f} m) and the points by role (thesis Figures 8, 16, 17)."
               if fps else "Points by role (no photo footprints: camera format or exterior orientation not "
                           "given).")
        centres = np.array([[_num(r.get("X0")), _num(r.get("Y0"))] for r in eop
                            if _num(r.get("X0")) is not None and _num(r.get("Y0")) is not None]) if eop else None
        _figure(b, "block_layout.png", layout_figure(pts, fps, centres, title), cap)
        counts: dict[str, int] = {}
        for p in pts:
            counts[p["role"]] = counts.get(p["role"], 0) + 1
        _table(b, ["role", "points"], sorted(counts.items()), "")
    else:
        _para(b, "Not available: neither adjusted points nor check points were given.", "na")
    return fps


def _adjustment_summary(doc: Document, adj: Mapping[str, Any]) -> None:
    """Adjustment summary (thesis Appendix 2), data snooping, mean point sds."""
    pts_adj = adj.get("points")
    summ = adj.get("summary")
    b = _section(doc, "adjustment-summary")
    if summ:
        order = {k: i for i, k in enumerate(_SUMMARY_LABELS)}
        keys = sorted((k for k, v in summ.items() if not isinstance(v, (dict, list))),
                      key=lambda k: (order.get(k, len(order)), k))
        rows = [[_SUMMARY_LABELS.get(k, k), _f(summ[k], 4) if isinstance(summ[k], float) else _f(summ[k])]
                for k in keys]
        _table(b, ["quantity", "value"], rows, "Bundle adjustment summary (as thesis Appendix 2).")
        per_photo = summ.get("rms_image_residuals_mm")
        if isinstance(per_photo, Mapping) and per_photo:
            _table(b, ["photo", "x (mm)", "y (mm)"],
                   [[k, _f(_num(v.get("x")), 4), _f(_num(v.get("y")), 4)] for k, v in per_photo.items()
                    if isinstance(v, Mapping)],
                   "RMS image residuals per photo (Appendix 2: 'Desvio Padrao Medio das observacoes').")
        enh = [(k, v) for k, v in summ.items() if isinstance(v, Mapping) and v and set(v) <= {"E", "N", "h"}]
        if enh:
            _table(b, ["quantity", "E (m)", "N (m)", "h (m)"],
                   [[_SUMMARY_LABELS.get(k, k)] + [_f(_num(v.get(c)), 3) for c in ("E", "N", "h")] for k, v in enh],
                   "Point statistics of the adjustment (Appendix 2).")
        sn = summ.get("snooping") if isinstance(summ.get("snooping"), Mapping) else {}
        if sn and sn.get("mode") != "off":
            bl = [x for x in summ.get("blunders") or [] if isinstance(x, Mapping)]
            _table(b, ["kind", "photo", "point", "w", "w critical", "redundancy", "estimated error", "removed"],
                   [[x.get("kind"), x.get("photo") or "", x.get("point") or "", _f(_num(x.get("w")), 2),
                     _f(_num(x.get("w_critical")), 2), _f(_num(x.get("redundancy")), 2),
                     ", ".join(f"{k} {_f(_num(v), 4)}" for k, v in (x.get("estimated_error") or {}).items())
                     + f" {x.get('unit', '')}", "yes" if x.get("removed") else "no (kept)"] for x in bl]
                   or [["none", "", "", "", "", "", "", ""]],
                   f"Data snooping ({sn.get('mode')}, alpha {_num(sn.get('level')) or float('nan'):.3g}"
                   + (f", family-wise {_num(sn.get('family_level')):g}" if _num(sn.get("family_level")) else "")
                   + "): observations whose w-test "
                   "rejects (blunders.csv; every observation's redundancy and MDB in reliability.csv).")
    if pts_adj and not (summ and ("mean_sd_control_m" in summ or "mean_sd_free_m" in summ)):
        groups: dict[str, list[list[float]]] = {}
        for r in pts_adj:
            sd = [_num(r.get(k)) for k in ("sd_E", "sd_N", "sd_h")]
            if all(s is not None for s in sd):
                role = str(r.get("role") or "point").lower()
                groups.setdefault("control (fixed)" if role == "control" else "free", []).append(sd)
        if groups:
            _table(b, ["points", "n", "mean sd E (m)", "mean sd N (m)", "mean sd h (m)"],
                   [[g, len(v), *(_f(x) for x in np.mean(np.array(v), axis=0))] for g, v in sorted(groups.items())],
                   "Mean standard deviation of the adjusted points (Appendix 2: 'Desvio Padrao Medio').")
    if not summ and not pts_adj:
        _para(b, "Not applicable: no adjustment output was given (assess-only run).", "na")


def _exterior_orientation(doc: Document, adj: Mapping[str, Any]) -> None:
    """Exterior orientation and its sds (thesis Table 6)."""
    eop = adj.get("eop")
    b = _section(doc, "exterior-orientation")
    if eop:
        keys = ["X0", "Y0", "Z0", "omega", "phi", "kappa"]
        rows = []
        for r in eop:
            row = [str(r.get("photo"))]
            for k in keys:
                v, s = _num(r.get(k)), _num(r.get(f"sd_{k}"))
                nd = 3 if k in ("X0", "Y0", "Z0") else 5
                row.append(_f(v, nd) + (f" ± {_f(s, nd)}" if s is not None else ""))
            rows.append(row)
        _table(b, ["photo", "X0 (m)", "Y0 (m)", "Z0 (m)", "omega (°)", "phi (°)", "kappa (°)"], rows,
               "Exterior orientation and standard deviations (as thesis Table 6).")
    else:
        _para(b, "Not applicable: no exterior orientation was given (assess-only run).", "na")


def _discrepancies(doc: Document, a: Any) -> None:
    """Check-point discrepancies (thesis Table 7)."""
    b = _section(doc, "discrepancies")
    if a:
        rows = [[r["point"], _f(r["dE"]), _f(r["dN"]), _f(r["dh"]), _f(r["dP"])] for r in a.point_rows()]
        for stat, key in (("mean", "mean"), ("std (n-1)", "std"), ("RMSE", "rmse"), ("max |d|", "max_abs")):
            rows.append([f"**{stat}**"] + [_f(a.summary[c][key]) for c in ("E", "N", "h", "planimetric")])
        _table(b, ["point", "dE (m)", "dN (m)", "dh (m)", "dP plani. (m)"], rows,
               f"Discrepancies at the {a.n} check points, {a.settings['sign'].replace('_', ' ')} "
               "(as thesis Table 7).")
    else:
        _para(b, "Not available: no check-point assessment was given.", "na")


def _plots(doc: Document, a: Any) -> None:
    """Discrepancy plots (thesis Figures 20, 21) and Q-Q plots (Figure 22)."""
    b = _section(doc, "discrepancy-plots")
    if a and a.n >= 1:
        _figure(b, "planimetric_vectors.png", vector_figure(a),
                "Planimetric discrepancy vectors at the check points (thesis Figure 20).")
        _figure(b, "height_discrepancies.png", height_figure(a),
                "Height discrepancies (thesis Figure 21).")
    else:
        _para(b, "Not available: no check-point assessment was given.", "na")
    b = _section(doc, "qq-plots")
    if a and a.n >= 3:
        _figure(b, "qq_plots.png", qq_figure(a),
                "Normal Q-Q plots of the discrepancies with the Filliben r (thesis Figure 22).")
    else:
        _para(b, "Not applicable: fewer than 3 check points." if a else
              "Not available: no check-point assessment was given.", "na")


def _tests(doc: Document, a: Any) -> None:
    """Every statistical test with its verdict."""
    b = _section(doc, "tests")
    if a:
        for tname, comps in a.tests.items():
            rows = []
            for comp, t in comps.items():
                det = t.details
                extra = []
                for k in ("p_value", "mean_lower", "mean_upper", "sigma0", "sigma_bound", "F", "fraction_within",
                          "lower", "df", "diagonal_statistic", "side"):
                    if det.get(k) is not None:
                        extra.append(f"{k} {_f(det[k], 4)}")
                if det.get("critical_source"):
                    extra.append(str(det["critical_source"]))
                if t.reason:
                    extra.append(t.reason)
                rows.append([comp, _f(t.statistic, 4), _f(t.critical, 4), _verdict_cell(t.verdict),
                             "; ".join(extra)])
            lvl = next((t.alpha for t in comps.values() if t.alpha is not None), None)
            _table(b, ["component", next(iter(comps.values())).statistic_name, "critical", "verdict", "details"],
                   rows, _TEST_TITLES.get(tname, tname) + (f", alpha = {lvl:g}" if lvl is not None else ""))
    else:
        _para(b, "Not applicable: no check-point assessment was given.", "na")


def _standards(doc: Document, a: Any) -> None:
    """Classification by each standard, with its evidence and notes."""
    b = _section(doc, "standards")
    if a and a.standards:
        from ..accuracy.standards import CONFIDENCE_LABELS

        _para(b, "Confidence of the rules of each standard, and tags such as [K] in the notes: "
              + "; ".join(f"{k} = {v}" for k, v in CONFIDENCE_LABELS.items())
              + ". Rules, sources and the open items the notes cite: STANDARDS.md (docs/standards.md; "
                "installed as lidarcat/standards_data/STANDARDS.md).", "note")
        for name, s in a.standards.items():
            _para(b, f"**{s.title}** ({s.version}; confidence {s.confidence}): {s.label}")
            if name in ("pec", "pec-pcd"):
                rows = []
                for r in s.evidence["classes"]:
                    for comp in ("planimetric", "altimetric"):
                        c = r.get(comp)
                        if not c:
                            continue
                        rows.append([r["class"], comp, _f(c["pec_m"]), _f(c["ep_m"]),
                                     f"{100 * c['fraction_within_pec']:.1f} %", _f(c["rms_m"]),
                                     "yes" if c["passed"] else "no", _f(c["chi2"], 3),
                                     "yes" if c["chi2_passed"] else "no"])
                _table(b, ["class", "component", "PEC (m)", "EP (m)", "within PEC", "RMS (m)",
                           "90 % + EP rule", "chi2 (EP as sigma0)", "chi2 passed"], rows,
                       f"{name}: class = best class meeting the 90 % and RMS <= EP rules; chi-square class "
                       f"(thesis reading, sigma0 = EP): planimetric {s.evidence['chi2_class']['planimetric']}, "
                       f"altimetric {s.evidence['chi2_class']['altimetric']}.")
            else:
                rows = [[k, _f(v, 4) if isinstance(v, float) else _f(v)] for k, v in s.evidence.items()
                        if not isinstance(v, (dict, list))]
                _table(b, ["quantity", "value"], rows, f"{name}: evidence")
            for note in s.notes:
                _para(b, f"Note: {note}", "note")
        _ce90_le90(b, a)
    elif a:
        _para(b, "Not applicable: no standard was requested or no map scale was given.", "na")
    else:
        _para(b, "Not applicable: no check-point assessment was given.", "na")


def _ce90_le90(b: list, a: Any) -> None:
    """CE90 / LE90 of the check points beside the standards (:func:`lidarcat.accuracy.standards.ce90_le90`)."""
    from ..accuracy.standards import ce90_le90

    d = np.array([[r["dE"], r["dN"], r["dh"]] for r in a.point_rows()], dtype=np.float64).reshape(-1, 3)
    d = d[np.isfinite(d).all(axis=1)]
    if not len(d):
        return
    ce = ce90_le90(d)
    _table(b, ["quantity", "from the RMSE (m)", "empirical: 90th percentile (m)"],
           [["CE90 (plan)", _f(ce["ce90_m"]), _f(ce["ce90_empirical_m"])],
            ["LE90 (height)", _f(ce["le90_m"]), _f(ce["le90_empirical_m"])]],
           f"CE90 / LE90 of the {len(d)} check points: the radius and the height error holding 90 % of the "
           "errors, from the RMSE under normal errors (2.1460 RMSE per axis, 1.6449 RMSE_h) and from "
           "the errors themselves.")


def _comparison(doc: Document, a: Any, comparison: Any) -> None:
    """A second run side by side."""
    b = _section(doc, "comparison")
    if comparison is None:
        _para(b, "Not applicable: no second run to compare with.", "na")
    else:
        label, other = ("other run", comparison)
        if isinstance(comparison, tuple) and len(comparison) == 2:
            label, other = comparison
        if hasattr(other, "summary") and hasattr(other, "tests") and a:
            rows = []
            for comp in ("E", "N", "h", "planimetric"):
                for key in ("mean", "std", "rmse", "max_abs"):
                    rows.append([comp, key, _f(a.summary[comp][key]), _f(other.summary[comp][key])])
            _table(b, ["component", "statistic", "this run", str(label)], rows,
                   f"Check-point statistics of this run and of {label}.")
            vrows = []
            for tname, comps in a.tests.items():
                for comp, t in comps.items():
                    o = other.tests.get(tname, {}).get(comp)
                    vrows.append([_TEST_TITLES.get(tname, tname), comp, _verdict_cell(t.verdict),
                                  _verdict_cell(o.verdict) if o else "—"])
            _table(b, ["test", "component", "this run", str(label)], vrows, "Verdicts side by side.")
        elif isinstance(other, Mapping):
            flat = _flatten(other)
            _table(b, ["quantity", "value"], [[k, _f(v, 4) if isinstance(v, float) else _f(v)] for k, v in flat],
                   f"Comparison ({label}).")
        else:
            _para(b, f"Comparison of type {type(other).__name__} cannot be shown.", "na")


def _notes(doc: Document, a: Any) -> None:
    """Notes and settings of the assessment."""
    b = _section(doc, "notes")
    if a:
        from ..survey.folder import DEFAULT_CONTOUR_INTERVAL_M, DEFAULT_SCALE

        ci, sc = a.settings.get("contour_interval_m"), a.settings.get("scale")
        _para(b, f"Map scale {f'1:{sc:g}' if sc else 'not given'}, contour interval "
                 f"{f'{ci:g} m' if ci else 'not given'} "
                 f"for the altimetric classes. `lidarcat assess` and `lidarcat run` share the defaults "
                 f"1:{DEFAULT_SCALE:g} and {DEFAULT_CONTOUR_INTERVAL_M:g} m (the thesis's); a survey sets its own "
                 "in survey.toml [assessment].")
        for note in a.notes:
            _para(b, f"Note: {note}", "note")
        _table(b, ["setting", "value"], [[k, _f(v)] for k, v in a.settings.items()], "Settings of the assessment.")
    else:
        _para(b, "No assessment settings.", "na")


def _build(doc: Document, title: str, a: Any, adj: Mapping[str, Any], cams: Mapping[str, Any],
           comparison: Any) -> dict[str, Any]:
    """Fill *doc* with the sections of :data:`SECTIONS`; returns ``footprints`` and ``sections``
    (blocks per section) for the JSON."""
    meta: dict[str, Any] = {"sections": {}}
    _overview(doc, a, adj)
    fps = _block_layout(doc, a, adj, cams, title)
    _adjustment_summary(doc, adj)
    _exterior_orientation(doc, adj)
    _discrepancies(doc, a)
    _plots(doc, a)
    _tests(doc, a)
    _standards(doc, a)
    _comparison(doc, a, comparison)
    _notes(doc, a)
    meta["footprints"] = {k: v.tolist() for k, v in fps.items()}
    meta["sections"] = {s.id: len(s.blocks) for s in doc.sections}
    return meta


def _flatten(obj: Any, prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    if isinstance(obj, Mapping):
        for k, v in obj.items():
            out.extend(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
    elif isinstance(obj, (list, tuple)) and len(obj) <= 6 and all(not isinstance(v, (dict, list)) for v in obj):
        out.append((prefix, ", ".join(_f(v, 4) if isinstance(v, float) else _f(v) for v in obj)))
    elif not isinstance(obj, (list, tuple)):
        out.append((prefix, obj))
    return out


def write_report(outdir_or_path: str | os.PathLike, *, assessment: Any = None, adjustment_dir: Any = None,
                 survey: Any = None, camera: Any = None, title: str = "lidarcat accuracy report",
                 comparison: Any = None) -> dict[str, Any]:
    """Write the HTML, Markdown and JSON report (atomically).

    Parameters
    ----------
    outdir_or_path : path
        A folder (``report.html``, ``report.md``, ``report.json`` and
        ``figures/*.png`` are written in it) or a file name ending in
        ``.html`` (``NAME.html``, ``NAME.md``, ``NAME.json`` and
        ``NAME_figures/*.png`` next to it).
    assessment : Assessment, optional
        From :func:`lidarcat.accuracy.checkpoints.assess`.
    adjustment_dir : path or mapping, optional
        Adjustment output (see :func:`load_adjustment`).
    survey : Survey, path or mapping, optional
        Used for the camera format and focal length (photo footprints).
    camera : mapping or Camera, optional
        ``focal_length_mm``, ``pixel_size_x_mm``, ``pixel_size_y_mm``,
        ``columns_px``, ``rows_px`` when no survey is given.
    title : str
    comparison : Assessment, (label, Assessment) or mapping, optional
        A second run shown side by side.

    Returns
    -------
    dict
        ``{"html": Path, "markdown": Path, "json": Path, "figures": [Path, ...]}``.

    Raises
    ------
    AssessmentError
        Neither an assessment nor adjustment output was given, or an input
        cannot be read (the message names it).
    """
    if assessment is None and adjustment_dir is None:
        raise AssessmentError("nothing to report: give an assessment and/or an adjustment output folder")
    adj = load_adjustment(adjustment_dir)
    cams = _camera_info(survey, camera)
    target = Path(outdir_or_path)
    if target.suffix.lower() in (".html", ".htm"):
        folder, stem, fig_dir = target.parent, target.stem, f"{target.stem}_figures"
    else:
        folder, stem, fig_dir = target, "report", "figures"
    doc = Document(title)
    meta = _build(doc, title, assessment, adj, cams, comparison)
    html_text = to_html(doc)
    md_text = to_markdown(doc, fig_dir)
    payload = {
        "title": title,
        "lidarcat_version": __version__,
        "sections": [s.id for s in doc.sections],
        "assessment": assessment.to_dict() if assessment is not None else None,
        "adjustment": {"source": adj["source"], "summary": adj["summary"], "eop": adj["eop"],
                       "n_points": len(adj["points"]) if adj["points"] else 0},
        "footprints": meta["footprints"],
        "comparison": (comparison[1].to_dict() if isinstance(comparison, tuple) and hasattr(comparison[1], "to_dict")
                       else comparison.to_dict() if hasattr(comparison, "to_dict") else comparison),
    }
    figures = figure_files(doc)  # (name, png)
    with atomic_dir(folder) as tmp:
        (tmp / f"{stem}.html").write_text(html_text, encoding="utf-8")
        (tmp / f"{stem}.md").write_text(md_text, encoding="utf-8")
        (tmp / f"{stem}.json").write_text(dumps_json(payload) + "\n", encoding="utf-8")
        if figures:
            (tmp / fig_dir).mkdir(exist_ok=True)
        for name, png in figures:
            (tmp / fig_dir / name).write_bytes(png)
    log.info("report written to %s", folder / f"{stem}.html")
    return {"html": folder / f"{stem}.html", "markdown": folder / f"{stem}.md", "json": folder / f"{stem}.json",
            "figures": [folder / fig_dir / name for name, _ in figures]}
