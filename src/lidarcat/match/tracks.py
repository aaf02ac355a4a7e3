r"""Tracks across photos by union-find, and the control of their distribution over each photo.

Tracks
------
Every keypoint of the block is a node ``g = offset[photo] + k``; every verified match an
edge.  A track is a connected component of this graph (``scipy.sparse.csgraph.
connected_components``: union-find over all edges at once, vectorised).  A component that
holds two keypoints of the same photo is *inconsistent* -- two different image points cannot
both be the same object point -- and is dropped whole (splitting it would have to guess
which of the chains is right; the chains of a wrong match are exactly the ones to lose).
Components of a single node (no match) are no tracks.

Twin keypoints are one node: SIFT gives an extremum a keypoint per orientation peak (a second
one when its gradient histogram has another peak within 80 % of the highest; a fifth of OpenCV's
keypoints), at the same position with different descriptors.  Matched on their own, the twins of
a point made two tracks through the same image points: on a rendered 24-photo block 7 % of the
tie points, whose errors are the same (correlation 1.0) and which the adjustment weighed as
independent -- twice.  With the keypoints' positions (*xy_px*) every keypoint stands for the first
keypoint at its position, so a match through either orientation joins the same track.  (Keeping
one orientation per position at detection instead loses the matches whose first orientation
differs between the photos: 15-20 % of the inliers of the pairs across strips, turned by 180°.)

Distribution
------------
Classical aerial triangulation asks for tie points in the six (or nine) *Von Gruber areas*
of each photo; with automatic matching the same idea becomes a grid of ``rows x cols``
cells per photo with a target of ``per_cell`` points in each.  Each track gets a score --
its number of rays first (a point seen on more photos ties more of the block), then the
mean ratio-test value (lower is a more distinctive match) -- and in every cell of every
photo the ``per_cell`` best observed tracks are *chosen*.  A track is kept when it is chosen
in at least one of its photos: a cell keeps its best points, and a point needed by a
sparse cell of one photo stays even if the neighbouring photo has plenty.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Tracks", "build_tracks", "distribute", "first_at_position"]


@dataclass(frozen=True, eq=False)
class Tracks:
    """Observations grouped in tracks, one row per observation, sorted by track then photo.

    Attributes
    ----------
    track : ndarray (n,) int
        Track number 0 .. n_tracks-1.
    photo : ndarray (n,) int
        Photo index.
    keypoint : ndarray (n,) int
        Keypoint index within its photo.
    n_inconsistent : int
        Components dropped because they held two keypoints of one photo.
    """

    track: np.ndarray
    photo: np.ndarray
    keypoint: np.ndarray
    n_inconsistent: int = 0

    def __len__(self) -> int:
        return len(self.track)

    @property
    def n_tracks(self) -> int:
        return int(self.track.max()) + 1 if len(self.track) else 0

    def rays(self) -> np.ndarray:
        """Observations per track, (n_tracks,)."""
        return np.bincount(self.track, minlength=self.n_tracks)

    def select_tracks(self, keep: np.ndarray) -> Tracks:
        """The tracks where *keep* (n_tracks,) is True, renumbered in order."""
        keep = np.asarray(keep, bool)
        new = np.cumsum(keep) - 1
        rows = keep[self.track]
        return Tracks(new[self.track[rows]], self.photo[rows], self.keypoint[rows], self.n_inconsistent)


def build_tracks(n_keypoints: Sequence[int], pairs: np.ndarray, matches: Sequence[tuple[np.ndarray, np.ndarray]],
                 xy_px: Sequence[np.ndarray] | None = None) -> Tracks:
    """Tracks from the verified matches of every pair (module docstring).

    Parameters
    ----------
    n_keypoints : sequence of int
        Keypoints per photo.
    pairs : ndarray (m, 2) int
        Photo indices (a, b) of each matched pair.
    matches : sequence of (i, j)
        Per pair, keypoint indices in a and in b of its verified matches.
    xy_px : sequence of ndarray (n_keypoints[p], 2), optional
        Keypoint positions per photo: keypoints at one position (twins) are one node, the first of
        them (module docstring).

    Examples
    --------
    Photos 0-1 match keypoints (0,0) and (1,1); photos 1-2 match (0,2):

    >>> t = build_tracks([2, 2, 3], np.array([[0, 1], [1, 2]]),
    ...                  [(np.array([0, 1]), np.array([0, 1])), (np.array([0]), np.array([2]))])
    >>> t.track.tolist(), t.photo.tolist(), t.keypoint.tolist()
    ([0, 0, 0, 1, 1], [0, 1, 2, 0, 1], [0, 0, 2, 1, 1])

    Keypoints 0 and 1 of photo 0 are twins (one position): their matches make one track.

    >>> xy = [np.array([[5.0, 5.0], [5.0, 5.0]]), np.array([[1.0, 1.0], [2.0, 2.0]]), np.arange(6.0).reshape(3, 2)]
    >>> t = build_tracks([2, 2, 3], np.array([[0, 1], [0, 2]]),
    ...                  [(np.array([0]), np.array([1])), (np.array([1]), np.array([2]))], xy_px=xy)
    >>> t.track.tolist(), t.photo.tolist(), t.keypoint.tolist()
    ([0, 0, 0], [0, 1, 2], [0, 1, 2])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_kp = np.asarray(n_keypoints, dtype=np.int64)
    offset = np.r_[0, np.cumsum(n_kp)]
    total = int(offset[-1])
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    first = [np.arange(int(k), dtype=np.int64) for k in n_kp] if xy_px is None else \
        [first_at_position(x) for x in xy_px]
    u = [offset[a] + first[a][np.asarray(i, np.int64)] for (a, _), (i, _) in zip(pairs, matches)]
    v = [offset[b] + first[b][np.asarray(j, np.int64)] for (_, b), (_, j) in zip(pairs, matches)]
    u = np.concatenate(u) if u else np.empty(0, np.int64)
    v = np.concatenate(v) if v else np.empty(0, np.int64)
    empty = Tracks(np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int64))
    if len(u) == 0:
        return empty
    g = coo_matrix((np.ones(len(u), np.int8), (u, v)), shape=(total, total))
    _, label = connected_components(g, directed=False)
    node = np.unique(np.concatenate([u, v]))                 # matched keypoints only
    lab = label[node]
    photo = np.searchsorted(offset, node, side="right") - 1
    kp = node - offset[photo]
    # inconsistent: a component with two nodes on one photo
    key = lab * (len(n_kp) + 1) + photo
    uk, cnt = np.unique(key, return_counts=True)
    bad_comp = np.unique(uk[cnt > 1] // (len(n_kp) + 1))
    keep = ~np.isin(lab, bad_comp)
    lab, photo, kp = lab[keep], photo[keep], kp[keep]
    if len(lab) == 0:
        return Tracks(empty.track, empty.photo, empty.keypoint, int(len(bad_comp)))
    order = np.lexsort((photo, lab))
    lab, photo, kp = lab[order], photo[order], kp[order]
    _, track = np.unique(lab, return_inverse=True)
    return Tracks(track.astype(np.int64), photo.astype(np.int64), kp.astype(np.int64), int(len(bad_comp)))


def first_at_position(xy_px: np.ndarray) -> np.ndarray:
    """(n,) index of the first keypoint at each keypoint's position (itself when it has no twin).

    >>> first_at_position(np.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0]])).tolist()
    [0, 1, 0]
    """
    xy = np.asarray(xy_px, dtype=np.float64).reshape(-1, 2)
    if len(xy) == 0:
        return np.empty(0, np.int64)
    _, first, inverse = np.unique(xy, axis=0, return_index=True, return_inverse=True)
    return first[inverse.ravel()].astype(np.int64)


def distribute(tracks: Tracks, xy_px: np.ndarray, frame_px: np.ndarray, score: np.ndarray, *,
               grid: tuple[int, int] = (6, 6), per_cell: int = 8) -> np.ndarray:
    """Which tracks to keep so that each photo's grid cells hold their best points (module docstring).

    Parameters
    ----------
    tracks : Tracks
    xy_px : ndarray (n, 2)
        Pixel of every observation of *tracks*.
    frame_px : ndarray (n_photos, 2)
        Columns, rows of each photo.
    score : ndarray (n_tracks,)
        Higher is better.
    grid : (rows, cols)
    per_cell : int
        Target points per cell; ``per_cell <= 0`` keeps every track.

    Returns
    -------
    keep : ndarray (n_tracks,) bool
    """
    n_t = tracks.n_tracks
    if per_cell <= 0 or n_t == 0:
        return np.ones(n_t, bool)
    gr, gc = grid
    size = np.asarray(frame_px, dtype=np.float64)[tracks.photo]
    col = np.clip((xy_px[:, 0] + 0.5) / size[:, 0] * gc, 0, gc - 1).astype(np.int64)
    row = np.clip((xy_px[:, 1] + 0.5) / size[:, 1] * gr, 0, gr - 1).astype(np.int64)
    cell = tracks.photo * (gr * gc) + row * gc + col
    s = np.asarray(score, dtype=np.float64)[tracks.track]
    order = np.lexsort((tracks.track, -s, cell))
    co = cell[order]
    start = np.flatnonzero(np.r_[True, co[1:] != co[:-1]])
    rank = np.arange(len(co)) - np.repeat(start, np.diff(np.r_[start, len(co)]))
    keep = np.zeros(n_t, bool)
    keep[tracks.track[order[rank < per_cell]]] = True
    return keep
