"""Roof facets: triangles (eq. 25-32), Gauss-Helmert plane fit (eq. 33-37), grouping, presets."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from conftest import DATA, THESIS_TABLES
from lidarcat.control.vertices import ControlPoint, extract_roof, find_candidates
from lidarcat.control.facets import (
    PRESETS, ExtractionParams, Plane, delaunay_facets, fit_plane, get_params, segment_faces,
    triangle_planes, triangle_slope_aspect,
)
from lidarcat.synthetic.roofs import LABELS, synthetic_roof


# ----------------------------------------------------------------- eq. 25-32
def test_triangle_plane_passes_through_vertices_and_has_twice_the_area():
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-5, 5, (50, 3))
    fac = delaunay_facets(xyz)
    pl = fac.planes
    local = xyz - xyz.mean(axis=0)
    for k in range(3):
        vals = np.einsum("ij,ij->i", pl[:, :3], local[fac.simplices[:, k]]) + pl[:, 3]
        np.testing.assert_allclose(vals, 0.0, atol=1e-9)
    # |(a, b, c)| projected on the vertical = 2 x plan area (c = twice the signed plan area)
    np.testing.assert_allclose(np.abs(pl[:, 2]), 2 * fac.area_m2, rtol=1e-9)
    assert np.all(pl[:, 2] >= 0)  # normals oriented upwards


def test_slope_eq32_and_aspect():
    s30 = math.tan(math.radians(30))
    xyz = np.array([[0, 0, 0], [1, 0, 0], [0, 1, s30]], dtype=float)  # rises to the north
    pl = triangle_planes(xyz, np.array([[0, 1, 2]]))
    slope, aspect = triangle_slope_aspect(pl)
    np.testing.assert_allclose(slope, [30.0], atol=1e-9)
    np.testing.assert_allclose(aspect, [180.0], atol=1e-9)  # faces south


# ----------------------------------------------------------------- eq. 33-37
def _plane_points(rng, m, noise_h, noise_plan=0.0, slope=0.5):
    e, n = rng.uniform(-2, 2, (2, m))
    h = 100 + slope * e + rng.normal(0, noise_h, m)
    return np.column_stack([e + rng.normal(0, noise_plan, m) + 677000, n + rng.normal(0, noise_plan, m) + 7183000, h])


def test_gauss_helmert_covariance_is_honest():
    rng = np.random.default_rng(1)
    z = []
    v = np.array([677001.0, 7183001.0, 100.5])
    for _ in range(600):
        x = _plane_points(rng, 30, 0.10, 0.02)
        fit = fit_plane(x, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None)
        pl = fit.plane
        xh = np.append(v - pl.centroid_m, 1.0)
        z.append(pl.distance(v[None])[0] / math.sqrt(xh @ pl.cov_at(pl.centroid_m) @ xh))
    z = np.array(z)
    assert abs(z.mean()) < 0.12
    assert 0.9 < z.std() < 1.12


def test_gauss_helmert_with_equal_sds_is_orthogonal_regression():
    rng = np.random.default_rng(2)
    x = _plane_points(rng, 80, 0.05, 0.05)
    fit = fit_plane(x, sd_m=(0.05, 0.05, 0.05), residual_threshold_m=10.0)
    c = x - x.mean(axis=0)
    n_tls = np.linalg.eigh(c.T @ c)[1][:, 0]
    n_tls *= np.sign(n_tls[2])
    np.testing.assert_allclose(fit.plane.n, n_tls, atol=1e-9)


def test_per_point_sds_weight_the_fit():
    rng = np.random.default_rng(3)
    x = _plane_points(rng, 60, 0.01)
    x[:10, 2] += rng.normal(0, 0.5, 10)  # ten poor points...
    sd = np.tile([0.01, 0.01, 0.01], (60, 1))
    sd[:10, 2] = 0.5  # ...declared poor
    good = fit_plane(x, sd_m=sd, residual_threshold_m=10.0).plane
    assert abs(good.slope_deg - math.degrees(math.atan(0.5))) < 0.1


def test_iterative_rejection_removes_chimney_points_thesis_threshold():
    rng = np.random.default_rng(4)
    x = _plane_points(rng, 100, 0.03)
    x[:12, 2] += 1.0  # a chimney 1 m above the face
    fit = fit_plane(x, sd_m=(0.5, 0.5, 0.15), residual_threshold_m=0.15, residual_kind="vertical")
    assert not fit.used[:12].any()
    # the GH adjusted-height residual absorbs most of the misclosure into the 0.5 m
    # plan sds: the same threshold on v_h lets chimney points through
    weak = fit_plane(x, sd_m=(0.5, 0.5, 0.15), residual_threshold_m=0.15, residual_kind="height")
    assert weak.used[:12].any()
    assert fit.used[12:].sum() >= 85
    assert fit.plane.n_rejected == 100 - fit.plane.n_used


def test_fit_fails_with_a_reason():
    fit = fit_plane(np.zeros((4, 3)) + [1, 2, 3], min_points=6)
    assert not fit and "4 points, a plane needs at least 6" in fit.reason
    line = np.column_stack([np.arange(10.0), np.arange(10.0), np.arange(10.0)])
    fit = fit_plane(line)
    assert not fit and "collinear" in fit.reason


# ----------------------------------------------------------------- Table 4 layout
def _table4():
    return np.loadtxt(THESIS_TABLES / "table4_planes_708.csv", delimiter=",", skiprows=2)


def test_table4_roundtrip_thesis_form():
    t = _table4()
    for row in t:
        pl = Plane.from_abcd(row[1:5])
        abcd, sd = pl.thesis_form(d=row[4])
        np.testing.assert_allclose(abcd, row[1:5], rtol=1e-12)
        assert sd[3] == 0.0


def test_table4_sds_follow_the_fixed_d_datum():
    """Table 4 prints sd_b / sd_a = E / N of point 708: d was held fixed.

    A plane fitted through synthetic points at 708 and printed in the same
    datum shows the same ratio, which any unit-normal datum would not.
    """
    t = _table4()
    e708, n708 = 677872.658, 7183983.510
    np.testing.assert_allclose(t[:, 6] / t[:, 5], e708 / n708, rtol=0.015)
    rng = np.random.default_rng(5)
    e, n = rng.uniform(-3, 3, (2, 40))
    h = 918.0 - 0.17 * e + rng.normal(0, 0.05, 40)
    fit = fit_plane(np.column_stack([e + e708, n + n708, h]), residual_threshold_m=None)
    abcd, sd = fit.plane.thesis_form(d=t[0, 4])
    assert sd[1] / sd[0] == pytest.approx(e708 / n708, rel=0.02)


# ----------------------------------------------------------------- presets
def test_presets():
    th = get_params("thesis")
    assert (th.slope_min_deg, th.slope_max_deg, th.residual_threshold_m, th.height_window_m,
            th.height_filter, th.method) == (4.0, 30.0, 0.15, 2.0, "thesis", "thesis")
    assert get_params("default") is PRESETS["default"]
    with pytest.raises(ValueError, match="unknown preset 'x'"):
        get_params("x")
    with pytest.raises(ValueError, match="method must be one of region, ransac, thesis, got 'hough'"):
        ExtractionParams(method="hough")
    with pytest.raises(ValueError, match="residual_threshold_m must be positive, got -0.15"):
        get_params("thesis", residual_threshold_m=-0.15)


def test_robust_height_filter_is_the_lidar_clip_filter():
    """ExtractionParams(height_filter="robust") is lidarcat.lidar.clip's "robust": +-2 m
    around the median of the clip's upper half, so the ground 6 m below the eaves goes."""
    s = synthetic_roof("pyramid", density_m2=4, noise_h_m=0.05, seed=0, slope_deg=30)
    v = s.vertices[0]
    cp = extract_roof(s.xyz, v[:2] + 0.4, params=get_params(height_filter="robust"))
    assert cp, cp.reason
    np.testing.assert_allclose(cp.enh_m, v, atol=0.15)
    xyz, _ = cp.labels
    truth = s.label[cKDTree(s.xyz).query(xyz)[1]]
    in_clip = np.hypot(*(s.xyz[:, :2] - (v[:2] + 0.4)).T) <= 8.0
    assert (s.label[in_clip] == LABELS["ground"]).sum() > 300  # the clip does hold ground...
    assert (truth == LABELS["ground"]).sum() == 0  # ...which the filter removes
    with pytest.raises(ValueError, match="height_window_m must be positive, got 0"):
        get_params(height_filter="robust", height_window_m=0)


