r"""The bundle adjustment bordered by additional (global) parameters.

The unknowns are the exterior orientations ``c`` (6 per photo), the points
``p`` (3 each) and ``k`` global parameters ``g`` (:mod:`.additional`,
:mod:`.frame_offset`).  The normal equations are

.. math::  \begin{bmatrix}U & N_{cg} & W\\ N_{gc} & N_{gg} & N_{gp}\\ W^T & N_{pg} & V\end{bmatrix}
           \begin{bmatrix}\Delta_c\\ \Delta_g\\ \Delta_p\end{bmatrix} =
           -\begin{bmatrix}g_c\\ g_g\\ g_p\end{bmatrix}

``N_cg`` is dense 6P x k (the photos of a camera share its interior
orientation; GNSS offsets touch camera constraints), ``N_pg`` dense 3Q x k
(image rays and control points of a shifted source), ``N_gg`` k x k with the
prior weights on its diagonal.  Eliminating the points (block diagonal V):

    S_cc = U - W V^-1 W^T                 (the reduced camera system of :mod:`.linear`)
    S_cg = N_cg - W V^-1 N_pg             (summed per observation: T_a N_pg[j_a], T_a = W_a V_j^-1)
    S_gg = N_gg - N_gp V^-1 N_pg
    r_c  = b_c - W V^-1 b_p,   r_g = b_g - N_gp V^-1 b_p

The bordered system ``[[S_cc, S_cg], [S_gc, S_gg]]`` is solved by block
elimination of the k globals with k + 1 solves against the sparse factor of
``S_cc`` (so the camera system keeps its sparsity, whatever k):

    X = S_cc^-1 S_cg,    G = S_gg - S_gc X   (k x k),
    Delta_g = G^-1 (r_g - S_gc S_cc^-1 r_c),  Delta_c = S_cc^-1 r_c - X Delta_g,
    Delta_p = V^-1 (b_p - W^T Delta_c - N_pg Delta_g).

``G`` is equilibrated (unit diagonal) before its Cholesky factorisation.

Precision.  With ``H = G^-1`` and ``Z = S_cc^-1`` the inverse of the reduced
system is ``[[Z + X H X^T, -X H], [-H X^T, H]]``, hence

    Cov(g) = H,    Cov(c_i, g) = -X_i H,    Cov(c_i) = Z_ii + X_i H X_i^T,
    Cov(p_j) = V_j^-1 + t_j^T Z t_j + u_j^T H u_j,   Cov(p_j, g) = u_j^T H,

with ``t_j`` the camera blocks ``T_a`` of the rays of point j and
``u_j = sum_a X_{i_a}^T T_a - N_gp[j] V_j^-1`` (k x 3): the Z-terms are the
ordinary blocks of :func:`.precision.covariance_blocks`, the H-terms a rank-k
correction -- no dense inverse of anything that grows with the block.

Iteration: Levenberg-Marquardt (damping ``lambda diag``) from the converged
adjustment without the additional parameters (which is kept: its v'Pv and
residuals show the misfit the parameters remove), the parameters starting at
0 (the calibration certificate / no offset).  The observations change with
the parameters, so each linearisation works on an *effective problem* (the
corrected photo coordinates under the current interior orientation, the
source's control moved into the reference frame): :class:`.NormalSystem` gives the
ordinary blocks, the components add the bordering.

Errors in variables.  A named set's terms are evaluated at the measured photo coordinates,
whose noise the residuals share, so the gradient's expectation at the truth is not 0
(``beta``, a component's ``score_bias``) and the least-squares estimate is biased by
``-N^-1 beta``; after convergence one more solve removes it: ``x + N^-1 beta``
(docs/cameras.md, "The cause").
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import scipy.linalg as sla

from ..geometry.collinearity import block_sum
from ..errors import DatumError
from ._blas import pinned
from ._heap import heap_reuse
from .linear import CHUNK_PAIRS, inv3, Schur, SingularSystem
from .model import NormalSystem, weighted_cost
from .precision import covariance_blocks
from .rays import observation_parts
from .problem import BundleProblem, chi2_bounds
from .result import STATUS_MESSAGES, BundleResult
from .solve import adjust, step_below_tolerance

__all__ = ["SelfCalResult", "adjust_with_parameters"]

log = logging.getLogger(__name__)

#: values (floats) of one chunk of per-observation products T_a N_pg[j_a] (32 MB)
_CHUNK_VALUES = 1 << 22

_FIELDS = ("focal_length_mm", "xy_mm", "constraint_enh_m", "eo_constraint_params", "rays")


class _Globals:
    """The bound components side by side: names, units, prior sds, column offsets."""

    def __init__(self, components: Sequence[Any], problem: BundleProblem):
        self.problem = problem
        self.parts = [c.bind(problem) for c in components]
        self.offsets = np.cumsum([0] + [b.n for b in self.parts])
        self.k = int(self.offsets[-1])
        self.names = [n for b in self.parts for n in b.names]
        dup = sorted({n for n in self.names if self.names.count(n) > 1})
        if dup:
            from .additional import AdditionalParameterError
            raise AdditionalParameterError(f"additional parameter {dup[0]!r} is switched on twice")
        self.units = [u for b in self.parts for u in b.units]
        self.groups = [g for b in self.parts for g in b.groups]
        self.prior_sd = np.concatenate([b.prior_sd for b in self.parts]) if self.parts else np.zeros(0)
        self.prior_w = np.where(np.isfinite(self.prior_sd), 1.0 / self.prior_sd**2, 0.0)

    def effective(self, theta: np.ndarray) -> BundleProblem:
        p = self.problem
        fields = {f: getattr(p, f) for f in _FIELDS}
        for b, o in zip(self.parts, self.offsets):
            b.apply(theta[o:o + b.n], fields)
        fields = {f: v for f, v in fields.items() if v is not None}
        return dataclasses.replace(p, **fields)

    def prior_cost(self, theta: np.ndarray) -> float:
        return float(np.sum(self.prior_w * theta**2))


class _BorderedSystem:
    """One linearisation of the bordered normal equations at (eo, pts, theta)."""

    def __init__(self, gl: _Globals, eo: np.ndarray, pts: np.ndarray, theta: np.ndarray, schur: Schur):
        self.gl = gl
        self.theta = theta
        pe = gl.effective(theta)
        self.pe = pe
        self.sys = sys = NormalSystem(pe, eo, pts, schur)
        self.vtpv = sys.vtpv + gl.prior_cost(theta)
        n_ph, n_pt, k = pe.n_photos, pe.n_points, gl.k
        ei, pj = pe.photo_index, pe.point_index
        xy, a_pt, a_ang, _ = observation_parts(pe, eo, pts)
        a_eo = np.concatenate([-a_pt, a_ang], axis=2)
        self.a_pt = a_pt
        state = _State(pe, xy, eo, pts, a_pt)
        w_obs = 1.0 / pe.sd_mm**2
        rc, re = sys.r_con, sys.r_eo
        wc = np.where(np.isfinite(pe.constraint_sd_m), 1.0 / pe.constraint_sd_m**2, 0.0)
        we = (np.where(np.isfinite(pe.eo_constraint_sd), 1.0 / pe.eo_constraint_sd**2, 0.0)
              if re is not None else None)
        Ncg = np.zeros((n_ph, 6, k))
        Npg = np.zeros((n_pt, 3, k))
        Ngg = np.diag(gl.prior_w).astype(float)
        gg = gl.prior_w * theta
        for b, o in zip(gl.parts, gl.offsets):
            for kind, rows, J, cols in b.jacobians(theta[o:o + b.n], state):
                cols = np.asarray(cols) + o
                if kind == "obs":
                    w, r = w_obs[rows], sys.r_obs[rows]
                    wJ = J * w[:, :, None]
                    _scatter(Ncg, ei[rows], np.transpose(a_eo[rows], (0, 2, 1)) @ wJ, cols)
                    _scatter(Npg, pj[rows], np.transpose(a_pt[rows], (0, 2, 1)) @ wJ, cols)
                elif kind == "con":
                    w, r = wc[rows], rc[rows]
                    wJ = J * w[:, :, None]
                    _scatter(Npg, pe.constraint_point_index[rows], wJ, cols)
                else:  # "eo"
                    w, r = we[rows], re[rows]
                    wJ = J * w[:, :, None]
                    _scatter(Ncg, pe.eo_constraint_photo_index[rows], wJ, cols)
                JtwJ = np.transpose(J, (0, 2, 1)) @ wJ                       # (r, m, m)
                flat = (cols[:, :, None] * k + cols[:, None, :]).ravel()
                Ngg += np.bincount(flat, weights=JtwJ.ravel(), minlength=k * k).reshape(k, k)
                gg += np.bincount(cols.ravel(), weights=np.einsum("rdm,rd->rm", wJ, r).ravel(), minlength=k)
        self.Ncg, self.Npg, self.Ngg, self.gg = Ncg, Npg, Ngg, gg

    def solve(self, lam: float, want_cov: bool = False):
        """Corrections (P, 6), (Q, 3), (k,) of the (damped) bordered normal equations."""
        sys, pe, k = self.sys, self.pe, self.gl.k
        ei, pj = pe.photo_index, pe.point_index
        U, V, Ngg = sys.U.copy(), sys.V.copy(), self.Ngg.copy()
        if lam > 0:
            iu, iv = np.arange(6), np.arange(3)
            U[:, iu, iu] *= 1.0 + lam
            V[:, iv, iv] *= 1.0 + lam
            Ngg[np.diag_indices(k)] *= 1.0 + lam
        vinv = inv3(V)
        schur = sys.schur
        data, T = schur.assemble(U, vinv, sys.W)
        F = schur.factor(data)
        Scg = self.Ncg.copy()
        n = len(ei)
        chunk = max(1024, min(CHUNK_PAIRS, _CHUNK_VALUES // max(6 * k, 1)))   # bounded memory for any k
        for c0 in range(0, n, chunk):
            c1 = min(n, c0 + chunk)
            Scg -= block_sum(ei[c0:c1], T[c0:c1] @ self.Npg[pj[c0:c1]], pe.n_photos)
        VN = vinv @ self.Npg                                                  # (Q, 3, k)
        Sgg = Ngg - np.einsum("qik,qil->kl", self.Npg, VN)
        b_c, b_p, b_g = -sys.g_c, -sys.g_p, -self.gg
        vb = np.einsum("qij,qj->qi", vinv, b_p)
        r_c = b_c - block_sum(ei, np.einsum("nij,nj->ni", T, b_p[pj]), pe.n_photos)
        r_g = b_g - np.einsum("qik,qi->k", self.Npg, vb)
        Scg2 = Scg.reshape(-1, k)
        X = F.solve(Scg2) if k else np.zeros((Scg2.shape[0], 0))
        y = F.solve(r_c.reshape(-1))
        G = Sgg - Scg2.T @ X
        H, dg = _solve_globals(G, r_g - Scg2.T @ y, self.gl.names, np.diag(Ngg))
        dc = (y - X @ dg).reshape(pe.n_photos, 6)
        bp = b_p - block_sum(pj, np.einsum("nij,ni->nj", sys.W, dc[ei]), pe.n_points) - self.Npg @ dg
        dp = np.einsum("qij,qj->qi", vinv, bp)
        if want_cov:
            return dc, dp, dg, (X.reshape(pe.n_photos, 6, k), H, T, vinv)
        return dc, dp, dg


def _score_bias(gl: _Globals, theta: np.ndarray, bs: _BorderedSystem) -> np.ndarray | None:
    """The components' expected gradients at the truth (``score_bias``), or None when none has one.

    Each observation's weight less the part its own point absorbs, ``P = W - W a V_j^-1 a^T W``
    (``a`` = d x / d point, ``V_j`` the point's normal block with its constraints): the residual
    at the solution keeps ``(I - H)`` of the noise, and only the diagonal block of ``H`` enters a
    trace per observation (the photos' share, 6 unknowns over hundreds of rays, is left out).
    """
    if not any(hasattr(b, "score_bias") for b in gl.parts):
        return None
    pe = bs.pe
    w = 1.0 / np.asarray(pe.sd_mm, dtype=float) ** 2
    wa = bs.a_pt * w[:, :, None]                                           # (n, 2, 3)
    vinv = inv3(bs.sys.V)[pe.point_index]
    weight = np.einsum("ij,ni->nij", np.eye(2), w) - wa @ vinv @ np.transpose(wa, (0, 2, 1))
    parts, found = [], False
    for b, o in zip(gl.parts, gl.offsets):
        f = getattr(b, "score_bias", None)
        v = f(theta[o:o + b.n], gl.problem, weight) if f is not None else None
        found = found or v is not None
        parts.append(np.zeros(b.n) if v is None else np.asarray(v, dtype=float))
    return np.concatenate(parts) if found and parts else None


def _bias_corrected(bs: _BorderedSystem, beta: np.ndarray, eo: np.ndarray, pts: np.ndarray,
                    theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The converged estimate less its bias: ``x + N^-1 beta`` (one solve of the bordered system).

    At the least-squares solution ``g(x) = 0 = g(x*) + N (x - x*)``, so ``E[x - x*] = -N^-1 E[g(x*)]
    = -N^-1 beta`` where the gradient's expectation at the truth is not 0 (the errors-in-variables
    terms of :meth:`lidarcat.bundle.additional.SelfCalibration`'s named sets).
    """
    sys = bs.sys
    saved = sys.g_c, sys.g_p, bs.gg
    sys.g_c, sys.g_p, bs.gg = np.zeros_like(sys.g_c), np.zeros_like(sys.g_p), -beta
    try:
        dc, dp, dg = bs.solve(0.0)
    finally:
        sys.g_c, sys.g_p, bs.gg = saved
    eo = eo + dc
    eo[:, 3:] = (eo[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    return eo, pts + dp, theta + dg


class _State:
    """What the Jacobians of a component may read: the effective problem and the predictions."""

    def __init__(self, pe: BundleProblem, xy_pred: np.ndarray, eo: np.ndarray | None = None,
                 pts: np.ndarray | None = None, a_pt: np.ndarray | None = None):
        self.problem = pe
        self.focal_length_mm = pe.focal_length_mm
        self.photo_index = pe.photo_index
        self.xy_pred = xy_pred
        self.eo, self.pts, self.a_pt = eo, pts, a_pt      # the linearisation (rolling shutter, rigs)


def _scatter(target: np.ndarray, index: np.ndarray, blocks: np.ndarray, cols: np.ndarray) -> None:
    """target[index[r], d, cols[r, m]] += blocks[r, d, m] (duplicates summed)."""
    n, d, k = target.shape
    flat = ((np.asarray(index)[:, None, None] * d + np.arange(d)[None, :, None]) * k
            + np.asarray(cols)[:, None, :]).ravel()
    target += np.bincount(flat, weights=blocks.ravel(), minlength=n * d * k).reshape(n, d, k)


def _solve_globals(G: np.ndarray, rhs: np.ndarray, names: Sequence[str],
                   n_diag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H = G^-1 and G^-1 rhs by an equilibrated Cholesky; :class:`SingularSystem` names the worst parameter.

    *n_diag* is the diagonal of N_gg (before the elimination): a parameter with none has no
    observation; one whose diagonal the elimination cancels is absorbed by the other unknowns.
    """
    k = len(G)
    if k == 0:
        return np.zeros((0, 0)), np.zeros(0)
    if np.any(n_diag <= 0):
        i = int(np.argmin(n_diag))
        raise SingularSystem(f"additional parameter {names[i]!r} has no observation (zero normal-equation row)")
    d = np.sqrt(np.clip(np.diag(G), 0, None))
    if np.any(d <= 1e-6 * np.sqrt(n_diag)) or not np.all(np.isfinite(G)):
        i = int(np.argmin(d / np.sqrt(n_diag)))
        raise SingularSystem(f"additional parameter {names[i]!r} cannot be determined: the exterior orientations "
                        "and points absorb it completely (a datum defect or a parameter the geometry "
                        "cannot see)")
    Gs = G / d[:, None] / d[None, :]
    w, vecs = np.linalg.eigh(0.5 * (Gs + Gs.T))
    if w[0] < 1e-12 * w[-1]:
        i = int(np.argmax(np.abs(vecs[:, 0])))
        raise SingularSystem(f"additional parameter {names[i]!r} cannot be determined: the normal equations "
                        f"of the additional parameters are singular (smallest eigenvalue {w[0]:.1e})")
    cf = sla.cho_factor(Gs)
    Hs = sla.cho_solve(cf, np.eye(k))
    H = Hs / d[:, None] / d[None, :]
    return 0.5 * (H + H.T), sla.cho_solve(cf, rhs / d) / d


# ---------------------------------------------------------------------------
# the result
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class SelfCalResult:
    """Adjustment with additional parameters, next to the one without.

    Attributes
    ----------
    bundle : BundleResult
        The adjustment with the additional parameters (its ``problem`` is the
        effective one: photo coordinates corrected with the estimated interior
        orientation, source control moved into the reference frame; ``dof``
        counts the additional unknowns and their priors).
    without : BundleResult
        The same block with the parameters switched off.
    names, units, groups : tuple of str, (k,)
    estimates : (k,) array
        Corrections to the calibration (interior orientation) or the offsets.
    cov : (k, k) array
        Their covariance (the result's variance factor applied).
    prior_sd : (k,) array
        inf for a free parameter.
    calibrated : dict
        name -> calibrated value (interior orientation only).
    eo_correlation : (k, P, 6) array
        Correlation of every parameter with every exterior-orientation parameter.
    singular : str
        Why the normal equations were singular (names the parameter), else "".
    point_coupling : (Q, k, 3) array or None
        ``u_j`` of the module docstring: ``Cov(p_j, g) = u_j^T cov`` and the
        rank-k term of the joint point covariance, ``Cov(p_a, p_b) += u_a^T cov u_b``.
    frame_offsets : tuple of FrameOffset
    explainers : tuple of callables
        ``explain(name, partner, eo, points_m, eo_params) -> str | None`` of the components
        (:meth:`why`: the reason a parameter cannot be told from its partner).
    notes : tuple of str
        Warnings of the components themselves (none of the present components has one).
    alpha : float
        Level of the significance tests.
    """

    bundle: BundleResult
    without: BundleResult
    names: tuple
    units: tuple
    groups: tuple
    estimates: np.ndarray
    cov: np.ndarray
    prior_sd: np.ndarray
    calibrated: dict
    eo_correlation: np.ndarray
    point_coupling: np.ndarray | None = None
    singular: str = ""
    frame_offsets: tuple = ()
    alpha: float = 0.05
    determinability_limit: float = 0.95
    explainers: tuple = ()
    notes: tuple = ()

    def why(self, name: str, partner: str, eo: bool) -> str:
        """Why *name* cannot be told from *partner* (an exterior-orientation parameter name when
        *eo*, else an additional parameter): the first component that knows, else a general clause."""
        for f in self.explainers:
            text = f(name, partner, eo, np.asarray(self.bundle.points_m), np.asarray(self.bundle.eo_params))
            if text:
                return text
        return "their effects on the observations are nearly the same in this block's geometry"

    @property
    def sd(self) -> np.ndarray:
        return np.sqrt(np.clip(np.diag(self.cov), 0, None))

    @property
    def correlation(self) -> np.ndarray:
        """(k, k) correlation matrix of the additional parameters."""
        sd = self.sd
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.cov / sd[:, None] / sd[None, :]

    def joint_point_covariance(self, points: Sequence[str]) -> np.ndarray:
        """:func:`lidarcat.bundle.joint_point_covariance` of the adjustment with the parameters,
        their rank-k term included, (3k, 3k) m^2."""
        from .precision import joint_point_covariance

        C = joint_point_covariance(self.bundle, points)
        if self.point_coupling is None or not len(self.names):
            return C
        pos = {str(q): i for i, q in enumerate(self.bundle.point_ids)}
        Uk = np.concatenate([self.point_coupling[pos[str(q)]] for q in points], axis=1)      # (k, 3m)
        return C + Uk.T @ self.cov @ Uk

    def index(self, name: str) -> int:
        """Position of parameter *name*; ValueError naming the known ones."""
        if name not in self.names:
            raise ValueError(f"no additional parameter {name!r}; there are: {', '.join(self.names)}")
        return self.names.index(name)

    def _test_dist(self):
        from scipy import stats
        if self.bundle.variance_factor_kind == "a_posteriori" and self.bundle.dof > 0:
            return stats.t(self.bundle.dof)
        return stats.norm()

    def tests(self) -> list[dict[str, Any]]:
        """One dict per parameter: estimate, sd, t, p-value, significant, determinable, largest correlations."""
        dist = self._test_dist()
        corr = self.correlation
        photos = self.bundle.photo_ids
        eo_names = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
        out = []
        for i, name in enumerate(self.names):
            est, sd = float(self.estimates[i]), float(self.sd[i])
            t = est / sd if sd > 0 else math.nan
            p = float(2 * dist.sf(abs(t))) if math.isfinite(t) else math.nan
            ce = self.eo_correlation[i]
            a = np.unravel_index(int(np.nanargmax(np.abs(ce))), ce.shape) if ce.size else None
            others = [(j, corr[i, j]) for j in range(len(self.names)) if j != i]
            best = max(others, key=lambda jc: abs(jc[1])) if others else None
            r_eo = float(ce[a]) if a is not None else math.nan
            r_ap = float(best[1]) if best else math.nan
            worst = max((abs(v) for v in (r_eo, r_ap) if math.isfinite(v)), default=0.0)
            out.append({
                "name": name, "unit": self.units[i], "group": self.groups[i],
                "estimate": est, "sd": sd, "t": t, "p_value": p,
                "significant": bool(math.isfinite(p) and p < self.alpha),
                "prior_sd": float(self.prior_sd[i]) if np.isfinite(self.prior_sd[i]) else None,
                **({"calibrated": self.calibrated[name], "value": self.calibrated[name] + est}
                   if name in self.calibrated else {}),
                "max_correlation_eo": {"photo": str(photos[a[0]]), "parameter": eo_names[a[1]], "r": r_eo}
                if a is not None else None,
                "max_correlation_additional": {"parameter": self.names[best[0]], "r": r_ap} if best else None,
                "determinable": bool(worst <= self.determinability_limit),
            })
            if not out[-1]["determinable"]:
                eo_worse = a is not None and abs(r_eo) >= (abs(r_ap) if math.isfinite(r_ap) else 0.0)
                out[-1]["why"] = self.why(name, eo_names[a[1]] if eo_worse else self.names[best[0]], eo_worse)
        return out

    def group_tests(self) -> list[dict[str, Any]]:
        """Joint test per group (camera, frame offset, GNSS line): theta' Sigma^-1 theta against chi^2(m)
        (a priori variance factor) or F(m, dof) (a posteriori)."""
        from scipy import stats
        out = []
        for g in dict.fromkeys(self.groups):
            idx = np.array([i for i, x in enumerate(self.groups) if x == g])
            th = self.estimates[idx]
            C = self.cov[np.ix_(idx, idx)]
            q = float(th @ np.linalg.solve(C, th))
            m = len(idx)
            if self.bundle.variance_factor_kind == "a_posteriori" and self.bundle.dof > 0:
                stat, dist, kind = q / m, stats.f(m, self.bundle.dof), "F"
            else:
                stat, dist, kind = q, stats.chi2(m), "chi2"
            p = float(dist.sf(stat))
            out.append({"group": g, "parameters": [self.names[i] for i in idx], "test": kind,
                        "statistic": stat, "dof": m, "p_value": p, "significant": bool(p < self.alpha)})
        return out

    def warnings(self) -> list[str]:
        """One message per parameter that the block cannot determine (|correlation| above the limit,
        or singular normal equations)."""
        out = [f"{self.singular}; the values written are those of the last iteration, without "
               "precision"] if self.singular else []
        out += list(self.notes)
        for t in self.tests():
            if not t["determinable"]:
                e, a = t["max_correlation_eo"], t["max_correlation_additional"]
                parts = []
                if e and abs(e["r"]) > self.determinability_limit:
                    parts.append(f"{e['parameter']} of photo {e['photo']} (r = {e['r']:+.3f})")
                if a and abs(a["r"]) > self.determinability_limit:
                    parts.append(f"{a['parameter']} (r = {a['r']:+.3f})")
                out.append(f"additional parameter {t['name']!r} is not determinable from this block: "
                           f"correlated with {' and '.join(parts)}; its estimate "
                           f"{t['estimate']:.4g} +- {t['sd']:.2g} {t['unit']} mostly trades against "
                           f"that parameter (fix it, give it a prior sd, or add geometry). Why: {t['why']}")
        return out

    def frame_offset_summary(self) -> list[dict[str, Any]]:
        """One dict per frame offset: source, reference, shift_m [E, N, h], sd_m, t, significant,
        joint test, correlation matrix of its parameters."""
        out = []
        for fo in self.frame_offsets:
            tag = f"frame.{fo.source}:{fo.reference}."
            idx = [i for i, n in enumerate(self.names) if n.startswith(tag)]
            tests = [t for t in self.tests() if t["name"].startswith(tag)]
            g = [t for t in self.group_tests() if t["parameters"][0].startswith(tag)][0]
            corr = self.correlation[np.ix_(idx, idx)]
            d = {"source": fo.source, "reference": fo.reference,
                 "parameters": [n[len(tag):] for n in (self.names[i] for i in idx)],
                 "shift_m": [t["estimate"] for t in tests[:3]],
                 "sd_m": [t["sd"] for t in tests[:3]],
                 "t": [t["t"] for t in tests[:3]],
                 "significant": bool(g["significant"]),
                 "significant_per_axis": [t["significant"] for t in tests[:3]],
                 "test": {k: g[k] for k in ("test", "statistic", "dof", "p_value")},
                 "alpha": self.alpha,
                 "correlation": corr.tolist(),
                 "n_control_source": int(len(fo.rows))}
            if fo.similarity:
                d["scale_ppm"] = {"estimate": tests[3]["estimate"], "sd": tests[3]["sd"]}
                d["rotation_urad"] = {"estimate": [t["estimate"] for t in tests[4:]],
                                      "sd": [t["sd"] for t in tests[4:]]}
            out.append(d)
        return out

    def summary(self) -> dict[str, Any]:
        """The keys this adds to ``summary.json``: ``additional_parameters``, ``frame_offset``,
        ``parameter_groups``, ``parameters_off`` and ``warnings``."""
        tests = [t for t in self.tests() if not t["name"].startswith("frame.")]
        w = self.without
        fo = self.frame_offset_summary()
        return {
            "additional_parameters": {t.pop("name"): t for t in tests},
            "frame_offset": (fo[0] if len(fo) == 1 else fo) if fo else None,
            "parameter_groups": self.group_tests(),
            "parameters_off": {"vtpv": float(w.vtpv), "dof": int(w.dof), "sigma0_sq": float(w.sigma0_sq),
                               "rms_image_residuals_mm": _rms_xy(w.residuals_mm),
                               "rms_control_residuals_m": _rms_con(w)},
            "parameters_on": {"vtpv": float(self.bundle.vtpv), "dof": int(self.bundle.dof),
                              "sigma0_sq": float(self.bundle.sigma0_sq),
                              "rms_image_residuals_mm": _rms_xy(self.bundle.residuals_mm),
                              "rms_control_residuals_m": _rms_con(self.bundle)},
            "warnings": self.warnings(),
        }


def _rms_xy(r: np.ndarray) -> dict[str, float]:
    return {"x": float(np.sqrt(np.mean(r[:, 0] ** 2))), "y": float(np.sqrt(np.mean(r[:, 1] ** 2)))}


def _rms_con(res: BundleResult) -> dict[str, float]:
    fin = np.isfinite(res.problem.constraint_sd_m)
    r = res.constraint_residuals_m
    return {a: float(np.sqrt(np.mean(r[fin[:, k], k] ** 2))) if fin[:, k].any() else math.nan
            for k, a in enumerate("ENh")}


# ---------------------------------------------------------------------------
# the adjustment
# ---------------------------------------------------------------------------


@heap_reuse()
@pinned()
def adjust_with_parameters(
    problem: BundleProblem,
    components: Sequence[Any],
    *,
    without: BundleResult | None = None,
    max_iter: int = 30,
    tol_m: float = 1e-4,
    tol_rad: float = 1e-8,
    tol_vtpv: float = 1e-8,
    variance_factor: str = "a_priori",
    chi2_level: float = 0.05,
    alpha: float = 0.05,
    determinability_limit: float = 0.95,
    precision: str = "all",
) -> SelfCalResult:
    """Bundle adjustment with additional parameters (self-calibration, frame offsets, GNSS lines).

    Parameters
    ----------
    problem : BundleProblem
    components : sequence
        :class:`~lidarcat.bundle.SelfCalibration`, :class:`~lidarcat.bundle.FrameOffset`,
        :class:`~lidarcat.bundle.GnssLineOffsets` (any mix; each parameter once).
    without : BundleResult, optional
        The adjustment without them (computed when not given); the iteration starts there.
    max_iter, tol_m, tol_rad, tol_vtpv, variance_factor, chi2_level
        As :func:`lidarcat.bundle.adjust`.
    alpha : float
        Level of the t-tests and group tests of the parameters.
    determinability_limit : float
        A parameter whose largest |correlation| with an exterior-orientation
        parameter or another additional parameter exceeds this is reported not
        determinable (a logged warning naming it; the result is still returned).
    precision : {"all", "photos", "none"}
        Covariance blocks of photos and points, as :func:`lidarcat.bundle.adjust`.

    Returns
    -------
    SelfCalResult

    Raises
    ------
    AdditionalParameterError
        A component that cannot be set up (named).
    DatumError
        From the datum check of the ordinary adjustment.
    """
    if not 0 < alpha < 1:
        raise ValueError("`alpha` must be in (0, 1)")
    t0 = time.perf_counter()
    gl = _Globals(components, problem)
    if without is None:
        without = adjust(problem, variance_factor=variance_factor, chi2_level=chi2_level, precision="none")
    eo, pts = np.array(without.eo_params, dtype=float), np.array(without.points_m, dtype=float)
    theta = np.zeros(gl.k)
    schur = Schur(problem.photo_index, problem.point_index, problem.n_photos, problem.n_points, coords=eo[:, :3])
    lam = 1e-6
    status, n_iter, history = "max_iterations", 0, []
    message_extra = singular = ""
    bs = None
    try:
        bs = _BorderedSystem(gl, eo, pts, theta, schur)
        cost = bs.vtpv
        history.append(cost)
        while n_iter < max_iter:
            n_iter += 1
            while True:
                dc, dp, dg = bs.solve(lam)
                eo_n, pts_n, th_n = eo + dc, pts + dp, theta + dg
                new = weighted_cost(gl.effective(th_n), eo_n, pts_n) + gl.prior_cost(th_n)
                if new <= cost * (1 + 1e-12) or step_below_tolerance(dc, dp, tol_m, tol_rad):
                    break
                lam = max(lam, 1e-6) * 10.0
                if lam > 1e12:
                    status = "stalled"
                    break
            if status == "stalled":
                break
            small = step_below_tolerance(dc, dp, tol_m, tol_rad)
            dcost = abs(cost - new) / max(cost, 1.0)
            eo, pts, theta, cost = eo_n, pts_n, th_n, new
            eo[:, 3:] = (eo[:, 3:] + np.pi) % (2 * np.pi) - np.pi
            history.append(cost)
            lam = lam / 10.0 if lam > 1e-12 else 0.0
            bs = _BorderedSystem(gl, eo, pts, theta, schur)
            log.debug("additional parameters: iteration %d, v'Pv %.6g", n_iter, cost)
            if small and dcost < tol_vtpv:
                status = "converged"
                break
        beta = _score_bias(gl, theta, bs) if status == "converged" else None
        if beta is not None:                       # errors in variables: remove the bias of the estimate
            eo, pts, theta = _bias_corrected(bs, beta, eo, pts, theta)
            bs = _BorderedSystem(gl, eo, pts, theta, schur)
            history.append(bs.vtpv)
        _, _, _, (X, H, T, vinv) = bs.solve(0.0, want_cov=True)
        eo_cov, point_cov = covariance_blocks(bs.sys, precision if precision != "none" else "photos")
    except SingularSystem as ex:
        status = "singular"
        log.warning("adjustment with additional parameters: %s", ex)
        message_extra, singular = f": {ex}", str(ex)
        if bs is None:
            raise DatumError(f"adjustment with additional parameters: {ex}") from ex
        k = gl.k
        X, H = np.full((problem.n_photos, 6, k), np.nan), np.full((k, k), np.nan)
        eo_cov = np.full((problem.n_photos, 6, 6), np.nan)
        point_cov = np.full((problem.n_points, 3, 3), np.nan)
        T, vinv = None, None

    pe, sys = bs.pe, bs.sys
    # rank-k corrections of the photo and point blocks (module docstring)
    eo_cov = eo_cov + np.einsum("pik,kl,pjl->pij", X, H, X)
    u = None
    if T is not None and precision == "all":
        ei, pj = pe.photo_index, pe.point_index
        u = -np.einsum("qik,qij->qkj", bs.Npg, vinv)                         # (Q, k, 3)
        chunk = max(1024, _CHUNK_VALUES // max(6 * gl.k, 1))
        for c0 in range(0, len(ei), chunk):
            sl = slice(c0, c0 + chunk)
            u += block_sum(pj[sl], np.einsum("nik,nij->nkj", X[ei[sl]], T[sl]), pe.n_points)
        point_cov = point_cov + np.einsum("qkj,kl,qlm->qjm", u, H, u)
    elif precision != "all":
        point_cov = np.full((problem.n_points, 3, 3), np.nan)
    dof = problem.dof - gl.k + int(np.isfinite(gl.prior_sd).sum())
    vtpv = bs.vtpv
    sigma0_sq = vtpv / dof if dof > 0 else math.nan
    factor = 1.0 if variance_factor == "a_priori" else sigma0_sq
    bounds = chi2_bounds(dof, chi2_level)
    chi2 = {"statistic": vtpv, "level": chi2_level, **bounds,
            "passed": bool(dof > 0 and bounds["lower"] <= vtpv <= bounds["upper"])}
    msg = STATUS_MESSAGES[status] + message_extra + (f" after {n_iter} iteration(s)" if status == "converged"
                                                      else "")
    info = dict(problem.info)
    info["additional_parameters_on"] = list(gl.names)
    pe = dataclasses.replace(pe, info=info)
    result = BundleResult(
        status=status, message=msg, success=status == "converged", n_iter=n_iter, vtpv=vtpv, dof=dof,
        sigma0_sq=sigma0_sq, variance_factor=factor, variance_factor_kind=variance_factor, chi2=chi2,
        photo_ids=pe.photo_ids, eo_params=eo, eo_cov=eo_cov * factor, point_ids=pe.point_ids, points_m=pts,
        point_cov=point_cov * factor, point_role=pe.point_role, residuals_mm=sys.r_obs,
        constraint_residuals_m=sys.r_con, eo_constraint_residuals=sys.r_eo, history=tuple(history),
        problem=pe, initial_eo=np.asarray(without.eo_params), initial_points_m=np.asarray(without.points_m),
        elapsed_s=time.perf_counter() - t0, precision=precision)
    # correlations with the exterior orientation: Cov(c_i, g) = -X_i H
    cov_g = H * factor
    sd_g = np.sqrt(np.clip(np.diag(cov_g), 0, None))
    sd_c = np.sqrt(np.clip(np.diagonal(eo_cov * factor, axis1=1, axis2=2), 0, None))       # (P, 6)
    with np.errstate(invalid="ignore", divide="ignore"):
        eo_corr = -np.einsum("pik,kl->lpi", X, H) * factor / sd_g[:, None, None] / sd_c[None]
    calibrated = {}
    for b in gl.parts:
        if hasattr(b, "calibrated"):
            calibrated.update(dict(zip(b.names, (float(v) for v in b.calibrated))))
    from .frame_offset import FrameOffset
    out = SelfCalResult(
        bundle=result, without=without, names=tuple(gl.names), units=tuple(gl.units), groups=tuple(gl.groups),
        estimates=theta, cov=cov_g, prior_sd=gl.prior_sd, calibrated=calibrated,
        eo_correlation=np.nan_to_num(eo_corr), point_coupling=u, singular=singular, alpha=alpha,
        determinability_limit=determinability_limit,
        explainers=tuple(b.explain for b in gl.parts if hasattr(b, "explain")),
        notes=tuple(dict.fromkeys(n for b in gl.parts for n in getattr(b, "notes", ()))),
        frame_offsets=tuple(c for c in components if isinstance(c, FrameOffset)))
    for w in out.warnings():
        log.warning(w)
    return out
