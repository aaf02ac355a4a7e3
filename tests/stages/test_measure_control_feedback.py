"""``lidarcat measure-control``: the review (decisions.csv and line_decisions.csv edited and fed back), the
rollback when the written survey does not load, and bad input reported per vertex and photo (issue 29, steps 4
and "Bad input").

One small block, fast: :mod:`lidarcat.synthetic.aerial`, seed 2, one strip of two 640 x 480 photos at 0.12 m,
LiDAR at 10 points/m^2; its 8 roof vertices (two hip roofs) as LiDAR control.  The scene reaches beyond the photos:
four vertices (L005-L008) lie outside every photo; L003 and L004 are measured on photo 102, L003's north-west hip
(planes 2 and 3, ``control_block.L003_NO_EDGE``) is not found in the photo (faces of one shade).
"""

from __future__ import annotations

import csv
import re
import shutil

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.stages.measure_control import DECISION_FIELDS, LINE_CANDIDATES, LINE_DECISION_FIELDS, measure_control
from lidarcat.survey.folder import Survey
from lidarcat.survey.lines import read_line_control

from control_block import L003_HIP, L003_NO_EDGE, edited_decisions, measured_block, read_rows, write_rows


_rows, _write = read_rows, write_rows


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    """(unmeasured survey folder, the same measured by measure-control): copy before changing either."""
    return measured_block(tmp_path_factory.mktemp("feedback"))


def _copy(src, tmp_path, name="s"):
    dst = tmp_path / name
    shutil.copytree(src, dst)
    return dst


def _state(root):
    """The bytes of the files measure-control may write into the survey (None: absent)."""
    return {n: (root / n).read_bytes() if (root / n).is_file() else None
            for n in ("image_points.csv", "image_points.csv.json", "line_control.csv", "line_control.csv.json",
                      "control_decisions.csv", "control_decisions.csv.json", "survey.toml")}


def _lidar_obs(root):
    ip = Survey.load(root).image_points
    return {(str(a), str(b)) for a, b in zip(ip.photo, ip.point) if str(b).startswith("L")}


# -- bad input, reported per vertex and photo -------------------------------------------------------------------

def test_vertex_outside_every_photo_and_edge_without_image_edge_are_reported(blocks):
    _, root = blocks
    out = root / "out" / "measure_control"
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv")}
    ldec = _rows(out / "line_decisions.csv")
    assert len(dec) == 8 * 2 and len(ldec) == 8 * 2 * 3            # one row per vertex (edge) and photo
    for v in ("L005", "L006", "L007", "L008"):
        for ph in ("101", "102"):
            r = dec[(v, ph)]
            assert r["status"] == "not_visible" and r["decision"] == "reject" and r["col_px"] == ""
            got = re.fullmatch(r"outside: predicted at column (-?[0-9.]+), row (-?[0-9.]+): off the 640 x 480 frame",
                               r["reason"])
            assert got, r["reason"]         # the reason's pixel (0.1 px) is the prediction's (0.01 px)
            assert abs(float(got[1]) - float(r["pred_col_px"])) <= 0.055
            assert abs(float(got[2]) - float(r["pred_row_px"])) <= 0.055
            edges = [e for e in ldec if e["point"] == v and e["photo"] == ph]
            assert len(edges) == 3
            assert all(e["status"] == "not_written" and e["reason"] == f"not_visible: {r['reason']}"
                       and e["decision"] == "reject" and e["col1_px"] == "" for e in edges)
    # a roof edge with no image edge, on a photo where its vertex is measured from the other two
    assert dec[("L003", "102")]["status"] == "measured" and dec[("L003", "102")]["decision"] == "accept"
    e_no = next(e for e in ldec if (e["line"], e["photo"]) == (L003_NO_EDGE, "102"))
    assert (e_no["status"], e_no["reason"], e_no["decision"], e_no["col1_px"]) == (
        "not_written", "no image edge found (or too weak for a line without its vertex)", "reject", "")
    assert {(e["line"], e["status"]) for e in ldec if e["point"] == "L003" and e["photo"] == "102"} == {
        ("L003/1-2", "in_point"), (L003_NO_EDGE, "not_written"), (L003_HIP, "in_point")}
    # only the accepted pairs went into the survey; no line was written (add: the points carry the edges)
    assert _lidar_obs(root) == {(ph, v) for (v, ph), r in dec.items() if r["decision"] == "accept"} == {
        ("102", "L003"), ("102", "L004")}
    assert not (root / "line_control.csv").exists()
    # every edge tried has its 3-D line in line_candidates.csv (what --line-decisions reads)
    cand = _rows(out / LINE_CANDIDATES)
    assert {r["line"] for r in cand} == {e["line"] for e in ldec}
    assert all(r["photo"] == "" and r["cov_m2"] and r["point"] == r["line"].split("/")[0] for r in cand)
    # which hip is which (the labels follow the faces' point counts, control_block): from the vertex (end 1), the
    # edge not found runs north-west, the one found south-west (each 2.0-2.7 m in E and in N)
    for lid, north in ((L003_NO_EDGE, 1), (L003_HIP, -1)):
        c = next(r for r in cand if r["line"] == lid)
        de, dn = float(c["e2_m"]) - float(c["e1_m"]), float(c["n2_m"]) - float(c["n1_m"])
        assert -3.0 < de < -1.5 and 1.5 < north * dn < 3.0, (lid, de, dn)


