"""`lidarcat adjust` on a rig survey (issue 27): the photos become exposures, eop.csv holds every
photo's pose (body o relative pose) with propagated sds, rig_poses.csv the relative poses."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.bundle.rig import photo_poses, rotation_log
from lidarcat.cli.main import cli
from lidarcat.geometry.camera import Camera
from lidarcat.synthetic.drone import DRONE_CAMERA, rig_block

D = np.diag([1.0, -1.0, -1.0])
SUFFIX = ("N", "F", "B")


def _table(path: Path) -> list[dict[str, str]]:
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _rig_toml(block, rotation, translation, estimate: str | None, poses: bool = True) -> str:
    lines = ["[oblique]", 'sensors = ["nadir", "forward", "backward"]']
    if estimate is not None:
        lines.append(f"estimate = {estimate}")
    for k, name in enumerate(block.sensor_names[1:] if poses else (), start=1):
        rv = np.degrees(rotation_log(D @ rotation[k] @ D)[0])
        t = D @ translation[k]
        lines += [f"[oblique.{name}]", f"rotation_deg = [{', '.join(repr(float(v)) for v in rv)}]",
                  f"translation_m = [{', '.join(repr(float(v)) for v in t)}]"]
    return "\n".join(lines) + "\n"


def _write_rig_survey(folder: Path, block, *, estimate: str | None = "true", given: str = "start",
                      imu_deg: float | None = None) -> dict:
    """The rig block as a survey folder: one photo per exposure and sensor, corrected photo
    coordinates, GNSS on the nadir photos, the block's control points; returns photo -> (exposure, sensor).
    *imu_deg*: every photo gets its true position (3 cm noise) and attitude (*imu_deg* noise) and the rig
    file no pose tables (the relative poses estimated from nothing but photos.csv)."""
    p = block.problem
    rays = p.rays
    folder.mkdir(parents=True)
    pitch = DRONE_CAMERA["pitch_mm"]
    cam = Camera("nadir", DRONE_CAMERA["focal_px"] * pitch, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, pitch, pitch,
                 DRONE_CAMERA["width_px"], DRONE_CAMERA["height_px"])
    (folder / "camera.toml").write_text("".join(dataclasses.replace(cam, id=n).to_toml() for n in block.sensor_names),
                                        encoding="utf-8")
    rot, trans = ((rays.sensor_rotation, rays.sensor_translation_m) if given == "start"
                  else (block.true_rotation, block.true_translation_m))
    (folder / "rigs.toml").write_text(_rig_toml(block, rot, trans, estimate, poses=imu_deg is None), encoding="utf-8")
    rng = np.random.default_rng(11)
    truth = photo_poses(block.true_eo, block.true_rotation, block.true_translation_m,
                        np.repeat(np.arange(len(p.photo_ids)), 3), np.tile(np.arange(3), len(p.photo_ids)))
    photos = ["photo,camera,rig_exposure,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0"]
    which = {}
    for e, eid in enumerate(p.photo_ids):
        for s, name in enumerate(block.sensor_names):
            pid = f"{eid}{SUFFIX[s]}"
            which[pid] = (e, s)
            if imu_deg is not None:
                x0 = [float(v) for v in truth[3 * e + s, :3] + rng.normal(0, 0.03, 3)]
                ang = [float(v) for v in np.degrees(truth[3 * e + s, 3:]) + rng.normal(0, imu_deg, 3)]
                sd = "0.03,0.03,0.03" if s == 0 else ",,"
                photos.append(f"{pid},{name},{eid},{x0[0]!r},{x0[1]!r},{x0[2]!r},{ang[0]!r},{ang[1]!r},{ang[2]!r},{sd}")
            elif s == 0:
                x0 = p.eo_constraint_params[e, :3]
                ang = np.degrees(p.initial_eo[e, 3:])
                photos.append(f"{pid},{name},{eid},{float(x0[0])!r},{float(x0[1])!r},{float(x0[2])!r},{ang[0]},{ang[1]},{ang[2]},"
                              f"0.03,0.03,0.03")
            else:
                photos.append(f"{pid},{name},{eid},,,,,,,,,")
    (folder / "photos.csv").write_text("\n".join(photos) + "\n", encoding="utf-8")
    obs = ["photo,point,x_mm,y_mm"]
    for e, s, j, xy in zip(p.photo_index, rays.sensor_index, p.point_index, p.xy_mm):
        obs.append(f"{p.photo_ids[e]}{SUFFIX[s]},{p.point_ids[j]},{float(xy[0])!r},{float(xy[1])!r}")
    (folder / "image_points.csv").write_text("\n".join(obs) + "\n", encoding="utf-8")
    gp = ["point,E,N,h,sd_E,sd_N,sd_h,source"] + [
        f"{p.point_ids[j]},{float(x[0])!r},{float(x[1])!r},{float(x[2])!r},0.01,0.01,0.01,gcp"
        for j, x in zip(p.constraint_point_index, p.constraint_enh_m)]
    (folder / "ground_points.csv").write_text("\n".join(gp) + "\n", encoding="utf-8")
    cs = ["set,point,role,sd_E,sd_N,sd_h"] + [f"gcp,{p.point_ids[j]},control,,," for j in p.constraint_point_index]
    (folder / "control_sets.csv").write_text("\n".join(cs) + "\n", encoding="utf-8")
    (folder / "survey.toml").write_text(
        '[survey]\nname = "rig"\ncrs = "local: synthetic"\ndefault_control = "gcp"\n[files]\n'
        'camera = "camera.toml"\nphotos = "photos.csv"\nimage_points = "image_points.csv"\n'
        'ground_points = "ground_points.csv"\ncontrol_sets = "control_sets.csv"\nrigs = "rigs.toml"\n'
        f'[adjustment]\nobservations = "corrected"\nimage_sd_mm = {0.5 * pitch!r}\nvariance_factor = "a_priori"\n',
        encoding="utf-8")
    return which


def _photo_z(block, which, out: Path) -> np.ndarray:
    """Standardised errors (P, 6) of eop.csv's photo poses against the truth."""
    rows = _table(out / "eop.csv")
    ex = np.array([which[r["photo"]][0] for r in rows])
    se = np.array([which[r["photo"]][1] for r in rows])
    truth = photo_poses(block.true_eo, block.true_rotation, block.true_translation_m, ex, se)
    got = np.array([[float(r[c]) for c in ("X0", "Y0", "Z0", "omega", "phi", "kappa")] for r in rows])
    sd = np.array([[float(r[c]) for c in ("sd_X0", "sd_Y0", "sd_Z0", "sd_omega", "sd_phi", "sd_kappa")]
                   for r in rows])
    err = got - np.concatenate([truth[:, :3], np.degrees(truth[:, 3:])], axis=1)
    err[:, 3:] = (err[:, 3:] + 180) % 360 - 180
    return err / sd


