r"""OpenDroneMap ``gcp_list.txt`` (ground control with image measurements) and ``geo.txt``
(camera positions and attitudes).

``gcp_list.txt`` (ODM ``opendm/gcp.py``)
    Line 1 is the CRS: a PROJ string, ``EPSG:nnnn``, ``WGS84`` (lon/lat) or
    ``WGS84 UTM <zone><N|S>``.  Every following line is
    ``geo_x geo_y geo_z im_x im_y image_name [gcp_name] [extras...]`` separated
    by blanks or tabs.  ``im_x, im_y`` are the pixel column and row of the
    original image; ODM hands them to OpenSfM, which normalises
    ``(p + 0.5 - size/2) / max(w, h)``, i.e. the origin is the **centre** of the
    top-left pixel -- lidarcat's origin, so they are used as they are.  Points
    are named by ``gcp_name`` when given, else by their coordinates (rows with the
    same geo_x geo_y geo_z are one point, named ``gcp1``, ``gcp2``, ... in order
    of appearance).

``geo.txt`` (ODM ``opendm/geo.py``)
    Line 1 the CRS as above; then ``image x y [z [yaw pitch roll [horiz_acc vert_acc]]]``,
    angles in degrees, ``#`` comments.  Yaw/pitch/roll are converted to
    omega/phi/kappa with :func:`lidarcat.interop.rotations.ypr_to_opk` (the Pix4D
    formula: nadir camera, no boresight, no meridian convergence); the
    accuracies become sds of X0, Y0 (horizontal) and Z0 (vertical).

``cameras.json`` (ODM's cameras, ``odm --cameras``)
    Camera id (OpenSfM's without the ``v2 `` prefix) -> OpenSfM camera dict, fisheyes included:
    :func:`read_odm_cameras`, :func:`write_odm_cameras`; ``lidarcat import opensfm --cameras``
    makes a reconstruction's observations ideal through them.

Coordinates in a geographic CRS (``WGS84``) are projected to the target ``crs``
the caller gives (lidarcat adjusts in a projected frame); heights are passed
through unchanged and the caller declares whether they are ellipsoidal or
orthometric (:mod:`lidarcat.interop.heights` converts between them).
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from .._util import read_text, write_text_atomic
from ..errors import FormatError
from ._checks import check_crs
from ._text import sd_problem, Row, TextLines, format_error
from .merge import GroundControl, Orientations
from .rotations import ypr_to_opk

__all__ = ["parse_crs_line", "read_gcp_list", "read_geo_txt", "read_odm_cameras", "write_odm_cameras"]

log = logging.getLogger(__name__)


def parse_crs_line(text: str, path: object = "", line: int = 1):
    """The pyproj CRS of an ODM header line (``EPSG:4326``, ``WGS84 UTM 17N``, ``+proj=...``).

    >>> parse_crs_line("WGS84 UTM 17N").to_epsg()
    32617
    >>> parse_crs_line("WGS84").to_epsg()
    4326

    Raises
    ------
    FormatError
        ``FILE:LINE: field 'CRS': ...`` when pyproj does not know it.
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    s = text.strip()
    m = re.fullmatch(r"WGS84\s+UTM\s+(\d{1,2})\s*([NnSs])", s)
    try:
        if m:
            zone = int(m.group(1))
            if not 1 <= zone <= 60:
                raise format_error(path, line, "CRS", f"UTM zone {zone} is not in 1..60")
            return CRS.from_epsg((32600 if m.group(2).upper() == "N" else 32700) + zone)
        if s.upper() == "WGS84":
            return CRS.from_epsg(4326)
        return CRS.from_user_input(s)
    except CRSError as ex:
        raise format_error(path, line, "CRS", f"{s!r} is not a CRS pyproj knows (expected EPSG:nnnn, "
                           f"'WGS84 UTM 17N' or a PROJ string)") from ex


def _target(crs_in, crs: str | None, path: Path):
    """Transformer from the file CRS to the target (None: keep the file CRS, if projected)."""
    from pyproj import CRS, Transformer

    if crs is None:
        if crs_in.is_geographic:
            raise FormatError(f"{path}:1: field 'CRS': {crs_in.name} is geographic (lon/lat); give "
                              f"a projected target CRS (crs=, --crs EPSG:nnnn) to adjust in")
        return None, crs_in.to_string()
    out = CRS.from_user_input(check_crs(crs))
    if out == crs_in:
        return None, crs
    return Transformer.from_crs(crs_in, out, always_xy=True), crs


