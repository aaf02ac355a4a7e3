"""GeoTIFF files: the one reader and the one writer of lidarcat's rasters (through rasterio/GDAL).

Every raster lidarcat writes (``lidar raster``/``dsm``/``dtm``, the production
chain's models, orthophotos and mosaics, map sheets) and every DEM it reads
(``ortho``, ``monoplot``, ``lidar sheets``) goes through this module; the
gridding itself (:func:`lidarcat.lidar.raster.rasterize`) knows no file.

Grids
-----
A grid is north-up with square cells: :class:`GeoTransform` gives the west and
north edges and the cell size; cell ``(row, col)`` covers
``x0 + col*cell .. x0 + (col+1)*cell`` and ``y0 - (row+1)*cell .. y0 - row*cell``.

Written files
-------------
One profile for every writer (:func:`write_geotiff` for a whole array,
:class:`GeoTiffWriter` for an output streamed in row blocks):

- a cloud-optimised GeoTIFF (GDAL's COG driver: tiles of 512 x 512, overviews
  when the grid is larger than a tile), BigTIFF when the file could pass 4 GB;
- DEFLATE with the horizontal-differencing predictor (TIFF predictor 2) for
  every data type; the floating-point predictor (3) gives no smaller files on
  lidarcat's products (docs/production.md, "GeoTIFF files") and cannot be
  read by TIFF readers without its codec;
- float grids as float32, nodata NaN; integer images (the hypsometric RGB,
  uint8) as they are, without nodata; three bands are RGB;
- the CRS exactly as given: a CRS that *is* an EPSG code (pyproj finds it with
  full confidence) is written by its code, so a compound CRS such as
  EPSG:7415 (RD New + NAP height) keeps it (GeoKeys 28992 and 5709 that GDAL
  reads back as EPSG:7415; its WKT alone would lose the code); any other CRS
  is written from its WKT (GDAL's user-defined GeoKeys).

Files appear atomically: written to a temporary sibling, renamed on success.

Read files
----------
:func:`read_geotiff` reads any GeoTIFF GDAL reads: compressed (DEFLATE, LZW,
ZSTD, ...), tiled or stripped, BigTIFF, any data type, any CRS (returned, for
the caller to check), one band or several.  Heights come back as floats with
NaN at the file's nodata value; ``raw=True`` keeps the stored values.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import LidarFormatError, TileIOError
from .crs import resolve_crs

__all__ = ["GeoTransform", "write_geotiff", "read_geotiff", "GeoTiffWriter", "geotiff_crs", "BLOCK_PX"]

#: tile edge of every written GeoTIFF, pixels
BLOCK_PX = 512
_STREAM_CACHE_MB = 64   # GDAL block cache while streaming (MB): full tiles go to disk, memory stays bounded


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


# --------------------------------------------------------------------------- CRS
def geotiff_crs(crs: Any) -> Any:
    """The rasterio CRS that writes *crs* (CRS-like) into a GeoTIFF as given, or None.

    By its EPSG code when the CRS is that code (full confidence), else from its WKT.

    >>> geotiff_crs("EPSG:7415").to_epsg()
    7415
    """
    from rasterio.crs import CRS

    c = resolve_crs(crs)
    if c is None:
        return None
    auth = c.to_authority(min_confidence=100)
    if auth is not None and auth[0] == "EPSG":
        return CRS.from_epsg(int(auth[1]))
    return CRS.from_wkt(c.to_wkt())


def _pyproj_crs(rio_crs: Any) -> Any:
    """The pyproj CRS of a rasterio CRS: by its EPSG code when GDAL identifies it fully, else its WKT."""
    import pyproj

    if rio_crs is None:
        return None
    code = rio_crs.to_epsg(confidence_threshold=100)
    if code is not None:
        return pyproj.CRS.from_epsg(code)
    return pyproj.CRS.from_wkt(rio_crs.to_wkt())


# --------------------------------------------------------------------------- writing
def _profile(rows: int, cols: int, bands: int, dtype: np.dtype, transform: GeoTransform, crs: Any) -> dict[str, Any]:
    from rasterio.transform import Affine

    profile: dict[str, Any] = {
        "width": int(cols), "height": int(rows), "count": int(bands), "dtype": dtype.name,
        "transform": Affine(transform.cell_m, 0.0, transform.x0, 0.0, -transform.cell_m, transform.y0),
        "crs": geotiff_crs(crs), "compress": "DEFLATE", "predictor": 2, "bigtiff": "IF_SAFER",
    }
    if dtype.kind == "f":
        profile["nodata"] = float("nan")
    if bands == 3:
        profile["photometric"] = "RGB"
    return profile


def _values(array: np.ndarray) -> np.ndarray:
    """(bands, rows, cols) in the written data type: floats (and booleans) as float32, integers as they are."""
    a = np.asarray(array)
    if a.ndim not in (2, 3) or a.size == 0:
        raise ValueError(f"grid must be a non-empty (rows, cols) or (rows, cols, bands) array, got shape {a.shape}")
    if a.dtype.kind not in "iu":
        a = a.astype(np.float32, copy=False)
    return a[None] if a.ndim == 2 else np.moveaxis(a, 2, 0)


@contextlib.contextmanager
def _atomic_target(path: Path) -> Iterator[Path]:
    """A temporary sibling of *path* to write; renamed onto *path* on success, removed on any exception."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)   # mkstemp makes 0600; give the usual mode
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


