"""The adjustments of the block test: its observations in photo coordinates, one bundle problem per round.

Private to :mod:`lidarcat.photocontrol` (:func:`~lidarcat.photocontrol.blockcheck.check_block` builds one
:class:`BlockModel` and adjusts it once per round; its module docstring, "The model", gives the method):

* :meth:`BlockModel.of` -- the fixed inputs turned into photo coordinates once: the tie observations kept by
  :func:`~lidarcat.photocontrol._block_ties.prepared_ties`, the vertex measurements adjusted (their covariance
  replaced by the diagonal that dominates it, :func:`~lidarcat.photocontrol._block_ties.dominant_sd`, plus a
  floor), the roof edges' two equivalent points and their 3-D lines (one per line id);
* :meth:`BlockModel.problem` -- the :class:`~lidarcat.bundle.problem.BundleProblem` of the kept ties, the vertex
  measurements and edges still in (the approximate orientations weighted, the LiDAR vertices as weighted control
  points, the edges as :class:`~lidarcat.bundle.lines.LineControl`);
* :meth:`BlockModel.solve` -- its adjustment from a warm start (a block held by few lines, which converges slowly,
  continued for four times the iterations).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ._block_ties import dominant_sd

__all__ = ["TIE", "VERTEX", "BlockModel", "vertex_photo_coordinates"]

TIE, VERTEX = "t:", "v:"      # internal point-id prefixes (a tie id may equal a vertex id)


def vertex_photo_coordinates(ms: Sequence[Any], cameras: Mapping[str, Any], floor_sd_px: float
                             ) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) photo coordinates (mm) of the measurements and (N, 2) the sds of the diagonal that dominates
    their covariance (plus *floor_sd_px* in quadrature, px), mm."""
    v_xy = np.zeros((len(ms), 2))
    v_sd = np.zeros((len(ms), 2))
    for i, m in enumerate(ms):
        cam = cameras[m.photo]
        j = np.asarray(cam.pixel_to_photo_jacobian(np.asarray(m.px)[None]))[0]
        c = np.asarray(m.cov_px2, float) + np.eye(2) * float(floor_sd_px) ** 2
        v_xy[i] = cam.pixel_to_photo(np.asarray(m.px, float)[None])[0]
        v_sd[i] = dominant_sd(j @ c @ j.T)
    return v_xy, v_sd


