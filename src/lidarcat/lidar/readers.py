"""Reading and writing LiDAR point files: LAS 1.0-1.4, LAZ, COPC and ASCII.

Formats are chosen by file suffix:

==========================================  =========================================
``.las``, ``.laz``, ``.copc.laz``           laspy + lazrs (COPC: whole reads as LAZ 1.4,
                                            box queries by the octree, :mod:`.copc`)
``.xyz``, ``.txt``, ``.csv``, ``.asc``,     text: one point per line
``.pts``
==========================================  =========================================

**Text files.** Separators are whitespace, comma or semicolon (detected from the
first data line, or given as ``delimiter=``).  A decimal comma (``677757,8``) is
accepted when the separator is whitespace or a semicolon.  Lines starting with
``#`` and blank lines are skipped (but counted, so that error messages give the
line number an editor shows).  A first line that is not all numbers is a header
naming the columns; otherwise ``columns=`` names them, or the count decides:
``E N H``, ``E N H intensity`` (the thesis's Optech ``faixa.xyz``),
``E N H intensity return`` or ``E N H intensity return class``.  Column names
are case-insensitive with aliases (``x``/``east``/``este`` -> E, ``z``/``alt``
-> H, ``i``/``int`` -> intensity, ``class`` -> classification, ...); ``-``
skips a column; unknown names become float attributes.

**Coordinates.** LAS stores integers ``X`` with a scale and offset; when the
scale is a power of ten (0.01, 0.001 m...) the coordinate returned is the
float64 nearest to the decimal value (``(X + offset/scale) / (1/scale)``), so a
point read from LAS equals the same point read from text written with that
many decimals.

**Memory.** :func:`iter_points` streams a file in chunks of ``chunk_size``
points, so memory stays bounded whatever the file size.

**Broken files.** Before laspy sees a LAS/LAZ file its fixed header is read
with :mod:`struct` and checked against the file size (:func:`lidarcat.lidar._las.precheck_las`):
the header size, the offset to the points, the VLR count (each VLR takes at
least 54 bytes between the header and the points, so a count of 3.5 billion in
a 1 MB file is refused before anything is allocated), the extended VLRs of LAS
1.4, the point count against the bytes left, scales and offsets finite and
non-zero; for LAZ also the LasZip record (item sizes, chunk size), the chunk
table and, for LAS 1.4 points, the layer sizes of every chunk -- lazrs
allocates from these numbers and a failed allocation aborts the process.  The header's bounds are never used to select
points (they are often wrong); coordinates read must lie within
:data:`MAX_ABS_COORD_M` of zero.  Decoder failures -- including the Rust
``PanicException`` of lazrs, which derives from ``BaseException`` -- become a
:class:`~lidarcat.errors.LidarFormatError` naming the file.  See
``docs/robustness.md``.
"""

from __future__ import annotations

import io
import itertools
import logging
import math
import os
import re
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_write, parse_float
from ..errors import CRSError, LidarFormatError, TileIOError, location
from .cloud import STANDARD_ATTRIBUTES, Bounds, PointCloud
from ._las import (LAS_ATTRIBUTES, MAX_ABS_COORD_M, ascii_header_text, check_coords, decoder_error, las_record_cloud,
                   open_checked, open_error, open_las, settle_crs)
from .copc import is_copc
from .crs import resolve_crs

__all__ = [
    "is_foreign_table",
    "read_points",
    "iter_points",
    "write_points",
    "read_header",
    "FileHeader",
    "file_kind",
    "LAS_SUFFIXES",
    "ASCII_SUFFIXES",
    "DEFAULT_CHUNK_SIZE",
    "iter_las_ranges",
    "las_chunk_points",
    "MAX_ABS_COORD_M",
    "ascii_header_text",
]

log = logging.getLogger(__name__)

LAS_SUFFIXES = (".las", ".laz")
ASCII_SUFFIXES = (".xyz", ".txt", ".csv", ".asc", ".pts")
#: points per chunk when streaming (78 MB of coordinates + the six LAS attributes, 39 bytes a point)
DEFAULT_CHUNK_SIZE = 2_000_000

