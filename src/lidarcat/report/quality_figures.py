"""The figures of the quality report (:mod:`lidarcat.report.quality`), as PNG bytes (matplotlib, no display).

Each function takes arrays (no files) and returns the PNG of one figure:

* :func:`residual_vectors_figure` -- image residuals by image position: the
  frame cut into cells, the mean residual vector of each cell (Pix4D's
  "2D keypoint residuals"), exaggerated by a stated factor;
* :func:`residual_histograms_figure` -- histograms of the x and y image
  residuals with the normal curve of their sd;
* :func:`ellipses_figure` -- 1-sigma standard ellipses: of a 2 x 2 plan
  covariance ``C`` the semi-axes are the square roots of its eigenvalues along
  its eigenvectors (projection centres from the full orientation covariance,
  points from their E, N sds), exaggerated by a stated factor;
* :func:`coverage_figure` -- photos per ground cell (footprints counted on a grid);
* :func:`control_map_figure` -- control and check points with their residual
  vectors (control: adjusted minus observed; check: reference minus adjusted);
* :func:`distortion_figure` -- the camera's distortion: vectors over the frame
  and the radial curve against the radius;
* :func:`density_figure` -- LiDAR points per m2 on a grid;
* :func:`thumbnails_figure` -- small images of products and orthophotos;
* :func:`track_length_figure` -- tie points by number of photos that see them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from .figures import fixed_figure, png_bytes, text_height_in, text_width_in, wrap_text

__all__ = ["residual_vectors_figure", "residual_histograms_figure", "ellipses_figure", "coverage_figure",
           "control_map_figure", "distortion_figure", "density_figure", "thumbnails_figure",
           "track_length_figure", "ellipse_axes"]


_DPI = 90


def _png(fig: Any) -> bytes:
    """The PNG of *fig*, drawn once (:func:`lidarcat.report.figures.png_bytes`)."""
    return png_bytes(fig)


def _fig(w: float, h: float, ncols: int = 1, nrows: int = 1, **margins: float) -> tuple[Any, np.ndarray]:
    """A figure of *nrows* x *ncols* axes at 90 dpi with fixed *margins* in inches
    (:func:`lidarcat.report.figures.fixed_figure`)."""
    return fixed_figure(w, h, nrows, ncols, dpi=_DPI, **margins)


def _map_axes(ax: Any) -> None:
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.set_xlabel("E (m)")
    ax.set_ylabel("N (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, lw=0.3, alpha=0.5)


def residual_vectors_figure(xy_mm: np.ndarray, v_mm: np.ndarray, frame_mm: tuple[float, float],
                            pixel_mm: float, cells: int = 8) -> bytes:
    """Mean image residual per cell of the frame.

    Parameters
    ----------
    xy_mm : (n, 2) array
        Image positions of the observations (x right, y up, origin at the principal point), mm.
    v_mm : (n, 2) array
        Their residuals, mm.
    frame_mm : (width, height)
    pixel_mm : float
        Pixel size, mm (the legend is in pixels).
    cells : int
        Cells along the longer side.
    """
    w, h = frame_mm
    nx = cells
    ny = max(1, round(cells * h / w))
    ix = np.clip(((xy_mm[:, 0] + w / 2) / w * nx).astype(int), 0, nx - 1)
    iy = np.clip(((xy_mm[:, 1] + h / 2) / h * ny).astype(int), 0, ny - 1)
    k = iy * nx + ix
    n = np.bincount(k, minlength=nx * ny)
    mx = np.bincount(k, v_mm[:, 0], nx * ny) / np.maximum(n, 1)
    my = np.bincount(k, v_mm[:, 1], nx * ny) / np.maximum(n, 1)
    cx = (np.arange(nx) + 0.5) / nx * w - w / 2
    cy = (np.arange(ny) + 0.5) / ny * h - h / 2
    gx, gy = np.meshgrid(cx, cy)
    ok = n.reshape(ny, nx) > 0
    big = max(float(np.nanmax(np.hypot(mx, my))), 1e-12)
    scale = 0.6 * (w / nx) / big          # the longest mean vector spans 60 % of a cell
    title = wrap_text(f"mean residual per cell ({nx} x {ny}); longest {big / pixel_mm:.2f} px, drawn x{scale:.0f}",
                      7.5 - 1.1, 9)
    fig, (ax,) = _fig(7.5, 7.5 * h / w + 0.8, left=0.8, right=0.3, bottom=0.55, top=0.15 + text_height_in(title, 9))
    ax.add_patch(_rect(-w / 2, -h / 2, w, h))
    ax.scatter(xy_mm[:, 0], xy_mm[:, 1], s=2, color="#bbbbbb", zorder=1)
    ax.quiver(gx[ok], gy[ok], mx.reshape(ny, nx)[ok], my.reshape(ny, nx)[ok], angles="xy", scale_units="xy",
              scale=1 / scale, color="#c0392b", width=0.004, zorder=3)
    ax.set_xlim(-w / 2, w / 2)
    ax.set_ylim(-h / 2, h / 2)
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=9)
    return _png(fig)


def _rect(x: float, y: float, w: float, h: float) -> Any:
    from matplotlib.patches import Rectangle

    return Rectangle((x, y), w, h, fill=False, lw=1.0, color="#333333")


def residual_histograms_figure(v_px: np.ndarray) -> bytes:
    """Histograms of the x and y image residuals (px) with the normal density of their sd."""
    fig, axes = _fig(9, 3.2, ncols=2, left=0.75, right=0.2, bottom=0.55, top=0.35, wspace=0.6)
    for ax, comp, name in zip(axes, v_px.T, ("x", "y")):
        sd = float(np.std(comp)) or 1.0
        lim = max(4 * sd, float(np.max(np.abs(comp))))
        ax.hist(comp, bins=min(60, max(10, len(comp) // 10)), range=(-lim, lim), density=True,
                color="#7aa6d6", edgecolor="white")
        t = np.linspace(-lim, lim, 200)
        ax.plot(t, np.exp(-0.5 * (t / sd) ** 2) / (sd * np.sqrt(2 * np.pi)), color="#1f5fa8")
        ax.set_xlabel(f"residual {name} (px)")
        ax.set_title(f"{name}: n {len(comp)}, RMS {np.sqrt(np.mean(comp ** 2)):.3f} px", fontsize=9)
    axes[0].set_ylabel("density")
    return _png(fig)


def ellipse_axes(cov2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (n, 2) (major, minor) and azimuth of the major axis from E (n,), rad, of 2 x 2 covariances.

    >>> a, t = ellipse_axes(np.array([[[4.0, 0.0], [0.0, 1.0]]]))
    >>> a.tolist(), float(t[0])
    ([[2.0, 1.0]], 0.0)
    """
    c = np.asarray(cov2, dtype=np.float64).reshape(-1, 2, 2)
    lam, vec = np.linalg.eigh(0.5 * (c + np.swapaxes(c, 1, 2)))
    axes = np.sqrt(np.clip(lam[:, ::-1], 0, None))
    theta = np.arctan2(vec[:, 1, 1], vec[:, 0, 1])
    return axes, np.mod(theta, np.pi)


