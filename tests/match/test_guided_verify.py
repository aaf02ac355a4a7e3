"""Guided prediction within its ellipse on synthetic truth; verification rejecting planted wrong matches."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.match import HeightSurface, guided_match, ideal_pixels, predict, verify_pair
from lidarcat.match.guided import CHI2_2_999, Prediction
from lidarcat.match.rays import project_to_pixel
from lidarcat.match.verify import local_consistency, sampson_px
from lidarcat.synthetic.textured import TexturedGround, small_camera, strip_layout, true_points


@pytest.fixture(scope="module")
def scene():
    cam = small_camera(400, 300)
    eo = strip_layout(2, 2, cam, 600.0)
    # a terrain only (no texture needed): the relief of 8 m is what the mean height does not know
    ground = TexturedGround(0.0, 0.0, 1.0, np.zeros((2, 2), np.float32), h0_m=100.0, relief_m=8.0)
    return cam, eo, ground


def test_prediction_holds_the_truth_in_its_ellipse(scene):
    cam, eo, ground = scene
    rng = np.random.default_rng(3)
    sd_p, sd_a = 2.0, 0.5
    inside, total, radius = 0, 0, []
    for trial in range(20):
        approx = eo + np.column_stack([rng.normal(0, sd_p, (4, 3)), np.deg2rad(rng.normal(0, sd_a, (4, 3)))])
        a_px = rng.uniform([0, 0], [399, 299], (300, 2))
        xyz = true_points(ground, cam, eo[0], a_px)
        b_true, front = project_to_pixel(cam, eo[1], xyz)
        surf = HeightSurface(100.0, sd_m=8.0 / np.sqrt(2))      # the sd of a sine of amplitude 8 m
        pred = predict(cam, approx[0], a_px, cam, approx[1], surf, sd_position_m=sd_p, sd_angle_deg=sd_a)
        ok = front & cam.contains(b_true)
        inside += int(pred.inside(b_true)[ok].sum())
        total += int(ok.sum())
        radius.append(np.sqrt(np.linalg.eigvalsh(pred.cov_px2).max(axis=1) * CHI2_2_999).mean())
    # 99.9 % ellipses; first-order propagation of 13 independent errors: at least 99 % hold the truth
    assert inside / total >= 0.99
    # and the search is far narrower than the photo (about 60 px of 400)
    assert 20 < np.mean(radius) < 120


def test_guided_match_finds_planted_partners_only_in_the_ellipse():
    rng = np.random.default_rng(0)
    n = 50
    grid = np.stack(np.meshgrid(np.arange(10) * 100.0, np.arange(5) * 100.0), -1).reshape(-1, 2) + 50.0
    pred = Prediction(grid, np.tile(np.diag([25.0, 4.0]), (n, 1, 1)))
    desc_a = rng.integers(0, 256, (n, 128)).astype(np.uint8)
    # B: the true partner 3 px off along x (inside), a twin descriptor 30 px off (outside the ellipse)
    xy_b = np.vstack([pred.xy_px + [3.0, 0.0], pred.xy_px + [0.0, 30.0]])
    noise = rng.integers(-2, 3, (n, 128))
    desc_b = np.vstack([np.clip(desc_a + noise, 0, 255), desc_a]).astype(np.uint8)
    m, n_cand = guided_match(pred, desc_a, xy_b, desc_b)
    assert n_cand == n                       # the twins were never candidates
    assert m.i.tolist() == list(range(n)) and m.j.tolist() == list(range(n))


def _pair(rng, n_true=200, noise_px=0.3):
    cam = small_camera(800, 600)
    eo = strip_layout(1, 2, cam, 600.0)
    a = rng.uniform([0, 0], [799, 599], (n_true, 2))
    ground = TexturedGround(0.0, 0.0, 1.0, np.zeros((2, 2), np.float32), h0_m=100.0, relief_m=8.0)
    b, _ = project_to_pixel(cam, eo[1], true_points(ground, cam, eo[0], a))
    keep = cam.contains(b)
    return cam, eo, a[keep], b[keep] + rng.normal(0, noise_px, (int(keep.sum()), 2))


def test_verification_rejects_planted_wrong_matches():
    rng = np.random.default_rng(1)
    cam, eo, a, b = _pair(rng)
    n_wrong = 40
    wa = rng.uniform([0, 0], [799, 599], (n_wrong, 2))
    wb = rng.uniform([0, 0], [799, 599], (n_wrong, 2))
    ia, ib = ideal_pixels(cam, np.vstack([a, wa])), ideal_pixels(cam, np.vstack([b, wb]))
    v = verify_pair(ia, ib, threshold_px=1.5)
    assert v.accepted
    good, bad = v.inlier[:len(a)], v.inlier[len(a):]
    assert good.mean() >= 0.99
    # every planted match farther than 3 px from its epipolar line (under the estimated F) is rejected,
    # and the estimated F is the true geometry: the true matches lie within 1.5 px of it
    far = sampson_px(v.fundamental, ia[len(a):], ib[len(a):]) > 3.0
    assert far.sum() >= 35 and not bad[far].any()
    assert np.percentile(sampson_px(v.fundamental, ia[:len(a)], ib[:len(a)]), 99) < 1.5


def test_too_few_matches_reject_the_pair():
    rng = np.random.default_rng(2)
    cam, eo, a, b = _pair(rng, n_true=12)
    v = verify_pair(ideal_pixels(cam, a), ideal_pixels(cam, b), min_inliers=15)
    assert not v.accepted and "fewer than 15" in v.reason and not v.inlier.any()


def test_local_consistency_rejects_a_match_shifted_along_its_epipolar_line():
    rng = np.random.default_rng(4)
    a = rng.uniform(0, 800, (300, 2))
    shift = np.column_stack([200 + 0.01 * a[:, 0], 5 + 0.002 * a[:, 1]]) + rng.normal(0, 0.3, (300, 2))
    planted = [10, 50, 200]
    shift[planted, 0] += [12.0, -25.0, 8.0]          # along the base (x): the epipolar test cannot see it
    ok = local_consistency(a, shift, min_px=3.0)
    assert not ok[planted].any()
    assert ok.sum() >= 300 - len(planted) - 3


def test_degenerate_matches_reject_the_pair_without_an_opencv_error():
    a = np.column_stack([np.linspace(0, 500, 40), np.full(40, 100.0)])     # all on one line
    v = verify_pair(a, a + [10.0, 0.0])
    assert not v.accepted and not v.inlier.any()
