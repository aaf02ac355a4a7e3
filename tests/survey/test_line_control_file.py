"""line_control.csv (lidarcat.survey.lines): located errors, the [files] hook, line_residuals.csv."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.survey.lines import LINE_COLUMNS, read_line_control

HEADER = ",".join(LINE_COLUMNS)
LINE_R1 = "R1,,100.0,200.0,10.0,112.0,200.0,10.5,0.03,0.3,,,,,"
OBS_R1 = "R1,{photo},-1.0,2.0,3.0,2.5,,,,,,,,,0.004"


def _obs(photo="0001", x1="-1.0", y1="2.0", x2="3.0", y2="2.5", sd="0.004", line="R1"):
    return f"{line},{photo},,,,,,,,,{x1},{y1},{x2},{y2},{sd}"


def _write(tmp_path: Path, *rows: str) -> Path:
    p = tmp_path / "line_control.csv"
    p.write_text("# control lines\n" + HEADER + "\n" + "\n".join(rows) + "\n")
    return p


def test_reads_lines_and_observations(tmp_path):
    lines, obs = read_line_control(_write(tmp_path, LINE_R1, _obs(), _obs("0002")), ["0001", "0002"])
    assert [ln.line for ln in lines] == ["R1"]
    np.testing.assert_allclose(lines[0].b_m, [112.0, 200.0, 10.5])
    # sd 0.03 m across and 0.3 m along the line: the along-line variance of A is 0.09 m^2
    t = (lines[0].b_m - lines[0].a_m) / np.linalg.norm(lines[0].b_m - lines[0].a_m)
    assert t @ lines[0].cov_m2[:3, :3] @ t == pytest.approx(0.09)
    assert [(o.line, o.photo) for o in obs] == [("R1", "0001"), ("R1", "0002")]
    np.testing.assert_allclose(obs[1].xy2_mm, [3.0, 2.5])


@pytest.mark.parametrize("rows, message", [
    ((LINE_R1, _obs("0009")), "line_control.csv:4: field 'photo': unknown photo '0009' (not in photos.csv)"),
    ((LINE_R1, _obs(x2="-1.0", y2="2.0")),
     "line_control.csv:4: line R1 on photo 0001: the two image points coincide (a line of zero length)"),
    (("R1,,100.0,200.0,10.0,100.0,200.0,10.0,0.03,,,,,,", _obs()),
     "line_control.csv:3: line 'R1': its end points coincide (a line of zero length)"),
    ((LINE_R1, _obs(x1="nan")), "line_control.csv:4: field 'x1_mm': 'nan' is not a finite number"),
    ((LINE_R1, _obs(y2="inf")), "line_control.csv:4: field 'y2_mm': 'inf' is not a finite number"),
    (("R1,,100.0,200.0,nan,112.0,200.0,10.5,0.03,,,,,,",), "line_control.csv:3: field 'h1_m': 'nan' is not a finite number"),
    ((LINE_R1, _obs(sd="0")), "line_control.csv:4: field 'sd_mm': must be positive, got '0'"),
    ((LINE_R1, _obs(line="R2")),
     "line_control.csv:4: field 'line': observation of line 'R2', which no row defines (a row with this line "
     "id and photo empty)"),
    ((LINE_R1, _obs(), _obs()),
     "line_control.csv:5: line 'R1' is measured twice on photo '0001' (also on line 4); keep one measurement"),
    ((LINE_R1, LINE_R1), "line_control.csv:4: field 'line': line 'R1' is already defined on line 3"),
    ((LINE_R1, _obs(x1="")), "line_control.csv:4: field 'x1_mm': empty value; a number is required"),
])
def test_malformed_line_file_errors_are_located(tmp_path, rows, message):
    path = _write(tmp_path, *rows)
    with pytest.raises(SurveyError) as ex:
        read_line_control(path, ["0001", "0002"])
    assert str(ex.value) == f"{path.parent}/{message}"
