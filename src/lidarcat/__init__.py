"""lidarcat: LiDAR-controlled aerial triangulation.

The pipeline, one module per stage:

=================  =========================================================
``camera``         interior orientation of a non-metric camera (eq. 01-07)
``survey``         the survey folder: load, validate, write results
``lidar``          LiDAR tiles (LAS/LAZ/COPC/ASCII), tile index, clips, rasters
``facets``         Delaunay roof facets, slope filter, plane fitting (eq. 25-37)
``control``        plane intersection into control points (eq. 38-41)
``bundle``         bundle adjustment with weighted position constraints (eq. 08-22)
``accuracy``       discrepancies, Filliben, t, chi-square, K-S, Hotelling; standards
``report``         HTML / Markdown / JSON report
``pipeline``       the whole chain (``lidarcat run``)
=================  =========================================================

Public names are imported lazily so ``import lidarcat`` stays fast.
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
    "Camera": "geometry", "load_cameras": "geometry",
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
