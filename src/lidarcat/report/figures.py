"""The figures of the accuracy report, as PNG bytes (matplotlib, no display needed).

Block layout (thesis Figures 8, 16, 17), planimetric discrepancy vectors
(Figure 20), height discrepancies (Figure 21) and normal Q-Q plots (Figure 22);
:mod:`lidarcat.report.document` places them in the report.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

__all__ = ["layout_figure", "vector_figure", "height_figure", "qq_figure"]

_MAX_LABELS = 150  # point labels on the maps only up to this many points

_ROLE_STYLE = {  # role -> (marker, colour, label)
    "control": ("^", "#c0392b", "control"),
    "check": ("o", "#1f5fa8", "check"),
    "tie": ("x", "#555555", "tie / pass"),
}


def _fig_png(fig: Any) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    return buf.getvalue()


def _new_fig(w: float, h: float, n: int = 1, ncols: int = 1) -> tuple[Any, Any]:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h))
    axes = fig.subplots(max(1, n // ncols), ncols, squeeze=False)
    return fig, axes.ravel()


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
    fig, (ax,) = _new_fig(8.5, 8.5)
    for pid, poly in fps.items():
        closed = np.vstack([poly, poly[:1]])
        ax.fill(closed[:, 0], closed[:, 1], alpha=0.06, color="#2c7a2c")
        ax.plot(closed[:, 0], closed[:, 1], lw=1.0, color="#2c7a2c")
        cx, cy = poly.mean(axis=0)
        ax.text(cx, cy, f"photo {pid}", color="#2c7a2c", fontsize=8, ha="center", va="center", alpha=0.8)
    if centres is not None and centres.size:
        ax.plot(centres[:, 0], centres[:, 1], "s-", color="#2c7a2c", ms=4, lw=0.6, label="projection centres")
    roles = sorted({p["role"] for p in points}, key=lambda r: (r not in _ROLE_STYLE, r))
    for role in roles:
        sel = [p for p in points if p["role"] == role]
        mk, col, lab = _ROLE_STYLE.get(role, ("D", "#8e44ad", role))
        ax.scatter([p["E"] for p in sel], [p["N"] for p in sel], marker=mk, c=col, s=36,
                   label=f"{lab} ({len(sel)})", zorder=3)
        for p in sel if len(points) <= _MAX_LABELS else ():
            ax.annotate(p["point"], (p["E"], p["N"]), xytext=(3, 3), textcoords="offset points", fontsize=6.5,
                        color=col)
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
    fig, (ax,) = _new_fig(8.0, 7.5)
    e, n = a.reference[:, 0], a.reference[:, 1]
    d = a.d
    extent = max(float(np.ptp(e)), float(np.ptp(n)), 1.0)
    dmax = max(float(np.max(a.planimetric)), 1e-6)
    scale = 0.12 * extent / dmax  # arrow length on the map per metre of discrepancy
    q = ax.quiver(e, n, d[:, 0] * scale, d[:, 1] * scale, angles="xy", scale_units="xy", scale=1,
                  color="#1f5fa8", width=0.004)
    ax.scatter(e, n, s=10, c="#1f5fa8")
    for k, p in enumerate(a.points if a.n <= _MAX_LABELS else ()):
        ax.annotate(p, (e[k], n[k]), xytext=(3, -9), textcoords="offset points", fontsize=7)
    key = _nice_length(dmax / 2)
    ax.quiverkey(q, 0.12, 0.04, key * scale, f"{key:g} m discrepancy", coordinates="axes", labelpos="E",
                 fontproperties={"size": 8})
    _plain_axes(ax)
    ax.margins(0.12)
    ax.set_title(f"Planimetric discrepancies dE, dN ({a.settings['sign'].replace('_', ' ')}); "
                 f"arrows x{scale:.0f}", fontsize=10)
    return _fig_png(fig)


def height_figure(a: Any) -> bytes:
    """PNG of the height discrepancies at the check points of assessment *a* (thesis Figure 21)."""
    fig, (ax1, ax2) = _new_fig(13.0, 6.0, 2, 2)
    e, n, dh = a.reference[:, 0], a.reference[:, 1], a.d[:, 2]
    extent = max(float(np.ptp(e)), float(np.ptp(n)), 1.0)
    dmax = max(float(np.max(np.abs(dh))), 1e-6)
    scale = 0.12 * extent / dmax
    cols = np.where(dh >= 0, "#c0392b", "#1f5fa8")
    ax1.quiver(e, n, np.zeros_like(dh), dh * scale, angles="xy", scale_units="xy", scale=1, color=cols,
               width=0.005)
    ax1.scatter(e, n, s=10, c="k")
    for k, p in enumerate(a.points if a.n <= _MAX_LABELS else ()):
        ax1.annotate(p, (e[k], n[k]), xytext=(4, -3), textcoords="offset points", fontsize=7)
    _plain_axes(ax1)
    ax1.set_title(f"Height discrepancies dh on the map (up red, down blue; arrows x{scale:.0f})", fontsize=10)
    idx = np.arange(len(dh))
    ax2.bar(idx, dh, color=cols)
    if a.n <= _MAX_LABELS:
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
    fig, axes = _new_fig(10.0, 9.0, 4, 2)
    kind = a.settings.get("plotting_position", "filliben")
    for ax, (comp, x) in zip(axes, comps):
        n = x.size
        t = a.tests.get("filliben", {}).get(comp)
        if n < 3:
            ax.text(0.5, 0.5, f"{comp}: not applicable ({n} points)", ha="center", transform=ax.transAxes)
            continue
        q = stats.norm.ppf(plotting_positions(n, kind))
        xs = np.sort(x)
        ax.scatter(q, xs, s=16, c="#1f5fa8", zorder=3)
        if np.ptp(xs) > 0:
            slope, icpt = np.polyfit(q, xs, 1)
            ax.plot(q, icpt + slope * q, color="#c0392b", lw=1)
        txt = f"{comp}: r = {t.statistic:.4f}, r_crit = {t.critical:.3f} -> {t.verdict}" if t and t.applicable \
            else f"{comp}: {t.reason if t else 'no test'}"
        ax.set_title(txt, fontsize=9)
        ax.set_xlabel(f"normal quantile ({kind} positions)", fontsize=8)
        ax.set_ylabel(f"sorted d{comp if comp != 'planimetric' else 'P'} (m)", fontsize=8)
        ax.grid(True, lw=0.3)
    return _fig_png(fig)
