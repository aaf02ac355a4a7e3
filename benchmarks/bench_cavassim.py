"""Where does Cavassim's (2005) Table 09 building ordering exist?  A sweep of the synthetic town.

    python benchmarks/bench_cavassim.py                 # seeds 0, 1, 2 (62 s at load 1.3)
    python benchmarks/bench_cavassim.py --seeds 0-5     # more seeds (132 s at load 1.3-1.9)
    python benchmarks/bench_cavassim.py --quick         # seed 0, a smoke run (one seed decides no verdict: "=")
    python benchmarks/bench_cavassim.py --tables --seeds 0-5   # Tables 06-09 of the paper-admitted scene

:func:`lidarcat.synthetic.cavassim.cavassim_experiment` (the paper's three
products: digitising on the LiDAR images, monorestitution with the nearest
neighbour and with the triangular plane of a 1 m first-return DSM) on towns
whose buildings all have one eave height h in {3, 6, 9} m with every roof
outline corner within r in {100, 200, 330} m of the photo's nadir; the
largest lean at a corner is then ``h r / (922 - h)``.  Beside them the scene
the paper's Tables 06-08 admit (eaves 3-6 m, r <= 100 m: docs/mapping.md
derives it) and the default town (eaves 6-12 m, centres in a 600 m square:
corners to ~330 m) as the peer.  Everything else is the default experiment.

Printed per scene: the building r90 (m) of each product, mean over the seeds;
the differences TIN - nearest, nearest - image and TIN - image of the building r90
(mean over the seeds +- its standard error, sd / sqrt(seeds)) and their
verdict: ``<`` when the mean is below zero by more than two standard errors,
``>`` above, ``=`` within (a tie: the seeds do not decide); the paper's
ordering TIN < nearest < image holds (``yes``) where all three read ``<``
(``image only``: both monorestitutions beat the image, TIN vs nearest does
not hold); in how many seeds
it holds strictly; the mean resultant and its sd (Tables 06-08 style, mean
over the seeds); the road r90s.  With the same seed and radius the towns are
the same buildings at the same places (the eave height is drawn but does not
move them): the rows of one radius differ by the heights only.  BLAS is
pinned to one thread.  Note ``uptime`` next to the figures.

``--tables``: the paper's Tables 06-08 (mean and sd of dE, dN and the
resultant, m; K-S and Hotelling's T^2 passed in how many seeds) and Table 09
(r90) of the paper-admitted scene, each figure the mean over the seeds,
beside the paper's.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.synthetic.cavassim import CAVASSIM_TABLE_09, CAVASSIM_TABLES_06_08, cavassim_experiment  # noqa: E402

PRODUCTS = ("intensity_image", "nearest", "tin")
#: the scene the paper's Tables 06-08 admit (docs/mapping.md): its label and keyword arguments
PAPER_ADMITTED = ("paper-admitted: eaves 3-6 m, r <= 100 m", {"eave_m": (3.0, 6.0), "max_corner_radius_m": 100.0})


def _seeds(text: str) -> list[int]:
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(s) for s in text.split(",")]


def scenes() -> list[tuple[str, dict]]:
    """(label, keyword arguments of cavassim_experiment) of the rows of the table."""
    out: list[tuple[str, dict]] = [PAPER_ADMITTED]
    for h in (3.0, 6.0, 9.0):
        for r in (100.0, 200.0, 330.0):
            out.append((f"h = {h:g} m, r <= {r:g} m", {"eave_m": (h, h), "max_corner_radius_m": r}))
    out.append(("default: eaves 6-12 m, 600 m square", {}))
    return out


def run_scene(kwargs: dict, seeds: list[int]) -> dict:
    """Mean figures of one scene over *seeds* (module docstring)."""
    b_r90 = {p: [] for p in PRODUCTS}
    road = {p: [] for p in PRODUCTS}
    res = {p: [] for p in PRODUCTS}
    sd = {p: [] for p in PRODUCTS}
    lean_max, ordered, mono_better = [], 0, 0
    for s in seeds:
        r = cavassim_experiment(seed=s, all_products=False, **kwargs)
        for p in PRODUCTS:
            t = r["tables"][p]["building"]
            b_r90[p].append(t["r90_m"])
            res[p].append(t["mean_resultant"])
            sd[p].append(t["sd_resultant"])
            road[p].append(r["r90"][p]["road"])
        lean_max.append(float(np.max(r["corners"]["lean_m"])))
        x = {p: b_r90[p][-1] for p in PRODUCTS}
        ordered += x["tin"] < x["nearest"] < x["intensity_image"]
        mono_better += max(x["tin"], x["nearest"]) < x["intensity_image"]
    m = {p: float(np.mean(b_r90[p])) for p in PRODUCTS}
    diff = {}
    for key, (a, b) in {"tin-nearest": ("tin", "nearest"), "nearest-image": ("nearest", "intensity_image"),
                         "tin-image": ("tin", "intensity_image")}.items():
        d = np.subtract(b_r90[a], b_r90[b])
        se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
        mean = float(d.mean())
        diff[key] = (mean, se, "<" if mean + 2 * se < 0 else ">" if mean - 2 * se > 0 else "=")
    return {"r90": m, "diff": diff, "road": {p: float(np.mean(road[p])) for p in PRODUCTS},
            "res": {p: float(np.mean(res[p])) for p in PRODUCTS}, "sd": {p: float(np.mean(sd[p])) for p in PRODUCTS},
            "lean_max": float(np.max(lean_max)), "ordered_seeds": ordered, "mono_better_seeds": mono_better}


def _verdict(diff: dict) -> str:
    """The paper's ordering on the means: ``yes``, ``image only`` (both beat the image, TIN vs nearest
    undecided or reversed) or ``no``."""
    mono = diff["nearest-image"][2] == "<" and diff["tin-image"][2] == "<"
    if mono and diff["tin-nearest"][2] == "<":
        return "yes"
    return "image only" if mono else "no"


def paper_tables(seeds: list[int]) -> None:
    """Print Tables 06-09 of the paper-admitted scene beside the paper's (module docstring)."""
    label, kw = PAPER_ADMITTED
    runs = [cavassim_experiment(seed=s, all_products=False, **kw)["tables"] for s in seeds]
    keys = ("mean_E", "sd_E", "mean_N", "sd_N", "mean_resultant", "sd_resultant", "r90_m")
    names = {"intensity_image": "image (Table 06)", "nearest": "nearest (Table 07)", "tin": "TIN (Table 08)"}
    print(f"{label}, seeds {seeds}: ours (mean over the seeds) / paper, m")
    print("| product | class | mean dE | sd dE | mean dN | sd dN | mean resultant | sd resultant | r90 (Table 09) "
          "| K-S passed | T^2 passed |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for p in PRODUCTS:
        for c in ("building", "road"):
            ref = {**CAVASSIM_TABLES_06_08[p][c], "r90_m": CAVASSIM_TABLE_09[p][c]}
            cells = " | ".join(f"{np.mean([t[p][c][k] for t in runs]):.3f} / {ref[k]:.3f}" for k in keys)
            ks = sum(bool(t[p][c]["ks"]["passed"]) for t in runs)
            t2 = sum(bool(t[p][c]["hotelling"]["passed"]) for t in runs)
            print(f"| {names[p]} | {c} | {cells} | {ks}/{len(runs)} | {t2}/{len(runs)} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,1,2", help="seeds: 0,1,2 or 0-5 (default 0,1,2)")
    ap.add_argument("--quick", action="store_true", help="seed 0 only")
    ap.add_argument("--tables", action="store_true", help="Tables 06-09 of the paper-admitted scene only")
    a = ap.parse_args()
    seeds = [0] if a.quick else _seeds(a.seeds)
    print(f"load: {os.getloadavg()[0]:.2f} (1 min), seeds {seeds}")
    if a.tables:
        paper_tables(seeds)
        print(f"\nload: {os.getloadavg()[0]:.2f} (1 min)")
        return
    p = CAVASSIM_TABLE_09
    print(f"paper Table 09 buildings: image {p['intensity_image']['building']}, nearest {p['nearest']['building']}, "
          f"TIN {p['tin']['building']}; Tables 06-08 resultant 0.594 +- 0.194, 0.437 +- 0.151, 0.244 +- 0.147 m")
    print()
    print("| scene | largest lean (m) | r90 image | r90 nearest | r90 TIN | TIN - nearest | nearest - image "
          "| TIN - image | paper's ordering | TIN < nearest < image (seeds) | both monorestitutions < image (seeds) "
          "| resultant image / nearest / TIN (mean +- sd) | roads r90 image / nearest / TIN | s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    n = len(seeds)
    for label, kw in scenes():
        t0 = time.perf_counter()
        x = run_scene(kw, seeds)
        dt = time.perf_counter() - t0
        r, q = x["r90"], x["road"]
        resid = " / ".join(f"{x['res'][k]:.2f} +- {x['sd'][k]:.2f}" for k in PRODUCTS)
        print(f"| {label} | {x['lean_max']:.2f} | {r['intensity_image']:.2f} | {r['nearest']:.2f} | {r['tin']:.2f} "
              + "".join(f"| {d[0]:+.2f} +- {d[1]:.2f} {d[2]} " for d in x["diff"].values())
              + f"| {_verdict(x['diff'])} | {x['ordered_seeds']}/{n} | {x['mono_better_seeds']}/{n} | {resid} "
              f"| {q['intensity_image']:.2f} / {q['nearest']:.2f} / {q['tin']:.2f} | {dt:.0f} |", flush=True)
    print(f"\nload: {os.getloadavg()[0]:.2f} (1 min)")


if __name__ == "__main__":
    main()
