"""Shared geometry of every stage: the camera, the collinearity equations, the TIN locator.

================  ============================================================
``camera``        Interior orientation of a non-metric digital camera (thesis section 2.1.1, eq. 01-07).
``collinearity``  Collinearity equations, rotation matrices and their analytic derivatives.
``tin``           One Delaunay point locator (a walk) and barycentric weights, for every TIN surface.
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
from .tin import TinLocator, barycentric, find_simplex  # noqa: F401

__all__ = [
    'TinLocator',
    'barycentric',
    'find_simplex',
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
