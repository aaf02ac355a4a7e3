"""Membership of points in a circle, a box or a polygon, and a cell grid for box candidates.

Membership tests are the same whatever the tiling: a point is in a circle when
``(x - e)**2 + (y - n)**2 <= r**2``, in a box when ``xmin <= x <= xmax`` and
``ymin <= y <= ymax`` (edges included), in a polygon by the even-odd rule.
The tests are the same whatever the tiling, so a query over tiles returns what one
test over all the points returns.  :class:`CellGrid` buckets the points of a tile held
in memory into square cells and returns the candidates of a box in file order.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["in_radius", "in_box", "in_polygon", "CellGrid"]


def in_radius(xy: np.ndarray, center_en: Sequence[float], radius_m: float) -> np.ndarray:
    """Mask of points within *radius_m* (edge included) of *center_en* in plan.

    >>> in_radius(np.array([[0.0, 0.0], [3.0, 4.0], [3.0, 4.1]]), (0.0, 0.0), 5.0).tolist()
    [True, True, False]
    """
    dx = xy[:, 0] - float(center_en[0])
    dy = xy[:, 1] - float(center_en[1])
    with np.errstate(over="ignore"):  # a centre far outside (1e308): inf, outside the circle
        return dx * dx + dy * dy <= float(radius_m) ** 2


def in_box(xy: np.ndarray, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
    """Mask of points with ``xmin <= x <= xmax`` and ``ymin <= y <= ymax``."""
    x, y = xy[:, 0], xy[:, 1]
    return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)


def in_polygon(xy: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Mask of points inside a simple polygon (even-odd rule, vectorised over points).

    Parameters
    ----------
    xy : ndarray, shape (N, 2+)
    vertices : ndarray, shape (M, 2)
        Polygon vertices in order; closing the ring is optional.

    >>> sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    >>> in_polygon(np.array([[1.0, 1.0], [3.0, 1.0]]), sq).tolist()
    [True, False]
    """
    v = np.asarray(vertices, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    inside = np.zeros(len(xy), dtype=bool)
    m = len(v)
    for i in range(m):
        x1, y1 = v[i]
        x2, y2 = v[(i + 1) % m]
        if y1 == y2:
            continue
        crosses = (y1 > y) != (y2 > y)
        if not crosses.any():
            continue
        xint = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (x < xint)
    return inside


class CellGrid:
    """Points of an in-memory tile bucketed into square cells, for fast box candidates.

    Candidates come back as sorted indices, so that selecting them keeps the
    file order (queries return exactly what a full scan returns).
    """

    def __init__(self, xyz: np.ndarray, points_per_cell: int = 64) -> None:
        x, y = xyz[:, 0], xyz[:, 1]
        self.x0, self.y0 = float(x.min()), float(y.min())
        w = max(float(x.max()) - self.x0, 1e-9)
        h = max(float(y.max()) - self.y0, 1e-9)
        self.cell = max(float(np.sqrt(w * h * points_per_cell / max(len(xyz), 1))), 0.5)
        self.nx = int(w // self.cell) + 1
        self.ny = int(h // self.cell) + 1
        cx, cy = self._cells(x, y)
        key = cy * self.nx + cx
        self.order = np.argsort(key, kind="stable")
        self.starts = np.concatenate([[0], np.cumsum(np.bincount(key, minlength=self.nx * self.ny))])

    def _cells(self, x: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
        cx = np.clip(np.floor((np.asarray(x, dtype=np.float64) - self.x0) / self.cell), 0, self.nx - 1)
        cy = np.clip(np.floor((np.asarray(y, dtype=np.float64) - self.y0) / self.cell), 0, self.ny - 1)
        return cx.astype(np.int64), cy.astype(np.int64)

    def candidates(self, xmin: float, ymin: float, xmax: float, ymax: float) -> np.ndarray:
        (cx0, cx1), (cy0, cy1) = (self._cells([xmin, xmax], [ymin, ymax]))
        segs = [self.order[self.starts[cy * self.nx + cx0]:self.starts[cy * self.nx + cx1 + 1]]
                for cy in range(int(cy0), int(cy1) + 1)]
        idx = np.concatenate(segs) if segs else np.empty(0, dtype=np.int64)
        idx.sort()
        return idx
