r"""Contour verification (report 13.2), contour polygons (filled bands) and 3-D contour lines.

Verification over sparse ground
-------------------------------
The report checks the contours where the ground points are sparse: under
dense vegetation few pulses reach the ground, the terrain there is often
broken, and a misclassified point bends the contours; such stretches are
reviewed by drawing profiles across them and reclassifying points.

A contour drawn on the TIN crosses one triangle per segment (each segment
joins two edges of one triangle), so the ground density under a segment is
measured by the triangle under its middle: the longest edge of that
triangle.  A segment is *sparse* when that edge exceeds ``sparse_edge_m``;
the default is ``3 x`` the median edge length of the TIN (on evenly spread
points of spacing ``s`` the median edge is about ``1.1 s``, and fewer than
0.5 % of triangles have an edge above ``3.3 s``; ten times fewer points
under trees lengthen the edges about ``sqrt(10) = 3.2`` times).  Runs of
consecutive sparse segments of one contour are the *stretches*, reported with
their level, length and longest edge (a stretch shorter than
``min_length_m`` is dropped).

Profile across a stretch
------------------------
:func:`stretch_profile` cuts a vertical section across the stretch at its
middle, perpendicular to the contour (the direction of the segment there):
the LiDAR points within ``corridor_m`` of the section line, with their
distance along it, split into ground and other points, and the ground TIN
sampled along the section (linear in the triangles; NaN outside the TIN).
:func:`write_profile_png` draws it: the points, the TIN line, the contour's
level as a horizontal line and the crossing as a vertical one, so the
operator sees whether a ground point is off (the report's reclassification).

Filled bands (polygons)
-----------------------
:func:`contour_bands` fills the TIN between consecutive levels
(``tricontourf`` of matplotlib on the same masked TIN as :func:`contours`, so
the band edges are the contour lines): for each band ``[lower, upper)`` the
filled rings are split at their MOVETO codes, rings with positive signed
area (counter-clockwise) are outer boundaries and the others holes, each
hole assigned to the smallest outer ring holding its first vertex; one
MultiPolygon per band.  The lowest band starts at the lowest ground height
and the highest ends at the highest.

3-D lines
---------
:func:`contour_features_3d` writes each contour as a LineString with the
level as the third coordinate (LineStringZ in a GeoPackage), for CAD and
3-D viewers.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ProductError
from ..geometry.tin import TinLocator
from .contours import Contour, contour_generator, contour_levels

__all__ = ["SparseStretch", "Profile", "triangle_max_edges", "sparse_stretches", "stretch_features",
           "stretch_profile", "write_profile_png", "contour_bands", "contour_features_3d"]


@dataclass(frozen=True, eq=False)
class SparseStretch:
    """A stretch of a contour over sparse ground.

    Attributes
    ----------
    level_m : float
    xy : (K, 2) float
        The stretch's vertices (m).
    length_m : float
    max_edge_m : float
        Longest TIN edge under the stretch (m).
    contour : int
        Index of its contour in the list given.
    """

    level_m: float
    xy: np.ndarray
    length_m: float
    max_edge_m: float
    contour: int


@dataclass(frozen=True, eq=False)
class Profile:
    """A vertical section across a stretch (module docstring).

    Attributes
    ----------
    origin_m, direction : (2,) float
        Start of the section and its unit direction; distance ``d`` is at ``origin + d direction``.
    distance_m, height_m : (P,) float
        The points within the corridor.
    ground : (P,) bool
    tin_distance_m, tin_height_m : (S,) float
        The ground TIN sampled along the section (NaN outside it).
    crossing_m : float
        Distance of the stretch's middle (where the section crosses the contour).
    level_m : float
    """

    origin_m: np.ndarray
    direction: np.ndarray
    distance_m: np.ndarray
    height_m: np.ndarray
    ground: np.ndarray
    tin_distance_m: np.ndarray
    tin_height_m: np.ndarray
    crossing_m: float
    level_m: float


def triangle_max_edges(xy: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Longest edge of each triangle (T,), metres."""
    p = xy[triangles]
    return np.max(np.stack([np.hypot(*(p[:, i] - p[:, (i + 1) % 3]).T) for i in range(3)], axis=1), axis=1)


