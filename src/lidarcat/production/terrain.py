"""Terrain (DTM) and surface (DSM) models, nDSM, hillshade and the hypsometric image.

DTM by TIN interpolation
------------------------
The ground points (class 2) are triangulated (Delaunay, in plan) and every
cell centre :math:`q` takes the height of the plane of the triangle holding it,

.. math:: h(q) = \\lambda_0 h_0 + \\lambda_1 h_1 + \\lambda_2 h_2,

with :math:`\\lambda_i` its barycentric coordinates.  Gaps are reported, not
invented: a cell outside the triangulation, or inside a triangle with an edge
longer than ``max_edge_m`` (a lake, a building larger than that, a hole in the
data), is NaN and counted in :attr:`TinGrid.gap_cells`.

:func:`tin_grid` triangulates with OpenCV (``cv2.Subdiv2D``, five to six times
faster than Qhull on scattered points) and rasterises the triangles: each
lists the cell centres in its bounding box and keeps those with non-negative
barycentric coordinates, all at once in numpy.  :func:`tin_heights` (any
query points) triangulates with Qhull and locates each point by a vectorised
walk; both give the same heights except along the hull, where OpenCV drops a
few slivers (gaps, never invented heights).

Grid extent
-----------
A tile's grid covers its area (header bounds) clipped to the extent of its
points, never the header alone: a header's bounds are a claim (-1e308, inf,
or a 1 m box away from the points are all seen in the wild).  A point far
outside the bulk of the tile (:func:`lidarcat.lidar.raster.bulk_box`) is left
out with a warning that counts such points and names the farthest; a grid of
more than ``max_cells`` (``--max-cells``, default
:data:`lidarcat.lidar.raster.MAX_CELLS`) is refused before anything is
allocated; ``bounds`` (``--bounds``) clips every tile to an area.

DSM, nDSM
---------
The DSM is the highest first (or only) return per cell
(:func:`lidarcat.lidar.raster.rasterize` ``"dsm"``, small holes closed); the
normalised DSM is DSM minus DTM (heights above ground in metres).

Hillshade and hypsometric image
-------------------------------
Hillshade (Horn's slope, illumination from ``azimuth_deg`` clockwise from north
at ``altitude_deg`` above the horizon):

.. math:: s = \\cos z\\cos\\theta + \\sin z\\sin\\theta\\cos(a - \\phi),

clipped to [0, 1], :math:`z` the sun's zenith angle, :math:`\\theta` the slope,
:math:`\\phi` the aspect.  The hypsometric image of the report (section 11.4:
ortho-images coloured by height from the intensity, 45 cm) maps height linearly
between ``h_min_m`` and ``h_max_m`` onto a colour ramp and multiplies the colour
by the normalised intensity, :math:`rgb = c(h)\\,(w_0 + (1 - w_0) I)` with
:math:`I` the intensity stretched between its 2nd and 98th percentile and
:math:`w_0` = ``shade_floor``.

Output
------
:func:`write_product` writes grids and RGB images as GeoTIFF through
:func:`lidarcat.lidar.geotiff.write_geotiff`, the one raster writer (tiled
512 x 512, DEFLATE, cloud-optimised, nodata NaN, the CRS as given).
:func:`write_text_grid` writes the report's text format: one ``E N H`` line per
valued cell centre (section 11.3: the MDT/MDS "formato de texto").
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_write
from ..errors import ProductError
from ..geometry.tin import barycentric, find_simplex
from ..lidar.geotiff import GeoTransform, write_geotiff
from ..lidar.jobs import TileJob, read_with_buffer
from ..lidar.raster import Extent, check_grid_size, grid_for, robust_extent

__all__ = ["stats_tile", "TinGrid", "tin_grid", "dtm_grid", "dsm_grid", "ndsm", "hillshade", "hypsometric_image",
           "write_product", "write_text_grid", "tin_heights", "dtm_tile", "dsm_tile"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class TinGrid:
    """A grid interpolated on a TIN, with its gaps.

    Attributes
    ----------
    grid : ndarray, shape (rows, cols), float32
        Heights in metres; NaN in gaps.
    transform : GeoTransform
    gap_cells : int
        Cells left NaN (outside the TIN or under a triangle with an edge
        longer than ``max_edge_m``).
    """

    grid: np.ndarray
    transform: GeoTransform
    gap_cells: int

    @property
    def gap_fraction(self) -> float:
        """Fraction of the cells that are gaps."""
        return self.gap_cells / self.grid.size if self.grid.size else 0.0


def tin_heights(xyz: np.ndarray, q: np.ndarray, max_edge_m: float | None = None) -> np.ndarray:
    """Height of the TIN of *xyz* (N, 3) at plan points *q* (M, 2), metres; NaN in gaps.

    Examples
    --------
    >>> xyz = np.array([[0, 0, 0.0], [10, 0, 10.0], [0, 10, 0.0], [10, 10, 10.0]])
    >>> np.round(tin_heights(xyz, np.array([[5.0, 5.0], [2.5, 7.0], [20.0, 0.0]])), 9).tolist()
    [5.0, 2.5, nan]
    """
    from scipy.spatial import Delaunay, QhullError


    xyz = np.asarray(xyz, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    out = np.full(len(q), np.nan)
    if len(xyz) < 3 or len(q) == 0:
        return out
    origin = xyz[:, :2].min(axis=0)
    try:
        tri = Delaunay(xyz[:, :2] - origin)
    except QhullError:
        return out
    ql = q - origin
    s = find_simplex(tri, ql)
    ok = s >= 0
    simp = tri.simplices[s[ok]]
    if max_edge_m is not None:
        p = tri.points[simp]
        edges = np.stack([np.hypot(*(p[:, i] - p[:, (i + 1) % 3]).T) for i in range(3)], axis=1)
        short = edges.max(axis=1) <= max_edge_m
        idx = np.flatnonzero(ok)
        ok[idx[~short]] = False
        simp = simp[short]
    lam = barycentric(tri.points[simp], ql[ok])
    out[ok] = np.einsum("ij,ij->i", lam, xyz[simp, 2])
    return out


def _delaunay_simplices(xy: np.ndarray) -> np.ndarray:
    """Delaunay triangles (m, 3) of plan points *xy* (N, 2), as indices into *xy*.

    OpenCV's incremental Delaunay (:class:`cv2.Subdiv2D`, single precision, on
    coordinates relative to the points' corner and inserted cell by cell) is
    five to six times faster than Qhull on scattered points.  Its triangles
    are mapped back to the input by their exact float32 coordinates; points
    that coincide in float32 (closer than about 0.1 mm in a few-km tile) are
    one vertex.  Triangles that touch OpenCV's enclosing virtual vertices are
    dropped, so a few slivers along the convex hull are missing (gaps, never
    invented heights).
    """
    import cv2

    if len(xy) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    lo = xy.min(axis=0)
    p = np.ascontiguousarray(xy - lo, dtype=np.float32)
    span = float(p.max()) + 1.0
    cx = np.floor(p[:, 0] / 4.0).astype(np.int64)
    cy = np.floor(p[:, 1] / 4.0).astype(np.int64)
    order = np.argsort(cy * (int(cx.max()) + 1) + cx, kind="stable")  # spatial order: short walks
    big = int(math.ceil(4 * span))
    sub = cv2.Subdiv2D((-big, -big, 3 * big, 3 * big))
    sub.insert(p[order])
    corners = np.ascontiguousarray(sub.getTriangleList(), dtype=np.float32).reshape(-1, 3, 2)
    key = p.view(np.uint64).ravel()
    srt = np.argsort(key, kind="stable")
    ks = key[srt]
    tk = corners.view(np.uint64).reshape(-1, 3)
    pos = np.minimum(np.searchsorted(ks, tk), len(ks) - 1)
    hit = ks[pos] == tk
    return srt[pos[hit[:, 0] & hit[:, 1] & hit[:, 2]]]


def tin_grid(xyz: np.ndarray, cell_m: float, bounds: tuple[float, float, float, float] | None = None, *,
             max_edge_m: float | None = 50.0, chunk_cells: int = 4_000_000,
             max_cells: int | None = None) -> TinGrid:
    """Grid the TIN of points *xyz* at cell centres (see the module docstring).

    The triangles are rasterised rather than the cells located: each triangle
    lists the cell centres inside its bounding box (a few per triangle), and
    their barycentric coordinates, all computed at once with numpy, keep the
    centres inside it and give their heights.

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
        Points (E, N, h in metres), e.g. the ground.
    cell_m : float
        Cell size, metres.
    bounds : (xmin, ymin, xmax, ymax), optional
        Area, metres (default: the points' bounds); snapped to *cell_m*.
    max_edge_m : float or None
        Triangles with a longer edge are gaps (None: none).
    chunk_cells : int
        Candidate cells handled at once (bounds the memory, about 100 bytes each).
    max_cells : int, optional
        Largest grid (default :data:`lidarcat.lidar.raster.MAX_CELLS`).

    Raises
    ------
    ProductError
        A grid larger than *max_cells*, or non-finite bounds.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if bounds is None:
        if len(xyz) == 0:
            raise ValueError("cannot grid an empty point set without bounds")
        bounds = (*xyz[:, :2].min(axis=0), *xyz[:, :2].max(axis=0))
    transform, nrows, ncols = grid_for(bounds, cell_m, max_cells=max_cells)
    out = np.full(nrows * ncols, np.nan)
    simp = _delaunay_simplices(xyz[:, :2]) if len(xyz) >= 3 else np.zeros((0, 3), dtype=np.int64)
    if len(simp):
        # vertices in grid units: u = column, v = row of the cell whose centre they sit on
        u = (xyz[:, 0] - transform.x0) / cell_m - 0.5
        v = (transform.y0 - xyz[:, 1]) / cell_m - 0.5
        tu, tv = u[simp], v[simp]
        if max_edge_m is not None:
            e = np.stack([np.hypot(tu[:, i] - tu[:, (i + 1) % 3], tv[:, i] - tv[:, (i + 1) % 3])
                          for i in range(3)], axis=1) * cell_m
            keep = (e[:, 0] <= max_edge_m) & (e[:, 1] <= max_edge_m) & (e[:, 2] <= max_edge_m)
            simp, tu, tv = simp[keep], tu[keep], tv[keep]
        def lo(a: np.ndarray) -> np.ndarray:
            return np.minimum(np.minimum(a[:, 0], a[:, 1]), a[:, 2])

        def hi(a: np.ndarray) -> np.ndarray:
            return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])

        c0 = np.maximum(np.ceil(lo(tu)), 0).astype(np.int64)
        c1 = np.minimum(np.floor(hi(tu)), ncols - 1).astype(np.int64)
        r0 = np.maximum(np.ceil(lo(tv)), 0).astype(np.int64)
        r1 = np.minimum(np.floor(hi(tv)), nrows - 1).astype(np.int64)
        nx = np.maximum(c1 - c0 + 1, 0)
        count = nx * np.maximum(r1 - r0 + 1, 0)
        hit = np.flatnonzero(count)
        cum = np.cumsum(count[hit])
        start = 0
        while start < len(hit):
            stop = int(np.searchsorted(cum, (cum[start - 1] if start else 0) + chunk_cells, side="right"))
            stop = max(stop, start + 1)
            t = hit[start:stop]
            cnt = count[t]
            tri = np.repeat(np.arange(len(t)), cnt)
            k = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            col = c0[t][tri] + k % nx[t][tri]
            row = r0[t][tri] + k // nx[t][tri]
            corners = np.stack([tu[t], tv[t]], axis=2)[tri]
            lam = barycentric(corners, np.column_stack([col, row]).astype(np.float64))
            inside = (lam >= -1e-9).all(axis=1)
            h = np.einsum("ij,ij->i", lam[inside], xyz[simp[t][tri[inside]], 2])
            out[row[inside] * ncols + col[inside]] = h
            start = stop
    h = out.reshape(nrows, ncols).astype(np.float32)
    return TinGrid(h, transform, int(np.isnan(h).sum()))


