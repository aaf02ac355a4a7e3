"""The figures of the accuracy report, as PNG bytes (matplotlib, no display needed).

Block layout (thesis Figures 8, 16, 17), planimetric discrepancy vectors
(Figure 20), height discrepancies (Figure 21) and normal Q-Q plots (Figure 22);
:mod:`lidarcat.report.document` places them in the report.  Every report figure
(these and :mod:`lidarcat.report.quality_figures`) has its margins fixed in inches
(:func:`fixed_figure`) and is drawn once (:func:`png_bytes`).
"""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["layout_figure", "vector_figure", "height_figure", "qq_figure", "fixed_figure", "png_bytes", "wrap_text",
           "text_width_in", "text_height_in"]

_MAX_LABELS = 150  # point labels on the maps only up to this many points

_ROLE_STYLE = {  # role -> (marker, colour, label)
    "control": ("^", "#c0392b", "control"),
    "check": ("o", "#1f5fa8", "check"),
    "tie": ("x", "#555555", "tie / pass"),
}


_DPI = 110
_CHAR_EM = 0.62  # upper bound of a DejaVu Sans character's advance, in em (digits 0.64, lower case ~0.55)


def png_bytes(fig: Any) -> bytes:
    """The PNG of *fig* at its own dpi, drawn once.

    ``savefig(bbox_inches="tight")`` -- and ``savefig`` with any layout engine -- draws a figure
    once to measure it and once more to paint it; the report's figures have their margins fixed in
    inches instead (:func:`fixed_figure`), sized for the text they hold (docs/figures.md, "The report
    figures: one draw").
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return buf.getvalue()


def text_width_in(n_chars: int, size_pt: float) -> float:
    """Width in inches that *n_chars* characters of *size_pt* points take at most."""
    return n_chars * _CHAR_EM * size_pt / 72.0


def wrap_text(text: str, width_in: float, size_pt: float) -> str:
    """*text* broken into lines of at most *width_in* inches at *size_pt* points."""
    return textwrap.fill(text, max(12, int(width_in * 72.0 / (_CHAR_EM * size_pt))))


def text_height_in(text: str, size_pt: float) -> float:
    """Height in inches of the lines of *text* at *size_pt* points."""
    return (text.count("\n") + 1) * 1.25 * size_pt / 72.0


def fixed_figure(w: float, h: float, nrows: int = 1, ncols: int = 1, *, dpi: float = _DPI, left: float = 1.05,
                 right: float = 0.4, bottom: float = 0.6, top: float = 0.45, wspace: float = 0.0,
                 hspace: float = 0.0) -> tuple[Any, np.ndarray]:
    """A *w* x *h* inch figure of *nrows* x *ncols* axes (flat array), with fixed margins in inches.

    *left*, *right*, *bottom*, *top*: from the figure's edges to the axes; *wspace*, *hspace*:
    between neighbouring axes.  The defaults fit a map axes (7-digit tick labels, axis labels,
    a one-line title of 10 pt).  No layout engine: :func:`png_bytes` draws it once.
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=dpi)
    ax_w = max((w - left - right - (ncols - 1) * wspace) / ncols, 0.5)
    ax_h = max((h - bottom - top - (nrows - 1) * hspace) / nrows, 0.5)
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=wspace / ax_w, hspace=hspace / ax_h)
    return fig, fig.subplots(nrows, ncols, squeeze=False).ravel()


def _fig_png(fig: Any) -> bytes:
    """:func:`png_bytes` (the figures of this module call it by this name)."""
    return png_bytes(fig)


