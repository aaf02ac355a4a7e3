"""The lidarcat stages in pipeline order for a survey (:func:`plan_pipeline`) and ``lidarcat run``.

:func:`plan_pipeline` turns a loaded survey into the list of stages (one
adjust/assess pair per control set, plus the extracted LiDAR set when the
survey has tiles and extraction jobs; one comparison per pair with the default
set); :func:`run_pipeline` loads the survey, runs the plan with
:func:`lidarcat.pipeline.runner.run_stages` under a folder lock with the log in
``OUTDIR/lidarcat.log``, and writes ``OUTDIR/summary.json``.
"""

from __future__ import annotations

import dataclasses

import logging
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from .._util import folder_lock, inside, write_json_atomic
from ..errors import LidarcatError, SurveyError
from .runner import (
    PipelineResult,
    ProgressCallback,
    Stage,
    StageRecord,
    failed_tests,
    log_to,
    run_stages,
    safe_name,
)
from ..stages import adjust, assess, camera, compare, extract, mapping, match, measure_control, products, report, selfcal, thesis
from ..stages.report import results

__all__ = ["FROM_SURVEY", "GNSS_RUN", "plan_pipeline", "run_pipeline"]

log = logging.getLogger(__name__)


def _survey_files(survey: Any, *, lidar: bool = True) -> list[Path]:
    """survey.toml and every file it names (LiDAR tiles when *lidar*), for hashing."""
    return [survey.toml_path, *survey.files.values(), *(survey.lidar_paths if lidar else ())]


#: default of ``scale`` / ``contour_interval_m``: take them from survey.toml [assessment]
FROM_SURVEY = "survey"
#: the run of a survey without control set whose photos.csv carries sd_X0.. (stage adjust-gnss)
GNSS_RUN = "gnss"


