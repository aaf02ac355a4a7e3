r"""Control points from roof planes: intersection (eq. 38-41) with covariance.

Three planes :math:`n_i \cdot x + d_i = 0` meet in the point that solves the
linear system of eq. 38, :math:`A x = -B` with rows :math:`A_i = n_i^T` and
:math:`B_i = d_i`.  It is refused when two normals are closer than
``min_dihedral_deg`` (nearly parallel planes) or the determinant of the unit
normals is below ``min_det`` (the three planes meet along a line or at a
grazing angle, so the point slides along it).

More than three planes: the least-squares solution of eq. 41,
:math:`x = -(A^T W A)^{-1} A^T W B`; the thesis uses :math:`W = I`, we weight
each plane by the inverse variance of its offset at the point (``weighted``).
The *misclosure* is the RMS of the distances :math:`r_i = n_i\cdot x + d_i` of
the point from the planes (zero for three planes), and
:math:`\chi^2 = \sum r_i^2 / \sigma_{r_i}^2` tests it.

**Covariance.**  Planes come from disjoint point sets and are independent.
Differentiating :math:`A x + B = 0`:

.. math:: A\,\delta x = -(\delta A\, x + \delta B) = -\delta r,\qquad
          \sigma^2_{r_i} = (x^T, 1)\, \Sigma_{(n,d)_i}\, (x^T, 1)^T

so :math:`\Sigma_x = A^{-1} \Sigma_r A^{-T}` (three planes) or
:math:`(A^T \Sigma_r^{-1} A)^{-1}` (least squares), all computed in a frame
centred on the planes so that national-grid coordinates lose no digits.
A survey may override it by specification standard deviations
(:meth:`ControlPoint.with_specification`, thesis 0.50 m plan / 0.15 m height).

:func:`extract_roof` chains the stage: clip -> faces (:mod:`lidarcat.control.facets`)
-> vertex; :func:`find_candidates` searches an area for every vertex of 3+
touching faces.

**The vertex asked for.**  A clip holds the faces of neighbouring roofs too;
with more of them than ``max_planes`` (or when faces merge across a larger
clip) the faces of a small corner may be lost, and the nearest surviving
intersection lies metres away.  :func:`extract_roof` therefore segments the
clip again at the smaller radii ``scales x radius_m`` and 4 and 3 m (those
below ``radius_m``, at least 3 m, largest first) and keeps the nearest over all
scales (a smaller clip's vertex replaces the first only when it is another
corner, farther than ``a = max(0.5 m, 4 sd_plan)`` from it -- the same corner is kept
from the larger clip -- and nearer by the measure :func:`select_vertex` ranks with,
the plan distance plus 3 x the 3-D sd).  It retries while a nearer distinct
corner is possible: another corner lies more than ``a`` from the vertex found,
so at more than ``a - o`` from the position when the vertex is ``o`` from it,
which is nearer only if ``o > a / 2``; it stops at the first vertex within
``min(near_m, a / 2)``.  (Retrying only beyond ``near_m`` and only down to
``0.5 radius_m`` let 12 of the 178 ``--find`` candidates of the AHN3 tiles come
back, as ``ok``, as another corner 1-6 m away at some clip radius of 4-12 m; now
4 do, 3 of them only at 4 m: ``benchmarks/bench_extract_sweep.py``,
docs/extraction.md.)
Two distinct vertices (as far apart; a rival is a vertex some clip chose, or a
triple with a face that is not the chosen vertex's -- the triples of a corner's
own faces are that corner: a pyramid's apex is not ambiguous with itself) whose
distances from the position differ
by less than ``ambiguity_m`` (the same penalised distance: a rival of a small
clip's few noisy points is no rival of a precise corner) give the status
``ambiguous`` with both listed; an ``ok`` vertex farther than ``near_m`` says so in its
reason, and :attr:`ControlPoint.offset_m` is written with every point.

**Local extraction** (``fit_radius_m``, 5 m by default).  The vertex chosen is then extracted again
from the clip of ``fit_radius_m`` centred on it, to a fixed point (:mod:`lidarcat.control.localfit`):
the search clip's radius decides which corner, the roof within 5 m of the corner decides where.  Off
(``None``) in the thesis preset.

**Radius stability.**  An ``ok`` vertex is then extracted again from clips of
``stability_scales x radius_m`` centred on it (4, 5, 6, 10, 12 m at the default)
and refused as ``unstable`` when it moves by more than its sd (and, without the
local extraction, by more than the covariance of the difference of the two clips'
vertices explains; :mod:`lidarcat.control.stability`); the reason names the radii,
the moves and their Mahalanobis distances.  The vertex is never replaced by another clip's.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Sequence

import numpy as np

from .._util.frozen import frozen_array
from .facets import segment_faces
from .localfit import LADDER, extract_locally
from .params import ExtractionParams, get_params
from .planes import Plane
from .stability import check_stability

__all__ = [
    "ControlPoint",
    "intersect_planes",
    "select_vertex",
    "candidate_vertices",
    "extract_roof",
    "find_candidates",
    "Candidate",
    "search_points",
    "cell_counts",
    "search_margin_m",
    "search_cells",
    "merge_candidates",
    "STATUSES",
    "ROW_FIELDS",
]

#: status values and their meaning
STATUSES: dict[str, str] = {
    "ok": "vertex of 3 or more planes",
    "too_few_points": "not enough LiDAR points in the clip",
    "degenerate_points": "points collinear or coincident; no triangulation",
    "flat_roof": "the clip is (nearly) horizontal; no sloped faces",
    "wall": "points lie on surfaces steeper than the slope window (walls)",
    "no_planes": "no face in the slope window",
    "one_plane": "only one face found",
    "two_planes": "only two faces found: they meet in a line, not a point",
    "ill_conditioned": "planes nearly parallel or meeting at a grazing angle",
    "no_vertex": "faces found but no three meet near the position",
    "ambiguous": "two distinct vertices about equally near the position (both in the reason)",
    "imprecise": "vertex found but its predicted standard deviation is too large",
    "unstable": "vertex found but it moves with the clip radius by more than its covariance explains "
                "(the radii and the Mahalanobis distance in the reason)",
    "bad_input": "input not understood",
}

ROW_FIELDS = ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "n_planes", "misclosure_m",
              "status", "reason"]


@dataclass(frozen=True, eq=False)
class ControlPoint:
    """A control point from intersected roof planes, or a falsy failure.

    Parameters
    ----------
    point_id : str
    enh_m : (3,) float
        E, N, h (m); NaN when failed before an intersection.
    cov_m2 : (3, 3) float
        Covariance of E, N, h (m^2).
    n_planes : int
        Planes intersected.
    misclosure_m : float
        RMS distance of the point from its planes (0 for three planes).
    status : str
        One of :data:`STATUSES`; ``bool(cp)`` is ``status == "ok"``.
    reason : str
        Why it failed (empty when ok).
    planes : tuple of Plane
        Planes used (or found, when failed).
    approx_en : (2,) float
        Approximate position it was searched at.
    chi2 : float
        Misclosure test statistic (0 for three planes).
    cov_source : str
        "extraction" (propagated from the planes) or "specification".

    Examples
    --------
    >>> cp = ControlPoint.failed("P1", [10.0, 20.0], "two_planes", "only 2 faces")
    >>> bool(cp), cp.status, cp.to_row()["reason"]
    (False, 'two_planes', 'only 2 faces')
    """

    point_id: str
    enh_m: np.ndarray
    cov_m2: np.ndarray
    n_planes: int = 0
    misclosure_m: float = math.nan
    status: str = "ok"
    reason: str = ""
    planes: tuple = ()
    approx_en: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    chi2: float = math.nan
    cov_source: str = "extraction"
    labels: Any = None  # optional (clip xyz, labels) for figures

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"unknown status {self.status!r}")
        object.__setattr__(self, "enh_m", frozen_array(self.enh_m, shape=(3,)))
        object.__setattr__(self, "cov_m2", frozen_array(self.cov_m2, shape=(3, 3)))
        object.__setattr__(self, "approx_en", frozen_array(self.approx_en, shape=(2,)))
        object.__setattr__(self, "planes", tuple(self.planes))
        object.__setattr__(self, "point_id", str(self.point_id))
        if self.labels is not None:  # (clip xyz, face label per point), kept for figures
            object.__setattr__(self, "labels", tuple(frozen_array(a, dtype=None) for a in self.labels))

    def __bool__(self) -> bool:
        return self.status == "ok"

    @classmethod
    def failed(cls, point_id: str, approx_en: Any, status: str, reason: str, *,
               planes: Sequence[Plane] = (), enh_m: Any = None, cov_m2: Any = None,
               labels: Any = None) -> "ControlPoint":
        """A falsy control point carrying *status* and *reason*."""
        return cls(point_id=point_id, enh_m=np.full(3, np.nan) if enh_m is None else enh_m,
                   cov_m2=np.full((3, 3), np.nan) if cov_m2 is None else cov_m2,
                   n_planes=len(planes), status=status, reason=reason, planes=tuple(planes),
                   approx_en=np.asarray(approx_en, dtype=float).reshape(-1)[:2], labels=labels)

    # ---------------------------------------------------------------- sds
    @property
    def sd_m(self) -> np.ndarray:
        """Standard deviations of E, N, h (m)."""
        return np.sqrt(np.maximum(np.diag(self.cov_m2), 0.0))

    @property
    def sd_e_m(self) -> float:
        return float(self.sd_m[0])

    @property
    def sd_n_m(self) -> float:
        return float(self.sd_m[1])

    @property
    def sd_h_m(self) -> float:
        return float(self.sd_m[2])

    @property
    def sd_plan_m(self) -> float:
        """Root of the plan variance trace (m)."""
        return float(math.sqrt(max(self.cov_m2[0, 0] + self.cov_m2[1, 1], 0.0)))

    def error_ellipse(self, k: float = 1.0) -> tuple[float, float, float]:
        """Plan error ellipse: semi-axes (m) scaled by *k* and azimuth of the major axis (deg)."""
        val, vec = np.linalg.eigh(self.cov_m2[:2, :2])
        val = np.maximum(val, 0.0)
        az = math.degrees(math.atan2(vec[0, 1], vec[1, 1])) % 180.0
        return k * math.sqrt(val[1]), k * math.sqrt(val[0]), az

    def with_specification(self, sd_plan_m: float = 0.50, sd_h_m: float = 0.15) -> "ControlPoint":
        """Copy whose covariance is the specification (thesis: 0.50 m plan, 0.15 m height)."""
        cov = np.diag([sd_plan_m**2, sd_plan_m**2, sd_h_m**2])
        return replace(self, cov_m2=cov, cov_source="specification")

    # ---------------------------------------------------------------- output
    def to_row(self) -> dict[str, Any]:
        """One output row (the columns of :data:`ROW_FIELDS`)."""
        e, n, h = (float(v) for v in self.enh_m)
        sd = self.sd_m
        return {"point": self.point_id, "E": e, "N": n, "h": h, "sd_E": float(sd[0]),
                "sd_N": float(sd[1]), "sd_h": float(sd[2]), "n_planes": self.n_planes,
                "misclosure_m": float(self.misclosure_m), "status": self.status, "reason": self.reason}

    def to_dict(self) -> dict[str, Any]:
        d = self.to_row()
        d["planes"] = [p.to_dict() for p in self.planes]
        d["cov_m2"] = self.cov_m2
        d["cov_source"] = self.cov_source
        d["approx_E"], d["approx_N"] = (float(v) for v in self.approx_en)
        d["offset_m"] = self.offset_m
        return d

    @property
    def offset_m(self) -> float:
        """Plan distance of the vertex from the position it was searched at (m; NaN if unknown)."""
        return float(np.hypot(*(self.enh_m[:2] - self.approx_en)))


# ------------------------------------------------------------------- intersection
def _conditioning(nmat: np.ndarray, min_dihedral_deg: float, min_det: float) -> str:
    m = len(nmat)
    for i, j in itertools.combinations(range(m), 2):
        ang = math.degrees(math.acos(min(1.0, abs(float(nmat[i] @ nmat[j])))))
        if ang < min_dihedral_deg:
            return (f"planes {i + 1} and {j + 1} are nearly parallel (normals {ang:.1f} deg "
                    f"apart < {min_dihedral_deg:g} deg)")
    best = max(abs(float(np.linalg.det(nmat[list(t)]))) for t in itertools.combinations(range(m), 3))
    if best < min_det:
        return (f"the planes meet at a grazing angle or along a common line (|det| of the unit "
                f"normals {best:.4f} < {min_det:g})")
    return ""


def intersect_planes(
    planes: Sequence[Plane],
    *,
    point_id: str = "",
    min_dihedral_deg: float = 3.0,
    min_det: float = 0.002,
    weighted: bool = True,
    approx_en: Any = None,
) -> ControlPoint:
    """Intersect 3 planes (eq. 38) or more (least squares, eq. 41) with covariance.

    Parameters
    ----------
    planes : sequence of Plane
        At least three.
    point_id : str
    min_dihedral_deg, min_det : float
        Conditioning limits (see module docstring).
    weighted : bool
        More than three planes: weight by plane offset variance (False: eq. 41 as printed).

    Returns
    -------
    ControlPoint
        Falsy with status ``"ill_conditioned"`` (reason says which planes) or
        ``"two_planes"``/``"one_plane"``/``"no_planes"`` when fewer than three.

    Examples
    --------
    >>> cov = np.diag([1e-6, 1e-6, 1e-6, 1e-4])
    >>> pl = [Plane(n=[0.5, 0, 0.866], d=-0.866 * 10, cov=cov, centroid_m=[0, 0, 10]),
    ...       Plane(n=[-0.5, 0, 0.866], d=-0.866 * 10, cov=cov, centroid_m=[0, 0, 10]),
    ...       Plane(n=[0, 0.5, 0.866], d=-0.866 * 10, cov=cov, centroid_m=[0, 0, 10])]
    >>> cp = intersect_planes(pl, point_id="V")
    >>> cp.status, np.round(cp.enh_m, 6).tolist()
    ('ok', [0.0, 0.0, 10.0])
    >>> intersect_planes(pl[:2]).status
    'two_planes'
    """
    planes = list(planes)
    m = len(planes)
    approx = np.full(2, np.nan) if approx_en is None else approx_en
    if m < 3:
        status = {0: "no_planes", 1: "one_plane", 2: "two_planes"}[m]
        return ControlPoint.failed(point_id, approx, status,
                                   f"{m} plane(s); a point needs 3 non-parallel planes", planes=planes)
    nmat = np.array([p.n for p in planes])
    why = _conditioning(nmat, min_dihedral_deg, min_det)
    if why:
        return ControlPoint.failed(point_id, approx, "ill_conditioned", why, planes=planes)
    origin = np.mean([p.centroid_m for p in planes], axis=0)
    dvec = np.array([p.offset_at(origin) for p in planes])
    covs = [p.cov_at(origin) for p in planes]
    if m == 3:
        x = np.linalg.solve(nmat, -dvec)  # eq. 38
    else:
        x = -np.linalg.lstsq(nmat, dvec, rcond=None)[0]  # eq. 41

    def var_r_at(x: np.ndarray) -> np.ndarray:
        """Variances of the plane distances r_i at x (m^2)."""
        xh = np.append(x, 1.0)
        return np.maximum(np.array([xh @ c @ xh for c in covs]), 1e-30)

    if m > 3 and weighted:
        for _ in range(3):
            w = 1.0 / var_r_at(x)
            x = -np.linalg.solve(nmat.T @ (nmat * w[:, None]), nmat.T @ (w * dvec))
    var_r = var_r_at(x)
    if m == 3:
        ainv = np.linalg.inv(nmat)
        cov_x = ainv @ np.diag(var_r) @ ainv.T
        r = np.zeros(3)
    else:
        if weighted:
            cov_x = np.linalg.inv(nmat.T @ (nmat / var_r[:, None]))
        else:
            g = np.linalg.inv(nmat.T @ nmat) @ nmat.T
            cov_x = g @ np.diag(var_r) @ g.T
        r = nmat @ x + dvec
    mis = float(np.sqrt(np.mean(r * r))) if m > 3 else 0.0
    chi2 = float(np.sum(r * r / var_r)) if m > 3 else 0.0
    return ControlPoint(point_id=point_id, enh_m=x + origin, cov_m2=0.5 * (cov_x + cov_x.T),
                        n_planes=m, misclosure_m=mis, status="ok", reason="", planes=tuple(planes),
                        approx_en=approx, chi2=chi2)


# ------------------------------------------------------------------- vertex search
def _spacing(xyz: np.ndarray, info: dict | None) -> float:
    if info and "spacing_m" in info:
        return float(info["spacing_m"])
    ext = np.ptp(xyz[:, :2], axis=0)
    area = max(float(ext[0] * ext[1]) * math.pi / 4, 1e-6)
    return math.sqrt(area / max(len(xyz), 1))


def _on_surface(x: np.ndarray, xyz: np.ndarray, tree_all, r: float, tol: float = 0.3) -> bool:
    """The vertex lies within the heights of the LiDAR points around it (+- tol)."""
    idx = tree_all.query_ball_point(x[:2], r=r)
    if not idx:
        return False
    h = xyz[idx, 2]
    return bool(h.min() - tol <= x[2] <= h.max() + tol)


def _face_support(xyz: np.ndarray, labels: np.ndarray, m: int, p: ExtractionParams,
                  info: dict | None) -> tuple[list, float, float]:
    """Plan KD-tree of each of the *m* faces' points, point spacing (m), support distance (m).

    A face's extent is its points before the break-line buffer (``info["extent_labels"]``,
    :mod:`lidarcat.control.segment`) when there is one: the buffer leaves points out of the fit, not
    out of the roof."""
    from scipy.spatial import cKDTree

    if info is not None and info.get("extent_labels") is not None and len(info["extent_labels"]) == len(labels):
        labels = info["extent_labels"]
    trees = [cKDTree(xyz[labels == k, :2]) for k in range(m)]
    spacing = _spacing(xyz, info)
    support = p.support_m if p.support_m is not None else max(1.5, 4.0 * spacing)
    return trees, spacing, support


def _triples(planes: Sequence[Plane], xyz: np.ndarray, p: ExtractionParams,
             face_support: tuple[list, float, float], reasons: list[str] | None = None):
    """Yield (triple, ControlPoint, support distances) for every supported triple.

    *face_support* is :func:`_face_support` of the faces.  Refusals of the
    intersection are appended to *reasons*.
    """
    from scipy.spatial import cKDTree

    m = len(planes)
    trees, spacing, support = face_support
    tree_all = cKDTree(xyz[:, :2])
    # adjacency: two faces touch when their points come within 2 x support
    adj = np.zeros((m, m), dtype=bool)
    for i in range(m):
        for j in range(i + 1, m):
            if len(trees[i].data) and len(trees[j].data):
                dd, _ = trees[j].query(trees[i].data, k=1, distance_upper_bound=2 * support)
                adj[i, j] = adj[j, i] = bool(np.isfinite(dd).any())
    for t in itertools.combinations(range(m), 3):
        if not (adj[t[0], t[1]] and adj[t[0], t[2]] and adj[t[1], t[2]]):
            continue
        cp = intersect_planes([planes[i] for i in t], min_dihedral_deg=p.min_dihedral_deg,
                              min_det=p.min_det)
        if not cp:
            if reasons is not None:
                reasons.append(cp.reason)
            continue
        x = cp.enh_m
        sup = [float(trees[i].query(x[:2], k=1)[0]) for i in t]
        if max(sup) > support:
            continue
        r_s = max(1.0, 2 * spacing)
        tan_max = max(math.tan(math.radians(min(planes[i].slope_deg, 80.0))) for i in t)
        if not _on_surface(x, xyz, tree_all, r_s, 0.2 + 0.5 * r_s * tan_max):
            continue
        yield t, cp, sup


def select_vertex(planes: Sequence[Plane], xyz: np.ndarray, labels: np.ndarray, center_en: Any,
                  p: ExtractionParams, *, point_id: str = "", info: dict | None = None,
                  others: list | None = None) -> ControlPoint:
    """Choose the vertex of 3+ planes nearest to *center_en* among the faces of a clip.

    A triple of faces qualifies when the faces touch, their intersection is
    well conditioned, lies within ``max_offset_m`` (default half the clip radius)
    of the position, every
    face has a point within ``support_m`` of it in plan, and it lies on the
    LiDAR surface.  Further faces join when their distance from the point is
    below ``join_sigma`` standard deviations plus half their RMS and they have
    a point within ``support_m``; the point is then re-intersected by least
    squares.  *others*, when given, receives the chosen vertex and every qualifying
    triple with a face that is not one of the chosen vertex's (E, N, h, 3-D sd), so that a
    caller can test the choice for ambiguity: a triple of the chosen vertex's own faces is
    that corner from fewer planes, not another corner.
    """
    center = np.asarray(center_en, dtype=np.float64).reshape(-1)[:2]
    info = info or {}
    planes = list(planes)
    keep = (xyz, labels)
    if len(planes) < 3:
        n_el = info.get("n_in_window", 0) + info.get("n_flat", 0) + info.get("n_steep", 0)
        if len(planes) == 0 and n_el and info.get("n_flat", 0) > 0.6 * n_el:
            return ControlPoint.failed(point_id, center, "flat_roof",
                                       f"{info['n_flat']} of {n_el} elements slope less than "
                                       f"{p.slope_min_deg:g} deg: a flat roof has no vertex", labels=keep)
        if len(planes) == 0 and n_el and info.get("n_steep", 0) > 0.6 * n_el:
            return ControlPoint.failed(point_id, center, "wall",
                                       f"{info['n_steep']} of {n_el} elements slope more than "
                                       f"{p.slope_max_deg:g} deg: a wall, or a roof steeper than the "
                                       f"slope window (raise slope_max_deg)", labels=keep)
        status = {0: "no_planes", 1: "one_plane", 2: "two_planes"}[len(planes)]
        extra = {0: f"no face with {p.slope_min_deg:g}-{p.slope_max_deg:g} deg slope and "
                    f">= {p.min_points} points",
                 1: "one face found; a point needs three",
                 2: "two faces found: they meet in a ridge line, not a point"}[len(planes)]
        return ControlPoint.failed(point_id, center, status, extra, planes=planes, labels=keep)
    max_off = p.max_offset_m if p.max_offset_m is not None else 0.5 * p.radius_m
    found = []
    reasons: list[str] = []
    face_support = _face_support(xyz, labels, len(planes), p, info)
    trees, _, support = face_support
    for t, cp, sup in _triples(planes, xyz, p, face_support, reasons):
        off = float(np.hypot(*(cp.enh_m[:2] - center)))
        if off <= max_off:
            sd3 = float(np.sqrt(max(np.trace(cp.cov_m2), 0.0)))
            found.append((off + 3.0 * sd3, t, cp))
    if not found:
        if reasons and len(planes) == 3:
            return ControlPoint.failed(point_id, center, "ill_conditioned", reasons[0],
                                       planes=planes, labels=keep)
        return ControlPoint.failed(point_id, center, "no_vertex",
                                   f"{len(planes)} faces, but no three of them meet within "
                                   f"{max_off:g} m of the position where all three have points",
                                   planes=planes, labels=keep)
    found.sort(key=lambda f: f[0])
    off, t, cp = found[0]
    x = cp.enh_m
    members = list(t)
    for k in range(len(planes)):
        if k in members:
            continue
        pl = planes[k]
        r = float(pl.distance(x[None])[0])
        xh = np.append(x - pl.centroid_m, 1.0)
        var = float(xh @ pl.cov_at(pl.centroid_m) @ xh + pl.n @ cp.cov_m2 @ pl.n)
        if abs(r) < p.join_sigma * math.sqrt(max(var, 0.0)) + 0.5 * pl.rms_m and \
                float(trees[k].query(x[:2], k=1)[0]) <= support:
            members.append(k)
    if len(members) > 3:
        cp2 = intersect_planes([planes[i] for i in members], min_dihedral_deg=p.min_dihedral_deg,
                               min_det=p.min_det)
        if cp2:
            cp = cp2
        else:
            members = list(t)
    if others is not None:  # the chosen vertex, and the triples with a face of their own (docstring)
        own = frozenset(members)
        others.append(np.append(cp.enh_m, _sd3(cp)))
        others.extend(np.append(c.enh_m, _sd3(c)) for _, tt, c in found if not own.issuperset(tt))
    sd3 = float(math.sqrt(max(np.trace(cp.cov_m2), 0.0)))
    status, reason = "ok", ""
    if not np.isfinite(sd3) or sd3 > p.max_sd_m:
        status, reason = "imprecise", (f"predicted 3-D sd {sd3:.3f} m exceeds {p.max_sd_m:g} m "
                                       f"(weak faces or grazing intersection)")
    return replace(cp, point_id=point_id, approx_en=center, status=status, reason=reason,
                   labels=keep)


def candidate_vertices(planes: Sequence[Plane], xyz: np.ndarray, labels: np.ndarray | None,
                       p: ExtractionParams, info: dict | None = None) -> list[np.ndarray]:
    """Every supported, well-conditioned vertex of 3 touching faces in a segmented area."""
    if labels is None or len(planes) < 3:
        return []
    out: list[np.ndarray] = []
    for t, cp, sup in _triples(planes, xyz, p, _face_support(xyz, labels, len(planes), p, info)):
        if all(np.hypot(*(cp.enh_m[:2] - v[:2])) > 0.5 for v in out):
            out.append(np.array(cp.enh_m))
    return out


# --------------------------------------------------------------------------- extraction
def _as_xyz(points: Any) -> np.ndarray:
    xyz = getattr(points, "xyz", points)
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"points must be an (N, 3) array or a PointCloud, got shape {xyz.shape}")
    return xyz


def extract_roof(
    points: Any,
    center_en: Any,
    *,
    radius_m: float | None = None,
    params: ExtractionParams | str | None = None,
    point_id: str = "",
    clipped: bool = False,
):
    """Extract the roof vertex nearest to *center_en* as a :class:`~lidarcat.control.vertices.ControlPoint`.

    Parameters
    ----------
    points : (N, 3) float or PointCloud
        LiDAR points E, N, h (m); may be a whole tile (clipped here) or a clip.
    center_en : (2,) float
        Approximate plan position of the vertex (m); a third value (h) is ignored.
    radius_m : float, optional
        Clip radius (default ``params.radius_m``).
    params : ExtractionParams or {"default", "thesis"}
    point_id : str
        Name carried into the control point.
    clipped : bool
        *points* is already the clip (skip the radius selection).

    Returns
    -------
    ControlPoint
        The vertex of the clip of ``params.fit_radius_m`` centred on the corner found (when not None:
        :mod:`lidarcat.control.localfit`; its clips are cut from *points*, so pass more than the clip).
        Truthy when a vertex of 3+ planes was found (and passed the radius-stability check,
        ``params.stability_scales``; its clips need the points within ``max(stability_scales) x
        radius_m`` of the vertex, so pass more than the clip, or *clipped* to skip the larger ones);
        otherwise falsy with ``status`` and ``reason`` (degenerate roofs never raise).

    Raises
    ------
    ValueError
        *center_en* has fewer than two values, or a parameter is invalid.

    Examples
    --------
    >>> from lidarcat.synthetic.roofs import synthetic_roof
    >>> scene = synthetic_roof("pyramid", density_m2=8, noise_h_m=0.03, seed=1)
    >>> cp = extract_roof(scene.xyz, scene.vertices[0, :2] + 0.8, radius_m=6)
    >>> cp.status, cp.n_planes
    ('ok', 4)
    >>> bool(np.all(np.abs(cp.enh_m - scene.vertices[0]) < 0.15))
    True
    """
    p = get_params(params, radius_m=radius_m)
    center = np.asarray(center_en, dtype=np.float64).reshape(-1)[:2]
    if center.shape != (2,):
        raise ValueError(f"center_en must be (E, N) in metres, got {center_en!r}")
    try:
        xyz = _as_xyz(points)
    except ValueError as ex:
        return ControlPoint.failed(point_id, center, "bad_input", str(ex))
    given = xyz
    if not clipped:
        xyz = xyz[np.sum((xyz[:, :2] - center) ** 2, axis=1) <= p.radius_m**2]
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    # the vertex asked for: the clip at the full radius, then (while the vertex found
    # is farther than near_m from the position) at the smaller radii of p.scales; a
    # larger clip holds more faces, and the faces of the corner asked for may merge
    # with others or fall below the max_planes largest
    max_off = p.max_offset_m if p.max_offset_m is not None else 0.5 * p.radius_m
    radii = _retry_radii(p)
    first, best, others = None, None, []
    for r in radii:
        pr = p.replace(radius_m=r, max_offset_m=max_off)
        sub = xyz if r == p.radius_m else xyz[np.sum((xyz[:, :2] - center) ** 2, axis=1) <= r * r]
        cp = _extract_clip(sub, center, pr, point_id, others)
        first = cp if first is None else first
        if cp.status in ("ok", "imprecise"):
            off = float(np.hypot(*(cp.enh_m[:2] - center)))
            # a smaller clip replaces the vertex only with ANOTHER corner nearer the position: the same
            # corner again (within _apart_m of it) is kept from the larger clip, whose faces hold more points;
            # "nearer" penalised by 3 x the 3-D sd, as select_vertex ranks the corners of one clip (a small
            # clip's few points give imprecise triples, of noise rather than of another corner)
            if best is None or (off + 3.0 * _sd3(cp) < best[0] + 3.0 * _sd3(best[1]) - 0.05
                                and np.hypot(*(cp.enh_m[:2] - best[1].enh_m[:2])) > _apart_m(best[1])):
                best = (off, cp)
            if best[0] <= min(p.near_m, 0.5 * _apart_m(best[1])):
                break
    if best is None:
        return first
    off, cp = best
    if p.fit_radius_m is not None:
        cp = _local_vertex(cp, given, p, point_id)
        off = float(np.hypot(*(cp.enh_m[:2] - center)))
    cp = _check_choice(cp, off, center, others, p)
    if cp.status == "ok" and p.stability_scales:
        cp = _check_stability(cp, given, center, p, point_id, clipped)
    return cp


def _local_vertex(cp: ControlPoint, given: np.ndarray, p: ExtractionParams, point_id: str) -> ControlPoint:
    """*cp* extracted again from the clip of ``fit_radius_m`` centred on it (:mod:`lidarcat.control.localfit`).

    The local clips are cut from the points given (all of them: a local clip may reach beyond the search
    clip when the vertex lies off its centre)."""
    q = p.replace(max_offset_m=None, stability_scales=())
    pts = given[np.all(np.isfinite(given), axis=1)]

    def extract(centre: np.ndarray, r: float) -> ControlPoint:
        sub = pts[np.sum((pts[:, :2] - centre) ** 2, axis=1) <= r * r]
        return _extract_clip(sub, centre, q.replace(radius_m=r), point_id, [])

    return extract_locally(cp, float(p.fit_radius_m), extract, _apart_m(cp))


def _check_stability(cp: ControlPoint, given: np.ndarray, center: np.ndarray, p: ExtractionParams,
                     point_id: str, clipped: bool) -> ControlPoint:
    """*cp*, or *cp* refused as ``unstable`` when it moves with the clip radius (:mod:`lidarcat.control.stability`).

    The check clips are cut from the points given and centred on the vertex found -- or, with the local
    extraction (``fit_radius_m``), on *center*, the position asked: there every clip that finds the corner
    gives the fixed point of :mod:`lidarcat.control.localfit`, and what is left to depend on the radius is
    where the search finds the corner, so the check repeats the request itself at the other radii.  When
    the points are only the clip of ``radius_m`` about *center* (``clipped``), a check clip that would
    reach beyond it is not tried."""
    at = np.asarray(center if p.fit_radius_m is not None else cp.enh_m[:2], dtype=np.float64)
    reach = p.radius_m - float(np.hypot(*(at - center)))
    scales = tuple(s for s in p.stability_scales if not clipped or s * p.radius_m <= reach)
    if not scales:
        return cp
    q = p.replace(stability_scales=())

    def extract(r: float) -> ControlPoint:
        return extract_roof(given, at, params=q.replace(radius_m=r), point_id=point_id)

    res = check_stability(cp, p.replace(stability_scales=scales), extract)
    return cp if res.stable else replace(cp, status="unstable", reason=res.reason)


#: the smallest clip radii of the retries (m): a corner whose faces are lost in every larger clip
#: (merged with a neighbour's, or below the max_planes largest) is still found in one of these
_MIN_RETRY_RADII_M = (4.0, 3.0)


def _retry_radii(p: ExtractionParams) -> list[float]:
    """Clip radii (m) tried in turn: ``radius_m``, then ``scales x radius_m`` and 4 and 3 m, descending, >= 3 m."""
    if not p.scales:
        return [p.radius_m]
    smaller = {round(f * p.radius_m, 6) for f in p.scales} | set(_MIN_RETRY_RADII_M)
    return [p.radius_m] + sorted((r for r in smaller if 3.0 <= r < p.radius_m - 1e-6), reverse=True)


def _sd3(cp: ControlPoint) -> float:
    """Root of the covariance trace (m; infinite when unknown)."""
    v = float(np.trace(cp.cov_m2))
    return math.sqrt(v) if np.isfinite(v) and v >= 0 else math.inf


def _apart_m(cp: ControlPoint) -> float:
    """Plan distance (m) beyond which another vertex is a distinct corner of *cp*: ``max(0.5, 4 sd_plan)``."""
    sd = np.asarray(getattr(cp, "sd_m", (np.nan, np.nan)), dtype=float)[:2]
    return max(0.5, 4.0 * float(np.hypot(*sd))) if np.all(np.isfinite(sd)) else 0.5


def _check_choice(cp: ControlPoint, off: float, center: np.ndarray, others: list,
                  p: ExtractionParams) -> ControlPoint:
    """Say when the chosen vertex is far from the position, or another one is about as near.

    *others* are the vertices each clip chose and the triples with a face not among the chosen vertex's
    (:func:`select_vertex`; a triple of the corner's own faces is that corner).  Another vertex counts as distinct
    when it lies farther than ``max(0.5 m, 4 sd_plan)`` from the chosen one (``sd_plan`` the chosen
    vertex's plan sd): the same corner found again in another clip."""
    apart = _apart_m(cp)
    rivals = []
    for v in others:
        if np.hypot(*(v[:2] - cp.enh_m[:2])) <= apart:
            continue
        d = float(np.hypot(*(v[:2] - center)))
        # "about as near" by the penalised distance select_vertex ranks with (a rival of a small clip's
        # few noisy points is no rival of a precise corner)
        if (d + 3.0 * v[3]) - (off + 3.0 * _sd3(cp)) < p.ambiguity_m and all(np.hypot(*(v[:2] - w[:2])) > apart for _, w in rivals):
            rivals.append((d, v))
    if rivals:
        listed = "; ".join(f"{v[0]:.2f} {v[1]:.2f} {v[2]:.2f} at {d:.2f} m"
                           for d, v in [(off, cp.enh_m)] + sorted(rivals, key=lambda r: r[0]))
        return replace(cp, status="ambiguous",
                       reason=f"{1 + len(rivals)} vertices about equally near the position "
                              f"(E N h at plan distance): {listed}; give a nearer position")
    if cp.status == "ok" and off > p.near_m:
        return replace(cp, reason=f"the nearest vertex found is {off:.2f} m from the position "
                                  f"(more than near_m = {p.near_m:g} m): check it is the one meant")
    return cp


def _extract_clip(xyz: np.ndarray, center: np.ndarray, p: ExtractionParams, point_id: str,
                  others: list) -> ControlPoint:
    """Height filter, faces and vertex of one clip (the points within ``p.radius_m``)."""
    from ..lidar.clipping import height_window_mask

    if len(xyz) < 3 * p.min_points:
        return ControlPoint.failed(point_id, center, "too_few_points",
                                   f"{len(xyz)} points within {p.radius_m:g} m; 3 planes need at "
                                   f"least {3 * p.min_points} (increase the radius or check the position)")
    xyz = xyz[height_window_mask(xyz[:, 2], p.height_filter, p.height_window_m)]
    if len(xyz) < 3 * p.min_points:
        return ControlPoint.failed(point_id, center, "too_few_points",
                                   f"{len(xyz)} points left after the {p.height_filter} height filter")
    try:
        planes, labels, info = segment_faces(xyz, p)
    except ValueError as ex:
        return ControlPoint.failed(point_id, center, "degenerate_points", str(ex))
    return select_vertex(planes, xyz, labels, center, p, point_id=point_id, info=info, others=others)


# --------------------------------------------------------------------------- candidates
@dataclass(frozen=True, eq=False)
class Candidate:
    """An automatically found roof vertex (thesis section 5.2) with a quality score in [0, 1]."""

    point: Any  # ControlPoint
    score: float

    def to_feature(self) -> dict[str, Any]:
        cp = self.point
        props = cp.to_row()
        props["score"] = self.score
        return {"type": "Feature", "geometry": {"type": "Point", "coordinates": [float(v) for v in cp.enh_m]},
                "properties": props}


def _score(cp: Any) -> float:
    if not cp:
        return 0.0
    sd3 = float(np.sqrt(np.trace(cp.cov_m2)))
    min_pts = min(pl.n_used for pl in cp.planes)
    rms = max(pl.rms_m for pl in cp.planes)
    return float(np.exp(-sd3 / 0.10) * min(1.0, min_pts / 30.0) * np.exp(-rms / 0.10)
                 * min(1.0, (cp.n_planes / 3.0)))


def find_candidates(
    cloud: Any,
    box: Any = None,
    *,
    params: ExtractionParams | str | None = None,
    cell_m: float = 20.0,
    min_score: float = 0.2,
    classes: Any = None,
    progress: Callable[[int], None] | None = None,
) -> list[Candidate]:
    """Scan a tile (or a box) and propose every roof vertex where 3+ planes meet.

    The box is cut into cells of *cell_m*; the faces of each cell are
    segmented together with 2 m of its neighbours, every triple of faces
    whose intersection is supported by all three faces gives a seed, which is
    then refined by :func:`extract_roof` at that position.  Duplicates (closer than
    1 m) keep the best score.

    Parameters
    ----------
    cloud : (N, 3) float or PointCloud
    box : (xmin, ymin, xmax, ymax), optional
        Default: the extent of the cloud.
    params : ExtractionParams or preset name
    cell_m : float
        Cell size (m).
    min_score : float
        Candidates below this quality are dropped.
    classes : sequence of int, optional
        Keep only these classification codes (e.g. ``[6]`` buildings); needs a PointCloud.
    progress : callable(int), optional
        Called with 1 after each cell (an increment, like ``click.progressbar.update``).

    Returns
    -------
    list of Candidate
        Sorted by decreasing score.

    Raises
    ------
    LidarFormatError
        *classes* given but the points carry no classification.
    """

    p = get_params(params)
    xyz, box = search_points(cloud, box, p, classes)
    if xyz is None:
        return []
    nx, ny = cell_counts(box, cell_m)
    found = search_cells(xyz, box, [(i, j) for i in range(nx) for j in range(ny)], p, cell_m, min_score,
                          progress=progress)
    return merge_candidates([c for _, c in found])


def search_points(cloud: Any, box: Any, p: ExtractionParams, classes: Any) -> tuple[np.ndarray | None, tuple]:
    """The points the search sees (class filter, box + radius) and the box; ``(None, box)`` when empty."""
    xyz = _as_xyz(cloud)
    if classes is not None:
        from ..errors import LidarFormatError

        cls = getattr(cloud, "attributes", {}).get("classification")
        if cls is None:
            raise LidarFormatError("classes: the points carry no classification; "
                                   "drop --classes or use LAS/LAZ tiles with classes")
        xyz = xyz[np.isin(np.asarray(cls), np.asarray(classes))]
    if len(xyz) == 0:
        return None, box
    if box is None:
        box = (*xyz[:, :2].min(axis=0), *xyz[:, :2].max(axis=0))
    xmin, ymin, xmax, ymax = (float(v) for v in box)
    # every clip of a candidate: its seed's ``radius_m`` and the radius-stability check's clips about its
    # vertex (search_margin_m of a block of no width); a cloud that holds them gives whole clips at the box's edge
    pad = search_margin_m(p, 0.0)
    inbox = (xyz[:, 0] >= xmin - pad) & (xyz[:, 0] <= xmax + pad) & \
            (xyz[:, 1] >= ymin - pad) & (xyz[:, 1] <= ymax + pad)
    xyz = xyz[inbox]
    return (xyz if len(xyz) else None), (xmin, ymin, xmax, ymax)


def cell_counts(box: Any, cell_m: float) -> tuple[int, int]:
    """Number of search cells along E and N (the last ones may be narrower)."""
    xmin, ymin, xmax, ymax = (float(v) for v in box)
    return (max(1, int(math.ceil((xmax - xmin) / cell_m))), max(1, int(math.ceil((ymax - ymin) / cell_m))))


def search_margin_m(p: ExtractionParams, cell_m: float) -> float:
    """Points a block of cells needs beyond its own area (m).

    A cell is segmented in a square of half-side ``max(w, h)/2 + 2`` about its
    centre (at most ``cell_m/2 + 2`` beyond an edge); each seed is refined
    with the points within ``radius_m`` of it, the vertex found is extracted
    again from the clips of ``fit_radius_m`` (up to ``LADDER[-1] x fit_radius_m``) about it
    (:mod:`lidarcat.control.localfit`)
    and checked (``p.stability_scales``, :mod:`lidarcat.control.stability`) with
    clips of up to ``max(stability_scales) x radius_m`` about it, the vertex
    within 1 m of its seed (a farther one is dropped, whatever its check).  So
    the reach is ``max(radius_m x max(1, stability_scales), 1.6 fit_radius_m) + 1``:
    13 m at the defaults (8 m, 1.5, 5 m), and the margin
    ``max(cell_m/2 + 2, reach) + 1`` (14 m; 13 m without the check).
    """
    reach = max(float(p.radius_m) * max((1.0, *p.stability_scales)), float(p.fit_radius_m or 0.0) * LADDER[-1]) + 1.0
    return max(cell_m / 2.0 + 2.0, reach) + 1.0


def search_cells(xyz: np.ndarray, box: Any, cells: Sequence[tuple[int, int]], p: ExtractionParams,
                  cell_m: float, min_score: float, progress: Callable[[int], None] | None = None
                  ) -> list[tuple[tuple[int, int, int], Candidate]]:
    """Candidates found in *cells* (``(i, j)`` indices), each tagged ``(i, j, k)`` with its seed's order.

    The result depends only on the points within :func:`search_margin_m` of
    the cells, in their given order, so a block of cells computed from a
    subset of the points (same order) gives the same candidates as the whole.
    """
    from scipy.spatial import cKDTree

    xmin, ymin, xmax, ymax = (float(v) for v in box)
    tree = cKDTree(xyz[:, :2])
    seeds: list[tuple[tuple[int, int, int], np.ndarray]] = []
    for i, j in cells:
        x0, y0 = xmin + i * cell_m, ymin + j * cell_m
        x1, y1 = min(x0 + cell_m, xmax), min(y0 + cell_m, ymax)
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        half = max(x1 - x0, y1 - y0) / 2 + 2.0
        # sorted: the points' order (hence the segmentation) must not depend on the tree's layout
        idx = tree.query_ball_point(c, r=half * math.sqrt(2), return_sorted=True)
        sub = xyz[idx]
        sub = sub[(np.abs(sub[:, 0] - c[0]) <= half) & (np.abs(sub[:, 1] - c[1]) <= half)]
        if len(sub) >= 3 * p.min_points:
            try:
                planes, labels, info = segment_faces(sub, p.replace(max_planes=60))
            except ValueError:
                planes, labels, info = [], None, None
            k = 0
            # info: the faces' extent (support before the break-line buffer) and the point spacing
            for v in candidate_vertices(planes, sub, labels, p, info=info):
                if x0 <= v[0] < x1 and y0 <= v[1] < y1:
                    seeds.append(((i, j, k), v))
                    k += 1
        if progress is not None:
            progress(1)
    found = []
    # every clip of a kept candidate (its seed's, the retries', the check's about a vertex within 1 m of
    # the seed) lies within the margin of no width of its seed: those points, in their order, give the
    # same clips as the whole cloud, without scanning it for each clip
    reach = search_margin_m(p, 0.0)
    for tag, v in seeds:
        near = xyz[tree.query_ball_point(v[:2], r=reach, return_sorted=True)]
        cp = extract_roof(near, v[:2], params=p, point_id="C{:d}_{:d}_{:d}".format(*tag))
        if not cp:
            continue
        if np.hypot(*(cp.enh_m[:2] - v[:2])) > 1.0:
            continue
        s = _score(cp)
        if s >= min_score:
            found.append((tag, Candidate(cp, s)))
    return found


def merge_candidates(cands: Sequence[Candidate]) -> list[Candidate]:
    """Best-first, duplicates (closer than 1 m in plan) dropped, renumbered ``C0001``...

    *cands* in seed order (cell ``i`` then ``j``, then the seed within the
    cell): ties of score keep that order, so the merge is deterministic.
    """
    cands = sorted(cands, key=lambda c: -c.score)
    kept: list[Candidate] = []
    for c in cands:
        if all(np.hypot(*(c.point.enh_m[:2] - k.point.enh_m[:2])) > 1.0 for k in kept):
            kept.append(c)
    return [Candidate(replace(c.point, point_id=f"C{k + 1:04d}"), c.score) for k, c in enumerate(kept)]
