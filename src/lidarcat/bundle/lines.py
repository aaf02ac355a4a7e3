r"""Line control: image observations of LiDAR roof lines (ridges, hips, eaves) in the adjustment.

The thesis (recommendations, section 5.2) proposes the intersection *lines* of the fitted roof
planes as control beside their corners.  A control line is a 3-D segment with end points
``A, B`` (m; from two fitted planes: a point and the direction of their intersection, clipped
to the roof) and the 6 x 6 covariance of ``(A, B)`` propagated from the plane fits.  An
observation of it is the edge measured in one photo: two image points ``p1, p2`` on the edge
(photo coordinates, mm, x right, y up, corrected like every image point), each with an
isotropic sd ``s`` (mm) across the edge.  The in-memory forms are :class:`ControlLine`
(one 3-D line), :class:`LineObservation` (one photo's measurement; what an automatic line
measurement produces: :func:`observation_from_edge_points` turns n fitted edge points into the
exactly equivalent two points) and :class:`LineControl` (all of them as arrays, the ``lines`` field of
:class:`~lidarcat.bundle.problem.BundleProblem`).

The condition: the 3-D line projects onto the image line
--------------------------------------------------------
With the unit normal ``n = J (p2 - p1) / |p2 - p1|`` (``J`` the rotation by +90 degrees) the
image line is ``{x : n^T (x - p1) = 0}``.  The projection plane of this line (through the
projection centre) contains the 3-D line exactly when both end points project onto it, so the
two scalar residuals of one observation (photo i) are the signed distances (mm)

.. math::  r_k = n^T \,\bigl(x(eo_i, X_k) - p_1\bigr), \qquad X_k \in \{A, B\},

with ``x(eo, X)`` the collinearity projection (:mod:`lidarcat.geometry.collinearity`).
``r_A = r_B = 0`` is the coplanarity form: the plane through the projection centre and the
image line contains ``A`` and ``B``.  A shift of ``X_k`` along the 3-D line moves its
projection along the (nearly parallel) image line, so the end points need not be the measured
edge's ends, and the poorly determined along-line position of a plane-intersection segment
hardly enters.  The end points are given (not unknowns); only the orientation of photo i is
adjusted, so every line observation adds to that photo's blocks only:

.. math::  A = \partial r / \partial eo_i = \begin{bmatrix} n^T [-a_{pt}(A),\ a_{ang}(A)] \\
           n^T [-a_{pt}(B),\ a_{ang}(B)] \end{bmatrix}  (2 \times 6), \qquad
           U_i \mathrel{+}= A^T P A, \quad g_{c,i} \mathrel{+}= A^T P r, \quad
           v'Pv \mathrel{+}= r^T P r,

where ``a_pt`` (2 x 3) and ``a_ang`` (2 x 3) are the collinearity Jacobians of
:func:`~lidarcat.geometry.collinearity.project_jacobian_parts` (``dx/dX0 = -a_pt``).  Each
observation adds 2 to the observations, so 2 to the degrees of freedom.

Weights: the covariance of the two residuals
--------------------------------------------
The residuals depend on the measured ``p1, p2`` and on ``A, B``.  With ``s_k = t^T (x_k -
p_1) / L`` the position of the projected end point along the measured segment (0 at ``p1``,
1 at ``p2``; ``t`` the unit direction, ``L`` the length), a displacement ``d1, d2`` of the
measured points moves the image line across by ``(1 - s) n^T d1 + s n^T d2`` at ``s``, so
``dr_k / dp1 = -(1 - s_k) n^T`` and ``dr_k / dp2 = -s_k n^T`` and (``p1, p2`` independent,
sd ``s`` each)

.. math::  \Sigma_{img} = s^2 \begin{bmatrix} (1-s_A)^2 + s_A^2 & (1-s_A)(1-s_B) + s_A s_B \\
           \cdot & (1-s_B)^2 + s_B^2 \end{bmatrix}.

The end points enter through ``dr_k / dX_k = n^T a_pt(X_k)``: with ``J_L =
blockdiag(n^T a_pt(A), n^T a_pt(B))`` (2 x 6), ``Sigma_r = Sigma_img + J_L Sigma_AB J_L^T``
and ``P = Sigma_r^{-1}`` (evaluated at the current orientation; ``sigma0^2 = 1`` a priori).
An along-line variance of ``Sigma_AB`` (a plane-intersection segment's ends are poorly
fixed along the line) is projected almost entirely along the image line and drops out.

Neglected: the correlation between the observations of one line on different photos through
the common ``A, B`` (each photo's residuals get the line's full variance, the photos are
treated as independent).  It makes the orientation sds slightly optimistic when the 3-D
line's sd is comparable to the image sd projected to the ground; for LiDAR roof lines (cm)
against a GSD of 5-15 cm it is small (docs/lines.md has the numbers over seeds).

Testing (as point control)
--------------------------
Every line observation depends on one photo's orientation only, so its residual cofactor is
exact from that photo's 6 x 6 covariance ``C_i`` (the ``eo_cov`` of the result, divided by
the variance factor): ``Q_vv = Sigma_r - A C_i A^T`` (2 x 2).  Redundancy numbers are
the diagonal of ``P^1/2 Q_vv P^1/2`` (:mod:`lidarcat.bundle.line_tests`: the two residuals are
correlated, ``diag(Q_vv P)`` is no redundancy); the group test is ``T = e^T Q_vv^{-1} e ~ chi2(2)`` (``e = -r``), reported
as ``w = sqrt(T)`` against the B-method critical value of :mod:`lidarcat.bundle.redundancy`
(q = 2).  :func:`lidarcat.bundle.line_tests.line_tests` evaluates them;
:func:`lidarcat.bundle.reliability.snoop` tests them as groups of its one worst-first loop
beside image points and constraints (and re-weights them in its robust steps, through
``LineControl.weight``); :func:`lidarcat.bundle.line_tests.snoop_lines` snoops the line group
alone.

Limits: photos of the plain collinearity (a problem with ``rays`` (rolling shutter, rigs) and
lines is rejected by :class:`~lidarcat.bundle.problem.BundleProblem`).  In
:func:`~lidarcat.bundle.problem.check_datum` a part of the block with control lines in two
directions or more counts them as control when the lines and control points number 3 or more (a
line fixes 4 of the 7 datum parameters; two lines of one roof corner leave the scale about it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from ..errors import DatumError
from ..geometry.collinearity import project_jacobian_parts

__all__ = [
    "ControlLine",
    "LineControl",
    "LineObservation",
    "line_cost",
    "line_normal_terms",
    "line_residuals_mm",
    "line_terms",
]

#: a measured image segment shorter than this (mm) has no direction
MIN_LENGTH_MM = 1e-6


# ---------------------------------------------------------------------------
# value types
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class ControlLine:
    """One 3-D control line (e.g. a ridge from two fitted LiDAR roof planes).

    Parameters
    ----------
    line : str
        Line id.
    a_m, b_m : (3,) float
        End points (E, N, h in the survey CRS, m); any two distinct points of the line.
    cov_m2 : (6, 6) float, optional
        Covariance of ``(A, B)`` (m^2); default zeros (an exact line).
    """

    line: str
    a_m: np.ndarray
    b_m: np.ndarray
    cov_m2: np.ndarray | None = None

    def __post_init__(self) -> None:
        a = frozen_array(np.reshape(np.asarray(self.a_m, dtype=float), 3))
        b = frozen_array(np.reshape(np.asarray(self.b_m, dtype=float), 3))
        cov = np.zeros((6, 6)) if self.cov_m2 is None else np.reshape(np.asarray(self.cov_m2, dtype=float), (6, 6))
        object.__setattr__(self, "line", str(self.line))
        object.__setattr__(self, "a_m", a)
        object.__setattr__(self, "b_m", b)
        object.__setattr__(self, "cov_m2", frozen_array(cov))
        if not (np.isfinite(a).all() and np.isfinite(b).all() and np.isfinite(cov).all()):
            raise DatumError(f"control line {self.line}: end points and covariance must be finite")
        if np.linalg.norm(b - a) <= 0:
            raise DatumError(f"control line {self.line}: its end points coincide (a line of zero length)")

    @classmethod
    def from_sds(cls, line: str, a_m: Sequence[float], b_m: Sequence[float], sd_across_m: float,
                 sd_along_m: float | None = None) -> ControlLine:
        """A line whose end points have sd *sd_across_m* across the line (both axes) and
        *sd_along_m* along it (default: the same), independent."""
        a, b = np.asarray(a_m, dtype=float), np.asarray(b_m, dtype=float)
        t = (b - a) / max(float(np.linalg.norm(b - a)), 1e-300)
        along = sd_across_m if sd_along_m is None else sd_along_m
        c3 = sd_across_m**2 * (np.eye(3) - np.outer(t, t)) + along**2 * np.outer(t, t)
        cov = np.zeros((6, 6))
        cov[:3, :3] = cov[3:, 3:] = c3
        return cls(line, a, b, cov)


@dataclasses.dataclass(frozen=True, eq=False)
class LineObservation:
    """A control line measured in one photo: two image points on the edge.

    Parameters
    ----------
    line, photo : str
        Ids of the control line and the photo.
    xy1_mm, xy2_mm : (2,) float
        Two distinct points on the imaged edge (photo coordinates, mm, x right, y up).
    sd_mm : float
        Sd of each point across the edge (mm).
    pixel_mm : float, optional
        Pixel size of the photo (mm), for residuals in pixels; NaN: unknown.
    """

    line: str
    photo: str
    xy1_mm: np.ndarray
    xy2_mm: np.ndarray
    sd_mm: float
    pixel_mm: float = math.nan

    def __post_init__(self) -> None:
        p1 = frozen_array(np.reshape(np.asarray(self.xy1_mm, dtype=float), 2))
        p2 = frozen_array(np.reshape(np.asarray(self.xy2_mm, dtype=float), 2))
        object.__setattr__(self, "line", str(self.line))
        object.__setattr__(self, "photo", str(self.photo))
        object.__setattr__(self, "xy1_mm", p1)
        object.__setattr__(self, "xy2_mm", p2)
        object.__setattr__(self, "sd_mm", float(self.sd_mm))
        object.__setattr__(self, "pixel_mm", float(self.pixel_mm))
        where = f"line {self.line} on photo {self.photo}"
        if not (np.isfinite(p1).all() and np.isfinite(p2).all() and math.isfinite(self.sd_mm)):
            raise DatumError(f"{where}: image points and sd must be finite")
        if self.sd_mm <= 0:
            raise DatumError(f"{where}: sd must be positive, got {self.sd_mm:g} mm")
        if np.linalg.norm(p2 - p1) < MIN_LENGTH_MM:
            raise DatumError(f"{where}: the two image points coincide (a line of zero length)")


def observation_from_edge_points(line: str, photo: str, points_mm: np.ndarray, sd_mm: float,
                                 pixel_mm: float = math.nan) -> LineObservation:
    r"""The two-point observation equivalent to a least-squares line through *points_mm* (n, 2).

    For n >= 2 edge points with independent sd ``s`` across the edge, the fitted line (the
    principal axis) has, at the position ``u`` along it from the centroid, the offset variance
    ``s^2 (1/n + u^2 / S)`` with ``S = sum u_i^2``.  Two independent points at ``u = +-h`` with
    sd ``s_p`` give ``s_p^2 (1/2 + u^2 / (2 h^2))``; equal for every ``u`` when

    .. math::  s_p = s \sqrt{2 / n}, \qquad h = \sqrt{S / n}

    (the rms spread of the points): so an edge fitted from many points (an automatic
    measurement) enters :class:`LineControl` exactly through this :class:`LineObservation`.
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 2)
    where = f"line {line} on photo {photo}"
    if len(pts) < 2 or not np.isfinite(pts).all():
        raise DatumError(f"{where}: an edge needs at least 2 finite image points, got {len(pts)}")
    c = pts.mean(axis=0)
    vt = np.linalg.svd(pts - c, full_matrices=False)[2]
    t = vt[0]
    u = (pts - c) @ t
    h = math.sqrt(float(np.sum(u**2)) / len(pts))
    if h < MIN_LENGTH_MM:
        raise DatumError(f"{where}: the edge points coincide (a line of zero length)")
    return LineObservation(line, photo, c - h * t, c + h * t, sd_mm * math.sqrt(2.0 / len(pts)), pixel_mm)


