"""match_block on planted features: a blank photo and an isolated photo are reported skips, never errors."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.match import Features, FeatureOptions, HeightSurface, MatchError, detect, match_block
from lidarcat.match.rays import project_to_pixel
from lidarcat.synthetic.textured import small_camera, strip_layout


def _block(n_photos=3, n_points=1500, seed=0):
    """Photos of a flat ground at 100 m; each ground point a random descriptor seen by every photo it projects in."""
    rng = np.random.default_rng(seed)
    cam = small_camera(400, 300)
    eo = strip_layout(1, n_photos, cam, 600.0)
    lo, hi = eo[:, :2].min(axis=0) - 150, eo[:, :2].max(axis=0) + 150
    xyz = np.column_stack([rng.uniform(lo, hi, (n_points, 2)), np.full(n_points, 100.0)])
    desc = rng.integers(0, 256, (n_points, 128))
    feats = []
    _block.seen = []            # the ground point of each keypoint, per photo (for the tests that plant errors)
    for p in range(n_photos):
        px, front = project_to_pixel(cam, eo[p], xyz)
        ok = np.flatnonzero(front & cam.contains(px))
        _block.seen.append(ok)
        d = np.clip(desc[ok] + rng.integers(-3, 4, (len(ok), 128)), 0, 255).astype(np.uint8)
        feats.append(Features(px[ok] + rng.normal(0, 0.2, (len(ok), 2)), d, np.ones(len(ok), np.float32),
                              np.full(len(ok), 4.0, np.float32), 0))
    return cam, eo, feats


def _empty() -> Features:
    return Features(np.empty((0, 2)), np.empty((0, 128), np.uint8), np.empty(0, np.float32),
                    np.empty(0, np.float32), 0)


def test_planted_block_is_matched_exactly():
    cam, eo, feats = _block()
    res = match_block([cam] * 3, list(eo), lambda i: feats[i], surface=HeightSurface(100.0, sd_m=1.0))
    assert len(res.pairs) == 3 and all(r.n_inliers > 15 for r in res.pairs)
    # every observation of a track is the same ground point: same random descriptor -> same track
    assert res.tracks.n_tracks > 100 and res.tracks.n_inconsistent == 0


def test_a_blank_photo_is_a_reported_skip():
    cam, eo, feats = _block()
    feats[1] = _empty()
    res = match_block([cam] * 3, list(eo), lambda i: feats[i], surface=HeightSurface(100.0, sd_m=1.0))
    by_pair = {(r.a, r.b): r for r in res.pairs}
    assert by_pair[(0, 1)].n_inliers == 0 and by_pair[(0, 1)].reason == "no matches"
    assert by_pair[(1, 2)].n_inliers == 0 and by_pair[(1, 2)].reason == "no matches"
    assert by_pair[(0, 2)].n_inliers > 15
    assert not (res.tracks.photo == 1).any()


def test_all_blank_photos_are_one_located_error():
    cam, eo, _ = _block()
    with pytest.raises(MatchError, match=r"^no pair of the 3 overlapping pairs has verified matches "
                                         r"\(first: photos '0'-'1': no matches\)$"):
        match_block([cam] * 3, list(eo), lambda i: _empty(), surface=HeightSurface(100.0, sd_m=1.0))


def test_a_blank_image_has_no_features():
    f = detect(np.zeros((300, 400), np.uint8), FeatureOptions())
    assert len(f) == 0 and f.descriptors.shape == (0, 128) and f.xy_px.shape == (0, 2)


def test_no_overlap_at_all_is_refused_before_any_feature_is_read():
    cam, eo, feats = _block()
    far = eo.copy()
    far[:, 0] += 5000.0 * np.arange(3)
    read = []

    def get(i):
        read.append(i)
        return feats[i]

    with pytest.raises(MatchError, match=r"^no two of the 3 photos overlap by 10% or more"):
        match_block([cam] * 3, list(far), get, surface=HeightSurface(100.0, sd_m=1.0))
    assert read == []


def test_an_isolated_photo_is_a_reported_skip():
    cam, eo, feats = _block(4)
    eo = eo.copy()
    eo[3, 0] += 5000.0                          # photo 3 flies 5 km away: its footprint meets no other
    res = match_block([cam] * 4, list(eo), lambda i: feats[i], surface=HeightSurface(100.0, sd_m=1.0))
    assert res.unpaired == (3,)
    assert {(r.a, r.b) for r in res.pairs} == {(0, 1), (0, 2), (1, 2)}
    assert not (res.tracks.photo == 3).any()


def test_threads_detect_each_photo_once_and_give_the_same_tie_points():
    import threading
    import time

    cam, eo, feats = _block(4)
    calls = []
    lock = threading.Lock()

    def get(i):
        with lock:
            calls.append(i)
        time.sleep(0.01)            # a slow detection: the other thread asks for the same photo meanwhile
        return feats[i]

    one = match_block([cam] * 4, list(eo), lambda i: feats[i], surface=HeightSurface(100.0, sd_m=1.0))
    two = match_block([cam] * 4, list(eo), get, surface=HeightSurface(100.0, sd_m=1.0), workers=2, lru=8)
    assert sorted(calls) == [0, 1, 2, 3]
    assert np.array_equal(one.tracks.track, two.tracks.track) and np.array_equal(one.xy_px, two.xy_px)


def test_a_track_whose_rays_do_not_meet_is_dropped_when_the_orientations_are_good():
    from lidarcat.match import MatchOptions

    cam, eo, feats = _block(3, n_points=1500, seed=2)
    # photo 2 sees five points 30 px further along the strip: each pair's epipolar line (along the
    # strip) holds them, so the pairs (0, 2) and (1, 2) verify them; the three rays meet nowhere
    f2 = feats[2]
    xy2 = f2.xy_px.copy()
    desc2 = f2.descriptors
    # five keypoints of photo 2 whose ground points photos 0 and 1 see too, away from the frame edge
    seen = _block.seen
    in_all = np.isin(seen[2], seen[0]) & np.isin(seen[2], seen[1])
    inner = (xy2[:, 0] > 20) & (xy2[:, 0] < 380) & (xy2[:, 1] > 20) & (xy2[:, 1] < 280)
    common = np.flatnonzero(in_all & inner)[:5]
    xy2[common, 0] += 30.0
    feats[2] = Features(xy2, desc2, f2.response, f2.size_px, 0)
    surface = HeightSurface(100.0, sd_m=50.0)           # ellipses long along the base: the shifted rays are found
    good = MatchOptions(sd_position_m=0.1, sd_angle_deg=0.01, max_local_px=0.0, per_cell=0)
    loose = MatchOptions(sd_position_m=2.0, sd_angle_deg=0.5, max_local_px=0.0, per_cell=0)
    r_good = match_block([cam] * 3, list(eo), lambda i: feats[i], surface=surface, options=good)
    r_loose = match_block([cam] * 3, list(eo), lambda i: feats[i], surface=surface, options=loose)

    def three_ray_tracks_with_a_shifted_ray(res):
        t = res.tracks
        hit = np.unique(t.track[(t.photo == 2) & np.isin(t.keypoint, common)])
        return int((t.rays()[hit] >= 3).sum())

    n_shifted = three_ray_tracks_with_a_shifted_ray(r_loose)
    assert n_shifted >= 3 and r_loose.n_ray_inconsistent == 0              # 0.5 deg allows some 70 px
    # 0.01 deg / 0.1 m: about 7 px allowed; three rays in one plane (a strip) take a 30-px shift as a
    # height and leave about 10 px
    assert r_good.n_ray_inconsistent == n_shifted
    assert three_ray_tracks_with_a_shifted_ray(r_good) == 0
    assert r_good.tracks.n_tracks == r_loose.tracks.n_tracks - n_shifted


def test_serial_threads_and_dask_processes_give_the_same_tie_points():
    """The photo and pair tasks on the runner of lidar.jobs: the features callable and the shared data
    go to the worker processes, only positions and matches come back; the tracks are the same."""
    from lidarcat.lidar.jobs import dask_client, map_tasks
    from lidarcat.match.block import serial_map

    cam, eo, feats = _block(4)
    surface = HeightSurface(100.0, sd_m=1.0)
    one = match_block([cam] * 4, list(eo), lambda i: feats[i], surface=surface, mapper=serial_map)
    for sched in ("threads", "processes"):
        steps = []
        with dask_client(2, sched) as client:           # one cluster of 2 worker processes for both runs

            def mapper(f, s, items, p):
                return map_tasks(f, s, items, workers=2, scheduler=sched, client=client, progress=p)

            other = match_block([cam] * 4, list(eo), lambda i: feats[i], surface=surface, mapper=mapper,
                                progress=lambda step, d, t: steps.append((step, d, t)))
            # a photo that cannot be read in a worker: its located error, unchanged, in this process
            with pytest.raises(SurveyError, match=r"^photos.csv:3: field 'image': photo '2': cannot decode$"):
                match_block([cam] * 4, list(eo), _unreadable(feats, 2), surface=surface, mapper=mapper)
        assert np.array_equal(one.tracks.track, other.tracks.track) and np.array_equal(one.xy_px, other.xy_px)
        assert np.array_equal(one.tracks.keypoint, other.tracks.keypoint)
        assert [(r.a, r.b, r.n_inliers) for r in one.pairs] == [(r.a, r.b, r.n_inliers) for r in other.pairs]
        assert other.n_keypoints == tuple(len(f) for f in feats)
        assert steps[-1] == ("pairs", len(one.pairs), len(one.pairs)) and ("features", 4, 4) in steps


def _unreadable(feats, bad):
    def get(i):
        if i == bad:
            raise SurveyError("photos.csv:3: field 'image': photo '2': cannot decode")
        return feats[i]
    return get
