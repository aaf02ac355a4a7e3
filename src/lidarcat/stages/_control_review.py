"""The user's review of ``lidarcat measure-control`` fed back: decisions.csv and line_decisions.csv, remembered.

Private to :mod:`lidarcat.stages`; the contract is :mod:`lidarcat.stages.measure_control`'s docstring
("Feeding the decisions back", "The review remembered"):

* :func:`read_decisions`, :func:`read_line_decisions` -- the edited reports, every bad row one
  :class:`~lidarcat.errors.SurveyError` with ``file:line``, raised before anything is written; the 3-D
  line of a line id from :data:`LINE_CANDIDATES` beside line_decisions.csv, else from the survey's
  line_control.csv (:func:`known_lines`);
* :func:`fed_line_rows` -- the new line_control.csv: the rows of the (line, photo) pairs the file lists
  replaced, a line kept while an observation of it remains;
* :func:`recorded` -- the new control_decisions.csv (:mod:`lidarcat.survey.decisions`) with the user's
  word on every pair listed;
* :func:`feed_back` -- all of it written through :func:`~lidarcat.stages._control_tables.write_checked`
  (atomic, reloaded, rolled back), nothing measured.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_csv_atomic, write_json_atomic
from ..errors import SurveyError
from ._control_report import METHODS
from ._control_tables import edge_pairs, image_point_rows, line_obs_row, write_checked

__all__ = ["LINE_CANDIDATES", "read_decisions", "known_lines", "read_line_decisions", "fed_line_rows", "feed_back",
           "recorded"]

#: the file beside line_decisions.csv with the 3-D line of each of its line ids
LINE_CANDIDATES = "line_candidates.csv"


def read_decisions(path: Path, survey: Any) -> list[dict[str, Any]]:
    """The rows of an edited decisions.csv.

    A ``measured`` row of a point located along one edge (``method`` ``along``) has the status
    ``measured_along``: it may stand beside its written edges (not "the same fits" as they are).  An empty
    ``method``, or a file without the column (written before it), falls back to the reason: ``along`` when it
    starts "located along one edge".

    Raises
    ------
    SurveyError
        ``file:line``: a decision other than accept/reject, a method other than corner/along/empty, an unknown
        photo or ground point, a pixel or sd that is not a number, an accepted row without its pixel, a
        non-positive sd, a photo and point listed twice.
    """
    from .._util import excerpt, read_csv_table
    from ..errors import location

    t = read_csv_table(path, required=("photo", "point", "decision", "col_px", "row_px"),
                       optional=("sd_col_px", "sd_row_px", "status", "method", "reason", "pred_col_px", "pred_row_px",
                                 "pred_sd_px", "pass"))
    out = []
    photos, points, dec = t.column("photo"), t.column("point"), t.column("decision")
    status = t.column("status") if t.has("status") else [""] * len(t.rows)
    method = [str(v).strip().lower() for v in t.column("method")] if t.has("method") else [""] * len(t.rows)
    # a point located along one edge is written beside its edges (photocontrol.measure, step 3a): not "the same
    # fits".  The column ``method`` says so; an empty cell, or a file without the column (written before it),
    # falls back to the reason's opening words
    reason = t.column("reason") if t.has("reason") else [""] * len(t.rows)
    along = [mt == "along" or (not mt and str(r).startswith("located along one edge")) for mt, r in zip(method, reason)]
    status = [("measured_along" if st == "measured" and a else st) for st, a in zip(status, along)]
    cols, rows_ = t.floats("col_px", required=False), t.floats("row_px", required=False)
    sdc = t.floats("sd_col_px", required=False) if t.has("sd_col_px") else np.full(len(t.rows), np.nan)
    sdr = t.floats("sd_row_px", required=False) if t.has("sd_row_px") else np.full(len(t.rows), np.nan)
    known_photos = set(survey.photo_ids)
    known_points = set(np.asarray(survey.ground_points.point, dtype=str).tolist())
    seen: dict[tuple[str, str], int] = {}
    for k, line in enumerate(t.lines):
        d = str(dec[k]).strip().lower()
        if d not in ("accept", "reject"):
            raise SurveyError(f"{path}:{line}: decision must be accept or reject, got {dec[k]!r}")
        if method[k] not in ("", *METHODS):
            raise SurveyError(f"{location(path, line, 'method')}: must be {' or '.join(METHODS)} (or empty: no pixel "
                              f"measured), got {excerpt(t.column('method')[k])}")
        if photos[k] not in known_photos:
            raise SurveyError(f"{location(path, line, 'photo')}: unknown photo {excerpt(photos[k])} (not in "
                              f"photos.csv)")
        if points[k] not in known_points:
            raise SurveyError(f"{location(path, line, 'point')}: unknown point {excerpt(points[k])} (not in "
                              f"ground_points.csv)")
        if (photos[k], points[k]) in seen:
            raise SurveyError(f"{path}:{line}: point {excerpt(points[k])} on photo {excerpt(photos[k])} is listed "
                              f"twice (also on line {seen[(photos[k], points[k])]}); keep one row")
        seen[(photos[k], points[k])] = line
        if d == "accept" and not (np.isfinite(cols[k]) and np.isfinite(rows_[k])):
            raise SurveyError(f"{path}:{line}: decision accept needs col_px and row_px (photo {photos[k]!r}, "
                              f"point {points[k]!r})")
        for name, v in (("sd_col_px", sdc[k]), ("sd_row_px", sdr[k])):
            if d == "accept" and v <= 0:
                raise SurveyError(f"{location(path, line, name)}: must be positive, got {v:g}")
        out.append({"photo": str(photos[k]), "point": str(points[k]), "accept": d == "accept",
                    "px": np.array([cols[k], rows_[k]]), "sd": np.array([sdc[k], sdr[k]]), "at": line,
                    "status": status[k], "along": along[k]})
    return out


def known_lines(path: Path, survey: Any) -> dict[str, tuple[str, dict[str, str]]]:
    """The 3-D lines a line_decisions.csv at *path* may name: line id -> (its LiDAR point, the cells of its row in
    line_control.csv's columns), from :data:`LINE_CANDIDATES` beside *path* (the run that wrote it), else from the
    survey's line_control.csv."""
    from .._util import read_csv_table
    from ..survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    out: dict[str, tuple[str, dict[str, str]]] = {}
    own = survey.files.get("line_control")
    for src in (Path(own) if own is not None else None, path.with_name(LINE_CANDIDATES)):
        if src is None or not src.is_file():
            continue
        t = read_csv_table(src, required=("line", "photo"), optional=tuple(
            c for c in (*LINE_COLUMNS, *LINE_EXTRA_COLUMNS) if c not in ("line", "photo")))
        for r in t.rows:
            cells = dict(zip(t.header, r))
            if not cells["photo"]:
                lid = cells["line"]
                out[lid] = (cells.get("point", ""), cells)   # the candidates (read last) win
    return out


_LINE_PX = ("col1_px", "row1_px", "col2_px", "row2_px", "sd_px")


def read_line_decisions(path: Path, survey: Any) -> tuple[list[dict[str, Any]], dict[str, tuple[str, dict]]]:
    """The rows of an edited line_decisions.csv and the 3-D lines they name (:func:`known_lines`).

    Raises
    ------
    SurveyError
        ``file:line``: a decision other than accept/reject, an unknown photo or line, a ``point`` that is not the
        line's, a pixel or sd that is not a number, an accepted row without its pixels or with a zero-length edge,
        a line listed twice for one photo.
    """
    from .._util import excerpt, read_csv_table
    from ..errors import location

    t = read_csv_table(path, required=("line", "photo", "decision", *_LINE_PX),
                       optional=("point", "status", "reason", "ratio"))
    known = known_lines(path, survey)
    px = np.column_stack([t.floats(c, required=False) for c in _LINE_PX])
    photos = set(survey.photo_ids)
    out: list[dict[str, Any]] = []
    seen: dict[tuple[str, str], int] = {}
    for k, (row, ln) in enumerate(zip(t.rows, t.lines)):
        c = dict(zip(t.header, row))
        lid, photo, dec = c["line"], c["photo"], c["decision"].lower()
        if dec not in ("accept", "reject"):
            raise SurveyError(f"{path}:{ln}: decision must be accept or reject, got {c['decision']!r}")
        if photo not in photos:
            raise SurveyError(f"{location(path, ln, 'photo')}: unknown photo {excerpt(photo)} (not in photos.csv)")
        if lid not in known:
            raise SurveyError(f"{location(path, ln, 'line')}: unknown line {excerpt(lid)}: neither "
                              f"{LINE_CANDIDATES} beside this file nor the survey's line_control.csv defines it")
        point = known[lid][0]
        if c.get("point") and point and c["point"] != point:
            raise SurveyError(f"{location(path, ln, 'point')}: line {excerpt(lid)} is of point {excerpt(point)}, "
                              f"not {excerpt(c['point'])}")
        if (lid, photo) in seen:
            raise SurveyError(f"{path}:{ln}: line {excerpt(lid)} on photo {excerpt(photo)} is listed twice (also on "
                              f"line {seen[(lid, photo)]}); keep one row")
        seen[(lid, photo)] = ln
        p1, p2, sd = px[k, :2], px[k, 2:4], px[k, 4]
        if dec == "accept":
            if not np.isfinite(px[k]).all():
                raise SurveyError(f"{path}:{ln}: decision accept needs col1_px, row1_px, col2_px, row2_px and sd_px "
                                  f"(line {excerpt(lid)}, photo {excerpt(photo)})")
            if sd <= 0:
                raise SurveyError(f"{location(path, ln, 'sd_px')}: must be positive, got {c['sd_px']}")
            if np.hypot(*(p2 - p1)) <= 0:
                raise SurveyError(f"{path}:{ln}: line {excerpt(lid)} on photo {excerpt(photo)}: its two image points "
                                  f"coincide (an edge of zero length)")
        out.append({"line": lid, "point": point, "photo": photo, "accept": dec == "accept", "p1": p1, "p2": p2,
                    "sd": sd, "at": ln, "status": c.get("status", "")})
    return out, known


def fed_line_rows(path: Path | None, known: dict[str, tuple[str, dict]], fed: list[dict[str, Any]]
                  ) -> tuple[list[str], list[list[Any]]]:
    """The new line_control.csv after a fed-back line_decisions.csv *fed*: the rows of *path* of the (line, photo)
    pairs the file does not list kept; its accepted rows added as observations; each of its lines defined (from
    *known*) when an observation of it remains, dropped when none does."""
    from .._util import read_csv_table
    from ..survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    header = list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS)
    lids = list(dict.fromkeys(d["line"] for d in fed))
    pairs = {(d["line"], d["photo"]) for d in fed}
    rows: list[list[Any]] = []
    observed = {d["line"] for d in fed if d["accept"]}
    if path is not None and path.is_file():
        t = read_csv_table(path, required=("line", "photo"), optional=tuple(h for h in header if h not in
                                                                            ("line", "photo")))
        for r in t.rows:
            c = dict(zip(t.header, r))
            if (c["line"], c["photo"]) in pairs or (not c["photo"] and c["line"] in lids):
                continue
            if c["photo"]:
                observed.add(c["line"])
            rows.append([c.get(h, "") for h in header])
    rows += [[known[lid][1].get(h, "") for h in header] for lid in lids if lid in observed]
    rows += [line_obs_row(header, d["line"], d["photo"], d["p1"], d["p2"], d["sd"]) for d in fed if d["accept"]]
    return header, rows


