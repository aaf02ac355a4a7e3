r"""Precision of the adjusted parameters: blocks of the inverse normal matrix.

``Sigma_X = f N^-1`` with ``f = 1`` (a priori, the thesis tables) or
``f = v'Pv / dof`` (a posteriori).  Only the blocks that are needed are computed:
``Z = S^-1`` inside the block band of ``S`` (photos ordered by reverse
Cuthill-McKee, banded Cholesky ``S = L L^T``, then the Takahashi recursion
``Z[I, j] = -Z[I, I] L[I, j] L[j, j]^-1``, ``Z[j, j] = L[j, j]^-T L[j, j]^-1 -
Z[I, j]^T L[I, j] L[j, j]^-1`` from the last photo to the first), which holds the
6x6 block of every photo and of every pair of photos sharing a point; and for
every point ``V_j^-1 + T_j^T Z T_j`` with ``T_j = W_j V_j^-1``.  No dense inverse
of the whole system is formed; the work is O(P beta^2) for block bandwidth beta
(batched sparse solves are the fallback for blocks without a narrow band).

:func:`covariance_blocks` gives the photo and point blocks of one linearisation;
:func:`joint_point_covariance` the whole covariance of a set of points,
cross-covariances included.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from .._collinearity import block_sum
from ..errors import DatumError
from .linear import _factor, _Singular
from .model import _System

if TYPE_CHECKING:  # pragma: no cover
    from .solve import BundleResult

__all__ = ["covariance_blocks", "joint_point_covariance"]


def covariance_blocks(system: _System, method: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Blocks of N^-1: (P, 6, 6) per photo and (Q, 3, 3) per point.

    ``method``: ``"banded"`` (block Takahashi recursion on a banded Cholesky
    factor after reverse Cuthill-McKee ordering of the photos: work
    O(P beta^2), beta the block bandwidth), ``"solve"`` (batched sparse solves
    for all columns of S^-1: O(P nnz(L))) or ``"auto"`` (banded when the
    bandwidth is small against P).
    """
    p = system.p
    n_ph, n_pt = p.n_photos, p.n_points
    pj, ei = p.point_index, p.photo_index
    S, vinv, _, _ = system.reduced_system()
    T = system.W @ vinv[pj]                                  # (n, 6, 3)
    oa, ob = _observation_pairs(pj, n_pt)
    pi, pk = ei[oa], ei[ob]
    getter = None
    if method in ("auto", "banded"):
        getter = _banded_selected_inverse(S, n_ph, force=method == "banded")
    if getter is not None:
        eo_cov = getter(np.arange(n_ph), np.arange(n_ph))
        blocks_pair = getter(pi, pk)
    else:
        eo_cov, blocks_pair = _solve_selected_inverse(S, n_ph, pi, pk)
    # point blocks: V^-1 + sum_{a,b} T_a^T C_ik T_b over pairs of rays of the point
    contrib = (np.transpose(T[oa], (0, 2, 1)) @ blocks_pair) @ T[ob]
    point_cov = vinv + block_sum(pj[oa], contrib, n_pt)
    eo_cov = 0.5 * (eo_cov + np.transpose(eo_cov, (0, 2, 1)))
    point_cov = 0.5 * (point_cov + np.transpose(point_cov, (0, 2, 1)))
    return eo_cov, point_cov


def _observation_pairs(pj: np.ndarray, n_pt: int) -> tuple[np.ndarray, np.ndarray]:
    """All ordered pairs (a, b) of observations of the same point (including a == b)."""
    order = np.argsort(pj, kind="stable")
    counts = np.bincount(pj, minlength=n_pt)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    a_list, b_list = [], []
    for m in np.unique(counts):
        if m == 0:
            continue
        js = np.flatnonzero(counts == m)
        base = starts[js][:, None] + np.arange(m)[None, :]
        a_list.append(order[np.repeat(base, m, axis=1).ravel()])
        b_list.append(order[np.tile(base, (1, m)).ravel()])
    if not a_list:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(a_list), np.concatenate(b_list)


