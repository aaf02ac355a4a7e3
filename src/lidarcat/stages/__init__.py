"""The lidarcat stages, one module per stage, in pipeline order.

=============  ======================================================
``init``       a survey folder from a folder of photos (``lidarcat init``; before ``lidarcat run``)
``match``      tie points from the photos into image_points.csv (issue 28)
``camera``     interior orientation (eq. 01-07)
``extract``    LiDAR roof vertices -> control points, derived survey
``measure_control``  LiDAR control vertices measured in the photos into image_points.csv (issue 29)
``adjust``     bundle adjustment of one control set (eq. 08-22)
``assess``     check-point accuracy of one run (section 3.3.4)
``compare``    run A minus run B (section 4.4)
``thesis``     the thesis's printed section 4.4 beside this run
``mapping``    orthophotos, mosaic and monorestituted features of the adjusted photos ([mapping])
``products``   LiDAR ground, DTM/DSM, contours, hypsometry, sheets ([products])
``selfcal``    adjustment with additional parameters (issue 13), when planned
``report``     index.html / index.md / report.json of the whole run
=============  ======================================================

Each module has ``run(ctx, tmpdir) -> dict`` (``ctx`` a
:class:`~lidarcat.stages.context.StageContext`), run by :mod:`lidarcat.pipeline`,
which orders them for a survey; the stages with a command of their own expose
its action (one function, inputs in, files out), which the command in
:mod:`lidarcat.cli` and the ``run`` function both call: :func:`match.match` (``lidarcat match``), :func:`extract.extract`,
:func:`adjust.adjust`, :func:`assess.assess`, :func:`mapping.orthophotos` (``lidarcat ortho``),
:func:`lidar.ground` (``lidarcat lidar ground``) and :func:`lidar.terrain_model`
(``lidarcat lidar dtm|dsm``; the products stage calls both).  :data:`REGISTRY` lists the stages with their one-line
summaries (``lidarcat run --help`` is generated from it).

Also here: ``context`` (:class:`~lidarcat.stages.context.StageContext`, what a
stage sees), ``lidar`` (the actions of the LiDAR production commands) and the private
``_feature_cache`` (the match stage's per-photo feature files), ``_control_tables`` (the survey tables
measure-control writes, reloaded and rolled back), ``_control_review`` (measure-control's decisions
fed back and remembered), ``_control_report`` (measure-control's decisions.csv and gallery) and ``_second_pass``
(measure-control's second pass: the pairs lost at the frame or to the edges, predicted again from the block test's
orientation and measured again).
"""

from . import adjust, assess, camera, compare, context, extract, init, lidar, mapping, match, products, report, selfcal, thesis
from . import measure_control

__all__ = ["init", "match", "camera", "extract", "adjust", "assess", "compare", "thesis", "mapping", "products", "selfcal", "report",
           "context", "lidar", "measure_control", "REGISTRY"]

#: every stage of ``lidarcat run`` in pipeline order: (name, one-line summary); SET is a control set
REGISTRY: tuple[tuple[str, str], ...] = (
    ("match", "tie points from the photos (survey with images and too few tie points)"),
    ("measure_control", "LiDAR control vertices measured in the photos (images, tiles, ground points of source "
                        "lidar without observations)"),
    ("camera", "interior orientation, pixel -> corrected photo coordinates"),
    ("extract", "LiDAR roof vertices -> control points (survey with lidar + jobs)"),
    ("adjust-SET", "bundle adjustment per control set (thesis: gps, lidar); photos.csv sd_X0..: GNSS/IMU "
                   "constraints, the datum of adjust-gnss when there is no set"),
    ("assess-SET", "check-point accuracy of each run"),
    ("compare", "differences of the runs: orientations, points free in both"),
    ("thesis", "the thesis's printed section 4.4 beside this run (embedded block)"),
    ("mapping", "orthophotos, mosaic, monorestituted features (survey.toml [mapping])"),
    ("products", "LiDAR ground, DTM/DSM, contours, hypsometry, sheets ([products])"),
    ("selfcal", "adjustment with additional parameters ([self_calibration])"),
    ("report", "HTML / Markdown / JSON report in OUTDIR/report/"),
)
