"""Bundle adjustment with weighted position constraints (thesis section 2.1.2, eq. 08-22).

The package, one concern per module, in the order a step runs:

==================  ==========================================================
``problem``         :class:`BundleProblem` (the block as arrays),
                    :class:`ExteriorOrientation`, :func:`check_datum`,
                    :func:`chi2_bounds`
``model``           collinearity residuals, Jacobians and constraints assembled
                    into the normal-equation blocks U, V, W (``_System``)
``linear``          the reduced camera system S = U - W V^-1 W^T: pattern,
                    chunked assembly, solution
``cholesky``        supernodal sparse Cholesky (nested dissection) and its
                    selected inverse
``solve``           the Levenberg-Marquardt loop: :func:`adjust`,
                    :class:`BundleResult`
``precision``       blocks of N^-1 (photo 6x6, point 3x3, photo-point per
                    observation) by selected inversion, :func:`joint_point_covariance`
``survey_io``       survey folder -> problem, result -> output folder:
                    :func:`problem_from_survey`, :func:`write_adjustment`,
                    :func:`adjust_survey`, :func:`read_point_covariance`
==================  ==========================================================

Additional parameters (issue 13): ``additional`` (self-calibration, GNSS
line offsets), ``frame_offset`` (shift / similarity of a control source),
``selfcal`` (the bordered adjustment :func:`adjust_with_parameters`, tests of
significance and determinability), ``selfcal_survey`` (the ``[self_calibration]``
table and the CLI switches).  Blunders: ``reliability`` (redundancy numbers,
data snooping, robust re-weighting).  ``bal``: the Bundle Adjustment in the
Large camera model over the same core.

Every public name importable from ``lidarcat.bundle`` before the split still is.
"""

from __future__ import annotations

# the normal-equation system stays importable from here (tests and benchmarks/bench_bundle.py use it)
from .model import _System  # noqa: F401
from .precision import PRECISION_LEVELS, covariance_blocks, joint_point_covariance, observation_blocks
from .problem import BundleProblem, ExteriorOrientation, check_datum, chi2_bounds
from .additional import GnssLineOffsets, SelfCalibration
from .frame_offset import FrameOffset, frame_offset_from_sources
from .selfcal import SelfCalResult, adjust_with_parameters
from .solve import STATUS_MESSAGES, BundleResult, adjust
from .survey_io import (COVARIANCE_COLUMNS, EOP_COLUMNS, MAX_JOINT_COVARIANCE_POINTS, POINT_COLUMNS,
                        RESIDUAL_COLUMNS, adjust_survey, problem_from_survey, read_point_covariance,
                        write_adjustment)

__all__ = [
    "SelfCalibration",
    "GnssLineOffsets",
    "FrameOffset",
    "frame_offset_from_sources",
    "SelfCalResult",
    "adjust_with_parameters",
    "adjust_survey",
    "write_adjustment",
    "EOP_COLUMNS",
    "POINT_COLUMNS",
    "RESIDUAL_COLUMNS",
    "COVARIANCE_COLUMNS",
    "ExteriorOrientation",
    "BundleProblem",
    "BundleResult",
    "adjust",
    "check_datum",
    "problem_from_survey",
    "chi2_bounds",
    "covariance_blocks",
    "observation_blocks",
    "PRECISION_LEVELS",
    "joint_point_covariance",
    "read_point_covariance",
    "STATUS_MESSAGES",
    "MAX_JOINT_COVARIANCE_POINTS",
]
