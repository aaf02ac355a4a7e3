"""Stage ``products``: the LiDAR products of the LACTEC chain, when survey.toml asks for them.

survey.toml::

    [products]
    ground = true               # classify ground (class 2) into copies of the tiles (false: use their class 2)
    filter = "smrf"             # "smrf" (simple morphological filter), "ptd" (TerraScan's TIN densification)
                                # or "csf" (cloth simulation filter)
    noise = false               # ground: class 7 on isolated points (statistical outlier test)
    hag = false                 # ground: extra dimension HeightAboveGround (m) in the classified copies
    smrf_adaptive = true        # ground (smrf): cell grown to the point spacing (false: the fixed grid)
    copc = false                # ground: the classified copies as COPC (ground/<tile>.copc.laz)
    dtm = true                  # dtm.tif: TIN of the ground sampled at cell centres (gaps stay NaN)
    dsm = true                  # dsm.tif: highest first return per cell
    ndsm = false                # ndsm.tif: DSM - DTM (needs dtm and dsm)
    stats = false               # stats.tif: min, max, mean, count, stdev of the point heights per cell (cell_m)
    hillshade = false           # <model>_hillshade.tif of each model written
    text_grid = false           # <model>.txt: the report's E N H text grid
    cell_m = 1.0                # cell of the models, m
    max_edge_m = 50.0           # TIN triangles with a longer edge are gaps, m
    contours = true             # contours.geojson (+ spot_heights.geojson) from the ground TIN
    contour_interval_m = 1.0    # equidistance, m (the report: 1 m)
    master_every = 5            # every N-th level is a master curve
    smooth = 0                  # Chaikin passes (0: vertices exactly on the TIN)
    spots_m = 100.0             # spot heights: highest and lowest ground point per square, m
    hypsometry = false          # hypsometry.png and .tif: heights coloured, shaded by intensity
    hypsometry_cell_m = 0.45    # its cell, m (the report: 45 cm)
    sheet_size_m = 0            # > 0: also cut every product along a sheet grid (sheets/, sheets.geojson)
    sheet_index = "grid"        # or "brazil-5000" / "brazil-2000" (..-10000, -25000): the Brazilian systematic
                                # map index (sheets like SF-23-X-D-VI-1-SE-C-II) instead of the grid
    vector_format = "geojson"   # or "gpkg": contours, spot heights and the sheet index as GeoPackage (lidarcat[gis])
    charts = false              # charts/<sheet>.pdf + .png: orthophoto charts (ortofotocartas) of the sheets
    chart_mosaic = "mosaic.tif" # their orthomosaic (default: the mapping stage's mosaic.tif)
    chart_scale = 5000          # 1:5,000 (the report)
    chart_declination_deg = -22.3   # magnetic declination, east positive (not computed; default "not given")
    delivery = ["tfw", "shp", "dxf"]   # world files beside the GeoTIFFs, shp/ layers, contours.dxf
    contour_levels = [10.0, 12.5]      # fixed levels instead of the interval's
    contour_min_ring_m = 5.0           # closed rings shorter than this are left out, m
    contour_edge_peel = 3              # rings of triangles at the TIN's boundary left out of the contours
    contour_review = true              # contours_review.geojson: stretches over sparse ground (report 13.2)
    contour_profiles = 5               # contours_profiles/*.png across the 5 longest of them
    contour_polygons = true            # contours_bands.geojson: filled bands between the levels
    contour_3d = true                  # contour lines with the level as z
    swath = true                       # swath.tif/.png/.json: swath separation image (USGS LBS)
    calibration_trajectory = "sbet.out"    # calibration.json: boresight, scan-angle scale (and bias with:)
    calibration_control = "runway.csv"
    workers = 2                 # ground, models, stats and charts on one local Dask cluster of 2 processes
    scheduler = "tcp://10.0.0.5:8786"  # or on a running Dask cluster (wins over workers)

Charts (:mod:`lidarcat.production.charts`): one PDF and PNG per sheet of the
index that holds mosaic cells or contours (sheets outside the data get no
chart); the orthomosaic is ``chart_mosaic`` (relative to the survey folder) or
else the ``mapping`` stage's ``mosaic.tif`` of this run; without either the
stage fails with the reason.

The stage is planned only for a survey with a ``[products]`` table (skipped,
with the reason, when the survey has no LiDAR tiles).  Ground classification
runs tile by tile with the neighbours' points within two filter windows, so the
classified copies ``ground/<tile>.laz`` do not depend on where the tiles are
cut.  The DTM, DSM and nDSM are made as ``lidarcat lidar dtm|dsm TILES -o
dtm.tif`` makes them, by the same actions (:func:`lidarcat.stages.lidar.ground`,
:func:`lidarcat.stages.lidar.terrain_model`): tile by tile with the neighbours'
points within 50 m, mosaicked into one GeoTIFF over the survey.  Contours and
the hypsometric image are made over the whole survey area in one piece
(:mod:`lidarcat.production.contours`, :mod:`lidarcat.production.terrain`).
The tile work of the stage (ground, DTM, DSM, stats and the charts, one task per
sheet) runs in the run's process by default; ``workers = N`` starts one local
Dask cluster of N worker processes for all of it (:func:`lidarcat.lidar.jobs.dask_client`)
and hands its address to every action, as ``scheduler`` hands a running
cluster's; the products are the same either way.
Everything carries the LiDAR CRS; the stage writes
into its temporary folder and the runner moves it into ``OUTDIR/products/``
only when it succeeded.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from ..survey.schema import ProductsSettings
from .context import StageContext as Context

__all__ = ["run", "settings", "PRODUCTS_KEYS", "runner", "asked", "chart_mosaic_path", "chart_sheets", "write_charts", "deliver",
           "contour_options", "contour_checks", "lidar_checks"]

#: keys of the [products] table and their defaults (lidarcat.survey.schema.ProductsSettings)
PRODUCTS_KEYS: dict[str, Any] = ProductsSettings().to_dict()


def settings(survey: Any) -> dict[str, Any]:
    """The ``[products]`` table of the survey with its defaults (``{}`` when there is none); checked by
    :meth:`lidarcat.Survey.load` (:class:`lidarcat.survey.schema.ProductsSettings`)."""
    cfg = survey.config.products
    return {} if cfg is None else cfg.to_dict()


def runner(cfg: dict[str, Any]) -> dict[str, Any]:
    """``{"workers": N or None, "scheduler": ADDRESS or None}`` of the ``[products]`` keys *cfg*, as the
    tile actions take them: ``workers = 1`` (the default) is None, the run's own process."""
    workers = cfg.get("workers") or 1
    return {"workers": workers if workers > 1 else None, "scheduler": cfg.get("scheduler")}


