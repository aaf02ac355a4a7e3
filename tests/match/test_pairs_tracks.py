"""Pairs from footprints (exact pair sets on known layouts) and union-find tracks (hand-built cases)."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.match import HeightSurface, build_tracks, convex_overlap, distribute, exhaustive_pairs, footprint, \
    footprint_pairs
from lidarcat.match.pairs import polygon_area
from lidarcat.synthetic.textured import small_camera, strip_layout


def _footprints(n_strips: int, per_strip: int, forward: float = 0.6, side: float = 0.3):
    cam = small_camera(800, 600)
    eo = strip_layout(n_strips, per_strip, cam, 600.0, forward=forward, side=side)
    flat = HeightSurface(100.0)
    return cam, eo, [footprint(cam, e, flat) for e in eo]


def test_footprint_of_a_nadir_photo_is_its_frame_at_scale():
    cam, eo, fps = _footprints(1, 1)
    # 800 x 600 px of 10 um at c = 20 mm from 500 m: 200 m x 150 m (the distortion bends the corners a little)
    assert polygon_area(fps[0]) == pytest.approx(200.0 * 150.0, rel=0.01)
    assert polygon_area(fps[0]) > 0


def test_overlap_of_squares():
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2]], float)
    assert convex_overlap(sq, sq + [1, 0]) == pytest.approx(0.5)
    assert convex_overlap(sq, sq + [1, 1]) == pytest.approx(0.25)
    assert convex_overlap(sq, sq + [3, 0]) == 0.0
    assert convex_overlap(sq + 680_000.0, sq + [680_001.0, 680_000.0]) == pytest.approx(0.5)   # UTM size


def test_pairs_of_two_strips_exact():
    # strip 1: photos 0 1 2 west to east; strip 2 flown back: photo 3 beside 2, 4 beside 1, 5 beside 0
    _, _, fps = _footprints(2, 3)
    pairs, ov = footprint_pairs(fps, min_overlap=0.25)
    assert pairs.tolist() == [[0, 1], [0, 5], [1, 2], [1, 4], [2, 3], [3, 4], [4, 5]]
    forward = ov[[0, 2, 5, 6]]
    side = ov[[1, 3, 4]]
    assert forward == pytest.approx(0.6, abs=0.01) and side == pytest.approx(0.3, abs=0.01)
    # at 10 %: the photos two apart in a strip (20 %) and the diagonal neighbours (0.4 x 0.3 = 12 %) join
    pairs10, _ = footprint_pairs(fps, min_overlap=0.1)
    assert len(pairs10) == 7 + 2 * 1 + 4


def test_pairs_grow_linearly():
    counts = []
    for per_strip in (10, 20, 40):
        _, _, fps = _footprints(4, per_strip)
        pairs, _ = footprint_pairs(fps, min_overlap=0.25)
        counts.append(len(pairs))
        # forward neighbours 4 (n - 1) + side neighbours 3 n
        assert len(pairs) == 4 * (per_strip - 1) + 3 * per_strip
    assert len(exhaustive_pairs(160)) == 160 * 159 // 2


def test_no_overlap_gives_no_pair():
    _, _, fps = _footprints(1, 2, forward=-0.5)
    assert len(footprint_pairs(fps)[0]) == 0


def test_tracks_hand_built():
    # photos with 3, 3, 3, 2 keypoints
    pairs = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [0, 3]])
    matches = [
        (np.array([0, 1]), np.array([0, 2])),     # 0:0-1:0, 0:1-1:2
        (np.array([0, 2]), np.array([1, 0])),     # 1:0-2:1, 1:2-2:0
        (np.array([0]), np.array([1])),           # 0:0-2:1 (closes the triangle of track A)
        (np.array([2]), np.array([0])),           # 2:2-3:0 alone: track C
        (np.array([2, 1]), np.array([1, 1])),     # 0:2-3:1 and 0:1-3:1: 3:1 joins two points of photo 0
    ]
    t = build_tracks([3, 3, 3, 2], pairs, matches)
    # track A = {0:0, 1:0, 2:1}; {0:1, 1:2, 2:0, 3:1, 0:2} holds photo 0 twice -> dropped; C = {2:2, 3:0}
    assert t.n_inconsistent == 1
    assert t.track.tolist() == [0, 0, 0, 1, 1]
    assert t.photo.tolist() == [0, 1, 2, 2, 3]
    assert t.keypoint.tolist() == [0, 0, 1, 2, 0]
    assert t.rays().tolist() == [3, 2]


def test_distribution_keeps_the_best_per_cell():
    # four tracks of two rays, all in the top-left cell of a 2 x 2 grid of both photos; one per cell kept
    t = build_tracks([4, 4], np.array([[0, 1]]), [(np.arange(4), np.arange(4))])
    xy = np.tile([[10.0, 10.0]], (8, 1))
    score = np.array([1.0, 3.0, 2.0, 0.5])
    keep = distribute(t, xy, np.array([[100, 100], [100, 100]]), score, grid=(2, 2), per_cell=1)
    assert keep.tolist() == [False, True, False, False]
    assert distribute(t, xy, np.array([[100, 100], [100, 100]]), score, grid=(2, 2), per_cell=0).all()


def test_twin_keypoints_make_one_track():
    """Two keypoints at one position (SIFT's second orientation) matched to different photos join one
    track; without the positions they were two tracks through the same image point."""
    xy = [np.array([[10.0, 20.0], [10.0, 20.0], [50.0, 60.0]]), np.array([[11.0, 21.0], [70.0, 80.0]]),
          np.array([[12.0, 22.0], [90.0, 10.0]])]
    pairs = np.array([[0, 1], [0, 2], [1, 2]])
    matches = [(np.array([0, 2]), np.array([0, 1])), (np.array([1]), np.array([0])), (np.array([0]), np.array([0]))]
    apart = build_tracks([3, 2, 2], pairs, matches)
    assert apart.n_tracks == 1 and apart.n_inconsistent == 1     # kp 0 and 1 of photo 0 in one component: dropped
    apart = build_tracks([3, 2, 2], pairs[:2], matches[:2])
    assert apart.n_tracks == 3                                  # (0:0, 1:0), (0:2, 1:1), (0:1, 2:0)
    joined = build_tracks([3, 2, 2], pairs, matches, xy_px=xy)
    assert joined.n_tracks == 2 and joined.n_inconsistent == 0
    assert joined.track.tolist() == [0, 0, 0, 1, 1]
    assert joined.photo.tolist() == [0, 1, 2, 0, 1] and joined.keypoint.tolist() == [0, 0, 0, 2, 1]
