r"""Omega-phi-kappa orientation text: read (IGN ``.OPK``, Pix4D, Metashape) and write.

Layout
------
One header line naming the columns, then one photo per line; fields separated
by tabs, spaces, commas or semicolons.  Recognised column names (case-insensitive):

=========  ==========================================================
photo      ``NOM`` (IGN), ``imageName`` (Pix4D), ``#Label``/``Label`` (Metashape), ``photo``, ``image``, ``name``
X, Y, Z    ``X``/``Easting``/``X/East``/``E``/``X0``, ``Y``/..., ``Z``/``Altitude``/``Z/Altitude``/``h``/``Z0``
angles     ``O``/``Omega``, ``P``/``Phi``, ``K``/``Kappa`` (with or without ``_deg``)
camera     ``CAMERA``/``camera`` (optional)
sds        ``sd_X`` ... ``sd_kappa`` or ``X_est``/Metashape ``X_est`` are *not* read: give sds on import
=========  ==========================================================

Angle convention (proved by the round trips in the tests): Pix4D's camera-to-world
``R = Rx(omega) Ry(phi) Rz(kappa)`` (active rotations, camera x right, y up,
z back) is the transpose of lidarcat's ``M = R3(kappa) R2(phi) R1(omega)``, and IGN
Borea's ``Rx(pi) from_euler('xyz', -[O, P, K])`` is ``F M``: the three numbers are
the same in all of them (:mod:`lidarcat.interop.rotations`).  Angles are in
degrees unless ``angle_unit`` says ``rad`` or ``gon``.  The files carry no CRS and
no height datum: the caller states them (IGN's Z is an altitude, Lambert-93 E/N in
Borea's examples) and :func:`write_opk` records them in a JSON sidecar.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from .._util import atomic_write, write_json_atomic, write_text_atomic
from .._util.values import parse_number
from ..errors import FormatError
from ._text import TextLines, format_error
from .block import Block, require_orientations
from .merge import Orientations

__all__ = ["read_opk", "write_opk", "read_borea", "read_borea_camera", "read_borea_points",
           "read_borea_measurements", "orthority_int_param", "ANGLE_UNITS", "OPK_FLAVOURS"]

log = logging.getLogger(__name__)

#: OPK flavour -> header of :func:`write_opk`
_HEADERS: dict[str, tuple[str, ...]] = {
    "pix4d": ("imageName", "X", "Y", "Z", "Omega", "Phi", "Kappa"),
    "ign": ("NOM", "X", "Y", "Z", "O", "P", "K", "CAMERA"),
    "orthority": ("filename", "x", "y", "z", "omega", "phi", "kappa", "camera"),
}
OPK_FLAVOURS = tuple(_HEADERS)

#: angle unit -> radians per unit
ANGLE_UNITS: dict[str, float] = {"deg": math.pi / 180, "rad": 1.0, "gon": math.pi / 200}

_ALIASES: dict[str, tuple[str, ...]] = {
    "photo": ("nom", "imagename", "#label", "label", "photo", "image", "name", "filename", "#name"),
    "X": ("x", "easting", "x/east", "e", "x0", "east", "x/longitude", "longitude", "lon"),
    "Y": ("y", "northing", "y/north", "n", "y0", "north", "y/latitude", "latitude", "lat"),
    "Z": ("z", "altitude", "z/altitude", "h", "z0", "alt", "height"),
    "omega": ("o", "omega", "omega_deg", "omega_rad", "omega_gon"),
    "phi": ("p", "phi", "phi_deg", "phi_rad", "phi_gon"),
    "kappa": ("k", "kappa", "kappa_deg", "kappa_rad", "kappa_gon"),
    "camera": ("camera", "cam", "sensor"),
}


def _columns(header: tuple[str, ...], path: Path, line: int) -> dict[str, int]:
    low = [h.strip().lower() for h in header]
    cols: dict[str, int] = {}
    for key, names in _ALIASES.items():
        for i, h in enumerate(low):
            if h in names and i not in cols.values():
                cols[key] = i
                break
    missing = [k for k in ("photo", "X", "Y", "Z", "omega", "phi", "kappa") if k not in cols]
    if missing:
        raise format_error(path, line, missing[0], f"header {' '.join(header)!r} has no column for "
                           f"{', '.join(missing)} (expected e.g. 'NOM X Y Z O P K' or "
                           f"'imageName X Y Z Omega Phi Kappa')")
    return cols


def _sidecar(path: Path, crs: str, height_system: str) -> tuple[str, str]:
    """CRS and height system from the ``<file>.json`` sidecar :func:`write_opk` wrote (else the given)."""
    import json

    side = path.with_name(path.name + ".json")
    if not side.is_file() or side.stat().st_size > 1_000_000:
        return crs, height_system
    try:
        d = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        log.warning("%s: not a sidecar lidarcat wrote; CRS not taken from it", side)
        return crs, height_system
    if not isinstance(d, dict) or not isinstance(d.get("crs"), str):
        return crs, height_system
    hs = d.get("height_system")
    return d["crs"], hs if isinstance(hs, str) and height_system == "unspecified" else height_system


def read_opk(path: str | Path, *, angle_unit: str = "deg", crs: str = "unspecified",
             height_system: str = "unspecified") -> Orientations:
    """Read an omega-phi-kappa orientation file.

    Parameters
    ----------
    path : path
    angle_unit : {"deg", "rad", "gon"}
        Unit of omega, phi, kappa in the file (default degrees).
    crs, height_system : str
        What X, Y, Z are (the file does not say; with ``crs="unspecified"`` the
        ``<file>.json`` sidecar :func:`write_opk` wrote gives them, when present).

    Returns
    -------
    Orientations
        Angles converted to radians; sds NaN.

    Raises
    ------
    FormatError
        ``FILE:LINE: field 'NAME': ...`` for a missing column, a non-numeric or
        non-finite value, a duplicate photo; unknown *angle_unit*.
    """
    if angle_unit not in ANGLE_UNITS:
        raise FormatError(f"angle unit {angle_unit!r} is not one of {', '.join(ANGLE_UNITS)}")
    if crs == "unspecified":
        crs, height_system = _sidecar(Path(path), crs, height_system)
    tl = TextLines(path, comment=None)
    first = next((ln for ln in tl.text.splitlines() if ln.strip()), "")
    tl.split = None if ("," in first or ";" in first) else "ws"  # blanks: a comma is no separator
    rows = list(tl.rows())
    if not rows:
        raise FormatError(f"{tl.path}: empty file, expected a header line (e.g. 'NOM X Y Z O P K')")
    head = rows[0]
    cols = _columns(head.fields, tl.path, head.line)
    hdr = {k: head.fields[i] for k, i in cols.items()}
    unit = ANGLE_UNITS[angle_unit]
    photo, eo, cams, lines = [], [], [], []
    seen: dict[str, int] = {}
    for r in rows[1:]:
        if r.fields[0].startswith("#"):
            continue
        if len(r.fields) != len(head.fields):
            fld = head.fields[len(r.fields)] if len(r.fields) < len(head.fields) else head.fields[-1]
            raise r.error(fld, f"{len(r.fields)} fields, expected {len(head.fields)} "
                               f"({' '.join(head.fields)})")
        name = r.fields[cols["photo"]]
        if name in seen:
            raise r.error(hdr["photo"], f"photo {name!r} already on line {seen[name]}")
        seen[name] = r.line
        vals = ([r.number(cols[k], hdr[k], kind) for k, kind in (("X", "coordinate_m"), ("Y", "coordinate_m"),
                                                                 ("Z", "height_m"))]
                + [r.angle(cols[k], hdr[k], unit) for k in ("omega", "phi", "kappa")])
        photo.append(name)
        eo.append(vals)
        cams.append(r.fields[cols["camera"]] if "camera" in cols else "")
        lines.append(r.line)
    if not photo:
        raise FormatError(f"{tl.path}: no photo after the header line")
    return Orientations(np.array(photo, dtype=str), np.array(eo), np.full((len(photo), 6), np.nan),
                        crs, height_system, f"{tl.path} (omega, phi, kappa in {angle_unit})",
                        np.array(cams, dtype=str), np.array(lines))


def write_opk(block: Block, path: str | Path, *, angle_unit: str = "deg", flavour: str = "pix4d") -> Path:
    """Write the orientations of *block* as omega-phi-kappa text, atomically.

    Parameters
    ----------
    block : Block
        Photos with complete orientations (an adjusted block).
    path : path
        Output file; a sidecar ``<path>.json`` records CRS, height system, angle
        unit and the rotation convention.
    angle_unit : {"deg", "rad", "gon"}
    flavour : {"pix4d", "ign", "orthority"}
        ``pix4d``: header ``imageName X Y Z Omega Phi Kappa`` tab-separated (what
        Pix4D and Metashape import); ``ign``: ``NOM X Y Z O P K CAMERA`` as IGN's
        ``.OPK``; ``orthority``: orthority's CSV exterior parameters
        (``filename,x,y,z,omega,phi,kappa,camera``, comma-separated, degrees; the
        file must end in ``.csv`` or ``.txt``) with the CRS as WKT in a ``.prj``
        sidecar (orthority ``param_io.CsvReader``), when the CRS is a projected one, and
        the cameras in ``<stem>_int_param.yaml`` (:func:`orthority_int_param`).

    Raises
    ------
    FormatError
        A photo without a complete orientation, unknown unit or flavour.
    """
    if angle_unit not in ANGLE_UNITS:
        raise FormatError(f"angle unit {angle_unit!r} is not one of {', '.join(ANGLE_UNITS)}")
    if flavour not in OPK_FLAVOURS:
        raise FormatError(f"OPK flavour {flavour!r} is not one of {', '.join(OPK_FLAVOURS)}")
    require_orientations(block, "an OPK file")
    path = Path(path)
    unit = ANGLE_UNITS[angle_unit]
    prj = None
    if flavour == "orthority":
        if path.suffix.lower() not in (".csv", ".txt"):
            raise FormatError(f"{path}: orthority reads exterior parameters from a .csv or .txt file; give "
                              f"-o {path.with_suffix('.csv').name}")
        if angle_unit != "deg":
            raise FormatError(f"orthority reads omega, phi, kappa in degrees; give --angle-unit deg, not "
                              f"{angle_unit}")
        prj = _projected_wkt(block.crs)
    bad = [p for p in block.photo_ids.tolist() if not p or any(ch.isspace() for ch in p)]
    if bad:
        raise FormatError(f"photo id {bad[0]!r} contains white space; OPK fields are white-space separated")
    sep = "," if flavour == "orthority" else "\t"
    with atomic_write(path) as fh:
        fh.write(sep.join(_HEADERS[flavour]) + "\n")
        for pid, cam, e in zip(block.photo_ids.tolist(), block.photo_camera.tolist(), block.eo):
            cells = [pid] + [repr(float(v)) for v in e[:3]] + [repr(float(v / unit)) for v in e[3:]]
            if flavour != "pix4d":
                cells.append(cam)
            fh.write(sep.join(cells) + "\n")
    if prj is not None:
        write_text_atomic(path.with_suffix(".prj"), prj)
    if flavour == "orthority":
        write_text_atomic(path.with_name(path.stem + "_int_param.yaml"), orthority_int_param(block))
    write_json_atomic(path.with_name(path.name + ".json"), {
        "file": path.name, "crs": block.crs, "height_system": block.height_system,
        "angle_unit": angle_unit, "survey": block.name,
        "convention": "omega, phi, kappa: M = R3(kappa) R2(phi) R1(omega) object to image (lidarcat, "
                      "thesis eq. 08) = transpose of Pix4D's camera-to-world Rx(omega) Ry(phi) Rz(kappa)"})
    log.info("wrote %s: %d photos", path, len(block.photo_ids))
    return path


def orthority_int_param(block: Block) -> str:
    """orthority's interior parameter file (YAML; written as JSON, which YAML reads) of the block's
    cameras in their Brown or fisheye form (:func:`lidarcat.interop.lens.export_camera`; orthority's
    ``fisheye`` is OpenCV's, k1..k4): ``focal_len`` in
    pixels with ``sensor_size`` = the image size, so focal lengths mean the same for portrait and
    landscape images (an OpenSfM camera's normalised focal does not, for orthority, in portrait);
    ``cx, cy`` as OpenSfM's ``c_x, c_y`` (pixels from the image centre over ``max(w, h)``)."""
    import json

    from .lens import export_cameras

    out = {}
    for cid, m in export_cameras(block, rational=False).items():
        s = max(m["w"], m["h"])
        fisheye = m["kind"] == "fisheye"  # orthority's fisheye is OpenCV's (Kannala-Brandt k1..k4)
        keys = ("k1", "k2", "k3", "k4") if fisheye else ("k1", "k2", "k3", "p1", "p2")
        out[cid] = {"type": "fisheye" if fisheye else "brown", "im_size": [m["w"], m["h"]],
                    "focal_len": [m["fx"], m["fy"]], "sensor_size": [float(m["w"]), float(m["h"])],
                    "cx": (m["cx"] - m["w"] / 2) / s, "cy": (m["cy"] - m["h"] / 2) / s,
                    **{k: m["dist"].get(k, 0.0) for k in keys}}
    return json.dumps(out, indent=1) + "\n"


def _projected_wkt(crs: str) -> str | None:
    """WKT of a projected *crs* (for orthority's ``.prj``), else None (logged)."""
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        c = CRS.from_user_input(crs)
    except CRSError:
        log.warning("CRS %r is no CRS pyproj knows: no .prj written (orthority then needs its --crs)", crs)
        return None
    if not c.is_projected:
        log.warning("CRS %r is not projected: no .prj written (orthority needs a projected CRS)", crs)
        return None
    return c.to_wkt()


# ---------------------------------------------------------------------- IGN Borea companions
def read_borea_camera(path: str | Path, *, pixel_size_mm: float = 0.001):
    """An IGN Borea camera file (``key = value``: Name, PPAx, PPAy, focal in pixels, width, height).

    PPAx/PPAy are taken in the pixel frame of the ``.mes`` measurements (read here
    with the lidarcat origin, the centre of the top-left pixel: any common origin
    gives the same geometry).  The camera has no distortion.

    Raises
    ------
    FormatError
        Missing or non-numeric key (``FILE:LINE: field 'KEY'``).
    """
    from ..geometry.camera import Camera

    tl = TextLines(path, comment="#", split="ws")
    vals: dict[str, tuple[str, int]] = {}
    for r in tl.rows():
        text = " ".join(r.fields)
        if "=" not in text:
            raise r.error(None, "expected 'key = value'")
        k, v = (s.strip() for s in text.split("=", 1))
        vals[k] = (v, r.line)
    for key in ("Name", "PPAx", "PPAy", "focal", "width", "height"):
        if key not in vals:
            raise format_error(tl.path, None, key, "missing (a Borea camera file has Name, PPAx, PPAy, "
                               "focal, width, height)")

    def num(key: str) -> float:
        v, line = vals[key]
        try:
            x = parse_number(v, "image_px" if key in ("width", "height") else "pixel_px")
        except ValueError as ex:
            raise format_error(tl.path, line, key, str(ex)) from None
        if key in ("focal", "width", "height") and x <= 0:
            raise format_error(tl.path, line, key, f"{v!r} must be a positive finite number")
        return x

    w, h = int(num("width")), int(num("height"))
    t = float(pixel_size_mm)
    return Camera(vals["Name"][0], focal_length_mm=num("focal") * t,
                  principal_point_x_mm=t * (num("PPAx") - (w - 1) / 2),
                  principal_point_y_mm=-t * (num("PPAy") - (h - 1) / 2), k1=0.0, k2=0.0, k3=0.0,
                  p1=0.0, p2=0.0, refraction_eps45=0.0, pixel_size_x_mm=t, pixel_size_y_mm=t,
                  columns_px=w, rows_px=h, model="IGN Borea camera",
                  source=f"{tl.path.name}: PPA and focal in pixels, pixel pitch {t} mm assumed")


def read_borea_points(path: str | Path, *, sd_m: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground points of an IGN Borea ``.app`` file (``name type X Y H``, header PTXYH).

    Returns ids (G,), coordinates (G, 3) m and the Borea point types (G,) of str
    (``13`` = full control, ``3`` = check in Borea's examples).

    Raises
    ------
    FormatError
        Located (``FILE:LINE: field``).
    """
    tl = TextLines(path, comment="#", split="ws")
    ids, xyz, kind = [], [], []
    seen: dict[str, int] = {}
    for r in tl.rows():
        r.need(5, ("name", "type", "X", "Y", "H"))
        name = r.fields[0].strip('"')
        if name in seen:
            raise r.error("name", f"point {name!r} already on line {seen[name]}: keep one line per point")
        seen[name] = r.line
        ids.append(name)
        kind.append(r.fields[1])
        xyz.append([r.number(2, "X", "coordinate_m"), r.number(3, "Y", "coordinate_m"), r.number(4, "H", "height_m")])
    if not ids:
        raise FormatError(f"{tl.path}: no point")
    return np.array(ids, dtype=str), np.array(xyz), np.array(kind, dtype=str)


def read_borea_measurements(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Image measurements of an IGN Borea ``.mes`` file (``point image column row``, pixels).

    Returns point ids (n,), image names (n,), pixel column/row (n, 2).
    """
    tl = TextLines(path, comment="#", split="ws")
    pt, im, cr = [], [], []
    for r in tl.rows():
        r.need(4, ("point", "image", "column", "row"))
        pt.append(r.fields[0].strip('"'))
        im.append(r.fields[1])
        cr.append([r.number(2, "column", "pixel_px"), r.number(3, "row", "pixel_px")])
    return np.array(pt, dtype=str), np.array(im, dtype=str), np.array(cr).reshape(-1, 2)


def read_borea(opk: str | Path, cameras: list[str | Path], *, points: str | Path | None = None,
               measurements: list[str | Path] = (), crs: str = "unspecified",
               height_system: str = "unspecified", pixel_size_mm: float = 0.001,
               point_sd_m: float = 0.05) -> Block:
    """A block from IGN Borea files: ``.OPK`` orientations, camera files, ``.app`` ground
    points and ``.mes`` image measurements (degrees, as Borea's default ``-u degree``).

    Raises
    ------
    FormatError
        Located errors of any file; a photo naming an unknown camera; a measurement
        on a photo that is not in the OPK file.
    """
    ori = read_opk(opk, crs=crs, height_system=height_system)
    cams = {}
    for c in cameras:
        cam = read_borea_camera(c, pixel_size_mm=pixel_size_mm)
        cams[cam.id] = cam
    for name, cam, line in zip(ori.photo.tolist(), ori.camera.tolist(), ori.line.tolist()):
        if cam not in cams:
            raise format_error(opk, line, "CAMERA", f"camera {cam!r} of photo {name!r} is not among the "
                               f"camera files ({', '.join(cams) or 'none given'}): give its camera file "
                               f"(--camera)")
    o_pt, o_im, o_px = [np.empty(0, str)], [np.empty(0, str)], [np.empty((0, 2))]
    for m in measurements:
        p, i, c = read_borea_measurements(m)
        unknown = sorted(set(i.tolist()) - set(ori.photo.tolist()))
        if unknown:
            raise FormatError(f"{m}: image {unknown[0]!r} is not in {opk}: give the .mes files of the same "
                              f"block, or add the photo to the .OPK file")
        o_pt.append(p)
        o_im.append(i)
        o_px.append(c)
    gid, gxyz = np.empty(0, str), np.empty((0, 3))
    if points is not None:
        gid, gxyz, _ = read_borea_points(points)
    px = np.vstack(o_px)
    return Block(name=Path(opk).stem, crs=crs, height_system=height_system, cameras=cams,
                 photo_ids=ori.photo, photo_camera=ori.camera, eo=ori.eo,
                 obs_photo=np.concatenate(o_im), obs_point=np.concatenate(o_pt), obs_px=px,
                 obs_mm=np.full_like(px, np.nan), ground_ids=gid, ground_m=gxyz,
                 ground_sd_m=np.full((len(gid), 3), float(point_sd_m)),
                 ground_source=np.full(len(gid), "borea"),
                 description=f"imported from IGN Borea files {Path(opk).name}")