@contextlib.contextmanager
def _tile_runner(cfg: dict[str, Any]) -> Iterator[dict[str, Any]]:
    """The runner keywords of every tile action of one stage run: a local cluster of ``workers``
    processes is started once for all of them and handed on by its address."""
    r = runner(cfg)
    if r["workers"] is None or r["scheduler"] is not None:
        yield {"workers": None, "scheduler": r["scheduler"]}
        return
    from ..lidar.jobs import dask_client

    with dask_client(r["workers"], "processes") as client:
        yield {"workers": None, "scheduler": client.scheduler.address}


def asked(cfg: dict[str, Any]) -> list[str]:
    """The products a ``[products]`` table asks for, in the order the stage makes them."""
    return ([k for k in ("ground", "dtm", "dsm", "ndsm", "stats", "contours", "hypsometry", "charts") if cfg.get(k)]
            + (["swath"] if cfg.get("swath") else []) + (["calibration"] if cfg.get("calibration_trajectory") else []))


def run(ctx: Context, tmp: Path) -> dict:
    """Ground classification, DTM, DSM, nDSM, contours, hypsometric image and sheets of the survey's tiles."""
    with _tile_runner({k: ctx.params[k] for k in ("workers", "scheduler")}) as par:
        return _products(ctx, tmp, par)


