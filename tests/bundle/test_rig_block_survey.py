"""Rigs from the survey side (issue 27): the rig TOML and photos.csv's ``rig_exposure``, with
located errors; the rig file's poses are the bundle's (thesis frame) through rig_sensor_poses."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle.rig import rig_sensor_poses, rotation_log
from lidarcat.errors import SurveyError
from lidarcat.geometry.camera import Camera
from lidarcat.survey import Photo
from lidarcat.survey.rigs import load_rigs, rig_exposures
from lidarcat.synthetic.drone import rig_block

D = np.diag([1.0, -1.0, -1.0])
CAM = Camera("nadir", 12.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.004, 0.004, 4000, 3000)
CAMERAS = {c: dataclasses.replace(CAM, id=c) for c in ("nadir", "forward", "backward", "spare")}


def _rig_text(block) -> str:
    """The rig block's true relative poses as a rig file (COLMAP sensor_from_rig = D Q D, D d)."""
    lines = ['[oblique]', 'sensors = ["nadir", "forward", "backward"]']
    for k, name in enumerate(block.sensor_names[1:], start=1):
        r = D @ block.true_rotation[k] @ D
        rv = np.degrees(rotation_log(r)[0])
        t = D @ block.true_translation_m[k]
        lines += [f"[oblique.{name}]", f"rotation_deg = [{', '.join(repr(float(v)) for v in rv)}]",
                  f"translation_m = [{', '.join(repr(float(v)) for v in t)}]"]
    return "\n".join(lines) + "\n"


def test_a_rig_file_gives_the_bundle_its_relative_poses(tmp_path):
    b = rig_block(0, n_strips=2, exposures_per_strip=3, n_points=200)
    path = tmp_path / "rigs.toml"
    path.write_text(_rig_text(b), encoding="utf-8")
    rigs = load_rigs(path, CAMERAS)
    assert list(rigs) == ["oblique"] and [c.id for c in rigs["oblique"].cameras] == ["nadir", "forward", "backward"]
    q, d = rig_sensor_poses(rigs["oblique"])
    np.testing.assert_allclose(q, b.true_rotation, atol=1e-12)
    np.testing.assert_allclose(d, b.true_translation_m, atol=1e-12)


@pytest.mark.parametrize("text, message", [
    ('[r]\nsensors = ["nadir", "fwd"]\n', r"rigs\.toml:2: field 'sensors': rig 'r': camera 'fwd' is not defined"),
    ('[r]\nsensors = ["nadir", "forward"]\n',
     r"rigs\.toml:1: rig 'r': sensor 'forward' has no pose table \[r\.forward\] with rotation_deg and translation_m"),
    ('[r]\nsensors = ["nadir", "forward"]\n[r.forward]\nrotation_deg = [1, 2]\ntranslation_m = [0, 0, 0]\n',
     r"rigs\.toml:4: field 'rotation_deg': \[r\.forward\] rotation_deg must be three finite numbers, got \[1, 2\]"),
    ('[r]\nsensors = ["nadir", "forward"]\n[r.forward]\nrotation_deg = [0, 0, 0]\ntranslation = [0, 0, 0]\n',
     r"rigs\.toml:5: field 'translation': \[r\.forward\]: unknown key 'translation'; allowed: rotation_deg, "
     r"translation_m"),
    ('[r]\nsensors = ["nadir", "forward"]\n[r.nadir]\nrotation_deg = [0, 0, 0]\ntranslation_m = [0, 0, 0]\n',
     r"rigs\.toml:3: field 'nadir': rig 'r': 'nadir' is the rig frame \(its first sensor\) and has no pose table"),
    ('[r]\nsensors = ["nadir", "forward"]\nlever = 3\n',
     r"rigs\.toml:3: field 'lever': rig 'r': unknown key 'lever'; allowed: sensors and a pose table per sensor"),
    ('[r]\nsensors = ["nadir", "nadir"]\n', r"rigs\.toml:2: field 'sensors': rig 'r': camera 'nadir' is named twice"),
    ('[r]\nsensors = []\n', r"rigs\.toml:2: field 'sensors': rig 'r' needs sensors = \[camera ids"),
])
def test_bad_rig_files_are_refused_with_their_line(tmp_path, text, message):
    path = tmp_path / "rigs.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError, match=message):
        load_rigs(path, CAMERAS)