def dtm_grid(cloud: Any, cell_m: float = 1.0, bounds: tuple[float, float, float, float] | None = None, *,
             max_edge_m: float | None = 50.0, ground: np.ndarray | None = None,
             max_cells: int | None = None) -> TinGrid:
    """DTM of a :class:`PointCloud` from its ground points (class 2, or the mask *ground*).

    Raises
    ------
    ProductError
        No ground points (classify first: ``lidarcat lidar ground``).
    """
    if ground is None:
        if not cloud.has("classification"):
            raise ProductError("the points carry no classification; classify the ground first "
                             "(lidarcat lidar ground)")
        ground = np.asarray(cloud.attributes["classification"]) == 2
    if not np.any(ground):
        raise ProductError("no ground points (class 2); classify the ground first (lidarcat lidar ground)")
    return tin_grid(cloud.xyz[ground], cell_m, bounds if bounds is not None else cloud.bounds[:4],
                    max_edge_m=max_edge_m, max_cells=max_cells)


def dsm_grid(cloud: Any, cell_m: float = 1.0, bounds: tuple[float, float, float, float] | None = None, *,
             max_cells: int | None = None) -> tuple[np.ndarray, GeoTransform]:
    """DSM: highest first return per cell, small holes closed (metres)."""
    from ..lidar.raster import rasterize

    return rasterize(cloud, cell_m, "dsm", bounds, max_cells=max_cells)


