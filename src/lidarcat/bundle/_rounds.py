"""Which rejected groups data snooping removes together in one round (:func:`round_picks`).

A blunder raises the w-tests of the groups that share its photo, its point or a neighbouring
photo, not of groups far away; :class:`Neighbours` holds that footprint (the photos sharing a
point, the photos of every point) and the budget of rejections a crowded photo takes per round.
"""

from __future__ import annotations

import numpy as np

from .problem import BundleProblem
from .redundancy import Reliability

__all__ = ["Neighbours", "round_picks", "OBS_PER_REJECTION"]

#: data snooping: a photo takes one more rejection per round per this many observations (besides the
#: separate ones), the largest test of each point only
OBS_PER_REJECTION = 50


class Neighbours:
    """Photos of the original problem that share a point (or are the same photo), and the photos of
    every point: the footprint of a group for :func:`round_picks`."""

    def __init__(self, p: BundleProblem) -> None:
        from scipy import sparse

        inc = sparse.csr_matrix((np.ones(len(p.photo_index)), (p.photo_index, p.point_index)),
                                shape=(p.n_photos, p.n_points))
        self.adj = (inc @ inc.T + sparse.identity(p.n_photos, format="csr")).tocsr()
        self.of_point = inc.T.tocsr()
        self.photo_pos = {str(q): i for i, q in enumerate(p.photo_ids)}
        # rejections a photo may take in one round beside the separate ones (one per
        # OBS_PER_REJECTION of its observations: a blunder moves the photo's orientation, and
        # with it the tests of its other observations, by about 1 / their number)
        self.budget = np.bincount(p.photo_index, minlength=p.n_photos) // OBS_PER_REJECTION
        self.point_pos = {str(q): i for i, q in enumerate(p.point_ids)}

    def footprint(self, kind: str, photo: str, point: str) -> np.ndarray:
        """Photos whose unknowns the group's test depends on most: every photo that sees its point
        (image observation, control point), or its photo (GNSS/INS constraint, line observation)."""
        if kind not in ("eo", "line"):
            j = self.point_pos[point]
            return self.of_point.indices[self.of_point.indptr[j]:self.of_point.indptr[j + 1]]
        return np.array([self.photo_pos[photo]])

    def around(self, photos: np.ndarray) -> np.ndarray:
        return np.unique(np.concatenate([self.adj.indices[self.adj.indptr[i]:self.adj.indptr[i + 1]]
                                         for i in photos])) if len(photos) else photos


def round_picks(rel: Reliability, near: Neighbours, limit: int) -> list[int]:
    """Rejected groups removed together in one round, largest test ratio first.

    Rule: a group is picked when none of its photos (an image observation or a control
    point: every photo that sees its point; a GNSS/INS constraint or a line observation: its
    photo) is a photo of
    a group picked before it in this round or shares a point with one.  Two such groups
    share no unknown and no observation, and neither do the other rays of their points, so
    their residuals are correlated only through the rest of the network (weakly): one
    cannot be the reason the other's test rejects, and both are what one-at-a-time snooping
    would find in two rounds.

    Only image observations are picked together: a control point, a GNSS/INS constraint or an
    observation of line control carries the datum, and an error in one moves the whole block,
    raising the tests of datum groups far from it.  A round whose largest ratio is such a group
    removes it alone, and such a group is never a second pick (a line observation 60 px off on a
    block held by 2 m GNSS raised the test of a correct control point on a photo that shares no
    point with the line's: picked together, both went; tests/bundle/test_line_outliers.py).
    """
    ratio = np.where(rel.testable, np.nan_to_num(rel.ratio, nan=-np.inf), -np.inf)
    cand = np.flatnonzero(ratio > 1)
    cand = cand[np.argsort(-ratio[cand], kind="stable")]
    if len(cand) and str(rel.kind[cand[0]]) != "image":
        return [int(cand[0])]
    cand = cand[rel.kind[cand] == "image"]
    blocked = np.zeros(near.adj.shape[0], dtype=bool)
    budget = near.budget.copy()
    points_hit: set[str] = set()
    picks: list[int] = []
    for g in cand:
        if len(picks) >= limit:
            break
        kind = str(rel.kind[g])
        fp = near.footprint(kind, str(rel.photo[g]), str(rel.point[g]))
        separate = not blocked[fp].any()
        # on photos with many observations: the largest per point, a few per photo
        crowded = kind == "image" and str(rel.point[g]) not in points_hit and bool(np.all(budget[fp] > 0))
        if not (separate or crowded):
            continue
        picks.append(int(g))
        blocked[near.around(fp)] = True
        budget[fp] -= 1
        if kind not in ("eo", "line"):
            points_hit.add(str(rel.point[g]))
    return picks