@pytest.mark.parametrize("kind", ["too_dark", "saturated"])
def test_dark_or_saturated_photo_is_reported_per_vertex_and_not_written(blocks, tmp_path, kind):
    src, _ = blocks
    root = _copy(src, tmp_path)
    path = Survey.load(root).image_path("102")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(path), (img * 0.02).astype(img.dtype) if kind == "too_dark" else np.full_like(img, 255))
    before = _state(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--no-gallery"])
    assert res.exit_code == 0, res.output
    out = root / "out" / "measure_control"
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv")}
    for v in ("L003", "L004"):       # the two vertices on photo 102
        r = dec[(v, "102")]
        assert r["status"] == kind and r["decision"] == "reject" and r["col_px"] == ""
        if kind == "too_dark":
            assert r["reason"].startswith("median grey value ") and r["reason"].endswith(" below 12")
        else:
            assert r["reason"] == "100 % of the window at or above 250"
        edges = [e for e in _rows(out / "line_decisions.csv") if e["point"] == v and e["photo"] == "102"]
        assert len(edges) == 3 and all(e["status"] == "not_written" and e["reason"] == f"{kind}: {r['reason']}"
                                       for e in edges)
    assert res.output.startswith("0 control observations accepted (")
    assert _state(root) == before            # nothing accepted: image_points.csv, survey.toml as they were


def test_an_unreadable_photo_fails_the_run_and_nothing_is_written(blocks, tmp_path):
    src, _ = blocks
    root = _copy(src, tmp_path)
    path = Survey.load(root).image_path("102")
    data = path.read_bytes()
    path.write_bytes(data[:2000] + data[-12:])   # a PNG cut short but for its IEND chunk: it fails only when decoded
    before = _state(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root)])
    assert res.exit_code == 2
    assert f"photo '102': {path}: cannot decode the image (truncated, or not a PNG/TIFF/JPEG)" in \
        res.output.replace("\n", " ")
    assert _state(root) == before
    assert list((root / "out" / "measure_control").iterdir()) == []     # not even the report


# -- the review: decisions fed back --------------------------------------------------------------------------

_edited = edited_decisions


