r"""Swath separation images: height differences between overlapping flight lines (USGS lidar base specification).

The USGS Lidar Base Specification asks for *swath separation images*: over
the overlap of two flight lines (swaths), per cell, the difference between
the surfaces the two lines measured, from the last returns of all points not
withheld, so that a boresight error, a scan-angle scale error or a trajectory
error shows as a pattern (a roll misalignment: a difference growing across
the overlap, of opposite sign for lines flown in opposite directions).  It
also sets the interswath (between-swath) repeatability on smooth, flat
surfaces, :data:`INTERSWATH_LIMITS`::

    quality level   RMSDz     max |difference|
    QL0             <= 4 cm   +-8 cm
    QL1             <= 6 cm   +-12 cm
    QL2             <= 8 cm   +-16 cm
    QL3             <= 16 cm  +-32 cm

Per cell and per line
---------------------
Within each cell the points of each line are fitted by a plane in the cell's
local coordinates ``(dx, dy)`` about its centre (least squares from the
sums, vectorised over all (cell, line) groups)::

    z = a + b dx + c dy,   [n Sx Sy; Sx Sxx Sxy; Sy Sxy Syy] (a, b, c) = (Sz, Sxz, Syz)

``a`` is the line's height at the cell centre: fitting a plane rather than
averaging keeps the slope out of the difference (two lines sample a sloped
cell at different places).  A group needs ``min_points`` points (default 4)
and points spread in both directions (a well-conditioned normal matrix).

The cell's value is ``dz = a_low - a_high``, the line with the lower point
source id minus the other, taken from the two lines with the most points in
the cell (three or more lines in a cell: the two best sampled).

Tile by tile
------------
The plane fits need only the sums above, and sums add: :func:`swath_sums`
makes them per (global cell, line) for one tile's points (cells at
multiples of the cell size, so a cell cut by a tile boundary gets both
parts), :func:`merge_sums` adds the tiles' sums and :func:`swath_from_sums`
fits the planes.  Memory grows with the number of (cell, line) groups, not
with the points; the result equals the one of all points at once (test).

On the tile engine (:mod:`lidarcat.lidar.jobs`) this is a map-reduce:
:func:`swath_tile` is the map (one tile read, its points selected, its sums
written as an ``.npz``), the parent merges the tiles' sums in job order and
fits the planes once (:func:`lidarcat.stages.lidar.swath_check`).  Each tile
refers its heights to its own median (``z_ref_m``, which :func:`merge_sums`
reconciles), and the same function computes each tile serially or on Dask,
so both give the same bytes.  A worker holds one tile; the parent holds the
(cell, line) sums of the survey (10 numbers per group) and the image.

Smooth, flat cells (the statistics)
-----------------------------------
A cell counts towards ``RMSDz`` and the maximum when both planes fit their
points within ``smooth_rms_m`` (rms of the residuals, ``n - 3`` degrees of
freedom; default 5 cm: open ground, roads, flat roofs, not trees or edges) and
both slopes ``sqrt(b^2 + c^2)`` are at most ``max_slope`` (default tan 10 deg).
``RMSDz = sqrt(mean dz^2)`` over them; ``max |dz|`` is their largest
difference (one spike decides it, as the specification states it; the 95th and
99th percentiles are reported beside it).

Images
------
The GeoTIFF holds ``dz`` (float32, NaN outside the overlap) with the CRS of
the points; the PNG colours ``|dz|`` in the classes of the chosen quality
level: green within the RMSDz limit, yellow up to the maximum, red beyond,
grey for overlap cells that are not smooth, white outside the overlap (the
sign is in the GeoTIFF).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ProductError
from ..lidar.geotiff import GeoTransform

if TYPE_CHECKING:
    from ..lidar.jobs import TileJob

__all__ = ["INTERSWATH_LIMITS", "SwathSeparation", "swath_separation", "swath_sums", "merge_sums", "swath_from_sums",
           "SUM_NAMES", "write_swath_png", "swath_tile", "select_last_returns", "read_swath_partial"]

#: USGS Lidar Base Specification, interswath smooth-surface repeatability: QL -> (RMSDz, max |dz|), metres
INTERSWATH_LIMITS: dict[str, tuple[float, float]] = {
    "QL0": (0.04, 0.08), "QL1": (0.06, 0.12), "QL2": (0.08, 0.16), "QL3": (0.16, 0.32)}


@dataclass(frozen=True, eq=False)
class SwathSeparation:
    """Swath separation of a set of points (module docstring).

    Attributes
    ----------
    dz_m : (rows, cols) float
        ``a_low - a_high`` per cell, NaN outside the overlap.
    n_lines : (rows, cols) int
        Flight lines with a plane in the cell.
    smooth : (rows, cols) bool
        Overlap cells counted in the statistics.
    transform : GeoTransform
    pairs : dict
        ``"low-high"`` line ids -> number of overlap cells of that pair.
    """

    dz_m: np.ndarray
    n_lines: np.ndarray
    smooth: np.ndarray
    transform: GeoTransform
    pairs: dict[str, int]

    @property
    def smooth_dz_m(self) -> np.ndarray:
        return self.dz_m[self.smooth]

    @property
    def rmsdz_m(self) -> float:
        d = self.smooth_dz_m
        return float(np.sqrt(np.mean(d * d))) if d.size else math.nan

    @property
    def max_abs_m(self) -> float:
        d = self.smooth_dz_m
        return float(np.abs(d).max()) if d.size else math.nan

    def assess(self, quality_level: str = "QL2") -> dict[str, Any]:
        """The statistics against the limits of *quality_level* (``pass`` is None without smooth cells)."""
        if quality_level not in INTERSWATH_LIMITS:
            raise ProductError(f"quality level must be one of {', '.join(INTERSWATH_LIMITS)}, got {quality_level!r}")
        rms_lim, max_lim = INTERSWATH_LIMITS[quality_level]
        d = np.abs(self.smooth_dz_m)
        n = int(d.size)

        def clean(x: float) -> float | None:
            return None if math.isnan(x) else x

        ok_rms = None if n == 0 else bool(self.rmsdz_m <= rms_lim)
        ok_max = None if n == 0 else bool(self.max_abs_m <= max_lim)
        return {"quality_level": quality_level, "rmsdz_limit_m": rms_lim, "max_limit_m": max_lim,
                "overlap_cells": int(np.isfinite(self.dz_m).sum()), "smooth_cells": n,
                "rmsdz_m": clean(self.rmsdz_m), "mean_dz_m": clean(float(np.mean(self.smooth_dz_m)) if n else math.nan),
                "max_abs_dz_m": clean(self.max_abs_m),
                "p95_abs_dz_m": clean(float(np.percentile(d, 95)) if n else math.nan),
                "p99_abs_dz_m": clean(float(np.percentile(d, 99)) if n else math.nan),
                "cells_over_max": int((d > max_lim).sum()),
                "rmsdz_pass": ok_rms, "max_pass": ok_max,
                "pass": None if n == 0 else bool(ok_rms and ok_max), "pairs": dict(self.pairs)}


def swath_separation(xyz_m: np.ndarray, line_id: np.ndarray, cell_m: float = 1.0,
                     bounds: tuple[float, float, float, float] | None = None, *, min_points: int = 4,
                     smooth_rms_m: float = 0.05, max_slope: float = math.tan(math.radians(10.0)),
                     max_cells: int = 100_000_000) -> SwathSeparation:
    """Per-cell differences between overlapping flight lines (module docstring).

    Parameters
    ----------
    xyz_m : (N, 3) float
        Last returns (not withheld, not noise), metres.
    line_id : (N,) int
        Flight line of each point (LAS point source id).
    cell_m : float
        Cell size (m); cells are aligned to multiples of it.
    bounds : (xmin, ymin, xmax, ymax), optional
        Default: the points' extent; snapped outwards to multiples of the cell.
    min_points, smooth_rms_m, max_slope
        See the module docstring.
    max_cells : int
        A larger grid is refused.

    Raises
    ------
    ProductError
        Bad shapes or no point; a grid above *max_cells*; fewer than two flight lines.
    """
    p = np.asarray(xyz_m, dtype=float)
    ids = np.asarray(line_id).ravel()
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] == 0 or ids.shape[0] != p.shape[0]:
        raise ProductError(f"swath separation needs (N, 3) points and (N,) line ids, N >= 1; got {p.shape} "
                           f"and {ids.shape}")
    if not cell_m > 0:
        raise ProductError(f"swath separation: the cell must be positive, got {cell_m}")
    lines = np.unique(ids)
    if lines.size < 2:
        raise ProductError(f"swath separation needs points of at least two flight lines (point source ids); "
                           f"all {p.shape[0]} points are of line {lines[0]}")
    if bounds is None:
        lo, hi = p[:, :2].min(axis=0), p[:, :2].max(axis=0)
        x0, y0 = math.floor(lo[0] / cell_m) * cell_m, math.floor(lo[1] / cell_m) * cell_m
        x1, y1 = (math.floor(hi[0] / cell_m) + 1) * cell_m, (math.floor(hi[1] / cell_m) + 1) * cell_m
    else:   # snapped outwards to multiples of the cell (the cells of swath_sums)
        x0, y0 = math.floor(bounds[0] / cell_m) * cell_m, math.floor(bounds[1] / cell_m) * cell_m
        x1, y1 = math.ceil(bounds[2] / cell_m) * cell_m, math.ceil(bounds[3] / cell_m) * cell_m
    ncols, nrows = max(1, round((x1 - x0) / cell_m)), max(1, round((y1 - y0) / cell_m))
    if nrows * ncols > max_cells:
        raise ProductError(f"swath separation: a grid of {nrows} x {ncols} cells of {cell_m:g} m is above "
                           f"{max_cells:,} cells; give a larger cell or a smaller area")
    t = GeoTransform(float(x0), float(y1), float(cell_m))
    row, col = t.rowcol(p[:, 0], p[:, 1])
    inside = (row >= 0) & (row < nrows) & (col >= 0) & (col < ncols)
    part = swath_sums(p[inside], ids[inside], cell_m, z_ref_m=float(np.median(p[:, 2])))
    return swath_from_sums(merge_sums([part]), t, (nrows, ncols), min_points=min_points,
                           smooth_rms_m=smooth_rms_m, max_slope=max_slope)


#: the sums kept per (cell, line) group, in this order (z relative to ``z_ref_m``; dx, dy from the cell centre)
SUM_NAMES = ("n", "sx", "sy", "sz", "sxx", "sxy", "syy", "sxz", "syz", "szz")


def swath_sums(xyz_m: np.ndarray, line_id: np.ndarray, cell_m: float, *, z_ref_m: float = 0.0
               ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The additive sums of the plane fits per (cell, line), for streaming tile by tile.

    Cells are global (``col = floor(E / cell)``, ``row = floor(N / cell)``),
    so the sums of tiles add up to the sums of all their points: a cell cut by
    a tile boundary is fitted from both parts.

    Returns
    -------
    groups : (M, 3) int64
        ``row, col, line`` of each group (sorted).
    sums : (M, 10) float
        :data:`SUM_NAMES` of each group.
    cell_m, z_ref_m : float
    """
    p = np.asarray(xyz_m, dtype=float).reshape(-1, 3)
    ids = np.asarray(line_id).astype(np.int64).ravel()
    col = np.floor(p[:, 0] / cell_m).astype(np.int64)
    row = np.floor(p[:, 1] / cell_m).astype(np.int64)
    order = np.lexsort((ids, col, row))
    row, col, ids, p = row[order], col[order], ids[order], p[order]
    brk = np.r_[True, (row[1:] != row[:-1]) | (col[1:] != col[:-1]) | (ids[1:] != ids[:-1])] if len(p) else \
        np.zeros(0, bool)
    g = np.cumsum(brk) - 1
    m = int(brk.sum())
    dx = p[:, 0] - (col + 0.5) * cell_m
    dy = p[:, 1] - (row + 0.5) * cell_m
    z = p[:, 2] - z_ref_m
    cols = [np.ones(len(p)), dx, dy, z, dx * dx, dx * dy, dy * dy, dx * z, dy * z, z * z]
    sums = np.column_stack([np.bincount(g, weights=c, minlength=m) for c in cols]) if m else np.zeros((0, 10))
    first = np.flatnonzero(brk)
    return np.column_stack([row[first], col[first], ids[first]]), sums, float(cell_m), float(z_ref_m)


