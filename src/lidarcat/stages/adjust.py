"""Stage ``adjust-SET``: bundle adjustment of one control set (eq. 08-22).

Writes ``eop.csv``, ``points.csv``, ``residuals.csv``, ``summary.json``,
``blunders.csv`` and ``reliability.csv`` (:func:`lidarcat.bundle.write_adjustment`;
data snooping in ``report`` mode names the blunders and keeps every observation); a run of the extracted LiDAR
control reads the derived survey of the ``extract`` stage.

Above :data:`lidarcat.bundle.MAX_JOINT_COVARIANCE_POINTS` check points the
joint covariance of the check points is not written (``check_covariance.csv``
grows as k^2); this stage then uses it in memory for the consistency test
``d' (C_adj + C_ref)^-1 d ~ chi2(3k)`` and writes only the result,
``consistency.json`` (the ``assess`` stage reads it).  Its memory, two
(3k x 3k) float64 matrices, is bounded by :data:`CONSISTENCY_MEMORY_BYTES`;
beyond that the file says why the test was not computed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_json_atomic
from ..errors import LidarcatError
from .context import StageContext as Context

__all__ = ["adjust", "run", "auto_variance_components", "CONSISTENCY_MEMORY_BYTES"]

#: largest memory the in-memory consistency test may take (k check points: 2 x (3k)^2 x 8 bytes)
CONSISTENCY_MEMORY_BYTES = 1 << 30


def adjust(survey: Any, folder: Path, *, control: str | None = None, observations: str | None = None,
           variance_factor: str | None = None, chi2_level: float | None = None, eo_constraints: bool = False,
           max_iter: int = 50, precision: str = "all", snooping: str = "report", snooping_level: float | None = None,
           family_level: float | None = None, robust: str = "none", start: str = "robust",
           variance_components: bool = False, progress: Callable[[int, float], None] | None = None) -> Any:
    """The action of ``lidarcat adjust`` and of the stage ``adjust-SET``: a survey in, the adjustment folder out.

    :func:`lidarcat.survey.adjustment.adjust_survey_into`: builds the bundle problem of
    *survey*, adjusts it with Baarda's data snooping (:func:`lidarcat.bundle.reliability.snoop`)
    and writes ``eop.csv``, ``points.csv``, ``residuals.csv``, ``summary.json`` (and
    ``check_covariance.csv``, ``blunders.csv``, ``reliability.csv``) into *folder*, each file
    atomically (the callers make the folder appear at once).

    Parameters
    ----------
    survey : lidarcat.Survey
    folder : Path
        Output folder.
    control, observations, variance_factor, chi2_level : optional
        Control set, observation kind, variance factor and chi-square level (default:
        the survey's settings).
    eo_constraints : bool
        Use photos.csv exterior orientations with sigmas as weighted constraints.
    max_iter, precision, snooping, snooping_level, family_level, robust, start, variance_components
        See :func:`lidarcat.survey.adjust_survey` (family_level default
        :data:`lidarcat.bundle.reliability.FAMILY_LEVEL`).
    progress : callable, optional
        ``progress(iteration, vtpv)``.

    Returns
    -------
    SnoopingResult
        ``.result`` is the final :class:`~lidarcat.bundle.BundleResult`.
    """
    from ..survey.adjustment import adjust_survey_into

    return adjust_survey_into(survey, folder, control=control, observations=observations,
                              variance_factor=variance_factor, chi2_level=chi2_level,
                              eo_constraints=eo_constraints, max_iter=max_iter, precision=precision,
                              snooping=snooping, snooping_level=snooping_level, family_level=family_level,
                              robust=robust, start=start, variance_components=variance_components,
                              progress=progress)


def auto_variance_components(survey: Any) -> bool:
    """Whether the ``adjust-SET`` stage of ``lidarcat run`` estimates variance components (and removes
    the named observations): when image observations carry sds of their own -- the automatic tie
    points of ``lidarcat match``, thousands of redundant machine measurements whose sds are relative
    weights, their scale the block's to estimate (on the four NGI frames the tie points' residuals ask
    for their written sds x 1.3-1.5; with them as written, 1.8 m instead of 1.3 m off the published
    orientation).
    Not in a rig block (its variance components are not estimated yet).  ``lidarcat adjust`` follows
    the same rule by default (``--no-variance-components`` / ``--snooping report`` to change)."""
    if survey.files.get("rigs") is not None:    # not estimated in a rig block yet (survey.adjustment)
        return False
    return bool(np.isfinite(np.asarray(survey.image_points.sd_mm, float)).any())


def run(ctx: Context, tmp: Path) -> dict:
    """Bundle adjustment of one control set -> eop.csv, points.csv, residuals.csv, summary.json."""
    from ..survey.folder import Survey

    par = ctx.params
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]

    def prog(iteration: int, vtpv: float) -> None:
        ctx.progress(min(iteration, 49), 50)

    # data snooping, report only: the run keeps every observation and names the blunders.  Image observations
    # with sds of their own -- the automatic tie points of `lidarcat match`, thousands of redundant machine
    # measurements -- get their group factors estimated (lidarcat.bundle.variance) and the named ones removed
    matched = auto_variance_components(survey)
    sres = adjust(survey, tmp, control=par["control"], snooping="remove" if matched else "report", progress=prog,
                  eo_constraints=bool(par.get("eo_constraints")),  # photos.csv sd_X0..: GNSS/IMU
                  variance_components=matched)
    result = sres.result
    summ = result.summary()
    if not result.success:
        raise LidarcatError(f"adjustment with control set {par['control']!r} did not converge: "
                            f"{result.status} ({result.message}) after {result.n_iter} iterations")
    checks = [str(q) for q, r in zip(result.point_ids, result.point_role) if r == "check"]
    if checks and not (tmp / "check_covariance.csv").is_file():  # above the limit of write_adjustment
        write_json_atomic(tmp / "consistency.json", consistency_in_memory(result, checks, survey))
    keys = ("dof", "vtpv", "sigma0_sq", "chi2_lower", "chi2_upper", "chi2_pass", "n_iterations",
            "converged", "n_photos", "n_points", "n_observations", "n_constraints", "status")
    failed = []
    if summ.get("chi2_pass") is False:
        failed.append(f"chi-square test of the variance factor failed: v'Pv {summ['vtpv']:.2f} outside "
                      f"[{summ['chi2_lower']:.2f}, {summ['chi2_upper']:.2f}] ({summ['dof']} dof, "
                      f"{summ.get('chi2_level', 0.05):g} level; sigma0^2 {summ['sigma0_sq']:.3f}): the image or "
                      "control sds, the model or a blunder is wrong")
    blunders = [{k: b[k] for k in ("kind", "photo", "point", "w", "redundancy", "removed")}
                for b in sres.summary()["blunders"]]
    return {"adjustment": {**{k: summ.get(k) for k in keys}, "blunders": blunders},
            "control": par["control"],
            "derived_survey": bool(par.get("derived")), "failed_tests": failed}


def consistency_in_memory(result: Any, checks: list[str], survey: Any) -> dict:
    """The consistency test of the check points with their joint covariance held in memory only.

    Returns the :class:`lidarcat.accuracy.checkpoints.TestResult` as a dict (not applicable, with the
    reason, when the matrices would exceed :data:`CONSISTENCY_MEMORY_BYTES` or the reference
    has no sds).
    """
    from ..accuracy.checkpoints import TestResult, covariance_consistency_test
    from ..bundle import joint_point_covariance

    alpha = survey.assessment.alpha
    k = len(checks)
    need = 2 * (3 * k) ** 2 * 8
    gp = survey.ground_points
    ref = {str(q): (e, s) for q, e, s in zip(gp.point, gp.enh_m, gp.sd_m)}
    if need > CONSISTENCY_MEMORY_BYTES:
        reason = (f"not computed: the joint covariance of {k} check points needs {need / 2**30:.1f} GiB in "
                  f"memory (limit {CONSISTENCY_MEMORY_BYTES / 2**30:.0f} GiB); assess a subset of the check points")
    elif any(q not in ref or not np.all(np.isfinite(ref[q][1])) for q in checks):
        reason = "not computed: a check point has no reference sd_E, sd_N, sd_h"
    else:
        pos = {str(q): i for i, q in enumerate(result.point_ids)}
        adj = np.asarray(result.points_m)[[pos[q] for q in checks]]
        d = np.array([ref[q][0] for q in checks]) - adj
        cov = joint_point_covariance(result, checks)
        cov[np.diag_indices_from(cov)] += np.concatenate([ref[q][1] for q in checks]) ** 2
        test = covariance_consistency_test(d, cov, alpha, source=(
            f"joint covariance of the {k} adjusted check points, used in memory (not written above "
            "the check_covariance.csv limit) + reference sds (independent)"))
        return dataclasses.asdict(test)
    return dataclasses.asdict(TestResult("consistency", "ENh", "chi2", None, None, None, alpha, False, reason))
