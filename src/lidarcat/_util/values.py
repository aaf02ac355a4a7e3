"""Sane ranges of the values input files carry: one rule per kind of value, shared by every reader.

A number in an input file is written in ASCII decimal notation
(:func:`lidarcat._util.tables.parse_float`), is finite and lies in the range
of its kind (:data:`VALUE_RANGES`); a value outside is a typo, a unit mix-up
(mm for m, radians for degrees) or garbage, and a reader refuses it naming the
file, line and field instead of carrying it into an adjustment.  The ranges are
wide on purpose: they refuse what no survey can hold, never a real block.

>>> value_problem(-1e10, "coordinate_m")
'-10000000000.0 m is outside the sane range -1e+08..1e+08 m'
>>> value_problem(677757.8, "coordinate_m") is None
True
>>> parse_number("\u0661\u0662", "coordinate_m")
Traceback (most recent call last):
...
ValueError: '١٢' is not a number: only ASCII digits 0-9 are read
>>> parse_whole("4" * 400, "image_px")
Traceback (most recent call last):
...
ValueError: '4444444444444444...' (400 digits) is outside the sane range 1..1e+06 px
"""

from __future__ import annotations

import math
import re

from .tables import parse_float

__all__ = ["VALUE_RANGES", "value_problem", "parse_number", "parse_whole"]

#: kind -> (low, high, unit) of a value as a file gives it.
#: coordinate_m: E, N, X0, Y0 (and lon/lat); 10 x the largest projected coordinate (UTM northings
#: 1e7 m), above any geocentric coordinate.  height_m: h, Z0, model Z; below any orbit, above any
#: sea floor.  angle_deg: omega/phi/kappa, yaw/pitch/roll (a full turn).  pixel_px: image
#: measurements and principal points, origin at a corner or the centre.  normalised: OpenSfM image
#: coordinates (x / max(w, h); +-0.5 at the edges).  photo_mm: photo coordinates.  image_px: image
#: width and height.
VALUE_RANGES: dict[str, tuple[float, float, str]] = {
    "coordinate_m": (-1e8, 1e8, "m"),
    "height_m": (-1e4, 1e5, "m"),
    "angle_deg": (-360.0, 360.0, "deg"),
    "latitude_deg": (-90.0, 90.0, "deg"),
    "longitude_deg": (-360.0, 360.0, "deg"),
    "normalised": (-10.0, 10.0, "image widths"),
    "pixel_px": (-1e6, 1e6, "px"),
    "photo_mm": (-1e3, 1e3, "mm"),
    "image_px": (1, 1e6, "px"),
}


def value_problem(value: float, kind: str) -> str | None:
    """What is wrong with *value* as a value of *kind* (:data:`VALUE_RANGES`), or None."""
    lo, hi, unit = VALUE_RANGES[kind]
    if not math.isfinite(value):
        return f"{value!r} is not a finite number"
    if not lo <= value <= hi:
        return f"{value!r} {unit} is outside the sane range {lo:g}..{hi:g} {unit}"
    return None


def parse_number(text: str, kind: str | None = None) -> float:
    """*text* as a finite ASCII decimal number (:func:`parse_float`) in the range of *kind*.

    Raises
    ------
    ValueError
        Not such a number, or out of range; the message says why.
    """
    v = parse_float(text)
    if not math.isfinite(v):
        raise ValueError(f"{text.strip()!r} is not a finite number")
    problem = value_problem(v, kind) if kind else None
    if problem:
        raise ValueError(problem)
    return v


_WHOLE_RE = re.compile(r"[+-]?[0-9]+")


def parse_whole(text: str, kind: str | None = None) -> int:
    """*text* as a whole number in ASCII digits (at most 18 of them) in the range of *kind*.

    Python's ``int`` reads Unicode digits and 4,300-digit numbers; this reads neither.

    Raises
    ------
    ValueError
        Not such a number, or out of range; the message says why (a long number shortened).
    """
    s = text.strip(" \t\r\n")
    if not _WHOLE_RE.fullmatch(s):
        if any(ch.isdigit() and not ch.isascii() for ch in s):
            raise ValueError(f"{s[:40]!r} is not a whole number: only ASCII digits 0-9 are read")
        raise ValueError(f"{s[:40]!r} is not a whole number")
    shown = repr(s) if len(s) <= 20 else f"'{s[:16]}...' ({len(s.lstrip('+-'))} digits)"
    if len(s.lstrip("+-")) > 18:
        if kind:
            lo, hi, unit = VALUE_RANGES[kind]
            raise ValueError(f"{shown} is outside the sane range {lo:g}..{hi:g} {unit}")
        raise ValueError(f"{shown} has more than 18 digits")
    v = int(s)
    if kind:
        lo, hi, unit = VALUE_RANGES[kind]
        if not lo <= v <= hi:
            raise ValueError(f"{shown} is outside the sane range {lo:g}..{hi:g} {unit}")
    return v
