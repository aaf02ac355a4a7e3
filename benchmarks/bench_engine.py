"""Production-size bundle blocks: lidarcat's engine against Ceres in the same run (issue 11).

Run from the repository root::

    python benchmarks/bench_engine.py [--photos 100 1000 5000 10000] [--no-peer] [--json out.json]
                                      [--plot docs/figures/bundle_scaling.png]
    python benchmarks/bench_engine.py --photos 5000 10000 --pairs 8     # the scaling ratio

With ``--pairs K`` (two sizes) lidarcat alone runs K times on each size, the two
alternating, each in a fresh process from the same approximations, and the
table prints every pair's ratio and the median: one run's ratio spreads by
about +-15 % on this machine, the median is the figure to quote.  Each pair
also splits its time: the factorisations, the reuse steps and the precision
(work growing as photos^1.5 on a two-dimensional block) against the rest
(model, assembly, analysis, checks: work growing linearly) -- the ratio of
the rest is what the whole ratio would be if the photos^1.5 work cost nothing.

For every size, the seeded block of :func:`lidarcat.synthetic.block.aerial_block`
(60 % / 30 % overlap, about 58 observations per photo, 0.5 px noise) gets its
approximations once (timed, not part of the comparison), then each solver runs
in its own process from those same values (so ``max RSS`` is each solver's peak,
problem included):

* lidarcat: ``adjust(problem, initial=..., precision=...)`` -- default ``all``:
  the sd of every photo and every point -- with the share of each phase
  (``BundleResult.phases_s``); the engine pins BLAS to one thread and gives the
  dense kernels of the big fronts of its factor ``--blas-threads`` threads
  (default 2, the cores Ceres gets; 1: single-threaded throughout);
* Ceres 2.2 SPARSE_SCHUR (SuiteSparse), 2 threads, through pycolmap's bundle
  adjuster (``benchmarks/_ceres_peer.py``; the ``bench`` extra), no covariance;
  ``--peer-solver iterative_schur:schur_jacobi`` (or ``cluster_jacobi``,
  ``cluster_tridiagonal``) runs Ceres's iterative Schur solvers instead, whose
  cost per step grows linearly with the block.

Both reach the same minimum (the table prints 0.5 v'Pv of both).  Timings on a
shared machine: note the load printed with the table.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
#: Ceres step solvers the peer can run (``--peer-solver``)
PEER_SOLVERS = ("sparse_schur", "iterative_schur:schur_jacobi", "iterative_schur:cluster_jacobi",
                "iterative_schur:cluster_tridiagonal")


def _child(args) -> None:
    from lidarcat.synthetic.block import aerial_block

    block = aerial_block(args.photos[0])
    init = np.load(args.init)
    eo, pts = init["eo"], init["pts"]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    if args.child == "lidarcat":
        from lidarcat.bundle import adjust

        t0 = time.perf_counter()
        r = adjust(block.problem, initial=(eo, pts), precision=args.precision, solver=args.solver)
        out = {"seconds": time.perf_counter() - t0, "iterations": r.n_iter, "cost": 0.5 * r.vtpv,
               "status": r.status, "phases": r.phases_s,
               "finite_sd": bool(np.isfinite(r.point_sd_m).all() and np.isfinite(r.eo_sd).all())}
    else:
        sys.path.insert(0, str(HERE))
        from _ceres_peer import solve_with_ceres

        solver, _, prec = args.peer_solver.upper().partition(":")
        c = solve_with_ceres(block.problem, eo, pts, threads=args.threads, linear_solver=solver,
                             preconditioner=prec or None)
        out = {"seconds": c["seconds"], "iterations": c["iterations"], "cost": c["final_cost"],
               "status": c["report"].split("Termination: ")[-1]}
    out["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    out["rss_before_mb"] = rss0
    print("RESULT " + json.dumps(out))


def _run_child(kind: str, n: int, init: str, args) -> dict:
    cmd = [sys.executable, __file__, "--child", kind, "--photos", str(n), "--init", init,
           "--precision", args.precision, "--solver", args.solver, "--threads", str(args.threads),
           "--peer-solver", args.peer_solver]
    env = {**os.environ, "GLOG_minloglevel": "2"}
    if kind == "lidarcat":
        env.update(dict.fromkeys(("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"),
                                 str(args.blas_threads)))
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    for line in res.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return {"error": (res.stderr or res.stdout)[-400:]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photos", type=int, nargs="+", default=[100, 1000, 5000, 10000])
    ap.add_argument("--precision", default="all", choices=["all", "photos", "none"])
    ap.add_argument("--solver", default="auto", choices=["auto", "direct", "pcg"])
    ap.add_argument("--threads", type=int, default=2, help="Ceres threads")
    ap.add_argument("--blas-threads", type=int, default=2,
                    help="BLAS threads of lidarcat's big dense kernels (the rest runs on one)")
    ap.add_argument("--no-peer", action="store_true")
    ap.add_argument("--peer-solver", default="sparse_schur", choices=PEER_SOLVERS,
                    help="Ceres's linear solver (and preconditioner): the direct Schur solver, or its "
                         "iterative Schur solvers, whose cost per step grows linearly with the block")
    ap.add_argument("--pairs", type=int, default=0,
                    help="with two --photos sizes: K alternating lidarcat runs of each, every ratio and the median")
    ap.add_argument("--json", help="write the rows to this file")
    ap.add_argument("--plot", help="PNG of time against photos")
    ap.add_argument("--child", choices=["lidarcat", "ceres"], help=argparse.SUPPRESS)
    ap.add_argument("--init", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.blas_threads < 1 or args.threads < 1:
        ap.error("--threads and --blas-threads must be at least 1")
    if args.pairs and (args.pairs < 1 or len(args.photos) != 2):
        ap.error("--pairs K needs K >= 1 and exactly two --photos sizes")
    if args.child:
        _child(args)
        return

    from lidarcat.bundle.approx import approximations
    from lidarcat.synthetic.block import aerial_block

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.pairs:
            _pairs(args, tmp)
            return
        for n in args.photos:
            block = aerial_block(n)
            p = block.problem
            t0 = time.perf_counter()
            eo, pts = approximations(p)
            approx_s = time.perf_counter() - t0
            init = str(Path(tmp) / f"init{n}.npz")
            np.savez(init, eo=eo, pts=pts)
            load = os.getloadavg()[0]
            row = {"photos": p.n_photos, "observations": len(p.photo_index), "points": p.n_points,
                   "approx_s": approx_s, "load": load, "lidarcat": _run_child("lidarcat", n, init, args)}
            if not args.no_peer:
                row["ceres"] = _run_child("ceres", n, init, args)
            row["load_after"] = os.getloadavg()[0]
            rows.append(row)
            _print_row(row, header=len(rows) == 1)
    print(f"machine: 2 cores, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; lidarcat precision="
          f"{args.precision}, solver={args.solver}, BLAS threads for big fronts {args.blas_threads}; "
          f"Ceres {args.peer_solver.upper()}, {args.threads} threads")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1, sort_keys=True))
    if args.plot:
        _plot(rows, args.plot, args.peer_solver, args.threads)


def _pairs(args, tmp: str) -> None:
    """K alternating runs of the two sizes: each pair's times and ratio, then the median ratio."""
    from lidarcat.bundle.approx import approximations
    from lidarcat.synthetic.block import aerial_block

    inits = []
    for n in args.photos:
        eo, pts = approximations(aerial_block(n).problem)
        inits.append(str(Path(tmp) / f"init{n}.npz"))
        np.savez(inits[-1], eo=eo, pts=pts)
    small, large = args.photos
    print(f"{'pair':>4}{'load':>6} | {small:>7} photos s | {large:>7} photos s | ratio | factor+prec ratio | "
          f"rest ratio")
    ratios, rests = [], []
    for k in range(args.pairs):
        load = os.getloadavg()[0]
        a = _run_child("lidarcat", small, inits[0], args)
        b = _run_child("lidarcat", large, inits[1], args)
        if "error" in a or "error" in b:
            print(f"{k + 1:>4} failed: {(a.get('error') or b.get('error'))[-200:]}")
            continue
        ratios.append(b["seconds"] / a["seconds"])
        sa, sb = _superlinear_s(a), _superlinear_s(b)
        rests.append((b["seconds"] - sb) / (a["seconds"] - sa))
        print(f"{k + 1:>4}{load:>6.1f} | {a['seconds']:>16.2f} | {b['seconds']:>16.2f} | {ratios[-1]:>5.2f} | "
              f"{sb / sa:>17.2f} | {rests[-1]:>10.2f}", flush=True)
    if ratios:
        print(f"median ratio {np.median(ratios):.2f} over {len(ratios)} pairs (range {min(ratios):.2f}-"
              f"{max(ratios):.2f}); the phases that grow linearly alone: median {np.median(rests):.2f} "
              f"(range {min(rests):.2f}-{max(rests):.2f}); machine: 2 cores, "
              f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, precision={args.precision}, "
              f"BLAS threads for big fronts {args.blas_threads}")


