"""Stage ``measure-control``: LiDAR roof vertices predicted, found and measured in the photos (issue 29).

==============  ============================================================
``predict``     Predicted pixel of a vertex (and its roof edges) with the ellipse propagated from the orientation's
                and the vertex's covariance; visibility from the LiDAR DSM; a roof edge as a control line (end
                points and covariance from the two plane fits).
``measure``     The vertex in the image: a face template for the shift, roof-edge lines for the pixel, their
                intersection with its covariance; the fitted edges as line observations; the per-photo and multi-photo tests.
``blockcheck``  The block test of the vertex measurements: one bundle adjustment with the tie points, the
                approximate orientations and the LiDAR vertices as weighted observations; the measurements
                w-tested worst first (a measurement alone on its photo is tested through its tie points).
``review``      Image chips with the predicted ellipse and the measured point and lines, and a gallery of them.
``_along``      (private) The vertex as the weighted least-squares point of its edge lines, and located along
                one edge where two edges on either side of it bend (measure steps 3 and 3a).
``_edge_fit``   (private) A roof edge fitted to sub-pixel across its predicted segment: profiles, peaks, the
                robust line and its covariance (measure step 2).
``_weak_edge``  (private) A weak edge of a vertex w-tested against the point of its strong edges before it
                enters the point (measure step 3b).
==============  ============================================================

Private: ``_block_ties`` (the block test's tie points in photo coordinates, cleaned on their own),
``_block_model`` (its observations in photo coordinates and the bundle problem of each round) and
``_block_backward`` (its backward step over the roof edges: a rejected edge put back or exchanged).
"""

from __future__ import annotations

from .predict import (  # noqa: F401
    Prediction,
    RoofEdge,
    VISIBILITY,
    dsm_of_points,
    edge_line_m,
    ellipse_axes,
    face_labels,
    occluded,
    pixel_jacobians,
    pixel_positions,
    predict_edges,
    predict_points,
    roof_edges,
)
from .measure import (  # noqa: F401
    EdgeLine,
    Measurement,
    MeasureParams,
    STATUSES,
    VertexTarget,
    check_consistency,
    check_photo,
    grey,
    measure_photo,
    measure_vertex,
)
from .blockcheck import BlockCheck, EdgeObservation, TieObservations, check_block  # noqa: F401
from .review import chip_centre, chip_image, gallery  # noqa: F401

__all__ = [
    "Prediction",
    "RoofEdge",
    "VISIBILITY",
    "dsm_of_points",
    "edge_line_m",
    "ellipse_axes",
    "face_labels",
    "occluded",
    "pixel_jacobians",
    "pixel_positions",
    "predict_edges",
    "predict_points",
    "roof_edges",
    "EdgeLine",
    "Measurement",
    "MeasureParams",
    "STATUSES",
    "VertexTarget",
    "check_consistency",
    "check_photo",
    "grey",
    "measure_photo",
    "measure_vertex",
    "BlockCheck",
    "EdgeObservation",
    "TieObservations",
    "check_block",
    "chip_centre",
    "chip_image",
    "gallery",
]