def test_adjust_a_rig_survey_estimates_the_relative_poses(tmp_path):
    b = rig_block(0, n_strips=2, exposures_per_strip=4, n_points=800)
    which = _write_rig_survey(tmp_path / "s", b)
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(out), "--eo-constraints", "--json"])
    assert r.exit_code == 0, r.output
    z = _photo_z(b, which, out)
    assert z.shape == (3 * len(b.problem.photo_ids), 6)
    assert np.abs(z).max() < 3 and 0.5 < np.sqrt(np.mean(z**2)) < 1.5
    poses = {row["sensor"]: row for row in _table(out / "rig_poses.csv")}
    assert list(poses) == ["nadir", "forward", "backward"] and poses["nadir"]["estimated"] == "False"
    for k, name in enumerate(b.sensor_names[1:], start=1):
        row = poses[name]
        assert row["estimated"] == "True"
        rv = np.radians([float(row[f"rotation_{c}_deg"]) for c in "xyz"])
        from lidarcat.geometry.rolling import rodrigues

        r_est = rodrigues(rv)[0]
        dr = np.degrees(rotation_log(r_est @ (D @ b.true_rotation[k] @ D).T)[0])
        dt = np.array([float(row[f"translation_{c}_m"]) for c in "xyz"]) - D @ b.true_translation_m[k]
        sd = np.array([float(row[f"sd_rotation_{c}_deg"]) for c in "xyz"] +
                      [float(row[f"sd_translation_{c}_m"]) for c in "xyz"])
        assert np.all(np.abs(np.r_[dr, dt]) < 3 * sd), (name, np.r_[dr, dt] / sd)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["rig"]["exposures"] == len(b.problem.photo_ids) and summary["rig"]["photos"] == len(which)
    bodies = {row["exposure"]: row for row in _table(out / "rig_exposures.csv")}
    assert list(bodies) == list(b.problem.photo_ids)
    for row in _table(out / "eop.csv"):       # a nadir photo is its exposure's body, pose and sds alike
        if row["photo"].endswith("N"):
            body = bodies[row["photo"][:-1]]
            assert [float(row[c]) for c in row if c != "photo"] == pytest.approx(
                [float(body[c]) for c in body if c != "exposure"], rel=1e-9, abs=1e-12)
    image_rows = [row for row in _table(out / "residuals.csv") if row["kind"] == "image"]
    # every image row names its photo (exposure + sensor), the exposure's label nowhere
    assert {row["photo"] for row in image_rows} == set(which)
    assert 0.98 * len(b.problem.xy_mm) < len(image_rows) <= len(b.problem.xy_mm)


