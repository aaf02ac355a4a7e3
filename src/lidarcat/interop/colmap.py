r"""COLMAP text models (``cameras.txt``, ``images.txt``, ``points3D.txt``): read and write.

Conventions (COLMAP documentation, "Output format")
---------------------------------------------------
* ``images.txt``: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then a line of
  ``X Y POINT3D_ID`` triples.  ``x_cam = R(q) X + t`` maps **world to camera**,
  camera x right, **y down, z forward**; ``q`` is a Hamilton quaternion, scalar
  first.  In lidarcat's convention (:mod:`lidarcat.interop.rotations`)
  ``M = F R`` with ``F = diag(1, -1, -1)`` and the projection centre is
  ``X0 = -R^T t``.
* Pixel coordinates have the **upper-left image corner** at (0, 0): the centre of
  the top-left pixel is (0.5, 0.5).  lidarcat counts from the pixel centre, so
  ``col_px = X - 0.5``, ``row_px = Y - 0.5``.
* Camera models map onto lidarcat's camera (pixel pitch ``t`` chosen by the
  caller, default 0.001 mm, since COLMAP knows none): ``focal_length_mm = fx t``,
  ``pixel_size_y_mm = t fx / fy`` (non-square pixels reproduce fx != fy
  exactly), principal point ``dx = t (cx - W/2)``, ``dy = -t_y (cy - H/2)``
  (eq. 01-02 with the corner origin above).  Distortion (``SIMPLE_RADIAL``,
  ``RADIAL``, ``OPENCV``, ``FULL_OPENCV``) is of the forward kind, which
  lidarcat's correction polynomial cannot represent: the observations are
  undistorted exactly on import (:mod:`lidarcat.interop._distortion`) and enter
  as corrected photo coordinates ``x_mm = f x_u``, ``y_mm = -f y_u``; the camera
  keeps zero distortion and its ``source`` records the original model.
* Export writes every camera as the COLMAP model of its Brown form
  (:mod:`lidarcat.interop.lens`: a source model unchanged, a distortion-free camera
  exactly, lidarcat's correction polynomial fitted, its largest misfit in px in the
  header of ``cameras.txt``): ``SIMPLE_PINHOLE``/``PINHOLE`` without distortion,
  ``OPENCV`` (k1, k2, p1, p2) or ``FULL_OPENCV``; 2D points are the measured pixels
  (corner origin), so the exported model fits the original images.

The model is not georeferenced: the survey gets ``crs = "local: COLMAP model
frame"`` unless the caller gives the CRS it was aligned to.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, read_text, write_text_atomic
from ..geometry.camera import Camera
from ..errors import FormatError
from ._distortion import is_identity
from .._util.values import parse_number, parse_whole
from ._text import format_error
from .block import Block, require_orientations
from .cameras import MAX_RAY_ANGLE_DEG, check_source_model, ideal_observations, pinhole_camera
from .lens import export_cameras, notes, observed_pixels
from .rigs import check_rigs, read_colmap_rigs_text, write_colmap_rigs
from .rotations import matrix_to_quaternion_wxyz, opk_to_world_to_cv, quaternion_wxyz_to_matrix, world_to_cv_to_opk

__all__ = ["read_colmap", "write_colmap", "block_from_model", "colmap_camera", "COLMAP_MODELS", "LOCAL_CRS"]

log = logging.getLogger(__name__)

#: model name -> parameter names (COLMAP src/colmap/sensor/models.h)
COLMAP_MODELS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k1"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
    "SIMPLE_FISHEYE": ("f", "cx", "cy"),
    "FISHEYE": ("fx", "fy", "cx", "cy"),
}
#: crs written for a model that is not georeferenced
LOCAL_CRS = "local: COLMAP model frame (not georeferenced)"
_FILES = ("cameras.txt", "images.txt", "points3D.txt")
#: sane ranges of a model point's X, Y, Z (the projection centres' too)
_XYZ_KINDS = ("coordinate_m", "coordinate_m", "height_m")


def _lines(path: Path):
    """(line number, text) of every line that is no comment (blank lines kept)."""
    for no, raw in enumerate(read_text(path, FormatError).splitlines(), start=1):
        if raw.lstrip().startswith("#"):
            continue
        yield no, raw


def _num(path: Path, line: int, field: str, cell: str, kind: str | None = None) -> float:
    """A finite ASCII number in the sane range of *kind* (:data:`lidarcat._util.values.VALUE_RANGES`)."""
    try:
        return parse_number(cell, kind)
    except ValueError as ex:
        raise format_error(path, line, field, str(ex)) from None


def _int(path: Path, line: int, field: str, cell: str, kind: str | None = None) -> int:
    try:
        return parse_whole(cell, kind)
    except ValueError as ex:
        raise format_error(path, line, field, str(ex)) from None


def _read_cameras(path: Path, pixel_size_mm: float | None):
    cams: dict[str, tuple[Camera, dict]] = {}
    for no, raw in _lines(path):
        f = raw.split()
        if not f:
            continue
        if len(f) < 4:
            raise format_error(path, no, "MODEL" if len(f) < 2 else "WIDTH" if len(f) < 3 else "HEIGHT",
                               "missing: a camera line is CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")
        cid = str(_int(path, no, "CAMERA_ID", f[0]))
        model = f[1]
        if model not in COLMAP_MODELS:
            raise format_error(path, no, "MODEL", f"camera {cid}: camera model {model!r} is not supported "
                               f"(supported: {', '.join(COLMAP_MODELS)})")
        names = COLMAP_MODELS[model]
        w, h = _int(path, no, "WIDTH", f[2]), _int(path, no, "HEIGHT", f[3])
        if w < 1 or h < 1:
            raise format_error(path, no, "WIDTH" if w < 1 else "HEIGHT", "must be at least 1 pixel")
        w, h = _int(path, no, "WIDTH", f[2], "image_px"), _int(path, no, "HEIGHT", f[3], "image_px")
        if len(f) != 4 + len(names):
            raise format_error(path, no, "PARAMS", f"model {model} has {len(names)} parameters "
                               f"({' '.join(names)}), the line has {len(f) - 4}")
        p = {n: _num(path, no, n, c, "pixel_px" if n in ("f", "fx", "fy", "cx", "cy") else None)
             for n, c in zip(names, f[4:])}
        fx = p.get("fx", p.get("f"))
        fy = p.get("fy", p.get("f"))
        if fx <= 0 or fy <= 0:  # type: ignore[operator]
            raise format_error(path, no, "fx" if "fx" in p else "f", "focal length must be positive")
        if cid in cams:
            raise format_error(path, no, "CAMERA_ID", f"camera {cid} defined twice")
        cams[cid] = colmap_camera(cid, model, w, h, p, pixel_size_mm,
                                  f"{path.parent.name}/{path.name}:{no}", f"{path}:{no}")
    if not cams:
        raise FormatError(f"{path}: no camera defined")
    return cams


def colmap_camera(cid: str, model: str, w: int, h: int, p: dict[str, float], pixel_size_mm: float | None,
                  label: str, where: str) -> tuple[Camera, dict]:
    """lidarcat's stand-in camera and the source model of a COLMAP camera (:mod:`lidarcat.interop.cameras`).

    *p* maps the parameter names of :data:`COLMAP_MODELS` to values; *label* goes into the camera's
    ``source``, *where* (``FILE:LINE`` or ``FILE: byte N``) into errors.

    Raises
    ------
    FormatError
        A fisheye whose parameters are out of the model's valid range (``WHERE: camera 'ID': field ...``).
    """
    fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
    dist = {k: v for k, v in p.items() if k[0] in "kp"}
    fisheye = model.endswith("FISHEYE")
    cam, model_dict = pinhole_camera(
        cid, fx, fy, p["cx"], p["cy"], w, h, pixel_size_mm=pixel_size_mm, model=f"COLMAP {model}",
        source=f"{label}: {model} " + " ".join(f"{n}={v!r}" for n, v in p.items())
        + ("; observations made ideal through the fisheye model on import" if fisheye else
           "" if is_identity(dist) else "; distortion removed from the observations on import"),
        dist=dist, kind="fisheye" if fisheye else "brown")
    check_source_model(cid, model_dict, where)
    return cam, model_dict


def _written_crs(path: Path, crs: str, height_system: str) -> tuple[str, str]:
    """CRS and heights from the ``# written by lidarcat ..., CRS X, heights Y`` comment of a model
    :func:`write_colmap` wrote (else the given ones)."""
    import re

    with open(path, encoding="utf-8", errors="replace") as fh:
        for raw in fh:
            if not raw.startswith("#"):
                break
            m = re.match(r"# written by lidarcat from survey .*, CRS (.+), heights (.+)$", raw.rstrip("\n"))
            if m:
                return m.group(1), m.group(2)
    return crs, height_system


def read_colmap(folder: str | Path, *, pixel_size_mm: float | None = None, name: str | None = None,
                crs: str = LOCAL_CRS, height_system: str = "unspecified (model frame)") -> Block:
    """Read a COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``).

    Parameters
    ----------
    folder : path
        The model folder.
    pixel_size_mm : float, optional
        Pixel pitch given to the cameras, mm (COLMAP works in pixels only; any
        value gives the same geometry, 0.001 makes ``x_mm = px / 1000``); default
        :func:`lidarcat.interop.cameras.default_pixel_size_mm` (0.001, or 0.01 for a
        focal length under 500 px).
    name, crs, height_system : str
        Survey name (default: the folder name), CRS of the model frame and its heights
        (default: those :func:`write_colmap` wrote in the header of ``images.txt``, else a
        local frame).

    Returns
    -------
    Block
        Photo ids are the image NAMEs, point ids the POINT3D_IDs; only 2D points
        with a 3D point are kept (id -1 = not triangulated).

    Raises
    ------
    FormatError
        A missing file, a malformed line (``FILE:LINE: field 'NAME': ...``), an
        unknown camera model, an image naming an unknown camera, a 2D point naming
        an unknown 3D point.
    """
    folder = Path(folder)
    for fname in _FILES:
        if not (folder / fname).is_file():
            raise FormatError(f"{folder / fname}: file not found (a COLMAP text model has "
                              f"{', '.join(_FILES)}; convert a binary model with "
                              f"'colmap model_converter --output_type TXT')")
    if pixel_size_mm is not None and not (pixel_size_mm > 0 and math.isfinite(pixel_size_mm)):
        raise FormatError(f"pixel_size_mm must be a positive number, got {pixel_size_mm!r}")
    cams = _read_cameras(folder / "cameras.txt", pixel_size_mm)

    ppath = folder / "points3D.txt"
    pids: list[str] = []
    pxyz: list[list[float]] = []
    seen: set[str] = set()
    for no, raw in _lines(ppath):
        f = raw.split()
        if not f:
            continue
        if len(f) < 8:
            raise format_error(ppath, no, ("POINT3D_ID", "X", "Y", "Z", "R", "G", "B", "ERROR")[len(f)],
                               "missing: POINT3D_ID X Y Z R G B ERROR TRACK[]")
        pid = str(_int(ppath, no, "POINT3D_ID", f[0]))
        if pid in seen:
            raise format_error(ppath, no, "POINT3D_ID", f"point {pid} listed twice")
        seen.add(pid)
        pids.append(pid)
        pxyz.append([_num(ppath, no, n, c, k) for n, c, k in zip("XYZ", f[1:4], _XYZ_KINDS)])

    ipath = folder / "images.txt"
    if crs == LOCAL_CRS:  # a model lidarcat wrote carries its CRS in a comment of images.txt
        crs, height_system = _written_crs(ipath, crs, height_system)
    photo, pcam, eo = [], [], []
    o_photo: list[str] = []
    o_point: list[str] = []
    o_xy: list[np.ndarray] = []
    o_cam: list[str] = []
    names: set[str] = set()
    image_ids: dict[int, str] = {}
    lines = list(_lines(ipath))
    i = 0
    while i < len(lines):
        no, raw = lines[i]
        f = raw.split()
        if not f:
            i += 1
            continue
        if len(f) < 10:
            fields = ("IMAGE_ID", "QW", "QX", "QY", "QZ", "TX", "TY", "TZ", "CAMERA_ID", "NAME")
            raise format_error(ipath, no, fields[len(f)],
                               "missing: IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME")
        # kapture's COLMAP export writes "1, 0.95, ..., 2, NAME": the commas are dropped (pycolmap 4 refuses them)
        f = [c[:-1] if k < 9 and c.endswith(",") else c for k, c in enumerate(f)]
        iid = _int(ipath, no, "IMAGE_ID", f[0])
        q = np.array([_num(ipath, no, n, c) for n, c in zip(("QW", "QX", "QY", "QZ"), f[1:5])])
        tt = np.array([_num(ipath, no, n, c, "coordinate_m") for n, c in zip(("TX", "TY", "TZ"), f[5:8])])
        if not 0.5 < np.linalg.norm(q) < 2.0:
            raise format_error(ipath, no, "QW", f"quaternion of norm {np.linalg.norm(q):.3g} is no rotation")
        cid = str(_int(ipath, no, "CAMERA_ID", f[8]))
        if cid not in cams:
            raise format_error(ipath, no, "CAMERA_ID", f"camera {cid} is not in cameras.txt")
        img = " ".join(f[9:])
        if img in names:
            raise format_error(ipath, no, "NAME", f"image {img!r} listed twice")
        names.add(img)
        r = quaternion_wxyz_to_matrix(q)
        photo.append(img)
        image_ids[iid] = img
        pcam.append(cid)
        eo.append(np.concatenate([-r.T @ tt, world_to_cv_to_opk(r)]))
        pts_no, pts_raw = lines[i + 1] if i + 1 < len(lines) else (no + 1, "")
        cells = pts_raw.split()
        if len(cells) % 3:
            raise format_error(ipath, pts_no, "POINTS2D", f"{len(cells)} values; POINTS2D are "
                               f"(X, Y, POINT3D_ID) triples")
        if cells:
            arr = np.array([_num(ipath, pts_no, ("X", "Y", "POINT3D_ID")[k % 3], c,
                                 "pixel_px" if k % 3 < 2 else None) for k, c in enumerate(cells)]).reshape(-1, 3)
            use = arr[:, 2] >= 0
            ids = [str(int(v)) for v in arr[use, 2]]
            unknown = [p for p in ids if p not in seen]
            if unknown:
                raise format_error(ipath, pts_no, "POINT3D_ID", f"point {unknown[0]} is not in points3D.txt")
            o_photo += [img] * len(ids)
            o_point += ids
            o_xy.append(arr[use, :2])
            o_cam += [cid] * len(ids)
        i += 2
    if not photo:
        raise FormatError(f"{ipath}: no image")
    blk = block_from_model(ipath, cams, photo, pcam, eo, o_photo, o_point, o_xy, o_cam, pids, pxyz,
                           name=name or folder.name, crs=crs, height_system=height_system,
                           description=f"imported from the COLMAP model {folder}")
    if (folder / "rigs.txt").is_file() and (folder / "frames.txt").is_file():
        rigs = read_colmap_rigs_text(folder, image_ids, dict(zip(photo, pcam)))
        check_rigs(rigs, blk, str(folder / "frames.txt"))
        blk = blk.with_(rigs=rigs)
    return blk


def block_from_model(where: Path, cams: dict[str, tuple], photo: list[str], pcam: list[str], eo: list,
                     o_photo: list[str], o_point: list[str], o_xy: list[np.ndarray], o_cam: list[str],
                     pids: list[str], pxyz: Any, *, name: str, crs: str, height_system: str,
                     description: str) -> Block:
    """The :class:`Block` of a COLMAP model read by the text or the binary reader.

    A 2D point that repeats a 3D point already measured on the same image keeps its first
    measurement (logged, naming *where*); pixel positions (COLMAP: the corner of the first
    pixel at 0, 0) become lidarcat's (centre of the first pixel at 0, 0) and corrected photo
    coordinates through each camera's model.
    """
    xy = np.vstack(o_xy) if o_xy else np.empty((0, 2))
    keys = np.char.add(np.char.add(np.array(o_photo, dtype=str), "\x00"), np.array(o_point, dtype=str))
    _, first = np.unique(keys, return_index=True)
    if len(first) < len(keys):
        log.warning("%s: %d 2D point(s) repeat a 3D point already measured on the same image; "
                    "the first measurement is kept", where, len(keys) - len(first))
        first = np.sort(first)
        xy = xy[first]
        o_photo = [o_photo[k] for k in first]
        o_point = [o_point[k] for k in first]
        o_cam = [o_cam[k] for k in first]
    cam_arr = np.array(o_cam, dtype=str)
    obs_mm = np.empty_like(xy)
    sd = np.full_like(xy, np.nan)
    keep = np.ones(len(xy), dtype=bool)
    for cid, (cam, model_dict) in cams.items():
        rows = cam_arr == cid
        if rows.any():
            obs_mm[rows], keep[rows], sd[rows] = ideal_observations(xy[rows], cam, model_dict, where=str(where))
    if not keep.all():
        description += (f"; {int((~keep).sum())} observation(s) of rays beyond {MAX_RAY_ANGLE_DEG:g} deg from a "
                        f"fisheye's axis skipped")
        xy, obs_mm, sd = xy[keep], obs_mm[keep], sd[keep]
        o_photo = [p for p, k in zip(o_photo, keep) if k]
        o_point = [p for p, k in zip(o_point, keep) if k]
    return Block(
        name=name, crs=crs, height_system=height_system,
        cameras={c: v[0] for c, v in cams.items()}, photo_ids=np.array(photo, dtype=str),
        photo_camera=np.array(pcam, dtype=str), eo=np.array(eo), obs_photo=np.array(o_photo, dtype=str),
        obs_point=np.array(o_point, dtype=str), obs_px=xy - 0.5, obs_mm=obs_mm,
        point_ids=np.array(pids, dtype=str), points_m=np.array(pxyz, dtype=float).reshape(-1, 3),
        description=description, source_models={c: v[1] for c, v in cams.items()},
        obs_sd_mm=sd if np.isfinite(sd).any() else None)


def _r(v: float) -> str:
    """Shortest text that reads back to the same float64."""
    return repr(float(v))


def _colmap_model(m: dict):
    """(COLMAP model name, params, dict) reproducing a Brown or fisheye model (:mod:`lidarcat.interop.lens`)
    exactly: the simplest COLMAP model that holds its parameters."""
    d = {k: v for k, v in m["dist"].items() if v != 0.0}
    fx, fy, cx, cy = m["fx"], m["fy"], m["cx"], m["cy"]
    g = lambda k: m["dist"].get(k, 0.0)  # noqa: E731
    if m["kind"] == "fisheye":
        if fx == fy and set(d) <= {"k1"}:
            return "SIMPLE_RADIAL_FISHEYE", [fx, cx, cy, g("k1")], m
        if fx == fy and set(d) <= {"k1", "k2"}:
            return "RADIAL_FISHEYE", [fx, cx, cy, g("k1"), g("k2")], m
        return "OPENCV_FISHEYE", [fx, fy, cx, cy, g("k1"), g("k2"), g("k3"), g("k4")], m
    if not d and fx == fy:
        return "SIMPLE_PINHOLE", [fx, cx, cy], m
    if not d:
        return "PINHOLE", [fx, fy, cx, cy], m
    if fx == fy and set(d) <= {"k1"}:
        return "SIMPLE_RADIAL", [fx, cx, cy, g("k1")], m
    if fx == fy and set(d) <= {"k1", "k2"}:
        return "RADIAL", [fx, cx, cy, g("k1"), g("k2")], m
    if set(d) <= {"k1", "k2", "p1", "p2"}:
        return "OPENCV", [fx, fy, cx, cy, g("k1"), g("k2"), g("p1"), g("p2")], m
    return "FULL_OPENCV", [fx, fy, cx, cy] + [g(k) for k in ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")], m


def _int_ids(ids: list[str]) -> list[int]:
    """The ids as COLMAP integers: themselves when all are distinct whole numbers >= 0 (>= 1
    for images and cameras), else 1..n in order."""
    try:
        vals = [int(i) for i in ids]
        if len(set(vals)) == len(vals) and all(v >= 1 for v in vals) and all(str(v) == i for v, i in zip(vals, ids)):
            return vals
    except ValueError:
        pass
    return list(range(1, len(ids) + 1))


def write_colmap(block: Block, folder: str | Path) -> Path:
    """Write *block* as a COLMAP text model, atomically.

    Every camera is written as the COLMAP model of its Brown form
    (:func:`lidarcat.interop.lens.export_camera`: a COLMAP/OpenSfM source model
    unchanged, a distortion-free or Metashape camera exactly, lidarcat's correction
    polynomial fitted), with the measured pixels.

    Photo ids become image NAMEs (and IMAGE_IDs when they are whole numbers),
    point ids POINT3D_IDs when whole numbers (else 1..n, in block order; the
    mapping is in the header comment of points3D.txt).  Points without
    coordinates are left out; their 2D points get POINT3D_ID -1.

    Raises
    ------
    FormatError
        A photo without a complete orientation.
    """
    folder = Path(folder)
    require_orientations(block, "COLMAP")
    models = export_cameras(block)
    cam_ids = list(block.cameras)
    cam_num = dict(zip(cam_ids, range(1, len(cam_ids) + 1)))
    cam_lines = []
    for cid in cam_ids:
        model, params, m = _colmap_model(models[cid])
        cam_lines.append(f"{cam_num[cid]} {model} {m['w']} {m['h']} {' '.join(_r(v) for v in params)}")
    has_xyz = np.isfinite(block.points_m).all(axis=1)
    pt_ids = block.point_ids[has_xyz].tolist()
    pt_num = dict(zip(pt_ids, _int_ids(pt_ids)))
    img_ids = dict(zip(block.photo_ids.tolist(), _int_ids(block.photo_ids.tolist())))
    pix = observed_pixels(block)
    tracks: dict[str, list[tuple[int, int]]] = {p: [] for p in pt_ids}
    img_lines = []
    r_all = opk_to_world_to_cv(block.eo[:, 3:])
    for i, pid in enumerate(block.photo_ids.tolist()):
        r = r_all[i]
        q = matrix_to_quaternion_wxyz(r)
        t = -r @ block.eo[i, :3]
        rows = np.flatnonzero(block.obs_photo == pid)
        pts = []
        for k, j in enumerate(rows):
            pnt = block.obs_point[j]
            num = pt_num.get(pnt, -1)
            if num >= 0:
                tracks[pnt].append((img_ids[pid], k))
            x, y = pix[j]  # the measured pixels, corner origin
            pts.append(f"{_r(x)} {_r(y)} {num}")
        img_lines.append(f"{img_ids[pid]} {' '.join(_r(v) for v in q)} "
                         f"{' '.join(_r(v) for v in t)} {cam_num[block.photo_camera[i]]} {pid}")
        img_lines.append(" ".join(pts))
    pt_lines = []
    for pnt, xyz in zip(pt_ids, block.points_m[has_xyz]):
        tr = " ".join(f"{a} {b}" for a, b in tracks[pnt])
        pt_lines.append(f"{pt_num[pnt]} {_r(xyz[0])} {_r(xyz[1])} {_r(xyz[2])} 128 128 128 -1 {tr}".rstrip())
    renamed = [f"{n}={p}" for p, n in pt_num.items() if str(n) != p]
    with atomic_dir(folder) as tmp:
        write_text_atomic(tmp / "cameras.txt", (
            "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n"
            f"# Number of cameras: {len(cam_lines)}\n# written by lidarcat (cameras "
            f"{', '.join(f'{n}={c}' for c, n in cam_num.items())})\n"
            + "\n".join(cam_lines) + "\n"
            + "".join(f"# {line}\n" for line in notes(models))))  # after the cameras: lines keep their numbers
        write_text_atomic(tmp / "images.txt", (
            "# Image list with two lines of data per image:\n"
            "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n#   POINTS2D[] as (X, Y, POINT3D_ID)\n"
            f"# Number of images: {len(img_ids)}\n# written by lidarcat from survey {block.name!r}, "
            f"CRS {block.crs}, heights {block.height_system}\n" + "\n".join(img_lines) + "\n"))
        write_text_atomic(tmp / "points3D.txt", (
            "# 3D point list with one line of data per point:\n"
            "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n"
            f"# Number of points: {len(pt_lines)}\n"
            + (f"# lidarcat point ids: {' '.join(renamed)}\n" if renamed else "")
            + "\n".join(pt_lines) + ("\n" if pt_lines else "")))
        if block.rigs is not None:
            rigs_txt, frames_txt = write_colmap_rigs(block, cam_num, img_ids)
            write_text_atomic(tmp / "rigs.txt", rigs_txt)
            write_text_atomic(tmp / "frames.txt", frames_txt)
    log.info("wrote COLMAP model %s: %d cameras, %d images, %d points", folder, len(cam_lines),
             len(img_ids), len(pt_lines))
    return folder
