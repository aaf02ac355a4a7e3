r"""Roof facets from airborne LiDAR: Delaunay triangles, slope, grouping, plane fits.

This module implements thesis sections 3.2.3-3.2.6 (Fierro Sanhueza 2007) and a
robust alternative that works on steep European roofs:

1. **Clip** the points around the approximate vertex (radius 2.5-5 m in the
   thesis) and optionally pre-filter heights (thesis: mean height +- 2 m).
2. **Delaunay triangles** of the clip in plan (``scipy.spatial.Delaunay``).
   For each triangle, with :math:`x_0` its highest vertex and
   :math:`u = (r, s, t)`, :math:`v = (m, n, p)` the edges to the two others,
   the plane (eq. 25-31) is

   .. math:: a = sp - tn,\quad b = -(rp - tm),\quad c = rn - sm,\quad
             d = -(a x_0 + b y_0 + c z_0)

   and its slope against the horizontal plane :math:`n_H = (0, 0, 1)` (eq. 32)
   is :math:`\cos\theta = |c| / \|(a, b, c)\|`.
3. **Slope window**: triangles outside ``[slope_min_deg, slope_max_deg]`` are
   dropped (thesis 4-30 deg: flat chimney tops below, walls above).
4. **Grouping into faces**

   * ``method="thesis"``: triangles are grouped by the direction of their
     normal (the thesis uses the algebraic signs of a, b; we cluster the
     aspect, which is the same on axis-aligned roofs and also works on rotated
     ones), up to ``max_planes`` directions;
   * ``method="ransac"``: sequential RANSAC (plane with most inliers within
     the distance and normal tolerances, its largest connected patch, repeat),
     then the same merge / nearest-face assignment as "region";
   * ``method="region"`` (default): region growing on a k-nearest-neighbour
     graph with local PCA normals, accepting a neighbour when its normal is
     within ``angle_tol_deg`` of the region's plane and its distance to the
     plane below ``dist_tol_m``; coplanar regions are merged, thin strips of
     blended normals along edges dropped, and every point is given to a face
     by its plan position relative to the faces' intersection lines (the
     height noise does not enter, so the faces are not biased), points within
     ~1 sigma of a line being left out, as are the points on a face's outer
     edge (eaves, verges: facade points there would pull the face down).
     Assignment and fit are iterated twice.

5. **Plane fit by the combined (Gauss-Helmert) adjustment** (eq. 33-37). The
   condition of point *i* is :math:`n \cdot (x_i + v_i) + d = 0` with
   :math:`\|n\| = 1`; the observations :math:`x_i = (E, N, h)` carry their
   own covariance :math:`\Sigma_i = \mathrm{diag}(s_E^2, s_N^2, s_h^2)`.
   Linearised: :math:`A\,\delta + B\,v + w = 0` with
   :math:`A_i = ((x_i + v_i)^T, 1)` at the adjusted observations (Pope 1972),
   :math:`B_i = n^T`, :math:`w_i = n\cdot x_i + d`;
   the equivalent weight of a condition is
   :math:`1 / (n^T \Sigma_i n)`.  The normal equations are bordered by the
   constraint :math:`n^T \delta n = 0`; the inverse of the bordered matrix
   gives the 4x4 cofactor matrix of :math:`(n, d)`, scaled by the a-posteriori
   variance factor :math:`\hat\sigma_0^2 = \sum w_i r_i^2 / (m - 3)` times
   :math:`f / (f - 2)`, f = m - 3 (the standardised error is t-distributed).
   The residuals are :math:`v_i = -\Sigma_i n\, w_i r_i`.
6. **Iterative rejection**: points whose residual exceeds the threshold are
   removed and the plane refitted, until none remains (thesis: 0.15 m on the
   height residual; the thesis preset tests the vertical distance to the
   plane, see :func:`fit_plane`).

Coordinates are reduced to the clip centroid internally, so national grid
coordinates (E ~ 7e6 m) lose no precision.

**Table 4 normalisation.**  The thesis prints (a, b, c, d) with
:math:`\|(a,b,c)\| \approx 0.72-0.74` and d ~ 3e5-9e5.  The printed standard
deviations satisfy :math:`s_b / s_a = E/N` of point 708 to three digits for all
three planes and :math:`s_d \approx 10^{-11}`: d was *held fixed* (the datum of
the homogeneous plane equation was fixed on d, its value coming from the
approximate plane of a seed Delaunay triangle, whose
:math:`\|(a,b,c)\|` is twice the triangle area, ~0.36 m^2 at the 1-2 pts/m^2
of the survey).  :meth:`Plane.thesis_form` reproduces that layout for any
chosen d.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from ..errors import ClipError

__all__ = [
    "Plane",
    "ExtractionParams",
    "PRESETS",
    "get_params",
    "triangle_planes",
    "triangle_slope_aspect",
    "delaunay_facets",
    "fit_plane",
    "PlaneFit",
    "segment_faces",
]

log = logging.getLogger(__name__)


# --------------------------------------------------------------------------- Plane
@dataclass(frozen=True, eq=False)
class Plane:
    """A fitted roof plane :math:`n \\cdot x + d = 0` (metres, E N h).

    Parameters
    ----------
    n : (3,) float
        Unit normal, oriented upwards (``n[2] >= 0``).
    d : float
        Offset in metres.
    cov : (4, 4) float
        Covariance of ``(n_E, n_N, n_h, d)`` (absolute coordinates).
    centroid_m : (3,) float
        Centroid of the points used (E, N, h).
    n_used, n_rejected : int
        Points in the final fit and points removed by the residual test.
    rms_m : float
        RMS of the orthogonal point-to-plane distances of the points used.
    label : int
        Face number within its clip (for figures and the planes file).

    Examples
    --------
    >>> p = Plane(n=[0, 0, 1], d=-10.0, cov=np.eye(4) * 1e-6, centroid_m=[0, 0, 10])
    >>> round(p.slope_deg, 6), round(float(p.distance([[0, 0, 10.5]])[0]), 6)
    (0.0, 0.5)
    """

    n: np.ndarray
    d: float
    cov: np.ndarray
    centroid_m: np.ndarray
    n_used: int = 0
    n_rejected: int = 0
    rms_m: float = math.nan
    label: int = 0

    def __post_init__(self) -> None:
        n = np.asarray(self.n, dtype=np.float64).reshape(3)
        norm = float(np.linalg.norm(n))
        if not np.isfinite(norm) or norm == 0.0:
            raise ValueError("plane normal must be a finite non-zero vector")
        sign = -1.0 if n[2] < 0 else 1.0
        object.__setattr__(self, "n", frozen_array(sign * n / norm, shape=(3,)))
        object.__setattr__(self, "d", float(sign * self.d / norm))
        cov = np.asarray(self.cov, dtype=np.float64).reshape(4, 4)
        # a sign flip of (n, d) leaves the covariance unchanged
        object.__setattr__(self, "cov", frozen_array(cov / norm**2, shape=(4, 4)))
        object.__setattr__(self, "centroid_m", frozen_array(self.centroid_m, shape=(3,)))

    # ----------------------------------------------------------- geometry
    @property
    def slope_deg(self) -> float:
        """Angle between the plane and the horizontal, degrees (eq. 32)."""
        return float(np.degrees(np.arccos(np.clip(abs(self.n[2]), 0.0, 1.0))))

    @property
    def aspect_deg(self) -> float:
        """Direction the face looks to (down-slope), degrees clockwise from North."""
        if math.hypot(self.n[0], self.n[1]) < 1e-12:
            return math.nan
        return float(np.degrees(np.arctan2(self.n[0], self.n[1])) % 360.0)

    def distance(self, xyz: Any) -> np.ndarray:
        """Signed orthogonal distance (m) of points (N, 3) to the plane."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return (xyz - self.centroid_m) @ self.n + self.offset_at(self.centroid_m)

    def height_at(self, e: Any, n: Any) -> np.ndarray:
        """Plane height (m) above given E, N (arrays broadcast)."""
        c = self.centroid_m
        d0 = self.offset_at(c)
        e = np.asarray(e, dtype=np.float64) - c[0]
        nn = np.asarray(n, dtype=np.float64) - c[1]
        return c[2] - (self.n[0] * e + self.n[1] * nn + d0) / self.n[2]

    def offset_at(self, origin: Any) -> float:
        """Offset of the plane in a frame whose origin is *origin* (3,)."""
        return float(self.d + self.n @ np.asarray(origin, dtype=np.float64))

    def cov_at(self, origin: Any) -> np.ndarray:
        """4x4 covariance of ``(n, d_o)`` with d in a frame centred at *origin*."""
        k = np.eye(4)
        k[3, :3] = np.asarray(origin, dtype=np.float64)
        return k @ self.cov @ k.T

    @property
    def sd_n(self) -> np.ndarray:
        """Standard deviations of the normal components (3,)."""
        return np.sqrt(np.maximum(np.diag(self.cov)[:3], 0.0))

    @property
    def sd_offset_m(self) -> float:
        """Standard deviation (m) of the plane position at its centroid."""
        return float(math.sqrt(max(self.cov_at(self.centroid_m)[3, 3], 0.0)))

    @property
    def sd_slope_deg(self) -> float:
        """Standard deviation of the slope, degrees (first-order)."""
        # slope = arccos(n_z), d slope / d n_z = -1 / sin(slope)
        s = math.sin(math.radians(self.slope_deg))
        if s < 1e-9:
            return math.nan
        return math.degrees(math.sqrt(max(self.cov[2, 2], 0.0)) / s)

    # ----------------------------------------------------------- thesis form
    def thesis_form(self, d: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Plane as printed in thesis Table 4: ``(a, b, c, d)`` with d held fixed.

        Parameters
        ----------
        d : float, optional
            The value d is fixed at (the datum of the homogeneous equation).
            Default: the unit-normal offset, i.e. (a, b, c) is the unit normal.

        Returns
        -------
        abcd : (4,) float
            Parameters with ``a E + b N + c h + d = 0``.
        sd : (4,) float
            Their standard deviations in that datum (``sd[3] == 0``: d fixed).
            With E, N of Brazilian UTM, ``sd_b / sd_a = E / N`` as in Table 4.
        """
        d_fix = self.d if d is None else float(d)
        if self.d == 0.0:
            raise ValueError("plane passes through the origin; d cannot be the datum")
        k = d_fix / self.d
        abcd = np.append(k * self.n, d_fix)
        # q = n / d is datum free; (a, b, c) = d_fix * q
        j = np.zeros((3, 4))
        j[:, :3] = np.eye(3) / self.d
        j[:, 3] = -self.n / self.d**2
        cov_q = j @ self.cov @ j.T
        sd = np.append(abs(d_fix) * np.sqrt(np.maximum(np.diag(cov_q), 0.0)), 0.0)
        return abcd, sd

    @classmethod
    def from_abcd(cls, abcd: Any, *, centroid_m: Any = None, cov: Any = None, **kw: Any) -> "Plane":
        """Plane from ``a E + b N + c h + d = 0`` (any scale, e.g. thesis Table 4)."""
        a = np.asarray(abcd, dtype=np.float64).reshape(4)
        norm = float(np.linalg.norm(a[:3]))
        n = a[:3] / norm
        d = a[3] / norm
        if centroid_m is None:
            centroid_m = -d * n  # foot of the perpendicular from the origin
        return cls(n=n, d=d, cov=np.zeros((4, 4)) if cov is None else cov,
                   centroid_m=centroid_m, **kw)

    def to_dict(self) -> dict[str, Any]:
        abcd, sd = self.thesis_form()
        return {
            "label": self.label, "a": abcd[0], "b": abcd[1], "c": abcd[2], "d": abcd[3],
            "sd_a": sd[0], "sd_b": sd[1], "sd_c": sd[2], "sd_offset_m": self.sd_offset_m,
            "n_used": self.n_used, "n_rejected": self.n_rejected, "rms_m": self.rms_m,
            "slope_deg": self.slope_deg, "aspect_deg": self.aspect_deg,
            "centroid_m": self.centroid_m,
        }


def _translated(pl: Plane, shift_m: np.ndarray, **changes: Any) -> Plane:
    """*pl*, given in a frame whose origin is at *shift_m*, in the outer frame.

    ``x_out = x_in + shift``: ``d_out = d_in - n . shift`` and the covariance of
    ``(n, d)`` moves accordingly (:meth:`Plane.cov_at` at ``-shift``).
    """
    shift = np.asarray(shift_m, dtype=np.float64)
    return dataclasses.replace(pl, n=pl.n, d=pl.d - float(pl.n @ shift), cov=pl.cov_at(-shift),
                               centroid_m=pl.centroid_m + shift, **changes)


# --------------------------------------------------------------------------- params
_METHODS = ("region", "ransac", "thesis")
_RESID = ("normal", "vertical", "height")
_HFILT = (None, "thesis", "robust")


@dataclass(frozen=True)
class ExtractionParams:
    """Settings of one roof extraction.  Units in the names; defaults = preset "default".

    The ``thesis`` preset (:data:`PRESETS`) reproduces Fierro Sanhueza (2007):
    radius 5 m, heights within +-2 m of the clip mean, slope window 4-30 deg,
    grouping by normal direction, height residuals above 0.15 m rejected, point
    sds from the scanner specification (0.50 m plan, 0.15 m height).
    """

    #: grouping of triangles / points into faces: "region", "ransac" or "thesis"
    method: str = "region"
    #: clip radius around the approximate position (m)
    radius_m: float = 8.0
    #: height pre-filter: None, "thesis" (clip mean +- window) or "robust" (+- window
    #: around the median of the clip's upper half, the roof): the filters of
    #: :func:`lidarcat.lidar.clip`, see :func:`lidarcat.lidar.clipping.height_window_mask`
    height_filter: str | None = None
    #: half-width of the thesis height window (m)
    height_window_m: float = 2.0
    #: region / ransac: leave out points on the outer edges of faces (eaves, verges),
    #: where facade points would bias the face downwards
    drop_outer_edges: bool = True
    #: slope window of triangles / faces (deg)
    slope_min_deg: float = 4.0
    slope_max_deg: float = 65.0
    #: triangles with an edge longer than this are dropped; None = 4 x median edge
    max_edge_m: float | None = None
    #: thesis method: aspect tolerance of a direction group (deg)
    aspect_tol_deg: float = 35.0
    #: region growing: neighbours for local normals, angle and distance tolerances
    k_neighbours: int = 12
    angle_tol_deg: float = 20.0
    #: None = 3 x noise estimated from the local planes, at least 0.05 m
    dist_tol_m: float | None = None
    #: residual threshold of the iterative rejection; None = 3.5 sigma (MAD), >= 0.03 m
    residual_threshold_m: float | None = None
    #: residual tested: "normal" (orthogonal), "vertical" (height difference to the
    #: plane, thesis 4.2.2) or "height" (GH adjusted-height residual v_h)
    residual_kind: str = "normal"
    #: a-priori sds of every LiDAR point (m); their ratio sets the GH weights.  They must
    #: describe the points' random noise: overstating the plan noise against the height
    #: noise biases the fitted slopes (errors in variables) and lifts apexes
    sd_en_m: float = 0.10
    sd_h_m: float = 0.05
    #: scale the covariance by the a-posteriori variance factor
    posterior_variance: bool = True
    #: minimum points of a face (thesis: 6)
    min_points: int = 6
    #: faces considered per clip (largest first)
    max_planes: int = 12
    #: intersection: min angle between two normals (deg) and min |det| of unit normals
    min_dihedral_deg: float = 3.0
    min_det: float = 0.002
    #: max plan distance (m) from a face's nearest point to the vertex; None = max(1.5, 4 x spacing)
    support_m: float | None = None
    #: search radius: max plan distance (m) of the vertex from the approximate
    #: position; None = half the clip radius (4 m at the default 8 m, 2.5 m in the thesis preset)
    max_offset_m: float | None = None
    #: a vertex whose predicted 3-D sd exceeds this is "imprecise" (m)
    max_sd_m: float = 0.5
    #: extra planes join the vertex when their distance from it is below join_sigma x its
    #: sd plus half the plane's RMS, with a point of the plane within support_m
    join_sigma: float = 3.0

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {', '.join(_METHODS)}, got {self.method!r}")
        if self.residual_kind not in _RESID:
            raise ValueError(f"residual_kind must be one of {', '.join(_RESID)}, got {self.residual_kind!r}")
        if self.height_filter not in _HFILT:
            raise ValueError(f"height_filter must be None, 'thesis' or 'robust', got {self.height_filter!r}")
        if not (0 <= self.slope_min_deg < self.slope_max_deg <= 90):
            raise ValueError("slope window must satisfy 0 <= slope_min_deg < slope_max_deg <= 90")
        if not self.height_window_m > 0:
            raise ValueError(f"height_window_m must be positive, got {self.height_window_m}")
        if self.radius_m <= 0:
            raise ValueError(f"radius_m must be positive, got {self.radius_m}")
        if self.min_points < 4:
            raise ValueError("min_points must be >= 4 (a plane has 3 degrees of freedom)")
        if self.sd_en_m <= 0 or self.sd_h_m <= 0:
            raise ValueError("sd_en_m and sd_h_m must be positive")
        if self.residual_threshold_m is not None and not self.residual_threshold_m > 0:
            raise ValueError(f"residual_threshold_m must be positive, got {self.residual_threshold_m}")
        if self.max_offset_m is not None and self.max_offset_m <= 0:
            raise ValueError(f"max_offset_m must be positive, got {self.max_offset_m}")

    def replace(self, **kw: Any) -> "ExtractionParams":
        """Copy with some fields changed (unknown names raise TypeError)."""
        return dataclasses.replace(self, **kw)


PRESETS: dict[str, ExtractionParams] = {
    "default": ExtractionParams(),
    "thesis": ExtractionParams(
        method="thesis", radius_m=5.0, height_filter="thesis", height_window_m=2.0,
        slope_min_deg=4.0, slope_max_deg=30.0, residual_threshold_m=0.15,
        residual_kind="vertical", sd_en_m=0.50, sd_h_m=0.15, min_points=6, max_planes=4,
        aspect_tol_deg=35.0, max_sd_m=2.0,
    ),
}


def get_params(params: ExtractionParams | str | None = None, **overrides: Any) -> ExtractionParams:
    """Resolve a preset name or params object, then apply *overrides*.

    >>> get_params("thesis").slope_max_deg
    30.0
    >>> get_params("default", radius_m=12).radius_m
    12
    """
    if params is None:
        params = "default"
    if isinstance(params, str):
        if params not in PRESETS:
            raise ValueError(f"unknown preset {params!r}; choose one of {', '.join(PRESETS)}")
        params = PRESETS[params]
    overrides = {k: v for k, v in overrides.items() if v is not None}
    return params.replace(**overrides) if overrides else params


# --------------------------------------------------------------------------- triangles
def triangle_planes(xyz: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """Plane ``(a, b, c, d)`` of every triangle by eq. 25-31 (normal up, not unit).

    Parameters
    ----------
    xyz : (N, 3) float
        Points (any origin).
    simplices : (T, 3) int
        Vertex indices of the triangles.

    Returns
    -------
    (T, 4) float
        ``a, b, c`` = cross product of the edges from the highest vertex
        (length = twice the triangle area), ``d = -(a x0 + b y0 + c z0)``.

    >>> xyz = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 1]])
    >>> (triangle_planes(xyz, np.array([[0, 1, 2]])).round(6) + 0.0).tolist()
    [[0.0, -1.0, 1.0, 0.0]]
    """
    tri = xyz[simplices]  # (T, 3, 3)
    top = np.argmax(tri[:, :, 2], axis=1)
    idx = np.arange(len(tri))
    p0 = tri[idx, top]
    p1 = tri[idx, (top + 1) % 3]
    p2 = tri[idx, (top + 2) % 3]
    r, s, t = (p1 - p0).T
    m, n, p = (p2 - p0).T
    a = s * p - t * n  # eq. 28
    b = -(r * p - t * m)  # eq. 29
    c = r * n - s * m  # eq. 30
    sign = np.where(c < 0, -1.0, 1.0)
    a, b, c = a * sign, b * sign, c * sign
    d = -(a * p0[:, 0] + b * p0[:, 1] + c * p0[:, 2])  # eq. 31
    return np.column_stack([a, b, c, d])


def triangle_slope_aspect(abc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slope (eq. 32, deg) and aspect (deg from North, clockwise) of normals (T, 3)."""
    abc = np.asarray(abc, dtype=np.float64)[:, :3]
    norm = np.linalg.norm(abc, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.abs(abc[:, 2]) / norm
    slope = np.degrees(np.arccos(np.clip(np.nan_to_num(cos, nan=1.0), 0.0, 1.0)))
    aspect = np.degrees(np.arctan2(abc[:, 0], abc[:, 1])) % 360.0
    return slope, aspect


@dataclass(frozen=True, eq=False)
class _Facets:
    simplices: np.ndarray  # (T, 3)
    planes: np.ndarray  # (T, 4)
    slope_deg: np.ndarray
    aspect_deg: np.ndarray
    area_m2: np.ndarray
    keep: np.ndarray  # bool, passed edge-length test
    max_edge_m: float


def delaunay_facets(xyz: np.ndarray, max_edge_m: float | None = None) -> _Facets:
    """Delaunay triangulation in plan with per-triangle plane, slope, aspect, area.

    Raises
    ------
    ClipError
        Fewer than 3 points or all points collinear in plan (a ``ValueError``).
    """
    from scipy.spatial import Delaunay
    from scipy.spatial import QhullError

    xyz = np.asarray(xyz, dtype=np.float64)
    if len(xyz) < 3:
        raise ClipError(f"{len(xyz)} points: a triangulation needs at least 3")
    xy = xyz[:, :2] - xyz[:, :2].mean(axis=0)
    try:
        tri = Delaunay(xy)
    except (QhullError, ValueError) as ex:
        raise ClipError("points are collinear or coincident in plan; no triangulation") from ex
    simp = tri.simplices
    local = xyz - xyz.mean(axis=0)
    planes = triangle_planes(local, simp)
    slope, aspect = triangle_slope_aspect(planes)
    p = xy[simp]
    edges = np.stack([np.linalg.norm(p[:, 1] - p[:, 0], axis=1),
                      np.linalg.norm(p[:, 2] - p[:, 1], axis=1),
                      np.linalg.norm(p[:, 0] - p[:, 2], axis=1)], axis=1)
    longest = edges.max(axis=1)
    if max_edge_m is None:
        max_edge_m = 4.0 * float(np.median(edges)) if len(edges) else math.inf
    area = 0.5 * np.abs((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1])
                        - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1]))
    return _Facets(simp, planes, slope, aspect, area, longest <= max_edge_m, float(max_edge_m))


