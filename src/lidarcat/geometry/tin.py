r"""Point location in a plane Delaunay triangulation (a TIN): one vectorised visibility walk.

Barycentric coordinates
-----------------------
A plan point :math:`q` in the triangle :math:`(v_1, v_2, v_3)` is

.. math:: q = \lambda_1 v_1 + \lambda_2 v_2 + \lambda_3 v_3, \qquad
          \lambda_1 + \lambda_2 + \lambda_3 = 1,

so with :math:`A = [v_1 - v_3,\; v_2 - v_3]` (2 x 2, columns)

.. math:: (\lambda_1, \lambda_2)^T = A^{-1} (q - v_3), \qquad \lambda_3 = 1 - \lambda_1 - \lambda_2 .

:math:`q` is inside (or on the border of) the triangle when every
:math:`\lambda_i \ge 0` (here :math:`\ge -10^{-9}`), and the height of a TIN
there is :math:`h(q) = \sum_i \lambda_i h_i`.  :class:`TinLocator` keeps
:math:`A^{-1}` and :math:`v_3` of every triangle (a triangle with
:math:`|\det A| \le 10^{-12}` is degenerate: it never contains a point);
:func:`barycentric` computes the same coordinates from the corners directly
(edges from the first corner), for triangles given by their corners.

The walk
--------
A negative :math:`\lambda_i` means :math:`q` lies beyond the edge opposite
vertex :math:`i`; the walk steps to the neighbour across the edge of the most
negative :math:`\lambda_i` and repeats until none is negative (found), or the
edge is on the convex hull (no neighbour: outside, -1).  On a Delaunay
triangulation this walk never cycles (Edelsbrunner 1990).  It runs for all
query points at once, each starting in the triangle whose centroid is nearest
to the centre of the query's cell in a grid of one mean point spacing
(:math:`\sqrt{\text{hull area} / N}`), so a walk is a few steps.  Points on a
degenerate triangle, or still walking after ``max_steps``, are located among
the triangles of their 3, 12 and 96 nearest centroids.

``scipy.spatial.Delaunay.find_simplex`` gives the same triangles but builds
LAPACK-checked transforms of every triangle first and walks from the previous
point's triangle: orders of magnitude slower on large triangulations and
points in scan order.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["TinLocator", "barycentric", "find_simplex"]

#: a barycentric coordinate down to this is still inside (points on an edge belong to a triangle)
INSIDE_TOL = -1e-9


def barycentric(tri_xy: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Barycentric coordinates of plan points in triangles given by their corners.

    Parameters
    ----------
    tri_xy : ndarray, shape (m, 3, 2)
        Corners of one triangle per point (any plan units, e.g. metres or cells).
    q : ndarray, shape (m, 2)
        The points, same units.

    Returns
    -------
    ndarray, shape (m, 3)
        :math:`(\\lambda_1, \\lambda_2, \\lambda_3)` of each point in its
        triangle (dimensionless, summing to 1); NaN for a zero-area triangle.

    Examples
    --------
    >>> barycentric(np.array([[[0.0, 0.0], [2.0, 0.0], [0.0, 2.0]]]), np.array([[0.5, 1.0]])).tolist()
    [[0.25, 0.25, 0.5]]
    """
    a = tri_xy[:, 0]
    e1 = tri_xy[:, 1] - a
    e2 = tri_xy[:, 2] - a
    r = q - a
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = (r[:, 0] * e2[:, 1] - r[:, 1] * e2[:, 0]) / det
        v = (e1[:, 0] * r[:, 1] - e1[:, 1] * r[:, 0]) / det
    return np.column_stack([1.0 - u - v, u, v])


