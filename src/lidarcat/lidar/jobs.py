"""The tile engine: a function run on every tile of a survey, serially or on a Dask cluster.

As lidR's ``catalog_map(ctg, FUN)``, the engine knows no product: a run is a
list of :class:`TileJob`, each naming the function that makes its output
(``job.func(job)``: a module-level function, so Dask pickles it by name), one
input tile, the neighbour tiles whose points within ``overlap_m`` of it are
needed (ground classification and rasters see across the tile edge, so seams
do not show), one output file and the parameters.  The products pass their own
functions (:func:`lidarcat.production.ground.ground_tile`,
:func:`lidarcat.production.terrain.dtm_tile` and ``dsm_tile``,
:func:`lidarcat.control.search.search_block`); a function reads its tile and
the neighbours' points with :func:`read_with_buffer` and writes
``job.output``.  :func:`run_jobs` runs them

* serially in this process (``workers=None`` and no ``scheduler``), or
* on a ``LocalCluster`` of ``workers`` single-threaded worker processes, or on
  an existing cluster (``scheduler="tcp://host:8786"``).

The same function computes each tile either way, so the outputs are identical.
Memory per worker is bounded by one tile plus its overlap, not the survey.

Edge buffers
------------
A tile's overlap comes from up to eight neighbours; decoding each of them
whole for every tile decodes the survey nine times over (LAZ decoding then
dominated every production run).  So a run first makes one *edge buffer* per
tile (``ring`` jobs, in the same scheduler): the tile is decoded once and its
points inside any neighbour's buffered box are saved in file order as an
uncompressed ``.npz`` per neighbour under ``<output folder>/.buffers/``, for the jobs that
read through :func:`read_with_buffer` (``buffered=True``).  A tile job then
reads its own tile and the neighbours' buffers, keeping the points in its
buffered box, in the order a :class:`TileIndex` query returns them: the same
points as decoding the neighbours, so the outputs do not change.  The buffers
are resumable like the outputs and are deleted at the end of a run.

Resumable: each finished output gets a ``<output>.done.json`` marker holding
the function's name, the input tiles' sizes and modification times, the job's
parameters and the SHA-256 of every file it vouches for (the output; for an
edge-buffer job also its ``.npz`` pieces); a rerun skips a job only when the
marker matches and every file still has its recorded hash, so a changed,
truncated or replaced output is made again, never trusted.  A tile job reads a
neighbour's piece only when its bytes have the hash the edge-buffer marker
recorded (else it decodes the neighbour itself), and
:func:`read_done_output` gives a job's output only when it matches its marker.
Work files are data (``.npz`` read with ``allow_pickle=False``, JSON), never a
format that executes code when read (pickle).  Outputs are written
atomically, so a killed run leaves whole files or none.  A worker that dies
mid-tile: the scheduler gives its tile to another worker (``retries``).  A
missing or corrupt tile, or an output that cannot be written (full disk), ends
the run with an error naming the file; the finished tiles stay done.

Work that is not a tile of points runs on the same schedulers through two mappers:
:func:`run_tasks` (``func(task)``, tasks made lazily with a few in flight per worker, for
tasks that carry data: the charts' mosaic crops) and :func:`map_tasks`
(``func(shared, item)``, *shared* scattered once to every worker and also a thread pool, for
many small tasks over one large context: the photos and pairs of ``match``).  Both return the
results in task order and re-raise the first worker's error; :func:`dask_client` and
``run_jobs`` start their clusters through one private helper.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import uuid
import zipfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import FormatError, LidarcatError, TileIOError

__all__ = ["TileJob", "TileFunction", "run_jobs", "run_on_client", "run_tile_job", "tile_jobs",
           "read_with_buffer", "edge_buffer_jobs", "read_done_output", "read_npz", "run_tasks",
           "map_tasks", "dask_client", "SCHEDULERS"]

log = logging.getLogger(__name__)

#: what a job runs: ``func(job)`` writes ``job.output`` (atomically); its return value is ignored
TileFunction = Callable[["TileJob"], Any]


@dataclass(frozen=True)
class TileJob:
    """One tile of a production run.

    Attributes
    ----------
    func : callable
        ``func(job)`` makes the output: a module-level function (Dask
        workers import it by name; the done-marker records that name).  E.g.
        :func:`lidarcat.production.ground.ground_tile`; or
        :func:`lidarcat.control.search.search_block`, whose ``bounds`` is a
        block of search cells and ``tile`` and ``neighbours`` the tiles it meets.
    tile : str
        Input tile path.
    bounds : (xmin, ymin, xmax, ymax)
        The tile's own area, metres (from its header).
    neighbours : tuple of str
        Tiles whose points within ``overlap_m`` are read too.
    output : str
        Output path (e.g. ``.las``/``.laz`` for ground, ``.tif`` for rasters).
    params : dict
        Keyword parameters of the job (method, PTD/SMRF parameters, cell_m, ...);
        JSON-serialisable (they go into the done-marker).
    crs : str or None
        CRS for tiles that carry none.
    overlap_m : float
        Buffer read around the tile, metres.
    buffered : bool
        *func* reads the tile with :func:`read_with_buffer`, so the run makes
        the neighbours' edge buffers first (see the module docstring).
    """

    func: TileFunction
    tile: str
    bounds: tuple[float, float, float, float]
    neighbours: tuple[str, ...]
    output: str
    params: dict[str, Any] = field(default_factory=dict)
    crs: str | None = None
    overlap_m: float = 0.0
    buffered: bool = True

    def __post_init__(self) -> None:
        name = getattr(self.func, "__qualname__", "")
        if not callable(self.func) or not name or "<" in name:
            raise ValueError(f"a tile job's function must be a module-level function (Dask workers import "
                             f"it by name), got {self.func!r}")

    @property
    def name(self) -> str:
        """The function's import name, ``module.qualname``."""
        return f"{self.func.__module__}.{self.func.__qualname__}"

    def signature(self) -> dict[str, Any]:
        """What makes the output stale: the function, inputs (size, mtime) and parameters."""
        def stamp(p: str) -> list[Any]:
            st = os.stat(p)
            return [p, st.st_size, st.st_mtime_ns]
        return {"function": self.name, "inputs": [stamp(p) for p in (self.tile, *self.neighbours)],
                "params": {k: v for k, v in sorted(self.params.items())}, "crs": self.crs,
                "overlap_m": self.overlap_m}


