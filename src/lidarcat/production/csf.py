"""Cloth simulation filter (CSF, Zhang et al. 2016): ground by a cloth dropped on the inverted points.

Turn the point cloud upside down (:math:`z' = -z`) and let a cloth of particles
on a regular grid (``cloth_resolution_m``) fall onto it under gravity.  The
cloth rests on the inverted terrain, which is now the *top* of the cloth's
obstacles, and bridges over the pits that objects leave (a building is a hole
in the inverted cloud); where it rests, it is the terrain.

Each particle :math:`i` carries a height :math:`Z_i` (inverted), its previous
height and a flag *movable*.  One time step of the simulation (Verlet
integration with damping :math:`\\delta = 0.01`, gravity :math:`g = 0.2`, the
values of Zhang et al.'s reference code):

.. math:: Z_i \\leftarrow Z_i + (1 - \\delta)(Z_i - Z_i^{prev}) - g\\,\\Delta t^2

then collision: a particle that reaches the *intersection height* :math:`H_i`
(the highest inverted point, i.e. the lowest real point, in its cell; empty
cells take the nearest cell's value) is set to :math:`H_i` and stops (immovable).
Internal forces: each particle is pulled toward its four neighbours, ``rigidness``
times per step; between two movable particles each moves half of their height
difference, a movable particle next to an immovable one moves the whole of it.
The updates of one pass are applied to all particles at once (Jacobi: the mean
of the moves that the neighbours ask for), so each pass is a few numpy array
operations over the grid: no per-particle loop.  The simulation stops when the
largest move of a step is below ``0.005`` m or after ``iterations`` steps.

Stiffness comes from the constraints alone, and a Jacobi pass reaches one
particle further per pass: over a building 50 cells wide the cloth sags into the
inverted roof.  The simulation therefore runs coarse to fine (a pyramid of up to
three levels, each halving the resolution; a coarse particle's intersection
height is the highest of its block): the coarsest cloth runs ``iterations``
steps, and each finer cloth starts from the coarser one (bilinear, never below
its own intersection heights) and runs 10 steps, enough to settle onto the
detail and too few to fall through a roof.

Slope post-processing (``slope_smooth``, as the reference code's
``bSloopSmooth``): a movable particle next to an immovable one whose intersection
height differs from that neighbour's by less than ``0.3`` m is set onto its own
intersection height and made immovable; repeated until nothing changes.  This
lets the cloth follow steep slopes that its stiffness would otherwise bridge.

With ``adaptive`` (the default) the cloth falls on the lowest points less their
trend plane (:func:`trend_plane`, least squares through the lower half of the
cells, as SMRF's opening uses it): a stiff cloth bridges a 35 deg slope, but not
the same slope levelled.  The plane is added back to the cloth.

A point is ground when its real height is within ``class_threshold_m`` of the
cloth (bilinear at the point).  Only the points of the *candidates* mask (last
returns, low outliers set aside by the caller) shape the cloth and can be
ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["CSFParameters", "csf_ground", "cloth_surface", "trend_plane"]

_DAMPING = 0.01
_GRAVITY = 0.2
_CONVERGED_M = 0.005
_SLOPE_SMOOTH_M = 0.3
_PYRAMID_LEVELS = 3
_FINE_ITERATIONS = 10


@dataclass(frozen=True)
class CSFParameters:
    """Parameters of the cloth simulation filter (the reference code's names and defaults).

    Attributes
    ----------
    cloth_resolution_m : float
        Spacing of the cloth's particles, metres.  With ``adaptive`` it grows
        to the points' mean spacing on sparse data (the cloth must not be finer
        than the points that hold it).
    rigidness : int
        Constraint passes per time step: 3 for flat terrain (stiff cloth),
        2 for relief, 1 for steep slopes.
    time_step : float
        :math:`\\Delta t` of the integration.
    class_threshold_m : float
        Largest distance of a ground point from the cloth, metres.
    iterations : int
        Largest number of time steps.
    slope_smooth : bool
        The slope post-processing of the module docstring.
    adaptive : bool
        Grow ``cloth_resolution_m`` to the mean point spacing, and drop the cloth
        on the points less their trend plane.
    """

    cloth_resolution_m: float = 1.0
    rigidness: int = 2
    time_step: float = 0.65
    class_threshold_m: float = 0.5
    iterations: int = 500
    slope_smooth: bool = True
    adaptive: bool = True

    def __post_init__(self) -> None:
        for name in ("cloth_resolution_m", "time_step", "class_threshold_m"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if self.rigidness not in (1, 2, 3):
            raise ValueError(f"rigidness must be 1, 2 or 3, got {self.rigidness!r}")
        if self.iterations < 1:
            raise ValueError("iterations must be at least 1")


def _nearest_fill(grid: np.ndarray) -> np.ndarray:
    """NaN cells take the value of the nearest valued cell."""
    from scipy.ndimage import distance_transform_edt

    bad = ~np.isfinite(grid)
    if not bad.any() or bad.all():
        return grid
    idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
    return grid[tuple(idx)]


def _neighbour_moves(z: np.ndarray, movable: np.ndarray) -> np.ndarray:
    """Mean of the moves the four neighbours ask of each particle (see the module docstring)."""
    total = np.zeros_like(z)
    count = np.zeros_like(z)
    for axis in (0, 1):
        n = z.shape[axis]
        a = [slice(None)] * 2
        b = [slice(None)] * 2
        a[axis] = slice(0, n - 1)
        b[axis] = slice(1, n)
        ta, tb = tuple(a), tuple(b)
        d = z[tb] - z[ta]                       # pull of the upper/right neighbour on the lower/left one
        ma, mb = movable[ta], movable[tb]
        share_a = np.where(mb, 0.5, 1.0) * ma   # both movable: half each; the other fixed: all of it
        share_b = np.where(ma, 0.5, 1.0) * mb
        total[ta] += share_a * d
        count[ta] += ma
        total[tb] -= share_b * d
        count[tb] += mb
    return np.where(count > 0, total / np.maximum(count, 1), 0.0)


def _simulate(hv: np.ndarray, z: np.ndarray, params: CSFParameters, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Cloth heights (inverted) and the movable mask after at most *iterations* time steps from *z*."""
    prev = z.copy()
    movable = z > hv
    z = np.where(movable, z, hv)
    step = _GRAVITY * params.time_step ** 2
    for _ in range(iterations):
        new = np.where(movable, z + (1.0 - _DAMPING) * (z - prev) - step, z)
        hit = movable & (new <= hv)
        new[hit] = hv[hit]
        movable &= ~hit
        for _ in range(params.rigidness):
            new = new + _neighbour_moves(new, movable) * movable
            low = movable & (new <= hv)          # a neighbour must not pull a particle through the terrain
            new[low] = hv[low]
            movable &= ~low
        moved = float(np.max(np.abs(new - z))) if movable.any() else 0.0
        prev, z = z, new
        if moved < _CONVERGED_M or not movable.any():
            break
    return z, movable


