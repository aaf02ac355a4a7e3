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

``estimate = true`` (in the rig's table) makes ``lidarcat adjust`` estimate the relative poses of
every sensor but the rig frame, starting at the given ones; ``estimate = ["forward"]`` those of the
named sensors only (:func:`load_rig_estimates`; default: the poses are taken as given).  An
estimated sensor may have no pose table: its start is then the median over the exposures whose
rig-frame photo and sensor photo both have a position and attitude in photos.csv of
``Q_s = M_s M_b^T``, ``d_s = Q_s M_b (X0_b - X0_s)`` (the composition below solved for the
relative pose; the rotation the projection of the mean onto a rotation).

In ``lidarcat adjust`` (:func:`rig_plan`) the photos become their exposures
(:func:`lidarcat.bundle.rig.exposure_problem`); eop.csv then holds every photo's pose, the
composition ``M_s = Q_s M_b``, ``X0_s = X0_b - M_b^T Q_s^T d_s`` of its exposure's body pose
``b`` and its sensor's relative pose ``g = (eps_s, delta_s)`` (:func:`rig_photo_poses`), with the
covariance propagated to first order, ``C_s = J_b C_b J_b^T + J_b C_bg J_g^T + J_g C_gb J_b^T
+ J_g C_g J_g^T`` (J by central differences; ``C_bg = 0`` and ``J_g = 0`` for given poses and for the
rig frame), and rig_poses.csv the relative poses in the rig file's own convention
(:func:`rig_pose_rows`; their sds are those of a small rotation ``exp([e]x)`` applied on the left,
the same in both frames since ``D exp([e]x) D = exp([D e]x)``).

The photos of one exposure share photos.csv's ``rig_exposure`` label; each is one sensor's
(its camera).  :func:`rig_exposures` checks them against the rigs and gives what
:func:`lidarcat.bundle.rig.exposure_problem` takes.  Every error names the file, the line and
the field.  (Images whose size disagrees with their sensor's camera are refused when the survey
loads, by the image check of photos.csv; :meth:`lidarcat.geometry.rigs.Rig.check_image_sizes`
is the same check for an importer's rig.)
"""

from __future__ import annotations

import dataclasses
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

__all__ = ["RIG_POSE_KEYS", "load_rigs", "rig_exposures", "check_rig_exposures", "survey_rigs",
           "load_rig_estimates", "unposed_sensors", "RigPlan", "rig_plan", "rig_photo_poses", "rig_pose_rows", "RIG_POSE_COLUMNS"]

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
            if key in ("sensors", "estimate"):
                continue
            if key not in sensors or not isinstance(val, dict):
                raise SurveyError(f"{location(path, toml_line(text, rid, key) or toml_line(text, f'{rid}.{key}'), key)}"
                                  f": rig {excerpt(rid)}: unknown key {excerpt(key)}; allowed: sensors and a pose "
                                  f"table per sensor ({excerpt(', '.join(sensors[1:]), 200, quote=False)}), "
                                  "and estimate")
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
            est = tab.get("estimate", False)
            if pose is None and (est is True or (isinstance(est, list) and c in est)):
                rot[k] = np.eye(3)
                continue        # estimated from nothing: the approximation comes from photos.csv (rig_plan)
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


def load_rig_estimates(path: str | Path, rigs: Mapping[str, Rig]) -> dict[str, tuple[int, ...]]:
    """The sensors (indices, 1.. in the rig's ``sensors``) whose relative pose each rig's ``estimate``
    key asks ``lidarcat adjust`` to estimate (module docstring); no key or ``false``: ``()``.

    Raises
    ------
    SurveyError
        ``estimate`` neither a boolean nor a list of the rig's sensors, or naming its rig frame
        (file, line, field).
    """
    path = Path(path)
    data, text = read_toml(path)
    out: dict[str, tuple[int, ...]] = {}
    for rid, rig in rigs.items():
        names = [c.id for c in rig.cameras]
        val = data.get(rid, {}).get("estimate", False)
        where = location(path, toml_line(text, rid, "estimate"), "estimate")
        if isinstance(val, bool):
            out[rid] = tuple(range(1, len(names))) if val else ()
            continue
        if not (isinstance(val, list) and all(isinstance(v, str) for v in val)):
            raise SurveyError(f"{where}: rig {excerpt(rid)}: estimate must be true, false or a list of its "
                              f"sensors, got {excerpt(val)}")
        for v in val:
            if v not in names:
                raise SurveyError(f"{where}: rig {excerpt(rid)}: {excerpt(v)} is not one of its sensors "
                                  f"({excerpt(', '.join(names), 200, quote=False)})")
            if v == names[0]:
                raise SurveyError(f"{where}: rig {excerpt(rid)}: {excerpt(v)} is the rig frame (its first "
                                  "sensor); its pose is the exposure's and is not estimated")
        out[rid] = tuple(sorted({names.index(v) for v in val}))
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class RigPlan:
    """How a survey's photos make a rig block (:func:`rig_plan`).

    Attributes
    ----------
    rig_id : str
    sensor_names : tuple of str, (S,)
        The sensors' camera ids (the first the rig frame).
    photo_ids : tuple of str, (P,)
    exposure_ids : tuple of str, (E,)
    exposure_index, sensor : (P,) int arrays
        Every photo's exposure and sensor.
    estimate : tuple of int
        The sensors whose relative pose is estimated.
    start_rotation, start_translation_m : (S, 3, 3), (S, 3) arrays
        The rig file's relative poses in the thesis frame (:func:`lidarcat.bundle.rig.rig_sensor_poses`).
    """

    rig_id: str
    sensor_names: tuple[str, ...]
    photo_ids: tuple[str, ...]
    exposure_ids: tuple[str, ...]
    exposure_index: np.ndarray
    sensor: np.ndarray
    estimate: tuple[int, ...]
    start_rotation: np.ndarray
    start_translation_m: np.ndarray

    def photo_of_observation(self, exposure_index: Any, sensor_index: Any) -> np.ndarray:
        """The photo ids (k,) of observations made at exposures (k,) by sensors (k,)."""
        n_s = len(self.sensor_names)
        lookup = {int(e) * n_s + int(s): i for i, (e, s) in enumerate(zip(self.exposure_index, self.sensor))}
        key = np.asarray(exposure_index, dtype=np.int64) * n_s + np.asarray(sensor_index, dtype=np.int64)
        ids = np.asarray(self.photo_ids, dtype=object)
        return ids[np.array([lookup[int(k)] for k in key], dtype=np.int64)] if len(key) else ids[:0]


def rig_plan(survey: Any, problem: Any) -> tuple[Any, RigPlan | None]:
    """The block of rig exposures of a survey's photo block *problem*
    (:func:`lidarcat.survey.adjustment.problem_from_survey`), or ``(problem, None)`` without
    ``[files] rigs``.

    Raises
    ------
    SurveyError
        More than one rig; a photo of a camera outside the rig or of a rig sensor without a
        ``rig_exposure`` (photos.csv, line, field); a rig block with line control or a rolling
        shutter (not combined yet); the exposures' photos disagreeing (the exposure named).
    """
    from ..bundle.rig import exposure_problem, rig_sensor_poses

    path = survey.files.get("rigs")
    if path is None:
        return problem, None
    rigs, exposure, sensor, _ = survey_rigs(survey)
    if len(rigs) != 1:
        raise SurveyError(f"{path}: {len(rigs)} rigs ({excerpt(', '.join(rigs), 200, quote=False)}): "
                          "lidarcat adjust adjusts a survey of one rig")
    (rid, rig), = rigs.items()
    names = tuple(c.id for c in rig.cameras)
    where = survey.files.get("photos", survey.root / "photos.csv")
    for ph in survey.photos:
        if ph.camera not in names:
            raise SurveyError(f"{location(where, ph.line, 'camera')}: photo {excerpt(ph.id)} is of camera "
                              f"{excerpt(ph.camera)}, a sensor of no rig: a survey with a rig file adjusts the "
                              f"photos of rig {excerpt(rid)} only ({excerpt(', '.join(names), 200, quote=False)})")
        if not ph.rig_exposure and ph.camera != names[0]:
            raise SurveyError(f"{location(where, ph.line, 'rig_exposure')}: photo {excerpt(ph.id)} of sensor "
                              f"{excerpt(ph.camera)} of rig {excerpt(rid)} has no rig exposure")
    if getattr(problem, "lines", None) is not None:
        raise SurveyError(f"{survey.files.get('line_control')}: line control in a rig block is not supported "
                          "yet (adjust the rig block without [files] line_control)")
    if problem.rays is not None:
        raise SurveyError(f"{survey.files.get('camera', survey.toml_path)}: a rolling shutter (readout_time_ms) "
                          "in a rig block is not supported yet")
    q, d = rig_sensor_poses(rig)
    unposed = unposed_sensors(path, rigs)[rid]
    if unposed:
        _photo_relative_poses(survey, np.asarray(sensor), exposure, unposed, names, rid, path, q, d)
    focal = np.array([survey.cameras[c].focal_length_mm for c in names], dtype=float)
    try:
        out, ex = exposure_problem(problem, exposure, sensor, q, d, sensor_focal_mm=focal, sensor_names=names)
    except CameraError as err:
        raise SurveyError(f"{where}: {err}") from err
    estimate = load_rig_estimates(path, rigs)[rid]
    plan = RigPlan(rid, names, tuple(str(p) for p in problem.photo_ids), tuple(out.photo_ids), ex,
                   np.asarray(sensor, dtype=np.int64), estimate, q, d)
    return dataclasses.replace(out, info={**out.info, "rig": rid}), plan


def _wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def rig_photo_poses(plan: RigPlan, body_eo: Any, body_cov: Any, rotation: Any, translation_m: Any,
                    params: Any = None, params_cov: Any = None, cross_cov: Any = None,
                    start_rotation: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Every photo's pose (P, 6) (m, rad) and its covariance (P, 6, 6) (module docstring).

    Parameters
    ----------
    plan : RigPlan
    body_eo, body_cov : (E, 6), (E, 6, 6) arrays
        The adjusted exposures and their covariances.
    rotation, translation_m : (S, 3, 3), (S, 3) arrays
        The adjusted relative poses (thesis frame).
    params, params_cov : (6 k,), (6 k, 6 k) arrays, optional
        With estimated poses: the corrections ``(eps, delta)`` of the sensors ``plan.estimate`` about
        *start_rotation* (S, 3, 3) (the rotation the estimation started from) and their covariance.
    cross_cov : (E, 6, 6 k) array, optional
        ``Cov(body, params)``.
    """
    from ..bundle.rig import photo_poses

    body = np.asarray(body_eo, dtype=float)
    ex, sen = plan.exposure_index, plan.sensor
    n = len(ex)
    q = np.asarray(rotation, dtype=float)
    d = np.asarray(translation_m, dtype=float)
    eo = photo_poses(body, q, d, ex, sen)
    est = list(plan.estimate) if params is not None else []
    col = {s: k for k, s in enumerate(est)}
    b0 = body[ex].copy()
    b0[:, :3] = 0.0                          # the Jacobian does not depend on the position

    def poses(bb: np.ndarray, qq: np.ndarray, dd: np.ndarray) -> np.ndarray:
        k = np.arange(n)                     # photo k: its own body (row k) and relative pose (qq[k], dd[k])
        return photo_poses(bb, qq, dd, k, k)

    qs, ds = q[sen], d[sen]
    base_q = np.asarray(start_rotation, dtype=float)[sen] if est else qs
    eps = np.zeros((n, 3))
    if est:
        th = np.reshape(params, (-1, 6))
        has = np.array([s in col for s in sen])
        eps[has] = th[[col[s] for s in sen[has]], :3]
    h = 1e-6
    jb = np.zeros((n, 6, 6))
    jg = np.zeros((n, 6, 6))
    for k in range(6):
        step = np.zeros(6)
        step[k] = h
        up = poses(b0 + step, qs, ds)
        dn = poses(b0 - step, qs, ds)
        jb[:, :, k] = np.concatenate([up[:, :3] - dn[:, :3], _wrap(up[:, 3:] - dn[:, 3:])], axis=1) / (2 * h)
        if est:
            if k < 3:
                qu = rodrigues(eps + step[:3]) @ base_q
                qd = rodrigues(eps - step[:3]) @ base_q
                up, dn = poses(b0, qu, ds), poses(b0, qd, ds)
            else:
                up, dn = poses(b0, qs, ds + step[3:]), poses(b0, qs, ds - step[3:])
            jg[:, :, k] = np.concatenate([up[:, :3] - dn[:, :3], _wrap(up[:, 3:] - dn[:, 3:])], axis=1) / (2 * h)
    cb = np.asarray(body_cov, dtype=float)[ex]
    cov = jb @ cb @ np.transpose(jb, (0, 2, 1))
    if est:
        pc = np.asarray(params_cov, dtype=float)
        cc = np.asarray(cross_cov, dtype=float)[ex]
        for s in est:
            m = sen == s
            sl = slice(6 * col[s], 6 * col[s] + 6)
            jbm, jgm = jb[m], jg[m]
            cbg = cc[m][:, :, sl]
            t = jbm @ cbg @ np.transpose(jgm, (0, 2, 1))
            cov[m] += jgm @ pc[sl, sl] @ np.transpose(jgm, (0, 2, 1)) + t + np.transpose(t, (0, 2, 1))
    return eo, cov


#: columns of ``rig_poses.csv``: sensor_from_rig (the rig file's convention) and sds
RIG_POSE_COLUMNS = ("rig", "sensor", "rotation_x_deg", "rotation_y_deg", "rotation_z_deg", "translation_x_m",
                    "translation_y_m", "translation_z_m", "sd_rotation_x_deg", "sd_rotation_y_deg",
                    "sd_rotation_z_deg", "sd_translation_x_m", "sd_translation_y_m", "sd_translation_z_m",
                    "estimated")


def rig_pose_rows(plan: RigPlan, rotation: Any, translation_m: Any, params_cov: Any = None) -> list[list[Any]]:
    """One row of :data:`RIG_POSE_COLUMNS` per sensor: the relative pose as the rig file writes it
    (COLMAP ``sensor_from_rig``: ``R = D Q D`` as a rotation vector in degrees, ``t = D d``) and,
    for estimated sensors, the sds from *params_cov* (module docstring); NaN for given poses."""
    from ..bundle.rig import rotation_log

    dd = np.diag([1.0, -1.0, -1.0])
    q = np.asarray(rotation, dtype=float)
    rv = np.degrees(rotation_log(dd @ q @ dd))
    t = np.asarray(translation_m, dtype=float) @ dd
    col = {s: k for k, s in enumerate(plan.estimate)}
    rows = []
    for s, name in enumerate(plan.sensor_names):
        sd = np.full(6, np.nan)
        if s in col and params_cov is not None:
            sl = slice(6 * col[s], 6 * col[s] + 6)
            sd = np.sqrt(np.clip(np.diag(np.asarray(params_cov, dtype=float)[sl, sl]), 0, None))
            sd[:3] = np.degrees(sd[:3])
        rows.append([plan.rig_id, name, *rv[s], *t[s], *sd, s in col])
    return rows


def unposed_sensors(path: str | Path, rigs: Mapping[str, Rig]) -> dict[str, tuple[int, ...]]:
    """The sensors (indices) of each rig that the rig file gives no pose table (estimated ones only,
    :func:`load_rigs`)."""
    data, _ = read_toml(Path(path))
    return {rid: tuple(k for k, c in enumerate(rig.cameras) if k > 0 and c.id not in data.get(rid, {}))
            for rid, rig in rigs.items()}


def _photo_relative_poses(survey: Any, plan_sensor: np.ndarray, exposure: Sequence[str], sensors: Sequence[int],
                          names: Sequence[str], rid: str, path: Any, q: np.ndarray, d: np.ndarray) -> None:
    """Fill ``q[s]``, ``d[s]`` (thesis frame) of *sensors* from photos.csv (module docstring), in place."""
    from ..geometry.collinearity import rotation_matrix

    photos = survey.photos
    ref = {exposure[i]: ph for i, ph in enumerate(photos) if plan_sensor[i] == 0 and ph.rig_exposure}
    for s in sensors:
        pairs = [(ref[exposure[i]], ph) for i, ph in enumerate(photos) if plan_sensor[i] == s and ph.rig_exposure
                 and exposure[i] in ref]
        pairs = [(b, p) for b, p in pairs
                 if all(v is not None for v in (b.position_m, b.attitude_deg, p.position_m, p.attitude_deg))]
        if not pairs:
            raise SurveyError(f"{path}: rig {excerpt(rid)}: sensor {excerpt(names[s])} has no pose table and no "
                              "exposure gives both its photo and the rig frame's photo with a position and attitude "
                              "in photos.csv to start its estimate from")
        mb = rotation_matrix(np.radians([b.attitude_deg for b, _ in pairs])).reshape(-1, 3, 3)
        ms = rotation_matrix(np.radians([p.attitude_deg for _, p in pairs])).reshape(-1, 3, 3)
        dx = np.array([b.position_m for b, _ in pairs], dtype=float) - np.array([p.position_m for _, p in pairs])
        qs = ms @ np.transpose(mb, (0, 2, 1))
        u, _, vt = np.linalg.svd(qs.sum(axis=0))
        q[s] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
        d[s] = np.median(np.einsum("ij,njk,nk->ni", q[s], mb, dx), axis=0)
