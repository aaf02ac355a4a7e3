"""Accuracy assessment: Table 7 of the thesis, every test against an independent computation."""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
from scipy import stats

from conftest import THESIS_SURVEY, THESIS_TABLES
from lidarcat.accuracy.checkpoints import (
    Assessment,
    assess,
    ce90,
    chi2_precision_test,
    covariance_consistency_test,
    filliben_test,
    hotelling_t2_test,
    ks_mahalanobis_test,
    ks_test,
    lilliefors_test,
    plotting_positions,
    read_points,
    trend_t_test,
)
from lidarcat.errors import AssessmentError, SurveyError
from lidarcat.accuracy.standards import circular_error_radius

# -------------------------------------------------------------------- Table 7 fixture


def _table7():
    rows = {}
    with open(THESIS_TABLES / "table7_check_gps.csv", newline="") as fh:
        for row in csv.DictReader(line for line in fh if not line.startswith("#")):
            rows[row["point"]] = np.array([float(row[k]) for k in ("dE", "dN", "dh", "plani")])
    mean, std = rows.pop("mean"), rows.pop("std")
    ids = list(rows)
    d = np.array([rows[p][:3] for p in ids])
    plani = np.array([rows[p][3] for p in ids])
    return ids, d, plani, mean, std


IDS, D7, PLANI7, MEAN7, STD7 = _table7()
# adjusted coordinates of the right magnitude; reference = adjusted + d gives d = reference - adjusted
ADJ7 = np.array([677500.0, 7183900.0, 910.0]) + np.arange(13)[:, None] * np.array([10.0, 20.0, 1.0])


@pytest.fixture(scope="module")
def thesis7() -> Assessment:
    return assess((IDS, ADJ7), (IDS, ADJ7 + D7), scale=2000, contour_interval_m=2.0,
                  plotting_position="hazen", lilliefors_n_sim=4000)


def test_table7_mean_and_std_rows_reproduced(thesis7):
    s = thesis7.summary
    for k, comp in enumerate(("E", "N", "h")):
        assert round(s[comp]["mean"], 3) == pytest.approx(MEAN7[k], abs=1e-9)
        assert round(s[comp]["std"], 3) == pytest.approx(STD7[k], abs=1e-9)
        assert s[comp]["n"] == 13
    # planimetric: the thesis derived dP from unrounded coordinates (its per-point dP differ from
    # hypot(printed dE, dN) by up to 0.001); the std row is exact, the mean within the printed precision
    assert round(s["planimetric"]["std"], 3) == pytest.approx(STD7[3], abs=1e-9)
    assert s["planimetric"]["mean"] == pytest.approx(MEAN7[3], abs=0.0015)
    np.testing.assert_allclose(thesis7.planimetric, PLANI7, atol=0.0015)


def test_table7_sign_convention_from_published_coordinates():
    # Table 2 (GPS survey, via the embedded ground_points.csv) minus Appendix 3.1 (adjusted) = Table 7
    a = assess(THESIS_TABLES / "appendix3_1_points_gps.csv", THESIS_SURVEY / "ground_points.csv",
               points=IDS, scale=2000, contour_interval_m=2)
    np.testing.assert_allclose(a.d, D7, atol=1.5e-3)
    b = assess(THESIS_TABLES / "appendix3_1_points_gps.csv", THESIS_SURVEY / "ground_points.csv",
               points=IDS, sign="adjusted_minus_reference", scale=2000)
    np.testing.assert_allclose(b.d, -a.d, atol=1e-12)
    # reference sds (0.25 m) are read and reach ASPRS 2023 (RMSE_H2 = sqrt(2) * 0.25 m)
    assert a.standards["asprs2023"].evidence["rmse_h2_m"] == pytest.approx(0.25 * math.sqrt(2), abs=1e-9)


def test_default_selection_excludes_control_points():
    ref = {p: v for p, v in _gps_reference().items()}
    a = assess(THESIS_TABLES / "appendix3_1_points_gps.csv", ref, scale=2000)
    assert sorted(a.points) == sorted(IDS)  # the 8 "control" (Fixo) points are left out


