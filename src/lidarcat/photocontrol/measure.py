r"""Measuring a LiDAR roof vertex in a photo: a label template for the shift, roof-edge lines for the pixel.

**1. Coarse shift (template of faces).**  The LiDAR points within ``template_m`` of
the vertex are labelled by their nearest plane of the vertex (or "other surface")
and projected with the approximate orientation; every pixel of a window around the
prediction takes the label of the nearest projected point (none farther than two
point spacings).  The sun's shading is unknown, but inside one face the photo is
nearly uniform and between faces (and against the ground) it is not.  For every
integer shift :math:`s` inside ``search_sigma`` of the prediction's ellipse the
score is the log-likelihood ratio, per template pixel, of one normal grey-level
distribution per label against one for the whole template,

.. math:: \Lambda(s) = \frac{1}{N}\Big(\tfrac{N}{2}\ln\hat\sigma^2(s)
          - \sum_k \tfrac{N_k}{2}\ln\hat\sigma_k^2(s)\Big),

with :math:`\hat\sigma_k^2 = Q_k/N_k - (S_k/N_k)^2` from the sums :math:`S_k` and
:math:`Q_k` of the photo and its square over label *k*'s :math:`N_k` template
pixels (one ``cv2.matchTemplate`` correlation each, for all shifts at once;
1 grey level^2 added to every variance).  Uniform faces of different grey raise
it; texture lowers it; a uniform area under the whole template leaves it at 0.
The best shift is then refined within ``refine_px`` by the directional gradient
across the predicted edges (``coarse = "lines"``: the mean of
:math:`|\nabla I\cdot n_e|` along each edge's half-line from a candidate vertex,
over its mean in the window, summed over the edges).  :func:`measure_photo` sums
the normalised scores of all vertices of a photo over the common shift first
(the orientation's error moves them alike), then searches each vertex within
``local_search_px`` of it.

**2. Edges (sub-pixel).**  Each roof edge (:func:`~lidarcat.photocontrol.predict.roof_edges`)
is predicted as an image segment from the shifted vertex.  Across it, at
stations every 0.5 px from ``t0`` (clear of the other edges at the vertex) to
``t0`` short of its end (where a far vertex or an eave corner branches other edges off, which
pull the peaks and tilt the line), a profile of ``+-band_px`` is sampled (bilinear); the profiles'
derivatives are averaged over ``smooth_px`` along the edge, and the edge point is
the extremum of the derivative of the edge's dominant sign, refined by a
parabola through the three samples about it.  A line :math:`s = a + b\,t`
(offset across versus distance along) is fitted by least squares with
rejection at 3 robust sigmas (MAD); its covariance is
:math:`\hat\sigma^2 (A^TA)^{-1}\,k` with :math:`\hat\sigma` from the residuals
(at least ``min_sd_px``) and :math:`k = 2\max(1, 2\,\mathrm{smooth})` for the
correlation of stations 0.5 px apart.  The predicted direction is good to about the
orientation's attitude error, while texture correlated over several pixels tilts a free line by
a degree or two (seen on the renders: a ridge 2 deg off put the vertex 0.6 px off); so the slope
is also observed, :math:`b = 0` with sd :math:`\tan` ``direction_sd_deg`` (1 deg): the normal
matrix :math:`A^TA/\hat\sigma^2 k + \mathrm{diag}(0, \tan^{-2})`, its inverse the covariance.
An edge is dropped, with the reason, when
it has fewer than ``min_points`` inliers, a median gradient below
``min_contrast`` grey levels per pixel or below ``min_ratio`` times the texture's
(the gradient off the edge), or its points scatter more than ``max_scatter_px``.
The fit runs twice: from the coarse shift in a band of ``wide_band_px``, then
from the vertex found in ``band_px`` (the fit: private ``_edge_fit.fit_edge``).  The second fit
confirms the first: where the narrow band about the vertex found does not give a vertex again, the
wide band's lines were not the vertex's edges (a coarse shift some pixels off, the wide band
reaching a parallel line -- a ridge cap's far edge -- or a stretch of texture at the frame's edge, and
three such lines meeting within the chi2 check), and the pair is not measured, with the second
fit's status and reason (its edges are not written either).  Before session 9 the wide band's
point was kept: on the measured-control benchmark (seed 4, local extraction) a vertex at the frame's
corner was accepted 6.4 px off with an sd of 0.6 px, and on the AHN3 renders a hip-ridge vertex
4.2 px off (the ridge cap's far edge); both narrow-band fits found two edges only.

**3. Vertex.**  Line *i* in the image: :math:`m_i^T x = c_i` (unit normal
:math:`m_i`), with the variance :math:`w_i^{-1}` of its offset at the vertex.
:math:`w_i^{-1}` adds what the fit cannot see: the texture next to the edge moves the gradient
peaks of a whole stretch of the edge alike (the profiles are smoothed along it, the texture is
correlated over pixels), an offset of the line that its residual scatter does not show, the
larger the weaker the edge against the texture; so
:math:`\sigma_0^2 + (k/\rho_i)^2` with :math:`\rho_i` the edge's median gradient over the
texture's (the ratio the edge was accepted by), ``vertex_sd_px`` :math:`\sigma_0` = 0.1 px and
``vertex_texture_px`` :math:`k` = 1 px: chosen on the AHN3 renders of one set of seeds
(benchmarks/bench_photocontrol_ahn3.py; the accepted measurements' normalised errors' sd, their
points kept, 1.01 where a constant 0.25 px gave 0.75) and validated on another (1.00; 0.85).
Measured again with the new weights, the weak line weighs less in the point, whose errors shrink
(a 0.9 px one to 0.5 px): sd 0.88 and 0.73 (same blocks).  What is left of the over-estimate on
clean edges is the fit's own floor (``min_sd_px`` with the station correlation factor), which the
line observations share.  (The line observations, :class:`EdgeLine`, keep ``line_sd_px``.)
The vertex is the weighted
least-squares point :math:`x = (\sum w_i m_i m_i^T)^{-1} \sum w_i m_i c_i` with
covariance :math:`(\sum w_i m_i m_i^T)^{-1}` (two lines: their intersection).
Of two edges found on one image line (less than ``min_angle_deg`` apart) the one
turned farther from its predicted direction goes; with three or more lines, while
:math:`\chi^2 = \sum w_i (m_i^T x - c_i)^2` exceeds the 99.9 % point of
:math:`\chi^2_{n-2}`, one line goes: the one with the largest w, the weakest of three (step 3c).  Two lines
alone have no check: both must be ``two_line_ratio`` times stronger than the
texture.

**3b. A weak edge beside strong ones.**  A *weak* edge (gradient below ``two_line_ratio`` times the
texture's; two such lines alone are not accepted) beside two or more *strong* ones meeting at
``min_angle_deg`` or more is tested before it enters the point.  The strong lines alone give the
point :math:`x_S` with covariance :math:`N_S^{-1}`; the weak line *i*, independent of them, is off it
by :math:`r_i = m_i^T x_S - c_i` with variance :math:`m_i^T N_S^{-1} m_i + w_i^{-1}` (its offset
variance above, at :math:`x_S`), and

.. math:: \omega_i = r_i \big/ \sqrt{m_i^T N_S^{-1} m_i + w_i^{-1}}

(the w-test statistic; :math:`w_i` is still the line's weight) is standard normal when the edge is
right.  It is dropped when :math:`|\omega_i| >` ``weak_edge_w``
(1.96, the 95 % point), with the reason ("edge of planes 1-3: weak (gradient 2.8 x the texture's)
and off the point of the strong edges 1-2, 2-3 (w -2.2, \|w\| > 1.96)"; private
:mod:`~lidarcat.photocontrol._weak_edge`).  Why not the 99.9 % level of the chi2 check: three lines
leave one degree of freedom, and then every line's offset from the other two's point has the *same*
:math:`\omega^2 = \chi^2` -- the check cannot tell which line is off, and at 3.29 sd it passes offsets
that the least-squares point absorbs (bench_measured_control seed 1, C0006 on photo 101: a weak
edge 2.5 px across, :math:`\chi^2` 4.82, i.e. w 2.2; the point 1.89 px off at 3.7 sd of its
covariance).  The two lines' prior reliability differs, though: the strong pair is a measurement
by itself (two strong lines are accepted unchecked), the weak edge only refines it.  Dropping a
right weak edge costs its share of the precision (in 5 % of the cases), keeping a wrong one biases
the point by most of its offset with nothing downstream to see it; so the weak edge must agree at
the 95 % level.  Then the chi2 check runs on the lines left.

**3c. Which line goes when the lines do not meet.**  Line *i*'s offset from the point
:math:`x_{-i}` of the others, :math:`r_i = m_i^T x_{-i} - c_i`, has the variance
:math:`m_i^T N_{-i}^{-1} m_i + w_i^{-1}` (exact: line *i* is independent of the others), so
:math:`\omega_i = r_i / \sqrt{m_i^T N_{-i}^{-1} m_i + w_i^{-1}}` is the w-test of "line *i* alone is off"
(as in 3b).  With two or more redundancies (four lines or more) the line of the largest
:math:`|\omega_i|` is the likeliest single gross error, and it goes.  With one redundancy (three lines)
the lines' misclosure is one number, :math:`t = k^T c` (:math:`k` the left null vector of the normals,
:math:`k^T M = 0`); at :math:`x_{-i}` the other two lines' residuals vanish, so
:math:`k_i r_i = -t`: every :math:`|\omega_i|` equals :math:`\sqrt{\chi^2}` (but for the offset
variances' slight dependence on the point) and the raw offsets are
:math:`r_i = -t/k_i`.  The data cannot tell which line is off.  The largest raw offset (the rule
before) picks the smallest :math:`|k_i|`, a property of the three edge directions only: the same line
whichever one is off. On the symmetric 120 deg vertex all :math:`|k_i|` are equal and the noise picks.
So the choice must come from outside the misclosure, i.e. from the posterior odds of "line *i* is the
one", :math:`\pi_i\,p(t \mid i)`, where with one redundancy the likelihood carries only the geometry.
What differs between the lines is their prior reliability, the edge's strength :math:`\rho_i` (its
gradient over the texture's). A wrong lock (a texture streak, a parallel gutter or shadow line, a
stretch of texture displacing the gradient peaks) is the likelier the weaker the edge is against its
surroundings; this is the prior that 3b tests at 95 % and that step 3's :math:`(k/\rho_i)^2` models for
the random part.  So the weakest of three goes (reason: "... does not meet the other edges at one point
(1.7 px off, w -4.5; the weakest of three, gradient 4.5 x the texture's)").  The LiDAR prediction does
not tell the three candidate points apart: after the photo's common shift its sd is about
``local_search_px`` (8 px), while the three two-line points lie 1-3 px apart, a difference in squared
Mahalanobis distance below 0.1.  When the three edges are about equally strong, the choice is as
blind as before (docs/photocontrol.md, "Which line goes").

**3a. Along one edge.**  When the edges found lie on one image line (the crossing edges too weak
against the texture or scattered: faces of nearly the same grey across them) the rule above keeps
one line, and lines alone cannot place a point along a straight line.  But two edges on *either
side* of the vertex (opposite half-lines) that both lie on "one" image line are two different roof
edges: their 3-D lines meet at the vertex at an angle, so their images bend there by some degrees
(bench_measured_control seed 6, C0003 on photo 203: the edges at -55 and 137 deg, 12 deg as lines).
Their intersection is the vertex, by the same weighted least squares with the same offset variances
:math:`w_i^{-1}` (step 3, calibrated on the AHN3 renders: no new constant).  For two lines at angle
:math:`\beta` with offset variances :math:`v_1, v_2` the covariance in (across, along) the kept line
:math:`(m_1, d)` is exactly

.. math:: \operatorname{var}_\perp = v_1, \qquad
          \operatorname{var}_\parallel = \frac{v_2 + v_1\cos^2\beta}{\sin^2\beta}, \qquad
          \operatorname{cov}_{\perp\parallel} = -\frac{v_1\cos\beta}{\sin\beta}
          \;(\text{sign by orientation}),

tight across the line, :math:`\approx\sqrt{v_1+v_2}/\beta` along it: 0.2 px offsets at 12 deg give
~1.5 px along, at 4 deg ~5 px.  The vertex is taken (``measured``, :attr:`Measurement.along_line`,
reason "located along one edge: the edges of planes 3-4 and 1-2 lie nearly on one image line, their
intersection at 12 deg: sd 0.26 px across the edge, 1.79 px along it") when the bend is at least
``along_min_angle_deg`` (2 deg), both edges are ``two_line_ratio`` times the texture (two lines, no
check), the sd along is at most ``along_max_sd_px`` (5 px) and the point lies between the two
fitted stretches (within 2 sd); else ``weak_geometry`` with the reason ("... meet at 0.4 deg (< 2):
not located along the line").  :func:`check_photo` and :func:`check_consistency` test the point with
its elongated covariance; the block test (:mod:`~lidarcat.photocontrol.blockcheck`) tests its two
edges (across the line; an edge rejected rejects the point, the same fits) and the point's position along
the line on the final block with the point's own covariance ("Along one edge" there).  The survey's
image_points.csv holds no correlation, so such a point is written with its *along* sd in both columns (:attr:`Measurement.sd_px`, which
bounds the covariance) and its two edges go beside it as line observations (they carry the across
part; the point repeats at most :math:`(\sigma_\perp/\sigma_\parallel)^2` of it).  A point of
crossing edges from the first pass is never traded for an along-one-edge point of the second.
On the six bench seeds' 13 weak_geometry pairs (synthetic town, truth known) the bends are 0.6-14
deg; the 9 located are 0.2-5.6 px from truth, normalised along the line rms 0.71 (-1.14 to +1.15),
across 0.31; on eight more seeds (7-14) 6 of 12 located, rms 0.50 along, 0.22 across
(docs/figures.md, "Along one edge"): conservative, as step 3's sd is on that town (0.83) while it is
calibrated to 1.0 on the AHN3 renders -- which have no pair of this kind (no ``weak_geometry`` over
the 24 blocks) -- so no factor is applied.

**4. Consistency over photos** (:func:`check_consistency`).  A measurement
whose offset from the prediction is outside the 99.9 % ellipse of
(prediction + measurement) covariance is rejected.  The remaining ones are
intersected forward (each ray weighted by the measurement's covariance plus the
orientation's share of the prediction covariance); the photo with the largest
normalised residual beyond the 99.9 % point of :math:`\chi^2_2` is rejected and
the intersection repeated; a forward intersection farther from the LiDAR vertex
than the 99.9 % point of :math:`\chi^2_3` rejects all of that vertex's
measurements.  Every decision is returned with its reason.

**5. Consistency within a photo** (:func:`check_photo`).  The approximate orientation's error
:math:`\delta` (6 parameters, covariance :math:`P`, 2 m / 0.5 deg typically: ~20 px at GSD
0.15 m) moves all of a photo's predictions nearly alike: a common shift, with rotation and scale
across the frame.  Linearised, the offset of vertex *i* (measured minus predicted) is
:math:`d_i = J_i\delta + e_i` with :math:`J_i` the pixel Jacobian w.r.t. the orientation and
:math:`e_i` independent, of covariance :math:`C_i` = the measurement's + the LiDAR vertex's
(:math:`K_i V_i K_i^T`, :math:`K_i` the Jacobian w.r.t. the point) + ``model_sd_px``\ :sup:`2`
:math:`I` (what the linear model does not see).  Leaving vertex *i* out, the others estimate
:math:`\hat\delta_{-i} = N_{-i}^{-1}\sum_{j\ne i} J_j^T C_j^{-1} d_j` with
:math:`N_{-i} = P^{-1} + \sum_{j\ne i} J_j^T C_j^{-1} J_j`, and :math:`d_i` is tested against
:math:`J_i\hat\delta_{-i}` with covariance :math:`J_i N_{-i}^{-1} J_i^T + C_i`: two other
vertices spread over the frame fix shift, rotation and scale to a fraction of a pixel, so the
test is a few pixels wide, not the prediction's ~20 px (a close pair leaves the rotation near its
prior: ~5 px at 500 px from it).  With three or more measurements the one with the largest
normalised residual beyond the 99.9 % point of :math:`\chi^2_2` is rejected and the test
repeated (a fit locked onto another corner of the same roof is one gross value among the
photo's); two that disagree are both rejected (which one is off cannot be told); a measurement
alone on its photo cannot be tested and is kept (``alone="reject"`` rejects it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Sequence

import numpy as np

from .._util.frozen import frozen_array
from ..errors import LidarcatError
from ..geometry.camera import Camera
from ._along import intersect_lines, locate_along
from ._edge_fit import fit_edge
from ._weak_edge import weak_edge_tests, worst_line
from .predict import Prediction, face_labels, pixel_jacobians, pixel_positions, roof_edges

__all__ = ["Measurement", "MeasureParams", "VertexTarget", "STATUSES", "EdgeLine", "measure_photo", "measure_vertex",
           "check_consistency", "check_photo", "grey"]

#: statuses of a measurement and their meaning
STATUSES: dict[str, str] = {
    "measured": "measured and accepted",
    "rejected": "measured, then rejected (off the prediction or disagreeing with the other photos)",
    "not_visible": "the prediction is off the photo, behind the camera or occluded",
    "no_vertex": "the LiDAR vertex could not be extracted again (or not where its coordinates say)",
    "no_edges": "fewer than two roof edges of the vertex found in the LiDAR or in the photo",
    "weak_geometry": "the edges found meet at too small an angle (on one image line: not bent enough at the vertex to "
                     "locate it along the line; a point located along one edge is measured, its reason says so)",
    "too_dark": "the window is too dark to measure",
    "saturated": "the window is saturated",
    "near_border": "the vertex found lies at the photo's border, or its edges are cut by it too short to fit",
    "user_rejected": "rejected by the user in a review (the survey's control_decisions.csv): not measured again",
}

_CHI2_2 = 13.815510557964274   # chi2(2) 99.9 %
_CHI2_3 = 16.26623619623813    # chi2(3) 99.9 %
_CHI2_1 = 10.827566170662733   # chi2(1) 99.9 %


@dataclass(frozen=True, eq=False)
class EdgeLine:
    r"""A roof edge fitted in one photo, as the two-point line observation of
    :class:`lidarcat.bundle.lines.LineObservation` (pixels).

    The free fit :math:`s = a + b\,t` (offset across the predicted direction against the distance
    along it; *not* the direction-observed fit the vertex uses, which leans on the approximate
    orientation) has the offset variance :math:`v(t) = C_{aa} + 2 C_{ab} t + C_{bb} t^2 +
    \sigma_\ell^2 + \sigma_\theta^2 t^2` (``line_sd_px`` and ``line_direction_sd_deg`` the floors
    of what the fit cannot see; :math:`C'` the covariance with them added).  Its minimum
    :math:`v_0` lies at :math:`t^* = -C_{ab}/C_{bb}'`;
    two independent points at :math:`t^* \pm h` with sd :math:`s_p` across give
    :math:`s_p^2 (1/2 + (t - t^*)^2 / 2h^2)`: the same for every *t* when :math:`s_p^2 = 2 v_0`,
    :math:`h^2 = v_0 / C_{bb}'` (:func:`lidarcat.bundle.lines.observation_from_edge_points` is the
    case of independent points).

    Attributes
    ----------
    planes : (2,) int
        The two planes of the vertex that meet in the edge.
    p1_px, p2_px : (2,) float
        Column, row of the two equivalent points (px).
    sd_px : float
        Sd of each across the edge (px).
    ratio : float
        Edge gradient over the texture's.
    """

    planes: tuple
    p1_px: np.ndarray
    p2_px: np.ndarray
    sd_px: float
    ratio: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "planes", tuple(int(v) for v in self.planes))
        object.__setattr__(self, "p1_px", frozen_array(self.p1_px, shape=(2,)))
        object.__setattr__(self, "p2_px", frozen_array(self.p2_px, shape=(2,)))


def _edge_line(planes: Sequence[int], origin: np.ndarray, u: np.ndarray, free: tuple, ratio: float,
               line_sd_px: float, direction_sd_deg: float) -> EdgeLine | None:
    """The two-point equivalent (:class:`EdgeLine`) of a free edge fit ``(coef, cov)`` (px)."""
    coef, cov = free
    c = np.asarray(cov, dtype=np.float64) + np.diag([line_sd_px**2, math.tan(math.radians(direction_sd_deg)) ** 2])
    if not (np.isfinite(c).all() and c[1, 1] > 0):
        return None
    ts = -c[0, 1] / c[1, 1]
    v0 = c[0, 0] - c[0, 1] ** 2 / c[1, 1]
    if v0 <= 0:
        return None
    h = math.sqrt(v0 / c[1, 1])
    a, b = float(coef[0]), float(coef[1])
    nvec = np.array([-u[1], u[0]])

    def at(t: float) -> np.ndarray:
        return origin + t * u + (a + b * t) * nvec

    # the points lie on the fitted line; their spacing along it is 2 h sqrt(1 + b^2) (h measured along u)
    return EdgeLine(tuple(planes), at(ts - h), at(ts + h), math.sqrt(2.0 * v0), ratio)


@dataclass(frozen=True, eq=False)
class Measurement:
    """A vertex measured (or not) on one photo.

    Attributes
    ----------
    point, photo : str
    px : (2,) float
        Column, row (px); NaN unless measured.
    cov_px2 : (2, 2) float
    status : str
        One of :data:`STATUSES`; ``bool(m)`` is ``status == "measured"``.
    reason : str
    lines : tuple of ((2,), (2,))
        The fitted edge segments (px), for the review chips.
    shift_px : (2,) float
        The coarse shift from the prediction (px).
    predicted_px : (2,) float
    predicted_cov_px2 : (2, 2) float
    edge_lines : tuple of EdgeLine
        The roof edges fitted in the photo as line observations (:class:`EdgeLine`): of a measured
        vertex the edges its point was intersected from; of a vertex not measured (``no_edges``,
        ``weak_geometry``) its edges found strong (``two_line_ratio`` times the texture).
    along_line : bool
        Measured *along one edge* (module docstring, step 3a): the edges found lie nearly on one image
        line and the point is their intersection, tight across the line, loose along it.  Its edges are
        line observations beside the point (:attr:`sd_px` then carries the along-line sd only).
    """

    point: str
    photo: str
    px: np.ndarray
    cov_px2: np.ndarray
    status: str
    reason: str = ""
    lines: tuple = ()
    shift_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    predicted_px: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    predicted_cov_px2: np.ndarray = field(default_factory=lambda: np.full((2, 2), np.nan))
    edge_lines: tuple = ()
    along_line: bool = False

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"unknown status {self.status!r}")
        for name, shape in (("px", (2,)), ("cov_px2", (2, 2)), ("shift_px", (2,)), ("predicted_px", (2,)),
                            ("predicted_cov_px2", (2, 2))):
            object.__setattr__(self, name, frozen_array(getattr(self, name), shape=shape))

    def __bool__(self) -> bool:
        return self.status == "measured"

    @property
    def sd_px(self) -> np.ndarray:
        r"""(2,) sds of column and row (px), as written to image_points.csv (no correlation there).

        Of a point measured along one edge (:attr:`along_line`) both are its sd along the line (the
        covariance's larger axis): the edges go beside it as line observations and carry what is known
        across the line, the point what is known along it; the written point adds at most
        (sd across / sd along)\ :sup:`2` of the line's weight across it again."""
        if self.along_line:
            big = float(np.max(np.linalg.eigvalsh(np.asarray(self.cov_px2)))) if np.isfinite(self.cov_px2).all() \
                else math.nan
            return np.full(2, math.sqrt(max(big, 0.0)) if math.isfinite(big) else math.nan)
        return np.sqrt(np.maximum(np.diag(self.cov_px2), 0.0))

    def failed(self, status: str, reason: str) -> "Measurement":
        return replace(self, status=status, reason=reason)


def grey(image: Any) -> np.ndarray:
    """The image as float32 grey values (RGB averaged; 16-bit scaled to 0..255)."""
    a = np.asarray(image)
    if a.ndim == 3:
        a = a[..., :3].astype(np.float32).mean(axis=2)
    a = a.astype(np.float32)
    if np.asarray(image).dtype == np.uint16:
        a = a / 257.0
    return a


def _llr(chip: np.ndarray, masks: list[np.ndarray], valid: np.ndarray | None = None) -> np.ndarray:
    """Per pixel of the template: the log-likelihood ratio of one grey level (mean, variance) per face vs one
    for the whole template, for every shift.  *valid* (0 off the photo): each face's pixels counted per
    shift, only those on the photo (the replicated border would fake a uniform face)."""
    import cv2

    eps = 1.0
    n_tot, s_tot, q_tot, ll = 0.0, 0.0, 0.0, 0.0
    part = valid is not None and not bool(np.all(valid > 0))
    if part:
        chip = chip * valid
    sq = chip * chip
    for m in masks:
        nk: Any = float(m.sum())
        if part:   # a face needs 6 pixels on the photo at a shift to count there
            nk = np.rint(cv2.matchTemplate(valid, m, cv2.TM_CCORR).astype(np.float64))
            nk = np.where(nk >= 6, nk, 0.0)
        sk = cv2.matchTemplate(chip, m, cv2.TM_CCORR).astype(np.float64)
        qk = cv2.matchTemplate(sq, m, cv2.TM_CCORR).astype(np.float64)
        n1 = np.maximum(nk, 1.0)
        var = np.maximum(qk / n1 - (sk / n1) ** 2, 0.0) + eps
        ll = ll - 0.5 * nk * np.log(var)
        n_tot, s_tot, q_tot = n_tot + nk, s_tot + sk * (nk > 0), q_tot + qk * (nk > 0)
    if part:
        n_tot = np.maximum(n_tot, 1.0)
    var_all = np.maximum(q_tot / n_tot - (s_tot / n_tot) ** 2, 0.0) + eps
    return (ll + 0.5 * n_tot * np.log(var_all)) / n_tot


def _line_score(chip: np.ndarray, units: np.ndarray, lens: np.ndarray, t0s: Sequence[float]) -> np.ndarray:
    """Score of every chip pixel as the vertex: the directional gradient across each predicted edge,
    averaged along the edge's half-line from the pixel and divided by its mean over the chip, summed."""
    import cv2

    sm = cv2.GaussianBlur(chip, (0, 0), 1.0)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3)
    total = np.zeros_like(chip, dtype=np.float64)
    for u, length, t0 in zip(units, lens, t0s):
        r = np.abs(gx * float(-u[1]) + gy * float(u[0]))
        L = int(math.ceil(length))
        if L <= t0 + 2:
            continue
        ker = np.zeros((2 * L + 1, 2 * L + 1), np.uint8)
        p1 = (int(round((L + u[0] * length) * 16)), int(round((L + u[1] * length) * 16)))
        cv2.line(ker, (L * 16, L * 16), p1, 255, 1, cv2.LINE_AA, 4)
        yy, xx = np.mgrid[-L:L + 1, -L:L + 1]
        kf = ker.astype(np.float32) * (np.hypot(xx, yy) >= t0)
        if kf.sum() <= 0:
            continue
        kf /= kf.sum()
        total += cv2.filter2D(r, cv2.CV_32F, kf, anchor=(L, L), borderType=cv2.BORDER_REPLICATE) \
            / max(float(r.mean()), 1e-6)
    return total


