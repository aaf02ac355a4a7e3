"""The production-size engine: supernodal Cholesky, selected inversion, precision switch (issue 11)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from lidarcat.synthetic.block import synthetic_block
from lidarcat.bundle import NormalSystem, adjust, covariance_blocks, observation_blocks
from lidarcat.bundle.cholesky import SingularError, SupernodalCholesky


def _grid_matrix(nx: int, ny: int, k_global: int, seed: int):
    """A random SPD matrix of 6 x 6 units on an nx x ny grid graph (with diagonal and
    skip-one neighbours), plus one global unit of size *k_global* bordering every unit."""
    rng = np.random.default_rng(seed)
    P = nx * ny
    edges = []
    for i in range(nx):
        for j in range(ny):
            for di, dj in ((1, 0), (0, 1), (1, 1), (2, 0)):
                if i + di < nx and j + dj < ny:
                    edges.append((i * ny + j, (i + di) * ny + j + dj))
    sizes = np.r_[np.full(P, 6), [k_global] if k_global else []].astype(int)
    off = np.r_[0, np.cumsum(sizes)]
    pairs = edges + ([(u, P) for u in range(P)] if k_global else [])
    rows, cols, vals = [], [], []
    for a, b in pairs:
        B = rng.normal(size=(sizes[a], sizes[b]))
        R, C = np.meshgrid(np.arange(off[a], off[a + 1]), np.arange(off[b], off[b + 1]), indexing="ij")
        rows += [R.ravel(), C.ravel()]
        cols += [C.ravel(), R.ravel()]
        vals += [B.ravel(), B.ravel()]
    n = off[-1]
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    A = (A + sp.diags(np.abs(A).sum(axis=1).A1 + 1.0)).tocsr()
    A.sort_indices()
    return A, sizes, off, np.array(edges)


@pytest.mark.parametrize("k_global", [0, 4])
def test_supernodal_cholesky_solve_and_selected_inverse_equal_dense(k_global):
    A, sizes, off, edges = _grid_matrix(14, 9, k_global, seed=2)
    P = 14 * 9
    sym = SupernodalCholesky(A, sizes, root_units=[P] if k_global else (), leaf=6)
    assert sym.n_nodes > 10                      # a real tree, not one dense front
    f = sym.factor(A.data)
    b = np.random.default_rng(1).normal(size=(A.shape[0], 2))
    np.testing.assert_allclose(A @ f.solve(b), b, rtol=0, atol=1e-10)
    D = np.linalg.inv(A.toarray())
    Z = f.selected_inverse()
    ui = np.r_[np.arange(P), edges[:, 0], edges[:, 1]]
    uk = np.r_[np.arange(P), edges[:, 1], edges[:, 0]]
    ref = np.stack([D[off[i]:off[i + 1], off[k]:off[k + 1]] for i, k in zip(ui, uk)])
    np.testing.assert_allclose(Z.blocks(ui, uk), ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    if k_global:
        g = Z.blocks(np.arange(P), np.full(P, P))          # camera x global cross blocks (6 x k)
        ref = np.stack([D[off[i]:off[i + 1], off[P]:] for i in range(P)])
        np.testing.assert_allclose(g, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
        np.testing.assert_allclose(Z.blocks([P], [P])[0], D[off[P]:, off[P]:], rtol=1e-10)
    leaves = [k for k in range(sym.n_nodes) if not sym.kids[k]]
    u0 = np.flatnonzero(sym.node_of_unit == leaves[0])[0]
    u1 = np.flatnonzero(sym.node_of_unit == leaves[-1])[0]   # two leaves: never on each other's pattern
    with pytest.raises(ValueError, match="outside the pattern of the factor"):
        Z.blocks([u0], [u1])


def test_supernodal_cholesky_reports_an_indefinite_matrix():
    A, sizes, _, _ = _grid_matrix(6, 5, 0, seed=3)
    A = A.tolil()
    A[10, 10] = -1.0
    A = A.tocsr()
    A.sort_indices()
    with pytest.raises(SingularError):
        SupernodalCholesky(A, sizes, leaf=4).factor(A.data)


@pytest.fixture(scope="module")
def block100():
    """A 10 x 10 photo block linearised at its truth."""
    b = synthetic_block(10, 10, seed=3, point_spacing_m=150.0)
    return b, NormalSystem(b.problem, b.true_eo, b.true_points_m)


def test_precision_blocks_equal_dense_inverse_on_100_photos(block100):
    """Photo 6x6, point 3x3 and photo-point blocks equal a dense inverse to 1e-9 (relative)."""
    b, system = block100
    p = b.problem
    n_ph, n_pt = p.n_photos, p.n_points
    assert n_ph == 100
    schur = system.schur
    from lidarcat.bundle.linear import inv3

    vinv = inv3(system.V)
    data, T = schur.assemble(system.U, vinv, system.W)
    S = sp.csr_matrix((data, schur.pattern.indices, schur.pattern.indptr), shape=schur.pattern.shape).toarray()
    # the assembled S equals the dense Schur complement U - W V^-1 W^T
    W = np.zeros((6 * n_ph, 3 * n_pt))
    for a, (i, j) in enumerate(zip(p.photo_index, p.point_index)):
        W[6 * i:6 * i + 6, 3 * j:3 * j + 3] = system.W[a]
    Vi = sp.block_diag(list(vinv)).toarray()
    U = sp.block_diag(list(system.U)).toarray()
    S_dense = U - W @ Vi @ W.T
    np.testing.assert_allclose(S, S_dense, rtol=0, atol=1e-12 * np.abs(S_dense).max())
    d = 1.0 / np.sqrt(np.diag(S_dense))               # equilibrate (m and rad differ by 1e6)
    Z = d[:, None] * np.linalg.inv(d[:, None] * S_dense * d[None, :]) * d[None, :]
    cam_cov, point_cov = covariance_blocks(system, "all")
    ref_cam = np.stack([Z[6 * i:6 * i + 6, 6 * i:6 * i + 6] for i in range(n_ph)])
    rel = np.abs(cam_cov - ref_cam).max(axis=(1, 2)) / np.abs(ref_cam).max(axis=(1, 2))
    assert rel.max() < 1e-9
    TZ = Vi @ W.T @ Z                                  # (3Q, 6P): -Cov(X, c)
    M = TZ @ W @ Vi
    ref_pt = np.stack([vinv[j] + M[3 * j:3 * j + 3, 3 * j:3 * j + 3] for j in range(n_pt)])
    rel = np.abs(point_cov - ref_pt).max(axis=(1, 2)) / np.abs(ref_pt).max(axis=(1, 2))
    assert rel.max() < 1e-9
    ob = observation_blocks(system)
    cross = np.stack([-TZ[3 * j:3 * j + 3, 6 * i:6 * i + 6].T for i, j in zip(p.photo_index, p.point_index)])
    rel = np.abs(ob[:, :6, 6:] - cross).max(axis=(1, 2)) / np.abs(cross).max(axis=(1, 2))
    assert rel.max() < 1e-9
    np.testing.assert_array_equal(ob[:, :6, :6], cam_cov[p.photo_index])
    np.testing.assert_allclose(ob[:, 6:, 6:], point_cov[p.point_index], rtol=1e-12)
    np.testing.assert_array_equal(ob[:, 6:, :6], np.transpose(ob[:, :6, 6:], (0, 2, 1)))


def test_precision_switch():
    b = synthetic_block(3, 5, seed=4, point_spacing_m=120.0)
    init = (b.true_eo, b.true_points_m)
    full = adjust(b.problem, initial=init)
    photos = adjust(b.problem, initial=init, precision="photos")
    none = adjust(b.problem, initial=init, precision="none")
    np.testing.assert_array_equal(photos.eo_params, full.eo_params)
    np.testing.assert_allclose(photos.eo_cov, full.eo_cov, rtol=1e-12)
    assert np.isnan(photos.point_cov).all() and np.isfinite(full.point_cov).all()
    assert np.isnan(none.eo_cov).all() and np.isnan(none.point_cov).all()
    assert none.vtpv == full.vtpv and none.success
    with pytest.raises(ValueError, match="`precision` must be one of none, photos, all, got 'some'"):
        adjust(b.problem, initial=init, precision="some")


def test_pcg_solver_reaches_the_direct_minimum():
    """Inexact-Newton PCG steps (block Jacobi, Q-ratio truncation) end at the same minimum as the
    Cholesky steps; the covariance (always from the factor) is the same."""
    b = synthetic_block(3, 6, seed=6, point_spacing_m=120.0)
    direct = adjust(b.problem, solver="direct")
    pcg = adjust(b.problem, solver="pcg", max_iter=100)
    assert direct.success and pcg.success
    assert abs(pcg.vtpv - direct.vtpv) < 1e-8 * direct.vtpv
    np.testing.assert_allclose(pcg.points_m, direct.points_m, rtol=0, atol=1e-3)
    np.testing.assert_allclose(pcg.eo_cov, direct.eo_cov, rtol=1e-4, atol=1e-14)
    assert pcg.phases_s["solve_pcg"] > 0 and pcg.phases_s["solve_factor"] == 0
    with pytest.raises(ValueError, match="`solver` must be one of auto, direct, pcg, got 'lu'"):
        adjust(b.problem, solver="lu")


def test_pcg_truncation_and_exact_solution():
    """_pcg solves an SPD system exactly with a tiny eta, and stops early (fewer iterations) with
    Ceres's eta = 0.1 while still decreasing the quadratic model."""
    from lidarcat.bundle.linear import _pcg

    A, sizes, off, _ = _grid_matrix(8, 6, 0, seed=7)
    b = np.random.default_rng(8).normal(size=A.shape[0])
    D = A.toarray()
    prec = np.linalg.inv(np.stack([D[o:o + 6, o:o + 6] for o in off[:-1]]))
    x, it_exact = _pcg(A, b, prec, eta=1e-12, max_iter=2000)
    # the Q-ratio converges quadratically faster than x: S x = b to ~1e-8, not to rounding
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-6 * np.abs(b).max())
    y, it_trunc = _pcg(A, b, prec)
    assert 1 <= it_trunc < it_exact
    assert 0.5 * y @ (A @ y) - b @ y < 0


