"""Bundle adjustment: model, solver, precision, datum checks, thesis reproduction (issue 3).

Published values: Fierro Sanhueza (2007) Table 6 (errata applied), Appendix 2.1,
Appendix 3.1 and Table 7 (tests/data/thesis).  Tolerances are those of issue 3.
"""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import THESIS_SURVEY, THESIS_TABLES

from lidarcat.bundle.approx import approximations, planimetric_block
from lidarcat.geometry.collinearity import project, project_with_jacobians, rotation_matrix
from lidarcat.synthetic.block import synthetic_block
from lidarcat.bundle import BundleProblem, ExteriorOrientation, adjust, check_datum, chi2_bounds
from lidarcat.survey import problem_from_survey
from lidarcat.errors import DatumError
from lidarcat.survey.folder import Survey
from lidarcat.testing import assert_poses_close

EO_COLS = ["X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg"]


def _rows(path):
    with open(path, encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _table6():
    rows = {r["photo"]: r for r in _rows(THESIS_TABLES / "table6_eop_gps.csv")}
    ids = sorted(rows)
    val = np.array([[float(rows[i][c]) for c in EO_COLS] for i in ids])
    sd = np.array([[float(rows[i]["sd_" + c]) for c in EO_COLS] for i in ids])
    return ids, val, sd


def _eo_deg(result):
    return np.c_[result.eo_params[:, :3], np.degrees(result.eo_params[:, 3:])]


def _eo_sd_deg(result):
    sd = result.eo_sd
    return np.c_[sd[:, :3], np.degrees(sd[:, 3:])]


@pytest.fixture(scope="module")
def survey():
    return Survey.load(THESIS_SURVEY)


@pytest.fixture(scope="module")
def gps_problem(survey):
    return problem_from_survey(survey, control="gps", observations="corrected")


@pytest.fixture(scope="module")
def gps(gps_problem):
    return adjust(gps_problem)


@pytest.fixture(scope="module")
def gps_pixel(survey):
    return adjust(problem_from_survey(survey, control="gps", observations="pixel"))


@pytest.fixture(scope="module")
def lidar_problem(survey):
    return problem_from_survey(survey, control="lidar", observations="corrected")


# --------------------------------------------------------------------------- model


def test_rotation_is_r3_r2_r1():
    om, ph, ka = np.radians([3.0, -2.0, 68.0])
    r1 = np.array([[1, 0, 0], [0, np.cos(om), np.sin(om)], [0, -np.sin(om), np.cos(om)]])
    r2 = np.array([[np.cos(ph), 0, -np.sin(ph)], [0, 1, 0], [np.sin(ph), 0, np.cos(ph)]])
    r3 = np.array([[np.cos(ka), np.sin(ka), 0], [-np.sin(ka), np.cos(ka), 0], [0, 0, 1]])
    m = rotation_matrix([om, ph, ka])
    np.testing.assert_allclose(m, r3 @ r2 @ r1, atol=1e-15)
    np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-15)


def test_collinearity_vertical_photo():
    # camera 1000 m above a point 100 m east: x = -c * u1/u3 = 50 mm * 100/1000 = 5 mm (x right)
    eo = np.array([[0.0, 0.0, 1000.0, 0.0, 0.0, 0.0]])
    xy, u3 = project(eo, np.array([[100.0, -50.0, 0.0]]), np.array([50.0]))
    np.testing.assert_allclose(xy, [[5.0, -2.5]], atol=1e-12)
    assert u3[0] < 0


def test_jacobians_match_finite_differences():
    rng = np.random.default_rng(3)
    n = 20
    eo = np.c_[rng.normal(0, 50, (n, 2)), 1500 + rng.normal(0, 20, n), rng.normal(0, 0.1, (n, 2)),
               rng.uniform(-np.pi, np.pi, n)]
    xyz = np.c_[rng.normal(0, 300, (n, 2)), rng.normal(0, 30, n)]
    c = np.full(n, 51.902)
    xy, a_eo, a_pt, _ = project_with_jacobians(eo, xyz, c)
    for k in range(6):
        h = 1e-3 if k < 3 else 1e-7
        e1, e2 = eo.copy(), eo.copy()
        e1[:, k] += h
        e2[:, k] -= h
        num = (project(e1, xyz, c)[0] - project(e2, xyz, c)[0]) / (2 * h)
        np.testing.assert_allclose(a_eo[:, :, k], num, rtol=1e-6, atol=1e-9)
    for k in range(3):
        x1, x2 = xyz.copy(), xyz.copy()
        x1[:, k] += 1e-3
        x2[:, k] -= 1e-3
        num = (project(eo, x1, c)[0] - project(eo, x2, c)[0]) / 2e-3
        np.testing.assert_allclose(a_pt[:, :, k], num, rtol=1e-6, atol=1e-9)


