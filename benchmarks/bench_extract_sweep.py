"""Radius sweep of roof-vertex extraction over the ``extract --find`` candidates of both AHN3 tiles.

    python benchmarks/bench_extract_sweep.py [--workers 2] [--radii 4 5 6 8 10 12]
        [--classes 6 | --classes all] [--cache /tmp/cands.pkl] [--plot docs/figures/extract_radius_sweep.png]
        [--csv rows.csv] [--quick] [--replot rows.csv]

Issue 29 ("Extraction"): a sweep of radius 4-12 m over the ``--find`` candidates of both tiles must change no
accepted vertex by more than its sd.  The candidates are those of ``lidarcat extract --find --classes 6`` on
tests/data/lidar/ahn3_cropped_{1,2}.laz (EPSG:7415; the same bytes as the shared AHN3 crops); each is extracted
again, at its own position, with :func:`lidarcat.control.vertices.extract_roof` (what ``extract --at`` runs) at
every radius.  The reference is the default radius (8 m).  For each candidate accepted there (``ok``), and
each other radius whose extraction is ``ok``:

- ``d`` the 3-D displacement from the 8 m vertex (m), ``sd`` the largest axis of the 8 m vertex's 3 x 3
  covariance (m), ratio ``d / sd``;
- ``m`` the Mahalanobis distance ``sqrt(d' (C_8 + C_r)^-1 d)`` (both covariances, as if independent: the
  clips share points, so this is the lenient reading);
- the statuses per radius (ok / ambiguous / no_vertex ...).

The points are the ones ``--find`` searched (``--classes 6``, the building class) unless ``--classes all``.
Prints a table (one row per candidate with a ratio above 1, then the summary per radius) and writes the
figure of ``d / sd`` against radius.  BLAS is pinned to one thread; ``--workers`` processes share the cloud.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import pickle  # noqa: E402
import time  # noqa: E402
from collections import Counter  # noqa: E402
from concurrent.futures import ProcessPoolExecutor  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TILES = [ROOT / "tests" / "data" / "lidar" / "ahn3_cropped_1.laz", ROOT / "tests" / "data" / "lidar" / "ahn3_cropped_2.laz"]
DEFAULT_RADIUS_M = 8.0

_XYZ = None  # the cloud, shared with forked workers
_TREE = None


def sweep_one(args):
    """Extraction of one candidate at every radius: list of (radius, status, enh (3,), cov (3, 3), reason)."""
    pid, en, radii = args
    from lidarcat.control.vertices import extract_roof

    idx = _TREE.query_ball_point(en, r=max(radii) + 0.01, return_sorted=True)
    sub = _XYZ[idx]
    out = []
    for r in radii:
        cp = extract_roof(sub, en, radius_m=r, point_id=pid)
        out.append((r, cp.status, np.array(cp.enh_m), np.array(cp.cov_m2), cp.reason))
    return pid, np.asarray(en), out


def compare(rows, ref_radius: float = DEFAULT_RADIUS_M):
    """Per candidate accepted at *ref_radius*: per other radius d (m), sd (m), d/sd, Mahalanobis, status.

    *rows* as returned by :func:`sweep_one`.  Returns a list of dicts (one per candidate and radius).
    """
    table = []
    for pid, en, res in rows:
        ref = [x for x in res if x[0] == ref_radius][0]
        if ref[1] != "ok":
            continue
        e0, c0 = ref[2], ref[3]
        sd0 = float(np.sqrt(np.linalg.eigvalsh(c0)[-1]))
        for r, status, e, c, reason in res:
            row = dict(point=pid, radius_m=r, status=status, ref_sd_m=sd0, d_m=np.nan, d_plan_m=np.nan,
                       dh_m=np.nan, ratio=np.nan, maha=np.nan, sd_m=np.nan, reason=reason)
            if np.all(np.isfinite(e)):
                d = e - e0
                row.update(d_m=float(np.linalg.norm(d)), d_plan_m=float(np.hypot(*d[:2])), dh_m=float(d[2]),
                           ratio=float(np.linalg.norm(d)) / sd0)
                if np.all(np.isfinite(c)):
                    row["sd_m"] = float(np.sqrt(np.linalg.eigvalsh(c)[-1]))
                    row["maha"] = 0.0 if r == ref_radius else float(np.sqrt(d @ np.linalg.solve(c0 + c, d)))
            table.append(row)
    return table


def load_cloud(classes):
    from lidarcat.lidar import TileIndex

    idx = TileIndex.build([str(t) for t in TILES], crs="EPSG:7415")
    b = idx.bounds
    area = (b.xmin, b.ymin, b.xmax, b.ymax)
    return idx, area, idx.query_box(*area)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--radii", type=float, nargs="+", default=[4, 5, 6, 8, 10, 12])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--classes", default="6", help="comma list of classes for the extraction points, or 'all'")
    ap.add_argument("--cache", default=None, help="pickle of the --find candidates (read if present, else written)")
    ap.add_argument("--plot", default=None)
    ap.add_argument("--csv", default=None)
    ap.add_argument("--quick", action="store_true", help="the first 20 candidates only")
    ap.add_argument("--replot", default=None, help="a --csv table: draw --plot from it and stop")
    a = ap.parse_args()
    title = f"AHN3 --find candidates (classes {a.classes}): vertex at radius r vs the 8 m clip"
    if a.replot:
        replot(a.replot, a.plot, title)
        return
    if not all(t.exists() for t in TILES):
        print("AHN3 tiles not found in tests/data/lidar; skipping")
        return
    global _XYZ, _TREE
    from scipy.spatial import cKDTree

    from lidarcat.control.params import get_params
    from lidarcat.control.vertices import find_candidates, search_points

    print(f"load average before: {os.getloadavg()[0]:.2f}")
    idx, area, cloud = load_cloud(None)
    t0 = time.perf_counter()
    if a.cache and Path(a.cache).exists():
        cands = pickle.loads(Path(a.cache).read_bytes())
        print(f"{len(cands)} --find candidates (classes 6) read from {a.cache}")
    else:
        cands = find_candidates(cloud, box=area, classes=[6])
        print(f"{len(cands)} --find candidates (classes 6) in {time.perf_counter() - t0:.0f} s")
        if a.cache:
            Path(a.cache).write_bytes(pickle.dumps(cands))
    if a.quick:
        cands = cands[:20]
    classes = None if a.classes == "all" else [int(c) for c in a.classes.split(",")]
    if classes is None:
        _XYZ = np.asarray(cloud.xyz)
    else:
        _XYZ, _ = search_points(cloud, area, get_params(radius_m=max(a.radii)), classes)
    _TREE = cKDTree(_XYZ[:, :2])
    radii = sorted(set(float(r) for r in a.radii) | {DEFAULT_RADIUS_M})
    tasks = [(c.point.point_id, np.array(c.point.enh_m[:2]), radii) for c in cands]
    t0 = time.perf_counter()
    if a.workers > 1:
        import multiprocessing as mp

        with ProcessPoolExecutor(a.workers, mp_context=mp.get_context("fork")) as ex:
            rows = list(ex.map(sweep_one, tasks, chunksize=4))
    else:
        rows = [sweep_one(t) for t in tasks]
    dt = time.perf_counter() - t0
    print(f"{len(tasks)} candidates x {len(radii)} radii extracted in {dt:.0f} s ({a.workers} workers); "
          f"points: classes {a.classes} ({len(_XYZ)})")
    table = compare(rows)
    report(rows, table, radii)
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(table[0]))
            w.writeheader()
            w.writerows(table)
    if a.plot:
        plot(table, radii, a.plot, title=title)


def report(rows, table, radii) -> None:
    """Print statuses per radius, the candidates beyond their sd, and the summary per radius."""
    acc = sorted({t["point"] for t in table})
    print(f"\naccepted (ok) at {DEFAULT_RADIUS_M:g} m: {len(acc)} of {len(rows)}")
    print("\n| radius m | " + " | ".join(f"{s}" for s in ("ok", "other statuses (of the accepted)", "d/sd <= 1",
                                                             "median d/sd", "max d/sd", "median d mm",
                                                             "max Mahalanobis")) + " |")
    print("|---:|---:|---|---:|---:|---:|---:|---:|")
    for r in radii:
        sel = [t for t in table if t["radius_m"] == r]
        st = Counter(t["status"] for t in sel)
        ok = [t for t in sel if t["status"] == "ok"]
        rat = np.array([t["ratio"] for t in ok])
        mah = np.array([t["maha"] for t in ok])
        dd = np.array([t["d_m"] for t in ok])
        other = ", ".join(f"{k} {v}" for k, v in sorted(st.items()) if k != "ok") or "-"
        print(f"| {r:g} | {len(ok)} | {other} | {int(np.sum(rat <= 1.0))} | {np.median(rat):.2f} | "
              f"{np.max(rat):.1f} | {1000 * np.median(dd):.1f} | {np.max(mah):.1f} |")
    bad = sorted({t["point"] for t in table if t["status"] == "ok" and t["ratio"] > 1.0})
    print(f"\ncandidates whose ok vertex moves by more than its sd at some radius: {len(bad)} of {len(acc)}")
    print("| point | E | N | sd mm (8 m) | d mm at " + " / ".join(f"{r:g}" for r in radii) + " |")
    ref = {pid: [x for x in res if x[0] == DEFAULT_RADIUS_M][0] for pid, _, res in rows}
    for pid in bad:
        sel = {t["radius_m"]: t for t in table if t["point"] == pid}
        cells = " / ".join("-" if sel[r]["status"] != "ok" else f"{1000 * sel[r]['d_m']:.0f}" for r in radii)
        e = ref[pid][2]
        print(f"| {pid} | {e[0]:.2f} | {e[1]:.2f} | {1000 * sel[DEFAULT_RADIUS_M]['ref_sd_m']:.1f} | {cells} |")


def plot(table, radii, path, title="") -> None:
    """``|d| / sd`` and the Mahalanobis distance per radius: every candidate a dot (jittered), the median a bar."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    others = [r for r in radii if r != DEFAULT_RADIUS_M]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for ax, key, lab, lines in ((axes[0], "ratio", "|d| / sd  (sd: largest axis of the 8 m vertex)",
                                 ((1.0, "1 sd"), (4.03 * np.sqrt(2), "5.7 sd"))),
                                (axes[1], "maha", "Mahalanobis distance with C_8 + C_r",
                                 ((4.03, "chi2(3) 99.9 %"),))):
        for r in others:
            ok = [t for t in table if t["radius_m"] == r and t["status"] == "ok"]
            y = np.maximum(np.array([t[key] for t in ok]), 1e-2)
            far = np.array([t["d_m"] > 0.5 for t in ok])
            x = r + rng.uniform(-0.35, 0.35, len(y))
            ax.scatter(x[~far], y[~far], s=6, alpha=0.45, color="C0", lw=0)
            ax.scatter(x[far], y[far], s=18, color="C3", marker="x", label="another corner (> 0.5 m)"
                       if r == others[0] else None)
            ax.hlines(np.median(y), r - 0.45, r + 0.45, color="k", lw=2)
            n_bad = sum(t["status"] != "ok" for t in table if t["radius_m"] == r)
            if n_bad:
                ax.annotate(f"{n_bad} not ok", (r, 1.2e-2), ha="center", fontsize=7, color="C1")
        for v, txt in lines:
            ax.axhline(v, color="C2" if v == 1.0 else "C1", lw=1, ls="--")
            ax.annotate(txt, (max(others) + 0.6, v), fontsize=7, va="bottom", ha="right")
        ax.set_yscale("log")
        ax.set_xlabel("clip radius (m); reference: the default 8 m")
        ax.set_ylabel(lab)
        ax.set_xticks(others)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper center", fontsize=7)
    n = len({t["point"] for t in table})
    fig.suptitle(title + f"\n{n} candidates ok at 8 m; black bar: median", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    print(f"figure: {path}")


def replot(csv_path: str, path: str, title: str) -> None:
    """The figure again from a ``--csv`` table (no extraction)."""
    with open(csv_path, newline="") as f:
        table = [{k: (v if k in ("point", "status", "reason") else float(v)) for k, v in r.items()}
                 for r in csv.DictReader(f)]
    plot(table, sorted({t["radius_m"] for t in table}), path, title)


if __name__ == "__main__":
    main()
