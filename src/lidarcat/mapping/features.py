"""Features digitised on a photo (pixels in) and their monorestituted versions (map coordinates out).

Input, in pixels of one photo (column to the right, row down, origin at the
centre of the top-left pixel, as everywhere in lidarcat):

* **GeoJSON** -- a FeatureCollection whose coordinates are ``[col_px, row_px]``
  (Point, LineString, Polygon with one ring, or their Multi- forms are refused:
  digitise one part per feature); properties ``id`` and ``class`` are used
  when present (default: the feature's position in the file, ``""``);
* **CSV** -- one row per vertex, header ``feature,col_px,row_px`` plus the
  optional ``class`` and ``geometry`` (``point``, ``line`` or ``polygon``; default:
  a point for a single vertex, else a line); rows of a feature are consecutive.

Output (:func:`features_geojson`, :func:`features_rows`): the same features with
E, N, h coordinates in the survey CRS, the status of every vertex
(:data:`lidarcat.mapping.monoplot.STATUSES`) and its propagated standard deviations.
A feature whose vertices are not all ``ok`` keeps its properties but has a
null geometry and the first failing status -- never a half-placed outline.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import loads_json, read_csv_table, read_text
from ..errors import LidarcatError, SurveyError, location

__all__ = ["ImageFeature", "read_features", "features_geojson", "features_rows", "FEATURE_CSV_COLUMNS",
           "FeatureError"]

#: columns of the per-vertex CSV output
FEATURE_CSV_COLUMNS = ("feature", "class", "vertex", "col_px", "row_px", "E", "N", "h", "sd_E", "sd_N",
                       "sd_h", "status")


class FeatureError(SurveyError):
    """A feature file is invalid (names the file and the feature or line)."""


@dataclass(frozen=True, eq=False)
class ImageFeature:
    """A feature digitised on a photo.

    Attributes
    ----------
    id : str
    cls : str
        Feature class (e.g. ``building``, ``road``), free text.
    geometry : {"point", "line", "polygon"}
    colrow_px : (k, 2) float array
        Vertices, px (a polygon's ring without the closing repeat).
    """

    id: str
    cls: str
    geometry: str
    colrow_px: np.ndarray


def _geojson_features(path: Path) -> list[ImageFeature]:
    doc = loads_json(read_text(path, FeatureError), path, FeatureError)
    feats = doc.get("features") if isinstance(doc, dict) else None
    if not isinstance(feats, list):
        raise FeatureError(f"{path}: not a GeoJSON FeatureCollection (no 'features' list)")
    out = []
    for i, f in enumerate(feats, start=1):
        props = f.get("properties") if isinstance(f, dict) else None
        geom = f.get("geometry") if isinstance(f, dict) else None
        if not (isinstance(f, dict) and isinstance(props or {}, dict) and isinstance(geom or {}, dict)):
            raise FeatureError(f"{path}: feature {i} is not a GeoJSON Feature object (with object "
                               f"'properties' and 'geometry')")
        props, geom = props or {}, geom or {}
        fid = str(props.get("id", f.get("id", i)))
        kind = geom.get("type")
        coords = geom.get("coordinates")
        where = f"{path}: feature {fid!r}"
        try:
            if kind == "Point":
                arr, g = np.asarray([coords], dtype=float), "point"
            elif kind == "LineString":
                arr, g = np.asarray(coords, dtype=float), "line"
            elif kind == "Polygon":
                if len(coords) != 1:
                    raise FeatureError(f"{where}: polygons with holes are not supported; digitise the "
                                       f"outline only")
                arr, g = np.asarray(coords[0], dtype=float), "polygon"
                if len(arr) > 1 and np.array_equal(arr[0], arr[-1]):
                    arr = arr[:-1]
            else:
                raise FeatureError(f"{where}: geometry type {kind!r}; use Point, LineString or Polygon "
                                   f"(one part per feature)")
        except (TypeError, ValueError) as ex:
            if isinstance(ex, FeatureError):
                raise
            raise FeatureError(f"{where}: coordinates are not [col_px, row_px] numbers") from ex
        if arr.ndim != 2 or arr.shape[1] < 2 or len(arr) == 0 or not np.isfinite(arr[:, :2]).all():
            raise FeatureError(f"{where}: coordinates are not [col_px, row_px] numbers")
        if g == "line" and len(arr) < 2 or g == "polygon" and len(arr) < 3:
            raise FeatureError(f"{where}: a {g} needs at least {2 if g == 'line' else 3} vertices")
        out.append(ImageFeature(fid, str(props.get("class", "")), g, arr[:, :2]))
    return out


def _csv_features(path: Path) -> list[ImageFeature]:
    t = read_csv_table(path, required=("feature", "col_px", "row_px"), optional=("class", "geometry"))
    col, row = t.floats("col_px"), t.floats("row_px")
    ids = t.column("feature")
    cls = t.column("class") if t.has("class") else [""] * len(ids)
    geo = t.column("geometry") if t.has("geometry") else [""] * len(ids)
    out: list[ImageFeature] = []
    seen: set[str] = set()
    k = 0
    while k < len(ids):
        j = k
        while j < len(ids) and ids[j] == ids[k]:
            j += 1
        fid = ids[k]
        if fid in seen:
            raise FeatureError(f"{location(path, t.lines[k], 'feature')}: rows of feature {fid!r} are not "
                               f"consecutive")
        seen.add(fid)
        g = geo[k].strip().lower() or ("point" if j - k == 1 else "line")
        if g not in ("point", "line", "polygon"):
            raise FeatureError(f"{location(path, t.lines[k], 'geometry')}: {geo[k]!r}; use point, line or "
                               f"polygon")
        need = {"point": 1, "line": 2, "polygon": 3}[g]
        if (g == "point" and j - k != 1) or j - k < need:
            raise FeatureError(f"{location(path, t.lines[k], 'feature')}: feature {fid!r} is a {g} with "
                               f"{j - k} vertices")
        out.append(ImageFeature(fid, cls[k], g, np.column_stack([col[k:j], row[k:j]])))
        k = j
    return out


def read_features(path: str | os.PathLike) -> list[ImageFeature]:
    """Read features digitised on a photo from ``.geojson``/``.json`` or ``.csv`` (module docstring).

    Raises
    ------
    FeatureError
        Missing file, unknown suffix, bad JSON/CSV, unsupported geometry, too
        few vertices, non-numeric coordinates: names the file and the feature
        (GeoJSON) or line (CSV).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".geojson", ".json"):
        feats = _geojson_features(path)
    elif suffix == ".csv":
        feats = _csv_features(path)
    else:
        raise FeatureError(f"{path}: unknown feature file type {suffix!r}; use .geojson or .csv")
    if not feats:
        raise FeatureError(f"{path}: no feature")
    ids = [f.id for f in feats]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise FeatureError(f"{path}: duplicate feature id(s) {', '.join(dup[:5])}")
    return feats


