"""LiDAR system checks: ASPRS 2023 NVA/VVA on the AHN3 test tiles, and boresight recovery on synthetic strips.

AHN3 has no surveyed check points.  What is measured instead (leave-out
cross-validation, stated in docs/figures.md): per tile, N check points are drawn
(seeded) among the ground points (class 2) and *withheld*; the LiDAR height at
each is the TIN of the remaining ground points (``lidar_heights_at``), and
``dz = z_TIN - z_withheld``.  Non-vegetated: the ground points with no
non-ground point (class 1) within 2 m and a local plane rms (8 neighbours)
below 3 cm (hard, open surfaces: streets, squares); vegetated: ground points
with a class-1 point within 1 m (under trees, hedges, by cars).  This measures
the precision of the ground surface (noise + interpolation), not its absolute
accuracy (that needs an independent survey, the report's runway points).

Run::

    PYTHONPATH=src python benchmarks/bench_lidarchecks.py [--n 100] [--seeds 3]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from lidarcat.lidar.readers import read_points
from lidarcat.production.lidarchecks import estimate_system_parameters, lidar_heights_at, vertical_accuracy
from lidarcat.synthetic.strips import synthetic_strips

HERE = Path(__file__).resolve().parent.parent / "tests" / "data" / "lidar"


def ahn3(tile: Path, n: int, seed: int) -> dict:
    pc = read_points(tile)
    cls = pc.attributes["classification"]
    g, other = pc.xyz[cls == 2], pc.xyz[cls == 1]
    gtree, otree = cKDTree(g[:, :2]), cKDTree(other[:, :2])
    rng = np.random.default_rng(seed)
    cand = rng.choice(len(g), size=min(len(g), 40 * n), replace=False)
    _, nn = gtree.query(g[cand, :2], k=9)
    nbr = g[nn[:, 1:]]
    c = nbr.mean(axis=1)
    rms = np.sqrt(np.linalg.eigvalsh(np.einsum("mki,mkj->mij", nbr - c[:, None], nbr - c[:, None]) / 8)[:, 0])
    near2 = np.array([len(x) > 0 for x in otree.query_ball_point(g[cand, :2], 2.0)])
    near1 = np.array([len(x) > 0 for x in otree.query_ball_point(g[cand, :2], 1.0)])
    inside = np.all((g[cand, :2] > g[:, :2].min(0) + 5) & (g[cand, :2] < g[:, :2].max(0) - 5), axis=1)
    hard = cand[inside & ~near2 & (rms < 0.03)][:n]
    veg = cand[inside & near1][:n]
    keep = np.ones(len(g), dtype=bool)
    keep[hard] = keep[veg] = False
    z_hard = lidar_heights_at(g[keep], g[hard, :2])
    z_veg = lidar_heights_at(g[keep], g[veg, :2])
    acc = vertical_accuracy(z_hard - g[hard, 2], z_veg - g[veg, 2])
    return {"tile": tile.name, "n_nonveg": acc.n_nonveg, "n_veg": acc.n_veg, "nva_rmse_m": acc.nva_rmse_m,
            "nva_95_m": acc.nva_95_m, "vva_rmse_m": acc.vva_rmse_m, "vva_95_m": acc.vva_95th_percentile_m,
            "class": acc.asprs2023.classes["altimetric"]}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=3)
    a = ap.parse_args()
    print(f"load {os.getloadavg()[0]:.2f}")
    print("| tile | seed | n NVA | n VVA | NVA RMSE_z (cm) | NVA 95 % (cm) | VVA RMSE_z (cm) | VVA 95th pct (cm) "
          "| ASPRS 2023 class |")
    print("|---|---|---|---|---|---|---|---|---|")
    for tile in sorted(HERE.glob("ahn3_cropped_*.laz")):
        for seed in range(a.seeds):
            r = ahn3(tile, a.n, seed)
            print(f"| {r['tile']} | {seed} | {r['n_nonveg']} | {r['n_veg']} | {100 * r['nva_rmse_m']:.2f} | "
                  f"{100 * r['nva_95_m']:.2f} | {100 * r['vva_rmse_m']:.2f} | {100 * r['vva_95_m']:.2f} | "
                  f"{r['class']} |")
    print()
    print("| seed | pulses | roll dev (sd) | pitch dev (sd) | scale dev (sd) | bias dev (sd) | sigma0 | s |")
    print("|---|---|---|---|---|---|---|---|")
    for seed in range(a.seeds):
        t = time.perf_counter()
        s = synthetic_strips(seed, length_m=300.0, spacing_m=2.0)
        res = estimate_system_parameters(s.pulses, s.control_m)
        dev = (res.parameters.as_array() - s.truth.as_array()) / res.sd.as_array()
        print(f"| {seed} | {len(s.pulses)} | " + " | ".join(f"{x:+.2f}" for x in dev)
              + f" | {res.sigma0:.3f} | {time.perf_counter() - t:.1f} |")


if __name__ == "__main__":
    main()
