"""A spatial index over a folder (or globs) of LiDAR tiles.

:meth:`TileIndex.build` records, per tile, its bounds, point count, size,
modification time and CRS: read from the header for LAS/LAZ, from one scan for
text files.  The index can be cached as JSON (``cache_path=``; the CLI puts it
in the survey folder as ``lidar_index.json``); an entry is reused while the
file's size and modification time are unchanged and rebuilt otherwise.

Queries (:meth:`~TileIndex.query_radius`, :meth:`~TileIndex.query_box`,
:meth:`~TileIndex.query_polygon`) open only the tiles whose bounds meet the
query, stream them chunk by chunk and return one :class:`PointCloud` with the
points of every tile in index order (tiles in the order of the paths/globs
given, each glob sorted; points in file order), so a house straddling a tile
boundary comes back whole.  Recently read tiles stay in memory up to
``max_cached_points`` points so that many clips in one survey read each tile
once.

Membership tests are the same whatever the tiling: a point is in a circle when
``(x - e)**2 + (y - n)**2 <= r**2``, in a box when ``xmin <= x <= xmax`` and
``ymin <= y <= ymax`` (edges included), in a polygon by the even-odd rule.
"""

from __future__ import annotations

import glob as _glob
import json
import logging
import os
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

from .._io import write_json_atomic
from ..errors import CRSError, TileIOError
from .cloud import Bounds, PointCloud
from .crs import common_crs, crs_compatible, crs_label, resolve_crs, transform_points
from .readers import ASCII_SUFFIXES, LAS_SUFFIXES, file_kind, iter_points, read_header

__all__ = ["TileIndex", "Tile", "expand_paths", "in_radius", "in_box", "in_polygon"]

log = logging.getLogger(__name__)

_CACHE_FORMAT = "lidarcat-tile-index"
_CACHE_VERSION = 1
_GLOB_CHARS = set("*?[")


# --------------------------------------------------------------------------- membership
def in_radius(xy: np.ndarray, center_en: Sequence[float], radius_m: float) -> np.ndarray:
    """Mask of points within *radius_m* (edge included) of *center_en* in plan.

    >>> in_radius(np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.1]]), (0.0, 0.0), 5.0).tolist()
    [True, True, False]
    """
    dx = xy[:, 0] - float(center_en[0])
    dy = xy[:, 1] - float(center_en[1])
    return dx * dx + dy * dy <= float(radius_m) ** 2


def in_box(xy: np.ndarray, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    """Mask of points with ``xmin <= x <= xmax`` and ``ymin <= y <= ymax``."""
    x, y = xy[:, 0], xy[:, 1]
    return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)


