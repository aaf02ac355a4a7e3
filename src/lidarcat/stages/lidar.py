"""Actions of the LiDAR production commands: ground classification and terrain/surface models of tiles.

``lidarcat lidar ground|dtm|dsm`` (:mod:`lidarcat.cli.lidar_products`) and the
``products`` stage of ``lidarcat run`` (:mod:`lidarcat.stages.products`, ground)
call these functions: tiles in, files written, their paths out.  Every tile is
computed by the tile engine (:func:`lidarcat.lidar.jobs.run_jobs`) with the points
of its neighbours within the overlap, serially or on Dask.

A terrain or surface model asked as one ``.tif`` is computed the same way, tile
by tile into a hidden folder ``.<name>.tiles/`` beside it (kept for a resumed
run until the model is written), and the tile grids, snapped to multiples of
the cell, are mosaicked without resampling (:func:`mosaic_grids`): each cell
takes the value of the first tile whose own area holds the cell centre (else of
the first tile whose grid covers it), so the DTM, DSM and nDSM of one run take
every cell from the same tile.  Hillshade and text grid are then made from the
mosaic, so they show no seam.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ProductError

__all__ = ["ground", "terrain_model", "statistics_raster", "ground_parameters", "mosaic_grids", "read_grid", "vertical_check"]


def _jobs(kind: str, tiles: Sequence[str | os.PathLike], output: str | os.PathLike, **kw: Any) -> list[Any]:
    """The tile jobs of product *kind* (``"ground"``, ``"dtm"``, ``"dsm"``, ``"stats"``): the one place that names
    them."""
    from ..production.tiles import product_jobs

    return product_jobs(kind, [Path(t) for t in tiles], output, **kw)


def ground_parameters(method: str, **values: Any) -> Any:
    """The :class:`~lidarcat.production.ground.SMRFParameters` or ``PTDParameters`` of *method*.

    *values* may hold the parameters of both filters; those of the other one are ignored.
    """
    from ..production.csf import CSFParameters
    from ..production.ground import PTDParameters, SMRFParameters

    cls = {"ptd": PTDParameters, "csf": CSFParameters}.get(method, SMRFParameters)
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in values.items() if k in names and v is not None})


def ground(tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
           method: str = "smrf", params: Any = None, noise: bool = False, hag: bool = False,
           overlap_m: float | None = None, workers: int | None = None, scheduler: str | None = None,
           resume: bool = True, progress: Callable[[int], Any] | None = None) -> list[str]:
    """Classify ground (class 2) into LAS/LAZ copies of *tiles* (``lidarcat lidar ground``).

    Parameters
    ----------
    tiles : sequence of path
        Input tiles; never modified.
    output : path
        One tile and a ``.las``/``.laz`` name: that file; else a folder receiving a
        classified copy of every tile under its own name.
    crs : CRS, optional
        CRS of tiles that carry none.
    method : {"smrf", "ptd", "csf"}
    params : SMRFParameters, PTDParameters or CSFParameters, optional
        Default: the method's defaults (:func:`ground_parameters`).
    noise, hag : bool
        Class 7 on statistical outliers; the extra dimension ``HeightAboveGround``
        (:func:`lidarcat.production.ground.classify_tiles`).
    overlap_m : float, optional
        Points of neighbouring tiles read around each tile, metres (default
        :func:`lidarcat.production.ground.default_overlap_m`).
    workers, scheduler, resume, progress
        See :func:`lidarcat.lidar.jobs.run_jobs`.

    Returns
    -------
    list of str
        The written files, in tile order (each with its ``.done.json`` resume marker).
    """
    from ..production.ground import classify_tiles

    p = ground_parameters(method) if params is None else params
    written = classify_tiles([Path(t) for t in tiles], output, crs=crs, method=method, params=p,
                             noise=noise, hag=hag, overlap_m=overlap_m, workers=workers, scheduler=scheduler, resume=resume,
                             progress=progress)
    return [str(w) for w in written]


def terrain_model(kind: str, tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
                  cell_m: float = 1.0, max_edge_m: float = 50.0, text: bool = False, hillshade: bool = False,
                  ndsm: bool = False, overlap_m: float = 50.0, workers: int | None = None,
                  scheduler: str | None = None, resume: bool = True,
                  progress: Callable[[int], Any] | None = None,
                  bounds: Sequence[float] | None = None, max_cells: int | None = None,
                  vrt: bool = False) -> list[str]:
    """DTM (``kind="dtm"``: TIN of the ground) or DSM (``"dsm"``: highest first return) of tiles.

    Parameters
    ----------
    kind : {"dtm", "dsm"}
    tiles : sequence of path
    output : path
        Ending in ``.tif``/``.tiff``: one GeoTIFF over all the tiles (computed tile by tile,
        mosaicked; see the module docstring).  Else a folder receiving ``<tile>.tif`` per tile
        (grids snapped to the cell, so they mosaic).
    cell_m, max_edge_m : float
        Cell size and longest TIN edge (longer triangles are gaps), metres.
    text, hillshade, ndsm : bool
        Also write ``<output>.txt`` (E N H per cell centre), ``<output>_hillshade.tif``,
        and for a DSM ``<output>_ndsm.tif`` (DSM - DTM).
    overlap_m : float
        Points of neighbouring tiles read around each tile, metres.
    crs, workers, scheduler, resume, progress
        See :func:`ground`; *resume* also keeps the tile grids of an interrupted
        one-file model.
    bounds : (xmin, ymin, xmax, ymax), optional
        Grid only this area, metres (tiles whose header bounds miss it are skipped).
    max_cells : int, optional
        Largest grid, per tile and for the one-file model (default
        :data:`lidarcat.lidar.raster.MAX_CELLS`): a larger one is refused before it is made.
    vrt : bool
        Folder output: also write ``mosaic.vrt``, the tiles' virtual mosaic
        (:func:`lidarcat.lidar.geotiff.write_vrt`), as the last file returned.

    Raises
    ------
    ProductError
        A grid larger than *max_cells*, no tile in *bounds*, or a tile without ground (DTM).

    Returns
    -------
    list of str
        The written GeoTIFFs (the model, or one per tile in tile order).
    """
    from ..lidar.jobs import run_jobs

    if kind not in ("dtm", "dsm"):
        raise ValueError(f"kind must be 'dtm' or 'dsm', got {kind!r}")
    out = Path(output)
    params = {"cell_m": cell_m, "max_edge_m": max_edge_m, "text": text, "hillshade": hillshade, "ndsm": ndsm}
    if bounds is not None:
        bounds = tuple(map(float, bounds))
        if not (len(bounds) == 4 and np.isfinite(bounds).all() and bounds[0] < bounds[2] and bounds[1] < bounds[3]):
            raise ProductError(f"bounds {' '.join(f'{v:.6g}' for v in bounds)} are not an area "
                               "(give XMIN YMIN XMAX YMAX, finite, min < max)")
        params["bounds"] = bounds
    if max_cells is not None:
        params["max_cells"] = int(max_cells)
    if out.suffix.lower() not in (".tif", ".tiff"):
        jobs = _in_bounds(_jobs(kind, tiles, out, crs=crs, params=params, overlap_m=overlap_m, suffix=".tif"),
                          bounds)
        written = run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
        if vrt:
            from ..lidar.geotiff import write_vrt

            written = list(written) + [str(write_vrt(out / "mosaic.vrt", [Path(w) for w in written]))]
        return written
    import shutil

    from ..lidar.tileindex import TileIndex
    from ..production.terrain import hillshade as shade
    from ..production.terrain import write_product, write_text_grid

    parts = out.parent / f".{out.name}.tiles"
    jobs = _in_bounds(_jobs(kind, tiles, parts, crs=crs, params=params | {"text": False, "hillshade": False},
                            overlap_m=overlap_m, suffix=".tif"), bounds)
    run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
    out_crs = TileIndex.build([Path(t) for t in tiles], crs=crs).crs   # the CRS the tile jobs write
    bounds = [j.bounds for j in jobs]
    areas = [j.bounds for j in jobs]
    grid, transform = mosaic_grids([read_grid(j.output) for j in jobs], areas, max_cells=max_cells)
    stem = out.with_suffix("")
    if hillshade:
        write_product(Path(f"{stem}_hillshade.tif"), shade(grid, cell_m), transform, out_crs)
    if kind == "dsm" and ndsm:
        nd, _ = mosaic_grids([read_grid(Path(j.output).with_suffix("").as_posix() + "_ndsm.tif") for j in jobs],
                             areas, max_cells=max_cells)
        write_product(Path(f"{stem}_ndsm.tif"), nd, transform, out_crs)
    if text:
        write_text_grid(out.with_suffix(".txt"), grid, transform, crs=out_crs)
    write_product(out, grid, transform, out_crs)
    shutil.rmtree(parts, ignore_errors=True)
    return [str(out)]


def statistics_raster(tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
                      cell_m: float = 1.0, values: str = "z", classes: Sequence[int] | None = None,
                      vrt: bool = True, workers: int | None = None, scheduler: str | None = None,
                      resume: bool = True, progress: Callable[[int], Any] | None = None,
                      bounds: Sequence[float] | None = None, max_cells: int | None = None) -> list[str]:
    """Per-cell point statistics of tiles: min, max, mean, count and stdev bands (``lidarcat lidar stats``).

    Parameters
    ----------
    tiles : sequence of path
    output : path
        Ending in ``.tif``/``.tiff``: one five-band GeoTIFF over all the tiles (each band
        mosaicked as :func:`mosaic_grids` does).  Else a folder receiving ``<tile>.tif`` per
        tile, and with *vrt* their virtual mosaic ``mosaic.vrt``
        (:func:`lidarcat.lidar.geotiff.write_vrt`).
    cell_m : float
        Cell, metres.
    values : str
        ``"z"`` (heights, metres) or a point attribute (e.g. ``"intensity"``).
    classes : sequence of int, optional
        Only points of these classes (default: all but noise, class 7).
    crs, workers, scheduler, resume, progress, bounds, max_cells
        As :func:`terrain_model`.

    Returns
    -------
    list of str
        The written files (the GeoTIFF; or the tile GeoTIFFs, then the VRT).
    """
    import shutil

    from ..lidar.geotiff import write_bands, write_vrt
    from ..lidar.jobs import run_jobs
    from ..lidar.raster import STAT_BANDS
    from ..lidar.tileindex import TileIndex

    out = Path(output)
    params: dict[str, Any] = {"cell_m": float(cell_m), "values": values,
                              "classes": None if classes is None else [int(c) for c in classes]}
    if bounds is not None:
        params["bounds"] = tuple(map(float, bounds))
    if max_cells is not None:
        params["max_cells"] = int(max_cells)
    if out.suffix.lower() not in (".tif", ".tiff"):
        jobs = _in_bounds(_jobs("stats", tiles, out, crs=crs, params=params, overlap_m=cell_m, suffix=".tif"), params.get("bounds"))
        written = run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
        if vrt:
            written = list(written) + [str(write_vrt(out / "mosaic.vrt", [Path(w) for w in written]))]
        return written
    import rasterio

    parts = out.parent / f".{out.name}.tiles"
    jobs = _in_bounds(_jobs("stats", tiles, parts, crs=crs, params=params, overlap_m=cell_m, suffix=".tif"), params.get("bounds"))
    run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
    out_crs = TileIndex.build([Path(t) for t in tiles], crs=crs).crs
    stacks = []
    for j in jobs:
        with rasterio.open(j.output) as ds:
            stacks.append((ds.read().astype(np.float64), ds.transform))
    from ..lidar.raster import GeoTransform

    layers = []
    transform = None
    for b in range(len(STAT_BANDS)):
        grids = [(a[b], GeoTransform(t.c, t.f, t.a)) for a, t in stacks]
        g, transform = mosaic_grids(grids, [j.bounds for j in jobs], max_cells=max_cells)
        if STAT_BANDS[b] == "count":
            g = np.where(np.isnan(g), 0.0, g)
        layers.append(g)
    write_bands(out, np.stack(layers), transform, out_crs, STAT_BANDS)
    shutil.rmtree(parts, ignore_errors=True)
    return [str(out)]


def _in_bounds(jobs: list[Any], bounds: tuple[float, ...] | None) -> list[Any]:
    """The jobs whose tile's (header) area meets *bounds* (a non-finite header is kept: the tile decides)."""
    if bounds is None:
        return jobs
    keep = [j for j in jobs if not np.isfinite(j.bounds).all()
            or (j.bounds[0] <= bounds[2] and j.bounds[2] >= bounds[0] and j.bounds[1] <= bounds[3]
                and j.bounds[3] >= bounds[1])]
    if not keep:
        raise ProductError(f"no tile lies in the bounds E {bounds[0]:.3f}..{bounds[2]:.3f} "
                           f"N {bounds[1]:.3f}..{bounds[3]:.3f}")
    return keep


