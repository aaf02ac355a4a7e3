"""LiDAR system calibration tile by tile (LACTEC report 7.1.2): the observations chosen per tile on the tile engine.

The estimate of :mod:`lidarcat.production.lidarcalib` (the geolocation equation, the observations and
their normal equations are derived there) with bounded memory: arrays in and out, and the two tasks of
:mod:`lidarcat.lidar.jobs` (:func:`bounds_tile`, :func:`calibration_tile`) that write one ``.npz`` each.

Tile by tile (bounded memory, on the tile engine)
-------------------------------------------------
Every quantity of the estimate needs only the pulses of the observations, and each
observation only a point and its ``k`` neighbours within ``radius_m``.  So a
survey is calibrated tile by tile (:func:`calibration_tile`, a task of
:mod:`lidarcat.lidar.jobs`): a tile's own points, with its neighbours' points
within the planes' reach, give the observations whose point lies in the tile
(:func:`select_observations`: the control candidates inside the control TIN,
the strip pairs by the plane tests); the parent merges them
(:func:`merge_observations`) and iterates (:func:`estimate_from_observations`).
The iteration above chooses the observations at the first two iterations
(at ``q = 0`` and at the first step ``q1``) and freezes them from the third;
so the tiles are read in two passes: observations chosen at the delivered
points give ``q1`` (one step, robust rejection included); observations chosen
at the points georeferenced with ``q1`` are rejected once, frozen and iterated
from ``q1`` to convergence.  Pairs chosen only at ``q = 0`` would not do: a
pitch misalignment of 0.08 deg moves a point ~0.7 m along track at 500 m, the
neighbours chosen around the wrong place put curved terrain into the plane
differences (measured: pitch 9 sd off; two passes: the in-memory estimate to
1e-6 sd, test).

Memory: a worker holds one tile with its buffer and the trajectory; the
parent holds the merged observations, at most ``max_control`` and
``max_strip`` of them (each with its pulses).  The sample is *bottom-k* by a
hash of the point (:func:`point_keys`: its coordinates and GPS time, the same
in every tile or buffer that reads it): each tile keeps its smallest keys and
the merge the smallest of all, which are the smallest keys of the survey; so
the sample does not depend on the tiling, nor on the order the tasks finish
(test).  A sample of ``m`` of ``n`` observations widens the sds by about
``sqrt(n / m)``.  The tiles are merged in job order, so a serial run and a
Dask run give the same bits.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ProductError
from .lidarcalib import (CalibrationResult, PulseRecords, SystemParameters, adjust_parameters, control_array,
                         georeference, pulses_from_points, strip_pairs)

if TYPE_CHECKING:
    from ..lidar.jobs import TileJob

__all__ = [
    "CalibrationObservations",
    "point_keys",
    "select_observations",
    "merge_observations",
    "estimate_from_observations",
    "calibration_tile",
    "bounds_tile",
]


# ----------------------------------------------------------------------------- tile by tile


@dataclass(frozen=True, eq=False)
class CalibrationObservations:
    """Observations of the system calibration chosen at the delivered points, tile by tile (module
    docstring, "Tile by tile").

    Attributes
    ----------
    pulses : PulseRecords
        The pulses the observations refer to (only those).
    control : (C,) int
        Pulses tried against the control TIN (inside it at the delivered points).
    point : (M,) int
        Strip observations: the point of strip A ...
    neighbours : (M, k) int
        ... and its plane neighbours in strip B.
    control_key, strip_key : (C,) and (M,) uint64
        The observations' sampling keys (a hash of the point, and of strip B).
    seen_control, seen_strip : int
        Observations found before the bounded sample.
    """

    pulses: PulseRecords
    control: np.ndarray
    point: np.ndarray
    neighbours: np.ndarray
    control_key: np.ndarray
    strip_key: np.ndarray
    seen_control: int = 0
    seen_strip: int = 0

    _ARRAYS = ("control", "point", "neighbours", "control_key", "strip_key")

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save (``numpy.savez``); :meth:`from_arrays` reads them back."""
        p = self.pulses
        return {"gnss_m": p.gnss_m, "attitude_rad": p.attitude_rad, "range_m": p.range_m, "scan_rad": p.scan_rad,
                "strip": p.strip, **{n: getattr(self, n) for n in self._ARRAYS},
                "seen": np.array([self.seen_control, self.seen_strip], dtype=np.int64)}

    @classmethod
    def from_arrays(cls, z: dict[str, np.ndarray]) -> CalibrationObservations:
        pulses = PulseRecords(z["gnss_m"].reshape(-1, 3), z["attitude_rad"].reshape(-1, 3), z["range_m"],
                              z["scan_rad"], z["strip"])
        k = z["neighbours"].shape[1] if z["neighbours"].ndim == 2 else 0
        return cls(pulses, z["control"].astype(np.int64), z["point"].astype(np.int64),
                   z["neighbours"].astype(np.int64).reshape(-1, k), z["control_key"].astype(np.uint64),
                   z["strip_key"].astype(np.uint64), int(z["seen"][0]), int(z["seen"][1]))


