"""Issue 25: rendering the demo's photos reports progress photo by photo (it takes minutes)."""

from __future__ import annotations

import pytest

from lidarcat.synthetic.survey import write_synthetic_survey


@pytest.mark.slow
def test_progress_counts_every_rendered_photo(tmp_path):
    calls = []
    write_synthetic_survey(tmp_path / "d", n_photos=2, lidar_density_m2=0.05, images=True, image_downsample=20,
                           progress=lambda done, total: calls.append((done, total)))
    assert calls == [(1, 7), (2, 7), (3, 7), (4, 7), (5, 7), (6, 7), (7, 7)]
    without = []
    write_synthetic_survey(tmp_path / "e", n_photos=2, lidar_density_m2=0.05,
                           progress=lambda done, total: without.append((done, total)))
    assert without == [(1, 5), (2, 5), (3, 5), (4, 5), (5, 5)]