# ----------------------------------------------------------------- grouping
@pytest.mark.parametrize("method", ["region", "ransac", "thesis"])
def test_segment_pyramid_finds_four_faces(method):
    s = synthetic_roof("pyramid", slope_deg=20, density_m2=6, noise_h_m=0.03, walls=False,
                       ground=False, seed=6)
    base = "thesis" if method == "thesis" else "default"
    planes, labels, info = segment_faces(s.xyz, get_params(base, method=method, height_filter=None,
                                                           slope_max_deg=60))
    assert len(planes) == 4
    np.testing.assert_allclose(sorted(p.slope_deg for p in planes), [20] * 4, atol=1.0)


def test_facade_points_stay_out_of_the_faces_when_the_ground_is_a_face():
    """The ground below an eave is segmented as a face too; it must not make the eave an
    internal edge, or the facade points facing the scanner stay in the roof faces
    (they pulled pyramid apexes 0.2 sd towards the scanner, found in the demo)."""
    rng = np.random.default_rng(5)
    params = get_params(sd_en_m=0.03, sd_h_m=0.05)
    in_faces = walls_near_eave = 0
    for _ in range(20):
        s = synthetic_roof("pyramid", slope_deg=rng.uniform(25, 35), width_m=rng.uniform(9, 11),
                           eave_m=rng.uniform(5, 7), azimuth_deg=rng.uniform(0, 90),
                           density_m2=4.0, noise_h_m=0.05, noise_plan_m=0.03,
                           origin=(0.0, 0.0, 0.0), seed=int(rng.integers(2**31)))
        sel = np.hypot(*(s.xyz[:, :2] - s.vertices[0, :2]).T) <= 8.0
        xyz, truth = s.xyz[sel], s.label[sel]
        planes, labels, _ = segment_faces(xyz, params)
        wall = truth == LABELS["wall"]
        in_faces += int(np.sum(wall & (labels >= 0)))
        # facade points higher than 0.15 m below the lowest roof point: what the edge rule must drop
        walls_near_eave += int(np.sum(wall & (xyz[:, 2] > np.percentile(xyz[truth == 1, 2], 0) - 0.15)))
    assert walls_near_eave > 20  # the scenes do put facade points at the eaves
    assert in_faces <= 3, in_faces  # 28 before the fix


