r"""Where a LiDAR roof vertex (and its roof edges) should appear in a photo, and how sure that is.

**Position.**  The vertex :math:`X` (E, N, h) projects through the collinearity
equations of the photo's exterior orientation :math:`p = (X_0, Y_0, Z_0, \omega,
\varphi, \kappa)` and the camera's distortion into a pixel :math:`c = f(p, X)`.

**Uncertainty ellipse.**  With the approximate orientation's covariance
:math:`\Sigma_p` (GNSS/IMU sds, or the full 6 x 6 block of an adjustment) and
the vertex covariance :math:`\Sigma_X` from the plane intersection (the two are
independent), first-order propagation gives

.. math:: \Sigma_c = J_p \Sigma_p J_p^T + J_X \Sigma_X J_X^T ,

:math:`J_p = \partial c/\partial p` (2 x 6) and :math:`J_X = \partial c /
\partial X` (2 x 3).  The Jacobians are taken by central differences of the
full projection (distortion included; steps 1 mm and 1 micro-radian, whose
truncation error is far below a pixel), vectorised over all points of a photo.
The ellipse of :math:`k\,\sigma` has semi-axes :math:`k\sqrt{\lambda_{1,2}}` of
the eigenvalues; a 2-D normal lies inside :math:`k = 3.03` with 99 %.

**Roof edges.**  Two planes :math:`n_i \cdot x + d_i = 0` of a vertex meet in the
line through the vertex with direction :math:`n_i \times n_j`.  Of its two
half-lines the roof edge is the one along which both faces have LiDAR points
(:func:`roof_edges` counts the points of each face within 0.6 m of the two
candidate half-lines); it is clipped where either face's points end (at most
``max_length_m``).  Its image is the segment between the projections of its
ends, each with the ellipse above.

**The edge as a control line** (:func:`edge_line_m`).  Its end points ``A, B`` are the points
of the line :math:`n_i \cdot x + d_i = 0 = n_j \cdot x + d_j` nearest the edge's ends ``P``
(the third condition :math:`t \cdot x = t \cdot P`, exact, with :math:`t = n_i \times n_j`
normalised).  A plane's error moves its distance :math:`e_i(x) = \tilde x^T \delta(n_i, d_i)`,
:math:`\tilde x = (x, 1)`, with :math:`\mathrm{cov}(e_i(x), e_i(y)) = \tilde x^T C_i \tilde y`
(the planes' 4 x 4 covariances, independent fits); with :math:`M = [n_i; n_j; t]`,
:math:`\delta x = -M^{-1} (e_i(x), e_j(x), 0)^T`, so the 6 x 6 covariance of ``(A, B)`` is
:math:`G\,\Sigma_e\,G^T` with :math:`G = \mathrm{blockdiag}(M^{-1}[:, :2], M^{-1}[:, :2])` and
:math:`\Sigma_e` the 4 x 4 covariance of :math:`(e_i(A), e_j(A), e_i(B), e_j(B))`: the cross
terms between ``A`` and ``B`` (one plane tilted moves both) included.  Along the line it is
0 (``A, B`` are defined by their position along it; the observation does not see it).

**Visibility.**  A vertex is *outside* when its ``search_sigma`` ellipse (the
window the measurement searches, 3.5 sigma) does not reach the frame (less a
margin): the smallest Mahalanobis distance :math:`\min_{x \in F} (x - c)^T
\Sigma_c^{-1} (x - c)` from the prediction :math:`c` to the frame rectangle
:math:`F` exceeds ``search_sigma``\ :sup:`2`.  Outside the frame the minimum lies on
one of its four sides; on the side :math:`x_1 = a` it is at :math:`x_2 = c_2 -
(W_{12}/W_{22}) (a - c_1)` (:math:`W = \Sigma_c^{-1}`), clipped to the side.  A
prediction off the frame whose ellipse overlaps it is a candidate (``visible``;
its reason says so): with the approximate orientation's ~20 px sd a vertex
predicted 15 px off may be 29 px inside, and the measurement searches only the
part of the ellipse on the photo.  It is *behind* when it is
behind the camera, and *occluded* when the LiDAR surface model rises above the
ray from the vertex towards the projection centre: the DSM is sampled along
the ray from ``start_m`` (clear of the vertex's own roof) in steps of
``step_m`` until the ray is above the highest DSM value; a DSM height more than
``tol_m`` above the ray hides the vertex.  :func:`dsm_of_points` makes such a surface of the LiDAR points
around a vertex: the highest point of each 0.5 m cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from .._util.frozen import frozen_array
from ..geometry.camera import Camera
from ..geometry.collinearity import project

__all__ = ["Prediction", "RoofEdge", "pixel_positions", "pixel_jacobians", "predict_points", "dsm_of_points",
           "occluded", "roof_edges", "predict_edges", "ellipse_axes", "face_labels", "edge_line_m",
           "frame_distance_sigma", "VISIBILITY"]

#: visibility statuses of a prediction and their meaning
VISIBILITY: dict[str, str] = {
    "visible": "on the photo and not hidden by the LiDAR surface",
    "outside": "predicted off the photo, and its search ellipse does not reach the photo either",
    "behind": "behind the camera",
    "occluded": "hidden by the LiDAR surface between the vertex and the camera",
}

_STEPS = np.array([1e-3, 1e-3, 1e-3, 1e-6, 1e-6, 1e-6])


def pixel_positions(camera: Camera, eo: Any, xyz_m: Any) -> np.ndarray:
    """(N, 2) pixel column, row of points on one photo; NaN behind the camera or far off the frame.

    Parameters
    ----------
    camera : Camera
    eo : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad); or (N, 6) one per point
    xyz_m : (N, 3) E, N, h (m)
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(p), 2), np.nan)
    if len(p) == 0:
        return out
    eo_rows = np.broadcast_to(np.asarray(eo, dtype=np.float64).reshape(-1, 6), (len(p), 6))
    with np.errstate(divide="ignore", invalid="ignore"):
        xy, u3 = project(np.ascontiguousarray(eo_rows), p, np.full(len(p), float(camera.focal_length_mm)))
    w, h = camera.frame_size_mm
    ok = (u3 < 0) & np.isfinite(xy).all(axis=1) & (np.abs(xy[:, 0]) < 2 * w) & (np.abs(xy[:, 1]) < 2 * h)
    if ok.any():
        out[ok] = camera.photo_to_pixel(xy[ok], on_fail="nan")
    return out


