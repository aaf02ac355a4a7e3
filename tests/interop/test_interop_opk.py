"""Omega-phi-kappa text (IGN Borea .OPK with its camera, .app and .mes files; Pix4D layout):
conventions proved against the formulas each program documents, thesis round trip, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidarcat.errors import FormatError
from lidarcat.interop.block import block_from_survey
from lidarcat.interop.opk import read_borea, read_borea_camera, read_borea_points, read_opk, write_opk
from lidarcat.interop.rotations import FLIP, opk_to_matrix, opk_to_world_to_cv

D = Path(__file__).parents[1] / "data" / "interop" / "opk"
OPK = D / "borea_23FD1305_alt_test.OPK"
THESIS_ADJ = Path(__file__).parents[1] / "data" / "report"


def test_read_borea_opk():
    o = read_opk(OPK)
    assert len(o) == 7
    assert o.photo[0] == "23FD1305x00026_01306"
    np.testing.assert_allclose(o.eo[0, :3], [814975.925, 6283986.148, 1771.280], rtol=0, atol=5e-4)
    np.testing.assert_allclose(np.degrees(o.eo[0, 3:]), [-0.245070686036, -0.069409621323, 0.836320989726],
                               rtol=0, atol=5e-13)
    assert set(o.camera.tolist()) == {"UCE-M3-f120-s06"}


def test_angle_conventions_of_borea_and_pix4d():
    """Borea: R = Rx(pi) from_euler('xyz', -[O, P, K]) world->camera (y down); Pix4D/orthority:
    camera->world R = Rx(w) Ry(p) Rz(k) (active).  Both are lidarcat's M up to F / transposition."""
    o = read_opk(OPK)
    for a in o.eo[:, 3:]:
        borea = Rotation.from_euler("x", np.pi).as_matrix() @ Rotation.from_euler("xyz", -a).as_matrix()
        np.testing.assert_allclose(opk_to_world_to_cv(a), borea, rtol=0, atol=1e-15)
        pix4d_c2w = Rotation.from_euler("XYZ", a).as_matrix()
        np.testing.assert_allclose(opk_to_matrix(a), pix4d_c2w.T, rtol=0, atol=1e-15)
        np.testing.assert_allclose(FLIP @ opk_to_matrix(a), borea, rtol=0, atol=1e-15)


def test_borea_block_projects_control_in_the_measured_direction():
    """The 7 GCP measurements of the real IGN block: projected with the OPK angles, each GCP
    lies in the measured direction from the principal point (to 0.1 degree).  The lengths are
    2.9 % longer than measured for every ray: Borea's Z 'alt' values are not the heights the
    simple collinearity needs (Borea corrects for the linear alteration of Lambert-93)."""
    blk = read_borea(OPK, [D / "borea_Camera1.txt", D / "borea_Camera2.txt"],
                     points=D / "borea_GCP_test.app", measurements=[D / "borea_terrain_test.mes"])
    assert len(blk.ground_ids) == 3 and len(blk.obs_photo) == 7
    cam = blk.cameras["UCE-M3-f120-s06"]
    idx = blk.photo_index()
    ratios, angles = [], []
    for ph, pt, px in zip(blk.obs_photo.tolist(), blk.obs_point.tolist(), blk.obs_px):
        e = blk.eo[idx[ph]]
        v = opk_to_world_to_cv(e[3:]) @ (blk.ground_m[blk.ground_ids.tolist().index(pt)] - e[:3])
        proj = 30975.0 * v[:2] / v[2]
        meas = px - [13210.0, 8502.0]
        angles.append(np.degrees(np.arctan2(meas[0] * proj[1] - meas[1] * proj[0], meas @ proj)))
        ratios.append(np.linalg.norm(proj) / np.linalg.norm(meas))
    assert np.abs(angles).max() < 0.1
    assert np.ptp(ratios) < 0.005 and 1.02 < np.mean(ratios) < 1.04
    assert cam.focal_length_mm == pytest.approx(30.975, abs=1e-12)


def test_borea_companion_files():
    ids, xyz, kind = read_borea_points(D / "borea_GCP_test.app")
    assert ids.tolist() == ["1003", "1005", "1006"] and kind.tolist() == ["13", "3", "13"]
    np.testing.assert_allclose(xyz[1], [833670.940, 6281965.400, 52.630])
    cam2 = read_borea_camera(D / "borea_Camera2.txt", pixel_size_mm=0.004)
    assert cam2.id == "UCE-M3-f120-s07" and (cam2.columns_px, cam2.rows_px) == (26460, 17004)
    blk = read_borea(OPK, [D / "borea_Camera1.txt"], measurements=[D / "borea_liaisons_test.mes",
                                                                  D / "borea_terrain_test0.mes"])
    assert len(blk.obs_photo) == 17 + 7


@pytest.mark.parametrize("unit", ["deg", "rad", "gon"])
@pytest.mark.parametrize("flavour", ["pix4d", "ign"])
def test_thesis_round_trip(tmp_path, unit, flavour):
    blk = block_from_survey(None, THESIS_ADJ)
    p = write_opk(blk, tmp_path / "thesis.opk", angle_unit=unit, flavour=flavour)
    back = read_opk(p, angle_unit=unit)
    assert back.photo.tolist() == blk.photo_ids.tolist()
    assert np.abs(back.eo[:, 3:] - blk.eo[:, 3:]).max() < 1e-9
    assert np.abs(back.eo[:, :3] - blk.eo[:, :3]).max() == 0.0
    side = (tmp_path / "thesis.opk.json").read_text()
    assert "EPSG:29192" in side and "orthometric" in side


@pytest.mark.parametrize("text,expect", [
    ("NOM X Y Z O P\n", ":1: field 'kappa': header 'NOM X Y Z O P' has no column for kappa"),
    ("NOM X Y Z O P K\na 1 2 3 4 5 x\n", ":2: field 'K': 'x' is not a number"),
    ("NOM X Y Z O P K\na 1 2 3 4 5\n", ":2: field 'K': 6 fields, expected 7"),
    ("NOM X Y Z O P K\na 1 2 3 4 5 6,5\n", ":2: field 'K': '6,5' is not a number (a decimal comma? write 1.5"),
    ("NOM X Y Z O P K\na 1 2 3 4 5 6\na 1 2 3 4 5 6\n", ":3: field 'NOM': photo 'a' already on line 2"),
    ("imageName X Y Z Omega Phi Kappa\nb 1 2 inf 4 5 6\n", ":2: field 'Z': 'inf' is not a finite number"),
    ("", "empty file"),
])
def test_located_errors(tmp_path, text, expect):
    p = tmp_path / "bad.opk"
    p.write_text(text)
    with pytest.raises(FormatError) as ei:
        read_opk(p)
    assert str(ei.value).startswith(str(p)) and expect in str(ei.value)
