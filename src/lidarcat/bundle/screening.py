r"""Screening tie points by their intersection geometry, before any least-squares step.

Automatic matching delivers a few per cent of gross observations (a feature matched to
the wrong place, hundreds of pixels off).  Such a point, intersected from the approximate
orientation, can land behind a camera or kilometres away; the first linearisation of the
bundle adjustment is then meaningless and the iteration stalls before any test can run.
The screening looks at every point on its own, with the orientations held at their
approximate values.

Intersection and the residual of a ray
--------------------------------------
A ray of photo ``s`` leaves the projection centre ``O_s`` in the direction
``d_s = M_s^T (x, y, -c)^T / |.|``.  The least-squares intersection of the rays of a point
minimises the sum of squared perpendicular distances, ``sum_s |P_s (X - O_s)|^2`` with
``P_s = I - d_s d_s^T``:

    (sum_s P_s) X = sum_s P_s O_s.

The perpendicular distance ``e_s = |P_s (X - O_s)|`` seen from the camera at the range
``D_s = d_s . (X - O_s)`` is the image residual ``c e_s / D_s`` (mm, to first order); a
negative range puts the point behind the camera.

What is tested
--------------
The sd of a ray's image residual combines the measurement and what the approximate
orientation is worth (its weighted constraints, ``eo_constraint_sd``):

    sigma_s^2 = sd_img^2 + (c sigma_att)^2 (1 + rho^2 / c^2)^2 + (c sigma_pos / D_s)^2,

``rho`` the radial distance of the observation, ``sigma_att`` and ``sigma_pos`` the largest
attitude (rad) and position (m) sd of the photo (0 when unconstrained).  A point's statistic
is ``T = sum_s (c e_s / D_s)^2 / sigma_s^2`` (about chi-square with ``2n - 3`` dof for n rays):

* **two-ray points**: ``sqrt(T)`` is the normalised y-parallax (the distance between the two
  rays in the image); beyond ``k`` both rays are flagged: no test can tell which of the two is
  wrong, and a point with one ray has no intersection;
* **points with three rays or more**: leave one ray out, intersect the others, and take the
  ray whose removal lowers ``T`` most (``T - T_{-s}``, the squared normalised residual of the
  ray against the intersection of the others); beyond ``k^2`` it is flagged and the point is
  screened again without it, until no ray is flagged or two are left;
* **a point behind a camera**, or whose rays do not intersect (nearly parallel), has every ray
  flagged when it has two rays; with more, the leave-one-out step finds the ray that puts it
  there.

The threshold is ``k`` times the sd above, scaled by ``s = max(1, 1.4826 median(sqrt(T / dof)))``
over the block (the median absolute deviation of the normalised residuals): an approximate
orientation worse than its stated sds raises every residual, and the screening then flags only
the rays that stand out of the block's own spread.  The screening flags; the bundle
adjustment with robust weights and data snooping that follows decides (see
:mod:`lidarcat.bundle.robust`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..geometry.collinearity import rotation_matrix
from .._util.frozen import frozen_array
from .problem import BundleProblem

__all__ = ["Screening", "screen", "photo_sd", "intersect_rays", "SCREEN_K", "SCREEN_REASONS"]

#: default threshold of the screening, in (scaled) sds of a ray
SCREEN_K = 10.0
#: the reasons a ray is flagged
SCREEN_REASONS = ("", "parallax", "ray", "behind", "no intersection", "last ray")
#: rays are parallel when the smallest eigenvalue of sum P_s is below this share of the largest
_PARALLEL = 1e-8


@dataclasses.dataclass(frozen=True, eq=False)
class Screening:
    """Outcome of :func:`screen`.

    Attributes
    ----------
    flagged : (n,) bool
        Observations flagged (in the order of the problem's observations).
    reason : (n,) str
        ``parallax`` (a two-ray point), ``ray`` (the worst ray of a point with more), ``behind``
        (the point lies behind one of its cameras), ``no intersection`` (parallel rays),
        ``last ray`` (the other rays of its point were flagged); empty when kept.
    ratio : (n,) float
        Normalised residual of the ray over the threshold ``k s`` (the largest seen; > 1
        flagged, inf behind a camera).
    residual_mm : (n,) float
        The image residual ``c e / D`` of the ray at the intersection it was judged by, mm.
    points_m : (Q, 3) float
        Intersections from the kept rays (NaN where fewer than two are kept).
    k, scale : float
        Threshold and the block's robust scale ``s``.
    """

    flagged: np.ndarray
    reason: np.ndarray
    ratio: np.ndarray
    residual_mm: np.ndarray
    points_m: np.ndarray
    k: float
    scale: float

    def __post_init__(self) -> None:
        for f in ("flagged", "reason", "ratio", "residual_mm", "points_m"):
            object.__setattr__(self, f, frozen_array(getattr(self, f), dtype=None))

    @property
    def n_flagged(self) -> int:
        return int(self.flagged.sum())


def _rays(p: BundleProblem, eo: np.ndarray):
    """Unit directions (n, 3) in object space and projection centres (n, 3) of every observation."""
    ei = p.photo_index
    m = rotation_matrix(eo[ei, 3:6])
    v = np.concatenate([p.xy_mm, -p.focal_length_mm[ei][:, None]], axis=1)
    d = np.einsum("nji,nj->ni", m, v)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return d, eo[ei, :3]


def _intersect(pj: np.ndarray, d: np.ndarray, o: np.ndarray, n_pt: int):
    """Least-squares intersection of rays (d, o) grouped by point *pj*; ``(X (Q, 3), ok (Q,))``."""
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A = np.zeros((n_pt, 3, 3))
    b = np.zeros((n_pt, 3))
    np.add.at(A, pj, proj)
    np.add.at(b, pj, np.einsum("nij,nj->ni", proj, o))
    X = np.full((n_pt, 3), np.nan)
    w = np.linalg.eigvalsh(A)
    ok = (w[:, 0] > _PARALLEL * np.maximum(w[:, -1], 1e-300)) & (np.bincount(pj, minlength=n_pt) >= 2)
    if ok.any():
        X[ok] = np.linalg.solve(A[ok], b[ok][:, :, None])[:, :, 0]
    return X, ok, A, b, proj


def _image_residual(X: np.ndarray, d: np.ndarray, o: np.ndarray, c: np.ndarray):
    """Image residual ``c e / D`` (mm) of rays (d, o) at points X (n, 3), and the range D (m)."""
    rel = X - o
    rng = np.einsum("ni,ni->n", rel, d)
    perp = rel - rng[:, None] * d
    e = np.linalg.norm(perp, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.where(rng > 0, c * e / rng, np.inf)
    return res, rng


def _sigma_ray(p: BundleProblem, eo_sd: np.ndarray, rng: np.ndarray) -> np.ndarray:
    """sd of the image residual of every ray (n,), mm (module docstring)."""
    ei = p.photo_index
    c = p.focal_length_mm[ei]
    sd_img2 = np.mean(p.sd_mm**2, axis=1)
    att = eo_sd[ei, 3:].max(axis=1)
    pos = eo_sd[ei, :3].max(axis=1)
    rho2 = np.sum(p.xy_mm**2, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        pos_term = np.where(rng > 0, c * pos / np.where(rng > 0, rng, 1.0), 0.0)
    return np.sqrt(sd_img2 + (c * att * (1 + rho2 / c**2)) ** 2 + pos_term**2)


def photo_sd(p: BundleProblem) -> np.ndarray:
    """Largest-case sds (P, 6) of the approximate orientation: its weighted constraints, 0 where none."""
    sd = np.zeros((p.n_photos, 6))
    if p.eo_constraint_photo_index is not None and len(p.eo_constraint_photo_index):
        s = np.where(np.isfinite(p.eo_constraint_sd), p.eo_constraint_sd, 0.0)
        sd[p.eo_constraint_photo_index] = s
    return sd


def screen(problem: BundleProblem, eo: np.ndarray, *, k: float = SCREEN_K, eo_sd: np.ndarray | None = None,
           active: np.ndarray | None = None, max_rounds: int = 10) -> Screening:
    """Flag the observations whose ray does not meet the others of its point (module docstring).

    Parameters
    ----------
    problem : BundleProblem
    eo : (P, 6) array
        Approximate orientations (m, rad).
    k : float
        Threshold in sds of a ray (scaled by the block's robust scale).
    eo_sd : (P, 6) array, optional
        sds of the approximate orientations (m, rad); default: the problem's weighted
        GNSS/INS constraints (0 for a photo without).
    active : (n,) bool, optional
        Observations taking part (the others are ignored and not flagged).
    max_rounds : int
        Rounds of leave-one-out on points with three rays or more.

    Returns
    -------
    Screening

    Examples
    --------
    Two photos 600 m apart at 1,000 m looking down, three points, the second measured 0.2 mm off
    in y on the first photo (a y-parallax of 40 sds):

    >>> import numpy as np
    >>> from lidarcat.bundle import BundleProblem
    >>> from lidarcat.geometry.collinearity import project
    >>> eo = np.array([[0., 0., 1000., 0., 0., 0.], [600., 0., 1000., 0., 0., 0.]])
    >>> X = np.array([[300., 0., 0.], [300., 200., 0.], [300., -200., 0.]])
    >>> pi, pj = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)
    >>> xy = project(eo, X[pj], np.full(6, 100.), pi)[0]
    >>> xy[1, 1] += 0.2
    >>> prob = BundleProblem(["a", "b"], ["p", "q", "r"], 100., pi, pj, xy, 0.005,
    ...                      np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)))
    >>> s = screen(prob, eo)
    >>> s.flagged.tolist(), s.reason[1]
    ([False, True, False, False, True, False], 'parallax')
    """
    p = problem
    eo = np.asarray(eo, dtype=float).reshape(p.n_photos, 6)
    n, n_pt = len(p.photo_index), p.n_points
    act = np.ones(n, dtype=bool) if active is None else np.array(active, dtype=bool)
    sd = photo_sd(p) if eo_sd is None else np.asarray(eo_sd, dtype=float).reshape(p.n_photos, 6)
    d, o = _rays(p, eo)
    c = p.focal_length_mm[p.photo_index]
    pj = p.point_index
    flagged = np.zeros(n, dtype=bool)
    reason = np.full(n, "", dtype=object)
    ratio = np.zeros(n)
    resid = np.full(n, np.nan)

    def state(use):
        idx = np.flatnonzero(use)
        X, ok, A, b, proj = _intersect(pj[idx], d[idx], o[idx], n_pt)
        res, rng = _image_residual(X[pj[idx]], d[idx], o[idx], c[idx])
        sig = _sigma_ray(_sub(p, idx), sd, rng)
        return idx, X, ok, A, b, proj, res, rng, sig

    # the block's robust scale from every point's normalised residual at the start
    idx, X, ok, A, b, proj, res, rng, sig = state(act)
    nray = np.bincount(pj[idx], minlength=n_pt)
    T = np.bincount(pj[idx], weights=np.where(np.isfinite(res), (res / sig) ** 2, 0.0), minlength=n_pt)
    dof = np.maximum(2 * nray - 3, 1)
    good = ok & (nray >= 2) & np.isfinite(T)
    scale = 1.0
    if good.any():
        scale = max(1.0, 1.4826 * float(np.median(np.sqrt(T[good] / dof[good]))))
    thr = k * scale
    resid[idx] = res
    ratio[idx] = np.where(np.isfinite(res), res / sig, np.inf) * (np.sqrt(2.0) / thr)

    # two-ray points (and points that cannot be intersected or lie behind a camera)
    behind = np.zeros(n_pt, dtype=bool)
    np.logical_or.at(behind, pj[idx], rng <= 0)
    bad_pt = (nray >= 2) & (~ok | behind)
    two = (nray == 2) & ok & ~behind & (np.sqrt(T) > thr)
    for mask_pt, why in ((two, "parallax"), (bad_pt & (nray == 2), None)):
        hit = idx[mask_pt[pj[idx]]]
        flagged[hit] = True
        if why is None:
            reason[hit] = np.where(behind[pj[hit]], "behind", "no intersection")
            ratio[hit] = np.inf
        else:
            reason[hit] = why
    # three rays or more: leave one out, flag the ray whose removal lowers T most, repeat
    for _ in range(max_rounds):
        use = act & ~flagged
        idx, X, ok, A, b, proj, res, rng, sig = state(use)
        nray = np.bincount(pj[idx], minlength=n_pt)
        many = nray[pj[idx]] >= 3
        if not many.any():
            break
        r = idx[many]                          # observations of points with >= 3 rays
        jr = pj[r]
        A_loo = A[jr] - proj[many]
        b_loo = b[jr] - np.einsum("nij,nj->ni", proj[many], o[r])
        wv = np.linalg.eigvalsh(A_loo)
        solv = wv[:, 0] > _PARALLEL * np.maximum(wv[:, -1], 1e-300)
        X_loo = np.full((len(r), 3), np.nan)
        X_loo[solv] = np.linalg.solve(A_loo[solv], b_loo[solv][:, :, None])[:, :, 0]
        # T of the point without ray r at X_loo: the rays s != r of the same point, pairwise
        T_all = np.bincount(pj[idx], weights=np.where(np.isfinite(res), (res / sig) ** 2, 1e30),
                            minlength=n_pt)
        order = np.argsort(jr, kind="stable")
        starts = np.r_[0, np.flatnonzero(np.diff(jr[order])) + 1]
        counts = np.diff(np.r_[starts, len(order)])
        # pairs (a: the left-out ray, b: another ray of its point), positions in r
        grp = np.repeat(np.arange(len(starts)), counts)
        a_pos = np.repeat(order, counts[grp])
        first = np.repeat(starts[grp], counts[grp])
        within = np.arange(len(a_pos)) - np.repeat(np.cumsum(counts[grp]) - counts[grp], counts[grp])
        b_pos = order[first + within]
        keep = a_pos != b_pos
        a_pos, b_pos = a_pos[keep], b_pos[keep]
        rb, _ = _image_residual(X_loo[a_pos], d[r[b_pos]], o[r[b_pos]], c[r[b_pos]])
        sig_r = sig[many]
        term = np.where(np.isfinite(rb), (rb / sig_r[b_pos]) ** 2, 1e30)
        T_loo = np.bincount(a_pos, weights=term, minlength=len(r))
        T_loo[~solv] = np.inf
        gain = T_all[jr] - T_loo                       # how much leaving ray r out lowers T
        # the best ray to leave out per point
        best = np.full(n_pt, -np.inf)
        np.maximum.at(best, jr, gain)
        is_best = gain >= best[jr]
        # one per point: the first of the maxima
        chosen = np.zeros(len(r), dtype=bool)
        seen = np.zeros(n_pt, dtype=bool)
        for t in np.flatnonzero(is_best & (gain > thr**2)):
            if not seen[jr[t]]:
                seen[jr[t]] = True
                chosen[t] = True
        if not chosen.any():
            break
        # the ray's own residual against the others' intersection
        own, _ = _image_residual(X_loo, d[r], o[r], c[r])
        hit = r[chosen]
        flagged[hit] = True
        reason[hit] = np.where(np.isfinite(own[chosen]), "ray", "behind")
        ratio[hit] = np.sqrt(np.maximum(gain[chosen], 0.0)) / thr
        resid[hit] = own[chosen]
    # a point left with one ray has no intersection: that ray goes too
    use = act & ~flagged
    left = np.bincount(pj[use], minlength=n_pt)
    lone = use & (left[pj] == 1) & (np.bincount(pj[act], minlength=n_pt)[pj] >= 2)
    flagged[lone] = True
    reason[lone] = "last ray"
    X, ok, *_ = _intersect(pj[act & ~flagged], d[act & ~flagged], o[act & ~flagged], n_pt)
    # the kept rays judged at the final intersection (a residual of n rays has about (n - 1) / n of
    # the ray's variance)
    kept = np.flatnonzero(act & ~flagged & ok[pj])
    if len(kept):
        res_k, rng_k = _image_residual(X[pj[kept]], d[kept], o[kept], c[kept])
        sig_k = _sigma_ray(_sub(p, kept), sd, rng_k)
        nr = np.bincount(pj[kept], minlength=n_pt)[pj[kept]].astype(float)
        resid[kept] = res_k
        ratio[kept] = res_k / sig_k * np.sqrt(nr / np.maximum(nr - 1, 1)) / thr
    return Screening(flagged=flagged, reason=reason, ratio=ratio, residual_mm=resid, points_m=X,
                     k=float(k), scale=float(scale))


def intersect_rays(problem: BundleProblem, eo: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
    """Least-squares intersection (Q, 3) of every point from the rays *active* (default all) at the
    orientations *eo* (P, 6); NaN for a point with fewer than two rays or parallel rays."""
    p = problem
    use = np.ones(len(p.photo_index), dtype=bool) if active is None else np.asarray(active, dtype=bool)
    d, o = _rays(p, np.asarray(eo, dtype=float).reshape(p.n_photos, 6))
    return _intersect(p.point_index[use], d[use], o[use], p.n_points)[0]


def _sub(p: BundleProblem, idx: np.ndarray):
    """A light view of *p* restricted to observations *idx* (the fields :func:`_sigma_ray` reads)."""
    return _View(p.photo_index[idx], p.focal_length_mm, p.sd_mm[idx], p.xy_mm[idx])


@dataclasses.dataclass(frozen=True)
class _View:
    photo_index: np.ndarray
    focal_length_mm: np.ndarray
    sd_mm: np.ndarray
    xy_mm: np.ndarray