def in_polygon(xy: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Mask of points inside a simple polygon (even-odd rule, vectorised over points).

    Parameters
    ----------
    xy : ndarray, shape (N, 2+)
    vertices : ndarray, shape (M, 2)
        Polygon vertices in order; closing the ring is optional.

    >>> sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    >>> in_polygon(np.array([[1.0, 1.0], [3.0, 1.0]]), sq).tolist()
    [True, False]
    """
    v = np.asarray(vertices, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    inside = np.zeros(len(xy), dtype=bool)
    m = len(v)
    for i in range(m):
        x1, y1 = v[i]
        x2, y2 = v[(i + 1) % m]
        if y1 == y2:
            continue
        crosses = (y1 > y) != (y2 > y)
        if not crosses.any():
            continue
        xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xint)
    return inside


class _CellGrid:
    """Points of an in-memory tile bucketed into square cells, for fast box candidates.

    Candidates come back as sorted indices, so that selecting them keeps the
    file order (queries return exactly what a full scan returns).
    """

    def __init__(self, xyz: np.ndarray, points_per_cell: int = 64) -> None:
        x, y = xyz[:, 0], xyz[:, 1]
        self.x0, self.y0 = float(x.min()), float(y.min())
        w = max(float(x.max()) - self.x0, 1e-9)
        h = max(float(y.max()) - self.y0, 1e-9)
        self.cell = max(float(np.sqrt(w * h * points_per_cell / max(len(xyz), 1))), 0.5)
        self.nx = int(w // self.cell) + 1
        self.ny = int(h // self.cell) + 1
        cx, cy = self._cells(x, y)
        key = cy * self.nx + cx
        self.order = np.argsort(key, kind="stable")
        self.starts = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=self.nx * self.ny))])

    def _cells(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        cx = np.clip(np.floor((np.asarray(x, dtype=np.float64) - self.x0) / self.cell), 0, self.nx - 1)
        cy = np.clip(np.floor((np.asarray(y, dtype=np.float64) - self.y0) / self.cell), 0, self.ny - 1)
        return cx.astype(np.int64), cy.astype(np.int64)

    def candidates(self, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        (cx0, cx1), (cy0, cy1) = (self._cells([xmin, xmax], [ymin, ymax]))
        segs = [self.order[self.starts[cy * self.nx + cx0]:self.starts[cy * self.nx + cx1 + 1]]
                for cy in range(int(cy0), int(cy1) + 1)]
        idx = np.concatenate(segs) if segs else np.empty(0, dtype=np.int64)
        idx.sort()
        return idx


# --------------------------------------------------------------------------- tiles
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
    """

    path: Path
    size: int
    mtime_ns: int
    count: int
    bounds: Bounds
    file_crs_wkt: str | None
    description: str
    attributes: tuple[str, ...]

    def to_dict(self, relative_to: Path | None = None) -> dict[str, Any]:
        path = str(self.path)
        if relative_to is not None and self.path.is_relative_to(relative_to):
            path = self.path.relative_to(relative_to).as_posix()
        return {"path": path, "size": self.size, "mtime_ns": self.mtime_ns, "count": self.count,
                "bounds": list(self.bounds), "file_crs_wkt": self.file_crs_wkt,
                "description": self.description, "attributes": list(self.attributes)}

    @classmethod
    def from_dict(cls, d: dict[str, Any], base: Path) -> Tile:
        path = Path(d["path"])
        if not path.is_absolute():
            path = (base / path).resolve()
        return cls(path, int(d["size"]), int(d["mtime_ns"]), int(d["count"]),
                   Bounds(*map(float, d["bounds"])), d.get("file_crs_wkt"), str(d["description"]),
                   tuple(d.get("attributes", ())))


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

    for entry in paths_or_globs:
        text = os.fspath(entry)
        p = Path(text)
        full = p if p.is_absolute() else base / p
        if _GLOB_CHARS & set(text):
            matches = sorted(Path(m) for m in _glob.glob(str(full), recursive=True))
            matches = [m for m in matches if m.is_file() and m.suffix.lower() in suffixes]
            if not matches:
                raise TileIOError(f"{text}: no LiDAR files match this pattern (looked in {base})")
            for m in matches:
                add(m)
        elif full.is_dir():
            matches = sorted(m for m in full.iterdir() if m.is_file() and m.suffix.lower() in suffixes)
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
    """

    def __init__(self, tiles: Sequence[Tile], crs: Any = None, *, columns: Any = None,
                 delimiter: str | None = None, chunk_size: int | None = None,
                 max_cached_points: int = 8_000_000) -> None:
        self.tiles: tuple[Tile, ...] = tuple(tiles)
        self.crs: pyproj.CRS | None = resolve_crs(crs)
        self._columns = columns
        self._delimiter = delimiter
        self._chunk_size = chunk_size
        self.max_cached_points = int(max_cached_points)
        self._cache: OrderedDict[Path, PointCloud] = OrderedDict()
        self._grids: dict[Path, _CellGrid] = {}
        self._cached_points = 0

    # ---------------------------------------------------------------- building
    @classmethod
    def build(cls, paths_or_globs: str | os.PathLike | Iterable[str | os.PathLike], *, crs: Any = None,
              cache_path: str | os.PathLike | None = None, root: str | os.PathLike | None = None,
              columns: Any = None, delimiter: str | None = None,
              progress: Callable[[int], Any] | None = None,
              max_cached_points: int = 8_000_000) -> TileIndex:
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
        progress : callable, optional
            Called with the bytes of each tile indexed (or reused).

        Raises
        ------
        TileIOError
            Missing files, globs matching nothing.
        LidarFormatError
            A corrupt tile.
        CRSError
            Unknown *crs*, a tile whose CRS conflicts with *crs*, or tiles of
            different CRSs (the message names two of them).
        """
        given = resolve_crs(crs)
        paths = expand_paths(paths_or_globs, root)
        cached = cls._load_cache(Path(cache_path)) if cache_path is not None else {}
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
            h = read_header(p, crs=None if file_kind(p) == "las" else given, columns=columns,
                            delimiter=delimiter, progress=progress)
            wkt = h.crs.to_wkt() if (h.crs is not None and h.crs_from_file) else None
            tiles.append(Tile(p, st.st_size, st.st_mtime_ns, h.count, h.bounds, wkt,
                              h.description, h.attributes))
            changed = True
            log.debug("indexed %s: %d points", p, h.count)
        if cache_path is not None and (changed or set(cached) != set(paths)):
            cls._save_cache(Path(cache_path), tiles)
        tile_crs = []
        for t in tiles:
            file_crs = resolve_crs(t.file_crs_wkt) if t.file_crs_wkt else None
            if file_crs is not None and given is not None and not crs_compatible(file_crs, given):
                raise CRSError(f"{t.path}: the file says its CRS is {crs_label(file_crs)} but "
                               f"{crs_label(given)} was given; drop the CRS option or transform the file")
            tile_crs.append((str(t.path), file_crs if file_crs is not None else given))
        common = common_crs(tile_crs)
        return cls(tiles, common, columns=columns, delimiter=delimiter,
                   max_cached_points=max_cached_points)

    @staticmethod
    def _load_cache(path: Path) -> dict[Path, Tile]:
        if not path.exists():
            return {}
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            if doc.get("format") != _CACHE_FORMAT or doc.get("version") != _CACHE_VERSION:
                return {}
            tiles = [Tile.from_dict(d, path.parent.resolve()) for d in doc["tiles"]]
        except (OSError, ValueError, KeyError, TypeError) as ex:
            log.warning("%s: ignoring unreadable tile-index cache (%s)", path, ex)
            return {}
        return {t.path: t for t in tiles}

    @staticmethod
    def _save_cache(path: Path, tiles: Sequence[Tile]) -> None:
        base = path.parent.resolve()
        write_json_atomic(path, {"format": _CACHE_FORMAT, "version": _CACHE_VERSION,
                                 "tiles": [t.to_dict(base) for t in tiles]})

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

    @property
    def bounds(self) -> Bounds:
        """Union of the tile bounds (NaN when there are no points)."""
        bs = np.array([list(t.bounds) for t in self.tiles if t.count > 0])
        if len(bs) == 0:
            return Bounds(*([float("nan")] * 6))
        return Bounds(bs[:, 0].min(), bs[:, 1].min(), bs[:, 2].max(), bs[:, 3].max(),
                      bs[:, 4].min(), bs[:, 5].max())

    def to_dict(self) -> dict[str, Any]:
        return {"crs": None if self.crs is None else crs_label(self.crs), "points": self.count,
                "bounds": self.bounds._asdict(), "tiles": [t.to_dict() for t in self.tiles]}

    def tiles_in_box(self, xmin: float, ymin: float, xmax: float, ymax: float) -> list[Tile]:
        """Tiles whose bounds meet the plan box (edges included)."""
        return [t for t in self.tiles if t.count > 0 and t.bounds.intersects_box(xmin, ymin, xmax, ymax)]

    # ---------------------------------------------------------------- reading
    def _tile_chunks(self, tile: Tile) -> Iterator[PointCloud]:
        hit = self._cache.get(tile.path)
        if hit is not None:
            self._cache.move_to_end(tile.path)
            yield hit
            return
        try:
            st = tile.path.stat()
        except FileNotFoundError:
            raise TileIOError(f"{tile.path}: file not found (it was indexed; rebuild the index)") from None
        if st.st_size != tile.size or st.st_mtime_ns != tile.mtime_ns:
            raise TileIOError(f"{tile.path}: the file changed since it was indexed; rebuild the index")
        kw = dict(crs=self.crs if tile.file_crs_wkt is None else None, columns=self._columns,
                  delimiter=self._delimiter)
        if tile.count <= self.max_cached_points:
            parts = list(iter_points(tile.path, self._chunk_size, **kw))
            cloud = PointCloud.concat(parts) if parts else PointCloud.empty(tile.attributes, self.crs)
            if cloud.crs is not self.crs and self.crs is not None:
                cloud = cloud.with_crs(self.crs)
            self._remember(tile.path, cloud)
            yield cloud
            return
        for chunk in iter_points(tile.path, self._chunk_size, **kw):
            yield chunk if chunk.crs is self.crs or self.crs is None else chunk.with_crs(self.crs)

    def _remember(self, path: Path, cloud: PointCloud) -> None:
        self._cache[path] = cloud
        self._cached_points += len(cloud)
        while self._cached_points > self.max_cached_points and len(self._cache) > 1:
            old_path, old = self._cache.popitem(last=False)
            self._grids.pop(old_path, None)
            self._cached_points -= len(old)
        if self._cached_points > self.max_cached_points:
            self.clear_cache()

    def clear_cache(self) -> None:
        """Forget the tiles kept in memory."""
        self._cache.clear()
        self._grids.clear()
        self._cached_points = 0

    def iter_points(self, tiles: Sequence[Tile] | None = None) -> Iterator[PointCloud]:
        """Stream the points of *tiles* (default all), chunk by chunk, in index order."""
        for t in self.tiles if tiles is None else tiles:
            yield from self._tile_chunks(t)

    def _query(self, box: tuple[float, float, float, float],
               mask_fn: Callable[[np.ndarray], np.ndarray]) -> PointCloud:
        parts: list[PointCloud] = []
        attrs: tuple[str, ...] | None = None
        for t in self.tiles_in_box(*box):
            attrs = t.attributes if attrs is None else tuple(a for a in attrs if a in t.attributes)
            cached = self._cache.get(t.path)
            if cached is not None and len(cached) > 0:
                self._cache.move_to_end(t.path)
                grid = self._grids.get(t.path)
                if grid is None:
                    grid = self._grids[t.path] = _CellGrid(cached.xyz)
                idx = grid.candidates(*box)
                idx = idx[mask_fn(cached.xyz[idx])]
                if len(idx):
                    parts.append(cached.select(idx))
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
        c = self._to_index_crs(np.asarray(center_en[:2], dtype=np.float64), crs)
        r = float(radius_m)
        return self._query((c[0] - r, c[1] - r, c[0] + r, c[1] + r), lambda xyz: in_radius(xyz, c, r))

    def query_box(self, xmin: float, ymin: float, xmax: float, ymax: float, crs: Any = None) -> PointCloud:
        """Points with ``xmin <= E <= xmax`` and ``ymin <= N <= ymax`` (metres).

        With *crs*, the four corners are transformed and their bounding box used.
        """
        if xmax < xmin or ymax < ymin:
            raise ValueError(f"empty box: x {xmin}..{xmax}, y {ymin}..{ymax}")
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
