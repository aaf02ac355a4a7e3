r"""Rolling shutter in the bundle: linear motion during the read-out, and the residual test without it.

Model
-----
A rolling-shutter photo is read out row by row in the read-out time ``T`` (s) of its camera;
its exterior orientation holds at the middle of the read-out (as
:mod:`lidarcat.geometry.rolling`), and row ``v`` (pixel-centre origin, ``H`` rows) is exposed at

    t(v) = T ((v + 0.5) / H - 0.5)                       (-T/2 at the top edge, +T/2 at the bottom)

During the read-out the camera moves linearly, ``X0(t) = X0 + V t``.  The observation ``a`` of
point ``j`` on photo ``i`` at row ``v_a`` is then the collinearity of the projection centre
``X0_i + V_i t_a``:

    x_a = -c [M_i (X_j - X0_i - V_i t_a)]_{1,2} / [M_i (X_j - X0_i - V_i t_a)]_3

which is the plain collinearity of the shifted point ``X_j - V_i t_a`` -- a per-observation
centre offset ``o_a = V_i t_a`` (:mod:`.rays`), with the Jacobians by the exterior
orientation and the point unchanged in form.  The rotation during the read-out is not
modelled: a drone's gimbal holds the attitude; a turning camera needs the angular velocity of
:mod:`lidarcat.geometry.rolling` (not in the bundle yet).

The row.  ``t_a`` is taken at the *measured* row ``v_a``, not at the row the model predicts
(the engine of :func:`lidarcat.geometry.rolling.project_rolling` solves ``v = P_v(t(v))``).
The two differ by ``a_v tau (v_pred - v_obs)`` px, with ``a_v tau = f V T / (Z H)`` the image
motion during one row's read-out time in rows per row: 0.003 for a drone 100 m up at 10 m/s
with f = 3000 px, 30 ms and 3000 rows -- a 0.3 % change of a residual, far below the noise.
With the measured row the offset is a constant of each observation (not of the unknowns) and
the model stays the plain collinearity of :mod:`.model`.

Velocity
--------
By default ``V_i`` comes from the neighbouring exposures of the same flight line:
``V_i = (X_{i+1} - X_{i-1}) / (t_{i+1} - t_{i-1})`` (one-sided at the line's ends) from
the GNSS (or approximate) camera positions and the exposure times
(:func:`neighbour_velocities`); it is then known and enters only the offsets
(:func:`with_rolling_shutter`).  Estimated per photo, ``V_i = V_i^0 + delta_i`` with three
additional unknowns per photo bordering the normal equations (:class:`VelocityCorrections`,
a component of :func:`lidarcat.bundle.adjust_with_parameters`), with the prior
``delta_i = 0 +- sd`` (free with ``sd = inf``), and

    dx_a / d delta_i = -a_pt,a t_a          (a_pt = dx/dX, the point's Jacobian at the shifted point)

Tests without the model
-----------------------
A rolling-shutter photo adjusted as a global-shutter one should keep a residual trend with the
row: the image moves by ``-f V t(v) / Z``, linear in ``v``.  Measured on the drone block of
:func:`lidarcat.synthetic.drone.drone_block` (docs/figures.md) the bundle absorbs almost all of
it -- a row slope of 0.014 px per 1000 rows is left of the 3 px per 1000 rows of the motion --
into the orientations and the ground (whose errors grow 3-4x).  Two tests, therefore:

* :class:`ReadoutTime` estimates the read-out time of each camera, ``tau_c``, as an additional
  unknown from the block adjusted without it: the residuals' trend with the row *in the
  direction of the image motion*, with the bundle's own geometry (what the orientations absorb
  is taken out by the bordered normal equations).  Its t-value ``tau / sd`` is the test
  (:func:`readout_warning`: located at the camera, with the value to set).
* :func:`row_trend` fits, per photo and per image axis, ``r = a + b (v - mean v)`` to the
  residuals and gives ``t = b sqrt(S_vv) / s`` (``s^2`` the scatter about the line, ``n - 2``
  degrees of freedom), the block's ``sum t^2`` (against chi-square: conservative, the residuals
  are those of an adjustment: 27 for 60 degrees of freedom on a global-shutter block) and
  ``pooled_t``, the sum of the photos' t over ``sqrt(P)`` per axis: the pattern to report.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import stats

from .._util.frozen import frozen_array
from ..errors import CameraError
from .problem import BundleProblem
from .rays import ObservationRays

__all__ = ["row_times", "row_fractions", "neighbour_velocities", "with_rolling_shutter", "VelocityCorrections",
           "ReadoutTime", "readout_warning", "RowTrend", "row_trend"]


def row_times(row_px: Any, height_px: Any, readout_s: Any) -> np.ndarray:
    """Exposure time of each observation's row relative to the middle of the read-out, s (n,).

    Parameters
    ----------
    row_px : (n,) array
        Measured row (pixel-centre origin, down).
    height_px, readout_s : (n,) arrays or scalars
        Rows of the observation's camera and its read-out time (s; 0 = global shutter).

    >>> row_times([-0.5, 1499.5, 2999.5], 3000, 0.03).round(6)
    array([-0.015,  0.   ,  0.015])
    """
    v = np.asarray(row_px, dtype=float)
    return np.asarray(readout_s, dtype=float) * ((v + 0.5) / np.asarray(height_px, dtype=float) - 0.5)


def row_fractions(row_px: Any, height_px: Any) -> np.ndarray:
    """``s = (v + 0.5) / H - 0.5`` of each observation (n,), from -0.5 (top edge) to 0.5: ``t = T s``."""
    return (np.asarray(row_px, dtype=float) + 0.5) / np.asarray(height_px, dtype=float) - 0.5


def neighbour_velocities(positions_m: Any, times_s: Any, line: Sequence[Any] | None = None) -> np.ndarray:
    """Velocity of every exposure from its neighbours in the same flight line, m/s (P, 3).

    Central differences ``(X_{i+1} - X_{i-1}) / (t_{i+1} - t_{i-1})`` over the exposures of a
    line in time order, one-sided at its ends; a line of one exposure gets zero (no motion known).

    Parameters
    ----------
    positions_m : (P, 3) array
        Camera positions (GNSS or approximate), m.
    times_s : (P,) array
        Exposure times, s (any origin).
    line : sequence, (P,), optional
        Flight-line label of every exposure (default: one line).

    Raises
    ------
    CameraError
        Two exposures of a line at the same time (names the line).
    """
    x = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    t = np.asarray(times_s, dtype=float).ravel()
    labels = [0] * len(x) if line is None else list(line)
    v = np.zeros_like(x)
    for lab in dict.fromkeys(labels):
        idx = np.flatnonzero([lb == lab for lb in labels])
        idx = idx[np.argsort(t[idx], kind="stable")]
        if len(idx) < 2:
            continue
        if np.any(np.diff(t[idx]) <= 0):
            raise CameraError(f"flight line {lab!r}: two exposures at the same time")
        nxt = np.r_[idx[1:], idx[-1]]
        prv = np.r_[idx[0], idx[:-1]]
        v[idx] = (x[nxt] - x[prv]) / (t[nxt] - t[prv])[:, None]
    return v


def with_rolling_shutter(problem: BundleProblem, time_s: Any, velocity_m_s: Any) -> BundleProblem:
    """*problem* with the centre offsets ``V_i t_a`` of a known velocity (module docstring).

    Parameters
    ----------
    time_s : (n,) array
        Row time of every observation (:func:`row_times`), s.
    velocity_m_s : (P, 3) array
        Velocity of every photo, m/s.
    """
    p = problem
    t = np.asarray(time_s, dtype=float).ravel()
    v = np.asarray(velocity_m_s, dtype=float).reshape(p.n_photos, 3)
    if len(t) != len(p.photo_index):
        raise CameraError(f"`time_s` has {len(t)} entries for {len(p.photo_index)} observations")
    off = v[p.photo_index] * t[:, None]
    old = p.rays
    rays = (ObservationRays(centre_offset_m=off) if old is None
            else dataclasses.replace(old, centre_offset_m=off))
    return dataclasses.replace(p, rays=rays)


@dataclasses.dataclass(frozen=True, eq=False)
class VelocityCorrections:
    """Per-photo corrections to the velocity as additional unknowns (component of
    :func:`lidarcat.bundle.adjust_with_parameters`; module docstring).

    Parameters
    ----------
    time_s : (n,) array
        Row time of every observation, s.
    velocity_m_s : (P, 3) array
        The velocity the corrections start from (e.g. :func:`neighbour_velocities`), m/s.
    sd_m_s : float
        Prior sd of each correction, m/s (inf: free; a free velocity of a photo costs its pose a
        factor 2, docs/cameras.md).
    photos : sequence of int, optional
        The photos whose velocity is estimated (default: every photo with a nonzero read-out).
    """

    time_s: Any
    velocity_m_s: Any
    sd_m_s: float = np.inf
    photos: Sequence[int] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_s", frozen_array(np.ravel(self.time_s)))
        object.__setattr__(self, "velocity_m_s", frozen_array(np.reshape(self.velocity_m_s, (-1, 3))))

    def bind(self, problem: BundleProblem) -> _BoundVelocity:
        return _BoundVelocity(self, problem)


class _BoundVelocity:
    group_kind = "photo"

    def __init__(self, spec: VelocityCorrections, problem: BundleProblem):
        ei = problem.photo_index
        if len(spec.time_s) != len(ei) or len(spec.velocity_m_s) != problem.n_photos:
            raise CameraError("velocity corrections: `time_s` needs one entry per observation and "
                             "`velocity_m_s` one row per photo")
        if spec.photos is None:
            photos = np.unique(ei[spec.time_s != 0])
        else:
            photos = np.unique(np.asarray(spec.photos, dtype=np.int64))
        self.photos = photos
        self.col_of_photo = np.full(problem.n_photos, -1)
        self.col_of_photo[photos] = np.arange(len(photos))
        self.rows = np.flatnonzero(self.col_of_photo[ei] >= 0)
        self.t = spec.time_s
        self.v0 = spec.velocity_m_s
        self.ei = ei
        self.m = 3
        self.n = 3 * len(photos)
        self.names = [f"{problem.photo_ids[i]}.v{c}" for i in photos for c in "ENh"]
        self.units = ["m/s"] * self.n
        self.groups = [f"photo {problem.photo_ids[i]}" for i in photos for _ in range(3)]
        sd = float(spec.sd_m_s)
        self.prior_sd = np.full(self.n, sd if sd > 0 else np.inf)
        self.calibrated = np.asarray(self.v0)[photos].ravel()      # the start (the result's value = start + estimate)
        self.notes: list[str] = []

    def velocity(self, theta: np.ndarray) -> np.ndarray:
        """Velocity of every photo at the corrections *theta*, (P, 3) m/s."""
        v = np.array(self.v0, dtype=float)
        v[self.photos] += np.reshape(theta, (-1, 3))
        return v

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        off = self.velocity(theta)[self.ei] * self.t[:, None]
        old = fields.get("rays")
        fields["rays"] = (ObservationRays(centre_offset_m=off) if old is None
                          else dataclasses.replace(old, centre_offset_m=off))

    def jacobians(self, theta: np.ndarray, state) -> list:
        r = self.rows
        J = -state.a_pt[r] * self.t[r, None, None]                      # (r, 2, 3)
        cols = (3 * self.col_of_photo[self.ei[r]])[:, None] + np.arange(3)[None, :]
        return [("obs", r, J, cols)]


@dataclasses.dataclass(frozen=True, eq=False)
class ReadoutTime:
    """The read-out time of every camera as an additional unknown (component of
    :func:`lidarcat.bundle.adjust_with_parameters`; module docstring, "Residual test").

    ``o_a = V_i (T_c + tau_c) s_a`` with ``s_a`` the row fraction (:func:`row_fractions`) and
    ``dx_a / d tau_c = -a_pt,a V_i s_a``.  Estimated from a block adjusted with ``T_c = 0``
    (the model off) it is the test of a rolling shutter: its t-value ``tau / sd`` is large
    where the camera has one (:func:`readout_warning`); with ``T_c`` given it checks the value.

    Parameters
    ----------
    row_fraction : (n,) array
        ``s_a`` of every observation.
    velocity_m_s : (P, 3) array
        Velocity of every photo (:func:`neighbour_velocities`).
    camera_of_photo : sequence of str, (P,)
    readout_s : mapping of str to float, optional
        The read-out time the correction starts from, per camera (default 0 s).
    sd_s : float
        Prior sd of the correction, s (inf: free).
    """

    row_fraction: Any
    velocity_m_s: Any
    camera_of_photo: Sequence[str]
    readout_s: Any = None
    sd_s: float = np.inf

    def bind(self, problem: BundleProblem) -> _BoundReadout:
        return _BoundReadout(self, problem)


class _BoundReadout:
    group_kind = "camera"

    def __init__(self, spec: ReadoutTime, problem: BundleProblem):
        self.s = np.ravel(np.asarray(spec.row_fraction, dtype=float))
        self.v = np.reshape(np.asarray(spec.velocity_m_s, dtype=float), (-1, 3))
        cams = [str(c) for c in spec.camera_of_photo]
        ei = problem.photo_index
        if len(self.s) != len(ei) or len(self.v) != problem.n_photos or len(cams) != problem.n_photos:
            raise CameraError("read-out time: `row_fraction` needs one entry per observation, `velocity_m_s` "
                              "and `camera_of_photo` one per photo")
        self.cams = list(dict.fromkeys(cams))
        t0 = dict(spec.readout_s or {})
        self.t0 = np.array([float(t0.get(c, 0.0)) for c in self.cams])
        self.cam_of_obs = np.array([self.cams.index(c) for c in cams], dtype=np.int64)[ei]
        self.ei = ei
        self.m = 1
        self.n = len(self.cams)
        self.names = [f"{c}.readout_s" for c in self.cams]
        self.units = ["s"] * self.n
        self.groups = [f"camera {c}" for c in self.cams]
        sd = float(spec.sd_s)
        self.prior_sd = np.full(self.n, sd if sd > 0 else np.inf)
        self.calibrated = self.t0                                  # the start (the result's value = start + estimate)
        self.notes: list[str] = []

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        T = (self.t0 + np.asarray(theta))[self.cam_of_obs]
        off = self.v[self.ei] * (T * self.s)[:, None]
        old = fields.get("rays")
        fields["rays"] = (ObservationRays(centre_offset_m=off) if old is None
                          else dataclasses.replace(old, centre_offset_m=off))

    def jacobians(self, theta: np.ndarray, state) -> list:
        J = -np.einsum("nij,nj->ni", state.a_pt, self.v[self.ei] * self.s[:, None])[:, :, None]   # (n, 2, 1)
        return [("obs", np.arange(len(self.s)), J, self.cam_of_obs[:, None])]


def readout_warning(result, *, modelled_s: Any = None, level: float = 0.001) -> list[str]:
    """Located warnings from an adjustment with :class:`ReadoutTime` (a ``SelfCalResult``): one per
    camera whose read-out time differs significantly from the one modelled (two-sided test
    at *level*, normal quantile).

    >>> # e.g. "camera 'drone': the image residuals show a rolling shutter: read-out time 29.6 +- 0.9 ms
    >>> # (t = 33.4; modelled 0 ms): set readout_time_ms = 29.6 in its camera table"
    """
    z = float(stats.norm.isf(level / 2))
    out = []
    for name, est, sd in zip(result.names, np.asarray(result.estimates), result.sd):
        if not name.endswith(".readout_s"):
            continue
        cam = name[:-len(".readout_s")]
        base = float(dict(modelled_s or {}).get(cam, 0.0))
        t = est / sd if sd > 0 else np.inf
        if abs(t) > z:
            out.append(f"camera {cam!r}: the image residuals show a rolling shutter: read-out time "
                       f"{(base + est) * 1e3:.1f} +- {sd * 1e3:.1f} ms (t = {t:.1f}; modelled {base * 1e3:g} ms): "
                       f"set readout_time_ms = {(base + est) * 1e3:.1f} in its camera table")
    return out


@dataclasses.dataclass(frozen=True, eq=False)
class RowTrend:
    """The residuals' trend with the row, per photo (:func:`row_trend`).

    Attributes
    ----------
    photo_ids : (P,) str
    slope_px_per_krow : (P, 2) array
        Slope of the x and y residuals (adjusted - observed), px per 1000 rows (NaN: < 4 rays).
    t : (P, 2) array
        Their t statistics.
    n : (P,) int
        Rays per photo.
    chi2, dof, p_value : float
        ``sum t^2`` over the photos and axes, its degrees of freedom and the upper tail.
    level : float
        Level of the test (Bonferroni over the 2 P slopes for a single photo).
    """

    photo_ids: tuple
    slope_px_per_krow: np.ndarray
    t: np.ndarray
    n: np.ndarray
    chi2: float
    dof: int
    p_value: float
    level: float

    @property
    def pooled_t(self) -> np.ndarray:
        """``sum t / sqrt(k)`` over the photos, per axis (2,): a trend of one sign in every photo
        (the image motion of a rolling shutter has one direction in the image frame when the
        camera turns with the strips)."""
        fin = np.isfinite(self.t)
        return np.array([self.t[fin[:, k], k].sum() / np.sqrt(max(fin[:, k].sum(), 1)) for k in range(2)])

    @property
    def critical_t(self) -> float:
        """|t| beyond which one photo's slope is significant (Bonferroni over all slopes)."""
        k = max(int(np.isfinite(self.t).sum()), 1)
        df = max(int(np.nanmin(self.n)) - 2, 1) if len(self.n) else 1
        return float(stats.t.isf(self.level / (2 * k), df))

    @property
    def significant(self) -> bool:
        return bool(self.p_value < self.level)

    def warning(self, camera_hint: str = "") -> str:
        """One located sentence when the trend is significant, else ``""``."""
        if not self.significant:
            return ""
        a = np.where(np.isfinite(self.t), np.abs(self.t), -1.0)
        i, k = np.unravel_index(int(np.argmax(a)), a.shape)
        n_sig = int((a > self.critical_t).any(axis=1).sum())
        return (f"image residuals trend with the row (a rolling shutter not modelled?): {n_sig} of "
                f"{len(self.photo_ids)} photos, the largest photo {self.photo_ids[i]}, {'xy'[k]} residual slope "
                f"{self.slope_px_per_krow[i, k]:+.3g} px per 1000 rows, t = {self.t[i, k]:+.1f}; block: "
                f"sum t^2 = {self.chi2:.1f} for {self.dof} dof (p = {self.p_value:.2g})"
                + (f"; set readout_time_ms of camera {camera_hint}" if camera_hint else ""))


