"""`lidarcat match` names a blank photo as a reported skip and writes its tie points for the others."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.synthetic.textured import write_textured_survey


def test_a_blank_photo_is_named_and_the_others_are_matched(tmp_path):
    import cv2

    ts = write_textured_survey(tmp_path / "s", n_strips=1, per_strip=3, columns_px=320, rows_px=240, seed=2)
    cv2.imwrite(str(tmp_path / "s" / "images" / "03.png"), np.full((240, 320), 128, np.uint8))   # blank
    r = CliRunner().invoke(cli, ["match", str(ts.folder), "--per-cell", "0"])
    assert r.exit_code == 0, r.output
    assert "no tie point on 1 photo(s): 03 (no overlapping photo, no features, or no pair verified" in r.output
    rep = json.loads((tmp_path / "s" / "out" / "match" / "match_report.json").read_text())
    by_photo = {p["photo"]: p for p in rep["per_photo"]}
    assert by_photo["03"]["keypoints"] == 0 and by_photo["03"]["tie_points"] == 0
    assert by_photo["01"]["tie_points"] > 50 and by_photo["02"]["tie_points"] > 50
