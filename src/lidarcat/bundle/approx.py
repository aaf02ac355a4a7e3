"""Approximate values for the bundle adjustment, computed from the data alone.

Never from the answer.  :func:`approximations` (the default of
:func:`lidarcat.bundle.adjust`):

1. photos with a full approximate orientation in the problem
   (``BundleProblem.initial_eo``, e.g. GNSS/INS from ``photos.csv``) keep it;
2. all other photos get a near-vertical orientation from one linear
   *planimetric block adjustment* (:func:`planimetric_block`): a 2-D similarity
   per photo from photo coordinates to ground E, N, solved together with the
   planimetric coordinates of all points, the control points held by heavy
   weights.  It gives kappa, the scale (hence the flying height) and the nadir of
   every photo at once, with no error propagation along strips;
3. a few sweeps of (intersect all points by least-squares ray intersection,
   :func:`intersect_points`; resect every photo from all its points at once,
   :func:`resect_all`) recover omega and phi.

Known points are the constrained (control) points; check points are never used.
"""

from __future__ import annotations

import logging

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry.collinearity import block_sum, project, project_with_jacobians, rotation_matrix
from ..errors import DatumError

__all__ = ["approximations", "intersect_points", "planimetric_block", "resect_all"]

log = logging.getLogger(__name__)


