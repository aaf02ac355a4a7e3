"""``--find`` near the search area's edge: reading the area alone vs the area plus the search margin.

    PYTHONPATH=src python benchmarks/bench_find_edge.py [--seed 1] [--size 200 150] [--inset 2] [--repeats 1]

``lidarcat extract --find --box`` used to read only the points inside the area, so a candidate near the
area's edge was extracted from a clip cut by the area's edge and checked (radius-stability check,
``ExtractionParams.stability_scales``: clips of up to 12 m about the vertex) with the same cut clips.  Now the
serial run reads the area plus :func:`lidarcat.control.vertices.search_margin_m` (14 m at the defaults;
:func:`lidarcat.control.search.search_area`) and the blocks read their margin beyond the area too.

On the synthetic town of benchmarks/bench_measured_control.py (:func:`lidarcat.synthetic.aerial.aerial_scene`,
10 points per m2, 3 cm height noise), a search area about its middle whose edges lie ``--inset`` m outside its
outermost roof vertices (the bounding box of the vertices within ``--size`` of the middle): ``find_candidates``
with the area's points alone (before) and with the area plus the margin (now), timed alternately.  With
``PYTHONPATH`` of the code before this change, its "area only" row is the old ``--find --box`` run.  Printed:
time, points read, candidates, how many of them differ (position or status), and, per true roof vertex
within 12 m of the area's edge, the candidate found before / now.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from lidarcat.control.vertices import find_candidates  # noqa: E402
from lidarcat.synthetic.aerial import aerial_scene  # noqa: E402


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", nargs=2, type=float, default=(200.0, 150.0))
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--inset", type=float, default=2.0)
    a = ap.parse_args(argv)
    bounds = (680_000.0, 7_184_000.0, 680_500.0, 7_184_400.0)
    sc = aerial_scene(bounds, texel_m=0.1, seed=a.seed)
    true = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    # the area: the bounding box of the true roof vertices within --size about the town's middle, plus
    # --inset m: the outermost vertices lie that far inside the area's edges
    w, h = a.size
    cx, cy = np.median(true[:, 0]), np.median(true[:, 1])
    sel = (np.abs(true[:, 0] - cx) <= w / 2) & (np.abs(true[:, 1] - cy) <= h / 2)
    lo, hi = true[sel, :2].min(axis=0) - a.inset, true[sel, :2].max(axis=0) + a.inset
    area = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    w, h = area[2] - area[0], area[3] - area[1]
    try:
        from lidarcat.control.search import search_area
    except ImportError:  # the code before (PYTHONPATH of an older tree): its "area only" time
        def search_area(area):
            return (area[0] - 14.0, area[1] - 14.0, area[2] + 14.0, area[3] + 14.0)
    big = search_area(area)
    rng = np.random.default_rng(a.seed)
    m = int(rng.poisson(10.0 * (big[2] - big[0]) * (big[3] - big[1])))
    e, n = rng.uniform(big[0], big[2], m), rng.uniform(big[1], big[3], m)
    z, _ = sc.surface(e, n)
    xyz = np.column_stack([e, n, z + rng.normal(0, 0.03, m)])
    inside = (xyz[:, 0] >= area[0]) & (xyz[:, 0] <= area[2]) & (xyz[:, 1] >= area[1]) & (xyz[:, 1] <= area[3])
    clouds = {"area only (before)": xyz[inside], "area + margin (now)": xyz}
    times: dict[str, list[float]] = {k: [] for k in clouds}
    found: dict[str, list] = {}
    for _ in range(a.repeats):
        for name, cloud in clouds.items():
            t0 = time.perf_counter()
            found[name] = find_candidates(cloud, box=area)
            times[name].append(time.perf_counter() - t0)
    print(f"town seed {a.seed}, area {w:.0f} x {h:.0f} m, margin {big[2] - area[2]:g} m; {len(true)} true vertices "
          f"in the town; times: best of {a.repeats}")
    print(f"{'read':<22} {'points':>8} {'time s':>7} {'cands':>6}")
    for name in clouds:
        print(f"{name:<22} {len(clouds[name]):8d} {min(times[name]):7.1f} {len(found[name]):6d}")
    (b_name, before), (n_name, now) = found.items()

    def key(c):
        return tuple(np.round(c.point.enh_m, 4)), c.point.status

    kb, kn = {key(c) for c in before}, {key(c) for c in now}
    print(f"candidates in both, identical: {len(kb & kn)}; only before: {len(kb - kn)}; only now: {len(kn - kb)}")
    d_edge = np.minimum.reduce([true[:, 0] - area[0], area[2] - true[:, 0], true[:, 1] - area[1],
                                area[3] - true[:, 1]])
    near = true[(d_edge > -1.0) & (d_edge < 12.0)]
    print(f"true vertices within 12 m inside the area's edge: {len(near)}")
    print(f"{'E':>12} {'N':>13} {'edge m':>6}  {'before: error mm':>17}  {'now: error mm':>14}")
    for v in near:
        de = float(min(v[0] - area[0], area[2] - v[0], v[1] - area[1], area[3] - v[1]))
        row = []
        for cands in (before, now):
            d = [np.linalg.norm(c.point.enh_m - v) for c in cands]
            row.append(f"{1000 * min(d):.0f}" if d and min(d) < 0.5 else "not found")
        print(f"{v[0]:12.2f} {v[1]:13.2f} {de:6.1f}  {row[0]:>17}  {row[1]:>14}")


if __name__ == "__main__":
    main()