def test_gram_sums_per_group_with_mixed_group_sizes():
    """Gram (per-camera U blocks): sum of X_a' X_a per group, groups of many sizes, empty groups zero."""
    from lidarcat.bundle.linear import Gram

    rng = np.random.default_rng(11)
    index = rng.integers(0, 40, 700) ** 2 // 40          # skewed sizes; some groups empty
    X = rng.normal(size=(700, 2, 6))
    out = Gram(index, 41)(X)
    ref = np.zeros((41, 6, 6))
    for a, g in enumerate(index):
        ref[g] += X[a].T @ X[a]
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    empty = np.setdiff1d(np.arange(41), index)
    assert len(empty) and not out[empty].any()


def test_slot_groups_cover_every_pair_once_and_pad_with_the_sentinel():
    """The batched assembly plan: every (slot, a, b) exactly once; padding only in `a`, with the
    sentinel; padded sizes from the ladder (at most ~20 % above the count)."""
    from lidarcat.bundle.linear import _bucket, _slot_groups

    rng = np.random.default_rng(12)
    m = 5000
    slot = rng.integers(0, 300, m) ** 2 // 300
    a, b = np.arange(m), rng.permutation(m)
    got = []
    for slots, ga, gb in _slot_groups(slot, a, b, sentinel=m):
        assert len(np.unique(slots)) == len(slots) and ga.shape == gb.shape == (len(slots), ga.shape[1])
        real = ga != m
        assert real[:, 0].all()                        # every slot has a real first pair
        s = np.broadcast_to(slots[:, None], ga.shape)
        got.append(np.stack([s[real], ga[real], gb[real]], axis=1))
        assert np.isin(gb[~real], b).all()             # padding of b: real members (finite rows)
    got = np.concatenate(got)
    want = np.stack([slot, a, b], axis=1)
    np.testing.assert_array_equal(got[np.lexsort(got.T[::-1])], want[np.lexsort(want.T[::-1])])
    k = np.arange(1, 5000)
    assert np.all(_bucket(k) >= k) and np.all(_bucket(k) <= np.ceil(1.2 * k) + 1)
    np.testing.assert_array_equal(_bucket(np.arange(1, 9)), np.arange(1, 9))


