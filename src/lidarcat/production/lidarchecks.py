"""LiDAR system calibration checks (LACTEC report 7.1): vertical accuracy and systematic parameters.

Two checks, arrays in and out (no files):

1. **Vertical accuracy against surveyed check points** (the report's 900
   runway points, 7.1.1).  The LiDAR height at each check point is read from
   the points given (ground or last returns) either by the TIN (linear
   interpolation in the Delaunay triangle holding the point) or by a local
   plane ``z = a + b dx + c dy`` fitted by least squares to the points within
   a radius.  The discrepancy is ``dz = z_lidar - H_check``.  Reported as
   ASPRS 2023 NVA (``RMSE_z`` on non-vegetated points, ``1.96 RMSE_z`` the
   95 % figure of the 2014 edition and NSSDA), VVA (``RMSE_z`` of the
   vegetated points, which Edition 2 reports; and the 95th percentile of
   ``|dz|`` of the 2014 edition, linear interpolation between order
   statistics, ``numpy.percentile`` default), the ASPRS 2023 class
   (:func:`lidarcat.accuracy.standards.classify_asprs2023`) and the Brazilian
   PEC altimetric class (:func:`~lidarcat.accuracy.standards.classify_pec`).

2. **Systematic parameters** (7.1.2): roll and pitch misalignment between the
   scanner and the INS (boresight), the scan-angle scale factor and the
   elevation bias, by least squares from (a) LiDAR points over a surveyed
   control surface (vertical) and (b) the differences between overlapping
   strips.

Geolocation equation
--------------------
Frames: map ``(E, N, U)``; body ``(x forward, y left, z up)``.  For each
pulse the raw data give the GNSS antenna position ``g`` (3, m), the INS
attitude ``(r, p, k)`` (roll about x, pitch about y, heading about z, rad;
``k`` is the counter-clockwise angle of the body x axis from East), the range
``rho`` (m) and the recorded scan angle ``theta`` (rad, positive to the left).
With the calibration parameters ``omega`` (roll boresight, rad), ``phi``
(pitch boresight, rad), ``s`` (scan-angle scale) and ``b`` (elevation bias,
m)::

    P = g + R_ins R_b u + b e_z
    R_ins = R_z(k) R_y(p) R_x(r),   R_b = R_x(omega) R_y(phi)
    u = rho (0, sin t, -cos t),     t = theta (1 + s)

The raw (uncalibrated) cloud is ``P`` with all four parameters zero; the
parameters are the values that make ``P`` the true point.  The partial
derivatives (exact, not small-angle)::

    dP/domega = R_ins R_x'(omega) R_y(phi) u
    dP/dphi   = R_ins R_x(omega) R_y'(phi) u
    dP/ds     = R_ins R_b rho theta (0, cos t, sin t)
    dP/db     = e_z

with ``R_x'`` and ``R_y'`` the derivatives of the elementary rotations.  For
level flight over flat ground (``R_ins = R_z``, small angles, ``rho cos t =
H``) the height error is ``dz = omega H tan t + s theta H tan t + b``: roll
is odd in the scan angle, the scale even, the bias constant, and pitch (an
along-track shift ``phi H``) does not change heights over a flat runway.  It
shows only over slopes, as the difference between strips flown in opposite
directions; the bias cancels in strip differences and needs the control
surface (the report's runway); so both kinds of observations are combined.

Observations (Gauss-Newton, re-linearised at each iteration)
-----------------------------------------------------------
(a) *Control surface*: a LiDAR point ``P_i`` inside the TIN of the surveyed
    points; ``v_i = P_z - H(P_E, P_N)`` with ``H`` the linear TIN height,
    design row ``dP_z/dq - grad(H) . dP_EN/dq``, weight ``1 / sd_control^2``.
(b) *Strip pairs*: a point ``P_i`` of strip A and the plane (normal ``n``,
    centroid ``c``) of the ``k`` nearest points of strip B within a radius:
    ``v_i = n . (P_i - c)``, row ``n . (dP_i/dq - mean_j dP_j/dq)``, weight
    ``1 / (4 sd_strip^2)``, each pair of strips compared both ways (A to
    the planes of B and B to the planes of A) at half weight: on curved
    terrain a point lies off the plane of its neighbours by about ``kappa
    <r^2> / 2`` with the same sign both ways while the misalignment signal
    changes sign, so the curvature bias cancels in the normal equations; the
    redundancy counts each difference once (``n_strip / 2``).  A plane whose fit residual exceeds
    ``max_plane_rms_m`` (an edge, a roof, a tree) is skipped, and so is one
    whose points lie near a line (second eigenvalue sd below ``radius / 5``:
    points of one scan line leave the plane free to turn about it).

At each iteration observations of either kind with ``|v| > 4 x 1.4826 MAD``
of their kind (a crease, a wall, a car on the runway) are left out.

Tile by tile (bounded memory, on the tile engine)
-------------------------------------------------
Every quantity above needs only the pulses of the observations, and each
observation only a point and its ``k`` neighbours within ``radius_m``.  So a
survey is calibrated tile by tile (:func:`calibration_tile`, a task of
:mod:`lidarcat.lidar.jobs`): a tile's own points, with its neighbours' points
within the planes' reach, give the observations whose point lies in the tile
(:func:`select_observations`: the control candidates inside the control TIN,
the strip pairs by the plane tests); the parent merges them
(:func:`merge_observations`) and iterates (:func:`estimate_from_observations`).
The iteration above chooses the observations at the first two iterations
(at ``q = 0`` and at the first step ``q1``) and freezes them from the third;
so the tiles are read in two passes: observations chosen at the delivered
points give ``q1`` (one step, robust rejection included); observations chosen
at the points georeferenced with ``q1`` are rejected once, frozen and iterated
from ``q1`` to convergence.  Pairs chosen only at ``q = 0`` would not do: a
pitch misalignment of 0.08 deg moves a point ~0.7 m along track at 500 m, the
neighbours chosen around the wrong place put curved terrain into the plane
differences (measured: pitch 9 sd off; two passes: the in-memory estimate to
1e-6 sd, test).

Memory: a worker holds one tile with its buffer and the trajectory; the
parent holds the merged observations, at most ``max_control`` and
``max_strip`` of them (each with its pulses).  The sample is *bottom-k* by a
hash of the point (:func:`point_keys`: its coordinates and GPS time, the same
in every tile or buffer that reads it): each tile keeps its smallest keys and
the merge the smallest of all, which are the smallest keys of the survey; so
the sample does not depend on the tiling, nor on the order the tasks finish
(test).  A sample of ``m`` of ``n`` observations widens the sds by about
``sqrt(n / m)``.  The tiles are merged in job order, so a serial run and a
Dask run give the same bits.

Planimetric check against surveyed building outlines (7.1.1, Figure 5)
----------------------------------------------------------------------
The report surveys the corners of a building and compares them with the
building in the LiDAR.  Here each edge ``P_i -> P_i+1`` of a surveyed outline
(made counter-clockwise, outward normal ``n = (u_y, -u_x)`` for the edge
direction ``u``) is found in the points: roof points and low (ground) points
within ``band_m`` of the edge, away from the corners (the middle 80 % of
it), are binned every ``bin_m`` along the edge; in each bin the roof ends at
the outermost roof point (offset ``o_r`` along ``n``) and the ground starts
at the innermost low point beyond it (``o_g``), so the edge is at
``(o_r + o_g) / 2``.  With no low point the edge is ``o_r + ln 2 / (rho w)``:
for roof points of density ``rho`` (counted in the band inside the edge) the
gap between the outermost point of a bin ``w`` wide and the edge is
exponential (randomly spread points) with median ``ln 2 / (rho w)``.  The LiDAR edge is the line parallel to the surveyed one
at the median offset of the bins (robust to the gaps' long tail): a free direction would turn short edges (an 8 m wing at 0.5 m
spacing) by degrees, and the check is of a shift, not of the building's
shape; each LiDAR corner is the intersection of its two edges, and its discrepancy ``(dE, dN) =
corner_lidar - corner_surveyed``.  An edge with fewer than ``min_bins`` bins
leaves its two corners out (NaN).  Reported as ASPRS 2023 horizontal
accuracy (``RMSE_x``, ``RMSE_y``, ``RMSE_r = sqrt(RMSE_x^2 + RMSE_y^2)``)
and the PEC planimetric class at a scale (:func:`planimetric_accuracy`).

Normal equations ``N dq = A^T P v`` (with the sign of a correction:
``dq = -N^-1 A^T P v``), ``sigma0^2 = v^T P v / (n_control + n_strip / 2 - u)`` and sds
``sigma0 sqrt(diag N^-1)``.  A parameter with no observation (the bias
without control points) is left out and reported as NaN.

>>> round(vertical_accuracy(np.array([0.1, -0.1, 0.2, -0.2])).nva_rmse_m, 4)
0.1581
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..accuracy.standards import StandardResult, classify_asprs2023, classify_pec
from ..errors import ProductError

if TYPE_CHECKING:
    from ..lidar.jobs import TileJob

__all__ = [
    "PARAMETER_NAMES",
    "PulseRecords",
    "SystemParameters",
    "VerticalAccuracy",
    "CalibrationResult",
    "georeference",
    "geolocation_partials",
    "pulses_from_points",
    "lidar_heights_at",
    "vertical_accuracy",
    "estimate_system_parameters",
    "CalibrationObservations",
    "point_keys",
    "select_observations",
    "merge_observations",
    "estimate_from_observations",
    "calibration_tile",
    "bounds_tile",
    "OutlineEdges",
    "lidar_outline_corners",
    "planimetric_accuracy",
]

PARAMETER_NAMES = ("roll_rad", "pitch_rad", "scale", "bias_m")


# ----------------------------------------------------------------------------- values


@dataclass(frozen=True, eq=False)
class PulseRecords:
    """Raw pulse records of one or several strips (see the module docstring).

    Attributes
    ----------
    gnss_m : (N, 3) float
        Antenna position (E, N, U) in metres.
    attitude_rad : (N, 3) float
        INS roll, pitch, heading (rad).
    range_m : (N,) float
    scan_rad : (N,) float
        Recorded scan angle (rad, positive to the left).
    strip : (N,) int
        Strip number of each pulse.
    """

    gnss_m: np.ndarray
    attitude_rad: np.ndarray
    range_m: np.ndarray
    scan_rad: np.ndarray
    strip: np.ndarray

    def __post_init__(self) -> None:
        if np.ndim(self.range_m) != 1:
            raise ProductError(f"pulse records: range_m must be one-dimensional (N,), got shape "
                               f"{np.shape(self.range_m)}")
        n = np.shape(self.range_m)[0]
        shapes = {"gnss_m": (n, 3), "attitude_rad": (n, 3), "range_m": (n,), "scan_rad": (n,), "strip": (n,)}
        for name, shape in shapes.items():
            a = np.array(getattr(self, name), dtype=np.int64 if name == "strip" else np.float64)
            if a.shape != shape:
                raise ProductError(f"pulse records: {name} must have shape {shape}, got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ProductError(f"pulse records: {name} holds NaN or infinite values")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return int(self.range_m.shape[0])

    def subset(self, mask: np.ndarray) -> PulseRecords:
        return PulseRecords(self.gnss_m[mask], self.attitude_rad[mask], self.range_m[mask],
                            self.scan_rad[mask], self.strip[mask])


@dataclass(frozen=True)
class SystemParameters:
    """Calibration parameters: roll and pitch boresight (rad), scan-angle scale, elevation bias (m)."""

    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    scale: float = 0.0
    bias_m: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.roll_rad, self.pitch_rad, self.scale, self.bias_m])

    @classmethod
    def from_array(cls, q: Sequence[float]) -> SystemParameters:
        return cls(*(float(x) for x in q))


@dataclass(frozen=True, eq=False)
class VerticalAccuracy:
    """Vertical accuracy of a LiDAR surface against check points.

    Attributes
    ----------
    n_nonveg, n_veg : int
    nva_rmse_m : float
        RMSE_z of the non-vegetated discrepancies (ASPRS 2023 NVA).
    nva_95_m : float
        ``1.96 nva_rmse_m`` (ASPRS 2014 / NSSDA 95 % figure).
    mean_nonveg_m : float
    vva_rmse_m, vva_95th_percentile_m : float
        Vegetated: RMSE_z (Edition 2 reports it) and the 95th percentile of
        ``|dz|`` (Edition 1); NaN without vegetated points.
    asprs2023 : StandardResult
    pec : StandardResult or None
        PEC altimetric class when a scale and contour interval were given.
    """

    n_nonveg: int
    n_veg: int
    nva_rmse_m: float
    nva_95_m: float
    mean_nonveg_m: float
    vva_rmse_m: float
    vva_95th_percentile_m: float
    asprs2023: StandardResult
    pec: StandardResult | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"n_nonveg": self.n_nonveg, "n_veg": self.n_veg, "nva_rmse_m": self.nva_rmse_m,
                "nva_95_m": self.nva_95_m, "mean_nonveg_m": self.mean_nonveg_m,
                "vva_rmse_m": None if math.isnan(self.vva_rmse_m) else self.vva_rmse_m,
                "vva_95th_percentile_m": None if math.isnan(self.vva_95th_percentile_m)
                else self.vva_95th_percentile_m,
                "asprs2023": self.asprs2023.to_dict(), "pec": None if self.pec is None else self.pec.to_dict()}


@dataclass(frozen=True, eq=False)
class CalibrationResult:
    """Least-squares estimate of the system parameters.

    Attributes
    ----------
    parameters : SystemParameters
    sd : SystemParameters
        Standard deviations ``sigma0 sqrt(diag N^-1)``; NaN for a parameter left out.
    sigma0 : float
        A-posteriori unit-weight sd.
    n_control, n_strip : int
        Observations of each kind in the last iteration.
    n_iter : int
    correlation : (4, 4) float
    rms_before_m, rms_after_m : dict
        ``{"control": ..., "strip": ...}`` residual RMS before and after (m).
    notes : tuple of str
    """

    parameters: SystemParameters
    sd: SystemParameters
    sigma0: float
    n_control: int
    n_strip: int
    n_iter: int
    correlation: np.ndarray
    rms_before_m: dict[str, float]
    rms_after_m: dict[str, float]
    notes: tuple[str, ...] = field(default_factory=tuple)

    def to_dict(self) -> dict[str, Any]:
        def clean(x: float) -> float | None:
            return None if math.isnan(x) else x
        return {"parameters": {k: clean(v) for k, v in vars(self.parameters).items()},
                "sd": {k: clean(v) for k, v in vars(self.sd).items()},
                "sigma0": self.sigma0, "n_control": self.n_control, "n_strip": self.n_strip,
                "n_iter": self.n_iter, "rms_before_m": self.rms_before_m, "rms_after_m": self.rms_after_m,
                "notes": list(self.notes)}


# ----------------------------------------------------------------------------- geolocation


def _rx(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _drx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[0.0, 0.0, 0.0], [0.0, -s, -c], [0.0, c, -s]])


def _dry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[-s, 0.0, c], [0.0, 0.0, 0.0], [-c, 0.0, -s]])


def _ins(att: np.ndarray) -> np.ndarray:
    return _rz(att[:, 2]) @ _ry(att[:, 1]) @ _rx(att[:, 0])


def georeference(pulses: PulseRecords, params: SystemParameters | None = None) -> np.ndarray:
    """Ground points ``P = g + R_ins R_b u + b e_z`` (module docstring), (N, 3) in metres."""
    q = (params or SystemParameters()).as_array()
    t = pulses.scan_rad * (1.0 + q[2])
    u = pulses.range_m[:, None] * np.stack([np.zeros_like(t), np.sin(t), -np.cos(t)], -1)
    rb = _rx(np.array(q[0])) @ _ry(np.array(q[1]))
    local = u @ rb.T
    p = pulses.gnss_m + np.einsum("nij,nj->ni", _ins(pulses.attitude_rad), local)
    p[:, 2] += q[3]
    return p


def geolocation_partials(pulses: PulseRecords, params: SystemParameters | None = None) -> np.ndarray:
    """Partial derivatives ``dP/dq``, (N, 3, 4), columns in :data:`PARAMETER_NAMES` order."""
    q = (params or SystemParameters()).as_array()
    t = pulses.scan_rad * (1.0 + q[2])
    z = np.zeros_like(t)
    u = pulses.range_m[:, None] * np.stack([z, np.sin(t), -np.cos(t)], -1)
    du = (pulses.range_m * pulses.scan_rad)[:, None] * np.stack([z, np.cos(t), np.sin(t)], -1)
    rx, ry = _rx(np.array(q[0])), _ry(np.array(q[1]))
    ins = _ins(pulses.attitude_rad)
    cols = [u @ (_drx(q[0]) @ ry).T, u @ (rx @ _dry(q[1])).T, du @ (rx @ ry).T]
    jac = np.zeros((len(pulses), 3, 4))
    for k, c in enumerate(cols):
        jac[:, :, k] = np.einsum("nij,nj->ni", ins, c)
    jac[:, 2, 3] = 1.0
    return jac


def pulses_from_points(points_m: np.ndarray, sensor_m: np.ndarray, attitude_rad: np.ndarray,
                       strip: np.ndarray) -> tuple[PulseRecords, np.ndarray]:
    """Rebuild pulse records from delivered points and the trajectory at their GPS times.

    A LAS file holds the georeferenced point ``P``, not its range and scan
    angle.  With the sensor position ``g`` and INS attitude at the point's GPS
    time (:meth:`lidarcat.lidar.trajectory.Trajectory.at`), and the points taken
    as the raw cloud (all four parameters zero, ``P = g + R_ins u``), the body
    vector is ``u = R_ins^T (P - g)``, so::

        rho = |u|,   theta = atan2(u_y, -u_z),   alpha = asin(u_x / rho)

    ``alpha`` (the along-track angle) is zero for a scanner sweeping across
    track; a non-zero ``alpha`` is the pitch already applied by the software
    that made the points, or a trajectory that does not match them, and it is
    returned for the report.

    Parameters
    ----------
    points_m : (N, 3) float
    sensor_m, attitude_rad : (N, 3) float
        Trajectory at each point's time (map frame, module docstring convention).
    strip : (N,) int
        Flight line (LAS point source id).

    Returns
    -------
    pulses : PulseRecords
    along_track_rad : (N,) float
    """
    p = np.asarray(points_m, dtype=float)
    g = np.asarray(sensor_m, dtype=float)
    att = np.asarray(attitude_rad, dtype=float)
    u = np.einsum("nji,nj->ni", _ins(att), p - g)    # R_ins^T (P - g)
    rho = np.linalg.norm(u, axis=1)
    if np.any(rho <= 0):
        i = int(np.flatnonzero(rho <= 0)[0])
        raise ProductError(f"point {i + 1}: at the sensor position (zero range); the trajectory does not "
                           "match the points")
    theta = np.arctan2(u[:, 1], -u[:, 2])
    alpha = np.arcsin(np.clip(u[:, 0] / rho, -1.0, 1.0))
    return PulseRecords(g, att, rho, theta, np.asarray(strip, dtype=np.int64)), alpha


# ----------------------------------------------------------------------------- vertical accuracy


def lidar_heights_at(points_m: np.ndarray, check_en_m: np.ndarray, *, method: str = "tin",
                     radius_m: float = 1.0, ids: Sequence[str] | None = None) -> np.ndarray:
    """LiDAR height at plan positions, by the TIN of the points or a local plane.

    Parameters
    ----------
    points_m : (N, 3) float
        Ground or last-return points (m).
    check_en_m : (M, 2) float
        Plan positions of the check points (m).
    method : {"tin", "plane"}
    radius_m : float
        Plane method: the points within this plan distance (at least 3).
    ids : sequence of str, optional
        Check-point ids for the error messages (default: row numbers from 1).

    Returns
    -------
    (M,) float, the heights (m).

    Raises
    ------
    ProductError
        Fewer than 3 points; a check point outside the triangulation (TIN) or
        with fewer than 3 points within the radius (plane), naming the point.
    """
    from scipy.spatial import Delaunay, cKDTree

    from ..geometry.tin import TinLocator

    pts = np.asarray(points_m, dtype=float)
    q = np.asarray(check_en_m, dtype=float).reshape(-1, 2)
    names = list(ids) if ids is not None else [str(i + 1) for i in range(q.shape[0])]
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise ProductError(f"LiDAR heights need at least 3 points as an (N, 3) array; got shape {pts.shape}")
    origin = pts[:, :2].mean(axis=0)
    xy = pts[:, :2] - origin
    ql = q - origin
    if method == "tin":
        loc = TinLocator(Delaunay(xy))
        simplex, w = loc.locate(ql)
        bad = np.flatnonzero(simplex < 0)
        if bad.size:
            i = int(bad[0])
            raise ProductError(f"check point {names[i]} ({q[i, 0]:.3f}, {q[i, 1]:.3f}) is outside the LiDAR "
                               f"triangulation ({bad.size} of {q.shape[0]} check points outside)")
        verts = loc.triangulation.simplices[simplex]
        return np.einsum("mk,mk->m", w, pts[verts, 2])
    if method == "plane":
        tree = cKDTree(xy)
        nbrs = tree.query_ball_point(ql, radius_m)
        out = np.empty(q.shape[0])
        for i, nb in enumerate(nbrs):  # one small fit per check point (hundreds, not millions)
            if len(nb) < 3:
                raise ProductError(f"check point {names[i]} ({q[i, 0]:.3f}, {q[i, 1]:.3f}) has {len(nb)} LiDAR "
                                   f"points within {radius_m:g} m; a plane needs at least 3")
            d = xy[nb] - ql[i]
            a = np.column_stack([np.ones(len(nb)), d])
            coef, *_ = np.linalg.lstsq(a, pts[nb, 2], rcond=None)
            out[i] = coef[0]
        return out
    raise ProductError(f"method must be 'tin' or 'plane', got {method!r}")


def vertical_accuracy(dz_nonveg_m: np.ndarray, dz_veg_m: np.ndarray | None = None, *,
                      checkpoint_sd_m: float | None = None, scale: float | None = None,
                      contour_interval_m: float | None = None) -> VerticalAccuracy:
    """ASPRS 2023 NVA / VVA and the PEC class from height discrepancies ``z_lidar - H_check``.

    Parameters
    ----------
    dz_nonveg_m : (N,) float
        Discrepancies on non-vegetated (hard, open) check points (m), N >= 1.
    dz_veg_m : (M,) float, optional
        Discrepancies on vegetated check points (m).
    checkpoint_sd_m : float, optional
        Vertical sd of the check-point survey (ASPRS 2023 product accuracy).
    scale, contour_interval_m : float, optional
        Map scale denominator and contour interval for the PEC altimetric class.

    Raises
    ------
    AssessmentError
        No non-vegetated discrepancy, or NaN among them.
    """
    dz = np.asarray(dz_nonveg_m, dtype=float).ravel()
    dv = np.asarray(dz_veg_m if dz_veg_m is not None else [], dtype=float).ravel()
    d = np.column_stack([np.zeros_like(dz), np.zeros_like(dz), dz])
    sd = None if checkpoint_sd_m is None else np.array([0.0, 0.0, checkpoint_sd_m])
    asprs = classify_asprs2023(d, checkpoint_sd_m=sd)
    rmse = float(np.sqrt(np.mean(dz * dz)))
    pec = None
    if scale is not None and contour_interval_m is not None:
        pec = classify_pec(d, scale, contour_interval_m)
    vva_rmse = float(np.sqrt(np.mean(dv * dv))) if dv.size else math.nan
    vva95 = float(np.percentile(np.abs(dv), 95)) if dv.size else math.nan
    return VerticalAccuracy(int(dz.size), int(dv.size), rmse, 1.96 * rmse, float(np.mean(dz)), vva_rmse, vva95,
                            asprs, pec)


# ----------------------------------------------------------------------------- system parameters


def _control_rows(p: np.ndarray, jac: np.ndarray, control_m: np.ndarray, use: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Residuals and design rows of the points inside the control TIN (or of the indices *use*), and the indices."""
    from scipy.spatial import Delaunay

    from ..geometry.tin import TinLocator

    origin = control_m[:, :2].mean(axis=0)
    tri = Delaunay(control_m[:, :2] - origin)
    idx = np.arange(p.shape[0]) if use is None else use
    simplex, w = TinLocator(tri).locate(p[idx, :2] - origin)
    ok = simplex >= 0
    idx, simplex, w = idx[ok], simplex[ok], w[ok]
    verts = tri.simplices[simplex]
    h = np.einsum("mk,mk->m", w, control_m[verts, 2])
    # plane gradient of each triangle: solve [1 x y] c = z on its three vertices
    v3 = control_m[verts]
    a = np.concatenate([np.ones(v3.shape[:2] + (1,)), v3[:, :, :2] - origin], axis=2)
    grad = np.linalg.solve(a, v3[:, :, 2:3])[:, 1:, 0]
    v = p[idx, 2] - h
    rows = jac[idx, 2, :] - np.einsum("mk,mkq->mq", grad, jac[idx, :2, :])
    return v, rows, idx


