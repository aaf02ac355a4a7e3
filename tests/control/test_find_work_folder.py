"""Issue 24: the work folder of ``extract --find`` is read as data, never as code, and only as far as its
done-markers vouch for it.

Before, each block's candidates were a pickle (``find_*.pkl``) and the done-marker checked the
inputs and parameters only: ``extract --find --work-dir W`` unpickled whatever lay in W, a folder
the help recommends sharing with Dask workers.  Now a block is a ``.npz`` of plain arrays read with
``allow_pickle=False`` and rebuilt field by field, and its marker holds its SHA-256: a changed block
is recomputed on resume, and a forged one (marker included) is refused with a located error.
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat._util import file_sha256
from lidarcat.cli.main import cli
from lidarcat.control.facets import Plane
from lidarcat.control.search import find_candidates_tiles, find_jobs, read_block, run_find_block, write_block
from lidarcat.control.vertices import ControlPoint
from lidarcat.errors import TileIOError
from lidarcat.lidar import TileIndex

LID = Path(__file__).parents[1] / "data" / "lidar"
TILES = [str(LID / "ahn3_cropped_1.laz"), str(LID / "ahn3_cropped_2.laz")]
AREA = (84990.0, 447460.0, 85050.0, 447520.0)  # one block of 3 x 3 cells, 8 tagged candidates


class Payload:
    """Unpickling this creates the file *flag* (what an attacker's pickle does, harmlessly)."""

    def __init__(self, flag):
        self.flag = str(flag)

    def __reduce__(self):
        return (open, (self.flag, "w"))


def _key(c):
    cp = c.point
    return (cp.point_id, c.score, tuple(cp.enh_m), tuple(cp.cov_m2.ravel()), cp.n_planes, cp.status)


@pytest.fixture(scope="module")
def index():
    return TileIndex.build(TILES, crs="EPSG:7415")


@pytest.fixture(scope="module")
def done(index, tmp_path_factory):
    """A finished work folder and its candidates (equal to the serial search: test_find_parallel.py)."""
    work = tmp_path_factory.mktemp("work")
    cands = find_candidates_tiles(index, AREA, classes=[6], crs="EPSG:7415", work_dir=work)
    assert len(cands) >= 3 and sorted(p.name for p in work.iterdir()) == [
        "find_00000_00000.npz", "find_00000_00000.npz.done.json"]
    return work, [_key(c) for c in cands]


def _resume(index, src, dst, **kw):
    shutil.copytree(src, dst)
    seen = []
    cands = find_candidates_tiles(index, AREA, classes=[6], crs="EPSG:7415", work_dir=dst, progress=seen.append,
                                  **kw)
    return [_key(c) for c in cands], seen


def test_the_reproducer_a_planted_pickle_is_never_loaded(done, tmp_path):
    """`extract --find --work-dir W` with pickles in W: the old block name with a marker matching
    its inputs and parameters (what made main unpickle it) and a stray evil.pkl."""
    work, ref = done
    w = tmp_path / "W"
    w.mkdir()
    flag = tmp_path / "PAYLOAD_RAN"
    (w / "evil.pkl").write_bytes(pickle.dumps([Payload(flag)]))
    index = TileIndex.build(TILES, crs="EPSG:7415")
    job = find_jobs(index, AREA, w, crs="EPSG:7415", classes=[6])[0]
    (w / "find_00000_00000.pkl").write_bytes(pickle.dumps([Payload(flag)]))
    (w / "find_00000_00000.pkl.done.json").write_text(json.dumps(job.signature()))
    base = ["extract", "--find", "--lidar", *TILES, "--crs", "EPSG:7415", "--classes", "6",
            "--box", *(str(v) for v in AREA)]
    r = CliRunner().invoke(cli, [*base, "--workers", "1", "--work-dir", str(w), "-o", str(tmp_path / "p.geojson")])
    assert r.exit_code == 0, r.output
    assert not flag.exists()
    features = json.loads((tmp_path / "p.geojson").read_text())["features"]
    assert [f["properties"]["point"] for f in features] == [k[0] for k in ref]
    assert [f["properties"]["score"] for f in features] == [k[1] for k in ref]
    pickle.loads((w / "evil.pkl").read_bytes())  # the payload is real: unpickling it creates its file
    assert flag.exists()


def test_the_block_file_holds_plain_arrays_only(done):
    work, _ = done
    with np.load(work / "find_00000_00000.npz", allow_pickle=False) as z:
        kinds = {z[k].dtype.kind for k in z.files}
    assert kinds <= {"i", "f", "U"}
    marker = json.loads((work / "find_00000_00000.npz.done.json").read_text())
    assert marker["sha256"] == {str(work / "find_00000_00000.npz"): file_sha256(work / "find_00000_00000.npz")}


def _same(a, b, where="found"):
    """*b* is *a*: same types, same bits (NaN included), read-only arrays, every dataclass field."""
    assert type(a) is type(b), where
    if isinstance(a, np.ndarray):
        assert (a.dtype, a.shape, a.tobytes()) == (b.dtype, b.shape, b.tobytes()), where
        assert not b.flags.writeable, where
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif dataclasses.is_dataclass(a):
        assert sorted(vars(b)) == sorted(f.name for f in dataclasses.fields(a)) == sorted(vars(a)), where
        for k in vars(a):
            _same(getattr(a, k), getattr(b, k), f"{where}.{k}")
    elif isinstance(a, float) and math.isnan(a):
        assert math.isnan(b), where
    else:
        assert a == b, where


def test_block_file_round_trip_keeps_every_field(index, tmp_path):
    """The candidates read back are those computed: every field of Candidate, ControlPoint and Plane
    (a field added to them and not to the block file fails here), same bits, read-only arrays."""
    job = find_jobs(index, AREA, tmp_path, crs="EPSG:7415", classes=[6])[0]
    found = run_find_block(job)
    assert len(found) >= 3 and all(c.point.planes and c.point.labels is not None for _, c in found)
    write_block(tmp_path / "b.npz", found)
    back = read_block((tmp_path / "b.npz").read_bytes(), tmp_path / "b.npz")
    _same(found, back)
    assert isinstance(back[0][1].point, ControlPoint) and isinstance(back[0][1].point.planes[0], Plane)
    write_block(tmp_path / "e.npz", [])
    assert read_block((tmp_path / "e.npz").read_bytes()) == []


@pytest.mark.parametrize("tamper", ["edited", "truncated", "emptied", "marker of before issue 24"])
def test_resume_recomputes_a_changed_block(index, done, tmp_path, tamper):
    work, ref = done
    w = tmp_path / "W"
    shutil.copytree(work, w)
    block, marker = w / "find_00000_00000.npz", w / "find_00000_00000.npz.done.json"
    good = block.read_bytes()
    if tamper == "edited":  # a valid block file with other candidates: one dropped
        found = read_block(good)
        write_block(block, found[1:])
    elif tamper == "truncated":
        block.write_bytes(good[: len(good) // 2])
    elif tamper == "emptied":
        block.write_bytes(b"")
    else:
        marker.write_text(json.dumps({k: v for k, v in json.loads(marker.read_text()).items() if k != "sha256"}))
    got, seen = _resume(index, w, tmp_path / "again")
    assert got == ref and seen == [1]  # recomputed (one block run), not skipped
    assert (tmp_path / "again" / "find_00000_00000.npz").read_bytes() == good


def _npz(**arrays):
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _forged(good: bytes, flag: Path) -> dict[str, bytes]:
    with np.load(io.BytesIO(good)) as z:
        a = {k: z[k] for k in z.files}
    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as zf:
        buf = io.BytesIO()
        np.save(buf, np.zeros(4_000_000))  # 32 MB of zeros in a few kB
        zf.writestr("tag.npy", buf.getvalue())
    return {
        "object array": _npz(**{**a, "point_id": np.array([Payload(flag)] * len(a["tag"]), dtype=object)}),
        "pickle": pickle.dumps([Payload(flag)]),
        "not a zip": b"PK\x03\x04 but no zip",
        "zip bomb": bomb.getvalue(),
        "array missing": _npz(**{k: v for k, v in a.items() if k != "score"}),
        "wrong dtype": _npz(**{**a, "score": a["score"].astype(np.float32).astype(str)}),
        "wrong shape": _npz(**{**a, "enh_m": a["enh_m"][:, :2]}),
        "unequal lengths": _npz(**{**a, "chi2": a["chi2"][1:]}),
        "bad status": _npz(**{**a, "status": np.array(["\x1b[2J" + "x" * 500] * len(a["tag"]))}),
        "plane of nothing": _npz(**{**a, "plane_of": a["plane_of"] + 10_000}),
        "label counts": _npz(**{**a, "label_n": a["label_n"] + 1}),
        "other version": _npz(**{**a, "version": np.array([99])}),
    }


@pytest.mark.parametrize("kind", ["object array", "pickle", "not a zip", "zip bomb", "array missing", "wrong dtype",
                                  "wrong shape", "unequal lengths", "bad status", "plane of nothing",
                                  "label counts", "other version"])
def test_a_forged_block_with_a_forged_marker_is_refused_with_a_located_error(index, done, tmp_path, kind):
    """Whoever can write the work folder can also write a marker with the right hash: the block is then
    read, but as data only: it is refused, naming the file, in one short line; nothing is unpickled."""
    work, _ = done
    w = tmp_path / "W"
    shutil.copytree(work, w)
    block, marker = w / "find_00000_00000.npz", w / "find_00000_00000.npz.done.json"
    flag = tmp_path / "PAYLOAD_RAN"
    block.write_bytes(_forged(block.read_bytes(), flag)[kind])
    m = json.loads(marker.read_text())
    marker.write_text(json.dumps({**m, "sha256": {str(block): file_sha256(block)}}))
    with pytest.raises(TileIOError) as ei:
        find_candidates_tiles(index, AREA, classes=[6], crs="EPSG:7415", work_dir=w)
    msg = str(ei.value)
    assert msg.startswith(f"{block}: not a block file of the vertex search ("), msg
    assert msg.endswith("); delete it and its .done.json marker to recompute the block"), msg
    assert "\n" not in msg and "\x1b" not in msg and len(msg) < len(str(block)) + 260, msg
    assert not flag.exists()


def test_a_block_changed_after_its_check_is_refused(index, done, tmp_path, monkeypatch):
    """The driver reads a block's bytes once and checks them against the marker (no window between
    the resume check and the read)."""
    import lidarcat.lidar.jobs as jobs_mod

    work, _ = done
    w = tmp_path / "W"
    shutil.copytree(work, w)
    block = w / "find_00000_00000.npz"
    real_run_jobs = jobs_mod.run_jobs

    def run_then_tamper(*a, **k):
        out = real_run_jobs(*a, **k)
        block.write_bytes(block.read_bytes()[:-1])
        return out

    monkeypatch.setattr(jobs_mod, "run_jobs", run_then_tamper)
    with pytest.raises(TileIOError, match="does not match the SHA-256 of its done-marker"):
        find_candidates_tiles(index, AREA, classes=[6], crs="EPSG:7415", work_dir=w)
