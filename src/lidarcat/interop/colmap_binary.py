r"""COLMAP binary models (``cameras.bin``, ``images.bin``, ``points3D.bin``): read into a Block.

The binary files hold what the text files of :mod:`.colmap` hold, little-endian (COLMAP
``src/colmap/scene/reconstruction_io_binary.cc``)::

    cameras.bin   uint64 n; n x (uint32 CAMERA_ID, int32 MODEL_ID, uint64 WIDTH, uint64 HEIGHT,
                  double PARAMS[k(MODEL_ID)])
    images.bin    uint64 n; n x (uint32 IMAGE_ID, double QW QX QY QZ, double TX TY TZ,
                  uint32 CAMERA_ID, char NAME[] 0-terminated, uint64 m,
                  m x (double X, double Y, uint64 POINT3D_ID))
    points3D.bin  uint64 n; n x (uint64 POINT3D_ID, double X Y Z, uint8 R G B, double ERROR,
                  uint64 t, t x (uint32 IMAGE_ID, uint32 POINT2D_IDX))

COLMAP 3.12 and later add the rigs and frames (``rigs.bin``, ``frames.bin``; read by
:func:`read_colmap_rigs_binary`)::

    rigs.bin      uint64 n; n x (uint32 RIG_ID, uint32 NUM_SENSORS, int32 REF_TYPE, uint32 REF_ID,
                  (NUM_SENSORS - 1) x (int32 TYPE, uint32 ID, uint8 HAS_POSE,
                  [double QW QX QY QZ TX TY TZ]  -- sensor_from_rig, when HAS_POSE)
    frames.bin    uint64 n; n x (uint32 FRAME_ID, uint32 RIG_ID, double QW QX QY QZ TX TY TZ
                  -- rig_from_world, uint32 m, m x (int32 TYPE, uint32 SENSOR_ID, uint64 DATA_ID))

(sensor type 0 is a camera, 1 an IMU; a camera's DATA_ID is an IMAGE_ID).  An image's pose is
``cam_from_world = sensor_from_rig * rig_from_world`` (rigid transforms ``x -> R x + t``).

``POINT3D_ID = 2^64 - 1`` marks a 2D point without a 3D point.  The conventions (world to
camera, y down, corner pixel origin, the camera models and their undistortion on import) are
those of :func:`lidarcat.interop.colmap.read_colmap`, and :func:`read_colmap_binary` returns the
same :class:`~lidarcat.interop.block.Block` as the text reader on the ``write_text`` of the same
model (only the ``source`` of the cameras and the description name the binary files).  A
malformed file is refused with the file, the byte offset and the field.
"""

from __future__ import annotations

import logging
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._util.values import value_problem
from ..errors import FormatError
from .block import Block
from .colmap import COLMAP_MODELS, LOCAL_CRS, block_from_model, colmap_camera
from .rigs import check_rigs, rigs_from_colmap_binary
from .rotations import quaternion_wxyz_to_matrix, world_to_cv_to_opk

__all__ = ["read_colmap_binary", "read_colmap_rigs_binary", "ColmapRig", "ColmapFrame", "COLMAP_MODEL_IDS"]

log = logging.getLogger(__name__)

#: COLMAP model id -> (name, number of parameters) (src/colmap/sensor/models.h)
COLMAP_MODEL_IDS: dict[int, tuple[str, int]] = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12), 11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
    12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5), 14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6),
    17: ("EQUIRECTANGULAR", 2),
}
_FILES = ("cameras.bin", "images.bin", "points3D.bin")
_INVALID_ID = 2**64 - 1
_POINT2D = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<u8")])