def plan_pipeline(survey: Any, *, extracted_set: str = "lidar", scale: float | None | str = FROM_SURVEY,
                  contour_interval_m: float | None | str = FROM_SURVEY, figures: bool = False) -> list[Stage]:
    """The stages ``lidarcat run`` executes for a loaded survey, in order.

    Parameters
    ----------
    survey : lidarcat.Survey
    extracted_set : str
        Name of the control set made of the extracted LiDAR points (renamed
        ``<name>-extracted`` when the survey already has a set of that name).
    scale, contour_interval_m : float, None or FROM_SURVEY
        Map scale denominator and contour interval (m) of the check-point
        classification (PEC, the chi-square sigma0, the CE90 limit); default:
        survey.toml ``[assessment]`` (1:2000 and 2 m, as the thesis, when the
        table does not say); None: not applicable.
    figures : bool
        The extract stage also draws one figure per roof (``extract/figures/``:
        points by face, fitted planes, the vertex; thesis Figure 19).

    Returns
    -------
    list of Stage
        match (tie points: only when the photos have images and the survey too few tie points), measure_control
        (only when LiDAR control vertices lack image observations), camera, extract, one adjust-SET and assess-SET per control set, one
        compare stage per pair (default set vs each other set), thesis /
        mapping / products / selfcal when the survey asks for them, report.

    Raises
    ------
    SurveyError
        Two control sets whose names map to the same output folder.
    """
    files = _survey_files(survey, lidar=False)  # only the extraction reads the tiles
    judged = survey.assessment
    if scale == FROM_SURVEY:
        scale = judged.scale
    if contour_interval_m == FROM_SURVEY:
        contour_interval_m = judged.contour_interval_m
    files_lidar = _survey_files(survey)
    stages: list[Stage] = []

    why_no_match = match.planned(survey)    # tie points from the photos first, only for a survey that needs them
    if why_no_match is None:
        stages.append(Stage("match", "match", match.run, inputs=lambda ctx: [*files, *match.image_files(survey)],
                            description="tie points from the photos (SIFT, guided matching)"))
    # LiDAR control vertices measured in the photos (issue 29), after the tie points, before every adjustment;
    # a failed measurement skips nothing: the adjustments then take the match (or the survey's) table
    if measure_control.planned(survey) is None:
        stages.append(Stage("measure_control", "measure_control", measure_control.run,
                            requires=after_match_of(why_no_match),
                            inputs=_after_match(_survey_files(survey), measured=False,
                                                extra=lambda: match.image_files(survey)),
                            description="LiDAR control vertices measured in the photos"))
    own_pixels = bool(np.isfinite(survey.image_points.pixel_px).all(axis=1).any())
    has_pixels = own_pixels or why_no_match is None
    after_match = ("match",) if why_no_match is None else ()   # a failed match skips what adjusts its table
    stages.append(Stage(
        "camera", "camera", camera.run, inputs=_after_match(files), requires=() if own_pixels else after_match,
        skip_reason=None if has_pixels else "image_points has no pixel coordinates (col_px, row_px)",
        description="interior orientation (eq. 01-07)"))

    can_extract = bool(survey.lidar_paths) and survey.extraction_jobs is not None
    if not can_extract:
        why = ("the survey has no LiDAR tiles ([files] lidar) and no extraction jobs"
               if not survey.lidar_paths and survey.extraction_jobs is None else
               "the survey has no LiDAR tiles ([files] lidar)" if not survey.lidar_paths else
               "the survey has no extraction jobs ([files] extraction_jobs)")
    set_names = list(survey.control_sets)
    default = survey.default_control or (set_names[0] if set_names else None)
    if default in set_names:
        set_names.remove(default)
        set_names.insert(0, default)
    ext_name = extracted_set if extracted_set not in survey.control_sets else f"{extracted_set}-extracted"
    stages.append(Stage(
        "extract", "extract", extract.run, inputs=lambda ctx: files_lidar,
        params={"set": ext_name, "figures": bool(figures)},
        skip_reason=None if can_extract else why,
        description="LiDAR roof vertices -> control points"))

    runs: list[tuple[str, bool]] = [(name, False) for name in set_names]
    if can_extract:
        runs.append((ext_name, True))
    folder_of: dict[str, str] = {}
    for name, _ in runs:  # every run needs folders (and stage records) of its own
        other = folder_of.setdefault(safe_name(name), name)
        if other != name:
            raise SurveyError(f"{survey.files.get('control_sets', survey.toml_path)}: control sets "
                              f"{other!r} and {name!r} would share the output folder "
                              f"adjust-{safe_name(name)}; rename one (letters, digits, _ . - are kept)")
    # photos.csv sd_X0.. (GNSS/IMU): weighted constraints of every run; with no control set, the datum
    eo = {"eo_constraints": True} if any(ph.sd_position_m is not None or ph.sd_attitude_deg is not None
                                         for ph in survey.photos) else {}
    gnss_only = not runs and bool(eo)
    if gnss_only:
        runs.append((GNSS_RUN, False))
    if not runs:
        stages.append(Stage("adjust", "adjust", adjust.run,
                            skip_reason="the survey defines no control set (control_sets.csv) and photos.csv "
                                        "no sd_X0.. (GNSS/IMU orientations as the datum)"))
    for name, derived in runs:
        stages.append(Stage(
            f"adjust-{name}", f"adjust-{safe_name(name)}", adjust.run,
            requires=(("extract",) if derived else ()) + after_match,
            inputs=_after_match(files),
            params={"control": None if gnss_only else name, "derived": derived, **eo},
            description=f"bundle adjustment, control set {name}" if not gnss_only else
            "bundle adjustment, the GNSS/IMU orientations of photos.csv as the datum (no control set)"))
    for name, derived in runs:
        n_check = None if derived else 0 if gnss_only else len(survey.control_sets[name].check)
        stages.append(Stage(
            f"assess-{name}", f"assess-{safe_name(name)}", assess.run,
            requires=(f"adjust-{name}",) + (("extract",) if derived else ()),
            inputs=lambda ctx: files,
            params={"control": name, "derived": derived, "scale": scale,
                    "contour_interval_m": contour_interval_m, "alpha": judged.alpha,
                    "pec_class": judged.pec_class,
                    "plotting_position": judged.plotting_position},
            skip_reason=f"control set {name} has no check points" if n_check == 0 else None,
            description=f"check-point accuracy, control set {name}"))
    pairs = [(runs[0][0], other) for other, _ in runs[1:]]
    for a, b in pairs:
        stages.append(Stage(
            f"compare-{a}-{b}", f"compare-{safe_name(a)}-{safe_name(b)}", compare.run,
            requires=(f"adjust-{a}", f"adjust-{b}"), params={"first": a, "second": b},
            description=f"differences of the runs {a} and {b}"))
    if len(runs) < 2:
        stages.append(Stage("compare", "compare", compare.run,
                            skip_reason="needs two control sets (runs) to compare; the survey has "
                                        f"{len(runs)}"))
    published = survey.root / thesis.PUBLISHED
    if published.is_dir():  # a survey that reproduces the thesis (the embedded block)
        has_runs = all(r in dict(runs) for r in thesis.RUNS)
        stages.append(Stage(
            "thesis", "thesis", thesis.run, requires=tuple(f"adjust-{r}" for r in thesis.RUNS) if has_runs else (),
            inputs=lambda ctx: [*files, *thesis.published_files(published).values()],
            params={"alpha": judged.alpha},
            skip_reason=None if has_runs else f"needs the control sets {' and '.join(thesis.RUNS)} of the thesis",
            description="thesis section 4.4 (Tables 8-15) beside this run"))
    if "mapping" in survey_tables(survey):   # only surveys that ask for map products get the stage
        stages.append(_mapping_stage(survey, runs, files_lidar))
    if "products" in survey_tables(survey):  # only surveys that ask for LiDAR products get the stage
        stages.append(_products_stage(survey, files_lidar))
    if selfcal.planned(survey):
        stages.append(Stage("selfcal", "selfcal", selfcal.run, inputs=_after_match(files), params=dict(eo),
                            description="adjustment with additional parameters ([self_calibration])"))
    upstream = tuple(s.name for s in stages)
    stages.append(Stage("report", "report", report.run, uses=upstream,
                        inputs=lambda ctx: files, description="HTML / Markdown / JSON report"))
    return stages


