r"""The block test of the vertex measurements: tie points tie each photo to its neighbours.

Why.  The per-photo test (:func:`~lidarcat.photocontrol.measure.check_photo`) needs the photo's
other vertices to know its common shift; a measurement *alone on its photo* cannot be tested
there, and the multi-photo test (:func:`~lidarcat.photocontrol.measure.check_consistency`) has
only the approximate orientation's tolerance (~20 px at GSD 0.15 m for 2 m / 0.5 deg).  Over the
real AHN3 roofs the gross values that survive (32-47 px, a fit locked onto another corner of the
same roof) are all such lone measurements.  But the photo is not alone in the block: its tie
points fix its orientation relative to its neighbours, and their vertex measurements fix theirs.

The model.  One bundle adjustment (:mod:`lidarcat.bundle`, thesis eq. 08-22) with

* unknowns: the orientation :math:`p_i` (X0, Y0, Z0 m; omega, phi, kappa rad) of every photo
  that has a vertex measurement or a tie observation, the tie points (free), the vertices;
* observations: the approximate orientation as weighted observations of :math:`p_i` (its
  covariance ``eo_covs``, e.g. 2 m / 0.5 deg), each LiDAR vertex as a weighted control point
  (its covariance from the plane fits, millimetres to centimetres), the tie observations (pixels
  with ``sd_px``) and the accepted vertex measurements (pixels with ``cov_px2``), both turned into
  corrected photo coordinates by the camera (:meth:`~lidarcat.geometry.camera.Camera.pixel_to_photo`,
  covariance :math:`J C J^T`).

The engine weighs per axis; a full covariance :math:`C` is replaced by the diagonal :math:`D`
with :math:`D_{kk} = \sum_l |C_{kl}|`: :math:`D - C` is diagonally dominant, hence positive
semi-definite, so no direction gets a smaller variance than it has (the tests are conservative;
a measurement ellipse elongated along a diagonal is not made narrower across it).

The test.  With one vertex measurement :math:`a` biased by :math:`\nabla` (2-D), Baarda's
statistic :math:`T_a = e_a^T Q_{vv,a}^{-1} e_a` (:mod:`lidarcat.bundle.redundancy`; :math:`e_a`
the residual, :math:`Q_{vv,a}` its cofactor) is exactly the leave-one-out test: the measurement
against the block adjusted without it, whose prediction of the vertex in that photo carries the
covariance of the photo's orientation *as the ties and the other vertex observations fix it*.  A
photo tied to neighbours whose own vertices are measured has its orientation to a fraction of a
pixel, so a 30 px offset gives :math:`w = \sqrt{T} \gg` the critical value (3.42 for q = 2 at
``level`` 0.001, the B-method of :func:`~lidarcat.bundle.redundancy.critical_values`).  The vertex
measurements are tested worst first: the largest :math:`T_a / \chi^2_{1-\alpha_2}(2)` above 1 is
rejected, the block adjusted again without it, and the tests repeated (one rejection per round:
a gross value raises the tests of its neighbours).  The rejection's reason names the offset of
the measurement from the vertex projected with the block adjusted *without* it (px), the w and
the basis: ``inconsistent with the block (12 tie points on its photo and 4 other vertex
observations): 33.2 px, w = 9.1 (critical 3.42)``.

Tie points.  Matched tie points have gross errors too (issue 28), and only the vertex
measurements get decisions here; so the tie points are cleaned first, on their own: the block of
the ties with the approximate orientations as the datum goes through the engine's data snooping
with its robust start (:func:`lidarcat.bundle.reliability.snoop`: screening by the intersection
geometry, re-weighting, w-tests at the family level, the backward step; a photo's GNSS/INS
group is never removed there, it is the only datum).  The ties it rejects stay out; the photos
with fewer than 3 tie observations (after the points with fewer than two rays go) keep no ties.

What cannot be tested.  A photo with no tie point and a lone measurement: its orientation rests
on the prior alone, the measurement's redundancy is :math:`\approx \sigma^2 / (\sigma^2 +
\sigma_{pred}^2)` (0.3 px against 20 px: 2e-4), below
:data:`~lidarcat.bundle.redundancy.MIN_REDUNDANCY`; it is *untestable* and stays as
``check_photo`` left it (listed in :attr:`BlockCheck.untestable`).  Without any tie points
(``ties=None``) each photo is tied to the others only through the vertices (control points of
centimetres), so the block test is then ``check_photo``'s test of every photo at once (the
w-test is the leave-one-out test against the photo's other vertices and its prior) without its
0.5 px linearisation margin: useful as one test over all photos, but no better for a lone
measurement.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from ..errors import DatumError, LidarcatError
from ..geometry.camera import Camera
from .measure import Measurement
from .predict import pixel_positions

__all__ = ["TieObservations", "BlockCheck", "check_block", "REASON_PREFIX"]

log = logging.getLogger(__name__)

#: the reason of a measurement the block test rejects starts with this
REASON_PREFIX = "inconsistent with the block"
_TIE, _VERTEX = "t:", "v:"      # internal point-id prefixes (a tie id may equal a vertex id)


@dataclasses.dataclass(frozen=True, eq=False)
class TieObservations:
    """Image observations of tie points (no ground coordinates).

    Attributes
    ----------
    photo, point : (n,) str
    px : (n, 2) float
        Column, row (px).
    sd_px : (n,) float
        Sd of each coordinate (px), > 0.
    """

    photo: np.ndarray
    point: np.ndarray
    px: np.ndarray
    sd_px: np.ndarray

    def __post_init__(self) -> None:
        photo = frozen_array([str(v) for v in np.atleast_1d(self.photo)], dtype=object)
        point = frozen_array([str(v) for v in np.atleast_1d(self.point)], dtype=object)
        n = len(photo)
        px = np.asarray(self.px, dtype=np.float64).reshape(-1, 2) if n else np.zeros((0, 2))
        sd = np.broadcast_to(np.asarray(self.sd_px, dtype=np.float64), (n,))
        if len(point) != n or len(px) != n:
            raise LidarcatError(f"tie observations: photo ({n}), point ({len(point)}) and px ({len(px)}) must "
                                "have the same length")
        bad = ~(np.isfinite(px).all(axis=1) & np.isfinite(sd) & (sd > 0))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise LidarcatError(f"tie observation of point {point[k]!r} on photo {photo[k]!r}: px and sd_px must "
                                f"be finite and sd_px > 0 (got {px[k].tolist()}, {float(sd[k])})")
        object.__setattr__(self, "photo", photo)
        object.__setattr__(self, "point", point)
        object.__setattr__(self, "px", frozen_array(px))
        object.__setattr__(self, "sd_px", frozen_array(sd))

    def __len__(self) -> int:
        return len(self.photo)


@dataclasses.dataclass(frozen=True, eq=False)
class BlockCheck:
    """Outcome of :func:`check_block`.

    Attributes
    ----------
    measurements : tuple of Measurement
        Same order as given; those inconsistent with the block have status ``rejected`` and the reason.
    eo : dict photo -> (6,)
        Adjusted orientation (m, rad) of every photo of the final adjustment (empty when nothing
        was adjusted).
    eo_cov : dict photo -> (6, 6)
        Its covariance (a priori variance factor).
    tested : int
        Vertex measurements tested in the last adjustment (testable ones) plus those rejected.
    untestable : tuple of (point, photo)
        Accepted measurements whose test has no redundancy (a lone measurement on a photo without
        ties): kept as given.
    rejected : tuple of (point, photo, w, offset_px)
        The rejections, in the order found.
    ties_used, ties_rejected, ties_dropped : int
        Tie observations in the final adjustment; rejected by the tie snooping; left out because
        their point had fewer than two rays or their photo fewer than three tie observations.
    rounds : int
        Adjustments of the vertex test.
    status : str
        ``ok``; ``nothing`` (no accepted measurement); ``not_converged`` (the adjustment failed:
        nothing rejected, see *message*).
    message : str
    """

    measurements: tuple[Measurement, ...]
    eo: dict[str, np.ndarray]
    eo_cov: dict[str, np.ndarray]
    tested: int = 0
    untestable: tuple[tuple[str, str], ...] = ()
    rejected: tuple[tuple[str, str, float, float], ...] = ()
    ties_used: int = 0
    ties_rejected: int = 0
    ties_dropped: int = 0
    rounds: int = 0
    status: str = "ok"
    message: str = ""

    def summary(self) -> dict[str, Any]:
        """Counts for a JSON report."""
        return {"status": self.status, "message": self.message, "tested": self.tested,
                "untestable": len(self.untestable), "rejected": len(self.rejected), "ties_used": self.ties_used,
                "ties_rejected": self.ties_rejected, "ties_dropped": self.ties_dropped, "rounds": self.rounds,
                "photos": len(self.eo)}


def _dominant_sd(cov: np.ndarray) -> np.ndarray:
    """(..., k) sds of the diagonal D, D_kk = sum_l |C_kl|, that dominates the covariance C (..., k, k)."""
    return np.sqrt(np.sum(np.abs(cov), axis=-1))


def _located(name: str, pid: str, what: str) -> LidarcatError:
    return LidarcatError(f"photo {pid!r}: {what} but no {name} for it (check_block needs the camera, the "
                         "approximate orientation and its covariance of every photo observed)")


def _check_photo_inputs(pid: str, what: str, cameras: Mapping[str, Camera], eos: Mapping[str, Any],
                        eo_covs: Mapping[str, Any]) -> None:
    for name, table in (("camera", cameras), ("approximate orientation", eos), ("orientation covariance", eo_covs)):
        if pid not in table:
            raise _located(name, pid, what)


def _clean_ties(photo: np.ndarray, point: np.ndarray, keep: np.ndarray | None = None, min_rays: int = 2,
                min_per_photo: int = 3) -> np.ndarray:
    """(n,) bool: of the tie observations *keep* (default all), those of points with >= *min_rays* photos on
    photos with >= *min_per_photo* of them (repeated until stable)."""
    keep = np.ones(len(photo), dtype=bool) if keep is None else np.array(keep, dtype=bool)
    while keep.any():
        _, pinv, pcount = np.unique(point[keep], return_inverse=True, return_counts=True)
        k1 = keep.copy()
        k1[keep] = pcount[pinv] >= min_rays
        _, finv, fcount = np.unique(photo[k1], return_inverse=True, return_counts=True) if k1.any() else \
            (None, np.zeros(0, int), np.zeros(0, int))
        k2 = k1.copy()
        k2[k1] = fcount[finv] >= min_per_photo
        if np.array_equal(k2, keep):
            break
        keep = k2
    return keep


def _snoop_ties(ties: TieObservations, keep: np.ndarray, cameras, eos, eo_covs, xy_mm, sd_mm
                ) -> tuple[np.ndarray, dict[str, np.ndarray], str]:
    """The ties' own block (approximate orientations as the datum) through the engine's data snooping with
    its robust start; returns the kept mask, the adjusted orientations and a note."""
    from ..bundle import BundleProblem
    from ..bundle.reliability import snoop

    idx = np.flatnonzero(keep)
    photos = sorted(set(ties.photo[idx].tolist()))
    ph_pos = {p: i for i, p in enumerate(photos)}
    pts, pt_index = np.unique(ties.point[idx].astype(str), return_inverse=True)
    prob = BundleProblem(
        photo_ids=photos, point_ids=pts, focal_length_mm=[cameras[p].focal_length_mm for p in photos],
        photo_index=[ph_pos[p] for p in ties.photo[idx]], point_index=pt_index, xy_mm=xy_mm[idx], sd_mm=sd_mm[idx],
        constraint_point_index=np.zeros(0, int), constraint_enh_m=np.zeros((0, 3)), constraint_sd_m=np.zeros((0, 3)),
        eo_constraint_photo_index=np.arange(len(photos)),
        eo_constraint_params=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]),
        eo_constraint_sd=np.array([_dominant_sd(np.asarray(eo_covs[p], float).reshape(6, 6)) for p in photos]),
        initial_eo=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]))
    try:
        sr = snoop(prob, mode="remove", start="robust", precision="none")
    except DatumError as ex:
        log.warning("block check: the tie points' robust start failed (%s); snooping from least squares", ex)
        try:
            sr = snoop(prob, mode="remove", start="plain", precision="none")
        except DatumError as ex2:
            return np.zeros(len(keep), dtype=bool), {}, f"tie points left out: {ex2}"
    out = keep.copy()
    gone = {(b.photo, b.point) for b in sr.blunders if b.kind == "image" and b.removed}
    for k in idx:
        if (str(ties.photo[k]), str(ties.point[k])) in gone:
            out[k] = False
    eo = {}
    if sr.result is not None and np.isfinite(np.asarray(sr.result.eo_params)).all():
        eo = {p: np.asarray(sr.result.eo_params)[i] for i, p in enumerate(photos)}
    return _clean_ties(ties.photo, ties.point, out), eo, ""


def check_block(measurements: Sequence[Measurement], cameras: Mapping[str, Camera], eos: Mapping[str, Any],
                eo_covs: Mapping[str, Any], vertices_m: Mapping[str, Any], vertex_covs: Mapping[str, Any],
                ties: TieObservations | None, *, level: float = 0.001, power: float = 0.80,
                floor_sd_px: float = 0.0, snoop_ties: bool = True, max_iter: int = 50) -> BlockCheck:
    """The vertex measurements tested in one bundle adjustment of the block (module docstring).

    Parameters
    ----------
    measurements : sequence of Measurement
        Any photos and vertices; only those with status ``measured`` (finite px and cov_px2) are
        adjusted and tested, the others pass untouched.
    cameras : photo -> Camera
    eos : photo -> (6,)
        Approximate orientations X0, Y0, Z0 (m), omega, phi, kappa (rad) (the predictions').
    eo_covs : photo -> (6, 6)
        Their covariances (m^2, m rad, rad^2).
    vertices_m : point -> (3,)
        The LiDAR vertices (E, N, h, m); vertex_covs : point -> (3, 3) (m^2).
    ties : TieObservations or None
        Tie observations (pixels) on the photos; None: the vertices alone tie the photos.
    level : float
        alpha of the one-dimensional w-test (B-method: 0.001 gives w 3.42 for a 2-D measurement).
    power : float
        Power of the tests (B-method).
    floor_sd_px : float
        Added in quadrature to each coordinate sd of the vertex measurements (px), for what
        their covariance does not see.
    snoop_ties : bool
        Clean the tie points by the engine's data snooping first (default); False: use them as given.
    max_iter : int
        Iterations of each adjustment.

    Returns
    -------
    BlockCheck

    Raises
    ------
    LidarcatError
        A measurement or tie observation on a photo without a camera, approximate orientation or
        covariance (names the photo), a measurement of a vertex without coordinates or covariance
        (names the point), bad tie observations.
    """
    from ..bundle import BundleProblem, adjust
    from ..bundle.redundancy import check_level, reliability

    try:
        check_level(level, power)
    except ValueError as ex:
        raise LidarcatError(f"check_block: {ex}") from None
    ms = list(measurements)
    live = [k for k, m in enumerate(ms) if m and np.isfinite(m.px).all() and np.isfinite(m.cov_px2).all()]
    for k in live:
        m = ms[k]
        _check_photo_inputs(m.photo, f"a measurement of point {m.point!r}", cameras, eos, eo_covs)
        if m.point not in vertices_m or m.point not in vertex_covs:
            raise LidarcatError(f"point {m.point!r}: measured on photo {m.photo!r} but no vertex coordinates or "
                                "covariance for it")
    if ties is not None:
        for pid in sorted(set(ties.photo.tolist())):
            _check_photo_inputs(pid, "tie observations", cameras, eos, eo_covs)
    if not live:
        return BlockCheck(tuple(ms), {}, {}, status="nothing", message="no accepted measurement")

    # --- the tie points: in photo coordinates, cleaned on their own -------------------------------------
    n_t = 0 if ties is None else len(ties)
    t_xy = np.zeros((n_t, 2))
    t_sd = np.zeros((n_t, 2))
    for pid in sorted(set(ties.photo.tolist())) if n_t else []:
        sel = ties.photo == pid
        cam = cameras[pid]
        t_xy[sel] = cam.pixel_to_photo(ties.px[sel])
        t_sd[sel] = cam.photo_sd(ties.px[sel], np.repeat(ties.sd_px[sel, None], 2, axis=1))
    t_keep = _clean_ties(ties.photo, ties.point) if n_t else np.zeros(0, dtype=bool)
    dropped = int(n_t - t_keep.sum())
    start: dict[str, np.ndarray] = {}
    note = ""
    n_tie_rej = 0
    if t_keep.any() and snoop_ties:
        k0 = int(t_keep.sum())
        t_keep, start, note = _snoop_ties(ties, t_keep, cameras, eos, eo_covs, t_xy, t_sd)
        n_tie_rej = k0 - int(t_keep.sum())

    # --- the vertex measurements in photo coordinates ---------------------------------------------------
    v_xy = np.zeros((len(live), 2))
    v_sd = np.zeros((len(live), 2))
    for i, k in enumerate(live):
        m = ms[k]
        cam = cameras[m.photo]
        j = np.asarray(cam.pixel_to_photo_jacobian(np.asarray(m.px)[None]))[0]
        c = np.asarray(m.cov_px2, float) + np.eye(2) * float(floor_sd_px) ** 2
        v_xy[i] = cam.pixel_to_photo(np.asarray(m.px, float)[None])[0]
        v_sd[i] = _dominant_sd(j @ c @ j.T)
    v_photo = np.array([ms[k].photo for k in live], dtype=object)
    v_point = np.array([ms[k].point for k in live], dtype=object)
    t_photo_all = ties.photo if n_t else np.zeros(0, dtype=object)
    ties_on = {p: int(np.sum(t_keep & (t_photo_all == p))) for p in set(v_photo.tolist())}

    def problem(v_in: np.ndarray) -> tuple[Any, np.ndarray]:
        """The block of the kept ties and the vertex measurements *v_in*; the photo ids."""
        tp = t_photo_all[t_keep] if n_t else np.zeros(0, dtype=object)
        photos = sorted(set(tp.tolist()) | set(v_photo[v_in].tolist()))
        pos = {p: i for i, p in enumerate(photos)}
        verts = sorted(set(v_point[v_in].tolist()))
        tie_ids = sorted(set((_TIE + ties.point[t_keep].astype(str)).tolist())) if n_t else []
        pt_ids = tie_ids + [_VERTEX + v for v in verts]
        ppos = {q: i for i, q in enumerate(pt_ids)}
        ph_idx = [pos[p] for p in tp] + [pos[p] for p in v_photo[v_in]]
        pt_idx = ([ppos[_TIE + str(q)] for q in ties.point[t_keep]] if n_t else []) + \
            [ppos[_VERTEX + v] for v in v_point[v_in]]
        xy = np.concatenate([t_xy[t_keep], v_xy[v_in]])
        sd = np.concatenate([t_sd[t_keep], v_sd[v_in]])
        prob = BundleProblem(
            photo_ids=photos, point_ids=pt_ids, focal_length_mm=[cameras[p].focal_length_mm for p in photos],
            photo_index=np.asarray(ph_idx, dtype=np.int64), point_index=np.asarray(pt_idx, dtype=np.int64),
            xy_mm=xy.reshape(-1, 2), sd_mm=sd.reshape(-1, 2),
            constraint_point_index=np.array([ppos[_VERTEX + v] for v in verts], dtype=np.int64),
            constraint_enh_m=np.array([np.asarray(vertices_m[v], float).reshape(3) for v in verts]).reshape(-1, 3),
            constraint_sd_m=np.array([_dominant_sd(np.asarray(vertex_covs[v], float).reshape(3, 3))
                                      for v in verts]).reshape(-1, 3),
            eo_constraint_photo_index=np.arange(len(photos)),
            eo_constraint_params=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]),
            eo_constraint_sd=np.array([_dominant_sd(np.asarray(eo_covs[p], float).reshape(6, 6)) for p in photos]))
        return prob, np.asarray(photos, dtype=object)

    def solve(prob: Any, photos: np.ndarray, warm: dict[str, np.ndarray], precision: str = "none") -> Any:
        from ..bundle.approx import intersect_points

        eo0 = np.array([warm.get(p, np.asarray(eos[p], float).reshape(6)) for p in photos])
        return adjust(prob, initial=(eo0, intersect_points(prob, eo0)), check=False, precision=precision,
                      max_iter=max_iter)

    v_in = np.ones(len(live), dtype=bool)
    rejected: list[tuple[str, str, float, float]] = []
    rounds = 0
    warm = dict(start)
    prob, photos = problem(v_in)
    res = solve(prob, photos, warm)
    rounds += 1
    n_t_used = int(t_keep.sum())
    if not res.success:
        return BlockCheck(tuple(ms), {}, {}, ties_used=n_t_used, ties_rejected=n_tie_rej, ties_dropped=dropped,
                          rounds=rounds, status="not_converged",
                          message=f"the block adjustment did not converge ({res.message}); nothing rejected"
                                  + (f"; {note}" if note else ""))
    n_tie_obs = n_t_used
    untestable: list[tuple[str, str]] = []
    while True:
        try:
            rel = reliability(res, level=level, power=power)
        except DatumError as ex:
            return BlockCheck(tuple(ms), {}, {}, rejected=tuple(rejected), ties_used=n_t_used,
                              ties_rejected=n_tie_rej, ties_dropped=dropped, rounds=rounds, status="not_converged",
                              message=f"the block's tests failed ({ex})")
        n_obs = len(prob.photo_index)
        vrows = np.arange(n_tie_obs, n_obs)              # the vertex observations follow the ties
        ratio = np.where(rel.testable[vrows], np.nan_to_num(rel.ratio[vrows], nan=-np.inf), -np.inf)
        live_in = np.flatnonzero(v_in)                   # vertex observation i of the problem = live_in[i]
        if not len(vrows) or ratio.max() <= 1.0 or v_in.sum() == 0:
            untestable = [(str(v_point[live_in[i]]), str(v_photo[live_in[i]]))
                          for i in np.flatnonzero(~rel.testable[vrows])]
            break
        i = int(np.argmax(ratio))
        g = int(vrows[i])
        w, crit = float(rel.w[g]), float(rel.w_critical[g])
        a = int(live_in[i])
        pid, vid = str(v_photo[a]), str(v_point[a])
        others = int(v_in.sum()) - 1
        n_ties_photo = ties_on.get(pid, 0)
        # two measurements on a photo without ties: which of the two is off cannot be told (both go)
        same = [int(b) for b in np.flatnonzero(v_in & (v_photo == pid)) if b != a]
        partner = same[0] if n_ties_photo == 0 and len(same) == 1 else None
        warm = {p: np.asarray(res.eo_params)[j] for j, p in enumerate(photos)}
        v_in[a] = False
        if partner is not None:
            v_in[partner] = False
        prob, photos = problem(v_in) if v_in.any() or t_keep.any() else (None, photos)
        res_new = solve(prob, photos, warm) if prob is not None else res
        rounds += prob is not None
        if not res_new.success:
            v_in[a] = True
            if partner is not None:
                v_in[partner] = True
            prob, photos = problem(v_in)
            note = "; ".join(x for x in (note, f"the adjustment without {vid} on {pid} did not converge: "
                                               "testing stopped") if x)
            break
        res = res_new
        ph = {p: j for j, p in enumerate(photos)}
        eo_p = np.asarray(res.eo_params)[ph[pid]] if pid in ph else np.asarray(eos[pid], float).reshape(6)
        pts = {str(q): np.asarray(res.points_m)[j] for j, q in enumerate(res.point_ids)}

        def offset(b: int) -> float:
            """Measurement *b* minus its vertex projected with the block adjusted without it (px)."""
            x = pts.get(_VERTEX + str(v_point[b]), np.asarray(vertices_m[str(v_point[b])], float).reshape(3))
            return float(np.hypot(*(np.asarray(ms[live[b]].px) - pixel_positions(cameras[pid], eo_p, x[None])[0])))

        off = offset(a)
        rejected.append((vid, pid, w, off))
        basis = (f"{n_ties_photo} tie points on its photo and {others} other vertex observations" if n_ties_photo
                 else f"no tie points on its photo; {others} other vertex observations")
        ms[live[a]] = ms[live[a]].failed(
            "rejected", f"{REASON_PREFIX} ({basis}): {off:.1f} px, w = {w:.1f} (critical {crit:.2f})")
        if partner is not None:
            off_b = offset(partner)
            rejected.append((str(v_point[partner]), pid, math.nan, off_b))
            ms[live[partner]] = ms[live[partner]].failed(
                "rejected", f"{REASON_PREFIX}: {off_b:.1f} px; its photo has no tie points and its other measurement "
                            f"({vid}, w = {w:.1f}) disagrees with it: which of the two is off cannot be told")
        if prob is None:
            break
    tested = int(v_in.sum()) - len(untestable) + len(rejected)
    if prob is None:          # every measurement rejected
        return BlockCheck(tuple(ms), {}, {}, tested=tested, rejected=tuple(rejected), ties_used=n_t_used,
                          ties_rejected=n_tie_rej, ties_dropped=dropped, rounds=rounds, status="ok", message=note)
    final = adjust(prob, initial=(np.asarray(res.eo_params), np.asarray(res.points_m)), check=False,
                   precision="photos", max_iter=max_iter)
    rounds += 1
    use = final if final.success else res
    eo_out = {str(p): np.array(use.eo_params[j]) for j, p in enumerate(photos)}
    cov_out = {str(p): np.array(use.eo_cov[j]) for j, p in enumerate(photos)}
    return BlockCheck(tuple(ms), eo_out, cov_out, tested=tested, untestable=tuple(untestable),
                      rejected=tuple(rejected), ties_used=n_t_used, ties_rejected=n_tie_rej, ties_dropped=dropped,
                      rounds=rounds, status="ok", message=note)
