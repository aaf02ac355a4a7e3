"""Photos + LiDAR-derived control + GNSS/IMU: ``match`` -> ``measure-control`` -> ``adjust`` (issue 29).

A rendered block (:func:`lidarcat.synthetic.aerial.aerial_survey`: two strips of three photos,
1000 x 750 px at 0.1 m GSD, roofs shaded per ray and anti-aliased; approximate orientation
2 m / 0.5 deg off, given as photos.csv sds: the GNSS/IMU), LiDAR tiles (10 points/m^2, 3 cm noise)
and the roof vertices as ground points of source ``lidar`` (the true vertex plus 3 cm noise, sd
3 cm: what ``lidarcat extract`` gives), no image coordinate of them given by hand.  The control set
``lidar`` holds the vertices as control and the four GPS targets as check points.  The truth scores
the result only (``benchmarks/bench_photos_to_block.py``'s scoring).  Then ``lidarcat run`` on the
same survey.  Both slow (~35 s each at load 3); the fast cases of the modules are in
tests/photocontrol/test_measure.py, tests/stages/test_measure_control.py and
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
def test_lidarcat_run_measures_the_control_and_runs_every_stage(tmp_path):
    """``lidarcat run`` on the same survey: match -> measure_control -> camera -> adjust-gps, adjust-lidar
    -> assess -> compare -> report, none failed (a vertex accepted on one photo once made adjust-gps fail:
    a free point of one ray); exit 3 = the variance factor's test (the synthetic survey's a-priori image
    sd of 0.3 px against tie residuals of ~0.06 px), not a failed stage."""
    root = tmp_path / "survey"
    s, _ = lidar_controlled_survey(root)
    r = CliRunner().invoke(cli, ["run", str(root), "-o", str(tmp_path / "run")])
    assert r.exit_code in (0, 3), r.output
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    status = {st["name"]: st["status"] for st in summary["stages"]}
    assert status["match"] == status["measure_control"] == "ran"
    assert status["adjust-gps"] == status["adjust-lidar"] == "ran"
    assert "failed" not in status.values()
    # the LiDAR-controlled run: its orientation within 3 sd of truth
    import csv

    rows = {r["photo"]: r for r in csv.DictReader(ln for ln in open(tmp_path / "run" / "adjust-lidar" / "eop.csv")
                                                   if not ln.startswith("#"))}
    truth = np.asarray(s.true_eo, float).copy()
    truth[:, 3:] = np.degrees(truth[:, 3:])
    est = np.array([[float(rows[p][c]) for c in bench.EO_NAMES] for p in s.photo_ids])
    sd = np.array([[float(rows[p]["sd_" + c]) for c in bench.EO_NAMES] for p in s.photo_ids])
    d = est - truth
    d[:, 3:] = (d[:, 3:] + 180.0) % 360.0 - 180.0
    assert np.abs(d / sd).max() <= 3.0
