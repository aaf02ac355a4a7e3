"""Seeded synthetic aerial blocks with known truth, for tests and benchmarks.

A block of ``n_strips`` parallel strips of ``photos_per_strip`` near-vertical
photos (alternate strips flown in opposite directions), a smooth terrain, a
regular grid of object points, exact image coordinates plus Gaussian noise of
known sigma, and control points with noisy observed coordinates at the block
border (every few bases) and a few inside.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..geometry.collinearity import project
from .._util.frozen import frozen_array
from ..bundle import BundleProblem

__all__ = ["SyntheticBlock", "synthetic_block", "aerial_block", "AERIAL_LAYOUTS", "resimulated", "SelfCalBlock",
           "selfcal_block"]

#: photos -> (strips, photos per strip) of the benchmark blocks (about 1 : 2, strips growing)
AERIAL_LAYOUTS = {100: (7, 15), 1000: (22, 46), 5000: (50, 100), 10000: (70, 143)}


@dataclasses.dataclass(frozen=True, eq=False)
class SyntheticBlock:
    """A synthetic problem and the truth it was generated from.

    Attributes
    ----------
    problem : BundleProblem
    true_eo : (P, 6) array
        X0, Y0, Z0 (m), omega, phi, kappa (rad).
    true_points_m : (Q, 3) array
    image_sd_mm : float
    control_sd_m : (3,) array
    """

    problem: BundleProblem
    true_eo: np.ndarray
    true_points_m: np.ndarray
    image_sd_mm: float
    control_sd_m: np.ndarray

    def __post_init__(self) -> None:
        for name in ("true_eo", "true_points_m", "control_sd_m"):
            object.__setattr__(self, name, frozen_array(getattr(self, name)))


def synthetic_block(
    n_strips: int = 2,
    photos_per_strip: int = 6,
    *,
    seed: int = 0,
    focal_mm: float = 50.0,
    format_mm: tuple[float, float] = (36.0, 24.0),
    flying_height_m: float = 1000.0,
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
    point_spacing_m: float = 60.0,
    image_sd_mm: float = 0.005,
    control_sd_m: tuple[float, float, float] = (0.10, 0.10, 0.10),
    control_every: int = 2,
    tilt_sd_deg: float = 1.0,
    noise: bool = True,
) -> SyntheticBlock:
    """Generate a block; see the module docstring.

    Parameters
    ----------
    n_strips, photos_per_strip : int
    seed : int
        Seed of :func:`numpy.random.default_rng` (fully reproducible).
    focal_mm, format_mm : camera (x along the strip, y across), mm.
    flying_height_m : float
        Height above the mean terrain.
    forward_overlap, side_overlap : float
    point_spacing_m : float
        Spacing of the object-point grid.
    image_sd_mm : float
        Sigma of the noise added to the image coordinates (also their sd).
    control_sd_m : (3,) float
        Sigmas (E, N, h) of the control points (noise added to their observed values).
    control_every : int
        A control point near the block border every this many bases along the
        strips, plus a chain across the block at both ends and one per strip gap in
        the middle.
    tilt_sd_deg : float
        Sigma of the random omega, phi (and kappa jitter), degrees.
    noise : bool
        False gives exact observations (for tests of the model itself).
    """
    rng = np.random.default_rng(seed)
    scale = flying_height_m / focal_mm                  # m per mm
    foot_x, foot_y = format_mm[0] * scale, format_mm[1] * scale
    base = (1 - forward_overlap) * foot_x
    gap = (1 - side_overlap) * foot_y
    # photos
    eo = []
    for s in range(n_strips):
        for k in range(photos_per_strip):
            kk = k if s % 2 == 0 else photos_per_strip - 1 - k
            x0 = kk * base + rng.normal(0, 0.02 * base)
            y0 = s * gap + rng.normal(0, 0.02 * gap)
            z0 = flying_height_m + rng.normal(0, 10.0)
            kappa = (0.0 if s % 2 == 0 else np.pi) + np.radians(rng.normal(0, tilt_sd_deg))
            om, ph = np.radians(rng.normal(0, tilt_sd_deg, 2))
            eo.append([x0 + 500000.0, y0 + 7000000.0, z0, om, ph, kappa])
    eo = np.array(eo)
    eo[:, 5] = (eo[:, 5] + np.pi) % (2 * np.pi) - np.pi
    n_ph = len(eo)
    # object points on a jittered grid over the covered area
    x_min, x_max = -foot_x / 2, (photos_per_strip - 1) * base + foot_x / 2
    y_min, y_max = -foot_y / 2, (n_strips - 1) * gap + foot_y / 2
    gx = np.arange(x_min + point_spacing_m / 2, x_max, point_spacing_m)
    gy = np.arange(y_min + point_spacing_m / 2, y_max, point_spacing_m)
    X, Y = np.meshgrid(gx, gy)
    X = X.ravel() + rng.uniform(-0.3, 0.3, X.size) * point_spacing_m
    Y = Y.ravel() + rng.uniform(-0.3, 0.3, Y.size) * point_spacing_m
    Z = 30.0 * np.sin(X / 700.0) * np.cos(Y / 500.0) + rng.normal(0, 5.0, X.size)
    pts = np.stack([X + 500000.0, Y + 7000000.0, Z], axis=1)
    # visibility: every photo x every point inside the format (with margin)
    ph_idx, pt_idx = [], []
    half = np.array(format_mm) / 2 * 0.95
    for i in range(n_ph):
        near = np.flatnonzero((np.abs(pts[:, 0] - eo[i, 0]) < 0.75 * max(foot_x, foot_y))
                              & (np.abs(pts[:, 1] - eo[i, 1]) < 0.75 * max(foot_x, foot_y)))
        xy, u3 = project(np.broadcast_to(eo[i], (len(near), 6)), pts[near], np.full(len(near), focal_mm))
        inside = (np.abs(xy[:, 0]) < half[0]) & (np.abs(xy[:, 1]) < half[1]) & (u3 < 0)
        ph_idx.append(np.full(inside.sum(), i))
        pt_idx.append(near[inside])
    ph_idx = np.concatenate(ph_idx)
    pt_idx = np.concatenate(pt_idx)
    # control points: nearest grid points to chosen locations
    targets = []
    xs = np.arange(0, photos_per_strip, control_every) * base
    if len(xs) == 0 or xs[-1] < (photos_per_strip - 1) * base:
        xs = np.r_[xs, (photos_per_strip - 1) * base]
    for xv in xs:
        targets.append((xv, y_min + 0.3 * foot_y))
        targets.append((xv, y_max - 0.3 * foot_y))
    for s in range(n_strips):
        targets.append((0.0, s * gap))
        targets.append(((photos_per_strip - 1) * base, s * gap))
    for s in range(n_strips - 1):
        targets.append(((photos_per_strip - 1) * base / 2, (s + 0.5) * gap))
    rays = np.bincount(pt_idx, minlength=len(pts))
    cand = np.flatnonzero(rays >= 2)
    ctrl = set()
    for tx, ty in targets:
        d = np.hypot(pts[cand, 0] - 500000.0 - tx, pts[cand, 1] - 7000000.0 - ty)
        ctrl.add(int(cand[np.argmin(d)]))
    ctrl = np.array(sorted(ctrl))
    # keep points with >= 2 rays (or control)
    keep = rays >= 2
    keep[ctrl] = rays[ctrl] >= 1
    new_index = np.cumsum(keep) - 1
    sel = keep[pt_idx]
    ph_idx, pt_idx = ph_idx[sel], new_index[pt_idx[sel]]
    pts = pts[keep]
    ctrl = new_index[ctrl]
    xy, _ = project(eo[ph_idx], pts[pt_idx], np.full(len(ph_idx), focal_mm))
    csd = np.asarray(control_sd_m, dtype=float)
    cobs = pts[ctrl].copy()
    if noise:
        xy = xy + rng.normal(0.0, image_sd_mm, xy.shape)
        cobs = cobs + rng.normal(0.0, 1.0, cobs.shape) * csd
    problem = BundleProblem(
        photo_ids=[f"{i + 1:04d}" for i in range(n_ph)],
        point_ids=[f"P{j + 1:05d}" for j in range(len(pts))],
        focal_length_mm=np.full(n_ph, focal_mm),
        photo_index=ph_idx, point_index=pt_idx, xy_mm=xy, sd_mm=image_sd_mm,
        constraint_point_index=ctrl, constraint_enh_m=cobs, constraint_sd_m=np.broadcast_to(csd, (len(ctrl), 3)),
    )
    return SyntheticBlock(problem, eo, pts, image_sd_mm, csd)


def resimulated(problem: BundleProblem, eo: np.ndarray, points_m: np.ndarray,
                rng: np.random.Generator) -> BundleProblem:
    """*problem* with its observations replaced by exact ones of a known truth plus noise.

    The image coordinates are the projections of *points_m* (Q, 3) through *eo* (P, 6; m, rad)
    plus Gaussian noise of ``problem.sd_mm``; the control coordinates are *points_m* plus noise
    of ``problem.constraint_sd_m``.  Keeps the geometry of a real block (e.g. the thesis block
    with its adjusted solution as the truth) with every observation good by construction.
    """
    p = problem
    ei, pj = p.photo_index, p.point_index
    xy, _ = project(np.asarray(eo), np.asarray(points_m)[pj], p.focal_length_mm[ei], ei)
    enh = np.asarray(points_m)[p.constraint_point_index]
    sd_con = np.where(np.isfinite(p.constraint_sd_m), p.constraint_sd_m, 0.0)
    return dataclasses.replace(p, xy_mm=xy + rng.normal(0, 1, xy.shape) * p.sd_mm,
                               constraint_enh_m=enh + rng.normal(0, 1, enh.shape) * sd_con)


@dataclasses.dataclass(frozen=True, eq=False)
class SelfCalBlock:
    """A synthetic block whose camera departs from its certificate and whose control has two sources.

    Attributes
    ----------
    block : SyntheticBlock
        The geometry and truth (its ``problem`` is replaced by :attr:`problem`).
    problem : BundleProblem
        Observations corrected with the *certificate* :attr:`camera`; control
        rows of source ``lidar`` observed in a frame shifted by ``-shift_m``.
    camera : Camera
        The certificate (no sds: every parameter free when switched on).
    true_corrections : dict
        ``c``, ``x0``, ``y0``, ``k1``: truth minus certificate (mm, mm^-2).
    shift_m : (3,) array
        X_reference - X_source of the ``lidar`` control (E, N, h).
    control_source : (k,) str
        ``gps`` or ``lidar`` for every control row (alternating).
    """

    block: SyntheticBlock
    problem: BundleProblem
    camera: Any
    true_corrections: dict
    shift_m: np.ndarray
    control_source: tuple


def selfcal_block(
    seed: int = 0,
    *,
    dc_mm: float = 0.08,
    dx0_mm: float = 0.03,
    dy0_mm: float = -0.02,
    dk1: float = 5e-6,
    shift_m: tuple[float, float, float] = (0.3, -0.2, 0.4),
    gnss_sd_m: float | None = 0.05,
    ins_sd_deg: float | None = 0.003,
    n_strips: int = 3,
    photos_per_strip: int = 8,
    image_sd_mm: float = 0.004,
    control_sd_m: float = 0.08,
    noise: bool = True,
) -> SelfCalBlock:
    """The acceptance block of self-calibration (issue 13): see :class:`SelfCalBlock`.

    Geometry from :func:`synthetic_block` (seed *seed*); the true camera has
    focal length ``50 + dc_mm``, principal point ``(dx0_mm, dy0_mm)`` and radial
    ``K1 = dk1`` (mm^-2), the certificate 50 / (0, 0) / 0.  Image noise is added
    to the measured (uncorrected) coordinates.  Camera positions are
    constrained by GNSS with *gnss_sd_m* (None: no camera constraints; then a
    flat-ish nadir block cannot separate focal length from flying height), the
    attitudes by INS with *ins_sd_deg* (None: free; then the principal point
    across the strips trades against omega, r ~ 0.96).
    Control rows alternate between the sources ``gps`` and ``lidar``.
    """
    from ..geometry.camera import Camera

    rng = np.random.default_rng(seed + 7919)
    base = synthetic_block(n_strips, photos_per_strip, seed=seed, noise=False, image_sd_mm=image_sd_mm,
                           tilt_sd_deg=2.0)
    p = base.problem
    cert = Camera("cam", 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.006, 0.006, 6000, 4000,
                  model="synthetic")
    true = Camera("cam", 50.0 + dc_mm, dx0_mm, dy0_mm, dk1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.006, 0.006, 6000, 4000)
    ei, pj = p.photo_index, p.point_index
    xy_true, _ = project(base.true_eo[ei], base.true_points_m[pj], np.full(len(ei), true.focal_length_mm))
    fot = true.photo_to_fot(xy_true)                                    # distorted, true principal point
    pfid = fot + np.array([dx0_mm, dy0_mm])
    if noise:
        pfid = pfid + rng.normal(0.0, image_sd_mm, pfid.shape)
    fot_cert = pfid                                                    # certificate principal point 0, 0
    xy_obs = fot_cert - cert._total_distortion(fot_cert)
    k = len(p.constraint_point_index)
    source = tuple("gps" if i % 2 == 0 else "lidar" for i in range(k))
    shift = np.asarray(shift_m, dtype=float)
    cobs = base.true_points_m[p.constraint_point_index].copy()
    if noise:
        cobs = cobs + rng.normal(0.0, control_sd_m, cobs.shape)
    cobs[np.array(source) == "lidar"] -= shift
    extra: dict[str, Any] = {}
    if gnss_sd_m is not None:
        gnss = base.true_eo.copy()
        if noise:
            gnss[:, :3] += rng.normal(0.0, gnss_sd_m, (len(gnss), 3))
        sd = np.full((len(gnss), 6), np.inf)
        sd[:, :3] = gnss_sd_m
        if ins_sd_deg is not None:
            sd[:, 3:] = np.radians(ins_sd_deg)
            if noise:
                gnss[:, 3:] += rng.normal(0.0, np.radians(ins_sd_deg), (len(gnss), 3))
        extra = {"eo_constraint_photo_index": np.arange(len(gnss)), "eo_constraint_params": gnss,
                 "eo_constraint_sd": sd}
    problem = dataclasses.replace(p, xy_mm=xy_obs, sd_mm=np.full_like(xy_obs, image_sd_mm),
                                  constraint_enh_m=cobs,
                                  constraint_sd_m=np.full((k, 3), control_sd_m), **extra)
    return SelfCalBlock(base, problem, cert, {"c": dc_mm, "x0": dx0_mm, "y0": dy0_mm, "k1": dk1},
                        frozen_array(shift), source)


def aerial_block(n_photos: int, *, seed: int = 1) -> SyntheticBlock:
    """A production-like aerial block of about *n_photos* photos (benchmarks, issue 11).

    60 % / 30 % overlap at 1,200 m with a 50 mm camera on a 36 x 24 mm format,
    object points every 88 m (about 58 observations per photo, 3-4 rays per
    point), 0.5 px noise (5 um pixels: 0.0025 mm), control at the border every
    second base and across the block.  Layouts of :data:`AERIAL_LAYOUTS` (other
    sizes: 1 : 2 strips).  Seeded: the same block every time.
    """
    if n_photos in AERIAL_LAYOUTS:
        strips, per = AERIAL_LAYOUTS[n_photos]
    else:
        strips = max(2, int(round((n_photos / 2) ** 0.5)))
        per = max(3, int(round(n_photos / strips)))
    return synthetic_block(strips, per, seed=seed, flying_height_m=1200.0, point_spacing_m=88.0,
                           image_sd_mm=0.0025)
