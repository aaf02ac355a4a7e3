r"""Self-calibration parameter sets by name: ``thesis``, ``brown``, ``ebner`` (12), ``gruen`` (44).

A set switches on interior-orientation parameters the bundle already knows (``io``: ``c, x0,
y0, k1, k2, k3, p1, p2`` of :mod:`lidarcat.bundle.additional`) and/or *extra* parameters whose
correction this module computes.  Corrections are in the sense of thesis eq. 07: subtracted
from the photogrammetric coordinate ``x_fot`` (mm)::

    x_fotc = x_fot - D(x_fot) - A(x_fot; theta),      A = sum_i theta_i f_i(x_fot / b)

so the residual ``v = x_predicted - x_fotc`` has ``dv/dtheta_i = f_i`` (:meth:`ParameterSet.jacobian`)
and ``dA/dx_fot`` (:meth:`ParameterSet.jacobian_xy`) enters the principal-point columns and the
inverse.  Every ``f_i`` is a 2-vector of polynomials in ``u = x / b``, ``v = y / b``; they are
*linear* in ``theta``.

``thesis``: c, x0, y0, K1-K3, P1, P2 (eq. 01-07), no extra.

``brown`` (Metashape, MicMac ``Fraser``): the thesis set plus ``k4`` (``A = (x, y) r^8``, mm^-8)
and the affinity ``b1`` (``A = (x, 0)``), shear ``b2`` (``A = (y, 0)``), dimensionless; here
``b = 1`` (raw mm), as the certificate's k1..k3.

``ebner`` (Ebner 1976): the 18 polynomials ``(P_i(u) P_j(v), 0)`` and ``(0, P_i(u) P_j(v))``,
``i, j <= 2``, with the polynomials orthogonal over the 3 x 3 grid ``u, v in {-1, 0, 1}``::

    P0 = 1,  P1 = u,  P2 = u^2 - 2/3            (sum over the grid of P2 = 0)

Six combinations of them are the exterior/interior orientation and are removed: the shifts
``(1, 0)``, ``(0, 1)`` (principal point), the scale ``(u, v)`` (c), the rotation ``(-v, u)``
(kappa) and the two tilts ``(u^2, u v)``, ``(u v, v^2)`` (phi, omega, to first order).  What
is left, each orthogonal to those six and to each other over the grid, is Ebner's set::

    e1  = (u, -v)                    e2  = (v, u)
    e3  = (-2 P2(u), u v)            e4  = (u v, -2 P2(v))          (tilt complements:
    e5  = (P2(v), 0)                 e6  = (0, P2(u))                sum -2 P2(u) u^2 + (u v)^2 = 0)
    e7  = (u P2(v), 0)               e8  = (0, v P2(u))
    e9  = (v P2(u), 0)               e10 = (0, u P2(v))
    e11 = (P2(u) P2(v), 0)           e12 = (0, P2(u) P2(v))

which is Ebner's printed form ``dx = b1 x + b2 y - b3 (2 x^2 - 4 b^2/3) + b4 x y + b5 (y^2 -
2 b^2/3) + ...`` with ``x = b u`` (his b_i = theta_i / b^degree).  ``b`` is half the frame's
larger side, so the grid spans the frame and every ``theta_i`` is the size of its correction at a
grid corner (mm).

``gruen`` (Grün 1978): the same construction on the 5 x 5 grid ``u, v in {-2, ..., 2}``
(``b`` a quarter of the larger side) with the polynomials orthogonal over five points::

    P0 = 1, P1 = u, P2 = u^2 - 2, P3 = u^3 - 17/5 u, P4 = u^4 - 31/7 u^2 + 72/35

(``P3``: ``sum u^4 - a sum u^2 = 34 - 10 a = 0``; ``P4 = u^4 + a u^2 + d`` orthogonal to 1 and
``u^2``: ``34 + 10 a + 5 d = 0``, ``130 + 34 a + 10 d = 0``).  The 50 products ``i, j <= 4``
less the six orientation functions leave 44: ``g1, g2`` as e1, e2; the tilt complements
``g3 = (-10/7 P2(u), u v)``, ``g4 = (u v, -10/7 P2(v))`` (over five points ``sum P2^2 = 70``,
``sum (u v)^2 = 100``), ``g5 = (P2(v), 0)``, ``g6 = (0, P2(u))``; then the 19 remaining
products of each coordinate, ``(P_i(u) P_j(v), 0)`` and ``(0, P_i(u) P_j(v))`` alternately, in the
order of their degree ``i + j`` and then of ``i`` descending.  (The construction is Grün's --
orthogonal polynomials of fourth degree over the 5 x 5 grid, the orientation-like terms removed --;
the numbering is this module's and need not be his printed table's.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import CameraError

__all__ = ["ParameterSet", "PARAMETER_SETS", "parameter_set", "orientation_functions"]


def _poly(*coef: float) -> np.ndarray:
    return np.array(coef, dtype=float)


#: 1-D orthogonal polynomials (coefficients of u^0, u^1, ...) over 3 and 5 grid points
_P3 = [_poly(1), _poly(0, 1), _poly(-2 / 3, 0, 1)]
_P5 = [_poly(1), _poly(0, 1), _poly(-2, 0, 1), _poly(0, -17 / 5, 0, 1), _poly(72 / 35, 0, -31 / 7, 0, 1)]
_DEG = 10  # coefficient arrays are (_DEG, _DEG): u^a v^b, a, b < 10 (brown's x r^8 needs degree 9)


def _product(pu: np.ndarray, pv: np.ndarray) -> np.ndarray:
    c = np.zeros((_DEG, _DEG))
    c[:len(pu), :len(pv)] = np.outer(pu, pv)
    return c


def _mono(a: int, b: int, k: float = 1.0) -> np.ndarray:
    c = np.zeros((_DEG, _DEG))
    c[a, b] = k
    return c


_ZERO = np.zeros((_DEG, _DEG))


def _orthogonal_set(P: list[np.ndarray], tilt: float, prefix: str) -> tuple[tuple[str, ...], np.ndarray]:
    """The Ebner/Grün construction (module docstring): names and (m, 2, _DEG, _DEG) coefficients."""
    n = len(P)
    uv = _mono(1, 1)
    funcs = [
        (_mono(1, 0), _mono(0, 1, -1.0)),                  # (u, -v)
        (_mono(0, 1), _mono(1, 0)),                        # (v, u)
        (tilt * _product(P[2], P[0]), uv),                 # tilt complements
        (uv, tilt * _product(P[0], P[2])),
        (_product(P[0], P[2]), _ZERO),
        (_ZERO, _product(P[2], P[0])),
    ]
    removed = {(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)}
    pairs = sorted(((i, j) for i in range(n) for j in range(n) if (i, j) not in removed), key=lambda p: (p[0] + p[1], -p[0]))
    if n == 3:  # Ebner's own numbering: (1,2)x, (2,1)y, (2,1)x, (1,2)y, (2,2)x, (2,2)y
        funcs += [(_product(P[1], P[2]), _ZERO), (_ZERO, _product(P[2], P[1])),
                  (_product(P[2], P[1]), _ZERO), (_ZERO, _product(P[1], P[2])),
                  (_product(P[2], P[2]), _ZERO), (_ZERO, _product(P[2], P[2]))]
    else:
        for i, j in pairs:
            funcs += [(_product(P[i], P[j]), _ZERO), (_ZERO, _product(P[i], P[j]))]
    names = tuple(f"{prefix}{k + 1}" for k in range(len(funcs)))
    return names, np.array([[fx, fy] for fx, fy in funcs])


def orientation_functions(grid: int) -> np.ndarray:
    """The six orientation-like corrections removed from the orthogonal sets, (6, 2, _DEG, _DEG):
    shifts (1, 0), (0, 1), scale (u, v), rotation (-v, u), tilts (u^2, u v), (u v, v^2)."""
    del grid  # the same monomials on every grid
    return np.array([[_mono(0, 0), _ZERO], [_ZERO, _mono(0, 0)], [_mono(1, 0), _mono(0, 1)],
                     [_mono(0, 1, -1.0), _mono(1, 0)], [_mono(2, 0), _mono(1, 1)], [_mono(1, 1), _mono(0, 2)]])


def _brown_extra() -> tuple[tuple[str, ...], np.ndarray]:
    # x r^8 = x (x^2 + y^2)^4 = sum_k C(4, k) x^(2k+1) y^(8-2k)
    cx, cy = np.zeros((_DEG, _DEG)), np.zeros((_DEG, _DEG))
    for k in range(5):
        cx[2 * k + 1, 8 - 2 * k] = math.comb(4, k)
        cy[2 * k, 9 - 2 * k] = math.comb(4, k)
    return ("k4", "b1", "b2"), np.array([[cx, cy], [_mono(1, 0), _ZERO], [_mono(0, 1), _ZERO]])


@dataclass(frozen=True, eq=False)
class ParameterSet:
    """A named self-calibration parameter set.

    Attributes
    ----------
    name : str
        The set's name (``thesis``, ``brown``, ``ebner``, ``gruen``).
    io : tuple of str
        Interior-orientation parameters of :mod:`lidarcat.bundle.additional` the set switches on.
    extra : tuple of str
        The set's own parameters, whose corrections this class computes.
    units : dict of str to str
        The unit of every extra parameter.
    grid : int
        0 for raw mm (``b = 1``), else the points per side of the grid (3 Ebner, 5 Grün) the
        polynomials are orthogonal over; ``b`` is then the grid spacing.
    description : str
        One line: what the set is.
    """

    name: str
    io: tuple[str, ...]
    extra: tuple[str, ...]
    units: dict[str, str]
    grid: int
    description: str
    coef: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2, _DEG, _DEG)))

    @property
    def parameters(self) -> tuple[str, ...]:
        """Every parameter of the set: ``io + extra``."""
        return self.io + self.extra

    def scale_mm(self, width_mm: float, height_mm: float) -> float:
        """``b`` for a frame of *width_mm* x *height_mm*: the grid spans the larger side (1 for raw mm)."""
        if self.grid == 0:
            return 1.0
        return max(width_mm, height_mm) / 2 / ((self.grid - 1) // 2)

    def _powers(self, xy_mm: Any, b_mm: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        xy = np.asarray(xy_mm, dtype=float).reshape(-1, 2) / b_mm
        k = np.arange(_DEG)
        return xy, xy[:, 0:1] ** k, xy[:, 1:2] ** k

    def jacobian(self, xy_mm: Any, b_mm: float) -> np.ndarray:
        """d A / d theta = the functions ``f_i`` at *xy_mm* (N, 2), shape (N, 2, m) (mm per unit of theta)."""
        _, U, V = self._powers(xy_mm, b_mm)
        mono = (U[:, :, None] * V[:, None, :]).reshape(len(U), -1)          # u^a v^b, (N, _DEG^2)
        m = self.coef.shape[0]
        return (mono @ self.coef.reshape(m * 2, -1).T).reshape(len(U), m, 2).transpose(0, 2, 1)

    def corrections(self, xy_mm: Any, theta: Any, b_mm: float) -> np.ndarray:
        """The correction ``A(x_fot; theta)`` (N, 2), mm, subtracted as in eq. 07."""
        th = np.asarray(theta, dtype=float).ravel()
        if th.shape != (len(self.extra),):
            raise CameraError(f"parameter set {self.name!r}: {len(self.extra)} values expected "
                              f"({', '.join(self.extra)}), got {th.size}")
        _, U, V = self._powers(xy_mm, b_mm)
        c = np.tensordot(th, self.coef, axes=1).reshape(2, -1)
        return (U[:, :, None] * V[:, None, :]).reshape(len(U), -1) @ c.T

    def jacobian_xy(self, xy_mm: Any, theta: Any, b_mm: float) -> np.ndarray:
        """d A / d x_fot (N, 2, 2), dimensionless: enters ``(I - dD/dx - dA/dx)`` of x0, y0 and the inverse."""
        th = np.asarray(theta, dtype=float).ravel()
        _, U, V = self._powers(xy_mm, b_mm)
        k = np.arange(_DEG)
        dU = np.zeros_like(U)
        dU[:, 1:] = U[:, :-1] * k[1:]
        dV = np.zeros_like(V)
        dV[:, 1:] = V[:, :-1] * k[1:]
        c = np.tensordot(th, self.coef, axes=1).reshape(2, -1)              # (2, _DEG^2)
        out = np.empty((len(U), 2, 2))
        out[:, :, 0] = (dU[:, :, None] * V[:, None, :]).reshape(len(U), -1) @ c.T / b_mm
        out[:, :, 1] = (U[:, :, None] * dV[:, None, :]).reshape(len(U), -1) @ c.T / b_mm
        return out


def _build() -> dict[str, ParameterSet]:
    io8 = ("c", "x0", "y0", "k1", "k2", "k3", "p1", "p2")
    bn, bc = _brown_extra()
    en, ec = _orthogonal_set(_P3, -2.0, "e")
    gn, gc = _orthogonal_set(_P5, -10.0 / 7.0, "g")
    return {
        "thesis": ParameterSet("thesis", io8, (), {}, 0, "c, x0, y0, K1-K3, P1, P2 (thesis eq. 01-07)"),
        "brown": ParameterSet("brown", io8, bn, {"k4": "mm^-8", "b1": "1", "b2": "1"}, 0,
                              "the thesis set with k4 and the affinity b1, shear b2 (Metashape, MicMac Fraser)",
                              bc),
        "ebner": ParameterSet("ebner", (), en, {n: "mm" for n in en}, 3,
                              "Ebner's 12 polynomials, orthogonal over a 3 x 3 grid", ec),
        "gruen": ParameterSet("gruen", (), gn, {n: "mm" for n in gn}, 5,
                              "Grün's 44 polynomials, orthogonal over a 5 x 5 grid", gc),
    }


#: the parameter sets by name
PARAMETER_SETS: dict[str, ParameterSet] = _build()


def parameter_set(name: str) -> ParameterSet:
    """The parameter set *name*.

    >>> len(parameter_set("ebner").parameters), len(parameter_set("gruen").parameters)
    (12, 44)

    Raises
    ------
    CameraError
        An unknown name (with the known ones).
    """
    key = str(name).strip().lower()
    if key not in PARAMETER_SETS:
        raise CameraError(f"unknown self-calibration parameter set {name!r}; known: {', '.join(PARAMETER_SETS)}")
    return PARAMETER_SETS[key]