def test_jacobian_parts_with_a_photo_index_equal_the_gathered_form():
    """project / project_with_jacobians with one row per photo and an index equal the same with
    the rows gathered (the structure-of-arrays path), and a_eo = [-a_pt, a_ang]."""
    from lidarcat.geometry.collinearity import project_jacobian_parts, project, project_with_jacobians

    rng = np.random.default_rng(13)
    eo = np.c_[rng.normal(0, 50, (4, 2)), 1500 + rng.normal(0, 20, 4), rng.normal(0, 0.1, (4, 2)),
               rng.uniform(-np.pi, np.pi, 4)]
    idx = rng.integers(0, 4, 30)
    xyz = np.c_[rng.normal(0, 300, (30, 2)), rng.normal(0, 30, 30)]
    c = np.full(30, 51.902)
    full = project_with_jacobians(eo[idx], xyz, c)
    for got, want in zip(project_with_jacobians(eo, xyz, c, idx), full):
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-12)
    xy, a_pt, a_ang, u3 = project_jacobian_parts(eo, xyz, c, idx)
    np.testing.assert_array_equal(full[1][:, :, :3], -full[2])
    np.testing.assert_allclose(a_ang, full[1][:, :, 3:], rtol=1e-13, atol=1e-12)
    pxy, pu3 = project(eo, xyz, c, idx)
    np.testing.assert_allclose(pxy, full[0], rtol=1e-14)
    np.testing.assert_allclose(pu3, full[3], rtol=1e-14)


