r"""Bundle adjustment with weighted position constraints (thesis section 2.1.2, eq. 08-22).

Model
-----
Unknowns are the exterior orientation of every photo, ``(X0, Y0, Z0)`` in metres
and ``(omega, phi, kappa)`` in radians with ``M = R3(kappa) R2(phi) R1(omega)``
(see :mod:`lidarcat._collinearity` for the convention and the derivation of the
Jacobians), and the object coordinates ``(E, N, h)`` of every point.  The
observations are photo coordinates (x right, y up, mm, already corrected for the
interior orientation, eq. 07) with a standard deviation per coordinate; control
points enter as weighted position constraints (pseudo-observations of E, N and h
with their own sigmas, eq. 14-20), optionally also the camera positions and
attitudes (GNSS/INS).  Weights are ``P = sigma0^2 Sigma^-1`` with the a priori
variance factor ``sigma0^2 = 1``.

Solver
------
Gauss-Newton with Levenberg-Marquardt damping (``N + lambda diag(N)``) on the
normal equations

.. math::  \begin{bmatrix}U & W\\W^T & V\end{bmatrix}
           \begin{bmatrix}\Delta_c\\\Delta_p\end{bmatrix} =
           \begin{bmatrix}b_c\\b_p\end{bmatrix}

where ``U`` is block diagonal (6x6 per photo), ``V`` block diagonal (3x3 per
point) and ``W`` holds one 6x3 block per observation.  The points are eliminated
through the Schur complement, giving the reduced camera system
``S = U - W V^-1 W^T`` (sparse: a 6x6 block for every pair of photos sharing a
point), solved with a sparse LU factorisation; then
``Delta_p = V^-1 (b_p - W^T Delta_c)``.  Work and memory grow with the number of
photos and observations.  Iteration stops when the largest correction is below
``tol_m`` / ``tol_rad`` and v'Pv changes by less than ``tol_vtpv`` (relative).

Precision
---------
``Sigma_X = f N^-1`` with ``f = 1`` (a priori, the thesis tables) or
``f = v'Pv / dof`` (a posteriori).  Only the blocks that are needed are computed:
``Z = S^-1`` inside the block band of ``S`` (photos ordered by reverse
Cuthill-McKee, banded Cholesky ``S = L L^T``, then the Takahashi recursion
``Z[I, j] = -Z[I, I] L[I, j] L[j, j]^-1``, ``Z[j, j] = L[j, j]^-T L[j, j]^-1 -
Z[I, j]^T L[I, j] L[j, j]^-1`` from the last photo to the first), which holds the
6x6 block of every photo and of every pair of photos sharing a point; and for
every point ``V_j^-1 + T_j^T Z T_j`` with ``T_j = W_j V_j^-1``.  No dense inverse
of the whole system is formed; the work is O(P beta^2) for block bandwidth beta
(batched sparse solves are the fallback for blocks without a narrow band).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy import stats

from ._collinearity import block_sum, project, project_with_jacobians, rotation_matrix
from ._frozen import frozen_array
from .errors import DatumError

if TYPE_CHECKING:  # pragma: no cover
    from .survey import Survey

__all__ = [
    "adjust_survey",
    "write_adjustment",
    "EOP_COLUMNS",
    "POINT_COLUMNS",
    "RESIDUAL_COLUMNS",
    "COVARIANCE_COLUMNS",
    "ExteriorOrientation",
    "BundleProblem",
    "BundleResult",
    "adjust",
    "check_datum",
    "problem_from_survey",
    "chi2_bounds",
    "joint_point_covariance",
    "read_point_covariance",
    "STATUS_MESSAGES",
    "MAX_JOINT_COVARIANCE_POINTS",
]

log = logging.getLogger(__name__)

#: ``write_adjustment`` writes the joint covariance of the check points
#: (``check_covariance.csv``, k (k + 1) / 2 rows) up to this many check points
MAX_JOINT_COVARIANCE_POINTS = 500
#: columns of ``check_covariance.csv``: the 3 x 3 cross-covariance block of two points, m^2
COVARIANCE_COLUMNS = ("point_a", "point_b", "c_EE", "c_EN", "c_Eh", "c_NE", "c_NN", "c_Nh",
                      "c_hE", "c_hN", "c_hh")

#: status -> message of :class:`BundleResult`
STATUS_MESSAGES: dict[str, str] = {
    "converged": "converged: corrections and v'Pv change below tolerance",
    "max_iterations": "maximum number of iterations reached before convergence",
    "stalled": "no further decrease of v'Pv is possible (damping grew without bound)",
    "singular": "normal equations are singular (datum defect or degenerate geometry)",
}


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
    def dof(self) -> int:
        """Degrees of freedom: observations - unknowns + constraints."""
        return self.n_observations - self.n_unknowns + self.n_constraints


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
# result
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class BundleResult:
    """Outcome of :func:`adjust`. Non-convergence is a ``status``, not an exception.

    Attributes
    ----------
    status : str
        ``converged``, ``max_iterations``, ``stalled`` or ``singular``.
    message : str
    success : bool
        True when ``status == "converged"``.
    n_iter : int
    vtpv : float
        v'Pv of image observations and constraints (a priori weights).
    dof : int
        observations - unknowns + constraints.
    sigma0_sq : float
        A posteriori variance factor v'Pv / dof.
    variance_factor : float
        Factor applied to N^-1 for the covariances (1 for ``a_priori``).
    variance_factor_kind : str
    chi2 : dict
        ``statistic`` (v'Pv / sigma0^2 a priori), ``level``, ``lower``, ``upper``
        (exact quantiles), ``lower_fisher``, ``upper_fisher`` (approximation the
        thesis printed) and ``passed`` (exact interval).
    photo_ids : (P,) str
    eo_params : (P, 6)
        X0, Y0, Z0 (m), omega, phi, kappa (rad).
    eo_cov : (P, 6, 6)
    point_ids : (Q,) str
    points_m : (Q, 3)
        Adjusted E, N, h.
    point_cov : (Q, 3, 3)
    point_role : (Q,) str
    residuals_mm : (n, 2)
        Image residuals, adjusted minus observed (mm), in the order of the problem.
    constraint_residuals_m : (k, 3)
        Adjusted minus observed coordinates of the constrained points (m).
    eo_constraint_residuals : (e, 6) or None
    history : tuple of float
        v'Pv after every accepted iteration (index 0: approximations).
    problem : BundleProblem
    initial_eo : (P, 6), initial_points_m : (Q, 3)
        The approximations the iteration started from.
    elapsed_s : float
    """

    status: str
    message: str
    success: bool
    n_iter: int
    vtpv: float
    dof: int
    sigma0_sq: float
    variance_factor: float
    variance_factor_kind: str
    chi2: dict
    photo_ids: np.ndarray
    eo_params: np.ndarray
    eo_cov: np.ndarray
    point_ids: np.ndarray
    points_m: np.ndarray
    point_cov: np.ndarray
    point_role: np.ndarray
    residuals_mm: np.ndarray
    constraint_residuals_m: np.ndarray
    eo_constraint_residuals: np.ndarray | None
    history: tuple
    problem: BundleProblem
    initial_eo: np.ndarray
    initial_points_m: np.ndarray
    elapsed_s: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                object.__setattr__(self, f.name, frozen_array(v, dtype=None))

    @property
    def eo_sd(self) -> np.ndarray:
        """(P, 6) standard deviations of X0, Y0, Z0 (m), omega, phi, kappa (rad)."""
        return np.sqrt(np.clip(np.diagonal(self.eo_cov, axis1=1, axis2=2), 0, None))

    @property
    def point_sd_m(self) -> np.ndarray:
        """(Q, 3) standard deviations of E, N, h (m)."""
        return np.sqrt(np.clip(np.diagonal(self.point_cov, axis1=1, axis2=2), 0, None))

    @property
    def exterior_orientations(self) -> tuple[ExteriorOrientation, ...]:
        """One :class:`ExteriorOrientation` (with covariance) per photo."""
        return tuple(ExteriorOrientation.from_params(p, photo=i, cov=c)
                     for i, p, c in zip(self.photo_ids, self.eo_params, self.eo_cov))

    def eo(self, photo: str) -> ExteriorOrientation:
        """Exterior orientation of *photo*.

        Raises
        ------
        ValueError
            *photo* is not in the adjustment (named).
        """
        i = _position(self.photo_ids, photo, "photo")
        return ExteriorOrientation.from_params(self.eo_params[i], photo=self.photo_ids[i], cov=self.eo_cov[i])

    def point(self, point: str) -> np.ndarray:
        """Adjusted E, N, h of *point* (3,).

        Raises
        ------
        ValueError
            *point* is not in the adjustment (named).
        """
        return self.points_m[_position(self.point_ids, point, "point")]

    def rms_residuals_per_photo(self) -> np.ndarray:
        """(P, 2) RMS image residual in x and y per photo (mm) (Appendix 2 'desvio padrao medio')."""
        pi = self.problem.photo_index
        cnt = np.bincount(pi, minlength=len(self.photo_ids)).astype(float)
        out = np.full((len(self.photo_ids), 2), np.nan)
        for k in range(2):
            ss = np.bincount(pi, weights=self.residuals_mm[:, k] ** 2, minlength=len(self.photo_ids))
            with np.errstate(invalid="ignore", divide="ignore"):
                out[:, k] = np.sqrt(ss / cnt)
        return out

    def summary(self) -> dict[str, Any]:
        """Plain-dict summary (keys as in ``summary.json``)."""
        p = self.problem
        sd = self.point_sd_m
        role = self.point_role
        ctrl = role == "control"
        free = ~ctrl
        rms = self.rms_residuals_per_photo()
        cres = self.constraint_residuals_m
        finite = np.isfinite(p.constraint_sd_m)
        rms_con = [float(np.sqrt(np.mean(cres[finite[:, k], k] ** 2))) if finite[:, k].any() else math.nan
                   for k in range(3)]
        # Appendix 2 "desvio padrao medio dos pontos fixos": sqrt(sum v^2 / (n - 1))
        sd_con = [float(np.sqrt(np.sum(cres[finite[:, k], k] ** 2) / (finite[:, k].sum() - 1)))
                  if finite[:, k].sum() > 1 else math.nan for k in range(3)]
        return {
            **{k: v for k, v in p.info.items()},
            "status": self.status,
            "message": self.message,
            "converged": bool(self.success),
            "n_iterations": int(self.n_iter),
            "vtpv": float(self.vtpv),
            "dof": int(self.dof),
            "sigma0_sq": float(self.sigma0_sq),
            "sigma0_sq_a_priori": 1.0,
            "variance_factor": self.variance_factor_kind,
            "chi2_statistic": float(self.chi2["statistic"]),
            "chi2_level": float(self.chi2["level"]),
            "chi2_lower": float(self.chi2["lower"]),
            "chi2_upper": float(self.chi2["upper"]),
            "chi2_lower_fisher": float(self.chi2["lower_fisher"]),
            "chi2_upper_fisher": float(self.chi2["upper_fisher"]),
            "chi2_pass": bool(self.chi2["passed"]),
            "n_photos": int(p.n_photos),
            "n_points": int(p.n_points),
            "n_observations": int(p.n_observations),
            "n_unknowns": int(p.n_unknowns),
            "n_constraints": int(p.n_constraints),
            "rms_image_residuals_mm": {str(i): {"x": float(r[0]), "y": float(r[1])}
                                       for i, r in zip(self.photo_ids, rms)},
            "rms_control_residuals_m": dict(zip("ENh", rms_con)),
            "sd_control_residuals_m": dict(zip("ENh", sd_con)),
            "mean_sd_control_m": dict(zip("ENh", (float(v) for v in sd[ctrl].mean(axis=0))))
            if ctrl.any() else {},
            "mean_sd_free_m": dict(zip("ENh", (float(v) for v in sd[free].mean(axis=0))))
            if free.any() else {},
            # Appendix 2 "desvio padrao medio dos pontos livres" is reproduced (to its printed
            # precision) by the RMS of the sds over all adjusted points, control included
            "rms_sd_points_m": dict(zip("ENh", (float(v) for v in np.sqrt(np.mean(sd**2, axis=0)))))
            if len(sd) else {},
            "elapsed_s": float(self.elapsed_s),
        }


def _position(ids: np.ndarray, wanted: Any, what: str) -> int:
    hit = np.flatnonzero(ids == str(wanted))
    if not len(hit):
        raise ValueError(f"{what} {str(wanted)!r} is not in the adjustment")
    return int(hit[0])


# ---------------------------------------------------------------------------
# datum checks
# ---------------------------------------------------------------------------


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
    pairs = np.unique(np.stack([p.point_index, p.photo_index], axis=1), axis=0)
    rays = np.bincount(pairs[:, 0], minlength=n_pt)
    full = np.zeros(n_pt, dtype=bool)
    con_axes = np.zeros(n_pt, dtype=int)
    con_axes[p.constraint_point_index] = np.isfinite(p.constraint_sd_m).sum(axis=1)
    full[p.constraint_point_index] = con_axes[p.constraint_point_index] == 3
    if len(p.photo_index):
        raw = np.stack([p.photo_index, p.point_index], axis=1)
        _, inv, cnt = np.unique(raw, axis=0, return_inverse=True, return_counts=True)
        twice = np.flatnonzero(cnt[inv.ravel()] > 1)
        if len(twice):
            k = int(twice[0])
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
        if has_eo:
            eo_in = np.isin(p.eo_constraint_photo_index, photos_c)
            if eo_in.any():
                sd = p.eo_constraint_sd[eo_in]
                n_pos = int(np.isfinite(sd[:, :3]).all(axis=1).sum())
                n_att = int(np.isfinite(sd[:, 3:]).all(axis=1).sum())
                if (n_pos >= 1 and n_att >= 1 and n_pos + n_att >= 3) or n_pos >= 3:
                    continue
        seen = np.isin(p.photo_index, photos_c)
        pts_c = np.unique(p.point_index[seen])
        ctrl_c = np.intersect1d(ctrl_idx, pts_c)
        names = ", ".join(p.photo_ids[photos_c][:5]) + (" ..." if len(photos_c) > 5 else "")
        where = "the block" if len(comps) == 1 else f"the part of the block with photo(s) {names}"
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


# ---------------------------------------------------------------------------
# the solver
# ---------------------------------------------------------------------------


def _block_sparse(rows: np.ndarray, cols: np.ndarray, blocks: np.ndarray, shape: tuple[int, int]) -> sp.csr_matrix:
    """Sparse matrix from (m, a, b) blocks at block row/col indices (duplicates summed)."""
    m, a, b = blocks.shape
    r = (rows[:, None, None] * a + np.arange(a)[None, :, None]) + np.zeros((1, 1, b), dtype=np.int64)
    c = (cols[:, None, None] * b + np.arange(b)[None, None, :]) + np.zeros((1, a, 1), dtype=np.int64)
    return sp.csr_matrix((blocks.ravel(), (r.ravel(), c.ravel())), shape=shape)


def _constraint_terms(p: BundleProblem, eo: np.ndarray, pts: np.ndarray):
    """Residuals (adjusted - observed) and weights of the point and camera constraints.

    Returns ``(r_con (k, 3), w_con (k, 3), r_eo (e, 6) or None, w_eo (e, 6) or None)``;
    angle residuals wrapped to (-pi, pi], weight 0 on a free axis.
    """
    w_con = np.where(np.isfinite(p.constraint_sd_m), 1.0 / p.constraint_sd_m**2, 0.0)
    r_con = pts[p.constraint_point_index] - p.constraint_enh_m
    if p.eo_constraint_photo_index is None or not len(p.eo_constraint_photo_index):
        return r_con, w_con, None, None
    w_eo = np.where(np.isfinite(p.eo_constraint_sd), 1.0 / p.eo_constraint_sd**2, 0.0)
    r_eo = eo[p.eo_constraint_photo_index] - p.eo_constraint_params
    r_eo[:, 3:] = (r_eo[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    return r_con, w_con, r_eo, w_eo


def _reduce(ei: np.ndarray, pj: np.ndarray, U: np.ndarray, V: np.ndarray, W: np.ndarray):
    """Schur complement of the point blocks: S = U - W V^-1 W^T (sparse, 6P x 6P).

    Returns ``S`` (csc), ``V^-1`` (Q, 3, 3), ``Tm`` = W V^-1 and ``Wm`` = W as sparse
    (6P x 3Q) matrices.
    """
    n_ph, n_pt = len(U), len(V)
    vinv = _inv3(V)
    Tm = _block_sparse(ei, pj, W @ vinv[pj], (6 * n_ph, 3 * n_pt))
    Wm = _block_sparse(ei, pj, W, (6 * n_ph, 3 * n_pt))
    Ub = _block_sparse(np.arange(n_ph), np.arange(n_ph), U, (6 * n_ph, 6 * n_ph))
    return (Ub - Tm @ Wm.T).tocsc(), vinv, Tm, Wm


class _System:
    """Normal-equation blocks of one linearisation."""

    def __init__(self, problem: BundleProblem, eo: np.ndarray, pts: np.ndarray):
        p = problem
        self.p = p
        ei, pj = p.photo_index, p.point_index
        xy, a_eo, a_pt, u3 = project_with_jacobians(eo, pts[pj], p.focal_length_mm[ei], ei)
        self.u3 = u3
        r = xy - p.xy_mm                                 # residual (adjusted - observed)
        w = 1.0 / p.sd_mm**2                             # (n, 2)
        self.r_obs = r
        aw_eo = a_eo * w[:, :, None]
        aw_pt = a_pt * w[:, :, None]
        n_ph, n_pt = p.n_photos, p.n_points
        self.U = block_sum(ei, np.transpose(aw_eo, (0, 2, 1)) @ a_eo, n_ph)
        self.V = block_sum(pj, np.transpose(aw_pt, (0, 2, 1)) @ a_pt, n_pt)
        self.W = np.transpose(aw_eo, (0, 2, 1)) @ a_pt     # (n, 6, 3)
        self.g_c = block_sum(ei, np.einsum("nki,nk->ni", aw_eo, r)[:, :, None], n_ph)[:, :, 0]
        self.g_p = block_sum(pj, np.einsum("nki,nk->ni", aw_pt, r)[:, :, None], n_pt)[:, :, 0]
        vtpv = float(np.sum(r**2 * w))
        # point and exterior-orientation constraints
        rc, wc, re, we = _constraint_terms(p, eo, pts)
        self.r_con, self.r_eo = rc, re
        ci = p.constraint_point_index
        idx = np.arange(3)
        np.add.at(self.V, (ci[:, None], idx[None, :], idx[None, :]), wc)
        np.add.at(self.g_p, ci, wc * rc)
        vtpv += float(np.sum(wc * rc**2))
        if re is not None:
            k = p.eo_constraint_photo_index
            i6 = np.arange(6)
            np.add.at(self.U, (k[:, None], i6[None, :], i6[None, :]), we)
            np.add.at(self.g_c, k, we * re)
            vtpv += float(np.sum(we * re**2))
        self.vtpv = vtpv

    def solve(self, lam: float) -> tuple[np.ndarray, np.ndarray]:
        """Corrections (P, 6), (Q, 3) of the damped normal equations."""
        p = self.p
        U, V = self.U.copy(), self.V.copy()
        if lam > 0:
            iu, iv = np.arange(6), np.arange(3)
            U[:, iu, iu] *= 1.0 + lam
            V[:, iv, iv] *= 1.0 + lam
        S, vinv, Tm, Wm = _reduce(p.photo_index, p.point_index, U, V, self.W)
        b_c = -self.g_c.reshape(-1)
        b_p = -self.g_p.reshape(-1)
        rhs = b_c - Tm @ b_p
        dc = _factor(S).solve(rhs)
        bp = (b_p - Wm.T @ dc).reshape(p.n_points, 3)
        dp = np.einsum("qij,qj->qi", vinv, bp)
        return dc.reshape(p.n_photos, 6), dp

    def reduced_system(self):
        """Undamped ``S``, ``V^-1``, ``Tm``, ``Wm`` of :func:`_reduce`."""
        return _reduce(self.p.photo_index, self.p.point_index, self.U, self.V, self.W)

    def covariance(self, method: str = "auto") -> tuple[np.ndarray, np.ndarray]:
        """Blocks of N^-1: (P, 6, 6) per photo and (Q, 3, 3) per point.

        ``method``: ``"banded"`` (block Takahashi recursion on a banded Cholesky
        factor after reverse Cuthill-McKee ordering of the photos: work
        O(P beta^2), beta the block bandwidth), ``"solve"`` (batched sparse solves
        for all columns of S^-1: O(P nnz(L))) or ``"auto"`` (banded when the
        bandwidth is small against P).
        """
        p = self.p
        n_ph, n_pt = p.n_photos, p.n_points
        pj, ei = p.point_index, p.photo_index
        S, vinv, _, _ = self.reduced_system()
        T = self.W @ vinv[pj]                                  # (n, 6, 3)
        oa, ob = _observation_pairs(pj, n_pt)
        pi, pk = ei[oa], ei[ob]
        getter = None
        if method in ("auto", "banded"):
            getter = _banded_selected_inverse(S, n_ph, force=method == "banded")
        if getter is not None:
            eo_cov = getter(np.arange(n_ph), np.arange(n_ph))
            blocks_pair = getter(pi, pk)
        else:
            eo_cov, blocks_pair = _solve_selected_inverse(S, n_ph, pi, pk)
        # point blocks: V^-1 + sum_{a,b} T_a^T C_ik T_b over pairs of rays of the point
        contrib = (np.transpose(T[oa], (0, 2, 1)) @ blocks_pair) @ T[ob]
        point_cov = vinv + block_sum(pj[oa], contrib, n_pt)
        eo_cov = 0.5 * (eo_cov + np.transpose(eo_cov, (0, 2, 1)))
        point_cov = 0.5 * (point_cov + np.transpose(point_cov, (0, 2, 1)))
        return eo_cov, point_cov


def _observation_pairs(pj: np.ndarray, n_pt: int) -> tuple[np.ndarray, np.ndarray]:
    """All ordered pairs (a, b) of observations of the same point (including a == b)."""
    order = np.argsort(pj, kind="stable")
    counts = np.bincount(pj, minlength=n_pt)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    a_list, b_list = [], []
    for m in np.unique(counts):
        if m == 0:
            continue
        js = np.flatnonzero(counts == m)
        base = starts[js][:, None] + np.arange(m)[None, :]
        a_list.append(order[np.repeat(base, m, axis=1).ravel()])
        b_list.append(order[np.tile(base, (1, m)).ravel()])
    if not a_list:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return np.concatenate(a_list), np.concatenate(b_list)


def _solve_selected_inverse(S: sp.csc_matrix, n_ph: int, pi: np.ndarray, pk: np.ndarray,
                            batch: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Diagonal blocks and blocks (pi, pk) of S^-1 by batched sparse solves."""
    lu = _factor(S)
    eo_cov = np.empty((n_ph, 6, 6))
    blocks_pair = np.empty((len(pi), 6, 6))
    col_order = np.argsort(pk, kind="stable")
    pk_sorted = pk[col_order]
    for k0 in range(0, n_ph, batch):
        k1 = min(n_ph, k0 + batch)
        nb = k1 - k0
        rhs = np.zeros((6 * n_ph, 6 * nb))
        rhs[6 * k0:6 * k1, :] = np.eye(6 * nb)
        Xb = lu.solve(rhs).reshape(n_ph, 6, nb, 6)          # columns of S^-1 for photos k0..k1
        kk = np.arange(nb)
        eo_cov[k0:k1] = Xb[k0 + kk, :, kk, :]
        lo, hi = np.searchsorted(pk_sorted, [k0, k1])
        sel = col_order[lo:hi]
        blocks_pair[sel] = Xb[pi[sel], :, pk[sel] - k0, :]
    return eo_cov, blocks_pair


def _banded_selected_inverse(S: sp.csc_matrix, n_ph: int, force: bool = False):
    """Selected inverse of S within its block band (Takahashi recursion), or None.

    The photos are ordered by reverse Cuthill-McKee; S = L L^T is factored in
    LAPACK band storage; then for block columns j = P-1 .. 0, with I the block
    rows of the band below j (all within the band of each other):

        Z[I, j] = -Z[I, I] L[I, j] L[j, j]^-1
        Z[j, j] = L[j, j]^-T L[j, j]^-1 - Z[I, j]^T L[I, j] L[j, j]^-1

    which only reads and writes Z inside the band.  Returns a function
    ``get(i, k) -> (m, 6, 6)`` blocks of S^-1 for photo indices i, k sharing a
    point (inside the band), or None when the band is too wide to pay off.
    """
    import scipy.linalg as sla
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    coo = S.tocoo()
    br, bc = coo.row // 6, coo.col // 6
    graph = sp.csr_matrix((np.ones(len(br)), (br, bc)), shape=(n_ph, n_ph))
    perm = np.asarray(reverse_cuthill_mckee(graph, symmetric_mode=True), dtype=np.int64)
    pos = np.empty(n_ph, dtype=np.int64)
    pos[perm] = np.arange(n_ph)
    beta = int(np.abs(pos[br] - pos[bc]).max(initial=0))
    if not force and n_ph > 8 and beta > n_ph // 3:
        return None
    n = 6 * n_ph
    bw = 6 * beta + 5                                        # scalar lower bandwidth
    r = pos[br] * 6 + coo.row % 6
    c = pos[bc] * 6 + coo.col % 6
    low = r >= c
    ab = np.zeros((bw + 1, n))
    np.add.at(ab, (r[low] - c[low], c[low]), coo.data[low])
    try:
        lb = sla.cholesky_banded(ab, lower=True, check_finite=False)
    except np.linalg.LinAlgError as ex:
        raise _Singular(f"reduced camera system is not positive definite ({ex})") from ex
    diag = ab[0]
    if np.any(lb[0] ** 2 < 1e-11 * np.where(diag > 0, diag, 1.0)):
        raise _Singular("reduced camera system is singular (datum defect or degenerate photo)")

    def lblock(rows0: int, nrows: int, col0: int) -> np.ndarray:
        """L[rows0:rows0+nrows, col0:col0+6] from band storage (zeros outside)."""
        rr = rows0 + np.arange(nrows)[:, None]
        cc = col0 + np.arange(6)[None, :]
        d = rr - cc
        ok = (d >= 0) & (d <= bw)
        out = np.zeros((nrows, 6))
        out[ok] = lb[d[ok], np.broadcast_to(cc, d.shape)[ok]]
        return out

    zb = np.zeros((n_ph, beta + 1, 6, 6))                   # zb[i, d] = Z[i, i + d] (permuted order)
    for jb in range(n_ph - 1, -1, -1):
        j0 = 6 * jb
        m = min(beta, n_ph - 1 - jb)
        ljj = lblock(j0, 6, j0)
        ljj_inv = sla.solve_triangular(ljj, np.eye(6), lower=True, check_finite=False)
        if m:
            lij = lblock(j0 + 6, 6 * m, j0)
            x = lij @ ljj_inv                                # L[I, j] L[j, j]^-1
            a = np.arange(1, m + 1)
            aa, cc = np.meshgrid(a, a, indexing="ij")
            lo = np.minimum(aa, cc)
            blocks = zb[jb + lo, np.abs(aa - cc)]            # (m, m, 6, 6), upper-stored
            lower = aa > cc
            blocks[lower] = np.transpose(blocks[lower], (0, 2, 1))
            zii = blocks.transpose(0, 2, 1, 3).reshape(6 * m, 6 * m)
            zij = -zii @ x                                   # (6m, 6)
            zjj = ljj_inv.T @ ljj_inv - zij.T @ x
            zb[jb, 1:m + 1] = np.transpose(zij.reshape(m, 6, 6), (0, 2, 1))
        else:
            zjj = ljj_inv.T @ ljj_inv
        zb[jb, 0] = 0.5 * (zjj + zjj.T)

    def get(i: np.ndarray, k: np.ndarray) -> np.ndarray:
        pi_, pk_ = pos[np.asarray(i)], pos[np.asarray(k)]
        lo = np.minimum(pi_, pk_)
        d = np.abs(pi_ - pk_)
        if np.any(d > beta):
            raise ValueError("requested block outside the band of S")
        out = zb[lo, d].copy()
        swap = pi_ > pk_
        out[swap] = np.transpose(out[swap], (0, 2, 1))
        return out

    return get


class _Singular(Exception):
    pass


def _inv3(V: np.ndarray) -> np.ndarray:
    det = np.linalg.det(V)
    scale = np.abs(V).max(axis=(1, 2))
    if np.any(~np.isfinite(det)) or np.any(np.abs(det) <= 1e-12 * scale**3):
        raise _Singular("a point block of the normal equations is singular")
    return np.linalg.inv(V)


def _factor(S: sp.csc_matrix):
    try:
        # symmetric positive definite: symmetric ordering, no pivoting (much less fill)
        lu = spla.splu(S, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
    except RuntimeError as ex:  # "Factor is exactly singular"
        raise _Singular(f"reduced camera system is singular ({ex})") from ex
    # a rank defect shows as pivots at rounding level relative to the diagonal of S
    piv = np.abs(lu.U.diagonal())
    diag = np.abs(S.diagonal())[lu.perm_c]
    ratio = piv / np.where(diag > 0, diag, 1.0)
    if not np.all(np.isfinite(piv)) or ratio.min() < 1e-11:
        raise _Singular(f"reduced camera system is singular (relative pivot {ratio.min():.1e}: "
                        "datum defect or a photo with degenerate geometry)")
    return lu


def _cost(problem: BundleProblem, eo: np.ndarray, pts: np.ndarray) -> float:
    p = problem
    ei, pj = p.photo_index, p.point_index
    xy, u3 = project(eo, pts[pj], p.focal_length_mm[ei], ei)
    if np.any(u3 >= 0) or not np.all(np.isfinite(xy)):
        return math.inf  # a point behind (or in the plane of) a camera
    c = float(np.sum(((xy - p.xy_mm) / p.sd_mm) ** 2))
    rc, wc, re, we = _constraint_terms(p, eo, pts)
    c += float(np.sum(wc * rc**2))
    if re is not None:
        c += float(np.sum(we * re**2))
    return c


def adjust(
    problem: BundleProblem,
    *,
    initial: tuple[np.ndarray, np.ndarray | None] | None = None,
    max_iter: int = 50,
    tol_m: float = 1e-4,
    tol_rad: float = 1e-8,
    tol_vtpv: float = 1e-8,
    variance_factor: str = "a_priori",
    chi2_level: float = 0.05,
    damping: bool = True,
    check: bool = True,
    progress: Callable[[int, float], None] | None = None,
) -> BundleResult:
    """Simultaneous bundle adjustment with weighted position constraints.

    Parameters
    ----------
    problem : BundleProblem
    initial : (eo (P, 6), points (Q, 3) or None), optional
        Approximate values (m, rad).  Default: computed by
        :func:`lidarcat._approx.approximations` from control points, image
        measurements and ``problem.initial_eo`` (a planimetric block adjustment,
        then sweeps of intersection and space resection).  With points ``None``
        they are intersected from the given orientations.
    max_iter : int
    tol_m, tol_rad : float
        Convergence threshold on the largest correction of a coordinate (m) and of
        an angle (rad).
    tol_vtpv : float
        Convergence threshold on the relative change of v'Pv.
    variance_factor : {"a_priori", "a_posteriori"}
        Factor of N^-1 in the covariances: 1 (the thesis tables) or v'Pv / dof.
    chi2_level : float
        Level of the two-sided chi-square test of the variance factor.
    damping : bool
        Levenberg-Marquardt damping (needed from poor approximations); False is
        plain Gauss-Newton.
    check : bool
        Run :func:`check_datum` first.
    progress : callable(iteration, vtpv), optional

    Returns
    -------
    BundleResult

    Raises
    ------
    DatumError
        From :func:`check_datum`, or when approximations cannot be computed.
    ValueError
        Bad parameter values.
    """
    if variance_factor not in ("a_priori", "a_posteriori"):
        raise ValueError("`variance_factor` must be 'a_priori' or 'a_posteriori'")
    if not 0 < chi2_level < 1:
        raise ValueError("`chi2_level` must be in (0, 1)")
    t0 = time.perf_counter()
    p = problem
    if check:
        check_datum(p)
    from ._approx import approximations, intersect_points

    if initial is None:
        eo, pts = approximations(p)
    else:
        eo = np.array(initial[0], dtype=float).reshape(p.n_photos, 6)
        if initial[1] is None:
            pts = intersect_points(p, eo)
        else:
            pts = np.array(initial[1], dtype=float).reshape(p.n_points, 3)
    eo0, pts0 = eo.copy(), pts.copy()

    lam = 1e-3 if damping else 0.0
    status = "max_iterations"
    n_iter = 0
    history: list[float] = []
    system = None
    try:
        system = _System(p, eo, pts)
        cost = system.vtpv if np.all(system.u3 < 0) else _cost(p, eo, pts)
        history.append(cost)
        while n_iter < max_iter:
            n_iter += 1
            accepted = False
            while True:
                dc, dp = system.solve(lam)
                eo_new, pts_new = eo + dc, pts + dp
                new_cost = _cost(p, eo_new, pts_new)
                if not damping or new_cost <= cost * (1 + 1e-12) or _tiny(dc, dp, tol_m, tol_rad):
                    accepted = True
                    break
                lam = max(lam, 1e-6) * 10.0
                if lam > 1e12:
                    break
            if not accepted:
                status = "stalled"
                break
            small = _tiny(dc, dp, tol_m, tol_rad)
            dcost = abs(cost - new_cost) / max(cost, 1.0)
            eo, pts = eo_new, pts_new
            eo[:, 3:] = (eo[:, 3:] + np.pi) % (2 * np.pi) - np.pi
            cost = new_cost
            history.append(cost)
            if progress is not None:
                progress(n_iter, cost)
            log.debug("iteration %d: v'Pv %.6g, lambda %.1e, max|dX| %.3g m", n_iter, cost, lam,
                      np.abs(np.concatenate([dc[:, :3].ravel(), dp.ravel()])).max())
            if not math.isfinite(cost):
                status = "stalled"
                break
            if damping:
                lam = lam / 10.0 if lam > 1e-12 else 0.0
            system = _System(p, eo, pts)
            if small and dcost < tol_vtpv:
                status = "converged"
                break
        eo_cov, point_cov = system.covariance()       # system is linearised at (eo, pts)
    except _Singular as ex:
        status = "singular"
        log.warning("bundle adjustment: %s", ex)
        eo_cov = np.full((p.n_photos, 6, 6), np.nan)
        point_cov = np.full((p.n_points, 3, 3), np.nan)
        if system is None:
            system = _System(p, eo, pts)
        message_extra = f": {ex}"
    else:
        message_extra = ""

    vtpv = system.vtpv
    dof = p.dof
    sigma0_sq = vtpv / dof if dof > 0 else math.nan
    factor = 1.0 if variance_factor == "a_priori" else sigma0_sq
    eo_cov = eo_cov * factor
    point_cov = point_cov * factor
    bounds = chi2_bounds(dof, chi2_level)
    chi2 = {"statistic": vtpv, "level": chi2_level, **bounds,
            "passed": bool(dof > 0 and bounds["lower"] <= vtpv <= bounds["upper"])}
    msg = STATUS_MESSAGES[status] + message_extra
    if status == "converged":
        msg += f" after {n_iter} iteration(s)"
    return BundleResult(
        status=status, message=msg, success=status == "converged", n_iter=n_iter,
        vtpv=vtpv, dof=dof, sigma0_sq=sigma0_sq, variance_factor=factor,
        variance_factor_kind=variance_factor, chi2=chi2,
        photo_ids=p.photo_ids, eo_params=eo, eo_cov=eo_cov,
        point_ids=p.point_ids, points_m=pts, point_cov=point_cov, point_role=p.point_role,
        residuals_mm=system.r_obs, constraint_residuals_m=system.r_con,
        eo_constraint_residuals=system.r_eo, history=tuple(history), problem=p,
        initial_eo=eo0, initial_points_m=pts0, elapsed_s=time.perf_counter() - t0,
    )


def joint_point_covariance(result: BundleResult, points: Sequence[str], *, batch: int = 96) -> np.ndarray:
    """Joint covariance of several adjusted points, cross-covariances included.

    The per-point blocks of :attr:`BundleResult.point_cov` ignore that every
    point shares the errors of the photo orientations: points controlled by
    the same few constraints move together (a block tilt, a height offset).
    Tests on several points at once -- the check-point chi-square of
    :func:`lidarcat.accuracy.covariance_consistency_test` -- need the whole
    matrix ``C[a, b] = V_a^-1 delta_ab + T_a^T S^-1 T_b`` (Schur complement
    of the point blocks: S the reduced camera system, T_a = W_a V_a^-1).

    Work: one sparse factorisation of S and 3k solves in batches of *batch*
    columns; memory O(6 P batch + 9 k^2), never the dense N^-1.

    Parameters
    ----------
    result : BundleResult
        A converged adjustment (relinearised at its solution).
    points : sequence of str
        Point ids, in the order wanted.
    batch : int
        Right-hand sides per solve.

    Returns
    -------
    (3k, 3k) array
        Covariance of (E, N, h) of the points, point after point, m^2, scaled
        by the result's variance factor.  Its diagonal 3 x 3 blocks equal
        ``result.point_cov`` of those points.

    Raises
    ------
    DatumError
        An unknown point id (named), or a singular system.
    """
    ids = [str(q) for q in points]
    index = {str(q): i for i, q in enumerate(result.point_ids)}
    missing = [q for q in ids if q not in index]
    if missing:
        raise DatumError(f"joint covariance: point(s) not in the adjustment: {', '.join(missing[:10])}"
                         + (" ..." if len(missing) > 10 else ""))
    k = len(ids)
    if k == 0:
        return np.zeros((0, 0))
    p = result.problem
    sel = np.array([index[q] for q in ids])
    system = _System(p, np.asarray(result.eo_params), np.asarray(result.points_m))
    try:
        S, vinv, Tm, _ = system.reduced_system()
        lu = _factor(S)
    except _Singular as ex:
        raise DatumError(f"joint covariance: {ex}") from ex
    B = Tm.tocsc()[:, (3 * sel[:, None] + np.arange(3)[None, :]).ravel()]
    BT = B.T.tocsr()
    C = np.empty((3 * k, 3 * k))
    for c0 in range(0, 3 * k, batch):
        c1 = min(3 * k, c0 + batch)
        C[:, c0:c1] = BT @ lu.solve(B[:, c0:c1].toarray())
    C = 0.5 * (C + C.T)
    for a, q in enumerate(sel):
        C[3 * a:3 * a + 3, 3 * a:3 * a + 3] += vinv[q]
    return C * result.variance_factor


def read_point_covariance(path, points: Sequence[str] | None = None) -> tuple[list[str], np.ndarray]:
    """Read a ``check_covariance.csv`` written by :func:`write_adjustment`.

    Parameters
    ----------
    path : path
    points : sequence of str, optional
        Point ids to return, in this order (default: the file's order).

    Returns
    -------
    ids : list of str
    C : (3k, 3k) array
        Joint covariance of E, N, h, m^2.

    Raises
    ------
    SurveyError
        Missing or unreadable file, a missing column, a cell that is not a
        number (file, line and field named).
    AssessmentError
        A requested point with no rows, a pair with no row or with two rows, a
        point's own block with a variance that is not positive (file and line
        or points named).
    """
    from ._io import read_csv_table
    from .errors import AssessmentError, location

    t = read_csv_table(path, required=COVARIANCE_COLUMNS)
    vals = np.column_stack([t.floats(c) for c in COVARIANCE_COLUMNS[2:]]).reshape(-1, 3, 3)
    pa, pb = t.column("point_a"), t.column("point_b")
    seen: dict[frozenset, int] = {}
    for a, b, blk, line in zip(pa, pb, vals, t.lines):
        first = seen.setdefault(frozenset((a, b)), line)
        if first != line:
            raise AssessmentError(f"{location(path, line)}: a second row for the pair {a}, {b} (first at "
                                  f"line {first}); keep one row per pair")
        if a == b and np.any(np.diag(blk) <= 0):
            raise AssessmentError(f"{location(path, line)}: point {a}: the variances c_EE, c_NN, c_hh "
                                  "must be positive")
    order = list(dict.fromkeys(pa + pb))
    ids = [str(q) for q in points] if points is not None else order
    present = set(order)
    missing = [q for q in ids if q not in present]
    if missing:
        raise AssessmentError(f"{path}: no covariance for point(s) {', '.join(missing[:10])}"
                              + (" ..." if len(missing) > 10 else "")
                              + f"; the file holds {len(order)} check point(s) of its adjustment")
    pos = {q: i for i, q in enumerate(ids)}
    k = len(ids)
    C = np.full((3 * k, 3 * k), np.nan)
    for a, b, blk in zip(pa, pb, vals):
        if a in pos and b in pos:
            i, j = pos[a], pos[b]
            C[3 * i:3 * i + 3, 3 * j:3 * j + 3] = blk
            C[3 * j:3 * j + 3, 3 * i:3 * i + 3] = blk.T
    if np.isnan(C).any():
        i, j = (int(v) // 3 for v in np.argwhere(np.isnan(C))[0])
        raise AssessmentError(f"{path}: no row for the pair {ids[i]}, {ids[j]}; the file must hold one row "
                              "per pair of its points")
    return ids, C


def _write_point_covariance(path, ids: Sequence[str], C: np.ndarray, comment: str) -> None:
    """Write the joint covariance *C* (3k, 3k) of points *ids* as :func:`read_point_covariance` reads it:
    one row of the 3 x 3 block per pair a <= b, atomically."""
    from ._io import write_csv_atomic

    rows = [[a, b, *C[3 * i:3 * i + 3, 3 * j:3 * j + 3].ravel()]
            for i, a in enumerate(ids) for j, b in enumerate(ids[i:], start=i)]
    write_csv_atomic(path, COVARIANCE_COLUMNS, rows, comments=[comment])


def _tiny(dc: np.ndarray, dp: np.ndarray, tol_m: float, tol_rad: float) -> bool:
    lin = max(np.abs(dc[:, :3]).max(initial=0.0), np.abs(dp).max(initial=0.0))
    ang = np.abs(dc[:, 3:]).max(initial=0.0)
    return bool(lin < tol_m and ang < tol_rad)


# ---------------------------------------------------------------------------
# survey -> problem
# ---------------------------------------------------------------------------


def problem_from_survey(
    survey: Survey,
    control: str | None = None,
    observations: str | None = None,
    *,
    eo_constraints: bool = False,
) -> BundleProblem:
    """Build the :class:`BundleProblem` of a survey.

    Parameters
    ----------
    survey : lidarcat.Survey
    control : str, optional
        Control set name (default: the survey's default set).
    observations : {"corrected", "pixel"}, optional
        Printed corrected photo coordinates or pixel coordinates through the
        interior orientation (default: the survey setting).
    eo_constraints : bool
        Use the photo positions / attitudes of ``photos.csv`` that carry sigmas as
        weighted constraints.

    Points excluded by the survey settings are left out; ground points measured on
    no photo are ignored (control points among them with a logged warning and
    listed as ``control_unmeasured`` in the summary).  Check points of the set
    are free points with role ``check``; every other point has role ``tie``.
    """
    cset = survey.control_set(control)
    obs = survey.photo_observations(observations)
    photos = survey.photos
    photo_ids = [ph.id for ph in photos]
    focal = [survey.cameras[ph.camera].focal_length_mm for ph in photos]
    ph_pos = {pid: i for i, pid in enumerate(photo_ids)}
    point_ids: list[str] = []
    pt_pos: dict[str, int] = {}
    for q in obs.point:
        if q not in pt_pos:
            pt_pos[q] = len(point_ids)
            point_ids.append(q)
    gp = survey.ground_points
    g_index = {str(q): i for i, q in enumerate(gp.point)}
    ctrl_all = [str(c) for c in cset.control]
    measured = [c in pt_pos for c in ctrl_all]
    unmeasured = [c for c, m in zip(ctrl_all, measured) if not m]
    if unmeasured:
        log.warning("control set %r: point(s) %s measured on no photo; left out", cset.name,
                    ", ".join(unmeasured))
    ctrl = [c for c, m in zip(ctrl_all, measured) if m]
    ci = np.array([pt_pos[c] for c in ctrl], dtype=np.int64)
    cenh = np.array([gp.enh_m[g_index[c]] for c in ctrl], dtype=float).reshape(-1, 3)
    csd = np.asarray(cset.sd_m, dtype=float).reshape(-1, 3)[np.asarray(measured, dtype=bool)]
    role = np.full(len(point_ids), "tie", dtype=object)
    for q in cset.check:
        if str(q) in pt_pos:
            role[pt_pos[str(q)]] = "check"
    role[ci] = "control"
    n_ph = len(photo_ids)
    init = np.full((n_ph, 6), np.nan)
    e_idx, e_val, e_sd = [], [], []
    for i, ph in enumerate(photos):
        if ph.position_m is not None and ph.attitude_deg is not None:
            init[i, :3] = ph.position_m
            init[i, 3:] = np.radians(ph.attitude_deg)
        elif ph.position_m is not None:
            init[i, :3] = ph.position_m
        if eo_constraints and ph.position_m is not None:
            val = np.full(6, np.nan)
            sd = np.full(6, np.inf)
            val[:3] = ph.position_m
            if ph.sd_position_m is not None:
                sd[:3] = ph.sd_position_m
            if ph.attitude_deg is not None:
                val[3:] = np.radians(ph.attitude_deg)
                if ph.sd_attitude_deg is not None:
                    sd[3:] = np.radians(ph.sd_attitude_deg)
            val = np.where(np.isfinite(val), val, 0.0)
            sd = np.where(np.isfinite(sd) & (sd > 0), sd, np.inf)
            if np.isfinite(sd).any():
                e_idx.append(i)
                e_val.append(val)
                e_sd.append(sd)
    return BundleProblem(
        photo_ids=photo_ids, point_ids=point_ids, focal_length_mm=np.asarray(focal, dtype=float),
        photo_index=np.array([ph_pos[str(x)] for x in obs.photo], dtype=np.int64),
        point_index=np.array([pt_pos[str(x)] for x in obs.point], dtype=np.int64),
        xy_mm=obs.xy_mm, sd_mm=obs.sd_mm,
        constraint_point_index=ci, constraint_enh_m=cenh, constraint_sd_m=csd,
        eo_constraint_photo_index=np.array(e_idx, dtype=np.int64) if e_idx else None,
        eo_constraint_params=np.array(e_val) if e_idx else None,
        eo_constraint_sd=np.array(e_sd) if e_idx else None,
        initial_eo=init if np.isfinite(init).any() else None,
        point_role=role,
        info={"survey": survey.name, "control_set": cset.name, "control_unmeasured": unmeasured,
              "observations": observations or survey.settings.observations,
              "eo_constraints": bool(eo_constraints and e_idx)},
    )


# ---------------------------------------------------------------------------
# output files
# ---------------------------------------------------------------------------

#: columns of eop.csv (metres and degrees)
EOP_COLUMNS = ("photo", "X0", "Y0", "Z0", "omega", "phi", "kappa",
               "sd_X0", "sd_Y0", "sd_Z0", "sd_omega", "sd_phi", "sd_kappa")
#: columns of points.csv (metres); role is control, check or tie
POINT_COLUMNS = ("point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "role")
#: columns of residuals.csv: adjusted minus observed; image rows use vx_mm, vy_mm; control rows
#: vE_m, vN_m, vh_m; camera-constraint rows (kind eo) vE_m, vN_m, vh_m for X0, Y0, Z0 and the angles
RESIDUAL_COLUMNS = ("kind", "photo", "point", "vx_mm", "vy_mm", "vE_m", "vN_m", "vh_m",
                    "vomega_deg", "vphi_deg", "vkappa_deg")


def write_adjustment(result: BundleResult, folder, extra: dict | None = None) -> dict:
    """Write ``eop.csv``, ``points.csv``, ``residuals.csv`` and ``summary.json`` into *folder*,
    and ``check_covariance.csv`` (:func:`read_point_covariance`) when the adjustment converged
    with 1 to :data:`MAX_JOINT_COVARIANCE_POINTS` check points.

    Each file is written atomically; wrap the call in :func:`lidarcat._io.atomic_dir`
    to make the whole folder appear at once.  Returns the summary dict written.
    """
    from pathlib import Path

    from ._io import write_csv_atomic, write_json_atomic

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    sd = result.eo_sd
    write_csv_atomic(folder / "eop.csv", EOP_COLUMNS, [
        [pid, *p[:3], *np.degrees(p[3:]), *s[:3], *np.degrees(s[3:])]
        for pid, p, s in zip(result.photo_ids, result.eo_params, sd)],
        comments=["exterior orientation: X0, Y0, Z0 (m), omega, phi, kappa (deg), "
                  "M = R3(kappa) R2(phi) R1(omega); sd_* standard deviations "
                  f"({result.variance_factor_kind.replace('_', ' ')} variance factor)"])
    psd = result.point_sd_m
    write_csv_atomic(folder / "points.csv", POINT_COLUMNS, [
        [q, *x, *s, r] for q, x, s, r in zip(result.point_ids, result.points_m, psd, result.point_role)],
        comments=["adjusted object points: E, N, h and standard deviations (m); "
                  "role: control (weighted constraint), check (free, for assessment), tie (free)"])
    pr = result.problem
    nan = math.nan
    rows: list[list[Any]] = [["image", pr.photo_ids[i], pr.point_ids[j], v[0], v[1], nan, nan, nan, nan, nan, nan]
                             for i, j, v in zip(pr.photo_index, pr.point_index, result.residuals_mm)]
    for j, v, sdc in zip(pr.constraint_point_index, result.constraint_residuals_m, pr.constraint_sd_m):
        v = np.where(np.isfinite(sdc), v, nan)
        rows.append(["control", "", pr.point_ids[j], nan, nan, *v, nan, nan, nan])
    if result.eo_constraint_residuals is not None:
        for i, v, sde in zip(pr.eo_constraint_photo_index, result.eo_constraint_residuals, pr.eo_constraint_sd):
            v = np.where(np.isfinite(sde), v, nan)
            rows.append(["eo", pr.photo_ids[i], "", nan, nan, *v[:3], *np.degrees(v[3:])])
    write_csv_atomic(folder / "residuals.csv", RESIDUAL_COLUMNS, rows,
                     comments=["residuals v = adjusted - observed"])
    checks = [str(q) for q, r in zip(result.point_ids, result.point_role) if r == "check"]
    if checks and result.success and len(checks) <= MAX_JOINT_COVARIANCE_POINTS:
        _write_point_covariance(
            folder / "check_covariance.csv", checks, joint_point_covariance(result, checks),
            "joint covariance of the check points' adjusted E, N, h (m^2), cross-covariances "
            "included: c_XY = Cov(X of point_a, Y of point_b), one row per pair a <= b "
            f"({result.variance_factor_kind.replace('_', ' ')} variance factor)")
    elif len(checks) > MAX_JOINT_COVARIANCE_POINTS:
        log.info("%d check points: joint covariance not written (limit %d)", len(checks),
                 MAX_JOINT_COVARIANCE_POINTS)
    summary = {**result.summary(), **(extra or {})}
    write_json_atomic(folder / "summary.json", summary)
    return summary


def adjust_survey(
    survey=None,
    *,
    control: str | None = None,
    observations: str | None = None,
    outdir=None,
    variance_factor: str | None = None,
    chi2_level: float | None = None,
    eo_constraints: bool = False,
    max_iter: int = 50,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[BundleResult, Any]:
    """Load a survey, adjust it and write the result folder (``lidarcat adjust``).

    Parameters
    ----------
    survey : Survey, path or None
        None: the embedded thesis block.
    control, observations : str, optional
        Control set and observation kind (default: the survey's settings).
    outdir : path, optional
        Output folder (default :meth:`Survey.output_dir`); written atomically,
        files are replaced only when every file has been written.
    variance_factor, chi2_level : optional
        Default: the survey's ``[adjustment]`` settings.
    eo_constraints : bool
        Use photos.csv exterior orientations with sigmas as weighted constraints.

    Returns
    -------
    (BundleResult, Path of the output folder)

    Raises
    ------
    SurveyError, DatumError
    """
    from ._io import atomic_dir
    from .survey import Survey

    t0 = time.perf_counter()
    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    settings = survey.settings
    problem = problem_from_survey(survey, control=control, observations=observations,
                                  eo_constraints=eo_constraints)
    result = adjust(problem, max_iter=max_iter,
                    variance_factor=variance_factor or settings.variance_factor,
                    chi2_level=settings.chi2_level if chi2_level is None else chi2_level,
                    progress=progress)
    out = survey.output_dir(outdir)
    with atomic_dir(out) as tmp:
        write_adjustment(result, tmp, extra={"elapsed_total_s": time.perf_counter() - t0,
                                             "crs": survey.crs})
    return result, out
