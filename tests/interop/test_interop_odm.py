"""OpenDroneMap gcp_list.txt (real odm_data_bellus and OpenSfM Berlin files) and geo.txt
(synthetic: no licensed real file exists), merged into survey folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from lidarcat.errors import FormatError
from lidarcat.interop.block import apply_ground_control, apply_orientations
from lidarcat.interop.odm import read_gcp_list, read_geo_txt
from lidarcat.interop.rotations import ypr_to_opk
from lidarcat.survey.folder import Survey

D = Path(__file__).parents[1] / "data" / "interop"


def test_bellus_gcp_list_utm():
    g = read_gcp_list(D / "odm" / "bellus_gcp_list.txt")
    assert g.crs == "EPSG:32617"
    assert g.point.tolist() == ["gcp1", "gcp2", "gcp3", "gcp4"]
    np.testing.assert_allclose(g.enh_m[0], [441024.15704911412, 4564001.8747091573, 345.1689312], rtol=0, atol=0)
    assert g.obs_photo.tolist()[0] == "IMG_1356_RGB.jpg"
    np.testing.assert_allclose(g.obs_px[0], [2648, 2147])


def test_berlin_gcp_list_wgs84_projected():
    with pytest.raises(FormatError, match=r"berlin_gcp_list.txt:1: field 'CRS': WGS 84 is geographic"):
        read_gcp_list(D / "opensfm" / "berlin_gcp_list.txt")
    g = read_gcp_list(D / "opensfm" / "berlin_gcp_list.txt", crs="EPSG:32633", height_system="ellipsoidal")
    assert len(g.obs_point) == 26 and len(g.point) == 10  # rows with the same coordinates are one GCP
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32633", always_xy=True).transform(13.4007407457, 52.519134104)
    np.testing.assert_allclose(g.enh_m[0], [e, n, 12.0792090446], rtol=0, atol=1e-9)


def _thesis_geo(tmp_path: Path) -> Path:
    p = tmp_path / "geo.txt"
    p.write_text("EPSG:29192\n# image x y z yaw pitch roll horiz vert\n"
                 "1 677100.0 7183500.0 2100.0 90.0 1.0 -2.0 0.5 1.0\n"
                 "2.tif 677500.0 7183500.0 2101.0\n")
    return p


def test_geo_txt_into_thesis_survey(tmp_path):
    o = read_geo_txt(_thesis_geo(tmp_path))
    assert o.photo.tolist() == ["1", "2.tif"]
    np.testing.assert_allclose(o.eo[0, 3:], ypr_to_opk(np.radians([90.0, 1.0, -2.0])), atol=0)
    np.testing.assert_allclose(o.eo_sd[0, :3], [0.5, 0.5, 1.0])
    assert np.isnan(o.eo[1, 3:]).all()
    out = apply_orientations(None, o, tmp_path / "s")
    s = Survey.load(out)
    np.testing.assert_allclose(s.photo("1").position_m, [677100.0, 7183500.0, 2100.0])
    np.testing.assert_allclose(s.photo("1").attitude_deg, np.degrees(o.eo[0, 3:]), atol=1e-12)
    np.testing.assert_allclose(s.photo("2").position_m, [677500.0, 7183500.0, 2101.0])  # '2.tif' -> '2'
    assert s.photo("2").attitude_deg is None and s.photo("3").position_m is None
    assert len(s.image_points) == len(Survey.load().image_points)


def test_gcp_list_into_thesis_survey(tmp_path):
    p = tmp_path / "gcp_list.txt"
    p.write_text("EPSG:29192\n677300.0 7183400.0 910.0 1500.0 2200.0 1 G1\n"
                 "677300.0 7183400.0 910.0 1400.0 2210.0 2.jpg G1\n677300.0 7183400.0 910.0 1 1 99.jpg G1\n")
    g = read_gcp_list(p, height_system="orthometric")
    out = apply_ground_control(None, g, tmp_path / "s", sd_m=(0.1, 0.1, 0.2), set_name="odm")
    s = Survey.load(out)
    assert "G1" in s.ground_points and s.control_set("odm").control.tolist() == ["G1"]
    rows = s.image_points.point == "G1"
    assert sorted(s.image_points.photo[rows].tolist()) == ["1", "2"]  # 99.jpg is no photo of the survey
    cam = s.cameras["dcs14n"]
    i = int(np.flatnonzero(rows & (s.image_points.photo == "1"))[0])
    np.testing.assert_allclose(s.image_points.xy_mm[i], cam.pixel_to_photo([1500.0, 2200.0]), atol=1e-12)
    assert set(s.control_sets) == {"gps", "lidar", "odm"}
    with pytest.raises(FormatError, match="already holds a survey.toml"):
        apply_ground_control(None, g, out)


@pytest.mark.parametrize("text,expect", [
    ("EPSG:99999999\n", ":1: field 'CRS': 'EPSG:99999999' is not a CRS pyproj knows"),
    ("WGS84 UTM 61N\n", ":1: field 'CRS': UTM zone 61 is not in 1..60"),
    ("EPSG:32617\n1 2 3 4 5\n", ":2: field 'image_name': missing: the line has 5 field(s)"),
    ("EPSG:32617\n1 2 3 4 y a.jpg\n", ":2: field 'im_y': 'y' is not a number"),
    ("EPSG:32617\n1 2 3 4 5 a.jpg P\n1 2 4 4 5 b.jpg P\n", ":3: field 'geo_x': GCP 'P' has other coordinates on line 2"),
])
def test_gcp_list_errors(tmp_path, text, expect):
    p = tmp_path / "gcp_list.txt"
    p.write_text(text)
    with pytest.raises(FormatError) as ei:
        read_gcp_list(p)
    assert str(ei.value).startswith(str(p)) and expect in str(ei.value)


def test_geo_txt_errors(tmp_path):
    p = tmp_path / "geo.txt"
    p.write_text("EPSG:32617\na.jpg 1 2 3 4 5\n")
    with pytest.raises(FormatError, match=r"geo.txt:2: field 'roll': 6 fields"):
        read_geo_txt(p)
    p.write_text("EPSG:32617\na.jpg 1 2 3 4 5 6 0 1\n")
    with pytest.raises(FormatError, match=r"geo.txt:2: field 'horiz_acc': accuracy must be positive"):
        read_geo_txt(p)


def test_gcp_measured_twice_on_one_photo(tmp_path):
    """Fuzz cases 898/964: a point measured twice on one photo (here '2' and '2.jpg' are one photo)
    is refused with the file line, the photo and the point (the survey would refuse it on load)."""
    p = tmp_path / "gcp_list.txt"
    p.write_text("EPSG:29192\n677300.0 7183400.0 910.0 1500.0 2200.0 1 G1\n"
                 "677300.0 7183400.0 910.0 1400.0 2210.0 2 G1\n"
                 "677300.0 7183400.0 910.0 1401.0 2211.0 2.jpg G1\n")
    with pytest.raises(FormatError) as ei:
        apply_ground_control(None, read_gcp_list(p), tmp_path / "s")
    assert str(ei.value) == (f"{p}:4: point 'G1' is measured twice on photo '2' (also on line 3); keep one "
                             f"measurement per photo and point, then import again")
    assert not (tmp_path / "s").exists()


def test_gcp_measured_again_on_a_survey_photo(tmp_path):
    """A measurement of a (photo, point) that the survey measures already is refused, located (a
    GroundControl whose measurements name a tie point of the survey)."""
    from lidarcat.interop.block import GroundControl

    s = Survey.load()
    photo, point = str(s.image_points.photo[0]), str(s.image_points.point[0])
    g = GroundControl(["N1"], [[677300.0, 7183400.0, 910.0]], "EPSG:29192", "orthometric",
                      ["N1", point], ["1", photo], [[1500.0, 2200.0], [10.0, 10.0]], "g.txt (test)", [2, 3])
    with pytest.raises(FormatError) as ei:
        apply_ground_control(None, g, tmp_path / "s")
    assert str(ei.value) == (f"g.txt:3: point {point!r} is already measured on photo {photo!r} in "
                             f"{s.files['image_points']}; remove one of the two measurements, then import again")
