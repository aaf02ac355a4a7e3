"""The streamed COPC writer: several hierarchy pages, buckets, chunks; read back by laspy's CopcReader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarcat.lidar.copc import read_hierarchy
from lidarcat.lidar.copc_write import hierarchy_pages, write_copc

DATA = Path(__file__).resolve().parent.parent / "data" / "lidar"
TILE = DATA / "ahn3_cropped_2.laz"
N = 208_432


def _pages(path):
    """Every hierarchy entry (key -> (offset, bytes, count)) by following the pages; the number of pages."""
    return read_hierarchy(path)


@pytest.fixture(scope="module")
def paged(tmp_path_factory):
    # streamed from the file in chunks of 30,000 points, spilled to buckets of at most 60,000, pages of 16
    out = write_copc(TILE, tmp_path_factory.mktemp("pages") / "p.copc.laz", crs="EPSG:7415", max_points=4000,
                     page_entries=16, bucket_points=60_000, chunk_points=30_000)
    return out


def test_several_pages_and_every_node_once(paged):
    entries, pages = _pages(paged)
    assert pages > 5
    assert sum(c for _, _, c in entries.values()) == N
    assert (0, 0, 0, 0) in entries
    for d, x, y, z in entries:
        if d:
            assert (d - 1, x // 2, y // 2, z // 2) in entries        # every parent listed
    # leaves hold at most max_points; a node with children holds at most one point per voxel
    parents = {(d - 1, x // 2, y // 2, z // 2) for d, x, y, z in entries if d}
    assert max(c for k, (_, _, c) in entries.items() if k not in parents) <= 4000


def test_a_truncated_hierarchy_is_a_located_error(paged, tmp_path):
    from lidarcat.errors import LidarFormatError

    raw = Path(paged).read_bytes()
    cut = tmp_path / "cut.copc.laz"
    cut.write_bytes(raw[:-20])    # the hierarchy EVLR is the file's last record
    with pytest.raises(LidarFormatError, match=rf"^{cut}: a hierarchy page at byte \d+ \(\d+ bytes\) is past "
                                               rf"the end of the file \({len(raw) - 20} bytes\)$"):
        read_hierarchy(cut)


def test_laspy_reads_every_point_by_bounds_and_levels(paged):
    import laspy

    src = laspy.read(TILE)
    entries, _ = _pages(paged)
    key = lambda r: np.sort(np.asarray(r.X, np.int64) * 10**12 + np.asarray(r.Y, np.int64) * 10**3   # noqa: E731
                            + np.asarray(r.gps_time * 1e3, np.int64) % 1000)
    with laspy.CopcReader.open(str(paged)) as r:
        assert r.header.point_count == N
        everything = r.query()
        np.testing.assert_array_equal(key(everything), key(src.points))
        for box in ((85010.0, 447450.0, 85040.0, 447520.0), (85000.0, 447400.0, 85100.0, 447420.0)):
            q = r.query(laspy.Bounds(mins=np.array(box[:2]), maxs=np.array(box[2:])))
            x, y = np.asarray(src.x), np.asarray(src.y)
            inside = (x >= box[0]) & (x <= box[2]) & (y >= box[1]) & (y <= box[3])
            assert len(q) == inside.sum() > 0
            np.testing.assert_array_equal(key(q), key(src.points[inside]))
        depths = sorted({k[0] for k in entries})
        assert len(depths) >= 3
        for d in depths:
            assert len(r.query(level=d)) == sum(c for k, (_, _, c) in entries.items() if k[0] == d)
        assert len(r.query(level=range(0, 2))) == sum(c for k, (_, _, c) in entries.items() if k[0] < 2)


def test_same_octree_in_memory_in_one_bucket_and_streamed(paged, tmp_path):
    import laspy

    one = write_copc(laspy.read(TILE), tmp_path / "one.copc.laz", crs="EPSG:7415", max_points=4000)
    a, _ = _pages(paged)
    b, pages = _pages(one)
    assert pages == 1
    assert {k: v[2] for k, v in a.items()} == {k: v[2] for k, v in b.items()}


def test_extra_dimension_kept(tmp_path):
    import laspy

    las = laspy.read(DATA / "pdal_sample_c.las")
    las.add_extra_dim(laspy.ExtraBytesParams(name="HeightAboveGround", type=np.float32))
    las.HeightAboveGround = np.arange(len(las.points), dtype=np.float32)
    out = write_copc(las, tmp_path / "e.copc.laz", crs="EPSG:7415")
    back = laspy.read(out)
    assert back.header.point_format.id == 7
    np.testing.assert_array_equal(np.sort(np.asarray(back.HeightAboveGround)),
                                  np.arange(len(las.points), dtype=np.float32))


def test_pages_cut_breadth_first():
    entries = {(0, 0, 0, 0): (1, 1, 1)}
    for x in range(2):
        for y in range(2):
            entries[(1, x, y, 0)] = (1, 1, 1)
            for i in range(2):
                for j in range(2):
                    entries[(2, 2 * x + i, 2 * y + j, 0)] = (1, 1, 1)
    pages = hierarchy_pages(entries, page_entries=9)
    # root + its 4 children (5), then a child's 4 children do not fit in 9 with the other 3 children queued
    root = pages[0][1]
    assert len(root) <= 9 and sum(1 for e in root if e[3] == -1) >= 1
    listed = [e[0] for _, p in pages for e in p if e[3] != -1]
    assert sorted(listed) == sorted(entries)
    with pytest.raises(ValueError, match="page_entries must be at least 9"):
        hierarchy_pages(entries, page_entries=8)
