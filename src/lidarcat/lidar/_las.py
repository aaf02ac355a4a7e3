"""LAS/LAZ record helpers shared by :mod:`.readers` and :mod:`.copc` (private to :mod:`lidarcat.lidar`).

Header prechecks against the file size (before laspy or lazrs allocate
anything), the located errors of a failing decoder, opening a checked reader,
and turning LAS point records into a :class:`PointCloud` with sane coordinates.
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CRSError, LidarFormatError, TileIOError, location
from .cloud import PointCloud
from .crs import crs_compatible, crs_label, resolve_crs

__all__ = ["MAX_ABS_COORD_M", "VLR_HEADER_BYTES", "EVLR_HEADER_BYTES", "NOT_CAUGHT", "MAX_LAZ_POINTS_PER_BYTE",
           "MAX_LAZ_CHUNK_POINTS", "LAS_ATTRIBUTES", "settle_crs", "open_error", "precheck_las", "laszip_record",
           "precheck_laszip", "layered_items_only_point14", "precheck_layered_chunks", "precheck_laz_chunk_table",
           "decoder_error", "open_las", "las_crs", "check_las_size", "open_checked", "scale_coords",
           "check_coords", "las_record_cloud", "ascii_header_text"]

log = logging.getLogger("lidarcat.lidar.readers")   # the readers' messages, under the readers' logger

#: largest absolute coordinate accepted, metres (or degrees): the Earth fits well inside it
MAX_ABS_COORD_M = 1e9
#: bytes of a LAS VLR header / LAS 1.4 extended VLR header (a record is at least this long)
VLR_HEADER_BYTES = 54
EVLR_HEADER_BYTES = 60
NOT_CAUGHT = (KeyboardInterrupt, SystemExit, GeneratorExit)
#: upper bound of LAZ points per byte of compressed data (a chunk of 50 000 points starts with one
#: raw point of 20+ bytes: 2 500 points a byte; 10 000 leaves room for any real compressor)
MAX_LAZ_POINTS_PER_BYTE = 10_000
#: largest LAZ chunk accepted, points (LASzip writes 50 000; lazrs allocates a chunk's points)
MAX_LAZ_CHUNK_POINTS = 10_000_000

LAS_ATTRIBUTES = ("intensity", "return_number", "number_of_returns", "classification",
                   "point_source_id", "gps_time")


# --------------------------------------------------------------------------- CRS
def settle_crs(path: Path, file_crs: Any, given: Any) -> tuple[Any, bool]:
    given_crs = resolve_crs(given)
    if file_crs is None:
        return given_crs, False
    if given_crs is not None and not crs_compatible(file_crs, given_crs):
        raise CRSError(f"{path}: the file says its CRS is {crs_label(file_crs)} but "
                       f"{crs_label(given_crs)} was given; drop --crs or transform the file")
    return file_crs, True


def open_error(path: Path, ex: OSError, expected: str) -> TileIOError:
    """The located error for a point file that cannot be opened."""
    if isinstance(ex, FileNotFoundError):
        return TileIOError(f"{path}: file not found")
    if isinstance(ex, IsADirectoryError):
        return TileIOError(f"{path}: is a folder, expected {expected}")
    return TileIOError(f"{path}: cannot read ({ex.strerror})")


# --------------------------------------------------------------------------- LAS
def precheck_las(path: Path) -> None:
    """Check the fixed LAS header against the file size before laspy allocates anything.

    Raises
    ------
    TileIOError
        Missing or unreadable file.
    LidarFormatError
        Not a LAS file, or a header field that cannot be true for a file of
        this size (names the field and both numbers).
    """
    try:
        size = path.stat().st_size
        with open(path, "rb") as fh:
            head = fh.read(375)
    except OSError as ex:
        raise open_error(path, ex, "a LAS/LAZ file") from ex
    if len(head) < 4 or head[:4] != b"LASF":
        raise LidarFormatError(f"{path}: not a valid LAS/LAZ file (it does not start with 'LASF')")
    if len(head) < 227:
        raise LidarFormatError(f"{path}: truncated: {size} bytes, shorter than a LAS header (227 bytes)")
    major, minor = head[24], head[25]
    header_size, offset, n_vlr = struct.unpack_from("<HII", head, 94)
    fmt_byte, rec_len, legacy_count = struct.unpack_from("<BHI", head, 104)
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)

    def bad(what: str) -> LidarFormatError:
        return LidarFormatError(f"{path}: corrupt LAS header: {what}")

    if major != 1 or minor > 4:
        raise bad(f"version {major}.{minor}; LAS 1.0-1.4 are read")
    if not 227 <= header_size <= size:
        raise bad(f"header size {header_size} bytes (at least 227, at most the file's {size})")
    if not header_size <= offset <= size:
        raise bad(f"offset to the point data {offset} is outside the header size {header_size}.."
                  f"file size {size}")
    room = offset - header_size
    if n_vlr * VLR_HEADER_BYTES > room:
        raise bad(f"{n_vlr:,} variable-length records announced (at least {VLR_HEADER_BYTES} bytes "
                  f"each) but only {room:,} bytes lie between the header and the point data")
    count = legacy_count
    if minor >= 4 and header_size >= 375 and len(head) >= 375:
        evlr_start, n_evlr, count64 = struct.unpack_from("<QIQ", head, 235)
        count = count64 or legacy_count
        if n_evlr and (evlr_start < offset or evlr_start + n_evlr * EVLR_HEADER_BYTES > size):
            raise bad(f"{n_evlr:,} extended VLRs announced at byte {evlr_start:,} but the file has "
                      f"{size:,} bytes")
    compressed = bool(fmt_byte & 0xC0)
    if compressed:
        rec = laszip_record(path, header_size, offset, n_vlr)
        compressor = None if rec is None else precheck_laszip(path, rec, rec_len, bad)
        if compressor in (2, 3) and precheck_laz_chunk_table(path, size, offset, bad) \
                and compressor == 3 and layered_items_only_point14(rec):
            precheck_layered_chunks(path, offset, rec_len, bad)
    if compressed and count > MAX_LAZ_POINTS_PER_BYTE * max(size - offset, 0):
        raise LidarFormatError(f"{path}: corrupt LAS header: {count:,} points announced but the "
                               f"{max(size - offset, 0):,} bytes of compressed point data cannot hold more "
                               f"than {MAX_LAZ_POINTS_PER_BYTE * max(size - offset, 0):,}")
    if not compressed and rec_len and count * rec_len > size - offset:
        raise LidarFormatError(f"{path}: truncated: the header announces {count} points "
                               f"({count * rec_len + offset} bytes) but the file has {size} bytes")
    for axis, sc, off in zip("XYZ", scales, offsets):
        if not (math.isfinite(sc) and sc != 0.0 and math.isfinite(off)):
            raise bad(f"{axis} scale {sc!r} / offset {off!r}; a finite non-zero scale and a finite "
                      "offset are required")


def laszip_record(path: Path, header_size: int, offset: int, n_vlr: int) -> bytes | None:
    """The data of the LasZip record (user id ``laszip encoded``, record 22204), None when missing
    (laspy then says so)."""
    with open(path, "rb") as fh:
        pos = header_size
        for _ in range(n_vlr):
            fh.seek(pos)
            head = fh.read(VLR_HEADER_BYTES)
            if len(head) < VLR_HEADER_BYTES:
                return None
            user_id = head[2:18].split(b"\0", 1)[0]
            record_id, length = struct.unpack_from("<HH", head, 18)
            if user_id == b"laszip encoded" and record_id == 22204:
                return fh.read(min(length, max(offset - pos - VLR_HEADER_BYTES, 0)))
            pos += VLR_HEADER_BYTES + length
            if pos > offset:
                return None
    return None


def precheck_laszip(path: Path, rec: bytes, rec_len: int, bad: Callable[[str], LidarFormatError]) -> int:
    """Check the LasZip record (lazrs allocates from its chunk size and item sizes, and a failed
    allocation aborts the process); returns the compressor (1 pointwise, 2 chunked, 3 layered)."""
    if len(rec) < 34:
        raise bad(f"the LasZip record holds {len(rec)} bytes, fewer than its 34-byte head")
    compressor, = struct.unpack_from("<H", rec, 0)
    chunk_size, = struct.unpack_from("<I", rec, 12)
    n_items, = struct.unpack_from("<H", rec, 32)
    if len(rec) != 34 + 6 * n_items:
        raise bad(f"the LasZip record lists {n_items} items but holds {len(rec)} bytes "
                  f"(expected {34 + 6 * n_items})")
    sizes = [struct.unpack_from("<H", rec, 34 + 6 * k + 2)[0] for k in range(n_items)]
    if sum(sizes) != rec_len:
        raise bad(f"the LasZip items add up to {sum(sizes)} bytes a point but the header says {rec_len}")
    if chunk_size != 0xFFFFFFFF and not 0 < chunk_size <= MAX_LAZ_CHUNK_POINTS:
        raise bad(f"LAZ chunk size {chunk_size:,} points (1..{MAX_LAZ_CHUNK_POINTS:,}, or variable)")
    return compressor


def layered_items_only_point14(rec: bytes) -> bool:
    """True when the LasZip record holds one item, a LAS 1.4 point (type 10, 9 layers)."""
    n_items, = struct.unpack_from("<H", rec, 32)
    return n_items == 1 and struct.unpack_from("<H", rec, 34)[0] == 10


def precheck_layered_chunks(path: Path, offset: int, rec_len: int, bad: Callable[[str], LidarFormatError]
                             ) -> None:
    """Walk the chunks of a layered LAZ file of LAS 1.4 points: each is a point count (4 bytes),
    the first point raw, 9 layer sizes (4 bytes each) and the layers; every size must fit
    before the chunk table.  lazrs allocates each layer from its size (up to 4 GB) and a
    failed allocation aborts the process (found by the fuzz suite)."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        (table_at,) = struct.unpack("<q", fh.read(8))
        pos, k = offset + 8, 0
        while pos < table_at:
            fh.seek(pos + 4 + rec_len)
            raw = fh.read(36)
            if len(raw) < 36:
                return  # truncated: lazrs says where the data ends
            sizes = struct.unpack("<9I", raw)
            start = pos + 4 + rec_len + 36
            if sum(sizes) > table_at - start:
                raise bad(f"LAZ chunk {k} (byte {pos}) announces layers of {sum(sizes):,} bytes but only "
                          f"{max(table_at - start, 0):,} bytes lie before the chunk table")
            pos, k = start + sum(sizes), k + 1


