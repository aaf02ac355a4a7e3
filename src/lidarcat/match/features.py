r"""SIFT features of one photo, on the pyramid level that suits the photo scale.

Detection runs OpenCV's SIFT (Lowe 2004; ``cv2.SIFT_create``) on the photo reduced by
``2^level`` (``cv2.pyrDown``, a 5x5 Gaussian then every second pixel).  Level 0 is the full
photo; :func:`pyramid_level` picks the smallest level whose long side is at most
``max_side_px`` (default 4,000 px): a 24-MP aerial frame is matched at level 1, where SIFT
keeps about the same well-spread points in a quarter of the time.  A keypoint found at
``(c', r')`` of level ``L`` lies at ::

    C = 2^L (c' + 0.5) - 0.5,   L_row = 2^L (r' + 0.5) - 0.5

in the full photo (pixel centres at integers, as :mod:`lidarcat.geometry.camera`).

Twin keypoints: SIFT assigns a keypoint a second (third) orientation when its gradient histogram
has another peak within 80 % of the highest (Lowe 2004, section 5), so about a fifth of OpenCV's
keypoints share their position with another.  All are kept and matched (the orientation that a
photo lists first depends on its rotation: keeping only the first loses 15-20 % of the matches
between strips flown in opposite directions); :func:`lidarcat.match.tracks.build_tracks` makes
the twins one node, so that they give one track, not two with the same errors.
``unique_positions`` keeps one keypoint per position at detection (off).

Keypoints larger than ``max_size_px`` (diameter at the detection level) are dropped: measured
on the rendered test block, the observations of keypoints over 15 px are within 1 px of truth
in 93 % of cases against 99.4 % for 3-15 px.  At most ``max_features`` keypoints are kept, the strongest responses first, spread over
the frame by a grid of 8 x 8 cells that each keep their share (a textured corner must not
take all of them).  Descriptors are stored as ``uint8`` (OpenCV's SIFT values are
``min(round(512 v), 255)`` of the normalised descriptor), 128 bytes a keypoint: 8,000
keypoints are 1 MB, so the memory of a block's matching is bounded by two photos at a time.

The engine keeps no file: the stage (:mod:`lidarcat.stages.match`) caches each photo's
features on disk (``lidarcat.stages._feature_cache``) and hands them to the engine.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["Features", "FeatureOptions", "detect", "pyramid_level", "read_image", "grey8"]

_GRID = 8


@dataclass(frozen=True)
class FeatureOptions:
    """Detection options.

    Attributes
    ----------
    max_features : int
        Keypoints kept per photo (strongest first, spread over an 8 x 8 grid).
    level : int or None
        Pyramid level (0 = full resolution); None: :func:`pyramid_level` of *max_side_px*.
    max_side_px : int
        Long side of the detection image when *level* is None.
    contrast_threshold : float
        SIFT's contrast threshold (OpenCV default 0.04; lower finds more in flat texture).  0.0175:
        measured on six rendered 1200 x 900 photos against pycolmap's SIFT (whose peak threshold
        0.02 / 3 equals OpenCV's 0.02): 0.02 gives 16 % fewer tie points per photo than pycolmap,
        0.0175 6 % more at 0.46-0.49x its CPU time, 0.015 30 % more at 0.6x (docs/figures.md).
    max_size_px : float
        Largest keypoint diameter kept, pixels of the detection level (a blob's position is
        as good as its scale: the large ones are the least precise; 0 keeps all).
    unique_positions : bool
        One keypoint per position (the first orientation of an extremum; module docstring), off:
        twins are joined in the tracks instead.
    """

    max_features: int = 8000
    level: int | None = None
    max_side_px: int = 4000
    contrast_threshold: float = 0.0175
    max_size_px: float = 16.0
    unique_positions: bool = False

    def key(self) -> str:
        return json.dumps([self.max_features, self.level, self.max_side_px, self.contrast_threshold,
                           self.max_size_px] + (["one per position"] if self.unique_positions else []))


@dataclass(frozen=True, eq=False)
class Features:
    """Keypoints and descriptors of one photo.

    Attributes
    ----------
    xy_px : ndarray (n, 2) float64
        Column, row in full-resolution pixels.
    descriptors : ndarray (n, 128) uint8
    response : ndarray (n,) float32
        SIFT response (contrast of the extremum).
    size_px : ndarray (n,) float32
        Keypoint diameter in full-resolution pixels.
    level : int
        Pyramid level of the detection.
    """

    xy_px: np.ndarray
    descriptors: np.ndarray
    response: np.ndarray
    size_px: np.ndarray
    level: int

    def __len__(self) -> int:
        return len(self.xy_px)


def pyramid_level(columns_px: int, rows_px: int, max_side_px: int = 4000) -> int:
    """Smallest level ``L >= 0`` with ``max(columns, rows) / 2^L <= max_side_px``.

    >>> pyramid_level(6000, 4000), pyramid_level(3000, 2000), pyramid_level(17310, 11310)
    (1, 0, 3)
    """
    long_side = max(int(columns_px), int(rows_px))
    return max(0, int(math.ceil(math.log2(long_side / max_side_px)))) if long_side > max_side_px else 0


def grey8(image: np.ndarray) -> np.ndarray:
    """A uint8 grey image from grey/RGB uint8/uint16/float input (contrast stretched for 16 bits)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = img[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], dtype=np.float32)
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    f = img.astype(np.float32)
    finite = np.isfinite(f)
    if not finite.any():
        return np.zeros(f.shape, np.uint8)
    lo, hi = np.percentile(f[finite], [0.5, 99.5])
    scale = 255.0 / (hi - lo) if hi > lo else 1.0
    return np.clip((np.where(finite, f, lo) - lo) * scale, 0, 255).astype(np.uint8)


