"""``lidarcat extract``: roof planes to control points."""

from __future__ import annotations

import sys

import click

from .options import (crs_option, echo_json, json_option, output_option, progress_bar, scheduler_option,
                      workers_option)

__all__ = ["extract"]

_EPILOG = """\b
Examples:
  lidarcat extract jobs.txt -o control.csv --planes planes.csv
  lidarcat extract --at 84886.0 447427.6 ahn3_1.laz ahn3_2.laz --crs EPSG:7415
  lidarcat extract jobs.txt --preset thesis --figures figs/
  lidarcat extract --lidar ahn3_1.laz --lidar ahn3_2.laz --crs EPSG:7415 --at 84886.0 447427.6 --json
  lidarcat extract --find --lidar ahn3_1.laz --classes 6 -o candidates.geojson
  lidarcat extract --find --lidar ahn3_1.laz ahn3_2.laz --classes 6 --workers 2 -o c.geojson
\b
A job line (thesis section 4.2.2): file point E N threshold radius, e.g.
  faixa.xyz P704 677757.8 7183482.0 0.15 5.0
or a CSV with columns point,E,N[,threshold_m,radius_m,file,sd_en_m,sd_h_m]
(sd_*: LiDAR point noise in plan / height, m; empty = the preset value).
Units: metres, degrees. A roof that cannot give a point is a row with a
status (two_planes, flat_roof, no_vertex, unstable, ...) and a reason; the batch goes on.
\b
Tiles: as in `lidarcat lidar clip`, point files (.las .laz .xyz .asc .pts)
may follow as arguments, or be given with --lidar (repeatable); both forms
work, so `--lidar A B` takes B as a tile too. A .txt/.csv argument is the
job file (with --at or --find, where there is no job file, it is a tile).
\b
Exit status: 0 when at least one roof gave a control point (or --find ran),
1 when no roof did (the rows with their reasons are still printed and
written), 2 for invalid input.
"""


_TILE_ONLY_SUFFIXES = (".las", ".laz", ".xyz", ".asc", ".pts")


def _split_arguments(args: tuple[str, ...], lidar: tuple[str, ...], job_mode: bool
                     ) -> tuple[str | None, list[str]]:
    """(job file, tiles) from the positional arguments: point files are tiles (the convention of
    ``lidarcat lidar clip``); one .txt/.csv is the job file unless there is none to give."""
    from pathlib import Path

    jobs: list[str] = []
    tiles = list(lidar)
    for a in args:
        if not Path(a).exists():
            raise click.BadParameter(f"{a!r}: no such file or folder", param_hint="ARGS")
        if Path(a).is_dir() or Path(a).suffix.lower() in _TILE_ONLY_SUFFIXES or not job_mode:
            tiles.append(a)
        else:
            jobs.append(a)
    if len(jobs) > 1:
        raise click.UsageError(f"one job file, got {len(jobs)}: {', '.join(jobs)}")
    return (jobs[0] if jobs else None), tiles


@click.command(name="extract", epilog=_EPILOG)
@click.argument("args", nargs=-1, metavar="[JOBS] [TILE...]")
@click.option("--lidar", "lidar", multiple=True, type=click.Path(exists=True),
              help="LiDAR tile(s) or folders (LAS/LAZ/text); repeat for several, or list the tiles as "
                   "arguments. Default: each job's own file.")
@crs_option(help="CRS of tiles that carry none, e.g. EPSG:7415 (AHN3).")
@click.option("--at", "at", nargs=2, type=float, default=None, metavar="E N",
              help="Extract one roof at this approximate position (m).")
@click.option("--radius", type=float, default=None,
              help="Clip radius (m) for --at, --find and CSV jobs without radius_m; default from the preset (8 m; thesis 5 m).")
@click.option("--fit-radius", "fit_radius", type=float, default=None, metavar="M",
              help="Extract the vertex found again from the clip of M metres centred on it (to a fixed point; "
                   "1.3 and 1.6 x M when it finds no vertex there), so that it is the corner's and does not "
                   "depend on --radius (default 5 m; 0: off, the search clip's vertex, as the thesis preset).")