def merge_sums(parts: list[tuple[np.ndarray, np.ndarray, float, float]]) -> tuple[np.ndarray, np.ndarray, float,
                                                                                 float]:
    """Add the sums of several :func:`swath_sums` (same cell; their z references reconciled)."""
    if not parts:
        raise ProductError("swath separation: no points")
    parts = [q for q in parts if len(q[0])] or parts[:1]     # an empty part's z reference is no height
    cell, z0 = parts[0][2], parts[0][3]
    gs, ss = [], []
    for groups, sums, c, zr in parts:
        if c != cell:
            raise ProductError(f"swath sums of different cells ({c} and {cell} m)")
        sums = sums.copy()
        if zr != z0 and len(sums):    # z' = z + (zr - z0): shift the z sums to the common reference
            d = zr - z0
            n, sx, sy, sz = sums[:, 0], sums[:, 1], sums[:, 2], sums[:, 3]
            sums[:, 9] = sums[:, 9] + 2 * d * sz + d * d * n
            sums[:, 7] = sums[:, 7] + d * sx
            sums[:, 8] = sums[:, 8] + d * sy
            sums[:, 3] = sz + d * n
        gs.append(groups)
        ss.append(sums)
    g, s = np.concatenate(gs), np.concatenate(ss)
    order = np.lexsort((g[:, 2], g[:, 1], g[:, 0]))
    g, s = g[order], s[order]
    brk = np.r_[True, np.any(g[1:] != g[:-1], axis=1)] if len(g) else np.zeros(0, bool)
    first = np.flatnonzero(brk)
    return g[first], np.add.reduceat(s, first, axis=0) if len(first) else s, cell, z0


