"""Raster views of LiDAR points: intensity image, surface model (DSM), terrain (DTM).

These are what an operator needs to find roofs (thesis section 3.2.2: the
approximate vertex position is picked on the LiDAR intensity image) and what
monorestitution needs as a surface model.

Grids
-----
A grid is a float32 array, row 0 at the north edge, NaN where there is no
value.  Its :class:`GeoTransform` gives the west and north edges and the
square cell size in metres; cell ``(row, col)`` covers
``x0 + col*cell .. x0 + (col+1)*cell`` and ``y0 - (row+1)*cell .. y0 - row*cell``.

``what``:

``"intensity"``  mean intensity of the first (or only) returns in the cell;
``"dsm"``        highest first (or only) return in the cell;
``"dtm"``        lowest ground point (class 2) in the cell when the data are
                 classified and hold ground points, else lowest last return.

Holes (``fill=``): ``"small"`` (default for intensity and DSM) gives a cell
without points whose 8-neighbourhood holds at least 5 valued cells their
mean, repeated ``fill_iterations`` times: gaps of a few cells inside the data
close, the outline of the data does not grow.  ``"interpolate"`` (default for
DTM) fills every hole inside the convex hull of the valued cells (ground under
buildings) by linear interpolation (Delaunay) between cell centres: a planar
terrain stays planar; nothing is extrapolated outside the hull.

Files
-----
The grids are written and read by :mod:`lidarcat.lidar.geotiff` (rasterio:
tiled, DEFLATE-compressed, cloud-optimised GeoTIFF, the CRS as given);
:func:`write_raster` adds a PNG preview.  :class:`GeoTransform`,
:func:`write_geotiff` and :func:`read_geotiff` stay importable from here.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_write
from ..errors import LidarFormatError, ProductError
from .cloud import PointCloud
from .geotiff import GeoTransform, read_geotiff, write_geotiff

__all__ = ["STAT_BANDS", "point_statistics", "GeoTransform", "rasterize", "write_geotiff", "read_geotiff", "write_png_preview",
           "write_raster", "grid_for", "RASTER_KINDS", "MAX_CELLS", "Extent", "bulk_box", "robust_extent",
           "check_grid_size", "stream_extent"]

RASTER_KINDS = ("intensity", "dsm", "dtm")

#: Default largest grid, cells (10 km x 10 km at 1 m: about 0.4 GB as float32, some 2 GB while
#: it is computed); larger grids need an explicit ``max_cells`` (``--max-cells``).
MAX_CELLS = 100_000_000

#: Percentiles of the bulk of the data (see :func:`bulk_box`).
_BULK_PERCENTILES = (1.0, 99.0)

_ESCAPE = ("give the area to grid (--bounds XMIN YMIN XMAX YMAX), a coarser cell, or a larger --max-cells")


# --------------------------------------------------------------------------- grid extents
def bulk_box(x: np.ndarray, y: np.ndarray, cell_m: float) -> tuple[float, float, float, float]:
    """The box beyond which a point lies far outside the bulk of the data.

    The box of the 1st..99th percentiles of E and N grown on each side by its own
    width and by 10 cells: every point of a tile, a strip or a block lies inside it;
    a displaced point (a bird, a GNSS glitch, a byte flip) kilometres away does not.
    Fewer than 100 points: their whole box (no percentile can tell an outlier).
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) == 0:
        return (np.inf, np.inf, -np.inf, -np.inf)
    pad = 10.0 * float(cell_m)
    out = []
    for v in (x, y):
        lo = float(np.percentile(v, _BULK_PERCENTILES[0], method="lower"))
        hi = float(np.percentile(v, _BULK_PERCENTILES[1], method="higher"))
        w = hi - lo
        out.append((lo - w - pad, hi + w + pad))
    return (out[0][0], out[1][0], out[0][1], out[1][1])


