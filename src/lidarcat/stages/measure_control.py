"""Stage ``measure-control`` and the action of ``lidarcat measure-control``: LiDAR roof vertices measured in the photos.

:func:`measure_control` reads the survey -- cameras, photos with their approximate orientation,
sds and image files, the LiDAR tiles, and the LiDAR control vertices (ground points of source
``lidar``) -- and for every vertex:

1. reads the LiDAR within ``dsm_radius_m`` of it and extracts the vertex again
   (:func:`lidarcat.control.vertices.extract_roof`: the planes and the points around it; a vertex
   found more than ``max_shift_m`` from the ground point's coordinates is skipped with the reason);
2. predicts it in every photo with its ellipse and its visibility over a DSM of those points
   (:mod:`lidarcat.photocontrol.predict`);
3. measures it photo by photo (:func:`lidarcat.photocontrol.measure.measure_photo`) and tests the
   measurements of each photo against their common displacement
   (:func:`~lidarcat.photocontrol.measure.check_photo`; ``lone_photo``: a measurement alone on its photo
   kept or rejected), then all of them in one bundle adjustment with the survey's tie points
   (``block_check``, :func:`~lidarcat.photocontrol.blockcheck.check_block`: a lone measurement on a photo
   with tie points is tested through them; the roof edges that would be written go into the same adjustment as
   line control and are tested too), and of each vertex across the photos
   (:func:`~lidarcat.photocontrol.measure.check_consistency`);
4. (``second_pass``) predicts again, from the block test's adjusted orientation, the pairs lost at the frame
   or to the edges, and measures them (below, "The second pass").

It writes, into the output folder first:

* ``decisions.csv`` -- one row per vertex and photo: ``photo, point, status, method, reason, col_px, row_px,
  sd_col_px, sd_row_px, pred_col_px, pred_row_px, pred_sd_px, pass, decision`` (``method``: ``corner`` where the
  vertex's edges cross, ``along`` for a point located along one edge, empty where no pixel was measured;
  ``pass``: 1, 2 for the second pass, empty where no pass tried the pair); ``decision`` is
  ``accept`` for accepted measurements and ``reject`` otherwise.  A user may edit ``decision`` (and
  the pixel) and feed the file back (``decisions=``): then nothing is measured, the accepted rows
  are written;
* ``gallery_NN.png`` -- the chips of every vertex and photo that was tried (predicted ellipse at
  3 sigma in yellow, fitted edges green, measurement red; :mod:`lidarcat.photocontrol.review`);
* ``measure_control.json`` -- counts and options;

* ``line_decisions.csv`` -- one row per roof edge (the intersection line of two of the vertex's
  planes) and photo tried: ``line, point, photo, status, reason, col1_px .. row2_px, sd_px,
  ratio, decision``; ``written`` edges went to line_control.csv, the others say why not (the
  vertex's own status where the photo was not measured, ``no image edge`` where the edge was not
  found, ``in the point`` where the vertex's point observation already carries it, ``roof edge inconsistent
  with the block`` with its offset and w where the block test rejected it);

* ``line_candidates.csv`` -- the 3-D line of every edge of line_decisions.csv (what ``line_decisions=`` reads);

and then the accepted observations into the survey's ``image_points.csv`` (atomically; the
survey is loaded again from the new table, and the old file restored if it does not load; nothing
accepted: the survey's tables are not rewritten).  A
vertex and photo that already has an observation there keeps it (``replace=True`` measures it
again and replaces it: by its point, or by its edges where those are written instead, ``lines="only"``).
Pixel sds go to ``sd_x_mm, sd_y_mm`` (times the camera's pixel size).

**Line control** (``lines``).  Each roof edge fitted in a photo (:class:`~lidarcat.photocontrol.measure.EdgeLine`,
the two-point equivalent of the free line fit) is a line observation of the control line of its two
planes (:func:`~lidarcat.photocontrol.predict.edge_line_m`: end points and their 6 x 6 covariance from
the plane fits), written to ``line_control.csv`` (``[files] line_control``, added to survey.toml when
missing; the old observations of each photo and vertex pair written now -- a point or edges -- replaced,
the others kept) with the vertex as the line's ``point`` (the line is control where the vertex is).
A vertex's point and its edges on one photo come from the same fits, so one photo never gives both:
``lines="add"`` (default) writes the points, and the edges of the photos where the vertex's point was not
measured (two edges of which one is weak, edges on one image line: the strong ones alone); ``"only"`` writes
every photo's edges and no points; ``"none"`` no lines.  A line file that does not load leaves both tables as they were.

**Feeding the decisions back** (``decisions=``, ``line_decisions=``; the review of issue 29).  Both reports
can be edited -- ``decision`` flipped between ``accept`` and ``reject``, the pixels moved -- and fed back
together or alone; then nothing is measured.  Each file *replaces* the survey's rows of the pairs it lists
(rows a user deleted from it are not touched): decisions.csv the (photo, point) rows of image_points.csv,
line_decisions.csv the (line, photo) observations of line_control.csv.  An accepted edge needs its 3-D line:
line_decisions.csv names it only by id, so the run writes every edge's line (end points, ``cov_m2``, ``point``;
rejected and not-found edges too) to ``line_candidates.csv`` beside it, in line_control.csv's columns, and the
feedback takes the lines from there (else from the survey's line_control.csv); a line is written when an
observation of it remains, dropped with its last one.  One photo never gives a vertex's point and its edges
(they come from the same fits): an ``in_point`` edge accepted where the vertex's point on the photo is accepted
too (in the decisions.csv fed back, else in image_points.csv) is an error, and so is a ``measured`` point accepted
where the new line_control.csv has edges of its vertex on that photo; a point typed by hand (a row of another
status) may sit beside measured edges (independent measurements), and so may a point located along one edge
(``method`` ``along``: its edges are written beside it; a file without the column, written before it, is read by
the reason, "located along one edge").  Every bad row is one error with ``file:line`` (a decision other than
accept/reject, a method other than corner/along/empty, a pixel or sd that is not a number, an unknown photo,
point or line, a line's ``point`` changed, an accepted row without pixels or with an edge of zero length, a pair
listed twice), raised before anything is written; the tables then go through the same atomic write and reload as a
measurement's.

**The review remembered** (:mod:`lidarcat.survey.decisions`).  Feeding back also records the user's word on
every pair the files list (an ``in_point`` edge left at ``reject`` excepted: its point carries it) in the
survey's ``control_decisions.csv`` (``[files] control_decisions``, added when missing; written and rolled back
with the tables).  A measurement -- this command and the ``lidarcat run`` stage alike -- never measures a
rejected pair again (its decisions.csv row: ``user_rejected``, "rejected by the user (control_decisions.csv:LINE)";
its edges on the photo ``not_written`` with that reason; a rejected edge is never written), nor an accepted one
unless ``replace`` (a user-accepted edge's observation is kept while its vertex is measured on other photos).
:func:`planned` counts a vertex as done when it has an observation or the user's decision on every oriented
photo, so ``lidarcat run`` stops planning the stage after a full review.  The run measures into its own tables;
``lidarcat measure-control SURVEY --decisions RUN/measure_control/decisions.csv ...`` feeds its review back.

**The second pass** (``second_pass``, default on).  The first pass predicts from photos.csv (2 m / 0.5 deg: a
vertex's ellipse has a sd of ~20-30 px), so a vertex near the frame is ``outside`` or ``near_border`` and one
whose edges the wide search confuses is ``no_edges`` or ``weak_geometry``.  The block test's last adjustment
(ties + GNSS/IMU + the accepted measurements and edges) gives every photo of the block an orientation and its
covariance far tighter than that (seed 6 of bench_measured_control: C0003 on photo 202 from 27.9 px to 4.2 px
sd).  So after the block test the pairs of status ``near_border``, ``no_edges``, ``weak_geometry`` and
``not_visible`` *because of the frame* (the prediction ``outside`` it, or no shift searched on the photo) --
never ``occluded``, ``behind``, ``rejected``, ``user_rejected`` or ``no_vertex`` -- are predicted again from it
(still hidden or behind the camera: left as they were) and measured with ``MeasureParams(border="fit")``: the
tighter ellipse lets a vertex cut by the frame be searched on the part of the photo there is.  The new
measurements go through the same tests before anything is written: ``check_photo`` on each photo (with the
photo's accepted first-pass measurements beside them, predicted from the same orientation; only the new ones
take its verdict), the block test again over every measurement and edge (its verdict on the edges replaces the
first's; the block's datum is still photos.csv, not the adjusted orientation), then ``check_consistency``.  A
pair the second pass measured (accepted or rejected) has ``pass`` 2 in decisions.csv and its new prediction; a
pair it tried and lost again keeps its first row, the reason extended by ``; second pass: STATUS: REASON``.
Without the block test (``block_check=False``, no tie points, nothing measured, not converged) there is no
adjusted orientation, and the second pass is not run (``measure_control.json``: ``second_pass.status``).

**Sds of the edge fits.**  The predicted direction of an edge observes the fitted slope
(``direction_sd_deg``): taken from the photo's kappa sd (the image turns with kappa; omega and phi
turn a near-nadir photo's lines by far less), at least 0.1 deg (``direction_from_kappa``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_csv_atomic, write_json_atomic
from ..errors import LidarcatError, SurveyError
from ..photocontrol.predict import dsm_of_points
from ._control_report import CHIP_HALF_PX, DECISION_FIELDS, chip_window, write_report
from ._control_review import LINE_CANDIDATES, feed_back
from ._control_tables import (edge_pairs, image_point_rows, line_control_rows, line_def_row, line_observations,
                              write_checked)
from ._second_pass import measure_again
from .context import StageContext as Context

__all__ = ["measure_control", "run", "planned", "MeasureControlResult", "DECISION_FIELDS", "LINE_DECISION_FIELDS",
           "LINE_MODES", "LINE_CANDIDATES", "lidar_vertices", "dsm_of_points", "line_id"]

log = logging.getLogger(__name__)

#: columns of line_decisions.csv
LINE_DECISION_FIELDS = ["line", "point", "photo", "status", "reason", "col1_px", "row1_px", "col2_px", "row2_px",
                        "sd_px", "ratio", "decision"]
#: values of ``lines``
LINE_MODES = ("add", "only", "none")


@dataclasses.dataclass(frozen=True)
class MeasureControlResult:
    """What :func:`measure_control` wrote: the tables, and counts by status."""

    image_points: Path
    outdir: Path
    counts: dict
    accepted: int
    summary: dict
    line_control: Path | None = None
    lines_written: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"image_points": str(self.image_points), "outdir": str(self.outdir), "counts": self.counts,
                "accepted": self.accepted,
                "line_control": None if self.line_control is None else str(self.line_control),
                "line_observations": self.lines_written}


def line_id(point: str, planes: Sequence[int]) -> str:
    """Id of the control line of a vertex's planes *planes* (0-based): ``POINT/i-j`` (1-based)."""
    return f"{point}/{int(planes[0]) + 1}-{int(planes[1]) + 1}"


