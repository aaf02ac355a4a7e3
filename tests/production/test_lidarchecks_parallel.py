"""Swath image and calibration on the tile engine: serial == Dask, tile by tile == all at once."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from lidarcat.lidar import PointCloud, write_points
from lidarcat.production.lidarchecks import georeference
from lidarcat.synthetic.strips import synthetic_strips

CRS = "EPSG:31983"
OFF = np.array([680000.0, 7480000.0, 0.0])


@pytest.fixture(scope="module")
def strips():
    return synthetic_strips(1, spacing_m=3.0)


def _quadrant_tiles(folder: Path, s, *, gps: bool = False) -> list[Path]:
    """The raw strips written as four LAS tiles cut at the median E and N (not cell boundaries)."""
    raw = georeference(s.pulses) + OFF
    attrs = {"point_source_id": s.pulses.strip + 1, "classification": np.full(len(raw), 2, np.uint8)}
    if gps:
        attrs["gps_time"] = s.gps_time_s     # seconds of the week, the trajectory's time base
    ce, cn = np.median(raw[:, 0]) + 0.37, np.median(raw[:, 1]) + 0.21
    out = []
    for i, sel in enumerate(((raw[:, 0] < ce) & (raw[:, 1] < cn), (raw[:, 0] >= ce) & (raw[:, 1] < cn),
                             (raw[:, 0] < ce) & (raw[:, 1] >= cn), (raw[:, 0] >= ce) & (raw[:, 1] >= cn))):
        p = folder / f"t{i}.las"
        write_points(p, PointCloud(raw[sel], {k: v[sel] for k, v in attrs.items()}, crs=CRS))
        out.append(p)
    return out


def test_swath_serial_and_dask_give_the_same_image(tmp_path, strips):
    from lidarcat.lidar.geotiff import read_geotiff
    from lidarcat.stages.lidar import swath_check

    tiles = _quadrant_tiles(tmp_path, strips)
    seen: list[tuple[int, int]] = []
    one = swath_check(tiles, tmp_path / "serial.tif", cell_m=5.0, preview=False,
                      progress=lambda d, n: seen.append((d, n)))
    two = swath_check(tiles, tmp_path / "dask.tif", cell_m=5.0, preview=False, workers=2)
    assert seen == [(1, 4), (2, 4), (3, 4), (4, 4)]
    a, ta, ca = read_geotiff(tmp_path / "serial.tif")
    b, tb, cb = read_geotiff(tmp_path / "dask.tif")
    assert ta == tb and ca == cb
    np.testing.assert_array_equal(a, b)                        # NaN where NaN, the same bits elsewhere
    assert one["swath"] == two["swath"] and one["points"] == two["points"] == len(strips.pulses)
    assert one["swath"]["pass"] is False and one["swath"]["smooth_cells"] > 300   # the planted misalignment
    # the map step's work folder is gone
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())


def test_swath_of_four_tiles_equals_the_points_at_once(tmp_path, strips):
    """The tiles' sums, merged, give the image of all points at once (the cut is at no cell boundary)."""
    from lidarcat.lidar import read_points
    from lidarcat.lidar.geotiff import read_geotiff
    from lidarcat.stages.lidar import swath_check

    tiles = _quadrant_tiles(tmp_path, strips)
    whole = tmp_path / "whole.las"
    write_points(whole, PointCloud.concat([read_points(t) for t in tiles]))
    four = swath_check(tiles, tmp_path / "four.tif", cell_m=5.0, preview=False)
    one = swath_check([whole], tmp_path / "one.tif", cell_m=5.0, preview=False)
    a, _, _ = read_geotiff(tmp_path / "four.tif")
    b, _, _ = read_geotiff(tmp_path / "one.tif")
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], atol=1e-6)   # float32, reference shifts
    assert four["swath"]["smooth_cells"] == one["swath"]["smooth_cells"]
    assert json.loads((tmp_path / "four.json").read_text())["flight_lines"] == [1, 2, 3, 4]


def _four_owners(xy: np.ndarray) -> list[np.ndarray]:
    ce, cn = np.median(xy[:, 0]) + 0.37, np.median(xy[:, 1]) + 0.21
    return [(xy[:, 0] < ce) & (xy[:, 1] < cn), (xy[:, 0] >= ce) & (xy[:, 1] < cn),
            (xy[:, 0] < ce) & (xy[:, 1] >= cn), (xy[:, 0] >= ce) & (xy[:, 1] >= cn)]


def test_two_passes_over_tiles_give_the_estimate_of_all_points_at_once():
    """Observations chosen tile by tile (each tile's own points against all), merged, in two passes: the
    estimate of :func:`estimate_system_parameters` on all pulses, to rounding."""
    from lidarcat.production.lidarchecks import (
        estimate_from_observations,
        estimate_system_parameters,
        merge_observations,
        select_observations,
    )

    s = synthetic_strips(0, length_m=200.0, spacing_m=2.0)
    ref = estimate_system_parameters(s.pulses, s.control_m)
    owners = _four_owners(georeference(s.pulses))
    obs = merge_observations([select_observations(s.pulses, s.control_m, own=o) for o in owners])
    step = estimate_from_observations(obs, s.control_m, max_iter=1)
    obs2 = merge_observations([select_observations(s.pulses, s.control_m, own=o, at=step.parameters)
                               for o in owners])
    res = estimate_from_observations(obs2, s.control_m, start=step.parameters)
    dev = (res.parameters.as_array() - ref.parameters.as_array()) / ref.sd.as_array()
    assert np.all(np.abs(dev) < 1e-6), dev
    np.testing.assert_allclose(res.sd.as_array(), ref.sd.as_array(), rtol=1e-6)
    assert (res.n_control, res.n_strip) == (ref.n_control, ref.n_strip)
    truth = (res.parameters.as_array() - s.truth.as_array()) / res.sd.as_array()
    assert np.all(np.abs(truth) <= 3.0), truth


