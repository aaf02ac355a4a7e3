"""measure-control's report of the measurements: ``decisions.csv`` and the gallery of chips.

Private to :mod:`lidarcat.stages` (:mod:`~lidarcat.stages.measure_control` writes through here):

* :func:`decision_rows` -- one row of ``decisions.csv`` per vertex and photo (:data:`DECISION_FIELDS`):
  status, how the pixel was measured (``method``, :data:`METHODS`, :func:`method_of`) and the reason, the
  measured pixel and its sds, the prediction and the semi-major axis of its
  1-sigma ellipse (the square root of the largest eigenvalue of its covariance), the pass that measured it
  (1, or 2: the second pass), ``accept`` or ``reject``;
* :func:`chip_window` -- the window of a photo that a chip shows (read while the photo is in memory: a
  block's photos do not fit there all at once);
* :func:`write_report` -- decisions.csv and the gallery pages (:mod:`lidarcat.photocontrol.review`:
  predicted ellipse at 3 sigma, fitted edges, the measurement), written atomically.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_csv_atomic

__all__ = ["DECISION_FIELDS", "METHODS", "method_of", "CHIP_HALF_PX", "chip_window", "chip_label", "decision_rows",
           "write_report"]

#: columns of decisions.csv
DECISION_FIELDS = ["photo", "point", "status", "method", "reason", "col_px", "row_px", "sd_col_px", "sd_row_px",
                   "pred_col_px", "pred_row_px", "pred_sd_px", "pass", "decision"]

#: values of decisions.csv's ``method``: how the pair's pixel was measured (empty: no pixel measured)
METHODS: dict[str, str] = {
    "corner": "the vertex where its roof edges found in the photo cross (photocontrol.measure, step 3)",
    "along": "located along one edge (photocontrol.measure, step 3a): tight across the line, loose along it; "
             "its edges are written beside it as line observations",
}

#: half the side of a gallery chip, px of the photo
CHIP_HALF_PX = 32


def method_of(m: Any) -> str:
    """decisions.csv's ``method`` of the measurement *m* (:data:`METHODS`): ``along`` for a point located along
    one edge, ``corner`` for one where its edges cross, empty where no pixel was measured (accepted or rejected
    alike: a rejected row the user accepts keeps its meaning).

    >>> from types import SimpleNamespace as M
    >>> [method_of(M(px=(604.8, 637.5), along_line=a)) for a in (True, False)], method_of(M(px=(float("nan"),) * 2))
    (['along', 'corner'], '')
    """
    if not np.isfinite(np.asarray(m.px, dtype=np.float64)).all():
        return ""
    return "along" if getattr(m, "along_line", False) else "corner"


def chip_label(m: Any, second: Any = ()) -> str:
    """The gallery chip's caption: point, photo, status, and how a measured pair was measured.

    >>> from types import SimpleNamespace as M
    >>> chip_label(M(point="C0003", photo="203", status="measured", along_line=True), {("202", "C0003")})
    'C0003 203 measured along'
    >>> chip_label(M(point="C0003", photo="202", status="measured", along_line=False), {("202", "C0003")})
    'C0003 202 measured pass 2'
    """
    how = (" along" if getattr(m, "along_line", False) else "") + (" pass 2" if (m.photo, m.point) in second else "")
    return f"{m.point} {m.photo} {m.status}{how}"

def chip_window(img: np.ndarray, m: Any, half: int) -> tuple[np.ndarray, np.ndarray]:
    """The photo's window about the measured (else predicted) pixel that a chip shows, and its origin (col, row)."""
    from ..photocontrol import chip_centre

    c = chip_centre(m)
    if not np.isfinite(c).all():
        return np.zeros((2 * half + 4, 2 * half + 4), np.float32), np.zeros(2)
    c0, r0 = int(round(c[0])) - half - 2, int(round(c[1])) - half - 2
    h, w = img.shape[:2]
    win = np.zeros((2 * half + 4, 2 * half + 4) + img.shape[2:], img.dtype)
    rs, cs, re, ce = max(r0, 0), max(c0, 0), min(r0 + 2 * half + 4, h), min(c0 + 2 * half + 4, w)
    if re > rs and ce > cs:
        win[rs - r0:re - r0, cs - c0:ce - c0] = img[rs:re, cs:ce]
    return win, np.array([c0, r0], dtype=np.float64)


