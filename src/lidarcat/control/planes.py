r"""Roof planes: :class:`Plane` (unit normal, offset, covariance) and its fit (thesis eq. 33-37).

**Plane fit by the combined (Gauss-Helmert) adjustment** (eq. 33-37).  The
condition of point *i* is :math:`n \cdot (x_i + v_i) + d = 0` with
:math:`\|n\| = 1`; the observations :math:`x_i = (E, N, h)` carry their
own covariance :math:`\Sigma_i = \mathrm{diag}(s_E^2, s_N^2, s_h^2)`.
Linearised: :math:`A\,\delta + B\,v + w = 0` with
:math:`A_i = ((x_i + v_i)^T, 1)` at the adjusted observations (Pope 1972),
:math:`B_i = n^T`, :math:`w_i = n\cdot x_i + d`;
the equivalent weight of a condition is
:math:`1 / (n^T \Sigma_i n)`.  The normal equations are bordered by the
constraint :math:`n^T \delta n = 0`; the inverse of the bordered matrix
gives the 4x4 cofactor matrix of :math:`(n, d)`, scaled by the a-posteriori
variance factor :math:`\hat\sigma_0^2 = \sum w_i r_i^2 / (m - 3)` times
:math:`f / (f - 2)`, f = m - 3 (the standardised error is t-distributed).
The residuals are :math:`v_i = -\Sigma_i n\, w_i r_i`.

**Correlated residuals** (``cells_m``; the extraction's default ``(1, 3)`` m).
On real roofs the residuals are not independent: neighbouring points share
the tiles, the moss and the scan line they lie on, and a face is not a plane
at the 1-3 cm level.  On the AHN3 tiles the mean of ``n_cell x (cell mean
residual)^2`` over the residual variance (the design effect, ~1 for
independent residuals) is a median 1.62 for 1 m cells (docs/extraction.md), so
:math:`\hat\sigma_0^2 Q` is too small, and the vertex of a smaller clip (part of
the same faces) moves by several of its sds.  The model: the condition errors

.. math:: \varepsilon = e + \sum_k Z_k u_k,\qquad
          \mathrm{Cov}(e) = \sigma_0^2 W^{-1},\quad \mathrm{Cov}(u_k) = \tau_k^2 I

with :math:`Z_k` the indicator matrix of the points in the cells of a fixed
grid of size :math:`c_k` (``floor((E, N) / c_k)`` of the outer frame, so the
same cells in every clip): an iid part plus one random offset per cell and
scale -- 1 m for the correlation of neighbouring points, 3 m for the face's own
departure from a plane at a larger scale (the largest cell that still leaves
several cells on a face of an 8 m clip, so that its variance can be estimated
from the face itself).  The estimate is linear in the errors,
:math:`\delta\theta = -Q A^T W \varepsilon` (Q the 4x4 block of the bordered
inverse, which satisfies :math:`Q N Q = Q`), so

.. math:: \Sigma_\theta = \sigma_0^2 Q + \sum_k \tau_k^2\, Q F_k F_k^T Q,
          \qquad F_k = A^T W Z_k

(:math:`F_k` has one column per cell: the sum of :math:`w_i a_i` over its
points).  **The components are estimated from the face's residuals** by the
method of moments (MINQUE-like, exact for the fit's leverage): with the
whitened residuals :math:`\tilde r = R \tilde\varepsilon`,
:math:`R = I - \tilde A Q \tilde A^T` (a projection of rank m - 3),
:math:`\tilde Z_k = W^{1/2} Z_k` and :math:`\tilde Z_0 = I`, the statistics
:math:`T_0 = \sum w_i r_i^2` and :math:`T_k = \sum_{cells} (\sum_{i \in cell} w_i r_i)^2 = \|\tilde Z_k^T \tilde r\|^2`
have the expectations

.. math:: E[T_k] = \sum_j \vartheta_j\, \|\tilde Z_k^T R \tilde Z_j\|_F^2,
          \qquad \vartheta = (\sigma_0^2, \tau_1^2, \dots)

(:math:`\|R\|_F^2 = m - 3`; :math:`\|R \tilde Z_k\|_F^2 = \sum w_i - \mathrm{tr}(F_k^T Q F_k)`;
:math:`\tilde Z_k^T R \tilde Z_j = \tilde Z_k^T \tilde Z_j - F_k^T Q F_j`, all
small cell-by-cell matrices), a linear system solved for
:math:`\vartheta \ge 0` (NNLS).  **Consistency for independent points**: a
component is estimated only when its statistic shows it, i.e. when
:math:`T_k` exceeds its expectation under independence,
:math:`\hat\sigma_0^2 \|R \tilde Z_k\|_F^2`, by more than ``Z_KEEP`` = 2 of its
standard deviations :math:`\hat\sigma_0^2 \sqrt{2 \|\tilde Z_k^T R \tilde Z_k\|_F^2}`
(a Gaussian quadratic form); otherwise :math:`\tau_k^2 = 0` and the covariance
is exactly :math:`\hat\sigma_0^2 Q` as before.  Each term is multiplied by the
t factor f / (f - 2) of its own redundancy (below: m - 3 for
:math:`\sigma_0^2`, the number of cells minus 3 for :math:`\tau_k^2`): a face of
a few 3 m cells estimates its large-scale variance from few values.  Without that test the clipped
noise of :math:`\hat\tau_k^2` inflated the sds of independent points (a
30-point face: normalised errors' sd 0.87 instead of 1.0); with it, 1.01 (300
simulated faces), and 1.02-1.07 for faces with 1 m or 3 m cell offsets of 2 cm
over 3 cm noise, where :math:`\hat\sigma_0^2 Q` gives 1.38 and 3.13
(tests/control/test_plane_covariance.py).

**Iterative rejection**: points whose residual exceeds the threshold are
removed and the plane refitted, until none remains (thesis: 0.15 m on the
height residual; the thesis preset tests the vertical distance to the
plane, see :func:`fit_plane`).

Coordinates are reduced to the centroid of the points internally, so national grid
coordinates (E ~ 7e6 m) lose no precision; :func:`translated` moves a plane and its
covariance back to the outer frame.

**Table 4 normalisation.**  The thesis prints (a, b, c, d) with
:math:`\|(a,b,c)\| \approx 0.72-0.74` and d ~ 3e5-9e5.  The printed standard
deviations satisfy :math:`s_b / s_a = E/N` of point 708 to three digits for all
three planes and :math:`s_d \approx 10^{-11}`: d was *held fixed* (the datum of
the homogeneous plane equation was fixed on d, its value coming from the
approximate plane of a seed Delaunay triangle, whose
:math:`\|(a,b,c)\|` is twice the triangle area, ~0.36 m^2 at the 1-2 pts/m^2
of the survey).  :meth:`Plane.thesis_form` reproduces that layout for any
chosen d.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._util.frozen import frozen_array

__all__ = ["t_factor", "Plane", "PlaneFit", "fit_plane", "translated"]


@dataclass(frozen=True, eq=False)
class Plane:
    """A fitted roof plane :math:`n \\cdot x + d = 0` (metres, E N h).

    Parameters
    ----------
    n : (3,) float
        Unit normal, oriented upwards (``n[2] >= 0``).
    d : float
        Offset in metres.
    cov : (4, 4) float
        Covariance of ``(n_E, n_N, n_h, d)`` (absolute coordinates).
    centroid_m : (3,) float
        Centroid of the points used (E, N, h).
    n_used, n_rejected : int
        Points in the final fit and points removed by the residual test.
    rms_m : float
        RMS of the orthogonal point-to-plane distances of the points used.
    label : int
        Face number within its clip (for figures and the planes file).

    Examples
    --------
    >>> p = Plane(n=[0, 0, 1], d=-10.0, cov=np.eye(4) * 1e-6, centroid_m=[0, 0, 10])
    >>> round(p.slope_deg, 6), round(float(p.distance([[0, 0, 10.5]])[0]), 6)
    (0.0, 0.5)
    """

    n: np.ndarray
    d: float
    cov: np.ndarray
    centroid_m: np.ndarray
    n_used: int = 0
    n_rejected: int = 0
    rms_m: float = math.nan
    label: int = 0

    def __post_init__(self) -> None:
        n = np.asarray(self.n, dtype=np.float64).reshape(3)
        norm = float(np.linalg.norm(n))
        if not np.isfinite(norm) or norm == 0.0:
            raise ValueError("plane normal must be a finite non-zero vector")
        sign = -1.0 if n[2] < 0 else 1.0
        object.__setattr__(self, "n", frozen_array(sign * n / norm, shape=(3,)))
        object.__setattr__(self, "d", float(sign * self.d / norm))
        cov = np.asarray(self.cov, dtype=np.float64).reshape(4, 4)
        # a sign flip of (n, d) leaves the covariance unchanged
        object.__setattr__(self, "cov", frozen_array(cov / norm**2, shape=(4, 4)))
        object.__setattr__(self, "centroid_m", frozen_array(self.centroid_m, shape=(3,)))

    # ----------------------------------------------------------- geometry
    @property
    def slope_deg(self) -> float:
        """Angle between the plane and the horizontal, degrees (eq. 32)."""
        return float(np.degrees(np.arccos(np.clip(abs(self.n[2]), 0.0, 1.0))))

    @property
    def aspect_deg(self) -> float:
        """Direction the face looks to (down-slope), degrees clockwise from North."""
        if math.hypot(self.n[0], self.n[1]) < 1e-12:
            return math.nan
        return float(np.degrees(np.arctan2(self.n[0], self.n[1])) % 360.0)

    def distance(self, xyz: Any) -> np.ndarray:
        """Signed orthogonal distance (m) of points (N, 3) to the plane."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        return (xyz - self.centroid_m) @ self.n + self.offset_at(self.centroid_m)

    def height_at(self, e: Any, n: Any) -> np.ndarray:
        """Plane height (m) above given E, N (arrays broadcast)."""
        c = self.centroid_m
        d0 = self.offset_at(c)
        e = np.asarray(e, dtype=np.float64) - c[0]
        nn = np.asarray(n, dtype=np.float64) - c[1]
        return c[2] - (self.n[0] * e + self.n[1] * nn + d0) / self.n[2]

    def offset_at(self, origin: Any) -> float:
        """Offset of the plane in a frame whose origin is *origin* (3,)."""
        return float(self.d + self.n @ np.asarray(origin, dtype=np.float64))

    def cov_at(self, origin: Any) -> np.ndarray:
        """4x4 covariance of ``(n, d_o)`` with d in a frame centred at *origin*."""
        k = np.eye(4)
        k[3, :3] = np.asarray(origin, dtype=np.float64)
        return k @ self.cov @ k.T

    @property
    def sd_n(self) -> np.ndarray:
        """Standard deviations of the normal components (3,)."""
        return np.sqrt(np.maximum(np.diag(self.cov)[:3], 0.0))

    @property
    def sd_offset_m(self) -> float:
        """Standard deviation (m) of the plane position at its centroid."""
        return float(math.sqrt(max(self.cov_at(self.centroid_m)[3, 3], 0.0)))

    @property
    def sd_slope_deg(self) -> float:
        """Standard deviation of the slope, degrees (first-order)."""
        # slope = arccos(n_z), d slope / d n_z = -1 / sin(slope)
        s = math.sin(math.radians(self.slope_deg))
        if s < 1e-9:
            return math.nan
        return math.degrees(math.sqrt(max(self.cov[2, 2], 0.0)) / s)

    # ----------------------------------------------------------- thesis form
    def thesis_form(self, d: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Plane as printed in thesis Table 4: ``(a, b, c, d)`` with d held fixed.

        Parameters
        ----------
        d : float, optional
            The value d is fixed at (the datum of the homogeneous equation).
            Default: the unit-normal offset, i.e. (a, b, c) is the unit normal.

        Returns
        -------
        abcd : (4,) float
            Parameters with ``a E + b N + c h + d = 0``.
        sd : (4,) float
            Their standard deviations in that datum (``sd[3] == 0``: d fixed).
            With E, N of Brazilian UTM, ``sd_b / sd_a = E / N`` as in Table 4.
        """
        d_fix = self.d if d is None else float(d)
        if self.d == 0.0:
            raise ValueError("plane passes through the origin; d cannot be the datum")
        k = d_fix / self.d
        abcd = np.append(k * self.n, d_fix)
        # q = n / d is datum free; (a, b, c) = d_fix * q
        j = np.zeros((3, 4))
        j[:, :3] = np.eye(3) / self.d
        j[:, 3] = -self.n / self.d**2
        cov_q = j @ self.cov @ j.T
        sd = np.append(abs(d_fix) * np.sqrt(np.maximum(np.diag(cov_q), 0.0)), 0.0)
        return abcd, sd

    @classmethod
    def from_abcd(cls, abcd: Any, *, centroid_m: Any = None, cov: Any = None, **kw: Any) -> "Plane":
        """Plane from ``a E + b N + c h + d = 0`` (any scale, e.g. thesis Table 4)."""
        a = np.asarray(abcd, dtype=np.float64).reshape(4)
        norm = float(np.linalg.norm(a[:3]))
        n = a[:3] / norm
        d = a[3] / norm
        if centroid_m is None:
            centroid_m = -d * n  # foot of the perpendicular from the origin
        return cls(n=n, d=d, cov=np.zeros((4, 4)) if cov is None else cov,
                   centroid_m=centroid_m, **kw)

    def to_dict(self) -> dict[str, Any]:
        abcd, sd = self.thesis_form()
        return {
            "label": self.label, "a": abcd[0], "b": abcd[1], "c": abcd[2], "d": abcd[3],
            "sd_a": sd[0], "sd_b": sd[1], "sd_c": sd[2], "sd_offset_m": self.sd_offset_m,
            "n_used": self.n_used, "n_rejected": self.n_rejected, "rms_m": self.rms_m,
            "slope_deg": self.slope_deg, "aspect_deg": self.aspect_deg,
            "centroid_m": self.centroid_m,
        }


def translated(pl: Plane, shift_m: np.ndarray, **changes: Any) -> Plane:
    """*pl*, given in a frame whose origin is at *shift_m*, in the outer frame.

    ``x_out = x_in + shift``: ``d_out = d_in - n . shift`` and the covariance of
    ``(n, d)`` moves accordingly (:meth:`Plane.cov_at` at ``-shift``).
    """
    shift = np.asarray(shift_m, dtype=np.float64)
    return dataclasses.replace(pl, n=pl.n, d=pl.d - float(pl.n @ shift), cov=pl.cov_at(-shift),
                               centroid_m=pl.centroid_m + shift, **changes)


@dataclass(frozen=True, eq=False)
class PlaneFit:
    """Result of :func:`fit_plane`: the plane or a falsy failure with a reason."""

    plane: Plane | None
    used: np.ndarray  # bool (M,), points kept
    residual_m: np.ndarray  # (M,) tested residual (nan for never fitted)
    sigma0: float
    reason: str = ""
    #: variance components of the covariance: (sigma0^2, tau^2 (m^2) per cell size of ``cells_m``); empty
    #: when ``cells_m`` is empty (the covariance is then sigma0^2 Q)
    components: tuple = ()

    def __bool__(self) -> bool:
        return self.plane is not None


def _gh_solve(x: np.ndarray, s2: np.ndarray, n0: np.ndarray,
              max_iter: int = 30) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Gauss-Helmert iterations in a local frame. Returns n, d, Q (4x4), r, w.

    The design matrix A is evaluated at the *adjusted* observations
    ``x + v`` (Pope 1972); evaluating it at the raw observations biases the plane.
    """
    m = len(x)
    n = n0 / np.linalg.norm(n0)
    d = -float(x.mean(axis=0) @ n)
    v = np.zeros_like(x)

    def bordered(xa: np.ndarray, w: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a_mat = np.column_stack([xa, np.ones(m)])
        big = np.zeros((5, 5))
        big[:4, :4] = (a_mat * w[:, None]).T @ a_mat
        big[:3, 4] = n
        big[4, :3] = n
        return big, a_mat

    for _ in range(max_iter):
        q = s2 @ (n * n)
        w = 1.0 / q
        # misclosure f(X0, L0) + B (Lb - L0) = n . x_b + d
        wvec = x @ n + d
        big, a_mat = bordered(x + v, w, n)
        # A dx + B v + w = 0 with the linearisation point at x + v:
        # f(X0, L0) = n.(x + v) + d, B(Lb - L0) = -n.v  ->  misclosure = n.x + d
        rhs = np.append(-a_mat.T @ (w * wvec), 0.0)
        sol = np.linalg.solve(big, rhs)
        dn, dd = sol[:3], sol[3]
        n_new = n + dn
        norm = np.linalg.norm(n_new)
        n, d = n_new / norm, (d + dd) / norm
        r = x @ n + d
        q = s2 @ (n * n)
        v = -(s2 * n[None, :]) * (r / q)[:, None]
        if np.max(np.abs(dn)) < 1e-12 and abs(dd) < 1e-11:
            break
    r = x @ n + d
    q = s2 @ (n * n)
    w = 1.0 / q
    v = -(s2 * n[None, :]) * (r / q)[:, None]
    big, _ = bordered(x + v, w, n)
    qxx = np.linalg.inv(big)[:4, :4]
    return n, d, qxx, r, w


def _initial_normal(x: np.ndarray, s2: np.ndarray) -> np.ndarray:
    # generalised eigenproblem S n = lambda Sigma n (exact GH solution for equal sds)
    xc = x - x.mean(axis=0)
    scat = xc.T @ xc
    sig = np.diag(s2.mean(axis=0))
    isq = np.diag(1.0 / np.sqrt(np.diag(sig)))
    val, vec = np.linalg.eigh(isq @ scat @ isq)
    n = isq @ vec[:, 0]
    return n if n[2] >= 0 else -n


def fit_plane(
    xyz: Any,
    *,
    sd_m: Any = (0.10, 0.10, 0.05),
    residual_threshold_m: float | None = 0.15,
    residual_kind: str = "normal",
    min_points: int = 6,
    posterior_variance: bool = True,
    cells_m: Any = (),
    grid_origin_m: Any = (0.0, 0.0),
    label: int = 0,
) -> PlaneFit:
    """Fit one plane by the combined adjustment (eq. 33-37) with iterative rejection.

    Parameters
    ----------
    xyz : (M, 3) float
        Points E, N, h (m).
    sd_m : (3,) or (M, 3) float
        Standard deviations of E, N, h of every point (m).
    residual_threshold_m : float or None
        Points whose residual exceeds this are removed and the plane refitted
        (thesis 0.15 m).  None: 3.5 x robust sigma (MAD) of the distances of
        all points, >= 0.03 m.
    residual_kind : {"normal", "vertical", "height"}
        Orthogonal distance; vertical distance to the plane (the thesis's
        "altimetric residual"); or the adjusted-height residual v_h of the GH
        model, the fraction :math:`s_h^2 n_h^2 / (n^T \\Sigma n)` of the vertical
        misclosure: with the thesis sds (0.50 m plan, 0.15 m height) 74 % on a
        10 deg face but 26 % on a 27 deg face, too weak to catch a chimney at 0.15 m.
    min_points : int
        Fewer remaining points make the fit fail.
    posterior_variance : bool
        Scale the cofactor matrix by the a-posteriori variance factor.
    cells_m : sequence of float
        Cell sizes (m) of the correlated residual components (module docstring, "Correlated
        residuals"); the extraction uses ``(1.0, 3.0)``.  Empty: independent points, the
        covariance is :math:`\\hat\\sigma_0^2 Q` (eq. 37).  Needs *posterior_variance*.
    grid_origin_m : (2,) float
        E, N (m) of the origin of *xyz*'s frame when it is reduced: the cells are the grid
        ``floor((E, N) / c)`` of the outer frame, the same for every clip of a roof.

    Returns
    -------
    PlaneFit
        Falsy with a ``reason`` when fewer than *min_points* remain or the
        points are collinear.

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> e, n = rng.uniform(0, 5, (2, 200))
    >>> h = 10 + 0.5 * e + rng.normal(0, 0.02, 200)
    >>> fit = fit_plane(np.column_stack([e, n, h]))
    >>> bool(abs(fit.plane.slope_deg - 26.565) < 0.3), fit.plane.n_used
    (True, 200)
    """
    x_all = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    m_all = len(x_all)
    sd = np.broadcast_to(np.asarray(sd_m, dtype=np.float64), (m_all, 3))
    s2_all = sd**2
    used = np.ones(m_all, dtype=bool)
    resid = np.full(m_all, np.nan)
    if m_all < min_points:
        return PlaneFit(None, used, resid, math.nan,
                        f"{m_all} points, a plane needs at least {min_points}")
    origin = x_all.mean(axis=0)
    xl_all = x_all - origin
    n0 = _initial_normal(xl_all, s2_all)
    for _ in range(200):
        idx = np.flatnonzero(used)
        if len(idx) < min_points:
            return PlaneFit(None, used, resid, math.nan,
                            f"only {len(idx)} of {m_all} points left after rejection "
                            f"(threshold {residual_threshold_m} m); need {min_points}")
        xl, s2 = xl_all[idx], s2_all[idx]
        if np.linalg.matrix_rank(xl[:, :2] - xl[:, :2].mean(axis=0), tol=1e-6) < 2:
            return PlaneFit(None, used, resid, math.nan, "points are collinear in plan")
        try:
            n, d, qxx, r, w = _gh_solve(xl, s2, n0)
        except np.linalg.LinAlgError:
            return PlaneFit(None, used, resid, math.nan, "singular plane adjustment")
        n0 = n
        # residuals of all points to the current plane (removed ones too)
        r_all = xl_all @ n + d
        if residual_kind == "height":
            q_all = s2_all @ (n * n)
            test = np.abs(s2_all[:, 2] * n[2] * r_all / q_all)
        elif residual_kind == "vertical":
            test = np.abs(r_all) / max(abs(n[2]), 1e-6)
        else:
            test = np.abs(r_all)
        thr = residual_threshold_m
        if thr is None:
            # robust sigma from ALL points (rejected ones too), so that the
            # threshold does not shrink as the tails are cut
            mad = float(np.median(np.abs(r_all - np.median(r_all))))
            thr = max(0.03, 3.5 * 1.4826 * mad)
        bad = used & (test > thr)
        resid = test
        if not bad.any():
            break
        # remove the worst first (thesis: one point, then re-fit); batches for speed
        worst = float(test[bad].max())
        used = used & ~(bad & (test > max(thr, 0.5 * worst)))
    idx = np.flatnonzero(used)
    m = len(idx)
    dof = m - 3
    sigma0_2 = float(np.sum(w * r * r) / dof) if dof > 0 else math.nan
    # with the variance factor estimated from m - 3 redundancies, the standardised
    # error is t-distributed: its variance is dof / (dof - 2), not 1
    tcorr = t_factor(dof)
    components: tuple = ()
    if posterior_variance and np.isfinite(sigma0_2) and len(cells_m):
        en_abs = x_all[idx, :2] + np.asarray(grid_origin_m, dtype=np.float64).reshape(2)
        comp = _variance_components(en_abs, xl_all[idx], s2_all[idx], w, r, qxx, n, cells_m)
        components = comp.variances
        cov = comp.cov
    else:
        cov = qxx * (sigma0_2 * tcorr if posterior_variance and np.isfinite(sigma0_2) else 1.0)
    local = Plane(n=n, d=d, cov=cov, centroid_m=xl_all[idx].mean(axis=0),
                  n_used=m, n_rejected=m_all - m, rms_m=float(np.sqrt(np.mean(r * r))), label=label)
    plane = translated(local, origin)
    return PlaneFit(plane, used, resid, math.sqrt(sigma0_2) if np.isfinite(sigma0_2) else math.nan,
                    components=components)


def t_factor(dof: int) -> float:
    """Variance of a standardised error whose variance was estimated with *dof* redundancies: f / (f - 2).

    3 for f <= 4 (the t distribution's variance is infinite at f <= 2; a fixed, generous cap)."""
    return dof / (dof - 2.0) if dof > 4 else 3.0


#: a cell component is estimated when its statistic exceeds its value for independent residuals by this
#: many standard deviations (one-sided; module docstring)
Z_KEEP = 2.0


@dataclass(frozen=True, eq=False)
class _Components:
    """Variance components of one plane fit and the covariance of ``(n, d)`` they give (local frame)."""

    variances: tuple  # (sigma0^2, tau_1^2 (m^2), ...) in the order of cells_m
    cov: np.ndarray  # (4, 4), each component times its t factor


def _variance_components(en_abs: np.ndarray, xl: np.ndarray, s2: np.ndarray, w: np.ndarray, r: np.ndarray,
                         qxx: np.ndarray, n: np.ndarray, cells_m: Any) -> _Components:
    """Moment estimates of sigma0^2 and the cell variances tau_k^2, and the plane covariance (module docstring).

    *en_abs* (m, 2) E, N of the points used (absolute: the cells are a fixed grid, the same in every clip), *xl* the
    same in the local frame, *s2* (m, 3) their variances, *w* (m,) the condition weights, *r* (m,) the
    condition residuals (m), *qxx* the 4x4 cofactor block of the bordered normal matrix, *n* the unit normal.
    """
    from scipy.optimize import nnls

    m = len(xl)
    # design rows at the adjusted observations x + v, as in the last normal matrix of _gh_solve
    v = -(s2 * n[None, :]) * (r * w)[:, None]
    a_mat = np.column_stack([xl + v, np.ones(m)])
    keys, f_mats, t_obs = [], [], [float(np.sum(w * r * r))]
    for c in cells_m:
        cell = np.floor(en_abs / float(c)).astype(np.int64)
        _, inv = np.unique(cell, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        g = int(inv.max()) + 1
        keys.append((inv, g))
        # F_k = A~' Z~_k (4, G): per cell the sum of w_i a_i
        f_mats.append(np.stack([np.bincount(inv, weights=w * a_mat[:, j], minlength=g) for j in range(4)]))
        t_obs.append(float(np.sum(np.bincount(inv, weights=w * r, minlength=g) ** 2)))
    k = len(keys)
    coef = np.zeros((k + 1, k + 1))
    coef[0, 0] = m - 3.0  # ||R~||_F^2, R~ = I - A~ Q A~' of rank m - 3
    sum_w = float(np.sum(w))
    for i in range(k):
        fq = qxx @ f_mats[i]
        coef[0, i + 1] = coef[i + 1, 0] = sum_w - float(np.sum(f_mats[i] * fq))
        inv_i = keys[i][0]
        for j in range(i, k):
            inv_j, g_j = keys[j]
            # ||M - F_i' Q F_j||_F^2 with M = Z~_i' Z~_j (per pair of cells the sum of w over their common
            # points; at most m non-zeros), expanded so that no G_i x G_j matrix is formed:
            # ||M||^2 - 2 sum_ab M_ab (F_i' Q F_j)_ab + tr(Q F_i F_i' Q F_j F_j')
            pair, pinv = np.unique(inv_i * g_j + inv_j, return_inverse=True)
            mval = np.bincount(pinv.reshape(-1), weights=w)
            a_idx, b_idx = pair // g_j, pair % g_j
            cross = np.sum(f_mats[i][:, a_idx] * (qxx @ f_mats[j][:, b_idx]), axis=0)
            gi, gj = f_mats[i] @ f_mats[i].T, f_mats[j] @ f_mats[j].T
            coef[i + 1, j + 1] = coef[j + 1, i + 1] = float(
                np.sum(mval * mval) - 2.0 * np.sum(mval * cross) + np.trace(qxx @ gi @ qxx @ gj))
    t_obs = np.asarray(t_obs)
    # a component is estimated only where the cells show it: z_k of T_k against independent residuals
    # (E = s0^2 c_0k, Var = 2 s0^4 c_kk for Gaussian residuals) above Z_KEEP
    s0_2 = t_obs[0] / max(m - 3.0, 1.0)
    var = np.zeros(k + 1)
    var[0] = s0_2
    keep = [0] + [i + 1 for i in range(k)
                  if coef[i + 1, i + 1] > 0 and
                  (t_obs[i + 1] - s0_2 * coef[0, i + 1]) / (s0_2 * math.sqrt(2.0 * coef[i + 1, i + 1])) > Z_KEEP]
    if len(keep) > 1:
        sol, _ = nnls(coef[np.ix_(keep, keep)], t_obs[keep])
        var[keep] = sol
        if var[0] <= 0.0:  # all of the misclosure in the cells: keep the iid part at its usual estimate
            var[0] = s0_2
    # sigma0^2 Q N Q = sigma0^2 Q (Q the bordered inverse's block); each component times the t factor
    # f / (f - 2) of its own redundancy: m - 3 points, G_k - 3 cells
    cov = t_factor(m - 3) * var[0] * qxx
    for i in range(k):
        fq = qxx @ f_mats[i]
        cov = cov + t_factor(keys[i][1] - 3) * var[i + 1] * fq @ fq.T
    return _Components(tuple(float(x) for x in var), 0.5 * (cov + cov.T))