@dataclass(frozen=True)
class MeasureParams:
    """Settings of the image measurement (see the module docstring)."""

    #: the shift is searched within this many sigmas of the prediction's ellipse, at most max_search_px
    search_sigma: float = 3.5
    max_search_px: int = 150
    #: after the photo's common shift: each vertex searched this far around it (px)
    local_search_px: int = 8
    #: edge profiles +- this (px); stations and inliers needed; contrast limits
    band_px: float = 1.5
    #: the first pass, from the coarse shift, profiles +- this (px)
    wide_band_px: float = 3.5
    min_points: int = 8
    min_contrast: float = 2.0
    min_ratio: float = 2.5
    max_scatter_px: float = 1.2
    #: the edge profiles' gradients are averaged over this length along the edge (px)
    smooth_px: float = 1.5
    #: floor of the edge points' sd (px)
    min_sd_px: float = 0.15
    #: a vertex from two edges only (no redundancy) needs both this much stronger than the texture
    two_line_ratio: float = 3.5
    #: sd of a line's position from what the fit cannot see (texture next to the edge, blur), added (px);
    #: 0.25 makes the normalised errors' sd 1.0 over the benchmark's blocks (0.5 was needed while the
    #: renders painted roof shading into the plan albedo lattice, a texel off the roof edge); the line
    #: observations (EdgeLine) use it, the vertex vertex_sd_px and vertex_texture_px below
    line_sd_px: float = 0.25
    #: sd of the predicted edge direction in the photo (deg), an observation of each line's slope (0: free)
    direction_sd_deg: float = 1.0
    #: the vertex: sd added to each line's offset, sqrt(vertex_sd_px^2 + (vertex_texture_px / ratio)^2) with
    #: ratio the edge's gradient over the texture's (module docstring, step 3; calibrated on the AHN3 renders)
    vertex_sd_px: float = 0.10
    vertex_texture_px: float = 1.0
    #: a roof edge as a line observation (EdgeLine): sd of its direction from what the fit cannot see (deg),
    #: added to the free fit's (texture correlated along the edge tilts a fitted line)
    line_direction_sd_deg: float = 0.5
    #: at the frame's border: "edges" -- a vertex whose edges (max_edge_px) reach past the border, predicted or
    #: found, is near_border; "fit" -- the search clipped to the photo, each face scored on its pixels on the
    #: photo, the edges fitted on their part inside, near_border only within 8 px (docs/photocontrol.md)
    border: str = "edges"
    #: edges found on one image line only: the vertex located along it where two of them, on either side of
    #: it, meet at along_min_angle_deg or more (deg), if its sd along the line is at most along_max_sd_px
    #: (px; 0: never, weak_geometry) -- module docstring, step 3a
    along_min_angle_deg: float = 2.0
    along_max_sd_px: float = 5.0
    #: a weak edge (gradient < two_line_ratio x the texture's) beside two or more strong ones is dropped when its
    #: offset from the strong edges' point exceeds this many sds (the 95 % point of the normal; step 3b)
    weak_edge_w: float = 1.96
    #: the lines used must meet at least at this angle (deg)
    min_angle_deg: float = 20.0
    #: edges used up to this far from the vertex (px)
    max_edge_px: float = 60.0
    #: faces' points within this plan distance make the template (m)
    template_m: float = 8.0
    #: coarse score: "likelihood" (faces' grey levels) or "lines" (directional gradient along the predicted edges)
    coarse: str = "likelihood"
    #: then the "lines" score within this many px of the coarse shift (0: not)
    refine_px: float = 4.0
    #: window median below *dark*: too dark; more than half of it at or above *saturation*: saturated
    dark: float = 12.0
    saturation: float = 250.0

    def __post_init__(self) -> None:
        """Every field checked (one line naming the field, its allowed range and the value given): a bad value
        would not fail, it would silently change what is measured (a negative ``weak_edge_w`` drops every weak
        edge, a zero ``local_search_px`` divides by zero, ``dark`` >= ``saturation`` refuses every photo)."""
        for name, allowed, ok in _PARAM_RULES:
            value = getattr(self, name)
            if not ok(self, value):
                raise ValueError(f"{name} must be {allowed.format(p=self)}, got {value!r}")


