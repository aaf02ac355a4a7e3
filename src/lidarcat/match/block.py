r"""Tie points of a block: features -> pairs -> guided matching -> verification -> tracks -> distribution.

:func:`match_block` runs the steps of :mod:`lidarcat.match` on arrays: cameras, approximate
orientations (or none), a height surface and a function that yields each photo's features
(the stage reads the images and caches the features on disk; the engine writes no file).

1. Pairs: :func:`~lidarcat.match.pairs.footprint_pairs` when every photo has an approximate
   orientation, else :func:`~lidarcat.match.pairs.exhaustive_pairs` up to ``max_exhaustive``
   photos (a larger block without orientations is refused: its pairs would grow as n²).
2. Per pair: guided matching (:mod:`~lidarcat.match.guided`) when both photos have an
   orientation -- in two passes: the strongest features in the full ellipses, then all of them in
   the ellipses the first pass narrowed (:func:`_narrowed`) -- else descriptor matching over all features; then the robust epipolar test
   (:mod:`~lidarcat.match.verify`).  Only the features of A whose prediction falls inside B
   (with the ellipse's margin) are searched.
3. Tracks by union-find, inconsistent ones dropped (two keypoints on one photo; with orientations,
   rays of a track of three or more that do not meet within what the orientations allow:
   :func:`_inconsistent_rays`), then the distribution control
   (:mod:`~lidarcat.match.tracks`).

Parallel work and memory: the photos (features) and then the pairs (guided search and
verification) are independent tasks, ``task(shared, item)`` with module-level functions, run by
a *mapper* ``mapper(task, shared, items, progress) -> results in item order``: serially, on
``workers`` threads (OpenCV and numpy release the GIL in their inner loops), or the caller's
(:func:`lidarcat.lidar.jobs.map_tasks`: Dask worker processes or a cluster, where *shared* --
cameras, orientations, surface, options and the ``features`` callable -- is sent once per worker).
A photo task returns only the keypoint positions (n_i, 2), 16 bytes a keypoint, which stay in
this process; a pair task fetches its two photos' descriptors through a small least-recently-used
store of ``lru`` photos per process (``features(i)`` again when the store dropped a photo: the
stage reads them from its feature cache) and returns only its verified matches.  The tracks are
built here after all pairs.  So the memory of a worker is bounded by ``lru`` photos' features and
that of this process by the keypoint positions and the matches, not by the photos' descriptors;
the result does not depend on the mapper or the number of workers.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from threading import Lock
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from .features import Features
from .guided import Matches, Prediction, guided_match, match_descriptors, predict
from .pairs import exhaustive_pairs, footprint, footprint_pairs
from .rays import HeightSurface, MatchError
from .tracks import Tracks, build_tracks, distribute
from .verify import ideal_pixels, local_consistency, verify_pair

__all__ = ["MatchOptions", "PairReport", "BlockMatch", "MatchError", "match_block", "extract_features", "TaskMap",
           "serial_map", "thread_map"]

#: ``mapper(task, shared, items, progress) -> [task(shared, item) for item in items]`` (item order);
#: *progress* ``(done, total)`` or None
TaskMap = Callable[[Callable[[Any, Any], Any], Any, Sequence[Any], "Callable[[int, int], None] | None"], list]


def serial_map(task: Callable[[Any, Any], Any], shared: Any, items: Sequence[Any],
               progress: Callable[[int, int], None] | None = None) -> list:
    """The tasks one after the other in this thread (a :data:`TaskMap`)."""
    out = []
    for k, it in enumerate(items):
        out.append(task(shared, it))
        if progress:
            progress(k + 1, len(items))
    return out


def thread_map(workers: int) -> TaskMap:
    """A :data:`TaskMap` on a pool of *workers* threads (serial for one)."""
    if workers <= 1:
        return serial_map

    def run(task: Callable[[Any, Any], Any], shared: Any, items: Sequence[Any],
            progress: Callable[[int, int], None] | None = None) -> list:
        from concurrent.futures import ThreadPoolExecutor, as_completed

        out: list[Any] = [None] * len(items)
        with ThreadPoolExecutor(workers) as pool:
            futures = {pool.submit(task, shared, it): k for k, it in enumerate(items)}
            for d, f in enumerate(as_completed(futures), 1):
                out[futures[f]] = f.result()
                if progress:
                    progress(d, len(items))
        return out

    return run


@dataclass(frozen=True)
class MatchOptions:
    """Options of :func:`match_block` (units in the names).

    Attributes
    ----------
    min_overlap : float
        Footprint overlap of a matched pair (share of the smaller footprint).
    sd_position_m, sd_angle_deg : float
        Standard deviations of the approximate orientations (guided search ellipses).
    ratio : float
        Lowe's ratio test.
    threshold_px : float
        Epipolar (Sampson) distance of an inlier, px of the detection level (``threshold_px 2^level``
        in full-resolution pixels).  0.5: measured on the four NGI frames (every verified track), 1 px
        kept 29 observations more than 2 px from the published orientation's reprojection (97.6 %
        within 1 px), 0.5 px 6 (99.1 %) for 16 % fewer observations; on the rendered 1200 x 900 block
        1.4 % fewer tie points, within 1 px 99.68 -> 99.74 %.
    min_inliers : int
        Fewer inliers reject a pair.
    grid : (rows, cols)
        Distribution cells per photo.
    per_cell : int
        Target tie points per cell (0: keep every track).
    min_rays : int
        Tracks with fewer observations are dropped (2: every verified match).
    max_exhaustive : int
        Largest block matched all-pairs when photos have no orientation.
    seed_features : int
        Guided search in two passes (:func:`_narrowed`): this many strongest features of A first, in the
        full ellipses; their verified shifts from the prediction correct it, and every feature is then
        searched in the narrower ellipse of what is left.  0: one pass.
    max_local_px : float
        Local consistency of the shifts (:func:`~lidarcat.match.verify.local_consistency`), px; 0: off.
    guided : bool
        Use the orientations to guide the search (False: descriptor matching over the whole photo
        for the footprint pairs).
    """

    min_overlap: float = 0.1
    sd_position_m: float = 2.0
    sd_angle_deg: float = 0.5
    ratio: float = 0.8
    threshold_px: float = 0.5
    min_inliers: int = 15
    grid: tuple[int, int] = (6, 6)
    per_cell: int = 10
    min_rays: int = 2
    max_exhaustive: int = 30
    guided: bool = True
    max_local_px: float = 3.0
    seed_features: int = 0


@dataclass(frozen=True)
class PairReport:
    """One matched pair: photo indices, footprint overlap, matches, candidates, inliers, why rejected."""

    a: int
    b: int
    overlap: float
    n_matches: int
    n_candidates: int
    n_inliers: int
    reason: str = ""
    seconds: float = 0.0


@dataclass(frozen=True, eq=False)
class BlockMatch:
    """The tie points of a block.

    Attributes
    ----------
    tracks : Tracks
        One row per observation (track, photo index, keypoint index).
    xy_px : ndarray (n, 2)
        Column, row of every observation.
    score : ndarray (n_tracks,)
    pairs : tuple of PairReport
    n_tracks_before : int
        Consistent tracks before the distribution control.
    seconds : dict
        Time of each step (features, matching, tracks).
    unpaired : tuple of int
        Photos whose footprint overlaps no other photo's (matched with none: a reported skip).
    n_ray_inconsistent : int
        Tracks of three rays or more dropped because their rays do not meet within what the
        approximate orientations allow (:func:`_inconsistent_rays`).
    n_keypoints : tuple of int
        Keypoints of each photo.
    """

    tracks: Tracks
    xy_px: np.ndarray
    score: np.ndarray
    pairs: tuple[PairReport, ...]
    n_tracks_before: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    unpaired: tuple[int, ...] = ()
    n_ray_inconsistent: int = 0
    n_keypoints: tuple[int, ...] = ()


class _Store:
    """Features by photo index through a small LRU (thread-safe; two threads asking for the same
    photo at once wait for one ``get``, so no photo is detected twice in parallel)."""

    def __init__(self, get: Callable[[int], Features], size: int):
        self.get, self.size = get, max(2, size)
        self.items: OrderedDict[int, Features] = OrderedDict()
        self.lock = Lock()
        self.loading: dict[int, Lock] = {}
        self.levels: dict[int, int] = {}

    def __call__(self, i: int) -> Features:
        with self.lock:
            if i in self.items:
                self.items.move_to_end(i)
                return self.items[i]
            mine = self.loading.setdefault(i, Lock())
        with mine:
            with self.lock:
                if i in self.items:
                    self.items.move_to_end(i)
                    return self.items[i]
            f = self.get(i)
            with self.lock:
                self.items[i] = f
                self.levels[i] = int(f.level)
                self.loading.pop(i, None)
                while len(self.items) > self.size:
                    self.items.popitem(last=False)
        return f

    def __getstate__(self) -> dict[str, Any]:      # to a worker process: the function, an empty store
        return {"get": self.get, "size": self.size}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["get"], state["size"])


def _photo_task(store: _Store, i: int) -> tuple[np.ndarray, int]:
    """One photo's task: its features (detected or read by ``store``), returned as positions and level."""
    f = store(i)
    return np.asarray(f.xy_px, np.float64), int(f.level)