def _gps_reference():
    out = {}
    with open(THESIS_SURVEY / "ground_points.csv", newline="") as fh:
        for row in csv.DictReader(line for line in fh if not line.startswith("#")):
            if row["source"] == "gps":
                out[row["point"]] = (float(row["E"]), float(row["N"]), float(row["h"]))
    return out


def test_summary_rmse_and_max(thesis7):
    s = thesis7.summary
    np.testing.assert_allclose(s["E"]["rmse"], np.sqrt(np.mean(D7[:, 0] ** 2)), atol=1e-9)
    np.testing.assert_allclose(s["h"]["max_abs"], 1.028, atol=1e-9)
    dp = np.hypot(D7[:, 0], D7[:, 1])
    np.testing.assert_allclose(s["planimetric"]["rmse"], math.hypot(s["E"]["rmse"], s["N"]["rmse"]), atol=1e-12)
    np.testing.assert_allclose(s["planimetric"]["max_abs"], dp.max(), atol=1e-9)


# -------------------------------------------------------------------- Filliben


def test_plotting_positions_filliben_medians_match_scipy():
    for n in (5, 13, 21):
        osm = stats.probplot(np.arange(n, dtype=float))[0][0]
        np.testing.assert_allclose(stats.norm.ppf(plotting_positions(n, "filliben")), osm, atol=1e-12)


def test_filliben_r_matches_scipy_probplot_and_eq42(thesis7):
    for comp, x in (("h", D7[:, 2]), ("E", D7[:, 0])):
        r_filliben = filliben_test(x, 0.10, "filliben").statistic
        np.testing.assert_allclose(r_filliben, stats.probplot(x)[1][2], atol=1e-12)
        # eq. 42 written out with the thesis's Z_i (hazen)
        z = stats.norm.ppf((np.arange(1, 14) - 0.5) / 13)
        xs = np.sort(x)
        n = 13
        r42 = (n * np.sum(xs * z) - xs.sum() * z.sum()) / math.sqrt(
            (n * np.sum(xs ** 2) - xs.sum() ** 2) * (n * np.sum(z ** 2) - z.sum() ** 2))
        np.testing.assert_allclose(thesis7.tests["filliben"][comp].statistic, r42, atol=1e-12)
    assert thesis7.tests["filliben"]["h"].critical == 0.944  # n = 13, alpha = 0.10


def test_filliben_critical_n21_is_0961():
    x = stats.norm.ppf((np.arange(1, 22) - 0.5) / 21) + 0.01 * np.sin(np.arange(21))
    t = filliben_test(x, 0.10, "hazen")
    assert t.critical == 0.961
    assert t.passed is True


def test_filliben_rejects_skewed_sample():
    x = np.exp(np.linspace(0, 6, 21))
    t = filliben_test(x, 0.10)
    assert t.statistic < t.critical and t.passed is False


def test_filliben_montecarlo_critical_close_to_stored_simulation():
    x = np.random.default_rng(1).standard_normal(20)
    t = filliben_test(x, 0.10, "hazen", critical="montecarlo")
    # STANDARDS.md Monte-Carlo table: hazen, n = 20, alpha 0.10 -> 0.9603
    assert t.critical == pytest.approx(0.9603, abs=0.0015)
    big = filliben_test(np.random.default_rng(2).standard_normal(150), 0.10)
    assert "Monte-Carlo" in big.details["critical_source"]


# -------------------------------------------------------------------- K-S


def test_ks_plain_statistic_by_hand_and_massey_critical_values(thesis7):
    # D written out: the largest gap between the empirical CDF and N(mean, s), on both sides of each step
    x = np.sort(D7[:, 2])
    f = stats.norm.cdf((x - x.mean()) / x.std(ddof=1))
    i = np.arange(1, 14)
    t = thesis7.tests["ks"]["h"]
    np.testing.assert_allclose(t.statistic, max(np.max(i / 13 - f), np.max(f - (i - 1) / 13)), atol=1e-12)
    # two-sided critical D from the Massey (1951) table (3 decimals): n = 13 -> 0.325 at 0.10, 0.361 at 0.05
    assert t.critical == pytest.approx(0.325, abs=5e-4)
    assert ks_test(x, 0.05).critical == pytest.approx(0.361, abs=5e-4)
    assert ks_test(np.arange(20.0), 0.10).critical == pytest.approx(0.265, abs=5e-4)