def pixel_jacobians(camera: Camera, eo: Any, xyz_m: Any) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference Jacobians of the pixel position: (N, 2, 6) w.r.t. the orientation, (N, 2, 3) the point.

    Units: px per m (X0, Y0, Z0 and the point) and px per rad (omega, phi, kappa).
    """
    x = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    eo = np.asarray(eo, dtype=np.float64).reshape(6)
    n = len(x)
    # one projection call: rows (param k, sign, point)
    eos = np.repeat(eo[None], 2 * 9 * n, axis=0).reshape(9, 2, n, 6)
    pts = np.repeat(x[None], 2 * 9, axis=0).reshape(9, 2, n, 3).copy()
    for k in range(6):
        eos[k, 0, :, k] += _STEPS[k]
        eos[k, 1, :, k] -= _STEPS[k]
    for k in range(3):
        pts[6 + k, 0, :, k] += 1e-3
        pts[6 + k, 1, :, k] -= 1e-3
    px = pixel_positions(camera, eos.reshape(-1, 6), pts.reshape(-1, 3)).reshape(9, 2, n, 2)
    steps = np.r_[_STEPS, 1e-3, 1e-3, 1e-3]
    d = (px[:, 0] - px[:, 1]) / (2 * steps[:, None, None])          # (9, n, 2)
    jac = np.transpose(d, (1, 2, 0))                                  # (n, 2, 9)
    return jac[:, :, :6], jac[:, :, 6:]


def ellipse_axes(cov_px2: Any, k: float = 1.0) -> tuple[float, float, float]:
    """Semi-axes (px, major first) of the *k*-sigma ellipse and the major axis' angle (deg from the column axis)."""
    val, vec = np.linalg.eigh(np.asarray(cov_px2, dtype=np.float64).reshape(2, 2))
    val = np.maximum(val, 0.0)
    return (k * math.sqrt(val[1]), k * math.sqrt(val[0]),
            math.degrees(math.atan2(vec[1, 1], vec[0, 1])))


