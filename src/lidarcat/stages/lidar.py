"""Actions of the LiDAR production commands: ground classification and terrain/surface models of tiles.

``lidarcat lidar ground|dtm|dsm`` (:mod:`lidarcat.cli.lidar_products`) and the
``products`` stage of ``lidarcat run`` (:mod:`lidarcat.stages.products`, ground)
call these functions: tiles in, files written, their paths out.  Every tile is
computed by the tile engine (:func:`lidarcat.lidar.jobs.run_jobs`) with the points
of its neighbours within the overlap, serially or on Dask.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import LidarcatError

__all__ = ["ground", "terrain_model", "ground_parameters"]


def ground_parameters(method: str, **values: Any) -> Any:
    """The :class:`~lidarcat.production.ground.SMRFParameters` or ``PTDParameters`` of *method*.

    *values* may hold the parameters of both filters; those of the other one are ignored.
    """
    from ..production.ground import PTDParameters, SMRFParameters

    cls = PTDParameters if method == "ptd" else SMRFParameters
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in values.items() if k in names and v is not None})


def ground(tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
           method: str = "smrf", params: Any = None, overlap_m: float | None = None,
           workers: int | None = None, scheduler: str | None = None, resume: bool = True,
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
    method : {"smrf", "ptd"}
    params : SMRFParameters or PTDParameters, optional
        Default: the method's defaults (:func:`ground_parameters`).
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
    from ..lidar.jobs import run_jobs, tile_jobs
    from ..production.ground import default_overlap_m

    p = ground_parameters(method) if params is None else params
    pdict = {"method": method, **dataclasses.asdict(p)}
    ov = default_overlap_m(method, p) if overlap_m is None else float(overlap_m)
    jobs = tile_jobs("ground", [Path(t) for t in tiles], output, crs=crs, params=pdict, overlap_m=ov, suffix="")
    for j in jobs:
        if Path(j.output).resolve() == Path(j.tile).resolve():
            raise LidarcatError(f"{j.output}: the output would overwrite the input; choose another folder")
    return run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)


def terrain_model(kind: str, tiles: Sequence[str | os.PathLike], output: str | os.PathLike, *, crs: Any = None,
                  cell_m: float = 1.0, max_edge_m: float = 50.0, text: bool = False, hillshade: bool = False,
                  ndsm: bool = False, overlap_m: float = 50.0, workers: int | None = None,
                  scheduler: str | None = None, resume: bool = True,
                  progress: Callable[[int], Any] | None = None) -> list[str]:
    """DTM (``kind="dtm"``: TIN of the ground) or DSM (``"dsm"``: highest first return) per tile.

    Parameters
    ----------
    kind : {"dtm", "dsm"}
    tiles : sequence of path
    output : path
        One tile and a ``.tif`` name: that file; else a folder receiving ``<tile>.tif``
        per tile (grids snapped to the cell, so they mosaic).
    cell_m, max_edge_m : float
        Cell size and longest TIN edge (longer triangles are gaps), metres.
    text, hillshade, ndsm : bool
        Also write ``<output>.txt`` (E N H per cell centre), ``<output>_hillshade.tif``,
        and for a DSM ``<output>_ndsm.tif`` (DSM - DTM).
    overlap_m : float
        Points of neighbouring tiles read around each tile, metres.
    crs, workers, scheduler, resume, progress
        See :func:`ground`.

    Returns
    -------
    list of str
        The written GeoTIFFs, in tile order.
    """
    from ..lidar.jobs import run_jobs, tile_jobs

    if kind not in ("dtm", "dsm"):
        raise ValueError(f"kind must be 'dtm' or 'dsm', got {kind!r}")
    params = {"cell_m": cell_m, "max_edge_m": max_edge_m, "text": text, "hillshade": hillshade, "ndsm": ndsm}
    jobs = tile_jobs(kind, [Path(t) for t in tiles], output, crs=crs, params=params, overlap_m=overlap_m,
                     suffix=".tif")
    return run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
