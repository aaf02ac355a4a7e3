"""Synthetic roofs: known truth, scanner-like sampling, details, seeding."""

import math

import numpy as np
import pytest

from lidarcat.synthetic.roofs import KINDS, LABELS, synthetic_roof


@pytest.mark.parametrize("kind", ["hip", "pyramid", "lgable"])
def test_vertex_truth_lies_on_the_sampled_roof(kind):
    s = synthetic_roof(kind, slope_deg=35, density_m2=16, noise_h_m=0.0, noise_plan_m=0.0, seed=4)
    v = s.vertices[0]
    roof = s.xyz[s.label == LABELS["roof"]]
    near = roof[np.hypot(*(roof[:, :2] - v[:2]).T) < 0.3]
    assert len(near) > 0
    # every roof point near the apex is below it by at most 0.3 m * tan(35 deg)
    assert np.all(near[:, 2] <= v[2] + 1e-9)
    assert np.all(near[:, 2] >= v[2] - 0.3 * math.tan(math.radians(35)) - 1e-9)


def test_hip_vertex_formula():
    s = synthetic_roof("hip", slope_deg=30, length_m=14, width_m=9, eave_m=6, azimuth_deg=0,
                       origin=(0, 0, 0), seed=0)
    np.testing.assert_allclose(s.vertices, [[-2.5, 0, 6 + 4.5 * math.tan(math.radians(30))],
                                            [2.5, 0, 6 + 4.5 * math.tan(math.radians(30))]], atol=1e-9)
    assert s.vertex_planes.tolist() == [3, 3]


@pytest.mark.parametrize("density", [1.0, 4.0, 16.0])
def test_density_matches_request(density):
    s = synthetic_roof("gable", length_m=20, width_m=10, density_m2=density, walls=False, seed=1,
                       azimuth_deg=0)
    n_roof = (s.label == LABELS["roof"]).sum()
    assert n_roof / 200.0 == pytest.approx(density, rel=0.12)


def test_height_noise_matches_request():
    s = synthetic_roof("flat", density_m2=8, noise_h_m=0.10, noise_plan_m=0.0, walls=False, seed=2)
    z = s.xyz[s.label == LABELS["roof"], 2]
    assert np.std(z) == pytest.approx(0.10, rel=0.1)


def test_details_present_and_seeded():
    kw = dict(chimney=True, dormer=True, tree=True, walls=True, density_m2=8, seed=11)
    a = synthetic_roof("hip", **kw)
    b = synthetic_roof("hip", **kw)
    np.testing.assert_array_equal(a.xyz, b.xyz)
    for name in ("ground", "roof", "wall", "chimney", "tree", "dormer"):
        assert (a.label == LABELS[name]).sum() > 0, name
    assert len(a.vertices) == 3  # two ridge ends + the dormer valley vertex
    c = synthetic_roof("hip", **{**kw, "seed": 12})
    assert not np.array_equal(a.xyz[:10], c.xyz[:10])


def test_second_strip_has_the_offset():
    s = synthetic_roof("flat", strips=2, strip_offset_m=(0.0, 0.0, 0.20), noise_h_m=0.02,
                       walls=False, density_m2=6, seed=5)
    z0 = s.xyz[(s.strip == 0) & (s.label == LABELS["roof"]), 2].mean()
    z1 = s.xyz[(s.strip == 1) & (s.label == LABELS["roof"]), 2].mean()
    assert z1 - z0 == pytest.approx(0.20, abs=0.01)


def test_walls_face_the_scanner_only():
    s = synthetic_roof("gable", azimuth_deg=0, density_m2=10, seed=3, origin=(0, 0, 0))
    wall = s.xyz[s.label == LABELS["wall"]]
    assert len(wall) > 0
    # nadir is 150 m east: only the east facade (x = +7) is seen
    assert np.all(wall[:, 0] > 0)


def test_bad_kind_and_hip_shape():
    with pytest.raises(ValueError, match="unknown roof kind 'dome'"):
        synthetic_roof("dome")
    with pytest.raises(ValueError, match="length_m > width_m"):
        synthetic_roof("hip", length_m=8, width_m=8)
    with pytest.raises(ValueError, match="strips must be 1 or 2, got 3"):  # was silently 2
        synthetic_roof("hip", strips=3)
    assert set(KINDS) >= {"gable", "hip", "pyramid", "lgable"}
