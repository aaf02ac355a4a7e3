"""Brown and fisheye cameras through a survey folder (issue 27): camera.toml with ``model = "brown"``,
pixel measurements, ``lidarcat adjust --self-calibrate fx,fy,cx,cy,k1,k2,p1,p2``; and the located
refusal of fisheye rays beyond the image plane's reach."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.errors import SurveyError
from lidarcat.geometry.camera import Camera
from lidarcat.geometry.fisheye import FisheyeCamera
from lidarcat.survey.folder import MAX_IMAGE_PLANE_ANGLE_DEG, Survey

from test_models_block import BROWN_CERT, BROWN_TRUTH, PITCH_MM, SIGMA_PX, model_block


def _write(folder: Path, problem, cam: Camera, px: np.ndarray) -> Path:
    """A survey folder: the camera, photos.csv with GNSS positions (5 cm), pixel measurements."""
    folder.mkdir(parents=True)
    (folder / "survey.toml").write_text(
        '[survey]\nname = "brown"\ncrs = "local: synthetic"\ndefault_control = "gcp"\n[files]\n'
        'camera = "camera.toml"\nphotos = "photos.csv"\nimage_points = "image_points.csv"\n'
        'ground_points = "ground_points.csv"\ncontrol_sets = "control_sets.csv"\n[adjustment]\n'
        f'observations = "pixel"\nimage_sd_mm = {SIGMA_PX * PITCH_MM!r}\n', encoding="utf-8")
    ctrl = problem.point_ids[problem.constraint_point_index]
    with open(folder / "ground_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"])
        for pid, enh in zip(ctrl, problem.constraint_enh_m):
            w.writerow([pid, *map(repr, map(float, enh)), 0.05, 0.05, 0.05, "gps"])
    (folder / "control_sets.csv").write_text("set,point,role\n" + "".join(f"gcp,{pid},control\n" for pid in ctrl),
                                             encoding="utf-8")
    (folder / "camera.toml").write_text(cam.to_toml(), encoding="utf-8")
    with open(folder / "photos.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "camera", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg", "sd_X0", "sd_Y0",
                    "sd_Z0"])
        for pid, e in zip(problem.photo_ids, problem.eo_constraint_params):
            w.writerow([pid, cam.id, *map(repr, map(float, e[:3])), *map(repr, map(float, np.degrees(e[3:]))),
                        0.05, 0.05, 0.05])
    with open(folder / "image_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(["photo", "point", "col_px", "row_px"])
        for i, j, p in zip(problem.photo_index, problem.point_index, px):
            w.writerow([problem.photo_ids[i], problem.point_ids[j], repr(float(p[0])), repr(float(p[1]))])
    return folder


def test_camera_toml_of_a_brown_camera_round_trips_and_the_survey_observes_through_it(tmp_path):
    problem, cam, _ = model_block("brown", 0)
    px = cam.photo_to_pixel(problem.xy_mm)
    s = Survey.load(_write(tmp_path / "s", problem, cam, px))
    got = s.cameras["cam"]
    assert got.lens == BROWN_CERT and got.model == "brown" and got.focal_length_mm == cam.focal_length_mm
    obs = s.photo_observations()
    order = {(a, b): k for k, (a, b) in enumerate(zip(problem.photo_ids[problem.photo_index],
                                                        problem.point_ids[problem.point_index]))}
    k = np.array([order[(a, b)] for a, b in zip(obs.photo, obs.point)])
    assert np.abs(obs.xy_mm - problem.xy_mm[k]).max() < 1e-9
    # the pixel sd carried through the model, per axis: the certificate is a pinhole, so t x sd_px
    assert np.allclose(obs.sd_mm, cam.photo_sd(px[k], SIGMA_PX), rtol=1e-12)
    assert np.allclose(obs.sd_mm, SIGMA_PX * np.array([PITCH_MM, cam.pixel_size_y_mm]), rtol=1e-9)
    # with distortion it varies over the image: the true camera (k1 < 0) stretches the outer field
    sd = Camera.from_model(BROWN_TRUTH, pixel_size_mm=PITCH_MM).photo_sd(px[k], SIGMA_PX)
    assert sd.min() < 1.01 * SIGMA_PX * PITCH_MM and sd.max() > 1.04 * SIGMA_PX * PITCH_MM


def test_adjust_self_calibrates_a_brown_camera_from_a_survey_folder(tmp_path):
    problem, cam, delta = model_block("brown", 1)
    s = _write(tmp_path / "s", problem, cam, cam.photo_to_pixel(problem.xy_mm))
    r = CliRunner().invoke(cli, ["adjust", str(s), "--eo-constraints", "--self-calibrate",
                                 "fx,fy,cx,cy,k1,k2,p1,p2", "-o", str(tmp_path / "out"), "--json"])
    assert r.exit_code == 0, r.output
    ap = json.loads((tmp_path / "out" / "summary.json").read_text(encoding="utf-8"))["additional_parameters"]
    assert sorted(ap) == sorted(f"cam.{q}" for q in delta)
    for q, truth in delta.items():
        a = ap[f"cam.{q}"]
        assert abs(a["estimate"] - truth) < 3 * a["sd"], (q, a, truth)
        assert a["value"] == pytest.approx(getattr(BROWN_TRUTH, q), abs=3 * a["sd"])


def test_fisheye_rays_beyond_the_image_plane_limit_are_refused_with_file_line_and_count(tmp_path):
    lens = FisheyeCamera("fish", 2000, 2000, fx=500.0, fy=500.0, cx=999.5, cy=999.5)   # corners 162 deg
    cam = Camera.from_model(lens)
    folder = tmp_path / "f"
    folder.mkdir()
    (folder / "survey.toml").write_text(
        '[survey]\nname = "fish"\ncrs = "local: synthetic"\n[files]\ncamera = "camera.toml"\n'
        'photos = "photos.csv"\nimage_points = "image_points.csv"\n', encoding="utf-8")
    (folder / "camera.toml").write_text(cam.to_toml(), encoding="utf-8")
    (folder / "photos.csv").write_text("photo,camera\n1,fish\n2,fish\n", encoding="utf-8")
    # theta = r / fx: 0.5 rad (28.6 deg), 1.5 rad (85.9 deg), 1.7 rad (97.4 deg: behind the image plane)
    (folder / "image_points.csv").write_text(
        "photo,point,col_px,row_px\n1,a,1249.5,999.5\n2,a,1250.5,999.5\n1,b,1749.5,999.5\n2,b,1748.5,999.5\n"
        "1,c,1849.5,999.5\n2,c,1848.5,999.5\n", encoding="utf-8")
    s = Survey.load(folder)
    with pytest.raises(SurveyError) as ei:
        s.photo_observations("pixel")
    msg = str(ei.value)
    assert msg.startswith(f"{folder / 'image_points.csv'}:4: field 'col_px': photo '1': 2 measurement(s) of "
                          "camera 'fish' (fisheye) see rays more than 80 deg from the optical axis (this one "
                          "85.9 deg)"), msg
    assert MAX_IMAGE_PLANE_ANGLE_DEG == 80.0
    assert np.isnan(cam.pixel_to_photo([1849.5, 999.5])).all()           # beyond 90 deg: no image plane
