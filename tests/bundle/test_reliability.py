"""Blunder detection (issue 12 part 1): redundancy numbers, data snooping, robust re-weighting,
internal and external reliability, provenance of the outputs (part 3).

Published values: Baarda's noncentrality lambda0 = 17.07 for alpha = 0.001 and power 0.80 and
the critical w 3.29 (e.g. Teunissen, Testing theory, 2006, table 4.2 / Foerstner 1987).  The
other facts are the known truth of injected errors, the algebra (sum of the redundancy numbers =
degrees of freedom; the blockwise Q_vv equals the dense one) and the thesis tables (Table 6/7).
Long Monte Carlo runs: ``benchmarks/bench_reliability.py``.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import THESIS_SURVEY, THESIS_TABLES

from lidarcat.synthetic.block import resimulated, synthetic_block
from lidarcat.bundle import adjust
from lidarcat.survey import problem_from_survey
from lidarcat.bundle.reliability import MIN_REDUNDANCY, critical_values, family_alpha, noncentrality, reliability, snoop
from lidarcat.cli.main import cli
from lidarcat.survey.folder import Survey

SD_IMG = 0.006      # mm, the thesis image sigma
SD_CON = 0.25       # m, the thesis GPS control sigma


@pytest.fixture(scope="module")
def gps_problem():
    return problem_from_survey(Survey.load(THESIS_SURVEY), control="gps", observations="corrected")


@pytest.fixture(scope="module")
def gps(gps_problem):
    return adjust(gps_problem)


def _obs(p, photo, point):
    return int(np.flatnonzero((p.photo_ids[p.photo_index] == photo) & (p.point_ids[p.point_index] == point))[0])


def _with_image_error(p, photo, point, dxy_mm):
    xy = np.array(p.xy_mm)
    xy[_obs(p, photo, point)] += dxy_mm
    return dataclasses.replace(p, xy_mm=xy)


def _with_control_error(p, point, denh_m):
    enh = np.array(p.constraint_enh_m)
    enh[int(np.flatnonzero(p.point_ids[p.constraint_point_index] == point)[0])] += denh_m
    return dataclasses.replace(p, constraint_enh_m=enh)


# --------------------------------------------------------------------------- levels


def test_b_method_levels_published_values():
    assert abs(noncentrality(0.001, 0.80) - 17.07) <= 0.005
    alpha, k = critical_values(0.001, 0.80, 1)
    assert alpha == 0.001 and abs(np.sqrt(k) - 3.29) <= 0.005
    # every dimension detects lambda0 with the same power
    from scipy import stats
    for q in (2, 3, 6):
        a, kq = critical_values(0.001, 0.80, q)
        assert a > 0.001
        assert abs(stats.ncx2.sf(kq, q, noncentrality(0.001, 0.80)) - 0.80) < 1e-8
    with pytest.raises(ValueError, match=r"^`level` \(alpha of the w-test\) must be in \(0, 0.5\), got 0.7$"):
        noncentrality(0.7, 0.8)


def test_family_level_solves_sidak_over_the_b_method_levels(gps):
    """alpha_1 chosen so that 1 - prod (1 - alpha_q)^n_q = family over the block's tests."""
    from scipy import stats

    counts = {1: 26, 2: 125, 3: 8}
    a1 = family_alpha(counts, 0.05)
    none_reject = np.prod([(1 - critical_values(a1, 0.80, q)[0]) ** n for q, n in counts.items()])
    assert abs((1 - none_reject) - 0.05) < 1e-9
    assert family_alpha({1: 1}, 0.05) == pytest.approx(0.05, rel=1e-9)    # one 1-D test: its own level
    # Bonferroni bound for one dimension: alpha_1 -> family / n
    assert abs(family_alpha({1: 10_000}, 0.05) * 10_000 / 0.05 - 1) < 0.03
    # the thesis block: the counts above are its testable groups; critical w of an image point 4.00
    rel = reliability(gps)
    assert dict(zip(*np.unique(rel.q, return_counts=True))) == counts
    assert rel.family_level == 0.05 and rel.alpha == pytest.approx(a1, rel=1e-9)
    crit2 = float(rel.w_critical[(rel.kind == "image") & (rel.q == 2)][0])
    assert abs(crit2 - np.sqrt(stats.chi2.isf(critical_values(a1, 0.80, 2)[0], 2))) < 1e-9
    assert 3.99 < crit2 < 4.01
    # MDB follows the level: sd sqrt(lambda0 / r) with the family's lambda0
    assert rel.lam0 == pytest.approx(noncentrality(a1, 0.80))
    i = int(np.flatnonzero(rel.kind == "image")[0])
    assert rel.mdb[i, 0] == pytest.approx(SD_IMG * np.sqrt(rel.lam0 / rel.redundancy[i, 0]), rel=1e-9)
    with pytest.raises(ValueError, match=r"^`level` \(alpha of the w-test\) must be in \(0, 0.5\), got 0.0$"):
        family_alpha(counts, 0.0)


