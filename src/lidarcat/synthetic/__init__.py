"""Synthetic data with known truth, for the demo, the tests and the benchmarks.

==============  ============================================================
``block``       Seeded synthetic aerial blocks with known truth, for tests and benchmarks.
``survey``      A synthetic survey with known truth: ``lidarcat demo synthetic``.
``roofs``       Synthetic buildings with known roof vertices, sampled like an airborne scanner.
``scene``       A textured synthetic scene and aerial photos of it, rendered with known truth.
``aerial``      A synthetic aerial block from photos: realistic rendered photos, approximate GNSS/IMU, GPS control, truth.
``landscapes``  Synthetic landscapes with known ground, for judging ground filters beyond the AHN3 tiles.
``cavassim``    The experiment of Cavassim (2005) on a synthetic town: three mapping products against known truth.
``textured``    Small photos of a textured rolling ground with the true point behind every pixel (matching tests).
``matches``     A block of automatic tie-point matches with gross errors of known place (the NGI kind).
``strips``      Overlapping LiDAR strips with a known boresight, scan-angle scale and elevation bias.
``drone``       Drone blocks with known truth: a rolling-shutter camera, and a rig of three cameras.
``lines``       A block whose only control is roof lines measured in the photos (weak GNSS/IMU).
``lidarphoto``  Aerial photos rendered over a real LiDAR surface (exact planes at its roof vertices), with truth.
==============  ============================================================
"""

from __future__ import annotations

from .block import (  # noqa: F401
    SyntheticBlock,
    synthetic_block,
    aerial_block,
    AERIAL_LAYOUTS,
    resimulated,
    SelfCalBlock,
    selfcal_block,
)
from .matches import matched_block, MISMATCH_PX, WRONG_RAY_PX, MATCH_PIXEL_MM  # noqa: F401
from .survey import (  # noqa: F401
    DemoSurvey,
    write_synthetic_survey,
    compare_with_truth,
    demo_camera,
    project_points,
    DEMO_CRS,
)
from .roofs import (  # noqa: F401
    SyntheticScene,
    synthetic_roof,
    KINDS,
)
from .scene import (  # noqa: F401
    Building,
    Road,
    Scene,
    demo_scene,
)
from .aerial import (  # noqa: F401
    AerialScene,
    AerialSurvey,
    Exposure,
    RenderedPhoto,
    aerial_survey,
    load_aerial_survey,
    render_photo,
)
from .landscapes import (  # noqa: F401
    Landscape,
    make_landscape,
    LANDSCAPES,
)
from .cavassim import (  # noqa: F401
    cavassim_experiment,
    CAVASSIM_TABLE_09,
    CAVASSIM_TABLES_06_08,
    paper_camera,
)

__all__ = [
    'SyntheticBlock',
    'synthetic_block',
    'aerial_block',
    'AERIAL_LAYOUTS',
    'resimulated',
    'SelfCalBlock',
    'selfcal_block',
    'DemoSurvey',
    'write_synthetic_survey',
    'compare_with_truth',
    'demo_camera',
    'project_points',
    'DEMO_CRS',
    'SyntheticScene',
    'synthetic_roof',
    'KINDS',
    'Building',
    'Road',
    'Scene',
    'demo_scene',
    'AerialScene',
    'AerialSurvey',
    'Exposure',
    'RenderedPhoto',
    'aerial_survey',
    'load_aerial_survey',
    'render_photo',
    'Landscape',
    'make_landscape',
    'LANDSCAPES',
    'cavassim_experiment',
    'CAVASSIM_TABLE_09',
    'CAVASSIM_TABLES_06_08',
    'paper_camera',
    'matched_block',
    'MISMATCH_PX',
    'WRONG_RAY_PX',
    'MATCH_PIXEL_MM',
]
