"""Contour lines from the ground TIN, master/intermediate curves, spot heights, GeoJSON.

The report (section 11.5) triangulates the ground points (Delaunay) and draws
contours every metre, classified as master (every ``master_every``-th level)
and intermediate curves, with spot heights.  On a TIN a contour at level
:math:`L` crosses edge :math:`(P_i, P_j)` with :math:`h_i < L \\le h_j` at

.. math:: P = P_i + \\frac{L - h_i}{h_j - h_i} (P_j - P_i),

so every vertex lies exactly on the TIN at its level and two contours never
cross; inside one triangle a level gives at most one segment, so the chained
lines do not intersect themselves.  matplotlib's TIN contour generator does the
chaining (closed rings end with the first vertex repeated).  Triangles with an
edge longer than ``max_edge_m`` are masked (gaps: no contour is invented
there).

Edge of the triangulation: along the TIN's boundary (the convex hull, and
the rims of the gaps left by ``max_edge_m``) Delaunay makes slivers, long thin
triangles whose contour segments run along the boundary for tens of metres
(2.3-4.0 % of all contour length on AHN3 tiles, one run of 57 m; GDAL 0.1 %).
``edge_peel`` passes (default 3) mask every triangle with a vertex on the
boundary before contouring, so the contours stop about three point spacings
inside the data (a raster's contours stop half a cell inside).  On the two
AHN3 tiles the share along the edge falls from 3.2 and 4.5 % to 0.3 and
0.6 % with one pass, 0.08 and 0.28 % with two, 0.000 % with three, for 7 and
15 % less contour length (the rims of every building's gap); figures in
docs/figures.md.  :func:`edge_fraction`
measures what is left: the share of contour length within ``tol_m`` of the
boundary of the unpeeled TIN.

Small rings (``min_ring_m``): closed rings shorter than it are left out (on
an AHN3 tile 3,258 of 3,693 rings are shorter than 5 m: noise of the ground
points, not relief).  Fixed ``levels`` replace the interval.  A gridded DTM
(a GeoTIFF) is contoured by :func:`raster_contours`.

Smoothing (optional, ``smooth_iterations``): Chaikin's corner cutting replaces
each segment :math:`(A, B)` by the points at 1/4 and 3/4 of it; closed rings
stay closed and open lines keep their end points.  Smoothed vertices leave the
TIN (by less than the curvature of the line allows); leave it off when the
contours must honour the TIN exactly.

Spot heights: the highest and the lowest ground point in every
``spot_spacing_m`` square (aligned to multiples of it).

GeoJSON output carries the CRS as the (GDAL/QGIS-read) ``crs`` member.
GeoPackage output (:func:`write_contours` with a ``.gpkg`` path; needs the
optional ``gis`` extra, pyogrio, whose wheels bundle GDAL) holds two layers,
``contours`` (LineString: level_m, type, closed) and ``spot_heights`` (Point:
h_m, kind), both with the CRS; it is written by the GIS writer of
:mod:`lidarcat.interop.gis`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import dumps_json, write_text_atomic

__all__ = ["Contour", "contours", "contour_generator", "contour_levels", "raster_contours", "edge_fraction", "tin_mask", "boundary_edges",
           "spot_heights",
           "write_geojson", "contour_features", "spot_features",
           "write_contours", "write_layers", "read_line_layer", "CONTOUR_FORMATS"]

#: output formats of :func:`write_contours`, by file suffix
CONTOUR_FORMATS = {".geojson": "GeoJSON", ".json": "GeoJSON", ".gpkg": "GeoPackage"}


@dataclass(frozen=True, eq=False)
class Contour:
    """One contour line.

    Attributes
    ----------
    level_m : float
        Height, metres.
    xy : ndarray, shape (K, 2)
        Vertices E, N in metres (a closed ring repeats its first vertex).
    master : bool
        A master (index) curve.
    closed : bool
    """

    level_m: float
    xy: np.ndarray
    master: bool
    closed: bool


def _chaikin(xy: np.ndarray, closed: bool, iterations: int) -> np.ndarray:
    for _ in range(iterations):
        if len(xy) < 3:
            return xy
        pts = xy[:-1] if closed else xy
        a = pts
        b = np.roll(pts, -1, axis=0) if closed else pts[1:]
        a = a if closed else pts[:-1]
        q = 0.75 * a + 0.25 * b
        r = 0.25 * a + 0.75 * b
        new = np.empty((2 * len(q), 2))
        new[0::2], new[1::2] = q, r
        xy = np.vstack([new, new[:1]]) if closed else np.vstack([pts[:1], new, pts[-1:]])
    return xy



def contour_generator(xyz: np.ndarray, max_edge_m: float | None, edge_peel: int) -> tuple[np.ndarray, Any]:
    """The TIN of the ground points (N >= 3, E N h), masked by :func:`tin_mask`, and matplotlib's
    contour generator on it; coordinates relative to ``origin`` (the points' lower-left corner, so
    that float64 keeps millimetres).  Returns ``(origin (2,), generator)`` -- lines and filled
    bands (:func:`lidarcat.production.contourcheck.contour_bands`) come from the same TIN."""
    import matplotlib.tri as mtri
    from matplotlib._tri import TriContourGenerator

    origin = xyz[:, :2].min(axis=0)
    local = xyz[:, :2] - origin
    tri = mtri.Triangulation(local[:, 0], local[:, 1])
    tri.set_mask(tin_mask(local, tri.triangles, max_edge_m, edge_peel))
    return origin, TriContourGenerator(tri.get_cpp_triangulation(), xyz[:, 2])


def contours(ground_xyz: np.ndarray, interval_m: float = 1.0, *, master_every: int = 5,
             max_edge_m: float | None = 50.0, smooth_iterations: int = 0,
             base_m: float = 0.0, levels: Sequence[float] | None = None, min_ring_m: float = 0.0,
             edge_peel: int = 3) -> list[Contour]:
    """Contours of the TIN of *ground_xyz* every *interval_m* metres.

    Parameters
    ----------
    ground_xyz : ndarray, shape (N, 3)
        Ground points, E, N, h in metres.
    interval_m : float
        Contour interval (equidistance), metres (the report: 1 m).
    master_every : int
        Every this-th level (counted from *base_m*) is a master curve.
    max_edge_m : float or None
        Triangles with a longer edge are gaps.
    smooth_iterations : int
        Chaikin passes (0: none; the vertices then lie on the TIN).
    base_m : float
        Levels are ``base_m + k * interval_m``.
    levels : sequence of float, optional
        Fixed levels instead (a level on the ``base_m + k * interval_m`` grid keeps its master flag;
        others are intermediate).
    min_ring_m : float
        Closed rings shorter than this are left out, m (0: all kept).
    edge_peel : int
        Passes that mask the triangles touching the boundary of the TIN (module docstring, "Edge of
        the triangulation"); 0 keeps them.

    Returns
    -------
    list of Contour
        Ordered by level.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> xy = rng.uniform(-10, 10, (2000, 2))
    >>> cone = np.column_stack([xy, 10 - np.hypot(*xy.T)])
    >>> cs = contours(cone, 2.0, master_every=2)
    >>> [(c.level_m, c.master, c.closed) for c in cs if c.level_m >= 4]
    [(4.0, True, True), (6.0, False, True), (8.0, True, True)]
    """
    if not interval_m > 0:
        raise ValueError(f"interval_m must be positive, got {interval_m}")
    if master_every < 1:
        raise ValueError(f"master_every must be at least 1, got {master_every}")
    xyz = np.asarray(ground_xyz, dtype=np.float64)
    if len(xyz) < 3:
        return []
    origin, gen = contour_generator(xyz, max_edge_m, edge_peel)
    out: list[Contour] = []
    for level, k in contour_levels(xyz[:, 2], interval_m, base_m, levels):
        segs, codes = gen.create_contour(level)
        for seg, code in zip(segs, codes):
            # split at MOVETO codes (1): one path can hold several lines
            starts = list(np.flatnonzero(np.asarray(code) == 1)) + [len(seg)]
            for a, b in zip(starts[:-1], starts[1:]):
                line = np.asarray(seg[a:b], dtype=np.float64)
                if len(line) < 2:
                    continue
                closed = bool(np.asarray(code)[b - 1] == 79) or bool(np.all(line[0] == line[-1]))
                if closed and not np.all(line[0] == line[-1]):
                    line = np.vstack([line, line[:1]])
                if closed and min_ring_m > 0 and _length(line) < min_ring_m:
                    continue
                if smooth_iterations:
                    line = _chaikin(line, closed, smooth_iterations)
                out.append(Contour(float(level), line + origin, k is not None and k % master_every == 0, closed))
    return out


def _length(xy: np.ndarray) -> float:
    return float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0


def contour_levels(h: np.ndarray, interval_m: float, base_m: float,
            levels: Sequence[float] | None) -> list[tuple[float, int | None]]:
    """(level, k) to contour: ``base_m + k interval_m`` within the heights, or the fixed *levels*
    (k None when a level is off that grid)."""
    h = h[np.isfinite(h)]
    if not len(h):
        return []
    if levels is None:
        k0 = math.ceil((h.min() - base_m) / interval_m)
        k1 = math.floor((h.max() - base_m) / interval_m)
        return [(base_m + k * interval_m, k) for k in range(k0, k1 + 1)]
    out = []
    for lv in sorted(set(float(x) for x in levels)):
        k = round((lv - base_m) / interval_m)
        out.append((lv, k if abs(base_m + k * interval_m - lv) < 1e-9 * max(1.0, abs(lv)) else None))
    return out


def boundary_edges(triangles: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """(M, 2) vertex pairs of the edges that belong to one kept triangle only: the TIN's boundary."""
    t = triangles if mask is None else triangles[~mask]
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def tin_mask(xy: np.ndarray, triangles: np.ndarray, max_edge_m: float | None, edge_peel: int = 1) -> np.ndarray:
    """Triangles left out of the contouring: an edge longer than *max_edge_m*, then *edge_peel* passes of
    every triangle with a vertex on the boundary (module docstring)."""
    p = xy[triangles]
    mask = np.zeros(len(triangles), bool)
    if max_edge_m is not None:
        edges = np.stack([np.hypot(*(p[:, i] - p[:, (i + 1) % 3]).T) for i in range(3)], axis=1)
        mask = edges.max(axis=1) > max_edge_m
    for _ in range(max(0, int(edge_peel))):
        on = np.zeros(len(xy), bool)
        on[boundary_edges(triangles, mask).ravel()] = True
        peel = ~mask & on[triangles].any(axis=1)
        if peel.all() or not peel.any():   # keep something: a TIN too small to peel stays whole
            break
        mask = mask | peel
    return mask


def edge_fraction(cs: Sequence[Contour], ground_xyz: np.ndarray, *, max_edge_m: float | None = 50.0,
                  tol_m: float = 0.1) -> float:
    """The fraction of the contours' length that runs along the boundary of the ground TIN.

    A contour segment runs along it when both its ends and its middle lie within *tol_m* of the
    boundary edges of the TIN (triangles with an edge longer than *max_edge_m* left out, none peeled).
    """
    import matplotlib.tri as mtri
    from scipy.spatial import cKDTree

    xyz = np.asarray(ground_xyz, dtype=np.float64)
    origin = xyz[:, :2].min(axis=0)
    local = xyz[:, :2] - origin
    tri = mtri.Triangulation(local[:, 0], local[:, 1])
    b = boundary_edges(tri.triangles, tin_mask(local, tri.triangles, max_edge_m, 0))
    a, c = local[b[:, 0]], local[b[:, 1]]
    # the boundary sampled every tol/2 along each edge: a point within tol/2 of a sample is within tol
    n = np.maximum(1, np.ceil(np.hypot(*(c - a).T) / (tol_m / 2)).astype(int))
    t = np.concatenate([np.arange(k + 1) / k for k in n])
    i = np.repeat(np.arange(len(b)), n + 1)
    samples = a[i] + t[:, None] * (c[i] - a[i])
    tree = cKDTree(samples)
    total = along = 0.0
    for cn in cs:
        xy = cn.xy - origin
        if len(xy) < 2:
            continue
        seg = np.hypot(*np.diff(xy, axis=0).T)
        near = tree.query(xy, distance_upper_bound=tol_m / 2)[0] < np.inf
        mid = tree.query(0.5 * (xy[1:] + xy[:-1]), distance_upper_bound=tol_m / 2)[0] < np.inf
        total += float(seg.sum())
        along += float(seg[near[1:] & near[:-1] & mid].sum())
    return along / total if total else 0.0


def raster_contours(grid: np.ndarray, transform: Any, interval_m: float = 1.0, *, master_every: int = 5,
                    base_m: float = 0.0, levels: Sequence[float] | None = None, min_ring_m: float = 0.0,
                    smooth_iterations: int = 0) -> list[Contour]:
    """Contours of a gridded DTM (a GeoTIFF's values; NaN cells are gaps), at the cell centres.

    The grid is contoured by marching squares (contourpy, matplotlib's contour engine) on the
    cell-centre lattice; NaN cells are masked.  Levels, master curves, ring filter and smoothing as
    :func:`contours`.

    Parameters
    ----------
    grid : (rows, cols) array
        Heights, m (NaN: no data).
    transform : GeoTransform
        North-up: ``x0, y0`` the upper-left corner, ``cell_m``.
    """
    import contourpy

    z = np.asarray(grid, dtype=np.float64)
    if z.ndim != 2 or min(z.shape) < 2:
        from ..errors import ProductError

        raise ProductError(f"a DTM of {z.shape} cells cannot be contoured (needs 2 x 2 cells or more)")
    rows, cols = z.shape
    x = transform.x0 + (np.arange(cols) + 0.5) * transform.cell_m
    y = transform.y0 - (np.arange(rows) + 0.5) * transform.cell_m
    zm = np.ma.masked_invalid(z)
    gen = contourpy.contour_generator(x, y, zm, line_type=contourpy.LineType.Separate)
    out: list[Contour] = []
    for level, k in contour_levels(z.ravel(), interval_m, base_m, levels):
        for line in gen.lines(level):
            line = np.asarray(line, dtype=np.float64)
            if len(line) < 2:
                continue
            closed = bool(np.all(line[0] == line[-1])) and len(line) > 3
            if closed and min_ring_m > 0 and _length(line) < min_ring_m:
                continue
            if smooth_iterations:
                line = _chaikin(line, closed, smooth_iterations)
            out.append(Contour(float(level), line, k is not None and k % master_every == 0, closed))
    return out


def spot_heights(ground_xyz: np.ndarray, spacing_m: float = 100.0) -> np.ndarray:
    """Highest and lowest ground point of each *spacing_m* square: (M, 4) E, N, h, is_high (1/0)."""
    xyz = np.asarray(ground_xyz, dtype=np.float64)
    if len(xyz) == 0:
        return np.zeros((0, 4))
    cx = np.floor(xyz[:, 0] / spacing_m).astype(np.int64)
    cy = np.floor(xyz[:, 1] / spacing_m).astype(np.int64)
    rows = []
    for sign, flag in ((-1.0, 1.0), (1.0, 0.0)):
        order = np.lexsort((sign * xyz[:, 2], cy, cx))
        first = np.ones(len(order), dtype=bool)
        first[1:] = (cx[order][1:] != cx[order][:-1]) | (cy[order][1:] != cy[order][:-1])
        sel = order[first]
        rows.append(np.column_stack([xyz[sel], np.full(len(sel), flag)]))
    return np.vstack(rows)


def contour_features(cs: list[Contour], decimals: int = 3) -> list[dict[str, Any]]:
    """GeoJSON features: LineString per contour, properties level_m, type (master/intermediate), closed."""
    return [{"type": "Feature",
             "properties": {"level_m": c.level_m, "type": "master" if c.master else "intermediate",
                            "closed": c.closed},
             "geometry": {"type": "LineString", "coordinates": np.round(c.xy, decimals).tolist()}}
            for c in cs]


def spot_features(spots: np.ndarray, decimals: int = 3) -> list[dict[str, Any]]:
    """GeoJSON features: Point per spot height, properties h_m and kind (high/low)."""
    return [{"type": "Feature", "properties": {"h_m": round(float(s[2]), decimals),
                                               "kind": "high" if s[3] else "low"},
             "geometry": {"type": "Point", "coordinates": [round(float(s[0]), decimals),
                                                           round(float(s[1]), decimals)]}}
            for s in spots]


def write_geojson(path: str | os.PathLike, features: list[dict[str, Any]], crs: Any = None) -> Path:
    """Write a FeatureCollection with a ``crs`` member (EPSG URN or WKT name), atomically."""
    from ..lidar.crs import geojson_crs_member

    fc: dict[str, Any] = {"type": "FeatureCollection", "features": features}
    member = geojson_crs_member(crs)
    if member is not None:
        fc["crs"] = member
    return write_text_atomic(Path(path), dumps_json(fc, indent=None) + "\n")


def write_contours(path: str | os.PathLike, cs: list[Contour], spots: np.ndarray, crs: Any,
                   decimals: int = 3) -> list[Path]:
    """Write contours and spot heights; the format follows the suffix of *path*.

    ``.gpkg``: one GeoPackage with the layers ``contours`` and ``spot_heights``.
    ``.geojson`` (or ``.json``): *path* holds the contours and
    ``<stem>_spots<suffix>`` the spot heights.  Coordinates are rounded to
    *decimals* (metres) in both.

    Parameters
    ----------
    path : path-like
    cs : list of Contour
    spots : ndarray, shape (M, 4)
        E, N, h (metres), is_high, as :func:`spot_heights` returns.
    crs : CRS-like
        CRS of the coordinates, written into every layer.

    Returns
    -------
    list of Path
        The files written.

    Raises
    ------
    ValueError
        An unknown suffix.
    lidarcat.errors.FormatError
        ``.gpkg`` without pyogrio installed.
    lidarcat.errors.CRSError
        ``.gpkg`` without a CRS.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CONTOUR_FORMATS:
        raise ValueError(f"{path}: contour output must end in {', '.join(CONTOUR_FORMATS)}, got "
                         f"{path.suffix or '(no suffix)'!r}")
    if suffix == ".gpkg":
        return [write_layers(path, {"contours": contour_features(cs, decimals),
                                    "spot_heights": spot_features(spots, decimals)}, crs)]
    spots_path = path.with_name(path.stem + "_spots" + path.suffix)
    return [write_geojson(path, contour_features(cs, decimals), crs),
            write_geojson(spots_path, spot_features(spots, decimals), crs)]


def write_layers(path: str | os.PathLike, layers: dict[str, list[dict[str, Any]]], crs: Any) -> Path:
    """Write GeoJSON-like feature lists as named layers of one GeoPackage (``.gpkg``) or, for one
    layer, a GeoJSON file (any other suffix).

    Every feature of a layer has the geometry type of its first feature
    (Point, LineString or Polygon with one ring) and the properties of its
    first feature.  The GeoPackage goes through :func:`lidarcat.interop.gis.write_gpkg`
    (pyogrio), atomically.

    Raises
    ------
    ValueError
        Several layers for a GeoJSON file.
    lidarcat.errors.CRSError
        A GeoPackage without a CRS.
    lidarcat.errors.FormatError
        A GeoPackage without pyogrio installed.
    """
    path = Path(path)
    if path.suffix.lower() != ".gpkg":
        if len(layers) != 1:
            raise ValueError(f"{path}: a GeoJSON file holds one layer, got {len(layers)}")
        return write_geojson(path, next(iter(layers.values())), crs)
    from ..errors import CRSError
    from ..interop.gis import Layer, write_gpkg
    from ..lidar.crs import resolve_crs

    c = resolve_crs(crs)
    if c is None:
        raise CRSError(f"{path}: a GeoPackage needs the CRS of its layers; give the tiles' CRS (--crs)")
    if any(f["geometry"]["type"] == "MultiPolygon" or (f["geometry"]["type"] == "LineString"
                                                       and len(f["geometry"]["coordinates"][0]) == 3)
           for feats in layers.values() for f in feats[:1]):
        return _write_gpkg_wkb(path, layers, c)
    out = []
    for name, feats in layers.items():
        kind = feats[0]["geometry"]["type"] if feats else "LineString"
        coords = [f["geometry"]["coordinates"] for f in feats]
        geoms = [np.asarray(g[0] if kind == "Polygon" else [g] if kind == "Point" else g, dtype=np.float64)
                 for g in coords]
        keys = list(feats[0]["properties"]) if feats else []
        out.append(Layer(name, kind, geoms, {k: [f["properties"][k] for f in feats] for k in keys}))
    return write_gpkg(path, out, c)


def _wkb(geom: dict[str, Any]) -> tuple[bytes, str]:
    """ISO WKB of a GeoJSON geometry (Point, LineString, Polygon, MultiPolygon; 2-D or 3-D) and its OGR type name."""
    import struct

    kind, c = geom["type"], geom["coordinates"]

    def dims(a: Any) -> int:
        while isinstance(a[0], list):
            a = a[0]
        return len(a)

    z = dims(c) == 3
    add = 1000 if z else 0

    def pts(a: Any) -> bytes:
        arr = np.asarray(a, dtype="<f8").reshape(-1, 3 if z else 2)
        return struct.pack("<I", len(arr)) + arr.tobytes()

    def poly(rings: Any) -> bytes:
        return struct.pack("<BII", 1, 3 + add, len(rings)) + b"".join(pts(r) for r in rings)

    if kind == "Point":
        return struct.pack("<BI", 1, 1 + add) + np.asarray(c, dtype="<f8").tobytes(), "Point Z" if z else "Point"
    if kind == "LineString":
        return struct.pack("<BI", 1, 2 + add) + pts(c), "LineString Z" if z else "LineString"
    if kind == "Polygon":
        return poly(c), "Polygon Z" if z else "Polygon"
    if kind == "MultiPolygon":
        return (struct.pack("<BII", 1, 6 + add, len(c)) + b"".join(poly(p) for p in c),
                "MultiPolygon Z" if z else "MultiPolygon")
    from ..errors import ProductError

    raise ProductError(f"geometry type {kind!r} is not written to a GeoPackage here")


def _write_gpkg_wkb(path: Path, layers: dict[str, list[dict[str, Any]]], crs: Any) -> Path:
    """Layers of any geometry of :func:`_wkb` into one GeoPackage with pyogrio, atomically."""
    import shutil
    import tempfile

    from ..errors import FormatError

    try:
        from pyogrio.raw import write
    except ImportError:
        raise FormatError(f"{path}: GeoPackage output needs pyogrio (pip install 'lidarcat[gis]'); "
                          "or write GeoJSON") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        part = tmp / path.name
        for name, feats in layers.items():
            enc = [_wkb(f["geometry"]) for f in feats]
            gtype = enc[0][1] if enc else "LineString"
            keys = list(feats[0]["properties"]) if feats else []
            data = [np.asarray([f["properties"][k] for f in feats],
                               dtype=object if feats and isinstance(feats[0]["properties"][k], str) else None)
                    for k in keys]
            write(str(part), np.array([e[0] for e in enc], dtype=object), data, keys, layer=name, driver="GPKG",
                  geometry_type=gtype, crs=crs.to_wkt(), append=part.exists())
        os.replace(part, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def _check_vertices(xy: np.ndarray, where: str) -> None:
    """Refuse a vertex beyond any map (|E| or |N| above :data:`lidarcat.lidar.readers.MAX_ABS_COORD_M`)."""
    from ..errors import FormatError
    from ..lidar.readers import MAX_ABS_COORD_M

    far = np.abs(xy).max(axis=1) > MAX_ABS_COORD_M if len(xy) else np.zeros(0, bool)
    if far.any():
        k = int(np.argmax(far))
        raise FormatError(f"{where}: vertex {k}: E {xy[k, 0]:.6g} N {xy[k, 1]:.6g} is not a coordinate in "
                          f"metres on the Earth (|E|, |N| <= {MAX_ABS_COORD_M:.0e})")


def read_line_layer(path: str | os.PathLike, layer: str | None = None) -> tuple[list[dict[str, Any]], Any]:
    """The LineString features of a GeoJSON file or of a GeoPackage layer, and the layer's CRS.

    Parameters
    ----------
    path : path-like
        ``.geojson``/``.json`` (the ``crs`` member, if any, gives the CRS) or ``.gpkg``.
    layer : str, optional
        GeoPackage layer (default ``contours`` when present, else the first LineString layer).

    Returns
    -------
    (features, crs)
        GeoJSON-like LineString features (other geometries are left out) and a
        :class:`pyproj.CRS` or ``None``.

    Raises
    ------
    lidarcat.errors.FormatError
        Unreadable file, no LineString layer, a geometry that is not a 2-D
        LineString of finite numbers within 1e9 m of the origin (feature and vertex
        named), or a GeoPackage without pyogrio.
    """
    import struct

    from .._util import loads_json, read_text
    from ..errors import FormatError
    from ..lidar.crs import resolve_crs

    path = Path(path)
    if path.suffix.lower() != ".gpkg":
        try:
            doc = loads_json(read_text(path, FormatError), path, FormatError)
            feats = [(i, f) for i, f in enumerate(doc["features"])
                     if (f.get("geometry") or {}).get("type") == "LineString"]
            name = ((doc.get("crs") or {}).get("properties") or {}).get("name")
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as ex:
            raise FormatError(f"{path}: not a readable GeoJSON FeatureCollection ({ex})") from ex
        for i, f in feats:
            try:
                raw = f["geometry"]["coordinates"]
                boolean = any(isinstance(v, bool) for pair in raw for v in pair)    # JSON true is no coordinate
                xy = np.zeros(0) if boolean else np.asarray(raw, dtype=np.float64)
            except (KeyError, TypeError, ValueError):
                xy = np.zeros(0)
            if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 2 or not np.isfinite(xy).all():
                raise FormatError(f"{path}: feature {i}: not a 2-D LineString (coordinates must be two or "
                                  f"more [E, N] pairs of finite numbers)")
            _check_vertices(xy, f"{path}: feature {i}")
        feats = [f if isinstance(f.get("properties"), dict) else {**f, "properties": {}} for _, f in feats]
        return feats, resolve_crs(name) if name else None
    try:
        import pyogrio
        from pyogrio.raw import read
    except ImportError:
        raise FormatError(f"{path}: reading GeoPackage needs pyogrio (pip install 'lidarcat[gis]')") from None
    try:
        layers = [(str(n), str(g)) for n, g in pyogrio.list_layers(path)]
        if layer is None:
            names = [n for n, g in layers if g in ("LineString", "MultiLineString")]
            layer = "contours" if ("contours", "LineString") in layers else (names[0] if names else None)
        if layer is None:
            raise FormatError(f"{path}: no LineString layer (layers: {', '.join(n for n, _ in layers) or 'none'})")
        meta, _, geoms, values = read(path, layer=layer)
    except FormatError:
        raise
    except Exception as ex:  # pyogrio.errors.DataSourceError, DataLayerError...
        raise FormatError(f"{path}: cannot read layer {layer!r} ({ex})") from ex
    names = [str(n) for n in meta["fields"]]
    feats = []
    for i, g in enumerate(geoms):
        g = bytes(g) if g is not None else b""
        if len(g) < 9 or g[0] != 1 or struct.unpack_from("<I", g, 1)[0] != 2:
            raise FormatError(f"{path}: layer {layer!r}, feature {i}: not a 2-D LineString")
        n = struct.unpack_from("<I", g, 5)[0]
        if len(g) != 9 + 16 * n:
            raise FormatError(f"{path}: layer {layer!r}, feature {i}: {n} vertices announced in {len(g)} bytes")
        xy = np.frombuffer(g, dtype="<f8", offset=9).reshape(n, 2)
        if not np.isfinite(xy).all():
            raise FormatError(f"{path}: layer {layer!r}, feature {i}: a vertex is not a finite number")
        _check_vertices(xy, f"{path}: layer {layer!r}, feature {i}")
        props = {k: (v.item() if hasattr(v, "item") else v) for k, v in zip(names, (col[i] for col in values))}
        feats.append({"type": "Feature", "properties": props,
                      "geometry": {"type": "LineString", "coordinates": xy.tolist()}})
    return feats, resolve_crs(meta["crs"]) if meta.get("crs") else None
