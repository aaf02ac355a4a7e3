r"""Linear algebra of the normal equations: the reduced camera system and its solution.

The normal equations of one Gauss-Newton / Levenberg-Marquardt step are

.. math::  \begin{bmatrix}U & W\\W^T & V\end{bmatrix}
           \begin{bmatrix}\Delta_c\\\Delta_p\end{bmatrix} =
           \begin{bmatrix}b_c\\b_p\end{bmatrix}

where ``U`` is block diagonal (c x c per camera, c = 6 for the exterior
orientation), ``V`` block diagonal (3 x 3 per point) and ``W`` holds one c x 3
block ``W_a`` per observation a.  The points are eliminated through the Schur
complement, the reduced camera system

    S = U - W V^-1 W^T,      S_ik = delta_ik U_i - sum_{a, b: same point j} W_a V_j^-1 W_b^T

(sparse: a block for every pair of cameras sharing a point), solved for
``Delta_c``; then ``Delta_p = V^-1 (b_p - W^T Delta_c)``.

Assembly (:class:`Schur`).  The pattern of S, the list of the pairs (a, b),
a < b, of observations of the same point, the slot of every pair in the block
pattern and the gather from blocks to the CSR order of the scalar matrix are
computed once per problem; every step then evaluates ``T_a = W_a V_j^-1`` and
the sum of the pair products ``T_a W_b^T`` of every slot as one matrix product
``[T_a1 | T_a2 | ...] [W_b1 | W_b2 | ...]^T`` -- slots with the same number of pairs
batched, in chunks of fixed size (memory bounded whatever the block), the
diagonal blocks (pairs a = a) included.  The factorisation is the supernodal
Cholesky of :mod:`.cholesky`, its ordering and symbolic analysis reused in
every step.

Global parameters (the seam for self-calibration).  ``k`` parameters shared by
all observations of a camera (interior orientation) or by a control source
(frame offset) border S:  ``[[S_cc, S_cg], [S_gc, S_gg]]``.  They are one more
unit of size k in the root supernode of the factor (:class:`SupernodalCholesky`
takes ``root_units``), so the solve and the selected inverse carry them with
no other change; the model supplies the per-observation blocks.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import scipy.sparse as sp

from .cholesky import SingularError, SupernodalCholesky

__all__ = ["CHUNK_PAIRS", "REUSE_RTOL", "REUSE_MAX_ITER", "SingularSystem", "inv3", "Gram", "Schur"]

log = logging.getLogger(__name__)

#: observation pairs evaluated per chunk in the assembly of S
CHUNK_PAIRS = 1 << 16

#: a step solved with the previous factor as preconditioner must reach this relative residual...
REUSE_RTOL = 1e-8
#: ... within this many conjugate-gradient steps (each one triangular solve), else S is factored
REUSE_MAX_ITER = 6


class SingularSystem(Exception):
    """The reduced camera system is singular (internal: the callers turn it into a
    ``singular`` status or a :class:`~lidarcat.errors.DatumError`)."""


def inv3(V: np.ndarray) -> np.ndarray:
    """Inverses of (m, 3, 3) blocks by cofactors (vectorised; 20x numpy.linalg.inv on many blocks)."""
    a, b, c = V[:, 0, 0], V[:, 0, 1], V[:, 0, 2]
    d, e, f = V[:, 1, 0], V[:, 1, 1], V[:, 1, 2]
    g, h, i = V[:, 2, 0], V[:, 2, 1], V[:, 2, 2]
    out = np.empty_like(V)
    out[:, 0, 0] = e * i - f * h
    out[:, 1, 0] = f * g - d * i
    out[:, 2, 0] = d * h - e * g
    out[:, 0, 1] = c * h - b * i
    out[:, 1, 1] = a * i - c * g
    out[:, 2, 1] = b * g - a * h
    out[:, 0, 2] = b * f - c * e
    out[:, 1, 2] = c * d - a * f
    out[:, 2, 2] = a * e - b * d
    det = a * out[:, 0, 0] + b * out[:, 1, 0] + c * out[:, 2, 0]
    scale = np.abs(V).max(axis=(1, 2))
    if np.any(~np.isfinite(det)) or np.any(np.abs(det) <= 1e-12 * scale**3):
        raise SingularSystem("a point block of the normal equations is singular")
    return out / det[:, None, None]


class _Aggregator:
    """Sums of (m, ...) blocks by group index, as one sparse (n x m) product (built once).

    ``agg(blocks)[k] = sum of blocks[a] with index[a] == k``; a sparse matrix of ones
    times the blocks flattened to (m, size) -- 20-40x faster than ``np.bincount``
    or ``np.add.reduceat`` on tens of thousands of 6 x 6 blocks.
    """

    def __init__(self, index: np.ndarray, n: int):
        m = len(index)
        self.n = n
        self.matrix = sp.csr_matrix((np.ones(m), (np.asarray(index), np.arange(m))), shape=(n, m))

    def __call__(self, blocks: np.ndarray) -> np.ndarray:
        blocks = np.asarray(blocks)
        tail = blocks.shape[1:]
        return np.asarray(self.matrix @ blocks.reshape(len(blocks), -1)).reshape((self.n,) + tail)


class Gram:
    """Per-group Gram matrices ``out[g] = sum_{a: index[a] == g} X_a^T X_a`` (grouping analysed once).

    The rows of a group stacked are one matrix ``X_g`` (k r x c); groups with the
    same number k of members form one batched product (BLAS per group) -- for
    the camera blocks U_i of the normal equations, a few dozen products instead
    of one small product per observation and a scatter-add.
    """

    def __init__(self, index: np.ndarray, n: int):
        index = np.asarray(index, dtype=np.int64)
        self.n = n
        members = np.arange(len(index))
        self.groups = _slot_groups(index, members, members) if len(index) else []

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """X (m, r, c) -> (n, c, c)."""
        _, r, c = X.shape
        out = np.zeros((self.n, c, c))
        for targets, ia, _ in self.groups:
            g, k = ia.shape
            Xg = np.take(X, ia, axis=0).reshape(g, k * r, c)
            out[targets] = np.matmul(np.transpose(Xg, (0, 2, 1)), Xg)
        return out


def _distinct(a: np.ndarray) -> np.ndarray:
    """Sorted distinct values of an integer array, by sorting: numpy 2.4's hashed
    ``np.unique`` takes about 6x as long on a million keys (322 against 51 ms, quiet)."""
    s = np.sort(a)
    return s[np.r_[True, s[1:] != s[:-1]]] if len(s) else s


def _observation_pairs(pj: np.ndarray, n_pt: int, *, diagonal: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (a, b) of observations of the same point: all ordered pairs (a == b
    included) with *diagonal*, else the unordered pairs a < b (in point order)."""
    order = np.argsort(pj, kind="stable")
    counts = np.bincount(pj, minlength=n_pt)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    a_list, b_list = [], []
    for m in _distinct(counts):
        if m == 0 or (m == 1 and not diagonal):
            continue
        js = np.flatnonzero(counts == m)
        if diagonal:
            ii, kk = np.meshgrid(np.arange(m), np.arange(m), indexing="ij")
        else:
            ii, kk = np.triu_indices(m, 1)
        ii, kk = ii.ravel(), kk.ravel()
        a_list.append(order[(starts[js][:, None] + ii[None, :]).ravel()])
        b_list.append(order[(starts[js][:, None] + kk[None, :]).ravel()])
    if not a_list:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(a_list), np.concatenate(b_list)