@dataclasses.dataclass(frozen=True, eq=False)
class LineControl:
    """Control lines and their image observations as arrays (``BundleProblem.lines``).

    Parameters
    ----------
    line_ids : (L,) str
    a_m, b_m : (L, 3) float
        End points of every line (m).
    cov_m2 : (L, 6, 6) float
        Covariance of ``(A, B)`` of every line (m^2).
    line_index, photo_index : (m,) int
        Line and photo (index into the problem's ``photo_ids``) of every observation.
    xy1_mm, xy2_mm : (m, 2) float
        The two measured image points of every observation (mm).
    sd_mm : (m,) float
        Their sd across the edge (mm).
    pixel_mm : (m,) float, optional
        Pixel size of each observation's photo (mm; NaN: unknown), for residuals in pixels.
    weight : (m,) float, optional
        Factor on the weight matrix ``P`` of every observation (default 1): ``Sigma_r / weight``.
        The robust re-weighting (:mod:`lidarcat.bundle.robust`) sets it; the 3-D line's share
        of ``Sigma_r`` is scaled with the image share, so a factor near 0 takes the
        observation out whatever the line's own sd.
    """

    line_ids: np.ndarray
    a_m: np.ndarray
    b_m: np.ndarray
    cov_m2: np.ndarray
    line_index: np.ndarray
    photo_index: np.ndarray
    xy1_mm: np.ndarray
    xy2_mm: np.ndarray
    sd_mm: np.ndarray
    pixel_mm: np.ndarray | None = None
    weight: np.ndarray | None = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "line_ids", frozen_array([str(v) for v in self.line_ids], dtype=object))
        n_l = len(self.line_ids)
        s(self, "a_m", frozen_array(np.reshape(np.asarray(self.a_m, dtype=float), (n_l, 3))))
        s(self, "b_m", frozen_array(np.reshape(np.asarray(self.b_m, dtype=float), (n_l, 3))))
        s(self, "cov_m2", frozen_array(np.reshape(np.asarray(self.cov_m2, dtype=float), (n_l, 6, 6))))
        s(self, "line_index", frozen_array(np.atleast_1d(np.asarray(self.line_index, dtype=np.int64)), dtype=np.int64))
        s(self, "photo_index", frozen_array(np.atleast_1d(np.asarray(self.photo_index, dtype=np.int64)), dtype=np.int64))
        m = len(self.line_index)
        s(self, "xy1_mm", frozen_array(np.reshape(np.asarray(self.xy1_mm, dtype=float), (m, 2))))
        s(self, "xy2_mm", frozen_array(np.reshape(np.asarray(self.xy2_mm, dtype=float), (m, 2))))
        s(self, "sd_mm", frozen_array(np.broadcast_to(np.asarray(self.sd_mm, dtype=float), (m,))))
        s(self, "pixel_mm", frozen_array(np.broadcast_to(
            np.asarray(math.nan if self.pixel_mm is None else self.pixel_mm, dtype=float), (m,))))
        s(self, "weight", frozen_array(np.broadcast_to(
            np.asarray(1.0 if self.weight is None else self.weight, dtype=float), (m,))))
        if len(self.photo_index) != m:
            raise DatumError("`line_index` and `photo_index` must have the same length")
        if m and (self.line_index.min() < 0 or self.line_index.max() >= n_l):
            raise DatumError("`line_index` out of range of `line_ids`")
        if len(set(self.line_ids)) != n_l:
            raise DatumError("duplicate control line id(s)")
        if not (np.all(self.sd_mm > 0) and np.isfinite(self.xy1_mm).all() and np.isfinite(self.xy2_mm).all()):
            raise DatumError("line observations must be finite with positive `sd_mm`")
        if np.any(np.linalg.norm(self.xy2_mm - self.xy1_mm, axis=1) < MIN_LENGTH_MM):
            raise DatumError("a line observation of zero length")

    @classmethod
    def from_observations(cls, lines: Iterable[ControlLine], observations: Iterable[LineObservation],
                          photo_ids: Sequence[str]) -> LineControl:
        """Arrays from value types; raises :class:`~lidarcat.errors.DatumError` naming an
        observation of an unknown line or photo, or a line measured twice on one photo."""
        lines = list(lines)
        obs = list(observations)
        li = {ln.line: k for k, ln in enumerate(lines)}
        if len(li) != len(lines):
            dup = sorted({ln.line for ln in lines if sum(m.line == ln.line for m in lines) > 1})
            raise DatumError(f"control line id(s) given twice: {', '.join(dup)}")
        pi = {str(p): k for k, p in enumerate(photo_ids)}
        seen: set[tuple[str, str]] = set()
        for o in obs:
            if o.line not in li:
                raise DatumError(f"line {o.line} on photo {o.photo}: no control line {o.line}")
            if o.photo not in pi:
                raise DatumError(f"line {o.line} on photo {o.photo}: no photo {o.photo} in the block")
            if (o.line, o.photo) in seen:
                raise DatumError(f"line {o.line} is measured twice on photo {o.photo}; keep one measurement")
            seen.add((o.line, o.photo))
        return cls(
            line_ids=[ln.line for ln in lines], a_m=np.array([ln.a_m for ln in lines]).reshape(-1, 3),
            b_m=np.array([ln.b_m for ln in lines]).reshape(-1, 3),
            cov_m2=np.array([ln.cov_m2 for ln in lines]).reshape(-1, 6, 6),
            line_index=np.array([li[o.line] for o in obs], dtype=np.int64),
            photo_index=np.array([pi[o.photo] for o in obs], dtype=np.int64),
            xy1_mm=np.array([o.xy1_mm for o in obs]).reshape(-1, 2),
            xy2_mm=np.array([o.xy2_mm for o in obs]).reshape(-1, 2),
            sd_mm=np.array([o.sd_mm for o in obs], dtype=float),
            pixel_mm=np.array([o.pixel_mm for o in obs], dtype=float))

    @property
    def n_observations(self) -> int:
        """Scalar observations: 2 per line observation."""
        return 2 * len(self.line_index)

    def select(self, keep: Any) -> LineControl:
        """The same lines with the observations *keep* (mask or indices)."""
        return dataclasses.replace(self, line_index=self.line_index[keep], photo_index=self.photo_index[keep],
                                   xy1_mm=self.xy1_mm[keep], xy2_mm=self.xy2_mm[keep], sd_mm=self.sd_mm[keep],
                                   pixel_mm=self.pixel_mm[keep], weight=self.weight[keep])

    def observation_labels(self, photo_ids: Sequence[str]) -> list[str]:
        """``line L on photo P`` of every observation."""
        return [f"line {self.line_ids[k]} on photo {photo_ids[i]}"
                for k, i in zip(self.line_index.tolist(), self.photo_index.tolist())]


