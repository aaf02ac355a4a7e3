"""``lidarcat deliver``: products in the delivery formats of the LACTEC report (TIFF + TFW, Shapefile, DXF);
the action of ``[products] delivery`` (:func:`lidarcat.stages.products.deliver`)."""

from __future__ import annotations

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
    from .._util import atomic_dir
    from ..stages.products import deliver as deliver_action

    bad = [p for p in products if Path(p).suffix.lower() not in (".tif", ".tiff", ".geojson", ".json", ".gpkg")]
    if bad:
        raise click.BadParameter(f"{bad[0]}: give .tif, .geojson or .gpkg products", param_hint="PRODUCT")
    with atomic_dir(Path(outdir)) as tmp:
        written = deliver_action(tmp, formats, products=[Path(p) for p in products], crs=crs, shp_folder="",
                                 dxf_name="products.dxf")["files"]
    if as_json:
        echo_json({"files": written})
    else:
        click.echo(f"wrote {len(written)} file(s) to {outdir}")
