"""Tile-parallel roof-vertex search: :func:`~lidarcat.control.vertices.find_candidates` over blocks of cells.

The serial search cuts the area into cells of ``cell_m`` and, for each cell,
segments its points plus a 2 m rim, keeps the vertices of 3+ faces inside the
cell as seeds and refines each seed with the points within ``radius_m``.  A
cell therefore needs only the points within

    margin = max(cell_m / 2 + 2, radius_m) + 1   (m)

of it (:func:`~lidarcat.control.vertices.search_margin_m`; the ``cell_m/2`` covers the
square window of a narrower edge cell).  Here the cell grid, anchored at the
area's lower-left corner exactly as in the serial run, is split into blocks of
``block_cells x block_cells`` cells; each block is one
:class:`~lidarcat.lidar.jobs.TileJob` running :func:`search_block`, that reads from the
tiles only the points of its block plus the margin (clipped to the area, as the
serial run reads the area), searches its cells and pickles its candidates,
tagged ``(i, j, k)`` = cell and seed order.  The blocks run through
:func:`~lidarcat.lidar.jobs.run_jobs` (serial, a ``LocalCluster`` or a
running scheduler; retries; done-markers, so a rerun with the same work folder
resumes).  The driver sorts all tags into the serial seed order and applies the
same best-first duplicate merge, so the candidates are identical to the serial
run's: same points, same scores, same order, same names.

Identity needs every block to see its points in the serial order: tile order of
the index, file order within a tile (both kept by ``TileIndex.query_box``) and
a point order within a cell that does not depend on the k-d tree built over
them (the cell query returns sorted indices).

Memory per worker: the tiles' points within one block plus its margin.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import pickle
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .params import ExtractionParams, get_params
from .vertices import (
    cell_counts,
    merge_candidates,
    search_cells,
    search_margin_m,
    search_points,
)

if TYPE_CHECKING:
    from ..lidar.jobs import TileJob

__all__ = ["find_candidates_tiles", "find_jobs", "n_blocks", "run_find_block", "search_block", "write_block"]

log = logging.getLogger(__name__)


def find_jobs(index: Any, area: Sequence[float], work_dir: str | os.PathLike, *, crs: Any = None, params: Any = None,
              cell_m: float = 20.0, min_score: float = 0.2, classes: Sequence[int] | None = None,
              block_cells: int = 4) -> list:
    """One :class:`~lidarcat.lidar.jobs.TileJob` (:func:`search_block`) per block of cells that meets a tile.

    Parameters
    ----------
    index : TileIndex
        The tiles, in the order the serial run reads them.
    area : (xmin, ymin, xmax, ymax)
        Searched area, metres.
    work_dir : path
        Folder for the blocks' results and done-markers.
    crs : str, optional
        CRS of tiles that carry none (as given to ``TileIndex.build``).
    block_cells : int
        Cells per block side (a block covers ``block_cells * cell_m`` metres).
    """
    # lazy: importing lidarcat.control does not load the LiDAR readers
    from ..lidar.jobs import TileJob

    if block_cells < 1:
        raise ValueError(f"block_cells must be at least 1, got {block_cells}")
    p = get_params(params)
    xmin, ymin, xmax, ymax = (float(v) for v in area)
    nx, ny = cell_counts(area, cell_m)
    margin = search_margin_m(p, cell_m)
    jobs = []
    for i0 in range(0, nx, block_cells):
        for j0 in range(0, ny, block_cells):
            i1, j1 = min(i0 + block_cells, nx), min(j0 + block_cells, ny)
            bx0, by0 = xmin + i0 * cell_m, ymin + j0 * cell_m
            bx1, by1 = min(xmin + i1 * cell_m, xmax), min(ymin + j1 * cell_m, ymax)
            tiles = [str(t.path) for t in index.tiles_in_box(max(bx0 - margin, xmin), max(by0 - margin, ymin),
                                                             min(bx1 + margin, xmax), min(by1 + margin, ymax))]
            if not tiles:
                continue
            job_params = {"cells": [i0, i1, j0, j1], "area": [xmin, ymin, xmax, ymax], "cell_m": float(cell_m),
                          "min_score": float(min_score), "classes": None if classes is None else list(classes),
                          "extraction": dataclasses.asdict(p)}
            jobs.append(TileJob(search_block, tiles[0], (bx0, by0, bx1, by1), tuple(tiles[1:]),
                                str(Path(work_dir) / f"find_{i0:05d}_{j0:05d}.pkl"), job_params,
                                None if crs is None else str(crs), margin, buffered=False))
    return jobs


def run_find_block(job: TileJob) -> list:
    """Search the cells of one block; return ``[((i, j, k), Candidate), ...]``."""
    from ..lidar.tileindex import TileIndex

    prm = job.params
    p = ExtractionParams(**prm["extraction"])
    xmin, ymin, xmax, ymax = prm["area"]
    bx0, by0, bx1, by1 = job.bounds
    m = job.overlap_m
    index = TileIndex.build([job.tile, *job.neighbours], crs=job.crs)
    cloud = index.query_box(max(bx0 - m, xmin), max(by0 - m, ymin), min(bx1 + m, xmax), min(by1 + m, ymax))
    xyz, box = search_points(cloud, (xmin, ymin, xmax, ymax), p, prm["classes"])
    if xyz is None:
        return []
    i0, i1, j0, j1 = prm["cells"]
    cells = [(i, j) for i in range(i0, i1) for j in range(j0, j1)]
    return search_cells(xyz, box, cells, p, prm["cell_m"], prm["min_score"])


def search_block(job: TileJob) -> None:
    """The tile function of the block search (for :mod:`lidarcat.lidar.jobs`): :func:`run_find_block`,
    its tagged candidates pickled to ``job.output`` (:func:`write_block`)."""
    write_block(Path(job.output), run_find_block(job))


def write_block(path: Path, found: list) -> None:
    """Pickle a block's tagged candidates atomically (read back only by :func:`find_candidates_tiles`)."""
    from .._util import atomic_write

    with atomic_write(path, "wb") as fh:
        pickle.dump(found, fh, protocol=pickle.HIGHEST_PROTOCOL)