# ---------------------------------------------------------------------------
# the model
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class _Terms:
    r: np.ndarray         # (m, 2) residuals (mm): signed distances of the projected A, B from the image line
    A: np.ndarray         # (m, 2, 6) d r / d eo of the observation's photo
    cov: np.ndarray       # (m, 2, 2) Sigma_r (mm^2)
    P: np.ndarray         # (m, 2, 2) its inverse
    u3: np.ndarray        # (m, 2) third image-frame coordinate of A, B (< 0: in front)
    xy: np.ndarray        # (m, 2, 2) projections of A, B (mm)


def line_terms(lines: LineControl, eo: np.ndarray, focal_length_mm: np.ndarray, *,
               jacobians: bool = True) -> _Terms:
    """Residuals, Jacobians and weights of every line observation at *eo* (P, 6; m, rad).

    *focal_length_mm* (P,) per photo.  Returns an object with ``r`` (m, 2) mm, ``A`` (m, 2, 6),
    ``cov`` and ``P`` (m, 2, 2) and ``u3`` (m, 2); see the module docstring.
    """
    L = lines
    m = len(L.line_index)
    ei = L.photo_index
    X = np.concatenate([L.a_m[L.line_index], L.b_m[L.line_index]])           # (2m, 3): A's then B's
    idx = np.concatenate([ei, ei])
    f = np.asarray(focal_length_mm, dtype=float)[idx]
    xy, a_pt, a_ang, u3 = project_jacobian_parts(np.asarray(eo, dtype=float), X, f, idx)
    d = L.xy2_mm - L.xy1_mm
    length = np.linalg.norm(d, axis=1)
    t = d / length[:, None]
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)                                # (m, 2)
    n2, t2 = np.concatenate([n, n]), np.concatenate([t, t])
    p1 = np.concatenate([L.xy1_mm, L.xy1_mm])
    r = np.einsum("ki,ki->k", n2, xy - p1).reshape(2, m).T                   # (m, 2)
    s = (np.einsum("ki,ki->k", t2, xy - p1) / np.concatenate([length, length])).reshape(2, m).T
    sd2 = L.sd_mm**2
    cov = np.empty((m, 2, 2))
    cov[:, 0, 0] = sd2 * ((1 - s[:, 0]) ** 2 + s[:, 0] ** 2)
    cov[:, 1, 1] = sd2 * ((1 - s[:, 1]) ** 2 + s[:, 1] ** 2)
    cov[:, 0, 1] = cov[:, 1, 0] = sd2 * ((1 - s[:, 0]) * (1 - s[:, 1]) + s[:, 0] * s[:, 1])
    ja = np.einsum("ki,kij->kj", n2, a_pt)                                    # n^T a_pt (2m, 3)
    jl = np.zeros((m, 2, 6))
    jl[:, 0, :3] = ja[:m]
    jl[:, 1, 3:] = ja[m:]
    cov += jl @ L.cov_m2[L.line_index] @ np.transpose(jl, (0, 2, 1))
    cov /= L.weight[:, None, None]
    P = np.linalg.inv(cov)
    if jacobians:
        jang = np.einsum("ki,kij->kj", n2, a_ang)
        A = np.empty((m, 2, 6))
        A[:, 0, :3], A[:, 1, :3] = -ja[:m], -ja[m:]
        A[:, 0, 3:], A[:, 1, 3:] = jang[:m], jang[m:]
    else:
        A = np.zeros((0, 2, 6))
    return _Terms(r=r, A=A, cov=cov, P=P, u3=u3.reshape(2, m).T,
                  xy=np.stack([xy[:m], xy[m:]], axis=1))


