"""The review remembered (issue 29 step 4): decisions fed back to ``lidarcat measure-control`` are recorded in the
survey's control_decisions.csv, and a later measurement -- the command or the measure_control stage of
``lidarcat run`` -- never measures a rejected pair again (an accepted one only with ``--replace``).

The small fast block of ``test_measure_control_feedback.py``: :mod:`lidarcat.synthetic.aerial`, seed 2, two
640 x 480 photos at 0.12 m, 8 roof vertices as LiDAR control; L003 and L004 are measured on photo 102 (their ridge
1-2 and one hip found, ``in_point``: L003's 1-3 and L004's 2-3, see ``control_block.L003_HIP``), L001 and L002 are
``near_border`` on 101, every other pair is ``not_visible``.
"""

from __future__ import annotations

import csv
import re
from datetime import datetime

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import SurveyError
from lidarcat.pipeline.plan import plan_pipeline
from lidarcat.stages.measure_control import (DECISION_FIELDS, LINE_CANDIDATES, LINE_DECISION_FIELDS,
                                             measure_control, planned)
from lidarcat.survey.decisions import DECISION_COLUMNS
from lidarcat.survey.folder import Survey

from control_block import (L003_HIP, L003_NO_EDGE, copy_survey, edited_decisions, measured_block, read_rows,
                           write_rows)


_rows, _write = read_rows, write_rows


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    """(unmeasured survey folder, the same measured by measure-control): copy before changing either."""
    return measured_block(tmp_path_factory.mktemp("remember"))




_edited = edited_decisions


def _lidar_obs(root):
    ip = Survey.load(root).image_points
    return {(str(a), str(b)) for a, b in zip(ip.photo, ip.point) if str(b).startswith("L")}


def _recorded(root):
    """(kind, photo, id) -> (line in control_decisions.csv, row)."""
    sv = Survey.load(root)
    return {(r.kind, r.photo, r.id): (r.at, r) for r in sv.control_decisions.rows}


def _state(root):
    return {n: (root / n).read_bytes() if (root / n).is_file() else None
            for n in ("image_points.csv", "image_points.csv.json", "line_control.csv", "line_control.csv.json",
                      "control_decisions.csv", "control_decisions.csv.json", "survey.toml")}


def _run(root, *args):
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--no-gallery", *args])
    assert res.exit_code == 0, res.output
    return res


def test_a_rejection_fed_back_is_recorded_and_never_measured_again(blocks, tmp_path):
    _, src = blocks
    root = copy_survey(src, tmp_path)
    assert planned(Survey.load(root)) is None          # L001, L002, L005-L008 have no observation yet
    d, _ = _edited(root, {("L003", "102"): {"decision": "reject"}})
    _run(root, "--decisions", str(d))
    # survey.toml names the table; every row of the file is the user's word on its pair
    assert 'control_decisions = "control_decisions.csv"' in (root / "survey.toml").read_text()
    rec = _recorded(root)
    fed = _rows(d)
    assert len(rec) == len(fed) == 16
    for k, r in enumerate(fed):
        at, row = rec[("point", r["photo"], r["point"])]
        assert row.decision == r["decision"]
        assert row.source == f"out/measure_control/edited_decisions.csv:{k + 2}"
        assert datetime.fromisoformat(row.date).utcoffset().total_seconds() == 0
    assert rec[("point", "102", "L003")][1].decision == "reject"
    assert rec[("point", "102", "L004")][1].decision == "accept"
    assert _lidar_obs(root) == {("102", "L004")}
    assert list(_rows(root / "control_decisions.csv")[0]) == list(DECISION_COLUMNS)

    # every vertex observed or decided on every photo: `lidarcat run` no longer plans the stage
    sv = Survey.load(root)
    assert planned(sv) == ("every LiDAR control vertex has image observations or the user's decision on every "
                           "photo (control_decisions.csv); `lidarcat measure-control` measures again")
    assert "measure_control" not in [s.name for s in plan_pipeline(sv)]

    # measured again: the rejected pairs are not measured, and say why; the accepted one is left alone
    before = _state(root)
    _run(root)
    out = root / "out" / "measure_control"
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv")}
    assert set(dec) == {(r["point"], r["photo"]) for r in fed} - {("L004", "102")}
    for (v, ph), r in dec.items():
        assert (r["status"], r["reason"], r["decision"], r["col_px"]) == (
            "user_rejected", f"rejected by the user (control_decisions.csv:{rec[('point', ph, v)][0]})", "reject", "")
    edges = [e for e in _rows(out / "line_decisions.csv") if (e["point"], e["photo"]) == ("L003", "102")]
    why = f"rejected by the user (control_decisions.csv:{rec[('point', '102', 'L003')][0]})"
    assert [(e["status"], e["reason"]) for e in edges] == [("not_written", f"user_rejected: {why}")] * 3
    assert _state(root) == before                      # nothing measured, nothing written into the survey

    # --replace measures the accepted pair again (its record stays); the rejected ones still not
    _run(root, "--replace")
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv")}
    assert dec[("L004", "102")]["status"] == "measured"
    assert {k for k, r in dec.items() if r["status"] != "user_rejected"} == {("L004", "102")}
    assert _lidar_obs(root) == {("102", "L004")}
    assert (root / "control_decisions.csv").read_bytes() == before["control_decisions.csv"]


