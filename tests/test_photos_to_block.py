"""From photos to an oriented block (issue 28, the first acceptance line), end to end through the CLI.

A realistic synthetic block (:func:`lidarcat.synthetic.aerial.aerial_survey`: two strips, 60 %/30 %
overlap, rendered photos, approximate orientation 2 m / 0.5 deg off, 4 GPS points, LiDAR tiles, no tie
point) goes through ``lidarcat match`` and ``lidarcat adjust --eo-constraints --snooping remove``
with no hand-made observation file. The truth is used only to score (the scoring is
``benchmarks/bench_photos_to_block.py``'s, which prints the full table over seeds).

Fast: six 480 x 360 photos, one seed -- the facts that hold at that size (kept tie observations
within 1 px, none more than 3 px off unnamed, residual RMS, every orientation within 3 sd), the
a priori sd of every matched observation (``sd_x_mm, sd_y_mm``), the variance components that
make sigma0 1 and the chi-square test pass, and gross matches planted into the matched table
(mismatched two-ray points, a wrong ray of a multi-ray point, 3.5-50 px) named by the default
snooping while the good observations are kept.
Slow: the acceptance block itself, 24 photos of 1000 x 750 px, on six seeds: the per-seed facts, and
"every orientation within 3 sd" with "sds honest" as statistics pooled over the seeds (the count of
|z| > 3 against its binomial bound, the pooled empirical / predicted ratio in 0.8-1.25; the reasoning
is in that test's docstring); and the planted gross matches on it.
"""

from __future__ import annotations

import json
import shutil
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import ROOT
from lidarcat.cli.main import cli
from lidarcat.synthetic.aerial import aerial_survey

sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_photos_to_block as bench  # noqa: E402


