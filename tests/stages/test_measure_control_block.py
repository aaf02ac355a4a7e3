"""``measure-control``'s block test (--block-check, --lone-photo) wired to the survey's tie points.

Fast: the photos are small and never looked at -- the vertex extraction and the measurement are
replaced by their truth (the true projection + 0.3 px, one lone measurement moved 30 px), so what
is tested is the stage's check region: the tie points read from image_points.csv (points that are
not ground points, pixels through the camera), check_block over all photos, the decision and its
reason in decisions.csv, the switches."""

from __future__ import annotations

import csv
import json
import shutil
import types

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import SurveyError
from lidarcat.photocontrol import Measurement
from lidarcat.stages.measure_control import measure_control
from lidarcat.synthetic.aerial import aerial_survey

#: vertex -> photos it is measured on (101, 102 and 201 have one each; strip 2 runs back over strip 1: 203 over
#: 101), and the one moved onto another corner
MEASURED = {"V1": ["101", "203"], "V2": ["102", "103", "202"], "V3": ["103", "201"], "V4": ["202", "203"]}
MOVED = ("V1", "101")


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("mcb") / "s"
    s = aerial_survey(root, n_strips=2, photos_per_strip=3, gsd_m=0.15, image_size_px=(320, 240), side_overlap=0.6,
                      lidar_density_m2=0.05, n_gps_points=4, seed=3)
    assert list(s.photo_ids) == ["101", "102", "103", "201", "202", "203"]
    rng = np.random.default_rng(0)
    eo = s.true_eo
    ground = float(np.mean(eo[:, 2])) - 0.15 * s.camera.focal_length_mm / s.camera.pixel_size_x_mm
    # each vertex where its photos overlap: the mean of their nadir points, 8 m up
    verts = {}
    for v, photos in MEASURED.items():
        c = np.mean([eo[s.index(p), :2] for p in photos], axis=0) + rng.normal(0, 1.0, 2)
        verts[v] = np.r_[c, ground + 8.0]
        for p in photos:
            px = s.project(p, verts[v][None])[0]
            assert 20 < px[0] < 300 and 20 < px[1] < 220, (v, p, px)
    with open(root / "ground_points.csv", "a") as fh:
        for v, x in verts.items():
            fh.write(f"{v},{x[0]:.4f},{x[1]:.4f},{x[2]:.4f},0.01,0.01,0.03,lidar\n")
    # tie points: random points over the block, their true projections + 0.3 px
    lo, hi = eo[:, :2].min(axis=0) - 20, eo[:, :2].max(axis=0) + 20
    g = np.column_stack([rng.uniform(lo[0], hi[0], 400), rng.uniform(lo[1], hi[1], 400),
                         ground + rng.uniform(0, 6, 400)])
    px = {p: s.project(p, g) for p in s.photo_ids}
    ok = {p: np.isfinite(x).all(axis=1) & (x[:, 0] > 2) & (x[:, 1] > 2) & (x[:, 0] < 317) & (x[:, 1] < 237)
          for p, x in px.items()}
    two = np.sum(list(ok.values()), axis=0) >= 2            # a tie point needs two photos
    with open(root / "image_points.csv", "a") as fh:
        for p in s.photo_ids:
            for j in np.flatnonzero(ok[p] & two):
                c, r = px[p][j] + rng.normal(0, 0.3, 2)
                fh.write(f"{p},T{j:04d},{c:.3f},{r:.3f}\n")
    return s, root, verts


