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

__all__ = ["ground", "terrain_model", "statistics_raster", "ground_parameters", "mosaic_grids", "read_grid",
           "vertical_check", "system_calibration", "swath_check", "contour_extras", "read_outlines",
           "planimetric_check"]


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
           copc: bool = False, overlap_m: float | None = None, workers: int | None = None,
           scheduler: str | None = None, resume: bool = True,
           progress: Callable[[int], Any] | None = None) -> list[str]:
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
    copc : bool
        Write the copies as COPC files (``<tile>.copc.laz``, :mod:`lidarcat.lidar.copc_write`).
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
                             noise=noise, hag=hag, copc=copc, overlap_m=overlap_m, workers=workers, scheduler=scheduler, resume=resume,
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


def _read_control(path: str | os.PathLike) -> np.ndarray:
    """Surveyed control-surface points ``id,E,N,H`` (CSV) as an (M, 3) array."""
    from .._util.tables import read_csv_table
    from ..errors import SurveyError

    table = read_csv_table(path, ("id", "E", "N", "H"), ("vegetated",))
    if len(table.rows) < 3:
        raise SurveyError(f"{path}: {len(table.rows)} control points; a control surface needs at least 3")
    return np.column_stack([table.floats("E"), table.floats("N"), table.floats("H")])


