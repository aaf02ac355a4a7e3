"""Shared geometry of every stage: the camera, the collinearity equations.

================  ============================================================
``camera``        Interior orientation of a non-metric digital camera (thesis section 2.1.1, eq. 01-07).
``collinearity``  Collinearity equations, rotation matrices and their analytic derivatives.
================  ============================================================
"""

from __future__ import annotations

from .camera import (  # noqa: F401
    Camera,
    load_cameras,
    load_camera,
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

__all__ = [
    'Camera',
    'load_cameras',
    'load_camera',
    'CAMERA_KEYS',
    'SD_KEYS',
    'block_sum',
    'rotation_matrix',
    'rotation_and_derivatives',
    'project',
    'project_with_jacobians',
]