def feed_back(survey: Any, out: Path, ip_path: Path, decisions: Any, line_decisions: Any,
              table: Any, line_table: Any) -> tuple[dict[str, Any], int, int, Path | None]:
    """Write the accepted rows of an edited decisions.csv and/or line_decisions.csv, measure nothing.

    Returns
    -------
    summary : dict
        What measure_control.json holds.
    accepted, lines_accepted : int
        Point and line observations written.
    line_control : Path or None
        The line table written (None: no line_decisions.csv).
    """
    summary: dict[str, Any] = {}
    header = table_rows = None
    n_acc = 0
    if decisions is not None:
        rows = read_decisions(Path(decisions), survey)
        accepted = [d for d in rows if d["accept"]]
        header, table_rows = image_point_rows(survey, accepted, replace=True,
                                              drop={(d["photo"], d["point"]) for d in rows})
        summary.update(decisions=str(decisions), accepted=len(accepted), rejected=len(rows) - len(accepted))
        with_point = {(str(r[0]), str(r[1])): ("in image_points.csv", False) for r in table_rows}
        with_point.update({(d["photo"], d["point"]): (f"accepted in {Path(decisions).name}", d["status"] == "measured")
                           for d in accepted})
        n_acc = len(accepted)
    else:
        with_point = {(str(a), str(b)): ("in image_points.csv", False)
                      for a, b in zip(survey.image_points.photo, survey.image_points.point)}
    lines_out = None
    n_lines = 0
    if line_decisions is not None:
        lpath = Path(line_decisions)
        fed, known = read_line_decisions(lpath, survey)
        for d in fed:   # a measured point and the edges it was measured from: never both (the same fits)
            pair = (d["photo"], d["point"])
            if d["accept"] and d["point"] and pair in with_point and (d["status"] == "in_point" or with_point[pair][1]):
                raise SurveyError(f"{lpath}:{d['at']}: line {d['line']!r} on photo {d['photo']!r}: vertex "
                                  f"{d['point']!r} has a point observation on this photo ({with_point[pair][0]}) "
                                  f"measured from the same edge fits; accept the point or its edges, not both")
        own = survey.files.get("line_control")
        lp = Path(line_table) if line_table is not None else Path(own) if own is not None else \
            survey.root / "line_control.csv"
        lh, lrows = fed_line_rows(Path(own) if own is not None else None, known, fed)
        n_lines = sum(d["accept"] for d in fed)
        lines_out = (lp, lh, lrows, f"LiDAR roof edges as control lines: lidarcat measure-control, decisions of "
                                    f"{lpath.name} (3-D lines from {LINE_CANDIDATES})")
        summary.update(line_decisions=str(lpath), lines_accepted=n_lines, lines_rejected=len(fed) - n_lines)
    if decisions is not None:   # a point accepted where the line table (kept rows) has the vertex's edges
        own = survey.files.get("line_control")
        edges = edge_pairs(*lines_out[1:3]) if lines_out is not None else edge_pairs(None, Path(own)) \
            if own is not None else set()
        for d in accepted:
            if d["status"] == "measured" and (d["photo"], d["point"]) in edges:
                raise SurveyError(f"{decisions}:{d['at']}: point {d['point']!r} on photo {d['photo']!r}: measured "
                                  f"from the same edge fits as its roof edges on this photo in line_control.csv; "
                                  f"accept the point or its edges, not both")
    comment = f"LiDAR control observations: lidarcat measure-control, decisions of " \
              f"{Path(decisions).name if decisions is not None else ''}"
    if table is None:
        told = recorded(survey, rows if decisions is not None else [], Path(decisions or "."),
                         fed if line_decisions is not None else [], Path(line_decisions or "."))
        summary.update(control_decisions=str(told[0]), control_decision_rows=len(told[2]))
        write_checked(survey, ip_path, header, table_rows, comment, lines_out, told)
    else:
        if lines_out is not None:
            write_csv_atomic(lines_out[0], lines_out[1], lines_out[2], comments=[lines_out[3]])
        if header is not None:
            write_csv_atomic(ip_path, header, table_rows, comments=[comment])
    write_json_atomic(out / "measure_control.json", summary)
    return summary, n_acc, n_lines, None if lines_out is None else lines_out[0]


