r"""Agisoft Metashape project XML (chunk ``doc.xml`` + frame ``doc.xml``): cameras with their
calibration and orientation, markers with reference coordinates and image measurements.

Read from the project-internal XML (schema 1.2.0, Metashape 1.x; the
``File > Export Cameras`` XML shares these elements).

Conventions (Metashape manual, Appendix C "Camera models", and the files)
-------------------------------------------------------------------------
* ``<sensor><calibration>``: ``f, cx, cy, k1..k4, p1, p2, b1, b2`` in pixels (the
  ``class="adjusted"`` calibration, else the ``initial`` one, in whatever order they stand;
  a sensor of ``type="fisheye"`` maps the ray to ``(x, y) = theta (X, Y) / rho`` first and then
  distorts as below (kept as ``kind = "metashape_fisheye"``, :mod:`lidarcat.interop.cameras`);
  spherical, cylindrical and RPC sensors are refused);
  with ``x = X/Z``, ``y = Y/Z`` (camera x right, **y down, z forward**)::

      x' = x (1 + k1 r^2 + k2 r^4 + k3 r^6 + k4 r^8) + p1 (r^2 + 2 x^2) + 2 p2 x y
      y' = y (1 + ...)                             + p2 (r^2 + 2 y^2) + 2 p1 x y
      u  = w/2 + cx + x' (f + b1) + y' b2,   v = h/2 + cy + y' f

  (p1, p2 swapped with respect to OpenCV); ``u, v`` have the image *corner* at
  (0, 0), so lidarcat's ``col = u - 0.5``.  The model is kept as the source model
  (``kind = "metashape"``, skew ``b2``) and the marker measurements are undistorted
  exactly (:mod:`lidarcat.interop._distortion`).
* ``<camera><transform>``: 4x4 row-major **camera to chunk**; the chunk maps to
  geocentric (ECEF) coordinates by ``X = s R x + T`` (``<transform>`` of the
  camera's component, else of the chunk).  The camera-to-ECEF rotation is
  ``R R_cam``.  lidarcat needs a projected frame: centres go from ECEF to the
  target CRS with PROJ; rotations go ECEF -> local ENU at the camera -> grid by
  the meridian convergence (the angle of true north in the grid, measured with
  PROJ at each camera).  The scale factor of the projection is not applied to the
  bundle (as in every aerial triangulation in map coordinates).  Heights are
  **ellipsoidal** (WGS84 ECEF).
* Markers: ``<reference x y z>`` in the chunk CRS (``<reference>`` WKT, usually
  WGS84 lon/lat/h); measurements ``<location camera_id x y>`` in the frame XML.

Lost on import: tie points (in binary point clouds, not in the XML), camera
reference (GNSS) values (use :mod:`lidarcat.interop.gnss`), covariances,
disabled/unaligned cameras (no transform: no orientation).
"""

from __future__ import annotations

import logging
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._util import read_bytes
from .._util.tables import parse_float
from .._util.values import parse_number, value_problem
from ..errors import FormatError
from ._checks import check_crs
from ._text import format_error
from .block import Block
from .cameras import MAX_RAY_ANGLE_DEG, check_source_model, ideal_observations, pinhole_camera
from .rotations import FLIP, matrix_to_opk

__all__ = ["read_metashape", "utm_crs_for"]

log = logging.getLogger(__name__)


@dataclass
class _El:
    tag: str
    attrs: dict
    line: int
    parts: list = field(default_factory=list)
    children: list = field(default_factory=list)

    @property
    def text(self) -> str:
        return "".join(self.parts)

    def find(self, tag: str) -> _El | None:
        return next((c for c in self.children if c.tag == tag), None)

    def findall(self, tag: str) -> list[_El]:
        return [c for c in self.children if c.tag == tag]


class _Refused(Exception):
    """A construct Metashape never writes (a DTD, an entity declaration): the parse stops there."""

    def __init__(self, line: int, column: int, what: str):
        super().__init__(what)
        self.line, self.column, self.what = line, column, what


