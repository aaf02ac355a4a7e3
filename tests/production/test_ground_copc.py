"""``lidarcat lidar ground --copc``: the classified copy as a COPC file, the same classes as the LAZ copy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidarcat.lidar.copc import is_copc

DATA = Path(__file__).resolve().parent.parent / "data" / "lidar"


def _sorted_classes(las):
    k = np.lexsort((np.asarray(las.gps_time), np.asarray(las.Z), np.asarray(las.Y), np.asarray(las.X)))
    return np.asarray(las.classification)[k]


def test_ground_copc_equals_the_laz_copy(tmp_path):
    import laspy
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    tile = str(DATA / "ahn3_cropped_2.laz")
    r = CliRunner().invoke(cli, ["lidar", "ground", tile, "-o", str(tmp_path / "g.laz"), "--crs", "EPSG:7415"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["lidar", "ground", tile, "-o", str(tmp_path / "c"), "--crs", "EPSG:7415",
                                 "--copc", "--hag"])
    assert r.exit_code == 0, r.output
    out = tmp_path / "c" / "ahn3_cropped_2.copc.laz"
    assert is_copc(out)
    laz = laspy.read(tmp_path / "g.laz")
    with laspy.CopcReader.open(str(out)) as rd:
        assert rd.header.parse_crs().to_epsg() == 7415
        got = rd.query()
    assert len(got) == len(laz.points) == 208_432
    np.testing.assert_array_equal(_sorted_classes(got), _sorted_classes(laz))
    assert "HeightAboveGround" in laspy.read(out).point_format.extra_dimension_names


def test_ground_copc_refuses_a_las_name(tmp_path):
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    r = CliRunner().invoke(cli, ["lidar", "ground", str(DATA / "ahn3_cropped_2.laz"), "-o", str(tmp_path / "g.las"),
                                 "--crs", "EPSG:7415", "--copc"])
    assert r.exit_code != 0
    assert "a COPC file is LAZ; name it .copc.laz" in r.output
    assert not (tmp_path / "g.las").exists()
