"""The survey's control tables as ``lidarcat measure-control`` writes them, and their rollback.

Private to :mod:`lidarcat.stages` (the measuring, :mod:`~lidarcat.stages.measure_control`, and the
review fed back, :mod:`~lidarcat.stages._control_review`, both write through here):

* :func:`image_point_rows` -- the new ``image_points.csv``: the kept rows, then the accepted control
  observations (pixel sds times the camera's pixel size into ``sd_x_mm, sd_y_mm``);
* :func:`line_control_rows`, :func:`line_def_row`, :func:`line_obs_row` -- the new ``line_control.csv``:
  a line row holds the end points (m) and the 6 x 6 covariance ``cov_m2`` of the two plane fits, with
  ``sd_across_m`` the larger across-line sd of the two ends (the largest eigenvalue of the end's
  covariance projected across the line, ``(I - t t^T) C (I - t t^T)``); an observation row the
  edge's two image points and their sd across, px;
* :func:`edge_pairs`, :func:`line_observations` -- (photo, point) of the line observations whose line names
  its LiDAR point (one photo never gives a vertex's point and its edges), and each observation's point;
* :func:`write_checked` -- the tables (and survey.toml's ``[files]`` keys, :func:`add_files_key`) written
  atomically, the survey loaded again, and every file put back as it was when it does not load.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_csv_atomic
from ..errors import SurveyError

__all__ = ["image_point_rows", "write_checked", "add_files_key", "add_line_control_key", "line_control_rows",
           "line_def_row", "line_obs_row", "edge_pairs", "line_observations"]


def edge_pairs(header: Sequence[str] | None, rows: Any) -> set[tuple[str, str]]:
    """(photo, point) of the line observations of line_control rows (*header*, *rows*), or of the file *rows*
    (*header* None), whose line names its LiDAR ``point``."""
    return {(photo, point) for (photo, _), point in line_observations(header, rows).items() if point}


def line_observations(header: Sequence[str] | None, rows: Any) -> dict[tuple[str, str], str]:
    """``(photo, line) -> point`` of the line observations of line_control rows (*header*, *rows*), or of the
    file *rows* (*header* None; none when it does not exist): the LiDAR ``point`` its line names, or ``""``."""
    if header is None:
        from .._util import read_csv_table
        from ..survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

        if not Path(rows).is_file():
            return set()
        t = read_csv_table(rows, required=("line", "photo"), optional=tuple(
            c for c in (*LINE_COLUMNS, *LINE_EXTRA_COLUMNS) if c not in ("line", "photo")))
        header, rows = t.header, t.rows
    cells = [dict(zip(header, (str(v) for v in r))) for r in rows]
    point = {c["line"]: c.get("point", "") for c in cells if not c["photo"]}
    return {(c["photo"], c["line"]): point.get(c["line"], "") for c in cells if c["photo"]}


def image_point_rows(survey: Any, new: list[dict[str, Any]], replace: bool, drop: set | None = None
                     ) -> tuple[list[str], list[list[Any]]]:
    """The new image_points.csv: the kept rows, then the accepted control observations.

    With *replace*, rows of the (photo, point) pairs of *new* and of *drop* go; without, a pair
    already observed keeps its row and its new observation is not added.
    """
    ip = survey.image_points
    pairs = {(d["photo"], d["point"]) for d in new} | (drop or set())
    keep = np.array([not (replace and (str(a), str(b)) in pairs) for a, b in zip(ip.photo, ip.point)], bool)
    have = {(str(a), str(b)) for a, b, k in zip(ip.photo, ip.point, keep) if k}
    new = [d for d in new if (d["photo"], d["point"]) not in have]
    with_xy = bool(np.isfinite(ip.xy_mm).any()) or survey.settings.observations == "corrected" and len(ip) > 0
    header = ["photo", "point", "col_px", "row_px"] + (["x_mm", "y_mm"] if with_xy else []) + ["sd_x_mm", "sd_y_mm"]

    def num(v: float, nd: int = 6) -> Any:
        return "" if not np.isfinite(v) else round(float(v), nd)

    rows: list[list[Any]] = []
    for i in np.flatnonzero(keep):
        r = [ip.photo[i], ip.point[i], num(ip.pixel_px[i, 0], 3), num(ip.pixel_px[i, 1], 3)]
        if with_xy:
            r += [num(ip.xy_mm[i, 0]), num(ip.xy_mm[i, 1])]
        rows.append(r + [num(ip.sd_mm[i, 0]), num(ip.sd_mm[i, 1])])
    for d in new:
        cam = survey.camera_of(d["photo"])
        r = [d["photo"], d["point"], round(float(d["px"][0]), 3), round(float(d["px"][1]), 3)]
        if with_xy:
            xy = cam.pixel_to_photo(np.asarray(d["px"], float)[None])[0]
            r += [round(float(xy[0]), 6), round(float(xy[1]), 6)]
        sd = np.asarray(d["sd"], float) * np.array([cam.pixel_size_x_mm, cam.pixel_size_y_mm])
        rows.append(r + [num(sd[0], 6), num(sd[1], 6)])
    return header, rows


def write_checked(survey: Any, ip_path: Path, header: list[str] | None, rows: list[list[Any]] | None, comment: str,
                  lines: tuple[Path, list[str], list[list[Any]], str] | None = None,
                  told: tuple[Path, list[str], list[list[Any]], str] | None = None) -> None:
    """Replace image_points.csv (unless *header* is None; and line_control.csv, control_decisions.csv *told*,
    survey.toml's ``[files]`` keys of the two when it has none) atomically, then load the survey; put the old files
    back if it does not load (the error says so)."""
    from .._util import atomic_write
    from ..survey.folder import Survey

    tables = {k: v for k, v in (("line_control", lines), ("control_decisions", told)) if v is not None}
    keys = [k for k in tables if survey.files.get(k) is None and not survey.embedded]
    paths = [ip_path, *(v[0] for v in tables.values())] + ([survey.toml_path] if keys else [])
    paths += [q.with_name(q.name + ".json") for q in paths if q.suffix == ".csv"]   # the tables' metadata
    old = {q: (q.read_bytes() if q.is_file() else None) for q in paths}
    try:
        for key, v in tables.items():
            write_csv_atomic(v[0], v[1], v[2], comments=[v[3]])
            if key in keys:
                add_files_key(survey.toml_path, key, v[0])
        if header is not None:
            write_csv_atomic(ip_path, header, rows, comments=[comment])
        Survey.load(survey.root if not survey.embedded else survey.toml_path)
    except (SurveyError, OSError) as ex:
        for q, data in old.items():
            if data is None:
                q.unlink(missing_ok=True)
            else:
                with atomic_write(q, "wb") as fh:
                    fh.write(data)
        if isinstance(ex, SurveyError):
            names = ", ".join(q.name for q in paths if q.suffix != ".json")
            raise SurveyError(f"{ex} (the survey does not load with the new tables: {names} put back as they "
                              f"were)") from ex
        raise


def add_line_control_key(toml_path: Path, lines_path: Path) -> None:
    """survey.toml with ``line_control = "..."`` in its ``[files]`` table (appended when it has none)."""
    add_files_key(toml_path, "line_control", lines_path)


def add_files_key(toml_path: Path, key: str, path: Path) -> None:
    """survey.toml with ``key = "path"`` in its ``[files]`` table (appended when it has none)."""
    from .._util import atomic_write
    from .._util.tables import toml_line

    text = toml_path.read_text(encoding="utf-8")
    try:
        rel = path.resolve().relative_to(toml_path.parent.resolve()).as_posix()
    except ValueError:
        rel = path.resolve().as_posix()
    entry = f'{key} = "{rel}"'
    at = toml_line(text, "files")
    lines = text.splitlines()
    if at is None:
        lines += ["", "[files]", entry]
    else:
        lines.insert(at, entry)
    with atomic_write(toml_path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def line_control_rows(survey: Any, path: Path | None, new_lines: dict[str, tuple[str, Any, Any, Any]],
                      new_obs: list[tuple[str, str, Any]], replace_points: set[str],
                      keep: set[tuple[str, str]] | None = None) -> tuple[list[str], list[list[Any]]]:
    """The new line_control.csv: the kept rows of *path* (lines of other points, their observations, the
    observations ``(photo, line)`` in *keep* -- accepted by the user -- and their lines), then the lines
    measured now (``id -> (point, A, B, cov)``) and their observations ``(line, photo, EdgeLine)``."""
    from .._util import read_csv_table
    from ..survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    header = list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS)
    rows: list[list[Any]] = []
    if path is not None and path.is_file():
        t = read_csv_table(path, required=("line",), optional=tuple(c for c in header if c != "line"))
        col = {h: i for i, h in enumerate(t.header)}
        keep = keep or set()
        kept_lines = {lid for _, lid in keep} - set(new_lines)
        for r in t.rows:
            lid, pid = r[col["line"]], r[col["photo"]] if "photo" in col else ""
            if (lid in new_lines or lid.split("/")[0] in replace_points) and (pid, lid) not in keep and not (
                    not pid and lid in kept_lines):
                continue
            rows.append([r[col[c]] if c in col else "" for c in header])

    for lid, (pt, a, b, cov) in new_lines.items():
        rows.append(line_def_row(header, lid, pt, a, b, cov))
    for lid, pid, el in new_obs:
        rows.append(line_obs_row(header, lid, pid, el.p1_px, el.p2_px, el.sd_px))
    return header, rows


def line_def_row(header: Sequence[str], lid: str, point: str, a: Any, b: Any, cov: Any) -> list[Any]:
    """A line row of line_control.csv: end points *a*, *b* (m), ``sd_across_m`` (the larger across-line sd of
    the two ends) and the full 6 x 6 covariance *cov* (m^2) as ``cov_m2``."""
    from ..survey.lines import cov6_cell

    c = np.asarray(cov, float)
    t_ = (np.asarray(b, float) - np.asarray(a, float)) / float(np.linalg.norm(np.subtract(b, a)))
    across = np.eye(3) - np.outer(t_, t_)
    sd_across = math.sqrt(max(float(np.max(np.linalg.eigvalsh(across @ c[:3, :3] @ across))),
                              float(np.max(np.linalg.eigvalsh(across @ c[3:, 3:] @ across))), 1e-8))
    row = {"line": lid, "point": point, "e1_m": round(float(a[0]), 4), "n1_m": round(float(a[1]), 4),
           "h1_m": round(float(a[2]), 4), "e2_m": round(float(b[0]), 4), "n2_m": round(float(b[1]), 4),
           "h2_m": round(float(b[2]), 4), "sd_across_m": round(sd_across, 5), "cov_m2": cov6_cell(c)}
    return [row.get(h, "") for h in header]


def line_obs_row(header: Sequence[str], lid: str, photo: str, p1_px: Any, p2_px: Any, sd_px: float) -> list[Any]:
    """An observation row of line_control.csv: the edge's two points in the photo and their sd across, px."""
    row = {"line": lid, "photo": photo, "col1_px": round(float(p1_px[0]), 3), "row1_px": round(float(p1_px[1]), 3),
           "col2_px": round(float(p2_px[0]), 3), "row2_px": round(float(p2_px[1]), 3),
           "sd_px": round(float(sd_px), 4)}
    return [row.get(h, "") for h in header]

