r"""Optional sub-pixel refinement of the tie-point observations by area correlation (NCC + quadratic fit).

A SIFT keypoint is the extremum of a difference of Gaussians: its position is as good as the
blob's scale allows, a fraction of a pixel for small blobs and worse for large ones.  Area
matching refines it against the track's reference observation (its first, on the photo of
lowest index): the reference patch is resampled into the geometry of the other photo by the
affine map of all observations the two photos share (least squares over the pair, so a
photo of the return strip, turned by 180°, is compared turned), then the normalised
cross-correlation ::

    ρ(s) = Σ (f - f̄)(g_s - ḡ_s) / sqrt(Σ (f - f̄)² Σ (g_s - ḡ_s)²)

(gain and offset free) is computed for integer shifts ``s`` within ``±search_px``
(``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``) and the peak located to a fraction of a pixel
by a parabola through it and its two neighbours on each axis,
``δ = (ρ₋ - ρ₊) / (2 (ρ₋ - 2ρ₀ + ρ₊))``.  A peak on the border of the search window, a
correlation below ``min_corr`` or a move over ``max_shift_px`` keeps the SIFT position.

(OpenCV's ``findTransformECC`` -- the least-squares matching of Gruen 1985 with the gain and
offset eliminated -- was tried first: on 21 x 21 patches of smooth aerial texture it often
diverged, so the correlation peak is used.)  Reference observations are not moved; the
refinement is relative, which is what the adjustment needs.
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
                        image: Callable[[int], np.ndarray], *, half_px: int = 10, search_px: int = 3,
                        max_shift_px: float = 1.5, min_corr: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Refined pixel positions of the observations (module docstring).

    Parameters
    ----------
    track, photo : (n,) int
    xy_px : (n, 2)
    image : callable
        ``image(photo) -> (rows, cols)`` grey image (called once per photo pair).
    half_px : int
        Template half size (``2 half + 1`` pixels a side).
    search_px : int
        Integer shifts searched on each axis.

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
    order = np.lexsort((photo, track))
    first = order[np.r_[True, track[order][1:] != track[order][:-1]]]
    ref_of_track = np.full(track.max() + 1, -1, np.int64)
    ref_of_track[track[first]] = first
    ref = ref_of_track[track]
    todo = np.flatnonzero(ref != np.arange(n))
    size = 2 * half_px + 1
    win = size + 2 * search_px
    c = np.array([half_px, half_px], np.float64)
    pairs = photo[ref[todo]] * (photo.max() + 1) + photo[todo]
    for key in np.unique(pairs):
        sel = todo[pairs == key]
        if len(sel) < 3:
            continue
        a_lin = _pair_affine(xy[ref[sel]], xy[sel])
        if not np.isfinite(a_lin).all() or abs(np.linalg.det(a_lin)) < 1e-3:
            continue
        inv = np.linalg.inv(a_lin)
        f_img = np.asarray(image(int(photo[ref[sel[0]]])), np.float32)
        g_img = np.asarray(image(int(photo[sel[0]])), np.float32)
        for k in sel:
            m = np.column_stack([inv, xy[ref[k]] - inv @ c]).astype(np.float32)
            tpl = cv2.warpAffine(f_img, m, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
            if tpl.std() < 2.0:
                continue
            region = cv2.getRectSubPix(g_img, (win, win), (float(xy[k, 0]), float(xy[k, 1])))
            rho = cv2.matchTemplate(region, tpl, cv2.TM_CCOEFF_NORMED)
            r, q = np.unravel_index(int(np.argmax(rho)), rho.shape)
            if not (0 < r < rho.shape[0] - 1 and 0 < q < rho.shape[1] - 1) or rho[r, q] < min_corr:
                continue
            shift = np.array([q + _parabola(rho[r, q - 1:q + 2]), r + _parabola(rho[r - 1:r + 2, q])]) - search_px
            if np.hypot(*shift) <= max_shift_px:
                xy[k] += shift
                moved[k] = True
    return xy, moved


def _parabola(v: np.ndarray) -> float:
    """Sub-sample offset of the maximum of a parabola through three samples (-1, 0, 1)."""
    den = v[0] - 2.0 * v[1] + v[2]
    return float(0.5 * (v[0] - v[2]) / den) if den < 0 else 0.0