def test_adjust_a_rig_survey_with_given_relative_poses(tmp_path):
    b = rig_block(1, n_strips=2, exposures_per_strip=3, n_points=500)
    which = _write_rig_survey(tmp_path / "s", b, estimate=None, given="true")
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(out), "--eo-constraints", "--json"])
    assert r.exit_code == 0, r.output
    z = _photo_z(b, which, out)
    # 6 exposures: the photos of one exposure share its errors, so the rms is of few independent values
    assert np.abs(z).max() < 3 and np.sqrt(np.mean(z**2)) < 1.5
    poses = _table(out / "rig_poses.csv")
    assert [row["estimated"] for row in poses] == ["False"] * 3 and poses[1]["sd_rotation_x_deg"] == ""


@pytest.mark.parametrize("edit, message", [
    (lambda f: f.joinpath("photos.csv").write_text(
        f.joinpath("photos.csv").read_text().replace(",forward,X001,", ",forward,,", 1)),
     r"photos\.csv:3: field 'rig_exposure': photo 'X001F' of sensor 'forward' of rig 'oblique' has no rig exposure"),
    (lambda f: f.joinpath("rigs.toml").write_text(
        f.joinpath("rigs.toml").read_text().replace("estimate = true", 'estimate = ["nadir"]')),
     r"rigs\.toml:3: field 'estimate': rig 'oblique': 'nadir' is the rig frame \(its first sensor\); its pose is "
     r"the exposure's and is not estimated"),
])
def test_a_bad_rig_survey_is_refused_with_its_location(tmp_path, edit, message):
    b = rig_block(0, n_strips=2, exposures_per_strip=2, n_points=200)
    _write_rig_survey(tmp_path / "s", b)
    edit(tmp_path / "s")
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(tmp_path / "out"), "--eo-constraints"])
    assert r.exit_code == 2
    import re

    assert re.search(message, r.output), r.output
    assert not (tmp_path / "out").exists()


