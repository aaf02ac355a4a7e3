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
@click.option("--tile", "tile_px", type=click.IntRange(16), default=1024, show_default=True,
              help="Rows/columns computed at once (memory ~ 40 bytes x tile x output width).")
@output_option(outdir=True, required=True, type=click.Path(file_okay=False), help="Output folder.")
@json_option(help="Print what was written as JSON.")
def ortho(survey, photo_ids, all_photos, dtm, dsm, gsd_m, bounds, eop_path, images_dir, make_mosaic, feather_m,
          tile_px, outdir, as_json) -> None:
    """Orthophotos of adjusted photos over a DTM or DSM, and their mosaic."""
    from pathlib import Path

    from ..mapping.monoplot import GridSurface
    from ..mapping.mosaic import mosaic
    from ..mapping.ortho import PhotoModel, orthophoto
    from ..mapping.inputs import adjusted_orientations, default_eop_path, photo_image, read_orientations
    from ..survey.folder import Survey

    if bool(dtm) == bool(dsm):
        raise click.UsageError("give one of --dtm (standard orthophoto) or --dsm (true orthophoto)")
    if bool(photo_ids) == all_photos:
        raise click.UsageError("give --photo ID (repeatable) or --all")
    if feather_m and not make_mosaic:
        raise click.UsageError("--feather blends the mosaic's seamlines: give it with --mosaic")
    s = Survey.load(survey)
    if all_photos:
        eop = Path(eop_path) if eop_path else default_eop_path(s)
        adjusted = read_orientations(eop) if eop.is_file() else {}
        photo_ids = tuple(p for p in s.photo_ids if p in adjusted) or s.photo_ids
    surface = GridSurface.from_geotiff(dsm or dtm)
    images = Path(images_dir) if images_dir else s.root / "images"
    eos = adjusted_orientations(s, photo_ids, eop_path)
    photos = []
    for pid in photo_ids:
        cam = s.camera_of(pid)
        photos.append(PhotoModel(pid, photo_image(pid, images, cam), cam, eos[pid].params))
    out = Path(outdir)
    results = []
    for ph in photos:
        with progress_bar(1000, f"ortho {ph.photo_id}", enabled=not as_json) as bar:
            r = orthophoto(ph, surface, gsd_m, out / f"ortho_{ph.photo_id}.tif", bounds=bounds,
                           true_ortho=bool(dsm), crs=s.crs, tile_px=tile_px,
                           progress=(lambda d, n: bar.update(int(1000 * d / n) - bar.pos)) if bar else None)
        results.append(r.to_dict() | {"photo": ph.photo_id})
        if not as_json:
            click.echo(f"photo {ph.photo_id}: {r.shape[1]} x {r.shape[0]} cells of {gsd_m:g} m, "
                       f"{r.n_valid} valid, {r.n_occluded} occluded -> {r.path}")
    summary = {"orthophotos": results}
    if make_mosaic:
        with progress_bar(1000, "mosaic", enabled=not as_json) as bar:
            m = mosaic(photos, surface, gsd_m, out / "mosaic.tif", seams_path=out / "seamlines.geojson",
                       bounds=bounds, true_ortho=bool(dsm), crs=s.crs, tile_px=tile_px, feather_m=feather_m,
                       progress=(lambda d, n: bar.update(int(1000 * d / n) - bar.pos)) if bar else None)
        summary["mosaic"] = m.to_dict()
        if not as_json:
            click.echo(f"mosaic of {len(photos)} photos: {m.shape[1]} x {m.shape[0]} cells, "
                       f"{m.n_nodata} nodata -> {m.path}, seamlines {m.seams_path}")
    if as_json:
        echo_json(summary)
