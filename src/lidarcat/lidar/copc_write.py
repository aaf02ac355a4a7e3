r"""COPC writer: a LAS/LAZ point cloud as a Cloud Optimized Point Cloud (COPC 1.0), by hand with lazrs.

laspy reads COPC (:class:`laspy.CopcReader`) but writes no octree, so this
module lays the file out itself (the layout :mod:`lidarcat.lidar.copc` reads):

====================  ==========================================================
LAS 1.4 header        375 bytes; point format 6, 7 or 8 with bit 7 set (LAZ)
VLR ``copc`` 1        COPC info, 160 bytes, the *first* VLR: centre, half-size,
                      spacing, root hierarchy page (offset, size), GPS time range
VLR ``laszip``        lazrs' LAZ VLR with variable-size chunks
VLR ``LASF_Projection`` 2112   OGC WKT of the CRS (global encoding bit 4)
point data            8-byte offset of the chunk table, then one LAZ chunk per
                      octree node, then the LAZ chunk table (lazrs)
EVLR ``copc`` 1000    the hierarchy: one page of 32-byte entries (key ``d x y z``,
                      chunk offset, chunk bytes, point count)
====================  ==========================================================

The octree
----------
The cube has its centre :math:`c` at the middle of the points' bounds and the
half-size :math:`s` of their largest side.  Node :math:`(d, x, y, z)` covers
the cube of side :math:`2s/2^d` at index :math:`(x, y, z)` (the formula of
:mod:`lidarcat.lidar.copc`).  Every node is divided into :math:`G^3` voxels
(:math:`G` = ``GRID``, 128, as PDAL's and untwine's writers): from depth 0
down, each voxel of a node keeps the first point not yet placed (in file
order), so a node holds a subsample of its cube at spacing :math:`2s/(G\,2^d)`
(the COPC info's ``spacing`` is the root's :math:`2s/G`), and the points left
over go one level down.  The deepest level :math:`D` is the first at which
no node would hold more than ``max_points`` (100,000) of the points left: all
of them go there.  Every point is written exactly once.  Each depth is one
``np.unique`` over the voxel keys of the points left: no per-point loop.

Nodes without points are listed in the hierarchy (count 0, offset 0) when a
node below them holds points, so every node's parent is in the hierarchy.
Points are written by node (depth, then key), in file order within a node.
"""

from __future__ import annotations

import datetime
import os
import struct
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarFormatError, TileIOError

__all__ = ["write_copc", "GRID", "MAX_POINTS"]

#: voxels per node edge
GRID = 128
#: largest number of points in a node at the deepest level
MAX_POINTS = 100_000

_HEADER_SIZE = 375
_VLR_HEADER = 54
_EVLR_HEADER = 60


