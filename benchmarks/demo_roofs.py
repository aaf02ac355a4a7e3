"""Bias and honesty of roof extraction on the buildings of the demo survey.

Run: ``python benchmarks/demo_roofs.py [N_BUILDINGS] [WORKERS]`` (default 800
buildings, 2 worker processes; about 25 s).  The buildings come from the demo's
own generator (``lidarcat.synthetic.survey._place_buildings``: pyramid and hip roofs with
facades and ground, 4 points/m^2, 0.03 m plan / 0.05 m height noise, the
scanner 150 m east); each job starts 0.5-1.5 m off the vertex in a random
direction and is extracted with the noise the demo states.  Prints, per roof
kind, the mean z = error / reported sd with its standard error (0 for no bias)
and the RMS z (1 for honest sds).  Not a test: figures for docs/figures.md.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import sys  # noqa: E402

import numpy as np  # noqa: E402


def _batch(args: tuple[int, int]) -> list[tuple[str, list[float]]]:
    from lidarcat.synthetic import roofs
    from lidarcat.synthetic.survey import _LIDAR_PLAN_SD_M, _place_buildings
    from lidarcat.control.vertices import extract_roof
    from lidarcat.control.facets import get_params

    seed, n = args
    rng = np.random.default_rng(seed)
    cand = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(0, 1000, n)]) + [680_000, 7_184_000]
    params = get_params(sd_en_m=_LIDAR_PLAN_SD_M, sd_h_m=0.05)
    out = []
    for b in _place_buildings(cand, n, rng, roofs, 4.0, 0.05):
        a = rng.uniform(0, 2 * np.pi)
        approx = b["vertex"][:2] + rng.uniform(0.5, 1.5) * np.array([np.cos(a), np.sin(a)])
        cp = extract_roof(np.asarray(b["scene"].xyz), approx, params=params)
        out.append((b["kind"], ((cp.enh_m - b["vertex"]) / cp.sd_m).tolist() if cp else None))
    return out


def main() -> None:
    from concurrent.futures import ProcessPoolExecutor

    n = int(sys.argv[1]) if len(sys.argv) > 1 else 800
    workers = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    per = 50
    jobs = [(1000 + k, min(per, n - k * per)) for k in range((n + per - 1) // per)]
    rows: list[tuple[str, list[float] | None]] = []
    with ProcessPoolExecutor(workers) as pool:
        for part in pool.map(_batch, jobs):
            rows += part
    print(f"{'kind':<8} {'n':>5} {'failed':>6}  {'mean z E / N / h (+- SE)':<36} {'RMS z E / N / h':<18} "
          f"{'|z| > 3':>8}")
    for kind in sorted({k for k, _ in rows}):
        z = np.array([v for k, v in rows if k == kind and v is not None])
        failed = sum(1 for k, v in rows if k == kind and v is None)
        se = 1 / np.sqrt(len(z))
        mean = " / ".join(f"{v:+.3f}" for v in z.mean(axis=0))
        rms = " / ".join(f"{v:.2f}" for v in np.sqrt((z ** 2).mean(axis=0)))
        print(f"{kind:<8} {len(z):>5} {failed:>6}  {mean} (+- {se:.3f})   {rms:<18} {int((np.abs(z) > 3).sum()):>8}")


if __name__ == "__main__":
    main()