def _new_fig(w: float, h: float, n: int = 1, ncols: int = 1, **margins: float) -> tuple[Any, Any]:
    """:func:`fixed_figure` of *n* axes in *ncols* columns at the accuracy report's 110 dpi."""
    return fixed_figure(w, h, max(1, n // ncols), ncols, **margins)


def _label(ax: Any, text: str, xy: tuple[float, float], east: bool, dx: float, dy: float, **kw: Any) -> None:
    """Point label *dx*, *dy* points off *xy*: to its right, or to its left when *east* (a point in
    the east half of the map), so that labels stay inside the fixed margins."""
    ax.annotate(text, xy, xytext=(-dx if east else dx, dy), textcoords="offset points",
                ha="right" if east else "left", **kw)


def _east(e: np.ndarray) -> np.ndarray:
    """True for the points east of the middle of *e* (m)."""
    return e > (float(np.min(e)) + float(np.max(e))) / 2 if e.size else np.zeros(0, bool)


def _plain_axes(ax: Any) -> None:
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel("E (m)")
    ax.set_ylabel("N (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3, alpha=0.5)


def layout_figure(points: list[dict[str, Any]], fps: Mapping[str, np.ndarray],
                  centres: np.ndarray | None, title: str) -> bytes:
    """PNG of the block layout: photo footprints *fps* (``{photo: (4, 2) E, N}``), projection
    *centres* ((k, 2) E, N in m, or None) and *points* (``point``, ``E``, ``N``, ``role``) by role."""
    title = wrap_text(title, 8.5 - 1.05 - 0.4, 10)
    fig, (ax,) = _new_fig(8.5, 8.5, top=0.2 + text_height_in(title, 10))
    for pid, poly in fps.items():
        closed = np.vstack([poly, poly[:1]])
        ax.fill(closed[:, 0], closed[:, 1], alpha=0.06, color="#2c7a2c")
        ax.plot(closed[:, 0], closed[:, 1], lw=1.0, color="#2c7a2c")
        cx, cy = poly.mean(axis=0)
        ax.text(cx, cy, f"photo {pid}", color="#2c7a2c", fontsize=8, ha="center", va="center", alpha=0.8)
    if centres is not None and centres.size:
        ax.plot(centres[:, 0], centres[:, 1], "s-", color="#2c7a2c", ms=4, lw=0.6, label="projection centres")
    e_all = np.array([p["E"] for p in points], float)
    e_mid = (float(np.min(e_all)) + float(np.max(e_all))) / 2 if e_all.size else 0.0
    roles = sorted({p["role"] for p in points}, key=lambda r: (r not in _ROLE_STYLE, r))
    for role in roles:
        sel = [p for p in points if p["role"] == role]
        mk, col, lab = _ROLE_STYLE.get(role, ("D", "#8e44ad", role))
        ax.scatter([p["E"] for p in sel], [p["N"] for p in sel], marker=mk, c=col, s=36,
                   label=f"{lab} ({len(sel)})", zorder=3)
        for p in sel if len(points) <= _MAX_LABELS else ():
            _label(ax, p["point"], (p["E"], p["N"]), p["E"] > e_mid, 3, 3, fontsize=6.5, color=col)
    _plain_axes(ax)
    ax.legend(loc="best", fontsize=8, framealpha=0.8)
    ax.set_title(title, fontsize=10)
    return _fig_png(fig)


def _nice_length(x: float) -> float:
    if not x > 0:
        return 1.0
    e = 10 ** math.floor(math.log10(x))
    for m in (1, 2, 5, 10):
        if m * e >= x:
            return m * e
    return 10 * e


def vector_figure(a: Any) -> bytes:
    """PNG of the planimetric discrepancy vectors at the check points of assessment *a* (thesis Figure 20)."""
    e, n = a.reference[:, 0], a.reference[:, 1]
    d = a.d
    extent = max(float(np.ptp(e)), float(np.ptp(n)), 1.0)
    dmax = max(float(np.max(a.planimetric)), 1e-6)
    scale = 0.12 * extent / dmax  # arrow length on the map per metre of discrepancy
    title = wrap_text(f"Planimetric discrepancies dE, dN ({a.settings['sign'].replace('_', ' ')}); "
                  f"arrows x{scale:.0f}", 8.0 - 1.05 - 0.4, 10)
    fig, (ax,) = _new_fig(8.0, 7.5, top=0.2 + text_height_in(title, 10))
    q = ax.quiver(e, n, d[:, 0] * scale, d[:, 1] * scale, angles="xy", scale_units="xy", scale=1,
                  color="#1f5fa8", width=0.004)
    ax.scatter(e, n, s=10, c="#1f5fa8")
    east = _east(e)
    for k, p in enumerate(a.points if a.n <= _MAX_LABELS else ()):
        _label(ax, p, (e[k], n[k]), east[k], 3, -9, fontsize=7)
    key = _nice_length(dmax / 2)
    ax.quiverkey(q, 0.12, 0.04, key * scale, f"{key:g} m discrepancy", coordinates="axes", labelpos="E",
                 fontproperties={"size": 8})
    _plain_axes(ax)
    ax.margins(0.12)
    ax.set_title(title, fontsize=10)
    return _fig_png(fig)


def height_figure(a: Any) -> bytes:
    """PNG of the height discrepancies at the check points of assessment *a* (thesis Figure 21)."""
    e, n, dh = a.reference[:, 0], a.reference[:, 1], a.d[:, 2]
    extent = max(float(np.ptp(e)), float(np.ptp(n)), 1.0)
    dmax = max(float(np.max(np.abs(dh))), 1e-6)
    scale = 0.12 * extent / dmax
    labels = a.n <= _MAX_LABELS
    # below the bars: the point ids turned 90 degrees (7 pt), else the axis label
    bottom = 0.35 + (text_width_in(max((len(str(p)) for p in a.points), default=1), 7) if labels else 0.3)
    ax_w = (13.0 - 1.05 - 0.3 - 1.0) / 2
    title1 = wrap_text(f"Height discrepancies dh on the map (up red, down blue; arrows x{scale:.0f})", ax_w, 10)
    fig, (ax1, ax2) = _new_fig(13.0, 6.0, 2, 2, right=0.3, bottom=max(0.6, bottom), wspace=1.0,
                               top=0.2 + text_height_in(title1, 10))
    cols = np.where(dh >= 0, "#c0392b", "#1f5fa8")
    ax1.quiver(e, n, np.zeros_like(dh), dh * scale, angles="xy", scale_units="xy", scale=1, color=cols,
               width=0.005)
    ax1.scatter(e, n, s=10, c="k")
    east = _east(e)
    for k, p in enumerate(a.points if a.n <= _MAX_LABELS else ()):
        _label(ax1, p, (e[k], n[k]), east[k], 4, -3, fontsize=7)
    _plain_axes(ax1)
    ax1.set_title(title1, fontsize=10)
    idx = np.arange(len(dh))
    ax2.bar(idx, dh, color=cols)
    if labels:
        ax2.set_xticks(idx)
        ax2.set_xticklabels(a.points, rotation=90, fontsize=7)
    else:
        ax2.set_xlabel("check point (index)")
    ax2.axhline(0, color="k", lw=0.6)
    ax2.axhline(float(np.mean(dh)), color="#e67e22", lw=1, ls="--", label=f"mean {np.mean(dh):+.3f} m")
    if a.settings.get("scale") is not None and a.standards.get("pec"):
        rows = a.standards["pec"].evidence["classes"]
        cls = a.settings.get("pec_class", "A")
        row = next((r for r in rows if r["class"] == cls), None)
        if row and row.get("altimetric"):
            pec = row["altimetric"]["pec_m"]
            ax2.axhline(pec, color="#7f8c8d", lw=0.8, ls=":", label=f"PEC class {cls} +/-{pec:.2f} m")
            ax2.axhline(-pec, color="#7f8c8d", lw=0.8, ls=":")
    ax2.set_ylabel("dh (m)")
    ax2.legend(fontsize=8)
    ax2.grid(True, axis="y", lw=0.3)
    ax2.set_title("dh per check point", fontsize=10)
    return _fig_png(fig)


def qq_figure(a: Any) -> bytes:
    """PNG of the normal Q-Q plots of the discrepancies of assessment *a* with the Filliben r (thesis Figure 22)."""
    from scipy import stats

    from ..accuracy.statistics import plotting_positions

    comps = [("E", a.d[:, 0]), ("N", a.d[:, 1]), ("h", a.d[:, 2]), ("planimetric", a.planimetric)]
    kind = a.settings.get("plotting_position", "filliben")
    ax_w = (10.0 - 0.8 - 0.3 - 0.8) / 2
    titles = []
    for comp, x in comps:
        t = a.tests.get("filliben", {}).get(comp)
        txt = f"{comp}: r = {t.statistic:.4f}, r_crit = {t.critical:.3f} -> {t.verdict}" if t and t.applicable \
            else f"{comp}: {t.reason if t else 'no test'}"
        titles.append(wrap_text(txt, ax_w, 9))
    title_in = 0.15 + max(text_height_in(t, 9) for t in titles)
    fig, axes = _new_fig(10.0, 9.0, 4, 2, left=0.8, right=0.3, bottom=0.55, top=title_in, wspace=0.8,
                         hspace=0.55 + title_in)
    for ax, (comp, x), txt in zip(axes, comps, titles):
        n = x.size
        if n < 3:
            ax.text(0.5, 0.5, f"{comp}: not applicable ({n} points)", ha="center", transform=ax.transAxes)
            continue
        q = stats.norm.ppf(plotting_positions(n, kind))
        xs = np.sort(x)
        ax.scatter(q, xs, s=16, c="#1f5fa8", zorder=3)
        if np.ptp(xs) > 0:
            slope, icpt = np.polyfit(q, xs, 1)
            ax.plot(q, icpt + slope * q, color="#c0392b", lw=1)
        ax.set_title(txt, fontsize=9)
        ax.set_xlabel(f"normal quantile ({kind} positions)", fontsize=8)
        ax.set_ylabel(f"sorted d{comp if comp != 'planimetric' else 'P'} (m)", fontsize=8)
        ax.grid(True, lw=0.3)
    return _fig_png(fig)
