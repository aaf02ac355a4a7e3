"""Stage ``extract``: roof planes -> LiDAR control points, and a derived survey.

:func:`extract` is the action of ``lidarcat extract`` (a job file or ``--at``)
and of this stage: jobs and tiles in, ``control.csv``, ``planes.csv`` and the
figures out (:func:`lidarcat.control.batch.extract_batch`).  The stage runs it
on the survey's extraction jobs and LiDAR tiles and adds ``survey/``: a copy of
the survey whose ground points include the extracted points (source ``lidar``,
their propagated standard deviations) and a control set of them, in which every
other ground point is a check point.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarcatError
from .context import StageContext as Context

__all__ = ["extract", "extraction_params", "run"]

log = logging.getLogger(__name__)


def extract(jobs: str | os.PathLike | Sequence[Any], *, lidar: Sequence[str | os.PathLike] | None = None,
            crs: Any = None, preset: str = "default", radius_m: float | None = None,
            fit_radius_m: float | None = None, stability_check: bool | None = None,
            spec_sd: tuple[float, float] | None = None, index_cache: str | os.PathLike | None = None,
            control_csv: str | os.PathLike | None = None, planes_csv: str | os.PathLike | None = None,
            figures: str | os.PathLike | None = None,
            progress: Callable[[int], Any] | None = None) -> list[Any]:
    """The action of ``lidarcat extract`` (jobs, ``--at``) and of the stage ``extract``: roofs to control points.

    Parameters
    ----------
    jobs : path or sequence of Job
        A job file (:func:`lidarcat.control.batch.read_jobs`) or the jobs themselves.
    lidar : sequence of path, optional
        Tiles for every job (default: each job's own file).
    crs : CRS-like, optional
        CRS of tiles that carry none.
    preset : {"default", "thesis"}
        Parameter preset (:func:`lidarcat.control.params.get_params`).
    radius_m : float, optional
        Clip radius of the jobs without one, m (default: the preset's).
    fit_radius_m : float, optional
        Radius (m) of the local extraction: the vertex found is extracted again from the clip of this
        radius centred on it (:mod:`lidarcat.control.localfit`; 5 m is the value measured); 0 = off, the
        search clip's vertex; default: the preset's (5 m; thesis: off).
    stability_check : bool, optional
        Refuse vertices that move with the clip radius (:mod:`lidarcat.control.stability`); default:
        the preset's (on; thesis: off).
    spec_sd : (plan, height), optional
        Replace the propagated sds by these specification sds, m.
    index_cache : path, optional
        JSON tile index of *lidar*, reused and updated.
    control_csv, planes_csv : path, optional
        Write the control points (one row per job, failed ones with their status and
        reason) and their planes there.
    figures : path, optional
        Folder receiving one operator figure per point (PNG).
    progress : callable, optional
        Called with 1 after each job.

    Returns
    -------
    list of ControlPoint
        One per job, in job order (failed jobs falsy, with a status).
    """
    from ..control.batch import extract_batch, read_jobs, write_control_csv, write_figures, write_planes_csv

    if isinstance(jobs, (str, os.PathLike)):
        source, job_list = f"the jobs of {Path(jobs).name}", read_jobs(jobs)
    else:
        source, job_list = "the given positions", list(jobs)
    points = extract_batch(job_list, lidar=list(lidar) if lidar else None, crs=crs,
                           params=extraction_params(preset, radius_m, fit_radius_m, stability_check),
                           spec_sd=spec_sd, progress=progress,
                           index_cache=index_cache)
    if control_csv:
        sds = (f"specification sds {spec_sd[0]:g} m (plan), {spec_sd[1]:g} m (height)" if spec_sd
               else "sds propagated from the planes")
        write_control_csv(control_csv, points, comments=[
            f"Roof vertices extracted by lidarcat (preset {preset}) at {source}; metres, {sds}."])
    if planes_csv:
        write_planes_csv(planes_csv, points)
    if figures:
        write_figures(figures, points)
    return points


def extraction_params(preset: str = "default", radius_m: float | None = None, fit_radius_m: float | None = None,
                      stability_check: bool | None = None) -> Any:
    """The :class:`~lidarcat.control.params.ExtractionParams` of *preset* with the user's choices (None: the preset's).

    *fit_radius_m* 0 is the clip's whole faces (``fit_radius_m=None`` of the params); *stability_check*
    False switches the radius-stability check off (``stability_scales=()``), True on at the default scales.
    """
    from ..control.params import ExtractionParams, get_params

    p = get_params(preset, radius_m=radius_m)
    if fit_radius_m is not None:
        p = p.replace(fit_radius_m=None if fit_radius_m == 0 else float(fit_radius_m))
    if stability_check is not None:
        p = p.replace(stability_scales=ExtractionParams().stability_scales if stability_check else ())
    return p


def run(ctx: Context, tmp: Path) -> dict:
    """Extract the roof vertices of the survey's jobs; write control.csv and a derived survey.

    The derived survey (``extract/survey/``) is the original one plus the
    extracted points as ground points (source ``lidar``, their propagated
    standard deviations) and a control set of them, in which every other
    ground point is a check point.
    """
    from ..control.batch import read_jobs

    survey = ctx["survey"]
    par = ctx.params
    name = par["set"]
    n_jobs = len(read_jobs(survey.extraction_jobs))
    done = [0]

    def tick(n: int = 1) -> None:
        done[0] += n
        ctx.progress(done[0], n_jobs + 1)

    ctx.progress(0, n_jobs + 1)
    # the tile index (with the block index of each LAZ tile) persists across runs
    points = extract(survey.extraction_jobs, lidar=list(survey.lidar_paths), crs=survey.lidar_crs or survey.crs,
                     index_cache=ctx.outdir / ".lidar_index.json", control_csv=tmp / "control.csv",
                     planes_csv=tmp / "planes.csv", figures=tmp / "figures" if par.get("figures") else None,
                     progress=tick)
    ok = [cp for cp in points if cp and np.all(np.isfinite(cp.sd_m)) and np.all(cp.sd_m > 0)]
    if not ok:
        raise LidarcatError(f"no roof vertex could be extracted from {survey.extraction_jobs} "
                            f"({len(points)} jobs; see {ctx.stage.folder}/control.csv for the reasons)"
                            if points else f"{survey.extraction_jobs}: no extraction job")
    unmeasured = _write_derived_survey(survey, ok, name, tmp / "survey")
    if unmeasured:
        log.warning("extracted point(s) %s: measured on no photo (%s), so they cannot control the "
                    "block; check the ids in %s", ", ".join(unmeasured), survey.files["image_points"],
                    survey.extraction_jobs)
    status: dict[str, int] = {}
    for cp in points:
        status[cp.status] = status.get(cp.status, 0) + 1
    return {"n_jobs": len(points), "n_ok": len(ok), "statuses": status, "control_set": name,
            "not_measured": unmeasured,
            "points": {cp.point_id: {"status": cp.status, "n_planes": int(cp.n_planes),
                                     "sd_m": [float(v) for v in cp.sd_m]} for cp in points}}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def _write_derived_survey(survey: Any, points: Sequence[Any], set_name: str, folder: Path) -> list[str]:
    """A copy of *survey* whose ground points and control sets include the extracted points.

    Returns the ids of extracted points that no photo measures (they cannot control the block).
    """
    import shutil

    from .._util import read_csv_table, write_csv_atomic, write_text_atomic

    folder.mkdir(parents=True, exist_ok=True)
    written = survey.config.written   # survey.toml as Survey.load read it (no second read)
    new_files: dict[str, str] = {}
    for key in ("camera", "photos", "image_points"):
        src = survey.files[key]
        if key == "photos":   # its image paths stay right from the new folder
            survey.copy_photos_csv(folder / f"{key}{src.suffix}")
        else:
            shutil.copyfile(src, folder / f"{key}{src.suffix}")
        new_files[key] = f"{key}{src.suffix}"
    measured = set(survey.image_points.point.tolist())
    ids = []
    for cp in points:
        pid = str(cp.point_id)
        if pid not in measured and pid[:1] in "Pp" and pid[1:] in measured:
            pid = pid[1:]  # thesis job files name point 704 "P704"
        ids.append(pid)
    extracted = dict(zip(ids, points))
    gp = survey.ground_points
    rows = [[str(q), *enh, *sd, str(src)] for q, enh, sd, src in
            zip(gp.point, gp.enh_m, gp.sd_m, gp.source) if str(q) not in extracted]
    for pid, cp in extracted.items():
        rows.append([pid, *cp.enh_m, *cp.sd_m, "lidar"])
    write_csv_atomic(folder / "ground_points.csv", ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                     rows, comments=[f"Ground points of {survey.name} plus the roof vertices extracted "
                                     "by lidarcat run (source lidar)."])
    cs_rows = []
    if "control_sets" in survey.files:
        t = read_csv_table(survey.files["control_sets"], required=("set", "point", "role"),
                           optional=("sd_E", "sd_N", "sd_h"))
        for row in t.rows:
            d = dict(zip(t.header, row))
            cs_rows.append([d["set"], d["point"], d["role"], d.get("sd_E", ""), d.get("sd_N", ""),
                            d.get("sd_h", "")])
    exclude = survey.settings.exclude_points
    for pid in extracted:
        cs_rows.append([set_name, pid, "control", "", "", ""])
    for r in rows:
        if r[0] not in extracted and r[0] not in exclude:
            cs_rows.append([set_name, r[0], "check", "", "", ""])
    write_csv_atomic(folder / "control_sets.csv", ["set", "point", "role", "sd_E", "sd_N", "sd_h"],
                     cs_rows, comments=[f"Control sets of {survey.name}; set {set_name}: the extracted "
                                        "roof vertices as control, every other ground point as check."])
    new_files["ground_points"] = "ground_points.csv"
    new_files["control_sets"] = "control_sets.csv"
    sv = written("survey")
    sv["description"] = (sv.get("description", "")
                         + " [with the LiDAR control extracted by lidarcat run]").strip()
    lines = ["# Derived by lidarcat run: the survey plus the extracted LiDAR control points.", "", "[survey]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in sv.items()]
    lines += ["", "[files]"] + [f"{k} = {_toml_value(v)}" for k, v in new_files.items()]
    for table in ("adjustment", "assessment"):  # [lidar] is left out with the tiles
        if written(table):
            lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in written(table).items()]
    write_text_atomic(folder / "survey.toml", "\n".join(lines) + "\n")
    return [pid for pid in extracted if pid not in measured]
