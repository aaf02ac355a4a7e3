"""Heights: per-source declarations, geoid grids through PROJ (a synthetic GTX with a known
plane of undulations, so bilinear interpolation is exact), compound and SIRGAS 2000 CRSs."""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from pyproj import Transformer

from lidarcat.interop.heights import (
    HeightError,
    convert_heights,
    geoid_undulation,
    harmonise_ground_points,
    height_system_of_crs,
    read_height_declarations,
)
from lidarcat.survey.folder import Survey, thesis_survey_path


def _n_plane(lat, lon):
    """The synthetic geoid: N = 3 + 0.5 (lat + 26) - 0.25 (lon + 50) metres."""
    return 3.0 + 0.5 * (np.asarray(lat) + 26.0) - 0.25 * (np.asarray(lon) + 50.0)


def _gtx(path: Path) -> Path:
    """A NOAA .gtx grid: header (lat0, lon0, dlat, dlon as >f8; rows, cols as >i4), rows from south."""
    lat0, lon0, d, rows, cols = -26.0, -50.0, 0.05, 41, 41
    lat = lat0 + d * np.arange(rows)
    lon = lon0 + d * np.arange(cols)
    vals = _n_plane(lat[:, None], lon[None, :]).astype(">f4")
    path.write_bytes(struct.pack(">ddddii", lat0, lon0 + 360.0, d, d, rows, cols) + vals.tobytes())
    return path


def test_height_system_of_crs():
    assert height_system_of_crs("EPSG:7415") == "orthometric"
    assert height_system_of_crs("EPSG:4979") == "ellipsoidal"
    assert height_system_of_crs("EPSG:31982") is None
    assert height_system_of_crs("EPSG:29192") is None


def test_sirgas2000_utm_conversion_with_grid(tmp_path):
    grid = _gtx(tmp_path / "geoid.gtx")
    e, n = np.array([677000.0, 680000.0]), np.array([7183000.0, 7190000.0])
    lon, lat = Transformer.from_crs("EPSG:31982", "EPSG:4674", always_xy=True).transform(e, n)
    np.testing.assert_allclose(geoid_undulation(e, n, "EPSG:31982", grid), _n_plane(lat, lon), rtol=0, atol=1e-5)
    h = np.array([910.0, 920.0])
    big_h = convert_heights(e, n, h, "EPSG:31982", "ellipsoidal", "orthometric", grid)
    np.testing.assert_allclose(big_h, h - _n_plane(lat, lon), rtol=0, atol=1e-5)
    np.testing.assert_allclose(convert_heights(e, n, big_h, "EPSG:31982", "orthometric", "ellipsoidal", grid), h,
                               rtol=0, atol=1e-9)
    with pytest.raises(HeightError, match="ellipsoidal -> orthometric heights need a geoid model"):
        convert_heights(e, n, h, "EPSG:31982", "ellipsoidal", "orthometric", None)


def _survey_copy(tmp_path: Path, heights: str, crs: str | None = None, system: str | None = None) -> Path:
    d = shutil.copytree(thesis_survey_path(), tmp_path / "s")
    t = (d / "survey.toml").read_text()
    if crs:
        t = t.replace('crs = "EPSG:29192"', f'crs = "{crs}"')
    if system:
        t = t.replace('height_system = "orthometric"', f'height_system = "{system}"')
    (d / "survey.toml").write_text(t + "\n" + heights)
    return d


def test_mixing_refused_without_grid_and_converted_with_it(tmp_path):
    d = _survey_copy(tmp_path, '[heights]\nsources = { lidar = "ellipsoidal" }\n')
    with pytest.raises(HeightError) as ei:
        harmonise_ground_points(d)
    assert ("18 ground point(s) of source 'lidar' have ellipsoidal heights, the survey works in orthometric "
            "heights, and no geoid model is given") in str(ei.value)
    _gtx(d / "geoid.gtx")
    (d / "survey.toml").write_text((d / "survey.toml").read_text() + 'geoid_grid = "geoid.gtx"\n')
    gp, report = harmonise_ground_points(d)
    s = Survey.load(d)
    lidar = s.ground_points.source == "lidar"
    lon, lat = Transformer.from_crs("EPSG:29192", "EPSG:4618", always_xy=True).transform(
        s.ground_points.enh_m[lidar, 0], s.ground_points.enh_m[lidar, 1])
    np.testing.assert_allclose(gp.enh_m[lidar, 2], s.ground_points.enh_m[lidar, 2] - _n_plane(lat, lon),
                               rtol=0, atol=1e-5)
    np.testing.assert_array_equal(gp.enh_m[~lidar], s.ground_points.enh_m[~lidar])
    assert report["gps"]["from"] == "orthometric" and report["lidar"]["n"] == 18


def test_declaration_errors(tmp_path):
    d = _survey_copy(tmp_path, '[heights]\nsources = { lidar = "geoidal" }\n')
    with pytest.raises(HeightError, match=r"survey.toml:\d+: field 'sources': source 'lidar': 'geoidal' is not"):
        read_height_declarations(d)


def test_compound_crs_contradiction(tmp_path):
    # thesis coordinates: a compound CRS whose area of use holds them (SAD69 / UTM 22S + EGM96 height)
    d = _survey_copy(tmp_path, "", crs="EPSG:29192+5773", system="ellipsoidal")
    with pytest.raises(HeightError, match=r"survey.toml:\d+: field 'height_system': 'ellipsoidal' contradicts "
                                          r"the CRS EPSG:29192\+5773, whose heights are orthometric"):
        read_height_declarations(d)