@dataclasses.dataclass(frozen=True, eq=False)
class BlockModel:
    """The block test's observations in photo coordinates (module docstring); rows: ties ``t_*`` (all given,
    *t_keep* the ones kept), vertex measurements ``v_*`` (the adjusted ones, in order), edges ``e_*``."""

    cameras: Mapping[str, Any]
    eos: Mapping[str, Any]
    eo_covs: Mapping[str, Any]
    vertices_m: Mapping[str, Any]
    vertex_covs: Mapping[str, Any]
    max_iter: int
    ties: Any
    t_xy: np.ndarray
    t_sd: np.ndarray
    t_keep: np.ndarray
    t_photo: np.ndarray
    v_xy: np.ndarray
    v_sd: np.ndarray
    v_photo: np.ndarray
    v_point: np.ndarray
    edges: list
    e_photo: np.ndarray
    line_ids: list
    first: dict
    e_pix: np.ndarray
    e_xy1: np.ndarray
    e_xy2: np.ndarray
    floor_sd_px: float = 0.0

    @classmethod
    def of(cls, ms: Sequence[Any], edges: list, ties: Any, prepared: tuple, cameras: Mapping[str, Any],
           eos: Mapping[str, Any], eo_covs: Mapping[str, Any], vertices_m: Mapping[str, Any],
           vertex_covs: Mapping[str, Any], floor_sd_px: float, max_iter: int) -> "BlockModel":
        """The model of the adjusted vertex measurements *ms*, the *edges* and the *ties* (*prepared*: their
        ``(xy_mm, sd_mm, keep)`` of :func:`~lidarcat.photocontrol._block_ties.prepared_ties`)."""
        t_xy, t_sd, t_keep = prepared
        v_xy, v_sd = vertex_photo_coordinates(ms, cameras, floor_sd_px)
        n_e = len(edges)
        line_ids = list(dict.fromkeys(e.line for e in edges))
        return cls(
            cameras, eos, eo_covs, vertices_m, vertex_covs, max_iter, ties, t_xy, t_sd, t_keep,
            ties.photo if ties is not None and len(ties) else np.zeros(0, dtype=object), v_xy, v_sd,
            np.array([m.photo for m in ms], dtype=object), np.array([m.point for m in ms], dtype=object),
            edges, np.array([e.photo for e in edges], dtype=object), line_ids,
            {lid: next(e for e in edges if e.line == lid) for lid in line_ids},
            np.array([0.5 * (cameras[e.photo].pixel_size_x_mm + cameras[e.photo].pixel_size_y_mm)
                      for e in edges]).reshape(n_e),
            np.array([cameras[e.photo].pixel_to_photo(np.asarray(e.p1_px)[None])[0] for e in edges]).reshape(n_e, 2),
            np.array([cameras[e.photo].pixel_to_photo(np.asarray(e.p2_px)[None])[0] for e in edges]).reshape(n_e, 2),
            float(floor_sd_px))

    def ties_on(self, photos: Any) -> dict[str, int]:
        """Tie observations kept on each of *photos*."""
        return {p: int(np.sum(self.t_keep & (self.t_photo == p))) for p in photos}

    def problem(self, v_in: np.ndarray, e_in: np.ndarray) -> tuple[Any, np.ndarray]:
        """The block of the kept ties, the vertex measurements *v_in* and the edges *e_in*; the photo ids."""
        from ..bundle import BundleProblem
        from ..bundle.lines import LineControl

        n_t = 0 if self.ties is None else len(self.ties)
        ties, t_keep, edges = self.ties, self.t_keep, self.edges
        tp = self.t_photo[t_keep] if n_t else np.zeros(0, dtype=object)
        photos = sorted(set(tp.tolist()) | set(self.v_photo[v_in].tolist()) | set(self.e_photo[e_in].tolist()))
        pos = {p: i for i, p in enumerate(photos)}
        verts = sorted(set(self.v_point[v_in].tolist()))
        tie_ids = sorted(set((TIE + ties.point[t_keep].astype(str)).tolist())) if n_t else []
        pt_ids = tie_ids + [VERTEX + v for v in verts]
        ppos = {q: i for i, q in enumerate(pt_ids)}
        ph_idx = [pos[p] for p in tp] + [pos[p] for p in self.v_photo[v_in]]
        pt_idx = ([ppos[TIE + str(q)] for q in ties.point[t_keep]] if n_t else []) + \
            [ppos[VERTEX + v] for v in self.v_point[v_in]]
        xy = np.concatenate([self.t_xy[t_keep], self.v_xy[v_in]])
        sd = np.concatenate([self.t_sd[t_keep], self.v_sd[v_in]])
        lc = None
        if e_in.any():
            ei = np.flatnonzero(e_in)
            lc = LineControl(line_ids=self.line_ids, a_m=[self.first[q].a_m for q in self.line_ids],
                             b_m=[self.first[q].b_m for q in self.line_ids],
                             cov_m2=[self.first[q].cov_m2 for q in self.line_ids],
                             line_index=[self.line_ids.index(edges[k].line) for k in ei],
                             photo_index=[pos[edges[k].photo] for k in ei], xy1_mm=self.e_xy1[ei],
                             xy2_mm=self.e_xy2[ei], sd_mm=[edges[k].sd_px * self.e_pix[k] for k in ei],
                             pixel_mm=self.e_pix[ei])
        cameras, eos, eo_covs = self.cameras, self.eos, self.eo_covs
        prob = BundleProblem(
            photo_ids=photos, point_ids=pt_ids, focal_length_mm=[cameras[p].focal_length_mm for p in photos],
            photo_index=np.asarray(ph_idx, dtype=np.int64), point_index=np.asarray(pt_idx, dtype=np.int64),
            xy_mm=xy.reshape(-1, 2), sd_mm=sd.reshape(-1, 2),
            constraint_point_index=np.array([ppos[VERTEX + v] for v in verts], dtype=np.int64),
            constraint_enh_m=np.array([np.asarray(self.vertices_m[v], float).reshape(3) for v in verts]).reshape(-1, 3),
            constraint_sd_m=np.array([dominant_sd(np.asarray(self.vertex_covs[v], float).reshape(3, 3))
                                      for v in verts]).reshape(-1, 3),
            eo_constraint_photo_index=np.arange(len(photos)),
            eo_constraint_params=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]),
            eo_constraint_sd=np.array([dominant_sd(np.asarray(eo_covs[p], float).reshape(6, 6)) for p in photos]),
            lines=lc)
        return prob, np.asarray(photos, dtype=object)

    def solve(self, prob: Any, photos: np.ndarray, warm: dict[str, np.ndarray], precision: str = "none") -> Any:
        """The adjustment of *prob* from *warm* (photo -> (6,); the others from the approximate orientation)."""
        from ..bundle import adjust
        from ..bundle.approx import intersect_points

        eo0 = np.array([warm.get(p, np.asarray(self.eos[p], float).reshape(6)) for p in photos])
        if prob.lines is not None and precision == "none":
            precision = "photos"                 # the line tests need the photos' covariances
        res = adjust(prob, initial=(eo0, intersect_points(prob, eo0)), check=False, precision=precision,
                     max_iter=self.max_iter)
        if not res.success and prob.lines is not None:    # a block held by few lines converges slowly
            res = adjust(prob, initial=(np.asarray(res.eo_params), np.asarray(res.points_m)), check=False,
                         precision=precision, max_iter=4 * self.max_iter)
        return res
