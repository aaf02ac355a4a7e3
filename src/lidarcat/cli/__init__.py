"""Command-line interface (click). Thin: each command parses, calls one stage action, prints.

==================  ==================================================================
``main``            the ``lidarcat`` group: ``-v/-q``, one ``Error:`` line per library error
``options``         the one option registry (``-o/--output``, ``--crs``, ``--json``, ``--overwrite``)
``init``            ``lidarcat init``: a survey folder from a folder of photos
``interop``         ``lidarcat import`` / ``export``: other programs' files in and out
``match``           ``lidarcat match``: tie points from the photos
``convert``         ``lidarcat convert``: one format to another, without adjusting
``camera``          ``lidarcat camera``: interior orientation
``lidar``           ``lidarcat lidar info|index|clip|raster``: LiDAR tiles
``lidar_products``  ``lidarcat lidar ground|dtm|dsm|contours|hypsometry|sheets``: the production chain
``extract``         ``lidarcat extract``: roof planes to control points
``measure_control`` ``lidarcat measure-control``: LiDAR roof vertices measured in the photos
``adjust``          ``lidarcat adjust``: bundle adjustment of a survey
``assess``          ``lidarcat assess``: check-point accuracy, statistical tests, standards
``monoplot``        ``lidarcat monoplot``: features digitised on one photo onto the LiDAR surface
``ortho``           ``lidarcat ortho``: orthophotos and a mosaic of adjusted photos
``chart``           ``lidarcat chart``: orthophoto charts (ortofotocartas), one PDF + PNG per sheet
``deliver``         ``lidarcat deliver``: TIFF + TFW world files, Shapefile layers, DXF for CAD
``run``             ``lidarcat run``: the whole pipeline on a survey folder
``demo``            ``lidarcat demo``: surveys with known truth
``docs``            generates ``docs/cli.md`` from the commands
==================  ==================================================================

Each command module imports its stage action (:mod:`lidarcat.stages`) lazily, so
``lidarcat --help`` stays fast.
"""
