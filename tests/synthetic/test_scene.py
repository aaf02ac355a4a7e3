"""The synthetic scene, its rendered photos and the demo's photos and LiDAR attributes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.geometry.collinearity import project
from lidarcat.geometry.camera import Camera
from lidarcat.errors import LidarcatError
from lidarcat.mapping.accuracy import assess_features
from lidarcat.synthetic.scene import LABELS, Building, Scene, demo_scene

E0, N0 = 680_400.0, 7_184_200.0
CAM = Camera("s", 35.0, 0.01, -0.02, -2.5e-5, 1e-8, 0.0, 2e-6, -1e-6, 0.0, 0.06, 0.06, 600, 400)
EO = np.array([E0 - 30, N0 + 10, 910 + 250.0, math.radians(1.0), math.radians(-0.8), math.radians(20.0)])


def test_building_geometry():
    b = Building("pyramid", 100.0, 200.0, width_m=10.0, slope_deg=45.0, eave_m=5.0, azimuth_deg=90.0)
    assert b.length_m == 10.0 and b.top_m == pytest.approx(10.0)
    np.testing.assert_allclose(b.vertices(50.0), [[100.0, 200.0, 60.0]])
    np.testing.assert_allclose(b.roof(np.array([100.0, 102.0, 106.0]), np.array([200.0, 200.0, 200.0])),
                               [10.0, 8.0, np.nan])
    fp = b.footprint()
    np.testing.assert_allclose(np.sort(fp[:, 0]), [95, 95, 105, 105], atol=1e-12)
    with pytest.raises(LidarcatError, match="a hip roof needs length_m > width_m"):
        Building("hip", 0, 0, length_m=8, width_m=10)


def test_render_shows_each_surface_where_the_collinearity_puts_it():
    """Project points of known label into the photo: the rendered grey there is the
    scene's texture of that point (roof, road, ground) within interpolation noise."""
    scene = demo_scene()
    img = scene.render(CAM, EO).astype(float)
    rng = np.random.default_rng(1)
    e = rng.uniform(E0 - 60, E0 + 60, 40000)
    n = rng.uniform(N0 - 40, N0 + 40, 40000)
    h, lab = scene.surface(e, n)
    xy, _ = project(np.broadcast_to(EO, (len(e), 6)), np.column_stack([e, n, h]), np.full(len(e), 35.0))
    px = CAM.photo_to_pixel(xy)
    # pixel centres only (no interpolation), on the photo, and seen from the camera
    col, row = np.rint(px).T.astype(int)
    near = (np.abs(px - np.rint(px)) < 0.05).all(axis=1) & (col >= 0) & (col < 600) & (row >= 0) & (row < 400)
    from lidarcat.mapping.monoplot import ray_directions

    d = ray_directions(CAM, EO, px[near])
    hit = scene.hit(EO[:3], d)
    t_pt = (h[near] - EO[2]) / d[:, 2]
    seen = np.abs(hit[:, 0] - t_pt) * np.linalg.norm(d, axis=1) < 0.05
    idx = np.flatnonzero(near)[seen]
    want = scene.ortho_texture(e[idx], n[idx])
    got = img[row[idx], col[idx]]
    assert len(idx) > 50 and {0, 1, 2} <= set(lab[idx].tolist())
    # 0.05 px (2 cm) off a pixel centre on a texture of up to ~100 grey/m, plus rounding to integers
    err = np.abs(got - want)
    assert np.median(err) < 1.0 and np.percentile(err, 95) <= 3.0 and err.max() < 10


def test_scene_grids_and_lidar_attributes():
    scene = demo_scene()
    b = (E0 - 50, N0 - 40, E0 + 50, N0 + 40)
    dsm, t = scene.grid(b, 1.0, "dsm")
    dtm, _ = scene.grid(b, 1.0, "dtm")
    lab, _ = scene.grid(b, 1.0, "label")
    assert dsm.shape == (80, 100) and t.x0 == E0 - 50 and t.y0 == N0 + 40
    assert ((dsm - dtm)[lab == LABELS["roof"]] > 4.5).all() and (dsm == dtm)[lab < 2].all()
    pts = scene.lidar_points(b, 2.0, seed=3)
    assert abs(len(pts["xyz"]) - 16000) < 4 * math.sqrt(16000)
    roof = pts["classification"] == 6
    assert pts["intensity"][roof].mean() > 2 * pts["intensity"][~roof].mean()
    assert (pts["return_number"] == 1).all() and (pts["number_of_returns"] == 1).all()
    with pytest.raises(LidarcatError, match="what must be dsm, dtm, texture or label, got 'x'"):
        scene.grid(b, 1.0, "x")