def _superlinear_s(run: dict) -> float:
    """Seconds of the phases whose work grows faster than the block: the factorisations, the
    reuse steps' triangular solves and the precision (a factorisation and the selected inverse,
    with the points' linear terms: counted here, so "the rest" is the linear work alone)."""
    ph = run["phases"]
    return ph.get("solve_factor", 0.0) + ph.get("solve_reuse", 0.0) + ph.get("precision", 0.0)


def _print_row(row: dict, header: bool) -> None:
    if header:
        print(f"{'photos':>7}{'obs':>9}{'load':>6}{'approx s':>9} | {'lidarcat s':>10}{'it':>4}{'RSS MB':>8}"
              f"{'model':>7}{'assem':>7}{'factor':>7}{'reuse':>7}{'prec':>7} | {'ceres s':>8}{'it':>4}{'RSS MB':>8} | "
              f"{'ratio':>6}  cost lidarcat / ceres")
    lc, ce = row["lidarcat"], row.get("ceres", {})
    if "error" in lc:
        print(f"{row['photos']:>7} lidarcat failed: {lc['error']}")
        return
    ph = lc["phases"]
    tot = lc["seconds"]
    share = {k: 100 * ph.get(k, 0.0) / tot for k in ("model", "solve_assemble", "solve_factor", "solve_reuse",
                                                          "precision")}
    line = (f"{row['photos']:>7}{row['observations']:>9}{row['load']:>6.1f}{row['approx_s']:>9.1f} | "
            f"{tot:>10.2f}{lc['iterations']:>4}{lc['maxrss_mb']:>8.0f}"
            f"{share['model']:>6.0f}%{share['solve_assemble']:>6.0f}%{share['solve_factor']:>6.0f}%"
            f"{share['solve_reuse']:>6.0f}%"
            f"{share['precision']:>6.0f}% | ")
    if ce and "error" not in ce:
        line += (f"{ce['seconds']:>8.2f}{ce['iterations']:>4}{ce['maxrss_mb']:>8.0f} | "
                 f"{tot / ce['seconds']:>6.2f}  {lc['cost']:.6g} / {ce['cost']:.6g}")
    elif ce:
        line += f"ceres failed: {ce['error'][-200:]}"
    print(line, flush=True)


def _plot(rows: list[dict], path: str, peer: str, threads: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = [r["photos"] for r in rows]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(n, [r["lidarcat"].get("seconds", np.nan) for r in rows], "o-",
              label="lidarcat adjust (sd of every photo and point)")
    if any("ceres" in r for r in rows):
        ax.loglog(n, [r.get("ceres", {}).get("seconds", np.nan) for r in rows], "s--",
                  label=f"Ceres {peer.upper()}, {threads} threads (no covariance)")
    ax.set_xlabel("photos")
    ax.set_ylabel("seconds")
    ax.set_title(f"Bundle adjustment time, 2 cores, load {np.mean([r['load'] for r in rows]):.1f}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