def test_feeding_back_a_later_report_keeps_the_records_and_a_flipped_row_undoes_a_rejection(blocks, tmp_path):
    _, src = blocks
    root = copy_survey(src, tmp_path)
    d, _ = _edited(root, {("L003", "102"): {"decision": "reject"}})
    _run(root, "--decisions", str(d))
    _run(root)                                   # the later report: every row user_rejected
    recorded = (root / "control_decisions.csv").read_bytes()
    later = root / "out" / "measure_control" / "decisions.csv"
    _run(root, "--decisions", str(later))       # unchanged decisions: the records (source, date) unchanged
    assert (root / "control_decisions.csv").read_bytes() == recorded
    assert _lidar_obs(root) == {("102", "L004")}

    # the user changes their mind on L003: measured by hand, accepted
    rows = _rows(later)
    k = next(i for i, r in enumerate(rows) if (r["point"], r["photo"]) == ("L003", "102"))
    rows[k].update(decision="accept", col_px="331.5", row_px="140.25", sd_col_px="0.4", sd_row_px="0.4")
    _write(later, DECISION_FIELDS, rows)
    n = _rows(root / "control_decisions.csv")
    _run(root, "--decisions", str(later))
    rec = _recorded(root)
    at, row = rec[("point", "102", "L003")]
    assert (row.decision, row.source) == ("accept", f"out/measure_control/decisions.csv:{k + 2}")
    assert len(rec) == len(n)                   # replaced in place, no row added
    assert _lidar_obs(root) == {("102", "L003"), ("102", "L004")}
    ip = Survey.load(root).image_points
    i = next(i for i, (a, b) in enumerate(zip(ip.photo, ip.point)) if (a, b) == ("102", "L003"))
    np.testing.assert_allclose(ip.pixel_px[i], [331.5, 140.25])