def system_calibration(tiles: Sequence[str | os.PathLike], trajectory: str | os.PathLike,
                       output: str | os.PathLike, *, crs: Any = None, control: str | os.PathLike | None = None,
                       classes: Sequence[int] | None = None, stride: int = 1, sd_control_m: float = 0.05,
                       sd_strip_m: float = 0.05, radius_m: float = 2.5, max_plane_rms_m: float = 0.15,
                       max_observations: int | None = 200_000, workers: int | None = None,
                       scheduler: str | None = None,
                       progress: Callable[[int, int], Any] | None = None) -> dict[str, Any]:
    """Roll/pitch boresight, scan-angle scale and elevation bias from LiDAR tiles and the flight's trajectory
    (``lidarcat lidar calibrate``, report 7.1.2).

    The points' GPS times are matched to the trajectory (SBET or CSV,
    :mod:`lidarcat.lidar.trajectory`); range and scan angle are rebuilt from
    point and sensor (:func:`lidarcat.production.lidarchecks.pulses_from_points`);
    the flight lines are the points' ``point_source_id``; the parameters are
    estimated as :func:`lidarcat.production.lidarchecks.estimate_system_parameters`
    does, tile by tile on the tile engine (module docstring of
    :mod:`lidarcat.production.lidarchecks`, "Tile by tile"): the tiles'
    measured bounds (:func:`~lidarcat.production.lidarchecks.bounds_tile`,
    which give each tile its neighbours), then two passes of
    :func:`~lidarcat.production.lidarchecks.calibration_tile` (observations
    chosen at the delivered points, then at the first step), each tile with
    its neighbours' points within the planes' reach; the parent merges the
    tiles' observations (at most *max_observations* of each kind) and
    iterates.  Work files go to ``.<name>.calibration-tiles/`` beside the
    output and are removed at the end.

    Parameters
    ----------
    tiles : sequence of path
        LAS/LAZ tiles with ``gps_time`` and ``point_source_id``.
    trajectory : path
        SBET (``.out``/``.sbet``) or CSV (``.csv``) trajectory.
    output : path
        The JSON report.
    crs : CRS-like, optional
        CRS of the tiles when they carry none (the SBET is projected into it).
    control : path, optional
        Surveyed control surface (the runway), CSV ``id,E,N,H``; without it the
        elevation bias is not estimated.
    classes : sequence of int, optional
        Use only points of these classes (default: all).
    stride : int
        Use one point in ``stride`` (chosen by a hash of the point, the same in
        every tile that reads it).
    max_observations : int or None
        Keep at most this many control and this many strip observations (the
        smallest point hashes of the survey); None: all.
    workers, scheduler
        The tile engine (:func:`lidarcat.lidar.jobs.run_jobs`): serial by
        default; the same estimate either way.
    sd_control_m, sd_strip_m, radius_m, max_plane_rms_m
        :func:`~lidarcat.production.lidarchecks.estimate_system_parameters`.
    progress : callable, optional
        ``progress(done, total)``: the tiles of the three passes, then the iterations.

    Raises
    ------
    ProductError
        A tile without GPS times or point source ids, points outside the
        trajectory (names the first), fewer than two flight lines without a
        control surface, or a singular adjustment.
    """
    import shutil

    from .._util import file_sha256
    from .._util.tables import write_json_atomic
    from ..lidar.jobs import read_done_output, read_npz, run_jobs, tile_jobs
    from ..production.lidarchecks import (
        PARAMETER_NAMES,
        CalibrationObservations,
        bounds_tile,
        calibration_tile,
        estimate_from_observations,
        merge_observations,
    )

    tiles = [Path(t) for t in tiles]
    ctrl = _read_control(control) if control is not None else None
    out = Path(output)
    work = out.parent / f".{out.stem}.calibration-tiles"
    max_iter = 10
    cap = None if max_observations is None else int(max_observations)
    params = {"trajectory": str(trajectory), "trajectory_sha256": file_sha256(trajectory),
              "control": None if ctrl is None else ctrl.tolist(),
              "classes": None if classes is None else [int(c) for c in classes], "stride": int(stride),
              "radius_m": float(radius_m), "k": 6, "max_plane_rms_m": float(max_plane_rms_m),
              "max_control": cap, "max_strip": cap}
    # the neighbours within the plane radius of a point at the first step, which moves it by < 1 m + radius
    overlap = 2.0 * float(radius_m) + 1.0
    n_tiles = len(tiles)
    total = 3 * n_tiles + max_iter
    done = [0]

    def tick(k: int) -> None:
        done[0] += k
        if progress is not None:
            progress(done[0], total)

    # the tiles' measured bounds first: header bounds are unverified, so the engine would make every tile a
    # neighbour of every other (n^2 edge-buffer pieces)
    bjobs = [dataclasses.replace(j, neighbours=(), buffered=False)
             for j in tile_jobs(bounds_tile, tiles, work / "bounds", crs=crs, suffix=".bounds.npz")]
    run_jobs(bjobs, workers=workers, scheduler=scheduler, progress=tick)
    measured = {j.tile: read_npz(read_done_output(j), j.output)["bounds"] for j in bjobs}

    def near(b: np.ndarray, c: np.ndarray) -> bool:
        return bool(np.all(np.isfinite(c)) and c[0] <= b[2] + overlap and c[2] >= b[0] - overlap
                    and c[1] <= b[3] + overlap and c[3] >= b[1] - overlap)

    def one_pass(name: str, at: Any) -> tuple[Any, list[dict[str, Any]]]:
        jobs = tile_jobs(calibration_tile, tiles, work / name, crs=crs, overlap_m=overlap, suffix=".obs.npz",
                         params={**params, "at": None if at is None else [float(x) for x in np.nan_to_num(
                             at.as_array())]})
        jobs = [dataclasses.replace(j, bounds=tuple(float(x) for x in measured[j.tile]), neighbours=tuple(
            t for t, c in measured.items() if t != j.tile and near(measured[j.tile], c)))
            if np.all(np.isfinite(measured[j.tile])) else dataclasses.replace(j, neighbours=()) for j in jobs]
        run_jobs(jobs, workers=workers, scheduler=scheduler, progress=tick)
        obs, zs = None, []
        for j in jobs:      # in job order (serial == Dask), merged as they are read: at most the cap held
            z = read_npz(read_done_output(j), j.output)
            part = CalibrationObservations.from_arrays(z)
            obs = part if obs is None else merge_observations([obs, part], max_control=cap, max_strip=cap)
            zs.append({k: z[k] for k in ("lines", "n_points", "along_ss", "time_note")})
        obs = merge_observations([obs], max_control=cap, max_strip=cap)
        return obs, zs

    obs1, zs = one_pass("first", None)
    lines = np.unique(np.concatenate([z["lines"] for z in zs]))
    n_points = int(sum(int(z["n_points"]) for z in zs))
    if ctrl is None and lines.size < 2:
        raise ProductError(f"{n_points} points of one flight line (point source id "
                           f"{int(lines[0]) if lines.size else '-'}) and no control surface: the calibration "
                           "needs overlapping flight lines or a control surface")
    step = estimate_from_observations(obs1, ctrl, sd_control_m=sd_control_m, sd_strip_m=sd_strip_m, max_iter=1)
    del obs1
    obs2, _ = one_pass("second", step.parameters)
    base = 3 * n_tiles
    res = estimate_from_observations(obs2, ctrl, start=step.parameters, sd_control_m=sd_control_m,
                                     sd_strip_m=sd_strip_m, max_iter=max_iter - 1,
                                     progress=lambda i, n: progress(base + 1 + i, total) if progress else None)
    res = dataclasses.replace(res, n_iter=res.n_iter + 1, rms_before_m=step.rms_before_m)
    if progress is not None:
        progress(total, total)
    d = res.to_dict()
    deg = {n.replace("_rad", "_deg"): (None if d["parameters"][n] is None else float(np.degrees(d["parameters"][n])))
           for n in PARAMETER_NAMES if n.endswith("_rad")}
    sd_deg = {n.replace("_rad", "_deg"): (None if d["sd"][n] is None else float(np.degrees(d["sd"][n])))
              for n in PARAMETER_NAMES if n.endswith("_rad")}
    along_ss = sum(float(z["along_ss"]) for z in zs)
    notes = sorted({str(z["time_note"]) for z in zs if int(z["n_points"])})
    report = {"calibration": d, "parameters_deg": deg, "sd_deg": sd_deg, "points": n_points,
              "flight_lines": [int(x) for x in lines], "time_base": "; ".join(notes),
              "along_track_rms_deg": float(np.degrees(np.sqrt(along_ss / max(n_points, 1)))),
              "observations": {"control": int(obs2.control.size), "strip": int(obs2.point.size),
                               "control_found": obs2.seen_control, "strip_found": obs2.seen_strip,
                               "max_observations": cap},
              "trajectory": str(trajectory), "control": None if control is None else str(control),
              "tiles": [str(t) for t in tiles], "files": [str(output)]}
    write_json_atomic(out, report)
    shutil.rmtree(work, ignore_errors=True)
    return report


