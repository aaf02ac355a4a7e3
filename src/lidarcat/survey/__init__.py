"""The survey folder: ``survey.toml`` and its tables in, results out (the one home of folder I/O).

==============  ============================================================
``folder``      The survey folder: load, validate and locate a photogrammetric project.
``cameras``     camera.toml files: the survey's cameras read, every error located (file:line and key).
``adjustment``  The survey adapter: a survey folder in, the adjustment folder out.
``covariance``  ``eop_covariance.csv``: the full 6 x 6 covariance of every adjusted orientation.
``schema``      The survey.toml schema: every table and key, typed, parsed once and validated at load.
``selfcal``     Additional parameters from a survey folder: the ``[self_calibration]`` table and the CLI switches.
``motion``      The camera's motion during an exposure: the rolling shutter of the survey's cameras in the bundle.
``rigs``        Rigs from the survey: a rig TOML of cameras with fixed relative poses, and photos.csv's exposures.
``lines``       line_control.csv: control lines (LiDAR roof edges) and their image observations; line_residuals.csv.
``decisions``   control_decisions.csv: the user's review of the LiDAR control measured in the photos, remembered.
==============  ============================================================
"""

from __future__ import annotations

from .folder import (  # noqa: F401
    AssessmentSettings,
    Survey,
    Photo,
    ImagePoints,
    GroundPoints,
    ControlSet,
    AdjustmentSettings,
    CorrectedMeasurements,
    thesis_survey_path,
    example_camera_path,
    correct_measurements,
    cameras_of,
    SURVEY_KEYS,
)
from .cameras import load_cameras, load_camera  # noqa: F401
from .schema import (  # noqa: F401
    SurveyConfig,
    MappingSettings,
    ProductsSettings,
    parse_survey_toml,
)
from .adjustment import (  # noqa: F401
    adjust_survey,
    write_adjustment,
    problem_from_survey,
    read_point_covariance,
    EOP_COLUMNS,
    POINT_COLUMNS,
    RESIDUAL_COLUMNS,
    COVARIANCE_COLUMNS,
    MAX_JOINT_COVARIANCE_POINTS,
    BLUNDER_COLUMNS,
)
from .selfcal import (  # noqa: F401
    SelfCalSettings,
    self_calibration_settings,
    combined_control_set,
    components_from_survey,
    adjust_survey_with_parameters,
    selfcal_adjust,
    write_selfcal,
    format_parameters,
    wants_parameters,
    SNOOPING_WITH_PARAMETERS,
)

__all__ = [
    'AssessmentSettings',
    'Survey',
    'Photo',
    'ImagePoints',
    'GroundPoints',
    'ControlSet',
    'AdjustmentSettings',
    'CorrectedMeasurements',
    'thesis_survey_path',
    'example_camera_path',
    'correct_measurements',
    'cameras_of',
    'SURVEY_KEYS',
    'load_cameras',
    'load_camera',
    'SurveyConfig',
    'MappingSettings',
    'ProductsSettings',
    'parse_survey_toml',
    'adjust_survey',
    'write_adjustment',
    'problem_from_survey',
    'read_point_covariance',
    'EOP_COLUMNS',
    'POINT_COLUMNS',
    'RESIDUAL_COLUMNS',
    'COVARIANCE_COLUMNS',
    'MAX_JOINT_COVARIANCE_POINTS',
    'BLUNDER_COLUMNS',
    'SelfCalSettings',
    'self_calibration_settings',
    'combined_control_set',
    'components_from_survey',
    'adjust_survey_with_parameters',
    'selfcal_adjust',
    'write_selfcal',
    'format_parameters',
    'wants_parameters',
    'SNOOPING_WITH_PARAMETERS',
]
