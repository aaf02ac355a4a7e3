"""Shared by the orthophoto and the mosaic: z-buffer, cell centres, row bands streamed into a GeoTIFF.

Private to :mod:`lidarcat.mapping` (imported by :mod:`.ortho` and :mod:`.mosaic`).  :func:`run_bands`
computes row bands one after the other (float32, NaN = nodata); :func:`run_tiles` computes tiles in a
thread pool and writes the photo's data type with an internal mask (:mod:`.ortho`, "Tiles, threads and
the file").
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_write
from ..errors import LidarcatError
from ..lidar.geotiff import GeoTiffWriter

__all__ = ["ZBuffer", "tile_cells", "row_bands", "run_bands", "run_tiles", "remap_points", "write_png"]


class ZBuffer:
    """Smallest depth per bin of photo pixels, from the DSM cells around the output area."""

    def __init__(self, photo: Any, surface: Any, bounds: Sequence[float], tol_m: float | None = None):
        import cv2

        cell = float(surface.transform.cell_m)
        cam = photo.camera
        height = photo.eo_params[2] - float(np.nanmedian(surface.grid))
        gsd_photo = cam.pixel_size_x_mm * height / cam.focal_length_mm
        self.bin = max(1, int(math.ceil(cell / max(gsd_photo, 1e-9))))
        self.tol = 3.0 * cell if tol_m is None else float(tol_m)
        nb_r = cam.rows_px // self.bin + 3   # bins -1 .. N/bin + 1 (projections up to a bin off the frame)
        nb_c = cam.columns_px // self.bin + 3
        z = np.full(nb_r * nb_c, np.inf)
        t = surface.transform
        g = surface.grid
        xmin, ymin, xmax, ymax = bounds
        margin = 60.0
        c0 = max(0, int((xmin - margin - t.x0) / cell))
        c1 = min(g.shape[1], int(math.ceil((xmax + margin - t.x0) / cell)))
        r0 = max(0, int((t.y0 - ymax - margin) / cell))
        r1 = min(g.shape[0], int(math.ceil((t.y0 - ymin + margin) / cell)))
        cols = np.arange(c0, c1)
        for rs in range(r0, r1, 256):
            rows = np.arange(rs, min(rs + 256, r1))
            e, n = t.xy(rows[:, None], cols[None, :])
            e, n = np.broadcast_arrays(e, n)
            h = g[rows[:, None], cols[None, :]]
            ok = np.isfinite(h)
            col, row, depth = photo.project(e[ok], n[ok], h[ok])
            keep = np.isfinite(col) & (col > -self.bin) & (row > -self.bin) \
                & (col < cam.columns_px + self.bin) & (row < cam.rows_px + self.bin)
            bi = (np.floor(row[keep] / self.bin).astype(np.int64) + 1) * nb_c \
                + np.floor(col[keep] / self.bin).astype(np.int64) + 1
            np.minimum.at(z, bi, depth[keep])
        z = z.reshape(nb_r, nb_c).astype(np.float32)
        filled = cv2.erode(np.where(np.isinf(z), np.float32(3e38), z), np.ones((3, 3), np.uint8))
        self.z = np.where(np.isinf(z), filled, z)
        self.nb_c = nb_c

    def visible(self, col: np.ndarray, row: np.ndarray, depth: np.ndarray) -> np.ndarray:
        r = np.floor(row / self.bin).astype(np.int64) + 1
        c = np.floor(col / self.bin).astype(np.int64) + 1
        r = np.clip(r, 0, self.z.shape[0] - 1)
        c = np.clip(c, 0, self.z.shape[1] - 1)
        return depth <= self.z[r, c] + self.tol


def write_png(path: Path, grid: np.ndarray) -> Path:
    """A plain 8-bit PNG preview of a float grid (nodata black; values clipped to 0-255)."""
    import cv2

    g = np.nan_to_num(np.asarray(grid, dtype=np.float32), nan=0.0)
    g = np.clip(g, 0, 255).astype(np.uint8)
    if g.ndim == 3 and g.shape[2] == 3:
        g = g[:, :, ::-1]              # RGB -> BGR for OpenCV
    elif g.ndim == 3:
        g = g[:, :, 0]
    ok, buf = cv2.imencode(".png", g)
    if not ok:  # pragma: no cover - OpenCV failure
        raise LidarcatError(f"{path}: PNG encoding failed")
    with atomic_write(path, "wb") as fh:
        fh.write(buf.tobytes())
    return path


def tile_cells(transform: Any, r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray]:
    """E and N (m) of the cell centres of rows r0..r1-1 and columns c0..c1-1, each (rows, cols)."""
    e, n = transform.xy(np.arange(r0, r1)[:, None], np.arange(c0, c1)[None, :])
    return np.broadcast_arrays(e, n)


def row_bands(total_rows: int, cols: int, bands: int, tile_px: int) -> Iterator[tuple[int, int]]:
    """(first, past-last) rows of each band: at most *tile_px* rows and 64 MB of float32 values."""
    step = max(1, min(tile_px, (64 << 20) // max(cols * bands * 4, 1)))
    for r0 in range(0, total_rows, step):
        yield r0, min(total_rows, r0 + step)


def run_bands(compute: Callable[[int, int], np.ndarray], rows: int, cols: int, bands: int, tile_px: int,
              path: str | os.PathLike | None, transform: Any, crs: Any, preview: bool,
              progress: Callable[[int, int], None] | None) -> np.ndarray | None:
    """Compute the output band by band: stream it into *path* (+ PNG preview), or return the array."""
    if path is None:
        out = np.full((rows, cols, bands), np.nan, dtype=np.float32)
        for r0, r1 in row_bands(rows, cols, bands, tile_px):
            out[r0:r1] = compute(r0, r1)
            if progress:
                progress(r1, rows)
        return out
    path = Path(path)
    step = max(1, int(math.ceil(max(rows, cols) / 2000)))
    small: list[np.ndarray] = []
    with GeoTiffWriter(path, (rows, cols), bands, transform, crs) as tif:
        for r0, r1 in row_bands(rows, cols, bands, tile_px):
            band = compute(r0, r1)
            tif.write_rows(band)
            small.append(band[np.arange(r0, r1) % step == 0][:, ::step])
            if progress:
                progress(r1, rows)
    if preview:
        write_png(path.with_suffix(".png"), np.concatenate(small, axis=0))
    return None


def remap_points(grids: Sequence[np.ndarray], fx: np.ndarray, fy: np.ndarray) -> list[np.ndarray]:
    """Bilinear values of float32 grids at fractional (column, row) positions of any shape (``cv2.remap``).

    NaN where a position is off the grid (or a neighbour is NaN); ``cv2.remap`` quantises the
    interpolation weights to 1/32 of a cell.  Positions are processed as 2-D blocks of at most
    4096 columns (OpenCV's maps are limited in width).
    """
    import cv2

    fx = np.asarray(fx)
    shape = fx.shape
    mx = np.where(np.isfinite(fx), fx, -10.0).astype(np.float32).reshape(-1)
    my = np.where(np.isfinite(fy), fy, -10.0).astype(np.float32).reshape(-1)
    n = mx.size
    if len(shape) == 2 and 0 < shape[1] <= 4096:
        mx, my = mx.reshape(shape), my.reshape(shape)
    else:
        w = 4096 if n > 4096 else max(n, 1)
        pad = (-n) % w
        mx = np.concatenate([mx, np.full(pad, -10.0, np.float32)]).reshape(-1, w)
        my = np.concatenate([my, np.full(pad, -10.0, np.float32)]).reshape(-1, w)
    out = []
    for g in grids:
        v = cv2.remap(g, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                      borderValue=float("nan"))
        out.append(v.reshape(-1)[:n].reshape(shape).astype(np.float64))
    return out


def run_tiles(compute: Callable[[int, int, int, int], tuple[np.ndarray, np.ndarray, np.ndarray]], rows: int,
              cols: int, bands: int, tile_px: int, path: str | os.PathLike | None, transform: Any, crs: Any,
              preview: bool, progress: Callable[[int, int], None] | None, *, dtype: Any, compress: str = "deflate",
              workers: int | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """Compute the output in tiles on a thread pool, write it in row bands (or return it as an array).

    Parameters
    ----------
    compute : callable
        ``compute(r0, r1, c0, c1) -> (values, valid, occluded)``: values (rows, cols, bands) of
        *dtype*, valid and occluded cells (rows, cols) bool.  Called from the pool's threads.
    dtype : numpy dtype
        Of the file: integers get an internal mask of the valid cells, floats NaN.
    compress, workers
        GeoTIFF compression (``deflate``/``jpeg``), threads (default CPU count).

    Returns
    -------
    array : (rows, cols, bands) float32 with NaN, or None (written to *path*)
    counts : (3,) int64
        Valid, occluded and other (off the photo or the surface) cells.
    """
    import collections
    import concurrent.futures

    import cv2

    dtype = np.dtype(dtype)
    workers = max(1, int(workers or os.cpu_count() or 1))
    step = max(16, int(tile_px))
    band_rows = [(r0, min(rows, r0 + step)) for r0 in range(0, rows, step)]
    col_tiles = [(c0, min(cols, c0 + step)) for c0 in range(0, cols, step)]
    ahead = max(2, -(-2 * workers // len(col_tiles)))          # bands in flight
    counts = np.zeros(3, dtype=np.int64)
    out = np.full((rows, cols, bands), np.nan, dtype=np.float32) if path is None else None
    integer = dtype.kind in "iu"
    small: list[np.ndarray] = []
    pstep = max(1, int(math.ceil(max(rows, cols) / 2000)))
    with contextlib.ExitStack() as stack:
        tif = None
        if path is not None:
            tif = stack.enter_context(GeoTiffWriter(Path(path), (rows, cols), bands, transform, crs, dtype,
                                                    compress=compress.upper(), mask=integer, threads=workers))
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)                        # one OpenCV thread per pool thread
        stack.callback(cv2.setNumThreads, threads)
        pool = stack.enter_context(concurrent.futures.ThreadPoolExecutor(max_workers=workers))
        stack.callback(pool.shutdown, wait=True, cancel_futures=True)   # on an error: drop what is queued
        pending: collections.deque[tuple[int, int, list[Any]]] = collections.deque()
        todo = iter(band_rows)

        def submit() -> None:
            nxt = next(todo, None)
            if nxt is not None:
                pending.append((*nxt, [pool.submit(compute, nxt[0], nxt[1], c0, c1) for c0, c1 in col_tiles]))

        for _ in range(ahead):
            submit()
        while pending:
            r0, r1, futs = pending.popleft()
            submit()
            vals = np.empty((r1 - r0, cols, bands), dtype=dtype)
            valid = np.empty((r1 - r0, cols), dtype=bool)
            for (c0, c1), f in zip(col_tiles, futs):
                v, ok, occl = f.result()
                vals[:, c0:c1] = v
                valid[:, c0:c1] = ok
                n_ok, n_occl = int(ok.sum()), int(occl.sum())
                counts += (n_ok, n_occl, ok.size - n_ok - n_occl)
            if out is not None or not integer or preview:
                as_float = vals.astype(np.float32)
                as_float[~valid] = np.nan
            if out is not None:
                out[r0:r1] = as_float
            else:
                assert tif is not None
                if integer:
                    tif.write_rows(vals, valid)
                else:
                    tif.write_rows(as_float)
                if preview:
                    keep = np.arange(r0, r1) % pstep == 0
                    small.append(as_float[keep][:, ::pstep] / (257.0 if dtype == np.uint16 else 1.0))
            if progress:
                progress(r1, rows)
    if path is not None and preview:
        write_png(Path(path).with_suffix(".png"), np.concatenate(small, axis=0))
    return out, counts