def cloth_surface(heights: np.ndarray, params: CSFParameters | None = None) -> np.ndarray:
    """The cloth (real heights, metres) over a grid of the lowest point heights per cell.

    Parameters
    ----------
    heights : ndarray, shape (rows, cols)
        Lowest real height of the points of each cell, metres; NaN where empty.
    params : CSFParameters, optional

    Returns
    -------
    ndarray, shape (rows, cols)
        Height of the cloth at each particle, metres (real, not inverted).
    """
    from scipy.ndimage import maximum_filter, zoom

    params = params or CSFParameters()
    hv = _nearest_fill(-np.asarray(heights, dtype=np.float64))  # intersection heights, inverted
    if not np.isfinite(hv).any():
        return np.full(hv.shape, np.nan)
    # coarse to fine: the cloth of a grid 2**L times coarser (the highest inverted point of each block)
    # starts the next finer one, so a particle never has to be held up across more than a few cells
    levels = max(0, min(_PYRAMID_LEVELS, int(math.floor(math.log2(max(1, min(hv.shape) // 4))))))
    z = None
    for lev in range(levels, -1, -1):
        f = 2 ** lev
        h = maximum_filter(hv, size=f, mode="nearest", origin=0)[::f, ::f] if f > 1 else hv
        if z is None:
            z = np.full(h.shape, float(np.max(h)) + 1.0)
        else:
            z = zoom(z, (h.shape[0] / z.shape[0], h.shape[1] / z.shape[1]), order=1, mode="nearest")
            z = np.maximum(z, h)
        z, movable = _simulate(h, z, params, params.iterations if lev == levels else _FINE_ITERATIONS)
    assert z is not None
    if params.slope_smooth:
        z = z.copy()
        for _ in range(sum(hv.shape)):
            fixed = ~movable
            grow = np.zeros_like(movable)
            for axis in (0, 1):
                for shift in (1, -1):
                    nb_fixed = np.roll(fixed, shift, axis=axis)
                    nb_hv = np.roll(hv, shift, axis=axis)
                    edge = [slice(None)] * 2
                    edge[axis] = slice(0, 1) if shift == 1 else slice(-1, None)
                    nb_fixed[tuple(edge)] = False    # no wrap-around
                    grow |= movable & nb_fixed & (np.abs(hv - nb_hv) < _SLOPE_SMOOTH_M)
            if not grow.any():
                break
            z[grow] = hv[grow]
            movable &= ~grow
    return -z


def trend_plane(surface: np.ndarray, c: float, passes: int = 3) -> np.ndarray:
    """Least-squares plane through the lower half of the valued cells of *surface*, iterated.

    Parameters
    ----------
    surface : ndarray, shape (rows, cols)
        Heights, metres; NaN cells are left out of the fit.
    c : float
        Cell size, metres.
    passes : int
        Fits; each after the first uses the cells at or below the median residual of the last.

    Returns
    -------
    ndarray, shape (rows, cols)
        The plane's height at every cell, metres.
    """
    nr, nc = surface.shape
    rr, cc = np.mgrid[0:nr, 0:nc]
    a = np.column_stack([np.ones(nr * nc), (cc.ravel() - nc / 2) * c, (rr.ravel() - nr / 2) * c])
    z = surface.ravel()
    use = np.isfinite(z)
    coef = np.zeros(3)
    for _ in range(passes):
        coef = np.linalg.lstsq(a[use], z[use], rcond=None)[0]
        res = z - a @ coef
        use = np.isfinite(z) & (res <= np.median(res[use]))
    return (a @ coef).reshape(nr, nc)


def csf_ground(xyz: np.ndarray, candidates: np.ndarray | None = None,
               params: CSFParameters | None = None) -> np.ndarray:
    """Ground mask of points by the cloth simulation filter (see the module docstring).

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
        E, N, h in metres.
    candidates : ndarray of bool, shape (N,), optional
        Points that may be ground and hold the cloth (default all).
    params : CSFParameters, optional

    Returns
    -------
    ndarray of bool, shape (N,)

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> xy = rng.uniform(0, 100, (20000, 2))
    >>> h = 0.05 * xy[:, 0] + np.where((abs(xy[:, 0] - 50) < 10) & (abs(xy[:, 1] - 50) < 10), 6.0, 0.0)
    >>> g = csf_ground(np.column_stack([xy, h]))
    >>> roof = h > 0.05 * xy[:, 0] + 1
    >>> float(g[roof].mean()) < 0.05, float(g[~roof].mean()) > 0.99   # a few roof edges drape
    (True, True)
    """
    from scipy.ndimage import map_coordinates

    params = params or CSFParameters()
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    cand = np.ones(n, dtype=bool) if candidates is None else np.asarray(candidates, dtype=bool).copy()
    ground = np.zeros(n, dtype=bool)
    if not cand.any():
        return ground
    res = params.cloth_resolution_m
    if params.adaptive:
        xy = xyz[cand, :2]
        k = np.floor((xy - xy.min(axis=0)) / 5.0).astype(np.int64)
        occupied = len(np.unique(k[:, 0] * (int(k[:, 1].max()) + 1) + k[:, 1]))
        res = max(res, 0.5 * round(2.0 * math.sqrt(occupied * 25.0 / len(xy))))
    x0 = math.floor(xyz[:, 0].min() / res) * res - res
    y0 = math.floor(xyz[:, 1].min() / res) * res - res
    col = np.rint((xyz[:, 0] - x0) / res).astype(np.int64)
    row = np.rint((xyz[:, 1] - y0) / res).astype(np.int64)
    nr, nc = int(row.max()) + 2, int(col.max()) + 2
    zmin = np.full(nr * nc, np.inf)
    np.minimum.at(zmin, (row * nc + col)[cand], xyz[cand, 2])
    zmin = np.where(np.isfinite(zmin), zmin, np.nan).reshape(nr, nc)
    trend = np.zeros_like(zmin)
    if params.adaptive and np.isfinite(zmin).sum() >= 3:
        trend = trend_plane(np.where(np.isfinite(zmin), zmin, np.nan), res)
    cloth = cloth_surface(zmin - trend, params) + trend
    zc = map_coordinates(cloth, np.vstack([(xyz[:, 1] - y0) / res, (xyz[:, 0] - x0) / res]), order=1,
                         mode="nearest")
    return cand & (np.abs(xyz[:, 2] - zc) <= params.class_threshold_m)