def _real(v: Any, *, inf: bool = False) -> bool:
    """A real number (not a bool), finite unless *inf*."""
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            and (math.isfinite(v) or (inf and v == math.inf)))


def _int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _in(lo: float, hi: float, *, lo_open: bool = False, hi_open: bool = False, inf: bool = False):
    """A test of a real number in the interval from *lo* to *hi* (open ends as given)."""
    return lambda _p, v: (_real(v, inf=inf) and (v > lo if lo_open else v >= lo)
                          and (v < hi if hi_open else v <= hi))


_POS = (_in(0.0, math.inf, lo_open=True), "a finite number > 0")
_NONNEG = (_in(0.0, math.inf), "a finite number >= 0")
_ANGLE = (_in(0.0, 90.0, lo_open=True, hi_open=True), "an angle in (0, 90) deg")
_SD_DEG = (_in(0.0, 90.0, hi_open=True), "an angle in [0, 90) deg")
#: (field, allowed range as written in the message, test of (params, value)); the cross-field rules test a
#: field against one checked before it
_PARAM_RULES: tuple = tuple((name, allowed, ok) for name, (ok, allowed) in (
    ("search_sigma", _POS),
    ("max_search_px", (lambda _p, v: _int(v) and v >= 1, "an integer >= 1")),
    ("local_search_px", (lambda _p, v: _int(v) and v >= 1, "an integer >= 1")),
    ("band_px", _POS),
    ("wide_band_px", (lambda p, v: _real(v) and v >= p.band_px, "a finite number >= band_px ({p.band_px:g})")),
    ("min_points", (lambda _p, v: _int(v) and v >= 3, "an integer >= 3 (a line with one redundancy)")),
    ("min_contrast", _NONNEG),
    ("min_ratio", _NONNEG),
    ("max_scatter_px", _POS),
    ("smooth_px", _NONNEG),
    ("min_sd_px", _POS),
    ("two_line_ratio", _NONNEG),
    ("line_sd_px", _NONNEG),
    ("direction_sd_deg", _SD_DEG),
    ("vertex_sd_px", _NONNEG),
    ("vertex_texture_px", _NONNEG),
    ("line_direction_sd_deg", _SD_DEG),
    ("border", (lambda _p, v: v in ("edges", "fit"), "'edges' or 'fit'")),
    ("along_min_angle_deg", _ANGLE),
    ("along_max_sd_px", _NONNEG),
    ("weak_edge_w", (_in(0.0, math.inf, lo_open=True, inf=True), "a number > 0 (inf: never dropped)")),
    ("min_angle_deg", _ANGLE),
    ("max_edge_px", _POS),
    ("template_m", _POS),
    ("coarse", (lambda _p, v: v in ("lines", "likelihood"), "'lines' or 'likelihood'")),
    ("refine_px", _NONNEG),
    ("dark", _NONNEG),
    ("saturation", (lambda p, v: _real(v) and v > p.dark, "a finite number > dark ({p.dark:g})")),
))


