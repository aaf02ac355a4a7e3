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
        attrs["gps_time"] = 2000 * 604800 + s.gps_time_s - 1e9
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
    from lidarcat.lidar.geotiff import read_geotiff
    from lidarcat.lidar import read_points
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