def test_the_bounded_sample_does_not_depend_on_the_tiling():
    from lidarcat.production.lidarchecks import merge_observations, select_observations

    s = synthetic_strips(0, length_m=120.0, spacing_m=3.0)
    whole = select_observations(s.pulses, s.control_m, max_control=300, max_strip=400)
    tiled = merge_observations([select_observations(s.pulses, s.control_m, own=o, max_control=300, max_strip=400)
                                for o in _four_owners(georeference(s.pulses))], max_control=300, max_strip=400)
    assert whole.point.size == tiled.point.size == 400 and whole.control.size == tiled.control.size == 300
    assert whole.seen_strip == tiled.seen_strip > 800 and whole.seen_control == tiled.seen_control > 900
    np.testing.assert_array_equal(whole.strip_key, tiled.strip_key)      # the same observations, same order
    np.testing.assert_array_equal(whole.control_key, tiled.control_key)
    np.testing.assert_array_equal(whole.pulses.range_m[whole.neighbours], tiled.pulses.range_m[tiled.neighbours])
    assert len(tiled.pulses) < len(s.pulses)                              # only the pulses referred to


def _survey_files(tmp: Path, s, tiles: list[Path]) -> tuple[Path, Path]:
    from lidarcat.lidar.trajectory import Trajectory, write_sbet

    t = s.trajectory
    traj = write_sbet(tmp / "sbet.out", Trajectory(t.time_s, t.position_m + OFF, t.attitude_rad, crs=CRS))
    ctrl = tmp / "runway.csv"
    c = s.control_m + OFF
    ctrl.write_text("id,E,N,H\n" + "".join(f"r{i},{x:.4f},{y:.4f},{z:.4f}\n" for i, (x, y, z) in enumerate(c)),
                    encoding="utf-8")
    return traj, ctrl


def test_calibration_stage_on_tiles_equals_the_in_memory_estimate(tmp_path):
    """The stage's two passes over four tiles (LAS + SBET) give the estimate of all the files' points at once
    (the pulses rebuilt from the points and the trajectory, :func:`estimate_system_parameters`)."""
    from lidarcat.lidar import read_points
    from lidarcat.lidar.trajectory import read_trajectory
    from lidarcat.production.lidarchecks import estimate_system_parameters, pulses_from_points
    from lidarcat.stages.lidar import system_calibration

    s = synthetic_strips(2, length_m=160.0, spacing_m=2.5)
    tiles = _quadrant_tiles(tmp_path, s, gps=True)
    traj, ctrl = _survey_files(tmp_path, s, tiles)
    rep = system_calibration(tiles, traj, tmp_path / "four.json", control=ctrl)
    pc = PointCloud.concat([read_points(t) for t in tiles])
    sensor, att = read_trajectory(traj, CRS).at(pc.attributes["gps_time"])
    pulses, _ = pulses_from_points(pc.xyz, sensor, att, pc.attributes["point_source_id"])
    ref = estimate_system_parameters(pulses, s.control_m + OFF)
    names = ("roll_rad", "pitch_rad", "scale", "bias_m")
    est = np.array([rep["calibration"]["parameters"][n] for n in names])
    dev = (est - ref.parameters.as_array()) / ref.sd.as_array()
    assert np.all(np.abs(dev) < 1e-3), dev          # the runway CSV is written to 0.1 mm
    assert rep["calibration"]["n_strip"] == ref.n_strip and rep["calibration"]["n_control"] == ref.n_control


@pytest.mark.slow
def test_calibration_on_tiles_serial_equals_dask_equals_one_file(tmp_path):
    """Four tiles serially, on two Dask workers, and one file (~60 s at load 6, 17 s CPU; the engine's
    tile-by-tile equality is the fast test above)."""
    from lidarcat.lidar import read_points
    from lidarcat.stages.lidar import system_calibration

    s = synthetic_strips(1, spacing_m=3.0)
    tiles = _quadrant_tiles(tmp_path, s, gps=True)
    traj, ctrl = _survey_files(tmp_path, s, tiles)
    whole = tmp_path / "whole" / "all.las"
    whole.parent.mkdir()
    write_points(whole, PointCloud.concat([read_points(t) for t in tiles]))
    seen: list[tuple[int, int]] = []
    four = system_calibration(tiles, traj, tmp_path / "four.json", control=ctrl, stride=2,
                              progress=lambda d, n: seen.append((d, n)))
    dask = system_calibration(tiles, traj, tmp_path / "dask.json", control=ctrl, stride=2, workers=2)
    one = system_calibration([whole], traj, tmp_path / "one.json", control=ctrl, stride=2)
    assert four["calibration"] == dask["calibration"]                    # bit for bit
    assert seen[:12] == [(i, 22) for i in range(1, 13)] and seen[-1] == (22, 22)
    p4, p1, sd = (np.array([r["calibration"][k][n] for n in ("roll_rad", "pitch_rad", "scale", "bias_m")])
                  for r, k in ((four, "parameters"), (one, "parameters"), (one, "sd")))
    assert np.all(np.abs(p4 - p1) < 1e-6 * sd), (p4 - p1) / sd          # tiles: the same observations
    assert np.all(np.abs(p4 - s.truth.as_array()) < 3 * sd)
    assert four["points"] == one["points"] and 0.45 < four["points"] / len(s.pulses) < 0.55   # stride 2
    assert four["flight_lines"] == [1, 2, 3, 4]
    assert four["observations"]["strip"] == one["observations"]["strip"]
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())