def precheck_laz_chunk_table(path: Path, size: int, offset: int, bad: Callable[[str], LidarFormatError]
                              ) -> bool:
    """The LAZ chunk table (its offset, the first 8 bytes of the point data, or the file's last 8
    when that is -1; then a version and the chunk count) must lie in the file and count no more
    chunks than bytes before it: lazrs allocates the table from that count and a failed
    allocation aborts the process (no exception to catch)."""
    if size < offset + 8:
        raise LidarFormatError(f"{path}: truncated: no compressed point data after byte {offset}")
    with open(path, "rb") as fh:
        fh.seek(offset)
        (table_at,) = struct.unpack("<q", fh.read(8))
        if table_at == -1:  # written by a streaming compressor: the offset is at the end
            fh.seek(size - 8)
            (table_at,) = struct.unpack("<q", fh.read(8))
        if table_at > size - 8:
            return False  # a truncated file: lazrs decodes without the table and says where the data ends
        if table_at < offset + 8:
            raise bad(f"the LAZ chunk table offset {table_at} lies before the compressed data "
                      f"(bytes {offset + 8}..{size - 8})")
        fh.seek(table_at)
        _version, n_chunks = struct.unpack("<II", fh.read(8))
    room = table_at - offset - 8
    if n_chunks > room:
        raise bad(f"the LAZ chunk table announces {n_chunks:,} chunks but only {room:,} bytes of "
                  "compressed points precede it")
    return True


