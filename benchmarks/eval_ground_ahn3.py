"""Ground classification against the AHN3 tiles' own class 2 (the Dutch provider's, independent).

For each tile in tests/data/lidar and each method (SMRF, PTD with defaults),
prints Type I (reference ground rejected, % of the reference ground), Type II
(reference objects accepted, % of the objects), total error (% of all points),
Cohen's kappa and the time.  Reference: class 2 is ground; every other class
(1, 6 building, 9 water, 26) is an object.  The filters read only E, N, h and
the return numbers, never the classes.

Usage::

    python benchmarks/eval_ground_ahn3.py            # both methods (PTD takes minutes)
    python benchmarks/eval_ground_ahn3.py --methods smrf
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from lidarcat.lidar import read_points
from lidarcat.production.ground import classify_ground, confusion

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "lidar"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--methods", default="smrf,ptd")
    args = ap.parse_args()
    print(f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    print(f"{'tile':20} {'method':6} {'points':>8} {'Type I %':>9} {'Type II %':>9} {'total %':>8} "
          f"{'kappa':>6} {'s':>7}")
    for f in ("ahn3_cropped_1.laz", "ahn3_cropped_2.laz"):
        pc = read_points(DATA / f, crs="EPSG:7415")
        a = pc.attributes
        ref = a["classification"] == 2
        for m in args.methods.split(","):
            t = time.perf_counter()
            g = classify_ground(pc.xyz, a["return_number"], a["number_of_returns"], method=m)
            dt = time.perf_counter() - t
            c = confusion(ref, g)
            print(f"{f:20} {m:6} {len(pc):8d} {100 * c.type1:9.2f} {100 * c.type2:9.2f} {100 * c.total:8.2f} "
                  f"{c.kappa:6.3f} {dt:7.1f}", flush=True)


if __name__ == "__main__":
    main()