def swath_from_sums(merged: tuple[np.ndarray, np.ndarray, float, float], transform: GeoTransform | None = None,
                    shape: tuple[int, int] | None = None, *, min_points: int = 4, smooth_rms_m: float = 0.05,
                    max_slope: float = math.tan(math.radians(10.0)), max_cells: int = 100_000_000
                    ) -> SwathSeparation:
    """The swath separation from merged sums (module docstring); grid: *transform* and *shape*, or the
    occupied cells."""
    groups, sums, cell_m, z_ref = merged
    if transform is None:
        if not len(groups):
            raise ProductError("swath separation: no points")
        r0, r1 = int(groups[:, 0].min()), int(groups[:, 0].max())
        c0, c1 = int(groups[:, 1].min()), int(groups[:, 1].max())
        shape = (r1 - r0 + 1, c1 - c0 + 1)
        if shape[0] * shape[1] > max_cells:
            raise ProductError(f"swath separation: a grid of {shape[0]} x {shape[1]} cells of {cell_m:g} m is "
                               f"above {max_cells:,} cells; give a larger cell or a smaller area")
        transform = GeoTransform(c0 * cell_m, (r1 + 1) * cell_m, cell_m)
    assert shape is not None
    nrows, ncols = shape
    lines = np.unique(groups[:, 2])
    if lines.size < 2:
        raise ProductError(f"swath separation needs points of at least two flight lines (point source ids); "
                           f"all points are of line {lines[0] if lines.size else '-'}")
    # global cell -> this grid (row down from the north edge)
    row = np.round(transform.y0 / cell_m).astype(np.int64) - 1 - groups[:, 0]
    col = groups[:, 1] - np.round(transform.x0 / cell_m).astype(np.int64)
    inside = (row >= 0) & (row < nrows) & (col >= 0) & (col < ncols)
    groups, sums, row, col = groups[inside], sums[inside], row[inside], col[inside]
    n, sx, sy, sz, sxx, sxy, syy, sxz, syz, szz = sums.T
    m = len(n)
    with np.errstate(invalid="ignore", divide="ignore"):
        zbar = sz / n
        # centre z on the group mean: sz' = 0, sxz' = sxz - sx zbar, syz' = syz - sy zbar, szz' = szz - n zbar^2
        sz0 = np.zeros(m)
        sxz0, syz0, szz0 = sxz - sx * zbar, syz - sy * zbar, szz - sz * zbar
        mat = np.stack([np.stack([n, sx, sy], -1), np.stack([sx, sxx, sxy], -1), np.stack([sy, sxy, syy], -1)], -2)
        rhs = np.stack([sz0, sxz0, syz0], -1)
        ok = n >= max(3, min_points)
        # spread in both directions: the smaller eigenvalue of the plan covariance above (cell / 10)^2
        varx, vary, cov = sxx / n - (sx / n) ** 2, syy / n - (sy / n) ** 2, sxy / n - sx * sy / n**2
        lam = 0.5 * (varx + vary) - np.sqrt(0.25 * (varx - vary) ** 2 + cov**2)
    ok &= lam > (0.1 * cell_m) ** 2
    coef = np.full((m, 3), np.nan)
    if np.any(ok):
        coef[ok] = np.linalg.solve(mat[ok], rhs[ok][:, :, None])[:, :, 0]
    height = z_ref + zbar + coef[:, 0]
    slope = np.hypot(coef[:, 1], coef[:, 2])
    ss = np.maximum(szz0 - np.einsum("mk,mk->m", np.nan_to_num(coef), rhs), 0.0)
    rms = np.sqrt(ss / np.maximum(n - 3, 1))
    gcell, gline = row * ncols + col, groups[:, 2]
    # the two best-sampled lines of each cell
    sel = np.flatnonzero(ok)
    order = sel[np.lexsort((-n[sel], gcell[sel]))]
    oc = gcell[order]
    first = np.r_[True, oc[1:] != oc[:-1]] if oc.size else np.zeros(0, bool)
    second = np.r_[False, ~first[1:]] & np.r_[False, first[:-1]] if oc.size else np.zeros(0, bool)
    a_idx = order[np.flatnonzero(second) - 1]
    b_idx = order[np.flatnonzero(second)]
    swap = gline[a_idx] > gline[b_idx]
    lo_idx, hi_idx = np.where(swap, b_idx, a_idx), np.where(swap, a_idx, b_idx)
    dz = np.full(nrows * ncols, np.nan)
    cells = gcell[lo_idx]
    dz[cells] = height[lo_idx] - height[hi_idx]
    smooth = np.zeros(nrows * ncols, dtype=bool)
    smooth[cells] = ((rms[lo_idx] <= smooth_rms_m) & (rms[hi_idx] <= smooth_rms_m)
                     & (slope[lo_idx] <= max_slope) & (slope[hi_idx] <= max_slope))
    nl = np.bincount(gcell[sel], minlength=nrows * ncols)
    pair_names = [f"{a}-{b}" for a, b in zip(gline[lo_idx], gline[hi_idx])]
    names, counts = np.unique(np.array(pair_names, dtype=object).astype(str), return_counts=True) \
        if pair_names else (np.zeros(0, dtype=str), np.zeros(0, dtype=int))
    return SwathSeparation(dz.reshape(nrows, ncols), nl.reshape(nrows, ncols).astype(np.int32),
                           smooth.reshape(nrows, ncols), transform,
                           {str(k): int(v) for k, v in zip(names, counts)})


