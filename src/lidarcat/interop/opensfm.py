r"""OpenSfM ``reconstruction.json`` + ``tracks.csv`` and ``ground_control_points.json``: read and write.

Conventions (OpenSfM ``doc/source/geometry.rst``)
-------------------------------------------------
* A shot's ``rotation`` is an **angle-axis** vector and, with ``translation``,
  maps world to camera, ``x_cam = R x_world + t``; camera x right, **y down,
  z forward**.  So lidarcat's ``M = F R`` (``F = diag(1, -1, -1)``) and
  ``X0 = -R^T t`` (:mod:`lidarcat.interop.rotations`).
* The world frame is a local **topocentric ENU** frame (x east, y north, z up) at
  ``reference_lla`` on the WGS84 ellipsoid; the survey gets it as a PROJ
  pipeline description in ``crs`` and heights are ``ellipsoidal`` (OpenSfM
  converts lat/lon/alt with the WGS84 ellipsoid, ``geo.ecef_from_lla``).
* Image points are **normalised**: origin at the image centre, x right, y down,
  divided by ``S = max(width, height)``.  In lidarcat pixels (origin at the centre
  of the top-left pixel) ``col = (W - 1)/2 + S x_n``, and the COLMAP-style corner
  pixel is ``col + 0.5``.
* Cameras: ``perspective`` (``focal``, ``k1``, ``k2``: ``x_n = f d(r) x``,
  ``d = 1 + k1 r^2 + k2 r^4``) and ``brown`` (``focal_x``, ``focal_y``,
  ``c_x``, ``c_y``, ``k1``, ``k2``, ``k3``, ``p1``, ``p2``: ``x_n = f_x x_d + c_x``
  with OpenCV's distortion), focal and principal point in units of ``S``.
  ``fisheye`` (``focal``, ``k1``, ``k2``) and ``fisheye_opencv`` (``focal_x``, ``focal_y``,
  ``c_x``, ``c_y``, ``k1``..``k4``) are the equidistant Kannala-Brandt fisheye
  (``theta_d = theta (1 + k1 theta^2 + ...)``, ``x_n = f theta_d X / rho + c``).
  All map onto lidarcat's camera as in :mod:`lidarcat.interop.colmap`
  (pixels ``fx = f S``, ``cx = W/2 + c_x S``); the model is kept as the source
  model and the observations are made ideal through it exactly
  (:mod:`lidarcat.interop.cameras`).  Other projection types (spherical, dual,
  fisheye62, ...) are refused with a located error.
* Rigs: a reconstruction's ``rig_cameras`` (sensor from rig) and ``rig_instances``
  (rig from world, ``rig_camera_ids`` shot -> rig camera), else the dataset's
  ``rig_cameras.json`` and ``rig_assignments.json`` beside it, become the block's
  rigs (:mod:`lidarcat.interop.rigs`); the export writes them back.

Writing produces one reconstruction with the block's cameras (``perspective`` or
``brown`` when the block came from a Brown-type model, else the undistorted
``brown`` pinhole), shots, points and a ``tracks.csv`` (``OPENSFM_TRACKS_VERSION_v2``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from .._util import atomic_dir, read_text, write_text_atomic
from ..errors import FormatError
from .._util.tables import JSON_MAX_DEPTH as MAX_JSON_DEPTH, json_too_deep, parse_float
from .._util.values import parse_number, parse_whole, value_problem
from ._text import format_error, sd_problem
from .block import Block, require_orientations
from .merge import GroundControl
from .cameras import MAX_RAY_ANGLE_DEG, check_source_model, ideal_observations, pinhole_camera
from .lens import export_cameras, notes, observed_pixels
from .rigs import opensfm_rig_entries, rigs_from_opensfm
from .rotations import opk_to_world_to_cv, world_to_cv_to_opk

__all__ = ["read_opensfm", "read_opensfm_gcp", "read_opensfm_config", "gcp_sd_from_config", "write_opensfm",
           "opensfm_camera", "opensfm_camera_dict",
           "topocentric_crs", "reference_lla", "to_topocentric", "OPENSFM_PROJECTIONS"]

log = logging.getLogger(__name__)

OPENSFM_PROJECTIONS = ("perspective", "brown", "fisheye", "fisheye_opencv")


def topocentric_crs(lat_deg: float, lon_deg: float, alt_m: float) -> str:
    """Description of OpenSfM's topocentric frame as a PROJ pipeline from WGS84 lon/lat/h (deg, m).

    >>> topocentric_crs(52.5, 13.4, 0.0)[:40]
    'local ENU (OpenSfM reference_lla): +proj'
    """
    return (f"local ENU (OpenSfM reference_lla): {_pipeline(lat_deg, lon_deg, alt_m)}")


def reference_lla(crs: str) -> dict[str, float] | None:
    """OpenSfM's ``reference_lla`` of a topocentric CRS written by :func:`topocentric_crs` (None for
    any other CRS).

    >>> reference_lla(topocentric_crs(52.5, 13.4, 34.0))
    {'latitude': 52.5, 'longitude': 13.4, 'altitude': 34.0}
    """
    import re

    m = re.search(r"\+proj=topocentric \+ellps=WGS84 \+lat_0=(\S+) \+lon_0=(\S+) \+h_0=(\S+)", crs)
    if m is None:
        return None
    return {"latitude": float(m.group(1)), "longitude": float(m.group(2)), "altitude": float(m.group(3))}


def _pipeline(lat: float, lon: float, alt: float) -> str:
    return ("+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad +step +proj=cart "
            f"+ellps=WGS84 +step +proj=topocentric +ellps=WGS84 +lat_0={lat!r} +lon_0={lon!r} +h_0={alt!r}")


def _json_depth_error(path: Path, text: str) -> FormatError | None:
    """A located error when arrays/objects nest deeper than :data:`MAX_JSON_DEPTH`, else None."""
    deep = json_too_deep(text, MAX_JSON_DEPTH)
    if deep is None:
        return None
    return format_error(path, deep[0], None, f"arrays/objects nested deeper than {MAX_JSON_DEPTH} "
                        f"levels (column {deep[1]}); OpenSfM and ODM files nest a few levels")


def _load_json(path: Path) -> Any:
    text = read_text(path, FormatError)
    deep = _json_depth_error(path, text)
    if deep is not None:
        raise deep
    try:
        return json.loads(text)
    except json.JSONDecodeError as ex:
        raise format_error(path, ex.lineno, None, f"invalid JSON: {ex.msg} (column {ex.colno})") from None
    except (ValueError, RecursionError) as ex:  # an integer of over 4,300 digits
        raise format_error(path, None, None, f"invalid JSON: {str(ex)[:120]}") from None


def _short(v: Any) -> str:
    """*v* for a message: its repr, at most 40 characters."""
    r = repr(v)
    return r if len(r) <= 40 else r[:37] + "..."


def _json_line(text: str, key: str) -> int | None:
    """Line of the first occurrence of ``"key"`` in a JSON text (for messages)."""
    i = text.find(json.dumps(key))
    return None if i < 0 else text.count("\n", 0, i) + 1


def _num(path: Path, text: str, where: str, name: str, v: Any, kind: str | None = None) -> float:
    """*v* as a finite number in the sane range of *kind* (:data:`lidarcat._util.values.VALUE_RANGES`)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, int) and abs(v) > 10 ** 18) \
            or not math.isfinite(v):
        shown = repr(v) if not isinstance(v, (int, str)) or len(str(v)) <= 40 else f"{str(v)[:20]}..."
        raise format_error(path, _json_line(text, where), name, f"{shown} is not a finite number ({where})")
    problem = value_problem(float(v), kind) if kind else None
    if problem:
        raise format_error(path, _json_line(text, where), name, f"{problem} ({where})")
    return float(v)


