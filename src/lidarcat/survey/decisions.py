"""control_decisions.csv: the user's review of the LiDAR control measured in the photos, remembered by the survey.

``lidarcat measure-control SURVEY --decisions decisions.csv --line-decisions line_decisions.csv`` writes the
accepted rows into image_points.csv and line_control.csv; the *decisions* themselves -- this vertex on that photo
rejected, that roof edge accepted -- are recorded here, so that a later measurement (``lidarcat measure-control``
or the measure_control stage of ``lidarcat run``) leaves them alone (:mod:`lidarcat.stages.measure_control`).
The file is named in survey.toml (``[files] control_decisions``, added when the first review is fed back).

One table for both kinds, one row per reviewed pair::

    kind,photo,id,decision,source,date
    point,102,L003,reject,out/measure_control/decisions.csv:7,2026-11-28T11:02:13+00:00
    line,102,L003/1-2,accept,out/measure_control/line_decisions.csv:21,2026-11-28T11:02:13+00:00

* ``kind`` -- ``point`` (a LiDAR vertex's point observation: ``id`` is the ground point) or ``line`` (a roof
  edge: ``id`` is the line, ``POINT/i-j`` as measure-control names it, or a line of line_control.csv);
* ``photo`` -- the photo; ``decision`` -- ``accept`` or ``reject``;
* ``source`` -- where the decision came from (the file fed back and its line; free text, may be empty for a row
  typed by hand); ``date`` -- when it was recorded (ISO 8601; may be empty).

A pair is listed once.  Recording a review (:func:`merged_rows`) replaces the row of each pair the review lists
(keeping the old row, its source and date, when the decision did not change), drops the rows of pairs it says
nothing about any more (an edge carried by its vertex's point again) and keeps the rows of the pairs it does not
list.

The meaning (enforced by the stage): a **rejected** pair is never measured again (its row in a later run's
decisions.csv says ``rejected by the user (control_decisions.csv:LINE)``); an **accepted** pair is not measured
again unless ``replace``.  To have a rejected pair measured again, delete its row here.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

from .._util import excerpt, read_csv_table
from ..errors import SurveyError, location

__all__ = ["DECISION_COLUMNS", "DECISION_KINDS", "ControlDecision", "ControlDecisions", "read_control_decisions",
           "merged_rows", "now_utc"]

#: columns of control_decisions.csv
DECISION_COLUMNS = ("kind", "photo", "id", "decision", "source", "date")
#: values of ``kind``
DECISION_KINDS = ("point", "line")

_LINE_ID = re.compile(r"(?P<point>.+)/[1-9][0-9]*-[1-9][0-9]*")


@dataclass(frozen=True)
class ControlDecision:
    """One row of control_decisions.csv (``at``: its line in the file, 0 for a row not read from a file)."""

    kind: str
    photo: str
    id: str
    decision: str
    source: str = ""
    date: str = ""
    at: int = 0

    @property
    def point(self) -> str:
        """The LiDAR vertex: the point itself, or the ``POINT`` of a line ``POINT/i-j`` ('' for another line)."""
        if self.kind == "point":
            return self.id
        m = _LINE_ID.fullmatch(self.id)
        return m["point"] if m else ""

    def cells(self) -> list[str]:
        return [self.kind, self.photo, self.id, self.decision, self.source, self.date]


@dataclass(frozen=True)
class ControlDecisions:
    """The survey's control_decisions.csv (``path`` None and no rows when survey.toml names none)."""

    path: Path | None = None
    rows: tuple[ControlDecision, ...] = field(default=())

    def __len__(self) -> int:
        return len(self.rows)

    def of(self, kind: str, decision: str | None = None) -> dict[tuple[str, str], ControlDecision]:
        """``(photo, id) -> row`` of the pairs of *kind* (with *decision* if given)."""
        return {(r.photo, r.id): r for r in self.rows if r.kind == kind and decision in (None, r.decision)}

    def where(self, row: ControlDecision) -> str:
        """``control_decisions.csv:LINE`` of *row* (the file's own name)."""
        return f"{self.path.name if self.path is not None else 'control_decisions.csv'}:{row.at}"

    def reason(self, row: ControlDecision) -> str:
        """The reason a later run gives for a pair it leaves alone: ``rejected by the user (FILE:LINE)``."""
        return f"{row.decision}ed by the user ({self.where(row)})"


