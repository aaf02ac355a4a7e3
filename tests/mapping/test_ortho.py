"""Orthophotos and mosaics of rendered synthetic photos against the scene's own ortho texture."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from lidarcat.lidar.geotiff import read_geotiff
from lidarcat.mapping.monoplot import GridSurface, PointSurface
from lidarcat.mapping.mosaic import mosaic
from lidarcat.mapping.ortho import OrthoError, PhotoModel, orthophoto
from lidarcat.synthetic.scene import demo_scene

from ortho_scene import BOUNDS, CAM, E0, EO_A, EO_B, GSD, MODEL_BOUNDS, N0, rendered  # noqa: I001  (tests/ortho_scene.py)


@pytest.fixture(scope="module")
def scene():
    return demo_scene()


@pytest.fixture(scope="module")
def photo_a(scene):
    return PhotoModel("A", rendered("A"), CAM, EO_A)


@pytest.fixture(scope="module")
def photo_b(scene):
    return PhotoModel("B", rendered("B"), CAM, EO_B)


@pytest.fixture(scope="module")
def models(scene):
    dsm = GridSurface(*scene.grid(MODEL_BOUNDS, 0.25, "dsm"))
    dtm = GridSurface(*scene.grid(MODEL_BOUNDS, 0.25, "dtm"))
    return dsm, dtm


@pytest.fixture(scope="module")
def reference(scene):
    return scene.grid(BOUNDS, GSD, "texture")


def _shift(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> tuple[float, float]:
    a = img.astype(np.float64).copy()
    bad = ~np.isfinite(a) if mask is None else (~np.isfinite(a) | mask)
    a[bad] = ref[bad]                 # masked cells cannot pull the peak anywhere
    win = cv2.createHanningWindow(a.shape[::-1], cv2.CV_64F)
    (dx, dy), _ = cv2.phaseCorrelate(a, ref.astype(np.float64), win)
    return dx, dy


def test_distortion_lookup_matches_newton_inverse(photo_a):
    rng = np.random.default_rng(0)
    px = rng.uniform(0, [CAM.columns_px - 1, CAM.rows_px - 1], (3000, 2))
    xy = CAM.pixel_to_photo(px)
    col, row = photo_a._lut(xy[:, 0], xy[:, 1])
    assert np.abs(col - px[:, 0]).max() < 0.01 and np.abs(row - px[:, 1]).max() < 0.01


def test_true_ortho_matches_the_scene_texture_within_a_pixel(photo_a, models, reference):
    dsm, _ = models
    ref, t = reference
    res = orthophoto(photo_a, dsm, GSD, bounds=BOUNDS, true_ortho=True)
    assert res.transform == t and res.shape == ref.shape
    assert res.n_occluded > 500 and res.n_valid > 0.85 * ref.size
    img = res.array[:, :, 0]
    dx, dy = _shift(img, ref)
    assert math.hypot(dx, dy) < 1.0
    # whole-image agreement: the median grey difference is a fraction of a grey level
    assert np.nanmedian(np.abs(img - ref)) < 2.0


def test_standard_ortho_of_flat_ground_matches_texture_but_roofs_lean(scene, photo_a, models, reference):
    """Over the DTM the ground is right (phase correlation < 1 px on a building-free window)
    but the roofs lean away from the nadir; over the DSM (true ortho) each roof's outline is
    within 1 px of its footprint."""
    dsm, dtm = models
    ref, t = reference
    std = orthophoto(photo_a, dtm, GSD, bounds=BOUNDS).array[:, :, 0]
    true = orthophoto(photo_a, dsm, GSD, bounds=BOUNDS, true_ortho=True).array[:, :, 0]
    labels, _ = scene.grid(BOUNDS, GSD, "label")
    # a 128 x 128 window of ground and road only (no roof within 10 m of it)
    roofs = cv2.dilate((labels >= 2).astype(np.uint8), np.ones((81, 81), np.uint8))
    free = [(r, c) for r in range(0, ref.shape[0] - 128, 16) for c in range(0, ref.shape[1] - 128, 16)
            if not roofs[r:r + 128, c:c + 128].any()]
    assert free
    win = (slice(free[0][0], free[0][0] + 128), slice(free[0][1], free[0][1] + 128))
    assert math.hypot(*_shift(std[win], ref[win])) < 1.0
    # the flat roof (building 3, 9 m eaves: the biggest lean) as a mask of its grey
    b3 = scene.buildings[3]
    ce, cn = t.xy(*np.indices(ref.shape))
    near = np.hypot(ce - b3.e_m, cn - b3.n_m) < 20
    truth = ((labels == 2) & near).astype(np.uint8)                 # cell centres on the roof
    roof_grey = float(np.median(ref[truth.astype(bool)]))

    def roof_mask(img: np.ndarray) -> np.ndarray:
        m = (np.abs(np.nan_to_num(img) - roof_grey) < 40).astype(np.uint8)   # half way to the walls
        m = cv2.morphologyEx(m, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        n, lab, stats, cent = cv2.connectedComponentsWithStats(m)
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        return lab == big

    def edges_px(mask: np.ndarray) -> np.ndarray:
        """Offsets (px) of the 4 edges of the rectangle fitted to the mask from the footprint's."""
        cnts, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        (cx, cy), (w, h), ang = cv2.minAreaRect(max(cnts, key=cv2.contourArea))
        b = scene.buildings[3]
        u = np.array([math.cos(math.radians(b.azimuth_deg)), -math.sin(math.radians(b.azimuth_deg))])
        v = np.array([-u[1], u[0]])                       # image axes: col right, row down
        pts = cv2.boxPoints(((cx, cy), (w + 1, h + 1), ang))   # contour runs through pixel centres
        ctr = np.array([(b.e_m - t.x0) / GSD - 0.5, (t.y0 - b.n_m) / GSD - 0.5])
        pu, pv = (pts - ctr) @ u, (pts - ctr) @ v
        half_l, half_w = b.length_m / 2 / GSD, b.width_m / 2 / GSD
        return np.array([pu.max() - half_l, pu.min() + half_l, pv.max() - half_w, pv.min() + half_w])

    print("edge offsets (px): truth", edges_px(truth), "true ortho", edges_px(roof_mask(true)),
          "standard ortho", edges_px(roof_mask(std)))
    assert np.abs(edges_px(truth)).max() < 0.6                        # the fit itself
    assert np.abs(edges_px(roof_mask(true))).max() < 1.0              # true ortho: edges within 1 px
    assert np.abs(edges_px(roof_mask(std))).max() > 3.0               # standard ortho: the lean


