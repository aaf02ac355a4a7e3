"""A synthetic block whose only control is roof lines measured in the photos (known truth).

The photos, tie points and terrain of :func:`lidarcat.synthetic.block.synthetic_block`, its
control points dropped; instead ``n_lines`` roof edges (ridges, hips, eaves: 3-D segments of
8-20 m at 4-12 m above the terrain, directions spread over 180 degrees, a third of them
sloping like hips) are measured in every photo that sees both ends: two image points on the
true edge (at 10-35 % and 65-90 % of it) with Gaussian noise of ``line_image_sd_mm``.  The given
3-D end points carry noise of ``line_sd_m`` across and ``line_along_sd_m`` along the line (as
from two fitted LiDAR planes) with that covariance.  The photo positions and attitudes are
constrained weakly (GNSS/IMU ``gnss_sd_m``, ``ins_sd_deg``, noise of those sds), so the lines
carry the accuracy.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._util.frozen import frozen_array
from ..bundle import BundleProblem
from ..bundle.lines import ControlLine, LineControl, LineObservation
from ..geometry.collinearity import project
from .block import synthetic_block

__all__ = ["LineBlock", "line_block"]


@dataclasses.dataclass(frozen=True, eq=False)
class LineBlock:
    """A line-controlled problem and its truth.

    Attributes
    ----------
    problem : BundleProblem
        With ``lines`` and weak GNSS/IMU constraints, no control points.
    true_eo : (P, 6) array
    true_points_m : (Q, 3) array
    true_a_m, true_b_m : (L, 3) array
        True end points of the control lines.
    initial_eo : (P, 6) array
        The GNSS/IMU observations (the approximations).
    """

    problem: BundleProblem
    true_eo: np.ndarray
    true_points_m: np.ndarray
    true_a_m: np.ndarray
    true_b_m: np.ndarray
    initial_eo: np.ndarray

    def __post_init__(self) -> None:
        for name in ("true_eo", "true_points_m", "true_a_m", "true_b_m", "initial_eo"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))


def line_block(n_lines: int = 12, *, seed: int = 0, n_strips: int = 2, photos_per_strip: int = 6,
               image_sd_mm: float = 0.005, line_image_sd_mm: float = 0.004, line_sd_m: float = 0.03,
               line_along_sd_m: float = 0.3, gnss_sd_m: float = 2.0, ins_sd_deg: float = 0.5,
               n_control_points: int = 0, noise: bool = True) -> LineBlock:
    """Generate a line-controlled block; see the module docstring.  Seeded (reproducible).

    *n_control_points* of the base block's control points (spread over its list, sd 0.1 m) are
    kept beside the lines (a block with few usable roof corners); 0: lines only.
    """
    base = synthetic_block(n_strips, photos_per_strip, seed=seed, image_sd_mm=image_sd_mm, noise=noise)
    rng = np.random.default_rng(seed + 7919)
    eo, pts = base.true_eo, base.true_points_m
    f = float(base.problem.focal_length_mm[0])
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    lines: list[ControlLine] = []
    obs: list[LineObservation] = []
    true_a, true_b = [], []
    half = np.array([36.0, 24.0]) / 2 * 0.95
    k = 0
    while len(lines) < n_lines and k < 50 * n_lines:
        k += 1
        c = lo + rng.uniform(0.1, 0.9, 2) * (hi - lo)
        z = 30.0 * np.sin((c[0] - 500000.0) / 700.0) * np.cos((c[1] - 7000000.0) / 500.0) + rng.uniform(4, 12)
        az = np.pi * (len(lines) + rng.uniform(0, 1)) / n_lines       # directions spread over 180 degrees
        length = rng.uniform(8, 20)
        slope = rng.uniform(0.3, 0.6) if len(lines) % 3 == 2 else 0.0  # hips slope, ridges and eaves level
        d = np.array([np.cos(az), np.sin(az), slope])
        d /= np.linalg.norm(d)
        a = np.r_[c, z] - d * length / 2
        b = np.r_[c, z] + d * length / 2
        u = np.array([rng.uniform(0.10, 0.35), rng.uniform(0.65, 0.90)])
        on = a + u[:, None] * (b - a)                                    # the two measured edge points
        seen = []
        for i in range(len(eo)):
            xy, u3 = project(np.broadcast_to(eo[i], (4, 6)), np.stack([a, b, *on]), np.full(4, f))
            if np.all(u3 < 0) and np.all(np.abs(xy) < half):
                seen.append((i, xy[2:]))
        if len(seen) < 2:
            continue
        lid = f"L{len(lines) + 1:02d}"
        tt = d
        cov3 = line_sd_m**2 * (np.eye(3) - np.outer(tt, tt)) + line_along_sd_m**2 * np.outer(tt, tt)
        cov = np.zeros((6, 6))
        cov[:3, :3] = cov[3:, 3:] = cov3
        ga, gb = a, b
        if noise:
            ga = a + rng.multivariate_normal(np.zeros(3), cov3)
            gb = b + rng.multivariate_normal(np.zeros(3), cov3)
        lines.append(ControlLine(lid, ga, gb, cov))
        true_a.append(a)
        true_b.append(b)
        for i, xy in seen:
            if noise:
                xy = xy + rng.normal(0, line_image_sd_mm, xy.shape)
            obs.append(LineObservation(lid, base.problem.photo_ids[i], xy[0], xy[1], line_image_sd_mm))
    p0 = base.problem
    lc = LineControl.from_observations(lines, obs, p0.photo_ids)
    n_ph = len(eo)
    sd = np.r_[np.full(3, gnss_sd_m), np.radians(np.full(3, ins_sd_deg))]
    gnss = eo + (rng.normal(0, 1, eo.shape) * sd if noise else 0.0)
    keep = np.unique(np.linspace(0, len(p0.constraint_point_index) - 1, n_control_points).round().astype(int)) \
        if n_control_points > 0 else np.zeros(0, dtype=int)
    problem = dataclasses.replace(
        p0, constraint_point_index=p0.constraint_point_index[keep], constraint_enh_m=p0.constraint_enh_m[keep],
        constraint_sd_m=p0.constraint_sd_m[keep], point_role=None,
        eo_constraint_photo_index=np.arange(n_ph), eo_constraint_params=gnss,
        eo_constraint_sd=np.broadcast_to(sd, (n_ph, 6)), initial_eo=gnss, lines=lc)
    return LineBlock(problem, eo, pts, np.array(true_a), np.array(true_b), gnss)