def _intersect(problem, eo: np.ndarray, oriented: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares intersection of the rays from oriented photos to *targets* (point indices).

    Returns coordinates (len(targets), 3) and a mask of the points with >= 2
    rays from distinct oriented photos and a well-conditioned intersection.
    """
    p = problem
    n_pt = p.n_points
    use = oriented[p.photo_index] & np.isin(p.point_index, targets)
    ei, pj = p.photo_index[use], p.point_index[use]
    out = np.full((len(targets), 3), np.nan)
    ok = np.zeros(len(targets), dtype=bool)
    if not use.any():
        return out, ok
    xy = p.xy_mm[use]
    c = p.focal_length_mm[ei]
    m = rotation_matrix(eo[ei, 3:6])
    v = np.stack([xy[:, 0], xy[:, 1], -c], axis=1)
    d = np.einsum("nji,nj->ni", m, v)                  # M^T (x, y, -c): ray direction in object space
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    x0 = eo[ei, :3]
    A = block_sum(pj, proj, n_pt)
    b = block_sum(pj, np.einsum("nij,nj->ni", proj, x0), n_pt)
    # distinct photos per point (one 1-D unique of pj * P + ei)
    n_photos = np.bincount(np.unique(pj.astype(np.int64) * p.n_photos + ei) // p.n_photos, minlength=n_pt)
    At, bt = A[targets], b[targets]
    good = n_photos[targets] >= 2
    if good.any():
        w = np.linalg.eigvalsh(At[good])
        cond_ok = w[:, 0] > 1e-6 * w[:, -1]
        idx = np.flatnonzero(good)[cond_ok]
        out[idx] = np.linalg.solve(At[idx], bt[idx][:, :, None])[:, :, 0]
        ok[idx] = True
    return out, ok


def intersect_points(problem, eo: np.ndarray) -> np.ndarray:
    """Approximate coordinates of all points from given orientations (P, 6).

    Free points are intersected from all their rays; control points keep their
    observed coordinates (intersected when a coordinate is unconstrained).
    Points that cannot be intersected get the mean height of the others below the
    centre of their first photo.
    """
    p = problem
    eo = np.asarray(eo, dtype=float)
    pts, ok = _intersect(p, eo, np.ones(p.n_photos, dtype=bool), np.arange(p.n_points))
    full = np.isfinite(p.constraint_sd_m).all(axis=1)
    ci = p.constraint_point_index
    pts[ci[full]] = p.constraint_enh_m[full]
    ok[ci[full]] = True
    if not ok.all():
        h = np.nanmean(pts[ok, 2]) if ok.any() else float(np.mean(eo[:, 2]) - 1000.0)
        for j in np.flatnonzero(~ok):
            k = np.flatnonzero(p.point_index == j)[0]           # its first observation
            i = p.photo_index[k]
            pts[j] = _ray_at_height(eo[i], p.xy_mm[k], p.focal_length_mm[i], h)
    return pts


def _ray_at_height(eo: np.ndarray, xy: np.ndarray, c: float, h: float) -> np.ndarray:
    m = rotation_matrix(eo[3:6])
    d = m.T @ np.array([xy[0], xy[1], -c])
    if abs(d[2]) < 1e-12:
        return np.array([eo[0], eo[1], h])
    t = (h - eo[2]) / d[2]
    return eo[:3] + t * d


def planimetric_block(problem) -> np.ndarray:
    """Near-vertical approximation of every photo from one linear block adjustment.

    Each photo maps its photo coordinates to the ground plane by a 2-D similarity
    ``E + iN = a_i (x + iy) + b_i``; all similarities and the planimetric
    coordinates of all points are solved together by linear least squares, the
    control points' E, N held by heavy weights (a planimetric block adjustment by
    independent similarity transforms).  From ``a_i``: ``kappa = arg a_i`` and the
    flying height ``H = c |a_i|``; ``b_i`` is the nadir.  omega = phi = 0.

    Returns
    -------
    (P, 6) array
    """
    p = problem
    n_ph, n_pt = p.n_photos, p.n_points
    n_obs = len(p.photo_index)
    ei, pj = p.photo_index, p.point_index
    x, y = p.xy_mm[:, 0], p.xy_mm[:, 1]
    # unknowns: photo i -> [ar, ai, br, bi] at 4i; point j -> [E, N] at 4P + 2j
    off = 4 * n_ph
    r = np.arange(n_obs)
    rows = np.concatenate([np.repeat(2 * r, 4), np.repeat(2 * r + 1, 4)])
    cols = np.concatenate([
        np.stack([4 * ei, 4 * ei + 1, 4 * ei + 2, off + 2 * pj], axis=1).ravel(),
        np.stack([4 * ei, 4 * ei + 1, 4 * ei + 3, off + 2 * pj + 1], axis=1).ravel()])
    vals = np.concatenate([
        np.stack([-x, y, -np.ones(n_obs), np.ones(n_obs)], axis=1).ravel(),
        np.stack([-y, -x, -np.ones(n_obs), np.ones(n_obs)], axis=1).ravel()])
    full = np.isfinite(p.constraint_sd_m[:, :2]).all(axis=1)
    ci = p.constraint_point_index[full]
    k = len(ci)
    w = 100.0
    rows_c = 2 * n_obs + np.arange(2 * k)
    cols_c = (off + 2 * ci[:, None] + np.arange(2)[None, :]).ravel()
    A = sp.csr_matrix((np.concatenate([vals, np.full(2 * k, w)]),
                       (np.concatenate([rows, rows_c]), np.concatenate([cols, cols_c]))),
                      shape=(2 * n_obs + 2 * k, off + 2 * n_pt))
    rhs = np.concatenate([np.zeros(2 * n_obs), w * p.constraint_enh_m[full, :2].ravel()])
    # centre the ground coordinates for conditioning
    centre = p.constraint_enh_m[full, :2].mean(axis=0) if k else np.zeros(2)
    rhs[2 * n_obs:] -= w * np.tile(centre, k)
    N = (A.T @ A).tocsr()
    b = A.T @ rhs
    # the point block of N is diagonal (E and N of a point enter separate rows with
    # coefficient 1): eliminate the points (Schur complement on the 4P photo unknowns),
    # solve, back-substitute -- a sparse LU of 4P instead of 4P + 2Q unknowns
    d_inv = 1.0 / N.diagonal()[off:]
    N_cp = N[:off, off:]
    S = (N[:off, :off] - N_cp @ sp.diags(d_inv) @ N_cp.T).tocsc()
    try:
        sol_c = spla.splu(S, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                          options={"SymmetricMode": True}).solve(b[:off] - N_cp @ (d_inv * b[off:]))
    except RuntimeError as ex:
        raise DatumError(f"approximations: the planimetric block is singular ({ex})") from ex
    sol = np.concatenate([sol_c, d_inv * (b[off:] - N_cp.T @ sol_c)])
    if not np.all(np.isfinite(sol)):
        raise DatumError("approximations: the planimetric block is singular (too little control)")
    a = sol[0:off:4] + 1j * sol[1:off:4]
    b = sol[2:off:4] + 1j * sol[3:off:4]
    heights = p.constraint_enh_m[np.isfinite(p.constraint_sd_m[:, 2]), 2]
    h0 = float(np.mean(heights)) if len(heights) else 0.0
    eo = np.zeros((n_ph, 6))
    eo[:, 0] = b.real + centre[0]
    eo[:, 1] = b.imag + centre[1]
    eo[:, 2] = h0 + p.focal_length_mm * np.abs(a)
    eo[:, 5] = np.angle(a)
    return eo


def approximations(problem, sweeps: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Approximate exterior orientations (P, 6) and point coordinates (Q, 3).

    Photos with a full approximate orientation in the problem (position and
    attitude, e.g. GNSS/INS) keep it.  The others
    start from :func:`planimetric_block` (near-vertical, from one linear solve
    over the whole block); then *sweeps* rounds of (intersect all points,
    resect every photo from all its points) recover the tilts.

    Raises
    ------
    DatumError
        Singular planimetric block (too little control or disconnected block).
    """
    p = problem
    given = np.zeros(p.n_photos, dtype=bool)
    if p.initial_eo is not None:
        # a full orientation is used as it is; a position without attitude is not (a true
        # position with omega = phi = 0 would point the rays away from the nadir geometry the
        # planimetric block is consistent with)
        given = np.isfinite(p.initial_eo).all(axis=1)
    if given.all():
        return np.array(p.initial_eo, dtype=float), intersect_points(p, p.initial_eo)
    eo = planimetric_block(p)
    if given.any():
        eo[given] = p.initial_eo[given]
    pts = intersect_points(p, eo)
    counts = np.bincount(p.photo_index, minlength=p.n_photos)
    todo = ~given & (counts >= 4)
    for _ in range(sweeps):
        eo = resect_all(p, eo, pts, todo)
        pts = intersect_points(p, eo)
    return eo, pts


