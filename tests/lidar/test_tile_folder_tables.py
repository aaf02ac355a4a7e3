"""Issue 25: a table beside the tiles (a jobs.csv) is not read as a LiDAR tile."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from lidarcat.errors import LidarFormatError
from lidarcat.lidar import PointCloud, read_points, write_points
from lidarcat.lidar.readers import is_foreign_table
from lidarcat.lidar.tiles import expand_paths


def test_folder_and_glob_skip_a_job_table_and_say_so(tmp_path, caplog):
    xyz = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 2.0], [0.0, 1.0, 3.0]])
    write_points(tmp_path / "a.laz", PointCloud(xyz))
    (tmp_path / "b.xyz").write_text("E N H\n0 0 1\n1 1 2\n")
    (tmp_path / "jobs.csv").write_text("point,E,N,sd_en_m,sd_h_m\nR01,680058.02,7184039.35,0.03,0.05\n")
    (tmp_path / "plain.txt").write_text("0 0 1\n1 1 2\n")   # headerless text: points
    assert is_foreign_table(tmp_path / "jobs.csv")
    assert not is_foreign_table(tmp_path / "b.xyz") and not is_foreign_table(tmp_path / "a.laz")
    assert not is_foreign_table(tmp_path / "plain.txt")
    with caplog.at_level(logging.WARNING):
        got = expand_paths([tmp_path])
        got_glob = expand_paths([str(tmp_path / "*")])
    assert [p.name for p in got] == [p.name for p in got_glob] == ["a.laz", "b.xyz", "plain.txt"]
    assert "jobs.csv: skipped, a table that names no E, N, H columns (not a LiDAR tile)" in caplog.text
    # named explicitly, the file is read, and the error says what to do in the CLI's words
    with pytest.raises(LidarFormatError, match=r"jobs\.csv:1: no column for H among point E N sd_en_m sd_h_m; "
                       r"not a point file\? Name its columns \(--columns of `lidarcat lidar`, columns= in "
                       r"Python\) or move it out of the tiles"):
        read_points(tmp_path / "jobs.csv")