_CREATION_OPTIONS = ("driver", "compress", "predictor", "bigtiff", "blocksize")   # what a COG copy takes


def _cog_options(profile: dict[str, Any]) -> dict[str, Any]:
    """The COG driver's spelling of the profile (it tiles by BLOCKSIZE and takes no PHOTOMETRIC)."""
    opts = {k: v for k, v in profile.items() if k not in ("photometric",)}
    opts.update(driver="COG", blocksize=BLOCK_PX, predictor="STANDARD")
    return opts


def write_geotiff(path: str | os.PathLike, grid: np.ndarray, transform: GeoTransform, crs: Any = None) -> Path:
    """Write a grid or an image as a cloud-optimised GeoTIFF, atomically (the module docstring's profile).

    Parameters
    ----------
    path : path-like
        Output ``.tif``.
    grid : ndarray, shape (rows, cols) or (rows, cols, bands)
        Values; floats are written as float32 with NaN as nodata, integers
        (e.g. an RGB uint8 image) as they are.
    transform : GeoTransform
    crs : CRS-like, optional
        Written as given (EPSG code kept, compound CRSs included).

    Returns
    -------
    Path
    """
    import rasterio

    path = Path(path)
    bands = _values(grid)
    profile = _profile(bands.shape[1], bands.shape[2], bands.shape[0], bands.dtype, transform, crs)
    with _atomic_target(path) as tmp:
        with rasterio.open(tmp, "w", **_cog_options(profile)) as dst:
            if bands.shape[0] == 3:
                dst.colorinterp = _rgb()
            dst.write(bands)
    return path


def _rgb() -> list[Any]:
    from rasterio.enums import ColorInterp

    return [ColorInterp.red, ColorInterp.green, ColorInterp.blue]


class GeoTiffWriter:
    """Write a GeoTIFF in row blocks (top to bottom), atomically, with the profile of :func:`write_geotiff`.

    The rows are written into a tiled GeoTIFF as they come (a window of whole
    tile rows at a time, GDAL's block cache held to 64 MB), then copied into
    the cloud-optimised file (GDAL reads it tile by tile): the whole grid is
    never in memory.  Use as a context manager; the file appears only on a
    clean exit with every row written.

    Parameters
    ----------
    path : path-like
    shape : (rows, cols)
    bands : int
    transform : GeoTransform
    crs : CRS-like, optional
    dtype : numpy dtype
        Data type of the file (default float32, nodata NaN).
    """

    def __init__(self, path: str | os.PathLike, shape: tuple[int, int], bands: int, transform: GeoTransform,
                 crs: Any = None, dtype: Any = np.float32) -> None:
        self.path = Path(path)
        self.rows, self.cols = (int(v) for v in shape)
        self.bands = int(bands)
        self.dtype = np.dtype(dtype)
        self.transform = transform
        self._profile = _profile(self.rows, self.cols, self.bands, self.dtype, transform, crs)
        self._row = 0
        self._pending: list[np.ndarray] = []
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> GeoTiffWriter:
        import rasterio

        stack = self._stack
        try:
            self._final = stack.enter_context(_atomic_target(self.path))
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tiled", dir=self.path.parent)
            os.close(fd)
            self._tiled = Path(name)
            stack.callback(self._tiled.unlink, missing_ok=True)
            stack.enter_context(rasterio.Env(GDAL_CACHEMAX=_STREAM_CACHE_MB))
            self._dst = stack.enter_context(rasterio.open(
                self._tiled, "w", driver="GTiff", tiled=True, blockxsize=BLOCK_PX, blockysize=BLOCK_PX,
                interleave="pixel", **self._profile))
            if self.bands == 3:
                self._dst.colorinterp = _rgb()
        except BaseException:
            stack.close()
            raise
        return self

    def write_rows(self, block: np.ndarray) -> None:
        """Append rows: (k, cols) or (k, cols, bands) values (cast to the file's data type)."""
        b = np.asarray(block)
        if b.ndim == 2:
            b = b[:, :, None]
        if b.shape[1:] != (self.cols, self.bands) or self._row + b.shape[0] > self.rows:
            raise ValueError(f"{self.path}: row block of shape {b.shape} does not fit a "
                             f"{self.rows} x {self.cols} x {self.bands} grid at row {self._row}")
        self._pending.append(b.astype(self.dtype, copy=False))
        self._row += b.shape[0]
        self._flush(final=self._row == self.rows)

    def _flush(self, final: bool) -> None:
        """Write the pending rows in whole tile rows (all of them at the end)."""
        from rasterio.windows import Window

        n = sum(p.shape[0] for p in self._pending)
        top = self._row - n
        keep = 0 if final else (top + n) % BLOCK_PX
        if n - keep <= 0:
            return
        rows = np.concatenate(self._pending, axis=0)
        self._dst.write(np.moveaxis(rows[:n - keep], 2, 0), window=Window(0, top, self.cols, n - keep))
        self._pending = [rows[n - keep:]] if keep else []

    def __exit__(self, et: Any, ev: Any, tb: Any) -> bool:
        if et is None and self._row != self.rows:
            err = ValueError(f"{self.path}: only {self._row} of {self.rows} rows written")
            self._stack.__exit__(ValueError, err, None)   # removes the temporary files
            raise err
        if et is not None:
            self._stack.__exit__(et, ev, tb)
            return False
        try:
            import rasterio.shutil

            self._dst.close()
            opts = {k: v for k, v in _cog_options(self._profile).items() if k in _CREATION_OPTIONS}
            rasterio.shutil.copy(self._tiled, self._final, **opts)
        except BaseException as ex:
            self._stack.__exit__(type(ex), ex, ex.__traceback__)
            raise
        self._stack.__exit__(None, None, None)
        return False


