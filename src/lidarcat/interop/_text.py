"""Located parsing of the whitespace/CSV text files other programs write.

Every reader of :mod:`lidarcat.interop` goes through :class:`TextLines`: it reads
the file as UTF-8 (:func:`lidarcat._util.read_text`), numbers the physical lines
(comments and blank lines count, as in an editor) and turns a bad cell into a
:class:`~lidarcat.errors.FormatError` ``FILE:LINE: field 'NAME': what is wrong``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from .._util import read_text
from .._util.values import parse_number, parse_whole
from ..errors import FormatError, location

__all__ = ["TextLines", "Row", "format_error", "sd_problem"]

_SPLIT = re.compile(r"[\s,;]+")


def sd_problem(value: float, unit: str) -> str | None:
    """What is wrong with a standard deviation in *unit* (``m``, ``mm``, ``deg``) by the survey's
    own rule (:data:`lidarcat.survey.schema.SD_BOUNDS`), or None."""
    from ..survey.schema import SD_BOUNDS

    lo, hi = SD_BOUNDS[unit]
    if not value > 0:
        return f"must be positive, got {value!r} {unit}"
    if not lo <= value <= hi:
        return f"is outside the sane range, got {value!r} {unit}; sane values lie in {lo:g}..{hi:g} {unit}"
    return None


def format_error(path: object, line: int | None, field: str | None, message: str) -> FormatError:
    """``FILE:LINE: field 'NAME': message`` as a :class:`FormatError`."""
    return FormatError(f"{location(path, line, field)}: {message}")


@dataclass(frozen=True)
class Row:
    """One data line: its physical line number and its fields (strings)."""

    path: Path
    line: int
    fields: tuple[str, ...]

    def error(self, field: str | None, message: str) -> FormatError:
        return format_error(self.path, self.line, field, message)

    def need(self, n: int, names: Sequence[str]) -> None:
        """At least *n* fields, else an error naming the first missing one."""
        if len(self.fields) < n:
            missing = names[len(self.fields)] if len(self.fields) < len(names) else f"#{n}"
            raise self.error(missing, f"missing: the line has {len(self.fields)} field(s), "
                                      f"expected {n} ({' '.join(names[:n])})")

    def text(self, i: int, name: str) -> str:
        if i >= len(self.fields):
            raise self.error(name, "missing")
        return self.fields[i]

    def number(self, i: int, name: str, kind: str | None = None) -> float:
        """Field *i* as a finite ASCII decimal number, in the sane range of *kind*
        (:data:`lidarcat._util.values.VALUE_RANGES`) when given."""
        cell = self.text(i, name)
        try:
            return parse_number(cell, kind)
        except ValueError as ex:
            msg = str(ex)
            if "," in cell and msg.endswith("is not a number: write the decimal separator as a point"):
                msg = f"{cell!r} is not a number (a decimal comma? write 1.5, not 1,5)"
            raise self.error(name, msg) from None

    def angle(self, i: int, name: str, unit_rad: float) -> float:
        """Field *i*, an angle in the unit of *unit_rad* radians, in radians; at most a full turn."""
        v = self.number(i, name)
        if not abs(v * unit_rad) <= 2 * math.pi * (1 + 1e-12):
            raise self.error(name, f"{self.fields[i]!r} is outside the sane range of an angle "
                                   f"(at most a full turn: 360 deg, 400 gon, 2 pi rad)")
        return v * unit_rad

    def sd(self, i: int, name: str, unit: str, scale: float = 1.0) -> float:
        """Field *i*, a standard deviation, times *scale*; refused unless positive and in
        :data:`lidarcat.survey.schema.SD_BOUNDS` of *unit* (after scaling), as the survey refuses it."""
        v = self.number(i, name)
        problem = sd_problem(v * scale, unit)
        if problem:
            raise self.error(name, f"{problem} (a standard deviation; the file gives {self.fields[i]!r})")
        return v * scale

    def integer(self, i: int, name: str, kind: str | None = None) -> int:
        cell = self.text(i, name)
        try:
            return parse_whole(cell, kind)
        except ValueError as ex:
            raise self.error(name, str(ex)) from None


class TextLines:
    """The data lines of a text file (blank lines and comment lines skipped).

    Parameters
    ----------
    path : path
        The file (UTF-8; a BOM is dropped).
    comment : str or None
        Lines whose first non-blank character starts with this are comments.
    split : str or None
        ``None``: fields separated by runs of whitespace, commas or semicolons;
        ``"ws"``: whitespace only; ``"tab"``: tab only.
    """

    def __init__(self, path: str | Path, comment: str | None = "#", split: str | None = None):
        self.path = Path(path)
        self.text = read_text(self.path, FormatError)
        self.comment = comment
        self.split = split

    def _fields(self, raw: str) -> tuple[str, ...]:
        s = raw.strip()
        if self.split == "ws":
            return tuple(s.split())
        if self.split == "tab":
            return tuple(c.strip() for c in s.split("\t"))
        return tuple(f for f in _SPLIT.split(s) if f)

    def rows(self) -> Iterator[Row]:
        for lineno, raw in enumerate(self.text.splitlines(), start=1):
            s = raw.strip()
            if not s or (self.comment and s.startswith(self.comment)):
                continue
            yield Row(self.path, lineno, self._fields(raw))

    def error(self, line: int | None, field: str | None, message: str) -> FormatError:
        return format_error(self.path, line, field, message)