def _header(tl: TextLines):
    rows = list(tl.rows())
    if not rows:
        raise FormatError(f"{tl.path}: empty file; line 1 must be the CRS")
    first = rows[0]
    raw = tl.text.splitlines()[first.line - 1]
    return parse_crs_line(raw, tl.path, first.line), rows[1:]


def read_gcp_list(path: str | Path, *, crs: str | None = None,
                  height_system: str = "unspecified") -> GroundControl:
    """Read an ODM/OpenSfM ``gcp_list.txt``.

    Parameters
    ----------
    path : path
    crs : str, optional
        Target CRS of the coordinates (required when the file is in ``WGS84`` lon/lat).
    height_system : str
        What geo_z is (the file does not say).

    Raises
    ------
    FormatError
        Unknown CRS (line 1), a line with fewer than 6 fields, non-numeric values,
        two names for the same coordinates or two coordinates for one name
        (``FILE:LINE: field ...``).
    """
    tl = TextLines(path, comment="#", split="ws")
    crs_in, rows = _header(tl)
    tr, crs_out = _target(crs_in, crs, tl.path)
    names = ("geo_x", "geo_y", "geo_z", "im_x", "im_y", "image_name")
    pts: dict[str, tuple[tuple[float, float, float], int]] = {}
    by_xyz: dict[tuple[float, float, float], str] = {}
    o_pt, o_im, o_px, o_line = [], [], [], []
    for r in rows:
        r.need(6, names)
        xyz = (r.number(0, "geo_x", "coordinate_m"), r.number(1, "geo_y", "coordinate_m"),
               r.number(2, "geo_z", "height_m"))
        px = (r.number(3, "im_x", "pixel_px"), r.number(4, "im_y", "pixel_px"))
        name = r.fields[6] if len(r.fields) > 6 else None
        if name is None:
            name = by_xyz.get(xyz) or f"gcp{len(by_xyz) + 1}"
        _register(r, name, xyz, pts, by_xyz)
        o_pt.append(name)
        o_im.append(r.fields[5])
        o_px.append(px)
        o_line.append(r.line)
    if not pts:
        raise FormatError(f"{tl.path}: no GCP after the CRS line")
    ids = list(pts)
    xyz = np.array([pts[p][0] for p in ids])
    if tr is not None:
        e, n = tr.transform(xyz[:, 0], xyz[:, 1])
        xyz = np.column_stack([e, n, xyz[:, 2]])
    return GroundControl(np.array(ids, dtype=str), xyz, crs_out, height_system,
                         np.array(o_pt, dtype=str), np.array(o_im, dtype=str), np.array(o_px).reshape(-1, 2),
                         f"{tl.path} (ODM gcp_list, CRS {crs_in.name})", np.array(o_line, dtype=np.int64))


def _register(r: Row, name: str, xyz, pts: dict, by_xyz: dict) -> None:
    if name in pts and pts[name][0] != xyz:
        raise r.error("geo_x", f"GCP {name!r} has other coordinates on line {pts[name][1]}")
    other = by_xyz.get(xyz)
    if other is not None and other != name:
        raise r.error("gcp_name", f"the coordinates of line {pts[other][1]} ({other!r}) are named {name!r} here")
    pts.setdefault(name, (xyz, r.line))
    by_xyz.setdefault(xyz, name)


_GEO_KIND = {1: "coordinate_m", 2: "coordinate_m", 3: "height_m"}


