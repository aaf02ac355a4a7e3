r"""Orthophotos: a photo resampled onto a north-up ground grid over a terrain or surface model.

For every output cell centre ``(E, N)`` (row 0 at the north edge, cell size
``gsd_m``) the model gives ``h`` (bilinear on a DTM: a *standard* orthophoto,
buildings lean away from the nadir; on a DSM: a *true* orthophoto, roofs stand
on their footprints).  The collinearity equations (eq. 08) give the ideal photo
coordinates

.. math::  u = M (X - X_0),\qquad x = -c\,u_1/u_3,\qquad y = -c\,u_2/u_3,

and the camera's distortion model turns them into pixel positions (``C, L``).
The photo is then resampled at ``(C, L)`` with ``cv2.remap`` (bilinear).

Distortion look-up table
------------------------
Photo -> pixel has no closed form (:meth:`lidarcat.geometry.camera.Camera.photo_to_pixel`
runs Newton's method).  It is evaluated once on a lattice of ideal photo
coordinates every ``16`` pixels (frame plus a 10 % margin).  An affine map
``(x, y) -> (C, L)`` is fitted to the lattice by least squares; what is left,
the distortion ``d(x, y)`` (at most tens of pixels, smooth), is stored as two
float32 grids and interpolated bilinearly by ``cv2.remap``.  ``cv2.remap``
quantises its interpolation weights to 1/32 of a lattice cell, so the error
is at most ``|grad d| x 16 / 64`` px -- below 0.005 px for a distortion that
changes by 1 px across a 16-pixel cell -- where interpolating the pixel
positions themselves would be off by up to a quarter pixel.

Surface heights
---------------
The output grid and the DSM/DTM grid are both north-up: the DSM column of an
output cell depends on its column only, the row on its row.  Bilinear
interpolation is therefore separable: per tile, one set of column weights and
one of row weights, and two gathers of DSM rows (the values are those of
:meth:`lidarcat.mapping.monoplot.GridSurface.height`, bilinear, to the bit).

Holes in the surface model
--------------------------
A DSM rasterised from the LiDAR keeps cells without a point (4.3 % of the
0.5 m cells at 4 points/m^2); a cell of the output over a hole has no height,
and the orthophoto loses it (speckle).  Before orthorectifying, the holes are
filled by GDAL's inverse-distance fill (``rasterio.fill.fillnodata``: each
empty cell takes the inverse-distance weighted mean of the nearest valid cells
found along 4 x 4 search directions, up to ``fill_m`` metres away; no
smoothing), the known heights unchanged (:func:`fill_holes`).  Cells farther
than ``fill_m`` from any height (water, the edge of the survey) stay empty.
The z-buffer then sees the filled surface too: a hole is not an occluder, nor
is it a gap through which a hidden cell shows.

Occlusion (true orthophoto)
---------------------------
A z-buffer: every DSM cell in the output area (plus a margin) is projected
into the photo; each bin of ``b x b`` photo pixels (``b`` = one DSM cell seen
from the camera) keeps the smallest depth ``-u_3``; empty bins take the
smallest depth of their 3 x 3 neighbours.  An output cell is occluded when
its depth exceeds the bin's by more than ``3 x`` the DSM cell size (an
occluder stands at least an eave height in front of what it hides).
Occluded cells are nodata in the true orthophoto and listed in its mask.

Tiles, threads and the file
---------------------------
The output is computed in tiles of ``tile_px x tile_px`` cells (default 512)
by a pool of ``workers`` threads (numpy's array arithmetic and OpenCV release
the GIL; OpenCV's own threads are held to one meanwhile), assembled into row
bands in order and streamed into the GeoTIFF: the whole output grid is never
in memory, only the photo, the z-buffer (one value per ``b x b`` photo
pixels) and the tiles in flight.  The GeoTIFF keeps the photo's data type
(uint8 or uint16; a float photo gives float32 with NaN as nodata) and marks
the valid cells with an internal mask (every value stays a value), DEFLATE
(lossless, default) or JPEG (uint8, lossy, YCbCr), cloud-optimised with
overviews (:class:`lidarcat.lidar.geotiff.GeoTiffWriter`, the CRS as given).
A PNG preview (at most 2000 px on a side, nodata black) goes next to it.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry.collinearity import rotation_matrix
from ..geometry.camera import Camera
from ..errors import LidarcatError
from ..lidar.geotiff import GeoTiffWriter
from ._raster_cells import ZBuffer, remap_points, run_tiles

__all__ = ["OrthoError", "PhotoModel", "OrthoResult", "orthophoto", "output_grid", "DistortionLUT",
           "sample_photo", "GeoTiffStream", "fill_holes", "grid_heights", "COMPRESSIONS"]

#: compressions of the orthophoto GeoTIFF
COMPRESSIONS = ("deflate", "jpeg")

#: the streaming GeoTIFF writer, by its name before issue 23 (:class:`lidarcat.lidar.geotiff.GeoTiffWriter`)
GeoTiffStream = GeoTiffWriter

log = logging.getLogger(__name__)


class OrthoError(LidarcatError, ValueError):
    """Orthophoto inputs are invalid (names the photo, file or parameter)."""


# ---------------------------------------------------------------------------- distortion LUT
class DistortionLUT:
    """Ideal (corrected) photo coordinates -> pixel, interpolated on a lattice (module docstring).

    Parameters
    ----------
    camera : Camera
    spacing_px : float
        Lattice spacing, pixels of the sensor.
    margin : float
        Extra frame fraction covered on each side.
    """

    def __init__(self, camera: Camera, spacing_px: float = 16.0, margin: float = 0.1) -> None:
        w, h = camera.frame_size_mm
        step = spacing_px * min(camera.pixel_size_x_mm, camera.pixel_size_y_mm)
        half_w, half_h = w / 2 * (1 + 2 * margin), h / 2 * (1 + 2 * margin)
        cx, cy = -camera.principal_point_x_mm, -camera.principal_point_y_mm
        self.x0, self.y0 = cx - half_w, cy - half_h
        self.step = step
        nx = int(math.ceil(2 * half_w / step)) + 1
        ny = int(math.ceil(2 * half_h / step)) + 1
        xs = self.x0 + step * np.arange(nx)
        ys = self.y0 + step * np.arange(ny)
        gx, gy = np.meshgrid(xs, ys)
        px = camera.photo_to_pixel(np.column_stack([gx.ravel(), gy.ravel()]), on_fail="nan")
        self.col = px[:, 0].reshape(ny, nx)
        self.row = px[:, 1].reshape(ny, nx)
        # the affine part (lattice coordinates -> pixels) and the distortion left over, float32 for cv2.remap
        fx, fy = np.meshgrid(np.arange(nx, dtype=np.float64), np.arange(ny, dtype=np.float64))
        ok = np.isfinite(self.col) & np.isfinite(self.row)
        a = np.column_stack([np.ones(int(ok.sum())), fx[ok], fy[ok]])
        self._affine = np.linalg.lstsq(a, np.column_stack([self.col[ok], self.row[ok]]), rcond=None)[0]  # (3, 2)
        self._res_col = (self.col - (self._affine[0, 0] + self._affine[1, 0] * fx + self._affine[2, 0] * fy)
                         ).astype(np.float32)
        self._res_row = (self.row - (self._affine[0, 1] + self._affine[1, 1] * fx + self._affine[2, 1] * fy)
                         ).astype(np.float32)

    def __call__(self, x_mm: np.ndarray, y_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel column and row (float64) of ideal photo coordinates (any shape); NaN off the lattice."""
        fx = (np.asarray(x_mm, dtype=np.float64) - self.x0) / self.step
        fy = (np.asarray(y_mm, dtype=np.float64) - self.y0) / self.step
        fx, fy = np.broadcast_arrays(fx, fy)
        dc, dr = remap_points((self._res_col, self._res_row), fx, fy)
        a = self._affine
        col = a[0, 0] + a[1, 0] * fx + a[2, 0] * fy
        col += dc
        row = a[0, 1] + a[1, 1] * fx + a[2, 1] * fy
        row += dr
        return col, row


