"""``lidarcat measure-control``: LiDAR roof vertices measured in the photos into the survey's image_points.csv."""

from __future__ import annotations

import click

from .options import POSITIVE, echo_json, json_option, output_option, progress_bar

__all__ = ["measure_control"]

_EPILOG = """\b
Examples:
  lidarcat measure-control survey/
  lidarcat measure-control survey/ --points L001,L002 --replace
  lidarcat measure-control survey/ --decisions survey/out/measure_control/decisions.csv \\
      --line-decisions survey/out/measure_control/line_decisions.csv
\b
Every LiDAR control vertex (ground point of source lidar) is extracted again from the
survey's tiles, predicted in every photo with its ellipse from the approximate orientation
(photos.csv sds) and the vertex's covariance, tested for visibility on the LiDAR DSM, and
measured: a template of its roof faces gives the shift, the roof edges fitted in the photo
meet in the vertex. Measurements that disagree (within a photo, with the block and its tie
points: --block-check, across photos) are rejected. A second pass (--second-pass) then
predicts the pairs lost at the frame or to the edges again from the block test's adjusted
orientation and measures them with --border fit. OUTDIR (default
SURVEY/out/measure_control) gets decisions.csv (one row per vertex and photo, with status,
reason and an editable decision accept/reject), gallery_NN.png (chips: prediction ellipse
yellow, edges green, measurement red) and measure_control.json; the accepted observations
go into image_points.csv last (pixels with their sds). Roof edges fitted in the photos go to
line_control.csv as line control (--lines; line_decisions.csv says per edge and photo why
one was not written; line_candidates.csv holds the 3-D line of each edge); survey.toml gets
[files] line_control when it has none.
\b
Review: edit decision (accept/reject, and the pixels if need be) in decisions.csv and/or
line_decisions.csv and pass them back with --decisions and/or --line-decisions: nothing is
measured, the rows of the pairs each file lists are replaced by its accepted rows (points
into image_points.csv, edges into line_control.csv with their 3-D line from
line_candidates.csv beside line_decisions.csv; keep the two together). A vertex's point and
its edges on one photo come from the same fits: accept one or the other, not both. Each
row fed back is recorded in the survey's control_decisions.csv ([files] control_decisions):
a later measure-control or `lidarcat run` never measures a rejected pair again (its row says
"rejected by the user (control_decisions.csv:LINE)"), an accepted one only with --replace.
\b
Exit status: 0 done, 2 bad input (no LiDAR vertex, no tiles, no orientation, a bad row of
a decisions file, a survey that would not load with the new tables); image_points.csv,
line_control.csv, control_decisions.csv and survey.toml are left as they were then.
"""


@click.command(name="measure-control", epilog=_EPILOG)
@click.argument("survey", type=click.Path(exists=True, file_okay=False))
@click.option("--points", default=None, metavar="ID,ID",
              help="Measure these ground points (default: every ground point of source lidar).")
@click.option("--decisions", type=click.Path(exists=True, dir_okay=False), default=None,
              help="An edited decisions.csv: write its accepted rows to image_points.csv, measure nothing.")
@click.option("--line-decisions", type=click.Path(exists=True, dir_okay=False), default=None,
              help="An edited line_decisions.csv (line_candidates.csv beside it): write its accepted rows to "
                   "line_control.csv, measure nothing. With --decisions or alone.")
@click.option("--replace", is_flag=True, help="Measure again (and replace) vertex/photo pairs already observed or "
                                                "accepted by the user; never those the user rejected.")
@click.option("--no-gallery", is_flag=True, help="Do not write the PNG chips.")
@click.option("--lines", "lines", type=click.Choice(["add", "only", "none"]), default="add", show_default=True,
              help="Roof edges as line control (line_control.csv): add = the edges of photos where the vertex's "
                   "point was not measured; only = every photo's edges, no points; none.")
@click.option("--block-check/--no-block-check", default=True, show_default=True,
              help="Test the measurements in one bundle adjustment with the survey's tie points (a measurement "
                   "alone on its photo is tested through them).")
@click.option("--lone-photo", type=click.Choice(["keep", "reject"]), default="keep", show_default=True,
              help="A measurement alone on its photo (the per-photo test cannot test it): keep it for the block "
                   "test, or reject it.")
@click.option("--second-pass/--no-second-pass", default=True, show_default=True,
              help="After the block test, predict the pairs lost at the frame or to the edges again from the block's "
                   "adjusted orientation (a far tighter ellipse) and measure them with --border fit; the new "
                   "measurements go through the same tests (decisions.csv: pass 2). Needs --block-check and tie "
                   "points.")
@click.option("--border", type=click.Choice(["edges", "fit"]), default="edges", show_default=True,
              help="A vertex near the photo's border: edges = near_border when its roof edges reach past the "
                   "border; fit = predicted outside only when its search ellipse misses the frame, searched and "
                   "its edges fitted on the part inside (near_border within 8 px of the border).")
@click.option("--search-sigma", type=POSITIVE, default=3.5, show_default=True,
              help="Search the vertex within this many sigmas of its predicted ellipse.")
@click.option("--max-shift", "max_shift_m", type=POSITIVE, default=0.5, show_default=True,
              help="Skip a vertex extracted again farther than this from its ground point, m.")
@output_option(outdir=True, type=click.Path(file_okay=False),
               help="Report folder (default SURVEY/out/measure_control).")
@json_option(help="Print the counts as JSON.")
def measure_control(survey, points, decisions, line_decisions, replace, no_gallery, lines, block_check, lone_photo,
                    second_pass, border, search_sigma, max_shift_m, outdir, as_json) -> None:
    """LiDAR roof vertices found and measured in the photos, into image_points.csv."""
    from ..photocontrol import MeasureParams
    from ..stages.measure_control import measure_control as action

    ids = [p.strip() for p in points.split(",") if p.strip()] if points else None
    with progress_bar(1, "Measuring LiDAR control", enabled=not as_json) as bar:
        def progress(done: int, total: int) -> None:
            if bar is not None:
                bar.length = total
                bar.update(done - bar.pos)

        res = action(survey, outdir, points=ids, decisions=decisions, line_decisions=line_decisions, replace=replace,
                     gallery=not no_gallery, params=MeasureParams(search_sigma=search_sigma, border=border), max_shift_m=max_shift_m,
                     lines=lines, block_check=block_check, lone_photo=lone_photo, second_pass=second_pass,
                     progress=progress)
    if as_json:
        echo_json({**res.to_dict(), "summary": res.summary})
        return
    if decisions is not None or line_decisions is not None:
        if decisions is not None:
            click.echo(f"{res.accepted} control observations accepted -> {res.image_points}")
        if res.line_control is not None:
            click.echo(f"{res.lines_written} roof-edge line observations accepted -> {res.line_control}")
        if "control_decisions" in res.summary:
            click.echo(f"the review recorded -> {res.summary['control_decisions']} "
                       f"({res.summary['control_decision_rows']} decisions)")
        return
    counts = ", ".join(f"{v} {k}" for k, v in sorted(res.counts.items()))
    click.echo(f"{res.accepted} control observations accepted ({counts})")
    click.echo(f"-> {res.image_points}; decisions and gallery in {res.outdir}")
    if res.line_control is not None:
        click.echo(f"{res.lines_written} roof-edge line observations -> {res.line_control}")
