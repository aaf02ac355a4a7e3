"""``lidarcat lidar check``: vertical accuracy of tiles at check points, from the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.lidar.cloud import PointCloud
from lidarcat.lidar.readers import write_points


@pytest.fixture()
def tile(tmp_path):
    """A 60 m x 60 m ground plane z = 10 + 0.02 E (class 2) and 500 points 5 m above it (class 1)."""
    rng = np.random.default_rng(7)
    xy = rng.uniform(0, 60, (6000, 2))
    z = 10 + 0.02 * xy[:, 0]
    cls = np.full(6000, 2, dtype=np.uint8)
    cls[:500] = 1
    z[:500] += 5.0                                  # trees: must be ignored (class 1)
    path = tmp_path / "t.las"
    write_points(path, PointCloud(np.column_stack([xy, z]), {"classification": cls}, crs="EPSG:31982"))
    return path


def _csv(tmp_path, rows):
    p = tmp_path / "cp.csv"
    p.write_text("id,E,N,H,vegetated\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return p


def test_check_writes_nva_vva(tmp_path, tile):
    # check points 0.1 m below / above the plane: non-vegetated dz = +0.1, -0.1, +0.1, -0.1 -> RMSE 0.1
    rows = [(f"P{i}", e, n, round(10 + 0.02 * e - s, 4), 0)
            for i, (e, n, s) in enumerate([(10, 10, 0.1), (20, 30, -0.1), (40, 15, 0.1), (50, 50, -0.1)])]
    rows.append(("V1", 30, 30, round(10 + 0.6 - 0.5, 4), 1))
    out = tmp_path / "check.json"
    r = CliRunner().invoke(cli, ["lidar", "check", str(tile), "--checkpoints", str(_csv(tmp_path, rows)),
                                 "-o", str(out), "--scale", "2000", "--contour-interval-m", "1"])
    assert r.exit_code == 0, r.output
    rep = json.loads(out.read_text())["accuracy"]
    # heights are stored to 1 mm in the LAS file: 2 mm tolerance
    assert rep["nva_rmse_m"] == pytest.approx(0.1, abs=0.002)
    assert rep["nva_95_m"] == pytest.approx(0.196, abs=0.004)
    assert rep["vva_95th_percentile_m"] == pytest.approx(0.5, abs=0.002)
    assert rep["pec"]["class"]["altimetric"] == "A"
    assert "NVA RMSE_z 0.100 m" in r.output
    lines = (tmp_path / "check.csv").read_text().splitlines()
    assert lines[0] == "id,E,N,H,vegetated,lidar_h,dz" and len(lines) == 6


def test_check_point_outside_the_tile_is_named(tmp_path, tile):
    rows = [("P1", 10, 10, 10.2, 0), ("FAR", 500, 10, 10.0, 0)]
    r = CliRunner().invoke(cli, ["lidar", "check", str(tile), "--checkpoints", str(_csv(tmp_path, rows)),
                                 "-o", str(tmp_path / "c.json")])
    assert r.exit_code != 0
    assert "check point FAR (500.000, 10.000) is outside the LiDAR triangulation" in r.output
    assert not (tmp_path / "c.json").exists()


def test_bad_vegetated_cell_is_located(tmp_path, tile):
    p = tmp_path / "cp.csv"
    p.write_text("id,E,N,H,vegetated\nP1,10,10,10.2,0\nP2,20,20,10.4,maybe\n")
    r = CliRunner().invoke(cli, ["lidar", "check", str(tile), "--checkpoints", str(p), "-o", str(tmp_path / "c.json")])
    assert r.exit_code != 0
    assert "cp.csv:3: field 'vegetated': 'maybe' is not 1/0" in r.output