# ---------------------------------------------------------------------------- photo model
@dataclass(frozen=True, eq=False)
class PhotoModel:
    """One oriented photo: its pixels, camera and exterior orientation.

    Attributes
    ----------
    photo_id : str
    image : (rows, cols) or (rows, cols, 3) uint8/float array
        The photo; its size must be the camera's.
    camera : Camera
    eo_params : (6,) array
        X0, Y0, Z0 (m), omega, phi, kappa (rad).
    """

    photo_id: str
    image: np.ndarray
    camera: Camera
    eo_params: np.ndarray

    def __post_init__(self) -> None:
        img = np.asarray(self.image)
        if img.ndim not in (2, 3) or img.shape[:2] != (self.camera.rows_px, self.camera.columns_px) \
                or (img.ndim == 3 and img.shape[2] not in (1, 3)):
            raise OrthoError(f"photo {self.photo_id!r}: image is {img.shape[1::-1] if img.ndim >= 2 else img.shape}"
                             f" px but camera {self.camera.id!r} is {self.camera.columns_px} x "
                             f"{self.camera.rows_px} px (grey or 3-band)")
        p = np.asarray(self.eo_params, dtype=np.float64).reshape(-1)
        if p.shape != (6,) or not np.isfinite(p).all():
            raise OrthoError(f"photo {self.photo_id!r}: exterior orientation must be 6 finite numbers")
        object.__setattr__(self, "eo_params", p)
        object.__setattr__(self, "_m", rotation_matrix(p[3:]))
        object.__setattr__(self, "_lut", DistortionLUT(self.camera))

    @property
    def bands(self) -> int:
        return 1 if self.image.ndim == 2 else self.image.shape[2]

    def project(self, e: np.ndarray, n: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel column, row and depth ``-u3`` (m, > 0 in front) of ground points (any shape)."""
        p = self.eo_params
        m = self._m  # type: ignore[attr-defined]
        de, dn, dh = e - p[0], n - p[1], h - p[2]
        u1 = m[0, 0] * de + m[0, 1] * dn + m[0, 2] * dh
        u2 = m[1, 0] * de + m[1, 1] * dn + m[1, 2] * dh
        u3 = m[2, 0] * de + m[2, 1] * dn + m[2, 2] * dh
        c = self.camera.focal_length_mm
        with np.errstate(divide="ignore", invalid="ignore"):
            x = -c * u1 / u3
            y = -c * u2 / u3
        col, row = self._lut(x, y)  # type: ignore[attr-defined]
        bad = ~(u3 < 0)
        col[bad] = np.nan
        row[bad] = np.nan
        return col, row, -u3

    def inside(self, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        """Pixel positions on the sensor (interpolation needs the pixel centres around them)."""
        return ((col >= 0) & (col <= self.camera.columns_px - 1)
                & (row >= 0) & (row <= self.camera.rows_px - 1))

    def footprint(self, h_m: float, n_edge: int = 16) -> np.ndarray:
        """(K, 2) plan outline of the frame on the plane ``h = h_m``, m."""
        from .monoplot import ray_directions

        cam = self.camera
        c, r = cam.columns_px - 1.0, cam.rows_px - 1.0
        s = np.linspace(0, 1, n_edge, endpoint=False)
        edge = np.concatenate([np.column_stack([s * c, 0 * s]), np.column_stack([c + 0 * s, s * r]),
                               np.column_stack([c - s * c, r + 0 * s]), np.column_stack([0 * s, r - s * r])])
        d = ray_directions(cam, self.eo_params, edge)
        t = (h_m - self.eo_params[2]) / d[:, 2]
        return self.eo_params[:2] + t[:, None] * d[:, :2]

    @property
    def out_dtype(self) -> np.dtype:
        """Data type of the orthophoto file: the photo's uint8/uint16, else float32."""
        d = np.asarray(self.image).dtype
        return d if d in (np.uint8, np.uint16) else np.dtype(np.float32)

    def _source(self) -> np.ndarray:
        """The photo as OpenCV samples it: contiguous (rows, cols, bands) uint8/uint16/float32 (made once)."""
        src = self.__dict__.get("_src")
        if src is None:
            img = np.asarray(self.image)
            img = img if img.ndim == 3 else img[:, :, None]
            if img.dtype not in (np.uint8, np.uint16, np.float32):
                img = img.astype(np.float32)
            src = np.ascontiguousarray(img)
            object.__setattr__(self, "_src", src)
        return src

    def remap_native(self, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        """Bilinear samples of the photo at (col, row) (2-D arrays), (..., bands) in :attr:`out_dtype`
        (integers rounded by OpenCV); 0 off the photo."""
        import cv2

        src = self._source()
        mx = np.where(np.isfinite(col), col, -10).astype(np.float32)
        my = np.where(np.isfinite(row), row, -10).astype(np.float32)
        bands = src.shape[2]
        if bands in (1, 3, 4):
            out = cv2.remap(src if bands > 1 else src[:, :, 0], mx, my, interpolation=cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            out = out.reshape(col.shape + (bands,))
        else:  # pragma: no cover - PhotoModel takes 1 or 3 bands
            out = np.stack([cv2.remap(np.ascontiguousarray(src[:, :, b]), mx, my, interpolation=cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=0) for b in range(bands)], -1)
        return out.astype(self.out_dtype, copy=False)

    def remap(self, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        """Bilinear samples of the photo at (col, row): float32 (..., bands)."""
        return self.remap_native(col, row).astype(np.float32)


# ---------------------------------------------------------------------------- surface
def fill_holes(surface: Any, max_distance_m: float) -> tuple[Any, int]:
    """The surface model with its empty cells filled by inverse distance (module docstring).

    Parameters
    ----------
    surface : lidarcat.mapping.monoplot.GridSurface
    max_distance_m : float
        Search distance, m: empty cells farther from every height stay empty
        (0: nothing is filled).

    Returns
    -------
    surface : GridSurface
        The same object when nothing was filled; else a new one, its known
        heights unchanged.
    n_filled : int
        Cells filled.
    """
    from .monoplot import GridSurface

    g = surface.grid
    holes = ~np.isfinite(g)
    cells = int(math.ceil(max_distance_m / float(surface.transform.cell_m))) if max_distance_m > 0 else 0
    if cells <= 0 or not holes.any():
        return surface, 0
    from rasterio.fill import fillnodata

    # the holes stay NaN in the input: the cells the search does not reach come back NaN
    filled = fillnodata(g.astype(np.float32), mask=(~holes).astype(np.uint8), max_search_distance=float(cells),
                        smoothing_iterations=0)
    reached = holes & np.isfinite(filled)
    out = g.copy()
    out[reached] = filled[reached]
    n = int(reached.sum())
    if n == 0:
        return surface, 0
    log.info("surface model: %d empty cells filled (inverse distance, up to %.3g m)", n, max_distance_m)
    return GridSurface(out, surface.transform, surface.interpolator, surface.sd_m), n


def grid_heights(surface: Any, e_m: np.ndarray, n_m: np.ndarray) -> np.ndarray:
    """Bilinear heights of a north-up grid at the cells ``(n_m[i], e_m[j])`` of a north-up lattice.

    Separable (module docstring): *e_m* (cols,) and *n_m* (rows,) cell-centre
    coordinates, m; returns (rows, cols) heights, m, equal to
    ``surface.height(E, N)`` of the bilinear :class:`~lidarcat.mapping.monoplot.GridSurface`
    (NaN outside the grid and next to its holes).
    """
    t, g = surface.transform, surface.grid
    rows, cols = g.shape
    fc = (np.asarray(e_m, dtype=np.float64) - t.x0) / t.cell_m
    fr = (t.y0 - np.asarray(n_m, dtype=np.float64)) / t.cell_m
    x = np.clip(fc - 0.5, 0, cols - 1)
    y = np.clip(fr - 0.5, 0, rows - 1)
    c0 = np.minimum(np.floor(x).astype(np.int64), max(cols - 2, 0))
    r0 = np.minimum(np.floor(y).astype(np.int64), max(rows - 2, 0))
    c1, r1 = np.minimum(c0 + 1, cols - 1), np.minimum(r0 + 1, rows - 1)
    ax, ay = x - c0, (y - r0)[:, None]
    g0, g1 = g[r0], g[r1]
    out = (g0[:, c0] * (1 - ax) + g0[:, c1] * ax) * (1 - ay) + (g1[:, c0] * (1 - ax) + g1[:, c1] * ax) * ay
    out[~((fr >= 0) & (fr <= rows))] = np.nan
    out[:, ~((fc >= 0) & (fc <= cols))] = np.nan
    return out


# ---------------------------------------------------------------------------- grid and driver
def output_grid(bounds: Sequence[float], gsd_m: float) -> tuple[Any, int, int]:
    """GeoTransform, rows and columns of a north-up grid covering *bounds* (snapped to *gsd_m*)."""
    from ..lidar.geotiff import GeoTransform

    if not gsd_m > 0:
        raise OrthoError(f"--gsd must be positive, got {gsd_m}")
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    if not (xmax > xmin and ymax > ymin):
        raise OrthoError(f"empty output area {xmin:.2f} {ymin:.2f} {xmax:.2f} {ymax:.2f} (E, N min/max)")
    x0 = math.floor(xmin / gsd_m) * gsd_m
    y0 = math.ceil(ymax / gsd_m) * gsd_m
    cols = int(math.ceil((xmax - x0) / gsd_m - 1e-9))
    rows = int(math.ceil((y0 - ymin) / gsd_m - 1e-9))
    return GeoTransform(x0, y0, float(gsd_m)), rows, cols


@dataclass(frozen=True)
class OrthoResult:
    """What :func:`orthophoto` made.

    Attributes
    ----------
    path : Path or None
        The GeoTIFF (None when only an array was asked for).
    array : ndarray or None
        The orthophoto, float32 (rows, cols, bands), NaN = nodata (only without *path*).
    transform : GeoTransform
    shape : (rows, cols)
    n_valid, n_occluded, n_outside : int
        Cells with a value, hidden by the z-buffer, off the photo or the surface.
    true_ortho : bool
    n_filled : int
        Empty cells of the surface model filled before orthorectifying (:func:`fill_holes`).
    """

    path: Path | None
    array: np.ndarray | None
    transform: Any
    shape: tuple[int, int]
    n_valid: int
    n_occluded: int
    n_outside: int
    true_ortho: bool
    n_filled: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"path": str(self.path) if self.path else None, "x0": self.transform.x0,
                "y0": self.transform.y0, "gsd_m": self.transform.cell_m, "rows": self.shape[0],
                "cols": self.shape[1], "n_valid": self.n_valid, "n_occluded": self.n_occluded,
                "n_outside": self.n_outside, "true_ortho": self.true_ortho, "surface_filled": self.n_filled}


def _default_bounds(photo: PhotoModel, surface: Any) -> tuple[float, float, float, float]:
    h = float(np.nanmedian(surface.grid))
    fp = photo.footprint(h)
    sb = surface.bounds
    b = (max(fp[:, 0].min(), sb[0]), max(fp[:, 1].min(), sb[1]),
         min(fp[:, 0].max(), sb[2]), min(fp[:, 1].max(), sb[3]))
    if not (b[2] > b[0] and b[3] > b[1]):
        raise OrthoError(f"photo {photo.photo_id!r}: the surface model ({sb[0]:.1f} {sb[1]:.1f} "
                         f"{sb[2]:.1f} {sb[3]:.1f}) does not cover the photo's footprint "
                         f"({fp[:, 0].min():.1f} {fp[:, 1].min():.1f} {fp[:, 0].max():.1f} "
                         f"{fp[:, 1].max():.1f})")
    return b


def _visibility(photo: PhotoModel, h: np.ndarray, col: np.ndarray, row: np.ndarray, depth: np.ndarray,
                zbuf: ZBuffer | None) -> tuple[np.ndarray, np.ndarray]:
    """Valid and occluded cells of sampled positions."""
    ok = np.isfinite(h) & np.isfinite(col) & photo.inside(col, row)
    occl = np.zeros(h.shape, dtype=bool)
    if zbuf is not None:
        occl[ok] = ~zbuf.visible(col[ok], row[ok], depth[ok])
        ok &= ~occl
    return ok, occl


def sample_photo(photo: PhotoModel, surface: Any, e: np.ndarray, n: np.ndarray,
                 zbuf: ZBuffer | None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Values (..., bands), valid mask, occluded mask and off-nadir tan of ground cells of one photo."""
    h = surface.height(e, n)
    col, row, depth = photo.project(e, n, h)
    ok, occl = _visibility(photo, h, col, row, depth, zbuf)
    vals = photo.remap(col, row)
    p = photo.eo_params
    with np.errstate(invalid="ignore", divide="ignore"):
        tan = np.hypot(e - p[0], n - p[1]) / (p[2] - h)
    return vals, ok, occl, tan


def _ortho_tile(photo: PhotoModel, surface: Any, zbuf: ZBuffer | None, transform: Any,
                r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Values (photo's data type, (rows, cols, bands); 0 where not valid), valid and occluded cells of a tile."""
    cell = transform.cell_m
    e = transform.x0 + (np.arange(c0, c1) + 0.5) * cell
    n = transform.y0 - (np.arange(r0, r1) + 0.5) * cell
    h = grid_heights(surface, e, n)
    col, row, depth = photo.project(e[None, :], n[:, None], h)
    ok, occl = _visibility(photo, h, col, row, depth, zbuf)
    vals = photo.remap_native(col, row)
    vals[~ok] = 0
    return vals, ok, occl


def orthophoto(photo: PhotoModel, surface: Any, gsd_m: float, path: str | os.PathLike | None = None, *,
               bounds: Sequence[float] | None = None, true_ortho: bool = False, crs: Any = None,
               tile_px: int = 512, preview: bool = True, zbuffer_tol_m: float | None = None,
               fill_m: float = 10.0, compress: str = "deflate", workers: int | None = None,
               progress: Callable[[int, int], None] | None = None) -> OrthoResult:
    """Orthorectify one photo over a terrain (standard) or surface model (true orthophoto).

    Parameters
    ----------
    photo : PhotoModel
    surface : lidarcat.mapping.monoplot.GridSurface
        DTM (standard ortho) or DSM (with ``true_ortho``: occlusions masked),
        heights in m; its bilinear interpolator is used whatever it was built with.
    gsd_m : float
        Output cell size (ground sample distance), m.
    path : path-like, optional
        GeoTIFF to write (plus ``.png`` preview); without it the orthophoto is
        returned as a float32 array (small areas, tests).
    bounds : (xmin, ymin, xmax, ymax), optional
        Output area, m (default: the photo's footprint on the surface, clipped to it).
    true_ortho : bool
        Mask the cells the photo does not see (z-buffer on the surface).
    crs : CRS-like, optional
        Written into the GeoTIFF.
    tile_px : int
        Tile edge, cells: memory ~ workers x tile_px^2 x 120 bytes.
    preview : bool
        Also write ``<path>.png``.
    zbuffer_tol_m : float, optional
        Depth tolerance of the z-buffer (default 3 DSM cells).
    fill_m : float
        Fill the surface model's empty cells from known heights up to this
        far, m (:func:`fill_holes`; 0: no filling).
    compress : {"deflate", "jpeg"}
        GeoTIFF compression: lossless DEFLATE, or JPEG (uint8 photos, lossy).
    workers : int, optional
        Threads computing tiles (default: the CPU count).
    progress : callable, optional
        ``progress(done_rows, total_rows)``.

    Returns
    -------
    OrthoResult

    Raises
    ------
    OrthoError
        A non-positive GSD, an empty area, a surface that does not cover the
        photo, JPEG for a photo that is not 8-bit.
    """
    from .monoplot import GridSurface

    if not isinstance(surface, GridSurface):
        raise OrthoError("orthophotos need a gridded DTM/DSM (GridSurface); rasterise the LiDAR first "
                         "(`lidarcat lidar raster --what dsm`)")
    if surface.interpolator != "bilinear":
        surface = GridSurface(surface.grid, surface.transform, "bilinear", surface.sd_m)
    if tile_px < 16:
        raise OrthoError(f"tile_px must be at least 16, got {tile_px}")
    if compress not in COMPRESSIONS:
        raise OrthoError(f"compression must be one of {', '.join(COMPRESSIONS)}, got {compress!r}")
    dtype = photo.out_dtype
    if compress == "jpeg" and dtype != np.uint8:
        raise OrthoError(f"photo {photo.photo_id!r}: JPEG compression takes 8-bit photos; this one is "
                         f"{np.asarray(photo.image).dtype.name} (use deflate)")
    if not (math.isfinite(fill_m) and fill_m >= 0):
        raise OrthoError(f"fill_m must be >= 0 (metres), got {fill_m!r}")
    surface, n_filled = fill_holes(surface, fill_m)
    bounds = _default_bounds(photo, surface) if bounds is None else bounds
    transform, rows, cols = output_grid(bounds, gsd_m)
    zbuf = ZBuffer(photo, surface, (transform.x0, transform.y0 - rows * gsd_m,
                                     transform.x0 + cols * gsd_m, transform.y0),
                    zbuffer_tol_m) if true_ortho else None

    def compute(r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return _ortho_tile(photo, surface, zbuf, transform, r0, r1, c0, c1)

    out_arr, counts = run_tiles(compute, rows, cols, photo.bands, tile_px, path, transform, crs, preview, progress,
                                dtype=dtype, compress=compress, workers=workers)
    log.info("orthophoto of photo %s: %d x %d cells of %.3g m, %d valid, %d occluded", photo.photo_id,
             cols, rows, gsd_m, counts[0], counts[1])
    return OrthoResult(Path(path) if path is not None else None, out_arr, transform, (rows, cols), int(counts[0]),
                       int(counts[1]), int(counts[2]), bool(true_ortho), n_filled)
