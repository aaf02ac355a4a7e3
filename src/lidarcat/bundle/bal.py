r"""The Bundle Adjustment in the Large (BAL) camera model over the same solver core.

BAL problems (Agarwal, Snavely, Seitz and Szeliski, *Bundle Adjustment in the
Large*, ECCV 2010; https://grail.cs.washington.edu/projects/bal/) give 9
parameters per camera, all free: a Rodrigues rotation vector r, a translation t,
a focal length f and two radial distortion coefficients k1, k2.  A point X
projects as

    P = R(r) X + t,      p = -P_xy / P_z,      s = p . p,
    x = f (1 + k1 s + k2 s^2) p                 (pixels, origin at the centre)

and the cost is ``0.5 sum |x - x_obs|^2`` (what Ceres reports).

Jacobians (analytic).  With ``d = 1 + k1 s + k2 s^2``:
``dx/dp = f (d I + 2 (k1 + 2 k2 s) p p^T)``,
``dp/dP = -[[1/P_z, 0, -P_x/P_z^2], [0, 1/P_z, -P_y/P_z^2]]``,
``dP/dX = R``, ``dP/dt = I``, and for the additive rotation vector
``dP/dr = -R [X]_x J_r(r)`` with the right Jacobian of SO(3)
``J_r(r) = I - (1 - cos a)/a^2 [r]_x + (a - sin a)/a^3 [r]_x^2`` (a = |r|);
``dx/df = d p``, ``dx/dk1 = f s p``, ``dx/dk2 = f s^2 p``.

Solver.  The normal-equation blocks (9 x 9 per camera, 3 x 3 per point, 9 x 3 per
observation) go to the reduced camera system of :mod:`.linear` (camera size 9,
supernodal Cholesky); the step control is Ceres's Levenberg-Marquardt trust
region: ``(N + D / radius) delta = -g`` with ``D = diag(N)`` clamped to
[1e-6, 1e32], the gain ratio ``rho`` of actual to predicted decrease, radius
``/= max(1/3, 1 - (2 rho - 1)^3)`` after a success, halved (then quartered, ...)
after a failure; stop when the cost changes by less than ``function_tolerance``
(relative), as Ceres does.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from .._util import read_text
from ..errors import LidarcatError
from ._blas import pinned
from ._heap import heap_reuse
from .linear import Gram, Schur, SingularSystem

__all__ = ["BalProblem", "BalResult", "read_bal", "solve_bal", "bal_project"]


class BalFormatError(LidarcatError, ValueError):
    """A BAL file that cannot be read (file and line named)."""


@dataclasses.dataclass(frozen=True, eq=False)
class BalProblem:
    """A BAL problem.

    Attributes
    ----------
    camera_index, point_index : (n,) int
    observations_px : (n, 2) float
        Observed image coordinates (pixels, origin at the image centre).
    cameras : (C, 9) float
        Initial r (rad, Rodrigues), t, f (px), k1, k2.
    points : (Q, 3) float
        Initial points.
    """

    camera_index: np.ndarray
    point_index: np.ndarray
    observations_px: np.ndarray
    cameras: np.ndarray
    points: np.ndarray

    @property
    def n_cameras(self) -> int:
        return len(self.cameras)

    @property
    def n_points(self) -> int:
        return len(self.points)


def read_bal(path) -> BalProblem:
    """Read a BAL text file (``problem-*.txt``).

    Raises
    ------
    BalFormatError
        A missing or unreadable file, a short file, a negative count, a value that is not a finite number, or
        indices out of range (file and line named).
    """
    path = Path(path)
    text = read_text(path, error=BalFormatError)
    lines = text.split("\n", 1)
    try:
        n_cam, n_pt, n_obs = (int(v) for v in lines[0].split())
        if min(n_cam, n_pt, n_obs) < 0:
            raise ValueError("negative count")
    except ValueError as ex:
        raise BalFormatError(f"{path}:1: expected 'cameras points observations', got {lines[0][:60]!r}") from ex
    body = lines[1] if len(lines) > 1 else ""
    tokens = body.split()
    try:
        vals = np.array(tokens, dtype=float)
        bad = np.flatnonzero(~np.isfinite(vals))
    except ValueError:
        bad = [next(k for k, v in enumerate(tokens) if not _finite(v))]
    if len(bad):
        line, token = _locate_token(body, int(bad[0]))
        raise BalFormatError(f"{path}:{line + 2}: {token!r} is not a finite number")
    need = 4 * n_obs + 9 * n_cam + 3 * n_pt
    if len(vals) < need:
        raise BalFormatError(f"{path}: {len(vals)} values after line 1, the header announces {need}")
    obs = vals[:4 * n_obs].reshape(n_obs, 4)
    cam_i, pt_i = obs[:, 0].astype(np.int64), obs[:, 1].astype(np.int64)
    for idx, n, what in ((cam_i, n_cam, "camera"), (pt_i, n_pt, "point")):
        bad = np.flatnonzero((idx < 0) | (idx >= n))
        if len(bad):
            raise BalFormatError(f"{path}:{bad[0] + 2}: {what} index {idx[bad[0]]} out of range (there are {n})")
    cams = vals[4 * n_obs:4 * n_obs + 9 * n_cam].reshape(n_cam, 9)
    pts = vals[4 * n_obs + 9 * n_cam:need].reshape(n_pt, 3)
    return BalProblem(cam_i, pt_i, obs[:, 2:4].copy(), cams, pts)


def _finite(token: str) -> bool:
    """True for a token that parses as a finite float."""
    try:
        return math.isfinite(float(token))
    except ValueError:
        return False


def _locate_token(body: str, k: int) -> tuple[int, str]:
    """(0-based line of *body*, text) of its k-th whitespace-separated token (error path only)."""
    for i, line in enumerate(body.split("\n")):
        words = line.split()
        if k < len(words):
            return i, words[k]
        k -= len(words)
    raise IndexError(k)


def _rodrigues(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrices R(r) (m, 3, 3) and right Jacobians J_r(r) (m, 3, 3)."""
    a = np.linalg.norm(r, axis=1)
    small = a < 1e-8
    a_ = np.where(small, 1.0, a)
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    K2 = K @ K
    s1 = np.where(small, 1.0, np.sin(a_) / a_)
    c1 = np.where(small, 0.5, (1 - np.cos(a_)) / a_**2)
    c2 = np.where(small, 1.0 / 6.0, (a_ - np.sin(a_)) / a_**3)
    eye = np.eye(3)[None]
    R = eye + s1[:, None, None] * K + c1[:, None, None] * K2
    J = eye - c1[:, None, None] * K + c2[:, None, None] * K2
    return R, J