def test_extend_add_runs_split_at_the_parents_columns():
    """The extend-add plan: maximal runs of consecutive parent positions, never straddling the
    parent's column / boundary split; the slice additions equal a fancy-indexed scatter (lower part)."""
    from lidarcat.bundle.cholesky import _extend_add, _runs

    ext = np.array([0, 1, 2, 5, 6, 7, 8, 11])
    assert _runs(ext, 7) == ((0, 3, 0), (3, 5, 5), (5, 7, 7), (7, 8, 11))
    nc, nb = 7, 5
    rng = np.random.default_rng(14)
    Uc = rng.normal(size=(8, 8))
    F, Fbb = np.zeros((nc + nb, nc)), np.zeros((nb, nb))
    _extend_add(F, Fbb, Uc, _runs(ext, nc), nc)
    full = np.zeros((nc + nb, nc + nb))
    full[np.ix_(ext, ext)] += Uc
    low = np.tril(np.ones((nc + nb, nc + nb), dtype=bool))
    got = np.zeros_like(full)
    got[:, :nc] = F
    got[nc:, nc:] = Fbb
    np.testing.assert_array_equal(got[low], full[low])


# --- factor reuse (linear._pcg_factor) and BLAS threads per kernel (_blas) ---------------------

def _spd_pattern_system(seed: int, n_units: int = 40):
    """A random SPD block-tridiagonal-plus matrix on 6-units, its CSR pattern and analysis."""
    import scipy.sparse as sp
    from lidarcat.bundle.cholesky import SupernodalCholesky

    rng = np.random.default_rng(seed)
    n = 6 * n_units
    A = sp.random(n, n, density=0.02, random_state=seed) + sp.eye(n, k=6) + sp.eye(n, k=12)
    A = (A @ A.T + n * sp.eye(n)).tocsr()
    A.sort_indices()
    sym = SupernodalCholesky(A, np.full(n_units, 6), leaf=4)
    return A, sym, rng


