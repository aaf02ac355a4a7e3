r"""COPC writer: a LAS/LAZ point cloud as a Cloud Optimized Point Cloud (COPC 1.0), streamed, by hand with lazrs.

laspy reads COPC (:class:`laspy.CopcReader`) but writes no octree, so this
module lays the file out itself (the layout :mod:`lidarcat.lidar.copc` reads):

====================  ==========================================================
LAS 1.4 header        375 bytes; point format 6, 7 or 8 with bit 7 set (LAZ)
VLR ``copc`` 1        COPC info, 160 bytes, the *first* VLR: centre, half-size,
                      spacing, root hierarchy page (offset, size), GPS time range
VLR ``laszip``        lazrs' LAZ VLR with variable-size chunks
VLR ``LASF_Spec`` 4   extra bytes descriptions (when the points carry extra dimensions)
VLR ``LASF_Projection`` 2112   OGC WKT of the CRS (global encoding bit 4)
point data            8-byte offset of the chunk table, then one LAZ chunk per
                      octree node, then the LAZ chunk table (lazrs)
EVLR ``copc`` 1000    the hierarchy: pages of 32-byte entries (key ``d x y z``,
                      offset, bytes, point count); the root page first
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
over go one level down.  A node whose points left (those not taken by the
nodes above it) number at most ``max_points`` (100,000) is a *leaf*: it takes
all of them and has no children.  Every point is written exactly once.  Each
depth is one ``np.unique`` over the voxel keys of the points left: no
per-point loop.

Bounded memory: buckets
-----------------------
The points are read twice in chunks (``chunk_points``) and never held whole.
The first pass takes the exact bounds, the GPS time range, the counts by
return and a histogram of the points over the :math:`2^7` cubes per axis of
depth 7.  The *spill depth* :math:`S` is the smallest depth whose fullest cube
(a *bucket*) holds at most ``bucket_points``.  The second pass appends every
point's raw record to the temporary file of its bucket, in file order.

Because :math:`G = 2^7` and :math:`S \le 7`, a voxel of any depth :math:`d`
(side :math:`2s/(G\,2^d)`) lies inside one bucket (side :math:`2s/2^S`), so the
voxel rule above can be run bucket by bucket on the bucket's own points, in
file order, with the same result as on all the points.  Only the leaf test of
the nodes above the buckets (:math:`d \le S`, which span several buckets)
needs the whole: a first sweep over the buckets sums the points each such
node has left; the second sweep places every point, writes the nodes of depth
:math:`\ge S` (inside the bucket) as LAZ chunks at once, and appends the points
of the upper nodes to one temporary file per node, written as chunks at the
end (an upper node holds at most one point per voxel, or at most
``max_points`` when a leaf).  Peak memory is about one bucket of records and
its working arrays, whatever the number of points (the file, not memory, grows).

Hierarchy pages
---------------
Nodes without points are listed (count 0, offset 0) when a node below them
holds points, so every node's parent is in the hierarchy.  The hierarchy is cut
into pages of at most ``page_entries`` entries: a page starts at its root node
and takes its descendants breadth first while the page still has room for the
node's children; a node that does not fit becomes an entry with point count
:math:`-1`, the offset and size of its own page (the COPC spec's page key),
and that page starts with the node's own entry.  The pages are written one
after the other in the hierarchy EVLR, the root page first.
"""

from __future__ import annotations

import datetime
import os
import shutil
import struct
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarFormatError, TileIOError

__all__ = ["write_copc", "hierarchy_pages", "GRID", "MAX_POINTS", "PAGE_ENTRIES", "BUCKET_POINTS",
           "CHUNK_POINTS", "MAX_DEPTH"]

#: voxels per node edge (a power of two: the buckets rely on it)
GRID = 128
#: largest number of points in a leaf node
MAX_POINTS = 100_000
#: largest number of entries in a hierarchy page (32 bytes each)
PAGE_ENTRIES = 4096
#: largest number of points of a bucket (held in memory at once)
BUCKET_POINTS = 1_000_000
#: points read per chunk of the input
CHUNK_POINTS = 500_000
#: deepest octree level (21-bit keys per axis: GRID * 2**MAX_DEPTH <= 2**21)
MAX_DEPTH = 14

_HEADER_SIZE = 375
_VLR_HEADER = 54
_EVLR_HEADER = 60
_HIST_DEPTH = 7
_ENTRY = struct.Struct("<4iQii")