def ellipses_figure(centres_en: np.ndarray, centre_cov: np.ndarray, points_en: np.ndarray,
                    point_cov: np.ndarray, labels: Sequence[str]) -> bytes:
    """1-sigma plan ellipses of the projection centres (left) and of the object points (right)."""
    from matplotlib.collections import EllipseCollection

    ax_w = (11 - 1.05 - 0.4 - 1.1) / 2
    fig, axes = _fig(11, 5.2, ncols=2, wspace=1.1, top=0.55)   # room for a title of two lines
    for ax, xy, cov, what, colour in ((axes[0], centres_en, centre_cov, "projection centres", "#2c7a2c"),
                                      (axes[1], points_en, point_cov, "object points", "#1f5fa8")):
        if len(xy) == 0:
            ax.set_axis_off()
            continue
        ab, th = ellipse_axes(cov)
        span = float(max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1]), 1.0))
        big = max(float(np.nanmax(ab[:, 0])), 1e-9)
        k = 10 ** np.floor(np.log10(0.04 * span / big))    # a power of ten: the largest ellipse ~4 % of the map
        ax.add_collection(EllipseCollection(2 * k * ab[:, 0], 2 * k * ab[:, 1], np.degrees(th), units="xy",
                                            offsets=xy, offset_transform=ax.transData, facecolors="none",
                                            edgecolors=colour, linewidths=1.2))
        ax.plot(xy[:, 0], xy[:, 1], "+", color="#555555", ms=4)
        if what == "projection centres":
            for (e, n), lab in zip(xy, labels):
                ax.annotate(str(lab), (e, n), fontsize=7, xytext=(3, 3), textcoords="offset points")
        _map_axes(ax)
        ax.set_title(wrap_text(f"{what}: 1-sigma ellipses x{k:g}; largest semi-axis {100 * big:.1f} cm", ax_w, 9),
                     fontsize=9)
    return _png(fig)


