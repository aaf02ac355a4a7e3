r"""The bundle block as arrays: exterior orientations, the problem, datum checks, chi-square.

Model (thesis section 2.1.2, eq. 08-22)
---------------------------------------
Unknowns are the exterior orientation of every photo, ``(X0, Y0, Z0)`` in metres
and ``(omega, phi, kappa)`` in radians with ``M = R3(kappa) R2(phi) R1(omega)``
(see :mod:`lidarcat.geometry.collinearity` for the convention and the derivation of the
Jacobians), and the object coordinates ``(E, N, h)`` of every point.  The
observations are photo coordinates (x right, y up, mm, already corrected for the
interior orientation, eq. 07) with a standard deviation per coordinate; control
points enter as weighted position constraints (pseudo-observations of E, N and h
with their own sigmas, eq. 14-20), optionally also the camera positions and
attitudes (GNSS/INS).  Weights are ``P = sigma0^2 Sigma^-1`` with the a priori
variance factor ``sigma0^2 = 1``.

:class:`BundleProblem` holds all of this as frozen arrays, independent of the
survey folder; :func:`check_datum` finds what would make the normal equations
singular before any solving; :func:`chi2_bounds` is the acceptance interval of
the variance-factor test (eq. 22).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy import stats

from ..geometry.collinearity import project, rotation_matrix
from .._util.frozen import frozen_array
from ..errors import DatumError

__all__ = ["ExteriorOrientation", "BundleProblem", "check_datum", "chi2_bounds"]


def _frozen_array(a: Any, shape_tail: tuple[int, ...], name: str, dtype=float) -> np.ndarray:
    """:func:`frozen_array` of shape (n, *shape_tail*), any n; the error names *name*."""
    arr = frozen_array(a, dtype=dtype)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ValueError(f"`{name}` must have shape (n, {', '.join(map(str, shape_tail))})"
                         if shape_tail else f"`{name}` must be one-dimensional")
    return arr


# ---------------------------------------------------------------------------
# value types
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class ExteriorOrientation:
    """Exterior orientation of one photo.

    Parameters
    ----------
    position_m : (3,) array
        Projection centre X0, Y0, Z0 in the survey CRS, metres.
    angles_rad : (3,) array
        omega, phi, kappa in radians; the rotation from object to image frame is
        ``M = R3(kappa) R2(phi) R1(omega)`` (thesis eq. 08; image x right, y up).
    photo : str
        Photo id.
    cov : (6, 6) array, optional
        Covariance of (X0, Y0, Z0, omega, phi, kappa) in m^2, m rad, rad^2.

    >>> import numpy as np
    >>> eo = ExteriorOrientation([0.0, 0.0, 1000.0], np.radians([0.0, 0.0, 90.0]), photo="1")
    >>> np.round(eo.rotation, 6)
    array([[ 0.,  1.,  0.],
           [-1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    >>> np.round(eo.angles_deg, 6)
    array([ 0.,  0., 90.])
    """

    position_m: np.ndarray
    angles_rad: np.ndarray
    photo: str = ""
    cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        pos = frozen_array(np.reshape(self.position_m, 3))
        ang = frozen_array(np.reshape(self.angles_rad, 3))
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(ang))):
            raise ValueError(f"exterior orientation of photo {self.photo!r} is not finite")
        object.__setattr__(self, "position_m", pos)
        object.__setattr__(self, "angles_rad", ang)
        object.__setattr__(self, "photo", str(self.photo))
        if self.cov is not None:
            object.__setattr__(self, "cov", frozen_array(np.reshape(self.cov, (6, 6))))

    @property
    def angles_deg(self) -> np.ndarray:
        """omega, phi, kappa in degrees, (3,)."""
        return np.degrees(self.angles_rad)

    @property
    def rotation(self) -> np.ndarray:
        """M = R3(kappa) R2(phi) R1(omega), object to image frame, (3, 3)."""
        return rotation_matrix(self.angles_rad)

    @property
    def params(self) -> np.ndarray:
        """(X0, Y0, Z0, omega, phi, kappa) in m and rad, (6,)."""
        return np.concatenate([self.position_m, self.angles_rad])

    @property
    def sd(self) -> np.ndarray:
        """Standard deviations of :attr:`params` (m, rad); NaN without covariance."""
        if self.cov is None:
            return np.full(6, np.nan)
        return np.sqrt(np.diag(self.cov))

    @classmethod
    def from_params(cls, params: Sequence[float], photo: str = "", cov=None) -> ExteriorOrientation:
        """Build from (X0, Y0, Z0, omega, phi, kappa) in m and rad."""
        p = np.asarray(params, dtype=float).reshape(6)
        return cls(p[:3], p[3:], photo=photo, cov=cov)

    def project(self, xyz_m: np.ndarray, focal_length_mm: float) -> np.ndarray:
        """Photo coordinates (mm, x right, y up) of object points (n, 3) -> (n, 2)."""
        xyz = np.asarray(xyz_m, dtype=float).reshape(-1, 3)
        eo = np.broadcast_to(self.params, (len(xyz), 6))
        return project(eo, xyz, np.full(len(xyz), float(focal_length_mm)))[0]


def _check_range(index: np.ndarray, n: int, name: str, of: str) -> None:
    bad = (index < 0) | (index >= n)
    if bad.any():
        raise ValueError(f"`{name}` out of range of `{of}`: {int(index[bad][0])} (there are {n})")


def _sigmas(a: Any, shape: tuple[int, int], name: str, free: str) -> np.ndarray:
    """Constraint sigmas broadcast to *shape*, frozen; inf or NaN (a free *free*) -> inf."""
    sd = np.array(np.broadcast_to(np.asarray(a, dtype=float), shape))
    sd[~np.isfinite(sd)] = np.inf
    if np.any(sd <= 0):
        raise ValueError(f"`{name}` must be positive (use inf for a free {free})")
    return frozen_array(sd)


def _str_array(a: Sequence[Any]) -> np.ndarray:
    return frozen_array([str(v) for v in a], dtype=object)


@dataclasses.dataclass(frozen=True, eq=False)
class BundleProblem:
    """A bundle block as arrays only (independent of the survey folder).

    Parameters
    ----------
    photo_ids : (P,) str
    point_ids : (Q,) str
    focal_length_mm : (P,) float
        Calibrated focal length of the camera of each photo.
    photo_index, point_index : (n,) int
        Photo and point of every image observation.
    xy_mm : (n, 2) float
        Observed photo coordinates (corrected, x right, y up, mm).
    sd_mm : (n, 2) float
        Their standard deviations (mm).
    constraint_point_index : (k,) int
        Points with weighted position constraints (control points).
    constraint_enh_m : (k, 3) float
        Observed E, N, h of the constrained points (m).
    constraint_sd_m : (k, 3) float
        Their sigmas (m); ``inf`` or NaN leaves that axis free.
    eo_constraint_photo_index : (e,) int, optional
        Photos with weighted constraints on their exterior orientation.
    eo_constraint_params : (e, 6) float, optional
        Observed X0, Y0, Z0 (m), omega, phi, kappa (rad).
    eo_constraint_sd : (e, 6) float, optional
        Their sigmas (m, rad); ``inf`` or NaN leaves the parameter free.
    initial_eo : (P, 6) float, optional
        Approximate exterior orientation (m, rad), e.g. from GNSS/INS; rows of NaN
        are unknown and computed by resection.
    point_role : (Q,) str, optional
        ``control``, ``check`` or ``tie`` (only used for reporting); default:
        ``control`` for constrained points, ``tie`` otherwise.
    info : dict, optional
        Free metadata copied into the summary (survey name, control set, ...).
    rays : lidarcat.bundle.rays.ObservationRays, optional
        Per-observation projection-centre offsets (rolling shutter) and sensor poses within a
        rig (the photos are then rig exposures); None: the plain collinearity.
    lines : lidarcat.bundle.lines.LineControl, optional
        Control lines (3-D segments, e.g. LiDAR roof ridges) and their image observations
        (:mod:`lidarcat.bundle.lines`); each observation adds 2 to the observations.  None: no
        line control (not combined with *rays*).
    """

    photo_ids: np.ndarray
    point_ids: np.ndarray
    focal_length_mm: np.ndarray
    photo_index: np.ndarray
    point_index: np.ndarray
    xy_mm: np.ndarray
    sd_mm: np.ndarray
    constraint_point_index: np.ndarray
    constraint_enh_m: np.ndarray
    constraint_sd_m: np.ndarray
    eo_constraint_photo_index: np.ndarray | None = None
    eo_constraint_params: np.ndarray | None = None
    eo_constraint_sd: np.ndarray | None = None
    initial_eo: np.ndarray | None = None
    point_role: np.ndarray | None = None
    info: dict = dataclasses.field(default_factory=dict)
    rays: Any = None
    lines: Any = None

    def __post_init__(self) -> None:
        s = object.__setattr__
        s(self, "info", dict(self.info))
        s(self, "photo_ids", _str_array(self.photo_ids))
        s(self, "point_ids", _str_array(self.point_ids))
        n_ph, n_pt = len(self.photo_ids), len(self.point_ids)
        for ids, what in ((self.photo_ids, "photo"), (self.point_ids, "point")):
            if len(set(ids)) != len(ids):
                dup = sorted({i for i in ids if list(ids).count(i) > 1})
                raise ValueError(f"duplicate {what} id(s): {', '.join(dup)}")
        s(self, "focal_length_mm", _frozen_array(np.broadcast_to(
            np.asarray(self.focal_length_mm, dtype=float), (n_ph,)), (), "focal_length_mm"))
        s(self, "photo_index", _frozen_array(self.photo_index, (), "photo_index", dtype=np.int64))
        s(self, "point_index", _frozen_array(self.point_index, (), "point_index", dtype=np.int64))
        n = len(self.photo_index)
        s(self, "xy_mm", _frozen_array(self.xy_mm, (2,), "xy_mm"))
        s(self, "sd_mm", _frozen_array(np.broadcast_to(np.asarray(self.sd_mm, dtype=float), (n, 2)),
                                       (2,), "sd_mm"))
        if len(self.point_index) != n or len(self.xy_mm) != n:
            raise ValueError("`photo_index`, `point_index`, `xy_mm` and `sd_mm` must have the same length")
        _check_range(self.photo_index, n_ph, "photo_index", "photo_ids")
        _check_range(self.point_index, n_pt, "point_index", "point_ids")
        if not np.all(self.sd_mm > 0):
            raise ValueError("`sd_mm` must be positive")
        s(self, "constraint_point_index",
          _frozen_array(self.constraint_point_index, (), "constraint_point_index", dtype=np.int64))
        k = len(self.constraint_point_index)
        s(self, "constraint_enh_m", _frozen_array(np.reshape(self.constraint_enh_m, (k, 3)), (3,),
                                                  "constraint_enh_m"))
        s(self, "constraint_sd_m", _sigmas(self.constraint_sd_m, (k, 3), "constraint_sd_m", "axis"))
        _check_range(self.constraint_point_index, n_pt, "constraint_point_index", "point_ids")
        if len(set(self.constraint_point_index.tolist())) != k:
            raise ValueError("a point is constrained twice in `constraint_point_index`")
        if self.eo_constraint_photo_index is not None:
            e = len(np.atleast_1d(self.eo_constraint_photo_index))
            s(self, "eo_constraint_photo_index",
              _frozen_array(np.atleast_1d(self.eo_constraint_photo_index), (), "eo_constraint_photo_index",
                            dtype=np.int64))
            s(self, "eo_constraint_params", _frozen_array(np.reshape(self.eo_constraint_params, (e, 6)),
                                                          (6,), "eo_constraint_params"))
            s(self, "eo_constraint_sd", _sigmas(self.eo_constraint_sd, (e, 6), "eo_constraint_sd", "parameter"))
            _check_range(self.eo_constraint_photo_index, n_ph, "eo_constraint_photo_index", "photo_ids")
        if self.initial_eo is not None:
            s(self, "initial_eo", _frozen_array(np.reshape(self.initial_eo, (n_ph, 6)), (6,), "initial_eo"))
        if self.point_role is None:
            role = np.full(n_pt, "tie", dtype=object)
            role[self.constraint_point_index] = "control"
        else:
            role = _str_array(self.point_role)
            if len(role) != n_pt:
                raise ValueError("`point_role` must have one entry per point")
        s(self, "point_role", frozen_array(role, dtype=None))
        if self.rays is not None:
            self.rays.check(n)
        if self.lines is not None:
            if self.rays is not None:
                raise DatumError("line control is not combined with per-observation rays (rolling shutter, rigs)")
            if len(self.lines.photo_index) and self.lines.photo_index.max(initial=0) >= n_ph:
                raise DatumError("a line observation's photo index is out of range of `photo_ids`")

    @property
    def n_photos(self) -> int:
        return len(self.photo_ids)

    @property
    def n_points(self) -> int:
        return len(self.point_ids)

    @property
    def n_observations(self) -> int:
        """Number of scalar image observations (2 per measured point)."""
        return 2 * len(self.photo_index)

    @property
    def n_constraints(self) -> int:
        """Number of scalar constraints (finite sigmas)."""
        n = int(np.isfinite(self.constraint_sd_m).sum())
        if self.eo_constraint_sd is not None:
            n += int(np.isfinite(self.eo_constraint_sd).sum())
        return n

    @property
    def n_unknowns(self) -> int:
        return 6 * self.n_photos + 3 * self.n_points

    @property
    def n_line_observations(self) -> int:
        """Number of scalar line observations (2 per line measured in a photo; 0 without lines)."""
        return 0 if self.lines is None else self.lines.n_observations

    @property
    def dof(self) -> int:
        """Degrees of freedom: observations (image points and lines) - unknowns + constraints."""
        return self.n_observations + self.n_line_observations - self.n_unknowns + self.n_constraints


# ---------------------------------------------------------------------------
# chi-square test of the variance factor
# ---------------------------------------------------------------------------


def chi2_bounds(dof: int, level: float = 0.05) -> dict[str, float]:
    """Two-sided acceptance interval of v'Pv / sigma0^2 (a priori) at *level*.

    Returns exact quantiles and Fisher's approximation
    ``0.5 (sqrt(2 dof - 1) -+ z)^2`` that the thesis printed (Appendix 2).

    >>> b = chi2_bounds(128)
    >>> round(b["lower_fisher"], 2), round(b["upper_fisher"], 2)
    (98.12, 160.72)
    >>> round(b["lower"], 2), round(b["upper"], 2)
    (98.58, 161.21)
    """
    if dof <= 0:
        return {"lower": math.nan, "upper": math.nan, "lower_fisher": math.nan, "upper_fisher": math.nan}
    z = float(stats.norm.ppf(1 - level / 2))
    root = math.sqrt(2 * dof - 1)
    return {
        "lower": float(stats.chi2.ppf(level / 2, dof)),
        "upper": float(stats.chi2.ppf(1 - level / 2, dof)),
        "lower_fisher": 0.5 * max(root - z, 0.0) ** 2,
        "upper_fisher": 0.5 * (root + z) ** 2,
    }


# ---------------------------------------------------------------------------
# datum checks
# ---------------------------------------------------------------------------


#: constrained photo positions (without attitudes) closer to their line than this many of their sds leave
#: the rotation about it undetermined (its sd would be sd / distance rad: 0.05 rad at this limit)
LINE_SDS = 20.0


def _eo_datum_defect(p: BundleProblem, photos: np.ndarray) -> str | None:
    """What the weighted GNSS/INS constraints of *photos* leave undetermined of the 7 datum
    parameters (a phrase naming the defect), or None when they fix all of them.

    Positions fix the translation (one photo) and the scale (two distinct photos); the rotation
    needs three positions off a line, or two positions and one constrained attitude (a single
    attitude fixes the rotation; without a second position the scale stays free).
    """
    eo_in = np.isin(p.eo_constraint_photo_index, photos)
    sd = p.eo_constraint_sd[eo_in]
    pos_rows = np.isfinite(sd[:, :3]).all(axis=1)
    att = int(np.isfinite(sd[:, 3:]).all(axis=1).sum())
    pos = p.eo_constraint_params[eo_in][pos_rows, :3]
    ids = p.photo_ids[p.eo_constraint_photo_index[eo_in][pos_rows]]
    listed = ", ".join(ids[:5]) + (" ..." if len(ids) > 5 else "")
    if len(pos) == 0:
        return ("a datum defect of " + ("4" if att else "7") + ": no photo position is constrained (position"
                + (" and scale" if att else ", attitude and scale") + " free)")
    distinct = pos - pos.mean(axis=0)
    sv = np.linalg.svd(distinct, compute_uv=False) if len(pos) > 1 else np.zeros(3)
    if len(pos) == 1 or sv[0] < 1e-6:
        return (f"a datum defect of {1 if att else 4}: one constrained photo position ({listed}) fixes no scale"
                + ("" if att else " and no rotation"))
    sd_max = float(np.max(sd[pos_rows][:, :3]))
    off_line = sv[1] / math.sqrt(len(pos))               # RMS distance of the positions from their line
    if att == 0 and (len(pos) == 2 or off_line < LINE_SDS * sd_max or sv[1] < 1e-3 * sv[0]):
        return (f"a datum defect of 1 (rank deficiency: the rotation about the line through the "
                f"{len(pos)} constrained photo positions ({listed}; {off_line:.3g} m off the line, their sd "
                f"{sd_max:.3g} m) is not determined, no attitude is constrained)")
    return None


def _line_points(p: BundleProblem, photos: np.ndarray) -> np.ndarray:
    """(2k, 3) end points of the k control lines observed on *photos*, when they fix a datum with the
    control points: lines in >= 2 directions (one direction leaves the turn about it), whose end
    points are not on one line; else (0, 3).  A line fixes 4 of the 7 datum parameters (the shifts
    across it, the turns about the axes across it); so lines count as control here when the lines
    plus control points number 3 or more (the caller's test), two lines of a corner alone do not
    fix the scale about it."""
    L = p.lines
    if L is None or not len(L.photo_index):
        return np.zeros((0, 3))
    k = np.unique(L.line_index[np.isin(L.photo_index, photos)])
    if len(k) == 0:
        return np.zeros((0, 3))
    d = L.b_m[k] - L.a_m[k]
    d = d / np.linalg.norm(d, axis=1)[:, None]
    if np.max(np.linalg.norm(np.cross(d[0], d), axis=1)) < 0.1:       # all parallel (< 6 deg)
        return np.zeros((0, 3))
    return np.concatenate([L.a_m[k], L.b_m[k]])


def check_datum(problem: BundleProblem) -> None:
    """Detect what makes the normal equations singular, before solving.

    Raises
    ------
    DatumError
        A photo with fewer than 3 measured points; a free point seen on one photo
        only (or on none); a block (or a part of it not connected to the rest
        through shared points) without enough control (datum defect); control
        points all on a line.  The message names the photo or point.
    """
    p = problem
    n_ph, n_pt = p.n_photos, p.n_points
    per_photo = np.bincount(p.photo_index, minlength=n_ph)
    for i in np.flatnonzero(per_photo < 3):
        raise DatumError(f"photo {p.photo_ids[i]!r} has {per_photo[i]} measured point(s); at least 3 "
                         "are needed to determine its 6 orientation parameters (measure more points "
                         "or remove the photo)")
    # distinct photos per point
    view = p.photo_index.astype(np.int64)
    if p.rays is not None and p.rays.has_sensors:     # a rig exposure: one view per sensor
        view = view * len(p.rays.sensor_rotation) + p.rays.sensor_index
    key = view * n_pt + p.point_index      # one integer per (photo, point)
    # a stable sort of the keys, not np.unique (numpy 2.4 hashes: 0.17-0.30 s for this check at
    # 10,010 photos, 0.02 s sorted); equal keys keep their input order
    korder = np.argsort(key, kind="stable")
    ks = key[korder]
    first = np.r_[True, ks[1:] != ks[:-1]] if len(ks) else np.zeros(0, dtype=bool)   # first of its key
    rays = np.bincount(ks[first] % n_pt, minlength=n_pt) if n_pt else np.zeros(0, dtype=np.int64)
    full = np.zeros(n_pt, dtype=bool)
    con_axes = np.zeros(n_pt, dtype=int)
    con_axes[p.constraint_point_index] = np.isfinite(p.constraint_sd_m).sum(axis=1)
    full[p.constraint_point_index] = con_axes[p.constraint_point_index] == 3
    if len(p.photo_index):
        raw = np.stack([p.photo_index, p.point_index], axis=1)
        repeated = first & ~np.r_[first[1:], True]   # first observations of keys that come again
        if repeated.any():
            k = int(korder[repeated].min())           # the earliest of them in the input
            raise DatumError(f"point {p.point_ids[raw[k, 1]]!r} is measured twice on photo "
                             f"{p.photo_ids[raw[k, 0]]!r}; keep one measurement")
    for j in np.flatnonzero(rays < 2):
        if full[j] and rays[j] == 1:
            continue  # a control point on one photo is determined by its constraint
        if rays[j] == 0:
            raise DatumError(f"point {p.point_ids[j]!r} is measured on no photo; remove it from the block")
        photo = p.photo_ids[p.photo_index[p.point_index == j][0]]
        raise DatumError(f"point {p.point_ids[j]!r} is seen on one photo only ({photo!r}); a free point "
                         "needs at least 2 rays: measure it on another photo or remove it")
    has_eo = p.eo_constraint_sd is not None and len(p.eo_constraint_sd) > 0
    # connected parts of the block: components of the photo-point graph
    from scipy.sparse.csgraph import connected_components

    graph = sp.csr_matrix((np.ones(len(p.photo_index)), (p.photo_index, n_ph + p.point_index)),
                          shape=(n_ph + n_pt, n_ph + n_pt))
    _, labels = connected_components(graph, directed=False)
    comp = labels[:n_ph]
    comps = np.unique(comp)
    ctrl_idx = p.constraint_point_index[con_axes[p.constraint_point_index] > 0]
    row_of = {int(j): r for r, j in enumerate(p.constraint_point_index)}
    for c in comps:
        photos_c = np.flatnonzero(comp == c)
        names = ", ".join(p.photo_ids[photos_c][:5]) + (" ..." if len(photos_c) > 5 else "")
        where = "the block" if len(comps) == 1 else f"the part of the block with photo(s) {names}"
        eo_defect = _eo_datum_defect(p, photos_c) if has_eo else "no GNSS/INS constraint"
        if eo_defect is None:
            continue
        in_c = np.zeros(n_pt, dtype=bool)                  # points seen from this part (a mask: linear)
        in_c[p.point_index[comp[p.photo_index] == c]] = True
        ctrl_c = np.unique(ctrl_idx[in_c[ctrl_idx]])
        lpts = _line_points(p, photos_c)   # control lines observed in this part: their end points count (E, N, h)
        if len(lpts) and len(ctrl_c) + len(lpts) // 2 >= 3:
            continue
        if len(ctrl_c) == 0 and has_eo and np.isin(p.eo_constraint_photo_index, photos_c).any():
            raise DatumError(f"{where} has no control points and its GNSS/INS constraints leave {eo_defect}; "
                             "constrain the attitudes too (sd_omega_deg, sd_phi_deg, sd_kappa_deg in photos.csv), "
                             "the positions of more photos off a line, or add control points")
        if len(ctrl_c) == 0:
            raise DatumError(f"no control in {where}: datum defect of 7 (position, attitude, scale); "
                             "give at least 3 control points not on a line (or GNSS/INS constraints)")
        kk = np.array([row_of[int(j)] for j in ctrl_c], dtype=np.int64)
        ax = np.isfinite(p.constraint_sd_m[kk])
        n_plan = int((ax[:, 0] & ax[:, 1]).sum())
        n_h = int(ax[:, 2].sum())
        if n_plan < 2 or n_h < 3:
            raise DatumError(f"too little control in {where}: {n_plan} point(s) with E, N and {n_h} with h "
                             f"({', '.join(p.point_ids[ctrl_c])}); the datum needs at least 2 planimetric and "
                             "3 height control points not on a line")
        plan = p.constraint_enh_m[kk][ax[:, 0] & ax[:, 1], :2]     # >= 2 points
        if np.ptp(plan, axis=0).max() < 1e-6:
            raise DatumError(f"planimetric control points coincide in {where}: "
                             f"{', '.join(p.point_ids[ctrl_c[ax[:, 0] & ax[:, 1]]])}; the block can turn "
                             "about them (give control at distinct places)")
        hpts = p.constraint_enh_m[kk][ax[:, 2], :2]                   # >= 3 points
        sv = np.linalg.svd(hpts - hpts.mean(axis=0), compute_uv=False)
        if sv[0] == 0 or sv[-1] / sv[0] < 1e-3:
            raise DatumError(f"height control points are (nearly) on a line in {where}: "
                             f"{', '.join(p.point_ids[ctrl_c[ax[:, 2]]])}; the block can rotate about "
                             "that line (add control off the line)")
