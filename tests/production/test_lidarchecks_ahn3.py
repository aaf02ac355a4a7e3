"""NVA/VVA on the AHN3 test tile by leave-out check points (no surveyed points exist; see docs/figures.md)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lidarcat.lidar.readers import read_points
from lidarcat.production.lidarchecks import lidar_heights_at, vertical_accuracy

TILE = Path(__file__).resolve().parents[1] / "data" / "lidar" / "ahn3_cropped_1.laz"


def test_leave_out_nva_on_ahn3_hard_surfaces_is_centimetric_and_below_vva():
    pc = read_points(TILE)
    cls = pc.attributes["classification"]
    g, other = pc.xyz[cls == 2], pc.xyz[cls == 1]
    otree = cKDTree(other[:, :2])
    rng = np.random.default_rng(0)
    cand = rng.choice(len(g), size=4000, replace=False)
    inside = np.all((g[cand, :2] > g[:, :2].min(0) + 5) & (g[cand, :2] < g[:, :2].max(0) - 5), axis=1)
    n2 = np.array([len(x) for x in otree.query_ball_point(g[cand, :2], 2.0)])
    n1 = np.array([len(x) for x in otree.query_ball_point(g[cand, :2], 1.0)])
    hard, veg = cand[inside & (n2 == 0)][:100], cand[inside & (n1 > 0)][:100]
    keep = np.ones(len(g), dtype=bool)
    keep[hard] = keep[veg] = False
    dz_h = lidar_heights_at(g[keep], g[hard, :2]) - g[hard, 2]
    dz_v = lidar_heights_at(g[keep], g[veg, :2]) - g[veg, 2]
    acc = vertical_accuracy(dz_h, dz_v)
    assert acc.n_nonveg == 100 and acc.n_veg == 100
    # AHN3 specifies 5 cm systematic + 5 cm stochastic height error; the withheld ground points of open,
    # hard surfaces are read back from their neighbours' TIN within a few cm, the vegetated ones worse
    assert 0.005 < acc.nva_rmse_m < 0.05
    assert acc.vva_95th_percentile_m > acc.nva_95_m
    assert abs(acc.mean_nonveg_m) < 0.01
