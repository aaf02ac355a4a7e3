"""Stage ``adjust-SET``: bundle adjustment of one control set (eq. 08-22).

Writes ``eop.csv``, ``points.csv``, ``residuals.csv``, ``summary.json``,
``blunders.csv`` and ``reliability.csv`` (:func:`lidarcat.bundle.write_adjustment`;
data snooping in ``report`` mode names the blunders and keeps every observation); a run of the extracted LiDAR
control reads the derived survey of the ``extract`` stage.
"""

from __future__ import annotations

from pathlib import Path

from ...errors import LidarcatError
from ..runner import Context

__all__ = ["run"]


def run(ctx: Context, tmp: Path) -> dict:
    """Bundle adjustment of one control set -> eop.csv, points.csv, residuals.csv, summary.json."""
    from ...bundle import problem_from_survey, write_adjustment
    from ...bundle.reliability import snoop
    from ...bundle.survey_io import survey_provenance
    from ...survey import Survey

    par = ctx.params
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]
    problem = problem_from_survey(survey, control=par["control"])

    def prog(iteration: int, vtpv: float) -> None:
        ctx.progress(min(iteration, 49), 50)

    kw = dict(variance_factor=survey.settings.variance_factor, chi2_level=survey.settings.chi2_level)
    # data snooping, report only: the run keeps every observation and names the blunders
    sres = snoop(problem, mode="report", progress=prog, **kw)
    result = sres.result
    write_adjustment(result, tmp, extra={"crs": survey.crs, "survey": survey.name,
                                         "control_set": par["control"],
                                         "observations": survey.settings.observations},
                     snooping=sres, provenance=survey_provenance(survey, {
                         "control": par["control"], "snooping": "report", "snooping_level": 0.001, **kw}))
    summ = result.summary()
    if not result.success:
        raise LidarcatError(f"adjustment with control set {par['control']!r} did not converge: "
                            f"{result.status} ({result.message}) after {result.n_iter} iterations")
    keys = ("dof", "vtpv", "sigma0_sq", "chi2_lower", "chi2_upper", "chi2_pass", "n_iterations",
            "converged", "n_photos", "n_points", "n_observations", "n_constraints", "status")
    blunders = [{k: b[k] for k in ("kind", "photo", "point", "w", "redundancy", "removed")}
                for b in sres.summary()["blunders"]]
    return {"adjustment": {**{k: summ.get(k) for k in keys}, "blunders": blunders},
            "control": par["control"],
            "derived_survey": bool(par.get("derived"))}
