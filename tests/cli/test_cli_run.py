"""`lidarcat run`: exit codes, --json, reuse, and interruption by SIGINT."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import THESIS_SURVEY

from lidarcat.cli.main import cli


def _part_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if ".part" in p.name]


@pytest.fixture
def survey_copy(tmp_path) -> Path:
    """A writable copy of the thesis survey folder (tmp_path/s)."""
    survey = tmp_path / "s"
    shutil.copytree(THESIS_SURVEY, survey)
    return survey


def test_run_thesis_json_then_reuse(tmp_path):
    runner = CliRunner()
    res = runner.invoke(cli, ["run", "-o", str(tmp_path / "out"), "--json"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output)
    assert summary["ok"] is True
    assert summary["runs"]["gps"]["adjustment"]["dof"] == 128
    assert summary["stages_skipped"] == ["extract"]
    assert (tmp_path / "out" / "report" / "index.html").is_file()
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["ok"] is True

    res = runner.invoke(cli, ["run", "-o", str(tmp_path / "out")])
    assert res.exit_code == 0, res.output
    assert "adjust-gps         reused" in res.output
    assert "run gps: dof 128" in res.output
    assert res.output.rstrip().endswith("ok")

    # a different map scale changes only the assessment (and the report built from it)
    res = runner.invoke(cli, ["run", "-o", str(tmp_path / "out"), "--scale", "5000", "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["stages_ran"] == ["assess-gps", "assess-lidar", "report"]
    assessment = json.loads((tmp_path / "out" / "assess-gps" / "assessment.json").read_text())
    assert assessment["settings"]["scale"] == 5000
    # --force: test_run_default_outdir_of_a_survey_folder (a gps-only run, a third cheaper)


def _gps_only(survey: Path) -> None:
    """Leave the lidar set out of the survey's control_sets.csv: its adjustment and assessment (a third of a
    thesis run) are not what the tests that call this assert."""
    cs = survey / "control_sets.csv"
    cs.write_text("".join(line for line in cs.read_text().splitlines(keepends=True) if not line.startswith("lidar,")))


def test_run_failed_stage_exits_1(tmp_path, survey_copy):
    survey = survey_copy
    _gps_only(survey)
    with open(survey / "control_sets.csv", "a") as fh:
        fh.write("weak,601,control,0.25,0.25,0.25\nweak,603,check,,,\n")
    res = CliRunner().invoke(cli, ["run", str(survey), "-o", str(tmp_path / "out")])
    assert res.exit_code == 1, res.output
    assert "adjust-weak        failed" in res.output
    assert "FAILED: adjust-weak" in res.output
    assert "Traceback" not in res.output


def test_run_invalid_survey_exits_2(tmp_path, survey_copy):
    survey = survey_copy
    (survey / "photos.csv").write_text("photo,camera\n1,nosuchcamera\n")
    res = CliRunner().invoke(cli, ["run", str(survey), "-o", str(tmp_path / "out")])
    assert res.exit_code == 2
    assert res.output.startswith("Error: ") and "photos.csv" in res.output
    assert "Traceback" not in res.output


def test_run_unwritable_outdir_exits_2(tmp_path):
    (tmp_path / "file").write_text("x")
    res = CliRunner().invoke(cli, ["run", "-o", str(tmp_path / "file" / "out")])
    assert res.exit_code == 2
    assert res.output == (f"Error: {tmp_path / 'file' / 'out'}: cannot write the output folder (Not a "
                          "directory); choose another with -o/--outdir\n")


def test_run_default_outdir_of_a_survey_folder(tmp_path, survey_copy):
    survey = survey_copy
    _gps_only(survey)
    res = CliRunner().invoke(cli, ["run", str(survey), "--json"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.output)["outdir"] == str(survey / "out")
    assert json.loads((survey / "out" / "summary.json").read_text())["runs"]["gps"]["adjustment"]["dof"] == 128
    res = CliRunner().invoke(cli, ["run", str(survey), "--force", "--json"])   # --force: every stage again
    assert res.exit_code == 0
    assert "adjust-gps" in json.loads(res.output)["stages_ran"]


@pytest.mark.slow
def test_sigint_leaves_no_partial_output_and_rerun_finishes(tmp_path):
    """Interrupt `lidarcat run` while a stage is running; nothing half-written stays behind."""
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cmd = [sys.executable, "-m", "lidarcat.cli.main", "run", "-o", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    log = out / "lidarcat.log"
    deadline = time.monotonic() + 600    # hang guards only: under a load of 20 the run is 10x slower
    # wait until the first adjustment has started, then interrupt it
    while time.monotonic() < deadline and proc.poll() is None:
        if log.is_file() and "stage adjust-gps: running" in log.read_text():
            break
        time.sleep(0.005)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=600)
    # lidarcat reports an interrupt in one line with exit code 130
    interrupted = proc.returncode == 130
    if interrupted:
        assert stderr.strip().splitlines()[-1] == b"Interrupted; no partial output was kept."
    if interrupted:
        assert b"Traceback" not in stderr
    else:  # the run beat the signal: it must have finished cleanly
        assert proc.returncode == 0, stderr.decode()
    assert _part_files(out) == []
    # every stage record describes complete outputs
    records = {p.stem: json.loads(p.read_text()) for p in (out / ".stages").glob("*.json")}
    for rec in records.values():
        for rel in rec["outputs"]:
            assert (out / rel).is_file(), rel
    if interrupted:
        assert "report" not in records
        assert not (out / "summary.json").exists()
    # running again finishes the job
    res = subprocess.run(cmd + ["--json"], capture_output=True, env=env, timeout=1200)
    assert res.returncode == 0, res.stderr.decode()
    summary = json.loads(res.stdout)
    assert summary["ok"] is True
    assert summary["runs"]["gps"]["adjustment"]["dof"] == 128
    done = set(summary["stages_ran"]) | set(summary["stages_reused"])
    assert {"camera", "adjust-gps", "adjust-lidar", "report"} <= done
    assert set(summary["stages_reused"]) <= set(records)
    assert _part_files(out) == []


@pytest.mark.slow
def test_run_from_an_installed_layout_finds_the_embedded_block(tmp_path):
    """As after a non-editable `pip install .`: package only, thesis data as lidarcat/_data/thesis."""
    import tomllib

    from conftest import ROOT

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    force = pyproject["tool"]["hatch"]["build"]["targets"]["wheel"]["force-include"]
    assert force["data/thesis"] == "lidarcat/_data/thesis"
    site = tmp_path / "site"
    shutil.copytree(ROOT / "src" / "lidarcat", site / "lidarcat",
                    ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(ROOT / "data" / "thesis", site / "lidarcat" / "_data" / "thesis")
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = dict(os.environ, PYTHONPATH=str(site))
    res = subprocess.run([sys.executable, "-m", "lidarcat.cli.main", "run", "--json"], cwd=work,
                         capture_output=True, env=env, timeout=300)
    assert res.returncode == 0, res.stderr.decode()
    summary = json.loads(res.stdout)
    assert summary["survey"]["root"] == str(site / "lidarcat" / "_data" / "thesis")
    assert summary["survey"]["embedded"] is True
    # the default output folder of the embedded block is ./lidarcat-out
    assert (work / "lidarcat-out" / "report" / "index.html").is_file()
    assert summary["runs"]["gps"]["adjustment"]["dof"] == 128


def test_run_whose_adjustment_fails_its_chi_square_test_does_not_end_ok(tmp_path):
    """Image sd halved (0.003 mm instead of the thesis's 0.006): v'Pv is four times too large, both
    adjustments fail the chi-square test of the variance factor. Every stage still runs, but the
    run line, the last line, the exit code (3), summary.json and the report say so."""
    survey = tmp_path / "thesis"
    shutil.copytree(THESIS_SURVEY, survey)
    toml = survey / "survey.toml"
    toml.write_text(toml.read_text().replace("image_sd_mm = 0.006", "image_sd_mm = 0.003"))
    r = CliRunner().invoke(cli, ["run", str(survey), "-o", str(tmp_path / "out")])
    assert r.exit_code == 3, r.output
    lines = r.output.splitlines()
    assert lines[-1] == ("STATISTICAL TEST FAILED: every stage ran, but adjust-gps, adjust-lidar failed its "
                         "chi-square test (exit code 3)")
    assert "ok" not in lines
    run_gps = next(ln for ln in lines if ln.startswith("  run gps:"))
    assert "chi2 FAILED" in run_gps
    fail = next(ln for ln in lines if ln.startswith("  statistical test failed, adjust-gps:"))
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    adj = summary["runs"]["gps"]["adjustment"]
    assert adj["vtpv"] > 3 * 148.30 and adj["chi2_pass"] is False  # the image residuals now weigh 4 x
    assert (f"chi-square test of the variance factor failed: v'Pv {adj['vtpv']:.2f} outside [98.58, 161.21] "
            f"(128 dof, 0.05 level; sigma0^2 {adj['sigma0_sq']:.3f})") in fail
    assert summary["status"] == "test failed" and summary["ok"] is False and summary["failed"] == []
    assert [t.split(":")[0] for t in summary["tests_failed"]] == ["adjust-gps", "adjust-lidar"]
    md = (tmp_path / "out" / "report" / "index.md").read_text()
    assert md.splitlines()[2].startswith("**Statistical test failed** (every stage ran; read the results")
    # the thesis settings pass (exit 0, last line ok): covered by test_run_thesis_block_default_outdir
