"""COPC tiles read by their octree: only the nodes a box meets, the same points as a full read, located errors."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from lidarcat.errors import LidarFormatError
from lidarcat.lidar import TileIndex, clip, read_header, read_points
from lidarcat.lidar.copc import is_copc, read_copc_box

copclib = pytest.importorskip("copclib")
laspy = pytest.importorskip("laspy")

from copc_fixture import write_copc  # noqa: E402  (needs copclib)

CRS = "EPSG:31983"
N = 20_000


@pytest.fixture(scope="module")
def copc(tmp_path_factory):
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(500000, 500400, N), rng.uniform(7500000, 7500300, N), rng.uniform(10, 40, N)])
    path = tmp_path_factory.mktemp("copc") / "tile.copc.laz"
    fx = write_copc(path, xyz, classification=rng.integers(1, 7, N))
    return fx, xyz


def _inside(xyz, box):
    return (xyz[:, 0] >= box[0]) & (xyz[:, 0] <= box[2]) & (xyz[:, 1] >= box[1]) & (xyz[:, 1] <= box[3])


def test_fixture_is_a_copc_file_laspy_reads(copc):
    fx, xyz = copc
    assert is_copc(fx.path)
    with laspy.CopcReader.open(str(fx.path)) as r:
        assert int(r.header.point_count) == N and r.header.version.minor == 4 and r.header.point_format.id == 6
        np.testing.assert_allclose(r.copc_info.center, fx.center)
        assert r.copc_info.halfsize == pytest.approx(fx.halfsize)
        pts = r.query()                                     # every node
        assert len(pts) == N
    whole = read_points(fx.path, crs=CRS)                   # the LAS/LAZ path reads it as LAZ 1.4
    np.testing.assert_allclose(whole.xyz, np.round(xyz[fx.file_order()], 2), atol=1e-9)
    assert read_header(fx.path, crs=CRS).description == "COPC 1.4, point format 6"
    assert not is_copc(fx.path.parent / "missing.laz")


@pytest.mark.parametrize("box", [(500010.3, 7500020.7, 500090.1, 7500110.2),    # inside one depth-2 column
                                 (500150.5, 7500080.5, 500260.5, 7500230.5),    # across node edges
                                 (499000.0, 7499000.0, 499500.0, 7499500.0),    # outside the cube
                                 (499000.0, 7499000.0, 501000.0, 7501000.0)])   # everything
def test_a_box_reads_only_the_nodes_it_meets_and_returns_the_filtered_points(copc, box):
    fx, _ = copc
    whole = read_points(fx.path, crs=CRS)
    res = read_copc_box(fx.path, box, crs=CRS)
    # the nodes whose cube meets the box, from the fixture's own octree
    met = [k for k in fx.nodes
           if (lambda b: b[0] <= box[2] and b[2] >= box[0] and b[1] <= box[3] and b[3] >= box[1])(fx.node_box(k))]
    assert res.nodes_read == len(met)
    assert res.points_decoded == sum(len(fx.nodes[k]) for k in met)
    assert res.nodes_known == len(fx.nodes)
    m = _inside(whole.xyz, box)
    assert len(res.cloud) == int(m.sum())
    np.testing.assert_array_equal(res.cloud.xyz, whole.xyz[m])          # same points, same (file) order
    for name, values in whole.attributes.items():
        np.testing.assert_array_equal(res.cloud.attributes[name], values[m])
    assert res.cloud.crs is not None and res.cloud.crs.to_epsg() == 31983
    if box[2] - box[0] < 100:                     # the box inside one depth-2 column
        assert res.points_decoded < N / 3 and res.bytes_read < fx.path.stat().st_size / 2


def test_tile_index_queries_copc_by_the_octree(copc, tmp_path):
    """TileIndex (clips, windows, tile-parallel products, extract --find) uses the octree on a COPC tile."""
    fx, _ = copc
    whole = read_points(fx.path, crs=CRS)
    idx = TileIndex.build([fx.path], crs=CRS)
    box = (500010.3, 7500020.7, 500090.1, 7500110.2)
    got = idx.query_box(*box)
    m = _inside(whole.xyz, box)
    np.testing.assert_array_equal(got.xyz, whole.xyz[m])
    assert idx.decoded_points == read_copc_box(fx.path, box, crs=CRS).points_decoded < N / 3
    c = np.array([500200.0, 7500150.0])
    r = idx.query_radius(c, 12.0)
    d = np.hypot(*(whole.xyz[:, :2] - c).T)
    np.testing.assert_array_equal(r.xyz, whole.xyz[d <= 12.0])
    found = clip([fx.path], c, 12.0, height_filter=None, crs=CRS)
    np.testing.assert_array_equal(found.xyz, whole.xyz[d <= 12.0])


def test_wrong_header_bounds_do_not_hide_points(copc, tmp_path):
    """The header's bounds are never used: moved 10 km away, the query still finds the points."""
    fx, _ = copc
    bad = tmp_path / "lying.copc.laz"
    data = bytearray(fx.path.read_bytes())
    mx, mn_x, my, mn_y, mz, mn_z = struct.unpack_from("<6d", data, 179)
    struct.pack_into("<6d", data, 179, mx + 1e4, mn_x + 1e4, my + 1e4, mn_y + 1e4, 1000.0, 999.0)
    bad.write_bytes(bytes(data))
    box = (500150.5, 7500080.5, 500260.5, 7500230.5)
    want = read_copc_box(fx.path, box, crs=CRS).cloud
    got = TileIndex.build([bad], crs=CRS).query_box(*box)
    assert len(got) == len(want) > 0
    np.testing.assert_array_equal(got.xyz, want.xyz)                    # heights outside the header's too


