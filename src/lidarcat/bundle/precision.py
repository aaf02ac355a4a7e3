r"""Precision of the adjusted parameters: blocks of the inverse normal matrix.

``Sigma_X = f N^-1`` with ``f = 1`` (a priori, the thesis tables) or
``f = v'Pv / dof`` (a posteriori).  With the points eliminated
(:mod:`.linear`), the blocks of ``N^-1`` follow from ``Z = S^-1``:

    Cov(c_i, c_k)  = Z_ik
    Cov(c_i, X_j)  = -sum_{b: obs of j} Z_{i, i_b} T_b                 (T_b = W_b V_j^-1)
    Cov(X_j)       = V_j^-1 + sum_{a, b: obs of j} T_a^T Z_{i_a, i_b} T_b

Every ``Z`` block these need -- the diagonal block of every camera and the block
of every pair of cameras sharing a point -- lies on the pattern of the Cholesky
factor of ``S``, so the selected inversion of :mod:`.cholesky` (Takahashi
recursion over supernodes) gives them without a dense inverse: its work is a
few times that of the factorisation.  The pair sums run in chunks of fixed size
over the observation pairs of :class:`lidarcat.bundle.linear.Schur`.

Functions
---------
:func:`covariance_blocks` ``(system, precision="all") -> (cam_cov (P, 6, 6), point_cov (Q, 3, 3))``
    photo and point blocks of one linearisation (``precision="photos"``: point
    blocks NaN; ``"none"``: both NaN, nothing computed).
:func:`observation_blocks` ``(system) -> (n, 9, 9)``
    for every image observation a = (photo i, point j), the covariance of
    ``[eo_i (6), X_j (3)]``: ``[[Z_ii, C_ij], [C_ij^T, Cov(X_j)]]`` with the
    cross block ``C_ij = Cov(c_i, X_j)`` above (blunder detection: redundancy
    numbers and standardised residuals need ``A_a Sigma A_a^T``).
:func:`joint_point_covariance` ``(result, points) -> (3k, 3k)``
    the whole covariance of a set of points, cross-covariances included.

All are a priori (factor 1); :func:`lidarcat.bundle.adjust` scales its result.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from ..geometry.collinearity import block_sum
from ..errors import DatumError
from .linear import CHUNK_PAIRS, inv3, SingularSystem
from .model import NormalSystem
from .result import BundleResult

__all__ = ["PRECISION_LEVELS", "covariance_blocks", "observation_blocks", "joint_point_covariance"]

#: values of the ``precision`` switch: nothing, the photo blocks, photo and point blocks
PRECISION_LEVELS = ("none", "photos", "all")


def _factorised(system: NormalSystem):
    """Factor of the undamped S, V^-1 and T = W V^-1 of one linearisation."""
    schur = system.schur
    vinv = inv3(system.V)
    data, T = schur.assemble(system.U, vinv, system.W)
    return schur.factor(data), vinv, T


class _Blocks:
    """Selected inverse of S with the locations of the camera and pair blocks."""

    def __init__(self, system: NormalSystem):
        self.schur = schur = system.schur
        self.factor, self.vinv, self.T = _factorised(system)
        self.Z = self.factor.selected_inverse()
        if schur._zloc is None:                # the locations depend on the pattern only
            cams = np.arange(schur.n_cameras)
            schur._zloc = (schur.chol.locate(cams, cams),
                           schur.chol.locate(system.p.photo_index[schur.oa], system.p.photo_index[schur.ob]))
        self.loc_diag, self.loc_pair = schur._zloc

    def cameras(self) -> np.ndarray:
        cb = self.schur.cb
        z = self.Z.gather(self.loc_diag, cb, cb)
        return 0.5 * (z + np.transpose(z, (0, 2, 1)))

    def pair(self, c0: int, c1: int) -> np.ndarray:
        """Z[i_a, i_b] of the observation pairs c0:c1 of the Schur pattern (a < b)."""
        base, rs, cs = self.loc_pair
        cb = self.schur.cb
        return self.Z.gather((base[c0:c1], rs[c0:c1], cs[c0:c1]), cb, cb)


def _point_terms(system: NormalSystem, blk: _Blocks, cam_cov: np.ndarray, *, cross: bool):
    """Point blocks ``V_j^-1 + sum_{a,b} T_a^T Z_{i_a i_b} T_b`` (Q, 3, 3) and, with *cross*, the
    photo-point blocks ``-sum_b Z_{i_a i_b} T_b`` of every observation (n, cb, 3), else None;
    the pairs a < b in chunks of :data:`CHUNK_PAIRS`."""
    p, schur = system.p, system.schur
    T, pj, ei = blk.T, p.point_index, p.photo_index
    Tt = np.transpose(T, (0, 2, 1))
    n_obs = len(pj)
    zt = cam_cov[ei] @ T                                           # Z_ii T_a
    point_cov = blk.vinv + schur.by_point(Tt @ zt)                 # a == b
    cr = -zt if cross else None
    for c0 in range(0, len(schur.oa), CHUNK_PAIRS):
        c1 = min(len(schur.oa), c0 + CHUNK_PAIRS)
        oa, ob = schur.oa[c0:c1], schur.ob[c0:c1]
        z = blk.pair(c0, c1)                                       # Z[i_a, i_b]
        if cross:
            cr -= block_sum(oa, z @ T[ob], n_obs)
            cr -= block_sum(ob, np.transpose(z, (0, 2, 1)) @ T[oa], n_obs)
        x = Tt[oa] @ z @ T[ob]                                     # a < b: x + x^T
        point_cov += block_sum(pj[oa], x + np.transpose(x, (0, 2, 1)), p.n_points)
    return 0.5 * (point_cov + np.transpose(point_cov, (0, 2, 1))), cr


def covariance_blocks(system: NormalSystem, precision: str = "all") -> tuple[np.ndarray, np.ndarray]:
    """Blocks of N^-1 (a priori): (P, 6, 6) per photo and (Q, 3, 3) per point.

    Parameters
    ----------
    system : NormalSystem
        A linearisation (normally at the solution).
    precision : {"all", "photos", "none"}
        What to compute; the rest is NaN.

    Raises
    ------
    ValueError
        An unknown *precision*.
    SingularSystem
        The normal equations are singular.
    """
    if precision not in PRECISION_LEVELS:
        raise ValueError(f"`precision` must be one of {', '.join(PRECISION_LEVELS)}, got {precision!r}")
    p = system.p
    cb = system.schur.cb
    cam_cov = np.full((p.n_photos, cb, cb), np.nan)
    point_cov = np.full((p.n_points, 3, 3), np.nan)
    if precision == "none":
        return cam_cov, point_cov
    blk = _Blocks(system)
    cam_cov = blk.cameras()
    if precision == "photos":
        return cam_cov, point_cov
    point_cov, _ = _point_terms(system, blk, cam_cov, cross=False)
    return cam_cov, point_cov


def observation_blocks(system: NormalSystem) -> np.ndarray:
    """Joint covariance of ``[eo_i, X_j]`` for every image observation (photo i, point j), a priori.

    Parameters
    ----------
    system : NormalSystem
        A linearisation (normally at the solution).

    Returns
    -------
    (n, 9, 9) array
        In the order of the problem's observations: rows/columns 0-5 the
        exterior orientation of the photo (m, rad), 6-8 the point (m).
        Computed through the same selected inverse as :func:`covariance_blocks`.

    Raises
    ------
    SingularSystem
        The normal equations are singular.
    """
    p = system.p
    cb = system.schur.cb
    blk = _Blocks(system)
    cam_cov = blk.cameras()
    point_cov, cross = _point_terms(system, blk, cam_cov, cross=True)
    ei, pj = p.photo_index, p.point_index
    n_obs = len(pj)
    out = np.empty((n_obs, cb + 3, cb + 3))
    out[:, :cb, :cb] = cam_cov[ei]
    out[:, :cb, cb:] = cross
    out[:, cb:, :cb] = np.transpose(cross, (0, 2, 1))
    out[:, cb:, cb:] = point_cov[pj]
    return out


def joint_point_covariance(result: BundleResult, points: Sequence[str], *, batch: int = 96) -> np.ndarray:
    """Joint covariance of several adjusted points, cross-covariances included.

    The per-point blocks of :attr:`BundleResult.point_cov` ignore that every
    point shares the errors of the photo orientations: points controlled by
    the same few constraints move together (a block tilt, a height offset).
    Tests on several points at once -- the check-point chi-square of
    :func:`lidarcat.accuracy.checkpoints.covariance_consistency_test` -- need the whole
    matrix ``C[a, b] = V_a^-1 delta_ab + T_a^T S^-1 T_b`` (Schur complement
    of the point blocks: S the reduced camera system, T_a = W_a V_a^-1).

    Work: one supernodal factorisation of S and 3k solves in batches of *batch*
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
    system = NormalSystem(p, np.asarray(result.eo_params), np.asarray(result.points_m))
    try:
        lu, vinv, T = _factorised(system)
    except SingularSystem as ex:
        raise DatumError(f"joint covariance: {ex}") from ex
    # B = the columns of T W^-1-style coupling of the selected points: (cb P, 3k), sparse
    col_of = np.full(p.n_points, -1)
    col_of[sel] = np.arange(k)
    obs = np.flatnonzero(col_of[p.point_index] >= 0)
    cb = system.schur.cb
    rr = (p.photo_index[obs][:, None, None] * cb + np.arange(cb)[None, :, None]) + np.zeros((1, 1, 3), np.int64)
    cc = (col_of[p.point_index[obs]][:, None, None] * 3 + np.arange(3)[None, None, :]) + np.zeros((1, cb, 1), np.int64)
    B = sp.csc_matrix((T[obs].ravel(), (rr.ravel(), cc.ravel())), shape=(cb * p.n_photos, 3 * k))
    BT = B.T.tocsr()
    C = np.empty((3 * k, 3 * k))
    for c0 in range(0, 3 * k, batch):
        c1 = min(3 * k, c0 + batch)
        C[:, c0:c1] = BT @ lu.solve(B[:, c0:c1].toarray())
    C = 0.5 * (C + C.T)
    for a, q in enumerate(sel):
        C[3 * a:3 * a + 3, 3 * a:3 * a + 3] += vinv[q]
    return C * result.variance_factor