def ndsm(dsm: np.ndarray, dtm: np.ndarray) -> np.ndarray:
    """Normalised DSM: heights above the ground (metres), NaN where either is NaN."""
    if dsm.shape != dtm.shape:
        raise ValueError(f"DSM and DTM grids differ: {dsm.shape} vs {dtm.shape}")
    return (dsm - dtm).astype(np.float32)


def hillshade(grid: np.ndarray, cell_m: float, azimuth_deg: float = 315.0,
              altitude_deg: float = 45.0) -> np.ndarray:
    """Hillshade in [0, 1] (float32, NaN where the grid is NaN).

    Examples
    --------
    >>> flat = np.zeros((3, 3))
    >>> round(float(hillshade(flat, 1.0)[1, 1]), 6) == round(math.sin(math.radians(45)), 6)
    True
    """
    g = np.asarray(grid, dtype=np.float64)
    dzdy_rows, dzdx = np.gradient(g, cell_m)
    dzdy = -dzdy_rows  # rows run south
    slope = np.arctan(np.hypot(dzdx, dzdy))
    aspect = np.arctan2(-dzdx, -dzdy)  # direction of steepest descent, clockwise from north
    zen = math.radians(90.0 - altitude_deg)
    az = math.radians(azimuth_deg)
    s = math.cos(zen) * np.cos(slope) + math.sin(zen) * np.sin(slope) * np.cos(az - aspect)
    return np.clip(s, 0.0, 1.0).astype(np.float32)


