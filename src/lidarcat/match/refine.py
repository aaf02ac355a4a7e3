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

Precision of a refined observation (:func:`refine_with_precision`)
-----------------------------------------------------------------
The correlation peak is the least-squares match of the template ``f`` and the search image
``g`` for a pure shift (with gain and offset free): linearised at the peak,
``g(x + δ) - (a f(x) + b) = e``, the normal equations of ``δ`` are the structure tensor of the
template's grey-value gradients ``∇f = (f_x, f_y)`` (central differences),

.. math::  N = \sum_{\text{window}} \nabla f \, \nabla f^T , \qquad
           \Sigma_\delta = \hat\sigma_e^2 \, N^{-1}

(Förstner 1982; Ackermann 1984: the precision of least-squares matching).  The residual
variance per pixel follows from the correlation itself: the regression of ``g`` on ``f`` leaves
``σ_e² = (1 - ρ²) var(f)`` of the template's variance, so

.. math::  \Sigma_\delta = (1 - \rho^2) \, \frac{\sum (f - \bar f)^2}{n} \, N^{-1} ,

small for a high correlation and a template with strong gradients in both directions, large
along an edge (``N`` nearly singular) or on smooth texture.  The sds written are the square
roots of its diagonal, in pixels of the searched photo.  The white-noise model behind the
formula ignores what the residuals of real patches are made of (resampling, relief inside the
window, the parabola's bias), so :data:`PRECISION_SCALE` multiplies it and :data:`PRECISION_FLOOR_PX`
is added in quadrature, both calibrated on rendered blocks against the true position
(``benchmarks/bench_photos_to_block.py``, docs/match.md "Precision").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["refine_observations", "refine_with_precision", "Refinement", "PRECISION_SCALE", "PRECISION_FLOOR_PX",
           "SIFT_SD_PX", "REFERENCE_SHARE", "observation_sds"]

#: factor of the least-squares-matching sd (module docstring), calibrated on rendered blocks: the rms
#: truth error per axis of the refined observations over the rms of their formula sds, 2.7-2.85 in
#: every sd class from 0.017 to 0.05 px (aerial_survey seed 0, 1000 x 750 px, 10,571 observations)
PRECISION_SCALE = 2.8
#: added in quadrature to every refined observation's sd, px (a correlation of 1 gives a formula sd of 0)
PRECISION_FLOOR_PX = 0.01
#: sd of an observation at its SIFT position (not refined), px (median SIFT error 0.15 px, docs/match.md)
SIFT_SD_PX = 0.2
#: a track's reference gets this share of the median sd of its refined partners (module docstring)
REFERENCE_SHARE = 0.5


@dataclass(frozen=True, eq=False)
class Refinement:
    """Refined observations and their precision (:func:`refine_with_precision`).

    Attributes
    ----------
    xy_px : (n, 2) float
        Refined positions (the others as given).
    moved : (n,) bool
        Observations refined.
    sd_px : (n, 2) float
        Sd of the refined position relative to the track's reference, px (x = column, y = row);
        NaN where not refined (references and the observations the refinement kept).
    corr : (n,) float
        Peak correlation (NaN where not refined).
    """

    xy_px: np.ndarray
    moved: np.ndarray
    sd_px: np.ndarray
    corr: np.ndarray


def _pair_affine(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Linear part (2, 2) of the least-squares affine map src -> dst."""
    a = np.column_stack([src - src.mean(axis=0), np.ones(len(src))])
    sol, *_ = np.linalg.lstsq(a, dst - dst.mean(axis=0), rcond=None)
    return sol[:2].T


def refine_observations(track: np.ndarray, photo: np.ndarray, xy_px: np.ndarray,
                        image: Callable[[int], np.ndarray], *, half_px: int = 10, search_px: int = 3,
                        max_shift_px: float = 1.5, min_corr: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Refined pixel positions of the observations and which moved (:func:`refine_with_precision`)."""
    r = refine_with_precision(track, photo, xy_px, image, half_px=half_px, search_px=search_px,
                              max_shift_px=max_shift_px, min_corr=min_corr)
    return r.xy_px, r.moved


def refine_with_precision(track: np.ndarray, photo: np.ndarray, xy_px: np.ndarray,
                          image: Callable[[int], np.ndarray], *, half_px: int = 10, search_px: int = 3,
                          max_shift_px: float = 1.5, min_corr: float = 0.8) -> Refinement:
    """Refined pixel positions of the observations and their sds (module docstring).

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
    Refinement
    """
    import cv2

    track = np.asarray(track, np.int64)
    photo = np.asarray(photo, np.int64)
    xy = np.asarray(xy_px, dtype=np.float64).copy()
    n = len(track)
    moved = np.zeros(n, bool)
    sd = np.full((n, 2), np.nan)
    corr = np.full(n, np.nan)
    if n == 0:
        return Refinement(xy, moved, sd, corr)
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
            shift, ok, peak = _ncc_peak(tpl, region, search_px, min_corr)
            ok &= np.hypot(shift[:, 0], shift[:, 1]) <= max_shift_px
            xy[k[ok]] += shift[ok]
            moved[k[ok]] = True
            sd[k[ok]] = _lsm_sd(tpl[ok], peak[ok])
            corr[k[ok]] = peak[ok]
    return Refinement(xy, moved, sd, corr)


def _lsm_sd(tpl: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """(K, 2) sds of the shift of each template (K, h, w) matched with correlation *rho* (module docstring):
    ``sqrt(diag((1 - rho^2) var(f) N^-1)) * PRECISION_SCALE`` with the floor added in quadrature."""
    if len(tpl) == 0:
        return np.zeros((0, 2))
    fy, fx = np.gradient(tpl, axis=(1, 2))
    fx, fy = fx[:, 1:-1, 1:-1], fy[:, 1:-1, 1:-1]               # central differences only
    nxx = np.einsum("kij,kij->k", fx, fx)
    nyy = np.einsum("kij,kij->k", fy, fy)
    nxy = np.einsum("kij,kij->k", fx, fy)
    det = nxx * nyy - nxy * nxy
    var = np.var(tpl, axis=(1, 2))
    s2 = (1.0 - np.clip(rho, -1.0, 1.0) ** 2) * var
    with np.errstate(all="ignore"):
        cov = np.column_stack([nyy, nxx]) / det[:, None] * s2[:, None]
    sd = np.sqrt(np.where(np.isfinite(cov) & (cov >= 0), cov, np.inf)) * PRECISION_SCALE
    return np.sqrt(sd ** 2 + PRECISION_FLOOR_PX ** 2)


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
              min_corr: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sub-pixel shift (K, 2) of the NCC peak of each template in its region, where it is valid, and the
    peak correlation (K,) interpolated by the two parabolas.

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
    # the parabola's value at its vertex: rho_0 - (rho_- - rho_+) delta / 4, per axis
    top = rho[kk, rc, qc] - 0.25 * ((rho[kk, rc, qc - 1] - rho[kk, rc, qc + 1]) * dq
                                    + (rho[kk, rc - 1, qc] - rho[kk, rc + 1, qc]) * dr)
    top = np.where(np.isfinite(top), np.minimum(top, 1.0), peak)
    return np.column_stack([q + dq, r + dr]) - search_px, ok, top


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


def observation_sds(track: np.ndarray, photo: np.ndarray, refined_sd_px: np.ndarray | None, *,
                    sift_sd_px: float = SIFT_SD_PX) -> np.ndarray:
    """The a priori sd (n, 2) of every observation of the tracks, px.

    A refined observation: its least-squares-matching sd (:class:`Refinement`); one left at its
    SIFT position: *sift_sd_px*; a track's reference (the template of its refined observations,
    never moved itself): :data:`REFERENCE_SHARE` of the median sd of the refined observations of
    its track, or *sift_sd_px* when none of them was refined.  The reference has no matching error
    of its own relative to the ground point it defines (the refined errors are relative to it), so
    its full partners' sd would count the matching error twice; a much smaller sd would make its
    residual untestable (redundancy ~ 0), and a wrong reference could not be named.

    Parameters
    ----------
    track, photo : (n,) int
        As given to :func:`refine_with_precision` (the reference is a track's observation on the photo
        of lowest index).
    refined_sd_px : (n, 2) float or None
        :attr:`Refinement.sd_px` (NaN where not refined); None: nothing refined.
    """
    track = np.asarray(track, np.int64)
    n = len(track)
    out = np.full((n, 2), float(sift_sd_px))
    if refined_sd_px is None or n == 0:
        return out
    sd = np.asarray(refined_sd_px, float)
    ok = np.isfinite(sd).all(axis=1)
    out[ok] = sd[ok]
    order = np.lexsort((np.asarray(photo, np.int64), track))
    ref = order[np.r_[True, track[order][1:] != track[order][:-1]]]   # the references, as refined
    is_ref = np.zeros(n, bool)
    is_ref[ref] = ~ok[ref]
    if ok.any() and is_ref.any():
        # median of the refined sds of each track (per axis), by sorting within tracks
        for axis in (0, 1):
            t, v = track[ok], sd[ok, axis]
            o = np.lexsort((v, t))
            t, v = t[o], v[o]
            start = np.searchsorted(t, np.unique(t))
            cnt = np.diff(np.r_[start, len(t)])
            med = 0.5 * (v[start + (cnt - 1) // 2] + v[start + cnt // 2])
            pos = np.searchsorted(np.unique(t), track[is_ref])
            has = (pos < len(start)) & (np.unique(t)[np.minimum(pos, len(start) - 1)] == track[is_ref])
            rows = np.flatnonzero(is_ref)[has]
            out[rows, axis] = REFERENCE_SHARE * med[pos[has]]
    return out
