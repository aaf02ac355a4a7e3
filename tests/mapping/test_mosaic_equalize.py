"""Radiometric equalisation of the mosaic (report 12.1): gains and offsets from the overlaps, seam contrast."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.mapping.monoplot import GridSurface
from lidarcat.mapping.mosaic import mosaic, seam_contrast
from lidarcat.mapping.ortho import PhotoModel
from lidarcat.synthetic.scene import demo_scene

from ortho_scene import BOUNDS, CAM, EO_A, EO_B, GSD, MODEL_BOUNDS, rendered  # noqa: I001


@pytest.fixture(scope="module")
def block():
    """The two rendered photos of the synthetic scene, B exposed darker with a lifted black level."""
    scene = demo_scene()
    a = PhotoModel("A", rendered("A"), CAM, EO_A)
    img_b = rendered("B").astype(np.float64)
    b = PhotoModel("B", np.clip(0.6 * img_b + 25.0, 0, 255).astype(np.uint8), CAM, EO_B)
    return a, b, GridSurface(*scene.grid(MODEL_BOUNDS, 0.25, "dsm"))


def test_equalised_feathered_mosaic_cuts_the_seam_contrast_by_80_percent(block):
    a, b, dsm = block
    raw = mosaic([a, b], dsm, GSD, bounds=BOUNDS)
    bal = mosaic([a, b], dsm, GSD, bounds=BOUNDS, equalize=True, feather_m=2.0)
    assert raw.label_step == 1 and np.array_equal(raw.labels, bal.labels)
    c_raw = seam_contrast(raw.array, raw.labels)
    c_bal = seam_contrast(bal.array, bal.labels)
    # B = 0.6 A + 25 on the scene's grey levels: the raw step is tens of grey levels
    assert c_raw > 10.0
    assert c_bal <= 0.2 * c_raw, (c_raw, c_bal)
    # the gains undo the exposure: g_B * 0.6 = g_A and g_B * 25 + o_B = o_A (to the rounding to 8 bits)
    g = bal.gains[:, 0]
    assert g[1, 0] * 0.6 == pytest.approx(g[0, 0], rel=0.03)
    assert g[1, 0] * 25.0 + g[1, 1] == pytest.approx(g[0, 1], abs=2.0)
    assert g[:, 0].mean() == pytest.approx(1.0, abs=1e-9) and g[:, 1].mean() == pytest.approx(0.0, abs=1e-6)
    assert bal.to_dict()["gains"]["B"][0][0] == pytest.approx(g[1, 0], abs=1e-6)


def test_equalisation_of_equal_photos_is_the_identity_and_alone_already_lowers_the_contrast(block):
    a, b, dsm = block
    same = mosaic([a, a.__class__("A2", a.image, CAM, EO_A)], dsm, GSD, bounds=BOUNDS, equalize=True)
    np.testing.assert_allclose(same.gains[:, 0], [[1.0, 0.0], [1.0, 0.0]], atol=1e-6)
    raw = mosaic([a, b], dsm, GSD, bounds=BOUNDS)
    eq = mosaic([a, b], dsm, GSD, bounds=BOUNDS, equalize=True)     # hard seams, balanced photos
    assert seam_contrast(eq.array, eq.labels) < 0.2 * seam_contrast(raw.array, raw.labels)


def test_seam_contrast_is_the_mean_step_between_the_sides():
    labels = np.array([[0, 0, 1, 1]] * 3)
    arr = np.array([[10.0, 12.0, 20.0, 22.0]] * 3)
    assert seam_contrast(arr, labels) == pytest.approx(8.0)          # 12 beside 20 on each row
    assert seam_contrast(arr, np.zeros_like(labels)) == 0.0           # one photo: no seam


def test_ortho_equalize_needs_the_mosaic(tmp_path):
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    (tmp_path / "x.tif").write_bytes(b"")
    r = CliRunner().invoke(cli, ["ortho", str(tmp_path), "--all", "--dsm", str(tmp_path / "x.tif"), "--equalize", "-o",
                                 str(tmp_path / "o")])
    assert r.exit_code == 2 and "--equalize balances the mosaic's photos: give it with --mosaic" in r.output