def _used_truth_labels(cp, scene, intersected_only=False):
    xyz, lab = cp.labels
    _, ix = cKDTree(scene.xyz).query(xyz)
    keep = np.isin(lab, [p.label for p in cp.planes]) if intersected_only else lab >= 0
    return scene.label[ix][keep]


@pytest.mark.parametrize("kind,faces,length", [("hip", 3, 24.0), ("pyramid", 4, 16.0)])
def test_thesis_preset_on_curitiba_like_roofs(kind, faces, length):
    """15-25 deg, 1-2 pts/m2: 3 (hip end) or 4 (pyramid) planes; chimney and walls rejected."""
    found, n_ok = 0, 0
    for i in range(12):
        rng = np.random.default_rng(100 + i)
        s = synthetic_roof(kind, length_m=length, width_m=16, slope_deg=rng.uniform(15, 25),
                           density_m2=rng.uniform(1, 2), noise_h_m=0.05, noise_plan_m=0.05,
                           chimney=True, walls=True, seed=100 + i, azimuth_deg=rng.uniform(0, 90))
        v = s.vertices[0]
        cp = extract_roof(s.xyz, v[:2] + rng.uniform(-0.7, 0.7, 2), params="thesis")
        if not cp:
            continue
        n_ok += 1
        found += cp.n_planes in (3, 4)
        used = _used_truth_labels(cp, s)
        assert (used == LABELS["chimney"]).sum() == 0
        assert (used == LABELS["wall"]).sum() <= 1  # at most one point at an eave
        assert np.all(np.abs(cp.enh_m - v) < [0.6, 0.6, 0.2])
    assert n_ok >= 11 and found == n_ok


def test_thesis_preset_with_015_noise_still_finds_planes():
    """0.15 m noise (the issue's Curitiba case): 3-4 planes on most roofs, chimney and facades out."""
    counts = []
    for i in range(16):
        rng = np.random.default_rng(200 + i)
        kind, length = (("pyramid", 16.0), ("hip", 24.0))[i % 2]
        s = synthetic_roof(kind, length_m=length, width_m=16, slope_deg=rng.uniform(15, 25),
                           density_m2=rng.uniform(1, 2), noise_h_m=0.15, noise_plan_m=0.05,
                           chimney=True, seed=200 + i, azimuth_deg=rng.uniform(0, 90))
        cp = extract_roof(s.xyz, s.vertices[0, :2] + rng.uniform(-0.7, 0.7, 2), params="thesis")
        counts.append((cp.n_planes, bool(cp)))
        if cp:
            used = _used_truth_labels(cp, s, intersected_only=True)
            # at 1 sigma = 0.15 m the thesis method lets at most a stray point through
            assert (used == LABELS["chimney"]).sum() <= 1
            assert (used == LABELS["wall"]).sum() <= 1
    # planes detected in the clip (also when no vertex qualifies), and vertices found
    assert np.mean([n in (3, 4) for n, _ in counts]) >= 0.9, counts
    assert np.mean([ok for _, ok in counts]) >= 0.5, counts


