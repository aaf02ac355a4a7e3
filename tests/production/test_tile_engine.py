"""The tile engine (lidarcat.lidar.jobs) knows no product: it runs the function each job names."""

from __future__ import annotations

import json
import pickle
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


# --------------------------------------------------------------------------- issue 24: markers prove content
def _engine_job(tmp_path, name="o.json"):
    tile = tmp_path / "t.laz"
    tile.write_bytes(b"not read by the function")
    return TileJob(write_bounds, str(tile), (0.0, 0.0, 1.0, 1.0), (), str(tmp_path / name), {"k": 1},
                   buffered=False)


def test_the_marker_records_the_sha256_of_the_output(tmp_path):
    from lidarcat._util import file_sha256

    job = _engine_job(tmp_path)
    run_jobs([job])
    marker = json.loads((tmp_path / "o.json.done.json").read_text())
    assert marker["sha256"] == {job.output: file_sha256(job.output)}
    assert {k: v for k, v in marker.items() if k != "sha256"} == json.loads(json.dumps(job.signature()))


GOOD = {"bounds": [0.0, 0.0, 1.0, 1.0], "params": {"k": 1}}


@pytest.mark.parametrize("tamper", ["edited", "truncated", "emptied", "marker without hashes",
                                    "marker with another hash", "marker garbage", "marker nested"])
def test_resume_redoes_a_job_whose_output_or_marker_changed(tmp_path, tamper):
    job = _engine_job(tmp_path)
    out, marker = tmp_path / "o.json", tmp_path / "o.json.done.json"
    run_jobs([job])
    skipped = []
    run_jobs([job], progress=skipped.append)
    assert skipped == [1]  # unchanged: trusted, not redone
    m = json.loads(marker.read_text())
    if tamper == "edited":
        out.write_text(json.dumps({"bounds": [9.0, 9.0, 9.0, 9.0], "params": {"k": 1}}))
    elif tamper == "truncated":
        out.write_bytes(out.read_bytes()[:10])
    elif tamper == "emptied":
        out.write_bytes(b"")
    elif tamper == "marker without hashes":  # a marker of before issue 24
        marker.write_text(json.dumps({k: v for k, v in m.items() if k != "sha256"}))
    elif tamper == "marker with another hash":
        marker.write_text(json.dumps({**m, "sha256": {job.output: "0" * 64}}))
    elif tamper == "marker garbage":
        marker.write_bytes(b"\xff\xfe{not json")
    else:
        marker.write_text("[" * 100_000 + "]" * 100_000)  # RecursionError in json.loads
    seen = []
    assert run_jobs([job], progress=seen.append) == [job.output]
    assert seen == [1] and json.loads(out.read_text()) == GOOD  # redone: progress counts a run tile, not a skip
    again = []
    run_jobs([job], progress=again.append)
    assert again == [1] and json.loads(marker.read_text())["sha256"] == m["sha256"]


def test_read_done_output_gives_only_the_vouched_bytes(tmp_path):
    from lidarcat.errors import TileIOError
    from lidarcat.lidar.jobs import read_done_output

    job = _engine_job(tmp_path)
    run_jobs([job])
    assert json.loads(read_done_output(job)) == GOOD
    (tmp_path / "o.json").write_text(json.dumps({"bounds": [9.0] * 4, "params": {"k": 1}}))
    with pytest.raises(TileIOError) as ei:
        read_done_output(job)
    assert str(ei.value) == (f"{job.output}: does not match the SHA-256 of its done-marker o.json.done.json "
                             f"(changed after its job finished); delete both to recompute it")
    (tmp_path / "o.json").unlink()
    with pytest.raises(TileIOError, match=r"o\.json: cannot read the output of tile .*t\.laz"):
        read_done_output(job)


# --------------------------------------------------------------------------- edge buffers
def _tiles(tmp_path, starts_m=(0.0, 20.0)):
    """20 m LAS tiles of 400 points each starting at these eastings (default two adjacent ones,
    E 0-20 and 20-40)."""
    laspy = pytest.importorskip("laspy")
    import numpy as np

    rng = np.random.default_rng(1)
    paths = []
    for k, e0 in enumerate(starts_m):
        header = laspy.LasHeader(point_format=1, version="1.2")
        header.scales, header.offsets = [0.01] * 3, [500000.0, 7000000.0, 0.0]
        las = laspy.LasData(header)
        las.x = 500000.0 + e0 + rng.uniform(0, 20, 400)
        las.y = 7000000.0 + rng.uniform(0, 20, 400)
        las.z = rng.uniform(10, 20, 400)
        las.classification = np.full(400, 2, dtype=np.uint8)
        paths.append(tmp_path / f"t{k}.las")
        las.write(str(paths[-1]))
    return paths


