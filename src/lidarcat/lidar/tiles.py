"""One indexed tile (:class:`Tile`) and its block index (:class:`BlockIndex`).

A :class:`Tile` records a file's bounds, point count, size, modification time and CRS.
**Header bounds are never trusted for selection.**  Writers get them wrong
(laspy's ``simple1_3.las`` claims bounds that miss its points), so the bounds
of a LAS/LAZ tile count as *unverified* until its points have been read once
(any whole read, the block index, or :meth:`TileIndex.verify_bounds`); a
query reads every unverified tile, and from then on uses the measured bounds,
which the JSON cache keeps.

**Block index (LAS/LAZ).**  A LAZ file is compressed in chunks (usually 50 000
points) that can be decoded on their own.  A :class:`BlockIndex` cuts the points
of a tile, in file order, into blocks (the LAZ chunk, or ``block_points`` points
for LAS and variable-chunk LAZ) and cells (``cell_points``, default 5 000, a
divisor of the block) and records the plan box of every cell.  With it, a query
on a tile that is not in memory seeks to each block holding a cell whose box
meets the query box and decodes it from its start to the end of the last such
cell (touching ranges read in one go); it returns exactly the points,
attributes and order a whole-tile decode returns.  Airborne scans store points
in acquisition order, so a block covers a short piece of a strip and a roof clip
decodes part of one or two blocks; in a file whose points are shuffled every
cell spans the tile and the whole tile is decoded as before.

:class:`BlockBoxes` computes the block index in the one full pass, point chunk by point
chunk; :func:`verified_by_blocks` and :func:`with_bounds` replace the header bounds of a
tile by the measured ones.  How queries use the blocks: :mod:`lidarcat.lidar.tileindex`.

:func:`expand_paths` turns paths, folders and globs into the list of tile files, in the
order given (each glob and folder sorted).
"""

from __future__ import annotations

import base64
import glob as _glob
import logging
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import TileIOError
from .cloud import Bounds
from .readers import ASCII_SUFFIXES, LAS_SUFFIXES, file_kind, is_foreign_table

__all__ = ["Tile", "BlockIndex", "BlockBoxes", "DEFAULT_BLOCK_POINTS", "DEFAULT_CELL_POINTS",
           "cell_points_for", "verified_by_blocks", "with_bounds", "expand_paths"]

log = logging.getLogger("lidarcat.lidar.tileindex")   # the index's messages, under the index's logger

#: points per block for LAS files and LAZ files with variable-size chunks
DEFAULT_BLOCK_POINTS = 50_000
#: points per cell (the unit of the recorded boxes; a divisor of the block size)
DEFAULT_CELL_POINTS = 5_000
_GLOB_CHARS = set("*?[")


@dataclass(frozen=True)
class Tile:
    """One indexed file.

    Attributes
    ----------
    path : Path
    size : int
        File size, bytes.
    mtime_ns : int
        Modification time, ns.
    count : int
        Points in the file.
    bounds : Bounds
        Bounds in metres.
    file_crs_wkt : str or None
        The CRS stored in the file (WKT), ``None`` when it has none.
    description : str
        Format description, e.g. ``"LAZ 1.2, point format 1"``.
    attributes : tuple of str
        Attribute names.
    bounds_verified : bool
        True when *bounds* were measured on the points (text files, or a LAS/LAZ
        tile read once); False while they are the LAS header's claim, which is
        never used to leave a tile out of a query.
    """

    path: Path
    size: int
    mtime_ns: int
    count: int
    bounds: Bounds
    file_crs_wkt: str | None
    description: str
    attributes: tuple[str, ...]
    bounds_verified: bool = False

    def may_meet(self, xmin: float, ymin: float, xmax: float, ymax: float) -> bool:
        """False only when the tile's points certainly miss the plan box (edges included)."""
        if self.count <= 0:
            return False
        return not self.bounds_verified or self.bounds.intersects_box(xmin, ymin, xmax, ymax)

    def to_dict(self, relative_to: Path | None = None) -> dict[str, Any]:
        path = str(self.path)
        if relative_to is not None and self.path.is_relative_to(relative_to):
            path = self.path.relative_to(relative_to).as_posix()
        return {"path": path, "size": self.size, "mtime_ns": self.mtime_ns, "count": self.count,
                "bounds": list(self.bounds), "file_crs_wkt": self.file_crs_wkt,
                "description": self.description, "attributes": list(self.attributes),
                "bounds_verified": self.bounds_verified}

    @classmethod
    def from_dict(cls, d: dict[str, Any], base: Path) -> Tile:
        path = Path(d["path"])
        if not path.is_absolute():
            path = (base / path).resolve()
        return cls(path, int(d["size"]), int(d["mtime_ns"]), int(d["count"]),
                   Bounds(*(math.nan if v is None else float(v) for v in d["bounds"])), d.get("file_crs_wkt"), str(d["description"]),
                   tuple(d.get("attributes", ())), bool(d.get("bounds_verified", False)))


