r"""The adjustment: Levenberg-Marquardt iteration and its result.

Gauss-Newton with Levenberg-Marquardt damping (``N + lambda diag(N)``) on the
normal equations of :mod:`.model`, each step solved through the reduced camera
system of :mod:`.linear`.  A step is accepted when v'Pv does not grow (else
lambda grows tenfold); lambda shrinks tenfold after an accepted step.  Iteration
stops when the largest correction is below ``tol_m`` / ``tol_rad`` and v'Pv
changes by less than ``tol_vtpv`` (relative).  The covariance blocks
(:mod:`.precision`) come from the normal equations linearised at the solution.
Non-convergence is a ``status`` of :class:`BundleResult`, not an exception.

Geodesic acceleration on a rejected step
----------------------------------------
A block held in one direction only by weak constraints (one control line in two photos plus
GNSS 2 m / IMU 0.5 deg: along the line the block rests on the GNSS) has a long, *curved*
valley of v'Pv: the weak mode is a joint motion of cameras and points that keeps the image
residuals small only along a curve in parameter space.  The Gauss-Newton step ``d`` is its
tangent; along it the image residuals grow quadratically, ``r(x + t d) = r + t J d + t^2 r''/2``,
so v'Pv is quartic in ``t`` (seed 3 of the measured-control benchmark: 820 t^4 for the image
observations against a GNSS decrease of a few units).  The full step is rejected, lambda
grows, the next damped step is accepted but short, lambda shrinks, and so on: linear
convergence at a rate near 1 (>100 iterations, corrections of mm-cm that never fall under
``tol_m`` in 50).  The damping rule is not at fault (the nearly undamped step itself raises v'Pv),
nor the line Jacobian (exact): the Gauss-Newton model is.

The cure is the second-order term of the path (Transtrum & Sethna 2012, "geodesic
acceleration"): with the second directional derivative ``r''`` of the residuals along ``d``
(central differences, ``r'' = (r(x + h d) - 2 r(x) + r(x - h d)) / h^2``, exact for residuals
quadratic along ``d``), the acceleration solves the same damped normal equations,
``(N + lambda diag N) a = -J^T P r''``, and the step ``d + a/2`` follows the valley to second
order.  It is tried only when the plain step is rejected (before lambda grows), so a
well-behaved adjustment -- every step accepted, the thesis tables -- iterates exactly as before;
the extra cost is three residual evaluations and one solve with the factor just computed
(re-used as the preconditioner of conjugate gradients).  Point and camera constraints are
linear (``r'' = 0``); line observations contribute ``A^T P l''``.  The accelerated step is
accepted when it lowers v'Pv.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable

import numpy as np

from ..errors import DatumError

from ..geometry.collinearity import project, project_jacobian_parts

from .approx import approximations, intersect_points
from ._blas import pinned
from ._heap import heap_reuse
from .model import NormalSystem, weighted_cost
from .lines import line_terms
from .rays import observation_project
from .linear import Schur, SingularSystem
from .precision import PRECISION_LEVELS, covariance_blocks
from .problem import BundleProblem, check_datum, chi2_bounds
from .rig import rig_initial_points
from .result import STATUS_MESSAGES, BundleResult

__all__ = ["BundleResult", "adjust", "geodesic_acceleration", "where_it_fails", "STATUS_MESSAGES", "PCG_MIN_PHOTOS", "FACTOR_REUSE_MIN_PHOTOS"]

#: ``adjust(solver="auto")`` iterates with PCG from this many photos (the direct solver below; on
#: strip blocks block-Jacobi PCG lost to the supernodal factor at 1,000 photos: docs/bundle.md)
PCG_MIN_PHOTOS = 20000

#: the direct solver reuses its last factor (as the preconditioner of a few conjugate-gradient
#: steps, :func:`lidarcat.bundle.linear._pcg_factor`) from this many photos ...
FACTOR_REUSE_MIN_PHOTOS = 2000
#: ... once an accepted step lowered v'Pv by less than this fraction (the quadratic phase)
FACTOR_REUSE_BELOW = 1e-4

log = logging.getLogger(__name__)

def step_below_tolerance(dc: np.ndarray, dp: np.ndarray, tol_m: float, tol_rad: float) -> bool:
    """True when every linear correction (m) is below *tol_m* and every angle (rad) below *tol_rad*."""
    lin = max(np.abs(dc[:, :3]).max(initial=0.0), np.abs(dp).max(initial=0.0))
    ang = np.abs(dc[:, 3:]).max(initial=0.0)
    return bool(lin < tol_m and ang < tol_rad)


def _residuals(p: BundleProblem, eo: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Image residuals (n, 2) mm and line residuals (m, 2) mm (or None) at *eo*, *pts*."""
    xy, _ = project(eo, pts[p.point_index], p.focal_length_mm[p.photo_index], p.photo_index)
    rl = None if p.lines is None else line_terms(p.lines, eo, p.focal_length_mm, jacobians=False).r
    return xy - p.xy_mm, rl


