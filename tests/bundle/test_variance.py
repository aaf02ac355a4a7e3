"""Variance components (lidarcat.bundle.variance) on synthetic blocks with known noise."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle.redundancy import reliability
from lidarcat.bundle.solve import adjust
from lidarcat.bundle.variance import (GROUPS, estimate_components, group_labels, iterate_components,
                                      scaled_problem, snoop_with_components)
from lidarcat.synthetic.block import resimulated, synthetic_block


def _fit(pr):
    r = adjust(pr)
    return r, reliability(r).redundancy, None, r


@pytest.fixture(scope="module")
def block():
    """A 2 x 6 block; tie points measured to 0.002 mm, the targets (control points' images) to 0.005 mm,
    both declared 0.005 mm -- the tie sds 2.5 x too large, as matched tie points under a survey's one sd."""
    b = synthetic_block(2, 6, seed=3, noise=False)
    p = b.problem
    tie = group_labels(p)[:len(p.photo_index), 0] == GROUPS.index("tie")
    true_sd = np.where(tie, 0.002, 0.005)[:, None] * np.ones(2)
    noisy = resimulated(dataclasses.replace(p, sd_mm=true_sd), b.true_eo, b.true_points_m, np.random.default_rng(1))
    return dataclasses.replace(noisy, sd_mm=np.full_like(true_sd, 0.005)), tie


def test_group_labels_rows_in_reliability_order(block):
    p, tie = block
    lab = group_labels(p)
    n, k = len(p.photo_index), len(p.constraint_point_index)
    assert lab.shape == (n + k, 6)                            # no GNSS/INS constraints in this block
    assert np.all(lab[:n, 2:] == -1) and np.all(lab[n:, 3:] == -1)
    assert np.sum(lab[:n, 0] == GROUPS.index("target")) == np.sum(~tie) > 0
    assert np.all(lab[n:, :3] == GROUPS.index("control"))


def test_iteration_finds_the_tie_point_factor_and_sigma0_one(block):
    p, _ = block
    first = adjust(p)
    assert first.sigma0_sq < 0.4                               # the a priori tie sds are too large
    vc = iterate_components(p, _fit)
    assert vc.converged and vc.rounds <= 8
    f = vc.factors()
    # true factor (0.002 / 0.005)^2 = 0.16; sd of the estimate ~ 0.16 sqrt(2 / r_tie), r_tie ~ 660: 0.009
    assert f["tie"] == pytest.approx(0.16, abs=0.03)
    assert f["target"] == pytest.approx(1.0, abs=3 * np.sqrt(2 / 40))
    assert vc.payload.sigma0_sq == pytest.approx(1.0, abs=0.05)
    assert vc.payload.summary()["chi2_pass"]
    # the final adjustment used the reported factors: its tie sds are 0.005 sqrt(factor)
    res_p = vc.payload.problem
    lab = group_labels(res_p)[:len(res_p.photo_index), 0]
    np.testing.assert_allclose(res_p.sd_mm[lab == GROUPS.index("tie")], 0.005 * np.sqrt(f["tie"]))
    assert vc.summary()["groups"][0]["group"] == "tie"


def test_right_sds_give_factors_near_one():
    b = synthetic_block(2, 6, seed=5)                      # noise = the declared sds
    comps = estimate_components(*_fit(b.problem)[:2])
    for c in comps:
        assert c.estimated
        assert c.sigma0_sq == pytest.approx(1.0, abs=4 * np.sqrt(2 / c.redundancy)), c


def test_small_groups_are_not_estimated(block):
    p, _ = block
    comps = {c.group: c for c in estimate_components(*_fit(p)[:2], min_redundancy=100.0)}
    assert comps["tie"].estimated and comps["tie"].factor < 0.4
    assert not comps["control"].estimated and comps["control"].factor == 1.0
    assert comps["control"].redundancy < 100


def test_excluded_rows_leave_the_sums(block):
    p, _ = block
    res, red, _, _ = _fit(p)
    ex = np.zeros(len(red), bool)
    ex[:10] = True
    a = {c.group: c for c in estimate_components(res, red)}
    b = {c.group: c for c in estimate_components(res, red, exclude=ex)}
    assert b["tie"].n == a["tie"].n - 2 * np.sum(group_labels(p)[:10, 0] == GROUPS.index("tie"))
    assert b["tie"].redundancy < a["tie"].redundancy


def test_scaled_problem_scales_only_its_group(block):
    p, tie = block
    q = scaled_problem(p, {"tie": 0.25, "control": 4.0})
    np.testing.assert_allclose(q.sd_mm[tie], 0.5 * p.sd_mm[tie])
    np.testing.assert_allclose(q.sd_mm[~tie], p.sd_mm[~tie])
    np.testing.assert_allclose(q.constraint_sd_m, 2.0 * p.constraint_sd_m)
    assert scaled_problem(p, {}) is p


def _planted(p, tie, errors_mm, seed=0):
    """*p* with one ray of distinct tie points of >= 3 rays moved by *errors_mm* (random direction)."""
    rng = np.random.default_rng(seed)
    rays = np.bincount(p.point_index, minlength=p.n_points)
    cand = np.flatnonzero(tie & (rays[p.point_index] >= 3))
    picks, seen = [], set()
    for i in rng.permutation(cand):
        if int(p.point_index[i]) not in seen:
            seen.add(int(p.point_index[i]))
            picks.append(int(i))
        if len(picks) == len(errors_mm):
            break
    xy = np.array(p.xy_mm, float)
    ang = rng.uniform(0, 2 * np.pi, len(picks))
    xy[picks] += np.c_[np.cos(ang), np.sin(ang)] * np.asarray(errors_mm)[:, None]
    return dataclasses.replace(p, xy_mm=xy), picks


@pytest.mark.parametrize("mode", ["report", "remove"])
def test_blunders_named_and_the_factor_unbiased_in_every_mode(block, mode):
    """Gross tie observations: three of 10-15 true sds (4-6 declared sds: their w-tests pass at the a
    priori weights) and two of 250.  In both modes every one is named, and the tie factor is the true
    0.16 -- estimated from the adjustment without the named ones (kept in report mode, the large ones
    spread into their points' other rays and inflate the factor)."""
    p0, tie = block
    p, picks = _planted(p0, tie, [0.02, 0.025, 0.03, 0.5, 0.5])
    vc = snoop_with_components(p, mode=mode)
    sres = vc.payload
    assert vc.converged and sres.mode == mode
    assert vc.factors()["tie"] == pytest.approx(0.16, abs=0.03)
    named = {(b.photo, b.point) for b in sres.blunders if b.kind == "image"}
    planted = {(str(p.photo_ids[p.photo_index[i]]), str(p.point_ids[p.point_index[i]])) for i in picks}
    assert planted <= named
    assert len(named - planted) <= 2
    assert all(b.removed == (mode == "remove") for b in sres.blunders)
    if mode == "report":            # the adjustment of every observation, at the converged factors
        assert len(sres.result.problem.photo_index) == len(p.photo_index)
        np.testing.assert_allclose(sres.result.problem.sd_mm[tie], 0.005 * np.sqrt(vc.factors()["tie"]))