def lidar_vertices(survey: Any, points: Sequence[str] | None = None) -> list[tuple[str, np.ndarray]]:
    """(id, E N h) of the survey's LiDAR control vertices (ground points of source ``lidar``), or of *points*."""
    gp = survey.ground_points
    src = np.asarray(gp.source, dtype=str)
    ids = np.asarray(gp.point, dtype=str)
    if points:
        missing = sorted(set(points) - set(ids.tolist()))
        if missing:
            raise SurveyError(f"{gp.path}: no ground point {missing[0]!r} (asked for by points)")
        sel = np.isin(ids, list(points))
    else:
        sel = np.char.lower(src) == "lidar"
    return [(str(ids[i]), np.asarray(gp.enh_m[i], dtype=float)) for i in np.flatnonzero(sel)]


def planned(survey: Any) -> str | None:
    """Why ``lidarcat run`` skips the stage (None: planned): it needs images, LiDAR tiles and a LiDAR vertex
    still open -- one with no observation (a point in image_points.csv or an edge in line_control.csv) of
    which some photo with an approximate orientation has no decision of the user (control_decisions.csv).
    A vertex the user rejected on every photo is done: the run does not plan it again."""
    if not getattr(survey, "has_images", False):
        return "the photos have no image files"
    if not survey.lidar_paths:
        return "the survey has no LiDAR tiles"
    verts = lidar_vertices(survey)
    if not verts:
        return "the survey has no LiDAR control vertices (ground points of source lidar)"
    observed = set(np.asarray(survey.image_points.point, dtype=str).tolist())
    own = survey.files.get("line_control")
    observed |= {pt for _, pt in edge_pairs(None, Path(own))} if own is not None else set()
    told = survey.control_decisions.of("point")
    oriented = [ph.id for ph in survey.photos if ph.position_m is not None and ph.attitude_deg is not None]
    if all(v in observed or (oriented and all((pid, v) in told for pid in oriented)) for v, _ in verts):
        return "every LiDAR control vertex has image observations" + (
            " or the user's decision on every photo (control_decisions.csv)" if told else "") + \
            "; `lidarcat measure-control` measures again"
    return None