def coverage_figure(count: np.ndarray, extent: tuple[float, float, float, float],
                    centres_en: np.ndarray | None = None) -> bytes:
    """Photos per ground cell: *count* (rows, cols) over *extent* (xmin, xmax, ymin, ymax), north up."""
    from matplotlib.colors import BoundaryNorm, ListedColormap

    fig, (ax,) = _fig(7.5, 6.5, right=0.2, top=0.2)   # the colour bar takes its room from the axes
    top = int(max(count.max(), 1))
    colours = ["#ffffff", "#d7301f", "#fc8d59", "#fdcc8a", "#c2e699", "#78c679", "#31a354", "#006837"]
    levels = list(range(0, min(top, 7) + 1)) + [max(top, 7) + 1]
    cmap = ListedColormap(colours[:len(levels) - 1])
    im = ax.imshow(count, extent=extent, origin="upper", cmap=cmap, norm=BoundaryNorm(levels, cmap.N),
                   interpolation="nearest")
    cb = fig.colorbar(im, ax=ax, shrink=0.8, ticks=[v + 0.5 for v in levels[:-1]])
    cb.ax.set_yticklabels([str(v) if v < 7 else f">={v}" for v in levels[:-1]])
    cb.set_label("photos per cell")
    if centres_en is not None and len(centres_en):
        ax.plot(centres_en[:, 0], centres_en[:, 1], "k^", ms=4)
    _map_axes(ax)
    return _png(fig)


def control_map_figure(points: Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]]) -> bytes:
    """Control and check points with their plan residual vectors and height residuals.

    *points* maps a role (``control``, ``check``) to ``(en (n, 2) m, d_en (n, 2) m, d_h (n,) m)``.
    """
    k_title = "plan residual vectors x{k:g} (longest {big:.1f} cm); labels: height residual (cm)"
    style = {"control": ("^", "#c0392b"), "check": ("o", "#1f5fa8")}
    all_xy = np.vstack([v[0] for v in points.values() if len(v[0])] or [np.zeros((1, 2))])
    span = float(max(np.ptp(all_xy[:, 0]), np.ptp(all_xy[:, 1]), 1.0))
    d_all = np.concatenate([np.hypot(*v[1].T) for v in points.values() if len(v[0])] or [np.zeros(1)])
    big = max(float(np.nanmax(d_all)), 1e-9)
    k = _nice(0.08 * span / big)
    title = wrap_text(k_title.format(k=k, big=100 * big), 8 - 1.45, 9)
    fig, (ax,) = _fig(8, 7, top=0.15 + text_height_in(title, 9))
    for role, (xy, d, dh) in points.items():
        if not len(xy):
            continue
        m, c = style.get(role, ("s", "#555555"))
        ax.scatter(xy[:, 0], xy[:, 1], marker=m, color=c, s=30, label=f"{role} ({len(xy)})", zorder=3)
        ax.quiver(xy[:, 0], xy[:, 1], d[:, 0], d[:, 1], angles="xy", scale_units="xy", scale=1 / k,
                  color="#222222", width=0.005, zorder=4)
        if len(xy) <= 60:
            for (e, n), h in zip(xy, dh):
                if np.isfinite(h):
                    ax.annotate(f"{100 * h:+.0f}", (e, n), fontsize=7, xytext=(4, -9), textcoords="offset points",
                                color=c)
    _map_axes(ax)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(title, fontsize=9)
    return _png(fig)


def _nice(x: float) -> float:
    """The largest of 1, 2, 5 times a power of ten not above *x* (> 0).

    >>> _nice(367.0), _nice(0.9), _nice(25.0)
    (200.0, 0.5, 20.0)
    """
    p = 10 ** np.floor(np.log10(x))
    return float(max(m * p for m in (1, 2, 5) if m * p <= x))


def distortion_figure(xy_mm: np.ndarray, d_mm: np.ndarray, r_mm: np.ndarray, dr_mm: np.ndarray,
                      frame_mm: tuple[float, float], pixel_mm: float, title: str) -> bytes:
    """The camera's distortion: vectors *d_mm* at *xy_mm* over the frame, and the radial curve *dr_mm*(*r_mm*)."""
    w, h = frame_mm
    mag = np.hypot(d_mm[:, 0], d_mm[:, 1])
    big = max(float(mag.max()), 1e-12)
    spacing = float(np.min(np.diff(np.unique(xy_mm[:, 0])))) if len(np.unique(xy_mm[:, 0])) > 1 else w / 10
    k = 0.9 * spacing / big
    ax_w = (11 - 0.8 - 0.3 - 1.0) / 2
    titles = [wrap_text(f"{title}: distortion, largest {big / pixel_mm:.1f} px, drawn x{k:.0f}", ax_w, 9),
              wrap_text("radial distortion along the radius (to the frame corner)", ax_w, 9)]
    fig, axes = _fig(11, 4.6, ncols=2, left=0.8, right=0.3, bottom=0.55, wspace=1.0,
                     top=0.15 + max(text_height_in(t, 9) for t in titles))
    ax = axes[0]
    ax.add_patch(_rect(-w / 2, -h / 2, w, h))
    ax.quiver(xy_mm[:, 0], xy_mm[:, 1], d_mm[:, 0], d_mm[:, 1], mag / pixel_mm, angles="xy", scale_units="xy",
              scale=1 / k, cmap="viridis", width=0.004)
    ax.set_aspect("equal")
    ax.set_xlim(-w / 2 * 1.05, w / 2 * 1.05)
    ax.set_ylim(-h / 2 * 1.05, h / 2 * 1.05)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(titles[0], fontsize=9)
    ax = axes[1]
    ax.plot(r_mm, dr_mm / pixel_mm, color="#1f5fa8")
    ax.axhline(0, color="#888888", lw=0.5)
    ax.set_xlabel("radius (mm)")
    ax.set_ylabel("radial distortion (px)")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.set_title(titles[1], fontsize=9)
    return _png(fig)


