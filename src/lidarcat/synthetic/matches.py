"""A block of automatic tie-point matches with gross errors of known place, for tests and benchmarks.

The NGI frames (``../shared/data/frames/ngi``, evaluation only) carry what OpenCV SIFT matching
leaves in a block: 8 two-ray points mismatched outright (3.5-719 px) and one wrong ray of a
three-ray point, with the GNSS/INS orientation (sd 1 m / 0.01 deg) as the only datum.
:func:`matched_block` plants the same kind of errors in a :func:`lidarcat.synthetic.block.synthetic_block`
(2 strips x 3 photos, about 1,500 observations, no control points): each mismatch across the
base of its two photos (a y-parallax, the part a two-ray point can reveal), the wrong ray in a
random direction.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..bundle import BundleProblem
from .block import SyntheticBlock, synthetic_block

__all__ = ["matched_block", "MISMATCH_PX", "WRONG_RAY_PX", "MATCH_PIXEL_MM"]

#: pixel of the block's camera, mm (the image sd is 0.3 px: SIFT's sub-pixel accuracy)
MATCH_PIXEL_MM = 0.01
#: planted mismatches of two-ray points, px (across the base)
MISMATCH_PX = (3.5, 6.0, 12.0, 30.0, 80.0, 200.0, 400.0, 700.0)
#: the wrong ray of a three-ray point, px
WRONG_RAY_PX = 242.0


def matched_block(seed: int = 5, *, sd_position_m: float = 1.0,
                  sd_attitude_deg: float = 0.01) -> tuple[BundleProblem, SyntheticBlock, set[tuple[str, str]]]:
    """The block, its truth and the planted gross observations.

    Returns
    -------
    problem : BundleProblem
        No control points; every photo's orientation observed with the given sds (noise of those
        sds added to the truth) as weighted constraints and as the approximate orientation.
    truth : SyntheticBlock
    planted : set of (photo, point)
        The gross observations: both rays of each mismatched two-ray point (no test can tell
        which of the two is wrong) and the wrong ray.

    >>> p, truth, planted = matched_block()
    >>> len(planted), len(p.constraint_point_index), 1300 < len(p.photo_index) < 1800
    (17, 0, True)
    """
    b = synthetic_block(2, 3, seed=seed, image_sd_mm=0.3 * MATCH_PIXEL_MM, point_spacing_m=31.0)
    p = b.problem
    rng = np.random.default_rng(seed)
    sd = np.r_[np.full(3, sd_position_m), np.full(3, np.radians(sd_attitude_deg))]
    eo_obs = np.asarray(b.true_eo) + rng.normal(0.0, 1.0, (p.n_photos, 6)) * sd
    xy = np.array(p.xy_mm)
    rays = np.bincount(p.point_index)
    strip = (np.arange(p.n_photos) // 3)[p.photo_index]
    same = np.bincount(p.point_index, weights=strip, minlength=p.n_points)   # 0 or 2: one strip
    cand = np.flatnonzero((rays == 2) & ((same == 0) | (same == 2)))
    planted: set[tuple[str, str]] = set()
    for j, e_px in zip(rng.choice(cand, len(MISMATCH_PX), replace=False), MISMATCH_PX):
        k = int(np.flatnonzero(p.point_index == j)[rng.integers(2)])
        xy[k] += np.array([rng.uniform(-0.3, 0.3), rng.choice([-1.0, 1.0])]) * e_px * MATCH_PIXEL_MM
        planted |= {(str(p.photo_ids[p.photo_index[i]]), str(p.point_ids[j]))
                    for i in np.flatnonzero(p.point_index == j)}
    j3 = int(rng.choice(np.flatnonzero(rays == 3)))
    k3 = int(np.flatnonzero(p.point_index == j3)[0])
    ang = rng.uniform(0, 2 * np.pi)
    xy[k3] += WRONG_RAY_PX * MATCH_PIXEL_MM * np.array([np.cos(ang), np.sin(ang)])
    planted.add((str(p.photo_ids[p.photo_index[k3]]), str(p.point_ids[j3])))
    bad = dataclasses.replace(
        p, xy_mm=xy, constraint_point_index=np.zeros(0, int), constraint_enh_m=np.zeros((0, 3)),
        constraint_sd_m=np.zeros((0, 3)), eo_constraint_photo_index=np.arange(p.n_photos),
        eo_constraint_params=eo_obs, eo_constraint_sd=np.broadcast_to(sd, (p.n_photos, 6)), initial_eo=eo_obs,
        point_role=None)
    return bad, b, planted
