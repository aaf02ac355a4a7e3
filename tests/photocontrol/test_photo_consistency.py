"""The per-photo consistency test (measure.check_photo): a planted common displacement of the
approximate orientation (~15 px shift plus a 0.4 deg rotation across the frame) and one
measurement moved 30 px onto another corner."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.photocontrol import Measurement, check_photo, pixel_positions
from lidarcat.synthetic.aerial import aerial_camera

EO_COV = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
CAM = aerial_camera((1000, 750))
TRUE_EO = np.array([0.0, 0.0, 146.0, 0.0, 0.0, 0.0])       # GSD ~0.15 m
# 2 m / 0.5 deg class error: ~15 px common shift, 0.4 deg kappa (~3 px across the frame)
APPROX_EO = TRUE_EO + np.array([1.5, -1.5, 1.0, math.radians(0.3), math.radians(-0.2), math.radians(0.4)])
VERTS = np.array([[-40.0, -30.0, 8.0], [35.0, -25.0, 11.0], [-30.0, 28.0, 6.0], [38.0, 30.0, 9.5],
                  [0.0, 2.0, 12.0], [15.0, -10.0, 7.0]])
VCOV = np.repeat((np.eye(3) * 0.03**2)[None], len(VERTS), axis=0)


def measurements(moved: dict[int, tuple[float, float]] | None = None, seed: int = 0) -> list[Measurement]:
    rng = np.random.default_rng(seed)
    truth = pixel_positions(CAM, TRUE_EO, VERTS)
    pred = pixel_positions(CAM, APPROX_EO, VERTS)
    out = []
    for k in range(len(VERTS)):
        px = truth[k] + rng.normal(0, 0.2, 2) + np.asarray((moved or {}).get(k, (0.0, 0.0)))
        out.append(Measurement(f"v{k}", "p0", px, np.eye(2) * 0.3**2, "measured", predicted_px=pred[k],
                               predicted_cov_px2=np.eye(2) * 20.0**2))
    return out


def test_planted_shift_is_large_and_not_a_pure_translation():
    d = np.array([np.asarray(m.px) - np.asarray(m.predicted_px) for m in measurements()])
    assert np.all(np.hypot(*d.T) > 10.0)
    assert np.ptp(d, axis=0).max() > 2.0          # rotation across the frame: a median shift alone is not enough


def test_clean_measurements_are_all_kept():
    for seed in range(5):
        out = check_photo(measurements(seed=seed), CAM, APPROX_EO, EO_COV, VERTS, VCOV)
        assert all(m.status == "measured" for m in out), [m.reason for m in out]


def test_one_measurement_on_another_corner_is_rejected_with_the_reason():
    ms = measurements({3: (30.0, 0.0)})
    out = check_photo(ms, CAM, APPROX_EO, EO_COV, VERTS, VCOV)
    assert [m.status for m in out] == ["measured"] * 3 + ["rejected"] + ["measured"] * 2
    assert out[3].reason.startswith("inconsistent with the photo's common shift: ")
    assert float(out[3].reason.split(": ")[1].split(" px")[0]) == pytest.approx(30.0, abs=1.5)
    assert "from the other 5 vertices" in out[3].reason
    # the multi-photo ellipse alone passes it: 30 px is within 3.7 sigma of a 20 px prediction sd
    d = np.asarray(ms[3].px) - np.asarray(ms[3].predicted_px)
    assert d @ np.linalg.solve(ms[3].predicted_cov_px2 + ms[3].cov_px2, d) < 13.8


def test_two_gross_of_six_are_both_rejected():
    out = check_photo(measurements({0: (0.0, -25.0), 4: (12.0, 9.0)}), CAM, APPROX_EO, EO_COV, VERTS, VCOV)
    assert [m.status for m in out] == ["rejected", "measured", "measured", "measured", "rejected", "measured"]


def test_two_that_disagree_are_both_rejected_and_one_alone_is_kept():
    ms = measurements({1: (0.0, 30.0)})
    two = [m if k in (0, 1) else m.failed("no_edges", "x") for k, m in enumerate(ms)]
    out = check_photo(two, CAM, APPROX_EO, EO_COV, VERTS, VCOV)
    assert out[0].status == out[1].status == "rejected"
    assert "which of the two is off cannot be told" in out[0].reason
    assert all(m.status == "no_edges" for m in out[2:])
    agree = [m if k in (0, 2) else m.failed("no_edges", "x") for k, m in enumerate(ms)]
    assert [m.status for m in check_photo(agree, CAM, APPROX_EO, EO_COV, VERTS, VCOV)][:3] == \
        ["measured", "no_edges", "measured"]
    alone = [m if k == 1 else m.failed("no_edges", "x") for k, m in enumerate(ms)]
    assert check_photo(alone, CAM, APPROX_EO, EO_COV, VERTS, VCOV)[1].status == "measured"
    out = check_photo(alone, CAM, APPROX_EO, EO_COV, VERTS, VCOV, alone="reject")[1]
    assert out.status == "rejected"
    assert out.reason == "alone on its photo: not tested against the photo's common shift (prediction sd 20 px)"