def _median_edge(xy: np.ndarray, triangles: np.ndarray) -> float:
    e = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    key = np.unique(e[:, 0].astype(np.int64) * len(xy) + e[:, 1])      # each edge once (1-D: fast)
    e = np.column_stack([key // len(xy), key % len(xy)])
    return float(np.median(np.hypot(*(xy[e[:, 0]] - xy[e[:, 1]]).T)))


def sparse_stretches(cs: Sequence[Contour], ground_xyz: np.ndarray, *, sparse_edge_m: float | None = None,
                     min_length_m: float = 0.0) -> tuple[list[SparseStretch], float]:
    """Stretches of the contours over sparse ground (module docstring).

    Parameters
    ----------
    cs : sequence of Contour
        Contours of the TIN of *ground_xyz* (:func:`lidarcat.production.contours.contours`).
    ground_xyz : (N, 3) float
    sparse_edge_m : float, optional
        A segment over a triangle with a longer edge is sparse; default 3 x the median TIN edge.
    min_length_m : float
        Shorter stretches are not reported.

    Returns
    -------
    stretches : list of SparseStretch
    sparse_edge_m : float
        The threshold used (m).
    """
    from scipy.spatial import Delaunay

    xyz = np.asarray(ground_xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[0] < 3:
        raise ProductError(f"contour verification needs at least 3 ground points, got shape {xyz.shape}")
    origin = xyz[:, :2].min(axis=0)
    local = xyz[:, :2] - origin
    tri = Delaunay(local)
    if sparse_edge_m is None:
        sparse_edge_m = 3.0 * _median_edge(local, tri.simplices)
    maxe = triangle_max_edges(local, tri.simplices)
    lines = [np.asarray(c.xy, dtype=np.float64) - origin for c in cs]
    nseg = np.array([max(len(x) - 1, 0) for x in lines])
    if nseg.sum() == 0:
        return [], float(sparse_edge_m)
    a = np.concatenate([x[:-1] for x in lines if len(x) > 1])
    b = np.concatenate([x[1:] for x in lines if len(x) > 1])
    owner = np.repeat(np.arange(len(lines)), nseg)
    simplex = TinLocator(tri).locate(0.5 * (a + b))[0]
    edge = np.where(simplex >= 0, maxe[np.maximum(simplex, 0)], 0.0)
    sparse = edge > sparse_edge_m
    # runs of sparse segments within one contour
    brk = np.r_[True, (owner[1:] != owner[:-1]) | (sparse[1:] != sparse[:-1])]
    starts = np.flatnonzero(brk)
    ends = np.r_[starts[1:], sparse.size]
    seglen = np.hypot(*(b - a).T)
    out = []
    keep = sparse[starts]
    for s0, s1 in zip(starts[keep], ends[keep]):
        length = float(seglen[s0:s1].sum())
        if length < min_length_m:
            continue
        xy = np.vstack([a[s0:s1], b[s1 - 1:s1]]) + origin
        k = int(owner[s0])
        out.append(SparseStretch(float(cs[k].level_m), xy, length, float(edge[s0:s1].max()), k))
    return out, float(sparse_edge_m)


def stretch_features(stretches: Sequence[SparseStretch], decimals: int = 3) -> list[dict[str, Any]]:
    """GeoJSON LineString features: level_m, length_m, max_edge_m, contour (index), review (True)."""
    return [{"type": "Feature",
             "properties": {"level_m": s.level_m, "length_m": round(s.length_m, decimals),
                            "max_edge_m": round(s.max_edge_m, decimals), "contour": s.contour, "review": True},
             "geometry": {"type": "LineString", "coordinates": np.round(s.xy, decimals).tolist()}}
            for s in stretches]


def stretch_profile(stretch: SparseStretch, points_xyz: np.ndarray, ground: np.ndarray, *,
                    half_length_m: float | None = None, corridor_m: float = 1.0, samples: int = 401) -> Profile:
    """The vertical section across *stretch* at its middle (module docstring).

    Parameters
    ----------
    stretch : SparseStretch
    points_xyz : (N, 3) float
        All LiDAR points near the stretch (ground and other classes).
    ground : (N,) bool
        Which of them are ground.
    half_length_m : float, optional
        Half the section's length; default ``max(10, 3 x max_edge_m)``.
    corridor_m : float
        Points within this distance of the section line are shown.
    samples : int
        TIN samples along the section (odd: the middle one is the crossing).
    """
    from scipy.spatial import Delaunay

    p = np.asarray(points_xyz, dtype=np.float64)
    g = np.asarray(ground, dtype=bool)
    if g.sum() < 3:
        raise ProductError(f"profile of the {stretch.level_m:g} m contour: fewer than 3 ground points given")
    xy = stretch.xy
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(xy, axis=0).T))]
    half = 0.5 * cum[-1]
    j = int(np.clip(np.searchsorted(cum, half) - 1, 0, len(xy) - 2))
    t = (half - cum[j]) / max(cum[j + 1] - cum[j], 1e-12)
    mid = xy[j] + t * (xy[j + 1] - xy[j])
    tangent = xy[j + 1] - xy[j]
    tangent = tangent / max(np.hypot(*tangent), 1e-12)
    normal = np.array([-tangent[1], tangent[0]])
    hl = half_length_m if half_length_m is not None else max(10.0, 3.0 * stretch.max_edge_m)
    origin = mid - hl * normal
    rel = p[:, :2] - origin
    d = rel @ normal
    off = rel @ tangent
    keep = (np.abs(off) <= corridor_m) & (d >= 0) & (d <= 2 * hl)
    gx = p[g]
    o2 = gx[:, :2].min(axis=0)
    tri = Delaunay(gx[:, :2] - o2)
    sd = np.linspace(0.0, 2 * hl, samples)
    sxy = origin + sd[:, None] * normal - o2
    simplex, w = TinLocator(tri).locate(sxy)
    ok = simplex >= 0
    h = np.full(samples, np.nan)
    h[ok] = np.einsum("mk,mk->m", w[ok], gx[tri.simplices[simplex[ok]], 2])
    return Profile(origin, normal, d[keep], p[keep, 2], g[keep], sd, h, float(hl), float(stretch.level_m))


