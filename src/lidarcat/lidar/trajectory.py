r"""Aircraft trajectories: Applanix SBET binary and plain CSV, interpolated at the points' GPS times.

LAS files carry neither the range nor the sensor position of a pulse; the
LiDAR system checks (:mod:`lidarcat.production.lidarchecks`) rebuild them from
the points and the trajectory of the flight, joined on GPS time.

SBET (Smoothed Best Estimate of Trajectory, Applanix POSPac; the format PDAL's
``readers.sbet`` reads): a headerless file of records of 17 little-endian
float64 (136 bytes)::

    0 time (GPS seconds of the week)   1 latitude (rad)   2 longitude (rad)
    3 altitude (m, ellipsoidal)         4-6 velocity x, y, z (m/s)
    7 roll (rad)   8 pitch (rad)   9 platform heading (rad, true, clockwise from north)
    10 wander angle (rad)   11-13 body accelerations   14-16 body angular rates

Roll, pitch and heading follow the aviation convention: body axes forward,
right, down (FRD) in a north-east-down frame, ``R = R_z(yaw) R_y(pitch)
R_x(roll)``; roll positive right wing down, pitch positive nose up.

CSV: a header and the columns ``time, E, N, H, roll_deg, pitch_deg,
heading_deg`` (metres in the map CRS; angles in the same aviation convention,
heading clockwise from *grid* north).

Conversion to the map frame
---------------------------
The checks use map axes ``(E, N, U)`` and body axes forward, left, up (FLU),
``R_ins = R_z(k) R_y(p) R_x(r)`` with ``k`` the counter-clockwise angle of the
body x axis from East.  With ``T`` the NED-to-ENU swap and ``D = diag(1, -1,
-1)`` the FRD-to-FLU flip, ``T R_z(psi) R_y(theta) R_x(phi) D = R_z(pi/2 - psi)
R_y(-theta) R_x(phi)`` (checked numerically in the tests), so::

    r = roll,   p = -pitch,   k = pi/2 - psi_grid

SBET's heading is *true* (from the meridian); the grid heading ``psi_grid`` is
found without a convergence formula: the point one metre ahead along the true
azimuth (pyproj ``Geod.fwd`` on the ellipsoid of WGS 84) is projected with the
position, and ``psi_grid = atan2(dE, dN)`` of the two projected points.  The
SBET position is projected from WGS 84 (EPSG:4979, 3-D) into the map CRS; a
map CRS without a vertical part keeps the ellipsoidal altitude (the LiDAR
heights must then be ellipsoidal too).

Interpolation
-------------
Position and attitude are linear in time between the two records bracketing
a GPS time (headings unwrapped first, so that a turn through north does not
spin the other way).  A time outside the trajectory is an error naming the
first such point.

GPS time bases
--------------
SBET time is seconds of the GPS week; LAS 1.2+ point times are often
*adjusted standard* GPS time (seconds since 1980-01-06 minus 10^9).
:func:`match_time_base` converts the point times to seconds of the week when
the trajectory is in week seconds and the point times are not
(``(t + 1e9) mod 604800``); it cannot know the week, so a survey crossing a
week boundary (Saturday/Sunday midnight UTC) must be split.

The sensor is taken at the trajectory's reference point: lever arms are not
modelled (a constant lever arm moves every point of a strip alike and goes
into the elevation bias and, across the scan, into nothing else).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import LidarFormatError, ProductError

__all__ = ["Trajectory", "SBET_FIELDS", "read_sbet", "write_sbet", "read_trajectory_csv", "read_trajectory",
           "match_time_base", "aviation_to_map", "map_to_aviation", "END_TOLERANCE_S"]

#: the 17 fields of an SBET record, in file order
SBET_FIELDS = ("time", "latitude", "longitude", "altitude", "x_velocity", "y_velocity", "z_velocity",
               "roll", "pitch", "heading", "wander_angle", "x_acceleration", "y_acceleration",
               "z_acceleration", "x_angular_rate", "y_angular_rate", "z_angular_rate")

_WEEK_S = 604800.0
#: how far (s) a time may lie outside a trajectory's records and still take the end record's pose
END_TOLERANCE_S = 1e-6


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A trajectory in the map frame.

    Attributes
    ----------
    time_s : (N,) float
        GPS time of each record, increasing (s).
    position_m : (N, 3) float
        Sensor position E, N, h (m, map CRS).
    attitude_rad : (N, 3) float
        Roll, pitch, heading in the map convention of
        :mod:`lidarcat.production.lidarchecks` (body forward-left-up, heading
        counter-clockwise from East), rad.
    crs : pyproj.CRS or None
    source : str
        The file read (for messages).
    """

    time_s: np.ndarray
    position_m: np.ndarray
    attitude_rad: np.ndarray
    crs: Any = None
    source: str = "trajectory"

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s, dtype=float).ravel()
        n = t.size
        if n < 2:
            raise ProductError(f"{self.source}: a trajectory needs at least 2 records, got {n}")
        for name, shape in (("position_m", (n, 3)), ("attitude_rad", (n, 3))):
            a = np.asarray(getattr(self, name), dtype=float)
            if a.shape != shape:
                raise ProductError(f"{self.source}: {name} must have shape {shape}, got {a.shape}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            i = int(bad[0]) + 1
            raise ProductError(f"{self.source}: record {i + 1}: time {t[i]:.6f} s does not increase "
                               f"(previous {t[i - 1]:.6f} s)")
        for name in ("position_m", "attitude_rad"):
            a = np.array(getattr(self, name), dtype=float)
            if not np.all(np.isfinite(a)):
                i = int(np.flatnonzero(~np.all(np.isfinite(a), axis=1))[0])
                raise ProductError(f"{self.source}: record {i + 1}: {name} is not finite")
            a.setflags(write=False)
            object.__setattr__(self, name, a)
        t = t.copy()
        t.setflags(write=False)
        object.__setattr__(self, "time_s", t)

    def __len__(self) -> int:
        return int(self.time_s.size)

    def at(self, time_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Position (M, 3) and attitude (M, 3) at GPS times (M,), linear between records.

        A time up to :data:`END_TOLERANCE_S` (1 microsecond) before the first record or after the
        last takes that record's pose: converting adjusted standard GPS time to week seconds
        rounds the last point of a flight ~1e-10 s past the end (at 70 m/s a microsecond is 0.07 mm).

        Raises
        ------
        ProductError
            A time outside the trajectory (names the first such point, 1-based, and its time).
        """
        t = np.asarray(time_s, dtype=float).ravel()
        out = np.flatnonzero(~((t >= self.time_s[0] - END_TOLERANCE_S) & (t <= self.time_s[-1] + END_TOLERANCE_S)))
        if out.size:
            i = int(out[0])
            raise ProductError(f"point {i + 1}: GPS time {t[i]:.6f} s is outside the trajectory "
                               f"{self.source} ({self.time_s[0]:.3f} .. {self.time_s[-1]:.3f} s; "
                               f"{out.size} points outside)")
        j = np.clip(np.searchsorted(self.time_s, t, side="right") - 1, 0, len(self) - 2)
        w = np.clip((t - self.time_s[j]) / (self.time_s[j + 1] - self.time_s[j]), 0.0, 1.0)[:, None]
        pos = (1 - w) * self.position_m[j] + w * self.position_m[j + 1]
        att = np.unwrap(self.attitude_rad, axis=0)
        a = (1 - w) * att[j] + w * att[j + 1]
        return pos, a


def aviation_to_map(roll: np.ndarray, pitch: np.ndarray, heading_grid: np.ndarray) -> np.ndarray:
    """Aviation roll, pitch, grid heading (rad, FRD/NED) to the map convention (r, p, k), (N, 3)."""
    return np.column_stack([np.asarray(roll, float), -np.asarray(pitch, float),
                            0.5 * math.pi - np.asarray(heading_grid, float)])


def map_to_aviation(attitude_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`aviation_to_map`: roll, pitch, grid heading in [0, 2 pi) (rad)."""
    a = np.asarray(attitude_rad, dtype=float)
    return a[:, 0], -a[:, 1], np.mod(0.5 * math.pi - a[:, 2], 2 * math.pi)


def _geographic_transformers(crs: Any) -> tuple[Any, Any]:
    import pyproj

    from .crs import resolve_crs

    c = resolve_crs(crs)
    if c is None:
        raise ProductError("an SBET trajectory is geographic: give the CRS of the LiDAR points to project it into")
    src = pyproj.CRS.from_epsg(4979)
    fwd = pyproj.Transformer.from_crs(src, c, always_xy=True)
    inv = pyproj.Transformer.from_crs(c, src, always_xy=True)
    return fwd, inv


def read_sbet(path: str | os.PathLike, crs: Any) -> Trajectory:
    """Read an Applanix SBET file and project it into *crs* (module docstring).

    Raises
    ------
    LidarFormatError
        A size that is not a whole number of 136-byte records (names the file and the size),
        or no record.
    ProductError
        No CRS given; times that do not increase (names the record).
    """
    import pyproj

    p = Path(path)
    size = p.stat().st_size
    if size == 0 or size % (17 * 8):
        raise LidarFormatError(f"{p}: {size} bytes is not a whole number of 136-byte SBET records "
                               "(17 little-endian doubles each)")
    rec = np.fromfile(p, dtype="<f8").reshape(-1, 17)
    fwd, _ = _geographic_transformers(crs)
    lat, lon, alt = np.degrees(rec[:, 1]), np.degrees(rec[:, 2]), rec[:, 3]
    e, n, h = fwd.transform(lon, lat, alt)
    geod = pyproj.Geod(ellps="WGS84")
    lon2, lat2, _ = geod.fwd(lon, lat, np.degrees(rec[:, 9]), np.ones_like(lon))
    e2, n2, _ = fwd.transform(lon2, lat2, alt)
    grid = np.arctan2(np.asarray(e2) - e, np.asarray(n2) - n)
    pos = np.column_stack([e, n, h])
    return Trajectory(rec[:, 0], pos, aviation_to_map(rec[:, 7], rec[:, 8], grid), crs=fwd.target_crs,
                      source=str(p))


def write_sbet(path: str | os.PathLike, trajectory: Trajectory, crs: Any = None) -> Path:
    """Write *trajectory* (map frame) as an SBET file (velocities, accelerations and rates zero).

    For tests and for exchanging a trajectory built here; written atomically.
    """
    import pyproj

    from .._util import atomic_write

    _, inv = _geographic_transformers(crs if crs is not None else trajectory.crs)
    pos = trajectory.position_m
    lon, lat, alt = inv.transform(pos[:, 0], pos[:, 1], pos[:, 2])
    roll, pitch, grid = map_to_aviation(trajectory.attitude_rad)
    lon2, lat2, _ = inv.transform(pos[:, 0] + np.sin(grid), pos[:, 1] + np.cos(grid), pos[:, 2])
    az = pyproj.Geod(ellps="WGS84").inv(lon, lat, lon2, lat2)[0]
    rec = np.zeros((len(trajectory), 17))
    rec[:, 0] = trajectory.time_s
    rec[:, 1], rec[:, 2], rec[:, 3] = np.radians(lat), np.radians(lon), alt
    rec[:, 7], rec[:, 8], rec[:, 9] = roll, pitch, np.mod(np.radians(az), 2 * math.pi)
    out = Path(path)
    with atomic_write(out, "wb") as f:
        f.write(rec.astype("<f8").tobytes())
    return out


def read_trajectory_csv(path: str | os.PathLike, crs: Any = None) -> Trajectory:
    """Read a CSV trajectory ``time,E,N,H,roll_deg,pitch_deg,heading_deg`` (module docstring).

    Raises
    ------
    SurveyError
        A missing column or a bad number (names file, line and column).
    ProductError
        Fewer than 2 records, times that do not increase (names the record).
    """
    from .._util.tables import read_csv_table
    from .crs import resolve_crs

    t = read_csv_table(path, ("time", "E", "N", "H", "roll_deg", "pitch_deg", "heading_deg"))
    pos = np.column_stack([t.floats("E"), t.floats("N"), t.floats("H")])
    att = aviation_to_map(np.radians(t.floats("roll_deg")), np.radians(t.floats("pitch_deg")),
                          np.radians(t.floats("heading_deg")))
    return Trajectory(t.floats("time"), pos, att, crs=resolve_crs(crs), source=str(path))


def read_trajectory(path: str | os.PathLike, crs: Any = None) -> Trajectory:
    """A trajectory file by its suffix: ``.csv``/``.txt`` CSV, anything else (``.out``, ``.sbet``) SBET."""
    if Path(path).suffix.lower() in (".csv", ".txt"):
        return read_trajectory_csv(path, crs)
    return read_sbet(path, crs)


def match_time_base(point_time_s: np.ndarray, trajectory: Trajectory) -> tuple[np.ndarray, str]:
    """Point GPS times in the trajectory's time base, and what was done (module docstring).

    Returns ``(times, note)``: the times unchanged when they fall in the
    trajectory's span, or converted from adjusted standard GPS time to seconds
    of the week when the trajectory is in week seconds.
    """
    t = np.asarray(point_time_s, dtype=float)
    t0, t1 = trajectory.time_s[0], trajectory.time_s[-1]
    if t.size == 0 or np.mean((t >= t0) & (t <= t1)) > 0.5:
        return t, "point times in the trajectory's time base"
    if 0.0 <= t0 and t1 <= _WEEK_S:
        w = np.mod(t + 1e9, _WEEK_S)
        if np.mean((w >= t0) & (w <= t1)) > 0.5:
            return w, "point times converted from adjusted standard GPS time to seconds of the week"
    return t, "point times do not match the trajectory's time base"
