"""Tables: CSV written with the header first (and read back with located errors), TOML with line numbers, JSON.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import re
import stat
import sys
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurveyError, location
from .files import atomic_write, read_text, write_text_atomic

__all__ = ['write_csv_atomic', 'csv_sidecar_path', 'write_csv', 'to_json', 'dumps_json', 'write_json_atomic', 'read_toml', 'toml_line', 'parse_float', 'CsvTable', 'read_csv_table', 'excerpt',
           'TOML_MAX_BYTES', 'TOML_MAX_DEPTH', 'JSON_MAX_DEPTH', 'json_too_deep', 'loads_json']


def write_csv_atomic(
    path: str | os.PathLike,
    header: Sequence[str],
    rows: Sequence[Sequence[Any]],
    *,
    comments: Sequence[str] = (),
    provenance: Mapping[str, Any] | None = None,
) -> Path:
    """Write a CSV file atomically, header on the first line (cells as in :func:`write_csv`).

    *comments* (units, provenance, conventions) do not go into the CSV, where
    pandas, QGIS and GDAL/OGR would take them for the header: they are written
    to a sidecar ``<name>.csv.json`` (``{"file", "notes", "lidarcat_version"}``,
    and ``"provenance"`` when given: what the file was made from, e.g.
    :func:`provenance`), see :func:`csv_sidecar_path`.  Without comments and
    provenance no sidecar is written and a stale one is removed.
    """
    path = Path(path)
    with atomic_write(path, "w") as fh:
        write_csv(fh, header, rows)
    side = csv_sidecar_path(path)
    if comments or provenance:
        from .. import __version__

        doc: dict[str, Any] = {"file": path.name, "notes": list(comments), "lidarcat_version": __version__}
        if provenance:
            doc["provenance"] = dict(provenance)
        write_json_atomic(side, doc)
    elif side.exists():
        side.unlink()
    return path


def csv_sidecar_path(path: str | os.PathLike) -> Path:
    """The JSON sidecar of a CSV file written by :func:`write_csv_atomic`.

    >>> csv_sidecar_path("out/eop.csv").as_posix()
    'out/eop.csv.json'
    """
    path = Path(path)
    return path.with_name(path.name + ".json")


def write_csv(fh: Any, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    """Write CSV to an open text file (e.g. ``sys.stdout``), header on the first line.

    Floats are written with ``repr`` (they read back bit-identical), NaN and
    infinities as empty cells.  (Files of lidarcat 0.1 began with ``# ...``
    comment lines; :func:`read_csv_table` still skips them.)

    >>> import io
    >>> buf = io.StringIO()
    >>> write_csv(buf, ["point", "x_mm"], [["701", np.float64(0.1)], ["702", float("nan")]])
    >>> print(buf.getvalue(), end="")
    point,x_mm
    701,0.1
    702,
    """
    w = csv.writer(fh, lineterminator="\n")
    w.writerow(header)
    for row in rows:
        w.writerow([_csv_cell(v) for v in row])


def _csv_cell(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        if not math.isfinite(v):
            return ""
        return repr(float(v))
    if isinstance(v, np.integer):
        return int(v)
    return v


def to_json(obj: Any) -> Any:
    """``default=`` hook for :func:`json.dumps`: numpy, paths, dataclasses."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        if hasattr(obj, "to_dict"):
            return obj.to_dict()
        return {f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)}
    if hasattr(obj, "to_dict"):
        return obj.to_dict()
    raise TypeError(f"cannot serialise {type(obj).__name__} to JSON")


def _finite(obj: Any) -> Any:
    # JSON has no NaN/inf: write null instead of an invalid token.
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def dumps_json(obj: Any, indent: int | None = 2) -> str:
    """Serialise *obj* deterministically (sorted keys, NaN -> null)."""
    plain = json.loads(json.dumps(obj, default=to_json))
    return json.dumps(_finite(plain), sort_keys=True, indent=indent, allow_nan=False)


def write_json_atomic(path: str | os.PathLike, obj: Any) -> Path:
    """Write *obj* as JSON to *path* atomically."""
    return write_text_atomic(path, dumps_json(obj) + "\n")


#: the largest TOML input read (survey.toml and camera.toml are a few kB)
TOML_MAX_BYTES = 1_000_000
#: the deepest nesting of arrays and inline tables accepted in a TOML input (tomllib recurses)
TOML_MAX_DEPTH = 32