def test_pcg_with_a_nearby_factor_reaches_the_direct_solution():
    import scipy.sparse as sp
    from lidarcat.bundle.linear import _pcg_factor

    A, sym, rng = _spd_pattern_system(0)
    # the factor of a matrix 1e-3 away (relative) on the same pattern preconditions A
    B = A.copy()
    B.data = B.data * (1 + 1e-3 * rng.standard_normal(B.nnz))
    B = ((B + B.T) * 0.5).tocsr()
    B.sort_indices()
    fb = sym.factor(sp.csr_matrix(B).data)
    b = rng.standard_normal(A.shape[0])
    x, it = _pcg_factor(A, b, fb, rtol=1e-12, max_iter=10)
    exact = np.linalg.solve(A.toarray(), b)
    assert x is not None and 1 <= it <= 10
    np.testing.assert_allclose(x, exact, rtol=1e-9, atol=1e-12 * np.abs(exact).max())
    assert np.linalg.norm(b - A @ x) <= 1e-12 * np.linalg.norm(b)


def test_pcg_with_a_far_factor_gives_up_so_the_caller_factors():
    from lidarcat.bundle.linear import _pcg_factor

    A, sym, rng = _spd_pattern_system(1)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    far = sym.factor(np.where(A.indices == rows, A.data, 0.0))   # the diagonal of A alone: far from A
    b = rng.standard_normal(A.shape[0])
    x, it = _pcg_factor(A, b, far, rtol=1e-12, max_iter=2)
    assert x is None and it == 2


def test_blas_threads_context_restores_and_pinned_keeps_the_configured_count():
    from lidarcat.bundle import _blas

    libs = _blas._controllers()
    if not libs:
        pytest.skip("threadpoolctl finds no BLAS")
    before = [lc.num_threads for lc in libs]
    with _blas.threads(3):
        assert all(lc.num_threads == 3 for lc in libs)
    assert [lc.num_threads for lc in libs] == before
    configured = _blas.configured()
    with _blas.threads(2):
        with _blas.pinned():
            assert all(lc.num_threads == 1 for lc in libs)
            assert _blas.big() == 2            # big kernels get what was configured
        assert _blas.configured() == 2
    assert _blas.configured() == configured and _blas.big() == configured


def test_factor_reuse_reaches_the_minimum_of_exact_steps(monkeypatch):
    """On a block large enough to reuse (threshold lowered), the same minimum as exact steps."""
    from lidarcat.synthetic.block import aerial_block
    from lidarcat.bundle import adjust, linear as linear_mod, solve as solve_mod

    block = aerial_block(100)
    exact = adjust(block.problem, precision="photos")
    monkeypatch.setattr(solve_mod, "FACTOR_REUSE_MIN_PHOTOS", 10)
    calls = []
    real = linear_mod._pcg_factor

    def counting(*args, **kwargs):
        out = real(*args, **kwargs)
        calls.append(out[0] is not None)
        return out

    monkeypatch.setattr(linear_mod, "_pcg_factor", counting)
    reused = adjust(block.problem, precision="photos")
    assert any(calls)                          # steps were solved with the previous factor
    assert reused.success and exact.success
    assert reused.vtpv == pytest.approx(exact.vtpv, rel=1e-10)
    np.testing.assert_allclose(reused.eo_params, exact.eo_params, atol=1e-6)
    np.testing.assert_allclose(reused.eo_cov, exact.eo_cov, rtol=1e-6, atol=1e-14)
