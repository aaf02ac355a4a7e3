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


def _quality_cases():
    rng = np.random.default_rng(5)
    xy = rng.uniform(-10, 10, (300, 2))
    en = np.column_stack([rng.uniform(677_000, 678_000, 12), rng.uniform(7_183_000, 7_184_500, 12)])
    cov = np.tile(np.diag([0.01, 0.004]), (12, 1, 1))
    grid = np.meshgrid(np.linspace(-10, 10, 6), np.linspace(-7, 7, 5))
    gxy = np.column_stack([g.ravel() for g in grid])
    r = np.linspace(0, 12, 30)
    photos = {f"DSC_{k:05d}_strip_north": int(v) for k, v in enumerate(rng.integers(50, 400, 15))}
    return {
        "residual_vectors": lambda q: q.residual_vectors_figure(xy, rng.normal(0, 0.002, (300, 2)), (20.0, 15.0),
                                                                0.004),
        "residual_histograms": lambda q: q.residual_histograms_figure(rng.normal(0, 0.4, (300, 2))),
        "ellipses": lambda q: q.ellipses_figure(en[:6], cov[:6], en, cov, [f"photo {k}" for k in range(6)]),
        "coverage": lambda q: q.coverage_figure(rng.integers(0, 9, (30, 40)), (677_000, 678_000, 7_183_000,
                                                                               7_183_750), en[:4]),
        "control_map": lambda q: q.control_map_figure({"control": (en[:6], rng.normal(0, 0.05, (6, 2)),
                                                                   rng.normal(0, 0.05, 6)),
                                                       "check": (en[6:], rng.normal(0, 0.05, (6, 2)),
                                                                 rng.normal(0, 0.05, 6))}),
        "distortion": lambda q: q.distortion_figure(gxy, 1e-3 * gxy, r, 1e-5 * r ** 3, (20.0, 15.0), 0.004,
                                                    "camera long-camera-identifier"),
        "density": lambda q: q.density_figure(rng.uniform(0, 12, (30, 40)), (677_000, 678_000, 7_183_000,
                                                                              7_183_750), 25.0),
        "thumbnails": lambda q: q.thumbnails_figure([("dtm.tif, the terrain model of the block", rng.normal(
            size=(40, 50)), "heights"), ("orthophoto A", rng.uniform(0, 255, (40, 50)), "photo"),
            ("hillshade", rng.normal(size=(40, 50)), "shade"), ("mosaic", rng.integers(0, 255, (40, 50, 3),
                                                                                          dtype=np.uint8), "rgb")]),
        "track_length": lambda q: q.track_length_figure(rng.integers(2, 7, 500), photos),
    }


@pytest.mark.parametrize("name", list(_quality_cases()))
def test_each_quality_figure_is_drawn_once_and_holds_its_text(monkeypatch, name):
    from lidarcat.report import quality_figures as q

    figs, draws = [], [0]
    real_png, real_draw = q._png, Figure.draw

    def counting_draw(self, renderer):
        draws[0] += 1
        return real_draw(self, renderer)

    def keep(fig):
        figs.append(fig)
        return real_png(fig)

    monkeypatch.setattr(Figure, "draw", counting_draw)
    monkeypatch.setattr(q, "_png", keep)
    png = _quality_cases()[name](q)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(figs) == 1 and draws[0] == 1
    _assert_inside(figs[0])