def _products(ctx: Context, tmp: Path, par: dict[str, Any]) -> dict:
    """:func:`run` with the runner keywords *par* of the tile actions."""
    import json

    import numpy as np

    from ..errors import SurveyError
    from ..lidar import read_points
    from ..lidar.cloud import PointCloud
    from ..production.contours import (contour_features, contours, spot_features, spot_heights, write_geojson,
                                   write_layers)
    from ..production.ground import params_from_dict
    from ..production.terrain import write_text_grid
    from .lidar import ground, read_grid, statistics_raster, terrain_model

    survey = ctx["survey"]
    cfg = {k: ctx.params[k] for k in PRODUCTS_KEYS}
    crs = survey.lidar_crs or survey.crs
    tiles = [Path(p) for p in survey.lidar_paths]
    want_sheets = cfg["sheet_size_m"] > 0 or cfg["sheet_index"] != "grid"
    vext = "." + cfg["vector_format"]
    steps = len(asked(cfg)) + (1 if want_sheets else 0)
    step = 0

    def tick() -> None:
        nonlocal step
        step += 1
        ctx.progress(step, steps)

    done: dict[str, Any] = {"crs": str(crs), "files": []}
    if cfg["ground"]:
        method = cfg["filter"]
        params = params_from_dict(method, {"adaptive": cfg["smrf_adaptive"]} if method == "smrf" else {})
        outs = [Path(p) for p in ground(tiles, tmp / "ground", crs=crs, method=method, params=params,
                                        noise=cfg["noise"], hag=cfg["hag"], copc=cfg["copc"], resume=False, **par)]
        for m in (tmp / "ground").glob("*.done.json"):   # resume markers of the tile runner: not products
            m.unlink()
        tiles = sorted(outs)
        done["ground"] = {"filter": method, "tiles": [f"ground/{p.name}" for p in tiles]}
        done["files"] += done["ground"]["tiles"]
        tick()
    cloud = PointCloud.concat([read_points(p, crs=crs) for p in tiles])
    cls = np.asarray(cloud.attributes["classification"]) if cloud.has("classification") else None
    gmask = cls == 2 if cls is not None else np.zeros(len(cloud), bool)
    if (cfg["dtm"] or cfg["contours"]) and not gmask.any():
        raise SurveyError(f"{survey.toml_path}: [products] dtm/contours need ground points (class 2) and the "
                          f"tiles have none; set ground = true")
    b = cloud.bounds
    area = (float(b.xmin), float(b.ymin), float(b.xmax), float(b.ymax))
    cell = cfg["cell_m"]
    rasters: dict[str, tuple[Any, Any]] = {}

    def model(kind: str, **extra: bool) -> np.ndarray:
        """The DTM or DSM of the tiles by the action of ``lidarcat lidar dtm|dsm TILES -o <kind>.tif``."""
        terrain_model(kind, tiles, tmp / f"{kind}.tif", crs=crs, cell_m=cell, max_edge_m=cfg["max_edge_m"],
                      text=cfg["text_grid"], hillshade=cfg["hillshade"], resume=False, **par, **extra)
        rasters[f"{kind}.tif"] = read_grid(tmp / f"{kind}.tif")
        done["files"] += [f"{kind}.tif"] + [n for n, on in ((f"{kind}_hillshade.tif", cfg["hillshade"]),
                                                             (f"{kind}.txt", cfg["text_grid"]),
                                                             (f"{kind}.prj", cfg["text_grid"])) if on]
        return rasters[f"{kind}.tif"][0]

    if cfg["dtm"]:
        grid = model("dtm")
        gaps = int(np.isnan(grid).sum())
        done["dtm"] = {"cell_m": cell, "rows": int(grid.shape[0]), "cols": int(grid.shape[1]),
                       "gap_cells": gaps, "gap_fraction": round(gaps / grid.size if grid.size else 0.0, 6)}
        tick()
    if cfg["dsm"]:
        grid = model("dsm", ndsm=cfg["ndsm"])
        done["dsm"] = {"cell_m": cell, "rows": int(grid.shape[0]), "cols": int(grid.shape[1]),
                       "empty_cells": int(np.isnan(grid).sum())}
        tick()
    if cfg["ndsm"]:   # the action's <output>_ndsm.tif of the DSM, DSM - DTM cell by cell
        (tmp / "dsm_ndsm.tif").replace(tmp / "ndsm.tif")
        rasters["ndsm.tif"] = read_grid(tmp / "ndsm.tif")
        done["files"].append("ndsm.tif")
        if cfg["text_grid"]:
            write_text_grid(tmp / "ndsm.txt", *rasters["ndsm.tif"], crs=crs)
            done["files"] += ["ndsm.txt", "ndsm.prj"]
        tick()
    if cfg["stats"]:   # the action of `lidarcat lidar stats TILES -o stats.tif`
        statistics_raster(tiles, tmp / "stats.tif", crs=crs, cell_m=cell, resume=False, **par)
        done["files"].append("stats.tif")
        done["stats"] = {"cell_m": cell, "bands": ["min", "max", "mean", "count", "stdev"]}
        tick()
    features: list[dict[str, Any]] = []
    spots = np.zeros((0, 4))
    if cfg["contours"]:
        g = cloud.xyz[gmask]
        cs = contours(g, cfg["contour_interval_m"], master_every=cfg["master_every"],
                      max_edge_m=cfg["max_edge_m"], smooth_iterations=cfg["smooth"], **contour_options(cfg))
        features = contour_features(cs)
        spots = spot_heights(g, cfg["spots_m"])
        if vext == ".gpkg":   # one GeoPackage, layers contours and spot_heights
            write_layers(tmp / "contours.gpkg", {"contours": features, "spot_heights": spot_features(spots)}, crs)
            done["files"].append("contours.gpkg")
        else:
            write_geojson(tmp / "contours.geojson", features, crs)
            write_geojson(tmp / "spot_heights.geojson", spot_features(spots), crs)
            done["files"] += ["contours.geojson", "spot_heights.geojson"]
        done["contours"] = {"interval_m": cfg["contour_interval_m"], "master_every": cfg["master_every"],
                            "lines": len(cs), "master_lines": sum(1 for c in cs if c.master),
                            "spot_heights": int(len(spots))}
        if any(cfg.get(k) for k in ("contour_review", "contour_polygons", "contour_3d")):
            done["contours"].update(contour_checks(cfg, cs, g, cloud.xyz, gmask, spots, crs, tmp, vext))
            done["files"] += [f for f in done["contours"]["files"] if f not in done["files"]]
        tick()
    if cfg["hypsometry"]:
        done["hypsometry"] = _hypsometry(cloud, cfg["hypsometry_cell_m"], area, crs, tmp)
        done["files"] += done["hypsometry"]["files"]
        tick()
    if want_sheets:
        done["sheets"] = _sheets(rasters, features, area, cfg, crs, tmp)
        done["files"].append("sheets" + vext)
        tick()
    if cfg.get("charts"):
        done["charts"] = chart_sheets(ctx, features, spots, area, cfg, crs, tmp, **par)
        done["files"] += done["charts"]["files"]
        tick()
    if cfg.get("swath") or cfg.get("calibration_trajectory"):
        done.update(lidar_checks(ctx, cfg, crs, tmp))
        done["files"] += done.get("swath", {}).get("files", []) + done.get("calibration", {}).get("files", [])
        for _ in ("swath", "calibration"):
            if _ in done:
                tick()
    if cfg.get("delivery"):
        index = []   # the sheet frames of the DXF and shp/sheets.shp (a GeoJSON index only, as before)
        if want_sheets and (tmp / "sheets.geojson").is_file():
            index = json.loads((tmp / "sheets.geojson").read_text(encoding="utf-8"))["features"]
        done["delivery"] = deliver(tmp, list(cfg["delivery"]), products=sorted(tmp.rglob("*.tif")),
                                   layers={"contours": features, "spot_heights": spot_features(spots),
                                           "sheets": index}, crs=crs, area=area)
        done["files"] += done["delivery"]["files"]
    return done


