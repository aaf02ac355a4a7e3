"""The one TIN locator (lidarcat.geometry.tin): the triangles scipy finds, weights that rebuild the point."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import Delaunay

from lidarcat.geometry.tin import TinLocator, barycentric, find_simplex


@pytest.fixture(scope="module")
def tri():
    rng = np.random.default_rng(3)
    return Delaunay(rng.uniform(0, 100, (3000, 2)))


def test_locate_gives_scipys_triangles_and_weights_that_rebuild_the_point(tri):
    rng = np.random.default_rng(4)
    q = rng.uniform(-10, 110, (20000, 2))              # about a third outside the hull
    s, w = TinLocator(tri).locate(q)
    want = tri.find_simplex(q)
    assert (want < 0).sum() > 3000 and np.array_equal(s, want)
    ins = s >= 0
    np.testing.assert_allclose(w[ins].sum(axis=1), 1.0, atol=1e-12)
    v = tri.points[tri.simplices[s[ins]]]
    np.testing.assert_allclose(np.einsum("mk,mkj->mj", w[ins], v), q[ins], atol=1e-9)
    assert (w[~ins] == 0).all()
    np.testing.assert_allclose(barycentric(v, q[ins]), w[ins], atol=1e-12)


def test_results_do_not_depend_on_how_many_points_are_located_at_once(tri):
    """Few points: transforms of the visited triangles; many: one table of all (the same numbers)."""
    rng = np.random.default_rng(5)
    q = rng.uniform(0, 100, (5000, 2))
    s_all, w_all = TinLocator(tri).locate(q)
    loc = TinLocator(tri)
    parts = [loc.locate(q[i:i + 7]) for i in range(0, 70, 7)]
    assert loc._inv_all is None                        # the small batches built no table
    assert np.array_equal(np.concatenate([p[0] for p in parts]), s_all[:70])
    assert np.array_equal(np.concatenate([p[1] for p in parts]), w_all[:70])  # bit for bit


def test_nan_rows_are_outside_and_duplicate_points_are_located():
    """A point given twice (Qhull triangulates one of them) and NaN rows (outside, -1)."""
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0], [5.0, 5.0], [5.0, 5.0]])
    tri = Delaunay(pts)
    q = np.array([[5.0, 5.2], [np.nan, 1.0], [20.0, 0.0], [5.1, 4.9], [5.0, 5.0]])
    s = find_simplex(tri, q)
    assert s[1] == -1 and s[2] == -1
    assert (s[[0, 3, 4]] >= 0).all()
    for k in (0, 3, 4):  # inside (or on the border of) the triangle found
        assert (barycentric(tri.points[tri.simplices[s[k]]][None], q[k][None])[0] >= -1e-9).all(), k