@dataclass(frozen=True, eq=False)
class VertexTarget:
    """One LiDAR vertex to measure on one photo: the vertex, its planes, the LiDAR around it, its prediction."""

    vertex_m: np.ndarray
    planes: tuple
    xyz_m: np.ndarray
    prediction: Prediction


def _setup(img: np.ndarray, camera: Camera, eo: Any, t: VertexTarget, p: MeasureParams):
    """Edges, template and search chip of one target; a failed Measurement instead when it cannot be measured."""
    pr = t.prediction
    base = Measurement(pr.point, pr.photo, np.full(2, np.nan), np.full((2, 2), np.nan), "not_visible",
                       predicted_px=pr.px, predicted_cov_px2=pr.cov_px2)
    if not pr:
        return base.failed("not_visible", f"{pr.status}: {pr.reason}")
    v = np.asarray(t.vertex_m, dtype=np.float64).reshape(3)
    xyz = np.asarray(t.xyz_m, dtype=np.float64).reshape(-1, 3)
    planes = list(t.planes)
    edges = roof_edges(v, planes, xyz)
    if len(edges) < 2:
        return base.failed("no_edges", f"{len(edges)} roof edge(s) supported by the LiDAR at the vertex")
    vpx = np.asarray(pr.px, dtype=np.float64)
    seg = pixel_positions(camera, eo, np.array([e.end_m for e in edges])) - vpx
    lens = np.linalg.norm(seg, axis=1)
    units = seg / np.maximum(lens, 1e-9)[:, None]
    t0s = []
    for k in range(len(edges)):
        u = units[k]
        others = [units[j] for j in range(len(edges)) if j != k]
        sin_min = min((abs(u[0] * o[1] - u[1] * o[0]) if u @ o > 0 else 1.0) for o in others)
        t0s.append(max(4.0, (p.band_px + 1.5) / max(sin_min, 0.2)))
    near = np.hypot(xyz[:, 0] - v[0], xyz[:, 1] - v[1]) <= p.template_m
    pts = xyz[near]
    tol = max(0.15, 3.0 * max(float(getattr(pl, "rms_m", 0.05) or 0.05) for pl in planes))
    lab = face_labels(planes, pts, tol)
    qpx = pixel_positions(camera, eo, pts)
    ok = np.isfinite(qpx).all(axis=1)
    qpx, lab = qpx[ok], lab[ok]
    if int(np.sum(lab >= 0)) < 10:
        return base.failed("no_edges", f"{int(np.sum(lab >= 0))} LiDAR points of the faces project onto the photo")
    from scipy.spatial import cKDTree

    tree = cKDTree(qpx)
    spacing = float(np.median(tree.query(qpx, k=2)[0][:, 1]))
    half = max(int(np.ceil(np.max(np.abs(qpx[lab >= 0] - vpx)))) + 1, int(math.ceil(min(lens.max(), p.max_edge_px))) + 1)
    c0, r0 = (int(round(x)) for x in vpx)
    gc, gr = np.meshgrid(np.arange(c0 - half, c0 + half + 1), np.arange(r0 - half, r0 + half + 1))
    dist, idx = tree.query(np.column_stack([gc.ravel(), gr.ravel()]))
    # every pixel takes its nearest point's label: faces, -1 other surfaces, -2 no point near
    tl = np.where(dist <= 2.0 * max(spacing, 1.0), lab[idx], -2).reshape(gc.shape)
    masks = [(tl == k).astype(np.float32) for k in range(len(planes)) if (tl == k).sum() >= 6]
    if (tl == -1).sum() >= 6:
        masks.append((tl == -1).astype(np.float32))
    srch = int(min(p.max_search_px, math.ceil(p.search_sigma * pr.sd_max_px) + 2))
    H, W = img.shape
    m_edge = int(math.ceil(min(float(lens.max()), p.max_edge_px) + p.wide_band_px)) + 2
    if p.border not in ("edges", "fit"):
        raise ValueError(f"border must be 'edges' or 'fit', got {p.border!r}")
    if p.border == "edges" and (c0 - m_edge < 0 or r0 - m_edge < 0 or c0 + m_edge >= W or r0 + m_edge >= H):
        return base.failed("near_border", f"the vertex's edges, {m_edge} px, around "
                                          f"column {c0}, row {r0} reach past the photo's border")
    b = _border_px(p)
    if c0 + srch < b or r0 + srch < b or c0 - srch >= W - b or r0 - srch >= H - b:
        return base.failed("near_border", f"the search window, {srch} px around column {c0}, row {r0}, does "
                                          f"not reach {b} px inside the photo")
    # frame edge: the search (and the prediction itself) may reach past the border; only shifts that put
    # the vertex on the photo, border_px inside, are searched (_scores), and the edges are fitted on
    # their part inside the photo (_refine).  The template may reach past the border: the photo is
    # continued by its edge values there (index clipping = replicated border, any offset)
    pad = half + srch
    rows = np.clip(np.arange(r0 - pad, r0 + pad + 1), 0, H - 1)
    cols = np.clip(np.arange(c0 - pad, c0 + pad + 1), 0, W - 1)
    chip = np.ascontiguousarray(img[np.ix_(rows, cols)], dtype=np.float32)
    valid = ((np.arange(r0 - pad, r0 + pad + 1) == rows)[:, None]
             & (np.arange(c0 - pad, c0 + pad + 1) == cols)[None, :]).astype(np.float32)
    if p.border == "edges":
        valid = np.ones_like(valid)
    if float(np.median(chip)) < p.dark:
        return base.failed("too_dark", f"median grey value {float(np.median(chip)):.0f} below {p.dark:g}")
    if float(np.mean(chip >= p.saturation)) > 0.5:
        return base.failed("saturated", f"{100 * float(np.mean(chip >= p.saturation)):.0f} % of the window "
                                        f"at or above {p.saturation:g}")
    return dict(base=base, edges=edges, units=units, lens=lens, t0s=t0s, half=half, srch=srch, chip=chip,
                masks=masks, c0=c0, r0=r0, vpx=vpx, size=(W, H), valid=valid, m_edge=m_edge)


