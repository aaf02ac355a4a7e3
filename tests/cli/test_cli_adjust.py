"""``lidarcat adjust``: files, columns, report, errors (issue 3)."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import THESIS_SURVEY, THESIS_TABLES

from lidarcat.survey import COVARIANCE_COLUMNS, EOP_COLUMNS, POINT_COLUMNS, RESIDUAL_COLUMNS
from lidarcat.cli.main import cli

SUMMARY_KEYS = {"dof", "vtpv", "sigma0_sq", "chi2_lower", "chi2_upper", "chi2_pass", "n_iterations",
                "converged", "survey", "control_set", "observations", "elapsed_s"}


def _read(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.reader(line for line in fh if not line.startswith("#")))


@pytest.fixture(scope="module")
def gps_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("adjust") / "gps"
    result = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--control", "gps",
                                      "--observations", "corrected", "-o", str(out)])
    return result, out


def test_gps_run_writes_its_files(gps_run):
    result, out = gps_run
    # the thesis measurements hold one observation the w-tests reject at the family-wise level 0.05
    # (photo 3 point 407, w 4.26 > 4.00; default --snooping report): named on the last line, exit 0
    # as `lidarcat run` exits on the same block (issue 25; tests/cli/test_exit_codes_same_block.py)
    assert result.exit_code == 0, result.output
    assert "family-wise 0.05 over 159 tests" in result.output
    assert result.output.endswith("Warning: 1 blunder(s) remain in the adjustment.\n")
    assert sorted(p.name for p in out.iterdir() if not p.name.endswith(".csv.json")) == [
        "blunders.csv", "check_covariance.csv", "eop.csv", "eop_covariance.csv", "points.csv", "reliability.csv",
        "residuals.csv", "summary.json"]
    assert (out / "eop.csv").read_text().startswith("photo,")  # header first (notes in eop.csv.json)
    assert "check_covariance.csv" in result.output
    eop = _read(out / "eop.csv")
    assert tuple(eop[0]) == EOP_COLUMNS == ("photo", "X0", "Y0", "Z0", "omega", "phi", "kappa", "sd_X0",
                                            "sd_Y0", "sd_Z0", "sd_omega", "sd_phi", "sd_kappa")
    assert [r[0] for r in eop[1:]] == ["1", "2", "3", "4", "5", "6"]
    pts = _read(out / "points.csv")
    assert tuple(pts[0]) == POINT_COLUMNS == ("point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "role")
    assert len(pts) == 55
    roles = {r[0]: r[7] for r in pts[1:]}
    assert {q for q, r in roles.items() if r == "control"} == {"601", "604", "619", "624", "627", "661",
                                                                "662", "664"}
    assert sum(r == "check" for r in roles.values()) == 13
    assert set(roles.values()) == {"control", "check", "tie"}
    res = _read(out / "residuals.csv")
    assert tuple(res[0]) == RESIDUAL_COLUMNS
    kinds = [r[0] for r in res[1:]]
    assert kinds.count("image") == 151 and kinds.count("control") == 8
    cov = _read(out / "check_covariance.csv")
    assert tuple(cov[0]) == COVARIANCE_COLUMNS == ("point_a", "point_b", "c_EE", "c_EN", "c_Eh", "c_NE", "c_NN",
                                                   "c_Nh", "c_hE", "c_hN", "c_hh")
    assert len(cov) - 1 == 13 * 14 // 2 and cov[1][:2] == ["603", "603"]   # pairs a <= b of the 13 checks


def test_gps_run_values_in_files(gps_run):
    _, out = gps_run
    s = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= set(s)
    assert s["dof"] == 128 and s["converged"] is True and s["chi2_pass"] is True
    assert abs(s["vtpv"] - 148.35) < 0.5
    assert abs(s["sigma0_sq"] - 1.16) < 0.01
    assert (s["survey"], s["control_set"], s["observations"]) == ("thesis-fierro-2007", "gps", "corrected")
    assert (s["crs"], s["height_system"]) == ("EPSG:29192", "orthometric")  # the datum of every height written
    eop = _read(out / "eop.csv")
    t6 = _read(THESIS_TABLES / "table6_eop_gps.csv")
    h = t6[0]
    for mine, ref in zip(eop[1:], t6[1:]):
        for col, refcol, tol in (("X0", "X0", 0.10), ("Y0", "Y0", 0.10), ("Z0", "Z0", 0.03),
                                 ("omega", "omega_deg", 0.005), ("kappa", "kappa_deg", 0.005),
                                 ("sd_X0", "sd_X0", 0.05)):
            assert abs(float(mine[EOP_COLUMNS.index(col)]) - float(ref[h.index(refcol)])) < tol


def test_gps_run_report(gps_run):
    """The report prints what summary.json holds; the published Appendix 2.1 figures agree."""
    from scipy.stats import chi2

    result, out = gps_run
    text = result.output
    s = json.loads((out / "summary.json").read_text())
    app = json.loads((THESIS_SURVEY / "published" / "app2.json").read_text())["2.1_gps"]
    assert "Degrees of freedom             128" in text and app["dof"] == 128
    assert f"Chi-square computed (v'Pv)     {s['vtpv']:.2f}" in text
    assert abs(s["vtpv"] - app["chi2_computed"]) < 0.5      # printed 148.35
    lo, hi = chi2.ppf([0.025, 0.975], 128)                  # exact two-sided 5 % range
    assert f"{lo:.2f} - {hi:.2f}" in text and "accepted" in text
    flo, fhi = app["chi2_range_5pct"]                       # the thesis's Fisher approximation, 2 decimals
    assert f"Fisher approx. {flo:.2f} - {fhi:.2f}" in text
    assert "Variance factor a posteriori   1.16" in text
    assert "RMS sd of all points (m)       E 0.264  N 0.215  h 1.057  (Appendix 2 'pontos livres')" in text
    assert str(out) in text


def test_pixel_and_lidar_runs_json(tmp_path):
    runner = CliRunner()
    r = runner.invoke(cli, ["adjust", "--control", "lidar", "--observations", "pixel", "-o",
                            str(tmp_path / "lidar"), "--json", "--snooping", "off"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["converged"] and s["dof"] == 128
    assert (s["control_set"], s["observations"]) == ("lidar", "pixel")
    assert (tmp_path / "lidar" / "eop.csv").is_file()
    pts = _read(tmp_path / "lidar" / "points.csv")
    assert {r[0] for r in pts[1:] if r[7] == "control"} == {"701", "703", "705", "706", "707", "712",
                                                            "719", "721"}


def test_pixel_run_side_by_side_with_corrected(gps_run, tmp_path):
    """Both runs against Table 6: corrected within 0.10 m, pixel within 0.3 m / 0.015 deg."""
    _, out = gps_run
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--observations", "pixel",
                                 "-o", str(tmp_path / "pix"), "--snooping", "off"])
    assert r.exit_code == 0, r.output
    t6 = _read(THESIS_TABLES / "table6_eop_gps.csv")
    cols = [t6[0].index(c) for c in ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")]
    ref = np.array([[float(row[c]) for c in cols] for row in t6[1:]])
    a = np.array([[float(v) for v in row[1:7]] for row in _read(out / "eop.csv")[1:]])
    b = np.array([[float(v) for v in row[1:7]] for row in _read(tmp_path / "pix" / "eop.csv")[1:]])
    assert np.abs(a - ref)[:, :3].max() < 0.10
    assert np.abs(b - ref)[:, :3].max() < 0.3
    assert np.abs(b - ref)[:, 3:].max() < 0.015


def test_a_posteriori_option(tmp_path, gps_run):
    _, out = gps_run
    r = CliRunner().invoke(cli, ["adjust", "--variance-factor", "a_posteriori", "-o", str(tmp_path), "--json",
                                 "--snooping", "off"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["variance_factor"] == "a_posteriori"
    assert abs(s["sigma0_sq"] - 1.16) < 0.005                  # Appendix 2.1, printed 1.16
    a = np.array([[float(v) for v in row[7:]] for row in _read(out / "eop.csv")[1:]])
    b = np.array([[float(v) for v in row[7:]] for row in _read(tmp_path / "eop.csv")[1:]])
    np.testing.assert_allclose(b / a, np.sqrt(s["vtpv"] / s["dof"]), rtol=1e-9)   # every sd scaled


def test_unknown_control_set_leaves_no_files(tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", "--control", "nope", "-o", str(out)])
    assert r.exit_code == 2
    assert r.output.startswith("Error: ") and "no control set 'nope'" in r.output
    assert len(r.output.strip().splitlines()) == 1
    assert not out.exists()


def test_datum_error_names_the_points(tmp_path):
    survey = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, survey)
    with open(survey / "control_sets.csv", "a", encoding="utf-8") as fh:
        fh.write("two,601,control,0.25,0.25,0.25\ntwo,604,control,0.25,0.25,0.25\n")
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(survey), "--control", "two", "-o", str(out)])
    assert r.exit_code == 2
    assert r.output.startswith("Error: too little control in the block: 2 point(s) with E, N and 2 with h "
                               "(601, 604)")
    assert "Traceback" not in r.output
    assert not out.exists()


def test_not_converged_exit_1_but_results_written(tmp_path):
    r = CliRunner().invoke(cli, ["adjust", "--max-iter", "1", "-o", str(tmp_path), "--json"])
    assert r.exit_code == 1
    s = json.loads(r.output.split("Warning")[0])
    assert s["converged"] is False and s["status"] == "max_iterations"
    assert (tmp_path / "summary.json").is_file()


def test_help_teaches_units_and_example():
    r = CliRunner().invoke(cli, ["adjust", "--help"])
    assert r.exit_code == 0
    for text in ("--control", "--observations", "--variance-factor", "deg", "lidarcat adjust --control gps"):
        assert text in r.output


def test_eo_constraints_flag(tmp_path, gps_run):
    _, out = gps_run
    survey = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, survey)
    eop = _read(out / "eop.csv")
    rows = ["photo,camera,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0,sd_omega_deg,sd_phi_deg,"
            "sd_kappa_deg"]
    for r in eop[1:]:
        x0, y0, z0, om, ph, ka = (float(v) for v in r[1:7])
        rows.append(f"{r[0]},dcs14n,{x0 + 1:.2f},{y0 - 1:.2f},{z0:.2f},{om:.3f},{ph:.3f},{ka:.3f},2,2,2,"
                    "0.05,0.05,0.05")
    (survey / "photos.csv").write_text("\n".join(rows) + "\n")
    res = CliRunner().invoke(cli, ["adjust", str(survey), "--eo-constraints", "-o", str(tmp_path / "o"),
                                   "--json", "--snooping", "off"])
    assert res.exit_code == 0, res.output
    s = json.loads(res.output)
    assert s["eo_constraints"] is True and s["n_constraints"] == 24 + 36 and s["dof"] == 128 + 36
    kinds = [r[0] for r in _read(tmp_path / "o" / "residuals.csv")[1:]]
    assert kinds.count("eo") == 6


def test_precision_option(tmp_path, gps_run):
    """--precision photos: photo sds as in the full run, point sds empty, no joint covariance file."""
    out = tmp_path / "photos"
    result = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--control", "gps", "--observations",
                                      "corrected", "--precision", "photos", "-o", str(out), "--json",
                                      "--snooping", "off"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["precision"] == "photos"
    _, full = gps_run
    full_eop, eop = _read(full / "eop.csv"), _read(out / "eop.csv")
    assert eop[0] == full_eop[0] == list(EOP_COLUMNS)
    for a, b in zip(full_eop[1:], eop[1:]):
        np.testing.assert_allclose(np.array(b[7:], float), np.array(a[7:], float), rtol=1e-9)
    pts = _read(out / "points.csv")
    assert all(v in ("", "nan") for row in pts[1:] for v in row[4:7])
    assert not (out / "check_covariance.csv").exists() and (full / "check_covariance.csv").exists()
    bad = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--precision", "some"])
    assert bad.exit_code == 2 and "'some' is not one of 'all', 'photos', 'none'" in bad.output


def test_snooping_with_additional_parameters_refused_or_off(tmp_path):
    """With --self-calibrate / --frame-offset --robust is refused (exit 2, nothing written); data snooping
    runs on the adjustment without the parameters when asked (blunders.csv, no reliability.csv); by
    default on a survey without matched tie points it is off and the output says why."""
    from lidarcat.survey.selfcal import ROBUST_WITH_PARAMETERS, SNOOPED_WITHOUT_PARAMETERS, SNOOPING_WITH_PARAMETERS

    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--self-calibrate", "c", "--robust", "danish",
                                 "-o", str(tmp_path / "x")])
    assert r.exit_code == 2, r.output
    assert r.output.endswith(f"Error: --robust danish: {ROBUST_WITH_PARAMETERS}\n")
    assert not (tmp_path / "x").exists()
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--self-calibrate", "c", "--snooping", "report",
                                 "--snooping-level", "0.001", "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    assert f"Note: {SNOOPED_WITHOUT_PARAMETERS}." in r.output
    s = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert s["snooping"]["mode"] == "report" and s["snooping"]["reason"] == SNOOPED_WITHOUT_PARAMETERS
    assert len(s["blunders"]) == 3 and not any(b["removed"] for b in s["blunders"])   # as without parameters
    assert (tmp_path / "rep" / "blunders.csv").exists() and not (tmp_path / "rep" / "reliability.csv").exists()
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--self-calibrate", "c", "--snooping", "off",
                                 "-o", str(tmp_path / "off")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--self-calibrate", "c", "-o", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert r.output.endswith(f"Note: {SNOOPING_WITH_PARAMETERS}.\n")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["snooping"] == {"mode": "off", "reason": SNOOPING_WITH_PARAMETERS}
    assert "blunders" not in s and not (tmp_path / "o" / "blunders.csv").exists()


def test_snooping_level_options(tmp_path):
    """--family-level 0.01 (critical w 4.39 on the thesis block): no test rejects, exit 0;
    a fixed --snooping-level 0.001 (critical w 3.42): the three groups, named, exit 0 (the global
    test passes; issue 25: the exit code of `lidarcat run`)."""
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--family-level", "0.01", "-o", str(tmp_path / "a"),
                                 "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["blunders"] == [] and s["snooping"]["family_level"] == 0.01 and s["snooping"]["family_tests"] == 159
    assert abs(s["snooping"]["critical_w"]["2"] - 4.386) < 0.0015
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--snooping-level", "0.001", "-o", str(tmp_path / "b")])
    assert r.exit_code == 0, r.output
    assert r.output.endswith("Warning: 3 blunder(s) remain in the adjustment.\n")
    assert "Data snooping (report, alpha 0.001, power 0.8; critical w 3.29 (q=1), 3.42 (q=2), 3.55 (q=3)): " \
           "3 blunder(s)" in r.output
    s = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert s["snooping"]["family_level"] is None and s["provenance"]["parameters"]["snooping_level"] == 0.001
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--family-level", "0.7", "-o", str(tmp_path / "c")])
    assert r.exit_code == 2 and "--family-level" in r.output


def test_progress_bar_ticks_once_per_iteration(tmp_path, monkeypatch):
    """On a terminal the plain adjustment drives a progress bar through ``progress=``: one tick per
    iteration (the bar itself is click's; here a recorder stands in for it)."""
    import contextlib

    import lidarcat.cli.adjust as cli_adjust

    ticks, made = [], []

    class _Bar:
        def update(self, n):
            ticks.append(n)

    @contextlib.contextmanager
    def fake_bar(length, label, *, enabled=True):
        made.append((length, label, enabled))
        yield _Bar()

    monkeypatch.setattr(cli_adjust, "progress_bar", fake_bar)
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--snooping", "off", "-o", str(tmp_path / "a")])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert made == [(50, "Adjusting (iterations)", True)]
    assert ticks == [1] * s["n_iterations"] and s["n_iterations"] >= 2


@pytest.mark.parametrize("precision", ["none", "photos"])
def test_report_of_sds_not_computed(tmp_path, gps_run, precision):
    """The reproducer of issue 24: with --precision none (or photos) summary.json holds null point sds,
    and the text report ended in a TypeError; a figure not computed is written as '-'."""
    out = tmp_path / precision
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "--control", "gps", "--observations", "corrected",
                                 "--precision", precision, "-o", str(out)])
    assert r.exit_code == 0, r.output  # the one blunder the thesis data holds: named, exit 0 (as the full run)
    assert r.output.endswith("Warning: 1 blunder(s) remain in the adjustment.\n")
    assert "Traceback" not in r.output and "internal error" not in r.output
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert summary["mean_sd_free_m"] == {"E": None, "N": None, "h": None}
    assert "Mean sd of free points (m)     E -  N -  h -\n" in r.output
    assert "RMS sd of all points (m)       E -  N -  h -  (Appendix 2 'pontos livres')\n" in r.output
    # the figures that were computed read as in the full run
    full = gps_run[0].output
    for label in ("Control residuals sd (m)", "Variance factor a posteriori", "Chi-square range (5%)"):
        assert next(ln for ln in r.output.splitlines() if ln.startswith(label)) == \
            next(ln for ln in full.splitlines() if ln.startswith(label))