def _parse(path: Path) -> _El:
    """The XML tree with the line of every element (expat).

    Metashape writes no DTD and no entity: a document type declaration, an entity
    declaration or a reference to an external entity is refused where it starts, before
    anything is expanded (entity expansion is how a small XML file asks for gigabytes or
    quadratic time: "billion laughs"), so the parse is linear in the file size.  Element
    text is collected in parts and joined once.
    """
    data = read_bytes(path, FormatError)
    p = xml.parsers.expat.ParserCreate()
    stack: list[_El] = [_El("#root", {}, 0)]

    def start(tag, attrs):
        el = _El(tag, dict(attrs), p.CurrentLineNumber)
        stack[-1].children.append(el)
        stack.append(el)

    def end(tag):
        stack.pop()

    def chars(text):
        stack[-1].parts.append(text)

    def refuse(what):
        def handler(*args):
            raise _Refused(p.CurrentLineNumber, p.CurrentColumnNumber + 1, what)
        return handler

    p.StartElementHandler, p.EndElementHandler, p.CharacterDataHandler = start, end, chars
    p.StartDoctypeDeclHandler = refuse("a document type declaration (<!DOCTYPE>)")
    p.EntityDeclHandler = refuse("an entity declaration (<!ENTITY>)")
    p.ExternalEntityRefHandler = refuse("a reference to an external entity")
    p.SetParamEntityParsing(xml.parsers.expat.XML_PARAM_ENTITY_PARSING_NEVER)
    try:
        p.Parse(data, True)
    except _Refused as ex:
        raise format_error(path, ex.line, None, f"{ex.what} (column {ex.column}): Metashape writes none, and "
                           f"lidarcat reads no XML with one (entities can expand to gigabytes)") from None
    except xml.parsers.expat.ExpatError as ex:
        raise format_error(path, ex.lineno, None, f"invalid XML: {xml.parsers.expat.ErrorString(ex.code)} "
                           f"(column {ex.offset + 1})") from None
    return stack[0].children[0]


def _floats(path: Path, el: _El | None, name: str, n: int | None = None, parent: _El | None = None) -> np.ndarray:
    if el is None:
        raise format_error(path, parent.line if parent else None, name, "missing")
    cells = el.text.split()
    try:
        v = np.array([parse_float(c) for c in cells], dtype=float)
    except ValueError:
        raise format_error(path, el.line, name, f"{el.text.strip()[:40]!r} is not a list of numbers "
                           f"(ASCII digits 0-9)") from None
    if (n is not None and v.size != n) or not np.isfinite(v).all():
        raise format_error(path, el.line, name, f"expected {n or 'finite'} finite numbers, got "
                           f"{v.size}{'' if np.isfinite(v).all() else ' (not finite)'}")
    return v


def _attr(path: Path, el: _El, name: str, kind: str | None = None) -> float:
    """Attribute *name* of *el*: a finite ASCII number in the sane range of *kind*
    (:data:`lidarcat._util.values.VALUE_RANGES`)."""
    if name not in el.attrs:
        raise format_error(path, el.line, name, f"missing attribute of <{el.tag}>")
    try:
        return parse_number(el.attrs[name], kind)
    except ValueError as ex:
        raise format_error(path, el.line, name, str(ex)[:200]) from None


