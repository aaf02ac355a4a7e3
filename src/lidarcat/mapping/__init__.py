"""Stage ``mapping``: monorestitution, orthophotos and mosaics over a LiDAR surface (Cavassim 2005).

============  ============================================================
``inputs``    What the mapping products need from an adjusted survey: orientations, photo files, surfaces.
``monoplot``  Monorestitution: a pixel of ONE oriented photo intersected with the LiDAR surface.
``features``  Features digitised on a photo (pixels in) and their monorestituted versions (map coordinates out).
``ortho``     Orthophotos: a photo resampled onto a north-up ground grid over a terrain or surface model.
``mosaic``    Orthomosaic: per output cell, the most nadir photo that sees it; seamlines as polygons.
``accuracy``  Accuracy of mapped features as Cavassim (2005) judges it (the paper's experiment: :mod:`lidarcat.synthetic.cavassim`).
============  ============================================================

The functions named as their modules (``monoplot.monoplot``, ``mosaic.mosaic``) are
reached through the module: the package attribute is the module.
"""

from __future__ import annotations

from .inputs import (  # noqa: F401
    read_orientations,
    default_eop_path,
    adjusted_orientation,
    adjusted_orientations,
    photo_image,
    IMAGE_SUFFIXES,
    lidar_surface,
    ray_area,
)
from .monoplot import (  # noqa: F401
    GridSurface,
    PointSurface,
    MonoplotResult,
    ray_directions,
    STATUSES,
    INTERPOLATORS,
    MonoplotError,
)
from .features import (  # noqa: F401
    ImageFeature,
    read_features,
    features_geojson,
    features_rows,
    FEATURE_CSV_COLUMNS,
    FeatureError,
)
from .ortho import (  # noqa: F401
    OrthoError,
    PhotoModel,
    OrthoResult,
    orthophoto,
    output_grid,
    DistortionLUT,
    GeoTiffStream,
)
from .mosaic import (  # noqa: F401
    MosaicResult,
    seam_polygons,
)
from .accuracy import (  # noqa: F401
    assess_features,
    assess_monoplot,
    read_reference,
    REFERENCE_CSV_COLUMNS,
)

__all__ = [
    'read_orientations',
    'default_eop_path',
    'adjusted_orientation',
    'adjusted_orientations',
    'photo_image',
    'IMAGE_SUFFIXES',
    'lidar_surface',
    'ray_area',
    'GridSurface',
    'PointSurface',
    'MonoplotResult',
    'ray_directions',
    'STATUSES',
    'INTERPOLATORS',
    'MonoplotError',
    'ImageFeature',
    'read_features',
    'features_geojson',
    'features_rows',
    'FEATURE_CSV_COLUMNS',
    'FeatureError',
    'OrthoError',
    'PhotoModel',
    'OrthoResult',
    'orthophoto',
    'output_grid',
    'DistortionLUT',
    'GeoTiffStream',
    'MosaicResult',
    'seam_polygons',
    'assess_features',
    'assess_monoplot',
    'read_reference',
    'REFERENCE_CSV_COLUMNS',
]
