r"""Supernodal sparse Cholesky of the reduced camera system, and its selected inverse.

Why here and not a library: the covariance of every photo and point needs the
blocks of ``Z = S^-1`` on the pattern of the Cholesky factor of ``S``
(Takahashi / Erisman-Tinney), so the factor itself must be at hand.  CHOLMOD
(scikit-sparse) ships no wheel; cholespy keeps its factor private; SuperLU
(scipy) in symmetric mode gives ``L`` but as a scalar CSC matrix whose
Python-level traversal is slow.  The factor below is written in numpy with
dense BLAS-3 kernels on supernodes, so Python only loops over a few hundred
supernodes.

Ordering (nested dissection on units)
-------------------------------------
``S`` is a matrix of *units*: the 6 (or 9) parameters of a camera, and
optionally one global unit of k parameters (interior orientation, frame
offset) that borders every camera.  The unit graph (an edge for every pair of
cameras sharing a point) is split recursively by a separator: with camera
positions, the vertices of one half of a median split along the longer axis
that see the other half (for strips: a cut straight across them); without,
the middle level of a breadth-first level structure from a pseudo-peripheral
unit (George's automatic nested dissection).  Every separator and every leaf (at
most ``leaf`` units) is a *supernode*; a separator is the parent of the parts
it separates, the global unit (if any) the root.  Units are numbered in
postorder of that tree.

Symbolic analysis (once per pattern)
------------------------------------
The structure of the factor below supernode s is its *boundary*
``b(s) = (adj(s) u  U_{children c} b(c)) \ s`` -- with nested dissection every
neighbour of the subtree of s outside it lies in an ancestor, so ``b(s)`` is a
set of ancestor units and a clique of the filled graph.

Numeric factorisation (multifrontal)
------------------------------------
For every supernode in postorder, the dense front

    F = [[S_ss, S_sb], [S_bs, 0]] + extend-add of the children's update matrices

is factored partially: ``L_ss = chol(F_ss)``, ``L_bs = F_bs L_ss^-T``, and the
update ``F_bb - L_bs L_bs^T`` is passed to the parent.  A pivot
``L_ss[i, i]^2 < 1e-11 S[i, i]`` (or a failed dense Cholesky) is a singular
system (datum defect).

Solve: forward ``x_s <- L_ss^-1 x_s, x_b -= L_bs x_s`` in postorder, backward
``x_s <- L_ss^-T (x_s - L_bs^T x_b)`` in reverse.

Selected inversion (Takahashi recursion over supernodes)
--------------------------------------------------------
From ``Z = L^-T L^-1`` and ``Z L = L^-T``, in reverse postorder (root first),
with ``X = L_bs L_ss^-1``:

    Z_bs = -Z_bb X
    Z_ss = L_ss^-T L_ss^-1 - X^T Z_bs

``Z_bb`` (boundary x boundary) only reads blocks already computed: ``b(s)`` at or
above an ancestor a lies in ``a u b(a)``.  The result is Z on the whole pattern
of L -- every camera's diagonal block and every pair of cameras sharing a point
(they are adjacent in S, so one is in the other's supernode or boundary) --
never a dense inverse.  Work equals a few factorisations.

Threads: both run with BLAS on one thread, the kernels of a big front on the
threads BLAS was configured with (:mod:`._blas`); every kernel is scipy's BLAS.
"""

from __future__ import annotations

import contextlib
import dataclasses

import numpy as np
import scipy.linalg as sla
from scipy.linalg.blas import dgemm as _dgemm
from scipy.linalg.blas import dsymm as _dsymm
from scipy.linalg.blas import dsyrk as _dsyrk
from scipy.linalg.blas import dtrsm as _dtrsm
from scipy.linalg.blas import dtrsv as _dtrsv
from scipy.linalg.lapack import dpotrf as _dpotrf
from scipy.linalg.lapack import dpotri as _dpotri
import scipy.sparse as sp
from scipy.sparse import csgraph