def _solve_selected_inverse(S: sp.csc_matrix, n_ph: int, pi: np.ndarray, pk: np.ndarray,
                            batch: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal blocks and blocks (pi, pk) of S^-1 by batched sparse solves."""
    lu = _factor(S)
    eo_cov = np.empty((n_ph, 6, 6))
    blocks_pair = np.empty((len(pi), 6, 6))
    col_order = np.argsort(pk, kind="stable")
    pk_sorted = pk[col_order]
    for k0 in range(0, n_ph, batch):
        k1 = min(n_ph, k0 + batch)
        nb = k1 - k0
        rhs = np.zeros((6 * n_ph, 6 * nb))
        rhs[6 * k0:6 * k1, :] = np.eye(6 * nb)
        Xb = lu.solve(rhs).reshape(n_ph, 6, nb, 6)          # columns of S^-1 for photos k0..k1
        kk = np.arange(nb)
        eo_cov[k0:k1] = Xb[k0 + kk, :, kk, :]
        lo, hi = np.searchsorted(pk_sorted, [k0, k1])
        sel = col_order[lo:hi]
        blocks_pair[sel] = Xb[pi[sel], :, pk[sel] - k0, :]
    return eo_cov, blocks_pair


def _banded_selected_inverse(S: sp.csc_matrix, n_ph: int, force: bool = False):
    """Selected inverse of S within its block band (Takahashi recursion), or None.

    The photos are ordered by reverse Cuthill-McKee; S = L L^T is factored in
    LAPACK band storage; then for block columns j = P-1 .. 0, with I the block
    rows of the band below j (all within the band of each other):

        Z[I, j] = -Z[I, I] L[I, j] L[j, j]^-1
        Z[j, j] = L[j, j]^-T L[j, j]^-1 - Z[I, j]^T L[I, j] L[j, j]^-1

    which only reads and writes Z inside the band.  Returns a function
    ``get(i, k) -> (m, 6, 6)`` blocks of S^-1 for photo indices i, k sharing a
    point (inside the band), or None when the band is too wide to pay off.
    """
    import scipy.linalg as sla
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    coo = S.tocoo()
    br, bc = coo.row // 6, coo.col // 6
    graph = sp.csr_matrix((np.ones(len(br)), (br, bc)), shape=(n_ph, n_ph))
    perm = np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True), dtype=np.int64)
    pos = np.empty(n_ph, dtype=np.int64)
    pos[perm] = np.arange(n_ph)
    beta = int(np.abs(pos[br] - pos[bc]).max(initial=0))
    if not force and n_ph > 8 and beta > n_ph // 3:
        return None
    n = 6 * n_ph
    bw = 6 * beta + 5                                        # scalar lower bandwidth
    r = pos[br] * 6 + coo.row % 6
    c = pos[bc] * 6 + coo.col % 6
    low = r >= c
    ab = np.zeros((bw + 1, n))
    np.add.at(ab, (r[low] - c[low], c[low]), coo.data[low])
    try:
        lb = sla.cholesky_banded(ab, lower=True, check_finite=False)
    except np.linalg.LinAlgError as ex:
        raise _Singular(f"reduced camera system is not positive definite ({ex})") from ex
    diag = ab[0]
    if np.any(lb[0] ** 2 < 1e-11 * np.where(diag > 0, diag, 1.0)):
        raise _Singular("reduced camera system is singular (datum defect or degenerate photo)")

    def lblock(rows0: int, nrows: int, col0: int) -> np.ndarray:
        """L[rows0:rows0+nrows, col0:col0+6] from band storage (zeros outside)."""
        rr = rows0 + np.arange(nrows)[:, None]
        cc = col0 + np.arange(6)[None, :]
        d = rr - cc
        ok = (d >= 0) & (d <= bw)
        out = np.zeros((nrows, 6))
        out[ok] = lb[d[ok], np.broadcast_to(cc, d.shape)[ok]]
        return out

    zb = np.zeros((n_ph, beta + 1, 6, 6))                   # zb[i, d] = Z[i, i + d] (permuted order)
    for jb in range(n_ph - 1, -1, -1):
        j0 = 6 * jb
        m = min(beta, n_ph - 1 - jb)
        ljj = lblock(j0, 6, j0)
        ljj_inv = sla.solve_triangular(ljj, np.eye(6), lower=True, check_finite=False)
        if m:
            lij = lblock(j0 + 6, 6 * m, j0)
            x = lij @ ljj_inv                                # L[I, j] L[j, j]^-1
            a = np.arange(1, m + 1)
            aa, cc = np.meshgrid(a, a, indexing="ij")
            lo = np.minimum(aa, cc)
            blocks = zb[jb + lo, np.abs(aa - cc)]            # (m, m, 6, 6), upper-stored
            lower = aa > cc
            blocks[lower] = np.transpose(blocks[lower], (0, 2, 1))
            zii = blocks.transpose(0, 2, 1, 3).reshape(6 * m, 6 * m)
            zij = -zii @ x                                   # (6m, 6)
            zjj = ljj_inv.T @ ljj_inv - zij.T @ x
            zb[jb, 1:m + 1] = np.transpose(zij.reshape(m, 6, 6), (0, 2, 1))
        else:
            zjj = ljj_inv.T @ ljj_inv
        zb[jb, 0] = 0.5 * (zjj + zjj.T)

    def get(i: np.ndarray, k: np.ndarray) -> np.ndarray:
        pi_, pk_ = pos[np.asarray(i)], pos[np.asarray(k)]
        lo = np.minimum(pi_, pk_)
        d = np.abs(pi_ - pk_)
        if np.any(d > beta):
            raise ValueError("requested block outside the band of S")
        out = zb[lo, d].copy()
        swap = pi_ > pk_
        out[swap] = np.transpose(out[swap], (0, 2, 1))
        return out

    return get


def joint_point_covariance(result: BundleResult, points: Sequence[str], *, batch: int = 96) -> np.ndarray:
    """Joint covariance of several adjusted points, cross-covariances included.

    The per-point blocks of :attr:`BundleResult.point_cov` ignore that every
    point shares the errors of the photo orientations: points controlled by
    the same few constraints move together (a block tilt, a height offset).
    Tests on several points at once -- the check-point chi-square of
    :func:`lidarcat.accuracy.covariance_consistency_test` -- need the whole
    matrix ``C[a, b] = V_a^-1 delta_ab + T_a^T S^-1 T_b`` (Schur complement
    of the point blocks: S the reduced camera system, T_a = W_a V_a^-1).

    Work: one sparse factorisation of S and 3k solves in batches of *batch*
    columns; memory O(6 P batch + 9 k^2), never the dense N^-1.

    Parameters
    ----------
    result : BundleResult
        A converged adjustment (relinearised at its solution).
    points : sequence of str
        Point ids, in the order wanted.
    batch : int
        Right-hand sides per solve.

    Returns
    -------
    (3k, 3k) array
        Covariance of (E, N, h) of the points, point after point, m^2, scaled
        by the result's variance factor.  Its diagonal 3 x 3 blocks equal
        ``result.point_cov`` of those points.

    Raises
    ------
    DatumError
        An unknown point id (named), or a singular system.
    """
    ids = [str(q) for q in points]
    index = {str(q): i for i, q in enumerate(result.point_ids)}
    missing = [q for q in ids if q not in index]
    if missing:
        raise DatumError(f"joint covariance: point(s) not in the adjustment: {', '.join(missing[:10])}"
                         + (" ..." if len(missing) > 10 else ""))
    k = len(ids)
    if k == 0:
        return np.zeros((0, 0))
    p = result.problem
    sel = np.array([index[q] for q in ids])
    system = _System(p, np.asarray(result.eo_params), np.asarray(result.points_m))
    try:
        S, vinv, Tm, _ = system.reduced_system()
        lu = _factor(S)
    except _Singular as ex:
        raise DatumError(f"joint covariance: {ex}") from ex
    B = Tm.tocsc()[:, (3 * sel[:, None] + np.arange(3)[None, :]).ravel()]
    BT = B.T.tocsr()
    C = np.empty((3 * k, 3 * k))
    for c0 in range(0, 3 * k, batch):
        c1 = min(3 * k, c0 + batch)
        C[:, c0:c1] = BT @ lu.solve(B[:, c0:c1].toarray())
    C = 0.5 * (C + C.T)
    for a, q in enumerate(sel):
        C[3 * a:3 * a + 3, 3 * a:3 * a + 3] += vinv[q]
    return C * result.variance_factor
