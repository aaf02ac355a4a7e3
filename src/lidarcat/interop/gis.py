r"""GIS layer set of an adjusted block: GeoPackage (pyogrio, optional) or GeoJSON.

Layers, each in the survey CRS and carrying the height system in a field
``height_system``:

``photo_centres`` (Point)
    photo, camera, X0, Y0, Z0 (m), omega, phi, kappa (deg) and their sds.
``footprints`` (Polygon)
    the four image corners projected onto the horizontal plane at the mean
    height of the adjusted object points: the corner ``(x, y)`` (mm, eq. 07)
    gives the ray ``d = M^T (x, y, -c)`` and the ground point
    ``X0 + (h_mean - Z0) d / d_z``.
``object_points`` (Point)
    point, role (control/check/tie), E, N, h, sd_E, sd_N, sd_h (m).
``error_ellipses`` (Polygon)
    the horizontal standard error ellipse of each point, from its 2x2 E, N
    covariance (``check_covariance.csv`` for check points, else the sds of
    points.csv without correlation), 72 vertices, magnified by ``ellipse_scale``
    (field ``scale``): semi-axes ``sqrt(lambda_i)``, orientation of the
    eigenvectors.
``residual_vectors`` (LineString)
    for every control point the constraint residual ``v = adjusted - reference``
    from ``residuals.csv``, drawn from the reference position, magnified by
    ``vector_scale``; fields vE, vN, vh (m, true size).
``check_discrepancies`` (LineString)
    adjusted minus reference coordinates of every check point (dE, dN, dh, m),
    drawn like the residuals.

GeoPackage is written when ``pyogrio`` is importable (its wheels bundle GDAL;
``pip install lidarcat[gis]``), else one GeoJSON file per layer with the
``crs`` member GDAL/QGIS read (``urn:ogc:def:crs:EPSG::nnnn``).  Geometries are
encoded here (WKB / GeoJSON), so shapely is not needed.
"""

from __future__ import annotations

import json
import logging
import math
import os
import shutil
import struct
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, read_csv_table, write_text_atomic
from ..errors import FormatError
from .block import Block, block_from_survey
from .rotations import opk_to_matrix

__all__ = ["Layer", "gis_layers", "write_gis", "write_gpkg", "LAYER_NAMES"]

log = logging.getLogger(__name__)

LAYER_NAMES = ("photo_centres", "footprints", "object_points", "error_ellipses", "residual_vectors",
               "check_discrepancies")


@dataclass(frozen=True, eq=False)
class Layer:
    """One vector layer: geometry type, coordinates per feature and attribute columns.

    ``geoms`` holds, per feature, an (k, 2) array: one vertex for a Point, the
    vertices of a LineString, the closed ring of a Polygon.
    """

    name: str
    geometry_type: str
    geoms: list
    fields: dict[str, list]


def _ellipse(c2: np.ndarray, centre: np.ndarray, scale: float, n: int = 72) -> np.ndarray:
    w, v = np.linalg.eigh(c2)
    w = np.sqrt(np.clip(w, 0.0, None)) * scale
    t = np.linspace(0.0, 2 * np.pi, n + 1)
    pts = (v @ (w[:, None] * np.vstack([np.cos(t), np.sin(t)]))).T + centre
    pts[-1] = pts[0]
    return pts


