"""Feature detection (pyramid level, coordinates at level > 0), the cache, and the ECC refinement."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.match import FeatureOptions, detect, pyramid_level, refine_observations


def _texture(seed=0, shape=(240, 320)):
    import cv2

    rng = np.random.default_rng(seed)
    img = np.zeros(shape, np.float32)
    for k in (4, 8, 16, 32):
        img += cv2.resize(rng.standard_normal((shape[0] // k + 2, shape[1] // k + 2)).astype(np.float32),
                          shape[::-1], interpolation=cv2.INTER_CUBIC) * k
    img = (img - img.min()) / np.ptp(img) * 255
    return img.astype(np.uint8)


def test_level_one_keypoints_are_in_full_resolution_pixels():
    import cv2

    img = _texture(1, (480, 640))
    shifted = np.zeros_like(img)
    shifted[:, 20:] = img[:, :-20]            # the same photo moved 20 px right
    f0 = detect(img, FeatureOptions(level=1))
    f1 = detect(shifted, FeatureOptions(level=1))
    assert f0.level == 1 and len(f0) > 50
    m = cv2.BFMatcher(cv2.NORM_L2, crossCheck=True).match(f0.descriptors.astype(np.float32),
                                                          f1.descriptors.astype(np.float32))
    d = np.array([f1.xy_px[x.trainIdx] - f0.xy_px[x.queryIdx] for x in m])
    assert np.median(d[:, 0]) == pytest.approx(20.0, abs=0.3) and np.median(d[:, 1]) == pytest.approx(0.0, abs=0.3)


def test_pyramid_level_and_max_features():
    assert pyramid_level(17310, 11310, 4000) == 3
    f = detect(_texture(2, (480, 640)), FeatureOptions(max_features=100))
    assert len(f) == 100 and f.descriptors.dtype == np.uint8


def test_one_keypoint_per_extremum():
    """OpenCV's SIFT gives a keypoint per orientation peak at one position (about a fifth of them here);
    ``unique_positions`` keeps one (off by default: the tracks join the twins)."""
    img = _texture(4, (480, 640))
    every = detect(img, FeatureOptions())
    one = detect(img, FeatureOptions(unique_positions=True))
    n_positions = len(np.unique(every.xy_px, axis=0))
    assert n_positions < 0.95 * len(every)                   # the duplicates exist
    assert len(np.unique(one.xy_px, axis=0)) == len(one) == n_positions
    assert FeatureOptions().key() == FeatureOptions(unique_positions=False).key() \
        != FeatureOptions(unique_positions=True).key()
    assert json.loads(FeatureOptions().key()) == [8000, None, 4000, 0.0175, 16.0]    # the caches of before stay valid


def test_cache_detects_once(tmp_path):
    import cv2

    from lidarcat.stages._feature_cache import FeatureCache

    src = tmp_path / "a.png"
    cv2.imwrite(str(src), _texture(3))
    calls = []
    cache = FeatureCache(tmp_path / "cache")

    def load():
        calls.append(1)
        return cv2.imread(str(src), 0)

    a = cache.get("a", src, load)
    b = cache.get("a", src, load)
    assert len(calls) == 1 and np.array_equal(a.xy_px, b.xy_px) and np.array_equal(a.descriptors, b.descriptors)
    # without a folder the features spill to a temporary one: still detected once, removed on close
    spill = FeatureCache(None)
    c = spill.get("a", src, load)
    d = spill.get("a", src, load)
    folder = spill.folder
    assert len(calls) == 2 and np.array_equal(c.descriptors, d.descriptors) and len(list(folder.iterdir())) == 1
    spill.close()
    assert not folder.exists()


def test_refinement_recovers_a_subpixel_shift():
    import cv2

    img = _texture(4).astype(np.float32)
    m = np.float32([[1, 0, 0.4], [0, 1, -0.3]])            # photo 1 = photo 0 moved by (0.4, -0.3) px
    img1 = cv2.warpAffine(img, m, img.shape[::-1], flags=cv2.INTER_CUBIC)
    rng = np.random.default_rng(0)
    ref = rng.uniform(40, [280, 200], (20, 2))
    xy = np.vstack([ref, ref + [0.4, -0.3] + rng.normal(0, 0.01, (20, 2)) - [0.5, -0.5]])   # 0.5 px off
    track = np.r_[np.arange(20), np.arange(20)]
    photo = np.r_[np.zeros(20, int), np.ones(20, int)]
    out, moved = refine_observations(track, photo, xy, lambda p: [img, img1][p])
    assert not moved[:20].any() and moved[20:].mean() >= 0.9
    err = np.hypot(*(out[20:][moved[20:]] - (ref[moved[20:]] + [0.4, -0.3])).T)
    # 0.71 px off before; the parabola through the correlation peak keeps some pixel-locking bias
    assert np.max(err) < 0.4 and np.median(err) < 0.25
