"""``lidarcat lidar ground|dtm|dsm|contours|hypsometry|sheets|check``: the LiDAR production chain (report 7.1, 11)."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from .options import (NON_NEGATIVE, POSITIVE, FiniteRange, crs_option, echo_json, json_option, output_option,
                      progress_bar, tile_sources)
from .options import scheduler_option as _scheduler_opt
from .options import workers_option as _workers_opt

__all__ = ["ground", "dtm", "dsm", "stats", "copc", "contours_cmd", "hypsometry", "sheets", "check", "PRODUCT_COMMANDS"]

_resume_opt = click.option(
    "--resume/--no-resume", default=True, show_default=True,
    help="Skip tiles whose output and <output>.done.json marker match the inputs and parameters.")
_overlap_opt = click.option(
    "--overlap-m", type=NON_NEGATIVE, default=None, metavar="M",
    help="Points of neighbouring tiles read around each tile, metres, so that seams do not show "
         "(default: two seed windows / two opening windows for ground, 50 m for rasters).")


@click.command()
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT",
              help="One TILE and OUT ending in .las/.laz: that file. Otherwise a folder receiving a "
                   "classified copy of every tile under its own name. Inputs are never modified.")
@click.option("--method", type=click.Choice(["smrf", "ptd", "csf"]), default="smrf", show_default=True,
              help="smrf: simple morphological filter (Pingel et al. 2013; 2.6-2.9 % total error on the "
                   "AHN3 tiles; cell and outlier test follow the point spacing). ptd: progressive TIN "
                   "densification as TerraScan does it (report 11.2). csf: cloth simulation filter "
                   "(Zhang et al. 2016; flat and urban ground, not steep slopes).")
@click.option("--noise", is_flag=True,
              help="Class 7 on isolated points (statistical outlier test, PDAL's defaults: 8 neighbours, "
                   "2 sd), left out of the ground filter.")
@click.option("--hag", is_flag=True,
              help="Write each point's height above the ground TIN as the extra dimension HeightAboveGround.")
@click.option("--copc", is_flag=True,
              help="Write the classified copies as COPC (LAZ 1.4 octree, <tile>.copc.laz in a folder OUT; one "
                   "TILE and OUT ending in .laz: that file).")
@click.option("--max-building-m", type=POSITIVE, default=60.0, show_default=True,
              help="PTD: size of the largest building, metres: one seed (the lowest last return) per "
                   "window of this size.")
@click.option("--iteration-angle-deg", type=FiniteRange(0, 90, min_open=True, max_open=True), default=6.0,
              show_default=True,
              help="PTD: largest angle between a triangle's plane and the line from a point to the "
                   "triangle's nearest vertex, degrees (raise on steep terrain, lower on flat).")
@click.option("--iteration-distance-m", type=POSITIVE, default=1.4, show_default=True,
              help="PTD: largest distance of a point from the triangle's plane, metres.")
@click.option("--window-m", type=POSITIVE, default=40.0, show_default=True,
              help="SMRF: largest object (opening radius), metres. 40 m keeps the inside of 40-60 m "
                   "flat roofs out of the ground; 18 m (Pingel's ISPRS value) classified them as ground.")
@click.option("--slope", type=POSITIVE, default=0.15, show_default=True,
              help="SMRF: terrain slope allowed (rise/run).")
@click.option("--elevation-threshold-m", type=POSITIVE, default=0.5, show_default=True,
              help="SMRF: height above the provisional DTM still counted as ground, metres.")
@click.option("--adaptive/--fixed-grid", default=True, show_default=True,
              help="SMRF: grow the cell to the point spacing and continue the terrain's trend beyond the "
                   "edge (sparse points), or keep Pingel's fixed grid (on terraced, cliffy ground at "
                   "0.1-0.3 pts/m2 the fixed grid measured better: docs/production.md).")
@_overlap_opt
@crs_option()
@_workers_opt
@_scheduler_opt
@_resume_opt
def ground(paths: tuple[str, ...], output: str, method: str, noise: bool, hag: bool, copc: bool,
           max_building_m: float,
           iteration_angle_deg: float, adaptive: bool,
           iteration_distance_m: float, window_m: float, slope: float, elevation_threshold_m: float,
           overlap_m: float | None, crs: str | None, workers: int | None, scheduler: str | None,
           resume: bool) -> None:
    """Classify ground (class 2) into LAS/LAZ copies; other classes are kept.

    Only last (or only) returns can be ground; isolated low outliers are set
    aside first. The filter never reads the input's classes. Each tile is
    classified with the points of its neighbours within --overlap-m.

    \b
    Examples:
      lidarcat lidar ground tile.laz -o tile_ground.laz --crs EPSG:7415
      lidarcat lidar ground 'tiles/*.laz' -o classified/ --workers 4
      lidarcat lidar ground tiles/ -o classified/ --method ptd --max-building-m 80
      lidarcat lidar ground tiles/ -o classified/ --noise --hag
      lidarcat lidar ground tiles/ -o classified/ --copc
    """
    from ..stages import lidar as actions

    p = actions.ground_parameters(method, max_building_m=max_building_m, iteration_angle_deg=iteration_angle_deg,
                                  iteration_distance_m=iteration_distance_m, window_m=window_m, slope=slope,
                                  elevation_threshold_m=elevation_threshold_m,
                                  adaptive=adaptive if method == "smrf" else None)
    files, crs, _ = tile_sources(paths, crs)
    with progress_bar(len(files), "ground tiles") as bar:
        outs = actions.ground(files, output, crs=crs, method=method, params=p, noise=noise, hag=hag, copc=copc,
                              overlap_m=overlap_m,
                              workers=workers, scheduler=scheduler, resume=resume,
                              progress=bar.update if bar is not None else None)
    click.echo(f"wrote {len(outs)} classified file(s): {outs[0] if len(outs) == 1 else Path(output)}")


_vrt_opt = click.option(
    "--vrt/--no-vrt", default=False, show_default=True,
    help="Folder OUT: also write OUT/mosaic.vrt, one virtual raster over the tile GeoTIFFs (GDAL VRT).")


def _raster_command(kind: str, doc: str) -> click.Command:
    @click.command(name=kind, help=doc)
    @click.argument("paths", nargs=-1, required=True, metavar="TILE...")
    @output_option(required=True, metavar="OUT",
                  help="OUT ending in .tif: one GeoTIFF over all the TILEs (computed tile by tile, "
                       "mosaicked). Otherwise a folder receiving <tile>.tif per tile (grids snapped to the "
                       "cell, so they mosaic).")
    @click.option("--cell-m", type=POSITIVE, default=1.0, show_default=True, help="Cell size, metres.")
    @click.option("--max-edge-m", type=POSITIVE, default=50.0, show_default=True,
                  help="TIN triangles with a longer edge are gaps (NaN, counted in the log), metres.")
    @click.option("--text", is_flag=True,
                  help="Also write the report's text grid (E N H per cell centre) as <output>.txt.")
    @click.option("--hillshade", is_flag=True, help="Also write <output>_hillshade.tif (sun NW, 45 deg).")
    @click.option("--ndsm", is_flag=True, help="dsm: also write <output>_ndsm.tif (DSM - DTM, needs class 2).")
    @click.option("--bounds", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
                  help="Grid only this area, metres (default: each tile's points).")
    @click.option("--max-cells", type=click.IntRange(1), default=None, metavar="N",
                  help="Largest grid, cells (default 100,000,000); a larger one is refused.")
    @click.option("--overlap-m", type=NON_NEGATIVE, default=50.0, show_default=True, metavar="M",
                  help="Points of neighbouring tiles read around each tile, metres.")
    @_vrt_opt
    @crs_option()
    @_workers_opt
    @_scheduler_opt
    @_resume_opt
    def cmd(paths: tuple[str, ...], output: str, cell_m: float, max_edge_m: float, text: bool, hillshade: bool,
            ndsm: bool, bounds: tuple[float, ...] | None, max_cells: int | None, overlap_m: float, vrt: bool,
            crs: str | None, workers: int | None, scheduler: str | None, resume: bool) -> None:
        from ..stages.lidar import terrain_model

        files, crs, _ = tile_sources(paths, crs)
        with progress_bar(len(files), f"{kind} tiles") as bar:
            outs = terrain_model(kind, files, output, crs=crs, cell_m=cell_m, max_edge_m=max_edge_m, text=text,
                                 hillshade=hillshade, ndsm=ndsm, overlap_m=overlap_m, workers=workers,
                                 scheduler=scheduler, resume=resume, bounds=bounds or None, max_cells=max_cells,
                                 progress=bar.update if bar is not None else None, vrt=vrt)
        click.echo(f"wrote {len(outs)} {kind.upper()} GeoTIFF(s): {outs[0] if len(outs) == 1 else Path(output)}")
    return cmd


dtm = _raster_command("dtm", """Terrain model (DTM): TIN of the ground points (class 2) sampled at cell centres.

