"""line_control.csv (lidarcat.survey.lines): located errors, the [files] hook, line_residuals.csv."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.survey.lines import LINE_COLUMNS, read_line_control

HEADER = ",".join(LINE_COLUMNS)
LINE_R1 = "R1,,100.0,200.0,10.0,112.0,200.0,10.5,0.03,0.3,,,,,,,,,,"


def _obs(photo="0001", x1="-1.0", y1="2.0", x2="3.0", y2="2.5", sd="0.004", line="R1"):
    return f"{line},{photo},,,,,,,,,{x1},{y1},{x2},{y2},{sd},,,,,"


def _obs_px(photo="0001", c1="100", r1="200", c2="900", r2="260", sd="0.5", line="R1"):
    return f"{line},{photo},,,,,,,,,,,,,,{c1},{r1},{c2},{r2},{sd}"


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
    (("R1,,100.0,200.0,10.0,100.0,200.0,10.0,0.03,,,,,,,,,,,", _obs()),
     "line_control.csv:3: line 'R1': its end points coincide (a line of zero length)"),
    ((LINE_R1, _obs(x1="nan")), "line_control.csv:4: field 'x1_mm': 'nan' is not a finite number"),
    ((LINE_R1, _obs(y2="inf")), "line_control.csv:4: field 'y2_mm': 'inf' is not a finite number"),
    (("R1,,100.0,200.0,nan,112.0,200.0,10.5,0.03,,,,,,,,,,,",), "line_control.csv:3: field 'h1_m': 'nan' is not a finite number"),
    ((LINE_R1, _obs(sd="0")), "line_control.csv:4: field 'sd_mm': must be positive, got '0'"),
    ((LINE_R1, _obs(line="R2")),
     ("line_control.csv:4: field 'line': observation of line 'R2', which no row defines (a row with this line "
      "id and photo empty)")),
    ((LINE_R1, _obs(), _obs()),
     "line_control.csv:5: line 'R1' is measured twice on photo '0001' (also on line 4); keep one measurement"),
    ((LINE_R1, LINE_R1), "line_control.csv:4: field 'line': line 'R1' is already defined on line 3"),
    ((LINE_R1, _obs(x1="")), "line_control.csv:4: field 'x1_mm': empty value; a number is required"),
    ((LINE_R1, _obs_px()), "line_control.csv:4: field 'col1_px': pixel coordinates need the photo's camera "
                           "(read the file through Survey.load)"),
    ((LINE_R1, "R1,0001,,,,,,,,,,,,,,,,,,"),
     "line_control.csv:4: line 'R1' on photo '0001': give the image points either in mm (x1_mm, y1_mm, x2_mm, "
     "y2_mm, sd_mm) or in pixels (col1_px, row1_px, col2_px, row2_px, sd_px)"),
])
def test_malformed_line_file_errors_are_located(tmp_path, rows, message):
    path = _write(tmp_path, *rows)
    with pytest.raises(SurveyError) as ex:
        read_line_control(path, ["0001", "0002"])
    assert str(ex.value) == f"{path.parent}/{message}"


def test_pixel_observations_go_through_the_camera(tmp_path):
    from lidarcat.synthetic import demo_camera

    cam = demo_camera()
    lines, obs = read_line_control(_write(tmp_path, LINE_R1, _obs_px(), _obs("0002")), ["0001", "0002"],
                                   {"0001": cam, "0002": cam})
    np.testing.assert_allclose(obs[0].xy1_mm, cam.pixel_to_photo(np.array([[100.0, 200.0]]))[0])
    np.testing.assert_allclose(obs[0].xy2_mm, cam.pixel_to_photo(np.array([[900.0, 260.0]]))[0])
    assert obs[0].sd_mm == pytest.approx(0.5 * 0.006) and obs[0].pixel_mm == pytest.approx(0.006)
    assert obs[1].sd_mm == 0.004 and obs[1].pixel_mm == pytest.approx(0.006)


def _project(eo, f_mm, X):
    from lidarcat.geometry.collinearity import project

    xy, u3 = project(np.broadcast_to(eo, (len(X), 6)), X, np.full(len(X), f_mm))
    return xy, u3


def test_survey_with_line_control_writes_line_residuals_naming_a_wrong_line(tmp_path):
    """The demo survey plus roof lines measured (exactly) in its photos at the adjusted orientation,
    one of them 3 px (0.018 mm) off: line_residuals.csv and summary.json name it."""
    import json

    from lidarcat import Survey
    from lidarcat.survey.adjustment import adjust_survey
    from lidarcat.synthetic import write_synthetic_survey

    demo = write_synthetic_survey(tmp_path / "s", lidar_density_m2=0.2)
    first, _ = adjust_survey(demo.path, outdir=tmp_path / "a0")
    p = first.problem
    sd_mm = 0.003
    lo = np.abs(p.xy_mm).max(axis=0) * 0.9
    rows = []
    rng = np.random.default_rng(5)
    pts = first.points_m[p.point_role == "tie"]
    bad = None
    for k in range(8):
        c = pts[rng.integers(len(pts))]
        az = np.pi * k / 8
        d = np.array([np.cos(az), np.sin(az), 0.0])
        a, b = c - 6 * d, c + 6 * d
        rows.append(f"R{k},,{a[0]},{a[1]},{a[2]},{b[0]},{b[1]},{b[2]},0.02,0.2,,,,,,,,,,")
        for i, pid in enumerate(p.photo_ids):
            xy, u3 = _project(first.eo_params[i], p.focal_length_mm[i], np.stack([a + 0.2 * (b - a), a + 0.8 * (b - a)]))
            if np.all(u3 < 0) and np.all(np.abs(xy) < lo):
                if bad is None:
                    t = (xy[1] - xy[0]) / np.linalg.norm(xy[1] - xy[0])
                    xy = xy + 0.018 * np.array([-t[1], t[0]])
                    bad = f"line R{k} on photo {pid}"
                rows.append(f"R{k},{pid},,,,,,,,,{xy[0, 0]},{xy[0, 1]},{xy[1, 0]},{xy[1, 1]},{sd_mm},,,,,")
    _write(demo.path, *rows)
    toml = demo.path / "survey.toml"
    toml.write_text(toml.read_text().replace('extraction_jobs = "jobs.csv"',
                                             'extraction_jobs = "jobs.csv"\nline_control = "line_control.csv"'))
    survey = Survey.load(demo.path)
    assert survey.files["line_control"].name == "line_control.csv"
    res, _ = adjust_survey(survey, outdir=tmp_path / "a1")
    assert res.problem.lines is not None and res.dof == first.dof + 2 * len(res.problem.lines.line_index)
    with open(tmp_path / "a1" / "line_residuals.csv") as fh:
        table = [r for r in csv.reader(line for line in fh if not line.startswith("#"))]
    assert tuple(table[0]) == ("line", "photo", "v_a_mm", "v_b_mm", "v_a_px", "v_b_px", "redundancy_a",
                               "redundancy_b", "w", "w_critical", "rejected")
    assert len(table) - 1 == len(res.problem.lines.line_index) > 8
    summary = json.loads((tmp_path / "a1" / "summary.json").read_text())
    assert summary["line_control"]["rejected"] == [bad]
    # residuals in pixels through the demo camera's 6 um pixels
    np.testing.assert_allclose(np.array([r[4:6] for r in table[1:]], dtype=float),
                               np.array([r[2:4] for r in table[1:]], dtype=float) / 0.006, rtol=1e-6)
    rejected = [r for r in table[1:] if r[-1] == "True"]
    assert [f"line {r[0]} on photo {r[1]}" for r in rejected] == [bad]


def test_survey_load_reports_a_bad_line_file(tmp_path):
    from lidarcat import Survey
    from lidarcat.synthetic import write_synthetic_survey

    demo = write_synthetic_survey(tmp_path / "s", lidar_density_m2=0.2)
    path = _write(demo.path, LINE_R1, _obs("X9"))
    toml = demo.path / "survey.toml"
    toml.write_text(toml.read_text().replace('extraction_jobs = "jobs.csv"',
                                             'extraction_jobs = "jobs.csv"\nline_control = "line_control.csv"'))
    with pytest.raises(SurveyError, match=r"line_control.csv:4: field 'photo': unknown photo 'X9' \(not in photos.csv\)$"):
        Survey.load(demo.path)
    assert path.exists()