def test_assess_features_per_class_as_the_paper():
    """Known discrepancies: means, sds, r90 (the 9th of 10 sorted resultants) and the PEC class."""
    r = np.arange(1, 11) / 10.0                                # resultants 0.1 .. 1.0 m
    ang = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    d = np.column_stack([r * np.cos(ang), r * np.sin(ang)])
    d2 = np.vstack([d, 3 * d])
    out = assess_features(d2, ["building"] * 10 + ["road"] * 10, scale=2000)
    assert list(out) == ["building", "road"]
    b, rd = out["building"], out["road"]
    assert b["n"] == 10 and b["r90_m"] == pytest.approx(0.9) and rd["r90_m"] == pytest.approx(2.7)
    assert b["mean_resultant"] == pytest.approx(0.55) and b["sd_resultant"] == pytest.approx(np.std(r, ddof=1))
    assert b["mean_E"] == pytest.approx(d[:, 0].mean()) and b["sd_N"] == pytest.approx(d[:, 1].std(ddof=1))
    # 1:2000, class A: 90 % within 1.0 m and RMS <= 0.6 m; the RMS here is sqrt(0.385) = 0.62 m: class B
    assert b["pec_class"] == "B" and rd["pec_class"] == "none"
    assert b["hotelling"]["passed"] and b["ks"]["applicable"]


@pytest.mark.slow
def test_demo_images_and_lidar_intensity(tmp_path):
    laspy = pytest.importorskip("laspy")
    import cv2

    from lidarcat.synthetic.survey import demo_camera, write_synthetic_survey

    res = write_synthetic_survey(tmp_path / "d", n_photos=2, images=True, image_downsample=20,
                                 lidar_density_m2=0.5)
    assert "images/1.png" in res.files and "images/2.png" in res.files
    img = cv2.imread(str(tmp_path / "d" / "images" / "1.png"), cv2.IMREAD_UNCHANGED)
    cam = demo_camera()
    assert img.shape == (cam.rows_px, cam.columns_px) and img.dtype == np.uint8 and img.std() > 5
    las = laspy.read(next((tmp_path / "d" / "lidar").glob("*.laz")))
    assert (np.asarray(las.return_number) == 1).all() and (np.asarray(las.number_of_returns) == 1).all()
    inten = np.asarray(las.intensity).astype(float)
    cls = np.asarray(las.classification)
    assert inten.min() > 0 and inten[cls == 6].mean() > 1.5 * inten[cls == 2].mean()
    with pytest.raises(LidarcatError, match="--image-downsample 7 must divide the image size 6000 x 4000"):
        write_synthetic_survey(tmp_path / "e", n_photos=2, images=True, image_downsample=7, lidar_density_m2=0.5)
    assert not (tmp_path / "e").exists()


@pytest.mark.slow
def test_cavassim_experiment_roads_reproduce_the_papers_ordering():
    """A small run of the paper's comparison (3 buildings, 12 road points; docs/mapping.md has the
    full one): on road edges the TIN is at least as good as the nearest neighbour and both beat
    digitising on the LiDAR intensity image, as in Table 09."""
    from lidarcat.synthetic.cavassim import cavassim_experiment

    r = cavassim_experiment(seed=1, n_buildings=3, n_road_points=12)
    assert r["setup"]["n_building_points"] == 12 and r["setup"]["n_road_points"] == 12
    assert all(s == {"ok": 24} for p, s in r["status"].items() if "iterate" not in p)   # the first hit
    road = {p: v["road"] for p, v in r["r90"].items()}
    assert road["tin"] <= road["nearest"] + 0.02 < road["intensity_image"]
    assert road["intensity_image"] > 2 * road["tin"]
    t = r["tables"]["tin"]["road"]
    assert t["n"] == 12 and t["pec_class"] == "A" and t["ks"]["applicable"]
    # why buildings do not reproduce it (docs/mapping.md): a roof corner whose ray leaves the roof as it
    # descends meets the roof only where the surface holds the roof up to the corner; otherwise it falls,
    # and the plan error is the height it fell times the ray's tan(off-nadir) (+ orientation and pointing)
    co = r["corners"]
    assert len(co["leaving"]) == 12 and 0 < co["leaving"].sum() < 12
    tan_off = np.tan(np.radians(co["off_nadir_deg"]))
    for prod in ("nearest", "tin", "tin_points", "nearest_iterate"):
        dh, err = co["h_error_m"][prod], co["error_m"][prod]
        fell = np.isfinite(dh) & (dh < -1.0)
        assert fell.any()
        np.testing.assert_allclose(err[fell], -dh[fell] * tan_off[fell], atol=0.4)
    # the TIN of the points keeps no roof corner whose ray leaves the roof: its edge triangles ramp
    # down from the last roof point, inside the outline
    dh = co["h_error_m"]["tin_points"]
    assert (dh[co["leaving"]] < -1.0).mean() >= 0.75
    # the paper's iteration started on the ground converges behind the roof (flagged) or oscillates
    assert r["status"]["nearest_iterate"]["ok"] < 24