class Schur:
    """The reduced camera system of one observation pattern (analysed once).

    Parameters
    ----------
    camera_index, point_index : (n,) int
        Camera and point of every observation.
    n_cameras, n_points : int
    camera_size : int
        Parameters per camera (6: exterior orientation; 9: BAL).
    coords : (C, 3) array, optional
        Approximate camera positions: a better fill-reducing ordering
        (:class:`~lidarcat.bundle.cholesky.SupernodalCholesky`).
    """

    def __init__(self, camera_index: np.ndarray, point_index: np.ndarray, n_cameras: int, n_points: int,
                 camera_size: int = 6, coords: np.ndarray | None = None):
        ei, pj = np.asarray(camera_index), np.asarray(point_index)
        self.ei, self.pj = ei, pj
        self.n_cameras, self.n_points, self.cb = n_cameras, n_points, camera_size
        self.timings = {"assemble": 0.0, "factor": 0.0, "pcg": 0.0, "reuse": 0.0}  # s, accumulated by solve()
        self._factor = None      # the last factor of S (reused by solve(reuse=True))
        self.by_camera = _Aggregator(ei, n_cameras)
        self.by_point = _Aggregator(pj, n_points)
        self.gram_by_camera = Gram(ei, n_cameras)
        cb = camera_size
        oa, ob = _observation_pairs(pj, n_points, diagonal=False)
        ia, ib = ei[oa], ei[ob]
        swap = ia > ib                                   # upper triangle: camera ia < ib
        oa, ob = np.where(swap, ob, oa), np.where(swap, oa, ob)
        ia, ib = ei[oa], ei[ob]
        # block pattern: the diagonal and every camera pair (both triangles)
        diag = np.arange(n_cameras)
        br = np.r_[diag, ia, ib]
        bc = np.r_[diag, ib, ia]
        bpat = sp.csr_matrix((np.ones(len(br)), (br, bc)), shape=(n_cameras, n_cameras))
        bpat.sum_duplicates()
        bpat.sort_indices()
        bpat.data = np.arange(bpat.nnz, dtype=float)      # slot number of every block
        self.n_slots = bpat.nnz
        self.slot_diag = _slots(bpat, diag, diag)
        s_up = _slots(bpat, ia, ib)
        order = np.argsort(s_up, kind="stable")          # pairs sorted by slot (chunks touch few slots)
        self.oa, self.ob, self.s_up = oa[order], ob[order], s_up[order]
        # a point seen twice by one camera (two sensors of a rig exposure): its diagonal block needs
        # T_b W_a^T beside T_a W_b^T (the pair is listed once, a < b, for the precision)
        same = np.flatnonzero(ei[self.oa] == ei[self.ob])
        self._groups = _slot_groups(np.r_[self.s_up, self.s_up[same], self.slot_diag[ei]],
                                    np.r_[self.oa, self.ob[same], np.arange(len(ei))],
                                    np.r_[self.ob, self.oa[same], np.arange(len(ei))], sentinel=len(ei))
        self.up_slots = _distinct(self.s_up)
        ui, uk = _slot_rc(bpat, self.up_slots)
        self.lo_slots = _slots(bpat, uk, ui)
        # scalar CSR pattern: row cb I + a holds, block after block of row I, its cb columns;
        # source (slot s, a, b) of block row I goes to
        # cb^2 indptr[I] + a cb cnt[I] + (s - indptr[I]) cb + b
        indptr, cnt = bpat.indptr, np.diff(bpat.indptr)
        s_all = np.arange(self.n_slots)
        I = np.repeat(np.arange(n_cameras), cnt)
        ar = np.arange(cb)
        dest = (cb * cb * indptr[I][:, None, None] + ar[None, :, None] * cb * cnt[I][:, None, None]
                + (s_all - indptr[I])[:, None, None] * cb + ar[None, None, :])
        total = self.n_slots * cb * cb
        self.gather = np.empty(total, dtype=np.int64)
        self.gather[dest.ravel()] = np.arange(total)
        scal_cols = np.empty(total, dtype=np.int64)
        scal_cols[dest.ravel()] = np.broadcast_to(bpat.indices[:, None, None] * cb + ar[None, None, :],
                                                  dest.shape).ravel()
        scal_indptr = np.r_[0, np.cumsum(np.repeat(cnt * cb, cb))]
        self.pattern = sp.csr_matrix((np.ones(total), scal_cols, scal_indptr),
                                     shape=(n_cameras * cb, n_cameras * cb))
        self.chol = SupernodalCholesky(self.pattern, np.full(n_cameras, cb), coords=coords)
        self._zloc = None        # locations of the Z blocks of the precision (set on first use)
        self._dg: np.ndarray | None = None

    # -----------------------------------------------------------------------

    def release_factor(self) -> None:
        """Drop the factor kept for reuse (before the precision makes its own)."""
        self._factor = None

    def _diag_gather(self) -> np.ndarray:
        """Positions in the scalar CSR data of the diagonal blocks, (C * cb * cb,) in block order."""
        if self._dg is None:
            inv = np.empty_like(self.gather)
            inv[self.gather] = np.arange(len(self.gather))
            cb2 = self.cb * self.cb
            self._dg = inv[(self.slot_diag[:, None] * cb2 + np.arange(cb2)[None, :]).ravel()]
        return self._dg

    def assemble(self, U: np.ndarray, vinv: np.ndarray, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """CSR data of S (pattern :attr:`pattern`) and T = W V^-1 (n, cb, 3).

        Every block of S is one matrix product over the observation pairs of its
        slot: ``sum_pairs T_a W_b^T = A B^T`` with ``A = [T_a1 | T_a2 | ...]``
        (cb x 3k) and ``B = [W_b1 | ...]``; slots with the same number k of pairs
        form one batched product (BLAS per slot), in chunks of at most
        :data:`CHUNK_PAIRS` pairs (memory bounded whatever the block).
        """
        cb = self.cb
        Wt = np.ascontiguousarray(np.transpose(W, (0, 2, 1)))   # (n, 3, cb); free when W is a view
        n = len(self.pj)
        Tt = np.empty((n + 1, 3, cb))                           # T^T = V^-T W^T, then a zero row
        np.matmul(np.transpose(vinv[self.pj], (0, 2, 1)), Wt, out=Tt[:n])
        Tt[n] = 0.0                                             # (the padding of the pair groups)
        blocks = np.zeros((self.n_slots, cb, cb))
        blocks[self.slot_diag] = U
        for slots, ia, ib in self._groups:
            m, k = ia.shape
            At = np.take(Tt, ia, axis=0).reshape(m, 3 * k, cb)   # A^T of every slot
            Bt = np.take(Wt, ib, axis=0).reshape(m, 3 * k, cb)
            blocks[slots] -= np.matmul(np.transpose(At, (0, 2, 1)), Bt)
        blocks[self.lo_slots] = np.transpose(blocks[self.up_slots], (0, 2, 1))
        return blocks.ravel()[self.gather], np.transpose(Tt[:n], (0, 2, 1))

    def factor(self, data: np.ndarray):
        """Supernodal Cholesky of S with CSR *data*; :class:`SingularSystem` if not positive definite."""
        try:
            return self.chol.factor(data)
        except SingularError as ex:
            raise SingularSystem(f"reduced camera system is singular ({ex}: datum defect or a photo with "
                            "degenerate geometry)") from ex

    def solve(self, U, V, W, g_c, g_p, method: str = "direct", reuse: bool = False):
        """Corrections (cameras (C, cb), points (Q, 3)) of the normal equations with gradient g.

        *method*: ``"direct"`` (supernodal Cholesky of S) or ``"pcg"`` (block-Jacobi
        preconditioned conjugate gradients on the explicit S, truncated as in
        inexact Newton: :func:`_pcg`).  With *reuse* (direct only) the factor of
        the previous direct step preconditions conjugate gradients on this S
        (:func:`_pcg_factor`, to :data:`REUSE_RTOL`); when they do not get there
        in :data:`REUSE_MAX_ITER` steps, S is factored afresh.  Worth it once
        the iteration is in its quadratic phase: S hardly changes from step to
        step and a few triangular solves cost less than a factorisation.
        """
        t0 = time.perf_counter()
        vinv = inv3(V)
        data, T = self.assemble(U, vinv, W)
        t1 = time.perf_counter()
        self.timings["assemble"] += t1 - t0
        b_c, b_p = -g_c, -g_p
        rhs = b_c - self.by_camera(np.einsum("nij,nj->ni", T, b_p[self.pj]))
        if method == "pcg":
            S = sp.csr_matrix((data, self.pattern.indices, self.pattern.indptr), shape=self.pattern.shape)
            diag_blocks = data[self._diag_gather()].reshape(self.n_cameras, self.cb, self.cb)
            try:
                prec = np.linalg.inv(diag_blocks)
            except np.linalg.LinAlgError as ex:
                raise SingularSystem(f"reduced camera system is singular ({ex})") from ex
            dc, self.last_cg_iterations = _pcg(S, rhs.reshape(-1), prec)
            dc = dc.reshape(self.n_cameras, self.cb)
            self.timings["pcg"] += time.perf_counter() - t1
        else:
            x = None
            if reuse and self._factor is not None:
                S = sp.csr_matrix((data, self.pattern.indices, self.pattern.indptr), shape=self.pattern.shape)
                x, it = _pcg_factor(S, rhs.reshape(-1), self._factor)
                log.debug("step with the previous factor: %s after %d CG iterations",
                          "converged" if x is not None else "no convergence, factoring", it)
                self.timings["reuse"] += time.perf_counter() - t1
            if x is None:
                t2 = time.perf_counter()
                self._factor = None                          # one factor in memory at a time
                self._factor = self.factor(data)
                x = self._factor.solve(rhs.reshape(-1))
                self.timings["factor"] += time.perf_counter() - t2
            dc = x.reshape(self.n_cameras, self.cb)
        bp = b_p - self.by_point(np.einsum("nij,ni->nj", W, dc[self.ei]))
        dp = np.einsum("qij,qj->qi", vinv, bp)
        return dc, dp


def _pcg_factor(S: sp.csr_matrix, b: np.ndarray, factor, *, rtol: float | None = None,
                max_iter: int | None = None) -> tuple[np.ndarray | None, int]:
    """Conjugate gradients on S x = b preconditioned by the Cholesky *factor* of a nearby S.

    Stops when ``|b - S x| <= rtol |b|`` (default :data:`REUSE_RTOL`: the step as
    exact as a direct solve needs to be for the iteration) and returns
    ``(x, iterations)``; ``(None, max_iter)`` when *max_iter* (default
    :data:`REUSE_MAX_ITER`) steps do not get there (the preconditioner is
    too far from S).
    """
    rtol = REUSE_RTOL if rtol is None else rtol
    max_iter = REUSE_MAX_ITER if max_iter is None else max_iter
    bnorm = float(np.linalg.norm(b))
    if bnorm == 0.0:
        return np.zeros_like(b), 0
    x = factor.solve(b)                      # the preconditioner's own answer is the first iterate
    r = b - S @ x
    d = np.zeros_like(b)
    rz_old = math.inf                        # first direction: the preconditioned residual itself
    for i in range(1, max_iter + 1):
        if float(np.linalg.norm(r)) <= rtol * bnorm:
            return x, i
        z = factor.solve(r)
        rz = float(r @ z)
        d = z + (rz / rz_old) * d
        sd = S @ d
        dsd = float(d @ sd)
        if not dsd > 0:
            break
        alpha = rz / dsd
        x = x + alpha * d
        r = r - alpha * sd
        rz_old = rz
    if float(np.linalg.norm(r)) <= rtol * bnorm:
        return x, max_iter
    return None, max_iter


def _pcg(S: sp.csr_matrix, b: np.ndarray, prec: np.ndarray, *, eta: float = 0.1, max_iter: int = 500,
         min_iter: int = 1) -> tuple[np.ndarray, int]:
    """Preconditioned conjugate gradients for S x = b, truncated (inexact Newton).

    *prec* (C, cb, cb) is the inverse of the diagonal blocks of S (block Jacobi).
    Iteration stops by the Q-ratio rule of Nash and Sofer that Ceres uses for its
    iterative Schur solver: with ``Q_i = x_i' S x_i / 2 - b' x_i`` (monotonically
    decreasing along CG), stop when ``i (Q_i - Q_{i-1}) / Q_i < eta`` -- the
    quadratic model no longer improves by more than eta / i per iteration -- or
    when the residual vanishes.  Returns ``(x, iterations)``.
    """
    cb = prec.shape[1]
    x = np.zeros_like(b)
    r = b.copy()
    z = np.einsum("cij,cj->ci", prec, r.reshape(-1, cb)).ravel()
    d = z.copy()
    rz = float(r @ z)
    q_old = 0.0
    bnorm = float(np.linalg.norm(b))
    if bnorm == 0.0:
        return x, 0
    for i in range(1, max_iter + 1):
        sd = S @ d
        dsd = float(d @ sd)
        if dsd <= 0:
            break
        alpha = rz / dsd
        x += alpha * d
        r -= alpha * sd
        # Q(x) = x'Sx/2 - b'x = -(b'x + r'x)/2 with r = b - S x
        q = -0.5 * float(x @ (b + r))
        if np.linalg.norm(r) <= 1e-14 * bnorm or (i >= min_iter and q != 0 and i * (q - q_old) / q < eta):
            return x, i
        q_old = q
        z = np.einsum("cij,cj->ci", prec, r.reshape(-1, cb)).ravel()
        rz_new = float(r @ z)
        d = z + (rz_new / rz) * d
        rz = rz_new
    return x, i


def _bucket(k: np.ndarray) -> np.ndarray:
    """Padded group size for k members: k itself up to 8, then the next size of a
    geometric ladder of ratio about 1.2 (at most ~20 % padding, few distinct sizes)."""
    k = np.asarray(k, dtype=np.int64)
    ladder = np.unique(np.r_[np.arange(1, 9), np.ceil(8 * 1.2 ** np.arange(1, 80)).astype(np.int64)])
    return ladder[np.searchsorted(ladder, k)]


def _slot_groups(slot: np.ndarray, a: np.ndarray, b: np.ndarray,
                 sentinel: int | None = None) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Observation pairs (a, b) grouped by their slot of S, slots grouped by pair count.

    Returns ``[(slots (m,), a (m, k), b (m, k)), ...]``: m slots of k pairs each,
    at most :data:`CHUNK_PAIRS` pairs per entry (slots distinct within an entry).
    With *sentinel* (the index of a zero row of the arrays that ``a`` indexes),
    counts are padded up to :func:`_bucket` sizes -- fewer, larger batches: ``a``
    is padded with the sentinel, ``b`` with a real member.
    """
    order = np.argsort(slot, kind="stable")
    slot, a, b = slot[order], a[order], b[order]
    n_slots = int(slot.max()) + 1 if len(slot) else 0
    cnt = np.bincount(slot, minlength=n_slots)
    starts = np.r_[0, np.cumsum(cnt)[:-1]]
    size = cnt if sentinel is None else np.where(cnt > 0, _bucket(cnt), 0)
    groups = []
    for k in _distinct(size[size > 0]):
        slots = np.flatnonzero(size == k)
        t = np.arange(k)[None, :]
        real = t < cnt[slots][:, None]
        idx = starts[slots][:, None] + np.where(real, t, 0)
        ga, gb = a[idx], b[idx]
        if sentinel is not None:
            ga = np.where(real, ga, sentinel)
        step = max(1, CHUNK_PAIRS // int(k))
        for c0 in range(0, len(slots), step):
            groups.append((slots[c0:c0 + step], ga[c0:c0 + step], gb[c0:c0 + step]))
    return groups


def _slots(bpat: sp.csr_matrix, r: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Slot (position in the CSR data) of blocks (r, c) of a sorted block pattern."""
    r = np.asarray(r, dtype=np.int64)
    c = np.asarray(c, dtype=np.int64)
    n = bpat.shape[1]
    keys = np.repeat(np.arange(bpat.shape[0]), np.diff(bpat.indptr)) * n + bpat.indices
    pos = np.searchsorted(keys, r * n + c)
    return pos


def _slot_rc(bpat: sp.csr_matrix, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rows = np.repeat(np.arange(bpat.shape[0]), np.diff(bpat.indptr))
    return rows[slots], bpat.indices[slots]