def _approx(survey: Any, default_sd: tuple[float, float]) -> tuple[dict, dict]:
    eos, covs = {}, {}
    for ph in survey.photos:
        if ph.position_m is None or ph.attitude_deg is None:
            continue
        eos[ph.id] = np.r_[np.asarray(ph.position_m, float), np.deg2rad(np.asarray(ph.attitude_deg, float))]
        sp = np.asarray(ph.sd_position_m, float) if ph.sd_position_m is not None else np.full(3, default_sd[0])
        sa = np.asarray(ph.sd_attitude_deg, float) if ph.sd_attitude_deg is not None else np.full(3, default_sd[1])
        covs[ph.id] = np.diag(np.r_[sp**2, np.deg2rad(sa) ** 2])
    return eos, covs


#: statuses of a vertex not measured on a photo for a reason of the photo or the vertex: its edges there say that reason
_UNMEASURED = ("not_visible", "too_dark", "saturated", "near_border", "no_vertex", "user_rejected")
#: statuses of a vertex measurement whose roof edges are never written (nor tested)
_NO_EDGE_STATUSES = _UNMEASURED + ("rejected",)


def _edge_lines(vertex_info: dict) -> dict[str, tuple[str, Any, Any, Any] | None]:
    """The 3-D control line of every roof edge of the vertices extracted (``line id -> (point, A, B, cov)``,
    :func:`~lidarcat.photocontrol.predict.edge_line_m`; None where the two planes give none), computed once for
    the block test (:func:`_block_edges`) and the line rows (:func:`_line_control`)."""
    from ..photocontrol import edge_line_m

    out: dict[str, tuple[str, Any, Any, Any] | None] = {}
    for vid, (cp, _, edges) in vertex_info.items():
        for planes, e in edges.items():
            try:
                out[line_id(vid, planes)] = (vid, *edge_line_m(cp.planes[planes[0]], cp.planes[planes[1]],
                                                               np.array([e.start_m, e.end_m])))
            except np.linalg.LinAlgError:      # planes (nearly) parallel: no line
                out[line_id(vid, planes)] = None
    return out


def _block_edges(per_vertex: dict, lines3d: dict, lines: str, line_rejected: Any) -> list[Any]:
    """The roof edges the line rows would write now (as :func:`_line_control` decides), with their 3-D lines
    (*lines3d*, :func:`_edge_lines`), for the block test."""
    from ..photocontrol import EdgeObservation

    out: list[Any] = []
    if lines == "none":
        return out
    for vid, lst in per_vertex.items():
        for pid, m in lst:
            if m.status in _NO_EDGE_STATUSES or (m and lines == "add" and not m.along_line):
                continue
            for el in m.edge_lines:
                lid = line_id(vid, el.planes)
                if lines3d.get(lid) is None or (pid, lid) in line_rejected:
                    continue
                try:
                    out.append(EdgeObservation(lid, vid, pid, el.p1_px, el.p2_px, el.sd_px, *lines3d[lid][1:]))
                except LidarcatError:     # no line: the line rows say why
                    continue
    return out


