"""The report figures are drawn once, with fixed margins that hold all their text.

``savefig(bbox_inches="tight")`` drew every figure twice (a measuring pass, then the picture);
:mod:`lidarcat.report.figures` now fixes the margins in inches and draws once.  These tests check
both halves of that: one ``Figure.draw`` per figure, and nothing drawn outside the figure (the bbox
``bbox_inches="tight"`` would have cropped to lies inside the canvas), on the thesis check points
and on a block with long point ids and a long title.
"""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.figure import Figure

from conftest import DATA, THESIS_SURVEY
from lidarcat.accuracy.checkpoints import assess
from lidarcat.report import figures

REPORT_FIXTURE = DATA / "report"


@pytest.fixture()
def drawn(monkeypatch):
    """Every figure handed to ``_fig_png`` and the number of ``Figure.draw`` calls."""
    figs: list = []
    draws = [0]
    real_png, real_draw = figures._fig_png, Figure.draw

    def counting_draw(self, renderer):
        draws[0] += 1
        return real_draw(self, renderer)

    def keep(fig):
        png = real_png(fig)
        figs.append(fig)
        return png

    monkeypatch.setattr(Figure, "draw", counting_draw)
    monkeypatch.setattr(figures, "_fig_png", keep)
    return figs, draws


def _long_id_assessment():
    rng = np.random.default_rng(3)
    ids = [f"roof_plane_vertex_north_{k:04d}" for k in range(6)]
    ref = {p: (677_000.0 + 150 * k, 7_184_000.0 + 90 * (k % 3), 900.0 + k) for k, p in enumerate(ids)}
    adj = {p: tuple(np.add(v, rng.normal(0, 0.2, 3))) for p, v in ref.items()}
    return assess(adj, ref, scale=2000, contour_interval_m=2)


def _assert_inside(fig):
    renderer = fig.canvas.get_renderer()
    tight = fig.get_tightbbox(renderer)  # inches, what bbox_inches="tight" would crop to
    w, h = fig.get_size_inches()
    tol = 1.0 / fig.dpi  # a pixel
    assert tight.x0 >= -tol and tight.y0 >= -tol, (tight, w, h)
    assert tight.x1 <= w + tol and tight.y1 <= h + tol, (tight, w, h)


@pytest.mark.parametrize("case", ["thesis", "long ids"])
def test_each_figure_is_drawn_once_and_holds_its_text(drawn, case):
    figs, draws = drawn
    if case == "thesis":
        a = assess(REPORT_FIXTURE / "points.csv", THESIS_SURVEY / "ground_points.csv", scale=2000,
                   contour_interval_m=2)
        title = "thesis gps"
    else:
        a = _long_id_assessment()
        title = "A block layout title long enough to need two lines in the figure: " * 2
    pts = [{"point": p, "E": e, "N": n, "role": "check"} for p, (e, n) in zip(a.points, a.reference[:, :2])]
    pngs = [figures.vector_figure(a), figures.height_figure(a), figures.qq_figure(a),
            figures.layout_figure(pts, {}, None, title)]
    assert all(p[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs)
    assert len(figs) == 4 and draws[0] == 4  # one draw per figure
    for fig in figs:
        _assert_inside(fig)