def _vec(path: Path, text: str, where: str, name: str, v: Any, n: int, kind: str | None = None) -> np.ndarray:
    if not isinstance(v, list) or len(v) != n:
        raise format_error(path, _json_line(text, where), name, f"expected a list of {n} numbers ({where})")
    return np.array([_num(path, text, where, name, x, kind) for x in v])


def opensfm_camera(path: Path, text: str, cid: str, c: Any, pixel_size_mm: float | None):
    """lidarcat's stand-in camera and the source model of one OpenSfM camera dict *c* (``cameras`` of a
    reconstruction.json, or an OpenDroneMap ``cameras.json``), errors located in *path* (its *text*).

    Raises
    ------
    FormatError
        ``FILE:LINE: field 'NAME': camera 'ID': ...``: an unsupported projection, a missing or
        non-numeric field, a fisheye out of its valid range.
    """
    if not isinstance(c, dict):
        raise format_error(path, _json_line(text, cid), "cameras", f"camera {cid!r} is not an object")
    kind = c.get("projection_type")
    if kind not in OPENSFM_PROJECTIONS:
        raise format_error(path, _json_line(text, cid), "projection_type",
                           f"camera {cid!r}: projection {kind!r} is not supported "
                           f"(supported: {', '.join(OPENSFM_PROJECTIONS)})")
    num = lambda k, d=None: _num(path, text, cid, k, c.get(k, d))  # noqa: E731
    w, h = (int(_num(path, text, cid, k, c.get(k), "image_px")) for k in ("width", "height"))
    if w < 1 or h < 1:
        raise format_error(path, _json_line(text, cid), "width", f"camera {cid!r}: image size {w}x{h}")
    s = max(w, h)
    if kind in ("perspective", "fisheye"):
        fx = fy = num("focal") * s
        cx, cy = w / 2, h / 2
        dist = {"k1": num("k1", 0.0), "k2": num("k2", 0.0)}
    elif kind == "fisheye_opencv":
        fx, fy = num("focal_x") * s, num("focal_y") * s
        cx, cy = w / 2 + num("c_x", 0.0) * s, h / 2 + num("c_y", 0.0) * s
        dist = {k: num(k, 0.0) for k in ("k1", "k2", "k3", "k4")}
    else:
        fx, fy = num("focal_x") * s, num("focal_y") * s
        cx, cy = w / 2 + num("c_x", 0.0) * s, h / 2 + num("c_y", 0.0) * s
        dist = {k: num(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2")}
    if fx <= 0 or fy <= 0:
        raise format_error(path, _json_line(text, cid), "focal", f"camera {cid!r}: focal must be positive")
    for k, v in (("focal", fx), ("focal", fy), ("c_x", cx), ("c_y", cy)):
        problem = value_problem(v, "pixel_px")
        if problem:
            raise format_error(path, _json_line(text, cid), k, f"camera {cid!r}: {problem} (times the image size)")
    fisheye = kind.startswith("fisheye")
    cam, model = pinhole_camera(cid, fx, fy, cx, cy, w, h, pixel_size_mm=pixel_size_mm,
                                model=f"OpenSfM {kind}", source=f"{path.name}: camera {cid!r} ({kind})",
                                dist=dist, kind="fisheye" if fisheye else "brown")
    check_source_model(cid, model, f"{path}:{_json_line(text, cid)}")
    model["opensfm"] = kind
    return cam, model


def read_opensfm(reconstruction: str | Path, tracks: str | Path | None = None, *, index: int = 0,
                 pixel_size_mm: float | None = None, name: str | None = None,
                 cameras: str | Path | None = None) -> Block:
    """Read one reconstruction of an OpenSfM ``reconstruction.json`` and its ``tracks.csv``.

    Parameters
    ----------
    reconstruction : path
    tracks : path, optional
        ``tracks.csv`` (default: ``tracks.csv`` next to the reconstruction, if any).
        Only observations of shots and points of the reconstruction are kept.  A
        reconstruction without ``points`` (orientation only, as OpenDroneMap writes) gives
        a block of oriented photos without observations (:mod:`lidarcat.interop.convert`
        writes it to every format but a survey folder).
    index : int
        Which reconstruction of the list (OpenSfM writes one per connected component).
    pixel_size_mm : float, optional
        Pixel pitch given to the cameras (OpenSfM knows none; default
        :func:`lidarcat.interop.cameras.default_pixel_size_mm`).
    cameras : path, optional
        An OpenDroneMap ``cameras.json`` (camera id without OpenSfM's ``v2 `` prefix -> OpenSfM
        camera dict): its models replace the reconstruction's cameras of the same id, and the
        observations are made ideal through them.

    Raises
    ------
    FormatError
        Invalid JSON (line, column), a missing or non-numeric field (the line of
        the shot/camera/point id and the field), an unsupported projection, a
        malformed tracks.csv line (``FILE:LINE: field``), a tracks.csv that measures
        no point of the reconstruction on two shots.
    """
    path = Path(reconstruction)
    text = read_text(path, FormatError)
    data = _load_json(path)
    if not isinstance(data, list) or not data:
        raise format_error(path, 1, None, "expected a JSON list of reconstructions")
    if not 0 <= index < len(data):
        raise FormatError(f"{path}: reconstruction {index} requested, the file has {len(data)}")
    rec = data[index]
    if not isinstance(rec, dict):
        raise format_error(path, 1, None, f"reconstruction {index} is not an object")
    if "points" not in rec:  # an orientation-only reconstruction (OpenDroneMap writes them)
        rec = {**rec, "points": {}}
    for key in ("cameras", "shots", "points"):
        if not isinstance(rec.get(key), dict):
            raise format_error(path, _json_line(text, key) or 1, key,
                               f"missing or not an object in reconstruction {index}")
    cams, models = {}, {}
    odm = {} if cameras is None else _odm_cameras(Path(cameras), rec["cameras"])
    for cid, c in rec["cameras"].items():
        if cid in odm:
            cam, models[cid] = opensfm_camera(*odm[cid], pixel_size_mm)
            cams[cid] = dataclasses.replace(cam, id=cid)
        else:
            cams[cid], models[cid] = opensfm_camera(path, text, cid, c, pixel_size_mm)
    photo, pcam, eo = [], [], []
    for sid, sh in rec["shots"].items():
        if not isinstance(sh, dict):
            raise format_error(path, _json_line(text, sid), "shots", f"shot {sid!r} is not an object")
        rv = _vec(path, text, sid, "rotation", sh.get("rotation"), 3)
        tv = _vec(path, text, sid, "translation", sh.get("translation"), 3, "coordinate_m")
        cid = sh.get("camera")
        if not isinstance(cid, str) or cid not in cams:
            raise format_error(path, _json_line(text, sid), "camera", f"shot {sid!r}: camera {cid!r} is not defined")
        r = Rotation.from_rotvec(rv).as_matrix()
        photo.append(sid)
        pcam.append(cid)
        eo.append(np.concatenate([-r.T @ tv, world_to_cv_to_opk(r)]))
    pids, pxyz = [], []
    for pid, pt in rec["points"].items():
        pids.append(str(pid))
        pxyz.append(_vec(path, text, pid, "coordinates", pt.get("coordinates") if isinstance(pt, dict) else None, 3,
                         "coordinate_m"))
    lla = rec.get("reference_lla")
    if isinstance(lla, dict):
        lat, lon, alt = (_num(path, text, "reference_lla", k, lla.get(k), kind) for k, kind in
                         (("latitude", "latitude_deg"), ("longitude", "longitude_deg"), ("altitude", "height_m")))
        crs, hs = topocentric_crs(lat, lon, alt), "ellipsoidal"
    else:
        crs, hs = "local: OpenSfM reconstruction frame (no reference_lla)", "unspecified"
    o_ph: list[str] = []
    o_pt: list[str] = []
    o_xy: list[list[float]] = []
    tpath = Path(tracks) if tracks is not None else path.with_name("tracks.csv")
    if tracks is not None or tpath.is_file():
        o_ph, o_pt, o_xy = _read_tracks(tpath, set(photo), set(pids))
        if pids and (not o_pt or max(Counter(o_pt).values()) < 2):
            raise FormatError(f"{tpath}: no measurements: no point of {path.name} is measured on two of its "
                              f"shots ({len(o_pt)} usable measurement(s) of {len(pids)} points; is the file "
                              f"truncated?); write tracks.csv again with OpenSfM, or remove it to import the "
                              f"orientations only")
    cam_of = dict(zip(photo, pcam))
    xy_n = np.array(o_xy, dtype=float).reshape(-1, 2)
    corner = np.empty_like(xy_n)
    mm = np.empty_like(xy_n)
    keep = np.ones(len(xy_n), dtype=bool)
    sd = np.full_like(xy_n, np.nan)
    oc = np.array([cam_of[p] for p in o_ph], dtype=object)
    for cid, m in models.items():
        rows = oc == cid
        if rows.any():
            s = max(m["w"], m["h"])
            corner[rows] = xy_n[rows] * s + [m["w"] / 2, m["h"] / 2]
            mm[rows], keep[rows], sd[rows] = ideal_observations(corner[rows], cams[cid], m, where=str(tpath))
    description = f"imported from OpenSfM {path.name} (reconstruction {index})"
    if not keep.all():
        description += (f"; {int((~keep).sum())} observation(s) of rays beyond {MAX_RAY_ANGLE_DEG:g} deg from a "
                        f"fisheye's axis skipped")
        corner, mm, sd = corner[keep], mm[keep], sd[keep]
        o_ph = [p for p, k in zip(o_ph, keep) if k]
        o_pt = [p for p, k in zip(o_pt, keep) if k]
    rigs = _read_rigs(path, rec, cam_of, {c: (m["w"], m["h"]) for c, m in models.items()})
    return Block(name=name or path.stem, crs=crs, height_system=hs, cameras=cams,
                 photo_ids=np.array(photo, dtype=str), photo_camera=np.array(pcam, dtype=str),
                 eo=np.array(eo).reshape(-1, 6), obs_photo=np.array(o_ph, dtype=str),
                 obs_point=np.array(o_pt, dtype=str), obs_px=corner - 0.5, obs_mm=mm,
                 point_ids=np.array(pids, dtype=str), points_m=np.array(pxyz).reshape(-1, 3),
                 description=description, source_models=models, rigs=rigs,
                 obs_sd_mm=sd if np.isfinite(sd).any() else None)


def _read_rigs(path: Path, rec: dict, shot_cameras: dict[str, str], sizes: dict[str, tuple[int, int]]):
    """The rigs of a reconstruction (``rig_cameras`` + ``rig_instances``), else of the dataset's
    ``rig_cameras.json`` + ``rig_assignments.json`` beside it (:func:`lidarcat.interop.rigs.rigs_from_opensfm`);
    None without rigs."""
    if isinstance(rec.get("rig_instances"), dict) and rec.get("rig_cameras"):
        inst = {}
        for iid, ri in rec["rig_instances"].items():
            ids = ri.get("rig_camera_ids") if isinstance(ri, dict) else None
            if not isinstance(ids, dict) or not all(isinstance(v, str) for v in ids.values()):
                raise FormatError(f"{path}: rig instance {str(iid)[:40]!r}: field 'rig_camera_ids': expected an object "
                                  f"shot -> rig camera id")
            inst[str(iid)] = list(ids.items())
        rigs = rigs_from_opensfm(rec["rig_cameras"], inst, shot_cameras, sizes, str(path))
    elif (path.parent / "rig_cameras.json").is_file() and (path.parent / "rig_assignments.json").is_file():
        where = path.parent / "rig_assignments.json"
        doc = _load_json(where)
        if isinstance(doc, list):  # older OpenSfM: a list of instances without ids
            doc = {str(i): v for i, v in enumerate(doc)}
        inst = {}
        for iid, pairs in (doc.items() if isinstance(doc, dict) else []):
            if not isinstance(pairs, list) or not all(isinstance(p, list) and len(p) == 2 and all(
                    isinstance(x, str) for x in p) for p in pairs):
                raise FormatError(f"{where}: rig instance {str(iid)[:40]!r}: expected a list of [image, rig camera id]")
            inst[str(iid)] = [tuple(p) for p in pairs]
        if not isinstance(doc, dict):
            raise FormatError(f"{where}: expected an object (or a list) of rig instances")
        rigs = rigs_from_opensfm(_load_json(path.parent / "rig_cameras.json"), inst, shot_cameras, sizes, str(where))
    else:
        return None
    return rigs if rigs.rigs else None


def _odm_cameras(path: Path, ids: dict) -> dict[str, tuple]:
    """Reconstruction camera id -> (path, text, id in the file, dict) of an ODM ``cameras.json``."""
    text = read_text(path, FormatError)
    doc = _load_json(path)
    if not isinstance(doc, dict):
        raise format_error(path, 1, None, "expected an object camera id -> camera (an OpenDroneMap cameras.json)")
    out = {}
    for cid in ids:
        bare = cid[3:] if cid.startswith("v2 ") else cid
        key = cid if cid in doc else bare if bare in doc else None
        if key is not None:
            out[cid] = (path, text, key, doc[key])
    if not out:
        raise FormatError(f"{path}: none of its cameras ({', '.join(list(doc)[:3]) or 'none'}) is a camera of the "
                          f"reconstruction ({', '.join(list(ids)[:3])}); give the cameras.json of the same ODM project")
    return out


def _read_tracks(path: Path, shots: set[str], points: set[str]):
    text = read_text(path, FormatError)
    lines = text.splitlines()
    start = 1 if lines and lines[0].startswith("OPENSFM_TRACKS_VERSION") else 0
    o_ph, o_pt, o_xy = [], [], []
    seen = set()
    for no, raw in enumerate(lines[start:], start=start + 1):
        if not raw.strip():
            continue
        f = raw.split("\t")
        names = ("image", "track_id", "feature_id", "x", "y")
        if len(f) < 5:
            raise format_error(path, no, names[len(f)], "missing: image track_id feature_id x y ... (tab-separated)")
        xy = []
        for k, n in ((3, "x"), (4, "y")):
            try:  # normalised image coordinates: |x|, |y| <= 0.5 inside the image
                v = parse_number(f[k], "normalised")
            except ValueError as ex:
                raise format_error(path, no, n, str(ex)) from None
            xy.append(v)
        im, tr = f[0], f[1].strip()
        if im in shots and tr in points and (im, tr) not in seen:
            seen.add((im, tr))
            o_ph.append(im)
            o_pt.append(tr)
            o_xy.append(xy)
    return o_ph, o_pt, o_xy


def read_opensfm_gcp(path: str | Path, block: Block, *, height_system: str = "ellipsoidal") -> GroundControl:
    """OpenSfM ``ground_control_points.json`` in the frame of *block* (read by :func:`read_opensfm`).

    Positions (latitude, longitude, altitude on WGS84) go to the block's
    topocentric frame with PROJ (the ``+proj=topocentric`` pipeline of its
    ``crs``); points without ``position`` are kept with NaN coordinates (their
    measurements are still tie observations).  Normalised projections become
    pixels with the shot's camera.  Point ids get the prefix ``gcp`` (OpenSfM keeps
    GCP ids apart from track ids, which are the survey's tie-point ids).

    Raises
    ------
    FormatError
        The block has no reference_lla, invalid JSON, a missing field, a shot not
        in the block (``FILE:LINE: field``).
    """
    from pyproj import Transformer

    path = Path(path)
    text = read_text(path, FormatError)
    data = _load_json(path)
    if "proj=topocentric" not in block.crs:
        raise FormatError(f"{path}: the block {block.name!r} has no OpenSfM reference_lla frame, so GCPs in "
                          f"lat/lon cannot be placed; give --survey a survey imported from a georeferenced "
                          f"OpenSfM reconstruction (with reference_lla), or write the GCPs as an ODM "
                          f"gcp_list.txt in the survey CRS and use lidarcat import odm-gcp")
    tr = Transformer.from_pipeline(block.crs.split(": ", 1)[1])
    pts = data.get("points") if isinstance(data, dict) else None
    if not isinstance(pts, list):
        raise format_error(path, 1, "points", "expected an object with a list 'points'")
    ids, enh, o_pt, o_ph, o_px = [], [], [], [], []
    cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
    for k, p in enumerate(pts):
        if not isinstance(p, dict):
            raise format_error(path, None, "points", f"point {k + 1} is not an object, got {_short(p)}")
        if not isinstance(p.get("id"), (str, int)) or isinstance(p.get("id"), bool):
            raise format_error(path, None, "id", f"point {k + 1}: expected a string id, got {_short(p.get('id'))}")
        line = _json_line(text, str(p["id"]))
        pid = f"gcp{p['id']}"  # GCP ids are their own namespace in OpenSfM, apart from track ids
        pos = p.get("position")
        xyz = np.full(3, np.nan)
        if pos is not None:
            if not isinstance(pos, dict):
                raise format_error(path, line, "position", f"GCP {pid!r}: expected an object with latitude, "
                                   f"longitude, altitude, got {_short(pos)}")
            lat, lon, alt = (_num(path, text, str(p["id"]), k, pos.get(k), kind) for k, kind in
                             (("latitude", "latitude_deg"), ("longitude", "longitude_deg"), ("altitude", "height_m")))
            xyz = np.array(tr.transform(lon, lat, alt))
        ids.append(pid)
        enh.append(xyz)
        obs = p.get("observations", [])
        if not isinstance(obs, list):
            raise format_error(path, line, "observations", f"GCP {pid!r}: expected a list, got {_short(obs)}")
        for ob in obs:
            if not isinstance(ob, dict):
                raise format_error(path, line, "observations", f"GCP {pid!r}: an observation is not an object, "
                                   f"got {_short(ob)}")
            sid = ob.get("shot_id")
            if not isinstance(sid, str) or sid not in cam_of or cam_of[sid] not in block.source_models:
                raise format_error(path, line, "shot_id", f"GCP {pid!r}: shot {_short(sid)} is not in the "
                                   f"reconstruction of {block.name!r}: give --survey the survey imported "
                                   f"from the reconstruction these GCPs were measured in")
            xy = _vec(path, text, str(p["id"]), "projection", ob.get("projection"), 2, "normalised")
            m = block.source_models[cam_of[sid]]
            s = max(m["w"], m["h"])
            o_pt.append(pid)
            o_ph.append(sid)
            o_px.append(xy * s + [m["w"] / 2, m["h"] / 2] - 0.5)
    return GroundControl(np.array(ids, dtype=str), np.array(enh).reshape(-1, 3), block.crs, height_system,
                         np.array(o_pt, dtype=str), np.array(o_ph, dtype=str), np.array(o_px).reshape(-1, 2),
                         f"{path} (OpenSfM GCPs, WGS84 lat/lon/alt -> topocentric ENU)")


def opensfm_camera_dict(m: dict) -> dict:
    """OpenSfM camera dict of a Brown model without k4..k6 (:func:`lidarcat.interop.lens.export_camera`):
    ``perspective`` when it is one (fx = fy, centred, k1 and k2 only), else ``brown``."""
    w, h = m["w"], m["h"]
    s = max(w, h)
    d = m["dist"]
    if m["kind"] == "fisheye":
        if m["fx"] == m["fy"] and m["cx"] == w / 2 and m["cy"] == h / 2 and not any(
                d.get(k, 0.0) for k in ("k3", "k4")):
            return {"projection_type": "fisheye", "width": w, "height": h, "focal": m["fx"] / s,
                    "k1": d.get("k1", 0.0), "k2": d.get("k2", 0.0)}
        return {"projection_type": "fisheye_opencv", "width": w, "height": h, "focal_x": m["fx"] / s,
                "focal_y": m["fy"] / s, "c_x": (m["cx"] - w / 2) / s, "c_y": (m["cy"] - h / 2) / s,
                **{k: d.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")}}
    if m["fx"] == m["fy"] and m["cx"] == w / 2 and m["cy"] == h / 2 and not any(
            d.get(k, 0.0) for k in ("k3", "p1", "p2")):
        return {"projection_type": "perspective", "width": w, "height": h, "focal": m["fx"] / s,
                "k1": d.get("k1", 0.0), "k2": d.get("k2", 0.0)}
    return {"projection_type": "brown", "width": w, "height": h, "focal_x": m["fx"] / s,
            "focal_y": m["fy"] / s, "c_x": (m["cx"] - w / 2) / s, "c_y": (m["cy"] - h / 2) / s,
            **{k: d.get(k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2")}}


def to_topocentric(block: Block) -> tuple[Block, str] | None:
    """*block* in OpenSfM's topocentric ENU frame at the mean photo centre, when its CRS is a map
    CRS pyproj knows (None otherwise: a local frame).

    Positions go through PROJ: map CRS -> its geographic 3D CRS -> ECEF -> topocentric (the
    heights taken as ellipsoidal: an orthometric block lands N metres low, which the returned note
    says).  A rotation ``R`` (world to camera) becomes ``R Q^T`` with ``Q`` the rotation part (polar
    decomposition) of the Jacobian of the map -> topocentric mapping at the photo centre, taken by
    central differences over 1 m: the meridian convergence, the tilt of the tangent plane and
    the scale factor of the projection (which the rotation leaves out, as the map-frame
    adjustment did) are all in it.

    Returns
    -------
    (Block, str) or None
        The converted block (``crs`` = :func:`topocentric_crs`, heights ellipsoidal) and a note.
    """
    from pyproj import CRS, Transformer
    from pyproj.exceptions import CRSError

    try:
        crs = CRS.from_user_input(block.crs)
    except CRSError:
        return None
    if not (crs.is_projected or crs.is_geographic):
        return None
    geo3d = crs.geodetic_crs.to_3d()
    to_geo = Transformer.from_crs(crs.to_3d() if not crs.is_compound else crs, geo3d, always_xy=True)
    c0 = np.nanmean(block.eo[:, :3], axis=0)
    lon0, lat0, h0 = to_geo.transform(*c0)
    pipe = Transformer.from_pipeline(_pipeline(float(lat0), float(lon0), float(h0)))

    def fwd(xyz: np.ndarray) -> np.ndarray:
        lon, lat, h = to_geo.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        return np.column_stack(pipe.transform(lon, lat, h))

    eo = np.array(block.eo, dtype=float)
    centres = fwd(eo[:, :3])
    steps = np.eye(3)
    jac = np.stack([(fwd(eo[:, :3] + d) - fwd(eo[:, :3] - d)) / 2.0 for d in steps], axis=2)  # (P, 3, 3)
    u, _, vt = np.linalg.svd(jac)
    q = u @ vt
    r = opk_to_world_to_cv(eo[:, 3:]).reshape(-1, 3, 3) @ np.transpose(q, (0, 2, 1))
    eo = np.column_stack([centres, world_to_cv_to_opk(r)])
    pts = np.array(block.points_m, dtype=float)
    ok = np.isfinite(pts).all(axis=1)
    if ok.any():
        pts[ok] = fwd(pts[ok])
    gm = np.array(block.ground_m, dtype=float)
    okg = np.isfinite(gm).all(axis=1)
    if okg.any():
        gm[okg] = fwd(gm[okg])
    hs = block.height_system
    note = (f"coordinates converted from {block.crs} to OpenSfM's topocentric frame at reference_lla "
            f"(lat {float(lat0)!r}, lon {float(lon0)!r}, alt {float(h0)!r})"
            + ("" if hs.startswith("ellipsoidal") else f"; the block's heights ({hs}) were taken as "
               f"ellipsoidal: the frame lies N (geoid undulation) metres low"))
    return block.with_(crs=topocentric_crs(float(lat0), float(lon0), float(h0)), height_system="ellipsoidal",
                       eo=eo, points_m=pts, ground_m=gm), note


def write_opensfm(block: Block, folder: str | Path) -> Path:
    """Write *block* as ``reconstruction.json`` + ``tracks.csv`` in *folder*, atomically.

    Observations are written in normalised coordinates of the camera model
    written (:mod:`lidarcat.interop.lens`).  Only points with coordinates get a
    ``points`` entry and tracks.  A block in a map CRS is written in OpenSfM's
    topocentric frame with its ``reference_lla`` (:func:`to_topocentric`); a local
    frame gets no ``reference_lla``.

    Raises
    ------
    FormatError
        A photo without a complete orientation.
    """
    folder = Path(folder)
    require_orientations(block, "OpenSfM")
    note = None
    if reference_lla(block.crs) is None:
        topo = to_topocentric(block)
        if topo is not None:
            block, note = topo
    models = export_cameras(block, rational=False)
    cams = {cid: opensfm_camera_dict(m) for cid, m in models.items()}
    r = opk_to_world_to_cv(block.eo[:, 3:]).reshape(-1, 3, 3)
    shots = {}
    for i, pid in enumerate(block.photo_ids.tolist()):
        shots[pid] = {"rotation": Rotation.from_matrix(r[i]).as_rotvec().tolist(),
                      "translation": (-r[i] @ block.eo[i, :3]).tolist(), "camera": block.photo_camera[i]}
    ok = np.isfinite(block.points_m).all(axis=1)
    points = {p: {"coordinates": x.tolist(), "color": [128.0, 128.0, 128.0]}
              for p, x in zip(block.point_ids[ok].tolist(), block.points_m[ok])}
    pix = observed_pixels(block)
    cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
    lines = ["OPENSFM_TRACKS_VERSION_v2"]
    for k, (ph, pt) in enumerate(zip(block.obs_photo.tolist(), block.obs_point.tolist())):
        if pt not in points:
            continue
        cid = cam_of[ph]
        c = cams[cid]
        s = max(c["width"], c["height"])
        xn = (pix[k] - [c["width"] / 2, c["height"] / 2]) / s
        lines.append(f"{ph}\t{pt}\t{k}\t{float(xn[0])!r}\t{float(xn[1])!r}\t0.004\t128\t128\t128\t-1\t-1")
    rec: dict[str, Any] = {"cameras": cams, "shots": shots, "points": points}
    if block.rigs is not None:
        rig_cams, rig_inst = opensfm_rig_entries(block)
        if rig_inst:
            rec["rig_cameras"], rec["rig_instances"] = rig_cams, rig_inst
    lla = reference_lla(block.crs)
    if lla is not None:
        rec["reference_lla"] = lla
    else:
        log.warning("%s: CRS %s is a local frame: reconstruction.json gets no reference_lla "
                    "(the CRS is in lidarcat_export.txt)", folder, block.crs)
    with atomic_dir(folder) as tmp:
        write_text_atomic(tmp / "reconstruction.json", json.dumps([rec], indent=1) + "\n")
        write_text_atomic(tmp / "tracks.csv", "\n".join(lines) + "\n")
        write_text_atomic(tmp / "lidarcat_export.txt", "".join(
            f"{line}\n" for line in [f"written by lidarcat from survey {block.name!r}: CRS {block.crs}, heights "
                                      f"{block.height_system}", *([note] if note else []), *notes(models)]))
    log.info("wrote OpenSfM reconstruction %s: %d shots, %d points (CRS %s, heights %s)", folder,
             len(shots), len(points), block.crs, block.height_system)
    return folder


def read_opensfm_config(path: str | Path) -> dict[str, Any]:
    """An OpenSfM dataset ``config.yaml``: flat ``key: value`` lines (``#`` comments).

    Values become bool (``yes``/``no``/``true``/``false``), int, float or text.
    Only the flat subset of YAML that OpenSfM configs use is read (no PyYAML needed).

    Raises
    ------
    FormatError
        A line that is no ``key: value`` pair, or a key given twice (``FILE:LINE: field``).
    """
    path = Path(path)
    out: dict[str, Any] = {}
    lines: dict[str, int] = {}
    for no, raw in enumerate(read_text(path, FormatError).splitlines(), start=1):
        s = raw.split("#", 1)[0].strip()
        if not s:
            continue
        if ":" not in s:
            raise format_error(path, no, None, f"{s!r} is no 'key: value' line")
        key, val = (x.strip() for x in s.split(":", 1))
        if not key or not val:
            raise format_error(path, no, key or None, "expected 'key: value' with both parts")
        if key in out:
            raise format_error(path, no, key, f"given twice (also line {lines[key]})")
        low = val.lower()
        v: Any
        if low in ("yes", "true", "on"):
            v = True
        elif low in ("no", "false", "off"):
            v = False
        else:
            try:  # ASCII numbers only (int() and float() read Unicode digits and 1_000)
                v = parse_whole(val)
            except ValueError:
                try:
                    v = parse_float(val)
                except ValueError:
                    v = val.strip("'\"")
        out[key] = v
        lines[key] = no
    for key in ("gcp_horizontal_sd", "gcp_vertical_sd"):
        if key in out:
            v = out[key]
            problem = (f"{_short(v)} is not a number" if isinstance(v, (bool, str))
                       else sd_problem(float(v), "m"))
            if problem:
                raise format_error(path, lines[key], key, f"{problem} (a standard deviation, m)")
    return out


def gcp_sd_from_config(config: dict[str, Any], default: float) -> tuple[float, float, float]:
    """(sd_E, sd_N, sd_h) of GCPs from OpenSfM's ``gcp_horizontal_sd``/``gcp_vertical_sd`` (m).

    Keys missing from the dataset's config take *default*; a config with
    ``bundle_use_gcp: no`` is logged (OpenSfM would not have used the GCPs).
    """
    if config.get("bundle_use_gcp") is False:
        log.warning("the OpenSfM config says bundle_use_gcp: no; the GCPs are imported anyway")
    hz, vt = (config.get(k, default) for k in ("gcp_horizontal_sd", "gcp_vertical_sd"))
    for k, v in (("gcp_horizontal_sd", hz), ("gcp_vertical_sd", vt)):
        problem = (f"{_short(v)} is not a number" if isinstance(v, bool) or not isinstance(v, (int, float))
                   else sd_problem(float(v), "m"))
        if problem:
            raise FormatError(f"OpenSfM config: field {k!r}: {problem} (a standard deviation, m)")
    hz, vt = float(hz), float(vt)
    return hz, hz, vt
