"""Block index of LAS/LAZ tiles: cold queries decode only the blocks they need.

Every block-path answer is compared with an oracle that does not use the index
(the whole files read with read_points, concatenated in index order, masked
with the same membership rules), and with today's whole-tile decode
(``decode="whole"``).
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from conftest import LIDAR_DATA
from lidarcat.errors import LidarFormatError, TileIOError
from lidarcat.lidar import PointCloud, TileIndex, in_box, in_polygon, in_radius, read_points, write_points
from lidarcat.lidar import tileindex as ti
from lidarcat.lidar.readers import iter_las_ranges, las_chunk_points
from lidarcat.lidar.tileindex import BlockIndex

AHN1 = LIDAR_DATA / "ahn3_cropped_1.laz"
AHN2 = LIDAR_DATA / "ahn3_cropped_2.laz"
RD = "EPSG:7415"
UTM = "EPSG:31982"
X0, Y0 = 677000.0, 7183000.0


def _scan_cloud(n: int, x0: float, seed: int) -> PointCloud:
    """Two flight strips along x (y 0-55 m and 45-100 m, the second flown back), points in
    acquisition order: each 50 000-point LAZ chunk covers about 100 m of one strip."""
    rng = np.random.default_rng(seed)
    half = n // 2
    parts = []
    for s, (ya, yb) in enumerate(((0.0, 55.0), (45.0, 100.0))):
        m = half if s == 0 else n - half
        x = np.sort(rng.uniform(0.0, 300.0, m))
        if s == 1:
            x = x[::-1]
        y = rng.uniform(ya, yb, m)
        parts.append(np.column_stack([x, y]))
    xy = np.concatenate(parts)
    xy = np.round(xy + [x0, Y0], 3)
    h = np.round(900.0 + 0.02 * (xy[:, 0] - X0) + rng.normal(0, 0.05, n), 3)
    attrs = {"intensity": rng.integers(0, 4000, n).astype(np.uint16),
             "return_number": np.ones(n, np.uint8), "number_of_returns": rng.integers(1, 3, n).astype(np.uint8),
             "classification": rng.choice(np.array([1, 2, 6], np.uint8), n),
             "point_source_id": np.repeat(np.array([1, 2], np.uint16), [half, n - half]),
             "gps_time": np.round(1e5 + np.arange(n) * 1e-4, 6)}
    return PointCloud(np.column_stack([xy, h]), attrs, UTM)


@pytest.fixture(scope="module")
def tiles(tmp_path_factory) -> dict:
    d = tmp_path_factory.mktemp("blocks")
    scan = _scan_cloud(300_000, X0, 1)
    write_points(d / "a_scan.laz", scan)
    rng = np.random.default_rng(2)
    shuffled = _scan_cloud(120_000, X0 + 300.0, 3)
    shuffled = shuffled.select(rng.permutation(len(shuffled)))
    write_points(d / "b_shuffled.laz", shuffled)
    write_points(d / "c_scan.las", _scan_cloud(90_000, X0 + 600.0, 4))
    return {"dir": d, "utm": sorted(d.glob("*.la[sz]"))}


def _oracle(paths, crs=None) -> PointCloud:
    return PointCloud.concat([read_points(p, crs=crs) for p in paths])


def _same(a: PointCloud, b: PointCloud) -> None:
    assert len(a) == len(b)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    assert list(a.attributes) == list(b.attributes)
    for k in a.attributes:
        assert a.attributes[k].dtype == b.attributes[k].dtype, k
        np.testing.assert_array_equal(a.attributes[k], b.attributes[k], err_msg=k)
    assert a.crs == b.crs


def _random_queries(rng, bounds, n, blocks_of=()):
    """Boxes, circles and polygons around *bounds*, plus boxes whose edges are exactly
    cell-box edges at block boundaries (points on them) and the tile bounds."""
    xmin, ymin, xmax, ymax = bounds
    out = []
    for _ in range(n):
        cx, cy = rng.uniform(xmin - 5, xmax + 5), rng.uniform(ymin - 5, ymax + 5)
        w, h = rng.uniform(0.5, 40, 2)
        out.append(("box", (cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2)))
        out.append(("radius", ((cx, cy), float(rng.uniform(0.3, 25)))))
        ang = np.sort(rng.uniform(0, 2 * np.pi, 5))
        rad = rng.uniform(2, 15, 5)
        out.append(("polygon", np.column_stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang)])))
    for bi in blocks_of:  # the first and last cell of every block
        per = bi.block_points // bi.cell_points
        firsts = np.arange(0, len(bi.boxes), per)
        for b in bi.boxes[np.unique(np.r_[firsts, np.minimum(firsts + per, len(bi.boxes)) - 1])]:
            out.append(("box", tuple(b)))                                      # a block exactly
            out.append(("box", (b[2], b[1], b[2] + 3.0, b[3])))                 # starts on its xmax edge
            out.append(("box", (b[0] - 2.0, b[3], b[0] + 2.0, b[3] + 0.0)))     # a line on its ymax edge
    out.append(("box", (xmin, ymin, xmax, ymax)))                               # the whole extent
    out.append(("box", (xmin - 10, ymin - 10, xmin - 1, ymin - 1)))             # outside: empty
    return out


def _run(idx: TileIndex, q):
    kind, arg = q
    if kind == "box":
        return idx.query_box(*arg)
    if kind == "radius":
        return idx.query_radius(*arg)
    return idx.query_polygon(arg)


def _mask(xyz, q):
    kind, arg = q
    if kind == "box":
        return in_box(xyz, *arg)
    if kind == "radius":
        return in_radius(xyz, *arg)
    return in_polygon(xyz, arg)


# --------------------------------------------------------------------------- BlockIndex
def test_block_index_ranges_boxes_and_json():
    bi = BlockIndex(3, 8, np.array([[0, 0, 1, 1], [2, 0, 3, 1], [0, 5, 3, 6]], float))
    assert len(bi) == 3
    assert bi.needs(bi.cells_in_box(1.0, 1.0, 2.0, 5.0)) == ([0, 1, 2], [3, 6, 8])  # edges touch all three
    assert bi.cells_in_box(1.0000001, 1.0000001, 1.9999999, 4.9999999).tolist() == []
    assert bi.ranges([0, 1, 2], [3, 6, 8]) == [(0, 8)] and bi.ranges([0, 2], [3, 8]) == [(0, 3), (6, 8)]
    back = BlockIndex.from_dict(json.loads(json.dumps(bi.to_dict())))
    np.testing.assert_array_equal(back.boxes, bi.boxes)
    assert (back.block_points, back.count) == (3, 8)
    with pytest.raises(ValueError, match="2 boxes for 8 points in cells of 3"):
        BlockIndex(3, 8, bi.boxes[:2])
    # cells: boxes every 2 points, blocks of 4; reading stops after the last cell met
    cells = BlockIndex(4, 9, np.array([[0, 0, 1, 1], [5, 0, 6, 1], [0, 0, 1, 1], [9, 9, 9, 9],
                                       [0, 0, 1, 1]], float), 2)
    assert len(cells) == 3 and cells.needs(cells.cells_in_box(5, 0, 5, 0)) == ([0], [4])
    assert cells.needs(cells.cells_in_box(0, 0, 1, 1)) == ([0, 1, 2], [2, 6, 9])
    assert cells.needs(cells.cells_in_box(5, 0, 9, 9)) == ([0, 1], [4, 8])
    assert cells.ranges([0, 1], [4, 6]) == [(0, 6)] and cells.ranges([0, 1], [2, 6]) == [(0, 2), (4, 6)]
    back = BlockIndex.from_dict(json.loads(json.dumps(cells.to_dict())))
    assert (back.block_points, back.cell_points, back.count) == (4, 2, 9)
    with pytest.raises(ValueError, match=r"block_points \(4\) must be a positive multiple of cell_points \(3\)"):
        BlockIndex(4, 9, np.zeros((3, 4)), 3)


def test_read_ranges_equal_whole_read(tiles):
    p = tiles["utm"][0]
    assert las_chunk_points(p) == 50_000 and las_chunk_points(tiles["utm"][2]) is None
    full = read_points(p)
    got = list(iter_las_ranges(p, [(100_000, 170_000), (299_990, 300_000), (5, 6)], piece_points=50_000))
    assert [(s, len(c)) for s, c in got] == [(100_000, 50_000), (150_000, 20_000), (299_990, 10), (5, 1)]
    for s, c in got:
        _same(c, full.select(slice(s, s + len(c))))
    with pytest.raises(LidarFormatError, match=r"point range 299999\.\.300001 is outside the file's 0\.\.300000"):
        list(iter_las_ranges(p, [(299_999, 300_001)]))


# --------------------------------------------------------------------------- identity with the full decode
def test_block_queries_equal_full_decode_synthetic(tiles):
    paths = tiles["utm"]
    idx = TileIndex.build(paths, decode="blocks", blocks=True, max_cached_points=0, block_points=20_000)
    bis = [idx.block_index(p) for p in paths]
    assert [len(b) for b in bis] == [6, 3, 5]          # LAZ: its 50 000-point chunks; LAS: block_points
    assert bis[2].block_points == 20_000
    assert [b.cell_points for b in bis] == [5_000, 5_000, 5_000] and len(bis[0].boxes) == 60
    allpts = _oracle(paths)
    rng = np.random.default_rng(11)
    queries = _random_queries(rng, idx.bounds[:4], 40, blocks_of=bis)
    nonempty = 0
    for q in queries:
        got = _run(idx, q)
        _same(got, allpts.select(_mask(allpts.xyz, q)))
        nonempty += len(got) > 0
    assert nonempty > len(queries) // 2
    # today's path (whole-tile decode, nothing cached) gives the same answers
    whole = TileIndex.build(paths, decode="whole", max_cached_points=0)
    for q in queries[:12] + queries[-8:]:
        _same(_run(idx, q), _run(whole, q))


def test_block_queries_equal_full_decode_ahn3():
    idx = TileIndex.build([AHN1, AHN2], crs=RD, decode="blocks", blocks=True, max_cached_points=0)
    allpts = _oracle([AHN1, AHN2], crs=RD)
    bis = [idx.block_index(AHN1), idx.block_index(AHN2)]
    assert [len(b) for b in bis] == [13, 5]
    rng = np.random.default_rng(7)
    queries = _random_queries(rng, idx.bounds[:4], 15, blocks_of=[bis[1]])
    queries += [("radius", ((85000.0, 447472.0), 6.0)),            # the house on the tile boundary
                ("box", (84999.999, 447412.8, 85000.001, 447641.299))]  # the seam itself
    for q in queries:
        _same(_run(idx, q), allpts.select(_mask(allpts.xyz, q)))
    assert idx.crs.to_epsg() == 7415 and idx.query_radius((85000.0, 447472.0), 6.0).crs.to_epsg() == 7415


# --------------------------------------------------------------------------- fewer points decoded
def test_cold_clip_decodes_few_blocks(tiles):
    scan, shuffled = tiles["utm"][0], tiles["utm"][1]
    idx = TileIndex.build([scan, shuffled], blocks=True, max_cached_points=0)  # decode="auto"
    assert idx.decoded_points == 420_000            # the one pass that made the block indexes
    idx.decoded_points = 0
    c = (X0 + 150.0, Y0 + 20.0)                     # inside strip 1 only
    got = idx.query_radius(c, 5.0)
    # strip 1 holds 500 points per metre of x in file order: x 145-155 m is points ~72 500-77 500,
    # cells 14-15 of block 1; the chunk is decoded from its start (50 000) to the end of cell 15
    bi = idx.block_index(scan)
    assert bi.needs(bi.cells_in_box(c[0] - 5, c[1] - 5, c[0] + 5, c[1] + 5)) == ([1], [80_000])
    assert len(got) > 500 and idx.decoded_points == 30_000
    ref = read_points(scan)
    _same(got, ref.select(in_radius(ref.xyz, c, 5.0)))
    # shuffled points: every block spans the tile, "auto" falls back to the whole tile
    idx.decoded_points = 0
    got = idx.query_radius((X0 + 450.0, Y0 + 50.0), 5.0)
    assert idx.decoded_points == 120_000 and len(got) > 500
    # same with decode="whole": always the whole tile
    whole = TileIndex.build([scan], decode="whole", max_cached_points=0)
    whole.query_radius(c, 5.0)
    assert whole.decoded_points == 300_000 and whole.block_index(scan) is None


def test_lazy_block_index_then_block_cache(tiles):
    scan = tiles["utm"][0]
    idx = TileIndex.build([scan], max_cached_points=120_000)   # tile too big to keep whole
    assert idx.block_index(scan) is None
    c = (X0 + 40.0, Y0 + 80.0)
    first = idx.query_radius(c, 4.0)                 # whole decode, records the block index
    assert idx.decoded_points == 300_000 and len(idx.block_index(scan)) == 6
    second = idx.query_radius(c, 4.0)                # block path: one or two chunks
    assert 300_000 < idx.decoded_points <= 400_000
    _same(first, second)
    n = idx.decoded_points
    _same(idx.query_radius(c, 4.0), first)           # blocks kept in memory: nothing decoded
    assert idx.decoded_points == n
    assert idx._cached_points <= 120_000
    idx.query_box(X0, Y0, X0 + 300.0, Y0 + 100.0)    # everything: auto -> whole tile, not kept
    assert idx._cached_points <= 120_000


def test_small_tile_still_cached_whole(tiles):
    scan = tiles["utm"][0]
    idx = TileIndex.build([scan], blocks=True)       # 300 000 points fit the default budget
    n = idx.decoded_points
    c = (X0 + 150.0, Y0 + 20.0)
    a = idx.query_radius(c, 5.0)                     # block path (index known): two chunks at most
    assert idx.decoded_points - n <= 100_000
    idx.clear_cache()
    list(idx.iter_points())                          # a whole read keeps the tile in memory
    n = idx.decoded_points
    _same(idx.query_radius(c, 5.0), a)
    assert idx.decoded_points == n
    # many clips in one tile that fits: once block reads add up to a quarter of it, it is read whole
    fresh = TileIndex.build([scan], blocks=True)
    fresh.decoded_points = 0
    ref = read_points(scan)
    for x in np.linspace(10.0, 290.0, 15):
        q = (X0 + x, Y0 + (20.0 if x < 150 else 80.0))
        _same(fresh.query_radius(q, 5.0), ref.select(in_radius(ref.xyz, q, 5.0)))
    assert scan in fresh._cache and 75_000 <= fresh.decoded_points < 75_000 + 300_000


# --------------------------------------------------------------------------- cache file
def test_cache_round_trips_block_index(tiles, tmp_path, monkeypatch):
    folder = tmp_path / "lidar"
    folder.mkdir()
    for p in tiles["utm"]:
        shutil.copy(p, folder / p.name)
    os.utime(folder / "c_scan.las", ns=(5, 5))
    cache = tmp_path / "lidar_index.json"
    idx = TileIndex.build("lidar/*", cache_path=cache, root=tmp_path, blocks=True, max_cached_points=0,
                          block_points=20_000)
    doc = json.loads(cache.read_text())
    assert doc["version"] == 2 and all("blocks" in t for t in doc["tiles"])

    def no_full_read(*a, **k):
        raise AssertionError("a tile was read whole although its block index is cached")

    monkeypatch.setattr(ti, "iter_points", no_full_read)
    again = TileIndex.build("lidar/*", cache_path=cache, root=tmp_path, max_cached_points=0)
    for t in idx.tiles:
        a, b = idx.block_index(t), again.block_index(t)
        assert (a.block_points, a.count) == (b.block_points, b.count)
        np.testing.assert_array_equal(a.boxes, b.boxes)
    c = (X0 + 700.0, Y0 + 30.0)
    got = again.query_radius(c, 6.0)
    assert 0 < again.decoded_points <= 40_000        # LAS blocks of 20 000: one or two of five read
    monkeypatch.undo()
    ref = read_points(folder / "c_scan.las")
    _same(got, ref.select(in_radius(ref.xyz, c, 6.0)))
    # a changed file: refused by the index that knew it; a rebuild drops its block index
    write_points(folder / "c_scan.las", ref.select(slice(0, 1000)))
    os.utime(folder / "c_scan.las", ns=(6, 6))
    again.clear_cache()
    with pytest.raises(TileIOError, match=r"c_scan\.las: the file changed since it was indexed"):
        again.query_radius(c, 6.0)
    fresh = TileIndex.build("lidar/*", cache_path=cache, root=tmp_path)
    assert fresh.block_index(folder / "c_scan.las") is None
    assert fresh.block_index(folder / "a_scan.laz") is not None


def test_lazy_index_written_to_cache_and_old_cache_ignored(tiles, tmp_path):
    folder = tmp_path / "t"
    folder.mkdir()
    shutil.copy(tiles["utm"][0], folder / "a.laz")
    cache = tmp_path / "idx.json"
    old = {"format": "lidarcat-tile-index", "version": 1,
           "tiles": [{"path": "t/a.laz", "size": 1, "mtime_ns": 1, "count": 7, "bounds": [0, 0, 1, 1, 0, 1],
                      "file_crs_wkt": None, "description": "x", "attributes": []}]}
    cache.write_text(json.dumps(old))
    idx = TileIndex.build("t/*", cache_path=cache, root=tmp_path, max_cached_points=0)
    assert idx.tiles[0].count == 300_000             # the version-1 file was read as absent
    assert "blocks" not in json.loads(cache.read_text())["tiles"][0]
    idx.query_radius((X0 + 10.0, Y0 + 10.0), 3.0)    # first cold query: whole read, index stored
    second = TileIndex.build("t/*", cache_path=cache, root=tmp_path, max_cached_points=0)
    assert len(second.block_index(folder / "a.laz")) == 6
    second.query_radius((X0 + 10.0, Y0 + 10.0), 3.0)
    assert second.decoded_points <= 100_000


def test_decode_option_checked():
    with pytest.raises(ValueError, match="decode must be one of auto, blocks, whole, got 'fast'"):
        TileIndex.build([AHN2], crs=RD, decode="fast")


def test_truncated_files_give_located_errors(tmp_path):
    data = AHN2.read_bytes()
    (tmp_path / "t.laz").write_bytes(data[:len(data) // 2])  # the chunk table at the end is gone
    with pytest.raises(LidarFormatError, match=r"t\.laz: truncated or corrupt point data reading points "
                                               r"150000\.\.200000 of 208432"):
        list(iter_las_ranges(tmp_path / "t.laz", [(150_000, 200_000)], crs=RD))
    pdal = (LIDAR_DATA / "pdal_sample_c.las").read_bytes()
    (tmp_path / "t.las").write_bytes(pdal[:len(pdal) // 2])
    with pytest.raises(LidarFormatError, match=r"t\.las: truncated: the header announces 14408 points"):
        list(iter_las_ranges(tmp_path / "t.las", [(0, 10)]))
    with pytest.raises(LidarFormatError, match=r"point ranges can be read from LAS/LAZ files only"):
        list(iter_las_ranges(tmp_path / "t.xyz", [(0, 10)]))


def test_block_prefixes_kept_and_extended(tiles):
    scan = tiles["utm"][0]
    idx = TileIndex.build([scan], blocks=True, decode="blocks", max_cached_points=1_000_000)
    ref = read_points(scan)
    idx.decoded_points = 0
    a, b = (X0 + 112.0, Y0 + 20.0), (X0 + 190.0, Y0 + 20.0)  # both in block 1 (points 50 000-99 999)
    _same(idx.query_radius(a, 3.0), ref.select(in_radius(ref.xyz, a, 3.0)))
    # strip 1 holds 500 points per metre of x: x 109-115 m is points ~54 500-57 500, cells 10-11
    first = idx.decoded_points
    assert first == 10_000                             # block 1 from its start to the end of cell 11
    _same(idx.query_radius(b, 3.0), ref.select(in_radius(ref.xyz, b, 3.0)))
    assert idx.decoded_points - first == 50_000        # x 187-193 m: cells 18-19, block 1 to its end
    n = idx.decoded_points
    _same(idx.query_radius(a, 3.0), ref.select(in_radius(ref.xyz, a, 3.0)))
    assert idx.decoded_points == n                     # the longer part kept in memory serves both