def _hypsometry(cloud: Any, cell_m: float, area: tuple[float, float, float, float], crs: Any,
                tmp: Path) -> dict[str, Any]:
    """hypsometry.png and hypsometry.tif: DSM heights coloured, shaded by intensity."""
    import matplotlib.image

    from .._util import atomic_write
    from ..lidar import rasterize
    from ..production.terrain import hypsometric_image, write_product

    h, t = rasterize(cloud, cell_m, "dsm", area)
    inten = rasterize(cloud, cell_m, "intensity", area)[0] if cloud.has("intensity") else None
    img = hypsometric_image(h, inten)
    files = ["hypsometry.png", "hypsometry.tif"]
    with atomic_write(tmp / "hypsometry.png", "wb") as fh:
        matplotlib.image.imsave(fh, img, format="png")
    write_product(tmp / "hypsometry.tif", img, t, crs)
    return {"cell_m": cell_m, "intensity": inten is not None, "files": files}


def _sheets(rasters: dict[str, tuple[Any, Any]], features: list[dict[str, Any]],
            area: tuple[float, float, float, float], cfg: dict[str, Any], crs: Any, tmp: Path) -> dict[str, Any]:
    """Every model and the contours cut along the sheet index; the index of the sheets holding data."""
    import numpy as np

    from .._util import safe_component
    from ..errors import ProductError
    from ..production.contours import write_layers
    from ..production.sheets import cut_contours, cut_raster, index_sheets, sheet_index_features
    from ..production.terrain import write_product

    ext = "." + cfg["vector_format"]
    used = []
    for s in index_sheets(area, cfg["sheet_index"], crs=crs, size_m=cfg["sheet_size_m"] or 1000.0):
        wrote = False
        folder = tmp / "sheets" / safe_component(s.name, "sheet name", error=ProductError)
        for name, (grid, transform) in rasters.items():
            cut = cut_raster(grid, transform, s, crs)
            if cut is not None and np.isfinite(cut[0].astype(float)).any():
                write_product(folder / name, cut[0], cut[1], crs)
                wrote = True
        part = cut_contours(features, s, crs) if features else []
        if part:
            write_layers(folder / ("contours" + ext), {"contours": part}, crs)
            wrote = True
        if wrote:
            used.append(s)
    write_layers(tmp / ("sheets" + ext), {"sheets": sheet_index_features(used, crs)}, crs)
    out: dict[str, Any] = {"index": cfg["sheet_index"], "sheets": [s.name for s in used]}
    if cfg["sheet_index"] == "grid":
        out["size_m"] = cfg["sheet_size_m"]
    return out