def detect(image: np.ndarray, options: FeatureOptions = FeatureOptions()) -> Features:
    """SIFT keypoints and descriptors of one photo (see the module docstring).

    Parameters
    ----------
    image : ndarray (rows, cols) or (rows, cols, 3)
        The photo, grey or RGB, uint8/uint16/float.
    options : FeatureOptions
    """
    import cv2

    grey = grey8(image)
    level = options.level if options.level is not None else pyramid_level(grey.shape[1], grey.shape[0],
                                                                           options.max_side_px)
    work = grey
    for _ in range(level):
        work = cv2.pyrDown(work)
    sift = cv2.SIFT_create(nfeatures=0, contrastThreshold=options.contrast_threshold)
    kps, desc = sift.detectAndCompute(work, None)
    if not kps or desc is None:
        return Features(np.empty((0, 2)), np.empty((0, 128), np.uint8), np.empty(0, np.float32),
                        np.empty(0, np.float32), level)
    pt = np.array([k.pt for k in kps], dtype=np.float64)
    resp = np.array([k.response for k in kps], dtype=np.float32)
    size = np.array([k.size for k in kps], dtype=np.float32)
    # OpenCV's keypoint coordinates: pixel centres at integers; undo the level's halvings
    xy = (pt + 0.5) * (2 ** level) - 0.5
    cand = np.arange(len(pt))
    if options.unique_positions:          # one keypoint per extremum (module docstring: orientations)
        cand = np.sort(np.unique(pt, axis=0, return_index=True)[1])
    small = cand[size[cand] <= options.max_size_px] if options.max_size_px > 0 else cand
    keep = small[_spread(pt[small], resp[small], work.shape, options.max_features)]
    return Features(xy[keep], np.clip(np.rint(desc[keep]), 0, 255).astype(np.uint8), resp[keep],
                    size[keep] * (2 ** level), level)


def _spread(pt: np.ndarray, resp: np.ndarray, shape: tuple[int, ...], n_max: int) -> np.ndarray:
    """Indices of at most *n_max* keypoints: per grid cell the strongest, the cell quota first,
    then the remaining strongest overall (sorted by index)."""
    n = len(pt)
    if n <= n_max:
        return np.arange(n)
    rows, cols = shape[:2]
    cell = (np.minimum((pt[:, 1] * _GRID / rows).astype(int), _GRID - 1) * _GRID
            + np.minimum((pt[:, 0] * _GRID / cols).astype(int), _GRID - 1))
    order = np.lexsort((-resp, cell))
    sc = cell[order]
    start = np.r_[0, np.flatnonzero(np.diff(sc)) + 1]
    rank = np.arange(n) - np.repeat(start, np.diff(np.r_[start, n]))
    quota = n_max // (_GRID * _GRID)
    chosen = np.zeros(n, bool)
    chosen[order[rank < quota]] = True
    rest = np.flatnonzero(~chosen)
    more = n_max - int(chosen.sum())
    if more > 0:
        chosen[rest[np.argsort(-resp[rest], kind="stable")[:more]]] = True
    return np.flatnonzero(chosen)


def read_image(path: str | os.PathLike, error: Callable[[str], Exception]) -> np.ndarray:
    """Read an image file (PNG, TIFF, JPEG) as grey or RGB; *error(message)* builds the exception
    raised for a file that cannot be decoded (a truncated or non-image file)."""
    import cv2

    p = Path(path)
    try:
        data = np.fromfile(p, dtype=np.uint8)
    except OSError as ex:
        raise error(f"{p}: cannot read the image ({ex.strerror or ex})") from None
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if len(data) else None
    if img is None:
        raise error(f"{p}: cannot decode the image (truncated, or not a PNG/TIFF/JPEG)")
    if img.ndim == 3:
        img = img[:, :, 2::-1] if img.shape[2] >= 3 else img[:, :, 0]
    return np.ascontiguousarray(img)
