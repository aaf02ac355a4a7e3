"""Map sheets: a regular sheet grid (the report's "articulação"), its index layer, products cut per sheet.

The LACTEC report (sections 11.3 and 13.3) cuts every product along a
predefined sheet layout: 66 sheets, one DTM, DSM, hypsometric image and
contour plate each.  Here a sheet grid is regular: squares (or rectangles) of
``width_m`` x ``height_m`` aligned to multiples of the size in the projected
CRS, so that neighbouring surveys share sheet edges.  A sheet is named by its
south-west corner, ``E<easting>_N<northing>`` in whole metres.

:func:`sheet_grid` lists the sheets meeting an area; :func:`sheet_index_features`
gives the index layer (GeoJSON polygons, closed, counter-clockwise);
:func:`cut_raster` slices a grid to a sheet (cells whose centre lies in the
sheet; the grid's cell must divide the sheet size for exact edges);
:func:`cut_contours` keeps the contour pieces inside a sheet.

The Brazilian systematic map index (MI numbers of 1:5,000 and 1:2,000 sheets)
is not implemented.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .raster import GeoTransform

__all__ = ["Sheet", "sheet_grid", "sheet_index_features", "cut_raster", "cut_contours"]


@dataclass(frozen=True)
class Sheet:
    """One map sheet: name and bounds (xmin, ymin, xmax, ymax) in metres."""

    name: str
    xmin: float
    ymin: float
    xmax: float
    ymax: float


def sheet_grid(bounds: tuple[float, float, float, float], width_m: float,
               height_m: float | None = None) -> list[Sheet]:
    """Sheets of *width_m* x *height_m* (default square) meeting *bounds*, west to east, north to south.

    Examples
    --------
    >>> [s.name for s in sheet_grid((85000, 447400, 85150, 447600), 100)]
    ['E85000_N447500', 'E85100_N447500', 'E85000_N447400', 'E85100_N447400']
    """
    h = width_m if height_m is None else height_m
    if not (width_m > 0 and h > 0):
        raise ValueError(f"sheet size must be positive, got {width_m} x {h}")
    xmin, ymin, xmax, ymax = map(float, bounds)
    i0, i1 = math.floor(xmin / width_m), max(math.ceil(xmax / width_m), math.floor(xmin / width_m) + 1)
    j0, j1 = math.floor(ymin / h), max(math.ceil(ymax / h), math.floor(ymin / h) + 1)
    out = []
    for j in range(j1 - 1, j0 - 1, -1):
        for i in range(i0, i1):
            x, y = i * width_m, j * h
            out.append(Sheet(f"E{x:.0f}_N{y:.0f}", x, y, x + width_m, y + h))
    return out


def sheet_index_features(sheets: list[Sheet]) -> list[dict[str, Any]]:
    """The sheet index layer: one closed counter-clockwise Polygon per sheet, with name and bounds."""
    return [{"type": "Feature",
             "properties": {"name": s.name, "xmin": s.xmin, "ymin": s.ymin, "xmax": s.xmax, "ymax": s.ymax},
             "geometry": {"type": "Polygon", "coordinates": [[[s.xmin, s.ymin], [s.xmax, s.ymin], [s.xmax, s.ymax],
                                                              [s.xmin, s.ymax], [s.xmin, s.ymin]]]}}
            for s in sheets]


def cut_raster(grid: np.ndarray, transform: GeoTransform, sheet: Sheet) -> tuple[np.ndarray, GeoTransform] | None:
    """The part of *grid* whose cell centres lie in *sheet* (None when empty).

    Examples
    --------
    >>> g = np.arange(16.0).reshape(4, 4)
    >>> sub, t = cut_raster(g, GeoTransform(0.0, 4.0, 1.0), Sheet("s", 2.0, 0.0, 4.0, 2.0))
    >>> sub.tolist(), t
    ([[10.0, 11.0], [14.0, 15.0]], GeoTransform(x0=2.0, y0=2.0, cell_m=1.0))
    """
    c = transform.cell_m
    nrows, ncols = grid.shape[:2]
    c0 = max(0, math.ceil((sheet.xmin - transform.x0) / c - 0.5))
    c1 = min(ncols, math.ceil((sheet.xmax - transform.x0) / c - 0.5))
    r0 = max(0, math.ceil((transform.y0 - sheet.ymax) / c - 0.5))
    r1 = min(nrows, math.ceil((transform.y0 - sheet.ymin) / c - 0.5))
    if c1 <= c0 or r1 <= r0:
        return None
    return grid[r0:r1, c0:c1], GeoTransform(transform.x0 + c0 * c, transform.y0 - r0 * c, c)


def cut_contours(features: list[dict[str, Any]], sheet: Sheet) -> list[dict[str, Any]]:
    """Contour LineStrings clipped to *sheet*: the runs of vertices inside it (edge crossings added).

    A line leaving and re-entering the sheet becomes several pieces; a closed
    ring wholly inside stays closed.
    """
    out = []
    for f in features:
        xy = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
        pieces = _clip_polyline(xy, sheet)
        for p in pieces:
            props = dict(f["properties"])
            props["closed"] = bool(props.get("closed")) and len(pieces) == 1 and len(p) == len(xy)
            out.append({"type": "Feature", "properties": props,
                        "geometry": {"type": "LineString", "coordinates": p.tolist()}})
    return out


def _clip_polyline(xy: np.ndarray, s: Sheet) -> list[np.ndarray]:
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


def _clip_segment(a: np.ndarray, b: np.ndarray, s: Sheet) -> tuple[np.ndarray, np.ndarray] | None:
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