def gis_layers(survey: Any = None, adjustment: str | Path | None = None, *, ellipse_scale: float = 1.0,
               vector_scale: float = 1.0) -> tuple[list[Layer], str, str]:
    """The layers of an adjusted block (survey folder + ``lidarcat adjust`` output folder).

    Without *adjustment* the survey's own orientations and ground points (with their
    reference sds) are written, and the residual and discrepancy layers are empty.

    Returns
    -------
    (layers, crs, height_system)

    Raises
    ------
    FormatError
        A non-georeferenced (local) CRS.
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    from ..survey import read_point_covariance

    adj = Path(adjustment) if adjustment is not None else None
    blk: Block = block_from_survey(survey, adj)
    try:
        CRS.from_user_input(blk.crs)
    except CRSError:
        raise FormatError(f"survey CRS {blk.crs!r} is no CRS pyproj knows (a local model frame?); GIS "
                          f"layers need a georeferenced block") from None
    hs = blk.height_system
    sd_cols: list[str] = []
    sds: dict[str, dict] = {}
    if adj is not None:
        eop = read_csv_table(adj / "eop.csv", required=("photo",), allow_extra=True)
        sd_cols = [c for c in ("sd_X0", "sd_Y0", "sd_Z0", "sd_omega", "sd_phi", "sd_kappa") if eop.has(c)]
        sds = {c: dict(zip(eop.column("photo"), eop.floats(c, required=False))) for c in sd_cols}
    cam_of = dict(zip(blk.photo_ids.tolist(), blk.photo_camera.tolist()))
    ok = np.isfinite(blk.eo).all(axis=1)
    pid = blk.photo_ids[ok].tolist()
    eo = blk.eo[ok]
    fields: dict[str, list] = {"photo": pid, "camera": [cam_of[p] for p in pid],
                               "X0": eo[:, 0].tolist(), "Y0": eo[:, 1].tolist(), "Z0": eo[:, 2].tolist(),
                               "omega_deg": np.degrees(eo[:, 3]).tolist(), "phi_deg": np.degrees(eo[:, 4]).tolist(),
                               "kappa_deg": np.degrees(eo[:, 5]).tolist()}
    for c in sd_cols:
        fields[c + ("" if c in ("sd_X0", "sd_Y0", "sd_Z0") else "_deg")] = [sds[c].get(p, math.nan) for p in pid]
    fields["height_system"] = [hs] * len(pid)
    layers = [Layer("photo_centres", "Point", [e[None, :2] for e in eo], fields)]

    if adj is not None:
        pts = read_csv_table(adj / "points.csv", required=("point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "role"),
                             allow_extra=True)
        p_ids = pts.column("point")
        enh = np.column_stack([pts.floats(c) for c in ("E", "N", "h")])
        psd = np.column_stack([pts.floats(c, required=False) for c in ("sd_E", "sd_N", "sd_h")])
        role = pts.column("role")
    else:  # an unadjusted survey: its ground points with their reference sds
        p_ids, enh, psd = blk.ground_ids.tolist(), blk.ground_m.reshape(-1, 3), blk.ground_sd_m.reshape(-1, 3)
        role = ["ground"] * len(p_ids)
    h_mean = float(np.mean(enh[:, 2])) if len(enh) else 0.0
    foot = []
    for p, e in zip(pid, eo):
        cam = blk.cameras[cam_of[p]]
        w, hh = cam.columns_px, cam.rows_px
        corners = np.asarray(cam.pixel_to_photo([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, hh - 0.5], [-0.5, hh - 0.5]]))
        d = (opk_to_matrix(e[3:]).T @ np.column_stack([corners, np.full(4, -cam.focal_length_mm)]).T).T
        g = e[:2] + (h_mean - e[2]) * d[:, :2] / d[:, 2:3]
        foot.append(np.vstack([g, g[:1]]))
    layers.append(Layer("footprints", "Polygon", foot, {"photo": pid, "plane_h_m": [h_mean] * len(pid),
                                                         "height_system": [hs] * len(pid)}))
    layers.append(Layer("object_points", "Point", [x[None, :2] for x in enh], {
        "point": p_ids, "role": role, "E": enh[:, 0].tolist(), "N": enh[:, 1].tolist(), "h": enh[:, 2].tolist(),
        "sd_E": psd[:, 0].tolist(), "sd_N": psd[:, 1].tolist(), "sd_h": psd[:, 2].tolist(),
        "height_system": [hs] * len(p_ids)}))
    cov = np.zeros((len(p_ids), 2, 2))
    cov[:, 0, 0], cov[:, 1, 1] = np.nan_to_num(psd[:, 0]) ** 2, np.nan_to_num(psd[:, 1]) ** 2
    full = np.zeros(len(p_ids), bool)
    if adj is not None and (adj / "check_covariance.csv").is_file():
        ids, c = read_point_covariance(adj / "check_covariance.csv")
        pos = {p: i for i, p in enumerate(p_ids)}
        for k, q in enumerate(ids):
            if q in pos:
                cov[pos[q]] = c[3 * k:3 * k + 2, 3 * k:3 * k + 2]
                full[pos[q]] = True
    layers.append(Layer("error_ellipses", "Polygon", [_ellipse(cv, x[:2], ellipse_scale) for cv, x in zip(cov, enh)], {
        "point": p_ids, "role": role, "scale": [float(ellipse_scale)] * len(p_ids),
        "correlated": [bool(f) for f in full],
        "semi_major_m": [float(np.sqrt(max(np.linalg.eigvalsh(cv)[1], 0))) for cv in cov],
        "semi_minor_m": [float(np.sqrt(max(np.linalg.eigvalsh(cv)[0], 0))) for cv in cov]}))
    if adj is not None and (adj / "residuals.csv").is_file():
        res = read_csv_table(adj / "residuals.csv", required=("kind", "point", "vE_m", "vN_m", "vh_m"),
                             allow_extra=True)
        kinds, res_pts = res.column("kind"), res.column("point")
        v = np.column_stack([res.floats(c, required=False) for c in ("vE_m", "vN_m", "vh_m")])
    else:
        if adj is not None:
            log.warning("%s: no residuals.csv; the residual_vectors layer is empty", adj)
        kinds, res_pts, v = [], [], np.empty((0, 3))
    sel = [i for i, k in enumerate(kinds) if k == "control"]
    rpts = [res_pts[i] for i in sel]
    gpos = {p: i for i, p in enumerate(blk.ground_ids.tolist())}
    geo, keep = [], []
    for i, q in zip(sel, rpts):
        if q in gpos:
            ref = blk.ground_m[gpos[q], :2]
            geo.append(np.vstack([ref, ref + vector_scale * np.nan_to_num(v[i, :2])]))
            keep.append(i)
    layers.append(Layer("residual_vectors", "LineString", geo, {
        "point": [res_pts[i] for i in keep], "vE_m": [float(v[i, 0]) for i in keep],
        "vN_m": [float(v[i, 1]) for i in keep], "vh_m": [float(v[i, 2]) for i in keep],
        "scale": [float(vector_scale)] * len(keep)}))
    chk = [i for i, r in enumerate(role) if r == "check" and p_ids[i] in gpos]
    dis = [enh[i] - blk.ground_m[gpos[p_ids[i]]] for i in chk]
    refs = [blk.ground_m[gpos[p_ids[i]], :2] for i in chk]
    layers.append(Layer("check_discrepancies", "LineString",
                        [np.vstack([ref, ref + vector_scale * d[:2]]) for ref, d in zip(refs, dis)], {
        "point": [p_ids[i] for i in chk], "dE_m": [float(d[0]) for d in dis], "dN_m": [float(d[1]) for d in dis],
        "dh_m": [float(d[2]) for d in dis], "scale": [float(vector_scale)] * len(chk),
        "height_system": [hs] * len(chk)}))
    return layers, blk.crs, hs


def _wkb(kind: str, xy: np.ndarray) -> bytes:
    xy = np.asarray(xy, dtype="<f8")
    if kind == "Point":
        return struct.pack("<BI", 1, 1) + xy[0].tobytes()
    if kind == "LineString":
        return struct.pack("<BII", 1, 2, len(xy)) + xy.tobytes()
    return struct.pack("<BIII", 1, 3, 1, len(xy)) + xy.tobytes()


def _geojson_geom(kind: str, xy: np.ndarray) -> dict:
    c = np.asarray(xy).tolist()
    if kind == "Point":
        return {"type": "Point", "coordinates": c[0]}
    if kind == "LineString":
        return {"type": "LineString", "coordinates": c}
    return {"type": "Polygon", "coordinates": [c]}


def _have_pyogrio() -> bool:
    try:
        import pyogrio  # noqa: F401
    except ImportError:
        return False
    return True


def _write_gpkg_layers(target: Path, layers: list[Layer], crs_wkt: str) -> None:
    """Write *layers* into the (new) GeoPackage *target* with pyogrio."""
    from pyogrio.raw import write

    for lay in layers:
        names = list(lay.fields)
        data = [np.asarray(lay.fields[k], dtype=object if isinstance(
            (lay.fields[k] or [""])[0], str) else None) for k in names]
        geom = np.array([_wkb(lay.geometry_type, g) for g in lay.geoms], dtype=object)
        write(str(target), geom, data, names, layer=lay.name, driver="GPKG",
              geometry_type=lay.geometry_type, crs=crs_wkt, append=target.exists())


def write_gpkg(path: str | Path, layers: list[Layer], crs: Any) -> Path:
    """Write *layers* as one GeoPackage file *path* (atomically: a temporary sibling, then renamed).

    Parameters
    ----------
    path : path-like
        The ``.gpkg`` file; an existing one is replaced whole once the new one is complete.
    layers : list of Layer
    crs : CRS-like
        CRS of every layer (anything :class:`pyproj.CRS` accepts).

    Raises
    ------
    FormatError
        pyogrio is not installed.
    """
    from pyproj import CRS

    if not _have_pyogrio():
        raise FormatError(f"{path}: GeoPackage output needs pyogrio (pip install 'lidarcat[gis]'); "
                          "or write GeoJSON")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    wkt = CRS.from_user_input(crs).to_wkt()
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent))
    try:
        part = tmp / path.name
        _write_gpkg_layers(part, layers, wkt)
        os.replace(part, path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    log.info("wrote %d layers to %s (GeoPackage)", len(layers), path)
    return path


def write_gis(layers: list[Layer], crs: str, folder: str | Path, *, fmt: str = "auto",
              name: str = "block") -> Path:
    """Write *layers* into *folder* (atomically): ``<name>.gpkg`` or ``<name>_<layer>.geojson``.

    Parameters
    ----------
    fmt : {"auto", "gpkg", "geojson"}
        ``auto``: GeoPackage when pyogrio is installed, else GeoJSON.

    Raises
    ------
    FormatError
        ``gpkg`` asked for without pyogrio; unknown *fmt*.
    """
    from pyproj import CRS

    if fmt not in ("auto", "gpkg", "geojson"):
        raise FormatError(f"GIS format {fmt!r} is not auto, gpkg or geojson")
    if fmt == "gpkg" and not _have_pyogrio():
        raise FormatError("GeoPackage output needs pyogrio (pip install 'lidarcat[gis]'); or use geojson")
    use_gpkg = fmt == "gpkg" or (fmt == "auto" and _have_pyogrio())
    c = CRS.from_user_input(crs)
    folder = Path(folder)
    with atomic_dir(folder) as tmp:
        if use_gpkg:
            _write_gpkg_layers(tmp / f"{name}.gpkg", layers, c.to_wkt())
        else:
            auth = c.to_authority()
            crs_name = f"urn:ogc:def:crs:{auth[0]}::{auth[1]}" if auth else c.to_wkt()
            for lay in layers:
                feats = [{"type": "Feature", "geometry": _geojson_geom(lay.geometry_type, g),
                          "properties": {k: (None if isinstance(vals[i], float) and not math.isfinite(vals[i])
                                             else vals[i]) for k, vals in lay.fields.items()}}
                         for i, g in enumerate(lay.geoms)]
                write_text_atomic(tmp / f"{name}_{lay.name}.geojson", json.dumps(
                    {"type": "FeatureCollection", "name": lay.name,
                     "crs": {"type": "name", "properties": {"name": crs_name}}, "features": feats}) + "\n")
    log.info("wrote %d GIS layers to %s (%s)", len(layers), folder, "GeoPackage" if use_gpkg else "GeoJSON")
    return folder
