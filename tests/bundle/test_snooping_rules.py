"""Two rules of data snooping for automatic matches (lidarcat.bundle.reliability).

1. A track that joined two ground points: snooping removes the whole track.

Four rays of one tie point, two of them (on photos of the other strip) moved to the images of a
second ground point 2 m away: each pair is consistent with itself, the split 2 against 2 has no
majority.  Snooping rejects one ray, then its partner on the same side; the pair left passes every
test, whichever side it is.  The rule of :data:`lidarcat.bundle.reliability.HALF_RAYS_RULE`: a free
point that lost as many rays as it has left loses the rest too, named with a note.

2. The weighted GNSS/INS orientations as the only datum (no control point): a photo's GNSS/INS group
whose test rejects is named but never removed (:data:`lidarcat.bundle.reliability.EO_DATUM_NOTE`):
without it the photo's position and attitude would rest on the tie points alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle import reliability as rel_mod
from lidarcat.bundle.reliability import snoop
from lidarcat.geometry.collinearity import project
from lidarcat.synthetic.block import synthetic_block
from lidarcat.synthetic.matches import matched_block


@pytest.fixture(scope="module")
def merged():
    """(problem, point id, photos of the moved rays): a 2 x 6 block, one four-ray tie point (two rays
    per strip) whose rays on the second strip see a point 2 m east, 1 m north of the first."""
    b = synthetic_block(2, 6, seed=3)
    p = b.problem
    role = np.asarray(p.point_role)
    rays = np.bincount(p.point_index, minlength=p.n_points)
    strip = np.asarray(p.photo_index) // 6
    n2 = np.bincount(p.point_index, weights=strip, minlength=p.n_points)     # rays on the second strip
    j = int(np.flatnonzero((role == "tie") & (rays == 4) & (n2 == 2))[0])
    k = np.flatnonzero((p.point_index == j) & (strip == 1))
    xyz = np.asarray(b.true_points_m)[j] + np.array([2.0, 1.0, 0.0])
    eo = np.asarray(b.true_eo)[p.photo_index[k]]
    xy_true, _ = project(eo, np.repeat(xyz[None], len(k), 0), np.asarray(p.focal_length_mm)[p.photo_index[k]])
    noise = np.asarray(p.xy_mm)[k] - project(eo, np.repeat(np.asarray(b.true_points_m)[j][None], len(k), 0),
                                             np.asarray(p.focal_length_mm)[p.photo_index[k]])[0]
    xy = np.array(p.xy_mm, float)
    xy[k] = xy_true + noise
    return (dataclasses.replace(p, xy_mm=xy), str(p.point_ids[j]),
            {str(x) for x in p.photo_ids[p.photo_index[k]]})


def _named(sres, point):
    return {b.photo: b for b in sres.blunders if b.kind == "image" and b.point == point}


def test_a_track_of_two_ground_points_is_removed_whole(merged):
    p, point, moved = merged
    sres = snoop(p, mode="remove")
    named = _named(sres, point)
    assert len(named) == 4 and all(b.removed for b in named.values())
    assert sum("lost 2 of its 4 rays" in b.note for b in named.values()) == 3   # the trigger and the two others
    assert point not in set(sres.result.point_ids.tolist())
    assert len(sres.blunders) <= 6                        # no good observation of the block pays for it


def test_without_the_rule_a_self_consistent_pair_stays(merged, monkeypatch):
    """What the rule is for: snooping alone names two rays, one pair of the two ground points stays."""
    p, point, _ = merged
    monkeypatch.setattr(rel_mod, "HALF_RAYS_RULE", False)
    named = _named(snoop(p, mode="remove"), point)
    assert len(named) == 2


def test_a_gnss_blunder_is_named_not_removed_when_the_orientations_are_the_datum():
    """The matched block (17 gross matches, GNSS/INS the only datum) with photo 2's X0 observed 10 m
    (10 sd) off: its group is named, with the note, and stays in the adjustment; the 17 gross matches
    are removed as before."""
    p, truth, planted = matched_block()
    assert rel_mod.eo_is_datum(p)
    obs = np.array(p.eo_constraint_params, float)
    i = int(np.flatnonzero(np.asarray(p.photo_ids) == "0002")[0])
    obs[i, 0] += 10.0
    sres = snoop(dataclasses.replace(p, eo_constraint_params=obs), mode="remove")
    eo = [b for b in sres.blunders if b.kind == "eo"]
    assert [(b.photo, b.removed, b.note) for b in eo] == [("0002", False, rel_mod.EO_DATUM_NOTE)]
    assert eo[0].estimated_error[0] > 5.0
    assert len(sres.result.problem.eo_constraint_photo_index) == p.n_photos
    assert {(b.photo, b.point) for b in sres.blunders if b.kind == "image"} == planted


@pytest.mark.parametrize("robust", ["danish", "huber"])
def test_robust_reweighting_keeps_the_datum_gnss_groups(robust):
    """The same block through the robust re-weighting first (``--robust``): the Danish weight took photo 2's
    GNSS/INS group down to 1.5e-2 and removed it (the photo's datum gone, the gross matches found differed);
    held, it is named as snooping names it and stays, and the gross matches found are those of the same
    method on the block without the GNSS blunder: the 17 planted, with either method (Danish listed 15
    before: the partner rays of two two-ray points went with their cut rays without a blunder record)."""
    p, _, planted = matched_block()
    obs = np.array(p.eo_constraint_params, float)
    i = int(np.flatnonzero(np.asarray(p.photo_ids) == "0002")[0])
    obs[i, 0] += 10.0
    sres = snoop(dataclasses.replace(p, eo_constraint_params=obs), mode="remove", robust=robust)
    eo = [b for b in sres.blunders if b.kind == "eo"]
    assert [(b.photo, b.removed, b.note) for b in eo] == [("0002", False, rel_mod.EO_DATUM_NOTE)]
    assert len(sres.result.problem.eo_constraint_photo_index) == p.n_photos
    found = {(b.photo, b.point) for b in sres.blunders if b.kind == "image"}
    clean = {(b.photo, b.point) for b in snoop(p, mode="remove", robust=robust).blunders if b.kind == "image"}
    assert found == clean == planted


@pytest.mark.parametrize("robust", ["none", "danish", "huber"])
def test_every_observation_that_left_the_adjustment_is_a_listed_blunder(robust):
    """blunders.csv names every image observation the final adjustment lacks, however it went (screening,
    the robust re-weighting, snooping, or with the other ray of its point): on the matched block the
    removed set is the 17 planted gross matches.  Danish listed 15: the two rays on photo 0003 of points
    P00063 and P00064 went with their partners on photo 0002 (weight factors 3.3e-3 and 1e-4) and were
    named only in those partners' notes."""
    p, _, planted = matched_block()
    sres = snoop(p, mode="remove", robust=robust)
    r = sres.result.problem
    left = set(zip(r.photo_ids[r.photo_index].tolist(), r.point_ids[r.point_index].tolist()))
    every = set(zip(p.photo_ids[p.photo_index].tolist(), p.point_ids[p.point_index].tolist()))
    listed = [(b.photo, b.point) for b in sres.blunders if b.kind == "image" and b.removed]
    assert len(listed) == len(set(listed))                  # each once
    assert set(listed) == every - left == planted