def test_edges_accepted_instead_of_the_point_go_to_line_control_and_back(blocks, tmp_path):
    _, src = blocks
    root = _copy(src, tmp_path)
    cand = {r["line"]: r for r in _rows(root / "out" / "measure_control" / LINE_CANDIDATES)}
    # the user prefers L003's two edges on photo 102 to its point, and moves one end of an edge
    d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}},
                    {("L003/1-2", "102"): {"decision": "accept", "col1_px": "398.5", "row1_px": "137.25"},
                     (L003_HIP, "102"): {"decision": "accept"}})
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    assert res.exit_code == 0, res.output
    assert res.output.splitlines() == [
        f"1 control observations accepted -> {root / 'image_points.csv'}",
        f"2 roof-edge line observations accepted -> {root / 'line_control.csv'}",
        f"the review recorded -> {root / 'control_decisions.csv'} (62 decisions)"]
    assert _lidar_obs(root) == {("102", "L004")}
    sv = Survey.load(root)
    assert sv.files["line_control"] == root / "line_control.csv"      # survey.toml got the key
    lc = _rows(root / "line_control.csv")
    defs = {r["line"]: r for r in lc if not r["photo"]}
    assert set(defs) == {"L003/1-2", L003_HIP}
    for lid, r in defs.items():       # the 3-D line as measure-control computed it, with its covariance
        assert all(r[c] == cand[lid][c] for c in ("e1_m", "n1_m", "h1_m", "e2_m", "n2_m", "h2_m", "cov_m2", "point"))
    obs = {(r["line"], r["photo"]): r for r in lc if r["photo"]}
    assert set(obs) == {("L003/1-2", "102"), (L003_HIP, "102")}
    assert (obs[("L003/1-2", "102")]["col1_px"], obs[("L003/1-2", "102")]["row1_px"]) == ("398.5", "137.25")
    lines, lobs = read_line_control(root / "line_control.csv", sv.photo_ids, {p: sv.camera_of(p) for p in sv.photo_ids})
    assert len(lines) == 2 and len(lobs) == 2
    np.testing.assert_allclose(lines[0].cov_m2[np.triu_indices(6)],
                               [float(v) for v in cand[lines[0].line]["cov_m2"].split()])

    # the point accepted again while its edges stay in line_control.csv: one photo counted twice, refused
    orig = root / "out" / "measure_control" / "decisions.csv"
    n = next(i for i, r in enumerate(_rows(orig)) if (r["point"], r["photo"]) == ("L003", "102")) + 2
    before = _state(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(orig)])
    assert res.exit_code == 2
    assert (f"{orig}:{n}: point 'L003' on photo '102': measured from the same edge fits as its roof edges on this "
            f"photo in line_control.csv; accept the point or its edges, not both"
            in res.output.replace("\n", " ")), res.output
    assert _state(root) == before

    # rejected again (alone): the observations go, and the lines without observations with them
    _, ld2 = _edited(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--line-decisions", str(ld2)])
    assert res.exit_code == 0, res.output
    assert res.output.splitlines() == [f"0 roof-edge line observations accepted -> {root / 'line_control.csv'}",
                                       f"the review recorded -> {root / 'control_decisions.csv'} (60 decisions)"]
    assert [r for r in _rows(root / "line_control.csv")] == []
    assert _lidar_obs(root) == {("102", "L004")}          # image_points.csv untouched without --decisions


def test_a_point_and_an_edge_typed_by_hand_may_share_a_photo(blocks, tmp_path):
    """L001 on photo 101 was not measured (near_border): its point and one edge measured by hand are independent
    observations, both written."""
    _, src = blocks
    root = _copy(src, tmp_path)
    d, ld = _edited(root,
                    {("L001", "101"): {"decision": "accept", "col_px": "183.5", "row_px": "451.0", "sd_col_px": "0.5",
                                       "sd_row_px": "0.5"}},
                    {("L001/1-2", "101"): {"decision": "accept", "col1_px": "183.5", "row1_px": "451", "col2_px":
                                           "215", "row2_px": "451.5", "sd_px": "0.5"}})
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    assert res.exit_code == 0, res.output
    assert _lidar_obs(root) == {("101", "L001"), ("102", "L003"), ("102", "L004")}
    assert [(r["line"], r["photo"]) for r in _rows(root / "line_control.csv")] == [("L001/1-2", ""),
                                                                                    ("L001/1-2", "101")]


def test_a_hand_line_and_other_photos_observations_are_kept(blocks, tmp_path):
    """Rows of line_control.csv that the fed-back file does not list stay: a hand-made line, and the observation of
    a listed line on a photo the file does not list (its definition stays with it)."""
    _, src = blocks
    root = _copy(src, tmp_path)
    cand = {r["line"]: r for r in _rows(root / "out" / "measure_control" / LINE_CANDIDATES)}
    from lidarcat.survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    header = list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS)
    hand = {"line": "R1", "e1_m": "679990", "n1_m": "7183980", "h1_m": "910", "e2_m": "679995", "n2_m": "7183980",
            "h2_m": "910", "sd_across_m": "0.05"}
    hand_obs = {"line": "R1", "photo": "101", "col1_px": "100", "row1_px": "100", "col2_px": "150", "row2_px": "100",
                "sd_px": "0.5"}
    l004 = {**cand["L004/1-2"]}
    l004_on_101 = {"line": "L004/1-2", "photo": "101", "col1_px": "10", "row1_px": "10", "col2_px": "40",
                   "row2_px": "12", "sd_px": "0.5"}
    _write(root / "line_control.csv", header, [hand, hand_obs, l004, l004_on_101])
    from lidarcat.stages._control_tables import add_line_control_key as _add_line_control_key

    _add_line_control_key(root / "survey.toml", root / "line_control.csv")
    d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}},
                    {(L003_HIP, "102"): {"decision": "accept"}})
    # the user keeps only the rows of L003 on photo 102 (the others: not listed, not touched)
    _write(ld, LINE_DECISION_FIELDS, [r for r in _rows(ld) if r["point"] == "L003" and r["photo"] == "102"])
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    assert res.exit_code == 0, res.output
    got = [(r["line"], r["photo"]) for r in _rows(root / "line_control.csv")]
    assert got == [("R1", ""), ("R1", "101"), ("L004/1-2", ""), ("L004/1-2", "101"), (L003_HIP, ""),
                   (L003_HIP, "102")]