def test_lilliefors_matches_statsmodels():
    from statsmodels.stats.diagnostic import lilliefors

    for x in (D7[:, 2], D7[:, 0], np.random.default_rng(3).standard_normal(21)):
        d_sm, p_sm = lilliefors(x, dist="norm", pvalmethod="table")
        t = lilliefors_test(x, 0.10, n_sim=20000)
        np.testing.assert_allclose(t.statistic, d_sm, atol=1e-12)
        assert t.details["p_value"] == pytest.approx(p_sm, abs=0.03)


def test_ks_stricter_than_plain_for_estimated_parameters():
    x = np.random.default_rng(5).standard_normal(21)
    plain, lil = ks_test(x), lilliefors_test(x, n_sim=5000)
    assert plain.statistic == pytest.approx(lil.statistic, abs=1e-12)
    assert lil.details["p_value"] < plain.details["p_value"]


def test_ks_mahalanobis_matches_scipy_beta_reference():
    x = np.random.default_rng(7).standard_normal((25, 2))
    t = ks_mahalanobis_test(x)
    c = x - x.mean(0)
    d2 = np.einsum("ij,jk,ik->i", c, np.linalg.inv(np.cov(x.T)), c)
    ref = stats.kstest(25 * d2 / 24 ** 2, stats.beta(1, 11).cdf)
    np.testing.assert_allclose(t.statistic, ref.statistic, atol=1e-12)


# -------------------------------------------------------------------- t and chi-square


def test_trend_t_matches_scipy_ttest(thesis7):
    for k, comp in enumerate(("E", "N", "h")):
        ref = stats.ttest_1samp(D7[:, k], 0.0)
        t = thesis7.tests["trend_t"][comp]
        np.testing.assert_allclose(t.statistic, ref.statistic, atol=1e-9)
        np.testing.assert_allclose(t.details["p_value"], ref.pvalue, atol=1e-9)
        np.testing.assert_allclose(t.critical, stats.t.ppf(0.95, 12), atol=1e-12)
        # eq. 43: the interval is scipy's 90 % confidence interval of the mean
        lo, hi = ref.confidence_interval(0.90)
        np.testing.assert_allclose([t.details["mean_lower"], t.details["mean_upper"]], [lo, hi], atol=1e-9)
    # the thesis GPS run: dh has a significant bias (t = -3.0), E and N do not
    assert thesis7.tests["trend_t"]["h"].passed is False
    assert thesis7.tests["trend_t"]["E"].passed is True and thesis7.tests["trend_t"]["N"].passed is True


def test_t_and_chi2_critical_values_of_standards_md():
    assert trend_t_test(np.arange(21.0)).critical == pytest.approx(1.7247, abs=5e-5)
    assert trend_t_test(np.arange(20.0)).critical == pytest.approx(1.7291, abs=5e-5)
    assert chi2_precision_test(np.arange(21.0), 100.0).critical == pytest.approx(28.412, abs=5e-4)
    assert chi2_precision_test(np.arange(20.0), 100.0).critical == pytest.approx(27.204, abs=5e-4)
    assert chi2_precision_test(np.arange(30.0), 100.0).critical == pytest.approx(39.087, abs=5e-4)


def test_chi2_thesis_settings(thesis7):
    c = thesis7.tests["chi2_precision"]
    # thesis 3.3.4: class A at 1:2000: EP 0.60 m planimetric; Eq 2 m -> EP 0.67 m altimetric
    assert c["planimetric"].details["sigma0"] == pytest.approx(0.60, abs=1e-12)
    assert c["h"].details["sigma0"] == pytest.approx(2 / 3, abs=1e-6)
    assert c["E"].details["sigma0"] == pytest.approx(0.60 / math.sqrt(2), abs=1e-12)
    s = np.std(D7[:, 2], ddof=1)
    np.testing.assert_allclose(c["h"].statistic, 12 * s ** 2 / (2 / 3) ** 2, rtol=1e-6)
    np.testing.assert_allclose(c["h"].details["sigma_bound"], math.sqrt(12 * s ** 2 / stats.chi2.ppf(0.9, 12)),
                               rtol=1e-9)
    # eq. 45 bound: the sample passes exactly for sigma0 >= sigma_bound
    b = c["h"].details["sigma_bound"]
    assert chi2_precision_test(D7[:, 2], b * 1.0001).passed is True
    assert chi2_precision_test(D7[:, 2], b * 0.9999).passed is False
    assert all(c[k].passed for k in c)