def hypsometric_image(height: np.ndarray, intensity: np.ndarray | None, h_min_m: float | None = None,
                      h_max_m: float | None = None, *, cmap: str = "terrain",
                      shade_floor: float = 0.35) -> np.ndarray:
    """RGB image (rows, cols, 3) uint8: height colours times normalised intensity.

    Parameters
    ----------
    height : ndarray, shape (rows, cols)
        Heights, metres (DSM in the report).
    intensity : ndarray, shape (rows, cols), optional
        Mean intensity per cell; None: colours only.
    h_min_m, h_max_m : float, optional
        Colour range, metres (the report chose 60 and 460 for its area);
        default the 2nd and 98th percentile.
    cmap : str
        A matplotlib colour map.
    shade_floor : float
        Brightness of the lowest intensity, 0..1.

    Cells without height are black.
    """
    import matplotlib

    h = np.asarray(height, dtype=np.float64)
    fin = np.isfinite(h)
    if not fin.any():
        return np.zeros((*h.shape, 3), dtype=np.uint8)
    lo, hi = np.percentile(h[fin], [2, 98])
    lo = lo if h_min_m is None else h_min_m
    hi = hi if h_max_m is None else h_max_m
    if hi <= lo:
        hi = lo + 1.0
    t = np.clip((np.where(fin, h, lo) - lo) / (hi - lo), 0.0, 1.0)
    rgb = matplotlib.colormaps[cmap](t)[..., :3]
    if intensity is not None:
        i = np.asarray(intensity, dtype=np.float64)
        ifin = np.isfinite(i)
        if ifin.any():
            a, b = np.percentile(i[ifin], [2, 98])
            inorm = np.clip((np.where(ifin, i, a) - a) / max(b - a, 1e-9), 0.0, 1.0)
            rgb = rgb * (shade_floor + (1.0 - shade_floor) * inorm)[..., None]
    rgb[~fin] = 0.0
    return np.round(rgb * 255).astype(np.uint8)


