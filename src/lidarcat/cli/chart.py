"""``lidarcat chart``: orthophoto charts (ortofotocartas), one PDF + PNG per sheet (LACTEC report 12.4, 13.3)."""

from __future__ import annotations

import datetime
from pathlib import Path

import click

from .options import (POSITIVE, FiniteRange, crs_option, echo_json, json_opt, output_option, progress_bar,
                      scheduler_option, workers_option)

__all__ = ["chart"]


@click.command("chart")
@click.argument("mosaic", type=click.Path(exists=True, dir_okay=False), metavar="MOSAIC.tif")
@click.argument("contours", type=click.Path(exists=True, dir_okay=False), metavar="CONTOURS.geojson|.gpkg")
@output_option(outdir=True, required=True, type=click.Path(file_okay=False),
              help="Folder receiving <sheet>.pdf and <sheet>.png (created; the charts are moved in once all "
                   "are written).")
@click.option("--spots", type=click.Path(exists=True, dir_okay=False), default=None, metavar="FILE.geojson",
              help="Spot heights (Points with h_m, as `lidarcat lidar contours` writes OUT_spots.geojson).")
@click.option("--index", type=click.Choice(["grid", "brazil-25000", "brazil-10000", "brazil-5000", "brazil-2000"]),
              default="grid", show_default=True,
              help="Sheet index: a regular grid of --size-m, or the Brazilian systematic index.")
@click.option("--size-m", type=POSITIVE, default=1000.0, show_default=True, help="grid: sheet size, metres.")
@click.option("--sheet", "only", multiple=True, metavar="NAME",
              help="Chart only this sheet (repeat for more); default: every sheet holding data.")
@click.option("--scale", type=click.IntRange(1), default=5000, show_default=True,
              help="Scale denominator: the map is drawn at 1:SCALE on the page.")
@click.option("--project", default="", help="Project name in the title block (default: the mosaic's file name).")
@click.option("--declination-deg", type=FiniteRange(-180, 180), default=None, metavar="DEG",
              help="Magnetic declination, degrees, east positive (not computed; without it the title block "
                   "says 'not given').")
@click.option("--declination-date", default="", metavar="DATE", help="Date (epoch) of the declination value.")
@click.option("--date", "date", default=None, metavar="DATE", help="Date in the title block (default: today, UTC).")
@click.option("--dpi", type=click.IntRange(10, 1200), default=150, show_default=True, help="PNG resolution.")
@workers_option
@scheduler_option
@crs_option(help="CRS of the products (default: the mosaic's).")
@json_opt
def chart(mosaic: str, contours: str, outdir: str, spots: str | None, index: str, size_m: float,
          only: tuple[str, ...], scale: int, project: str, declination_deg: float | None, declination_date: str,
          date: str | None, dpi: int, workers: int | None, scheduler: str | None, crs: str | None,
          as_json: bool) -> None:
    """Orthophoto charts: the mosaic with contours, spot heights, UTM grid, legend, title block and index map.

    One printable sheet (PDF at true scale, and PNG) per sheet of the index
    holding mosaic cells or contours; master curves are labelled with their
    height. Conventions (colours, layers) of the LACTEC report's Figure 27.

    \b
    Examples:
      lidarcat chart mosaic.tif curvas.geojson --spots curvas_spots.geojson -o cartas/ --size-m 1000
      lidarcat chart mosaic.tif curvas.gpkg -o cartas/ --index brazil-5000 --declination-deg -22.3
    """
    import json

    import numpy as np

    from .._util import atomic_dir
    from ..lidar.crs import crs_label, resolve_crs
    from ..lidar.geotiff import read_geotiff
    from ..production.charts import TitleBlock
    from ..production.contours import read_line_layer
    from ..stages.products import write_charts

    feats, lcrs = read_line_layer(contours)
    c = resolve_crs(crs) or read_geotiff(mosaic)[2] or lcrs
    if c is None:
        raise click.UsageError("the mosaic carries no CRS: give --crs (e.g. EPSG:31983)")
    sp = None
    if spots is not None:
        doc = json.loads(Path(spots).read_text(encoding="utf-8"))
        pts = [(f["geometry"]["coordinates"][0], f["geometry"]["coordinates"][1], f["properties"]["h_m"])
               for f in doc.get("features", []) if (f.get("geometry") or {}).get("type") == "Point"]
        sp = np.asarray(pts, dtype=float).reshape(-1, 3)
    title = TitleBlock(project or Path(mosaic).stem, scale, crs_label(c), declination_deg, declination_date,
                       date or datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
                       _interval(feats), _master_every(feats))
    with atomic_dir(Path(outdir)) as tmp, progress_bar(len(only) or 1, "charts") as bar:
        def tick(done: int, total: int) -> None:
            bar.length = total          # the sheets holding data are known once the index is cut
            bar.update(1)

        res = write_charts(Path(mosaic), feats, sp, tmp, crs=c, title=title, index=index, size_m=size_m,
                           only=list(only) or None, dpi=dpi, workers=workers, scheduler=scheduler,
                           progress=tick if bar is not None else None)
    if as_json:
        echo_json(res)
    else:
        click.echo(f"wrote {len(res['sheets'])} chart(s) at 1:{scale:,} to {outdir}: {', '.join(res['sheets'])}")


def _levels(feats: list[dict]) -> list[float]:
    return sorted({float(f["properties"]["level_m"]) for f in feats if "level_m" in (f.get("properties") or {})})


def _interval(feats: list[dict]) -> float:
    """The contour interval: the smallest step between the levels (1 m when there is one level)."""
    lv = _levels(feats)
    steps = [round(b - a, 6) for a, b in zip(lv, lv[1:]) if b - a > 1e-9]
    return min(steps) if steps else 1.0


def _master_every(feats: list[dict]) -> int:
    """Master curves every N intervals: the smallest step between master levels over the interval."""
    m = sorted({float(f["properties"]["level_m"]) for f in feats
                if (f.get("properties") or {}).get("type") == "master"})
    steps = [b - a for a, b in zip(m, m[1:]) if b - a > 1e-9]
    return max(1, round(min(steps) / _interval(feats))) if steps else 5