# -- bad edited rows: one located error each, nothing written ----------------------------------------------------

@pytest.mark.parametrize("change, message", [
    ({("L003/1-2", "102"): {"decision": "yes"}}, "edited_lines.csv:{n}: decision must be accept or reject, got 'yes'"),
    ({("L003/1-2", "102"): {"col2_px": "12,5.3"}}, "edited_lines.csv:{n}: field 'col2_px': "),
    ({("L003/1-2", "102"): {"line": "L003/1-4"}},
     "edited_lines.csv:{n}: field 'line': unknown line 'L003/1-4': neither line_candidates.csv beside this file nor "
     "the survey's line_control.csv defines it"),
    ({("L003/1-2", "102"): {"photo": "109"}}, "edited_lines.csv:{n}: field 'photo': unknown photo '109' (not in "
                                              "photos.csv)"),
    ({("L003/1-2", "102"): {"point": "L004"}}, "edited_lines.csv:{n}: field 'point': line 'L003/1-2' is of point "
                                               "'L003', not 'L004'"),
    ({("L001/1-2", "102"): {"decision": "accept"}},
     "edited_lines.csv:{n}: decision accept needs col1_px, row1_px, col2_px, row2_px and sd_px (line 'L001/1-2', "
     "photo '102')"),
    ({("L003/1-2", "102"): {"decision": "accept", "sd_px": "0"}}, "edited_lines.csv:{n}: field 'sd_px': must be "
                                                                  "positive, got 0"),
    ({("L003/1-2", "102"): {"decision": "accept", "col2_px": "{c1}", "row2_px": "{r1}"}},
     "edited_lines.csv:{n}: line 'L003/1-2' on photo '102': its two image points coincide (an edge of zero length)"),
    ({("L003/1-2", "102"): {"decision": "accept"}},
     "edited_lines.csv:{n}: line 'L003/1-2' on photo '102': vertex 'L003' has a point observation on this photo "
     "(in image_points.csv) measured from the same edge fits; accept the point or its edges, not both"),
], ids=["decision", "pixel", "line", "photo", "point", "no-pixels", "sd", "zero-length", "point-and-edge"])
def test_bad_line_decision_rows_are_located_and_nothing_is_written(blocks, tmp_path, change, message):
    _, src = blocks
    root = _copy(src, tmp_path)
    out = root / "out" / "measure_control"
    ldec = _rows(out / "line_decisions.csv")
    k = next(i for i, r in enumerate(ldec) if (r["line"], r["photo"]) == next(iter(change)))
    row = ldec[k]
    cells = {c: v.format(c1=row["col1_px"], r1=row["row1_px"]) for c, v in next(iter(change.values())).items()}
    _, ld = _edited(root, line_changes={next(iter(change)): cells})
    before = _state(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--line-decisions", str(ld)])
    assert res.exit_code == 2, res.output
    assert f"{ld.parent}/" + message.format(n=k + 2) in res.output.replace("\n", " ")
    assert _state(root) == before


@pytest.mark.parametrize("key, cells, message", [
    (("L003", "102"), {"decision": "ok"}, "edited_decisions.csv:{n}: decision must be accept or reject, got 'ok'"),
    (("L003", "102"), {"row_px": "abc"}, "edited_decisions.csv:{n}: field 'row_px': "),
    (("L003", "102"), {"photo": "109"}, "edited_decisions.csv:{n}: field 'photo': unknown photo '109' (not in "
                                        "photos.csv)"),
    (("L003", "102"), {"point": "X9"}, "edited_decisions.csv:{n}: field 'point': unknown point 'X9' (not in "
                                       "ground_points.csv)"),
    (("L005", "101"), {"decision": "accept"}, "edited_decisions.csv:{n}: decision accept needs col_px and row_px "
                                              "(photo '101', point 'L005')"),
    (("L003", "102"), {"sd_col_px": "-0.5"}, "edited_decisions.csv:{n}: field 'sd_col_px': must be positive, "
                                             "got -0.5"),
    (("L003", "102"), {"point": "L004"}, "edited_decisions.csv:{n}: point 'L004' on photo '102' is listed twice "
                                         "(also on line {m}); keep one row"),
], ids=["decision", "pixel", "photo", "point", "no-pixel", "sd", "twice"])
def test_bad_point_decision_rows_are_located_and_nothing_is_written(blocks, tmp_path, key, cells, message):
    _, src = blocks
    root = _copy(src, tmp_path)
    dec = _rows(root / "out" / "measure_control" / "decisions.csv")
    k = next(i for i, r in enumerate(dec) if (r["point"], r["photo"]) == key)
    m = next((i for i, r in enumerate(dec) if (r["point"], r["photo"]) == ("L004", "102")), 0)
    d, _ = _edited(root, point_changes={key: cells})
    before = _state(root)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d)])
    assert res.exit_code == 2, res.output
    n, m = (m + 2, k + 2) if "twice" in message else (k + 2, m + 2)      # the second of the two rows is reported
    assert f"{d.parent}/" + message.format(n=n, m=m) in res.output.replace("\n", " ")
    assert _state(root) == before


