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

The Brazilian systematic map index (sheets such as ``SF-23-X-D-VI-1-SE-C-II``
at 1:5,000 and ``...-II-6`` at 1:2,000) is in :mod:`lidarcat.production.mapindex`;
its sheets are geographic rectangles, and the functions here accept them too
(with the CRS of the products): :func:`index_sheets` lists the sheets of
either index meeting an area, :func:`sheet_index_features` draws a Brazilian
sheet as its densified projected outline, :func:`cut_raster` and
:func:`cut_contours` cut in the sheet's geographic frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ProductError
from ..lidar.raster import GeoTransform
from ._clip import clip_lines, cut_grid
from .mapindex import MAX_SHEETS

__all__ = ["Sheet", "sheet_grid", "sheet_index_features", "cut_raster", "cut_contours", "index_sheets",
           "SHEET_INDEXES"]

#: sheet indexes of :func:`index_sheets` (``brazil-N``: the Brazilian index at 1:N)
SHEET_INDEXES = ("grid", "brazil-25000", "brazil-10000", "brazil-5000", "brazil-2000")


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
    if not (0 < width_m < math.inf and 0 < h < math.inf):
        raise ProductError(f"sheet size must be positive and finite, got {width_m} x {h} m")
    xmin, ymin, xmax, ymax = map(float, bounds)
    if not (math.isfinite(xmin) and math.isfinite(ymin) and math.isfinite(xmax) and math.isfinite(ymax)):
        raise ProductError(f"the area E {xmin:.6g}..{xmax:.6g} N {ymin:.6g}..{ymax:.6g} is not finite")
    n = ((xmax - xmin) / width_m + 2) * ((ymax - ymin) / h + 2)   # counted before any is made
    if n > MAX_SHEETS:
        raise ProductError(f"the area E {xmin:.6g}..{xmax:.6g} N {ymin:.6g}..{ymax:.6g} holds about {n:.3g} "
                           f"sheets of {width_m:g} x {h:g} m, more than {MAX_SHEETS:,}; a point far from "
                           "the others, or a larger sheet size?")
    i0, i1 = math.floor(xmin / width_m), max(math.ceil(xmax / width_m), math.floor(xmin / width_m) + 1)
    j0, j1 = math.floor(ymin / h), max(math.ceil(ymax / h), math.floor(ymin / h) + 1)
    out = []
    for j in range(j1 - 1, j0 - 1, -1):
        for i in range(i0, i1):
            x, y = i * width_m, j * h
            out.append(Sheet(f"E{x:.0f}_N{y:.0f}", x, y, x + width_m, y + h))
    return out


def index_sheets(bounds: tuple[float, float, float, float], index: str = "grid", *, crs: Any = None,
                 size_m: float = 1000.0, height_m: float | None = None,
                 geographic_crs: Any = None) -> list[Any]:
    """The sheets of *index* meeting the plan box *bounds* (metres, in *crs*).

    Parameters
    ----------
    bounds : (xmin, ymin, xmax, ymax)
    index : str
        ``"grid"``: :func:`sheet_grid` of *size_m* x *height_m*;
        ``"brazil-5000"``, ``"brazil-2000"`` (or another scale of
        :data:`lidarcat.production.mapindex.SCALES`): the Brazilian systematic
        index, :func:`lidarcat.production.mapindex.sheets_covering`.
    crs : CRS-like
        Projected CRS of *bounds* (needed by the Brazilian index).
    geographic_crs : CRS-like, optional
        Frame of the Brazilian index (default: the datum of *crs*).

    Raises
    ------
    ProductError
        An unknown index, or the Brazilian index without a CRS.
    """
    if index == "grid":
        return sheet_grid(bounds, size_m, height_m)
    from .mapindex import SCALES, sheets_covering

    scale = index[len("brazil-"):] if index.startswith("brazil-") else ""
    if not scale.isdigit() or int(scale) not in SCALES:
        raise ProductError(f"unknown sheet index {index!r}; use grid or brazil-N with N one of "
                         f"{', '.join(map(str, SCALES))}")
    if crs is None:
        raise ProductError(f"the {index} sheet index needs the CRS of the products")
    return sheets_covering(bounds, crs, int(scale), geographic_crs=geographic_crs)


def sheet_index_features(sheets: list[Any], crs: Any = None) -> list[dict[str, Any]]:
    """The sheet index layer: one closed counter-clockwise Polygon per sheet, with name and bounds.

    A Brazilian sheet (:class:`lidarcat.production.mapindex.MapSheet`) is drawn in
    the projected *crs* as its densified outline, with its scale and its
    geographic bounds (degrees) as properties.
    """
    from .mapindex import MapSheet, sheet_outline

    out = []
    for s in sheets:
        if isinstance(s, MapSheet):
            if crs is None:
                raise ProductError(f"sheet {s.name}: drawing a geographic sheet needs the CRS of the layer")
            ring = np.round(sheet_outline(s, crs), 3)
            out.append({"type": "Feature",
                        "properties": {"name": s.name, "scale": s.scale, "west_deg": s.west, "south_deg": s.south,
                                       "east_deg": s.east, "north_deg": s.north},
                        "geometry": {"type": "Polygon", "coordinates": [ring.tolist()]}})
            continue
        out.append({"type": "Feature",
                    "properties": {"name": s.name, "xmin": s.xmin, "ymin": s.ymin, "xmax": s.xmax, "ymax": s.ymax},
                    "geometry": {"type": "Polygon", "coordinates": [[[s.xmin, s.ymin], [s.xmax, s.ymin],
                                                                     [s.xmax, s.ymax], [s.xmin, s.ymax],
                                                                     [s.xmin, s.ymin]]]}})
    return out


def cut_raster(grid: np.ndarray, transform: GeoTransform, sheet: Any,
               crs: Any = None) -> tuple[np.ndarray, GeoTransform] | None:
    """The part of *grid* whose cell centres lie in *sheet* (None when empty).

    A Brazilian sheet needs the grid's *crs*; cells of its bounding box
    outside the sheet are NaN (see :func:`lidarcat.production.mapindex.cut_raster_geo`).

    Examples
    --------
    >>> g = np.arange(16.0).reshape(4, 4)
    >>> sub, t = cut_raster(g, GeoTransform(0.0, 4.0, 1.0), Sheet("s", 2.0, 0.0, 4.0, 2.0))
    >>> sub.tolist(), t
    ([[10.0, 11.0], [14.0, 15.0]], GeoTransform(x0=2.0, y0=2.0, cell_m=1.0))
    """
    from .mapindex import MapSheet, cut_raster_geo

    if isinstance(sheet, MapSheet):
        if crs is None:
            raise ProductError(f"sheet {sheet.name}: cutting along a geographic sheet needs the grid's CRS")
        return cut_raster_geo(grid, transform, sheet, crs)
    return cut_grid(grid, transform, sheet)


def cut_contours(features: list[dict[str, Any]], sheet: Any, crs: Any = None) -> list[dict[str, Any]]:
    """Contour LineStrings clipped to *sheet*: the runs of vertices inside it (edge crossings added).

    A line leaving and re-entering the sheet becomes several pieces; a closed
    ring wholly inside stays closed.  A Brazilian sheet needs the lines' *crs*
    (they are clipped in the sheet's geographic frame).
    """
    from .mapindex import MapSheet, cut_contours_geo

    if isinstance(sheet, MapSheet):
        if crs is None:
            raise ProductError(f"sheet {sheet.name}: cutting along a geographic sheet needs the lines' CRS")
        return cut_contours_geo(features, sheet, crs)
    return clip_lines(features, sheet)
