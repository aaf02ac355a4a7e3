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
query points at once, each starting in a triangle of its nearest vertex (a
k-d tree query), or, for a triangulation built to be queried many times
(``start_grid=True``), in the triangle whose centroid is nearest to the centre
of the point's cell in a grid of one mean point spacing
(:math:`\sqrt{\text{hull area} / N}`); either way a walk is a few steps.  Points on a degenerate triangle,
still walking after ``max_steps``, or whose nearest vertex is a duplicate
point Qhull left out of the triangulation, are located among the triangles of
their 3, 12 and 96 nearest centroids.  The triangles' :math:`A^{-1}` are
computed for the triangles a step visits, or once for all triangles when the
query points are many (at least a quarter of the triangles; the same numbers
either way).

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
    start_grid : bool
        For a triangulation that locates many batches of points (a surface):
        build once a grid of one mean point spacing holding the triangle of
        the centroid nearest to each cell centre, and start each walk there
        (no k-d tree query per point), with the transforms of every triangle.
        Default: start at a triangle of the point's nearest vertex.

    Attributes
    ----------
    triangulation : scipy.spatial.Delaunay

    Examples
    --------
    >>> from scipy.spatial import Delaunay
    >>> loc = TinLocator(Delaunay(np.array([[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]])))
    >>> s, w = loc.locate(np.array([[0.5, 0.5], [3.0, 3.0]]))
    >>> bool(s[0] >= 0), int(s[1]), round(float(w[0].sum()), 12)
    (True, -1, 1.0)
    """

    def __init__(self, triangulation: Any, *, start_grid: bool = False) -> None:
        from scipy.spatial import cKDTree

        self.triangulation = triangulation
        self._points = np.asarray(triangulation.points, dtype=np.float64)
        self._simplices = np.asarray(triangulation.simplices)
        self._inv_all: np.ndarray | None = None
        self._tree: Any = None
        self._ctree: Any = None
        self._area: float | None = None
        self._guess: np.ndarray | None = None
        if start_grid:
            # the nearest centroid to each cell centre of a grid of one point spacing (int32, about one
            # cell per point): the walks start there, without a k-d tree query per point
            self._inv_all, self._v3_all = self._transforms()
            self._ctree = cKDTree(self._points[self._simplices].mean(axis=1))
            cell = self.resolution
            lo, hi = self._points.min(axis=0), self._points.max(axis=0)
            cols, rows = int((hi[0] - lo[0]) / cell) + 1, int((hi[1] - lo[1]) / cell) + 1
            ce, cn = np.meshgrid(lo[0] + (np.arange(cols) + 0.5) * cell, lo[1] + (np.arange(rows) + 0.5) * cell)
            _, guess = self._ctree.query(np.column_stack([ce.ravel(), cn.ravel()]))
            self._guess = guess.astype(np.int32)
            self._guess_grid = (float(lo[0]), float(lo[1]), cell, cols, rows)

    def _transforms(self, t: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """:math:`A^{-1}` (m, 2, 2) and :math:`v_3` (m, 2) of triangles *t* (all: None); NaN when degenerate."""
        v = self._points[self._simplices if t is None else self._simplices[t]]   # (m, 3, 2)
        a = np.stack([v[:, 0] - v[:, 2], v[:, 1] - v[:, 2]], axis=2)   # columns v1-v3, v2-v3
        det = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
        keep = np.abs(det) > 1e-12
        inv = np.zeros_like(a)
        inv[keep, 0, 0] = a[keep, 1, 1] / det[keep]
        inv[keep, 1, 1] = a[keep, 0, 0] / det[keep]
        inv[keep, 0, 1] = -a[keep, 0, 1] / det[keep]
        inv[keep, 1, 0] = -a[keep, 1, 0] / det[keep]
        inv[~keep] = np.nan                                            # degenerate: never contains
        return inv, v[:, 2].copy()

    def _step_transforms(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Transforms of triangles *t*: from the table of all of them once it pays (bitwise the same)."""
        if self._inv_all is not None:
            return self._inv_all[t], self._v3_all[t]
        return self._transforms(t)

    @property
    def area(self) -> float:
        """Area of the triangulation (its convex hull), squared plan units."""
        if self._area is None:
            v = self._points[self._simplices]
            det = (v[:, 0, 0] - v[:, 2, 0]) * (v[:, 1, 1] - v[:, 2, 1]) - \
                  (v[:, 1, 0] - v[:, 2, 0]) * (v[:, 0, 1] - v[:, 2, 1])
            self._area = float(0.5 * np.abs(det).sum())
        return self._area

    @property
    def resolution(self) -> float:
        """Mean point spacing :math:`\\sqrt{\\text{area} / N}`, plan units."""
        return float(math.sqrt(self.area / len(self._points)))

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
        from scipy.spatial import cKDTree

        q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
        found = np.full(len(q), -1, dtype=np.int64)
        w = np.zeros((len(q), 3))
        idx = np.flatnonzero(np.isfinite(q).all(axis=1))
        if self._inv_all is None and len(idx) >= len(self._simplices) // 4:
            self._inv_all, self._v3_all = self._transforms()   # many points: one table of every triangle
        if self._guess is not None:
            x0, y0, cell, cols, rows = self._guess_grid
            c = np.clip(((q[idx, 0] - x0) / cell).astype(np.int64), 0, cols - 1)
            r = np.clip(((q[idx, 1] - y0) / cell).astype(np.int64), 0, rows - 1)
            tri = self._guess[r * cols + c].astype(np.int64)
        else:
            if self._tree is None:
                self._tree = cKDTree(self._points)
            _, v = self._tree.query(q[idx])
            tri = self.triangulation.vertex_to_simplex[v].astype(np.int64)
        nostart = tri < 0                                 # a duplicate point Qhull left out
        left = [idx[nostart]]
        idx, tri = idx[~nostart], tri[~nostart]
        nb = self.triangulation.neighbors
        for _ in range(max_steps):
            if idx.size == 0:
                break
            inv, v3 = self._step_transforms(tri)
            b = np.einsum("mij,mj->mi", inv, q[idx] - v3)
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
        from scipy.spatial import cKDTree

        found = np.full(len(q), -1, dtype=np.int64)
        w = np.zeros((len(q), 3))
        todo = np.flatnonzero(np.isfinite(q).all(axis=1))
        if todo.size and self._ctree is None:
            self._ctree = cKDTree(self._points[self._simplices].mean(axis=1))
        for k in (3, 12, 96):
            if todo.size == 0:
                break
            k = min(k, len(self._simplices))
            _, cand = self._ctree.query(q[todo], k=k)
            cand = cand.reshape(len(todo), k)
            inv, v3 = self._step_transforms(cand.ravel())
            rel = q[todo, None, :] - v3.reshape(len(todo), k, 2)            # (m, k, 2)
            b = np.einsum("mkij,mkj->mki", inv.reshape(len(todo), k, 2, 2), rel)   # (m, k, 2)
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