def write_buffered_points(job: TileJob) -> None:
    """A buffered tile function of this test: writes the SHA-256 of the points it reads and their count."""
    import hashlib

    from lidarcat.lidar.jobs import read_with_buffer

    cloud, n_own = read_with_buffer(job)
    with open(job.output, "w", encoding="utf-8") as fh:
        json.dump({"n": len(cloud), "n_own": n_own, "xyz": hashlib.sha256(cloud.xyz.tobytes()).hexdigest()}, fh)


class _Payload:
    """Unpickling this creates the file *flag* (what an attacker's pickle would do, harmlessly)."""

    def __init__(self, flag):
        self.flag = str(flag)

    def __reduce__(self):
        return (open, (self.flag, "w"))


@pytest.mark.parametrize("tamper", ["points changed", "object array with a forged hash"])
def test_a_changed_edge_buffer_piece_is_not_read(tmp_path, tamper):
    """A piece whose bytes are not those its edge-buffer marker vouches for is ignored: the tile job
    decodes the neighbour itself (same output); an object array in it is never unpickled."""
    import numpy as np

    from lidarcat._util import file_sha256
    from lidarcat.lidar.jobs import edge_buffer_jobs, run_tile_job

    tiles = _tiles(tmp_path)
    jobs = tile_jobs_for(tiles, tmp_path / "ref")
    run_jobs(jobs)  # buffers made, read and removed
    ref = [json.loads(open(j.output).read()) for j in jobs]
    assert all(r["n"] > r["n_own"] == 400 for r in ref)  # the neighbours' strips are there

    jobs = tile_jobs_for(tiles, tmp_path / "out")
    rings = edge_buffer_jobs(jobs)
    for r in rings:
        run_tile_job(r)
    flag = tmp_path / "PAYLOAD_RAN"
    for r in rings:
        for piece in r.params["pieces"]:
            with np.load(piece) as z:
                arrays = {k: z[k] for k in z.files}
            assert len(arrays["xyz"]) > 0
            if tamper == "points changed":  # every height 1 m up
                arrays["xyz"] = arrays["xyz"] + [0.0, 0.0, 1.0]
            else:
                arrays["xyz"] = np.array([_Payload(flag)], dtype=object)
            with open(piece, "wb") as fh:
                np.savez(fh, **arrays)
            if tamper != "points changed":
                marker = json.loads(open(r.output + ".done.json").read())
                marker["sha256"][piece] = file_sha256(piece)  # the attacker forges the marker too
                with open(r.output + ".done.json", "w") as fh:
                    json.dump(marker, fh)
    for j in jobs:
        run_tile_job(j)
    assert [json.loads(open(j.output).read()) for j in jobs] == ref
    assert not flag.exists()
    proof = tmp_path / "proof"  # the payload is real: unpickling it creates its file
    pickle.loads(pickle.dumps(_Payload(proof)))
    assert proof.exists()


def test_resume_redoes_an_edge_buffer_whose_piece_changed(tmp_path):
    import numpy as np

    from lidarcat.lidar.jobs import edge_buffer_jobs, run_tile_job

    rings = edge_buffer_jobs(tile_jobs_for(_tiles(tmp_path), tmp_path / "out"))
    for r in rings:
        run_tile_job(r)
    piece = rings[0].params["pieces"][0]
    good = open(piece, "rb").read()
    run_jobs(rings, progress=(skipped := []).append)
    assert skipped == [len(rings)]
    with open(piece, "wb") as fh:
        np.savez(fh, xyz=np.zeros((3, 3)), crs=np.array(""))
    run_jobs(rings[:1], progress=(seen := []).append)
    assert seen == [1] and open(piece, "rb").read() == good  # rebuilt, not trusted


def tile_jobs_for(tiles, out):
    """The jobs of write_buffered_points over *tiles* with a 5 m overlap."""
    from lidarcat.lidar.jobs import tile_jobs

    return tile_jobs(write_buffered_points, tiles, out, crs="EPSG:31982", overlap_m=5.0, suffix=".json")


def test_fresh_las_tiles_are_neighbours_only_of_the_tiles_they_touch(tmp_path):
    """Three tiles in a row (E 0-20, 20-40, 80-100): with a 5 m overlap the first and the last
    are not neighbours.  Header bounds are unverified claims, so tile_jobs measures them first
    (before, every unverified tile was every tile's neighbour: n^2 reads)."""
    paths = _tiles(tmp_path, starts_m=(0.0, 20.0, 80.0))
    jobs = {j.tile.rsplit("/", 1)[-1]: j for j in tile_jobs_for(paths, tmp_path / "out")}
    names = {k: sorted(n.rsplit("/", 1)[-1] for n in j.neighbours) for k, j in jobs.items()}
    assert names == {"t0.las": ["t1.las"], "t1.las": ["t0.las"], "t2.las": []}
