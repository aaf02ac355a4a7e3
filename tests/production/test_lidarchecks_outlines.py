"""Planimetric check: building corners from the LiDAR roof edges against surveyed outlines."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from matplotlib.path import Path as MplPath

from lidarcat.errors import ProductError
from lidarcat.lidar import PointCloud, write_points
from lidarcat.production.lidarchecks import lidar_outline_corners, planimetric_accuracy

E0, N0 = 680000.0, 7480000.0
OUTLINES = [np.array([[10, 10], [30, 10], [30, 22], [10, 22.0]]),
            np.array([[50, 10], [70, 10], [70, 30], [62, 30], [62, 18], [50, 18.0]])]   # an L


def _scene(shift, seed=0, density=4.0):
    """Flat roofs 8 m high on flat ground, uniform random points, the LiDAR shifted by *shift* (m)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 80, (int(80 * 80 * density), 2))
    roof = np.zeros(len(xy), bool)
    for o in OUTLINES:
        roof |= MplPath(o).contains_points(xy - shift)
    return np.column_stack([xy, np.where(roof, 8.0, 0.0)]), roof


def test_planted_shift_is_recovered_from_the_corners():
    shift = np.array([0.3, -0.2])
    pts, roof = _scene(shift)
    d = np.vstack([lidar_outline_corners(o, pts[roof], pts[~roof]).discrepancies_m for o in OUTLINES])
    assert np.isfinite(d).all() and d.shape == (10, 2)
    # 4 pts/m2 (0.5 m spacing): a corner to about a decimetre, the mean of ten to a few centimetres
    np.testing.assert_allclose(d.mean(axis=0), shift, atol=0.08)
    acc = planimetric_accuracy(d, scale=5000)
    assert acc["rmse_r_m"] == pytest.approx(np.hypot(*shift), abs=0.1)
    assert acc["pec"]["class"] == {"planimetric": "A"}      # PEC A at 1:5,000: 0.5 mm x 5000 x 0.6 = 1.5 m sd


def test_without_shift_the_corners_agree_and_orientation_does_not_matter():
    pts, roof = _scene(np.zeros(2), seed=1)
    r = lidar_outline_corners(OUTLINES[1], pts[roof], pts[~roof])
    rev = lidar_outline_corners(OUTLINES[1][::-1], pts[roof], pts[~roof])
    np.testing.assert_allclose(rev.lidar_m, r.lidar_m[::-1], atol=1e-9)
    np.testing.assert_allclose(rev.edge_offset_m, np.roll(r.edge_offset_m[::-1], -1), atol=1e-9)
    assert np.sqrt(np.mean(np.sum(r.discrepancies_m ** 2, axis=1))) < 0.15
    # without low points the edge is the outermost roof point + the mean exponential gap 1 / (rho w):
    # unbiased over every edge of three scenes (0.25 m sd per bin, ~300 bins: 0.015 m sd of the mean)
    offs = []
    for seed in (2, 3, 4):
        p2, r2 = _scene(np.zeros(2), seed=seed)
        for o in OUTLINES:
            e = lidar_outline_corners(o, p2[r2], None)
            offs += list(np.repeat(e.edge_offset_m, e.edge_bins))
    assert abs(np.mean(offs)) < 0.05


def test_bad_outline_and_no_corner():
    with pytest.raises(ProductError, match="at least 3 corners, got 2"):
        lidar_outline_corners(np.array([[0, 0], [1, 1], [0, 0.0]]), np.zeros((5, 3)))
    r = lidar_outline_corners(OUTLINES[0], np.zeros((0, 3)))
    assert np.isnan(r.lidar_m).all()
    from lidarcat.errors import AssessmentError

    with pytest.raises(AssessmentError, match="no building corner was found"):
        planimetric_accuracy(r.discrepancies_m)


def test_check_command_with_outlines_geopackage(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    from lidarcat.cli.main import cli
    from lidarcat.production.contours import write_layers

    pts, roof = _scene(np.array([0.3, -0.2]))
    cls = np.where(roof, 6, 2).astype(np.uint8)
    las = tmp_path / "t.las"
    write_points(las, PointCloud(pts + [E0, N0, 0], {"classification": cls}, crs="EPSG:31983"))
    feats = [{"type": "Feature", "properties": {"id": f"b{i + 1}"},
              "geometry": {"type": "Polygon", "coordinates": [(np.vstack([o, o[:1]]) + [E0, N0]).tolist()]}}
             for i, o in enumerate(OUTLINES)]
    gpkg = write_layers(tmp_path / "outlines.gpkg", {"outlines": feats}, "EPSG:31983")
    assert pyogrio.read_info(gpkg)["features"] == 2
    res = CliRunner().invoke(cli, ["lidar", "check", str(las), "--outlines", str(gpkg), "-o",
                                   str(tmp_path / "chk.json"), "--scale", "5000"])
    assert res.exit_code == 0, res.output
    assert "10 building corners (0 not found)" in res.output and "PEC planimetric class: A" in res.output
    rep = json.loads((tmp_path / "chk_planimetric.json").read_text())
    assert [o["id"] for o in rep["outlines"]] == ["b1", "b2"]
    assert rep["planimetric"]["mean_dE_m"] == pytest.approx(0.3, abs=0.08)
    rows = (tmp_path / "chk_corners.csv").read_text().splitlines()
    assert rows[-1].startswith("b2,6,")
    # outlines in another CRS are refused, naming both
    other = write_layers(tmp_path / "o2.gpkg", {"outlines": feats}, "EPSG:31982")
    res = CliRunner().invoke(cli, ["lidar", "check", str(las), "--outlines", str(other), "-o",
                                   str(tmp_path / "x.json")])
    assert res.exit_code != 0 and "the outlines are in EPSG:31982" in res.output, res.output
    res = CliRunner().invoke(cli, ["lidar", "check", str(las), "-o", str(tmp_path / "x.json")])
    assert res.exit_code != 0 and "give --checkpoints" in res.output
