"""A spatial index over a folder (or globs) of LiDAR tiles.

:meth:`TileIndex.build` records, per tile, its bounds, point count, size,
modification time and CRS: read from the header for LAS/LAZ, from one scan for
text files.  The index can be cached as JSON (``cache_path=``; the CLI puts it
in the survey folder as ``lidar_index.json``); an entry is reused while the
file's size and modification time are unchanged and rebuilt otherwise.

**Header bounds are never trusted for selection.**  Writers get them wrong
(laspy's ``simple1_3.las`` claims bounds that miss its points), so the bounds
of a LAS/LAZ tile count as *unverified* until its points have been read once
(any whole read, the block index, or :meth:`TileIndex.verify_bounds`); a
query reads every unverified tile, and from then on uses the measured bounds,
which the JSON cache keeps.

Queries (:meth:`~TileIndex.query_radius`, :meth:`~TileIndex.query_box`,
:meth:`~TileIndex.query_polygon`) open only the tiles whose bounds meet the
query, stream them chunk by chunk and return one :class:`PointCloud` with the
points of every tile in index order (tiles in the order of the paths/globs
given, each glob sorted; points in file order), so a house straddling a tile
boundary comes back whole.  Recently read tiles stay in memory up to
``max_cached_points`` points so that many clips in one survey read each tile
once.

Membership tests (:mod:`lidarcat.lidar.membership`) are the same whatever the tiling: a
point is in a circle, a box (edges included) or a polygon (even-odd rule).

**Block index (LAS/LAZ).**  A :class:`BlockIndex` (:mod:`lidarcat.lidar.tiles`) records the plan
box of every cell of a tile's points in file order; a query on a tile that is not in
memory decodes only the blocks holding a cell whose box meets the query box, and returns
exactly the points, attributes and order a whole-tile decode returns.

The block index of a tile is computed in one full pass: as a by-product of the
first whole-tile read (any query or :meth:`TileIndex.iter_points`), by
:meth:`TileIndex.index_blocks`, or at :meth:`TileIndex.build` with
``blocks=True``; it is kept in the JSON cache (``cache_path=``) with the tile
and dropped when the file's size or modification time changes.  ``decode=``
chooses how cold queries read: ``"auto"`` (default) uses the blocks when the
index is known and they would decode less than half the tile's points,
otherwise decodes the whole tile as before (tiles within ``max_cached_points``
are then kept in memory whole, which is also done once the block reads of a
tile that fits add up to a quarter of its points: many clips in one tile);
``"blocks"`` always uses the blocks once the index is known; ``"whole"`` never
does.  Decoded blocks share the ``max_cached_points`` memory
budget with whole tiles; the counter :attr:`TileIndex.decoded_points` tells how
many points were decoded from files.

**COPC tiles.**  A tile whose first VLR is the COPC info record is queried
by its octree (:mod:`lidarcat.lidar.copc`, laspy's COPC reader): a query
not served from memory decodes only the nodes whose cube meets the query box
(``decode="whole"`` turns this off; with ``"auto"`` a tile that fits in
memory is decoded once and kept whole after its octree reads reach a quarter
of its points, as for block reads).  Its header bounds are not trusted
either: every query consults the octree of such a tile until its points have
been read once (only hierarchy pages are read when the query misses the tile).
"""

from __future__ import annotations

import json
import logging
import os
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from .._util import write_json_atomic
from ..errors import ClipError, CRSError, TileIOError
from .cloud import Bounds, PointCloud
from .copc import is_copc, read_copc_box
from .crs import common_crs, crs_compatible, crs_label, require_metres, resolve_crs, transform_points
from .membership import CellGrid, in_box, in_polygon, in_radius
from .readers import (file_kind, iter_las_ranges, iter_points,
                      las_chunk_points, read_header)
from .tiles import (DEFAULT_BLOCK_POINTS, DEFAULT_CELL_POINTS, BlockBoxes, BlockIndex, Tile, cell_points_for,
                    expand_paths, verified_by_blocks, with_bounds)

