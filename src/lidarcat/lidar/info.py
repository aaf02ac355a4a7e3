"""Summaries of point files: counts, bounds, CRS, density, classes, returns.

Density is points per square metre of *covered* ground: the number of points
divided by the area of the 1 m cells holding at least one point (coarser cells
for very large files, so the occupancy grid stays under 50 million cells).
Dividing by the bounding box instead under-states it for irregular crops.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .cloud import Bounds
from .crs import common_crs, crs_label
from .readers import iter_points, read_header
from .tileindex import expand_paths

__all__ = ["describe", "describe_file"]

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


def _describe_file(path: Path, crs: Any, columns: Any, delimiter: str | None, chunk_size: int | None,
                   progress: Callable[[int], Any] | None) -> tuple[dict[str, Any], Any]:
    head = read_header(path, crs=crs, columns=columns, delimiter=delimiter)
    b = head.bounds
    cell = 1.0
    if head.count and np.isfinite(b.area_m2):
        while ((b.xmax - b.xmin) / cell + 1) * ((b.ymax - b.ymin) / cell + 1) > _MAX_CELLS:
            cell *= 2.0
    ncols = int((b.xmax - b.xmin) // cell) + 1 if head.count else 1
    nrows = int((b.ymax - b.ymin) // cell) + 1 if head.count else 1
    occupied = np.zeros(nrows * ncols, dtype=bool)
    count = first = 0
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    classes = np.zeros(256, dtype=np.int64)
    returns = np.zeros(16, dtype=np.int64)
    has_class = has_ret = False
    for c in iter_points(path, chunk_size, crs=crs, columns=columns, delimiter=delimiter,
                         progress=progress):
        count += len(c)
        lo = np.minimum(lo, c.xyz.min(axis=0))
        hi = np.maximum(hi, c.xyz.max(axis=0))
        col = np.clip(((c.x - b.xmin) // cell).astype(np.int64), 0, ncols - 1)
        row = np.clip(((c.y - b.ymin) // cell).astype(np.int64), 0, nrows - 1)
        occupied[row * ncols + col] = True
        first += int(c.first_returns().sum())
        if c.has("classification"):
            has_class = True
            classes += np.bincount(c.attributes["classification"], minlength=256)[:256]
        if c.has("return_number"):
            has_ret = True
            returns += np.bincount(np.minimum(c.attributes["return_number"], 15), minlength=16)[:16]
    area = float(occupied.sum()) * cell * cell
    bounds = Bounds.from_minmax(lo if count else None, hi)
    return {
        "path": str(path),
        "format": head.description,
        "points": count,
        "header_points": head.count,
        "bounds": bounds._asdict(),
        "crs": crs_label(head.crs) if head.crs is not None else None,
        "crs_from_file": head.crs_from_file,
        "covered_area_m2": area,
        "density_cell_m": cell,
        "density_pts_m2": count / area if area else None,
        "first_return_density_pts_m2": first / area if area and has_ret else None,
        "classes": {str(k): int(v) for k, v in enumerate(classes) if v} if has_class else None,
        "returns": {str(k): int(v) for k, v in enumerate(returns) if v} if has_ret else None,
        "attributes": list(head.attributes),
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
    area = sum(f["covered_area_m2"] for f in files)
    total["covered_area_m2"] = area
    total["density_pts_m2"] = total["points"] / area if area else None
    for key in ("classes", "returns"):
        merged: dict[str, int] = {}
        for f in files:
            for k, v in (f[key] or {}).items():
                merged[k] = merged.get(k, 0) + v
        total[key] = dict(sorted(merged.items(), key=lambda kv: int(kv[0]))) or None
    return {"files": files, "total": total}
