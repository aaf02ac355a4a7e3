"""The lidarcat stages, one module per stage, in pipeline order.

=============  ======================================================
``camera``     interior orientation (eq. 01-07)
``extract``    LiDAR roof vertices -> control points, derived survey
``adjust``     bundle adjustment of one control set (eq. 08-22)
``assess``     check-point accuracy of one run (section 3.3.4)
``compare``    run A minus run B (section 4.4)
``thesis``     the thesis's printed section 4.4 beside this run
``mapping``    orthophotos, mosaic and monorestituted features of the adjusted photos ([mapping])
``products``   LiDAR ground, DTM/DSM, contours, hypsometry, sheets ([products])
``selfcal``    adjustment with additional parameters (issue 13), when planned
``report``     index.html / index.md / report.json of the whole run
=============  ======================================================

Each module has ``run(ctx, tmpdir) -> dict`` (see
:class:`lidarcat.pipeline.runner.Stage`); :mod:`lidarcat.pipeline.plan`
orders them for a survey.
"""

from . import adjust, assess, camera, compare, extract, mapping, products, report, selfcal, thesis

__all__ = ["camera", "extract", "adjust", "assess", "compare", "thesis", "mapping", "products", "selfcal", "report"]
