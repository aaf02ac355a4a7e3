r"""Roof facets from airborne LiDAR: Delaunay triangles, slope, grouping, plane fits.

This chain implements thesis sections 3.2.3-3.2.6 (Fierro Sanhueza 2007) and a
robust alternative that works on steep European roofs; :func:`segment_faces` runs it
on one clip, each step in its module of :mod:`lidarcat.control`:

1. **Clip** the points around the approximate vertex (radius 2.5-5 m in the
   thesis) and optionally pre-filter heights (thesis: mean height +- 2 m):
   :func:`lidarcat.lidar.clip`, settings :class:`~lidarcat.control.params.ExtractionParams`.
2. **Delaunay triangles** of the clip in plan, the plane of each (eq. 25-31) and its
   slope (eq. 32): :mod:`lidarcat.control.triangles`.
3. **Slope window**: faces (and, for the thesis grouping, triangles) outside
   ``[slope_min_deg, slope_max_deg]`` are dropped (thesis 4-30 deg: flat chimney
   tops below, walls above).
4. **Grouping into faces** (``thesis``, ``ransac``, ``region``): :mod:`lidarcat.control.segment`.
5. **Plane fit by the combined (Gauss-Helmert) adjustment** (eq. 33-37) and
6. **iterative rejection** of points: :mod:`lidarcat.control.planes`.

Coordinates are reduced to the clip centroid internally, so national grid
coordinates (E ~ 7e6 m) lose no precision; the planes are returned in the outer frame.

The names of the steps' modules (:class:`Plane`, :func:`fit_plane`, :func:`delaunay_facets`,
:func:`get_params`, ...) stay importable from here (they were defined here before issue 23).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .params import PRESETS, ExtractionParams, get_params
from .planes import Plane, PlaneFit, fit_plane, translated
from .segment import group_faces
from .triangles import delaunay_facets, triangle_planes, triangle_slope_aspect

__all__ = [
    "Plane",
    "ExtractionParams",
    "PRESETS",
    "get_params",
    "triangle_planes",
    "triangle_slope_aspect",
    "delaunay_facets",
    "fit_plane",
    "PlaneFit",
    "segment_faces",
]


def segment_faces(xyz: Any, params: ExtractionParams | str | None = None) -> tuple[list[Plane], np.ndarray, dict[str, Any]]:
    """Group the points of a clip into roof faces and fit a plane to each.

    Parameters
    ----------
    xyz : (N, 3) float
        Clip points (already pre-filtered).
    params : ExtractionParams or preset name

    Returns
    -------
    planes : list of Plane
        Faces in the slope window, largest first, at most ``params.max_planes``.
    labels : (N,) int
        Face index per point into *planes* (-1: unused / rejected).
    info : dict
        Counts for diagnostics (flat and steep elements, noise estimate...).
    """
    p = get_params(params)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    origin = xyz.mean(axis=0) if len(xyz) else np.zeros(3)
    loc = xyz - origin
    faces, info = group_faces(loc, p, grid_origin_m=origin[:2])
    extent = info.pop("extent_idx", None)
    faces = [(pl, idx, idx if extent is None else extent[k]) for k, (pl, idx) in enumerate(faces)]
    faces = [f for f in faces if p.slope_min_deg < f[0].slope_deg < p.slope_max_deg]
    faces.sort(key=lambda f: -f[0].n_used)
    faces = faces[: p.max_planes]
    out_labels = np.full(len(xyz), -1)
    ext_labels = np.full(len(xyz), -1)
    planes = []
    for k, (pl, idx, ext) in enumerate(faces):
        ext_labels[ext] = k
    for k, (pl, idx, ext) in enumerate(faces):
        out_labels[idx] = k
        planes.append(translated(pl, origin, label=k))
    info["n_faces"] = len(planes)
    if extent is not None:
        info["extent_labels"] = ext_labels
    return planes, out_labels, info