def _photos_to_block(tmp_path, seed, per_strip, size):
    s = aerial_survey(tmp_path / "survey", n_strips=2, photos_per_strip=per_strip, forward_overlap=0.6,
                      side_overlap=0.3, image_size_px=size, approx_position_sd_m=2.0, approx_angle_sd_deg=0.5,
                      n_gps_points=4, seed=seed)
    folder = tmp_path / "survey"
    ip = (folder / "image_points.csv").read_text()
    assert ",tp" not in ip  # no tie point before matching: only the GPS targets
    r = CliRunner().invoke(cli, ["match", str(folder), "-o", str(tmp_path / "match")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["adjust", str(folder), "--eo-constraints", "--snooping", "remove",
                                 "--no-variance-components", "-o", str(tmp_path / "adjust")])  # the sds as written
    assert r.exit_code in (0, 3), r.output
    return s, bench.score_block(s, folder, tmp_path / "adjust")


def _pixel_mm(folder):
    return float(next(ln.split("=")[1] for ln in (folder / "camera.toml").read_text().splitlines()
                      if ln.startswith("pixel_size_x_mm")))


@pytest.fixture(scope="module")
def six(tmp_path_factory):
    """The six-photo block rendered and matched once (480 x 360 px, seed 1); tests copy its folder."""
    tmp = tmp_path_factory.mktemp("six")
    s = aerial_survey(tmp / "survey", n_strips=2, photos_per_strip=3, forward_overlap=0.6, side_overlap=0.3,
                      image_size_px=(480, 360), approx_position_sd_m=2.0, approx_angle_sd_deg=0.5,
                      n_gps_points=4, seed=1)
    r = CliRunner().invoke(cli, ["match", str(tmp / "survey"), "-o", str(tmp / "match")])
    assert r.exit_code == 0, r.output
    return s, tmp / "survey"


def _copy(six, tmp_path):
    s, folder = six
    shutil.copytree(folder, tmp_path / "survey")
    return s, tmp_path / "survey"


def test_match_writes_the_precision_of_every_tie_observation(six):
    """sd_x_mm, sd_y_mm of every matched row: positive, about the size of the truth errors (the
    refinement's precision calibrated on rendered truth); the GPS targets keep the survey's sd."""
    s, folder = six
    rows = bench._rows(folder / "image_points.csv")
    tie = [r for r in rows if r["point"].startswith("tp")]
    assert all(r["sd_x_mm"] == "" for r in rows if not r["point"].startswith("tp"))
    sd = np.array([[float(r["sd_x_mm"]), float(r["sd_y_mm"])] for r in tie]) / _pixel_mm(folder)
    assert np.all(sd > 0)
    assert 0.03 <= np.median(sd) <= 0.2                        # px: refined matches, not the 0.3 px of a target
    photo = np.array([r["photo"] for r in tie])
    point = np.array([r["point"] for r in tie])
    err = bench.score_tracks(s, photo, point, np.array([[float(r["col_px"]), float(r["row_px"])] for r in tie]))
    ok = err < 3
    # per axis: the rms truth error over the rms sd written (1 = calibrated), measured 1.08
    ratio = np.sqrt(np.mean(err[ok] ** 2) / 2) / np.sqrt(np.mean(sd[ok] ** 2))
    assert 0.7 <= ratio <= 1.5


def test_variance_components_make_sigma0_one(six, tmp_path):
    """--variance-components: one factor per group; the tie points' is below 1 (their sds are the
    matcher's, conservative), sigma0 is 1 and the chi-square test passes (exit 0)."""
    s, folder = _copy(six, tmp_path)
    r = CliRunner().invoke(cli, ["adjust", str(folder), "--eo-constraints", "--snooping", "remove",
                                 "--variance-components", "-o", str(tmp_path / "adjust")])
    assert r.exit_code == 0, r.output
    assert "Variance components" in r.output
    summary = json.loads((tmp_path / "adjust" / "summary.json").read_text())
    vc = {g["group"]: g for g in summary["variance_components"]["groups"]}
    assert summary["variance_components"]["converged"]
    assert set(vc) == {"tie", "target", "control", "gnss", "imu"}
    assert vc["tie"]["estimated"] and 0.5 < vc["tie"]["sd_scale"] < 1.2
    assert not vc["control"]["estimated"]                      # 4 GPS points: too little redundancy
    assert abs(summary["sigma0_sq"] - 1.0) < 0.05 and summary["chi2_pass"]
    sc = bench.score_block(s, folder, tmp_path / "adjust")
    _assert_acceptance(sc)


def _assert_planted_named(s, folder, adjust_dir, planted):
    """Every observation more than 3 px off (the planted ones among them) named in blunders.csv; at most
    1 % of the good ones (within 1 px of truth) named."""
    tie = [r for r in bench._rows(folder / "image_points.csv") if r["point"].startswith("tp")]
    photo = np.array([r["photo"] for r in tie])
    point = np.array([r["point"] for r in tie])
    err = bench.score_tracks(s, photo, point, np.array([[float(r["col_px"]), float(r["row_px"])] for r in tie]))
    named = {(r["photo"], r["point"]) for r in bench._rows(adjust_dir / "blunders.csv") if r["kind"] == "image"}
    is_named = np.array([(a, b) in named for a, b in zip(photo, point)])
    off = err > 3.0
    assert {(a, b) for a, b in zip(photo[off], point[off])} >= planted   # the scoring sees the planted ones
    assert np.all(is_named[off]), [(a, b, round(float(e), 1)) for a, b, e in
                                   zip(photo[off & ~is_named], point[off & ~is_named], err[off & ~is_named])]
    good = err <= 1.0
    assert np.sum(is_named & good) <= 0.01 * np.sum(good)


def test_planted_gross_matches_are_named(six, tmp_path):
    """Mismatched two-ray points and wrong rays of multi-ray points (3.5-50 px) planted into the matched
    image_points.csv; `lidarcat adjust --eo-constraints` with the default snooping (report) names every
    observation more than 3 px off and at most 1 % of the good ones."""
    s, folder = _copy(six, tmp_path)
    planted = bench.plant_gross(s, folder, seed=3)
    assert len(planted) == 2 * len(bench.MISMATCH_PX) + len(bench.WRONG_RAY_PX)
    r = CliRunner().invoke(cli, ["adjust", str(folder), "--eo-constraints", "-o", str(tmp_path / "adjust")])
    assert r.exit_code in (0, 3), r.output
    _assert_planted_named(s, folder, tmp_path / "adjust", planted)


def _assert_acceptance(sc, max_z: float | None = 3.0):
    assert sc["status"] == "converged"
    assert sc["kept"] >= 0.95 * sc["observations"]             # snooping removes a few, not the block
    assert sc["kept_within1"] >= 0.99                          # >= 99 % of the kept within 1 px of truth
    assert sc["kept_over3_unnamed"] == 0                       # every kept one > 3 px off named
    assert sc["rms_px"] <= 0.5                                 # image residual RMS
    if max_z is not None:                                      # every orientation within 3 sd of truth
        assert sc["max_z"] <= max_z


def test_six_photos_matched_and_adjusted_within_truth(six, tmp_path):
    s, folder = _copy(six, tmp_path)
    r = CliRunner().invoke(cli, ["adjust", str(folder), "--eo-constraints", "--snooping", "remove",
                                 "-o", str(tmp_path / "adjust")])
    assert r.exit_code in (0, 3), r.output
    sc = bench.score_block(s, folder, tmp_path / "adjust")
    assert sc["photos"] == 6 and sc["tie_points"] >= 100
    _assert_acceptance(sc)
    summary = json.loads((tmp_path / "adjust" / "summary.json").read_text())
    assert summary["eo_constraints"] is True and summary["control_set"] == "gps"


def test_scoring_counts_a_two_ray_mismatch_on_both_rays():
    """The score's reference rule: a mismatched two-ray point has no correct observation."""
    class Flat:   # ground z = 0 seen from nadir photos at x-offsets: pixel = ground (shifted per photo)
        off = {"a": 0.0, "b": 10.0, "c": 20.0}

        def ground_point(self, photo, colrow):
            c = np.asarray(colrow, float)
            return np.c_[c[:, 0] + self.off[photo], c[:, 1], np.zeros(len(c))]

        def project(self, photo, xyz):
            x = np.asarray(xyz, float)
            return np.c_[x[:, 0] - self.off[photo], x[:, 1]]

    photo = np.array(["a", "b", "a", "b", "c"])
    point = np.array(["p", "p", "q", "q", "q"])
    # p: b is 5 px off (both rays off); q: c is 4 px off, a and b agree (a is q's reference)
    colrow = np.array([[50.0, 50.0], [45.0, 45.0], [60.0, 60.0], [50.0, 60.0], [44.0, 60.0]])
    err = bench.score_tracks(Flat(), photo, point, colrow)
    np.testing.assert_allclose(err[:2], [np.hypot(5, 5)] * 2)
    np.testing.assert_allclose(err[2:], [0.0, 0.0, 4.0])


def test_pooled_honesty_accepts_honest_sds_and_rejects_sds_too_small():
    """The pooled statistics of the slow acceptance test can fail: N(0, 1) errors pass, the same errors
    over sds 1.5 x too small (about 40 beyond 3 "sd" expected) do not."""
    rng = np.random.default_rng(0)
    z = [rng.standard_normal((24, 6)) for _ in range(6)]
    h = bench.pooled_honesty(z)
    assert h["n"] == 864 and h["bound_over3"] == 8 and h["expected_over3"] == pytest.approx(2.33, abs=0.01)
    assert h["over3"] <= h["bound_over3"] and 0.8 <= h["rms_z"] <= 1.25
    h = bench.pooled_honesty([1.5 * a for a in z])
    assert h["over3"] > h["bound_over3"] and h["rms_z"] > 1.25


#: seeds of the slow acceptance tests (10-13 are the bench rows of docs/figures.md "Honest sds" at 1000 x 750 px)
ACCEPTANCE_SEEDS = (10, 11, 12, 13, 14, 15)


@pytest.fixture(scope="module")
def acceptance_blocks(tmp_path_factory):
    """The 24-photo block of 1000 x 750 px matched and adjusted for every seed of :data:`ACCEPTANCE_SEEDS`,
    adjusted as the matched sds are written and with ``--variance-components``: {seed: (as given, vce)}
    scores (slow: 2-10 min a seed)."""
    out = {}
    for seed in ACCEPTANCE_SEEDS:
        tmp = tmp_path_factory.mktemp(f"block{seed}")
        s, sc = _photos_to_block(tmp, seed=seed, per_strip=12, size=(1000, 750))
        r = CliRunner().invoke(cli, ["adjust", str(tmp / "survey"), "--eo-constraints", "--snooping", "remove",
                                     "--variance-components", "-o", str(tmp / "adjust_vc")])
        assert r.exit_code in (0, 3), r.output
        out[seed] = (sc, bench.score_block(s, tmp / "survey", tmp / "adjust_vc"))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("seed", ACCEPTANCE_SEEDS)
def test_acceptance_block_24_photos(acceptance_blocks, seed):
    """Issue 28's first acceptance line on the 24-photo block, per seed, for both adjustments: converged,
    >= 99 % of the kept tie observations within 1 px of truth, every kept one > 3 px off named, residual
    RMS <= 0.5 px.  "Every orientation within 3 sd" and "sds honest" are claims about the sds' statistics
    and are tested pooled over the seeds (:func:`test_acceptance_orientations_within_3_sd_over_seeds`)."""
    for sc in acceptance_blocks[seed]:
        assert sc["photos"] == 24 and sc["tie_points"] >= 2000
        _assert_acceptance(sc, max_z=None)


@pytest.mark.slow
def test_acceptance_orientations_within_3_sd_over_seeds(acceptance_blocks):
    """"Every orientation within 3 sd of truth" and "sds honest (empirical / predicted 0.8-1.25 over seeds)",
    as statistics over the seeds.

    Read literally, per seed, the first cannot hold together with the second: with honest sds each
    normalised error ``z = (adjusted - true) / sd`` is N(0, 1) and exceeds 3 with probability 0.27 %, so
    the largest of a block's 24 x 6 = 144 |z| exceeds 3 with probability 1 - 0.9973^144 = 32 % (for
    independent z); on six seeds at least one block would fail with probability 90 %.  A test of the
    sds that can fail is the count of |z| > 3 over all seeds (6 x 144 = 864 elements): its expectation
    is 864 x 0.27 % = 2.3 whatever the correlation of the z, and its binomial 99.9 % quantile (8) is the
    bound (:func:`bench_photos_to_block.pooled_honesty`); sds 1.5 x too small would put about 40 beyond
    3 "sd".  The second is the pooled rms z, the empirical / predicted ratio, in 0.8-1.25.  One seed
    alone does not measure it: a block's largest errors are one roll (omega with Y0) shared by its 24
    photos, about one sample per seed (rms z 0.4-1.7 per seed, docs/figures.md "Honest sds").  Both are
    asserted for the adjustment with variance components (the sds the residuals ask for: what
    ``lidarcat run`` adjusts) and for the sds as ``match`` writes them.
    """
    for k, variant in enumerate(("as given", "vce")):
        h = bench.pooled_honesty([acceptance_blocks[seed][k]["z_apriori"] for seed in ACCEPTANCE_SEEDS])
        assert h["n"] == len(ACCEPTANCE_SEEDS) * 24 * 6
        assert h["over3"] <= h["bound_over3"], (variant, h)
        assert 0.8 <= h["rms_z"] <= 1.25, (variant, h)


@pytest.mark.slow
def test_planted_gross_matches_are_named_on_the_24_photo_block(tmp_path):
    """The planted gross matches of the fast test on the acceptance block (seed 2, 1000 x 750 px)."""
    s = aerial_survey(tmp_path / "survey", n_strips=2, photos_per_strip=12, forward_overlap=0.6, side_overlap=0.3,
                      image_size_px=(1000, 750), approx_position_sd_m=2.0, approx_angle_sd_deg=0.5,
                      n_gps_points=4, seed=2)
    folder = tmp_path / "survey"
    r = CliRunner().invoke(cli, ["match", str(folder), "-o", str(tmp_path / "match")])
    assert r.exit_code == 0, r.output
    planted = bench.plant_gross(s, folder, seed=2)
    r = CliRunner().invoke(cli, ["adjust", str(folder), "--eo-constraints", "-o", str(tmp_path / "adjust")])
    assert r.exit_code in (0, 3), r.output
    _assert_planted_named(s, folder, tmp_path / "adjust", planted)


def test_run_plans_match_then_an_adjustment_on_the_gnss_imu_datum(tmp_path):
    """`lidarcat run` on photos + approximate GNSS/IMU (photos.csv sd_X0..) + LiDAR tiles: match first,
    the adjustment after it with the GNSS/IMU constraints; with no control set they are its datum."""
    from lidarcat.pipeline import plan_pipeline
    from lidarcat.survey.folder import Survey

    aerial_survey(tmp_path / "s", n_strips=1, photos_per_strip=2, image_size_px=(160, 120), seed=0)
    plan = {st.name: st for st in plan_pipeline(Survey.load(tmp_path / "s"))}
    names = list(plan)
    assert names.index("match") < names.index("adjust-gps")
    assert plan["adjust-gps"].requires == ("match",)          # a failed match skips the adjustment
    assert plan["adjust-gps"].params == {"control": "gps", "derived": False, "eo_constraints": True}
    toml = (tmp_path / "s" / "survey.toml").read_text()
    toml = "\n".join(ln for ln in toml.splitlines() if not ln.startswith(("control_sets", "default_control")))
    (tmp_path / "s" / "survey.toml").write_text(toml)
    plan = {st.name: st for st in plan_pipeline(Survey.load(tmp_path / "s"))}
    assert "adjust-gps" not in plan and plan["adjust-gnss"].skip_reason is None
    assert plan["adjust-gnss"].params == {"control": None, "derived": False, "eo_constraints": True}
    assert plan["assess-gnss"].skip_reason == "control set gnss has no check points"


@pytest.mark.slow
def test_run_on_photos_gnss_lidar_and_gps_exits_0(tmp_path):
    """`lidarcat run` on a folder of photos + GNSS/IMU (photos.csv sds) + LiDAR tiles + GPS control: match,
    then the adjustment with the matched sds, their variance components and the named matches removed --
    exit 0 (it exited 3 on the chi-square test while the tie points had the targets' sd)."""
    aerial_survey(tmp_path / "s", n_strips=2, photos_per_strip=3, forward_overlap=0.6, side_overlap=0.3,
                  image_size_px=(480, 360), approx_position_sd_m=2.0, approx_angle_sd_deg=0.5, n_gps_points=4, seed=1)
    r = CliRunner().invoke(cli, ["run", str(tmp_path / "s"), "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "out" / "adjust-gps" / "summary.json").read_text())
    assert summary["chi2_pass"] and summary["variance_components"]["converged"]
    assert summary["snooping"]["mode"] == "remove" and not summary["snooping"]["blunders_remain"]
