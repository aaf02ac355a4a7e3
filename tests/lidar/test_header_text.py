"""Issue 24: a non-ASCII byte in a LAS header text field made ``lidar ground`` end in a traceback
(laspy reads the bytes, then refuses to write them back).  Now the copy is written, the field
made ASCII (``?`` for each other byte), with a warning naming the file and the field."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli


def _tile(path: Path, offset: int, junk: bytes) -> Path:
    rng = np.random.default_rng(24)
    n = 3000
    xyz = np.column_stack([85000 + rng.random(n) * 50, 447000 + rng.random(n) * 50, 400 + rng.random(n)])
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales, h.offsets = [0.01] * 3, [85000, 447000, 0]
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz.T
    las.write(path)
    data = bytearray(path.read_bytes())
    data[offset:offset + len(junk)] = junk
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("offset,field", [(26, "system identifier"), (58, "generating software")])
@pytest.mark.parametrize("junk", [b"\xe9\xff\x80A", "Agência".encode()], ids=["bytes", "utf8"])
def test_ground_copies_a_tile_with_non_ascii_header_text(tmp_path, offset, field, junk):
    src = _tile(tmp_path / "a.las", offset, junk)
    before = src.read_bytes()
    r = CliRunner().invoke(cli, ["lidar", "ground", str(src), "-o", str(tmp_path / "g"), "--crs", "EPSG:28992"])
    assert r.exit_code == 0, r.output
    assert "Traceback" not in r.output and "internal error" not in r.output
    assert f"{src}: the header's {field} b'" in r.output and "is not ASCII (as LAS requires); written as '" in r.output
    out = laspy.read(tmp_path / "g" / "a.las")
    text = getattr(out.header, field.replace(" ", "_"))
    assert isinstance(text, str) and text.isascii() and "?" in text
    assert len(out.points) == 3000 and (np.asarray(out.classification) == 2).any()
    assert src.read_bytes() == before      # the input is never modified
    r = CliRunner().invoke(cli, ["lidar", "info", str(src)])
    assert r.exit_code == 0, r.output
