"""Issue 27 figures: the rolling-shutter drone block and the rig block over seeds (docs/figures.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_rolling_rig.py [--seeds 10] [--rig-seeds 20]

Prints, per seed, the rms errors (camera position m, rotation mrad, check points m) of the
global-shutter block, the rolling-shutter block with the model on (velocity from the
neighbouring exposures) and off, the read-out time estimated from the model-off block, the
pooled row trend of the y residuals, the free-velocity variant; then the rig block's
standardised relative-pose errors.  The tests (tests/bundle/test_rolling_block.py,
test_rig_block.py) assert the same quantities.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from lidarcat.bundle import adjust, adjust_with_parameters
from lidarcat.bundle.rig import RigRelativePoses, rig_initial_points, rotation_log
from lidarcat.bundle.rolling import (ReadoutTime, VelocityCorrections, neighbour_velocities, row_fractions, row_times,
                                     row_trend, with_rolling_shutter)
from lidarcat.synthetic.drone import drone_block, rig_block


def _errors(block, result) -> np.ndarray:
    dp = np.asarray(result.eo_params)[:, :3] - block.true_eo[:, :3]
    da = np.asarray(result.eo_params)[:, 3:] - block.true_eo[:, 3:]
    dc = np.asarray(result.points_m)[block.check_index] - block.true_points_m[block.check_index]
    return np.array([np.sqrt((dp**2).sum(1).mean()), 1e3 * np.sqrt((da**2).sum(1).mean()),
                     np.sqrt((dc**2).sum(1).mean())])


def rolling(seeds: range) -> None:
    rows = []
    print("seed | global pos m, rot mrad, check m | on | off | free velocity | T_hat ms (sd) | t | pooled t_y off/on")
    for seed in seeds:
        g, b = drone_block(seed, readout_s=0.0), drone_block(seed, readout_s=0.03)
        v = neighbour_velocities(b.gnss_m, b.exposure_time_s, b.line)
        t = row_times(b.row_px, b.height_px, b.readout_s)
        on_p = with_rolling_shutter(b.problem, t, v)
        r_g, r_on, r_off = adjust(g.problem), adjust(on_p), adjust(b.problem)
        free = adjust_with_parameters(on_p, [VelocityCorrections(t, v)], without=r_on).bundle
        ro = adjust_with_parameters(b.problem, [ReadoutTime(row_fractions(b.row_px, b.height_px), v,
                                                            ["drone"] * b.problem.n_photos)], without=r_off)
        pt_off = row_trend(b.problem, r_off.residuals_mm, b.row_px, b.pitch_mm).pooled_t[1]
        pt_on = row_trend(on_p, r_on.residuals_mm, b.row_px, b.pitch_mm).pooled_t[1]
        e = [_errors(g, r_g), _errors(b, r_on), _errors(b, r_off), _errors(b, free)]
        rows.append(e + [ro.estimates[0], ro.sd[0]])
        fmt = lambda a: " ".join(f"{x:.4f}" for x in a)  # noqa: E731
        print(f"{seed} | {fmt(e[0])} | {fmt(e[1])} | {fmt(e[2])} | {fmt(e[3])} | {1e3 * ro.estimates[0]:.1f} "
              f"({1e3 * ro.sd[0]:.2f}) | {ro.estimates[0] / ro.sd[0]:.1f} | {pt_off:.2f}/{pt_on:.2f}")
    e = np.array([r[:4] for r in rows])                                  # (seeds, 4, 3)
    pooled = np.sqrt(np.mean(e**2, axis=0))
    print("pooled rms (global, on, off, free velocity):\n", pooled.round(4))
    print("ratio to global:\n", (pooled / pooled[0]).round(3))
    z = np.array([(r[4] - 0.03) / r[5] for r in rows])
    print(f"read-out estimate: standardised errors rms {np.sqrt(np.mean(z**2)):.2f}, largest {np.abs(z).max():.2f}")


def rig(seeds: range) -> None:
    zs = []
    for seed in seeds:
        blk = rig_block(seed)
        p = blk.problem
        w = adjust(p, initial=(p.initial_eo, rig_initial_points(p, p.initial_eo)))
        res = adjust_with_parameters(p, [RigRelativePoses(blk.sensor_names)], without=w)
        rays = res.bundle.problem.rays
        er = rotation_log(rays.sensor_rotation[1:] @ np.transpose(blk.true_rotation[1:], (0, 2, 1)))
        ed = rays.sensor_translation_m[1:] - blk.true_translation_m[1:]
        zs.append(np.concatenate([er, ed], axis=1).ravel() / res.sd)
        if seed == seeds[0]:
            print("rig sds (rad, m):", res.sd.round(6))
    z = np.array(zs)
    print(f"rig: {len(z)} seeds x {z.shape[1]} parameters: standardised errors rms {np.sqrt(np.mean(z**2)):.3f}, "
          f"largest {np.abs(z).max():.2f}; rms per parameter {np.sqrt(np.mean(z**2, axis=0)).round(2)}")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--rig-seeds", type=int, default=20)
    a = ap.parse_args()
    t0 = time.perf_counter()
    rolling(range(1, 1 + a.seeds))
    rig(range(a.rig_seeds))
    print(f"{time.perf_counter() - t0:.0f} s")
