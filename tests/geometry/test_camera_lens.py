"""Brown and fisheye cameras as :class:`Camera` (``Camera.from_model``, ``model = "brown"`` in camera.toml):
the pinhole equivalence, the exact geometry through every Camera method, the TOML round trip and the
located errors of bad tables."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.geometry.brown import BrownCamera
from lidarcat.geometry.camera import Camera
from lidarcat.geometry.conversion import image_plane_observations
from lidarcat.geometry.fisheye import FisheyeCamera
from lidarcat.survey.cameras import load_cameras

BROWN = BrownCamera("b", 4000, 3000, fx=3000.0, fy=2990.0, cx=2010.0, cy=1490.0, k1=-0.1, k2=0.05, k4=0.01,
                    p1=1e-3, p2=-5e-4, skew=0.5)
FISHEYE = FisheyeCamera("f", 1000, 800, fx=300.0, fy=301.0, cx=500.0, cy=400.0, k1=0.02, k2=-0.001)


def test_a_pinhole_brown_camera_is_the_frame_camera_of_the_exact_conversion():
    lens = BrownCamera("p", 3000, 2000, fx=4000.0, fy=4000.0, cx=1510.0, cy=990.0)
    cam = Camera.from_model(lens, pixel_size_mm=0.008)
    frame = Camera("p", 32.0, (1510.0 - 1499.5) * 0.008, -(990.0 - 999.5) * 0.008, 0, 0, 0, 0, 0, 0, 0.008, 0.008,
                   3000, 2000)
    px = lens.grid_px(9)
    assert np.abs(cam.pixel_to_photo(px) - frame.pixel_to_photo(px)).max() < 1e-12
    assert cam.focal_length_mm == 32.0 and cam.model == "brown" and cam.lens is lens


@pytest.mark.parametrize("lens", [BROWN, FISHEYE], ids=["brown", "fisheye"])
def test_camera_methods_follow_the_model_exactly(lens):
    cam = Camera.from_model(lens)
    px = lens.grid_px(21)
    xy = cam.pixel_to_photo(px)
    with np.errstate(invalid="ignore"):
        ok = np.hypot(*xy.T) < 5.67 * cam.focal_length_mm           # within 80 deg of the axis (the survey's limit)
    assert ok.sum() >= 290
    n, _, dn_dpx = image_plane_observations(lens, px[ok])
    c = cam.focal_length_mm
    assert np.abs(xy[ok] - c * n * [1, -1]).max() < 1e-12                    # x_fotc = c (X/Z, -Y/Z)
    assert np.abs(cam.photo_to_pixel(xy[ok]) - px[ok]).max() < 1e-9          # round trip
    j = cam.pixel_to_photo_jacobian(px[ok])
    assert np.abs(j - c * np.array([1, -1])[None, :, None] * dn_dpx).max() < 1e-12 * c
    h = 1e-4
    fd = np.stack([(cam.pixel_to_photo(px[ok] + [h, 0]) - cam.pixel_to_photo(px[ok] - [h, 0])) / (2 * h),
                   (cam.pixel_to_photo(px[ok] + [0, h]) - cam.pixel_to_photo(px[ok] - [0, h])) / (2 * h)], axis=2)
    assert np.abs(j - fd).max() < 1e-7 * np.abs(j).max()
    d = cam.distortion_corrections(cam.pixel_to_fot(px[ok]))                 # the whole correction, radial columns
    assert np.abs(cam.pixel_to_fot(px[ok]) - np.column_stack([d["dx_ra"], d["dy_ra"]]) - xy[ok]).max() < 1e-12
    assert not np.any(d["dx_des"]) and not np.any(d["dy_ref"])


def test_fisheye_pixels_beyond_90_deg_have_no_photo_coordinate():
    cam = Camera.from_model(FISHEYE)
    xy = cam.pixel_to_photo(FISHEYE.grid_px(11))
    theta = np.degrees(np.arccos(FISHEYE.unproject(FISHEYE.grid_px(11))[:, 2]))
    assert np.array_equal(np.isnan(xy).any(axis=1), theta >= 90 - 1e-6)
    assert (theta >= 90).sum() == 34


def test_camera_toml_round_trip_of_brown_and_fisheye(tmp_path):
    b = Camera.from_model(BROWN, pixel_size_mm=0.004, source="OpenSfM export", sd={"sd_fx": 2.0, "sd_k1": 1e-3})
    f = Camera.from_model(FISHEYE)
    (tmp_path / "c.toml").write_text(b.to_toml() + "\n" + f.to_toml(), encoding="utf-8")
    got = load_cameras(tmp_path / "c.toml")
    assert got["b"].lens == BROWN and got["f"].lens == FISHEYE
    assert got["b"].source == "OpenSfM export" and dict(got["b"].sd) == {"sd_fx": 2.0, "sd_k1": 1e-3}
    assert got["b"].pixel_size_x_mm == 0.004 and got["b"].focal_length_mm == b.focal_length_mm
    assert got["b"].to_toml() == b.to_toml()
    assert b.to_toml().splitlines()[:3] == ["[b]", 'model = "brown"', 'source = "OpenSfM export"']


GOOD = 'width_px = 1000\nheight_px = 1000\nfx = 500.0\nfy = 500.0\ncx = 500.0\ncy = 500.0\n'


@pytest.mark.parametrize("table, message", [
    ('model = "pinhole"\n' + GOOD,
     ":2: field 'model': camera [x]: unknown camera model 'pinhole'; known: frame, brown, fisheye"),
    ('model = "fisheye"\n' + GOOD.replace("fx = 500.0\nfy = 500.0", "fx = 100.0\nfy = 100.0"),
     ":5: field 'fx': camera [x]: the image corner (-0.5, -0.5) px lies beyond 180 deg from the optical axis "
     "(theta_d = 7.078 rad, the model reaches 3.142 rad at 180 deg); check fx, fy (px per radian) and k1..k4"),
    ('model = "brown"\n' + GOOD + "k1 = -0.5\n",
     ":9: field 'k1': camera [x]: radial distortion k1 = -0.5, k2 = 0, k3 = 0, k4 = 0 folds over inside the image: "
     "the distorted radius stops increasing at r = 0.8165 (normalised, 39.23 deg from the axis) before it reaches "
     "the image corner (1.416); no ray can be found for the corner pixels"),
    (GOOD, ":2: field 'width_px': camera [x]: a camera with width_px, height_px, fx, fy, cx, cy needs model = "
           "\"brown\" or \"fisheye\" (a frame camera has focal_length_mm, ...)"),
    ('model = "brown"\n' + GOOD.replace("fy = 500.0\n", ""), ":1: field 'fy': camera [x]: missing (required "
                                                               "for a brown camera)"),
    ('model = "fisheye"\n' + GOOD + "skew = 1.0\n", ":9: field 'skew': camera [x]: unknown key of a fisheye camera; "
     "allowed: model, source, width_px, height_px, pixel_size_mm, fx, fy, cx, cy, k1, k2, k3, k4, sd_fx, sd_fy, "
     "sd_cx, sd_cy, sd_k1, sd_k2, sd_k3, sd_k4, readout_time_ms"),
    ('model = "brown"\n' + GOOD + "pixel_size_mm = 0.0\n",
     ":9: field 'pixel_size_mm': camera [x]: must be a positive number, got 0.0"),
])
def test_bad_camera_tables_are_refused_with_file_line_and_field(tmp_path, table, message):
    path = tmp_path / "bad.toml"
    path.write_text("[x]\n" + table, encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        load_cameras(path)
    assert str(ei.value) == f"{path}{message}"


def test_a_free_text_model_still_describes_a_frame_camera(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text('[k]\nmodel = "Kodak DCS Pro 14n"\nfocal_length_mm = 35.0\nprincipal_point_x_mm = 0.0\n'
                    'principal_point_y_mm = 0.0\nk1 = 0.0\nk2 = 0.0\nk3 = 0.0\np1 = 0.0\np2 = 0.0\n'
                    'refraction_eps45 = 0.0\npixel_size_x_mm = 0.008\npixel_size_y_mm = 0.008\ncolumns_px = 4500\n'
                    'rows_px = 3000\n', encoding="utf-8")
    cam = load_cameras(path)["k"]
    assert cam.lens is None and cam.model == "Kodak DCS Pro 14n"


def test_a_lens_camera_keeps_its_rolling_shutter_readout(tmp_path):
    """A drone's Brown camera carries ``readout_time_ms`` (the rolling shutter) like a frame camera,
    through the camera table and back."""
    from lidarcat.survey.cameras import load_camera

    (tmp_path / "camera.toml").write_text(
        '[d]\nmodel = "brown"\nwidth_px = 4000\nheight_px = 3000\nfx = 3000.0\nfy = 3000.0\n'
        'cx = 1999.5\ncy = 1499.5\nreadout_time_ms = 30.0\n')
    cam = load_camera(tmp_path / "camera.toml")
    assert cam.lens is not None and cam.readout_time_ms == 30.0
    assert cam.to_dict()["readout_time_ms"] == 30.0
    (tmp_path / "again.toml").write_text(cam.to_toml())
    assert load_camera(tmp_path / "again.toml").readout_time_ms == 30.0
