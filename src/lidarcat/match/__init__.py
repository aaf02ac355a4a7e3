"""Automatic tie points from the photos (the engine of ``lidarcat match``): arrays in, arrays out.

=================  =========================================================
``features``       SIFT keypoints on the pyramid level of the photo scale
``rays``           pixel rays onto a height surface (LiDAR DSM/DTM or mean height) and into another photo
``pairs``          footprints of the approximate orientations, convex overlap, pairs that grow linearly
``guided``         predicted position + covariance in the other photo, search in the ellipse, ratio + mutual
``verify``         robust fundamental matrix (MAGSAC++) on distortion-free pixels, inliers in px
``tracks``         union-find tracks (inconsistent ones dropped), Von Gruber-like distribution per photo
``refine``         sub-pixel refinement of the observations: correlation peak against the track's first observation
``block``          the whole chain on a block (:func:`match_block`), photos and pairs as tasks (threads, or Dask through ``lidar.jobs.map_tasks``)
=================  =========================================================

The engine knows no survey folder: :mod:`lidarcat.stages.match` reads the survey, the images
and the LiDAR surface, calls :func:`match_block` and writes ``image_points.csv``.
"""

from __future__ import annotations

from .block import BlockMatch, MatchError, MatchOptions, PairReport, extract_features, match_block
from .features import FeatureOptions, Features, detect, pyramid_level, read_image
from .guided import Matches, Prediction, guided_match, match_descriptors, predict
from .pairs import convex_overlap, exhaustive_pairs, footprint, footprint_pairs
from .rays import HeightSurface, project_to_pixel, ray_to_surface, transfer
from .refine import refine_observations
from .tracks import Tracks, build_tracks, distribute
from .verify import Verification, ideal_pixels, verify_pair

__all__ = ["BlockMatch", "MatchError", "MatchOptions", "PairReport", "extract_features", "match_block",
           "FeatureOptions", "Features", "detect", "pyramid_level", "read_image",
           "Matches", "Prediction", "guided_match", "match_descriptors", "predict",
           "convex_overlap", "exhaustive_pairs", "footprint", "footprint_pairs",
           "HeightSurface", "project_to_pixel", "ray_to_surface", "transfer",
           "refine_observations", "Tracks", "build_tracks", "distribute", "Verification", "ideal_pixels", "verify_pair"]
