"""Survey folder: the embedded thesis block, and every validation error.

Every error test builds a broken copy of the thesis folder and asserts that the
message names the file, the line (as an editor shows it) and the field.
Errors made by replacing one string are rows of ONE_EDIT_ERRORS / DUPLICATE_ERRORS.
"""

from __future__ import annotations

import csv
import io
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT, THESIS_SURVEY, THESIS_TABLES
from lidarcat._util import dumps_json
from lidarcat.errors import SurveyError
from lidarcat.survey.folder import (
    AdjustmentSettings,
    Survey,
    example_camera_path,
    thesis_survey_path,
)

GPS_CONTROL = ["601", "604", "619", "624", "627", "661", "662", "664"]
GPS_CHECK = ["603", "605", "606", "615", "616", "617", "618", "620", "621", "622", "623",
             "625", "626"]
LIDAR_CONTROL = ["701", "703", "705", "706", "707", "712", "719", "721"]


@pytest.fixture(scope="module")
def thesis() -> Survey:
    return Survey.load()


# ------------------------------------------------------------------ helpers
def copy_thesis(tmp_path: Path) -> Path:
    dest = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, dest, ignore=shutil.ignore_patterns("out"))
    return dest


def edit(folder: Path, name: str, old: str, new: str) -> str:
    """Replace the first *old* in file *name* by *new*; return the new text."""
    p = folder / name
    text = p.read_text(encoding="utf-8")
    assert old in text, f"{old!r} not in {name}"
    text = text.replace(old, new, 1)
    p.write_text(text, encoding="utf-8")
    return text


def line_of(text: str, needle: str, occurrence: int = 1) -> int:
    hits = [i for i, line in enumerate(text.splitlines(), 1) if needle in line]
    return hits[occurrence - 1]


def rewrite_csv(folder: Path, name: str, fn) -> str:
    """Rewrite CSV *name* (comments dropped) as fn(header, rows) -> (header, rows)."""
    p = folder / name
    with open(p, encoding="utf-8") as fh:
        rows = list(csv.reader(line for line in fh if not line.startswith("#")))
    header, body = fn(rows[0], rows[1:])
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    w.writerows(body)
    p.write_text(out.getvalue(), encoding="utf-8")
    return out.getvalue()


def drop_column(col):
    def fn(header, rows):
        i = header.index(col)
        return header[:i] + header[i + 1:], [r[:i] + r[i + 1:] for r in rows]
    return fn


def expect(folder: Path, file: str, line: int, field: str, message: str = ""):
    pattern = rf"{re.escape(file)}:{line}: field '{re.escape(field)}'"
    if message:
        pattern += rf".*{message}"
    with pytest.raises(SurveyError, match=pattern) as ei:
        Survey.load(folder)
    assert str(folder) in str(ei.value)  # the full path of the file
    return ei.value


# ------------------------------------------------------------------ the thesis block
def test_thesis_block_counts(thesis):
    assert thesis.name == "thesis-fierro-2007"
    assert thesis.crs == "EPSG:29192" and thesis.height_system == "orthometric"
    assert thesis.embedded and thesis.root == thesis_survey_path()
    assert thesis.photo_ids == ("1", "2", "3", "4", "5", "6")
    assert list(thesis.cameras) == ["dcs14n"]
    assert {p.camera for p in thesis.photos} == {"dcs14n"}
    assert len(thesis.image_points) == 153
    assert len(thesis.photo_observations()) == 151
    assert int((thesis.image_points.point == "417").sum()) == 2
    assert len(thesis.ground_points) == 39
    src = thesis.ground_points.source.tolist()
    assert (src.count("gps"), src.count("lidar")) == (21, 18)
    assert thesis.tie_points == ("401", "403", "405", "406", "407", "408", "409", "410", "411",
                                 "412", "413", "414", "415", "416", "418")
    assert thesis.lidar_paths == () and thesis.extraction_jobs is None
    root = thesis_survey_path()
    assert thesis.files == {"camera": root / "camera.toml", "photos": root / "photos.csv",
                            "ground_points": root / "ground_points.csv",
                            "image_points": root / "image_points.csv",
                            "control_sets": root / "control_sets.csv"}


