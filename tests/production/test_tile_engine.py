"""The tile engine (lidarcat.lidar.jobs) knows no product: it runs the function each job names."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from lidarcat.lidar.jobs import TileJob, run_jobs


def test_importing_the_engine_loads_no_product():
    code = ("import sys, lidarcat.lidar.jobs; "
            "print(sorted(m for m in sys.modules if m.startswith(('lidarcat.production', 'lidarcat.control'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def write_bounds(job: TileJob) -> None:
    """A tile function of this test: writes the job's bounds and parameters."""
    with open(job.output, "w", encoding="utf-8") as fh:
        json.dump({"bounds": list(job.bounds), "params": job.params}, fh)


def test_a_job_runs_its_function_and_its_marker_names_it(tmp_path):
    tile = tmp_path / "t.laz"
    tile.write_bytes(b"not read by the function")
    job = TileJob(write_bounds, str(tile), (0.0, 0.0, 1.0, 1.0), (), str(tmp_path / "o.json"), {"k": 1},
                  buffered=False)
    assert run_jobs([job]) == [job.output]
    assert json.loads((tmp_path / "o.json").read_text()) == {"bounds": [0.0, 0.0, 1.0, 1.0], "params": {"k": 1}}
    marker = json.loads((tmp_path / "o.json.done.json").read_text())
    assert marker["function"] == f"{__name__}.write_bounds"


def test_a_lambda_is_refused():
    with pytest.raises(ValueError, match="a tile job's function must be a module-level function"):
        TileJob(lambda job: None, "t.laz", (0.0, 0.0, 1.0, 1.0), (), "o.json")