def _strip_pairs(p: np.ndarray, strip: np.ndarray, *, radius_m: float, k: int, max_plane_rms_m: float,
                 stride: int, own: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points of strip A (M,) and the indices (M, k) of their plane neighbours in strip B, both ways
    (points of A only where *own* is True, when given; the neighbours from all points)."""
    from scipy.spatial import cKDTree

    pas, nbs = [np.zeros(0, dtype=np.int64)], [np.zeros((0, k), dtype=np.int64)]
    ids = np.unique(strip)
    trees = {s: (np.flatnonzero(strip == s), cKDTree(p[strip == s, :2])) for s in ids}
    for a in ids:
        ia = trees[a][0]
        ia = (ia if own is None else ia[own[ia]])[::stride]
        for b in ids[ids != a]:
            ib, tree = trees[b]
            dist, nn = tree.query(p[ia, :2], k=k, distance_upper_bound=radius_m)
            full = np.all(np.isfinite(dist), axis=1)
            if not np.any(full):
                continue
            pa, nb = ia[full], ib[nn[full]]
            nbr = p[nb]
            c = nbr.mean(axis=1)
            evals = np.linalg.eigvalsh(np.einsum("mki,mkj->mij", nbr - c[:, None], nbr - c[:, None]) / k)
            # a plane: small residual, and neighbours spread in two directions (not one scan line)
            good = ((np.sqrt(np.maximum(evals[:, 0], 0.0)) <= max_plane_rms_m)
                    & (np.sqrt(np.maximum(evals[:, 1], 0.0)) >= 0.2 * radius_m))
            pas.append(pa[good])
            nbs.append(nb[good])
    return np.concatenate(pas), np.concatenate(nbs)


def _strip_rows(p: np.ndarray, jac: np.ndarray, pa: np.ndarray, nb: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Point-to-plane residuals ``n . (P_a - c)`` and rows ``n . (dP_a - mean dP_nb)`` (module docstring)."""
    if pa.size == 0:
        return np.zeros(0), np.zeros((0, 4))
    nbr = p[nb]
    c = nbr.mean(axis=1)
    _, evecs = np.linalg.eigh(np.einsum("mki,mkj->mij", nbr - c[:, None], nbr - c[:, None]))
    n = evecs[:, :, 0]
    n *= np.where(n[:, 2:3] < 0, -1.0, 1.0)
    v = np.einsum("mi,mi->m", n, p[pa] - c)
    rows = np.einsum("mi,miq->mq", n, jac[pa] - jac[nb].mean(axis=1))
    return v, rows


def _keep(v: np.ndarray) -> np.ndarray:
    """Mask of the residuals within 4 robust sds (1.4826 MAD about the median)."""
    if v.size < 10:
        return np.ones(v.size, dtype=bool)
    med = np.median(v)
    mad = 1.4826 * np.median(np.abs(v - med))
    return np.abs(v - med) <= 4.0 * max(mad, 1e-6)


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v))) if v.size else math.nan


