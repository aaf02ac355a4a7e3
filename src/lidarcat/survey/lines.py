"""``line_control.csv``: control lines (LiDAR roof edges) and their measurements in the photos.

One file, two kinds of row (``[files] line_control`` in survey.toml):

* a **line** (``photo`` empty): its two end points ``e1_m, n1_m, h1_m, e2_m, n2_m, h2_m`` (survey
  CRS, m; any two distinct points of the 3-D line, e.g. the plane intersection clipped to the
  roof) and the sds of those end points ``sd_across_m`` (across the line) and ``sd_along_m``
  (along it; empty: the same), or their full 6 x 6 covariance ``cov_m2`` (the upper triangle's
  21 numbers, row by row, separated by spaces; it replaces the sds: a line from two fitted
  planes has correlated ends);
* an **observation** (``photo`` given): two points on the edge in that photo, either ``x1_mm,
  y1_mm, x2_mm, y2_mm`` (corrected photo coordinates, mm, x right, y up, as ``x_mm, y_mm`` of
  image_points.csv) with their sd across the edge ``sd_mm``, or ``col1_px, row1_px, col2_px,
  row2_px`` (pixels, as ``col_px, row_px``; run through the photo's camera, eq. 01-07) with
  ``sd_px``.

A line row may name the LiDAR control ``point`` it was measured at (``lidarcat measure-control``
writes the roof edges of a vertex so, with the vertex's id): such a line is control only in the
adjustments where that point is control (a control set without it -- the GPS targets' -- does not
use it, nor its observations); a line without ``point`` is control in every adjustment.

Columns a row does not use stay empty.  Every error names the file and line: an unknown photo,
an observation of a line the file does not define, a line defined twice or measured twice on one
photo, a line or edge of zero length, a missing or non-finite number.  The rows become
:class:`lidarcat.bundle.lines.ControlLine` and :class:`~lidarcat.bundle.lines.LineObservation`
(:func:`read_line_control`); :func:`write_line_residuals` writes ``line_residuals.csv`` of an
adjustment (residuals, redundancy numbers, w-tests: a wrong line observation is the row with
``rejected`` true).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from .._util import excerpt
from .._util.tables import parse_float, read_csv_table
from ..bundle.lines import ControlLine, LineObservation
from ..errors import DatumError, SurveyError, location

__all__ = ["LINE_COLUMNS", "LINE_EXTRA_COLUMNS", "LINE_RESIDUAL_COLUMNS", "photo_cameras", "read_line_control",
           "write_line_residuals", "cov6_cell"]

#: columns of ``line_control.csv``
LINE_COLUMNS = ("line", "photo", "e1_m", "n1_m", "h1_m", "e2_m", "n2_m", "h2_m", "sd_across_m", "sd_along_m",
                "x1_mm", "y1_mm", "x2_mm", "y2_mm", "sd_mm", "col1_px", "row1_px", "col2_px", "row2_px", "sd_px")
#: the optional columns (``lidarcat measure-control`` writes them): the line's LiDAR point, its 6 x 6 covariance
LINE_EXTRA_COLUMNS = ("point", "cov_m2")
_LINE = ("e1_m", "n1_m", "h1_m", "e2_m", "n2_m", "h2_m", "sd_across_m")
_OBS = ("x1_mm", "y1_mm", "x2_mm", "y2_mm", "sd_mm")
_PX = ("col1_px", "row1_px", "col2_px", "row2_px", "sd_px")

#: columns of ``line_residuals.csv`` (:class:`lidarcat.bundle.line_tests.LineTests`)
LINE_RESIDUAL_COLUMNS = ("line", "photo", "v_a_mm", "v_b_mm", "v_a_px", "v_b_px", "redundancy_a",
                         "redundancy_b", "w", "w_critical", "rejected")


def _number(path: Path, line: int, name: str, cell: str, *, positive: bool = False) -> float:
    if cell == "":
        raise SurveyError(f"{location(path, line, name)}: empty value; a number is required")
    try:
        v = parse_float(cell)
    except ValueError as ex:
        raise SurveyError(f"{location(path, line, name)}: {ex}") from None
    if not math.isfinite(v):
        raise SurveyError(f"{location(path, line, name)}: {excerpt(cell)} is not a finite number")
    if positive and v <= 0:
        raise SurveyError(f"{location(path, line, name)}: must be positive, got {excerpt(cell)}")
    return v


def read_line_control(path: str | Path, photo_ids: Iterable[str], cameras: Mapping[str, Any] | None = None,
                      control_points: Iterable[str] | None = None,
                      ) -> tuple[list[ControlLine], list[LineObservation]]:
    """The control lines and their observations of *path* (``line_control.csv``).

    Parameters
    ----------
    path : path of the file
    photo_ids : the survey's photo ids (an observation on another photo is an error)
    cameras : photo id -> :class:`lidarcat.geometry.camera.Camera`, optional
        For pixel coordinates (``col1_px`` ...) and the observations' pixel size; without it a
        pixel row is an error.
    control_points : ids, optional
        The adjustment's control points: a line whose ``point`` is not among them is left out with
        its observations (None: every line).

    Raises
    ------
    SurveyError
        With ``file:line: ...`` (see the module docstring).
    """
    path = Path(path)
    t = read_csv_table(path, required=("line", "photo", *_LINE), optional=("point", "sd_along_m", "cov_m2", *_OBS,
                                                                            *_PX))
    col = {h: i for i, h in enumerate(t.header)}
    photos = {str(p) for p in photo_ids}
    lines: dict[str, ControlLine] = {}
    defined_at: dict[str, int] = {}
    obs: list[tuple[int, LineObservation]] = []
    seen: dict[tuple[str, str], int] = {}
    of_point: dict[str, str] = {}
    for row, ln in zip(t.rows, t.lines):
        def cell(name: str, row: tuple[str, ...] = row) -> str:
            return row[col[name]] if name in col else ""

        lid, photo = cell("line"), cell("photo")
        if not lid:
            raise SurveyError(f"{location(path, ln, 'line')}: empty line id")
        if photo == "":
            stray = [c for c in (*_OBS, *_PX) if cell(c)]
            if stray:
                raise SurveyError(f"{location(path, ln, stray[0])}: a line row (photo empty) has no image "
                                  "coordinates; give the photo or leave the cell empty")
            if lid in lines:
                raise SurveyError(f"{location(path, ln, 'line')}: line {excerpt(lid)} is already defined "
                                  f"on line {defined_at[lid]}")
            v = [_number(path, ln, c, cell(c)) for c in _LINE[:6]]
            sd_across = _number(path, ln, "sd_across_m", cell("sd_across_m"), positive=True)
            along = cell("sd_along_m")
            sd_along = sd_across if along == "" else _number(path, ln, "sd_along_m", along, positive=True)
            if np.linalg.norm(np.subtract(v[3:], v[:3])) <= 0:
                raise SurveyError(f"{location(path, ln)}: line {excerpt(lid)}: its end points coincide "
                                  "(a line of zero length)")
            lines[lid] = ControlLine.from_sds(lid, v[:3], v[3:], sd_across, sd_along)
            if cell("cov_m2"):
                lines[lid] = ControlLine(lid, v[:3], v[3:], _cov6(path, ln, cell("cov_m2")))
            if cell("point"):
                of_point[lid] = cell("point")
            defined_at[lid] = ln
            continue
        stray = [c for c in _LINE if cell(c)]
        if stray:
            raise SurveyError(f"{location(path, ln, stray[0])}: an observation row (photo {excerpt(photo)}) has "
                              "no 3-D coordinates; define the line on a row of its own with photo empty")
        if photo not in photos:
            raise SurveyError(f"{location(path, ln, 'photo')}: unknown photo {excerpt(photo)} (not in photos.csv)")
        if (lid, photo) in seen:
            raise SurveyError(f"{location(path, ln)}: line {excerpt(lid)} is measured twice on photo "
                              f"{excerpt(photo)} (also on line {seen[(lid, photo)]}); keep one measurement")
        seen[(lid, photo)] = ln
        has_mm, has_px = any(cell(c) for c in _OBS), any(cell(c) for c in _PX)
        if has_mm == has_px:
            raise SurveyError(f"{location(path, ln)}: line {excerpt(lid)} on photo {excerpt(photo)}: give the image "
                              "points either in mm (x1_mm, y1_mm, x2_mm, y2_mm, sd_mm) or in pixels (col1_px, "
                              "row1_px, col2_px, row2_px, sd_px)" + (", not both" if has_mm else ""))
        cam = None if cameras is None else cameras.get(photo)
        pixel_mm = math.nan if cam is None else 0.5 * (cam.pixel_size_x_mm + cam.pixel_size_y_mm)
        cols = _OBS if has_mm else _PX
        v = [_number(path, ln, c, cell(c)) for c in cols[:4]]
        sd = _number(path, ln, cols[4], cell(cols[4]), positive=True)
        xy = np.reshape(v, (2, 2))
        if has_px:
            if cam is None:
                raise SurveyError(f"{location(path, ln, 'col1_px')}: pixel coordinates need the photo's camera "
                                  "(read the file through Survey.load)")
            xy, sd = cam.pixel_to_photo(xy), sd * pixel_mm
        try:
            o = LineObservation(lid, photo, xy[0], xy[1], sd, pixel_mm)
        except DatumError as ex:
            raise SurveyError(f"{location(path, ln)}: {ex}") from None
        obs.append((ln, o))
    for ln, o in obs:
        if o.line not in lines:
            raise SurveyError(f"{location(path, ln, 'line')}: observation of line {excerpt(o.line)}, which no row "
                              "defines (a row with this line id and photo empty)")
    if control_points is not None:
        ctrl = {str(q) for q in control_points}
        lines = {k: v for k, v in lines.items() if k not in of_point or of_point[k] in ctrl}
        obs = [(ln, o) for ln, o in obs if o.line in lines]
    return list(lines.values()), [o for _, o in obs]


def _cov6(path: Path, line: int, cell: str) -> np.ndarray:
    """The ``cov_m2`` cell: the 21 numbers of the upper triangle (row by row) of the 6 x 6 covariance of
    the end points (E1 N1 h1 E2 N2 h2, m^2), separated by spaces."""
    parts = cell.split()
    if len(parts) != 21:
        raise SurveyError(f"{location(path, line, 'cov_m2')}: 21 numbers (the upper triangle of the 6 x 6 "
                          f"covariance, row by row) separated by spaces, got {len(parts)}")
    vals = [_number(path, line, "cov_m2", c) for c in parts]
    cov = np.zeros((6, 6))
    cov[np.triu_indices(6)] = vals
    cov = cov + np.triu(cov, 1).T
    if np.min(np.linalg.eigvalsh(cov)) < -1e-6 * max(float(np.max(np.abs(np.diag(cov)))), 1e-30):
        raise SurveyError(f"{location(path, line, 'cov_m2')}: not a covariance (not positive semi-definite)")
    return cov


def cov6_cell(cov_m2: Any) -> str:
    """The ``cov_m2`` cell of a 6 x 6 covariance (m^2): its upper triangle, row by row."""
    c = np.asarray(cov_m2, dtype=np.float64).reshape(6, 6)
    return " ".join(f"{v:.8g}" for v in c[np.triu_indices(6)])


def photo_cameras(photos: Iterable[Any], cameras: Mapping[str, Any]) -> dict[str, Any]:
    """photo id -> its :class:`~lidarcat.geometry.camera.Camera` (the *cameras* argument of
    :func:`read_line_control`) from the survey's photos (``id``, ``camera``) and cameras."""
    return {p.id: cameras[p.camera] for p in photos}