def test_a_partial_review_leaves_the_stage_planned_and_the_run_skips_the_rejected_pair(blocks, tmp_path):
    """Only L003 on 102 reviewed (rejected): the open vertices keep the stage in ``lidarcat run``'s plan; the
    stage (its table written beside, as the run does) leaves L003 on 102 alone and measures L004 there again."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    d, _ = _edited(root, {("L003", "102"): {"decision": "reject"}},
                   keep=lambda r: (r["point"], r["photo"]) == ("L003", "102"))
    _run(root, "--decisions", str(d))
    sv = Survey.load(root)
    assert len(sv.control_decisions) == 1
    assert planned(sv) is None
    assert "measure_control" in [s.name for s in plan_pipeline(sv)]
    before = _state(root)
    run = tmp_path / "run"
    run.mkdir()
    res = measure_control(sv, run, table=run / "image_points.csv", line_table=run / "line_control.csv",
                          gallery=False, replace=True)
    dec = {(r["point"], r["photo"]): r for r in _rows(run / "decisions.csv")}
    assert (dec[("L003", "102")]["status"], dec[("L003", "102")]["reason"]) == (
        "user_rejected", "rejected by the user (control_decisions.csv:2)")
    assert dec[("L004", "102")]["status"] == "measured" and res.counts["user_rejected"] == 1
    got = {(r["photo"], r["point"]) for r in _rows(run / "image_points.csv") if r["point"].startswith("L")}
    assert got == {("102", "L004")}
    assert _state(root) == before               # the run's table is its own

    # through `lidarcat run`'s runner: the same; the review is one of the stage's hashed inputs
    import dataclasses

    from lidarcat.pipeline.runner import run_stages

    def stage(sv):
        return dataclasses.replace({st.name: st for st in plan_pipeline(sv)}["measure_control"], requires=())

    recs = run_stages([stage(sv)], tmp_path / "out", values={"survey": sv})
    assert [r.status for r in recs] == ["ran"], [r.reason for r in recs]
    assert recs[0].result["counts"]["user_rejected"] == 1 and recs[0].result["accepted"] == 0
    dec = {(r["point"], r["photo"]): r for r in _rows(tmp_path / "out" / "measure_control" / "decisions.csv")}
    assert dec[("L003", "102")]["reason"] == "rejected by the user (control_decisions.csv:2)"
    assert ("L004", "102") not in dec             # accepted (observed): left alone without replace
    assert [r.status for r in run_stages([stage(sv)], tmp_path / "out", values={"survey": sv})] == ["reused"]
    with open(root / "control_decisions.csv", "a") as fh:
        fh.write("point,101,L001,reject,,\n")
    sv = Survey.load(root)
    recs = run_stages([stage(sv)], tmp_path / "out", values={"survey": sv})
    assert [r.status for r in recs] == ["ran"] and recs[0].result["counts"]["user_rejected"] == 2


def test_line_decisions_are_remembered(blocks, tmp_path):
    """From a lines-only report, the user takes L003's and L004's edges on photo 102 instead of their points, but
    rejects L004's edge 1-2: a later measurement (even --replace) keeps the accepted edges, never writes the
    rejected one, and says why; deleting a record reopens its pair."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    rep = root / "out" / "lines_only"
    measure_control(root, rep, lines="only", replace=True, points=["L003", "L004"], table=rep / "ip.csv",
                    line_table=rep / "lc.csv", gallery=False)
    d, ld = rep / "decisions.csv", rep / "line_decisions.csv"
    dec, ldec = _rows(d), _rows(ld)
    assert {(r["point"], r["photo"], r["status"]) for r in dec if r["photo"] == "102"} == {
        ("L003", "102", "measured"), ("L004", "102", "measured")}
    for r in dec:
        r["decision"] = "reject"
    k = next(i for i, r in enumerate(ldec) if (r["line"], r["photo"]) == ("L004/1-2", "102"))
    assert ldec[k]["status"] == "written"
    ldec[k]["decision"] = "reject"
    _write(d, DECISION_FIELDS, dec)
    _write(ld, LINE_DECISION_FIELDS, ldec)
    _run(root, "--decisions", str(d), "--line-decisions", str(ld))
    rec = _recorded(root)
    lines = {(k[2], k[1]): r.decision for k, (_, r) in rec.items() if k[0] == "line"}
    assert {k: v for k, v in lines.items() if k[1] == "102"} == {
        ("L003/1-2", "102"): "accept", (L003_HIP, "102"): "accept", (L003_NO_EDGE, "102"): "reject",
        ("L004/1-2", "102"): "reject", ("L004/2-3", "102"): "accept", ("L004/1-3", "102"): "reject"}
    assert rec[("line", "102", "L004/1-2")][1].source == f"out/lines_only/line_decisions.csv:{k + 2}"
    obs = {(r["line"], r["photo"]) for r in _rows(root / "line_control.csv") if r["photo"]}
    assert obs == {("L003/1-2", "102"), (L003_HIP, "102"), ("L004/2-3", "102")}
    assert _lidar_obs(root) == set()

    lines_before = (root / "line_control.csv").read_bytes()
    _run(root, "--replace")
    out = root / "out" / "measure_control"
    ldec = {(r["line"], r["photo"]): r for r in _rows(out / "line_decisions.csv")}
    for v in ("L003", "L004"):
        why = f"rejected by the user (control_decisions.csv:{rec[('point', '102', v)][0]})"
        assert all((ldec[(f"{v}/{e}", "102")]["status"], ldec[(f"{v}/{e}", "102")]["reason"]) == (
            "not_written", f"user_rejected: {why}") for e in ("1-2", "1-3", "2-3"))
    assert (root / "line_control.csv").read_bytes() == lines_before    # the accepted edges kept, nothing new

    # the user reopens L004 on 102 (deletes its point's record); lines only, as the run stage writes them (tables
    # of its own): L004's edges measured again, but the rejected one, with the reason
    table = root / "control_decisions.csv"
    table.write_text("".join(t for t in table.read_text().splitlines(keepends=True)
                             if not t.startswith("point,102,L004,")))
    rec = _recorded(root)
    run = tmp_path / "run"
    run.mkdir()
    measure_control(root, run, table=run / "image_points.csv", line_table=run / "line_control.csv", gallery=False,
                    replace=True, lines="only", points=["L004"])
    ldec = {(r["line"], r["photo"]): r for r in _rows(run / "line_decisions.csv")}
    assert (ldec[("L004/1-2", "102")]["status"], ldec[("L004/1-2", "102")]["reason"],
            ldec[("L004/1-2", "102")]["decision"]) == (
        "user_rejected", f"rejected by the user (control_decisions.csv:{rec[('line', '102', 'L004/1-2')][0]})",
        "reject")
    assert ldec[("L004/2-3", "102")]["status"] == "written"
    lc = {(r["line"], r["photo"]) for r in _rows(run / "line_control.csv") if r["photo"]}
    assert lc == {("L003/1-2", "102"), (L003_HIP, "102"), ("L004/2-3", "102")}


