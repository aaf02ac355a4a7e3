"""Map-accuracy standards: the worked examples and oracles of STANDARDS.md."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.errors import AssessmentError
from lidarcat.accuracy.standards import (
    STANDARD_NAMES,
    asprs2023_product_rmse,
    classify,
    classify_asprs2014,
    classify_asprs2023,
    classify_nssda,
    classify_pec,
    filliben_critical_value,
    filliben_table,
    load_standard,
    nssda_horizontal_accuracy,
    pec_tolerances,
)


def test_every_data_file_is_versioned_and_sourced():
    for name in STANDARD_NAMES:
        data = load_standard(name)
        assert data["version"] and data["sources"] and data["title"] and "open_items" in data


def test_decreto_1_10000_class_a():
    t = pec_tolerances("pec", 10000)
    assert (t["A"]["plan_pec_m"], t["A"]["plan_ep_m"]) == (5.0, 3.0)
    assert (t["C"]["plan_pec_m"], t["C"]["plan_ep_m"]) == (10.0, 6.0)


def test_decreto_thesis_settings_1_2000_eq_2m():
    # thesis 3.3.4: class A at 1:2000 -> PEC 1.0 m, EP 0.60 m; Eq 2 m -> PEC 1.0 m, EP 0.67 m
    a = pec_tolerances("pec", 2000, 2.0)["A"]
    assert a["plan_pec_m"] == pytest.approx(1.0) and a["plan_ep_m"] == pytest.approx(0.6)
    assert a["alt_pec_m"] == pytest.approx(1.0) and round(a["alt_ep_m"], 2) == 0.67


def test_decreto_table_used_literally_not_derived():
    # the tabulated pairs do not satisfy PEC = 1.6449 EP: B is 0.8 / 0.5 mm
    b = pec_tolerances("pec", 1000)["B"]
    assert (b["plan_pec_m"], b["plan_ep_m"]) == (0.8, 0.5)


def test_pec_pcd_1_25000_class_a():
    t = pec_tolerances("pec-pcd", 25000, 10)["A"]
    assert (t["plan_pec_m"], t["plan_ep_m"]) == (7.0, 4.25)
    assert t["alt_pec_m"] == pytest.approx(2.7) and t["alt_ep_m"] == pytest.approx(1.667, abs=5e-4)
    # default contour interval from the table for a tabulated scale, said in eq_source
    d = pec_tolerances("pec-pcd", 25000)["A"]
    assert d["eq_m"] == 10 and d["eq_source"].startswith("default for 1:25000")


def test_pec_pcd_open_item_is_reported():
    d = np.array([[0.1, 0.1, 0.1]] * 5)
    r = classify_pec(d, 50000, standard="pec-pcd")
    assert any("open item 1" in n and "5.50" in n for n in r.notes)
    # the documented (fraction) value is used: 0.27 * 20 m = 5.4 m
    assert r.evidence["classes"][0]["altimetric"]["pec_m"] == pytest.approx(5.4)


def test_pec_arbitrary_scale_and_missing_contour_interval():
    t = pec_tolerances("pec", 3000)
    assert t["A"]["plan_pec_m"] == pytest.approx(1.5) and t["A"]["alt_pec_m"] is None
    r = classify_pec(np.zeros((3, 3)) + 0.1, 3000)
    assert r.classes["altimetric"] is None
    assert any("no contour interval" in n for n in r.notes)
    with pytest.raises(AssessmentError, match="positive scale denominator"):
        pec_tolerances("pec", -5)


def test_pec_90_percent_rule_and_ep_rule():
    # 10 points at 1:2000 class A (PEC 1.0 m, EP 0.6 m): one point over the PEC is allowed (90 %)
    dp = np.array([0.2] * 9 + [1.05])
    d = np.column_stack([dp, np.zeros(10), np.zeros(10)])
    r = classify_pec(d, 2000, 2.0)
    a = r.evidence["classes"][0]["planimetric"]
    assert a["fraction_within_pec"] == pytest.approx(0.9) and a["passed_90_percent"] is True
    assert r.classes["planimetric"] == "A"
    # two points over: class A fails on the 90 % rule, class B (PEC 1.6 m) passes
    dp2 = np.array([0.2] * 8 + [1.05, 1.05])
    r2 = classify_pec(np.column_stack([dp2, np.zeros(10), np.zeros(10)]), 2000, 2.0)
    assert r2.classes["planimetric"] == "B"
    # the thesis chi-square rule (eq. 46, sigma0 = EP 0.6 m) on the same sample: 9 s^2 / 0.36 with
    # 9 s^2 = 8 (0.2 - 0.37)^2 + 2 (1.05 - 0.37)^2 = 1.156, against chi2(9, 0.90) = 14.684: class A
    a2 = r2.evidence["classes"][0]["planimetric"]
    assert a2["chi2"] == pytest.approx(1.156 / 0.36, abs=1e-9)
    assert a2["chi2_critical"] == pytest.approx(14.684, abs=5e-4) and a2["chi2_passed"] is True
    assert r2.evidence["chi2_class"]["planimetric"] == "A"
    # RMS above every EP: no class, and the label states the EP found (Art. 10)
    r3 = classify_pec(np.column_stack([np.full(10, 1.5), np.zeros(10), np.zeros(10)]), 2000, 2.0)
    assert r3.classes["planimetric"] == "none" and "EP found 1.500 m" in r3.label


def test_pec_boundary_uses_less_or_equal():
    d = np.column_stack([np.full(10, 0.6), np.zeros(10), np.zeros(10)])  # RMS = EP exactly
    assert classify_pec(d, 2000, 2.0).classes["planimetric"] == "A"


def test_nssda_factors_and_ratio_switch():
    acc, how = nssda_horizontal_accuracy(1.0, 1.0)
    assert acc == pytest.approx(1.7308 * math.sqrt(2), abs=1e-9) and acc == pytest.approx(2.4477, abs=1e-4)
    assert how.startswith("case 1")
    acc2, how2 = nssda_horizontal_accuracy(1.0, 0.6)
    assert acc2 == pytest.approx(2.4477 * 0.8, abs=1e-12) and how2.startswith("case 2")
    acc3, how3 = nssda_horizontal_accuracy(1.0, 0.59)
    assert how3.startswith("ratio < 0.6")
    e = np.random.default_rng(0).standard_normal((400_000, 2)) * [1.0, 0.59]
    assert np.mean(np.hypot(e[:, 0], e[:, 1]) <= acc3) == pytest.approx(0.95, abs=0.002)
    r = classify_nssda(np.column_stack([np.full(4, 0.1), np.full(4, -0.1), np.full(4, 0.2)]))
    assert r.evidence["accuracy_z_95_m"] == pytest.approx(1.96 * 0.2)
    assert "Tested 0.245 (m) horizontal accuracy at 95% confidence level" in r.label
    assert any("at least 20 check points" in n for n in r.notes)
    assert not any("0.6" in n for n in r.notes)  # the open item is stated only when it is used
    r2 = classify_nssda(np.column_stack([np.full(4, 0.1), np.full(4, -0.05), np.full(4, 0.2)]))
    assert r2.evidence["horizontal_formula"].startswith("ratio < 0.6")
    assert any("lidarcat integrates the bivariate normal" in n for n in r2.notes)


def test_asprs2023_worked_example():
    assert round(asprs2023_product_rmse(1.00, 2.0), 2) == 2.24


def test_asprs2023_includes_checkpoint_error():
    d = np.column_stack([np.full(30, 0.01), np.full(30, -0.01), np.full(30, 0.02)])
    sd = np.tile([0.02, 0.02, 0.03], (30, 1))
    r = classify_asprs2023(d, checkpoint_sd_m=sd)
    ev = r.evidence
    assert ev["rmse_h1_m"] == pytest.approx(math.sqrt(2) * 0.01)
    assert ev["rmse_h2_m"] == pytest.approx(math.sqrt(2) * 0.02)  # sqrt(2) x per-axis survey RMSE
    assert ev["rmse_h_m"] == pytest.approx(math.hypot(math.sqrt(2) * 0.01, math.sqrt(2) * 0.02))
    assert ev["rmse_v_m"] == pytest.approx(math.hypot(0.02, 0.03))
    assert r.classes == {"planimetric": "3.2-cm", "altimetric": "3.7-cm"}
    assert any("not 2x more accurate" in n for n in r.notes)
    r0 = classify_asprs2023(d)
    assert any("survey accuracy unknown" in n for n in r0.notes)
    # targets are tested on the product RMSE (fit + survey): RMSE_H 3.16 cm, RMSE_V 3.61 cm
    ev = classify_asprs2023(d, checkpoint_sd_m=sd, target_cm={"planimetric": 3.2, "altimetric": 3.6}).evidence
    assert ev["target_planimetric_passed"] is True and ev["target_altimetric_passed"] is False
    assert classify_asprs2023(d, checkpoint_sd_m=[0.02, 0.02, 0.03]).evidence["rmse_v_m"] == pytest.approx(
        math.hypot(0.02, 0.03))


def test_asprs_bad_targets_and_sds_are_named():
    d = np.column_stack([np.full(5, 0.01), np.full(5, -0.01), np.full(5, 0.02)])
    with pytest.raises(AssessmentError, match=r"^asprs2014 target class 'vertical': use 'planimetric' and/or "
                                              r"'altimetric'"):
        classify_asprs2014(d, target_cm={"vertical": 5.0})
    with pytest.raises(AssessmentError, match=r"^asprs2023 target class 'h'"):
        classify_asprs2023(d, target_cm={"h": 5.0})
    with pytest.raises(AssessmentError, match=r"^check-point sds must be \(3,\) or \(5, 3\) \(sd_E, sd_N, sd_h "
                                              r"in m\), got shape \(4, 3\)$"):
        classify_asprs2023(d, checkpoint_sd_m=np.full((4, 3), 0.02))
    with pytest.raises(AssessmentError, match="must be finite and >= 0"):
        classify_asprs2023(d, checkpoint_sd_m=[0.02, -0.02, 0.03])


def test_asprs2014_classes():
    d = np.column_stack([np.full(25, 0.05), np.full(25, 0.03), np.full(25, 0.10)])
    r = classify_asprs2014(d, target_cm={"planimetric": 5.0, "altimetric": 7.5})
    assert r.classes == {"planimetric": "5.0-cm", "altimetric": "10.0-cm"}
    assert r.evidence["horizontal_accuracy_95_m"] == pytest.approx(1.7308 * math.hypot(0.05, 0.03))
    assert r.evidence["nva_95_m"] == pytest.approx(0.196)
    assert r.evidence["target_planimetric_passed"] is True and r.evidence["target_altimetric_passed"] is False


def test_filliben_table_values():
    assert filliben_critical_value(21, 0.10) == 0.961
    assert filliben_critical_value(21, 0.05) == 0.952
    assert filliben_critical_value(21, 0.01) == 0.928
    assert filliben_critical_value(100, 0.10) == 0.989
    # interpolation between tabulated rows 50 and 55
    assert filliben_critical_value(52, 0.10) == pytest.approx(0.981 + 0.4 * 0.001, abs=1e-9)
    alphas, ns, crit = filliben_table()
    assert alphas == (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5) and ns[0] == 3 and crit.shape[1] == 7
    with pytest.raises(AssessmentError, match="not in the Filliben table"):
        filliben_critical_value(21, 0.2)
    with pytest.raises(AssessmentError, match="outside the Filliben table"):
        filliben_critical_value(101, 0.1)


def test_classify_dispatch_errors():
    with pytest.raises(AssessmentError, match="needs a map scale"):
        classify("pec", np.zeros((3, 3)))
    with pytest.raises(AssessmentError, match="unknown standard"):
        classify("iso19157", np.zeros((3, 3)))
    with pytest.raises(AssessmentError, match=r"\(N, 3\) array"):
        classify("nssda", np.zeros((3, 2)))
