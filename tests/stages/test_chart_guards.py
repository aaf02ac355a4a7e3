"""Bad contour layers meet the charts (found by the command fuzz run, ``benchmarks/fuzz_commands.py --seed 3
--only chart --case 11``: a JSON ``true`` in a coordinate became a vertex 7,000 km away and
``lidarcat chart`` looped over 28,000 empty sheets)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.errors import FormatError, ProductError
from lidarcat.lidar.geotiff import GeoTransform, write_geotiff
from lidarcat.production.contours import read_line_layer
from lidarcat.stages.products import MAX_CHART_SPAN_M, write_charts

CRS = "EPSG:31982"


def _layer(path, coords):
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"level_m": 10.0, "type": "master"},
         "geometry": {"type": "LineString", "coordinates": c}} for c in coords]}))
    return path


def test_a_boolean_coordinate_is_no_vertex(tmp_path):
    p = _layer(tmp_path / "c.geojson", [[[680000.0, 7184000.0], [680010.0, 7184000.0]],
                                        [[680000.0, 7184000.0], [680001.0, True]]])
    with pytest.raises(FormatError) as e:
        read_line_layer(p)
    assert str(e.value) == (f"{p}: feature 1: not a 2-D LineString (coordinates must be two or more [E, N] "
                            "pairs of finite numbers)")


def test_charts_refuse_a_contour_far_from_the_mosaic(tmp_path):
    mosaic = tmp_path / "m.tif"
    write_geotiff(mosaic, np.full((20, 30), 100.0), GeoTransform(680000.0, 7184000.0, 2.0), CRS)
    feats = [{"type": "Feature", "properties": {"level_m": 10.0, "type": "master"},
              "geometry": {"type": "LineString", "coordinates": c}}
             for c in ([[680000.0, 7183990.0], [680040.0, 7183990.0]], [[680010.0, 7183980.0], [680020.0, 1.0]])]
    with pytest.raises(ProductError) as e:
        write_charts(mosaic, feats, None, tmp_path / "charts", crs=CRS, title=None, size_m=500.0)
    assert str(e.value) == ("charts: the mosaic and the contours span 7184 km (at most "
                            f"{MAX_CHART_SPAN_M / 1000:.0f} km charted); contour feature 1 reaches 7184 km from "
                            "the mosaic's centre: check its coordinates and CRS")
    assert not (tmp_path / "charts").exists()
