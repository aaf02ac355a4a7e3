"""GNSS/IMU text: omega/phi/kappa or roll/pitch/yaw (conversion proved on the physical meaning
of the angles), as weighted constraints of a re-adjustment of the thesis block; kapture GNSS."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from lidarcat.survey import adjust_survey
from lidarcat.errors import FormatError
from lidarcat.interop.block import apply_orientations, block_from_survey
from lidarcat.interop.gnss import read_gnss, read_kapture_gnss
from lidarcat.interop.rotations import opk_to_matrix, ypr_to_opk
from lidarcat.survey.folder import Survey

DATA = Path(__file__).parents[1] / "data"


def test_yaw_pitch_roll_meaning():
    """Camera y = the flight direction, camera x = the right wing (camera->world = M^T)."""
    def axes(yaw, pitch, roll):
        m_t = opk_to_matrix(ypr_to_opk(np.radians([yaw, pitch, roll]))).T
        return m_t[:, 0], m_t[:, 1], m_t[:, 2]
    x, y, z = axes(30.0, 0.0, 0.0)
    np.testing.assert_allclose(y, [np.sin(np.radians(30)), np.cos(np.radians(30)), 0], atol=1e-15)
    np.testing.assert_allclose(z, [0, 0, 1], atol=1e-15)  # looking down: camera z (back) is up
    x, y, z = axes(0.0, 0.0, 5.0)  # right wing down
    assert x[2] == pytest.approx(-np.sin(np.radians(5)), abs=1e-15)
    x, y, z = axes(0.0, 4.0, 0.0)  # nose up
    assert y[2] == pytest.approx(np.sin(np.radians(4)), abs=1e-15)


def test_gnss_constraints_into_thesis(tmp_path):
    adj = block_from_survey(None, DATA / "report")
    p = tmp_path / "gnss.txt"
    lines = ["photo;E;N;h;omega;phi;kappa;sd_E;sd_N;sd_h;sd_omega;sd_phi;sd_kappa"]
    for pid, e in zip(adj.photo_ids.tolist(), adj.eo):
        lines.append(";".join([pid, *(repr(float(v)) for v in e[:3]),
                               *(repr(float(v)) for v in np.degrees(e[3:])), "0.1", "0.1", "0.15", "0.01", "0.01", "0.02"]))
    p.write_text("\n".join(lines) + "\n")
    o = read_gnss(p, file_crs="EPSG:29192", height_system="orthometric")
    np.testing.assert_allclose(o.eo, adj.eo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.degrees(o.eo_sd[0, 3:]), [0.01, 0.01, 0.02], atol=1e-15)
    out = apply_orientations(None, o, tmp_path / "s")
    s = Survey.load(out)
    np.testing.assert_allclose(s.photo("4").sd_position_m, [0.1, 0.1, 0.15])
    res, _ = adjust_survey(s, outdir=tmp_path / "adj", eo_constraints=True)
    assert res.success and res.eo_constraint_residuals is not None
    assert res.eo_constraint_residuals.shape == (6, 6)


def test_roll_pitch_yaw_file(tmp_path):
    p = tmp_path / "imu.csv"
    p.write_text("image,X,Y,Z,roll,pitch,yaw,sd_roll\n1,677100,7183500,2100,1.0,-2.0,95.0,0.5\n")
    o = read_gnss(p, file_crs="EPSG:29192")
    np.testing.assert_allclose(o.eo[0, 3:], ypr_to_opk(np.radians([95.0, -2.0, 1.0])), atol=0)
    assert "roll/pitch/yaw -> omega/phi/kappa" in o.source
    np.testing.assert_allclose(np.degrees(o.eo_sd[0, 3:]), [0.5, 0.5, 0.5])


def test_kapture_records_gnss():
    o = read_kapture_gnss(DATA / "interop" / "colmap" / "kapture_maupertuis" / "kapture_records_gnss.txt",
                          crs="EPSG:32631")
    assert o.photo.tolist() == ["1", "2", "3", "4"]
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True).transform(5.793155, 45.216783)
    np.testing.assert_allclose(o.eo[:, :3], [[e, n, 280.0]] * 4, rtol=0, atol=1e-9)
    assert np.isnan(o.eo[:, 3:]).all() and (o.eo_sd[:, :3] == 10.0).all()


@pytest.mark.parametrize("text,expect", [
    ("photo,E,N\n", ":1: field 'h': no position column for h"),
    ("photo,E,N,h,omega,phi\n", ":1: field 'kappa': missing: omega, phi, kappa come together"),
    ("photo,E,N,h\n1,2,3\n", ":2: 3 fields, expected 4"),
    ("photo,E,N,h,sd_h\n1,2,3,4,0\n", ":2: field 'sd_h': must be positive, got 0.0"),
    ("photo,E,N,h\n1,2,3,4\n1,2,3,4\n", ":3: field 'photo': photo '1' already on line 2"),
    ("photo,E,N,h\n1,2,x,4\n", ":2: field 'N': 'x' is not a number"),
])
def test_located_errors(tmp_path, text, expect):
    p = tmp_path / "g.csv"
    p.write_text(text)
    with pytest.raises(FormatError) as ei:
        read_gnss(p, file_crs="EPSG:29192")
    assert str(ei.value).startswith(str(p)) and expect in str(ei.value)


def test_crs_mismatch_is_refused(tmp_path):
    p = tmp_path / "g.csv"
    p.write_text("photo,E,N,h\n1,500000,5000000,100\n")
    o = read_gnss(p, file_crs="EPSG:32722")
    with pytest.raises(FormatError, match="coordinates are in EPSG:32722, the survey .* in EPSG:29192"):
        apply_orientations(None, o, tmp_path / "s")
    assert not (tmp_path / "s").exists()