def _check_block(survey: Any, per_vertex: dict, eos: dict, covs: dict, vertex_info: dict,
                 edges: Sequence[Any] = (), line_reasons: dict | None = None, adjusted: dict | None = None) -> dict:
    """The block test (:func:`~lidarcat.photocontrol.blockcheck.check_block`) of every photo's measurements and the
    roof *edges* (:func:`_block_edges`), with the survey's tie points (image observations of points that are not
    ground points, in corrected photo coordinates as the survey's adjustment uses them); *per_vertex* is updated
    in place, the reasons of the rejected edges go to *line_reasons* ((line, photo) -> reason), the adjusted
    orientation of every photo of its final adjustment and its covariance to *adjusted* (photo -> ((6,),
    (6, 6)); the second pass predicts from them).  Returns the test's summary.  Without tie points it is not
    run (it would be the per-photo test again)."""
    from ..photocontrol import TieObservations, check_block

    try:
        obs = survey.photo_observations()
    except SurveyError as ex:
        log.warning("measure-control: no tie points for the block test: %s", ex)
        obs = None
    ties = None
    if obs is not None and len(obs):
        ground = set(np.asarray(survey.ground_points.point, dtype=str).tolist())
        sel = np.flatnonzero(~np.isin(obs.point.astype(str), list(ground)) & np.isin(obs.photo.astype(str), list(eos)))
        xy, sd = obs.xy_mm[sel], obs.sd_mm[sel]           # as the survey's adjustment uses them
        ok = np.isfinite(xy).all(axis=1) & np.isfinite(sd).all(axis=1) & (sd > 0).all(axis=1)
        if ok.any():
            ties = TieObservations(obs.photo[sel][ok], obs.point[sel][ok], xy_mm=xy[ok], sd_mm=sd[ok])
    if ties is None:
        return {"status": "no tie points", "message": "the survey's image points hold no tie points: not run"}
    flat = [(vid, pid, m) for vid, lst in per_vertex.items() for pid, m in lst]
    photos = {pid for _, pid, _ in flat} | set(ties.photo.tolist())
    cps = {v: vertex_info[v][0] for v in per_vertex}
    bc = check_block([m for _, _, m in flat], {p: survey.camera_of(p) for p in photos}, eos, covs,
                     {v: cp.enh_m for v, cp in cps.items()}, {v: cp.cov_m2 for v, cp in cps.items()}, ties,
                     lines=edges)
    if line_reasons is not None:
        line_reasons.update(bc.line_reasons)
    per_vertex.clear()
    for (vid, pid, _), m in zip(flat, bc.measurements):
        per_vertex.setdefault(vid, []).append((pid, m))
    log.info("measure-control: block test %s: %d tested, %d rejected, %d untestable, %d tie observations",
             bc.status, bc.tested, len(bc.rejected), len(bc.untestable), bc.ties_used)
    if adjusted is not None:
        adjusted.update({p: (bc.eo[p], bc.eo_cov[p]) for p in bc.eo})
    return bc.summary()


@dataclasses.dataclass(frozen=True)
class _Review:
    """The user's review (control_decisions.csv) as a measurement sees it (module docstring, "The review
    remembered"): the rejected pairs and edges, the pairs accepted (a point or one of its edges)."""

    user: Any
    rejected: dict
    line_rejected: dict
    kept: set

    @classmethod
    def of(cls, survey: Any) -> "_Review":
        user = survey.control_decisions
        kept = set(user.of("point", "accept")) | {(d.photo, d.point) for d in user.of("line", "accept").values()}
        return cls(user, user.of("point", "reject"), user.of("line", "reject"), kept)

    def told(self, vid: str, pid: str, m: Any = None) -> Any:
        """*m*, or the pair's ``user_rejected`` measurement when the user rejected it."""
        d = self.rejected.get((pid, vid))
        return m if d is None else _unmeasured(vid, pid, "user_rejected", self.user.reason(d))


def _unmeasured(vid: str, pid: str, status: str, reason: str) -> Any:
    from ..photocontrol.measure import Measurement

    return Measurement(vid, pid, np.full(2, np.nan), np.full((2, 2), np.nan), status, reason)


