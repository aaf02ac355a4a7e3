"""The break-line buffer as a test (:mod:`lidarcat.control.segment`, "Break-line buffer"; ``edge_buffer_level``).

Known truth: a gable roof (two 30 deg faces, 3 cm E/N and 2 cm h sds, 2 cm height noise, 20 points per m2),
with or without 5 cm ridge tiles (the points within 0.15 m of the ridge).  With tiles each face's ridge band is
off its plane and leaves the fit (the planes are then exactly the blanket buffer's); without, no band is off
and the planes are exactly those without any buffer.  The offset's sd under the fit's error model (iid + the
cells' offsets) is checked on faces whose residuals share 1 m cell offsets, where the naive sd of a mean
(sigma0 / sqrt(n)) makes the test fire far too often.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarcat.control.facets import segment_faces
from lidarcat.control.params import get_params
from lidarcat.control.planes import fit_plane
from lidarcat.control.segment import _band_offset


def _gable(seed: int, cap_m: float, m: int = 2000):
    rng = np.random.default_rng(seed)
    e, n = rng.uniform(-5, 5, m), rng.uniform(-5, 5, m)
    h = 10.0 - np.tan(np.radians(30.0)) * np.abs(e) + rng.normal(0, 0.02, m)
    h[np.abs(e) < 0.15] += cap_m
    return np.column_stack([e + 1000.0, n + 2000.0, h])


def _faces(xyz, buffer_m, level=0.999):
    p = get_params(sd_en_m=0.03, sd_h_m=0.02, edge_buffer_m=buffer_m).replace(edge_buffer_level=level)
    return segment_faces(xyz, p)


def _nd(planes):
    return np.array([np.append(pl.n, pl.d) for pl in planes])


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_ridge_tiles_are_off_the_plane_so_the_band_leaves_the_fit(seed):
    """Measured (seeds 1-8): the ridge bands lie 14-36 mm above the interior planes, z 4.2-10.0 (> 3.29)."""
    xyz = _gable(seed, cap_m=0.05)
    planes, _, info = _faces(xyz, 0.2)
    bands = info["edge_bands"]
    assert sorted(b["line"] for b in bands) == [(0, 1), (1, 0)]
    assert all(b["dropped"] and b["offset_m"] > 0.01 and b["z"] > 3.29 for b in bands), bands
    assert info["edge_bands_pooled"]["pooled"] == 1.0
    # both bands dropped: the same fits as the blanket buffer's, so the ridge is not lifted by the tiles
    blanket, _, info0 = _faces(xyz, 0.2, level=0.0)
    assert all(b["dropped"] for b in info0["edge_bands"])
    np.testing.assert_array_equal(_nd(planes), _nd(blanket))
    none, _, _ = _faces(xyz, 0.0)
    ridge = lambda pls: float(np.linalg.solve([pls[0].n, pls[1].n, [0, 1, 0]], [-pls[0].d, -pls[1].d, 2000.0])[2])
    assert ridge(none) - ridge(planes) > 0.003  # the tiles lift the ridge 3.3-5.0 mm without the buffer


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_clean_roof_keeps_every_band_and_its_planes(seed):
    xyz = _gable(seed, cap_m=0.0)
    planes, lab, info = _faces(xyz, 0.2)
    bands = info["edge_bands"]
    assert len(bands) == 2 and not any(b["dropped"] for b in bands)
    assert all(abs(b["z"]) < 3.29 and abs(b["offset_m"]) < 0.01 for b in bands)
    assert info["edge_bands_pooled"]["pooled"] == 0.0
    none, lab0, _ = _faces(xyz, 0.0)
    np.testing.assert_array_equal(_nd(planes), _nd(none))
    np.testing.assert_array_equal(lab, lab0)


def test_a_clean_hip_roof_gives_the_vertex_of_no_buffer():
    """A hip roof (4 faces, two 3-face vertices): no band off, the vertex is the one without the buffer."""
    from lidarcat.control.vertices import extract_roof

    rng = np.random.default_rng(5)
    m = 3000
    e, n = rng.uniform(-6, 6, m), rng.uniform(-4, 4, m)
    t = np.tan(np.radians(30.0))
    h = 10.0 - t * np.maximum(np.abs(n), np.abs(e) - 2.0) + rng.normal(0, 0.02, m)
    xyz = np.column_stack([e + 1000.0, n + 2000.0, h])
    at = (1002.0, 2000.0)  # the ridge's east end
    base = get_params(sd_en_m=0.03, sd_h_m=0.02, radius_m=5.0)
    cp0 = extract_roof(xyz, at, params=base.replace(edge_buffer_m=0.0))
    cp1 = extract_roof(xyz, at, params=base.replace(edge_buffer_m=0.2))
    assert cp0.status == cp1.status == "ok" and cp1.n_planes == 3
    np.testing.assert_array_equal(cp1.enh_m, cp0.enh_m)
    assert np.linalg.norm(cp1.enh_m - [1002.0, 2000.0, 10.0]) < 0.05
    _, _, info = segment_faces(xyz - [0, 0, 0], base.replace(edge_buffer_m=0.2))
    assert info["edge_bands"] and not any(b["dropped"] for b in info["edge_bands"])


def test_the_offsets_sd_holds_with_cell_offsets_where_the_naive_one_does_not():
    """Faces with 1 m cell offsets (sd 2 cm) over 2 cm noise; band: the points within 0.4 m of a face's edge.

    z over 150 faces: sd 0.85 (a little conservative: the t factors and the noisy components), none beyond
    3.29; with sigma0 / sqrt(n_B) alone (no cells, no plane error) its sd is 1.64 and 4.7 % are beyond 3.29
    (0.1 % expected).
    """
    rng = np.random.default_rng(7)
    cells = (1.0, 3.0)
    z, z_naive = [], []
    for _ in range(150):
        m = 500
        e, n = rng.uniform(0, 8, m), rng.uniform(0, 6, m)
        cell = np.floor(e).astype(int) * 10 + np.floor(n).astype(int)
        u = rng.normal(0, 0.02, 100)
        h = 5.0 + 0.3 * e - 0.1 * n + rng.normal(0, 0.02, m) + u[cell]
        xyz = np.column_stack([e, n, h])
        band = np.flatnonzero(e > 7.6)
        interior = np.flatnonzero(e <= 7.6)
        p = get_params(sd_en_m=0.03, sd_h_m=0.02, cells_m=cells)
        fit = fit_plane(xyz[interior], sd_m=(0.03, 0.03, 0.02), residual_threshold_m=None, cells_m=cells,
                        min_points=p.min_points)
        off, sd, nb = _band_offset(xyz, fit, interior, band, p, (0.0, 0.0))
        z.append(off / sd)
        z_naive.append(off / (fit.sigma0 * math.sqrt(float(fit.plane.n @ np.diag([9e-4, 9e-4, 4e-4]) @ fit.plane.n))
                              / math.sqrt(nb)))
    z, z_naive = np.asarray(z), np.asarray(z_naive)
    assert 0.75 < np.std(z) < 1.25 and np.mean(np.abs(z) > 3.29) < 0.01, np.std(z)
    assert np.std(z_naive) > 1.4 and np.mean(np.abs(z_naive) > 3.29) > 0.02, np.std(z_naive)


def test_level_validation_and_the_blanket_value():
    assert get_params().edge_buffer_level == 0.999 and get_params().edge_buffer_m is None
    with pytest.raises(ValueError, match=r"edge_buffer_level must be in \[0, 1\), got 1.0"):
        get_params().replace(edge_buffer_level=1.0)
    with pytest.raises(ValueError, match=r"edge_buffer_level must be in \[0, 1\), got -0.1"):
        get_params().replace(edge_buffer_level=-0.1)


def _hip_roof(seed: int, cap_m: float):
    """A hip roof (ridge along E, 4 m long; four 30 deg faces), its ridge and hip points (within 0.15 m in plan)
    raised by *cap_m*."""
    rng = np.random.default_rng(seed)
    m = 3000
    e, n = rng.uniform(-6, 6, m), rng.uniform(-4, 4, m)
    h = 10.0 - np.tan(np.radians(30.0)) * np.maximum(np.abs(n), np.abs(e) - 2.0) + rng.normal(0, 0.02, m)
    ae, an = np.abs(e), np.abs(n)
    hip_d = np.abs(an - (ae - 2.0)) / np.sqrt(2.0)
    dist = np.where(ae < 2.0 + an, np.where(ae <= 2.0, an, np.minimum(an, hip_d)), hip_d)
    h[dist < 0.15] += cap_m
    return np.column_stack([e + 1000.0, n + 2000.0, h])


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_the_pooled_test_drops_every_band_of_a_tiled_roof_and_none_of_a_clean_one(seed):
    """2 cm ridge and hip tiles: 10 bands, measured z 1.4-6.3 (seeds 1-4), several below 3.29 alone; their
    sum of squares 106-212 against chi2_10's 29.6 at 99.9 %: every band leaves the fit.  Clean: q 7-17."""
    p = get_params(sd_en_m=0.03, sd_h_m=0.02, edge_buffer_m=0.2)
    _, _, info = segment_faces(_hip_roof(seed, 0.02), p)
    pool, bands = info["edge_bands_pooled"], info["edge_bands"]
    assert pool["k"] == len(bands) == 10 and pool["pooled"] == 1.0 and pool["q"] > 29.6
    assert all(b["dropped"] for b in bands)
    assert all(b["z"] > 1.0 for b in bands)  # all above: tiles
    _, _, info = segment_faces(_hip_roof(seed, 0.0), p)
    pool, bands = info["edge_bands_pooled"], info["edge_bands"]
    assert pool["pooled"] == 0.0 and pool["p"] > 0.001 and not any(b["dropped"] for b in bands)


def test_some_tiled_bands_are_not_significant_alone():
    """The pooled stage matters: on seed 2 six of the ten tiled bands have z < 3.29 (1.4-2.6)."""
    p = get_params(sd_en_m=0.03, sd_h_m=0.02, edge_buffer_m=0.2)
    _, _, info = segment_faces(_hip_roof(2, 0.02), p)
    assert sum(abs(b["z"]) < 3.29 for b in info["edge_bands"]) >= 5