def _moved(m: Any, origin: np.ndarray) -> Any:
    """*m* in the coordinates of a window whose top-left pixel is *origin* of the photo."""
    return dataclasses.replace(m, px=np.asarray(m.px) - origin, predicted_px=np.asarray(m.predicted_px) - origin,
                               lines=tuple((np.asarray(a) - origin, np.asarray(b) - origin) for a, b in m.lines))


#: statuses of a pair no pass measured (its ``pass`` is empty)
_NOT_TRIED = ("user_rejected", "no_vertex")


def decision_rows(ms: Sequence[Any], second: Any = ()) -> list[list[Any]]:
    """The rows of decisions.csv (:data:`DECISION_FIELDS`) of the measurements *ms*; *second*: the (photo, point)
    pairs the second pass measured (``pass`` 2; the others 1, or empty where no pass tried the pair)."""
    second = set(second)
    rows = []
    for m in ms:
        def f(v: float, nd: int = 3) -> Any:
            return "" if not np.isfinite(v) else round(float(v), nd)

        sd = m.sd_px if m else np.full(2, np.nan)
        psd = math.sqrt(max(float(np.max(np.linalg.eigvalsh(np.asarray(m.predicted_cov_px2)))), 0.0)) \
            if np.isfinite(np.asarray(m.predicted_cov_px2)).all() else math.nan
        rows.append([m.photo, m.point, m.status, method_of(m), m.reason, f(m.px[0]), f(m.px[1]), f(sd[0]),
                     f(sd[1]), f(m.predicted_px[0], 2), f(m.predicted_px[1], 2), f(psd, 2),
                     2 if (m.photo, m.point) in second else "" if m.status in _NOT_TRIED else 1,
                     "accept" if m else "reject"])
    return rows


def write_report(out: Path, results: list[Any], images: dict, gallery: bool, second: Any = ()) -> list[str]:
    """Step 4 of :func:`~lidarcat.stages.measure_control.measure_control`: decisions.csv and the gallery pages
    (their names) into *out*; *images*: ``(photo, vertex) -> (window, origin)`` of :func:`chip_window`;
    *second*: the (photo, point) pairs measured by the second pass."""
    import cv2

    from ..photocontrol import chip_image, gallery as tile_gallery

    write_csv_atomic(out / "decisions.csv", DECISION_FIELDS, decision_rows(results, second), comments=[
        "LiDAR vertices measured in the photos (lidarcat measure-control). Edit decision (accept/reject) and feed "
        "the file back with --decisions; method = how the pixel was measured (corner: where the vertex's edges "
        "cross; along: located along one edge, its edges written beside it); pixels col_px, row_px; pred_sd_px = "
        "semi-major axis of the prediction's 1-sigma ellipse; pass = the pass that measured the pair (2: predicted "
        "again from the block test's orientation)."])
    tried = [m for m in results if (m.photo, m.point) in images]
    pages = []
    if gallery and tried:
        per_page = 48
        for k0 in range(0, len(tried), per_page):
            chunk = tried[k0:k0 + per_page]
            img = tile_gallery([chip_image(images[(m.photo, m.point)][0], _moved(m, images[(m.photo, m.point)][1]),
                                           half_px=CHIP_HALF_PX, zoom=3) for m in chunk],
                               [chip_label(m, second) for m in chunk], columns=6)
            path = out / f"gallery_{k0 // per_page + 1:02d}.png"
            ok, buf = cv2.imencode(".png", img)
            if ok:
                from .._util import atomic_write

                with atomic_write(path, "wb") as fh:
                    fh.write(buf.tobytes())
                pages.append(path.name)
    return pages