def _predict(survey: Any, verts: list[tuple[str, np.ndarray]], photos: list[str], eos: dict, covs: dict,
             review: _Review, *, replace: bool, dsm_radius_m: float, max_shift_m: float,
             progress: Callable[[int, int], Any] | None, total: int, search_sigma: float = 0.0
             ) -> tuple[list[Any], dict, dict]:
    """Step 1: every vertex extracted again from the LiDAR around it and predicted in every photo
    (*search_sigma* > 0: ``outside`` only when that ellipse misses the frame, :func:`~lidarcat.photocontrol.predict_points`).

    Returns the measurements of the pairs not measured (``no_vertex``, ``user_rejected``), the targets of each
    photo (``photo -> [(vertex, VertexTarget)]``; not the pairs observed or accepted by the user, unless
    *replace*) and each vertex extracted (``vertex -> (ControlPoint, LiDAR points (N, 3), roof edges by
    planes)``).
    """
    from ..control.vertices import extract_roof
    from ..lidar.clipping import clip
    from ..photocontrol import VertexTarget, predict_points, roof_edges

    observed = {(str(a), str(b)) for a, b in zip(survey.image_points.photo, survey.image_points.point)}
    crs = survey.lidar_crs or survey.crs
    results: list[Any] = []
    targets: dict[str, list[tuple[str, Any]]] = {}
    vertex_info: dict[str, tuple[Any, np.ndarray, dict]] = {}
    for i, (vid, enh) in enumerate(verts):
        if progress is not None:
            progress(i, total)
        try:
            cloud = clip(list(survey.lidar_paths), enh[:2], dsm_radius_m, height_filter=None, crs=crs)
            xyz = np.asarray(cloud.xyz, dtype=np.float64)
        except LidarcatError as ex:
            results += [review.told(vid, pid, _unmeasured(vid, pid, "no_vertex", f"no LiDAR around the vertex: {ex}"))
                        for pid in photos]
            continue
        cp = extract_roof(xyz, enh[:2], point_id=vid)
        if not cp or np.linalg.norm(cp.enh_m - enh) > max_shift_m:
            why = (f"the vertex is not extracted again ({cp.status}: {cp.reason})" if not cp else
                   f"the vertex extracted again lies {float(np.linalg.norm(cp.enh_m - enh)):.2f} m from the "
                   f"ground point (> {max_shift_m:g} m)")
            results += [review.told(vid, pid, _unmeasured(vid, pid, "no_vertex", why)) for pid in photos]
            continue
        vertex_info[vid] = (cp, xyz, {e.planes: e for e in roof_edges(cp.enh_m, cp.planes, xyz)})
        dsm = dsm_of_points(xyz)
        for pid in photos:
            if (pid, vid) in review.rejected:
                results.append(review.told(vid, pid))
                continue
            if ((pid, vid) in observed or (pid, vid) in review.kept) and not replace:
                continue
            cam = survey.camera_of(pid)
            pr = predict_points(cam, eos[pid], covs[pid], cp.enh_m[None], cp.cov_m2[None], points=[vid], photo=pid,
                                dsm=dsm, search_sigma=search_sigma)[0]
            targets.setdefault(pid, []).append((vid, VertexTarget(cp.enh_m, cp.planes, xyz, pr)))
    return results, targets, vertex_info


def _measure_photos(survey: Any, photos: list[str], targets: dict, vertex_info: dict, eos: dict, covs: dict, *,
                    params: Any, direction_from_kappa: bool, lone_photo: str, gallery: bool,
                    progress: Callable[[int, int], Any] | None, done: int, total: int) -> tuple[dict, dict]:
    """Step 2: each photo read once, its targets measured and tested against their common displacement.

    Returns the measurements by vertex (``vertex -> [(photo, Measurement)]``) and, with *gallery*, the window of
    each chip and its origin (``(photo, vertex) -> (window, (col, row))``; a block's photos do not fit in memory).
    """
    from ..match import read_image
    from ..photocontrol import check_photo, measure_photo
    from ..photocontrol.measure import MeasureParams

    per_vertex: dict[str, list[tuple[str, Any]]] = {}
    images: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    for j, pid in enumerate(photos):
        if progress is not None:
            progress(done + j, total)
        if pid not in targets:
            continue
        img = read_image(survey.image_path(pid), lambda msg, pid=pid: SurveyError(f"photo {pid!r}: {msg}"))
        # the predicted edge directions are good to the photo's kappa sd (module docstring)
        p_ph = params if not direction_from_kappa else dataclasses.replace(
            params or MeasureParams(),
            direction_sd_deg=max(0.1, math.degrees(math.sqrt(max(float(covs[pid][5, 5]), 0.0)))))
        ms = measure_photo(img, survey.camera_of(pid), eos[pid], [t for _, t in targets[pid]], p_ph)
        ms = check_photo(ms, survey.camera_of(pid), eos[pid], covs[pid],
                         [vertex_info[vid][0].enh_m for vid, _ in targets[pid]],
                         [vertex_info[vid][0].cov_m2 for vid, _ in targets[pid]], alone=lone_photo)
        for (vid, _), m in zip(targets[pid], ms):
            per_vertex.setdefault(vid, []).append((pid, m))
        if gallery:
            for (vid, _), m in zip(targets[pid], ms):
                if m.status != "not_visible":
                    images[(pid, vid)] = chip_window(img, m, CHIP_HALF_PX)
    return per_vertex, images


def _check_vertices(survey: Any, per_vertex: dict, vertex_info: dict, eos: dict, covs: dict,
                    min_photos: int) -> list[Any]:
    """Step 3 (after the block test): each vertex's measurements tested across the photos, and rejected where
    fewer than *min_photos* remain."""
    from ..photocontrol import check_consistency

    results: list[Any] = []
    for vid, lst in per_vertex.items():
        cp = vertex_info[vid][0]
        pids = [pid for pid, _ in lst]
        checked = check_consistency([m for _, m in lst], [survey.camera_of(pid) for pid in pids],
                                    np.array([eos[pid] for pid in pids]), np.array([covs[pid] for pid in pids]),
                                    cp.enh_m, cp.cov_m2)
        n_ok = sum(bool(m) for m in checked)
        if 0 < n_ok < min_photos:
            checked = [m.failed("rejected", f"measured on {n_ok} photo(s) only (< {min_photos}): no check across "
                                            f"photos, and a free point needs two rays") if m else m for m in checked]
        results += checked
    return results


