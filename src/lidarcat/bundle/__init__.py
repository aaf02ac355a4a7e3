"""Bundle adjustment with weighted position constraints (thesis section 2.1.2, eq. 08-22).

The package, one concern per module, in the order a step runs:

==================  ==========================================================
``problem``         :class:`BundleProblem` (the block as arrays),
                    :class:`ExteriorOrientation`, :func:`check_datum`,
                    :func:`chi2_bounds`
``model``           collinearity residuals, Jacobians and constraints assembled
                    into the normal-equation blocks U, V, W (``NormalSystem``)
``linear``          the reduced camera system S = U - W V^-1 W^T: pattern,
                    chunked assembly, solution
``cholesky``        supernodal sparse Cholesky (nested dissection) and its
                    selected inverse
``solve``           the Levenberg-Marquardt loop: :func:`adjust`
``result``          its outcome, :class:`BundleResult`
``precision``       blocks of N^-1 (photo 6x6, point 3x3, photo-point per
                    observation) by selected inversion, :func:`joint_point_covariance`
``approx``          approximate values from the data alone (never from the answer)
``screening``       tie points screened by their intersection geometry at the
                    approximate orientation (:func:`screen`)
``robust``          the robust start: screening, graduated IRLS, the rejected
                    observations named and put back (:func:`robust_start`)
``rays``            per-observation rays: a moving projection centre (rolling
                    shutter) and the sensor of a rig exposure
                    (:class:`~lidarcat.bundle.rays.ObservationRays`)
``rolling``         rolling shutter: row times, velocities from the neighbouring
                    exposures, velocity and read-out-time unknowns, the tests
``rig``             rigs: one body pose per exposure, the sensors' relative
                    poses given or estimated (:class:`~lidarcat.bundle.rig.RigRelativePoses`)
``lines``           line control: image observations of LiDAR roof lines
                    (:class:`~lidarcat.bundle.lines.LineControl`), their share of
                    the camera blocks and v'Pv
``line_tests``      the line observations' residuals, redundancy numbers,
                    w-tests and data snooping (:func:`~lidarcat.bundle.line_tests.snoop_lines`)
``variance``        variance components: one factor per observation group (tie
                    points, targets, control, GNSS, IMU), Förstner's iterated
                    estimate (:func:`iterate_components`)
==================  ==========================================================

Additional parameters (issue 13): ``additional`` (self-calibration, GNSS
line offsets), ``frame_offset`` (shift / similarity of a control source),
``selfcal`` (the bordered adjustment :func:`adjust_with_parameters`, tests of
significance and determinability; the ``[self_calibration]`` table is read in
:mod:`lidarcat.survey.selfcal`).  Blunders: ``redundancy`` (redundancy numbers,
the group tests of one adjustment, minimal detectable bias) and ``reliability``
(data snooping, robust re-weighting).  ``bal``: the Bundle Adjustment in the
Large camera model over the same core.

The engine knows no survey folder and no files: reading a survey into a
:class:`BundleProblem` and writing the adjustment's tables live in
:mod:`lidarcat.survey.adjustment` (``adjust_survey``, ``problem_from_survey``,
``write_adjustment``, also importable from :mod:`lidarcat`).
"""

from __future__ import annotations

# the normal-equation system is importable from here (tests and benchmarks/bench_bundle.py use it)
from .model import NormalSystem
from .precision import PRECISION_LEVELS, covariance_blocks, joint_point_covariance, observation_blocks
from .problem import BundleProblem, ExteriorOrientation, check_datum, chi2_bounds
from .additional import GnssLineOffsets, SelfCalibration
from .frame_offset import FrameOffset, frame_offset_from_sources
from .selfcal import SelfCalResult, adjust_with_parameters
from .result import STATUS_MESSAGES, BundleResult
from .solve import adjust

__all__ = [
    "SelfCalibration",
    "GnssLineOffsets",
    "FrameOffset",
    "frame_offset_from_sources",
    "SelfCalResult",
    "adjust_with_parameters",
    "ExteriorOrientation",
    "BundleProblem",
    "BundleResult",
    "adjust",
    "check_datum",
    "chi2_bounds",
    "covariance_blocks",
    "observation_blocks",
    "PRECISION_LEVELS",
    "joint_point_covariance",
    "STATUS_MESSAGES",
    "NormalSystem",
]