def _vlr(user: str, record: int, data: bytes, description: str = "") -> bytes:
    return (struct.pack("<H16sHH32s", 0, user.encode(), record, len(data), description.encode()[:32]) + data)


def _pack(cells: np.ndarray) -> np.ndarray:
    """One int64 per row of (n, 3) non-negative cell indices below 2**21."""
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


def _unpack(keys: np.ndarray) -> np.ndarray:
    return np.column_stack([(keys >> 42) & 0x1FFFFF, (keys >> 21) & 0x1FFFFF, keys & 0x1FFFFF])


class _Source:
    """The input as chunks of raw point records in a COPC point format (6, 7 or 8)."""

    def __init__(self, las: Any, chunk_points: int) -> None:
        import laspy

        self.chunk_points = chunk_points
        self.path: Path | None = None
        self.las = None
        if isinstance(las, laspy.LasData):
            self.las = las
            header = las.header
        else:
            self.path = Path(las)
            try:
                with laspy.open(str(self.path)) as r:
                    header = r.header
            except OSError as ex:
                raise TileIOError(f"{las}: cannot read ({ex})") from ex
            except Exception as ex:  # laspy's own LaspyException on a corrupt header
                raise LidarFormatError(f"{las}: corrupt LAS/LAZ ({type(ex).__name__}: {ex})") from ex
        self.header = header
        fmt = header.point_format
        self.convert_to = None
        if fmt.id not in (6, 7, 8):
            target = 8 if "nir" in fmt.dimension_names else (7 if "red" in fmt.dimension_names else 6)
            empty = laspy.LasData(laspy.LasHeader(point_format=fmt, version=header.version))
            self.out_header = laspy.convert(empty, point_format_id=target, file_version="1.4").header
            self.convert_to = self.out_header.point_format
        else:
            self.out_header = header
        self.point_format = self.out_header.point_format
        self.dtype = self.point_format.dtype()
        self.scales = np.asarray(header.scales, dtype=np.float64)
        self.offsets = np.asarray(header.offsets, dtype=np.float64)

    def chunks(self) -> Iterator[np.ndarray]:
        """Structured arrays of raw records (the output format), in file order."""
        import laspy

        if self.las is not None:
            arr = self.las.points.array
            for a in range(0, len(arr), self.chunk_points):
                yield self._converted(self.las.points[a:a + self.chunk_points])
            return
        assert self.path is not None
        try:
            with laspy.open(str(self.path)) as r:
                for rec in r.chunk_iterator(self.chunk_points):
                    yield self._converted(rec)
        except OSError as ex:
            raise TileIOError(f"{self.path}: cannot read ({ex})") from ex
        except Exception as ex:  # laspy and lazrs raise their own kinds on corrupt data
            raise LidarFormatError(f"{self.path}: corrupt LAS/LAZ ({type(ex).__name__}: {ex})") from ex

    def _converted(self, rec: Any) -> np.ndarray:
        import laspy

        if self.convert_to is None:
            return np.asarray(rec.array)
        return laspy.PackedPointRecord.from_point_record(rec, self.convert_to).array

    def xyz(self, arr: np.ndarray) -> np.ndarray:
        """Real coordinates (n, 3) of raw records."""
        ints = np.column_stack([arr["X"], arr["Y"], arr["Z"]]).astype(np.float64)
        return ints * self.scales + self.offsets


