"""The four figures of the accuracy report, drawn three ways (``report.figures``).

The thesis block's check points (tests/data/report/points.csv against data/thesis/ground_points.csv,
as ``lidarcat assess``) give the block layout, the planimetric vectors, the height discrepancies and
the Q-Q plots.  Each repeat draws all four with, in turn:

* ``tight`` -- the code before: matplotlib's default subplot margins, ``savefig(bbox_inches="tight")``
  (a measuring draw, then the picture);
* ``constrained`` -- ``layout="constrained"`` and ``savefig``: savefig draws twice for any layout
  engine too, and the engine itself measures every axes twice;
* ``fixed`` -- now: margins fixed in inches, one draw (``FigureCanvasAgg.print_png``).

CPU seconds of this process (``time.process_time``: less sensitive to a shared machine's load than the
wall clock, which is printed too) and the number of ``Figure.draw`` calls; the load is printed.

Run::

    PYTHONPATH=src python benchmarks/bench_report_figures.py [--repeats 5]
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import time
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lidarcat.accuracy.checkpoints import assess
from lidarcat.report import figures

ROOT = Path(__file__).resolve().parents[1]
FIXED = (figures._new_fig, figures._fig_png)
DRAWS = [0]
_draw = Figure.draw


def _counting_draw(self, renderer):
    DRAWS[0] += 1
    return _draw(self, renderer)


def _variant(mode: str):
    if mode == "fixed":
        return FIXED

    def new_fig(w, h, n=1, ncols=1, **_margins):
        fig = Figure(figsize=(w, h), dpi=110, layout="constrained" if mode == "constrained" else None)
        return fig, fig.subplots(max(1, n // ncols), ncols, squeeze=False).ravel()

    def png(fig):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight" if mode == "tight" else None)
        return buf.getvalue()

    return new_fig, png


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    Figure.draw = _counting_draw
    asm = assess(ROOT / "tests" / "data" / "report" / "points.csv", ROOT / "data" / "thesis" / "ground_points.csv",
                 scale=2000, contour_interval_m=2.0)
    pts = [{"point": p, "E": e, "N": n, "role": "check"} for p, (e, n) in zip(asm.points, asm.reference[:, :2])]

    def draw_all() -> None:
        figures.vector_figure(asm), figures.height_figure(asm), figures.qq_figure(asm)
        figures.layout_figure(pts, {}, None, "thesis gps")

    modes = ("tight", "constrained", "fixed")
    cpu: dict[str, list[float]] = {m: [] for m in modes}
    wall: dict[str, list[float]] = {m: [] for m in modes}
    draws: dict[str, int] = {}
    figures._new_fig, figures._fig_png = _variant("fixed")
    draw_all()   # warm-up: imports, font cache
    print(f"4 report figures (thesis, 13 check points), cpu_count {os.cpu_count()}, "
          f"load {os.getloadavg()[0]:.2f} at the start")
    for _ in range(a.repeats):
        for m in modes:   # alternated
            figures._new_fig, figures._fig_png = _variant(m)
            DRAWS[0] = 0
            c0, w0 = time.process_time(), time.perf_counter()
            draw_all()
            cpu[m].append(time.process_time() - c0)
            wall[m].append(time.perf_counter() - w0)
            draws[m] = DRAWS[0]
    figures._new_fig, figures._fig_png = FIXED
    print(f"load {os.getloadavg()[0]:.2f} at the end, {a.repeats} alternated repeats")
    print("| figures drawn with | Figure.draw calls | CPU s (median) | CPU s (each) | wall s (median) |")
    print("|---|---:|---:|---|---:|")
    for m in modes:
        print(f"| {m} | {draws[m]} | {statistics.median(cpu[m]):.2f} | {' '.join(f'{x:.2f}' for x in cpu[m])} | "
              f"{statistics.median(wall[m]):.2f} |")


if __name__ == "__main__":
    main()
