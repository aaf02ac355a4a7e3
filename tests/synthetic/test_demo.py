"""`lidarcat demo synthetic` + `lidarcat run`: the end-to-end test of the whole tool against known truth."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import stats

from lidarcat.cli.main import cli
from lidarcat.synthetic.survey import compare_with_truth, demo_camera, project_points, write_synthetic_survey
from lidarcat.errors import LidarcatError
from lidarcat.survey.folder import Survey

# demo synthetic + run end to end (about 15 s): slow-marked (run with -m slow)
pytestmark = pytest.mark.slow


def _csv(path: Path) -> dict[str, dict[str, str]]:
    with open(path, encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    key = "photo" if "photo" in rows[0] and "point" not in rows[0] else "point"
    return {r[key]: r for r in rows}


def _f(row: dict[str, str], *keys: str) -> np.ndarray:
    return np.array([float(row[k]) for k in keys])


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("demo")
    runner = CliRunner()
    res = runner.invoke(cli, ["demo", "synthetic", "-o", str(root / "survey"), "--seed", "7", "--json"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    res = runner.invoke(cli, ["run", str(root / "survey"), "-o", str(root / "out"), "--json"])
    assert res.exit_code == 0, res.output
    return root / "survey", root / "out", info, json.loads(res.output)


def test_demo_writes_a_valid_survey(demo_run):
    survey_dir, _, info, _ = demo_run
    s = Survey.load(survey_dir)
    assert len(s.photos) == info["n_photos"] == 6
    assert s.settings.observations == "pixel"
    assert len(s.lidar_paths) == 4 and s.extraction_jobs is not None
    assert set(s.control_sets) == {"gps"}
    assert len(s.control_sets["gps"].control) == 5
    assert len(s.control_sets["gps"].check) == info["n_gps"] - 5 >= 6
    for name in ("eop.csv", "points.csv", "roofs.csv", "README.md"):
        assert (survey_dir / "truth" / name).is_file()


def test_demo_measurements_follow_the_truth(demo_run):
    """Pixel measurements, back through eq. 01-07, fit the true orientation within the noise."""
    survey_dir, _, info, _ = demo_run
    s = Survey.load(survey_dir)
    obs = s.photo_observations("pixel")
    eop = _csv(survey_dir / "truth" / "eop.csv")
    pts = _csv(survey_dir / "truth" / "points.csv")
    cam = demo_camera()
    res = []
    for ph, q, xy in zip(obs.photo, obs.point, obs.xy_mm):
        e = _f(eop[ph], "X0", "Y0", "Z0", "omega", "phi", "kappa")
        e[3:] = np.radians(e[3:])
        res.append(project_points(_f(pts[q], "E", "N", "h")[None], e, cam.focal_length_mm)[0] - xy)
    res = np.array(res) / cam.pixel_size_x_mm  # px
    # 0.5 px noise: the sample sd agrees within 10 %, no bias
    assert abs(res.std() / info["image_sd_px"] - 1) < 0.1
    assert np.all(np.abs(res.mean(axis=0)) < 0.1)


def test_demo_projection_known_geometry():
    # camera at 1000 m, kappa = 90 deg, c = 50 mm: a point 10 m east lands at y = -0.5 mm
    xy = project_points(np.array([[10.0, 0.0, 0.0], [0.0, 0.0, 1500.0]]),
                        [0.0, 0.0, 1000.0, 0.0, 0.0, np.pi / 2], 50.0)
    np.testing.assert_allclose(xy[0], [0.0, -0.5], atol=1e-12)
    assert np.isnan(xy[1]).all()  # above the camera: not imaged


def test_extraction_recovers_every_roof_vertex_within_3_sigma(demo_run):
    survey_dir, out, info, summary = demo_run
    truth = _csv(survey_dir / "truth" / "roofs.csv")
    got = _csv(out / "extract" / "control.csv")
    assert sorted(got) == sorted(truth) and len(truth) == info["n_roofs"] == 7
    z = []
    for pid, row in got.items():
        assert row["status"] == "ok", row
        assert int(row["n_planes"]) == int(truth[pid]["n_planes"])
        err = _f(row, "E", "N", "h") - _f(truth[pid], "E", "N", "h")
        z.extend(err / _f(row, "sd_E", "sd_N", "sd_h"))
    assert np.all(np.abs(z) <= 3.0), np.round(z, 2)
    assert summary["extraction"]["n_ok"] == 7


def test_demo_roofs_are_extracted_without_bias_and_with_honest_sds():
    """The 3-sigma statement above is one draw; this is its distribution: 160 buildings of the
    demo's own generator (pyramid and hip roofs, facades, 4 pts/m2, 0.03 / 0.05 m noise), jobs
    0.5-1.5 m off, extracted with the noise the demo states."""
    from lidarcat.synthetic import roofs
    from lidarcat.synthetic.survey import _LIDAR_PLAN_SD_M, _place_buildings
    from lidarcat.control.vertices import extract_roof
    from lidarcat.control.facets import get_params

    rng = np.random.default_rng(2026)
    cand = np.column_stack([rng.uniform(0, 1000, 160), rng.uniform(0, 1000, 160)]) + [680_000, 7_184_000]
    buildings = _place_buildings(cand, 160, rng, roofs, 4.0, 0.05)
    params = get_params(sd_en_m=_LIDAR_PLAN_SD_M, sd_h_m=0.05)
    z = []
    for b in buildings:
        a = rng.uniform(0, 2 * np.pi)
        approx = b["vertex"][:2] + rng.uniform(0.5, 1.5) * np.array([np.cos(a), np.sin(a)])
        cp = extract_roof(np.asarray(b["scene"].xyz), approx, params=params)
        assert cp, (b["id"], cp.status, cp.reason)
        z.append((cp.enh_m - b["vertex"]) / cp.sd_m)
    z = np.array(z)
    se = 1 / np.sqrt(len(z))
    assert np.all(np.abs(z.mean(axis=0)) < 3.5 * se), z.mean(axis=0)   # no bias (facades handled)
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert np.all((rms > 0.85) & (rms < 1.2)), rms                        # honest sds
    assert np.mean(np.abs(z) <= 3) >= 0.99


@pytest.mark.parametrize("run", ["gps", "lidar"])
def test_orientations_within_3_sigma_of_the_truth(demo_run, run):
    survey_dir, out, _, summary = demo_run
    adj = summary["runs"][run]["adjustment"]
    assert adj["converged"] and adj["chi2_pass"]
    truth = _csv(survey_dir / "truth" / "eop.csv")
    got = _csv(out / f"adjust-{run}" / "eop.csv")
    keys = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    z = []
    for ph, row in truth.items():
        d = _f(got[ph], *keys) - _f(row, *keys)
        d[3:] = (d[3:] + 180) % 360 - 180
        sd = _f(got[ph], *(f"sd_{k}" for k in keys))
        assert np.all(np.abs(d) <= 3 * sd), (run, ph, d, sd)
        z.extend(d / sd)
    # jointly: the normalised errors are consistent with N(0, 1) (36 values, 99.9 % bound)
    assert np.sum(np.square(z)) < stats.chi2.ppf(0.999, len(z))


@pytest.mark.parametrize("run", ["gps", "lidar"])
def test_check_points_pass_chi_square_at_the_noise_level(demo_run, run):
    """d' C^-1 d ~ chi2(3n): C the joint covariance of the adjusted check points (their errors
    are correlated through the orientations) plus the GPS variances."""
    from lidarcat.survey import read_point_covariance

    survey_dir, out, _, summary = demo_run
    disc = _csv(out / f"assess-{run}" / "discrepancies.csv")
    ground = _csv(survey_dir / "ground_points.csv")
    ids, C = read_point_covariance(out / f"adjust-{run}" / "check_covariance.csv", points=list(disc))
    d = np.concatenate([_f(disc[q], "dE", "dN", "dh") for q in ids])
    C = C + np.diag(np.concatenate([_f(ground[q], "sd_E", "sd_N", "sd_h") ** 2 for q in ids]))
    t = float(d @ np.linalg.solve(C, d))
    df = 3 * len(disc)
    assert summary["runs"][run]["check"]["n"] == len(disc) >= 6
    assert stats.chi2.ppf(0.005, df) < t < stats.chi2.ppf(0.995, df), (t, df)
    cons = summary["runs"][run]["check"]["consistency"]   # the assessment computed the same test
    assert cons["df"] == df and abs(cons["chi2"] - t) < 1e-6 * t


def test_check_points_against_the_truth_within_3_sigma(demo_run):
    survey_dir, out, _, _ = demo_run
    truth = _csv(survey_dir / "truth" / "points.csv")
    for run in ("gps", "lidar"):
        pts = _csv(out / f"adjust-{run}" / "points.csv")
        for pid, row in pts.items():
            if row["role"] == "control":
                continue
            err = _f(row, "E", "N", "h") - _f(truth[pid], "E", "N", "h")
            # 3.9 sigma: 52 points x 3 axes, a 1 % family-wise level
            assert np.all(np.abs(err) <= 3.9 * _f(row, "sd_E", "sd_N", "sd_h")), (run, pid, err)


def test_all_stages_ran(demo_run):
    _, out, _, summary = demo_run
    assert summary["ok"] is True
    assert summary["stages_ran"] == ["camera", "extract", "adjust-gps", "adjust-lidar", "assess-gps",
                                     "assess-lidar", "compare-gps-lidar", "report"]
    assert (out / ".lidar_index.json").is_file()      # tile + block index kept for the next run
    assert not (out / ".lidarcat.lock").exists()
    derived = Survey.load(out / "extract" / "survey")
    assert set(derived.control_sets) == {"gps", "lidar"}
    assert len(derived.control_sets["lidar"].control) == 7


def test_demo_compare_command(demo_run):
    survey_dir, out, _, _ = demo_run
    res = CliRunner().invoke(cli, ["demo", "compare", str(survey_dir), str(out), "--json"])
    assert res.exit_code == 0, res.output
    cmp_ = json.loads(res.output)
    assert set(cmp_["runs"]) == {"gps", "lidar"} and len(cmp_["extraction"]) == 7
    for r in cmp_["runs"].values():
        assert r["eo_max_abs_z"] <= 3.0 and 0.5 < r["eo_rms_z"] < 1.5
        assert r["check_dof"] == 3 * r["n_check"]
        assert stats.chi2.ppf(0.005, r["check_dof"]) < r["check_chi2_joint"] < stats.chi2.ppf(0.995, r["check_dof"])
    res = CliRunner().invoke(cli, ["demo", "compare", str(survey_dir), str(out)])
    assert res.exit_code == 0 and "run lidar: orientations max |z|" in res.output


def test_demo_compare_errors_name_the_folder_and_the_missing_id(demo_run, tmp_path):
    import shutil

    survey_dir, out, _, _ = demo_run
    empty = tmp_path / "empty"
    empty.mkdir()
    res = CliRunner().invoke(cli, ["demo", "compare", str(survey_dir), str(empty)])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output == (f"Error: {empty}: no adjust-* folder; run `lidarcat run {survey_dir} "
                          f"-o {empty}` first\n")
    # the truth of another survey: photo 6 of the run is not in its truth/eop.csv
    other = tmp_path / "other"
    shutil.copytree(survey_dir / "truth", other / "truth")
    shutil.copy(survey_dir / "ground_points.csv", other)
    eop = other / "truth" / "eop.csv"
    eop.write_text("".join(ln for ln in eop.read_text().splitlines(keepends=True)
                           if not ln.startswith("6,")))
    with pytest.raises(LidarcatError) as ei:
        compare_with_truth(other, out)
    assert str(ei.value) == (f"{out / 'adjust-gps' / 'eop.csv'}: '6' is not in {eop}; is {out} the "
                             f"output of `lidarcat run {other}`?")


def test_a_job_for_a_point_no_photo_measures_is_reported_and_settings_carry_over(demo_run, tmp_path):
    import shutil

    survey_dir, _, _, _ = demo_run
    survey = tmp_path / "survey"
    shutil.copytree(survey_dir, survey, ignore=shutil.ignore_patterns("out"))
    jobs = survey / "jobs.csv"
    last = jobs.read_text().splitlines()[-1]
    jobs.write_text(jobs.read_text() + "X99" + last[last.index(","):] + "\n")   # R07's roof, unmeasured id
    toml = survey / "survey.toml"
    toml.write_text(toml.read_text() + '\n[assessment]\nscale = 5000\npec_class = "B"\n')
    res = CliRunner().invoke(cli, ["run", str(survey), "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert ("  extraction: measured on no photo, no effect on the block: X99 (check the ids in the "
            "jobs file)\n") in res.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["extraction"]["not_measured"] == ["X99"] and summary["extraction"]["n_ok"] == 8
    assert "X99: measured on no photo" in (tmp_path / "out" / "lidarcat.log").read_text()
    # the derived survey keeps the [assessment] table (for lidarcat adjust / assess on it)
    derived = Survey.load(tmp_path / "out" / "extract" / "survey")
    assert (derived.assessment.scale, derived.assessment.pec_class) == (5000.0, "B")


def test_run_with_figures_draws_every_roof(demo_run, tmp_path):
    survey_dir, _, info, _ = demo_run
    res = CliRunner().invoke(cli, ["run", str(survey_dir), "-o", str(tmp_path / "out"), "--figures"])
    assert res.exit_code == 0, res.output
    pngs = sorted(p.name for p in (tmp_path / "out" / "extract" / "figures").iterdir())
    assert pngs == [f"R{k:02d}.png" for k in range(1, info["n_roofs"] + 1)]
    assert all((tmp_path / "out" / "extract" / "figures" / p).read_bytes()[:4] == b"\x89PNG" for p in pngs)


def test_same_seed_same_survey(tmp_path):
    a = write_synthetic_survey(tmp_path / "a", n_photos=4, seed=3)
    b = write_synthetic_survey(tmp_path / "b", n_photos=4, seed=3)
    c = write_synthetic_survey(tmp_path / "c", n_photos=4, seed=4)
    assert a.files == b.files
    for name in a.files:
        if name.endswith(".csv"):
            assert (a.path / name).read_bytes() == (b.path / name).read_bytes(), name
    assert (a.path / "image_points.csv").read_bytes() != (c.path / "image_points.csv").read_bytes()
    assert a.n_photos == 4 and a.n_roofs == 5


def test_bad_sizes_are_errors(tmp_path):
    with pytest.raises(LidarcatError, match="at least 2"):
        write_synthetic_survey(tmp_path / "x", n_photos=1)
    res = CliRunner().invoke(cli, ["demo", "synthetic", "-o", str(tmp_path / "y"), "--photos", "1"])
    assert res.exit_code == 2 and "Traceback" not in res.output
