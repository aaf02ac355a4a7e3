"""LiDAR system calibration checks: partials, heights at check points, NVA/VVA, parameter recovery."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.errors import AssessmentError, ProductError
from lidarcat.production.lidarchecks import (
    PulseRecords,
    SystemParameters,
    estimate_system_parameters,
    geolocation_partials,
    georeference,
    lidar_heights_at,
    vertical_accuracy,
)
from lidarcat.synthetic.strips import synthetic_strips


def _pulses(n: int = 50, seed: int = 1) -> PulseRecords:
    rng = np.random.default_rng(seed)
    return PulseRecords(rng.normal(0, 50, (n, 3)) + [0, 0, 600], rng.normal(0, 0.05, (n, 3)),
                        rng.uniform(400, 700, n), rng.uniform(-0.4, 0.4, n), np.zeros(n, dtype=int))


def test_partials_match_central_differences():
    p = _pulses()
    q = np.array([0.01, -0.02, 0.003, 0.2])
    jac = geolocation_partials(p, SystemParameters.from_array(q))
    for k in range(4):
        e = np.zeros(4)
        e[k] = 1e-6
        num = (georeference(p, SystemParameters.from_array(q + e))
               - georeference(p, SystemParameters.from_array(q - e))) / 2e-6
        np.testing.assert_allclose(jac[:, :, k], num, atol=1e-5 * max(1.0, np.abs(num).max()))


def test_level_flight_nadir_is_straight_down():
    p = PulseRecords([[10.0, 20.0, 500.0]], [[0.0, 0.0, 0.3]], [400.0], [0.0], [0])
    np.testing.assert_allclose(georeference(p), [[10.0, 20.0, 100.0]], atol=1e-9)
    # roll boresight of +0.01 rad (about the forward axis) moves the nadir point 400 sin(0.01) m to the left (+y);
    # bias adds to the height
    q = SystemParameters(roll_rad=0.01, bias_m=0.5)
    got = georeference(p, q)[0]
    side = np.array([-math.sin(0.3), math.cos(0.3)])          # body +y (left) in the map
    np.testing.assert_allclose(got[:2], [10.0, 20.0] + 400 * math.sin(0.01) * side, atol=1e-9)
    assert got[2] == pytest.approx(500 - 400 * math.cos(0.01) + 0.5, abs=1e-9)


def test_heights_at_check_points_on_a_plane_tin_and_plane_fit():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 100, (2000, 2))
    z = 50 + 0.1 * xy[:, 0] - 0.05 * xy[:, 1]
    pts = np.column_stack([xy, z])
    chk = np.array([[20.0, 30.0], [55.5, 70.25]])
    truth = 50 + 0.1 * chk[:, 0] - 0.05 * chk[:, 1]
    np.testing.assert_allclose(lidar_heights_at(pts, chk), truth, atol=1e-9)
    np.testing.assert_allclose(lidar_heights_at(pts, chk, method="plane", radius_m=3.0), truth, atol=1e-9)


def test_check_point_outside_the_data_is_named():
    pts = np.array([[0.0, 0.0, 1.0], [10.0, 0.0, 1.0], [0.0, 10.0, 1.0], [10.0, 10.0, 1.0]])
    with pytest.raises(ProductError, match=r"check point CP7 \(20\.000, 5\.000\) is outside the LiDAR "
                                           r"triangulation \(1 of 2 check points outside\)"):
        lidar_heights_at(pts, [[5.0, 5.0], [20.0, 5.0]], ids=["CP1", "CP7"])
    with pytest.raises(ProductError, match=r"check point 2 \(9\.000, 9\.000\) has 1 LiDAR points within 7\.1 m"):
        lidar_heights_at(pts, [[5.0, 5.0], [9.0, 9.0]], method="plane", radius_m=7.1)
    with pytest.raises(ProductError, match="at least 3 points"):
        lidar_heights_at(pts[:2], [[1.0, 1.0]])


def test_nva_vva_hand_case():
    # non-vegetated: RMSE = sqrt((0.01 + 0.01 + 0.04 + 0.04) / 4) = sqrt(0.025)
    # vegetated |dz| = 0.1 .. 2.0 (20 values): 95th percentile at rank 0.95 * 19 = 18.05 -> 1.9 + 0.05 * 0.1
    acc = vertical_accuracy([0.1, -0.1, 0.2, -0.2], np.arange(1, 21) * 0.1 * (-1) ** np.arange(20),
                            scale=2000, contour_interval_m=1.0)
    assert acc.nva_rmse_m == pytest.approx(math.sqrt(0.025), rel=1e-12)
    assert acc.nva_95_m == pytest.approx(1.96 * math.sqrt(0.025), rel=1e-12)
    assert acc.mean_nonveg_m == pytest.approx(0.0, abs=1e-15)
    assert acc.vva_95th_percentile_m == pytest.approx(1.905, rel=1e-12)
    assert acc.vva_rmse_m == pytest.approx(math.sqrt(np.mean((np.arange(1, 21) * 0.1) ** 2)), rel=1e-12)
    assert acc.asprs2023.evidence["rmse_v_m"] == pytest.approx(math.sqrt(0.025), rel=1e-12)
    assert acc.asprs2023.classes["altimetric"] == "15.9-cm"   # next 0.1 cm step at or above 15.81 cm
    # PEC 1:2,000, 1 m contours, class A: PEC 0.5 m, EP 0.333 m: all |dz| <= 0.5, RMS 0.158 <= 0.333
    assert acc.pec is not None and acc.pec.classes["altimetric"] == "A"
    assert acc.to_dict()["n_veg"] == 20


def test_vertical_accuracy_needs_non_vegetated_points():
    with pytest.raises(AssessmentError, match="no check points"):
        vertical_accuracy([])
    assert math.isnan(vertical_accuracy([0.1]).vva_95th_percentile_m)


def _check(res, truth, n_sd=3.0):
    dev = (res.parameters.as_array() - truth.as_array()) / res.sd.as_array()
    assert np.all(np.abs(dev) <= n_sd), dev


def test_parameters_recovered_within_3_sd():
    s = synthetic_strips(0, length_m=300.0, spacing_m=2.0)
    res = estimate_system_parameters(s.pulses, s.control_m)
    _check(res, s.truth)
    assert res.rms_after_m["control"] < 0.5 * res.rms_before_m["control"]
    assert res.rms_after_m["strip"] < 0.5 * res.rms_before_m["strip"]
    # the a-posteriori sigma0 matches the range noise against the a-priori 5 cm (within 30 %)
    assert res.sigma0 * 0.05 == pytest.approx(s.range_sd_m, rel=0.3)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_parameters_recovered_within_3_sd_more_seeds(seed):
    s = synthetic_strips(seed, length_m=300.0, spacing_m=2.0)
    _check(estimate_system_parameters(s.pulses, s.control_m), s.truth)


@pytest.mark.slow
def test_without_control_the_bias_is_left_out():
    s = synthetic_strips(4, length_m=300.0, spacing_m=2.0)
    res = estimate_system_parameters(s.pulses)
    assert math.isnan(res.parameters.bias_m) and math.isnan(res.sd.bias_m)
    assert "elevation bias is not observable" in res.notes[0]
    dev = (res.parameters.as_array() - s.truth.as_array())[:3] / res.sd.as_array()[:3]
    assert np.all(np.abs(dev) <= 3.0), dev


def test_bad_input_is_located():
    s = synthetic_strips(0, length_m=120.0, spacing_m=4.0, strip_offsets_m=(0.0,), cross_strip=False,
                         attitude_sd_rad=0.0)
    with pytest.raises(ProductError, match="at least 3 finite surveyed"):
        estimate_system_parameters(s.pulses, s.control_m[:2])
    far = s.control_m + [10_000.0, 0.0, 0.0]
    with pytest.raises(ProductError, match=r"0 observations \(0 on the control surface, 0 between strips\)"):
        estimate_system_parameters(s.pulses, far)
    with pytest.raises(ProductError, match="gnss_m must have shape"):
        PulseRecords(np.zeros((3, 2)), np.zeros((3, 3)), np.ones(3), np.zeros(3), np.zeros(3))
    # one level strip over a flat runway: pitch has no observation -> singular, named
    flat = s.pulses.subset(s.true_points_m[:, 1] < -20.0)
    with pytest.raises(ProductError, match=r"normal matrix of \(roll_rad, pitch_rad, scale, bias_m\) is singular"):
        estimate_system_parameters(flat, s.control_m)
