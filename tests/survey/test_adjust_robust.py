"""``lidarcat adjust`` on a survey of automatic matches with gross errors and the GNSS/INS orientation
as its only datum (no control set): the robust start names the planted gross observations; a
failed adjustment exits 1 with a located message and writes tables of one state; the datum
defect of too weak constraints is named."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.geometry.collinearity import project
from lidarcat.synthetic.matches import MATCH_PIXEL_MM, matched_block


def _write(folder: Path, p, sd_rows=None, obs_sd_mm=None) -> Path:
    """A survey folder of the problem: photos.csv with the observed EO and its sds (rows *sd_rows*
    only, default all), image_points.csv in corrected mm (with sd_x_mm, sd_y_mm = *obs_sd_mm* when
    given: what `lidarcat match` writes), no ground points, no control set."""
    folder.mkdir(parents=True)
    (folder / "survey.toml").write_text(
        '[survey]\nname = "matches"\ncrs = "local: synthetic"\n[files]\ncamera = "camera.toml"\n'
        'photos = "photos.csv"\nimage_points = "image_points.csv"\n[adjustment]\nobservations = "corrected"\n'
        f"image_sd_mm = {float(p.sd_mm[0, 0])}\n", encoding="utf-8")
    (folder / "camera.toml").write_text(
        f"[cam]\nfocal_length_mm = {float(p.focal_length_mm[0])}\nprincipal_point_x_mm = 0.0\n"
        "principal_point_y_mm = 0.0\nk1 = 0.0\nk2 = 0.0\nk3 = 0.0\np1 = 0.0\np2 = 0.0\nrefraction_eps45 = 0.0\n"
        f"pixel_size_x_mm = {MATCH_PIXEL_MM}\npixel_size_y_mm = {MATCH_PIXEL_MM}\ncolumns_px = 3600\n"
        "rows_px = 2400\n", encoding="utf-8")
    sd = np.asarray(p.eo_constraint_sd)[0]
    rows = range(p.n_photos) if sd_rows is None else sd_rows
    with open(folder / "photos.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "camera", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg", "sd_X0", "sd_Y0",
                    "sd_Z0", "sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"])
        for i, (pid, e) in enumerate(zip(p.photo_ids, p.eo_constraint_params)):
            sds = [*sd[:3], *np.degrees(sd[3:])] if i in rows else [""] * 6
            w.writerow([pid, "cam", *e[:3], *np.degrees(e[3:]), *sds])
    with open(folder / "image_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "point", "x_mm", "y_mm"] + (["sd_x_mm", "sd_y_mm"] if obs_sd_mm else []))
        for i, j, xy in zip(p.photo_index, p.point_index, p.xy_mm):
            w.writerow([p.photo_ids[i], p.point_ids[j], repr(float(xy[0])), repr(float(xy[1]))]
                       + ([obs_sd_mm] * 2 if obs_sd_mm else []))
    return folder


def _table(path: Path) -> list[dict[str, str]]:
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


@pytest.fixture(scope="module")
def block():
    return matched_block()


def test_adjust_names_the_gross_matches_with_gnss_ins_as_the_datum(tmp_path, block):
    p, truth, planted = block
    s = _write(tmp_path / "s", p)
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "--snooping", "remove", "-o",
                                 str(tmp_path / "out"), "--json"])
    assert r.exit_code in (0, 3), r.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text(encoding="utf-8"))
    assert summary["converged"] and summary["control_set"] == "none"
    named = {(b["photo"], b["point"]) for b in _table(tmp_path / "out" / "blunders.csv")}
    assert named == planted
    eop = {row["photo"]: row for row in _table(tmp_path / "out" / "eop.csv")}
    for i, pid in enumerate(p.photo_ids):
        got = np.array([float(eop[pid][k]) for k in ("X0", "Y0", "Z0")])
        sd = np.array([float(eop[pid][k]) for k in ("sd_X0", "sd_Y0", "sd_Z0")])
        assert np.all(np.abs(got - truth.true_eo[i, :3]) < 3 * sd)


def test_a_matched_survey_gets_variance_components_and_remove_by_default(tmp_path, block):
    """image_points.csv with sds of its own (as `lidarcat match` writes them), here declared twice the
    true 0.3 px: the default `lidarcat adjust` follows `lidarcat run` -- variance components and
    snooping remove -- names exactly the 17 gross observations, finds the tie factor (1/2)^2 and
    exits 0; --no-variance-components gives the plain report adjustment (the blunders kept)."""
    p, truth, planted = block
    s = _write(tmp_path / "s", p, obs_sd_mm=repr(0.6 * MATCH_PIXEL_MM))
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "-o", str(tmp_path / "out")])
    assert r.exit_code == 0, r.output
    assert "variance components estimated and the named observations removed" in r.output
    summary = json.loads((tmp_path / "out" / "summary.json").read_text(encoding="utf-8"))
    assert summary["snooping"]["mode"] == "remove" and summary["provenance"]["parameters"]["variance_components"]
    vc = {g["group"]: g for g in summary["variance_components"]["groups"]}
    assert vc["tie"]["estimated"] and vc["tie"]["factor"] == pytest.approx(0.25, abs=0.04)
    assert not vc["gnss"]["estimated"] and vc["gnss"]["factor"] == 1.0      # 6 photos: redundancy < 10
    assert {(b["photo"], b["point"]) for b in _table(tmp_path / "out" / "blunders.csv")} == planted
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "--no-variance-components", "-o",
                                 str(tmp_path / "plain")])
    assert r.exit_code == 3, r.output                     # report: the 17 blunders kept
    summary = json.loads((tmp_path / "plain" / "summary.json").read_text(encoding="utf-8"))
    assert summary["snooping"]["mode"] == "report" and "variance_components" not in summary
    assert summary["provenance"]["parameters"]["variance_components"] is False


def test_no_control_set_and_no_eo_constraints_says_what_to_do(tmp_path, block):
    s = _write(tmp_path / "s", block[0])
    r = CliRunner().invoke(cli, ["adjust", str(s), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2
    assert "no control set named and no [survey] default_control (available: none defined); photos.csv " \
           "carries sd_X0.. : adjust with the weighted GNSS/INS orientations alone as the datum " \
           "(--eo-constraints)" in r.output
    assert not (tmp_path / "out").exists()


def test_a_failed_adjustment_exits_1_with_a_located_message_and_tables_of_one_state(tmp_path, block):
    """Least squares alone (--snooping off) on the gross matches does not converge in 5 iterations; the
    message names the largest residuals; eop.csv, points.csv and residuals.csv describe one iterate."""
    p, _, _ = block
    s = _write(tmp_path / "s", p)
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "--snooping", "off", "--max-iter", "5",
                                 "-o", str(out)])
    assert r.exit_code == 1
    text = " ".join(r.output.split())
    assert re.search(r"Warning: the adjustment did not converge \(max_iterations\): maximum number of iterations "
                     r"reached before convergence; largest image residuals: point P\d+ on photo \d+ \([0-9.]+ sd\)",
                     text), text
    eop = {row["photo"]: row for row in _table(out / "eop.csv")}
    pts = {row["point"]: row for row in _table(out / "points.csv")}
    res = _table(out / "residuals.csv")
    photos = {row["photo"]: row for row in _table(s / "photos.csv")}
    ph = {pid: i for i, pid in enumerate(p.photo_ids)}
    eo = np.array([[float(eop[pid][k]) for k in ("X0", "Y0", "Z0")]
                   + list(np.radians([float(eop[pid][k]) for k in ("omega", "phi", "kappa")])) for pid in p.photo_ids])
    for row in res:
        if row["kind"] == "eo":
            d = float(eop[row["photo"]]["X0"]) - float(photos[row["photo"]]["X0"])
            assert abs(float(row["vE_m"]) - d) < 1e-6
    img = [row for row in res if row["kind"] == "image"]
    assert len(img) == len(p.photo_index)
    i = np.array([ph[row["photo"]] for row in img])
    X = np.array([[float(pts[row["point"]][k]) for k in ("E", "N", "h")] for row in img])
    xy = project(eo, X, np.asarray(p.focal_length_mm)[i], i)[0]
    obs = {(p.photo_ids[a], p.point_ids[b]): v for a, b, v in zip(p.photo_index, p.point_index, p.xy_mm)}
    v = np.array([[float(row["vx_mm"]), float(row["vy_mm"])] for row in img])
    o = np.array([obs[(row["photo"], row["point"])] for row in img])
    front = np.all(np.isfinite(xy), axis=1)
    np.testing.assert_allclose(v[front], (xy - o)[front], atol=2e-6)


def test_two_constrained_positions_leave_a_datum_defect_named(tmp_path, block):
    p = block[0]
    s = _write(tmp_path / "s", p, sd_rows=(0, 1))
    text = (s / "photos.csv").read_text(encoding="utf-8").splitlines()
    # positions only: drop the attitude sds of the two rows
    rows = [line.split(",") for line in text]
    for r_ in rows[1:3]:
        r_[11:14] = ["", "", ""]
    (s / "photos.csv").write_text("\n".join(",".join(r_) for r_ in rows) + "\n", encoding="utf-8")
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "-o", str(tmp_path / "out")])
    assert r.exit_code == 2
    assert ("the block has no control points and its GNSS/INS constraints leave a datum defect of 1 (rank "
            "deficiency: the rotation about the line through the 2 constrained photo positions (0001, 0002; ") \
        in " ".join(r.output.split())
    assert not (tmp_path / "out").exists()