def _scores(ctx: dict, p: MeasureParams) -> np.ndarray:
    """(2 srch + 1, 2 srch + 1) coarse score of the integer shifts (row: dy, column: dx) from (c0, r0)."""
    half, srch = ctx["half"], ctx["srch"]
    if p.coarse == "lines":
        full = _line_score(ctx["chip"], ctx["units"], np.minimum(ctx["lens"], p.max_edge_px), ctx["t0s"])
        sc = full[half:half + 2 * srch + 1, half:half + 2 * srch + 1]
    elif p.coarse == "likelihood":
        sc = _llr(ctx["chip"], ctx["masks"], ctx["valid"])
    else:
        raise ValueError(f"coarse must be 'lines' or 'likelihood', got {p.coarse!r}")
    if p.border == "edges":
        return sc
    # the search is clipped to the photo: a shift putting the vertex within border_px of the border is not tried
    W, H = ctx["size"]
    b = _border_px(p)
    dc, dr = ctx["c0"] + np.arange(-srch, srch + 1), ctx["r0"] + np.arange(-srch, srch + 1)
    on = ((dr >= b) & (dr < H - b))[:, None] & ((dc >= b) & (dc < W - b))[None, :]
    return np.where(on, sc, -np.inf)


def _border_px(p: "MeasureParams") -> int:
    """A vertex nearer than this to the border has no edge profile (``wide_band_px`` + 3 px) beside it (px)."""
    return int(math.ceil(p.wide_band_px + 3.0)) + 1


