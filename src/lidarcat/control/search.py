"""Tile-parallel roof-vertex search: :func:`~lidarcat.control.vertices.find_candidates` over blocks of cells.

The serial search cuts the area into cells of ``cell_m`` and, for each cell,
segments its points plus a 2 m rim, keeps the vertices of 3+ faces inside the
cell as seeds, refines each seed with the points within ``radius_m`` and checks
the vertex found (the radius-stability check, ``stability_scales``: clips of up to
1.5 x ``radius_m`` about a vertex that lies within 1 m of its seed).  A cell
therefore needs only the points within

    margin = max(cell_m / 2 + 2, radius_m x max(1, stability_scales) + 1) + 1   (m)

of it (:func:`~lidarcat.control.vertices.search_margin_m`; 14 m at the defaults, 13 m
without the check; the ``cell_m/2`` covers the square window of a narrower edge cell).
Here the cell grid, anchored at the area's lower-left corner exactly as in the serial run, is split into blocks of
``block_cells x block_cells`` cells; each block is one
:class:`~lidarcat.lidar.jobs.TileJob` running :func:`search_block`, that reads from the
tiles only the points of its block plus the margin (beyond the area too: a
candidate near the area's edge is extracted and checked with all its points, as
``extract --at`` there would; the serial run reads the area plus the margin,
:func:`search_area`), searches its cells and writes its candidates,
tagged ``(i, j, k)`` = cell and seed order, as a ``.npz`` of plain arrays
(:func:`write_block`; no pickle: the work folder may be shared with other
machines, and reading it must never run code).  The blocks run through
:func:`~lidarcat.lidar.jobs.run_jobs` (serial, a ``LocalCluster`` or a
running scheduler; retries; done-markers holding each block file's SHA-256,
so a rerun with the same work folder resumes and redoes a changed block).  The
driver reads a block only when its bytes match its marker
(:func:`~lidarcat.lidar.jobs.read_done_output`) and rebuilds the candidates
field by field (:func:`read_block`).  The driver sorts all tags into the serial seed order and applies the
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
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._util.frozen import frozen_array
from ..errors import TileIOError
from .params import ExtractionParams, get_params
from .planes import Plane
from .vertices import (
    STATUSES,
    Candidate,
    ControlPoint,
    cell_counts,
    merge_candidates,
    search_cells,
    search_margin_m,
    search_points,
)

if TYPE_CHECKING:
    from ..lidar.jobs import TileJob

__all__ = ["find_candidates_tiles", "find_jobs", "n_blocks", "read_block", "run_find_block", "search_area",
           "search_block", "write_block"]

log = logging.getLogger(__name__)


def search_area(area: Sequence[float], params: Any = None, cell_m: float = 20.0) -> tuple[float, float, float, float]:
    """The box of the points a search of *area* reads: *area* plus
    :func:`~lidarcat.control.vertices.search_margin_m` on every side (m).

    A candidate near the area's edge is refined and checked (``stability_scales``) with clips that reach
    beyond the area; reading only the area would cut them.

    Examples
    --------
    >>> search_area((0.0, 0.0, 100.0, 50.0))
    (-14.0, -14.0, 114.0, 64.0)
    """
    m = search_margin_m(get_params(params), cell_m)
    xmin, ymin, xmax, ymax = (float(v) for v in area)
    return (xmin - m, ymin - m, xmax + m, ymax + m)


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
            tiles = [str(t.path) for t in index.tiles_in_box(bx0 - margin, by0 - margin, bx1 + margin, by1 + margin)]
            if not tiles:
                continue
            job_params = {"cells": [i0, i1, j0, j1], "area": [xmin, ymin, xmax, ymax], "cell_m": float(cell_m),
                          "min_score": float(min_score), "classes": None if classes is None else list(classes),
                          "extraction": dataclasses.asdict(p)}
            jobs.append(TileJob(search_block, tiles[0], (bx0, by0, bx1, by1), tuple(tiles[1:]),
                                str(Path(work_dir) / f"find_{i0:05d}_{j0:05d}.npz"), job_params,
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
    cloud = index.query_box(bx0 - m, by0 - m, bx1 + m, by1 + m)
    xyz, box = search_points(cloud, (xmin, ymin, xmax, ymax), p, prm["classes"])
    if xyz is None:
        return []
    i0, i1, j0, j1 = prm["cells"]
    cells = [(i, j) for i in range(i0, i1) for j in range(j0, j1)]
    return search_cells(xyz, box, cells, p, prm["cell_m"], prm["min_score"])


def search_block(job: TileJob) -> None:
    """The tile function of the block search (for :mod:`lidarcat.lidar.jobs`): :func:`run_find_block`,
    its tagged candidates written to ``job.output`` (:func:`write_block`)."""
    write_block(Path(job.output), run_find_block(job))


#: version of the block file layout (a ``version`` array in the .npz)
_BLOCK_VERSION = 1


def write_block(path: Path, found: list) -> None:
    """Write a block's tagged candidates ``[((i, j, k), Candidate), ...]`` atomically as a ``.npz`` of plain arrays.

    One row per candidate (tag, score and the :class:`~lidarcat.control.vertices.ControlPoint`
    fields), one row per plane (``plane_of`` = its candidate's row) and the
    candidates' clip points and face labels (``label_n`` points per candidate,
    -1 for none) concatenated.  Numbers, strings and nothing else: reading it
    back (:func:`read_block`) cannot run code.
    """
    from .._util import atomic_write

    cps = [c.point for _, c in found]
    planes = [(r, pl) for r, cp in enumerate(cps) for pl in cp.planes]
    labelled = [cp.labels for cp in cps if cp.labels is not None]

    def col(values: list, dtype: Any, shape: tuple[int, ...] = ()) -> np.ndarray:
        return np.array(values, dtype=dtype).reshape((len(values), *shape))

    arrays = {
        "version": np.array([_BLOCK_VERSION], dtype=np.int64),
        "tag": col([list(t) for t, _ in found], np.int64, (3,)),
        "score": col([c.score for _, c in found], np.float64),
        "point_id": col([cp.point_id for cp in cps], np.str_),
        "enh_m": col([cp.enh_m for cp in cps], np.float64, (3,)),
        "cov_m2": col([cp.cov_m2 for cp in cps], np.float64, (3, 3)),
        "n_planes": col([cp.n_planes for cp in cps], np.int64),
        "misclosure_m": col([cp.misclosure_m for cp in cps], np.float64),
        "status": col([cp.status for cp in cps], np.str_),
        "reason": col([cp.reason for cp in cps], np.str_),
        "approx_en": col([cp.approx_en for cp in cps], np.float64, (2,)),
        "chi2": col([cp.chi2 for cp in cps], np.float64),
        "cov_source": col([cp.cov_source for cp in cps], np.str_),
        "plane_of": col([r for r, _ in planes], np.int64),
        "plane_n": col([pl.n for _, pl in planes], np.float64, (3,)),
        "plane_d": col([pl.d for _, pl in planes], np.float64),
        "plane_cov": col([pl.cov for _, pl in planes], np.float64, (4, 4)),
        "plane_centroid_m": col([pl.centroid_m for _, pl in planes], np.float64, (3,)),
        "plane_n_used": col([pl.n_used for _, pl in planes], np.int64),
        "plane_n_rejected": col([pl.n_rejected for _, pl in planes], np.int64),
        "plane_rms_m": col([pl.rms_m for _, pl in planes], np.float64),
        "plane_label": col([pl.label for _, pl in planes], np.int64),
        "label_n": col([-1 if cp.labels is None else len(cp.labels[0]) for cp in cps], np.int64),
        "label_xyz": (np.concatenate([np.asarray(x, dtype=np.float64).reshape(-1, 3) for x, _ in labelled])
                      if labelled else np.zeros((0, 3))),
        "label_face": (np.concatenate([np.asarray(f, dtype=np.int64).reshape(-1) for _, f in labelled])
                       if labelled else np.zeros(0, dtype=np.int64)),
    }
    with atomic_write(path, "wb") as fh:
        np.savez(fh, **arrays)  # no object array among them: nothing is pickled


def _rebuilt(cls: type, **fields: Any) -> Any:
    """An instance of the frozen value type *cls* holding exactly *fields*, as written.

    Not through ``cls(...)``: its ``__post_init__`` would normalise a plane's
    normal once more and could move the last bit, and the parallel search must
    give the serial candidates bit for bit.  *fields* are checked by the caller
    (and ``test_block_file_round_trip_keeps_every_field`` checks they are all of them).
    """
    obj = object.__new__(cls)
    for k, v in fields.items():
        object.__setattr__(obj, k, v)
    return obj


def read_block(data: bytes, path: str | os.PathLike = "<block>") -> list:
    """The tagged candidates ``[((i, j, k), Candidate), ...]`` of a block file written by :func:`write_block`.

    *data* is the file's content (see :func:`~lidarcat.lidar.jobs.read_done_output`),
    *path* its name for messages.  Loaded with ``allow_pickle=False`` and
    checked array by array (dtype, shape, counts, statuses) before any
    candidate is built.

    Raises
    ------
    TileIOError
        Not a block file of this version (names *path* and the array at fault).
    """
    from ..lidar.jobs import read_npz

    def bad(what: str) -> TileIOError:
        return TileIOError(f"{path}: not a block file of the vertex search ({what}); delete it and its "
                           f".done.json marker to recompute the block")

    try:
        a = read_npz(data, path)
    except TileIOError as ex:
        raise bad(str(ex).removeprefix(f"{path}: ")) from None
    shapes = {"version": ("i", ()), "tag": ("i", (3,)), "score": ("f", ()), "point_id": ("U", ()),
              "enh_m": ("f", (3,)), "cov_m2": ("f", (3, 3)), "n_planes": ("i", ()), "misclosure_m": ("f", ()),
              "status": ("U", ()), "reason": ("U", ()), "approx_en": ("f", (2,)), "chi2": ("f", ()),
              "cov_source": ("U", ()), "plane_of": ("i", ()), "plane_n": ("f", (3,)), "plane_d": ("f", ()),
              "plane_cov": ("f", (4, 4)), "plane_centroid_m": ("f", (3,)), "plane_n_used": ("i", ()),
              "plane_n_rejected": ("i", ()), "plane_rms_m": ("f", ()), "plane_label": ("i", ()),
              "label_n": ("i", ()), "label_xyz": ("f", (3,)), "label_face": ("i", ())}
    if sorted(a) != sorted(shapes):
        raise bad(f"arrays {sorted(set(a) ^ set(shapes))!r:.80} missing or unknown")
    for k, (kind, shape) in shapes.items():
        if a[k].dtype.kind != kind or a[k].ndim != 1 + len(shape) or a[k].shape[1:] != shape:
            raise bad(f"array {k!r} is {a[k].dtype} {a[k].shape}")
    if a["version"].tolist() != [_BLOCK_VERSION]:
        raise bad(f"version {a['version'].tolist()!r:.40}, expected {_BLOCK_VERSION}")
    n, m, n_lab = len(a["tag"]), len(a["plane_of"]), len(a["label_xyz"])
    rows = [k for k in shapes if not k.startswith(("plane_", "label_", "version"))] + ["label_n"]
    if any(len(a[k]) != n for k in rows) or any(len(a[k]) != m for k in shapes if k.startswith("plane_")):
        raise bad("arrays of unequal length")
    label_n = a["label_n"]
    if (label_n < -1).any() or int(label_n[label_n > 0].sum()) != n_lab or len(a["label_face"]) != n_lab:
        raise bad("label counts do not add up")
    if ((a["plane_of"] < 0) | (a["plane_of"] >= n)).any() or (np.diff(a["plane_of"]) < 0).any():
        raise bad("plane rows out of order")
    unknown = set(a["status"].tolist()) - set(STATUSES)
    if unknown:
        raise bad(f"unknown status {sorted(unknown)[0]!r:.40}")

    planes: list[list[Plane]] = [[] for _ in range(n)]
    for q in range(m):
        planes[int(a["plane_of"][q])].append(_rebuilt(
            Plane, n=frozen_array(a["plane_n"][q]), d=float(a["plane_d"][q]), cov=frozen_array(a["plane_cov"][q]),
            centroid_m=frozen_array(a["plane_centroid_m"][q]), n_used=int(a["plane_n_used"][q]),
            n_rejected=int(a["plane_n_rejected"][q]), rms_m=float(a["plane_rms_m"][q]),
            label=int(a["plane_label"][q])))
    found = []
    start = 0
    for r in range(n):
        k = int(label_n[r])
        labels = None
        if k >= 0:
            labels = (frozen_array(a["label_xyz"][start:start + k]),
                      frozen_array(a["label_face"][start:start + k], dtype=None))
            start += k
        cp = _rebuilt(
            ControlPoint, point_id=str(a["point_id"][r]), enh_m=frozen_array(a["enh_m"][r]),
            cov_m2=frozen_array(a["cov_m2"][r]), n_planes=int(a["n_planes"][r]),
            misclosure_m=float(a["misclosure_m"][r]), status=str(a["status"][r]), reason=str(a["reason"][r]),
            planes=tuple(planes[r]), approx_en=frozen_array(a["approx_en"][r]), chi2=float(a["chi2"][r]),
            cov_source=str(a["cov_source"][r]), labels=labels)
        found.append((tuple(int(t) for t in a["tag"][r]), Candidate(cp, float(a["score"][r]))))
    return found


def find_candidates_tiles(index: Any, area: Sequence[float], *, params: Any = None, cell_m: float = 20.0,
                          min_score: float = 0.2, classes: Sequence[int] | None = None, block_cells: int = 4,
                          crs: Any = None, work_dir: str | os.PathLike | None = None, workers: int | None = None,
                          scheduler: str | None = None, resume: bool = True,
                          progress: Callable[[int], Any] | None = None) -> list:
    """Candidates of :func:`~lidarcat.control.vertices.find_candidates` over *area* of the tiles, block-parallel.

    Identical to ``find_candidates(index.query_box(*search_area(area, params)), box=area, ...)``.

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
    from ..lidar.jobs import read_done_output, run_jobs

    def run(folder: str | os.PathLike) -> list:
        jobs = find_jobs(index, area, folder, crs=crs, params=params, cell_m=cell_m, min_score=min_score,
                         classes=classes, block_cells=block_cells)
        log.info("roof-vertex search: %d blocks of up to %d x %d cells", len(jobs), block_cells, block_cells)
        run_jobs(jobs, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
        found = []
        for j in jobs:  # only the bytes each block's done-marker vouches for
            found.extend(read_block(read_done_output(j), j.output))
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
