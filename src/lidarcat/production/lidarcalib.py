"""LiDAR system calibration (LACTEC report 7.1.2): boresight, scan-angle scale and elevation bias by least squares.

Roll and pitch misalignment between the scanner and the INS (boresight), the scan-angle scale factor and
the elevation bias, by least squares from (a) LiDAR points over a surveyed control surface (vertical)
and (b) the differences between overlapping strips; arrays in and out (no files).  The same estimate tile
by tile, with bounded memory, is :mod:`lidarcat.production.lidarcalib_tiles`; the checks against surveyed
points (vertical and planimetric accuracy) are :mod:`lidarcat.production.lidarchecks`.

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

Normal equations ``N dq = A^T P v`` (with the sign of a correction:
``dq = -N^-1 A^T P v``), ``sigma0^2 = v^T P v / (n_control + n_strip / 2 - u)`` and sds
``sigma0 sqrt(diag N^-1)``.  A parameter with no observation (the bias
without control points) is left out and reported as NaN.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import ProductError

__all__ = [
    "PARAMETER_NAMES",
    "PulseRecords",
    "SystemParameters",
    "CalibrationResult",
    "georeference",
    "geolocation_partials",
    "pulses_from_points",
    "estimate_system_parameters",
    "adjust_parameters",
    "control_array",
    "strip_pairs",
]

#: the calibration parameters, in the order of :meth:`SystemParameters.as_array`
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


def strip_pairs(p: np.ndarray, strip: np.ndarray, *, radius_m: float, k: int, max_plane_rms_m: float,
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
    ctrl = control_array(control_m)

    def select(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return strip_pairs(p, pulses.strip, radius_m=radius_m, k=k, max_plane_rms_m=max_plane_rms_m,
                           stride=stride)
    return adjust_parameters(pulses, ctrl, select, None, sd_control_m=sd_control_m, sd_strip_m=sd_strip_m,
                             max_iter=max_iter, tol=tol, progress=progress)


def control_array(control_m: np.ndarray | None) -> np.ndarray | None:
    """The control surface as an (M, 3) float array, M >= 3 (None stays None)."""
    if control_m is None:
        return None
    ctrl = np.asarray(control_m, dtype=float)
    if ctrl.ndim != 2 or ctrl.shape[1] != 3 or ctrl.shape[0] < 3 or not np.all(np.isfinite(ctrl)):
        raise ProductError(f"control surface: at least 3 finite surveyed (E, N, H) points are needed; got "
                           f"shape {ctrl.shape}")
    return ctrl


def adjust_parameters(pulses: PulseRecords, ctrl: np.ndarray | None,
                      select: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], candidates: np.ndarray | None,
                      *, sd_control_m: float, sd_strip_m: float, max_iter: int, tol: float,
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