# -- control_decisions.csv at load: one located error per bad row ------------------------------------------------

@pytest.mark.parametrize("row, message", [
    ("pt,101,L001,reject", "field 'kind': must be point or line, got 'pt'"),
    ("point,109,L001,reject", "field 'photo': unknown photo '109' (not in photos.csv)"),
    ("point,101,X9,reject", "field 'id': unknown point 'X9' (not in ground_points.csv)"),
    ("line,101,X9/1-2,reject", "field 'id': unknown line 'X9/1-2' (neither a line of line_control.csv nor POINT/i-j "
                               "of a ground point)"),
    ("line,101,L001,reject", "field 'id': unknown line 'L001' (neither a line of line_control.csv nor POINT/i-j "
                             "of a ground point)"),
    ("point,101,L001,maybe", "field 'decision': must be accept or reject, got 'maybe'"),
    ("point,101,L001,reject,x.csv:2,yesterday", "field 'date': not an ISO 8601 date 'yesterday' (e.g. "
                                                "2026-11-28T11:02:13+00:00)"),
    ("point,102,L003,accept", "point 'L003' on photo '102' is listed twice (also on line 3); keep one row"),
], ids=["kind", "photo", "point", "line", "line-id", "decision", "date", "twice"])
def test_bad_rows_of_control_decisions_are_located(blocks, tmp_path, row, message):
    src, _ = blocks
    root = copy_survey(src, tmp_path)
    from lidarcat.stages._control_tables import add_files_key as _add_files_key

    cells = row.split(",")
    (root / "control_decisions.csv").write_text(
        "# the user's review\nkind,photo,id,decision,source,date\npoint,102,L003,reject,,2026-11-28T11:02:13+00:00\n"
        + ",".join(cells + [""] * (6 - len(cells))) + "\n")
    _add_files_key(root / "survey.toml", "control_decisions", root / "control_decisions.csv")
    with pytest.raises(SurveyError) as ex:
        Survey.load(root)
    assert str(ex.value) == f"{root / 'control_decisions.csv'}:4: {message}"


