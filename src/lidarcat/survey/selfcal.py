r"""Additional parameters from a survey folder: the ``[self_calibration]`` table and the CLI switches.

survey.toml (every key optional)::

    [self_calibration]
    parameters = "c,x0,y0,k1"     # interior orientation to estimate, per camera (or "all"), or a
                                  # named set: thesis, brown, ebner, gruen ("c,x0,y0,ebner")
    use_priors = true             # weight them by the sd_* of camera.toml (no sd: free)
    frame_offset = "lidar:gps"    # SOURCE:REFERENCE -- shift the control of ground-point source
                                  # SOURCE into the frame of REFERENCE (needs control of both)
    similarity = false            # 7-parameter similarity instead of a 3-D shift
    control = "gps+lidar"         # control set(s); "a+b" joins two sets of control_sets.csv
    alpha = 0.05                  # level of the t-tests and group tests
    gnss_drift = false            # GNSS lines: also a drift along each line (m/km)

    [self_calibration.gnss_lines] # GNSS antenna offset per flight line (photos.csv X0, Y0, Z0 with
    1 = ["1", "2", "3"]           # sd_X0.. become constraints): line label = its photo ids
    2 = ["4", "5", "6"]

``lidarcat adjust --self-calibrate c,x0,y0,k1 --frame-offset lidar:gps
--control gps+lidar`` overrides them.  A control-set name ``a+b`` is the union of
the sets' control points (each with its own set's sds) and of their check
points that are control in neither.  With a frame offset and no control named,
the default set is joined with every set that holds control of one of the two
sources (``gps+lidar`` for the thesis block).

Blunders and variance components with additional parameters
------------------------------------------------------------
Baarda's w-test of observation i needs its redundancy number
r_i = (Q_vv P)_ii with Q_vv = Q_ll - A Q_xx A', where Q_xx is the cofactor of
*every* unknown: with additional parameters g it would be the inverse of the
normal equations bordered by the columns of g.  :mod:`lidarcat.bundle.reliability`
computes Q_vv of the plain problem only.  So :func:`selfcal_snooped` works in three
steps, in one call:

1. data snooping (:func:`lidarcat.bundle.reliability.snoop`, with the variance
   factor of each observation group estimated by
   :func:`lidarcat.bundle.variance.snoop_with_components` when asked) on the
   adjustment *without* the parameters;
2. the adjustment with the parameters (:func:`lidarcat.bundle.selfcal.adjust_with_parameters`)
   of the problem snooping ended with: its kept observations (``remove``) or all
   of them (``report``), their sds multiplied by the estimated group factors,
   started from the snooping's final adjustment;
3. with the variance components: their factors re-estimated in the adjustment with
   the parameters, ``sigma_g^2 = v_g' P_g v_g / r_g`` (Förstner, iterated,
   :func:`lidarcat.bundle.variance.iterate_components`), where r_g are the
   redundancy numbers of step 1's last adjustment, those of the image
   observations reduced in proportion by the k unknowns the parameters add
   (sum r = dof - k).  The r_i of the individual observations move little when k
   parameters join thousands of observations; the sum is exact.  Without this
   step the factors of step 1, which hold the model error the parameters remove,
   are too large: on a synthetic block with 1.7 px of radial distortion at the
   corners, tie factor 0.286 instead of 0.25, and the global test of the
   adjustment with the parameters rejected at the lower tail.

A model error the parameters absorb (a principal-point offset: one pixel shift
of every ray of a photo) enters step 1 as a systematic residual; a ray near the
image edge, where the missing distortion is largest, can be named although the
camera with the parameters fits it, and a large one can make the tests reject a
photo's GNSS/INS group.  With 6 px at the corners of the synthetic block, four
groups were named (kept, as the datum) and one good ray was removed; k1 and the
tie factor were still recovered.
On the NGI frames (docs/figures.md, ``--self-calibrate thesis``) one ``lidarcat adjust``
brings the orientation to within 1 m / 0.01 deg of the published one (0.85 m /
0.0036 deg with the default distribution of the matches, 0.98 m / 0.0068 deg
with every track) and names every observation more than 2 px from the published
geometry with the default distribution (with every track, one 3.8-px ray of a
three-ray track is not named).

:func:`adjust_survey_with_parameters` writes the usual adjustment folder
(:func:`lidarcat.bundle.write_adjustment`) of the adjustment *with* the
parameters; ``summary.json`` gains ``additional_parameters``, ``frame_offset``,
``parameter_groups``, ``parameters_off`` / ``parameters_on`` (v'Pv, sigma0^2,
RMS residuals without and with them) and ``warnings``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import re
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from ..errors import SurveyError
from ..bundle.additional import GnssLineOffsets, SelfCalibration, parse_parameters
from ..bundle.frame_offset import frame_offset_from_sources
from ..bundle.problem import BundleProblem
from ..bundle.selfcal import SelfCalResult, adjust_with_parameters
from .schema import SURVEY_KEYS, SelfCalSettings, split_frame_offset

__all__ = ["SelfCalSettings", "self_calibration_settings", "combined_control_set", "components_from_survey",
           "adjust_survey_with_parameters", "selfcal_adjust", "write_selfcal", "format_parameters",
           "wants_parameters", "SNOOPING_WITH_PARAMETERS", "ROBUST_WITH_PARAMETERS",
           "SNOOPED_WITHOUT_PARAMETERS", "SelfCalSnooped", "selfcal_snooped"]

log = logging.getLogger(__name__)


#: keys of the [self_calibration] table of survey.toml (validated by lidarcat.survey.schema)
SELF_CALIBRATION_KEYS = tuple(SURVEY_KEYS["self_calibration"])

#: why the adjustment with additional parameters is not tested for blunders by default (summary.json, CLI)
SNOOPING_WITH_PARAMETERS = (
    "data snooping is off by default with additional parameters (--self-calibrate, --frame-offset or "
    "[self_calibration]) on a survey without matched tie points: give --snooping report|remove to test the "
    "observations in the adjustment without the parameters first")

#: why --robust is refused with additional parameters (CLI)
ROBUST_WITH_PARAMETERS = (
    "the iteratively re-weighted start is not available with additional parameters (--self-calibrate, "
    "--frame-offset or [self_calibration]); use --snooping report|remove (--start robust screens the matches)")

#: how the blunders of an adjustment with additional parameters were found (summary.json, CLI)
SNOOPED_WITHOUT_PARAMETERS = (
    "the w-tests (blunders.csv) are those of the adjustment without the additional parameters; the "
    "parameters were then estimated from the observations it kept, the variance components re-estimated "
    "with them (lidarcat.survey.selfcal: a residual the parameters explain can be named)")


@dataclasses.dataclass(frozen=True, eq=False)
class SelfCalSnooped:
    """Outcome of :func:`selfcal_snooped`.

    Attributes
    ----------
    survey : Survey
    result : SelfCalResult
        The adjustment with the additional parameters.
    snooping : SnoopingResult or None
        Data snooping of the adjustment without them (None: snooping ``off``).
    variance_components : VarianceComponents or None
        The group factors the sds of *result* were multiplied by (None: not estimated).
    """

    survey: Any
    result: SelfCalResult
    snooping: Any = None
    variance_components: Any = None


def self_calibration_settings(survey) -> SelfCalSettings:
    """The ``[self_calibration]`` table of the survey (parsed and checked by :meth:`Survey.load`)."""
    return survey.config.self_calibration


def combined_control_set(survey, name: str | None):
    """The control set *name*, or the union of ``a+b`` (see the module docstring).

    Raises
    ------
    SurveyError
        An unknown set (from :meth:`lidarcat.Survey.control_set`).
    """
    from .folder import ControlSet

    if name is None or "+" not in name:
        return survey.control_set(name)
    sets = [survey.control_set(n.strip()) for n in name.split("+")]
    ctrl, sd = [], []
    for s in sets:
        for q, v in zip(s.control.tolist(), s.sd_m):
            if q not in ctrl:
                ctrl.append(q)
                sd.append(v)
    chk, csd = [], []
    for s in sets:
        for q, v in zip(s.check.tolist(), s.check_sd_m):
            if q not in ctrl and q not in chk:
                chk.append(q)
                csd.append(v)
    return ControlSet(name, np.array(ctrl, dtype=str), np.array(chk, dtype=str),
                      np.array(sd).reshape(-1, 3), np.array(csd).reshape(-1, 3))


def _sets_with_sources(survey, sources: tuple[str, str]) -> str | None:
    """``a+b``: the default control set and every other set holding control of the two sources
    (the default control of a frame offset); None when the default alone holds both."""
    gp = survey.ground_points
    src_of = dict(zip(gp.point.tolist(), gp.source.tolist()))
    names = list(survey.control_sets)
    default = survey.default_control or (names[0] if names else None)
    if default is None:
        return None
    order = [default] + [n for n in names if n != default]
    chosen, seen = [], set()
    for n in order:
        got = {src_of.get(q) for q in survey.control_sets[n].control.tolist()} & set(sources)
        if n == default or got - seen:
            chosen.append(n)
            seen |= got
    if len(chosen) > 1:
        log.info("frame offset %s:%s: control sets %s joined", *sources, "+".join(chosen))
    return "+".join(chosen) if len(chosen) > 1 else None


def components_from_survey(survey, problem: BundleProblem, settings: SelfCalSettings) -> list[Any]:
    """The components (:class:`SelfCalibration`, :class:`FrameOffset`, :class:`GnssLineOffsets`) of
    *settings* for *problem*.

    Raises
    ------
    AdditionalParameterError
        A frame-offset source without control in the problem (named).
    """
    comps: list[Any] = []
    if settings.parameters:
        photo_camera = [survey.photo(str(i)).camera for i in problem.photo_ids]
        comps.append(SelfCalibration(survey.cameras, photo_camera, settings.parameters,
                                     use_priors=settings.use_priors))
    if settings.frame_offset is not None:
        gp = survey.ground_points
        src_of = dict(zip(gp.point.tolist(), gp.source.tolist()))
        sources = [src_of.get(str(problem.point_ids[j]), "") for j in problem.constraint_point_index]
        comps.append(frame_offset_from_sources(problem, sources, *settings.frame_offset,
                                               similarity=settings.similarity))
    if settings.gnss_lines:
        comps.append(GnssLineOffsets([settings.gnss_lines.get(str(i)) for i in problem.photo_ids],
                                     drift=settings.gnss_drift))
    return comps


def adjust_survey_with_parameters(
    survey=None,
    *,
    control: str | None = None,
    self_calibrate: str | None = None,
    frame_offset: str | None = None,
    similarity: bool | None = None,
    observations: str | None = None,
    outdir=None,
    variance_factor: str | None = None,
    chi2_level: float | None = None,
    eo_constraints: bool = False,
    max_iter: int = 50,
    precision: str = "all",
    snooping: str = "off",
    snooping_level: float | None = None,
    family_level: float | None = None,
    start: str = "robust",
    variance_components: bool = False,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[SelfCalResult, Any]:
    """``lidarcat adjust`` with additional parameters: adjust, test, write the result folder.

    Parameters
    ----------
    survey : Survey, path or None
        None: the embedded thesis block.
    control : str, optional
        Control set, ``a+b`` for a union (default: ``[self_calibration] control``,
        else the survey's default).
    self_calibrate : str, optional
        ``"c,x0,y0,k1"``, a set name ``"ebner"`` or both ``"c,x0,y0,ebner"``
        (:func:`lidarcat.bundle.additional.parse_parameters`; default: ``[self_calibration] parameters``).
    frame_offset : str, optional
        ``"SOURCE:REFERENCE"`` (default: ``[self_calibration] frame_offset``).
    similarity : bool, optional
        7-parameter similarity for the frame offset.
    observations, outdir, variance_factor, chi2_level, eo_constraints, max_iter, precision
        As :func:`lidarcat.bundle.adjust_survey`.
    snooping, snooping_level, family_level, start, variance_components, progress
        Data snooping (and the group variance factors) of the adjustment without the parameters,
        before it (:func:`selfcal_snooped`); ``blunders.csv`` and the summary's ``snooping``,
        ``blunders`` and ``variance_components`` keys as :func:`lidarcat.survey.adjust_survey` writes
        them (no ``reliability.csv``: its tests would be of the other adjustment).

    Returns
    -------
    (SelfCalResult, Path of the output folder)

    Raises
    ------
    SurveyError
        Nothing to estimate, a bad switch, or an unknown control set (named).
    AdditionalParameterError, DatumError
    """
    t0 = time.perf_counter()
    sc = selfcal_snooped(survey, control=control, self_calibrate=self_calibrate, frame_offset=frame_offset,
                         similarity=similarity, observations=observations, variance_factor=variance_factor,
                         chi2_level=chi2_level, eo_constraints=eo_constraints, max_iter=max_iter,
                         precision=precision, snooping=snooping, snooping_level=snooping_level,
                         family_level=family_level, start=start, variance_components=variance_components,
                         progress=progress)
    survey, res = sc.survey, sc.result
    from .adjustment import write_survey_folder

    info = res.bundle.problem.info
    params = dict(control=info.get("control_set"), observations=info.get("observations"),
                  variance_factor=res.bundle.variance_factor_kind, chi2_level=float(res.bundle.chi2["level"]),
                  eo_constraints=bool(info.get("eo_constraints")), max_iter=int(max_iter), precision=precision,
                  additional_parameters=list(res.names), alpha=res.alpha, snooping=snooping,
                  snooping_level=None if snooping_level is None else float(snooping_level),
                  family_level=family_level, start=start, variance_components=bool(variance_components))
    extra: dict[str, Any] = {}
    if sc.variance_components is not None:
        extra["variance_components"] = sc.variance_components.summary()
    if sc.snooping is None:
        extra["snooping"] = {"mode": "off", "reason": SNOOPING_WITH_PARAMETERS}
    out = write_survey_folder(survey, outdir, t0, params,
                              lambda tmp, ex, prov: write_selfcal(res, tmp, extra=ex, provenance=prov,
                                                                  snooping=sc.snooping),
                              extra=extra)
    return res, out


def selfcal_adjust(survey=None, *, control: str | None = None, self_calibrate: str | None = None,
                   frame_offset: str | None = None, similarity: bool | None = None,
                   observations: str | None = None, variance_factor: str | None = None,
                   chi2_level: float | None = None, eo_constraints: bool = False, max_iter: int = 50,
                   precision: str = "all") -> tuple[Any, SelfCalResult]:
    """The adjustment of :func:`adjust_survey_with_parameters` without writing and without data
    snooping: ``(survey, result)``."""
    out = selfcal_snooped(survey, control=control, self_calibrate=self_calibrate, frame_offset=frame_offset,
                          similarity=similarity, observations=observations, variance_factor=variance_factor,
                          chi2_level=chi2_level, eo_constraints=eo_constraints, max_iter=max_iter,
                          precision=precision)
    return out.survey, out.result


def selfcal_snooped(survey=None, *, control: str | None = None, self_calibrate: str | None = None,
                    frame_offset: str | None = None, similarity: bool | None = None,
                    observations: str | None = None, variance_factor: str | None = None,
                    chi2_level: float | None = None, eo_constraints: bool = False, max_iter: int = 50,
                    precision: str = "all", snooping: str = "off", snooping_level: float | None = None,
                    family_level: float | None = None, start: str = "robust",
                    variance_components: bool = False,
                    progress: Callable[[int, float], None] | None = None) -> SelfCalSnooped:
    """The adjustment with additional parameters after data snooping without them (module docstring).

    Parameters
    ----------
    survey, control, self_calibrate, frame_offset, similarity, observations, variance_factor, chi2_level,
    eo_constraints, max_iter, precision
        As :func:`adjust_survey_with_parameters`.
    snooping : {"off", "report", "remove"}
        Data snooping of the adjustment without the parameters; ``remove``: the parameters are estimated
        without the named observations, ``report``: with every observation (the blunders named).
    snooping_level, family_level, start
        As :func:`lidarcat.survey.adjust_survey`.
    variance_components : bool
        Estimate one variance factor per observation group with the snooping
        (:func:`lidarcat.bundle.variance.snoop_with_components`); the adjustment with the parameters
        uses the sds times the factors.
    progress : callable, optional
        ``progress(iteration, vtpv)`` of the snooping's adjustments.

    Returns
    -------
    SelfCalSnooped

    Raises
    ------
    SurveyError
        Nothing to estimate, a bad switch, an unknown control set, a rig survey, or an unknown
        snooping mode (named).
    AdditionalParameterError, DatumError
    """
    from ..bundle.redundancy import FAMILY_LEVEL
    from ..bundle.reliability import snoop
    from ..bundle.variance import snoop_with_components
    from .adjustment import problem_from_survey
    from .folder import Survey

    if snooping not in ("off", "report", "remove"):
        raise SurveyError(f"snooping {snooping!r}: expected off, report or remove")
    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    st = self_calibration_settings(survey)
    try:
        st = dataclasses.replace(
            st,
            parameters=parse_parameters(self_calibrate) if self_calibrate else st.parameters,
            frame_offset=split_frame_offset(frame_offset) if frame_offset else st.frame_offset,
            similarity=st.similarity if similarity is None else bool(similarity))
    except ValueError as ex:
        raise SurveyError(str(ex)) from ex
    if not st.active:
        raise SurveyError(f"{survey.toml_path}: no additional parameter switched on: give --self-calibrate "
                          "and/or --frame-offset, or a [self_calibration] table")
    if survey.files.get("rigs") is not None:   # the rig block is survey.adjustment's (survey.rigs.rig_plan)
        raise SurveyError(f"{survey.files['rigs']}: additional parameters (self-calibration, frame offsets) in a rig "
                          "survey are not supported yet; adjust it without them")
    control = control or st.control
    if control is None and st.frame_offset is not None:
        control = _sets_with_sources(survey, st.frame_offset)
    # no control set: the weighted GNSS/INS orientations are the datum (as survey.adjustment.problem_from_survey)
    cset = None if control is None and survey.default_control is None and eo_constraints else \
        combined_control_set(survey, control)
    # GNSS line offsets act on the camera-position constraints: switch them on
    problem = problem_from_survey(survey, control=cset, observations=observations,
                                  eo_constraints=eo_constraints or bool(st.gnss_lines))
    held = problem.eo_constraint_photo_index
    if st.gnss_lines and (held is None or not len(held)):
        raise survey.config.error(
            "self_calibration", "gnss_lines", f"GNSS line offsets act on constrained camera positions, but no "
            f"photo of {survey.files['photos']} has X0, Y0, Z0 with sd_X0, sd_Y0, sd_Z0")
    settings = survey.settings
    vf = variance_factor or settings.variance_factor
    level = settings.chi2_level if chi2_level is None else chi2_level
    comps = components_from_survey(survey, problem, st)

    def with_parameters(prob: BundleProblem, without=None) -> SelfCalResult:
        return adjust_with_parameters(prob, comps, without=without, max_iter=max_iter, variance_factor=vf,
                                      chi2_level=level, alpha=st.alpha, precision=precision)

    if snooping == "off" and not variance_components:
        return SelfCalSnooped(survey, with_parameters(problem))
    kw = dict(mode=snooping, level=snooping_level, family_level=FAMILY_LEVEL if family_level is None
              else float(family_level), start=start, max_iter=max_iter, precision=precision,
              variance_factor=vf, chi2_level=level, progress=progress)
    vc = None
    if variance_components:
        vc = snoop_with_components(problem, **kw)     # lidarcat.bundle.variance
        sres = vc.payload
    else:
        sres = snoop(problem, **kw)
    if sres.result is None or not sres.result.success:
        res = with_parameters(problem)
    elif vc is None or sres.reliability is None:
        # the problem snooping ended with: without the removed groups (remove), sds x the group factors
        res = with_parameters(sres.result.problem, sres.result)
    else:
        vc, res = _components_with_parameters(sres, vc, with_parameters)
    return SelfCalSnooped(survey, res, None if snooping == "off" else sres, vc)


def _components_with_parameters(sres, vc, with_parameters) -> tuple[Any, SelfCalResult]:
    """The group factors re-estimated in the adjustment with the parameters (module docstring, step 3):
    ``r_g`` from the snooping's redundancy numbers, the image rows' sum less the unknowns the
    parameters add; the adjustment with the parameters at the factors reached."""
    from ..bundle.variance import GROUPS, group_labels, iterate_components, scaled_problem

    rel = sres.reliability
    f0 = vc.factors()
    raw = scaled_problem(sres.result.problem, {g: 1.0 / f for g, f in f0.items()})   # the a priori sds
    red = np.array(rel.redundancy, float)
    kept = {(b.kind, b.photo or "", b.point or "") for b in sres.blunders if not b.removed}
    exclude = None
    if kept:     # named but kept (a GNSS/INS group of the datum, report mode): out of the sums
        keys = zip(rel.kind.tolist(), [str(x) for x in rel.photo], [str(x) for x in rel.point])
        exclude = np.array([k in kept for k in keys], dtype=bool)
    lab = group_labels(raw)
    img = np.isin(lab, (GROUPS.index("tie"), GROUPS.index("target"))) & np.isfinite(red)
    out: dict[str, SelfCalResult] = {}

    def fit(prob: BundleProblem):
        res = with_parameters(prob, None if out else sres.result)   # round 1: the snooping's sds
        out["res"] = res
        k = max(0.0, float(sres.result.dof - res.bundle.dof))     # the unknowns the parameters add
        r = red.copy()
        r[img] *= max(0.0, 1.0 - k / max(float(r[img].sum()), 1.0))
        return res.bundle, (r if res.bundle.success else None), exclude, None

    vc2 = iterate_components(raw, fit, factors=f0)
    return dataclasses.replace(vc2, payload=None), out["res"]


def write_selfcal(res: SelfCalResult, folder, extra: dict | None = None, provenance: dict | None = None,
                  snooping: Any = None) -> dict:
    """:func:`lidarcat.bundle.write_adjustment` of the adjustment with the parameters, summary.json with
    :meth:`SelfCalResult.summary`, check_covariance.csv with the parameters' rank-k term (and the
    *provenance* of :func:`lidarcat.survey.adjustment.survey_provenance`).  With *snooping* (the
    :class:`~lidarcat.bundle.reliability.SnoopingResult` of :func:`selfcal_snooped`) also blunders.csv and
    the summary's ``snooping`` (with ``reason`` :data:`SNOOPED_WITHOUT_PARAMETERS`) and ``blunders``.
    Returns the summary written."""
    from pathlib import Path

    from .._util import write_json_atomic
    from .adjustment import write_adjustment, write_point_covariance

    folder = Path(folder)
    # reliability.csv is not written: its redundancy numbers are of the adjustment without the parameters
    summary = write_adjustment(res.bundle, folder, extra={**(extra or {}), **res.summary()},
                               provenance=provenance,
                               snooping=None if snooping is None else dataclasses.replace(snooping, reliability=None))
    if snooping is not None:
        sn = snooping.summary()["snooping"]        # the levels and critical values of the tests made
        summary["snooping"] = {**sn, "reason": SNOOPED_WITHOUT_PARAMETERS}
        write_json_atomic(folder / "summary.json", summary)
    if (folder / "check_covariance.csv").is_file():       # add the additional parameters' rank-k term
        checks = [str(q) for q, r in zip(res.bundle.point_ids, res.bundle.point_role) if r == "check"]
        write_point_covariance(
            folder / "check_covariance.csv", checks, res.joint_point_covariance(checks),
            "joint covariance of the check points' adjusted E, N, h (m^2), cross-covariances and the "
            "uncertainty of the additional parameters included: c_XY = Cov(X of point_a, Y of "
            f"point_b), one row per pair a <= b ({res.bundle.variance_factor_kind.replace('_', ' ')} "
            "variance factor)", provenance=provenance)
    return summary


def wants_parameters(survey, self_calibrate: str | None = None, frame_offset: str | None = None) -> bool:
    """True when switches are given or the survey's ``[self_calibration]`` switches something on."""
    if self_calibrate or frame_offset:
        return True
    from .folder import Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    return self_calibration_settings(survey).active


