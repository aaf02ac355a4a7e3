"""Accuracy study: ``lidarcat demo synthetic`` + ``lidarcat run`` over several seeds, against the truth.

Run: ``python benchmarks/demo_seeds.py [N_SEEDS] [N_PHOTOS]`` (default 8 seeds, 6 photos;
about 15 s per seed).  Prints, per seed and run, the largest and RMS normalised
error z = error / sd of the exterior orientations and free points, and the
check-point statistic sum d^2 / (sd_adj^2 + sd_gps^2) with its chi-square
bounds; then the RMS and mean z of the extracted roof vertices per axis (1 and
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

from lidarcat.demo import compare_with_truth, write_synthetic_survey  # noqa: E402
from lidarcat.pipeline import run_pipeline  # noqa: E402


def main() -> None:
    n_seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 8
    n_photos = int(sys.argv[2]) if len(sys.argv) > 2 else 6
    zs = []
    print(f"{'seed':>4} {'run':<6} {'EO max|z|':>9} {'EO rms z':>8} {'pts rms z':>9} "
          f"{'check chi2':>10} {'dof':>4} {'99% bounds':>14}")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, n_seeds + 1):
            d = write_synthetic_survey(Path(tmp) / f"s{seed}", n_photos=n_photos, seed=seed)
            out = Path(tmp) / f"o{seed}"
            run_pipeline(d.path, out)
            c = compare_with_truth(d.path, out)
            zs += [e["z"] for e in c["extraction"].values() if e["status"] == "ok"]
            for run, v in c["runs"].items():
                lo, hi = stats.chi2.ppf([0.005, 0.995], v["check_dof"])
                print(f"{seed:>4} {run:<6} {v['eo_max_abs_z']:>9.2f} {v['eo_rms_z']:>8.2f} "
                      f"{v['points_rms_z']:>9.2f} {v['check_chi2']:>10.1f} {v['check_dof']:>4} "
                      f"{lo:>6.1f}-{hi:<6.1f}")
    z = np.array(zs)
    print(f"extracted roof vertices: {len(z)}; RMS z E/N/h "
          + " / ".join(f"{v:.2f}" for v in np.sqrt((z ** 2).mean(axis=0)))
          + "; mean z " + " / ".join(f"{v:+.2f}" for v in z.mean(axis=0))
          + f"; |z| > 3: {int((np.abs(z) > 3).sum())} of {z.size}")


if __name__ == "__main__":
    main()
