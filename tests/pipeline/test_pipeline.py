"""The stage runner (caching, atomicity, failures) and `run_pipeline` on the thesis block."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import THESIS_SURVEY, THESIS_TABLES

from lidarcat.errors import LidarcatError, SurveyError
from lidarcat.pipeline import Stage, plan_pipeline, run_pipeline, run_stages
from lidarcat.survey.folder import Survey


# --------------------------------------------------------------------------- helpers

def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _no_part_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(".part") or ".part" in p.name]


class _Counter:
    """Stage bodies that count their calls and copy an input file."""

    def __init__(self, src: Path):
        self.src = src
        self.calls: dict[str, int] = {}

    def body(self, name: str, fail: Exception | None = None):
        def run(ctx, tmp: Path) -> dict:
            self.calls[name] = self.calls.get(name, 0) + 1
            if fail is not None:
                (tmp / "partial.txt").write_text("half")
                raise fail
            text = self.src.read_text()
            if name == "second":
                text = (ctx.folder("first") / "copy.txt").read_text() + "+"
            (tmp / "copy.txt").write_text(text)
            (tmp / "sub").mkdir()
            (tmp / "sub" / "n.txt").write_text(str(len(text)))
            return {"length": len(text)}
        return run

    def stages(self, **kw) -> list[Stage]:
        return [
            Stage("first", "first", self.body("first"), inputs=lambda ctx: [self.src],
                  params={"p": kw.get("p", 1)}),
            Stage("second", "second", self.body("second"), requires=("first",)),
        ]


@pytest.fixture
def counter(tmp_path) -> _Counter:
    """A _Counter whose input file tmp_path/input.txt holds "abc"."""
    src = tmp_path / "input.txt"
    src.write_text("abc")
    return _Counter(src)


@pytest.fixture
def survey_copy(tmp_path) -> Path:
    """A writable copy of the thesis survey folder (tmp_path/thesis)."""
    survey = tmp_path / "thesis"
    shutil.copytree(THESIS_SURVEY, survey)
    return survey


# --------------------------------------------------------------------------- runner

def test_stages_run_then_reuse_then_rerun_on_change(tmp_path, counter):
    c, src = counter, counter.src
    out = tmp_path / "out"
    recs = run_stages(c.stages(), out)
    assert [r.status for r in recs] == ["ran", "ran"]
    assert (out / "second" / "copy.txt").read_text() == "abc+"
    assert recs[1].outputs == ("second/copy.txt", "second/sub/n.txt")
    assert recs[0].result == {"length": 3}
    assert (out / ".stages" / "first.json").is_file()

    recs = run_stages(c.stages(), out)
    assert [r.status for r in recs] == ["reused", "reused"]
    assert recs[1].result == {"length": 4}
    assert c.calls == {"first": 1, "second": 1}

    # a parameter change reruns the stage and, through its outputs, the next one
    recs = run_stages(c.stages(p=2), out)
    assert [r.status for r in recs] == ["ran", "reused"]  # same output content: second reused
    src.write_text("abcd")
    recs = run_stages(c.stages(p=2), out)
    assert [r.status for r in recs] == ["ran", "ran"]
    assert (out / "second" / "copy.txt").read_text() == "abcd+"
    recs = run_stages(c.stages(p=2), out, force=True)
    assert [r.status for r in recs] == ["ran", "ran"]
    assert c.calls == {"first": 4, "second": 3}


def test_tampered_or_missing_output_reruns_stage(tmp_path, counter):
    c = counter
    out = tmp_path / "out"
    run_stages(c.stages(), out)
    (out / "second" / "copy.txt").write_text("edited by hand")
    assert [r.status for r in run_stages(c.stages(), out)] == ["reused", "ran"]
    (out / "first" / "sub" / "n.txt").unlink()
    assert [r.status for r in run_stages(c.stages(), out)] == ["ran", "reused"]
    assert (out / "first" / "sub" / "n.txt").read_text() == "3"


def test_failed_stage_keeps_no_output_and_skips_dependents(tmp_path, counter):
    c = counter
    stages = [Stage("first", "first", c.body("first", LidarcatError("no roof at (1, 2)"))),
              Stage("second", "second", c.body("second"), requires=("first",)),
              Stage("third", "third", c.body("third", RuntimeError("bug"))),
              Stage("fourth", "fourth", c.body("fourth"), skip_reason="no LiDAR tiles")]
    recs = run_stages(stages, tmp_path / "out")
    assert [r.status for r in recs] == ["failed", "skipped", "failed", "skipped"]
    assert recs[0].reason == "no roof at (1, 2)"
    assert recs[1].reason == "needs first (first failed)"
    assert recs[2].reason == "RuntimeError: bug"
    assert recs[3].reason == "no LiDAR tiles"
    assert "fourth" not in c.calls
    assert not (tmp_path / "out" / "first").exists()
    assert not (tmp_path / "out" / ".stages" / "first.json").exists()
    assert _no_part_files(tmp_path / "out") == []


def test_interrupted_stage_leaves_nothing_and_next_run_finishes(tmp_path, counter):
    c, src = counter, counter.src
    out = tmp_path / "out"
    run_stages(c.stages(), out)
    src.write_text("changed")
    stages = c.stages()
    stages[1] = Stage("second", "second", c.body("second", KeyboardInterrupt()), requires=("first",))
    with pytest.raises(KeyboardInterrupt):
        run_stages(stages, out)
    assert _no_part_files(out) == []
    # the old outputs of the interrupted stage are intact, its record is gone
    assert (out / "second" / "copy.txt").read_text() == "abc+"
    assert not (out / ".stages" / "second.json").exists()
    recs = run_stages(c.stages(), out)
    assert [r.status for r in recs] == ["reused", "ran"]
    assert (out / "second" / "copy.txt").read_text() == "changed+"


def test_leftovers_of_a_killed_run_are_removed(tmp_path, counter):
    """After SIGKILL nothing can clean up; the next run removes the temporary files."""
    out = tmp_path / "out"
    (out / ".first.abc123.part" / "sub").mkdir(parents=True)
    (out / ".first.abc123.part" / "sub" / "half.txt").write_text("half")
    (out / ".stages").mkdir()
    (out / ".stages" / ".first.json.xyz.part").write_text("{")
    (out / ".summary.json.q.part").write_text("{")
    (out / ".unrelated.part").write_text("not ours")
    recs = run_stages(counter.stages(), out)
    assert [r.status for r in recs] == ["ran", "ran"]
    assert _no_part_files(out) == [out / ".unrelated.part"]


def test_stale_outputs_of_a_stage_are_removed(tmp_path):
    out = tmp_path / "out"

    def writes(names):
        def run(ctx, tmp):
            for n in names:
                (tmp / n).write_text(n)
            return {}
        return run

    run_stages([Stage("s", "s", writes(["a.txt", "b.txt"]), params={"v": 1})], out)
    recs = run_stages([Stage("s", "s", writes(["a.txt"]), params={"v": 2})], out)
    assert recs[0].outputs == ("s/a.txt",)
    assert sorted(p.name for p in (out / "s").iterdir()) == ["a.txt"]


def test_failure_removes_results_of_an_earlier_run(tmp_path, counter):
    c, src = counter, counter.src
    out = tmp_path / "out"
    run_stages(c.stages(), out)
    assert (out / "first" / "copy.txt").is_file()
    src.write_text("changed")
    recs = run_stages([Stage("first", "first", c.body("first", LidarcatError("broken")),
                             inputs=lambda ctx: [src])], out)
    assert recs[0].status == "failed"
    assert not (out / "first").exists()
    assert (out / "second" / "copy.txt").is_file()  # other stages are not touched


def test_duplicate_stage_names_rejected(tmp_path):
    s = Stage("x", "x", lambda ctx, tmp: {})
    with pytest.raises(ValueError, match="duplicate stage names"):
        run_stages([s, s], tmp_path)


# --------------------------------------------------------------------------- thesis block

@pytest.fixture(scope="module")
def thesis_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("thesis") / "out"
    return run_pipeline(None, out)


def test_thesis_run_stages_and_summary(thesis_run):
    r = thesis_run
    assert r.ok, r.summary
    status = {s.name: s.status for s in r.stages}
    assert status == {"camera": "ran", "extract": "skipped", "adjust-gps": "ran",
                      "adjust-lidar": "ran", "assess-gps": "ran", "assess-lidar": "ran",
                      "compare-gps-lidar": "ran", "thesis": "ran", "report": "ran"}
    assert "no LiDAR tiles" in r.stage("extract").reason
    summary = json.loads((r.outdir / "summary.json").read_text())
    assert summary["ok"] is True and summary["failed"] == []
    assert summary["stages_skipped"] == ["extract"]
    assert (r.outdir / "lidarcat.log").read_text().count("stage adjust-gps: ran") == 1
    assert _no_part_files(r.outdir) == []
    # the camera stage reproduces the printed corrected coordinates (Appendix 1, 3 decimals;
    # photo 5 point 662 is a known misprint of 0.003 mm)
    cam = r.stage("camera").result
    assert cam["n_points"] == 153 and cam["n_compared_with_file"] == 153
    assert cam["max_abs_diff_file_mm"] < 0.0035


def test_thesis_gps_run_matches_appendix_2_1(thesis_run):
    published = json.loads((THESIS_TABLES / "appendix2_1_gps.json").read_text())["2.1_gps"]
    for adj in (thesis_run.summary["runs"]["gps"]["adjustment"],
                json.loads((thesis_run.outdir / "adjust-gps" / "summary.json").read_text())):
        assert adj["dof"] == published["dof"] == 128
        assert abs(adj["vtpv"] - 148.35) <= 0.5
        assert abs(adj["sigma0_sq"] - 1.16) <= 0.01
        assert adj["chi2_pass"] is True


def test_thesis_gps_run_matches_table_6(thesis_run):
    eop = {r["photo"]: r for r in _csv(thesis_run.outdir / "adjust-gps" / "eop.csv")}
    for row in _csv(THESIS_TABLES / "table6_eop_gps.csv"):
        got = eop[row["photo"]]
        for key, tol in (("X0", 0.10), ("Y0", 0.10), ("Z0", 0.03)):
            assert abs(float(got[key]) - float(row[key])) <= tol, (row["photo"], key)
        for key in ("omega", "phi", "kappa"):
            assert abs(float(got[key]) - float(row[f"{key}_deg"])) <= 0.005, (row["photo"], key)


def test_thesis_gps_run_matches_appendix_3_1(thesis_run):
    pts = {r["point"]: r for r in _csv(thesis_run.outdir / "adjust-gps" / "points.csv")}
    rows = _csv(THESIS_TABLES / "appendix3_1_points_gps.csv")
    assert len(rows) == 54 and len(pts) == 54
    for row in rows:
        got = pts[row["point"]]
        for key, tol in (("E", 0.03), ("N", 0.03), ("h", 0.12)):
            assert abs(float(got[key]) - float(row[key])) <= tol, (row["point"], key)
        assert (got["role"] == "control") == (row["role"] == "control")


def test_thesis_gps_check_points_match_table_7(thesis_run):
    disc = {r["point"]: r for r in _csv(thesis_run.outdir / "assess-gps" / "discrepancies.csv")}
    table = _csv(THESIS_TABLES / "table7_check_gps.csv")
    points = [r for r in table if r["point"] not in ("mean", "std")]
    assert sorted(disc) == sorted(r["point"] for r in points)
    for row in points:
        got = disc[row["point"]]
        for key, tol in (("dE", 0.03), ("dN", 0.03), ("dh", 0.12)):
            assert abs(float(got[key]) - float(row[key])) <= tol, (row["point"], key)
    mean = next(r for r in table if r["point"] == "mean")
    check = thesis_run.summary["runs"]["gps"]["check"]
    assert check["n"] == 13
    np.testing.assert_allclose([check["mean_E_m"], check["mean_N_m"], check["mean_h_m"]],
                               [float(mean["dE"]), float(mean["dN"]), float(mean["dh"])], atol=0.03)
    # the report says the same
    report = json.loads((thesis_run.outdir / "report" / "report.json").read_text())
    assert report["runs"]["gps"]["check"]["n"] == 13
    assert report["runs"]["gps"]["adjustment"]["dof"] == 128


def test_thesis_comparison_of_the_two_runs(thesis_run):
    cmp_ = thesis_run.summary["comparison"]["gps-lidar"]
    assert cmp_["n_photos"] == 6
    # 54 points minus 8 GPS and 8 LiDAR control points are free in both runs
    assert cmp_["n_points"] == 38
    rows = _csv(thesis_run.outdir / "compare-gps-lidar" / "point_differences.csv")
    assert len(rows) == 38
    gps = {r["point"]: r for r in _csv(thesis_run.outdir / "adjust-gps" / "points.csv")}
    lid = {r["point"]: r for r in _csv(thesis_run.outdir / "adjust-lidar" / "points.csv")}
    for r in rows:
        assert abs(float(r["dE"]) - (float(gps[r["point"]]["E"]) - float(lid[r["point"]]["E"]))) < 1e-9
    # the LiDAR control (0.5 m plan) moves the photo centres by metres at most, not tens of metres
    assert cmp_["eop"]["dX0"]["max_abs"] < 5.0 and cmp_["eop"]["dkappa"]["max_abs"] < 0.1


def test_thesis_run_reuses_everything(thesis_run):
    again = run_pipeline(None, thesis_run.outdir)
    assert {s.status for s in again.stages} == {"reused", "skipped"}
    assert again.summary["runs"]["gps"]["adjustment"]["dof"] == 128
    assert again.summary["stages_ran"] == []


@pytest.mark.slow
def test_edited_control_set_reruns_dependent_stages(tmp_path, survey_copy):
    survey = survey_copy
    first = run_pipeline(survey, tmp_path / "out")
    assert first.ok
    text = (survey / "control_sets.csv").read_text().replace("lidar,702,check", "lidar,702,control")
    (survey / "control_sets.csv").write_text(text)
    second = run_pipeline(survey, tmp_path / "out")
    # every stage that reads the survey's files reruns
    assert second.stage("adjust-lidar").status == "ran"
    assert second.stage("assess-lidar").result["check"]["n"] == 30


@pytest.mark.slow
def test_failed_stage_gives_failed_summary(tmp_path, survey_copy):
    survey = survey_copy
    # a control set whose only control point is measured on no photo: datum defect
    with open(survey / "control_sets.csv", "a") as fh:
        fh.write("weak,601,control,0.25,0.25,0.25\nweak,603,check,,,\n")
    r = run_pipeline(survey, tmp_path / "out")
    assert not r.ok
    assert r.failed == ["adjust-weak"]
    assert r.stage("assess-weak").status == "skipped"
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["ok"] is False and summary["failed"] == ["adjust-weak"]
    assert not (tmp_path / "out" / "adjust-weak").exists()


def test_invalid_survey_raises_before_any_stage(tmp_path, survey_copy):
    survey = survey_copy
    (survey / "survey.toml").write_text((survey / "survey.toml").read_text() + "\n[bogus]\nx = 1\n")
    with pytest.raises(SurveyError, match="bogus"):
        run_pipeline(survey, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_plan_for_a_survey_with_one_control_set_and_no_pixels(survey_copy):
    survey = survey_copy
    rows = [ln for ln in (survey / "control_sets.csv").read_text().splitlines()
            if not ln.startswith("lidar,")]
    (survey / "control_sets.csv").write_text("\n".join(rows) + "\n")
    lines = (survey / "image_points.csv").read_text().splitlines()
    out = []
    for ln in lines:
        if ln.startswith("#"):
            out.append(ln)
            continue
        cells = ln.split(",")
        out.append(",".join(cells[:2] + cells[4:]))  # drop col_px, row_px
    (survey / "image_points.csv").write_text("\n".join(out) + "\n")
    plan = plan_pipeline(Survey.load(survey))
    names = [s.name for s in plan]
    assert names == ["camera", "extract", "adjust-gps", "assess-gps", "compare", "thesis", "report"]
    skipped = {s.name: s.skip_reason for s in plan if s.skip_reason}
    assert skipped == {
        "camera": "image_points has no pixel coordinates (col_px, row_px)",
        "extract": "the survey has no LiDAR tiles ([files] lidar) and no extraction jobs",
        "compare": "needs two control sets (runs) to compare; the survey has 1",
        "thesis": "needs the control sets gps and lidar of the thesis",
    }


def test_only_the_extraction_hashes_the_lidar_tiles(survey_copy):
    survey = survey_copy
    (survey / "tile.xyz").write_text("677757.8 7183482.0 922.0\n677758.8 7183482.0 922.5\n")
    (survey / "jobs.csv").write_text("point,E,N\n704,677757.8,7183482.0\n")
    text = (survey / "survey.toml").read_text().replace(
        'control_sets = "control_sets.csv"',
        'control_sets = "control_sets.csv"\nlidar = ["tile.xyz"]\nextraction_jobs = "jobs.csv"')
    (survey / "survey.toml").write_text(text)
    plan = {s.name: s for s in plan_pipeline(Survey.load(survey))}
    assert list(plan) == ["camera", "extract", "adjust-gps", "adjust-lidar", "adjust-lidar-extracted",
                          "assess-gps", "assess-lidar", "assess-lidar-extracted",
                          "compare-gps-lidar", "compare-gps-lidar-extracted", "thesis", "report"]
    assert plan["extract"].skip_reason is None
    tile = (survey / "tile.xyz").resolve()
    assert tile in {Path(p).resolve() for p in plan["extract"].inputs(None)}
    for name in ("camera", "adjust-gps", "adjust-lidar-extracted", "report"):
        assert tile not in {Path(p).resolve() for p in plan[name].inputs(None)}, name
    assert plan["adjust-lidar-extracted"].requires == ("extract",)


def test_a_second_run_on_the_same_output_folder_is_refused(tmp_path):
    import os
    import socket
    import subprocess

    out = tmp_path / "out"
    out.mkdir()
    lock = out / ".lidarcat.lock"
    host = socket.gethostname()
    lock.write_text(f"pid={os.getpid()} host={host} started=2026-11-22T08:00:00\n")   # a live run
    with pytest.raises(LidarcatError, match=rf"in use by another lidarcat run \(pid {os.getpid()} on "
                                            rf"{host}, started 2026-11-22T08:00:00\); .* delete .*lidarcat.lock"):
        run_pipeline(None, out)
    assert not (out / "summary.json").exists() and lock.is_file()
    lock.write_text("pid=123 host=some-other-node started=2026-11-22T08:00:00\n")   # cannot tell: refuse
    with pytest.raises(LidarcatError, match="pid 123 on some-other-node"):
        run_pipeline(None, out)
    dead = subprocess.Popen(["true"])
    dead.wait()
    lock.write_text(f"pid={dead.pid} host={host} started=2026-11-22T08:00:00\n")    # a run that died
    res = run_pipeline(None, out)
    assert res.ok and not lock.exists()


def test_assessment_table_of_survey_toml_sets_scale_and_level(tmp_path, survey_copy):
    survey = survey_copy
    toml = survey / "survey.toml"
    text = toml.read_text()  # the thesis's own [assessment] table is replaced
    toml.write_text(text[:text.index("\n[assessment]")] + '\n[assessment]\nscale = 5000\ncontour_interval_m = 5.0\n'
                                        'alpha = 0.05\npec_class = "B"\n')
    s = Survey.load(survey)
    assert (s.assessment.scale, s.assessment.contour_interval_m, s.assessment.alpha,
            s.assessment.pec_class) == (5000.0, 5.0, 0.05, "B")
    plan = {st.name: st for st in plan_pipeline(s)}
    assert plan["assess-gps"].params["scale"] == 5000.0 and plan["assess-gps"].params["alpha"] == 0.05
    over = {st.name: st for st in plan_pipeline(s, scale=1000)}
    assert over["assess-gps"].params["scale"] == 1000 and over["assess-gps"].params["contour_interval_m"] == 5.0
    res = run_pipeline(survey, tmp_path / "out")
    doc = json.loads((tmp_path / "out" / "assess-gps" / "assessment.json").read_text())
    assert doc["settings"]["scale"] == 5000 and doc["settings"]["alpha"] == 0.05
    assert doc["settings"]["pec_class"] == "B" and res.ok


def test_control_sets_sharing_an_output_folder_are_refused(survey_copy, tmp_path):
    with open(survey_copy / "control_sets.csv", "a") as fh:
        fh.write("a b,601,control,0.25,0.25,0.25\na_b,601,control,0.25,0.25,0.25\n")
    with pytest.raises(SurveyError) as ei:
        run_pipeline(survey_copy, tmp_path / "out")
    assert str(ei.value) == (f"{survey_copy / 'control_sets.csv'}: control sets 'a b' and 'a_b' would "
                             "share the output folder adjust-a_b; rename one (letters, digits, _ . - "
                             "are kept)")
    assert not (tmp_path / "out" / "adjust-a_b").exists()


def test_every_csv_output_of_the_run_opens_in_pandas_with_its_header_first(thesis_run):
    """pandas.read_csv with default arguments (as QGIS and GDAL read the first line as the header):
    the columns are the header line, numbers parse as numbers, notes live in the .csv.json sidecar."""
    pd = pytest.importorskip("pandas")
    csvs = sorted(thesis_run.outdir.rglob("*.csv"))
    folders = {p.relative_to(thesis_run.outdir).parts[0] for p in csvs}
    assert folders >= {"camera", "adjust-gps", "adjust-lidar", "assess-gps", "assess-lidar", "compare-gps-lidar"}
    for path in csvs:
        first = path.read_text(encoding="utf-8").splitlines()[0]
        assert not first.startswith("#"), path
        df = pd.read_csv(path)
        assert list(df.columns) == first.split(","), path
        assert len(df) > 0 and not any(str(c).startswith(("#", "Unnamed")) for c in df.columns), path
        numeric = [c for c in df.columns if c in ("E", "N", "h", "X0", "dE", "dh", "x_mm")]
        for c in numeric:
            assert pd.api.types.is_float_dtype(df[c]), (path, c)


def test_index_report_shows_the_figures_of_every_run(thesis_run):
    """index.html embeds (base64, opens offline) the block layout and the discrepancy plots of each
    run; index.md links the same PNG files of the runs' own reports."""
    import base64
    import re

    out = thesis_run.outdir / "report"
    md = (out / "index.md").read_text()
    links = re.findall(r"^!\[([^\]]+)\]\(([^)]+)\)$", md, re.M)
    runs = [(cap, src) for cap, src in links if not src.startswith("quality/")]   # issue 25: + the quality figures
    assert [cap.split(":")[0] for cap, _ in runs] == ["Run gps"] * 3 + ["Run lidar"] * 3
    for _, src in links:
        assert (out / src).resolve().is_file(), src
    html = (out / "index.html").read_text()
    imgs = re.findall(r"src='data:image/png;base64,([A-Za-z0-9+/=]+)'", html)
    assert len(imgs) == len(links) >= 6 + 5
    assert all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in imgs)
    assert "<figcaption>Run lidar: block layout (photo footprints, control, check and tie points)</figcaption>" in html
    assert not re.search(r"(src|href)='(https?:)?//", html)