_GOLDEN, _M1, _M2 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser of uint64 values (wrapping arithmetic): a well-spread hash."""
    x = np.asarray(x, dtype=np.uint64) + _GOLDEN
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


def point_keys(points_m: np.ndarray, time_s: np.ndarray | None = None) -> np.ndarray:
    """(N,) uint64 hash of each point's coordinates (and GPS time): the same point gets the same key in
    whichever tile or buffer it is read, so a sample by the smallest keys does not depend on the tiling."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    h = np.zeros(len(p), dtype=np.uint64)
    cols = [p[:, 0], p[:, 1], p[:, 2]] + ([np.asarray(time_s, dtype=np.float64).ravel()] if time_s is not None
                                          else [])
    for c in cols:
        h = _mix(h ^ np.ascontiguousarray(c).view(np.uint64))
    return h


def _smallest(keys: np.ndarray, m: int | None) -> np.ndarray:
    """Indices of the *m* smallest keys (all when None), in key order."""
    if m is not None and keys.size > m:
        sel = np.argpartition(keys, m - 1)[:m] if m > 0 else np.zeros(0, dtype=np.int64)
        return sel[np.argsort(keys[sel], kind="stable")]
    return np.argsort(keys, kind="stable")


def _compact(pulses: PulseRecords, control: np.ndarray, point: np.ndarray, neighbours: np.ndarray,
             control_key: np.ndarray, strip_key: np.ndarray, seen: tuple[int, int]) -> CalibrationObservations:
    """Keep only the pulses the observations refer to; renumber."""
    used = np.unique(np.concatenate([control, point, neighbours.ravel()]).astype(np.int64))

    def remap(i: np.ndarray) -> np.ndarray:
        return np.searchsorted(used, i).astype(np.int64)
    return CalibrationObservations(pulses.subset(used), remap(control), remap(point),
                                   remap(neighbours).reshape(neighbours.shape), control_key, strip_key, *seen)


def select_observations(pulses: PulseRecords, control_m: np.ndarray | None = None, *, own: np.ndarray | None = None,
                        keys: np.ndarray | None = None, at: SystemParameters | None = None, radius_m: float = 2.5,
                        k: int = 6, max_plane_rms_m: float = 0.15, stride: int = 1, max_control: int | None = None,
                        max_strip: int | None = None) -> CalibrationObservations:
    """The observations of one tile, chosen at the points georeferenced with *at* (the map step; module
    docstring, "Tile by tile").

    Parameters
    ----------
    pulses : PulseRecords
        The tile's pulses followed by its neighbours' within ``radius_m``.
    control_m : (M, 3) float, optional
        Control surface: the tile's points inside its TIN are control candidates.
    own : (N,) bool, optional
        The tile's own pulses (default all): the control candidates and the
        points of strip A are taken among them, the plane neighbours among all.
    keys : (N,) uint64, optional
        :func:`point_keys` of the pulses (default: of their georeferenced points).
    at : SystemParameters, optional
        The parameters the points are georeferenced with to choose the
        observations (default zero: the delivered points; the second pass:
        the first pass's step).
    radius_m, k, max_plane_rms_m, stride
        As :func:`~lidarcat.production.lidarcalib.estimate_system_parameters`.
    max_control, max_strip : int, optional
        Keep at most this many observations of each kind: those of the
        smallest keys (the merge keeps the smallest of all tiles, so the
        sample is the same however the survey is tiled).
    """
    ctrl = control_array(control_m)
    p = georeference(pulses, None if at is None else SystemParameters.from_array(np.nan_to_num(at.as_array())))
    own = np.ones(len(pulses), dtype=bool) if own is None else np.asarray(own, dtype=bool)
    keys = point_keys(p) if keys is None else np.asarray(keys, dtype=np.uint64)
    cidx = np.zeros(0, dtype=np.int64)
    if ctrl is not None and len(pulses):
        from scipy.spatial import Delaunay

        from ..geometry.tin import TinLocator

        origin = ctrl[:, :2].mean(axis=0)
        mine = np.flatnonzero(own)
        simplex, _ = TinLocator(Delaunay(ctrl[:, :2] - origin)).locate(p[mine, :2] - origin)
        cidx = mine[simplex >= 0]
    if len(np.unique(pulses.strip)) > 1:
        pa, nb = strip_pairs(p, pulses.strip, radius_m=radius_m, k=k, max_plane_rms_m=max_plane_rms_m,
                             stride=max(1, int(stride)), own=own)
    else:
        pa, nb = np.zeros(0, dtype=np.int64), np.zeros((0, k), dtype=np.int64)
    ck = _mix(keys[cidx])
    sk = _mix(keys[pa] ^ _mix(pulses.strip[nb[:, 0]].astype(np.uint64))) if pa.size else np.zeros(0, np.uint64)
    cs, ss = _smallest(ck, max_control), _smallest(sk, max_strip)
    return _compact(pulses, cidx[cs], pa[ss], nb[ss], ck[cs], sk[ss], (int(cidx.size), int(pa.size)))