class TinLocator:
    """Locate plan points in a Delaunay triangulation (see the module docstring).

    Parameters
    ----------
    triangulation : scipy.spatial.Delaunay
        A plane triangulation (``points`` (N, 2), ``simplices`` (T, 3),
        ``neighbors`` (T, 3)).  Coordinates should be local (a few km at
        most): UTM-size numbers lose digits in the inverses.

    Attributes
    ----------
    triangulation : scipy.spatial.Delaunay
    area : float
        Area of the triangulation (its convex hull), squared plan units.
    resolution : float
        Mean point spacing :math:`\\sqrt{\\text{area} / N}`, plan units.

    Examples
    --------
    >>> from scipy.spatial import Delaunay
    >>> loc = TinLocator(Delaunay(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])))
    >>> s, w = loc.locate(np.array([[0.5, 0.5], [3.0, 3.0]]))
    >>> bool(s[0] >= 0), int(s[1]), round(float(w[0].sum()), 12)
    (True, -1, 1.0)
    """

    def __init__(self, triangulation: Any) -> None:
        from scipy.spatial import cKDTree

        self.triangulation = triangulation
        pts = np.asarray(triangulation.points, dtype=np.float64)
        v = pts[triangulation.simplices]                               # (T, 3, 2)
        a = np.stack([v[:, 0] - v[:, 2], v[:, 1] - v[:, 2]], axis=2)   # columns v1-v3, v2-v3
        det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        keep = np.abs(det) > 1e-12
        inv = np.zeros_like(a)
        inv[keep, 0, 0] = a[keep, 1, 1] / det[keep]
        inv[keep, 1, 1] = a[keep, 0, 0] / det[keep]
        inv[keep, 0, 1] = -a[keep, 0, 1] / det[keep]
        inv[keep, 1, 0] = -a[keep, 1, 0] / det[keep]
        inv[~keep] = np.nan                                            # degenerate: never contains
        self._inv = inv
        self._v3 = v[:, 2].copy()
        self._ctree = cKDTree(v.mean(axis=1))
        self.area = float(0.5 * np.abs(det).sum())
        self.resolution = float(math.sqrt(self.area / len(pts))) if self.area > 0 else 1.0
        # the walk's starting triangles: the nearest centroid to each cell centre of a grid of one
        # point spacing (int32, about one cell per point)
        cell = self.resolution
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        cols, rows = int((hi[0] - lo[0]) / cell) + 1, int((hi[1] - lo[1]) / cell) + 1
        ce, cn = np.meshgrid(lo[0] + (np.arange(cols) + 0.5) * cell, lo[1] + (np.arange(rows) + 0.5) * cell)
        _, guess = self._ctree.query(np.column_stack([ce.ravel(), cn.ravel()]))
        self._guess = guess.astype(np.int32)
        self._guess_grid = (float(lo[0]), float(lo[1]), cell, cols, rows)

    def locate(self, q: np.ndarray, max_steps: int = 10_000) -> tuple[np.ndarray, np.ndarray]:
        """Triangle holding each plan point and the point's barycentric coordinates in it.

        Parameters
        ----------
        q : ndarray, shape (m, 2)
            Plan points in the triangulation's coordinates; non-finite rows are outside.
        max_steps : int
            Steps of the walk before the remaining points are located among
            their nearest triangles.

        Returns
        -------
        simplex : ndarray, shape (m,), int64
            Index into ``triangulation.simplices``; -1 outside the convex hull.
        weights : ndarray, shape (m, 3)
            :math:`\\lambda` of the point for the triangle's vertices in
            ``simplices`` order (zeros outside).
        """
        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        found = np.full(len(q), -1, dtype=np.int64)
        w = np.zeros((len(q), 3))
        idx = np.flatnonzero(np.isfinite(q).all(axis=1))
        x0, y0, cell, cols, rows = self._guess_grid
        c = np.clip(((q[idx, 0] - x0) / cell).astype(np.int64), 0, cols - 1)
        r = np.clip(((q[idx, 1] - y0) / cell).astype(np.int64), 0, rows - 1)
        tri = self._guess[r * cols + c].astype(np.int64)
        nb = self.triangulation.neighbors
        left = []
        for _ in range(max_steps):
            if idx.size == 0:
                break
            rel = q[idx] - self._v3[tri]
            b = np.einsum("mij,mj->mi", self._inv[tri], rel)
            bb = np.column_stack([b, 1.0 - b.sum(axis=1)])
            j = np.argmin(bb, axis=1)
            low = bb[np.arange(len(idx)), j]
            bad = ~np.isfinite(low)
            inside = low >= INSIDE_TOL
            found[idx[inside]] = tri[inside]
            w[idx[inside]] = bb[inside]
            nxt = nb[tri, j]
            move = ~inside & ~bad & (nxt >= 0)            # nxt < 0: across the hull, outside
            left.append(idx[bad])
            idx, tri = idx[move], nxt[move]
        left.append(idx)
        rest = np.concatenate(left)
        if rest.size:
            f2, w2 = self._locate_among_nearest(q[rest])
            found[rest], w[rest] = f2, w2
        return found, w

    def _locate_among_nearest(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`locate` by the triangles of the 3 (then 12, then 96) nearest centroids."""
        found = np.full(len(q), -1, dtype=np.int64)
        w = np.zeros((len(q), 3))
        todo = np.flatnonzero(np.isfinite(q).all(axis=1))
        for k in (3, 12, 96):
            if todo.size == 0:
                break
            k = min(k, len(self._inv))
            _, cand = self._ctree.query(q[todo], k=k)
            cand = cand.reshape(len(todo), k)
            rel = q[todo, None, :] - self._v3[cand]                         # (m, k, 2)
            b = np.einsum("mkij,mkj->mki", self._inv[cand], rel)           # (m, k, 2)
            b3 = 1.0 - b.sum(axis=2)
            inside = (b >= INSIDE_TOL).all(axis=2) & (b3 >= INSIDE_TOL)
            hit = inside.any(axis=1)
            j = np.argmax(inside, axis=1)
            rows = np.flatnonzero(hit)
            found[todo[rows]] = cand[rows, j[rows]]
            w[todo[rows], :2] = b[rows, j[rows]]
            w[todo[rows], 2] = b3[rows, j[rows]]
            todo = todo[~hit]
        return found, w


def find_simplex(triangulation: Any, q: np.ndarray) -> np.ndarray:
    """Triangle of *triangulation* holding each plan point of *q* (m, 2); -1 outside.

    The same as ``triangulation.find_simplex(q)`` (up to points on an edge,
    which belong to either triangle), by :meth:`TinLocator.locate`.

    Returns
    -------
    ndarray, shape (m,), int64
    """
    return TinLocator(triangulation).locate(q)[0]