#: the largest done-marker read back, bytes (a marker holds a signature and hashes, never data)
_MARKER_MAX_BYTES = 1 << 22


def _marker(job: TileJob) -> Path:
    return Path(job.output + ".done.json")


def _vouched(job: TileJob) -> list[str]:
    """The files a job's done-marker vouches for: its output, and an edge-buffer job's pieces."""
    return [job.output, *(job.params["pieces"] if job.func is _write_ring else ())]


def _write_marker(job: TileJob) -> None:
    """The done-marker of a finished job: its signature and the SHA-256 of every file it vouches for."""
    from .._util import file_sha256, write_json_atomic

    write_json_atomic(_marker(job), {**job.signature(), "sha256": {p: file_sha256(p) for p in _vouched(job)}})


def _read_marker(path: Path) -> dict[str, Any] | None:
    """A done-marker's content, or None when it is missing, too large or not a JSON object."""
    try:
        if not path.is_file() or path.stat().st_size > _MARKER_MAX_BYTES:
            return None
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError):
        return None
    return content if isinstance(content, dict) else None


def _recorded_sha256(marker: dict[str, Any] | None, path: str) -> str | None:
    """The SHA-256 a marker records for *path* (None when it records none)."""
    files = marker.get("sha256") if marker is not None else None
    sha = files.get(path) if isinstance(files, dict) else None
    return sha if isinstance(sha, str) else None


def _is_done(job: TileJob) -> bool:
    """The job's marker matches its signature and every file it vouches for has the recorded hash."""
    from .._util import file_sha256

    marker = _read_marker(_marker(job))
    if marker is None:
        return False
    try:
        signature = json.loads(json.dumps(job.signature()))
        if {k: v for k, v in marker.items() if k != "sha256"} != signature:
            return False
        files = marker.get("sha256")
        return (isinstance(files, dict) and sorted(files) == sorted(_vouched(job))
                and all(Path(p).is_file() and file_sha256(p) == files[p] for p in _vouched(job)))
    except OSError:  # an input or output vanished or cannot be read: redo the job (its errors name the file)
        return False


