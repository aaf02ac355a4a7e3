"""``lidarcat lidar``: LiDAR tiles from the command line (info, index, clip, raster; calibrate, swath)."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import click

from .options import (
    POSITIVE,
    crs_option,
    echo_json,
    json_opt,
    output_option,
    progress_bar,
    scheduler_option,
    tile_sources,
    workers_option,
)

__all__ = ["lidar", "info", "index", "clip_cmd", "raster", "calibrate", "swath"]

_columns_opt = click.option(
    "--columns", default=None, metavar="'E N H ...'",
    help="Text files: column names in order (E N H intensity return class ...; '-' skips one). "
         "Default: the file's header line, or E N H [intensity] [return] [class] by count.")
_delimiter_opt = click.option(
    "--delimiter", default=None, type=click.Choice(["whitespace", "comma", "semicolon"]),
    help="Text files: field separator (default: detected from the first data line).")


@click.group(short_help="LiDAR tiles: info, index, clip, raster views; ground, DTM/DSM, contours.")
def lidar() -> None:
    """LiDAR point files: LAS 1.0-1.4, LAZ, COPC and ASCII (.xyz .txt .csv .asc .pts).

    PATH arguments take files, folders (all point files in them), globs
    ('tiles/*.laz', quoted) or a survey folder (its [files] lidar tiles and
    [lidar] crs). Coordinates are E, N, h in metres.
    """


@contextlib.contextmanager
def _progress(label: str, paths: Sequence[Path]) -> Iterator[Any]:
    """A click progress bar over the bytes of *paths* on a TTY, else a no-op callable."""
    total = sum(p.stat().st_size for p in paths if p.exists()) if sys.stderr.isatty() else 0
    with progress_bar(total, label) as bar:
        yield bar.update if bar is not None else None


def _advance(bar: Any) -> Any:
    """A ``progress(done, total)`` callback moving *bar* to *done* (None without a bar)."""
    if bar is None:
        return None

    def update(done: int, total: int) -> None:
        bar.update(max(0, done - bar.pos))
    return update


# ----------------------------------------------------------------------------- info
@lidar.command()
@click.argument("paths", nargs=-1, required=True, metavar="PATH...")
@crs_option()
@_columns_opt
@_delimiter_opt
@json_opt
def info(paths: tuple[str, ...], crs: str | None, columns: str | None, delimiter: str | None,
         as_json: bool) -> None:
    """Point counts, bounds, CRS, density, classes and returns of point files.

    Density is points per m2 of covered ground (1 m cells holding a point).

    \b
    Examples:
      lidarcat lidar info tests/data/lidar/ahn3_cropped_1.laz --crs EPSG:7415
      lidarcat lidar info 'tiles/*.laz' --json
      lidarcat lidar info faixa.xyz --columns 'E N H intensity' --crs EPSG:29192
    """
    from ..lidar import describe

    files, crs, _ = tile_sources(paths, crs)
    with _progress("Reading", files) as progress:
        result = describe(files, crs=crs, columns=columns, delimiter=delimiter, progress=progress)
    if as_json:
        echo_json(result)
        return
    for f in result["files"] + ([{"path": "TOTAL", **result["total"]}] if len(result["files"]) > 1 else []):
        click.echo(_info_text(f))


def _fmt_counts(d: dict[str, int] | None) -> str:
    return "-" if not d else ", ".join(f"{k}: {v:,}" for k, v in d.items())


def _info_text(f: dict[str, Any]) -> str:
    b = f.get("bounds") or {}
    lines = [f"{f['path']}"]
    if "format" in f:
        lines.append(f"  format     {f['format']}")
    lines.append(f"  points     {f['points']:,}")
    if b:
        lines.append(f"  E          {b['xmin']:.3f} .. {b['xmax']:.3f} m")
        lines.append(f"  N          {b['ymin']:.3f} .. {b['ymax']:.3f} m")
        lines.append(f"  h          {b['zmin']:.3f} .. {b['zmax']:.3f} m")
    src = "" if "crs_from_file" not in f else (" (from the file)" if f["crs_from_file"] else
                                              " (given)" if f["crs"] else "")
    lines.append(f"  CRS        {f['crs'] or 'none (give --crs)'}{src}")
    if f.get("density_pts_m2"):
        dens = f"{f['density_pts_m2']:.2f} pts/m2 over {f['covered_area_m2']:,.0f} m2"
        if f.get("first_return_density_pts_m2"):
            dens += f" ({f['first_return_density_pts_m2']:.2f} first returns/m2)"
        lines.append(f"  density    {dens}")
    elif f.get("density_note"):
        lines.append(f"  density    - ({f['density_note']})")
    lines.append(f"  classes    {_fmt_counts(f.get('classes'))}")
    lines.append(f"  returns    {_fmt_counts(f.get('returns'))}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- index
@lidar.command()
@click.argument("paths", nargs=-1, required=True, metavar="SURVEY|PATH...")
@crs_option()
@click.option("--index-file", "index_file", type=click.Path(dir_okay=False), default=None,
              help="Where to keep the index (JSON). Default: SURVEY/lidar_index.json, or "
                   "lidar_index.json in the folder of the first tile.")
@click.option("--rebuild", is_flag=True, help="Ignore the cached index and read every tile again.")
@click.option("--blocks", is_flag=True,
              help="Also index every LAS/LAZ tile by blocks (plan box of every 5 000 points): later "
                   "clips of a tile not in memory decode only the blocks they touch. The full read "
                   "that measures a tile's bounds makes it anyway; kept for scripts.")
@json_opt
def index(paths: tuple[str, ...], crs: str | None, index_file: str | None, rebuild: bool, blocks: bool,
          as_json: bool) -> None:
    """Index LiDAR tiles: bounds and point counts per tile.

    SURVEY is a survey folder (its [files] lidar and [lidar] crs are used);
    otherwise give the tiles as files, folders or quoted globs, as for
    `lidar info` and `lidar clip`. Every tile is read once: the bounds in a
    LAS header are often wrong, so the index records the bounds of the points
    themselves (and the block index of LAS/LAZ tiles). The index is cached and
    refreshed for tiles whose size or modification time changed, so later
    clips read only the tiles they need.

    \b
    Examples:
      lidarcat lidar index my_survey/
      lidarcat lidar index 'tiles/*.laz' --crs EPSG:7415 --index-file tiles/index.json
    """
    from ..lidar import TileIndex

    files, crs, root = tile_sources(paths, crs)
    if index_file is not None:
        cache = Path(index_file)
    elif root is not None and len(paths) == 1:
        cache = Path(root) / "lidar_index.json"
    else:
        cache = files[0].parent / "lidar_index.json"
    if rebuild and cache.exists():
        cache.unlink()
    with _progress("Indexing", files) as progress:
        idx = TileIndex.build(files, crs=crs, cache_path=cache, progress=progress, blocks=blocks)
    with _progress("Measuring", [t.path for t in idx.tiles if not t.bounds_verified]) as progress:
        idx.verify_bounds(progress=progress)
    if as_json:
        echo_json({"index": str(cache), **idx.to_dict()})
        return
    b = idx.bounds
    click.echo(f"{len(idx)} tiles, {idx.count:,} points, CRS {idx.to_dict()['crs'] or 'none'}")
    click.echo(f"E {b.xmin:.2f} .. {b.xmax:.2f} m, N {b.ymin:.2f} .. {b.ymax:.2f} m")
    for t in idx.tiles:
        tb = t.bounds
        click.echo(f"  {t.path.name:<32} {t.count:>12,}  E {tb.xmin:.1f}..{tb.xmax:.1f}  "
                   f"N {tb.ymin:.1f}..{tb.ymax:.1f}")
    if blocks:
        n_blk = sum(idx.block_index(t) is not None for t in idx.tiles)
        click.echo(f"block index: {n_blk} of {len(idx)} tiles (LAS/LAZ)")
    click.echo(f"index written to {cache}")


# ----------------------------------------------------------------------------- clip
@lidar.command("clip")
@click.argument("paths", nargs=-1, required=True, metavar="PATH...")
@click.option("--at", "at", nargs=2, type=float, required=True, metavar="E N",
              help="Approximate plan position of the roof vertex, metres.")
@click.option("--radius", type=POSITIVE, required=True, metavar="R",
              help="Clip radius in metres (thesis: 2.5-5.0).")
@crs_option()
@click.option("--at-crs", default=None, metavar="CRS",
              help="CRS of --at when it differs from the tiles' (it is transformed with pyproj).")
@click.option("--height-filter", type=click.Choice(["thesis", "robust", "none"]), default="thesis",
              show_default=True,
              help="thesis: drop points more than WINDOW from the clip's mean height; robust: window "
                   "around the median of the upper half (the roof); none: no height filter.")
@click.option("--window", "window_m", type=POSITIVE, default=2.0,
              show_default=True, help="Half-width of the height window, metres.")
@click.option("--first-returns", is_flag=True, help="Keep only first (or only) returns.")
@click.option("--class", "classes", type=int, multiple=True, metavar="CODE",
              help="Keep only this LAS class (repeatable), e.g. --class 6 for buildings.")
@click.option("--min-points", type=click.IntRange(min=1), default=10, show_default=True,
              help="Fewest points accepted.")
@output_option(type=click.Path(dir_okay=False), default=None,
              help="Write the clip to .laz/.las/.csv/.xyz/.txt (atomically).")
@_columns_opt
@_delimiter_opt
@json_opt
def clip_cmd(paths: tuple[str, ...], at: tuple[float, float], radius: float, crs: str | None,
             at_crs: str | None, height_filter: str, window_m: float, first_returns: bool,
             classes: tuple[int, ...], min_points: int, output: str | None, columns: str | None,
             delimiter: str | None, as_json: bool) -> None:
    """Clip the points around a roof position (thesis section 3.2.3).

    Only tiles near the position are read; a roof straddling tiles comes back
    whole.

    \b
    Examples:
      lidarcat lidar clip tests/data/lidar/ahn3_cropped_*.laz --crs EPSG:7415 \\
          --at 85000.5 447500 --radius 5 --height-filter robust -o roof.laz
      lidarcat lidar clip faixa.xyz --crs EPSG:29192 --at 677757.8 7183482.0 --radius 5
    """
    from ..lidar import TileIndex, clip, write_points

    files, crs, _ = tile_sources(paths, crs)
    idx = TileIndex.build(files, crs=crs, columns=columns, delimiter=delimiter)
    cloud = clip(idx, at, radius, height_filter=None if height_filter == "none" else height_filter,
                 height_window_m=window_m, first_returns_only=first_returns,
                 classes=list(classes) or None, min_points=min_points, crs=at_crs)
    if output is not None:
        write_points(output, cloud)
    summary = {"at": list(at), "radius_m": radius, "points": len(cloud),
               "bounds": cloud.bounds._asdict(), "height_filter": height_filter,
               "crs": None if cloud.crs is None else cloud.crs.to_string(), "output": output}
    if as_json:
        echo_json(summary)
        return
    b = cloud.bounds
    click.echo(f"{len(cloud):,} points within {radius:g} m of E {at[0]:.3f} N {at[1]:.3f}; "
               f"h {b.zmin:.2f} .. {b.zmax:.2f} m")
    if output is not None:
        click.echo(f"written to {output}")


# ----------------------------------------------------------------------------- raster
@lidar.command()
@click.argument("paths", nargs=-1, required=True, metavar="PATH...")
@click.option("--cell", "cell_m", type=POSITIVE, default=0.5,
              show_default=True, help="Cell size, metres.")
@click.option("--what", type=click.Choice(["intensity", "dsm", "dtm"]), default="intensity",
              show_default=True,
              help="intensity: mean of first returns; dsm: highest first return; dtm: lowest "
                   "ground (class 2) or last return, holes interpolated.")
@click.option("--bounds", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Area to grid, metres (default: the extent of the points; points far outside "
                   "their bulk are left out with a warning).")
@click.option("--max-cells", type=click.IntRange(1), default=None, metavar="N",
              help="Largest grid, cells (default 100,000,000); a larger one is refused.")
@output_option(type=click.Path(dir_okay=False), required=True,
              help="GeoTIFF to write (a PNG preview with a colour bar goes next to it).")
@click.option("--no-preview", is_flag=True, help="Do not write the PNG preview.")
@crs_option()
@_columns_opt
@_delimiter_opt
@json_opt
def raster(paths: tuple[str, ...], cell_m: float, what: str, bounds: tuple[float, ...] | None,
           max_cells: int | None, output: str, no_preview: bool, crs: str | None, columns: str | None,
           delimiter: str | None, as_json: bool) -> None:
    """Grid points into an intensity image, surface model or terrain model.

    Writes a float32 GeoTIFF (EPSG GeoKeys; GDAL/QGIS open it georeferenced;
    NaN = no data) and OUTPUT.png, a preview with a colour bar: the intensity
    image is where an operator picks roof vertices (thesis section 3.2.2).

    Without --bounds the grid covers the points, not the files' headers; a
    point far outside the bulk of the data (a displaced point kilometres
    away) is left out with a warning that counts such points and names the
    farthest; give --bounds to grid it anyway.  A grid above --max-cells is
    refused before anything is allocated.

    \b
    Example:
      lidarcat lidar raster tests/data/lidar/ahn3_cropped_*.laz --crs EPSG:7415 \\
          --cell 0.5 --what intensity -o intensity.tif
    """
    import logging

    import numpy as np

    from ..lidar import TileIndex, rasterize, write_raster
    from ..lidar.raster import grid_for, stream_extent

    files, crs, _ = tile_sources(paths, crs)
    idx = TileIndex.build(files, crs=crs, columns=columns, delimiter=delimiter, max_cached_points=0)
    idx.verify_bounds()  # header bounds are claims: measure them before choosing tiles or the box
    if bounds:
        box = tuple(bounds)
        grid_for(box, cell_m, max_cells=max_cells)   # a clear error before any point is read
    else:
        if not np.all(np.isfinite(tuple(idx.bounds[:4]))):
            raise click.UsageError("the files hold no points")
        ext = stream_extent(lambda: idx.iter_points(idx.tiles), cell_m, sum(t.count for t in idx.tiles))
        if ext.empty:
            raise click.UsageError("the files hold no points with finite coordinates")
        if ext.n_out:
            logging.getLogger("lidarcat.lidar.raster").warning(
                "%s; left out of the grid (give --bounds to grid them)", ext.describe_outliers())
        box = ext.bounds
    tiles = idx.tiles_in_box(*box)
    if not tiles:
        from ..errors import ClipError

        raise ClipError(f"no LiDAR points in E {box[0]:.1f}..{box[2]:.1f}, N {box[1]:.1f}..{box[3]:.1f}; "
                        f"the tiles cover E {idx.bounds.xmin:.1f}..{idx.bounds.xmax:.1f}, "
                        f"N {idx.bounds.ymin:.1f}..{idx.bounds.ymax:.1f}")
    with _progress("Gridding", [t.path for t in tiles]) as progress:
        def stream():
            for t in tiles:
                for chunk in idx.iter_points([t]):
                    yield chunk
                if progress is not None:
                    progress(t.size)

        grid, transform = rasterize(stream(), cell_m, what, box, max_cells=max_cells)
    written = write_raster(output, grid, transform, idx.crs, what, preview=not no_preview)
    filled = float(np.isfinite(grid).mean())
    result = {"what": what, "cell_m": cell_m, "rows": grid.shape[0], "cols": grid.shape[1],
              "transform": transform.to_gdal(), "valued_fraction": filled,
              "crs": None if idx.crs is None else idx.crs.to_string(), "files": [str(p) for p in written]}
    if as_json:
        echo_json(result)
        return
    click.echo(f"{what}: {grid.shape[1]} x {grid.shape[0]} cells of {cell_m:g} m, "
               f"{100 * filled:.1f} % valued")
    for p in written:
        click.echo(f"written {p}")


# ----------------------------------------------------------------------------- calibrate
@lidar.command()
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@click.option("--trajectory", required=True, type=click.Path(exists=True, dir_okay=False),
              metavar="SBET|CSV",
              help="The flight's trajectory: an Applanix SBET (.out/.sbet, 17 doubles per record, WGS 84) or a "
                   "CSV time,E,N,H,roll_deg,pitch_deg,heading_deg (map CRS; heading clockwise from grid north).")
@click.option("--control", type=click.Path(exists=True, dir_okay=False), default=None, metavar="CSV",
              help="Surveyed control surface (the runway): id,E,N,H. Without it the elevation bias is not "
                   "estimated.")
@output_option(required=True, metavar="OUT.json", help="The report (JSON).")
@click.option("--classes", default=None, metavar="C1,C2",
              help="Use only points of these classes (default: all; walls, trees and cars are rejected "
                   "by the plane and 4-MAD tests).")
@click.option("--stride", type=click.IntRange(1), default=1, show_default=True,
              help="Use one point in N (chosen by a hash of the point; thins dense tiles).")
@click.option("--max-observations", type=click.IntRange(0), default=200_000, show_default=True, metavar="N",
              help="At most N control and N strip observations (a sample by point hash, the same however the "
                   "survey is tiled); 0: all.")
@click.option("--radius-m", type=POSITIVE, default=2.5, show_default=True,
              help="Strip planes: radius of the other line's points fitted, metres.")
@click.option("--sd-control-m", type=POSITIVE, default=0.05, show_default=True,
              help="A-priori sd of a LiDAR height against the control surface, metres.")
@click.option("--sd-strip-m", type=POSITIVE, default=0.05, show_default=True,
              help="A-priori sd of a point against the other flight line's plane, metres.")
@workers_option
@scheduler_option
@crs_option()
@json_opt
def calibrate(paths: tuple[str, ...], trajectory: str, control: str | None, output: str, classes: str | None,
              stride: int, max_observations: int, radius_m: float, sd_control_m: float, sd_strip_m: float,
              workers: int | None, scheduler: str | None, crs: str | None, as_json: bool) -> None:
    """Boresight (roll, pitch), scan-angle scale and elevation bias from tiles + trajectory (report 7.1.2).

    LAS points carry no range or scan angle: they are rebuilt from each
    point and the trajectory at its GPS time (adjusted standard GPS time is
    converted to seconds of the week for an SBET). Flight lines are the
    points' point source ids; overlapping lines flown both ways over sloped
    ground give roll, pitch and scale, the control surface the bias.

    Tile by tile (serial, or on Dask with --workers/--scheduler; the same
    estimate either way): each tile, with its neighbours' points within the
    planes' reach, gives its observations in two passes; one tile at a time
    is in memory per worker, and the merged observations are bounded by
    --max-observations.

    \b
    Example:
      lidarcat lidar calibrate strips/*.laz --trajectory sbet_001.out --control runway.csv -o calib.json
    """
    from ..stages.lidar import system_calibration

    cls = None
    if classes:
        try:
            cls = [int(c) for c in classes.split(",") if c.strip()]
        except ValueError:
            raise click.BadParameter(f"{classes!r} is not a comma-separated list of integers",
                                     param_hint="--classes") from None
    files, crs, _ = tile_sources(paths, crs)
    with progress_bar(3 * len(files) + 10, "Tiles (bounds, 2 passes), adjusting") as bar:
        report = system_calibration(files, trajectory, output, crs=crs, control=control, classes=cls, stride=stride,
                                    radius_m=radius_m, sd_control_m=sd_control_m, sd_strip_m=sd_strip_m,
                                    max_observations=max_observations or None, workers=workers,
                                    scheduler=scheduler, progress=_advance(bar))
    if as_json:
        echo_json(report)
        return
    c, deg, sdd = report["calibration"], report["parameters_deg"], report["sd_deg"]
    click.echo(f"{report['points']:,} points of flight lines {', '.join(map(str, report['flight_lines']))}; "
               f"{report['time_base']}")
    click.echo(f"roll  {deg['roll_deg']:+.5f} +/- {sdd['roll_deg']:.5f} deg")
    click.echo(f"pitch {deg['pitch_deg']:+.5f} +/- {sdd['pitch_deg']:.5f} deg")
    click.echo(f"scan-angle scale {c['parameters']['scale']:+.6f} +/- {c['sd']['scale']:.6f}")
    if c["parameters"]["bias_m"] is not None:
        click.echo(f"elevation bias {c['parameters']['bias_m']:+.3f} +/- {c['sd']['bias_m']:.3f} m")
    for note in c["notes"]:
        click.echo(f"note: {note}")
    click.echo(f"written {output}")


# ----------------------------------------------------------------------------- swath
@lidar.command()
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT.tif",
               help="The difference image (GeoTIFF, metres, the tiles' CRS); OUT.png (coloured) and OUT.json "
                    "(statistics) go beside it.")
@click.option("--cell", "cell_m", type=POSITIVE, default=1.0, show_default=True, help="Cell size, metres.")
@click.option("--quality-level", type=click.Choice(["QL0", "QL1", "QL2", "QL3"]), default="QL2", show_default=True,
              help="USGS quality level whose interswath limits are applied (QL2: RMSDz <= 8 cm, max +-16 cm).")
@click.option("--classes", default="auto", show_default=True, metavar="auto|all|C1,C2",
              help="Last returns used: auto = ground (2) when the tiles are classified, else all; all; or "
                   "a list of classes. Noise (7, 18) and withheld points are always left out.")
@click.option("--smooth-rms-m", type=POSITIVE, default=0.05, show_default=True,
              help="A cell counts in the statistics when both lines' planes fit within this rms, metres.")
@click.option("--max-slope-deg", type=click.FloatRange(0, 90), default=10.0, show_default=True,
              help="... and both planes are at most this steep.")
@click.option("--no-preview", is_flag=True, help="Do not write the PNG.")
@workers_option
@scheduler_option
@crs_option()
@json_opt
def swath(paths: tuple[str, ...], output: str, cell_m: float, quality_level: str, classes: str,
          smooth_rms_m: float, max_slope_deg: float, no_preview: bool, workers: int | None, scheduler: str | None,
          crs: str | None, as_json: bool) -> None:
    """Swath separation image: per cell, the difference between overlapping flight lines (USGS LBS).

    Flight lines are the points' point source ids. Each line's last returns
    in a cell are fitted by a plane; the cell holds the height difference
    of the two best-sampled lines at its centre (lower id minus higher).
    RMSDz and max |dz| over smooth, flat cells are checked against the
    quality level's interswath limits.

    Tile by tile: each tile's sums of the plane fits are a task (serial, or
    on Dask with --workers/--scheduler; the same image either way), merged
    once.

    \b
    Example:
      lidarcat lidar swath tests/data/lidar/ahn3_cropped_1.laz --crs EPSG:7415 -o swath.tif
      lidarcat lidar swath 'strips/*.laz' -o swath.tif --workers 4
    """
    from ..stages.lidar import swath_check

    cls: Any = "auto"
    word = classes.strip().lower()
    if word == "all":
        cls = None
    elif word != "auto":
        try:
            cls = [int(c) for c in classes.split(",") if c.strip()]
        except ValueError:
            raise click.BadParameter(f"{classes!r} is not auto, all or a comma-separated list of integers",
                                     param_hint="--classes") from None
    files, crs, _ = tile_sources(paths, crs)
    with progress_bar(len(files), "Tiles") as bar:
        report = swath_check(files, output, crs=crs, cell_m=cell_m, quality_level=quality_level, classes=cls,
                             smooth_rms_m=smooth_rms_m, max_slope_deg=max_slope_deg, preview=not no_preview,
                             workers=workers, scheduler=scheduler, progress=_advance(bar))
    if as_json:
        echo_json(report)
        return
    st = report["swath"]
    verdict = {True: "PASS", False: "FAIL", None: "no smooth overlap"}[st["pass"]]
    click.echo(f"{st['overlap_cells']:,} overlap cells of {cell_m:g} m ({st['smooth_cells']:,} smooth), "
               f"flight lines {', '.join(map(str, report['flight_lines']))}")
    if st["smooth_cells"]:
        click.echo(f"RMSDz {100 * st['rmsdz_m']:.1f} cm (limit {100 * st['rmsdz_limit_m']:g}), max |dz| "
                   f"{100 * st['max_abs_dz_m']:.1f} cm (limit {100 * st['max_limit_m']:g}), 95 % "
                   f"{100 * st['p95_abs_dz_m']:.1f} cm: {quality_level} {verdict}")
    else:
        click.echo(f"{quality_level}: {verdict}")
    for p in report["files"]:
        click.echo(f"written {p}")


# production chain (ground, dtm, dsm, contours, hypsometry) lives in its own module
from .lidar_products import PRODUCT_COMMANDS as _PRODUCTS  # noqa: E402

for _cmd in _PRODUCTS:
    lidar.add_command(_cmd)