def swath_check(tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
                cell_m: float = 1.0, quality_level: str = "QL2", classes: Sequence[int] | None | str = "auto",
                smooth_rms_m: float = 0.05, max_slope_deg: float = 10.0, preview: bool = True,
                workers: int | None = None, scheduler: str | None = None,
                progress: Callable[[int, int], Any] | None = None) -> dict[str, Any]:
    """Swath separation image of LiDAR tiles (``lidarcat lidar swath``; USGS lidar base specification).

    Parameters
    ----------
    tiles : sequence of path
        LAS/LAZ tiles with ``point_source_id`` (the flight line).
    output : path
        ``<name>.tif``: the per-cell difference (float32, m, NaN outside the
        overlap, the tiles' CRS); ``<name>.png`` the coloured image;
        ``<name>.json`` the statistics against the quality level's limits.
    cell_m, smooth_rms_m, max_slope_deg
        :func:`lidarcat.production.swath.swath_separation`.
    quality_level : {"QL0", "QL1", "QL2", "QL3"}
    classes : sequence of int, None or "auto"
        Points used, all last returns except noise (7, 18) and withheld
        points, further limited to these classes; ``"auto"``: the ground
        class (2) when the tiles hold ground points, else every class.
    workers, scheduler
        The tile engine (:func:`lidarcat.lidar.jobs.run_jobs`): serial by
        default, else a local Dask cluster of *workers* processes or the
        cluster at *scheduler*; the same result either way.
    progress : callable, optional
        ``progress(tiles_done, tiles)``.

    A map-reduce on the tile engine: each tile's sums of the plane fits per
    (cell, flight line) are a task (:func:`lidarcat.production.swath.swath_tile`,
    written into ``.<name>.swath-tiles/`` beside the output, removed at the
    end); the parent merges them in tile order and fits the planes once.

    Raises
    ------
    ProductError
        Points without point source ids, fewer than two flight lines, an unknown quality level.
    """
    import math
    import shutil

    from .._util.tables import write_json_atomic
    from ..lidar.crs import crs_label
    from ..lidar.geotiff import write_geotiff
    from ..lidar.jobs import read_done_output, read_npz, run_jobs, tile_jobs
    from ..lidar.tileindex import TileIndex
    from ..production.swath import (INTERSWATH_LIMITS, merge_sums, read_swath_partial, swath_from_sums,
                                    swath_tile, write_swath_png)

    if quality_level not in INTERSWATH_LIMITS:
        raise ProductError(f"quality level must be one of {', '.join(INTERSWATH_LIMITS)}, got {quality_level!r}")
    fixed = None if isinstance(classes, str) or classes is None else [int(c) for c in classes]
    out = Path(output)
    work = out.parent / f".{out.stem}.swath-tiles"
    out_crs = TileIndex.build([Path(t) for t in tiles], crs=crs).crs
    jobs = tile_jobs(swath_tile, tiles, work, crs=crs, suffix=".swath.npz",
                     params={"cell_m": float(cell_m), "classes": "auto" if isinstance(classes, str) else fixed})
    jobs = [dataclasses.replace(j, buffered=False, neighbours=()) for j in jobs]   # own points only: sums add
    done = [0]

    def tick(k: int) -> None:
        done[0] += k
        if progress is not None:
            progress(done[0], len(jobs))

    run_jobs(jobs, workers=workers, scheduler=scheduler, progress=tick)
    # the reduce: the tiles' sums in job order (the same bytes serially or on Dask)
    parts: dict[str, list[Any]] = {"": [], "_ground": []}
    npts = {"": 0, "_ground": 0}
    for j in jobs:
        z = read_npz(read_done_output(j), j.output)
        for which in (("", "_ground") if isinstance(classes, str) else ("",)):
            sums, n = read_swath_partial(z, which)
            parts[which].append(sums)
            npts[which] += n
    used: list[int] | None = fixed
    key = ""
    if isinstance(classes, str) and npts["_ground"] > 0:
        used, key = [2], "_ground"
    if npts[key] == 0:
        raise ProductError(f"no last return{'' if used is None else ' of classes ' + ','.join(map(str, used))} "
                           f"in {', '.join(map(str, tiles))}")
    merged = merge_sums(parts[key])
    sep = swath_from_sums(merged, smooth_rms_m=smooth_rms_m, max_slope=math.tan(math.radians(max_slope_deg)))
    lid = merged[0][:, 2]
    files = [write_geotiff(out.with_suffix(".tif"), sep.dz_m.astype(np.float32), sep.transform, out_crs)]
    if preview:
        files.append(write_swath_png(out.with_suffix(".png"), sep, quality_level))
    stats = sep.assess(quality_level)
    report = {"swath": stats, "cell_m": cell_m, "classes": used, "points": int(npts[key]),
              "flight_lines": [int(x) for x in np.unique(lid)], "smooth_rms_m": smooth_rms_m,
              "max_slope_deg": max_slope_deg, "crs": crs_label(out_crs) if out_crs is not None else None,
              "tiles": [str(t) for t in tiles]}
    json_path = out.with_suffix(".json")
    report["files"] = [str(f) for f in files] + [str(json_path)]
    write_json_atomic(json_path, report)
    shutil.rmtree(work, ignore_errors=True)
    return report