class _Cube:
    """The octree's cube: origin ``lo`` (3,) and side ``2 * half``."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, scale: float) -> None:
        self.centre = (lo + hi) / 2.0
        self.half = max(float((hi - lo).max()) / 2.0, 1e-3) * (1.0 + 1e-9) + scale
        self.lo = self.centre - self.half

    def rel(self, xyz: np.ndarray) -> np.ndarray:
        """Position in the cube, 0..1 per axis (n, 3)."""
        r = (xyz - self.lo) / (2.0 * self.half)
        return np.clip(r, 0.0, np.nextafter(1.0, 0.0))


def _cells(rel: np.ndarray, level: int) -> np.ndarray:
    """Cell indices (n, 3) int64 at *level* (2**level cells per axis); exact for powers of two."""
    return np.floor(rel * float(2 ** level)).astype(np.int64)


def _place(rel: np.ndarray, grid_bits: int, max_points: int, upto: int,
           leaf_of: Callable[[int, np.ndarray], np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    """Depth (n,) of every point of one bucket (in file order) and the points left per depth.

    Runs the voxel rule of the module docstring from depth 0.  At depths up to
    *upto* the leaf test is *leaf_of(depth, node keys)* (the global one; None:
    no leaves there, for the counting sweep, which stops after *upto*); deeper,
    the bucket's own counts decide.  Returns the depths (-1 for points not
    placed when *leaf_of* is None) and ``left[d]`` = points of the bucket not
    taken above depth *d*, for d = 0 .. *upto*.
    """
    n = len(rel)
    depth = np.full(n, -1, dtype=np.int32)
    left = np.arange(n)
    counts = []
    d = 0
    while len(left):
        if d <= upto:
            counts.append(len(left))
        node = _pack(_cells(rel[left], d))
        if d <= upto:
            if leaf_of is None:
                if d == upto:
                    break
                leaf = np.zeros(len(left), dtype=bool)
            else:
                leaf = leaf_of(d, node)
        else:
            _, inv, cnt = np.unique(node, return_inverse=True, return_counts=True)
            leaf = cnt[inv] <= max_points
        if d >= MAX_DEPTH:
            leaf[:] = True
        depth[left[leaf]] = d
        left = left[~leaf]
        if not len(left):
            break
        vkey = _pack(_cells(rel[left], d + grid_bits))
        _, first = np.unique(vkey, return_index=True)
        depth[left[first]] = d
        left = np.delete(left, first)
        d += 1
    while len(counts) <= upto:
        counts.append(0)
    return depth, np.asarray(counts[:upto + 1])


def hierarchy_pages(entries: dict[tuple[int, int, int, int], tuple[int, int, int]],
                    page_entries: int = PAGE_ENTRIES) -> list[tuple[tuple[int, int, int, int], list[tuple]]]:
    """Cut the hierarchy into pages (see the module docstring, "Hierarchy pages").

    Parameters
    ----------
    entries : dict
        ``(d, x, y, z) -> (offset, bytes, points)`` of every node, the empty
        parents included (``(0, 0, 0)``); the root ``(0, 0, 0, 0)`` among them.
    page_entries : int
        Largest number of entries per page (at least 9: a node and its 8 children).

    Returns
    -------
    list of (key, list)
        The pages, root page first; each is its root key and its entries
        ``(key, offset, bytes, points)`` in breadth-first order, where a child
        page appears as ``(key, None, None, -1)`` (its place, filled in by the writer).
    """
    if page_entries < 9:
        raise ValueError(f"page_entries must be at least 9 (a node and its 8 children), got {page_entries}")
    children: dict[tuple[int, int, int, int], list[tuple[int, int, int, int]]] = {}
    for k in sorted(entries):
        if k[0]:
            children.setdefault((k[0] - 1, k[1] // 2, k[2] // 2, k[3] // 2), []).append(k)
    pages = []
    todo = [(0, 0, 0, 0)]
    while todo:
        root = todo.pop(0)
        page = [(root, *entries[root])]
        queue = list(children.get(root, []))
        while queue:
            k = queue.pop(0)
            kids = children.get(k, [])
            if len(page) + len(queue) + 1 + len(kids) <= page_entries:
                page.append((k, *entries[k]))
                queue.extend(kids)
            else:
                page.append((k, None, None, -1))
                todo.append(k)
        pages.append((root, page))
    return pages


def write_copc(las: Any, path: str | os.PathLike, *, crs: Any = None, max_points: int = MAX_POINTS,
               grid: int = GRID, page_entries: int = PAGE_ENTRIES, bucket_points: int = BUCKET_POINTS,
               chunk_points: int = CHUNK_POINTS, tmp_dir: str | os.PathLike | None = None) -> Path:
    """Write *las* (a :class:`laspy.LasData`, or a path of a LAS/LAZ file) as the COPC file *path*, atomically.

    A path is read in chunks and never whole (see the module docstring,
    "Bounded memory").

    Parameters
    ----------
    las : laspy.LasData or path-like
        The points with all their fields; point formats 0-5 are converted to
        6, 7 or 8 (LAS 1.4: COPC allows only those; 7 with RGB, 8 with NIR).
    path : path-like
        Output ``.copc.laz``.
    crs : CRS-like, optional
        CRS to write (WKT); default the file's own (laspy ``parse_crs``).
    max_points : int
        Largest number of points of a leaf node.
    grid : int
        Voxels per node edge, a power of two from 8 to 128.
    page_entries : int
        Largest number of entries of a hierarchy page (at least 9).
    bucket_points, chunk_points : int
        Largest bucket held in memory (unless the points crowd into one cube of
        depth 7) and points read per chunk of the input.
    tmp_dir : path-like, optional
        Where the buckets are spilled (default: beside *path*).

    Returns
    -------
    Path

    Raises
    ------
    LidarFormatError
        No points, or a corrupt input file.
    TileIOError
        *las* is a path that cannot be read.
    """
    from .._util import atomic_write
    from .crs import resolve_crs

    grid_bits = int(round(np.log2(grid))) if grid > 0 else -1
    if not (3 <= grid_bits <= _HIST_DEPTH and 2 ** grid_bits == grid):
        raise ValueError(f"grid must be a power of two from 8 to 128, got {grid!r}")
    if max_points < 1 or bucket_points < 1 or chunk_points < 1:
        raise ValueError("max_points, bucket_points and chunk_points must be positive")
    if page_entries < 9:
        raise ValueError(f"page_entries must be at least 9 (a node and its 8 children), got {page_entries}")
    path = Path(path)
    src = _Source(las, chunk_points)
    hdr = src.header

    # pass 1: bounds, counts, GPS range; the histogram at depth 7 (cube from the header's bounds)
    def first_pass(cube: _Cube | None) -> tuple[int, np.ndarray, np.ndarray, list[float], np.ndarray, np.ndarray]:
        n, lo, hi, gps, by_ret = 0, np.full(3, np.inf), np.full(3, -np.inf), [np.inf, -np.inf], np.zeros(16, np.int64)
        hist = np.zeros(8 ** _HIST_DEPTH, dtype=np.int64) if cube is not None else np.zeros(0, np.int64)
        for arr in src.chunks():
            if not len(arr):
                continue
            xyz = src.xyz(arr)
            n += len(arr)
            lo, hi = np.minimum(lo, xyz.min(axis=0)), np.maximum(hi, xyz.max(axis=0))
            g = arr["gps_time"]
            gps = [min(gps[0], float(g.min())), max(gps[1], float(g.max()))]
            rn = (arr["bit_fields"] & 0x0F).astype(np.int64)
            by_ret += np.bincount(rn, minlength=16)[:16]
            if cube is not None:
                c = _cells(cube.rel(xyz), _HIST_DEPTH)
                hist += np.bincount((c[:, 0] << 14) | (c[:, 1] << 7) | c[:, 2], minlength=len(hist))
        return n, lo, hi, gps, by_ret, hist

    scale = float(np.max(src.scales))
    if src.las is not None and len(src.las.points):   # in memory: the exact bounds cost nothing
        pts = src.las.points
        box = [np.array([float(np.min(pts[c])), float(np.max(pts[c]))]) for c in ("x", "y", "z")]
        cube = _Cube(np.array([b[0] for b in box]), np.array([b[1] for b in box]), scale)
    else:
        cube = _Cube(np.asarray(hdr.mins, dtype=np.float64), np.asarray(hdr.maxs, dtype=np.float64), scale)
    n, lo, hi, gps, by_ret, hist = first_pass(cube)
    if n == 0:
        raise LidarFormatError(f"{path}: no points to write as COPC")
    if np.any(lo < cube.lo) or np.any(hi > cube.lo + 2 * cube.half) or not np.all(np.isfinite(cube.lo)):
        cube = _Cube(lo, hi, scale)                   # the header's bounds were wrong: the exact ones
        n, lo, hi, gps, by_ret, hist = first_pass(cube)
    spill = _HIST_DEPTH
    h = hist.reshape((2 ** _HIST_DEPTH,) * 3)
    for s in range(0, _HIST_DEPTH + 1):
        f = 2 ** (_HIST_DEPTH - s)
        blocks = h.reshape(2 ** s, f, 2 ** s, f, 2 ** s, f).sum(axis=(1, 3, 5))
        if blocks.max() <= bucket_points:
            spill = s
            break
    if crs is None:
        try:
            crs = hdr.parse_crs()
        except Exception:  # laspy raises several kinds on odd GeoTIFF keys: then no CRS
            crs = None
    crs = resolve_crs(crs) if crs is not None else None
    path.parent.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".buckets",
                                 dir=str(tmp_dir) if tmp_dir is not None else str(path.parent)))
    try:
        return _write(src, path, work, cube, spill, n, lo, hi, gps, by_ret, crs, max_points, grid_bits,
                      page_entries, atomic_write)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _spill(src: _Source, cube: _Cube, spill: int, work: Path) -> list[int]:
    """Pass 2: every record appended to its bucket's file ``b<key>.bin`` in *work*, in file order; the keys."""
    for arr in src.chunks():
        b = _pack(_cells(cube.rel(src.xyz(arr)), spill))
        order = np.argsort(b, kind="stable")
        bs = b[order]
        cut = np.flatnonzero(bs[1:] != bs[:-1]) + 1
        for a, e in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(bs)]])):
            with open(work / f"b{int(bs[a])}.bin", "ab") as fh:
                fh.write(arr[order[a:e]].tobytes())
    return sorted(int(p.stem[1:]) for p in work.glob("b*.bin"))


