"""Photos + LiDAR-derived control + GNSS/IMU, end to end (issue 29).

1. ``match`` -> ``measure-control`` -> ``adjust`` on a rendered block
   (:func:`lidarcat.synthetic.aerial.aerial_survey`: two strips of three photos, 1000 x 750 px at
   0.1 m GSD, roofs shaded per ray and anti-aliased; approximate orientation 2 m / 0.5 deg off, given
   as photos.csv sds: the GNSS/IMU), LiDAR tiles (10 points/m^2, 3 cm noise) and the roof vertices as
   ground points of source ``lidar`` (the true vertex plus 3 cm noise, sd 3 cm), control set ``lidar``
   (the vertices control, the four GPS targets check).
2. The acceptance: ``lidarcat run`` on the same kind of block with the vertices from ``lidarcat
   extract --find`` and no image coordinate of them given by hand, beside the block with the vertices
   measured by hand (``benchmarks/bench_measured_control.py``).

Both slow (minutes on the shared machine: rendering, matching, two runs); the truth scores only.  The
fast cases of the same code: tests/photocontrol/test_lines.py (the roof edge's 3-D line and
covariance, the edge fit as a line observation, line_control.csv's point/cov_m2 columns, lines in the
datum check), tests/survey/test_measured_control_in_adjustment.py (a one-ray ground point left out
where it is not control, lines by their LiDAR point), tests/photocontrol/test_measure.py and
tests/synthetic/test_roof_edges.py.
"""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import ROOT
from lidarcat.cli.main import cli
from lidarcat.synthetic.aerial import aerial_survey

sys.path.insert(0, str(ROOT / "benchmarks"))
import bench_photos_to_block as bench  # noqa: E402


def lidar_controlled_survey(root, seed: int = 1):
    """The block above with its LiDAR vertices as ground points and the control set ``lidar``."""
    s = aerial_survey(root, n_strips=2, photos_per_strip=3, gsd_m=0.1, image_size_px=(1000, 750),
                      lidar_density_m2=10, lidar_noise_m=0.03, n_gps_points=4, seed=seed, supersample=4)
    sc = s.scene
    rng = np.random.default_rng(seed)
    verts = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    noisy = verts + rng.normal(0, 0.03, verts.shape)
    gp = root / "ground_points.csv"
    gp.write_text(gp.read_text().rstrip("\n") + "\n" + "".join(
        f"L{i + 1:03d},{v[0]:.3f},{v[1]:.3f},{v[2]:.3f},0.03,0.03,0.03,lidar\n" for i, v in enumerate(noisy)))
    cs = root / "control_sets.csv"
    gps = [ln.split(",")[1] for ln in cs.read_text().splitlines()[1:] if ln.startswith("gps,")]
    cs.write_text(cs.read_text().rstrip("\n") + "\n"
                  + "".join(f"lidar,L{i + 1:03d},control,,,\n" for i in range(len(verts)))
                  + "".join(f"lidar,{g},check,,,\n" for g in gps))
    return s, {f"L{i + 1:03d}": v for i, v in enumerate(verts)}


@pytest.mark.slow
def test_match_measure_control_adjust_orients_the_block_on_lidar_control(tmp_path):
    root = tmp_path / "survey"
    s, truth = lidar_controlled_survey(root)
    r = CliRunner().invoke(cli, ["match", str(root), "-o", str(tmp_path / "match")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(cli, ["measure-control", str(root), "--json", "-o", str(tmp_path / "mc")])
    assert r.exit_code == 0, r.output
    mc = json.loads(r.output)
    assert mc["accepted"] >= 4                    # vertices accepted on two photos or more
    r = CliRunner().invoke(cli, ["adjust", str(root), "--control", "lidar", "--eo-constraints", "--snooping",
                                 "remove", "-o", str(tmp_path / "adjust")])
    assert r.exit_code in (0, 3), r.output
    summary = json.loads((tmp_path / "adjust" / "summary.json").read_text())
    assert summary["control_set"] == "lidar"
    sc = bench.score_block(s, root, tmp_path / "adjust")
    assert sc["status"] == "converged"
    assert sc["max_z"] <= 3.0, sc                   # every orientation within 3 sd of truth
    # the LiDAR control was used: its observations are in the adjustment's residuals
    res = (tmp_path / "adjust" / "residuals.csv").read_text()
    assert sum(",L0" in ln for ln in res.splitlines()) >= 4


@pytest.mark.slow
def test_lidarcat_run_with_measured_control_is_as_good_as_hand_measured(tmp_path):
    """Issue 29's end-to-end acceptance (``benchmarks/bench_measured_control.py``, seed 1): the LiDAR
    vertices from ``lidarcat extract --find`` on the block's own tiles; ``lidarcat run`` with no image
    coordinate of them given by hand (match -> measure_control: points and roof-edge lines -> adjust-gps,
    adjust-lidar -> assess -> report) exits 0 (the run's variance components scale the tie points' and
    the control's sds; every stage ran), orients the block within 3 sd of truth, and its rms errors are
    within 1.5 x those of the same block with the vertices measured by hand (true projection + 0.5 px)."""
    import shutil

    import bench_measured_control as mc

    s, truth = mc.build(tmp_path / "auto", seed=1)
    assert len(truth) >= 6                                       # extract --find found the roofs' vertices
    shutil.copytree(tmp_path / "auto", tmp_path / "hand")
    assert mc.hand_measure(s, tmp_path / "hand", truth, seed=1) >= 8
    auto = mc.run_variant(s, tmp_path / "auto", tmp_path / "run-auto")
    hand = mc.run_variant(s, tmp_path / "hand", tmp_path / "run-hand")
    assert auto["exit"] == 0 and hand["exit"] == 0, (auto, hand)
    summary = json.loads((tmp_path / "run-auto" / "summary.json").read_text())
    status = {st["name"]: st["status"] for st in summary["stages"]}
    assert status["match"] == status["measure_control"] == status["adjust-lidar"] == "ran"
    assert "failed" not in status.values()
    assert auto["lidar_observations"] >= 4
    assert auto["max_z"] <= 3.0, auto                            # every orientation within 3 sd of truth
    assert auto["pos_rms_m"] <= 1.5 * hand["pos_rms_m"], (auto, hand)
    assert auto["att_rms_deg"] <= 1.5 * hand["att_rms_deg"], (auto, hand)
    # the GPS check points in the thesis's accuracy class (PEC 1:2000, class A, assess-lidar) as by hand
    assert auto["pec"]["planimetric"] == auto["pec"]["altimetric"] == "A", auto["pec"]
    assert hand["pec"]["planimetric"] == hand["pec"]["altimetric"] == "A", hand["pec"]
