"""The tie points of the block test: in photo coordinates, cleaned on their own.

Private to :mod:`lidarcat.photocontrol` (:func:`~lidarcat.photocontrol.blockcheck.check_block` uses it; its
module docstring, "Tie points", gives the method): :func:`prepared_ties` turns the
:class:`~lidarcat.photocontrol.blockcheck.TieObservations` into corrected photo coordinates (pixels through the
camera; a survey's photo coordinates as they are), drops the points with fewer than two rays and the photos with
fewer than three tie observations (:func:`clean_ties`, repeated until stable), and runs the ties' own block --
the approximate orientations as its datum -- through the engine's data snooping with its robust start
(:func:`snoop_tie_block`).  :func:`dominant_sd` is the diagonal that dominates a covariance (the engine weighs per
axis).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..errors import DatumError

__all__ = ["dominant_sd", "clean_ties", "snoop_tie_block", "prepared_ties"]

log = logging.getLogger(__name__)


def dominant_sd(cov: np.ndarray) -> np.ndarray:
    """(..., k) sds of the diagonal D, D_kk = sum_l |C_kl|, that dominates the covariance C (..., k, k)."""
    return np.sqrt(np.sum(np.abs(cov), axis=-1))


def clean_ties(photo: np.ndarray, point: np.ndarray, keep: np.ndarray | None = None, min_rays: int = 2,
                min_per_photo: int = 3) -> np.ndarray:
    """(n,) bool: of the tie observations *keep* (default all), those of points with >= *min_rays* photos on
    photos with >= *min_per_photo* of them (repeated until stable)."""
    keep = np.ones(len(photo), dtype=bool) if keep is None else np.array(keep, dtype=bool)
    while keep.any():
        _, pinv, pcount = np.unique(point[keep], return_inverse=True, return_counts=True)
        k1 = keep.copy()
        k1[keep] = pcount[pinv] >= min_rays
        _, finv, fcount = np.unique(photo[k1], return_inverse=True, return_counts=True) if k1.any() else \
            (None, np.zeros(0, int), np.zeros(0, int))
        k2 = k1.copy()
        k2[k1] = fcount[finv] >= min_per_photo
        if np.array_equal(k2, keep):
            break
        keep = k2
    return keep


def snoop_tie_block(ties: Any, keep: np.ndarray, cameras, eos, eo_covs, xy_mm, sd_mm
                ) -> tuple[np.ndarray, dict[str, np.ndarray], str]:
    """The ties' own block (approximate orientations as the datum) through the engine's data snooping with
    its robust start; returns the kept mask, the adjusted orientations and a note."""
    from ..bundle import BundleProblem
    from ..bundle.reliability import snoop

    idx = np.flatnonzero(keep)
    photos = sorted(set(ties.photo[idx].tolist()))
    ph_pos = {p: i for i, p in enumerate(photos)}
    pts, pt_index = np.unique(ties.point[idx].astype(str), return_inverse=True)
    prob = BundleProblem(
        photo_ids=photos, point_ids=pts, focal_length_mm=[cameras[p].focal_length_mm for p in photos],
        photo_index=[ph_pos[p] for p in ties.photo[idx]], point_index=pt_index, xy_mm=xy_mm[idx], sd_mm=sd_mm[idx],
        constraint_point_index=np.zeros(0, int), constraint_enh_m=np.zeros((0, 3)), constraint_sd_m=np.zeros((0, 3)),
        eo_constraint_photo_index=np.arange(len(photos)),
        eo_constraint_params=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]),
        eo_constraint_sd=np.array([dominant_sd(np.asarray(eo_covs[p], float).reshape(6, 6)) for p in photos]),
        initial_eo=np.array([np.asarray(eos[p], float).reshape(6) for p in photos]))
    try:
        sr = snoop(prob, mode="remove", start="robust", precision="none")
    except DatumError as ex:
        log.warning("block check: the tie points' robust start failed (%s); snooping from least squares", ex)
        try:
            sr = snoop(prob, mode="remove", start="plain", precision="none")
        except DatumError as ex2:
            return np.zeros(len(keep), dtype=bool), {}, f"tie points left out: {ex2}"
    out = keep.copy()
    gone = {(b.photo, b.point) for b in sr.blunders if b.kind == "image" and b.removed}
    for k in idx:
        if (str(ties.photo[k]), str(ties.point[k])) in gone:
            out[k] = False
    eo = {}
    if sr.result is not None and np.isfinite(np.asarray(sr.result.eo_params)).all():
        eo = {p: np.asarray(sr.result.eo_params)[i] for i, p in enumerate(photos)}
    return clean_ties(ties.photo, ties.point, out), eo, ""


def prepared_ties(ties: Any, cameras: Mapping[str, Any], eos: Mapping[str, Any],
                   eo_covs: Mapping[str, Any], snoop_ties: bool) -> tuple:
    """The tie observations in photo coordinates (mm; pixels through the camera) with their sds, the kept mask
    (points on >= 2 photos, photos with >= 3 ties, snooped on their own when *snoop_ties*), the ties' adjusted
    orientations (a warm start), a note, and the counts rejected by snooping and dropped by the ray rules."""
    n_t = 0 if ties is None else len(ties)
    t_xy = np.zeros((n_t, 2))
    t_sd = np.zeros((n_t, 2))
    if n_t and ties.xy_mm is not None:          # the survey's corrected photo coordinates, as they are
        t_xy, t_sd = np.array(ties.xy_mm), np.array(ties.sd_mm)
    for pid in sorted(set(ties.photo.tolist())) if n_t and ties.xy_mm is None else []:
        sel = ties.photo == pid
        cam = cameras[pid]
        t_xy[sel] = cam.pixel_to_photo(ties.px[sel])
        t_sd[sel] = cam.photo_sd(ties.px[sel], np.repeat(ties.sd_px[sel, None], 2, axis=1))
    t_keep = clean_ties(ties.photo, ties.point) if n_t else np.zeros(0, dtype=bool)
    dropped = int(n_t - t_keep.sum())
    start: dict[str, np.ndarray] = {}
    note = ""
    n_tie_rej = 0
    if t_keep.any() and snoop_ties:
        k0 = int(t_keep.sum())
        t_keep, start, note = snoop_tie_block(ties, t_keep, cameras, eos, eo_covs, t_xy, t_sd)
        n_tie_rej = k0 - int(t_keep.sum())
    return t_xy, t_sd, t_keep, start, note, n_tie_rej, dropped