# --------------------------------------------------------------------------- reading
_MAGIC = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")


def read_geotiff(path: str | os.PathLike, *, raw: bool = False) -> tuple[np.ndarray, GeoTransform, Any]:
    """Read a GeoTIFF: values, north-up transform and CRS.

    Parameters
    ----------
    path : path-like
        Any GeoTIFF GDAL reads (compressed, tiled, BigTIFF, any data type).
    raw : bool
        Keep the stored data type and values; by default the values are
        floats (float64 when stored so, else float32) with NaN where the file
        says nodata.

    Returns
    -------
    grid : ndarray, shape (rows, cols) for one band, (rows, cols, bands) for more
    transform : GeoTransform
    crs : pyproj.CRS or None
        As in the file (an EPSG code GDAL identifies, compound ones included,
        else the file's WKT); check it against what you expect.

    Raises
    ------
    TileIOError
        The file is missing or unreadable.
    LidarFormatError
        Not a TIFF, truncated, not georeferenced, or not a north-up grid of
        square cells.
    """
    import rasterio
    import rasterio.errors

    path = Path(path)
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except FileNotFoundError:
        raise TileIOError(f"{path}: file not found") from None
    except OSError as ex:
        raise TileIOError(f"{path}: cannot read ({ex.strerror})") from ex
    if head not in _MAGIC:
        raise LidarFormatError(f"{path}: not a little-endian TIFF, nor a big-endian or BigTIFF one")
    try:
        with rasterio.open(path) as ds:
            a, b, c, d, e, f = (ds.transform.a, ds.transform.b, ds.transform.c,
                                ds.transform.d, ds.transform.e, ds.transform.f)
            if ds.transform.is_identity or b != 0 or d != 0 or not (a > 0 and e < 0):
                raise LidarFormatError(f"{path}: not a north-up georeferenced grid (geotransform "
                                       f"{(c, a, b, f, d, e)})")
            if not math.isclose(a, -e, rel_tol=1e-9):
                raise LidarFormatError(f"{path}: cells of {a:g} x {-e:g} are not square; resample the "
                                       "grid to square cells (e.g. gdalwarp -tr)")
            data = ds.read()
            nodata = ds.nodata
            crs = _pyproj_crs(ds.crs)
    except rasterio.errors.RasterioError as ex:
        raise LidarFormatError(f"{path}: truncated or incomplete GeoTIFF ({str(ex).splitlines()[0]})") from ex
    except UnicodeDecodeError as ex:  # a text tag (CRS WKT, nodata, citation) that is not text
        raise LidarFormatError(f"{path}: corrupt GeoTIFF: a text tag is not UTF-8 text (byte {ex.start})") from ex
    grid = data[0] if data.shape[0] == 1 else np.moveaxis(data, 0, 2)
    if not raw:
        stored = grid
        grid = grid.astype(np.float64 if grid.dtype == np.float64 else np.float32)
        if nodata is not None and not math.isnan(nodata):
            grid[stored == nodata] = np.nan
    return grid, GeoTransform(float(c), float(f), float(a)), crs