def _split(features: list[ImageFeature], result: Any) -> list[tuple[ImageFeature, slice]]:
    out, k = [], 0
    for f in features:
        out.append((f, slice(k, k + len(f.colrow_px))))
        k += len(f.colrow_px)
    if k != len(result):
        raise LidarcatError(f"{k} feature vertices but {len(result)} monoplot results")
    return out


def features_geojson(features: list[ImageFeature], result: Any, crs: Any = None,
                     extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """GeoJSON FeatureCollection of monorestituted features (E, N, h; survey CRS as a ``crs`` member)."""
    out_feats = []
    for f, sl in _split(features, result):
        st = [str(s) for s in result.status[sl]]
        enh = np.round(result.enh[sl], 4).tolist()
        ok = all(s == "ok" for s in st)
        geom: dict[str, Any] | None = None
        if ok:
            if f.geometry == "point":
                geom = {"type": "Point", "coordinates": enh[0]}
            elif f.geometry == "line":
                geom = {"type": "LineString", "coordinates": enh}
            else:
                geom = {"type": "Polygon", "coordinates": [enh + [enh[0]]]}
        sd = result.sd[sl]
        props = {"id": f.id, "class": f.cls, "status": "ok" if ok else next(s for s in st if s != "ok"),
                 "vertex_status": st,
                 "sd_E_m": _nums(sd[:, 0]), "sd_N_m": _nums(sd[:, 1]), "sd_h_m": _nums(sd[:, 2])}
        out_feats.append({"type": "Feature", "properties": props, "geometry": geom})
    doc: dict[str, Any] = {"type": "FeatureCollection", "features": out_feats}
    if extra:
        doc["lidarcat"] = extra
    if crs is not None:
        from ..lidar.crs import geojson_crs_member

        doc["crs"] = geojson_crs_member(crs)
    return doc


def _nums(values: np.ndarray) -> list[float | None]:
    """Rounded floats for JSON; None (null) where a vertex has no value (JSON has no NaN)."""
    return [round(float(v), 4) if np.isfinite(v) else None for v in values]


def features_rows(features: list[ImageFeature], result: Any) -> list[list[Any]]:
    """Rows of :data:`FEATURE_CSV_COLUMNS`: one per vertex."""
    rows = []
    for f, sl in _split(features, result):
        for v, k in enumerate(range(sl.start, sl.stop)):
            rows.append([f.id, f.cls, v, *f.colrow_px[v], *result.enh[k], *result.sd[k], result.status[k]])
    return rows