def _inside_px(origin: np.ndarray, u: np.ndarray, size: tuple[int, int], margin: float) -> float:
    """How far (px) from *origin* along *u* the line stays *margin* px inside the W x H photo."""
    W, H = size
    t = np.inf
    for o, d, hi in ((origin[0], u[0], W - 1 - margin), (origin[1], u[1], H - 1 - margin)):
        if d > 1e-12:
            t = min(t, (hi - o) / d)
        elif d < -1e-12:
            t = min(t, (margin - o) / d)
    return float(max(t, 0.0))


def _refine(img: np.ndarray, ctx: dict, shift: np.ndarray, p: MeasureParams) -> Measurement:
    """Edge lines from the shifted prediction and their intersection (module docstring, steps 2-3)."""
    base = replace(ctx["base"], shift_px=shift)
    origin = ctx["vpx"] + shift
    W, H = ctx["size"]
    me = ctx["m_edge"]
    if p.border == "edges" and not (me <= origin[0] < W - me and me <= origin[1] < H - me):
        return base.failed("near_border", f"the vertex found at column {origin[0]:.0f}, row {origin[1]:.0f}: its "
                                          f"edges, {me} px, reach past the photo's border")
    bd = _border_px(p)
    if not (bd <= origin[0] < W - bd and bd <= origin[1] < H - bd):
        return base.failed("near_border", f"the vertex found at column {origin[0]:.0f}, row {origin[1]:.0f} lies "
                                          f"within {bd} px of the photo's border: no edge profile beside it")
    fits, why, fits_planes, cut_failed = [], [], [], 0
    for k, e in enumerate(ctx["edges"]):
        # the edge's far end is a junction (a vertex, an eave corner) unless the edge is cut at max_edge_px
        length = min(float(ctx["lens"][k]), p.max_edge_px)
        far = float(ctx["t0s"][k]) if float(ctx["lens"][k]) <= p.max_edge_px else 1.0
        # fitted on its part inside the photo (the profiles, band_px + 3 px across, on the photo)
        inside = _inside_px(origin, ctx["units"][k], (W, H), p.band_px + 3.0)
        cut = p.border == "fit" and inside < length
        if cut:
            length, far = inside, 1.0
        fit, reason = fit_edge(img, origin, ctx["units"][k], length,
                                ctx["t0s"][k], p.band_px, p.min_points, p.min_contrast, p.min_sd_px,
                                p.min_ratio, p.max_scatter_px, p.smooth_px, far, p.direction_sd_deg)
        if fit is None:
            cut_failed += int(cut)
            why.append(f"edge of planes {e.planes[0] + 1}-{e.planes[1] + 1}: {reason}"
                       + (f" (cut at {length:.0f} px by the photo's border)" if cut else ""))
            continue
        fits.append((ctx["units"][k], fit))
        fits_planes.append(e.planes)
    def edge_lines(idx: Sequence[int], strong: bool) -> tuple:
        out = []
        for i in idx:
            u, fit = fits[i]
            if strong and fit[3] < p.two_line_ratio:
                continue
            el = _edge_line(fits_planes[i], origin, u, fit[4], fit[3], p.line_sd_px, p.line_direction_sd_deg)
            if el is not None:
                out.append(el)
        return tuple(out)

    base = replace(base, edge_lines=())
    if len(fits) < 2:
        return replace(base.failed("near_border" if len(fits) + cut_failed >= 2 else "no_edges",
                                   f"{len(fits)} of {len(ctx['edges'])} edges found in the photo"
                                   + (f" ({'; '.join(why)})" if why else "")),
                       edge_lines=edge_lines(range(len(fits)), True))
    lines, mm, cc, covs = [], [], [], []
    for u, (coef, cov, tk, *_) in fits:
        nvec = np.array([-u[1], u[0]])
        a, b = coef
        dirv = (u + b * nvec) / math.hypot(1.0, b)
        m = np.array([-dirv[1], dirv[0]])
        mm.append(m)
        cc.append(float(m @ (origin + a * nvec)))
        covs.append((cov, b))
        lines.append((origin + tk[0] * u + (a + b * tk[0]) * nvec, origin + tk[-1] * u + (a + b * tk[-1]) * nvec))
    mm = np.array(mm)
    use = list(range(len(fits)))
    # two edges on one image line: the one turned farther from its predicted direction goes
    dropped = []
    for i in range(len(fits)):
        for j in range(i + 1, len(fits)):
            if i in use and j in use and \
                    math.degrees(math.acos(min(1.0, abs(float(mm[i] @ mm[j]))))) < p.min_angle_deg:
                drop = i if abs(covs[i][1]) > abs(covs[j][1]) else j
                why.append(f"edge of planes {fits_planes[drop][0] + 1}-{fits_planes[drop][1] + 1}: found on "
                           f"the line of another edge")
                use.remove(drop)
                dropped.append(drop)
    if len(use) < 2:
        # the edges found lie on one image line: located along it where the line bends (step 3a)
        found = locate_along(fits, mm, np.array(cc), covs, use[0], dropped, origin,
                             min_angle_deg=p.along_min_angle_deg, max_sd_px=p.along_max_sd_px,
                             two_line_ratio=p.two_line_ratio, sd_px=p.vertex_sd_px,
                             texture_px=p.vertex_texture_px) if len(use) == 1 else "no edge left"
        if isinstance(found, str):
            return replace(base.failed("weak_geometry", f"the edges found lie on one image line: {found}"
                                       + (f" ({'; '.join(why)})" if why else "")),
                           edge_lines=edge_lines(use, True))
        x, cov_x, o, how = found
        pk, po = fits_planes[use[0]], fits_planes[o]
        return replace(base, px=x, cov_px2=cov_x, status="measured", along_line=True,
                       reason=f"located along one edge: the edges of planes {pk[0] + 1}-{pk[1] + 1} and "
                              f"{po[0] + 1}-{po[1] + 1} lie nearly on one image line, {how}"
                       + (f" ({'; '.join(w for w in why if 'found on the line' not in w)})"
                          if any('found on the line' not in w for w in why) else ""),
                       lines=(lines[use[0]], lines[o]), edge_lines=edge_lines([use[0], o], False))
    # a weak edge enters the point only if it agrees with the strong edges' point (step 3b)
    if len(use) >= 3:
        for i, w in weak_edge_tests(fits, mm, np.array(cc), covs, use, origin, two_line_ratio=p.two_line_ratio,
                                    min_angle_deg=p.min_angle_deg, sd_px=p.vertex_sd_px,
                                    texture_px=p.vertex_texture_px):
            if abs(w) > p.weak_edge_w:
                strong = [fits_planes[j] for j in use if fits[j][1][3] >= p.two_line_ratio]
                why.append(f"edge of planes {fits_planes[i][0] + 1}-{fits_planes[i][1] + 1}: weak (gradient "
                           f"{fits[i][1][3]:.1f} x the texture's) and off the point of the strong edges "
                           f"{', '.join(f'{a + 1}-{b + 1}' for a, b in strong)} (w {w:+.1f}, "
                           f"|w| > {p.weak_edge_w:g})")
                use.remove(i)
    while True:
        x, n_mat, chi2 = intersect_lines([fits[i] for i in use], mm[use], np.array(cc)[use],
                                         [covs[i] for i in use], origin, p.vertex_sd_px, p.vertex_texture_px)
        if len(use) <= 2 or chi2 <= _CHI2_1 * (len(use) - 2):
            break
        # which line goes (module docstring, step 3c): the largest w; of three lines (all w alike) the weakest
        drop, off, w = worst_line(fits, mm, np.array(cc), covs, use, origin, sd_px=p.vertex_sd_px,
                                  texture_px=p.vertex_texture_px)
        why.append(f"edge of planes {fits_planes[drop][0] + 1}-{fits_planes[drop][1] + 1}: does not meet the "
                   f"other edges at one point ({abs(off):.1f} px off, w {w:+.1f}"
                   + (f"; the weakest of three, gradient {fits[drop][1][3]:.1f} x the texture's)" if len(use) == 3
                      else ")"))
        use.remove(drop)
    if len(use) == 2 and min(fits[i][1][3] for i in use) < p.two_line_ratio:
        weak = min(use, key=lambda i: fits[i][1][3])
        return replace(base.failed("no_edges", f"two edges only, and the edge of planes {fits_planes[weak][0] + 1}-"
                                               f"{fits_planes[weak][1] + 1} is weak (gradient {fits[weak][1][3]:.1f} x "
                                               f"the texture's, < {p.two_line_ratio:g}): no check of it"
                                   + (f" ({'; '.join(why)})" if why else "")), edge_lines=edge_lines(use, True))
    angs = [math.degrees(math.acos(min(1.0, abs(float(mm[i] @ mm[j]))))) for i in use for j in use if i < j]
    if max(angs) < p.min_angle_deg:
        return replace(base.failed("weak_geometry", f"the edges left meet at {max(angs):.0f} deg "
                                                    f"(< {p.min_angle_deg:g})"), edge_lines=edge_lines(use, True))
    lines = [lines[i] for i in use]
    cov_x = np.linalg.inv(n_mat)
    return replace(base, px=x, cov_px2=0.5 * (cov_x + cov_x.T), status="measured",
                   reason="; ".join(why), lines=tuple(lines), edge_lines=edge_lines(use, False))