@pytest.mark.slow
def test_family_level_false_alarms_on_clean_blocks(gps_problem, gps):
    """Clean thesis geometry (simulated noise only): at the family level at most ~5 % of the
    blocks have any test rejecting; at a fixed 0.001 per test about n * alpha_q good
    observations are flagged per block (151 image tests x 0.0028).  Slow (150 adjustments, 58 s at
    load 15); the family level's fast cases are the blunder tests of this file."""
    rng = np.random.default_rng(21)
    n, any_family, flagged_fixed = 150, 0, 0
    start = (np.asarray(gps.eo_params), np.asarray(gps.points_m))
    for _ in range(n):
        q = _simulated(gps_problem, gps, rng)
        r = adjust(q, initial=start, precision="none")
        any_family += reliability(r).n_rejected > 0
        flagged_fixed += reliability(r, level=0.001).n_rejected
    # binomial(150, 0.05): mean 7.5, P(X >= 15) < 0.01; the tests are correlated, so fewer
    assert any_family <= 14, any_family
    assert flagged_fixed / n > 0.2, flagged_fixed


# --------------------------------------------------------------------------- redundancy numbers


def test_redundancy_numbers_sum_to_dof(gps):
    rel = reliability(gps)
    r = rel.redundancy[np.isfinite(rel.redundancy)]
    assert abs(r.sum() - gps.dof) < 1e-6          # trace(Q_vv P) = n - u + constraints = 128
    assert r.min() > -1e-9 and r.max() < 1 + 1e-9
    assert list(rel.kind).count("image") == 151 and list(rel.kind).count("control") == 8


def test_blockwise_cofactor_equals_dense():
    """Q_vv blocks from the sparse selected inverse = Q_ll - A N^-1 A^T formed densely."""
    b = synthetic_block(2, 4, seed=5)
    p = b.problem
    res = adjust(p)
    rel = reliability(res)
    from lidarcat.bundle.redundancy import _dense_cofactor

    qvv, qll = _dense_cofactor(res)           # Q_ll - A N^-1 A^T with a dense N^-1
    n = len(p.photo_index)
    r_dense = np.diag(qvv) / qll
    np.testing.assert_allclose(rel.redundancy[:n, :2].ravel(), r_dense[:2 * n], atol=1e-9)
    np.testing.assert_allclose(rel.redundancy[n:, :3].ravel(), r_dense[2 * n:], atol=1e-9)
    # the 2-D test statistic of every image observation: e^T Q_vv,a^-1 e
    # (groups with a direction of redundancy below MIN_REDUNDANCY are tested in the other direction only)
    e = -np.asarray(res.residuals_mm)
    blocks = [qvv[2 * a:2 * a + 2, 2 * a:2 * a + 2] for a in range(n)]
    T = np.array([e[a] @ np.linalg.solve(blocks[a], e[a]) for a in range(n)])
    full = np.array([np.linalg.eigvalsh(blocks[a] / np.outer(p.sd_mm[a], p.sd_mm[a]))[0] > MIN_REDUNDANCY
                     for a in range(n)])
    assert 0 < full.sum() < n
    np.testing.assert_allclose(rel.w[:n][full] ** 2, T[full], rtol=1e-6)
    assert np.all(rel.q[:n][full] == 2) and np.all(rel.q[:n][~full] == 1)


# --------------------------------------------------------------------------- the reproducers


