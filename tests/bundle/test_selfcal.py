"""Self-calibration, frame offsets and their significance (issue 13).

Synthetic truth: :func:`lidarcat.synthetic.block.selfcal_block` (a camera off
its certificate by known c, x0, y0, K1; LiDAR control shifted by a known
0.3 / -0.2 / 0.4 m).  Jacobians are checked by central finite differences, the
bordered solve and its precision against the dense normal equations.
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from scipy import stats

from lidarcat.synthetic.block import selfcal_block, synthetic_block
from lidarcat.bundle import adjust
from lidarcat.bundle.additional import (AdditionalParameterError, GnssLineOffsets, SelfCalibration,
                                        parse_parameters)
from lidarcat.bundle.frame_offset import FrameOffset, frame_offset_from_sources
from lidarcat.bundle.linear import Schur
from lidarcat.geometry.collinearity import project
from lidarcat.bundle.selfcal import _BorderedSystem, _Globals, _State, adjust_with_parameters
from lidarcat.geometry.camera import Camera


def _components(b, params="c,x0,y0,k1", similarity=False):
    p = b.problem
    return [SelfCalibration({"cam": b.camera}, ["cam"] * p.n_photos, params),
            frame_offset_from_sources(p, b.control_source, "lidar", "gps", similarity=similarity)]


@pytest.fixture(scope="module")
def block():
    return selfcal_block(1)


@pytest.fixture(scope="module")
def solved(block):
    return adjust_with_parameters(block.problem, _components(block))


# ---------------------------------------------------------------------------
# model: Jacobians by finite differences
# ---------------------------------------------------------------------------


def _residual_and_jacobian(gl, eo, pts, theta):
    """Stacked residuals (image, control, camera constraints) and their Jacobian wrt theta."""
    def resid(t):
        bs = _BorderedSystem(gl, eo, pts, t, Schur(gl.problem.photo_index, gl.problem.point_index,
                                                    gl.problem.n_photos, gl.problem.n_points))
        parts = [bs.sys.r_obs.ravel(), bs.sys.r_con.ravel()]
        if bs.sys.r_eo is not None:
            parts.append(bs.sys.r_eo.ravel())
        return np.concatenate(parts), bs
    return resid


def test_io_and_frame_jacobians_match_finite_differences():
    # a camera with every distortion term non-zero, all 8 IO parameters and the 7-parameter frame
    b = selfcal_block(3, n_strips=2, photos_per_strip=4, noise=False)
    cam = Camera("cam", 50.0, 0.02, -0.03, -3e-5, 2e-8, -1e-11, 4e-6, -3e-6, 0.0, 0.006, 0.006, 6000, 4000,
                 sd={"sd_k1": 1e-6})
    b = dataclasses.replace(b, camera=cam)
    gl = _Globals(_components(b, "all", similarity=True), b.problem)
    p = b.problem
    eo, pts = np.array(b.block.true_eo), np.array(b.block.true_points_m)
    theta = np.array([0.05, 0.01, -0.02, 2e-6, -1e-9, 3e-12, 1e-6, -2e-6, 0.3, -0.2, 0.4, 5.0, 3.0, -4.0, 6.0])
    resid = _residual_and_jacobian(gl, eo, pts, theta)
    r0, bs = resid(theta)
    # analytic: dense Jacobian from the components
    n_obs, n_con = 2 * len(p.photo_index), 3 * len(p.constraint_point_index)
    A = np.zeros((len(r0), gl.k))
    xy, _ = project(eo, pts[p.point_index], bs.pe.focal_length_mm[p.photo_index], p.photo_index)
    for part, o in zip(gl.parts, gl.offsets):
        for kind, rows, J, cols in part.jacobians(theta[o:o + part.n], _State(bs.pe, xy)):
            d = J.shape[1]
            base = {"obs": 0, "con": n_obs, "eo": n_obs + n_con}[kind]
            for a in range(J.shape[2]):
                for c in range(d):
                    np.add.at(A, (base + rows * d + c, o + cols[:, a]), J[:, c, a])
    steps = np.array([1e-4, 1e-4, 1e-4, 1e-8, 1e-11, 1e-14, 1e-7, 1e-7, 1e-3, 1e-3, 1e-3, 10.0, 10.0, 10.0, 10.0])
    for i in range(gl.k):
        e = np.zeros(gl.k)
        e[i] = steps[i]
        fd = (resid(theta + e)[0] - resid(theta - e)[0]) / (2 * steps[i])
        scale = np.abs(fd).max()
        assert scale > 0, gl.names[i]
        np.testing.assert_allclose(A[:, i], fd, atol=1e-6 * scale, err_msg=gl.names[i])


def test_gnss_line_offset_jacobian_and_recovery():
    # the camera on its certificate, no frame shift: the line offset is the only systematic error
    b = selfcal_block(4, n_strips=2, photos_per_strip=6, dc_mm=0, dx0_mm=0, dy0_mm=0, dk1=0, shift_m=(0, 0, 0))
    p = b.problem
    lines = [str(i // 6) for i in range(p.n_photos)]
    # antenna offset of line "1": the GNSS positions of its photos are off by a known vector
    off = np.array([0.4, -0.3, 0.25])
    gnss = np.array(p.eo_constraint_params)
    gnss[6:, :3] += off
    p2 = dataclasses.replace(p, eo_constraint_params=gnss)
    res = adjust_with_parameters(p2, [GnssLineOffsets(lines)])
    est = np.array([res.estimates[res.index(f"gnss.1.offset_{c}")] for c in "ENh"])
    sd = np.array([res.sd[res.index(f"gnss.1.offset_{c}")] for c in "ENh"])
    assert np.all(np.abs(est - off) < 3 * sd), (est, sd)
    assert np.all(sd < 0.1)
    assert res.bundle.vtpv < res.without.vtpv - 100
    assert res.group_tests()[1]["significant"] and not res.group_tests()[0]["significant"]
    # a drift of line "0": 0.2 / -0.1 / 0.3 m per km along the line (tau from its centre, photo order)
    drift = np.array([0.2, -0.1, 0.3])
    xy = np.asarray(p.eo_constraint_params)[:6, :2]
    d = xy - xy.mean(axis=0)
    axis = (d[-1] - d[0]) / np.linalg.norm(d[-1] - d[0])
    tau = d @ axis / 1000.0
    gnss = np.array(p.eo_constraint_params)
    gnss[:6, :3] += tau[:, None] * drift
    res = adjust_with_parameters(dataclasses.replace(p, eo_constraint_params=gnss),
                                 [GnssLineOffsets(lines, drift=True)])
    est = res.estimates[[res.index(f"gnss.0.drift_{c}") for c in "ENh"]]
    sd = res.sd[[res.index(f"gnss.0.drift_{c}") for c in "ENh"]]
    assert np.all(np.abs(est - drift) < 3 * sd) and np.all(sd < 0.2), (est, sd)
    with pytest.raises(AdditionalParameterError, match="need constrained camera positions"):
        GnssLineOffsets(lines[:8]).bind(synthetic_block(2, 4).problem)


# ---------------------------------------------------------------------------
# linear algebra: bordered Schur step and precision against the dense normal equations
# ---------------------------------------------------------------------------


def _dense_normal(bs, p):
    """The full normal matrix [[U, N_cg, W], [., N_gg, N_gp], [., ., V]] (cameras, points, globals)."""
    P, Q, k = p.n_photos, p.n_points, bs.gl.k
    o, og = 6 * P, 6 * P + 3 * Q
    N = np.zeros((og + k, og + k))
    for i in range(P):
        N[6 * i:6 * i + 6, 6 * i:6 * i + 6] = bs.sys.U[i]
    for j in range(Q):
        N[o + 3 * j:o + 3 * j + 3, o + 3 * j:o + 3 * j + 3] = bs.sys.V[j]
    for a, (i, j) in enumerate(zip(p.photo_index, p.point_index)):
        N[6 * i:6 * i + 6, o + 3 * j:o + 3 * j + 3] += bs.sys.W[a]
        N[o + 3 * j:o + 3 * j + 3, 6 * i:6 * i + 6] += bs.sys.W[a].T
    N[:o, og:] = bs.Ncg.reshape(-1, k)
    N[o:og, og:] = bs.Npg.reshape(-1, k)
    N[og:, :og] = N[:og, og:].T
    N[og:, og:] = bs.Ngg
    return N


def test_bordered_step_and_covariance_equal_dense_inverse():
    b = selfcal_block(2, n_strips=2, photos_per_strip=4)
    p = b.problem
    gl = _Globals(_components(b), p)
    r0 = adjust(p, precision="none")
    eo, pts = np.array(r0.eo_params), np.array(r0.points_m)
    theta = np.array([0.05, 0.01, -0.01, 1e-6, 0.1, 0.1, 0.1])
    bs = _BorderedSystem(gl, eo, pts, theta, Schur(p.photo_index, p.point_index, p.n_photos, p.n_points))
    P, Q = p.n_photos, p.n_points
    o, og = 6 * P, 6 * P + 3 * Q
    N = _dense_normal(bs, p)
    g = np.r_[bs.sys.g_c.ravel(), bs.sys.g_p.ravel(), bs.gg]
    x = np.linalg.solve(N, -g)
    dc, dp, dg = bs.solve(0.0)
    np.testing.assert_allclose(dc.ravel(), x[:o], atol=1e-9 * np.abs(x[:o]).max())
    np.testing.assert_allclose(dp.ravel(), x[o:og], atol=1e-9 * np.abs(x[o:og]).max())
    np.testing.assert_allclose(dg, x[og:], rtol=1e-7)
    # precision at the solution
    res = adjust_with_parameters(p, _components(b), without=r0)
    bs = _BorderedSystem(gl, np.array(res.bundle.eo_params), np.array(res.bundle.points_m), res.estimates,
                         Schur(p.photo_index, p.point_index, P, Q))
    N = _dense_normal(bs, p)
    Ninv = np.linalg.inv(N)
    np.testing.assert_allclose(res.cov, Ninv[og:, og:], rtol=1e-6)
    for i in range(P):
        np.testing.assert_allclose(res.bundle.eo_cov[i], Ninv[6 * i:6 * i + 6, 6 * i:6 * i + 6], rtol=1e-5,
                                   atol=1e-12)
    for j in range(Q):
        np.testing.assert_allclose(res.bundle.point_cov[j], Ninv[o + 3 * j:o + 3 * j + 3, o + 3 * j:o + 3 * j + 3],
                                   rtol=1e-5, atol=1e-12)
    # joint covariance of two points, the rank-k term included
    a, b2 = 3, 10
    J = res.joint_point_covariance([p.point_ids[a], p.point_ids[b2]])
    np.testing.assert_allclose(J[:3, 3:], Ninv[o + 3 * a:o + 3 * a + 3, o + 3 * b2:o + 3 * b2 + 3], rtol=1e-5,
                               atol=1e-12)
    # correlation of the focal length with Z0 of photo 0
    sd_c = np.sqrt(np.diag(Ninv)[:o]).reshape(P, 6)
    r = Ninv[og, 2] / np.sqrt(Ninv[og, og]) / sd_c[0, 2]
    assert res.eo_correlation[0, 0, 2] == pytest.approx(r, abs=1e-8)


# ---------------------------------------------------------------------------
# acceptance on the synthetic block
# ---------------------------------------------------------------------------


def test_synthetic_truth_recovered_within_3_sd_and_shift_significant(block, solved):
    res = solved
    assert res.bundle.success
    truth = {f"cam.{k}": v for k, v in block.true_corrections.items()}
    truth.update({f"frame.lidar:gps.{c}": v for c, v in zip(("dE", "dN", "dh"), block.shift_m)})
    for name, true in truth.items():
        i = res.index(name)
        assert abs(res.estimates[i] - true) < 3 * res.sd[i], (name, res.estimates[i], true, res.sd[i])
        assert res.sd[i] < abs(true) / 2, name          # each one significantly determined
    fo = res.summary()["frame_offset"]
    assert fo["source"] == "lidar" and fo["reference"] == "gps"
    assert fo["significant"] and fo["test"]["p_value"] < 0.05
    assert all(fo["significant_per_axis"])
    assert res.warnings() == []
    tests = {t["name"]: t for t in res.tests()}
    assert all(t["significant"] and t["determinable"] for t in tests.values())
    # with the parameters off, v'Pv shows the misfit: the chi-square test of sigma0^2 fails
    off, on = res.without, res.bundle
    assert off.vtpv > 2 * on.vtpv
    assert not off.chi2["passed"] and on.chi2["passed"]
    assert on.dof == off.dof - 7


def test_residual_pattern_without_parameters_is_radial(block, solved):
    """Without K1 the image residuals carry the radial signature x r^2: their regression on it is
    significant off and vanishes on."""
    def slope_t(res):
        cam = block.camera
        fot = cam.photo_to_fot(np.asarray(block.problem.xy_mm))
        r2 = (fot**2).sum(axis=1)
        a = (fot * r2[:, None]).ravel()
        v = np.asarray(res.residuals_mm).ravel()
        beta = a @ v / (a @ a)
        s = np.sqrt(np.sum((v - beta * a) ** 2) / (len(v) - 1) / (a @ a))
        return beta / s
    assert abs(slope_t(solved.without)) > 10
    assert abs(slope_t(solved.bundle)) < 3


def test_undeterminable_focal_length_warns_and_still_returns(caplog, tmp_path):
    # no GNSS/INS, moderate relief, nadir: c trades against the flying height
    b = selfcal_block(5, n_strips=2, photos_per_strip=6, gnss_sd_m=None)
    p = b.problem
    with caplog.at_level(logging.WARNING, logger="lidarcat.bundle.selfcal"):
        res = adjust_with_parameters(p, [SelfCalibration({"cam": b.camera}, ["cam"] * p.n_photos, "c")])
    assert res.bundle.status == "converged"
    msg = [r.getMessage() for r in caplog.records]
    assert any("additional parameter 'cam.c' is not determinable" in m and "Z0 of photo" in m for m in msg), msg
    t = res.tests()[0]
    assert not t["determinable"] and abs(t["max_correlation_eo"]["r"]) > 0.95
    assert np.isfinite(t["estimate"]) and np.isfinite(t["sd"])
    assert res.summary()["warnings"] == res.warnings() != []
    # ... and still written
    import json
    from lidarcat.survey.selfcal import write_selfcal
    write_selfcal(res, tmp_path / "o")
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert s["warnings"] == res.warnings() and s["additional_parameters"]["cam.c"]["determinable"] is False
    assert (tmp_path / "o" / "eop.csv").is_file() and (tmp_path / "o" / "points.csv").is_file()


def test_singular_parameter_is_named_and_result_still_returned():
    # every control point shifted: the shift is a datum defect (the whole block moves with it)
    b = selfcal_block(7, n_strips=2, photos_per_strip=4, gnss_sd_m=None)
    p = b.problem
    res = adjust_with_parameters(p, [FrameOffset("all", "none", np.arange(len(p.constraint_point_index)))])
    assert res.bundle.status == "singular"
    w = res.warnings()
    assert len(w) == 1 and "additional parameter 'frame.all:none.d" in w[0] and "cannot be determined" in w[0]
    assert np.all(np.isnan(res.sd)) and len(res.tests()) == 3


def test_priors_from_certificate_and_free_parameters():
    b = selfcal_block(6, n_strips=2, photos_per_strip=4)
    cam = dataclasses.replace(b.camera, sd={"sd_focal_length_mm": 0.01, "sd_k1": 0.0})
    p = b.problem
    gl = _Globals([SelfCalibration({"cam": cam}, ["cam"] * p.n_photos, "c,k1")], p)
    assert gl.prior_sd[0] == 0.01 and np.isinf(gl.prior_sd[1])      # sd 0: free
    res = adjust_with_parameters(p, [SelfCalibration({"cam": cam}, ["cam"] * p.n_photos, "c,k1")])
    assert res.bundle.dof == res.without.dof - 2 + 1
    assert res.sd[0] < 0.01                                         # the prior bounds the sd
    assert parse_parameters("K1,c") == ("c", "k1")
    with pytest.raises(AdditionalParameterError, match="unknown self-calibration parameter 'f'; allowed: c, x0"):
        parse_parameters("c,f")
    with pytest.raises(AdditionalParameterError, match="no control point from source 'lidar'"):
        frame_offset_from_sources(p, ["gps"] * len(p.constraint_point_index), "lidar", "gps")
    with pytest.raises(AdditionalParameterError, match="has no control point"):
        FrameOffset("a", "b", [])


def test_monte_carlo_empirical_sd_matches_predicted():
    """A small honest version of the 50-seed run of benchmarks/bench_selfcal.py: over 10 seeds the
    standardised errors (estimate - truth) / sd of all 7 parameters (70 values) have a variance
    inside the two-sided 99.9 % chi-square interval of 1."""
    z = []
    for seed in range(10):
        b = selfcal_block(100 + seed, n_strips=2, photos_per_strip=6)
        res = adjust_with_parameters(b.problem, _components(b))
        truth = np.r_[[b.true_corrections[k] for k in ("c", "x0", "y0", "k1")], b.shift_m]
        z.append((res.estimates - truth) / res.sd)
    z = np.concatenate(z)
    n = len(z)
    q = float(np.sum(z**2))
    assert stats.chi2.ppf(0.0005, n) < q < stats.chi2.ppf(0.9995, n), q / n
    assert abs(z.mean()) < 4 / np.sqrt(n)


# ---------------------------------------------------------------------------
# the thesis block: both control sets and the LiDAR frame offset
# ---------------------------------------------------------------------------


def _table13():
    import csv
    from conftest import THESIS_TABLES
    with open(THESIS_TABLES / "table13_gps_points_lidar_run.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    return [r["point"] for r in rows], np.array([[float(r[c]) for c in ("dE", "dN", "dh")] for r in rows])


@pytest.fixture(scope="module")
def thesis_offset(tmp_path_factory):
    from lidarcat.survey.selfcal import adjust_survey_with_parameters
    from lidarcat.survey.folder import Survey
    survey = Survey.load()
    out = tmp_path_factory.mktemp("sc") / "out"
    res, _ = adjust_survey_with_parameters(survey, control="gps+lidar", frame_offset="lidar:gps", outdir=out)
    return survey, res, out


def test_thesis_frame_offset_beside_table12(thesis_offset):
    """Joint GPS + LiDAR control (0.25 m; 0.50 / 0.50 / 0.15 m, the thesis's sigmas): the shift of the
    LiDAR frame agrees with the thesis's Table 12 means (-0.32 / -0.20 / +0.37 m) within one sd, and
    with these sigmas it is not significant at 5 %."""
    import json
    from conftest import THESIS_TABLES
    _, res, out = thesis_offset
    t12 = json.loads((THESIS_TABLES / "table12_free_points.json").read_text())["text_line_1354"]
    mean = np.array([t12["mean_shift_E"], t12["mean_shift_N"], t12["mean_shift_h"]])
    s = json.loads((out / "summary.json").read_text())
    fo = s["frame_offset"]
    assert (fo["source"], fo["reference"]) == ("lidar", "gps")
    shift, sd = np.array(fo["shift_m"]), np.array(fo["sd_m"])
    assert np.all(np.abs(shift - mean) < sd), (shift, sd)
    assert np.all(np.sign(shift) == np.sign(mean))
    assert not fo["significant"] and fo["test"]["p_value"] > 0.05
    assert fo["test"]["dof"] == 3 and np.allclose(np.diag(fo["correlation"]), 1.0)
    assert s["dof"] == s["parameters_off"]["dof"] - 3 == 149
    assert s["parameters_on"]["vtpv"] < s["parameters_off"]["vtpv"]
    assert s["additional_parameters"] == {} and s["warnings"] == []


def test_thesis_lidar_run_with_corrected_control_beside_table13(thesis_offset):
    """The LiDAR-controlled run reproduces Table 13 (reference minus adjusted at the 21 GPS points,
    within the reproduction tolerance of 0.02 m in E, N and 0.12 m in h); moving the LiDAR control by
    the estimated shift removes the systematic E, N part: the mean goes to ~0 and the RMS drops."""
    from lidarcat.survey import problem_from_survey
    survey, res, _ = thesis_offset
    ids, t13 = _table13()
    p = problem_from_survey(survey, control="lidar")
    ref = survey.ground_points.enh_m[survey.ground_points.index(ids)]
    r0 = adjust(p, precision="none")
    shift = res.estimates[:3]
    r1 = adjust(dataclasses.replace(p, constraint_enh_m=np.asarray(p.constraint_enh_m) + shift), precision="none")
    d0 = ref - np.array([r0.point(i) for i in ids])
    d1 = ref - np.array([r1.point(i) for i in ids])
    assert np.all(np.abs(d0 - t13).max(axis=0) < [0.02, 0.02, 0.12])
    rms0, rms1 = np.sqrt((d0**2).mean(axis=0)), np.sqrt((d1**2).mean(axis=0))
    assert np.all(np.abs(d1.mean(axis=0)[:2]) < 0.05)
    assert np.all(rms1[:2] < rms0[:2] - 0.09)
    # the same shift lowers every height by +0.29 m: the h discrepancies grow (Table 13 mean -0.165 m)
    assert d1.mean(axis=0)[2] == pytest.approx(d0.mean(axis=0)[2] - shift[2], abs=0.05)


def test_cli_adjust_self_calibrate_and_frame_offset(tmp_path):
    import json
    from click.testing import CliRunner
    from lidarcat.cli.main import cli
    out = tmp_path / "o"
    r = CliRunner().invoke(cli, ["adjust", "--control", "gps+lidar", "--frame-offset", "lidar:gps",
                                 "--self-calibrate", "c,k1", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "Frame offset lidar -> gps" in r.output and "dcs14n.k1" in r.output
    s = json.loads((out / "summary.json").read_text())
    ap = s["additional_parameters"]
    assert set(ap) == {"dcs14n.c", "dcs14n.k1"}
    assert {"estimate", "sd", "t", "significant", "unit"} <= set(ap["dcs14n.c"])
    assert ap["dcs14n.c"]["unit"] == "mm" and ap["dcs14n.c"]["prior_sd"] == 0.032
    assert ap["dcs14n.c"]["sd"] <= 0.032
    # the command line: no --control, the sets holding LiDAR and GPS control are joined
    r = CliRunner().invoke(cli, ["adjust", "--self-calibrate", "c,x0,y0,k1,k2", "--frame-offset", "lidar:gps",
                                 "-o", str(tmp_path / "i"), "--json"])
    assert r.exit_code == 0, r.output
    s2 = json.loads(r.output)
    assert s2["control_set"] == "gps+lidar" and len(s2["additional_parameters"]) == 5
    assert s2["frame_offset"]["shift_m"] == pytest.approx(s["frame_offset"]["shift_m"], abs=0.05)
    r = CliRunner().invoke(cli, ["adjust", "--self-calibrate", "c,f", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2
    assert "unknown self-calibration parameter 'f'" in r.output
    assert not (tmp_path / "x").exists()
    r = CliRunner().invoke(cli, ["adjust", "--control", "gps", "--frame-offset", "lidar", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and "must be SOURCE:REFERENCE" in r.output


def test_survey_toml_self_calibration_table(tmp_path):
    import shutil
    from lidarcat.survey.selfcal import self_calibration_settings
    from lidarcat.errors import SurveyError
    from lidarcat.survey.folder import Survey, thesis_survey_path
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    toml = folder / "survey.toml"
    base = toml.read_text()
    toml.write_text(base + '\n[self_calibration]\nparameters = "k1,c"\nframe_offset = "lidar:gps"\n'
                    'control = "gps+lidar"\n')
    st = self_calibration_settings(Survey.load(folder))
    assert st.parameters == ("c", "k1") and st.frame_offset == ("lidar", "gps") and st.control == "gps+lidar"
    toml.write_text(base + '\n[self_calibration]\nparameters = "c,zz"\n')
    n = len(base.splitlines()) + 3
    with pytest.raises(SurveyError, match=rf"survey.toml:{n}: field 'parameters': unknown self-calibration "
                                          "parameter 'zz'"):
        self_calibration_settings(Survey.load(folder))


def test_run_report_shows_additional_parameters(tmp_path):
    import json
    import shutil
    from lidarcat.pipeline import run_pipeline
    from lidarcat.survey.folder import thesis_survey_path
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    with open(folder / "survey.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[self_calibration]\nparameters = "c"\nframe_offset = "lidar:gps"\ncontrol = "gps+lidar"\n')
    # no check points: the (slow) assess stages are skipped, the rest of the run is unchanged
    sets = (folder / "control_sets.csv").read_text().splitlines()
    (folder / "control_sets.csv").write_text("\n".join(r for r in sets if ",check," not in r) + "\n")
    res = run_pipeline(folder, tmp_path / "out")
    assert res.ok
    sc = res.summary["selfcal"]
    assert sc["control_set"] == "gps+lidar" and sc["frame_offset"]["source"] == "lidar"
    assert set(sc["additional_parameters"]) == {"dcs14n.c"}
    md = (tmp_path / "out" / "report" / "index.md").read_text()
    assert "## Additional parameters" in md and "| dcs14n.c | mm |" in md
    shift = sc["frame_offset"]["shift_m"]
    assert "| shift | " + " | ".join(f"{v:+.3f}" for v in shift) + " |" in md
    s = json.loads((tmp_path / "out" / "selfcal" / "summary.json").read_text())
    assert s["frame_offset"]["shift_m"] == shift


def test_survey_gnss_lines_without_camera_positions_named(tmp_path):
    """[self_calibration] gnss_lines on a survey whose photos.csv has no camera positions with sds:
    exit 2 with survey.toml's line and photos.csv named, nothing written."""
    import shutil

    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.survey.folder import thesis_survey_path
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    text = (folder / "survey.toml").read_text()
    (folder / "survey.toml").write_text(text + '\n[self_calibration]\ngnss_lines = { a = ["1", "2", "3"] }\n')
    line = text.count("\n") + 3
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2, r.output
    assert r.output == (f"Error: {folder / 'survey.toml'}:{line}: field 'gnss_lines': GNSS line offsets act on "
                        f"constrained camera positions, but no photo of {folder / 'photos.csv'} has X0, Y0, Z0 "
                        "with sd_X0, sd_Y0, sd_Z0\n")
    assert not (tmp_path / "out").exists()


def test_survey_gnss_lines_recover_an_antenna_offset(tmp_path):
    """The thesis block with GNSS camera positions (the GPS run's own, 0.10 m) whose second line
    (photos 4-6) is off by 0.5 / -0.4 / 0.6 m: [self_calibration.gnss_lines] finds it exactly (the
    positions are the adjustment's own, so no noise) -- and warns that in this 6-photo strip the
    offsets are not determinable: the projection centres are known to about a metre only (8 GPS
    points at 0.25 m), so an offset trades against them (r ~ -0.99)."""
    import shutil
    from lidarcat.survey.selfcal import selfcal_adjust
    from lidarcat.survey.folder import Survey, thesis_survey_path
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    from lidarcat.survey import problem_from_survey
    ref = adjust(problem_from_survey(Survey.load(folder), control="gps"), precision="none")
    off = np.array([0.5, -0.4, 0.6])
    rows = ["photo,camera,X0,Y0,Z0,sd_X0,sd_Y0,sd_Z0"]
    for i, (pid, eo) in enumerate(zip(ref.photo_ids, ref.eo_params)):
        x = eo[:3] + (off if i >= 3 else 0.0)
        rows.append(f"{pid},dcs14n,{x[0]:.3f},{x[1]:.3f},{x[2]:.3f},0.1,0.1,0.1")
    (folder / "photos.csv").write_text("\n".join(rows) + "\n")
    with open(folder / "survey.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[self_calibration]\ncontrol = "gps"\n\n[self_calibration.gnss_lines]\n'
                 'a = ["1", "2", "3"]\nb = ["4", "5", "6"]\n')
    _, res = selfcal_adjust(Survey.load(folder))
    est = res.estimates[[res.index(f"gnss.b.offset_{c}") for c in "ENh"]]
    sd = res.sd[[res.index(f"gnss.b.offset_{c}") for c in "ENh"]]
    np.testing.assert_allclose(est, off, atol=0.01)
    assert np.all(sd > 0.3)
    a = res.estimates[[res.index(f"gnss.a.offset_{c}") for c in "ENh"]]
    np.testing.assert_allclose(a, 0.0, atol=0.01)
    assert res.bundle.problem.info["eo_constraints"]
    w = res.warnings()
    assert len(w) == 6 and all("is not determinable" in m for m in w)
    assert "'gnss.b.offset_E' is not determinable from this block: correlated with X0 of photo" in w[3]


def test_thesis_free_focal_length_is_warned_and_written(tmp_path):
    """A real survey that cannot determine a switched-on parameter: the thesis strip with c free
    (no certificate prior) -- r = +1.000 with a flying height; the warning is in summary.json and in
    the CLI output, and the result folder is written."""
    import json
    import shutil
    from click.testing import CliRunner
    from lidarcat.cli.main import cli
    from lidarcat.survey.folder import thesis_survey_path
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    with open(folder / "survey.toml", "a", encoding="utf-8") as fh:
        fh.write('\n[self_calibration]\nparameters = "c"\nuse_priors = false\n')
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    assert "WARNING: additional parameter 'dcs14n.c' is not determinable from this block: correlated with Z0" \
        in r.output
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    c = s["additional_parameters"]["dcs14n.c"]
    assert not c["determinable"] and c["max_correlation_eo"]["parameter"] == "Z0"
    assert c["max_correlation_eo"]["r"] > 0.99
    assert c["prior_sd"] is None and s["warnings"]
    assert (tmp_path / "o" / "eop.csv").is_file()


def test_similarity_frame_offset_recovered_on_exact_data():
    """Noise-free block whose LiDAR control is off by a shift, 40 ppm of scale and rotations of
    50 / -30 / 80 urad: the 7-parameter frame offset returns them (to the linearisation, 1e-3)."""
    b = selfcal_block(8, noise=False, dc_mm=0, dx0_mm=0, dy0_mm=0, dk1=0)
    p = b.problem
    lid = np.array(b.control_source) == "lidar"
    truth = b.block.true_points_m[np.asarray(p.constraint_point_index)[lid]]
    shift, scale, eps = np.array([0.3, -0.2, 0.4]), 40.0, np.array([50.0, -30.0, 80.0])
    d = truth - truth.mean(axis=0)
    src = truth - shift - 1e-6 * (scale * d + np.cross(eps, d))        # X_ref = X_s + t + 1e-6 (s dX + eps x dX)
    c = np.asarray(p.constraint_enh_m).copy()
    c[lid] = src
    p2 = dataclasses.replace(p, constraint_enh_m=c)
    res = adjust_with_parameters(p2, [frame_offset_from_sources(p2, b.control_source, "lidar", "gps",
                                                                similarity=True)])
    est = res.estimates
    np.testing.assert_allclose(est[:3], shift, atol=2e-3)
    assert est[3] == pytest.approx(scale, abs=1.0)
    np.testing.assert_allclose(est[4:], eps, atol=1.0)
    fo = res.summary()["frame_offset"]
    assert fo["parameters"] == ["dE", "dN", "dh", "scale", "rot_E", "rot_N", "rot_h"]
    assert fo["scale_ppm"]["estimate"] == pytest.approx(scale, abs=1.0) and len(fo["correlation"]) == 7
