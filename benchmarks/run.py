"""Run every ``benchmarks/bench_*.py`` and print their tables.

Usage::

    python benchmarks/run.py                 # all benchmarks
    python benchmarks/run.py bundle lidar    # only bench_bundle.py and bench_lidar.py
    python benchmarks/run.py --list          # names only

Each benchmark runs in its own process (BLAS pinned to one thread, so numbers
are comparable across machines with different core counts) and prints its own
table; a summary of wall times and exit codes follows.  The exit code is
non-zero when a benchmark failed.  Benchmarks measure speed and memory: they
are never assertions in the test suite.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def discover(names: list[str] | None = None) -> list[Path]:
    """The benchmark scripts, optionally only those whose name contains one of *names*."""
    scripts = sorted(HERE.glob("bench_*.py"))
    if names:
        scripts = [p for p in scripts if any(n in p.stem for n in names)]
    return scripts


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if "-h" in args or "--help" in args:
        print(__doc__)
        return 0
    scripts = discover([a for a in args if not a.startswith("-")])
    if "--list" in args:
        print("\n".join(p.stem.removeprefix("bench_") for p in scripts))
        return 0
    if not scripts:
        print("no benchmark matches", " ".join(args), file=sys.stderr)
        return 2
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    rows = []
    for script in scripts:
        name = script.stem.removeprefix("bench_")
        print(f"\n=== {name} ({script.name}) ===", flush=True)
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, str(script)], env=env, cwd=HERE.parent)
        rows.append((name, proc.returncode, time.perf_counter() - t0))
    print("\n=== summary ===")
    print(f"{'benchmark':<20} {'exit':>4} {'wall s':>9}")
    for name, code, sec in rows:
        print(f"{name:<20} {code:>4} {sec:>9.1f}")
    return 0 if all(code == 0 for _, code, _ in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