def read_grid(path: str | os.PathLike) -> tuple[np.ndarray, Any]:
    """(grid, GeoTransform) of a one-band GeoTIFF written by :func:`lidarcat.production.terrain.write_product`."""
    from ..lidar.geotiff import read_geotiff

    grid, transform, _crs = read_geotiff(path)
    return grid, transform


def mosaic_grids(grids: Sequence[tuple[np.ndarray, Any]],
                 areas: Sequence[tuple[float, float, float, float]], *,
                 max_cells: int | None = None) -> tuple[np.ndarray, Any]:
    """One grid from tile grids on one lattice (origins multiples of the common cell), without resampling.

    Parameters
    ----------
    grids : sequence of (grid, GeoTransform)
        The tiles' grids, each snapped to multiples of the same cell.
    areas : sequence of (xmin, ymin, xmax, ymax)
        Each tile's own area, metres (a tile grid reaches beyond it by up to one cell).
    max_cells : int, optional
        Largest mosaic (default :data:`lidarcat.lidar.raster.MAX_CELLS`): tiles far apart
        are refused before the mosaic is allocated.

    Returns
    -------
    (grid, GeoTransform)
        The union of the grids; a cell takes the value of the first tile whose area holds
        its centre, else of the first tile whose grid covers it; NaN where none does.
    """
    from ..lidar.raster import GeoTransform, check_grid_size

    if len(grids) != len(areas) or not grids:
        raise ValueError("give one area per grid, and at least one grid")
    cell = float(grids[0][1].cell_m)
    if any(abs(t.cell_m - cell) > 1e-9 * cell for _, t in grids):
        raise ValueError("the grids have different cells")
    x0 = min(t.x0 for _, t in grids)
    y0 = max(t.y0 for _, t in grids)
    cols = max(round((t.x0 - x0) / cell) + g.shape[1] for g, t in grids)
    rows = max(round((y0 - t.y0) / cell) + g.shape[0] for g, t in grids)
    check_grid_size(rows, cols, max_cells, where="mosaic of the tiles",
                    bounds=(x0, y0 - rows * cell, x0 + cols * cell, y0), cell_m=cell)
    dtype = np.result_type(*(g.dtype for g, _ in grids))
    out = np.full((rows, cols), np.nan, dtype=dtype)
    owned = np.zeros((rows, cols), bool)      # taken from the tile whose area holds the centre
    filled = np.zeros((rows, cols), bool)
    for (g, t), (xmin, ymin, xmax, ymax) in zip(grids, areas):
        r0, c0 = round((y0 - t.y0) / cell), round((t.x0 - x0) / cell)
        win = (slice(r0, r0 + g.shape[0]), slice(c0, c0 + g.shape[1]))
        e = t.x0 + (np.arange(g.shape[1]) + 0.5) * cell
        n = t.y0 - (np.arange(g.shape[0]) + 0.5) * cell
        own = ((n >= ymin) & (n <= ymax))[:, None] & ((e >= xmin) & (e <= xmax))[None, :]
        take = ~owned[win] & (own | ~filled[win])
        out[win][take] = g[take]
        owned[win] |= take & own
        filled[win] |= take
    return out, GeoTransform(float(x0), float(y0), cell)


