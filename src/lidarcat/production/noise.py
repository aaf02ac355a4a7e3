"""Noise (ASPRS class 7) and height above ground of LiDAR points.

Statistical outliers (as PDAL ``filters.outlier``, method ``statistical``)
--------------------------------------------------------------------------
For each point :math:`p_i` let :math:`\\bar d_i` be the mean 3-D distance to its
``mean_k`` nearest neighbours (itself excluded).  Over all points these means
have a mean :math:`\\mu` and a standard deviation :math:`\\sigma`; a point is
noise when

.. math:: \\bar d_i > \\mu + m\\,\\sigma

with the ``multiplier`` :math:`m`.  PDAL's defaults are ``mean_k = 8`` and
``multiplier = 2``; both are kept here.  Birds, multipath echoes far below the
ground and returns from dust are isolated and fail this test; points of a
surface, however sparse, have neighbours at about the point spacing.  One
k-d tree query for all points (:class:`scipy.spatial.cKDTree`): no loop.

A bare threshold on :math:`\\mu + m\\sigma` also flags the points of a sparse
edge of a dense cloud; the test therefore only judges points whose mean
distance is also more than ``min_distance_m`` (2 m): a point within 2 m of its
neighbours on average is part of something.

Height above ground (as PDAL ``filters.hag_delaunay``)
-------------------------------------------------------
The ground points form a TIN (Delaunay triangulation in plan); the height
above ground of any point is its height less the TIN's at its plan position
(barycentric interpolation, :func:`lidarcat.geometry.tin.find_simplex`).  A
point outside the ground's convex hull takes the height of the nearest ground
point.  Ground points get 0 by construction (they are the TIN's vertices).
"""

from __future__ import annotations

import numpy as np

from ..geometry.tin import barycentric, find_simplex

__all__ = ["statistical_outliers", "height_above_ground", "NOISE_CLASS"]

#: ASPRS class code of low or high noise points (LAS 1.4 "low point (noise)")
NOISE_CLASS = 7


def statistical_outliers(xyz: np.ndarray, mean_k: int = 8, multiplier: float = 2.0,
                         min_distance_m: float = 2.0) -> np.ndarray:
    """Noise mask by the statistical outlier test of the module docstring.

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
        E, N, h, metres.
    mean_k : int
        Neighbours whose mean distance is tested.
    multiplier : float
        Standard deviations above the mean of the mean distances.
    min_distance_m : float
        A point whose mean distance is within this is never noise, metres.

    Returns
    -------
    ndarray of bool, shape (N,)
        True for noise.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = np.column_stack([rng.uniform(0, 50, (5000, 2)), rng.normal(0, 0.05, 5000)])
    >>> pts[:3, 2] = [-30.0, 45.0, 80.0]          # two birds and a multipath echo
    >>> np.flatnonzero(statistical_outliers(pts)).tolist()
    [0, 1, 2]
    """
    from scipy.spatial import cKDTree

    if mean_k < 1:
        raise ValueError(f"mean_k must be at least 1, got {mean_k}")
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    if n <= mean_k:
        return np.zeros(n, dtype=bool)
    local = xyz - xyz.min(axis=0)
    d, _ = cKDTree(local).query(local, k=mean_k + 1)
    mean_d = d[:, 1:].mean(axis=1)
    limit = mean_d.mean() + multiplier * mean_d.std()
    return (mean_d > limit) & (mean_d > min_distance_m)


def height_above_ground(xyz: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """Height of each point above the TIN of the *ground* points, metres (see the module docstring).

    Parameters
    ----------
    xyz : ndarray, shape (N, 3)
    ground : ndarray of bool, shape (N,)

    Returns
    -------
    ndarray of float64, shape (N,)
        Height above ground, metres; NaN for every point when there are fewer
        than three ground points.

    Examples
    --------
    >>> g = np.array([[0, 0, 10.0], [10, 0, 11.0], [0, 10, 12.0], [10, 10, 13.0], [5, 5, 20.0]])
    >>> height_above_ground(g, np.array([True, True, True, True, False])).round(3).tolist()
    [0.0, 0.0, 0.0, 0.0, 8.5]
    """
    from scipy.spatial import Delaunay, QhullError, cKDTree

    xyz = np.asarray(xyz, dtype=np.float64)
    ground = np.asarray(ground, dtype=bool)
    if ground.shape != (len(xyz),):
        raise ValueError(f"ground has shape {ground.shape}, expected ({len(xyz)},)")
    out = np.full(len(xyz), np.nan)
    gi = np.flatnonzero(ground)
    if len(gi) < 3:
        return out
    origin = xyz[gi].min(axis=0)
    g = xyz[gi] - origin
    q = xyz - origin
    zt = np.full(len(xyz), np.nan)
    try:
        tri = Delaunay(g[:, :2])
    except QhullError:
        tri = None
    if tri is not None:
        s = find_simplex(tri, q[:, :2])
        ok = s >= 0
        simp = tri.simplices[s[ok]]
        zt[ok] = np.einsum("ij,ij->i", barycentric(g[simp, :2], q[ok, :2]), g[simp, 2])
    miss = ~np.isfinite(zt)
    if miss.any():
        zt[miss] = g[cKDTree(g[:, :2]).query(q[miss, :2])[1], 2]
    out = q[:, 2] - zt
    out[gi] = 0.0
    return out