def contour_extras(output: str | os.PathLike, cs: Sequence[Any], ground_xyz: np.ndarray, crs: Any, *,
                   points_xyz: np.ndarray | None = None, ground_mask: np.ndarray | None = None,
                   review: bool = False, sparse_edge_m: float | None = None, review_min_m: float = 0.0,
                   profiles: int = 0, polygons: bool = False, band_kw: dict[str, Any] | None = None
                   ) -> dict[str, Any]:
    """The contour verification layer, its profiles and the filled bands beside the contours at *output*.

    ``.gpkg``: the layers ``review`` and ``contour_bands`` are returned
    (``layers``) for the caller to write with the contours; otherwise they are
    written as ``<stem>_review.geojson`` and ``<stem>_bands.geojson``.  Profiles of the *profiles* longest stretches go
    to ``<stem>_profiles/<k>_<level>m.png``
    (:mod:`lidarcat.production.contourcheck`).

    Parameters
    ----------
    output : path
        The contours file already written.
    cs : sequence of Contour
    ground_xyz : (N, 3) float
        The ground points the contours were drawn from.
    crs : CRS-like
    points_xyz, ground_mask : optional
        Every point and which are ground, for the profiles (default: the ground alone).
    review, sparse_edge_m, review_min_m
        Flag stretches over sparse ground (threshold and shortest stretch, m).
    profiles : int
        Profile PNGs of the longest stretches (needs *review*).
    polygons : bool
        Filled bands between the levels.
    band_kw : dict, optional
        Keywords of :func:`lidarcat.production.contourcheck.contour_bands` (interval, levels, edges).

    Returns
    -------
    dict
        ``files`` written, ``review`` (stretch count, length, threshold), ``bands`` (count),
        ``layers`` (GeoPackage output only).
    """
    from ..production.contourcheck import (contour_bands, sparse_stretches, stretch_features, stretch_profile,
                                           write_profile_png)
    from ..production.contours import write_layers

    out = Path(output)
    gpkg = out.suffix.lower() == ".gpkg"
    files: list[str] = []
    result: dict[str, Any] = {}
    layers: dict[str, list[dict[str, Any]]] = {}
    if review:
        st, thr = sparse_stretches(cs, ground_xyz, sparse_edge_m=sparse_edge_m, min_length_m=review_min_m)
        layers["review"] = stretch_features(st)
        result["review"] = {"stretches": len(st), "length_m": float(sum(s.length_m for s in st)),
                            "sparse_edge_m": thr}
        if profiles and st:
            pts = np.asarray(ground_xyz) if points_xyz is None else np.asarray(points_xyz)
            gm = np.ones(len(pts), bool) if ground_mask is None else np.asarray(ground_mask, bool)
            folder = out.with_name(out.stem + "_profiles")
            folder.mkdir(parents=True, exist_ok=True)
            for k, s in enumerate(sorted(st, key=lambda x: -x.length_m)[:profiles]):
                png = folder / f"{k + 1:03d}_{s.level_m:g}m.png"
                write_profile_png(png, stretch_profile(s, pts, gm))
                files.append(str(png))
    if polygons:
        layers["contour_bands"] = contour_bands(ground_xyz, **(band_kw or {}))
        result["bands"] = len(layers["contour_bands"])
    if gpkg:
        result["layers"] = layers          # the caller writes them into the GeoPackage with the contours
    else:
        for name, feats in layers.items():
            if not feats:
                continue
            p = out.with_name(f"{out.stem}_{'review' if name == 'review' else 'bands'}{out.suffix}")
            write_layers(p, {name: feats}, crs)
            files.append(str(p))
    result["files"] = files
    return result