def test_image_blunder_named_where_raw_residuals_point_elsewhere(gps_problem):
    """30 sigma on photo 3, point 405: the largest raw residual is on photo 2; the w-test names photo 3."""
    bad = _with_image_error(gps_problem, "3", "405", [30 * SD_IMG, 0.0])
    raw = adjust(bad)
    big = int(np.argmax(np.hypot(*np.asarray(raw.residuals_mm).T)))
    assert (bad.photo_ids[bad.photo_index[big]], bad.point_ids[bad.point_index[big]]) == ("2", "405")
    sr = snoop(bad, mode="remove")
    first = sr.blunders[0]
    assert (first.kind, first.photo, first.point, first.removed) == ("image", "3", "405", True)
    assert first.w > first.w_critical
    # the estimate recovers the injected 0.180 mm within 3 sd of the estimate (sigma / sqrt(r))
    assert abs(first.estimated_error[0] - 0.180) < 3 * SD_IMG / np.sqrt(first.redundancy)
    assert abs(first.estimated_error[1]) < 3 * SD_IMG / np.sqrt(first.redundancy)
    assert sr.result.chi2["passed"] and len(sr.result.residuals_mm) == 151 - len(sr.blunders)


def test_control_point_2m_in_E_named(gps_problem):
    sr = snoop(_with_control_error(gps_problem, "619", [2.0, 0.0, 0.0]), mode="report")
    first = sr.blunders[0]
    assert (first.kind, first.photo, first.point, first.removed) == ("control", None, "619", False)
    rel = reliability(sr.result)
    g = int(np.flatnonzero((rel.kind == "control") & (rel.point == "619"))[0])
    assert abs(first.estimated_error[0] - 2.0) < 3 * SD_CON / np.sqrt(rel.redundancy[g, 0])
    assert len(sr.result.constraint_residuals_m) == 8          # report: every observation kept


def test_control_height_error_below_mdb_is_not_detectable_above_it_named(gps_problem, gps):
    """1 m in h of control 619 is below its minimal detectable bias (r_h ~ 0.06: the six photos
    hardly check control heights), so no test can name it; 6 m (above the MDB) is named."""
    rel = reliability(gps)
    g = int(np.flatnonzero((rel.kind == "control") & (rel.point == "619"))[0])
    assert 0.04 < rel.redundancy[g, 2] < 0.08
    assert abs(rel.mdb[g, 2] - SD_CON * np.sqrt(rel.lam0 / rel.redundancy[g, 2])) < 1e-9
    assert rel.mdb[g, 2] > 4.0
    small = snoop(_with_control_error(gps_problem, "619", [0.0, 0.0, 1.0]), mode="report")
    assert all(b.kind == "image" for b in small.blunders)
    big = snoop(_with_control_error(gps_problem, "619", [0.0, 0.0, 6.0]), mode="report")
    assert (big.blunders[0].kind, big.blunders[0].point) == ("control", "619")
    assert abs(big.blunders[0].estimated_error[2] - 6.0) < 3 * SD_CON / np.sqrt(rel.redundancy[g, 2])


def test_gnss_constraint_blunder_named(gps_problem, gps):
    eo = np.asarray(gps.eo_params)
    sd = np.tile([0.5, 0.5, 0.5, np.radians(0.01), np.radians(0.01), np.radians(0.01)], (6, 1))
    obs = eo.copy()
    obs[1, 0] += 10.0                                    # photo 2, X0 off by 10 m (20 sigma)
    p = dataclasses.replace(gps_problem, eo_constraint_photo_index=np.arange(6), eo_constraint_params=obs,
                            eo_constraint_sd=sd)
    sr = snoop(p, mode="remove")
    eo_b = [b for b in sr.blunders if b.kind == "eo"]
    assert [(b.photo, b.point) for b in eo_b] == [("2", None)]
    assert eo_b[0].removed and abs(eo_b[0].estimated_error[0] - 10.0) < 1.5
    rel = reliability(adjust(p))
    r = rel.redundancy[np.isfinite(rel.redundancy)]
    assert abs(r.sum() - p.dof) < 1e-6


