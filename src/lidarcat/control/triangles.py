r"""Delaunay triangles of a roof clip in plan, with the plane, slope and aspect of each (thesis 3.2.3-3.2.4).

**Delaunay triangles** of the clip in plan (``scipy.spatial.Delaunay``).
For each triangle, with :math:`x_0` its highest vertex and
:math:`u = (r, s, t)`, :math:`v = (m, n, p)` the edges to the two others,
the plane (eq. 25-31) is

.. math:: a = sp - tn,\quad b = -(rp - tm),\quad c = rn - sm,\quad
          d = -(a x_0 + b y_0 + c z_0)

and its slope against the horizontal plane :math:`n_H = (0, 0, 1)` (eq. 32)
is :math:`\cos\theta = |c| / \|(a, b, c)\|`.

**Slope window**: triangles outside ``[slope_min_deg, slope_max_deg]`` are
dropped (thesis 4-30 deg: flat chimney tops below, walls above).  The ``thesis`` grouping
(:mod:`lidarcat.control.segment`) uses these triangles; the other methods work on the points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ClipError

__all__ = ["triangle_planes", "triangle_slope_aspect", "delaunay_facets"]


def triangle_planes(xyz: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Plane ``(a, b, c, d)`` of every triangle by eq. 25-31 (normal up, not unit).

    Parameters
    ----------
    xyz : (N, 3) float
        Points (any origin).
    simplices : (T, 3) int
        Vertex indices of the triangles.

    Returns
    -------
    (T, 4) float
        ``a, b, c`` = cross product of the edges from the highest vertex
        (length = twice the triangle area), ``d = -(a x0 + b y0 + c z0)``.

    >>> xyz = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 1]])
    >>> (triangle_planes(xyz, np.array([[0, 1, 2]])).round(6) + 0.0).tolist()
    [[0.0, -1.0, 1.0, 0.0]]
    """
    tri = xyz[simplices]  # (T, 3, 3)
    top = np.argmax(tri[:, :, 2], axis=1)
    idx = np.arange(len(tri))
    p0 = tri[idx, top]
    p1 = tri[idx, (top + 1) % 3]
    p2 = tri[idx, (top + 2) % 3]
    r, s, t = (p1 - p0).T
    m, n, p = (p2 - p0).T
    a = s * p - t * n  # eq. 28
    b = -(r * p - t * m)  # eq. 29
    c = r * n - s * m  # eq. 30
    sign = np.where(c < 0, -1.0, 1.0)
    a, b, c = a * sign, b * sign, c * sign
    d = -(a * p0[:, 0] + b * p0[:, 1] + c * p0[:, 2])  # eq. 31
    return np.column_stack([a, b, c, d])


def triangle_slope_aspect(abc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slope (eq. 32, deg) and aspect (deg from North, clockwise) of normals (T, 3)."""
    abc = np.asarray(abc, dtype=np.float64)[:, :3]
    norm = np.linalg.norm(abc, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(abc[:, 2]) / norm
    slope = np.degrees(np.arccos(np.clip(np.nan_to_num(cos, nan=1.0), 0.0, 1.0)))
    aspect = np.degrees(np.arctan2(abc[:, 0], abc[:, 1])) % 360.0
    return slope, aspect


@dataclass(frozen=True, eq=False)
class _Facets:
    simplices: np.ndarray  # (T, 3)
    planes: np.ndarray  # (T, 4)
    slope_deg: np.ndarray
    aspect_deg: np.ndarray
    area_m2: np.ndarray
    keep: np.ndarray  # bool, passed edge-length test
    max_edge_m: float


def delaunay_facets(xyz: np.ndarray, max_edge_m: float | None = None) -> _Facets:
    """Delaunay triangulation in plan with per-triangle plane, slope, aspect, area.

    Raises
    ------
    ClipError
        Fewer than 3 points or all points collinear in plan (a ``ValueError``).
    """
    from scipy.spatial import Delaunay
    from scipy.spatial import QhullError

    xyz = np.asarray(xyz, dtype=np.float64)
    if len(xyz) < 3:
        raise ClipError(f"{len(xyz)} points: a triangulation needs at least 3")
    xy = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    try:
        tri = Delaunay(xy)
    except (QhullError, ValueError) as ex:
        raise ClipError("points are collinear or coincident in plan; no triangulation") from ex
    simp = tri.simplices
    local = xyz - xyz.mean(axis=0)
    planes = triangle_planes(local, simp)
    slope, aspect = triangle_slope_aspect(planes)
    p = xy[simp]
    edges = np.stack([np.linalg.norm(p[:, 1] - p[:, 0], axis=1),
                      np.linalg.norm(p[:, 2] - p[:, 1], axis=1),
                      np.linalg.norm(p[:, 0] - p[:, 2], axis=1)], axis=1)
    longest = edges.max(axis=1)
    if max_edge_m is None:
        max_edge_m = 4.0 * float(np.median(edges)) if len(edges) else math.inf
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    return _Facets(simp, planes, slope, aspect, area, longest <= max_edge_m, float(max_edge_m))
