r"""Which photos to match: pairs from approximate footprints, never all pairs of a large block.

A photo's *footprint* is its four frame corners' rays met with the height surface
(:func:`lidarcat.match.rays.ray_to_surface`): a convex quadrilateral on the ground for a
near-nadir frame (checked: a footprint whose corners are not in convex order, a ray that
misses the ground ahead, is refused).

Two footprints ``P``, ``Q`` overlap by ::

    overlap(P, Q) = area(P ∩ Q) / min(area(P), area(Q)),

the share of the smaller footprint seen by both (for equal frames: the forward overlap of
a strip, 0.6 at 60 %).  ``area(P ∩ Q)`` of two convex polygons is the area of a convex
polygon, computed by ``cv2.intersectConvexConvex`` (O'Rourke's algorithm).  A pair is
matched when its overlap is at least ``min_overlap`` (default 0.1: photos of neighbouring
strips at 30 % side lap qualify, photos two strips apart do not).

Candidate pairs come from a k-d tree of the footprint centres queried within the sum of
the two circumscribed radii (``query_pairs`` at the largest diameter): each photo meets the
photos of a bounded neighbourhood, so the pairs grow linearly with the photos of a block
of constant overlap, and only the candidates get the exact polygon test.  Without any
orientation (:func:`exhaustive_pairs`) every pair is matched -- only for small blocks.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..geometry.camera import Camera
from .rays import HeightSurface, ray_to_surface

__all__ = ["footprint", "polygon_area", "convex_overlap", "footprint_pairs", "exhaustive_pairs"]


def footprint(camera: Camera, eo: Any, surface: HeightSurface) -> np.ndarray:
    """Ground corners (E, N; m) of the frame, counter-clockwise, shape (4, 2).

    Corners in pixel order (0, 0), (C-1, 0), (C-1, R-1), (0, R-1), met with *surface*.
    """
    c, r = camera.columns_px - 1.0, camera.rows_px - 1.0
    px = np.array([[0.0, 0.0], [c, 0.0], [c, r], [0.0, r]])
    en = ray_to_surface(camera, eo, px, surface)[:, :2]
    if polygon_area(en) < 0:
        en = en[::-1]
    return en


def polygon_area(poly: Any) -> float:
    """Signed area (shoelace; > 0 counter-clockwise) of a polygon (k, 2), m².

    >>> polygon_area([[0, 0], [2, 0], [2, 1], [0, 1]])
    2.0
    """
    p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * (np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def convex_overlap(a: Any, b: Any) -> float:
    """Area of the intersection of two convex polygons over the smaller area (0..1).

    >>> convex_overlap([[0, 0], [2, 0], [2, 2], [0, 2]], [[1, 0], [3, 0], [3, 2], [1, 2]])
    0.5
    """
    import cv2

    pa = np.asarray(a, dtype=np.float64).reshape(-1, 2)
    pb = np.asarray(b, dtype=np.float64).reshape(-1, 2)
    # shift to a common origin: cv2 works in float32, which loses centimetres at UTM coordinates
    o = pa.mean(axis=0)
    area_a, area_b = abs(polygon_area(pa)), abs(polygon_area(pb))
    if min(area_a, area_b) <= 0:
        return 0.0
    inter, _ = cv2.intersectConvexConvex((pa - o).astype(np.float32), (pb - o).astype(np.float32), handleNested=True)
    return float(min(max(inter, 0.0) / min(area_a, area_b), 1.0))


def footprint_pairs(footprints: Any, min_overlap: float = 0.1) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of photos whose footprints overlap by at least *min_overlap*.

    Parameters
    ----------
    footprints : ndarray (n, 4, 2) or sequence of (k, 2) convex polygons, m
    min_overlap : float
        Share of the smaller footprint (module docstring).

    Returns
    -------
    pairs : ndarray (m, 2) int
        ``i < j``, sorted.
    overlap : ndarray (m,)
    """
    from scipy.spatial import cKDTree

    polys = [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in footprints]
    if len(polys) < 2:
        return np.empty((0, 2), np.int64), np.empty(0)
    centre = np.array([p.mean(axis=0) for p in polys])
    radius = np.array([np.hypot(*(p - c).T).max() for p, c in zip(polys, centre)])
    cand = cKDTree(centre).query_pairs(2.0 * float(radius.max()), output_type="ndarray")
    if len(cand) == 0:
        return np.empty((0, 2), np.int64), np.empty(0)
    d = np.hypot(*(centre[cand[:, 0]] - centre[cand[:, 1]]).T)
    cand = cand[d <= radius[cand[:, 0]] + radius[cand[:, 1]]]
    ov = np.array([convex_overlap(polys[i], polys[j]) for i, j in cand])
    keep = ov >= min_overlap
    pairs = np.sort(cand[keep], axis=1)
    order = np.lexsort((pairs[:, 1], pairs[:, 0]))
    return pairs[order].astype(np.int64), ov[keep][order]


def exhaustive_pairs(n: int) -> np.ndarray:
    """Every pair ``i < j`` of *n* photos, shape (n (n-1) / 2, 2).

    >>> exhaustive_pairs(3).tolist()
    [[0, 1], [0, 2], [1, 2]]
    """
    i, j = np.triu_indices(int(n), k=1)
    return np.column_stack([i, j]).astype(np.int64)
