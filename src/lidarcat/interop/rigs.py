r"""Multi-camera rigs in a block: COLMAP ``rigs.txt``/``frames.txt``, OpenSfM rig entries, ``rigs.json``.

A rig is a set of sensors with fixed poses relative to the rig; an exposure (a COLMAP *frame*, an
OpenSfM *rig instance*) places the rig in the world and holds one photo per sensor that fired.
The convention is COLMAP's (:mod:`lidarcat.geometry.rigs`): rigid transforms ``x -> R(q) x + t``
with ``q = (qw, qx, qy, qz)`` a Hamilton quaternion; a sensor's ``sensor_from_rig`` and an
exposure's ``rig_from_world`` compose to a photo's ``cam_from_world``::

    cam_from_world = sensor_from_rig * rig_from_world

(cameras x right, y down, z forward, as in COLMAP and OpenSfM).  OpenSfM's rig cameras
(``rotation`` an angle-axis vector, ``translation``) are ``sensor_from_rig``, its rig instances
``rig_from_world`` (OpenSfM ``doc/source/rig.rst``; ``opensfm/io.py``).

What is kept (:class:`RigSet`, ``Block.rigs``): the rigs with their sensors (a sensor names the
block camera its photos use, and its ``sensor_from_rig`` when known), and the exposures (which
photo each sensor took).  The photos keep their own orientations, so a block with rigs reads and
adjusts as before; the rig information travels to the survey folder (``rigs.json``, below) and
back to the exports (COLMAP ``rigs.txt``/``frames.txt``, OpenSfM ``rig_cameras`` and
``rig_instances``), and :func:`geometry_rig` gives the :class:`lidarcat.geometry.rigs.Rig` of a rig
for a bundle that adjusts one body per exposure.  An exposure's ``rig_from_world`` is derived on
export from a photo whose sensor pose is known (``sensor_from_rig^-1 * cam_from_world``; from the
reference sensor's photo when the exposure has one).

``rigs.json`` (survey folder; written by :func:`lidarcat.interop.block.write_survey`)::

    {"format": "lidarcat rigs 1",
     "rigs": [{"id": "1", "sensors": [
         {"sensor": "1", "camera": "1", "sensor_from_rig": {"q_wxyz": [1, 0, 0, 0], "t_m": [0, 0, 0]}},
         {"sensor": "2", "camera": "2", "sensor_from_rig": null}]}],
     "exposures": [{"id": "1", "rig": "1", "photos": {"1": "left/0001.jpg", "2": "right/0001.jpg"}}]}

The first sensor of a rig is its reference (COLMAP's ``REF_SENSOR``); ``null`` is a pose the rig
leaves unknown.  Checks (located errors): a sensor's camera must exist, a photo must exist and
be in one exposure only, and a photo's camera must have the size of its sensor's camera ("the
rig's cameras disagree in size").
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import read_text
from .._util.values import parse_number, parse_whole
from ..errors import FormatError
from ._text import format_error
from .rotations import matrix_to_quaternion_wxyz, opk_to_world_to_cv, quaternion_wxyz_to_matrix

__all__ = ["RigSensor", "BlockRig", "Exposure", "RigSet", "read_colmap_rigs_text", "rigs_from_colmap_binary",
           "write_colmap_rigs", "rigs_from_opensfm", "opensfm_rig_entries", "rigs_to_json", "read_rigs_json",
           "check_rigs", "geometry_rig", "survey_reads_rig_files", "survey_rig_file", "rigs_from_survey", "RIGS_FILE",
           "RIGS_TOML"]

log = logging.getLogger(__name__)

#: file of a survey folder keeping the rigs of an imported block
RIGS_FILE = "rigs.json"
#: the survey's rig file (survey.toml ``[files] rigs``) an import writes beside it
RIGS_TOML = "rigs.toml"


@dataclass(frozen=True)
class RigSensor:
    """A sensor of a rig: its name, the block camera its photos use, ``sensor_from_rig`` (7,)
    ``QW QX QY QZ TX TY TZ`` or None when unknown."""

    sensor: str
    camera: str
    sensor_from_rig: tuple[float, ...] | None = None


@dataclass(frozen=True)
class BlockRig:
    """A rig: its id and sensors (the first is the reference)."""

    id: str
    sensors: tuple[RigSensor, ...]

    def sensor(self, name: str) -> RigSensor | None:
        return next((s for s in self.sensors if s.sensor == name), None)


@dataclass(frozen=True)
class Exposure:
    """One exposure of a rig: ``photos`` as ((sensor, photo id), ...)."""

    id: str
    rig: str
    photos: tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class RigSet:
    """The rigs of a block and their exposures."""

    rigs: tuple[BlockRig, ...]
    exposures: tuple[Exposure, ...]

    def rig(self, rig_id: str) -> BlockRig:
        return next(r for r in self.rigs if r.id == rig_id)


def _pose7(q: Any, t: Any) -> tuple[float, ...]:
    return tuple(float(v) for v in (*np.asarray(q, dtype=float).ravel(), *np.asarray(t, dtype=float).ravel()))


def _rigid(pose: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    q = np.asarray(pose[:4], dtype=float)
    return quaternion_wxyz_to_matrix(q / np.linalg.norm(q)), np.asarray(pose[4:], dtype=float)


# ---------------------------------------------------------------------- COLMAP text
def _text_lines(path: Path):
    for no, raw in enumerate(read_text(path, FormatError).splitlines(), start=1):
        if raw.strip() and not raw.lstrip().startswith("#"):
            yield no, raw.split()


def _take_num(path: Path, no: int, field: str, cell: str, kind: str | None = None) -> float:
    try:
        return parse_number(cell, kind)
    except ValueError as ex:
        raise format_error(path, no, field, str(ex)) from None


def _take_int(path: Path, no: int, field: str, cell: str) -> int:
    try:
        return parse_whole(cell)
    except ValueError as ex:
        raise format_error(path, no, field, str(ex)) from None


def _text_pose(path: Path, no: int, cells: list[str]) -> tuple[float, ...]:
    names = ("QW", "QX", "QY", "QZ", "TX", "TY", "TZ")
    if len(cells) < 7:
        raise format_error(path, no, names[len(cells)], "missing: a pose is QW QX QY QZ TX TY TZ")
    v = [_take_num(path, no, n, c, None if n[0] == "Q" else "coordinate_m") for n, c in zip(names, cells)]
    if not 0.5 < math.hypot(*v[:4]) < 2.0:
        raise format_error(path, no, "QW", f"quaternion of norm {math.hypot(*v[:4]):.3g} is no rotation")
    return tuple(v)


def _sensor_type(path: Path, no: int, cell: str) -> str:
    if cell not in ("CAMERA", "IMU"):
        raise format_error(path, no, "SENSOR_TYPE", f"{cell[:20]!r} is no sensor type (CAMERA, IMU)")
    return cell


def read_colmap_rigs_text(folder: str | Path, image_names: dict[int, str], image_cameras: dict[str, str]) -> RigSet:
    """The rigs and frames of a COLMAP text model (``rigs.txt``, ``frames.txt``; COLMAP 3.12+).

    ``rigs.txt``: ``RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID`` then, per further sensor,
    ``SENSOR_TYPE SENSOR_ID HAS_POSE [QW QX QY QZ TX TY TZ]``; ``frames.txt``: ``FRAME_ID RIG_ID
    QW QX QY QZ TX TY TZ NUM_DATA_IDS`` then ``SENSOR_TYPE SENSOR_ID DATA_ID`` triples (a camera's
    DATA_ID is an IMAGE_ID).  IMU sensors are left out (logged).

    Parameters
    ----------
    folder : path
    image_names : dict of int to str
        IMAGE_ID -> image NAME (the photo id) of the model's images.
    image_cameras : dict of str to str
        Photo id -> its CAMERA_ID.

    Raises
    ------
    FormatError
        ``FILE:LINE: field 'NAME': ...``: a malformed line, a rig defined twice, a frame of an
        unknown rig or sensor, an image not in images.txt, an image whose camera is not the
        sensor (COLMAP's sensors are cameras), an image in two frames.
    """
    folder = Path(folder)
    rpath, fpath = folder / "rigs.txt", folder / "frames.txt"
    rigs: dict[str, BlockRig] = {}
    imu = 0
    for no, f in _text_lines(rpath):
        if len(f) < 4:
            raise format_error(rpath, no, ("RIG_ID", "NUM_SENSORS", "REF_SENSOR_TYPE", "REF_SENSOR_ID")[len(f)],
                               "missing: RIG_ID NUM_SENSORS REF_SENSOR_TYPE REF_SENSOR_ID SENSORS[]")
        rid = str(_take_int(rpath, no, "RIG_ID", f[0]))
        n = _take_int(rpath, no, "NUM_SENSORS", f[1])
        if rid in rigs:
            raise format_error(rpath, no, "RIG_ID", f"rig {rid} defined twice")
        if n < 1:
            raise format_error(rpath, no, "NUM_SENSORS", "a rig has at least its reference sensor")
        kind = _sensor_type(rpath, no, f[2])
        sensors = [RigSensor(str(_take_int(rpath, no, "REF_SENSOR_ID", f[3])), "", _pose7([1, 0, 0, 0], [0, 0, 0]))]
        if kind != "CAMERA":
            raise format_error(rpath, no, "REF_SENSOR_TYPE", f"rig {rid}: the reference sensor is an {kind}; "
                               f"lidarcat keeps camera rigs (the reference must be a camera)")
        k = 4
        for _ in range(n - 1):
            if len(f) < k + 3:
                raise format_error(rpath, no, ("SENSOR_TYPE", "SENSOR_ID", "HAS_POSE")[len(f) - k],
                                   f"rig {rid}: {n} sensors announced, the line ends early")
            kind = _sensor_type(rpath, no, f[k])
            sid = str(_take_int(rpath, no, "SENSOR_ID", f[k + 1]))
            has = f[k + 2]
            if has not in ("0", "1"):
                raise format_error(rpath, no, "HAS_POSE", f"{has[:20]!r} is not 0 or 1")
            k += 3
            pose = None
            if has == "1":
                pose = _text_pose(rpath, no, f[k:k + 7])
                k += 7
            if kind == "IMU":
                imu += 1
                continue
            if any(s.sensor == sid for s in sensors):
                raise format_error(rpath, no, "SENSOR_ID", f"rig {rid}: camera {sid} listed twice")
            sensors.append(RigSensor(sid, "", pose))
        if len(f) != k:
            raise format_error(rpath, no, "SENSORS", f"rig {rid}: {len(f) - k} value(s) after its {n} sensors")
        rigs[rid] = BlockRig(rid, tuple(RigSensor(s.sensor, s.sensor, s.sensor_from_rig) for s in sensors))
    exposures: list[Exposure] = []
    seen: dict[str, int] = {}
    for no, f in _text_lines(fpath):
        if len(f) < 10:
            raise format_error(fpath, no, ("FRAME_ID", "RIG_ID", "QW", "QX", "QY", "QZ", "TX", "TY", "TZ",
                                           "NUM_DATA_IDS")[len(f)], "missing: FRAME_ID RIG_ID RIG_FROM_WORLD[7] "
                               "NUM_DATA_IDS DATA_IDS[]")
        fid = str(_take_int(fpath, no, "FRAME_ID", f[0]))
        rid = str(_take_int(fpath, no, "RIG_ID", f[1]))
        if rid not in rigs:
            raise format_error(fpath, no, "RIG_ID", f"frame {fid}: rig {rid} is not in rigs.txt")
        _text_pose(fpath, no, f[2:9])
        m = _take_int(fpath, no, "NUM_DATA_IDS", f[9])
        if len(f) != 10 + 3 * m:
            raise format_error(fpath, no, "DATA_IDS", f"frame {fid}: {m} data ids announced (3 values each), "
                               f"the line has {len(f) - 10} values")
        photos = []
        for j in range(m):
            kind = _sensor_type(fpath, no, f[10 + 3 * j])
            sid = str(_take_int(fpath, no, "SENSOR_ID", f[11 + 3 * j]))
            data = _take_int(fpath, no, "DATA_ID", f[12 + 3 * j])
            if kind == "IMU":
                continue
            if rigs[rid].sensor(sid) is None:
                raise format_error(fpath, no, "SENSOR_ID", f"frame {fid}: camera {sid} is not a sensor of rig {rid}")
            if data not in image_names:
                raise format_error(fpath, no, "DATA_ID", f"frame {fid}: image {data} is not in images.txt")
            photo = image_names[data]
            if image_cameras[photo] != sid:
                raise format_error(fpath, no, "DATA_ID", f"frame {fid}: image {data} ({photo!r}) is of camera "
                                   f"{image_cameras[photo]}, not of the rig's sensor camera {sid}")
            if photo in seen:
                raise format_error(fpath, no, "DATA_ID", f"frame {fid}: image {data} ({photo!r}) is also in the frame "
                                   f"of line {seen[photo]}")
            seen[photo] = no
            photos.append((sid, photo))
        exposures.append(Exposure(fid, rid, tuple(photos)))
    if imu:
        log.info("%s: %d IMU sensor(s) left out (lidarcat keeps camera rigs)", rpath, imu)
    return RigSet(tuple(rigs.values()), tuple(exposures))


def rigs_from_colmap_binary(rigs: dict, frames: dict, image_names: dict[int, str], image_cameras: dict[str, str],
                            where: Path) -> RigSet:
    """The :class:`RigSet` of :func:`lidarcat.interop.colmap_binary.read_colmap_rigs_binary`'s rigs and frames
    (the checks of :func:`read_colmap_rigs_text`, located at *where* and the frame)."""
    out_rigs = []
    for r in rigs.values():
        if r.ref_sensor[0] != "CAMERA":
            raise FormatError(f"{where / 'rigs.bin'}: rig {r.rig_id}: the reference sensor is an IMU; lidarcat keeps "
                              f"camera rigs")
        sensors = [RigSensor(str(r.ref_sensor[1]), str(r.ref_sensor[1]), _pose7([1, 0, 0, 0], [0, 0, 0]))]
        sensors += [RigSensor(str(sid), str(sid), None if pose is None else tuple(float(v) for v in pose))
                    for (kind, sid), pose in r.sensors.items() if kind == "CAMERA"]
        out_rigs.append(BlockRig(str(r.rig_id), tuple(sensors)))
    exposures, seen = [], {}
    for fr in frames.values():
        photos = []
        for kind, sid, data in fr.data:
            if kind != "CAMERA":
                continue
            where_f = f"{where / 'frames.bin'}: frame {fr.frame_id}"
            if data not in image_names:
                raise FormatError(f"{where_f}: image {data} is not in images.bin")
            photo = image_names[data]
            if image_cameras[photo] != str(sid):
                raise FormatError(f"{where_f}: image {data} ({photo!r}) is of camera {image_cameras[photo]}, not of "
                                  f"the rig's sensor camera {sid}")
            if photo in seen:
                raise FormatError(f"{where_f}: image {data} ({photo!r}) is also in frame {seen[photo]}")
            seen[photo] = fr.frame_id
            photos.append((str(sid), photo))
        exposures.append(Exposure(str(fr.frame_id), str(fr.rig_id), tuple(photos)))
    return RigSet(tuple(out_rigs), tuple(exposures))


def _cam_from_world(block: Any) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    r = opk_to_world_to_cv(block.eo[:, 3:]).reshape(-1, 3, 3)
    return {p: (r[i], -r[i] @ block.eo[i, :3]) for i, p in enumerate(block.photo_ids.tolist())}


def rig_from_world(block: Any, rig: BlockRig, exposure: Exposure,
                   poses: dict[str, tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray] | None:
    """``rig_from_world`` (R, t) of an exposure from its photos' orientations (module docstring), or None
    when none of its photos has a known sensor pose."""
    order = {s.sensor: k for k, s in enumerate(rig.sensors)}
    for sensor, photo in sorted(exposure.photos, key=lambda sp: order.get(sp[0], 1 << 30)):
        s = rig.sensor(sensor)
        if s is None or s.sensor_from_rig is None or photo not in poses:
            continue
        rs, ts = _rigid(s.sensor_from_rig)
        rc, tc = poses[photo]
        return rs.T @ rc, rs.T @ (tc - ts)
    return None


def write_colmap_rigs(block: Any, cam_num: dict[str, int], img_ids: dict[str, int]) -> tuple[str, str]:
    """The texts of ``rigs.txt`` and ``frames.txt`` for a block with rigs (COLMAP 3.12+).

    COLMAP's sensors are cameras: every sensor must use a camera of its own.  Cameras in no rig get
    a rig of their own and their images a frame each (as COLMAP does for a model without rigs).

    Raises
    ------
    FormatError
        Two sensors on one camera (COLMAP cannot hold them).
    """
    rs: RigSet = block.rigs
    poses = _cam_from_world(block)
    used: dict[str, str] = {}
    rig_num = {r.id: k for k, r in enumerate(rs.rigs, start=1)}
    rig_lines, frame_lines = [], []
    for r in rs.rigs:
        for s in r.sensors:
            if s.camera in used:
                raise FormatError(f"rig {r.id!r}: sensor {s.sensor!r} uses camera {s.camera!r}, as does sensor "
                                  f"{used[s.camera]!r}: COLMAP's rig sensors are cameras, one each; give each "
                                  f"sensor a camera of its own")
            used[s.camera] = s.sensor
        cells = [str(rig_num[r.id]), str(len(r.sensors)), "CAMERA", str(cam_num[r.sensors[0].camera])]
        for s in r.sensors[1:]:
            cells += ["CAMERA", str(cam_num[s.camera])]
            if s.sensor_from_rig is None:
                cells.append("0")
            else:
                cells += ["1"] + [repr(float(v)) for v in s.sensor_from_rig]
        rig_lines.append(" ".join(cells))
    n_rig = len(rs.rigs)
    in_frame = set()
    frame_id = 0
    identity = (np.eye(3), np.zeros(3))
    for ex in rs.exposures:
        r = rs.rig(ex.rig)
        pose = rig_from_world(block, r, ex, poses) or identity
        frame_id += 1
        data = []
        for sensor, photo in ex.photos:
            in_frame.add(photo)
            data += ["CAMERA", str(cam_num[r.sensor(sensor).camera]), str(img_ids[photo])]  # type: ignore[union-attr]
        frame_lines.append(" ".join([str(frame_id), str(rig_num[r.id]),
                                     *(repr(float(v)) for v in matrix_to_quaternion_wxyz(pose[0])),
                                     *(repr(float(v)) for v in pose[1]), str(len(ex.photos)), *data]))
    solo: dict[str, int] = {}
    for cid in block.cameras:
        if cid not in used:
            n_rig += 1
            solo[cid] = n_rig
            rig_lines.append(f"{n_rig} 1 CAMERA {cam_num[cid]}")
    cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
    for photo in block.photo_ids.tolist():
        if photo in in_frame:
            continue
        cid = cam_of[photo]
        rc, tc = poses[photo]
        frame_id += 1
        if cid in solo:
            rid, (rr, tr) = solo[cid], (rc, tc)
        else:  # a photo of a rig sensor outside every exposure: a frame of its own
            rig = next(r for r in rs.rigs if any(s.camera == cid for s in r.sensors))
            one = Exposure("", rig.id, ((used[cid], photo),))
            rid = rig_num[rig.id]
            rr, tr = rig_from_world(block, rig, one, poses) or identity
        frame_lines.append(" ".join([str(frame_id), str(rid), *(repr(float(v)) for v in matrix_to_quaternion_wxyz(rr)),
                                     *(repr(float(v)) for v in tr), "1", "CAMERA", str(cam_num[cid]),
                                     str(img_ids[photo])]))
    rigs_txt = ("# Rig calib list with one line of data per calib:\n#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, "
                "REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, [QW, QX, QY, QZ, TX, TY, TZ])\n"
                f"# Number of rigs: {len(rig_lines)}\n" + "\n".join(rig_lines) + "\n")
    frames_txt = ("# Frame list with one line of data per frame:\n#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, "
                  "TX, TY, TZ], NUM_DATA_IDS, DATA_IDS[] as (SENSOR_TYPE, SENSOR_ID, DATA_ID)\n"
                  f"# Number of frames: {len(frame_lines)}\n" + "\n".join(frame_lines) + "\n")
    return rigs_txt, frames_txt


# ---------------------------------------------------------------------- OpenSfM
def _rotvec_pose(where: str, what: str, obj: Any) -> tuple[float, ...]:
    from scipy.spatial.transform import Rotation

    if not isinstance(obj, dict):
        raise FormatError(f"{where}: {what}: expected an object with rotation and translation")
    vals = []
    for key in ("rotation", "translation"):
        v = obj.get(key)
        if not isinstance(v, list) or len(v) != 3 or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and abs(x) < 1e7
                for x in v):
            raise FormatError(f"{where}: {what}: field {key!r}: expected a list of 3 finite numbers")
        vals.append(np.asarray(v, dtype=float))
    return _pose7(matrix_to_quaternion_wxyz(Rotation.from_rotvec(vals[0]).as_matrix()), vals[1])


def rigs_from_opensfm(rig_cameras: Any, instances: dict[str, list[tuple[str, str]]], shot_cameras: dict[str, str],
                      camera_sizes: dict[str, tuple[int, int]], where: str) -> RigSet:
    """The :class:`RigSet` of OpenSfM rig cameras and rig instances (one rig of all rig cameras).

    Parameters
    ----------
    rig_cameras : dict
        ``{rig camera id: {"rotation": [3], "translation": [3]}}`` (``rig_cameras`` of a reconstruction,
        or ``rig_cameras.json``).
    instances : dict of str to list of (str, str)
        Instance id -> (shot, rig camera id) pairs (``rig_instances`` / ``rig_assignments.json``).
    shot_cameras : dict of str to str
        Shot -> camera id of the reconstruction (shots not in it are left out, logged).
    camera_sizes : dict of str to (int, int)
        Camera id -> (width, height).
    where : str
        File named in errors.

    Raises
    ------
    FormatError
        A malformed pose, an instance naming an unknown rig camera, a shot in two instances, a rig
        camera whose shots use cameras of different sizes.
    """
    if not isinstance(rig_cameras, dict):
        raise FormatError(f"{where}: rig_cameras: expected an object rig camera id -> pose")
    poses = {str(k): _rotvec_pose(where, f"rig camera {k!r}", v) for k, v in rig_cameras.items()}
    cam_of_sensor: dict[str, str] = {}
    seen: dict[str, str] = {}
    exposures = []
    missing = 0
    for iid, pairs in instances.items():
        photos = []
        for shot, rc in pairs:
            if rc not in poses:
                raise FormatError(f"{where}: rig instance {iid!r}: shot {shot!r}: rig camera {rc!r} is not defined "
                                  f"(rig cameras: {', '.join(poses) or 'none'})")
            if shot not in shot_cameras:
                missing += 1
                continue
            if shot in seen:
                raise FormatError(f"{where}: rig instance {iid!r}: shot {shot!r} is also in rig instance "
                                  f"{seen[shot]!r}")
            seen[shot] = iid
            cam = shot_cameras[shot]
            first = cam_of_sensor.setdefault(rc, cam)
            if camera_sizes[first] != camera_sizes[cam]:
                (w0, h0), (w1, h1) = camera_sizes[first], camera_sizes[cam]
                raise FormatError(f"{where}: rig instance {iid!r}: shot {shot!r} of rig camera {rc!r} is "
                                  f"{w1} x {h1} px (camera {cam!r}), the rig camera's other shots {w0} x {h0} px "
                                  f"(camera {first!r}): "
                                  f"the rig's cameras disagree in size")
            photos.append((rc, shot))
        if photos:
            exposures.append(Exposure(str(iid), "opensfm", tuple(photos)))
    if missing:
        log.warning("%s: %d rig-instance shot(s) are not in the reconstruction; left out", where, missing)
    ids = sorted(poses, key=lambda k: (max(abs(v) for v in np.subtract(poses[k], (1, 0, 0, 0, 0, 0, 0))), k))
    sensors = tuple(RigSensor(k, cam_of_sensor.get(k, ""), poses[k]) for k in ids)
    return RigSet((BlockRig("opensfm", sensors),) if sensors else (), tuple(exposures))


def opensfm_rig_entries(block: Any) -> tuple[dict, dict]:
    """``rig_cameras`` and ``rig_instances`` of a reconstruction.json for a block with rigs (rig camera ids
    are the sensors', prefixed with the rig id when rigs share a sensor name)."""
    from scipy.spatial.transform import Rotation

    rs: RigSet = block.rigs
    poses = _cam_from_world(block)
    names = [s.sensor for r in rs.rigs for s in r.sensors]
    clash = len(set(names)) < len(names)
    name = (lambda r, s: f"{r.id}/{s}") if clash else (lambda r, s: s)  # noqa: E731
    cams, inst = {}, {}
    for r in rs.rigs:
        for s in r.sensors:
            if s.sensor_from_rig is not None:
                rr, tt = _rigid(s.sensor_from_rig)
                cams[name(r, s.sensor)] = {"rotation": Rotation.from_matrix(rr).as_rotvec().tolist(),
                                           "translation": tt.tolist()}
    for ex in rs.exposures:
        r = rs.rig(ex.rig)
        pose = rig_from_world(block, r, ex, poses)
        keep = [(s, p) for s, p in ex.photos if name(r, s) in cams]
        if pose is None or not keep:
            continue
        inst[ex.id] = {"rotation": Rotation.from_matrix(pose[0]).as_rotvec().tolist(), "translation": pose[1].tolist(),
                       "rig_camera_ids": {p: name(r, s) for s, p in keep}}
    return cams, inst


# ---------------------------------------------------------------------- rigs.json
def _pose_json(pose: tuple[float, ...] | None) -> dict | None:
    return None if pose is None else {"q_wxyz": list(pose[:4]), "t_m": list(pose[4:])}


def rigs_to_json(rs: RigSet) -> dict:
    """The ``rigs.json`` document of a :class:`RigSet` (module docstring)."""
    return {"format": "lidarcat rigs 1",
            "rigs": [{"id": r.id, "sensors": [{"sensor": s.sensor, "camera": s.camera,
                                               "sensor_from_rig": _pose_json(s.sensor_from_rig)} for s in r.sensors]}
                     for r in rs.rigs],
            "exposures": [{"id": e.id, "rig": e.rig, "photos": dict(e.photos)} for e in rs.exposures]}


def read_rigs_json(path: str | Path) -> RigSet:
    """A survey's ``rigs.json`` (module docstring).

    Raises
    ------
    FormatError
        Invalid JSON or a malformed entry: ``FILE: rig 'ID': sensor 'S': field 'q_wxyz': ...``.
    """
    path = Path(path)
    try:
        doc = json.loads(read_text(path, FormatError))
    except (ValueError, RecursionError) as ex:
        raise FormatError(f"{path}: invalid JSON: {str(ex)[:120]}") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("rigs"), list) or not isinstance(doc.get("exposures"), list):
        raise FormatError(f"{path}: expected an object with lists 'rigs' and 'exposures'")

    def text(v: Any, what: str) -> str:
        if not isinstance(v, str) or not v or len(v) > 200:
            raise FormatError(f"{path}: {what}: expected a non-empty name")
        return v

    rigs = []
    for r in doc["rigs"]:
        rid = text(r.get("id") if isinstance(r, dict) else None, "rig: field 'id'")
        sens = r.get("sensors")
        if not isinstance(sens, list) or not sens:
            raise FormatError(f"{path}: rig {rid!r}: field 'sensors': expected a non-empty list")
        out = []
        for s in sens:
            name = text(s.get("sensor") if isinstance(s, dict) else None, f"rig {rid!r}: field 'sensor'")
            cam = s.get("camera", "")
            if not isinstance(cam, str):
                raise FormatError(f"{path}: rig {rid!r}: sensor {name!r}: field 'camera': expected a camera id")
            pose = s.get("sensor_from_rig")
            p7 = None
            if pose is not None:
                vals = []
                for key, n in (("q_wxyz", 4), ("t_m", 3)):
                    v = pose.get(key) if isinstance(pose, dict) else None
                    if not isinstance(v, list) or len(v) != n or not all(
                            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                            and abs(x) < 1e7 for x in v):
                        raise FormatError(f"{path}: rig {rid!r}: sensor {name!r}: field {key!r}: expected {n} finite "
                                          f"numbers")
                    vals += v
                if not 0.5 < math.hypot(*vals[:4]) < 2.0:
                    raise FormatError(f"{path}: rig {rid!r}: sensor {name!r}: field 'q_wxyz': a quaternion of norm "
                                      f"{math.hypot(*vals[:4]):.3g} is no rotation")
                p7 = tuple(float(x) for x in vals)
            out.append(RigSensor(name, cam, p7))
        rigs.append(BlockRig(rid, tuple(out)))
    exposures = []
    for e in doc["exposures"]:
        eid = text(e.get("id") if isinstance(e, dict) else None, "exposure: field 'id'")
        rig = text(e.get("rig"), f"exposure {eid!r}: field 'rig'")
        ph = e.get("photos")
        if not isinstance(ph, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in ph.items()):
            raise FormatError(f"{path}: exposure {eid!r}: field 'photos': expected an object sensor -> photo id")
        exposures.append(Exposure(eid, rig, tuple(ph.items())))
    return RigSet(tuple(rigs), tuple(exposures))


def check_rigs(rs: RigSet, block: Any, where: str) -> None:
    """Refuse rigs that do not fit *block* (module docstring), located at *where*.

    Raises
    ------
    FormatError
        ``WHERE: rig 'R': sensor 'S': ...`` or ``WHERE: exposure 'E': ...``.
    """
    cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
    ids = {}
    for r in rs.rigs:
        if r.id in ids:
            raise FormatError(f"{where}: rig {r.id!r} defined twice")
        ids[r.id] = r
        for s in r.sensors:
            if s.camera and s.camera not in block.cameras:
                raise FormatError(f"{where}: rig {r.id!r}: sensor {s.sensor!r}: camera {s.camera!r} is not a camera of "
                                  f"the block")
    seen: dict[str, str] = {}
    for e in rs.exposures:
        if e.rig not in ids:
            raise FormatError(f"{where}: exposure {e.id!r}: rig {e.rig!r} is not defined")
        r = ids[e.rig]
        for sensor, photo in e.photos:
            s = r.sensor(sensor)
            if s is None:
                raise FormatError(f"{where}: exposure {e.id!r}: sensor {sensor!r} is not a sensor of rig {r.id!r}")
            if photo not in cam_of:
                raise FormatError(f"{where}: exposure {e.id!r}: photo {photo!r} is not a photo of the block")
            if photo in seen:
                raise FormatError(f"{where}: exposure {e.id!r}: photo {photo!r} is also in exposure {seen[photo]!r}")
            seen[photo] = e.id
            if s.camera:
                a, b = block.cameras[s.camera], block.cameras[cam_of[photo]]
                if (a.columns_px, a.rows_px) != (b.columns_px, b.rows_px):
                    raise FormatError(f"{where}: rig {r.id!r}: photo {photo!r} is {b.columns_px} x {b.rows_px} px "
                                      f"(camera {cam_of[photo]!r}), its sensor {sensor!r} {a.columns_px} x {a.rows_px} "
                                      f"px (camera {s.camera!r}): the rig's cameras disagree in size")


def geometry_rig(block: Any, rig_id: str) -> Any:
    """The :class:`lidarcat.geometry.rigs.Rig` of a rig of *block* (sensor models from the source models:
    Brown or fisheye, pixel-centre origin; the reference sensor first).

    Raises
    ------
    FormatError
        A sensor without a known pose or a camera without an exact model (a rational FULL_OPENCV,
        a Metashape camera), naming the rig and the sensor.
    """
    from ..errors import CameraError
    from ..geometry.models import BrownCamera
    from ..geometry.rigs import Rig
    from .cameras import fisheye_model

    r = block.rigs.rig(rig_id)
    models, rots, ts = [], [], []
    for s in r.sensors:
        m = block.source_models.get(s.camera)
        if s.sensor_from_rig is None or m is None or m["kind"] not in ("brown", "fisheye") or any(
                m["dist"].get(k, 0.0) for k in ("k4", "k5", "k6")) and m["kind"] == "brown":
            raise FormatError(f"rig {rig_id!r}: sensor {s.sensor!r} (camera {s.camera!r}): "
                              + ("its pose relative to the rig is unknown" if s.sensor_from_rig is None else
                                 "its camera has no exact Brown or fisheye model"))
        if m["kind"] == "fisheye":
            models.append(fisheye_model(s.camera, m))
        else:
            d = m["dist"]
            try:
                models.append(BrownCamera(s.camera, m["w"], m["h"], fx=m["fx"], fy=m["fy"], cx=m["cx"] - 0.5,
                                          cy=m["cy"] - 0.5, k1=d.get("k1", 0.0), k2=d.get("k2", 0.0),
                                          k3=d.get("k3", 0.0), p1=d.get("p1", 0.0), p2=d.get("p2", 0.0),
                                          skew=m.get("skew", 0.0)))
            except CameraError as ex:
                raise FormatError(f"rig {rig_id!r}: sensor {s.sensor!r}: {ex}") from None
        rr, tt = _rigid(s.sensor_from_rig)
        rots.append(rr)
        ts.append(tt)
    try:
        return Rig(rig_id, models, np.array(rots), np.array(ts))
    except CameraError as ex:
        raise FormatError(str(ex)) from None


# ---------------------------------------------------------------------- the survey's rig file
def survey_reads_rig_files() -> bool:
    """True when the survey format has the rig file (survey.toml ``[files] rigs`` and photos.csv
    ``rig_exposure``, :mod:`lidarcat.survey.rigs`), which the bundle adjusts as one body per exposure."""
    import dataclasses

    from ..survey.schema import FilesTable

    return "rigs" in {f.name for f in dataclasses.fields(FilesTable)}


def survey_rig_file(rs: RigSet) -> tuple[str, dict[str, str]] | str:
    """The survey's rig TOML of a :class:`RigSet` and every rig photo's ``rig_exposure`` label, or why it
    has none (the survey's rig file needs each sensor a camera of its own, every pose known, a camera in
    one rig).

    The TOML (:mod:`lidarcat.survey.rigs`): one table per rig, ``sensors`` = the cameras (the reference
    first), and per further sensor ``rotation_deg`` (the rotation vector of ``sensor_from_rig``, deg)
    and ``translation_m``.
    """
    from scipy.spatial.transform import Rotation

    lines: list[str] = ["# rigs imported by lidarcat (sensor_from_rig: x_sensor = R x_rig + t, COLMAP's convention)"]
    rig_of_cam: dict[str, str] = {}
    for r in rs.rigs:
        cams = [s.camera for s in r.sensors]
        if not all(cams) or len(set(cams)) < len(cams):
            return f"rig {r.id!r}: its sensors do not each use a camera of their own"
        unknown = [s.sensor for s in r.sensors[1:] if s.sensor_from_rig is None]
        if unknown:
            return f"rig {r.id!r}: the pose of sensor {unknown[0]!r} is unknown"
        rr, tt = _rigid(r.sensors[0].sensor_from_rig or _pose7([1, 0, 0, 0], [0, 0, 0]))
        if np.abs(rr - np.eye(3)).max() > 1e-12 or np.abs(tt).max() > 1e-12:
            return f"rig {r.id!r}: no sensor is the rig frame (OpenSfM's rig frame is a rig camera's only by choice)"
        for c in cams:
            if c in rig_of_cam:
                return f"camera {c!r} is a sensor of rigs {rig_of_cam[c]!r} and {r.id!r}"
            rig_of_cam[c] = r.id
        lines += ["", f"[{json.dumps(r.id)}]", f"sensors = {json.dumps(cams)}"]
        for s in r.sensors[1:]:
            rr, tt = _rigid(s.sensor_from_rig)  # type: ignore[arg-type]
            rv = np.degrees(Rotation.from_matrix(rr).as_rotvec())
            lines += ["", f"[{json.dumps(r.id)}.{json.dumps(s.camera)}]",
                      f"rotation_deg = [{', '.join(repr(float(v)) for v in rv)}]",
                      f"translation_m = [{', '.join(repr(float(v)) for v in tt)}]"]
    ids = [e.id for e in rs.exposures]
    unique = len(set(ids)) == len(ids)
    labels = {p: (e.id if unique else f"{e.rig}/{e.id}") for e in rs.exposures for _, p in e.photos}
    return "\n".join(lines) + "\n", labels


def rigs_from_survey(survey: Any) -> RigSet | None:
    """The :class:`RigSet` of a survey's rig file and photos.csv ``rig_exposure`` labels (a survey made by
    hand, without ``rigs.json``), or None without them.  ``Survey.load`` has checked both."""
    import tomllib

    from scipy.spatial.transform import Rotation

    path = getattr(survey, "files", {}).get("rigs")
    if path is None:
        return None
    doc = tomllib.loads(read_text(Path(path), FormatError))
    rigs = []
    for rid, tab in doc.items():
        sensors = [RigSensor(tab["sensors"][0], tab["sensors"][0], _pose7([1, 0, 0, 0], [0, 0, 0]))]
        for cam in tab["sensors"][1:]:
            q = matrix_to_quaternion_wxyz(Rotation.from_rotvec(np.radians(tab[cam]["rotation_deg"])).as_matrix())
            sensors.append(RigSensor(cam, cam, _pose7(q, tab[cam]["translation_m"])))
        rigs.append(BlockRig(str(rid), tuple(sensors)))
    rig_of_cam = {s.camera: r.id for r in rigs for s in r.sensors}
    groups: dict[str, list[tuple[str, str]]] = {}
    rig_of: dict[str, str] = {}
    for ph in survey.photos:
        label = getattr(ph, "rig_exposure", None)
        if label and ph.camera in rig_of_cam:
            groups.setdefault(label, []).append((ph.camera, ph.id))
            rig_of[label] = rig_of_cam[ph.camera]
    return RigSet(tuple(rigs), tuple(Exposure(k, rig_of[k], tuple(v)) for k, v in groups.items()))