def test_tiling_does_not_change_the_output(photo_a, models):
    dsm, _ = models
    b = (E0 - 30, N0 - 20, E0 + 30, N0 + 20)
    one = orthophoto(photo_a, dsm, 0.5, bounds=b, true_ortho=True, tile_px=4096).array
    many = orthophoto(photo_a, dsm, 0.5, bounds=b, true_ortho=True, tile_px=17).array
    np.testing.assert_array_equal(np.isnan(one), np.isnan(many))
    np.testing.assert_array_equal(np.nan_to_num(one), np.nan_to_num(many))


def test_geotiff_is_georeferenced_for_gdal_readers(tmp_path, photo_a, models):
    rasterio = pytest.importorskip("rasterio")
    dsm, _ = models
    b = (E0 - 40, N0 - 30, E0 + 40, N0 + 30)
    res = orthophoto(photo_a, dsm, 0.5, tmp_path / "o.tif", bounds=b, true_ortho=True,
                     crs="EPSG:31982", tile_px=32)
    assert res.array is None and (tmp_path / "o.png").is_file()
    with rasterio.open(tmp_path / "o.tif") as src:
        assert src.crs.to_epsg() == 31982
        assert tuple(src.transform)[:6] == (0.5, 0.0, E0 - 40, 0.0, -0.5, N0 + 30)
        assert (src.width, src.height, src.count) == (160, 120, 1)
        data = src.read(1)
    mem = orthophoto(photo_a, dsm, 0.5, bounds=b, true_ortho=True).array[:, :, 0]
    np.testing.assert_array_equal(np.nan_to_num(data), np.nan_to_num(mem))
    grid, t, crs = read_geotiff(tmp_path / "o.tif")                # the project's own reader too
    assert t.x0 == E0 - 40 and crs.to_epsg() == 31982
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.png", "o.tif"]


