"""Ground classification (PTD, SMRF): synthetic truth, AHN3 reference, LAS copies, tile seams."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from scipy.spatial import Delaunay

from lidarcat.lidar import read_points
from lidarcat.geometry.tin import find_simplex as _locate
from lidarcat.production.ground import (PTDParameters, SMRFParameters, classify_ground, classify_tiles,
                                   confusion, ptd_ground, write_classified_copy)

DATA = Path(__file__).parents[1] / "data" / "lidar"
AHN2 = DATA / "ahn3_cropped_2.laz"


def _scene(seed: int = 3, n: int = 15_000):
    """Hilly sloped terrain with two buildings, trees (two returns) and three low outliers."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 150, (n, 2))
    terrain = 0.08 * xy[:, 0] + 3.0 * np.sin(xy[:, 1] / 25.0)
    h = terrain.copy()
    bld = ((abs(xy[:, 0] - 40) < 12) & (abs(xy[:, 1] - 50) < 9)) | ((abs(xy[:, 0] - 110) < 20) & (abs(xy[:, 1] - 100) < 15))
    h[bld] += 7.0
    tree = (np.hypot(xy[:, 0] - 80, xy[:, 1] - 30) < 6) & ~bld
    canopy = tree & (rng.random(n) < 0.6)
    h[canopy] += rng.uniform(3, 9, canopy.sum())
    rn = np.ones(n, dtype=np.uint8)
    nr = np.ones(n, dtype=np.uint8)
    nr[tree] = 2
    rn[tree & ~canopy] = 2          # ground under the tree: last of two returns
    rn[canopy] = 1                  # canopy hit, not last
    truth = ~bld & ~canopy
    low = np.array([5, 6, 7])
    h[low] -= 8.0
    truth[low] = False
    return np.column_stack([xy, h]), rn, nr, truth


@pytest.mark.parametrize("method, min_kappa", [("ptd", 0.97), ("smrf", 0.9)])
def test_synthetic_scene_classified_against_truth(method, min_kappa):
    xyz, rn, nr, truth = _scene()
    g = classify_ground(xyz, rn, nr, method=method)
    c = confusion(truth, g)
    assert c.total < 0.01 and c.kappa > min_kappa, c.to_dict()
    assert not g[[5, 6, 7]].any()  # low outliers are never ground


def test_only_last_returns_can_be_ground():
    xyz, rn, nr, _ = _scene(n=10_000)
    g = ptd_ground(xyz, rn, nr)
    assert not g[rn < nr].any()


def test_locate_matches_scipy_find_simplex():
    rng = np.random.default_rng(0)
    tri = Delaunay(rng.uniform(0, 100, (2000, 2)))
    q = np.vstack([rng.uniform(-5, 105, (3000, 2))])
    np.testing.assert_array_equal(_locate(tri, q), tri.find_simplex(q))


def test_confusion_errors_and_kappa():
    ref = np.array([True] * 90 + [False] * 10)
    cls = ref.copy()
    cls[:3] = False      # 3 ground rejected
    cls[95:] = True      # 5 objects accepted
    c = confusion(ref, cls)
    assert (c.type1, c.type2, c.total) == (3 / 90, 5 / 10, 8 / 100)
    po, pe = 0.92, 0.9 * 0.92 + 0.1 * 0.08
    assert c.kappa == pytest.approx((po - pe) / (1 - pe), abs=1e-12)


def test_bad_parameters_named():
    with pytest.raises(ValueError, match="iteration_angle_deg must be below 90"):
        PTDParameters(iteration_angle_deg=95)
    with pytest.raises(ValueError, match="max_building_m must be a positive number"):
        PTDParameters(max_building_m=0)
    with pytest.raises(ValueError, match="window_m must be a positive number"):
        SMRFParameters(window_m=-1)
    with pytest.raises(ValueError, match="unknown ground method 'tin'; use one of ptd, smrf, csf"):
        classify_ground(np.zeros((3, 3)), method="tin")


def _crop(tmp_path: Path, name: str, box: tuple[float, float, float, float]) -> Path:
    las = laspy.read(str(AHN2))
    x, y = np.asarray(las.x), np.asarray(las.y)
    m = (x >= box[0]) & (x < box[2]) & (y >= box[1]) & (y < box[3])
    out = laspy.LasData(las.header)
    out.points = las.points[m]
    p = tmp_path / name
    out.write(str(p))
    return p


@pytest.mark.slow
def test_ahn3_against_the_providers_ground_class():
    """AHN3 tile 2 (Delft): the Dutch provider's class 2 is the reference; total error < 5 %.

    Measured (docs/production.md): SMRF 2.90 % total, kappa 0.941.  PTD with
    TerraScan's defaults reaches 5.05 % there (Type I 5.1 %, Type II 5.0 %): not asserted.
    """
    pc = read_points(AHN2, crs="EPSG:7415")
    a = pc.attributes
    g = classify_ground(pc.xyz, a["return_number"], a["number_of_returns"], method="smrf")
    c = confusion(a["classification"] == 2, g)
    assert c.total == pytest.approx(0.0290, abs=0.0015) and c.kappa == pytest.approx(0.941, abs=0.0015)


