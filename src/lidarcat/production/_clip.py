"""Rectangles cut out of grids and line layers (shared by :mod:`.sheets` and :mod:`.mapindex`).

A *box* is anything with ``xmin``, ``ymin``, ``xmax``, ``ymax`` (a
:class:`~lidarcat.production.sheets.Sheet`, a
:class:`~lidarcat.production.mapindex.MapSheet` in degrees, a :class:`Box`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from ..lidar.raster import GeoTransform

__all__ = ["Box", "cut_grid", "clip_lines"]


class Box(NamedTuple):
    """A plan rectangle (any units)."""

    xmin: float
    ymin: float
    xmax: float
    ymax: float


def cut_grid(grid: np.ndarray, transform: GeoTransform, box: Any) -> tuple[np.ndarray, GeoTransform] | None:
    """The part of *grid* (rows, cols[, bands]) whose cell centres lie in *box* (same units), and its transform.

    A centre on the west or north edge is in, on the east or south edge out;
    None when no centre lies in the box.
    """
    c = transform.cell_m
    nrows, ncols = grid.shape[:2]
    c0 = max(0, math.ceil((box.xmin - transform.x0) / c - 0.5))
    c1 = min(ncols, math.ceil((box.xmax - transform.x0) / c - 0.5))
    r0 = max(0, math.ceil((transform.y0 - box.ymax) / c - 0.5))
    r1 = min(nrows, math.ceil((transform.y0 - box.ymin) / c - 0.5))
    if c1 <= c0 or r1 <= r0:
        return None
    return grid[r0:r1, c0:c1], GeoTransform(transform.x0 + c0 * c, transform.y0 - r0 * c, c)


def clip_lines(features: list[dict[str, Any]], box: Any) -> list[dict[str, Any]]:
    """LineString features clipped to the rectangle xmin..xmax, ymin..ymax of *box* (any frame).

    A line leaving and re-entering the box becomes several pieces; the
    ``closed`` property stays true only for a ring wholly inside.
    """
    out = []
    for f in features:
        xy = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
        pieces = _clip_polyline(xy, box)
        for p in pieces:
            props = dict(f["properties"])
            props["closed"] = bool(props.get("closed")) and len(pieces) == 1 and len(p) == len(xy)
            out.append({"type": "Feature", "properties": props,
                        "geometry": {"type": "LineString", "coordinates": p.tolist()}})
    return out


def _clip_polyline(xy: np.ndarray, s: Any) -> list[np.ndarray]:
    """Liang-Barsky clip of every segment, then chain consecutive visible pieces."""
    pieces: list[list[np.ndarray]] = []
    cur: list[np.ndarray] = []
    for a, b in zip(xy[:-1], xy[1:]):
        seg = _clip_segment(a, b, s)
        if seg is None:
            if cur:
                pieces.append(cur)
                cur = []
            continue
        p, q = seg
        if cur and np.all(cur[-1] == p):
            cur.append(q)
        else:
            if cur:
                pieces.append(cur)
            cur = [p, q]
        if not np.all(q == b):  # left the sheet
            pieces.append(cur)
            cur = []
    if cur:
        pieces.append(cur)
    return [np.array(p) for p in pieces if len(p) >= 2]


def _clip_segment(a: np.ndarray, b: np.ndarray, s: Any) -> tuple[np.ndarray, np.ndarray] | None:
    d = b - a
    t0, t1 = 0.0, 1.0
    for p, q in ((-d[0], a[0] - s.xmin), (d[0], s.xmax - a[0]), (-d[1], a[1] - s.ymin), (d[1], s.ymax - a[1])):
        if p == 0:
            if q < 0:
                return None
            continue
        t = q / p
        if p < 0:
            t0 = max(t0, t)
        else:
            t1 = min(t1, t)
        if t0 > t1:
            return None
    return (a if t0 == 0 else a + t0 * d), (b if t1 == 1 else a + t1 * d)
