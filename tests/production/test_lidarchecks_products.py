"""``[products]`` of ``lidarcat run``: contour review/bands/3-D, swath image and the system calibration."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.lidar import PointCloud, write_points
from lidarcat.lidar.trajectory import Trajectory, write_sbet
from lidarcat.pipeline.plan import plan_pipeline
from lidarcat.pipeline.runner import run_stages
from lidarcat.production.lidarchecks import georeference
from lidarcat.survey.folder import Survey
from lidarcat.synthetic.strips import synthetic_strips

from ortho_scene import CAM  # noqa: I001  (tests/ortho_scene.py: a camera for the survey's photos)

CRS = "EPSG:31983"
OFF = np.array([680000.0, 7480000.0, 0.0])
BASE = (f'[survey]\nname = "strips"\ncrs = "{CRS}"\n\n[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\n'
        f'image_points = "image_points.csv"\nlidar = ["lidar/*.las"]\n\n[lidar]\ncrs = "{CRS}"\n')


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    root = tmp_path_factory.mktemp("strips_survey")
    s = synthetic_strips(1, spacing_m=3.0)
    (root / "camera.toml").write_text(CAM.to_toml())
    (root / "photos.csv").write_text("photo,camera\nA,small\nB,small\n")
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\nA,T1,600,400\nB,T1,610,390\n")
    (root / "lidar").mkdir()
    n = len(s.pulses)
    write_points(root / "lidar" / "strips.las", PointCloud(
        georeference(s.pulses) + OFF, {"gps_time": 2000 * 604800 + s.gps_time_s - 1e9,
                                       "point_source_id": s.pulses.strip + 1,
                                       "classification": np.full(n, 2, np.uint8)}, crs=CRS))
    t = s.trajectory
    write_sbet(root / "sbet.out", Trajectory(t.time_s, t.position_m + OFF, t.attitude_rad, crs=CRS))
    c = s.control_m + OFF
    (root / "runway.csv").write_text("id,E,N,H\n" + "".join(f"r{i},{x:.4f},{y:.4f},{z:.4f}\n"
                                                          for i, (x, y, z) in enumerate(c)))
    return root, s


def _work(root, tmp_path, toml):
    work = tmp_path / "s"
    work.mkdir()
    for p in root.iterdir():
        if p.name != "survey.toml":
            (work / p.name).symlink_to(p)
    (work / "survey.toml").write_text(toml)
    return work


@pytest.mark.parametrize("extra, message", [
    ("contours = false\ncontour_review = true\n", r"field 'contour_review': needs contours = true"),
    ("contour_profiles = 3\n", r"field 'contour_profiles': needs contour_review = true"),
    ('swath_quality_level = "QL9"\n', r"field 'swath_quality_level': 'QL9' is not one of 'QL0', 'QL1'"),
    ('calibration_control = "runway.csv"\n', r"field 'calibration_control': needs calibration_trajectory"),
    ("contour_sparse_edge_m = 0\n", r"field 'contour_sparse_edge_m': must be positive"),
])
def test_bad_keys_are_located(survey, tmp_path, extra, message):
    root, _ = survey
    with pytest.raises(SurveyError, match=r"survey\.toml:\d+: " + message):
        plan_pipeline(Survey.load(_work(root, tmp_path, BASE + "\n[products]\nground = false\n" + extra)))


def test_products_stage_writes_checks(survey, tmp_path):
    root, s = survey
    work = _work(root, tmp_path, BASE + "\n[products]\nground = false\ndtm = false\ndsm = false\n"
                                  "contour_review = true\ncontour_profiles = 1\ncontour_polygons = true\n"
                                  "contour_3d = true\nswath = true\nswath_cell_m = 5.0\n"
                                  'calibration_trajectory = "sbet.out"\ncalibration_control = "runway.csv"\n')
    sv = Survey.load(work)
    stage = next(st for st in plan_pipeline(sv) if st.name == "products")
    out = tmp_path / "out"
    rec = run_stages([stage], out, values={"survey": sv})[0]
    assert rec.status == "ran", rec.reason
    folder = out / "products"
    res = rec.result
    for f in ("contours.geojson", "contours_review.geojson", "contours_bands.geojson", "swath.tif", "swath.png",
              "swath.json", "calibration.json"):
        assert (folder / f).is_file(), f
        assert f in res["files"], f
    line = json.loads((folder / "contours.geojson").read_text())["features"][0]
    assert len(line["geometry"]["coordinates"][0]) == 3
    assert res["swath"]["swath"]["pass"] is False          # the raw strips carry the planted misalignment
    cal = json.loads((folder / "calibration.json").read_text())["calibration"]
    for name, true in vars(s.truth).items():
        assert abs(cal["parameters"][name] - true) < 3 * cal["sd"][name], name


@pytest.mark.parametrize("edited", ["sbet.out", "runway.csv"])
def test_editing_the_trajectory_or_control_reruns_the_stage(survey, tmp_path, edited):
    """The products stage's fingerprint holds the content of the calibration's SBET and control files:
    the same survey.toml with an edited file runs the stage again (its action is a stub here)."""
    import dataclasses
    import shutil

    root, _ = survey
    work = _work(root, tmp_path, BASE + "\n[products]\nground = false\ndtm = false\ndsm = false\n"
                                  "contours = false\n"
                                  'calibration_trajectory = "sbet.out"\ncalibration_control = "runway.csv"\n')
    calls = []
    stage = next(st for st in plan_pipeline(Survey.load(work)) if st.name == "products")
    stage = dataclasses.replace(stage, run=lambda ctx, tmp: calls.append(1) or {})
    out = tmp_path / "out"
    status = []
    for _ in range(2):
        status.append(run_stages([stage], out, values={"survey": Survey.load(work)})[0].status)
    target = work / edited
    target.unlink()                                          # a symlink to the shared fixture: copy, then edit
    shutil.copyfile(root / edited, target)
    data = bytearray(target.read_bytes())
    data[-9] ^= 0x01                                         # one bit of the last record / line
    target.write_bytes(bytes(data))
    status.append(run_stages([stage], out, values={"survey": Survey.load(work)})[0].status)
    assert status == ["ran", "reused", "ran"] and len(calls) == 2
