"""Ground on sparse LiDAR (0.1-0.3 pulses/m2), the cloth simulation filter, noise (class 7) and height above ground.

Bounds are the measured errors of ``python benchmarks/eval_ground_density.py``
(200 m squares there; 160 m here to keep the tests fast, re-measured) plus a
margin; the landscape seeds used here (1, 2) are the benchmark's held-out seeds,
not the ones the adaptive defaults were chosen on (seed 0).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.production.csf import CSFParameters, cloth_surface, csf_ground
from lidarcat.production.ground import SMRFParameters, classify_ground, confusion
from lidarcat.production.noise import height_above_ground, statistical_outliers
from lidarcat.synthetic.landscapes import make_landscape

SIZE = 160.0


def _total(name, density, seed, **kw):
    ls = make_landscape(name, size_m=SIZE, density=density, seed=seed)
    g = classify_ground(ls.xyz, ls.return_number, ls.number_of_returns, **kw)
    return confusion(ls.ground, g)


@pytest.mark.parametrize("name, density, adaptive_max, fixed_min", [
    ("steep", 0.1, 0.015, 0.05),          # 160 m: adaptive 0.45-0.87 %, fixed 1 m cell 6.25-8.76 %
    ("forest", 0.1, 0.10, 0.12),          # 7.80-8.33 % against 15.5-16.4 %
    ("low_outliers", 0.3, 0.002, 0.004),  # 0.00 % against 0.54-0.64 %
])
def test_sparse_points_adaptive_smrf_beats_the_fixed_grid(name, density, adaptive_max, fixed_min):
    for seed in (1, 2):
        ad = _total(name, density, seed)
        fixed = _total(name, density, seed, params=SMRFParameters(adaptive=False))
        assert ad.total < adaptive_max, (seed, ad.total)
        assert fixed.total > fixed_min, (seed, fixed.total)


def test_adaptive_smrf_keeps_the_dense_city():
    c = _total("city", 3.0, 1)
    assert c.total < 0.005 and c.type2 < 0.005


def test_csf_on_the_city_and_forest():
    city = make_landscape("city", size_m=SIZE, density=0.3, seed=1)
    c = confusion(city.ground, classify_ground(city.xyz, city.return_number, city.number_of_returns, method="csf"))
    assert c.total < 0.005  # measured 0.0-0.01 % (at 1-3 pulses/m2 the 1 m cloth sags onto the largest
    # roofs: 10.4-10.7 %, docs/production.md)
    forest = make_landscape("forest", size_m=SIZE, density=3.0, seed=1)
    f = confusion(forest.ground, classify_ground(forest.xyz, forest.return_number, forest.number_of_returns,
                                                 method="csf"))
    assert f.total < 0.01  # measured 0.31 %
    steep = make_landscape("steep", size_m=SIZE, density=3.0, seed=1)
    st = confusion(steep.ground, classify_ground(steep.xyz, steep.return_number, steep.number_of_returns,
                                                 method="csf"))
    assert st.total < 0.01  # measured 0.02 % (the cloth falls on the points less their trend plane;
    # without it 65-80 %, as the reference code's wheel: 57-78 %)


def test_cloth_rests_on_a_plane_and_bridges_a_pit():
    z = np.add.outer(np.zeros(40), 0.1 * np.arange(40))   # a plane rising 0.1 m per cell
    z[15:25, 15:25] += 8.0                                 # a 10-cell roof
    cloth = cloth_surface(z, CSFParameters())              # with the slope post-processing (the default)
    plane = np.add.outer(np.zeros(40), 0.1 * np.arange(40))
    off = np.ones_like(z, bool)
    off[13:27, 13:27] = False
    err = np.abs(cloth[off] - plane[off])
    # some particles stay hanging about one cell's rise (0.1 m) off the plane (measured: 91 of 1404 cells
    # beyond 0.05 m, 0.13 m at most): small groups of movable particles that the reference's post-processing
    # leaves as they are (50 particles or fewer); far below the 0.5 m class threshold
    assert np.mean(err < 0.05) > 0.9 and np.max(err) < 0.15
    # the cloth bridges the roof (measured 0.08 m above the plane) and stays far more than 0.5 m below it
    assert np.max(cloth[18:22, 18:22] - plane[18:22, 18:22]) < 8.0 - 2.0
    # without the post-processing the stiff cloth (the reference's sequential constraints) hangs below
    # the rising plane, as the reference wheel's does on this scene (90 % of the off-roof points within
    # 0.5 m; ours 80 %; measured 1.15 m at the upper edge)
    hang = cloth_surface(z, CSFParameters(slope_smooth=False))
    assert np.max(np.abs(hang[off] - plane[off])) > 0.5


def test_csf_parameters_are_checked():
    with pytest.raises(ValueError, match="rigidness must be 1, 2 or 3, got 4"):
        CSFParameters(rigidness=4)
    with pytest.raises(ValueError, match="method 'csf' takes CSFParameters"):
        classify_ground(np.zeros((3, 3)), method="csf", params=SMRFParameters())
    assert not csf_ground(np.zeros((0, 3))).any()


def test_statistical_outliers_find_birds_and_echoes_not_the_ground():
    ls = make_landscape("low_outliers", size_m=SIZE, density=1.0, seed=2)
    xyz = np.array(ls.xyz)
    rng = np.random.default_rng(3)
    birds = rng.choice(len(xyz), 20, replace=False)
    xyz[birds, 2] += rng.uniform(30.0, 80.0, 20)
    noise = statistical_outliers(xyz)
    assert noise[birds].all()
    assert noise[ls.ground].mean() < 0.001


def test_height_above_ground_is_exact_on_a_plane():
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 50, (3000, 2))
    plane = 100.0 + 0.2 * xy[:, 0] - 0.1 * xy[:, 1]
    above = rng.uniform(0.0, 20.0, 3000)
    is_ground = np.arange(3000) < 1500
    z = np.where(is_ground, plane, plane + above)
    hag = height_above_ground(np.column_stack([xy, z]), is_ground)
    assert np.all(hag[is_ground] == 0.0)
    inside = ~is_ground & np.all((xy > 3.0) & (xy < 47.0), axis=1)   # inside the ground's hull: exact
    np.testing.assert_allclose(hag[inside], above[inside], atol=1e-9)
    outside = ~is_ground & ~inside                                     # the nearest ground point's height
    assert np.max(np.abs(hag[outside] - above[outside])) < 0.2 * 5.0
    assert np.isnan(height_above_ground(np.zeros((2, 3)), np.array([True, True]))).all()


def test_ground_tiles_write_noise_class_and_height_above_ground(tmp_path):
    import laspy

    from lidarcat.production.ground import classify_tiles

    ls = make_landscape("low_outliers", size_m=100.0, density=1.0, seed=4)
    xyz = np.array(ls.xyz) + [500000.0, 7000000.0, 0.0]
    xyz[:5, 2] += 60.0
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = xyz.T
    las.return_number, las.number_of_returns = ls.return_number, ls.number_of_returns
    src = tmp_path / "t.las"
    las.write(src)
    out = classify_tiles([src], tmp_path / "g.las", crs="EPSG:31983", noise=True, hag=True)
    got = laspy.read(out[0])
    cls = np.asarray(got.classification)
    assert (cls[:5] == 7).all() and (cls == 2).sum() > 0.5 * len(cls)
    hag = np.asarray(got.HeightAboveGround)
    assert np.all(hag[cls == 2] == 0.0)
    assert np.all(hag[:5] > 50.0)


def test_noise_points_stay_out_of_the_dsm():
    from lidarcat.lidar.cloud import PointCloud
    from lidarcat.lidar.raster import rasterize

    xy = np.array([[0.5, 0.5], [0.5, 0.5], [1.5, 0.5]])
    z = np.array([10.0, 90.0, 11.0])
    pc = PointCloud(np.column_stack([xy, z]), attributes={"classification": np.array([1, 7, 1], np.uint8)})
    grid, _ = rasterize(pc, 1.0, "dsm", (0.0, 0.0, 2.0, 1.0), fill=None)
    assert grid.tolist() == [[10.0, 11.0]]   # the bird (class 7, 90 m) is no surface


def test_cli_fixed_grid_is_the_non_adaptive_smrf(tmp_path):
    import laspy
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    ls = make_landscape("steep", size_m=100.0, density=0.2, seed=5)
    hdr = laspy.LasHeader(point_format=1, version="1.2")
    hdr.scales = np.array([0.001, 0.001, 0.001])
    hdr.offsets = np.array([500000.0, 7000000.0, 0.0])
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = (np.array(ls.xyz) + [500000.0, 7000000.0, 0.0]).T
    las.return_number, las.number_of_returns = ls.return_number, ls.number_of_returns
    las.write(tmp_path / "t.las")
    back = laspy.read(tmp_path / "t.las")
    xyz = np.column_stack([back.x, back.y, back.z])
    for flag, adaptive in (("--adaptive", True), ("--fixed-grid", False)):
        out = tmp_path / f"g{flag}.las"
        r = CliRunner().invoke(cli, ["lidar", "ground", str(tmp_path / "t.las"), "-o", str(out),
                                     "--crs", "EPSG:31983", flag])
        assert r.exit_code == 0, r.output
        want = classify_ground(xyz, ls.return_number, ls.number_of_returns,
                               params=SMRFParameters(adaptive=adaptive))
        np.testing.assert_array_equal(np.asarray(laspy.read(out).classification) == 2, want)