@pytest.fixture()
def measured(block, monkeypatch):
    """The extraction and the measurement replaced by the truth (the check region runs as it is)."""
    s, root, verts = block
    import lidarcat.control.vertices as cv
    import lidarcat.lidar.clipping as lc
    import lidarcat.match as lm
    import lidarcat.photocontrol as pc

    def clip(paths, en, radius, **kw):
        e, n = np.meshgrid(np.linspace(-5, 5, 11), np.linspace(-5, 5, 11))
        return types.SimpleNamespace(xyz=np.column_stack([en[0] + e.ravel(), en[1] + n.ravel(), np.zeros(e.size)]))

    class Vertex:
        def __init__(self, enh):
            self.enh_m, self.cov_m2, self.planes, self.status, self.reason = (
                np.asarray(enh, float), np.diag([0.01**2, 0.01**2, 0.03**2]), [], "ok", "")

        def __bool__(self):
            return True

    def measure_photo(img, cam, eo, targets, params=None):
        out = []
        for t in targets:
            pr = t.prediction
            if pr.photo not in MEASURED.get(pr.point, []):
                out.append(Measurement(pr.point, pr.photo, np.full(2, np.nan), np.full((2, 2), np.nan), "no_edges",
                                       "x", predicted_px=pr.px, predicted_cov_px2=pr.cov_px2))
                continue
            rng = np.random.default_rng(abs(hash((pr.point, pr.photo))) % 2**32)
            px = s.project(pr.photo, verts[pr.point][None])[0] + rng.normal(0, 0.3, 2)
            if (pr.point, pr.photo) == MOVED:
                px = px + np.array([30.0, 0.0])
            out.append(Measurement(pr.point, pr.photo, px, np.eye(2) * 0.09, "measured", predicted_px=pr.px,
                                   predicted_cov_px2=pr.cov_px2))
        return out

    monkeypatch.setattr(lc, "clip", clip)
    monkeypatch.setattr(cv, "extract_roof", lambda xyz, en, point_id=None: Vertex(verts[point_id]))
    monkeypatch.setattr(pc, "roof_edges", lambda *a, **k: [])
    monkeypatch.setattr(pc, "measure_photo", measure_photo)
    monkeypatch.setattr(lm, "read_image", lambda *a, **k: np.zeros((240, 320), np.uint8))
    return s, root, verts


def test_the_block_test_rejects_the_lone_gross_measurement_through_the_tie_points(measured, tmp_path):
    s, root, verts = measured
    out = tmp_path / "on"
    measure_control(root, out, gallery=False, lines="none", table=tmp_path / "ip_on.csv")
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv") if r["status"] in ("measured", "rejected")}
    assert len(dec) == sum(len(v) for v in MEASURED.values())
    assert [k for k, r in dec.items() if r["decision"] == "reject"] == [MOVED]
    reason = dec[MOVED]["reason"]
    assert reason.startswith("inconsistent with the block (") and " tie points on its photo and 8 other vertex " \
        "observations): " in reason, reason
    assert float(reason.split("): ")[1].split(" px")[0]) == pytest.approx(30.0, abs=1.5)
    info = json.loads((out / "measure_control.json").read_text())["block_check"]
    assert info["status"] == "ok" and info["rejected"] == 1 and info["ties_used"] > 100 and info["photos"] == 6
    # off: the lone gross measurement passes the per-photo and the multi-photo tests (its prediction's 20 px)
    copy = tmp_path / "copy"                    # the command writes image_points.csv: a copy of the survey
    shutil.copytree(root, copy)
    res = CliRunner().invoke(cli, ["measure-control", str(copy), "--no-block-check", "--no-gallery", "--lines",
                                   "none", "-o", str(tmp_path / "off"), "--json"])
    assert res.exit_code == 0, res.output
    off = {(r["point"], r["photo"]): r for r in _rows(tmp_path / "off" / "decisions.csv")}
    assert off[MOVED]["decision"] == "accept"
    assert json.loads((tmp_path / "off" / "measure_control.json").read_text())["block_check"] == {"status": "off"}


def test_lone_photo_reject_rejects_the_lone_measurements_before_the_block(measured, tmp_path):
    s, root, verts = measured
    out = tmp_path / "rej"
    measure_control(root, out, gallery=False, lines="none", table=tmp_path / "ip.csv", lone_photo="reject",
                    block_check=False)
    dec = {(r["point"], r["photo"]): r for r in _rows(out / "decisions.csv")}
    assert dec[MOVED]["decision"] == "reject"
    assert dec[MOVED]["reason"].startswith("alone on its photo: not tested against the photo's common shift")
    assert json.loads((out / "measure_control.json").read_text())["block_check"] == {"status": "off"}
    # a survey without tie points: the block test is not run (it would be the per-photo test again)
    copy = tmp_path / "no_ties"
    shutil.copytree(root, copy)
    ip = copy / "image_points.csv"
    ip.write_text("".join(line for line in ip.read_text().splitlines(True) if ",T" not in line))
    measure_control(copy, tmp_path / "nt", gallery=False, lines="none", table=tmp_path / "ip_nt.csv")
    info = json.loads((tmp_path / "nt" / "measure_control.json").read_text())["block_check"]
    assert info["status"] == "no tie points"
    assert {(r["point"], r["photo"]): r for r in _rows(tmp_path / "nt" / "decisions.csv")}[MOVED]["decision"] == \
        "accept"
    with pytest.raises(SurveyError, match="lone_photo must be keep or reject, got 'drop'"):
        measure_control(root, out, gallery=False, lines="none", table=tmp_path / "ip.csv", lone_photo="drop")
