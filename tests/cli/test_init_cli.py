"""``lidarcat init``: the command (the action is tested in tests/stages/test_init.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from click.testing import CliRunner

from conftest import assert_one_line_error
from lidarcat.cli.main import cli
from lidarcat.survey.folder import Survey

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "survey"))
from test_exif import write_photo  # noqa: E402


def _photos(tmp_path: Path) -> Path:
    d = tmp_path / "photos"
    d.mkdir()
    for k in range(3):
        write_photo(d / f"IMG_{k}.jpg", -25.43, -49.27 + 0.001 * k, 1000.0)
    return d


def test_help_teaches_with_an_example():
    r = CliRunner().invoke(cli, ["init", "--help"])
    assert r.exit_code == 0
    assert "lidarcat init block --images flight/photos --gnss flight/gnss.txt" in r.output
    assert "lidarcat match block" in r.output


def test_init_then_adjust_says_match_first(tmp_path):
    photos = _photos(tmp_path)
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos), "--crs", "EPSG:31982",
                                 "--position-sd", "2", "--json"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.output)
    assert out["n_photos"] == 3 and out["crs"] == "EPSG:31982" and out["with_position"] == 3
    assert out["without_position"] == [] and out["with_attitude"] == 0
    s = Survey.load(tmp_path / "s")
    assert s.photos[2].sd_position_m.tolist() == [2.0, 2.0, 2.0]
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(tmp_path / "out")])
    assert_one_line_error(r, f"{tmp_path / 's' / 'image_points.csv'}: no image observations: run "
                             f"`lidarcat match {tmp_path / 's'}` first")


def test_text_output_and_refusal_of_an_existing_survey(tmp_path):
    photos = _photos(tmp_path)
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos)])
    assert r.exit_code == 0, r.output
    assert r.output.startswith(f"Survey {tmp_path / 's'}: 3 photos, camera camera (EXIF (approximate)), "
                               f"CRS EPSG:32722, 3 with approximate position, 0 with attitude, 0 LiDAR tile(s)")
    assert f"Next: lidarcat match {tmp_path / 's'}" in r.output
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos)])
    assert_one_line_error(r, f"{tmp_path / 's'}: already holds a survey (survey.toml); choose another folder or "
                             f"pass --overwrite")
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos), "--overwrite"])
    assert r.exit_code == 0, r.output


def test_a_truncated_photo_is_one_line_and_nothing_is_written(tmp_path):
    photos = _photos(tmp_path)
    bad = photos / "IMG_1.jpg"
    bad.write_bytes(bad.read_bytes()[:-40])
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos)])
    assert_one_line_error(r, f"{bad}: truncated JPEG image")
    assert not (tmp_path / "s").exists()


def test_run_accepts_a_survey_of_photos_gnss_and_lidar_tiles(tmp_path):
    """`lidarcat run` on what `init` wrote (photos, approximate EO, LiDAR tiles, no image observation yet):
    a valid survey: match is planned before adjust, and adjust waits for it."""
    photos = tmp_path / "photos"
    photos.mkdir()
    for k in range(2):
        write_photo(photos / f"IMG_{k}.jpg", 52.0, 4.5 + 0.001 * k, 400.0)
    tiles = Path(__file__).resolve().parents[1] / "data" / "lidar"
    r = CliRunner().invoke(cli, ["init", str(tmp_path / "s"), "--images", str(photos), "--crs", "EPSG:28992",
                                 "--lidar", str(tiles / "ahn3_cropped_*.laz")])
    assert r.exit_code == 0, r.output
    s = Survey.load(tmp_path / "s")
    assert [p.name for p in s.lidar_paths] == ["ahn3_cropped_1.laz", "ahn3_cropped_2.laz"]
    r = CliRunner().invoke(cli, ["run", str(tmp_path / "s"), "-o", str(tmp_path / "out")])
    # the survey is valid: the run plans match before adjust; these two featureless test photos give
    # no verified pair, so match fails with its reason and the stages that need it are skipped
    assert r.exit_code == 1, r.output
    assert "Traceback" not in r.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    stages = {st["name"]: st for st in summary["stages"]}
    assert summary["failed"] == ["match"]
    assert stages["match"]["reason"].startswith("no pair of the 1 overlapping pairs has verified matches "
                                                "(first: photos 'IMG_0'-'IMG_1': ")
    assert stages["camera"]["reason"] == "needs match (match failed)"
    assert stages["adjust-gnss"]["reason"] == "needs match (match failed)"
    assert stages["report"]["status"] == "ran"
