"""Radius sweep of roof-vertex extraction over the ``extract --find`` candidates of both AHN3 tiles.

    python benchmarks/bench_extract_sweep.py [--workers 2] [--radii 4 5 6 8 10 12]
        [--classes 6 | --classes all] [--cache /tmp/cands.pkl] [--plot docs/figures/extract_radius_sweep.png]
        [--csv rows.csv] [--quick] [--replot rows.csv] [--before rows_before.csv] [--cells [C ...]]
        [--rows rows.pkl [--reuse]] [--labels BEFORE NOW] [--buffer M] [--check-scales [S ...]] [--time-find]
        [--replot rows.csv --accepted --before rows.csv]

Issue 29 ("Extraction"): a sweep of radius 4-12 m over the ``--find`` candidates of both tiles must change no
accepted vertex by more than its sd.  The candidates are those of ``lidarcat extract --find --classes 6`` on
tests/data/lidar/ahn3_cropped_{1,2}.laz (EPSG:7415; the same bytes as the shared AHN3 crops); each is extracted
again, at its own position, with :func:`lidarcat.control.vertices.extract_roof` (what ``extract --at`` runs) at
every radius.  The reference is the default radius (8 m).  For each candidate accepted there (``ok``), and
each other radius whose extraction is ``ok``:

- ``d`` the 3-D displacement from the 8 m vertex (m), ``sd`` the largest axis of the 8 m vertex's 3 x 3
  covariance (m), ratio ``d / sd``;
- ``maha`` the Mahalanobis distance ``sqrt(d' (C_8 + C_r)^-1 d)`` (both covariances, as if independent: the
  clips share points, so this is the lenient reading);
- ``maha_diff`` the Mahalanobis distance with the covariance of the difference ``x_r - x_8`` itself: each
  vertex written as a linear function of its points' errors (:func:`lidarcat.control.stability.influence`), the points both clips
  share cancelling, propagated with the plane fit's own error model (iid part plus the cell components of
  :mod:`lidarcat.control.planes`): chi2 with 3 degrees of freedom when the covariances are honest;
- the statuses per radius (ok / ambiguous / no_vertex ...).

- ``check``: the radius-stability check of the 8 m vertex (:mod:`lidarcat.control.stability`: the extraction
  with the default ``stability_scales``, clips of 4, 5, 6, 10 and 12 m about the vertex): ``stable`` or
  ``unstable`` (refused); ``check_radius`` 1 on the rows of the radii it used.  The sweep's own extractions
  run without the check.  The summary counts the candidates refused and the accepted ones whose move still
  fails the difference test, at the radii the check used (moves shorter than the sd) and at the others (5 m).

The points are the ones ``--find`` searched (``--classes 6``, the building class) unless ``--classes all``.
Prints a table (one row per candidate with a ratio above 1, then the summary per radius) and writes the
figure of ``d / sd`` and both Mahalanobis distances against radius.  ``--cells`` with no sizes: the planes'
covariance of independent points (the code before the cell components), for a before/after comparison;
``--buffer 0``: no break-line buffer (:mod:`lidarcat.control.segment`; the code before it).  BLAS is pinned to one thread; ``--workers`` processes share the cloud.
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
    """Extraction of one candidate at every radius, and the radius-stability check of its 8 m vertex.

    Returns ``(pid, en, out, check)``, *out* a list of ``(radius, status, enh (3,), cov (3, 3), reason, m_exact,
    self_check)`` with ``m_exact`` the Mahalanobis distance of the vertex from the 8 m vertex with the
    covariance of their difference (:func:`lidarcat.control.stability.difference_cov`; NaN for the reference,
    when either is not ok, or when the propagation does not reproduce a reported covariance) and
    ``self_check`` the ratio of the propagated variance trace to the reported one.  The sweep's extractions
    run without the check (``stability_scales=()``); *check* is ``(status, reason, scales)`` of the 8 m
    extraction with it (``extract_roof`` as ``extract --at`` runs it: ``ok`` or ``unstable``; the vertex is
    the same), or None when the 8 m vertex is not ok or the check is off.
    """
    pid, en, radii, cells_m, *rest = args
    buffer_m = rest[0] if rest else None
    scales = tuple(rest[1]) if len(rest) > 1 and rest[1] is not None else None
    from lidarcat.control.params import get_params
    from lidarcat.control.stability import influence, move_distance
    from lidarcat.control.vertices import extract_roof

    idx = _TREE.query_ball_point(en, r=max(radii) + 1.5, return_sorted=True)
    sub = _XYZ[idx]
    p_check = get_params(cells_m=tuple(cells_m), edge_buffer_m=buffer_m)
    if scales is not None:
        p_check = p_check.replace(stability_scales=scales)
    p = p_check.replace(stability_scales=())
    cps = {r: extract_roof(sub, en, params=p.replace(radius_m=r), point_id=pid) for r in radii}
    infl = {r: influence(cp, p) if cp.status == "ok" else None for r, cp in cps.items()}
    ref = cps[DEFAULT_RADIUS_M]
    out = []
    for r in radii:
        cp, m_exact, check = cps[r], np.nan, np.nan
        if infl[r] is not None:
            check = float(np.trace(infl[r].cov_m2) / np.trace(cp.cov_m2))
            if ref.status == "ok" and r != DEFAULT_RADIUS_M:
                m, exact = move_distance(cp, ref, infl[r], infl[DEFAULT_RADIUS_M])
                m_exact = m if exact else np.nan
        out.append((r, cp.status, np.array(cp.enh_m), np.array(cp.cov_m2), cp.reason, m_exact, check))
    verdict = None
    if ref.status == "ok" and p_check.stability_scales:
        # the sub-cloud holds the points within max(radii) + 1.5 m of the position (the sweep re-clips it,
        # with the same points in the same order); the check clips reach max(scales) x 8 m about the vertex
        chk = extract_roof(sub, en, params=p_check.replace(radius_m=DEFAULT_RADIUS_M), point_id=pid)
        verdict = (chk.status, chk.reason, tuple(p_check.stability_scales))
    return pid, np.asarray(en), out, verdict


def compare(rows, ref_radius: float = DEFAULT_RADIUS_M):
    """Per candidate accepted at *ref_radius*: per other radius d (m), sd (m), d/sd, Mahalanobis, status.

    ``maha`` uses ``C_8 + C_r`` (independent clips), ``maha_diff`` the covariance of the difference with the
    shared points shared (:func:`lidarcat.control.stability.difference_cov`).

    *rows* as returned by :func:`sweep_one`.  Returns a list of dicts (one per candidate and radius); ``check``
    is the 8 m vertex's radius-stability verdict (``stable`` / ``unstable``; empty when not computed: rows of
    an older run) and ``check_radius`` 1 on the rows of the radii the check used.
    """
    table = []
    for pid, en, res, *rest in rows:
        ref = [x for x in res if x[0] == ref_radius][0]
        if ref[1] != "ok":
            continue
        verdict = rest[0] if rest else None
        check = "" if verdict is None else ("unstable" if verdict[0] == "unstable" else "stable")
        used = set() if verdict is None else {round(s * ref_radius, 6) for s in verdict[2]}
        e0, c0 = ref[2], ref[3]
        sd0 = float(np.sqrt(np.linalg.eigvalsh(c0)[-1]))
        verdict_s = check
        for r, status, e, c, reason, m_exact, check in res:
            row = dict(point=pid, radius_m=r, status=status, ref_sd_m=sd0, d_m=np.nan, d_plan_m=np.nan,
                       dh_m=np.nan, ratio=np.nan, maha=np.nan, maha_diff=m_exact, sd_m=np.nan, cov_check=check,
                       reason=reason, check=verdict_s, check_radius=int(round(r, 6) in used))
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
    ap.add_argument("--rows", default=None, help="pickle of the raw extractions (statuses, vertices, covariances) "
                                                 "written here; with --reuse read instead of extracting")
    ap.add_argument("--reuse", action="store_true", help="read --rows instead of extracting")
    ap.add_argument("--before", default=None, help="a --csv table drawn in grey beside (e.g. the --cells run)")
    ap.add_argument("--buffer", type=float, default=None,
                    help="edge_buffer_m of the faces' break-line buffer (default: the extraction default; 0: none, "
                         "the code before the buffer)")
    ap.add_argument("--check-scales", type=float, nargs="*", default=None,
                    help="stability_scales of the radius-stability check of the 8 m vertex (default: the "
                         "extraction default, 0.5 1.5; each scale x 8 m must be among --radii)")
    ap.add_argument("--labels", nargs=2, default=["before", "now"], metavar=("BEFORE", "NOW"),
                    help="legend names of the --before table and of this one")
    ap.add_argument("--cells", type=float, nargs="*", default=None,
                    help="cells_m of the plane covariance (default: the extraction default; none: independent "
                         "points, the covariance before the correlated components)")
    ap.add_argument("--accepted", action="store_true",
                    help="with --replot: draw only the candidates the radius-stability check accepts")
    ap.add_argument("--time-find", action="store_true",
                    help="time `extract --find --classes 6` on both tiles without and with the radius-stability "
                         "check (find_candidates, one process) and stop")
    a = ap.parse_args()
    title = f"AHN3 --find candidates (classes {a.classes}): vertex at radius r vs the 8 m clip"
    if a.replot:
        replot(a.replot, a.plot, title, a.before, tuple(a.labels), a.accepted)
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
    if a.time_find:
        time_find(cloud, area)
        return
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
    cells_m = tuple(get_params().cells_m if a.cells is None else a.cells)
    tasks = [(c.point.point_id, np.array(c.point.enh_m[:2]), radii, cells_m, a.buffer, a.check_scales)
             for c in cands]
    t0 = time.perf_counter()
    if a.reuse and a.rows:
        rows = pickle.loads(Path(a.rows).read_bytes())
    elif a.workers > 1:
        import multiprocessing as mp

        with ProcessPoolExecutor(a.workers, mp_context=mp.get_context("fork")) as ex:
            rows = list(ex.map(sweep_one, tasks, chunksize=4))
    else:
        rows = [sweep_one(t) for t in tasks]
    dt = time.perf_counter() - t0
    if a.rows and not a.reuse:
        Path(a.rows).write_bytes(pickle.dumps(rows))
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
        plot(table, radii, a.plot, title=title, before=read_table(a.before) if a.before else None,
             labels=tuple(a.labels))


def time_find(cloud, area) -> None:
    """``find_candidates(classes=[6])`` on both tiles without, then with, the radius-stability check: time, counts."""
    from lidarcat.control.params import get_params
    from lidarcat.control.vertices import find_candidates

    found = {}
    for name, p in (("without the check (stability_scales=())", get_params(stability_scales=())),
                    ("with the check (default)", get_params())):
        t0 = time.perf_counter()
        found[name] = find_candidates(cloud, box=area, classes=[6], params=p)
        print(f"--find {name}: {len(found[name])} candidates in {time.perf_counter() - t0:.0f} s "
              f"(load average {os.getloadavg()[0]:.2f})")
    off, on = found.values()
    gone = [c for c in off if all(np.hypot(*(c.point.enh_m[:2] - k.point.enh_m[:2])) > 1.0 for k in on)]
    print(f"candidates without the check that are not among those with it (within 1 m): {len(gone)}")


#: sqrt(chi2_3) quantiles: 99 % and 99.9 %
CHI3_99, CHI3_999 = 3.368, 4.033


def report(rows, table, radii) -> None:
    """Print statuses per radius, the candidates beyond their sd, and the summary per radius."""
    acc = sorted({t["point"] for t in table})
    print(f"\naccepted (ok) at {DEFAULT_RADIUS_M:g} m: {len(acc)} of {len(rows)}")
    checks = np.array([t["cov_check"] for t in table if t["status"] == "ok"], dtype=float)
    checks = checks[np.isfinite(checks)]
    if len(checks):
        print(f"propagated / reported covariance trace (influence rows vs cov_m2): median {np.median(checks):.3f}, "
              f"range {checks.min():.3f}-{checks.max():.3f}")
    print("\n| radius m | ok | other statuses | d <= sd | median d/sd | median d mm | median sd mm (8 m) "
          "| M_ind > 3.37 | median M_ind | M_diff > 3.37 | M_diff > 4.03 | median M_diff | d > 0.5 m |")
    print("|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in radii:
        if r == DEFAULT_RADIUS_M:
            continue
        sel = [t for t in table if t["radius_m"] == r]
        st = Counter(t["status"] for t in sel)
        ok = [t for t in sel if t["status"] == "ok"]
        rat = np.array([t["ratio"] for t in ok])
        mah = np.array([t["maha"] for t in ok])
        mdf = np.array([t["maha_diff"] for t in ok], dtype=float)
        dd = np.array([t["d_m"] for t in ok])
        sd0 = np.array([t["ref_sd_m"] for t in ok])
        other = ", ".join(f"{k} {v}" for k, v in sorted(st.items()) if k != "ok") or "-"
        print(f"| {r:g} | {len(ok)} | {other} | {int(np.sum(rat <= 1.0))} | {np.median(rat):.2f} | "
              f"{1000 * np.median(dd):.1f} | {1000 * np.median(sd0):.1f} | {int(np.sum(mah > CHI3_99))} | "
              f"{np.median(mah):.2f} | {int(np.sum(mdf > CHI3_99))} | {int(np.sum(mdf > CHI3_999))} | "
              f"{np.nanmedian(mdf):.2f} | {int(np.sum(dd > 0.5))} |")
    okr = [t for t in table if t["status"] == "ok" and t["radius_m"] != DEFAULT_RADIUS_M]
    n_nan = sum(not np.isfinite(t["maha_diff"]) for t in okr)
    if n_nan:
        print(f"M_diff not computed (a face refit failed): {n_nan}")
    bad = sorted({t["point"] for t in okr if t["ratio"] > 1.0})
    bad_m = sorted({t["point"] for t in okr if t["maha_diff"] > CHI3_999})
    print(f"\ncandidates whose ok vertex moves by more than its sd at some radius: {len(bad)} of {len(acc)}")
    print(f"candidates whose move fails the difference test (M_diff > {CHI3_999}, chi2_3 99.9 %) at some radius: "
          f"{len(bad_m)} of {len(acc)}; at 5-12 m: "
          f"{len({t['point'] for t in okr if t['maha_diff'] > CHI3_999 and t['radius_m'] >= 5})}")
    checked = {t["point"]: t["check"] for t in table if t["check"]}
    if checked:
        refused = sorted(k for k, v in checked.items() if v == "unstable")
        kept = [t for t in okr if checked.get(t["point"]) == "stable"]
        left = sorted({t["point"] for t in kept if t["maha_diff"] > CHI3_999})
        left_other = sorted({t["point"] for t in kept if t["maha_diff"] > CHI3_999 and not t["check_radius"]})
        print(f"\nradius-stability check of the {DEFAULT_RADIUS_M:g} m vertex: {len(refused)} of {len(checked)} "
              f"refused as unstable: {' '.join(refused)}")
        print(f"accepted (stable) with M_diff > {CHI3_999} at some radius: {len(left)} ({' '.join(left)}); at a "
              f"radius the check did not use: {len(left_other)}")
        okk = [t for t in kept]
        for r in radii:
            if r == DEFAULT_RADIUS_M:
                continue
            sel = [t for t in okk if t["radius_m"] == r]
            mdf = np.array([t["maha_diff"] for t in sel], dtype=float)
            rat = np.array([t["ratio"] for t in sel])
            print(f"  accepted, {r:g} m: {len(sel)} ok, d <= sd {int(np.sum(rat <= 1.0))}, M_diff > 4.03 "
                  f"{int(np.sum(mdf > CHI3_999))}, median M_diff {np.nanmedian(mdf) if len(mdf) else np.nan:.2f}, "
                  f"d > 0.5 m {int(np.sum(np.array([t['d_m'] for t in sel]) > 0.5))}")
    print("| point | E | N | sd mm (8 m) | d mm at " + " / ".join(f"{r:g}" for r in radii) + " | M_diff | check |")
    ref = {row[0]: [x for x in row[2] if x[0] == DEFAULT_RADIUS_M][0] for row in rows}
    for pid in sorted(set(bad) | set(bad_m)):
        sel = {t["radius_m"]: t for t in table if t["point"] == pid}
        cells = " / ".join("-" if sel[r]["status"] != "ok" else f"{1000 * sel[r]['d_m']:.0f}" for r in radii)
        mds = " / ".join("-" if sel[r]["status"] != "ok" or r == DEFAULT_RADIUS_M else f"{sel[r]['maha_diff']:.1f}"
                         for r in radii)
        e = ref[pid][2]
        print(f"| {pid} | {e[0]:.2f} | {e[1]:.2f} | {1000 * sel[DEFAULT_RADIUS_M]['ref_sd_m']:.1f} | {cells} | "
              f"{mds} | {sel[DEFAULT_RADIUS_M]['check']} |")


def plot(table, radii, path, title="", before=None, labels=("before", "now")) -> None:
    """``|d| / sd`` and the two Mahalanobis distances per radius: every candidate a dot (jittered), the median a bar.

    *before*: a table of the same form (e.g. ``--cells`` with no sizes: the covariance of independent
    points) drawn in grey to the left of each radius; *labels* name the two in the legend.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(0)
    others = [r for r in radii if r != DEFAULT_RADIUS_M]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    panels = ((axes[0], "ratio", "|d| / sd  (sd: largest axis of the 8 m vertex)", ((1.0, "1 sd"),)),
              (axes[1], "maha", "Mahalanobis distance with C_8 + C_r (independent clips)",
               ((CHI3_99, "chi2(3) 99 %"), (CHI3_999, "99.9 %"))),
              (axes[2], "maha_diff", "Mahalanobis distance with Cov(x_r - x_8) (shared points)",
               ((CHI3_99, "chi2(3) 99 %"), (CHI3_999, "99.9 %"))))
    # offsets, jitter and bars scaled to the spacing of the radii (1 m in the default sweep, 0.5 m in 4-12 m by halves)
    w = min(1.0, float(np.min(np.diff(others)))) if len(others) > 1 else 1.0
    for ax, key, lab, lines in panels:
        for tab, dx, col, name in ((before, -0.22 * w, "0.6", "before"),
                                   (table, 0.22 * w if before else 0.0, "C0", "now")):
            if tab is None:
                continue
            for r in others:
                ok = [t for t in tab if t["radius_m"] == r and t["status"] == "ok" and np.isfinite(t.get(key, np.nan))]
                if not ok:
                    continue
                y = np.maximum(np.array([t[key] for t in ok]), 1e-2)
                far = np.array([t["d_m"] > 0.5 for t in ok])
                x = r + dx + rng.uniform(-0.18 * w, 0.18 * w, len(y))
                ax.scatter(x[~far], y[~far], s=5, alpha=0.45, color=col, lw=0,
                           label=(labels[0] if name == "before" else labels[1])
                           if r == others[0] and before is not None else None)
                ax.scatter(x[far], y[far], s=16, color="C3", marker="x",
                           label="another corner (> 0.5 m)" if r == others[0] and name == "now" else None)
                ax.hlines(np.median(y), r + dx - 0.22 * w, r + dx + 0.22 * w, color="k", lw=2)
        for v, txt in lines:
            ax.axhline(v, color="C2" if v == 1.0 else "C1", lw=1, ls="--")
            ax.annotate(txt, (max(others) + 0.9, v), fontsize=7, va="bottom", ha="right")
        ax.set_yscale("log")
        ax.set_xlabel("clip radius (m); reference: the default 8 m")
        ax.set_title(lab, fontsize=9)
        ax.set_xticks(others, [f"{r:g}" for r in others], fontsize=7 if w < 1.0 else None)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=7)
    n = len({t["point"] for t in table})
    fig.suptitle(title + f"\n{n} candidates ok at 8 m; black bar: median", fontsize=10)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    print(f"figure: {path}")


def read_table(csv_path: str) -> list[dict]:
    """A ``--csv`` table back as dicts (numbers as floats)."""
    with open(csv_path, newline="") as f:
        return [{k: (v if k in ("point", "status", "reason", "check") else float(v)) for k, v in r.items()}
                for r in csv.DictReader(f)]


def replot(csv_path: str, path: str, title: str, before: str | None = None,
           labels: tuple = ("before", "now"), accepted: bool = False) -> None:
    """The figure again from a ``--csv`` table (no extraction); *accepted*: only the candidates the
    radius-stability check accepts (column ``check``), e.g. with the whole table as *before*."""
    table = read_table(csv_path)
    if accepted:
        table = [t for t in table if t.get("check") == "stable"]
    plot(table, sorted({t["radius_m"] for t in table}), path, title, read_table(before) if before else None,
         labels)


if __name__ == "__main__":
    main()