def density_figure(density: np.ndarray, extent: tuple[float, float, float, float], cell_m: float) -> bytes:
    """LiDAR points per m2 on cells of *cell_m* (rows, cols), north up, over *extent* (xmin, xmax, ymin, ymax)."""
    fig, (ax,) = _fig(7.5, 6.5, right=0.2, top=0.35)   # the colour bar takes its room from the axes
    shown = np.where(density > 0, density, np.nan)
    vmax = float(np.nanpercentile(shown, 99)) if np.isfinite(shown).any() else 1.0
    im = ax.imshow(shown, extent=extent, origin="upper", cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
    fig.colorbar(im, ax=ax, shrink=0.8).set_label("points per m2")
    _map_axes(ax)
    ax.set_title(f"LiDAR point density, cells of {cell_m:g} m", fontsize=9)
    return _png(fig)


def thumbnails_figure(images: Sequence[tuple[str, np.ndarray, str]], ncols: int = 3) -> bytes:
    """Thumbnails: ``(title, array, kind)`` with kind ``heights`` (terrain colours), ``shade``
    (hillshade, grey, stretched), ``photo`` (grey photo values, 0-255) or ``rgb`` ((rows, cols, 3) uint8)."""
    n = len(images)
    ncols = min(ncols, n)
    nrows = -(-n // ncols)
    titles = [wrap_text(t, 3.4, 8) for t, _, _ in images]
    head = 0.1 + max(text_height_in(t, 8) for t in titles)
    fig, axes = _fig(3.6 * ncols, 3.4 * nrows, ncols=ncols, nrows=nrows, left=0.1, right=0.1, bottom=0.1, top=head,
                     wspace=0.2, hspace=head + 0.1)
    for ax in axes:
        ax.set_axis_off()
    for ax, (_, a, kind), title in zip(axes, images, titles):
        if kind == "rgb" and a.ndim == 3:
            ax.imshow(a, interpolation="nearest")
        elif kind == "photo":   # grey photo values as they are (a contrast stretch turns texture into noise)
            top = 255.0 if np.nanmax(a) <= 255 else float(np.nanmax(a))
            ax.imshow(a, cmap="gray", vmin=0, vmax=top, interpolation="antialiased")
        elif kind == "heights":
            lo, hi = np.nanpercentile(a, [2, 98]) if np.isfinite(a).any() else (0, 1)
            ax.imshow(a, cmap="terrain", vmin=lo, vmax=hi, interpolation="nearest")
        else:
            lo, hi = np.nanpercentile(a, [1, 99]) if np.isfinite(a).any() else (0, 1)
            ax.imshow(a, cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")
        ax.set_title(title, fontsize=8)
    return _png(fig)


def track_length_figure(track_lengths: np.ndarray, per_photo: Mapping[str, int]) -> bytes:
    """Tie points by track length (photos that see them) and tie points per photo."""
    ids = list(per_photo)
    turned = len(ids) > 12
    below = text_width_in(max((len(str(i)) for i in ids), default=1), 7) if turned else 0.15
    fig, axes = _fig(10, 3.4, ncols=2, left=0.8, right=0.2, bottom=0.55 + below, top=0.35, wspace=0.9)
    lengths = np.asarray(track_lengths, dtype=int)
    top = int(lengths.max()) if len(lengths) else 2
    axes[0].bar(np.arange(2, top + 1), np.bincount(lengths, minlength=top + 1)[2:], color="#7aa6d6")
    axes[0].set_xlabel("photos that see the point (track length)")
    axes[0].set_ylabel("tie points")
    axes[0].set_title(f"{len(lengths)} tie points, mean track {lengths.mean() if len(lengths) else 0:.2f}",
                      fontsize=9)
    axes[1].bar(range(len(ids)), [per_photo[i] for i in ids], color="#2c7a2c")
    axes[1].set_xticks(range(len(ids)))
    axes[1].set_xticklabels(ids, rotation=90 if turned else 0, fontsize=7)
    axes[1].set_xlabel("photo")
    axes[1].set_ylabel("tie points measured")
    return _png(fig)