def merge_observations(parts: Sequence[CalibrationObservations], *, max_control: int | None = None,
                       max_strip: int | None = None) -> CalibrationObservations:
    """The tiles' observations as one set (the reduce step): the *max_control* / *max_strip* of the
    smallest keys over all tiles, in key order.

    Raises
    ------
    ProductError
        No part, or parts of different ``k``.
    """
    if not parts:
        raise ProductError("system calibration: no tile observations to merge")
    ks = {o.neighbours.shape[1] for o in parts}
    if len(ks) != 1:
        raise ProductError(f"system calibration: tile observations of different plane sizes k {sorted(ks)}")
    off = np.cumsum([0] + [len(o.pulses) for o in parts])

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(o.pulses, name) for o in parts])
    pulses = PulseRecords(cat("gnss_m"), cat("attitude_rad"), cat("range_m"), cat("scan_rad"), cat("strip"))
    control = np.concatenate([o.control + d for o, d in zip(parts, off)])
    point = np.concatenate([o.point + d for o, d in zip(parts, off)])
    nb = np.concatenate([o.neighbours + d for o, d in zip(parts, off)])
    ck = np.concatenate([o.control_key for o in parts])
    sk = np.concatenate([o.strip_key for o in parts])
    cs, ss = _smallest(ck, max_control), _smallest(sk, max_strip)
    seen = (sum(o.seen_control for o in parts), sum(o.seen_strip for o in parts))
    return _compact(pulses, control[cs], point[ss], nb[ss], ck[cs], sk[ss], seen)


def estimate_from_observations(obs: CalibrationObservations, control_m: np.ndarray | None = None, *,
                               start: SystemParameters | None = None, sd_control_m: float = 0.05,
                               sd_strip_m: float = 0.05, max_iter: int = 10, tol: float = 1e-10,
                               progress: Callable[[int, int], None] | None = None) -> CalibrationResult:
    """:func:`~lidarcat.production.lidarcalib.estimate_system_parameters` on observations chosen tile by tile
    (:func:`select_observations`, :func:`merge_observations`; module docstring, "Tile by tile").

    Without *start*: the first pass, observations chosen at the delivered
    points; run it with ``max_iter=1`` for the step ``q1`` (its robust
    rejection included).  With ``start=q1``: the second pass, observations
    chosen at ``q1`` (``select_observations(at=q1)``), rejected once and
    frozen, iterated to convergence, as :func:`~lidarcat.production.lidarcalib.estimate_system_parameters`
    does from its second iteration on.

    Raises
    ------
    ProductError
        As :func:`~lidarcat.production.lidarcalib.estimate_system_parameters`.
    """
    ctrl = control_array(control_m)
    pairs = (obs.point, obs.neighbours)
    res = adjust_parameters(obs.pulses, ctrl, lambda p: pairs, obs.control, sd_control_m=sd_control_m,
                            sd_strip_m=sd_strip_m, max_iter=max_iter, tol=tol, progress=progress, start=start,
                            freeze_at=1 if start is None else 0)
    notes = list(res.notes)
    for what, kept, seen in (("control", obs.control.size, obs.seen_control),
                             ("strip", obs.point.size, obs.seen_strip)):
        if kept < seen:
            notes.append(f"{what} observations: a sample of {kept:,} of {seen:,} (the smallest point keys)")
    return dataclasses.replace(res, notes=tuple(notes))