def test_a_hand_written_table_loads_and_a_line_of_line_control_may_be_named(blocks, tmp_path):
    src, _ = blocks
    root = copy_survey(src, tmp_path)
    from lidarcat.stages._control_tables import add_files_key as _add_files_key

    (root / "control_decisions.csv").write_text("kind,photo,id,decision\nPOINT,101,L001,Reject\nline,102,L003/1-2,"
                                                "accept\n")
    _add_files_key(root / "survey.toml", "control_decisions", root / "control_decisions.csv")
    sv = Survey.load(root)
    assert [(r.kind, r.photo, r.id, r.decision, r.point, r.at) for r in sv.control_decisions.rows] == [
        ("point", "101", "L001", "reject", "L001", 2), ("line", "102", "L003/1-2", "accept", "L003", 3)]
    assert sv.files["control_decisions"] == root / "control_decisions.csv"


# -- the rollback: control_decisions.csv and survey.toml put back ------------------------------------------------

def test_records_are_rolled_back_with_the_tables(blocks, tmp_path):
    """A survey that does not load with the new tables (a corrupted 3-D line reaches line_control.csv) gets
    control_decisions.csv and survey.toml back byte for byte: absent and without the key, then present."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    out = root / "out" / "measure_control"
    from lidarcat.survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    good = _rows(out / LINE_CANDIDATES)
    bad = [dict(r) for r in good]
    next(r for r in bad if r["line"] == L003_HIP)["cov_m2"] = " ".join(["-1"] + ["0"] * 20)
    _write(out / LINE_CANDIDATES, list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS), bad)
    d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}}, {(L003_HIP, "102"): {"decision": "accept"}})
    for first in (True, False):
        before = _state(root)
        assert (before["control_decisions.csv"] is None) == first
        res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions",
                                       str(ld)])
        assert res.exit_code == 2
        text = res.output.replace("\n", " ")
        assert re.search(r"line_control\.csv:\d+: field 'cov_m2': not a covariance \(not positive semi-definite\) "
                         r"\(the survey does not load with the new tables: image_points\.csv, line_control\.csv, "
                         r"control_decisions\.csv(, survey\.toml)? put back as they were\)", text), text
        assert ("survey.toml put back" in text) == first
        assert _state(root) == before
        if first:     # a good review first: the table and its key exist
            _write(out / LINE_CANDIDATES, list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS), good)
            _run(root, "--decisions", str(d), "--line-decisions", str(ld))
            _write(out / LINE_CANDIDATES, list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS), bad)
            d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}, ("L004", "102"): {"decision": "reject"}},
                            {(L003_HIP, "102"): {"decision": "accept"}, ("L004/2-3", "102"): {"decision": "accept"}})


def test_an_edge_its_point_carries_is_not_recorded_as_rejected(blocks, tmp_path):
    """The report's ``in_point`` edges (decision ``reject``: not written because the vertex's point carries them)
    are no decision on the edge: feeding the report back records every other row."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    _, ld = _edited(root)
    ldec = _rows(ld)
    _run(root, "--line-decisions", str(ld))
    rec = _recorded(root)
    carried = {(r["line"], r["photo"]) for r in ldec if r["status"] == "in_point"}
    assert carried == {("L003/1-2", "102"), (L003_HIP, "102"), ("L004/1-2", "102"), ("L004/2-3", "102")}
    assert {(k[2], k[1]) for k in rec} == {(r["line"], r["photo"]) for r in ldec} - carried
    assert all(r.kind == "line" and r.decision == "reject" for _, r in rec.values())

    # an edge accepted instead of its point, then carried by the point again: its record goes with it
    d, ld2 = _edited(root, {("L003", "102"): {"decision": "reject"}}, {("L003/1-2", "102"): {"decision": "accept"}})
    _run(root, "--decisions", str(d), "--line-decisions", str(ld2))
    assert _recorded(root)[("line", "102", "L003/1-2")][1].decision == "accept"
    out = root / "out" / "measure_control"
    _run(root, "--decisions", str(out / "decisions.csv"), "--line-decisions", str(out / "line_decisions.csv"))
    rec = _recorded(root)
    assert ("line", "102", "L003/1-2") not in rec and rec[("point", "102", "L003")][1].decision == "accept"
    assert _lidar_obs(root) == {("102", "L003"), ("102", "L004")}
    assert [r for r in _rows(root / "line_control.csv")] == []