def frame_distance_sigma(px: Any, cov_px2: Any, cols: tuple[float, float], rows: tuple[float, float]) -> np.ndarray:
    """(N,) smallest Mahalanobis distance (sigmas) from each prediction to the frame rectangle; 0 inside.

    Parameters
    ----------
    px : (N, 2) column, row (px)
    cov_px2 : (N, 2, 2) their covariances (px^2)
    cols, rows : (lo, hi) the rectangle's columns and rows (px)

    Examples
    --------
    >>> round(float(frame_distance_sigma([[-10.0, 5.0]], [np.diag([25.0, 25.0])], (0, 99), (0, 99))[0]), 6)
    2.0
    """
    c = np.asarray(px, dtype=np.float64).reshape(-1, 2)
    cov = np.asarray(cov_px2, dtype=np.float64).reshape(-1, 2, 2)
    out = np.full(len(c), np.inf)
    fin = np.isfinite(c).all(axis=1)
    inside = fin & (c[:, 0] >= cols[0]) & (c[:, 0] <= cols[1]) & (c[:, 1] >= rows[0]) & (c[:, 1] <= rows[1])
    out[inside] = 0.0
    todo = fin & ~inside & np.isfinite(cov).all(axis=(1, 2))   # an undefined ellipse: inf (outside)
    if not todo.any():
        return out
    w = np.linalg.pinv(cov[todo] + np.eye(2) * 1e-9)       # (M, 2, 2)
    cc = c[todo]
    best = np.full(len(cc), np.inf)
    for axis, lims, span in ((0, cols, rows), (1, rows, cols)):
        o = 1 - axis
        for a in lims:
            da = a - cc[:, axis]
            t = cc[:, o] - w[:, axis, o] / np.maximum(w[:, o, o], 1e-300) * da
            db = np.clip(t, span[0], span[1]) - cc[:, o]
            d2 = w[:, axis, axis] * da**2 + 2 * w[:, axis, o] * da * db + w[:, o, o] * db**2
            best = np.minimum(best, d2)
    out[todo] = np.sqrt(np.maximum(best, 0.0))
    return out


@dataclass(frozen=True, eq=False)
class Prediction:
    """The predicted image position of a point on one photo.

    Attributes
    ----------
    point, photo : str
    px : (2,) float
        Column, row (px); NaN when behind the camera.
    cov_px2 : (2, 2) float
        Covariance (px^2) from the orientation's and the point's covariance.
    status : str
        One of :data:`VISIBILITY`; ``bool(pred)`` is ``status == "visible"``.
    reason : str
    """

    point: str
    photo: str
    px: np.ndarray
    cov_px2: np.ndarray
    status: str = "visible"
    reason: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "px", frozen_array(self.px, shape=(2,)))
        object.__setattr__(self, "cov_px2", frozen_array(self.cov_px2, shape=(2, 2)))

    def __bool__(self) -> bool:
        return self.status == "visible"

    @property
    def sd_max_px(self) -> float:
        """Semi-major axis of the 1-sigma ellipse (px)."""
        return ellipse_axes(self.cov_px2)[0]