@click.option("--stability-check/--no-stability-check", "stability_check", default=None,
              help="Refuse (status unstable) a vertex that moves by more than its sd when extracted again "
                   "from clips of 0.5-1.5 x the radius (default on; thesis preset off). Off: --find ran "
                   "2.3x faster on a 60 m AHN3 area with the local extraction (1.6x with --fit-radius 0; "
                   "session 8, four check radii; docs/extraction.md).")
@click.option("--find", is_flag=True, help="Search the tiles (or --box) for every roof vertex of 3+ planes.")
@click.option("--box", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Area for --find (m); default: all the tiles.")
@click.option("--classes", default=None, help="Comma list of LAS classes kept for --find, e.g. 6 (buildings).")
@click.option("--preset", type=click.Choice(["default", "thesis"]), default="default", show_default=True,
              help="Parameter preset: 'thesis' = 4-30 deg window, 0.15 m threshold, +-2 m heights.")
@output_option(type=click.Path(dir_okay=False), default=None,
              help="Output: control.csv (jobs), candidates.geojson or .csv (--find).")
@click.option("--planes", "planes_out", type=click.Path(dir_okay=False), default=None,
              help="Also write the planes (a, b, c, d, sds, counts, RMS, slope, aspect) to this CSV.")
@click.option("--figures", type=click.Path(file_okay=False), default=None,
              help="Folder for one operator figure per point (PNG).")
@click.option("--spec-sd", nargs=2, type=float, default=None, metavar="PLAN H",
              help="Replace the propagated sds by specification sds (m), e.g. 0.50 0.15 (thesis).")
@click.option("--index-cache", "index_cache", type=click.Path(dir_okay=False), default=None,
              help="JSON tile index of the --lidar tiles to reuse and update, e.g. SURVEY/lidar_index.json "
                   "from `lidarcat lidar index --blocks`: later clips decode only the parts of a LAZ "
                   "tile they need.")
@json_option(help="Print results as JSON (with --at: one object).")
@workers_option
@scheduler_option
@click.option("--work-dir", "work_dir", type=click.Path(file_okay=False), default=None,
              help="--find with --workers/--scheduler: keep each block's result and done-marker here, so a "
                   "rerun skips finished blocks (with --scheduler, a folder every worker sees). "
                   "Default: a temporary folder.")
def extract(args, lidar, crs, at, radius, fit_radius, stability_check, find, box, classes, preset, output, planes_out, figures,
            spec_sd, index_cache, as_json, workers, scheduler, work_dir) -> None:
    """Roof planes to control points (Delaunay facets + plane intersection).

    Exit status 1 when no roof gave a control point (see below).
    """
    from ..stages.extract import extraction_params

    jobs, tiles = _split_arguments(args, lidar, job_mode=at is None and not find)
    lidar = tuple(tiles)

    if radius is not None and not radius > 0:
        raise click.BadParameter(f"must be positive (m), got {radius:g}", param_hint="--radius")
    if box is not None and not (box[0] < box[2] and box[1] < box[3]):
        raise click.BadParameter(f"{' '.join(f'{v:g}' for v in box)}: need XMIN < XMAX and YMIN < YMAX",
                                 param_hint="--box")
    if fit_radius is not None and not fit_radius >= 0:
        raise click.BadParameter(f"must be positive (m), or 0 for whole faces, got {fit_radius:g}",
                                 param_hint="--fit-radius")
    params = extraction_params(preset, radius, fit_radius, stability_check)
    modes = sum([jobs is not None, at is not None, bool(find)])
    if modes != 1:
        raise click.UsageError("give exactly one of: a JOBS file, --at E N, or --find")
    if (at is not None or find) and not lidar:
        raise click.UsageError("--at and --find need --lidar PATH")
    if find:
        unused = [opt for opt, v in (("--planes", planes_out), ("--figures", figures), ("--spec-sd", spec_sd)) if v]
        if unused:
            raise click.UsageError(f"{', '.join(unused)}: for jobs and --at, not --find")
        if work_dir and workers is None and scheduler is None:
            raise click.UsageError("--work-dir: for --find with --workers or --scheduler")
        _find(lidar, crs, box, classes, params, output, as_json, index_cache, workers, scheduler, work_dir)
        return
    if workers is not None or scheduler is not None or work_dir:
        raise click.UsageError("--workers, --scheduler and --work-dir: for --find, not jobs or --at")
    from ..control.batch import Job, read_jobs
    from ..stages.extract import extract as extract_action

    job_list = [Job("P1", at[0], at[1])] if at is not None else read_jobs(jobs)
    with progress_bar(len(job_list), "Extracting roofs") as bar:
        points = extract_action(jobs if at is None else job_list, lidar=lidar or None, crs=crs, preset=preset,
                                radius_m=radius, fit_radius_m=fit_radius, stability_check=stability_check,
                                spec_sd=tuple(spec_sd) if spec_sd else None,
                                index_cache=index_cache, control_csv=output, planes_csv=planes_out,
                                figures=figures, progress=bar.update if bar is not None else None)
    if as_json:
        if at is not None:
            echo_json(points[0].to_dict())
        else:
            echo_json({"points": [cp.to_dict() for cp in points]})
        if not any(points):
            sys.exit(1)
        return
    if not output:
        click.echo(f"{'point':<10} {'E':>12} {'N':>13} {'h':>9} {'sd_E':>6} {'sd_N':>6} {'sd_h':>6} "
                   f"{'pl':>2}  status")
        for cp in points:
            r = cp.to_row()
            click.echo(f"{r['point']:<10} {r['E']:12.3f} {r['N']:13.3f} {r['h']:9.3f} {r['sd_E']:6.3f} "
                       f"{r['sd_N']:6.3f} {r['sd_h']:6.3f} {r['n_planes']:2d}  {r['status']}"
                       + (f" ({r['reason']})" if r["reason"] else ""))
    n_ok = sum(bool(cp) for cp in points)
    click.echo(f"{n_ok} of {len(points)} roofs gave a control point"
               + (f"; written to {output}" if output else ""))
    if n_ok == 0:
        click.echo("no roof gave a control point (exit status 1); see the status and reason of each row",
                   err=True)
        sys.exit(1)


def _find(lidar, crs, box, classes, params, output, as_json, index_cache, workers, scheduler, work_dir) -> None:
    from ..control.batch import write_candidates
    from ..control.vertices import find_candidates
    from ..lidar import TileIndex, require_metres

    index = TileIndex.build(list(lidar), crs=crs, cache_path=index_cache)
    require_metres(index.crs, "roof extraction (--find)", str(index.tiles[0].path) if index.tiles else "")
    if not box:
        index.verify_bounds()  # the area is the points' own extent, not the headers' claim
    b = index.bounds
    area = box if box else (b.xmin, b.ymin, b.xmax, b.ymax)
    cls = None
    if classes:
        try:
            cls = [int(c) for c in classes.split(",")]
        except ValueError:
            raise click.BadParameter(f"{classes!r}: expected a comma list of integers", param_hint="--classes")
    from ..control.search import find_candidates_tiles, n_blocks, search_area

    if workers is None and scheduler is None:
        # the area plus the margin the candidates' clips reach (a vertex near the area's edge whole)
        cands = find_candidates(index.query_box(*search_area(area, params)), box=area, params=params, classes=cls)
    else:  # blocks of cells on Dask; the same candidates (lidarcat.control.search)

        with progress_bar(n_blocks(index, area, params=params), "Searching blocks") as bar:
            cands = find_candidates_tiles(index, area, params=params, classes=cls, crs=crs, workers=workers,
                                          scheduler=scheduler, work_dir=work_dir,
                                          progress=bar.update if bar is not None else None)
    if output:
        write_candidates(output, cands, crs=index.crs)  # the tiles' own CRS, else --crs
    if as_json:
        echo_json({"candidates": [c.to_feature() for c in cands]})
        return
    for c in cands:
        r = c.point.to_row()
        click.echo(f"{r['point']:<7} {r['E']:12.3f} {r['N']:13.3f} {r['h']:9.3f}  "
                   f"{r['n_planes']} planes  score {c.score:.2f}")
    click.echo(f"{len(cands)} candidate vertices" + (f"; written to {output}" if output else ""))