from . import _blas

__all__: list[str] = []

#: relative pivot below which the reduced camera system counts as singular
PIVOT_RTOL = 1e-11


class SingularError(Exception):
    """The matrix is not (numerically) positive definite."""


# ---------------------------------------------------------------------------
# ordering
# ---------------------------------------------------------------------------


def _levels(adj: sp.csr_matrix, start: int) -> np.ndarray:
    """Breadth-first level (hop distance) of every vertex from *start*."""
    return csgraph.shortest_path(adj, method="D", unweighted=True, directed=False, indices=start)


def _coordinate_separator(sub: sp.csr_matrix, xy: np.ndarray) -> np.ndarray | None:
    """Vertex separator of a connected graph by coordinate bisection, or None.

    Split at the median of the coordinate with the larger spread; the separator
    is the smaller of the two one-sided boundaries (vertices of one half with a
    neighbour in the other).  For a block of strips this cuts straight across
    the strips, which level structures (diagonal fronts) do not.
    """
    axis = int(np.argmax(np.ptp(xy, axis=0)))
    left = xy[:, axis] <= np.median(xy[:, axis])
    if left.all() or not left.any():
        return None
    coo = sub.tocoo()
    cross = left[coo.row] != left[coo.col]
    side_l = np.zeros(len(xy), dtype=bool)
    side_l[coo.row[cross & left[coo.row]]] = True
    side_r = np.zeros(len(xy), dtype=bool)
    side_r[coo.row[cross & ~left[coo.row]]] = True
    sep = side_l if side_l.sum() <= side_r.sum() else side_r
    if sep.all() or not sep.any():
        return None
    return sep


def _nested_dissection(adj: sp.csr_matrix, leaf: int,
                       coords: np.ndarray | None = None) -> tuple[list[np.ndarray], list[int]]:
    """Supernodes (unit index arrays) in postorder and their parent (-1: a root).

    With *coords* (one row per vertex, e.g. camera positions) separators come
    from coordinate bisection (:func:`_coordinate_separator`), else from the
    middle level of a breadth-first level structure.
    """
    nodes: list[np.ndarray] = []
    parent: list[int] = []

    def new(v: np.ndarray) -> int:
        nodes.append(np.sort(v))
        parent.append(-1)
        return len(nodes) - 1

    pending: list[tuple[int, list[int]]] = []        # (separator, the nodes it separates)
    tops: list[int] = []
    stack: list[tuple[np.ndarray, list[int]]] = [(np.arange(adj.shape[0]), tops)]
    while stack:
        v, slot = stack.pop()
        sub = adj[v][:, v]
        ncomp, lab = csgraph.connected_components(sub, directed=False)
        if ncomp > 1:
            stack.extend((v[lab == c], slot) for c in range(ncomp))
            continue
        if len(v) <= leaf:
            slot.append(new(v))
            continue
        sep = _coordinate_separator(sub, coords[v]) if coords is not None else None
        if sep is None:
            d = _levels(sub, 0)                       # pseudo-peripheral start: two sweeps
            d = _levels(sub, int(np.argmax(d))).astype(np.int64)
            counts = np.bincount(d)
            m = int(np.searchsorted(np.cumsum(counts), len(v) / 2))
            if m == 0 or m >= len(counts) - 1:        # no useful separator: a dense leaf
                slot.append(new(v))
                continue
            sep = d == m
        sid = new(v[sep])
        slot.append(sid)
        children: list[int] = []
        pending.append((sid, children))
        stack.append((v[~sep], children))
    for sid, ch in pending:
        for c in ch:
            parent[c] = sid
    # postorder
    n = len(nodes)
    kids: list[list[int]] = [[] for _ in range(n)]
    for c, p_ in enumerate(parent):
        if p_ >= 0:
            kids[p_].append(c)
    order: list[int] = []
    for r in tops:
        st = [(r, False)]
        while st:
            x, done = st.pop()
            if done:
                order.append(x)
                continue
            st.append((x, True))
            st.extend((k, False) for k in kids[x])
    new_id = np.empty(n, dtype=np.int64)
    new_id[order] = np.arange(n)
    out_nodes = [nodes[o] for o in order]
    out_parent = [int(new_id[parent[o]]) if parent[o] >= 0 else -1 for o in order]
    return out_nodes, out_parent


