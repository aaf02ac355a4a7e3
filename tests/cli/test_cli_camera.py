"""``lidarcat camera correct``."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
from click.testing import CliRunner

from conftest import ROOT, THESIS_SURVEY, THESIS_TABLES
from lidarcat.cli.main import cli

LACTEC = ROOT / "data" / "cameras" / "lactec_dcs14n_2008.toml"


def _read(text: str) -> list[dict[str, str]]:
    return list(csv.DictReader(line for line in io.StringIO(text) if not line.startswith("#")))


def _appendix1() -> dict[tuple[str, str], dict[str, str]]:
    with open(THESIS_TABLES / "appendix1_corrections.csv", encoding="utf-8") as fh:
        rows = _read(fh.read())
    return {(r["photo"], r["point"]): r for r in rows}


def _pixel_csv(tmp_path):
    # other columns are ignored, also an unnamed one (a spreadsheet's trailing comma)
    p = tmp_path / "px.csv"
    p.write_text("# two measurements\nphoto,point,col_px,row_px,comment,\n"
                 "1,701,1715.7,636.9,a,\n5,662,2021.6,111.23,b,\n", encoding="utf-8")
    return p


def test_correct_survey_to_file(tmp_path):
    out = tmp_path / "sub" / "corrected.csv"
    res = CliRunner().invoke(cli, ["camera", "correct", str(THESIS_SURVEY), "-o", str(out)])
    assert res.exit_code == 0, res.output
    assert "153 measurements corrected (camera dcs14n" in res.output
    text = out.read_text(encoding="utf-8")
    rows = _read(text)
    assert list(rows[0])[:4] == ["photo", "point", "x_mm", "y_mm"]
    assert {"dx_ra_mm", "dy_ra_mm", "dx_des_mm", "dy_des_mm", "dx_ref_mm", "dy_ref_mm"} <= set(rows[0])
    assert len(rows) == 153
    ref = _appendix1()
    for r in rows:
        a = ref[(r["photo"], r["point"])]
        assert abs(float(r["x_mm"]) - float(a["x_fotc"])) < 0.0015
        assert abs(float(r["dx_ra_mm"]) - float(a["dx_ra"])) < 0.0015
        tol = 0.0035 if (r["photo"], r["point"]) == ("5", "662") else 0.0015
        assert abs(float(r["y_mm"]) - float(a["y_fotc"])) < tol
    assert sorted(p.name for p in out.parent.iterdir()) == ["corrected.csv", "corrected.csv.json"]  # no temporary left


def test_correct_csv_with_camera_id_to_stdout(tmp_path):
    cams = tmp_path / "cams.toml"
    cams.write_text((THESIS_SURVEY / "camera.toml").read_text(encoding="utf-8") + "\n"
                    + LACTEC.read_text(encoding="utf-8"), encoding="utf-8")
    res = CliRunner().invoke(cli, ["camera", "correct", str(_pixel_csv(tmp_path)),
                                   "--camera", f"{cams}:dcs14n"])
    assert res.exit_code == 0, res.output
    rows = _read(res.output)
    assert [(r["photo"], r["point"], r["camera"]) for r in rows] == [("1", "701", "dcs14n"),
                                                                    ("5", "662", "dcs14n")]
    np.testing.assert_allclose([float(rows[0]["x_mm"]), float(rows[0]["y_mm"])], [1.686, 12.888],
                               atol=0.0015)
    # L = 111.23 reproduces the printed y of the misprinted row
    np.testing.assert_allclose(float(rows[1]["y_mm"]), 17.143, atol=0.0005)


def test_correct_csv_json_with_lactec_camera(tmp_path):
    res = CliRunner().invoke(cli, ["camera", "correct", str(_pixel_csv(tmp_path)),
                                   "--camera", str(LACTEC), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["n_points"] == 2 and doc["cameras"] == ["lactec_dcs14n"] and doc["output"] is None
    p = doc["points"][0]
    # 8 um pixels, 4500 x 3000: x_pfid = 0.008 (1715.7 - 2249.5), minus dx = 0.152
    np.testing.assert_allclose(p["x_fot_mm"], 0.008 * (1715.7 - 2249.5) - 0.152, atol=1e-12)
    np.testing.assert_allclose(p["y_fot_mm"], -0.008 * (636.9 - 1499.5) - 0.139, atol=1e-12)
    np.testing.assert_allclose(p["x_mm"], p["x_fot_mm"] - p["dx_ra_mm"] - p["dx_des_mm"]
                               - p["dx_ref_mm"], atol=1e-12)


def test_csv_without_camera_is_clean_error(tmp_path):
    res = CliRunner().invoke(cli, ["camera", "correct", str(_pixel_csv(tmp_path))])
    assert res.exit_code == 2
    assert "Traceback" not in res.output
    assert res.output.strip().splitlines() == [
        f"Error: {tmp_path / 'px.csv'}: a CSV of pixel measurements needs --camera FILE[:ID] "
        f"(a survey folder brings its own camera)"]


def test_bad_inputs_leave_no_output(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("photo,point,col_px\n1,2,3\n", encoding="utf-8")
    out = tmp_path / "o.csv"
    res = CliRunner().invoke(cli, ["camera", "correct", str(bad), "--camera", str(LACTEC),
                                   "-o", str(out)])
    assert res.exit_code == 2
    assert "bad.csv:1: missing column 'row_px'" in res.output
    assert not out.exists() and list(tmp_path.iterdir()) == [bad]
    res = CliRunner().invoke(cli, ["camera", "correct", str(_pixel_csv(tmp_path)),
                                   "--camera", f"{LACTEC}:nope"])
    assert res.exit_code == 2 and "no camera 'nope'; defined: lactec_dcs14n" in res.output


def test_survey_with_other_camera(tmp_path):
    res = CliRunner().invoke(cli, ["camera", "correct", str(THESIS_SURVEY), "--camera", str(LACTEC),
                                   "--json", "-o", str(tmp_path / "c.csv")])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)
    assert doc["cameras"] == ["lactec_dcs14n"] and doc["n_points"] == 153 and "points" not in doc


def test_help_teaches():
    res = CliRunner().invoke(cli, ["camera", "correct", "--help"])
    assert res.exit_code == 0
    for needle in ("SURVEY_OR_CSV", "FILE[:ID]", "mm", "x_mm, y_mm", "Examples:",
                   "lidarcat camera correct data/thesis -o corrected.csv"):
        assert needle in res.output
    res = CliRunner().invoke(cli, ["camera", "--help"])
    assert res.exit_code == 0 and "eq. 01" in res.output and "correct" in res.output


def test_info_default_and_json():
    res = CliRunner().invoke(cli, ["camera", "info"])
    assert res.exit_code == 0, res.output
    assert "[dcs14n] Kodak DCS Pro 14n" in res.output
    assert "3000 x 4500 px of 7.9 x 7.9 um = 23.70 x 35.55 mm" in res.output
    res = CliRunner().invoke(cli, ["camera", "info", str(LACTEC), "--json"])
    assert res.exit_code == 0, res.output
    doc = json.loads(res.output)["lactec_dcs14n"]
    assert (doc["frame_width_mm"], doc["frame_height_mm"]) == (36.0, 24.0)
    # the farthest corner of the 36 x 24 mm frame from the principal point (dx, dy) =
    # (0.152, 0.139) is the bottom-left one; radial distortion only (P1 = P2 = 0)
    x, y = 0.008 * (0 - 2249.5) - 0.152, 0.008 * (1499.5 - 2999) - 0.139
    r2 = x * x + y * y
    corner = np.sqrt(r2) * abs(-6.60603693e-05 * r2 + 5.70499159e-08 * r2 * r2)
    # |r (k1 r^2 + k2 r^4)| still grows at the corner, and the border samples include it
    np.testing.assert_allclose(doc["max_correction_mm"], corner, rtol=1e-12)
    np.testing.assert_allclose(doc["max_correction_px"], corner / 0.008, rtol=1e-12)


def test_info_errors(tmp_path):
    res = CliRunner().invoke(cli, ["camera", "info", str(tmp_path / "none.toml")])
    assert res.exit_code == 2 and "none.toml: file not found" in res.output