def test_copy_keeps_other_classes_and_input_and_ignores_input_classes(tmp_path):
    src = _crop(tmp_path, "crop.laz", (85000, 447420, 85070, 447480))
    before = src.read_bytes()
    out1 = classify_tiles([src], tmp_path / "out1.laz", crs="EPSG:7415", method="smrf")[0]
    assert src.read_bytes() == before                       # input untouched
    # scramble the input's classes: the result must not change (the filter never reads them)
    las = laspy.read(str(src))
    rng = np.random.default_rng(1)
    las.classification = rng.choice(np.array([1, 2, 6, 9], dtype=np.uint8), len(las.points))
    scrambled = tmp_path / "scrambled.laz"
    las.write(str(scrambled))
    out2 = classify_tiles([scrambled], tmp_path / "out2.laz", crs="EPSG:7415", method="smrf")[0]
    c1 = np.asarray(laspy.read(str(out1)).classification)
    c2 = np.asarray(laspy.read(str(out2)).classification)
    np.testing.assert_array_equal(c1 == 2, c2 == 2)
    orig = np.asarray(laspy.read(str(src)).classification)
    keep = (orig != 2) & (c1 != 2)
    np.testing.assert_array_equal(c1[keep], orig[keep])     # other classes kept
    assert set(np.unique(c1[(orig == 2) & (c1 != 2)])) <= {1}
    with pytest.raises(ValueError, match="overwrite the input"):
        write_classified_copy(src, src, c1 == 2)


@pytest.mark.parametrize("method", ["smrf", pytest.param("ptd", marks=pytest.mark.slow)])
def test_tile_seams_do_not_change_the_result(tmp_path, method):
    """Two tiles classified with their overlap give what the merged area gives."""
    top = 447540 if method == "smrf" else 447470        # PTD is slower: a smaller area
    whole = _crop(tmp_path, "whole.laz", (85000, 447412, 85072.3, top))
    west = _crop(tmp_path, "west.laz", (85000, 447412, 85036, top))
    east = _crop(tmp_path, "east.laz", (85036, 447412, 85072.3, top))
    p = PTDParameters(max_building_m=30.0) if method == "ptd" else None
    ref = classify_tiles([whole], tmp_path / "ref.laz", crs="EPSG:7415", method=method, params=p)[0]
    outs = classify_tiles([west, east], tmp_path / "tiles", crs="EPSG:7415", method=method, params=p)
    def keyed(lasses):
        cols = [np.concatenate([np.asarray(getattr(las, f)) for las in lasses])
                for f in ("X", "Y", "Z", "gps_time", "return_number", "classification")]
        order = np.lexsort(cols[:5][::-1])
        return [c[order] for c in cols]
    r = keyed([laspy.read(str(ref))])
    t = keyed([laspy.read(str(o)) for o in outs])
    for a, b in zip(r[:5], t[:5]):
        np.testing.assert_array_equal(a, b)                 # same points
    diff = np.mean((r[5] == 2) != (t[5] == 2))
    assert diff < 0.002, diff


def test_low_outliers_single_pairs_and_a_ditch():
    """Grid low-outlier test: an isolated low point, a pair of different depths in one block
    (found by the repeated pass), and a one-cell-wide ditch left alone (it is ground)."""
    from lidarcat.production.ground import _low_outliers

    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 60, (36000, 2))
    z = 100 + 0.1 * xy[:, 0] + rng.normal(0, 0.03, len(xy))
    ditch = np.abs(xy[:, 0] - 30.3) < 0.4  # 0.8 m wide, 1.5 m deep, along y
    z[ditch] -= 1.5
    xyz = np.column_stack([xy, z])
    lone = np.array([[10.2, 10.2, 100.0 + 1.02 - 8.0]])  # 8 m below the terrain
    pair = np.array([[45.3, 45.3, 100.0 + 4.53 - 12.0], [45.8, 45.6, 100.0 + 4.58 - 6.0]])
    allp = np.vstack([xyz, lone, pair])
    found = _low_outliers(allp, np.arange(len(allp)), 1.0, 1.0)
    n = len(xyz)
    assert set(found.tolist()) == {n, n + 1, n + 2}
    g = classify_ground(allp)
    assert not g[n:].any()
    assert g[:n][ditch].mean() > 0.99  # the pit test leaves a ditch one cell wide alone
    # measured 98.4 %: bank points in the 1 m cells the ditch shares are judged against the
    # ditch's height (SMRF's minimum grid), all within 1 m west of it
    assert g[:n][~ditch].mean() > 0.975


def test_cli_ground_defaults_are_the_library_defaults():
    """`lidarcat lidar ground` must classify as `classify_ground` does by default (the CLI once
    kept an 18 m SMRF window after the library moved to 40 m and classified large roofs as ground)."""
    import dataclasses

    from lidarcat.cli.main import cli
    from lidarcat.production.ground import PTDParameters, SMRFParameters

    import click

    ctx = click.Context(cli)
    ground_cmd = cli.get_command(ctx, "lidar").get_command(ctx, "ground")
    opts = {p.name: p.default for p in ground_cmd.params}
    smrf, ptd = SMRFParameters(), PTDParameters()
    assert opts["window_m"] == smrf.window_m
    assert opts["slope"] == smrf.slope
    assert opts["elevation_threshold_m"] == smrf.elevation_threshold_m
    ptd_fields = {f.name for f in dataclasses.fields(ptd)}
    for name in ("max_building_m", "iteration_angle_deg", "iteration_distance_m"):
        assert name in ptd_fields
        assert opts[name] == getattr(ptd, name), name