def estimate_system_parameters(pulses: PulseRecords, control_m: np.ndarray | None = None, *,
                               sd_control_m: float = 0.05, sd_strip_m: float = 0.05,
                               radius_m: float = 2.5, k: int = 6, max_plane_rms_m: float = 0.15,
                               stride: int = 1, max_iter: int = 10, tol: float = 1e-10,
                               progress: Callable[[int, int], None] | None = None) -> CalibrationResult:
    """Roll/pitch boresight, scan-angle scale and elevation bias by least squares (module docstring).

    The observations (points in the control TIN, strip point/plane pairs,
    robust rejection) are selected at the first two iterations and kept from
    the third on, so that the iteration converges on one set.

    Parameters
    ----------
    pulses : PulseRecords
        Raw pulses of at least one strip (two or more overlapping strips for
        the strip observations).
    control_m : (M, 3) float, optional
        Surveyed points of a control surface (the runway), M >= 3; LiDAR points
        inside their triangulation are the control observations.
    sd_control_m, sd_strip_m : float
        A-priori sd of one LiDAR height against the control surface and of one
        LiDAR point against the other strip's plane (m).
    radius_m, k, max_plane_rms_m : float, int, float
        Strip planes: the ``k`` nearest points of the other strip, all within
        ``radius_m``, with a plane-fit rms at most ``max_plane_rms_m``.
    stride : int
        Use every ``stride``-th point of each strip as a strip observation.
    max_iter : int
    tol : float
        Stop when the largest correction is below it.
    progress : callable, optional
        ``progress(iteration, max_iter)``.

    Raises
    ------
    ProductError
        Fewer than 3 control points, fewer observations than parameters, or a
        singular normal matrix (the message names the parameters).
    """
    ctrl = _control_array(control_m)

    def select(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _strip_pairs(p, pulses.strip, radius_m=radius_m, k=k, max_plane_rms_m=max_plane_rms_m,
                            stride=stride)
    return _adjust(pulses, ctrl, select, None, sd_control_m=sd_control_m, sd_strip_m=sd_strip_m,
                   max_iter=max_iter, tol=tol, progress=progress)


def _control_array(control_m: np.ndarray | None) -> np.ndarray | None:
    """The control surface as an (M, 3) float array, M >= 3 (None stays None)."""
    if control_m is None:
        return None
    ctrl = np.asarray(control_m, dtype=float)
    if ctrl.ndim != 2 or ctrl.shape[1] != 3 or ctrl.shape[0] < 3 or not np.all(np.isfinite(ctrl)):
        raise ProductError(f"control surface: at least 3 finite surveyed (E, N, H) points are needed; got "
                           f"shape {ctrl.shape}")
    return ctrl


def _adjust(pulses: PulseRecords, ctrl: np.ndarray | None,
            select: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], candidates: np.ndarray | None, *,
            sd_control_m: float, sd_strip_m: float, max_iter: int, tol: float,
            progress: Callable[[int, int], None] | None, start: SystemParameters | None = None,
            freeze_at: int = 1) -> CalibrationResult:
    """The Gauss-Newton iteration of :func:`estimate_system_parameters` (module docstring), from *start*
    (default zero).

    ``select(points)`` gives the strip pairs at the iterations up to
    *freeze_at*; *candidates* (indices) are the pulses tried against the
    control TIN then (None: all).  The robust rejection of iteration
    *freezes_at* freezes the observations for the iterations after it.
    """
    q = np.zeros(4) if start is None else np.nan_to_num(start.as_array())
    free = np.array([True, True, True, ctrl is not None])
    u = int(free.sum())
    notes = [] if ctrl is not None else ["no control surface: the elevation bias is not observable "
                                         "(strip differences cancel it) and is left out"]
    before: dict[str, float] = {}
    cuse: np.ndarray | None = None
    pairs: tuple[np.ndarray, np.ndarray] | None = None
    ninv = np.eye(u)
    v = w = np.zeros(0)
    n_iter, vc, vs = 0, np.zeros(0), np.zeros(0)
    for it in range(max_iter + 1):
        sp = SystemParameters.from_array(q)
        p, jac = georeference(pulses, sp), geolocation_partials(pulses, sp)
        vc, ac = np.zeros(0), np.zeros((0, 4))
        if ctrl is not None:
            vc, ac, cidx = _control_rows(p, jac, ctrl, cuse if cuse is not None else candidates)
        pa, nb = pairs if pairs is not None else select(p)
        vs, as_ = _strip_rows(p, jac, pa, nb)
        if it == 0:
            before = {"control": _rms(vc), "strip": _rms(vs)}
        if pairs is None:
            kc, ks = _keep(vc), _keep(vs)
            vc, ac, vs, as_ = vc[kc], ac[kc], vs[ks], as_[ks]
            if it >= freeze_at:              # freeze the observations from the third iteration on
                cuse = cidx[kc] if ctrl is not None else None
                pairs = (pa[ks], nb[ks])
        v = np.concatenate([vc, vs])
        a = np.concatenate([ac, as_])[:, free]
        w = np.concatenate([np.full(vc.size, sd_control_m**-2), np.full(vs.size, 0.25 * sd_strip_m**-2)])
        if v.size <= u:
            raise ProductError(f"system calibration: {v.size} observations ({vc.size} on the control surface, "
                               f"{vs.size} between strips) for {u} parameters; the strips must overlap each "
                               "other or the control surface")
        nmat = a.T @ (a * w[:, None])
        try:
            ninv = np.linalg.inv(nmat)
        except np.linalg.LinAlgError:
            ninv = np.full((u, u), np.nan)
        if not np.all(np.isfinite(ninv)) or np.linalg.cond(nmat) > 1e14:
            names = ", ".join(n for n, f in zip(PARAMETER_NAMES, free) if f)
            raise ProductError(f"system calibration: the normal matrix of ({names}) is singular; fly strips "
                               "in both directions over sloped terrain and a control surface across the scan")
        if it == max_iter:
            break
        dq = -ninv @ (a.T @ (w * v))
        q[free] += dq
        n_iter = it + 1
        if progress is not None:
            progress(n_iter, max_iter)
        if pairs is not None and it > freeze_at and np.max(np.abs(dq)) < tol:
            # residuals at the final parameters for sigma0
            sp = SystemParameters.from_array(q)
            p, jac = georeference(pulses, sp), geolocation_partials(pulses, sp)
            vc = _control_rows(p, jac, ctrl, cuse)[0] if ctrl is not None else np.zeros(0)
            vs = _strip_rows(p, jac, *pairs)[0]
            v = np.concatenate([vc, vs])
            break
    after = {"control": _rms(vc), "strip": _rms(vs)}
    sigma0 = float(np.sqrt(np.sum(w * v * v) / (vc.size + 0.5 * vs.size - u)))
    sd = np.full(4, math.nan)
    sd[free] = sigma0 * np.sqrt(np.diag(ninv))
    corr = np.full((4, 4), math.nan)
    s = np.sqrt(np.diag(ninv))
    corr[np.ix_(free, free)] = ninv / np.outer(s, s)
    if ctrl is None:
        q[3] = math.nan
    return CalibrationResult(SystemParameters.from_array(q), SystemParameters.from_array(sd), sigma0,
                             int(vc.size), int(vs.size), n_iter, corr, before, after, tuple(notes))


