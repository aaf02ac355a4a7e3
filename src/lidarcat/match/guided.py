r"""Guided matching: predict where a feature of photo A must appear in photo B, search only there.

Prediction
----------
With approximate orientations ``p_A``, ``p_B`` (X0, Y0, Z0, omega, phi, kappa) and a height
surface, a feature at pixel ``a`` of A is transferred to ``b = T(a; p_A, p_B, dh)``: A's ray
met with the surface raised by ``dh``, projected into B (:func:`lidarcat.match.rays.transfer`).

Uncertainty
-----------
The orientations and the surface are uncertain: ``p_A``, ``p_B`` with standard deviations
``sd_position_m`` (each of X0, Y0, Z0) and ``sd_angle_deg`` (each angle), the height with
``surface.sd_m``, independent.  First-order propagation through ``T`` gives the 2 x 2
covariance of the predicted pixel ::

    Σ_b = J Σ_θ J^T + σ_f² I,    J = ∂b/∂θ,  θ = (p_A, p_B, dh)  (13 parameters),

``σ_f`` the feature's own localisation (1 px at the detection level).  ``J`` is computed by
central differences (26 vectorised transfers of all features: the transfer is smooth and the
steps -- 1 cm, 1e-6 rad, 1 cm -- are far inside its linear range).  The perturbed transfers
stop at B's distortion-corrected photo coordinates ``x_B`` (a projection, no iteration); the
pixel Jacobian follows by the chain rule ``∂b/∂θ = (∂x_B/∂b)^{-1} ∂x_B/∂θ`` with B's
distortion Jacobian at ``b`` -- one inversion of B's distortion per feature instead of 27
(the covariance agrees with 27 full transfers to 1e-9).  The true position lies
in the ellipse ::

    (b' - b)^T Σ_b^{-1} (b' - b) <= χ²_2(1 - α) = -2 ln α,

with probability ``1 - α`` (``α = 0.001``: ``χ² = 13.8``, 3.7 sd).  Only the features of B
inside a feature's ellipse are candidates.

Matching
--------
Among the candidates of a feature of A, the nearest descriptor (Euclidean distance of the
SIFT vectors) is accepted when it passes Lowe's ratio test, ``d1 < ratio · d2`` against the
second nearest candidate (a lone candidate passes), and the mutual check: the feature of A
is also the nearest among all features of A whose ellipses hold that feature of B.
Without orientations (:func:`match_descriptors`) the candidates are all features of B and the
same ratio and mutual rules apply (OpenCV's brute-force matcher).

The candidate search takes B's features in the grid cells (sorted by cell) that cover each
ellipse's bounding box ``b ± sqrt(χ² diag Σ_b)``, all queries at once by ``np.repeat``, followed by
the exact Mahalanobis test; the descriptor distances of the candidate pairs are computed in
chunks, so memory grows with the candidates, never with ``n_A x n_B``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from ..geometry.collinearity import project, rotation_matrix
from .rays import HeightSurface, transfer

__all__ = ["Prediction", "Matches", "predict", "guided_match", "match_descriptors", "CHI2_2_999"]

#: χ²(2) quantile of probability 0.999: the search ellipse holds the true position with 99.9 %
CHI2_2_999 = float(-2.0 * np.log(0.001))

#: queries whose candidates' descriptor distances are computed together
_BLOCK = 1024


@dataclass(frozen=True, eq=False)
class Prediction:
    """Predicted pixels of A's features in B, with their covariance.

    Attributes
    ----------
    xy_px : ndarray (n, 2)
        NaN where the prediction fails (ray behind B, off any sensible place).
    cov_px2 : ndarray (n, 2, 2)
    """

    xy_px: np.ndarray
    cov_px2: np.ndarray

    def inside(self, xy_px: Any, chi2: float = CHI2_2_999) -> np.ndarray:
        """Boolean (n,): point *i* of *xy_px* (n, 2) lies in prediction *i*'s ellipse."""
        d = np.asarray(xy_px, dtype=np.float64) - self.xy_px
        return _mahalanobis2(d, self.cov_px2) <= chi2


