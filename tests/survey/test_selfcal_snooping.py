"""``lidarcat adjust S --eo-constraints --self-calibrate k1`` on a matched survey in one command: data snooping
(``remove``) and the variance components, the default of a matched survey, before the self-calibration
(:mod:`lidarcat.survey.selfcal`, "Blunders and variance components with additional parameters").

The block is :func:`lidarcat.synthetic.matches.matched_block` (six photos, no control, 17 planted gross
observations) with radial distortion planted in every photo coordinate: ``x_meas = x (1 + k1 r^2)``,
k1 = 2e-6 mm^-2 (1.7 px at the corners of the 36 x 24 mm frame), which the camera.toml (k1 = 0) does not
model.  Image sds written 0.6 px against a true 0.3 px: tie factor (1/2)^2.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.synthetic.matches import MATCH_PIXEL_MM, matched_block
from test_adjust_robust import _table, _write

K1 = 2e-6   # mm^-2


@pytest.fixture(scope="module")
def distorted():
    p, truth, planted = matched_block()
    xy = np.asarray(p.xy_mm, float)
    xy = xy * (1.0 + K1 * (xy ** 2).sum(axis=1))[:, None]     # first order: the camera's k1 inverts it
    return dataclasses.replace(p, xy_mm=xy), truth, planted


def test_self_calibration_with_snooping_and_variance_components_in_one_command(tmp_path, distorted):
    """Exactly the 17 planted gross observations are named and removed; k1 is recovered within 3 sd
    (and significant); the tie factor is the true 0.25 once re-estimated with the parameter (the factor
    of the adjustment without it, 0.286, holds the distortion); the global test accepts: exit 0."""
    p, _, planted = distorted
    s = _write(tmp_path / "s", p, obs_sd_mm=repr(0.6 * MATCH_PIXEL_MM))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "--self-calibrate", "k1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "variance components estimated and the named observations removed" in r.output
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["snooping"]["mode"] == "remove" and summary["snooping"]["n_removed"] == 17
    assert "are those of the adjustment without the additional parameters" in summary["snooping"]["reason"]
    assert {(b["photo"], b["point"]) for b in _table(out / "blunders.csv")} == planted
    assert not (out / "reliability.csv").exists()      # its redundancy numbers would be of the other adjustment
    k1 = summary["additional_parameters"]["cam.k1"]
    assert abs(k1["estimate"] - K1) < 3 * k1["sd"] and k1["significant"] and k1["sd"] < K1 / 5
    vc = {g["group"]: g for g in summary["variance_components"]["groups"]}
    assert vc["tie"]["estimated"] and vc["tie"]["factor"] == pytest.approx(0.25, abs=0.02)
    assert summary["chi2_pass"] and summary["converged"]
    assert len(_table(out / "residuals.csv")) == len(p.photo_index) - 17 + p.n_photos   # kept rays + 6 eo rows
    params = summary["provenance"]["parameters"]
    assert params["snooping"] == "remove" and params["variance_components"] is True


def test_report_mode_without_variance_components_keeps_every_observation(tmp_path, distorted):
    """The library call with snooping ``report`` and ``variance_components=False``: the sds stay as
    written (twice the true ones, so each test is half as sensitive: 15 of the 17 are named, the two rays
    of one mismatched two-ray point are not), nothing else is named, and every observation stays in the
    adjustment with the parameter -- the kept gross matches pull k1 to 3.5e-5, over 100 sd from the truth:
    why a matched survey removes them by default."""
    from lidarcat.survey.folder import Survey
    from lidarcat.survey.selfcal import selfcal_snooped

    p, _, planted = distorted
    s = _write(tmp_path / "s", p, obs_sd_mm=repr(0.6 * MATCH_PIXEL_MM))
    sc = selfcal_snooped(Survey.load(s), self_calibrate="k1", eo_constraints=True, snooping="report")
    assert sc.variance_components is None and sc.snooping.mode == "report"
    named = {(b.photo, b.point) for b in sc.snooping.blunders}
    assert named <= planted and len(named) == 15
    assert not any(b.removed for b in sc.snooping.blunders)
    assert len(sc.result.bundle.problem.photo_index) == len(p.photo_index)     # report: every observation
    i = sc.result.index("cam.k1")
    assert abs(sc.result.estimates[i] - K1) > 100 * sc.result.sd[i]


def test_run_selfcal_stage_removes_the_gross_matches_before_estimating(tmp_path, distorted):
    """The ``selfcal`` stage of ``lidarcat run`` on the matched survey with ``[self_calibration] parameters =
    "k1"``: as ``lidarcat adjust --self-calibrate`` on a matched survey, the 17 planted gross matches are
    removed (the plan weights the GNSS/IMU orientation, photos.csv's sds) and k1 comes within 3 sd of the
    truth -- kept, they pull it over 100 sd away (the test above)."""
    from lidarcat.pipeline.plan import plan_pipeline
    from lidarcat.stages import selfcal
    from lidarcat.stages.context import StageContext
    from lidarcat.survey.folder import Survey

    p, _, planted = distorted
    s = _write(tmp_path / "s", p, obs_sd_mm=repr(0.6 * MATCH_PIXEL_MM))
    with open(s / "survey.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[self_calibration]\nparameters = "k1"\n')
    survey = Survey.load(s)
    stage = next(st for st in plan_pipeline(survey) if st.name == "selfcal")
    assert stage.params == {"eo_constraints": True}
    tmp = tmp_path / "out" / "selfcal"
    tmp.mkdir(parents=True)
    ctx = StageContext(tmp_path / "out", {"survey": survey})
    ctx.stage, ctx.current = stage, stage.name          # as the runner hands the planned stage over
    got = selfcal.run(ctx, tmp)
    assert got["blunders_removed"] == 17
    assert {(b["photo"], b["point"]) for b in _table(tmp / "blunders.csv")} == planted
    k1 = got["additional_parameters"]["cam.k1"]
    assert abs(k1["estimate"] - K1) < 3 * k1["sd"] and k1["significant"]
    summary = json.loads((tmp / "summary.json").read_text(encoding="utf-8"))
    assert summary["snooping"]["mode"] == "remove"
    assert {g["group"] for g in summary["variance_components"]["groups"]} >= {"tie"}