def chart_mosaic_path(ctx: Context, cfg: dict[str, Any]) -> Path:
    """The orthomosaic of the charts: ``chart_mosaic`` (relative to the survey folder), else the mapping
    stage's ``mosaic.tif`` of this run.

    Raises
    ------
    SurveyError
        Neither is there.
    """
    from ..errors import SurveyError

    survey = ctx["survey"]
    if cfg.get("chart_mosaic"):
        p = survey.root / cfg["chart_mosaic"]
        if not p.is_file():
            raise SurveyError(f"{survey.toml_path}: [products] chart_mosaic: {p} does not exist")
        return p
    if ctx.done("mapping") and (ctx.folder("mapping") / "mosaic.tif").is_file():
        return ctx.folder("mapping") / "mosaic.tif"
    raise SurveyError(f"{survey.toml_path}: [products] charts need the orthomosaic: the mapping stage's "
                      "mosaic.tif ([mapping] orthophotos = true, mosaic = true) or chart_mosaic = FILE.tif")


def chart_sheets(ctx: Context, features: list[dict[str, Any]], spots: Any, area: tuple[float, float, float, float],
                 cfg: dict[str, Any], crs: Any, tmp: Path, *, workers: int | None = None,
                 scheduler: str | None = None) -> dict[str, Any]:
    """charts/<sheet>.pdf and .png of the run (:func:`write_charts` with the ``[products]`` keys, on the
    tile runner of *workers* / *scheduler*)."""
    import datetime

    from ..lidar.crs import crs_label, resolve_crs
    from ..production.charts import TitleBlock

    survey = ctx["survey"]
    mosaic_path = chart_mosaic_path(ctx, cfg)
    if not features:
        from ..errors import ProductError

        raise ProductError(f"{survey.toml_path}: [products] charts: the ground gave no contour line at "
                           f"{cfg['contour_interval_m']:g} m")
    title = TitleBlock(project=cfg.get("chart_project") or survey.config.survey.name,
                       scale=int(cfg["chart_scale"]), datum_projection=crs_label(resolve_crs(crs)),
                       declination_deg=cfg.get("chart_declination_deg"),
                       declination_date=cfg.get("chart_declination_date") or "",
                       date=cfg.get("chart_date") or datetime.datetime.now(datetime.timezone.utc).date().isoformat(),
                       contour_interval_m=cfg["contour_interval_m"], master_every=cfg["master_every"])
    out = write_charts(mosaic_path, features, spots, tmp / "charts", crs=crs, title=title,
                       index=cfg["sheet_index"], size_m=cfg["sheet_size_m"] or 1000.0, area=area,
                       dpi=int(cfg["chart_dpi"]), workers=workers, scheduler=scheduler)
    out["files"] = [f"charts/{f}" for f in out["files"]]
    return out


#: the widest extent (m) the orthophoto charts of one run cover: 200 km is some 800 sheets of 1:5,000 (Itaocara: 66);
#: wider is a vertex or a mosaic in the wrong place, and the sheet loop would run for hours
MAX_CHART_SPAN_M = 200_000.0


