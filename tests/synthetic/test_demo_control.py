"""Control placement of the synthetic demo survey: a block of any size gets the control it needs."""

from __future__ import annotations

import numpy as np

from lidarcat.synthetic.survey import _CONTROL_EVERY_BASES, _pick_control


def _grid(n_cols: int, base: float = 100.0) -> np.ndarray:
    """GPS points as the demo lays them out: 3 rows across 2 strips, every half base along them."""
    e = np.arange(n_cols) * base / 2
    return np.array([(x, y) for y in (0.0, 300.0, 600.0) for x in e])


def test_short_block_keeps_corners_and_centre():
    en = _grid(11)  # 5 bases long
    control = _pick_control(en, 100.0)
    assert control == _pick_control(en) and len(control) == 5
    assert {tuple(en[i]) for i in control} >= {(0.0, 0.0), (500.0, 0.0), (0.0, 600.0), (500.0, 600.0)}


def test_long_block_gets_chains_across_the_strips_every_few_bases():
    """A 200-photo demo (two strips of 100) with only 5 control points bends: 9.9 m height RMSE at
    the check points and a failed chi-square test (docs/figures.md). With chains across the strips
    every 4 bases, no stretch of 4 bases along the block lacks control at both block edges."""
    base = 100.0
    en = _grid(199, base)  # 99 bases
    control = _pick_control(en, base)
    pts = en[sorted(control)]
    # corners and centre, and 25 stretches x 2 edges; the first stretch picks the two west corners
    assert len(control) == 5 + 2 * 25 - 2
    for lo in np.arange(0, 99 * base - _CONTROL_EVERY_BASES * base, _CONTROL_EVERY_BASES * base):
        inside = pts[(pts[:, 0] >= lo) & (pts[:, 0] < lo + _CONTROL_EVERY_BASES * base)]
        assert {0.0, 600.0} <= set(inside[:, 1]), lo  # both edges controlled in every stretch