def geodesic_acceleration(system: NormalSystem, eo: np.ndarray, pts: np.ndarray, dc: np.ndarray,
                          dp: np.ndarray, lam: float, method: str, h: float = 0.5):
    """Second-order correction ``(ac (P, 6), ap (Q, 3))`` of the step ``(dc, dp)`` (Transtrum & Sethna).

    Solves ``(N + lam diag N) a = -J' P r''`` with ``r''`` the second directional derivative of the
    image and line residuals along the step, by central differences (step *h*: exact for residuals
    quadratic along it; the point and camera constraints are linear, ``r'' = 0``).  The accelerated
    step is ``d + a / 2``: it follows a curved valley of v'Pv (see the module docstring).  Returns
    None for a block with ``rays`` (rolling shutter, rigs).
    """
    p = system.p
    if p.rays is not None:
        return None
    r0, l0 = _residuals(p, eo, pts)
    rp, lp = _residuals(p, eo + h * dc, pts + h * dp)
    rm, lm = _residuals(p, eo - h * dc, pts - h * dp)
    rdd = (rp - 2 * r0 + rm) / h**2
    ei, pj = p.photo_index, p.point_index
    _, a_pt, a_ang, _ = project_jacobian_parts(eo, pts[pj], p.focal_length_mm[ei], ei)
    wr = rdd / p.sd_mm**2
    gp_obs = np.einsum("nki,nk->ni", a_pt, wr)
    ga_obs = np.einsum("nki,nk->ni", a_ang, wr)
    schur = system.schur
    g_c = schur.by_camera(np.concatenate([-gp_obs, ga_obs], axis=1))
    g_p = schur.by_point(gp_obs)
    if p.lines is not None:
        T = line_terms(p.lines, eo, p.focal_length_mm)
        ldd = (lp - 2 * l0 + lm) / h**2
        np.add.at(g_c, p.lines.photo_index, np.einsum("kji,kjl,kl->ki", T.A, T.P, ldd))
    if not (np.isfinite(g_c).all() and np.isfinite(g_p).all()):
        return None
    U, V = system.U.copy(), system.V.copy()
    if lam > 0:
        iu, iv = np.arange(6), np.arange(3)
        U[:, iu, iu] *= 1.0 + lam
        V[:, iv, iv] *= 1.0 + lam
    return schur.solve(U, V, system.W, g_c, g_p, method, method == "direct")


def where_it_fails(p: BundleProblem, eo: np.ndarray, pts: np.ndarray, n: int = 3) -> str:
    """``: ...`` naming the observations a failed adjustment ends on: points behind a camera, else the
    largest normalised image residuals (photo, point, residual in sds)."""
    ei, pj = p.photo_index, p.point_index
    if not len(ei):
        return ""
    xy, u3 = observation_project(p, eo, pts)
    behind = np.flatnonzero((u3 >= 0) | ~np.isfinite(xy).all(axis=1))
    if len(behind):
        names = ", ".join(f"point {p.point_ids[pj[k]]} on photo {p.photo_ids[ei[k]]}" for k in behind[:n])
        return (f"; {len(behind)} observation(s) of points behind their camera ({names}"
                + (" ..." if len(behind) > n else "") + "): gross matches; adjust with --snooping "
                "report or remove (the robust start screens them)")
    u = np.sqrt(np.sum(((xy - p.xy_mm) / p.sd_mm) ** 2, axis=1))
    top = np.argsort(-u)[:n]
    return "; largest image residuals: " + ", ".join(
        f"point {p.point_ids[pj[k]]} on photo {p.photo_ids[ei[k]]} ({u[k]:.3g} sd)" for k in top)