def _confirmed(wide: Measurement, narrow: Measurement, shift: np.ndarray, p: MeasureParams) -> Measurement:
    """The measurement of the two fits (module docstring, step 2): *narrow*, from *wide*'s vertex in ``band_px``,
    confirms *wide*, from the coarse *shift* in ``wide_band_px``.

    *narrow* measured: its point (but a point of crossing edges is not traded for one along a single edge:
    *wide* kept then).  *narrow* not measured: the wide band's edges do not hold about their own vertex, so it
    is not a corner of the photo; *narrow*'s status, the reason naming both fits, and no point, segments or
    edge lines (they were fitted about a vertex that is not there).
    """
    if narrow:
        return replace(narrow, shift_px=shift) if wide.along_line or not narrow.along_line else wide
    return replace(narrow, shift_px=shift, lines=(), edge_lines=(), along_line=False).failed(
        narrow.status, f"the vertex found in the {p.wide_band_px:g} px band (column {wide.px[0]:.1f}, row "
                       f"{wide.px[1]:.1f}) is not found again from it in the {p.band_px:g} px band: {narrow.reason}")


def _masked_best(score: np.ndarray, ctx: dict, centre: np.ndarray, cinv: np.ndarray, radius2: float,
                 value: bool = False) -> Any:
    """The best shift (2,) within the ellipse; *value*: its score instead (-inf: none searched on the photo)."""
    srch = ctx["srch"]
    dy, dx = np.mgrid[-srch:srch + 1, -srch:srch + 1]
    d = np.stack([dx + (ctx["c0"] - ctx["vpx"][0]) - centre[0], dy + (ctx["r0"] - ctx["vpx"][1]) - centre[1]],
                 axis=-1)
    m2 = np.einsum("...i,ij,...j->...", d, cinv, d)
    sc = np.where(m2 <= radius2, score, -np.inf)
    iy, ix = np.unravel_index(int(np.argmax(sc)), sc.shape)
    if value:
        return float(sc[iy, ix])
    return np.array([float(dx[iy, ix] + ctx["c0"] - ctx["vpx"][0]), float(dy[iy, ix] + ctx["r0"] - ctx["vpx"][1])])


def measure_photo(image: Any, camera: Camera, eo: Any, targets: Sequence[VertexTarget],
                  params: MeasureParams | None = None) -> list[Measurement]:
    """Measure the LiDAR vertices of one photo (module docstring); one Measurement per target, in order.

    The orientation's error moves every vertex of a photo by nearly the same shift, so the
    coarse scores of all vertices (each normalised: median 0, MAD 1) are summed over the
    common shift; its best shift, searched within ``search_sigma`` of the mean prediction
    ellipse, is each vertex's start, refined within ``local_search_px``.  A photo with a single
    measurable vertex uses that vertex's own best shift.

    Parameters
    ----------
    image : (H, W) or (H, W, 3) array
        The photo (uint8, uint16 or float grey values 0..255).
    camera : Camera
    eo : (6,) the approximate orientation the predictions were made with (m, rad)
    targets : sequence of VertexTarget
    params : MeasureParams, optional

    Returns
    -------
    list of Measurement
    """
    p = params or MeasureParams()
    img = grey(image)
    ctxs = [_setup(img, camera, eo, t, p) for t in targets]
    live = [k for k, c in enumerate(ctxs) if isinstance(c, dict)]
    out: list[Any] = [c if not isinstance(c, dict) else None for c in ctxs]
    if not live:
        return out
    scores = {k: _scores(ctxs[k], p) for k in live}
    # the common shift: normalised score maps summed on a shift grid centred on zero
    srch = max(ctxs[k]["srch"] for k in live)
    acc = np.zeros((2 * srch + 1, 2 * srch + 1))
    cnt = np.zeros_like(acc)
    for k in live:
        sc = scores[k]
        fin = np.isfinite(sc)
        med = float(np.median(sc[fin]))
        mad = 1.4826 * float(np.median(np.abs(sc[fin] - med))) or 1.0
        z = np.where(fin, (sc - med) / mad, 0.0)
        sk = ctxs[k]["srch"]
        acc[srch - sk:srch + sk + 1, srch - sk:srch + sk + 1] += z
        cnt[srch - sk:srch + sk + 1, srch - sk:srch + sk + 1] += 1
    cov = np.mean([np.asarray(targets[k].prediction.cov_px2) for k in live], axis=0)
    common = {"srch": srch, "c0": 0, "r0": 0, "vpx": np.zeros(2)}
    cinv = np.linalg.inv(cov + np.eye(2) * 0.25)
    shift0 = _masked_best(np.where(cnt > 0, acc / np.maximum(cnt, 1) * np.sqrt(np.maximum(cnt, 1)), -np.inf),
                          common, np.zeros(2), cinv, p.search_sigma**2)
    local = np.eye(2) / float(p.local_search_px) ** 2
    for k in live:
        ctx = ctxs[k]
        start = shift0 if len(live) > 1 else np.zeros(2)
        lim = 1.0 if len(live) > 1 else p.search_sigma**2
        ci = local if len(live) > 1 else np.linalg.inv(np.asarray(targets[k].prediction.cov_px2) + np.eye(2) * 0.25)
        best = _masked_best(scores[k], ctx, start, ci, lim)
        if not np.isfinite(_masked_best(scores[k], ctx, start, ci, lim, value=True)):
            # every shift searched puts the vertex off the photo (border_px inside): not on this photo
            out[k] = ctx["base"].failed("not_visible", "off the photo: no shift searched ("
                                        + ("about the photo's common shift" if len(live) > 1 else "in its ellipse")
                                        + f") puts it {_border_px(p)} px inside the frame (predicted at column "
                                        f"{ctx['vpx'][0]:.0f}, row {ctx['vpx'][1]:.0f})")
            continue
        if p.coarse != "lines" and p.refine_px > 0:
            # the edges' directional gradient, near the coarse shift: the vertex to a pixel or so
            lines = _scores(ctx, replace(p, coarse="lines"))
            best = _masked_best(lines, ctx, best, np.eye(2) / float(p.refine_px) ** 2, 1.0)
        # integer shift of the template's centre (c0, r0) = round(prediction)
        shift = np.round(best + ctx["vpx"] - np.array([ctx["c0"], ctx["r0"]])) + np.array([ctx["c0"], ctx["r0"]]) \
            - ctx["vpx"]
        m = _refine(img, ctx, shift, replace(p, band_px=p.wide_band_px))
        if m:   # again from the vertex found, in the narrow band
            m = _confirmed(m, _refine(img, ctx, np.asarray(m.px) - ctx["vpx"], p), shift, p)
        out[k] = m
    return out


