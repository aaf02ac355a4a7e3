"""``lidarcat monoplot``: features digitised on one photo, intersected with the LiDAR surface."""

from __future__ import annotations

import click

from .options import echo_json, json_option, output_option, progress_bar

__all__ = ["monoplot"]

_EPILOG = """\b
Examples:
  lidarcat monoplot demo/ --photo 3 --features roofs.geojson --lidar 'demo/lidar/*.laz' -o roofs_map.geojson
  lidarcat monoplot demo/ --photo 3 --features pts.csv --surface dsm.tif --interpolator bilinear -o pts_map.csv
\b
Features are in pixels of the photo (column right, row down; GeoJSON coordinates
[col_px, row_px], or CSV feature,col_px,row_px[,class,geometry]); docs/mapping.md.
Each vertex gets E, N, h (m, survey CRS), sd_E, sd_N, sd_h (m) and a status:
ok, outside_photo, no_intersection, outside_surface, not_converged, occluded.
"""


@click.command(name="monoplot", epilog=_EPILOG)
@click.argument("survey", type=click.Path(exists=True, file_okay=False))
@click.option("--photo", "photo_id", required=True, help="Photo id (photos.csv) the features were digitised on.")
@click.option("--features", "features_path", required=True, type=click.Path(dir_okay=False),
              help="Features in pixels: .geojson or .csv.")
@click.option("--surface", "surface_path", type=click.Path(dir_okay=False), default=None,
              help="Surface model GeoTIFF (DSM; `lidarcat lidar raster --what dsm`).")
@click.option("--lidar", "lidar", multiple=True,
              help="LiDAR tiles (paths or globs; repeat) as the surface, no grid: their first returns "
                   "around the rays. Default with neither option: the survey's tiles.")
@click.option("--interpolator", type=click.Choice(["tin", "nearest", "bilinear"]), default=None,
              help="Surface height between samples: tin (LiDAR points; default), nearest, bilinear "
                   "(grids; default with --surface).")
@click.option("--method", type=click.Choice(["exact", "iterate"]), default="exact", show_default=True,
              help="exact: the ray's first hit (occlusion-aware); iterate: the paper's height iteration.")
@click.option("--eop", "eop_path", type=click.Path(dir_okay=False), default=None,
              help="Adjusted orientations (eop.csv). Default: SURVEY/out/adjust-<default control>/eop.csv.")
@click.option("--image-sd", "image_sd_px", type=click.FloatRange(min=0), default=0.5, show_default=True,
              help="Pointing sd of the digitised pixels, px.")
@click.option("--surface-sd", "surface_sd_m", type=click.FloatRange(min=0), default=0.15, show_default=True,
              help="Height sd of the surface, m (LiDAR noise + interpolation).")
@output_option(required=True, type=click.Path(dir_okay=False),
              help="Output .geojson (features) or .csv (one row per vertex).")
@json_option(help="Print the status counts as JSON.")
def monoplot(survey, photo_id, features_path, surface_path, lidar, interpolator, method, eop_path,
             image_sd_px, surface_sd_m, output, as_json) -> None:
    """Monorestitution: features digitised on ONE photo, intersected with the LiDAR surface.

    Inverse collinearity through the camera's distortion model, the adjusted
    orientation of the photo, and the surface (the LiDAR points as a TIN or
    nearest neighbour, or a DSM grid); each vertex carries a propagated sd
    (orientation covariance, pointing sd, surface sd) and a status.
    """
    from pathlib import Path

    import numpy as np

    from .._util import write_csv_atomic, write_text_atomic
    from ..mapping.features import FEATURE_CSV_COLUMNS, features_geojson, features_rows, read_features
    from ..mapping.monoplot import GridSurface
    from ..mapping.monoplot import monoplot as run_monoplot
    from ..mapping.inputs import adjusted_orientation, lidar_surface, ray_area
    from ..survey.folder import Survey

    if surface_path and lidar:
        raise click.UsageError("give --surface or --lidar, not both")
    if surface_path and interpolator == "tin":
        raise click.UsageError("--interpolator tin triangulates LiDAR points (--lidar); a --surface grid "
                               "takes nearest or bilinear")
    if not surface_path and interpolator == "bilinear":
        raise click.UsageError("--interpolator bilinear interpolates a grid (--surface DSM.tif); LiDAR points "
                               "take tin or nearest")
    out = Path(output)
    if out.suffix.lower() not in (".geojson", ".json", ".csv"):
        raise click.BadParameter(f"{output}: use a .geojson or .csv file", param_hint="-o")
    s = Survey.load(survey)
    eo = adjusted_orientation(s, photo_id, eop_path)
    camera = s.camera_of(photo_id)
    feats = read_features(features_path)
    px = np.vstack([f.colrow_px for f in feats])
    if surface_path:
        surface = GridSurface.from_geotiff(surface_path, interpolator or "bilinear", surface_sd_m)
    else:
        paths = list(lidar) or [str(p) for p in s.lidar_paths]
        if not paths:
            raise click.UsageError("the survey has no LiDAR tiles; give --lidar TILES or --surface DSM.tif")
        from ..lidar import TileIndex

        index = TileIndex.build(paths, crs=s.lidar_crs)
        box = ray_area(camera, eo.params, px, index.bounds.zmin, index.bounds.zmax)
        surface = lidar_surface(index, box, interpolator or "tin", surface_sd_m)
    with progress_bar(2, "monoplot", enabled=not as_json) as bar:
        res = run_monoplot(px, camera, eo, surface, method=method, image_sd_px=image_sd_px,
                           progress=(lambda i, n: bar.update(i - bar.pos)) if bar is not None else None)
    if out.suffix.lower() == ".csv":
        write_csv_atomic(out, FEATURE_CSV_COLUMNS, features_rows(feats, res),
                         comments=[f"monorestitution of {features_path} on photo {photo_id} ({method}, "
                                   f"{res.interpolator}); E, N, h and sd in m, CRS {s.crs}"])
    else:
        import json

        doc = features_geojson(feats, res, crs=s.crs, extra={
            "photo": photo_id, "method": method, "interpolator": res.interpolator,
            "image_sd_px": image_sd_px, "surface_sd_m": surface_sd_m})
        write_text_atomic(out, json.dumps(doc, indent=1))
    counts = res.counts()
    if as_json:
        echo_json({"output": str(out), "vertices": len(res), "features": len(feats), "status": counts})
        return
    click.echo(f"{len(feats)} features ({len(res)} vertices) on photo {photo_id}: "
               + ", ".join(f"{k} {v}" for k, v in counts.items()) + f" -> {out}")
