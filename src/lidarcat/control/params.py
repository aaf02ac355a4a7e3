"""Settings of one roof extraction: :class:`ExtractionParams` and its presets (:data:`PRESETS`).

The parameters of every step of :func:`lidarcat.control.facets.segment_faces` and of
the vertex selection: clip radius and height pre-filter, slope window, grouping
method and its tolerances, the sigmas of the points and the rejection threshold of
the plane fit.  Units are in the names (``_m``, ``_deg``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

__all__ = ["ExtractionParams", "PRESETS", "get_params"]

_METHODS = ("region", "ransac", "thesis")
_RESID = ("normal", "vertical", "height")
_HFILT = (None, "thesis", "robust")


@dataclass(frozen=True)
class ExtractionParams:
    """Settings of one roof extraction.  Units in the names; defaults = preset "default".

    The ``thesis`` preset (:data:`PRESETS`) reproduces Fierro Sanhueza (2007):
    radius 5 m, heights within +-2 m of the clip mean, slope window 4-30 deg,
    grouping by normal direction, height residuals above 0.15 m rejected, point
    sds from the scanner specification (0.50 m plan, 0.15 m height).
    """

    #: grouping of triangles / points into faces: "region", "ransac" or "thesis"
    method: str = "region"
    #: clip radius around the approximate position (m)
    radius_m: float = 8.0
    #: height pre-filter: None, "thesis" (clip mean +- window) or "robust" (+- window
    #: around the median of the clip's upper half, the roof): the filters of
    #: :func:`lidarcat.lidar.clip`, see :func:`lidarcat.lidar.clipping.height_window_mask`
    height_filter: str | None = None
    #: half-width of the thesis height window (m)
    height_window_m: float = 2.0
    #: region / ransac: leave out points on the outer edges of faces (eaves, verges),
    #: where facade points would bias the face downwards
    drop_outer_edges: bool = True
    #: region / ransac: after the faces are fitted, the points within this plan distance (m) of a
    #: face's break lines (ridges, hips, valleys: its intersection lines with the faces that reach
    #: them) are left out of its final fit (:mod:`lidarcat.control.segment`, "Break-line buffer");
    #: None = 2 x ``sd_en_m`` (0.2 m at the default: a point that near the line may, by its plan
    #: error, belong to the other face, and a footprint there mixes both; the default since session 7,
    #: tested by ``edge_buffer_level``); 0 = no buffer
    edge_buffer_m: float | None = None
    #: the buffer as a TEST at this level (:mod:`lidarcat.control.segment`, "Break-line buffer"): every band
    #: leaves the faces' fits when the clip's bands are off their planes as a whole (chi2 of their z), else
    #: only a band whose mean offset from the plane of its face's interior is significant alone (two-sided;
    #: the sd from the fit's own error model, iid + cell components); 0 = no test, every band leaves the
    #: fit (the blanket buffer)
    edge_buffer_level: float = 0.999
    #: slope window of triangles / faces (deg)
    slope_min_deg: float = 4.0
    slope_max_deg: float = 65.0
    #: triangles with an edge longer than this are dropped; None = 4 x median edge
    max_edge_m: float | None = None
    #: thesis method: aspect tolerance of a direction group (deg)
    aspect_tol_deg: float = 35.0
    #: region growing: neighbours for local normals, angle and distance tolerances
    k_neighbours: int = 12
    angle_tol_deg: float = 20.0
    #: None = 3 x noise estimated from the local planes, at least 0.05 m
    dist_tol_m: float | None = None
    #: residual threshold of the iterative rejection; None = 3.5 sigma (MAD), >= 0.03 m
    residual_threshold_m: float | None = None
    #: residual tested: "normal" (orthogonal), "vertical" (height difference to the
    #: plane, thesis 4.2.2) or "height" (GH adjusted-height residual v_h)
    residual_kind: str = "normal"
    #: a-priori sds of every LiDAR point (m); their ratio sets the GH weights.  They must
    #: describe the points' random noise: overstating the plan noise against the height
    #: noise biases the fitted slopes (errors in variables) and lifts apexes
    sd_en_m: float = 0.10
    sd_h_m: float = 0.05
    #: scale the covariance by the a-posteriori variance factor
    posterior_variance: bool = True
    #: cell sizes (m) of the correlated parts of the points' residuals: the planes' covariance adds the
    #: variance components the residuals show on these grids (:mod:`lidarcat.control.planes`, "Correlated
    #: residuals"); () = independent points (eq. 37 alone)
    cells_m: tuple = (1.0, 3.0)
    #: minimum points of a face (thesis: 6)
    min_points: int = 6
    #: faces considered per clip (largest first)
    max_planes: int = 12
    #: intersection: min angle between two normals (deg) and min |det| of unit normals
    min_dihedral_deg: float = 3.0
    min_det: float = 0.002
    #: max plan distance (m) from a face's nearest point to the vertex; None = max(1.5, 4 x spacing)
    support_m: float | None = None
    #: search radius: max plan distance (m) of the vertex from the approximate
    #: position; None = half the clip radius (4 m at the default 8 m, 2.5 m in the thesis preset)
    max_offset_m: float | None = None
    #: the vertex asked for: the clip is segmented again at smaller radii (``scales``) while a
    #: nearer distinct corner is possible, and the search stops at the first vertex within
    #: ``min(near_m, a / 2)`` of the position (``a``: how far apart two corners are told apart;
    #: :mod:`lidarcat.control.vertices`); an ``ok`` vertex farther than this (m) says so in
    #: its reason (1.5 m: beyond the 1-m-per-axis uncertainty of a position picked by hand or
    #: by ``--find``)
    near_m: float = 1.5
    #: clip radii of the retries, as fractions of ``radius_m``, besides 4 and 3 m (each at least 3 m)
    scales: tuple = (0.65, 0.5)
    #: two distinct vertices (> 0.5 m apart) whose distances from the position differ by
    #: less than this (m) make the request "ambiguous" (both listed); 0 never
    ambiguity_m: float = 0.3
    #: a vertex whose predicted 3-D sd exceeds this is "imprecise" (m)
    max_sd_m: float = 0.5
    #: extra planes join the vertex when their distance from it is below join_sigma x its
    #: sd plus half the plane's RMS, with a point of the plane within support_m
    join_sigma: float = 3.0
    #: radius stability (:mod:`lidarcat.control.stability`): an ``ok`` vertex is extracted again from
    #: clips of these multiples of ``radius_m`` centred on it (4, 5, 6, 10 and 12 m at the default 8 m: radii of
    #: the sweep of issue 29) and refused as "unstable" when its move to one of them is longer than
    #: its sd and (without the local extraction, ``fit_radius_m=None``) significant at ``stability_level``
    #: (Mahalanobis distance with the covariance of the difference of the two clips' vertices, chi2 with 3
    #: degrees of freedom); () = no check
    stability_scales: tuple = (0.5, 0.625, 0.75, 1.25, 1.5)
    #: local extraction (:mod:`lidarcat.control.localfit`): the vertex found in the clip of ``radius_m`` is
    #: extracted again from the clip of this radius (m) centred on it, to a fixed point, so that it is the
    #: corner's and does not depend on the search clip (5 m, the default since session 9: docs/extraction.md,
    #: "Local extraction"); None = the search clip's vertex (the thesis preset)
    fit_radius_m: float | None = 5.0
    stability_level: float = 0.999

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {', '.join(_METHODS)}, got {self.method!r}")
        if self.residual_kind not in _RESID:
            raise ValueError(f"residual_kind must be one of {', '.join(_RESID)}, got {self.residual_kind!r}")
        if self.height_filter not in _HFILT:
            raise ValueError(f"height_filter must be None, 'thesis' or 'robust', got {self.height_filter!r}")
        if not (0 <= self.slope_min_deg < self.slope_max_deg <= 90):
            raise ValueError("slope window must satisfy 0 <= slope_min_deg < slope_max_deg <= 90")
        if not self.height_window_m > 0:
            raise ValueError(f"height_window_m must be positive, got {self.height_window_m}")
        if self.radius_m <= 0:
            raise ValueError(f"radius_m must be positive, got {self.radius_m}")
        if self.min_points < 4:
            raise ValueError("min_points must be >= 4 (a plane has 3 degrees of freedom)")
        if self.sd_en_m <= 0 or self.sd_h_m <= 0:
            raise ValueError("sd_en_m and sd_h_m must be positive")
        if self.residual_threshold_m is not None and not self.residual_threshold_m > 0:
            raise ValueError(f"residual_threshold_m must be positive, got {self.residual_threshold_m}")
        if not self.near_m > 0:
            raise ValueError(f"near_m must be positive, got {self.near_m}")
        if self.edge_buffer_m is not None and not self.edge_buffer_m >= 0:
            raise ValueError(f"edge_buffer_m must be >= 0, got {self.edge_buffer_m}")
        if not 0 <= self.edge_buffer_level < 1:
            raise ValueError(f"edge_buffer_level must be in [0, 1), got {self.edge_buffer_level}")
        if any(not c > 0 for c in self.cells_m):
            raise ValueError(f"cells_m must be positive sizes in metres, got {self.cells_m!r}")
        if any(not 0 < f < 1 for f in self.scales):
            raise ValueError(f"scales must be fractions in (0, 1), got {self.scales!r}")
        if any(not (f > 0 and f != 1) for f in self.stability_scales):
            raise ValueError(f"stability_scales must be positive multiples of radius_m other than 1, "
                             f"got {self.stability_scales!r}")
        if not 0 < self.stability_level < 1:
            raise ValueError(f"stability_level must be in (0, 1), got {self.stability_level}")
        if self.fit_radius_m is not None and not self.fit_radius_m > 0:
            raise ValueError(f"fit_radius_m must be positive (m) or None, got {self.fit_radius_m}")
        if self.ambiguity_m < 0:
            raise ValueError(f"ambiguity_m must be >= 0, got {self.ambiguity_m}")
        if self.max_offset_m is not None and self.max_offset_m <= 0:
            raise ValueError(f"max_offset_m must be positive, got {self.max_offset_m}")

    def replace(self, **kw: Any) -> "ExtractionParams":
        """Copy with some fields changed (unknown names raise TypeError)."""
        return dataclasses.replace(self, **kw)


PRESETS: dict[str, ExtractionParams] = {
    "default": ExtractionParams(),
    "thesis": ExtractionParams(
        method="thesis", radius_m=5.0, height_filter="thesis", height_window_m=2.0,
        slope_min_deg=4.0, slope_max_deg=30.0, residual_threshold_m=0.15,
        residual_kind="vertical", sd_en_m=0.50, sd_h_m=0.15, min_points=6, max_planes=4,
        aspect_tol_deg=35.0, max_sd_m=2.0,
        # the thesis's method as published: one clip, no radius-stability check
        stability_scales=(), fit_radius_m=None,
    ),
}


def get_params(params: ExtractionParams | str | None = None, **overrides: Any) -> ExtractionParams:
    """Resolve a preset name or params object, then apply *overrides*.

    An override of None means "not given" and is dropped (the CLI passes its unset options so): to set a
    field to None, e.g. ``fit_radius_m`` for the search clip's whole faces, use
    ``get_params().replace(fit_radius_m=None)``.

    >>> get_params("thesis").slope_max_deg
    30.0
    >>> get_params("default", radius_m=12).radius_m
    12
    """
    if params is None:
        params = "default"
    if isinstance(params, str):
        if params not in PRESETS:
            raise ValueError(f"unknown preset {params!r}; choose one of {', '.join(PRESETS)}")
        params = PRESETS[params]
    overrides = {k: v for k, v in overrides.items() if v is not None}
    return params.replace(**overrides) if overrides else params