def test_default_preset_on_dormer_chimney_tree_roof():
    s = synthetic_roof("hip", slope_deg=40, density_m2=8, noise_h_m=0.05, chimney=True, dormer=True,
                       tree=True, seed=7)
    params = get_params(sd_en_m=0.03)
    v = s.vertices[0]  # the ridge end away from the tree, near the chimney
    cp = extract_roof(s.xyz, v[:2] + 0.5, params=params)
    assert cp, cp.reason
    np.testing.assert_allclose(cp.enh_m, v, atol=0.15)
    used = _used_truth_labels(cp, s)
    assert (used == LABELS["chimney"]).sum() == 0 and (used == LABELS["tree"]).sum() == 0
    # the ridge end under the tree: the canopy points (118 in the 8 m search clip, 20 in the 5 m clip centred on
    # the vertex, lidarcat.control.localfit) stay out of the faces
    near = np.hypot(*(s.xyz[:, :2] - s.vertices[1, :2]).T) <= params.radius_m
    assert (s.label[near] == LABELS["tree"]).sum() > 100
    cp = extract_roof(s.xyz, s.vertices[1, :2], params=params)
    assert cp, cp.reason
    np.testing.assert_allclose(cp.enh_m, s.vertices[1], atol=0.15)
    xyz, _ = cp.labels
    assert (s.label[cKDTree(s.xyz).query(xyz)[1]] == LABELS["tree"]).sum() >= 15
    assert (_used_truth_labels(cp, s) == LABELS["tree"]).sum() == 0
    # the dormer's valley vertex (3 planes: two dormer faces + the main face): at 8 pts/m2
    # the 1.6 m2 dormer faces carry ~13 points each and one of them is lost, so no vertex...
    cp = extract_roof(s.xyz, s.vertices[2, :2] + 0.3, radius_m=4, params=params)
    assert cp.status == "no_vertex" and "no three of them meet within 2 m" in cp.reason
    # ...at 16 pts/m2 it is found
    s = synthetic_roof("hip", slope_deg=40, density_m2=16, noise_h_m=0.05, chimney=True, dormer=True,
                       tree=True, seed=7)
    cp = extract_roof(s.xyz, s.vertices[2, :2] + 0.3, radius_m=4, params=params)
    assert cp and cp.n_planes == 3, cp.reason
    np.testing.assert_allclose(cp.enh_m, s.vertices[2], atol=0.15)
    assert (_used_truth_labels(cp, s, intersected_only=True) == LABELS["dormer"]).sum() >= 40


# ----------------------------------------------------------------- degenerate input
def test_degenerate_inputs_end_with_a_status():
    rng = np.random.default_rng(8)
    few = rng.uniform(0, 1, (10, 3))
    cp = extract_roof(few, (0.5, 0.5), radius_m=5)
    assert not cp and cp.status == "too_few_points" and "10 points within 5 m" in cp.reason
    flat = synthetic_roof("flat", density_m2=6, walls=False, ground=False, seed=1)
    cp = extract_roof(flat.xyz, flat.xyz[:, :2].mean(axis=0), radius_m=5)
    assert cp.status == "flat_roof" and "flat roof has no vertex" in cp.reason
    gable = synthetic_roof("gable", density_m2=6, walls=False, ground=False, seed=1, azimuth_deg=0,
                           origin=(0, 0, 0))
    cp = extract_roof(gable.xyz, (0, 0), radius_m=3)
    assert cp.status == "two_planes" and "ridge line" in cp.reason
    y = rng.uniform(0, 10, 400)
    wall = np.column_stack([np.full(400, 5.0) + rng.normal(0, 0.02, 400), y, rng.uniform(0, 6, 400)])
    cp = extract_roof(wall, (5, 5), radius_m=6)
    assert not cp and cp.status == "wall" and "400 of 400 elements slope more than 65 deg" in cp.reason
    line = np.column_stack([np.arange(40.0), np.zeros(40), np.arange(40.0)])
    cp = extract_roof(line, (20, 0), radius_m=30)
    assert cp.status == "no_planes" and cp.reason == "no face with 4-65 deg slope and >= 6 points"
    cp = extract_roof(np.zeros((5, 2)), (0, 0))
    assert isinstance(cp, ControlPoint) and cp.status == "bad_input"
    assert cp.reason == "points must be an (N, 3) array or a PointCloud, got shape (5, 2)"
    with pytest.raises(ValueError, match=r"center_en must be \(E, N\) in metres, got \(5.0,\)"):
        extract_roof(flat.xyz, (5.0,))  # was taken for (5, 5)
    # a search over no points (e.g. no point of the requested class) finds nothing
    assert find_candidates(np.zeros((0, 3))) == []


def test_two_face_real_building_pdal_sample_c():
    laspy = pytest.importorskip("laspy")
    las = laspy.read(DATA / "lidar" / "pdal_sample_c.las")
    xyz = np.column_stack([las.x, las.y, las.z])
    c = np.median(xyz[:, :2], axis=0)
    cp = extract_roof(xyz, c, radius_m=8)
    assert not cp and cp.status == "two_planes" and cp.n_planes == 2
    assert "ridge line, not a point" in cp.reason
    # the low-pitch gable: 5 and ~12 deg faces
    np.testing.assert_allclose(sorted(p.slope_deg for p in cp.planes), [5.0, 11.9], atol=1.0)
