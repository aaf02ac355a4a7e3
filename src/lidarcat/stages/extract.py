"""Stage ``extract``: roof planes -> LiDAR control points, and a derived survey.

Runs the survey's extraction jobs on its LiDAR tiles
(:func:`lidarcat.control.batch.extract_batch`) and writes ``control.csv``,
``planes.csv`` and ``survey/``: a copy of the survey whose ground points
include the extracted points (source ``lidar``, their propagated standard
deviations) and a control set of them, in which every other ground point is a
check point.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarcatError
from .context import StageContext as Context

__all__ = ["run"]

log = logging.getLogger(__name__)


def run(ctx: Context, tmp: Path) -> dict:
    """Extract the roof vertices of the survey's jobs; write control.csv and a derived survey.

    The derived survey (``extract/survey/``) is the original one plus the
    extracted points as ground points (source ``lidar``, their propagated
    standard deviations) and a control set of them, in which every other
    ground point is a check point.
    """
    from ..control.batch import write_control_csv, write_figures, write_planes_csv

    survey = ctx["survey"]
    par = ctx.params
    name = par["set"]
    points = _extract_jobs(survey, ctx)
    write_control_csv(tmp / "control.csv", points, comments=[
        f"Roof vertices extracted from the LiDAR tiles of survey {survey.name} "
        f"({survey.extraction_jobs.name}); metres, sds propagated from the planes."])
    write_planes_csv(tmp / "planes.csv", points)
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
    if par.get("figures"):
        write_figures(tmp / "figures", points)
    status: dict[str, int] = {}
    for cp in points:
        status[cp.status] = status.get(cp.status, 0) + 1
    return {"n_jobs": len(points), "n_ok": len(ok), "statuses": status, "control_set": name,
            "not_measured": unmeasured,
            "points": {cp.point_id: {"status": cp.status, "n_planes": int(cp.n_planes),
                                     "sd_m": [float(v) for v in cp.sd_m]} for cp in points}}


def _extract_jobs(survey: Any, ctx: Context) -> list:
    """ControlPoints of every extraction job of *survey* (failed jobs included, falsy)."""
    from ..control.batch import extract_batch, read_jobs

    jobs = read_jobs(survey.extraction_jobs)
    done = [0]

    def tick(n: int = 1) -> None:
        done[0] += n
        ctx.progress(done[0], len(jobs) + 1)

    ctx.progress(0, len(jobs) + 1)
    # the tile index (with the block index of each LAZ tile) persists across runs
    return list(extract_batch(jobs, lidar=list(survey.lidar_paths),
                              crs=survey.lidar_crs or survey.crs, progress=tick,
                              index_cache=ctx.outdir / ".lidar_index.json"))


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
    import tomllib

    from .._util import read_csv_table, write_csv_atomic, write_text_atomic

    folder.mkdir(parents=True, exist_ok=True)
    data = tomllib.loads(survey.toml_path.read_text(encoding="utf-8-sig"))
    new_files: dict[str, str] = {}
    for key in ("camera", "photos", "image_points"):
        src = survey.files[key]
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
    sv = dict(data.get("survey", {}))
    sv["description"] = (sv.get("description", "")
                         + " [with the LiDAR control extracted by lidarcat run]").strip()
    lines = ["# Derived by lidarcat run: the survey plus the extracted LiDAR control points.", "", "[survey]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in sv.items()]
    lines += ["", "[files]"] + [f"{k} = {_toml_value(v)}" for k, v in new_files.items()]
    for table in ("adjustment", "assessment"):  # [lidar] is left out with the tiles
        if data.get(table):
            lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    write_text_atomic(folder / "survey.toml", "\n".join(lines) + "\n")
    return [pid for pid in extracted if pid not in measured]
