"""decisions.csv's column ``method``: how each pixel was measured, written by the stage and read when fed back.

A point located along one edge (``photocontrol.measure`` step 3a) is written beside its two edges; any other
measured point beside its own edges is refused ("the same edge fits").  The fed-back row is recognised by its
``method`` (``along``), not by its reason text, so a user who rewrites the reason changes nothing; a file without
the column (written before it) falls back to the reason's "located along one edge".

The block is tests/stages/control_block.py's (two photos, L003 and L004 measured on photo 102 where their edges
cross).  No pair of it is measured along one edge, so the tests give L003's row on 102 ``method`` ``along`` and its
two edges ``written`` -- the rows the stage writes for such a point.
"""

from __future__ import annotations


import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.stages._control_report import decision_rows
from lidarcat.stages.measure_control import DECISION_FIELDS
from lidarcat.survey.folder import Survey

from control_block import copy_survey, edited_decisions, measured_block, read_rows, write_rows

ALONG_REASON = ("located along one edge: the edges of planes 1-2 and 2-3 lie nearly on one image line, their "
                "intersection at 12 deg: sd 0.26 px across the edge, 1.79 px along it")


def _found_edges(root):
    """L003's edges found on photo 102 (with pixels; ``in_point`` beside its point), as the stage writes them
    beside an along-one-edge point: ``written``, accepted."""
    rows = read_rows(root / "out" / "measure_control" / "line_decisions.csv")
    found = [r["line"] for r in rows if (r["point"], r["photo"]) == ("L003", "102") and r["col1_px"] != ""]
    assert len(found) == 2, found
    return {(lid, "102"): {"status": "written", "reason": "", "decision": "accept"} for lid in found}


@pytest.fixture(scope="module")
def blocks(tmp_path_factory):
    return measured_block(tmp_path_factory.mktemp("method"))




def _state(root):
    return {n: (root / n).read_bytes() if (root / n).is_file() else None
            for n in ("image_points.csv", "line_control.csv", "control_decisions.csv", "survey.toml")}


def _feed(root, point_cells, fields=DECISION_FIELDS):
    """Feed back L003 on 102 with *point_cells* and its two edges accepted; the decisions file under *fields*."""
    d, ld = edited_decisions(root, {("L003", "102"): point_cells}, _found_edges(root))
    write_rows(d, fields, [{k: v for k, v in r.items() if k in fields} for r in read_rows(d)])
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(d), "--line-decisions", str(ld)])
    return res, d, ld


def _observations(root):
    sv = Survey.load(root)
    pts = {(str(a), str(b)) for a, b in zip(sv.image_points.photo, sv.image_points.point) if str(b).startswith("L")}
    lines = {(r["line"], r["photo"]) for r in read_rows(root / "line_control.csv") if r["photo"]}
    return pts, lines


def test_the_stage_writes_how_each_pixel_was_measured(blocks):
    _, root = blocks
    dec = read_rows(root / "out" / "measure_control" / "decisions.csv")
    assert list(dec[0]) == DECISION_FIELDS and DECISION_FIELDS.index("method") == DECISION_FIELDS.index("status") + 1
    got = {(r["point"], r["photo"]): r["method"] for r in dec}
    measured = {k for k, r in zip(got, dec) if r["col_px"] != ""}
    assert measured == {("L003", "102"), ("L004", "102")}
    assert all(got[k] == "corner" for k in measured)
    assert all(v == "" for k, v in got.items() if k not in measured)      # no pixel: no method


def test_decision_rows_write_along_for_a_point_located_along_one_edge():
    from lidarcat.photocontrol.measure import Measurement

    cov = np.array([[2.0, 1.5], [1.5, 1.6]])
    along = Measurement("C1", "101", np.array([604.8, 637.5]), cov, "measured", ALONG_REASON, along_line=True)
    lost = along.failed("rejected", "inconsistent with the photo's common shift")
    plain = Measurement("C2", "101", np.array([624.9, 459.4]), np.diag([0.25, 0.07]), "measured")
    none = Measurement("C3", "101", np.full(2, np.nan), np.full((2, 2), np.nan), "no_edges", "1 of 3 edges found")
    rows = [dict(zip(DECISION_FIELDS, r)) for r in decision_rows([along, lost, plain, none])]
    assert [r["method"] for r in rows] == ["along", "along", "corner", ""]


def test_an_along_row_with_a_rewritten_reason_keeps_its_meaning(blocks, tmp_path):
    _, src = blocks
    root = copy_survey(src, tmp_path)
    res, _, _ = _feed(root, {"method": "along", "reason": "checked by hand: the corner under the tree"})
    assert res.exit_code == 0, res.output
    pts, lines = _observations(root)
    assert ("102", "L003") in pts                                          # the point beside its two edges
    assert set(_found_edges(root)) <= lines


def test_the_column_decides_over_the_reason(blocks, tmp_path):
    """A ``corner`` row whose reason says "located along one edge": the same fits as its edges, refused."""
    _, src = blocks
    root = copy_survey(src, tmp_path)
    before = _state(root)
    res, d, ld = _feed(root, {"method": "corner", "reason": ALONG_REASON})
    assert res.exit_code == 2, res.output
    lid, _ = min(_found_edges(root))
    n = next(i for i, r in enumerate(read_rows(ld)) if (r["line"], r["photo"]) == (lid, "102")) + 2
    assert (f"{ld}:{n}: line '{lid}' on photo '102': vertex 'L003' has a point observation on this photo "
            f"(accepted in {d.name}) measured from the same edge fits; accept the point or its edges, not both"
            in res.output.replace("\n", " ")), res.output
    assert _state(root) == before


@pytest.mark.parametrize("reason, ok", [(ALONG_REASON, True), ("checked by hand", False)], ids=["along", "rewritten"])
def test_a_file_without_the_column_is_read_by_the_reason(blocks, tmp_path, reason, ok):
    _, src = blocks
    root = copy_survey(src, tmp_path)
    before = _state(root)
    res, d, _ = _feed(root, {"reason": reason}, [f for f in DECISION_FIELDS if f != "method"])
    assert "method" not in read_rows(d)[0]
    if ok:
        assert res.exit_code == 0, res.output
        assert ("102", "L003") in _observations(root)[0]
    else:   # an ordinary point beside its own edges
        assert res.exit_code == 2 and "measured from the same edge fits" in res.output.replace("\n", " ")
        assert _state(root) == before


@pytest.mark.parametrize("cell", ["alongside", "2"])
def test_a_bad_method_is_a_located_error(blocks, tmp_path, cell):
    _, src = blocks
    root = copy_survey(src, tmp_path)
    before = _state(root)
    res, d, _ = _feed(root, {"method": cell})
    assert res.exit_code == 2, res.output
    n = next(i for i, r in enumerate(read_rows(d)) if (r["point"], r["photo"]) == ("L003", "102")) + 2
    assert (f"{d}:{n}: field 'method': must be corner or along (or empty: no pixel measured), got {cell!r}"
            in res.output.replace("\n", " ")), res.output
    assert _state(root) == before