def excerpt(value: Any, limit: int = 60, *, quote: bool = True) -> str:
    r"""A short, quoted, escaped excerpt of *value* (file content) for an error message.

    At most *limit* characters of the text are shown, non-printable characters
    as Python escapes (``\x00``, ``\n``), and ``...`` marks a cut: an error
    never echoes a file (say ``/proc/self/environ`` named as a table) into a
    terminal or log.  Text is quoted unless ``quote=False`` (for a list such
    as a header); other values are shown as their ``repr``, cut the same way.

    >>> excerpt("701")
    "'701'"
    >>> excerpt("A=1\x00B=2")
    "'A=1\\x00B=2'"
    >>> excerpt("x" * 100, limit=5)
    "'xxxxx'... (100 characters)"
    >>> excerpt("photo, E, N", quote=False), excerpt(0), excerpt([1.5, "a"])
    ('photo, E, N', '0', "[1.5, 'a']")
    """
    try:
        text = value if isinstance(value, str) else repr(value)
    except ValueError:  # an int beyond Python's 4300-digit conversion limit
        text = f"<a number of {value.bit_length() * 0.30103:.0f} digits>" if isinstance(value, int) else "<?>"
    shown = "".join(ch if ch.isprintable() else repr(ch)[1:-1] for ch in text[:limit])
    if quote and isinstance(value, str):
        shown = "'" + shown.replace("'", "\\'") + "'"
    if len(text) > limit:
        shown += f"... ({len(text)} characters)"
    return shown


def read_toml(path: str | os.PathLike) -> tuple[dict[str, Any], str]:
    """Parse a TOML input file; return its content and its text (for :func:`toml_line`).

    Files over :data:`TOML_MAX_BYTES`, anything but a regular file (a FIFO, a
    device) and arrays or inline tables nested deeper than
    :data:`TOML_MAX_DEPTH` are refused before tomllib (which recurses) sees them.

    Raises
    ------
    SurveyError
        As :func:`read_text`, too large, not a regular file, nested too deep, or
        invalid TOML (names the line tomllib reports).
    """
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise SurveyError(f"{path}: file not found") from None
    except OSError as ex:
        raise SurveyError(f"{path}: cannot read ({ex.strerror})") from None
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):  # a folder: read_text says so
        raise SurveyError(f"{path}: not a regular file (a pipe or a device); name a TOML file")
    if st.st_size > TOML_MAX_BYTES:
        raise SurveyError(f"{path}: {st.st_size:,} bytes is too large for a TOML settings file "
                          f"(at most {TOML_MAX_BYTES:,})")
    text = read_text(path)
    deep = _toml_too_deep(text, TOML_MAX_DEPTH)
    if deep is not None:
        raise SurveyError(f"{location(path, deep)}: arrays or inline tables nested more than "
                          f"{TOML_MAX_DEPTH} deep; a settings file needs a few levels at most")
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as ex:
        m = re.search(r"line (\d+)", str(ex))
        line = int(m.group(1)) if m else None
        raise SurveyError(f"{location(path, line)}: invalid TOML: {ex}") from ex
    except RecursionError:  # a nesting the scan missed: refuse it all the same
        raise SurveyError(f"{path}: values nested too deep for a TOML settings file") from None
    except ValueError:  # not a TOMLDecodeError: an integer beyond Python's conversion limit
        m = re.search(r"\d{%d,}" % (sys.get_int_max_str_digits() + 1), text)
        line = text.count("\n", 0, m.start()) + 1 if m else None
        raise SurveyError(f"{location(path, line)}: a number of more than {sys.get_int_max_str_digits()} "
                          f"digits") from None
    return data, text


def _toml_too_deep(text: str, limit: int) -> int | None:
    """The 1-based line where ``[``/``{`` nesting outside strings and comments passes *limit*
    (None if it never does).  A linear scan, not a parser: tomllib judges the syntax."""
    depth, line, i, n = 0, 1, 0, len(text)
    while i < n:
        ch = text[i]
        if ch == "\n":
            line += 1
        elif ch == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        elif ch in "\"'":
            quote = text[i:i + 3] if text[i:i + 3] in ('"""', "'''") else ch
            j = i + len(quote)
            while j < n and not text.startswith(quote, j):
                if text[j] == "\n" and len(quote) == 1:
                    break  # an unterminated string: tomllib reports it
                j += 2 if text[j] == "\\" and ch == '"' else 1
            line += text.count("\n", i, j)
            i = j if j < n and text[j] == "\n" else j + len(quote)
            continue
        elif ch in "[{":
            depth += 1
            if depth > limit:
                return line
        elif ch in "]}":
            depth = max(depth - 1, 0)
        i += 1
    return None