def read_done_output(job: TileJob) -> bytes:
    """The bytes of a finished job's output, checked against the SHA-256 its done-marker recorded.

    Read once and hashed in memory, so what is returned is what was checked.

    Raises
    ------
    TileIOError
        The output cannot be read, or it (or its marker) changed since the job
        finished: names the output and says how to recompute it.
    """
    out = Path(job.output)
    try:
        data = out.read_bytes()
    except OSError as ex:
        raise TileIOError(f"{out}: cannot read the output of tile {job.tile} ({ex.strerror or ex})") from ex
    if hashlib.sha256(data).hexdigest() != _recorded_sha256(_read_marker(_marker(job)), job.output):
        raise TileIOError(f"{out}: does not match the SHA-256 of its done-marker {_marker(job).name} (changed "
                          f"after its job finished); delete both to recompute it")
    return data


def read_npz(data: bytes, path: str | os.PathLike) -> dict[str, Any]:
    """The arrays of the ``.npz`` *data* (the content of the work file *path*), read as data only.

    ``allow_pickle=False`` (an object array, which would unpickle, is refused)
    and members adding up to no more than the file itself (:func:`numpy.savez`
    stores its arrays uncompressed, so arrays inflating beyond that are a zip bomb).

    Raises
    ------
    TileIOError
        Not such an ``.npz`` (names *path*; the reason is a short escaped excerpt).
    """
    import numpy as np

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as zf:
            inflated = sum(i.file_size for i in zf.infolist())
        if inflated > len(data):
            raise TileIOError(f"{path}: not an uncompressed .npz (its arrays inflate to {inflated} bytes, "
                              f"beyond the file's {len(data)})")
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as ex:
        if isinstance(ex, TileIOError):
            raise
        raise TileIOError(f"{path}: not a readable .npz ({str(ex)!r:.80})") from None


def _ring_path(job: TileJob, tile: str) -> Path:
    """Manifest of the edge buffers of *tile* for the run of *job* (next to the job's output)."""
    return Path(job.output).parent / ".buffers" / f"{Path(tile).name}.{job.overlap_m:g}.json"


def _piece_path(job: TileJob, tile: str) -> Path:
    """The points of neighbour *tile* that *job* needs (its strip of the edge buffer)."""
    return Path(job.output).parent / ".buffers" / f"{Path(tile).name}.{job.overlap_m:g}.for.{Path(job.tile).name}.npz"


def _write_ring(job: TileJob) -> None:
    """For each box of ``job.params["boxes"]``, the points of ``job.tile`` inside it (file order),
    as the .npz ``job.params["pieces"][i]``; then the manifest ``job.output``.

    Raises
    ------
    TileIOError
        A piece or the manifest cannot be written (names the manifest and the tile).
    """
    import numpy as np

    from .._util import atomic_write, write_json_atomic
    from .crs import crs_label
    from .readers import read_points
    from .membership import in_box

    pc = read_points(job.tile, crs=job.crs)
    label = np.array(crs_label(pc.crs) if pc.crs is not None else "")
    try:
        for box, piece in zip(job.params["boxes"], job.params["pieces"]):
            keep = in_box(pc.xyz, *box)
            arrays = {"xyz": pc.xyz[keep], "crs": label}
            arrays.update({f"a_{k}": np.asarray(v)[keep] for k, v in pc.attributes.items()})
            with atomic_write(piece, "wb") as fh:
                np.savez(fh, **arrays)
        write_json_atomic(job.output, {"tile": job.tile, "pieces": list(job.params["pieces"])})
    except OSError as ex:
        raise TileIOError(f"{job.output}: cannot write the edge buffer of tile {job.tile} "
                          f"({ex.strerror or ex})") from ex


def edge_buffer_jobs(jobs: Sequence[TileJob]) -> list[TileJob]:
    """The edge-buffer jobs a run of *jobs* needs: one per tile that neighbours a buffered job.

    Each writes, for every buffered job the tile neighbours, the tile's points
    inside that job's buffered box (one ``.npz`` piece per job) and a manifest.
    """
    pieces: dict[tuple[str, str, float, str | None], list[tuple[list[float], str]]] = {}
    first: dict[tuple[str, str, float, str | None], TileJob] = {}
    for j in jobs:
        if not j.buffered or j.overlap_m <= 0:
            continue
        o = j.overlap_m
        box = [j.bounds[0] - o, j.bounds[1] - o, j.bounds[2] + o, j.bounds[3] + o]
        for nb in j.neighbours:
            key = (nb, str(_ring_path(j, nb)), o, j.crs)
            pieces.setdefault(key, []).append((box, str(_piece_path(j, nb))))
            first.setdefault(key, j)
    out = []
    for key, bp in pieces.items():
        nb, ring, o, crs = key
        bp = sorted(bp, key=lambda t: t[1])
        out.append(TileJob(_write_ring, nb, first[key].bounds, (), ring,
                           {"boxes": [b for b, _ in bp], "pieces": [p for _, p in bp]}, crs, o, buffered=False))
    return out