def write_product(path: str | os.PathLike, array: np.ndarray, transform: GeoTransform, crs: Any = None) -> Path:
    """Write a grid (rows, cols) float or an RGB image (rows, cols, 3) uint8 as GeoTIFF, atomically.

    The one raster writer, :func:`lidarcat.lidar.geotiff.write_geotiff`: tiled
    512 x 512, DEFLATE, cloud-optimised, float grids as float32 with nodata
    NaN, the CRS as given (EPSG codes of compound CRSs kept).
    """
    return write_geotiff(path, array, transform, crs)


def write_text_grid(path: str | os.PathLike, grid: np.ndarray, transform: GeoTransform, *,
                    extra: np.ndarray | None = None, extra_name: str = "intensity", decimals: int = 3,
                    crs: Any = None) -> Path:
    """Write the report's text grid: a header, then ``E N H [extra]`` per valued cell centre (metres).

    With *crs* (anything :class:`pyproj.CRS` takes), its CRS goes into ``<name>.prj`` beside it
    (ESRI WKT, the sidecar GIS programs read for XYZ and ASCII grids), written first.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "mdt.txt"
    >>> _ = write_text_grid(p, np.array([[1.0, np.nan]]), GeoTransform(100.0, 200.0, 2.0))
    >>> p.read_text().splitlines()
    ['E N H', '101.000 199.000 1.000']
    """
    g = np.asarray(grid, dtype=np.float64)
    rows, cols = np.nonzero(np.isfinite(g))
    e, n = transform.xy(rows, cols)
    colsv = [e, n, g[rows, cols]]
    header = "E N H"
    if extra is not None:
        colsv.append(np.asarray(extra, dtype=np.float64)[rows, cols])
        header += f" {extra_name}"
    data = np.column_stack(colsv)
    path = Path(path)
    if crs is not None:
        from pyproj import CRS

        with atomic_write(path.with_suffix(".prj"), "w") as fh:
            fh.write(CRS.from_user_input(crs).to_wkt("WKT1_ESRI"))
    with atomic_write(path, "w") as fh:
        fh.write(header + "\n")
        np.savetxt(fh, data, fmt=f"%.{decimals}f", delimiter=" ")
    return path