# --------------------------------------------------------------------------- GH fit
@dataclass(frozen=True, eq=False)
class PlaneFit:
    """Result of :func:`fit_plane`: the plane or a falsy failure with a reason."""

    plane: Plane | None
    used: np.ndarray  # bool (M,), points kept
    residual_m: np.ndarray  # (M,) tested residual (nan for never fitted)
    sigma0: float
    reason: str = ""

    def __bool__(self) -> bool:
        return self.plane is not None


def _gh_solve(x: np.ndarray, s2: np.ndarray, n0: np.ndarray,
              max_iter: int = 30) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Helmert iterations in a local frame. Returns n, d, Q (4x4), r, w.

    The design matrix A is evaluated at the *adjusted* observations
    ``x + v`` (Pope 1972); evaluating it at the raw observations biases the plane.
    """
    m = len(x)
    n = n0 / np.linalg.norm(n0)
    d = -float(x.mean(axis=0) @ n)
    v = np.zeros_like(x)

    def bordered(xa: np.ndarray, w: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a_mat = np.column_stack([xa, np.ones(m)])
        big = np.zeros((5, 5))
        big[:4, :4] = (a_mat * w[:, None]).T @ a_mat
        big[:3, 4] = n
        big[4, :3] = n
        return big, a_mat

    for _ in range(max_iter):
        q = s2 @ (n * n)
        w = 1.0 / q
        # misclosure f(X0, L0) + B (Lb - L0) = n . x_b + d
        wvec = x @ n + d
        big, a_mat = bordered(x + v, w, n)
        # A dx + B v + w = 0 with the linearisation point at x + v:
        # f(X0, L0) = n.(x + v) + d, B(Lb - L0) = -n.v  ->  misclosure = n.x + d
        rhs = np.append(-a_mat.T @ (w * wvec), 0.0)
        sol = np.linalg.solve(big, rhs)
        dn, dd = sol[:3], sol[3]
        n_new = n + dn
        norm = np.linalg.norm(n_new)
        n, d = n_new / norm, (d + dd) / norm
        r = x @ n + d
        q = s2 @ (n * n)
        v = -(s2 * n[None, :]) * (r / q)[:, None]
        if np.max(np.abs(dn)) < 1e-12 and abs(dd) < 1e-11:
            break
    r = x @ n + d
    q = s2 @ (n * n)
    w = 1.0 / q
    v = -(s2 * n[None, :]) * (r / q)[:, None]
    big, _ = bordered(x + v, w, n)
    qxx = np.linalg.inv(big)[:4, :4]
    return n, d, qxx, r, w


def _initial_normal(x: np.ndarray, s2: np.ndarray) -> np.ndarray:
    # generalised eigenproblem S n = lambda Sigma n (exact GH solution for equal sds)
    xc = x - x.mean(axis=0)
    scat = xc.T @ xc
    sig = np.diag(s2.mean(axis=0))
    isq = np.diag(1.0 / np.sqrt(np.diag(sig)))
    val, vec = np.linalg.eigh(isq @ scat @ isq)
    n = isq @ vec[:, 0]
    return n if n[2] >= 0 else -n


def fit_plane(
    xyz: Any,
    *,
    sd_m: Any = (0.10, 0.10, 0.05),
    residual_threshold_m: float | None = 0.15,
    residual_kind: str = "normal",
    min_points: int = 6,
    posterior_variance: bool = True,
    label: int = 0,
) -> PlaneFit:
    """Fit one plane by the combined adjustment (eq. 33-37) with iterative rejection.

    Parameters
    ----------
    xyz : (M, 3) float
        Points E, N, h (m).
    sd_m : (3,) or (M, 3) float
        Standard deviations of E, N, h of every point (m).
    residual_threshold_m : float or None
        Points whose residual exceeds this are removed and the plane refitted
        (thesis 0.15 m).  None: 3.5 x robust sigma (MAD) of the distances of
        all points, >= 0.03 m.
    residual_kind : {"normal", "vertical", "height"}
        Orthogonal distance; vertical distance to the plane (the thesis's
        "altimetric residual"); or the adjusted-height residual v_h of the GH
        model, the fraction :math:`s_h^2 n_h^2 / (n^T \\Sigma n)` of the vertical
        misclosure: with the thesis sds (0.50 m plan, 0.15 m height) 74 % on a
        10 deg face but 26 % on a 27 deg face, too weak to catch a chimney at 0.15 m.
    min_points : int
        Fewer remaining points make the fit fail.
    posterior_variance : bool
        Scale the cofactor matrix by the a-posteriori variance factor.

    Returns
    -------
    PlaneFit
        Falsy with a ``reason`` when fewer than *min_points* remain or the
        points are collinear.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> e, n = rng.uniform(0, 5, (2, 200))
    >>> h = 10 + 0.5 * e + rng.normal(0, 0.02, 200)
    >>> fit = fit_plane(np.column_stack([e, n, h]))
    >>> bool(abs(fit.plane.slope_deg - 26.565) < 0.3), fit.plane.n_used
    (True, 200)
    """
    x_all = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    m_all = len(x_all)
    sd = np.broadcast_to(np.asarray(sd_m, dtype=np.float64), (m_all, 3))
    s2_all = sd**2
    used = np.ones(m_all, dtype=bool)
    resid = np.full(m_all, np.nan)
    if m_all < min_points:
        return PlaneFit(None, used, resid, math.nan,
                        f"{m_all} points, a plane needs at least {min_points}")
    origin = x_all.mean(axis=0)
    xl_all = x_all - origin
    n0 = _initial_normal(xl_all, s2_all)
    for _ in range(200):
        idx = np.flatnonzero(used)
        if len(idx) < min_points:
            return PlaneFit(None, used, resid, math.nan,
                            f"only {len(idx)} of {m_all} points left after rejection "
                            f"(threshold {residual_threshold_m} m); need {min_points}")
        xl, s2 = xl_all[idx], s2_all[idx]
        if np.linalg.matrix_rank(xl[:, :2] - xl[:, :2].mean(axis=0), tol=1e-6) < 2:
            return PlaneFit(None, used, resid, math.nan, "points are collinear in plan")
        try:
            n, d, qxx, r, w = _gh_solve(xl, s2, n0)
        except np.linalg.LinAlgError:
            return PlaneFit(None, used, resid, math.nan, "singular plane adjustment")
        n0 = n
        # residuals of all points to the current plane (removed ones too)
        r_all = xl_all @ n + d
        if residual_kind == "height":
            q_all = s2_all @ (n * n)
            test = np.abs(s2_all[:, 2] * n[2] * r_all / q_all)
        elif residual_kind == "vertical":
            test = np.abs(r_all) / max(abs(n[2]), 1e-6)
        else:
            test = np.abs(r_all)
        thr = residual_threshold_m
        if thr is None:
            # robust sigma from ALL points (rejected ones too), so that the
            # threshold does not shrink as the tails are cut
            mad = float(np.median(np.abs(r_all - np.median(r_all))))
            thr = max(0.03, 3.5 * 1.4826 * mad)
        bad = used & (test > thr)
        resid = test
        if not bad.any():
            break
        # remove the worst first (thesis: one point, then re-fit); batches for speed
        worst = float(test[bad].max())
        used = used & ~(bad & (test > max(thr, 0.5 * worst)))
    idx = np.flatnonzero(used)
    m = len(idx)
    dof = m - 3
    sigma0_2 = float(np.sum(w * r * r) / dof) if dof > 0 else math.nan
    # with the variance factor estimated from m - 3 redundancies, the standardised
    # error is t-distributed: its variance is dof / (dof - 2), not 1
    scale = sigma0_2 * (dof / (dof - 2.0) if dof > 4 else 3.0) \
        if posterior_variance and np.isfinite(sigma0_2) else 1.0
    local = Plane(n=n, d=d, cov=qxx * scale, centroid_m=xl_all[idx].mean(axis=0),
                  n_used=m, n_rejected=m_all - m, rms_m=float(np.sqrt(np.mean(r * r))), label=label)
    plane = _translated(local, origin)
    return PlaneFit(plane, used, resid, math.sqrt(sigma0_2) if np.isfinite(sigma0_2) else math.nan)


# --------------------------------------------------------------------------- grouping
def _circular_peaks(angles_deg: np.ndarray, weights: np.ndarray, tol_deg: float, max_peaks: int) -> list[float]:
    if len(angles_deg) == 0:
        return []
    bins = np.arange(0, 361, 5.0)
    hist, _ = np.histogram(angles_deg % 360, bins=bins, weights=weights)
    # circular smoothing over +-10 deg
    k = np.array([0.25, 0.5, 1.0, 0.5, 0.25])
    ext = np.concatenate([hist[-2:], hist, hist[:2]])
    smooth = np.convolve(ext, k, mode="valid")
    centres = bins[:-1] + 2.5
    peaks: list[float] = []
    order = np.argsort(-smooth)
    for i in order:
        if smooth[i] < 0.2 * smooth.max() or len(peaks) >= max_peaks:
            break
        a = centres[i]
        if all(abs((a - b + 180) % 360 - 180) >= tol_deg for b in peaks):
            peaks.append(float(a))
    return peaks


def _segment_thesis(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Label points by the direction of their Delaunay triangles (thesis 3.2.4-3.2.5)."""
    labels = np.full(len(xyz), -1)
    fac = delaunay_facets(xyz, p.max_edge_m)
    ok = fac.keep & (fac.slope_deg > p.slope_min_deg) & (fac.slope_deg < p.slope_max_deg)
    info = {"n_triangles": len(fac.simplices), "n_in_window": int(ok.sum()),
            "n_flat": int((fac.keep & (fac.slope_deg <= p.slope_min_deg)).sum()),
            "n_steep": int((fac.keep & (fac.slope_deg >= p.slope_max_deg)).sum()), "facets": fac}
    if not ok.any():
        return labels, info
    peaks = _circular_peaks(fac.aspect_deg[ok], fac.area_m2[ok], p.aspect_tol_deg, p.max_planes)
    if not peaks:
        return labels, info
    asp = fac.aspect_deg[ok][:, None]
    dist = np.abs((asp - np.array(peaks)[None, :] + 180) % 360 - 180)
    g = np.argmin(dist, axis=1)
    g[dist[np.arange(len(g)), g] > p.aspect_tol_deg] = -1
    simp = fac.simplices[ok]
    # a point takes the group most of its triangles belong to
    votes = np.zeros((len(xyz), len(peaks)))
    for k in range(len(peaks)):
        sel = simp[g == k].ravel()
        np.add.at(votes[:, k], sel, 1.0)
    has = votes.sum(axis=1) > 0
    labels[has] = np.argmax(votes[has], axis=1)
    return labels, info