def _read_ring(job: TileJob, tile: str, box: tuple[float, float, float, float], crs_label_own: str) -> Any:
    """Points of *tile*'s edge-buffer piece for *job* inside *box*, or None when the piece is missing, of
    another CRS, or not the bytes its edge-buffer marker vouches for (then the caller decodes *tile*)."""
    import numpy as np

    from .cloud import PointCloud
    from .membership import in_box

    piece = _piece_path(job, tile)
    marker = _read_marker(Path(str(_ring_path(job, tile)) + ".done.json"))
    try:
        data = piece.read_bytes()
        if hashlib.sha256(data).hexdigest() != _recorded_sha256(marker, str(piece)):
            return None
        z = read_npz(data, piece)
        if str(z["crs"]) != crs_label_own:
            return None
        xyz = z["xyz"]
        m = in_box(xyz, *box)
        attrs = {k[2:]: v[m] for k, v in z.items() if k.startswith("a_")}
        return PointCloud(xyz[m], attrs)  # the caller gives it the tile's CRS
    except (OSError, ValueError, KeyError, IndexError, TypeError):  # TileIOError is an OSError
        return None


def read_with_buffer(job: TileJob) -> tuple[Any, int]:
    """The tile's points followed by the neighbours' points within the overlap, and the tile's count.

    The neighbours' points come from their edge buffers when the run made them
    (see the module docstring), else from the neighbour files themselves; the
    same points in the same order either way.  Only the attributes that every
    part carries are kept.

    Returns
    -------
    cloud : PointCloud
        ``n_own`` points of ``job.tile`` (file order), then those of the
        neighbours inside the tile's box grown by ``job.overlap_m``.
    n_own : int
    """
    from .cloud import PointCloud
    from .crs import crs_label
    from .readers import read_points
    from .tileindex import TileIndex

    own = read_points(job.tile, crs=job.crs)
    if not job.neighbours or job.overlap_m <= 0:
        return own, len(own)
    xmin, ymin, xmax, ymax = job.bounds
    o = job.overlap_m
    box = (xmin - o, ymin - o, xmax + o, ymax + o)
    idx = TileIndex.build(list(job.neighbours), crs=job.crs)
    own_label = crs_label(own.crs) if own.crs is not None else ""
    parts: list[Any] = []
    for t in idx.tiles_in_box(*box):
        part = _read_ring(job, str(t.path), box, own_label)
        if part is None:
            parts = []
            break
        parts.append(part)
    if parts:  # concatenated on the attributes every piece carries
        common = [k for k in parts[0].attributes if all(k in p.attributes for p in parts)]
        extra = PointCloud.concat([PointCloud(p.xyz, {k: p.attributes[k] for k in common}, own.crs)
                                   for p in parts])
    else:
        extra = idx.query_box(*box)
    keep = [k for k in own.attributes if k in extra.attributes]
    own_k = PointCloud(own.xyz, {k: own.attributes[k] for k in keep}, own.crs)
    extra_k = PointCloud(extra.xyz, {k: extra.attributes[k] for k in keep}, own.crs)
    return PointCloud.concat([own_k, extra_k]), len(own)


def run_tile_job(job: TileJob) -> str:
    """Run ``job.func(job)`` and write the done-marker; return the output path.

    Raises
    ------
    TileIOError
        The output cannot be written (names it: full disk, permissions).
    LidarcatError
        Whatever located error the function raises (e.g. a corrupt or
        missing input tile), unchanged.
    """
    out = Path(job.output)
    try:
        job.func(job)
        _write_marker(job)
    except LidarcatError as ex:
        if job.tile in str(ex):
            raise
        raise type(ex)(f"{job.tile}: {ex}") from ex  # a data condition of the tile (no ground...)
    except OSError as ex:
        raise TileIOError(f"{out}: cannot write the output of tile {job.tile} ({ex.strerror or ex})") from ex
    return str(out)