def extract_features(n: int, get: Callable[[int], Features], *, workers: int = 1,
                     progress: Callable[[int, int], None] | None = None,
                     mapper: TaskMap | None = None) -> list[np.ndarray]:
    """Run *get(i)* for every photo (detect or read the cache) and return the keypoint positions.

    Photos run on *mapper* (default: *workers* threads); only the positions (n_i, 2) are kept.
    """
    store = get if isinstance(get, _Store) else _Store(get, 8)
    res = (mapper or thread_map(workers))(_photo_task, store, list(range(n)), progress)
    return [xy for xy, _ in res]


def _narrowed(pred: Prediction, fa: Features, fb: Features, ca: Camera, cb: Camera, opt: MatchOptions
              ) -> Prediction:
    """The prediction corrected by the first pass, with the covariance of what it leaves.

    The orientation errors move a pair's predictions nearly affinely over the photo (a shift, a
    rotation, a scale); the relief the surface misses adds a parallax.  The ``seed_features``
    strongest features of A are matched in their full ellipses and verified; their shifts
    ``r = b - p`` are fitted by ``r ≈ c0 + C a`` (least squares, refitted once without the
    residuals over ``3 σ``), and every prediction becomes ``p + c0 + C a`` with the isotropic
    covariance ``(σ² + σ_f²) I``, ``σ = 1.4826 MAD`` of the remaining residuals (at least 1 px).
    Too few verified seeds (< 30) keep the first prediction.
    """
    n = len(fa)
    if opt.seed_features <= 0 or n <= 2 * opt.seed_features:
        return pred
    seeds = np.argsort(-fa.response, kind="stable")[:opt.seed_features]
    sub = Prediction(pred.xy_px[seeds], pred.cov_px2[seeds])
    m, _ = guided_match(sub, fa.descriptors[seeds], fb.xy_px, fb.descriptors, ratio=opt.ratio)
    if len(m) < 30:
        return pred
    ia = seeds[m.i]
    v = verify_pair(ideal_pixels(ca, fa.xy_px[ia]), ideal_pixels(cb, fb.xy_px[m.j]),
                    threshold_px=opt.threshold_px * 2 ** max(fa.level, fb.level), min_inliers=30)
    if not v.accepted:
        return pred
    ia, jb = ia[v.inlier], m.j[v.inlier]
    scale = float(max(ca.columns_px, ca.rows_px))

    def design(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([np.ones(len(xy)), xy / scale])

    r = fb.xy_px[jb] - pred.xy_px[ia]
    d = design(fa.xy_px[ia])
    keep = np.ones(len(r), bool)
    for _ in range(2):
        coef, *_ = np.linalg.lstsq(d[keep], r[keep], rcond=None)
        e = np.hypot(*(r - d @ coef).T)
        sigma = max(1.4826 * float(np.median(e[keep])), 1.0)
        keep = e <= 3.0 * sigma
    ok = np.isfinite(pred.xy_px).all(axis=1)
    xy = pred.xy_px.copy()
    xy[ok] += design(fa.xy_px[ok]) @ coef
    sd_f = float(2 ** fa.level)
    cov = np.tile(np.eye(2) * (sigma ** 2 + sd_f ** 2), (n, 1, 1))
    cov[~ok] = pred.cov_px2[~ok]
    return Prediction(xy, cov)


def _inconsistent_rays(tracks: Tracks, xy: np.ndarray, cams: Sequence[Camera], eos: Sequence[np.ndarray],
                       levels: np.ndarray, opt: MatchOptions) -> np.ndarray:
    """Tracks of three rays or more whose rays do not meet within what the approximate orientations
    allow, (n_tracks,) bool.

    Every pair of a track passed its own epipolar test, but a track joined by union-find can still
    hold rays that agree pairwise along their epipolar lines and meet nowhere together (two wrong
    rays consistent with each other, one right).  The track is intersected with the approximate
    orientations (least squares of its rays) and each ray reprojected; the residual an orientation
    error can cause is about ``σ_o = f_px (σ_angle + σ_position / D)`` per photo (``D`` the distance
    to the point), two photos' worth ``sqrt(2) σ_o``, plus the feature's ``2^level`` px.  A ray
    more than ``3.7 sqrt(2) σ_o + 3 · 2^level`` px off (99.9 % for the orientation part) marks the
    track inconsistent.  With orientations 2 m / 0.5 deg off this allows some 70 px and drops
    nothing; with a published orientation at 1 m / 0.01 deg (the NGI frames) about 4 px.
    """
    from .rays import project_to_pixel, ray_directions

    n_t = tracks.n_tracks
    rays = tracks.rays()
    use = rays[tracks.track] >= 3
    bad = np.zeros(n_t, bool)
    if not use.any():
        return bad
    t, ph, p_xy = tracks.track[use], tracks.photo[use], xy[use]
    eo = np.array([eos[i] for i in range(len(eos))], dtype=np.float64)
    d = np.empty((len(t), 3))
    for p in np.unique(ph):
        sel = ph == p
        d[sel] = ray_directions(cams[p], eo[p], p_xy[sel])
    d /= np.linalg.norm(d, axis=1)[:, None]
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    a = np.zeros((n_t, 3, 3))
    b = np.zeros((n_t, 3))
    np.add.at(a, t, proj)
    np.add.at(b, t, np.einsum("nij,nj->ni", proj, eo[ph, :3]))
    live = np.unique(t)
    x = np.zeros((n_t, 3))
    x[live] = np.linalg.solve(a[live] + 1e-9 * np.eye(3)[None], b[live][:, :, None])[:, :, 0]
    res = np.full(len(t), np.inf)
    allow = np.empty(len(t))
    for p in np.unique(ph):
        sel = np.flatnonzero(ph == p)
        px, front = project_to_pixel(cams[p], eo[p], x[t[sel]])
        r = np.hypot(*(px - p_xy[sel]).T)
        res[sel] = np.where(front & np.isfinite(r), r, np.inf)
        dist = np.linalg.norm(x[t[sel]] - eo[p, :3], axis=1)
        f_px = cams[p].focal_length_mm / cams[p].pixel_size_x_mm
        sd_o = f_px * (np.deg2rad(opt.sd_angle_deg) + opt.sd_position_m / np.maximum(dist, 1e-6))
        allow[sel] = 3.7 * np.sqrt(2.0) * sd_o + 3.0 * 2.0 ** levels[p]
    bad[t[res > allow]] = True
    return bad


@dataclass(frozen=True, eq=False)
class _Shared:
    """What every pair task needs (sent once to each worker process)."""

    cameras: tuple[Camera, ...]
    eos: tuple[np.ndarray | None, ...]
    surface: HeightSurface
    store: _Store
    options: MatchOptions


def _pair_task(shared: _Shared, pair: tuple[int, int, float]) -> tuple[PairReport, Matches]:
    """One pair's task: guided search and verification of photos ``a, b`` (:func:`_match_pair`)."""
    a, b, overlap = pair
    return _match_pair(a, b, overlap, shared.cameras, shared.eos, shared.surface, shared.store, shared.options)


def _match_pair(a: int, b: int, overlap: float, cams: Sequence[Camera], eos: Sequence[np.ndarray | None],
                surface: HeightSurface, store: _Store, opt: MatchOptions) -> tuple[PairReport, Matches]:
    t0 = time.perf_counter()
    fa, fb = store(a), store(b)
    ca, cb = cams[a], cams[b]
    guided = opt.guided and eos[a] is not None and eos[b] is not None
    n_cand = 0
    pred_xy = None
    if guided:
        pred = predict(ca, eos[a], fa.xy_px, cb, eos[b], surface, sd_position_m=opt.sd_position_m,
                       sd_angle_deg=opt.sd_angle_deg, sd_feature_px=float(2 ** fa.level))
        pred = _narrowed(pred, fa, fb, ca, cb, opt)
        m, n_cand = guided_match(pred, fa.descriptors, fb.xy_px, fb.descriptors, ratio=opt.ratio)
        pred_xy = pred.xy_px
    else:
        m = match_descriptors(fa.descriptors, fb.descriptors, ratio=opt.ratio)
        n_cand = len(fa) * len(fb)
    if len(m) == 0:
        return PairReport(a, b, overlap, 0, n_cand, 0, "no matches", time.perf_counter() - t0), m
    v = verify_pair(ideal_pixels(ca, fa.xy_px[m.i]), ideal_pixels(cb, fb.xy_px[m.j]),
                    threshold_px=opt.threshold_px * 2 ** max(fa.level, fb.level), min_inliers=opt.min_inliers)
    ok = v.inlier.copy()
    if v.accepted and opt.max_local_px > 0:
        base = pred_xy[m.i] if pred_xy is not None else fa.xy_px[m.i]
        ok[ok] = local_consistency(fa.xy_px[m.i][ok], (fb.xy_px[m.j] - base)[ok], min_px=opt.max_local_px)
    kept = m.select(ok) if v.accepted and ok.sum() >= opt.min_inliers else m.select(np.zeros(len(m), bool))
    return (PairReport(a, b, overlap, len(m), n_cand, len(kept), v.reason, time.perf_counter() - t0), kept)


def match_block(cameras: Sequence[Camera], eos: Sequence[np.ndarray | None], features: Callable[[int], Features],
                *, surface: HeightSurface | None = None, options: MatchOptions = MatchOptions(),
                workers: int = 1, lru: int = 8, ids: Sequence[str] | None = None,
                progress: Callable[[str, int, int], None] | None = None,
                mapper: TaskMap | None = None) -> BlockMatch:
    """Tie points of a block (module docstring).

    Parameters
    ----------
    cameras : sequence of Camera
        Camera of each photo.
    eos : sequence of (6,) arrays or None
        Approximate orientation of each photo: X0, Y0, Z0 (m), omega, phi, kappa (rad); None unknown.
    features : callable
        ``features(i) -> Features`` of photo *i* (cached by the caller: it is called again when the
        LRU dropped a photo, and in every worker process that matches a pair of photo *i*;
        picklable for a process mapper).
    surface : HeightSurface or None
        Height model of the footprints and the guided search; needed when the photos have orientations.
    options : MatchOptions
    workers : int
        Threads for the features and the pairs (when no *mapper* is given).
    lru : int
        Photos' features kept in memory per process.
    ids : sequence of str, optional
        Photo ids for messages.
    progress : callable, optional
        ``progress(step, done, total)`` with step ``features``, ``pairs``.
    mapper : TaskMap, optional
        Runs the photo and pair tasks (module docstring); default :func:`thread_map` of *workers*.

    Raises
    ------
    MatchError
        No orientation on a block larger than ``max_exhaustive``; no two photos overlap; no pair verified.
    """
    n = len(cameras)
    ids = list(ids) if ids is not None else [str(i) for i in range(n)]
    seconds: dict[str, float] = {}
    oriented = all(e is not None for e in eos)
    if oriented:
        if surface is None:
            raise MatchError("photos with orientations need a height surface (HeightSurface) for their footprints")
        polys = [footprint(cameras[i], eos[i], surface) for i in range(n)]
        pairs, overlap = footprint_pairs(polys, options.min_overlap)
    else:
        if n > options.max_exhaustive:
            missing = [ids[i] for i, e in enumerate(eos) if e is None]
            raise MatchError(f"photo {missing[0]!r} and {len(missing) - 1} more have no approximate orientation; "
                             f"a block of {n} photos is matched by footprints (all pairs only up to "
                             f"{options.max_exhaustive} photos): give positions and attitudes in photos.csv")
        pairs = exhaustive_pairs(n)
        overlap = np.full(len(pairs), np.nan)
    if len(pairs) == 0:
        raise MatchError(f"no two of the {n} photos overlap by {options.min_overlap:.0%} or more "
                         f"(approximate footprints on the surface); nothing to match")
    t0 = time.perf_counter()
    mapper = mapper or thread_map(workers)
    store = _Store(features, lru)
    photo_res = mapper(_photo_task, store, list(range(n)),
                       (lambda d, t: progress("features", d, t)) if progress else None)
    xy_all = [xy for xy, _ in photo_res]
    levels = np.array([lv for _, lv in photo_res], dtype=np.int64)
    seconds["features"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    shared = _Shared(tuple(cameras), tuple(eos), surface or HeightSurface(0.0), store, options)
    items = [(int(pairs[k, 0]), int(pairs[k, 1]), float(overlap[k])) for k in range(len(pairs))]
    pair_res = mapper(_pair_task, shared, items, (lambda d, t: progress("pairs", d, t)) if progress else None)
    reports: list[PairReport] = [r for r, _ in pair_res]
    kept: list[Matches] = [m for _, m in pair_res]
    seconds["matching"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    pair_reports = tuple(r for r in reports if r is not None)
    ok = [k for k, r in enumerate(pair_reports) if r.n_inliers > 0]
    if not ok:
        raise MatchError(f"no pair of the {len(pairs)} overlapping pairs has verified matches "
                         f"(first: photos {ids[pair_reports[0].a]!r}-{ids[pair_reports[0].b]!r}: "
                         f"{pair_reports[0].reason or 'no inliers'})")
    ms = [kept[k] for k in ok]
    tracks = build_tracks([len(x) for x in xy_all], pairs[ok], [(m.i, m.j) for m in ms], xy_px=xy_all)
    # score: rays, then the mean ratio of the track's matches (lower = more distinctive)
    offset = np.r_[0, np.cumsum([len(x) for x in xy_all])]
    node_track = np.full(int(offset[-1]), -1, np.int64)
    node_track[offset[tracks.photo] + tracks.keypoint] = tracks.track
    e_track = np.concatenate([node_track[offset[pairs[k, 0]] + m.i] for k, m in zip(ok, ms)])
    e_ratio = np.concatenate([m.ratio for m in ms])
    good = e_track >= 0
    nt = tracks.n_tracks
    rsum = np.bincount(e_track[good], weights=e_ratio[good], minlength=nt)
    rcnt = np.maximum(np.bincount(e_track[good], minlength=nt), 1)
    rays = tracks.rays()
    score = rays + (1.0 - rsum / rcnt)
    keep = rays >= options.min_rays
    xy = np.empty((len(tracks), 2))
    for p in np.unique(tracks.photo):
        rows = tracks.photo == p
        xy[rows] = xy_all[p][tracks.keypoint[rows]]
    n_rays_dropped = 0
    if oriented and options.guided:
        inconsistent = _inconsistent_rays(tracks, xy, cameras, eos, levels, options)
        n_rays_dropped = int(inconsistent.sum())
        keep &= ~inconsistent
    n_before = int(keep.sum())
    frame = np.array([[c.columns_px, c.rows_px] for c in cameras], dtype=np.float64)
    keep &= distribute(tracks, xy, frame, score, grid=options.grid, per_cell=options.per_cell)
    rows = keep[tracks.track]
    final = tracks.select_tracks(keep)
    if n_rays_dropped:       # the report's "inconsistent tracks dropped" counts both kinds
        final = Tracks(final.track, final.photo, final.keypoint, final.n_inconsistent + n_rays_dropped)
    seconds["tracks"] = time.perf_counter() - t0
    unpaired = tuple(int(i) for i in np.setdiff1d(np.arange(n), pairs.ravel()))
    return BlockMatch(final, xy[rows], score[keep], pair_reports, n_before, seconds, unpaired, n_rays_dropped,
                      tuple(len(x) for x in xy_all))