# ---------------------------------------------------------------------------
# symbolic analysis
# ---------------------------------------------------------------------------


@dataclasses.dataclass(eq=False)
class _Node:
    cols: np.ndarray        # scalar indices (new numbering) of the supernode, contiguous
    rows: np.ndarray        # scalar indices of its boundary (ascending)
    parent: int
    ext: np.ndarray         # positions of `rows` within the parent's cols + rows
    s_src: np.ndarray       # positions in the S data array of the entries of this front
    s_dst: np.ndarray       # flat positions in the (nc + nb) x nc front
    runs: tuple = ()        # extend-add plan: (child lo, child hi, parent lo) contiguous runs of `ext`
    # selected-inverse gather plan: (ancestor a, row in Z_bb, col in Z_bb, row in Z_a, col in Z_a,
    # rows, cols) rectangular copies that fill the lower triangle of Z_bb
    zbb: list = dataclasses.field(default_factory=list)


class SupernodalCholesky:
    """Symbolic analysis of a symmetric positive (semi)definite unit-block pattern.

    Parameters
    ----------
    pattern : (n, n) sparse
        Pattern of S (symmetric; only the structure is used).  Entries are
        looked up later in the CSR order of this matrix (``pattern.indptr``,
        ``pattern.indices`` with sorted indices).
    unit_sizes : (u,) int
        Scalar size of every unit (6 per camera, k for a global block), units
        contiguous in the scalar numbering.
    root_units : sequence of int, optional
        Units forced into the root supernode (global parameters).
    leaf : int
        Largest number of units in a leaf supernode.
    coords : (u, k) array, optional
        A position per unit (camera centres) for coordinate nested dissection;
        rows of root units are ignored.
    """

    def __init__(self, pattern: sp.spmatrix, unit_sizes: np.ndarray, root_units=(), leaf: int = 16,
                 coords: np.ndarray | None = None):
        pat = sp.csr_matrix(pattern)
        pat.sort_indices()
        self.n = pat.shape[0]
        sizes = np.asarray(unit_sizes, dtype=np.int64)
        self.unit_sizes = sizes
        u_off = np.r_[0, np.cumsum(sizes)]
        if u_off[-1] != self.n:
            raise ValueError("unit sizes do not add up to the matrix size")
        n_units = len(sizes)
        unit_of = np.repeat(np.arange(n_units), sizes)
        coo = pat.tocoo()
        ur, uc = unit_of[coo.row], unit_of[coo.col]
        # one entry per run of a row's columns in one unit (sorted indices: a unit's columns are
        # adjacent): a unit-size-fold fewer entries to sum (10,010 photos: 87 -> 47 ms, same graph)
        first = (np.r_[True, (uc[1:] != uc[:-1]) | (coo.row[1:] != coo.row[:-1])] if len(uc)
                 else np.zeros(0, dtype=bool))
        ur, uc = ur[first], uc[first]
        ug = sp.csr_matrix((np.ones(len(ur)), (ur, uc)), shape=(n_units, n_units))
        ug.setdiag(0)
        ug.eliminate_zeros()
        root = np.asarray(sorted(set(int(r) for r in root_units)), dtype=np.int64)
        free = np.setdiff1d(np.arange(n_units), root)
        sub = ug[free][:, free].tocsr()
        xy = None
        if coords is not None:
            xy = np.asarray(coords, dtype=float)[free]
            xy = xy if np.all(np.isfinite(xy)) else None
        nodes_u, parent = _nested_dissection(sub, leaf, xy)
        nodes_u = [free[nd] for nd in nodes_u]
        if len(root):
            rid = len(nodes_u)
            parent = [rid if p_ < 0 else p_ for p_ in parent] + [-1]
            nodes_u.append(root)
        self.n_nodes = len(nodes_u)
        # unit order: postorder, then scalar permutation
        uorder = np.concatenate(nodes_u)
        upos = np.empty(n_units, dtype=np.int64)
        upos[uorder] = np.arange(n_units)
        new_sizes = sizes[uorder]
        new_off = np.r_[0, np.cumsum(new_sizes)]
        perm = _ranges(u_off[uorder], sizes[uorder])          # new -> old scalar
        iperm = np.empty(self.n, dtype=np.int64)
        iperm[perm] = np.arange(self.n)
        self.perm, self.iperm = perm, iperm
        node_of_unit = np.empty(n_units, dtype=np.int64)
        for k, nd in enumerate(nodes_u):
            node_of_unit[nd] = k
        self.node_of_unit = node_of_unit
        self.unit_pos = upos
        self.unit_off_new = new_off
        # boundaries in unit positions (new numbering), bottom-up
        ugc = ug.tocsr()
        bnd: list[np.ndarray] = []
        kids: list[list[int]] = [[] for _ in range(self.n_nodes)]
        for k, p_ in enumerate(parent):
            if p_ >= 0:
                kids[p_].append(k)
        for k, nd in enumerate(nodes_u):
            last = upos[nd].max()
            nb = [upos[ugc.indices[_ranges(ugc.indptr[nd], ugc.indptr[nd + 1] - ugc.indptr[nd])]]]
            nb += [bnd[c] for c in kids[k]]
            allb = np.unique(np.concatenate(nb)) if nb else np.zeros(0, dtype=np.int64)
            allb = allb[allb > last]               # ancestors only (nested dissection)
            bnd.append(allb)
        # scalar structure

        def scal(units_pos: np.ndarray) -> np.ndarray:
            return _ranges(new_off[units_pos], new_sizes[units_pos])

        self.nodes: list[_Node] = []
        for k, nd in enumerate(nodes_u):
            up = np.sort(upos[nd])
            cols = scal(up)
            rows = scal(bnd[k])
            self.nodes.append(_Node(cols=cols, rows=rows, parent=parent[k], ext=np.zeros(0, np.int64),
                                    s_src=np.zeros(0, np.int64), s_dst=np.zeros(0, np.int64)))
        self.kids = kids
        for node in self.nodes:
            if node.parent >= 0:
                pn = self.nodes[node.parent]
                allp = np.concatenate([pn.cols, pn.rows])
                node.ext = np.searchsorted(allp, node.rows)
                node.runs = _runs(node.ext, len(pn.cols))
        # S entries -> fronts: lower part, column in node cols, row in cols or rows
        r_new, c_new = iperm[coo.row], iperm[coo.col]
        # coo of a sorted csr has the csr data order
        keep = r_new >= c_new
        src = np.flatnonzero(keep)
        r_new, c_new = r_new[keep], c_new[keep]
        col_node = node_of_unit[unit_of[perm[c_new]]]
        order = np.argsort(col_node, kind="stable")
        src, r_new, c_new, col_node = src[order], r_new[order], c_new[order], col_node[order]
        bounds = np.searchsorted(col_node, np.arange(self.n_nodes + 1))
        for k, node in enumerate(self.nodes):
            a, b = bounds[k], bounds[k + 1]
            allr = np.concatenate([node.cols, node.rows])
            rp = np.searchsorted(allr, r_new[a:b])
            cp = c_new[a:b] - node.cols[0]
            node.s_src = src[a:b]
            node.s_dst = rp * len(node.cols) + cp
        # Z_bb gather plan for the selected inverse
        for node in self.nodes:
            if not len(node.rows):
                continue
            rnode = node_of_unit[unit_of[perm[node.rows]]]
            for a in np.unique(rnode):
                an = self.nodes[a]
                cpos = np.flatnonzero(rnode == a)          # b entries inside ancestor a: columns
                rpos = np.flatnonzero(node.rows >= an.cols[0])  # b entries at or above a
                alla = np.concatenate([an.cols, an.rows])
                rr = _pair_runs(rpos, np.searchsorted(alla, node.rows[rpos]))
                cr = _pair_runs(cpos, node.rows[cpos] - an.cols[0])
                node.zbb.extend((int(a), dr, dc, sr, sc, nr, ncl) for dr, sr, nr in rr for dc, sc, ncl in cr)
        self.diag_src = np.full(self.n, -1, dtype=np.int64)
        on = coo.row == coo.col
        self.diag_src[coo.row[on]] = np.flatnonzero(on)
        self.pattern_shape = pat.shape
        self.nnz_l = int(sum(len(nd.cols) * (len(nd.cols) + len(nd.rows)) for nd in self.nodes))
        self.z_offsets = np.r_[0, np.cumsum([len(nd.cols) * (len(nd.cols) + len(nd.rows)) for nd in self.nodes])]

    def locate(self, ui: np.ndarray, uk: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where the blocks Z[unit ui, unit uk] lie in :attr:`SelectedInverse.flat`.

        Returns ``(base, row_stride, col_stride)``, each (m,): element (p, q) of
        block m is ``flat[base + p row_stride + q col_stride]``.  Depends on the
        pattern only (compute once, gather every time).

        Raises
        ------
        ValueError
            A pair outside the pattern of the factor.
        """
        ui, uk = np.asarray(ui, dtype=np.int64), np.asarray(uk, dtype=np.int64)
        pi, pk = self.unit_pos[ui], self.unit_pos[uk]
        swap = pi > pk                       # column unit: the one earlier in the order
        uc, ur = np.where(swap, uk, ui), np.where(swap, ui, uk)
        node = self.node_of_unit[uc]
        base = np.empty(len(ui), dtype=np.int64)
        nc_of = np.empty(len(ui), dtype=np.int64)
        offn = self.unit_off_new
        order = np.argsort(node, kind="stable")
        bounds = np.searchsorted(node[order], np.arange(self.n_nodes + 1))
        for k in np.flatnonzero(np.diff(bounds)):
            sel = order[bounds[k]:bounds[k + 1]]
            nd = self.nodes[k]
            nc = len(nd.cols)
            allr = np.concatenate([nd.cols, nd.rows])
            r0 = offn[self.unit_pos[ur[sel]]]
            rp = np.searchsorted(allr, r0)
            if np.any(rp >= len(allr)) or np.any(allr[np.minimum(rp, len(allr) - 1)] != r0):
                raise ValueError("requested block outside the pattern of the factor")
            base[sel] = self.z_offsets[k] + rp * nc + offn[self.unit_pos[uc[sel]]] - nd.cols[0]
            nc_of[sel] = nc
        one = np.ones(len(ui), dtype=np.int64)
        return base, np.where(swap, nc_of, one), np.where(swap, one, nc_of)

    # -----------------------------------------------------------------------

    def factor(self, data: np.ndarray) -> _Factor:
        """Numeric factorisation of the matrix with the analysed pattern and CSR *data*.

        Raises
        ------
        SingularError
            Not positive definite, or a relative pivot below :data:`PIVOT_RTOL`.
        """
        return _Factor(self, np.asarray(data, dtype=float))


def _ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + l)`` for every (s, l), vectorised (int64)."""
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    total = int(lengths.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    first = np.cumsum(lengths) - lengths                 # position of each range in the output
    return np.repeat(starts - first, lengths) + np.arange(total)


def _pair_runs(dst: np.ndarray, src: np.ndarray) -> list[tuple[int, int, int]]:
    """Maximal runs where both *dst* and *src* advance by one: ``[(dst0, src0, length), ...]``."""
    if not len(dst):
        return []
    brk = np.flatnonzero((np.diff(dst) != 1) | (np.diff(src) != 1)) + 1
    lo = np.concatenate([[0], brk])
    hi = np.concatenate([brk, [len(dst)]])
    return [(int(dst[a]), int(src[a]), int(b - a)) for a, b in zip(lo, hi)]


def _runs(ext: np.ndarray, nc: int) -> tuple:
    """Maximal runs of consecutive positions in *ext* (ascending), split at the parent's *nc*.

    Returns ``((lo, hi, dest), ...)``: ``ext[lo:hi] == dest + arange(hi - lo)``, each run
    entirely in the parent's columns (dest < nc) or entirely in its boundary.
    """
    if not len(ext):
        return ()
    brk = np.flatnonzero((np.diff(ext) != 1) | (ext[1:] == nc)) + 1
    lo = np.concatenate([[0], brk])
    hi = np.concatenate([brk, [len(ext)]])
    return tuple((int(a), int(b), int(ext[a])) for a, b in zip(lo, hi))


def _extend_add(F: np.ndarray, Fbb: np.ndarray, Uc: np.ndarray, runs: tuple, nc: int) -> None:
    """Add a child's update matrix *Uc* (lower triangle valid) into the parent's front.

    The front is ``F`` ((nc + nb) x nc: the parent's columns) and ``Fbb`` (nb x nb:
    boundary x boundary).  The child's boundary maps onto few contiguous runs of the
    parent's positions (units of 6 or 9 scalars, consecutive cameras), so the
    scatter is a handful of rectangular slice additions (memory speed) instead of
    fancy indexing of every entry; blocks above the diagonal are skipped.
    """
    for i, (r0, r1, pr) in enumerate(runs):
        for c0, c1, pc in runs[:i + 1]:
            if pc < nc:
                F[pr:pr + r1 - r0, pc:pc + c1 - c0] += Uc[r0:r1, c0:c1]
            else:
                Fbb[pr - nc:pr - nc + r1 - r0, pc - nc:pc - nc + c1 - c0] += Uc[r0:r1, c0:c1]


def _big_kernels(nc: int, nb: int, big: int):
    """All *big* configured BLAS threads for a front whose kernels are big (:mod:`._blas`)."""
    flops = nc * nb * (nc + nb) + nc**3 / 3.0
    if big > 1 and flops >= _blas.BIG_KERNEL_FLOPS:
        return _blas.threads(big)
    return contextlib.nullcontext()


class _Factor:
    """A numeric supernodal factor ``P S P^T = L L^T``."""

    def __init__(self, sym: SupernodalCholesky, data: np.ndarray):
        self.sym = sym
        self.Lss: list[np.ndarray] = []
        self.Lbs: list[np.ndarray] = []
        diag = np.where(sym.diag_src >= 0, data[np.maximum(sym.diag_src, 0)], 0.0)[sym.perm]
        with _blas.pinned():
            self._factor_fronts(sym, data, diag, _blas.big())

    def _factor_fronts(self, sym: SupernodalCholesky, data: np.ndarray, diag: np.ndarray, big: int) -> None:
        updates: dict[int, np.ndarray] = {}
        for k, node in enumerate(sym.nodes):
            nc, nb = len(node.cols), len(node.rows)
            F = np.zeros((nc + nb) * nc)
            F[node.s_dst] = data[node.s_src]
            F = F.reshape(nc + nb, nc)
            Fbb = np.zeros((nb, nb)) if nb else None
            for c in sym.kids[k]:
                Uc = updates.pop(c, None)
                if Uc is not None and len(Uc):
                    _extend_add(F, Fbb, Uc, sym.nodes[c].runs, nc)
            with _big_kernels(nc, nb, big):
                self._front(k, node, F, Fbb, nc, nb, diag, updates)

    def _front(self, k: int, node: _Node, F: np.ndarray, Fbb: np.ndarray | None, nc: int, nb: int,
               diag: np.ndarray, updates: dict[int, np.ndarray]) -> None:
        """Partial factorisation of one assembled front (module docstring)."""
        # LAPACK/BLAS straight on Fortran views of the C-ordered front (no copies, no
        # wrapper overhead): F[:nc].T is upper-stored L^T, F[nc:].T = F_bs^T
        Lt, info = _dpotrf(F[:nc].T, lower=0, clean=0, overwrite_a=1)
        if info != 0:
            raise SingularError(f"not positive definite (leading minor {info})")
        if not np.shares_memory(Lt, F):  # pragma: no cover - f2py copied
            F[:nc] = Lt.T
        L = F[:nc]                                       # lower triangle valid
        piv = np.diagonal(L) ** 2
        ref = diag[node.cols]
        ratio = piv / np.where(ref > 0, ref, 1.0)
        if not np.all(np.isfinite(piv)) or ratio.min() < PIVOT_RTOL:
            raise SingularError(f"relative pivot {ratio.min():.1e}")
        self.Lss.append(L)
        if nb:
            # L_bs^T = L_ss^-1 F_bs^T in place
            out = _dtrsm(1.0, L.T, F[nc:].T, side=0, lower=0, trans_a=1, overwrite_b=1)
            if not np.shares_memory(out, F):  # pragma: no cover - f2py copied
                F[nc:] = out.T
            Lbs = F[nc:]
            self.Lbs.append(Lbs)
            # Fbb - Lbs Lbs^T, lower triangle only (BLAS syrk on the Fortran views: half the
            # flops of a product); every reader of an update reads its lower triangle
            ft = Fbb.T
            out = _dsyrk(-1.0, Lbs.T, beta=1.0, c=ft, trans=1, lower=0, overwrite_c=1)
            if out is not ft:  # pragma: no cover - f2py copied
                Fbb = out.T
            updates[k] = Fbb
        else:
            self.Lbs.append(np.zeros((0, nc)))

    def solve(self, b: np.ndarray) -> np.ndarray:
        """x with S x = b, b of shape (n,) or (n, m)."""
        sym = self.sym
        x = np.asarray(b, dtype=float)[sym.perm].copy()
        if x.ndim == 1:
            # L_ss^-1 and L_ss^-T by BLAS trsv on the Fortran view (upper-stored L^T)
            def fwd(L, v):
                return _dtrsv(L.T, v, lower=0, trans=1)

            def bwd(L, v):
                return _dtrsv(L.T, v, lower=0, trans=0)
        else:
            def fwd(L, v):
                return sla.solve_triangular(L, v, lower=True, check_finite=False)

            def bwd(L, v):
                return sla.solve_triangular(L, v, lower=True, trans="T", check_finite=False)
        for k, node in enumerate(sym.nodes):
            c0, c1 = node.cols[0], node.cols[-1] + 1
            xs = fwd(self.Lss[k], x[c0:c1])
            x[c0:c1] = xs
            if len(node.rows):
                x[node.rows] -= self.Lbs[k] @ xs
        for k in range(sym.n_nodes - 1, -1, -1):
            node = sym.nodes[k]
            c0, c1 = node.cols[0], node.cols[-1] + 1
            xs = x[c0:c1]
            if len(node.rows):
                xs = xs - self.Lbs[k].T @ x[node.rows]
            x[c0:c1] = bwd(self.Lss[k], xs)
        return x[sym.iperm]

    def selected_inverse(self) -> SelectedInverse:
        """Z = S^-1 on the pattern of the factor (see the module docstring)."""
        sym = self.sym
        flat = np.empty(sym.z_offsets[-1])
        Z: list[np.ndarray] = [np.zeros((0, 0))] * sym.n_nodes   # Z[cols + rows, cols] per supernode
        with _blas.pinned():
            big = _blas.big()
            for k in range(sym.n_nodes - 1, -1, -1):
                node = sym.nodes[k]
                nc, nb = len(node.cols), len(node.rows)
                zk = flat[sym.z_offsets[k]:sym.z_offsets[k + 1]].reshape(nc + nb, nc)
                with _big_kernels(nc, nb, big):
                    self._inverse_front(k, node, zk, Z, nc, nb)
                Z[k] = zk
        return SelectedInverse(sym, flat)

    def _inverse_front(self, k: int, node: _Node, zk: np.ndarray, Z: list[np.ndarray], nc: int, nb: int) -> None:
        """Z_ss and Z_bs of supernode k from the Z blocks of its ancestors (module docstring)."""
        # L_ss^-T L_ss^-1 from the Cholesky factor (LAPACK potri: lower triangle)
        inv, info = _dpotri(self.Lss[k].T, lower=0)    # Fortran view: upper-stored L^T
        if info:  # pragma: no cover - the factor was checked
            raise SingularError(f"potri failed ({info})")
        inv = inv.T                                     # lower triangle valid
        inv = np.tril(inv) + np.tril(inv, -1).T
        if nb:
            Zbb = np.empty((nb, nb))
            for a, dr, dc, sr, sc, nr, ncl in node.zbb:
                Zbb[dr:dr + nr, dc:dc + ncl] = Z[a][sr:sr + nr, sc:sc + ncl]
            # X = L_bs L_ss^-1, i.e. X^T = L_ss^-T L_bs^T (one triangular solve)
            Xt = _dtrsm(1.0, self.Lss[k].T, self.Lbs[k].T, side=0, lower=0, trans_a=0)
            # Z_bs = -Z_bb X with only the lower triangle of Z_bb filled (BLAS symm; Z_bb.T
            # is Fortran-ordered, its upper triangle is Z_bb's lower)
            zbs = _dsymm(-1.0, Zbb.T, Xt.T, side=0, lower=0)
            zk[nc:] = zbs
            # Z_ss = inv - X^T Z_bs, by scipy's BLAS like every kernel here: numpy's own BLAS
            # is a second library whose idle threads would spin against these (_blas)
            zss = _dgemm(-1.0, Xt, zbs, beta=1.0, c=np.asfortranarray(inv), overwrite_c=1)
            zk[:nc] = 0.5 * (zss + zss.T)
        else:
            zk[:nc] = inv


class SelectedInverse:
    """Blocks of S^-1 on the pattern of its Cholesky factor (one flat array)."""

    def __init__(self, sym: SupernodalCholesky, flat: np.ndarray):
        self.sym = sym
        self.flat = flat

    def gather(self, loc: tuple[np.ndarray, np.ndarray, np.ndarray], a: int, b: int) -> np.ndarray:
        """Blocks (m, a, b) at the locations *loc* of :meth:`SupernodalCholesky.locate`."""
        base, rs, cs = loc
        idx = (base[:, None, None] + np.arange(a)[None, :, None] * rs[:, None, None]
               + np.arange(b)[None, None, :] * cs[:, None, None])
        return self.flat[idx]

    def blocks(self, ui: np.ndarray, uk: np.ndarray) -> np.ndarray:
        """Blocks Z[unit i, unit k] (m, a, b) for unit index arrays (all ui of size a, all uk of size b).

        Raises
        ------
        ValueError
            A pair outside the pattern of the factor, or units of mixed sizes.
        """
        sym = self.sym
        ui, uk = np.asarray(ui, dtype=np.int64), np.asarray(uk, dtype=np.int64)
        if len(ui) == 0:
            return np.zeros((0, 0, 0))
        a, b = int(sym.unit_sizes[ui[0]]), int(sym.unit_sizes[uk[0]])
        if np.any(sym.unit_sizes[ui] != a) or np.any(sym.unit_sizes[uk] != b):
            raise ValueError("blocks(): all units of one call must have the same size")
        return self.gather(sym.locate(ui, uk), a, b)