def _root_page(data: bytes) -> tuple[int, int]:
    """Offset and size of the root hierarchy page, from the COPC info VLR (the first VLR)."""
    header_size = struct.unpack_from("<H", data, 94)[0]
    info = header_size + 54
    return struct.unpack_from("<QQ", data, info + 40)


def _entries(data: bytes) -> dict[tuple, int]:
    off, size = _root_page(data)
    out = {}
    for k in range(size // 32):
        key = struct.unpack_from("<iiii", data, off + 32 * k)
        out[key] = off + 32 * k
    return out


def _other_chunk(data: bytearray, entry_at: int) -> bytes:
    """Offset and size (12 bytes) of a depth-2 node's chunk, to be written over another entry's."""
    other = next(at for key, at in _entries(bytes(data)).items() if key[0] == 2)
    return bytes(data[other + 16:other + 28])


@pytest.mark.parametrize("what, patch, message", [
    ("chunk offset past the end", lambda d, e: struct.pack_into("<Q", d, e + 16, len(d) + 1000),
     r"corrupt COPC hierarchy: node 0-0-0-0: its chunk \(byte [\d,]+, [\d,]+ bytes\) lies outside the point data"),
    ("negative point count", lambda d, e: struct.pack_into("<i", d, e + 28, -5),
     r"corrupt COPC hierarchy: node 0-0-0-0 has -5 points in a chunk of"),
    ("absurd point count", lambda d, e: struct.pack_into("<i", d, e + 28, 2_000_000_000),
     r"corrupt COPC hierarchy: node 0-0-0-0 claims 2,000,000,000 points in [\d,]+ compressed bytes"),
    ("child page past the end", lambda d, e: struct.pack_into("<Qii", d, e + 16, len(d) - 8, 64, -1),
     r"corrupt COPC hierarchy: a read of 64 bytes at byte [\d,]+ lies outside the file"),
    ("offset of another node's chunk", lambda d, e: d.__setitem__(slice(e + 16, e + 28), _other_chunk(d, e)),
     r"corrupt COPC hierarchy: node 0-0-0-0 \(chunk at byte [\d,]+\): the chunk holds [\d,]+ points, the "
     r"hierarchy says 1,250"),
])
def test_corrupt_hierarchy_is_a_located_error(copc, tmp_path, what, patch, message):
    fx, _ = copc
    data = bytearray(fx.path.read_bytes())
    patch(data, _entries(bytes(data))[(0, 0, 0, 0)])
    bad = tmp_path / "bad.copc.laz"
    bad.write_bytes(bytes(data))
    box = (500010.3, 7500020.7, 500090.1, 7500110.2)
    with pytest.raises(LidarFormatError, match=str(bad).replace(".", r"\.") + ": " + message):
        read_copc_box(bad, box, crs=CRS)
    with pytest.raises(LidarFormatError, match=message):                # the same through the tile index
        TileIndex.build([bad], crs=CRS).query_box(*box)


def test_root_page_outside_the_file_is_a_located_error(copc, tmp_path):
    fx, _ = copc
    data = bytearray(fx.path.read_bytes())
    header_size = struct.unpack_from("<H", data, 94)[0]
    struct.pack_into("<Q", data, header_size + 54 + 48, 10 ** 9)       # root page size: 1 GB
    bad = tmp_path / "bad_root.copc.laz"
    bad.write_bytes(bytes(data))
    with pytest.raises(LidarFormatError, match=rf"{bad.name}: .*(outside the file|not a valid COPC file)"):
        read_copc_box(bad, (500000.0, 7500000.0, 500100.0, 7500100.0), crs=CRS)


def test_garbage_in_a_node_chunk_is_a_located_error(copc, tmp_path):
    """Random bytes over a node's compressed chunk: refused before (or while) decoding, naming the file."""
    fx, _ = copc
    data = bytearray(fx.path.read_bytes())
    e = _entries(bytes(data))[(0, 0, 0, 0)]
    off, nbytes = struct.unpack_from("<Qi", data, e + 16)
    data[off + 4:off + nbytes - 4] = np.random.default_rng(1).integers(0, 256, nbytes - 8, dtype=np.uint8).tobytes()
    bad = tmp_path / "garbage.copc.laz"
    bad.write_bytes(bytes(data))
    with pytest.raises(LidarFormatError, match=rf"^{str(bad).replace('.', '[.]')}: "):
        read_copc_box(bad, (500000.0, 7500000.0, 500400.0, 7500300.0), crs=CRS)


def test_random_damage_to_the_hierarchy_gives_points_or_a_located_error(copc, tmp_path):
    """Bytes of the hierarchy pages overwritten at random (60 cases): the reader returns points or raises
    LidarFormatError naming the file; never another exception, a crash or a huge allocation."""
    fx, _ = copc
    clean = fx.path.read_bytes()
    off, size = _root_page(clean)
    rng = np.random.default_rng(11)
    bad = tmp_path / "fuzz.copc.laz"
    outcomes = {"points": 0, "error": 0}
    for _ in range(60):
        data = bytearray(clean)
        for _ in range(int(rng.integers(1, 4))):
            k = int(rng.integers(off, off + size))
            data[k] = int(rng.integers(0, 256))
        bad.write_bytes(bytes(data))
        try:
            res = read_copc_box(bad, (500150.5, 7500080.5, 500260.5, 7500230.5), crs=CRS)
        except LidarFormatError as ex:
            assert str(ex).startswith(f"{bad}: "), ex
            outcomes["error"] += 1
        else:
            assert res.points_decoded <= N
            outcomes["points"] += 1
    assert outcomes["error"] > 0 and outcomes["points"] > 0


def test_tile_parallel_dsm_on_copc_tiles_equals_the_laz_run(tmp_path):
    """lidarcat lidar dsm over two COPC tiles (the neighbour's overlap read by the octree) writes the same
    rasters as over the same points in plain LAZ tiles."""
    pytest.importorskip("rasterio")
    import rasterio
    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.lidar import PointCloud, resolve_crs, write_points

    rng = np.random.default_rng(5)
    n = 12_000
    xy = np.column_stack([rng.uniform(600000, 600200, n), rng.uniform(7400000, 7400100, n)])
    z = 50 + 0.05 * (xy[:, 0] - 600000) + 3 * np.sin(xy[:, 1] / 15.0) + rng.normal(0, 0.05, n)
    xyz = np.column_stack([xy, z])
    for fmt in ("copc", "laz"):
        (tmp_path / fmt).mkdir()
    for name, sel in (("west", xy[:, 0] < 600100), ("east", xy[:, 0] >= 600100)):
        write_copc(tmp_path / "copc" / f"{name}.laz", xyz[sel])
        write_points(tmp_path / "laz" / f"{name}.laz", PointCloud(np.round(xyz[sel], 2), {}, crs=resolve_crs(CRS)),
                     scale_m=0.01)
    assert is_copc(tmp_path / "copc" / "west.laz") and not is_copc(tmp_path / "laz" / "west.laz")
    grids = {}
    for fmt in ("copc", "laz"):
        res = CliRunner().invoke(cli, ["lidar", "dsm", str(tmp_path / fmt), "-o", str(tmp_path / f"dsm_{fmt}"),
                                       "--crs", CRS, "--cell-m", "2", "--overlap-m", "20"])
        assert res.exit_code == 0, res.output
        for name in ("west", "east"):
            with rasterio.open(tmp_path / f"dsm_{fmt}" / f"{name}.tif") as ds:
                grids[fmt, name] = (ds.read(1), tuple(ds.transform))
    for name in ("west", "east"):
        np.testing.assert_array_equal(grids["copc", name][0], grids["laz", name][0])
        assert grids["copc", name][1] == grids["laz", name][1]
        assert np.isfinite(grids["copc", name][0]).mean() > 0.9


def test_many_queries_in_one_copc_tile_switch_to_one_whole_decode(copc):
    """decode="auto": octree reads until they add up to a quarter of the tile, then the tile is decoded
    once and kept in memory; the answers stay those of a whole read + filter."""
    fx, _ = copc
    whole = read_points(fx.path, crs=CRS)
    idx = TileIndex.build([fx.path], crs=CRS)
    rng = np.random.default_rng(3)
    counts = []
    for _ in range(12):
        x, y = rng.uniform(500000, 500380), rng.uniform(7500000, 7500280)
        box = (x, y, x + 20.0, y + 20.0)
        got = idx.query_box(*box)
        np.testing.assert_array_equal(got.xyz, whole.xyz[_inside(whole.xyz, box)])
        counts.append(idx.decoded_points)
    steps = np.diff([0] + counts)
    switch = int(np.flatnonzero(steps == N)[0])                     # the one whole decode
    assert switch >= 1 and counts[switch - 1] >= N / 4                # octree reads reached a quarter...
    assert switch == 1 or counts[switch - 2] < N / 4                 # ...just before the switch
    assert np.all(steps[:switch] < N) and np.all(steps[switch + 1:] == 0)   # octree reads before, memory after
    only = TileIndex.build([fx.path], crs=CRS, decode="blocks")       # "blocks": always the octree
    for _ in range(12):
        only.query_box(500100.0, 7500100.0, 500120.0, 7500120.0)
    assert only.decoded_points == 12 * read_copc_box(fx.path, (500100.0, 7500100.0, 500120.0, 7500120.0),
                                                     crs=CRS).points_decoded