def test_replace_measures_an_accepted_edge_again_instead_of_writing_it_twice(blocks, tmp_path):
    """--replace measures a pair whose edges the user accepted again: each new edge observation replaces the
    accepted one of its line and photo (the accepted observations are kept only while their vertex is measured on
    other photos), never one row beside the other."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    rep = root / "out" / "lines_only"
    measure_control(root, rep, lines="only", replace=True, points=["L004"], table=rep / "ip.csv",
                    line_table=rep / "lc.csv", gallery=False)
    d, ld = rep / "decisions.csv", rep / "line_decisions.csv"
    dec = _rows(d)
    for r in dec:
        r["decision"] = "reject"
    _write(d, DECISION_FIELDS, dec)
    _run(root, "--decisions", str(d), "--line-decisions", str(ld))
    accepted = [(r["line"], r["photo"]) for r in _rows(root / "line_control.csv") if r["photo"]]
    assert sorted(accepted) == [("L004/1-2", "102"), ("L004/2-3", "102")]
    table = root / "control_decisions.csv"      # the user reopens L004 on 102 (deletes its point's record)
    table.write_text("".join(t for t in table.read_text().splitlines(keepends=True)
                             if not t.startswith("point,102,L004,")))
    run = tmp_path / "run"
    run.mkdir()
    measure_control(root, run, table=run / "image_points.csv", line_table=run / "line_control.csv", gallery=False,
                    replace=True, lines="only", points=["L004"])
    written = [(r["line"], r["photo"]) for r in _rows(run / "line_decisions.csv") if r["status"] == "written"]
    assert sorted(written) == [("L004/1-2", "102"), ("L004/2-3", "102")]
    obs = [(r["line"], r["photo"]) for r in _rows(run / "line_control.csv") if r["photo"]]
    assert sorted(obs) == [("L004/1-2", "102"), ("L004/2-3", "102")]      # once each


def test_lines_only_replace_over_a_measured_point_writes_the_edges_instead_of_beside_it(blocks, tmp_path):
    """--lines only --replace over the measured block (L003 and L004 points on photo 102 in image_points.csv):
    the pairs are measured again and their edges replace the points -- one photo never gives a vertex's point and
    its edges (a double count of the same corner); a pair whose new measurement writes no edge keeps its row."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    assert _lidar_obs(root) == {("102", "L003"), ("102", "L004")}
    _run(root, "--lines", "only", "--replace")
    out = root / "out" / "measure_control"
    written = {(r["line"].split("/")[0], r["photo"]) for r in _rows(out / "line_decisions.csv")
               if r["status"] == "written"}
    assert written == {("L003", "102"), ("L004", "102")}
    edges = {(r["photo"], r["line"].split("/")[0]) for r in _rows(root / "line_control.csv") if r["photo"]}
    assert edges == {("102", "L003"), ("102", "L004")}
    assert _lidar_obs(root) == set()


def test_a_point_measured_over_its_written_edges_replaces_them(blocks, tmp_path):
    """The other way round: over edges written by a lines-only run (L003 and L004 on photo 102), a default run
    measures the pairs again and writes their points; the edges of those pairs go (no edge is written now, so
    line_control.csv is rewritten for that alone), never one beside the other."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    _run(root, "--lines", "only", "--replace")
    assert _lidar_obs(root) == set()
    assert {(r["photo"], r["line"].split("/")[0]) for r in _rows(root / "line_control.csv") if r["photo"]} == {
        ("102", "L003"), ("102", "L004")}
    _run(root)
    out = root / "out" / "measure_control"
    assert {(r["line"], r["photo"]) for r in _rows(out / "line_decisions.csv") if r["status"] == "in_point"} == {
        ("L003/1-2", "102"), (L003_HIP, "102"), ("L004/1-2", "102"), ("L004/2-3", "102")}
    assert not [r for r in _rows(out / "line_decisions.csv") if r["status"] == "written"]
    assert _lidar_obs(root) == {("102", "L003"), ("102", "L004")}
    assert [r for r in _rows(root / "line_control.csv")] == []