@heap_reuse()
@pinned()
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
    acceleration: bool = True,
    check: bool = True,
    precision: str = "all",
    solver: str = "auto",
    progress: Callable[[int, float], None] | None = None,
) -> BundleResult:
    """Simultaneous bundle adjustment with weighted position constraints.

    Parameters
    ----------
    problem : BundleProblem
    initial : (eo (P, 6), points (Q, 3) or None), optional
        Approximate values (m, rad).  Default: computed by
        :func:`lidarcat.bundle.approx.approximations` from control points, image
        measurements and ``problem.initial_eo`` (a planimetric block adjustment,
        then sweeps of intersection and space resection).  With points ``None``
        they are intersected from the given orientations.  A rig block
        (``problem.rays`` with sensors) starts from ``problem.initial_eo`` (every
        exposure's body pose) and :func:`lidarcat.bundle.rig.rig_initial_points`.
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
    acceleration : bool
        Retry a rejected damped step with its geodesic acceleration (module docstring)
        before increasing lambda; blocks with ``rays`` never (plain collinearity only).
    check : bool
        Run :func:`check_datum` first.
    precision : {"all", "photos", "none"}
        Covariance blocks to compute at the solution: of every photo and point,
        of the photos only (``point_cov`` NaN), or none (both NaN; the fastest).
    solver : {"auto", "direct", "pcg"}
        Linear solver of the reduced camera system in the iterations: the
        supernodal Cholesky (exact steps), or block-Jacobi preconditioned
        conjugate gradients truncated as inexact Newton (cheaper steps on large
        blocks); ``auto``: ``pcg`` from :data:`PCG_MIN_PHOTOS` photos.  From
        :data:`FACTOR_REUSE_MIN_PHOTOS` photos the direct solver, once a step
        lowers v'Pv by less than :data:`FACTOR_REUSE_BELOW`, first tries the
        previous factor as the preconditioner of a few conjugate-gradient steps
        (to a relative residual of 1e-8) and factors only when they do not
        converge.  The covariance always uses a fresh Cholesky factor at the
        solution.
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
    if precision not in PRECISION_LEVELS:
        raise ValueError(f"`precision` must be one of {', '.join(PRECISION_LEVELS)}, got {precision!r}")
    if solver not in ("auto", "direct", "pcg"):
        raise ValueError(f"`solver` must be one of auto, direct, pcg, got {solver!r}")
    t0 = time.perf_counter()
    p = problem
    phases = dict.fromkeys(("check", "approximations", "analysis", "model", "solve", "precision"), 0.0)

    @contextlib.contextmanager
    def phase(name: str):
        t = time.perf_counter()
        yield
        phases[name] += time.perf_counter() - t

    if check:
        with phase("check"):
            check_datum(p)
    rig = p.rays is not None and p.rays.has_sensors
    if initial is None and rig:
        if p.initial_eo is None or not np.isfinite(p.initial_eo).all():
            raise DatumError("a rig block needs approximate body poses of every exposure (initial_eo): "
                             "lidarcat.bundle.rig.exposure_problem takes them from the photos' approximations")
        initial = (p.initial_eo, None)
    if initial is None:
        with phase("approximations"):
            eo, pts = approximations(p)
    else:
        eo = np.array(initial[0], dtype=float).reshape(p.n_photos, 6)
        if initial[1] is None:
            pts = rig_initial_points(p, eo) if rig else intersect_points(p, eo)
        else:
            pts = np.array(initial[1], dtype=float).reshape(p.n_points, 3)
    eo0, pts0 = eo.copy(), pts.copy()

    lam = 1e-3 if damping else 0.0
    status = "max_iterations"
    n_iter = 0
    n_accelerated = 0
    history: list[float] = []
    system = None
    with phase("analysis"):
        # pattern of S and its ordering (camera positions of the approximations), analysed once
        schur = Schur(p.photo_index, p.point_index, p.n_photos, p.n_points, coords=eo[:, :3])
    method = solver if solver != "auto" else ("pcg" if p.n_photos >= PCG_MIN_PHOTOS else "direct")
    may_reuse = method == "direct" and p.n_photos >= FACTOR_REUSE_MIN_PHOTOS
    last_gain = math.inf          # relative decrease of v'Pv by the last accepted step
    try:
        with phase("model"):
            system = NormalSystem(p, eo, pts, schur)
            cost = system.vtpv if np.all(system.u3 < 0) else weighted_cost(p, eo, pts)
        history.append(cost)
        if not math.isfinite(cost):
            status = "behind"
            max_iter = 0            # no step can be compared with an infinite v'Pv
        while n_iter < max_iter:
            n_iter += 1
            accepted = False
            while True:
                with phase("solve"):
                    dc, dp = system.solve(lam, method, reuse=may_reuse and last_gain < FACTOR_REUSE_BELOW)
                eo_new, pts_new = eo + dc, pts + dp
                with phase("model"):
                    new_cost = weighted_cost(p, eo_new, pts_new)
                if math.isfinite(new_cost) and (not damping or new_cost <= cost * (1 + 1e-12)
                                                or step_below_tolerance(dc, dp, tol_m, tol_rad)):
                    accepted = True
                    break
                if damping and acceleration:
                    # a rejected step: try it bent along the valley (d + a/2) before damping more
                    with phase("solve"):
                        acc = geodesic_acceleration(system, eo, pts, dc, dp, lam, method)
                    if acc is not None:
                        eo_acc, pts_acc = eo + dc + 0.5 * acc[0], pts + dp + 0.5 * acc[1]
                        with phase("model"):
                            acc_cost = weighted_cost(p, eo_acc, pts_acc)
                        if math.isfinite(acc_cost) and acc_cost < cost:
                            dc, dp = dc + 0.5 * acc[0], dp + 0.5 * acc[1]
                            eo_new, pts_new, new_cost = eo_acc, pts_acc, acc_cost
                            n_accelerated += 1
                            accepted = True
                            break
                lam = max(lam, 1e-6) * 10.0
                if lam > 1e12:
                    break
            if not accepted:
                status = "stalled"
                break
            small = step_below_tolerance(dc, dp, tol_m, tol_rad)
            dcost = abs(cost - new_cost) / max(cost, 1.0)
            last_gain = (cost - new_cost) / cost if cost > 0 else 0.0
            eo, pts = eo_new, pts_new
            eo[:, 3:] = (eo[:, 3:] + np.pi) % (2 * np.pi) - np.pi
            cost = new_cost
            history.append(cost)
            if progress is not None:
                progress(n_iter, cost)
            log.debug("iteration %d: v'Pv %.6g, lambda %.1e, max|dX| %.3g m (%d accelerated)", n_iter, cost, lam,
                      np.abs(np.concatenate([dc[:, :3].ravel(), dp.ravel()])).max(), n_accelerated)
            if damping:
                lam = lam / 10.0 if lam > 1e-12 else 0.0
            with phase("model"):
                system = NormalSystem(p, eo, pts, schur)
            if small and dcost < tol_vtpv:
                status = "converged"
                break
        schur.release_factor()
        with phase("precision"):
            eo_cov, point_cov = covariance_blocks(system, precision)  # linearised at (eo, pts)
    except SingularSystem as ex:
        status = "singular"
        log.warning("bundle adjustment: %s", ex)
        eo_cov = np.full((p.n_photos, 6, 6), np.nan)
        point_cov = np.full((p.n_points, 3, 3), np.nan)
        if system is None:
            system = NormalSystem(p, eo, pts, schur)
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
    if status in ("stalled", "behind", "max_iterations"):
        msg += where_it_fails(p, eo, pts)
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
        initial_eo=eo0, initial_points_m=pts0, elapsed_s=time.perf_counter() - t0, precision=precision,
        phases_s={**phases, **{f"solve_{k}": v for k, v in schur.timings.items()}},
    )