class Extent:
    """The extent of the points inside a :func:`bulk_box`, and what lies outside it.

    Attributes
    ----------
    bounds : (xmin, ymin, xmax, ymax)
        Extent of the kept points, metres (infinite when none).
    box : (xmin, ymin, xmax, ymax)
        The bulk box: points outside it are left out.
    n_out : int
        Points left out (outside the box, or with a non-finite coordinate).
    farthest : (x, y) or None
        The left-out point farthest from the bulk.
    """

    def __init__(self, box: tuple[float, float, float, float]) -> None:
        self.box = tuple(map(float, box))
        self.bounds = (np.inf, np.inf, -np.inf, -np.inf)
        self.n_out = 0
        self.farthest: tuple[float, float] | None = None
        self._far_d = -2.0

    def add(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Take points into the extent; return the mask of those inside the box."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        bx0, by0, bx1, by1 = self.box
        with np.errstate(invalid="ignore"):
            m = (x >= bx0) & (x <= bx1) & (y >= by0) & (y <= by1)
        if m.any():
            xs, ys = x[m], y[m]
            b = self.bounds
            self.bounds = (min(b[0], float(xs.min())), min(b[1], float(ys.min())),
                           max(b[2], float(xs.max())), max(b[3], float(ys.max())))
        out = ~m
        if out.any():
            self.n_out += int(out.sum())
            cx, cy = (bx0 + bx1) / 2, (by0 + by1) / 2
            with np.errstate(invalid="ignore", over="ignore"):
                d = np.abs(x[out] - cx) + np.abs(y[out] - cy)
            d = np.where(np.isnan(d), -1.0, d)   # name a finite point when there is one
            k = int(np.argmax(d))
            if float(d[k]) > self._far_d:
                self._far_d = float(d[k])
                self.farthest = (float(x[out][k]), float(y[out][k]))
        return m

    @property
    def empty(self) -> bool:
        return not self.bounds[0] <= self.bounds[2]

    def describe_outliers(self, what: str = "points") -> str:
        """``"N points far outside the bulk of the data (E..N..), the farthest at E x N y"``."""
        bx0, by0, bx1, by1 = self.box
        far = "" if self.farthest is None else f", the farthest at E {self.farthest[0]:.6g} N {self.farthest[1]:.6g}"
        verb = "lie" if self.n_out != 1 else "lies"
        if self.n_out == 1 and what.startswith("points"):
            what = "point" + what[len("points"):]
        return (f"{self.n_out} {what} {verb} far outside the bulk of the data (E {bx0:.3f}..{bx1:.3f} "
                f"N {by0:.3f}..{by1:.3f}){far}")


def robust_extent(x: np.ndarray, y: np.ndarray, cell_m: float) -> Extent:
    """The :class:`Extent` of points *x*, *y* inside their :func:`bulk_box`."""
    ext = Extent(bulk_box(x, y, cell_m))
    ext.add(x, y)
    return ext


def stream_extent(chunks: Callable[[], Iterable[PointCloud]], cell_m: float, n_points: int,
                  sample_points: int = 1_000_000) -> Extent:
    """The :class:`Extent` of a stream of chunks, reading it once or, when points lie far out, twice.

    Parameters
    ----------
    chunks : callable
        Returns a fresh iterable of :class:`PointCloud` chunks each time it is called.
    cell_m : float
        Cell size, metres (pads the bulk box by 10 cells).
    n_points : int
        Points in the stream (about): the bulk box is taken from every k-th point,
        at most *sample_points* of them, so memory stays bounded.
    """
    step = max(1, int(n_points) // int(sample_points))
    xs, ys = [], []
    lo = np.array([np.inf, np.inf])
    hi = -lo
    for c in chunks():
        if len(c) == 0:
            continue
        x, y = c.x, c.y
        xs.append(np.array(x[::step], dtype=np.float64))
        ys.append(np.array(y[::step], dtype=np.float64))
        with np.errstate(invalid="ignore"):
            lo = np.fmin(lo, [np.min(x), np.min(y)])
            hi = np.fmax(hi, [np.max(x), np.max(y)])
    x = np.concatenate(xs) if xs else np.zeros(0)
    y = np.concatenate(ys) if ys else np.zeros(0)
    ext = Extent(bulk_box(x, y, cell_m))
    b = ext.box
    if lo[0] >= b[0] and lo[1] >= b[1] and hi[0] <= b[2] and hi[1] <= b[3]:
        ext.bounds = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
        return ext
    for c in chunks():     # points far out (or non-finite): measure the bulk exactly
        if len(c):
            ext.add(c.x, c.y)
    return ext


def check_grid_size(nrows: int, ncols: int, max_cells: int | None = None, *, where: str = "",
                    bounds: tuple[float, float, float, float] | None = None, cell_m: float | None = None) -> None:
    """Raise :class:`ProductError` when a grid of *nrows* x *ncols* exceeds *max_cells* (default :data:`MAX_CELLS`)."""
    limit = MAX_CELLS if max_cells is None else int(max_cells)
    if nrows * ncols <= limit:
        return
    area = ""
    if bounds is not None:
        area = f" over E {bounds[0]:.6g}..{bounds[2]:.6g} N {bounds[1]:.6g}..{bounds[3]:.6g}"
    cell = f" at {cell_m:g} m" if cell_m is not None else ""
    raise ProductError(f"{where}{': ' if where else ''}the data ask for a grid of {nrows:,} x {ncols:,} cells"
                       f"{area}{cell}, more than the limit of {limit:,}; {_ESCAPE}")


# --------------------------------------------------------------------------- rasterize
def grid_for(bounds: tuple[float, float, float, float], cell_m: float, *,
             max_cells: int | None = None) -> tuple[GeoTransform, int, int]:
    """The transform and shape of the grid over *bounds*, snapped to multiples of *cell_m*.

    Raises
    ------
    ProductError
        Non-finite or inverted bounds, or a grid of more than *max_cells* cells
        (default :data:`MAX_CELLS`), checked before anything is allocated.
    """
    xmin, ymin, xmax, ymax = map(float, bounds[:4])
    if not (np.isfinite([xmin, ymin, xmax, ymax]).all() and xmin <= xmax and ymin <= ymax):
        raise ProductError(f"cannot grid the area E {xmin:.6g}..{xmax:.6g} N {ymin:.6g}..{ymax:.6g}: "
                           "it is not a finite box")
    with np.errstate(over="ignore", invalid="ignore"):
        span = max((xmax - xmin) / cell_m, (ymax - ymin) / cell_m)
    if not np.isfinite(span) or span > 1e15:   # beyond any int: the size check below needs numbers
        check_grid_size(10 ** 16, 10 ** 16, max_cells, bounds=(xmin, ymin, xmax, ymax), cell_m=cell_m)
    x0 = np.floor(xmin / cell_m) * cell_m
    y0 = np.ceil(ymax / cell_m) * cell_m
    # ceil, not floor + 1: bounds on a cell edge (e.g. --bounds 0 0 10 10, cell 1) give exactly
    # 10 x 10 cells; points on the east/south edge fall in the last cell (see _edge_rowcol)
    ncols = max(1, int(np.ceil((xmax - x0) / cell_m - 1e-9)))
    nrows = max(1, int(np.ceil((y0 - ymin) / cell_m - 1e-9)))
    check_grid_size(nrows, ncols, max_cells, bounds=(xmin, ymin, xmax, ymax), cell_m=cell_m)
    return GeoTransform(float(x0), float(y0), float(cell_m)), nrows, ncols


def _edge_rowcol(transform: GeoTransform, x: Any, y: Any, nrows: int, ncols: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell indices; a point exactly on the grid's east or south edge goes to the last cell."""
    row, col = transform.rowcol(x, y)
    x_east = transform.x0 + ncols * transform.cell_m
    y_south = transform.y0 - nrows * transform.cell_m
    col = np.where((col == ncols) & (np.asarray(x) <= x_east), ncols - 1, col)
    row = np.where((row == nrows) & (np.asarray(y) >= y_south), nrows - 1, row)
    return row, col


def _fill_small_holes(grid: np.ndarray, iterations: int, min_neighbours: int = 5) -> np.ndarray:
    from scipy.ndimage import convolve

    kernel = np.ones((3, 3))
    kernel[1, 1] = 0
    g = grid.astype(np.float64)
    for _ in range(iterations):
        valid = np.isfinite(g)
        if valid.all():
            break
        vals = np.where(valid, g, 0.0)
        s = convolve(vals, kernel, mode="constant", cval=0.0)
        n = convolve(valid.astype(np.float64), kernel, mode="constant", cval=0.0)
        fill = ~valid & (n >= min_neighbours)
        if not fill.any():
            break
        g[fill] = s[fill] / n[fill]
    return g.astype(grid.dtype)


def _interpolate_holes(grid: np.ndarray) -> np.ndarray:
    from scipy.interpolate import LinearNDInterpolator
    from scipy.spatial import QhullError

    valid = np.isfinite(grid)
    if valid.all() or valid.sum() < 3:
        return grid
    rows, cols = np.nonzero(valid)
    holes = np.nonzero(~valid)
    try:
        f = LinearNDInterpolator(np.column_stack([rows, cols]).astype(np.float64), grid[valid])
    except QhullError:  # all valid cells on a line
        return grid
    out = grid.copy()
    out[holes] = f(np.column_stack(holes).astype(np.float64)).astype(grid.dtype)
    return out


def rasterize(cloud: PointCloud | Iterable[PointCloud], cell_m: float, what: str = "intensity",
              bounds: tuple[float, float, float, float] | None = None, *,
              fill: str | None = "auto", fill_iterations: int = 2,
              max_cells: int | None = None) -> tuple[np.ndarray, GeoTransform]:
    """Grid a point cloud (or a stream of chunks) into an intensity, DSM or DTM raster.

    Parameters
    ----------
    cloud : PointCloud or iterable of PointCloud
        Points (E, N, h in metres).  An iterable of chunks (e.g.
        :meth:`TileIndex.iter_points`) keeps memory bounded; then *bounds* is
        required.
    cell_m : float
        Cell size, metres.
    what : {"intensity", "dsm", "dtm"}
        See the module docstring.  Points of the noise classes (7 low, 18 high)
        are left out of every grid.
    bounds : (xmin, ymin, xmax, ymax), optional
        Area to grid, metres (default: the cloud's bounds); the grid is
        snapped to multiples of *cell_m*.
    fill : {"auto", "small", "interpolate", None}
        Hole filling: ``"small"`` closes holes of a few cells, ``"interpolate"``
        interpolates all holes inside the data linearly; ``"auto"`` is
        ``"interpolate"`` for DTM and ``"small"`` otherwise.
    fill_iterations : int
        Passes of the small-hole filling.
    max_cells : int, optional
        Largest grid, cells (default :data:`MAX_CELLS`).

    Returns
    -------
    grid : ndarray, shape (rows, cols), float32
        NaN where no value.
    transform : GeoTransform

    Raises
    ------
    ValueError
        Bad *what*, *cell_m* or missing *bounds* for a stream.
    LidarFormatError
        ``"intensity"`` asked of points without intensity.
    ProductError
        An empty cloud without *bounds*, or a grid of more than *max_cells* cells.

    Examples
    --------
    >>> pc = PointCloud(np.array([[0.2, 0.2, 1.0], [0.7, 0.2, 3.0], [0.2, 0.7, 2.0]]))
    >>> grid, t = rasterize(pc, 0.5, "dsm", fill=None)
    >>> grid.tolist(), t
    ([[2.0, nan], [1.0, 3.0]], GeoTransform(x0=0.0, y0=1.0, cell_m=0.5))
    """
    if what not in RASTER_KINDS:
        raise ValueError(f"unknown raster {what!r}; use one of {', '.join(RASTER_KINDS)}")
    if not cell_m > 0:
        raise ValueError(f"cell_m must be positive, got {cell_m}")
    if fill not in ("auto", "small", "interpolate", None):
        raise ValueError(f"unknown fill {fill!r}")
    chunks: Iterable[PointCloud]
    if isinstance(cloud, PointCloud):
        chunks = [cloud]
        if bounds is None:
            if len(cloud) == 0:
                raise ProductError("cannot rasterize an empty point cloud without bounds")
            bounds = cloud.bounds[:4]
    else:
        if bounds is None:
            raise ValueError("bounds are required when rasterizing a stream of chunks")
        chunks = cloud
    transform, nrows, ncols = grid_for(bounds, cell_m, max_cells=max_cells)
    ncell = nrows * ncols
    acc = np.zeros(ncell) if what == "intensity" else np.full(ncell, -np.inf if what == "dsm" else np.inf)
    cnt = np.zeros(ncell, dtype=np.int64) if what == "intensity" else None
    ground = np.full(ncell, np.inf) if what == "dtm" else None
    has_ground = False
    for c in chunks:
        if len(c) == 0:
            continue
        if what == "intensity":
            if not c.has("intensity"):
                raise LidarFormatError("the points carry no intensity; choose --what dsm or dtm")
            sel = c.first_returns()
        elif what == "dsm":
            sel = c.first_returns()
        else:
            sel = c.last_returns()
        if c.has("classification"):   # noise (ASPRS 7 low, 18 high) is no surface
            sel = sel & ~np.isin(c.attributes["classification"], (7, 18))
        row, col = _edge_rowcol(transform, c.x, c.y, nrows, ncols)
        inside = (row >= 0) & (row < nrows) & (col >= 0) & (col < ncols)
        flat = row * ncols + col
        m = inside & sel
        if what == "intensity":
            acc += np.bincount(flat[m], weights=c.attributes["intensity"][m].astype(np.float64),
                               minlength=ncell)
            cnt += np.bincount(flat[m], minlength=ncell)
        elif what == "dsm":
            np.maximum.at(acc, flat[m], c.z[m])
        else:
            np.minimum.at(acc, flat[m], c.z[m])
            if c.has("classification"):
                g = inside & (c.attributes["classification"] == 2)
                if g.any():
                    has_ground = True
                    np.minimum.at(ground, flat[g], c.z[g])
    if what == "intensity":
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(cnt > 0, acc / np.maximum(cnt, 1), np.nan)
    else:
        if what == "dtm" and has_ground:
            acc = ground
        out = np.where(np.isfinite(acc), acc, np.nan)
    grid = out.reshape(nrows, ncols).astype(np.float32)
    mode = ("interpolate" if what == "dtm" else "small") if fill == "auto" else fill
    if mode == "small":
        grid = _fill_small_holes(grid, fill_iterations)
    elif mode == "interpolate":
        grid = _interpolate_holes(grid)
    return grid, transform


# --------------------------------------------------------------------------- PNG preview
_NODATA_COLOUR = "#cfe3f5"
_LABELS = {"intensity": ("gray", "intensity (first returns, mean)"),
           "dsm": ("viridis", "surface height h (m), highest first return"),
           "dtm": ("terrain", "terrain height h (m)")}


def write_png_preview(path: str | os.PathLike, grid: np.ndarray, transform: GeoTransform,
                      what: str = "intensity", *, title: str | None = None, dpi: int = 120) -> Path:
    """Write a PNG preview with axes in metres and a labelled colour bar (atomically).

    Colours span the 2nd-98th percentile of the values, so a few outliers do
    not wash out the image; cells without data are pale blue.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    cmap, label = _LABELS.get(what, ("viridis", what))
    finite = grid[np.isfinite(grid)]
    vmin, vmax = (np.percentile(finite, [2, 98]) if finite.size else (0.0, 1.0))
    if vmax <= vmin:
        vmax = vmin + 1.0
    nrows, ncols = grid.shape
    extent = (transform.x0, transform.x0 + ncols * transform.cell_m,
              transform.y0 - nrows * transform.cell_m, transform.y0)
    aspect = nrows / max(ncols, 1)
    fig = Figure(figsize=(7.5, float(np.clip(6.0 * aspect, 3.0, 12.0)) + 0.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    cm = matplotlib.colormaps[cmap].with_extremes(bad=_NODATA_COLOUR)
    im = ax.imshow(np.ma.masked_invalid(grid), cmap=cm, vmin=vmin, vmax=vmax, extent=extent,
                   interpolation="nearest", origin="upper")
    ax.set_xlabel("E (m)")
    ax.set_ylabel("N (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_title(title or f"{what}, cell {transform.cell_m:g} m (pale blue: no data)")
    fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    fig.tight_layout()
    bio = io.BytesIO()
    fig.savefig(bio, format="png", dpi=dpi)
    with atomic_write(path, "wb") as fh:
        fh.write(bio.getvalue())
    return path


def write_raster(path: str | os.PathLike, grid: np.ndarray, transform: GeoTransform, crs: Any,
                 what: str, *, preview: bool = True) -> list[Path]:
    """Write ``path`` (GeoTIFF) and, with *preview*, ``path`` with suffix ``.png``; return the paths."""
    path = Path(path)
    out = [write_geotiff(path, grid, transform, crs)]
    if preview:
        out.append(write_png_preview(path.with_suffix(".png"), grid, transform, what))
    return out


#: bands of :func:`point_statistics`, in order
STAT_BANDS = ("min", "max", "mean", "count", "stdev")


def point_statistics(xyz: np.ndarray, cell_m: float, bounds: tuple[float, float, float, float] | None = None,
                     *, values: np.ndarray | None = None,
                     max_cells: int | None = None) -> tuple[np.ndarray, GeoTransform]:
    r"""Per-cell statistics of the points' heights (or *values*): min, max, mean, count, stdev.

    The grid is :func:`grid_for` over *bounds* (default: the points' extent),
    snapped to multiples of *cell_m*, so tile grids mosaic.  Per cell
    :math:`c` with points :math:`v_1..v_n`: :math:`n`, :math:`\min v`,
    :math:`\max v`, the mean :math:`\bar v` and the population standard
    deviation :math:`\sqrt{\overline{(v - \bar v)^2}}` (two passes of
    ``np.bincount``: no cancellation from :math:`\overline{v^2} - \bar v^2`).
    Empty cells are NaN in every band but ``count`` (0).

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
        E, N, h, metres.
    cell_m : float
    bounds : (xmin, ymin, xmax, ymax), optional
        Points outside are left out.
    values : ndarray, shape (N,), optional
        Statistics of these instead of the heights (e.g. intensity).
    max_cells : int, optional

    Returns
    -------
    (ndarray of float64, shape (5, rows, cols), GeoTransform)
        Bands in the order of :data:`STAT_BANDS`.

    Examples
    --------
    >>> pts = np.array([[0.5, 0.5, 1.0], [0.5, 0.5, 3.0], [1.5, 0.5, 7.0]])
    >>> bands, t = point_statistics(pts, 1.0, (0.0, 0.0, 2.0, 1.0))
    >>> bands[:, 0, :].tolist()
    [[1.0, 7.0], [3.0, 7.0], [2.0, 7.0], [2.0, 1.0], [1.0, 0.0]]
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    v = xyz[:, 2] if values is None else np.asarray(values, dtype=np.float64)
    if bounds is None:
        if len(xyz) == 0:
            raise ProductError("no points to grid (give the bounds)")
        bounds = (float(xyz[:, 0].min()), float(xyz[:, 1].min()), float(xyz[:, 0].max()), float(xyz[:, 1].max()))
    transform, nrows, ncols = grid_for(bounds, cell_m, max_cells=max_cells)
    row, col = _edge_rowcol(transform, xyz[:, 0], xyz[:, 1], nrows, ncols)
    ok = (row >= 0) & (row < nrows) & (col >= 0) & (col < ncols) & np.isfinite(v)
    k = (row * ncols + col)[ok]
    v = v[ok]
    m = nrows * ncols
    count = np.bincount(k, minlength=m).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.bincount(k, weights=v, minlength=m) / count
        var = np.bincount(k, weights=(v - mean[k]) ** 2, minlength=m) / count
    lo = np.full(m, np.inf)
    hi = np.full(m, -np.inf)
    np.minimum.at(lo, k, v)
    np.maximum.at(hi, k, v)
    empty = count == 0
    out = np.stack([lo, hi, mean, count, np.sqrt(var)])
    for b in (0, 1, 2, 4):
        out[b, empty] = np.nan
    return out.reshape(5, nrows, ncols), transform
