"""The COPC writer: read back by laspy's CopcReader, by lidarcat's octree reader and as plain LAZ."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from lidarcat.errors import LidarFormatError
from lidarcat.lidar.copc import is_copc, read_copc_box
from lidarcat.lidar.copc_write import write_copc

DATA = Path(__file__).resolve().parent.parent / "data" / "lidar"
FIELDS = ("X", "Y", "Z", "intensity", "return_number", "number_of_returns", "classification", "gps_time",
          "point_source_id")


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    import laspy

    src = laspy.read(DATA / "ahn3_cropped_2.laz")
    out = write_copc(src, tmp_path_factory.mktemp("copc") / "t.copc.laz", crs="EPSG:7415", max_points=20_000)
    return src, out


def _sorted(las, names):
    k = np.lexsort((np.asarray(las.Z), np.asarray(las.Y), np.asarray(las.X), np.asarray(las.gps_time)))
    return {n: np.asarray(las[n])[k] for n in names}


def test_every_point_and_field_comes_back(written):
    import laspy

    src, out = written
    assert is_copc(out)
    back = laspy.read(out)                      # as plain LAZ (the chunk table)
    assert back.header.point_format.id == 6 and back.header.version == "1.4"
    assert back.header.parse_crs().to_epsg() == 7415
    a, b = _sorted(src, FIELDS), _sorted(back, FIELDS)
    for f in FIELDS:
        np.testing.assert_array_equal(a[f], b[f], err_msg=f)


def test_laspy_copc_reader_queries_the_octree(written):
    import laspy

    src, out = written
    box = (85010.0, 447450.0, 85040.0, 447520.0)
    with laspy.CopcReader.open(str(out)) as r:
        assert r.header.point_count == len(src.points) == 208_432
        assert len(r.query()) == 208_432
        q = r.query(laspy.Bounds(mins=np.array(box[:2]), maxs=np.array(box[2:])))
        info = r.copc_info
    x, y = np.asarray(src.x), np.asarray(src.y)
    inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
    qx, qy = np.asarray(q.x), np.asarray(q.y)
    q_in = (qx >= box[0]) & (qx <= box[2]) & (qy >= box[1]) & (qy <= box[3])
    assert q_in.sum() == inside.sum()          # laspy returns whole nodes: every point in the box is there
    assert info.spacing == pytest.approx(2 * info.halfsize / 128)


def test_lidarcat_reader_decodes_only_the_nodes_it_needs(written):
    src, out = written
    box = (85010.0, 447450.0, 85040.0, 447520.0)
    r = read_copc_box(out, box)
    x, y = np.asarray(src.x), np.asarray(src.y)
    inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
    assert len(r.cloud) == inside.sum()
    assert 0 < r.nodes_read < r.nodes_known
    assert r.cloud.crs.to_epsg() == 7415


def test_hierarchy_lists_every_parent(written):
    _, out = written
    raw = Path(out).read_bytes()
    info = struct.unpack_from("<5d2Q2d", raw, 375 + 54)
    off, size = int(info[5]), int(info[6])
    entries = [struct.unpack_from("<4iQii", raw, off + 32 * i) for i in range(size // 32)]
    keys = {e[:4] for e in entries}
    assert (0, 0, 0, 0) in keys
    for d, x, y, z in keys:
        if d:
            assert (d - 1, x // 2, y // 2, z // 2) in keys
    assert sum(e[6] for e in entries) == 208_432
    deepest = max(e[0] for e in entries)
    assert deepest >= 1 and max(e[6] for e in entries if e[0] == deepest) <= 20_000   # the leaves: max_points


def test_formats_below_6_are_converted_and_empty_input_refused(tmp_path):
    import laspy

    src = laspy.read(DATA / "pdal_sample_c.las")       # point format 3 (RGB)
    out = write_copc(src, tmp_path / "c.copc.laz")
    back = laspy.read(out)
    assert back.header.point_format.id == 7 and len(back.points) == len(src.points)
    np.testing.assert_array_equal(np.sort(np.asarray(back.red)), np.sort(np.asarray(src.red)))
    empty = laspy.LasData(laspy.LasHeader(point_format=6, version="1.4"))
    with pytest.raises(LidarFormatError, match="no points to write as COPC"):
        write_copc(empty, tmp_path / "e.copc.laz")
    assert not (tmp_path / "e.copc.laz").exists()


def test_cli_copc(tmp_path):
    import laspy
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    r = CliRunner().invoke(cli, ["lidar", "copc", str(DATA / "ahn3_cropped_2.laz"), "-o", str(tmp_path / "a.copc.laz"),
                                 "--crs", "EPSG:7415"])
    assert r.exit_code == 0, r.output
    assert is_copc(tmp_path / "a.copc.laz")
    with laspy.CopcReader.open(str(tmp_path / "a.copc.laz")) as rd:
        assert rd.header.point_count == 208_432
