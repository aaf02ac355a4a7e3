"""Accuracy study: ``lidarcat demo synthetic`` + ``lidarcat run`` over several seeds, against the truth.

Run: ``python benchmarks/demo_seeds.py [N_SEEDS] [N_PHOTOS] [WORKERS]`` (default 8 seeds,
6 photos, 2 worker processes; about 15 s per seed and worker).  Prints, per seed and run, the largest and RMS normalised
error z = error / sd of the exterior orientations and free points, and the
check-point statistic d' C^-1 d (C: joint covariance of the adjusted check
points, cross-covariances included, + GPS variances) with its chi-square
bounds, beside the statistic that ignores the correlations (sum d^2 /
(sd_adj^2 + sd_gps^2)); then the RMS and mean z of the extracted roof vertices per axis (1 and
0 for honest, unbiased standard deviations).  Not a test: figures for
docs/figures.md.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from lidarcat.synthetic.survey import compare_with_truth, write_synthetic_survey  # noqa: E402
from lidarcat.pipeline import run_pipeline  # noqa: E402


def _one(args: tuple[int, int, str]) -> tuple[int, dict]:
    seed, n_photos, tmp = args
    d = write_synthetic_survey(Path(tmp) / f"s{seed}", n_photos=n_photos, seed=seed)
    out = Path(tmp) / f"o{seed}"
    run_pipeline(d.path, out)
    return seed, compare_with_truth(d.path, out)


def main() -> None:
    from concurrent.futures import ProcessPoolExecutor

    n_seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    n_photos = int(sys.argv[2]) if len(sys.argv) > 2 else 6
    workers = int(sys.argv[3]) if len(sys.argv) > 3 else 2
    zs = []
    print(f"{'seed':>4} {'run':<6} {'EO max|z|':>9} {'EO rms z':>8} {'pts rms z':>9} "
          f"{'dCd':>7} {'diag':>7} {'dof':>4} {'99% bounds':>14}")
    fails = {"joint": 0, "diag": 0, "runs": 0, "seeds_beyond_3": 0}
    with tempfile.TemporaryDirectory() as tmp, ProcessPoolExecutor(workers) as pool:
        for seed, c in pool.map(_one, [(s, n_photos, tmp) for s in range(1, n_seeds + 1)]):
            zz = [e["z"] for e in c["extraction"].values() if e["status"] == "ok"]
            zs += zz
            fails["seeds_beyond_3"] += bool(np.any(np.abs(zz) > 3))
            for run, v in c["runs"].items():
                lo, hi = stats.chi2.ppf([0.005, 0.995], v["check_dof"])
                print(f"{seed:>4} {run:<6} {v['eo_max_abs_z']:>9.2f} {v['eo_rms_z']:>8.2f} "
                      f"{v['points_rms_z']:>9.2f} {v['check_chi2_joint']:>7.1f} {v['check_chi2']:>7.1f} "
                      f"{v['check_dof']:>4} {lo:>6.1f}-{hi:<6.1f}", flush=True)
                fails["runs"] += 1
                fails["joint"] += not lo <= v["check_chi2_joint"] <= hi
                fails["diag"] += not lo <= v["check_chi2"] <= hi
    z = np.array(zs)
    print(f"extracted roof vertices: {len(z)}; RMS z E/N/h "
          + " / ".join(f"{v:.2f}" for v in np.sqrt((z ** 2).mean(axis=0)))
          + "; mean z " + " / ".join(f"{v:+.2f}" for v in z.mean(axis=0))
          + f"; |z| > 3: {int((np.abs(z) > 3).sum())} of {z.size}")
    k = z.size // max(n_seeds, 1)
    print(f"seeds with some extracted component beyond 3 sd: {fails['seeds_beyond_3']} of {n_seeds} "
          f"(normal errors: {100 * (1 - 0.9973 ** k):.1f} % of seeds with {k} components)")
    print(f"check points outside the 99 % chi-square interval: d'C^-1d {fails['joint']} of {fails['runs']} "
          f"runs, correlations ignored {fails['diag']} of {fails['runs']}")


if __name__ == "__main__":
    main()
