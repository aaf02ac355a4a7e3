"""``lidarcat measure-control``: LiDAR vertices measured into the survey, decisions fed back, bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.stages.measure_control import DECISION_FIELDS, dsm_of_points, planned
from lidarcat.survey.folder import Survey
from lidarcat.synthetic.aerial import aerial_survey


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    root = tmp_path_factory.mktemp("mc") / "s"
    s = aerial_survey(root, n_strips=1, photos_per_strip=4, gsd_m=0.1, image_size_px=(1200, 900),
                      lidar_density_m2=10, lidar_noise_m=0.03, n_gps_points=4, seed=0)
    sc = s.scene
    verts = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    gp = root / "ground_points.csv"
    lines = [f"L{i + 1:03d},{v[0]:.3f},{v[1]:.3f},{v[2]:.3f},0.02,0.02,0.02,lidar" for i, v in enumerate(verts)]
    gp.write_text(gp.read_text().rstrip("\n") + "\n" + "\n".join(lines) + "\n")
    return s, root, {f"L{i + 1:03d}": v for i, v in enumerate(verts)}


@pytest.mark.slow
def test_measure_control_writes_observations_decisions_and_gallery(survey):
    s, root, truth = survey
    before = Survey.load(root)
    assert planned(before) is None
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    folder = root / "out" / "measure_control"
    dec = _rows(folder / "decisions.csv")
    assert list(dec[0]) == DECISION_FIELDS
    assert len(dec) == len(truth) * len(s.photo_ids)           # one row per vertex and photo
    acc = [r for r in dec if r["decision"] == "accept"]
    assert len(acc) == out["accepted"] >= 3
    assert all(r["reason"] for r in dec if r["decision"] == "reject")
    per_point = {}
    for r in acc:
        per_point[r["point"]] = per_point.get(r["point"], 0) + 1
    # a vertex accepted on one photo is kept (good control; a set where it is not control leaves it out)
    assert all(per_point[v] == sum(r["point"] == v and r["decision"] == "accept" for r in dec) for v in per_point)
    # the roof edges: one row per edge and photo tried, every written one in line_control.csv, every other with
    # its reason; survey.toml names the file; no edge both in a point and as a line on one photo
    ldec = _rows(folder / "line_decisions.csv")
    assert ldec and all(r["reason"] for r in ldec if r["status"] != "written")
    # (a point located along one edge is the exception: its two edges are written beside it, as they carry
    # the across-line part the point's one-sd-for-both-axes row cannot)
    along = {(a["photo"], a["point"]) for a in acc if a["reason"].startswith("located along one edge")}
    assert not any(r["status"] == "written" and (r["photo"], r["point"]) in {(a["photo"], a["point"]) for a in acc}
                   - along for r in ldec)
    assert all(sum(r["status"] == "written" and (r["photo"], r["point"]) == pair for r in ldec) == 2
               for pair in along)
    written = {(r["line"], r["photo"]) for r in ldec if r["status"] == "written"}
    assert len(written) == out["line_observations"]
    if written:
        lc = _rows(root / "line_control.csv")
        assert {(r["line"], r["photo"]) for r in lc if r["photo"]} == written
        assert all(r["cov_m2"] and r["point"] for r in lc if not r["photo"])
        assert Survey.load(root).files["line_control"] == root / "line_control.csv"
    for r in acc:   # against the true vertex's true projection
        d = np.array([float(r["col_px"]), float(r["row_px"])]) - s.project(r["photo"], truth[r["point"]][None])[0]
        assert np.hypot(*d) < 3.0, (r, d)
    assert (folder / "gallery_01.png").stat().st_size > 1000
    after = Survey.load(root)
    ip = after.image_points
    got = {(str(a), str(b)) for a, b in zip(ip.photo, ip.point) if str(b).startswith("L")}
    assert got == {(r["photo"], r["point"]) for r in acc}
    # the sds written: the measured pixel sds times the pixel size
    k = [i for i, p in enumerate(ip.point) if str(p).startswith("L")][0]
    r = next(r for r in acc if (r["photo"], r["point"]) == (str(ip.photo[k]), str(ip.point[k])))
    assert ip.sd_mm[k, 0] == pytest.approx(float(r["sd_col_px"]) * s.camera.pixel_size_x_mm, rel=1e-3)
    assert len(ip.point) == len(before.image_points.point) + len(acc)   # the GPS rows kept
    assert planned(after) is None   # vertices not measured on any photo: a run would try again

    # the user rejects one and accepts another by hand: fed back, exactly those rows
    edited = folder / "edited.csv"
    rows = [dict(r) for r in dec]
    rows[[i for i, r in enumerate(rows) if r["decision"] == "accept"][0]]["decision"] = "reject"
    hand = next(i for i, r in enumerate(rows) if r["decision"] == "reject" and r["status"] != "not_visible"
                and (r["photo"], r["point"]) not in got)
    rows[hand].update(decision="accept", col_px="100.5", row_px="200.25", sd_col_px="0.5", sd_row_px="0.5")
    with open(edited, "w", newline="") as fh:
        w = csv.DictWriter(fh, DECISION_FIELDS)
        w.writeheader()
        w.writerows(rows)
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(edited)])
    assert res.exit_code == 0, res.output
    ip = Survey.load(root).image_points
    got2 = {(str(a), str(b)): ip.pixel_px[i] for i, (a, b) in enumerate(zip(ip.photo, ip.point))
            if str(b).startswith("L")}
    assert set(got2) == {(r["photo"], r["point"]) for r in rows if r["decision"] == "accept"}
    np.testing.assert_allclose(got2[(rows[hand]["photo"], rows[hand]["point"])], [100.5, 200.25])


@pytest.mark.slow
def test_bad_decisions_file_and_no_vertices_leave_image_points_alone(survey, tmp_path):
    s, root, _ = survey
    ip_file = root / "image_points.csv"
    old = ip_file.read_bytes()
    bad = tmp_path / "bad.csv"
    bad.write_text("photo,point,decision,col_px,row_px\n" + f"{s.photo_ids[0]},L001,maybe,1,2\n")
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(bad)])
    assert res.exit_code == 2 and "bad.csv:2: decision must be accept or reject, got 'maybe'" in res.output
    assert ip_file.read_bytes() == old
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--points", "G9"])
    assert res.exit_code == 2 and "no ground point 'G9'" in res.output
    assert ip_file.read_bytes() == old


def test_bad_input_is_a_located_error_on_the_thesis_block(tmp_path):
    """The fast case of the command (the cases above are slow): a point the survey does not have and a bad
    decisions file are one located error each, and image_points.csv is left alone."""
    import shutil

    from lidarcat.survey.folder import thesis_survey_path

    root = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), root)
    old = (root / "image_points.csv").read_bytes()
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--points", "G9"])
    assert res.exit_code == 2 and "ground_points.csv: no ground point 'G9' (asked for by points)" in res.output
    bad = tmp_path / "bad.csv"
    bad.write_text("photo,point,decision,col_px,row_px\nx,L001,maybe,1,2\n")
    res = CliRunner().invoke(cli, ["measure-control", str(root), "--decisions", str(bad)])
    assert res.exit_code == 2 and "bad.csv:2: decision must be accept or reject, got 'maybe'" in res.output
    assert (root / "image_points.csv").read_bytes() == old


def test_dsm_of_points_is_the_highest_point_per_cell():
    xyz = np.array([[0.1, 0.1, 5.0], [0.2, 0.3, 7.0], [1.2, 0.1, 3.0]])
    dsm = dsm_of_points(xyz, cell_m=0.5)
    h = dsm(np.array([0.15, 1.3, 0.7, 50.0]), np.array([0.2, 0.2, 0.2, 0.0]))
    assert h[0] == 7.0 and h[1] == 3.0 and np.isnan(h[2]) and np.isnan(h[3])


@pytest.mark.slow
def test_run_plans_measure_control_before_the_adjustments_and_they_read_its_table(survey, tmp_path):
    """``lidarcat run``: the stage comes after match and before camera and the adjustments; run through the
    runner (without the match), its table feeds the next stage's survey."""
    from lidarcat.pipeline.plan import plan_pipeline
    from lidarcat.pipeline.runner import run_stages

    import shutil

    s, root0, _ = survey
    root = tmp_path / "s"   # a copy without LiDAR observations (an earlier test may have written some)
    shutil.copytree(root0, root, ignore=shutil.ignore_patterns("out"))
    ip = root / "image_points.csv"
    ip.write_text("".join(line for line in ip.read_text().splitlines(keepends=True) if ",L0" not in line))
    toml = root / "survey.toml"     # nor the review an earlier test fed back (control_decisions.csv)
    toml.write_text("".join(t for t in toml.read_text().splitlines(keepends=True)
                            if not t.startswith("control_decisions")))
    sv = Survey.load(root)
    assert not any(str(p).startswith("L") for p in sv.image_points.point)
    names = [st.name for st in plan_pipeline(sv)]
    assert "measure_control" in names
    k = names.index("measure_control")
    assert names.index("match") < k < names.index("camera")
    assert all(k < i for i, n in enumerate(names) if n.startswith("adjust"))
    stages = {st.name: st for st in plan_pipeline(sv)}
    import dataclasses

    mc = dataclasses.replace(stages["measure_control"], requires=())   # no matching in this test: its table is the survey's
    recs = run_stages([mc, stages["camera"]], tmp_path / "out", values={"survey": sv})
    assert [r.status for r in recs] == ["ran", "ran"], [r.reason for r in recs]
    table = tmp_path / "out" / "measure_control" / "image_points.csv"
    rows = _rows(table)
    assert len(rows) == len(sv.image_points.point) + recs[0].result["accepted"]   # observed pairs kept as they were
    assert recs[0].result["accepted"] >= 1
    # the camera stage corrected the measured table's observations, not the survey's
    assert recs[1].result["n_points"] == len(rows)