def _wkb_rings(b: bytes) -> list[np.ndarray]:
    """The exterior rings (2-D) of a WKB Polygon or MultiPolygon (ISO or EWKB Z/M flags)."""
    import struct

    out: list[np.ndarray] = []

    def geom(o: int) -> int:
        endian = "<" if b[o] == 1 else ">"
        (code,) = struct.unpack_from(endian + "I", b, o + 1)
        o += 5
        base = code & 0xFFFF
        dims = 2 + (1 if (code & 0x80000000) or base // 1000 in (1, 3) else 0) + \
            (1 if (code & 0x40000000) or base // 1000 in (2, 3) else 0)
        kind = base % 1000
        if kind == 3:
            (nr,) = struct.unpack_from(endian + "I", b, o)
            o += 4
            for r in range(nr):
                (npt,) = struct.unpack_from(endian + "I", b, o)
                o += 4
                a = np.frombuffer(b, dtype=endian + "f8", count=npt * dims, offset=o).reshape(npt, dims)
                o += 8 * npt * dims
                if r == 0:
                    out.append(a[:, :2].astype(float))
            return o
        if kind == 6:
            (ng,) = struct.unpack_from(endian + "I", b, o)
            o += 4
            for _ in range(ng):
                o = geom(o)
            return o
        raise ProductError(f"building outlines must be polygons; got WKB geometry type {code}")

    geom(0)
    return out


def read_outlines(path: str | os.PathLike, crs: Any = None) -> tuple[list[str], list[np.ndarray], Any]:
    """Surveyed building outlines (polygons; GeoPackage, Shapefile, GeoJSON, ... through pyogrio).

    Returns the outline ids (the ``id`` or ``name`` field, else ``<file>#<n>``,
    ``-k`` appended for the k-th part of a multipolygon), their exterior rings
    (K, 2) and the layer's CRS.

    Raises
    ------
    FormatError
        pyogrio missing, or a file it cannot read.
    ProductError
        A geometry that is not a polygon; no outline; a CRS other than *crs* (names both).
    """
    from ..errors import FormatError
    from ..lidar.crs import crs_compatible, crs_label, resolve_crs

    try:
        from pyogrio.raw import read
    except ImportError:
        raise FormatError(f"{path}: reading building outlines needs pyogrio (pip install 'lidarcat[gis]')") from None
    try:
        meta, _, geoms, fields = read(str(path))
    except Exception as ex:   # pyogrio's DataSourceError and friends
        raise FormatError(f"{path}: cannot read the building outlines: {ex}") from None
    names = [str(n).lower() for n in meta.get("fields", [])]
    col = next((names.index(k) for k in ("id", "name") if k in names), None)
    ids, rings = [], []
    for i, g in enumerate(geoms):
        if g is None:
            continue
        parts = _wkb_rings(bytes(g))
        base = str(fields[col][i]) if col is not None else f"{Path(path).name}#{i + 1}"
        for k, r in enumerate(parts):
            ids.append(base if len(parts) == 1 else f"{base}-{k + 1}")
            rings.append(r)
    if not rings:
        raise ProductError(f"{path}: no building outline (polygon) in the file")
    lcrs = resolve_crs(meta["crs"]) if meta.get("crs") else None
    want = resolve_crs(crs)
    if lcrs is not None and want is not None and not crs_compatible(lcrs, want):
        raise ProductError(f"{path}: the outlines are in {crs_label(lcrs)}, the LiDAR tiles in {crs_label(want)}")
    return ids, rings, lcrs


def planimetric_check(tiles: Sequence[str | os.PathLike], outlines: str | os.PathLike, output: str | os.PathLike,
                      *, crs: Any = None, roof_classes: Sequence[int] = (6,), ground_classes: Sequence[int] = (2,),
                      min_height_m: float = 2.0, band_m: float = 2.0, bin_m: float = 1.0,
                      checkpoint_sd_m: float | None = None, scale: float | None = None) -> dict[str, Any]:
    """Planimetric accuracy of LiDAR tiles against surveyed building outlines (``lidarcat lidar check
    --outlines``, report 7.1.1 Figure 5).

    Each outline's corners are found in the points
    (:func:`lidarcat.production.lidarchecks.lidar_outline_corners`) and compared
    with the surveyed ones (:func:`~lidarcat.production.lidarchecks.planimetric_accuracy`).

    Parameters
    ----------
    tiles : sequence of path
    outlines : path
        Polygons (GeoPackage, Shapefile, GeoJSON) of the surveyed outlines, in the tiles' CRS.
    output : path
        ``<stem>_planimetric.json`` (the report) and ``<stem>_corners.csv`` (every corner) are written
        beside it.
    roof_classes, ground_classes : sequence of int
        Roof and low points; without points of the roof classes, the points more than *min_height_m*
        above the 10th percentile of the heights near each outline are its roof.
    band_m, bin_m
        :func:`~lidarcat.production.lidarchecks.lidar_outline_corners`.
    checkpoint_sd_m, scale
        Survey sd of the corners (ASPRS 2023) and the scale of the PEC class.
    """
    from .._util.tables import write_csv_atomic, write_json_atomic
    from ..lidar.readers import read_points
    from ..production.lidarchecks import lidar_outline_corners, planimetric_accuracy

    clouds = [read_points(t, crs=crs) for t in tiles]
    tile_crs = next((c.crs for c in clouds if c.crs is not None), None) if crs is None else crs
    ids, rings, _ = read_outlines(outlines, tile_crs)
    xyz = np.concatenate([c.xyz for c in clouds])
    cls = np.concatenate([np.asarray(c.attributes["classification"]) if "classification" in c.attributes
                          else np.zeros(len(c), np.uint8) for c in clouds])
    have_roof = bool(np.isin(cls, list(roof_classes)).any())
    rows, d_all, per = [], [], []
    for oid, ring in zip(ids, rings):
        lo, hi = ring.min(axis=0) - band_m - 5.0, ring.max(axis=0) + band_m + 5.0
        near = np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1)
        p, c = xyz[near], cls[near]
        if len(p) == 0:
            raise ProductError(f"{outlines}: outline {oid} (E {ring[:, 0].mean():.1f}, N {ring[:, 1].mean():.1f}) "
                               "has no LiDAR point around it")
        if have_roof:
            roof, low = p[np.isin(c, list(roof_classes))], p[np.isin(c, list(ground_classes))]
        else:
            base = np.percentile(p[:, 2], 10)
            roof, low = p[p[:, 2] > base + min_height_m], p[p[:, 2] <= base + min_height_m]
        res = lidar_outline_corners(ring, roof, low, band_m=band_m, bin_m=bin_m)
        d = res.discrepancies_m
        d_all.append(d)
        per.append({"id": oid, "corners": len(ring), "found": int(np.isfinite(d).all(axis=1).sum()),
                    "edge_offset_m": [None if not np.isfinite(x) else float(x) for x in res.edge_offset_m]})
        for k, (sv, li, dd) in enumerate(zip(res.surveyed_m, res.lidar_m, d)):
            rows.append([oid, k + 1, float(sv[0]), float(sv[1]), float(li[0]), float(li[1]), float(dd[0]),
                         float(dd[1])])
    acc = planimetric_accuracy(np.vstack(d_all), checkpoint_sd_m=checkpoint_sd_m, scale=scale)
    out = Path(output)
    csv_path = out.with_name(out.stem + "_corners.csv")
    json_path = out.with_name(out.stem + "_planimetric.json")
    write_csv_atomic(csv_path, ["outline", "corner", "E", "N", "lidar_E", "lidar_N", "dE", "dN"], rows,
                     comments=["metres; dE, dN = LiDAR corner - surveyed corner (NaN: an edge not found)"])
    report = {"planimetric": acc, "outlines": per, "roof": "classes " + ",".join(map(str, roof_classes))
              if have_roof else f"points {min_height_m:g} m above the local ground", "band_m": band_m,
              "bin_m": bin_m, "tiles": [str(t) for t in tiles], "outlines_file": str(outlines),
              "files": [str(json_path), str(csv_path)]}
    write_json_atomic(json_path, report)
    return report