def write_profile_png(path: str | os.PathLike, prof: Profile, *, title: str | None = None, dpi: int = 110) -> Path:
    """Draw a :class:`Profile` (module docstring) as a PNG, atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from .._util import atomic_write

    fig = Figure(figsize=(8.0, 4.0))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    other = ~prof.ground
    ax.plot(prof.distance_m[other], prof.height_m[other], ".", ms=3, color="#2ca02c", label="other points")
    ax.plot(prof.distance_m[prof.ground], prof.height_m[prof.ground], "o", ms=4, color="#8c564b",
            label="ground points")
    ax.plot(prof.tin_distance_m, prof.tin_height_m, "-", lw=1.2, color="#333333", label="ground TIN")
    ax.axhline(prof.level_m, ls="--", lw=1.0, color="#d62728", label=f"contour {prof.level_m:g} m")
    ax.axvline(prof.crossing_m, ls=":", lw=1.0, color="#d62728")
    ax.set_xlabel("distance across the contour (m)")
    ax.set_ylabel("height (m)")
    e, n = prof.origin_m + prof.crossing_m * prof.direction
    ax.set_title(title or f"Profile across the {prof.level_m:g} m contour at E {e:.1f} N {n:.1f}", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    out = Path(path)
    with atomic_write(out, "wb") as fh:
        fig.savefig(fh, format="png", dpi=dpi, metadata={"Software": None})
    return out


def _signed_area(r: np.ndarray) -> float:
    x, y = r[:, 0], r[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def contour_bands(ground_xyz: np.ndarray, interval_m: float = 1.0, *, max_edge_m: float | None = 50.0,
                  base_m: float = 0.0, levels: Sequence[float] | None = None, edge_peel: int = 3,
                  decimals: int = 3) -> list[dict[str, Any]]:
    """Filled bands between consecutive levels as GeoJSON MultiPolygon features (module docstring).

    Parameters are those of :func:`lidarcat.production.contours.contours`.
    Properties: ``lower_m``, ``upper_m``, ``area_m2``.
    """
    from matplotlib.path import Path as MplPath

    if not interval_m > 0:
        raise ProductError(f"interval_m must be positive, got {interval_m}")
    xyz = np.asarray(ground_xyz, dtype=np.float64)
    if len(xyz) < 3:
        return []
    origin, gen = contour_generator(xyz, max_edge_m, edge_peel)
    lv = [x for x, _ in contour_levels(xyz[:, 2], interval_m, base_m, levels)]
    lo_h, hi_h = float(xyz[:, 2].min()), float(xyz[:, 2].max())
    edges = sorted(set([lo_h] + [x for x in lv if lo_h < x < hi_h] + [hi_h]))
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        # the top band includes the highest point
        verts, codes = gen.create_filled_contour(lo, hi if hi < hi_h else math.nextafter(hi, math.inf))
        rings = []
        for v, c in zip(verts, codes):
            v, c = np.asarray(v, dtype=np.float64), np.asarray(c)
            starts = list(np.flatnonzero(c == 1)) + [len(v)]
            for a, b in zip(starts[:-1], starts[1:]):
                r = v[a:b]
                if c[b - 1] == 79:
                    r = r[:-1]
                if len(r) >= 3:
                    rings.append(r)
        if not rings:
            continue
        areas = np.array([_signed_area(r) for r in rings])
        outer = [i for i in range(len(rings)) if areas[i] > 0]
        holes: dict[int, list[int]] = {i: [] for i in outer}
        paths = {i: MplPath(rings[i]) for i in outer}
        for h in (i for i in range(len(rings)) if areas[i] <= 0):
            inside = [i for i in outer if paths[i].contains_point(rings[h][0])]
            if inside:
                holes[min(inside, key=lambda i: areas[i])].append(h)
        polys = []
        total = 0.0
        for i in outer:
            ring_list = [rings[i]] + [rings[h] for h in holes[i]]
            total += areas[i] + sum(areas[h] for h in holes[i])
            polys.append([np.round(np.vstack([r, r[:1]]) + origin, decimals).tolist() for r in ring_list])
        out.append({"type": "Feature",
                    "properties": {"lower_m": lo, "upper_m": hi, "area_m2": round(total, 3)},
                    "geometry": {"type": "MultiPolygon", "coordinates": polys}})
    return out


def contour_features_3d(cs: Sequence[Contour], decimals: int = 3) -> list[dict[str, Any]]:
    """GeoJSON LineString features with the level as the z coordinate (properties as
    :func:`lidarcat.production.contours.contour_features`)."""
    return [{"type": "Feature",
             "properties": {"level_m": c.level_m, "type": "master" if c.master else "intermediate",
                            "closed": c.closed},
             "geometry": {"type": "LineString", "coordinates": np.round(
                 np.column_stack([c.xy, np.full(len(c.xy), c.level_m)]), decimals).tolist()}}
            for c in cs]