def test_three_blunders_removed_back_within_thesis_tables(gps_problem):
    """After removal the orientations and check points are back within the Table 6/7 tolerances.

    The tolerances (0.10 m, 0.005 deg) are far below the block's precision (sd of Y0 up to 4 m):
    removing most single observations of this six-photo block moves it beyond them.  So the
    blunders go on well-checked observations (redundancy > 0.5) whose removal does not, and
    the level is 1e-5, at which the three observations the thesis data itself has flagged at
    0.001 (w 4.26, 3.99, 3.56; kept by the thesis) stay in.
    """
    bad = _with_image_error(gps_problem, "3", "617", [25 * SD_IMG, -20 * SD_IMG])
    bad = _with_image_error(bad, "5", "625", [0.0, 40 * SD_IMG])
    bad = _with_image_error(bad, "4", "708", [-15 * SD_IMG, 10 * SD_IMG])
    raw = adjust(bad)
    assert not raw.chi2["passed"]
    sr = snoop(bad, mode="remove", level=1e-5)
    assert {(b.photo, b.point) for b in sr.blunders} == {("3", "617"), ("5", "625"), ("4", "708")}
    assert all(b.removed for b in sr.blunders)
    res = sr.result
    with open(THESIS_TABLES / "table6_eop_gps.csv", encoding="utf-8") as fh:
        t6 = {r["photo"]: r for r in csv.DictReader(line for line in fh if not line.startswith("#"))}
    ref = np.array([[float(t6[i][c]) for c in ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")]
                    for i in res.photo_ids])
    d = np.abs(np.c_[res.eo_params[:, :3], np.degrees(res.eo_params[:, 3:])] - ref)
    assert d[:, :2].max() < 0.10 and d[:, 2].max() < 0.03 and d[:, 3:].max() < 0.005
    with open(THESIS_TABLES / "table7_check_gps.csv", encoding="utf-8") as fh:
        t7 = [r for r in csv.DictReader(line for line in fh if not line.startswith("#"))
              if r["point"] not in ("mean", "std")]
    gp = Survey.load(THESIS_SURVEY).ground_points
    truth = {q: gp.enh_m[i] for i, q in enumerate(gp.point)}
    for r in t7:
        dq = truth[r["point"]] - res.point(r["point"])
        printed = np.array([float(r[k]) for k in ("dE", "dN", "dh")])
        assert np.abs(dq - printed)[:2].max() < 0.03 and abs(dq[2] - printed[2]) < 0.12


def test_two_ray_point_both_rays_named(gps_problem, gps):
    """A point on two photos: the two rays cannot be told apart, both are named and removed."""
    rays = np.bincount(gps_problem.point_index)
    j = int(np.flatnonzero((rays == 2) & (gps.point_role == "tie"))[0])
    a = int(np.flatnonzero(gps_problem.point_index == j)[0])
    photo, point = gps_problem.photo_ids[gps_problem.photo_index[a]], gps_problem.point_ids[j]
    sr = snoop(_with_image_error(gps_problem, photo, point, [0.0, 40 * SD_IMG]), mode="remove")
    pair = [b for b in sr.blunders if b.point == point]
    assert len(pair) == 2 and {b.photo for b in pair} >= {photo} and all(b.removed for b in pair)
    assert "cannot be told apart" in pair[0].note
    assert point not in set(sr.result.point_ids)


# --------------------------------------------------------------------------- trials (modest)


def _simulated(p, truth, rng):
    """The thesis geometry with exact observations of *truth* plus noise of the stated sigmas."""
    return resimulated(p, np.asarray(truth.eo_params), np.asarray(truth.points_m), rng)


@pytest.mark.slow
def test_snooping_trials_thesis_geometry(gps_problem, gps):
    """Seeded trials of 1 and 3 blunders of 10-50 sigma in random directions on the thesis geometry.

    Counted over the blunders above their minimal detectable bias (lambda >= lambda0; below it
    no test can see them, e.g. along the base of a point on two photos).  The full 100 trials of
    1, 3 and 5 blunders: benchmarks/bench_reliability.py.
    """
    rel0 = reliability(gps)
    found = wrong = trials = 0
    for n_bl, seed in ((1, 11), (3, 13)):
        rng = np.random.default_rng(seed)
        for _ in range(8):
            q = _simulated(gps_problem, gps, rng)
            idx = rng.choice(len(q.photo_index), n_bl, replace=False)
            size = rng.uniform(10, 50, n_bl)
            ang = rng.uniform(0, 2 * np.pi, n_bl)
            err = size[:, None] * np.c_[np.cos(ang), np.sin(ang)] * q.sd_mm[idx]
            # detectability of each blunder: lambda = nabla^T P Q_vv P nabla >= lambda0
            lam = [_noncentrality_of(rel0, q, i, d) for i, d in zip(idx, err)]
            if min(lam) < rel0.lam0:
                continue
            xy = np.array(q.xy_mm)
            xy[idx] += err
            sr = snoop(dataclasses.replace(q, xy_mm=xy), mode="remove")
            injected = {(q.photo_ids[q.photo_index[i]], q.point_ids[q.point_index[i]]) for i in idx}
            named = {(b.photo, b.point) for b in sr.blunders}
            trials += 1
            found += injected <= named
            wrong += len(named - injected)
    assert trials >= 10
    assert found / trials >= 0.9, (found, trials)
    assert wrong / trials <= 1.0, (wrong, trials)


def _noncentrality_of(rel, p, i, err):
    """lambda = nabla^T P Q_vv P nabla of a bias *err* (2,) on image observation *i*, with the
    diagonal of P Q_vv P only (r_k / sd_k^2; the x-y correlation of the residuals is left out:
    a filter of the trials, the benchmark uses the full 2 x 2 block)."""
    w = err / p.sd_mm[i]
    return float(np.sum(w**2 * rel.redundancy[i, :2]))


# --------------------------------------------------------------------------- robust


def test_robust_danish_recovers_orientations_within_3_sd():
    b = synthetic_block(3, 6, seed=2)
    p = b.problem
    rng = np.random.default_rng(4)
    idx = rng.choice(len(p.photo_index), max(3, len(p.photo_index) // 50), replace=False)
    xy = np.array(p.xy_mm)
    xy[idx] += rng.choice([-1, 1], (len(idx), 2)) * rng.uniform(20, 50, (len(idx), 2)) * b.image_sd_mm
    bad = dataclasses.replace(p, xy_mm=xy)
    for robust in ("danish", "huber"):
        sr = snoop(bad, mode="remove", robust=robust, start="plain")   # the IRLS of the group tests alone
        res = sr.result
        dev = np.abs(np.asarray(res.eo_params) - np.asarray(b.true_eo)) / res.eo_sd
        assert dev.max() < 3.0, (robust, dev.max())
        injected = {(p.photo_ids[p.photo_index[i]], p.point_ids[p.point_index[i]]) for i in idx}
        named = {(x.photo, x.point) for x in sr.blunders if x.removed}
        assert injected <= named, robust
        assert any(x.found_by == robust for x in sr.blunders)


def test_snooping_arguments_checked(gps_problem):
    with pytest.raises(ValueError, match=r"^`snooping` must be one of off, report, remove, got 'on'$"):
        snoop(gps_problem, mode="on")
    with pytest.raises(ValueError, match=r"^`robust` must be one of none, danish, huber, got 'l1'$"):
        snoop(gps_problem, robust="l1")


# --------------------------------------------------------------------------- CLI and outputs


def test_cli_json_blunders_and_exit_code(tmp_path):
    survey = tmp_path / "s"
    import shutil
    shutil.copytree(THESIS_SURVEY, survey)
    gp = (survey / "ground_points.csv").read_text().splitlines()
    for k, line in enumerate(gp):
        cells = line.split(",")
        if cells[0] == "619":
            cells[1] = repr(float(cells[1]) + 2.0)         # E + 2 m
            gp[k] = ",".join(cells)
    (survey / "ground_points.csv").write_text("\n".join(gp) + "\n")
    out = tmp_path / "o"
    r = CliRunner().invoke(cli, ["adjust", str(survey), "-o", str(out), "--json", "--snooping", "remove"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    b0 = s["blunders"][0]
    assert {"kind", "photo", "point", "w", "redundancy", "estimated_error", "removed"} <= set(b0)
    assert (b0["kind"], b0["photo"], b0["point"], b0["removed"]) == ("control", None, "619", True)
    assert b0["w"] > b0["w_critical"] and 0 < b0["redundancy"] < 1
    assert s["snooping"]["mode"] == "remove" and s["snooping"]["blunders_remain"] is False
    # blunders.csv lists the same, header first
    with open(out / "blunders.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert (rows[0]["kind"], rows[0]["point"], rows[0]["removed"]) == ("control", "619", "True")
    # the same survey reported, not removed: exit 3 and the verdict line
    r = CliRunner().invoke(cli, ["adjust", str(survey), "-o", str(tmp_path / "o2")])
    assert r.exit_code == 3
    assert "control point 619" in r.output and "KEPT" in r.output
    n = len(json.loads((tmp_path / "o2" / "summary.json").read_text())["blunders"])
    assert r.output.endswith("Warning: the global chi-square test of the variance factor REJECTED; "
                             f"{n} blunder(s) remain in the adjustment.\n")


def test_provenance_in_every_output(tmp_path):
    out = tmp_path / "o"
    r = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "-o", str(out), "--snooping", "off"])
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    prov = s["provenance"]
    from lidarcat import __version__
    assert prov["lidarcat_version"] == __version__
    for role, name in (("image_points", "image_points.csv"), ("survey.toml", "survey.toml"),
                       ("control_sets", "control_sets.csv")):
        assert prov["inputs"][role] == {"path": name, "sha256": hashlib.sha256(
            (THESIS_SURVEY / name).read_bytes()).hexdigest()}
    assert prov["parameters"]["snooping"] == "off" and prov["parameters"]["control"] == "gps"
    for csv_name in ("eop.csv", "points.csv", "residuals.csv", "check_covariance.csv"):
        side = json.loads((out / (csv_name + ".json")).read_text())
        assert side["provenance"] == prov and side["notes"] and side["file"] == csv_name
    # no clock time: a rerun writes the same bytes
    r2 = CliRunner().invoke(cli, ["adjust", str(THESIS_SURVEY), "-o", str(tmp_path / "o2"), "--snooping", "off"])
    assert r2.exit_code == 0
    assert (out / "eop.csv.json").read_bytes() == (tmp_path / "o2" / "eop.csv.json").read_bytes()


# --------------------------------------------------------------------------- lidarcat run


class _Ctx:
    """The part of :class:`lidarcat.pipeline.runner.Context` the adjust stage uses."""

    def __init__(self, survey, control):
        self.params = {"control": control}
        self._survey = survey

    def __getitem__(self, key):
        return {"survey": self._survey}[key]

    def progress(self, done, total):
        pass


def test_run_adjust_stage_and_run_line_name_the_blunders(tmp_path):
    from types import SimpleNamespace

    from lidarcat.cli.run import _text
    from lidarcat.stages import adjust as stage

    out = stage.run(_Ctx(Survey.load(THESIS_SURVEY), "gps"), tmp_path)
    bl = out["adjustment"]["blunders"]
    # family-wise 0.05 over the block's 159 tests: only photo 3 point 407 (w 4.26 > 4.00)
    assert [(b["kind"], b["photo"], b["point"], b["removed"]) for b in bl] == [("image", "3", "407", False)]
    assert (tmp_path / "blunders.csv").is_file() and (tmp_path / "reliability.csv").is_file()
    assert json.loads((tmp_path / "eop.csv.json").read_text())["provenance"]["parameters"]["snooping"] == "report"
    fake = SimpleNamespace(summary={"survey": {"name": "thesis"}, "runs": {"gps": out}}, stages=(),
                           outdir=tmp_path, ok=True, failed=(), tests_failed=())
    line = [t for t in _text(fake).splitlines() if t.startswith("  run gps:")][0]
    assert line.endswith("1 blunder(s) remain (w-test): image photo 3 point 407")


def test_thesis_block_at_a_fixed_level_flags_three_groups(gps_problem):
    """At 0.001 per test (critical w 3.42) the thesis data hold three rejected groups; at the
    family level 0.05 (critical w 4.00) only the first, w 4.26."""
    fixed = snoop(gps_problem, mode="report", level=0.001, multiple=False)
    assert [(b.photo, b.point, round(b.w, 2)) for b in fixed.blunders] == [
        ("3", "407", 4.26), ("2", "702", 3.88), ("5", "709", 3.56)]
    # several per round: every point of this block is seen from photos that share points with
    # all the others, so no two groups are separate: the classic one per round
    both = snoop(gps_problem, mode="report", level=0.001)
    assert [(b.photo, b.point, b.w, b.iteration) for b in both.blunders] == [
        (b.photo, b.point, b.w, b.iteration) for b in fixed.blunders]
    fam = snoop(gps_problem, mode="report")
    assert [(b.photo, b.point, round(b.w, 2), round(b.w_critical, 2)) for b in fam.blunders] == [
        ("3", "407", 4.26, 4.0)]


def test_report_lists_the_blunders(tmp_path):
    from lidarcat.survey import adjust_survey
    from lidarcat.report.document import load_adjustment, write_report

    _, out = adjust_survey(THESIS_SURVEY, control="gps", outdir=tmp_path / "adj")
    adj = load_adjustment(out)
    paths = write_report(tmp_path / "rep", adjustment_dir={"eop": adj["eop"], "points": adj["points"],
                                                           "summary": adj["summary"]})
    md = paths["markdown"].read_text()
    assert "Data snooping (report, alpha 0.000104, family-wise 0.05)" in md
    assert "| image | 3 | 407 |" in md
    assert md.count("no (kept)") == 1


def test_io_provenance_paths_and_hashes(tmp_path):
    from lidarcat import __version__
    from lidarcat._util import csv_sidecar_path, provenance, write_csv_atomic

    (tmp_path / "in").mkdir()
    f = tmp_path / "in" / "obs.csv"
    f.write_bytes(b"a,b\n1,2\n")
    prov = provenance({"obs": f}, {"level": 0.001}, root=tmp_path / "in")
    assert prov == {"lidarcat_version": __version__, "parameters": {"level": 0.001},
                    "inputs": {"obs": {"path": "obs.csv", "sha256": hashlib.sha256(b"a,b\n1,2\n").hexdigest()}}}
    outside = provenance({"obs": f}, {}, root=tmp_path / "elsewhere")
    assert outside["inputs"]["obs"]["path"] == f.as_posix()
    out = tmp_path / "o.csv"
    write_csv_atomic(out, ["x"], [[1]], provenance=prov)              # provenance alone writes the sidecar
    assert json.loads(csv_sidecar_path(out).read_text())["provenance"] == prov
    write_csv_atomic(out, ["x"], [[1]])                               # neither: the stale sidecar goes
    assert not csv_sidecar_path(out).exists()


def test_several_rejections_per_round_only_when_separate():
    """Blunders on photos far apart are removed in one round; two on neighbouring photos (which
    share points) in two rounds; the result is the one of one-at-a-time snooping."""
    b = synthetic_block(3, 8, seed=3)
    p = b.problem
    from lidarcat.bundle.reliability import _Neighbours

    near = _Neighbours(p)
    adj = near.adj.toarray() > 0
    ph = p.photo_index
    # one blunder on photo 0, one on a photo sharing no point with it, one on a neighbour of photo 0
    # (each on its own point seen on three or more photos)
    far = int(np.flatnonzero(~adj[0])[-1])
    neighbour = int(np.flatnonzero(adj[0])[1])
    rays = np.bincount(p.point_index)[p.point_index]
    idx, used = [], set()
    for k in (0, far, neighbour):
        i = next(int(i) for i in np.flatnonzero((ph == k) & (rays >= 3)) if p.point_index[i] not in used)
        used.add(p.point_index[i])
        idx.append(i)
    xy = np.array(p.xy_mm)
    xy[idx] += np.array([[40.0, 0.0], [0.0, -40.0], [30.0, 30.0]]) * p.sd_mm[idx]
    bad = dataclasses.replace(p, xy_mm=xy)
    one = snoop(bad, mode="remove", start="plain", multiple=False, backward=False)
    several = snoop(bad, mode="remove", start="plain", backward=False)
    named = [(x.photo, x.point) for x in one.blunders]
    assert len(named) == 3 and {(x.photo, x.point) for x in several.blunders} == set(named)
    assert [x.iteration for x in one.blunders] == [1, 2, 3]
    rounds = {(x.photo, x.point): x.iteration for x in several.blunders}
    assert sorted(rounds.values()) == [1, 1, 2]             # three blunders, two rounds
    far_key = (p.photo_ids[far], p.point_ids[p.point_index[idx[1]]])
    assert rounds[far_key] == 1                             # the separate one goes with the first
    assert several.n_adjustments == one.n_adjustments - 1
    np.testing.assert_allclose(several.result.eo_params, one.result.eo_params, atol=1e-9)


def test_rejection_limit_stops_and_says_so():
    """A limit on the rejections leaves the rest reported as remaining (exit 3 on the CLI)."""
    b = synthetic_block(3, 8, seed=3)
    p = b.problem
    rays = np.bincount(p.point_index)[p.point_index]
    idx = np.flatnonzero(rays >= 3)[[0, 200, 400]]
    xy = np.array(p.xy_mm)
    xy[idx] += 40 * p.sd_mm[idx]
    bad = dataclasses.replace(p, xy_mm=xy)
    sr = snoop(bad, mode="remove", start="plain", max_rejections=1, backward=False)
    assert sr.more_remain and sr.blunders_remain and len([x for x in sr.blunders if x.removed]) == 1
    assert sr.summary()["snooping"]["blunders_remain"] is True
    full = snoop(bad, mode="remove", backward=False)            # default limit: max(100, 5 % of the tests)
    assert not full.more_remain and len(full.blunders) >= 3
