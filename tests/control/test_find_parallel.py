"""``lidarcat extract --find`` block-parallel on Dask gives exactly the serial candidates."""

import json
from pathlib import Path

import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.control.vertices import find_candidates
from lidarcat.control.search import find_candidates_tiles, find_jobs, search_area
from lidarcat.lidar import TileIndex

LID = Path(__file__).parents[1] / "data" / "lidar"
TILES = [str(LID / "ahn3_cropped_1.laz"), str(LID / "ahn3_cropped_2.laz")]
# straddles the two crops' common edge, holds A10 (85036.956, 447493.697)
AREA = (84990.0, 447460.0, 85050.0, 447520.0)


def _key(c):
    cp = c.point
    return (cp.point_id, c.score, tuple(cp.enh_m), tuple(cp.cov_m2.ravel()), cp.n_planes, cp.status)


@pytest.fixture(scope="module")
def serial():
    idx = TileIndex.build(TILES, crs="EPSG:7415")
    # the area plus the margin its candidates' clips reach, as the blocks and the CLI read (test_find_edge.py)
    return idx, find_candidates(idx.query_box(*search_area(AREA)), box=AREA, classes=[6])


def test_blocks_equal_serial_and_resume(serial, tmp_path):
    idx, ref = serial
    assert len(ref) >= 3
    jobs = find_jobs(idx, AREA, tmp_path, crs="EPSG:7415", classes=[6], block_cells=1)
    assert len(jobs) == 9  # 3 x 3 cells of 20 m
    # each block reads only the tiles within its margin (14 m) of it: crop 1 ends at E 85000
    reads = {j.bounds[0]: {Path(p).name for p in (j.tile, *j.neighbours)} for j in jobs}
    assert reads == {84990.0: {"ahn3_cropped_1.laz", "ahn3_cropped_2.laz"},
                     85010.0: {"ahn3_cropped_1.laz", "ahn3_cropped_2.laz"}, 85030.0: {"ahn3_cropped_2.laz"}}
    got = find_candidates_tiles(idx, AREA, classes=[6], block_cells=1, crs="EPSG:7415", work_dir=tmp_path)
    assert [_key(c) for c in got] == [_key(c) for c in ref]
    assert all(Path(j.output + ".done.json").is_file() for j in jobs)
    done = []
    again = find_candidates_tiles(idx, AREA, classes=[6], block_cells=1, crs="EPSG:7415", work_dir=tmp_path,
                                  progress=done.append)
    assert done == [9] and [_key(c) for c in again] == [_key(c) for c in ref]  # resumed: all skipped


def test_cli_two_workers_equal_serial(serial, tmp_path):
    _, ref = serial
    base = ["extract", "--find", "--lidar", *TILES, "--crs", "EPSG:7415", "--classes", "6",
            "--box", *(str(v) for v in AREA)]
    r = CliRunner().invoke(cli, [*base, "-o", str(tmp_path / "s.geojson")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, [*base, "--workers", "2", "--work-dir", str(tmp_path / "blocks"),
                                 "-o", str(tmp_path / "p.geojson")])
    assert r.exit_code == 0, r.output
    assert len(list((tmp_path / "blocks").glob("find_*.npz.done.json"))) == 1  # 60 m = one block of 3 x 3 cells
    s = json.loads((tmp_path / "s.geojson").read_text())
    p = json.loads((tmp_path / "p.geojson").read_text())
    assert p == s and len(p["features"]) == len(ref)
    assert [f["properties"]["point"] for f in p["features"]] == [c.point.point_id for c in ref]


def test_workers_only_for_find(tmp_path):
    r = CliRunner().invoke(cli, ["extract", "--at", "85036.9", "447493.7", "--lidar", TILES[1],
                                 "--crs", "EPSG:7415", "--workers", "2"])
    assert r.exit_code == 2 and "--workers, --scheduler and --work-dir: for --find, not jobs or --at" in r.output
    r = CliRunner().invoke(cli, ["extract", "--find", "--lidar", TILES[1], "--work-dir", str(tmp_path)])
    assert r.exit_code == 2 and "--work-dir: for --find with --workers or --scheduler" in r.output
