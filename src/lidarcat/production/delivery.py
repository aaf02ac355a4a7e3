"""Delivery formats of the LACTEC report (13.3, 14): TIFF + TFW world files, Shapefile layers, DXF for CAD.

World file (``.tfw`` beside ``X.tif``): six lines, the affine transform from
pixel (column, row) to map coordinates,

.. math::  E = A\\,c + B\\,r + C, \\qquad N = D\\,c + E_y\\,r + F,

written in the order A, D, B, E_y, C, F, where C and F are the **centre** of
the upper-left pixel (the GeoTIFF transform's corner plus half a cell):
for a north-up grid of cell *s* with corner (x0, y0) that is
``s, 0, 0, -s, x0 + s/2, y0 - s/2``.  It is written from the file's own
transform (rasterio), so it agrees with the GeoTIFF tags.

Shapefile (one layer per ``.shp`` with its ``.shx``, ``.dbf``, ``.prj`` and
``.cpg``): through pyogrio (the ``gis`` extra), written into a temporary
folder and moved in, so no half set of sidecars is left.

DXF (R2013, UTF-8; the ``cad`` extra, ezdxf): one layer per element of the
report's conventions (:mod:`lidarcat.production.conventions`, Figure 27), with
its true colour, nearest ACI colour and line weight: contours as 2-D
polylines (LWPOLYLINE) at their height (the entity's elevation), master and
intermediate curves on ``Curvas Mestras`` / ``Curvas Intermediárias``; spot
heights as 3-D points on ``Pontos Cotados`` with their height as text on
``Cotas``; sheet frames on ``Prancha``; the mapped area on ``Limite de
Restituição``.  A layer without features is not written; a DXF with no feature
at all is refused (:class:`~lidarcat.errors.ProductError`), never an empty file.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FormatError, ProductError
from .conventions import convention

__all__ = ["world_file_text", "write_world_file", "write_shapefile", "write_dxf", "read_point_layer",
           "DXF_LINEWEIGHTS"]

#: the line weights DXF allows, 1/100 mm
DXF_LINEWEIGHTS = (0, 5, 9, 13, 15, 18, 20, 25, 30, 35, 40, 50, 53, 60, 70, 80, 90, 100, 106, 120, 140, 158, 200, 211)


def world_file_text(x0: float, y0: float, cell_x: float, cell_y: float) -> str:
    """The six lines of a world file for a north-up grid with corner (*x0*, *y0*) and cells *cell_x* x *cell_y*.

    Examples
    --------
    >>> print(world_file_text(680000.0, 7184000.0, 0.5, 0.5), end="")
    0.5
    0.0
    0.0
    -0.5
    680000.25
    7183999.75
    """
    vals = (cell_x, 0.0, 0.0, -cell_y, x0 + cell_x / 2, y0 - cell_y / 2)
    return "".join(f"{v!r}\n" for v in map(float, vals))


def write_world_file(tif: str | os.PathLike) -> Path:
    """Write ``<tif>.tfw`` (same stem) from the GeoTIFF's own transform; the path written.

    Raises
    ------
    FormatError
        Not a readable GeoTIFF, or a rotated grid (a world file can hold one, but the products are north-up).
    """
    import rasterio
    import rasterio.errors

    from .._util import write_text_atomic

    tif = Path(tif)
    try:
        with rasterio.open(tif) as ds:
            t = ds.transform
    except rasterio.errors.RasterioError as ex:
        raise FormatError(f"{tif}: not a readable GeoTIFF ({str(ex).splitlines()[0]})") from ex
    if t.b != 0 or t.d != 0 or t.is_identity:
        raise FormatError(f"{tif}: not a north-up georeferenced grid; no world file written")
    out = tif.with_suffix(".tfw")
    write_text_atomic(out, world_file_text(t.c, t.f, t.a, -t.e))
    return out


def write_shapefile(path: str | os.PathLike, features: Sequence[dict[str, Any]], crs: Any) -> Path:
    """One Shapefile layer (``.shp`` + sidecars) of GeoJSON-like features (Point, LineString or Polygon).

    Raises
    ------
    ProductError
        No feature (a Shapefile of nothing is refused).
    FormatError
        pyogrio is not installed.
    """
    from ..lidar.crs import resolve_crs

    path = Path(path)
    if not features:
        raise ProductError(f"{path}: no feature to write; an empty Shapefile is not written")
    try:
        from pyogrio.raw import write
    except ImportError:
        raise FormatError(f"{path}: Shapefile output needs pyogrio (pip install 'lidarcat[gis]')") from None
    kind = features[0]["geometry"]["type"]
    geoms = [np.asarray(f["geometry"]["coordinates"][0] if kind == "Polygon" else
                        [f["geometry"]["coordinates"]] if kind == "Point" else f["geometry"]["coordinates"],
                        dtype=np.float64) for f in features]
    keys = list(features[0].get("properties") or {})
    fields = {k: [f["properties"][k] for f in features] for k in keys}
    c = resolve_crs(crs)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        data = [np.asarray([int(v) if isinstance(v, bool) else v for v in fields[k]],
                           dtype=object if isinstance(fields[k][0], str) else None) for k in keys]
        geom = np.array([_wkb(kind, g) for g in geoms], dtype=object)
        write(str(tmp / path.name), geom, data, keys, driver="ESRI Shapefile", geometry_type=kind,
              crs=c.to_wkt() if c is not None else None, encoding="UTF-8")
        for part in sorted(tmp.iterdir()):
            os.replace(part, path.parent / part.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def _wkb(kind: str, xy: np.ndarray) -> bytes:
    """Little-endian WKB of a 2-D Point, LineString or one-ring Polygon."""
    import struct

    xy = np.ascontiguousarray(xy, dtype="<f8")[:, :2]
    if kind == "Point":
        return struct.pack("<BI", 1, 1) + xy[0].tobytes()
    if kind == "LineString":
        return struct.pack("<BII", 1, 2, len(xy)) + xy.tobytes()
    if kind == "Polygon":
        return struct.pack("<BIII", 1, 3, 1, len(xy)) + xy.tobytes()
    raise ProductError(f"Shapefile: geometry {kind!r} is not Point, LineString or Polygon")


def _lineweight(mm: float) -> int:
    return min(DXF_LINEWEIGHTS, key=lambda w: abs(w - 100 * mm))


def write_dxf(path: str | os.PathLike, *, contours: Sequence[dict[str, Any]] = (), spots: np.ndarray | None = None,
              sheets: Sequence[dict[str, Any]] = (), area: tuple[float, float, float, float] | None = None) -> Path:
    """The contours, spot heights, sheet frames and mapped area as a DXF drawing (module docstring).

    Parameters
    ----------
    path : path-like
    contours : GeoJSON LineString features
        Properties ``level_m`` and ``type`` (``master``/``intermediate``).
    spots : (M, 3+) array, optional
        Spot heights E, N, h.
    sheets : GeoJSON Polygon features
        The sheet index (property ``name``), drawn on ``Prancha`` with the name.
    area : (xmin, ymin, xmax, ymax), optional
        The mapped area, on ``Limite de Restituição``.

    Raises
    ------
    ProductError
        Nothing to draw (every layer empty).
    FormatError
        ezdxf is not installed.
    """
    from .._util import atomic_write

    path = Path(path)
    spots = np.zeros((0, 3)) if spots is None else np.asarray(spots, dtype=np.float64)
    if not len(contours) and not len(spots) and not len(sheets) and area is None:
        raise ProductError(f"{path}: nothing to draw (no contour, spot height, sheet or area); an empty DXF "
                           "is not written")
    try:
        import ezdxf
    except ImportError:
        raise FormatError(f"{path}: DXF output needs ezdxf (pip install 'lidarcat[cad]')") from None
    doc = ezdxf.new("R2013", setup=True)
    msp = doc.modelspace()
    used = set()

    def layer(key: str) -> str:
        cv = convention(key)
        if cv.layer not in used:
            lay = doc.layers.add(cv.layer, color=cv.aci)
            lay.rgb = tuple(int(cv.rgb[i:i + 2], 16) for i in (1, 3, 5))
            lay.dxf.lineweight = _lineweight(cv.width_mm)
            used.add(cv.layer)
        return cv.layer

    for f in contours:
        p = f.get("properties") or {}
        key = "master" if p.get("type") == "master" else "intermediate"
        xy = np.asarray(f["geometry"]["coordinates"], dtype=np.float64)
        closed = len(xy) > 3 and bool(np.all(xy[0] == xy[-1]))
        msp.add_lwpolyline((xy[:-1] if closed else xy).tolist(), close=closed,
                           dxfattribs={"layer": layer(key), "elevation": float(p.get("level_m", 0.0))})
    for e, n, h in spots[:, :3]:
        msp.add_point((e, n, h), dxfattribs={"layer": layer("spot")})
        msp.add_text(f"{h:.2f}", height=1.5, dxfattribs={"layer": layer("label"), "insert": (e + 1.0, n + 1.0, h)})
    for f in sheets:
        ring = np.asarray(f["geometry"]["coordinates"][0], dtype=np.float64)
        msp.add_lwpolyline(ring[:-1].tolist(), close=True, dxfattribs={"layer": layer("sheet")})
        name = (f.get("properties") or {}).get("name")
        if name:
            c = ring[:-1].mean(axis=0)
            msp.add_text(str(name), height=5.0, dxfattribs={"layer": layer("sheet"), "insert": (c[0], c[1])})
    if area is not None:
        x0, y0, x1, y1 = map(float, area)
        msp.add_lwpolyline([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], close=True,
                           dxfattribs={"layer": layer("boundary")})
    with atomic_write(path, "w", encoding="utf-8") as fh:
        doc.write(fh)
    return path


def read_point_layer(path: str | os.PathLike) -> tuple[list[dict[str, Any]], Any]:
    """The Point features of a GeoJSON file (spot heights, as ``lidarcat lidar contours`` writes
    ``OUT_spots.geojson``) and the layer's CRS.

    Returns
    -------
    (features, crs)
        GeoJSON-like Point features (other geometries are left out; ``properties`` always a dict,
        ``h_m`` a finite number or absent) and a :class:`pyproj.CRS` or ``None``.

    Raises
    ------
    lidarcat.errors.FormatError
        Not a GeoJSON FeatureCollection (nesting deeper than 64 levels included, located by line), or
        a Point whose coordinates are not two or three finite numbers within 1e9 m of the origin,
        or whose ``h_m`` is not a number (the feature named).
    """
    from .._util import loads_json, read_text
    from ..lidar.crs import resolve_crs

    path = Path(path)
    doc = loads_json(read_text(path, FormatError), path, FormatError)
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list):
        raise FormatError(f"{path}: not a GeoJSON FeatureCollection (no 'features' list)")
    out = []
    for i, f in enumerate(feats):
        geom = f.get("geometry") if isinstance(f, dict) else None
        if not isinstance(geom, dict) or geom.get("type") != "Point":
            continue
        xy = geom.get("coordinates")
        ok = isinstance(xy, list) and len(xy) in (2, 3) and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in xy)
        if not ok or not np.isfinite(np.asarray(xy, dtype=np.float64)).all() or max(abs(v) for v in xy[:2]) > 1e9:
            raise FormatError(f"{path}: feature {i}: a Point needs coordinates [E, N] or [E, N, h] of finite "
                              f"numbers within 1e9 m of the origin")
        props = f.get("properties") if isinstance(f.get("properties"), dict) else {}
        h = props.get("h_m")
        if h is not None and (isinstance(h, bool) or not isinstance(h, (int, float)) or not np.isfinite(h)):
            raise FormatError(f"{path}: feature {i}: property 'h_m' is not a finite number: {h!r}")
        out.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": list(xy)},
                    "properties": props})
    crs_member = doc.get("crs")
    name = crs_member.get("properties", {}).get("name") if isinstance(crs_member, dict) and \
        isinstance(crs_member.get("properties"), dict) else None
    if name is not None and not isinstance(name, str):
        raise FormatError(f"{path}: member 'crs': the name is not a string: {name!r}")
    try:
        crs = resolve_crs(name) if name else None
    except Exception as ex:  # noqa: BLE001 -- the CRS resolver's own error, located here
        raise FormatError(f"{path}: member 'crs': {ex}") from None
    return out, crs