def _upper_leaves(buckets: list[int], load: Callable[[int], tuple[np.ndarray, np.ndarray]], spill: int,
                  grid_bits: int, max_points: int) -> list[np.ndarray]:
    """Sweep 1: the keys of the leaf nodes of each depth 0 .. *spill* (from the points each has left)."""
    left: list[dict[int, int]] = [{} for _ in range(spill + 1)]
    for bk in buckets:
        _, rel = load(bk)
        _, cnt = _place(rel, grid_bits, max_points, spill, None)
        cell = _unpack(np.array([bk]))[0]
        for d in range(spill + 1):
            k = int(_pack((cell >> (spill - d))[None, :])[0])
            left[d][k] = left[d].get(k, 0) + int(cnt[d])
    leaves: list[set[int]] = [set() for _ in range(spill + 1)]
    for d in range(spill + 1):
        for k, c in left[d].items():
            cell = _unpack(np.array([k]))[0]
            parent_leaf = any(int(_pack((cell >> (d - u))[None, :])[0]) in leaves[u] for u in range(d))
            if not parent_leaf and (c <= max_points or d >= MAX_DEPTH):
                leaves[d].add(k)
    return [np.fromiter(s, dtype=np.int64, count=len(s)) for s in leaves]


def _hierarchy(entries: dict[tuple[int, int, int, int], tuple[int, int, int]], page_entries: int,
               data_start: int) -> tuple[bytes, tuple[int, int]]:
    """The hierarchy EVLR's payload starting at file offset *data_start*, and the root page's (offset, size).

    Adds the empty nodes above nodes with points to *entries* (in place) first.
    """
    for d, x, y, z in list(entries):
        while d > 0:
            d, x, y, z = d - 1, x // 2, y // 2, z // 2
            if (d, x, y, z) in entries:
                break
            entries[(d, x, y, z)] = (0, 0, 0)
    entries.setdefault((0, 0, 0, 0), (0, 0, 0))
    pages = hierarchy_pages(entries, page_entries)
    page_at: dict[tuple[int, int, int, int], tuple[int, int]] = {}
    at = data_start
    for root, page in pages:
        page_at[root] = (at, 32 * len(page))
        at += 32 * len(page)
    blob = b"".join(_ENTRY.pack(*k, *(page_at[k] if cnt == -1 else (off, size)), cnt)
                    for _, page in pages for k, off, size, cnt in page)
    return blob, page_at[(0, 0, 0, 0)]


