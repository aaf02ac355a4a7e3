"""Issue 25, the dead ends of ``lidarcat import``: every import either succeeds or says what to do
next (each error test asserts the message names the next step), an invalid ``--crs`` is a one-line
error for every format, Metashape's adjusted calibration wins over the initial one whatever their
order, a fisheye sensor is refused by name, and a Metashape block (no tie points) can be exported."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import FormatError
from lidarcat.interop.metashape import read_metashape
from lidarcat.interop.opensfm import read_opensfm
from lidarcat.survey.folder import Survey
from tests.conftest import assert_one_line_error

D = Path(__file__).parents[1] / "data" / "interop"
CHUNK = D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml"
FRAME = D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml"
COLMAP = D / "colmap" / "kapture_maupertuis"
REC = D / "opensfm" / "berlin_reconstruction_example.json"
TRACKS = D / "opensfm" / "berlin_tracks_example.csv"
BOREA = D / "opk"
PITCH_MM = 0.0037557825786083223


def _invoke(*args) -> object:
    return CliRunner().invoke(cli, [str(a) for a in args])


BAD_CRS = "--crs 'not a crs' is not a CRS pyproj knows: give EPSG:nnnn (e.g. EPSG:31982), a WKT or a PROJ string"


@pytest.mark.parametrize("args,local", [
    (["odm-gcp", D / "odm" / "bellus_gcp_list.txt"], False),
    (["metashape", CHUNK, "--frame", FRAME], False),
    (["colmap", COLMAP], True),
])
def test_invalid_crs_is_one_line_error(tmp_path, args, local):
    res = _invoke("import", *args, "--crs", "not a crs", "-o", tmp_path / "out")
    assert_one_line_error(res, BAD_CRS + (", or 'local: <description>' for a frame that is not georeferenced"
                                          if local else ""))
    assert not (tmp_path / "out").exists()


def test_borea_needs_crs(tmp_path):
    res = _invoke("import", "borea", BOREA / "borea_23FD1305_alt_test.OPK", "--camera", BOREA / "borea_Camera1.txt",
                  "-o", tmp_path / "out")
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert ("borea needs --crs: the CRS of the .OPK and .app coordinates (IGN blocks: EPSG:2154, Lambert-93), "
            "or 'local: <description>' for a local frame") in res.output
    assert not (tmp_path / "out").exists()


def test_colmap_without_control_names_the_next_step(tmp_path):
    out = tmp_path / "c"
    res = _invoke("import", "colmap", COLMAP, "-o", out)
    assert res.exit_code == 0, res.output
    assert res.output.splitlines()[-1] == (
        f"next: the model has no control, which lidarcat adjust needs to fix its datum: import again with "
        f"--control-sd-m 0.01 (the model points become control) or add ground control "
        f"(lidarcat import odm-gcp gcp_list.txt --survey {out} -o {out}_gcp)")
    res = _invoke("import", "colmap", COLMAP, "--control-sd-m", "0.01", "-o", tmp_path / "c2")
    assert res.exit_code == 0 and "next:" not in res.output


def test_opensfm_gcp_errors_name_the_next_step(tmp_path):
    gcp = D / "opensfm" / "berlin_ground_control_points.json"
    res = _invoke("import", "opensfm-gcp", gcp, "-o", tmp_path / "x")
    assert res.exit_code == 2 and ("opensfm-gcp needs --survey, a survey imported from the same OpenSfM "
                                   "reconstruction: lidarcat import opensfm reconstruction.json -o SURVEY, "
                                   "then --survey SURVEY") in res.output
    assert _invoke("import", "colmap", COLMAP, "-o", tmp_path / "c").exit_code == 0
    res = _invoke("import", "opensfm-gcp", gcp, "--survey", tmp_path / "c", "-o", tmp_path / "y")
    assert_one_line_error(res, f"{gcp}: the block 'kapture_maupertuis' has no OpenSfM reference_lla frame, so GCPs in lat/lon "
                          f"cannot be placed; give --survey a survey imported from a georeferenced OpenSfM "
                          f"reconstruction (with reference_lla), or write the GCPs as an ODM gcp_list.txt in "
                          f"the survey CRS and use lidarcat import odm-gcp")


def test_borea_errors_name_the_next_step(tmp_path):
    mes = tmp_path / "x.mes"
    mes.write_text("P1 NOPHOTO 10 10\n")
    res = _invoke("import", "borea", BOREA / "borea_23FD1305_alt_test.OPK", "--camera", BOREA / "borea_Camera1.txt",
                  "--camera", BOREA / "borea_Camera2.txt", "--measurements", mes, "--crs", "EPSG:2154",
                  "-o", tmp_path / "out")
    assert_one_line_error(res, f"{mes}: image 'NOPHOTO' is not in {BOREA / 'borea_23FD1305_alt_test.OPK'}: give "
                          f"the .mes files of the same block, or add the photo to the .OPK file")
    res = _invoke("import", "borea", BOREA / "borea_23FD1305_alt_test.OPK", "--camera", BOREA / "borea_Camera2.txt",
                  "--crs", "EPSG:2154", "-o", tmp_path / "out")
    assert_one_line_error(res, "field 'CAMERA': camera 'UCE-M3-f120-s06' of photo '23FD1305x00026_01306' is not "
                          "among the camera files (UCE-M3-f120-s07): give its camera file (--camera)")
    out = tmp_path / "out"
    res = _invoke("import", "borea", BOREA / "borea_23FD1305_alt_test.OPK", "--camera", BOREA / "borea_Camera1.txt",
                  "--camera", BOREA / "borea_Camera2.txt", "--crs", "EPSG:2154", "-o", out)
    assert res.exit_code == 0, res.output      # no .mes: the oriented photos, no observation yet
    assert res.output.splitlines()[-1] == (
        f"next: the borea file holds oriented photos but no image observations, so the block cannot be "
        f"adjusted yet; export it as it is (lidarcat export colmap|opensfm|opk|gis {out} -o OUT), or give "
        f"photos.csv an image column (each photo's image file) and run lidarcat match {out} first")
    assert len(Survey.load(out).photos) == 7


# ---------------------------------------------------------------------- Metashape
def _with_initial(tmp_path: Path, first: str) -> Path:
    """The chunk with an `initial` calibration (f = 15.00 mm) before or after its `adjusted` one."""
    text = CHUNK.read_text()
    m = re.search(r'      <calibration type="frame" class="adjusted">.*?</calibration>\n', text, flags=re.S)
    initial = ('      <calibration type="frame" class="initial">\n        <resolution width="4608" height="3456"/>\n'
               f"        <f>{15.0 / PITCH_MM!r}</f>\n      </calibration>\n")
    both = initial + m.group(0) if first == "initial" else m.group(0) + initial
    p = tmp_path / f"chunk_{first}.xml"
    p.write_text(text[:m.start()] + both + text[m.end():])
    return p


@pytest.mark.parametrize("first", ["initial", "adjusted"])
def test_metashape_adjusted_calibration_whatever_the_order(tmp_path, first):
    b = read_metashape(_with_initial(tmp_path, first), FRAME)
    assert b.cameras["0"].focal_length_mm == pytest.approx(4785.3046873759595 * PITCH_MM, rel=1e-15)  # 17.97 mm
    assert round(b.cameras["0"].focal_length_mm, 2) == 17.97


def test_metashape_initial_calibration_alone_is_used(tmp_path):
    p = _with_initial(tmp_path, "initial")
    text = re.sub(r'      <calibration type="frame" class="adjusted">.*?</calibration>\n', "", p.read_text(), flags=re.S)
    p.write_text(text)
    assert read_metashape(p, FRAME).cameras["0"].focal_length_mm == pytest.approx(15.0, rel=1e-15)


def test_metashape_spherical_sensor_refused(tmp_path):
    p = tmp_path / "chunk.xml"
    p.write_text(CHUNK.read_text().replace('label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="frame"',
                                           'label="FC550, DJI MFT 15mm F1.7 ASPH (15mm)" type="spherical"', 1))
    with pytest.raises(FormatError) as ei:
        read_metashape(p, FRAME)
    assert str(ei.value) == (f"{p}:4: field 'type': sensor 0 (FC550, DJI MFT 15mm F1.7 ASPH (15mm)) is a spherical "
                             f"camera; lidarcat reads frame and fisheye cameras: remove or disable its cameras "
                             f"in Metashape, or export undistorted frame images of them, then import again")


def test_metashape_block_names_the_next_step_and_exports(tmp_path):
    out = tmp_path / "ms"
    res = _invoke("import", "metashape", CHUNK, "--frame", FRAME, "-o", out)
    assert res.exit_code == 0, res.output
    assert res.output.splitlines()[-1] == (
        f"next: the Metashape XML holds no tie points (Metashape keeps them in binary point clouds), so the "
        f"block cannot be adjusted; export it as it is (lidarcat export colmap|opensfm|opk|gis {out} -o OUT) "
        f"or add tie points before lidarcat adjust")
    for fmt, name in (("colmap", "colmap"), ("opensfm", "opensfm"), ("opk", "b.opk"), ("gis", "gis")):
        res = _invoke("export", fmt, out, "-o", tmp_path / name)
        assert res.exit_code == 0, (fmt, res.output)
        assert res.output.splitlines()[-1] == f"wrote {fmt} {tmp_path / name}: CRS EPSG:32654, heights ellipsoidal (WGS84)"
    images = (tmp_path / "colmap" / "images.txt").read_text().splitlines()
    assert sum(1 for ln in images if re.fullmatch(r"\d+( \S+){8} DJI_\d+", ln)) == 138  # every photo, oriented


def test_export_survey_folder_and_survey_option_conflict(tmp_path):
    out = tmp_path / "ms"
    assert _invoke("import", "metashape", CHUNK, "--frame", FRAME, "-o", out).exit_code == 0
    res = _invoke("export", "colmap", out, "--survey", out, "-o", tmp_path / "x")
    assert res.exit_code == 2 and (f"{out} is a survey folder; give either it or --survey with the output folder "
                                   f"of lidarcat adjust") in res.output


def test_borea_duplicate_ground_point_refused(tmp_path):
    """Found by the fuzz harness (import borea, GCP_test.app with a line repeated): import wrote a
    ground_points.csv that Survey.load refuses; now a located error."""
    app = tmp_path / "GCP.app"
    lines = (BOREA / "borea_GCP_test.app").read_text().splitlines()
    app.write_text("\n".join(lines + [lines[-1]]) + "\n")
    res = _invoke("import", "borea", BOREA / "borea_23FD1305_alt_test.OPK", "--camera", BOREA / "borea_Camera1.txt",
                  "--camera", BOREA / "borea_Camera2.txt", "--points", app, "--measurements",
                  BOREA / "borea_terrain_test.mes", "--crs", "EPSG:2154", "-o", tmp_path / "out")
    assert_one_line_error(res, f"{app}:4: field 'name': point '1006' already on line 3: keep one line per point")
    assert not (tmp_path / "out").exists()


def test_metashape_block_without_markers_imports_and_exports(tmp_path):
    """A Metashape frame without marker projections (no image measurement at all) imports as a survey of
    oriented photos (header-only image_points.csv) that loads and exports; next: names export or match."""
    frame = tmp_path / "frame.doc.xml"
    frame.write_text(re.sub(r"  <markers>.*?</markers>\n", "", FRAME.read_text(), flags=re.S))
    out = tmp_path / "ms"
    res = _invoke("import", "metashape", CHUNK, "--frame", frame, "-o", out)
    assert res.exit_code == 0, res.output
    assert res.output.splitlines()[-1] == (
        f"next: the metashape file holds oriented photos but no image observations, so the block cannot be "
        f"adjusted yet; export it as it is (lidarcat export colmap|opensfm|opk|gis {out} -o OUT), or give "
        f"photos.csv an image column (each photo's image file) and run lidarcat match {out} first")
    s = Survey.load(out)
    assert len(s.image_points) == 0 and len(s.photos) == 138
    res = _invoke("export", "opk", out, "-o", tmp_path / "b.opk")
    assert res.exit_code == 0, res.output
    assert len((tmp_path / "b.opk").read_text().splitlines()) == 1 + 138
