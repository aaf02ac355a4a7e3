"""Named self-calibration parameter sets in the bundle (issue 27): ``--self-calibrate ebner``.

Synthetic truth: the block of :func:`lidarcat.synthetic.block.synthetic_block` photographed by a
camera whose image carries a known Ebner distortion ``A(x_fot; theta)``
(:mod:`lidarcat.geometry.apsets`); the certificate has none.  The measured coordinates are the
solution of ``x_fot - A(x_fot) = x_true`` (fixed point, 1e-12 mm) plus noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.bundle.additional import AdditionalParameterError, SelfCalibration, parse_parameters
from lidarcat.bundle.selfcal import adjust_with_parameters
from lidarcat.geometry.apsets import parameter_set
from lidarcat.geometry.camera import Camera
from lidarcat.geometry.collinearity import project
from lidarcat.synthetic.block import synthetic_block

#: the true Ebner parameters (mm at a grid corner; b = 18 mm on the 36 x 24 mm frame)
TRUE_EBNER = np.array([0.006, -0.004, 0.005, 0.003, -0.006, 0.004, 0.003, -0.005, 0.004, 0.002, -0.003, 0.003])
NOISE_MM = 0.003


def ebner_block(seed: int = 0, noise: bool = True, theta=TRUE_EBNER):
    """(problem, certificate camera) of a 3 x 8 block whose images carry *theta* (Ebner, mm)."""
    import dataclasses
    base = synthetic_block(3, 8, seed=seed, noise=False, image_sd_mm=NOISE_MM, tilt_sd_deg=2.0,
                           point_spacing_m=40.0)
    p = base.problem
    cam = Camera("cam", 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.006, 0.006, 6000, 4000, model="synthetic")
    aps = parameter_set("ebner")
    b = aps.scale_mm(*cam.frame_size_mm)
    xy_true, _ = project(base.true_eo[p.photo_index], base.true_points_m[p.point_index],
                         np.full(len(p.photo_index), 50.0))
    fot = xy_true.copy()
    for _ in range(60):                                     # x_fot = x_true + A(x_fot): a contraction
        fot = xy_true + aps.corrections(fot, theta, b)
    assert np.abs(fot - aps.corrections(fot, theta, b) - xy_true).max() < 1e-12
    if noise:
        fot = fot + np.random.default_rng(seed + 101).normal(0.0, NOISE_MM, fot.shape)
    return dataclasses.replace(p, xy_mm=fot), cam


@pytest.fixture(scope="module")
def ebner_solved():
    problem, cam = ebner_block(0)
    comp = SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "ebner")
    return adjust_with_parameters(problem, [comp])


def test_parse_parameter_sets():
    assert parse_parameters("ebner") == tuple(f"e{i}" for i in range(1, 13))
    assert parse_parameters("c,x0,y0,ebner") == ("c", "x0", "y0") + tuple(f"e{i}" for i in range(1, 13))
    assert parse_parameters("brown") == ("c", "x0", "y0", "k1", "k2", "k3", "p1", "p2", "k4", "b1", "b2")
    assert parse_parameters("thesis") == parse_parameters("all")
    assert parse_parameters("e3, c, e1") == ("c", "e1", "e3")
    assert len(parse_parameters("gruen")) == 44
    assert parse_parameters(parse_parameters("brown")) == parse_parameters("brown")   # idempotent


def test_unknown_set_name_is_one_line_listing_the_names():
    with pytest.raises(AdditionalParameterError) as ei:
        parse_parameters("c,ebnr")
    msg = str(ei.value)
    assert "\n" not in msg
    assert msg == ("unknown self-calibration parameter 'ebnr'; allowed: c, x0, y0, k1, k2, k3, p1, p2 (or 'all'), "
                   "the sets thesis, brown, ebner, gruen, or single terms of a set (k4, b1, b2; e1-e12; g1-g44)")
    with pytest.raises(AdditionalParameterError, match="the sets 'ebner' and 'gruen' cannot be combined"):
        parse_parameters("ebner,g5")


@pytest.mark.parametrize("params, extra", [("x0,y0,ebner", TRUE_EBNER),
                                           ("x0,y0,k1,k4,b1,b2", [2e-5, 1e-13, 3e-4, -2e-4]),
                                           ("x0,y0,g1,g7,g27,g44", [0.004, -0.003, 0.002, 0.001])])
def test_set_jacobians_match_finite_differences(params, extra):
    """The extra columns and the x0/y0 columns with dA/dx, against differences of the effective
    observations at a non-zero theta (Ebner; Brown's k4, b1, b2; terms of Grün's set)."""
    problem, cam = ebner_block(0, noise=False)
    comp = SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, params).bind(problem)
    theta = np.concatenate([[0.01, -0.02], extra])         # extra: every parameter after x0, y0

    class _S:  # the state the jacobians read (c is not switched on)
        pass

    def obs(th):
        f = {"xy_mm": problem.xy_mm, "focal_length_mm": problem.focal_length_mm}
        comp.apply(th, f)
        return f["xy_mm"]

    (_, rows, J, cols), = comp.jacobians(theta, _S())
    for a in range(comp.n):
        d = np.zeros(comp.n)
        h = d[a] = 1e-6 / (cam.frame_size_mm[0] / 2) ** (2 * (comp.params[a] == "k1") + 8 * (comp.params[a] == "k4"))
        num = -(obs(theta + d) - obs(theta - d)) / (2 * h)     # v = x_pred - x_fotc
        assert np.allclose(J[:, :, a], num, atol=1e-7 * max(1.0, np.abs(num).max()), rtol=1e-6), comp.names[a]


def test_ebner_distortion_recovered_within_3_sd_and_residuals_at_noise(ebner_solved):
    res = ebner_solved
    assert res.bundle.success
    names = [f"cam.e{i}" for i in range(1, 13)]
    assert list(res.names) == names
    assert list(res.units) == ["mm"] * 12
    tests = {t["name"]: t for t in res.tests()}
    for name, true in zip(names, TRUE_EBNER):
        i = res.index(name)
        assert abs(res.estimates[i] - true) < 3 * res.sd[i], (name, res.estimates[i], true, res.sd[i])
    # the joint test of the camera's 12 terms is far beyond chance; the best-determined singly too
    assert res.group_tests()[0]["p_value"] < 1e-12
    assert all(abs(tests[f"cam.{q}"]["t"]) > 3 for q in ("e1", "e2", "e3", "e8", "e9")), tests
    # the 36 x 24 mm frame spans only v in [-2/3, 2/3] of Ebner's grid (b = 18 mm): there
    # P2(v) = v^2 - 2/3 hardly changes, so e12 = (0, P2(u) P2(v)) ~ -0.5 e6 = (0, P2(u))
    bad = sorted(n for n, t in tests.items() if not t["determinable"])
    assert bad == ["cam.e12", "cam.e6"], bad
    w = res.warnings()
    assert len(w) == 2 and all("\n" not in m for m in w)
    assert "'cam.e6' is not determinable from this block: correlated with cam.e12 (r = +0.9" in w[0]
    assert "the measured photo coordinates span" in w[0] and "v -0.6" in w[0] and "frame 36.0 x 24.0 mm" in w[0]
    assert tests["cam.e6"]["why"] == w[0].split("Why: ")[1]
    # the image residuals back to the noise level: the RMS of the same block with the same noise
    # and no distortion, adjusted without parameters (least-squares residuals are below the noise
    # itself by the redundancy: 0.00196 vs 0.003 mm here)
    from lidarcat.bundle import adjust
    clean, _ = ebner_block(0, theta=np.zeros(12))
    ref = adjust(clean)
    rms = {k: float(np.sqrt(np.mean(np.asarray(r.residuals_mm) ** 2)))
           for k, r in (("on", res.bundle), ("off", res.without), ("ref", ref))}
    assert abs(rms["on"] / rms["ref"] - 1) < 0.03, rms
    assert rms["off"] > 1.15 * rms["ref"], rms
    assert res.bundle.chi2["passed"] and not res.without.chi2["passed"]


def test_gruen_carries_no_caveat_since_its_bias_is_removed():
    """The gruen set's warning ("its standard deviations are too small", GRUEN_CAVEAT) predated the
    bias correction of the bundle; with it the six terms' mean standardised error is -0.03 and all 44
    have rms 0.98 over 20 seeds (tests/bundle/test_models_block_gruen.py, slow), so the set adds no
    warning of its own: what is left are the block's parameters it cannot determine."""
    problem, cam = ebner_block(0)
    res = adjust_with_parameters(problem, [SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "gruen")])
    assert len(res.names) == 44 and res.notes == ()
    w = res.warnings()
    assert w and all(x.startswith("additional parameter 'cam.g") and "is not determinable from this block" in x
                     for x in w)
    assert not any("too small" in x or "optimistic" in x for x in res.summary()["warnings"])


