"""``lidarcat lidar`` commands (issue 4)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import LIDAR_DATA, THESIS_SURVEY, assert_one_line_error
from lidarcat.cli.main import cli
from lidarcat.lidar import read_points
from lidarcat.lidar.raster import read_geotiff

AHN1 = str(LIDAR_DATA / "ahn3_cropped_1.laz")
AHN2 = str(LIDAR_DATA / "ahn3_cropped_2.laz")
PDAL = str(LIDAR_DATA / "pdal_sample_c.las")


def run(*args: str):
    return CliRunner().invoke(cli, ["lidar", *args])


def test_info_text_and_json():
    r = run("info", AHN1, "--crs", "EPSG:7415")
    assert r.exit_code == 0, r.output
    assert "points     640,510" in r.output
    assert "EPSG:7415 (Amersfoort / RD New + NAP height) (given)" in r.output
    assert "6: 246,753" in r.output and "LAZ 1.2, point format 1" in r.output
    r = run("info", AHN1, AHN2, PDAL, "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    assert [f["points"] for f in doc["files"]] == [640_510, 208_432, 14_408]
    assert doc["total"]["points"] == 863_350 and doc["files"][0]["crs"] is None
    assert doc["files"][1]["bounds"]["xmin"] == pytest.approx(85000.001, abs=5e-4)
    assert doc["files"][2]["returns"] == {"1": 14272, "2": 130, "3": 5, "4": 1}


def test_clip_straddling_house_to_laz_and_csv(tmp_path):
    out = tmp_path / "roof.laz"
    r = run("clip", AHN1, AHN2, "--crs", "EPSG:7415", "--at", "85000", "447472", "--radius", "6",
            "-o", str(out), "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.output)
    pc = read_points(out)
    assert doc["points"] == len(pc) > 400 and pc.crs.to_epsg() == 7415
    assert (pc.x < 85000).sum() > 200 and (pc.x > 85000).sum() > 200
    r = run("clip", AHN1, AHN2, "--crs", "EPSG:7415", "--at", "85000", "447472", "--radius", "6",
            "-o", str(tmp_path / "roof.csv"))
    assert r.exit_code == 0 and "written to" in r.output
    np.testing.assert_array_equal(read_points(tmp_path / "roof.csv").xyz, pc.xyz)


def test_raster_writes_geotiff_and_preview(tmp_path):
    out = tmp_path / "int.tif"
    r = run("raster", AHN2, "--crs", "EPSG:7415", "--cell", "1", "--what", "intensity", "-o", str(out))
    assert r.exit_code == 0, r.output
    grid, t, crs = read_geotiff(out)
    assert crs.to_epsg() == 7415 and t.cell_m == 1.0
    assert t.x0 == 85000.0 and t.y0 == 447642.0 and grid.shape == (230, 73)
    assert (tmp_path / "int.png").read_bytes()[:4] == b"\x89PNG"
    assert np.nanmax(grid) > 0


def test_index_survey_writes_cache(tmp_path):
    survey = tmp_path / "s"
    shutil.copytree(THESIS_SURVEY, survey)
    (survey / "lidar").mkdir()
    shutil.copy(AHN1, survey / "lidar")
    shutil.copy(AHN2, survey / "lidar")
    text = (survey / "survey.toml").read_text()
    text = text.replace("[files]\n", '[files]\nlidar = ["lidar/*.laz"]\n') + '\n[lidar]\ncrs = "EPSG:7415"\n'
    (survey / "survey.toml").write_text(text)
    r = run("index", str(survey))
    assert r.exit_code == 0, r.output
    assert "2 tiles, 848,942 points" in r.output
    doc = json.loads((survey / "lidar_index.json").read_text())
    assert [t["path"] for t in doc["tiles"]] == ["lidar/ahn3_cropped_1.laz", "lidar/ahn3_cropped_2.laz"]
    r = run("index", str(survey), "--json")
    assert json.loads(r.output)["points"] == 848_942
    # a survey folder is also a PATH for clip
    r = run("clip", str(survey), "--at", "85000", "447472", "--radius", "6", "--json")
    assert r.exit_code == 0, r.output
    assert json.loads(r.output)["crs"] == "EPSG:7415"


def test_index_blocks_then_extract_reuses_the_block_index(tmp_path):
    from lidarcat.lidar import TileIndex

    survey = tmp_path / "s"
    shutil.copytree(THESIS_SURVEY, survey)
    (survey / "lidar").mkdir()
    shutil.copy(AHN1, survey / "lidar")
    text = (survey / "survey.toml").read_text()
    text = text.replace("[files]\n", '[files]\nlidar = ["lidar/*.laz"]\n') + '\n[lidar]\ncrs = "EPSG:7415"\n'
    (survey / "survey.toml").write_text(text)
    r = run("index", str(survey), "--blocks")
    assert r.exit_code == 0, r.output
    assert "block index: 1 of 1 tiles" in r.output
    doc = json.loads((survey / "lidar_index.json").read_text())
    assert doc["tiles"][0].get("blocks") is not None
    idx = TileIndex.build([str(survey / "lidar" / "ahn3_cropped_1.laz")], crs="EPSG:7415",
                          cache_path=survey / "lidar_index.json")
    assert idx.block_index(idx.tiles[0]) is not None   # read back, no second full pass
    args = ["extract", "--lidar", str(survey / "lidar" / "ahn3_cropped_1.laz"), "--crs", "EPSG:7415",
            "--at", "85000", "447472", "--json"]
    plain = CliRunner().invoke(cli, args)
    cached = CliRunner().invoke(cli, args + ["--index-cache", str(survey / "lidar_index.json")])
    assert plain.exit_code == 0 and cached.exit_code == 0, cached.output
    assert json.loads(plain.output) == json.loads(cached.output)


def test_errors_are_one_line(tmp_path):
    trunc = tmp_path / "trunc.laz"
    data = (LIDAR_DATA / "ahn3_cropped_2.laz").read_bytes()
    trunc.write_bytes(data[: len(data) // 3])
    assert_one_line_error(run("info", str(trunc)), "trunc.laz", "truncated or corrupt")
    assert_one_line_error(run("info", PDAL, "--crs", "EPSG:12345678"), "unknown CRS 'EPSG:12345678'")
    bad = tmp_path / "bad.xyz"
    bad.write_text("1 2 3\n4 5 six\n")
    assert_one_line_error(run("clip", str(bad), "--at", "1", "2", "--radius", "3"),
                          "bad.xyz:2: field 'H': 'six' is not a number")
    assert_one_line_error(run("clip", AHN1, "--at", "0", "0", "--radius", "5"),
                          "no LiDAR points within 5 m of E=0.000 N=0.000")
    assert_one_line_error(run("info", str(tmp_path / "missing.laz")), "missing.laz: file not found")
    assert_one_line_error(run("raster", AHN1, "-o", str(tmp_path / "x.tif"), "--bounds", "0", "0", "10", "10"),
                          "no LiDAR points in E 0.0..10.0, N 0.0..10.0")
    assert not list(tmp_path.glob("x.*"))
    survey = tmp_path / "s"
    shutil.copytree(THESIS_SURVEY, survey)  # a survey without [files] lidar
    assert_one_line_error(run("index", str(survey)),
                          f"{survey / 'survey.toml'}: no LiDAR tiles; add lidar = [\"lidar/*.laz\"] to [files]")
    assert not (survey / "lidar_index.json").exists()


def test_help_teaches_units_and_examples():
    for cmd in ("info", "index", "clip", "raster"):
        r = run(cmd, "--help")
        assert r.exit_code == 0 and "Example" in r.output
    assert "metres" in run("clip", "--help").output
