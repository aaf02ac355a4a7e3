"""``lidarcat match``: automatic tie points from the photos into the survey's image_points.csv."""

from __future__ import annotations

import click

from .options import NON_NEGATIVE, POSITIVE, echo_json, json_option, output_option, progress_bar

__all__ = ["match"]

_EPILOG = """\b
Examples:
  lidarcat match survey/
  lidarcat match survey/ --max-features 12000 --per-cell 20 --workers 2
  lidarcat match survey/ --workers 4 --scheduler processes
  lidarcat match survey/ --height 35 --sd-position 5 --sd-angle 1 --json
\b
Pairs come from the footprints of the approximate orientations of photos.csv on the LiDAR
DSM (the survey's tiles) or the mean ground height; without orientations every pair is
matched (small blocks only). Tie points go into image_points.csv as rows tpNNNNNN (col_px,
row_px; earlier tpNNNNNN rows are replaced, every other row is kept), provenance in
image_points.csv.json; the report (match_report.json, match_pairs.csv, match_photos.csv)
and the feature cache go to OUTDIR (default SURVEY/out/match).
\b
Exit status: 0 done, 2 bad input (a photo without image, an image that cannot be decoded
or has another size than its camera, no overlap, no pair verified); nothing is written then.
"""


def _scheduler(ctx: click.Context, param: click.Parameter, value: str) -> str:
    from ..lidar.jobs import SCHEDULERS

    if value in SCHEDULERS or "://" in value:
        return value
    raise click.BadParameter(f"{value!r}: one of {', '.join(SCHEDULERS)}, or a Dask scheduler's address "
                             f"(tcp://host:8786)", ctx=ctx, param=param)


@click.command(name="match", epilog=_EPILOG)
@click.argument("survey", type=click.Path(exists=True, file_okay=False))
@click.option("--max-features", type=click.IntRange(100), default=8000, show_default=True,
              help="SIFT keypoints kept per photo (strongest, spread over the frame).")
@click.option("--level", type=click.IntRange(0, 6), default=None,
              help="Pyramid level of the detection (0 = full resolution). Default: long side <= --max-side.")
@click.option("--max-side", "max_side_px", type=click.IntRange(256), default=4000, show_default=True,
              help="Long side of the detection image when --level is not given, px.")
@click.option("--min-overlap", type=click.FloatRange(0, 1, max_open=True), default=0.1, show_default=True,
              help="Footprint overlap of a matched pair (share of the smaller footprint).")
@click.option("--sd-position", "sd_position_m", type=POSITIVE, default=None,
              help="Sd of the approximate positions, m (guided search). Default: photos.csv sd_X0.., else 2.")
@click.option("--sd-angle", "sd_angle_deg", type=POSITIVE, default=None,
              help="Sd of the approximate attitudes, deg. Default: photos.csv sd_omega_deg.., else 0.5.")
@click.option("--height", "height_m", type=float, default=None,
              help="Mean ground height, m (no LiDAR tiles). Default: mean of the ground points.")
@click.option("--dem", type=click.Path(exists=True, dir_okay=False), default=None,
              help="DEM/DSM GeoTIFF (survey CRS) as the surface of footprints and guided search.")
@click.option("--height-sd", "height_sd_m", type=POSITIVE, default=None,
              help="Sd of the surface heights, m (relief a mean height does not model). Default: 2 with --dem, 10 "
                   "with --height.")
@click.option("--ratio", type=click.FloatRange(0, 1, min_open=True), default=0.8, show_default=True,
              help="Lowe's ratio test of the nearest / second nearest descriptor.")
@click.option("--threshold", "threshold_px", type=POSITIVE, default=0.5, show_default=True,
              help="Epipolar (Sampson) distance of an inlier, px of the detection level.")
@click.option("--per-cell", type=click.IntRange(0), default=10, show_default=True,
              help="Tie points kept per grid cell of each photo (0: all).")
@click.option("--grid", nargs=2, type=click.IntRange(1, 50), default=(6, 6), show_default=True,
              metavar="ROWS COLS", help="Distribution cells per photo (Von Gruber areas).")
@click.option("--local", "max_local_px", type=NON_NEGATIVE, default=3.0, show_default=True,
              help="Local consistency of the matches' shifts, px (0: off).")