# ----------------------------------------------------------------------------- tile by tile


@dataclass(frozen=True, eq=False)
class CalibrationObservations:
    """Observations of the system calibration chosen at the delivered points, tile by tile (module
    docstring, "Tile by tile").

    Attributes
    ----------
    pulses : PulseRecords
        The pulses the observations refer to (only those).
    control : (C,) int
        Pulses tried against the control TIN (inside it at the delivered points).
    point : (M,) int
        Strip observations: the point of strip A ...
    neighbours : (M, k) int
        ... and its plane neighbours in strip B.
    control_key, strip_key : (C,) and (M,) uint64
        The observations' sampling keys (a hash of the point, and of strip B).
    seen_control, seen_strip : int
        Observations found before the bounded sample.
    """

    pulses: PulseRecords
    control: np.ndarray
    point: np.ndarray
    neighbours: np.ndarray
    control_key: np.ndarray
    strip_key: np.ndarray
    seen_control: int = 0
    seen_strip: int = 0

    _ARRAYS = ("control", "point", "neighbours", "control_key", "strip_key")

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The arrays to save (``numpy.savez``); :meth:`from_arrays` reads them back."""
        p = self.pulses
        return {"gnss_m": p.gnss_m, "attitude_rad": p.attitude_rad, "range_m": p.range_m, "scan_rad": p.scan_rad,
                "strip": p.strip, **{n: getattr(self, n) for n in self._ARRAYS},
                "seen": np.array([self.seen_control, self.seen_strip], dtype=np.int64)}

    @classmethod
    def from_arrays(cls, z: dict[str, np.ndarray]) -> CalibrationObservations:
        pulses = PulseRecords(z["gnss_m"].reshape(-1, 3), z["attitude_rad"].reshape(-1, 3), z["range_m"],
                              z["scan_rad"], z["strip"])
        k = z["neighbours"].shape[1] if z["neighbours"].ndim == 2 else 0
        return cls(pulses, z["control"].astype(np.int64), z["point"].astype(np.int64),
                   z["neighbours"].astype(np.int64).reshape(-1, k), z["control_key"].astype(np.uint64),
                   z["strip_key"].astype(np.uint64), int(z["seen"][0]), int(z["seen"][1]))


_GOLDEN, _M1, _M2 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser of uint64 values (wrapping arithmetic): a well-spread hash."""
    x = np.asarray(x, dtype=np.uint64) + _GOLDEN
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