def decoder_error(path: Path, ex: BaseException, what: str) -> LidarFormatError:
    """The located error for a failure inside laspy/lazrs (a Rust panic included)."""
    if isinstance(ex, NOT_CAUGHT):
        raise ex
    return LidarFormatError(f"{path}: {what} ({type(ex).__name__}: {str(ex)[:200]})")


def open_las(path: Path, serial: bool = False):
    import laspy

    precheck_las(path)
    backend = None
    if serial and laspy.LazBackend.Lazrs.is_available():
        backend = laspy.LazBackend.Lazrs
    try:
        return laspy.open(path, laz_backend=backend)
    except (FileNotFoundError, IsADirectoryError, PermissionError) as ex:
        raise open_error(path, ex, "a LAS/LAZ file") from ex
    except BaseException as ex:  # LaspyException, ValueError, struct.error, a lazrs PanicException...
        raise decoder_error(path, ex, "not a valid LAS/LAZ file: corrupt header") from ex


def las_crs(path: Path, header: Any, given: Any = None) -> Any:
    """The CRS record of the file; when *given* is set, an unreadable record is ignored."""
    try:
        return header.parse_crs()
    except BaseException as ex:
        if isinstance(ex, NOT_CAUGHT):
            raise
        if given is not None:
            log.warning("%s: unreadable CRS record ignored, using the given %s (%s)", path,
                        crs_label(given), str(ex)[:120])
            return None
        raise CRSError(f"{path}: cannot parse the CRS record of the file ({str(ex)[:200]}); "
                       "give the CRS with --crs") from ex