def bounds_tile(job: TileJob) -> None:
    """The plan bounds of ``job.tile``'s points, measured (``.npz`` ``bounds`` = xmin, ymin, xmax, ymax; NaN
    without points): the tile engine takes LAS header bounds for unverified and makes every tile a neighbour
    of every other; the calibration's passes take their neighbours from these."""
    from .._util import atomic_write
    from ..lidar.readers import read_points

    xy = read_points(job.tile, crs=job.crs).xyz[:, :2]
    b = np.r_[xy.min(axis=0), xy.max(axis=0)] if len(xy) else np.full(4, np.nan)
    with atomic_write(job.output, "wb") as fh:
        np.savez(fh, bounds=b)


@functools.lru_cache(maxsize=1)
def _trajectory_of(path: str, sha256: str | None, crs_wkt: str | None) -> Any:
    from ..lidar.trajectory import read_trajectory

    return read_trajectory(path, crs_wkt)


def _trajectory(path: str, sha256: str | None, crs: Any) -> Any:
    """The trajectory *path* in *crs*, read once per process for the tiles of a run (keyed by its hash)."""
    from ..lidar.crs import resolve_crs

    c = resolve_crs(crs)
    return _trajectory_of(str(path), sha256 if sha256 else None, None if c is None else c.to_wkt()) \
        if sha256 else _trajectory_of.__wrapped__(str(path), None, None if c is None else c.to_wkt())


def calibration_tile(job: TileJob) -> None:
    """The map step of the system calibration on the tile engine (module docstring, "Tile by tile").

    Reads ``job.tile`` with its neighbours' points within ``job.overlap_m``
    (at least the plane radius), rebuilds the pulses from the trajectory
    ``job.params["trajectory"]`` and writes the tile's
    :class:`CalibrationObservations` to ``job.output`` (``.npz``, atomically),
    with the tile's point count, flight lines, along-track angles (sum of
    squares) and time-base note.  ``job.params``: ``trajectory``, ``control``
    (list of (E, N, H) or None), ``classes``, ``stride``, ``radius_m``, ``k``,
    ``max_plane_rms_m``, ``max_control``, ``max_strip`` (``trajectory_sha256``
    only marks the done-marker stale when the file changes).

    Raises
    ------
    ProductError
        The points carry no ``gps_time`` or ``point_source_id`` (names the tile); points outside the trajectory.
    """
    from .._util import atomic_write
    from ..lidar.jobs import read_with_buffer
    from ..lidar.trajectory import match_time_base

    cloud, n_own = read_with_buffer(job)
    a = cloud.attributes
    for name in ("gps_time", "point_source_id"):
        if name not in a:
            raise ProductError(f"{job.tile}: the points carry no {name}; the calibration joins points to the "
                               "trajectory by GPS time and to flight lines by point source id")
    prm = job.params
    gps_all = np.asarray(a["gps_time"], dtype=float)
    keys = point_keys(cloud.xyz, gps_all)
    keep = np.ones(len(cloud), dtype=bool)
    if prm.get("classes") is not None and "classification" in a:
        keep &= np.isin(a["classification"], list(prm["classes"]))
    stride = max(1, int(prm.get("stride", 1)))
    if stride > 1:     # by key, so a point kept in its tile is kept in its neighbours' buffers too
        keep &= (keys % np.uint64(stride)) == 0
    idx = np.flatnonzero(keep)
    own = idx < n_own
    traj = _trajectory(prm["trajectory"], prm.get("trajectory_sha256"), cloud.crs if cloud.crs is not None
                       else job.crs)
    gps, note = match_time_base(gps_all[idx], traj)
    strip = np.asarray(a["point_source_id"])[idx]
    if idx.size:
        sensor, att = traj.at(gps)
        pulses, along = pulses_from_points(cloud.xyz[idx], sensor, att, strip)
    else:
        pulses = PulseRecords(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
        along = np.zeros(0)
    ctrl = None if prm.get("control") is None else np.asarray(prm["control"], dtype=float)
    at = None if prm.get("at") is None else SystemParameters.from_array(prm["at"])
    obs = select_observations(pulses, ctrl, own=own, keys=keys[idx], at=at, radius_m=float(prm.get("radius_m", 2.5)),
                              k=int(prm.get("k", 6)), max_plane_rms_m=float(prm.get("max_plane_rms_m", 0.15)),
                              max_control=prm.get("max_control"), max_strip=prm.get("max_strip"))
    arrays = obs.to_arrays()
    arrays.update(n_points=np.int64(own.sum()), lines=np.unique(strip[own]).astype(np.int64),
                  along_ss=np.float64(np.sum(along[own] ** 2)), time_note=np.array(note))
    with atomic_write(job.output, "wb") as fh:
        np.savez(fh, **arrays)
