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
(OpenCV's ``TM_CCOEFF_NORMED``) and the peak located to a fraction of a pixel
by a parabola through it and its two neighbours on each axis,
``δ = (ρ₋ - ρ₊) / (2 (ρ₋ - 2ρ₀ + ρ₊))``.  A peak on the border of the search window, a
correlation below ``min_corr`` or a move over ``max_shift_px`` keeps the SIFT position.

The observations of a photo pair are processed together: templates and search regions are
resampled by one bilinear ``cv2.remap`` per 1,000 observations, ``ρ`` for all shifts comes from
``(2 search + 1)²`` batched products and the window sums of an integral image.

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
    grid = np.stack(np.meshgrid(np.arange(size, dtype=np.float64), np.arange(size, dtype=np.float64)), -1)
    gwin = np.stack(np.meshgrid(np.arange(win, dtype=np.float64), np.arange(win, dtype=np.float64)), -1)
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
        # template pixel (col, row) = reference + inv ((col, row) - centre); region around the SIFT position
        off_t = (grid - half_px) @ inv.T
        off_g = gwin - (win - 1) / 2.0
        for s0 in range(0, len(sel), _CHUNK):
            k = sel[s0:s0 + _CHUNK]
            tpl = _sample(f_img, xy[ref[k]], off_t, cv2.BORDER_CONSTANT)
            region = _sample(g_img, xy[k], off_g, cv2.BORDER_REPLICATE)
            shift, ok = _ncc_peak(tpl, region, search_px, min_corr)
            ok &= np.hypot(shift[:, 0], shift[:, 1]) <= max_shift_px
            xy[k[ok]] += shift[ok]
            moved[k[ok]] = True
    return xy, moved


#: observations resampled in one call (the remap of OpenCV takes fewer than 32,767 rows)
_CHUNK = 1000


def _sample(img: np.ndarray, xy: np.ndarray, offsets: np.ndarray, border: int) -> np.ndarray:
    """Bilinear samples of *img* at ``xy[k] + offsets`` (h, w, 2), shape (K, h, w), one ``cv2.remap``."""
    import cv2

    h, w = offsets.shape[:2]
    mx = (xy[:, None, None, 0] + offsets[None, :, :, 0]).astype(np.float32).reshape(-1, w)
    my = (xy[:, None, None, 1] + offsets[None, :, :, 1]).astype(np.float32).reshape(-1, w)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    return out.reshape(len(xy), h, w).astype(np.float64)


def _ncc_peak(tpl: np.ndarray, region: np.ndarray, search_px: int,
              min_corr: float) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel shift (K, 2) of the NCC peak of each template in its region, and where it is valid.

    ``ρ`` for every integer shift at once (sliding windows, ``TM_CCOEFF_NORMED``); invalid: a flat
    template (sd < 2 grey levels), the peak on the window's border or below *min_corr*.
    """
    n = tpl.shape[1] * tpl.shape[2]
    t = tpl - tpl.mean(axis=(1, 2), keepdims=True)
    tt = np.einsum("kij,kij->k", t, t)
    h, w = tpl.shape[1:]
    m = region.shape[1] - h + 1
    num = np.empty((len(t), m, m))
    for a in range(m):             # (2 search + 1)² products over all observations at once
        for b in range(m):
            num[:, a, b] = np.einsum("kij,kij->k", region[:, a:a + h, b:b + w], t)
    s1 = _box_sums(region, h, w)
    s2 = _box_sums(region * region, h, w)
    with np.errstate(all="ignore"):
        rho = num / np.sqrt(tt[:, None, None] * np.maximum(s2 - s1 * s1 / n, 0.0))
    rho = np.where(np.isfinite(rho), rho, -np.inf)
    flat = rho.reshape(len(rho), -1)
    best = np.argmax(flat, axis=1)
    r, q = np.divmod(best, m)
    peak = flat[np.arange(len(flat)), best]
    ok = (tt / n >= 4.0) & (r > 0) & (r < m - 1) & (q > 0) & (q < m - 1) & (peak >= min_corr)
    rc, qc = np.clip(r, 1, m - 2), np.clip(q, 1, m - 2)
    kk = np.arange(len(rho))
    dq = _parabola_v(rho[kk, rc, qc - 1], rho[kk, rc, qc], rho[kk, rc, qc + 1])
    dr = _parabola_v(rho[kk, rc - 1, qc], rho[kk, rc, qc], rho[kk, rc + 1, qc])
    return np.column_stack([q + dq, r + dr]) - search_px, ok


def _box_sums(x: np.ndarray, h: int, w: int) -> np.ndarray:
    """Sums of every h x w window of each image of *x* (K, H, W) by an integral image, (K, H-h+1, W-w+1)."""
    c = np.zeros((x.shape[0], x.shape[1] + 1, x.shape[2] + 1))
    c[:, 1:, 1:] = x.cumsum(axis=1).cumsum(axis=2)
    return c[:, h:, w:] - c[:, :-h, w:] - c[:, h:, :-w] + c[:, :-h, :-w]


def _parabola_v(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray) -> np.ndarray:
    """:func:`_parabola` of many triples."""
    den = v0 - 2.0 * v1 + v2
    with np.errstate(all="ignore"):
        out = 0.5 * (v0 - v2) / den
    return np.where((den < 0) & np.isfinite(out), out, 0.0)


def _parabola(v: np.ndarray) -> float:
    """Sub-sample offset of the maximum of a parabola through three samples (-1, 0, 1)."""
    den = v[0] - 2.0 * v[1] + v[2]
    return float(0.5 * (v[0] - v[2]) / den) if den < 0 else 0.0