def test_focal_length_against_flying_height_says_why():
    """Flat terrain, nadir, no GNSS: c trades against Z0 and the warning gives the relief ratio."""
    from lidarcat.synthetic.block import selfcal_block
    b = selfcal_block(5, n_strips=2, photos_per_strip=6, gnss_sd_m=None)
    p = b.problem
    res = adjust_with_parameters(p, [SelfCalibration({"cam": b.camera}, ["cam"] * p.n_photos, "c")])
    t = res.tests()[0]
    assert not t["determinable"] and t["max_correlation_eo"]["parameter"] == "Z0"
    h = np.asarray(res.bundle.points_m)[:, 2]
    rel = np.std(h) / (np.mean(np.asarray(res.bundle.eo_params)[:, 2]) - np.mean(h))
    assert t["why"].startswith("c scales the image as the flying height does and the terrain relief (sd of "
                               f"the point heights) is {rel:.1%} of the flying height")
    assert rel < 0.05
    assert res.warnings()[0].endswith("Why: " + t["why"])


def test_cli_adjust_self_calibrate_ebner(tmp_path):
    import json
    from click.testing import CliRunner
    from lidarcat.cli.main import cli
    r = CliRunner().invoke(cli, ["adjust", "--self-calibrate", "ebner", "-o", str(tmp_path / "o")])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert sorted(s["additional_parameters"]) == sorted(f"dcs14n.e{i}" for i in range(1, 13))
    assert all(t["unit"] == "mm" and t["prior_sd"] is None for t in s["additional_parameters"].values())
    assert "dcs14n.e12" in r.output
    r = CliRunner().invoke(cli, ["adjust", "--self-calibrate", "c,x0,y0,ebnr", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2
    lines = [ln for ln in r.output.splitlines() if "unknown self-calibration parameter" in ln]
    assert len(lines) == 1 and "'ebnr'" in lines[0] and "the sets thesis, brown, ebner, gruen" in lines[0]
    assert not (tmp_path / "x").exists()


def test_survey_toml_parameter_set(tmp_path):
    import shutil
    from lidarcat.errors import SurveyError
    from lidarcat.survey.folder import Survey, thesis_survey_path
    from lidarcat.survey.selfcal import self_calibration_settings
    folder = tmp_path / "s"
    shutil.copytree(thesis_survey_path(), folder)
    toml = folder / "survey.toml"
    base = toml.read_text()
    toml.write_text(base + '\n[self_calibration]\nparameters = "c,x0,y0,ebner"\n')
    st = self_calibration_settings(Survey.load(folder))
    assert st.parameters == ("c", "x0", "y0") + tuple(f"e{i}" for i in range(1, 13))
    toml.write_text(base + '\n[self_calibration]\nparameters = "ebner,g3"\n')
    n = len(base.splitlines()) + 3
    with pytest.raises(SurveyError, match=rf"survey.toml:{n}: field 'parameters': self-calibration: the sets "
                                          "'ebner' and 'gruen' cannot be combined"):
        self_calibration_settings(Survey.load(folder))


@pytest.mark.slow
def test_ebner_sds_honest_over_20_seeds():
    """20 seeds (a new geometry and noise each): the 240 standardised errors of the Ebner terms have
    their sum of squares inside the two-sided 99.9 % chi-square interval (measured: rms 0.94, largest
    2.62; 65 s at load 8 on 2 cores)."""
    from scipy import stats
    z = []
    for seed in range(20):
        problem, cam = ebner_block(seed)
        res = adjust_with_parameters(problem, [SelfCalibration({"cam": cam}, ["cam"] * problem.n_photos, "ebner")])
        z.append((res.estimates - TRUE_EBNER) / res.sd)
    q = float(np.sum(np.square(z)))
    n = np.size(z)
    assert stats.chi2(n).ppf(0.0005) < q < stats.chi2(n).ppf(0.9995), (q, n)
    assert np.abs(z).max() < 4


def test_why_of_two_radial_terms_and_of_the_gruen_grid():
    """Thesis block: with brown, k3 and k4 trade (successive powers of r); with gruen the grid is
    [-2, 2] and the shorter side of the 23.7 x 35.6 mm frame spans only about u +-1.3 of it."""
    from lidarcat.survey.selfcal import selfcal_adjust
    _, res = selfcal_adjust(self_calibrate="brown")
    t = {x["name"]: x for x in res.tests()}
    assert not t["dcs14n.k4"]["determinable"] and t["dcs14n.k4"]["max_correlation_additional"]["parameter"] == "dcs14n.k3"
    assert t["dcs14n.k4"]["why"].startswith("over the measured photo coordinates (up to 21.3 mm from the centre; "
                                            "the frame corner is at 21.4 mm) the corrections of k4 and k3 are "
                                            "nearly proportional; fix one of them")
    _, res = selfcal_adjust(self_calibrate="gruen")
    w = [m for m in res.warnings() if "Why: the gruen polynomials" in m]
    assert w and all("orthogonal over the grid u, v in [-2, 2] (b = 8.89 mm), but the measured photo "
                     "coordinates span u -1.25 .. +1.30" in m for m in w)