def test_exterior_orientation_is_frozen():
    eo = ExteriorOrientation([1.0, 2.0, 3.0], [0.1, 0.2, 0.3], photo="7")
    with pytest.raises(ValueError):
        eo.position_m[0] = 5.0
    np.testing.assert_allclose(eo.params, [1, 2, 3, 0.1, 0.2, 0.3])
    # camera 1000 m above a point 100 m east, 50 m south: x = 50 mm * 100 / 1000 (x right, y up)
    vertical = ExteriorOrientation([0.0, 0.0, 1000.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(vertical.project([[100.0, -50.0, 0.0]], 50.0), [[5.0, -2.5]], atol=1e-12)
    assert np.isnan(eo.sd).all()
    with pytest.raises(ValueError, match="not finite"):
        ExteriorOrientation([np.nan, 0, 0], [0, 0, 0])


def test_problem_validation():
    kw = dict(photo_ids=["a", "b"], point_ids=["1"], focal_length_mm=50.0, photo_index=[0, 1],
              point_index=[0, 0], xy_mm=[[0, 0], [1, 1]], sd_mm=0.005, constraint_point_index=[],
              constraint_enh_m=np.zeros((0, 3)), constraint_sd_m=np.zeros((0, 3)))
    BundleProblem(**kw)
    with pytest.raises(ValueError, match="duplicate photo id"):
        BundleProblem(**{**kw, "photo_ids": ["a", "a"]})
    with pytest.raises(ValueError, match="`sd_mm` must be positive"):
        BundleProblem(**{**kw, "sd_mm": 0.0})
    with pytest.raises(ValueError, match=r"^`point_index` out of range of `point_ids`: 1 \(there are 1\)$"):
        BundleProblem(**{**kw, "point_index": [0, 1]})
    # a negative index would silently wrap to the last point
    with pytest.raises(ValueError, match=r"^`constraint_point_index` out of range of `point_ids`: -1 "):
        BundleProblem(**{**kw, "constraint_point_index": [-1], "constraint_enh_m": np.zeros((1, 3)),
                         "constraint_sd_m": 0.1})
    with pytest.raises(ValueError, match=r"^`constraint_sd_m` must be positive \(use inf for a free axis\)$"):
        BundleProblem(**{**kw, "constraint_point_index": [0], "constraint_enh_m": np.zeros((1, 3)),
                         "constraint_sd_m": [0.1, 0.0, 0.1]})
    eo = dict(eo_constraint_photo_index=[2], eo_constraint_params=np.zeros((1, 6)), eo_constraint_sd=1.0)
    with pytest.raises(ValueError, match=r"^`eo_constraint_photo_index` out of range of `photo_ids`: 2 "):
        BundleProblem(**kw, **eo)
    with pytest.raises(ValueError, match=r"^`eo_constraint_sd` must be positive \(use inf for a free "):
        BundleProblem(**kw, **{**eo, "eo_constraint_photo_index": [1], "eo_constraint_sd": 0.0})


def test_chi2_bounds_exact_and_fisher():
    b = chi2_bounds(128, 0.05)
    np.testing.assert_allclose([b["lower"], b["upper"]], [98.58, 161.21], atol=0.005)
    # Appendix 2.1 prints Fisher's approximation
    app2 = json.loads((THESIS_TABLES / "appendix2_1_gps.json").read_text())["2.1_gps"]
    np.testing.assert_allclose([b["lower_fisher"], b["upper_fisher"]], app2["chi2_range_5pct"], atol=0.005)


# --------------------------------------------------------------------------- thesis, GPS run


def test_gps_problem_counts(gps_problem):
    p = gps_problem
    assert (p.n_photos, p.n_points) == (6, 54)
    assert (p.n_observations, p.n_unknowns, p.n_constraints) == (302, 198, 24)
    assert p.dof == 128
    assert "417" not in set(p.point_ids)


def test_gps_run_summary(gps):
    app2 = json.loads((THESIS_TABLES / "appendix2_1_gps.json").read_text())["2.1_gps"]
    assert gps.success, gps.message
    assert gps.dof == app2["dof"] == 128
    assert abs(gps.vtpv - app2["chi2_computed"]) < 0.5
    assert abs(gps.sigma0_sq - app2["variance_a_posteriori"]) < 0.01
    assert gps.chi2["passed"]
    s = gps.summary()
    # "desvio padrao medio dos pontos fixos": sqrt(sum v^2 / (n - 1)) of the control residuals
    np.testing.assert_allclose([s["sd_control_residuals_m"][k] for k in "ENh"],
                               [app2["mean_std_fixed_points_m"][k] for k in "ENh"], atol=0.0015)
    # "desvio padrao medio dos pontos livres" 0.264 / 0.216 / 1.057: the RMS sd over all 54 points
    # (printed to 1 mm; the thesis sds are 0.9985 of ours, errata.json); the mean over the 46 free
    # points (0.259 / 0.214 / 1.090) is not it
    np.testing.assert_allclose([s["rms_sd_points_m"][k] for k in "ENh"],
                               [app2["mean_std_free_points_m"][k] for k in "ENh"], atol=0.0015)


def test_gps_run_rms_image_residuals(gps):
    app2 = json.loads((THESIS_TABLES / "appendix2_1_gps.json").read_text())["2.1_gps"]["mean_std_obs_mm"]
    rms = gps.rms_residuals_per_photo()
    for i, photo in enumerate(gps.photo_ids):
        for k, axis in enumerate(("x_mm", "y_mm")):
            printed = app2[photo][axis]
            if (photo, axis) == ("4", "y_mm"):
                printed = 0.0054  # errata.json: printed 0.006
            assert abs(rms[i, k] - printed) <= 0.0006, (photo, axis, rms[i, k], printed)


def test_gps_run_exterior_orientation_table6(gps):
    ids, val, sd = _table6()
    assert list(gps.photo_ids) == ids
    d = np.abs(_eo_deg(gps) - val)
    assert d[:, :2].max() < 0.10
    assert d[:, 2].max() < 0.03
    assert d[:, 3:].max() < 0.005
    np.testing.assert_allclose(_eo_sd_deg(gps), sd, rtol=0.02)
    # the same through the pose helper (metres, radians)
    assert_poses_close(gps.exterior_orientations, np.c_[val[:, :3], np.radians(val[:, 3:])],
                       atol_m=0.10, atol_rad=np.radians(0.005))


def test_gps_run_points_appendix3(gps):
    rows = _rows(THESIS_TABLES / "appendix3_1_points_gps.csv")
    assert len(rows) == 54
    ids = list(gps.point_ids)
    idx = [ids.index(r["point"]) for r in rows]
    ref = np.array([[float(r[k]) for k in "ENh"] for r in rows])
    ref_sd = np.array([[float(r["sd_" + k]) for k in "ENh"] for r in rows])
    d = np.abs(gps.points_m[idx] - ref)
    assert d[:, :2].max() < 0.03
    assert d[:, 2].max() < 0.12
    np.testing.assert_allclose(gps.point_sd_m[idx], ref_sd, rtol=0.02)
    fixed = {r["point"] for r in rows if r["role"] == "control"}
    assert fixed == {q for q, r in zip(gps.point_ids, gps.point_role) if r == "control"}


def test_gps_run_check_points_table7(gps, survey):
    rows = [r for r in _rows(THESIS_TABLES / "table7_check_gps.csv") if r["point"] not in ("mean", "std")]
    assert len(rows) == 13
    gp = survey.ground_points
    ref = {q: gp.enh_m[i] for i, q in enumerate(gp.point)}
    d = np.array([ref[r["point"]] - gps.point(r["point"]) for r in rows])   # reference minus adjusted
    printed = np.array([[float(r[k]) for k in ("dE", "dN", "dh")] for r in rows])
    assert np.abs(d - printed)[:, :2].max() < 0.03
    assert np.abs(d - printed)[:, 2].max() < 0.12
    assert {r["point"] for r in rows} == {q for q, r in zip(gps.point_ids, gps.point_role) if r == "check"}


def test_result_lookup_by_id(gps):
    np.testing.assert_array_equal(gps.point("601"), gps.points_m[list(gps.point_ids).index("601")])
    assert gps.eo("4").photo == "4"
    np.testing.assert_array_equal(gps.eo("4").params, gps.eo_params[3])
    with pytest.raises(ValueError, match="^point 'zz' is not in the adjustment$"):
        gps.point("zz")
    with pytest.raises(ValueError, match="^photo '9' is not in the adjustment$"):
        gps.eo(9)


def test_variance_factor_a_posteriori_scales_sds(gps_problem, gps):
    post = adjust(gps_problem, variance_factor="a_posteriori")
    np.testing.assert_allclose(post.eo_sd, gps.eo_sd * np.sqrt(gps.sigma0_sq), rtol=1e-9)
    np.testing.assert_allclose(post.point_sd_m, gps.point_sd_m * np.sqrt(gps.sigma0_sq), rtol=1e-9)


def test_gps_pixel_run_side_by_side(gps, gps_pixel):
    """The pixel coordinates through interior orientation: Table 6 within 0.3 m / 0.015 deg."""
    _, val, _ = _table6()
    assert gps_pixel.success
    assert gps_pixel.dof == 128
    d = np.abs(_eo_deg(gps_pixel) - val)
    assert d[:, :3].max() < 0.3
    assert d[:, 3:].max() < 0.015
    # the printed corrected coordinates reproduce Table 6 more closely than the pixels
    assert np.abs(_eo_deg(gps) - val)[:, :2].max() < d[:, :2].max()


def test_lidar_run_converges(lidar_problem):
    """Section 4.3.2 is withheld (blind test); the set-up the thesis states is checked."""
    r = adjust(lidar_problem)
    assert r.success, r.message
    assert r.dof == 128
    control = r.point_role == "control"
    assert set(r.point_ids[control]) == {"701", "703", "705", "706", "707", "712", "719", "721"}
    # sigma 0.50 m in E, N and 0.15 m in h (section 4.2.3); a constraint can only sharpen them
    np.testing.assert_array_equal(lidar_problem.constraint_sd_m, np.tile([0.5, 0.5, 0.15], (8, 1)))
    assert np.all(r.point_sd_m[control] < [0.5, 0.5, 0.15])
    # all 21 GPS points free and checked, the 15 pass points free
    gps_points = [q for q in r.point_ids if q.startswith("6")]
    assert len(gps_points) == 21 and set(r.point_role[np.isin(r.point_ids, gps_points)]) == {"check"}
    assert set(r.point_ids[r.point_role == "tie"]) == {q for q in r.point_ids if q.startswith("4")}
    assert (r.point_role == "tie").sum() == 15
    assert r.chi2["passed"]


# --------------------------------------------------------------------------- approximations, convergence


@pytest.mark.parametrize("control", ["gps", "lidar"])
def test_converges_from_computed_approximations(survey, control, gps):
    p = problem_from_survey(survey, control=control)
    eo0, pts0 = approximations(p)
    _, val, _ = _table6()
    # the approximations are approximations, not the answer
    assert np.abs(eo0[:, :3] - val[:, :3]).max() > 1.0
    r = adjust(p, initial=(eo0, pts0))
    assert r.success and r.n_iter <= 15
    if control == "gps":
        assert abs(r.vtpv - gps.vtpv) < 1e-6
        assert_poses_close(r.eo_params, gps.eo_params, atol_m=1e-4, atol_rad=1e-9)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("control", ["gps", "lidar"])
def test_converges_from_perturbed_approximations(survey, control, seed):
    p = problem_from_survey(survey, control=control)
    eo0, pts0 = approximations(p)
    reference = adjust(p, initial=(eo0, pts0))
    rng = np.random.default_rng(seed)
    eo = eo0.copy()
    eo[:, :3] += rng.choice([-200.0, 200.0], size=(p.n_photos, 3))
    eo[:, 3:5] += np.radians(rng.choice([-5.0, 5.0], size=(p.n_photos, 2)))
    eo[:, 5] += np.radians(rng.choice([-20.0, 20.0], size=p.n_photos))
    r = adjust(p, initial=(eo, pts0), damping=True, max_iter=100)
    assert r.success, r.message
    assert abs(r.vtpv - reference.vtpv) < 1e-6
    assert_poses_close(r.eo_params, reference.eo_params, atol_m=1e-3, atol_rad=1e-8)


def test_planimetric_block_recovers_kappa_and_height():
    b = synthetic_block(2, 6, seed=4)
    eo = planimetric_block(b.problem)
    dk = (eo[:, 5] - b.true_eo[:, 5] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(np.degrees(dk)).max() < 3.0
    assert np.abs(eo[:, 2] - b.true_eo[:, 2]).max() < 60.0


def test_non_convergence_is_a_status(gps_problem):
    r = adjust(gps_problem, max_iter=1)
    assert r.status == "max_iterations" and not r.success
    assert "maximum number of iterations" in r.message
    assert r.n_iter == 1


def test_singular_system_is_a_status():
    b = synthetic_block(1, 4, seed=2)
    p = b.problem
    free = BundleProblem(p.photo_ids, p.point_ids, p.focal_length_mm, p.photo_index, p.point_index,
                         p.xy_mm, p.sd_mm, [], np.zeros((0, 3)), np.zeros((0, 3)))
    r = adjust(free, initial=(b.true_eo, b.true_points_m), check=False)
    assert r.status == "singular" and not r.success
    assert np.isnan(r.eo_sd).all()


# --------------------------------------------------------------------------- synthetic blocks


def test_synthetic_exact_observations_recover_truth():
    b = synthetic_block(2, 6, seed=11, noise=False)
    r = adjust(b.problem)
    assert r.success
    assert r.vtpv < 1e-10
    assert_poses_close(r.eo_params, b.true_eo, atol_m=1e-5, atol_rad=1e-9)
    np.testing.assert_allclose(r.points_m, b.true_points_m, atol=1e-5)


@pytest.mark.parametrize("seed", [1, 2])
def test_synthetic_block_truth_within_3_sigma(seed):
    b = synthetic_block(3, 8, seed=seed)
    r = adjust(b.problem)
    assert r.success
    d = r.eo_params - b.true_eo
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    z_eo = d / r.eo_sd
    z_pt = (r.points_m - b.true_points_m) / r.point_sd_m
    z = np.concatenate([z_eo.ravel(), z_pt.ravel()])
    # normal errors: >= 99 % within 3 sigma (expected 99.73 %), none beyond 4.5 sigma, RMS ~ 1
    assert np.mean(np.abs(z) <= 3) >= 0.99
    assert np.abs(z).max() < 4.5
    assert 0.85 < np.sqrt(np.mean(z**2)) < 1.15
    assert np.mean(np.abs(z_eo) <= 3) >= 0.98
    # the variance factor passes its chi-square test
    assert r.chi2["lower"] <= r.vtpv <= r.chi2["upper"]
    assert abs(r.sigma0_sq - 1) < 3 * np.sqrt(2 / r.dof)


def _dense_inverse(r):
    """N^-1 of the whole (unreduced) normal matrix J'PJ at the solution, built densely: the
    reference for the selected and joint inverses (photos first, then points)."""
    p = r.problem
    n_ph, n_pt = p.n_photos, p.n_points
    ei, pj = p.photo_index, p.point_index
    _, a_eo, a_pt, _ = project_with_jacobians(r.eo_params[ei], r.points_m[pj], p.focal_length_mm[ei])
    nrow = 2 * len(ei) + 3 * len(p.constraint_point_index)
    J = np.zeros((nrow, 6 * n_ph + 3 * n_pt))
    w = np.zeros(nrow)
    for k, (i, j) in enumerate(zip(ei, pj)):
        J[2 * k:2 * k + 2, 6 * i:6 * i + 6] = a_eo[k]
        J[2 * k:2 * k + 2, 6 * n_ph + 3 * j:6 * n_ph + 3 * j + 3] = a_pt[k]
        w[2 * k:2 * k + 2] = 1.0 / p.sd_mm[k] ** 2
    for m, (j, sd) in enumerate(zip(p.constraint_point_index, p.constraint_sd_m)):
        row = 2 * len(ei) + 3 * m
        J[row:row + 3, 6 * n_ph + 3 * j:6 * n_ph + 3 * j + 3] = np.eye(3)
        w[row:row + 3] = 1.0 / sd ** 2
    return np.linalg.inv(J.T @ (w[:, None] * J))


def test_selected_inverse_equals_dense_inverse():
    b = synthetic_block(2, 4, seed=5, point_spacing_m=120.0)
    p = b.problem
    r = adjust(p)
    n_ph, n_pt = p.n_photos, p.n_points
    Q = _dense_inverse(r)
    from lidarcat.bundle import NormalSystem, observation_blocks

    # the 9 x 9 blocks [eo_i, X_j] of every observation, photo-point cross blocks included
    ob = observation_blocks(NormalSystem(p, r.eo_params, r.points_m))
    for k, (i, j) in enumerate(zip(p.photo_index, p.point_index)):
        idx = np.r_[6 * i:6 * i + 6, 6 * n_ph + 3 * j:6 * n_ph + 3 * j + 3]
        ref = Q[np.ix_(idx, idx)]
        np.testing.assert_allclose(ob[k], ref, rtol=0, atol=1e-6 * np.abs(ref).max())
    for i in range(n_ph):
        np.testing.assert_allclose(r.eo_cov[i], Q[6 * i:6 * i + 6, 6 * i:6 * i + 6], rtol=1e-6, atol=1e-14)
    for j in range(n_pt):
        o = 6 * n_ph + 3 * j
        np.testing.assert_allclose(r.point_cov[j], Q[o:o + 3, o:o + 3], rtol=1e-6, atol=1e-12)


def _gnss_ins_block(seed: int, sd: np.ndarray):
    """A synthetic block with no control points, every photo's X0..kappa observed with noise of
    sigma *sd* (m, rad), those observations also the approximations: (block, problem, observations)."""
    b = synthetic_block(2, 5, seed=seed)
    p = b.problem
    obs = b.true_eo + np.random.default_rng(seed).normal(0, 1, b.true_eo.shape) * sd
    kw = {f: getattr(p, f) for f in ("photo_ids", "point_ids", "focal_length_mm", "photo_index",
                                     "point_index", "xy_mm", "sd_mm")}
    q = BundleProblem(**kw, constraint_point_index=[], constraint_enh_m=np.zeros((0, 3)),
                      constraint_sd_m=np.zeros((0, 3)), eo_constraint_photo_index=np.arange(p.n_photos),
                      eo_constraint_params=obs, eo_constraint_sd=np.broadcast_to(sd, (p.n_photos, 6)),
                      initial_eo=obs)
    return b, q, obs


def test_eo_constraints_are_weighted():
    sd = np.array([0.05, 0.05, 0.05, np.radians(0.002), np.radians(0.002), np.radians(0.002)])
    b, q, obs = _gnss_ins_block(8, sd)
    assert q.n_constraints == 6 * q.n_photos
    r = adjust(q)
    assert r.success
    assert np.all(r.eo_sd < sd)                       # the images sharpen every observed parameter
    d = r.eo_params - b.true_eo
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    assert np.abs(d / r.eo_sd).max() < 3.5            # 60 parameters against the truth
    np.testing.assert_allclose(r.eo_constraint_residuals, r.eo_params - obs, atol=1e-12)


# --------------------------------------------------------------------------- datum checks


def _subset(p: BundleProblem, keep_obs=None, compact=False, drop=(), **changes) -> BundleProblem:
    """*p* with only the observations *keep_obs* (mask), without the rows *drop*, and *changes*."""
    keep = np.ones(len(p.photo_index), dtype=bool) if keep_obs is None else np.array(keep_obs)
    keep[np.asarray(drop, dtype=np.int64)] = False
    kw = dict(photo_ids=p.photo_ids, point_ids=p.point_ids, focal_length_mm=p.focal_length_mm,
              photo_index=p.photo_index[keep], point_index=p.point_index[keep], xy_mm=p.xy_mm[keep],
              sd_mm=p.sd_mm[keep], constraint_point_index=p.constraint_point_index,
              constraint_enh_m=p.constraint_enh_m, constraint_sd_m=p.constraint_sd_m)
    kw.update(changes)
    if compact:  # drop points measured on no photo
        used = np.zeros(len(p.point_ids), dtype=bool)
        used[kw["point_index"]] = True
        new = np.cumsum(used) - 1
        kw["point_ids"] = p.point_ids[used]
        kw["point_index"] = new[kw["point_index"]]
        kw["constraint_point_index"] = new[np.asarray(kw["constraint_point_index"], dtype=int)]
    return BundleProblem(**kw)


def test_datum_ok_for_thesis(gps_problem, lidar_problem):
    check_datum(gps_problem)
    check_datum(lidar_problem)


def test_datum_photo_with_too_few_points(gps_problem):
    p = gps_problem
    on6 = np.flatnonzero(p.photo_index == list(p.photo_ids).index("6"))
    # points left with one ray must not mask the photo error: the photo check comes first
    with pytest.raises(DatumError, match=r"photo '6' has 2 measured point\(s\); at least 3"):
        adjust(_subset(p, drop=on6[2:]))


def test_datum_point_on_one_photo(gps_problem):
    p = gps_problem
    j = list(p.point_ids).index("401")   # pass point on photos 1 and 2
    rows = np.flatnonzero(p.point_index == j)
    with pytest.raises(DatumError, match=r"point '401' is seen on one photo only \('1'\)"):
        check_datum(_subset(p, drop=rows[1:]))


def test_datum_point_on_no_photo(gps_problem):
    p = gps_problem
    keep = p.point_index != list(p.point_ids).index("401")
    with pytest.raises(DatumError, match=r"point '401' is measured on no photo"):
        check_datum(_subset(p, keep))


def test_datum_control_point_on_one_photo_is_fine():
    b = synthetic_block(2, 4, seed=3)
    p = b.problem
    j = int(p.constraint_point_index[0])
    rows = np.flatnonzero(p.point_index == j)
    q = _subset(p, drop=rows[1:])
    check_datum(q)
    r = adjust(q)                               # determined by its constraint
    assert r.success
    assert np.all(r.point_sd_m[j] <= p.constraint_sd_m[0] * (1 + 1e-9))


def test_datum_no_control(gps_problem):
    p = _subset(gps_problem, constraint_point_index=[], constraint_enh_m=np.zeros((0, 3)),
                constraint_sd_m=np.zeros((0, 3)))
    with pytest.raises(DatumError, match="no control in the block: datum defect of 7"):
        adjust(p)


def test_datum_too_little_control(gps_problem):
    p = _subset(gps_problem, constraint_point_index=gps_problem.constraint_point_index[:2],
                constraint_enh_m=gps_problem.constraint_enh_m[:2],
                constraint_sd_m=gps_problem.constraint_sd_m[:2])
    with pytest.raises(DatumError, match=r"too little control in the block: 2 point\(s\) with E, N and 2 "
                                         r"with h \(601, 604\)"):
        adjust(p)


def test_datum_coincident_planimetric_control(gps_problem):
    p = gps_problem
    sd = np.array(p.constraint_sd_m)
    sd[2:, :2] = np.inf                         # E, N held on the first two control points only
    enh = np.array(p.constraint_enh_m)
    enh[1, :2] = enh[0, :2]                     # ... at the same place
    names = ", ".join(p.point_ids[p.constraint_point_index[:2]])
    assert names == "601, 604"
    with pytest.raises(DatumError, match=r"^planimetric control points coincide in the block: 601, 604; the "
                                         r"block can turn about them \(give control at distinct places\)$"):
        check_datum(_subset(p, constraint_enh_m=enh, constraint_sd_m=sd))


def test_datum_collinear_control():
    b = synthetic_block(2, 6, seed=6)
    p = b.problem
    truth = b.true_points_m
    # three points on one line through the block: the block could roll about it
    pts = np.flatnonzero(np.bincount(p.point_index, minlength=p.n_points) >= 2)
    a, c = truth[pts[0]], truth[pts[-1]]
    t = ((truth[pts, :2] - a[:2]) @ (c[:2] - a[:2])) / np.sum((c[:2] - a[:2]) ** 2)
    off = np.linalg.norm(truth[pts, :2] - (a[:2] + t[:, None] * (c[:2] - a[:2])), axis=1)
    mid = pts[np.argsort(off + 1e3 * (np.abs(t - 0.5) > 0.4))[2]]
    chosen = np.array([pts[0], mid, pts[-1]])
    enh = truth[chosen].copy()
    # put the middle point exactly on the line
    tm = ((enh[1, :2] - a[:2]) @ (c[:2] - a[:2])) / np.sum((c[:2] - a[:2]) ** 2)
    enh[1, :2] = a[:2] + tm * (c[:2] - a[:2])
    q = _subset(p, constraint_point_index=chosen, constraint_enh_m=enh,
                constraint_sd_m=np.full((3, 3), 0.1))
    names = ", ".join(p.point_ids[chosen])
    with pytest.raises(DatumError, match=f"on a line in the block: {names}"):
        check_datum(q)


def test_datum_disconnected_part_without_control():
    b = synthetic_block(1, 6, seed=9)
    p = b.problem
    # cut the strip between photos 3 and 4: drop every point seen on both sides
    left = p.photo_index < 3
    pts_left = set(p.point_index[left])
    pts_right = set(p.point_index[~left])
    shared = np.array(sorted(pts_left & pts_right))
    keep = ~np.isin(p.point_index, shared)
    ctrl_left = np.array([j for j in p.constraint_point_index if j in pts_left and j not in pts_right])
    rows = [list(p.constraint_point_index).index(j) for j in ctrl_left]
    q = _subset(p, keep, compact=True, constraint_point_index=ctrl_left,
                constraint_enh_m=p.constraint_enh_m[rows], constraint_sd_m=p.constraint_sd_m[rows])
    with pytest.raises(DatumError, match=r"no control in the part of the block with photo\(s\) 0004, 0005, 0006"):
        check_datum(q)


# --------------------------------------------------------------------------- photos.csv orientation, testing helper


def test_photo_orientation_of_the_survey_is_used_and_constrained(tmp_path, gps):
    import shutil

    folder = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, folder)
    # GNSS-like camera positions: the GPS-run centres shifted by 3 m east, sigma 5 m; no attitude
    lines = ["photo,camera,X0,Y0,Z0,sd_X0,sd_Y0,sd_Z0"]
    for pid, e in zip(gps.photo_ids, gps.eo_params):
        lines.append(f"{pid},dcs14n,{e[0] + 3.0:.3f},{e[1]:.3f},{e[2]:.3f},5,5,5")
    (folder / "photos.csv").write_text("\n".join(lines) + "\n")
    s = Survey.load(folder)
    plain = problem_from_survey(s, "gps")
    assert plain.eo_constraint_photo_index is None and plain.dof == 128
    np.testing.assert_allclose(plain.initial_eo[:, 0], gps.eo_params[:, 0] + 3.0, atol=1e-3)
    assert np.isnan(plain.initial_eo[:, 3:]).all()
    con = problem_from_survey(s, "gps", eo_constraints=True)
    assert con.n_constraints == 24 + 18 and con.dof == 128 + 18
    r = adjust(con)
    assert r.success
    # the constraints pull X0 east, by less than the 3 m shift; residuals adjusted - observed ~ -shift
    dx = r.eo_params[:, 0] - gps.eo_params[:, 0]
    assert np.all(dx > 0) and np.all(dx < 3.0)
    np.testing.assert_allclose(r.eo_constraint_residuals[:, 0], dx - 3.0, atol=6e-4)  # 3-decimal file
    assert np.all(r.eo_sd[:, 0] < gps.eo_sd[:, 0])


def test_given_orientation_is_kept_by_approximations(gps_problem):
    # a GNSS/INS-like orientation for photo 3: computed approximation + 10 m and 0.5 deg
    computed, _ = approximations(gps_problem)
    start = np.full((6, 6), np.nan)
    start[2] = computed[2] + [10.0, -10.0, 10.0, np.radians(0.5), np.radians(-0.5), np.radians(0.5)]
    p = BundleProblem(**{f: getattr(gps_problem, f) for f in (
        "photo_ids", "point_ids", "focal_length_mm", "photo_index", "point_index", "xy_mm", "sd_mm",
        "constraint_point_index", "constraint_enh_m", "constraint_sd_m")}, initial_eo=start)
    eo, _ = approximations(p)
    np.testing.assert_array_equal(eo[2], start[2])
    assert adjust(p).success


def test_assert_poses_close_messages():
    a = [ExteriorOrientation([0.0, 0.0, 1000.0], [0.0, 0.0, np.pi], photo="12"),
         ExteriorOrientation([5.0, 0.0, 1000.0], [0.0, 0.01, 0.0], photo="13")]
    b = np.array([[0.0, 0.0, 1000.0, 0.0, 0.0, -np.pi], [5.0, 0.3, 1000.0, 0.0, 0.01, 0.0]])
    assert_poses_close(a, b, atol_m=0.5, atol_rad=1e-12)
    with pytest.raises(AssertionError, match=r"worst photo 13 Y0: .* 0\.3 m > 0\.1 m"):
        assert_poses_close(a, b, atol_m=0.1, atol_rad=1e-12)
    with pytest.raises(AssertionError, match="shape mismatch"):
        assert_poses_close(a, b[:1], atol_m=1, atol_rad=1)
    # arrays are named by row index, a single orientation by its photo id
    with pytest.raises(AssertionError, match=r"^poses differ: 1 value\(s\) beyond tolerance; "
                                             r"worst photo 1 Y0"):
        assert_poses_close(np.array([e.params for e in a]), b, atol_m=0.1, atol_rad=1e-12)
    with pytest.raises(AssertionError, match=r"^check: poses differ: 1 value\(s\) beyond tolerance; worst photo 13 "
                                             r"phi: .* > 0\.001 rad$"):
        assert_poses_close(a[1], b[1] + [0, 0, 0, 0, 0.002, 0], atol_m=1, atol_rad=1e-3, err_msg="check:")


def test_datum_point_measured_twice_on_a_photo(gps_problem):
    p = gps_problem
    k = 5
    q = BundleProblem(p.photo_ids, p.point_ids, p.focal_length_mm, np.r_[p.photo_index, p.photo_index[k]],
                      np.r_[p.point_index, p.point_index[k]], np.r_[p.xy_mm, p.xy_mm[k:k + 1]],
                      np.r_[p.sd_mm, p.sd_mm[k:k + 1]], p.constraint_point_index, p.constraint_enh_m,
                      p.constraint_sd_m)
    with pytest.raises(DatumError, match=f"point '{p.point_ids[p.point_index[k]]}' is measured twice on "
                                         f"photo '{p.photo_ids[p.photo_index[k]]}'"):
        check_datum(q)
    # two repeated pairs, the later observation's repeat first: the earliest observation is named
    q = BundleProblem(p.photo_ids, p.point_ids, p.focal_length_mm, np.r_[p.photo_index, p.photo_index[[9, 3]]],
                      np.r_[p.point_index, p.point_index[[9, 3]]], np.r_[p.xy_mm, p.xy_mm[[9, 3]]],
                      np.r_[p.sd_mm, p.sd_mm[[9, 3]]], p.constraint_point_index, p.constraint_enh_m,
                      p.constraint_sd_m)
    with pytest.raises(DatumError, match=f"point '{p.point_ids[p.point_index[3]]}' is measured twice on "
                                         f"photo '{p.photo_ids[p.photo_index[3]]}'"):
        check_datum(q)


def test_synthetic_100_photo_block_from_computed_approximations():
    b = synthetic_block(4, 25, seed=21)
    p = b.problem
    assert p.n_photos == 100
    r = adjust(p)
    assert r.success and r.n_iter <= 15
    d = r.eo_params - b.true_eo
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    z = np.concatenate([(d / r.eo_sd).ravel(), ((r.points_m - b.true_points_m) / r.point_sd_m).ravel()])
    assert np.mean(np.abs(z) <= 3) >= 0.99
    assert 0.9 < np.sqrt(np.mean(z**2)) < 1.1
    assert r.chi2["lower"] <= r.vtpv <= r.chi2["upper"]


def test_synthetic_block_from_perturbed_approximations():
    b = synthetic_block(2, 8, seed=13)
    p = b.problem
    eo0, pts0 = approximations(p)
    reference = adjust(p, initial=(eo0, pts0))
    rng = np.random.default_rng(13)
    eo = eo0.copy()
    eo[:, :3] += rng.choice([-200.0, 200.0], size=(p.n_photos, 3))
    eo[:, 3:5] += np.radians(rng.choice([-5.0, 5.0], size=(p.n_photos, 2)))
    eo[:, 5] += np.radians(rng.choice([-20.0, 20.0], size=p.n_photos))
    r = adjust(p, initial=(eo, pts0), max_iter=100)
    assert r.success, r.message
    np.testing.assert_allclose(r.vtpv, reference.vtpv, rtol=1e-9)
    assert_poses_close(r.eo_params, reference.eo_params, atol_m=1e-3, atol_rad=1e-8)


def test_gnss_ins_datum_without_control_points():
    """Full camera constraints (position and attitude) give the datum; approximations come from them."""
    b, q, _ = _gnss_ins_block(17, np.array([0.1, 0.1, 0.1, np.radians(0.005), np.radians(0.005),
                                            np.radians(0.01)]))
    r = adjust(q)
    assert r.success
    z = (r.points_m - b.true_points_m) / r.point_sd_m
    assert np.mean(np.abs(z) <= 3) >= 0.99


# --------------------------------------------------------------------------- joint covariance of points


def test_joint_point_covariance_equals_the_dense_inverse():
    from lidarcat.bundle import joint_point_covariance

    b = synthetic_block(2, 4, seed=3)
    r = adjust(b.problem)
    assert r.success
    ids = [str(q) for q in r.point_ids]
    pick = [ids[k] for k in (40, 3, 17, 25, 8)]           # any order, batches smaller than 3k
    C = joint_point_covariance(r, pick, batch=4)
    full = _dense_inverse(r)[6 * r.problem.n_photos:, 6 * r.problem.n_photos:]
    sel = np.concatenate([[3 * ids.index(q) + c for c in range(3)] for q in pick])
    np.testing.assert_allclose(C, full[np.ix_(sel, sel)], rtol=1e-7, atol=1e-12)
    for a, q in enumerate(pick):   # its diagonal blocks are the per-point covariances
        np.testing.assert_allclose(C[3 * a:3 * a + 3, 3 * a:3 * a + 3], r.point_cov[ids.index(q)], rtol=1e-7)
    assert abs(full[np.ix_(sel, sel)][0, 3]) > 1e-3 * np.sqrt(full[sel[0], sel[0]] * full[sel[3], sel[3]])
    with pytest.raises(DatumError, match="not in the adjustment: nope"):
        joint_point_covariance(r, ["nope"])


@pytest.mark.slow
def test_joint_covariance_makes_the_point_chi_square_exact():
    """d' C^-1 d of 20 free points against the truth ~ chi2(60) over 80 blocks; the sum of
    per-coordinate z^2 (correlations ignored) has the same mean but is over-dispersed."""
    from scipy import stats

    from lidarcat.bundle import joint_point_covariance

    joint, diag = [], []
    for seed in range(80):
        b = synthetic_block(2, 4, seed=seed, control_every=4)
        r = adjust(b.problem)
        assert r.success
        free = np.flatnonzero(r.point_role != "control")[:20]
        C = joint_point_covariance(r, [str(q) for q in r.point_ids[free]])
        d = (r.points_m[free] - b.true_points_m[free]).ravel()
        joint.append(d @ np.linalg.solve(C, d))
        diag.append(np.sum(d ** 2 / np.diag(C)))
    joint, diag = np.array(joint), np.array(diag)
    assert stats.kstest(joint, stats.chi2(60).cdf).pvalue > 0.01
    assert abs(joint.mean() - 60) < 3 * np.sqrt(120 / 80)
    assert diag.var() > 2 * joint.var()   # correlated points: the diagonal statistic is no chi2(60)


def test_adjust_writes_the_check_point_covariance(tmp_path, gps):
    from lidarcat.bundle import joint_point_covariance
    from lidarcat.survey import read_point_covariance, write_adjustment

    r = gps
    write_adjustment(r, tmp_path)
    checks = [str(q) for q, role in zip(r.point_ids, r.point_role) if role == "check"]
    assert len(checks) == 13
    path = tmp_path / "check_covariance.csv"
    assert len(_rows(path)) == 13 * 14 // 2               # one row per pair a <= b
    ids, C = read_point_covariance(path)
    assert ids == checks
    np.testing.assert_allclose(C, joint_point_covariance(r, checks), rtol=1e-12)   # repr floats: exact
    pick = [checks[12], checks[0], checks[5]]
    sub_ids, sub = read_point_covariance(path, points=pick)
    assert sub_ids == pick
    sel = np.concatenate([[3 * checks.index(q) + c for c in range(3)] for q in pick])
    np.testing.assert_array_equal(sub, C[np.ix_(sel, sel)])


def test_read_point_covariance_errors_name_the_file_line_and_points(tmp_path, gps):
    from lidarcat.survey import read_point_covariance, write_adjustment
    from lidarcat.errors import AssessmentError, SurveyError

    write_adjustment(gps, tmp_path)
    path = tmp_path / "check_covariance.csv"
    text = path.read_text()
    lines = text.splitlines()
    head = sum(1 for line in lines if line.startswith("#")) + 1     # comment lines + header
    first = lines[head].split(",")                                  # the first point with itself
    assert first[0] == first[1] == "603"
    with pytest.raises(AssessmentError, match=r"check_covariance\.csv: no covariance for point\(s\) zz; the "
                                              r"file holds 13 check point\(s\) of its adjustment$"):
        read_point_covariance(path, points=["603", "zz"])
    bad = tmp_path / "bad.csv"
    bad.write_text(text + lines[head + 1] + "\n")
    with pytest.raises(AssessmentError, match=rf"bad\.csv:{len(lines) + 1}: a second row for the pair "
                                              rf"603, {lines[head + 1].split(',')[1]} \(first at line {head + 2}\)"):
        read_point_covariance(bad)
    bad.write_text("\n".join(lines[:head + 1] + lines[head + 2:]) + "\n")
    with pytest.raises(AssessmentError, match=rf"bad\.csv: no row for the pair 603, "
                                              rf"{lines[head + 1].split(',')[1]}; the file must hold"):
        read_point_covariance(bad)
    bad.write_text("\n".join(lines[:head] + [",".join(first[:2] + ["-1"] + first[3:])]
                             + lines[head + 1:]) + "\n")
    with pytest.raises(AssessmentError, match=rf"bad\.csv:{head + 1}: point 603: the variances c_EE, c_NN, "
                                              "c_hh must be positive"):
        read_point_covariance(bad)
    bad.write_text("\n".join(lines[:head] + [",".join(first[:3] + ["x"] + first[4:])]
                             + lines[head + 1:]) + "\n")
    with pytest.raises(SurveyError, match=rf"bad\.csv:{head + 1}: field 'c_EN': 'x' is not a number"):
        read_point_covariance(bad)
    with pytest.raises(SurveyError, match=r"nothing\.csv: file not found"):
        read_point_covariance(tmp_path / "nothing.csv")