@dataclass(frozen=True, eq=False)
class Matches:
    """Matches of one pair: feature *i* of A with feature *j* of B.

    Attributes
    ----------
    i, j : ndarray (m,) int
    distance : ndarray (m,)
        Descriptor distance.
    ratio : ndarray (m,)
        ``d1 / d2`` of the ratio test (0 for a lone candidate).
    """

    i: np.ndarray
    j: np.ndarray
    distance: np.ndarray
    ratio: np.ndarray

    def __len__(self) -> int:
        return len(self.i)

    def select(self, keep: np.ndarray) -> Matches:
        return Matches(self.i[keep], self.j[keep], self.distance[keep], self.ratio[keep])


def _mahalanobis2(d: np.ndarray, cov: np.ndarray) -> np.ndarray:
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    with np.errstate(all="ignore"):
        return (c * d[:, 0] ** 2 - 2 * b * d[:, 0] * d[:, 1] + a * d[:, 1] ** 2) / det


def predict(camera_a: Camera, eo_a: Any, xy_a_px: Any, camera_b: Camera, eo_b: Any, surface: HeightSurface, *,
            sd_position_m: float, sd_angle_deg: float, sd_feature_px: float = 1.0) -> Prediction:
    """Predicted pixels in B of features of A and their covariance (module docstring).

    Parameters
    ----------
    camera_a, camera_b : Camera
    eo_a, eo_b : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad)
    xy_a_px : (n, 2) columns, rows of the features in A
    surface : HeightSurface
    sd_position_m, sd_angle_deg : float
        Standard deviations of the approximate orientations (each coordinate / angle).
    sd_feature_px : float
        Localisation sd of a feature, px.
    """
    pa = np.asarray(eo_a, dtype=np.float64)
    pb = np.asarray(eo_b, dtype=np.float64)
    xy = np.asarray(xy_a_px, dtype=np.float64).reshape(-1, 2)
    b0 = transfer(camera_a, pa, xy, camera_b, pb, surface)
    # The 26 perturbed transfers stop at B's corrected photo coordinates (mm): no inversion of
    # B's distortion per perturbation; the chain rule through d(pixel)/d(photo) at b0 follows.
    photo_a = np.column_stack([camera_a.pixel_to_photo(xy), np.full(len(xy), -camera_a.focal_length_mm)])
    sd_ang = np.deg2rad(sd_angle_deg)
    steps = [0.01] * 3 + [1e-6] * 3
    sds = [sd_position_m] * 3 + [sd_ang] * 3
    grads = []
    for which in (0, 1):
        for k in range(6):
            if sds[k] <= 0:
                continue
            dp = np.zeros(6)
            dp[k] = steps[k]
            if which == 0:
                plus = _transfer_mm(photo_a, pa + dp, camera_b, pb, surface)
                minus = _transfer_mm(photo_a, pa - dp, camera_b, pb, surface)
            else:
                plus = _transfer_mm(photo_a, pa, camera_b, pb + dp, surface)
                minus = _transfer_mm(photo_a, pa, camera_b, pb - dp, surface)
            grads.append((plus - minus) / (2 * steps[k]) * sds[k])
    if surface.sd_m > 0:
        plus = _transfer_mm(photo_a, pa, camera_b, pb, surface, dh_m=0.01)
        minus = _transfer_mm(photo_a, pa, camera_b, pb, surface, dh_m=-0.01)
        grads.append((plus - minus) / 0.02 * surface.sd_m)
    cov = np.zeros((len(xy), 2, 2))
    if grads:
        with np.errstate(all="ignore"):
            jp = camera_b.pixel_to_photo_jacobian(np.nan_to_num(b0))       # d(photo mm)/d(pixel)
            det = jp[:, 0, 0] * jp[:, 1, 1] - jp[:, 0, 1] * jp[:, 1, 0]
            inv = np.stack([np.stack([jp[:, 1, 1], -jp[:, 0, 1]], -1),
                            np.stack([-jp[:, 1, 0], jp[:, 0, 0]], -1)], 1) / det[:, None, None]
            for g_mm in grads:
                g = np.einsum("nij,nj->ni", inv, g_mm)
                cov += g[:, :, None] * g[:, None, :]
    cov += np.eye(2)[None] * sd_feature_px ** 2
    bad = ~np.isfinite(cov).all(axis=(1, 2)) | ~np.isfinite(b0).all(axis=1)
    b0[bad] = np.nan
    cov[bad] = np.eye(2)
    return Prediction(b0, cov)


