r"""Monorestitution: a pixel of ONE oriented photo intersected with the LiDAR surface.

Cavassim (2005, section 6.2) maps buildings and roads by digitising them on a
single oriented photo and intersecting each image ray with a LiDAR surface
model; this module does that, vectorised over all points.

The image ray (inverse collinearity)
------------------------------------
A pixel (column C, row L) becomes corrected photo coordinates ``(x, y)`` (mm,
distortion, decentering and refraction removed by
:meth:`lidarcat.geometry.camera.Camera.pixel_to_photo`, eq. 01-07).  With
``u = M (X - X0)`` and ``x = -c u1/u3``, ``y = -c u2/u3`` (eq. 08,
:mod:`lidarcat.geometry.collinearity`), every object point on the ray is

.. math::  X(t) = X_0 + t\,d, \qquad d = M^T (x,\;y,\;-c)^T,\quad t > 0 .

Two ways to meet the surface ``h = S(E, N)``
--------------------------------------------
``method="iterate"`` -- the paper's (Mitishita 1997) height iteration: start at
``h_0`` (the surface height under the projection centre), put the ray at that
height, ``t_k = (h_k - Z_0) / d_z``, read ``h_{k+1} = S(E(t_k), N(t_k))``, and
stop when the plan position moves less than ``tol_m``.  It is a fixed-point
iteration: it converges when ``|grad S| tan(ray off-nadir angle) < 1`` and may
oscillate on walls (status ``not_converged``); it may also converge to a point
the camera cannot see, behind a building: such a result is checked against the
first hit and flagged ``occluded`` (its coordinates are NaN: a hidden point is
never returned as if measured).

``method="exact"`` (default) -- the ray's FIRST hit: ``f(t) = Z(t) - S(E(t), N(t))``
is sampled from where the ray enters the surface's height range
``[h_min, h_max]`` to where it leaves it, with a plan step of half the
surface's resolution, and the first sign change ``f > 0 -> f <= 0`` is bisected
to ``tol_m``.  A ray can clip a roof corner between two samples; every interval
before the first sign change where the ray's lower end lies under a local upper
bound of the surface (the 3 x 3 cell maximum of a grid; the 5 x 5 maximum of
the highest point per cell for points) is sub-sampled 16 times, and the
earliest crossing wins.  This is the exact intersection with the interpolated
surface (up to a clip shorter than 1/32 of a cell), and it is occlusion-aware
by construction: the camera sees what the ray meets first, so a pixel on a
roof gives the roof, never the ground hidden behind it.

Surfaces and interpolators
--------------------------
:class:`GridSurface` -- a DSM/DTM grid (:mod:`lidarcat.lidar.raster`):
``nearest`` (the cell's value) or ``bilinear`` (between cell centres).
:class:`PointSurface` -- the LiDAR points themselves, no grid: ``nearest``
(the height of the nearest point, the paper's "vizinho mais proximo") or
``tin`` (the plane of the Delaunay triangle containing the position, the
paper's "superficie triangular plana").  Outside the data (grid NaN, outside
the convex hull of the points) the height is NaN: status ``outside_surface``.

Propagated standard deviation
-----------------------------
Near the hit the surface is its tangent plane ``n . (X - H) = 0`` with
``n = (-dS/dE, -dS/dN, 1)`` (finite differences over one resolution step), so
``X = C + t d`` with ``t = n . (H - C) / (n . d)``.  The Jacobian of ``X``
with respect to ``p = (X0, Y0, Z0, omega, phi, kappa, C, L, dh)`` is taken by
central differences of that closed form, and

.. math::  \Sigma_X = J\,\mathrm{diag}(\Sigma_{EO},\;\sigma_{px}^2 I_2,\;\sigma_S^2)\,J^T .

``Sigma_EO`` is the 6 x 6 covariance of the photo's exterior orientation when
the adjustment gives it (:class:`lidarcat.bundle.ExteriorOrientation` from a
:class:`~lidarcat.bundle.BundleResult`); read from an ``eop.csv`` only the
standard deviations are known
(:func:`lidarcat.mapping.inputs.read_orientations`), so the correlations
between the position and the angles are taken as zero there -- the usual case
of a vertical photo, where X0 and phi are strongly correlated, then overstates
the plan sd.  ``sigma_S`` is the height sd of the surface (LiDAR noise plus
interpolation), ``sigma_px`` the pointing sd of the operator.

Statuses
--------
``ok``, ``outside_photo`` (the pixel is not on the sensor), ``no_intersection``
(the ray points upwards or passes over the surface), ``outside_surface`` (the
surface has no data where the ray comes down), ``not_converged`` (iteration
only), ``occluded`` (iteration only: the converged point is hidden).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry.collinearity import rotation_matrix
from .._util.frozen import frozen_array
from ..geometry.camera import Camera
from ..geometry.tin import TinLocator
from ..errors import LidarcatError

__all__ = ["GridSurface", "PointSurface", "MonoplotResult", "monoplot", "ray_directions",
           "STATUSES", "INTERPOLATORS", "MonoplotError"]

log = logging.getLogger(__name__)

#: statuses of a monorestituted point
STATUSES = ("ok", "outside_photo", "no_intersection", "outside_surface", "not_converged", "occluded")
#: interpolators by surface kind
INTERPOLATORS = {"grid": ("nearest", "bilinear"), "points": ("nearest", "tin")}

#: rays x samples evaluated at once by the first-hit search (bounds memory)
_CHUNK_SAMPLES = 2_000_000


class MonoplotError(LidarcatError, ValueError):
    """Monorestitution inputs are invalid (names the file, photo or parameter)."""


# ---------------------------------------------------------------------------- surfaces
class _Surface:
    """Common interface: ``height(e, n)``, ``bounds``, ``h_range``, ``resolution_m``, ``sd_m``."""

    interpolator: str
    sd_m: float

    def height(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def resolution_m(self) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def h_range(self) -> tuple[float, float]:  # pragma: no cover - abstract
        raise NotImplementedError

    def upper_bound(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """An upper bound of the surface within ``resolution_m / 4`` of each position (m; -inf: no data).

        The first-hit search uses it to find rays that clip the surface between two samples.
        """
        b, t = self._bound()
        col = np.floor((np.asarray(e) - t[0]) / t[2]).astype(np.int64)
        row = np.floor((t[1] - np.asarray(n)) / t[2]).astype(np.int64)
        inside = (col >= 0) & (col < b.shape[1]) & (row >= 0) & (row < b.shape[0])
        out = np.full(np.shape(e), -np.inf)
        out[inside] = b[row[inside], col[inside]]
        return out

    def _bound(self) -> tuple[np.ndarray, tuple[float, float, float]]:
        cached = self.__dict__.get("_bound_cache")
        if cached is None:
            cached = self._make_bound()
            object.__setattr__(self, "_bound_cache", cached)
        return cached

    def _make_bound(self) -> tuple[np.ndarray, tuple[float, float, float]]:  # pragma: no cover - abstract
        raise NotImplementedError

    def gradient(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """(N, 2) dS/dE, dS/dN by central differences over one resolution step (0 where undefined)."""
        s = self.resolution_m
        g = np.column_stack([(self.height(e + s, n) - self.height(e - s, n)) / (2 * s),
                             (self.height(e, n + s) - self.height(e, n - s)) / (2 * s)])
        return np.where(np.isfinite(g), g, 0.0)


@dataclass(frozen=True, eq=False)
class GridSurface(_Surface):
    """A north-up height grid (DSM or DTM) as a surface.

    Parameters
    ----------
    grid : (rows, cols) array
        Heights, m; NaN = no data.  Row 0 is the north edge.
    transform : lidarcat.lidar.GeoTransform
        West edge, north edge and cell size (m).
    interpolator : {"bilinear", "nearest"}
        Bilinear between cell centres, or the value of the cell containing the point.
    sd_m : float
        Height sd of the surface (m), used in the propagated sd.
    """

    grid: np.ndarray
    transform: Any
    interpolator: str = "bilinear"
    sd_m: float = 0.15

    def __post_init__(self) -> None:
        g = np.asarray(self.grid, dtype=np.float64)
        if g.ndim != 2 or g.size == 0:
            raise MonoplotError(f"surface grid must be a non-empty 2-D array, got shape {g.shape}")
        if not np.isfinite(g).any():
            raise MonoplotError("surface grid holds no finite height")
        if self.interpolator not in INTERPOLATORS["grid"]:
            raise MonoplotError(f"grid interpolator must be one of {', '.join(INTERPOLATORS['grid'])}, "
                                f"got {self.interpolator!r} (tin works on LiDAR points: PointSurface)")
        object.__setattr__(self, "grid", frozen_array(g))

    @classmethod
    def from_geotiff(cls, path: str | os.PathLike, interpolator: str = "bilinear",
                     sd_m: float = 0.15, *, crs: Any = None) -> GridSurface:
        """Read a DSM/DTM GeoTIFF: any that GDAL reads (compressed, tiled, BigTIFF, any data type).

        Through :func:`lidarcat.lidar.geotiff.read_geotiff`: the file's nodata
        cells are NaN; heights in the file's vertical unit (metres expected).
        With *crs* (CRS-like, e.g. the survey's), a file labelled with another
        CRS is refused (a file without a CRS is taken as in *crs*).

        Raises
        ------
        MonoplotError
            The file holds more than one band (an image, not heights), or its
            CRS is not compatible with *crs*.
        """
        from ..lidar.crs import crs_compatible, crs_label, resolve_crs
        from ..lidar.geotiff import read_geotiff

        grid, transform, file_crs = read_geotiff(path)
        if grid.ndim != 2:
            raise MonoplotError(f"{path}: {grid.shape[2]} bands; a surface model has one band of heights")
        want = resolve_crs(crs)
        if want is not None and file_crs is not None and not crs_compatible(file_crs, want):
            raise MonoplotError(f"{path}: the surface model is in {crs_label(file_crs)}, not in "
                                f"{crs_label(want)}; reproject it (e.g. gdalwarp -t_srs)")
        return cls(grid, transform, interpolator, sd_m)

    @property
    def resolution_m(self) -> float:
        return float(self.transform.cell_m)

    def _make_bound(self) -> tuple[np.ndarray, tuple[float, float, float]]:
        """Max over the 3 x 3 cells around each cell: both interpolators stay below it within a cell."""
        from scipy.ndimage import maximum_filter

        g = np.where(np.isfinite(self.grid), self.grid, -np.inf)
        t = self.transform
        return maximum_filter(g, size=3, mode="nearest"), (t.x0, t.y0, t.cell_m)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax), m."""
        t, (r, c) = self.transform, self.grid.shape
        return t.x0, t.y0 - r * t.cell_m, t.x0 + c * t.cell_m, t.y0

    @property
    def h_range(self) -> tuple[float, float]:
        return float(np.nanmin(self.grid)), float(np.nanmax(self.grid))

    def height(self, e: Any, n: Any) -> np.ndarray:
        """Surface height (m) at plan positions; NaN outside the grid or in its holes."""
        e = np.asarray(e, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        t, g = self.transform, self.grid
        rows, cols = g.shape
        fc = (e - t.x0) / t.cell_m
        fr = (t.y0 - n) / t.cell_m
        inside = (fc >= 0) & (fc <= cols) & (fr >= 0) & (fr <= rows)
        out = np.full(e.shape, np.nan)
        if self.interpolator == "nearest":
            c = np.clip(np.floor(fc[inside]).astype(np.int64), 0, cols - 1)
            r = np.clip(np.floor(fr[inside]).astype(np.int64), 0, rows - 1)
            out[inside] = g[r, c]
            return out
        x = np.clip(fc[inside] - 0.5, 0, cols - 1)   # between cell centres; the outer half cell
        y = np.clip(fr[inside] - 0.5, 0, rows - 1)   # takes the border value
        c0 = np.minimum(np.floor(x).astype(np.int64), max(cols - 2, 0))
        r0 = np.minimum(np.floor(y).astype(np.int64), max(rows - 2, 0))
        c1, r1 = np.minimum(c0 + 1, cols - 1), np.minimum(r0 + 1, rows - 1)
        ax, ay = x - c0, y - r0
        out[inside] = ((g[r0, c0] * (1 - ax) + g[r0, c1] * ax) * (1 - ay)
                       + (g[r1, c0] * (1 - ax) + g[r1, c1] * ax) * ay)
        return out


@dataclass(frozen=True, eq=False)
class PointSurface(_Surface):
    """The LiDAR points as a surface, without a grid.

    Parameters
    ----------
    xyz : (N, 3) array
        E, N, h of the points, m (first returns: the visible surface).
    interpolator : {"tin", "nearest"}
        ``tin``: the plane of the Delaunay triangle (in plan) containing the
        position; ``nearest``: the height of the nearest point in plan.
    sd_m : float
        Height sd of the surface (m).

    Notes
    -----
    Both interpolators return NaN outside the convex hull of the points.
    Coordinates are centred before triangulating (UTM values lose digits in Qhull).
    """

    xyz: np.ndarray
    interpolator: str = "tin"
    sd_m: float = 0.15
    _origin: np.ndarray = field(init=False, repr=False)
    _tri: Any = field(init=False, repr=False)
    _tree: Any = field(init=False, repr=False)
    _locator: TinLocator = field(init=False, repr=False)

    def __post_init__(self) -> None:
        from scipy.spatial import Delaunay, QhullError, cKDTree

        p = np.asarray(self.xyz, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3:
            raise MonoplotError(f"surface points must be an (N >= 3, 3) array, got shape {p.shape}")
        p = p[np.isfinite(p).all(axis=1)]
        if self.interpolator not in INTERPOLATORS["points"]:
            raise MonoplotError(f"point interpolator must be one of {', '.join(INTERPOLATORS['points'])}, "
                                f"got {self.interpolator!r} (bilinear needs a grid: GridSurface)")
        origin = p[:, :2].mean(axis=0)
        en = p[:, :2] - origin
        try:
            tri = Delaunay(en)
        except QhullError as ex:
            raise MonoplotError(f"surface points cannot be triangulated (all on a line?): {ex}") from ex
        object.__setattr__(self, "xyz", frozen_array(p))
        object.__setattr__(self, "_origin", origin)
        object.__setattr__(self, "_tri", tri)
        object.__setattr__(self, "_tree", cKDTree(en) if self.interpolator == "nearest" else None)
        object.__setattr__(self, "_locator", TinLocator(tri, start_grid=True))

    @property
    def resolution_m(self) -> float:
        """Mean point spacing: sqrt(hull area / N), m."""
        return float(math.sqrt(self._locator.area / len(self.xyz)))

    def _make_bound(self) -> tuple[np.ndarray, tuple[float, float, float]]:
        """Highest point per cell of one resolution, max over 5 x 5 cells (triangles span ~2 cells)."""
        from scipy.ndimage import maximum_filter

        cell = self.resolution_m
        lo, hi = self.xyz[:, :2].min(axis=0), self.xyz[:, :2].max(axis=0)
        cols = int((hi[0] - lo[0]) / cell) + 1
        rows = int((hi[1] - lo[1]) / cell) + 1
        c = np.floor((self.xyz[:, 0] - lo[0]) / cell).astype(np.int64)
        r = np.floor((hi[1] - self.xyz[:, 1]) / cell).astype(np.int64)
        b = np.full(rows * cols, -np.inf)
        np.maximum.at(b, r * cols + c, self.xyz[:, 2])
        b = maximum_filter(b.reshape(rows, cols), size=5, mode="nearest")
        return b, (float(lo[0]), float(hi[1]), cell)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        lo, hi = self.xyz[:, :2].min(axis=0), self.xyz[:, :2].max(axis=0)
        return float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])

    @property
    def h_range(self) -> tuple[float, float]:
        return float(self.xyz[:, 2].min()), float(self.xyz[:, 2].max())

    def _locate(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Triangle containing each (centred) plan position (-1: none) and its barycentric weights.

        :meth:`lidarcat.geometry.tin.TinLocator.locate`, walking at most 48
        steps before the nearest triangles are searched.
        """
        return self._locator.locate(q, max_steps=48)

    def height(self, e: Any, n: Any) -> np.ndarray:
        """Surface height (m) at plan positions; NaN outside the convex hull."""
        e = np.asarray(e, dtype=np.float64)
        shape = e.shape
        q = np.column_stack([e.ravel() - self._origin[0], np.asarray(n, dtype=np.float64).ravel()
                             - self._origin[1]])
        out = np.full(len(q), np.nan)
        s, w = self._locate(q)
        inside = s >= 0
        if self.interpolator == "nearest":
            _, idx = self._tree.query(q[inside])
            out[inside] = self.xyz[idx, 2]
            return out.reshape(shape)
        out[inside] = np.einsum("ki,ki->k", w[inside], self.xyz[self._tri.simplices[s[inside]], 2])
        return out.reshape(shape)


# ---------------------------------------------------------------------------- rays
def ray_directions(camera: Camera, eo_params: Any, colrow_px: Any) -> np.ndarray:
    """Object-space directions ``d = M^T (x, y, -c)`` of the rays of pixels (not normalised).

    Parameters
    ----------
    camera : Camera
    eo_params : (6,) array
        X0, Y0, Z0 (m), omega, phi, kappa (rad).
    colrow_px : (N, 2) array
        Column, row (px).

    Returns
    -------
    (N, 3) array
        Direction of each ray in E, N, h (units of the photo coordinates, mm).
    """
    xy = np.asarray(camera.pixel_to_photo(np.asarray(colrow_px, dtype=float).reshape(-1, 2)))
    m = rotation_matrix(np.asarray(eo_params, dtype=float)[3:6])
    v = np.column_stack([xy, np.full(len(xy), -camera.focal_length_mm)])
    return v @ m   # rows: (M^T v)^T = v^T M


def _first_hit(surface: _Surface, c: np.ndarray, d: np.ndarray, tol_m: float,
               t_max: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """First crossing of rays ``c + t d`` with the surface.

    Returns ``t`` (N,) (NaN where none) and a status code (N,): 0 ok,
    2 no_intersection, 3 outside_surface.  With *t_max* the search stops there.
    """
    n = len(d)
    t_hit = np.full(n, np.nan)
    code = np.full(n, 2, dtype=np.int8)
    hmin, hmax = surface.h_range
    dz = d[:, 2]
    down = dz < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = np.maximum((hmax + 0.01 - c[2]) / dz, 0.0)
        t1 = (hmin - 0.01 - c[2]) / dz
    if t_max is not None:
        t1 = np.minimum(t1, t_max)
    down &= t1 > t0
    step = 0.5 * surface.resolution_m
    plan = np.hypot(d[:, 0], d[:, 1])
    k_need = np.ones(n, dtype=np.int64)
    k_need[down] = np.ceil((t1[down] - t0[down]) * plan[down] / step).astype(np.int64) + 1
    k_need = np.maximum(k_need, 2)
    # rays sorted by their number of samples, processed in chunks of bounded size
    idx_all = np.flatnonzero(down)
    idx_all = idx_all[np.argsort(k_need[idx_all], kind="stable")]
    start = 0
    while start < len(idx_all):
        k = int(k_need[idx_all[start]])
        m = max(1, _CHUNK_SAMPLES // max(k, 1))
        # grow the chunk while the sample count stays within budget
        stop = min(len(idx_all), start + m)
        k = int(k_need[idx_all[stop - 1]])
        while k * (stop - start) > _CHUNK_SAMPLES and stop - start > 1:
            stop = start + max(1, (stop - start) // 2)
            k = int(k_need[idx_all[stop - 1]])
        ids = idx_all[start:stop]
        start = stop
        s = np.linspace(0.0, 1.0, k)
        tt = t0[ids, None] + (t1[ids] - t0[ids])[:, None] * s[None, :]          # (m, k)
        pe = c[0] + tt * d[ids, 0:1]
        pn = c[1] + tt * d[ids, 1:2]
        pz = c[2] + tt * d[ids, 2:3]
        f = pz - surface.height(pe, pn)
        below = f <= 0                                # NaN compares False
        has = below.any(axis=1)
        first = np.argmax(below, axis=1)
        nan_any = np.isnan(f).any(axis=1)
        prev_ok = np.zeros(len(ids), dtype=bool)
        ok_rows = np.flatnonzero(has)
        j = first[ok_rows]
        prev_ok[ok_rows] = (j == 0) | np.isfinite(f[ok_rows, np.maximum(j - 1, 0)])
        good = has & prev_ok
        lo_all = np.full(len(ids), np.nan)
        hi_all = np.full(len(ids), np.nan)
        g = np.flatnonzero(good)
        lo_all[g] = tt[g, np.maximum(first[g] - 1, 0)]
        hi_all[g] = tt[g, first[g]]
        # grazing hits between two samples (a roof corner the ray clips): intervals whose lower
        # end is under the surface's local upper bound are searched with 16 sub-samples
        j_cross = np.where(good, first, k)
        ub = surface.upper_bound(0.5 * (pe[:, :-1] + pe[:, 1:]), 0.5 * (pn[:, :-1] + pn[:, 1:]))
        cand = (pz[:, 1:] <= ub) & (np.arange(k - 1)[None, :] < (j_cross - 1)[:, None])
        ri, ii = np.nonzero(cand)
        if ri.size:
            sub = np.linspace(0.0, 1.0, 18)[1:-1]
            ts = tt[ri, ii][:, None] + (tt[ri, ii + 1] - tt[ri, ii])[:, None] * sub
            fs = c[2] + ts * d[ids[ri], 2:3] - surface.height(c[0] + ts * d[ids[ri], 0:1],
                                                              c[1] + ts * d[ids[ri], 1:2])
            bel = fs <= 0
            found = bel.any(axis=1)
            ri, ii, ts, bel = ri[found], ii[found], ts[found], bel[found]
            rows, at = np.unique(ri, return_index=True)       # earliest interval of each ray
            jj = np.argmax(bel[at], axis=1)
            hi_all[rows] = ts[at, jj]
            lo_all[rows] = np.where(jj > 0, ts[at, np.maximum(jj - 1, 0)], tt[rows, ii[at]])
            good[rows] = True
        code[ids[~good & nan_any]] = 3
        if not good.any():
            continue
        g = np.flatnonzero(good)
        lo, hi = lo_all[g], hi_all[g]
        rid = ids[g]
        speed = np.linalg.norm(d[rid], axis=1)
        # bisection to tol_m along the ray; f(lo) > 0 >= f(hi)
        for _ in range(64):
            if np.all((hi - lo) * speed <= tol_m):
                break
            mid = 0.5 * (lo + hi)
            fm = c[2] + mid * d[rid, 2] - surface.height(c[0] + mid * d[rid, 0], c[1] + mid * d[rid, 1])
            under = ~(fm > 0)           # NaN in the middle: keep the lower half (the crossing is there)
            hi = np.where(under, mid, hi)
            lo = np.where(under, lo, mid)
        t_hit[rid] = hi
        code[rid] = 0
    return t_hit, code


def _iterate(surface: _Surface, c: np.ndarray, d: np.ndarray, tol_m: float,
             max_iter: int, start: str = "nadir") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The paper's height iteration; returns t, status code (0, 2, 3, 4) and iterations used."""
    n = len(d)
    code = np.zeros(n, dtype=np.int8)
    n_iter = np.zeros(n, dtype=np.int64)
    t = np.full(n, np.nan)
    down = d[:, 2] < 0
    code[~down] = 2
    h0 = (surface.height(np.array([c[0]]), np.array([c[1]]))[0] if start == "nadir"
          else float(surface.h_range[1]))
    if not np.isfinite(h0):
        h0 = float(np.mean(surface.h_range))
    h = np.full(n, h0)
    e_prev = np.full((n, 2), np.nan)
    todo = down.copy()
    for it in range(1, max_iter + 1):
        idx = np.flatnonzero(todo)
        if idx.size == 0:
            break
        ti = (h[idx] - c[2]) / d[idx, 2]
        en = c[:2] + ti[:, None] * d[idx, :2]
        t[idx] = ti
        n_iter[idx] = it
        moved = np.hypot(*(en - e_prev[idx]).T)
        done = moved <= tol_m
        todo[idx[done]] = False
        e_prev[idx] = en
        hn = surface.height(en[:, 0], en[:, 1])
        bad = ~np.isfinite(hn) & ~done
        code[idx[bad]] = 3
        todo[idx[bad]] = False
        h[idx] = np.where(np.isfinite(hn), hn, h[idx])
    code[todo] = 4
    return t, code, n_iter


# ---------------------------------------------------------------------------- result
@dataclass(frozen=True, eq=False)
class MonoplotResult:
    """Monorestituted points.

    Attributes
    ----------
    enh : (N, 3) float
        E, N, h (m); NaN where the status is not ``ok``.
    sd : (N, 3) float
        Propagated standard deviations of E, N, h (m).
    cov : (N, 3, 3) float
        Propagated covariance of E, N, h (m^2).
    status : (N,) str
        One of :data:`STATUSES`.
    n_iter : (N,) int
        Height iterations (``method="iterate"``; 0 for ``exact``).
    method : str
        ``exact`` or ``iterate``.
    interpolator : str
    """

    enh: np.ndarray
    sd: np.ndarray
    cov: np.ndarray
    status: np.ndarray
    n_iter: np.ndarray
    method: str
    interpolator: str

    def __post_init__(self) -> None:
        for name in ("enh", "sd", "cov", "status", "n_iter"):
            object.__setattr__(self, name, frozen_array(getattr(self, name), dtype=None))

    def __len__(self) -> int:
        return len(self.enh)

    @property
    def ok(self) -> np.ndarray:
        """(N,) bool: status ``ok``."""
        return self.status == "ok"

    def counts(self) -> dict[str, int]:
        """Number of points per status."""
        return {s: int((self.status == s).sum()) for s in STATUSES if (self.status == s).any()}


# ---------------------------------------------------------------------------- main entry
def monoplot(colrow_px: Any, camera: Camera, eo: Any, surface: _Surface, *, method: str = "exact",
             image_sd_px: float = 0.5, eo_cov: Any = None, tol_m: float = 1e-3, max_iter: int = 50,
             start: str = "nadir", progress: Callable[[int, int], None] | None = None) -> MonoplotResult:
    """Intersect the image rays of pixels with a surface (see the module docstring).

    Parameters
    ----------
    colrow_px : (N, 2) array
        Column, row of the digitised positions on the photo, px.
    camera : Camera
        The photo's interior orientation (distortion is removed through it).
    eo : ExteriorOrientation or (6,) array
        Adjusted exterior orientation (X0, Y0, Z0 m; omega, phi, kappa rad).
        An :class:`lidarcat.bundle.ExteriorOrientation` brings its 6 x 6
        covariance (``.cov``), used unless *eo_cov* is given.
    surface : GridSurface or PointSurface
    method : {"exact", "iterate"}
        First hit of the ray (occlusion-aware), or the paper's height iteration.
    image_sd_px : float
        Pointing sd of the digitised positions, px.
    eo_cov : (6, 6) array, optional
        Covariance of the exterior orientation (m^2, rad^2).  Default: the one
        of *eo*; none at all: the orientation is taken as error-free.
    tol_m : float
        Convergence: plan change (iteration) or bracket length (exact), m.
    max_iter : int
        Iterations of ``method="iterate"`` before ``not_converged``.
    start : {"nadir", "top"}
        First height of ``method="iterate"``: the surface below the projection
        centre (``nadir``, default: the local ground, as the paper's first
        position from a plane projective transformation) or the highest
        height of the surface (``top``: the iteration comes down onto a roof
        from above; from the ground, the ray through a roof corner that
        leaves the roof as it descends converges on the ground behind the
        building even where the surface holds the roof: flagged ``occluded``).
    progress : callable, optional
        ``progress(done, total)`` after each stage.

    Returns
    -------
    MonoplotResult

    Raises
    ------
    MonoplotError
        Unknown method, an input of the wrong shape, a negative sd.
    """
    if method not in ("exact", "iterate"):
        raise MonoplotError(f"method must be 'exact' or 'iterate', got {method!r}")
    if start not in ("nadir", "top"):
        raise MonoplotError(f"start must be 'nadir' or 'top', got {start!r}")
    if not (image_sd_px >= 0 and tol_m > 0 and max_iter >= 1):
        raise MonoplotError("image_sd_px must be >= 0, tol_m > 0 and max_iter >= 1 "
                            f"(got {image_sd_px}, {tol_m}, {max_iter})")
    cr = np.asarray(colrow_px, dtype=np.float64)
    if cr.ndim == 1 and cr.size == 2:
        cr = cr.reshape(1, 2)
    if cr.ndim != 2 or cr.shape[1] != 2:
        raise MonoplotError(f"colrow_px must have shape (N, 2), got {cr.shape}")
    params = np.asarray(getattr(eo, "params", eo), dtype=np.float64).reshape(-1)
    if params.shape != (6,) or not np.isfinite(params).all():
        raise MonoplotError(f"exterior orientation must be 6 finite numbers, got {params}")
    if eo_cov is None:
        eo_cov = getattr(eo, "cov", None)
    cov6 = np.zeros((6, 6)) if eo_cov is None else np.asarray(eo_cov, dtype=np.float64).reshape(6, 6)
    cov6 = np.where(np.isfinite(cov6), cov6, 0.0)
    tick = progress or (lambda i, n: None)

    n = len(cr)
    status = np.full(n, "outside_photo", dtype=object)
    enh = np.full((n, 3), np.nan)
    n_iter = np.zeros(n, dtype=np.int64)
    inside = np.asarray(camera.contains(cr)) & np.isfinite(cr).all(axis=1)
    idx = np.flatnonzero(inside)
    c = params[:3]
    d = ray_directions(camera, params, cr[idx]) if idx.size else np.zeros((0, 3))
    if method == "exact":
        t, code = _first_hit(surface, c, d, tol_m)
    else:
        t, code, it = _iterate(surface, c, d, tol_m, max_iter, start)
        n_iter[idx] = it
        ok = code == 0
        if ok.any():   # is the converged point the first thing the ray meets?
            t_first, _ = _first_hit(surface, c, d[ok], tol_m, t_max=t[ok] * 1.0)
            hidden = np.isfinite(t_first) & (
                (t[ok] - t_first) * np.linalg.norm(d[ok], axis=1) > max(10 * tol_m, surface.resolution_m))
            sub = np.flatnonzero(ok)[hidden]
            code[sub] = 5
    tick(1, 2)
    names = np.array(["ok", "", "no_intersection", "outside_surface", "not_converged", "occluded"],
                     dtype=object)
    status[idx] = names[code]
    good = idx[code == 0]
    enh[good] = c + t[code == 0, None] * d[code == 0]

    cov = np.full((n, 3, 3), np.nan)
    if good.size:
        cov[good] = _propagate(camera, params, cr[good], enh[good], surface, cov6, image_sd_px)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    tick(2, 2)
    counts = {s: int((status == s).sum()) for s in STATUSES}
    log.info("monoplot (%s, %s): %s", method, surface.interpolator,
             ", ".join(f"{k} {v}" for k, v in counts.items() if v))
    return MonoplotResult(enh, sd, cov, status.astype(str), n_iter, method, surface.interpolator)


def _plane_hit(camera: Camera, params: np.ndarray, cr: np.ndarray, hit: np.ndarray,
               normal: np.ndarray, dh: np.ndarray) -> np.ndarray:
    """Intersection of rays with the tangent planes ``normal . (X - hit - dh e_z) = 0``."""
    d = ray_directions(camera, params, cr)
    c = params[:3]
    t = np.einsum("ij,ij->i", normal, hit + np.column_stack([0 * dh, 0 * dh, dh]) - c) \
        / np.einsum("ij,ij->i", normal, d)
    return c + t[:, None] * d


def _propagate(camera: Camera, params: np.ndarray, cr: np.ndarray, hit: np.ndarray, surface: _Surface,
               cov6: np.ndarray, image_sd_px: float) -> np.ndarray:
    """(N, 3, 3) covariance of the hits from the EO covariance, pixel sd and surface sd."""
    g = surface.gradient(hit[:, 0], hit[:, 1])
    normal = np.column_stack([-g, np.ones(len(g))])
    steps = np.array([1e-3, 1e-3, 1e-3, 1e-7, 1e-7, 1e-7, 1e-3, 1e-3, 1e-3])
    jac = np.empty((len(cr), 3, 9))
    zero = np.zeros(len(cr))
    for k, h in enumerate(steps):
        out = []
        for sgn in (1.0, -1.0):
            p, c, dh = params.copy(), cr.copy(), zero.copy()
            if k < 6:
                p[k] += sgn * h
            elif k < 8:
                c[:, k - 6] += sgn * h
            else:
                dh = dh + sgn * h
            out.append(_plane_hit(camera, p, c, hit, normal, dh))
        jac[:, :, k] = (out[0] - out[1]) / (2 * h)
    sigma = np.zeros((9, 9))
    sigma[:6, :6] = cov6
    sigma[6, 6] = sigma[7, 7] = image_sd_px ** 2
    sigma[8, 8] = surface.sd_m ** 2
    return jac @ sigma @ np.swapaxes(jac, 1, 2)
