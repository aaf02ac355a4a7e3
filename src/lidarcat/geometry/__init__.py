"""Shared geometry of every stage: the camera and its models, the collinearity equations, the TIN locator.

================  ============================================================
``camera``        Interior orientation of a non-metric digital camera (thesis section 2.1.1, eq. 01-07).
``collinearity``  Collinearity equations, rotation matrices and their analytic derivatives.
``models``        Camera models as a family: frame (the thesis camera), normalised Brown, fisheye (Kannala-Brandt).
``modelbase``     What every camera model shares: the CameraModel interface, array shapes, value and ray checks.
``brown``         The normalised Brown-Conrady camera (OpenCV, COLMAP, OpenSfM/ODM, Metashape).
``fisheye``       The equidistant Kannala-Brandt fisheye (OpenCV fisheye, COLMAP OPENCV_FISHEYE, OpenSfM).
``conversion``    Conversions between camera models (exact, or fitted with their residual); COLMAP and Metashape parameters.
``apsets``        Self-calibration parameter sets by name (thesis, brown, ebner, gruen) and their correction polynomials.
``rolling``       Rolling shutter: projection with the row's read-out time solved, and its Jacobians.
``rigs``          Camera rigs: sensors with fixed relative poses moved as one body per exposure, and Jacobians.
``tin``           One Delaunay point locator (a walk) and barycentric weights, for every TIN surface.
================  ============================================================

Private: ``_distortion_limits`` (whether a frame camera's distortion can be inverted over its frame),
``_camera_tables`` (a camera's ``camera.toml`` table: its keys, ``Camera.from_dict``/``to_dict``/``to_toml``;
the files are read by :mod:`lidarcat.survey.cameras`).
"""

from __future__ import annotations

from .camera import (  # noqa: F401
    Camera,
    CAMERA_KEYS,
    SD_KEYS,
)
from .collinearity import (  # noqa: F401
    block_sum,
    rotation_matrix,
    rotation_and_derivatives,
    project,
    project_with_jacobians,
)
from .models import BrownCamera, CameraModel, FisheyeCamera, FrameModel, MODELS, camera_model  # noqa: F401
from .conversion import (Conversion, convert, from_colmap, to_colmap, from_metashape, to_metashape,  # noqa: F401
                         image_plane_observations)
from .rigs import Rig, project_rig  # noqa: F401
from .tin import TinLocator, barycentric, find_simplex  # noqa: F401

__all__ = [
    'BrownCamera',
    'CameraModel',
    'FisheyeCamera',
    'FrameModel',
    'MODELS',
    'camera_model',
    'Conversion',
    'convert',
    'from_colmap',
    'to_colmap',
    'from_metashape',
    'to_metashape',
    'image_plane_observations',
    'Rig',
    'project_rig',
    'TinLocator',
    'barycentric',
    'find_simplex',
    'Camera',
    'CAMERA_KEYS',
    'SD_KEYS',
    'block_sum',
    'rotation_matrix',
    'rotation_and_derivatives',
    'project',
    'project_with_jacobians',
]
