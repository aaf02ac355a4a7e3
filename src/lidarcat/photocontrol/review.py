"""Review of the measurements: image chips with the prediction and the measurement drawn, and a gallery of them.

A chip is a window of the photo around the measured (or predicted) vertex,
magnified ``zoom`` times (nearest neighbour: the pixels stay visible), with

* the prediction's ``k``-sigma ellipse (yellow) and its centre, the coarse shift's vertex (cyan ring),
* the fitted roof-edge lines (green),
* the measured vertex (red cross) and, when given, a reference position (magenta ring).

:func:`gallery` tiles chips into one RGB image with a caption strip under each.
Both return arrays; writing the PNG belongs to the stage.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .measure import Measurement, grey
from .predict import ellipse_axes

__all__ = ["chip_image", "chip_centre", "gallery"]


def chip_centre(m: Measurement) -> np.ndarray:
    """(2,) where a chip of *m* is centred: the measured pixel, else the prediction moved by the coarse shift
    when there is one, else the prediction (px)."""
    for c in (np.asarray(m.px, dtype=np.float64), np.asarray(m.predicted_px) + np.asarray(m.shift_px)):
        if np.isfinite(c).all():
            return c
    return np.asarray(m.predicted_px, dtype=np.float64)


def chip_image(image: Any, m: Measurement, *, half_px: int = 40, zoom: int = 4, k: float = 3.0,
               reference_px: Any = None) -> np.ndarray:
    """(2 h z, 2 h z, 3) uint8 BGR chip of *m* on its photo, centred at :func:`chip_centre` (module docstring)."""
    import cv2

    img = grey(image)
    centre = chip_centre(m)
    if not np.isfinite(centre).all():
        return np.zeros((2 * half_px * zoom, 2 * half_px * zoom, 3), np.uint8)
    c0, r0 = int(round(centre[0])) - half_px, int(round(centre[1])) - half_px
    h, w = img.shape
    win = np.zeros((2 * half_px, 2 * half_px), np.float32)
    rs, cs = max(r0, 0), max(c0, 0)
    re, ce = min(r0 + 2 * half_px, h), min(c0 + 2 * half_px, w)
    if re > rs and ce > cs:
        win[rs - r0:re - r0, cs - c0:ce - c0] = img[rs:re, cs:ce]
    lo, hi = np.percentile(win, [1, 99]) if win.any() else (0.0, 1.0)
    win8 = np.clip((win - lo) / max(hi - lo, 1e-6) * 255.0, 0, 255).astype(np.uint8)
    out = cv2.cvtColor(cv2.resize(win8, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST),
                       cv2.COLOR_GRAY2BGR)
    shift = 4   # fixed-point bits of cv2's drawing

    def to_chip(p: Any) -> tuple[int, int]:
        # pixel centre (c, r) -> chip coordinates: centre of the zoomed pixel
        x = (float(p[0]) - c0 + 0.5) * zoom - 0.5
        y = (float(p[1]) - r0 + 0.5) * zoom - 0.5
        return int(round(x * (1 << shift))), int(round(y * (1 << shift)))

    pp = np.asarray(m.predicted_px, dtype=np.float64)
    if np.isfinite(pp).all() and np.isfinite(np.asarray(m.predicted_cov_px2)).all():
        a, b, ang = ellipse_axes(m.predicted_cov_px2, k)
        cv2.ellipse(out, to_chip(pp), (int(a * zoom * (1 << shift)), int(b * zoom * (1 << shift))), ang, 0, 360,
                    (0, 220, 255), 1, cv2.LINE_AA, shift)
        cv2.circle(out, to_chip(pp), 3 << shift, (0, 220, 255), 1, cv2.LINE_AA, shift)
    sh = pp + np.asarray(m.shift_px, dtype=np.float64)
    if np.isfinite(sh).all():
        cv2.circle(out, to_chip(sh), 4 << shift, (255, 255, 0), 1, cv2.LINE_AA, shift)
    for p0, p1 in m.lines:
        cv2.line(out, to_chip(p0), to_chip(p1), (0, 200, 0), 1, cv2.LINE_AA, shift)
    if reference_px is not None and np.isfinite(np.asarray(reference_px, dtype=float)).all():
        cv2.circle(out, to_chip(reference_px), 5 << shift, (255, 0, 255), 1, cv2.LINE_AA, shift)
    if m:
        x, y = to_chip(m.px)
        d = 6 << shift
        cv2.line(out, (x - d, y), (x + d, y), (0, 0, 255), 1, cv2.LINE_AA, shift)
        cv2.line(out, (x, y - d), (x, y + d), (0, 0, 255), 1, cv2.LINE_AA, shift)
    return out


def gallery(chips: Sequence[np.ndarray], captions: Sequence[str], *, columns: int = 6) -> np.ndarray:
    """Chips (same size) tiled row by row with a caption strip of 18 px under each; (H, W, 3) uint8 BGR."""
    import cv2

    if not chips:
        return np.zeros((18, 18, 3), np.uint8)
    ch, cw = chips[0].shape[:2]
    cols = max(1, min(columns, len(chips)))
    rows = math.ceil(len(chips) / cols)
    out = np.full((rows * (ch + 18), cols * cw, 3), 255, np.uint8)
    for i, (c, text) in enumerate(zip(chips, captions)):
        r, k = divmod(i, cols)
        y, x = r * (ch + 18), k * cw
        out[y:y + ch, x:x + cw] = c[:ch, :cw]
        cv2.putText(out, str(text)[: max(8, cw // 7)], (x + 2, y + ch + 13), cv2.FONT_HERSHEY_SIMPLEX, 0.38,
                    (0, 0, 0), 1, cv2.LINE_AA)
    return out
