"""The CSF's vectorised constraint sweep equals the reference's sequential updates along a line."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.production import csf


def _sequential(z, movable, line, c1, c2):
    """The reference's update order on one line: particle k applies its constraint to k+1, then k+1 applies
    the same constraint back (each constraint twice, in place), k = 0, 1, ..."""
    z = z.copy()
    for a, b in zip(line[:-1], line[1:]):
        for _ in range(2):
            d = z[b] - z[a]
            if movable[a] and movable[b]:
                z[a] += c2 * d
                z[b] -= c2 * d
            elif movable[a]:
                z[a] += c1 * d
            elif movable[b]:
                z[b] -= c1 * d
    return z


@pytest.mark.parametrize("rigidness", [1, 2, 3])
def test_sweep_is_the_sequential_update(rigidness):
    rng = np.random.default_rng(rigidness)
    nr, nc = 7, 11
    z = np.append(rng.normal(0.0, 1.0, nr * nc), 0.0)
    movable = np.append(rng.random(nr * nc) < 0.7, False)
    c1 = 1.0 - 0.7 ** rigidness
    c2 = 0.5 * (1.0 - 0.4 ** rigidness)
    assert (c1, c2) == pytest.approx(((0.3, 0.51, 0.657)[rigidness - 1], (0.3, 0.42, 0.468)[rigidness - 1]))
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0), (2, 2), (2, -2)):
        lines = csf._family_lines(nr, nc, dr, dc)
        # every particle on exactly one line of the family
        assert np.array_equal(np.sort(lines[lines >= 0]), np.arange(nr * nc))
        want = z.copy()
        for line in lines:
            want = _sequential(want, movable, line[line >= 0], c1, c2)
        got = z.copy()
        csf._sweep(got, movable, lines, c1, c2)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
