"""Bundle Adjustment in the Large: lidarcat's engine on a BAL file, and Ceres in the same run.

Run from the repository root::

    python -m benchmarks.bal benchmarks/data/problem-49-7776-pre.txt [--json] [--no-peer]

Prints ``final_cost`` (0.5 sum r^2, px^2), ``iterations`` (steps, accepted and
rejected, as Ceres counts them) and ``seconds`` (the solve, after reading) of
:func:`lidarcat.bundle.bal.solve_bal`; then the same for Ceres (SPARSE_SCHUR,
2 threads) through pycolmap (``bench`` extra) unless ``--no-peer``.  With
``--json``: one object with those keys, the peer under ``"ceres"``.  BLAS is
pinned to one thread (the supernodal factor's fronts are small).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("path", help="BAL problem file (text)")
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--no-peer", action="store_true", help="skip the Ceres peer")
    ap.add_argument("--threads", type=int, default=2, help="Ceres threads (default 2 = this machine's cores)")
    args = ap.parse_args(argv)

    from lidarcat.bundle.bal import read_bal, solve_bal

    problem = read_bal(args.path)
    r = solve_bal(problem)
    out = {"final_cost": r.final_cost, "iterations": r.iterations, "seconds": r.seconds,
           "initial_cost": r.initial_cost, "status": r.status, "load": os.getloadavg()[0],
           "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    if not args.no_peer:
        try:
            from benchmarks._ceres_peer import solve_bal_with_ceres
        except ImportError:  # pragma: no cover
            from _ceres_peer import solve_bal_with_ceres
        try:
            c = solve_bal_with_ceres(problem, threads=args.threads)
        except ImportError as ex:
            out["ceres"] = {"error": f"pyceres/pycolmap not installed ({ex}); pip install -e '.[bench]'"}
        else:
            out["ceres"] = {k: c[k] for k in ("final_cost", "initial_cost", "iterations", "seconds")}
    if args.json:
        print(json.dumps(out, sort_keys=True))
    else:
        print(f"{'solver':<22}{'final_cost':>14}{'iterations':>12}{'seconds':>10}")
        print(f"{'lidarcat':<22}{r.final_cost:>14.1f}{r.iterations:>12d}{r.seconds:>10.2f}")
        c = out.get("ceres")
        if c and "error" not in c:
            print(f"{'ceres (pycolmap)':<22}{c['final_cost']:>14.1f}{c['iterations']:>12d}{c['seconds']:>10.2f}")
        elif c:
            print(c["error"])
        print(f"load average {out['load']:.1f} (2 cores), {out['date']}")
    return out


if __name__ == "__main__":
    main()