def _edge_status(m: Any, lid: str, el: Any, lines: str, review: _Review,
                 block_lines: dict | None = None) -> tuple[str, str]:
    """(status, reason) of the roof edge *lid* of measurement *m*'s vertex on its photo (*el*: its image edge or
    None): ``written`` or why not (module docstring, "Line control"); *block_lines*: (line, photo) -> why the
    block test rejected the edge."""
    if m.status in _UNMEASURED:
        return "not_written", f"{m.status}: {m.reason}"
    if block_lines and (lid, m.photo) in block_lines:
        return "not_written", block_lines[(lid, m.photo)]
    if m.status == "rejected":
        return "not_written", f"the vertex's measurement was rejected: {m.reason}"
    if el is None:
        return "not_written", "no image edge found (or too weak for a line without its vertex)"
    if m and lines == "add" and not m.along_line:   # a point along one edge: its edges written beside it
        return "in_point", "the vertex's point observation carries this edge (not written twice)"
    if (m.photo, lid) in review.line_rejected:
        return "user_rejected", review.user.reason(review.line_rejected[(m.photo, lid)])
    return "written", ""


def _line_control(out: Path, results: list[Any], vertex_info: dict, lines3d: dict, lines: str, review: _Review,
                  block_lines: dict | None = None
                  ) -> tuple[dict[str, tuple[str, Any, Any, Any]], list[tuple[str, str, Any]]]:
    """Step 5: the roof edges of the vertices tried, per photo, into line_decisions.csv and their 3-D lines
    (*lines3d*, :func:`_edge_lines`) into line_candidates.csv (module docstring, "Line control").  Returns the
    lines to write (``id -> (point, A, B, cov)``) and their observations (``(line, photo, EdgeLine)``)."""
    from ..survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS

    def f(v: float, nd: int = 3) -> Any:
        return "" if v is None or not np.isfinite(v) else round(float(v), nd)

    new_lines: dict[str, tuple[str, Any, Any, Any]] = {}
    candidates: dict[str, tuple[str, Any, Any, Any] | None] = {}   # the 3-D line of each edge tried
    new_obs: list[tuple[str, str, Any]] = []
    line_rows: list[list[Any]] = []
    for m in results:
        if m.point not in vertex_info:
            continue
        found = {tuple(el.planes): el for el in m.edge_lines}
        for planes in vertex_info[m.point][2]:
            lid = line_id(m.point, planes)
            candidates[lid] = lines3d[lid]      # None: the planes (nearly) parallel, no line (not a candidate)
            el = found.get(tuple(planes))
            status, reason = _edge_status(m, lid, el, lines, review, block_lines)
            if status == "written" and candidates[lid] is None:
                status, reason = "not_written", "the two planes give no line (nearly parallel)"
            if status == "written":
                new_lines[lid] = candidates[lid]
                new_obs.append((lid, m.photo, el))
            line_rows.append([lid, m.point, m.photo, status, reason,
                              *(f(v) for v in (el.p1_px if el else (None, None))),
                              *(f(v) for v in (el.p2_px if el else (None, None))),
                              f(el.sd_px if el else None, 4), f(el.ratio if el else None, 2),
                              "accept" if status == "written" else "reject"])
    write_csv_atomic(out / "line_decisions.csv", LINE_DECISION_FIELDS, line_rows, comments=[
        "LiDAR roof edges measured in the photos as line control (lidarcat measure-control): one row per edge "
        "(line = POINT/plane-plane) and photo tried; written rows went to line_control.csv. Edit decision "
        "(accept/reject; the pixels col1_px .. row2_px, sd_px) and feed the file back with --line-decisions; "
        "the 3-D lines are in line_candidates.csv beside it."])
    ch = list(LINE_COLUMNS) + list(LINE_EXTRA_COLUMNS)
    write_csv_atomic(out / LINE_CANDIDATES, ch, [line_def_row(ch, lid, *v) for lid, v in candidates.items()
                                                  if v is not None and np.linalg.norm(np.subtract(v[2], v[1])) > 0],
                     comments=["The 3-D control line of every roof edge of line_decisions.csv (line = POINT/"
                               "plane-plane; end points and cov_m2 from the two plane fits), in line_control.csv's "
                               "columns: measure-control --line-decisions takes the lines of accepted rows from "
                               "here."])
    return new_lines, new_obs


def _write_tables(survey: Any, ip_path: Path, accepted: list[dict[str, Any]], *, replace: bool,
                  table: Any, line_table: Any, new_lines: dict, new_obs: list, vertex_info: dict
                  ) -> Path | None:
    """Step 6: the accepted observations into image_points.csv and line_control.csv (the survey's, through
    :func:`~lidarcat.stages._control_tables.write_checked`, unless nothing is new; or *table*, *line_table*).
    One photo never gives a vertex's point and its edges: the (photo, vertex) pairs written now (a point or
    edges) replace the pair's old observations of either kind (the point row with *replace*: without it an
    observed pair is not measured); the old observations of every other pair stay (a user-accepted edge, or one
    whose new measurement failed).  Returns the line table written, if any."""
    written = {(d["photo"], d["point"]) for d in accepted} | {(pid, new_lines[lid][0]) for lid, pid, _ in new_obs}
    header, table_rows = image_point_rows(survey, accepted, replace=replace, drop=written)
    comment = ("LiDAR control observations: lidarcat measure-control (roof vertices measured in the photos, col_px, "
               "row_px)")
    lines_out = None
    own = survey.files.get("line_control")
    old = line_observations(None, Path(own)) if own is not None else {}
    if new_obs or any((ph, pt) in written for (ph, _), pt in old.items()):
        lp = Path(line_table) if line_table is not None else Path(own) if own is not None else \
            survey.root / "line_control.csv"
        lh, lrows = line_control_rows(survey, Path(own) if own is not None else None, new_lines, new_obs,
                                      set(vertex_info), {k for k, pt in old.items() if (k[0], pt) not in written})
        lines_out = (lp, lh, lrows, "LiDAR roof edges as control lines: lidarcat measure-control (line = POINT/"
                                    "plane-plane; end points and cov_m2 from the two plane fits; observations: the "
                                    "edge fits' two equivalent points, px)")
    if table is None:
        if accepted or lines_out is not None:   # nothing new: the survey's tables (and their notes) stay as they are
            write_checked(survey, ip_path, header, table_rows, comment, lines_out)
    else:
        if lines_out is not None:
            write_csv_atomic(lines_out[0], lines_out[1], lines_out[2], comments=[lines_out[3]])
        write_csv_atomic(ip_path, header, table_rows, comments=[comment])
    return None if lines_out is None else lines_out[0]


