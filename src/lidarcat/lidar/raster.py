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

GeoTIFF writer
--------------
No rasterio/GDAL dependency: :func:`write_geotiff` writes a baseline TIFF
(float32, uncompressed strips, little-endian) with the GeoTIFF tags
ModelPixelScale, ModelTiepoint and GeoKeyDirectory (projected or geographic
EPSG code, vertical EPSG code of a compound CRS, PixelIsArea) and the GDAL
nodata tag (``nan``).  GDAL and QGIS open it georeferenced.  A CRS without an
EPSG code is written as "user-defined" plus a GDAL ``.aux.xml`` sidecar
holding its WKT, which GDAL reads.  :func:`read_geotiff` reads these files back.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any, NamedTuple
from xml.sax.saxutils import escape

import numpy as np

from .._util import atomic_write, read_bytes, write_text_atomic
from ..errors import LidarcatError, LidarFormatError, TileIOError
from .cloud import PointCloud
from .crs import _parts, resolve_crs

__all__ = ["GeoTransform", "rasterize", "write_geotiff", "read_geotiff", "write_png_preview",
           "write_raster", "RASTER_KINDS"]

RASTER_KINDS = ("intensity", "dsm", "dtm")


class GeoTransform(NamedTuple):
    """North-up grid georeferencing: west edge, north edge, cell size (metres).

    >>> t = GeoTransform(1000.0, 2000.0, 0.5)
    >>> t.to_gdal()
    (1000.0, 0.5, 0.0, 2000.0, 0.0, -0.5)
    >>> t.xy(0, 0)
    (1000.25, 1999.75)
    """

    x0: float
    y0: float
    cell_m: float

    def to_gdal(self) -> tuple[float, float, float, float, float, float]:
        """GDAL geotransform ``(x0, cell, 0, y0, 0, -cell)``."""
        return (self.x0, self.cell_m, 0.0, self.y0, 0.0, -self.cell_m)

    def xy(self, row: Any, col: Any) -> tuple[Any, Any]:
        """Centre of cell (row, col), metres."""
        return self.x0 + (col + 0.5) * self.cell_m, self.y0 - (row + 0.5) * self.cell_m

    def rowcol(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        """Cell indices (row, col) containing the points (x, y)."""
        col = np.floor((np.asarray(x, dtype=np.float64) - self.x0) / self.cell_m).astype(np.int64)
        row = np.floor((self.y0 - np.asarray(y, dtype=np.float64)) / self.cell_m).astype(np.int64)
        return row, col


# --------------------------------------------------------------------------- rasterize
def grid_for(bounds: tuple[float, float, float, float], cell_m: float) -> tuple[GeoTransform, int, int]:
    xmin, ymin, xmax, ymax = map(float, bounds[:4])
    x0 = np.floor(xmin / cell_m) * cell_m
    y0 = np.ceil(ymax / cell_m) * cell_m
    # ceil, not floor + 1: bounds on a cell edge (e.g. --bounds 0 0 10 10, cell 1) give exactly
    # 10 x 10 cells; points on the east/south edge fall in the last cell (see _edge_rowcol)
    ncols = max(1, int(np.ceil((xmax - x0) / cell_m - 1e-9)))
    nrows = max(1, int(np.ceil((y0 - ymin) / cell_m - 1e-9)))
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
              fill: str | None = "auto", fill_iterations: int = 2) -> tuple[np.ndarray, GeoTransform]:
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
        See the module docstring.
    bounds : (xmin, ymin, xmax, ymax), optional
        Area to grid, metres (default: the cloud's bounds); the grid is
        snapped to multiples of *cell_m*.
    fill : {"auto", "small", "interpolate", None}
        Hole filling: ``"small"`` closes holes of a few cells, ``"interpolate"``
        interpolates all holes inside the data linearly; ``"auto"`` is
        ``"interpolate"`` for DTM and ``"small"`` otherwise.
    fill_iterations : int
        Passes of the small-hole filling.

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
                raise ValueError("cannot rasterize an empty point cloud without bounds")
            bounds = cloud.bounds[:4]
    else:
        if bounds is None:
            raise ValueError("bounds are required when rasterizing a stream of chunks")
        chunks = cloud
    transform, nrows, ncols = grid_for(bounds, cell_m)
    ncell = nrows * ncols
    if ncell > 400_000_000:
        raise ValueError(f"grid of {nrows} x {ncols} cells is too large; use a coarser cell")
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


# --------------------------------------------------------------------------- GeoTIFF
_SHORT, _LONG, _ASCII, _DOUBLE = 3, 4, 2, 12
_TYPE_SIZE = {_SHORT: 2, _LONG: 4, _ASCII: 1, _DOUBLE: 8}
_TYPE_FMT = {_SHORT: "H", _LONG: "I", _DOUBLE: "d"}


def _geokeys(crs: Any) -> tuple[list[int], str, bool]:
    """GeoKeyDirectory values, GeoAsciiParams text, and whether a WKT sidecar is needed."""
    keys: list[tuple[int, int, int, int]] = [(1025, 0, 1, 1)]  # PixelIsArea
    ascii_params = ""
    sidecar = False
    if crs is not None:
        horiz, vert = _parts(crs)
        horiz = horiz or crs
        code = horiz.to_epsg(min_confidence=90)
        citation = (crs.name + "|").replace("\x00", "")
        ascii_params = citation
        keys.append((1026, 34737, len(citation), 0))  # GTCitationGeoKey
        if horiz.is_geographic:
            keys.append((1024, 0, 1, 2))
            keys.append((2048, 0, 1, code if code and code < 32767 else 32767))
        else:
            keys.append((1024, 0, 1, 1))
            keys.append((3072, 0, 1, code if code and code < 32767 else 32767))
        if not code or code >= 32767:
            sidecar = True
        if vert is not None:
            vcode = vert.to_epsg(min_confidence=90)
            if vcode and vcode < 32767:
                keys.append((4096, 0, 1, vcode))
            else:
                sidecar = True
    keys.sort()
    directory = [1, 1, 0, len(keys)]
    for k in keys:
        directory.extend(k)
    return directory, ascii_params, sidecar


def _geotiff_ifd(cols: int, rows: int, bands: int, rows_per_strip: int, strip_offsets: list[int],
                 strip_counts: list[int], transform: GeoTransform, crs: Any, ifd_offset: int
                 ) -> tuple[bytes, bool]:
    """The image file directory (and its out-of-line values) of a float32 strip GeoTIFF.

    Shared by :func:`write_geotiff` and the streaming writer of :mod:`lidarcat.mapping.ortho`:
    tags 256-339 (1 or 3 float32 bands, chunky, no compression), ModelPixelScale,
    ModelTiepoint, GeoKeys (+ GeoAscii) and GDAL_NODATA ``nan``.  *ifd_offset* is the
    (even) byte offset the directory will be written at.  Returns the bytes and
    whether the CRS needs a ``.aux.xml`` sidecar (see :func:`_geokeys`).
    """
    geokeys, geo_ascii, sidecar = _geokeys(crs)
    entries: list[tuple[int, int, list[Any] | bytes]] = [
        (256, _LONG, [cols]), (257, _LONG, [rows]), (258, _SHORT, [32] * bands), (259, _SHORT, [1]),
        (262, _SHORT, [2 if bands == 3 else 1]), (273, _LONG, strip_offsets), (277, _SHORT, [bands]),
        (278, _LONG, [rows_per_strip]), (279, _LONG, strip_counts), (284, _SHORT, [1]),
        (339, _SHORT, [3] * bands),
        (33550, _DOUBLE, [transform.cell_m, transform.cell_m, 0.0]),
        (33922, _DOUBLE, [0.0, 0.0, 0.0, transform.x0, transform.y0, 0.0]),
        (34735, _SHORT, geokeys),
    ]
    if geo_ascii:
        entries.append((34737, _ASCII, geo_ascii.encode("ascii", "replace") + b"\x00"))
    entries.append((42113, _ASCII, b"nan\x00"))
    entries.sort(key=lambda e: e[0])
    extra_offset = ifd_offset + 2 + 12 * len(entries) + 4
    ifd = bytearray(struct.pack("<H", len(entries)))
    extra = bytearray()
    for tag, typ, values in entries:
        if typ == _ASCII:
            payload = bytes(values)  # type: ignore[arg-type]
            count = len(payload)
        else:
            payload = struct.pack(f"<{len(values)}{_TYPE_FMT[typ]}", *values)
            count = len(values)
        if len(payload) <= 4:
            ifd += struct.pack("<HHI", tag, typ, count) + payload.ljust(4, b"\x00")
        else:
            ifd += struct.pack("<HHII", tag, typ, count, extra_offset + len(extra))
            extra += payload
            if len(extra) % 2:
                extra += b"\x00"
    ifd += struct.pack("<I", 0)
    return bytes(ifd) + bytes(extra), sidecar


def _tiff_bytes(grid: np.ndarray, transform: GeoTransform, crs: Any) -> tuple[bytes, bool]:
    data = np.ascontiguousarray(grid, dtype="<f4")
    nrows, ncols = data.shape
    row_bytes = ncols * 4
    rows_per_strip = max(1, min(nrows, (256 * 1024) // max(row_bytes, 1)))
    nstrips = (nrows + rows_per_strip - 1) // rows_per_strip
    data_offset = 8
    strip_offsets = [data_offset + k * rows_per_strip * row_bytes for k in range(nstrips)]
    strip_counts = [min(rows_per_strip, nrows - k * rows_per_strip) * row_bytes for k in range(nstrips)]
    image_end = data_offset + data.nbytes
    if image_end > 2**32 - 2**20:
        raise ValueError("grid too large for a classic TIFF (4 GB); use a coarser cell")
    ifd_offset = image_end + (image_end % 2)
    ifd, sidecar = _geotiff_ifd(ncols, nrows, 1, rows_per_strip, strip_offsets, strip_counts,
                                transform, crs, ifd_offset)
    head = b"II" + struct.pack("<HI", 42, ifd_offset)
    pad = b"\x00" * (ifd_offset - image_end)
    return head + data.tobytes() + pad + ifd, sidecar


def write_geotiff(path: str | os.PathLike, grid: np.ndarray, transform: GeoTransform, crs: Any = None) -> Path:
    """Write a float32 GeoTIFF (atomically); see the module docstring for the tags.

    Parameters
    ----------
    path : path-like
        Output ``.tif``.
    grid : ndarray, shape (rows, cols)
        Values (cast to float32); NaN is nodata.
    transform : GeoTransform
    crs : CRS-like, optional
        Written as EPSG GeoKeys; without an EPSG code, also as WKT in
        ``<path>.aux.xml``.

    Returns
    -------
    Path
    """
    path = Path(path)
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.size == 0:
        raise ValueError(f"grid must be a non-empty 2-D array, got shape {grid.shape}")
    crs_obj = resolve_crs(crs)
    blob, sidecar = _tiff_bytes(grid, transform, crs_obj)
    with atomic_write(path, "wb") as fh:
        fh.write(blob)
    aux = path.with_name(path.name + ".aux.xml")
    if sidecar and crs_obj is not None:
        write_text_atomic(aux, f"<PAMDataset>\n  <SRS>{escape(crs_obj.to_wkt())}</SRS>\n</PAMDataset>\n")
    return path


def read_geotiff(path: str | os.PathLike) -> tuple[np.ndarray, GeoTransform, Any]:
    """Read a GeoTIFF written by :func:`write_geotiff` (uncompressed float32 strips).

    Returns
    -------
    grid : ndarray, float32
    transform : GeoTransform
    crs : pyproj.CRS or None
        From the EPSG GeoKeys (horizontal + vertical as a compound CRS), or
        the ``.aux.xml`` sidecar.

    Raises
    ------
    TileIOError
        The file is missing or unreadable.
    LidarFormatError
        Not a TIFF of that kind, or truncated.
    """
    path = Path(path)
    buf = read_bytes(path, TileIOError)
    if buf[:4] != b"II*\x00":
        raise LidarFormatError(f"{path}: not a little-endian TIFF")
    try:
        return _parse_geotiff(path, buf)
    except LidarcatError:
        raise
    except (struct.error, KeyError, IndexError, ValueError) as ex:
        raise LidarFormatError(f"{path}: truncated or incomplete GeoTIFF ({type(ex).__name__}: {ex})") from ex


def _parse_geotiff(path: Path, buf: bytes) -> tuple[np.ndarray, GeoTransform, Any]:
    (ifd_offset,) = struct.unpack_from("<I", buf, 4)
    (n,) = struct.unpack_from("<H", buf, ifd_offset)
    tags: dict[int, Any] = {}
    for k in range(n):
        tag, typ, count, value = struct.unpack_from("<HHI4s", buf, ifd_offset + 2 + 12 * k)
        size = _TYPE_SIZE.get(typ, 1) * count
        raw = value[:size] if size <= 4 else buf[struct.unpack("<I", value)[0]:][:size]
        tags[tag] = raw if typ == _ASCII else list(struct.unpack(f"<{count}{_TYPE_FMT[typ]}", raw))
    if tags.get(259, [1])[0] != 1 or tags.get(339, [1])[0] != 3 or tags.get(258, [0])[0] != 32:
        raise LidarFormatError(f"{path}: only uncompressed float32 GeoTIFFs are supported")
    ncols, nrows = tags[256][0], tags[257][0]
    data = b"".join(buf[o:o + c] for o, c in zip(tags[273], tags[279]))
    grid = np.frombuffer(data, dtype="<f4").reshape(nrows, ncols).astype(np.float32)
    scale = tags[33550]
    tie = tags[33922]
    transform = GeoTransform(tie[3] - tie[0] * scale[0], tie[4] + tie[1] * scale[1], scale[0])
    crs = None
    aux = path.with_name(path.name + ".aux.xml")
    if aux.exists():
        import re
        from xml.sax.saxutils import unescape

        m = re.search(r"<SRS>(.*)</SRS>", aux.read_text(encoding="utf-8"), re.S)
        if m:
            crs = resolve_crs(unescape(m.group(1)))
    if crs is None and 34735 in tags:
        d = tags[34735]
        keys = {d[4 + 4 * i]: d[4 + 4 * i + 3] for i in range(d[3])}
        code = keys.get(3072, keys.get(2048))
        if code and code != 32767:
            crs = resolve_crs(f"EPSG:{code}")
            v = keys.get(4096)
            if v and v != 32767:
                import pyproj

                crs = pyproj.CRS.from_user_input(f"EPSG:{code}+{v}")
    return grid, transform, crs


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
