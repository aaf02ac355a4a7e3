"""Metashape project XML (the real EasyIDP wheat_tanashi chunk and frame): calibration,
camera transforms through the chunk's ECEF transform into UTM, markers and their measurements."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from lidarcat.errors import FormatError
from lidarcat.interop._distortion import distort, undistort
from lidarcat.interop.block import reprojection_residuals_px, write_survey
from lidarcat.interop.metashape import read_metashape
from lidarcat.survey.folder import Survey

D = Path(__file__).parents[1] / "data" / "interop" / "metashape"
CHUNK = D / "easyidp_wheat_tanashi_chunk.doc.xml"
FRAME = D / "easyidp_wheat_tanashi_frame.doc.xml"


@pytest.fixture(scope="module")
def block():
    return read_metashape(CHUNK, FRAME)


def test_calibration_and_counts(block):
    assert block.crs == "EPSG:32654" and block.height_system.startswith("ellipsoidal")
    assert len(block.photo_ids) == 138 and np.isfinite(block.eo).all()
    assert block.ground_ids.tolist() == ["7", "13.1", "X", "17", "13.2", "1"]
    assert len(block.obs_photo) == 23
    cam = block.cameras["0"]
    assert (cam.columns_px, cam.rows_px) == (4608, 3456)
    assert cam.focal_length_mm == pytest.approx(4785.3046873759595 * 0.0037557825786083223, rel=1e-15)
    m = block.source_models["0"]
    assert m["cx"] == pytest.approx(2304 + 48.037918055786299) and m["cy"] == pytest.approx(1728 - 73.278107967250861)


def test_markers_reproject_to_their_measurements(block):
    """Marker references (WGS84 lon/lat/h -> UTM 54N) projected through the imported orientations
    and the Metashape calibration land within a few pixels of the 23 pinned measurements
    (at 30 m flying height a pixel is ~8 mm): transform direction, chunk scale, ENU/grid rotation,
    p1/p2 order and the corner pixel origin are right (a wrong one costs hundreds of pixels)."""
    r = reprojection_residuals_px(block)
    assert np.abs(r).max() < 12.0
    assert np.sqrt(np.mean(r**2)) < 6.0


def test_camera_centres_agree_with_their_gnss_reference(block):
    text = CHUNK.read_text()
    refs = re.findall(r'<camera id="\d+" sensor_id="0" component_id="0" label="(DJI_\d+)">.*?'
                      r'<reference x="([\d.]+)" y="([\d.]+)"', text, flags=re.S)
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32654", always_xy=True)
    idx = block.photo_index()
    d = np.array([np.hypot(*(np.array(to_utm.transform(float(x), float(y))) - block.eo[idx[lab], :2]))
                  for lab, x, y in refs])
    assert len(d) == 138
    assert np.median(d) < 10.0  # the references' own sxy = 10 m


def test_metashape_distortion_formula():
    """p1 multiplies (r^2 + 2 x^2) in Metashape (OpenCV's p2); the inverse is exact."""
    p = {"k1": -0.0086, "k2": -0.0149, "k3": 0.0216, "k4": 0.001, "p1": 0.0021, "p2": 0.0023}
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    rad = 1 + p["k1"] * r2 + p["k2"] * r2**2 + p["k3"] * r2**3 + p["k4"] * r2**4
    want = [x * rad + p["p1"] * (r2 + 2 * x * x) + 2 * p["p2"] * x * y,
            y * rad + p["p2"] * (r2 + 2 * y * y) + 2 * p["p1"] * x * y]
    np.testing.assert_allclose(distort([[x, y]], p, metashape=True)[0], want, rtol=0, atol=1e-16)
    np.testing.assert_allclose(undistort(distort([[x, y]], p, metashape=True), p, metashape=True)[0],
                               [x, y], rtol=0, atol=1e-14)


def test_survey_written(tmp_path, block):
    s = Survey.load(write_survey(block, tmp_path / "s"))
    assert len(s.photos) == 138 and s.control_set("imported").control.tolist() == block.ground_ids.tolist()
    assert s.height_system == "ellipsoidal (WGS84)"


@pytest.mark.parametrize("old,new,expect", [
    ("<f>4785.3046873759595</f>", "<f>abc</f>", "field 'f': 'abc' is not a list of numbers"),
    ("<f>4785.3046873759595</f>", "<f>4785.3</g>", "invalid XML: mismatched tag"),
    ('<resolution width="4608" height="3456"/>\n        <f>', '<resolution width="4608"/>\n        <f>',
     "field 'height': missing attribute of <resolution>"),
])
def test_located_errors(tmp_path, old, new, expect):
    text = CHUNK.read_text()
    assert old in text
    bad = text.replace(old, new, 1)
    line = text[:text.index(old)].count("\n") + 1
    p = tmp_path / "doc.xml"
    p.write_text(bad)
    with pytest.raises(FormatError) as ei:
        read_metashape(p)
    assert str(ei.value).startswith(f"{p}:{line}") or str(ei.value).startswith(f"{p}:{line + 1}")
    assert expect in str(ei.value)
