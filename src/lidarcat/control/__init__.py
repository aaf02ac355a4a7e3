"""Stage ``extract``: LiDAR roof facets -> roof vertices -> control points (thesis 3.2, eq. 25-41).

============  ============================================================
``facets``    Roof facets from airborne LiDAR: the chain triangles -> slope -> grouping -> plane fits.
``params``    :class:`ExtractionParams`, the settings of one extraction, and its presets.
``triangles`` Delaunay triangles of a clip with plane, slope and aspect (eq. 25-32).
``segment``   Grouping the points into faces: thesis, RANSAC, region growing.
``planes``    :class:`Plane` and its Gauss-Helmert fit with rejection (eq. 33-37).
``vertices``  Control points from roof planes: intersection (eq. 38-41) with covariance.
``localfit``  The vertex from the roof near it: extracted again from a fixed clip centred on it (``fit_radius_m``).
``stability`` Radius stability of a roof vertex: the same corner from nested clips, and the test of how far it moved.
``batch``     Batch roof extraction: job files, tiles, output tables, operator figures.
``search``    Tile-parallel roof-vertex search: :func:`~lidarcat.control.vertices.find_candidates` over blocks of cells.
============  ============================================================
"""

from __future__ import annotations

from .params import ExtractionParams, PRESETS, get_params  # noqa: F401
from .planes import Plane, fit_plane, PlaneFit  # noqa: F401
from .triangles import triangle_planes, triangle_slope_aspect, delaunay_facets  # noqa: F401
from .facets import segment_faces  # noqa: F401
from .vertices import (  # noqa: F401
    ControlPoint,
    intersect_planes,
    select_vertex,
    candidate_vertices,
    extract_roof,
    find_candidates,
    Candidate,
    STATUSES,
    ROW_FIELDS,
)
from .batch import (  # noqa: F401
    Job,
    read_jobs,
    extract_batch,
    write_control_csv,
    write_planes_csv,
    write_candidates,
    plot_control_point,
    write_figures,
    PLANE_FIELDS,
)
from .search import (  # noqa: F401
    find_candidates_tiles,
    find_jobs,
    n_blocks,
    run_find_block,
    search_block,
    write_block,
)

__all__ = [
    'Plane',
    'ExtractionParams',
    'PRESETS',
    'get_params',
    'triangle_planes',
    'triangle_slope_aspect',
    'delaunay_facets',
    'fit_plane',
    'PlaneFit',
    'segment_faces',
    'ControlPoint',
    'intersect_planes',
    'select_vertex',
    'candidate_vertices',
    'extract_roof',
    'find_candidates',
    'Candidate',
    'STATUSES',
    'ROW_FIELDS',
    'Job',
    'read_jobs',
    'extract_batch',
    'write_control_csv',
    'write_planes_csv',
    'write_candidates',
    'plot_control_point',
    'write_figures',
    'PLANE_FIELDS',
    'find_candidates_tiles',
    'find_jobs',
    'n_blocks',
    'run_find_block',
    'search_block',
    'write_block',
]