def after_match_of(why_no_match: str | None) -> tuple[str, ...]:
    """``requires`` of a stage that reads the match stage's table when it is planned."""
    return ("match",) if why_no_match is None else ()


def _after_match(files: list[Path], *, measured: bool = True, extra: Any = None) -> Any:
    """``inputs`` of a stage that adjusts the image observations: once the match stage is done (ran or
    reused), ``ctx["survey"]`` becomes the survey with ``match/image_points.csv`` and that table is an input;
    once the measure_control stage is done (and *measured*), its table (the match's rows plus the LiDAR
    control observations) instead."""
    def inputs(ctx: Any) -> list[Path]:
        more = list(extra()) if extra is not None else []
        if ctx is None:
            return [*files, *more]
        for stage in (("measure_control", "match") if measured else ("match",)):
            if ctx.done(stage):
                table = ctx.folder(stage) / "image_points.csv"
                ctx.values["survey"] = match.survey_with(ctx["survey"], table)
                lines = ctx.folder(stage) / "line_control.csv"    # measure_control's roof edges (line control)
                if stage == "measure_control" and lines.is_file():
                    sv = ctx.values["survey"]
                    ctx.values["survey"] = dataclasses.replace(sv, files={**sv.files, "line_control": lines})
                    return [*files, *more, table, lines]
                return [*files, *more, table]
        return [*files, *more]
    return inputs


def survey_tables(survey: Any) -> set[str]:
    """The top-level tables of the survey's survey.toml (as :meth:`lidarcat.Survey.load` parsed it)."""
    return set(survey.config.tables)


def _mapping_stage(survey: Any, runs: Sequence[tuple[str, bool]], files_lidar: list[Path]) -> Stage:
    """Orthophotos / mosaic of the default run when survey.toml's [mapping] asks (stages/mapping.py)."""
    cfg = mapping.settings(survey)
    first = runs[0][0] if runs else None
    why = ("[mapping] asks for neither orthophotos (orthophotos = false) nor features"
           if not cfg["orthophotos"] and not cfg["features"] else
           "the survey has no LiDAR tiles ([files] lidar) for the surface model" if not survey.lidar_paths else
           "no adjustment (control set) to take the orientations from" if first is None else None)
    images = survey.root / (cfg.get("images") or "images")      # read only for the orthophotos
    mapped = [survey.root / f for f in [*(cfg.get("features") or {}).values(), cfg.get("reference")] if f]
    return Stage("mapping", "mapping", mapping.run,
                 requires=(f"adjust-{first}",) if why is None else (),
                 inputs=lambda ctx: [*files_lidar,
                                     *(sorted(p for p in images.glob("*") if p.is_file()) if cfg["orthophotos"]
                                       else ()),
                                     *(p for p in mapped if p.is_file())],
                 params={"adjust": f"adjust-{first}", **cfg},
                 skip_reason=why,
                 description="orthophotos, mosaic and monorestituted features of the adjusted photos ([mapping])")


def _products_stage(survey: Any, files_lidar: list[Path]) -> Stage:
    """Ground, DTM/DSM, contours, hypsometry, sheets of the LiDAR tiles when survey.toml's [products] asks."""
    cfg = products.settings(survey)
    what = products.asked(cfg)
    why = ("the survey has no LiDAR tiles ([files] lidar)" if not survey.lidar_paths else
           "[products] asks for nothing (every product false)" if not what else None)
    chart_mosaic = [survey.root / cfg["chart_mosaic"]] if cfg.get("chart_mosaic") else []
    # the calibration's trajectory (SBET) and control surface: their content, not only their names
    checks = [survey.root / cfg[k] for k in ("calibration_trajectory", "calibration_control") if cfg.get(k)]
    return Stage("products", "products", products.run,
                 inputs=lambda ctx: [*files_lidar, *(p for p in [*chart_mosaic, *checks] if p.is_file())],
                 params=dict(cfg),
                 uses=("mapping",) if cfg.get("charts") and "mapping" in survey_tables(survey) else (),
                 skip_reason=why, description=f"LiDAR products ({', '.join(what) or 'none'}) ([products])")