def point_keys(points_m: np.ndarray, time_s: np.ndarray | None = None) -> np.ndarray:
    """(N,) uint64 hash of each point's coordinates (and GPS time): the same point gets the same key in
    whichever tile or buffer it is read, so a sample by the smallest keys does not depend on the tiling."""
    p = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    h = np.zeros(len(p), dtype=np.uint64)
    cols = [p[:, 0], p[:, 1], p[:, 2]] + ([np.asarray(time_s, dtype=np.float64).ravel()] if time_s is not None
                                          else [])
    for c in cols:
        h = _mix(h ^ np.ascontiguousarray(c).view(np.uint64))
    return h


def _smallest(keys: np.ndarray, m: int | None) -> np.ndarray:
    """Indices of the *m* smallest keys (all when None), in key order."""
    if m is not None and keys.size > m:
        sel = np.argpartition(keys, m - 1)[:m] if m > 0 else np.zeros(0, dtype=np.int64)
        return sel[np.argsort(keys[sel], kind="stable")]
    return np.argsort(keys, kind="stable")


def _compact(pulses: PulseRecords, control: np.ndarray, point: np.ndarray, neighbours: np.ndarray,
             control_key: np.ndarray, strip_key: np.ndarray, seen: tuple[int, int]) -> CalibrationObservations:
    """Keep only the pulses the observations refer to; renumber."""
    used = np.unique(np.concatenate([control, point, neighbours.ravel()]).astype(np.int64))

    def remap(i: np.ndarray) -> np.ndarray:
        return np.searchsorted(used, i).astype(np.int64)
    return CalibrationObservations(pulses.subset(used), remap(control), remap(point),
                                   remap(neighbours).reshape(neighbours.shape), control_key, strip_key, *seen)


