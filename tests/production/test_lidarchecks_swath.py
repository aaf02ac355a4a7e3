"""Swath separation images: synthetic strips with a planted misalignment, a planted offset, AHN3, the command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.errors import ProductError
from lidarcat.lidar import PointCloud, write_points
from lidarcat.production.lidarchecks import georeference
from lidarcat.production.swath import INTERSWATH_LIMITS, swath_separation
from lidarcat.synthetic.strips import strip_terrain, synthetic_strips

DATA = Path(__file__).resolve().parents[1] / "data" / "lidar"


@pytest.fixture(scope="module")
def strips():
    return synthetic_strips(1, spacing_m=2.0)


def test_usgs_interswath_limits():
    assert INTERSWATH_LIMITS["QL2"] == (0.08, 0.16)
    assert INTERSWATH_LIMITS["QL1"] == (0.06, 0.12)


def test_calibrated_strips_pass_and_raw_strips_fail(strips):
    good = swath_separation(georeference(strips.pulses, strips.truth), strips.pulses.strip, 5.0).assess("QL2")
    raw = swath_separation(georeference(strips.pulses), strips.pulses.strip, 5.0).assess("QL2")
    assert good["pass"] is True and good["rmsdz_m"] < 0.025     # 2 cm range noise, planes of ~6 points
    assert raw["pass"] is False and raw["rmsdz_m"] > 0.08 and raw["max_abs_dz_m"] > 0.16
    assert good["smooth_cells"] > 1000 and set(good["pairs"]) >= {"0-1", "1-2"}


def test_difference_is_the_difference_of_the_lines_height_errors(strips):
    """On the runway (flat) the cell value is line low's mean height error minus line high's, sign included."""
    raw = georeference(strips.pulses)
    sep = swath_separation(raw, strips.pulses.strip, 5.0)
    err = raw[:, 2] - strip_terrain(raw[:, 0], raw[:, 1])        # the planted misalignment, point by point
    row, col = sep.transform.rowcol(raw[:, 0], raw[:, 1])
    cell = row * sep.dz_m.shape[1] + col
    key = cell * 8 + strips.pulses.strip
    keys, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    means = dict(zip(keys.tolist(), (np.bincount(inv, weights=err) / cnt).tolist()))
    rows, cols = np.nonzero(sep.smooth)
    cx, cy = sep.transform.xy(rows, cols)
    runway = cy < -30
    checked = 0
    diffs = []
    for r, c in zip(rows[runway], cols[runway]):
        k = r * sep.dz_m.shape[1] + c
        present = [s for s in range(4) if k * 8 + s in means]
        if len(present) != 2:
            continue
        lo, hi = present
        diffs.append(sep.dz_m[r, c] - (means[k * 8 + lo] - means[k * 8 + hi]))
        checked += 1
    assert checked > 150
    # planes vs means of ~6 noisy points (2 cm range noise): agree to the noise, no sign flip
    assert np.sqrt(np.mean(np.square(diffs))) < 0.02


def test_planted_offset_of_one_line(strips):
    p = georeference(strips.pulses, strips.truth)
    p[strips.pulses.strip == 1, 2] += 0.20
    sep = swath_separation(p, strips.pulses.strip, 5.0)
    st = sep.assess("QL2")
    assert st["pass"] is False
    # cells of the pair 0-1 hold line 0 minus line 1 = -0.20 m
    pair01 = np.isfinite(sep.dz_m) & sep.smooth
    vals = sep.dz_m[pair01]
    assert np.sum(np.abs(vals + 0.20) < 0.06) > 300          # 0-1 cells
    assert np.sum(np.abs(vals - 0.20) < 0.06) > 200          # 1-2 and 1-3 cells (1 is the lower id)


def test_one_flight_line_is_refused():
    with pytest.raises(ProductError, match=r"at least two flight lines .* all 10 points are of line 5"):
        swath_separation(np.zeros((10, 3)), np.full(10, 5), 1.0)


def test_command_writes_geotiff_with_crs_png_and_report(tmp_path, strips):
    from lidarcat.cli.main import cli
    from lidarcat.lidar.geotiff import read_geotiff

    off = np.array([680000.0, 7480000.0, 0.0])
    las = tmp_path / "strips.las"
    write_points(las, PointCloud(georeference(strips.pulses) + off, {"point_source_id": strips.pulses.strip + 1},
                                 crs="EPSG:31983"))
    res = CliRunner().invoke(cli, ["lidar", "swath", str(las), "-o", str(tmp_path / "sw.tif"), "--cell", "5",
                                   "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert rep["swath"]["pass"] is False and rep["classes"] is None     # unclassified: every last return
    grid, transform, crs = read_geotiff(tmp_path / "sw.tif")
    assert crs.to_epsg() == 31983 and transform.cell_m == 5.0
    assert np.isfinite(grid).sum() == rep["swath"]["overlap_cells"]
    assert (tmp_path / "sw.png").stat().st_size > 10_000
    assert json.loads((tmp_path / "sw.json").read_text())["flight_lines"] == [1, 2, 3, 4]


def test_ahn3_tile_2_ground_passes_ql2(tmp_path):
    """AHN3 tile 2: flight lines 57138 and 57139 overlap; ground last returns, 1 m cells."""
    from lidarcat.stages.lidar import swath_check

    rep = swath_check([DATA / "ahn3_cropped_2.laz"], tmp_path / "sw.tif", crs="EPSG:7415")
    st = rep["swath"]
    assert rep["classes"] == [2] and rep["flight_lines"] == [57138, 57139]
    assert 0.02 < st["rmsdz_m"] < 0.05 and st["pass"] is True     # measured 3.5 cm, max 8.1 cm
    assert rep["crs"] == "EPSG:7415 (Amersfoort / RD New + NAP height)"


def test_tile_by_tile_equals_all_at_once(tmp_path):
    """AHN3 tile 1 cut in two at an E that is not a cell boundary: the streamed sums give the same image."""
    from lidarcat.lidar import read_points
    from lidarcat.lidar.geotiff import read_geotiff
    from lidarcat.stages.lidar import swath_check

    src = DATA / "ahn3_cropped_1.laz"
    pc = read_points(src, crs="EPSG:7415")
    cut = float(np.median(pc.xyz[:, 0])) + 0.37
    parts = []
    for name, sel in (("w", pc.xyz[:, 0] < cut), ("e", pc.xyz[:, 0] >= cut)):
        p = tmp_path / f"{name}.las"
        write_points(p, pc.select(sel))
        parts.append(p)
    seen = []
    two = swath_check(parts, tmp_path / "two.tif", preview=False, progress=lambda d, n: seen.append((d, n)))
    one = swath_check([src], tmp_path / "one.tif", crs="EPSG:7415", preview=False)
    assert seen == [(1, 2), (2, 2)]
    a, ta, _ = read_geotiff(tmp_path / "one.tif")
    b, tb, _ = read_geotiff(tmp_path / "two.tif")
    assert ta == tb and a.shape == b.shape
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], atol=2e-3)   # LAS 1 mm rewrite
    assert one["swath"]["smooth_cells"] == two["swath"]["smooth_cells"]
