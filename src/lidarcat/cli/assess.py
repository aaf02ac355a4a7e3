"""``lidarcat assess``: check-point accuracy, statistical tests, standards, report."""

from __future__ import annotations

from pathlib import Path

import click

from .._util.formatting import format_number
from ..survey.folder import DEFAULT_CONTOUR_INTERVAL_M, DEFAULT_SCALE
from .options import echo_json, json_opt, output_option

__all__ = ["assess"]

_STANDARDS = ("pec", "pec-pcd", "asprs2014", "asprs2023", "nssda")


def _split(values: tuple[str, ...]) -> list[str] | None:
    out = [v.strip() for val in values for v in val.split(",") if v.strip()]
    return out or None


@click.command(short_help="Check-point accuracy: Filliben, t, chi-square, PEC, ASPRS, NSSDA.")
@click.argument("adjusted", metavar="ADJUSTED_POINTS", type=click.Path(exists=True))
@click.argument("reference", metavar="REFERENCE", type=click.Path(exists=True))
@click.option("--points", "points", multiple=True, metavar="ID[,ID...]",
              help="Check points to assess (repeat or comma-separate). Default: role=check points of "
                   "ADJUSTED_POINTS, else every reference point that is not a control point.")
@click.option("--scale", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_SCALE,
              help=f"Map scale denominator for PEC / PEC-PCD, the chi-square sigma0 and the CE90 limit. "
                   f"Default: {DEFAULT_SCALE:g} (the thesis's 1:{DEFAULT_SCALE:g}; the same default as "
                   "`lidarcat run` and survey.toml [assessment]).")
@click.option("--contour-interval", "contour_interval", type=click.FloatRange(min=0, min_open=True),
              default=DEFAULT_CONTOUR_INTERVAL_M, metavar="METRES",
              help=f"Contour interval Eq (m) for the altimetric PEC classes. Default: "
                   f"{DEFAULT_CONTOUR_INTERVAL_M:g} m (the thesis's; the same default as `lidarcat run` and "
                   "survey.toml [assessment]).")
@click.option("--standard", "standards", multiple=True, type=click.Choice(_STANDARDS, case_sensitive=False),
              help="Standard(s) to classify by (repeatable). Default: all.")
@click.option("--alpha", type=float, default=0.10, show_default=True, help="Level of every test.")
@click.option("--plotting-position", type=click.Choice(["filliben", "hazen", "blom"]), default="filliben",
              show_default=True, help="Filliben test positions; 'hazen' is the thesis's (i-0.5)/n.")
@click.option("--sign", type=click.Choice(["reference_minus_adjusted", "adjusted_minus_reference"]),
              default="reference_minus_adjusted", show_default=True,
              help="Discrepancy convention (the thesis: reference minus adjusted).")
@click.option("--pec-class", default="A", show_default=True,
              help="Decreto class whose EP is the chi-square sigma0 and whose PEC limits CE90.")
@click.option("--adjustment", "adjustment_dir", type=click.Path(exists=True, file_okay=False), default=None,
              help="Adjustment output folder (eop.csv, points.csv, summary.json) for the report. "
                   "Default: the folder of ADJUSTED_POINTS when it holds eop.csv.")
@click.option("--covariance", "covariance", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Joint covariance of the adjusted check points (check_covariance.csv of `lidarcat "
                   "adjust`) for the consistency test d'C^-1 d ~ chi2(3n). Default: the file beside "
                   "ADJUSTED_POINTS when there is one.")
@click.option("--survey", "survey", type=click.Path(exists=True, file_okay=False), default=None,
              help="Survey folder (camera format for photo footprints in the report).")
@output_option(type=click.Path(), default=None,
              help="Write the report: NAME.html (+ .md, .json, NAME_figures/), or a folder (report.html, .md, "
                   ".json, report_figures/, and assessment.json and discrepancies.csv as `lidarcat run` writes "
                   "them).")