def select_observations(pulses: PulseRecords, control_m: np.ndarray | None = None, *, own: np.ndarray | None = None,
                        keys: np.ndarray | None = None, at: SystemParameters | None = None, radius_m: float = 2.5,
                        k: int = 6, max_plane_rms_m: float = 0.15, stride: int = 1, max_control: int | None = None,
                        max_strip: int | None = None) -> CalibrationObservations:
    """The observations of one tile, chosen at the points georeferenced with *at* (the map step; module
    docstring, "Tile by tile").

    Parameters
    ----------
    pulses : PulseRecords
        The tile's pulses followed by its neighbours' within ``radius_m``.
    control_m : (M, 3) float, optional
        Control surface: the tile's points inside its TIN are control candidates.
    own : (N,) bool, optional
        The tile's own pulses (default all): the control candidates and the
        points of strip A are taken among them, the plane neighbours among all.
    keys : (N,) uint64, optional
        :func:`point_keys` of the pulses (default: of their georeferenced points).
    at : SystemParameters, optional
        The parameters the points are georeferenced with to choose the
        observations (default zero: the delivered points; the second pass:
        the first pass's step).
    radius_m, k, max_plane_rms_m, stride
        As :func:`estimate_system_parameters`.
    max_control, max_strip : int, optional
        Keep at most this many observations of each kind: those of the
        smallest keys (the merge keeps the smallest of all tiles, so the
        sample is the same however the survey is tiled).
    """
    ctrl = _control_array(control_m)
    p = georeference(pulses, None if at is None else SystemParameters.from_array(np.nan_to_num(at.as_array())))
    own = np.ones(len(pulses), dtype=bool) if own is None else np.asarray(own, dtype=bool)
    keys = point_keys(p) if keys is None else np.asarray(keys, dtype=np.uint64)
    cidx = np.zeros(0, dtype=np.int64)
    if ctrl is not None and len(pulses):
        from scipy.spatial import Delaunay

        from ..geometry.tin import TinLocator

        origin = ctrl[:, :2].mean(axis=0)
        mine = np.flatnonzero(own)
        simplex, _ = TinLocator(Delaunay(ctrl[:, :2] - origin)).locate(p[mine, :2] - origin)
        cidx = mine[simplex >= 0]
    if len(np.unique(pulses.strip)) > 1:
        pa, nb = _strip_pairs(p, pulses.strip, radius_m=radius_m, k=k, max_plane_rms_m=max_plane_rms_m,
                              stride=max(1, int(stride)), own=own)
    else:
        pa, nb = np.zeros(0, dtype=np.int64), np.zeros((0, k), dtype=np.int64)
    ck = _mix(keys[cidx])
    sk = _mix(keys[pa] ^ _mix(pulses.strip[nb[:, 0]].astype(np.uint64))) if pa.size else np.zeros(0, np.uint64)
    cs, ss = _smallest(ck, max_control), _smallest(sk, max_strip)
    return _compact(pulses, cidx[cs], pa[ss], nb[ss], ck[cs], sk[ss], (int(cidx.size), int(pa.size)))


def merge_observations(parts: Sequence[CalibrationObservations], *, max_control: int | None = None,
                       max_strip: int | None = None) -> CalibrationObservations:
    """The tiles' observations as one set (the reduce step): the *max_control* / *max_strip* of the
    smallest keys over all tiles, in key order.

    Raises
    ------
    ProductError
        No part, or parts of different ``k``.
    """
    if not parts:
        raise ProductError("system calibration: no tile observations to merge")
    ks = {o.neighbours.shape[1] for o in parts}
    if len(ks) != 1:
        raise ProductError(f"system calibration: tile observations of different plane sizes k {sorted(ks)}")
    off = np.cumsum([0] + [len(o.pulses) for o in parts])

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(o.pulses, name) for o in parts])
    pulses = PulseRecords(cat("gnss_m"), cat("attitude_rad"), cat("range_m"), cat("scan_rad"), cat("strip"))
    control = np.concatenate([o.control + d for o, d in zip(parts, off)])
    point = np.concatenate([o.point + d for o, d in zip(parts, off)])
    nb = np.concatenate([o.neighbours + d for o, d in zip(parts, off)])
    ck = np.concatenate([o.control_key for o in parts])
    sk = np.concatenate([o.strip_key for o in parts])
    cs, ss = _smallest(ck, max_control), _smallest(sk, max_strip)
    seen = (sum(o.seen_control for o in parts), sum(o.seen_strip for o in parts))
    return _compact(pulses, control[cs], point[ss], nb[ss], ck[cs], sk[ss], seen)


