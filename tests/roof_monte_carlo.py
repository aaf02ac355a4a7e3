"""The roofs of the extraction Monte Carlo (tests/control/test_control.py), shared with the tests that rebuild one run.

Per run *i*: azimuth U(0, 90) deg, slope U(25, 45) deg and the offset of the position asked U(-1, 1) m per
axis, drawn in that order from one ``default_rng(0)`` stream; the roof of ``synthetic_roof(seed=1000 + i)``
with facades and ground, 0.03 m plan noise.  A run is the same roof whichever runs are asked for.
"""

from __future__ import annotations

from typing import Iterable, Iterator

import numpy as np

from lidarcat.synthetic.roofs import synthetic_roof


def monte_carlo_roofs(kind: str, density_m2: float, noise_h_m: float,
                      runs: Iterable[int] = range(200)) -> Iterator[tuple[int, object, np.ndarray]]:
    """Yield ``(run, scene, position asked (E, N; m))`` for *runs* (ascending), the vertex ``scene.vertices[0]``."""
    wanted = sorted(set(runs))
    rng = np.random.default_rng(0)
    for i in range(wanted[-1] + 1 if wanted else 0):
        azimuth, slope, off = rng.uniform(0, 90), rng.uniform(25, 45), rng.uniform(-1, 1, 2)
        if i in wanted:
            s = synthetic_roof(kind, density_m2=density_m2, noise_h_m=noise_h_m, noise_plan_m=0.03,
                               seed=1000 + i, azimuth_deg=azimuth, slope_deg=slope)
            yield i, s, s.vertices[0][:2] + off