def test_rig_exposures_of_photos_csv(tmp_path):
    path = tmp_path / "rigs.toml"
    path.write_text('[r]\nsensors = ["nadir", "forward"]\n[r.forward]\nrotation_deg = [30, 0, 0]\n'
                    'translation_m = [0, -0.1, 0]\n', encoding="utf-8")
    rigs = load_rigs(path, CAMERAS)
    photos = [Photo("a", "nadir", line=2, rig_exposure="E1"), Photo("b", "forward", line=3, rig_exposure="E1"),
              Photo("c", "nadir", line=4, rig_exposure="E2"), Photo("d", "spare", line=5)]
    exposure, sensor, rig_of = rig_exposures(photos, rigs, tmp_path / "photos.csv")
    assert exposure == ["E1", "E1", "E2", "d"] and sensor.tolist() == [0, 1, 0, 0] and rig_of == {"E1": "r", "E2": "r"}
    twice = photos[:2] + [Photo("c", "forward", line=4, rig_exposure="E1")]
    with pytest.raises(SurveyError, match=r"photos\.csv:4: field 'rig_exposure': photo 'c': rig exposure 'E1' "
                                          r"already has photo 'b' of sensor 'forward'"):
        rig_exposures(twice, rigs, tmp_path / "photos.csv")
    stray = [Photo("s", "spare", line=7, rig_exposure="E3")]
    with pytest.raises(SurveyError, match=r"photos\.csv:7: field 'rig_exposure': photo 's' of rig exposure 'E3' is "
                                          r"of camera 'spare', a sensor of no rig"):
        rig_exposures(stray, rigs, tmp_path / "photos.csv")


def _survey(folder, rigs_text: str | None, exposures=("E1", "E1", "E2", "E2")):
    """A small survey of two rig exposures (nadir + forward camera), pixels on both."""
    folder.mkdir(parents=True)
    files = 'camera = "camera.toml"\nphotos = "photos.csv"\nimage_points = "image_points.csv"\n'
    if rigs_text is not None:
        files += 'rigs = "rigs.toml"\n'
        (folder / "rigs.toml").write_text(rigs_text, encoding="utf-8")
    (folder / "survey.toml").write_text(f'[survey]\nname = "rig"\ncrs = "local: synthetic"\n[files]\n{files}',
                                        encoding="utf-8")
    (folder / "camera.toml").write_text(CAMERAS["nadir"].to_toml() + dataclasses.replace(CAM, id="forward").to_toml(),
                                        encoding="utf-8")
    rows = ["photo,camera,rig_exposure"] + [f"p{i},{cam},{ex}" for i, (cam, ex) in
                                            enumerate(zip(("nadir", "forward", "nadir", "forward"), exposures))]
    (folder / "photos.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    pts = ["photo,point,col_px,row_px"] + [f"p{i},q{j},{1000 + 100 * j},{800 + 50 * i}" for i in range(4)
                                          for j in range(4)]
    (folder / "image_points.csv").write_text("\n".join(pts) + "\n", encoding="utf-8")
    return folder


RIG = '[r]\nsensors = ["nadir", "forward"]\n[r.forward]\nrotation_deg = [30, 0, 0]\ntranslation_m = [0, -0.1, 0]\n'


def test_a_survey_with_rig_exposures_loads_and_is_checked(tmp_path):
    from lidarcat.survey import Survey
    from lidarcat.survey.rigs import survey_rigs

    s = Survey.load(_survey(tmp_path / "ok", RIG))
    rigs, exposure, sensor, rig_of = survey_rigs(s)
    assert list(rigs) == ["r"] and exposure == ["E1", "E1", "E2", "E2"] and sensor.tolist() == [0, 1, 0, 1]
    with pytest.raises(SurveyError, match=r"photos\.csv:2: field 'rig_exposure': photo 'p0' is in rig exposure 'E1' "
                                          r"but survey\.toml \[files\] names no rigs file"):
        Survey.load(_survey(tmp_path / "norig", None))
    with pytest.raises(SurveyError, match=r"photos\.csv:4: field 'rig_exposure': photo 'p2': rig exposure 'E1' "
                                          r"already has photo 'p0' of sensor 'nadir'"):
        Survey.load(_survey(tmp_path / "twice", RIG, exposures=("E1", "E1", "E1", "E2")))
    with pytest.raises(SurveyError, match=r"rigs\.toml:2: field 'sensors': rig 'r': camera 'side' is not defined"):
        Survey.load(_survey(tmp_path / "cam", RIG.replace('"forward"]', '"forward", "side"]')))