# -------------------------------------------------------------------- Hotelling and CE90


def test_hotelling_matches_statsmodels(thesis7):
    from statsmodels.stats.multivariate import test_mvmean

    for x in (D7[:, :2], np.random.default_rng(11).normal(0.1, 1.0, (21, 2))):
        ref = test_mvmean(x, mean_null=np.zeros(2))
        t = hotelling_t2_test(x, 0.10)
        np.testing.assert_allclose(t.details["F"], ref.statistic, rtol=1e-9)
        np.testing.assert_allclose(t.details["p_value"], ref.pvalue, rtol=1e-9)
        np.testing.assert_allclose(t.statistic, ref.t2, rtol=1e-9)
    assert thesis7.tests["hotelling"]["EN"].passed is True


def test_ce90_circular_factor_and_bivariate_exact_monte_carlo():
    assert circular_error_radius(0.90, (0, 0), np.eye(2) * 4.0) == pytest.approx(2.1460 * 2, abs=2e-4)
    cov = np.array([[0.04, 0.01], [0.01, 0.01]])
    mean = np.array([0.05, -0.02])
    r = circular_error_radius(0.90, mean, cov)
    e = np.random.default_rng(0).multivariate_normal(mean, cov, 400_000)
    assert np.mean(np.hypot(e[:, 0], e[:, 1]) <= r) == pytest.approx(0.90, abs=0.002)
    # degenerate: all error on one axis
    r1 = circular_error_radius(0.90, (0, 0), np.diag([1.0, 0.0]))
    assert r1 == pytest.approx(stats.norm.ppf(0.95), abs=1e-6)


def test_ce90_empirical_is_order_statistic(thesis7):
    t = thesis7.tests["ce90"]["empirical"]
    dp = np.sort(np.hypot(D7[:, 0], D7[:, 1]))
    assert t.statistic == pytest.approx(dp[11], abs=1e-9)  # ceil(0.9 * 13) = 12th smallest
    assert t.details["fraction_within"] >= 0.9
    assert t.critical == pytest.approx(1.0) and t.passed is True
    circ = ce90(D7[:, :2], "circular")
    sc = math.sqrt((np.var(D7[:, 0], ddof=1) + np.var(D7[:, 1], ddof=1)) / 2)
    assert circ.statistic == pytest.approx(2.1460 * sc, rel=1e-4)


# -------------------------------------------------------------------- bad input


# -------------------------------------------------------------------- consistency with the claimed precision


def _correlated_cov(n_pts, rng):
    """A covariance like a block's: a common tilt/shift term on top of independent noise."""
    g = rng.normal(size=(3 * n_pts, 4)) * 0.3
    return g @ g.T + np.diag(rng.uniform(0.01, 0.05, 3 * n_pts))


def test_consistency_statistic_is_the_mahalanobis_form():
    rng = np.random.default_rng(1)
    C = _correlated_cov(5, rng)
    d = rng.normal(size=(5, 3))
    r = covariance_consistency_test(d, C, alpha=0.05)
    assert r.statistic == pytest.approx(float(d.ravel() @ np.linalg.solve(C, d.ravel())), rel=1e-10)
    assert r.details["df"] == 15 and r.details["n"] == 5
    assert r.details["lower"] == pytest.approx(stats.chi2.ppf(0.025, 15))
    assert r.critical == pytest.approx(stats.chi2.ppf(0.975, 15))
    assert r.details["diagonal_statistic"] == pytest.approx(float(np.sum(d.ravel() ** 2 / np.diag(C))))


def test_consistency_test_has_its_size_under_correlated_errors():
    """Errors drawn from C: the test rejects alpha of the time; the diagonal sum far more."""
    rng = np.random.default_rng(7)
    C = _correlated_cov(10, rng)
    L = np.linalg.cholesky(C)
    lo, hi = stats.chi2.ppf([0.05, 0.95], 30)
    passed, diag_out = 0, 0
    for _ in range(2000):
        d = (L @ rng.normal(size=30)).reshape(10, 3)
        r = covariance_consistency_test(d, C, alpha=0.10)
        passed += r.passed
        diag_out += not lo <= r.details["diagonal_statistic"] <= hi
    assert abs(passed / 2000 - 0.90) < 0.02
    assert diag_out / 2000 > 0.3