def resect_all(problem, eo: np.ndarray, pts: np.ndarray, mask: np.ndarray, max_iter: int = 20) -> np.ndarray:
    """Space resection of every photo in *mask* at once, points held fixed.

    Damped Gauss-Newton with one Levenberg-Marquardt factor per photo; the 6x6
    normal matrices of all photos are built and solved together (vectorised).
    A photo whose resection does not reduce its residuals keeps its start.

    Returns
    -------
    (P, 6) array
    """
    p = problem
    eo = np.array(eo, dtype=float)
    rows = np.flatnonzero(mask[p.photo_index])
    if len(rows) == 0:
        return eo
    ei, pj = p.photo_index[rows], p.point_index[rows]
    obs, w = p.xy_mm[rows], 1.0 / p.sd_mm[rows] ** 2
    c = p.focal_length_mm[ei]
    xyz = pts[pj]
    n_ph = p.n_photos

    def costs(e):
        xy, u3 = project(e, xyz, c, ei)
        per = np.bincount(ei, weights=np.sum(w * (xy - obs) ** 2, axis=1), minlength=n_ph)
        bad = np.bincount(ei, weights=(u3 >= 0).astype(float), minlength=n_ph) > 0
        per[bad] = np.inf
        return per

    cur = costs(eo)
    lam = np.full(n_ph, 1e-3)
    active = mask.copy()
    i6 = np.arange(6)
    for _ in range(max_iter):
        xy, a_eo, _, _ = project_with_jacobians(eo, xyz, c, ei)
        r = xy - obs
        aw_t = np.transpose(a_eo * w[:, :, None], (0, 2, 1))
        U = block_sum(ei, aw_t @ a_eo, n_ph)
        g = block_sum(ei, np.einsum("nik,nk->ni", aw_t, r), n_ph)
        U[~active] = np.eye(6)
        g[~active] = 0.0
        for _inner in range(8):
            D = U.copy()
            D[:, i6, i6] *= 1.0 + lam[:, None]
            try:
                d = np.linalg.solve(D, -g[:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                return eo
            trial = eo + d
            new = costs(trial)
            ok = active & (new <= cur)
            eo[ok] = trial[ok]
            small = ok & (np.abs(d[:, :3]).max(axis=1) < 1e-3) & (np.abs(d[:, 3:]).max(axis=1) < 1e-7)
            cur[ok] = new[ok]
            lam[ok] = np.maximum(lam[ok] / 10.0, 1e-9)
            fail = active & ~ok
            lam[fail] *= 10.0
            active &= ~small & (lam < 1e8)
            if not fail.any():
                break
        if not active.any():
            break
    return eo