def write_line_residuals(result: Any, folder: Path, write_csv: Callable[..., Any],
                         pixel_mm: float | None = None, level: float = 0.001) -> dict:
    # pixel_mm None: each observation's own pixel size (LineControl.pixel_mm)
    """``line_residuals.csv`` of an adjustment with line control; returns the summary keys
    (``line_control``: observations, rejected ones named, the largest w).  *level*: alpha_1 of the
    tests (``lidarcat adjust`` passes its data snooping's level, so that the 2-D tests here are those
    of reliability.csv and blunders.csv)."""
    from ..bundle.line_tests import line_tests

    p = result.problem
    if np.isfinite(result.eo_cov).all():
        t = line_tests(result, pixel_mm=pixel_mm, level=level)
        rows = [[lid, ph, *v, *vp, *r, w, t.critical_w, bool(w > t.critical_w)]
                for lid, ph, v, vp, r, w in zip(t.line_ids, t.photo_ids, t.residuals_mm, t.residuals_px,
                                                 t.redundancy, t.w)]
        rejected = [str(t.labels[k]) for k in t.rejected]
        worst = float(np.nanmax(t.w)) if len(t.w) and np.isfinite(t.w).any() else math.nan
    else:                    # no covariances (precision "none"): residuals only
        from ..bundle.lines import line_residuals_mm

        r = line_residuals_mm(p, result.eo_params)
        L = p.lines
        nan = math.nan
        rows = [[L.line_ids[k], p.photo_ids[i], *v, *(v / px), nan, nan, nan, nan, ""]
                for k, i, v, px in zip(L.line_index, L.photo_index, r, L.pixel_mm)]
        rejected, worst = [], math.nan
    write_csv(folder / "line_residuals.csv", LINE_RESIDUAL_COLUMNS, rows, comments=[
        ("line control: v_a, v_b = signed distances (adjusted - observed) of the projected 3-D end points A, B "
         "from the measured image line (mm, px); redundancy numbers; w = sqrt of the 2-D group test, "
         "rejected when above w_critical (B-method)")])
    return {"line_control": {"observations": len(rows), "scalar_observations": 2 * len(rows),
                             "rejected": rejected, "max_w": worst}}