def measure_vertex(image: Any, camera: Camera, eo: Any, vertex_m: Any, planes: Sequence[Any], xyz_m: Any,
                   prediction: Prediction, params: MeasureParams | None = None) -> Measurement:
    """Measure one LiDAR vertex on one photo by itself (:func:`measure_photo` with one target)."""
    return measure_photo(image, camera, eo, [VertexTarget(np.asarray(vertex_m, dtype=np.float64), tuple(planes),
                                                          np.asarray(xyz_m, dtype=np.float64), prediction)],
                         params)[0]


def check_consistency(measurements: Sequence[Measurement], cameras: Sequence[Camera], eos: Any, eo_covs: Any,
                      vertex_m: Any, vertex_cov: Any) -> list[Measurement]:
    """The multi-photo test of one vertex's measurements (module docstring, step 4).

    Parameters
    ----------
    measurements : sequence of Measurement (one vertex, one per photo)
    cameras : the photos' cameras (same order)
    eos : (P, 6) approximate orientations; eo_covs : (P, 6, 6) their covariances
    vertex_m : (3,) LiDAR vertex; vertex_cov : (3, 3)

    Returns
    -------
    list of Measurement
        The same, with rejected ones' status ``"rejected"`` and the reason.
    """
    out = list(measurements)
    eos = np.asarray(eos, dtype=np.float64).reshape(-1, 6)
    eo_covs = np.asarray(eo_covs, dtype=np.float64).reshape(-1, 6, 6)
    v = np.asarray(vertex_m, dtype=np.float64).reshape(3)
    vc = np.asarray(vertex_cov, dtype=np.float64).reshape(3, 3)
    for k, m in enumerate(out):
        if not m:
            continue
        if not (np.isfinite(m.px).all() and np.isfinite(m.cov_px2).all()):
            out[k] = m.failed("rejected", "the measurement or its covariance is not finite")
            continue
        d = np.asarray(m.px) - np.asarray(m.predicted_px)
        m2 = float(d @ np.linalg.solve(np.asarray(m.predicted_cov_px2) + np.asarray(m.cov_px2), d))
        if m2 > _CHI2_2:
            out[k] = m.failed("rejected", f"measured {float(np.hypot(*d)):.1f} px from the prediction: outside "
                                          f"its 99.9 % ellipse (normalised {math.sqrt(m2):.1f})")
    while True:
        live = [k for k, m in enumerate(out) if m]
        if len(live) < 2:
            return out
        jp, wts = {}, {}
        for k in live:
            jpk, _ = pixel_jacobians(cameras[k], eos[k], v[None])
            jp[k] = jpk[0]
            wts[k] = np.linalg.inv(np.asarray(out[k].cov_px2) + jp[k] @ eo_covs[k] @ jp[k].T)
        x = v.copy()
        for _ in range(5):
            n_mat = np.zeros((3, 3))
            rhs = np.zeros(3)
            for k in live:
                px = pixel_positions(cameras[k], eos[k], x[None])[0]
                _, jx = pixel_jacobians(cameras[k], eos[k], x[None])
                r = np.asarray(out[k].px) - px
                n_mat += jx[0].T @ wts[k] @ jx[0]
                rhs += jx[0].T @ wts[k] @ r
            try:
                dx = np.linalg.solve(n_mat + np.eye(3) * 1e-9, rhs)
            except np.linalg.LinAlgError:
                return out
            x = x + dx
            if np.linalg.norm(dx) < 1e-5:
                break
        norm = {}
        for k in live:
            r = np.asarray(out[k].px) - pixel_positions(cameras[k], eos[k], x[None])[0]
            norm[k] = float(r @ wts[k] @ r)
        worst = max(live, key=lambda k: norm[k])
        if len(live) > 2 and norm[worst] > _CHI2_2:
            out[worst] = out[worst].failed(
                "rejected", f"disagrees with the other {len(live) - 1} photos: normalised residual "
                            f"{math.sqrt(norm[worst]):.1f} of the forward intersection")
            continue
        dv = x - v
        try:
            q = float(dv @ np.linalg.solve(np.linalg.inv(n_mat) + vc, dv))
        except np.linalg.LinAlgError:
            q = math.inf
        if not math.isfinite(q):
            q = math.inf
        if q > _CHI2_3:
            for k in live:
                out[k] = out[k].failed("rejected", f"the forward intersection of the {len(live)} photos lies "
                                                   f"{float(np.linalg.norm(dv)):.2f} m from the LiDAR vertex "
                                                   f"(normalised {math.sqrt(q):.1f}): not this vertex")
        return out


def check_photo(measurements: Sequence[Measurement], camera: Camera, eo: Any, eo_cov: Any, vertices_m: Any,
                vertex_covs: Any, *, model_sd_px: float = 0.5, alone: str = "keep") -> list[Measurement]:
    """The per-photo test of one photo's measurements against their common displacement (module docstring, step 5).

    Parameters
    ----------
    measurements : sequence of Measurement (one photo, one per vertex; those not ``measured`` pass untouched)
    camera : Camera
    eo : (6,) the approximate orientation the predictions were made with (m, rad); eo_cov : (6, 6)
    vertices_m : (N, 3) the LiDAR vertices (same order); vertex_covs : (N, 3, 3) their covariances (m^2)
    model_sd_px : float
        Sd (px) added to each offset for what the linear model of the orientation's error does not see.
    alone : ``"keep"`` or ``"reject"``
        A measurement alone on its photo cannot be tested: kept (default), or rejected with the
        reason (over real roofs, a fit locked onto another corner of the same roof is then caught
        only by the other photos' test, whose tolerance is the prediction's ~20 px).

    Returns
    -------
    list of Measurement
        The same, inconsistent ones with status ``"rejected"`` and the reason.
    """
    out = list(measurements)
    v = np.asarray(vertices_m, dtype=np.float64).reshape(-1, 3)
    vc = np.asarray(vertex_covs, dtype=np.float64).reshape(-1, 3, 3)
    live = [k for k, m in enumerate(out) if m and np.isfinite(m.px).all() and np.isfinite(m.cov_px2).all()
            and np.isfinite(m.predicted_px).all()]
    if alone not in ("keep", "reject"):
        raise LidarcatError(f"alone must be 'keep' or 'reject', got {alone!r}")
    if len(live) == 1 and alone == "reject":
        m = out[live[0]]
        out[live[0]] = m.failed("rejected", f"alone on its photo: not tested against the photo's common shift "
                                            f"(prediction sd {math.sqrt(max(np.linalg.eigvalsh(m.predicted_cov_px2))):.0f} px)")
    if len(live) < 2:
        return out
    jp, jx = pixel_jacobians(camera, eo, v[live])
    p_inv = np.linalg.pinv(np.asarray(eo_cov, dtype=np.float64).reshape(6, 6))
    d = {k: np.asarray(out[k].px) - np.asarray(out[k].predicted_px) for k in live}
    jac = dict(zip(live, jp))
    cov = {k: np.asarray(out[k].cov_px2) + jx[i] @ vc[k] @ jx[i].T + np.eye(2) * model_sd_px**2
           for i, k in enumerate(live)}
    w = {k: np.linalg.inv(cov[k]) for k in live}

    def loo(k: int, among: list[int]) -> tuple[float, float]:
        """(normalised, px) residual of vertex k against the common displacement from the others."""
        n_mat = p_inv.copy()
        rhs = np.zeros(6)
        for j in among:
            if j != k:
                n_mat += jac[j].T @ w[j] @ jac[j]
                rhs += jac[j].T @ w[j] @ d[j]
        n_inv = np.linalg.inv(n_mat)
        r = d[k] - jac[k] @ (n_inv @ rhs)
        q = float(r @ np.linalg.solve(jac[k] @ n_inv @ jac[k].T + cov[k], r))
        return q, float(np.hypot(*r))

    while len(live) >= 2:
        res = {k: loo(k, live) for k in live}
        worst = max(live, key=lambda k: res[k][0])
        if res[worst][0] <= _CHI2_2:
            break
        if len(live) == 2:
            for k in live:
                out[k] = out[k].failed("rejected", f"inconsistent with the photo's common shift: {res[k][1]:.1f} px "
                                                   f"from the other vertex's (normalised {math.sqrt(res[k][0]):.1f}); "
                                                   f"which of the two is off cannot be told")
            break
        out[worst] = out[worst].failed(
            "rejected", f"inconsistent with the photo's common shift: {res[worst][1]:.1f} px (normalised "
                        f"{math.sqrt(res[worst][0]):.1f}, from the other {len(live) - 1} vertices)")
        live.remove(worst)
    return out
