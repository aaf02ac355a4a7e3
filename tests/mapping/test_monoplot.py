"""Monorestitution against the known truth of the synthetic scene (lidarcat.synthetic.scene)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import DATA

from lidarcat.geometry.collinearity import project
from lidarcat.geometry.camera import Camera
from lidarcat.synthetic.survey import demo_camera
from lidarcat.errors import LidarcatError, SurveyError
from lidarcat.lidar import GeoTransform
from lidarcat.mapping.inputs import read_orientations
from lidarcat.mapping.monoplot import GridSurface, MonoplotError, PointSurface, monoplot
from lidarcat.synthetic.scene import demo_scene

E0, N0 = 680_400.0, 7_184_200.0
BOUNDS = (E0 - 110, N0 - 70, E0 + 110, N0 + 70)
CAM = demo_camera()
#: an oblique-ish photo: nadir 120 m west of the scene centre, 700 m above it
EO = np.array([E0 - 120, N0 + 15, 910 + 700.0, math.radians(1.5), math.radians(-2.0), math.radians(12.0)])
GSD_M = CAM.pixel_size_x_mm * 700.0 / CAM.focal_length_mm    # 0.12 m


def _pixels(points: np.ndarray, eo: np.ndarray = EO, cam: Camera = CAM) -> np.ndarray:
    xy, _ = project(np.broadcast_to(eo, (len(points), 6)), points, np.full(len(points), cam.focal_length_mm))
    return cam.photo_to_pixel(xy)


@pytest.fixture(scope="module")
def scene():
    return demo_scene()


@pytest.fixture(scope="module")
def lidar(scene):
    return scene.lidar_points(BOUNDS, 4.0, noise_m=0.05, seed=1)


@pytest.fixture(scope="module")
def tin(lidar):
    return PointSurface(lidar["xyz"], "tin", sd_m=0.05)


@pytest.fixture(scope="module")
def truth_points(scene):
    """Roof vertices (apex, ridge ends) and ground points of the scene."""
    verts = np.vstack([b.vertices(scene.base_height(i)) for i, b in enumerate(scene.buildings)])
    rng = np.random.default_rng(3)
    e = rng.uniform(BOUNDS[0] + 10, BOUNDS[2] - 10, 60)
    n = rng.uniform(BOUNDS[1] + 10, BOUNDS[3] - 10, 60)
    h, lab = scene.surface(e, n)
    ground = np.column_stack([e, n, h])[lab < 2]
    # keep the ground points the photo sees (the scene's own ray caster decides)
    from lidarcat.mapping.monoplot import ray_directions

    d = ray_directions(CAM, EO, _pixels(ground))
    t = scene.hit(EO[:3], d)
    seen = t[:, 1] < 0
    return verts, ground[seen]


@pytest.mark.parametrize("method", ["exact", "iterate"])
def test_tin_roof_vertices_and_ground_within_1_5_ground_pixels(tin, truth_points, method):
    verts, ground = truth_points
    pts = np.vstack([verts, ground])
    res = monoplot(_pixels(pts), CAM, EO, tin, method=method)
    assert res.status.tolist() == ["ok"] * len(pts)
    err = np.hypot(*(res.enh[:, :2] - pts[:, :2]).T)
    assert err.max() <= 1.5 * GSD_M
    assert len(verts) == 6 and len(ground) > 30


def test_grid_interpolators_and_exact_agree_with_iteration_on_the_terrain(scene, truth_points):
    _, ground = truth_points
    grid, t = scene.grid(BOUNDS, 0.5, "dsm")
    for interp in ("bilinear", "nearest"):
        surf = GridSurface(grid, t, interp)
        a = monoplot(_pixels(ground), CAM, EO, surf, method="exact", tol_m=1e-4)
        b = monoplot(_pixels(ground), CAM, EO, surf, method="iterate", tol_m=1e-4)
        assert (a.status == "ok").all() and (b.status == "ok").all()
        assert np.abs(a.enh - b.enh).max() < 0.01
        # bilinear on a smooth terrain: far inside a ground pixel
        if interp == "bilinear":
            assert np.hypot(*(a.enh[:, :2] - ground[:, :2]).T).max() < 0.1 * GSD_M


def test_occluded_ground_point_first_hit_is_the_visible_roof_and_iteration_is_flagged(scene):
    """A ground point hidden behind a building: the exact ray gives the roof the pixel shows
    (which reprojects to the same pixel); the paper's iteration, which would converge to
    the hidden ground point, is flagged ``occluded`` and gives no coordinates."""
    from lidarcat.mapping.monoplot import ray_directions

    grid, t = scene.grid(BOUNDS, 0.25, "dsm")
    surf = GridSurface(grid, t, "bilinear")
    eo = EO.copy()
    eo[0] = E0 - 250.0                     # the scene 250 m east of nadir: buildings lean east
    # ground points just east of each building (away from the camera)
    cands = []
    for b in scene.buildings:
        fp = b.footprint()
        e, n = np.meshgrid(np.linspace(fp[:, 0].max() + 0.5, fp[:, 0].max() + 4, 8),
                           b.n_m + np.array([-2.0, 0.0, 2.0]))
        h, lab = scene.surface(e.ravel(), n.ravel())
        cands.append(np.column_stack([e.ravel(), n.ravel(), h])[lab < 2])
    cands = np.vstack(cands)
    px = _pixels(cands, eo)
    d = ray_directions(CAM, eo, px)
    hit = scene.hit(eo[:3], d)
    # hidden: the ray is still inside the building 0.5 m (plan) past where it enters it
    t_in = hit[:, 0] + 0.5 / np.hypot(d[:, 0], d[:, 1])
    inside = eo[2] + t_in * d[:, 2] < scene.dsm(eo[0] + t_in * d[:, 0], eo[1] + t_in * d[:, 1]) - 0.5
    hidden = (hit[:, 1] >= 0) & inside
    assert hidden.sum() >= 10
    pts, px = cands[hidden], px[hidden]
    exact = monoplot(px, CAM, eo, surf, method="exact", tol_m=1e-4)
    assert (exact.status == "ok").all()
    assert (exact.enh[:, 2] > pts[:, 2] + 2.0).all()                       # on the building
    np.testing.assert_allclose(_pixels(exact.enh, eo), px, atol=1e-3)          # on the same ray
    true_h = scene.dsm(exact.enh[:, 0], exact.enh[:, 1])                    # the visible surface
    assert np.abs(exact.enh[:, 2] - true_h).max() < 0.3
    it = monoplot(px, CAM, eo, surf, method="iterate", tol_m=1e-4)
    assert set(it.status) <= {"occluded", "ok", "not_converged"}
    assert (it.status == "occluded").sum() >= 1
    on_ground = it.enh[it.status == "ok"]
    assert (on_ground[:, 2] > pts[it.status == "ok", 2] + 2.0).all()        # ok only on the roof
    assert np.isnan(it.enh[it.status != "ok"]).all()


def test_statuses_outside_photo_outside_surface_no_intersection(scene):
    grid, t = scene.grid((E0 - 20, N0 - 20, E0 + 20, N0 + 20), 0.5, "dsm")
    surf = GridSurface(grid, t, "bilinear")
    inside = _pixels(np.array([[E0, N0, float(scene.dsm(E0, N0))]]))[0]
    far = _pixels(np.array([[E0 + 60, N0 + 40, 905.0]]))[0]           # on the photo, off the surface
    px = np.array([inside, far, [-5.0, 10.0], [10.0, CAM.rows_px + 3.0], [np.nan, 1.0]])
    res = monoplot(px, CAM, EO, surf)
    assert res.status.tolist() == ["ok", "outside_surface", "outside_photo", "outside_photo",
                                   "outside_photo"]
    assert np.isnan(res.enh[1:]).all() and np.isnan(res.sd[1:]).all()
    up = EO.copy()
    up[3] = math.pi                                                      # camera looking up
    res = monoplot(px[:1], CAM, up, surf)
    assert res.status.tolist() == ["no_intersection"]
    assert res.counts() == {"no_intersection": 1}


def test_iteration_oscillates_on_a_wall_exact_finds_it():
    """A 50 m step seen obliquely: the fixed point jumps between the foot and the top."""
    g = np.zeros((40, 160))
    g[:, 80:] = 50.0                                    # east part 50 m higher, wall at E = 20
    surf = GridSurface(g, GeoTransform(-60.0, 40.0, 1.0), "nearest")
    cam = Camera("c", 50.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.01, 0.01, 1001, 1001)
    eo = np.array([-300.0, 20.0, 300.0, 0.0, math.radians(-45.0), 0.0])   # looking east, 45 deg down
    wall = np.array([[20.0, 20.0, 25.0]])
    px = _pixels(wall, eo, cam)
    it = monoplot(px, cam, eo, surf, method="iterate", max_iter=30)
    assert it.status.tolist() == ["not_converged"] and it.n_iter.tolist() == [30]
    ex = monoplot(px, cam, eo, surf, method="exact", tol_m=1e-5)
    assert ex.status.tolist() == ["ok"]
    np.testing.assert_allclose(ex.enh[0], wall[0], atol=1e-3)


def test_iteration_from_the_ground_lands_behind_a_roof_edge_from_the_top_on_it():
    """A roof point 0.3 m inside the far edge of a 10 m box, its ray leaving the roof as it descends:
    the paper's iteration started on the ground below the camera converges on the ground behind the
    building (a fixed point the ray never reaches: flagged occluded); started at the top of the surface
    it comes down onto the roof, where the first hit is."""
    g = np.zeros((40, 160))
    g[10:30, 60:80] = 10.0                              # E 0..20, N 10..30, roof at 10 m
    surf = GridSurface(g, GeoTransform(-60.0, 40.0, 1.0), "nearest")
    cam = Camera("c", 50.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.01, 0.01, 1001, 1001)
    eo = np.array([-5.0, 20.0, 300.0, 0.0, 0.0, 0.0])   # vertical photo, nadir on the ground west of it
    roof = np.array([[19.7, 20.0, 10.0]])
    px = _pixels(roof, eo, cam)
    ground = monoplot(px, cam, eo, surf, method="iterate")
    assert ground.status.tolist() == ["occluded"] and np.isnan(ground.enh).all()
    top = monoplot(px, cam, eo, surf, method="iterate", start="top")
    ex = monoplot(px, cam, eo, surf, method="exact", tol_m=1e-5)
    assert top.status.tolist() == ex.status.tolist() == ["ok"]
    np.testing.assert_allclose(top.enh[0], roof[0], atol=1e-6)
    np.testing.assert_allclose(ex.enh[0], roof[0], atol=1e-3)
    with pytest.raises(MonoplotError, match="start must be 'nadir' or 'top', got 'roof'"):
        monoplot(px, cam, eo, surf, method="iterate", start="roof")


def test_tin_point_location_walk_agrees_with_scipy_find_simplex():
    """The vectorised walk finds the triangle scipy's find_simplex finds, inside and outside the hull
    (NaN), and the TIN height is the plane of that triangle."""
    rng = np.random.default_rng(5)
    xyz = np.column_stack([rng.uniform(E0, E0 + 60, 3000), rng.uniform(N0, N0 + 40, 3000), rng.normal(900, 3, 3000)])
    surf = PointSurface(xyz, "tin")
    q = np.column_stack([rng.uniform(-40, 40, 20000), rng.uniform(-30, 30, 20000)])   # centred; ~1/3 outside
    q[:3] = np.nan
    found, w = surf._locate(q)
    want = surf._tri.find_simplex(np.where(np.isfinite(q), q, 1e9))
    assert (want < 0).sum() > 5000 and np.array_equal(found, want)
    ins = found >= 0
    np.testing.assert_allclose(w[ins].sum(axis=1), 1.0, atol=1e-12)
    v = surf._tri.points[surf._tri.simplices[found[ins]]]                    # (m, 3, 2) plan vertices
    np.testing.assert_allclose(np.einsum("mk,mkj->mj", w[ins], v), q[ins], atol=1e-9)
    h = surf.height(q[:, 0] + surf._origin[0], q[:, 1] + surf._origin[1])
    assert np.isnan(h[~ins]).all() and np.isfinite(h[ins]).all()


def test_propagated_sd_matches_the_closed_form_on_a_flat_ground():
    """Vertical photo over a plane h = 0 from 1000 m, c = 50 mm, 10 um pixels (0.2 m GSD):
    a pixel sd of 0.5 px is 0.1 m on the ground; an sd of Z0 moves a point r metres from
    nadir by r / H per metre; the surface sd moves it by the same ratio."""
    g = np.zeros((300, 300))
    surf = GridSurface(g, GeoTransform(-150.0, 150.0, 1.0), "bilinear", sd_m=0.2)
    cam = Camera("c", 50.0, 0, 0, 0, 0, 0, 0, 0, 0, 0.01, 0.01, 1001, 1001)
    eo = np.zeros(6)
    eo[2] = 1000.0
    pts = np.array([[0.0, 0.0, 0.0], [80.0, 0.0, 0.0], [0.0, -60.0, 0.0]])
    px = _pixels(pts, eo, cam)
    res = monoplot(px, cam, eo, surf, image_sd_px=0.5, eo_cov=np.zeros((6, 6)))
    np.testing.assert_allclose(res.enh, pts, atol=1e-3)
    r = np.array([0.0, 80.0, 60.0])
    want_e = np.hypot(0.1, 0.2 * np.array([0.0, 80.0, 0.0]) / 1000)
    want_n = np.hypot(0.1, 0.2 * np.array([0.0, 0.0, 60.0]) / 1000)
    np.testing.assert_allclose(res.sd[:, 0], want_e, rtol=1e-3)
    np.testing.assert_allclose(res.sd[:, 1], want_n, rtol=1e-3)
    np.testing.assert_allclose(res.sd[:, 2], 0.2, rtol=1e-6)            # the plane's own sd
    cov = np.zeros((6, 6))
    cov[2, 2] = 0.5 ** 2
    res = monoplot(px, cam, eo, surf.__class__(g, surf.transform, "bilinear", sd_m=0.0),
                   image_sd_px=0.0, eo_cov=cov)
    np.testing.assert_allclose(np.hypot(res.sd[:, 0], res.sd[:, 1]), 0.5 * r / 1000, atol=1e-7)


def test_read_orientations_from_eop_csv_diagonal_covariance(tmp_path):
    eos = read_orientations(DATA / "report" / "eop.csv")
    e1 = eos["1"]
    np.testing.assert_allclose(e1.params[:3], [677344.86, 7183454.439, 2255.938])
    np.testing.assert_allclose(np.degrees(e1.params[3:]), [-4.76844, -2.31709, 67.05276])
    np.testing.assert_allclose(np.sqrt(np.diag(e1.cov))[:3], [2.429, 4.219, 0.732])
    np.testing.assert_allclose(np.degrees(np.sqrt(np.diag(e1.cov))[3:]), [0.17916, 0.09894, 0.02848])
    assert np.count_nonzero(e1.cov - np.diag(np.diag(e1.cov))) == 0
    with pytest.raises(SurveyError, match=r"nope\.csv: no such orientation file"):
        read_orientations(DATA / "nope.csv")
    (tmp_path / "eop.csv").write_text("photo,X0,Y0,Z0,omega,phi,kappa\nA,1,2,3,0,0,0\nB,1,2,3,0,0,0\n"
                                      "A,1,2,3,0,0,0\n")
    with pytest.raises(SurveyError) as ei:
        read_orientations(tmp_path / "eop.csv")
    assert str(ei.value) == f"{tmp_path / 'eop.csv'}:4: field 'photo': photo 'A' is given twice"


def test_bad_inputs_are_located_errors():
    g = np.zeros((3, 3))
    t = GeoTransform(0.0, 3.0, 1.0)
    with pytest.raises(MonoplotError, match=r"^grid interpolator must be one of nearest, bilinear, got 'tin' "
                                            r"\(tin works on LiDAR points: PointSurface\)$"):
        GridSurface(g, t, "tin")
    with pytest.raises(MonoplotError, match=r"^point interpolator must be one of nearest, tin, got 'bilinear'"):
        PointSurface(np.random.default_rng(0).uniform(0, 1, (10, 3)), "bilinear")
    with pytest.raises(MonoplotError, match="surface grid holds no finite height"):
        GridSurface(np.full((2, 2), np.nan), t)
    with pytest.raises(MonoplotError, match=r"method must be 'exact' or 'iterate', got 'newton'"):
        monoplot([[0.0, 0.0]], CAM, EO, GridSurface(g, t), method="newton")
    with pytest.raises(MonoplotError, match=r"colrow_px must have shape \(N, 2\), got \(2, 3\)"):
        monoplot(np.zeros((2, 3)), CAM, EO, GridSurface(g, t))
    assert issubclass(MonoplotError, LidarcatError) and issubclass(MonoplotError, ValueError)
