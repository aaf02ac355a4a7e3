"""Convergence of the Levenberg-Marquardt iteration where a weakly held block bends its valley.

A block of six photos held by one control line seen on two photos plus GNSS (10 m) / IMU (3 deg):
along the line only the GNSS/IMU hold the block, v'Pv is quartic along the Gauss-Newton step (the
image observations leave the curved valley of the weak mode) and plain LM creeps (every second
step rejected).  The geodesic acceleration retried on a rejected step (bundle.solve) follows it.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.bundle import adjust
from lidarcat.synthetic.lines import line_block

ONE_LINE = dict(n_lines=1, n_strips=2, photos_per_strip=3, gnss_sd_m=10.0, ins_sd_deg=3.0)


def test_a_block_held_by_one_line_converges_in_few_iterations():
    b = line_block(seed=5, **ONE_LINE)
    assert len(b.problem.lines.line_index) == 2                 # one line, two photos
    fast = adjust(b.problem, max_iter=300)
    slow = adjust(b.problem, max_iter=300, acceleration=False)
    assert fast.success and slow.success
    assert fast.n_iter <= 20 < 100 <= slow.n_iter               # 11 and 137 iterations
    # the same minimum: v'Pv and the orientations within 1 % of their sds
    assert fast.vtpv == pytest.approx(slow.vtpv, rel=1e-7)
    assert np.abs((fast.eo_params - slow.eo_params) / fast.eo_sd).max() < 0.01
    # the default 50 iterations suffice
    assert adjust(b.problem).success


def test_acceleration_changes_nothing_where_no_step_is_rejected():
    """A well-held block (12 lines) accepts every LM step: the iterates are identical."""
    b = line_block(seed=0)
    a = adjust(b.problem, initial=(b.initial_eo, None))
    c = adjust(b.problem, initial=(b.initial_eo, None), acceleration=False)
    assert a.n_iter == c.n_iter
    np.testing.assert_array_equal(a.eo_params, c.eo_params)
    np.testing.assert_array_equal(a.points_m, c.points_m)
