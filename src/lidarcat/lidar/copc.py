r"""COPC (Cloud Optimized Point Cloud) tiles read by their octree: only the nodes a query box meets.

A COPC file (COPC 1.0) is a LAZ 1.4 file (point formats 6-8) whose points are
stored as an octree: every node of the cube of half-size :math:`s` about the
centre :math:`c` (the *COPC info* VLR, user ``copc``, record 1, 160 bytes,
the first VLR of the file) holds a subsample of the points inside it, in one
LAZ chunk of its own (variable-size chunks); the *hierarchy* (EVLR user
``copc`` record 1000, pages of 32-byte entries: key ``(d, x, y, z)``, chunk
offset, chunk size, point count; a count of -1 points to a child page) tells
where each node's chunk is.  Node :math:`(d, x, y, z)` covers

.. math:: c - s + \frac{2s}{2^d}\,(x, y, z) \;\le\; P \;<\; c - s + \frac{2s}{2^d}\,(x + 1, y + 1, z + 1),

so a plan box needs only the nodes whose cube meets it, at every depth --
a query decodes those chunks and nothing else.

:func:`read_copc_box` does that with laspy's own COPC reader
(:class:`laspy.CopcReader`, lazrs backend) and the same hardening as the
LAS/LAZ readers (:mod:`lidarcat.lidar.readers`):

* the fixed header is checked against the file size first
  (``_las.precheck_las``, through ``_las.open_checked``, which also
  settles the CRS);
* every byte laspy reads goes through a guard that refuses a read past the
  end of the file or a negative size, so a hierarchy entry pointing outside
  the file gives a located :class:`~lidarcat.errors.LidarFormatError` instead
  of a short read or a huge allocation;
* each selected node's entry is checked (chunk inside the point data, point
  count positive and at most what its bytes can hold, the sum at most the
  header's count) and so is the head of its chunk (the count the chunk stores
  after its first point equals the entry's; for point format 6 its 9 layer
  sizes fit in the chunk)
  before anything is decompressed;
* decoder failures, a lazrs ``PanicException`` included, become a
  :class:`~lidarcat.errors.LidarFormatError` naming the file;
* the header's bounds are never used: the query asks laspy for the box
  widened by one coordinate step, over the whole representable height range
  (laspy would otherwise take the heights from the header), and the exact
  box is applied to the decoded coordinates.

Points come back in file order (laspy reads the selected chunks by
ascending offset), so a box read equals a whole-file read filtered by the
box, point for point.  :class:`lidarcat.lidar.tileindex.TileIndex` uses this
for every query on a COPC tile not already in memory (clips, windows, the
tile-parallel products and ``extract --find``); whole-file reads go through
the LAS/LAZ path, COPC being valid LAZ.
"""

from __future__ import annotations

import contextlib
import io
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarFormatError
from ._las import (LAS_ATTRIBUTES, MAX_LAZ_POINTS_PER_BYTE, check_coords, decoder_error, las_record_cloud,
                   layered_items_only_point14, open_checked)
from .cloud import PointCloud

__all__ = ["is_copc", "read_copc_box", "read_hierarchy", "CopcRead", "COPC_INFO_BYTES"]

#: size of the COPC info VLR payload
COPC_INFO_BYTES = 160
_VLR_HEADER = 54