@dataclass(frozen=True, eq=False)
class BlockIndex:
    """Plan boxes of the consecutive points of one LAS/LAZ tile, for partial decoding.

    The points are cut, in file order, into *blocks* of ``block_points`` (the
    unit a LAZ decoder starts from: its compressed chunk) and each block into
    *cells* of ``cell_points``; ``boxes`` holds the exact minimum and maximum
    of the coordinates of each cell as read.  A query decodes, in every block
    holding a cell its box meets, the points from the block start to the end of
    the last such cell.

    Attributes
    ----------
    block_points : int
        Points per block (the last block may hold fewer).
    count : int
        Points in the tile.
    boxes : ndarray, shape (C, 4)
        ``xmin, ymin, xmax, ymax`` of each cell, metres; ``C = ceil(count / cell_points)``.
    cell_points : int
        Points per cell, a divisor of *block_points* (default: *block_points*).

    Examples
    --------
    >>> bi = BlockIndex(2, 5, np.array([[0, 0, 1, 1], [5, 0, 6, 1], [0.5, 0, 2, 1.0]]))
    >>> bi.needs(bi.cells_in_box(0.9, 0.5, 1.5, 0.6))   # blocks 0 and 2, read to their ends
    ([0, 2], [2, 5])
    >>> bi.ranges([0, 2], [2, 5]), bi.ranges([0, 1], [2, 4])
    ([(0, 2), (4, 5)], [(0, 4)])
    >>> cells = BlockIndex(4, 7, np.array([[0, 0, 1, 1], [5, 0, 6, 1], [0, 0, 1, 1], [9, 9, 9, 9]]), 2)
    >>> cells.needs(cells.cells_in_box(0, 0, 1, 1))     # blocks 0 and 1, each read up to point 2 / 6
    ([0, 1], [2, 6])
    """

    block_points: int
    count: int
    boxes: np.ndarray
    cell_points: int = 0

    def __post_init__(self) -> None:
        bp, count = int(self.block_points), int(self.count)
        cp = int(self.cell_points) or bp
        boxes = np.array(self.boxes, dtype=np.float64, copy=True).reshape(-1, 4)
        if bp <= 0 or cp <= 0 or count < 0 or bp % cp:
            raise ValueError(f"block_points ({bp}) must be a positive multiple of cell_points ({cp}) "
                             f"and count ({count}) >= 0")
        if len(boxes) != -(-count // cp):
            raise ValueError(f"{len(boxes)} boxes for {count} points in cells of {cp}")
        boxes.setflags(write=False)
        object.__setattr__(self, "block_points", bp)
        object.__setattr__(self, "cell_points", cp)
        object.__setattr__(self, "count", count)
        object.__setattr__(self, "boxes", boxes)

    def __len__(self) -> int:
        """Number of blocks."""
        return -(-self.count // self.block_points)

    def cells_in_box(self, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        """Ascending indices of the cells whose box meets the plan box (edges included)."""
        b = self.boxes
        return np.flatnonzero((b[:, 0] <= xmax) & (b[:, 2] >= xmin) & (b[:, 1] <= ymax) & (b[:, 3] >= ymin))

    def needs(self, cells: np.ndarray) -> tuple[list[int], list[int]]:
        """Blocks holding the ascending *cells*, and per block the point index where reading
        may stop (the end of its last cell among *cells*)."""
        c = np.asarray(cells, dtype=np.int64)
        if len(c) == 0:
            return [], []
        blk = c // (self.block_points // self.cell_points)
        ends = np.minimum((c + 1) * self.cell_points, self.count)
        last = np.flatnonzero(np.r_[blk[1:] != blk[:-1], True])  # cells ascend: last one per block
        return blk[last].tolist(), ends[last].tolist()

    def ranges(self, blocks: Iterable[int], stops: Iterable[int]) -> list[tuple[int, int]]:
        """Point ranges ``[start, stop)`` of ascending *blocks*, each read from its start to
        its entry of *stops* (see :meth:`needs`); ranges that touch are merged."""
        out: list[tuple[int, int]] = []
        for k, e in zip(map(int, blocks), map(int, stops)):
            a = k * self.block_points
            if out and out[-1][1] == a:
                out[-1] = (out[-1][0], e)
            else:
                out.append((a, e))
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON form: the boxes as base64 of little-endian float64 (exact round trip)."""
        return {"block_points": self.block_points, "cell_points": self.cell_points, "count": self.count,
                "boxes_f8le": base64.b64encode(self.boxes.astype("<f8").tobytes()).decode("ascii")}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BlockIndex:
        raw = base64.b64decode(d["boxes_f8le"], validate=True)
        return cls(int(d["block_points"]), int(d["count"]), np.frombuffer(raw, dtype="<f8").reshape(-1, 4),
                   int(d.get("cell_points", 0)))


def verified_by_blocks(tile: Tile, blocks: BlockIndex | None) -> Tile:
    """*tile* with plan bounds measured by its block index (the exact boxes of its points)."""
    if tile.bounds_verified or blocks is None or blocks.count == 0:
        return tile
    b = blocks.boxes
    return with_bounds(tile, (float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()),
                               float(b[:, 3].max()), tile.bounds.zmin, tile.bounds.zmax))


def with_bounds(tile: Tile, measured: Sequence[float]) -> Tile:
    """*tile* with bounds measured on its points (a warning when the header's claim missed them)."""
    old, new = tile.bounds, Bounds(*map(float, measured))
    tol = 1e-3  # m: headers round their bounds
    if not (old.xmin - tol <= new.xmin and old.ymin - tol <= new.ymin and old.xmax + tol >= new.xmax
            and old.ymax + tol >= new.ymax):
        log.warning("%s: the header's bounds E %.3f..%.3f N %.3f..%.3f do not hold the points "
                    "(E %.3f..%.3f N %.3f..%.3f); the points' bounds are used", tile.path, old.xmin,
                    old.xmax, old.ymin, old.ymax, new.xmin, new.xmax, new.ymin, new.ymax)
    return replace(tile, bounds=new, bounds_verified=True)


def cell_points_for(block_points: int, cell_points: int) -> int:
    """The largest divisor of *block_points* not above *cell_points*."""
    for c in range(min(int(cell_points), block_points), 0, -1):
        if block_points % c == 0:
            return c
    return block_points


class BlockBoxes:
    """Accumulates cell boxes from a stream of chunks in file order (any chunk sizes)."""

    def __init__(self, block_points: int, cell_points: int, count: int) -> None:
        self.block_points = int(block_points)
        self.cell_points = int(cell_points)
        self.count = int(count)
        self.cells = -(-self.count // self.cell_points)
        # grown as points arrive: a header's count is a claim and must not size an allocation
        self.boxes = self._empty(min(self.cells, 1024))
        self.seen = 0

    @staticmethod
    def _empty(k: int) -> np.ndarray:
        boxes = np.empty((k, 4))
        boxes[:, :2] = np.inf
        boxes[:, 2:] = -np.inf
        return boxes

    def add(self, xyz: np.ndarray) -> None:
        m = len(xyz)
        if m == 0:
            return
        if self.seen + m > self.count:
            raise ValueError("more points than the tile holds")
        cp = self.cell_points
        first, last = self.seen // cp, (self.seen + m - 1) // cp
        if last >= len(self.boxes):
            grown = self._empty(min(self.cells, max(last + 1, 2 * len(self.boxes))))
            grown[:len(self.boxes)] = self.boxes
            self.boxes = grown
        edges = np.concatenate([[0], np.arange(first + 1, last + 1) * cp - self.seen]).astype(np.intp)
        x, y = xyz[:, 0], xyz[:, 1]
        box = self.boxes[first:last + 1]
        np.minimum(box[:, 0], np.minimum.reduceat(x, edges), out=box[:, 0])
        np.minimum(box[:, 1], np.minimum.reduceat(y, edges), out=box[:, 1])
        np.maximum(box[:, 2], np.maximum.reduceat(x, edges), out=box[:, 2])
        np.maximum(box[:, 3], np.maximum.reduceat(y, edges), out=box[:, 3])
        self.seen += m

    def finish(self) -> BlockIndex | None:
        if self.seen != self.count:
            return None
        return BlockIndex(self.block_points, self.count, self.boxes, self.cell_points)


def expand_paths(paths_or_globs: str | os.PathLike | Iterable[str | os.PathLike],
                 root: str | os.PathLike | None = None) -> list[Path]:
    """Files named by paths, folders (their point files) and globs, in order, without duplicates.

    Relative entries are taken relative to *root* (default: the working folder).

    Raises
    ------
    TileIOError
        A named file does not exist, or a glob or folder matches no point file.
    """
    if isinstance(paths_or_globs, (str, os.PathLike)):
        paths_or_globs = [paths_or_globs]
    base = Path(root) if root is not None else Path.cwd()
    out: list[Path] = []
    seen: set[Path] = set()
    suffixes = LAS_SUFFIXES + ASCII_SUFFIXES

    def add(p: Path) -> None:
        p = p.resolve()
        if p not in seen:
            seen.add(p)
            out.append(p)

    def points_only(matches: list[Path]) -> list[Path]:
        """A folder's or a glob's files without the tables beside the tiles (a jobs.csv, a control file)."""
        keep = [m for m in matches if not is_foreign_table(m)]
        for m in matches:
            if m not in keep:
                log.warning("%s: skipped, a table that names no E, N, H columns (not a LiDAR tile)", m)
        return keep

    for entry in paths_or_globs:
        text = os.fspath(entry)
        p = Path(text)
        full = p if p.is_absolute() else base / p
        if _GLOB_CHARS & set(text):
            matches = sorted(Path(m) for m in _glob.glob(str(full), recursive=True))
            matches = points_only([m for m in matches if m.is_file() and m.suffix.lower() in suffixes])
            if not matches:
                raise TileIOError(f"{text}: no LiDAR files match this pattern (looked in {base})")
            for m in matches:
                add(m)
        elif full.is_dir():
            matches = points_only(sorted(m for m in full.iterdir() if m.is_file() and m.suffix.lower() in suffixes))
            if not matches:
                raise TileIOError(f"{full}: folder holds no LiDAR files ({', '.join(suffixes)})")
            for m in matches:
                add(m)
        else:
            if not full.exists():
                raise TileIOError(f"{full}: file not found")
            file_kind(full)
            add(full)
    return out