def utm_crs_for(lon_deg: float, lat_deg: float) -> str:
    """The WGS84 / UTM zone CRS containing a point, as ``EPSG:326zz``/``327zz``.

    >>> utm_crs_for(139.54, 35.74)
    'EPSG:32654'
    """
    zone = int((lon_deg + 180.0) // 6) % 60 + 1
    return f"EPSG:{(32600 if lat_deg >= 0 else 32700) + zone}"


def _calibration(sensor: _El) -> _El | None:
    """The sensor's ``<calibration class="adjusted">`` wherever it stands, else its ``initial`` one,
    else its first (Metashape writes ``initial`` before ``adjusted`` once a camera was optimised)."""
    cals = sensor.findall("calibration")
    for cls in ("adjusted", "initial"):
        hit = next((c for c in cals if c.attrs.get("class") == cls), None)
        if hit is not None:
            return hit
    return cals[0] if cals else None


def _chunk_transform(path: Path, el: _El | None):
    if el is None:
        return None
    rot = _floats(path, el.find("rotation"), "rotation", 9, el).reshape(3, 3)
    tr = _floats(path, el.find("translation"), "translation", 3, el)
    sc = el.find("scale")
    s = float(_floats(path, sc, "scale", 1, el)[0]) if sc is not None else 1.0
    return rot, tr, s


def read_metashape(chunk_xml: str | Path, frame_xml: str | Path | None = None, *, crs: str | None = None,
                   pixel_size_mm: float | None = None, marker_sd_m: float = 0.02) -> Block:
    """Read a Metashape chunk (and its frame XML with the marker measurements).

    Parameters
    ----------
    chunk_xml : path
        The chunk ``doc.xml`` (unzipped ``chunk.zip``).
    frame_xml : path, optional
        The frame ``doc.xml`` (``0/frame.zip``) with the marker measurements.
    crs : str, optional
        Projected target CRS (default: the WGS84 / UTM zone of the first camera).
    pixel_size_mm : float, optional
        Pixel pitch (default: the sensor's ``pixel_width`` property, else 0.001).
    marker_sd_m : float
        Sd given to the marker reference coordinates (m).

    Raises
    ------
    FormatError
        Invalid XML (line, column); a missing or non-numeric element/attribute
        (``FILE:LINE: field``); a georeferenced chunk without transform; a marker
        measurement on an unknown camera.
    """
    from pyproj import CRS, Transformer

    path = Path(chunk_xml)
    root = _parse(path)
    if root.tag != "chunk":
        raise format_error(path, root.line, None, f"root element <{root.tag}> is not <chunk> (a Metashape "
                           f"chunk doc.xml, unzipped from chunk.zip)")
    sensors_el = root.find("sensors")
    if sensors_el is None:
        raise format_error(path, root.line, "sensors", "missing (a Metashape chunk doc.xml has <sensors>): "
                           "give the doc.xml unzipped from the chunk's chunk.zip")
    crs = check_crs(crs)
    cams, models = {}, {}
    for s in sensors_el.findall("sensor"):
        sid = s.attrs.get("id", "")
        kind = s.attrs.get("type", "frame")
        if kind not in ("frame", "fisheye"):
            raise format_error(path, s.line, "type", f"sensor {sid} ({s.attrs.get('label', 'no label')}) is a "
                               f"{kind} camera; lidarcat reads frame and fisheye cameras: remove or disable "
                               f"its cameras in Metashape, or export undistorted frame images of them, then "
                               f"import again")
        cal = _calibration(s)
        res = (cal.find("resolution") if cal is not None else None) or s.find("resolution")
        if cal is None or res is None:
            log.warning("%s:%d: sensor %s has no calibration; its cameras are skipped", path, s.line, sid)
            continue
        w, h = int(_attr(path, res, "width", "image_px")), int(_attr(path, res, "height", "image_px"))
        val = {k: float(_floats(path, cal.find(k), k, 1, cal)[0]) if cal.find(k) is not None else 0.0
               for k in ("f", "cx", "cy", "b1", "b2", "k1", "k2", "k3", "k4", "p1", "p2")}
        if val["f"] <= 0:
            raise format_error(path, cal.line, "f", "focal length must be positive")
        for k in ("f", "cx", "cy", "b1", "b2"):
            problem = value_problem(val[k], "pixel_px")
            if problem:
                raise format_error(path, cal.find(k).line, k, problem)
        t = pixel_size_mm
        if t is None:
            pw = next((p for p in s.findall("property") if p.attrs.get("name") == "pixel_width"), None)
            t = _attr(path, pw, "value") if pw is not None and pw.attrs.get("value", "").strip() else 0.0
            t = t if t > 0 else 0.001  # Metashape writes 0 for an unknown pitch
            if t > 1:
                raise format_error(path, pw.line, "pixel_width", f"{pw.attrs['value'][:40]!r} mm is no pixel pitch "
                                   f"(0 < pixel_width <= 1 mm)")
        fx, fy = val["f"] + val["b1"], val["f"]
        cam, model = pinhole_camera(
            sid, fx, fy, w / 2 + val["cx"], h / 2 + val["cy"], w, h, pixel_size_mm=t,
            model=f"Metashape {s.attrs.get('label', '')}".strip(),
            source=f"{path.name}:{cal.line}: Metashape {kind} calibration "
                   + " ".join(f"{k}={v!r}" for k, v in val.items() if v),
            dist={k: val[k] for k in ("k1", "k2", "k3", "k4", "p1", "p2")},
            kind="metashape" if kind == "frame" else "metashape_fisheye")
        model["skew"] = val["b2"]
        check_source_model(sid, model, f"{path}:{cal.line}")
        cams[sid], models[sid] = cam, model
    comps = {c.attrs.get("id"): _chunk_transform(path, c.find("transform"))
             for c in (root.find("components").findall("component") if root.find("components") else [])}
    chunk_tr = _chunk_transform(path, root.find("transform"))
    ref_el = root.find("reference")
    chunk_crs = CRS.from_user_input(ref_el.text.strip()) if ref_el is not None and ref_el.text.strip() else None

    photo, pcam, eo, num_of = [], [], [], {}
    ecef_to_geo = Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    cams_el = root.find("cameras")
    rows = []
    for c in (cams_el.findall("camera") if cams_el is not None else []):
        sid = c.attrs.get("sensor_id")
        if sid not in cams:
            continue
        label = c.attrs.get("label", c.attrs.get("id"))
        num_of[c.attrs.get("id")] = label
        tr_el = c.find("transform")
        if tr_el is None:
            photo.append(label)
            pcam.append(sid)
            eo.append(np.full(6, np.nan))
            continue
        m4 = _floats(path, tr_el, "transform", 16).reshape(4, 4)
        ct = comps.get(c.attrs.get("component_id")) or chunk_tr
        if ct is None:
            raise format_error(path, tr_el.line, "transform", "the chunk has no transform to geocentric "
                               "coordinates (not georeferenced); lidarcat needs a georeferenced chunk: give its "
                               "markers or cameras reference coordinates in Metashape, update the transform "
                               "(Reference pane), save and import again")
        rot, tr, sc = ct
        centre = sc * rot @ m4[:3, 3] + tr
        r_c2e = rot @ m4[:3, :3]
        r_c2e = r_c2e / np.cbrt(np.linalg.det(r_c2e))
        photo.append(label)
        pcam.append(sid)
        rows.append((len(eo), centre, r_c2e))
        eo.append(np.full(6, np.nan))
    if not photo:
        raise FormatError(f"{path}: no camera with a calibrated sensor: align the photos in Metashape (the "
                          f"sensors get a <calibration>), save and import again")
    eo_a = np.array(eo)
    if rows:
        xyz = np.array([r[1] for r in rows])
        lon, lat, hgt = ecef_to_geo.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        crs = crs or utm_crs_for(float(lon[0]), float(lat[0]))
        to_grid = Transformer.from_crs("EPSG:4979", CRS.from_user_input(crs), always_xy=True)
        e, n = to_grid.transform(lon, lat)
        e1, n1 = to_grid.transform(lon, np.asarray(lat) + 1e-5)
        theta = np.arctan2(np.asarray(e1) - e, np.asarray(n1) - n)  # true north in the grid
        for k, (i, _, r_c2e) in enumerate(rows):
            la, lo = np.radians(lat[k]), np.radians(lon[k])
            r_e2enu = np.array([[-np.sin(lo), np.cos(lo), 0.0],
                                [-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)],
                                [np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)]])
            ct_, st_ = np.cos(theta[k]), np.sin(theta[k])
            r_enu2g = np.array([[ct_, st_, 0.0], [-st_, ct_, 0.0], [0.0, 0.0, 1.0]])
            r_c2g = r_enu2g @ r_e2enu @ r_c2e
            eo_a[i] = np.concatenate([[e[k], n[k], hgt[k]], matrix_to_opk(FLIP @ r_c2g.T)])
    crs = crs or "unspecified"

    gid, gxyz, glabel = [], [], {}
    mk = root.find("markers")
    for m in (mk.findall("marker") if mk is not None else []):
        label = m.attrs.get("label", m.attrs.get("id"))
        glabel[m.attrs.get("id")] = label
        ref = m.find("reference")
        if ref is None or ref.attrs.get("enabled", "true") != "true" or chunk_crs is None:
            continue
        x, y, z = (_attr(path, ref, k, kind) for k, kind in (("x", "coordinate_m"), ("y", "coordinate_m"),
                                                               ("z", "height_m")))
        gid.append(label)
        gxyz.append((x, y, z, m.line))
    g_m = np.empty((0, 3))
    if gid:
        src = chunk_crs.to_3d() if chunk_crs.is_geographic else chunk_crs
        tr_m = Transformer.from_crs(src, CRS.from_user_input(crs).to_3d() if CRS.from_user_input(crs).is_projected
                                    else CRS.from_user_input(crs), always_xy=True)
        a = np.array([g[:3] for g in gxyz])
        ee, nn, hh = tr_m.transform(a[:, 0], a[:, 1], a[:, 2])
        g_m = np.column_stack([ee, nn, hh])
    o_ph, o_pt, o_xy = [], [], []
    if frame_xml is not None:
        fpath = Path(frame_xml)
        froot = _parse(fpath)
        fm = froot.find("markers")
        for m in (fm.findall("marker") if fm is not None else []):
            label = glabel.get(m.attrs.get("marker_id"))
            if label is None:
                raise format_error(fpath, m.line, "marker_id", f"marker {m.attrs.get('marker_id')!r} is not "
                                   f"in the chunk {path.name}: give the frame doc.xml of the same chunk (--frame)")
            for loc in m.findall("location"):
                cid = loc.attrs.get("camera_id")
                if cid not in num_of:
                    raise format_error(fpath, loc.line, "camera_id", f"camera {cid!r} is not a calibrated "
                                       f"camera of the chunk {path.name}: give the frame doc.xml of the same "
                                       f"chunk (--frame)")
                o_ph.append(num_of[cid])
                o_pt.append(label)
                o_xy.append([_attr(fpath, loc, "x", "pixel_px"), _attr(fpath, loc, "y", "pixel_px")])
    xy = np.array(o_xy, dtype=float).reshape(-1, 2)
    mm = np.empty_like(xy)
    keep = np.ones(len(xy), dtype=bool)
    sd = np.full_like(xy, np.nan)
    cam_of = dict(zip(photo, pcam))
    oc = np.array([cam_of[p] for p in o_ph], dtype=object)
    for sid, mdl in models.items():
        sel = oc == sid
        if sel.any():
            mm[sel], keep[sel], sd[sel] = ideal_observations(xy[sel], cams[sid], mdl, where=str(frame_xml))
    description = f"imported from Metashape {path.name}"
    if not keep.all():
        description += (f"; {int((~keep).sum())} marker measurement(s) of rays beyond {MAX_RAY_ANGLE_DEG:g} deg from "
                        f"a fisheye's axis skipped")
        xy, mm, sd = xy[keep], mm[keep], sd[keep]
        o_ph = [p for p, k in zip(o_ph, keep) if k]
        o_pt = [p for p, k in zip(o_pt, keep) if k]
    return Block(name=root.attrs.get("label", path.stem), crs=crs, height_system="ellipsoidal (WGS84)",
                 cameras=cams, photo_ids=np.array(photo, dtype=str), photo_camera=np.array(pcam, dtype=str),
                 eo=eo_a, obs_photo=np.array(o_ph, dtype=str), obs_point=np.array(o_pt, dtype=str),
                 obs_px=xy - 0.5, obs_mm=mm, point_ids=np.array(gid, dtype=str), points_m=g_m,
                 ground_ids=np.array(gid, dtype=str), ground_m=g_m,
                 ground_sd_m=np.full((len(gid), 3), float(marker_sd_m)),
                 ground_source=np.full(len(gid), "marker"),
                 description=description, source_models=models, obs_sd_mm=sd if np.isfinite(sd).any() else None)