def measure_control(survey_dir: Any, outdir: str | Path | None = None, *, points: Sequence[str] | None = None,
                    decisions: str | Path | None = None, line_decisions: str | Path | None = None,
                    params: Any = None, replace: bool = False,
                    gallery: bool = True, table: str | Path | None = None, dsm_radius_m: float = 30.0,
                    max_shift_m: float = 0.5, default_sd: tuple[float, float] = (2.0, 0.5),
                    min_photos: int = 1, lines: str = "add", line_table: str | Path | None = None,
                    direction_from_kappa: bool = True, block_check: bool = True, lone_photo: str = "keep",
                    second_pass: bool = True,
                    progress: Callable[[int, int], Any] | None = None) -> MeasureControlResult:
    """LiDAR control vertices measured in the photos into image_points.csv (module docstring).

    Parameters
    ----------
    survey_dir : path or Survey
    outdir : path, optional
        Report folder (default ``SURVEY/out/measure_control``).
    points : ids, optional
        Measure these ground points (default: every ground point of source ``lidar``).
    decisions : path, optional
        An edited decisions.csv: write its accepted rows, measure nothing; every row is recorded in the
        survey's control_decisions.csv (module docstring, "The review remembered"; not with *table*).
    line_decisions : path, optional
        An edited line_decisions.csv (with line_candidates.csv beside it): write its accepted rows as line
        observations, measure nothing (module docstring, "Feeding the decisions back").
    params : MeasureParams, optional
    replace : bool
        Measure (and replace) vertex/photo pairs that already have an observation or that the user accepted
        (control_decisions.csv); never the pairs the user rejected.
    gallery : bool
        Write the chips.
    table : path, optional
        Write the new image_points table there instead of the survey's own file (``lidarcat run``).
    dsm_radius_m : float
        LiDAR read around each vertex, m (the DSM of the visibility test).
    max_shift_m : float
        A vertex extracted farther than this from its ground point is not measured, m.
    default_sd : (m, deg)
        Sds of the approximate orientation where photos.csv gives none.
    min_photos : int
        A vertex measured (and accepted) on fewer photos is rejected there (default 1: a vertex on
        one photo is good control; the adjustment of a set where it is not control leaves it out,
        :func:`lidarcat.survey.adjustment.problem_from_survey`).
    lines : {"add", "only", "none"}
        Roof edges as line control (module docstring).
    line_table : path, optional
        Write the line control there instead of the survey's line_control.csv (``lidarcat run``).
    direction_from_kappa : bool
        ``direction_sd_deg`` of each photo from its kappa sd (module docstring); False: *params*'.
    block_check : bool
        Test the measurements in one bundle adjustment with the survey's tie points
        (:func:`~lidarcat.photocontrol.blockcheck.check_block`; module docstring).
    lone_photo : {"keep", "reject"}
        A measurement alone on its photo, which the per-photo test cannot test
        (:func:`~lidarcat.photocontrol.measure.check_photo`'s ``alone``): kept for the block test, or rejected.
    second_pass : bool
        After the block test, predict the pairs lost at the frame or to the edges again from its adjusted
        orientation and measure them with ``border="fit"`` (module docstring, "The second pass"; needs the
        block test and tie points).
    progress : callable(done, total), optional

    Returns
    -------
    MeasureControlResult

    Raises
    ------
    SurveyError
        No LiDAR vertex, no LiDAR tiles, no approximate orientation, a bad decisions file.
    """
    if lines not in LINE_MODES:
        raise SurveyError(f"lines must be one of {', '.join(LINE_MODES)}, got {lines!r}")
    if lone_photo not in ("keep", "reject"):
        raise SurveyError(f"lone_photo must be keep or reject, got {lone_photo!r}")
    from ..survey.folder import Survey

    t_start = time.perf_counter()
    survey = survey_dir if isinstance(survey_dir, Survey) else Survey.load(survey_dir)
    out = Path(outdir) if outdir is not None else survey.output_dir() / "measure_control"
    out.mkdir(parents=True, exist_ok=True)
    ip_path = Path(table) if table is not None else \
        Path(survey.files.get("image_points", survey.root / survey.config.files.image_points))
    if decisions is not None or line_decisions is not None:
        summary, n_acc, n_lines, lp = feed_back(survey, out, ip_path, decisions, line_decisions, table, line_table)
        return MeasureControlResult(ip_path, out, {"accepted": n_acc, "lines_accepted": n_lines}, n_acc, summary,
                                    lp, n_lines)

    verts = lidar_vertices(survey, points)
    if not verts:
        raise SurveyError(f"{survey.files.get('ground_points', survey.toml_path)}: no LiDAR control vertex (ground "
                          f"points of source lidar): run `lidarcat extract` and add its points, or give points")
    if not survey.lidar_paths:
        raise SurveyError(f"{survey.toml_path}: no LiDAR tiles: the vertices' planes come from them")
    eos, covs = _approx(survey, default_sd)
    if not eos:
        raise SurveyError(f"{survey.files.get('photos', survey.toml_path)}: no approximate orientation "
                          f"(X0 .. kappa) of any photo: nothing to predict with")
    # the user's review (control_decisions.csv): rejected pairs never measured, accepted ones not unless replace
    review = _Review.of(survey)
    photos = [pid for pid in survey.photo_ids if pid in eos]
    total = len(verts) + len(photos)
    # the frame edge (MeasureParams.border): "fit" predicts a vertex outside only when its search ellipse misses
    # the frame, and measures it on the part of the photo there is (docs/photocontrol.md steps 2-3)
    fit_border = params is not None and params.border == "fit"
    results, targets, vertex_info = _predict(survey, verts, photos, eos, covs, review, replace=replace,
                                             dsm_radius_m=dsm_radius_m, max_shift_m=max_shift_m, progress=progress,
                                             total=total, search_sigma=params.search_sigma if fit_border else 0.0)
    per_vertex, images = _measure_photos(survey, photos, targets, vertex_info, eos, covs, params=params,
                                         direction_from_kappa=direction_from_kappa, lone_photo=lone_photo,
                                         gallery=gallery, progress=progress, done=len(verts), total=total)
    lines3d = _edge_lines(vertex_info) if lines != "none" else {}
    block_lines: dict[tuple[str, str], str] = {}       # (line, photo) -> why the block test rejected the edge
    adjusted: dict[str, tuple[np.ndarray, np.ndarray]] = {}     # photo -> the block test's orientation, covariance
    block_info = _check_block(survey, per_vertex, eos, covs, vertex_info,
                              _block_edges(per_vertex, lines3d, lines, review.line_rejected), block_lines,
                              adjusted) if block_check else {"status": "off"}
    # the second pass (module docstring): the pairs lost at the frame or to the edges, from the block's orientation
    tried: dict[tuple[str, str], str] = {}
    if not second_pass:
        second_info: dict[str, Any] = {"status": "off"}
    elif not adjusted:
        second_info = {"status": "not run", "message": "no orientation of the block test to predict from (block "
                                                       f"test: {block_info['status']})"}
    else:
        tried = measure_again(survey, per_vertex, vertex_info, adjusted, params=params,
                              direction_from_kappa=direction_from_kappa, lone_photo=lone_photo, gallery=gallery,
                              images=images)
        n_new = sum(st == "measured" for st in tried.values())
        second_info = {"status": "ok", "tried": len(tried), "measured": n_new,
                       "rejected": sum(st == "rejected" for st in tried.values())}
        if n_new:       # the block test again, over every measurement (its verdict on the edges replaces the first's)
            block_lines.clear()
            second_info["block_check"] = _check_block(survey, per_vertex, eos, covs, vertex_info,
                                                      _block_edges(per_vertex, lines3d, lines, review.line_rejected),
                                                      block_lines)
        log.info("measure-control: second pass: %d pairs tried again, %d measured", len(tried), n_new)
    second = {(pid, vid) for (vid, pid), st in tried.items() if st in ("measured", "rejected")}
    results += _check_vertices(survey, per_vertex, vertex_info, eos, covs, min_photos)
    order = {pid: k for k, pid in enumerate(survey.photo_ids)}
    results.sort(key=lambda m: (m.point, order.get(m.photo, 0)))
    counts: dict[str, int] = {}
    for m in results:
        counts[m.status] = counts.get(m.status, 0) + 1
    pages = write_report(out, results, images, gallery, second)   # the report first
    new_lines, new_obs = _line_control(out, results, vertex_info, lines3d, lines, review, block_lines) \
        if lines != "none" else ({}, [])
    written_points = {m.point for m in results if m and lines != "only"}
    accepted = [{"photo": m.photo, "point": m.point, "px": np.asarray(m.px), "sd": m.sd_px} for m in results
                if m and lines != "only"]
    summary = {"vertices": len(verts), "photos": len(photos), "counts": counts, "accepted": len(accepted),
               "lines": lines, "control_lines": len(new_lines), "line_observations": len(new_obs),
               "points_written": len(written_points), "block_check": block_info, "second_pass": second_info,
               "gallery": pages, "params": dataclasses.asdict(params) if params is not None else "default",
               "seconds": round(time.perf_counter() - t_start, 2)}
    write_json_atomic(out / "measure_control.json", json.loads(json.dumps(summary, default=str)))
    lp = _write_tables(survey, ip_path, accepted, replace=replace, table=table, line_table=line_table,
                       new_lines=new_lines, new_obs=new_obs, vertex_info=vertex_info)
    if progress is not None:
        progress(total, total)
    log.info("measure-control: %d vertices, %d accepted observations -> %s; %d line observations", len(verts),
             len(accepted), ip_path, len(new_obs))
    return MeasureControlResult(ip_path, out, counts, len(accepted), summary, lp, len(new_obs))


def run(ctx: Context, tmp: Path) -> dict:
    """The LiDAR vertices measured into ``measure_control/image_points.csv`` (the survey's rows plus them) and the
    report; the later stages adjust that table."""
    survey = ctx["survey"]
    res = measure_control(survey, tmp, table=tmp / "image_points.csv", line_table=tmp / "line_control.csv",
                          progress=lambda done, total: ctx.progress(done, total))
    return {"counts": res.counts, "accepted": res.accepted, "line_observations": res.lines_written}
