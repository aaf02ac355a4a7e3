r"""The block test of the vertex measurements and roof edges: tie points tie each photo to its neighbours.

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
  with ``sd_px``, or a survey's corrected photo coordinates with ``sd_mm`` as its adjustment uses them)
  and the accepted vertex measurements (pixels with ``cov_px2``), pixels turned into corrected photo
  coordinates by the camera (:meth:`~lidarcat.geometry.camera.Camera.pixel_to_photo`, covariance
  :math:`J C J^T`).

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

Roof edges (``lines=``).  The edges that measure-control writes as line control (one
:class:`EdgeObservation` per edge and photo: the two equivalent points of the free edge fit,
:class:`~lidarcat.photocontrol.measure.EdgeLine`, and the 3-D line of the two planes with its 6 x 6
covariance, :func:`~lidarcat.photocontrol.predict.edge_line_m`) enter the same adjustment as line
control (:class:`lidarcat.bundle.lines.LineControl`: the projection plane of the image line contains
the 3-D line, two residuals per edge, weighted by the image sd and the line's covariance).  Each is
tested by the 2-D line test of :func:`lidarcat.bundle.line_tests.line_tests`, :math:`T = e^T
Q_{vv}^{-1} e` with :math:`Q_{vv} = \Sigma_r - A C_i A^T` exact from its photo's covariance -- again
the leave-one-out test -- on the scale of the vertex tests (``T`` over the same
:math:`\chi^2_{1-\alpha_2}(2)`): in every round the worst of all vertex and edge observations above
its critical value is rejected and the block adjusted again.  A rejected edge's reason names the
distance (px) of the middle of the measured edge from its 3-D line projected with the block adjusted
*without* it, and w: ``roof edge inconsistent with the block (456 tie points on its photo, 1 vertex
observations and 3 other edges): 64.8 px off its LiDAR line, w = 25.3 (critical 3.42)``.  Line
control converges slowly when few lines hold the block's datum: an adjustment that does not converge
in ``max_iter`` is continued for ``4 max_iter``.

Points and edges of one vertex on one photo come from the same edge fits (the point is the
intersection of its edges).  Adjusting both would count the fits twice; so where an edge of vertex V
on photo P is given, V's point measurement on P is *not* adjusted: its edges stand for it (they carry
more -- each edge on its own, its direction too).  Its verdict is theirs: an edge rejected indicts
the point (``rejected``, ``inconsistent with the block: its roof edge V/1-2 on this photo is 64.8 px
off its LiDAR line (w = 25.3)``); a point kept is not tested twice.  The other edges of V on P stay
(separate fits of separate image edges, each tested itself in the next round).  measure-control
passes only the edges it would write: with ``--lines add`` those of vertices whose point was not
measured (so points and edges never meet there), with ``--lines only`` every edge (then the edges
replace the points in the test).

Along one edge.  A point located along one edge (:attr:`~lidarcat.photocontrol.measure.Measurement.along_line`,
measure step 3a) is the intersection of two edges that lie nearly on one image line: its covariance is tight
across the line (the edges' offsets) and loose along it (their small angle).  measure-control writes its edges
beside it, so they stand for it here too and test it *across* the line; its position *along* the line is what
the point adds, and that is tested on the final block (which does not hold the point): with :math:`u` the
major axis of the point's covariance :math:`C` (the line's direction), :math:`d` the point minus its LiDAR
vertex projected with the photo's adjusted orientation,

.. math:: w = \frac{u^T d}{\sqrt{u^T (C + J_o \Sigma_o J_o^T + J_x \Sigma_x J_x^T) u}}

(:math:`\Sigma_o` the photo's orientation covariance from the block, :math:`\Sigma_x` the vertex's, :math:`J`
the pixel Jacobians; ``floor_sd_px`` added to :math:`C`), against the 1-D critical value (3.29 at ``level``
0.001): the leave-one-out test of the along component alone.  Rejected: ``inconsistent with the block along
its edge (456 tie points on its photo): 12.1 px along the line from the vertex projected with the block, w =
6.0 (critical 3.29)``, and measure-control then writes neither the point nor its edges.  Ignored: the
correlation of the photo's adjusted orientation with the vertex (through its other photos) and with the point's
own edges (the same fits, in the block) -- small beside a pixel when tie points hold the photo; where they do
not, the test is weaker, not wrong.  A point with no edge given is adjusted like any vertex measurement.

The backward step over the edges.  Worst first presumes the largest test is the gross observation's;
that holds while the observations' tests are nearly independent.  When the block's datum rests on the
edges of one short line alone (ties and GNSS/IMU otherwise), its observations on the different photos
are tested against each other and the block, distorted by the gross one, can make a good edge look
worse: with one 2.5 m line on three photos and no vertex point, one edge 50 px off, the three w come
out within a few per cent of each other (12.1, 11.4, 12.7), and the largest may be a good one's -- then
the good edge goes first and the gross one second, or the gross one is left untestable beside the last
good one.  So, as the engine's data snooping does (:func:`lidarcat.bundle.reliability.snoop`, whose
tests of the rays of one point are correlated the same way), a backward step follows the worst-first
rounds: each rejected edge is put back, and when every test then passes it was a false rejection and
stays in; otherwise each other edge of its line that is in is rejected instead, in turn, and the
exchange that lowers :math:`v^T P v` most (the same number of observations out: the likelihood
decides) is kept when every test passes then (its reason says so: ``rejected instead of its line's
edge on photo P (lower v'Pv)``, its w from the adjustment with both in).  One change at a time, until
none.  The reasons of the edges rejected in the end name their offsets from the final block (four such
blocks are in tests/photocontrol/test_block_check.py).  The vertex measurements have no such step: their
tests on a tied photo are nearly independent.

Bench_lines seed 4 (docs/figures.md): an edge 64 px off its LiDAR line (the approximate orientation
predicts to ~87 px) with 3 other edges and one vertex observation; without it the block predicts that
edge to 2.5 px, so its w is 25.3 and it is rejected; the good vertex observation, which a block
distorted by the edge had rejected (17 px, w 12.5), is kept.  (That needed the line tests' testability
from the eigenvalues of :math:`Q_{vv} P`: the diagonal of it, the per-component redundancy, leaves
[0, 1] when the 3-D line's ends lie far outside the measured segment, and the edge was called
untestable.)

Tie points.  Matched tie points have gross errors too (issue 28), and only the vertex
measurements get decisions here; so the tie points are cleaned first, on their own: the block of
the ties with the approximate orientations as the datum goes through the engine's data snooping
with its robust start (:func:`lidarcat.bundle.reliability.snoop`: screening by the intersection
geometry, re-weighting, w-tests at the family level, the backward step; a photo's GNSS/INS
group is never removed there, it is the only datum).  The ties it rejects stay out; the photos
with fewer than 3 tie observations (after the points with fewer than two rays go) keep no ties.

What cannot be tested.  A photo with no tie point and a lone measurement: its orientation rests
on the prior alone, so the measurement is tested against its prediction only (the w-test is then
the ellipse test of :func:`~lidarcat.photocontrol.measure.check_consistency`: 30 px passes a 20 px
prediction sd), or, when its redundancy :math:`\approx \sigma^2 / (\sigma^2 + \sigma_{pred}^2)`
(0.3 px against 20 px: 2e-4) is below :data:`~lidarcat.bundle.redundancy.MIN_REDUNDANCY`, not at
all (listed in :attr:`BlockCheck.untestable`); either way it stays as ``check_photo`` left it.
Two measurements on a photo without tie points that the test separates are both rejected, as
``check_photo`` does (which of the two is off cannot be told against a 20 px prior).  Without any
tie points (``ties=None``) each photo is tied to the others only through the vertices (control
points of centimetres), so the block test is then ``check_photo``'s test of every photo at once
(the w-test is the leave-one-out test against the photo's other vertices and its prior) without
its 0.5 px linearisation margin, plus the ellipse test of the lone ones: one test over all photos,
no better for a lone measurement.

Over the real AHN3 roofs (five blocks at GSD 0.10-0.15 m, tie points from the truth + 0.3 px;
docs/photocontrol.md) the six gross measurements left by the per-photo test (5-47 px, three of them
alone on their photo) are rejected with w 6-74 and the 37 good ones kept.
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
from ._block_backward import block_tests, edge_backward_step
from ._block_model import VERTEX, BlockModel
from ._block_ties import dominant_sd, prepared_ties
from .measure import Measurement
from .predict import pixel_positions

__all__ = ["TieObservations", "EdgeObservation", "BlockCheck", "check_block", "REASON_PREFIX", "LINE_REASON_PREFIX"]

log = logging.getLogger(__name__)

#: the reason of a measurement the block test rejects starts with this
REASON_PREFIX = "inconsistent with the block"
#: the reason of a roof edge the block test rejects starts with this
LINE_REASON_PREFIX = "roof edge inconsistent with the block"


@dataclasses.dataclass(frozen=True, eq=False)
class TieObservations:
    """Image observations of tie points (no ground coordinates): in pixels, or in corrected photo
    coordinates as a survey's adjustment uses them (:meth:`lidarcat.survey.folder.Survey.photo_observations`;
    then they go into the block as they are, with no camera model in between).

    Attributes
    ----------
    photo, point : (n,) str
    px : (n, 2) float or None
        Column, row (px).
    sd_px : (n,) float or None
        Sd of each coordinate (px), > 0.
    xy_mm : (n, 2) float or None
        Corrected photo coordinates (mm), instead of *px*.
    sd_mm : (n, 2) float or None
        Their sds (mm), > 0 (with *xy_mm*).
    """

    photo: np.ndarray
    point: np.ndarray
    px: np.ndarray | None = None
    sd_px: np.ndarray | None = None
    xy_mm: np.ndarray | None = None
    sd_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        photo = frozen_array([str(v) for v in np.atleast_1d(self.photo)], dtype=object)
        point = frozen_array([str(v) for v in np.atleast_1d(self.point)], dtype=object)
        n = len(photo)
        in_mm = self.xy_mm is not None
        if in_mm == (self.px is not None) or (self.sd_mm is None if in_mm else self.sd_px is None):
            raise LidarcatError("tie observations: give px with sd_px, or xy_mm with sd_mm")
        xy, unit = (self.xy_mm, "xy_mm") if in_mm else (self.px, "px")
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2) if n else np.zeros((0, 2))
        sd = np.broadcast_to(np.asarray(self.sd_mm, dtype=np.float64), (n, 2)) if in_mm else \
            np.broadcast_to(np.asarray(self.sd_px, dtype=np.float64), (n,))
        if len(point) != n or len(xy) != n:
            raise LidarcatError(f"tie observations: photo ({n}), point ({len(point)}) and {unit} ({len(xy)}) must "
                                "have the same length")
        sd2 = sd.reshape(n, -1)
        bad = ~(np.isfinite(xy).all(axis=1) & np.isfinite(sd2).all(axis=1) & (sd2 > 0).all(axis=1))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            what = "xy_mm and sd_mm" if in_mm else "px and sd_px"
            got = sd2[k].tolist() if in_mm else float(sd[k])
            raise LidarcatError(f"tie observation of point {point[k]!r} on photo {photo[k]!r}: {what} must "
                                f"be finite and {what.split()[-1]} > 0 (got {xy[k].tolist()}, {got})")
        object.__setattr__(self, "photo", photo)
        object.__setattr__(self, "point", point)
        object.__setattr__(self, "xy_mm" if in_mm else "px", frozen_array(xy))
        object.__setattr__(self, "sd_mm" if in_mm else "sd_px", frozen_array(sd))

    def __len__(self) -> int:
        return len(self.photo)


@dataclasses.dataclass(frozen=True, eq=False)
class EdgeObservation:
    """A roof edge measured in one photo (:class:`~lidarcat.photocontrol.measure.EdgeLine`) with its 3-D line
    (:func:`~lidarcat.photocontrol.predict.edge_line_m`): what measure-control writes to line_control.csv.

    Attributes
    ----------
    line, point, photo : str
        Line id, the LiDAR vertex whose edge fits it comes from, the photo.
    p1_px, p2_px : (2,) float
        The edge's two equivalent points (column, row, px).
    sd_px : float
        Their sd across the edge (px), > 0.
    a_m, b_m : (3,) float
        End points of the 3-D line (E, N, h, m); cov_m2 : (6, 6) covariance of (A, B) (m^2).
    """

    line: str
    point: str
    photo: str
    p1_px: np.ndarray
    p2_px: np.ndarray
    sd_px: float
    a_m: np.ndarray
    b_m: np.ndarray
    cov_m2: np.ndarray

    def __post_init__(self) -> None:
        s = object.__setattr__
        for k in ("line", "point", "photo"):
            s(self, k, str(getattr(self, k)))
        vals = {k: np.asarray(getattr(self, k), dtype=np.float64).reshape(n) for k, n in
                (("p1_px", 2), ("p2_px", 2), ("a_m", 3), ("b_m", 3))}
        cov = np.asarray(self.cov_m2, dtype=np.float64).reshape(6, 6)
        sd = float(self.sd_px)
        where = f"edge {self.line} on photo {self.photo!r}"
        if not (all(np.isfinite(v).all() for v in vals.values()) and np.isfinite(cov).all() and math.isfinite(sd)
                and sd > 0):
            raise LidarcatError(f"{where}: points, line, covariance and sd_px must be finite, sd_px > 0")
        if np.hypot(*(vals["p2_px"] - vals["p1_px"])) <= 1e-9 or np.linalg.norm(vals["b_m"] - vals["a_m"]) <= 0:
            raise LidarcatError(f"{where}: its two image points or its line's end points coincide")
        for k, v in vals.items():
            s(self, k, frozen_array(v))
        s(self, "cov_m2", frozen_array(cov))
        s(self, "sd_px", sd)


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
    lines_tested : int
        Edge observations (``lines=``) tested in the last adjustment plus those rejected.
    lines_untestable : tuple of (line, photo)
        Edges whose test has no redundancy: kept.
    lines_rejected : tuple of (line, photo, w, offset_px)
        The rejected edges, in the order found.
    line_reasons : dict (line, photo) -> str
        The reason of every rejected edge (starts with :data:`LINE_REASON_PREFIX`).
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
    lines_tested: int = 0
    lines_untestable: tuple[tuple[str, str], ...] = ()
    lines_rejected: tuple[tuple[str, str, float, float], ...] = ()
    line_reasons: dict[tuple[str, str], str] = dataclasses.field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """Counts for a JSON report."""
        return {"status": self.status, "message": self.message, "tested": self.tested,
                "untestable": len(self.untestable), "rejected": len(self.rejected), "ties_used": self.ties_used,
                "ties_rejected": self.ties_rejected, "ties_dropped": self.ties_dropped, "rounds": self.rounds,
                "photos": len(self.eo), "lines_tested": self.lines_tested,
                "lines_untestable": len(self.lines_untestable), "lines_rejected": len(self.lines_rejected)}


def _located(name: str, pid: str, what: str) -> LidarcatError:
    return LidarcatError(f"photo {pid!r}: {what} but no {name} for it (check_block needs the camera, the "
                         "approximate orientation and its covariance of every photo observed)")


def _check_photo_inputs(pid: str, what: str, cameras: Mapping[str, Camera], eos: Mapping[str, Any],
                        eo_covs: Mapping[str, Any]) -> None:
    for name, table in (("camera", cameras), ("approximate orientation", eos), ("orientation covariance", eo_covs)):
        if pid not in table:
            raise _located(name, pid, what)


def _live_measurements(ms: list[Measurement], edges: list[EdgeObservation], cameras: Mapping[str, Camera],
                       eos: Mapping[str, Any], eo_covs: Mapping[str, Any], vertices_m: Mapping[str, Any],
                       vertex_covs: Mapping[str, Any], ties: TieObservations | None) -> tuple[list[int], dict]:
    """The indices of the measurements the block adjusts and those its *edges* stand for (``(point, photo) ->
    index``), the inputs checked (located errors, :func:`check_block`)."""
    live = [k for k, m in enumerate(ms) if m and np.isfinite(m.px).all() and np.isfinite(m.cov_px2).all()]
    for k in live:
        m = ms[k]
        _check_photo_inputs(m.photo, f"a measurement of point {m.point!r}", cameras, eos, eo_covs)
        if m.point not in vertices_m or m.point not in vertex_covs:
            raise LidarcatError(f"point {m.point!r}: measured on photo {m.photo!r} but no vertex coordinates or "
                                "covariance for it")
    for e in edges:
        _check_photo_inputs(e.photo, f"an edge of line {e.line!r}", cameras, eos, eo_covs)
    # a vertex measured on a photo where its edges are tested: the edges stand for it (the same fits)
    edge_pairs = {(e.point, e.photo) for e in edges}
    replaced = {(ms[k].point, ms[k].photo): k for k in live if (ms[k].point, ms[k].photo) in edge_pairs}
    live = [k for k in live if (ms[k].point, ms[k].photo) not in replaced]
    if ties is not None:
        for pid in sorted(set(ties.photo.tolist())):
            _check_photo_inputs(pid, "tie observations", cameras, eos, eo_covs)
    if not live and not edges:
        return live, replaced
    used = {ms[k].photo for k in live} | {e.photo for e in edges} | \
        (set(ties.photo.tolist()) if ties is not None else set())
    for pid in sorted(used):
        if not np.all(dominant_sd(np.asarray(eo_covs[pid], float).reshape(6, 6)) > 0):
            raise LidarcatError(f"photo {pid!r}: the covariance of its approximate orientation has a zero or "
                                "undefined variance (use inf for a free parameter)")
    for v in sorted({ms[k].point for k in live}):
        if not np.all(dominant_sd(np.asarray(vertex_covs[v], float).reshape(3, 3)) > 0):
            raise LidarcatError(f"point {v!r}: the covariance of the LiDAR vertex has a zero or undefined variance")
    return live, replaced


def check_block(measurements: Sequence[Measurement], cameras: Mapping[str, Camera], eos: Mapping[str, Any],
                eo_covs: Mapping[str, Any], vertices_m: Mapping[str, Any], vertex_covs: Mapping[str, Any],
                ties: TieObservations | None, *, level: float = 0.001, power: float = 0.80,
                floor_sd_px: float = 0.0, snoop_ties: bool = True, max_iter: int = 50,
                lines: Sequence[EdgeObservation] | None = None) -> BlockCheck:
    """The vertex measurements (and roof edges) tested in one bundle adjustment of the block (module docstring).

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
        Tie observations (pixels, or a survey's corrected photo coordinates) on the photos; None: the vertices
        alone tie the photos.
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
    lines : sequence of EdgeObservation, optional
        Roof edges to test as line control (what would be written to line_control.csv).  A vertex
        measurement on the photo of one of its edges given here is not adjusted (the same fits), it
        gets the verdict of its edges (module docstring).

    Returns
    -------
    BlockCheck

    Raises
    ------
    LidarcatError
        A measurement, edge or tie observation on a photo without a camera, approximate orientation or
        covariance (names the photo), a measurement of a vertex without coordinates or covariance
        (names the point), bad tie observations.
    """
    from ..bundle.redundancy import check_level

    try:
        check_level(level, power)
    except ValueError as ex:
        raise LidarcatError(f"check_block: {ex}") from None
    ms = list(measurements)
    given = tuple(ms)
    edges = list(lines or ())
    live, replaced = _live_measurements(ms, edges, cameras, eos, eo_covs, vertices_m, vertex_covs, ties)
    if not live and not edges:
        return BlockCheck(tuple(ms), {}, {}, status="nothing", message="no accepted measurement")
    # step 1: the tie points in photo coordinates, cleaned on their own; the block's observations
    t_xy, t_sd, t_keep, start, note, n_tie_rej, dropped = prepared_ties(ties, cameras, eos, eo_covs, snoop_ties)
    blk = BlockModel.of([ms[k] for k in live], edges, ties, (t_xy, t_sd, t_keep), cameras, eos, eo_covs,
                        vertices_m, vertex_covs, floor_sd_px, max_iter)
    ties_on = blk.ties_on(set(blk.v_photo.tolist()) | {e.photo for e in edges})
    tie_counts = dict(ties_used=int(t_keep.sum()), ties_rejected=n_tie_rej, ties_dropped=dropped)
    # step 2: the block with every observation
    v_in, e_in = np.ones(len(live), dtype=bool), np.ones(len(edges), dtype=bool)
    prob, photos = blk.problem(v_in, e_in)
    res = blk.solve(prob, photos, dict(start))
    if not res.success:
        return BlockCheck(tuple(ms), {}, {}, rounds=1, status="not_converged",
                          message=f"the block adjustment did not converge ({res.message}); nothing rejected"
                                  + (f"; {note}" if note else ""), **tie_counts)
    st = _Rounds(v_in, e_in, prob, photos, res, note)
    # step 3: worst first, one rejection per round
    failed = _worst_first(st, blk, ms, live, replaced, ties_on, tie_counts["ties_used"], level, power)
    if failed:
        return BlockCheck(tuple(ms), {}, {}, rejected=tuple(st.rejected), rounds=st.rounds, status="not_converged",
                          message=failed, lines_rejected=tuple(st.e_rejected), line_reasons=dict(st.line_reasons),
                          **tie_counts)
    # step 4: the backward step over the rejected edges
    if st.e_rejected and st.prob is not None and not st.stopped:
        _backward(st, blk, ms, given, replaced, ties_on, tie_counts["ties_used"], level, power)
    # step 5: the final adjustment, its orientations and covariances; the along-one-edge points tested on it
    return _outcome(st, blk, ms, tie_counts, replaced, ties_on, level, power)


@dataclasses.dataclass(eq=False)
class _Rounds:
    """The state of :func:`check_block`'s rounds: the vertex measurements (*v_in*, over the adjusted ones) and
    edges (*e_in*) still in, the last problem (None: nothing left to adjust), its photos and adjustment, the
    rejections and reasons so far, the untestable ones of the last round; *stopped*: an adjustment without a
    rejected observation did not converge (testing stopped)."""

    v_in: np.ndarray
    e_in: np.ndarray
    prob: Any
    photos: np.ndarray
    res: Any
    note: str
    rounds: int = 1
    rejected: list = dataclasses.field(default_factory=list)
    e_rejected: list = dataclasses.field(default_factory=list)
    line_reasons: dict = dataclasses.field(default_factory=dict)
    untestable: list = dataclasses.field(default_factory=list)
    e_untestable: list = dataclasses.field(default_factory=list)
    stopped: bool = False


def _worst_first(st: _Rounds, blk: BlockModel, ms: list[Measurement], live: list[int], replaced: dict,
                 ties_on: dict, n_tie_obs: int, level: float, power: float) -> str:
    """Step 3 of :func:`check_block`: in each round the worst vertex or edge test above its critical value is
    rejected (two measurements on a photo without ties: both) and the block adjusted again without it, until
    every test passes; *ms* and *st* updated.  Returns the message when the block's tests fail (else empty)."""
    from ..bundle.line_tests import line_tests
    from ..bundle.redundancy import reliability

    edges, v_photo, v_point, e_photo = blk.edges, blk.v_photo, blk.v_point, blk.e_photo
    v_in, e_in, res, prob, photos = st.v_in, st.e_in, st.res, st.prob, st.photos
    while True:
        n_obs = len(prob.photo_index)
        vrows = np.arange(n_tie_obs, n_obs)              # the vertex observations follow the ties
        live_in = np.flatnonzero(v_in)                   # vertex observation i of the problem = live_in[i]
        edge_in = np.flatnonzero(e_in)                   # line observation i of the problem = edge_in[i]
        try:
            rel = reliability(res, level=level, power=power) if n_obs else None
            lt = line_tests(res, level=level, power=power) if len(edge_in) else None
        except DatumError as ex:
            return f"the block's tests failed ({ex})"
        ratio = np.where(rel.testable[vrows], np.nan_to_num(rel.ratio[vrows], nan=-np.inf), -np.inf) \
            if rel is not None and len(vrows) else np.full(0, -np.inf)
        # the line group test T = w^2 against chi2_{1-alpha_2}(2) = critical_w^2: the same scale as rel.ratio
        e_ratio = np.nan_to_num((lt.w / lt.critical_w) ** 2, nan=-np.inf) if lt is not None else np.full(0, -np.inf)
        worst_v = float(ratio.max(initial=-np.inf))
        worst_e = float(e_ratio.max(initial=-np.inf))
        if max(worst_v, worst_e) <= 1.0:
            if rel is not None and len(vrows):
                st.untestable = [(str(v_point[live_in[i]]), str(v_photo[live_in[i]]))
                                 for i in np.flatnonzero(~rel.testable[vrows])]
            if lt is not None:
                st.e_untestable = [(edges[edge_in[i]].line, edges[edge_in[i]].photo)
                                   for i in np.flatnonzero(~np.isfinite(lt.w))]
            break
        warm = {p: np.asarray(res.eo_params)[j] for j, p in enumerate(photos)}
        is_edge = worst_e > worst_v
        partner = None
        others = int(v_in.sum()) - (not is_edge)         # the vertex observations beside the rejected one
        if is_edge:
            i = int(np.argmax(e_ratio))
            w, crit = float(lt.w[i]), float(lt.critical_w)
            a = int(edge_in[i])
            pid, vid = edges[a].photo, edges[a].line
            e_in[a] = False
        else:
            i = int(np.argmax(ratio))
            g = int(vrows[i])
            w, crit = float(rel.w[g]), float(rel.w_critical[g])
            a = int(live_in[i])
            pid, vid = str(v_photo[a]), str(v_point[a])
            # two measurements on a photo without ties: which of the two is off cannot be told (both go)
            same = [int(b) for b in np.flatnonzero(v_in & (v_photo == pid)) if b != a]
            partner = same[0] if ties_on.get(pid, 0) == 0 and len(same) == 1 and not \
                (e_in & (e_photo == pid)).any() else None
            v_in[a] = False
            if partner is not None:
                v_in[partner] = False
        n_ties_photo = ties_on.get(pid, 0)
        more = v_in.any() or blk.t_keep.any() or e_in.any()
        prob, photos = blk.problem(v_in, e_in) if more else (None, photos)
        res_new = blk.solve(prob, photos, warm) if prob is not None else res
        st.rounds += prob is not None
        if not res_new.success:
            (e_in if is_edge else v_in)[a] = True
            if partner is not None:
                v_in[partner] = True
            prob, photos = blk.problem(v_in, e_in)
            st.note = "; ".join(x for x in (st.note, f"the adjustment without {vid} on {pid} did not converge: "
                                                     "testing stopped") if x)
            st.stopped = True
            break
        res = res_new
        ph = {p: j for j, p in enumerate(photos)}
        eo_p = np.asarray(res.eo_params)[ph[pid]] if pid in ph else np.asarray(blk.eos[pid], float).reshape(6)
        pts = {str(q): np.asarray(res.points_m)[j] for j, q in enumerate(res.point_ids)}

        def offset(b: int) -> float:
            """Measurement *b* minus its vertex projected with the block adjusted without it (px)."""
            x = pts.get(VERTEX + str(v_point[b]), np.asarray(blk.vertices_m[str(v_point[b])], float).reshape(3))
            return float(np.hypot(*(np.asarray(ms[live[b]].px) - pixel_positions(blk.cameras[pid], eo_p,
                                                                                  x[None])[0])))

        if is_edge:
            e = edges[a]
            off = _edge_offset_px(blk.cameras[pid], eo_p, e)
            st.e_rejected.append((vid, pid, w, off))
            st.line_reasons[(vid, pid)] = _edge_reason(n_ties_photo, others, int(e_in.sum()), off, w, crit)
            _indict(ms, replaced, e, off, w)
        else:
            off = offset(a)
            st.rejected.append((vid, pid, w, off))
            basis = (f"{n_ties_photo} tie points on its photo and {others} other vertex observations"
                     if n_ties_photo else f"no tie points on its photo; {others} other vertex observations")
            ms[live[a]] = ms[live[a]].failed(
                "rejected", f"{REASON_PREFIX} ({basis}): {off:.1f} px, w = {w:.1f} (critical {crit:.2f})")
            if partner is not None:
                off_b = offset(partner)
                st.rejected.append((str(v_point[partner]), pid, math.nan, off_b))
                ms[live[partner]] = ms[live[partner]].failed(
                    "rejected", f"{REASON_PREFIX}: {off_b:.1f} px; its photo has no tie points and its other "
                                f"measurement ({vid}, w = {w:.1f}) disagrees with it: which of the two is off cannot "
                                "be told")
        if prob is None:
            break
    st.res, st.prob, st.photos = res, prob, photos
    return ""


def _backward(st: _Rounds, blk: BlockModel, ms: list[Measurement], given: tuple, replaced: dict, ties_on: dict,
              n_tie_obs: int, level: float, power: float) -> None:
    """Step 4 of :func:`check_block` (module docstring, "The backward step over the edges"): a rejected edge put
    back, or exchanged for another of its line; the reasons of the edges rejected in the end and the points
    they stand for judged again on the final block; *st* and *ms* updated."""
    from ..bundle.redundancy import critical_values

    edges, res, photos = blk.edges, st.res, st.photos

    def rebuild(e_try: np.ndarray) -> Any:
        pr, ph = blk.problem(st.v_in, e_try)
        r = blk.solve(pr, ph, {p: np.asarray(res.eo_params)[j] for j, p in enumerate(photos)})
        return r if r.success else None

    key = {(e.line, e.photo): k for k, e in enumerate(edges)}
    e_in, res_b, changes, n_adj = edge_backward_step(edges, st.e_in, [key[r[:2]] for r in st.e_rejected], res,
                                                      rebuild, n_tie_obs, level, power)
    st.e_in = e_in
    st.rounds += n_adj
    if not changes:
        return
    st.res, st.prob = res_b, res_b.problem
    st.photos = np.asarray(st.prob.photo_ids, dtype=object)
    st.e_rejected, st.line_reasons = _edges_judged_again(
        edges, st.e_rejected, changes, st.res, blk.cameras, ties_on, int(st.v_in.sum()), int(e_in.sum()), ms,
        given, replaced, math.sqrt(critical_values(level, power, 2)[1]))
    rel, lt = block_tests(st.res, level, power)
    vrows = np.arange(n_tie_obs, len(st.prob.photo_index))
    live_in, edge_in = np.flatnonzero(st.v_in), np.flatnonzero(e_in)
    st.untestable = [] if rel is None or not len(vrows) else [
        (str(blk.v_point[live_in[i]]), str(blk.v_photo[live_in[i]])) for i in np.flatnonzero(~rel.testable[vrows])]
    st.e_untestable = [] if lt is None else [(edges[edge_in[i]].line, edges[edge_in[i]].photo)
                                             for i in np.flatnonzero(~np.isfinite(lt.w))]


def _outcome(st: _Rounds, blk: BlockModel, ms: list[Measurement], tie_counts: dict, replaced: dict,
             ties_on: dict, level: float, power: float) -> BlockCheck:
    """Step 5 of :func:`check_block`: the final adjustment's orientations and covariances (none when every
    observation was rejected), the along-one-edge points tested on it (:func:`_along_tests`), the counts."""
    from ..bundle import adjust

    tested = int(st.v_in.sum()) - len(st.untestable) + len(st.rejected)
    e_tested = int(st.e_in.sum()) - len(st.e_untestable) + len(st.e_rejected)
    kw = dict(status="ok", message=st.note, lines_tested=e_tested, lines_untestable=tuple(st.e_untestable),
              lines_rejected=tuple(st.e_rejected), line_reasons=st.line_reasons, **tie_counts)
    if st.prob is None:          # every measurement rejected
        return BlockCheck(tuple(ms), {}, {}, rounds=st.rounds, tested=tested, rejected=tuple(st.rejected), **kw)
    final = adjust(st.prob, initial=(np.asarray(st.res.eo_params), np.asarray(st.res.points_m)), check=False,
                   precision="photos", max_iter=blk.max_iter)
    use = final if final.success else st.res
    eo_out = {str(p): np.array(use.eo_params[j]) for j, p in enumerate(st.photos)}
    cov_out = {str(p): np.array(use.eo_cov[j]) for j, p in enumerate(st.photos)}
    tested += _along_tests(st, blk, ms, replaced, eo_out, cov_out, ties_on, level, power)
    return BlockCheck(tuple(ms), eo_out, cov_out, untestable=tuple(st.untestable), rounds=st.rounds + 1,
                      tested=tested, rejected=tuple(st.rejected), **kw)


def _along_tests(st: _Rounds, blk: BlockModel, ms: list[Measurement], replaced: dict, eo: dict, eo_cov: dict,
                 ties_on: dict, level: float, power: float) -> int:
    r"""The along-line position of each accepted along-one-edge point whose edges stand for it, tested on the
    final block (module docstring, "Along one edge"); *ms* and *st* (rejected, untestable) updated.  Returns the
    number tested."""
    from ..bundle.redundancy import MIN_REDUNDANCY, critical_values
    from .predict import pixel_jacobians

    crit = math.sqrt(critical_values(level, power, 1)[1])
    n = 0
    for (vid, pid), k in replaced.items():
        m = ms[k]
        if not (m and m.along_line):
            continue
        if pid not in eo or pid not in eo_cov:
            st.untestable.append((vid, pid))
            continue
        cam, x = blk.cameras[pid], np.asarray(blk.vertices_m[vid], float).reshape(3)
        jp, jx = pixel_jacobians(cam, eo[pid], x[None])
        lam, vec = np.linalg.eigh(np.asarray(m.cov_px2, float))
        u = vec[:, -1]                                   # the line's direction: the covariance's major axis
        var_m = float(lam[-1]) + blk.floor_sd_px ** 2
        var_p = float(u @ (jp[0] @ eo_cov[pid] @ jp[0].T
                           + jx[0] @ np.asarray(blk.vertex_covs[vid], float).reshape(3, 3) @ jx[0].T) @ u)
        d = float(u @ (np.asarray(m.px) - pixel_positions(cam, eo[pid], x[None])[0]))
        if not (math.isfinite(d) and math.isfinite(var_p) and var_m / (var_m + var_p) >= MIN_REDUNDANCY):
            st.untestable.append((vid, pid))
            continue
        n += 1
        w = abs(d) / math.sqrt(var_m + var_p)
        if w > crit:
            st.rejected.append((vid, pid, w, abs(d)))
            ms[k] = m.failed("rejected", f"{REASON_PREFIX} along its edge ({ties_on.get(pid, 0)} tie points on its "
                                         f"photo): {abs(d):.1f} px along the line from the vertex projected with "
                                         f"the block, w = {w:.1f} (critical {crit:.2f})")
    return n


def _edge_reason(n_ties: int, n_vertex: int, n_other: int, off: float, w: float, crit: float) -> str:
    """The reason of a rejected edge: its basis, its offset from its LiDAR line (px) and its w (if testable)."""
    return (f"{LINE_REASON_PREFIX} ({n_ties} tie points on its photo, {n_vertex} vertex observations and "
            f"{n_other} other edges): {off:.1f} px off its LiDAR line, " + (
                f"w = {w:.1f} (critical {crit:.2f})" if math.isfinite(w) else "untestable beside the other edge"))


def _indict(ms: list[Measurement], replaced: dict, e: EdgeObservation, off: float, w: float) -> None:
    """The point measurement that the rejected edge *e* stands for (if any, and accepted) rejected with it."""
    k_pt = replaced.get((e.point, e.photo))
    if k_pt is not None and ms[k_pt]:
        ms[k_pt] = ms[k_pt].failed("rejected", f"{REASON_PREFIX}: its roof edge {e.line} on this photo is "
                                               f"{off:.1f} px off its LiDAR line (w = {w:.1f})")


def _edges_judged_again(edges: list[EdgeObservation], e_rejected: list, changes: list, res: Any,
                        cameras: Mapping[str, Camera], ties_on: dict, n_vertex: int, n_edges: int,
                        ms: list[Measurement], given: tuple, replaced: dict, crit: float) -> tuple[list, dict]:
    """The rejected edges and their reasons after the backward step's *changes* (``(edge put back or exchanged,
    edge rejected instead or None, its w, ...)``): each one's offset from the final block *res* (adjusted without
    every rejected edge), the points their edges stand for judged again (*ms* from *given*)."""
    key = {(e.line, e.photo): k for k, e in enumerate(edges)}
    rej = {r[:2]: (r[2], None) for r in e_rejected}     # (line, photo) -> (w, photo of the edge it replaced)
    for a, h, w_h, _ in changes:
        rej.pop((edges[a].line, edges[a].photo))
        if h is not None:
            rej[(edges[h].line, edges[h].photo)] = (w_h, edges[a].photo)
    for k in replaced.values():
        ms[k] = given[k]
    ph = {str(p): j for j, p in enumerate(res.problem.photo_ids)}
    out, reasons = [], {}
    for (lid, pid), (w, instead) in rej.items():
        e = edges[key[(lid, pid)]]
        off = _edge_offset_px(cameras[pid], np.asarray(res.eo_params)[ph[pid]], e)
        reasons[(lid, pid)] = _edge_reason(ties_on.get(pid, 0), n_vertex, n_edges, off, w, crit) + (
            f"; rejected instead of its line's edge on photo {instead} (lower v'Pv)" if instead else "")
        out.append((lid, pid, w, off))
        _indict(ms, replaced, e, off, w)
    return out, reasons


def _edge_offset_px(cam: Camera, eo: np.ndarray, e: EdgeObservation) -> float:
    """Distance (px) of the middle of the measured edge from its 3-D line projected with *eo*."""
    ab = pixel_positions(cam, eo, np.array([e.a_m, e.b_m]))
    d = ab[1] - ab[0]
    mid = 0.5 * (np.asarray(e.p1_px) + np.asarray(e.p2_px)) - ab[0]
    return float(abs(d[0] * mid[1] - d[1] * mid[0]) / max(float(np.hypot(*d)), 1e-12))
