"""Ground classification: progressive TIN densification and a simple morphological filter.

Progressive TIN densification (PTD)
-----------------------------------
The LACTEC report (section 11.2) classifies ground with TerraScan's routine,
after Axelsson (2000): a coarse TIN of the *lowest* last-return points, one per
square window the size of the largest building (``max_building_m``), so that at
least one point of each window reached the ground; the TIN lies mostly below
the terrain, touching it at its vertices.  The TIN is then densified: a point
inside triangle :math:`(P_0, P_1, P_2)` with unit normal :math:`\\hat n` lies at
the distance

.. math:: d = (p - P_0)\\cdot\\hat n

from the triangle's plane (positive above it), and its *iteration angle* is the
angle between that plane and the line from the point to the triangle's nearest
vertex :math:`V`,

.. math:: \\alpha = \\arcsin\\frac{|d|}{\\lVert p - V\\rVert}.

A point is accepted when :math:`|d| \\le` ``iteration_distance_m`` (no big jumps
under large triangles) and :math:`\\alpha \\le` ``iteration_angle_deg``.  Per
iteration each triangle may accept only its candidate of smallest angle (Axelsson's
rule, ``one_per_triangle=True``; by default every point that passes is
accepted at once, which converges in far fewer iterations and measured better
on AHN3); the TIN is re-triangulated and the test repeated until no point is
accepted.  Candidates
outside the TIN's hull are tested against the nearest ground point as if it
carried a level triangle.  All of one iteration is vectorised:
:class:`scipy.spatial.Delaunay` and :func:`lidarcat.geometry.tin.find_simplex` locate the candidates,
numpy computes :math:`d` and :math:`\\alpha` for all of them, and a sort picks
the best per triangle.  No per-point Python loop.

Only last (or only) returns are candidates: an earlier return of a pulse that
went on is by definition above the ground.  Isolated low outliers (multipath,
birds below the ground are impossible but sensor noise is not) would become
seeds and drag the TIN down, so first a candidate lower than every other
candidate of its block of 3 x 3 cells of ``outlier_cell_m`` (1 m) by more
than ``low_outlier_m`` is set aside (it is never ground).  Only the lowest
point of a cell can be that low, so a sort by cell and height and a minimum
filter over the grid of cell minima find them all (a k-nearest-neighbour test
did the same at a third of the speed of the whole filter).  The filter never reads the points'
existing classes.

Defaults (TerraScan's own, which the report quotes): max building 60 m,
iteration angle 6 deg, iteration distance 1.4 m.  The report says to raise the
angle and distance on steep terrain and lower them on flat terrain.

Simple morphological filter (SMRF)
----------------------------------
Pingel, Clarke and McBride (2013): a minimum-height grid (``cell_m``) with
holes filled by interpolation is opened (erosion then dilation) with windows of
growing radius :math:`r = 1 .. \\text{window\\_m}` cells; a cell whose height
drops by more than ``slope * r * cell_m`` at one step is an object.  The ground
cells are interpolated into a provisional DTM, and a point is ground when it
lies within ``elevation_threshold_m + elevation_scaler * slope_of_dtm`` of it.
Square windows (separable min/max filters) stand in for the paper's discs;
low outliers are set aside first as for PTD, and cells of the minimum surface
lower than the second lowest of their 8 neighbours by ``low_outlier_m`` (pits
left by outliers the point test missed) are dropped before the opening.
The paper reports 2.97 % mean total error on the ISPRS filter test with tuned
parameters and about 4.5 % with one parameter set.

Adaptive SMRF (``adaptive=True``, the default): on sparse points (0.1-1 per m2)
a 1 m grid is mostly interpolated and a 3 x 3 m outlier block holds one point.
The mean spacing of the candidates, :math:`\\delta = 1/\\sqrt{\\rho}` with the
density :math:`\\rho` over the occupied 5 m cells, sets the cell
:math:`\\max(\\text{cell\\_m}, \\delta)` (in steps of 0.5 m, so neighbouring
tiles share a lattice) and the outlier cell :math:`\\max(\\text{outlier\\_cell\\_m}, 2\\delta)`.
And the grid is padded by one window on every side with the terrain's trend
continued: the least-squares plane :math:`P` through the lower half of the cells
(:func:`lidarcat.production.csf.trend_plane`) extended outward (odd reflection
of a plane is the plane), plus the residual :math:`z - P` of the nearest edge
cell clipped to at most the median residual.  On a slope the opening then no
longer cuts the band within a window of the upper edge, and an object cut by the
edge is not carried outward (its residual is clipped).  Opening the whole
surface less :math:`P` instead did the same for uniform slopes and better under
a canopy on a slope, but cut the tops of terrace cliffs (18-23 % on the
benchmark's terraces, 8.7 % with the padding).

Tiles
-----
:func:`classify_ground` classifies one array of points.  Tile-by-tile runs
(:func:`classify_tiles`) classify each tile together with the points of its
neighbours within ``overlap_m`` (default two building windows) and keep the
tile's own points; seed windows are aligned to multiples of
``max_building_m`` in absolute coordinates, so neighbouring tiles see the same
seeds near their common edge and classify the seam alike.

Evaluation
----------
:func:`confusion` gives Type I (ground rejected), Type II (object accepted),
total error and Cohen's kappa of a classification against a reference.
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

from ..errors import LidarFormatError, ProductError, TileIOError
from ..geometry.tin import barycentric, find_simplex
from ..lidar.crs import add_las_crs
from ..lidar.jobs import TileJob, read_with_buffer, run_jobs, tile_jobs
from ..lidar.raster import bulk_box
from .csf import CSFParameters, csf_ground, trend_plane
from .noise import NOISE_CLASS, height_above_ground, statistical_outliers

__all__ = ["PTDParameters", "SMRFParameters", "GroundMethod", "GROUND_METHODS", "classify_ground",
           "ptd_ground", "smrf_ground", "Confusion", "confusion", "write_classified_copy",
           "classify_tiles", "ground_tile", "params_from_dict", "default_overlap_m", "GROUND_CLASS",
           "UNCLASSIFIED_CLASS"]

log = logging.getLogger(__name__)

#: ASPRS class codes written by the classifier
GROUND_CLASS = 2
UNCLASSIFIED_CLASS = 1
GROUND_METHODS = ("ptd", "smrf", "csf")
GroundMethod = str


@dataclass(frozen=True)
class PTDParameters:
    """Parameters of progressive TIN densification (TerraScan's names and defaults).

    Attributes
    ----------
    max_building_m : float
        Side of the seed windows, metres: the size of the largest building
        (one seed, the lowest point, per window).
    iteration_angle_deg : float
        Largest angle between the triangle's plane and the line from a
        candidate to the triangle's nearest vertex, degrees.
    iteration_distance_m : float
        Largest distance of a candidate from the triangle's plane, metres.
    low_outlier_m : float
        A candidate lower than every other candidate of its block of 3 x 3
        cells by more than this is a low outlier (never ground), metres.
    outlier_cell_m : float
        Cell of the low-outlier test, metres.
    max_iterations : int
        Safety stop for the densification loop.
    one_per_triangle : bool
        Accept at most one point (the smallest angle) per triangle and
        iteration, as Axelsson's description reads; default False: every
        point that passes is accepted at once.  On AHN3 tile 2 the strict rule
        needs more than 200 iterations and stops at 12.6 % total error, the
        default converges in a few dozen and reaches 4.9-5.1 %.
    """

    max_building_m: float = 60.0
    iteration_angle_deg: float = 6.0
    iteration_distance_m: float = 1.4
    low_outlier_m: float = 1.0
    outlier_cell_m: float = 1.0
    max_iterations: int = 200
    one_per_triangle: bool = False

    def __post_init__(self) -> None:
        for name in ("max_building_m", "iteration_angle_deg", "iteration_distance_m", "low_outlier_m",
                     "outlier_cell_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not self.iteration_angle_deg < 90:
            raise ValueError(f"iteration_angle_deg must be below 90, got {self.iteration_angle_deg}")
        if self.max_iterations < 1:
            raise ValueError("max_iterations must be at least 1")


@dataclass(frozen=True)
class SMRFParameters:
    """Parameters of the simple morphological filter (Pingel et al. 2013 defaults, window 40 m).

    Attributes
    ----------
    cell_m : float
        Grid cell, metres.
    window_m : float
        Largest opening window radius, metres.  The window (a square of side
        ``2 * window_m + cell_m``) must hold the largest building with a
        margin: the report's largest building is 60 m, and on synthetic city
        blocks of 40-60 m flat roofs 30 m still left 6.4 % of the objects as
        ground, 40 m none (docs/production.md).  Pingel et al.'s 18 m suits
        the ISPRS samples' smaller buildings.
    slope : float
        Terrain slope allowed, rise over run (0.15 = 15 %).
    elevation_threshold_m : float
        Height above the provisional DTM still ground on flat terrain, metres.
    elevation_scaler : float
        Extra height allowed per unit of DTM slope, metres.
    low_outlier_m, outlier_cell_m
        As :class:`PTDParameters` (low outliers are set aside first).
    adaptive : bool
        Grow the cell to the point spacing and the outlier cell to twice it,
        and continue the terrain's trend beyond the grid's edge (the module
        docstring, "Adaptive SMRF").  False: the fixed grid of Pingel et al.
    """

    cell_m: float = 1.0
    window_m: float = 40.0
    slope: float = 0.15
    elevation_threshold_m: float = 0.5
    elevation_scaler: float = 1.25
    low_outlier_m: float = 1.0
    outlier_cell_m: float = 1.0
    adaptive: bool = True

    def __post_init__(self) -> None:
        for name in ("cell_m", "window_m", "slope", "elevation_threshold_m", "low_outlier_m", "outlier_cell_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")


# --------------------------------------------------------------------------- helpers
def _candidates(n: int, return_number: Any, number_of_returns: Any) -> np.ndarray:
    """Last (or only) returns; every point when the returns are unknown."""
    if return_number is None or number_of_returns is None:
        return np.ones(n, dtype=bool)
    rn = np.asarray(return_number)
    nr = np.asarray(number_of_returns)
    return (rn >= nr) | (nr == 0)


def _low_outliers(xyz: np.ndarray, idx: np.ndarray, threshold_m: float, cell_m: float,
                  passes: int = 5) -> np.ndarray:
    """Indices (subset of *idx*) of low outliers: see the module docstring.

    Only the lowest point of a cell can be lower than every other point of its
    3 x 3 cell block, so the test compares each cell's lowest height with the
    second lowest of the cell and the lowest of the eight neighbour cells (a
    sort and a min filter: no neighbour search).  A point alone in its block
    is not judged.  The test is repeated without the outliers found (up to
    *passes* times), so that of two outliers in one block the higher one is
    found once the lower one is gone.
    """
    found = []
    rest = np.asarray(idx)
    for _ in range(passes):
        low = _low_outliers_once(xyz, rest, threshold_m, cell_m)
        if len(low) == 0:
            break
        found.append(low)
        rest = rest[~np.isin(rest, low, assume_unique=True)]
    return np.sort(np.concatenate(found)) if found else np.zeros(0, dtype=np.int64)


def _low_outliers_once(xyz: np.ndarray, idx: np.ndarray, threshold_m: float, cell_m: float) -> np.ndarray:
    """One pass of :func:`_low_outliers`."""
    from scipy.ndimage import minimum_filter

    if len(idx) < 2:
        return np.zeros(0, dtype=np.int64)
    pts = xyz[idx]
    lo = pts[:, :2].min(axis=0)
    col = np.floor((pts[:, 0] - lo[0]) / cell_m).astype(np.int64)
    row = np.floor((pts[:, 1] - lo[1]) / cell_m).astype(np.int64)
    nr, nc = int(row.max()) + 1, int(col.max()) + 1
    key = row * nc + col
    order = np.lexsort((pts[:, 2], key))
    ks = key[order]
    first = np.ones(len(ks), dtype=bool)
    first[1:] = ks[1:] != ks[:-1]
    second = np.zeros(len(ks), dtype=bool)
    second[1:] = first[:-1] & ~first[1:]
    z1 = np.full(nr * nc, np.inf)
    z1[ks[first]] = pts[order[first], 2]
    z2 = np.full(nr * nc, np.inf)
    z2[ks[second]] = pts[order[second], 2]
    ring = np.ones((3, 3), dtype=bool)
    ring[1, 1] = False
    others = np.minimum(z2, minimum_filter(z1.reshape(nr, nc), footprint=ring, mode="constant",
                                           cval=np.inf).ravel())
    low = np.isfinite(others) & (z1 < others - threshold_m)
    lowest = np.full(nr * nc, -1, dtype=np.int64)
    lowest[ks[first]] = order[first]
    return np.sort(idx[lowest[low]])


def _lowest_per_cell(xyz: np.ndarray, idx: np.ndarray, cell_m: float) -> np.ndarray:
    """Index of the lowest point of *idx* in each *cell_m* window aligned to multiples of it."""
    cx = np.floor(xyz[idx, 0] / cell_m).astype(np.int64)
    cy = np.floor(xyz[idx, 1] / cell_m).astype(np.int64)
    order = np.lexsort((xyz[idx, 2], cy, cx))
    key = np.stack([cx[order], cy[order]], axis=1)
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(key[1:] != key[:-1], axis=1)
    return idx[order[first]]


def _triangle_test(xyz: np.ndarray, cand: np.ndarray, verts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance to plane (m, signed, up positive) and iteration angle (rad) of each candidate.

    *cand* (m,) point indices, *verts* (m, 3) indices of their triangle's vertices.
    """
    p = xyz[cand]
    a, b, c = xyz[verts[:, 0]], xyz[verts[:, 1]], xyz[verts[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= np.sign(n[:, 2:3]) + (n[:, 2:3] == 0)  # normals point up
    d = np.einsum("ij,ij->i", p - a, n)
    dist = np.stack([np.linalg.norm(p - v, axis=1) for v in (a, b, c)], axis=1)
    near = dist.min(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ang = np.arcsin(np.clip(np.abs(d) / np.maximum(near, 1e-9), 0.0, 1.0))
    return d, ang


def ptd_ground(xyz: np.ndarray, return_number: Any = None, number_of_returns: Any = None,
               params: PTDParameters | None = None) -> np.ndarray:
    """Ground mask by progressive TIN densification (see the module docstring).

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
        E, N, h in metres.
    return_number, number_of_returns : array_like, shape (N,), optional
        Pulse returns; only last (or only) returns can be ground.  Without
        them every point is a candidate.
    params : PTDParameters, optional

    Returns
    -------
    ndarray of bool, shape (N,)
        True for ground points.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> xy = rng.uniform(0, 100, (20000, 2))
    >>> h = 0.05 * xy[:, 0] + np.where((abs(xy[:, 0] - 50) < 10) & (abs(xy[:, 1] - 50) < 10), 6.0, 0.0)
    >>> g = ptd_ground(np.column_stack([xy, h]))
    >>> roof = h > 0.05 * xy[:, 0] + 1
    >>> bool(g[roof].any()), float(g[~roof].mean()) > 0.99
    (False, True)
    """
    from scipy.spatial import Delaunay, QhullError, cKDTree

    params = params or PTDParameters()
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    ground = np.zeros(n, dtype=bool)
    cand_mask = _candidates(n, return_number, number_of_returns)
    if n == 0:
        return ground
    # work in local coordinates: Qhull and the cross products lose digits on UTM-size numbers
    origin = np.floor(xyz.min(axis=0) / params.max_building_m) * params.max_building_m
    local = xyz - origin
    cand_idx = np.flatnonzero(cand_mask)
    outliers = _low_outliers(local, cand_idx, params.low_outlier_m, params.outlier_cell_m)
    cand_mask[outliers] = False
    cand_idx = np.flatnonzero(cand_mask)
    if len(cand_idx) == 0:
        return ground
    seeds = _lowest_per_cell(local, cand_idx, params.max_building_m)
    ground[seeds] = True
    tan_max = math.radians(params.iteration_angle_deg)
    dmax = params.iteration_distance_m
    for it in range(params.max_iterations):
        g_idx = np.flatnonzero(ground)
        rest = np.flatnonzero(cand_mask & ~ground)
        if len(rest) == 0:
            break
        simplex = np.full(len(rest), -1, dtype=np.int64)
        tri = None
        if len(g_idx) >= 3:
            try:
                tri = Delaunay(local[g_idx, :2])
                simplex = find_simplex(tri, local[rest, :2])
            except QhullError:
                tri = None
        inside = simplex >= 0
        accept = np.zeros(len(rest), dtype=bool)
        score = np.full(len(rest), np.inf)
        group = np.full(len(rest), -1, dtype=np.int64)
        if inside.any() and tri is not None:
            verts = g_idx[tri.simplices[simplex[inside]]]
            d, ang = _triangle_test(local, rest[inside], verts)
            ok = (np.abs(d) <= dmax) & (ang <= tan_max)
            accept[inside] = ok
            score[inside] = ang
            group[inside] = simplex[inside]
        out = ~inside
        if out.any():
            # outside the hull: a level "triangle" at the nearest ground point
            tree = cKDTree(local[g_idx, :2])
            hd, j = tree.query(local[rest[out], :2])
            dz = local[rest[out], 2] - local[g_idx[j], 2]
            d3 = np.hypot(hd, dz)
            ang = np.arcsin(np.clip(np.abs(dz) / np.maximum(d3, 1e-9), 0.0, 1.0))
            accept[out] = (np.abs(dz) <= dmax) & (ang <= tan_max)
            score[out] = ang
            group[out] = (tri.nsimplex if tri is not None else 0) + j
        if not accept.any():
            break
        a = np.flatnonzero(accept)
        if not params.one_per_triangle:
            ground[rest[a]] = True
            log.debug("PTD iteration %d: %d ground points, %d added", it + 1, len(g_idx), len(a))
            continue
        order = np.lexsort((rest[a], score[a], group[a]))  # ties broken by point index
        a = a[order]
        first = np.ones(len(a), dtype=bool)
        first[1:] = group[a][1:] != group[a][:-1]
        ground[rest[a[first]]] = True
        log.debug("PTD iteration %d: %d ground points, %d added", it + 1, len(g_idx), int(first.sum()))
    return ground


def _fill_grid(grid: np.ndarray) -> np.ndarray:
    """Fill NaN cells: linear inside the hull of the valued cells, nearest outside.

    Only the valued cells that touch a hole or the grid's edge (8-neighbours)
    are triangulated: the triangle holding a hole has an empty circumcircle,
    so its corners touch a hole, and the hull and the nearest valued cell of a
    hole are made of such cells too.  Holes are few, so the triangulation is a
    small fraction of the grid.
    """
    from scipy.ndimage import binary_dilation
    from scipy.spatial import Delaunay, QhullError, cKDTree

    valid = np.isfinite(grid)
    if valid.all() or not valid.any():
        return grid
    pad = np.pad(~valid, 1, constant_values=True)
    rim = valid & binary_dilation(pad, structure=np.ones((3, 3), dtype=bool))[1:-1, 1:-1]
    rc = np.column_stack(np.nonzero(rim)).astype(np.float64)
    holes = np.column_stack(np.nonzero(~valid)).astype(np.float64)
    out = grid.copy()
    vals = np.full(len(holes), np.nan)
    z = grid[rim].astype(np.float64)
    if len(rc) >= 3:
        try:
            tri = Delaunay(rc)
        except QhullError:
            tri = None
        if tri is not None:
            s = find_simplex(tri, holes)
            ok = s >= 0
            simp = tri.simplices[s[ok]]
            vals[ok] = np.einsum("ij,ij->i", barycentric(tri.points[simp], holes[ok]), z[simp])
    miss = ~np.isfinite(vals)
    if miss.any():
        vals[miss] = z[cKDTree(rc).query(holes[miss])[1]]
    out[~valid] = vals
    return out


def _pit_cells(surface: np.ndarray, threshold_m: float) -> np.ndarray:
    """Cells lower than the second lowest of their 8 neighbours by more than *threshold_m*.

    Low outliers that survive the point test (two in one block within
    ``low_outlier_m`` of each other) leave a pit of one or two cells in the
    minimum surface; the opening keeps pits, and on a slope the cells within a
    window of a pit lose their uphill side and are taken for objects (measured:
    6.8 % total error on the low-outlier landscape, seeds 0-2, all of it
    around such pairs).  The second lowest neighbour tolerates a pit of two
    cells and a ditch one cell wide (two neighbours along it).
    """
    if min(surface.shape) < 3:
        return np.zeros(surface.shape, dtype=bool)
    p = np.pad(surface, 1, mode="edge")
    nr, nc = surface.shape
    nbrs = np.stack([p[1 + dr:1 + dr + nr, 1 + dc:1 + dc + nc] for dr in (-1, 0, 1) for dc in (-1, 0, 1)
                     if dr or dc])
    second = np.partition(nbrs, 1, axis=0)[1]
    return surface < second - threshold_m


def _point_spacing(xy: np.ndarray, cell_m: float = 5.0) -> float:
    """Mean spacing of plan points, metres: 1/sqrt(density) over the occupied cells of *cell_m*."""
    if len(xy) == 0:
        return 0.0
    k = np.floor((xy - xy.min(axis=0)) / cell_m).astype(np.int64)
    occupied = len(np.unique(k[:, 0] * (int(k[:, 1].max()) + 1) + k[:, 1]))
    return math.sqrt(occupied * cell_m * cell_m / len(xy))


def smrf_ground(xyz: np.ndarray, return_number: Any = None, number_of_returns: Any = None,
                params: SMRFParameters | None = None) -> np.ndarray:
    """Ground mask by the simple morphological filter (see the module docstring).

    Parameters and return as :func:`ptd_ground`.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> xy = rng.uniform(0, 100, (20000, 2))
    >>> h = 0.05 * xy[:, 0] + np.where((abs(xy[:, 0] - 50) < 10) & (abs(xy[:, 1] - 50) < 10), 6.0, 0.0)
    >>> g = smrf_ground(np.column_stack([xy, h]))
    >>> roof = h > 0.05 * xy[:, 0] + 1
    >>> bool(g[roof].any()), float(g[~roof].mean()) > 0.99
    (False, True)
    """
    from scipy.ndimage import map_coordinates, maximum_filter, minimum_filter

    params = params or SMRFParameters()
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    cand = _candidates(n, return_number, number_of_returns)
    ground = np.zeros(n, dtype=bool)
    if not cand.any():
        return ground
    spacing = _point_spacing(xyz[cand, :2]) if params.adaptive else 0.0
    c = max(params.cell_m, 0.5 * round(2.0 * spacing))  # steps of 0.5 m: neighbouring tiles share a grid
    ocell = max(params.outlier_cell_m, 2.0 * spacing)
    cand[_low_outliers(xyz, np.flatnonzero(cand), params.low_outlier_m, ocell)] = False
    x0 = math.floor(xyz[:, 0].min() / c) * c
    y0 = math.floor(xyz[:, 1].min() / c) * c
    col = np.floor((xyz[:, 0] - x0) / c).astype(np.int64)
    row = np.floor((xyz[:, 1] - y0) / c).astype(np.int64)
    nr, nc = int(row.max()) + 1, int(col.max()) + 1
    zmin = np.full(nr * nc, np.inf)
    np.minimum.at(zmin, (row * nc + col)[cand], xyz[cand, 2])
    zmin = np.where(np.isfinite(zmin), zmin, np.nan).reshape(nr, nc)
    surface = _fill_grid(zmin)
    pits = _pit_cells(surface, params.low_outlier_m)
    if pits.any():
        zmin[pits] = np.nan
        surface = _fill_grid(zmin)
    # without adaptive the grid's edge continues level ("nearest"): on a slope the opening then
    # cuts the band within one window of the upper edge; continuing the slope by odd reflection
    # raised objects cut by the edge (AHN3 2.59 -> 3.84 %).  The adaptive padding continues the
    # trend plane from the edge's residual clipped to the median residual: objects at the edge
    # are not carried outward.
    nwin = int(math.ceil(params.window_m / c))
    pad = 0
    last = surface
    if params.adaptive:   # continue the terrain's trend beyond the edge (see the module docstring)
        pad = nwin
        plane = trend_plane(surface, c)
        res = surface - plane
        low = np.minimum(res, np.median(res))
        last = np.pad(plane, pad, mode="reflect", reflect_type="odd") + np.pad(low, pad, mode="edge")
        last[pad:pad + nr, pad:pad + nc] = surface
    obj = np.zeros(last.shape, dtype=bool)
    for r in range(1, nwin + 1):
        size = 2 * r + 1
        opened = maximum_filter(minimum_filter(last, size=size, mode="nearest"), size=size, mode="nearest")
        obj |= (last - opened) > params.slope * r * c
        last = opened
    obj = obj[pad:pad + nr, pad:pad + nc]
    dtm = np.where(obj | ~np.isfinite(zmin), np.nan, zmin)
    if not np.isfinite(dtm).any():
        return ground
    dtm = _fill_grid(dtm)
    gy, gx = np.gradient(dtm, c)
    slope = np.hypot(gx, gy)
    # bilinear sampling at the points (cell centres at index + 0.5)
    coords = np.vstack([(xyz[:, 1] - y0) / c - 0.5, (xyz[:, 0] - x0) / c - 0.5])
    zs = map_coordinates(dtm, coords, order=1, mode="nearest")
    ss = map_coordinates(slope, coords, order=1, mode="nearest")
    ground = cand & (np.abs(xyz[:, 2] - zs) <= params.elevation_threshold_m + params.elevation_scaler * ss)
    return ground


def classify_ground(xyz: np.ndarray, return_number: Any = None, number_of_returns: Any = None, *,
                    method: str = "smrf", params: PTDParameters | SMRFParameters | CSFParameters | None = None
                    ) -> np.ndarray:
    """Ground mask of points by *method* ``"smrf"`` (default), ``"ptd"`` or ``"csf"``.

    CSF (:mod:`lidarcat.production.csf`) shapes its cloth from the last returns less
    the low outliers of the SMRF test (cell twice the point spacing, at least 1 m).

    SMRF is the default because one parameter set holds on the AHN3 reference
    (2.59 % and 2.90 % total error) and on synthetic steep, forested, bridge,
    city and low-outlier landscapes (0.0-1.6 %), where PTD with TerraScan's
    default parameters reaches 5.00 % and 4.89 % on AHN3 but fails on the steep
    slope, the forest and the bridge's valley (12-68 %; docs/production.md).

    Points far outside the bulk of the data in plan (:func:`lidarcat.lidar.raster.bulk_box`:
    a displaced point kilometres away, a byte flip) are not ground and are left out of
    the filter, with a warning that counts them: both filters grid the points' extent,
    which one such point would blow up to gigabytes.

    See :func:`ptd_ground` and :func:`smrf_ground`.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    x0, y0, x1, y1 = bulk_box(xyz[:, 0], xyz[:, 1], 1.0) if len(xyz) else (0.0, 0.0, 0.0, 0.0)
    near = (xyz[:, 0] >= x0) & (xyz[:, 0] <= x1) & (xyz[:, 1] >= y0) & (xyz[:, 1] <= y1)
    if len(xyz) and not near.all():
        far = np.flatnonzero(~near)
        log.warning("%d point(s) far outside the bulk of the data (E %.3f..%.3f N %.3f..%.3f), e.g. E %.3f "
                    "N %.3f: not ground, left out of the ground filter", len(far), x0, x1, y0, y1,
                    xyz[far[0], 0], xyz[far[0], 1])
        keep = np.flatnonzero(near)
        sub = [None if a is None else np.asarray(a)[keep] for a in (return_number, number_of_returns)]
        g = np.zeros(len(xyz), dtype=bool)
        g[keep] = classify_ground(xyz[keep], sub[0], sub[1], method=method, params=params)
        return g
    if method == "ptd":
        if params is not None and not isinstance(params, PTDParameters):
            raise ValueError("method 'ptd' takes PTDParameters")
        return ptd_ground(xyz, return_number, number_of_returns, params)  # type: ignore[arg-type]
    if method == "smrf":
        if params is not None and not isinstance(params, SMRFParameters):
            raise ValueError("method 'smrf' takes SMRFParameters")
        return smrf_ground(xyz, return_number, number_of_returns, params)  # type: ignore[arg-type]
    if method == "csf":
        if params is not None and not isinstance(params, CSFParameters):
            raise ValueError("method 'csf' takes CSFParameters")
        cand = _candidates(len(xyz), return_number, number_of_returns)
        if cand.any():
            cand[_low_outliers(xyz, np.flatnonzero(cand), SMRFParameters().low_outlier_m,
                               max(1.0, 2.0 * _point_spacing(xyz[cand, :2])))] = False
        return csf_ground(xyz, cand, params)  # type: ignore[arg-type]
    raise ValueError(f"unknown ground method {method!r}; use one of {', '.join(GROUND_METHODS)}")


# --------------------------------------------------------------------------- evaluation
@dataclass(frozen=True)
class Confusion:
    """Ground/object confusion counts against a reference, and Sithole-Vosselman errors.

    Attributes
    ----------
    ground_as_ground, ground_as_object, object_as_ground, object_as_object : int
        Point counts (reference first, classification second).
    """

    ground_as_ground: int
    ground_as_object: int
    object_as_ground: int
    object_as_object: int

    @property
    def n(self) -> int:
        """All points."""
        return self.ground_as_ground + self.ground_as_object + self.object_as_ground + self.object_as_object

    @property
    def type1(self) -> float:
        """Type I error: reference ground rejected, fraction of the reference ground."""
        g = self.ground_as_ground + self.ground_as_object
        return self.ground_as_object / g if g else float("nan")

    @property
    def type2(self) -> float:
        """Type II error: reference objects accepted as ground, fraction of the reference objects."""
        o = self.object_as_ground + self.object_as_object
        return self.object_as_ground / o if o else float("nan")

    @property
    def total(self) -> float:
        """Total error: misclassified fraction of all points."""
        return (self.ground_as_object + self.object_as_ground) / self.n if self.n else float("nan")

    @property
    def kappa(self) -> float:
        """Cohen's kappa of the two-class table."""
        n = self.n
        if not n:
            return float("nan")
        po = (self.ground_as_ground + self.object_as_object) / n
        ref_g = (self.ground_as_ground + self.ground_as_object) / n
        cls_g = (self.ground_as_ground + self.object_as_ground) / n
        pe = ref_g * cls_g + (1 - ref_g) * (1 - cls_g)
        return (po - pe) / (1 - pe) if pe < 1 else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """Counts and errors (fractions) as a plain dict."""
        return {"ground_as_ground": self.ground_as_ground, "ground_as_object": self.ground_as_object,
                "object_as_ground": self.object_as_ground, "object_as_object": self.object_as_object,
                "type1": self.type1, "type2": self.type2, "total": self.total, "kappa": self.kappa}


def confusion(reference_ground: Any, classified_ground: Any) -> Confusion:
    """Confusion of a ground mask against a reference ground mask (same shape).

    Examples
    --------
    >>> c = confusion([True, True, False, False], [True, False, False, True])
    >>> c.type1, c.type2, c.total, c.kappa
    (0.5, 0.5, 0.5, 0.0)
    """
    r = np.asarray(reference_ground, dtype=bool)
    c = np.asarray(classified_ground, dtype=bool)
    if r.shape != c.shape:
        raise ValueError(f"reference and classification differ in shape: {r.shape} vs {c.shape}")
    return Confusion(int(np.sum(r & c)), int(np.sum(r & ~c)), int(np.sum(~r & c)), int(np.sum(~r & ~c)))


# --------------------------------------------------------------------------- files
def write_classified_copy(src: str | os.PathLike, dst: str | os.PathLike, ground: np.ndarray,
                          crs: Any = None, *, noise: np.ndarray | None = None,
                          hag_m: np.ndarray | None = None, copc: bool = False) -> Path:
    """Copy the LAS/LAZ file *src* to *dst* with class 2 set on *ground* (atomically).

    With *copc* the copy is a COPC file (:func:`lidarcat.lidar.copc_write.write_copc`:
    LAS 1.4, point format 6-8, an octree of LAZ chunks) instead of LAS/LAZ by *dst*'s suffix.

    With *noise* (bool, one per point) those points get class 7 (noise; a point
    both noise and ground stays ground).  With *hag_m* (float, one per point,
    metres) the copy carries the extra dimension ``HeightAboveGround`` (float32,
    LAS extra bytes, as PDAL's ``filters.hag_*`` name it).

    Every other field, record and VLR is kept.  Points that were ground (2)
    in *src* but are not in *ground* become unclassified (1); the other classes
    stay as they were.  *src* is never modified.  When *src* carries no CRS and
    *crs* (CRS-like, e.g. the ``--crs`` given for such tiles) is given, the
    copy carries it (GeoTIFF keys in LAS 1.2/1.3, WKT in LAS 1.4 with point
    formats 6-10, laspy's ``add_crs``), so later stages read it from the copy.

    Raises
    ------
    ProductError
        *dst* is *src*.
    ValueError
        *ground* does not match the number of points.
    TileIOError, LidarFormatError
        *src* cannot be read.
    """
    import laspy

    from .._util import atomic_write
    from ..lidar.readers import ascii_header_text

    src, dst = Path(src), Path(dst)
    if dst.exists() and src.exists() and os.path.samefile(src, dst):
        raise ProductError(f"{dst}: the output would overwrite the input; choose another name")
    try:
        las = laspy.read(str(src))
    except OSError as ex:
        raise TileIOError(f"{src}: cannot read ({ex})") from ex
    except Exception as ex:  # laspy raises its own LaspyException and ValueErrors on corrupt data
        raise LidarFormatError(f"{src}: corrupt LAS/LAZ ({type(ex).__name__}: {ex})") from ex
    ground = np.asarray(ground, dtype=bool)
    if len(ground) != len(las.points):
        raise ValueError(f"{src}: {len(las.points)} points but {len(ground)} ground flags")
    cls = np.array(las.classification, dtype=np.uint8)
    cls[(cls == GROUND_CLASS) & ~ground] = UNCLASSIFIED_CLASS
    if noise is not None:
        noise = np.asarray(noise, dtype=bool)
        if len(noise) != len(las.points):
            raise ValueError(f"{src}: {len(las.points)} points but {len(noise)} noise flags")
        cls[noise & ~ground] = NOISE_CLASS
    cls[ground] = GROUND_CLASS
    las.classification = cls
    if hag_m is not None:
        hag_m = np.asarray(hag_m, dtype=np.float64)
        if len(hag_m) != len(las.points):
            raise ValueError(f"{src}: {len(las.points)} points but {len(hag_m)} heights above ground")
        if "HeightAboveGround" not in las.point_format.extra_dimension_names:
            las.add_extra_dim(laspy.ExtraBytesParams(name="HeightAboveGround", type=np.float32,
                                                     description="height above ground, m"))
        las.HeightAboveGround = hag_m.astype(np.float32)
    ascii_header_text(las.header, src)   # laspy writes no non-ASCII header text (issue 24)
    if copc:
        from ..lidar.copc_write import write_copc

        return write_copc(las, dst, crs=crs)
    add_las_crs(las.header, crs)
    compress = dst.suffix.lower() == ".laz"
    with atomic_write(dst, "wb") as fh:
        las.write(fh, do_compress=compress)
    return dst


def params_from_dict(method: str, d: dict[str, Any]) -> PTDParameters | SMRFParameters | CSFParameters:
    """The parameter object of *method* from the matching keys of *d* (others ignored)."""
    import dataclasses

    cls = {"ptd": PTDParameters, "csf": CSFParameters}.get(method, SMRFParameters)
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in d.items() if k in names})


def default_overlap_m(method: str, params: PTDParameters | SMRFParameters | None = None) -> float:
    """Neighbour buffer for tile runs, metres: two seed windows (PTD) or two opening windows (SMRF)."""
    if method == "smrf":
        return 2.0 * (params.window_m if isinstance(params, SMRFParameters) else SMRFParameters().window_m)
    if method == "csf":
        return 2.0 * SMRFParameters().window_m   # the cloth bridges objects about as wide as SMRF's window
    return 2.0 * (params.max_building_m if isinstance(params, PTDParameters) else PTDParameters().max_building_m)


def ground_tile(job: TileJob) -> None:
    """The tile function of :func:`classify_tiles` (for :mod:`lidarcat.lidar.jobs`).

    Classifies ``job.tile`` together with its neighbours' points within
    ``job.overlap_m`` by ``job.params`` (``method`` and the parameters of
    :func:`params_from_dict`; ``noise``: statistical outliers become class 7
    first and are left out of the ground filter; ``hag``: the copy carries the
    points' height above the ground TIN) and writes the tile's classified copy
    to ``job.output`` (:func:`write_classified_copy`).
    """
    cloud, n_own = read_with_buffer(job)
    method = job.params.get("method", "smrf")
    xyz = cloud.xyz
    rn, nr = cloud.attributes.get("return_number"), cloud.attributes.get("number_of_returns")
    noise = statistical_outliers(xyz) if job.params.get("noise") else np.zeros(len(xyz), dtype=bool)
    keep = np.flatnonzero(~noise)
    g = np.zeros(len(xyz), dtype=bool)
    g[keep] = classify_ground(xyz[keep], None if rn is None else np.asarray(rn)[keep],
                              None if nr is None else np.asarray(nr)[keep],
                              method=method, params=params_from_dict(method, job.params))
    hag = height_above_ground(xyz, g)[:n_own] if job.params.get("hag") else None
    write_classified_copy(job.tile, job.output, g[:n_own], crs=cloud.crs,
                          noise=noise[:n_own] if job.params.get("noise") else None, hag_m=hag,
                          copc=bool(job.params.get("copc")))


def classify_tiles(paths: Sequence[str | os.PathLike], out: str | os.PathLike, *, crs: Any = None,
                   method: str = "smrf", params: PTDParameters | SMRFParameters | CSFParameters | None = None,
                   noise: bool = False, hag: bool = False, copc: bool = False, overlap_m: float | None = None,
                   workers: int | None = None, scheduler: str | None = None,
                   resume: bool = True, progress: Callable[[int], Any] | None = None) -> list[Path]:
    """Classify LAS/LAZ tiles into copies, each with the points of its neighbours.

    Parameters
    ----------
    paths : sequence of path-like
        Input tiles (LAS/LAZ/COPC); never modified.
    out : path-like
        A ``.las``/``.laz`` file when there is one input, else a folder that
        receives one copy per tile under the input's name.
    method : {"smrf", "ptd", "csf"}
    params : PTDParameters, SMRFParameters or CSFParameters, optional
    noise : bool
        Statistical outliers (:func:`lidarcat.production.noise.statistical_outliers`)
        become class 7 and stay out of the ground filter.
    hag : bool
        Write each point's height above the ground TIN as the extra dimension
        ``HeightAboveGround`` (:func:`lidarcat.production.noise.height_above_ground`).
    copc : bool
        Write COPC files (:func:`lidarcat.lidar.copc_write.write_copc`): one tile and *out*
        ending in ``.laz``: that file; else ``<tile name>.copc.laz`` in the folder *out*.
    overlap_m : float, optional
        Buffer of neighbour points, metres (default :func:`default_overlap_m`).
    workers, scheduler, resume
        See :func:`lidarcat.lidar.jobs.run_jobs` (serial by default).
    progress : callable, optional
        Called with 1 after each tile.

    Returns
    -------
    list of Path
        The written files.
    """
    import dataclasses

    if method not in GROUND_METHODS:
        raise ValueError(f"unknown ground method {method!r}; use one of {', '.join(GROUND_METHODS)}")
    pdict: dict[str, Any] = {"method": method, "noise": bool(noise), "hag": bool(hag), "copc": bool(copc)}
    if params is not None:
        pdict.update(dataclasses.asdict(params))
    ov = default_overlap_m(method, params) if overlap_m is None else float(overlap_m)
    jobs = tile_jobs(ground_tile, paths, out, crs=crs, params=pdict, overlap_m=ov)
    if copc and len(jobs) == 1 and Path(out).suffix.lower() == ".las":
        raise ProductError(f"{out}: a COPC file is LAZ; name it .copc.laz")
    if copc and not (len(jobs) == 1 and Path(out).suffix.lower() == ".laz"):
        jobs = [dataclasses.replace(j, output=str(Path(out) / (Path(j.tile).name.split(".")[0] + ".copc.laz")))
                for j in jobs]
    for j in jobs:
        if Path(j.output).resolve() == Path(j.tile).resolve():
            raise ProductError(f"{j.output}: the output would overwrite the input; choose another name or folder")
    return [Path(p) for p in run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume,
                                      progress=progress)]
