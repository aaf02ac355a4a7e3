r"""Optional least-squares refinement of the tie-point observations (sub-pixel), by area matching.

A SIFT keypoint is the extremum of a difference of Gaussians: its position is as good as the
blob's scale allows, a fraction of a pixel for small blobs and worse for large ones.  Least-
squares matching (Gruen 1985) refines it: the patch ``g`` around an observation in photo ``q``
is warped onto the template ``f`` around the track's reference observation in photo ``p``
(the observation on the photo with the most observations of the track, its first) by an
affine map ``W``, minimising ::

    Σ_x ( f(x) - (α g(W(x)) + β) )²        (radiometric gain α and offset β eliminated)

OpenCV's ``findTransformECC`` (Evangelidis & Psarakis 2008) maximises the enhanced correlation
coefficient, which is the same criterion with the gain and offset eliminated by normalising
both patches.  The initial warp's linear part is the affine map of all the observations the
two photos share (least squares over the pair, so a photo of the return strip, turned by
180°, starts turned), its translation zero; the refined observation is ``W(c)`` for the
patch centre ``c``.  A refinement that does not converge, moves the point by more than
``max_shift_px``, or ends with a correlation below ``min_corr`` keeps the SIFT position.

Reference observations are not moved (the track's point is defined by them), so the
refinement is a relative one -- what the adjustment needs.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["refine_observations"]


def _pair_affine(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Linear part (2, 2) of the least-squares affine map src -> dst."""
    a = np.column_stack([src - src.mean(axis=0), np.ones(len(src))])
    sol, *_ = np.linalg.lstsq(a, dst - dst.mean(axis=0), rcond=None)
    return sol[:2].T


def refine_observations(track: np.ndarray, photo: np.ndarray, xy_px: np.ndarray,
                        image: Callable[[int], np.ndarray], *, half_px: int = 10, max_shift_px: float = 1.5,
                        min_corr: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Refined pixel positions of the observations (module docstring).

    Parameters
    ----------
    track, photo : (n,) int
    xy_px : (n, 2)
    image : callable
        ``image(photo) -> (rows, cols) uint8`` grey image (called once per photo pair).
    half_px : int
        Patch half size (patch ``2 half + 1`` pixels a side).

    Returns
    -------
    xy : (n, 2) refined positions
    moved : (n,) bool
        Observations refined (others kept their position).
    """
    import cv2

    track = np.asarray(track, np.int64)
    photo = np.asarray(photo, np.int64)
    xy = np.asarray(xy_px, dtype=np.float64).copy()
    n = len(track)
    moved = np.zeros(n, bool)
    if n == 0:
        return xy, moved
    # reference of each track: its first observation
    order = np.lexsort((photo, track))
    first = order[np.r_[True, track[order][1:] != track[order][:-1]]]
    ref_of_track = np.full(track.max() + 1, -1, np.int64)
    ref_of_track[track[first]] = first
    ref = ref_of_track[track]
    todo = np.flatnonzero(ref != np.arange(n))
    size = 2 * half_px + 1
    c = np.array([half_px, half_px], np.float64)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    pairs = photo[ref[todo]] * (photo.max() + 1) + photo[todo]
    for key in np.unique(pairs):
        sel = todo[pairs == key]
        p, q = int(photo[ref[sel[0]]]), int(photo[sel[0]])
        if len(sel) < 3:
            continue
        a_lin = _pair_affine(xy[ref[sel]], xy[sel])
        if not np.isfinite(a_lin).all() or abs(np.linalg.det(a_lin)) < 1e-3:
            continue
        f_img = np.asarray(image(p), np.float32)
        g_img = np.asarray(image(q), np.float32)
        for k in sel:
            tpl = cv2.getRectSubPix(f_img, (size, size), tuple(map(float, xy[ref[k]])))
            inp = cv2.getRectSubPix(g_img, (size, size), tuple(map(float, xy[k])))
            if tpl.std() < 2.0:
                continue
            warp = np.zeros((2, 3), np.float32)
            warp[:, :2] = a_lin
            warp[:, 2] = c - a_lin @ c
            try:
                corr, warp = cv2.findTransformECC(tpl, inp, warp, cv2.MOTION_AFFINE, crit, None, 5)
            except cv2.error:
                continue
            shift = warp[:, :2].astype(np.float64) @ c + warp[:, 2] - c
            if corr >= min_corr and np.hypot(*shift) <= max_shift_px:
                xy[k] += shift
                moved[k] = True
    return xy, moved