def find_candidates_tiles(index: Any, area: Sequence[float], *, params: Any = None, cell_m: float = 20.0,
                          min_score: float = 0.2, classes: Sequence[int] | None = None, block_cells: int = 4,
                          crs: Any = None, work_dir: str | os.PathLike | None = None, workers: int | None = None,
                          scheduler: str | None = None, resume: bool = True,
                          progress: Callable[[int], Any] | None = None) -> list:
    """Candidates of :func:`~lidarcat.control.vertices.find_candidates` over *area* of the tiles, block-parallel.

    Identical to ``find_candidates(index.query_box(*area), box=area, ...)``.

    Parameters
    ----------
    index : TileIndex
    area : (xmin, ymin, xmax, ymax)
        Metres.
    crs : str, optional
        CRS of tiles that carry none (as given to ``TileIndex.build``).
    params, cell_m, min_score, classes
        As in :func:`~lidarcat.control.vertices.find_candidates`.
    block_cells : int
        Cells per block side: one task per block.
    work_dir : path, optional
        Folder of the blocks' results (kept, so a rerun resumes); default a
        temporary folder removed at the end.  With ``scheduler``, it must be a
        path the workers see too.
    workers, scheduler, resume, progress
        As in :func:`~lidarcat.lidar.jobs.run_jobs`; *progress* counts blocks.

    Returns
    -------
    list of Candidate
        Sorted by decreasing score.
    """
    from ..lidar.jobs import run_jobs

    def run(folder: str | os.PathLike) -> list:
        jobs = find_jobs(index, area, folder, crs=crs, params=params, cell_m=cell_m, min_score=min_score,
                         classes=classes, block_cells=block_cells)
        log.info("roof-vertex search: %d blocks of up to %d x %d cells", len(jobs), block_cells, block_cells)
        outs = run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
        found = []
        for o in outs:
            with open(o, "rb") as fh:
                found.extend(pickle.load(fh))
        found.sort(key=lambda t: t[0])
        return merge_candidates([c for _, c in found])

    if work_dir is not None:
        return run(work_dir)
    with tempfile.TemporaryDirectory(prefix="lidarcat-find-") as tmp:
        return run(tmp)


def n_blocks(index: Any, area: Sequence[float], *, cell_m: float = 20.0, block_cells: int = 4,
             params: Any = None) -> int:
    """Number of block tasks (for a progress bar)."""
    return len(find_jobs(index, area, ".", params=params, cell_m=cell_m, block_cells=block_cells))
