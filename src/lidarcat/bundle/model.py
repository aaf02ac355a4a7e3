r"""The collinearity model with weighted constraints: residuals and normal-equation blocks.

For every image observation (photo i, point j) :func:`lidarcat.geometry.collinearity.project_with_jacobians`
(its parts, :func:`~lidarcat.geometry.collinearity.project_jacobian_parts`)
gives the residual ``r = x(eo_i, X_j) - x_obs`` (mm) and its Jacobians ``A_eo`` (2x6)
and ``A_pt`` (2x3); with the weights ``w = 1 / sd^2`` the blocks of the normal
equations are

    U_i = sum_obs A_eo^T w A_eo,   V_j = sum_obs A_pt^T w A_pt,   W_ij = A_eo^T w A_pt,
    g_c = sum_obs A_eo^T w r,      g_p = sum_obs A_pt^T w r.

The position constraints of control points add ``1 / sd^2`` to the diagonal of
``V_j`` and ``w (X_j - X_obs)`` to ``g_p``; camera constraints (GNSS/INS) do the
same to ``U_i`` and ``g_c`` (angle residuals wrapped to (-pi, pi]).  ``v'Pv`` is
the weighted sum of squares of all of them.  A problem with per-observation rays
(``problem.rays``: rolling-shutter centre offsets, sensors of a rig) is projected by
:func:`lidarcat.bundle.rays.observation_parts` with the same blocks (the body pose of a rig
exposure takes the photo's place).  :class:`NormalSystem` holds one
linearisation; :func:`weighted_cost` evaluates ``v'Pv`` only (infinite when a point is
behind a camera).  Line control (``problem.lines``, :mod:`lidarcat.bundle.lines`) adds
``A^T P A`` and ``A^T P r`` of every line observation to its photo's ``U_i`` and ``g_c`` and
``r^T P r`` to ``v'Pv`` (its residuals in ``NormalSystem.r_lines``).
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.collinearity import project, project_jacobian_parts
from .rays import observation_parts, observation_project
from .lines import line_cost, line_normal_terms
from .linear import Schur
from .problem import BundleProblem

__all__ = ["NormalSystem", "weighted_cost"]


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


class NormalSystem:
    """Normal-equation blocks of one linearisation.

    *schur* (:class:`lidarcat.bundle.linear.Schur`) is the analysed pattern of
    the reduced camera system, shared by every linearisation of one problem
    (built here when not given).
    """

    def __init__(self, problem: BundleProblem, eo: np.ndarray, pts: np.ndarray, schur: Schur | None = None):
        p = problem
        self.p = p
        self.schur = schur if schur is not None else Schur(p.photo_index, p.point_index, p.n_photos,
                                                            p.n_points, coords=np.asarray(eo)[:, :3])
        ei, pj = p.photo_index, p.point_index
        if p.rays is None:
            xy, a_pt, a_ang, u3 = project_jacobian_parts(eo, pts[pj], p.focal_length_mm[ei], ei)
        else:
            xy, a_pt, a_ang, u3 = observation_parts(p, eo, pts)
        self.u3 = u3
        r = xy - p.xy_mm                                 # residual (adjusted - observed)
        w = 1.0 / p.sd_mm**2                             # (n, 2)
        self.r_obs = r
        # a_eo = [-a_pt, a_ang]: W and V from two 3 x 3 products per ray, U as per-photo Gram
        # matrices of sqrt(w) a_eo (one BLAS product per photo)
        by_cam, by_pt = self.schur.by_camera, self.schur.by_point
        wr = w * r
        wp_t = np.transpose(a_pt * w[:, :, None], (0, 2, 1))     # (n, 3, 2)
        Ppp = wp_t @ a_pt                                  # a_pt' w a_pt (n, 3, 3)
        n = len(r)
        Wt = np.empty((n, 3, 6))                           # (a_eo' w a_pt)^T, stored contiguous
        np.negative(Ppp, out=Wt[:, :, :3])                 # (Ppp symmetric)
        np.matmul(wp_t, a_ang, out=Wt[:, :, 3:])           # (a_ang' w a_pt)^T
        self.W = np.transpose(Wt, (0, 2, 1))               # (n, 6, 3) view
        sw = np.sqrt(w)[:, :, None]
        swa = np.empty((n, 2, 6))
        np.multiply(a_pt, -sw, out=swa[:, :, :3])
        np.multiply(a_ang, sw, out=swa[:, :, 3:])
        self.U = self.schur.gram_by_camera(swa)
        self.V = by_pt(Ppp)
        gp_obs = np.einsum("nki,nk->ni", a_pt, wr)         # a_pt' w r (n, 3)
        ga_obs = np.einsum("nki,nk->ni", a_ang, wr)
        self.g_c = by_cam(np.concatenate([-gp_obs, ga_obs], axis=1))
        self.g_p = by_pt(gp_obs)
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
        self.r_lines = None
        if p.lines is not None:
            rl, ul, gl, vl, u3l = line_normal_terms(p.lines, eo, p.focal_length_mm, p.n_photos)
            self.U += ul
            self.g_c += gl
            vtpv += vl
            self.r_lines = rl
            if np.any(u3l >= 0):
                self.u3 = np.r_[self.u3, u3l.ravel()]      # an end point behind its camera
        self.vtpv = vtpv

    def solve(self, lam: float, method: str = "direct", reuse: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Corrections (P, 6), (Q, 3) of the damped normal equations (``N + lam diag(N)``);
        *method* ``direct`` or ``pcg``, *reuse* the previous factor
        (:meth:`lidarcat.bundle.linear.Schur.solve`)."""
        U, V = self.U.copy(), self.V.copy()
        if lam > 0:
            iu, iv = np.arange(6), np.arange(3)
            U[:, iu, iu] *= 1.0 + lam
            V[:, iv, iv] *= 1.0 + lam
        return self.schur.solve(U, V, self.W, self.g_c, self.g_p, method, reuse)


def weighted_cost(problem: BundleProblem, eo: np.ndarray, pts: np.ndarray) -> float:
    """v'Pv of image observations and constraints at *eo* (P, 6), *pts* (Q, 3); infinite
    when a point is behind (or in the plane of) a camera."""
    p = problem
    ei, pj = p.photo_index, p.point_index
    if p.rays is None:
        xy, u3 = project(eo, pts[pj], p.focal_length_mm[ei], ei)
    else:
        xy, u3 = observation_project(p, eo, pts)
    if np.any(u3 >= 0) or not np.all(np.isfinite(xy)):
        return math.inf  # a point behind (or in the plane of) a camera
    c = float(np.sum(((xy - p.xy_mm) / p.sd_mm) ** 2))
    rc, wc, re, we = _constraint_terms(p, eo, pts)
    c += float(np.sum(wc * rc**2))
    if re is not None:
        c += float(np.sum(we * re**2))
    if p.lines is not None:
        c += line_cost(p.lines, eo, p.focal_length_mm)
    return c