def test_photo_pose_covariance_is_the_propagated_joint_covariance():
    """rig_photo_poses' first-order covariance of a sensor's photo against the sample covariance of
    photos composed from draws of (body, relative-pose corrections) with a known joint covariance."""
    from lidarcat.geometry.collinearity import rotation_matrix
    from lidarcat.geometry.rolling import rodrigues
    from lidarcat.survey.rigs import RigPlan, rig_photo_poses

    rng = np.random.default_rng(3)
    q0 = np.stack([np.eye(3), np.reshape(rotation_matrix(np.array([0.5, 0.02, -0.01])), (3, 3))])
    d0 = np.array([[0.0, 0.0, 0.0], [0.02, 0.12, -0.03]])
    theta = np.array([1e-3, -2e-3, 5e-4, 0.01, -0.02, 0.005])           # the estimate about q0, d0
    q = np.stack([q0[0], rodrigues(theta[:3])[0] @ q0[1]])
    d = d0 + np.r_[np.zeros(3), theta[3:]].reshape(2, 3)
    body = np.array([[400000.0, 5500000.0, 100.0, 0.01, -0.02, 3.0]])
    a = rng.normal(size=(12, 12)) * np.r_[np.full(3, 0.02), np.full(3, 2e-4), np.full(3, 1e-4), np.full(3, 3e-3)]
    joint = a.T @ a / 12 + np.diag(np.r_[np.full(3, 1e-4), np.full(3, 1e-8), np.full(3, 1e-9), np.full(3, 1e-6)])
    plan = RigPlan("r", ("n", "f"), ("pn", "pf"), ("E",), np.array([0, 0]), np.array([0, 1]), (1,), q0, d0)
    eo, cov = rig_photo_poses(plan, body, joint[None, :6, :6], q, d, params=theta, params_cov=joint[6:, 6:],
                              cross_cov=joint[None, :6, 6:], start_rotation=q0)
    np.testing.assert_allclose(cov[0], joint[:6, :6], rtol=1e-9)        # the rig frame's photo is the body
    draws = rng.multivariate_normal(np.zeros(12), joint, 20000)
    th = theta + draws[:, 6:]
    k = np.arange(len(draws))
    sample = photo_poses(body + draws[:, :6], rodrigues(th[:, :3]) @ q0[1], d0[1] + th[:, 3:], k, k) - eo[1]
    sample[:, 3:] = (sample[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    emp = np.cov(sample.T)
    sd = np.sqrt(np.diag(cov[1]))
    # 20000 draws: the sample sds within 2 % (5 sigma of their sampling error), correlations within 0.04
    np.testing.assert_allclose(np.sqrt(np.diag(emp)), sd, rtol=0.02)
    np.testing.assert_allclose(emp / np.outer(sd, sd), cov[1] / np.outer(sd, sd), atol=0.04)


def test_self_calibration_of_a_rig_survey_is_refused(tmp_path):
    b = rig_block(0, n_strips=2, exposures_per_strip=2, n_points=200)
    _write_rig_survey(tmp_path / "s", b)
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(tmp_path / "out"), "--self-calibrate", "c"])
    assert r.exit_code == 2
    assert "rigs.toml: additional parameters (self-calibration, frame offsets) in a rig survey are not supported" in r.output


def test_relative_poses_without_pose_tables_start_from_photos_csv(tmp_path):
    """estimate = true and no pose tables: the start from photos.csv's positions and attitudes (0.3 deg,
    3 cm off per photo) converges to the truth, relative poses within 3 sd."""
    b = rig_block(2, n_strips=2, exposures_per_strip=3, n_points=500)
    which = _write_rig_survey(tmp_path / "s", b, imu_deg=0.3)
    assert "[oblique.forward]" not in (tmp_path / "s" / "rigs.toml").read_text()
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(out), "--eo-constraints", "--json"])
    assert r.exit_code == 0, r.output
    z = _photo_z(b, which, out)
    assert np.abs(z).max() < 3
    from lidarcat.geometry.rolling import rodrigues

    for row in _table(out / "rig_poses.csv")[1:]:
        k = b.sensor_names.index(row["sensor"])
        r_est = rodrigues(np.radians([float(row[f"rotation_{c}_deg"]) for c in "xyz"]))[0]
        dr = np.degrees(rotation_log(r_est @ (D @ b.true_rotation[k] @ D).T)[0])
        dt = np.array([float(row[f"translation_{c}_m"]) for c in "xyz"]) - D @ b.true_translation_m[k]
        sd = np.array([float(row[f"sd_rotation_{c}_deg"]) for c in "xyz"] +
                      [float(row[f"sd_translation_{c}_m"]) for c in "xyz"])
        assert np.all(np.abs(np.r_[dr, dt]) < 3 * sd), (row["sensor"], np.r_[dr, dt] / sd)


def test_an_unposed_sensor_needs_attitudes_in_photos_csv(tmp_path):
    b = rig_block(0, n_strips=2, exposures_per_strip=2, n_points=200)
    _write_rig_survey(tmp_path / "s", b)
    rigs = tmp_path / "s" / "rigs.toml"
    rigs.write_text(rigs.read_text().split("[oblique.forward]")[0], encoding="utf-8")
    r = CliRunner().invoke(cli, ["adjust", str(tmp_path / "s"), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    assert ("rigs.toml: rig 'oblique': sensor 'forward' has no pose table and no exposure gives both its photo and "
            "the rig frame's photo with a position and attitude in photos.csv") in r.output
