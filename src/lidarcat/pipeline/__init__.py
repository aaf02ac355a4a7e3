"""The whole chain in one call: ``lidarcat run``.

A survey folder goes through the stages of the tool in pipeline order:

================  ==========================================================  ========================
stage             what it does                                                 output folder
================  ==========================================================  ========================
``camera``        interior orientation, pixel -> corrected photo coordinates   ``camera/``
                  (eq. 01-07); skipped when the survey has no pixel columns
``extract``       roof planes -> LiDAR control points, only when the survey    ``extract/``
                  has LiDAR tiles and extraction jobs; writes a derived
                  survey whose ground points include the extracted points
                  and a control set ``lidar`` of them
``adjust-SET``    bundle adjustment for every control set (eq. 08-22)          ``adjust-SET/``
``assess-SET``    check-point accuracy of that run (thesis section 3.3.4) and  ``assess-SET/``
                  its HTML report; map scale and contour interval are
                  parameters (default 1:2000 and 2 m, as the thesis)
``compare-A-B``   run A (the default control set) minus run B, for every       ``compare-A-B/``
                  other run: exterior orientations and the points free
                  (not control) in both runs (thesis section 4.4)
``thesis``        the thesis's section 4.4 (Tables 8-15) beside this run,      ``thesis/``
                  when the survey holds the printed tables (``published/``)
``mapping``       orthophotos, mosaic and monorestituted features of the       ``mapping/``
                  default run, when survey.toml has ``[mapping]``
``products``      LiDAR ground, DTM/DSM, contours, hypsometry, sheets, when    ``products/``
                  survey.toml has ``[products]``
``selfcal``       adjustment with the additional parameters of                 ``selfcal/``
                  ``[self_calibration]``, when it switches one on
``report``        index.html / index.md / report.json: what ran, every run,    ``report/``
                  the comparison, links to the per-run HTML reports
================  ==========================================================  ========================

Every stage records the SHA-256 of its inputs (file contents, parameters,
lidarcat version and source code, and the outputs of the stages it depends on) in
``OUTDIR/.stages/<stage>.json``; a later run with unchanged inputs reuses the
stage (status ``reused``) instead of recomputing it, ``force=True`` recomputes
everything.  A stage writes its folder through :func:`lidarcat._util.atomic_dir`
and its record only afterwards, so an interrupted run (SIGINT) leaves no
half-written file and the next run redoes exactly the unfinished stages
(temporary ``.*.part`` leftovers of a killed run are removed first; two runs
must not share an output folder at the same time).
``OUTDIR/summary.json`` lists every stage with its status (``ran``, ``reused``,
``skipped`` or ``failed``), the reason and the key numbers, and
``OUTDIR/lidarcat.log`` keeps the log of every run.

Modules
-------
``runner``       the generic machinery (:class:`Stage`, :func:`run_stages`, hashing,
                 reuse, records, the log file); it knows nothing of photogrammetry
                 and can chain any stages
``plan``         :func:`plan_pipeline` (the lidarcat stages in order for a survey)
                 and :func:`run_pipeline`

The stages themselves are :mod:`lidarcat.stages`, one module per stage, each with
``run(ctx, tmpdir) -> dict``; a new stage is a module there plus its :class:`Stage`
line in :func:`plan_pipeline`.
"""

from __future__ import annotations

from .plan import FROM_SURVEY, plan_pipeline, run_pipeline
from .runner import (
    STATUSES,
    PipelineResult,
    ProgressCallback,
    Stage,
    StageRecord,
    run_stages,
)

__all__ = [
    "FROM_SURVEY",
    "Stage",
    "StageRecord",
    "PipelineResult",
    "ProgressCallback",
    "run_stages",
    "run_pipeline",
    "plan_pipeline",
    "STATUSES",
]
