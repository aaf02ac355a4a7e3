"""LiDAR data access: tiles (LAS/LAZ/COPC/ASCII), CRS, tile index, clips, raster views; the tile engine.

==================  ===========================================================
:mod:`.cloud`       :class:`PointCloud` (E, N, h in metres + attributes + CRS)
:mod:`.readers`     :func:`read_points`, :func:`iter_points`, :func:`write_points`
:mod:`.crs`         :func:`resolve_crs`, :func:`transform_points`, units and area-of-use checks
:mod:`.tileindex`   :class:`TileIndex`: bounds per tile, radius/box/polygon queries
:mod:`.tiles`       :class:`Tile`, :class:`BlockIndex` (cell boxes in file order), :func:`expand_paths`
:mod:`.membership`  :func:`in_radius`, :func:`in_box`, :func:`in_polygon`: which points a query holds
:mod:`.clipping`    :func:`clip`: points around a roof with height pre-filters
:mod:`.raster`      :func:`rasterize` (intensity, DSM, DTM), GeoTIFF and PNG output
:mod:`.geotiff`     :func:`read_geotiff`, :func:`write_geotiff`: the one raster I/O (rasterio)
:mod:`.info`        :func:`describe`: counts, bounds, density, classes, returns
:mod:`.copc`        COPC tiles read by their octree: only the nodes a query box meets
:mod:`.copc_write`  COPC writer: points into an octree of LAZ chunks (COPC 1.0), by hand with lazrs
:mod:`.jobs`        the tile engine: a function over tiles with overlap, serial or on Dask, resumable
:mod:`.trajectory`  :class:`Trajectory`: SBET and CSV flight trajectories, interpolated at GPS times
==================  ===========================================================

Examples
--------
>>> import numpy as np
>>> from lidarcat.lidar import PointCloud, clip
>>> rng = np.random.default_rng(0)
>>> xy = rng.uniform(0, 20, (4000, 2))
>>> h = np.where(np.hypot(xy[:, 0] - 10, xy[:, 1] - 10) < 4, 8.0, 0.0)   # a flat roof on the ground
>>> pc = PointCloud(np.column_stack([xy, h]), crs=None)
>>> roof = clip(pc, (10, 10), 3.5, height_filter="robust")
>>> bool(np.all(roof.z == 8.0)), len(roof) > 100
(True, True)
"""

from __future__ import annotations

from .cloud import STANDARD_ATTRIBUTES, Bounds, PointCloud
from .clipping import HEIGHT_FILTERS, clip, height_window_mask
from .crs import (check_area_of_use, common_crs, crs_compatible, crs_label, horizontal_unit, require_metres,
                  resolve_crs, transform_points, units_are_metres)
from .info import describe
from .geotiff import GeoTransform, read_geotiff, write_geotiff
from .raster import rasterize, write_png_preview, write_raster
from .readers import FileHeader, iter_points, read_header, read_points, write_points
from .membership import in_box, in_polygon, in_radius
from .tileindex import TileIndex
from .tiles import BlockIndex, Tile, expand_paths

__all__ = [
    "PointCloud", "Bounds", "STANDARD_ATTRIBUTES",
    "read_points", "iter_points", "write_points", "read_header", "FileHeader",
    "resolve_crs", "transform_points", "crs_compatible", "common_crs", "crs_label",
    "horizontal_unit", "units_are_metres", "require_metres", "check_area_of_use",
    "TileIndex", "Tile", "BlockIndex", "expand_paths", "in_radius", "in_box", "in_polygon",
    "clip", "height_window_mask", "HEIGHT_FILTERS",
    "rasterize", "GeoTransform", "write_geotiff", "read_geotiff", "write_png_preview", "write_raster",
    "describe",
]