def read_geo_txt(path: str | Path, *, crs: str | None = None,
                 height_system: str = "unspecified") -> Orientations:
    """Read an ODM ``geo.txt`` (image positions, optional yaw/pitch/roll and accuracies).

    Raises
    ------
    FormatError
        Unknown CRS, a line with neither 3 nor 4, 7, 9 or more fields, non-numeric
        values, a duplicate image (``FILE:LINE: field ...``).
    """
    tl = TextLines(path, comment="#", split="ws")
    crs_in, rows = _header(tl)
    tr, crs_out = _target(crs_in, crs, tl.path)
    names = ("image", "x", "y", "z", "yaw", "pitch", "roll", "horiz_acc", "vert_acc")
    photo, eo, sd, lines = [], [], [], []
    seen: dict[str, int] = {}
    for r in rows:
        r.need(3, names)
        n = len(r.fields)
        if n in (5, 6) or n == 8:
            raise r.error(names[min(n, 8)], f"{n} fields: give image x y [z [yaw pitch roll "
                                            f"[horiz_acc vert_acc]]]")
        im = r.fields[0]
        if im in seen:
            raise r.error("image", f"image {im!r} already on line {seen[im]}")
        seen[im] = r.line
        v = [r.number(k, names[k], _GEO_KIND[k]) if k < 4 else
             r.angle(k, names[k], np.pi / 180) * 180 / np.pi if k < 7 else r.number(k, names[k])
             for k in range(1, min(n, 10))]
        row = np.full(6, np.nan)
        s = np.full(6, np.nan)
        row[:len(v[:3])] = v[:3]
        if n >= 7:
            row[3:] = ypr_to_opk(np.radians(v[3:6]))
        if n >= 9:
            if v[6] <= 0 or v[7] <= 0:
                raise r.error("horiz_acc" if v[6] <= 0 else "vert_acc", "accuracy must be positive")
            for k in (7, 8):
                problem = sd_problem(v[k - 1], "m")
                if problem:
                    raise r.error(names[k], f"accuracy (a standard deviation) {problem}")
            s[:3] = [v[6], v[6], v[7]]
        photo.append(im)
        eo.append(row)
        sd.append(s)
        lines.append(r.line)
    if not photo:
        raise FormatError(f"{tl.path}: no image after the CRS line")
    eo_a = np.array(eo)
    if tr is not None:
        e, nn = tr.transform(eo_a[:, 0], eo_a[:, 1])
        eo_a[:, 0], eo_a[:, 1] = e, nn
    return Orientations(np.array(photo, dtype=str), eo_a, np.array(sd), crs_out, height_system,
                        f"{tl.path} (ODM geo.txt, CRS {crs_in.name}; yaw/pitch/roll -> omega/phi/kappa "
                        f"by the Pix4D formula, no meridian convergence)", line=np.array(lines))


def read_odm_cameras(path: str | Path, *, pixel_size_mm: float | None = None) -> dict[str, tuple]:
    """An OpenDroneMap ``cameras.json`` (camera id -> OpenSfM camera dict: ``perspective``, ``brown``,
    ``fisheye``, ``fisheye_opencv``): camera id -> (lidarcat's stand-in camera, source model), as
    :func:`lidarcat.interop.opensfm.opensfm_camera` reads a reconstruction's cameras.

    Raises
    ------
    FormatError
        Invalid JSON, an unsupported projection, a missing or non-numeric field, a fisheye out of
        its valid range (``FILE:LINE: ... camera 'ID' ...``).
    """
    from .opensfm import opensfm_camera

    path = Path(path)
    text = read_text(path, FormatError)
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError) as ex:
        raise format_error(path, getattr(ex, "lineno", None), None, f"invalid JSON: {str(ex)[:120]}") from None
    if not isinstance(doc, dict) or not doc:
        raise format_error(path, 1, None, "expected an object camera id -> camera (an OpenDroneMap cameras.json)")
    return {cid: opensfm_camera(path, text, cid, c, pixel_size_mm) for cid, c in doc.items()}


def write_odm_cameras(block, path: str | Path) -> Path:
    """Write the cameras of *block* as an OpenDroneMap ``cameras.json`` (for ``odm --cameras``), atomically.

    Each camera as :func:`lidarcat.interop.opensfm.write_opensfm` writes it (a fisheye as ``fisheye`` or
    ``fisheye_opencv``), keyed by its id without OpenSfM's ``v2 `` prefix (ODM adds it back).  ODM's
    ``--cameras`` reader (``get_opensfm_camera_models``) keeps the keys of ``brown`` and ``fisheye``
    cameras but drops a ``fisheye_opencv`` camera's ``k4`` as an unknown key.
    """
    from .lens import export_cameras
    from .opensfm import opensfm_camera_dict

    out = {(cid[3:] if cid.startswith("v2 ") else cid): opensfm_camera_dict(m)
           for cid, m in export_cameras(block, rational=False).items()}
    path = Path(path)
    write_text_atomic(path, json.dumps(out, indent=4) + "\n")
    return path