def test_report_writes_every_missing_figure_as_a_dash(gps_run):
    from lidarcat.cli.adjust import format_report
    from lidarcat.survey.selfcal import format_parameters

    _, out = gps_run
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    for key in ("sd_control_residuals_m", "mean_sd_free_m", "rms_sd_points_m"):
        summary[key] = {"E": None, "N": None, "h": None}
    for key in ("sigma0_sq", "vtpv", "chi2_lower", "chi2_upper", "chi2_lower_fisher", "chi2_upper_fisher", "elapsed_s"):
        summary[key] = None
    summary["rms_image_residuals_mm"]["1"] = {"x": None, "y": None}
    summary["snooping"].update(level=None, power=None)
    for b in summary["blunders"]:
        b.update(w=None, redundancy=None, estimated_error={"x": None, "y": 0.01})
    text = format_report(summary)
    assert "Control residuals sd (m)       E -  N -  h -" in text
    assert "Chi-square range (5%)         - - -  (Fisher approx. - - -): accepted" in text
    assert "alpha -, power -;" in text and "w      -  r -  error y +0.01 mm" in text
    assert f"{'':31}    1        -        -" in text
    doc = {"additional_parameters": {"dcs14n.k1": {"unit": "mm^-2", "estimate": None, "sd": None, "t": None,
                                                   "significant": False}},
           "parameters_off": {"vtpv": None, "dof": 128}, "parameters_on": {"vtpv": 1.5, "dof": 127}}
    assert format_parameters(doc).splitlines()[2:] == [
        "  dcs14n.k1              mm^-2               -          -       -  no       +0.000 (None photo None)",
        "v'Pv without / with the parameters: - (dof 128) / 1.50 (dof 127)"]
