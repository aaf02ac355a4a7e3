"""Regression of every released table of the thesis against `lidarcat run` on the embedded block.

Fierro Sanhueza (2007), chapter 4 and Appendices 2-3: the GPS-controlled run (Tables 6, 7,
Appendices 2.1, 3.1), the LiDAR-controlled run (Table 8, Appendices 2.2, 3.2, Table 9) and the
comparison of the two runs (section 4.4: Tables 10-15 and the statistics of 4.4.4.1-4.4.4.4).
The printed tables are in tests/data/thesis/ (each file cites its table). Tolerances: the
printed precision (1.5 units of the last printed digit: 0.0015 for 3 decimals), or, where the
rounding of the published photo coordinates (0.001 mm) limits the reproduction, those of the
GPS run stated by the issue: EOP 0.10 m / 0.005 deg, points 0.03 m E/N and 0.12 m h, sds 2 %.
Every misprint a test meets is named by its errata.json entry (listed in docs/errata.md) and
checked as a fact: the printed value disagrees, the corrected one agrees.

`python -m pytest -k thesis` runs them all.
"""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import THESIS_TABLES

from lidarcat.accuracy.checkpoints import read_points
from lidarcat.pipeline import run_pipeline
from lidarcat.stages.thesis import STATISTICS, table13_statistics

EOP = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
EOP_PRINTED = ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")


def _csv(name: str) -> list[dict[str, str]]:
    with open(THESIS_TABLES / name, encoding="utf-8") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _json(name: str) -> dict:
    return json.loads((THESIS_TABLES / name).read_text(encoding="utf-8"))


def _floats(rows: list[dict[str, str]], cols) -> np.ndarray:
    return np.array([[float(r[c]) for c in cols] for r in rows])


ERRATA = {e["where"]: e for e in _json("errata.json")}


def _erratum(where: str) -> dict:
    """The errata.json entry a test depends on (KeyError when it is not documented)."""
    return ERRATA[where]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """`lidarcat run` on the embedded thesis block (both runs, the comparison, the thesis stage)."""
    out = tmp_path_factory.mktemp("thesis_tables") / "out"
    res = run_pipeline(None, out)
    assert res.ok, res.summary
    return res