def is_copc(path: str | os.PathLike) -> bool:
    """True when *path* is a LAS 1.4 file whose first VLR is the COPC info record (user "copc", id 1).

    Reads the header and the first VLR header (429 bytes for a plain LAS 1.4
    header); a file that cannot be read, or is no LAS file, is not COPC (the
    LAS/LAZ reader reports what is wrong with it).
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(512)
            if len(head) >= 96 and head[:4] == b"LASF":
                need = struct.unpack_from("<H", head, 94)[0] + _VLR_HEADER
                if need > len(head):
                    head += fh.read(need - len(head))
    except OSError:
        return False
    if len(head) < 227 or head[:4] != b"LASF" or (head[24], head[25]) != (1, 4):
        return False
    header_size = struct.unpack_from("<H", head, 94)[0]
    if len(head) < header_size + _VLR_HEADER:
        return False
    user = head[header_size + 2:header_size + 18].rstrip(b"\0")
    record = struct.unpack_from("<H", head, header_size + 18)[0]
    return user == b"copc" and record == 1


@dataclass(frozen=True, eq=False)
class CopcRead:
    """The points of a COPC box query and what it took.

    Attributes
    ----------
    cloud : PointCloud
        Points with ``xmin <= E <= xmax`` and ``ymin <= N <= ymax``, in file order.
    nodes_read : int
        Octree nodes whose chunk was decompressed (their cube meets the box).
    nodes_known : int
        Nodes the hierarchy pages read so far list (an upper bound of those with data).
    points_decoded : int
        Points decompressed (the sum of the point counts of the nodes read).
    bytes_read : int
        Bytes read from the file for this query (header, VLRs, hierarchy, chunks).
    """

    cloud: PointCloud
    nodes_read: int
    nodes_known: int
    points_decoded: int
    bytes_read: int


class _Guarded(io.RawIOBase):
    """A read-only file that refuses reads beyond its end (a corrupt offset or size) and counts bytes."""

    def __init__(self, fh: Any, size: int, path: Path) -> None:
        super().__init__()
        self._fh, self._size, self._path = fh, size, path
        self.bytes_read = 0

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, pos: int, whence: int = io.SEEK_SET) -> int:
        return self._fh.seek(pos, whence)

    def tell(self) -> int:
        return self._fh.tell()

    def _check(self, n: int) -> None:
        pos = self._fh.tell()
        if n < 0 or pos + n > self._size:
            raise LidarFormatError(f"{self._path}: corrupt COPC hierarchy: a read of {n:,} bytes at byte "
                                   f"{pos:,} lies outside the file ({self._size:,} bytes)")

    def read(self, n: int = -1) -> bytes:
        self._check(n)
        data = self._fh.read(n)
        self.bytes_read += len(data)
        return data

    def readinto(self, b: Any) -> int:
        self._check(len(b))
        k = self._fh.readinto(b)
        self.bytes_read += k
        return k


@contextlib.contextmanager
def _located(path: Path, what: str) -> Iterator[None]:
    """Turn any failure inside laspy/lazrs (a Rust panic included) into a LidarFormatError naming *path*."""

    try:
        yield
    except LidarFormatError:
        raise
    except BaseException as ex:  # LaspyException, struct.error, ValueError, lazrs errors and panics
        raise decoder_error(path, ex, what) from ex   # re-raises KeyboardInterrupt & co. unchanged


def _node_name(key: Any) -> str:
    return f"{key.level}-{key.x}-{key.y}-{key.z}"


def _check_entries(path: Path, entries: Any) -> None:
    """No hierarchy entry read so far has a point count below -1 (laspy would skip its subtree)."""
    for e in entries:
        if e.point_count < -1:
            raise LidarFormatError(f"{path}: corrupt COPC hierarchy: node {_node_name(e.key)} has "
                                   f"{e.point_count:,} points in a chunk of {e.byte_size:,} bytes")


def _check_chunk_heads(path: Path, stream: Any, nodes: list[Any], rec_len: int, point14_only: bool) -> None:
    """Each selected chunk starts as its entry says: a LAS 1.4 (layered) LAZ chunk opens with its
    first point raw, then its point count (4 bytes) and, for point format 6 alone, 9 layer sizes
    that must fit in the chunk (LASzip's LASreadPoint::read).  A hierarchy entry pointing into
    another chunk is caught here, before lazrs decodes garbage (which can take seconds, or
    allocate from a garbage layer size)."""
    for nd in nodes:
        n, off, nb = int(nd.point_count), int(nd.offset), int(nd.byte_size)
        if n <= 0:
            continue
        head = 4 + rec_len + (36 if point14_only else 0)
        where = f"{path}: corrupt COPC hierarchy: node {_node_name(nd.key)} (chunk at byte {off:,})"
        if nb < head:
            raise LidarFormatError(f"{where}: {nb:,} bytes cannot hold a chunk of {n:,} points")
        stream.seek(off)
        raw = stream.read(head)
        own = struct.unpack_from("<I", raw, rec_len)[0]
        if own != n:
            raise LidarFormatError(f"{where}: the chunk holds {own:,} points, the hierarchy says {n:,}")
        if point14_only:
            layers = sum(struct.unpack_from("<9I", raw, 4 + rec_len))
            if layers > nb - head:
                raise LidarFormatError(f"{where}: its layers take {layers:,} bytes, the chunk has {nb - head:,}")


def _check_nodes(path: Path, nodes: list[Any], header: Any, size: int) -> None:
    """Every selected node's chunk lies in the point data and holds a believable number of points."""

    start = int(header.offset_to_point_data)
    end = int(header.start_of_first_evlr) if int(getattr(header, "number_of_evlrs", 0) or 0) else size
    end = min(max(end, start), size)
    total = 0
    for nd in nodes:
        n, off, nb = int(nd.point_count), int(nd.offset), int(nd.byte_size)
        if n == 0:
            continue
        where = f"{path}: corrupt COPC hierarchy: node {_node_name(nd.key)}"
        if n < 0 or nb <= 0:
            raise LidarFormatError(f"{where} has {n:,} points in a chunk of {nb:,} bytes")
        if off < start or off + nb > end:
            raise LidarFormatError(f"{where}: its chunk (byte {off:,}, {nb:,} bytes) lies outside the point "
                                   f"data (bytes {start:,}..{end:,})")
        if n > MAX_LAZ_POINTS_PER_BYTE * nb:
            raise LidarFormatError(f"{where} claims {n:,} points in {nb:,} compressed bytes")
        total += n
    if total > int(header.point_count):
        raise LidarFormatError(f"{path}: corrupt COPC hierarchy: the nodes of one query hold {total:,} points, "
                               f"more than the {int(header.point_count):,} of the header")


def read_hierarchy(path: str | os.PathLike) -> tuple[dict[tuple[int, int, int, int], tuple[int, int, int]], int]:
    """Every node of a COPC file's hierarchy and the number of hierarchy pages, by following the pages.

    The ``copc info`` VLR (at byte 375 + 54 of a COPC file) gives the root page's offset and size; a page
    is 32-byte entries (key ``d x y z`` as int32, offset uint64, byte size int32, point count int32);
    a count of -1 points to a child page.  Returns ``{(d, x, y, z): (offset, bytes, point_count)}`` and
    the page count.  An entry listed twice or a page outside the file is a :class:`LidarFormatError`.
    """
    path = Path(path)
    raw = path.read_bytes()
    info = struct.unpack_from("<5d2Q2d", raw, 375 + 54)
    todo = [(int(info[5]), int(info[6]))]
    entries: dict[tuple[int, int, int, int], tuple[int, int, int]] = {}
    pages = 0
    while todo:
        off, size = todo.pop()
        if off + size > len(raw):
            raise LidarFormatError(f"{path}: a hierarchy page at byte {off} ({size} bytes) is past the end "
                                   f"of the file ({len(raw)} bytes)")
        pages += 1
        for i in range(size // 32):
            e = struct.unpack_from("<4iQii", raw, off + 32 * i)
            if e[6] == -1:
                todo.append((e[4], e[5]))
            elif e[:4] in entries:
                raise LidarFormatError(f"{path}: hierarchy node {e[:4]} is listed twice")
            else:
                entries[e[:4]] = e[4:]
    return entries, pages


def read_copc_box(path: str | os.PathLike, box: tuple[float, float, float, float], *,
                  crs: Any = None) -> CopcRead:
    """The points of a COPC file inside the plan box, decoding only the octree nodes that meet it.

    Parameters
    ----------
    path : path-like
        A COPC file (:func:`is_copc`).
    box : (xmin, ymin, xmax, ymax)
        Plan box in the file's coordinates, metres; edges included.
    crs : CRS-like, optional
        CRS of the points when the file carries none.

    Returns
    -------
    CopcRead

    Raises
    ------
    TileIOError
        The file is missing or unreadable.
    LidarFormatError
        Not a COPC file; a corrupt header, hierarchy or chunk (file and node named).
    CRSError
        As :func:`lidarcat.lidar.readers.read_points`.
    """
    import laspy
    from laspy.copc import Bounds, load_octree_for_query


    path = Path(path)
    xmin, ymin, xmax, ymax = map(float, box)
    reader, file_crs, _ = open_checked(path, crs)    # header prechecks, CRS record
    with reader:
        header = reader.header
        scales, offsets = np.asarray(header.scales, float), np.asarray(header.offsets, float)
    size = path.stat().st_size
    with open(path, "rb") as raw:
        stream = _Guarded(raw, size, path)
        with _located(path, "not a valid COPC file (COPC info or hierarchy unreadable)"):
            copc = laspy.CopcReader(stream, close_fd=False)
        info = copc.copc_info
        if not (np.isfinite(info.center).all() and np.isfinite(info.halfsize) and info.halfsize > 0):
            raise LidarFormatError(f"{path}: corrupt COPC info VLR: centre {info.center.tolist()}, half-size "
                                   f"{info.halfsize!r}")
        # the widest box laspy can represent in int32 coordinates, and the query box one step wider
        lo_rep = offsets + scales * (-(2 ** 31) + 2)
        hi_rep = offsets + scales * (2 ** 31 - 2)
        lo = np.maximum([xmin - abs(scales[0]), ymin - abs(scales[1]), lo_rep[2]], lo_rep)
        hi = np.minimum([xmax + abs(scales[0]), ymax + abs(scales[1]), hi_rep[2]], hi_rep)
        query = Bounds(lo, hi)
        with _located(path, "corrupt COPC hierarchy or point chunk"):
            nodes = load_octree_for_query(stream, info, copc.root_page, query_bounds=query)
            _check_entries(path, copc.root_page.entries.values())
            _check_nodes(path, nodes, copc.header, size)
            _check_chunk_heads(path, stream, nodes, int(copc.header.point_format.size),
                               layered_items_only_point14(copc.laszip_vlr.record_data))
            rec = copc.query(bounds=query) if nodes else None
        known = len(copc.root_page.entries)
        bytes_read = stream.bytes_read
    if rec is None or len(rec) == 0:
        cloud = PointCloud.empty(_attributes(header), file_crs)
    else:
        cloud = las_record_cloud(rec, header, file_crs, 0, path)
        check_coords(path, cloud.xyz, 0)
        x, y = cloud.xyz[:, 0], cloud.xyz[:, 1]
        keep = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        if not keep.all():
            cloud = cloud.select(keep)
    return CopcRead(cloud, sum(1 for nd in nodes if nd.point_count > 0), known,
                    int(sum(int(nd.point_count) for nd in nodes)), int(bytes_read))


def _attributes(header: Any) -> tuple[str, ...]:

    names = set(header.point_format.dimension_names)
    return tuple(a for a in LAS_ATTRIBUTES if a in names)
