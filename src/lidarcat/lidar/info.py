"""Summaries of point files: counts, bounds, CRS, density, classes, returns.

Density is points per square metre of *covered* ground: the number of points
divided by the area of the 1 m cells holding at least one point (coarser cells
for very large files, so the occupancy grid stays under 50 million cells).
Dividing by the bounding box instead under-states it for irregular crops.

The grid is laid over the header's bounds; when a point falls outside them
(a header that lies, max < min, a bound of 1e308) the file is read a second
time over the points' own bounds, and ``header_bounds_ok`` is False.  Density
needs a CRS in metres: for a geographic (degrees) or foot-based CRS it is
``None`` (a degree is not a metre); with no CRS metres are assumed.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .cloud import Bounds
from .crs import common_crs, crs_label, units_are_metres
from .readers import MAX_ABS_COORD_M, iter_points, read_header
from .tiles import expand_paths

__all__ = ["describe", "describe_file"]

log = logging.getLogger(__name__)

_MAX_CELLS = 50_000_000


def describe_file(path: str | os.PathLike, *, crs: Any = None, columns: Any = None,
                  delimiter: str | None = None, chunk_size: int | None = None,
                  progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """Scan one point file and summarise it (see :func:`describe` for the keys).

    Raises
    ------
    TileIOError, LidarFormatError, CRSError
        As :func:`lidarcat.lidar.iter_points`.
    """
    return _describe_file(Path(path), crs, columns, delimiter, chunk_size, progress)[0]


def _grid_for(b: Bounds) -> tuple[float, int, int] | None:
    """(cell, columns, rows) of the occupancy grid over plan bounds *b*; None when *b* is unusable
    (NaN, max < min, or beyond the sane coordinate range)."""
    box = np.array(b[:4], dtype=np.float64)
    if not (np.isfinite(box).all() and b.xmin <= b.xmax and b.ymin <= b.ymax
            and np.abs(box).max() <= MAX_ABS_COORD_M):
        return None
    cell = 1.0
    while ((b.xmax - b.xmin) / cell + 1) * ((b.ymax - b.ymin) / cell + 1) > _MAX_CELLS:
        cell *= 2.0
    return cell, int((b.xmax - b.xmin) // cell) + 1, int((b.ymax - b.ymin) // cell) + 1


def _scan(path: Path, crs: Any, columns: Any, delimiter: str | None, chunk_size: int | None,
          progress: Callable[[int], Any] | None, b: Bounds, grid: tuple[float, int, int] | None
          ) -> dict[str, Any]:
    """One pass over the points: counts, bounds, classes, returns and, when *grid* is given,
    the occupied cells; ``outside`` says a point fell outside *b* (the grid is then wrong)."""
    count = first = 0
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    classes = np.zeros(256, dtype=np.int64)
    returns = np.zeros(16, dtype=np.int64)
    has_class = has_ret = outside = False
    occupied = None
    if grid is not None:
        cell, ncols, nrows = grid
        occupied = np.zeros(nrows * ncols, dtype=bool)
    for c in iter_points(path, chunk_size, crs=crs, columns=columns, delimiter=delimiter,
                         progress=progress):
        if len(c) == 0:
            continue
        count += len(c)
        lo = np.minimum(lo, c.xyz.min(axis=0))
        hi = np.maximum(hi, c.xyz.max(axis=0))
        if occupied is not None and not outside:
            fc = (c.x - b.xmin) // cell
            fr = (c.y - b.ymin) // cell
            if fc.min() < 0 or fc.max() >= ncols or fr.min() < 0 or fr.max() >= nrows:
                outside = True  # the header's bounds do not hold the points
            else:
                occupied[fr.astype(np.int64) * ncols + fc.astype(np.int64)] = True
        first += int(c.first_returns().sum())
        if c.has("classification"):
            has_class = True
            classes += np.bincount(c.attributes["classification"], minlength=256)[:256]
        if c.has("return_number"):
            has_ret = True
            returns += np.bincount(np.minimum(c.attributes["return_number"], 15), minlength=16)[:16]
    return {"count": count, "first": first, "lo": lo, "hi": hi, "classes": classes if has_class else None,
            "returns": returns if has_ret else None, "outside": outside or occupied is None,
            "area": float(occupied.sum()) * grid[0] ** 2 if occupied is not None else 0.0,
            "cell": grid[0] if grid is not None else 1.0}


def _describe_file(path: Path, crs: Any, columns: Any, delimiter: str | None, chunk_size: int | None,
                   progress: Callable[[int], Any] | None) -> tuple[dict[str, Any], Any]:
    head = read_header(path, crs=crs, columns=columns, delimiter=delimiter)
    grid = _grid_for(head.bounds) if head.count else None
    r = _scan(path, crs, columns, delimiter, chunk_size, progress, head.bounds, grid)
    count = r["count"]
    bounds = Bounds.from_minmax(r["lo"] if count else None, r["hi"])
    header_ok = bool(count == 0 or not r["outside"])
    own = _grid_for(bounds) if count else None
    if count and (r["outside"] or (own is not None and own[0] < r["cell"])):
        # the header's bounds are wrong, unusable or far too wide (a coarser grid than the points
        # need): grid the points' own bounds in a second pass
        if r["outside"]:
            log.warning("%s: the header's bounds %s do not hold the points %s; density from a second "
                        "pass", path, tuple(round(v, 3) for v in head.bounds[:4]),
                        tuple(round(v, 3) for v in bounds[:4]))
        r = _scan(path, crs, columns, delimiter, chunk_size, None, bounds, own)
    area = r["area"]
    density_ok = units_are_metres(head.crs)
    classes, returns = r["classes"], r["returns"]
    return {
        "path": str(path),
        "format": head.description,
        "points": count,
        "header_points": head.count,
        "header_bounds_ok": header_ok,
        "bounds": bounds._asdict(),
        "crs": crs_label(head.crs) if head.crs is not None else None,
        "crs_from_file": head.crs_from_file,
        "covered_area_m2": area if density_ok else None,
        "density_cell_m": r["cell"],
        "density_pts_m2": count / area if area and density_ok else None,
        "first_return_density_pts_m2": (r["first"] / area if area and density_ok and returns is not None
                                        else None),
        "classes": {str(k): int(v) for k, v in enumerate(classes) if v} if classes is not None else None,
        "returns": {str(k): int(v) for k, v in enumerate(returns) if v} if returns is not None else None,
        "attributes": list(head.attributes),
        "density_note": None if density_ok else f"no density: {crs_label(head.crs)} is not in metres",
    }, head.crs


def describe(paths: str | os.PathLike | Iterable[str | os.PathLike], *, crs: Any = None,
             columns: Sequence[str] | str | None = None, delimiter: str | None = None,
             progress: Callable[[int], Any] | None = None) -> dict[str, Any]:
    """Summarise point files (each scanned once, chunk by chunk).

    Returns
    -------
    dict
        ``files``: one dict per file with ``path``, ``format``, ``points``,
        ``bounds`` (xmin, ymin, xmax, ymax, zmin, zmax, metres), ``crs``,
        ``crs_from_file``, ``covered_area_m2``, ``density_pts_m2``,
        ``first_return_density_pts_m2``, ``classes`` ({code: count}),
        ``returns`` ({return number: count}), ``attributes``;
        ``total``: ``points``, ``bounds``, ``crs``, ``covered_area_m2``,
        ``density_pts_m2``, ``classes``, ``returns`` over all files.

    Raises
    ------
    TileIOError, LidarFormatError, CRSError
        A file is missing or bad; files of different CRSs.
    """
    done = [_describe_file(p, crs, columns, delimiter, None, progress) for p in expand_paths(paths)]
    files = [f for f, _ in done]
    common = common_crs([(f["path"], c) for f, c in done])
    total: dict[str, Any] = {"points": sum(f["points"] for f in files),
                             "crs": crs_label(common) if common is not None else None}
    with_pts = [f for f in files if f["points"]]
    if with_pts:
        total["bounds"] = Bounds.union(f["bounds"].values() for f in with_pts)._asdict()
    area = sum(f["covered_area_m2"] or 0.0 for f in files)
    total["covered_area_m2"] = area
    total["density_pts_m2"] = total["points"] / area if area else None
    for key in ("classes", "returns"):
        merged: dict[str, int] = {}
        for f in files:
            for k, v in (f[key] or {}).items():
                merged[k] = merged.get(k, 0) + v
        total[key] = dict(sorted(merged.items(), key=lambda kv: int(kv[0]))) or None
    return {"files": files, "total": total}
