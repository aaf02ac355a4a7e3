"""``lidarcat assess`` end to end: thesis GPS run, JSON layout, report, errors."""

from __future__ import annotations

import json
import shutil

import pytest
from click.testing import CliRunner

from conftest import DATA, THESIS_SURVEY
from lidarcat.cli.main import cli

POINTS = DATA / "report" / "points.csv"


def _run(args):
    return CliRunner().invoke(cli, ["assess", *args])


def test_text_output_thesis_gps_run():
    r = _run([str(POINTS), str(THESIS_SURVEY), "--contour-interval", "2", "--plotting-position", "hazen"])
    assert r.exit_code == 0, r.output
    assert "13 check points; discrepancies reference minus adjusted (m)" in r.output
    # Table 7 mean / sd rows (E, N, h)
    assert "E               0.056    0.119" in r.output
    assert "h              -0.397    0.476" in r.output
    assert "pec        1:2000 planimetric: class A; altimetric: class A" in r.output
    assert "h t=-3.0037/1.7823 failed" in r.output


def test_json_layout_scripts_rely_on():
    r = _run([str(POINTS), str(THESIS_SURVEY / "ground_points.csv"), "--scale", "2000", "--contour-interval", "2",
              "--standard", "pec", "--standard", "nssda", "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    for comp in ("E", "N", "h", "planimetric"):
        assert set(doc["summary"][comp]) >= {"n", "mean", "std", "rmse", "max_abs"}
        assert doc["summary"][comp]["n"] == 13
    for comp in ("planimetric", "h"):
        assert set(doc["tests"]["filliben"][comp]) >= {"r", "critical", "passed"}
        assert set(doc["tests"]["chi2_precision"][comp]) >= {"chi2", "critical", "passed", "sigma_bound"}
    for comp in ("E", "N", "h"):
        assert set(doc["tests"]["trend_t"][comp]) >= {"t", "critical", "passed"}
    assert sorted(doc["standards"]) == ["nssda", "pec"]
    assert doc["standards"]["pec"]["class"] == {"altimetric": "A", "planimetric": "A"}
    assert doc["summary"]["h"]["mean"] == pytest.approx(-0.397, abs=5e-4)


def test_points_option_and_report(tmp_path):
    out = tmp_path / "rep.html"
    r = _run([str(POINTS), str(THESIS_SURVEY), "--points", "603,605", "--points", "606", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["summary"]["E"]["n"] == 3
    assert doc["tests"]["filliben"]["h"]["critical"] == pytest.approx(0.891)  # n = 3
    assert doc["report"]["html"] == str(out)
    html = out.read_text()
    assert '<section id="exterior-orientation">' in html and "677344.860" in html  # adjustment folder found
    assert '<section id="qq-plots">' in html


def test_adjust_output_folder_as_input(tmp_path):
    folder = tmp_path / "gps"
    shutil.copytree(DATA / "report", folder)
    r = _run([str(folder), str(THESIS_SURVEY / "ground_points.csv"), "--standard", "pec", "-o", str(tmp_path / "r")])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "r" / "report.html").is_file()


def test_consistency_test_uses_the_covariance_beside_the_points(tmp_path):
    from lidarcat.survey import adjust_survey
    from lidarcat.survey.folder import Survey

    adjust_survey(Survey.load(THESIS_SURVEY), control="gps", outdir=tmp_path / "gps")
    assert (tmp_path / "gps" / "check_covariance.csv").is_file()
    r = _run([str(tmp_path / "gps" / "points.csv"), str(THESIS_SURVEY), "--json"])
    assert r.exit_code == 0, r.output
    cons = json.loads(r.output)["tests"]["consistency"]["ENh"]
    assert cons["df"] == 3 * 13 and cons["applicable"]
    r = _run([str(tmp_path / "gps" / "points.csv"), str(THESIS_SURVEY)])
    assert "consistency" in r.output and "ENh chi2=" in r.output
    bad = tmp_path / "cov.csv"
    bad.write_text("point_a,point_b\n")
    r = _run([str(tmp_path / "gps" / "points.csv"), str(THESIS_SURVEY), "--covariance", str(bad)])
    assert r.exit_code == 2 and "cov.csv" in r.output and "Traceback" not in r.output


def test_mismatched_ids_is_one_line_error(tmp_path):
    ref = tmp_path / "ref.csv"
    ref.write_text("point,E,N,h\n603,0,0,0\n")
    r = _run([str(POINTS), str(ref)])
    assert r.exit_code == 2
    assert "Traceback" not in r.output
    assert "Error: check point(s) 605, 606, 615" in r.output and "ref.csv" in r.output
    r2 = _run([str(POINTS), str(ref), "--points", "603,999"])
    assert r2.exit_code == 2
    assert r2.output == (f"Error: requested check point(s) not in the adjusted points ({POINTS}): 999; "
                         f"not in the reference ({ref}): 999\n")


def test_help_teaches_units_and_example():
    r = _run(["--help"])
    assert r.exit_code == 0
    assert "Metres" in r.output and "Examples:" in r.output and "--contour-interval" in r.output


def test_option_choices_are_the_library_ones():
    # the command keeps its own copies so that `assess --help` does not import scipy; they must not drift
    from lidarcat.accuracy.checkpoints import PLOTTING_POSITIONS, SIGNS
    from lidarcat.cli.assess import assess
    from lidarcat.accuracy.standards import STANDARD_NAMES

    choices = {p.name: tuple(p.type.choices) for p in assess.params if hasattr(p.type, "choices")}
    assert choices == {"standards": STANDARD_NAMES, "plotting_position": PLOTTING_POSITIONS, "sign": SIGNS}


def test_assess_and_run_share_one_contour_interval_default(tmp_path):
    """The same adjustment gets the same PEC classes from `assess` and from `run` without options:
    one default (2 m at 1:2000, the thesis's), stated in both --help texts and in the report."""
    from lidarcat.survey.folder import DEFAULT_CONTOUR_INTERVAL_M, DEFAULT_SCALE, AssessmentSettings

    assert (AssessmentSettings().scale, AssessmentSettings().contour_interval_m) == (DEFAULT_SCALE,
                                                                                   DEFAULT_CONTOUR_INTERVAL_M)
    assert (DEFAULT_SCALE, DEFAULT_CONTOUR_INTERVAL_M) == (2000.0, 2.0)
    for cmd, text in (("assess", "Default: 2 m (the thesis's; the same default as `lidarcat run`"),
                      ("run", "else 2 m (the thesis's; the same default as `lidarcat assess`)")):
        out = " ".join(CliRunner().invoke(cli, [cmd, "--help"], terminal_width=200).output.split())
        assert text in out, cmd
    r = _run([str(POINTS), str(THESIS_SURVEY), "--json", "-o", str(tmp_path / "rep")])
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert doc["settings"]["contour_interval_m"] == 2.0 and doc["settings"]["scale"] == 2000
    # at 1:2000 the altimetric class of the thesis's GPS run depends on the interval: 2 m gives A, 1 m B or worse
    assert doc["standards"]["pec"]["class"]["altimetric"] == "A"
    one = json.loads(_run([str(POINTS), str(THESIS_SURVEY), "--json", "--contour-interval", "1"]).output)
    assert one["standards"]["pec"]["class"]["altimetric"] != "A"
    md = (tmp_path / "rep" / "report.md").read_text()
    assert ("Map scale 1:2000, contour interval 2 m for the altimetric classes. `lidarcat assess` and "
            "`lidarcat run` share the defaults 1:2000 and 2 m") in md


def test_text_output_explains_the_confidence_labels():
    r = _run([str(POINTS), str(THESIS_SURVEY)])
    assert r.exit_code == 0, r.output
    assert "pec        1:2000 planimetric: class A; altimetric: class A [P (primary text read)]" in r.output
    legend = next(ln for ln in r.output.splitlines() if ln.startswith("  confidence / tags like [K]:"))
    assert "K domain knowledge, not confirmed against the standard" in legend
    assert "STANDARDS.md: docs/standards.md, installed as lidarcat/standards_data/STANDARDS.md" in legend


def test_without_the_covariance_file_the_output_says_why_the_consistency_test_did_not_run(tmp_path):
    # e.g. an adjustment with more check points than lidarcat adjust writes check_covariance.csv for
    from lidarcat.survey import MAX_JOINT_COVARIANCE_POINTS, adjust_survey
    from lidarcat.survey.folder import Survey

    adjust_survey(Survey.load(THESIS_SURVEY), control="gps", outdir=tmp_path / "gps")
    (tmp_path / "gps" / "check_covariance.csv").unlink()
    r = _run([str(tmp_path / "gps"), str(THESIS_SURVEY)])
    assert r.exit_code == 0, r.output
    assert r.output.splitlines()[-1] == (
        f"note: consistency test (d'C^-1d) not run: {tmp_path / 'gps' / 'check_covariance.csv'} does not exist "
        f"(lidarcat adjust writes it for 1 to {MAX_JOINT_COVARIANCE_POINTS} check points with --precision all; "
        "lidarcat run computes the test in memory for any number of check points)")
    doc = json.loads(_run([str(tmp_path / "gps"), str(THESIS_SURVEY), "--json"]).output)
    assert doc["consistency_not_run"].startswith("consistency test (d'C^-1d) not run")
    assert "consistency" not in doc["tests"]


# ------------------------------------------------------------------ bad covariance and reference values (issue 24)
@pytest.fixture(scope="module")
def gps_adjustment(tmp_path_factory):
    from lidarcat.survey import adjust_survey
    from lidarcat.survey.folder import Survey

    out = tmp_path_factory.mktemp("assess") / "gps"
    adjust_survey(Survey.load(THESIS_SURVEY), control="gps", outdir=out)
    return out


def _with_cells(src, dest, name, edits):
    """Copy the adjustment folder *src* to *dest*, setting cells {(row, column): text} of CSV *name*
    (row 1 is the first data row); return the edited file."""
    import csv
    import io

    shutil.copytree(src, dest)
    rows = list(csv.reader(io.StringIO((dest / name).read_text(encoding="utf-8"))))
    for (i, col), text in edits.items():
        rows[i][rows[0].index(col)] = text
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    (dest / name).write_text(buf.getvalue(), encoding="utf-8")
    return dest / name


def _sym(i, a, b, v):
    return {(i, f"c_{a}{b}"): v, (i, f"c_{b}{a}"): v}


@pytest.mark.parametrize("edits, message", [
    # the reproducer: an entry near the float maximum overflowed to inf in the test (a traceback)
    ({(1, "c_EE"): "1e308"}, ":2: field 'c_EE': 1e+308 m^2 is beyond any covariance of an adjusted point "
                             "(|c| <= 1e+06 m^2, an sd of 1000 m)"),
    ({(2, "c_hN"): "-1e308"}, ":3: field 'c_hN': -1e+308 m^2 is beyond any covariance of an adjusted point "
                              "(|c| <= 1e+06 m^2, an sd of 1000 m)"),
    ({(1, "c_EE"): "inf"}, ":2: field 'c_EE': 'inf' is not a finite number"),
    ({(1, "c_NN"): "1e-300"}, ":2: field 'c_NN': point 603: variance 1e-300 m^2 is below any adjusted point's "
                              "(1e-12 m^2, an sd of 1e-06 m)"),
    ({(1, "c_EN"): "0.5"}, ":2: point 603: its own block is not symmetric (c_EN = c_NE, c_Eh = c_hE, c_Nh = c_hN)"),
    (_sym(1, "E", "N", "0.5"), ":2: points 603, 603: covariance 0.5 m^2 exceeds the product of the two sds "
                               "(0.0423183 m^2): not a covariance matrix"),
    ({(2, "c_EE"): "0.5"}, ":3: points 603, 605: covariance 0.5 m^2 exceeds the product of the two sds "
                           "(0.0388183 m^2): not a covariance matrix"),
    # every |c_ij| <= sd_i sd_j, but correlations 0.99, 0.99, -0.99 have no positive definite matrix
    ({**_sym(1, "E", "N", repr(0.99 * (0.05169242301552696 * 0.034644050428048564) ** 0.5)),
      **_sym(1, "E", "h", repr(0.99 * (0.05169242301552696 * 1.0372325902840882) ** 0.5)),
      **_sym(1, "N", "h", repr(-0.99 * (0.034644050428048564 * 1.0372325902840882) ** 0.5))},
     ": the joint covariance of 603, 605, 606, 615, 616 ... is not positive definite: not the covariance of an "
     "adjustment (edited by hand?)"),
])
def test_bad_covariance_entry_is_a_located_error(tmp_path, gps_adjustment, edits, message):
    cov = _with_cells(gps_adjustment, tmp_path / "gps", "check_covariance.csv", edits)
    r = _run([str(tmp_path / "gps"), str(THESIS_SURVEY)])
    assert r.exit_code == 2, r.output
    assert r.output == f"Error: {cov}{message}\n"


@pytest.mark.parametrize("column, value, message", [
    ("sd_E", "1e308", "field 'sd_E': 1e+308 m is not a standard deviation (sane values lie in 0..1000 m)"),
    ("sd_h", "-0.1", "field 'sd_h': -0.1 m is not a standard deviation (sane values lie in 0..1000 m)"),
    ("E", "1e300", "field 'E': 1e+300 m is not a coordinate (sane values lie in -4e+08..4e+08 m)"),
])
def test_reference_values_beyond_any_survey_are_located_errors(tmp_path, gps_adjustment, column, value, message):
    ref = tmp_path / "ref.csv"
    lines = (THESIS_SURVEY / "ground_points.csv").read_text(encoding="utf-8").splitlines()
    header = next(ln for ln in lines if ln.startswith("point,")).split(",")
    k = next(i for i, ln in enumerate(lines) if ln.startswith("603,"))
    row = lines[k].split(",")
    row[header.index(column)] = value
    lines[k] = ",".join(row)
    ref.write_text("\n".join(lines) + "\n", encoding="utf-8")
    r = _run([str(gps_adjustment), str(ref)])
    assert r.exit_code == 2, r.output
    assert r.output == f"Error: {ref}:{k + 1}: {message}\n"


def test_the_consistency_test_survives_entries_near_the_float_maximum():
    import numpy as np

    from lidarcat.accuracy.statistics import covariance_consistency_test

    c = np.diag([1e308, 1e308, 1e308])
    c[0, 1] = c[1, 0] = 1e308
    r = covariance_consistency_test(np.array([[0.1, 0.1, 0.1]]), c)
    assert not r.applicable