def _eop(run, name: str) -> dict[str, np.ndarray]:
    with open(run.outdir / f"adjust-{name}" / "eop.csv", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    return {r["photo"]: (np.array([float(r[c]) for c in EOP]),
                         np.array([float(r[f"sd_{c}"]) for c in EOP])) for r in rows}


def _points(run, name: str):
    p = read_points(run.outdir / f"adjust-{name}" / "points.csv")
    idx = p.index()
    return p, idx


def _reference() -> dict[str, np.ndarray]:
    from lidarcat.survey.folder import Survey

    gp = Survey.load(None).ground_points
    return {str(q): e for q, e in zip(gp.point, gp.enh_m)}


def _check_point_diffs(run, name: str, table: str) -> tuple[list[dict[str, str]], np.ndarray]:
    """Rows of a printed discrepancy table (reference minus adjusted) and |this run - printed|, m."""
    rows = [r for r in _csv(table) if r["point"] not in ("mean", "std")]
    ref = _reference()
    pts, idx = _points(run, name)
    mine = np.array([ref[r["point"]] - pts.xyz[idx[r["point"]]] for r in rows])
    return rows, np.abs(mine - _floats(rows, ("dE", "dN", "dh")))


def _summary(run, name: str) -> dict:
    return json.loads((run.outdir / f"adjust-{name}" / "summary.json").read_text(encoding="utf-8"))


# --------------------------------------------------------------------------- 4.1-4.2: the points

#: Table 3: the points of the phototriangulation by type (code 700 LiDAR, 400 pass, 600 GPS)
TABLE3 = {
    "lidar": "701 702 703 704 705 706 707 708 709 710 711 712 713 717 718 719 720 721",
    "pass": "401 403 405 406 407 408 409 410 411 412 413 414 415 416 418",
    "gps": "601 603 604 605 606 615 616 617 618 619 620 621 622 623 624 625 626 627 661 662 664",
}


def test_thesis_table3_point_types(run):
    from lidarcat.survey.folder import Survey

    s = Survey.load(None)
    by_source = {src: sorted(str(q) for q, so in zip(s.ground_points.point, s.ground_points.source) if so == src)
                 for src in ("lidar", "gps")}
    assert by_source == {k: TABLE3[k].split() for k in ("lidar", "gps")}
    pts, _ = _points(run, "gps")  # every adjusted point is one of Table 3 (pass point 417 left out)
    assert sorted(pts.ids) == sorted(" ".join(TABLE3.values()).split())


def test_thesis_tables4_5_point_708_and_the_lidar_points():
    """Table 5's LiDAR coordinates are the survey's; Table 4's planes intersect in Table 5's point 708
    within the rounding of the printed plane parameters (0.39 / 0.52 / 0.055 m, see test_control)."""
    from lidarcat.control.vertices import intersect_planes
    from lidarcat.control.facets import Plane

    ref = _reference()
    rows = _csv("table5_lidar_points.csv")
    assert len(rows) == 18
    for r in rows:
        np.testing.assert_allclose(ref[r["point"]], [float(r[c]) for c in ("E", "N", "h")], atol=0.0015)
    t4 = _floats(_csv("table4_planes_708.csv"), ("a", "b", "c", "d"))
    cp = intersect_planes([Plane.from_abcd(row, centroid_m=[677872.0, 7183983.0, 918.0]) for row in t4],
                          point_id="708")
    assert np.all(np.abs(cp.enh_m - ref["708"]) < [0.39, 0.52, 0.055])


# --------------------------------------------------------------------------- the GPS-controlled run

def test_thesis_table6_eop_gps_run(run):
    rows = _csv("table6_eop_gps.csv")  # errata applied in the file (photo 1 X0 and omega)
    mine = _eop(run, "gps")
    val = np.array([mine[r["photo"]][0] for r in rows])
    sd = np.array([mine[r["photo"]][1] for r in rows])
    printed = _floats(rows, EOP_PRINTED)
    d = np.abs(val - printed)
    assert d[:, :3].max() < 0.10 and d[:, 3:].max() < 0.005, d
    np.testing.assert_allclose(sd, _floats(rows, [f"sd_{c}" for c in EOP_PRINTED]), rtol=0.02)
    # erratum: the printed photo-1 X0 677343.860 and omega -4.72844 are 1 m and 0.04 deg off
    e = _erratum("Table 6 (EOP, GPS run), photo 1, X0")
    assert abs(mine["1"][0][0] - e["printed"]) > 0.9 and abs(mine["1"][0][0] - e["corrected"]) < 0.10
    e = _erratum("Table 6, photo 1, omega")
    assert abs(mine["1"][0][3] - e["printed"]) > 0.03 and abs(mine["1"][0][3] - e["corrected"]) < 0.005


def test_thesis_table7_check_points_gps_run(run):
    rows, d = _check_point_diffs(run, "gps", "table7_check_gps.csv")
    assert d[:, :2].max() < 0.03 and d[:, 2].max() < 0.12, d
    assert len(rows) == 13


def test_thesis_appendix3_1_points_gps_run(run):
    rows = _csv("appendix3_1_points_gps.csv")
    pts, idx = _points(run, "gps")
    xyz = np.array([pts.xyz[idx[r["point"]]] for r in rows])
    d = np.abs(xyz - _floats(rows, ("E", "N", "h")))
    assert len(rows) == 54 and d[:, :2].max() < 0.03 and d[:, 2].max() < 0.12
    sd = np.array([pts.sd[idx[r["point"]]] for r in rows])
    np.testing.assert_allclose(sd, _floats(rows, ("sd_E", "sd_N", "sd_h")), rtol=0.02)
    assert [r["role"] == "control" for r in rows] == [pts.roles[idx[r["point"]]] == "control" for r in rows]


def _appendix2(run, name: str, key: str) -> tuple[dict, dict]:
    """Appendix 2.x against this run's summary: dof, v'Pv (0.5, as the GPS run), sigma0^2 (printed
    with 2 decimals), chi-square range (Fisher's approximation, erratum); returns (printed, ours)."""
    app = _json("appendix2_both_runs.json")[key]
    s = _summary(run, name)
    assert s["dof"] == app["dof"] == 128
    assert abs(s["vtpv"] - app["chi2_computed"]) <= 0.5
    assert abs(s["sigma0_sq"] - app["variance_a_posteriori"]) <= 0.01
    assert s["chi2_pass"] is True
    np.testing.assert_allclose([s["chi2_lower_fisher"], s["chi2_upper_fisher"]], app["chi2_range_5pct"],
                               atol=0.005)  # printed with 2 decimals
    return app, s


def test_thesis_appendix2_1_gps_run(run):
    app, _ = _appendix2(run, "gps", "2.1_gps")
    assert (app["chi2_computed"], app["variance_a_posteriori"]) == (148.35, 1.16)


# --------------------------------------------------------------------------- the LiDAR-controlled run

def test_thesis_table8_eop_lidar_run(run):
    rows = _csv("table8_eop_lidar.csv")  # as printed
    mine = _eop(run, "lidar")
    val = np.array([mine[r["photo"]][0] for r in rows])
    printed = _floats(rows, EOP_PRINTED)
    e = _erratum("Table 8 (EOP, LiDAR run), photo 5, kappa")
    assert printed[4, 5] == e["printed"] and abs(val[4, 5] - e["printed"]) > 0.2  # the misprint
    printed[4, 5] = e["corrected"]
    d = np.abs(val - printed)
    assert d[:, :3].max() < 0.10 and d[:, 3:].max() < 0.005, d
    sd = np.array([mine[r["photo"]][1] for r in rows])
    np.testing.assert_allclose(sd, _floats(rows, ("sX0", "sY0", "sZ0", "somega_deg", "sphi_deg", "skappa_deg")),
                               rtol=0.02)


def test_thesis_appendix3_2_points_lidar_run(run):
    rows = _csv("appendix3_2_points_lidar.csv")
    pts, idx = _points(run, "lidar")
    xyz = np.array([pts.xyz[idx[r["name"]]] for r in rows])
    d = np.abs(xyz - _floats(rows, ("E", "N", "h")))
    assert len(rows) == 54 and d[:, :2].max() < 0.03 and d[:, 2].max() < 0.12, d.max(axis=0)
    sd = np.array([pts.sd[idx[r["name"]]] for r in rows])
    np.testing.assert_allclose(sd, _floats(rows, ("sE", "sN", "sh")), rtol=0.02)
    controls = sorted(r["name"] for r in rows if r["type"] == "control")
    assert controls == ["701", "703", "705", "706", "707", "712", "719", "721"]
    assert controls == sorted(q for q, role in zip(pts.ids, pts.roles) if role == "control")


def test_thesis_appendix2_2_lidar_run(run):
    app, s = _appendix2(run, "lidar", "2.2_lidar")
    assert (app["chi2_computed"], app["variance_a_posteriori"]) == (149.12, 1.16)
    # the printed range is Fisher's approximation, not the chi-square quantiles (erratum)
    e = _erratum("Appendix 2 chi-square range (5%)")
    assert abs(s["chi2_lower"] - 98.58) < 0.005 and "98.58" in e["corrected"]
    # "desvio padrao medio dos pontos fixos": sample sd of the control residuals; "... livres": RMS sd
    np.testing.assert_allclose([s["sd_control_residuals_m"][k] for k in "ENh"],
                               [app["mean_std_fixed_points_m"][k] for k in "ENh"], atol=0.0015)
    np.testing.assert_allclose([s["rms_sd_points_m"][k] for k in "ENh"],
                               [app["mean_std_free_points_m"][k] for k in "ENh"], atol=0.0015)
    # "desvio padrao medio das observacoes": per-photo RMS image residual (printed to 1 um)
    e = _erratum("Appendix 2 'Desvio padrao medio das observacoes'")
    misprinted = {("2", "y_mm"): 0.0047, ("6", "x_mm"): 0.0015}  # the evidence of the erratum
    assert "2.2 photo 2 y 0.006" in e["printed"] and "2.2 photo 6 x 0.002" in e["printed"]
    for photo, axes in app["mean_std_obs_mm"].items():
        for axis, printed in axes.items():
            mine = s["rms_image_residuals_mm"][photo][axis[0]]
            if (photo, axis) in misprinted:
                assert abs(mine - printed) > 0.0005 and abs(mine - misprinted[photo, axis]) < 0.00015
            else:
                assert abs(mine - printed) <= 0.0006, (photo, axis, mine, printed)


def test_thesis_table9_lidar_check_points_lidar_run(run):
    rows, d = _check_point_diffs(run, "lidar", "table9_check_lidar.csv")
    assert len(rows) == 10 and d[:, :2].max() < 0.03 and d[:, 2].max() < 0.12, d
    # plani is the planimetric resultant of the printed dE, dN
    np.testing.assert_allclose(np.hypot(*_floats(rows, ("dE", "dN")).T), _floats(rows, ("plani",))[:, 0],
                               atol=0.0015)


# --------------------------------------------------------------------------- section 4.4: the two runs

def test_thesis_table10_lidar_points_gps_run_minus_lidar(run):
    rows = _csv("table10_lidar_points_gps_run.csv")
    ref = _reference()
    pts, idx = _points(run, "gps")
    mine = np.array([pts.xyz[idx[r["point"]]] - ref[r["point"]] for r in rows])
    printed = _floats(rows, ("dE", "dN", "dh"))
    k705 = [r["point"] for r in rows].index("705")
    e = _erratum("Table 10, point 705, dN")
    assert printed[k705, 1] == e["printed"] and abs(mine[k705, 1] - 0.234) < 0.0015  # "0.234 from my adjustment"
    assert abs(mine[k705, 1] - e["printed"]) > 0.003
    ok = np.arange(len(rows)) != k705
    d = np.abs(mine - printed)
    assert d[ok, :2].max() < 0.03 and d[:, 2].max() < 0.12, d
    assert len(rows) == 18


def test_thesis_table11_eop_gps_minus_lidar_run(run):
    rows = _csv("table11_eop_differences.csv")
    g, li = _eop(run, "gps"), _eop(run, "lidar")
    mine = np.array([g[r["photo"]][0] - li[r["photo"]][0] for r in rows])
    printed = _floats(rows, ("dX0", "dY0", "dZ0", "domega_deg", "dphi_deg", "dkappa_deg"))
    e = _erratum("Table 11, photo 5, domega")
    assert printed[4, 3] == e["printed"] == printed[3, 3]  # a copy of photo 4
    assert abs(mine[4, 3] - e["printed"]) > 0.003
    printed[4, 3] = e["corrected"]
    d = np.abs(mine - printed)
    assert d[:, :3].max() < 0.10 and d[:, 3:].max() < 0.005, d
    # Table 11 = Table 6 - Table 8 (both corrected) to the printed precision
    t6 = _floats(_csv("table6_eop_gps.csv"), EOP_PRINTED)
    t8 = _floats(_csv("table8_eop_lidar.csv"), EOP_PRINTED)
    t8[4, 5] = _erratum("Table 8 (EOP, LiDAR run), photo 5, kappa")["corrected"]
    np.testing.assert_allclose((t6 - t8)[:, :3], printed[:, :3], atol=0.0015)
    np.testing.assert_allclose((t6 - t8)[:, 3:], printed[:, 3:], atol=0.000015)


def test_thesis_table12_free_points_gps_minus_lidar_run(run):
    groups = _json("table12_free_points.json")["groups"]
    pg, ig = _points(run, "gps")
    pl, il = _points(run, "lidar")
    free = [q for q in pg.ids if q in il and pg.roles[ig[q]] != "control" and pl.roles[il[q]] != "control"]
    counts = {}
    for group, prefix in (("lidar_700", "7"), ("pass_400", "4"), ("gps_600", "6")):
        d = np.array([pg.xyz[ig[q]] - pl.xyz[il[q]] for q in free if q.startswith(prefix)])
        counts[group] = len(d)
        d = np.c_[d, np.hypot(d[:, 0], d[:, 1])]
        for k, c in enumerate(("dE", "dN", "dh", "plani")):
            tol = 0.12 if c == "dh" else 0.03
            assert abs(d[:, k].mean() - groups[group]["mean"][c]) < tol, (group, c)
            assert abs(d[:, k].std(ddof=1) - groups[group]["std"][c]) < tol, (group, c)
    # "10 LiDAR check points, 15 pass points, 13 GPS check points"
    assert counts == {"lidar_700": 10, "pass_400": 15, "gps_600": 13}


def test_thesis_table13_gps_points_lidar_run(run):
    rows, d = _check_point_diffs(run, "lidar", "table13_gps_points_lidar_run.csv")
    assert len(rows) == 21 and d[:, :2].max() < 0.03 and d[:, 2].max() < 0.12, d


# --------------------------------------------------------------------------- 4.4.4.1-4.4.4.4, Tables 14/15

def _table13_printed() -> tuple[np.ndarray, np.ndarray]:
    rows = _csv("table13_gps_points_lidar_run.csv")
    return _floats(rows, ("dE", "dN", "dh")), _floats(rows, ("plani",))[:, 0]


def _get(doc: dict, key: str):
    for part in key.split("."):
        doc = doc[part]
    return doc


@pytest.mark.parametrize("key,decimals", [(k, nd) for k, _, nd, _ in STATISTICS])
def test_thesis_section_4_4_4_statistics_of_the_printed_table13(key, decimals):
    """Each printed statistic follows from the printed Table 13 with the thesis's arithmetic
    (its rounded plani column, t = 1.33) to the printed precision, except the two errata."""
    printed = _json("section_4_4_4_statistics.json")
    d, plani = _table13_printed()
    got = _get(table13_statistics(d, plani=plani, t_alpha=printed["t_alpha"], alpha=printed["alpha"]), key)
    want = _get(printed, key)
    tol = 1.5 * 10.0 ** -decimals
    if key == "mu_upper.mu_plan_le":
        # documented discrepancy: 0.441 is not reproducible with t = 1.33 (0.411); it needs t = 2.11
        e = _erratum("section 4.4.4.3, mu_plan <= 0.441")
        assert want == e["printed"] == 0.441
        assert abs(got - 0.411) <= tol and abs(got - want) > 0.025
        sp = d.shape[0] ** -0.5 * np.std(plani, ddof=1)
        assert abs((want - np.mean(plani)) / sp - 2.11) < 0.01
    elif key == "chi2_computed.chi2_altim":
        # erratum: printed 14.166 with "sigma0 = 0.67 m"; the computation used 2/3 m (14.170), not 0.67
        e = _erratum("section 4.4.4.4, chi2_altim")
        assert "2/3" in e["corrected"] and abs(got - 14.170) <= tol and abs(got - want) < 0.005
        n, s = len(d), np.std(d[:, 2], ddof=1)
        assert abs((n - 1) * s ** 2 / 0.67 ** 2 - 14.029) <= tol
    else:
        assert abs(got - want) <= tol, (key, got, want)


def test_thesis_section_4_4_4_erratum_eq45_uses_chi2_alpha():
    """The sigma bounds 0.225 / 0.711 need chi2_{0.10,20} = 12.443; eq. 45's chi2_{0.90,20} gives 0.149 / 0.470."""
    e = _erratum("eq. 45 (upper bound of sigma)")
    d, plani = _table13_printed()
    n = len(d)
    for s, printed, wrong in ((np.std(plani, ddof=1), 0.225, 0.149), (np.std(d[:, 2], ddof=1), 0.711, 0.470)):
        assert abs(math.sqrt((n - 1) * s ** 2 / 12.443) - printed) <= 0.0015
        assert abs(math.sqrt((n - 1) * s ** 2 / 28.412) - wrong) <= 0.0015
    assert "12.443" in e["corrected"]


@pytest.mark.parametrize("table,column", [("table14", "plani"), ("table15", "dh")])
def test_thesis_tables14_15_normal_scores(table, column):
    printed = _json("section_4_4_4_statistics.json")[table]
    d, plani = _table13_printed()
    x = plani if column == "plani" else d[:, 2]
    got = table13_statistics(d, plani=plani)[table]
    assert [r["pos"] for r in got] == [r["pos"] for r in printed] == list(range(1, 22))
    np.testing.assert_allclose([r["X"] for r in got], [r["X"] for r in printed], atol=0.0015)
    np.testing.assert_allclose([r["prob_acum"] for r in got], [r["prob_acum"] for r in printed], atol=0.015)
    np.testing.assert_allclose([r["Z"] for r in got], [r["Z"] for r in printed], atol=0.015)
    # the printed rows are Table 13's points in the order of X
    rows = _csv("table13_gps_points_lidar_run.csv")
    order = np.argsort(x, kind="stable")
    assert [rows[i]["point"] for i in order] == [r["point"] for r in printed] or \
        np.allclose(np.sort(x), [r["X"] for r in printed], atol=0.0015)


def test_thesis_section_4_4_4_verdicts_of_this_run(run):
    """This run's own adjustment reaches the thesis's verdicts on Table 13: normal (Filliben r above
    0.961), a trend in E and N but not in h (|t| vs 1.725 two-sided 10 %), chi-square passes, PEC A."""
    det = json.loads((run.outdir / "thesis" / "thesis_4_4.json").read_text())
    s = det["table13_this_run"]
    assert s["filliben"]["r_plan"] > 0.961 and s["filliben"]["r_altim"] > 0.961
    assert abs(s["filliben"]["r_plan"] - 0.973) <= 0.0015 and abs(s["filliben"]["r_altim"] - 0.978) <= 0.0015
    assert abs(s["trend_t"]["t_E"]) > 1.725 and abs(s["trend_t"]["t_N"]) > 1.725 and abs(s["trend_t"]["t_h"]) < 1.725
    assert s["chi2_computed"]["chi2_plan"] < 28.412 and s["chi2_computed"]["chi2_altim"] < 28.412
    assess = json.loads((run.outdir / "assess-lidar" / "assessment.json").read_text())
    assert assess["settings"]["plotting_position"] == "hazen"
    assert assess["standards"]["pec"]["class"] == {"planimetric": "A", "altimetric": "A"}


# --------------------------------------------------------------------------- what a user sees

def test_thesis_run_prints_table13_statistics_and_reports_section_4_4(run):
    from lidarcat.cli.main import cli

    r = CliRunner().invoke(cli, ["run", "-o", str(run.outdir)])  # stages reused: fast
    assert r.exit_code == 0, r.output
    line = next(ln for ln in r.output.splitlines() if "Table 13, recomputed from its printed values" in ln)
    assert "Filliben r plan/h 0.973/0.978 (critical 0.961)" in line and "t E/N/h -6.55/-5.61/-1.35" in line
    assert ("thesis section 4.4: 19 of 21 statistics and 20 of 20 table comparisons reproduced; not "
            "reproduced (errata, see the report): mu_upper.mu_plan_le, chi2_computed.chi2_altim") in r.output
    md = (run.outdir / "report" / "index.md").read_text()
    section = md[md.index("## Thesis section 4.4"):]
    for table in ("Table 8", "Appendix 3.2", "Appendix 2.2", "Table 9", "Table 10", "Table 11", "Table 12",
                  "Table 13", "Table 14", "Table 15"):
        assert f"| {table}" in section or f"({table})" in section, table
    assert "| mean bound mu_plan <= (4.4.4.3) | 0.441 | 0.4107 | 0.4116 | NO | [E] section 4.4.4.3" in section
    assert "[E] Table 8 (EOP, LiDAR run), photo 5, kappa: printed 68.21269, corrected 67.98952" in section
    assert "| 1 | 605 | 0.067 | 0.067 |" in section and "| 21 | 605 | 0.876 | 0.876 |" in section  # Tables 14, 15
    html = (run.outdir / "report" / "index.html").read_text()
    assert "<h2>Thesis section 4.4</h2>" in html


def test_thesis_errata_are_all_listed_in_docs_with_their_test():
    text = (THESIS_TABLES.parents[2] / "docs" / "errata.md").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln.startswith("| ") and ln[2].isdigit()]
    assert len(rows) == len(ERRATA) == 18
    for where in ERRATA:
        assert f"| {where.replace('|', chr(92) + '|')} |" in text, where
    # the package ships the same list the tests use
    shipped = json.loads((THESIS_TABLES.parents[2] / "data" / "thesis" / "published" / "errata.json").read_text())
    assert shipped == _json("errata.json")