def write_charts(mosaic_path: Path, features: list[dict[str, Any]], spots: Any, folder: Path, *, crs: Any,
                 title: Any, index: str = "grid", size_m: float = 1000.0,
                 area: tuple[float, float, float, float] | None = None, only: list[str] | None = None,
                 dpi: int = 150, progress: Any = None, workers: int | None = None,
                 scheduler: str | None = None) -> dict[str, Any]:
    """The orthophoto chart of every sheet of *index* holding mosaic cells or contours: <sheet>.pdf and .png
    in *folder* (the action of ``lidarcat chart`` and of ``[products] charts``).

    Parameters
    ----------
    mosaic_path : Path
        The orthomosaic GeoTIFF.
    features : list of GeoJSON LineString features
        The contours (properties ``level_m``, ``type``).
    spots : (M, 3+) array or None
        Spot heights E, N, h.
    folder : Path
        Receives the charts (written file by file, atomically).
    crs, title, index, size_m, area, dpi
        CRS of the products, :class:`lidarcat.production.charts.TitleBlock`, sheet index and grid size,
        the mapped area (default: the mosaic and the contours), PNG resolution.
    only : list of str, optional
        Chart only these sheets (a name outside the data is an error).
    progress : callable, optional
        ``progress(done, total)`` per chart.
    workers, scheduler : optional
        The tile runner's (:func:`lidarcat.production.charts.render_charts`): default serially in this
        process, else a local Dask cluster of *workers* processes or the Dask scheduler at *scheduler*.

    Returns
    -------
    dict
        ``sheets`` (names charted), ``scale``, ``mosaic``, ``files`` (relative to *folder*).

    Raises
    ------
    ProductError
        No contour line; a sheet of *only* that is not in the index or holds no data; the mosaic and the
        contours span more than :data:`MAX_CHART_SPAN_M`.
    """
    import numpy as np

    from .._util import safe_component
    from ..errors import ProductError
    from ..lidar.geotiff import read_geotiff
    from ..production.charts import crop_image, render_charts, sheet_extent
    from ..production.sheets import index_sheets

    image, transform, _ = read_geotiff(mosaic_path)   # (rows, cols[, bands]), NaN = nodata
    if not features:
        raise ProductError("charts: no contour line given; an orthophoto chart shows the contours")
    lines = [np.asarray(f["geometry"]["coordinates"], dtype=float) for f in features]
    ib = (transform.x0, transform.y0 - image.shape[0] * transform.cell_m,
          transform.x0 + image.shape[1] * transform.cell_m, transform.y0)
    lb = (min(xy[:, 0].min() for xy in lines), min(xy[:, 1].min() for xy in lines),
          max(xy[:, 0].max() for xy in lines), max(xy[:, 1].max() for xy in lines))
    whole = (min(ib[0], lb[0]), min(ib[1], lb[1]), max(ib[2], lb[2]), max(ib[3], lb[3]))
    span = max(whole[2] - whole[0], whole[3] - whole[1])
    if span > MAX_CHART_SPAN_M:
        centre = np.array([(ib[0] + ib[2]) / 2, (ib[1] + ib[3]) / 2])
        far = [float(np.abs(xy - centre).max()) for xy in lines]
        k = int(np.argmax(far))
        raise ProductError(f"charts: the mosaic and the contours span {span / 1000:.0f} km (at most "
                           f"{MAX_CHART_SPAN_M / 1000:.0f} km charted); contour feature {k} reaches "
                           f"{far[k] / 1000:.0f} km from the mosaic's centre: check its coordinates and CRS")
    grid = index_sheets(whole, index, crs=crs, size_m=size_m)

    def holds_data(s: Any) -> bool:
        box = sheet_extent(s, crs)[0]
        return crop_image(image, transform, box) is not None or any(
            ((xy[:, 0] >= box[0]) & (xy[:, 0] <= box[2]) & (xy[:, 1] >= box[1]) & (xy[:, 1] <= box[3])).any()
            for xy in lines)

    used = [s for s in grid if holds_data(s)]
    todo = used
    if only:
        names = {s.name: s for s in used}
        missing = [n for n in only if n not in names]
        if missing:
            raise ProductError(f"charts: sheet {missing[0]} holds no data of {mosaic_path} and the contours "
                               f"(sheets with data: {', '.join(names) or 'none'})")
        todo = [names[n] for n in only]
    names = [safe_component(s.name, "sheet name", error=ProductError) for s in todo]
    files = render_charts(todo, names, title, folder, image=image, image_transform=transform, contours=features,
                          spots=spots, sheets=used, area=area or lb, crs=crs, dpi=dpi, workers=workers,
                          scheduler=scheduler, progress=progress)
    return {"sheets": [s.name for s in todo], "scale": int(title.scale), "mosaic": str(mosaic_path),
            "files": files}