#: progress callback: receives the number of bytes of the file just processed
Progress = Callable[[int], Any]

_ALIASES = {
    "E": ("e", "x", "east", "easting", "este", "leste"),
    "N": ("n", "y", "north", "northing", "norte"),
    "H": ("h", "z", "height", "elevation", "elev", "alt", "altitude", "altitud", "altura"),
    "intensity": ("i", "int", "intensity", "intensidade", "intensidad", "amplitude"),
    "return_number": ("r", "ret", "return", "return_number", "returnnumber", "retorno"),
    "number_of_returns": ("number_of_returns", "numberofreturns", "num_returns", "nreturns",
                          "returns"),
    "classification": ("c", "class", "classification", "classe", "clase"),
    "point_source_id": ("point_source_id", "pointsourceid", "psid", "source", "strip", "faixa"),
    "gps_time": ("t", "time", "gps_time", "gpstime"),
}
_ALIAS_TO_NAME = {alias: name for name, aliases in _ALIASES.items() for alias in aliases}
_DEFAULT_COLUMNS = {
    3: ("E", "N", "H"),
    4: ("E", "N", "H", "intensity"),
    5: ("E", "N", "H", "intensity", "return_number"),
    6: ("E", "N", "H", "intensity", "return_number", "classification"),
}
_NUMBER_RE = re.compile(r"^[+-]?([0-9]+\.?[0-9]*([eE][+-]?[0-9]+)?|\.[0-9]+([eE][+-]?[0-9]+)?|nan|inf)$", re.I)
_DECIMAL_COMMA_RE = re.compile(r"^[+-]?[0-9]+(,[0-9]+)?([eE][+-]?[0-9]+)?$")


def file_kind(path: str | os.PathLike) -> str:
    """``"las"`` or ``"ascii"`` from the file suffix.

    Raises
    ------
    LidarFormatError
        The suffix is not a supported point format.

    >>> file_kind("tile_01.LAZ"), file_kind("faixa.xyz")
    ('las', 'ascii')
    """
    suffix = Path(path).suffix.lower()
    if suffix in LAS_SUFFIXES:
        return "las"
    if suffix in ASCII_SUFFIXES:
        return "ascii"
    raise LidarFormatError(f"{path}: unsupported point file type {suffix or '(no suffix)'!r}; "
                           f"use one of {', '.join(LAS_SUFFIXES + ASCII_SUFFIXES)}")


@dataclass(frozen=True)
class FileHeader:
    """What a point file says about itself without reading every point.

    Attributes
    ----------
    path : Path
    kind : str
        ``"las"`` or ``"ascii"``.
    description : str
        e.g. ``"LAZ 1.2, point format 1"`` or ``"ASCII (whitespace; E N H intensity)"``.
    count : int
        Number of points.
    bounds : Bounds
        Bounds in metres (from the LAS header, or scanned for text files).
    crs : pyproj.CRS or None
        The file's CRS, or the one given by the caller when the file has none.
    crs_from_file : bool
        True when the CRS was read from the file.
    attributes : tuple of str
        Attribute names the points carry.
    """

    path: Path
    kind: str
    description: str
    count: int
    bounds: Bounds
    crs: Any
    crs_from_file: bool
    attributes: tuple[str, ...]


# --------------------------------------------------------------------------- LAS
def _las_description(path: Path, header: Any) -> str:
    kind = "LAZ" if header.are_points_compressed else "LAS"
    if header.are_points_compressed and is_copc(path):   # the COPC info VLR, whatever the file name
        kind = "COPC"
    return f"{kind} {header.version}, point format {header.point_format.id}"