def test_consistency_not_applicable_with_reasons():
    d = np.zeros((2, 3))
    assert covariance_consistency_test(d, np.eye(3)).reason == "covariance has shape (3, 3), expected (6, 6)"
    bad = np.eye(6)
    bad[0, 0] = -1
    assert covariance_consistency_test(d, bad).reason == "covariance of the discrepancies is not positive definite"


def test_assess_runs_the_consistency_test_with_the_adjusted_covariance():
    adj = {"1": (0.1, 0.0, 0.0), "2": (1.0, 1.2, 1.0), "3": (2.0, 2.0, 1.7)}
    ref = {"point": ["1", "2", "3"], "E": [0.0, 1.0, 2.0], "N": [0.0, 1.0, 2.0], "h": [0.0, 1.0, 2.0],
           "sd_E": [0.1] * 3, "sd_N": [0.1] * 3, "sd_h": [0.1] * 3}
    cov = (["3", "2", "1"], np.eye(9) * 0.04)            # any order: matched by id
    a = assess(adj, ref, scale=None, adjusted_cov=cov)
    r = a.tests["consistency"]["ENh"]
    # d = ref - adj = (-0.1, 0, 0), (0, -0.2, 0), (0, 0, 0.3); variances 0.04 + 0.01
    assert r.statistic == pytest.approx((0.01 + 0.04 + 0.09) / 0.05)
    assert "consistency" not in assess(adj, ref, scale=None).tests
    miss = assess(adj, ref, scale=None, adjusted_cov=(["1", "2"], np.eye(6)))
    assert miss.tests["consistency"]["ENh"].reason == "no adjusted covariance for check point(s) 3"
    with pytest.raises(AssessmentError, match=r"^adjusted_cov: covariance of shape \(6, 6\) for 3 point ids; "
                                              r"expected \(9, 9\)"):
        assess(adj, ref, scale=None, adjusted_cov=(["1", "2", "3"], np.eye(6)))


def test_mismatched_ids_named():
    adj = {"1": (0, 0, 0), "2": (1, 1, 1), "3": (2, 2, 2)}
    ref = {"1": (0, 0, 0), "2": (1, 1, 1), "9": (2, 2, 2), "8": (3, 3, 3)}
    with pytest.raises(AssessmentError, match=r"reference point\(s\) 9, 8 of reference are missing in the "
                                              r"adjusted points adjusted; 2 ids are common"):
        assess(adj, ref)
    with pytest.raises(AssessmentError, match=r"not in the reference \(reference\): 3"):
        assess(adj, ref, points=["1", "3"])


def test_mismatched_ids_in_csv_files_named(tmp_path):
    a = tmp_path / "adj.csv"
    r = tmp_path / "ref.csv"
    a.write_text("point,E,N,h\nA,0,0,0\nB,1,1,1\n")
    r.write_text("point,E,N,h,sd_E,sd_N,sd_h,source\nA,0,0,0,0.1,0.1,0.1,gps\nC,1,1,1,0.1,0.1,0.1,gps\n")
    with pytest.raises(AssessmentError, match=r"C of .*ref\.csv are missing in the adjusted points .*adj\.csv"):
        assess(a, r)


def test_bad_csv_is_located(tmp_path):
    a = tmp_path / "adj.csv"
    a.write_text("point,E,N\nA,0,0\n")
    with pytest.raises(SurveyError, match=r"adj\.csv:1: missing column 'h'"):
        read_points(a)
    b = tmp_path / "b.csv"
    b.write_text("point,E,N,h\nA,0,0,x\n")
    with pytest.raises(SurveyError, match=r"b\.csv:2: field 'h': 'x' is not a number"):
        read_points(b)
    c = tmp_path / "c.csv"
    c.write_text("point,E,N,h\nA,0,0,0\nA,1,1,1\n")
    with pytest.raises(AssessmentError, match="duplicate point id"):
        read_points(c)


