"""Synthetic strips: the pulses trace the terrain with the true parameters."""

from __future__ import annotations

import numpy as np

from lidarcat.production.lidarchecks import SystemParameters, georeference
from lidarcat.synthetic.strips import strip_terrain, synthetic_strips


def test_true_parameters_put_the_points_on_the_terrain():
    s = synthetic_strips(5, length_m=120.0, spacing_m=4.0, range_sd_m=0.0)
    p = georeference(s.pulses, s.truth)
    np.testing.assert_allclose(p, s.true_points_m, atol=1e-6)
    np.testing.assert_allclose(p[:, 2], strip_terrain(p[:, 0], p[:, 1]), atol=1e-6)
    # without calibration the cloud is off by decimetres (the misalignment the checks must find)
    raw = georeference(s.pulses, SystemParameters())
    assert np.sqrt(np.mean((raw[:, 2] - p[:, 2]) ** 2)) > 0.1
    assert set(np.unique(s.pulses.strip)) == {0, 1, 2, 3}
    np.testing.assert_allclose(s.control_m[:, 2], 100.0, atol=0)        # the runway is flat
