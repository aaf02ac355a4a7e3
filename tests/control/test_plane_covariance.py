"""The plane covariance with correlated residuals (``fit_plane(cells_m=...)``, lidarcat.control.planes).

Simulated faces with known truth: the normalised error of the plane's height at a point 1 m outside the
face's centre (its distance over the propagated sd) must have sd ~1.  Independent noise: the cell components
must not inflate the sds (the estimator is consistent: a component enters only when its statistic shows it).
Noise with one random offset per 1 m or 3 m cell (2 cm over 3 cm iid): the iid covariance
:math:`\\hat\\sigma_0^2 Q` is too small by 1.4-3x (asserted, so the test sees the defect), the components'
covariance is honest.  Bounds: 300 faces give the sd of z within about +-4 % (1 sigma), so 0.9-1.12 is
about +-2.5-3 sigma, as in tests/control/test_facets.py::test_gauss_helmert_covariance_is_honest.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.control.params import get_params
from lidarcat.control.planes import fit_plane

O = np.array([677000.0, 7183000.0])
V = np.array([677001.0, 7183001.0, 100.5])  # on the true plane h = 100 + 0.5 e
CELLS = (1.0, 3.0)


def _face(rng, m, noise_h, ext, tau=0.0, cell=1.0):
    e, n = rng.uniform(-ext / 2, ext / 2, (2, m))
    en = np.column_stack([e, n]) + O
    h = 100 + 0.5 * e + rng.normal(0, noise_h, m)
    if tau:
        _, inv = np.unique(np.floor(en / cell).astype(int), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        h = h + rng.normal(0, tau, inv.max() + 1)[inv]
    return np.column_stack([en + rng.normal(0, 0.02, (m, 2)), h])


def _z(seed, cells_m, runs=300, **face):
    rng = np.random.default_rng(seed)
    z = []
    for _ in range(runs):
        pl = fit_plane(_face(rng, **face), sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None,
                       cells_m=cells_m).plane
        xh = np.append(V - pl.centroid_m, 1.0)
        z.append(pl.distance(V[None])[0] / math.sqrt(xh @ pl.cov_at(pl.centroid_m) @ xh))
    return np.array(z)


@pytest.mark.parametrize("m,noise,ext", [(30, 0.10, 4.0), (200, 0.03, 8.0)])
def test_independent_points_keep_honest_sds(m, noise, ext):
    z = _z(1, CELLS, m=m, noise_h=noise, ext=ext)
    assert abs(z.mean()) < 0.15
    assert 0.9 < z.std() < 1.12, z.std()


@pytest.mark.parametrize("cell,m,ext", [(1.0, 200, 8.0), (3.0, 400, 10.0)])
def test_cell_correlated_residuals_get_honest_sds(cell, m, ext):
    face = dict(m=m, noise_h=0.03, ext=ext, tau=0.02, cell=cell)
    old = _z(2, (), **face)
    new = _z(2, CELLS, **face)
    assert old.std() > 1.3, old.std()  # sigma0^2 Q alone: too small
    assert 0.9 < new.std() < 1.15, new.std()


def test_components_are_estimated_and_reported():
    """A large face with 1 m cell offsets of 2 cm and 1 cm iid noise: tau_1^2 ~ 4e-4 m^2, no 3 m component."""
    rng = np.random.default_rng(3)
    x = _face(rng, 3000, 0.01, 12.0, tau=0.02, cell=1.0)
    fit = fit_plane(x, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None, cells_m=CELLS)
    s0_2, t1, t3 = fit.components
    # 144 cells: the sample variance of 144 offsets is within ~12 % (1 sigma) of tau^2
    assert 0.6 * 0.02**2 < t1 < 1.4 * 0.02**2, t1
    assert t3 < 0.2 * t1
    # sigma0^2 is the variance factor of the a-priori sds: (0.01 / sd of the condition)^2
    n = fit.plane.n
    q = (0.02**2) * (n[0] ** 2 + n[1] ** 2) + 0.10**2 * n[2] ** 2
    assert s0_2 == pytest.approx((0.01**2 + 0.02**2 * (n[0] ** 2 + n[1] ** 2)) / q, rel=0.15)
    plain = fit_plane(x, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None)
    assert plain.components == () and fit.plane.sd_offset_m > 2 * plain.plane.sd_offset_m


def test_cells_are_a_fixed_grid_of_the_outer_frame():
    """The same points reduced to another origin (as segment_faces does per clip) give the same covariance."""
    rng = np.random.default_rng(4)
    x = _face(rng, 400, 0.03, 8.0, tau=0.02, cell=1.0)
    fa = fit_plane(x, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None, cells_m=CELLS)
    shift = np.array([0.37, 0.61, 0.0]) + np.append(O, 100.0)
    fb = fit_plane(x - shift, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None, cells_m=CELLS,
                   grid_origin_m=shift[:2])
    np.testing.assert_allclose(fa.components, fb.components, rtol=1e-6)
    assert fa.components[1] > 0  # the 1 m component was found (else the test would prove nothing)
    # the covariance at the centroid (absolute national-grid offsets cost ~3 digits of the offset's variance)
    a, b = fa.plane, fb.plane
    np.testing.assert_allclose(a.cov_at(a.centroid_m), b.cov_at(b.centroid_m), rtol=1e-2, atol=1e-12)
    # the cells moved with the points (no grid_origin_m): other cells, another estimate
    fc = fit_plane(x - shift, sd_m=(0.02, 0.02, 0.10), residual_threshold_m=None, cells_m=CELLS)
    assert abs(fc.components[1] - fa.components[1]) > 0.05 * fa.components[1]
    assert get_params().cells_m == CELLS
    with pytest.raises(ValueError, match="cells_m must be positive"):
        get_params(cells_m=(0.0,))