def tile_jobs(func: TileFunction, paths: Sequence[str | os.PathLike], out: str | os.PathLike, *,
              crs: Any = None, params: dict[str, Any] | None = None, overlap_m: float = 0.0,
              suffix: str | None = None) -> list[TileJob]:
    """One :class:`TileJob` running *func* per tile; neighbours are the tiles within *overlap_m* of it.

    With several tiles, each tile's bounds are first measured from its points (one read per
    tile, :meth:`TileIndex.verify_bounds`): header bounds are unverified claims, and a tile with
    unverified bounds would be every other tile's neighbour.

    Parameters
    ----------
    func : callable
        ``func(job)``, module-level (see :class:`TileJob`); it reads the tile
        with :func:`read_with_buffer` (the jobs are ``buffered``).
    paths : sequence of path-like
        Input tiles.
    out : path-like
        A file when there is one tile and its suffix names a file type
        (``.las``, ``.laz``, ``.tif``), else a folder receiving ``<tile stem><suffix>``.
    crs : str or CRS, optional
        CRS of tiles that carry none.
    params : dict, optional
        The jobs' parameters (JSON-serialisable).
    overlap_m : float
        Neighbour buffer, metres.
    suffix : str, optional
        Output suffix in a folder (default the tile's own).
    """
    from .crs import crs_label
    from .tileindex import TileIndex

    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("no tiles given")
    index = TileIndex.build(paths, crs=crs)
    if len(index.tiles) > 1:
        # A LAS header's bounds are a claim; an unverified tile "may meet" every box, so each
        # job would read every other tile as its neighbour (n^2 reads).  One read per tile
        # measures them instead (n reads).
        index.verify_bounds()
    tiles = list(index.tiles)
    out = Path(out)
    single = len(tiles) == 1 and out.suffix.lower() in (".las", ".laz", ".tif", ".tiff")
    crs_s = crs if crs is None or isinstance(crs, str) else crs_label(crs)
    jobs = []
    for t in tiles:
        b = t.bounds
        nb = tuple(str(u.path) for u in index.tiles_in_box(b.xmin - overlap_m, b.ymin - overlap_m,
                                                           b.xmax + overlap_m, b.ymax + overlap_m)
                   if Path(u.path) != Path(t.path))
        dst = out if single else out / (Path(t.path).stem + (suffix or Path(t.path).suffix))
        jobs.append(TileJob(func, str(t.path), (b.xmin, b.ymin, b.xmax, b.ymax), nb, str(dst),
                            dict(params or {}), crs_s, float(overlap_m)))
    return jobs


def run_jobs(jobs: Sequence[TileJob], *, workers: int | None = None, scheduler: str | None = None,
             resume: bool = True, retries: int = 2,
             progress: Callable[[int], Any] | None = None) -> list[str]:
    """Run tile jobs serially (default) or on Dask; return the output paths in job order.

    Parameters
    ----------
    jobs : sequence of TileJob
    workers : int, optional
        Start a ``LocalCluster`` with this many single-threaded worker processes.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); wins over *workers*.
    resume : bool
        Skip jobs whose output and done-marker match (finished tiles are not redone).
    retries : int
        Dask: times a tile is retried after a failure (e.g. its worker died).
    progress : callable, optional
        Called with 1 per finished (or skipped) tile.
    """
    todo = [j for j in jobs if not (resume and _is_done(j))]
    skipped = len(jobs) - len(todo)
    if skipped:
        log.info("%d of %d tiles already done; skipped", skipped, len(jobs))
        if progress is not None:
            progress(skipped)
    rings = [r for r in edge_buffer_jobs(todo) if not (resume and _is_done(r))]
    if workers is None and scheduler is None:
        for r in rings:
            run_tile_job(r)
        for j in todo:
            run_tile_job(j)
            if progress is not None:
                progress(1)
        _drop_rings(todo)
        return [j.output for j in jobs]
    with _client(workers, scheduler) as client:
        run_on_client(client, todo, rings=rings, retries=retries, progress=progress)
    return [j.output for j in jobs]