def estimate_from_observations(obs: CalibrationObservations, control_m: np.ndarray | None = None, *,
                               start: SystemParameters | None = None, sd_control_m: float = 0.05,
                               sd_strip_m: float = 0.05, max_iter: int = 10, tol: float = 1e-10,
                               progress: Callable[[int, int], None] | None = None) -> CalibrationResult:
    """:func:`estimate_system_parameters` on observations chosen tile by tile (:func:`select_observations`,
    :func:`merge_observations`; module docstring, "Tile by tile").

    Without *start*: the first pass, observations chosen at the delivered
    points; run it with ``max_iter=1`` for the step ``q1`` (its robust
    rejection included).  With ``start=q1``: the second pass, observations
    chosen at ``q1`` (``select_observations(at=q1)``), rejected once and
    frozen, iterated to convergence, as :func:`estimate_system_parameters`
    does from its second iteration on.

    Raises
    ------
    ProductError
        As :func:`estimate_system_parameters`.
    """
    ctrl = _control_array(control_m)
    pairs = (obs.point, obs.neighbours)
    res = _adjust(obs.pulses, ctrl, lambda p: pairs, obs.control, sd_control_m=sd_control_m,
                  sd_strip_m=sd_strip_m, max_iter=max_iter, tol=tol, progress=progress, start=start,
                  freeze_at=1 if start is None else 0)
    notes = list(res.notes)
    for what, kept, seen in (("control", obs.control.size, obs.seen_control),
                             ("strip", obs.point.size, obs.seen_strip)):
        if kept < seen:
            notes.append(f"{what} observations: a sample of {kept:,} of {seen:,} (the smallest point keys)")
    return dataclasses.replace(res, notes=tuple(notes))


def bounds_tile(job: TileJob) -> None:
    """The plan bounds of ``job.tile``'s points, measured (``.npz`` ``bounds`` = xmin, ymin, xmax, ymax; NaN
    without points): the tile engine takes LAS header bounds for unverified and makes every tile a neighbour
    of every other; the calibration's passes take their neighbours from these."""
    from .._util import atomic_write
    from ..lidar.readers import read_points

    xy = read_points(job.tile, crs=job.crs).xyz[:, :2]
    b = np.r_[xy.min(axis=0), xy.max(axis=0)] if len(xy) else np.full(4, np.nan)
    with atomic_write(job.output, "wb") as fh:
        np.savez(fh, bounds=b)


@functools.lru_cache(maxsize=1)
def _trajectory_of(path: str, sha256: str | None, crs_wkt: str | None) -> Any:
    from ..lidar.trajectory import read_trajectory

    return read_trajectory(path, crs_wkt)


def _trajectory(path: str, sha256: str | None, crs: Any) -> Any:
    """The trajectory *path* in *crs*, read once per process for the tiles of a run (keyed by its hash)."""
    from ..lidar.crs import resolve_crs

    c = resolve_crs(crs)
    return _trajectory_of(str(path), sha256 if sha256 else None, None if c is None else c.to_wkt()) \
        if sha256 else _trajectory_of.__wrapped__(str(path), None, None if c is None else c.to_wkt())


