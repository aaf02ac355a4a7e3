"""``lidarcat ortho``: orthophotos (standard or true) and a mosaic of adjusted photos."""

from __future__ import annotations

import click

from .options import echo_json, json_option, output_option, progress_bar

__all__ = ["ortho"]

_EPILOG = """\b
Examples:
  lidarcat lidar raster 'demo/lidar/*.laz' --what dsm --cell 0.5 -o dsm.tif
  lidarcat ortho demo/ --all --dsm dsm.tif --gsd 0.2 -o ortho/ --mosaic
  lidarcat ortho demo/ --photo 3 --dtm dtm.tif --gsd 0.5 -o ortho/
\b
Writes DIR/ortho_<photo>.tif (+ .png preview) per photo, and with --mosaic
DIR/mosaic.tif (+ .png) and DIR/seamlines.geojson. GeoTIFFs are float32
(grey or RGB), NaN = nodata, in the survey CRS. Over a DSM the orthophotos are
true orthophotos: cells the photo does not see (z-buffer) are nodata, and the
mosaic fills them from another photo.
"""


@click.command(name="ortho", epilog=_EPILOG)
@click.argument("survey", type=click.Path(exists=True, file_okay=False))
@click.option("--photo", "photo_ids", multiple=True, help="Photo id; repeat for several.")
@click.option("--all", "all_photos", is_flag=True, help="Every adjusted photo of the survey.")
@click.option("--dtm", "dtm", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Terrain model GeoTIFF: standard orthophotos (buildings lean).")
@click.option("--dsm", "dsm", type=click.Path(exists=True, dir_okay=False), default=None,
              help="Surface model GeoTIFF: true orthophotos (occlusions masked).")
@click.option("--gsd", "gsd_m", type=click.FloatRange(min=0, min_open=True), default=0.2, show_default=True,
              help="Output ground sample distance (cell size), m.")
@click.option("--bounds", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Output area (m). Default: each photo's footprint (the mosaic: their union).")
@click.option("--eop", "eop_path", type=click.Path(dir_okay=False), default=None,
              help="Adjusted orientations (eop.csv). Default: SURVEY/out/adjust-<default control>/eop.csv.")
@click.option("--images", "images_dir", type=click.Path(file_okay=False), default=None,
              help="Folder of the photo files <photo>.png/.tif/.jpg. Default: SURVEY/images.")
@click.option("--mosaic", "make_mosaic", is_flag=True,
              help="Also mosaic the photos: the most nadir photo that sees each cell; seamlines as GeoJSON.")
@click.option("--feather", "feather_m", type=click.FloatRange(min=0), default=0.0, show_default=True,
              help="Mosaic: blend the photos across each seamline over +- this many metres (0: hard seams).")
@click.option("--equalize", is_flag=True,
              help="Mosaic: balance the photos first, a gain and an offset per photo from the overlaps "
                   "(least squares, mean gain 1).")
@click.option("--tile", "tile_px", type=click.IntRange(16), default=1024, show_default=True,
              help="Rows/columns computed at once (memory ~ 40 bytes x tile x output width).")
@output_option(outdir=True, required=True, type=click.Path(file_okay=False), help="Output folder.")
@json_option(help="Print what was written as JSON.")
def ortho(survey, photo_ids, all_photos, dtm, dsm, gsd_m, bounds, eop_path, images_dir, make_mosaic, feather_m,
          equalize, tile_px, outdir, as_json) -> None:
    """Orthophotos of adjusted photos over a DTM or DSM, and their mosaic."""
    import contextlib
    from pathlib import Path

    from ..mapping.inputs import default_eop_path, read_orientations
    from ..stages.mapping import orthophotos
    from ..survey.folder import Survey

    if bool(dtm) == bool(dsm):
        raise click.UsageError("give one of --dtm (standard orthophoto) or --dsm (true orthophoto)")
    if bool(photo_ids) == all_photos:
        raise click.UsageError("give --photo ID (repeatable) or --all")
    if feather_m and not make_mosaic:
        raise click.UsageError("--feather blends the mosaic's seamlines: give it with --mosaic")
    if equalize and not make_mosaic:
        raise click.UsageError("--equalize balances the mosaic's photos: give it with --mosaic")
    s = Survey.load(survey)
    if all_photos:
        eop = Path(eop_path) if eop_path else default_eop_path(s)
        adjusted = read_orientations(eop) if eop.is_file() else {}
        photo_ids = tuple(p for p in s.photo_ids if p in adjusted) or s.photo_ids
    with contextlib.ExitStack() as bars:
        current: dict[str, object] = {}

        def progress(step: str, done: int, total: int) -> None:
            if current.get("step") != step:  # one bar per photo, then the mosaic's
                bars.close()
                current.update(step=step, bar=bars.enter_context(progress_bar(1000, step, enabled=not as_json)))
            bar = current["bar"]
            if bar is not None:
                bar.update(int(1000 * done / total) - bar.pos)

        summary = orthophotos(s, outdir, list(photo_ids), dsm or dtm, true_ortho=bool(dsm), gsd_m=gsd_m,
                              eop=eop_path, images=images_dir, bounds=bounds, mosaic=make_mosaic,
                              feather_m=feather_m, tile_px=tile_px, equalize=equalize,
                              progress=progress)
    if as_json:
        echo_json(summary)
        return
    for r in summary["orthophotos"]:
        click.echo(f"photo {r['photo']}: {r['cols']} x {r['rows']} cells of {gsd_m:g} m, {r['n_valid']} valid, "
                   f"{r['n_occluded']} occluded -> {r['path']}")
    if make_mosaic:
        m = summary["mosaic"]
        click.echo(f"mosaic of {len(summary['orthophotos'])} photos: {m['cols']} x {m['rows']} cells, "
                   f"{m['n_nodata']} nodata -> {m['path']}, seamlines {m['seams']}")