class _Reader:
    """A little-endian cursor over one file's bytes; errors name the file, byte offset and field."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self.data = path.read_bytes()
        except OSError as ex:
            raise FormatError(f"{path}: cannot be read ({ex.strerror or ex})") from None
        self.pos = 0

    def error(self, field: str, message: str, pos: int | None = None) -> FormatError:
        return FormatError(f"{self.path}: byte {self.pos if pos is None else pos}: field {field!r}: {message}")

    def take(self, fmt: str, field: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise self.error(field, f"the file ends after {len(self.data)} bytes (truncated)")
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def number(self, fmt: str, field: str, kind: str | None = None) -> float:
        start = self.pos
        (v,) = self.take(fmt, field)
        problem = value_problem(float(v), kind) if kind else (None if math.isfinite(v) else f"{v!r} is not finite")
        if problem:
            raise self.error(field, problem, start)
        return float(v)

    def count(self, field: str, item_bytes: int) -> int:
        """A uint64 count whose items (at least *item_bytes* each) fit in the rest of the file."""
        start = self.pos
        (n,) = self.take("Q", field)
        if n * item_bytes > len(self.data) - self.pos:
            raise self.error(field, f"{n} items cannot fit in the {len(self.data) - self.pos} bytes left "
                                    f"(truncated or not a COLMAP binary file)", start)
        return int(n)

    def name(self, field: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise self.error(field, "the name has no terminating 0 byte (truncated)")
        raw = self.data[self.pos:end]
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise self.error(field, "the name is not UTF-8") from None
        self.pos = end + 1
        return text

    def end(self) -> None:
        if self.pos != len(self.data):
            raise self.error("end", f"{len(self.data) - self.pos} byte(s) after the last record")


def _read_cameras(path: Path, pixel_size_mm: float | None) -> dict[str, tuple]:
    rd = _Reader(path)
    cams: dict[str, tuple] = {}
    for _ in range(rd.count("num_cameras", 24)):
        start = rd.pos
        (cid_raw, model_id) = rd.take("Ii", "CAMERA_ID")
        cid = str(cid_raw)
        if model_id not in COLMAP_MODEL_IDS:
            raise rd.error("MODEL_ID", f"unknown COLMAP camera model id {model_id}", start + 4)
        model = COLMAP_MODEL_IDS[model_id][0]
        if model not in COLMAP_MODELS:
            raise rd.error("MODEL_ID", f"camera {cid}: camera model {model!r} is not supported (supported: "
                           f"{', '.join(COLMAP_MODELS)})", start + 4)
        w = int(rd.number("Q", "WIDTH", "image_px"))
        h = int(rd.number("Q", "HEIGHT", "image_px"))
        names = COLMAP_MODELS[model]
        p = {n: rd.number("d", n, "pixel_px" if n in ("f", "fx", "fy", "cx", "cy") else None) for n in names}
        fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
        if fx <= 0 or fy <= 0:  # type: ignore[operator]
            raise rd.error("fx" if "fx" in p else "f", "focal length must be positive", start)
        if cid in cams:
            raise rd.error("CAMERA_ID", f"camera {cid} defined twice", start)
        cams[cid] = colmap_camera(cid, model, w, h, p, pixel_size_mm, f"{path.parent.name}/{path.name}@{start}",
                                  f"{path}: byte {start}")
    rd.end()
    if not cams:
        raise FormatError(f"{path}: no camera defined")
    return cams


def _read_points(path: Path) -> tuple[list[str], np.ndarray]:
    rd = _Reader(path)
    n = rd.count("num_points3D", 51)
    ids: list[str] = []
    xyz = np.empty((n, 3))
    seen: set[int] = set()
    for i in range(n):
        start = rd.pos
        (pid,) = rd.take("Q", "POINT3D_ID")
        if pid in seen:
            raise rd.error("POINT3D_ID", f"point {pid} listed twice", start)
        seen.add(pid)
        ids.append(str(pid))
        for a, (fld, kind) in enumerate((("X", "coordinate_m"), ("Y", "coordinate_m"), ("Z", "height_m"))):
            xyz[i, a] = rd.number("d", fld, kind)
        rd.take("3Bd", "RGB")
        track = rd.count("TRACK_LENGTH", 8)
        rd.pos += 8 * track
    rd.end()
    return ids, xyz


def read_colmap_binary(folder: str | Path, *, pixel_size_mm: float | None = None, name: str | None = None,
                       crs: str = LOCAL_CRS, height_system: str = "unspecified (model frame)") -> Block:
    """Read a COLMAP binary model (``cameras.bin``, ``images.bin``, ``points3D.bin``).

    Parameters and result as :func:`lidarcat.interop.colmap.read_colmap`.

    Raises
    ------
    FormatError
        A missing or truncated file, a value out of range (``FILE: byte N: field 'NAME': ...``),
        an unsupported camera model, an image naming an unknown camera, a 2D point naming an
        unknown 3D point.
    """
    folder = Path(folder)
    for fname in _FILES:
        if not (folder / fname).is_file():
            raise FormatError(f"{folder / fname}: file not found (a COLMAP binary model has "
                              f"{', '.join(_FILES)})")
    if pixel_size_mm is not None and not (pixel_size_mm > 0 and math.isfinite(pixel_size_mm)):
        raise FormatError(f"pixel_size_mm must be a positive number, got {pixel_size_mm!r}")
    cams = _read_cameras(folder / "cameras.bin", pixel_size_mm)
    pids, pxyz = _read_points(folder / "points3D.bin")
    known = set(pids)

    rd = _Reader(folder / "images.bin")
    photo, pcam, eo = [], [], []
    o_photo: list[str] = []
    o_point: list[str] = []
    o_xy: list[np.ndarray] = []
    o_cam: list[str] = []
    names: set[str] = set()
    image_ids: dict[int, str] = {}
    for _ in range(rd.count("num_images", 64)):
        start = rd.pos
        (iid,) = rd.take("I", "IMAGE_ID")
        q = np.array([rd.number("d", f) for f in ("QW", "QX", "QY", "QZ")])
        tt = np.array([rd.number("d", f, "coordinate_m") for f in ("TX", "TY", "TZ")])
        if not 0.5 < np.linalg.norm(q) < 2.0:
            raise rd.error("QW", f"quaternion of norm {np.linalg.norm(q):.3g} is no rotation", start + 4)
        (cid_raw,) = rd.take("I", "CAMERA_ID")
        cid = str(cid_raw)
        if cid not in cams:
            raise rd.error("CAMERA_ID", f"camera {cid} is not in cameras.bin", rd.pos - 4)
        img = rd.name("NAME")
        if img in names:
            raise rd.error("NAME", f"image {img!r} listed twice", start)
        names.add(img)
        r = quaternion_wxyz_to_matrix(q)
        photo.append(img)
        image_ids[int(iid)] = img
        pcam.append(cid)
        eo.append(np.concatenate([-r.T @ tt, world_to_cv_to_opk(r)]))
        m = rd.count("NUM_POINTS2D", 24)
        arr = np.frombuffer(rd.data, dtype=_POINT2D, count=m, offset=rd.pos)
        bad = ~np.isfinite(arr["x"]) | ~np.isfinite(arr["y"]) | (np.abs(arr["x"]) > 1e6) | (np.abs(arr["y"]) > 1e6)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise rd.error("X", f"2D point {k} ({arr['x'][k]!r}, {arr['y'][k]!r}) is not a finite pixel position "
                                f"within +-1e6 px", rd.pos + 24 * k)
        use = arr["id"] != _INVALID_ID
        ids = [str(v) for v in arr["id"][use]]
        unknown = [p for p in ids if p not in known]
        if unknown:
            k = int(np.flatnonzero(use)[ids.index(unknown[0])])
            raise rd.error("POINT3D_ID", f"point {unknown[0]} is not in points3D.bin", rd.pos + 24 * k + 16)
        rd.pos += 24 * m
        o_photo += [img] * len(ids)
        o_point += ids
        o_xy.append(np.column_stack([arr["x"][use], arr["y"][use]]))
        o_cam += [cid] * len(ids)
    rd.end()
    if not photo:
        raise FormatError(f"{rd.path}: no image")
    blk = block_from_model(rd.path, cams, photo, pcam, eo, o_photo, o_point, o_xy, o_cam, pids, pxyz,
                           name=name or folder.name, crs=crs, height_system=height_system,
                           description=f"imported from the COLMAP binary model {folder}")
    if (folder / "rigs.bin").is_file() and (folder / "frames.bin").is_file():
        rigs = rigs_from_colmap_binary(*read_colmap_rigs_binary(folder), image_ids, dict(zip(photo, pcam)), folder)
        check_rigs(rigs, blk, str(folder / "frames.bin"))
        blk = blk.with_(rigs=rigs)
    return blk


# ---------------------------------------------------------------------------------------
# rigs and frames
# ---------------------------------------------------------------------------------------

#: COLMAP sensor types
_SENSOR_TYPES = {0: "CAMERA", 1: "IMU"}


@dataclass(frozen=True)
class ColmapRig:
    """A rig of ``rigs.bin``.

    Attributes
    ----------
    rig_id : int
    ref_sensor : tuple of (str, int)
        Type and id of the reference sensor (its pose is the rig's).
    sensors : dict of (str, int) to ndarray or None
        Every other sensor: ``sensor_from_rig`` as (7,) ``QW QX QY QZ TX TY TZ``, or None when
        the rig leaves it unknown.
    """

    rig_id: int
    ref_sensor: tuple[str, int]
    sensors: dict


@dataclass(frozen=True)
class ColmapFrame:
    """A frame of ``frames.bin``: one exposure of a rig.

    Attributes
    ----------
    frame_id, rig_id : int
    rig_from_world : ndarray, (7,)
        ``QW QX QY QZ TX TY TZ``.
    data : tuple of (str, int, int)
        (sensor type, sensor id, data id) of every measurement; a camera's data id is an IMAGE_ID.
    """

    frame_id: int
    rig_id: int
    rig_from_world: np.ndarray
    data: tuple


def _pose(rd: _Reader, field: str) -> np.ndarray:
    start = rd.pos
    pose = np.array([rd.number("d", f) for f in ("QW", "QX", "QY", "QZ")]
                    + [rd.number("d", f, "coordinate_m") for f in ("TX", "TY", "TZ")])
    if not 0.5 < np.linalg.norm(pose[:4]) < 2.0:
        raise rd.error(field, f"quaternion of norm {np.linalg.norm(pose[:4]):.3g} is no rotation", start)
    return pose


def _sensor(rd: _Reader) -> tuple[str, int]:
    start = rd.pos
    kind, sid = rd.take("iI", "SENSOR_TYPE")
    if kind not in _SENSOR_TYPES:
        raise rd.error("SENSOR_TYPE", f"unknown sensor type {kind} (0 camera, 1 IMU)", start)
    return _SENSOR_TYPES[kind], int(sid)


def read_colmap_rigs_binary(folder: str | Path) -> tuple[dict[int, ColmapRig], dict[int, ColmapFrame]]:
    """The rigs and frames of a COLMAP binary model (``rigs.bin``, ``frames.bin``).

    Returns
    -------
    rigs : dict of int to ColmapRig
    frames : dict of int to ColmapFrame

    Raises
    ------
    FormatError
        A missing or malformed file (``FILE: byte N: field 'NAME': ...``), a frame of an unknown
        rig, a frame whose sensor is not in its rig.
    """
    folder = Path(folder)
    for fname in ("rigs.bin", "frames.bin"):
        if not (folder / fname).is_file():
            raise FormatError(f"{folder / fname}: file not found (COLMAP writes rigs.bin and frames.bin "
                              f"from version 3.12 on)")
    rd = _Reader(folder / "rigs.bin")
    rigs: dict[int, ColmapRig] = {}
    for _ in range(rd.count("num_rigs", 16)):
        start = rd.pos
        rig_id, n = rd.take("II", "RIG_ID")
        if rig_id in rigs:
            raise rd.error("RIG_ID", f"rig {rig_id} defined twice", start)
        if n < 1:
            raise rd.error("NUM_SENSORS", "a rig has at least its reference sensor", start + 4)
        ref = _sensor(rd)
        sensors: dict = {}
        for _ in range(n - 1):
            key = _sensor(rd)
            (has_pose,) = rd.take("B", "HAS_POSE")
            sensors[key] = _pose(rd, "QW") if has_pose else None
        rigs[rig_id] = ColmapRig(rig_id, ref, sensors)
    rd.end()
    rd = _Reader(folder / "frames.bin")
    frames: dict[int, ColmapFrame] = {}
    for _ in range(rd.count("num_frames", 68)):
        start = rd.pos
        frame_id, rig_id = rd.take("II", "FRAME_ID")
        if frame_id in frames:
            raise rd.error("FRAME_ID", f"frame {frame_id} defined twice", start)
        if rig_id not in rigs:
            raise rd.error("RIG_ID", f"rig {rig_id} is not in rigs.bin", start + 4)
        pose = _pose(rd, "QW")
        (m,) = rd.take("I", "NUM_DATA_IDS")
        data = []
        for _ in range(m):
            at = rd.pos
            kind, sid = _sensor(rd)
            (data_id,) = rd.take("Q", "DATA_ID")
            rig = rigs[rig_id]
            if (kind, sid) != rig.ref_sensor and (kind, sid) not in rig.sensors:
                raise rd.error("SENSOR_ID", f"{kind} {sid} is not a sensor of rig {rig_id}", at)
            data.append((kind, sid, int(data_id)))
        frames[frame_id] = ColmapFrame(frame_id, rig_id, pose, tuple(data))
    rd.end()
    return rigs, frames
