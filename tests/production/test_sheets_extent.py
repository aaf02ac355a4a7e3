"""Issue 24: ``lidar sheets`` with one contour vertex at 1e29 m ran to a MemoryError at 6 GB.  Now a
vertex beyond any map is refused naming the file, feature and vertex, and an area that would
make more than MAX_SHEETS sheets is refused before any is made, naming who stretches it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import assert_one_line_error
from lidarcat.cli.main import cli
from lidarcat.errors import ProductError
from lidarcat.production.mapindex import MAX_SHEETS
from lidarcat.production.sheets import sheet_grid


def _contours(path: Path, far: float) -> Path:
    feats = [{"type": "Feature", "properties": {"h": 400 + i}, "geometry": {"type": "LineString",
              "coordinates": [[85000 + i, 447000], [85050, 447000 + i * 3]]}} for i in range(10)]
    feats[3]["geometry"]["coordinates"].append([far, 447010])
    path.write_text(json.dumps({"type": "FeatureCollection", "features": feats,
                                "crs": {"type": "name", "properties": {"name": "EPSG:28992"}}}))
    return path


@pytest.mark.parametrize("index", [[], ["--index", "brazil-2000", "--crs", "EPSG:31983"]], ids=["grid", "brazil"])
def test_sheets_vertex_at_1e29_is_a_located_error(tmp_path, index):
    c = _contours(tmp_path / "c.geojson", 1e29)
    r = CliRunner().invoke(cli, ["lidar", "sheets", str(c), "-o", str(tmp_path / "out"), *index])
    assert_one_line_error(r, f"{c}: feature 3: vertex 2: E 1e+29 N 447010 is not a coordinate in metres on the "
                             "Earth (|E|, |N| <= 1e+09)")
    assert not (tmp_path / "out").exists()


def test_sheets_far_vertex_names_the_feature_that_stretches_the_area(tmp_path):
    c = _contours(tmp_path / "c.geojson", 1e8)
    r = CliRunner().invoke(cli, ["lidar", "sheets", str(c), "-o", str(tmp_path / "out")])
    assert_one_line_error(r, "the area E 85000..1e+08 N 447000..447027 holds about 2.03e+05 sheets of 1000 x 1000 m, "
                             "more than 100,000", f"east edge from {c}: feature 3")
    assert not (tmp_path / "out").exists()


def test_brazil_index_counts_its_sheets_first(tmp_path):
    c = _contours(tmp_path / "c.geojson", 300_000)
    r = CliRunner().invoke(cli, ["lidar", "sheets", str(c), "-o", str(tmp_path / "out"), "--index", "brazil-2000",
                                 "--crs", "EPSG:31983"])
    assert_one_line_error(r, "sheets of the 1:2,000 index, more than 100,000", f"east edge from {c}: feature 3")


def test_sheet_grid_limit():
    assert len(sheet_grid((0, 0, 99_000, 99_000), 1000)) == 99 * 99
    with pytest.raises(ProductError, match=r"the area E 0..100000 N 0..100000 holds about 1e\+10 sheets of 1 x 1 m, more than 100,000"):
        sheet_grid((0, 0, 1e5, 1e5), 1)
    with pytest.raises(ProductError, match="is not finite"):
        sheet_grid((0, 0, float("inf"), 1), 1)
    assert MAX_SHEETS == 100_000


def test_brazil_area_that_does_not_transform_is_one_line(tmp_path):
    c = _contours(tmp_path / "c.geojson", 1e8)
    r = CliRunner().invoke(cli, ["lidar", "sheets", str(c), "-o", str(tmp_path / "out"), "--index", "brazil-2000",
                                 "--crs", "EPSG:31983"])
    assert_one_line_error(r, "the area E 85000.0..100000000.0, N 447000.0..447027.0 does not transform to "
                             "geographic coordinates in SIRGAS 2000; is the CRS right?")
