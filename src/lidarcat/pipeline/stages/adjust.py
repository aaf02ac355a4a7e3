"""Stage ``adjust-SET``: bundle adjustment of one control set (eq. 08-22).

Writes ``eop.csv``, ``points.csv``, ``residuals.csv`` and ``summary.json``
(:func:`lidarcat.bundle.write_adjustment`); a run of the extracted LiDAR
control reads the derived survey of the ``extract`` stage.
"""

from __future__ import annotations

from pathlib import Path

from ...errors import LidarcatError
from ..runner import Context

__all__ = ["run"]


def run(ctx: Context, tmp: Path) -> dict:
    """Bundle adjustment of one control set -> eop.csv, points.csv, residuals.csv, summary.json."""
    from ...bundle import adjust, problem_from_survey, write_adjustment
    from ...survey import Survey

    par = ctx.params
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]
    problem = problem_from_survey(survey, control=par["control"])

    def prog(iteration: int, vtpv: float) -> None:
        ctx.progress(min(iteration, 49), 50)

    result = adjust(problem, variance_factor=survey.settings.variance_factor,
                    chi2_level=survey.settings.chi2_level, progress=prog)
    write_adjustment(result, tmp, extra={"crs": survey.crs, "survey": survey.name,
                                         "control_set": par["control"],
                                         "observations": survey.settings.observations})
    summ = result.summary()
    if not result.success:
        raise LidarcatError(f"adjustment with control set {par['control']!r} did not converge: "
                            f"{result.status} ({result.message}) after {result.n_iter} iterations")
    keys = ("dof", "vtpv", "sigma0_sq", "chi2_lower", "chi2_upper", "chi2_pass", "n_iterations",
            "converged", "n_photos", "n_points", "n_observations", "n_constraints", "status")
    return {"adjustment": {k: summ.get(k) for k in keys}, "control": par["control"],
            "derived_survey": bool(par.get("derived"))}