def recorded(survey: Any, rows: list[dict[str, Any]], path: Path, fed: list[dict[str, Any]], lpath: Path
             ) -> tuple[Path, list[str], list[list[str]], str]:
    """control_decisions.csv (path, header, rows, comment) after recording every row of a fed-back decisions.csv
    (*rows* of *path*) and line_decisions.csv (*fed* of *lpath*) -- the user's word on each pair they list
    (:mod:`lidarcat.survey.decisions`) -- but an ``in_point`` edge left at ``reject`` (not written because the
    vertex's point carries it, not rejected: no decision, an earlier one of the pair dropped)."""
    from ..survey.decisions import DECISION_COLUMNS, ControlDecision, merged_rows, now_utc

    def src(p: Path) -> str:
        try:
            return p.resolve().relative_to(survey.root.resolve()).as_posix()
        except ValueError:
            return p.resolve().as_posix()

    date = now_utc()
    carried = {("line", d["photo"], d["line"]) for d in fed if not d["accept"] and d["status"] == "in_point"}
    new = [ControlDecision("point", d["photo"], d["point"], "accept" if d["accept"] else "reject",
                           f"{src(path)}:{d['at']}", date) for d in rows] + \
          [ControlDecision("line", d["photo"], d["line"], "accept" if d["accept"] else "reject",
                           f"{src(lpath)}:{d['at']}", date) for d in fed
           if ("line", d["photo"], d["line"]) not in carried]   # an edge its point carries: no decision on the edge
    own = survey.files.get("control_decisions")
    return (Path(own) if own is not None else survey.root / "control_decisions.csv", list(DECISION_COLUMNS),
            merged_rows(survey.control_decisions, new, carried),
            "The user's review of the LiDAR control measured in the photos (lidarcat measure-control --decisions / "
            "--line-decisions): a rejected pair is never measured again, an accepted one only with --replace; "
            "delete a row to have its pair measured again.")