@json_opt
def assess(adjusted: str, reference: str, points: tuple[str, ...], scale: float, contour_interval: float,
           standards: tuple[str, ...], alpha: float, plotting_position: str, sign: str, pec_class: str,
           adjustment_dir: str | None, covariance: str | None, survey: str | None, output: str | None,
           as_json: bool) -> None:
    """Compare adjusted coordinates with reference check points (thesis 3.3.4).

    ADJUSTED_POINTS is a CSV with columns point, E, N, h (the points.csv of
    `lidarcat adjust`, or its output folder). REFERENCE is a CSV with the
    same columns (extra columns such as sd_E, sd_N, sd_h, source are allowed;
    a survey's ground_points.csv qualifies) or a survey folder. Metres.

    Prints the discrepancy summary (mean, sd, RMSE, max), the tests (Filliben,
    K-S and Lilliefors, t trend, chi-square precision, Hotelling T^2, CE90)
    with their verdicts, and the class by each standard.  With the joint
    covariance of the adjusted points (written by `lidarcat adjust` as
    check_covariance.csv), the consistency test asks whether the discrepancies
    agree with the precision the adjustment claims.

    \b
    Examples:
      lidarcat assess out/gps/points.csv data/thesis --scale 2000 --contour-interval 2
      lidarcat assess out/gps data/thesis/ground_points.csv --standard pec --json
      lidarcat assess adj.csv ref.csv --points 603,605,606 -o report.html
    """
    from ..stages.assess import assess as run_assess

    ref_path = Path(reference)
    if ref_path.is_dir():
        survey = survey or str(ref_path)
        ref_path = ref_path / "ground_points.csv"
    adj_path = Path(adjusted)
    if adjustment_dir is None and adj_path.is_dir() and (adj_path / "eop.csv").is_file():
        adjustment_dir = str(adj_path)
    elif adjustment_dir is None and adj_path.is_file() and (adj_path.parent / "eop.csv").is_file():
        adjustment_dir = str(adj_path.parent)
    adj_dir = adj_path if adj_path.is_dir() else adj_path.parent
    if covariance is None and (adj_dir / "check_covariance.csv").is_file():
        covariance = str(adj_dir / "check_covariance.csv")
    cov = None
    no_cov = None
    if covariance is None and adjustment_dir is not None:
        from ..survey import MAX_JOINT_COVARIANCE_POINTS

        no_cov = (f"consistency test (d'C^-1d) not run: {adj_dir / 'check_covariance.csv'} does not exist "
                  f"(lidarcat adjust writes it for 1 to {MAX_JOINT_COVARIANCE_POINTS} check points with "
                  "--precision all; lidarcat run computes the test in memory for any number of check points)")
    if covariance is not None:
        from ..survey import read_point_covariance

        cov = read_point_covariance(covariance)
    control_set = None
    if adjustment_dir is not None and (Path(adjustment_dir) / "summary.json").is_file():
        import json

        control_set = json.loads((Path(adjustment_dir) / "summary.json").read_text(encoding="utf-8")).get("control_set")
    a, paths = run_assess(adj_path, ref_path, output, points=_split(points), sign=sign, scale=scale,
                          contour_interval_m=contour_interval,
                          standards=tuple(s.lower() for s in standards) or _STANDARDS, alpha=alpha,
                          plotting_position=plotting_position, pec_class=pec_class, adjusted_cov=cov,
                          control_set=control_set, adjustment_dir=adjustment_dir, survey=survey,
                          title=f"lidarcat accuracy report: {adj_path.name} vs {ref_path.name}")
    if as_json:
        doc = a.to_dict()
        if no_cov:
            doc["consistency_not_run"] = no_cov
        if paths is not None:
            doc["report"] = {k: (str(v) if not isinstance(v, list) else [str(p) for p in v]) for k, v in paths.items()}
        echo_json(doc)
        return
    _print_text(a)
    if no_cov:
        click.echo(f"note: {no_cov}")
    if paths is not None:
        click.echo(f"report: {paths['html']} (+ {paths['markdown'].name}, {paths['json'].name})")


def _print_text(a) -> None:
    click.echo(f"{a.n} check points; discrepancies {a.settings['sign'].replace('_', ' ')} (m)")
    click.echo(f"{'':12s}{'mean':>9s}{'sd':>9s}{'RMSE':>9s}{'max|d|':>9s}")
    for comp in ("E", "N", "h", "planimetric"):
        s = a.summary[comp]
        click.echo(f"{comp:12s}" + "".join(f"{format_number(s[k]):>9s}" for k in ("mean", "std", "rmse", "max_abs")))
    click.echo(f"\ntests (alpha = {a.settings['alpha']:g}):")
    for tname, comps in a.tests.items():
        parts = []
        for comp, t in comps.items():
            if t.applicable:
                parts.append(f"{comp} {t.statistic_name}={format_number(t.statistic, 4)}"
                             f"{'' if t.critical is None else '/' + format_number(t.critical, 4)} {t.verdict}")
            else:
                parts.append(f"{comp} not applicable ({t.reason})")
        click.echo(f"  {tname:15s} " + "; ".join(parts))
    if a.standards:
        from ..accuracy.standards import CONFIDENCE_LABELS

        click.echo("\nstandards (confidence of the rules in brackets):")
        for name, s in a.standards.items():
            click.echo(f"  {name:10s} {s.label} [{s.confidence}]")
        click.echo("  confidence / tags like [K]: " + "; ".join(f"{k} {v}" for k, v in CONFIDENCE_LABELS.items())
                   + " (STANDARDS.md: docs/standards.md, installed as lidarcat/standards_data/STANDARDS.md)")
    for note in a.notes:
        click.echo(f"note: {note}")
