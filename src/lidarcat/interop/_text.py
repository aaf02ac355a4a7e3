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
from ..errors import FormatError, location

__all__ = ["TextLines", "Row", "format_error"]

_SPLIT = re.compile(r"[\s,;]+")


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

    def number(self, i: int, name: str) -> float:
        """Field *i* as a finite float."""
        cell = self.text(i, name)
        try:
            v = float(cell)
        except ValueError:
            hint = " (a decimal comma? write 1.5, not 1,5)" if "," in cell else ""
            raise self.error(name, f"{cell!r} is not a number{hint}") from None
        if not math.isfinite(v):
            raise self.error(name, f"{cell!r} is not a finite number")
        return v

    def integer(self, i: int, name: str) -> int:
        cell = self.text(i, name)
        try:
            return int(cell)
        except ValueError:
            raise self.error(name, f"{cell!r} is not a whole number") from None


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