def _write(src: _Source, path: Path, work: Path, cube: _Cube, spill: int, n: int, lo: np.ndarray,
           hi: np.ndarray, gps: list[float], by_ret: np.ndarray, crs: Any, max_points: int, grid_bits: int,
           page_entries: int, atomic_write: Any) -> Path:
    """Pass 2 (spill), the two sweeps over the buckets, the hierarchy and the header (see :func:`write_copc`)."""
    import lazrs

    dtype = src.dtype
    buckets = _spill(src, cube, spill, work)

    def load(key: int) -> tuple[np.ndarray, np.ndarray]:
        arr = np.fromfile(work / f"b{key}.bin", dtype=dtype)
        return arr, cube.rel(src.xyz(arr))

    leaf_arrays = _upper_leaves(buckets, load, spill, grid_bits, max_points)

    def leaf_of(d: int, node: np.ndarray) -> np.ndarray:
        return np.isin(node, leaf_arrays[d])

    fmt = src.point_format
    vlr = lazrs.LazVlr.new_for_compression(fmt.id, fmt.num_extra_bytes, use_variable_size_chunks=True)
    wkt = crs.to_wkt(version="WKT1_GDAL") if crs is not None else None
    eb = src.out_header.vlrs.get("ExtraBytesVlr")
    eb_data = eb[0].record_data_bytes() if eb else None
    vlrs_len = _VLR_HEADER + 160 + _VLR_HEADER + len(vlr.record_data())
    if eb_data is not None:
        vlrs_len += _VLR_HEADER + len(eb_data)
    if wkt is not None:
        vlrs_len += _VLR_HEADER + len(wkt.encode()) + 1
    point_start = _HEADER_SIZE + vlrs_len
    entries: dict[tuple[int, int, int, int], tuple[int, int, int]] = {}

    with atomic_write(path, "wb") as fh:
        fh.write(b"\0" * point_start)
        comp = lazrs.LasZipCompressor(fh, vlr)
        comp.reserve_offset_to_chunk_table()

        def chunk(key: tuple[int, int, int, int], records: np.ndarray) -> None:
            off = fh.tell()
            comp.compress_many(records.tobytes())
            comp.finish_current_chunk()
            entries[key] = (off, fh.tell() - off, len(records))

        # sweep 2: place every point; the nodes inside the bucket now, the upper ones to their files
        for bk in buckets:
            arr, rel = load(bk)
            depth, _ = _place(rel, grid_bits, max_points, spill, leaf_of)
            nodes = np.floor(rel * (2.0 ** depth)[:, None]).astype(np.int64)
            keys = np.column_stack([depth, nodes])
            order = np.lexsort((keys[:, 3], keys[:, 2], keys[:, 1], keys[:, 0]))
            ks = keys[order]
            cut = np.flatnonzero(np.any(ks[1:] != ks[:-1], axis=1)) + 1
            for a, e in zip(np.concatenate([[0], cut]), np.concatenate([cut, [len(ks)]])):
                key = tuple(int(v) for v in ks[a])
                recs = arr[order[a:e]]
                if key[0] >= spill:
                    chunk(key, recs)          # type: ignore[arg-type]
                else:
                    with open(work / ("u%d_%d_%d_%d.bin" % key), "ab") as uf:
                        uf.write(recs.tobytes())
            (work / f"b{bk}.bin").unlink()
        for p in sorted(work.glob("u*.bin"), key=lambda q: tuple(int(v) for v in q.stem[1:].split("_"))):
            key = tuple(int(v) for v in p.stem[1:].split("_"))
            chunk(key, np.fromfile(p, dtype=dtype))     # type: ignore[arg-type]
        comp.done()

        evlr_start = fh.tell()
        blob, root_page = _hierarchy(entries, page_entries, evlr_start + _EVLR_HEADER)
        fh.write(struct.pack("<H16sHQ32s", 0, b"copc", 1000, len(blob), b"EPT hierarchy"))
        fh.write(blob)

        # the VLRs, then the header, in front of the points
        fh.seek(_HEADER_SIZE)
        info = struct.pack("<5d2Q2d11Q", *cube.centre, cube.half, 2.0 * cube.half / 2 ** grid_bits,
                           *root_page, gps[0], gps[1], *([0] * 11))
        fh.write(_vlr("copc", 1, info, "COPC info"))
        fh.write(_vlr("laszip encoded", 22204, vlr.record_data(), "lazrs variable chunks"))
        if eb_data is not None:
            fh.write(_vlr("LASF_Spec", 4, eb_data, "extra bytes"))
        if wkt is not None:
            fh.write(_vlr("LASF_Projection", 2112, wkt.encode() + b"\0", "OGC WKT"))
        assert fh.tell() == point_start
        fh.seek(0)
        hdr = src.header
        today = datetime.date.today()
        n_vlrs = 2 + (eb_data is not None) + (wkt is not None)
        head = struct.pack(
            "<4sHH16sBB32s32sHHHIIBHI5I3d3d6dQQIQ15Q",
            b"LASF", int(hdr.file_source_id), 16 if wkt is not None else 0, hdr.uuid.bytes, 1, 4,
            b"lidarcat", b"lidarcat copc_write", today.timetuple().tm_yday, today.year, _HEADER_SIZE,
            point_start, n_vlrs, fmt.id | 0x80, fmt.size, 0, 0, 0, 0, 0, 0,
            *src.scales, *src.offsets, hi[0], lo[0], hi[1], lo[1], hi[2], lo[2], 0, evlr_start, 1, n,
            *[int(v) for v in by_ret[1:16]])
        assert len(head) == _HEADER_SIZE
        fh.write(head)
    return path