def test_image_points_are_appendix1(thesis):
    with open(THESIS_TABLES / "appendix1_corrections.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    ip = thesis.image_points
    assert ip.photo.tolist() == [r["photo"] for r in rows]
    assert ip.point.tolist() == [r["point"] for r in rows]
    np.testing.assert_array_equal(ip.pixel_px, [[float(r["C"]), float(r["L"])] for r in rows])
    np.testing.assert_array_equal(ip.xy_mm, [[float(r["x_fotc"]), float(r["y_fotc"])] for r in rows])
    assert np.isnan(ip.sd_mm).all()


def test_thesis_settings(thesis):
    s = thesis.settings
    assert s == AdjustmentSettings("corrected", 0.006, frozenset({"417"}), "a_priori", 0.05)


def test_thesis_control_sets(thesis):
    assert list(thesis.control_sets) == ["gps", "lidar"]
    gps = thesis.control_set()
    assert gps.name == "gps" and thesis.default_control == "gps"
    assert gps.control.tolist() == GPS_CONTROL
    assert gps.check.tolist() == GPS_CHECK
    np.testing.assert_array_equal(gps.sd_m, np.full((8, 3), 0.25))
    lidar = thesis.control_set("lidar")
    assert lidar.control.tolist() == LIDAR_CONTROL
    assert len(lidar.check) == 31
    np.testing.assert_array_equal(lidar.sd_m, np.tile([0.5, 0.5, 0.15], (8, 1)))
    # checks keep their own ground-point sds: LiDAR 0.50/0.50/0.15, GPS 0.25
    i = lidar.check.tolist().index("702")
    np.testing.assert_array_equal(lidar.check_sd_m[i], [0.5, 0.5, 0.15])
    i = lidar.check.tolist().index("603")
    np.testing.assert_array_equal(lidar.check_sd_m[i], [0.25, 0.25, 0.25])
    with pytest.raises(SurveyError, match="no control set 'nope'; available: gps, lidar"):
        thesis.control_set("nope")


def test_thesis_ground_points_are_table5(thesis):
    with open(THESIS_TABLES / "table5_lidar_points.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    idx = thesis.ground_points.index([r["point"] for r in rows])
    enh = np.array([[float(r[k]) for k in ("E", "N", "h")] for r in rows])
    np.testing.assert_allclose(thesis.ground_points.enh_m[idx], enh, atol=5e-4)
    with pytest.raises(SurveyError, match="point.s. 999 not among the ground points"):
        thesis.ground_points.index(["601", "999"])
    assert thesis.ground_points.index("601").tolist() == [0]


def test_photo_observations_corrected_vs_pixel(thesis):
    corr = thesis.photo_observations("corrected")
    pix = thesis.photo_observations("pixel")
    assert "417" not in corr.point
    np.testing.assert_array_equal(corr.point, pix.point)
    np.testing.assert_array_equal(corr.sd_mm, np.full((151, 2), 0.006))
    diff = np.abs(corr.xy_mm - pix.xy_mm)
    mis = (corr.photo == "5") & (corr.point == "662")
    assert diff[~mis].max() < 0.0015            # rounding of Appendix 1
    assert 0.0025 < diff[mis, 1][0] < 0.0035    # the documented misprint
    with pytest.raises(SurveyError, match="observations kind 'raw'"):
        thesis.photo_observations("raw")


def test_arrays_are_read_only(thesis):
    with pytest.raises(ValueError):
        thesis.image_points.xy_mm[0, 0] = 1.0
    with pytest.raises(ValueError):
        thesis.ground_points.enh_m[0, 0] = 1.0
    cs = thesis.control_set()
    ip, gp = thesis.image_points, thesis.ground_points
    for arr in (ip.photo, ip.point, ip.pixel_px, ip.sd_mm, ip.line, gp.point, gp.sd_m, gp.source,
                gp.line, cs.control, cs.check, cs.sd_m, cs.check_sd_m):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = arr[1]


def test_select_and_lines(thesis):
    ip = thesis.image_points
    sub = ip.select(ip.photo == "5")
    assert len(sub) == len(set(sub.point.tolist())) and set(sub.photo.tolist()) == {"5"}
    i = sub.point.tolist().index("662")
    assert sub.line[i] == 126  # line of image_points.csv, comments counted
    assert sub.where(i).endswith("image_points.csv:126")


def test_output_dir_and_summary(thesis, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert thesis.output_dir() == tmp_path / "lidarcat-out"
    assert thesis.output_dir("x") == Path("x")
    copy = Survey.load(copy_thesis(tmp_path))
    assert not copy.embedded and copy.output_dir() == tmp_path / "survey" / "out"
    d = thesis.to_dict()
    assert d["n_image_points"] == 153 and d["n_observations"] == 151
    assert d["control_sets"] == {"gps": {"control": 8, "check": 13},
                                 "lidar": {"control": 8, "check": 31}}
    assert '"name": "thesis-fierro-2007"' in dumps_json(d)


def test_load_by_toml_path_and_missing(tmp_path):
    s = Survey.load(THESIS_SURVEY / "survey.toml")
    assert s.root == THESIS_SURVEY and not s.embedded
    with pytest.raises(SurveyError, match="survey folder not found"):
        Survey.load(tmp_path / "nope")
    with pytest.raises(SurveyError, match="no survey.toml in this folder"):
        Survey.load(tmp_path)


def test_embedded_paths():
    assert (thesis_survey_path() / "image_points.csv").is_file()
    assert example_camera_path().is_file()
    assert example_camera_path("lactec_dcs14n_2008.toml") == example_camera_path()
    with pytest.raises(SurveyError, match="available: lactec_dcs14n_2008"):
        example_camera_path("nope")


# ------------------------------------------------------------------ optional content
def test_photos_with_positions_and_attitudes(tmp_path):
    f = copy_thesis(tmp_path)
    with open(THESIS_TABLES / "table6_eop_gps.csv", encoding="utf-8") as fh:
        eo = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    cols = ["X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg", "sd_X0", "sd_Y0", "sd_Z0"]
    rewrite_csv(f, "photos.csv", lambda h, rows: (
        h + cols, [r + [e[c] for c in cols] for r, e in zip(rows, eo)]))
    s = Survey.load(f)
    np.testing.assert_allclose(s.photo("1").position_m, [677344.86, 7183454.439, 2255.938])
    np.testing.assert_allclose(s.photo("6").attitude_deg, [-6.20025, 1.01147, 68.00129])
    np.testing.assert_allclose(s.photo("2").sd_position_m, [1.78, 2.356, 0.427])
    assert s.photo("2").sd_attitude_deg is None
    assert s.camera_of("3").id == "dcs14n"
    with pytest.raises(ValueError):
        s.photo("1").position_m[0] = 0.0
    with pytest.raises(SurveyError, match="no photo '9'"):
        s.photo("9")


def test_pixel_only_defaults(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "image_points.csv", drop_column("x_mm"))
    rewrite_csv(f, "image_points.csv", drop_column("y_mm"))
    edit(f, "survey.toml", 'observations = "corrected"', "")
    edit(f, "survey.toml", "image_sd_mm = 0.006", "")
    s = Survey.load(f)
    assert s.settings.observations == "pixel"
    assert s.settings.image_sd_mm == pytest.approx(0.75 * 0.0079)
    obs = s.photo_observations()
    assert np.isfinite(obs.xy_mm).all() and len(obs) == 151
    with pytest.raises(SurveyError, match=r"image_points.csv:2: field 'x_mm': no corrected"):
        s.photo_observations("corrected")


def test_lidar_globs_and_extraction_jobs(tmp_path):
    f = copy_thesis(tmp_path)
    (f / "tiles").mkdir()
    for n in ("b.laz", "a.laz", "c.txt"):
        (f / "tiles" / n).write_bytes(b"")
    (f / "extra.las").write_bytes(b"")
    (f / "jobs.txt").write_text("faixa.xyz P799 677757.8 7183482.0 0.15 5.0\n", encoding="utf-8")
    edit(f, "survey.toml", 'control_sets = "control_sets.csv"',
         'control_sets = "control_sets.csv"\nlidar = ["tiles/*.laz", "extra.las"]\n'
         'extraction_jobs = "jobs.txt"\n[lidar]\ncrs = "EPSG:31982"')
    # 799 is measured on one photo only: legal because an extraction job names it
    text = (f / "image_points.csv").read_text(encoding="utf-8")
    (f / "image_points.csv").write_text(text + "3,799,1000,1000,,\n", encoding="utf-8")
    s = Survey.load(f)
    assert s.lidar_paths == (f / "extra.las", f / "tiles" / "a.laz", f / "tiles" / "b.laz")
    assert s.lidar_crs == "EPSG:31982" and s.extraction_jobs == f / "jobs.txt"
    assert "799" in s.tie_points


# ------------------------------------------------------------------ one edit, one located error
#: (file, old, new, needle, field, message): replace *old* by *new* in *file* of a copy of the
#: thesis folder; Survey.load must fail at the line of *needle*, naming *field* and *message*.
ONE_EDIT_ERRORS = [
    # survey.toml
    ("survey.toml", "chi2_level = 0.05", "chi2_level = 0.05\nmax_iterations = 3", "max_iterations",
     "max_iterations", r"unknown key 'max_iterations' in \[adjustment\]; allowed: observations"),
    ("survey.toml", "[adjustment]", "[bundle]\nx = 1\n\n[adjustment]", "[bundle]", "bundle",
     "unknown key/table"),
    ("survey.toml", 'crs = "EPSG:29192"', "", "[survey]", "crs", "missing required key 'crs'"),
    ("survey.toml", 'observations = "corrected"', 'observations = "raw"', "observations =",
     "observations", "'raw' is not one of 'corrected', 'pixel'"),
    ("survey.toml", "image_sd_mm = 0.006", 'image_sd_mm = "0.006"', "image_sd_mm =", "image_sd_mm",
     "expected int/float"),
    ("survey.toml", "image_sd_mm = 0.006", "image_sd_mm = true", "image_sd_mm =", "image_sd_mm",
     "expected int/float, got True$"),
    ("survey.toml", "image_sd_mm = 0.006", "image_sd_mm = -0.006", "image_sd_mm =", "image_sd_mm",
     "must be positive"),
    ("survey.toml", "image_sd_mm = 0.006", "image_sd_mm = nan", "image_sd_mm =", "image_sd_mm",
     "must be a finite number"),
    ("survey.toml", "image_sd_mm = 0.006", "image_sd_mm = 1e300", "image_sd_mm =", "image_sd_mm",
     r"1e\+300 mm is outside the sane range 1e-06\.\.10 mm$"),
    ("survey.toml", 'crs = "EPSG:29192"', 'crs = "EPSG:99999999"', "crs =", "crs", r"unknown CRS 'EPSG:99999999'"),
    ("survey.toml", 'variance_factor = "a_priori"', 'variance_factor = "posterior"',
     "variance_factor =", "variance_factor", "not one of 'a_priori', 'a_posteriori'"),
    ("survey.toml", "chi2_level = 0.05", "chi2_level = 5", "chi2_level =", "chi2_level",
     "between 0 and 1"),
    ("survey.toml", 'exclude_points = ["417"]', 'exclude_points = ["417", "999"]', "exclude_points =",
     "exclude_points", "point '999' is defined nowhere"),
    ("survey.toml", 'exclude_points = ["417"]', 'exclude_points = "417"', "exclude_points =",
     "exclude_points", "expected list"),
    ("survey.toml", 'default_control = "gps"', 'default_control = "GPS"', "default_control =",
     "default_control", r"control set 'GPS' is not in control_sets \(gps, lidar\)"),
    ("survey.toml", 'name = "thesis-fierro-2007"', 'name = ""', "name =", "name", "must not be empty"),
    ("survey.toml", 'photos = "photos.csv"', 'photos = "fotos.csv"', "photos =", "photos",
     "file 'fotos.csv' not found"),
    ("survey.toml", 'control_sets = "control_sets.csv"',
     'control_sets = "control_sets.csv"\nlidar = ["tiles/*.laz"]', "lidar =", "lidar", "matches no file"),
    ("survey.toml", 'control_sets = "control_sets.csv"',
     'control_sets = "control_sets.csv"\nlidar = "t.laz"', "lidar =", "lidar",
     "LiDAR file 't.laz' not found"),
    # survey.toml [assessment] (the thesis block states the thesis's settings)
    ("survey.toml", "scale = 2000\n", "scale = -2\n", "scale =", "scale",
     r"must be a positive scale denominator \(2000 for 1:2000\), got -2$"),
    ("survey.toml", "contour_interval_m = 2.0", "contour_interval_m = 0", "contour_interval_m =",
     "contour_interval_m", r"must be positive \(metres\), got 0$"),
    ("survey.toml", "alpha = 0.10", "alpha = 1.5", "alpha =", "alpha",
     "must lie between 0 and 1, got 1.5$"),
    ("survey.toml", 'pec_class = "A"', 'pec_class = "Z"', "pec_class =", "pec_class",
     "'Z' is not one of A, B, C$"),
    ("survey.toml", 'plotting_position = "hazen"', 'plotting_position = "weibull"', "plotting_position =",
     "plotting_position", "'weibull' is not one of filliben, hazen, blom$"),
    ("survey.toml", 'pec_class = "A"', 'pec_class = "A"\ncolour = 1', "colour =", "colour",
     r"unknown key 'colour' in \[assessment\]"),
    # camera.toml of a survey
    ("camera.toml", "k3 = 0.0", "k3 = 0.0\nk4 = 1.0", "k4 =", "k4", "unknown key"),
    ("camera.toml", "columns_px = 3000", "columns_px = 0", "columns_px", "columns_px", "at least 1 pixel"),
    # photos.csv
    ("photos.csv", "4,dcs14n", "4,dcs15n", "4,dcs15n", "camera",
     r"camera 'dcs15n' is not defined in camera.toml \(defined: dcs14n\)"),
    # image_points.csv
    ("image_points.csv", "1,701,", "9,701,", "9,701,", "photo",
     "photo '9' is not in photos.csv; add it there or fix the id"),
    ("image_points.csv", "1,702,2643.3,", "1,702,abc,", "1,702,", "col_px", "'abc' is not a number"),
    ("image_points.csv", "1,702,2643.3,", "1,702,nan,", "1,702,", "col_px", "'nan' is not a finite number"),
    ("image_points.csv", "1,702,2643.3,", "1,702,inf,", "1,702,", "col_px", "'inf' is not a finite number"),
    ("image_points.csv", "1,702,2643.3,", "1,702,-Infinity,", "1,702,", "col_px",
     "'-Infinity' is not a finite number"),
    ("image_points.csv", "1,702,2643.3,449.8,9.095,14.432", "1,702,2643.3,449.8,9.095,", "1,702,",
     "y_mm", "fill both x_mm and y_mm or neither"),
    ("image_points.csv", "1,702,2643.3,449.8,9.095,14.432", "1,702,,,,", "1,702,", "x_mm",
     "no coordinates"),
    ("image_points.csv", "1,702,", "1,7020,", "1,7020,", "point",
     "'7020' is measured on photo '1' only and defined nowhere"),
    # ground_points.csv
    ("ground_points.csv", "603,677249.591,", "603,677249.591x,", "603,", "E",
     "'677249.591x' is not a number"),
    ("ground_points.csv", "603,677249.591,", "603,NaN,", "603,", "E", "'NaN' is not a finite number"),
    ("ground_points.csv", "603,677249.591,", "603,,", "603,", "E", "empty value; a number is required"),
    ("ground_points.csv", "908.745,0.25,0.25,0.25,gps", "908.745,0.25,0.25,0,gps", "603,", "sd_h",
     "must be positive"),
    ("ground_points.csv", "908.745,0.25,0.25,0.25,gps", "908.745,0.25,0.25,0.25,", "603,", "source",
     "empty; name the source"),
    # control_sets.csv
    ("control_sets.csv", "gps,619,control", "gps,6190,control", "gps,6190", "point",
     "point '6190' is defined nowhere: not in ground_points.csv"),
    ("control_sets.csv", "gps,605,check", "gps,605,chek", "gps,605", "role",
     "'chek' is not 'control' or 'check'"),
    ("control_sets.csv", "gps,604,control,0.25,0.25,0.25", "gps,604,control,0.25,,0.25", "gps,604",
     "sd_N", "fill all of sd_E, sd_N, sd_h or none"),
]


@pytest.mark.parametrize("file, old, new, needle, field, message", ONE_EDIT_ERRORS,
                         ids=[f"{c[0].split('.')[0]}-{c[4]}" for c in ONE_EDIT_ERRORS])
def test_one_edit_located_error(tmp_path, file, old, new, needle, field, message):
    f = copy_thesis(tmp_path)
    text = edit(f, file, old, new)
    expect(f, file, line_of(text, needle), field, message)


#: (file, old, new, key, field, message): the edit repeats an id; the error is at the second row
#: starting with *key* and names the first one's line.
DUPLICATE_ERRORS = [
    ("photos.csv", "6,dcs14n", "6,dcs14n\n3,dcs14n", "3,", "photo", r"duplicate photo id \(photo='3'\)"),
    ("image_points.csv", "1,701,1715.7,636.9,1.686,12.888",
     "1,701,1715.7,636.9,1.686,12.888\n1,701,1715.8,636.9,1.686,12.888", "1,701,", "point",
     r"duplicate measurement of this point on this photo \(photo='1', point='701'\)"),
    ("ground_points.csv", "603,677249.591", "601,677249.591", "601,", "point",
     r"duplicate ground point id \(point='601'\)"),
    ("control_sets.csv", "gps,605,check,,,", "gps,605,check,,,\ngps,601,check,,,", "gps,601,", "point",
     r"duplicate point in this control set \(set='gps', point='601'\)"),
]


@pytest.mark.parametrize("file, old, new, key, field, message", DUPLICATE_ERRORS,
                         ids=[c[0].split(".")[0] for c in DUPLICATE_ERRORS])
def test_duplicate_names_both_lines(tmp_path, file, old, new, key, field, message):
    f = copy_thesis(tmp_path)
    text = edit(f, file, old, new)
    first, second = [i for i, line in enumerate(text.splitlines(), 1) if line.startswith(key)]
    expect(f, file, second, field, rf"{message}; first defined on line {first}$")


# ------------------------------------------------------------------ survey.toml errors
def test_toml_missing_table(tmp_path):
    f = copy_thesis(tmp_path)
    edit(f, "survey.toml", "[files]", "[adjustment2]")
    with pytest.raises(SurveyError, match="unknown key/table 'adjustment2'"):
        Survey.load(f)


def test_toml_missing_files_table(tmp_path):
    f = copy_thesis(tmp_path)
    (f / "survey.toml").write_text('[survey]\nname = "x"\ncrs = "EPSG:29192"\n', encoding="utf-8")
    with pytest.raises(SurveyError, match=r"survey.toml: missing table \[files\]"):
        Survey.load(f)
    (f / "survey.toml").write_text('[survey]\nname = "x"\ncrs = "EPSG:29192"\n[files]\n'
                                   'camera = "camera.toml"\nphotos = "photos.csv"\n', encoding="utf-8")
    expect(f, "survey.toml", 4, "image_points", "missing required key 'image_points' in \\[files\\]")


def test_toml_invalid(tmp_path):
    f = copy_thesis(tmp_path)
    edit(f, "survey.toml", 'height_system = "orthometric"', "height_system = orthometric")
    with pytest.raises(SurveyError, match=r"survey.toml:9: invalid TOML"):
        Survey.load(f)


# ------------------------------------------------------------------ camera.toml errors
def test_two_cameras_need_camera_column(tmp_path):
    f = copy_thesis(tmp_path)
    cam = (f / "camera.toml").read_text(encoding="utf-8")
    (f / "camera.toml").write_text(cam + "\n" + cam.replace("[dcs14n]", "[other]"), encoding="utf-8")
    rewrite_csv(f, "photos.csv", drop_column("camera"))
    expect(f, "photos.csv", 1, "camera", "missing column 'camera'; camera.toml defines 2 cameras")


# ------------------------------------------------------------------ photos.csv errors
def test_photos_unknown_column(tmp_path):
    f = copy_thesis(tmp_path)
    text = rewrite_csv(f, "photos.csv", lambda h, r: (h + ["lens"], [x + ["a"] for x in r]))
    assert text.startswith("photo,camera,lens")
    with pytest.raises(SurveyError, match=r"photos.csv:1: unknown column\(s\) lens; allowed: photo"):
        Survey.load(f)


def test_photos_partial_position_columns(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "photos.csv", lambda h, r: (h + ["X0", "Y0"], [x + ["1", "2"] for x in r]))
    expect(f, "photos.csv", 1, "Z0", "missing column 'Z0'; a position needs all of X0, Y0, Z0")


def test_photos_partial_position_row(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "photos.csv", lambda h, r: (
        h + ["X0", "Y0", "Z0"], [x + ["1", "2", "3" if x[0] != "4" else ""] for x in r]))
    expect(f, "photos.csv", 5, "Z0", "empty; fill all of X0, Y0, Z0 or none")


# ------------------------------------------------------------------ image_points.csv errors
def test_image_points_missing_columns(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "image_points.csv", drop_column("row_px"))
    expect(f, "image_points.csv", 1, "row_px", "columns col_px, row_px come as a pair")
    f2 = copy_thesis(tmp_path / "b")
    rewrite_csv(f2, "image_points.csv", lambda h, r: (h[:2], [x[:2] for x in r]))
    expect(f2, "image_points.csv", 1, "col_px", "give col_px, row_px")
    f3 = copy_thesis(tmp_path / "c")
    rewrite_csv(f3, "image_points.csv", drop_column("point"))
    with pytest.raises(SurveyError, match=r"image_points.csv:1: missing column 'point'"):
        Survey.load(f3)


def test_image_points_trailing_comma(tmp_path):
    """A spreadsheet's trailing comma makes an unnamed column: say so, not 'unknown column(s) '."""
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "image_points.csv", lambda h, r: (h + [""], [x + [""] for x in r]))
    with pytest.raises(SurveyError, match=r"image_points.csv:1: column 7 has no name \(a trailing "
                                          r"comma\?\); name it or delete it$"):
        Survey.load(f)


def test_image_points_negative_sd(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "image_points.csv", lambda h, r: (
        h + ["sd_x_mm", "sd_y_mm"], [x + (["0.006", "-1"] if i == 3 else ["", ""]) for i, x in enumerate(r)]))
    expect(f, "image_points.csv", 5, "sd_y_mm", "must be positive")


def test_observations_kind_missing_for_a_row(tmp_path):
    f = copy_thesis(tmp_path)
    text = edit(f, "image_points.csv", "2,", "2,", )  # locate photo 2's first row
    first2 = next(line for line in text.splitlines() if line.startswith("2,"))
    photo, point, c, r, x, y = first2.split(",")
    text = edit(f, "image_points.csv", first2, f"{photo},{point},,,{x},{y}")
    s = Survey.load(f)
    assert len(s.photo_observations("corrected")) == 151
    with pytest.raises(SurveyError, match=rf"image_points.csv:{line_of(text, f'{photo},{point},,,')}: "
                       rf"field 'col_px': no pixel coordinates .* photo '2' point '{point}'"):
        s.photo_observations("pixel")


def test_latin1_files_are_located_errors(tmp_path):
    """A CSV or jobs file saved as Latin-1 (old spreadsheets) names its line, no traceback."""
    f = copy_thesis(tmp_path)
    text = edit(f, "ground_points.csv", "908.745,0.25,0.25,0.25,gps", "908.745,0.25,0.25,0.25,estação")
    (f / "ground_points.csv").write_bytes(text.encode("latin-1"))
    with pytest.raises(SurveyError, match=rf"ground_points.csv:{line_of(text, '603,')}: byte 0xe7 "
                                          r"is not UTF-8 text; save the file as UTF-8$"):
        Survey.load(f)
    f = copy_thesis(tmp_path / "b")
    (f / "jobs.txt").write_bytes("# faixa São José\nfaixa.xyz P799 1 2\n".encode("latin-1"))
    edit(f, "survey.toml", 'control_sets = "control_sets.csv"',
         'control_sets = "control_sets.csv"\nextraction_jobs = "jobs.txt"')
    with pytest.raises(SurveyError, match=r"jobs.txt:1: byte 0xe3 is not UTF-8 text"):
        Survey.load(f)


# ------------------------------------------------------------------ ground_points.csv errors
def test_ground_points_missing_column(tmp_path):
    f = copy_thesis(tmp_path)
    rewrite_csv(f, "ground_points.csv", drop_column("sd_h"))
    with pytest.raises(SurveyError, match=r"ground_points.csv:1: missing column 'sd_h'"):
        Survey.load(f)


def test_ground_points_wrong_field_count(tmp_path):
    f = copy_thesis(tmp_path)
    text = edit(f, "ground_points.csv", "908.745,0.25,0.25,0.25,gps", "908.745,0.25,0.25,0.25,gps,x")
    with pytest.raises(SurveyError, match=rf"ground_points.csv:{line_of(text, '603,')}: 9 fields, expected 8"):
        Survey.load(f)


# ------------------------------------------------------------------ control_sets.csv errors
def test_control_point_excluded(tmp_path):
    f = copy_thesis(tmp_path)
    edit(f, "survey.toml", 'exclude_points = ["417"]', 'exclude_points = ["417", "603"]')
    text = (f / "control_sets.csv").read_text(encoding="utf-8")
    expect(f, "control_sets.csv", line_of(text, "gps,603"), "point", "excluded by survey.toml")


def test_control_set_without_default(tmp_path):
    f = copy_thesis(tmp_path)
    edit(f, "survey.toml", 'default_control = "gps"', "")
    s = Survey.load(f)
    with pytest.raises(SurveyError, match="no control set named and no .survey. default_control; "
                                          "available: gps, lidar"):
        s.control_set()


# ------------------------------------------------------------------ packaging
@pytest.mark.slow
def test_wheel_contains_thesis_block(tmp_path):
    """Build the wheel, import lidarcat from it alone, load the embedded block."""
    out = tmp_path / "wheel"
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out),
                           str(ROOT)], capture_output=True, text=True, timeout=300)
    if proc.returncode != 0:
        pytest.skip(f"cannot build the wheel here (offline?): {proc.stderr[-300:]}")
    wheel = next(out.glob("lidarcat-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for n in ("survey.toml", "camera.toml", "photos.csv", "image_points.csv",
              "ground_points.csv", "control_sets.csv"):
        assert f"lidarcat/_data/thesis/{n}" in names
    assert "lidarcat/_data/cameras/lactec_dcs14n_2008.toml" in names
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import sys; sys.path.insert(0, sys.argv[1]); sys.meta_path[:] = [f for f in sys.meta_path "
            "if 'editable' not in type(f).__module__.lower() and 'editable' not in repr(f).lower()]\n"
            "import lidarcat, lidarcat.survey.folder as s\n"
            "assert lidarcat.__file__.startswith(sys.argv[1]), lidarcat.__file__\n"
            "sv = s.Survey.load(); print(sv.root, len(sv.image_points))")
    res = subprocess.run([sys.executable, "-c", code, str(site)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    root, n = res.stdout.split()
    assert Path(root) == site / "lidarcat" / "_data" / "thesis" and n == "153"


def test_cameras_of(tmp_path):
    from lidarcat.survey.folder import cameras_of

    assert list(cameras_of()) == ["dcs14n"]
    assert list(cameras_of(THESIS_SURVEY)) == ["dcs14n"]
    assert list(cameras_of(THESIS_SURVEY / "survey.toml")) == ["dcs14n"]
    assert list(cameras_of(example_camera_path())) == ["lactec_dcs14n"]
    assert list(cameras_of(f"{example_camera_path()}:lactec_dcs14n")) == ["lactec_dcs14n"]


def test_correct_measurements_uses_each_photos_camera(tmp_path):
    """Two cameras in one survey: each row is corrected with its own photo's camera."""
    from lidarcat.survey.folder import correct_measurements

    f = copy_thesis(tmp_path)
    lactec = example_camera_path().read_text(encoding="utf-8")
    (f / "camera.toml").write_text((f / "camera.toml").read_text(encoding="utf-8") + "\n" + lactec,
                                   encoding="utf-8")
    edit(f, "photos.csv", "5,dcs14n", "5,lactec_dcs14n")
    with open(THESIS_TABLES / "appendix1_corrections.csv", encoding="utf-8") as fh:
        ref = {(r["photo"], r["point"]): r
               for r in csv.DictReader(line for line in fh if not line.startswith("#"))}
    table = correct_measurements(f)
    assert len(table) == 153
    on5 = table.photo == "5"
    assert set(table.camera[on5].tolist()) == {"lactec_dcs14n"}
    assert set(table.camera[~on5].tolist()) == {"dcs14n"}
    # thesis camera rows: Appendix 1 (3 printed decimals)
    for i in np.flatnonzero(~on5):
        r = ref[(str(table.photo[i]), str(table.point[i]))]
        np.testing.assert_allclose(table.xy_mm[i], [float(r["x_fotc"]), float(r["y_fotc"])], atol=0.0015)
    # LACTEC rows: eq. 01-02 with its 8 um pixels, 4500 x 3000 frame, (dx, dy) = (0.152, 0.139)
    px = table.pixel_px[on5]
    np.testing.assert_allclose(table.fot_mm[on5, 0], 0.008 * (px[:, 0] - 2249.5) - 0.152, atol=1e-12)
    np.testing.assert_allclose(table.fot_mm[on5, 1], -0.008 * (px[:, 1] - 1499.5) - 0.139, atol=1e-12)


# ------------------------------------------------------------------ [assessment]
def test_survey_knows_the_pec_classes_of_the_standards_tables():
    from lidarcat.accuracy import standards
    from lidarcat.survey.folder import PEC_CLASSES

    for scale, eq in ((500, 0.5), (2000, 2.0), (100_000, 50.0)):
        assert tuple(standards.pec_tolerances("pec", scale, eq)) == PEC_CLASSES


def test_assessment_defaults_are_the_thesis_settings(thesis):
    a = thesis.assessment
    assert (a.scale, a.contour_interval_m, a.alpha, a.pec_class) == (2000.0, 2.0, 0.10, "A")
    # Tables 14/15 print Z_i for the cumulative probabilities (i - 0.5)/n (Hazen positions)
    assert a.plotting_position == "hazen"