# --------------------------------------------------------------------------- tile functions
def _raster_tile(job: TileJob, kind: str) -> None:
    """DTM or DSM of the tile's area (grid snapped to multiples of the cell), plus extras.

    Extras by ``job.params``: ``text`` (the report's E N H text grid, ``.txt``),
    ``hillshade`` (``<stem>_hillshade.tif``), ``ndsm`` (DSM jobs: ``<stem>_ndsm.tif``).
    """
    cloud, n_own = read_with_buffer(job)
    out = Path(job.output)
    cell = float(job.params.get("cell_m", 1.0))
    max_edge = job.params.get("max_edge_m", 50.0)
    max_cells = job.params.get("max_cells")
    cloud, area = _tile_area(job, cloud, n_own, cell, max_edge)
    nrows = math.ceil((area[3] - area[1]) / cell) + 1
    ncols = math.ceil((area[2] - area[0]) / cell) + 1
    check_grid_size(nrows, ncols, max_cells, where=str(job.tile), bounds=area, cell_m=cell)
    if kind == "dtm":
        res = dtm_grid(cloud, cell, area, max_edge_m=max_edge, max_cells=max_cells)
        grid, transform = res.grid, res.transform
        log.info("%s: DTM %d x %d cells, %d gap cells (%.1f %%)", job.tile, *grid.shape, res.gap_cells,
                 100 * res.gap_fraction)
    else:
        grid, transform = dsm_grid(cloud, cell, area, max_cells=max_cells)
    stem = out.with_suffix("")
    if job.params.get("hillshade"):
        write_product(Path(f"{stem}_hillshade.tif"), hillshade(grid, cell), transform, cloud.crs)
    if kind == "dsm" and job.params.get("ndsm"):
        dtm = dtm_grid(cloud, cell, area, max_edge_m=max_edge, max_cells=max_cells)
        write_product(Path(f"{stem}_ndsm.tif"), ndsm(grid, dtm.grid), transform, cloud.crs)
    if job.params.get("text"):
        write_text_grid(out.with_suffix(".txt"), grid, transform, crs=cloud.crs)
    write_product(out, grid, transform, cloud.crs)


def _tile_area(job: TileJob, cloud: Any, n_own: int, cell_m: float,
               max_edge_m: float | None) -> tuple[Any, tuple[float, float, float, float]]:
    """The points that may reach the tile's grid, and the grid's area (see "Grid extent").

    The area is the tile's header bounds clipped to the extent of its own points
    (the bulk: far outliers left out, with a warning), then to ``job.params["bounds"]``;
    the points kept are those within the overlap (or the longest TIN edge) of the area.
    """
    bx = job.bounds
    own = cloud.xyz[:n_own]
    user = job.params.get("bounds")
    if user is not None:   # the area asked for: nothing in it is an outlier
        ext = Extent(user)
        ext.add(own[:, 0], own[:, 1])
    else:
        ext = robust_extent(own[:, 0], own[:, 1], cell_m)
        if ext.n_out:
            log.warning("%s: %s; left out of the grid (give --bounds to grid them)", job.tile,
                        ext.describe_outliers("points of the tile"))
    header_ok = bool(np.isfinite(bx).all()) and bx[0] <= bx[2] and bx[1] <= bx[3]
    if ext.empty:   # no point of its own: the header's area, if it is one
        if not header_ok:
            raise ProductError(f"{job.tile}: the tile holds no points and its header's bounds "
                               f"({', '.join(f'{v:.6g}' for v in bx)}) are no area")
        area = tuple(map(float, bx))
    else:
        e = ext.bounds
        tol = 1e-3  # m: headers round their bounds
        if header_ok and bx[0] - tol <= e[0] and bx[1] - tol <= e[1] and bx[2] + tol >= e[2] and bx[3] + tol >= e[3]:
            area = (max(bx[0], e[0]), max(bx[1], e[1]), min(bx[2], e[2]), min(bx[3], e[3]))
        else:
            log.warning("%s: the header's bounds E %.3f..%.3f N %.3f..%.3f do not hold the points "
                        "(E %.3f..%.3f N %.3f..%.3f); the points' extent is gridded", job.tile,
                        bx[0], bx[2], bx[1], bx[3], e[0], e[2], e[1], e[3])
            area = e
    if user is not None:
        area = (max(area[0], user[0]), max(area[1], user[1]), min(area[2], user[2]), min(area[3], user[3]))
        if not (area[0] <= area[2] and area[1] <= area[3]):
            raise ProductError(f"{job.tile}: no part of the tile lies in the bounds E {user[0]:.3f}..{user[2]:.3f} "
                               f"N {user[1]:.3f}..{user[3]:.3f}")
    margin = max(float(job.overlap_m), float(max_edge_m or 0.0), cell_m)
    x, y = cloud.xyz[:, 0], cloud.xyz[:, 1]
    with np.errstate(invalid="ignore"):
        keep = ((x >= area[0] - margin) & (x <= area[2] + margin) & (y >= area[1] - margin)
                & (y <= area[3] + margin))
    if not keep.all():
        cloud = cloud.select(keep)
    return cloud, tuple(map(float, area))