def deliver(folder: Path, formats: Sequence[str], *, products: Sequence[Path] = (),
            layers: dict[str, list[dict[str, Any]]] | None = None, crs: Any = None,
            area: tuple[float, float, float, float] | None = None, shp_folder: str = "shp",
            dxf_name: str = "contours.dxf") -> dict[str, Any]:
    """The delivery formats of products (:mod:`lidarcat.production.delivery`): the action of ``lidarcat deliver``
    and of ``[products] delivery``.

    ``tfw``: every GeoTIFF of *products* with its world file in *folder* (copied in when it lies elsewhere;
    the stage's own GeoTIFFs get theirs beside them); ``shp``: one Shapefile ``<shp_folder>/<name>.shp`` per
    layer that holds features; ``dxf``: one drawing *dxf_name* of every LineString (contours), Point (spot
    heights, property ``h_m``) and Polygon (sheet frames) of the layers, and the mapped *area*.

    Parameters
    ----------
    folder : Path
        Receives the files (the stage's temporary folder, or the command's).
    formats : sequence of {"tfw", "shp", "dxf"}
    products : sequence of Path
        Product files: ``.tif``/``.tiff``, and ``.geojson``/``.json`` (Point layer, else LineString layer)
        or ``.gpkg`` (its LineString layer), each a layer named by its stem.
    layers : dict, optional
        More layers by name: GeoJSON features already in memory (the stage's contours, spot heights, sheets).
    crs : optional
        CRS of the layers (default: that of the first layer read that carries one).
    area : (xmin, ymin, xmax, ymax), optional
        The mapped area, drawn in the DXF.
    shp_folder, dxf_name : str
        Where the Shapefiles go below *folder* (``""``: *folder* itself) and the DXF's file name.

    Returns
    -------
    dict
        ``formats`` and ``files`` (relative to *folder*, in the order written).

    Raises
    ------
    ProductError
        A product that is not a GeoTIFF or a vector layer; no CRS for the layers; nothing to draw in the DXF.
    FormatError
        A layer that cannot be read (located by file and feature).
    """
    import shutil

    import numpy as np

    from ..errors import ProductError
    from ..lidar.crs import resolve_crs
    from ..production.contours import read_line_layer
    from ..production.delivery import read_point_layer, write_dxf, write_shapefile, write_world_file

    folder = Path(folder)
    c = resolve_crs(crs) if crs is not None else None
    rasters: list[Path] = []
    named: list[tuple[str, list[dict[str, Any]]]] = []
    for p in map(Path, products):
        suffix = p.suffix.lower()
        if suffix in (".tif", ".tiff"):
            rasters.append(p)
            continue
        if suffix not in (".geojson", ".json", ".gpkg"):
            raise ProductError(f"{p}: give .tif, .geojson or .gpkg products")
        pts, lcrs = read_point_layer(p) if suffix != ".gpkg" else ([], None)
        feats, lcrs = read_line_layer(p) if not pts else (pts, lcrs)
        if (c or lcrs) is None:
            raise ProductError(f"{p}: the layer carries no CRS; give it (lidarcat deliver --crs)")
        c = c or lcrs
        named.append((p.stem, feats))
    named += list((layers or {}).items())
    files: list[str] = []
    if "tfw" in formats:
        for tif in rasters:
            if not tif.resolve().is_relative_to(folder.resolve()):   # a product from elsewhere: copied in
                shutil.copyfile(tif, folder / tif.name)
                tif = folder / tif.name
                files.append(tif.name)
            files.append(str(write_world_file(tif).relative_to(folder)))
    if "shp" in formats:
        for name, feats in named:
            if feats:
                shp = write_shapefile(folder / shp_folder / f"{name}.shp", feats, c)
                files += [str(q.relative_to(folder)) for q in sorted(shp.parent.glob(f"{name}.*"))]
    if "dxf" in formats:
        def geometry(kind: str) -> list[dict[str, Any]]:
            return [f for _, feats in named for f in feats if (f.get("geometry") or {}).get("type") == kind]

        spots = np.asarray([(*f["geometry"]["coordinates"][:2], (f.get("properties") or {}).get("h_m", np.nan))
                            for f in geometry("Point")], dtype=float).reshape(-1, 3)
        write_dxf(folder / dxf_name, contours=geometry("LineString"), spots=spots, sheets=geometry("Polygon"),
                  area=area)
        files.append(dxf_name)
    return {"formats": list(formats), "files": files}


