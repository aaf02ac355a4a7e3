"""Ground classification against the AHN3 tiles' own class 2 (the Dutch provider's, independent).

For each tile in tests/data/lidar and each method, prints Type I (reference
ground rejected, % of the reference ground), Type II (reference objects
accepted, % of the objects), total error (% of all points), Cohen's kappa and
the time.  Reference: class 2 is ground; every other class (1, 6 building, 9
water, 26) is an object.  The filters read only E, N, h and the return numbers,
never the classes.

Methods: ``smrf``, ``ptd``, ``csf`` (lidarcat's, defaults: adaptive), ``csf0``
(lidarcat's CSF with ``adaptive=False``: the reference algorithm), and the peer
``csfref``: the reference CSF wheel (PyPI ``cloth-simulation-filter``, bench
extra; skipped when absent) on the last returns, resolution 1 m, rigidness 2,
slope post-processing, as ``csf0``.  Peers and ours alternate tile by tile in
the same run; note the load printed.

Usage::

    python benchmarks/eval_ground_ahn3.py            # smrf and ptd (PTD takes minutes)
    python benchmarks/eval_ground_ahn3.py --methods smrf
    python benchmarks/eval_ground_ahn3.py --methods csfref,csf0,csf
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from lidarcat.lidar import read_points
from lidarcat.production.csf import CSFParameters
from lidarcat.production.ground import classify_ground, confusion

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "lidar"
sys.path.insert(0, str(Path(__file__).resolve().parent))


def _classify(method: str, xyz: np.ndarray, rn: np.ndarray, nr: np.ndarray) -> np.ndarray:
    if method == "csfref":
        from eval_ground_density import _csf_reference

        return _csf_reference(xyz, rn >= nr)
    if method == "csf0":
        return classify_ground(xyz, rn, nr, method="csf", params=CSFParameters(adaptive=False))
    return classify_ground(xyz, rn, nr, method=method)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--methods", default="smrf,ptd")
    ap.add_argument("--tiles", default="1,2", help="AHN3 tiles (ahn3_cropped_N.laz)")
    args = ap.parse_args()
    methods = args.methods.split(",")
    if "csfref" in methods:
        try:
            import CSF  # noqa: F401
        except ImportError:
            print("csfref skipped: the cloth-simulation-filter wheel is not installed (pip install .[bench])")
            methods.remove("csfref")
    print(f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores")
    print(f"{'tile':20} {'method':6} {'points':>8} {'Type I %':>9} {'Type II %':>9} {'total %':>8} "
          f"{'kappa':>6} {'s':>7}")
    for t in args.tiles.split(","):
        f = f"ahn3_cropped_{t}.laz"
        pc = read_points(DATA / f, crs="EPSG:7415")
        a = pc.attributes
        ref = a["classification"] == 2
        rn, nr = np.asarray(a["return_number"]), np.asarray(a["number_of_returns"])
        for m in methods:
            t0 = time.perf_counter()
            g = _classify(m, pc.xyz, rn, nr)
            dt = time.perf_counter() - t0
            c = confusion(ref, g)
            print(f"{f:20} {m:6} {len(pc):8d} {100 * c.type1:9.2f} {100 * c.type2:9.2f} {100 * c.total:8.2f} "
                  f"{c.kappa:6.3f} {dt:7.1f}", flush=True)
    print(f"load average {' '.join(f'{v:.1f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