def check_las_size(path: Path, header: Any) -> None:
    if header.are_points_compressed:
        return
    need = header.offset_to_point_data + header.point_count * header.point_format.size
    have = path.stat().st_size
    if have < need:
        raise LidarFormatError(f"{path}: truncated: the header announces {header.point_count} points "
                               f"({need} bytes) but the file has {have} bytes")


def open_checked(path: Path, crs: Any, serial: bool = False) -> tuple[Any, Any, bool]:
    """An open laspy reader whose header was checked (CRS record, size against the point
    count), the CRS of its points (the file's, else *crs*) and whether it is the file's."""
    given = resolve_crs(crs)  # the caller's CRS first: it decides what an unreadable record means
    reader = open_las(path, serial)
    try:
        crs_out, from_file = settle_crs(path, las_crs(path, reader.header, given), given)
        check_las_size(path, reader.header)
    except BaseException:
        reader.close()
        raise
    return reader, crs_out, from_file


def scale_coords(raw: np.ndarray, scale: float, offset: float) -> np.ndarray:
    inv = 1.0 / scale
    inv_r = round(inv)
    if inv_r >= 1 and abs(inv - inv_r) <= 1e-9 * inv_r and float(offset * inv_r).is_integer() \
            and abs(offset * inv_r) < 2**52:
        return (raw.astype(np.float64) + offset * inv_r) / inv_r
    return raw.astype(np.float64) * scale + offset


def check_coords(path: Path, xyz: np.ndarray, first: int, lines: np.ndarray | None = None) -> None:
    """Refuse coordinates beyond :data:`MAX_ABS_COORD_M` (a corrupt scale, offset or value)."""
    with np.errstate(invalid="ignore"):
        ok = np.abs(xyz) <= MAX_ABS_COORD_M
    if ok.all():
        return
    i, k = map(int, np.argwhere(~ok)[0])
    name = "ENH"[k]
    where = (location(path, int(lines[i]), name) if lines is not None
             else f"{path}: point {first + i} (counting from 0), {name}")
    raise LidarFormatError(f"{where}: coordinate {float(xyz[i, k])!r} is outside the sane range "
                           f"+-{MAX_ABS_COORD_M:g} m; the file (or its scale/offset) is corrupt")


def las_record_cloud(rec: Any, header: Any, crs: Any, first: int = 0, path: Path | None = None) -> PointCloud:
    xyz = np.empty((len(rec), 3))
    for k, dim in enumerate(("X", "Y", "Z")):
        xyz[:, k] = scale_coords(np.asarray(rec[dim]), float(header.scales[k]), float(header.offsets[k]))
    if path is not None:
        check_coords(path, xyz, first)
    names = set(rec.point_format.dimension_names)
    attrs = {name: np.array(rec[name]) for name in LAS_ATTRIBUTES if name in names}
    return PointCloud._owned(xyz, attrs, crs)


#: The header's free-text fields (LAS 1.0-1.4: 32 ASCII characters each, null-padded).
HEADER_TEXT_FIELDS = ("system_identifier", "generating_software")


def ascii_header_text(header: Any, path: Path | str) -> list[str]:
    """Make the header's text fields ASCII, so that laspy can write a copy of the file.

    The LAS specification makes them ASCII; files in the wild hold Latin-1 or UTF-8
    bytes (a company name with an accent, a byte flip).  laspy reads them as raw
    bytes and refuses to write them back (``UnicodeDecodeError``); every byte that
    is not printable ASCII becomes ``?``, with a warning naming the file and the
    field (the bytes escaped).  Returns the names of the fields changed.
    """
    changed = []
    for name in HEADER_TEXT_FIELDS:
        value = getattr(header, name, None)
        raw = value.encode("utf-8", "surrogateescape") if isinstance(value, str) else value
        if not isinstance(raw, (bytes, bytearray)):
            continue
        raw = bytes(raw).split(b"\0", 1)[0]
        if all(32 <= b < 127 for b in raw):
            if not isinstance(value, str):
                setattr(header, name, raw.decode("ascii"))
            continue
        clean = "".join(chr(b) if 32 <= b < 127 else "?" for b in raw)
        log.warning("%s: the header's %s %s is not ASCII (as LAS requires); written as %r", path,
                    name.replace("_", " "), repr(raw[:32]), clean)
        setattr(header, name, clean)
        changed.append(name)
    return changed
