"""``lidarcat adjust``: bundle adjustment of a survey (thesis section 2.1.2)."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from .options import echo_json, json_opt, survey_arg

__all__ = ["adjust", "format_report"]


def format_report(summary: dict, outdir: str | None = None) -> str:
    """A short text report in the layout of the thesis Appendix 2."""
    s = summary
    lines = [
        f"Bundle adjustment: survey {s.get('survey', '?')}, control set {s.get('control_set', '?')}, "
        f"{s.get('observations', '?')} photo coordinates",
        f"{s['message']} ({s['elapsed_s']:.2f} s)",
        f"{s['n_photos']} photos, {s['n_points']} points, {s['n_observations']} observations, "
        f"{s['n_unknowns']} unknowns, {s['n_constraints']} constraints",
        "",
        "RMS image residuals (mm)       photo       x        y",
    ]
    for photo, v in s["rms_image_residuals_mm"].items():
        lines.append(f"{'':31}{photo:>5}  {v['x']:7.4f}  {v['y']:7.4f}")
    con = s.get("sd_control_residuals_m") or {}
    if con:
        lines.append(f"Control residuals sd (m)       E {con['E']:.3f}  N {con['N']:.3f}  h {con['h']:.3f}")
    free = s.get("mean_sd_free_m") or {}
    if free:
        lines.append(f"Mean sd of free points (m)     E {free['E']:.3f}  N {free['N']:.3f}  h {free['h']:.3f}")
    rms = s.get("rms_sd_points_m") or {}
    if rms:
        lines.append(f"RMS sd of all points (m)       E {rms['E']:.3f}  N {rms['N']:.3f}  h {rms['h']:.3f}"
                     "  (Appendix 2 'pontos livres')")
    lines += [
        f"Variance factor a priori       {s['sigma0_sq_a_priori']:.2f}",
        f"Variance factor a posteriori   {s['sigma0_sq']:.2f}",
        f"Degrees of freedom             {s['dof']}",
        f"Chi-square computed (v'Pv)     {s['vtpv']:.2f}",
        f"Chi-square range ({100 * s['chi2_level']:g}%)         {s['chi2_lower']:.2f} - {s['chi2_upper']:.2f}"
        f"  (Fisher approx. {s['chi2_lower_fisher']:.2f} - {s['chi2_upper_fisher']:.2f}): "
        + ("accepted" if s["chi2_pass"] else "REJECTED"),
        f"Parameter sds use the {s['variance_factor'].replace('_', ' ')} variance factor",
    ]
    if outdir is not None:
        lines.append(f"Results: {outdir}/eop.csv, points.csv, residuals.csv, summary.json"
                     + (", check_covariance.csv" if (Path(outdir) / "check_covariance.csv").is_file() else ""))
    return "\n".join(lines)


@click.command(short_help="Bundle adjustment with weighted position constraints.")
@survey_arg
@click.option("--control", metavar="NAME", default=None,
              help="Control set of control_sets.csv (default: the survey's default_control, "
                   "'gps' for the thesis block).")
@click.option("--observations", type=click.Choice(["corrected", "pixel"]), default=None,
              help="Photo coordinates: 'corrected' (x_mm, y_mm of image_points.csv) or 'pixel' "
                   "(col_px, row_px through the interior orientation, eq. 01-07). "
                   "Default: the survey's setting.")
@click.option("-o", "--outdir", type=click.Path(file_okay=False), default=None,
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
@click.option("--self-calibrate", metavar="PARAMS", default=None,
              help="Estimate interior-orientation corrections per camera: a comma list of c, x0, y0, "
                   "k1, k2, k3, p1, p2 (or 'all'), weighted by the sd_* of camera.toml (no sd: free). "
                   "Each gets estimate, sd, t-test and its largest correlations; a warning names a "
                   "parameter the block cannot determine (|r| > 0.95).")
@click.option("--frame-offset", metavar="SOURCE:REFERENCE", default=None,
              help="Estimate the 3-D shift to add to the control of ground-point source SOURCE to put it "
                   "in the frame of REFERENCE (e.g. lidar:gps with --control gps+lidar), with its sd and "
                   "a joint chi-square test.")
@click.option("--similarity", is_flag=True, default=None,
              help="With --frame-offset: a 7-parameter similarity (shift, scale ppm, rotations urad).")
@json_opt
def adjust(survey: str | None, control: str | None, observations: str | None, outdir: str | None,
           variance_factor: str | None, eo_constraints: bool, max_iter: int, precision: str,
           self_calibrate: str | None, frame_offset: str | None, similarity: bool | None,
           as_json: bool) -> None:
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
    variance factor, iterations). Exit code 1
    when the adjustment did not converge (results are still written).

    \b
    Examples:
      lidarcat adjust --control gps -o out/gps
      lidarcat adjust data/thesis --control lidar --observations pixel -o out/lidar
      lidarcat adjust my_survey --json
      lidarcat adjust big_block --precision photos
      lidarcat adjust --control gps+lidar --frame-offset lidar:gps --self-calibrate c,x0,y0,k1

    With --self-calibrate / --frame-offset (or a [self_calibration] table in
    survey.toml) summary.json gains additional_parameters, frame_offset,
    parameter_groups, parameters_off/parameters_on (v'Pv without and with them)
    and warnings; a control set 'a+b' joins two sets of control_sets.csv.
    """
    from ..bundle import adjust_survey
    from ..bundle.selfcal_survey import adjust_survey_with_parameters, format_parameters, wants_parameters
    from ..survey import Survey

    loaded = Survey.load(survey)  # once, for both paths
    if wants_parameters(loaded, self_calibrate, frame_offset):
        sc, out = adjust_survey_with_parameters(
            loaded, control=control, self_calibrate=self_calibrate, frame_offset=frame_offset,
            similarity=similarity, observations=observations, outdir=outdir,
            variance_factor=variance_factor, eo_constraints=eo_constraints, max_iter=max_iter,
            precision=precision)
        result = sc.bundle
        summary = {**result.summary(), **sc.summary(), "outdir": str(out)}
    else:
        result, out = adjust_survey(loaded, control=control, observations=observations, outdir=outdir,
                                    variance_factor=variance_factor, eo_constraints=eo_constraints,
                                    max_iter=max_iter, precision=precision)
        summary = {**result.summary(), "outdir": str(out)}
    if as_json:
        echo_json(summary)
    else:
        click.echo(format_report(summary, str(out)))
        if "additional_parameters" in summary:
            click.echo(format_parameters(summary))
    if not result.success:
        click.echo(f"Warning: the adjustment did not converge ({result.status}).", err=True)
        sys.exit(1)
