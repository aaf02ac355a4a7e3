"""``measure-control``'s second pass on the small review block (2 photos of 640 x 480 px, the town's roof vertices
as LiDAR control) with tie points (the true projections of random ground points + 0.3 px): L001 on photo 101,
``near_border`` in the first pass (its edges reach past the border), is predicted again from the block test's
orientation, measured with ``border="fit"`` against its true projection (the renderer's truth), written to the
table, and its decisions.csv row says pass 2; ``--no-second-pass`` leaves it at the border."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.stages.measure_control import measure_control
from lidarcat.synthetic.aerial import project_to_pixels

from control_block import make_block, read_rows

#: the pair the first pass loses at the border
LOST = ("101", "L001")


@pytest.fixture(scope="module")
def tied(tmp_path_factory):
    root = tmp_path_factory.mktemp("mc2") / "s"
    s, verts = make_block(root)
    rng = np.random.default_rng(0)
    eo = s.true_eo
    ground = float(np.median(verts[:, 2])) - 6.0
    lo, hi = eo[:, :2].min(axis=0) - 40, eo[:, :2].max(axis=0) + 40
    g = np.column_stack([rng.uniform(lo[0], hi[0], 300), rng.uniform(lo[1], hi[1], 300),
                         ground + rng.uniform(0, 4, 300)])
    w, h = s.camera.columns_px, s.camera.rows_px
    px = {p: s.project(p, g) for p in s.photo_ids}
    ok = {p: np.isfinite(x).all(axis=1) & (x[:, 0] > 2) & (x[:, 1] > 2) & (x[:, 0] < w - 3) & (x[:, 1] < h - 3)
          for p, x in px.items()}
    two = np.sum(list(ok.values()), axis=0) >= 2              # a tie point needs two photos
    assert two.sum() >= 30
    with open(root / "image_points.csv", "a") as fh:
        for p in s.photo_ids:
            for j in np.flatnonzero(ok[p] & two):
                c, r = px[p][j] + rng.normal(0, 0.3, 2)
                fh.write(f"{p},T{j:04d},{c:.3f},{r:.3f}\n")
    ids = [f"L{i + 1:03d}" for i in range(len(verts))]
    truth = {(pid, v): x for k, pid in enumerate(s.photo_ids)
             for v, x in zip(ids, project_to_pixels(s.camera, s.true_eo[k], verts))}
    return s, root, truth


def test_the_second_pass_measures_the_pair_the_first_lost_at_the_border(tied, tmp_path):
    s, root, truth = tied
    res = measure_control(root, tmp_path / "on", gallery=False, lines="none", table=tmp_path / "ip_on.csv")
    dec = {(r["photo"], r["point"]): r for r in read_rows(tmp_path / "on" / "decisions.csv")}
    d = dec[LOST]
    assert d["status"] == "measured" and d["decision"] == "accept" and d["pass"] == "2", d
    px = np.array([float(d["col_px"]), float(d["row_px"])])
    assert np.hypot(*(px - truth[LOST])) < 3.0, (px, truth[LOST])
    # written to the table, to the pixel of decisions.csv
    rows = {(r["photo"], r["point"]): r for r in read_rows(tmp_path / "ip_on.csv")}
    assert abs(float(rows[LOST]["col_px"]) - px[0]) < 1e-3 and abs(float(rows[LOST]["row_px"]) - px[1]) < 1e-3
    info = res.summary["second_pass"]
    assert info["status"] == "ok" and info["measured"] >= 1 and info["block_check"]["status"] == "ok"
    assert info["block_check"]["tested"] >= 3          # the first pass's two and the new one, in one block again
    # the first pass's rows say pass 1; a pair the second pass tried and lost again keeps its first reason + why
    assert all(r["pass"] == "1" for k, r in dec.items() if k != LOST and r["status"] == "measured")
    again = [r for r in dec.values() if r["status"] == "not_visible" and r["reason"].startswith("outside:")]
    assert again and all("; second pass: " in r["reason"] for r in again)
    # off: the same pair stays at the border (the CLI switch)
    r = CliRunner().invoke(cli, ["measure-control", str(root), "--no-second-pass", "--no-gallery", "--lines", "none",
                                 "-o", str(tmp_path / "off"), "--json"])
    assert r.exit_code == 0, r.output
    off = {(r["photo"], r["point"]): r for r in read_rows(tmp_path / "off" / "decisions.csv")}
    assert off[LOST]["status"] == "near_border" and off[LOST]["pass"] == "1"
    assert json.loads(r.output)["summary"]["second_pass"] == {"status": "off"}
    assert sum(x["decision"] == "accept" for x in off.values()) + 1 == res.accepted