def _local_normals(xyz: np.ndarray, k: int):
    from scipy.spatial import cKDTree

    tree = cKDTree(xyz[:, :2])
    k = int(min(k, len(xyz)))
    dist, nb = tree.query(xyz[:, :2], k=k)
    nb = np.asarray(nb).reshape(len(xyz), k)
    pts = xyz[nb]
    c = pts.mean(axis=1, keepdims=True)
    q = pts - c
    cov = np.einsum("nki,nkj->nij", q, q) / k
    val, vec = np.linalg.eigh(cov)
    normals = vec[:, :, 0]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    rms = np.sqrt(np.maximum(val[:, 0], 0.0))
    return normals, rms, nb, dist


def _segment_setup(xyz: np.ndarray, p: ExtractionParams) -> dict[str, Any]:
    """What both segmenters need: local normals, slopes, noise, tolerances, link length."""
    normals, lrms, nb, nbd = _local_normals(xyz, p.k_neighbours)
    k = nb.shape[1]
    slope = np.degrees(np.arccos(np.clip(normals[:, 2], 0.0, 1.0)))
    in_win = (slope > p.slope_min_deg) & (slope < p.slope_max_deg)
    # noise from the quieter local planes: the lower quartile of the local RMS
    # (ridges and edges inflate the upper part); for pure noise it is ~0.70 sigma at k = 12.
    # Vegetation and walls are not roof noise: estimate it on the sloped points.
    pool = lrms[in_win] if in_win.sum() >= 20 else lrms
    sigma = float(np.percentile(pool, 25)) / 0.70 if len(xyz) else 0.0
    dist_tol = p.dist_tol_m if p.dist_tol_m is not None else max(0.05, 3.0 * sigma)
    spacing = float(np.median(nbd[:, 1])) if k > 1 else 1.0
    link = 4.0 * spacing if p.max_edge_m is None else p.max_edge_m
    info = {"sigma_m": sigma, "dist_tol_m": dist_tol, "spacing_m": spacing,
            "n_flat": int((slope <= p.slope_min_deg).sum()),
            "n_steep": int((slope >= p.slope_max_deg).sum()), "n_in_window": int(in_win.sum())}
    return dict(normals=normals, lrms=lrms, nb=nb, nbd=nbd, k=k, slope=slope, in_win=in_win,
                sigma=sigma, dist_tol=dist_tol, spacing=spacing, link=link, info=info)