def _octree_depths(xyz: np.ndarray, centre: np.ndarray, half: float, grid: int,
                   max_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Depth (N,) and node key (N, 3) of every point (see the module docstring)."""
    n = len(xyz)
    depth = np.full(n, -1, dtype=np.int32)
    rel = (xyz - (centre - half)) / (2.0 * half)          # 0..1 within the cube
    rel = np.clip(rel, 0.0, np.nextafter(1.0, 0.0))
    left = np.arange(n)
    d = 0
    while len(left):
        cells = np.floor(rel[left] * (2 ** d)).astype(np.int64)
        key = (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]
        _, counts = np.unique(key, return_counts=True)
        if counts.max() <= max_points or d >= 20:
            depth[left] = d
            break
        vox = np.floor(rel[left] * (grid * 2 ** d)).astype(np.int64)
        vkey = (vox[:, 0] << 42) | (vox[:, 1] << 21) | vox[:, 2]
        _, first = np.unique(vkey, return_index=True)
        depth[left[first]] = d
        left = np.delete(left, first)
        d += 1
    nodes = np.floor(rel * (2.0 ** depth)[:, None]).astype(np.int64)
    return depth, nodes


def _vlr(user: str, record: int, data: bytes, description: str = "") -> bytes:
    return (struct.pack("<H16sHH32s", 0, user.encode(), record, len(data), description.encode()[:32]) + data)


def write_copc(las: Any, path: str | os.PathLike, *, crs: Any = None, max_points: int = MAX_POINTS,
               grid: int = GRID) -> Path:
    """Write *las* (a :class:`laspy.LasData`, or a path of a LAS/LAZ file) as the COPC file *path*, atomically.

    Parameters
    ----------
    las : laspy.LasData or path-like
        The points with all their fields; point formats 0-5 are converted to
        6, 7 or 8 (LAS 1.4: COPC allows only those; 7 with RGB, 8 with NIR).
    path : path-like
        Output ``.copc.laz``.
    crs : CRS-like, optional
        CRS to write (WKT); default the file's own (laspy ``parse_crs``).
    max_points, grid
        See the module docstring.

    Returns
    -------
    Path

    Raises
    ------
    LidarFormatError
        No points.
    TileIOError
        *las* is a path that cannot be read.
    """
    import laspy
    import lazrs

    from .._util import atomic_write
    from .crs import resolve_crs

    if not isinstance(las, laspy.LasData):
        try:
            las = laspy.read(str(las))
        except OSError as ex:
            raise TileIOError(f"{las}: cannot read ({ex})") from ex
    path = Path(path)
    n = len(las.points)
    if n == 0:
        raise LidarFormatError(f"{path}: no points to write as COPC")
    fmt = las.header.point_format
    if fmt.id not in (6, 7, 8):
        target = 8 if "nir" in fmt.dimension_names else (7 if "red" in fmt.dimension_names else 6)
        las = laspy.convert(las, point_format_id=target, file_version="1.4")
        fmt = las.header.point_format
    if crs is None:
        try:
            crs = las.header.parse_crs()
        except Exception:  # laspy raises several kinds on odd GeoTIFF keys: then no CRS
            crs = None
    crs = resolve_crs(crs) if crs is not None else None
    hdr = las.header
    xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    centre = (lo + hi) / 2.0
    half = max(float((hi - lo).max()) / 2.0, 1e-3) * (1.0 + 1e-9) + float(np.max(hdr.scales))
    depth, nodes = _octree_depths(xyz, centre, half, grid, max_points)
    order = np.lexsort((nodes[:, 2], nodes[:, 1], nodes[:, 0], depth))
    raw = las.points.array[order]
    keys = np.column_stack([depth[order], nodes[order]]).astype(np.int64)
    brk = np.flatnonzero(np.any(keys[1:] != keys[:-1], axis=1)) + 1
    starts = np.concatenate([[0], brk])
    ends = np.concatenate([brk, [n]])

    extra = fmt.num_extra_bytes
    vlr = lazrs.LazVlr.new_for_compression(fmt.id, extra, use_variable_size_chunks=True)
    wkt = crs.to_wkt(version="WKT1_GDAL") if crs is not None else None
    vlrs_len = _VLR_HEADER + 160 + _VLR_HEADER + len(vlr.record_data())
    if wkt is not None:
        vlrs_len += _VLR_HEADER + len(wkt.encode()) + 1
    point_start = _HEADER_SIZE + vlrs_len
    gps = np.asarray(las.gps_time)[order]
    rn = np.asarray(las.return_number)
    by_return = [int(np.sum(rn == r)) for r in range(1, 16)]

    with atomic_write(path, "wb") as fh:
        fh.write(b"\0" * point_start)
        comp = lazrs.LasZipCompressor(fh, vlr)
        comp.reserve_offset_to_chunk_table()
        entries = []
        for a, b in zip(starts, ends):
            off = fh.tell()
            comp.compress_many(raw[a:b].tobytes())
            comp.finish_current_chunk()
            entries.append((keys[a], off, fh.tell() - off, int(b - a)))
        comp.done()
        # nodes without points above nodes with points
        have = {tuple(int(v) for v in k) for k, _, _, _ in entries}
        empty = set()
        for d, x, y, z in list(have):
            while d > 0:
                d, x, y, z = d - 1, x // 2, y // 2, z // 2
                if (d, x, y, z) not in have:
                    empty.add((d, x, y, z))
        page = b"".join(struct.pack("<4iQii", *map(int, k), off, size, cnt) for k, off, size, cnt in entries)
        page += b"".join(struct.pack("<4iQii", *k, 0, 0, 0) for k in sorted(empty))
        evlr_start = fh.tell()
        fh.write(struct.pack("<H16sHQ32s", 0, b"copc", 1000, len(page), b"EPT hierarchy"))
        fh.write(page)
        # the VLRs, then the header, in front of the points
        fh.seek(_HEADER_SIZE)
        info = struct.pack("<5d2Q2d11Q", *centre, half, 2.0 * half / grid, evlr_start + _EVLR_HEADER, len(page),
                           float(gps.min()), float(gps.max()), *([0] * 11))
        fh.write(_vlr("copc", 1, info, "COPC info"))
        fh.write(_vlr("laszip encoded", 22204, vlr.record_data(), "lazrs variable chunks"))
        if wkt is not None:
            fh.write(_vlr("LASF_Projection", 2112, wkt.encode() + b"\0", "OGC WKT"))
        assert fh.tell() == point_start
        fh.seek(0)
        today = datetime.date.today()
        head = struct.pack(
            "<4sHH16sBB32s32sHHHIIBHI5I3d3d6dQQIQ15Q",
            b"LASF", int(hdr.file_source_id), 16 if wkt is not None else 0, hdr.uuid.bytes, 1, 4,
            b"lidarcat", b"lidarcat copc_write", today.timetuple().tm_yday, today.year, _HEADER_SIZE,
            point_start, 3 if wkt is not None else 2, fmt.id | 0x80, fmt.size, 0, 0, 0, 0, 0, 0,
            *hdr.scales, *hdr.offsets, hi[0], lo[0], hi[1], lo[1], hi[2], lo[2], 0, evlr_start, 1, n,
            *by_return)
        assert len(head) == _HEADER_SIZE
        fh.write(head)
    return path