_TOML_TABLE_RE = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")


_TOML_KEY_RE = re.compile(r'^\s*("([^"]*)"|\'([^\']*)\'|[A-Za-z0-9_-]+)\s*=')


def toml_line(text: str, table: str | None, key: str | None = None) -> int | None:
    r"""1-based line of ``key`` inside ``[table]`` (or of the table header) in TOML *text*.

    A best-effort scan for error messages (tomllib gives no positions): top-level
    keys have ``table=None``.  Returns the table's header line when *key* is not
    in it, None when the table is not found.

    >>> text = "top = 1\n[survey]\nname = 'x'\n"
    >>> toml_line(text, "survey", "name"), toml_line(text, "survey", "crs"), toml_line(text, None, "top")
    (3, 2, 1)
    """
    current: str | None = None
    header_line: int | None = None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        m = _TOML_TABLE_RE.match(raw)
        if m:
            current = m.group(1).strip().strip('"').strip("'")
            if current == table and key is None:
                return lineno
            if current == table:
                header_line = lineno
            continue
        if key is not None and current == table:
            km = _TOML_KEY_RE.match(raw)
            if km and (km.group(2) or km.group(3) or km.group(1)) == key:
                return lineno
    return header_line


_ASCII_FLOAT_RE = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                             r"|[+-]?(?:inf|infinity|nan)", re.IGNORECASE)


def parse_float(text: str, *, decimal_comma: bool = False) -> float:
    """A number written in ASCII decimal notation (``-12.5``, ``1e-3``, ``inf``, ``nan``).

    Python's ``float`` also reads Arabic-Indic and other Unicode digits,
    ``1_000`` and surrounding Unicode spaces; input files must not depend on
    that, so only ASCII digits, one ``.`` (or, with *decimal_comma*, one ``,``),
    a sign and an exponent are accepted.

    Raises
    ------
    ValueError
        Not such a number; the message says why (non-ASCII digits named).

    >>> parse_float(" 677757.80 "), parse_float("905,12", decimal_comma=True)
    (677757.8, 905.12)
    >>> parse_float("\u0661\u0662\u0663")
    Traceback (most recent call last):
    ...
    ValueError: '١٢٣' is not a number: only ASCII digits 0-9 are read
    """
    s = text.strip(" \t\r\n")
    if decimal_comma and "." not in s:
        s = s.replace(",", ".", 1)
    if _ASCII_FLOAT_RE.fullmatch(s):
        return float(s)
    if any(ch.isdigit() and not ch.isascii() for ch in s):
        raise ValueError(f"{excerpt(text)} is not a number: only ASCII digits 0-9 are read")
    if "," in s and _ASCII_FLOAT_RE.fullmatch(s.replace(",", ".", 1)):
        raise ValueError(f"{excerpt(text)} is not a number: write the decimal separator as a point")
    raise ValueError(f"{excerpt(text)} is not a number")


@dataclasses.dataclass(frozen=True)
class CsvTable:
    """A CSV file read as strings, each row remembering its physical line number."""

    path: Path
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    lines: tuple[int, ...]

    def column(self, name: str) -> list[str]:
        i = self.header.index(name)
        return [r[i] for r in self.rows]

    def has(self, name: str) -> bool:
        return name in self.header

    def floats(self, name: str, *, required: bool = True, default: float = math.nan,
               allow_nan: bool = False) -> np.ndarray:
        """Column *name* as float64; an empty cell is *default* unless *required*."""
        if not self.has(name):
            if required:
                raise SurveyError(f"{location(self.path, 1)}: missing column {name!r} "
                                  f"(header is {excerpt(', '.join(self.header), quote=False)})")
            return np.full(len(self.rows), default)
        i = self.header.index(name)
        out = np.empty(len(self.rows))
        for k, (row, line) in enumerate(zip(self.rows, self.lines)):
            cell = row[i].strip()
            if cell == "":
                if required:
                    raise SurveyError(f"{location(self.path, line, name)}: empty value; a number is required")
                out[k] = default
                continue
            try:
                v = parse_float(cell)
            except ValueError as ex:
                raise SurveyError(f"{location(self.path, line, name)}: {ex}") from None
            if not math.isfinite(v) and not allow_nan:
                raise SurveyError(f"{location(self.path, line, name)}: {excerpt(cell)} is not a finite number")
            out[k] = v
        return out


