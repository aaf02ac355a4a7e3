r"""Geometric verification of a pair's matches: the epipolar constraint with a robust estimator.

Corresponding image points of two central-perspective photos satisfy the epipolar
constraint ``b^T F a = 0`` with the fundamental matrix ``F`` (rank 2, 7 degrees of freedom).
It holds for the *ideal* pinhole image, so the matched pixels are first corrected for
distortion (eq. 01-07: :meth:`Camera.pixel_to_photo`) and scaled back to pixels,
``a = (x / t_x, -y / t_y)``: the threshold then stays in pixels.

``F`` is estimated by ``cv2.findFundamentalMat`` with MAGSAC++ (``cv2.USAC_MAGSAC``,
Barath et al. 2020: a threshold-free scoring marginalised over the noise scale, then
iteratively re-weighted least squares of the inliers); a match is an inlier when its
symmetric epipolar (Sampson) distance is within ``threshold_px`` (0.5 px of the detection level in :class:`~lidarcat.match.MatchOptions`).  A pair
with fewer than ``min_inliers`` inliers (default 15; the 7-point solution needs 7, a wrong F
fits a handful of random matches) is rejected as a whole: its matches are most likely
repeated texture.

A match that lies on its epipolar line but at the wrong place along it (repeated texture
parallel to the base) passes this test.  :func:`local_consistency` catches most of them: the
shift ``s_k = b_k - p_k`` of a match from its prediction ``p_k`` (or from its own position in A
without orientations) varies smoothly over the photo -- the orientation errors move whole
regions, the relief the surface does not model moves a point by its parallax
``c B dh / H²`` -- so a match whose shift departs from the median shift of its ``k`` nearest
matched neighbours by more than ``max(min_px, 5 · 1.4826 MAD)`` of those neighbours is
rejected.  The few that remain have no redundancy in a two-ray track; the adjustment's
data snooping names them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.camera import Camera

__all__ = ["Verification", "ideal_pixels", "verify_pair", "sampson_px", "local_consistency"]


@dataclass(frozen=True, eq=False)
class Verification:
    """Result of verifying one pair.

    Attributes
    ----------
    inlier : ndarray (m,) bool
    fundamental : ndarray (3, 3) or None
        F in ideal pixels (None when the pair is rejected before estimation).
    reason : str
        Why the pair was rejected ("" when accepted).
    """

    inlier: np.ndarray
    fundamental: np.ndarray | None
    reason: str = ""

    @property
    def accepted(self) -> bool:
        return not self.reason


def ideal_pixels(camera: Camera, colrow_px: Any) -> np.ndarray:
    """Distortion-free pixels: corrected photo coordinates over the pixel size, y down, (n, 2)."""
    xy = camera.pixel_to_photo(np.asarray(colrow_px, dtype=np.float64).reshape(-1, 2))
    return np.column_stack([xy[:, 0] / camera.pixel_size_x_mm, -xy[:, 1] / camera.pixel_size_y_mm])


def sampson_px(f: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Sampson distance (px) of correspondences a -> b (n, 2) under F (b^T F a = 0)."""
    ah = np.column_stack([a, np.ones(len(a))])
    bh = np.column_stack([b, np.ones(len(b))])
    fa = ah @ f.T
    ftb = bh @ f
    e = np.einsum("ij,ij->i", bh, fa)
    den = fa[:, 0] ** 2 + fa[:, 1] ** 2 + ftb[:, 0] ** 2 + ftb[:, 1] ** 2
    return np.abs(e) / np.sqrt(np.maximum(den, 1e-300))


def verify_pair(a_px: Any, b_px: Any, *, threshold_px: float = 1.5, min_inliers: int = 15,
                confidence: float = 0.9999, max_iters: int = 10000, seed: int = 0) -> Verification:
    """Robust fundamental matrix of matched ideal pixels and its inliers (module docstring).

    Parameters
    ----------
    a_px, b_px : (m, 2) ideal pixels of the matches in A and B (:func:`ideal_pixels`)
    threshold_px : float
        Sampson distance of an inlier, px.
    min_inliers : int
        Fewer inliers reject the pair.
    """
    import cv2

    a = np.asarray(a_px, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(b_px, dtype=np.float64).reshape(-1, 2)
    m = len(a)
    none = np.zeros(m, bool)
    if m < max(min_inliers, 8):
        return Verification(none, None, f"{m} matches, fewer than {max(min_inliers, 8)}")
    cv2.setRNGSeed(int(seed))
    o = np.vstack([a, b]).mean(axis=0)      # centred: the estimator's float32 arithmetic keeps precision
    try:
        f, mask = cv2.findFundamentalMat((a - o).astype(np.float32), (b - o).astype(np.float32), cv2.USAC_MAGSAC,
                                         float(threshold_px), float(confidence), int(max_iters))
    except cv2.error:   # degenerate input (e.g. all matches on a line): OpenCV asserts instead of returning None
        return Verification(none, None, "no fundamental matrix found (degenerate matches)")
    if f is None or mask is None or f.shape != (3, 3):
        return Verification(none, None, "no fundamental matrix found")
    # F of centred points -> F of the ideal pixels: b^T T^T F T a with T the shift by -o
    t = np.array([[1.0, 0.0, -o[0]], [0.0, 1.0, -o[1]], [0.0, 0.0, 1.0]])
    f = t.T @ f @ t
    inlier = sampson_px(f, a, b) <= threshold_px
    if inlier.sum() < min_inliers:
        return Verification(inlier, f, f"{int(inlier.sum())} inliers, fewer than {min_inliers}")
    return Verification(inlier, f)


def local_consistency(a_px: Any, shift_px: Any, *, k: int = 8, min_px: float = 3.0) -> np.ndarray:
    """Boolean (m,): the match's shift agrees with the median shift of its *k* nearest matched
    neighbours in A within ``max(min_px, 5 sigma_MAD)`` (module docstring).  Fewer than ``k + 1``
    matches: all True."""
    from scipy.spatial import cKDTree

    a = np.asarray(a_px, dtype=np.float64).reshape(-1, 2)
    s = np.asarray(shift_px, dtype=np.float64).reshape(-1, 2)
    m = len(a)
    if m <= k:
        return np.ones(m, bool)
    _, nb = cKDTree(a).query(a, k=k + 1)
    nb = nb[:, 1:]
    med = np.median(s[nb], axis=1)                                  # (m, 2)
    dev_nb = np.hypot(*(s[nb] - med[:, None, :]).transpose(2, 0, 1))  # (m, k)
    sigma = 1.4826 * np.median(dev_nb, axis=1)
    dev = np.hypot(*(s - med).T)
    return dev <= np.maximum(min_px, 5.0 * sigma)
