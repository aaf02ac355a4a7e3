"""Ground filters on synthetic landscapes with known ground (steep, forest, bridge, city, low outliers).

For each landscape of :mod:`lidarcat.synthetic.landscapes` and each method with
its default parameters, prints Type I (true ground rejected, % of the ground),
Type II (objects accepted, % of the objects), total error (% of all points),
Cohen's kappa and the time, and the total error of the points farther than
``--margin`` (40 m, one SMRF window) from the area's edge: a tiled run reads
that much of the neighbours, so only a survey's own border behaves like the
edge of these squares.  The filters read only E, N, h and the return
numbers.

Usage::

    python benchmarks/eval_ground_landscapes.py                 # 200 m squares, 6 pulses/m2, both methods
    python benchmarks/eval_ground_landscapes.py --methods smrf --seeds 0,1,2
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from lidarcat.production.ground import classify_ground, confusion
from lidarcat.synthetic.landscapes import LANDSCAPES, make_landscape


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--methods", default="smrf,ptd")
    ap.add_argument("--landscapes", default=",".join(LANDSCAPES))
    ap.add_argument("--size", type=float, default=200.0, help="side of each landscape, metres")
    ap.add_argument("--density", type=float, default=6.0, help="pulses per m2")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--margin", type=float, default=40.0, help="edge band left out of 'inner %%', metres")
    args = ap.parse_args()
    print(f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores; "
          f"{args.size:.0f} m squares, {args.density:g} pulses/m2, seeds {args.seeds}")
    print(f"{'landscape':13} {'method':6} {'points':>8} {'Type I %':>9} {'Type II %':>9} {'total %':>8} "
          f"{'kappa':>6} {'inner %':>8} {'s':>6}")
    totals: dict[str, list[float]] = {}
    for name in args.landscapes.split(","):
        for m in args.methods.split(","):
            t1, t2, tot, kap, inner, n, dt = [], [], [], [], [], 0, 0.0
            for seed in (int(s) for s in args.seeds.split(",")):
                ls = make_landscape(name, size_m=args.size, density=args.density, seed=seed)
                t = time.perf_counter()
                g = classify_ground(ls.xyz, ls.return_number, ls.number_of_returns, method=m)
                dt += time.perf_counter() - t
                c = confusion(ls.ground, g)
                t1.append(c.type1), t2.append(c.type2), tot.append(c.total), kap.append(c.kappa)
                e = args.margin
                ins = np.all((ls.xyz[:, :2] >= e) & (ls.xyz[:, :2] <= args.size - e), axis=1)
                inner.append(confusion(ls.ground[ins], g[ins]).total)
                n += len(ls)
            totals.setdefault(m, []).append(float(np.mean(tot)))
            print(f"{name:13} {m:6} {n:8d} {100 * np.mean(t1):9.2f} {100 * np.mean(t2):9.2f} "
                  f"{100 * np.mean(tot):8.2f} {np.mean(kap):6.3f} {100 * np.mean(inner):8.2f} {dt:6.1f}", flush=True)
    for m, v in totals.items():
        print(f"mean total error {m}: {100 * np.mean(v):.2f} %")


if __name__ == "__main__":
    main()
