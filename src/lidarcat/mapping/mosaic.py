r"""Orthomosaic: per output cell, the most nadir photo that sees it; seamlines as polygons.

Every photo is sampled at every output cell as in :mod:`lidarcat.mapping.ortho`
(surface height, collinearity, distortion look-up, bilinear resampling, and
with ``true_ortho`` the photo's z-buffer).  Among the photos whose frame holds
the cell and that see it, the cell takes the one with the smallest off-nadir
tangent

.. math::  \tan\theta = \frac{\sqrt{(E - X_0)^2 + (N - Y_0)^2}}{Z_0 - h},

the least building lean and the least relief displacement; hidden cells thus
come from a photo that sees them.  A cell no photo sees stays nodata.

Feathering (``feather_m`` > 0, optional; default hard seams): across a seam
the photos are blended over a band of ``2 feather_m``.  With ``s_i`` the
signed distance (m) of a cell to the boundary of photo *i*'s region (positive
inside, negative outside; ``cv2.distanceTransform``, exact), each photo that
sees the cell weighs

.. math::  w_i = \mathrm{clip}\left(\tfrac12 + \frac{s_i}{2 f}, 0, 1\right),

and the cell is :math:`\sum w_i v_i / \sum w_i`: half and half on the seam,
the chosen photo alone from ``f`` inside its region on.  A cell's distances up
to ``f`` depend only on the choice within ``f`` of it, so every tile is
computed with a margin of ``f`` and the result does not depend on the tiling.
Occluded cells of a true orthomosaic get no weight from the photo that does not
see them.  The seamlines and the labels stay those of the hard choice.

Radiometric equalisation
------------------------
(``equalize=True``, optional; report 12.1: the photos are balanced to each
other before mosaicking.)  Each photo *i* and band gets a gain and an offset,
:math:`v' = g_i v + o_i`, estimated from the overlaps: at every cell of a
regular sample of the output grid (at most ``max_samples`` cells) that photos
*i* and *j* both see, the balanced values should agree,

.. math::  g_i v_i + o_i - g_j v_j - o_j = 0,

and the least-squares solution over all overlaps, with the datum
:math:`\frac1n \sum g_i = 1`, :math:`\sum o_i = 0` (mean gain 1, mean
offset 0: the block keeps its overall brightness; exact, by Lagrange
multipliers), minimises the squared
disagreements.  The normal equations need only the moments of each pair
(:math:`\sum v_i^2, \sum v_i v_j, \sum v_j^2, \sum v_i, \sum v_j`, count),
so they are :math:`2n \times 2n` whatever the overlaps hold.  A photo with no
overlap keeps gain 1, offset 0 (a weak prior, 1e-9 of the data's weight).
The balanced values then go into the choice and the feathering as the raw
ones did.

Seam contrast (:func:`seam_contrast`): for each pair of photos sharing a
seamline, the mean over the neighbouring cell pairs straddling it (a cell of
*i* beside a cell of *j*, rows and columns) of :math:`v_{side\,i} - v_{side\,j}`,
its absolute value weighted by the number of such pairs, averaged over the
bands.  Texture differences between neighbours average out in the signed mean;
an exposure step between the photos does not.

Seamlines
---------
The choice is kept on a label grid (one label per ``k x k`` cells, ``k`` so
that the label grid stays below 16 million cells); ``cv2.findContours`` traces
the region of each photo (outer rings and holes), written as a GeoJSON
FeatureCollection of (Multi)Polygons, one feature per photo (property
``photo``, area in m^2), with the survey CRS as a named ``crs`` member (read by
GDAL/QGIS).  The boundaries between the regions are the seamlines.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_text_atomic
from ._raster_cells import ZBuffer, run_bands, tile_cells
from .ortho import OrthoError, PhotoModel, output_grid, sample_photo

__all__ = ["MosaicResult", "mosaic", "seam_polygons", "equalization_gains", "seam_contrast"]

log = logging.getLogger(__name__)

_MAX_LABEL_CELLS = 16_000_000


@dataclass(frozen=True)
class MosaicResult:
    """What :func:`mosaic` made.

    Attributes
    ----------
    path, seams_path : Path or None
        Mosaic GeoTIFF and seamline GeoJSON (None when not written).
    array : ndarray or None
        (rows, cols, bands) float32 mosaic, NaN = nodata (only without *path*).
    labels : ndarray
        (rows/k, cols/k) int16: index of the photo chosen per label cell (-1: none).
    label_step : int
        k, output cells per label cell.
    transform : GeoTransform
    shape : (rows, cols)
    cells_per_photo : dict[str, int]
    n_nodata : int
    gains : ndarray or None
        (photos, bands, 2) gain and offset of each photo and band (``equalize``), else None.
    """

    path: Path | None
    seams_path: Path | None
    array: np.ndarray | None
    labels: np.ndarray
    label_step: int
    transform: Any
    shape: tuple[int, int]
    cells_per_photo: dict[str, int]
    n_nodata: int
    gains: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        out = {"path": str(self.path) if self.path else None,
               "seams": str(self.seams_path) if self.seams_path else None,
               "x0": self.transform.x0, "y0": self.transform.y0, "gsd_m": self.transform.cell_m,
               "rows": self.shape[0], "cols": self.shape[1], "cells_per_photo": self.cells_per_photo,
               "n_nodata": self.n_nodata}
        if self.gains is not None:   # per photo: [[gain, offset] per band]
            out["gains"] = {pid: np.round(g, 6).tolist() for pid, g in zip(self.cells_per_photo, self.gains)}
        return out


def _union_bounds(photos: Sequence[PhotoModel], surface: Any) -> tuple[float, float, float, float]:
    h = float(np.nanmedian(surface.grid))
    fps = np.vstack([p.footprint(h) for p in photos])
    sb = surface.bounds
    b = (max(fps[:, 0].min(), sb[0]), max(fps[:, 1].min(), sb[1]),
         min(fps[:, 0].max(), sb[2]), min(fps[:, 1].max(), sb[3]))
    if not (b[2] > b[0] and b[3] > b[1]):
        raise OrthoError("the surface model does not cover the photos' footprints")
    return b


def mosaic(photos: Sequence[PhotoModel], surface: Any, gsd_m: float, path: str | os.PathLike | None = None, *,
           seams_path: str | os.PathLike | None = None, bounds: Sequence[float] | None = None,
           true_ortho: bool = True, crs: Any = None, tile_px: int = 1024, preview: bool = True,
           feather_m: float = 0.0, equalize: bool = False, max_samples: int = 250_000,
           progress: Callable[[int, int], None] | None = None) -> MosaicResult:
    """Mosaic orthorectified photos, the most nadir visible view per cell (module docstring).

    Parameters
    ----------
    photos : sequence of PhotoModel
        With the same number of bands.
    surface : lidarcat.mapping.monoplot.GridSurface
        DSM (true orthomosaic, ``true_ortho``) or DTM.
    gsd_m : float
        Output cell size, m.
    path : path-like, optional
        Mosaic GeoTIFF (+ ``.png`` preview); without it the array is returned.
    seams_path : path-like, optional
        Seamline polygons (GeoJSON).
    bounds : (xmin, ymin, xmax, ymax), optional
        Default: the union of the photo footprints, clipped to the surface.
    true_ortho : bool
        Use each photo's z-buffer (cells a photo does not see come from another).
    crs : CRS-like, optional
    tile_px : int
    preview : bool
    feather_m : float
        Half width of the blend across seamlines, m (0: hard seams; module docstring).
    equalize : bool
        Balance the photos first: a gain and an offset per photo and band from the overlaps
        (:func:`equalization_gains`, module docstring).
    max_samples : int
        Cells of the output grid sampled for the equalisation (a regular subsample).
    progress : callable, optional
        ``progress(done_rows, total_rows)``.

    Returns
    -------
    MosaicResult

    Raises
    ------
    OrthoError
        No photo, photos with different band counts, a surface that does not cover them.
    """
    from .monoplot import GridSurface

    if not photos:
        raise OrthoError("mosaic: no photo given")
    if len({p.bands for p in photos}) != 1:
        raise OrthoError("mosaic: the photos have different numbers of bands (" +
                         ", ".join(f"{p.photo_id}: {p.bands}" for p in photos) + ")")
    if len({p.photo_id for p in photos}) != len(photos):
        raise OrthoError("mosaic: a photo id is given twice")
    if not isinstance(surface, GridSurface):
        raise OrthoError("mosaics need a gridded DTM/DSM (GridSurface)")
    if not (math.isfinite(feather_m) and feather_m >= 0):
        raise OrthoError(f"mosaic: feather_m must be >= 0 (metres), got {feather_m!r}")
    if surface.interpolator != "bilinear":
        surface = GridSurface(surface.grid, surface.transform, "bilinear", surface.sd_m)
    bounds = _union_bounds(photos, surface) if bounds is None else bounds
    transform, rows, cols = output_grid(bounds, gsd_m)
    full = (transform.x0, transform.y0 - rows * gsd_m, transform.x0 + cols * gsd_m, transform.y0)
    zbufs = [ZBuffer(p, surface, full) if true_ortho else None for p in photos]
    bands = photos[0].bands
    k = max(1, int(math.ceil(math.sqrt(rows * cols / _MAX_LABEL_CELLS))))
    labels = np.full(((rows + k - 1) // k, (cols + k - 1) // k), -1, dtype=np.int16)
    counts = np.zeros(len(photos) + 1, dtype=np.int64)
    tile_px = max(16, int(tile_px))
    margin = int(math.ceil(feather_m / gsd_m)) if feather_m > 0 else 0
    gains = (equalization_gains(photos, surface, transform, rows, cols, zbufs, max_samples)
             if equalize and len(photos) > 1 else None)

    def compute(r0: int, r1: int) -> np.ndarray:
        band = np.full((r1 - r0, cols, bands), np.nan, dtype=np.float32)
        for c0 in range(0, cols, tile_px):
            c1 = min(cols, c0 + tile_px)
            b = margin
            e, n = tile_cells(transform, r0 - b, r1 + b, c0 - b, c1 + b)
            best = np.full(e.shape, np.inf)
            choice = np.full(e.shape, -1, dtype=np.int16)
            vals_out = np.full(e.shape + (bands,), np.nan, dtype=np.float32)
            seen = []
            for i, (p, zb) in enumerate(zip(photos, zbufs)):
                vals, ok, _, tan = sample_photo(p, surface, e, n, zb)
                if gains is not None:
                    vals = (vals * gains[i, :, 0] + gains[i, :, 1]).astype(np.float32)
                better = ok & (tan < best)
                best[better] = tan[better]
                choice[better] = i
                vals_out[better] = vals[better]
                if b:
                    seen.append((i, vals, ok))
            if b:
                vals_out = _feather(seen, choice, vals_out, feather_m / gsd_m)
                inner = (slice(b, b + r1 - r0), slice(b, b + c1 - c0))
                choice, vals_out = choice[inner], vals_out[inner]
            band[:, c0:c1] = vals_out
            counts[:-1] += np.bincount(choice[choice >= 0].ravel(), minlength=len(photos))
            counts[-1] += int((choice < 0).sum())
            rr = np.arange(r0, r1)
            cc = np.arange(c0, c1)
            sr, sc = rr % k == 0, cc % k == 0
            labels[rr[sr][:, None] // k, cc[sc][None, :] // k] = choice[np.ix_(sr, sc)]
        return band

    out_arr = run_bands(compute, rows, cols, bands, tile_px, path, transform, crs, preview, progress)
    if seams_path is not None:
        seams_path = Path(seams_path)
        from ..lidar.geotiff import GeoTransform

        lt = GeoTransform(transform.x0, transform.y0, transform.cell_m * k)
        write_text_atomic(seams_path, json.dumps(seam_polygons(labels, lt, [p.photo_id for p in photos], crs)))
    per = {p.photo_id: int(c) for p, c in zip(photos, counts[:-1])}
    log.info("mosaic of %d photos: %d x %d cells of %.3g m; %s", len(photos), cols, rows, gsd_m, per)
    return MosaicResult(Path(path) if path is not None else None, seams_path, out_arr, labels, k, transform,
                        (rows, cols), per, int(counts[-1]), gains)


def equalization_gains(photos: Sequence[PhotoModel], surface: Any, transform: Any, rows: int, cols: int,
                       zbufs: Sequence[Any], max_samples: int = 250_000) -> np.ndarray:
    """Gain and offset of each photo and band from the overlaps (module docstring).

    Parameters
    ----------
    photos : sequence of PhotoModel
    surface : GridSurface
    transform, rows, cols
        The output grid.
    zbufs : sequence of ZBuffer or None
        Per photo (None: every cell of the frame counts as seen).
    max_samples : int
        At most this many output cells are sampled (every s-th row and column).

    Returns
    -------
    ndarray, shape (photos, bands, 2)
        ``[gain, offset]``; mean gain 1 and mean offset 0 over the photos, per band.
    """
    n, bands = len(photos), photos[0].bands
    s = max(1, int(math.ceil(math.sqrt(rows * cols / max(1, max_samples)))))
    rr, cc = np.arange(0, rows, s), np.arange(0, cols, s)
    e = transform.x0 + (cc[None, :] + 0.5) * transform.cell_m + 0 * rr[:, None]
    nn = transform.y0 - (rr[:, None] + 0.5) * transform.cell_m + 0 * cc[None, :]
    vals, oks = [], []
    for p, zb in zip(photos, zbufs):
        v, ok, _, _ = sample_photo(p, surface, e, nn, zb)
        ok &= np.isfinite(v).all(axis=-1)
        vals.append(v.reshape(-1, bands).astype(np.float64))
        oks.append(ok.ravel())
    out = np.zeros((n, bands, 2))
    for b in range(bands):
        N = np.zeros((2 * n, 2 * n))
        for i in range(n):
            for j in range(i + 1, n):
                both = oks[i] & oks[j]
                if not both.any():
                    continue
                vi, vj = vals[i][both, b], vals[j][both, b]
                # row r = [v_i at g_i, 1 at o_i, -v_j at g_j, -1 at o_j]: N += sum r r^T
                idx = [i, n + i, j, n + j]
                cols_ = [vi, np.ones_like(vi), -vj, -np.ones_like(vj)]
                for a in range(4):
                    for c in range(a, 4):
                        m = float(np.dot(cols_[a], cols_[c]))
                        N[idx[a], idx[c]] += m
                        if a != c:
                            N[idx[c], idx[a]] += m
        w = max(float(np.trace(N)), 1.0)
        cg = np.r_[np.ones(n), np.zeros(n)]
        co = np.r_[np.zeros(n), np.ones(n)]
        # weak prior gain 1, offset 0 (a photo without overlap), then the datum as exact constraints
        # (Lagrange multipliers): sum g = n, sum o = 0
        K = np.zeros((2 * n + 2, 2 * n + 2))
        K[:2 * n, :2 * n] = N + 1e-9 * w * np.eye(2 * n)
        K[:2 * n, 2 * n], K[:2 * n, 2 * n + 1] = cg, co
        K[2 * n, :2 * n], K[2 * n + 1, :2 * n] = cg, co
        rhs = np.r_[1e-9 * w * cg, n, 0.0]
        x = np.linalg.solve(K, rhs)
        out[:, b, 0], out[:, b, 1] = x[:n], x[n:2 * n]
    return out


def seam_contrast(array: np.ndarray, labels: np.ndarray, label_step: int = 1) -> float:
    """Mean absolute step across the seamlines of a mosaic (module docstring), in the values' unit.

    Parameters
    ----------
    array : (rows, cols[, bands]) array
        The mosaic (NaN: nodata).
    labels : (rows/k, cols/k) int array
        Photo per label cell (-1: none), :attr:`MosaicResult.labels`.
    label_step : int
        k: the array is read at every k-th cell.
    """
    a = np.asarray(array, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    a = a[::label_step, ::label_step][:labels.shape[0], :labels.shape[1]]
    lab = labels[:a.shape[0], :a.shape[1]]
    n = int(lab.max()) + 1 if lab.size else 0
    if n < 2:
        return 0.0
    keys, diffs = [], []
    for l1, l2, v1, v2 in ((lab[:, :-1], lab[:, 1:], a[:, :-1], a[:, 1:]), (lab[:-1], lab[1:], a[:-1], a[1:])):
        m = (l1 >= 0) & (l2 >= 0) & (l1 != l2) & np.isfinite(v1).all(-1) & np.isfinite(v2).all(-1)
        lo, hi = np.minimum(l1[m], l2[m]), np.maximum(l1[m], l2[m])
        d = np.where((l1[m] == lo)[:, None], v1[m] - v2[m], v2[m] - v1[m])   # side of lo minus side of hi
        keys.append(lo * n + hi)
        diffs.append(d)
    key = np.concatenate(keys)
    d = np.concatenate(diffs)
    if not len(key):
        return 0.0
    uk, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    sums = np.zeros((len(uk), d.shape[1]))
    np.add.at(sums, inv, d)
    step = np.abs(sums / cnt[:, None])                  # |mean step| per seam and band
    return float((step * cnt[:, None]).sum(axis=0).mean() / cnt.sum())


def _feather(seen: Sequence[tuple[int, np.ndarray, np.ndarray]], choice: np.ndarray, hard: np.ndarray,
             f_px: float) -> np.ndarray:
    """Blend across seams (module docstring): *seen* = (photo index, values (h, w, bands), sees-the-cell mask)."""
    import cv2

    num = np.zeros(hard.shape, dtype=np.float64)
    den = np.zeros(choice.shape, dtype=np.float64)
    for i, vals, ok in seen:
        m = (choice == i).astype(np.uint8)
        if not m.any():
            continue                        # no cell of the tile (+ margin) chose it: beyond every seam
        d_in = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        if m.all():
            s = d_in - 0.5
        else:
            d_out = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
            s = np.where(m > 0, d_in - 0.5, 0.5 - d_out)
        w = np.clip(0.5 + s / (2.0 * f_px), 0.0, 1.0) * ok
        num += w[..., None] * np.nan_to_num(vals.astype(np.float64))
        den += w
    out = hard.copy()
    blend = den > 0
    out[blend] = (num[blend] / den[blend, None]).astype(np.float32)
    return out


def seam_polygons(labels: np.ndarray, transform: Any, photo_ids: Sequence[str], crs: Any = None) -> dict:
    """GeoJSON FeatureCollection of the region of each photo in a label grid.

    Parameters
    ----------
    labels : (rows, cols) int array
        Photo index per cell, -1 for none.
    transform : GeoTransform
        Of the label grid.
    photo_ids : sequence of str
    crs : CRS-like, optional
        Written as ``{"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::<code>"}}``
        (or the CRS's WKT name when it has no EPSG code).

    Returns
    -------
    dict
        Features with ``photo`` and ``area_m2`` properties; polygon rings follow
        cell outlines (corners of the cells on the region's border).
    """
    import cv2

    feats = []
    cell = transform.cell_m
    for i, pid in enumerate(photo_ids):
        mask = np.pad((labels == i).astype(np.uint8), 1)
        if not mask.any():
            continue
        # traced on a 2x upsampled mask: the rings run a quarter cell inside the region's border
        up = cv2.resize(mask, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        contours, hier = cv2.findContours(up, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
        polys: list[list[list[list[float]]]] = []
        outer_of: dict[int, int] = {}
        for j, cnt in enumerate(contours):
            pts = cnt[:, 0, :].astype(np.float64)
            # centre of upsampled pixel j: (j + 0.5) / 2 cells of the padded grid (pad: - 1)
            cx = (pts[:, 0] + 0.5) / 2 - 1
            cy = (pts[:, 1] + 0.5) / 2 - 1
            e = transform.x0 + cx * cell
            n = transform.y0 - cy * cell
            ring = np.column_stack([e, n]).round(3).tolist()
            if len(ring) < 3:
                continue
            ring.append(ring[0])
            parent = hier[0][j][3]
            if parent < 0:
                outer_of[j] = len(polys)
                polys.append([ring])
            elif parent in outer_of:
                polys[outer_of[parent]].append(ring)
        area = float((labels == i).sum()) * cell * cell
        geom = {"type": "MultiPolygon", "coordinates": polys}
        feats.append({"type": "Feature", "properties": {"photo": pid, "area_m2": area}, "geometry": geom})
    out: dict[str, Any] = {"type": "FeatureCollection", "name": "seamlines", "features": feats}
    if crs is not None:
        from ..lidar.crs import geojson_crs_member

        out["crs"] = geojson_crs_member(crs)
    return out
