"""Realistic synthetic aerial photos (synthetic.aerial): truth maps, radiometry, determinism, matchability."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from lidarcat.errors import LidarcatError
from lidarcat.synthetic.aerial import (
    SURFACE,
    AerialScene,
    Exposure,
    aerial_camera,
    aerial_survey,
    ground_points,
    load_aerial_survey,
    project_to_pixels,
    render_photo,
    truth_map,
)
from lidarcat.synthetic.scene import demo_scene, demo_terrain

E0, N0 = 680_400.0, 7_184_200.0


@pytest.fixture(scope="module")
def scene():
    s = demo_scene()
    return AerialScene(buildings=s.buildings, roads=s.roads, targets=((E0 + 10, N0 - 60),), texel_m=0.5, seed=3)


CAM = aerial_camera((360, 240))
# 0.5 m pixels at nadir, 486 m above the ground: the whole demo town on one small photo, looked at obliquely
EO_A = np.array([E0 - 30, N0 + 10, 900 + 486.0, math.radians(2.0), math.radians(-3.0), math.radians(15.0)])
EO_B = np.array([E0 + 40, N0 - 5, 900 + 480.0, math.radians(-1.5), math.radians(2.5), math.radians(-10.0)])


def test_truth_map_projects_back_onto_each_pixel_and_lies_on_the_surface(scene):
    ph = render_photo(scene, CAM, EO_A, exposure=Exposure())
    xyz, surf, bld = ph.xyz, ph.surface, ph.building
    assert ph.image.shape == (240, 360) and ph.image.dtype == np.uint8
    assert xyz.shape == (240, 360, 3) and np.isfinite(xyz).all()
    counts = {k: int((surf == v).sum()) for k, v in SURFACE.items()}
    assert counts["none"] == 0 and counts["roof"] > 500 and counts["wall"] > 20 and counts["terrain"] > 50000
    rr, cc = np.mgrid[0:240, 0:360]
    px = project_to_pixels(CAM, EO_A, xyz.reshape(-1, 3))
    err = np.abs(px - np.column_stack([cc.ravel(), rr.ravel()]))
    assert err.max() < 0.01
    p = xyz.reshape(-1, 3)
    s = surf.ravel()
    b = bld.ravel()
    ground = s == SURFACE["terrain"]
    assert np.abs(p[ground, 2] - demo_terrain(p[ground, 0], p[ground, 1])).max() < 1e-3
    for k, bd in enumerate(scene.buildings):
        roof = (s == SURFACE["roof"]) & (b == k)
        z = bd.roof(p[roof, 0], p[roof, 1]) + scene.base_height(k)
        assert roof.sum() > 10 and np.abs(p[roof, 2] - z).max() < 1e-3
        wall = (s == SURFACE["wall"]) & (b == k)
        u, v = bd.to_local(p[wall, 0], p[wall, 1])
        off = np.minimum(np.abs(np.abs(u) - bd.length_m / 2), np.abs(np.abs(v) - bd.width_m / 2))
        assert off.max() < 1e-3
    # ground_points of the same pixels (another code path: arbitrary positions) and truth_map agree
    pick = np.random.default_rng(0).integers(0, len(p), 500)
    colrow = np.column_stack([cc.ravel(), rr.ravel()])[pick].astype(float)
    np.testing.assert_allclose(ground_points(scene, CAM, EO_A, colrow), p[pick], atol=1e-6)
    np.testing.assert_allclose(truth_map(scene, CAM, EO_A), xyz, atol=1e-6)


def test_albedo_is_a_function_of_ground_position_and_only_the_exposure_differs(scene):
    """Two photos with different exposures: every ground and roof pixel is the exposure's curve of
    the albedo at its true ground point (evaluated independently, on a lattice cropped elsewhere)."""
    exp = (Exposure(gain=0.8, gamma=2.0, offset=0.02), Exposure(gain=1.3, gamma=2.5, offset=0.0))
    fitted = []
    for eo, ex in zip((EO_A, EO_B), exp):
        ph = render_photo(scene, CAM, eo, exposure=ex)
        flat = (ph.surface != SURFACE["wall"]).ravel()
        p = ph.xyz.reshape(-1, 3)[flat]
        alb = scene.albedo(p[:, 0], p[:, 1], rgb=False)
        want = ex.apply(alb)
        got = ph.image.ravel()[flat].astype(float)
        assert np.abs(got - want).max() <= 1.0          # rounding + the tabulated curve
        # the gain recovered from the photo: median of (I / 255)^gamma / (k L)
        lin = ((got / 255 - ex.offset) / (1 - ex.offset)).clip(1e-3, 0.99) ** ex.gamma
        fitted.append(float(np.median(lin[alb > 0.05] / (1.2 * alb[alb > 0.05]))))
    assert fitted[0] == pytest.approx(0.8, rel=0.05) and fitted[1] == pytest.approx(1.3, rel=0.05)
    # the same plan positions, evaluated in two batches of different extent: the same albedo
    rng = np.random.default_rng(1)
    e = rng.uniform(E0 - 100, E0 + 100, 2000)
    n = rng.uniform(N0 - 80, N0 + 80, 2000)
    whole = scene.albedo(e, n)
    part = scene.albedo(e[:50], n[:50])
    np.testing.assert_allclose(part, whole[:50], atol=2e-5)   # float32 rounding of the local coordinates
    assert whole.shape == (2000, 3) and np.allclose(scene.albedo(e, n, rgb=False), whole @ [0.2126, 0.7152, 0.0722],
                                                     atol=1e-5)


def test_noise_and_vignetting_are_seeded_and_darken_the_corners(scene):
    a = render_photo(scene, CAM, EO_A, exposure=Exposure(noise_sd=2.0, seed=5), truth=False).image
    b = render_photo(scene, CAM, EO_A, exposure=Exposure(noise_sd=2.0, seed=5), truth=False).image
    c = render_photo(scene, CAM, EO_A, exposure=Exposure(noise_sd=2.0, seed=6), truth=False).image
    clean = render_photo(scene, CAM, EO_A, exposure=Exposure(), truth=False).image.astype(float)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.std(a - clean) == pytest.approx(2.0, rel=0.1)
    v = render_photo(scene, CAM, EO_A, exposure=Exposure(vignetting=0.3), truth=False).image.astype(float)
    corner, centre = v[:40, :40] / np.maximum(clean[:40, :40], 1), v[100:140, 160:200] / np.maximum(clean[100:140, 160:200], 1)
    assert np.median(corner) < 0.93 < 0.99 < np.median(centre)


def test_rgb_photo_is_the_grey_photo_in_colour(scene):
    grey = render_photo(scene, CAM, EO_A, truth=False).image
    rgb = render_photo(scene, CAM, EO_A, rgb=True, truth=False).image
    assert rgb.shape == (240, 360, 3)
    assert np.std(rgb[..., 1].astype(float) - rgb[..., 2]) > 3   # not grey: fields are green and brown
    # gamma-encoded channels do not add up to the grey exactly; the linear luminance does
    lin = (rgb / 255.0) ** 2.2 @ np.array([0.2126, 0.7152, 0.0722])
    assert np.median(np.abs(255 * lin ** (1 / 2.2) - grey)) < 1.5


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    root = tmp_path_factory.mktemp("aerial") / "block"
    return aerial_survey(root, n_strips=2, photos_per_strip=3, image_size_px=(480, 360), gsd_m=0.25,
                         lidar_density_m2=0.05, seed=4)


def test_aerial_survey_writes_a_loadable_survey_with_approximate_orientation_and_control(block):
    from lidarcat.survey import Survey

    s = Survey.load(block.path)
    assert [p.id for p in s.photos] == ["101", "102", "103", "201", "202", "203"]
    assert set(s.ground_points.point.tolist()) == {"G1", "G2", "G3", "G4"}
    truth = {row.split(",")[0]: row for row in (block.path / "truth" / "eop.csv").read_text().splitlines()
             if row and row[0].isdigit()}
    assert set(truth) == set(block.photo_ids)
    for p, k in zip(s.photos, range(len(block.photo_ids))):
        d = np.asarray(p.position_m) - block.true_eo[k, :3]
        assert np.abs(d).max() < 5 * 2.0 and np.allclose(p.sd_position_m, 2.0)
        da = (np.asarray(p.attitude_deg) - np.degrees(block.true_eo[k, 3:]) + 180) % 360 - 180
        assert np.abs(da).max() < 5 * 0.5
    assert np.allclose(block.approx_eo[:, :3], [p.position_m for p in s.photos], atol=1e-3)
    # every control target measured on >= 2 photos, at its true projection within 4 sd (0.3 px)
    ip = s.image_points
    for g, xyz in zip(block.gps_ids, block.gps_true):
        rows = np.flatnonzero(ip.point == g)
        assert len(rows) >= 2
        for i in rows:
            true_px = block.project(str(ip.photo[i]), xyz[None])[0]
            assert np.linalg.norm(ip.pixel_px[i] - true_px) < 4 * 0.3 * math.sqrt(2)
            img = cv2.imread(str(block.image_paths()[str(ip.photo[i])]), cv2.IMREAD_GRAYSCALE)
            c, r = np.rint(true_px).astype(int)
            assert img[r, c] > img[r - 4:r + 5, c - 4:c + 5].mean() + 20   # the white cross of the target
    assert {"lidar/tile_0_0.laz", "images/101.png", "truth/scene.json", "truth/exposure.csv"} <= set(block.files)
    again = load_aerial_survey(block.path)
    np.testing.assert_array_equal(again.true_eo, block.true_eo)
    assert again.exposures == block.exposures and len(again.scene.buildings) == len(block.scene.buildings)
    assert np.array_equal(again.render("102").image, cv2.imread(str(block.image_paths()["102"]), 0))


def test_aerial_survey_is_deterministic_by_seed(block, tmp_path):
    same = aerial_survey(tmp_path / "same", n_strips=2, photos_per_strip=3, image_size_px=(480, 360), gsd_m=0.25,
                         lidar_density_m2=0.05, seed=4)
    for f in ("photos.csv", "image_points.csv", "ground_points.csv", "truth/eop.csv", "truth/scene.json",
              "images/101.png", "images/203.png"):
        assert (same.path / f).read_bytes() == (block.path / f).read_bytes(), f
    other = aerial_survey(tmp_path / "other", n_strips=1, photos_per_strip=2, image_size_px=(480, 360), gsd_m=0.25,
                          lidar_density_m2=0, seed=5)
    assert (other.path / "images" / "101.png").read_bytes() != (block.path / "images" / "101.png").read_bytes()
    assert not any(f.startswith("lidar/") for f in other.files)


def test_sift_finds_dense_keypoints_and_matches_land_within_a_pixel_of_truth(block):
    """The property the matcher needs: OpenCV SIFT + ratio test + a RANSAC fundamental matrix on
    overlapping photos (three pairs, both strips); the true position of each match (its first photo's
    ground point, projected into the second) lies within 1 px of the matched keypoint for >= 99 % of
    the verified matches (the rest: coarse-scale keypoints, localised to a fraction of their size)."""
    paths = block.image_paths()
    sift = cv2.SIFT_create()
    errs = []
    for pa_id, pb_id in (("101", "102"), ("102", "103"), ("201", "202")):
        a = cv2.imread(str(paths[pa_id]), cv2.IMREAD_GRAYSCALE)
        b = cv2.imread(str(paths[pb_id]), cv2.IMREAD_GRAYSCALE)
        ka, da = sift.detectAndCompute(a, None)
        kb, db = sift.detectAndCompute(b, None)
        assert len(ka) > 1000 and len(kb) > 1000    # > 5,800 per megapixel (10,000 on a 1000 x 750 photo)
        good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.8 * n.distance]
        pa = np.array([ka[m.queryIdx].pt for m in good])
        pb = np.array([kb[m.trainIdx].pt for m in good])
        _, inl = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.0, 0.999)
        inl = inl.ravel().astype(bool)
        assert inl.sum() > 300
        true_b = block.transfer(pa_id, pa[inl], pb_id)
        seen = np.isfinite(true_b).all(axis=1)
        assert seen.mean() > 0.97
        errs.append(np.linalg.norm(true_b[seen] - pb[inl][seen], axis=1))
    err = np.concatenate(errs)
    assert np.mean(err < 1.0) >= 0.99 and np.median(err) < 0.3 and err.max() < 5.0


def test_transfer_is_nan_off_the_frame_and_behind_a_building(scene):
    """A ground point just behind a wall (seen from A) is hidden from a camera on the other side."""
    from lidarcat.synthetic.aerial import AerialSurvey

    b = scene.buildings[3]   # the flat building, 9 m eaves
    base = scene.base_height(3)
    u = b.length_m / 2 + 1.0
    ge, gn = b.to_world(np.array([u]), np.array([0.0]))
    ground = np.array([ge[0], gn[0], float(demo_terrain(ge, gn)[0])])
    ca, sa = math.cos(math.radians(b.azimuth_deg)), math.sin(math.radians(b.azimuth_deg))
    # camera A beyond the point (sees it), camera B across the building looking back at it
    eo_a = np.array([ge[0] + 60 * ca, gn[0] + 60 * sa, base + 300, 0.0, 0.0, 0.0])
    eo_b = np.array([ge[0] - 100 * ca, gn[0] - 100 * sa, base + 300, 0.0, 0.0, 0.0])
    cam = aerial_camera((400, 300))
    srv = AerialSurvey(None, scene, cam, ("a", "b"), np.array([eo_a, eo_b]), np.array([eo_a, eo_b]), 1.0, 0.1,
                       (Exposure(), Exposure()), (), np.zeros((0, 3)), 0.5, 0)
    pa = srv.project("a", ground[None])
    assert np.isfinite(pa).all() and np.linalg.norm(srv.ground_point("a", pa)[0] - ground) < 1e-3
    pb = srv.project("b", ground[None])
    assert cam.contains(pb)[0]                       # on B's frame ...
    assert np.isnan(srv.transfer("a", pa, "b")).all()   # ... but behind the building
    # a point of A's frame far from B's footprint: off B's frame
    off = srv.transfer("a", np.array([[399.0, 0.0]]), "b")
    assert not np.isfinite(srv.project("b", srv.ground_point("a", np.array([[399.0, 0.0]])))).all() \
        or not cam.contains(srv.project("b", srv.ground_point("a", np.array([[399.0, 0.0]]))))[0]
    assert np.isnan(off).all()


def test_aerial_survey_rejects_bad_arguments(tmp_path):
    with pytest.raises(LidarcatError, match="a block needs at least 1 strip of 2 photos, got 1 x 1"):
        aerial_survey(tmp_path / "x", n_strips=1, photos_per_strip=1)
    with pytest.raises(LidarcatError, match=r"forward_overlap must be in \[0, 1\), got 1.2"):
        aerial_survey(tmp_path / "x", forward_overlap=1.2)
    with pytest.raises(LidarcatError, match="gsd_m must be positive, got 0"):
        aerial_survey(tmp_path / "x", gsd_m=0)
    assert not (tmp_path / "x").exists()
