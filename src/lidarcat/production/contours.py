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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import dumps_json, write_text_atomic

__all__ = ["Contour", "contours", "spot_heights", "write_geojson", "contour_features", "spot_features",
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


def contours(ground_xyz: np.ndarray, interval_m: float = 1.0, *, master_every: int = 5,
             max_edge_m: float | None = 50.0, smooth_iterations: int = 0,
             base_m: float = 0.0) -> list[Contour]:
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
    import matplotlib.tri as mtri
    from matplotlib._tri import TriContourGenerator

    if not interval_m > 0:
        raise ValueError(f"interval_m must be positive, got {interval_m}")
    if master_every < 1:
        raise ValueError(f"master_every must be at least 1, got {master_every}")
    xyz = np.asarray(ground_xyz, dtype=np.float64)
    if len(xyz) < 3:
        return []
    origin = xyz[:, :2].min(axis=0)
    local = xyz[:, :2] - origin
    tri = mtri.Triangulation(local[:, 0], local[:, 1])
    if max_edge_m is not None:
        p = local[tri.triangles]
        edges = np.stack([np.hypot(*(p[:, i] - p[:, (i + 1) % 3]).T) for i in range(3)], axis=1)
        tri.set_mask(edges.max(axis=1) > max_edge_m)
    gen = TriContourGenerator(tri.get_cpp_triangulation(), xyz[:, 2])
    k0 = math.ceil((xyz[:, 2].min() - base_m) / interval_m)
    k1 = math.floor((xyz[:, 2].max() - base_m) / interval_m)
    out: list[Contour] = []
    for k in range(k0, k1 + 1):
        level = base_m + k * interval_m
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
                if smooth_iterations:
                    line = _chaikin(line, closed, smooth_iterations)
                out.append(Contour(float(level), line + origin, k % master_every == 0, closed))
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
    out = []
    for name, feats in layers.items():
        kind = feats[0]["geometry"]["type"] if feats else "LineString"
        coords = [f["geometry"]["coordinates"] for f in feats]
        geoms = [np.asarray(g[0] if kind == "Polygon" else [g] if kind == "Point" else g, dtype=np.float64)
                 for g in coords]
        keys = list(feats[0]["properties"]) if feats else []
        out.append(Layer(name, kind, geoms, {k: [f["properties"][k] for f in feats] for k in keys}))
    return write_gpkg(path, out, c)


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
                xy = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
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
