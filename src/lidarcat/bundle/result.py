r"""The result of an adjustment: :class:`BundleResult` and its status messages.

Its own module so that :mod:`.precision` (which reads a result) and
:mod:`.solve` (which makes one) both import it without importing each other.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from .problem import BundleProblem, ExteriorOrientation

__all__ = ["BundleResult", "STATUS_MESSAGES"]

#: status -> message of :class:`BundleResult`
STATUS_MESSAGES: dict[str, str] = {
    "converged": "converged: corrections and v'Pv change below tolerance",
    "max_iterations": "maximum number of iterations reached before convergence",
    "stalled": "no further decrease of v'Pv is possible (damping grew without bound)",
    "singular": "normal equations are singular (datum defect or degenerate geometry)",
    "behind": "a point lies behind a camera at the approximate values: no step can be taken",
}


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
    precision : str
        Which covariance blocks were computed (``all``, ``photos``, ``none``;
        the others are NaN).
    phases_s : dict
        Wall time (s) of the phases: ``check``, ``approximations``, ``analysis``
        (pattern and symbolic factorisation), ``model`` (residuals, Jacobians,
        normal-equation blocks), ``solve`` (of it ``solve_assemble`` and
        ``solve_factor``, or ``solve_pcg``), ``precision``.
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
    precision: str = "all"
    phases_s: dict = dataclasses.field(default_factory=dict)

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
            "precision": self.precision,
        }


def _position(ids: np.ndarray, wanted: Any, what: str) -> int:
    hit = np.flatnonzero(ids == str(wanted))
    if not len(hit):
        raise ValueError(f"{what} {str(wanted)!r} is not in the adjustment")
    return int(hit[0])