def contour_options(cfg: dict[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`lidarcat.production.contours.contours` that ``[products]`` sets
    beyond interval, master curves, gaps and smoothing (defaults when the keys are absent)."""
    return {"levels": cfg.get("contour_levels"), "min_ring_m": float(cfg.get("contour_min_ring_m", 0.0)),
            "edge_peel": int(cfg.get("contour_edge_peel", 3))}


def contour_checks(cfg: dict[str, Any], cs: Any, ground_xyz: Any, points_xyz: Any, ground_mask: Any, spots: Any,
                   crs: Any, tmp: Path, vext: str) -> dict[str, Any]:
    """``contour_review``, ``contour_profiles``, ``contour_polygons``, ``contour_3d`` of ``[products]``
    (:func:`lidarcat.stages.lidar.contour_extras`): the contour file is rewritten with the 3-D lines and,
    for a GeoPackage, the new layers."""
    from ..production.contourcheck import contour_features_3d
    from ..production.contours import contour_features, spot_features, write_layers
    from .lidar import contour_extras

    out = tmp / ("contours" + vext)
    extra = contour_extras(out, cs, ground_xyz, crs, points_xyz=points_xyz, ground_mask=ground_mask,
                           review=bool(cfg.get("contour_review")), sparse_edge_m=cfg.get("contour_sparse_edge_m"),
                           profiles=int(cfg.get("contour_profiles") or 0), polygons=bool(cfg.get("contour_polygons")),
                           band_kw={"interval_m": cfg["contour_interval_m"], "max_edge_m": cfg["max_edge_m"],
                                    **{k: v for k, v in contour_options(cfg).items() if k != "min_ring_m"}})
    feats = contour_features_3d(cs) if cfg.get("contour_3d") else contour_features(cs)
    if vext == ".gpkg":
        write_layers(out, {"contours": feats, "spot_heights": spot_features(spots),
                           **{k: v for k, v in extra.pop("layers", {}).items() if v}}, crs)
    elif cfg.get("contour_3d"):
        write_layers(out, {"contours": feats}, crs)
    files = [str(Path(f).relative_to(tmp)) for f in extra["files"]]
    return {k: v for k, v in {**extra, "files": files, "three_d": bool(cfg.get("contour_3d"))}.items()}


def lidar_checks(ctx: Context, cfg: dict[str, Any], crs: Any, tmp: Path) -> dict[str, Any]:
    """``swath`` and ``calibration_trajectory`` of ``[products]``: the swath separation image and the
    system calibration of the survey's tiles (:func:`lidarcat.stages.lidar.swath_check`,
    :func:`~lidarcat.stages.lidar.system_calibration`)."""
    from ..errors import SurveyError
    from .lidar import swath_check, system_calibration

    survey = ctx["survey"]
    tiles = [Path(p) for p in survey.lidar_paths]
    out: dict[str, Any] = {}
    if cfg.get("swath"):
        rep = swath_check(tiles, tmp / "swath.tif", crs=crs, cell_m=float(cfg["swath_cell_m"]),
                          quality_level=cfg["swath_quality_level"])
        rep["files"] = [str(Path(f).relative_to(tmp)) for f in rep["files"]]
        out["swath"] = rep
    if cfg.get("calibration_trajectory"):
        paths = {}
        for key in ("calibration_trajectory", "calibration_control"):
            if cfg.get(key):
                p = survey.root / cfg[key]
                if not p.is_file():
                    raise SurveyError(f"{survey.toml_path}: [products] {key}: {p} does not exist")
                paths[key] = p
        rep = system_calibration(tiles, paths["calibration_trajectory"], tmp / "calibration.json", crs=crs,
                                 control=paths.get("calibration_control"))
        rep["files"] = ["calibration.json"]
        out["calibration"] = rep
    return out