def bal_project(cameras: np.ndarray, points: np.ndarray, cam_i: np.ndarray, pt_i: np.ndarray,
                jacobians: bool = False):
    """Predicted pixels (n, 2); with *jacobians* also d/dcamera (n, 2, 9) and d/dpoint (n, 2, 3).

    Vectorised with two batched 3 x 3 products per observation: with ``A = dx/dP``
    (2 x 3, closed form: ``dp/dP = -(1/P_z) [I_2 | p]``), ``dx/dX = A R`` and, from
    ``R [X]_x = [R X]_x R``, ``dx/dr = -A [R X]_x (R J_r)`` -- the rows of
    ``A [y]_x`` are ``a_k x y`` (cross products) and ``R J_r`` is one 3 x 3 per camera.
    """
    R, J = _rodrigues(cameras[:, :3])
    # per-camera quantities as rows (structure of arrays): R, R J_r, t, f, k1, k2 -> (24, n)
    per_cam = np.concatenate([R.reshape(-1, 9), (R @ J).reshape(-1, 9), cameras[:, 3:9]], axis=1).T
    rows = np.take(per_cam, cam_i, axis=1)
    Rr, RJ = rows[0:9].reshape(3, 3, -1), rows[9:18].reshape(3, 3, -1)
    f, k1, k2 = rows[21], rows[22], rows[23]
    X = np.take(points.T, pt_i, axis=1)                        # (3, n)
    RX = Rr[:, 0] * X[0] + Rr[:, 1] * X[1] + Rr[:, 2] * X[2]   # (3, n)
    P = RX + rows[18:21]
    inv_z = 1.0 / P[2]
    p = -P[:2] * inv_z
    s = p[0] * p[0] + p[1] * p[1]
    d = 1 + k1 * s + k2 * s * s
    fd = f * d
    n = len(cam_i)
    x = np.empty((n, 2))
    x[:, 0] = fd * p[0]
    x[:, 1] = fd * p[1]
    if not jacobians:
        return x
    # dx/dp = f d I + e p p^T (e = 2 f (k1 + 2 k2 s));  A = dx/dp dp/dP = -(1/z) [dx/dp | dx/dp p]
    e = 2 * f * (k1 + 2 * k2 * s)
    ez = -e * inv_z
    fz = fd * inv_z
    A = np.empty((2, 3, n))                                    # A[k, l]: row k, column l
    A[0, 0] = ez * p[0] * p[0] - fz
    A[0, 1] = ez * p[0] * p[1]
    A[1, 0] = A[0, 1]
    A[1, 1] = ez * p[1] * p[1] - fz
    A[:, 2] = (-(fd + e * s) * inv_z) * p
    jc = np.empty((n, 2, 9))
    jp = np.empty((n, 2, 3))
    for k in range(2):
        a = A[k]
        # dx_k/dX = a R;  dx_k/dr = -(a x RX) R J_r
        jp[:, k] = (a[0] * Rr[0] + a[1] * Rr[1] + a[2] * Rr[2]).T
        b = (a[1] * RX[2] - a[2] * RX[1], a[2] * RX[0] - a[0] * RX[2], a[0] * RX[1] - a[1] * RX[0])
        jc[:, k, 0:3] = (-(b[0] * RJ[0] + b[1] * RJ[1] + b[2] * RJ[2])).T
        jc[:, k, 3:6] = a.T
        jc[:, k, 6] = d * p[k]
        jc[:, k, 7] = f * s * p[k]
        jc[:, k, 8] = f * s * s * p[k]
    return x, jc, jp


