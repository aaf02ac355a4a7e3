"""The CLI never shows a traceback: a bad input is one ``Error: ...`` line; ``run --help`` lists every stage."""

from __future__ import annotations

import pkgutil

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli


@pytest.fixture(scope="module")
def no_ground(tmp_path_factory):
    """A small LAS tile with no class-2 point."""
    path = tmp_path_factory.mktemp("bad") / "no_ground.las"
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales = [0.01, 0.01, 0.01]
    h.offsets = [500000.0, 7000000.0, 0.0]
    las = laspy.LasData(h)
    rng = np.random.default_rng(1)
    las.x = 500000 + rng.uniform(0, 20, 200)
    las.y = 7000000 + rng.uniform(0, 20, 200)
    las.z = 100 + rng.uniform(0, 1, 200)
    las.classification = np.full(200, 1, np.uint8)
    las.write(path)
    return path


def _one_line_error(args, code=2):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert "Traceback" not in r.output, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.output
    assert r.exit_code == code, (r.exit_code, r.output)
    return lines[0]


def test_lidar_dtm_on_a_tile_without_ground_is_one_line(no_ground, tmp_path):
    # a data condition (ProductError): one line naming the tile, exit 2
    line = _one_line_error(["lidar", "dtm", no_ground, "--crs", "EPSG:31982", "-o", tmp_path / "dtm.tif"])
    assert line == f"Error: {no_ground}: no ground points (class 2); classify the ground first (lidarcat lidar ground)"


@pytest.mark.parametrize("args", [
    ["adjust", "{bad}"],
    ["run", "{bad}", "-o", "{tmp}/out"],
    ["camera", "info", "{bad}"],
    ["assess", "{tmp}/points.csv", "{tmp}/points.csv"],
    ["extract", "{tmp}/jobs.txt", "{tmp}/broken.laz"],
    ["ortho", "{bad}", "--all", "--dtm", "{tmp}/points.csv", "-o", "{tmp}/o"],
    ["monoplot", "{bad}", "--photo", "1", "--features", "{tmp}/points.csv", "--surface", "{tmp}/points.csv",
     "-o", "{tmp}/m.geojson"],
    ["export", "opk", "{bad}", "-o", "{tmp}/x.opk"],
    ["lidar", "info", "{tmp}/points.csv"],
    ["lidar", "ground", "{tmp}/broken.laz", "-o", "{tmp}/g"],
    ["lidar", "dsm", "{tmp}/broken.laz", "-o", "{tmp}/d.tif"],
])
def test_every_command_on_a_bad_input_is_one_line(args, tmp_path):
    bad = tmp_path / "bad_survey"
    bad.mkdir()
    (bad / "survey.toml").write_text("[survey]\nname = 3\n")   # wrong type
    (tmp_path / "points.csv").write_text("not,a,table\n1\n")
    (tmp_path / "jobs.txt").write_text("garbage\n")
    (tmp_path / "broken.laz").write_bytes(b"LASF" + b"\0" * 50)
    _one_line_error([a.format(bad=bad, tmp=tmp_path) for a in args])


def test_run_help_lists_every_stage():
    import lidarcat.stages as stages
    from lidarcat.stages import REGISTRY

    r = CliRunner().invoke(cli, ["run", "--help"])
    assert r.exit_code == 0
    names = [n for n, _ in REGISTRY]
    for name, what in REGISTRY:
        assert f"{name}" in r.output and what in r.output, name
    modules = [m.name for m in pkgutil.iter_modules(stages.__path__)
               if not m.name.startswith("_") and hasattr(getattr(stages, m.name), "run")]
    assert sorted(modules) == sorted(n.replace("-SET", "") for n in names)