@contextlib.contextmanager
def _client(workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """A ``dask.distributed.Client`` of the scheduler at *scheduler*, else of a ``LocalCluster`` of
    *workers* single-threaded processes (closed on exit)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as ex:  # pragma: no cover - the extra is installed in CI
        raise FormatError("parallel runs need dask.distributed: pip install 'lidarcat[cluster]'") from ex
    cluster = None
    if scheduler is not None:
        client = Client(scheduler)
    else:
        if workers is None or workers < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=":0")  # any free port: runs side by side
        client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tasks(func: Callable[[Any], Any], tasks: Iterable[Any], *, workers: int | None = None,
              scheduler: str | None = None, retries: int = 2, window: int = 2,
              progress: Callable[[int], Any] | None = None) -> list[Any]:
    """``[func(t) for t in tasks]``, serially (default) or on Dask as :func:`run_jobs` runs tiles.

    For work that grows with the survey but is not a tile of points (the orthophoto charts of a sheet
    index): the engine knows no product, the caller passes a module-level *func* and picklable tasks.
    The same *func* computes each task either way, so the results are identical.

    Parameters
    ----------
    func : callable
        Module-level (Dask workers import it by name).
    tasks : iterable
        Made lazily: at most ``window`` tasks per worker are in flight at once, so tasks that carry data
        (a mosaic crop) hold a few tasks' worth of it, not the survey's.
    workers, scheduler, retries
        As :func:`run_jobs`.
    window : int
        Tasks in flight per worker (Dask).
    progress : callable, optional
        Called with 1 per finished task, in the calling process.

    Returns
    -------
    list
        ``func(task)`` of each task, in task order.

    Raises
    ------
    Exception
        The first failing task's error, re-raised in the caller (unfinished tasks are cancelled).
    """
    if workers is None and scheduler is None:
        out = []
        for t in tasks:
            out.append(func(t))
            if progress is not None:
                progress(1)
        return out
    with _client(workers, scheduler) as client:
        results: dict[int, Any] = {}
        for k, r in _windowed(client, func, ((t,) for t in tasks), retries=retries, window=window,
                              workers=int(workers or 1)):
            results[k] = r
            if progress is not None:
                progress(1)
    return [results[k] for k in range(len(results))]


def _windowed(client: Any, func: Callable[..., Any], args: Iterable[tuple[Any, ...]], *, retries: int,
              window: int, workers: int = 1) -> Iterator[tuple[int, Any]]:
    """``(k, func(*args_k))`` as tasks finish on *client*: the argument tuples are taken lazily, at most
    *window* per worker in flight; keys unique per call (runs may share a scheduler); the first
    failing task's error is raised here and the tasks still in flight are cancelled."""
    from dask.distributed import as_completed

    limit = max(1, window) * max(1, len(client.scheduler_info().get("workers", {})) or workers)
    it = iter(enumerate(args))
    order: dict[Any, int] = {}   # the futures in flight and their task numbers
    name, run = getattr(func, "__name__", "task"), uuid.uuid4().hex[:12]

    def submit(queue: Any) -> bool:
        for k, a in it:
            fut = client.submit(func, *a, retries=retries, pure=False, key=f"{name}-{run}-{k}")
            order[fut] = k
            queue.add(fut)
            return True
        return False

    pending = as_completed([])
    for _ in range(limit):
        if not submit(pending):
            break
    try:
        for fut in pending:
            k = order.pop(fut)
            r = fut.result()  # re-raises the worker's error
            fut.release()
            yield k, r
            submit(pending)
    finally:
        if order:   # an error, or the caller stopped early
            client.cancel(list(order))


def run_on_client(client: Any, jobs: Sequence[TileJob], *, rings: Sequence[TileJob] | None = None,
                  retries: int = 2, progress: Callable[[int], Any] | None = None) -> None:
    """Run *jobs* on a connected ``dask.distributed.Client``: edge buffers first, then the tiles.

    *rings* default to every edge buffer the jobs need (:func:`run_jobs` passes
    only those not done yet).  The buffers are deleted when all jobs are done.
    """
    from dask.distributed import as_completed, wait

    rings = edge_buffer_jobs(jobs) if rings is None else rings
    if rings:
        rf = client.map(run_tile_job, rings, retries=retries, pure=False,
                        key=[f"ring-{i}-{Path(r.tile).name}" for i, r in enumerate(rings)])
        wait(rf)
        for f in rf:
            f.result()  # re-raises the worker's located error
    futures = client.map(run_tile_job, jobs, retries=retries, pure=False,
                         key=[f"{j.func.__name__}-{i}-{Path(j.tile).name}" for i, j in enumerate(jobs)])
    for fut in as_completed(futures):
        fut.result()  # re-raises the worker's located error
        if progress is not None:
            progress(1)
    _drop_rings(jobs)


def _drop_rings(jobs: Sequence[TileJob]) -> None:
    """Delete the edge buffers (and their markers) of a finished run."""
    folders = set()
    for r in edge_buffer_jobs(jobs):
        for p in (Path(r.output), _marker(r), *map(Path, r.params["pieces"])):
            p.unlink(missing_ok=True)
        folders.add(Path(r.output).parent)
    for f in folders:
        try:
            f.rmdir()
        except OSError:  # another run's buffers are still there
            pass


#: the local schedulers of :func:`map_tasks` (anything else is the address of a running Dask scheduler)
SCHEDULERS = ("synchronous", "threads", "processes")


@contextlib.contextmanager
def dask_client(workers: int = 1, scheduler: str = "threads") -> Iterator[Any]:
    """The Dask client of :func:`map_tasks` for *scheduler*, closed on exit; None for ``synchronous``
    and ``threads`` (no Dask cluster: this process).  ``processes`` starts a ``LocalCluster`` of
    *workers* single-threaded worker processes, as :func:`run_jobs` does; else *scheduler* is the
    address of a running scheduler.  One client serves several :func:`map_tasks` calls (the
    processes start once)."""
    if scheduler in ("synchronous", "threads"):
        yield None
        return
    processes = scheduler == "processes"
    with _client(max(int(workers), 1) if processes else None, None if processes else scheduler) as client:
        yield client


def map_tasks(func: Callable[[Any, Any], Any], shared: Any, items: Sequence[Any], *, workers: int = 1,
              scheduler: str = "threads", client: Any = None, retries: int = 2,
              progress: Callable[[int, int], Any] | None = None) -> list[Any]:
    """``[func(shared, item) for item in items]`` on the runner of :func:`run_jobs`, in item order.

    The tile runner's choice for tasks that are not tiles (the photos and pairs of
    :func:`lidarcat.match.match_block`): ``synchronous`` in this process; ``threads``, a pool of
    *workers* threads (for code that releases the GIL); ``processes``, a ``LocalCluster`` of
    *workers* single-threaded worker processes as :func:`run_jobs` starts; else the address of a
    running Dask scheduler (``tcp://host:8786``).  On Dask, *shared* is scattered once to every
    worker (each task gets that worker's copy), *func* is pickled by cloudpickle, the items are
    submitted as :func:`run_tasks` submits its tasks (a few per worker in flight), and each task's
    result comes back to this process: keep results small.  A script that uses ``processes`` needs
    the ``if __name__ == "__main__":`` guard (the workers are spawned).

    Parameters
    ----------
    func : callable
        ``func(shared, item)``.
    shared : object
        What every task needs (picklable for processes and a cluster).
    items : sequence
    workers : int
        Threads or processes (a cluster brings its own).
    scheduler : str
        One of :data:`SCHEDULERS` or a scheduler's address.
    client : dask.distributed.Client, optional
        A client of :func:`dask_client` (for processes or a cluster): used, not closed; default one
        for this call.
    retries : int
        Dask: times a task is retried after a failure (its worker died).
    progress : callable, optional
        ``progress(done, total)`` after each finished task.
    """
    items = list(items)
    n = len(items)
    out: list[Any] = [None] * n
    if scheduler == "synchronous" or (scheduler == "threads" and workers <= 1) or n == 0:
        for k, it in enumerate(items):
            out[k] = func(shared, it)
            if progress is not None:
                progress(k + 1, n)
        return out
    if scheduler == "threads":
        from concurrent.futures import ThreadPoolExecutor, as_completed as done_first

        with ThreadPoolExecutor(int(workers)) as pool:
            futures = {pool.submit(func, shared, it): k for k, it in enumerate(items)}
            for d, fut in enumerate(done_first(futures), 1):
                out[futures[fut]] = fut.result()
                if progress is not None:
                    progress(d, n)
        return out
    if client is None:
        with dask_client(workers, scheduler) as own:
            return map_tasks(func, shared, items, workers=workers, scheduler=scheduler, client=own,
                             retries=retries, progress=progress)
    ctx = client.scatter(shared, broadcast=True, hash=False)
    try:   # the window of run_tasks: 4 items per worker in flight, the workers never wait for the next
        for d, (k, r) in enumerate(_windowed(client, func, ((ctx, it) for it in items), retries=retries, window=4,
                                             workers=int(workers)), 1):
            out[k] = r
            if progress is not None:
                progress(d, n)
    finally:
        ctx.release()
    return out
