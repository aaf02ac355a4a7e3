r"""The camera's motion during an exposure, from the survey: the rolling shutter of its cameras.

A camera of ``camera.toml`` with ``readout_time_ms > 0`` reads its photos out row by row; the
bundle then models each photo's linear motion during the read-out
(:mod:`lidarcat.bundle.rolling`): every observation's projection centre moves by ``V_i t_a``,
``t_a = T ((v_a + 0.5) / H - 0.5)`` from its row ``v_a``.  From the survey:

* the row ``v_a`` of every observation: the pixel of its corrected photo coordinate
  (:meth:`lidarcat.geometry.camera.Camera.photo_to_pixel`), whatever the observations were
  measured as;
* the velocity ``V_i`` of every photo of such a camera from its neighbouring exposures:
  photos.csv ``time_s`` (exposure time, s) and ``X0, Y0, Z0`` (GNSS or approximate), central
  differences within a flight line (:func:`lidarcat.bundle.rolling.neighbour_velocities`).
  The photos of a camera in time order form one line until the time between two exposures
  exceeds :data:`LINE_GAP_FACTOR` times the median step (a turn).

A photo of a rolling-shutter camera without ``time_s`` or a position is refused with its line
of photos.csv.

The test of a rolling shutter not modelled (:func:`rolling_shutter_test`): for a camera with
``readout_time_ms = 0`` whose photos all carry ``time_s`` and a position (a drone block; aerial
frame cameras come without exposure times), the adjusted block is adjusted once more with the
camera's read-out time ``T_c`` as one additional unknown
(:class:`lidarcat.bundle.rolling.ReadoutTime`, ``dx_a / dT_c = -A_pt,a V_i s_a``).  A global
shutter leaves ``T_c`` within its sd of 0; a rolling one shows as ``|T_c / sd| > z_{0.9995}``
(3.29): :func:`lidarcat.bundle.rolling.readout_warning` names the camera and the value to set.
The trend of the residuals with the row is the weaker test (the orientations absorb some 99 % of
the image motion, docs/cameras.md), so the read-out time itself is estimated.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._util import excerpt
from .._util.tables import location
from ..bundle import BundleProblem
from ..bundle.rolling import neighbour_velocities, row_times, with_rolling_shutter
from ..errors import SurveyError

__all__ = ["LINE_GAP_FACTOR", "flight_lines", "with_survey_motion", "rolling_shutter_test"]

#: a flight line ends where the time to the next exposure exceeds this many median steps
LINE_GAP_FACTOR = 3.0


def flight_lines(times_s: np.ndarray) -> np.ndarray:
    """Line number of every exposure (n,), from their times: a new line after a gap of more than
    :data:`LINE_GAP_FACTOR` median steps.

    >>> flight_lines(np.array([0.0, 2.0, 4.0, 60.0, 62.0, 6.0])).tolist()
    [0, 0, 0, 1, 1, 0]
    """
    t = np.asarray(times_s, dtype=float)
    order = np.argsort(t, kind="stable")
    steps = np.diff(t[order])
    if not len(steps):
        return np.zeros(len(t), dtype=np.int64)
    cut = steps > LINE_GAP_FACTOR * np.median(steps)
    out = np.empty(len(t), dtype=np.int64)
    out[order] = np.r_[0, np.cumsum(cut)]
    return out


def with_survey_motion(survey, problem: BundleProblem) -> BundleProblem:
    """*problem* of *survey* (:func:`lidarcat.survey.adjustment.problem_from_survey`) with the
    rolling shutter of its cameras (module docstring); unchanged when no camera has one.

    Raises
    ------
    SurveyError
        A photo of a rolling-shutter camera without ``time_s`` or position (file, line, field),
        or two exposures of one camera at the same time.
    """
    p = problem
    by_id = {ph.id: ph for ph in survey.photos}
    photos = [by_id[str(i)] for i in p.photo_ids]
    rolling = {c for c, cam in survey.cameras.items() if cam.readout_time_ms > 0}
    if not any(ph.camera in rolling for ph in photos):
        return p
    where = survey.files.get("photos", survey.root / "photos.csv")
    time_s = np.zeros(len(p.photo_index))
    velocity = np.zeros((p.n_photos, 3))
    cam_of_photo = np.array([ph.camera for ph in photos], dtype=object)
    cam_of_obs = cam_of_photo[p.photo_index]
    for c in sorted(rolling):
        sel = np.flatnonzero(cam_of_photo == c)
        if not len(sel):
            continue
        cam = survey.cameras[c]
        for i in sel:
            ph = photos[i]
            for ok, fld, what in ((ph.time_s is not None, "time_s", "its exposure time"),
                                  (ph.position_m is not None, "X0", "its position")):
                if not ok:
                    raise SurveyError(f"{location(where, ph.line, fld)}: photo {excerpt(ph.id)} of camera "
                                      f"{excerpt(c)} (readout_time_ms = {cam.readout_time_ms:g}) has no {fld}: "
                                      f"the rolling shutter needs {what} for the velocity from its neighbours")
        t = np.array([photos[i].time_s for i in sel])
        x = np.array([photos[i].position_m for i in sel])
        lines = flight_lines(t)
        for ln in np.unique(lines):
            tl = np.sort(t[lines == ln])
            dup = np.flatnonzero(np.diff(tl) <= 0)
            if len(dup):
                i = int(sel[np.flatnonzero(t == tl[dup[0]])[1]])
                raise SurveyError(f"{location(where, photos[i].line, 'time_s')}: photo {excerpt(photos[i].id)}: "
                                  f"camera {excerpt(c)} has another exposure at the same time {tl[dup[0]]:g} s")
        velocity[sel] = neighbour_velocities(x, t, lines.tolist())
        obs = np.flatnonzero(cam_of_obs == c)
        rows = cam.photo_to_pixel(np.asarray(p.xy_mm)[obs])[:, 1]
        time_s[obs] = row_times(rows, cam.rows_px, cam.readout_time_ms / 1000.0)
    out = with_rolling_shutter(p, time_s, velocity)
    return dataclasses.replace(out, info={**p.info, "rolling_shutter": sorted(rolling)})


def rolling_shutter_test(survey, result, *, level: float = 0.001) -> dict | None:
    """The read-out-time test of the global-shutter cameras of *survey* whose photos carry ``time_s``
    (module docstring), from *result* (its adjustment without a rolling-shutter model).

    Returns
    -------
    dict or None
        ``{"cameras": {id: {"readout_ms", "sd_ms", "t"}}, "warnings": [...]}``; None when no camera
        qualifies (every one modelled, photos without ``time_s`` or position, a rig or rolling block,
        an adjustment that did not converge) or the extra adjustment fails.
    """
    from ..bundle.rolling import ReadoutTime, readout_warning, row_fractions
    from ..bundle.selfcal import adjust_with_parameters

    p = result.problem
    if not result.success or p.rays is not None or getattr(p, "lines", None) is not None:
        return None
    by_id = {ph.id: ph for ph in survey.photos}
    photos = [by_id.get(str(i)) for i in p.photo_ids]
    if any(ph is None for ph in photos):             # exposures of a rig, not photos
        return None
    cam_of_photo = np.array([ph.camera for ph in photos], dtype=object)
    tested = [c for c in dict.fromkeys(cam_of_photo.tolist()) if survey.cameras[c].readout_time_ms == 0
              and all(photos[i].time_s is not None and photos[i].position_m is not None
                      for i in np.flatnonzero(cam_of_photo == c))
              and np.sum(cam_of_photo == c) >= 3]
    if not tested:
        return None
    velocity = np.zeros((p.n_photos, 3))
    fraction = np.zeros(len(p.photo_index))
    cam_of_obs = cam_of_photo[p.photo_index]
    for c in tested:
        sel = np.flatnonzero(cam_of_photo == c)
        t = np.array([photos[i].time_s for i in sel])
        x = np.array([photos[i].position_m for i in sel])
        velocity[sel] = neighbour_velocities(x, t, flight_lines(t).tolist())
        obs = np.flatnonzero(cam_of_obs == c)
        cam = survey.cameras[c]
        fraction[obs] = row_fractions(cam.photo_to_pixel(np.asarray(p.xy_mm)[obs])[:, 1], cam.rows_px)
    # photos of the other cameras keep velocity 0: their rows of dx/dT are zero whichever camera they name
    cams = [c if c in tested else tested[0] for c in cam_of_photo.tolist()]
    try:
        res = adjust_with_parameters(p, [ReadoutTime(fraction, velocity, cams)], without=result, precision="all")
    except Exception:   # noqa: BLE001 -- a test that cannot be made is no result, never a failed adjustment
        return None
    if not res.bundle.success:
        return None
    out = {}
    for name, est, sd in zip(res.names, np.asarray(res.estimates), res.sd):
        cam = name[:-len(".readout_s")]
        if cam in tested:
            out[cam] = {"readout_ms": float(est) * 1e3, "sd_ms": float(sd) * 1e3,
                        "t": float(est / sd) if sd > 0 else None}
    warnings = [w for w in readout_warning(res, level=level) if w.split("'")[1] in tested]
    return {"cameras": out, "warnings": warnings, "level": level}
