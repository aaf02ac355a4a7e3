"""``lidarcat adjust``: bundle adjustment of a survey (thesis section 2.1.2)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import click

from .._util.formatting import format_number
from .options import echo_json, json_opt, output_option, progress_bar, survey_arg

__all__ = ["adjust", "format_report", "format_blunders", "format_components", "exit_status"]


def format_report(summary: dict, outdir: str | None = None) -> str:
    """A short text report in the layout of the thesis Appendix 2.

    A figure that was not computed (``null`` in summary.json: sds with ``--precision
    none``, a control sd from one point) is written as ``-``.
    """
    s = summary
    n = format_number

    def enh(d: dict, digits: int = 3) -> str:
        return "  ".join(f"{k} {n(d.get(k), digits)}" for k in "ENh")

    lines = [
        f"Bundle adjustment: survey {s.get('survey', '?')}, control set {s.get('control_set', '?')}, "
        f"{s.get('observations', '?')} photo coordinates",
        f"{s['message']} ({n(s.get('elapsed_s'), 2)} s)",
        f"{s['n_photos']} photos, {s['n_points']} points, {s['n_observations']} observations, "
        f"{s['n_unknowns']} unknowns, {s['n_constraints']} constraints",
        "",
        "RMS image residuals (mm)       photo       x        y",
    ]
    for photo, v in s["rms_image_residuals_mm"].items():
        lines.append(f"{'':31}{photo:>5}  {n(v.get('x'), 4):>7}  {n(v.get('y'), 4):>7}")
    con = s.get("sd_control_residuals_m") or {}
    if con:
        lines.append(f"Control residuals sd (m)       {enh(con)}")
    free = s.get("mean_sd_free_m") or {}
    if free:
        lines.append(f"Mean sd of free points (m)     {enh(free)}")
    rms = s.get("rms_sd_points_m") or {}
    if rms:
        lines.append(f"RMS sd of all points (m)       {enh(rms)}"
                     "  (Appendix 2 'pontos livres')")
    lines += [
        f"Variance factor a priori       {n(s.get('sigma0_sq_a_priori'), 2)}",
        f"Variance factor a posteriori   {n(s.get('sigma0_sq'), 2)}",
        f"Degrees of freedom             {n(s.get('dof'))}",
        f"Chi-square computed (v'Pv)     {n(s.get('vtpv'), 2)}",
        f"Chi-square range ({100 * s['chi2_level']:g}%)         {n(s.get('chi2_lower'), 2)} - "
        f"{n(s.get('chi2_upper'), 2)}  (Fisher approx. {n(s.get('chi2_lower_fisher'), 2)} - "
        f"{n(s.get('chi2_upper_fisher'), 2)}): " + ("accepted" if s["chi2_pass"] else "REJECTED"),
        f"Parameter sds use the {s['variance_factor'].replace('_', ' ')} variance factor",
    ]
    lines += format_components(s)
    lines += format_blunders(s)
    if outdir is not None:
        lines.append(f"Results: {outdir}/eop.csv, points.csv, residuals.csv, summary.json"
                     + (", check_covariance.csv" if (Path(outdir) / "check_covariance.csv").is_file() else ""))
    return "\n".join(lines)


#: blunders listed in the text report (all of them are in blunders.csv and --json)
MAX_LISTED = 20


def format_blunders(summary: dict) -> list[str]:
    """Lines of the data-snooping result (empty when snooping was off)."""
    sn = summary.get("snooping") or {}
    if not sn or sn.get("mode") == "off":
        return []
    blunders = summary.get("blunders") or []
    crit = ", ".join(f"{format_number(v, 2)} (q={k})" for k, v in (sn.get("critical_w") or {}).items())
    fam = (f"family-wise {sn['family_level']:g} over {sn.get('family_tests')} tests, "
           if sn.get("family_level") else "")
    lines = ["", f"Data snooping ({sn['mode']}, {fam}alpha {_sig(sn.get('level'), 3)}, power "
                 f"{format_number(sn.get('power'), None)}; critical w {crit}): "
                 + (f"{len(blunders)} blunder(s)" if blunders else "no blunder found")]
    for b in blunders[:MAX_LISTED]:
        what = (f"image  photo {b['photo']} point {b['point']}" if b["kind"] == "image" else
                f"control point {b['point']}" if b["kind"] == "control" else f"eo     photo {b['photo']}")
        err = ", ".join(f"{k} {v:+.4g}" for k, v in b["estimated_error"].items()
                        if isinstance(v, (int, float)) and v == v)
        lines.append(f"  {what:<28} w {format_number(b.get('w'), 2):>6}  r {format_number(b.get('redundancy'), 2)}"
                     f"  error {err} {b['unit']}"
                     f"  {'removed' if b['removed'] else 'KEPT'}" + (f"  ({b['note']})" if b.get("note") else ""))
    if len(blunders) > MAX_LISTED:
        lines.append(f"  ... {len(blunders) - MAX_LISTED} more in blunders.csv")
    return lines


def format_components(summary: dict) -> list[str]:
    """Lines of the variance components (empty without --variance-components)."""
    vc = summary.get("variance_components")
    if not vc:
        return []
    lines = ["", f"Variance components ({vc['rounds']} round(s), "
                 + ("converged" if vc["converged"] else "NOT converged") + "):  group  n  redundancy  sigma0 (last "
                 "round)  sd factor applied"]
    for g in vc["groups"]:
        lines.append(f"  {g['group']:<8} {g['n']:>7}  {format_number(g['redundancy'], 1):>9}  "
                     f"{format_number(g['sigma0'], 3):>6}  "
                     + (f"{format_number(g['sd_scale'], 3)}" if g["estimated"] else "1 (not estimated: redundancy "
                        f"< {format_number(_min_redundancy(vc, g['group']), None)})"))
    return lines


def _min_redundancy(vc: dict, group: str) -> float:
    """The redundancy a group needs to be estimated (summary.json ``variance_components``)."""
    if group in ("gnss", "imu"):
        return vc.get("min_datum_redundancy") or vc["min_redundancy"]
    return vc["min_redundancy"]


def _sig(value: object, digits: int) -> str:
    """*value* with *digits* significant digits; None or a non-finite number as ``-``."""
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return f"{value:.{digits}g}"
    return format_number(None)


def exit_status(summary: dict) -> tuple[int, str]:
    """Exit code and the one-line verdict: 1 not converged, 3 global test rejected.

    Blunders that remain (data snooping in ``report`` mode keeps them) are named in the
    verdict with exit code 0 when the global test passes: the code of ``lidarcat run`` for
    the same block (issue 25: the quick-start block exited 3 here and 0 there).
    """
    if not summary["converged"]:
        return 1, (f"the adjustment did not converge ({summary['status']}): {summary.get('message', '')}; "
                   "the tables hold its last iterate (eop.csv, points.csv and residuals.csv agree)")
    problems = []
    if not summary["chi2_pass"]:
        problems.append("the global chi-square test of the variance factor REJECTED")
    sn = summary.get("snooping") or {}
    if sn.get("blunders_remain"):
        kept = sum(not b["removed"] for b in summary.get("blunders") or [])
        problems.append(f"{kept} blunder(s) remain in the adjustment" if kept else
                        "data snooping stopped with tests still rejecting")
    return (3 if not summary["chi2_pass"] else 0), "; ".join(problems)


@click.command(short_help="Bundle adjustment with weighted position constraints.")
@survey_arg
@click.option("--control", metavar="NAME", default=None,
              help="Control set of control_sets.csv (default: the survey's default_control, "
                   "'gps' for the thesis block).")
@click.option("--observations", type=click.Choice(["corrected", "pixel"]), default=None,
              help="Photo coordinates: 'corrected' (x_mm, y_mm of image_points.csv) or 'pixel' "
                   "(col_px, row_px through the interior orientation, eq. 01-07). "
                   "Default: the survey's setting.")
@output_option(outdir=True, type=click.Path(file_okay=False), default=None,
              help="Output folder (default SURVEY/out, or ./lidarcat-out for the embedded block); "
                   "written atomically.")
@click.option("--variance-factor", type=click.Choice(["a_priori", "a_posteriori"]), default=None,
              help="Scale N^-1 by sigma0^2 a priori (=1, as the thesis tables) or a posteriori "
                   "(v'Pv/dof). Default: the survey's setting.")
@click.option("--eo-constraints", is_flag=True,
              help="Use photo positions/attitudes of photos.csv that carry sd_* as weighted constraints.")
@click.option("--max-iter", type=click.IntRange(1), default=50, show_default=True,
              help="Maximum number of Gauss-Newton / Levenberg-Marquardt iterations.")
@click.option("--precision", type=click.Choice(["all", "photos", "none"]), default="all", show_default=True,
              help="Standard deviations to compute: of every photo and point ('all'), of the photos only "
                   "('photos': point sd_* empty), or none (fastest on blocks of thousands of photos; "
                   "no check_covariance.csv).")
@click.option("--snooping", type=click.Choice(["off", "report", "remove"]), default=None,
              help="Baarda's data snooping: test every image observation, control point and GNSS/INS "
                   "constraint (w-test) at the --family-level; one rejection per re-adjustment, or several when "
                   "they are far apart (no shared or neighbouring photo). 'report' names the blunders and keeps "
                   "them in the adjustment; 'remove' adjusts without them. Default 'report'; 'remove' on a "
                   "matched survey (image observations with sds of their own, see --variance-components). With "
                   "--self-calibrate/--frame-offset the tests are made in the adjustment without the parameters, "
                   "which are then estimated from the observations kept (default there: off, 'remove' on a "
                   "matched survey).")
@click.option("--family-level", type=click.FloatRange(0, 0.5, min_open=True, max_open=True),
              default=0.05, show_default=True,
              help="Probability that a block without blunders has any test rejecting: the level of each "
                   "test follows from the number of tests (Sidak over the B-method levels), so a clean "
                   "block of any size ends with about this many false alarms. On the thesis block "
                   "(159 tests) this is alpha 1.0e-4 per 1-D test, critical w 4.00 for an image point.")
@click.option("--snooping-level", type=click.FloatRange(1e-12, 0.5, min_open=True, max_open=True),
              default=None,
              help="Fix the alpha of the one-dimensional w-test instead (power 0.80; 2-D and 3-D tests use "
                   "the B-method levels with the same power); e.g. 0.001, critical w 3.29. Each test then "
                   "rejects a good observation with about this probability: n x alpha false alarms.")
@click.option("--robust", type=click.Choice(["none", "danish", "huber"]), default="none", show_default=True,
              help="Iteratively re-weighted least squares before snooping. Measured: plain snooping (several "
                   "separate rejections per round) names more of the blunders of a large block in about the "
                   "same time, and more on small blocks; see docs/reliability.md.")
@click.option("--start", type=click.Choice(["robust", "plain"]), default="robust", show_default=True,
              help="With --snooping report/remove: 'robust' screens the tie points by their intersection "
                   "geometry at the approximate orientation and re-weights with a graduated Cauchy loss before "
                   "any least-squares step (automatic matches with gross errors); the observations it rejects "
                   "are named in blunders.csv (found_by screening/cauchy) and put back when they pass at the "
                   "solution. 'plain': least squares from the start.")
@click.option("--variance-components/--no-variance-components", default=None,
              help="Estimate one variance factor per observation group -- tie-point and target image "
                   "coordinates, control coordinates, GNSS positions, IMU attitudes -- from the block (Förstner, "
                   "iterated with data snooping in every round, each factor from the adjustment without the "
                   "observations snooping named) and adjust with them: for image sds that do not fit the "
                   "measurements (automatic tie points are more precise than hand-measured targets; the "
                   "simplified camera of real frames makes them less). Default: on when image_points.csv "
                   "carries sds of its own (sd_x_mm, sd_y_mm: what `lidarcat match` writes) and the survey is "
                   "no rig block -- the rule of `lidarcat run` -- with --snooping remove; off otherwise. With "
                   "--self-calibrate/--frame-offset the factors are estimated without the parameters and the "
                   "adjustment with them uses the sds times the factors. summary.json lists each group's "
                   "sigma0, factor and redundancy.")
@click.option("--self-calibrate", metavar="PARAMS", default=None,
              help="Estimate interior-orientation corrections per camera: a comma list of c, x0, y0, "
                   "k1, k2, k3, p1, p2 (or 'all'), weighted by the sd_* of camera.toml (no sd: free), "
                   "and/or a named set: thesis (those eight), brown (+ k4, affinity b1, shear b2), "
                   "ebner (12 orthogonal polynomials), gruen (44), e.g. 'ebner' or 'c,x0,y0,ebner'. "
                   "Each gets estimate, sd, t-test "
                   "and its largest correlations; a warning names a parameter the block cannot "
                   "determine (|r| > 0.95), its partner and why.")
@click.option("--frame-offset", metavar="SOURCE:REFERENCE", default=None,
              help="Estimate the 3-D shift to add to the control of ground-point source SOURCE to put it "
                   "in the frame of REFERENCE (e.g. lidar:gps with --control gps+lidar), with its sd and "
                   "a joint chi-square test.")
@click.option("--similarity", is_flag=True, default=None,
              help="With --frame-offset: a 7-parameter similarity (shift, scale ppm, rotations urad).")
@json_opt
def adjust(survey: str | None, control: str | None, observations: str | None, outdir: str | None,
           variance_factor: str | None, eo_constraints: bool, max_iter: int, precision: str, snooping: str | None,
           family_level: float, snooping_level: float | None, robust: str, start: str,
           variance_components: bool | None,
           self_calibrate: str | None,
           frame_offset: str | None, similarity: bool | None, as_json: bool) -> None:
    """Bundle adjustment of SURVEY (default: the embedded thesis block).

    Unknowns: X0, Y0, Z0 (m) and omega, phi, kappa (deg; M = R3(kappa) R2(phi)
    R1(omega)) of every photo and E, N, h (m) of every point. Control points of
    the chosen set are weighted position constraints with their sigmas; check
    points and tie points are free. Approximate values are computed from the
    control points and the image measurements.

    Writes OUTDIR/eop.csv, points.csv (role control/check/tie), residuals.csv
    (adjusted minus observed), check_covariance.csv (joint covariance of the
    check points, m^2, for the consistency test of `lidarcat assess`) and
    summary.json (dof, v'Pv, sigma0^2, the two-sided chi-square test of the
    variance factor, iterations, blunders, provenance: lidarcat version, SHA-256
    of every survey file read, parameters). With --snooping report|remove also
    blunders.csv (w, redundancy number, estimated error of every blunder) and
    reliability.csv (redundancy number, w-test, minimal detectable bias and its
    effect on the orientations for every observation).

    \b
    Exit codes:
      0  converged, global test accepted (blunders that remain --
         --snooping report, or one that could not be removed -- are
         named on the last line, as lidarcat run names them)
      1  the adjustment did not converge (the tables hold its last iterate: eop.csv,
         points.csv and residuals.csv of the same state; the message names the
         observations it fails on)
      2  bad input (the error names the file, line or point)
      3  converged, but the global chi-square test rejected

    \b
    Examples:
      lidarcat adjust --control gps -o out/gps
      lidarcat adjust data/thesis --control lidar --observations pixel -o out/lidar
      lidarcat adjust my_survey --json
      lidarcat adjust big_block --precision photos
      lidarcat adjust big_block --snooping remove
      lidarcat adjust my_survey --family-level 0.01
      lidarcat adjust --control gps+lidar --frame-offset lidar:gps --self-calibrate c,x0,y0,k1

    With --self-calibrate / --frame-offset (or a [self_calibration] table in
    survey.toml) summary.json gains additional_parameters, frame_offset,
    parameter_groups, parameters_off/parameters_on (v'Pv without and with them)
    and warnings; a control set 'a+b' joins two sets of control_sets.csv. With
    parameters, data snooping and the variance components run on the adjustment
    without them, in the same command, and the parameters are estimated from the
    observations kept (on a matched survey by default: `lidarcat adjust S
    --eo-constraints --self-calibrate thesis`); --robust is refused (exit 2).
    """
    from .._util import atomic_dir
    from ..stages.adjust import adjust as adjust_action
    from ..stages.adjust import auto_variance_components
    from ..survey.selfcal import (
        ROBUST_WITH_PARAMETERS,
        adjust_survey_with_parameters,
        format_parameters,
        wants_parameters,
    )
    from ..survey.folder import Survey

    loaded = Survey.load(survey)  # once, for both paths
    with_parameters = wants_parameters(loaded, self_calibrate, frame_offset)
    if with_parameters and robust != "none":
        raise click.UsageError(f"--robust {robust}: {ROBUST_WITH_PARAMETERS}")
    auto = variance_components is None and auto_variance_components(loaded)
    if variance_components is None:     # the rule of `lidarcat run`: a matched survey
        variance_components = auto
    if snooping is None:
        snooping = "remove" if auto else ("off" if with_parameters else "report")
    if with_parameters:
        with progress_bar(max_iter, "Adjusting (iterations)", enabled=not as_json and snooping != "off") as bar:
            _, out = adjust_survey_with_parameters(
                loaded, control=control, self_calibrate=self_calibrate, frame_offset=frame_offset,
                similarity=similarity, observations=observations, outdir=outdir,
                variance_factor=variance_factor, eo_constraints=eo_constraints, max_iter=max_iter,
                precision=precision, snooping=snooping, snooping_level=snooping_level,
                family_level=family_level, start=start, variance_components=variance_components,
                progress=None if bar is None else lambda _it, _cost: bar.update(1))
    else:
        # one tick per Levenberg-Marquardt iteration (re-adjustments of the snooping included)
        with progress_bar(max_iter, "Adjusting (iterations)", enabled=not as_json) as bar:
            out = loaded.output_dir(outdir)
            with atomic_dir(out) as tmp:  # the folder appears when every file is written
                adjust_action(loaded, tmp, control=control, observations=observations,
                              variance_factor=variance_factor, eo_constraints=eo_constraints, max_iter=max_iter,
                              snooping=snooping, snooping_level=snooping_level,
                              family_level=family_level, robust=robust, start=start, precision=precision,
                              variance_components=variance_components,
                              progress=None if bar is None else lambda _it, _cost: bar.update(1))
    # what was written is what is shown
    summary = {**json.loads((Path(out) / "summary.json").read_text(encoding="utf-8")), "outdir": str(out)}
    code, verdict = exit_status(summary)
    if as_json:
        echo_json(summary)
    else:
        click.echo(format_report(summary, str(out)))
        if "additional_parameters" in summary:
            click.echo(format_parameters(summary))
        if auto:
            click.echo("Note: image_points.csv carries sds of its own (matched tie points): variance components "
                       "estimated" + (" and the named observations removed" if snooping == "remove" else "")
                       + " (--no-variance-components, --snooping report to change).")
        if (summary.get("snooping") or {}).get("reason"):
            click.echo(f"Note: {summary['snooping']['reason']}.")
        for gone in (summary.get("line_control") or {}).get("removed", ()):
            click.echo(f"Line snooping removed line {gone['line']} on photo {gone['photo']} "
                       f"(w {gone['w']:.2f} > {gone['w_critical']:.2f}; line_residuals.csv).")
    if verdict:
        click.echo(f"Warning: {verdict}.", err=True)
    if code:
        sys.exit(code)
