"""The broken-terrain landscape ("terraces"): cliffs, houses, and the SMRF figures it was made for."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.production.ground import SMRFParameters, classify_ground, confusion
from lidarcat.synthetic.landscapes import BROKEN_LANDSCAPES, LANDSCAPES, make_landscape


def test_terraces_cliffs_houses_and_seeds():
    ls = make_landscape("terraces", size_m=100.0, density=2.0, seed=4)
    assert "terraces" in BROKEN_LANDSCAPES and "terraces" not in LANDSCAPES
    assert len(ls) == 20_000 and np.all(ls.return_number == 1) and np.all(ls.number_of_returns == 1)
    x, y, z = ls.xyz.T
    # houses 12 x 12 m in every 50 x 60 m cell (4.8 % of the area), none on the mesa (radius 15 m about
    # 0.7 and 0.3 of the side)
    mesa = np.hypot(x - 70.0, y - 30.0) < 15.0
    house = (np.mod(x, 50) > 20) & (np.mod(x, 50) < 32) & (np.mod(y, 60) > 10) & (np.mod(y, 60) < 22) & ~mesa
    assert np.array_equal(~house, ls.ground)
    assert 0.040 < 1.0 - ls.ground.mean() < 0.056
    # the cliff at x + 10 sin(y / 25) = 40: 8 m, plus the 10 % slope over the 15 m between the two strips
    band = ls.ground & (y < 5.0)
    below = np.median(z[band & (x > 30) & (x < 35)])
    above = np.median(z[band & (x > 45) & (x < 50)])
    assert 9.0 < above - below < 10.0
    # a house stands 6 m above the terrain beside it (same terrace, 0.1 x + 0.05 y)
    terrace = 8.0 * np.floor((x + 10 * np.sin(y / 25)) / 40.0) + 0.1 * x + 0.05 * y + np.where(mesa, 15.0, 0.0)
    np.testing.assert_allclose(np.median(z[house] - terrace[house]), 6.0, atol=0.01)
    np.testing.assert_allclose(np.median(z[~house] - terrace[~house]), 0.0, atol=0.01)
    again = make_landscape("terraces", size_m=100.0, density=2.0, seed=4)
    assert np.array_equal(again.xyz, ls.xyz)
    assert not np.array_equal(make_landscape("terraces", size_m=100.0, density=2.0, seed=5).xyz, ls.xyz)


def test_unknown_landscape_names_the_choices():
    with pytest.raises(ValueError, match="use one of steep, forest, bridge, city, low_outliers, terraces"):
        make_landscape("canyon")


def test_fixed_grid_beats_the_adaptive_smrf_on_sparse_terraces():
    # the case `lidar ground --fixed-grid` and [products] smrf_adaptive = false exist for (measured at
    # 0.3 pulses/m2, seeds 0-2: adaptive 8.77 / 8.46 / 7.24 %, fixed grid 5.83 / 5.92 / 5.58 %)
    ls = make_landscape("terraces", size_m=200.0, density=0.3, seed=2)
    fixed = confusion(ls.ground, classify_ground(ls.xyz, ls.return_number, ls.number_of_returns,
                                                 params=SMRFParameters(adaptive=False)))
    adaptive = confusion(ls.ground, classify_ground(ls.xyz, ls.return_number, ls.number_of_returns))
    assert fixed.total < 0.065 and adaptive.total < 0.08
    assert fixed.total < adaptive.total - 0.01