def calibration_tile(job: TileJob) -> None:
    """The map step of the system calibration on the tile engine (module docstring, "Tile by tile").

    Reads ``job.tile`` with its neighbours' points within ``job.overlap_m``
    (at least the plane radius), rebuilds the pulses from the trajectory
    ``job.params["trajectory"]`` and writes the tile's
    :class:`CalibrationObservations` to ``job.output`` (``.npz``, atomically),
    with the tile's point count, flight lines, along-track angles (sum of
    squares) and time-base note.  ``job.params``: ``trajectory``, ``control``
    (list of (E, N, H) or None), ``classes``, ``stride``, ``radius_m``, ``k``,
    ``max_plane_rms_m``, ``max_control``, ``max_strip`` (``trajectory_sha256``
    only marks the done-marker stale when the file changes).

    Raises
    ------
    ProductError
        The points carry no ``gps_time`` or ``point_source_id`` (names the tile); points outside the trajectory.
    """
    from .._util import atomic_write
    from ..lidar.jobs import read_with_buffer
    from ..lidar.trajectory import match_time_base

    cloud, n_own = read_with_buffer(job)
    a = cloud.attributes
    for name in ("gps_time", "point_source_id"):
        if name not in a:
            raise ProductError(f"{job.tile}: the points carry no {name}; the calibration joins points to the "
                               "trajectory by GPS time and to flight lines by point source id")
    prm = job.params
    gps_all = np.asarray(a["gps_time"], dtype=float)
    keys = point_keys(cloud.xyz, gps_all)
    keep = np.ones(len(cloud), dtype=bool)
    if prm.get("classes") is not None and "classification" in a:
        keep &= np.isin(a["classification"], list(prm["classes"]))
    stride = max(1, int(prm.get("stride", 1)))
    if stride > 1:     # by key, so a point kept in its tile is kept in its neighbours' buffers too
        keep &= (keys % np.uint64(stride)) == 0
    idx = np.flatnonzero(keep)
    own = idx < n_own
    traj = _trajectory(prm["trajectory"], prm.get("trajectory_sha256"), cloud.crs if cloud.crs is not None
                       else job.crs)
    gps, note = match_time_base(gps_all[idx], traj)
    strip = np.asarray(a["point_source_id"])[idx]
    if idx.size:
        sensor, att = traj.at(gps)
        pulses, along = pulses_from_points(cloud.xyz[idx], sensor, att, strip)
    else:
        pulses = PulseRecords(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
        along = np.zeros(0)
    ctrl = None if prm.get("control") is None else np.asarray(prm["control"], dtype=float)
    at = None if prm.get("at") is None else SystemParameters.from_array(prm["at"])
    obs = select_observations(pulses, ctrl, own=own, keys=keys[idx], at=at, radius_m=float(prm.get("radius_m", 2.5)),
                              k=int(prm.get("k", 6)), max_plane_rms_m=float(prm.get("max_plane_rms_m", 0.15)),
                              max_control=prm.get("max_control"), max_strip=prm.get("max_strip"))
    arrays = obs.to_arrays()
    arrays.update(n_points=np.int64(own.sum()), lines=np.unique(strip[own]).astype(np.int64),
                  along_ss=np.float64(np.sum(along[own] ** 2)), time_note=np.array(note))
    with atomic_write(job.output, "wb") as fh:
        np.savez(fh, **arrays)


# ----------------------------------------------------------------------------- planimetric check


@dataclass(frozen=True, eq=False)
class OutlineEdges:
    """The LiDAR corners of one surveyed outline (module docstring, "Planimetric check").

    Attributes
    ----------
    surveyed_m : (K, 2) float
        The outline's corners as given (without a closing repeat).
    lidar_m : (K, 2) float
        The corners from the LiDAR edges (NaN where an edge was not found).
    edge_offset_m : (K,) float
        Mean offset of the LiDAR edge from the surveyed edge ``i -> i+1`` along its outward normal (m).
    edge_bins : (K,) int
        Bins that fixed each edge.
    """

    surveyed_m: np.ndarray
    lidar_m: np.ndarray
    edge_offset_m: np.ndarray
    edge_bins: np.ndarray

    @property
    def discrepancies_m(self) -> np.ndarray:
        """(K, 2) ``lidar - surveyed`` (NaN rows where a corner was not found)."""
        return self.lidar_m - self.surveyed_m


def _spacing_m(xy: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    if len(xy) < 2:
        return math.nan
    d, _ = cKDTree(xy).query(xy, k=2)
    return float(np.median(d[:, 1]))


def lidar_outline_corners(outline_m: np.ndarray, roof_xyz: np.ndarray, low_xyz: np.ndarray | None = None, *,
                          band_m: float = 2.0, bin_m: float = 1.0, min_bins: int = 3,
                          spacing_m: float | None = None) -> OutlineEdges:
    """The corners of a surveyed building outline as the LiDAR sees them (module docstring).

    Parameters
    ----------
    outline_m : (K, 2) float
        Surveyed corners (E, N), K >= 3, in order (either way round; a closing repeat is dropped).
    roof_xyz : (N, 3) float
        Points on the roof (building class, or points well above the ground).
    low_xyz : (L, 3) float, optional
        Ground (low) points around the building: they bound the edge from outside.
    band_m, bin_m, min_bins
        Points within ``band_m`` of an edge, binned every ``bin_m`` along it; an edge needs ``min_bins``.
    spacing_m : float, optional
        Largest gap between the outermost roof point and the innermost low point that still brackets the
        edge (default: the median nearest-neighbour distance of the roof points); 3 x this.

    Raises
    ------
    ProductError
        Fewer than 3 distinct corners.
    """
    q = np.asarray(outline_m, dtype=float)[:, :2]
    if len(q) > 1 and np.allclose(q[0], q[-1]):
        q = q[:-1]
    if len(q) < 3:
        raise ProductError(f"a building outline needs at least 3 corners, got {len(q)}")
    xs, ys = q[:, 0], q[:, 1]
    ccw = (np.dot(xs, np.roll(ys, -1)) - np.dot(np.roll(xs, -1), ys)) > 0
    order = np.arange(len(q)) if ccw else np.arange(len(q))[::-1]
    qq = q[order]
    roof = np.asarray(roof_xyz, dtype=float)[:, :2]
    low = np.zeros((0, 2)) if low_xyz is None else np.asarray(low_xyz, dtype=float)[:, :2]
    s = spacing_m if spacing_m is not None else _spacing_m(roof)
    k = len(qq)
    lines = []
    offs = np.full(k, np.nan)
    nbins = np.zeros(k, dtype=int)
    for i in range(k):
        a, b = qq[i], qq[(i + 1) % k]
        length = float(np.hypot(*(b - a)))
        u = (b - a) / length
        n = np.array([u[1], -u[0]])
        nb = max(1, int(0.8 * length // bin_m))

        def local(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            r = xy - a
            return r @ u, r @ n

        tr, orr = local(roof)
        sel = (tr >= 0.1 * length) & (tr <= 0.9 * length) & (np.abs(orr) <= band_m)
        tr, orr = tr[sel], orr[sel]
        br = np.minimum(((tr - 0.1 * length) / (0.8 * length) * nb).astype(int), nb - 1)
        o_r = np.full(nb, -np.inf)
        np.maximum.at(o_r, br, orr)
        tl, ol = local(low)
        sel = (tl >= 0.1 * length) & (tl <= 0.9 * length) & (np.abs(ol) <= band_m)
        tl, ol = tl[sel], ol[sel]
        bl = np.minimum(((tl - 0.1 * length) / (0.8 * length) * nb).astype(int), nb - 1)
        beyond = ol > o_r[bl]
        o_g = np.full(nb, np.inf)
        np.minimum.at(o_g, bl[beyond], ol[beyond])
        have = np.isfinite(o_r)
        inner = np.count_nonzero((orr <= -0.5) & (orr >= -band_m))
        rho = inner / max(0.8 * length * (band_m - 0.5), 1e-9)
        gap = math.log(2.0) / max(rho * (0.8 * length / nb), 1e-9) if rho > 0 else 0.5 * s
        o_r, o_g = o_r[have], o_g[have]
        bracket = np.isfinite(o_g) & (o_g - o_r <= 3 * s)
        e_ok = np.where(bracket, 0.5 * (o_r + np.where(bracket, o_g, 0.0)), o_r + gap)
        if e_ok.size < min_bins:
            lines.append(None)
            continue
        offs[i] = float(np.median(e_ok))        # the edge parallel to the surveyed one
        lines.append((a + offs[i] * n, u))
        nbins[i] = int(e_ok.size)
    corners = np.full((k, 2), np.nan)
    for i in range(k):
        l1, l2 = lines[i - 1], lines[i]           # edges into and out of corner i
        if l1 is None or l2 is None:
            continue
        m = np.column_stack([l1[1], -l2[1]])
        if abs(np.linalg.det(m)) < 1e-6:
            continue
        t = np.linalg.solve(m, l2[0] - l1[0])
        corners[i] = l1[0] + t[0] * l1[1]
    back = np.argsort(order)
    # edge i of the given order runs from corner i to i+1: in reversed order it is edge (k - 2 - i) mod k
    edge_map = np.arange(k) if ccw else (k - 2 - np.arange(k)) % k
    return OutlineEdges(q, corners[back], offs[edge_map], nbins[edge_map])


def planimetric_accuracy(d_en_m: np.ndarray, *, checkpoint_sd_m: float | None = None,
                         scale: float | None = None) -> dict[str, Any]:
    """ASPRS 2023 horizontal accuracy and the PEC planimetric class of corner discrepancies (M, 2), m.

    Rows with NaN (corners not found) are left out and counted.

    Raises
    ------
    AssessmentError
        No finite discrepancy.
    """
    from ..errors import AssessmentError

    d = np.asarray(d_en_m, dtype=float).reshape(-1, 2)
    ok = np.all(np.isfinite(d), axis=1)
    if not ok.any():
        raise AssessmentError("planimetric check: no building corner was found in the LiDAR points")
    dd = np.column_stack([d[ok], np.zeros(int(ok.sum()))])
    sd = None if checkpoint_sd_m is None else np.array([checkpoint_sd_m, checkpoint_sd_m, 0.0])
    asprs = classify_asprs2023(dd, checkpoint_sd_m=sd)
    rx, ry = (float(np.sqrt(np.mean(dd[:, j] ** 2))) for j in (0, 1))
    # the heights are not compared: only the planimetric classes are kept
    a = asprs.to_dict()
    a["class"] = {"planimetric": a["class"]["planimetric"]}
    out = {"n_corners": int(ok.sum()), "n_missing": int((~ok).sum()), "rmse_x_m": rx, "rmse_y_m": ry,
           "rmse_r_m": math.hypot(rx, ry), "mean_dE_m": float(np.mean(dd[:, 0])),
           "mean_dN_m": float(np.mean(dd[:, 1])), "asprs2023": a, "pec": None}
    if scale is not None:
        p = classify_pec(dd, scale).to_dict()
        p["class"] = {"planimetric": p["class"]["planimetric"]}
        out["pec"] = p
    return out