def test_too_few_points_marks_tests_not_applicable():
    adj = {"1": (0, 0, 0), "2": (1, 1, 1)}
    ref = {"1": (0.1, 0.0, 0.2), "2": (1.0, 1.2, 0.9)}
    a = assess(adj, ref, scale=2000, contour_interval_m=2)
    f = a.tests["filliben"]["h"]
    assert f.applicable is False and f.passed is None and "at least 3 points, got 2" in f.reason
    assert a.tests["hotelling"]["EN"].verdict == "not applicable"
    assert a.tests["trend_t"]["h"].applicable is True
    d = a.to_dict()
    assert d["tests"]["filliben"]["h"]["r"] is None and d["tests"]["filliben"]["h"]["applicable"] is False
    assert d["standards"]["pec"]["class"]["planimetric"] == "A"


def test_zero_variance_marks_tests_not_applicable():
    adj = np.zeros((6, 3))
    ref = np.tile([0.1, -0.1, 0.2], (6, 1))
    a = assess(adj, ref, scale=2000, contour_interval_m=2)
    for test in ("filliben", "ks", "lilliefors"):
        assert "zero variance" in a.tests[test]["h"].reason
    assert a.tests["trend_t"]["E"].reason == "zero variance: all discrepancies are equal"
    singular = "singular covariance of (dE, dN): zero variance or collinear discrepancies"
    assert a.tests["hotelling"]["EN"].reason == singular and a.tests["ks"]["EN"].reason == singular
    # collinear (dN = 2 dE) is singular too; too few points are named with the test's own minimum
    den = np.column_stack([np.arange(5.0), 2 * np.arange(5.0)])
    assert hotelling_t2_test(den).reason == singular and ks_mahalanobis_test(den).reason == singular
    assert ks_mahalanobis_test(den[:3]).reason == "needs at least 4 points, got 3"
    assert lilliefors_test(den[:3, 0]).reason == "needs at least 4 points, got 3"
    assert a.tests["chi2_precision"]["h"].passed is True  # s = 0 passes any sigma0
    ce = a.tests["ce90"]
    assert ce["circular"].reason == ce["bivariate_exact"].reason == "zero variance of dE and dN"
    assert ce["empirical"].statistic == pytest.approx(math.hypot(0.1, 0.1), abs=1e-12)


def test_no_scale_marks_chi2_not_applicable():
    a = assess(np.zeros((5, 3)), np.random.default_rng(0).normal(0, 0.1, (5, 3)), scale=None,
               standards=("pec", "nssda"))
    assert "map scale" in a.tests["chi2_precision"]["h"].reason
    assert "pec" not in a.standards and "nssda" in a.standards


def test_invalid_options():
    with pytest.raises(AssessmentError, match="sign must be one of"):
        assess(np.zeros((3, 3)), np.ones((3, 3)), sign="up")
    with pytest.raises(AssessmentError, match="unknown standard 'iso'"):
        assess(np.zeros((3, 3)), np.ones((3, 3)), standards=("iso",))
    with pytest.raises(AssessmentError, match="plotting_position must be one of"):
        assess(np.zeros((3, 3)), np.ones((3, 3)), plotting_position="weibull")


def test_input_forms_agree():
    cols = {"point": IDS, "E": ADJ7[:, 0], "N": ADJ7[:, 1], "h": ADJ7[:, 2]}
    ref = {p: ADJ7[k] + D7[k] for k, p in enumerate(IDS)}
    a = assess(cols, ref, scale=2000, lilliefors_n_sim=500)
    b = assess(ADJ7, ADJ7 + D7, scale=2000, lilliefors_n_sim=500)
    np.testing.assert_allclose(a.d, D7, atol=1e-9)  # reference - adjusted, paired by id / by position
    np.testing.assert_allclose(b.d, D7, atol=1e-9)
    assert a.points == tuple(IDS) and b.points == tuple(str(k) for k in range(1, 14))


