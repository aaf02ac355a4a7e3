"""Stage ``products``: the LACTEC production chain -- ground, DTM/DSM, contours, hypsometry, map sheets.

====================  ============================================================
``ground``            Ground classification: progressive TIN densification and a simple morphological filter.
``csf``               Cloth simulation filter (Zhang et al. 2016), the third ground method.
``noise``             Noise (class 7) by the statistical outlier test, and height above the ground TIN.
``terrain``           Terrain (DTM) and surface (DSM) models, nDSM, hillshade and the hypsometric image.
``contours``          Contour lines from the ground TIN, master/intermediate curves, spot heights, GeoJSON.
``contourcheck``      Contour verification over sparse ground (stretches, profiles), filled bands, 3-D lines.
``sheets``            Map sheets: a regular sheet grid (the report's "articulação"), its index layer, products cut per sheet.
``mapindex``          The Brazilian systematic map index (Cartografia Sistemática Brasileira) down to 1:5,000 and 1:2,000.
``tiles``             The products' tile functions by name (ground, dtm, dsm), as jobs of the tile engine ``lidar.jobs``.
``conventions``       The cartographic conventions of the sheets (report Figure 27): layer names, colours, widths.
``charts``            Orthophoto charts (ortofotocartas): mosaic, contours, UTM grid, legend, title block, index map.
``delivery``          Delivery formats: TIFF + TFW world files, Shapefile layers, DXF layers of the conventions.
``lidarchecks``       LiDAR system checks: vertical (NVA/VVA, PEC) and planimetric accuracy against surveyed points.
``lidarcalib``        LiDAR system calibration: the geolocation equation; boresight, scan-angle scale, bias by least squares.
``lidarcalib_tiles``  The LiDAR system calibration tile by tile on the tile engine (bounded memory, bottom-k sample).
``swath``             Swath separation images: per-cell differences between overlapping flight lines (USGS LBS).
====================  ============================================================

The functions named as their modules (``contours.contours``) are
reached through the module: the package attribute is the module.
"""

from __future__ import annotations

from .ground import (  # noqa: F401
    PTDParameters,
    SMRFParameters,
    GroundMethod,
    GROUND_METHODS,
    classify_ground,
    ptd_ground,
    smrf_ground,
    Confusion,
    confusion,
    write_classified_copy,
    classify_tiles,
    ground_tile,
    params_from_dict,
    default_overlap_m,
    GROUND_CLASS,
    UNCLASSIFIED_CLASS,
)
from .terrain import (  # noqa: F401
    TinGrid,
    tin_grid,
    dtm_grid,
    dsm_grid,
    ndsm,
    hillshade,
    hypsometric_image,
    write_product,
    write_text_grid,
    tin_heights,
    dtm_tile,
    dsm_tile,
)
from .tiles import PRODUCT_TILE_FUNCTIONS, product_jobs  # noqa: F401
from .contours import (  # noqa: F401
    Contour,
    spot_heights,
    write_geojson,
    contour_features,
    spot_features,
    write_contours,
    write_layers,
    read_line_layer,
    CONTOUR_FORMATS,
)
from .sheets import (  # noqa: F401
    Sheet,
    sheet_grid,
    sheet_index_features,
    cut_raster,
    cut_contours,
    index_sheets,
    SHEET_INDEXES,
)
from .mapindex import (  # noqa: F401
    MapSheet,
    Level,
    LEVELS,
    SCALES,
    sheet_at,
    sheet_names,
    sheet_from_name,
    sheets_covering,
    sheet_outline,
    cut_raster_geo,
    cut_contours_geo,
    geographic_crs_of,
)

__all__ = [
    'PTDParameters',
    'SMRFParameters',
    'GroundMethod',
    'GROUND_METHODS',
    'classify_ground',
    'ptd_ground',
    'smrf_ground',
    'Confusion',
    'confusion',
    'write_classified_copy',
    'classify_tiles',
    'ground_tile',
    'params_from_dict',
    'default_overlap_m',
    'GROUND_CLASS',
    'UNCLASSIFIED_CLASS',
    'TinGrid',
    'tin_grid',
    'dtm_grid',
    'dsm_grid',
    'ndsm',
    'hillshade',
    'hypsometric_image',
    'write_product',
    'write_text_grid',
    'tin_heights',
    'dtm_tile',
    'dsm_tile',
    'PRODUCT_TILE_FUNCTIONS',
    'product_jobs',
    'Contour',
    'spot_heights',
    'write_geojson',
    'contour_features',
    'spot_features',
    'write_contours',
    'write_layers',
    'read_line_layer',
    'CONTOUR_FORMATS',
    'Sheet',
    'sheet_grid',
    'sheet_index_features',
    'cut_raster',
    'cut_contours',
    'index_sheets',
    'SHEET_INDEXES',
    'MapSheet',
    'Level',
    'LEVELS',
    'SCALES',
    'sheet_at',
    'sheet_names',
    'sheet_from_name',
    'sheets_covering',
    'sheet_outline',
    'cut_raster_geo',
    'cut_contours_geo',
    'geographic_crs_of',
]
