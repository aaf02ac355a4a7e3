"""Stage ``assess-SET``: check-point accuracy of one run (thesis section 3.3.4).

Discrepancies reference minus adjusted of the control set's check points,
the statistical tests and the classification by standard
(:func:`lidarcat.accuracy.checkpoints.assess`), written as ``assessment.json``,
``discrepancies.csv`` and the run's HTML report (:mod:`lidarcat.report.document`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._util import write_json_atomic
from ..errors import LidarcatError
from .context import StageContext as Context

__all__ = ["assess", "run"]


def assess(adjusted: Any, reference: Any, output: Any = None, *, points: Sequence[str] | None = None,
           control_set: str | None = None, not_adjusted: Sequence[str] = (), adjustment_dir: Any = None,
           survey: Any = None, title: str | None = None, **kw: Any) -> tuple[Any, dict | None]:
    """The action of ``lidarcat assess`` and of the stage ``assess-SET``: check points in, tables and report out.

    Parameters
    ----------
    adjusted, reference
        Adjusted points (points.csv or its folder) and reference points (a CSV or
        columns), as :func:`lidarcat.accuracy.checkpoints.assess` takes them.
    output : path or None
        A folder: ``assessment.json``, ``discrepancies.csv`` (reference minus adjusted,
        m) and the report (``report.html``, ``.md``, ``.json``, ``report_figures/``;
        :func:`lidarcat.report.document.write_report`) go into it.  ``NAME.html``: the
        report only.  None: nothing is written.
    points : sequence of str, optional
        The check points, in this order.
    control_set : str, optional
        Name of the control set (recorded in assessment.json and the CSV comment).
    not_adjusted : sequence of str
        Check points of the control set that were not adjusted (recorded).
    adjustment_dir, survey, title
        For the report.
    **kw
        Further keywords of :func:`lidarcat.accuracy.checkpoints.assess` (scale,
        contour_interval_m, standards, alpha, plotting_position, sign, pec_class,
        adjusted_cov, consistency).

    Returns
    -------
    (Assessment, dict or None)
        The assessment and the report's paths (None without *output*).
    """
    from .._util import write_csv_atomic
    from ..accuracy.checkpoints import assess as run_assess

    a = run_assess(adjusted, reference, points=list(points) if points is not None else None, **kw)
    if output is None:
        return a, None
    out = Path(output)
    if out.suffix.lower() != ".html":
        doc = a.to_dict()
        doc["control_set"] = control_set
        doc["check_points_not_adjusted"] = list(not_adjusted)
        write_json_atomic(out / "assessment.json", doc)
        rows = a.point_rows()
        cols = ["point", "E_ref", "N_ref", "h_ref", "E_adj", "N_adj", "h_adj", "dE", "dN", "dh", "dP"]
        of = f" of control set {control_set}" if control_set else ""
        write_csv_atomic(out / "discrepancies.csv", cols, [[r[c] for c in cols] for r in rows],
                         comments=[f"Check points{of}: discrepancies reference minus "
                                   "adjusted (thesis Table 7 convention), metres."])
    from ..report.document import write_report

    paths = write_report(out if out.suffix.lower() == ".html" else out / "report.html", assessment=a,
                         adjustment_dir=adjustment_dir, survey=survey, title=title)
    return a, paths


def run(ctx: Context, tmp: Path) -> dict:
    """Check points of one run against the survey's ground points -> assessment.json, discrepancies.csv."""
    from ..accuracy.checkpoints import read_points
    from ..survey.folder import Survey

    par = ctx.params
    name = par["control"]
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]
    cset = survey.control_set(name)
    gp = survey.ground_points
    reference = {"point": [str(p) for p in gp.point], "E": gp.enh_m[:, 0], "N": gp.enh_m[:, 1],
                 "h": gp.enh_m[:, 2], "sd_E": gp.sd_m[:, 0], "sd_N": gp.sd_m[:, 1], "sd_h": gp.sd_m[:, 2]}
    adjusted = ctx.folder(f"adjust-{name}") / "points.csv"
    adjusted_ids = set(read_points(adjusted).ids)
    checks = [str(c) for c in cset.check if str(c) in adjusted_ids]
    missing = [str(c) for c in cset.check if str(c) not in adjusted_ids]
    if not checks:
        raise LidarcatError(f"control set {name!r}: none of its check points was adjusted "
                            f"(measured on no photo): {', '.join(missing)}")
    cov_path = ctx.folder(f"adjust-{name}") / "check_covariance.csv"
    cons_path = ctx.folder(f"adjust-{name}") / "consistency.json"
    cov = consistency = None
    if not cov_path.is_file() and cons_path.is_file():  # above the limit of check_covariance.csv
        import json

        from ..accuracy.checkpoints import TestResult

        consistency = TestResult(**json.loads(cons_path.read_text(encoding="utf-8")))
    if cov_path.is_file():
        from ..survey import read_point_covariance

        cov = read_point_covariance(cov_path)
    a, _ = assess(adjusted, reference, tmp, points=checks, scale=par.get("scale"),
                  contour_interval_m=par.get("contour_interval_m"), alpha=par.get("alpha", 0.10),
                  pec_class=par.get("pec_class", "A"), plotting_position=par.get("plotting_position", "filliben"),
                  adjusted_cov=cov, consistency=consistency, control_set=name, not_adjusted=missing,
                  adjustment_dir=ctx.folder(f"adjust-{name}"), survey=survey,
                  title=f"lidarcat: {survey.name}, control set {name}")
    doc = a.to_dict()
    # the assessment's own summary, under the key names of _stats
    check: dict[str, Any] = {"n": len(checks)}
    for c in ("E", "N", "h", "planimetric"):
        check.update({f"{k}_{c}_m": a.summary[c][k] for k in ("mean", "std", "rmse", "max_abs")})
    cons = a.tests.get("consistency", {}).get("ENh")
    if cons is not None and cons.applicable:
        check["consistency"] = {"chi2": cons.statistic, "df": cons.details["df"], "alpha": cons.alpha,
                                "lower": cons.details["lower"], "upper": cons.details["upper"],
                                "passed": cons.passed, "side": cons.details["side"]}
    elif cons is not None:
        check["consistency_not_computed"] = cons.reason
    tests = {t: {c: r.get("passed") for c, r in comps.items()} for t, comps in doc["tests"].items()}
    classes = {k: v.get("class", v.get("classes")) for k, v in doc["standards"].items()}
    return {"check": check, "tests_passed": tests, "standards": classes, "control": name,
            "n_missing": len(missing)}