def line_normal_terms(lines: LineControl, eo: np.ndarray, focal_length_mm: np.ndarray, n_photos: int):
    """``(r (m, 2), U (P, 6, 6), g_c (P, 6), v'Pv, u3 (m, 2))``: the line observations' share of
    the camera blocks of the normal equations (summed per photo)."""
    T = line_terms(lines, eo, focal_length_mm)
    At_P = np.transpose(T.A, (0, 2, 1)) @ T.P                                 # (m, 6, 2)
    U = np.zeros((n_photos, 6, 6))
    g = np.zeros((n_photos, 6))
    np.add.at(U, lines.photo_index, At_P @ T.A)
    np.add.at(g, lines.photo_index, np.einsum("kij,kj->ki", At_P, T.r))
    vtpv = float(np.einsum("ki,kij,kj->", T.r, T.P, T.r))
    return T.r, U, g, vtpv, T.u3


def line_cost(lines: LineControl, eo: np.ndarray, focal_length_mm: np.ndarray) -> float:
    """v'Pv of the line observations at *eo*; infinite when an end point is behind a camera."""
    T = line_terms(lines, eo, focal_length_mm, jacobians=False)
    if np.any(T.u3 >= 0) or not np.isfinite(T.r).all():
        return math.inf
    return float(np.einsum("ki,kij,kj->", T.r, T.P, T.r))


def line_residuals_mm(problem: Any, eo: np.ndarray) -> np.ndarray:
    """Residuals (m, 2) in mm (adjusted - observed: signed distances of the projected end points
    A, B from the measured image line) of ``problem.lines`` at *eo*."""
    return line_terms(problem.lines, eo, problem.focal_length_mm, jacobians=False).r
