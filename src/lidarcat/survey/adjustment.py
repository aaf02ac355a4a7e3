"""The survey adapter: a survey folder in, the adjustment folder out.

:func:`problem_from_survey` turns a :class:`lidarcat.Survey` and a control set
into a :class:`BundleProblem`; :func:`write_adjustment` writes ``eop.csv``,
``points.csv``, ``residuals.csv``, ``summary.json`` and ``check_covariance.csv``
(the joint covariance of the check points, read back by
:func:`read_point_covariance`); :func:`adjust_survey` is ``lidarcat adjust``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..bundle.precision import joint_point_covariance
from ..bundle.problem import BundleProblem
from ..bundle.redundancy import FAMILY_LEVEL
from ..bundle.reliability import SnoopingResult, snoop
from ..bundle.solve import BundleResult
from ..bundle.variance import snoop_with_components
from ..errors import SurveyError
from .covariance import write_result_eop_covariance
from .motion import rolling_shutter_test, with_survey_motion
from .rigs import rig_plan

if TYPE_CHECKING:  # pragma: no cover
    from .folder import Survey

__all__ = ["adjust_survey", "adjust_survey_into", "write_adjustment", "problem_from_survey", "read_point_covariance",
           "EOP_COLUMNS", "POINT_COLUMNS", "RESIDUAL_COLUMNS", "COVARIANCE_COLUMNS",
           "MAX_JOINT_COVARIANCE_POINTS", "BLUNDER_COLUMNS", "write_point_covariance", "require_observations",
           "NO_CONTROL"]

log = logging.getLogger(__name__)

#: the control-set name of an adjustment whose only datum is the GNSS/INS orientation of the photos
NO_CONTROL = "none"

#: ``write_adjustment`` writes the joint covariance of the check points
#: (``check_covariance.csv``, k (k + 1) / 2 rows) up to this many check points
MAX_JOINT_COVARIANCE_POINTS = 500
#: columns of ``check_covariance.csv``: the 3 x 3 cross-covariance block of two points, m^2
COVARIANCE_COLUMNS = ("point_a", "point_b", "c_EE", "c_EN", "c_Eh", "c_NE", "c_NN", "c_Nh",
                      "c_hE", "c_hN", "c_hh")


# ---------------------------------------------------------------------------
# survey -> problem
# ---------------------------------------------------------------------------


def require_observations(survey: Survey) -> None:
    """Refuse a survey without image observations (the state `lidarcat init` leaves: photos, no tie
    points yet) with what to do: ``image_points.csv: no image observations: run `lidarcat match SURVEY`
    first``."""
    if len(survey.image_points) == 0:
        where = survey.files.get("image_points", survey.root / "image_points.csv")
        raise SurveyError(f"{where}: no image observations: run `lidarcat match {survey.root}` first "
                          f"(or measure tie and control points into it)")


def problem_from_survey(
    survey: Survey,
    control: str | None = None,
    observations: str | None = None,
    *,
    eo_constraints: bool = False,
) -> BundleProblem:
    """Build the :class:`BundleProblem` of a survey.

    Parameters
    ----------
    survey : lidarcat.Survey
    control : str or ControlSet, optional
        Control set name (default: the survey's default set), or a set itself.
    observations : {"corrected", "pixel"}, optional
        Printed corrected photo coordinates or pixel coordinates through the
        interior orientation (default: the survey setting).
    eo_constraints : bool
        Use the photo positions / attitudes of ``photos.csv`` that carry sigmas as
        weighted constraints.

    Points excluded by the survey settings are left out; ground points measured on
    no photo are ignored (control points among them with a logged warning and
    listed as ``control_unmeasured`` in the summary).  Check points of the set
    are free points with role ``check``; every other point has role ``tie``.
    """
    require_observations(survey)
    if control is None and survey.default_control is None and eo_constraints:
        # no control set: the weighted GNSS/INS orientations of photos.csv are the datum
        # (check_datum explains a defect when they are too weak)
        from ._tables import ControlSet

        cset = ControlSet(NO_CONTROL, np.zeros(0, dtype=str), np.zeros(0, dtype=str), np.zeros((0, 3)))
    elif control is None and survey.default_control is None and any(
            ph.sd_position_m is not None for ph in survey.photos):
        from ..errors import SurveyError

        avail = ", ".join(survey.control_sets) or "none defined"
        raise SurveyError(f"{survey.toml_path}: no control set named and no [survey] default_control "
                          f"(available: {avail}); photos.csv carries sd_X0.. : adjust with the weighted "
                          "GNSS/INS orientations alone as the datum (--eo-constraints)")
    else:
        cset = survey.control_set(control) if control is None or isinstance(control, str) else control
    obs = survey.photo_observations(observations)
    obs, one_ray = _drop_one_ray_ground_points(survey, obs, cset)
    photos = survey.photos
    photo_ids = [ph.id for ph in photos]
    focal = [survey.cameras[ph.camera].focal_length_mm for ph in photos]
    ph_pos = {pid: i for i, pid in enumerate(photo_ids)}
    point_ids: list[str] = []
    pt_pos: dict[str, int] = {}
    for q in obs.point:
        if q not in pt_pos:
            pt_pos[q] = len(point_ids)
            point_ids.append(q)
    gp = survey.ground_points
    g_index = {str(q): i for i, q in enumerate(gp.point)}
    ctrl_all = [str(c) for c in cset.control]
    measured = [c in pt_pos for c in ctrl_all]
    unmeasured = [c for c, m in zip(ctrl_all, measured) if not m]
    if unmeasured:
        log.warning("control set %r: point(s) %s measured on no photo; left out", cset.name,
                    ", ".join(unmeasured))
    ctrl = [c for c, m in zip(ctrl_all, measured) if m]
    ci = np.array([pt_pos[c] for c in ctrl], dtype=np.int64)
    cenh = np.array([gp.enh_m[g_index[c]] for c in ctrl], dtype=float).reshape(-1, 3)
    csd = np.asarray(cset.sd_m, dtype=float).reshape(-1, 3)[np.asarray(measured, dtype=bool)]
    role = np.full(len(point_ids), "tie", dtype=object)
    for q in cset.check:
        if str(q) in pt_pos:
            role[pt_pos[str(q)]] = "check"
    role[ci] = "control"
    n_ph = len(photo_ids)
    init = np.full((n_ph, 6), np.nan)
    e_idx, e_val, e_sd = [], [], []
    for i, ph in enumerate(photos):
        if ph.position_m is not None and ph.attitude_deg is not None:
            init[i, :3] = ph.position_m
            init[i, 3:] = np.radians(ph.attitude_deg)
        elif ph.position_m is not None:
            init[i, :3] = ph.position_m
        if eo_constraints and ph.position_m is not None:
            val = np.full(6, np.nan)
            sd = np.full(6, np.inf)
            val[:3] = ph.position_m
            if ph.sd_position_m is not None:
                sd[:3] = ph.sd_position_m
            if ph.attitude_deg is not None:
                val[3:] = np.radians(ph.attitude_deg)
                if ph.sd_attitude_deg is not None:
                    sd[3:] = np.radians(ph.sd_attitude_deg)
            val = np.where(np.isfinite(val), val, 0.0)
            sd = np.where(np.isfinite(sd) & (sd > 0), sd, np.inf)
            if np.isfinite(sd).any():
                e_idx.append(i)
                e_val.append(val)
                e_sd.append(sd)
    return BundleProblem(
        photo_ids=photo_ids, point_ids=point_ids, focal_length_mm=np.asarray(focal, dtype=float),
        photo_index=np.array([ph_pos[str(x)] for x in obs.photo], dtype=np.int64),
        point_index=np.array([pt_pos[str(x)] for x in obs.point], dtype=np.int64),
        xy_mm=obs.xy_mm, sd_mm=obs.sd_mm,
        constraint_point_index=ci, constraint_enh_m=cenh, constraint_sd_m=csd,
        eo_constraint_photo_index=np.array(e_idx, dtype=np.int64) if e_idx else None,
        eo_constraint_params=np.array(e_val) if e_idx else None,
        eo_constraint_sd=np.array(e_sd) if e_idx else None,
        initial_eo=init if np.isfinite(init).any() else None,
        point_role=role, lines=_survey_lines(survey, photo_ids, ctrl_all),
        info={"survey": survey.name, "control_set": cset.name, "control_unmeasured": unmeasured,
              **({"one_ray_dropped": one_ray} if one_ray else {}),
              "observations": observations or survey.settings.observations,
              "eo_constraints": bool(eo_constraints and e_idx)},
    )


def _drop_one_ray_ground_points(survey: Survey, obs: Any, cset: Any) -> tuple[Any, list[str]]:
    """The observations without ground points seen on one photo that are not control of *cset*: a LiDAR
    vertex measured on one photo (``lidarcat measure-control``) is control in its set, but a free point of
    one ray in another (GPS) set cannot be adjusted; it is left out there (logged, ``one_ray_dropped``)."""
    ground = {str(q) for q in survey.ground_points.point} - {str(c) for c in cset.control}
    pts, cnt = np.unique(np.asarray(obs.point, dtype=str), return_counts=True)
    one = sorted(set(pts[cnt == 1].tolist()) & ground)
    if not one:
        return obs, []
    log.warning("control set %r: ground point(s) %s seen on one photo only and not control: left out",
                cset.name, ", ".join(one))
    return obs.select(~np.isin(np.asarray(obs.point, dtype=str), one)), one


def _survey_lines(survey: Survey, photo_ids: list[str], control_points: Any = None):
    """The survey's line control (``[files] line_control``) as arrays, or None; lines measured at a LiDAR
    point (their ``point``) only where *control_points* hold it."""
    path = survey.files.get("line_control")
    if path is None:
        return None
    from ..bundle.lines import LineControl
    from .lines import photo_cameras, read_line_control

    cams = photo_cameras(survey.photos, survey.cameras)
    return LineControl.from_observations(*read_line_control(path, photo_ids, cams, control_points), photo_ids)


# ---------------------------------------------------------------------------
# output files
# ---------------------------------------------------------------------------


def read_point_covariance(path, points: Sequence[str] | None = None) -> tuple[list[str], np.ndarray]:
    """Read a ``check_covariance.csv`` written by :func:`write_adjustment`.

    Parameters
    ----------
    path : path
    points : sequence of str, optional
        Point ids to return, in this order (default: the file's order).

    Returns
    -------
    ids : list of str
    C : (3k, 3k) array
        Joint covariance of E, N, h, m^2.

    Raises
    ------
    SurveyError
        Missing or unreadable file, a missing column, a cell that is not a
        number (file, line and field named).
    AssessmentError
        A requested point with no rows, a pair with no row or with two rows, a
        point's own block with a variance that is not positive (or below an sd
        of 1 um) or not symmetric, an entry beyond :data:`lidarcat.survey.schema.SD_BOUNDS`
        squared (``|c| <= 1e6`` m^2) or larger than the two variances allow
        (``|c_ij| > sqrt(c_ii c_jj)``), a matrix that is not positive definite
        (file and line or points named).
    """
    from .._util import excerpt, read_csv_table
    from ..errors import AssessmentError, location
    from .schema import SD_BOUNDS

    t = read_csv_table(path, required=COVARIANCE_COLUMNS)
    vals = np.column_stack([t.floats(c) for c in COVARIANCE_COLUMNS[2:]]).reshape(-1, 3, 3)
    pa, pb = t.column("point_a"), t.column("point_b")
    var_min, var_max = SD_BOUNDS["m"][0] ** 2, SD_BOUNDS["m"][1] ** 2
    seen: dict[frozenset, int] = {}
    for a, b, blk, line in zip(pa, pb, vals, t.lines):
        first = seen.setdefault(frozenset((a, b)), line)
        if first != line:
            raise AssessmentError(f"{location(path, line)}: a second row for the pair {excerpt(a, quote=False)}, {excerpt(b, quote=False)} "
                                  f"(first at line {first}); keep one row per pair")
        big = np.flatnonzero(np.abs(blk.ravel()) > var_max)
        if big.size:
            field = COVARIANCE_COLUMNS[2 + int(big[0])]
            raise AssessmentError(f"{location(path, line, field)}: {blk.ravel()[big[0]]:g} m^2 is beyond any "
                                  f"covariance of an adjusted point (|c| <= {var_max:g} m^2, an sd of "
                                  f"{SD_BOUNDS['m'][1]:g} m)")
        if a == b and np.any(np.diag(blk) <= 0):
            raise AssessmentError(f"{location(path, line)}: point {excerpt(a, quote=False)}: the variances c_EE, c_NN, c_hh "
                                  "must be positive")
        if a == b and np.any(np.diag(blk) < var_min):
            field = ("c_EE", "c_NN", "c_hh")[int(np.argmin(np.diag(blk)))]
            raise AssessmentError(f"{location(path, line, field)}: point {excerpt(a, quote=False)}: variance "
                                  f"{np.diag(blk).min():g} m^2 is below any adjusted point's ({var_min:g} m^2, "
                                  f"an sd of {SD_BOUNDS['m'][0]:g} m)")
        if a == b and np.any(np.abs(blk - blk.T) > 1e-9 * np.abs(np.diag(blk)).max()):
            raise AssessmentError(f"{location(path, line)}: point {excerpt(a, quote=False)}: its own block is not symmetric "
                                  "(c_EN = c_NE, c_Eh = c_hE, c_Nh = c_hN)")
    order = list(dict.fromkeys(pa + pb))
    ids = [str(q) for q in points] if points is not None else order
    present = set(order)
    missing = [q for q in ids if q not in present]
    if missing:
        raise AssessmentError(f"{path}: no covariance for point(s) {excerpt(', '.join(missing[:10]), 200, quote=False)}"
                              + (" ..." if len(missing) > 10 else "")
                              + f"; the file holds {len(order)} check point(s) of its adjustment")
    pos = {q: i for i, q in enumerate(ids)}
    k = len(ids)
    C = np.full((3 * k, 3 * k), np.nan)
    for a, b, blk in zip(pa, pb, vals):
        if a in pos and b in pos:
            i, j = pos[a], pos[b]
            C[3 * i:3 * i + 3, 3 * j:3 * j + 3] = blk
            C[3 * j:3 * j + 3, 3 * i:3 * i + 3] = blk.T
    if np.isnan(C).any():
        i, j = (int(v) // 3 for v in np.argwhere(np.isnan(C))[0])
        raise AssessmentError(f"{path}: no row for the pair {ids[i]}, {ids[j]}; the file must hold one row "
                              "per pair of its points")
    sd = np.sqrt(np.diag(C))
    over = np.argwhere(np.abs(C) > np.outer(sd, sd) * (1 + 1e-9))  # |c_ij| <= sd_i sd_j (Cauchy-Schwarz)
    if len(over):
        i, j = (int(v) for v in over[0])
        line = seen.get(frozenset((ids[i // 3], ids[j // 3])))
        raise AssessmentError(f"{location(path, line)}: points {excerpt(ids[i // 3], quote=False)}, {excerpt(ids[j // 3], quote=False)}: "
                              f"covariance {C[i, j]:g} m^2 exceeds the product of the two sds ({sd[i] * sd[j]:g} "
                              "m^2): not a covariance matrix")
    try:
        np.linalg.cholesky(C + np.diag(np.full(len(C), 1e-12 * float(np.max(np.diag(C), initial=0.0)))))
    except np.linalg.LinAlgError:
        raise AssessmentError(f"{path}: the joint covariance of {excerpt(', '.join(ids[:5]), 200, quote=False)}"
                              + (" ..." if len(ids) > 5 else "") + " is not positive definite: not the "
                              "covariance of an adjustment (edited by hand?)") from None
    return ids, C


def write_point_covariance(path, ids: Sequence[str], C: np.ndarray, comment: str,
                            provenance: dict | None = None) -> None:
    """Write the joint covariance *C* (3k, 3k) of points *ids* as :func:`read_point_covariance` reads it:
    one row of the 3 x 3 block per pair a <= b, atomically."""
    from .._util import write_csv_atomic

    rows = [[a, b, *C[3 * i:3 * i + 3, 3 * j:3 * j + 3].ravel()]
            for i, a in enumerate(ids) for j, b in enumerate(ids[i:], start=i)]
    write_csv_atomic(path, COVARIANCE_COLUMNS, rows, comments=[comment], provenance=provenance)


#: columns of eop.csv (metres and degrees)
EOP_COLUMNS = ("photo", "X0", "Y0", "Z0", "omega", "phi", "kappa",
               "sd_X0", "sd_Y0", "sd_Z0", "sd_omega", "sd_phi", "sd_kappa")
#: columns of points.csv (metres); role is control, check or tie
POINT_COLUMNS = ("point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "role")
#: columns of residuals.csv: adjusted minus observed; image rows use vx_mm, vy_mm; control rows
#: vE_m, vN_m, vh_m; camera-constraint rows (kind eo) vE_m, vN_m, vh_m for X0, Y0, Z0 and the angles
RESIDUAL_COLUMNS = ("kind", "photo", "point", "vx_mm", "vy_mm", "vE_m", "vN_m", "vh_m",
                    "vomega_deg", "vphi_deg", "vkappa_deg")


def write_adjustment(result: BundleResult, folder, extra: dict | None = None, *,
                     snooping: SnoopingResult | None = None, provenance: dict | None = None) -> dict:
    """Write ``eop.csv``, ``points.csv``, ``residuals.csv`` and ``summary.json`` into *folder*,
    and ``check_covariance.csv`` (:func:`read_point_covariance`) when the adjustment converged
    with 1 to :data:`MAX_JOINT_COVARIANCE_POINTS` check points and ``precision="all"``.

    With *snooping* (:func:`lidarcat.bundle.reliability.snoop`) also ``blunders.csv`` (every
    group rejected, :data:`BLUNDER_COLUMNS`) and ``reliability.csv`` (redundancy number,
    w-test, MDB and external reliability of every scalar observation), and the keys
    ``snooping`` and ``blunders`` in the summary.  *provenance*
    (:func:`lidarcat._util.provenance`) goes into every CSV sidecar and the summary.

    Each file is written atomically; wrap the call in :func:`lidarcat._util.atomic_dir`
    to make the whole folder appear at once.  Returns the summary dict written.
    """
    from functools import partial
    from pathlib import Path

    from .._util import write_csv_atomic as _write_csv
    from .._util import write_json_atomic

    write_csv_atomic = partial(_write_csv, provenance=provenance)

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sd = result.eo_sd
    write_csv_atomic(folder / "eop.csv", EOP_COLUMNS, [
        [pid, *p[:3], *np.degrees(p[3:]), *s[:3], *np.degrees(s[3:])]
        for pid, p, s in zip(result.photo_ids, result.eo_params, sd)],
        comments=["exterior orientation: X0, Y0, Z0 (m), omega, phi, kappa (deg), "
                  "M = R3(kappa) R2(phi) R1(omega); sd_* standard deviations "
                  f"({result.variance_factor_kind.replace('_', ' ')} variance factor)"])
    write_result_eop_covariance(result, folder, provenance)   # eop_covariance.csv: the full 6 x 6 blocks
    psd = result.point_sd_m
    write_csv_atomic(folder / "points.csv", POINT_COLUMNS, [
        [q, *x, *s, r] for q, x, s, r in zip(result.point_ids, result.points_m, psd, result.point_role)],
        comments=["adjusted object points: E, N, h and standard deviations (m); "
                  "role: control (weighted constraint), check (free, for assessment), tie (free)"])
    pr = result.problem
    nan = math.nan
    rows: list[list[Any]] = [["image", pr.photo_ids[i], pr.point_ids[j], v[0], v[1], nan, nan, nan, nan, nan, nan]
                             for i, j, v in zip(pr.photo_index, pr.point_index, result.residuals_mm)]
    for j, v, sdc in zip(pr.constraint_point_index, result.constraint_residuals_m, pr.constraint_sd_m):
        v = np.where(np.isfinite(sdc), v, nan)
        rows.append(["control", "", pr.point_ids[j], nan, nan, *v, nan, nan, nan])
    if result.eo_constraint_residuals is not None:
        for i, v, sde in zip(pr.eo_constraint_photo_index, result.eo_constraint_residuals, pr.eo_constraint_sd):
            v = np.where(np.isfinite(sde), v, nan)
            rows.append(["eo", pr.photo_ids[i], "", nan, nan, *v[:3], *np.degrees(v[3:])])
    write_csv_atomic(folder / "residuals.csv", RESIDUAL_COLUMNS, rows,
                     comments=["residuals v = adjusted - observed"])
    checks = [str(q) for q, r in zip(result.point_ids, result.point_role) if r == "check"]
    if checks and result.success and result.precision == "all" and len(checks) <= MAX_JOINT_COVARIANCE_POINTS:
        write_point_covariance(
            folder / "check_covariance.csv", checks, joint_point_covariance(result, checks),
            "joint covariance of the check points' adjusted E, N, h (m^2), cross-covariances "
            "included: c_XY = Cov(X of point_a, Y of point_b), one row per pair a <= b "
            f"({result.variance_factor_kind.replace('_', ' ')} variance factor)", provenance)
    elif len(checks) > MAX_JOINT_COVARIANCE_POINTS:
        log.info("%d check points: joint covariance not written (limit %d)", len(checks),
                 MAX_JOINT_COVARIANCE_POINTS)
    summary = {**result.summary(), **(extra or {})}
    if getattr(pr, "lines", None) is not None:          # line_residuals.csv (survey/lines.py)
        from .lines import write_line_residuals

        rel = None if snooping is None else snooping.reliability
        summary.update(write_line_residuals(result, folder, write_csv_atomic,
                                            level=0.001 if rel is None else rel.alpha))
    if snooping is not None:
        summary.update(_write_snooping(snooping, folder, write_csv_atomic))
    if provenance is not None:
        summary["provenance"] = provenance
    write_json_atomic(folder / "summary.json", summary)
    return summary


#: columns of ``blunders.csv``: estimated errors in mm (image), m (control), m and deg (eo)
BLUNDER_COLUMNS = ("kind", "photo", "point", "w", "w_critical", "redundancy", "estimated_error_1",
                   "estimated_error_2", "estimated_error_3", "removed", "found_by", "iteration", "note")


def _write_snooping(snooping: SnoopingResult, folder, write_csv) -> dict:
    """blunders.csv and reliability.csv of the snooping hook; returns the summary keys."""
    from ..bundle.redundancy import RELIABILITY_COLUMNS

    if snooping.mode == "off":
        return snooping.summary()
    rows = []
    for b in snooping.blunders:
        err = list(b.estimated_error[:3]) + [math.nan] * (3 - min(3, len(b.estimated_error)))
        rows.append([b.kind, b.photo or "", b.point or "", b.w, b.w_critical, b.redundancy, *err,
                     b.removed, b.found_by, b.iteration, b.note])
    write_csv(folder / "blunders.csv", BLUNDER_COLUMNS, rows, comments=[
        f"observation groups rejected by data snooping ({snooping.mode}; robust {snooping.robust}): "
        "w = sqrt of the group's chi-square test statistic, w_critical its critical value, redundancy "
        "the mean redundancy number, estimated_error_1..3 the estimated bias (observed minus true) of "
        "x, y (mm, image), E, N, h (m, control) or X0, Y0, Z0 (m, eo)"])
    if snooping.reliability is not None:
        write_csv(folder / "reliability.csv", RELIABILITY_COLUMNS, snooping.reliability.rows(), comments=[
            "one row per scalar observation: redundancy number r, component w-test, estimated error, "
            "minimal detectable bias (mdb) in the unit given, bias-to-noise ratio (bnr) and the shift of "
            "the orientation of effect_photo by that MDB (external reliability); w, w_critical: the "
            "group's multi-dimensional test"])
    return snooping.summary()


def adjust_survey(
    survey=None,
    *,
    control: str | None = None,
    observations: str | None = None,
    outdir=None,
    variance_factor: str | None = None,
    chi2_level: float | None = None,
    eo_constraints: bool = False,
    max_iter: int = 50,
    precision: str = "all",
    progress: Callable[[int, float], None] | None = None,
    snooping: str = "report",
    snooping_level: float | None = None,
    family_level: float = FAMILY_LEVEL,
    robust: str = "none",
    start: str = "robust",
    variance_components: bool = False,
) -> tuple[BundleResult, Any]:
    """Load a survey, adjust it and write the result folder (``lidarcat adjust``).

    Parameters
    ----------
    survey : Survey, path or None
        None: the embedded thesis block.
    control, observations : str, optional
        Control set and observation kind (default: the survey's settings).
    outdir : path, optional
        Output folder (default :meth:`Survey.output_dir`); written atomically,
        files are replaced only when every file has been written.
    variance_factor, chi2_level : optional
        Default: the survey's ``[adjustment]`` settings.
    eo_constraints : bool
        Use photos.csv exterior orientations with sigmas as weighted constraints.
    snooping : {"off", "report", "remove"}
        Baarda's data snooping (:func:`lidarcat.bundle.reliability.snoop`): list the
        blunders (``report``, the result keeps every observation) or remove them.
    snooping_level : float, optional
        alpha of the one-dimensional w-test (B-method, power 0.80); default: from
        *family_level* and the number of tests (:func:`lidarcat.bundle.reliability.family_alpha`).
    family_level : float
        Probability that a block without blunders has any test rejecting (0.05).
    robust : {"none", "danish", "huber"}
        Re-weighting before snooping (large blocks with many blunders).
    start : {"robust", "plain"}
        With snooping ``report``/``remove``: screen the tie points by their intersection geometry
        and re-weight with a graduated Cauchy loss before any least-squares step
        (:func:`lidarcat.bundle.robust.robust_start`), or least squares from the start.
    precision : {"all", "photos", "none"}
        Covariance blocks to compute (see :func:`adjust`); the joint covariance of
        the check points is written with ``"all"`` only.
    variance_components : bool
        Estimate one variance factor per observation group (tie points, targets, control,
        GNSS, IMU) and adjust with them (:mod:`lidarcat.bundle.variance`; the snooping is
        repeated in every round); ``summary.json`` gains ``variance_components``.

    Returns
    -------
    (BundleResult, Path of the output folder)
        The final adjustment (without the removed groups for ``remove``); the
        blunders are in ``summary.json`` (``blunders``, ``snooping``) and
        ``blunders.csv``.

    Raises
    ------
    SurveyError, DatumError
    """
    from .._util import atomic_dir
    from .folder import Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    out = survey.output_dir(outdir)
    with atomic_dir(out) as tmp:  # the folder is replaced only when every file is written
        sres = adjust_survey_into(survey, tmp, control=control, observations=observations,
                                  variance_factor=variance_factor, chi2_level=chi2_level,
                                  eo_constraints=eo_constraints, max_iter=max_iter, precision=precision,
                                  progress=progress, snooping=snooping, snooping_level=snooping_level,
                                  family_level=family_level, robust=robust, start=start,
                                  variance_components=variance_components)
    return sres.result, out


def adjust_survey_into(
    survey: Survey,
    folder,
    *,
    control: str | None = None,
    observations: str | None = None,
    variance_factor: str | None = None,
    chi2_level: float | None = None,
    eo_constraints: bool = False,
    max_iter: int = 50,
    precision: str = "all",
    progress: Callable[[int, float], None] | None = None,
    snooping: str = "report",
    snooping_level: float | None = None,
    family_level: float | None = FAMILY_LEVEL,
    robust: str = "none",
    start: str = "robust",
    variance_components: bool = False,
) -> SnoopingResult:
    """Adjust a loaded survey and write its adjustment tables into the existing *folder*.

    The body of :func:`adjust_survey` (which gives it a temporary folder and
    moves that into place): builds the bundle problem
    (:func:`problem_from_survey`), adjusts it with data snooping
    (:func:`lidarcat.bundle.reliability.snoop`) and writes ``eop.csv``,
    ``points.csv``, ``residuals.csv``, ``summary.json`` (and
    ``check_covariance.csv``, ``blunders.csv``, ``reliability.csv``) with
    :func:`write_adjustment`, each file atomically.  ``summary.json`` names the
    survey, control set and observations and holds the elapsed time (s), CRS,
    height system and the provenance (:func:`survey_provenance`).

    Parameters
    ----------
    survey : Survey
    folder : path
        Output folder.
    control, observations, variance_factor, chi2_level, eo_constraints, max_iter, precision, progress,
    snooping, snooping_level, family_level, robust, start, variance_components
        As :func:`adjust_survey` (``family_level=None``: :data:`lidarcat.bundle.reliability.FAMILY_LEVEL`).

    Returns
    -------
    SnoopingResult
        ``.result`` is the final :class:`~lidarcat.bundle.BundleResult`.
    """
    t0 = time.perf_counter()
    settings = survey.settings
    family_level = FAMILY_LEVEL if family_level is None else float(family_level)
    problem = with_survey_motion(survey, problem_from_survey(survey, control=control, observations=observations,
                                                             eo_constraints=eo_constraints))
    problem, plan = rig_plan(survey, problem)       # a rig block: photos -> exposures (survey/rigs.py)
    params = dict(control=problem.info.get("control_set"), observations=problem.info.get("observations"),
                  variance_factor=variance_factor or settings.variance_factor,
                  chi2_level=settings.chi2_level if chi2_level is None else chi2_level,
                  eo_constraints=bool(eo_constraints), max_iter=int(max_iter), snooping=snooping,
                  snooping_level=None if snooping_level is None else float(snooping_level),
                  family_level=family_level, robust=robust, start=start, precision=precision)
    params["variance_components"] = bool(variance_components)
    snoop_kw = dict(mode=snooping, level=snooping_level, family_level=family_level, robust=robust, start=start,
                    max_iter=max_iter, precision=precision, variance_factor=params["variance_factor"],
                    chi2_level=params["chi2_level"], progress=progress)

    def fit(prob: BundleProblem) -> SnoopingResult:
        return snoop(prob, **snoop_kw)

    extra: dict[str, Any] = {}
    selfcal = None
    if plan is not None and variance_components:
        raise SurveyError(f"{survey.files['rigs']}: variance components in a rig block are not estimated yet; "
                          "adjust it without --variance-components")
    if plan is not None and plan.estimate:
        sres, selfcal = _adjust_rig_block(problem, plan, snoop_kw)
    elif variance_components:
        vc = snoop_with_components(problem, **snoop_kw)     # lidarcat.bundle.variance
        sres = vc.payload
        extra["variance_components"] = vc.summary()
    else:
        sres = fit(problem)
    lines_removed = [b for b in sres.blunders if b.kind == "line" and b.removed]
    if sres.result is not None:
        rs_test = rolling_shutter_test(survey, sres.result)   # drone photos with exposure times, no model
        if rs_test is not None:
            extra["rolling_shutter_test"] = rs_test
            for w in rs_test["warnings"]:
                log.warning("%s", w)
    provenance = survey_provenance(survey, params)
    write_adjustment(sres.result, folder, extra={
        "elapsed_total_s": time.perf_counter() - t0, "crs": survey.crs, "height_system": survey.height_system,
        "survey": survey.name, "control_set": params["control"], "observations": params["observations"], **extra},
        snooping=sres, provenance=provenance)
    if lines_removed:
        _write_removed_lines(folder, sres.result, problem, lines_removed, provenance)
    if plan is not None:
        _write_rig_tables(folder, plan, sres.result, selfcal, provenance)
    return sres


def _write_removed_lines(folder, result: BundleResult, full: BundleProblem, removed_lines: list,
                         provenance: dict | None) -> None:
    """The line observations data snooping (or the robust start) removed -- tested in the same
    worst-first loop as the image points and the GNSS/INS groups
    (:func:`lidarcat.bundle.reliability.snoop`) -- as rows of line_residuals.csv (their residuals at
    the final orientation, the w at their removal, ``rejected`` = ``removed``) and
    ``line_control.removed`` of summary.json (line, photo, w, w_critical, found_by)."""
    import csv
    import json
    from pathlib import Path

    from .._util import write_csv_atomic, write_json_atomic
    from ..bundle.lines import line_residuals_mm
    from .lines import LINE_RESIDUAL_COLUMNS

    folder = Path(folder)
    L = full.lines
    labels = L.observation_labels(full.photo_ids)
    at = {lab: k for k, lab in enumerate(labels)}
    pos = {pid: i for i, pid in enumerate(result.photo_ids)}
    eo = np.asarray(result.eo_params)[[pos[str(p)] for p in full.photo_ids]]
    v = line_residuals_mm(full, eo)
    path = folder / "line_residuals.csv"
    with open(path, encoding="utf-8", newline="") as fh:
        text = fh.read().splitlines()
    comments = [ln[1:].strip() for ln in text if ln.startswith("#")]
    rows = list(csv.reader(ln for ln in text if not ln.startswith("#")))[1:]
    removed = []
    for b in removed_lines:
        k = at[f"line {b.point} on photo {b.photo}"]
        lid, ph = str(L.line_ids[L.line_index[k]]), str(full.photo_ids[L.photo_index[k]])
        rows.append([lid, ph, *v[k], *(v[k] / L.pixel_mm[k]), math.nan, math.nan, b.w, b.w_critical, "removed"])
        removed.append({"line": lid, "photo": ph, "w": float(b.w), "w_critical": float(b.w_critical),
                        "found_by": b.found_by})
    write_csv_atomic(path, LINE_RESIDUAL_COLUMNS, rows, comments=comments + [
        "rejected 'removed': removed by data snooping (--snooping remove; tested with the image points and "
        "GNSS/INS groups, blunders.csv) or the robust start, w at its removal, residuals at the final "
        "orientation"], provenance=provenance)
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    summary.setdefault("line_control", {})["removed"] = removed
    write_json_atomic(folder / "summary.json", summary)


def _adjust_rig_block(problem: BundleProblem, plan, snoop_kw: dict) -> tuple[SnoopingResult, Any]:
    """A rig block whose relative poses are estimated (rig file ``estimate``): the relative poses
    estimated from every observation (:class:`lidarcat.bundle.rig.RigRelativePoses` through
    :func:`lidarcat.bundle.adjust_with_parameters`), data snooping with the rig fixed at that
    estimate, then the estimation again without what snooping removed.  Returns the snooping
    result (its ``result`` the final adjustment) and the final :class:`SelfCalResult`."""
    import dataclasses

    from ..bundle.rig import RigRelativePoses
    from ..bundle.selfcal import adjust_with_parameters

    kw = {k: snoop_kw[k] for k in ("max_iter", "variance_factor", "chi2_level")}
    comp = [RigRelativePoses(plan.sensor_names, estimate=plan.estimate, rig_id=plan.rig_id)]
    first = adjust_with_parameters(problem, comp, precision="none", **kw)
    if not first.bundle.success:    # written as it stands (the status says why), the start poses as given
        log.warning("rig %s: the estimation of the relative poses did not converge (%s)", plan.rig_id,
                    first.bundle.message)
        return snoop(problem, **{**snoop_kw, "mode": "off"}), None
    fixed = dataclasses.replace(problem, rays=first.bundle.problem.rays)   # the rig at its estimate
    sres = snoop(fixed, **snoop_kw)
    final = adjust_with_parameters(sres.result.problem, comp, without=sres.result, precision=snoop_kw["precision"],
                                   **kw)
    return dataclasses.replace(sres, result=final.bundle), final


def _write_rig_tables(folder, plan, result: BundleResult, selfcal, provenance: dict | None) -> None:
    """The rig block's tables (:mod:`lidarcat.survey.rigs`): eop.csv, eop_covariance.csv and the image rows of
    residuals.csv per photo (the exposures' body poses move to rig_exposures.csv), rig_poses.csv (the
    relative poses, estimated or given) and the key ``rig`` of summary.json."""
    import json
    from functools import partial
    from pathlib import Path

    from .._util import write_csv_atomic as _write_csv
    from .._util import write_json_atomic
    from .covariance import EOP_COVARIANCE_FILE, write_eop_covariance
    from .rigs import RIG_POSE_COLUMNS, rig_photo_poses, rig_pose_rows

    write_csv = partial(_write_csv, provenance=provenance)
    folder = Path(folder)
    rays = result.problem.rays
    q, d = rays.sensor_rotation, rays.sensor_translation_m
    kw: dict[str, Any] = {}
    pcov = None
    if selfcal is not None:
        pcov = np.asarray(selfcal.cov)
        sd_g = np.sqrt(np.clip(np.diag(pcov), 0, None))
        sd_c = np.sqrt(np.clip(np.diagonal(np.asarray(result.eo_cov), axis1=1, axis2=2), 0, None))
        cross = np.einsum("kpi,k,pi->pik", np.asarray(selfcal.eo_correlation), sd_g, sd_c)   # Cov(body, g)
        start_q = np.asarray(rays.sensor_rotation).copy()
        eps = np.reshape(selfcal.estimates, (-1, 6))[:, :3]
        from ..geometry.rolling import rodrigues

        est = list(plan.estimate)
        start_q[est] = np.transpose(rodrigues(eps), (0, 2, 1)) @ start_q[est]   # Q = exp([eps]x) Q0
        kw = dict(params=np.asarray(selfcal.estimates), params_cov=pcov, cross_cov=cross, start_rotation=start_q)
    eo, cov = rig_photo_poses(plan, result.eo_params, result.eo_cov, q, d, **kw)
    sd = np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0, None))
    kind = result.variance_factor_kind.replace("_", " ")
    body_sd = result.eo_sd
    write_csv(folder / "rig_exposures.csv", ("exposure",) + EOP_COLUMNS[1:], [
        [eid, *p[:3], *np.degrees(p[3:]), *s[:3], *np.degrees(s[3:])]
        for eid, p, s in zip(result.photo_ids, result.eo_params, body_sd)],
        comments=[f"rig {plan.rig_id}: the body pose (the rig frame, sensor {plan.sensor_names[0]}) of every "
                  f"exposure: X0, Y0, Z0 (m), omega, phi, kappa (deg) and sds ({kind} variance factor)"])
    write_csv(folder / "eop.csv", EOP_COLUMNS, [
        [pid, *p[:3], *np.degrees(p[3:]), *s[:3], *np.degrees(s[3:])]
        for pid, p, s in zip(plan.photo_ids, eo, sd)],
        comments=["exterior orientation: X0, Y0, Z0 (m), omega, phi, kappa (deg), "
                  "M = R3(kappa) R2(phi) R1(omega); sd_* standard deviations "
                  f"({kind} variance factor); rig {plan.rig_id}: each photo its exposure's body pose composed "
                  "with its sensor's relative pose, the sds propagated (rig_poses.csv)"])
    if (folder / EOP_COVARIANCE_FILE).exists():
        write_eop_covariance(folder / EOP_COVARIANCE_FILE, list(plan.photo_ids), cov, variance_factor=kind,
                             provenance=provenance)
    pr = result.problem
    photo = plan.photo_of_observation(pr.photo_index, rays.sensor_index)
    ref = {int(e): pid for pid, e, s in zip(plan.photo_ids, plan.exposure_index, plan.sensor) if s == 0}
    nan = math.nan
    rows: list[list[Any]] = [["image", ph, pr.point_ids[j], v[0], v[1], nan, nan, nan, nan, nan, nan]
                             for ph, j, v in zip(photo, pr.point_index, result.residuals_mm)]
    for j, v, sdc in zip(pr.constraint_point_index, result.constraint_residuals_m, pr.constraint_sd_m):
        rows.append(["control", "", pr.point_ids[j], nan, nan, *np.where(np.isfinite(sdc), v, nan), nan, nan, nan])
    if result.eo_constraint_residuals is not None:
        for i, v, sde in zip(pr.eo_constraint_photo_index, result.eo_constraint_residuals, pr.eo_constraint_sd):
            v = np.where(np.isfinite(sde), v, nan)
            rows.append(["eo", ref.get(int(i), pr.photo_ids[i]), "", nan, nan, *v[:3], *np.degrees(v[3:])])
    write_csv(folder / "residuals.csv", RESIDUAL_COLUMNS, rows, comments=["residuals v = adjusted - observed"])
    prow = rig_pose_rows(plan, q, d, pcov)
    write_csv(folder / "rig_poses.csv", RIG_POSE_COLUMNS, prow, comments=[
        f"rig {plan.rig_id}: every sensor's pose relative to the rig frame (sensor_from_rig, as the rig file "
        "writes it: rotation vector deg, translation m); estimated: adjusted with sds (of a small rotation "
        "applied on the left), else the rig file's"])
    summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
    summary["rig"] = {"rig": plan.rig_id, "exposures": len(plan.exposure_ids), "photos": len(plan.photo_ids),
                      "sensors": [dict(zip(RIG_POSE_COLUMNS[1:], r[1:])) for r in prow]}
    write_json_atomic(folder / "summary.json", summary)


def write_survey_folder(survey: Survey, outdir, t0: float, parameters: dict,
                        write: Callable[[Any, dict, dict], Any], extra: dict | None = None):
    """Write a survey's result folder atomically; returns its path.

    ``write(tmp, extra, provenance)`` fills the temporary folder; *extra* (summary keys)
    gets the total elapsed time since *t0* (``time.perf_counter()``, s), the survey's CRS
    and height system; provenance is :func:`survey_provenance` of *parameters*.  The
    folder (default :meth:`Survey.output_dir`) is replaced only when ``write`` returns.
    """
    from .._util import atomic_dir

    out = survey.output_dir(outdir)
    with atomic_dir(out) as tmp:
        write(tmp, {"elapsed_total_s": time.perf_counter() - t0, "crs": survey.crs,
                    "height_system": survey.height_system, **(extra or {})},
              survey_provenance(survey, parameters))
    return out


def survey_provenance(survey: Survey, parameters: dict) -> dict:
    """:func:`lidarcat._util.provenance` of the survey files an adjustment reads (SHA-256 each), with the
    survey's ``crs`` and ``height_system``."""
    from .._util import provenance

    files = {"survey.toml": survey.toml_path, **{k: v for k, v in survey.files.items() if k != "lidar"}}
    # the CRS and height system of every coordinate in the tables, in each CSV's sidecar (issue 25)
    return provenance(files, parameters, root=survey.root) | {"crs": str(survey.crs),
                                                              "height_system": survey.height_system}