def _num(value: Any, spec: str) -> str:
    """*value* formatted with *spec*; None (a ``null`` of summary.json) or a non-finite number as ``-``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return format(value, spec)
    align, width = re.match(r"([<>^]?)[+ -]?(\d*)", spec).groups()  # type: ignore[union-attr]
    return format("-", f"{align or '>'}{width}")


def format_parameters(summary: dict) -> str:
    """Text lines of the additional parameters and the frame offset of a ``summary.json``
    (a figure not computed, ``null``, as ``-``)."""
    lines = []
    ap = summary.get("additional_parameters") or {}
    if ap:
        lines += ["", "Additional parameters (correction to the certificate)   estimate        sd       t  "
                  "signif.  max |r| (with)"]
        def natural(item):                       # e2 before e10 (summary.json keys come sorted as text)
            return [int(x) if x.isdigit() else x for x in re.split(r"(\d+)", item[0])]

        for name, t in sorted(ap.items(), key=natural):
            e = t.get("max_correlation_eo") or {}
            a = t.get("max_correlation_additional") or {}
            r, w = (e.get("r", 0.0), f"{e.get('parameter')} photo {e.get('photo')}")
            if a and abs(a.get("r") or 0.0) > abs(r or 0.0):
                r, w = a["r"], a["parameter"]
            lines.append(f"  {name:<22} {t['unit']:<6} {_num(t.get('estimate'), '>+14.6g')} "
                         f"{_num(t.get('sd'), '>10.3g')} {_num(t.get('t'), '>7.2f')}"
                         f"  {'yes' if t.get('significant') else 'no':<7}  {_num(r, '+.3f')} ({w})")
    fo = summary.get("frame_offset")
    for f in ([fo] if isinstance(fo, dict) else fo or []):
        s, sd, tt = f["shift_m"], f["sd_m"], f["t"]
        lines += ["", f"Frame offset {f['source']} -> {f['reference']} (add to {f['source']} coordinates), m:",
                  "  " + "   ".join(f"{k} {_num(s[i], '+.3f')} +- {_num(sd[i], '.3f')} (t {_num(tt[i], '+.1f')})"
                             for i, k in enumerate("ENh")),
                  f"  joint {f['test']['test']} test: statistic {_num(f['test'].get('statistic'), '.2f')}, p = "
                  f"{_num(f['test'].get('p_value'), '.2g')}: "
                  + ("significant" if f["significant"] else "not significant") + f" at {100 * f['alpha']:g} %"]
    off, on = summary.get("parameters_off"), summary.get("parameters_on")
    if off and on:
        lines.append(f"v'Pv without / with the parameters: {_num(off.get('vtpv'), '.2f')} (dof {off['dof']}) / "
                     f"{_num(on.get('vtpv'), '.2f')} (dof {on['dof']})")
    for w in summary.get("warnings") or []:
        lines.append(f"WARNING: {w}")
    return "\n".join(lines)
