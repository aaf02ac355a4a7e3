"""Stage ``assess``: check-point discrepancies, statistical tests and map-accuracy standards (thesis 3.3.4).

===============  ============================================================
``checkpoints``  Accuracy assessment by check points: discrepancies, statistical tests, standards.
``statistics``   The statistical tests of the check-point assessment (thesis section 3.3.4, Cavassim et al. 2005).
``standards``    Map-accuracy standards: PEC (Decreto 89.817), PEC-PCD, ASPRS 2014 / 2023, NSSDA.
===============  ============================================================
"""

from __future__ import annotations

from .checkpoints import (  # noqa: F401
    COMPONENTS,
    SIGNS,
    PointSet,
    Assessment,
    read_points,
    discrepancies,
    summarize,
    assess,
)
from .statistics import (  # noqa: F401
    PLOTTING_POSITIONS,
    TestResult,
    plotting_positions,
    filliben_test,
    ks_test,
    covariance_consistency_test,
    lilliefors_test,
    ks_mahalanobis_test,
    trend_t_test,
    chi2_precision_test,
    hotelling_t2_test,
    ce90,
    filliben_critical_value,
    filliben_table,
    circular_error_radius,
)
from .standards import (  # noqa: F401
    STANDARD_NAMES,
    StandardResult,
    load_standard,
    pec_tolerances,
    asprs2023_product_rmse,
    nssda_horizontal_accuracy,
    classify_pec,
    classify_nssda,
    classify_asprs2014,
    classify_asprs2023,
    classify,
    CONFIDENCE_LABELS,
    notes_path,
)

__all__ = [
    'COMPONENTS',
    'PLOTTING_POSITIONS',
    'SIGNS',
    'PointSet',
    'TestResult',
    'Assessment',
    'read_points',
    'discrepancies',
    'summarize',
    'plotting_positions',
    'filliben_test',
    'ks_test',
    'covariance_consistency_test',
    'lilliefors_test',
    'ks_mahalanobis_test',
    'trend_t_test',
    'chi2_precision_test',
    'hotelling_t2_test',
    'ce90',
    'assess',
    'STANDARD_NAMES',
    'StandardResult',
    'load_standard',
    'pec_tolerances',
    'filliben_critical_value',
    'filliben_table',
    'circular_error_radius',
    'asprs2023_product_rmse',
    'nssda_horizontal_accuracy',
    'classify_pec',
    'classify_nssda',
    'classify_asprs2014',
    'classify_asprs2023',
    'classify',
    'CONFIDENCE_LABELS',
    'notes_path',
]
