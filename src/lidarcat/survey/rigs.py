r"""Rigs from the survey: a rig TOML of cameras with fixed relative poses, and photos.csv's exposures.

A rig file (survey.toml ``[files] rigs``, or any path) names, per rig, its sensors -- camera ids
of ``camera.toml``, the first one the rig's frame -- and the pose of every other sensor relative
to it, ``sensor_from_rig`` in COLMAP's convention (x right, y down, z forward:
``x_s = R_s x_rig + t_s``, :mod:`lidarcat.geometry.rigs`) as a rotation vector in degrees and a
translation in metres::

    [oblique]                                  # the rig id
    sensors = ["nadir", "forward", "backward"] # camera ids; the first is the rig frame
    [oblique.forward]
    rotation_deg = [30.0, 0.0, 0.0]            # sensor_from_rig rotation vector, deg
    translation_m = [0.0, -0.12, 0.0]          # sensor_from_rig translation, m
    [oblique.backward]
    rotation_deg = [-30.0, 0.0, 0.0]
    translation_m = [0.0, 0.12, 0.0]

The photos of one exposure share photos.csv's ``rig_exposure`` label; each is one sensor's
(its camera).  :func:`rig_exposures` checks them against the rigs and gives what
:func:`lidarcat.bundle.rig.exposure_problem` takes.  Every error names the file, the line and
the field.  (Images whose size disagrees with their sensor's camera are refused when the survey
loads, by the image check of photos.csv; :meth:`lidarcat.geometry.rigs.Rig.check_image_sizes`
is the same check for an importer's rig.)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import excerpt
from .._util.tables import location, read_toml, toml_line
from ..errors import CameraError, SurveyError
from ..geometry.camera import Camera
from ..geometry.models import FrameModel
from ..geometry.rigs import Rig
from ..geometry.rolling import rodrigues

__all__ = ["RIG_POSE_KEYS", "load_rigs", "rig_exposures", "check_rig_exposures", "survey_rigs"]

#: the keys of a sensor's pose table
RIG_POSE_KEYS = ("rotation_deg", "translation_m")


def _vector(path: Path, text: str, table: str, key: str, value: Any) -> np.ndarray:
    ok = (isinstance(value, list) and len(value) == 3
          and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value))
    if not ok or not np.isfinite(np.asarray(value, dtype=float)).all():
        raise SurveyError(f"{location(path, toml_line(text, table, key), key)}: [{table}] {key} must be three "
                          f"finite numbers, got {excerpt(value)}")
    return np.asarray(value, dtype=float)


def load_rigs(path: str | Path, cameras: Mapping[str, Camera]) -> dict[str, Rig]:
    """The rigs of a rig file (module docstring), their sensors the survey's cameras.

    Raises
    ------
    SurveyError
        A rig without ``sensors``, an unknown camera, a camera twice in a rig, a missing or
        extra pose table, an unknown key, a pose that is not three numbers (file, line, field).
    """
    path = Path(path)
    data, text = read_toml(path)
    rigs: dict[str, Rig] = {}
    for rid, tab in data.items():
        where = location(path, toml_line(text, rid), None)
        if not isinstance(tab, dict):
            raise SurveyError(f"{location(path, toml_line(text, None, rid), rid)}: a rig is a table [{rid}] "
                              "with sensors = [camera ids]")
        sensors = tab.get("sensors")
        line = toml_line(text, rid, "sensors")
        if not (isinstance(sensors, list) and sensors and all(isinstance(c, str) for c in sensors)):
            raise SurveyError(f"{location(path, line or toml_line(text, rid), 'sensors')}: rig {excerpt(rid)} "
                              f"needs sensors = [camera ids of the camera file], the first the rig frame; "
                              f"got {excerpt(sensors)}")
        for c in sensors:
            if c not in cameras:
                raise SurveyError(f"{location(path, line, 'sensors')}: rig {excerpt(rid)}: camera {excerpt(c)} is "
                                  f"not defined (cameras: {excerpt(', '.join(cameras), 200, quote=False)})")
            if sensors.count(c) > 1:
                raise SurveyError(f"{location(path, line, 'sensors')}: rig {excerpt(rid)}: camera {excerpt(c)} is "
                                  "named twice; a rig has one sensor per camera")
        for key, val in tab.items():
            if key == "sensors":
                continue
            if key not in sensors or not isinstance(val, dict):
                raise SurveyError(f"{location(path, toml_line(text, rid, key) or toml_line(text, f'{rid}.{key}'), key)}"
                                  f": rig {excerpt(rid)}: unknown key {excerpt(key)}; allowed: sensors and a pose "
                                  f"table per sensor ({excerpt(', '.join(sensors[1:]), 200, quote=False)})")
        if sensors[0] in tab:
            raise SurveyError(f"{location(path, toml_line(text, f'{rid}.{sensors[0]}'), sensors[0])}: rig "
                              f"{excerpt(rid)}: {excerpt(sensors[0])} is the rig frame (its first sensor) and has "
                              "no pose table")
        rot = np.zeros((len(sensors), 3, 3))
        rot[0] = np.eye(3)
        trans = np.zeros((len(sensors), 3))
        for k, c in enumerate(sensors[1:], start=1):
            sub = f"{rid}.{c}"
            pose = tab.get(c)
            if pose is None:
                raise SurveyError(f"{where}: rig {excerpt(rid)}: sensor {excerpt(c)} has no pose table [{sub}] "
                                  "with rotation_deg and translation_m (sensor_from_rig)")
            for key in pose:
                if key not in RIG_POSE_KEYS:
                    raise SurveyError(f"{location(path, toml_line(text, sub, key), key)}: [{sub}]: unknown key "
                                      f"{excerpt(key)}; allowed: {', '.join(RIG_POSE_KEYS)}")
            for key in RIG_POSE_KEYS:
                if key not in pose:
                    raise SurveyError(f"{location(path, toml_line(text, sub), key)}: [{sub}]: missing key {key!r} "
                                      "(sensor_from_rig: rotation vector in degrees, translation in metres)")
            rot[k] = rodrigues(np.radians(_vector(path, text, sub, "rotation_deg", pose["rotation_deg"])))[0]
            trans[k] = _vector(path, text, sub, "translation_m", pose["translation_m"])
        try:
            rigs[rid] = Rig(rid, [FrameModel(cameras[c]) for c in sensors], rot, trans)
        except CameraError as ex:
            raise SurveyError(f"{where}: {ex}") from ex
    return rigs


def rig_exposures(photos: Sequence[Any], rigs: Mapping[str, Rig], photos_path: str | Path
                  ) -> tuple[list[str], np.ndarray, dict[str, str]]:
    """The rig exposures of photos.csv's ``rig_exposure`` column, checked against the rigs.

    Parameters
    ----------
    photos : sequence of lidarcat.survey.Photo
    rigs : mapping of str to Rig
    photos_path : path
        photos.csv (for the errors).

    Returns
    -------
    exposure : list of str, (P,)
        Every photo's exposure label (a photo in no rig exposure is its own, labelled by its id).
    sensor : (P,) int array
        Its sensor in its rig (0 outside a rig).
    rig_of_exposure : dict of str to str
        The rig of every rig exposure.

    Raises
    ------
    SurveyError
        A photo of a camera that is in no rig, or in two; an exposure whose photos are of two rigs
        or two of one sensor (photos.csv, line, field ``rig_exposure``).
    """
    rig_of_camera: dict[str, str] = {}
    for rid, rig in rigs.items():
        for cam in rig.cameras:
            if cam.id in rig_of_camera:
                raise SurveyError(f"camera {excerpt(cam.id)} is a sensor of rigs {excerpt(rig_of_camera[cam.id])} and "
                                  f"{excerpt(rid)}: a camera belongs to one rig")
            rig_of_camera[cam.id] = rid
    exposure, sensor = [], np.zeros(len(photos), dtype=np.int64)
    rig_of: dict[str, str] = {}
    first: dict[tuple[str, int], Any] = {}
    for i, ph in enumerate(photos):
        label = ph.rig_exposure
        if not label:
            exposure.append(str(ph.id))
            continue
        where = location(photos_path, ph.line, "rig_exposure")
        rid = rig_of_camera.get(ph.camera)
        if rid is None:
            raise SurveyError(f"{where}: photo {excerpt(ph.id)} of rig exposure {excerpt(label)} is of camera "
                              f"{excerpt(ph.camera)}, a sensor of no rig (rigs: {excerpt(', '.join(rigs), quote=False)})")
        if rig_of.setdefault(label, rid) != rid:
            raise SurveyError(f"{where}: photo {excerpt(ph.id)}: rig exposure {excerpt(label)} has photos of rigs "
                              f"{excerpt(rig_of[label])} and {excerpt(rid)}")
        s = [c.id for c in rigs[rid].cameras].index(ph.camera)
        if (label, s) in first:
            raise SurveyError(f"{where}: photo {excerpt(ph.id)}: rig exposure {excerpt(label)} already has photo "
                              f"{excerpt(first[(label, s)].id)} of sensor {excerpt(ph.camera)}")
        first[(label, s)] = ph
        exposure.append(str(label))
        sensor[i] = s
    return exposure, sensor, rig_of


def check_rig_exposures(photos: Sequence[Any], rigs_path: Path | None, cameras: Mapping[str, Camera],
                        photos_path: Path) -> dict[str, Rig]:
    """What :meth:`lidarcat.Survey.load` checks: the rig file and photos.csv's exposures agree.

    Raises
    ------
    SurveyError
        photos.csv has ``rig_exposure`` values and survey.toml names no rig file (the first such
        line), or any error of :func:`load_rigs` and :func:`rig_exposures`.
    """
    if rigs_path is None:
        ph = next(p for p in photos if p.rig_exposure)
        raise SurveyError(f"{location(photos_path, ph.line, 'rig_exposure')}: photo {excerpt(ph.id)} is in rig "
                          f"exposure {excerpt(ph.rig_exposure)} but survey.toml [files] names no rigs file")
    rigs = load_rigs(rigs_path, cameras)
    rig_exposures(photos, rigs, photos_path)
    return rigs


def survey_rigs(survey) -> tuple[dict[str, Rig], list[str], np.ndarray, dict[str, str]]:
    """The rigs of a loaded survey and its photos' exposures (:func:`rig_exposures`); no rigs: ``{}``."""
    path = survey.files.get("rigs")
    if path is None:
        return {}, [str(p.id) for p in survey.photos], np.zeros(len(survey.photos), dtype=np.int64), {}
    rigs = load_rigs(path, survey.cameras)
    where = survey.files.get("photos", survey.root / "photos.csv")
    return (rigs, *rig_exposures(survey.photos, rigs, where))