Gaps (no ground, or triangles longer than --max-edge-m) stay NaN and are
reported, not invented. Classify first with 'lidarcat lidar ground'.

\b
Examples:
  lidarcat lidar dtm classified/tile.laz -o dtm.tif --crs EPSG:7415 --text
  lidarcat lidar dtm 'classified/*.laz' -o dtm/ --cell-m 0.5 --workers 2
  lidarcat lidar dtm 'classified/*.laz' -o dtm.tif --workers 2    # one GeoTIFF of all tiles
""")
dsm = _raster_command("dsm", """Surface model (DSM): highest first return per cell (small holes closed).

\b
Examples:
  lidarcat lidar dsm tile.laz -o dsm.tif --crs EPSG:7415 --hillshade
  lidarcat lidar dsm 'classified/*.laz' -o dsm/ --ndsm
""")


@click.command(name="contours")
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT.geojson|OUT.gpkg",
              help="OUT.geojson: contour lines, spot heights in OUT_spots.geojson. OUT.gpkg: one "
                   "GeoPackage with the layers contours and spot_heights (needs lidarcat[gis]). CRS set.")
@click.option("--interval-m", type=POSITIVE, default=1.0, show_default=True,
              help="Contour interval (equidistance), metres; the report used 1 m.")
@click.option("--master-every", type=click.IntRange(1), default=5, show_default=True,
              help="Every N-th level is a master (index) curve, the others intermediate.")
@click.option("--smooth", type=click.IntRange(0), default=0, show_default=True,
              help="Chaikin corner-cutting passes (0: vertices exactly on the TIN).")
@click.option("--max-edge-m", type=POSITIVE, default=50.0, show_default=True,
              help="TIN triangles with a longer edge are gaps: no contour there, metres.")
@click.option("--spots-m", type=POSITIVE, default=100.0, show_default=True,
              help="Spot heights: highest and lowest ground point per square of this size, metres.")
@click.option("--levels", default=None, metavar="H1,H2,...",
              help="Fixed contour levels, metres, comma-separated (instead of every --interval-m).")
@click.option("--min-ring-m", type=NON_NEGATIVE, default=0.0, show_default=True,
              help="Leave out closed rings shorter than this, metres (noise of the ground points).")
@click.option("--edge-peel", type=click.IntRange(0), default=3, show_default=True,
              help="Rings of triangles at the boundary of the ground TIN left out: the Delaunay slivers "
                   "there make contours run along the edge (0: keep them).")
@click.option("--review", is_flag=True,
              help="Contour verification (report 13.2): flag the stretches over sparse ground (long TIN edges, "
                   "e.g. dense vegetation) as the layer 'review' (OUT_review.geojson or a layer of OUT.gpkg).")
@click.option("--sparse-edge-m", type=POSITIVE, default=None, metavar="M",
              help="--review: a TIN edge longer than this is sparse ground (default 3 x the median edge).")
@click.option("--review-min-m", type=NON_NEGATIVE, default=0.0, show_default=True,
              help="--review: shorter stretches are not flagged, metres.")
@click.option("--profiles", type=click.IntRange(0), default=0, show_default=True, metavar="N",
              help="--review: profile plots (PNG) across the N longest stretches, in OUT_profiles/.")
@click.option("--polygons", is_flag=True,
              help="Also the filled bands between the levels (MultiPolygons; OUT_bands.geojson or a layer).")
@click.option("--3d", "three_d", is_flag=True, help="Contour lines with the level as z (LineString Z).")
@crs_option()
def contours_cmd(paths: tuple[str, ...], output: str, interval_m: float, master_every: int, smooth: int,
                 max_edge_m: float, spots_m: float, levels: str | None, min_ring_m: float, edge_peel: int,
                 review: bool, sparse_edge_m: float | None, review_min_m: float, profiles: int, polygons: bool,
                 three_d: bool, crs: str | None) -> None:
    """Contour lines from the TIN of the ground points (class 2), with spot heights; or of a DTM GeoTIFF.

    One TILE ending in .tif is a gridded DTM: its cells are contoured (no spot heights).

    \b
    Examples:
      lidarcat lidar contours classified/tile.laz -o curvas.geojson --crs EPSG:7415
      lidarcat lidar contours classified/ -o curvas.geojson --interval-m 0.5 --master-every 10
      lidarcat lidar contours classified/ -o curvas.gpkg --min-ring-m 5
      lidarcat lidar contours dtm.tif -o curvas.geojson --levels 10,12.5,15
    """
    import numpy as np

    from ..lidar import read_points
    from ..lidar.cloud import PointCloud
    from ..production.contours import CONTOUR_FORMATS, contours, spot_heights, write_contours

    if Path(output).suffix.lower() not in CONTOUR_FORMATS:
        raise click.BadParameter(f"{output}: give a file ending in {', '.join(CONTOUR_FORMATS)}",
                                 param_hint="-o/--output")
    try:
        fixed = None if levels is None else [float(v) for v in levels.split(",") if v.strip()]
    except ValueError:
        raise click.BadParameter(f"{levels!r}: give numbers separated by commas", param_hint="--levels") from None
    if fixed is not None and not (fixed and np.isfinite(fixed).all()):
        raise click.BadParameter(f"{levels!r}: give finite numbers separated by commas", param_hint="--levels")
    if len(paths) == 1 and Path(paths[0]).suffix.lower() in (".tif", ".tiff"):
        from ..lidar.crs import resolve_crs
        from ..lidar.geotiff import read_geotiff
        from ..production.contours import raster_contours

        if review or polygons:
            raise click.UsageError("--review and --polygons need the ground points (a LAS/LAZ tile), not a DTM "
                                   "raster")
        grid, t, gcrs = read_geotiff(paths[0])
        if grid.ndim != 2:
            raise click.BadParameter(f"{paths[0]}: a DTM has one band, this has {grid.shape[2]}", param_hint="TILE")
        cs = raster_contours(grid, t, interval_m, master_every=master_every, levels=fixed, min_ring_m=min_ring_m,
                             smooth_iterations=smooth)
        written = write_contours(output, cs, np.zeros((0, 4)), resolve_crs(crs) or gcrs)
        click.echo(f"wrote {len(cs)} contour lines of {paths[0]} to {' and '.join(map(str, written))}")
        return
    files, crs, _ = tile_sources(paths, crs)
    clouds = [read_points(f, crs=crs) for f in files]
    pc = PointCloud.concat(clouds)
    if not pc.has("classification") or not np.any(pc.attributes["classification"] == 2):
        raise click.UsageError("no ground points (class 2); classify first with 'lidarcat lidar ground'")
    g = pc.xyz[np.asarray(pc.attributes["classification"]) == 2]
    cs = contours(g, interval_m, master_every=master_every, max_edge_m=max_edge_m, smooth_iterations=smooth,
                  levels=fixed, min_ring_m=min_ring_m, edge_peel=edge_peel)
    spots = spot_heights(g, spots_m)
    if not (review or polygons or three_d):
        written = write_contours(output, cs, spots, pc.crs)
        click.echo(f"wrote {len(cs)} contour lines and the spot heights to {' and '.join(map(str, written))}")
        return
    from ..production.contourcheck import contour_features_3d
    from ..production.contours import contour_features, spot_features, write_layers
    from ..stages.lidar import contour_extras

    cls = np.asarray(pc.attributes["classification"])
    extra = contour_extras(output, cs, g, pc.crs, points_xyz=pc.xyz, ground_mask=cls == 2, review=review,
                           sparse_edge_m=sparse_edge_m, review_min_m=review_min_m, profiles=profiles,
                           polygons=polygons, band_kw={"interval_m": interval_m, "max_edge_m": max_edge_m,
                                                       "levels": fixed, "edge_peel": edge_peel})
    feats = contour_features_3d(cs) if three_d else contour_features(cs)
    out = Path(output)
    if out.suffix.lower() == ".gpkg":
        written = [write_layers(out, {"contours": feats, "spot_heights": spot_features(spots),
                                      **{k: v for k, v in extra.get("layers", {}).items() if v}}, pc.crs)]
    else:
        written = [write_layers(out, {"contours": feats}, pc.crs),
                   write_layers(out.with_name(out.stem + "_spots" + out.suffix), {"spots": spot_features(spots)},
                                pc.crs)]
    click.echo(f"wrote {len(cs)} contour lines{' (3-D)' if three_d else ''} and the spot heights to "
               f"{' and '.join(map(str, written))}")
    if "review" in extra:
        r = extra["review"]
        click.echo(f"review: {r['stretches']} stretches over sparse ground (TIN edges above "
                   f"{r['sparse_edge_m']:.2f} m), {r['length_m']:.1f} m of contour")
    if "bands" in extra:
        click.echo(f"{extra['bands']} filled bands")
    for f in extra["files"]:
        click.echo(f"written {f}")


def _colour_map(name: str) -> str:
    import matplotlib

    if name not in matplotlib.colormaps:
        raise click.BadParameter(f"{name!r} is not a matplotlib colour map (e.g. terrain, gist_earth, viridis)")
    return name


@click.command()
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT.tif",
              help="RGB GeoTIFF (and OUT.png) of the area of all TILEs.")
@click.option("--cell-m", type=POSITIVE, default=0.45, show_default=True,
              help="Cell size, metres (the report: 45 cm, the photos' ground sample).")
@click.option("--h-min-m", type=float, default=None, help="Height of the first colour, metres (default 2nd percentile).")
@click.option("--h-max-m", type=float, default=None, help="Height of the last colour, metres (default 98th percentile).")
@click.option("--cmap", default="terrain", show_default=True, callback=lambda ctx, param, v: _colour_map(v),
              help="matplotlib colour map.")
@crs_option()
def hypsometry(paths: tuple[str, ...], output: str, cell_m: float, h_min_m: float | None, h_max_m: float | None,
               cmap: str, crs: str | None) -> None:
    """Hypsometric image: DSM heights as colours, shaded by the laser intensity (report 11.4).

    \b
    Examples:
      lidarcat lidar hypsometry tile.laz -o hipso.tif --crs EPSG:7415
      lidarcat lidar hypsometry tiles/ -o hipso.tif --h-min-m 60 --h-max-m 460
    """
    import matplotlib.image

    from ..lidar import read_points, rasterize
    from ..lidar.cloud import PointCloud
    from ..production.terrain import hypsometric_image, write_product

    out = Path(output)
    if out.suffix.lower() not in (".tif", ".tiff"):
        # the PNG goes beside OUT.tif: any other name would be overwritten by it (or hold a GeoTIFF)
        raise click.BadParameter(f"{output}: give a .tif name (the .png is written beside it)",
                                 param_hint="'-o' / '--output'")
    files, crs, _ = tile_sources(paths, crs)
    pc = PointCloud.concat([read_points(f, crs=crs) for f in files])
    h, t = rasterize(pc, cell_m, "dsm")
    inten, _ = rasterize(pc, cell_m, "intensity") if pc.has("intensity") else (None, None)
    img = hypsometric_image(h, inten, h_min_m, h_max_m, cmap=cmap)
    write_product(out, img, t, pc.crs)
    from .._util import atomic_write

    with atomic_write(out.with_suffix(".png"), "wb") as fh:
        matplotlib.image.imsave(fh, img, format="png")
    click.echo(f"wrote {out} and {out.with_suffix('.png')} ({img.shape[1]} x {img.shape[0]} cells of {cell_m:g} m)")


#: commands added to the ``lidar`` group
@click.command(name="stats")
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT",
              help="OUT ending in .tif: one five-band GeoTIFF over all the TILEs. Otherwise a folder "
                   "receiving <tile>.tif per tile (and mosaic.vrt over them, unless --no-vrt).")
@click.option("--cell-m", type=POSITIVE, default=1.0, show_default=True, help="Cell size, metres.")
@click.option("--values", default="z", show_default=True, metavar="z|ATTRIBUTE",
              help="Statistics of the heights (z) or of a point attribute such as intensity.")
@click.option("--classes", default=None, metavar="C1,C2,...",
              help="Only points of these classes (default: all but noise, class 7).")
@click.option("--bounds", nargs=4, type=float, default=None, metavar="XMIN YMIN XMAX YMAX",
              help="Grid only this area, metres (default: each tile's points).")
@click.option("--max-cells", type=click.IntRange(1), default=None, metavar="N",
              help="Largest grid, cells (default 100,000,000); a larger one is refused.")
@click.option("--vrt/--no-vrt", default=True, show_default=True,
              help="Folder OUT: also write OUT/mosaic.vrt over the tile GeoTIFFs.")
@crs_option()
@_workers_opt
@_scheduler_opt
@_resume_opt
def stats(paths: tuple[str, ...], output: str, cell_m: float, values: str, classes: str | None,
          bounds: tuple[float, ...] | None, max_cells: int | None, vrt: bool, crs: str | None,
          workers: int | None, scheduler: str | None, resume: bool) -> None:
    """Point statistics per cell: min, max, mean, count and stdev bands (named), CRS set.

    \b
    Examples:
      lidarcat lidar stats tile.laz -o stats.tif --crs EPSG:7415 --cell-m 2
      lidarcat lidar stats 'tiles/*.laz' -o stats/ --values intensity
      lidarcat lidar stats 'classified/*.laz' -o ground_stats.tif --classes 2
    """
    from ..stages.lidar import statistics_raster

    try:
        cls = None if classes is None else [int(c) for c in classes.split(",") if c.strip()]
    except ValueError:
        raise click.BadParameter(f"{classes!r} is not a comma-separated list of class codes",
                                 param_hint="--classes") from None
    files, crs, _ = tile_sources(paths, crs)
    with progress_bar(len(files), "stats tiles") as bar:
        outs = statistics_raster(files, output, crs=crs, cell_m=cell_m, values=values, classes=cls, vrt=vrt,
                                 workers=workers, scheduler=scheduler, resume=resume, bounds=bounds or None,
                                 max_cells=max_cells, progress=bar.update if bar is not None else None)
    click.echo(f"wrote {len(outs)} file(s): {outs[0] if len(outs) == 1 else outs[-1]}")


@click.command(name="copc")
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@output_option(required=True, metavar="OUT",
              help="One TILE and OUT ending in .laz: that COPC file. Otherwise a folder receiving "
                   "<tile>.copc.laz per tile. Inputs are never modified.")
@click.option("--max-points", type=click.IntRange(1), default=100_000, show_default=True,
              help="Largest number of points in a leaf node of the octree.")
@crs_option()
def copc(paths: tuple[str, ...], output: str, max_points: int, crs: str | None) -> None:
    """Write LAS/LAZ tiles as COPC (Cloud Optimized Point Cloud, COPC 1.0): an octree of LAZ chunks.

    Every point and field is kept; point formats 0-5 become 6, 7 or 8 (LAS 1.4).
    The CRS is the tile's own or --crs (written as WKT).

    \b
    Examples:
      lidarcat lidar copc tile.laz -o tile.copc.laz --crs EPSG:7415
      lidarcat lidar copc 'classified/*.laz' -o copc/
    """
    from ..lidar.copc_write import write_copc

    files, crs, _ = tile_sources(paths, crs)
    out = Path(output)
    if len(files) == 1 and out.suffix.lower() == ".laz":
        targets = [out]
    else:
        targets = [out / (Path(f).name.split(".")[0] + ".copc.laz") for f in files]
    with progress_bar(len(files), "copc tiles") as bar:
        for f, t in zip(files, targets):
            if Path(f).resolve() == t.resolve():
                raise click.BadParameter(f"{t}: the output would overwrite the input", param_hint="-o/--output")
            write_copc(f, t, crs=crs, max_points=max_points)
            if bar is not None:
                bar.update(1)
    click.echo(f"wrote {len(targets)} COPC file(s): {targets[0] if len(targets) == 1 else out}")


PRODUCT_COMMANDS = [ground, dtm, dsm, stats, copc, contours_cmd, hypsometry]


def _sheet_index_choice() -> click.Choice:
    from ..production.sheets import SHEET_INDEXES

    return click.Choice(list(SHEET_INDEXES))


@click.command()
@click.argument("products", nargs=-1, required=True, metavar="PRODUCT...")
@output_option(required=True, metavar="FOLDER",
              help="Receives <sheet>/<product> for every sheet holding data, and sheets.geojson (the index).")
@click.option("--index", "index", type=_sheet_index_choice(), default="grid", show_default=True,
              help="grid: a regular grid of --size-m in the products' CRS, sheets named E<east>_N<north>. "
                   "brazil-5000, brazil-2000 (also brazil-10000, brazil-25000): the Brazilian systematic map "
                   "index (Cartografia Sistematica), sheets such as SF-23-X-D-VI-1-SE-C-II (1:5,000), "
                   "geographic rectangles in the datum of the CRS, cut in that frame.")
@click.option("--size-m", type=POSITIVE, default=1000.0, show_default=True,
              help="grid: sheet width (and height, unless --height-m), metres; sheets are aligned to "
                   "multiples of it.")
@click.option("--height-m", type=POSITIVE, default=None, help="grid: sheet height, metres (default: --size-m).")
@crs_option(help="CRS of the products and the index layer (default: the first product's); the Brazilian "
                   "index needs it, e.g. EPSG:31983 (SIRGAS 2000 / UTM zone 23S).")
@click.option("--geographic-crs", default=None, metavar="CRS",
              help="brazil-*: the geographic frame of the sheets (default: the datum of --crs, e.g. "
                   "SIRGAS 2000 for EPSG:31983).")
@click.option("--layer-format", type=click.Choice(["geojson", "gpkg"]), default="geojson", show_default=True,
              help="Format of the index layer (sheets.geojson / sheets.gpkg) and of the contours cut per sheet; "
                   "gpkg needs lidarcat[gis].")
def sheets(products: tuple[str, ...], output: str, index: str, size_m: float, height_m: float | None,
           crs: str | None, geographic_crs: str | None, layer_format: str) -> None:
    """Cut GeoTIFF products (.tif) and contour lines (.geojson, .gpkg) along a sheet index.

    The sheet index layer (one polygon per sheet holding data, with its
    name; a Brazilian sheet as its outline densified in the products' CRS)
    is written as FOLDER/sheets.geojson (or .gpkg).

    \b
    Examples:
      lidarcat lidar sheets dtm.tif dsm.tif curvas.geojson -o folhas/ --size-m 500
      lidarcat lidar sheets dtm.tif curvas.geojson -o folhas/ --index brazil-5000 --crs EPSG:31983
      lidarcat lidar sheets dtm.tif curvas.gpkg -o folhas/ --index brazil-2000 --layer-format gpkg
    """
    from .._util import atomic_dir
    from ..errors import FormatError, LidarcatError, ProductError
    from ..lidar.geotiff import read_geotiff
    from ..production.contours import read_line_layer, write_layers
    from ..production.sheets import cut_contours, cut_raster, index_sheets, sheet_index_features
    from ..production.terrain import write_product

    rasters, vectors = [], []
    lo = [np.inf, np.inf]
    hi = [-np.inf, -np.inf]
    edge = ["", "", "", ""]   # the product (and feature) that sets the west, south, east, north edge
    for p in map(Path, products):
        if p.suffix.lower() in (".tif", ".tiff"):
            try:
                arr, t, rcrs = read_geotiff(p, raw=True)   # cut and written back as stored
            except LidarcatError as ex:
                raise FormatError(f"{p}: not a readable GeoTIFF ({ex})") from ex
            crs = crs or (rcrs.to_wkt() if rcrs is not None else None)
            b = (t.x0, t.y0 - arr.shape[0] * t.cell_m, t.x0 + arr.shape[1] * t.cell_m, t.y0)
            rasters.append((p, arr, t))
        elif p.suffix.lower() in (".geojson", ".json", ".gpkg"):
            feats, vcrs = read_line_layer(p)
            crs = crs or (vcrs.to_wkt() if vcrs is not None else None)
            vectors.append((p, feats))
            if not feats:
                continue
            fb = np.array([[*c.min(axis=0), *c.max(axis=0)] for c in
                           (np.asarray(f["geometry"]["coordinates"], dtype=float) for f in feats)])
            k = [int(np.argmin(fb[:, 0])), int(np.argmin(fb[:, 1])), int(np.argmax(fb[:, 2])),
                 int(np.argmax(fb[:, 3]))]
            b = (fb[k[0], 0], fb[k[1], 1], fb[k[2], 2], fb[k[3], 3])
            where = [f"{p}: feature {i}" for i in k]
        else:
            raise click.BadParameter(f"{p}: give .tif, .geojson or .gpkg products", param_hint="PRODUCT")
        if p.suffix.lower() in (".tif", ".tiff"):
            where = [str(p)] * 4
        for i, (old, new, better) in enumerate(zip(lo + hi, b, (np.less, np.less, np.greater, np.greater))):
            if better(new, old):
                edge[i] = where[i]
        lo = [min(lo[0], b[0]), min(lo[1], b[1])]
        hi = [max(hi[0], b[2]), max(hi[1], b[3])]
    if not np.isfinite(lo + hi).all():
        raise click.UsageError("the products hold no data (no raster, no line): nothing to cut")
    if index != "grid" and crs is None:
        raise click.UsageError(f"--index {index} needs the products' CRS: give --crs (e.g. EPSG:31983)")
    try:
        grid = index_sheets((lo[0], lo[1], hi[0], hi[1]), index, crs=crs, size_m=size_m, height_m=height_m,
                            geographic_crs=geographic_crs)
    except ValueError as ex:  # a bad --size-m / --height-m, or products outside the index in that --crs
        if isinstance(ex, LidarcatError) and "sheets of" in str(ex):   # too many: name who stretches the area
            by: dict[str, list[str]] = {}
            for side, w in zip(("west", "south", "east", "north"), edge):
                by.setdefault(w, []).append(side)
            sides = "; ".join(f"{' and '.join(v)} edge{'s' if len(v) > 1 else ''} from {w}" for w, v in by.items())
            raise ProductError(f"{ex} (the area's {sides})") from ex
        if isinstance(ex, LidarcatError):   # a data condition: one Error line (issue 24), not a usage text
            raise
        raise click.UsageError(str(ex)) from ex
    out = Path(output)
    ext = "." + layer_format
    used = []
    # the sheets and the index are built in a temporary sibling and moved in once all are written
    with atomic_dir(out) as tmp, progress_bar(len(grid), "sheets") as bar:
        for s in grid:
            wrote = False
            for p, arr, t in rasters:
                cut = cut_raster(arr, t, s, crs)
                if cut is not None and np.isfinite(cut[0].astype(float)).any():
                    write_product(tmp / s.name / p.name, cut[0], cut[1], crs)
                    wrote = True
            for p, feats in vectors:
                part = cut_contours([f for f in feats if f["geometry"]["type"] == "LineString"], s, crs)
                if part:
                    write_layers(tmp / s.name / (p.stem + ext), {"contours": part}, crs)
                    wrote = True
            if wrote:
                used.append(s)
            if bar is not None:
                bar.update(1)
        write_layers(tmp / ("sheets" + ext), {"sheets": sheet_index_features(used, crs)}, crs)
    what = f"of {size_m:g} m" if index == "grid" else f"of the {index} index"
    click.echo(f"wrote {len(used)} sheets {what} and the index {out / ('sheets' + ext)}")


PRODUCT_COMMANDS.append(sheets)


@click.command(name="check")
@click.argument("paths", nargs=-1, required=True, metavar="TILE...")
@click.option("--checkpoints", default=None, type=click.Path(exists=True, dir_okay=False), metavar="CSV",
              help="Surveyed check points: id,E,N,H[,vegetated] (metres, CRS of the tiles; vegetated 1/0, "
                   "default 0 = hard, open surface).")
@click.option("--outlines", default=None, type=click.Path(exists=True, dir_okay=False), metavar="FILE",
              help="Surveyed building outlines (polygons: .gpkg/.shp/.geojson, CRS of the tiles): planimetric "
                   "check of the LiDAR corners, OUT_planimetric.json and OUT_corners.csv (lidarcat[gis]).")
@click.option("--roof-classes", default="6", show_default=True, metavar="C1,C2",
              help="--outlines: classes of the roof points (without them: points 2 m above the local ground).")
@output_option(required=True, metavar="OUT.json",
               help="The report (JSON); the per-point discrepancies go beside it as OUT.csv.")
@click.option("--method", type=click.Choice(["tin", "plane"]), default="tin", show_default=True,
              help="LiDAR height at a check point: linear in the TIN of the points, or a plane fitted to "
                   "the points within --radius-m.")
@click.option("--radius-m", type=POSITIVE, default=1.0, show_default=True,
              help="Plane method: radius of the points fitted, metres.")
@click.option("--classes", default="2", show_default=True, metavar="C1,C2|all",
              help="Point classes used (ground = 2); 'all': every last return.")
@click.option("--checkpoint-sd-m", type=NON_NEGATIVE, default=None, metavar="M",
              help="Vertical sd of the check-point survey (ASPRS 2023 product accuracy includes it).")
@click.option("--scale", type=POSITIVE, default=None, metavar="DENOMINATOR",
              help="Map scale for the PEC altimetric class (e.g. 5000; with --contour-interval-m).")
@click.option("--contour-interval-m", type=POSITIVE, default=None, metavar="M",
              help="Contour interval for the PEC altimetric class, metres.")
@crs_option()
@json_option()
def check(paths: tuple[str, ...], checkpoints: str | None, outlines: str | None, roof_classes: str, output: str,
          method: str, radius_m: float, classes: str, checkpoint_sd_m: float | None, scale: float | None,
          contour_interval_m: float | None, crs: str | None, as_json: bool) -> None:
    """Vertical and planimetric accuracy of LiDAR tiles (LACTEC report 7.1.1).

    With --checkpoints: ASPRS 2023 NVA (RMSE_z of the non-vegetated points,
    and 1.96 RMSE_z), VVA (RMSE_z and 95th percentile of the vegetated
    points), the ASPRS 2023 vertical class and, with --scale and
    --contour-interval-m, the PEC altimetric class.  With --outlines: the
    building corners found from the LiDAR roof edges against the surveyed
    ones, ASPRS 2023 horizontal RMSE and, with --scale, the PEC planimetric class.
    """
    from ..stages.lidar import planimetric_check, vertical_check

    if checkpoints is None and outlines is None:
        raise click.UsageError("give --checkpoints (vertical check), --outlines (planimetric check) or both")
    if outlines is not None:
        try:
            rc = [int(c) for c in roof_classes.split(",") if c.strip()]
        except ValueError:
            raise click.BadParameter(f"{roof_classes!r} is not a comma-separated list of integers",
                                     param_hint="--roof-classes") from None
        files, tcrs, _ = tile_sources(paths, crs)
        plan = planimetric_check(files, outlines, output, crs=tcrs, roof_classes=rc,
                                 checkpoint_sd_m=checkpoint_sd_m, scale=scale)
        if checkpoints is None:
            if as_json:
                echo_json(plan)
                return
            _echo_planimetric(plan)
            return

    if classes.strip().lower() == "all":
        cls = None
    else:
        try:
            cls = [int(c) for c in classes.split(",") if c.strip()]
        except ValueError:
            raise click.BadParameter(f"{classes!r} is not a comma-separated list of integers or 'all'",
                                     param_hint="--classes") from None
    report = vertical_check(paths, checkpoints, output, crs=crs, classes=cls, method=method, radius_m=radius_m,
                            checkpoint_sd_m=checkpoint_sd_m, scale=scale, contour_interval_m=contour_interval_m)
    if outlines is not None:
        report = {**report, "planimetric_report": plan}
    if as_json:
        echo_json(report)
        return
    if outlines is not None:
        _echo_planimetric(plan)
    a = report["accuracy"]
    click.echo(f"{a['n_nonveg']} non-vegetated check points: NVA RMSE_z {a['nva_rmse_m']:.3f} m, "
               f"95 % {a['nva_95_m']:.3f} m, mean {a['mean_nonveg_m']:+.3f} m")
    if a["n_veg"]:
        click.echo(f"{a['n_veg']} vegetated check points: VVA RMSE_z {a['vva_rmse_m']:.3f} m, "
                   f"95th percentile {a['vva_95th_percentile_m']:.3f} m")
    click.echo(f"ASPRS 2023: {a['asprs2023']['label']}")
    if a["pec"] is not None:
        click.echo(f"PEC altimetric class: {a['pec']['class']['altimetric']}")
    for p in report["files"]:
        click.echo(f"written {p}")


def _echo_planimetric(plan: dict) -> None:
    a = plan["planimetric"]
    click.echo(f"{a['n_corners']} building corners ({a['n_missing']} not found): RMSE_x {a['rmse_x_m']:.3f} m, "
               f"RMSE_y {a['rmse_y_m']:.3f} m, RMSE_r {a['rmse_r_m']:.3f} m, mean dE {a['mean_dE_m']:+.3f} m, "
               f"dN {a['mean_dN_m']:+.3f} m")
    click.echo(f"ASPRS 2023 horizontal class: {a['asprs2023']['class']['planimetric']}")
    if a["pec"] is not None:
        click.echo(f"PEC planimetric class: {a['pec']['class']['planimetric']}")
    for p in plan["files"]:
        click.echo(f"written {p}")


PRODUCT_COMMANDS.append(check)