def dtm_tile(job: TileJob) -> None:
    """Tile function (for :mod:`lidarcat.lidar.jobs`): the DTM of ``job.tile``'s area from its and its
    neighbours' ground points, as the GeoTIFF ``job.output``.

    ``job.params``: ``cell_m`` (default 1), ``max_edge_m`` (50), ``text``
    (also the E N H text grid ``<output>.txt``), ``hillshade`` (also
    ``<stem>_hillshade.tif``), ``bounds`` (clip to an area), ``max_cells``
    (largest grid; see "Grid extent" in the module docstring).
    """
    _raster_tile(job, "dtm")


def dsm_tile(job: TileJob) -> None:
    """Tile function (for :mod:`lidarcat.lidar.jobs`): the DSM of ``job.tile``'s area, as the GeoTIFF
    ``job.output``.

    ``job.params`` as :func:`dtm_tile`, and ``ndsm`` (also the DSM minus the
    DTM, ``<stem>_ndsm.tif``).
    """
    _raster_tile(job, "dsm")


def stats_tile(job: TileJob) -> None:
    """Tile function (for :mod:`lidarcat.lidar.jobs`): per-cell statistics of the tile's own points
    (:func:`lidarcat.lidar.raster.point_statistics`: min, max, mean, count, stdev bands), as the
    GeoTIFF ``job.output`` with named bands and the tile's CRS.

    ``job.params``: ``cell_m`` (default 1), ``values`` (``"z"``, default, or an attribute such as
    ``"intensity"``), ``classes`` (only points of these classes; default all but noise, class 7),
    ``bounds``, ``max_cells``.  The neighbours' points read within ``job.overlap_m`` (one cell)
    fill the cells on the seams, so a cell counts every point in it whichever tile it is cut from.
    """
    from ..lidar.geotiff import write_bands
    from ..lidar.raster import STAT_BANDS, point_statistics

    cloud, n_own = read_with_buffer(job)
    cell = float(job.params.get("cell_m", 1.0))
    cloud, area = _tile_area(job, cloud, n_own, cell, None)
    keep = np.ones(len(cloud), dtype=bool)
    cls = cloud.attributes.get("classification")
    classes = job.params.get("classes")
    if cls is not None:
        keep = np.isin(np.asarray(cls), classes) if classes else np.asarray(cls) != 7
    what = job.params.get("values", "z")
    if what != "z" and what not in cloud.attributes:
        raise ProductError(f"{job.tile}: no attribute {what!r} to take statistics of")
    vals = None if what == "z" else np.asarray(cloud.attributes[what], dtype=np.float64)[keep]
    bands, transform = point_statistics(cloud.xyz[keep], cell, area, values=vals,
                                        max_cells=job.params.get("max_cells"))
    write_bands(job.output, bands, transform, cloud.crs, STAT_BANDS)
