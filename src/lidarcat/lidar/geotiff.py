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

Images (orthophotos) may ask for more (keyword arguments of :class:`GeoTiffWriter`,
defaults as above): ``compress="JPEG"`` (8-bit images; YCbCr for RGB, quality
``jpeg_quality``), ``mask=True`` -- an internal per-dataset mask (GDAL's
``.msk`` band inside the file, 1 bit per cell, DEFLATE) marks the valid cells
of an integer image, so that every value 0..255 (0..65535) stays a value and
lossy JPEG cannot blur the nodata edge -- ``threads`` (GDAL's
``NUM_THREADS``: tiles and overviews compressed in parallel) and ``cog=False``:
the rows go straight into the final tiled GeoTIFF, the overviews (average,
halving down to one tile) are added at the end -- no second compression pass
(4x faster on a 14 MP RGB image), but the overviews follow the full-resolution
tiles instead of preceding them (``gdal_translate -of COG`` reorders them).
:func:`read_geotiff` returns NaN where a file's mask says nodata.

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
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from ..errors import LidarFormatError, ProductError, TileIOError
from .crs import resolve_crs

__all__ = ["write_bands", "write_vrt", "GeoTransform", "write_geotiff", "read_geotiff", "GeoTiffWriter", "geotiff_crs", "BLOCK_PX"]

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
def _profile(rows: int, cols: int, bands: int, dtype: np.dtype, transform: GeoTransform, crs: Any,
             compress: str = "DEFLATE", mask: bool = False) -> dict[str, Any]:
    from rasterio.transform import Affine

    profile: dict[str, Any] = {
        "width": int(cols), "height": int(rows), "count": int(bands), "dtype": dtype.name,
        "transform": Affine(transform.cell_m, 0.0, transform.x0, 0.0, -transform.cell_m, transform.y0),
        "crs": geotiff_crs(crs), "compress": "DEFLATE", "predictor": 2, "bigtiff": "IF_SAFER",
    }
    if compress.upper() == "JPEG":
        if dtype != np.uint8 or bands not in (1, 3):
            raise ValueError(f"JPEG compression takes 1- or 3-band uint8 images, not {bands} x {dtype.name}")
        profile["compress"] = "JPEG"
        del profile["predictor"]
    elif compress.upper() != "DEFLATE":
        raise ValueError(f"compression must be DEFLATE or JPEG, got {compress!r}")
    if dtype.kind == "f" and not mask:
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
    compress : {"DEFLATE", "JPEG"}
        JPEG for 1- or 3-band uint8 images only (lossy; YCbCr for RGB).
    mask : bool
        Write an internal per-dataset mask: :meth:`write_rows` takes each
        block's valid cells (module docstring).
    threads : int, optional
        GDAL ``NUM_THREADS`` of the compression (default: one).
    jpeg_quality : int
        JPEG quality, 1-100 (GDAL's default 75).
    cog : bool
        Cloud-optimised layout (a copy at the end), or the tiled GeoTIFF written
        directly with overviews added (module docstring).
    deflate_level : int, optional
        DEFLATE level 1-12 (default GDAL's 6; 1 writes a 14 MP RGB orthophoto
        3.7x faster for a 6 % larger file).
    """

    def __init__(self, path: str | os.PathLike, shape: tuple[int, int], bands: int, transform: GeoTransform,
                 crs: Any = None, dtype: Any = np.float32, *, compress: str = "DEFLATE", mask: bool = False,
                 threads: int | None = None, jpeg_quality: int = 75, cog: bool = True,
                 deflate_level: int | None = None) -> None:
        self.path = Path(path)
        self.rows, self.cols = (int(v) for v in shape)
        self.bands = int(bands)
        self.dtype = np.dtype(dtype)
        self.transform = transform
        self._profile = _profile(self.rows, self.cols, self.bands, self.dtype, transform, crs, compress, mask)
        self._mask = bool(mask)
        self._cog = bool(cog)
        self._extra: dict[str, Any] = {}
        if threads and threads > 1:
            self._extra["num_threads"] = str(int(threads))
        if self._profile["compress"] == "JPEG":
            self._extra["quality"] = int(jpeg_quality)
        elif deflate_level is not None:
            self._extra["level"] = int(deflate_level)
        self._row = 0
        self._pending: list[np.ndarray] = []
        self._pending_mask: list[np.ndarray] = []
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> GeoTiffWriter:
        import rasterio

        stack = self._stack
        try:
            self._final = stack.enter_context(_atomic_target(self.path))
            if not self._cog:
                stack.enter_context(rasterio.Env(GDAL_CACHEMAX=_STREAM_CACHE_MB, GDAL_TIFF_INTERNAL_MASK=True))
                direct = dict(self._profile)
                if direct["compress"] == "JPEG":
                    direct.update(photometric="YCbCr" if self.bands == 3 else "MINISBLACK",
                                  jpeg_quality=self._extra["quality"])
                elif "level" in self._extra:
                    direct["zlevel"] = self._extra["level"]
                    stack.enter_context(rasterio.Env(ZLEVEL_OVERVIEW=self._extra["level"]))
                self._dst = stack.enter_context(rasterio.open(
                    self._final, "w", driver="GTiff", tiled=True, blockxsize=BLOCK_PX, blockysize=BLOCK_PX,
                    interleave="pixel", **direct, **{k: v for k, v in self._extra.items() if k == "num_threads"}))
                if self.bands == 3 and direct["compress"] != "JPEG":
                    self._dst.colorinterp = _rgb()
                return self
            fd, name = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tiled", dir=self.path.parent)
            os.close(fd)
            self._tiled = Path(name)
            stack.callback(self._tiled.unlink, missing_ok=True)
            stack.enter_context(rasterio.Env(GDAL_CACHEMAX=_STREAM_CACHE_MB, GDAL_TIFF_INTERNAL_MASK=True))
            tiled = dict(self._profile, compress="DEFLATE", predictor=2) if self._mask or \
                self._profile["compress"] == "JPEG" else self._profile   # the temporary file: lossless
            self._dst = stack.enter_context(rasterio.open(
                self._tiled, "w", driver="GTiff", tiled=True, blockxsize=BLOCK_PX, blockysize=BLOCK_PX,
                interleave="pixel", **tiled, **{k: v for k, v in self._extra.items() if k == "num_threads"}))
            if self.bands == 3:
                self._dst.colorinterp = _rgb()
        except BaseException:
            stack.close()
            raise
        return self

    def write_rows(self, block: np.ndarray, valid: np.ndarray | None = None) -> None:
        """Append rows: (k, cols) or (k, cols, bands) values (cast to the file's data type); with
        ``mask=True`` also their (k, cols) valid cells (bool)."""
        b = np.asarray(block)
        if b.ndim == 2:
            b = b[:, :, None]
        if b.shape[1:] != (self.cols, self.bands) or self._row + b.shape[0] > self.rows:
            raise ValueError(f"{self.path}: row block of shape {b.shape} does not fit a "
                             f"{self.rows} x {self.cols} x {self.bands} grid at row {self._row}")
        if self._mask:
            if valid is None or np.shape(valid) != b.shape[:2]:
                raise ValueError(f"{self.path}: a masked GeoTIFF needs the valid cells of each row block "
                                 f"(shape {b.shape[:2]})")
            self._pending_mask.append(np.asarray(valid, dtype=bool))
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
        win = Window(0, top, self.cols, n - keep)
        self._dst.write(np.moveaxis(rows[:n - keep], 2, 0), window=win)
        self._pending = [rows[n - keep:]] if keep else []
        if self._mask:
            valid = np.concatenate(self._pending_mask, axis=0)
            self._dst.write_mask(np.where(valid[:n - keep], np.uint8(255), np.uint8(0)), window=win)
            self._pending_mask = [valid[n - keep:]] if keep else []

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

            if not self._cog:
                from rasterio.enums import Resampling

                factors, f = [], 2
                while max(self.rows, self.cols) / (f // 2) > BLOCK_PX:
                    factors.append(f)
                    f *= 2
                if factors:
                    self._dst.build_overviews(factors, Resampling.average)
                self._dst.close()
                self._stack.__exit__(None, None, None)
                return False
            self._dst.close()
            opts = {k: v for k, v in _cog_options(self._profile).items() if k in _CREATION_OPTIONS}
            if self._profile["compress"] == "JPEG":
                opts.pop("predictor", None)
            with rasterio.Env(GDAL_TIFF_INTERNAL_MASK=True):
                rasterio.shutil.copy(self._tiled, self._final, **opts, **self._extra)
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
            masked = None
            if not raw and nodata is None and any(f.name == "per_dataset" for f in ds.mask_flag_enums[0]):
                masked = ds.dataset_mask() == 0           # an internal mask (module docstring)
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
        if masked is not None:
            grid[masked] = np.nan
    return grid, GeoTransform(float(c), float(f), float(a)), crs


def write_bands(path: str | os.PathLike, bands: np.ndarray, transform: GeoTransform, crs: Any,
                names: Sequence[str]) -> Path:
    """Write a (bands, rows, cols) stack as one cloud-optimised GeoTIFF with named bands, atomically.

    As :func:`write_geotiff` (floats as float32, NaN nodata, the CRS on the
    file), and each band's description set to its name (``gdalinfo`` and
    rasterio's ``descriptions`` show it).
    """
    import rasterio

    path = Path(path)
    a = np.asarray(bands)
    if a.ndim != 3 or len(names) != a.shape[0]:
        raise ValueError(f"give a (bands, rows, cols) stack and one name per band, got {a.shape} and {len(names)}")
    vals = _values(np.moveaxis(a, 0, 2))
    profile = _profile(vals.shape[1], vals.shape[2], vals.shape[0], vals.dtype, transform, crs)
    with _atomic_target(path) as tmp:
        with rasterio.open(tmp, "w", **_cog_options(profile)) as dst:
            dst.write(vals)
            for i, n in enumerate(names, start=1):
                dst.set_band_description(i, str(n))
    return path


def write_vrt(path: str | os.PathLike, sources: Sequence[str | os.PathLike]) -> Path:
    """A GDAL virtual mosaic (VRT) of GeoTIFFs on one lattice, atomically.

    The sources must share CRS, cell size, band count and data type (the tile
    GeoTIFFs of one product are on one lattice: origins at multiples of the
    cell).  Each source is placed by its origin (no resampling); where tiles
    overlap, the later one wins (GDAL draws sources in order).  Paths are
    written relative to the VRT's folder when they lie below it.  rasterio and
    GDAL open the VRT as one raster; the CRS is written into it.

    Raises
    ------
    ValueError
        No sources.
    ProductError
        Sources that differ in CRS, cell, bands or data type.
    """
    import xml.etree.ElementTree as ET

    import rasterio

    from .._util import atomic_write

    path = Path(path)
    if not sources:
        raise ValueError("a VRT needs at least one source GeoTIFF")
    meta = []
    for src in sources:
        with rasterio.open(src) as ds:
            meta.append((Path(src), ds.crs, ds.transform, ds.width, ds.height, ds.count, ds.dtypes[0], ds.nodata,
                         ds.descriptions))
    _, crs0, t0, _, _, count0, dtype0, nodata0, desc0 = meta[0]
    cell = t0.a
    for src, crs, t, _, _, count, dtype, _, _ in meta[1:]:
        if crs != crs0 or abs(t.a - cell) > 1e-9 * abs(cell) or abs(t.e - t0.e) > 1e-9 * abs(cell) \
                or count != count0 or dtype != dtype0:
            raise ProductError(f"{src}: not on the lattice of {meta[0][0]} (CRS, cell, bands and data type must agree)")
    x0 = min(m[2].c for m in meta)
    y0 = max(m[2].f for m in meta)
    x1 = max(m[2].c + m[3] * cell for m in meta)
    y1 = min(m[2].f + m[4] * t0.e for m in meta)
    cols = int(round((x1 - x0) / cell))
    rows = int(round((y1 - y0) / t0.e))
    root = ET.Element("VRTDataset", rasterXSize=str(cols), rasterYSize=str(rows))
    ET.SubElement(root, "SRS").text = crs0.to_wkt() if crs0 is not None else ""
    ET.SubElement(root, "GeoTransform").text = f"{x0!r}, {cell!r}, 0.0, {y0!r}, 0.0, {t0.e!r}"
    gdal_type = {"float32": "Float32", "float64": "Float64", "uint8": "Byte", "uint16": "UInt16",
                 "int16": "Int16", "uint32": "UInt32", "int32": "Int32"}[dtype0]
    for b in range(1, count0 + 1):
        band = ET.SubElement(root, "VRTRasterBand", dataType=gdal_type, band=str(b))
        if desc0[b - 1]:
            ET.SubElement(band, "Description").text = desc0[b - 1]
        if nodata0 is not None:
            ET.SubElement(band, "NoDataValue").text = "nan" if np.isnan(nodata0) else repr(nodata0)
        for src, _, t, w, h, _, _, _, _ in meta:
            try:
                name, rel = src.resolve().relative_to(path.parent.resolve()).as_posix(), "1"
            except ValueError:
                name, rel = str(src.resolve()), "0"
            s = ET.SubElement(band, "ComplexSource" if nodata0 is not None else "SimpleSource")
            ET.SubElement(s, "SourceFilename", relativeToVRT=rel).text = name
            ET.SubElement(s, "SourceBand").text = str(b)
            ET.SubElement(s, "SrcRect", xOff="0", yOff="0", xSize=str(w), ySize=str(h))
            ET.SubElement(s, "DstRect", xOff=str(int(round((t.c - x0) / cell))),
                          yOff=str(int(round((t.f - y0) / t0.e))), xSize=str(w), ySize=str(h))
            if nodata0 is not None:
                ET.SubElement(s, "NODATA").text = "nan" if np.isnan(nodata0) else repr(nodata0)
    ET.indent(root)
    with atomic_write(path, "w") as fh:
        fh.write(ET.tostring(root, encoding="unicode") + "\n")
    return path
