"""The break-line buffer of :mod:`lidarcat.control.segment`: points along ridges leave the fit, not the face.

A gable roof whose ridge tiles stand 5 cm above the two roof planes (the points within 0.15 m of the ridge,
as on the AHN3 tiles, where the points within 0.2 m of the break lines lie a median 21 mm above the planes of
the faces' interiors): without the buffer the planes tilt towards the ridge and the ridge comes out too high;
with it the ridge height is the planes' own, within its sd.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.control.facets import segment_faces
from lidarcat.control.params import get_params


def _gable(seed: int, cap_m: float = 0.05, half_width_m: float = 0.15):
    rng = np.random.default_rng(seed)
    m = 800
    e, n = rng.uniform(-5, 5, m), rng.uniform(-5, 5, m)
    h = 10.0 - np.tan(np.radians(30.0)) * np.abs(e) + rng.normal(0, 0.02, m)
    h[np.abs(e) < half_width_m] += cap_m
    return np.column_stack([e + 1000.0, n + 2000.0, h])


def _ridge_height(planes) -> float:
    """Height of the two planes' intersection above E = 1000, N = 2000 (m)."""
    a, b = planes[:2]
    mat = np.array([a.n, b.n, [0.0, 1.0, 0.0]])
    # the ridge runs along N: its point at N = 2000
    x = np.linalg.solve(mat, [-a.d, -b.d, 2000.0])
    return float(x[2])


@pytest.mark.parametrize("seed", [1, 2])
def test_buffer_leaves_the_ridge_points_out_of_the_fit_and_the_ridge_unbiased(seed):
    xyz = _gable(seed)
    near = np.abs(xyz[:, 0] - 1000.0) < 0.2
    p = get_params(sd_en_m=0.03, sd_h_m=0.02)  # buffer 2 x sd_en = 0.06 m: too narrow for these 0.15 m tiles
    planes0, lab0, _ = segment_faces(xyz, p.replace(edge_buffer_m=0.0))
    planes1, lab1, info = segment_faces(xyz, p.replace(edge_buffer_m=0.2))
    assert len(planes0) == len(planes1) == 2
    assert info["edge_buffer_m"] == 0.2
    # left out of the fit, still part of the face (its extent)
    assert np.all(lab1[near] == -1)
    assert np.mean(info["extent_labels"][near] >= 0) > np.mean(lab0[near] >= 0) - 0.05
    far = np.abs(xyz[:, 0] - 1000.0) > 0.3
    assert np.mean(lab1[far] >= 0) > np.mean(lab0[far] >= 0) - 0.02  # elsewhere the same points
    h0, h1 = _ridge_height(planes0), _ridge_height(planes1)
    sd1 = float(np.sqrt(planes1[0].cov_at([1000.0, 2000.0, 10.0])[3, 3]))
    assert h0 - 10.0 > 0.01  # the ridge tiles lift the ridge without the buffer
    assert abs(h1 - 10.0) < max(3 * sd1, 0.006), (h1, sd1)


def test_default_width_is_two_plan_sds_and_is_checked():
    xyz = _gable(3, cap_m=0.0)
    _, _, info = segment_faces(xyz, get_params(sd_en_m=0.03, sd_h_m=0.02))
    assert info["edge_buffer_m"] == pytest.approx(0.06)
    with pytest.raises(ValueError, match="edge_buffer_m must be >= 0"):
        get_params(edge_buffer_m=-0.1)