def run_pipeline(
    survey_path: str | os.PathLike | None = None,
    outdir: str | os.PathLike | None = None,
    *,
    force: bool = False,
    progress: ProgressCallback | None = None,
    scale: float | None | str = FROM_SURVEY,
    contour_interval_m: float | None | str = FROM_SURVEY,
    figures: bool = False,
) -> PipelineResult:
    """Run the whole pipeline on a survey folder (``lidarcat run``).

    Parameters
    ----------
    survey_path : path or None
        The survey folder; None runs the embedded thesis block.
    outdir : path or None
        Output folder; default ``Survey.output_dir()`` (``SURVEY/out``, or
        ``./lidarcat-out`` for the embedded block).
    force : bool
        Recompute every stage even when its inputs are unchanged.
    progress : callable, optional
        ``progress(stage, done, total)``.
    scale, contour_interval_m : float, None or FROM_SURVEY
        Map scale denominator and contour interval (m) for the classification
        of the check points; default: survey.toml ``[assessment]`` (1:2000 and
        2 m, as the thesis, when it does not say); None: not applicable.
    figures : bool
        Write one extraction figure per roof into ``OUTDIR/extract/figures/``.

    Returns
    -------
    PipelineResult
        ``result.status`` is ``ok``, ``test failed`` (an adjustment failed its
        chi-square test of the variance factor: outputs written, model or
        weights suspect) or ``stage failed``; ``result.ok`` is True only for
        ``ok``.  ``OUTDIR/summary.json`` holds ``result.summary`` (with
        ``status``, ``ok``, ``failed`` and ``tests_failed``).

    Raises
    ------
    SurveyError
        The survey folder is invalid (nothing is run).
    """
    from ..survey.folder import Survey

    survey = Survey.load(survey_path)
    out = Path(survey.output_dir(outdir))
    if outdir is None and not survey.embedded:  # SURVEY/out: chosen by the survey folder, so no link out of it
        inside(survey.root, out)
    inside(out, out / "lidarcat.log")  # a shipped link would be touched and appended to
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "lidarcat.log").touch()
    except OSError as ex:
        raise LidarcatError(f"{out}: cannot write the output folder ({ex.strerror or ex}); "
                            f"choose another with -o/--outdir") from ex
    with folder_lock(out), log_to(out / "lidarcat.log"):
        log.info("lidarcat %s run: survey %r (%s) -> %s%s", __version__, survey.name, survey.root,
                 out, " (forced)" if force else "")
        stages = plan_pipeline(survey, scale=scale, contour_interval_m=contour_interval_m, figures=figures)
        t0 = time.perf_counter()
        records = run_stages(stages, out, force=force, progress=progress,
                             values={"survey": survey, "plan": stages})
        summary = _summary(survey, out, records, time.perf_counter() - t0)
        write_json_atomic(out / "summary.json", summary)
        failed = [r.name for r in records if r.status == "failed"]
        if failed:
            log.error("run finished with failed stage(s): %s", ", ".join(failed))
        elif summary["tests_failed"]:
            log.error("run finished, but a statistical test failed: %s", "; ".join(summary["tests_failed"]))
        else:
            log.info("run finished: %s", ", ".join(f"{r.name} {r.status}" for r in records))
    return PipelineResult(out, tuple(records), summary)


def _summary(survey: Any, out: Path, records: Sequence[StageRecord], seconds: float) -> dict:
    report = next((r.result.get("index") for r in records if r.name == "report" and r.done), None)
    failed = [r.name for r in records if r.status == "failed"]
    tests = failed_tests(records)
    status = "stage failed" if failed else "test failed" if tests else "ok"
    return {
        "lidarcat_version": __version__,
        "survey": {"name": survey.name, "root": str(survey.root), "crs": survey.crs,
                   "embedded": bool(survey.embedded)},
        "outdir": str(out),
        "ok": status == "ok",
        "status": status,
        "failed": failed,
        "tests_failed": tests,
        "stages": [r.to_dict() for r in records],
        "stages_ran": [r.name for r in records if r.status == "ran"],
        "stages_reused": [r.name for r in records if r.status == "reused"],
        "stages_skipped": [r.name for r in records if r.status == "skipped"],
        "seconds": round(seconds, 3),
        **results(records),
        "report": report,
    }
