"""Overlapping LiDAR strips with a known boresight, scan-angle scale and elevation bias (calibration tests).

The terrain is flat (a runway at height ``h0``) in the south half of the
area and a sloped, undulating hillside in the north half::

    z(E, N) = h0 + g k(N) + a sin(2 pi E / L) (1 - cos(2 pi N / L)) / 2  [N > 0]
    k(N) = 0 (N <= 0),  N^2 / (2 w) (0 < N < w),  N - w / 2 (N >= w)

(exactly flat south of ``N = 0``; a knee of width ``w = 60 m`` into the slope
``g``; the undulation starts with zero height and slope at ``N = 0``: the
surface has continuous slopes, so planes of a few metres fit it everywhere).

Strips are flown east-west and west-east alternately (headings 0 and pi) and
one across (north-south) over the runway, at height ``H`` above ``h0``, scan
angles uniform in ``[-theta_max, theta_max]``.  Each pulse is traced with the
*true* parameters of :mod:`lidarcat.production.lidarchecks` (``P = g + R_ins
R_b u + b e_z``): the range is the intersection of the true ray with the
terrain (fixed-point iteration ``rho = (g_z + b - z(P_EN)) / (-d_z)``), plus
range noise; the records keep the recorded scan angle and the GNSS position,
so that georeferencing them with zero parameters gives the raw (biased)
cloud and with the true parameters the terrain.  The control surface is a
grid of surveyed runway points (20 m apart, ``N <= -length / 4``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lidar.trajectory import Trajectory
from ..production.lidarchecks import PulseRecords, SystemParameters, georeference

__all__ = ["SyntheticStrips", "synthetic_strips", "strip_terrain"]


@dataclass(frozen=True, eq=False)
class SyntheticStrips:
    """Pulses with known truth.

    Attributes
    ----------
    pulses : PulseRecords
    truth : SystemParameters
        The parameters the pulses were traced with.
    control_m : (M, 3) float
        Surveyed runway points (E, N, H), exact.
    true_points_m : (N, 3) float
        The terrain points hit (before range noise).
    range_sd_m : float
    gps_time_s : (N,) float
        GPS time of each pulse (s): strip ``s`` starts at ``1000 s``, scan lines
        ``spacing_m / 60`` s apart (60 m/s); every pulse of a scan line shares
        the line's time.
    trajectory : Trajectory
        The sensor positions and attitudes, one record per scan line (for the
        trajectory readers and :func:`lidarcat.production.lidarchecks.pulses_from_points`).
    """

    pulses: PulseRecords
    truth: SystemParameters
    control_m: np.ndarray
    true_points_m: np.ndarray
    range_sd_m: float
    gps_time_s: np.ndarray | None = None
    trajectory: Trajectory | None = None


def strip_terrain(e_m: np.ndarray, n_m: np.ndarray, *, h0_m: float = 100.0, slope: float = 0.25,
                  amp_m: float = 4.0, wave_m: float = 240.0) -> np.ndarray:
    """Terrain height (m): flat runway south, sloped and undulating hillside north (module docstring)."""
    e, n = np.asarray(e_m, dtype=float), np.asarray(n_m, dtype=float)
    w = 60.0
    knee = slope * np.where(n <= 0, 0.0, np.where(n < w, n * n / (2 * w), n - w / 2))
    wave = amp_m * np.sin(2 * np.pi * e / wave_m) * 0.5 * (1 - np.cos(2 * np.pi * n / wave_m))
    return h0_m + knee + np.where(n > 0, wave, 0.0)


def synthetic_strips(seed: int = 0, *, truth: SystemParameters | None = None, height_m: float = 500.0,
                     theta_max_deg: float = 20.0, length_m: float = 400.0, spacing_m: float = 2.0,
                     strip_offsets_m: tuple[float, ...] = (-60.0, 0.0, 60.0), range_sd_m: float = 0.02,
                     attitude_sd_rad: float = 0.01, cross_strip: bool = True) -> SyntheticStrips:
    """Several overlapping strips over a runway and a hillside, with known parameters.

    Parameters
    ----------
    seed : int
    truth : SystemParameters, optional
        Default: roll 0.05 deg, pitch -0.08 deg, scale 0.002, bias 0.12 m.
    height_m : float
        Flying height above the runway (m).
    theta_max_deg : float
        Half field of view (deg).
    length_m : float
        Strip length (m), centred on N = 0 for the east-west strips (half over the runway).
    spacing_m : float
        Along-track and across-track pulse spacing (m, approximate).
    strip_offsets_m : tuple of float
        North offsets of the east-west strips; alternate strips fly west.
    range_sd_m : float
        Range noise sd (m).
    attitude_sd_rad : float
        sd of the aircraft roll and pitch (known to the INS, so harmless).
    cross_strip : bool
        Add one north-south strip across the runway.

    Returns
    -------
    SyntheticStrips
    """
    rng = np.random.default_rng(seed)
    truth = truth or SystemParameters(np.radians(0.05), np.radians(-0.08), 0.002, 0.12)
    h0 = 100.0
    th = np.radians(theta_max_deg)
    swath = 2 * height_m * np.tan(th)
    n_across = max(int(swath / spacing_m), 8)
    n_along = max(int(length_m / spacing_m), 8)
    lines = []
    for i, off in enumerate(strip_offsets_m):
        heading = 0.0 if i % 2 == 0 else np.pi
        lines.append((np.array([0.0, off]), heading))
    if cross_strip:
        lines.append((np.array([0.0, -0.25 * length_m]), 0.5 * np.pi))
    gn, att, scan, strip, times, rec = [], [], [], [], [], []
    for s, (centre, heading) in enumerate(lines):
        fwd = np.array([np.cos(heading), np.sin(heading)])
        t = np.linspace(-0.5 * length_m, 0.5 * length_m, n_along)
        ang = rng.uniform(-th, th, size=(n_along, n_across))
        xy = centre + t[:, None] * fwd
        pos = np.column_stack([xy, np.full(n_along, h0 + height_m)])
        a = np.column_stack([rng.normal(0, attitude_sd_rad, n_along), rng.normal(0, attitude_sd_rad, n_along),
                             np.full(n_along, heading)])
        tt = 1000.0 * (s + 1) + np.arange(n_along) * spacing_m / 60.0
        times.append(np.repeat(tt, n_across))
        rec.append((tt, pos, a))
        gn.append(np.repeat(pos, n_across, axis=0))
        att.append(np.repeat(a, n_across, axis=0))
        scan.append(ang.ravel())
        strip.append(np.full(n_along * n_across, s))
    gnss, attitude, scan_rad, strip_id = (np.concatenate(x) for x in (gn, att, scan, strip))
    # trace the true rays: unit-range direction, then the range by fixed-point iteration
    unit = PulseRecords(gnss, attitude, np.ones(scan_rad.size), scan_rad, strip_id)
    d = georeference(unit, truth) - gnss
    d[:, 2] -= truth.bias_m
    rho = np.full(scan_rad.size, height_m / np.cos(th / 2))
    for _ in range(60):
        p = gnss + rho[:, None] * d
        rho = (gnss[:, 2] + truth.bias_m - strip_terrain(p[:, 0], p[:, 1])) / -d[:, 2]
    true_pts = gnss + rho[:, None] * d
    true_pts[:, 2] += truth.bias_m
    rho_obs = rho + rng.normal(0, range_sd_m, rho.size)
    pulses = PulseRecords(gnss, attitude, rho_obs, scan_rad, strip_id)
    ce, cn = np.meshgrid(np.arange(-0.45 * length_m, 0.45 * length_m + 1e-9, 20.0),
                         np.arange(-0.45 * length_m, -0.25 * length_m + 1e-9, 20.0))
    control = np.column_stack([ce.ravel(), cn.ravel(), strip_terrain(ce.ravel(), cn.ravel())])
    traj = Trajectory(np.concatenate([r[0] for r in rec]), np.concatenate([r[1] for r in rec]),
                      np.concatenate([r[2] for r in rec]), source="synthetic strips")
    return SyntheticStrips(pulses, truth, control, true_pts, range_sd_m, np.concatenate(times), traj)