def test_consistency_test_above_the_covariance_file_limit_is_computed_in_memory(thesis_run, tmp_path,
                                                                              monkeypatch):
    """Above MAX_JOINT_COVARIANCE_POINTS check points check_covariance.csv is not written; the adjust
    stage uses the joint covariance in memory and the run reports the same d'C^-1 d as with the file.
    (The limit is lowered to 5 so that the 13 GPS check points of the thesis exceed it.)"""
    import importlib

    from lidarcat import survey
    from lidarcat.stages import adjust as adjust_stage

    writer = importlib.import_module(survey.write_adjustment.__module__)  # where the limit is read

    want = thesis_run.summary["runs"]["gps"]["check"]["consistency"]
    assert (thesis_run.outdir / "adjust-gps" / "check_covariance.csv").is_file()
    monkeypatch.setattr(writer, "MAX_JOINT_COVARIANCE_POINTS", 5)
    res = run_pipeline(None, tmp_path / "memory")
    assert not (res.outdir / "adjust-gps" / "check_covariance.csv").exists()
    doc = json.loads((res.outdir / "adjust-gps" / "consistency.json").read_text())
    assert doc["applicable"] and "used in memory" in doc["details"]["covariance_source"]
    got = res.summary["runs"]["gps"]["check"]["consistency"]
    assert got["df"] == want["df"] == 39
    assert got["chi2"] == pytest.approx(want["chi2"], rel=1e-9) and got["passed"] == want["passed"]
    # beyond the memory bound the result says why (before any matrix is built)
    monkeypatch.setattr(adjust_stage, "CONSISTENCY_MEMORY_BYTES", 1000)
    checks = [f"c{i}" for i in range(13)]
    why = adjust_stage.consistency_in_memory(None, checks, Survey.load(None))
    assert why["applicable"] is False and why["statistic"] is None
    assert why["reason"] == ("not computed: the joint covariance of 13 check points needs 0.0 GiB in memory "
                             "(limit 0 GiB); assess a subset of the check points")