def dsm_of_points(xyz: np.ndarray, cell_m: float = 0.5) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The highest point of each *cell_m* cell as a surface ``dsm(e, n) -> h`` (NaN outside the points' cells)."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(xyz) == 0:
        return lambda e, n: np.full(np.shape(e), np.nan)
    lo = xyz[:, :2].min(axis=0)
    ij = np.floor((xyz[:, :2] - lo) / cell_m).astype(np.int64)
    shape = ij.max(axis=0) + 1
    grid = np.full(tuple(int(v) for v in shape), -np.inf)
    np.maximum.at(grid, (ij[:, 0], ij[:, 1]), xyz[:, 2])
    grid[~np.isfinite(grid)] = np.nan

    def dsm(e: np.ndarray, n: np.ndarray) -> np.ndarray:
        i = np.floor((np.asarray(e, dtype=np.float64) - lo[0]) / cell_m).astype(np.int64)
        j = np.floor((np.asarray(n, dtype=np.float64) - lo[1]) / cell_m).astype(np.int64)
        inside = (i >= 0) & (j >= 0) & (i < grid.shape[0]) & (j < grid.shape[1])
        out = np.full(i.shape, np.nan)
        out[inside] = grid[i[inside], j[inside]]
        return out

    return dsm


def occluded(dsm: Callable[[np.ndarray, np.ndarray], np.ndarray], xyz_m: Any, centre_m: Any, *,
             step_m: float = 0.25, start_m: float = 0.7, tol_m: float = 0.3) -> np.ndarray:
    """(N,) bool: the DSM rises more than *tol_m* above the ray from each point towards *centre_m*.

    Parameters
    ----------
    dsm : callable ``dsm(e, n) -> h`` (m), vectorised; NaN where unknown (never hides)
    xyz_m : (N, 3) points E, N, h (m)
    centre_m : (3,) the projection centre
    step_m, start_m, tol_m : float
        Sampling step along the ray (plan), first sample, and tolerance (see the module docstring).
    """
    x = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(centre_m, dtype=np.float64).reshape(3)
    d = c - x
    plan = np.hypot(d[:, 0], d[:, 1])
    rise = d[:, 2] / np.maximum(plan, 1e-9)                          # height gained per plan metre
    # the ray climbs; beyond 40 m of plan distance it is far above any roof (rise >= 0.5 typical)
    reach = np.minimum(plan, np.where(rise > 0, 40.0 / np.maximum(rise, 0.05), 0.0))
    t = np.arange(start_m, max(float(reach.max(initial=0.0)), start_m) + step_m, step_m)
    u = d[:, :2] / np.maximum(plan, 1e-9)[:, None]
    e = x[:, 0:1] + u[:, 0:1] * t[None]
    n = x[:, 1:2] + u[:, 1:2] * t[None]
    h_ray = x[:, 2:3] + rise[:, None] * t[None]
    h = np.asarray(dsm(e.ravel(), n.ravel()), dtype=np.float64).reshape(e.shape)
    above = (h > h_ray + tol_m) & (t[None] <= reach[:, None])
    return np.asarray(np.nan_to_num(above, nan=False).any(axis=1))


def predict_points(camera: Camera, eo: Any, eo_cov: Any, xyz_m: Any, xyz_cov: Any, *,
                   points: Sequence[str] | None = None, photo: str = "",
                   dsm: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
                   margin_px: float = 0.0, search_sigma: float = 0.0) -> list[Prediction]:
    """Predicted pixel positions with their covariance and visibility on one photo.

    Parameters
    ----------
    camera : Camera
    eo : (6,) approximate X0, Y0, Z0 (m), omega, phi, kappa (rad)
    eo_cov : (6, 6) its covariance (m^2, rad^2), or (6,) sds
    xyz_m : (N, 3) points E, N, h (m)
    xyz_cov : (N, 3, 3) their covariances (m^2)
    points : N point ids (default "0", "1", ...)
    photo : str
    dsm : callable, optional
        LiDAR surface ``dsm(e, n) -> h`` for the occlusion test (:func:`occluded`).
    margin_px : float
        The frame less this margin (px) is what the ellipse must reach.
    search_sigma : float
        "outside" only when the ellipse of this many sigmas (the measurement's search,
        ``MeasureParams.search_sigma``, 3.5, with ``MeasureParams(border="fit")``) does not reach the
        frame; 0 (the default): the predicted pixel alone.

    Returns
    -------
    list of Prediction, one per point in order.

    Examples
    --------
    >>> from lidarcat.geometry.camera import Camera
    >>> cam = Camera("c", 35.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.036, 0.036, 1000, 750)
    >>> eo = [0.0, 0.0, 200.0, 0.0, 0.0, 0.0]
    >>> pr = predict_points(cam, eo, np.r_[1.0, 1.0, 1.0, 0, 0, 0], [[0.0, 0.0, 0.0]], np.zeros((1, 3, 3)))
    >>> np.round(pr[0].px, 6).tolist(), round(float(pr[0].cov_px2[0, 0]), 3)   # 35/200/0.036 px per m
    ([499.5, 374.5], 23.63)
    """
    x = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    xc = np.asarray(xyz_cov, dtype=np.float64).reshape(-1, 3, 3)
    ec = np.asarray(eo_cov, dtype=np.float64)
    ec = np.diag(ec**2) if ec.shape == (6,) else ec.reshape(6, 6)
    ids = [str(i) for i in range(len(x))] if points is None else [str(p) for p in points]
    px = pixel_positions(camera, eo, x)
    jp, jx = pixel_jacobians(camera, eo, x)
    cov = jp @ ec @ jp.transpose(0, 2, 1) + jx @ xc @ jx.transpose(0, 2, 1)
    hidden = occluded(dsm, x, np.asarray(eo, dtype=np.float64)[:3]) if dsm is not None else np.zeros(len(x), bool)
    lo = -0.5 + margin_px
    reach = frame_distance_sigma(px, cov, (lo, camera.columns_px - 0.5 - margin_px),
                                 (lo, camera.rows_px - 0.5 - margin_px)) if search_sigma > 0 else \
        np.full(len(x), np.inf)       # without a search ellipse a prediction off the frame is outside
    out = []
    for k in range(len(x)):
        status, reason = "visible", ""
        if not np.isfinite(px[k]).all():
            status, reason = "behind", "behind the camera or far off the frame"
        elif not camera.contains(px[k][None], margin_px=-margin_px)[0]:
            frame = f"{camera.columns_px} x {camera.rows_px} frame" + (f" less a {margin_px:g} px margin"
                                                                        if margin_px else "")
            where = f"predicted at column {px[k, 0]:.1f}, row {px[k, 1]:.1f}"
            if reach[k] > search_sigma:
                status, reason = "outside", f"{where}: off the {frame}"   # its ellipse too
            elif hidden[k]:
                status, reason = "occluded", "the LiDAR surface rises above the ray to the camera"
            else:
                reason = (f"{where}: off the {frame}, {reach[k]:.1f} sigma away: within its "
                          f"{search_sigma:g}-sigma ellipse, searched on the photo")
        elif hidden[k]:
            status, reason = "occluded", "the LiDAR surface rises above the ray to the camera"
        out.append(Prediction(ids[k], str(photo), px[k], cov[k], status, reason))
    return out


@dataclass(frozen=True, eq=False)
class RoofEdge:
    """A roof edge at a vertex: the half-line where two of its planes meet, clipped to the roof.

    Attributes
    ----------
    planes : (2,) int
        Indices of the two planes (in the vertex's plane list).
    start_m, end_m : (3,) float
        The vertex and the far end of the supported edge (E, N, h, m).
    n_support : int
        LiDAR points of the weaker face within 0.6 m of the edge.
    """

    planes: tuple[int, int]
    start_m: np.ndarray
    end_m: np.ndarray
    n_support: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_m", frozen_array(self.start_m, shape=(3,)))
        object.__setattr__(self, "end_m", frozen_array(self.end_m, shape=(3,)))

    @property
    def length_m(self) -> float:
        return float(np.linalg.norm(self.end_m - self.start_m))


def face_labels(planes: Sequence[Any], xyz: np.ndarray, tol_m: float) -> np.ndarray:
    """Each point's nearest plane (index) when within *tol_m* of it, else -1."""
    dist = np.abs(np.column_stack([pl.distance(xyz) for pl in planes]))
    lab = np.argmin(dist, axis=1)
    return np.where(dist[np.arange(len(xyz)), lab] <= tol_m, lab, -1)


def roof_edges(vertex_m: Any, planes: Sequence[Any], xyz_m: Any, *, max_length_m: float = 4.0,
               min_length_m: float = 0.8, min_support: int = 4, radius_m: float = 6.0) -> list[RoofEdge]:
    """The roof edges at a vertex: for each pair of its planes, the supported half-line of their intersection.

    Parameters
    ----------
    vertex_m : (3,) E, N, h (m)
    planes : sequence of :class:`~lidarcat.control.planes.Plane` (3 or more)
    xyz_m : (N, 3) LiDAR points around the vertex (m)
    max_length_m, min_length_m : float
        Clip the edge to at most this length; drop edges shorter than the minimum.
    min_support : int
        Points of each face needed along the edge.
    radius_m : float
        Points farther than this from the vertex in plan are ignored.

    Returns
    -------
    list of RoofEdge (pairs of planes that meet in a roof edge; ridge, hips, valleys).
    """
    v = np.asarray(vertex_m, dtype=np.float64).reshape(3)
    xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    xyz = xyz[np.hypot(xyz[:, 0] - v[0], xyz[:, 1] - v[1]) <= radius_m]
    if len(xyz) == 0 or len(planes) < 2:
        return []
    tol = max(0.15, 3.0 * max(float(getattr(pl, "rms_m", 0.05) or 0.05) for pl in planes))
    lab = face_labels(planes, xyz, tol)
    rel = xyz[:, :2] - v[:2]
    out = []
    for i in range(len(planes)):
        for j in range(i + 1, len(planes)):
            d = np.cross(planes[i].n, planes[j].n)
            nd = float(np.linalg.norm(d))
            if nd < 0.05:
                continue
            d = d / nd
            dp = d[:2] / max(float(np.hypot(*d[:2])), 1e-9)
            along = rel @ dp
            across = np.abs(rel @ np.array([-dp[1], dp[0]]))
            best = None
            for sgn in (1.0, -1.0):
                t = sgn * along
                near = (across <= 0.6) & (t > 0.2) & (t <= max_length_m / max(float(np.hypot(*d[:2])), 0.2))
                ci, cj = int(np.sum(near & (lab == i))), int(np.sum(near & (lab == j)))
                if min(ci, cj) < min_support:
                    continue
                # clipped where the weaker face's points end (90th percentile of the distance along)
                reach = min(float(np.percentile(t[near & (lab == i)], 90)), float(np.percentile(t[near & (lab == j)], 90)))
                if best is None or min(ci, cj) > best[1]:
                    best = (sgn, min(ci, cj), reach)
            if best is None:
                continue
            sgn, cnt, reach = best
            dd = sgn * d
            length = min(max_length_m, reach / max(float(np.hypot(*dd[:2])), 1e-9))
            if length < min_length_m:
                continue
            out.append(RoofEdge((i, j), v, v + length * dd, cnt))
    return out


def predict_edges(camera: Camera, eo: Any, eo_cov: Any, edges: Sequence[RoofEdge], vertex_cov: Any) -> list[dict]:
    """Image segments of roof edges: per edge ``{"planes", "px0", "px1", "cov0", "cov1"}`` (px, px^2).

    Both ends carry the vertex covariance (the far end's own is larger along the edge, which
    does not move the line; across it the planes' fits agree with the vertex to first order).
    """
    if not edges:
        return []
    ends = np.array([[e.start_m, e.end_m] for e in edges]).reshape(-1, 3)
    covs = np.repeat(np.asarray(vertex_cov, dtype=np.float64).reshape(1, 3, 3), len(ends), axis=0)
    pr = predict_points(camera, eo, eo_cov, ends, covs)
    return [{"planes": e.planes, "px0": pr[2 * k].px, "px1": pr[2 * k + 1].px,
             "cov0": pr[2 * k].cov_px2, "cov1": pr[2 * k + 1].cov_px2} for k, e in enumerate(edges)]


def edge_line_m(plane_i: Any, plane_j: Any, ends_m: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The intersection line of two fitted planes as a control line: end points and their covariance.

    Parameters
    ----------
    plane_i, plane_j : :class:`~lidarcat.control.planes.Plane`
        With ``n``, ``d``, ``cov`` (4 x 4 of ``(n, d)``) and ``cov_at``.
    ends_m : (2, 3)
        Two points near the line (e.g. the vertex and the edge's far end, m).

    Returns
    -------
    a_m, b_m : (3,) the points of the line nearest *ends_m* (m)
    cov_m2 : (6, 6) covariance of ``(A, B)`` (module docstring; m^2)

    Examples
    --------
    >>> from lidarcat.control.planes import Plane
    >>> c = np.diag([1e-6, 1e-6, 1e-6, 1e-4])
    >>> pi = Plane(n=[0.5, 0, 0.866], d=-8.66, cov=c, centroid_m=[0, 0, 10])
    >>> pj = Plane(n=[-0.5, 0, 0.866], d=-8.66, cov=c, centroid_m=[0, 0, 10])
    >>> a, b, cov = edge_line_m(pi, pj, [[0.1, 0, 10], [0.1, 4, 10.2]])
    >>> np.round(a, 6).tolist(), np.round(b, 6).tolist(), round(float(cov[1, 1]), 12)
    ([0.0, 0.0, 10.0], [0.0, 4.0, 10.0], 0.0)
    """
    ends = np.asarray(ends_m, dtype=np.float64).reshape(2, 3)
    origin = 0.5 * (np.asarray(plane_i.centroid_m, float) + np.asarray(plane_j.centroid_m, float))
    ni, nj = np.asarray(plane_i.n, float), np.asarray(plane_j.n, float)
    t = np.cross(ni, nj)
    t = t / max(float(np.linalg.norm(t)), 1e-12)
    ci, cj = plane_i.cov_at(origin), plane_j.cov_at(origin)
    di, dj = plane_i.offset_at(origin), plane_j.offset_at(origin)
    m_mat = np.array([ni, nj, t])
    minv = np.linalg.inv(m_mat)
    rel = ends - origin
    pts = np.array([minv @ np.array([-di, -dj, float(t @ r)]) for r in rel])     # (2, 3) relative to origin
    xh = np.column_stack([pts, np.ones(2)])                                         # (2, 4)
    # (e_i(A), e_j(A), e_i(B), e_j(B)): the planes independent, each shared by A and B
    se = np.zeros((4, 4))
    for k in range(2):
        for m in range(2):
            se[2 * k, 2 * m] = xh[k] @ ci @ xh[m]
            se[2 * k + 1, 2 * m + 1] = xh[k] @ cj @ xh[m]
    g = np.zeros((6, 4))
    g[:3, :2] = -minv[:, :2]
    g[3:, 2:] = -minv[:, :2]
    cov = g @ se @ g.T
    return pts[0] + origin, pts[1] + origin, 0.5 * (cov + cov.T)
