"""measure-control's second pass: the pairs lost at the frame or to the edges, predicted again from the block
test's adjusted orientation and measured again.

Private to :mod:`lidarcat.stages`; the contract is :mod:`lidarcat.stages.measure_control`'s docstring ("The
second pass"), which calls :func:`measure_again` after the block test:

* :func:`retried` -- whether a pair is tried again (:data:`RETRIED`, or ``not_visible`` because of the frame:
  :data:`FRAME_REASONS`); never an occluded, behind, rejected, user's or ``no_vertex`` pair;
* :func:`measure_again` -- each such pair predicted from the block test's orientation and covariance (still
  hidden or behind: left as it was), measured with ``MeasureParams(border="fit")`` and tested against the
  photo's common displacement beside the photo's accepted first-pass measurements (predicted again the same
  way; only the new ones take its verdict).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from ..errors import SurveyError
from ..photocontrol.predict import dsm_of_points
from ._control_report import CHIP_HALF_PX, chip_window

__all__ = ["RETRIED", "FRAME_REASONS", "retried", "measure_again"]


#: statuses of a pair the second pass predicts and measures again (measure_control's docstring, "The second
#: pass"); a ``not_visible`` pair only when the frame hid it (its reason starts with one of :data:`FRAME_REASONS`)
RETRIED = ("near_border", "no_edges", "weak_geometry")
FRAME_REASONS = ("outside:", "off the photo")


def retried(m: Any) -> bool:
    """Whether the second pass tries the pair of *m* again: lost at the frame or to the edges, not occluded,
    not behind the camera, not rejected by a test, not the user's."""
    return m.status in RETRIED or (m.status == "not_visible" and str(m.reason).startswith(FRAME_REASONS))


def measure_again(survey: Any, per_vertex: dict, vertex_info: dict, adjusted: dict, *, params: Any,
                  direction_from_kappa: bool, lone_photo: str, gallery: bool, images: dict) -> dict:
    """Step 4 of :func:`~lidarcat.stages.measure_control.measure_control` (its docstring, "The second pass"): the
    pairs of *per_vertex* lost at the frame or to the edges (:func:`retried`) predicted again from the block
    test's orientation (*adjusted*: photo -> (eo, cov)), measured with ``border="fit"`` and tested against the
    photo's common displacement together with the photo's accepted first-pass measurements (predicted again the
    same way; only the new ones take its verdict).  A pair the second pass measures (accepted or rejected by that
    test) takes the new measurement in *per_vertex* (and its chip in *images*); the others keep theirs, the
    reason saying what the second pass found.  Returns ``(vertex, photo) -> status`` of the pairs tried."""
    from ..match import read_image
    from ..photocontrol import VertexTarget, check_photo, measure_photo, predict_points
    from ..photocontrol.measure import MeasureParams

    p2 = dataclasses.replace(params or MeasureParams(), border="fit")
    todo: dict[str, list[tuple[str, int]]] = {}
    for vid, lst in per_vertex.items():
        for k, (pid, m) in enumerate(lst):
            if pid in adjusted and retried(m):
                todo.setdefault(pid, []).append((vid, k))
    tried: dict[tuple[str, str], str] = {}
    dsms: dict[str, Any] = {}
    for pid in [p for p in survey.photo_ids if p in todo]:
        eo, cov = adjusted[pid]
        cam = survey.camera_of(pid)
        targets, slots = [], []
        for vid, k in todo[pid]:
            cp, xyz, _ = vertex_info[vid]
            if vid not in dsms:
                dsms[vid] = dsm_of_points(xyz)
            pr = predict_points(cam, eo, cov, cp.enh_m[None], cp.cov_m2[None], points=[vid], photo=pid,
                                dsm=dsms[vid], search_sigma=p2.search_sigma)[0]
            if pr.status in ("occluded", "behind"):         # hidden now that the orientation is known: as it was
                old = per_vertex[vid][k][1]
                per_vertex[vid][k] = (pid, old.failed(old.status, f"{old.reason}; second pass: {pr.status}: "
                                                                  f"{pr.reason}"))
                tried[(vid, pid)] = pr.status
                continue
            targets.append((vid, VertexTarget(cp.enh_m, cp.planes, xyz, pr)))
            slots.append(k)
        if not targets:
            continue
        img = read_image(survey.image_path(pid), lambda msg, pid=pid: SurveyError(f"photo {pid!r}: {msg}"))
        p_ph = p2 if not direction_from_kappa else dataclasses.replace(
            p2, direction_sd_deg=max(0.1, math.degrees(math.sqrt(max(float(cov[5, 5]), 0.0)))))
        new = measure_photo(img, cam, eo, [t for _, t in targets], p_ph)
        # the photo's accepted first-pass measurements beside them, predicted from the same orientation
        old = [(vid, m) for vid, lst in per_vertex.items() for q, m in lst if q == pid and m]
        old_pr = [predict_points(cam, eo, cov, vertex_info[vid][0].enh_m[None], vertex_info[vid][0].cov_m2[None],
                                 points=[vid], photo=pid)[0] for vid, _ in old]
        both = new + [dataclasses.replace(m, predicted_px=pr.px, predicted_cov_px2=pr.cov_px2)
                      for (_, m), pr in zip(old, old_pr)]
        vids = [vid for vid, _ in targets] + [vid for vid, _ in old]
        checked = check_photo(both, cam, eo, cov, [vertex_info[v][0].enh_m for v in vids],
                              [vertex_info[v][0].cov_m2 for v in vids], alone=lone_photo)[:len(new)]
        for (vid, _), k, m in zip(targets, slots, checked):
            tried[(vid, pid)] = m.status
            first = per_vertex[vid][k][1]
            if m.status in ("measured", "rejected"):
                per_vertex[vid][k] = (pid, m)
                if gallery:
                    images[(pid, vid)] = chip_window(img, m, CHIP_HALF_PX)
            else:
                per_vertex[vid][k] = (pid, first.failed(first.status, f"{first.reason}; second pass: {m.status}: "
                                                                      f"{m.reason}"))
    return tried