def test_demo_compare_never_prints_a_bare_nan(monkeypatch, tmp_path):
    import lidarcat.synthetic.survey
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    run = {"eo_max_abs_z": 1.0, "eo_rms_z": 0.5, "points_max_abs_z": 2.0, "points_rms_z": 0.9,
           "n_check": 600, "check_chi2": 1790.0, "check_chi2_joint": float("nan"),
           "check_chi2_joint_not_computed": "not computed: the joint covariance of 600 check points needs "
                                            "1.2 GiB in memory (limit 1 GiB)", "check_dof": 1800}
    monkeypatch.setattr(lidarcat.synthetic.survey, "compare_with_truth", lambda *a, **k: {"runs": {"gps": run},
                                                                               "extraction": {}})
    r = CliRunner().invoke(cli, ["demo", "compare", str(tmp_path)])
    assert r.exit_code == 0, r.output
    assert "nan" not in r.output.lower()
    assert ("check points d'C^-1d not computed: the joint covariance of 600 check points needs "
            "1.2 GiB in memory (limit 1 GiB) on 1800 dof") in r.output


def test_report_says_why_the_consistency_test_was_not_computed():
    from lidarcat.stages.report import _report_markdown

    why = "not computed: the joint covariance of 4000 check points needs 1.6 GiB in memory (limit 1 GiB)"
    md = _report_markdown({"survey": "s", "stages": [], "comparison": {},
                           "runs": {"gps": {"adjustment": {}, "check": {"n": 4000, "consistency_not_computed": why}}}})
    assert f"Discrepancies against the precision the adjustment claims (d'C^-1 d): {why}." in md
    assert "nan" not in md