@click.option("--unguided", is_flag=True, help="Match descriptors over the whole photo even with orientations.")
@click.option("--no-refine", is_flag=True, help="Keep the SIFT positions (no sub-pixel correlation refinement).")
@click.option("--prefix", default="tp", show_default=True, help="Id prefix of the tie points.")
@click.option("--workers", type=click.IntRange(1), default=1, show_default=True, metavar="N",
              help="Threads (or with --scheduler processes, Dask worker processes) for the photos and the pairs.")
@click.option("--scheduler", default="threads", show_default=True, metavar="threads|processes|synchronous|ADDRESS",
              callback=_scheduler,
              help="Where the photo and pair tasks run: threads of this process, a local Dask cluster of --workers "
                   "processes (pip install 'lidarcat[cluster]'), serially, or an existing Dask cluster, e.g. "
                   "tcp://10.0.0.5:8786 (every worker must see the images and OUTDIR). The tie points are the same.")
@click.option("--no-cache", is_flag=True, help="Do not keep the features in OUTDIR/features.")
@output_option(outdir=True, type=click.Path(file_okay=False), help="Report folder (default SURVEY/out/match).")
@json_option(help="Print the matching report as JSON.")
def match(survey, max_features, level, max_side_px, min_overlap, sd_position_m, sd_angle_deg, height_m, dem,
          height_sd_m, ratio,
          threshold_px, per_cell, grid, max_local_px, unguided, no_refine, prefix, workers, scheduler, no_cache, outdir,
          as_json) -> None:
    """Tie points from the photos (SIFT, footprint pairs, guided matching) into image_points.csv."""
    import contextlib
    import dataclasses

    from ..match import FeatureOptions, MatchOptions
    from ..stages.match import default_options
    from ..survey.folder import Survey

    s = Survey.load(survey)
    base = default_options(s)
    opts = dataclasses.replace(base, min_overlap=min_overlap, ratio=ratio, threshold_px=threshold_px,
                               per_cell=per_cell, grid=tuple(grid), max_local_px=max_local_px, guided=not unguided,
                               sd_position_m=sd_position_m or base.sd_position_m,
                               sd_angle_deg=sd_angle_deg or base.sd_angle_deg)
    assert isinstance(opts, MatchOptions)
    feats = FeatureOptions(max_features=max_features, level=level, max_side_px=max_side_px)
    from ..stages.match import match as match_action

    with contextlib.ExitStack() as bars:
        current: dict[str, object] = {}

        def progress(step: str, done: int, total: int) -> None:
            if current.get("step") != step:
                bars.close()
                current.update(step=step, bar=bars.enter_context(progress_bar(total, step, enabled=not as_json)))
            bar = current["bar"]
            if bar is not None:
                bar.update(done - bar.pos)

        res = match_action(s, outdir, options=opts, features=feats, workers=workers, scheduler=scheduler,
                           height_m=height_m, dem=dem, height_sd_m=height_sd_m,
                           prefix=prefix, cache=not no_cache, refine=not no_refine,
                           progress=progress)
    if as_json:
        echo_json(res.summary)
        return
    sm = res.summary
    click.echo(f"{sm['tie_points']} tie points, {sm['observations']} observations on {sm['photos']} photos; "
               f"{sm['pairs_verified']} of {sm['pairs']} pairs verified ({sm['pairing']}, surface: {sm['surface']})")
    rays = ", ".join(f"{v} with {k}" for k, v in sm["rays"].items())
    click.echo(f"rays: {rays}; inconsistent tracks dropped: {sm['inconsistent_tracks_dropped']}")
    skipped = [r["photo"] for r in sm["per_photo"] if r["tie_points"] == 0]
    if skipped:
        more = f" and {len(skipped) - 5} more" if len(skipped) > 5 else ""
        click.echo(f"no tie point on {len(skipped)} photo(s): {', '.join(skipped[:5])}{more} (no overlapping photo, "
                   f"no features, or no pair verified: see {res.outdir / 'match_pairs.csv'})")
    worst = min(sm["per_photo"], key=lambda r: r["tie_points"])
    click.echo(f"fewest on photo {worst['photo']}: {worst['tie_points']} tie points, "
               f"coverage {worst['coverage']:.0%}; seconds {sm['seconds']['total']:.1f}")
    click.echo(f"-> {res.image_points} ({sm['replaced_rows']} earlier rows replaced); report {res.outdir}")