@dataclasses.dataclass(frozen=True, eq=False)
class BalResult:
    """Outcome of :func:`solve_bal`: ``final_cost`` = 0.5 sum r^2 (px^2), ``initial_cost``,
    ``iterations`` (accepted + rejected steps, as Ceres counts), ``seconds``, the
    adjusted ``cameras`` (C, 9) and ``points`` (Q, 3), ``status``."""

    final_cost: float
    initial_cost: float
    iterations: int
    seconds: float
    cameras: np.ndarray
    points: np.ndarray
    status: str


@heap_reuse()
@pinned()
def solve_bal(problem: BalProblem, *, max_iter: int = 50, function_tolerance: float = 1e-6,
              initial_radius: float = 1e4) -> BalResult:
    """Levenberg-Marquardt on a BAL problem (see the module docstring).

    Parameters
    ----------
    problem : BalProblem
    max_iter : int
        Maximum number of steps (accepted or rejected).
    function_tolerance : float
        Stop when an accepted step changes the cost by less than this (relative).
    initial_radius : float
        Initial trust-region radius (Ceres's default 1e4).
    """
    t0 = time.perf_counter()
    p = problem
    ci, pj = p.camera_index, p.point_index
    cams, pts = p.cameras.astype(float).copy(), p.points.astype(float).copy()
    R, _ = _rodrigues(cams[:, :3])
    centres = -np.einsum("cji,cj->ci", R, cams[:, 3:6])          # C = -R^T t: ordering by position
    schur = Schur(ci, pj, p.n_cameras, p.n_points, camera_size=9, coords=centres)

    gram_by_point = Gram(pj, p.n_points)

    def linearise(c, x):
        pred, jc, jp = bal_project(c, x, ci, pj, jacobians=True)
        r = pred - p.observations_px
        U = schur.gram_by_camera(jc)                             # sum jc' jc per camera
        V = gram_by_point(jp)
        W = np.transpose(np.matmul(np.transpose(jp, (0, 2, 1)), jc), (0, 2, 1))   # view of W^T
        g_c = schur.by_camera(np.einsum("nki,nk->ni", jc, r))
        g_p = schur.by_point(np.einsum("nki,nk->ni", jp, r))
        return 0.5 * float(np.sum(r * r)), U, V, W, g_c, g_p

    def cost_at(c, x):
        r = bal_project(c, x, ci, pj) - p.observations_px
        val = 0.5 * float(np.sum(r * r))
        return val if math.isfinite(val) else math.inf

    cost, U, V, W, g_c, g_p = linearise(cams, pts)
    initial = cost
    radius, nu = initial_radius, 2.0
    status = "max_iterations"
    it = 0
    iu, iv = np.arange(9), np.arange(3)
    while it < max_iter:
        it += 1
        dU = np.clip(U[:, iu, iu], 1e-6, 1e32)
        dV = np.clip(V[:, iv, iv], 1e-6, 1e32)
        Ud, Vd = U.copy(), V.copy()
        Ud[:, iu, iu] += dU / radius
        Vd[:, iv, iv] += dV / radius
        try:
            dc, dp = schur.solve(Ud, Vd, W, g_c, g_p)
        except SingularSystem:
            radius /= nu
            nu *= 2
            continue
        new_cost = cost_at(cams + dc, pts + dp)
        # predicted decrease of the quadratic model: -g'd/2 + d'(D/radius)d/2
        pred = 0.5 * (-(np.sum(g_c * dc) + np.sum(g_p * dp))
                      + np.sum(dU / radius * dc * dc) + np.sum(dV / radius * dp * dp))
        rho = (cost - new_cost) / pred if pred > 0 else -1.0
        if rho > 1e-3 and math.isfinite(new_cost):
            cams, pts = cams + dc, pts + dp
            change = (cost - new_cost) / cost
            radius = min(radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), 1e16)
            nu = 2.0
            cost, U, V, W, g_c, g_p = linearise(cams, pts)
            if change < function_tolerance:
                status = "converged"
                break
        else:
            radius /= nu
            nu *= 2.0
            if radius < 1e-32:
                status = "stalled"
                break
    return BalResult(final_cost=cost, initial_cost=initial, iterations=it, seconds=time.perf_counter() - t0,
                     cameras=cams, points=pts, status=status)
