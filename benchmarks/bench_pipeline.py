"""Wall time and peak memory of the whole pipeline (``lidarcat run``) and of the demo survey.

Run: ``python benchmarks/bench_pipeline.py [--photos 6 12 24]`` (prints a table;
BLAS pinned to 1 thread).  Each case runs in a fresh process so that the peak
resident memory (ru_maxrss) is its own.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

_CASE = r"""
import json, resource, sys, time
from lidarcat.synthetic.survey import write_synthetic_survey
from lidarcat.pipeline import run_pipeline
kind, arg, out = sys.argv[1], sys.argv[2], sys.argv[3]
t = time.perf_counter()
if kind == "demo":
    d = write_synthetic_survey(out, n_photos=int(arg), seed=1)
    extra = {"lidar_points": d.n_lidar_points, "photos": d.n_photos}
else:
    r = run_pipeline(None if arg == "thesis" else arg, out)
    extra = {"ok": r.ok, "stages": {s.name: s.status for s in r.stages},
             "stage_s": {s.name: round(s.seconds, 2) for s in r.stages}}
wall = time.perf_counter() - t
rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"wall_s": wall, "peak_mb": rss, **extra}))
"""


def _case(*args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _CASE, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    photos = [6, 12]
    if "--photos" in sys.argv:
        photos = [int(v) for v in sys.argv[sys.argv.index("--photos") + 1:]]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        t = Path(tmp)
        cold = _case("run", "thesis", str(t / "thesis"))
        rows.append(("thesis block: run (cold)", cold))
        rows.append(("thesis block: run again (reused)", _case("run", "thesis", str(t / "thesis"))))
        for n in photos:
            demo = _case("demo", str(n), str(t / f"demo{n}"))
            rows.append((f"demo synthetic --photos {n} ({demo['lidar_points'] / 1e6:.1f} M LiDAR pts)", demo))
            rows.append((f"run on demo {n} photos", _case("run", str(t / f"demo{n}"), str(t / f"out{n}"))))
    print(f"{'case':<48} {'wall s':>8} {'peak MB':>8}  stage times (s)")
    for name, r in rows:
        stages = ", ".join(f"{k} {v}" for k, v in r.get("stage_s", {}).items() if v)
        print(f"{name:<48} {r['wall_s']:>8.2f} {r['peak_mb']:>8.0f}  {stages}")


if __name__ == "__main__":
    main()
