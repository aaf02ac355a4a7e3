"""Stage ``products``: the LiDAR products of the LACTEC chain, when survey.toml asks for them.

survey.toml::

    [products]
    ground = true               # classify ground (class 2) into copies of the tiles (false: use their class 2)
    filter = "smrf"             # "smrf" (simple morphological filter) or "ptd" (TerraScan's TIN densification)
    dtm = true                  # dtm.tif: TIN of the ground sampled at cell centres (gaps stay NaN)
    dsm = true                  # dsm.tif: highest first return per cell
    ndsm = false                # ndsm.tif: DSM - DTM (needs dtm and dsm)
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
Everything carries the LiDAR CRS; the stage writes
into its temporary folder and the runner moves it into ``OUTDIR/products/``
only when it succeeded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..survey.schema import ProductsSettings
from .context import StageContext as Context

__all__ = ["run", "settings", "PRODUCTS_KEYS", "asked"]

#: keys of the [products] table and their defaults (lidarcat.survey.schema.ProductsSettings)
PRODUCTS_KEYS: dict[str, Any] = ProductsSettings().to_dict()


def settings(survey: Any) -> dict[str, Any]:
    """The ``[products]`` table of the survey with its defaults (``{}`` when there is none); checked by
    :meth:`lidarcat.Survey.load` (:class:`lidarcat.survey.schema.ProductsSettings`)."""
    cfg = survey.config.products
    return {} if cfg is None else cfg.to_dict()


def asked(cfg: dict[str, Any]) -> list[str]:
    """The products a ``[products]`` table asks for, in the order the stage makes them."""
    return [k for k in ("ground", "dtm", "dsm", "ndsm", "contours", "hypsometry") if cfg.get(k)]


def run(ctx: Context, tmp: Path) -> dict:
    """Ground classification, DTM, DSM, nDSM, contours, hypsometric image and sheets of the survey's tiles."""
    import numpy as np

    from ..errors import SurveyError
    from ..lidar import read_points
    from ..lidar.cloud import PointCloud
    from ..production.contours import (contour_features, contours, spot_features, spot_heights, write_geojson,
                                   write_layers)
    from ..production.ground import params_from_dict
    from ..production.terrain import write_text_grid
    from .lidar import ground, read_grid, terrain_model

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
        params = params_from_dict(method, {})
        outs = [Path(p) for p in ground(tiles, tmp / "ground", crs=crs, method=method, params=params, resume=False)]
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
                      text=cfg["text_grid"], hillshade=cfg["hillshade"], resume=False, **extra)
        rasters[f"{kind}.tif"] = read_grid(tmp / f"{kind}.tif")
        done["files"] += [f"{kind}.tif"] + [n for n, on in ((f"{kind}_hillshade.tif", cfg["hillshade"]),
                                                             (f"{kind}.txt", cfg["text_grid"])) if on]
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
            write_text_grid(tmp / "ndsm.txt", *rasters["ndsm.tif"])
            done["files"].append("ndsm.txt")
        tick()
    features: list[dict[str, Any]] = []
    if cfg["contours"]:
        g = cloud.xyz[gmask]
        cs = contours(g, cfg["contour_interval_m"], master_every=cfg["master_every"],
                      max_edge_m=cfg["max_edge_m"], smooth_iterations=cfg["smooth"])
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
        tick()
    if cfg["hypsometry"]:
        done["hypsometry"] = _hypsometry(cloud, cfg["hypsometry_cell_m"], area, crs, tmp)
        done["files"] += done["hypsometry"]["files"]
        tick()
    if want_sheets:
        done["sheets"] = _sheets(rasters, features, area, cfg, crs, tmp)
        done["files"].append("sheets" + vext)
        tick()
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