def write_swath_png(path: str | os.PathLike, sep: SwathSeparation, quality_level: str = "QL2", *,
                    title: str | None = None, dpi: int = 120) -> Path:
    """The swath separation image: ``|dz|`` in the classes of *quality_level*, axes in metres (atomically)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    from .._util import atomic_write

    rms_lim, max_lim = INTERSWATH_LIMITS[quality_level]
    a = np.abs(sep.dz_m)
    cls = np.full(a.shape, np.nan)
    over = np.isfinite(a)
    cls[over & ~sep.smooth] = 0
    cls[over & sep.smooth & (a <= rms_lim)] = 1
    cls[over & sep.smooth & (a > rms_lim) & (a <= max_lim)] = 2
    cls[over & sep.smooth & (a > max_lim)] = 3
    colours = ["#b0b0b0", "#2ca02c", "#ffd21f", "#d62728"]
    cmap = ListedColormap(colours).with_extremes(bad="white")
    nrows, ncols = a.shape
    t = sep.transform
    extent = (t.x0, t.x0 + ncols * t.cell_m, t.y0 - nrows * t.cell_m, t.y0)
    fig = Figure(figsize=(8.0, float(np.clip(6.0 * nrows / max(ncols, 1), 3.0, 12.0)) + 0.8))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(np.ma.masked_invalid(cls), cmap=cmap, vmin=-0.5, vmax=3.5, extent=extent, interpolation="nearest")
    ax.set_xlabel("E (m)")
    ax.set_ylabel("N (m)")
    ax.ticklabel_format(useOffset=False, style="plain")
    st = sep.assess(quality_level)
    ax.set_title(title or (f"Swath separation, {quality_level}: RMSDz "
                           f"{'-' if st['rmsdz_m'] is None else format(100 * st['rmsdz_m'], '.1f')} cm "
                           f"(limit {100 * rms_lim:g}), max |dz| "
                           f"{'-' if st['max_abs_dz_m'] is None else format(100 * st['max_abs_dz_m'], '.1f')} cm "
                           f"(limit {100 * max_lim:g})"), fontsize=9)
    ax.legend(handles=[Patch(color=colours[1], label=f"|dz| <= {100 * rms_lim:g} cm"),
                       Patch(color=colours[2], label=f"{100 * rms_lim:g} < |dz| <= {100 * max_lim:g} cm"),
                       Patch(color=colours[3], label=f"|dz| > {100 * max_lim:g} cm"),
                       Patch(color=colours[0], label="overlap, not smooth/flat")],
              loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    out = Path(path)
    with atomic_write(out, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return out


def select_last_returns(attributes: dict[str, Any], n: int, classes: Sequence[int] | None = None) -> np.ndarray:
    """Mask (n,) of the points a swath image uses: last returns, not withheld, not noise (7, 18), and of
    *classes* when given (module docstring)."""
    a = attributes
    keep = np.ones(n, dtype=bool)
    if "return_number" in a and "number_of_returns" in a:
        keep &= np.asarray(a["return_number"]) == np.asarray(a["number_of_returns"])
    if "withheld" in a:
        keep &= ~np.asarray(a["withheld"], dtype=bool)
    c = np.asarray(a["classification"]) if "classification" in a else np.zeros(n, dtype=np.uint8)
    keep &= ~np.isin(c, (7, 18))
    if classes is not None:
        keep &= np.isin(c, list(classes))
    return keep


def swath_tile(job: TileJob) -> None:
    """The map step of the swath image on the tile engine: the sums of one tile (module docstring).

    ``job.params``: ``cell_m``; ``classes`` (a list, None for every class, or
    ``"auto"``: the sums of all selected points *and* of the ground class, so
    the parent can choose).  Writes ``job.output`` (``.npz``, atomically):
    ``groups``/``sums``/``n`` of all selected points, ``groups_ground``/
    ``sums_ground``/``n_ground`` and ``z_ref``, ``cell``.

    Raises
    ------
    ProductError
        The tile's points carry no ``point_source_id`` (names the tile).
    """
    from .._util import atomic_write
    from ..lidar.readers import read_points

    pc = read_points(job.tile, crs=job.crs)
    a = pc.attributes
    if "point_source_id" not in a:
        raise ProductError(f"{job.tile}: the points carry no point_source_id; swath separation compares "
                           "flight lines")
    cell = float(job.params["cell_m"])
    classes = job.params.get("classes")
    fixed = None if isinstance(classes, str) or classes is None else [int(c) for c in classes]
    keep = select_last_returns(a, len(pc), fixed)
    xyz, lid = pc.xyz[keep], np.asarray(a["point_source_id"])[keep]
    z_ref = float(np.median(xyz[:, 2])) if len(xyz) else 0.0
    g, s, _, _ = swath_sums(xyz, lid, cell, z_ref_m=z_ref)
    arrays: dict[str, Any] = {"groups": g, "sums": s, "n": np.int64(len(xyz)), "z_ref": np.float64(z_ref),
                              "cell": np.float64(cell)}
    if isinstance(classes, str):
        cls = np.asarray(a["classification"])[keep] if "classification" in a else np.zeros(len(xyz), np.uint8)
        gr = cls == 2
        gg, sg, _, _ = swath_sums(xyz[gr], lid[gr], cell, z_ref_m=z_ref)
        arrays.update(groups_ground=gg, sums_ground=sg, n_ground=np.int64(gr.sum()))
    with atomic_write(job.output, "wb") as fh:
        np.savez(fh, **arrays)


def read_swath_partial(z: dict[str, Any], which: str = "") -> tuple[tuple[np.ndarray, np.ndarray, float, float], int]:
    """The sums of one tile from the arrays of its :func:`swath_tile` output (``which``: ``""`` for all
    selected points, ``"_ground"`` for the ground class) and their point count."""
    return ((np.asarray(z["groups" + which]).reshape(-1, 3), np.asarray(z["sums" + which]).reshape(-1, 10),
             float(z["cell"]), float(z["z_ref"])), int(z["n" + which]))