def test_json_layout(thesis7):
    d = thesis7.to_dict()
    for comp in ("E", "N", "h", "planimetric"):
        assert set(d["summary"][comp]) >= {"n", "mean", "std", "rmse", "max_abs"}
    for comp in ("planimetric", "h"):
        assert set(d["tests"]["filliben"][comp]) >= {"r", "critical", "passed"}
        assert set(d["tests"]["chi2_precision"][comp]) >= {"chi2", "critical", "passed", "sigma_bound"}
    for comp in ("E", "N", "h"):
        assert set(d["tests"]["trend_t"][comp]) >= {"t", "critical", "passed"}
    assert set(d["tests"]) >= {"ks", "lilliefors", "hotelling", "ce90"}
    assert d["standards"]["pec"]["class"] == {"planimetric": "A", "altimetric": "A"}
    assert len(d["points"]) == 13 and d["points"][0]["point"] == "603"


def test_bad_in_memory_points_are_named():
    cols = {"point": ["a", "b", "c"], "E": [1.0, 2.0], "N": [1.0, 2.0, 3.0], "h": [1.0, 2.0, 3.0]}
    with pytest.raises(AssessmentError, match=r"^adjusted: column 'E' has 2 values for 3 points$"):
        read_points(cols, "adjusted")
    with pytest.raises(AssessmentError, match=r"^reference: point 'a': not a number \(could not convert string"):
        read_points({"a": (1.0, 2.0, "x")}, "reference")
    with pytest.raises(AssessmentError, match=r"^points: expected an \(N, 3\) array of E, N, h, got shape \(2, 2\)$"):
        read_points((["a", "b"], np.zeros((2, 2))))
    with pytest.raises(AssessmentError, match=r"^points: 2 ids for 3 coordinate rows$"):
        read_points((["a", "b"], np.zeros((3, 3))))


def test_lilliefors_is_scipy_goodness_of_fit_and_matches_the_hand_written_monte_carlo():
    """Issue 23: the Lilliefors test through scipy.stats.goodness_of_fit gives the D and p of the
    hand-written Monte-Carlo test it replaced (reproduced here), to 4 decimals (in fact exactly:
    the same seeded normal stream, the same statistic, the same p-value formula)."""
    from scipy import stats

    from lidarcat.accuracy.statistics import lilliefors_test

    def d_rows(z):  # K-S distance to N(mean, s), s with divisor n - 1 (the replaced code)
        n = z.shape[1]
        zs = np.sort(z, axis=1)
        u = (zs - zs.mean(axis=1, keepdims=True)) / zs.std(axis=1, ddof=1, keepdims=True)
        f = stats.norm.cdf(u)
        i = np.arange(1, n + 1)
        return np.maximum(np.max(i / n - f, axis=1), np.max(f - (i - 1) / n, axis=1))

    def hand_written(x, n_sim, seed):
        n = len(x)
        rng = np.random.default_rng(seed)
        step = max(1, 2_000_000 // n)
        sim = np.concatenate([d_rows(rng.standard_normal((min(step, n_sim - i), n))) for i in range(0, n_sim, step)])
        d = float(d_rows(x[None, :])[0])
        return d, float(np.quantile(sim, 0.90)), float((1 + np.sum(sim >= d - 1e-15)) / (n_sim + 1))

    rng = np.random.default_rng(2023)
    for x in (rng.normal(0.1, 0.3, 12), rng.exponential(1.0, 30), np.array([-1.2, -0.4, 0.1, 0.3, 0.9, 1.5])):
        d, crit, p = hand_written(x, 5000, 11)
        t = lilliefors_test(x, 0.10, n_sim=5000, seed=11)
        assert round(t.statistic, 4) == round(d, 4) and round(t.details["p_value"], 4) == round(p, 4)
        assert round(t.critical, 4) == round(crit, 4)
    # and scipy's own call, spelled out: the statistic is Lilliefors' (sd divisor n - 1), not scipy's "ks"
    x = np.array([-1.2, -0.4, 0.1, 0.3, 0.9, 1.5])
    t = lilliefors_test(x, 0.10, n_sim=2000, seed=5)

    def statistic(dist, data, axis):
        z = np.moveaxis(data, axis, -1)
        return d_rows(z.reshape(-1, z.shape[-1])).reshape(z.shape[:-1])

    res = stats.goodness_of_fit(stats.norm, x, statistic=statistic, n_mc_samples=2000, rng=np.random.default_rng(5))
    assert (t.statistic, t.details["p_value"]) == (float(res.statistic), float(res.pvalue))
    assert round(t.statistic, 4) == 0.1248
