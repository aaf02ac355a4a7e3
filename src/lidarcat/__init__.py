"""lidarcat: LiDAR-controlled aerial triangulation.

The house by stage, one package per stage of the pipeline (docs/layout.md):

=================  ============================================================
``errors``         the exception hierarchy: :class:`LidarcatError` and its located subclasses
``testing``        assertions for tests of code built on lidarcat
``_util/``         atomic writes, located reads, CSV/TOML/JSON tables, frozen value types
``geometry/``      the camera (interior orientation, eq. 01-07), collinearity equations
``survey/``        the survey folder: load, validate; survey -> bundle problem, tables out
``photos/``        photo files: header (size, truncation), EXIF focal length and GNSS position
``match/``         stage match: automatic tie points (SIFT, footprint pairs, guided matching, tracks)
``lidar/``         LiDAR data access (LAS/LAZ/COPC/ASCII, CRS, tile index, clips, rasters),
                   the tile engine
``control/``       stage extract: roof facets, plane intersection into control points
                   (eq. 25-41)
``photocontrol/``  stage measure-control: LiDAR roof vertices predicted and measured in the photos
``bundle/``        the bundle adjustment engine with weighted constraints (eq. 08-22)
``accuracy/``      stage assess: discrepancies, Filliben, t, chi-square, K-S, Hotelling;
                   PEC, ASPRS, NSSDA
``mapping/``       stage mapping: monorestitution, orthophotos, mosaics
``production/``    stage products: ground, DTM/DSM, contours, hypsometry, map sheets
``interop/``       other programs' files in and out (COLMAP, OpenSfM, ODM, Metashape, ...)
``report/``        the accuracy report and the pipeline report (HTML, Markdown, JSON)
``stages/``        one action per stage (survey folder in, stage folder out)
``pipeline/``      the stage runner and the whole chain (``lidarcat run``)
``synthetic/``     data with known truth for the demo, the tests and the benchmarks
``cli/``           the ``lidarcat`` command line
=================  ============================================================

The imports go one way: engines <- stage actions (``stages``) <- ``cli`` and ``pipeline``;
the engine never imports ``survey``.  Public names are imported lazily so
``import lidarcat`` stays fast.
"""

from __future__ import annotations

import importlib
import logging
from typing import Any

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())

#: public name -> module that defines it
_EXPORTS: dict[str, str] = {
    # errors
    "LidarcatError": "errors", "SurveyError": "errors", "CameraError": "errors",
    "LidarFormatError": "errors", "TileIOError": "errors", "CRSError": "errors",
    "ClipError": "errors", "DatumError": "errors", "ExtractionError": "errors",
    "AssessmentError": "errors",
    # camera / survey
    "Camera": "geometry", "load_cameras": "survey",
    "Survey": "survey", "thesis_survey_path": "survey", "example_camera_path": "survey",
    # bundle adjustment
    "ExteriorOrientation": "bundle", "BundleProblem": "bundle", "BundleResult": "bundle",
    "adjust": "bundle", "adjust_survey": "survey", "problem_from_survey": "survey",
    "check_datum": "bundle", "write_adjustment": "survey",
    # lidar
    "PointCloud": "lidar", "read_points": "lidar", "TileIndex": "lidar",
    # roof facets and control points
    "Plane": "control", "extract_roof": "control", "find_candidates": "control",
    "ControlPoint": "control", "intersect_planes": "control",
    # accuracy
    "assess": "accuracy", "Assessment": "accuracy", "write_report": "report",
    # the whole chain and the synthetic survey
    "run_pipeline": "pipeline", "PipelineResult": "pipeline",
    "write_synthetic_survey": "synthetic",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        module = importlib.import_module(f".{_EXPORTS[name]}", __name__)
        value = getattr(module, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'lidarcat' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