def _iter_las(path: Path, chunk_size: int, crs: Any, progress: Progress | None) -> Iterator[PointCloud]:
    reader, file_crs, _ = open_checked(path, crs)
    with reader:
        header = reader.header
        total = int(header.point_count)
        size = path.stat().st_size
        done = 0
        try:
            for rec in reader.chunk_iterator(chunk_size):
                if len(rec) == 0:
                    break
                cloud = las_record_cloud(rec, header, file_crs, done, path)
                done += len(rec)
                if progress is not None and total:
                    progress(int(size * len(rec) / total))
                yield cloud
        except (LidarFormatError, CRSError):
            raise
        except BaseException as ex:  # lazrs.LazrsError, a Rust panic, ValueError on a short buffer...
            raise decoder_error(path, ex, f"truncated or corrupt point data after {done} of "
                                           f"{total} points") from ex
        if done != total:
            raise LidarFormatError(f"{path}: truncated: read {done} of the {total} points "
                                   "the header announces")


def las_chunk_points(path: str | os.PathLike) -> int | None:
    """Points per compressed chunk of a LAZ file; ``None`` for LAS or variable-size chunks.

    Raises
    ------
    TileIOError, LidarFormatError
        As :func:`read_header`.
    """
    path = Path(path)
    reader = open_las(path)
    with reader:
        h = reader.header
        if not h.are_points_compressed:
            return None
        try:
            import lazrs

            vlr = h.vlrs[h.vlrs.index("LasZipVlr")]
            lv = lazrs.LazVlr(vlr.record_data)
            if lv.uses_variable_size_chunks():
                return None
            return int(lv.chunk_size())
        except BaseException as ex:  # missing or corrupt LasZip record (lazrs may panic)
            raise decoder_error(path, ex, "cannot read the LAZ chunk record") from ex