def row_trend(problem: BundleProblem, residuals_mm: Any, row_px: Any, pixel_size_mm: Any, *,
              level: float = 0.001) -> RowTrend:
    """Test the residuals of every photo for a linear trend with the row (module docstring).

    Parameters
    ----------
    problem : BundleProblem
    residuals_mm : (n, 2) array
        Image residuals (adjusted - observed), mm (``BundleResult.residuals_mm``).
    row_px : (n,) array
        Measured row of every observation.
    pixel_size_mm : float or (n,) array
        Pixel pitch (for the slope in px).
    level : float
        Level of the block test.
    """
    r = np.asarray(residuals_mm, dtype=float) / np.reshape(np.asarray(pixel_size_mm, dtype=float), (-1, 1))
    v = np.asarray(row_px, dtype=float).ravel() / 1000.0
    ei = problem.photo_index
    P = problem.n_photos
    n = np.bincount(ei, minlength=P)
    w = n.astype(float).clip(1)
    vm = np.bincount(ei, weights=v, minlength=P) / w
    dv = v - vm[ei]
    svv = np.bincount(ei, weights=dv * dv, minlength=P)
    slope = np.full((P, 2), np.nan)
    t = np.full((P, 2), np.nan)
    ok = (n >= 4) & (svv > 0)
    for k in range(2):
        rm = np.bincount(ei, weights=r[:, k], minlength=P) / w
        dr = r[:, k] - rm[ei]
        b = np.bincount(ei, weights=dv * dr, minlength=P) / np.where(svv > 0, svv, 1.0)
        rss = np.bincount(ei, weights=(dr - b[ei] * dv) ** 2, minlength=P)
        s = np.sqrt(rss / np.maximum(n - 2, 1))
        with np.errstate(divide="ignore", invalid="ignore"):
            tk = b * np.sqrt(svv) / s
        slope[ok, k] = b[ok]
        t[ok, k] = tk[ok]
    fin = np.isfinite(t)
    chi2 = float(np.sum(t[fin] ** 2))
    dof = int(fin.sum())
    p = float(stats.chi2.sf(chi2, dof)) if dof else 1.0
    return RowTrend(tuple(problem.photo_ids), slope, t, n, chi2, dof, p, level)