def read_control_decisions(path: str | Path, photo_ids: Iterable[str], point_ids: Iterable[str],
                           line_ids: Iterable[str] = ()) -> ControlDecisions:
    """Read and check control_decisions.csv.

    Parameters
    ----------
    path : path of the file
    photo_ids : the survey's photos
    point_ids : the survey's ground points (a ``point`` row's id, a ``line`` row's ``POINT/i-j``)
    line_ids : the lines of line_control.csv (a ``line`` row may name one of them by any id)

    Raises
    ------
    SurveyError
        ``file:line: field ...``: a kind other than point/line, an unknown photo, point or line, a decision other
        than accept/reject, a date that is not ISO 8601, a pair listed twice.
    """
    path = Path(path)
    t = read_csv_table(path, required=("kind", "photo", "id", "decision"), optional=("source", "date"))
    photos, points, lines = set(map(str, photo_ids)), set(map(str, point_ids)), set(map(str, line_ids))
    seen: dict[tuple[str, str, str], int] = {}
    out = []
    for row, ln in zip(t.rows, t.lines):
        c = dict(zip(t.header, row))
        kind, photo, rid, dec = c["kind"].lower(), c["photo"], c["id"], c["decision"].lower()
        if kind not in DECISION_KINDS:
            raise SurveyError(f"{location(path, ln, 'kind')}: must be point or line, got {excerpt(c['kind'])}")
        if photo not in photos:
            raise SurveyError(f"{location(path, ln, 'photo')}: unknown photo {excerpt(photo)} (not in photos.csv)")
        if kind == "point" and rid not in points:
            raise SurveyError(f"{location(path, ln, 'id')}: unknown point {excerpt(rid)} (not in ground_points.csv)")
        m = _LINE_ID.fullmatch(rid)
        if kind == "line" and rid not in lines and not (m and m["point"] in points):
            raise SurveyError(f"{location(path, ln, 'id')}: unknown line {excerpt(rid)} (neither a line of "
                              f"line_control.csv nor POINT/i-j of a ground point)")
        if dec not in ("accept", "reject"):
            raise SurveyError(f"{location(path, ln, 'decision')}: must be accept or reject, got "
                              f"{excerpt(c['decision'])}")
        date = c.get("date", "")
        if date:
            try:
                datetime.fromisoformat(date)
            except ValueError:
                raise SurveyError(f"{location(path, ln, 'date')}: not an ISO 8601 date {excerpt(date)} (e.g. "
                                  f"2026-11-28T11:02:13+00:00)") from None
        key = (kind, photo, rid)
        if key in seen:
            raise SurveyError(f"{path}:{ln}: {kind} {excerpt(rid)} on photo {excerpt(photo)} is listed twice (also "
                              f"on line {seen[key]}); keep one row")
        seen[key] = ln
        out.append(ControlDecision(kind, photo, rid, dec, c.get("source", ""), date, ln))
    return ControlDecisions(path, tuple(out))


def now_utc() -> str:
    """The date of a recorded decision: now, UTC, to the second (ISO 8601)."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def merged_rows(old: ControlDecisions, new: Sequence[ControlDecision],
                forget: Iterable[tuple[str, str, str]] = ()) -> list[list[str]]:
    """The rows of control_decisions.csv after recording *new*: each of *old*'s rows in place -- replaced by the
    new decision of its pair when that differs (an unchanged decision keeps its source and date), dropped when
    its pair ``(kind, photo, id)`` is in *forget* (no decision any more) --, then the pairs *old* does not have,
    in *new*'s order."""
    fresh = {(d.kind, d.photo, d.id): d for d in new}
    gone = set(forget) - set(fresh)
    rows = []
    for r in old.rows:
        if (r.kind, r.photo, r.id) in gone:
            continue
        d = fresh.pop((r.kind, r.photo, r.id), None)
        rows.append((r if d is None or d.decision == r.decision else d).cells())
    return rows + [d.cells() for d in fresh.values()]
