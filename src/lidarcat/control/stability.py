r"""Radius stability of a roof vertex: the same corner from nested clips, and the test of how far it moved.

**Why.**  A vertex is a function of the points its clip holds and of how the
segmentation groups them into faces.  On real roofs some faces change with
the clip: the eaves' points, the clip's rim, a neighbour's face merged with
one of the corner's, a face that one clip splits and another does not
(docs/extraction.md, "Radius sweep").  Such a vertex moves with the clip
radius by more than its covariance explains, so its covariance is not the
whole truth about it.  :func:`check_stability` extracts the vertex again from
clips of other radii at the same position and tests the move; a vertex that
moves significantly is refused (status ``unstable`` of
:data:`lidarcat.control.vertices.STATUSES`, with the radii and the distance
in the reason), never silently replaced by one of the other clips'.

**The vertex as a linear function of its points' errors** (:func:`influence`).
Each face's plane comes from the Gauss-Helmert fit of :mod:`lidarcat.control.planes`,
linear in the condition errors :math:`\varepsilon` of its points:
:math:`\delta\theta_i = -Q_i A_i^T W_i \varepsilon_i` (:math:`\theta = (n, d)`,
:math:`Q_i` the 4 x 4 block of the bordered inverse, :math:`A_i` rows
:math:`(x_p^T, 1)` in a frame at the vertex, :math:`W_i` the condition
weights).  The plane's offset at the vertex is :math:`\delta r_i = e_4^T
\delta\theta_i` and the vertex :math:`\delta x = G\, \delta r` with
:math:`G = A^{-1}` for three planes (eq. 38) and :math:`G = (A^T \Sigma_r^{-1}
A)^{-1} A^T \Sigma_r^{-1}` for more (eq. 41 weighted), :math:`A` the normals.
So :math:`\delta x = \sum_p L_p \varepsilon_p` with, for a point *p* of face *i*,
:math:`L_p = w_p\, (a_p^T Q_i e_4)\, G_{:, i}` (the sign is immaterial for the
covariance).  The errors follow the fit's own model: an independent part of
variance :math:`\hat\sigma_0^2 / w_p` and one random offset per cell of the
fixed 1 m and 3 m grids, :math:`\hat\tau_k^2` (each with the t factor of its
redundancy, as in the fit).  Propagated, this reproduces the vertex's
reported covariance (:attr:`VertexInfluence.cov`; the sweep benchmark prints
the ratio of the traces, median 1.000).

**Covariance of the move** (:func:`difference_cov`).  Two clips of one corner
share points: the displacement :math:`d = x_b - x_a` is
:math:`\sum_p (L^b_p - L^a_p)\, \varepsilon_p` over the union of both clips'
points (a row absent from a clip is zero), so the points both clips fit with
the same face cancel, and only what differs between the clips moves the vertex.
A shared point carries the error model of clip *a*'s face.  The covariance is
:math:`\sum_p \sigma_p^2 \ell_p \ell_p^T + \sum_k \sum_{c}
s_{kc} s_{kc}^T` with :math:`\ell_p = L^b_p - L^a_p` and
:math:`s_{kc} = \sum_{p \in c} \tau_{k,p} \ell_p` per cell *c* of grid *k*.
Under the model :math:`M^2 = d^T \mathrm{Cov}(d)^{-1} d` is
:math:`\chi^2_3`: the test of whether the covariance explains the move.
(The lenient :math:`d^T (C_a + C_b)^{-1} d`, the clips taken as independent,
passes moves that the shared points forbid; the literal "moves by less than
its sd" cannot hold with honest sds, docs/extraction.md.)  When the
propagation does not reproduce a reported covariance (its trace off by more
than a factor of 2: seen on a few vertices of 4+ planes) the test falls back
to the lenient one and says so.

**The check** (:func:`check_stability`; ``ExtractionParams.stability_scales``,
default 0.5, 0.625, 0.75, 1.25 and 1.5 x the radius, i.e. 4, 5, 6, 10 and 12 m at the
default 8 m; ``stability_level`` 0.999; 5 m since session 9).  The vertex is extracted again from
clips of those radii centred on it (with their own retries; with whole faces,
``fit_radius_m=None``, centred on the vertex, not on the position asked at, so that
the clips are nested about the corner itself and the retries rarely run; with the
local extraction, the default, on the position asked: below), and the move to each clip that
returns a vertex is tested.  The vertex is refused when some move is both

- *significant*: :math:`M > \sqrt{\chi^2_3(\text{level})}` (4.03 at 99.9 %),
  the covariance does not explain it; and
- *material*: longer than the vertex's sd (the largest axis of its
  covariance), i.e. it changes the vertex by more than its stated uncertainty.

A significant move shorter than the sd (on the AHN3 sweep, 1-10 mm moves of
vertices with 10-30 mm sds, where the clips share nearly all points and one
reassigned edge point gives :math:`M > 4`) leaves the vertex within its sd of
every clip's; refusing it would cost a good control point for nothing.  A clip
that returns no vertex (or an ambiguous / imprecise one) gives no test and is
named in the reason; another corner returned by a clip is a move like any other.

**With the local extraction** (``fit_radius_m``, the default since session 9:
:mod:`lidarcat.control.localfit`), the vertex of every search clip that finds the corner is that of the
5 m clip centred on it, iterated to a fixed point; two search clips give the same vertex to the
iteration's 1 mm, *not* two estimates from partly different points.  A longer move means that the
local clip, centred where another search clip found the corner, segments the roof differently (a face
split, merged or reassigned near the corner): a second fixed point, an error the covariance does not
hold.  So the test is then the material one alone: some move longer than the vertex's sd refuses it.
On sparse, noisy roofs a second fixed point also comes from the rim alone: the clip centred a few
centimetres away holds other points on its rim, whose leverage on the planes' slopes moves the vertex --
sampling, which the covariance of the move holds.  On the sparsest case of the extraction Monte Carlo
(pyramid, 2 pts/m\ :sup:`2`, 0.15 m height noise; tests/control/test_control.py) the rule refuses 4 of
200 such vertices (moves of 1.04-1.43 sd, Mahalanobis distances 1.7-3.2).  It keeps refusing them: the
significance condition as well (session 10, measured and reverted) accepts on the AHN3 tiles eight more
``--find`` candidates (161), of which four move by more than their sd -- C0086 by 111 mm at 10 m (4.7 sd,
Mahalanobis 3.9), three by 1.1-1.4 sd -- control points that depend on the clip by more than their
stated uncertainty, which issue 29's sweep forbids.  The cost: 2 % of the corners on the sparsest roofs.
And the clips are centred on the position asked, not on the vertex: what is left to depend on the
radius is where the search clip finds the corner (the local iteration's start; on the AHN3 sweep
C0089's 4-10 m clips about its ``--find`` position, 135 mm from the vertex, end at a second fixed
point 105 mm away, while clips about the vertex all give the first), so the check repeats the request
itself at the other radii.
The Mahalanobis distance is still computed and named in the reason.  On the AHN3 sweep the check
radii 4, 5, 6, 10 and 12 m are radii of issue 29's sweep (in-sample), so the sweep also reports radii the
check does not use, 4.5-11.5 m (docs/extraction.md, "Local extraction").  5 m joined in session 9: with
4, 6, 10 and 12 m, one accepted vertex of the AHN3 ``--find`` candidates moved 194 mm at 5 m (2.1 sd,
Mahalanobis 4.5), a second fixed point no other radius showed.

Why these radii: the move of a vertex with the clip is not monotone in the
radius (a face merges, splits or loses its outer part at one radius and not
at the next).  On the session-6 sweep of the 178 ``--find`` candidates of the
AHN3 tiles (radii 4, 5, 6, 10 and 12 m against 8 m), 36 candidates failed the
difference test at some radius; testing only the ends (4 and 12 m) would have
caught 19 of them, 4, 6 and 12 m 28, and 4, 6, 10 and 12 m 35
(docs/extraction.md, "Radius sweep", item 5).  The level: the sweep judges at
99.9 %; five tests per vertex refuse well under 0.5 % of stable vertices by
chance with whole faces, and fewer still with the sd condition (the local rule
has no such bound: "With the local extraction" above).  Cost: the five clips hold
0.25 + 0.39 + 0.56 + 1.56 + 2.25 = 5.0 times the points of one, and each is segmented; the vertex's points must reach ``max(stability_scales) x radius_m``
beyond it (:func:`lidarcat.control.vertices.extract_roof` skips the larger
clips when it is given only the clip of ``radius_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from .._util.frozen import frozen_array
from .planes import t_factor

__all__ = ["VertexInfluence", "influence", "difference_cov", "move_distance", "StabilityResult",
           "check_stability", "stability_limit"]


@dataclass(frozen=True, eq=False)
class VertexInfluence:
    """A vertex as a linear function of its points' errors: ``dx = sum_p rows_p eps_p`` (:func:`influence`).

    Parameters
    ----------
    points_m : (P, 3) float
        The points of the vertex's faces (E, N, h; absolute), one row per point.
    rows : (P, 3) float
        ``L_p``: the vertex's change per unit condition error of the point (dimensionless).
    var_iid_m2 : (P,) float
        Variance of the point's independent error (m^2), t-corrected as the fit.
    tau_m : (P, K) float
        The sds (m) of the point's face's cell offsets, one per ``cells_m`` size (t-corrected).
    cov_m2 : (3, 3) float
        The covariance propagated from them (it reproduces the vertex's reported covariance).
    cells_m : tuple of float
        The grid sizes (m) of the cell offsets.
    """

    points_m: np.ndarray
    rows: np.ndarray
    var_iid_m2: np.ndarray
    tau_m: np.ndarray
    cov_m2: np.ndarray
    cells_m: tuple = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "points_m", frozen_array(self.points_m))
        object.__setattr__(self, "rows", frozen_array(self.rows))
        object.__setattr__(self, "var_iid_m2", frozen_array(self.var_iid_m2))
        object.__setattr__(self, "tau_m", frozen_array(self.tau_m))
        object.__setattr__(self, "cov_m2", frozen_array(self.cov_m2, shape=(3, 3)))
        object.__setattr__(self, "cells_m", tuple(float(c) for c in self.cells_m))


def influence(cp: Any, p: Any) -> VertexInfluence | None:
    """The vertex of *cp* as a linear function of its points' errors (module docstring).

    Parameters
    ----------
    cp : ControlPoint
        An extracted vertex with its planes and ``labels`` (the clip's points and face labels).
    p : ExtractionParams
        The parameters it was extracted with (point sds, ``cells_m``).

    Returns
    -------
    VertexInfluence or None
        None when *cp* carries no clip (``labels``) or a face cannot be refitted.
    """
    from .planes import fit_plane

    if cp.labels is None or len(cp.planes) < 3:
        return None
    xyz, labels = (np.asarray(a) for a in cp.labels)
    x0 = np.asarray(cp.enh_m, dtype=float)
    planes = list(cp.planes)
    nmat = np.array([pl.n for pl in planes])
    if len(planes) == 3:
        g = np.linalg.inv(nmat)
    else:
        var_r = np.maximum(np.array([pl.cov_at(x0)[3, 3] for pl in planes]), 1e-30)
        g = np.linalg.solve(nmat.T @ (nmat / var_r[:, None]), nmat.T / var_r[None, :])
    sd = np.array([p.sd_en_m, p.sd_en_m, p.sd_h_m])
    cells = tuple(float(c) for c in p.cells_m)
    keys, rows, var_iid, taus = [], [], [], []
    for i, pl in enumerate(planes):
        pts = xyz[labels == pl.label]
        m = len(pts)
        if m < 4:
            return None
        loc = pts - x0
        fit = fit_plane(loc, sd_m=sd, residual_threshold_m=1e9, min_points=3, cells_m=cells,
                        grid_origin_m=x0[:2], posterior_variance=p.posterior_variance)
        if not fit:
            return None
        n = fit.plane.n
        comps = np.asarray(fit.components or (fit.sigma0**2,), dtype=float)
        w = 1.0 / float((sd**2) @ (n * n))
        a = np.column_stack([loc, np.ones(m)])
        big = np.zeros((5, 5))
        big[:4, :4] = w * a.T @ a
        big[:3, 4] = big[4, :3] = n
        q = np.linalg.inv(big)[:4, :4]
        keys.append(pts)
        rows.append(np.outer(w * (a @ q[3]), g[:, i]))
        var_iid.append(np.full(m, t_factor(m - 3) * comps[0] / w))
        # each cell component with the t factor of its own redundancy (cells - 3), as the fit
        tk = [t_factor(len(np.unique(np.floor(pts[:, :2] / c).astype(np.int64), axis=0)) - 3) for c in cells]
        tau = np.zeros(len(cells))
        if len(comps) > 1:
            tau = np.sqrt(np.asarray(tk) * np.maximum(comps[1:], 0.0))
        taus.append(np.tile(tau, (m, 1)))
    pts = np.vstack(keys)
    rows_a, var_a = np.vstack(rows), np.concatenate(var_iid)
    tau_a = np.vstack(taus) if cells else np.zeros((len(pts), 0))
    return VertexInfluence(pts, rows_a, var_a, tau_a, _cov_of(pts, rows_a, var_a, tau_a, cells), cells)


def _cov_of(points: np.ndarray, rows: np.ndarray, var_iid: np.ndarray, taus: np.ndarray,
            cells_m: tuple) -> np.ndarray:
    """Covariance (3, 3) of ``sum_p rows_p eps_p`` under the error model of :func:`influence`."""
    cov = (rows * var_iid[:, None]).T @ rows
    for k, c in enumerate(cells_m):
        _, inv = np.unique(np.floor(points[:, :2] / c).astype(np.int64), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        s = np.stack([np.bincount(inv, weights=taus[:, k] * rows[:, j]) for j in range(3)], axis=1)
        cov = cov + s.T @ s
    return 0.5 * (cov + cov.T)


def difference_cov(b: VertexInfluence, a: VertexInfluence) -> np.ndarray:
    """Covariance (3, 3) of ``x_b - x_a`` for two vertices of clips that share points (module docstring).

    A point in both clips (the same coordinates) carries the error model of *a* (the reference clip's
    face); its rows subtract.

    Examples
    --------
    >>> one = VertexInfluence(np.eye(3), np.eye(3), np.ones(3), np.zeros((3, 0)), np.eye(3))
    >>> difference_cov(one, one).tolist()  # the same points: no move
    [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    """
    points = np.vstack([b.points_m, a.points_m])
    _, inv = np.unique(points, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    n_b = len(b.points_m)
    u = int(inv.max()) + 1
    rows = np.zeros((u, 3))
    np.add.at(rows, inv[:n_b], b.rows)
    np.add.at(rows, inv[n_b:], -a.rows)
    k = b.tau_m.shape[1]
    var_iid, taus = np.zeros(u), np.zeros((u, k))
    var_iid[inv[:n_b]], taus[inv[:n_b]] = b.var_iid_m2, b.tau_m
    var_iid[inv[n_b:]], taus[inv[n_b:]] = a.var_iid_m2, a.tau_m  # the reference's model where both have the point
    pts = np.zeros((u, 3))
    pts[inv] = points
    return _cov_of(pts, rows, var_iid, taus, a.cells_m)


def _consistent(inf: VertexInfluence | None, cov_m2: np.ndarray) -> bool:
    """The propagation reproduces the reported covariance (trace within a factor of 2)."""
    if inf is None:
        return False
    t = float(np.trace(cov_m2))
    return bool(np.isfinite(t) and t > 0 and 0.5 <= float(np.trace(inf.cov_m2)) / t <= 2.0)


def move_distance(b: Any, a: Any, inf_b: VertexInfluence | None, inf_a: VertexInfluence | None
                  ) -> tuple[float, bool]:
    """Mahalanobis distance of the move ``x_b - x_a`` of two extractions of one corner, and whether it is exact.

    Exact: with :func:`difference_cov` (chi2_3 under the fit's model).  When either influence is missing or
    does not reproduce its vertex's covariance, the lenient ``sqrt(d' (C_a + C_b)^-1 d)`` (False).
    """
    d = np.asarray(b.enh_m, dtype=float) - np.asarray(a.enh_m, dtype=float)
    if _consistent(inf_b, b.cov_m2) and _consistent(inf_a, a.cov_m2):
        c = difference_cov(inf_b, inf_a)
        bound = 4.0 * float(np.trace(a.cov_m2) + np.trace(b.cov_m2))
        if np.all(np.isfinite(c)) and float(np.trace(c)) <= bound:
            # + (1 um)^2: the same points in both clips give the same vertex (c = 0, d = 0)
            return float(math.sqrt(max(float(d @ np.linalg.solve(c + 1e-12 * np.eye(3), d)), 0.0))), True
    c = np.asarray(a.cov_m2, dtype=float) + np.asarray(b.cov_m2, dtype=float)
    return float(math.sqrt(max(float(d @ np.linalg.solve(c + 1e-12 * np.eye(3), d)), 0.0))), False


def stability_limit(level: float) -> float:
    """``sqrt(chi2_3(level))``: the Mahalanobis distance of a 3-D move refused at *level* (4.03 at 0.999).

    >>> round(stability_limit(0.999), 3)
    4.033
    """
    from scipy.stats import chi2

    return float(math.sqrt(chi2.ppf(level, 3)))


@dataclass(frozen=True)
class StabilityResult:
    """The check of one vertex (:func:`check_stability`).

    ``tests``: per check radius tried, ``(radius_m, status of that clip, move (m), Mahalanobis distance, exact)``
    (move and distance NaN when the clip returned no vertex); ``stable`` False when some move exceeds both
    ``limit`` (Mahalanobis) and ``sd_m`` (the largest axis of the vertex's covariance, m); ``reason`` the
    refusal's text (empty when stable).
    """

    stable: bool
    limit: float
    sd_m: float
    tests: tuple = ()
    reason: str = ""


def check_stability(cp: Any, p: Any, extract: Callable[[float], Any]) -> StabilityResult:
    """Test whether the vertex *cp* (extracted at ``p.radius_m``) moves with the clip radius.

    Parameters
    ----------
    cp : ControlPoint
        The vertex, ``ok``, with its planes and clip (``labels``).
    p : ExtractionParams
        Its parameters: ``radius_m``, ``stability_scales``, ``stability_level``, the point sds.
    extract : callable(radius_m) -> ControlPoint
        The same extraction (same points, same position) at another clip radius, without this check.

    Returns
    -------
    StabilityResult
        Not stable when the move to some check radius's vertex has a Mahalanobis distance (with the
        covariance of the difference, module docstring) above ``sqrt(chi2_3(stability_level))`` and is
        longer than the vertex's sd (the largest axis of its covariance).
    """
    limit = stability_limit(p.stability_level)
    sd_m = float(math.sqrt(max(float(np.linalg.eigvalsh(np.asarray(cp.cov_m2, dtype=float))[-1]), 0.0)))
    inf_ref = influence(cp, p)
    tests = []
    for s in p.stability_scales:
        r = float(s) * float(p.radius_m)
        other = extract(r)
        if other.status != "ok":
            tests.append((r, other.status, math.nan, math.nan, False))
            continue
        m, exact = move_distance(other, cp, influence(other, p), inf_ref)
        tests.append((r, "ok", float(np.linalg.norm(np.asarray(other.enh_m) - np.asarray(cp.enh_m))), m, exact))
    local = p.fit_radius_m is not None
    # the local extraction: every search clip that finds the corner ends at one fixed point, so any move
    # longer than the sd is a second fixed point, not sampling (module docstring, "With the local extraction")
    bad = [t for t in tests if np.isfinite(t[2]) and t[2] > sd_m and (local or (np.isfinite(t[3]) and t[3] > limit))]
    if not bad:
        return StabilityResult(True, limit, sd_m, tuple(tests))
    parts = []
    for r, status, d, m, exact in sorted(tests, key=lambda t: t[0]):
        if status != "ok":
            parts.append(f"{r:g} m {status}")
        else:
            parts.append(f"{r:g} m {1000 * d:.0f} mm, {'M' if exact else 'M_ind'} {m:.2f}")
    if local:
        reason = (f"the vertex moves with the clip radius: from the {p.radius_m:g} m clip's vertex by more than "
                  f"its sd ({1000 * sd_m:.0f} mm) in clips about it of {'; '.join(parts)}: its clip of "
                  f"{p.fit_radius_m:g} m gives another vertex when centred where another search clip finds the "
                  f"corner (faces split, merged or reassigned near it); "
                  f"check the roof, or ask at another position or radius")
    else:
        reason = (f"the vertex moves with the clip radius: from the {p.radius_m:g} m clip's vertex by more than "
                  f"its sd ({1000 * sd_m:.0f} mm) and than the covariance of the move explains (Mahalanobis "
                  f"distance above {limit:.2f}, chi2_3 {100 * p.stability_level:g} %) in clips about it of "
                  f"{'; '.join(parts)}: its faces depend on the clip (a face not plane over its extent, eaves, the "
                  f"clip's rim, a neighbour's face); "
                  f"check the roof, or ask at another position or radius")
    return StabilityResult(False, limit, sd_m, tuple(tests), reason)
