"""The robust start (screening + graduated IRLS) on a block of automatic matches with gross errors of
the kind the NGI frames carry (8 mismatched two-ray points, 3.5-700 px, and one wrong ray of a
three-ray point), the GNSS/INS orientation (1 m / 0.01 deg) as the only datum; the datum defect of
too weak constraints; the screening on its own."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle import BundleProblem, adjust, check_datum
from lidarcat.bundle.reliability import snoop
from lidarcat.bundle.robust import loss_weight, robust_start
from lidarcat.bundle.screening import screen
from lidarcat.errors import DatumError
from lidarcat.synthetic.matches import matched_block

@pytest.fixture(scope="module")
def block():
    return matched_block()


def test_matched_block_is_what_the_test_says(block):
    p, _, planted = block
    assert 1300 <= len(p.photo_index) <= 1800
    assert len(planted) == 17 and len(p.constraint_point_index) == 0


def test_least_squares_alone_fails_and_says_where(block):
    p, _, _ = block
    r = adjust(p, precision="none")
    assert not r.success
    assert "point" in r.message and "photo" in r.message


def test_robust_start_names_exactly_the_planted_gross_observations(block):
    p, b, planted = block
    sr = snoop(p, mode="remove")
    res = sr.result
    assert res.success
    named = {(x.photo, x.point) for x in sr.blunders if x.removed}
    assert named == planted
    dev = np.abs(np.asarray(res.eo_params) - np.asarray(b.true_eo)) / res.eo_sd
    assert dev.max() < 3.0
    pairs = [x for x in sr.blunders if sum(y.point == x.point for y in sr.blunders) == 2]
    assert len(pairs) == 16 and all("cannot be told apart" in x.note for x in pairs)


def test_report_mode_with_gross_matches_removes_them_and_says_why(block):
    """The adjustment of every observation does not converge with 700-px matches in it: report mode
    returns the adjustment without them, each named, removed, and the note says why."""
    p, _, planted = block
    sr = snoop(p, mode="report")
    assert sr.result.success and len(sr.result.residuals_mm) == len(p.photo_index) - len(planted)
    assert {(x.photo, x.point) for x in sr.blunders} == planted and all(x.removed for x in sr.blunders)
    assert all("the adjustment with every observation does not converge (max_iterations) in report mode"
               in x.note for x in sr.blunders if x.found_by != "snooping")


def test_screening_flags_the_gross_rays_at_the_approximate_orientation(block):
    p, _, planted = block
    s = screen(p, np.asarray(p.initial_eo))
    flagged = {(p.photo_ids[p.photo_index[k]], p.point_ids[p.point_index[k]]) for k in np.flatnonzero(s.flagged)}
    assert flagged <= planted and len(flagged) >= 9        # the few-px mismatches are left to snooping
    rs = robust_start(p)
    kept_out = {(p.photo_ids[p.photo_index[k]], p.point_ids[p.point_index[k]]) for k in np.flatnonzero(~rs.keep)}
    assert kept_out <= planted


def test_loss_weights():
    t = np.array([0.0, 0.5, 1.0, 2.0])
    np.testing.assert_allclose(loss_weight("cauchy", t), [1.0, 0.8, 0.5, 0.2])
    np.testing.assert_allclose(loss_weight("huber", t), [1.0, 1.0, 1.0, 0.5])
    np.testing.assert_allclose(loss_weight("tukey", t), [1.0, 0.5625, 0.0, 0.0])
    with pytest.raises(ValueError, match="^`loss` must be one of cauchy, huber, tukey, got 'l1'$"):
        loss_weight("l1", t)


def _eo_only(p: BundleProblem, photos, sd) -> BundleProblem:
    photos = np.asarray(photos)
    return dataclasses.replace(p, eo_constraint_photo_index=photos,
                               eo_constraint_params=np.asarray(p.eo_constraint_params)[photos],
                               eo_constraint_sd=np.broadcast_to(sd, (len(photos), 6)))


def test_datum_from_gnss_ins_alone_and_its_defects(block):
    p, _, _ = block
    check_datum(p)                                             # positions and attitudes of 6 photos
    pos_only = np.r_[np.full(3, 1.0), np.full(3, np.inf)]
    check_datum(_eo_only(p, [0, 1, 3], pos_only))              # three positions off a line
    with pytest.raises(DatumError, match=r"^the block has no control points and its GNSS/INS constraints leave "
                                         r"a datum defect of 1 \(rank deficiency: the rotation about the line "
                                         r"through the 2 constrained photo positions \(0001, 0002; "):
        check_datum(_eo_only(p, [0, 1], pos_only))
    with pytest.raises(DatumError, match=r"a datum defect of 1 \(rank deficiency: the rotation about the line "
                                         r"through the 3 constrained photo positions \(0001, 0002, 0003"):
        check_datum(_eo_only(p, [0, 1, 2], pos_only))          # one strip: on a line
    check_datum(_eo_only(p, [0, 1, 2], np.r_[np.full(3, 1.0), np.full(3, 1e-4)]))   # with attitudes
    with pytest.raises(DatumError, match=r"a datum defect of 1: one constrained photo position \(0001\) fixes no "
                                         r"scale; constrain"):
        check_datum(_eo_only(p, [0], np.r_[np.full(3, 1.0), np.full(3, 1e-4)]))


def test_many_rejections_per_round_on_crowded_photos_name_what_one_at_a_time_names():
    """24 blunders of 25-40 sd on a block of ~250 observations per photo: snooping takes several per
    round (the largest test of each point, one per 50 observations of each photo) and puts back in
    one re-adjustment beyond 20 rejections; it names the same observations as one at a time, in
    far fewer adjustments."""
    from lidarcat.synthetic.block import synthetic_block

    b = synthetic_block(2, 3, seed=7, image_sd_mm=0.003, point_spacing_m=31.0)
    p = b.problem
    rng = np.random.default_rng(7)
    rays = np.bincount(p.point_index)
    pts = rng.choice(np.flatnonzero(rays >= 3), 24, replace=False)
    idx = np.array([int(rng.choice(np.flatnonzero(p.point_index == j))) for j in pts])
    xy = np.array(p.xy_mm)
    ang = rng.uniform(0, 2 * np.pi, len(idx))
    xy[idx] += (rng.uniform(25, 40, len(idx)) * p.sd_mm[idx, 0])[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    bad = dataclasses.replace(p, xy_mm=xy)
    planted = {(p.photo_ids[p.photo_index[i]], p.point_ids[p.point_index[i]]) for i in idx}
    one = snoop(bad, mode="remove", start="plain", multiple=False, backward=False)
    many = snoop(bad, mode="remove", start="plain")
    named_one = {(x.photo, x.point) for x in one.blunders if x.removed}
    named_many = {(x.photo, x.point) for x in many.blunders if x.removed}
    assert named_one == planted and named_many == planted
    assert one.n_adjustments >= 25 and many.n_adjustments <= 12
    assert len({x.iteration for x in many.blunders}) < len(many.blunders) / 2
