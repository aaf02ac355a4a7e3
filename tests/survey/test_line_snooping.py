"""`lidarcat adjust --snooping remove` removes a wrong line observation of line control (issue 29):
named in summary.json (``line_control.removed``, with its w) and in line_residuals.csv."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.geometry.collinearity import project
from lidarcat.survey.lines import LINE_COLUMNS


def _demo_with_lines(tmp_path: Path, offset_mm: float = 0.018) -> tuple[Path, str, int]:
    """The demo survey plus 8 roof lines measured exactly at its adjusted orientation (sd 3 um), the
    first observation *offset_mm* across its line; returns the folder, that observation's label and
    the number of line observations."""
    from lidarcat.survey.adjustment import adjust_survey
    from lidarcat.synthetic import write_synthetic_survey

    demo = write_synthetic_survey(tmp_path / "s", lidar_density_m2=0.2)
    first, _ = adjust_survey(demo.path, outdir=tmp_path / "a0")
    p = first.problem
    lo = np.abs(p.xy_mm).max(axis=0) * 0.9
    rows, bad = [], None
    rng = np.random.default_rng(5)
    noise = np.random.default_rng(6)
    pts = first.points_m[p.point_role == "tie"]
    for k in range(8):
        c = pts[rng.integers(len(pts))]
        az = np.pi * k / 8
        d = np.array([np.cos(az), np.sin(az), 0.0])
        a, b = c - 6 * d, c + 6 * d
        rows.append(f"R{k},,{a[0]},{a[1]},{a[2]},{b[0]},{b[1]},{b[2]},0.02,0.2,,,,,,,,,,")
        for i, pid in enumerate(p.photo_ids):
            ends = np.stack([a + 0.2 * (b - a), a + 0.8 * (b - a)])
            xy, u3 = project(np.broadcast_to(first.eo_params[i], (2, 6)), ends, np.full(2, p.focal_length_mm[i]))
            if np.all(u3 < 0) and np.all(np.abs(xy) < lo):
                xy = xy + noise.normal(0.0, 0.003, (2, 2))         # the measurement's sd, 3 um
                if bad is None:
                    t = (xy[1] - xy[0]) / np.linalg.norm(xy[1] - xy[0])
                    xy = xy + offset_mm * np.array([-t[1], t[0]])
                    bad = (f"R{k}", str(pid))
                rows.append(f"R{k},{pid},,,,,,,,,{xy[0, 0]},{xy[0, 1]},{xy[1, 0]},{xy[1, 1]},0.003,,,,,")
    (demo.path / "line_control.csv").write_text(",".join(LINE_COLUMNS) + "\n" + "\n".join(rows) + "\n")
    toml = demo.path / "survey.toml"
    toml.write_text(toml.read_text().replace('extraction_jobs = "jobs.csv"',
                                             'extraction_jobs = "jobs.csv"\nline_control = "line_control.csv"'))
    return demo.path, bad, len(rows) - 8


def _table(path: Path) -> list[list[str]]:
    with open(path, encoding="utf-8") as fh:
        return list(csv.reader(line for line in fh if not line.startswith("#")))


def test_snooping_remove_removes_a_wrong_line_observation(tmp_path):
    folder, (line, photo), n_obs = _demo_with_lines(tmp_path)
    out = tmp_path / "rm"
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(out), "--snooping", "remove", "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "summary.json").read_text())
    lc = summary["line_control"]
    assert [(x["line"], x["photo"]) for x in lc["removed"]] == [(line, photo)]
    # 3 px across, measured with 0.5 px: w (6.5) well above its critical value, that of every 2-D test of
    # the adjustment (image points too: one worst-first loop at the block's family level, 3.95 here)
    assert lc["removed"][0]["w_critical"] == pytest.approx(summary["snooping"]["critical_w"]["2"], abs=1e-9)
    assert 3.9 < lc["removed"][0]["w_critical"] < 4.0 and lc["removed"][0]["w"] > 5
    line_blunders = [b for b in summary["blunders"] if b["kind"] == "line"]
    assert [(b["point"], b["photo"], b["removed"], b["found_by"]) for b in line_blunders] == [
        (line, photo, True, "snooping")]
    assert lc["rejected"] == [] and lc["observations"] == n_obs - 1
    table = _table(out / "line_residuals.csv")
    assert table[0][-1] == "rejected" and len(table) - 1 == n_obs
    gone = [row for row in table[1:] if row[-1] == "removed"]
    assert [(row[0], row[1]) for row in gone] == [(line, photo)]
    # its residual at the final orientation is the planted 0.018 mm across the line, at both ends
    assert np.allclose(np.abs(np.array(gone[0][2:4], dtype=float)), 0.018, atol=0.009)
    assert all(row[-1] == "False" for row in table[1:] if row[-1] != "removed")


def test_snooping_report_keeps_the_wrong_line_observation(tmp_path):
    folder, (line, photo), n_obs = _demo_with_lines(tmp_path)
    out = tmp_path / "rp"
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(out), "--snooping", "report", "--json"])
    assert r.exit_code == 0, r.output
    lc = json.loads((out / "summary.json").read_text())["line_control"]
    assert "removed" not in lc and lc["rejected"] == [f"line {line} on photo {photo}"]
    assert len(_table(out / "line_residuals.csv")) - 1 == n_obs


def test_the_text_report_names_the_removed_line(tmp_path):
    folder, (line, photo), _ = _demo_with_lines(tmp_path)
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(tmp_path / "rm"), "--snooping", "remove"])
    assert r.exit_code == 0, r.output
    assert f"Line snooping removed line {line} on photo {photo} (w 6." in r.output