def vertical_check(tiles: Sequence[str | os.PathLike], checkpoints: str | os.PathLike, output: str | os.PathLike,
                   *, crs: Any = None, classes: Sequence[int] | None = (2,), method: str = "tin",
                   radius_m: float = 1.0, checkpoint_sd_m: float | None = None, scale: float | None = None,
                   contour_interval_m: float | None = None) -> dict[str, Any]:
    """Vertical accuracy of LiDAR tiles at surveyed check points (``lidarcat lidar check``, report 7.1.1).

    Parameters
    ----------
    tiles : sequence of path
        LiDAR tiles (LAS/LAZ or text).
    checkpoints : path
        CSV ``id,E,N,H`` and optionally ``vegetated`` (1/0, yes/no, true/false;
        default 0: a hard, open surface), metres, in the CRS of the tiles.
    output : path
        ``<name>.json`` report; the per-point discrepancies go to ``<name>.csv``.
    classes : sequence of int or None
        Point classes used (default ground, 2); ``None``: all last returns.
    method, radius_m
        :func:`lidarcat.production.lidarchecks.lidar_heights_at`.
    checkpoint_sd_m, scale, contour_interval_m
        :func:`lidarcat.production.lidarchecks.vertical_accuracy`.

    Returns
    -------
    dict
        The report written (``accuracy``, ``points``, ``files``).

    Raises
    ------
    SurveyError
        A bad check-point file (names file, line and field).
    ProductError
        No LiDAR point of the classes, a check point outside the data (named).
    """
    from .._util.tables import read_csv_table, write_csv_atomic, write_json_atomic
    from ..errors import SurveyError, location
    from ..lidar.readers import read_points
    from ..production.lidarchecks import lidar_heights_at, vertical_accuracy

    table = read_csv_table(checkpoints, ("id", "E", "N", "H"), ("vegetated",))
    if not table.rows:
        raise SurveyError(f"{checkpoints}: no check points (a header and no rows)")
    e, n, h = table.floats("E"), table.floats("N"), table.floats("H")
    ids = table.column("id")
    veg = np.zeros(len(ids), dtype=bool)
    if table.has("vegetated"):
        for k, (cell, line) in enumerate(zip(table.column("vegetated"), table.lines)):
            word = cell.strip().lower()
            if word not in ("", "0", "1", "yes", "no", "true", "false"):
                raise SurveyError(f"{location(checkpoints, line, 'vegetated')}: {cell!r} is not 1/0, yes/no "
                                  "or true/false")
            veg[k] = word in ("1", "yes", "true")
    if not np.any(~veg):
        raise SurveyError(f"{checkpoints}: every check point is vegetated; NVA needs hard, open surfaces")
    pad = 10.0 * radius_m + 50.0
    lo, hi = np.array([e.min() - pad, n.min() - pad]), np.array([e.max() + pad, n.max() + pad])
    parts = []
    for t in tiles:
        pc = read_points(t, crs=crs)
        keep = np.all((pc.xyz[:, :2] >= lo) & (pc.xyz[:, :2] <= hi), axis=1)
        a = pc.attributes
        if classes is not None and "classification" in a:
            keep &= np.isin(a["classification"], list(classes))
        elif "return_number" in a and "number_of_returns" in a:
            keep &= a["return_number"] == a["number_of_returns"]
        parts.append(pc.xyz[keep])
    pts = np.concatenate(parts) if parts else np.zeros((0, 3))
    if pts.shape[0] < 3:
        what = f"of classes {', '.join(map(str, classes))}" if classes is not None else "(last returns)"
        raise ProductError(f"{len(pts)} LiDAR points {what} around the check points of {checkpoints}; "
                           "at least 3 are needed")
    z = lidar_heights_at(pts, np.column_stack([e, n]), method=method, radius_m=radius_m, ids=ids)
    dz = z - h
    acc = vertical_accuracy(dz[~veg], dz[veg], checkpoint_sd_m=checkpoint_sd_m, scale=scale,
                            contour_interval_m=contour_interval_m)
    out = Path(output)
    csv_path = out.with_suffix(".csv")
    write_csv_atomic(csv_path, ["id", "E", "N", "H", "vegetated", "lidar_h", "dz"],
                     [[i, float(a), float(b), float(c), int(v), float(zz), float(d)]
                      for i, a, b, c, v, zz, d in zip(ids, e, n, h, veg, z, dz)],
                     comments=["metres; dz = lidar_h - H; lidar_h by " + method])
    report = {"accuracy": acc.to_dict(), "points": int(len(pts)), "method": method, "radius_m": radius_m,
              "classes": None if classes is None else list(classes), "checkpoints": str(checkpoints),
              "tiles": [str(t) for t in tiles], "files": [str(out), str(csv_path)]}
    write_json_atomic(out, report)
    return report