def _segment_region(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Region growing on the kNN graph (normal angle + point-to-plane distance)."""
    m = len(xyz)
    labels = np.full(m, -1)
    st = _segment_setup(xyz, p)
    normals, lrms, nb, nbd = st["normals"], st["lrms"], st["nb"], st["nbd"]
    in_win, sigma, dist_tol = st["in_win"], st["sigma"], st["dist_tol"]
    max_link, info = st["link"], st["info"]
    cos_tol = math.cos(math.radians(p.angle_tol_deg))
    linked = nbd <= max_link
    seeds = np.flatnonzero(in_win & (lrms < max(2.0 * sigma, 0.5 * dist_tol)))
    seeds = seeds[np.argsort(lrms[seeds])]
    region = 0
    tried = np.zeros(m, dtype=bool)
    for s in seeds:
        if labels[s] >= 0 or tried[s]:
            continue
        tried[s] = True
        members = [s]
        labels[s] = region
        n_r, c_r = normals[s], xyz[s]
        frontier = np.array([s])
        last_fit = 1
        while len(frontier):
            cand = nb[frontier][linked[frontier]]
            cand = np.unique(cand)
            cand = cand[labels[cand] < 0]
            if len(cand) == 0:
                break
            ok = (np.abs((xyz[cand] - c_r) @ n_r) < dist_tol) & (normals[cand] @ n_r > cos_tol)
            acc = cand[ok]
            if len(acc) == 0:
                break
            labels[acc] = region
            members.extend(acc.tolist())
            frontier = acc
            if len(members) >= 1.3 * last_fit and len(members) >= 6:
                pts = xyz[members]
                c_r = pts.mean(axis=0)
                val, vec = np.linalg.eigh(np.cov((pts - c_r).T))
                n_new = vec[:, 0] * (1 if vec[2, 0] >= 0 else -1)
                n_r = n_new
                last_fit = len(members)
        if len(members) < p.min_points:
            labels[np.array(members)] = -1
            tried[np.array(members)] = True
        else:
            region += 1
    info["n_regions_raw"] = region
    return labels, info


def _segment_ransac(xyz: np.ndarray, p: ExtractionParams) -> tuple[np.ndarray, dict[str, Any]]:
    """Sequential RANSAC: best-supported plane, its largest connected patch, repeat."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(xyz)
    labels = np.full(m, -1)
    st = _segment_setup(xyz, p)
    normals, nb, nbd, k = st["normals"], st["nb"], st["nbd"], st["k"]
    in_win, dist_tol, link, info = st["in_win"], st["dist_tol"], st["link"], st["info"]
    rows = np.repeat(np.arange(m), k)
    cols = nb.ravel()
    ok = nbd.ravel() <= link
    graph = coo_matrix((np.ones(ok.sum()), (rows[ok], cols[ok])), shape=(m, m)).tocsr()
    cos_tol = math.cos(math.radians(p.angle_tol_deg))
    rng = np.random.default_rng(0)
    free = in_win.copy()
    region = 0
    for _ in range(3 * p.max_planes):
        cand = np.flatnonzero(free)
        if len(cand) < p.min_points:
            break
        best, best_n = None, 0
        for _ in range(150):
            tri = xyz[rng.choice(cand, 3, replace=False)]
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            norm = np.linalg.norm(n)
            if norm < 1e-9:
                continue
            n = n / norm * (1 if n[2] >= 0 else -1)
            inl = (np.abs((xyz[cand] - tri[0]) @ n) < dist_tol) & (normals[cand] @ n > cos_tol)
            if inl.sum() > best_n:
                best, best_n = cand[inl], int(inl.sum())
        if best is None or best_n < p.min_points:
            break
        sub = graph[best][:, best]
        _, comp = connected_components(sub, directed=False)
        big = best[comp == np.argmax(np.bincount(comp))]
        if len(big) < p.min_points:
            free[best] = False
            continue
        labels[big] = region
        free[big] = False
        region += 1
    info["n_regions_raw"] = region
    return labels, info


def _fit_groups(xyz: np.ndarray, labels: np.ndarray, p: ExtractionParams) -> list[tuple[Plane, np.ndarray]]:
    """Fit every labelled group with the extraction's own rejection settings."""
    out = []
    for g in np.unique(labels[labels >= 0]):
        idx = np.flatnonzero(labels == g)
        fit = fit_plane(xyz[idx], sd_m=(p.sd_en_m, p.sd_en_m, p.sd_h_m),
                        residual_threshold_m=p.residual_threshold_m, residual_kind=p.residual_kind,
                        min_points=p.min_points, posterior_variance=p.posterior_variance)
        if fit:
            out.append((fit.plane, idx[fit.used]))
    return out


def _fit_trial(xyz: np.ndarray, p: ExtractionParams) -> PlaneFit:
    """Plane of a trial face while segmenting: robust (MAD) threshold, orthogonal residuals."""
    return fit_plane(xyz, sd_m=(p.sd_en_m, p.sd_en_m, p.sd_h_m), residual_threshold_m=None,
                     min_points=p.min_points)


def _drop_edge_strips(xyz: np.ndarray, idx_sets: list[np.ndarray], p: ExtractionParams,
                      dist_tol: float) -> list[tuple[np.ndarray, PlaneFit]]:
    """Drop small faces whose points are explained by larger faces.

    Points along a ridge, hip or valley have blended local normals and can
    grow into a thin region of intermediate orientation; its points lie within
    the distance tolerance of the two real faces, which take them back.
    Returns the kept point sets with their :func:`_fit_trial` fits.
    """
    order = sorted(range(len(idx_sets)), key=lambda i: -len(idx_sets[i]))
    fits = {i: _fit_trial(xyz[idx_sets[i]], p) for i in order}
    planes = {i: f.plane for i, f in fits.items() if f}
    keep = []
    for a, i in enumerate(order):
        pts = xyz[idx_sets[i]]
        bigger = [planes[j] for j in order[:a] if j in planes and j in keep]
        if bigger and len(idx_sets[i]) < 0.5 * len(idx_sets[order[0]]):
            near = np.zeros(len(pts), dtype=bool)
            for pl in bigger:
                near |= np.abs(pl.distance(pts)) < dist_tol
            if near.mean() >= 0.7:
                continue
        keep.append(i)
    return [(idx_sets[i], fits[i]) for i in sorted(keep)]


def _refine_assignment(xyz: np.ndarray, faces: list[tuple[Plane, np.ndarray]], p: ExtractionParams,
                       dist_tol: float, spacing: float) -> np.ndarray:
    """Merge coplanar faces, give every point to its nearest face, drop ridge points."""
    from scipy.spatial import cKDTree

    m = len(xyz)
    if not faces:
        return np.full(m, -1)
    # merge coplanar faces (same plane split by a chimney, terraced houses)
    planes = [f[0] for f in faces]
    members = [set(f[1].tolist()) for f in faces]
    parent = list(range(len(faces)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    order_sz = sorted(range(len(faces)), key=lambda i: -len(faces[i][1]))
    for a, i in enumerate(order_sz):
        for j in order_sz[a + 1:]:
            # j is the smaller face: merge it into i when its points lie on i's plane
            if planes[i].n @ planes[j].n < math.cos(math.radians(15.0)):
                continue
            dj = np.abs(planes[i].distance(xyz[faces[j][1]]))
            if np.median(dj) < dist_tol / 2.5:
                parent[root(j)] = root(i)
    groups: dict[int, set] = {}
    for i in range(len(faces)):
        groups.setdefault(root(i), set()).update(members[i])
    kept = _drop_edge_strips(xyz, [np.array(sorted(s)) for s in groups.values()], p, dist_tol)
    idx_sets = [idx for idx, _ in kept]
    nf = len(kept)
    dist = np.full((m, nf), np.inf)
    zpl = np.full((m, nf), np.nan)
    link = 3.0 * spacing + 0.2
    fitted = []
    for k, (idx, fit) in enumerate(kept):
        fitted.append(fit.plane if fit else None)
        if not fit:
            continue
        pl = fit.plane
        tree = cKDTree(xyz[idx[fit.used], :2])
        near, _ = tree.query(xyz[:, :2], k=1, distance_upper_bound=link)
        dk = np.abs(pl.distance(xyz))
        dk[~np.isfinite(near)] = np.inf
        dist[:, k] = dk
        if pl.n[2] > 0.05:
            zpl[:, k] = pl.height_at(xyz[:, 0], xyz[:, 1])
    # which side of the intersection line of faces i and j face i lies on:
    # sign of (z_i - z_j) over face i's own points (-1 ridge/hip, +1 valley)
    side = np.zeros((nf, nf))
    for i in range(nf):
        for j in range(nf):
            if i != j and fitted[i] is not None and fitted[j] is not None:
                diff = zpl[idx_sets[i], i] - zpl[idx_sets[i], j]
                side[i, j] = np.sign(np.nanmedian(diff)) if np.isfinite(diff).any() else 0.0
    labels = np.full(m, -1)
    cand = dist < max(2.0 * dist_tol, 0.5)
    ncand = cand.sum(axis=1)
    one = ncand == 1
    best1 = np.argmax(cand, axis=1)
    labels[one] = best1[one]
    # several faces close in height: decide by the plan position relative to
    # their intersection line (noise-free), not by the noisy distance
    band = dist_tol / 3.0
    for i_pt in np.flatnonzero(ncand > 1):
        faces_i = np.flatnonzero(cand[i_pt])
        win = faces_i[0]
        for c in faces_i[1:]:
            dz = zpl[i_pt, c] - zpl[i_pt, win]
            # the point is on c's side when sign(z_c - z_win) matches c's own side
            if side[c, win] != 0 and np.sign(dz) == side[c, win]:
                win = c
        # too close to an intersection line to tell the faces apart: leave it out
        gaps = [abs(zpl[i_pt, c] - zpl[i_pt, win]) for c in faces_i if c != win and side[c, win] != 0]
        labels[i_pt] = -1 if gaps and min(gaps) < band else win
    ok = labels >= 0
    ok[ok] = dist[np.flatnonzero(ok), labels[ok]] < dist_tol
    labels[~ok] = -1
    return labels


def _drop_outer_edges(xyz: np.ndarray, labels: np.ndarray, k: int = 12,
                      gap_deg: float = 150.0, max_slope_deg: float = 65.0,
                      noise_m: float = 0.25) -> np.ndarray:
    """Leave out the points on a face's outer edge (eaves, verges, clip rim).

    Facade points just below an eave lie within the distance tolerance of the
    roof plane and always below it, so they pull the face down.  They, and the
    roof points along the same edge, are the points whose same-face plan
    neighbours all lie on one side (angular gap > *gap_deg*) with no other
    face beyond the gap.  Edges between two faces (ridges, hips, valleys) are
    kept.  A face across the gap makes an internal edge only when it continues
    this face in height (height step at most ``plan distance x tan(max_slope_deg)
    + noise_m``): the ground segmented below an eave is another face too, and
    taking it for a ridge kept the facade points of the sides facing the
    scanner (a 0.2-sigma bias of pyramid apexes towards the scanner).  The
    choice depends on plan positions and metre-scale steps only, not on the
    height noise, so it removes the facade bias without biasing the face.
    """
    from scipy.spatial import cKDTree

    m = len(xyz)
    if m < 4:
        return labels
    k = int(min(k + 1, m))
    _, nb = cKDTree(xyz[:, :2]).query(xyz[:, :2], k=k)
    nb = nb[:, 1:]
    d = xyz[nb, :2] - xyz[:, None, :2]
    ang = np.arctan2(d[..., 1], d[..., 0])  # (m, k-1)
    lab_nb = labels[nb]
    same = lab_nb == labels[:, None]
    step = np.abs(xyz[nb, 2] - xyz[:, None, 2])
    joined = step <= np.hypot(d[..., 0], d[..., 1]) * math.tan(math.radians(max_slope_deg)) + noise_m
    other = (lab_nb >= 0) & ~same & joined
    a = np.where(same, ang, np.inf)
    a_sorted = np.sort(a, axis=1)
    n_same = same.sum(axis=1)
    out = labels.copy()
    for_pts = np.flatnonzero((labels >= 0) & (n_same >= 2))
    if len(for_pts) == 0:
        return out
    a_s = a_sorted[for_pts]
    cnt = n_same[for_pts]
    # angular gaps between consecutive same-face neighbours, with the wrap-around
    idx = np.arange(a_s.shape[1])[None, :]
    valid = idx < cnt[:, None]
    nxt = np.where(idx + 1 < cnt[:, None], np.roll(a_s, -1, axis=1), a_s[:, :1] + 2 * np.pi)
    gaps = np.where(valid, nxt - a_s, -np.inf)
    j = np.argmax(gaps, axis=1)
    gmax = gaps[np.arange(len(for_pts)), j]
    edge = gmax > np.radians(gap_deg)
    # another face inside the gap: an internal edge (ridge, hip, valley)
    rel = (ang[for_pts] - a_s[np.arange(len(for_pts)), j][:, None]) % (2 * np.pi)
    in_gap = (rel > 0) & (rel < gmax[:, None])
    internal = np.any(other[for_pts] & in_gap, axis=1)
    drop = for_pts[edge & ~internal]
    out[drop] = -1
    # lone points (no same-face neighbour) are dropped too
    out[(labels >= 0) & (n_same < 2)] = -1
    return out


def segment_faces(xyz: Any, params: ExtractionParams | str | None = None) -> tuple[list[Plane], np.ndarray, dict[str, Any]]:
    """Group the points of a clip into roof faces and fit a plane to each.

    Parameters
    ----------
    xyz : (N, 3) float
        Clip points (already pre-filtered).
    params : ExtractionParams or preset name

    Returns
    -------
    planes : list of Plane
        Faces in the slope window, largest first, at most ``params.max_planes``.
    labels : (N,) int
        Face index per point into *planes* (-1: unused / rejected).
    info : dict
        Counts for diagnostics (flat and steep elements, noise estimate...).
    """
    p = get_params(params)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    origin = xyz.mean(axis=0) if len(xyz) else np.zeros(3)
    loc = xyz - origin
    segment = {"thesis": _segment_thesis, "ransac": _segment_ransac, "region": _segment_region}[p.method]
    labels, info = segment(loc, p)
    faces = _fit_groups(loc, labels, p)
    if p.method != "thesis":
        # assign by the fitted faces, re-fit, and assign again with the better
        # intersection lines (a self-consistent partition)
        for it in range(2):
            lab2 = _refine_assignment(loc, faces, p, info["dist_tol_m"], info["spacing_m"])
            if it == 1 and p.drop_outer_edges:
                lab2 = _drop_outer_edges(loc, lab2, max_slope_deg=p.slope_max_deg)
            faces = _fit_groups(loc, lab2, p)
    faces = [f for f in faces if p.slope_min_deg < f[0].slope_deg < p.slope_max_deg]
    faces.sort(key=lambda f: -f[0].n_used)
    faces = faces[: p.max_planes]
    out_labels = np.full(len(xyz), -1)
    planes = []
    for k, (pl, idx) in enumerate(faces):
        out_labels[idx] = k
        planes.append(_translated(pl, origin, label=k))
    info["n_faces"] = len(planes)
    return planes, out_labels, info