def test_three_band_geotiff(tmp_path, photo_a, models):
    tifffile = pytest.importorskip("tifffile")
    dsm, _ = models
    # float32 bands: 255 - x is exact in float, while 8-bit bilinear rounding breaks the symmetry at ties
    # (cv2 rounds half up: 28 of these 1600 cells); the 8-bit file is checked in test_photo_dtype_kept...
    rgb = np.stack([photo_a.image, 255 - photo_a.image, photo_a.image // 2], axis=2).astype(np.float32)
    p = PhotoModel("A", rgb, CAM, EO_A)
    b = (E0 - 10, N0 - 10, E0 + 10, N0 + 10)
    orthophoto(p, dsm, 0.5, tmp_path / "rgb.tif", bounds=b, crs="EPSG:31982")
    with tifffile.TiffFile(tmp_path / "rgb.tif") as tf:
        page = tf.pages[0]
        arr = page.asarray()
        assert arr.shape == (40, 40, 3) and page.photometric == 2
        assert tf.pages[0].tags["ModelPixelScaleTag"].value[:2] == (0.5, 0.5)
    np.testing.assert_allclose(arr[..., 1], 255 - arr[..., 0], atol=1e-3)


def test_errors_and_nothing_half_written(tmp_path, photo_a, models, scene):
    dsm, _ = models
    small = GridSurface(*scene.grid((E0 + 500, N0 + 500, E0 + 520, N0 + 520), 1.0, "dsm"))
    with pytest.raises(OrthoError, match=r"photo 'A': the surface model \(680900\.0 7184700\.0 "
                                         r"680920\.0 7184720\.0\) does not cover the photo's footprint"):
        orthophoto(photo_a, small, 0.5)
    with pytest.raises(OrthoError, match="--gsd must be positive, got 0"):
        orthophoto(photo_a, dsm, 0, bounds=BOUNDS)
    with pytest.raises(OrthoError, match=r"orthophotos need a gridded DTM/DSM"):
        orthophoto(photo_a, PointSurface(np.random.default_rng(0).uniform(0, 9, (20, 3))), 0.5)
    with pytest.raises(OrthoError, match=r"photo 'X': image is \(10, 10\) px but camera 'small' is 1200 x 800"):
        PhotoModel("X", np.zeros((10, 10), np.uint8), CAM, EO_A)

    def boom(done, total):
        if done > 40:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        orthophoto(photo_a, dsm, 0.5, tmp_path / "cut.tif", bounds=BOUNDS, tile_px=20, progress=boom)
    assert list(tmp_path.iterdir()) == []


def test_mosaic_takes_the_most_nadir_visible_photo(tmp_path, scene, photo_a, photo_b, models, reference):
    dsm, _ = models
    ref, t = reference
    res = mosaic([photo_a, photo_b], dsm, GSD, tmp_path / "m.tif", seams_path=tmp_path / "seams.geojson",
                 bounds=BOUNDS, crs="EPSG:31982")
    arr, tt, _ = read_geotiff(tmp_path / "m.tif")
    assert tt == t and res.label_step == 1
    assert res.cells_per_photo["A"] > 0.3 * ref.size and res.cells_per_photo["B"] > 0.3 * ref.size
    # west of the midpoint between the nadirs the cells come from A, east from B
    e = tt.xy(0, np.arange(ref.shape[1]))[0]
    mid = (EO_A[0] + EO_B[0]) / 2
    row = res.labels[ref.shape[0] // 2]
    assert (row[(e < mid - 8) & (row >= 0)] == 0).mean() > 0.95
    assert (row[(e > mid + 8) & (row >= 0)] == 1).mean() > 0.95
    assert math.hypot(*_shift(arr, ref)) < 1.0
    assert np.nanmedian(np.abs(arr - ref)) < 2.0
    # fewer nodata cells than either true ortho alone: occlusions are filled from the other photo
    a = orthophoto(photo_a, dsm, GSD, bounds=BOUNDS, true_ortho=True)
    assert res.n_nodata < a.n_occluded + a.n_outside
    gj = json.loads((tmp_path / "seams.geojson").read_text())
    assert gj["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31982"
    assert [f["properties"]["photo"] for f in gj["features"]] == ["A", "B"]
    areas = [f["properties"]["area_m2"] for f in gj["features"]]
    assert sum(areas) == pytest.approx((ref.size - res.n_nodata) * GSD**2)
    ring = np.array(gj["features"][0]["geometry"]["coordinates"][0][0])
    assert ring[:, 0].min() >= BOUNDS[0] - GSD and ring[:, 0].max() <= BOUNDS[2] + GSD


def test_mosaic_feathering_blends_across_seams_only_and_does_not_depend_on_tiles(models, photo_a, photo_b):
    """feather_m = 2 m: a darker photo B blends into A over the seam band; cells farther than 2 m from
    every seam keep the hard mosaic's value; tiles of 17 px give the same output as one tile."""
    import cv2

    dsm, _ = models
    dark_b = PhotoModel("B", (photo_b.image * 0.6).astype(np.uint8), CAM, EO_B)
    hard = mosaic([photo_a, dark_b], dsm, GSD, bounds=BOUNDS)
    soft = mosaic([photo_a, dark_b], dsm, GSD, bounds=BOUNDS, feather_m=2.0, tile_px=4096)
    tiled = mosaic([photo_a, dark_b], dsm, GSD, bounds=BOUNDS, feather_m=2.0, tile_px=17)
    np.testing.assert_allclose(tiled.array, soft.array, atol=1e-4)
    assert np.array_equal(soft.labels, hard.labels)
    lab = hard.labels
    a, s = hard.array[..., 0], soft.array[..., 0]
    # cells whose every neighbour within 2 m + a cell (the seam lies half a cell off a centre) has their
    # label: untouched
    k = 2 * (int(np.ceil(2.0 / GSD)) + 1) + 1
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    far = np.zeros(lab.shape, dtype=bool)
    for i in (0, 1):
        far |= cv2.erode((lab == i).astype(np.uint8), disk, borderType=cv2.BORDER_REPLICATE) > 0
    assert far.mean() > 0.5
    np.testing.assert_allclose(s[far], a[far], atol=1e-3)
    # across the seam (A west, B east on a row) the step between neighbours shrinks
    across = (lab[:, :-1] >= 0) & (lab[:, 1:] >= 0) & (lab[:, :-1] != lab[:, 1:])
    assert across.sum() > 20
    step_hard = np.nanmean(np.abs(a[:, 1:] - a[:, :-1])[across])
    step_soft = np.nanmean(np.abs(s[:, 1:] - s[:, :-1])[across])
    assert step_soft < 0.5 * step_hard
    with pytest.raises(OrthoError, match=r"mosaic: feather_m must be >= 0 \(metres\), got -1"):
        mosaic([photo_a, dark_b], dsm, GSD, bounds=BOUNDS, feather_m=-1)
