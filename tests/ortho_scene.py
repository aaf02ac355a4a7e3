"""The synthetic orthophoto scene shared by tests/mapping and tests/stages: camera, photos, area."""

from __future__ import annotations

import functools
import math

import numpy as np

from lidarcat.geometry.camera import Camera

E0, N0 = 680_400.0, 7_184_200.0
#: a small camera with the demo's 36 x 24 mm frame: 1200 x 800 px of 30 um, c = 35 mm
CAM = Camera("small", 35.0, 0.01, -0.02, -2.5e-5, 1e-8, 0.0, 2e-6, -1e-6, 0.0, 0.03, 0.03, 1200, 800)
#: 250 m above the ground: 0.21 m photo pixels; nadir 40 m west of the scene centre
EO_A = np.array([E0 - 40, N0 + 10, 910 + 250.0, math.radians(1.0), math.radians(-0.8), math.radians(20.0)])
EO_B = np.array([E0 + 60, N0 - 5, 910 + 250.0, math.radians(-0.7), math.radians(0.9), math.radians(-10.0)])
GSD = 0.25
BOUNDS = (E0 - 100, N0 - 60, E0 + 100, N0 + 60)
MODEL_BOUNDS = (E0 - 130, N0 - 90, E0 + 130, N0 + 90)


@functools.lru_cache(maxsize=None)
def rendered(which: str) -> np.ndarray:
    """The demo scene photographed by CAM from EO_A (``"A"``) or EO_B (``"B"``), rendered once per test
    process (about 10 s each at load 17; seven test files use them) and read-only, so no test can
    change another's photo."""
    from lidarcat.synthetic.scene import demo_scene

    img = demo_scene().render(CAM, {"A": EO_A, "B": EO_B}[which])
    img.setflags(write=False)
    return img