def _transfer_mm(photo_a: np.ndarray, eo_a: np.ndarray, camera_b: Camera, eo_b: np.ndarray,
                 surface: HeightSurface, *, dh_m: float = 0.0) -> np.ndarray:
    """:func:`~lidarcat.match.rays.transfer` ending at B's corrected photo coordinates (mm), shape (n, 2).

    *photo_a* (n, 3): A's features as image vectors ``(x, y, -c)`` (mm), computed once per pair.
    """
    d = photo_a @ rotation_matrix(eo_a[3:6])
    dz = np.where(np.abs(d[:, 2]) < 1e-12, -1e-12, d[:, 2])
    h = np.full(len(d), float(surface.mean_m))
    for _ in range(8 if surface.heights_m is not None else 1):
        t = (h - eo_a[2]) / dz
        h = surface.height(eo_a[0] + t * d[:, 0], eo_a[1] + t * d[:, 1])
    t = (h + dh_m - eo_a[2]) / dz if dh_m else (h - eo_a[2]) / dz
    xyz = eo_a[:3] + t[:, None] * d
    out, _ = project(eo_b.reshape(1, 6), xyz, np.full(len(xyz), camera_b.focal_length_mm),
                     np.zeros(len(xyz), dtype=np.int64))
    return out


def _expand(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For groups of sizes *counts*: each element's group and its rank inside the group."""
    owner = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum(counts) - counts
    return owner, np.arange(int(counts.sum())) - starts[owner]


def _grid_candidates(centre: np.ndarray, half: np.ndarray, xy_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (query, point of B) with the point in the cells covering the query's box ``centre ± half``.

    *centre* (n, 2), *half* (n, 2) half-widths, px.  B's points are sorted by the cell of a square
    grid (cell = half the median half-width, at least 8 px: the boxes' cells then hold 1.4 times the
    ellipses' candidates instead of 2.7 with a cell of the whole half-width, at the same cost);
    each query's cells are enumerated and their points taken by the cell's range in the sorted
    order -- all by ``np.repeat``, no Python loop over queries or points.
    """
    cell = max(8.0, 0.5 * float(np.median(half)))
    lo = np.floor(xy_b.min(axis=0) / cell)
    cb = np.floor(xy_b / cell) - lo
    ncol, nrow = int(cb[:, 0].max()) + 1, int(cb[:, 1].max()) + 1
    cid = (cb[:, 1] * ncol + cb[:, 0]).astype(np.int64)
    order = np.argsort(cid, kind="stable")
    first = np.searchsorted(cid[order], np.arange(ncol * nrow + 1))
    top = np.array([ncol - 1, nrow - 1])
    c0 = np.maximum(np.floor((centre - half) / cell) - lo, 0).astype(np.int64)
    c1 = np.minimum(np.floor((centre + half) / cell) - lo, top).astype(np.int64)
    nx = np.maximum(c1[:, 0] - c0[:, 0] + 1, 0)
    ny = np.maximum(c1[:, 1] - c0[:, 1] + 1, 0)
    q, k = _expand(nx * ny)                                   # (query, cell of its square)
    col = c0[q, 0] + k % nx[q]
    row = c0[q, 1] + k // nx[q]
    cells = row * ncol + col
    start, n = first[cells], first[cells + 1] - first[cells]
    g, r = _expand(n)
    jb = order[start[g] + r]
    return q[g], jb


def _compact(idx: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(idx, return_inverse=True)`` for indices below *n*, by marks instead of a sort."""
    mark = np.zeros(n, bool)
    mark[idx] = True
    used = np.flatnonzero(mark)
    where = np.cumsum(mark) - 1
    return used, where[idx]


def _sort_order(q: np.ndarray) -> np.ndarray:
    """A stable sorting order of *q*: ``arange`` when *q* is already sorted (the candidates come by query)."""
    if len(q) < 2 or not (q[1:] < q[:-1]).any():
        return np.arange(len(q))
    return np.argsort(q, kind="stable")


def _best_two(q: np.ndarray, d: np.ndarray, n_q: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per query id in *q* (candidate pairs, distances *d*): the candidate index of its nearest,
    the nearest distance and the second nearest (inf when alone; -1 / inf for no candidate).

    One integer sort and three ``reduceat`` passes (no sort by distance)."""
    best = np.full(n_q, -1, np.int64)
    d1 = np.full(n_q, np.inf)
    d2 = np.full(n_q, np.inf)
    if len(q) == 0:
        return best, d1, d2
    order = _sort_order(q)
    qs, ds = q[order], d[order].astype(np.float64)
    starts = np.flatnonzero(np.r_[True, qs[1:] != qs[:-1]])
    counts = np.diff(np.r_[starts, len(qs)])
    m1 = np.minimum.reduceat(ds, starts)
    pos = np.arange(len(ds))
    first = np.minimum.reduceat(np.where(ds == np.repeat(m1, counts), pos, len(ds)), starts)
    ds2 = ds.copy()
    ds2[first] = np.inf
    m2 = np.minimum.reduceat(ds2, starts)
    ids = qs[starts]
    best[ids] = order[first]
    d1[ids] = m1
    d2[ids] = m2
    return best, d1, d2


def _decide(ia: np.ndarray, jb: np.ndarray, dist: np.ndarray, n_a: int, n_b: int, ratio: float) -> Matches:
    """Ratio test + mutual check over candidate pairs (ia, jb) with descriptor distances."""
    if len(ia) == 0:
        return Matches(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), np.empty(0))
    best_a, d1a, d2a = _best_two(ia, dist, n_a)
    best_b, _, _ = _best_two(jb, dist, n_b)
    has = best_a >= 0
    i = np.flatnonzero(has)
    k = best_a[i]
    j = jb[k]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(np.isfinite(d2a[i]), d1a[i] / np.maximum(d2a[i], 1e-12), 0.0)
    ok = (r < ratio) & (ia[best_b[j]] == i)
    return Matches(i[ok].astype(np.int64), j[ok].astype(np.int64), d1a[i][ok], r[ok])


def _distances(desc_a: np.ndarray, desc_b: np.ndarray, ia: np.ndarray, jb: np.ndarray) -> np.ndarray:
    """Descriptor distances of candidate pairs (ia, jb), shape (m,).

    Only the features that have a candidate take part: ``A' = A[unique ia]``, ``B' = B[unique jb]``
    (a pair of 15 % overlap keeps about 15 % of each).  The products ``A' B'^T`` are computed by
    BLAS in tiles of :data:`_BLOCK` rows of ``A'`` (memory ``_BLOCK |B'|`` floats, never
    ``n_A x n_B``), and each candidate's distance is ``sqrt(|a|^2 + |b|^2 - 2 a.b)``, gathered from
    its tile.  Exact for byte descriptors (every partial sum an integer below 2^24 in float32).
    Measured on a 1200 x 900 pair (5,891 x 5,517 features, 609 k candidates): 0.44 s against 0.89 s
    for products per block of 256 neighbouring queries with their own candidates of B.
    """
    out = np.empty(len(ia), np.float32)
    if len(ia) == 0:
        return out
    ua, ia_l = _compact(ia, len(desc_a))
    ub, jb_l = _compact(jb, len(desc_b))
    fa = desc_a[ua].astype(np.float32)
    fbt = np.ascontiguousarray(desc_b[ub].astype(np.float32).T)
    na = np.einsum("ij,ij->i", fa, fa)
    nb = np.einsum("ji,ji->i", fbt, fbt)
    order = _sort_order(ia_l)
    bounds = np.searchsorted(ia_l[order], np.arange(0, len(ua) + _BLOCK, _BLOCK))
    for k in range(len(bounds) - 1):
        lo, hi = bounds[k], bounds[k + 1]
        if lo == hi:
            continue
        rows = order[lo:hi]
        r = ia_l[rows]
        g = fa[k * _BLOCK:(k + 1) * _BLOCK] @ fbt
        out[rows] = na[r] + nb[jb_l[rows]] - 2.0 * g[r - k * _BLOCK, jb_l[rows]]
    return np.sqrt(np.maximum(out, 0.0))


def guided_match(pred: Prediction, desc_a: np.ndarray, xy_b_px: np.ndarray, desc_b: np.ndarray, *,
                 ratio: float = 0.8, chi2: float = CHI2_2_999) -> tuple[Matches, int]:
    """Match A's features to B's within their prediction ellipses (module docstring).

    Returns
    -------
    matches : Matches
    n_candidates : int
        Candidate pairs examined (the search effort).
    """
    xy_b = np.asarray(xy_b_px, dtype=np.float64).reshape(-1, 2)
    ok = np.isfinite(pred.xy_px).all(axis=1)
    n_a, n_b = len(pred.xy_px), len(xy_b)
    if not ok.any() or n_b == 0:
        return _decide(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), n_a, n_b, ratio), 0
    qa = np.flatnonzero(ok)
    cov = pred.cov_px2[qa]
    a, b, c = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
    det = a * c - b * b
    # the ellipse's bounding box: half-widths sqrt(χ² Σ_xx), sqrt(χ² Σ_yy)
    half = np.sqrt(chi2 * np.column_stack([a, c]))
    centre = pred.xy_px[qa]
    iq, jb = _grid_candidates(centre, half, xy_b)
    if len(iq) == 0:
        return _decide(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), n_a, n_b, ratio), 0
    with np.errstate(all="ignore"):
        w = (np.column_stack([c, -2.0 * b, a]) / det[:, None]).astype(np.float32)   # Σ^-1 terms per query
    # the Mahalanobis test of every box candidate, in float32 with np.take (4-5x faster than float64
    # fancy indexing; 1e-3 px at 17,000 px)
    cx, cy = centre[:, 0].astype(np.float32), centre[:, 1].astype(np.float32)
    dx = np.take(xy_b[:, 0].astype(np.float32), jb)
    dx -= np.take(cx, iq)
    dy = np.take(xy_b[:, 1].astype(np.float32), jb)
    dy -= np.take(cy, iq)
    m2 = np.take(w[:, 0], iq) * dx * dx
    m2 += np.take(w[:, 1], iq) * dx * dy
    m2 += np.take(w[:, 2], iq) * dy * dy
    inside = m2 <= chi2
    ia, jb = qa[iq[inside]], jb[inside]
    dist = _distances(desc_a, desc_b, ia, jb)
    return _decide(ia, jb, dist, n_a, n_b, ratio), int(len(ia))


def match_descriptors(desc_a: np.ndarray, desc_b: np.ndarray, *, ratio: float = 0.8) -> Matches:
    """Unguided matching: every feature of B a candidate (OpenCV brute force, k = 2), ratio + mutual."""
    import cv2

    n_a, n_b = len(desc_a), len(desc_b)
    if n_a < 2 or n_b < 2:
        return _decide(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0), n_a, n_b, ratio)
    bf = cv2.BFMatcher(cv2.NORM_L2)
    a = np.ascontiguousarray(desc_a, dtype=np.float32)
    b = np.ascontiguousarray(desc_b, dtype=np.float32)
    fwd = bf.knnMatch(a, b, k=2)
    bwd = bf.match(b, a)
    best_of_b = np.full(n_b, -1, np.int64)
    for m in bwd:
        best_of_b[m.queryIdx] = m.trainIdx
    i = np.array([m[0].queryIdx for m in fwd if len(m) == 2], np.int64)
    j = np.array([m[0].trainIdx for m in fwd if len(m) == 2], np.int64)
    d1 = np.array([m[0].distance for m in fwd if len(m) == 2])
    d2 = np.array([m[1].distance for m in fwd if len(m) == 2])
    r = d1 / np.maximum(d2, 1e-12)
    ok = (r < ratio) & (best_of_b[j] == i)
    return Matches(i[ok], j[ok], d1[ok], r[ok])