def iter_las_ranges(path: str | os.PathLike, ranges: Sequence[tuple[int, int]], *, crs: Any = None,
                    piece_points: int | None = None,
                    max_read_points: int = DEFAULT_CHUNK_SIZE) -> Iterator[tuple[int, PointCloud]]:
    """Decode only the point ranges ``[start, stop)`` of a LAS/LAZ file (seek, then read).

    The points, coordinates and attributes are exactly those :func:`iter_points`
    returns for the same indices.  A LAZ file is decompressed from the start of
    the compressed chunk holding *start*, so ranges starting on its chunks
    (:func:`las_chunk_points`) decode nothing else; the single-threaded lazrs
    decoder is used, which stops at *stop* (the parallel one decodes whole
    chunks).

    Parameters
    ----------
    path : path-like
        LAS/LAZ file.
    ranges : sequence of (int, int)
        Point index ranges, each ``0 <= start < stop <= count``; read in the order given.
    crs : CRS-like, optional
        CRS of the file when it carries none.
    piece_points : int, optional
        Split each range into pieces of this many points counted from its start
        (the last one shorter); default: pieces of at most *max_read_points*.
    max_read_points : int
        Largest number of points decoded in one read (bounds memory).

    Yields
    ------
    (int, PointCloud)
        Index of the first point of the piece, and the piece; in range order.

    Raises
    ------
    TileIOError
        The file is missing or unreadable.
    LidarFormatError
        Not a LAS/LAZ file, a range outside ``0..count``, truncated or corrupt data.
    CRSError
        As :func:`iter_points`.
    """
    path = Path(path)
    if file_kind(path) != "las":
        raise LidarFormatError(f"{path}: point ranges can be read from LAS/LAZ files only")
    piece = int(piece_points or max_read_points)
    if piece <= 0 or max_read_points <= 0:
        raise ValueError(f"piece_points and max_read_points must be positive, got {piece_points}, "
                         f"{max_read_points}")
    per_read = max(1, int(max_read_points) // piece) * piece
    reader, file_crs, _ = open_checked(path, crs, serial=True)
    with reader:
        header = reader.header
        total = int(header.point_count)
        for start, stop in ranges:
            start, stop = int(start), int(stop)
            if not 0 <= start < stop <= total:
                raise LidarFormatError(f"{path}: point range {start}..{stop} is outside the file's "
                                       f"0..{total} points; rebuild the index")
            pos = start
            try:
                reader.seek(start)
                while pos < stop:
                    n = min(per_read, stop - pos)
                    rec = reader.read_points(n)
                    if len(rec) != n:
                        raise LidarFormatError(f"{path}: truncated: read {len(rec)} of the {n} points "
                                               f"from point {pos}")
                    for a in range(0, n, piece):
                        b = min(a + piece, n)
                        yield pos + a, las_record_cloud(rec[a:b], header, file_crs, pos + a, path)
                    pos += n
            except (LidarFormatError, CRSError):
                raise
            except BaseException as ex:  # lazrs.LazrsError, a Rust panic, a short buffer...
                raise decoder_error(path, ex, f"truncated or corrupt point data reading points "
                                               f"{pos}..{stop} of {total}") from ex


def _las_header(path: Path, crs: Any) -> FileHeader:
    reader, crs_out, from_file = open_checked(path, crs)
    with reader:
        h = reader.header
        names = set(h.point_format.dimension_names)
        return FileHeader(path, "las", _las_description(path, h), int(h.point_count),
                          Bounds.from_minmax(h.mins, h.maxs), crs_out, from_file,
                          tuple(a for a in LAS_ATTRIBUTES if a in names))


# --------------------------------------------------------------------------- ASCII
@dataclass(frozen=True)
class _Layout:
    delimiter: str | None        # None = whitespace
    decimal_comma: bool
    names: tuple[str | None, ...]  # canonical name per field, None = skip
    data_start: int              # 0-based index of the first line after the header

    @property
    def ncols(self) -> int:
        return len(self.names)

    def describe(self) -> str:
        sep = {None: "whitespace", ",": "comma", ";": "semicolon"}.get(self.delimiter, repr(self.delimiter))
        dec = ", decimal comma" if self.decimal_comma else ""
        return f"ASCII ({sep}{dec}; {' '.join(n or '-' for n in self.names)})"


def _canonical(name: str, path: Path, line: int | None) -> str | None:
    key = name.strip().lower()
    if key in ("-", "_", "skip", ""):
        return None
    if key in _ALIAS_TO_NAME:
        return _ALIAS_TO_NAME[key]
    if not re.match(r"^[a-z_][a-z0-9_]*$", key):
        raise LidarFormatError(f"{location(path, line)}: column name {name!r} is not a valid name")
    return key


def _split(line: str, delimiter: str | None) -> list[str]:
    if delimiter is None:
        return line.split()
    return [t.strip() for t in line.split(delimiter)]


def _sniff_delimiter(line: str) -> tuple[str | None, bool]:
    if ";" in line:
        return ";", "," in line
    if "," in line:
        toks = line.split()
        if len(toks) >= 3 and all(_DECIMAL_COMMA_RE.match(t) for t in toks):
            return None, True
        return ",", False
    return None, False


def _norm_delimiter(delimiter: str | None) -> str | None:
    if delimiter is None:
        return None
    d = {"whitespace": " ", "space": " ", "tab": "\t", "comma": ",", "semicolon": ";"}.get(
        delimiter.lower(), delimiter)
    if d not in (" ", "\t", ",", ";"):
        raise LidarFormatError(f"unsupported delimiter {delimiter!r}; use whitespace, ',' or ';'")
    return None if d in (" ", "\t") else d


def _is_number(tok: str, decimal_comma: bool) -> bool:
    if decimal_comma:
        tok = tok.replace(",", ".")
    return bool(_NUMBER_RE.match(tok))


_NO_COORDINATES = "no column for"


def is_foreign_table(path: str | os.PathLike) -> bool:
    """True for a text file whose header names no E, N, H columns: a table (a job list, a
    control file) that is not a point file; folder and glob expansion of tiles skip it.

    LAS/LAZ files, headerless text and tables that do name coordinates are not foreign.
    """
    path = Path(path)
    if path.suffix.lower() not in ASCII_SUFFIXES:
        return False
    try:
        _ascii_layout(path, None, None)
    except LidarFormatError as ex:
        return _NO_COORDINATES in str(ex)
    except TileIOError:
        return False
    return False


def _ascii_layout(path: Path, columns: Sequence[str] | str | None, delimiter: str | None) -> _Layout:
    try:
        fh = open(path, encoding="utf-8-sig", errors="replace")
    except OSError as ex:
        raise open_error(path, ex, "a point file") from ex
    first: tuple[int, str] | None = None
    second: tuple[int, str] | None = None
    with fh:
        for idx, raw in enumerate(fh):
            s = raw.strip()
            if not s or s.startswith("#"):
                continue
            if first is None:
                first = (idx, s)
            else:
                second = (idx, s)
                break
    if first is None:
        raise LidarFormatError(f"{path}: no points (the file is empty or all comments)")
    forced = delimiter is not None
    delim = _norm_delimiter(delimiter)
    # header? a first line that is not all numbers
    sniff_line = first[1]
    d0, dc0 = _sniff_delimiter(sniff_line)
    tokens0 = _split(sniff_line, delim if forced else d0)
    has_header = not all(_is_number(t, dc0 or (forced and delim != ",")) for t in tokens0)
    data = second if has_header else first
    if data is None:
        raise LidarFormatError(f"{location(path, first[0] + 1)}: only a header line, no points")
    d, dec = _sniff_delimiter(data[1])
    if forced:
        d = delim
        dec = d != "," and "," in data[1]
    ntok = len(_split(data[1], d))
    if columns is not None:
        if isinstance(columns, str):
            columns = columns.replace(",", " ").split()
        names = tuple(_canonical(c, path, None) for c in columns)
    elif has_header:
        header_tokens = _split(first[1].lstrip("#"), d)
        names = tuple(_canonical(c, path, first[0] + 1) for c in header_tokens)
    else:
        if ntok not in _DEFAULT_COLUMNS:
            raise LidarFormatError(f"{location(path, data[0] + 1)}: {ntok} fields and no header; "
                                   "name the columns, e.g. columns='E N H intensity return class' "
                                   "(--columns on the command line)")
        names = _DEFAULT_COLUMNS[ntok]
    where = location(path, first[0] + 1 if has_header and columns is None else None)
    real = [n for n in names if n is not None]
    dup = sorted({n for n in real if real.count(n) > 1})
    if dup:
        raise LidarFormatError(f"{where}: column(s) {', '.join(dup)} given twice")
    missing = [n for n in ("E", "N", "H") if n not in real]
    if missing:
        raise LidarFormatError(f"{where}: {_NO_COORDINATES} {', '.join(missing)} among "
                               f"{' '.join(n or '-' for n in names)}; not a point file? Name its columns "
                               "(--columns of `lidarcat lidar`, columns= in Python) or move it out of the tiles")
    if len(names) != ntok:
        raise LidarFormatError(f"{location(path, data[0] + 1)}: {ntok} fields, expected {len(names)} "
                               f"({' '.join(n or '-' for n in names)})")
    return _Layout(d, dec, names, first[0] + 1 if has_header else 0)


def _locate_bad_line(path: Path, lines: list[str], first_line_no: int, layout: _Layout) -> None:
    """Find the first bad line of a chunk and raise a located error."""
    for k, raw in enumerate(lines):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        line_no = first_line_no + k
        toks = _split(s.split("#", 1)[0].strip(), layout.delimiter)
        if len(toks) != layout.ncols:
            raise LidarFormatError(f"{location(path, line_no)}: {len(toks)} fields, expected "
                                   f"{layout.ncols} ({' '.join(n or '-' for n in layout.names)})")
        for tok, name in zip(toks, layout.names):
            if name is None:
                continue
            t = tok.replace(",", ".") if layout.decimal_comma else tok
            try:
                v = parse_float(t)
            except ValueError as ex:
                raise LidarFormatError(f"{location(path, line_no, name)}: {ex}") from None
            if not math.isfinite(v):
                raise LidarFormatError(f"{location(path, line_no, name)}: {tok!r} is not a finite number")


def _data_line_numbers(lines: list[str], first_line_no: int) -> np.ndarray:
    return np.array([first_line_no + k for k, raw in enumerate(lines)
                     if raw.strip() and not raw.lstrip().startswith("#")], dtype=np.int64)


def _ascii_chunk_cloud(path: Path, lines: list[str], first_line_no: int, layout: _Layout,
                       crs: Any) -> PointCloud | None:
    text = "".join(lines)
    if layout.decimal_comma:
        text = text.replace(",", ".")
    usecols = [k for k, n in enumerate(layout.names) if n is not None]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
            arr = np.loadtxt(io.StringIO(text), dtype=np.float64, delimiter=layout.delimiter,
                             comments="#", ndmin=2)
    except ValueError:
        _locate_bad_line(path, lines, first_line_no, layout)
        raise LidarFormatError(f"{path}: cannot parse lines {first_line_no}-"
                               f"{first_line_no + len(lines) - 1}") from None
    if arr.size == 0:
        return None
    if arr.shape[1] != layout.ncols or not np.isfinite(arr[:, usecols]).all():
        _locate_bad_line(path, lines, first_line_no, layout)
    cols = {name: arr[:, k] for k, name in enumerate(layout.names) if name is not None}
    xyz = np.column_stack([cols.pop("E"), cols.pop("N"), cols.pop("H")])
    if not (np.abs(xyz) <= MAX_ABS_COORD_M).all():
        check_coords(path, xyz, 0, _data_line_numbers(lines, first_line_no))
    attrs: dict[str, np.ndarray] = {}
    for name, values in cols.items():
        dtype = STANDARD_ATTRIBUTES.get(name)
        if dtype is None or dtype.kind == "f":
            attrs[name] = values
            continue
        info = np.iinfo(dtype)
        ok = (values == np.round(values)) & (values >= info.min) & (values <= info.max)
        if ok.all():
            attrs[name] = values.astype(dtype)
        elif name == "intensity":
            attrs[name] = values
        else:
            bad = int(np.flatnonzero(~ok)[0])
            line_no = int(_data_line_numbers(lines, first_line_no)[bad])
            raise LidarFormatError(f"{location(path, line_no, name)}: {float(values[bad])!r} is not an "
                                   f"integer in {info.min}..{info.max}")
    return PointCloud(xyz, attrs, crs)


def _iter_ascii(path: Path, chunk_size: int, crs: Any, columns: Any, delimiter: str | None,
                progress: Progress | None) -> Iterator[PointCloud]:
    layout = _ascii_layout(path, columns, delimiter)
    crs_out, _ = settle_crs(path, None, crs)
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for _ in range(layout.data_start):
            next(fh)
        line_no = layout.data_start + 1
        while True:
            lines = list(itertools.islice(fh, chunk_size))
            if not lines:
                break
            cloud = _ascii_chunk_cloud(path, lines, line_no, layout, crs_out)
            if progress is not None:
                progress(sum(len(s) for s in lines))
            line_no += len(lines)
            if cloud is not None:
                yield cloud


# --------------------------------------------------------------------------- public
def iter_points(path: str | os.PathLike, chunk_size: int | None = None, *, crs: Any = None,
                columns: Sequence[str] | str | None = None, delimiter: str | None = None,
                progress: Progress | None = None) -> Iterator[PointCloud]:
    """Stream a point file as a sequence of :class:`PointCloud` chunks.

    Parameters
    ----------
    path : path-like
        LAS/LAZ/COPC or text point file.
    chunk_size : int, optional
        Points per chunk (default :data:`DEFAULT_CHUNK_SIZE`); lines per chunk
        for text files.  Streaming a LAS/LAZ file peaks at about 110 bytes per
        point of it (the chunk held, 39 bytes a point, and the decoding buffers).
    crs : CRS-like, optional
        CRS of the file when it carries none (text files never do).
    columns, delimiter
        Text files only; see the module docstring.
    progress : callable, optional
        Called with the number of bytes of the file processed by each chunk.

    Yields
    ------
    PointCloud
        Consecutive chunks, in file order.

    Raises
    ------
    TileIOError
        The file is missing or unreadable.
    LidarFormatError
        Unsupported suffix, corrupt header, truncated data, bad text line
        (names the file and the line).
    CRSError
        Unknown *crs*, or *crs* conflicts with the file's own.
    """
    path = Path(path)
    chunk = int(chunk_size or DEFAULT_CHUNK_SIZE)
    if chunk <= 0:
        raise ValueError(f"chunk_size must be positive, got {chunk_size}")
    if file_kind(path) == "las":
        if columns is not None or delimiter is not None:
            log.debug("%s: columns/delimiter ignored for LAS/LAZ", path)
        return _iter_las(path, chunk, crs, progress)
    return _iter_ascii(path, chunk, crs, columns, delimiter, progress)


def read_points(path: str | os.PathLike, *, crs: Any = None, columns: Sequence[str] | str | None = None,
                delimiter: str | None = None, chunk_size: int | None = None,
                progress: Progress | None = None) -> PointCloud:
    """Read a whole point file into one :class:`PointCloud`.

    Same parameters and errors as :func:`iter_points`; use that (or a
    :class:`~lidarcat.lidar.TileIndex`) for files larger than memory.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "faixa.xyz"
    >>> _ = p.write_text("677757,80 7183482,00 905,12 118\\n677758,10 7183482,40 905,20 121\\n")
    >>> pc = read_points(p, crs="EPSG:29192")
    >>> pc.xyz[0].tolist(), pc.attributes["intensity"].tolist(), pc.crs.to_epsg()
    ([677757.8, 7183482.0, 905.12], [118, 121], 29192)
    """
    chunks = list(iter_points(path, chunk_size, crs=crs, columns=columns, delimiter=delimiter,
                              progress=progress))
    if not chunks:
        return PointCloud.empty(crs=resolve_crs(crs))
    return PointCloud.concat(chunks)


def read_header(path: str | os.PathLike, *, crs: Any = None, columns: Sequence[str] | str | None = None,
                delimiter: str | None = None, progress: Progress | None = None) -> FileHeader:
    """Count, bounds and CRS of a point file (LAS: header only; text: one scan).

    Raises
    ------
    TileIOError, LidarFormatError, CRSError
        As :func:`iter_points`.
    """
    path = Path(path)
    if file_kind(path) == "las":
        h = _las_header(path, crs)
        if progress is not None:
            progress(path.stat().st_size)
        return h
    layout = _ascii_layout(path, columns, delimiter)
    count = 0
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    names: tuple[str, ...] = ()
    crs_out = resolve_crs(crs)
    for chunk in _iter_ascii(path, DEFAULT_CHUNK_SIZE, crs_out, columns, delimiter, progress):
        count += len(chunk)
        lo = np.minimum(lo, chunk.xyz.min(axis=0))
        hi = np.maximum(hi, chunk.xyz.max(axis=0))
        names = tuple(chunk.attributes)
    return FileHeader(path, "ascii", layout.describe(), count,
                      Bounds.from_minmax(lo if count else None, hi), crs_out, False, names)


# --------------------------------------------------------------------------- writing
def _decimals_for(values: np.ndarray, max_decimals: int = 9) -> str:
    """printf format that writes *values* so that they read back identically.

    The fewest decimals that round-trip exactly on a sample, confirmed on the
    whole column; ``%.17g`` (always exact) otherwise.
    """
    if values.size == 0:
        return "%.3f"
    sample = values[:: max(1, values.size // 5000)]
    for d in range(max_decimals + 1):
        fmt = f"%.{d}f"
        if np.array_equal(np.char.mod(fmt, sample).astype(np.float64), sample):
            if np.array_equal(np.round(values, d), values):
                return fmt
            break
    return "%.17g"


def _write_ascii(path: Path, cloud: PointCloud, delimiter: str | None) -> None:
    if delimiter is None:
        delimiter = "," if path.suffix.lower() == ".csv" else " "
    names = ["E", "N", "H"] + list(cloud.attributes)
    cols = [cloud.xyz[:, 0], cloud.xyz[:, 1], cloud.xyz[:, 2]] + list(cloud.attributes.values())
    fmts = ["%d" if c.dtype.kind in "iu" else _decimals_for(c) for c in cols]
    line_fmt = delimiter.join(fmts)
    with atomic_write(path, "w", newline="\n") as fh:
        fh.write(delimiter.join(names) + "\n")
        step = 500_000
        for start in range(0, len(cloud), step):
            block = [c[start:start + step].tolist() for c in cols]
            fh.write("".join([line_fmt % row + "\n" for row in zip(*block)]))


def _write_las(path: Path, cloud: PointCloud, scale_m: float) -> None:
    import laspy

    a = cloud.attributes
    big = any(name in a and len(cloud) and int(a[name].max()) > lim
              for name, lim in (("return_number", 7), ("number_of_returns", 7), ("classification", 31)))
    if big:
        point_format, version = 6, "1.4"
    else:
        point_format, version = (1 if "gps_time" in a else 0), "1.2"
    header = laspy.LasHeader(point_format=point_format, version=version)
    mins = cloud.xyz.min(axis=0) if len(cloud) else np.zeros(3)
    offsets = np.floor(mins)
    header.offsets = offsets
    header.scales = np.array([scale_m] * 3)
    if cloud.crs is not None:
        header.add_crs(cloud.crs)
    las = laspy.LasData(header)
    inv = round(1.0 / scale_m)
    for k, dim in enumerate(("X", "Y", "Z")):
        if abs(inv * scale_m - 1.0) < 1e-12:
            raw = np.rint(cloud.xyz[:, k] * inv) - offsets[k] * inv
        else:
            raw = np.rint((cloud.xyz[:, k] - offsets[k]) / scale_m)
        if len(raw) and (raw.max() > 2**31 - 1 or raw.min() < -(2**31)):
            raise LidarFormatError(f"{path}: the extent of the points is too large for a scale of "
                                   f"{scale_m} m; use a coarser scale")
        setattr(las, dim, raw.astype(np.int32))
    for name in LAS_ATTRIBUTES:
        if name in a:
            values = a[name]
            if name == "intensity" and values.dtype.kind == "f":
                values = np.clip(np.rint(values), 0, 65535)
            setattr(las, name, values.astype(STANDARD_ATTRIBUTES[name]))
    compress = path.suffix.lower() == ".laz"
    with atomic_write(path, "wb") as fh:
        las.write(fh, do_compress=compress)


def write_points(path: str | os.PathLike, cloud: PointCloud, *, scale_m: float = 0.001,
                 delimiter: str | None = None) -> Path:
    """Write *cloud* to a LAS/LAZ or text file (atomically), chosen by suffix.

    Parameters
    ----------
    path : path-like
        ``.las``/``.laz`` (LAS 1.2 point format 0/1, or 1.4 format 6 when return
        numbers exceed 7 or classes exceed 31; the CRS is written as a WKT
        record), or a text suffix (a header line, then one point per line; each
        column written with the fewest decimals that read back identically).
    cloud : PointCloud
    scale_m : float
        LAS coordinate resolution, metres (default 1 mm).
    delimiter : str, optional
        Text separator (default ``,`` for ``.csv``, a space otherwise).

    Returns
    -------
    Path

    Raises
    ------
    LidarFormatError
        Unsupported suffix, a NaN or infinite coordinate (the readers refuse
        them), or coordinates out of range for *scale_m*.
    """
    path = Path(path)
    kind = file_kind(path)
    bad = np.flatnonzero(~np.isfinite(cloud.xyz).all(axis=1))
    if len(bad):
        raise LidarFormatError(f"{path}: point {int(bad[0])} (counting from 0) has a non-finite coordinate "
                               f"{cloud.xyz[bad[0]].tolist()} ({len(bad)} such points); drop them first")
    if kind == "las":
        _write_las(path, cloud, scale_m)
    else:
        _write_ascii(path, cloud, delimiter)
    return path