def test_a_duplicated_line_row_is_located(blocks, tmp_path):
    _, src = blocks
    root = _copy(src, tmp_path)
    ldec = _rows(root / "out" / "measure_control" / "line_decisions.csv")
    ld = root / "out" / "measure_control" / "dup.csv"
    _write(ld, LINE_DECISION_FIELDS, ldec + [ldec[0]])
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--line-decisions", str(ld)])
    assert res.exit_code == 2
    assert (f"{ld}:{len(ldec) + 2}: line 'L001/1-2' on photo '101' is listed twice (also on line 2); keep one row"
            in res.output.replace("\n", " "))


# -- the rollback: a survey that does not load with the new tables is put back --------------------------------

def test_survey_that_does_not_load_with_the_new_tables_is_restored_byte_for_byte(blocks, tmp_path):
    """A corrupted 3-D line (its covariance not positive semi-definite) in line_candidates.csv reaches
    line_control.csv; the survey does not load with it: image_points.csv (rewritten from decisions.csv),
    line_control.csv (absent, then present) and survey.toml (given its [files] key, then not) are as before."""
    _, src = blocks
    root = _copy(src, tmp_path)
    out = root / "out" / "measure_control"
    cand = _rows(out / LINE_CANDIDATES)
    bad = next(r for r in cand if r["line"] == L003_HIP)
    bad["cov_m2"] = " ".join(["-1"] + ["0"] * 20)
    from lidarcat.survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    _write(out / LINE_CANDIDATES, list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS), cand)
    d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}},
                    {(L003_HIP, "102"): {"decision": "accept"}})
    expect = (f"{root / 'line_control.csv'}:2: field 'cov_m2': not a covariance (not positive semi-definite) (the "
              f"survey does not load with the new tables: image_points.csv, line_control.csv, control_decisions.csv, "
              f"survey.toml put back as they were)")
    before = _state(root)
    assert before["line_control.csv"] is None
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    assert res.exit_code == 2
    assert expect in res.output.replace("\n", " ")
    assert _state(root) == before
    assert _lidar_obs(root) == {("102", "L003"), ("102", "L004")}

    # with a line_control.csv and its key in survey.toml already there
    good, good_lines = _edited(root, {("L004", "102"): {"decision": "reject"}},
                               {("L004/2-3", "102"): {"decision": "accept"}})
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(good), "--line-decisions",
                                   str(good_lines)])
    assert res.exit_code == 0, res.output
    before = _state(root)
    assert before["line_control.csv"] is not None and b"line_control" in before["survey.toml"]
    d, ld = _edited(root, {("L003", "102"): {"decision": "reject"}, ("L004", "102"): {"decision": "reject"}},
                    {(L003_HIP, "102"): {"decision": "accept"}, ("L004/2-3", "102"): {"decision": "accept"}})
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    assert res.exit_code == 2
    assert (f"field 'cov_m2': not a covariance (not positive semi-definite) (the survey does not load with the new "
            f"tables: image_points.csv, line_control.csv, control_decisions.csv put back as they were)") in res.output.replace("\n", " ")
    assert _state(root) == before