__all__ = ["TileIndex", "Tile", "BlockIndex", "DECODE_MODES", "DEFAULT_BLOCK_POINTS", "DEFAULT_CELL_POINTS",
           "expand_paths", "in_radius", "in_box", "in_polygon"]

log = logging.getLogger(__name__)

_CACHE_FORMAT = "lidarcat-tile-index"
_CACHE_VERSION = 2  # 2: per-tile "blocks" (block index); version-1 files are read as absent
#: how cold queries read LAS/LAZ tiles (see the module docstring)
DECODE_MODES = ("auto", "blocks", "whole")
#: "auto" uses the blocks when a query would decode less than this fraction of the tile's points
_AUTO_BLOCK_FRACTION = 0.5
#: ... and reads a tile that fits in memory whole once its block reads reach this fraction
_AUTO_SWITCH_FRACTION = 0.25


class TileIndex:
    """Bounds and counts of a set of LiDAR tiles; spatial queries over them.

    Build with :meth:`build`.  Queries return a :class:`PointCloud` in
    :attr:`crs`; a query point given in another CRS (``crs=``) is transformed
    first.

    Attributes
    ----------
    tiles : tuple of Tile
    crs : pyproj.CRS or None
        The common CRS of the tiles (from the files, or given when they have none).
    decode : str
        How queries read LAS/LAZ tiles not in memory: ``"auto"``, ``"blocks"``
        or ``"whole"`` (see the module docstring).
    max_cached_points : int
        Memory budget, points, of the whole tiles and blocks kept in memory.
    decoded_points : int
        Points decoded from files so far by this index (diagnostics).
    """

    def __init__(self, tiles: Sequence[Tile], crs: Any = None, *, columns: Any = None,
                 delimiter: str | None = None, chunk_size: int | None = None,
                 max_cached_points: int = 8_000_000, decode: str = "auto",
                 block_points: int = DEFAULT_BLOCK_POINTS, cell_points: int = DEFAULT_CELL_POINTS,
                 blocks: dict[Path, BlockIndex] | None = None,
                 cache_path: str | os.PathLike | None = None) -> None:
        if decode not in DECODE_MODES:
            raise ValueError(f"decode must be one of {', '.join(DECODE_MODES)}, got {decode!r}")
        if int(block_points) <= 0 or int(cell_points) <= 0:
            raise ValueError(f"block_points and cell_points must be positive, got {block_points}, "
                             f"{cell_points}")
        self.tiles: tuple[Tile, ...] = tuple(tiles)
        self.crs: pyproj.CRS | None = resolve_crs(crs)
        self._columns = columns
        self._delimiter = delimiter
        self._chunk_size = chunk_size
        self.max_cached_points = int(max_cached_points)
        self.decode = decode
        self.block_points = int(block_points)
        self.cell_points = int(cell_points)
        self.decoded_points = 0
        self._cache_path = Path(cache_path) if cache_path is not None else None
        # whole tiles (key: path) and block prefixes (key: (path, block)), least recently used first
        self._cache: OrderedDict[Any, PointCloud] = OrderedDict()
        self._grids: dict[Path, CellGrid] = {}
        self._cached_points = 0
        self._block_decoded: dict[Path, int] = {}  # points of each tile decoded by block reads
        self._copc: dict[Path, bool] = {}  # tiles that are COPC files (queried by their octree)
        self._metres_checked = False
        by_path = {t.path: t for t in self.tiles}
        self._blocks: dict[Path, BlockIndex] = {
            p: b for p, b in (blocks or {}).items() if p in by_path and b.count == by_path[p].count}

    # ---------------------------------------------------------------- building
    @classmethod
    def build(cls, paths_or_globs: str | os.PathLike | Iterable[str | os.PathLike], *, crs: Any = None,
              cache_path: str | os.PathLike | None = None, root: str | os.PathLike | None = None,
              columns: Any = None, delimiter: str | None = None, chunk_size: int | None = None,
              progress: Callable[[int], Any] | None = None,
              max_cached_points: int = 8_000_000, decode: str = "auto", blocks: bool = False,
              block_points: int = DEFAULT_BLOCK_POINTS,
              cell_points: int = DEFAULT_CELL_POINTS) -> TileIndex:
        """Index the tiles named by paths, folders or globs.

        Parameters
        ----------
        paths_or_globs : path, glob or iterable of them
            Relative entries are relative to *root* (default: working folder).
        crs : CRS-like, optional
            CRS of the tiles that carry none (e.g. ``"EPSG:7415"`` for AHN3).
        cache_path : path-like, optional
            JSON file caching the index; entries whose file size and mtime
            are unchanged are reused, others re-read; rewritten when anything
            changed.
        columns, delimiter
            For text tiles (see :mod:`lidarcat.lidar.readers`).
        chunk_size : int, optional
            Points per chunk when streaming tiles too large to keep in memory
            (default :data:`~lidarcat.lidar.readers.DEFAULT_CHUNK_SIZE`).
        progress : callable, optional
            Called with the bytes of each tile indexed (or reused), and with
            those of each tile read for its block index.
        max_cached_points : int
            Memory budget, points, for tiles and blocks kept in memory.
        decode : {"auto", "blocks", "whole"}
            How queries read LAS/LAZ tiles not in memory (module docstring).
        blocks : bool
            Compute now the block index of every LAS/LAZ tile that has none
            yet (one full read per tile; stored in *cache_path*).  Without it
            a tile's block index is made on its first whole read.
        block_points : int
            Points per block for LAS files (LAZ files use their chunk size).
        cell_points : int
            Points per recorded box (the largest divisor of the block size
            not above it); smaller cells decode less per query but make a
            larger index (32 bytes per cell).

        Raises
        ------
        TileIOError
            Missing files, globs matching nothing, a *cache_path* that cannot be written.
        LidarFormatError
            A corrupt tile.
        CRSError
            Unknown *crs*, a tile whose CRS conflicts with *crs*, or tiles of
            different CRSs (the message names two of them).
        """
        given = resolve_crs(crs)
        paths = expand_paths(paths_or_globs, root)
        cached, cached_blocks = cls._load_cache_doc(Path(cache_path)) if cache_path is not None else ({}, {})
        tiles: list[Tile] = []
        changed = cache_path is not None and not Path(cache_path).exists()
        for p in paths:
            st = p.stat()
            old = cached.get(p)
            if old is not None and old.size == st.st_size and old.mtime_ns == st.st_mtime_ns:
                tiles.append(old)
                if progress is not None:
                    progress(st.st_size)
                continue
            h = read_header(p, crs=given, columns=columns,
                            delimiter=delimiter, progress=progress)
            wkt = h.crs.to_wkt() if (h.crs is not None and h.crs_from_file) else None
            tiles.append(Tile(p, st.st_size, st.st_mtime_ns, h.count, h.bounds, wkt,
                              h.description, h.attributes, bounds_verified=h.kind != "las"))
            changed = True
            log.debug("indexed %s: %d points", p, h.count)
        known_blocks = {t.path: cached_blocks[t.path] for t in tiles
                        if t.path in cached_blocks and cached.get(t.path) is t}
        tiles = [verified_by_blocks(t, known_blocks.get(t.path)) for t in tiles]
        if cache_path is not None and (changed or set(cached) != set(paths)):
            cls._save_cache(Path(cache_path), tiles, known_blocks)
        tile_crs = []
        for t in tiles:
            file_crs = resolve_crs(t.file_crs_wkt) if t.file_crs_wkt else None
            if file_crs is not None and given is not None and not crs_compatible(file_crs, given):
                raise CRSError(f"{t.path}: the file says its CRS is {crs_label(file_crs)} but "
                               f"{crs_label(given)} was given; drop the CRS option or transform the file")
            tile_crs.append((str(t.path), file_crs if file_crs is not None else given))
        common = common_crs(tile_crs)
        idx = cls(tiles, common, columns=columns, delimiter=delimiter, chunk_size=chunk_size,
                  max_cached_points=max_cached_points, decode=decode, block_points=block_points,
                  cell_points=cell_points,
                  blocks=known_blocks, cache_path=cache_path)
        if blocks:
            idx.index_blocks(progress=progress)
        return idx

    @staticmethod
    def _load_cache_doc(path: Path) -> tuple[dict[Path, Tile], dict[Path, BlockIndex]]:
        """Tiles and block indexes of a cache file; empty when absent, old or unreadable."""
        if not path.exists():
            return {}, {}
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            if doc.get("format") != _CACHE_FORMAT or doc.get("version") != _CACHE_VERSION:
                return {}, {}
            base = path.parent.resolve()
            tiles: dict[Path, Tile] = {}
            blocks: dict[Path, BlockIndex] = {}
            for d in doc["tiles"]:
                t = Tile.from_dict(d, base)
                tiles[t.path] = t
                if d.get("blocks") is not None:
                    try:
                        b = BlockIndex.from_dict(d["blocks"])
                    except (ValueError, KeyError, TypeError) as ex:  # only this block index is lost
                        log.warning("%s: ignoring the unreadable block index of %s (%s)", path, t.path, ex)
                        continue
                    if b.count == t.count:
                        blocks[t.path] = b
        except (OSError, ValueError, KeyError, TypeError) as ex:
            log.warning("%s: ignoring unreadable tile-index cache (%s)", path, ex)
            return {}, {}
        return tiles, blocks

    @staticmethod
    def _save_cache(path: Path, tiles: Sequence[Tile], blocks: dict[Path, BlockIndex] | None = None) -> None:
        base = path.parent.resolve()
        docs = []
        for t in tiles:
            d = t.to_dict(base)
            if blocks and t.path in blocks:
                d["blocks"] = blocks[t.path].to_dict()
            docs.append(d)
        try:
            write_json_atomic(path, {"format": _CACHE_FORMAT, "version": _CACHE_VERSION, "tiles": docs})
        except OSError as ex:
            raise TileIOError(f"{path}: cannot write the tile index ({ex.strerror or ex}); "
                              "choose a writable place for it") from ex

    def _save_blocks(self) -> None:
        """Write the block indexes to the cache file, merging those another process may
        have written there meanwhile (for the same file size and mtime)."""
        if self._cache_path is None:
            return
        on_disk_tiles, on_disk_blocks = self._load_cache_doc(self._cache_path)
        for t in self.tiles:
            old = on_disk_tiles.get(t.path)
            if (t.path not in self._blocks and t.path in on_disk_blocks and old is not None
                    and (old.size, old.mtime_ns, old.count) == (t.size, t.mtime_ns, t.count)):
                self._blocks[t.path] = on_disk_blocks[t.path]
        try:
            self._save_cache(self._cache_path, self.tiles, self._blocks)
        except OSError as ex:  # a read-only survey folder must not break queries
            log.warning("%s: cannot store the block index (%s)", self._cache_path, ex)

    # ---------------------------------------------------------------- facts
    def __len__(self) -> int:
        return len(self.tiles)

    def __iter__(self) -> Iterator[Tile]:
        return iter(self.tiles)

    def __repr__(self) -> str:
        return f"TileIndex({len(self.tiles)} tiles, {self.count} points, crs={crs_label(self.crs)!r})"

    @property
    def paths(self) -> list[Path]:
        return [t.path for t in self.tiles]

    @property
    def count(self) -> int:
        """Total number of points."""
        return sum(t.count for t in self.tiles)

    def verify_bounds(self, progress: Callable[[int], Any] | None = None) -> int:
        """Read every tile whose bounds are the header's unverified claim (one full read each,
        which also records its block index); returns the number of tiles read.  After it
        :attr:`bounds` is the bounds of the points themselves."""
        todo = [t for t in self.tiles if not t.bounds_verified and t.count > 0]
        for t in todo:
            for _ in self._decode_tile(t, progress=progress, save=False):
                pass
        if todo:
            self._save_blocks()
        return len(todo)

    @property
    def bounds(self) -> Bounds:
        """Union of the tile bounds (NaN when there are no points); a tile not read yet counts
        with its header's bounds (see :meth:`verify_bounds`)."""
        return Bounds.union(t.bounds for t in self.tiles if t.count > 0)

    def to_dict(self) -> dict[str, Any]:
        return {"crs": None if self.crs is None else crs_label(self.crs), "points": self.count,
                "bounds": self.bounds._asdict(), "tiles": [t.to_dict() for t in self.tiles]}

    def tiles_in_box(self, xmin: float, ymin: float, xmax: float, ymax: float) -> list[Tile]:
        """Tiles whose points may meet the plan box (edges included): those whose measured
        bounds meet it, and every tile whose bounds are still the header's unverified claim."""
        return [t for t in self.tiles if t.may_meet(xmin, ymin, xmax, ymax)]

    # ---------------------------------------------------------------- reading
    def _check_unchanged(self, tile: Tile) -> None:
        try:
            st = tile.path.stat()
        except FileNotFoundError:
            raise TileIOError(f"{tile.path}: file not found (it was indexed; rebuild the index)") from None
        if st.st_size != tile.size or st.st_mtime_ns != tile.mtime_ns:
            raise TileIOError(f"{tile.path}: the file changed since it was indexed; rebuild the index")

    def _file_crs_kw(self, tile: Tile) -> Any:
        return self.crs if tile.file_crs_wkt is None else None

    def _in_index_crs(self, cloud: PointCloud) -> PointCloud:
        return cloud if cloud.crs is self.crs or self.crs is None else cloud.with_crs(self.crs)

    def _wants_blocks(self, tile: Tile) -> bool:
        """True when a whole read of *tile* should record its block index on the way."""
        return (self.decode != "whole" and tile.count > 0 and tile.path not in self._blocks
                and file_kind(tile.path) == "las")

    def _decode_tile(self, tile: Tile, progress: Callable[[int], Any] | None = None,
                     save: bool = True) -> Iterator[PointCloud]:
        """Stream a whole tile from its file, recording its block index when wanted (and,
        with *save*, writing it to the cache file)."""
        self._check_unchanged(tile)
        acc = None
        if self._wants_blocks(tile):
            bp = las_chunk_points(tile.path) or self.block_points
            acc = BlockBoxes(bp, cell_points_for(bp, self.cell_points), tile.count)
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        for chunk in iter_points(tile.path, self._chunk_size, crs=self._file_crs_kw(tile),
                                 columns=self._columns, delimiter=self._delimiter, progress=progress):
            self.decoded_points += len(chunk)
            if acc is not None:
                acc.add(chunk.xyz)
            if not tile.bounds_verified and len(chunk):
                lo = np.minimum(lo, chunk.xyz.min(axis=0))
                hi = np.maximum(hi, chunk.xyz.max(axis=0))
            yield chunk
        if not tile.bounds_verified and np.isfinite(lo).all():
            k = next(i for i, t in enumerate(self.tiles) if t.path == tile.path)
            self.tiles = self.tiles[:k] + (with_bounds(tile, (lo[0], lo[1], hi[0], hi[1], lo[2], hi[2])),) \
                + self.tiles[k + 1:]
            if save and acc is None:
                self._save_blocks()
        if acc is not None:
            blocks = acc.finish()
            if blocks is not None:
                self._blocks[tile.path] = blocks
                if save:
                    self._save_blocks()

    def _tile_chunks(self, tile: Tile) -> Iterator[PointCloud]:
        hit = self._cache.get(tile.path)
        if hit is not None:
            self._touch(tile.path)
            yield hit
            return
        if tile.count <= self.max_cached_points:
            parts = list(self._decode_tile(tile))
            cloud = PointCloud.concat(parts) if parts else PointCloud.empty(tile.attributes, self.crs)
            cloud = self._in_index_crs(cloud)
            self._remember(tile.path, cloud)
            yield cloud
            return
        for chunk in self._decode_tile(tile):
            yield self._in_index_crs(chunk)

    def _touch(self, key: Any) -> None:
        self._cache.move_to_end(key)

    def _remember(self, key: Any, cloud: PointCloud) -> None:
        """Keep a whole tile (key: its path) or a block prefix (key: (path, block)) in memory;
        it replaces a shorter prefix of the same block, a whole tile all its blocks."""
        for old in [k for k in self._cache if k == key or (isinstance(k, tuple) and k[0] == key)]:
            self._forget(old)
        self._cache[key] = cloud
        self._cached_points += len(cloud)
        # drop the least recently used beyond the budget (the newest stays unless it alone is too big)
        while self._cached_points > self.max_cached_points and len(self._cache) > 1:
            self._forget(next(iter(self._cache)))
        if self._cached_points > self.max_cached_points:
            self.clear_cache()

    def _forget(self, key: Any) -> None:
        self._cached_points -= len(self._cache.pop(key))
        self._grids.pop(key, None)

    def clear_cache(self) -> None:
        """Forget the tiles and blocks kept in memory (block indexes are kept)."""
        self._cache.clear()
        self._grids.clear()
        self._cached_points = 0

    def iter_points(self, tiles: Sequence[Tile] | None = None) -> Iterator[PointCloud]:
        """Stream the points of *tiles* (default all), chunk by chunk, in index order."""
        for t in self.tiles if tiles is None else tiles:
            yield from self._tile_chunks(t)

    # ---------------------------------------------------------------- block index
    def block_index(self, tile: Tile | str | os.PathLike) -> BlockIndex | None:
        """The block index of a tile (a :class:`Tile` or its path), ``None`` when not known yet."""
        path = tile.path if isinstance(tile, Tile) else Path(tile).resolve()
        return self._blocks.get(path)

    def index_blocks(self, tiles: Sequence[Tile] | None = None,
                     progress: Callable[[int], Any] | None = None) -> int:
        """Compute the block index of the LAS/LAZ *tiles* (default all) that have none.

        One full read per tile, one tile at a time (memory bounded by the
        streaming chunk); the indexes are written to the cache file when the
        index was built with ``cache_path``.  Nothing happens with
        ``decode="whole"``.

        Parameters
        ----------
        tiles : sequence of Tile, optional
        progress : callable, optional
            Called with the bytes of the file processed by each chunk read.

        Returns
        -------
        int
            Number of tiles indexed.

        Raises
        ------
        TileIOError
            A tile is missing or changed since it was indexed.
        LidarFormatError
            Corrupt or truncated point data.
        """
        done = 0
        try:
            for t in self.tiles if tiles is None else tiles:
                if self._wants_blocks(t):
                    for _ in self._decode_tile(t, progress=progress, save=False):
                        pass
                    done += 1
        finally:
            if done:
                self._save_blocks()
        return done

    def _query_blocks(self, tile: Tile, box: tuple[float, float, float, float],
                      mask_fn: Callable[[np.ndarray], np.ndarray]) -> list[PointCloud] | None:
        """Matching points of a tile not in memory, decoding only the blocks that meet *box*;
        ``None`` when the block path does not apply (then the whole tile is read)."""
        if self.decode == "whole":
            return None
        bi = self._blocks.get(tile.path)
        if bi is None:
            return None
        blocks, stops = bi.needs(bi.cells_in_box(*box))
        starts = [k * bi.block_points for k in blocks]
        if self.decode == "auto" and sum(stops) - sum(starts) >= _AUTO_BLOCK_FRACTION * tile.count:
            return None
        have: dict[int, PointCloud | None] = {}
        missing: list[tuple[int, int]] = []
        for k, a, e in zip(blocks, starts, stops):
            c = self._cache.get((tile.path, k))
            if c is not None and a + len(c) >= e:  # kept in memory, long enough
                self._touch((tile.path, k))
            else:
                c = None
                missing.append((k, e))
            have[k] = c
        if missing:
            ranges = bi.ranges([k for k, _ in missing], [e for _, e in missing])
            need = sum(e - a for a, e in ranges)
            if self.decode == "auto" and tile.count <= self.max_cached_points and \
                    self._block_decoded.get(tile.path, 0) + need >= _AUTO_SWITCH_FRACTION * tile.count:
                return None  # many queries in this tile: decode it once and keep it whole
            self._block_decoded[tile.path] = self._block_decoded.get(tile.path, 0) + need
            self._check_unchanged(tile)
            per_read = max(int(self._chunk_size or 0), bi.block_points, 1_000_000)
            for start, cloud in iter_las_ranges(tile.path, ranges, crs=self._file_crs_kw(tile),
                                                piece_points=bi.block_points, max_read_points=per_read):
                self.decoded_points += len(cloud)
                cloud = self._in_index_crs(cloud)
                k = start // bi.block_points
                have[k] = cloud
                self._remember((tile.path, k), cloud)
        out: list[PointCloud] = []
        for k in blocks:
            cloud = have[k]
            assert cloud is not None
            m = mask_fn(cloud.xyz)  # points past the cells met cannot match: their cells miss the box
            if m.any():
                out.append(cloud.select(m))
        return out

    def _is_copc(self, tile: Tile) -> bool:
        """True for a COPC tile (checked once per path: the COPC info VLR, not the file name)."""
        hit = self._copc.get(tile.path)
        if hit is None:
            hit = self._copc[tile.path] = file_kind(tile.path) == "las" and is_copc(tile.path)
        return hit

    def _copc_by_octree(self, tile: Tile) -> bool:
        """Query *tile* by its octree: a COPC tile, unless ``decode="whole"``, or ``"auto"`` once its
        octree reads reached a quarter of its points and it fits in memory (then it is decoded
        once and kept whole, as for LAS/LAZ block reads)."""
        if self.decode == "whole" or not self._is_copc(tile):
            return False
        return not (self.decode == "auto" and tile.count <= self.max_cached_points
                    and self._block_decoded.get(tile.path, 0) >= _AUTO_SWITCH_FRACTION * tile.count)

    def _query_copc(self, tile: Tile, box: tuple[float, float, float, float],
                    mask_fn: Callable[[np.ndarray], np.ndarray]) -> list[PointCloud]:
        """Matching points of a COPC tile, decoding only the octree nodes that meet *box*."""
        self._check_unchanged(tile)
        res = read_copc_box(tile.path, box, crs=self._file_crs_kw(tile))
        self.decoded_points += res.points_decoded
        self._block_decoded[tile.path] = self._block_decoded.get(tile.path, 0) + res.points_decoded
        log.debug("%s: COPC query read %d of %d known nodes (%d points)", tile.path, res.nodes_read,
                  res.nodes_known, res.points_decoded)
        cloud = self._in_index_crs(res.cloud)
        m = mask_fn(cloud.xyz)
        return [cloud.select(m)] if m.any() else []

    def _query(self, box: tuple[float, float, float, float],
               mask_fn: Callable[[np.ndarray], np.ndarray]) -> PointCloud:
        parts: list[PointCloud] = []
        attrs: tuple[str, ...] | None = None
        for t in self.tiles_in_box(*box):
            attrs = t.attributes if attrs is None else tuple(a for a in attrs if a in t.attributes)
            cached = self._cache.get(t.path)
            if cached is not None and len(cached) > 0:
                self._touch(t.path)
                grid = self._grids.get(t.path)
                if grid is None:
                    grid = self._grids[t.path] = CellGrid(cached.xyz)
                idx = grid.candidates(*box)
                idx = idx[mask_fn(cached.xyz[idx])]
                if len(idx):
                    parts.append(cached.select(idx))
                continue
            if cached is None and self._copc_by_octree(t):
                parts.extend(self._query_copc(t, box, mask_fn))
                continue
            if cached is None:
                from_blocks = self._query_blocks(t, box, mask_fn)
                if from_blocks is not None:
                    parts.extend(from_blocks)
                    continue
            for chunk in self._tile_chunks(t):
                m = mask_fn(chunk.xyz)
                if m.any():
                    parts.append(chunk.select(m))
        if not parts:
            if attrs is None:  # no tile touched: keep the schema the whole index shares
                attrs = tuple(a for a in self.tiles[0].attributes
                              if all(a in t.attributes for t in self.tiles)) if self.tiles else ()
            return PointCloud.empty(attrs, self.crs)
        return PointCloud.concat(parts)

    def _to_index_crs(self, pts: np.ndarray, crs: Any) -> np.ndarray:
        q = resolve_crs(crs)
        if q is None or crs_compatible(q, self.crs):
            return pts
        if self.crs is None:
            raise CRSError(f"the query is in {crs_label(q)} but the tiles have no CRS; "
                           "give the tiles' CRS when building the index (crs=, [lidar] crs, --crs)")
        return transform_points(pts, q, self.crs)

    # ---------------------------------------------------------------- queries
    def query_radius(self, center_en: Sequence[float], radius_m: float, crs: Any = None) -> PointCloud:
        """Points within *radius_m* (plan distance, metres) of *center_en* = (E, N).

        *crs* is the CRS of *center_en* when it differs from the tiles'.
        """
        if not radius_m > 0:
            raise ValueError(f"radius_m must be positive, got {radius_m}")
        if not self._metres_checked:
            require_metres(self.crs, f"a clip radius of {radius_m:g} m",
                           str(self.tiles[0].path) if self.tiles else "")
            self._metres_checked = True
        c = self._to_index_crs(np.asarray(center_en[:2], dtype=np.float64), crs)
        r = float(radius_m)
        return self._query((c[0] - r, c[1] - r, c[0] + r, c[1] + r), lambda xyz: in_radius(xyz, c, r))

    def query_box(self, xmin: float, ymin: float, xmax: float, ymax: float, crs: Any = None) -> PointCloud:
        """Points with ``xmin <= E <= xmax`` and ``ymin <= N <= ymax`` (metres).

        With *crs*, the four corners are transformed and their bounding box used.
        """
        if xmax < xmin or ymax < ymin:
            raise ClipError(f"empty box: x {xmin}..{xmax}, y {ymin}..{ymax}; give xmin <= xmax and "
                            f"ymin <= ymax (metres)")
        if crs is not None:
            corners = self._to_index_crs(np.array([[xmin, ymin], [xmax, ymin], [xmax, ymax], [xmin, ymax]],
                                                  dtype=np.float64), crs)
            xmin, ymin = corners.min(axis=0)
            xmax, ymax = corners.max(axis=0)
        box = (float(xmin), float(ymin), float(xmax), float(ymax))
        return self._query(box, lambda xyz: in_box(xyz, *box))

    def query_polygon(self, vertices: Any, crs: Any = None) -> PointCloud:
        """Points inside the polygon *vertices* (shape (M, 2), E N in metres; even-odd rule)."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] < 2 or len(v) < 3:
            raise ValueError(f"a polygon needs at least 3 vertices as an (M, 2) array, got shape {v.shape}")
        v = self._to_index_crs(v[:, :2], crs)
        box = (float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max()))

        def mask(xyz: np.ndarray) -> np.ndarray:
            m = in_box(xyz, *box)
            idx = np.flatnonzero(m)
            m[idx] = in_polygon(xyz[idx], v)
            return m

        return self._query(box, mask)