def read_csv_table(
    path: str | os.PathLike,
    required: Sequence[str] = (),
    optional: Sequence[str] = (),
    *,
    allow_extra: bool = False,
) -> CsvTable:
    """Read a comma-separated file with a header line.

    Lines starting with ``#`` and blank lines are skipped (but counted, so that
    line numbers in messages are the ones an editor shows).  Cells are stripped.

    Raises
    ------
    SurveyError
        Missing, unreadable or non-UTF-8 file, missing required column, unknown
        or unnamed column (unless *allow_extra*), or a row with the wrong number
        of fields.
    """
    path = Path(path)
    text = read_text(path)
    if "\x00" in text:  # a binary file (or /proc/self/environ) named as a table: say so, quote nothing
        raise SurveyError(f"{location(path, text.count(chr(10), 0, text.index(chr(0))) + 1)}: "
                          f"a NUL byte: this is not a CSV text file")
    header: tuple[str, ...] | None = None
    rows: list[tuple[str, ...]] = []
    lines: list[int] = []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        cells = tuple(c.strip() for c in next(csv.reader([raw])))
        if header is None:
            header = cells
            hline = lineno
            continue
        if len(cells) != len(header):
            raise SurveyError(f"{location(path, lineno)}: {len(cells)} fields, expected "
                              f"{len(header)} ({excerpt(', '.join(header), quote=False)})")
        rows.append(cells)
        lines.append(lineno)
    if header is None:
        raise SurveyError(f"{path}: empty file, expected a header line")
    unnamed = [i for i, h in enumerate(header, start=1) if not h]
    if unnamed and not allow_extra:
        raise SurveyError(f"{location(path, hline)}: column {unnamed[0]} has no name (a trailing "
                          f"comma?); name it or delete it")
    dup = {h for h in header if h and header.count(h) > 1}
    if dup:
        raise SurveyError(f"{location(path, hline)}: duplicate column(s) {excerpt(', '.join(sorted(dup)), quote=False)}")
    for name in required:
        if name not in header:
            raise SurveyError(f"{location(path, hline)}: missing column {name!r} "
                              f"(header is {excerpt(', '.join(header), quote=False)})")
    if not allow_extra:
        known = set(required) | set(optional)
        extra = [h for h in header if h not in known]
        if extra:
            raise SurveyError(f"{location(path, hline)}: unknown column(s) {excerpt(', '.join(extra), quote=False)}; "
                              f"allowed: {', '.join(list(required) + list(optional))}")
    return CsvTable(path, header, tuple(rows), tuple(lines))


#: deepest nesting of arrays/objects lidarcat reads from a JSON file (GeoJSON, OpenSfM and ODM nest a few levels)
JSON_MAX_DEPTH = 64
_JSON_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')


def json_too_deep(text: str, limit: int = JSON_MAX_DEPTH) -> tuple[int, int] | None:
    """``(line, column)`` where arrays/objects first nest deeper than *limit*, else None.

    One linear scan that skips strings: :func:`json.loads` would recurse once per
    level into a ``RecursionError`` on a file nested 100,000 deep.

    >>> json_too_deep('{"a": [[1, 2], "[[["]}', 3) is None
    True
    >>> json_too_deep('[[[1]]]', 2)
    (1, 3)
    """
    depth = 0
    for m in _JSON_TOKEN.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > limit:
                line = text.count("\n", 0, m.start()) + 1
                return line, m.start() - text.rfind("\n", 0, m.start())
        elif c in "]}":
            depth -= 1
    return None


def loads_json(text: str, path: str | os.PathLike, error: type[Exception] = SurveyError,
               limit: int = JSON_MAX_DEPTH) -> Any:
    """Parse the JSON *text* of *path*; *error* (a LidarcatError class) located at the line when it is not JSON
    or nests deeper than *limit*."""
    deep = json_too_deep(text, limit)
    if deep is not None:
        raise error(f"{location(path, deep[0])}: arrays/objects nested deeper than {limit} levels "
                    f"(column {deep[1]})")
    try:
        return json.loads(text)
    except json.JSONDecodeError as ex:
        raise error(f"{location(path, ex.lineno)}: invalid JSON: {ex.msg} (column {ex.colno})") from None
    except (ValueError, RecursionError) as ex:  # an integer of over 4,300 digits
        raise error(f"{location(path, None)}: invalid JSON: {excerpt(str(ex), quote=False)}") from None
