r"""Linear algebra of the normal equations: the Schur complement and its factorisation.

The normal equations of one Gauss-Newton / Levenberg-Marquardt step are

.. math::  \begin{bmatrix}U & W\\W^T & V\end{bmatrix}
           \begin{bmatrix}\Delta_c\\\Delta_p\end{bmatrix} =
           \begin{bmatrix}b_c\\b_p\end{bmatrix}

where ``U`` is block diagonal (6x6 per photo), ``V`` block diagonal (3x3 per
point) and ``W`` holds one 6x3 block per observation.  The points are eliminated
through the Schur complement, giving the reduced camera system
``S = U - W V^-1 W^T`` (sparse: a 6x6 block for every pair of photos sharing a
point, :func:`_reduce`), solved with a sparse symmetric-mode LU factorisation
(:func:`_factor`, no pivoting, minimum-degree ordering on ``S + S^T``); then
``Delta_p = V^-1 (b_p - W^T Delta_c)``.  A rank defect shows as a pivot at
rounding level relative to the diagonal of ``S`` and raises :class:`_Singular`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__: list[str] = []


class _Singular(Exception):
    pass


def _block_sparse(rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray, shape: tuple[int, int]) -> sp.csr_matrix:
    """Sparse matrix from (m, a, b) blocks at block row/col indices (duplicates summed)."""
    m, a, b = blocks.shape
    r = (rows[:, None, None] * a + np.arange(a)[None, :, None]) + np.zeros((1, 1, b), dtype=np.int64)
    c = (cols[:, None, None] * b + np.arange(b)[None, None, :]) + np.zeros((1, a, 1), dtype=np.int64)
    return sp.csr_matrix((blocks.ravel(), (r.ravel(), c.ravel())), shape=shape)


def _reduce(ei: np.ndarray, pj: np.ndarray, U: np.ndarray, V: np.ndarray, W: np.ndarray):
    """Schur complement of the point blocks: S = U - W V^-1 W^T (sparse, 6P x 6P).

    Returns ``S`` (csc), ``V^-1`` (Q, 3, 3), ``Tm`` = W V^-1 and ``Wm`` = W as sparse
    (6P x 3Q) matrices.
    """
    n_ph, n_pt = len(U), len(V)
    vinv = _inv3(V)
    Tm = _block_sparse(ei, pj, W @ vinv[pj], (6 * n_ph, 3 * n_pt))
    Wm = _block_sparse(ei, pj, W, (6 * n_ph, 3 * n_pt))
    Ub = _block_sparse(np.arange(n_ph), np.arange(n_ph), U, (6 * n_ph, 6 * n_ph))
    return (Ub - Tm @ Wm.T).tocsc(), vinv, Tm, Wm


def _inv3(V: np.ndarray) -> np.ndarray:
    det = np.linalg.det(V)
    scale = np.abs(V).max(axis=(1, 2))
    if np.any(~np.isfinite(det)) or np.any(np.abs(det) <= 1e-12 * scale**3):
        raise _Singular("a point block of the normal equations is singular")
    return np.linalg.inv(V)


def _factor(S: sp.csc_matrix):
    try:
        # symmetric positive definite: symmetric ordering, no pivoting (much less fill)
        lu = spla.splu(S, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError as ex:  # "Factor is exactly singular"
        raise _Singular(f"reduced camera system is singular ({ex})") from ex
    # a rank defect shows as pivots at rounding level relative to the diagonal of S
    piv = np.abs(lu.U.diagonal())
    diag = np.abs(S.diagonal())[lu.perm_c]
    ratio = piv / np.where(diag > 0, diag, 1.0)
    if not np.all(np.isfinite(piv)) or ratio.min() < 1e-11:
        raise _Singular(f"reduced camera system is singular (relative pivot {ratio.min():.1e}: "
                        "datum defect or a photo with degenerate geometry)")
    return lu
