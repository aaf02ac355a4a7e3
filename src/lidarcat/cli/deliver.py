"""``lidarcat deliver``: products in the delivery formats of the LACTEC report (TIFF + TFW, Shapefile, DXF)."""

from __future__ import annotations

import shutil
from pathlib import Path

import click

from .options import crs_option, echo_json, json_opt, output_option

__all__ = ["deliver"]


@click.command("deliver")
@click.argument("products", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False),
                metavar="PRODUCT...")
@output_option(outdir=True, required=True, type=click.Path(file_okay=False),
              help="Folder receiving the delivered files (created; moved in once all are written).")
@click.option("--format", "formats", multiple=True, required=True, type=click.Choice(["tfw", "shp", "dxf"]),
              help="tfw: each GeoTIFF copied with its world file (.tfw). shp: each layer as a Shapefile "
                   "(<name>.shp + .shx .dbf .prj .cpg; needs lidarcat[gis]). dxf: one drawing <FOLDER>/products.dxf "
                   "of every contour and spot-height layer, layers named by the report's conventions "
                   "(Figure 27; needs lidarcat[cad]). Repeat for several.")
@crs_option(help="CRS of layers that carry none (default: the layer's own).")
@json_opt
def deliver(products: tuple[str, ...], outdir: str, formats: tuple[str, ...], crs: str | None,
            as_json: bool) -> None:
    """Write GeoTIFFs with world files, vector layers as Shapefiles, contours and spot heights as DXF.

    \b
    Examples:
      lidarcat deliver dtm.tif hypsometry.tif -o entrega/ --format tfw
      lidarcat deliver curvas.geojson curvas_spots.geojson -o entrega/ --format shp --format dxf
    """
    import numpy as np

    from .._util import atomic_dir
    from ..lidar.crs import resolve_crs
    from ..production.contours import read_line_layer
    from ..production.delivery import read_point_layer, write_dxf, write_shapefile, write_world_file

    lines, spots, written = [], [], []
    c = resolve_crs(crs) if crs else None
    with atomic_dir(Path(outdir)) as tmp:
        for p in map(Path, products):
            suffix = p.suffix.lower()
            if suffix in (".tif", ".tiff"):
                if "tfw" in formats:
                    shutil.copyfile(p, tmp / p.name)
                    written += [p.name, write_world_file(tmp / p.name).name]
                continue
            if suffix not in (".geojson", ".json", ".gpkg"):
                raise click.BadParameter(f"{p}: give .tif, .geojson or .gpkg products", param_hint="PRODUCT")
            pts, lcrs = read_point_layer(p) if suffix != ".gpkg" else ([], None)
            feats, lcrs = read_line_layer(p) if not pts else ([], lcrs)
            layer_crs = c or lcrs
            if layer_crs is None:
                raise click.UsageError(f"{p}: the layer carries no CRS; give --crs")
            c = c or layer_crs
            lines += feats
            spots += [(*f["geometry"]["coordinates"][:2], f["properties"].get("h_m", np.nan)) for f in pts]
            if "shp" in formats:
                shp = write_shapefile(tmp / f"{p.stem}.shp", feats or pts, layer_crs)
                written += sorted(q.name for q in tmp.glob(f"{shp.stem}.*"))
        if "dxf" in formats:
            write_dxf(tmp / "products.dxf", contours=lines, spots=np.asarray(spots, dtype=float).reshape(-1, 3))
            written.append("products.dxf")
    if as_json:
        echo_json({"files": written})
    else:
        click.echo(f"wrote {len(written)} file(s) to {outdir}")
