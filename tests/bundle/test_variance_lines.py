"""Variance components of line control (lidarcat.bundle.variance, group ``lines``) with known truth.

``line_block`` measures its roof edges with 4 um; declared with 8 um (sds 2 x too large) the
estimated line factor must come out 0.25 within its sd, the other groups as with the right sds.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from lidarcat.bundle.line_tests import line_tests
from lidarcat.bundle.redundancy import reliability
from lidarcat.bundle.solve import adjust
from lidarcat.bundle.variance import (
    GROUPS,
    estimate_components,
    iterate_components,
    line_group,
    scaled_problem,
    snoop_with_components,
)
from lidarcat.synthetic.lines import line_block

PIXEL_MM = 0.006


def _fit(pr):
    r = adjust(pr, precision="photos")
    return r, reliability(r).redundancy, None, r


def _declared(problem, scale: float):
    """*problem* with its line observations' sds multiplied by *scale* (the noise stays)."""
    return dataclasses.replace(problem, lines=dataclasses.replace(problem.lines, sd_mm=problem.lines.sd_mm * scale))


def _components(problem) -> dict:
    vc = iterate_components(problem, _fit)
    assert vc.converged
    return {c.group: c for c in vc.components}


def test_lines_is_a_group():
    assert GROUPS[-1] == "lines" and GROUPS[:5] == ("tie", "target", "control", "gnss", "imu")


def test_line_factor_of_sds_twice_too_large_is_a_quarter():
    """Seeds 0-2: each estimate within 3 of its sds of the true 0.25 (seen: 0.35, 0.21, 0.46, sds
    0.04-0.09), their mean within 3 sds of the mean; a factor of 1 (the group left out) or 0.5 (sds scaled,
    not variances) would be 3-18 sds off.  16 seeds (benchmark run by hand): mean 0.255, the estimates'
    sd over the seeds 0.066 against the quoted 0.052; with the right sds mean 1.003."""
    est, sds = [], []
    for seed in range(3):
        b = line_block(seed=seed)
        c = _components(_declared(b.problem, 2.0))
        lines = c["lines"]
        assert lines.estimated and lines.n == 2 * len(b.problem.lines.line_index)
        assert abs(lines.factor - 0.25) < 3 * lines.factor_sd, (seed, lines.factor, lines.factor_sd)
        est.append(lines.factor)
        sds.append(lines.factor_sd)
        if seed == 0:       # the other groups as with the right line sds (tie ~1; GNSS/IMU too little redundancy)
            right = _components(b.problem)
            assert c["tie"].factor == pytest.approx(right["tie"].factor, abs=0.005)
            assert c["tie"].factor == pytest.approx(1.0, abs=3 * c["tie"].factor_sd)
            assert not c["gnss"].estimated and not c["imu"].estimated
            assert c["gnss"].factor == c["imu"].factor == 1.0
            # with the right sds the line factor is 1 within its sd, and the ratio of the two estimates 1/4
            assert abs(right["lines"].factor - 1.0) < 3 * right["lines"].factor_sd
            assert lines.factor / right["lines"].factor == pytest.approx(0.25, rel=0.05)
    assert abs(np.mean(est) - 0.25) < 3 * math.sqrt(np.sum(np.square(sds))) / len(sds)
    # the text report of `lidarcat adjust` lists the group beside the others
    from lidarcat.cli.adjust import format_components

    vc = iterate_components(_declared(line_block(seed=0).problem, 2.0), _fit)
    text = format_components({"variance_components": vc.summary()})
    row = next(ln for ln in text if ln.strip().startswith("lines "))
    f = {c.group: c for c in vc.components}["lines"]
    assert row.split()[1] == str(f.n) and row.split()[-1] == f"{f.sd_scale:.3f}"


def test_line_group_sums_are_the_line_tests():
    b = line_block(seed=1)
    r = adjust(b.problem, precision="photos")
    n, red, vtpv = line_group(r)
    t = line_tests(r)
    assert n == 2 * len(b.problem.lines.line_index)
    assert red == pytest.approx(float(t.redundancy.sum()))
    # v'Pv of the lines: the adjustment's total less the points' and constraints' (reliability's rows)
    comps = {c.group: c for c in estimate_components(r, reliability(r).redundancy)}
    others = sum(c.vtpv for g, c in comps.items() if g != "lines")
    assert vtpv == pytest.approx(r.vtpv - others, rel=1e-6)
    assert comps["lines"].vtpv == pytest.approx(vtpv) and comps["lines"].redundancy == pytest.approx(red)
    # the redundancy numbers of every group sum to the degrees of freedom
    assert sum(c.redundancy for c in comps.values()) == pytest.approx(r.dof, abs=1e-6)
    # without lines: no group; without photo covariances: present, redundancy unknown, not estimated
    assert line_group(adjust(dataclasses.replace(b.problem, lines=None))) is None
    r0 = adjust(b.problem, precision="none")
    n0, red0, _ = line_group(r0)
    assert n0 == n and math.isnan(red0)
    c0 = {c.group: c for c in estimate_components(r0, np.full((1, 6), np.nan))}
    assert not c0["lines"].estimated and c0["lines"].factor == 1.0


def test_a_rejected_line_observation_is_left_out_of_the_sums():
    b = line_block(seed=0)
    L = b.problem.lines
    k = 0
    d = L.xy2_mm[k] - L.xy1_mm[k]
    nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    xy1, xy2 = L.xy1_mm.copy(), L.xy2_mm.copy()
    xy1[k] += 6 * PIXEL_MM * nrm              # 36 um across an edge measured to 4 um
    xy2[k] += 6 * PIXEL_MM * nrm
    bad = dataclasses.replace(b.problem, lines=dataclasses.replace(L, xy1_mm=xy1, xy2_mm=xy2))
    r = adjust(bad, precision="photos")
    t = line_tests(r)
    assert int(t.rejected[0]) == k
    n_all, red_all, v_all = line_group(r)
    n_kept, red_kept, v_kept = line_group(r, reject=True)
    gone = len(t.rejected)
    assert n_kept == n_all - 2 * gone
    assert red_kept == pytest.approx(red_all - float(t.redundancy[t.rejected].sum()))
    assert v_kept < 0.5 * v_all                 # the blunder dominated the group's v'Pv
    # snooping with components: the rounds leave it out, so the line factor stays near 1 (not the blunder's)
    vc = snoop_with_components(bad, mode="remove", precision="photos")
    f = {c.group: c for c in vc.components}["lines"]
    assert f.estimated and abs(f.factor - 1.0) < 3 * f.factor_sd


def test_scaled_problem_scales_the_line_image_sds_only():
    b = line_block(seed=2)
    p = b.problem
    q = scaled_problem(p, {"lines": 0.25})
    np.testing.assert_allclose(q.lines.sd_mm, 0.5 * p.lines.sd_mm)
    np.testing.assert_array_equal(q.lines.cov_m2, p.lines.cov_m2)     # the 3-D lines' covariance stays
    np.testing.assert_array_equal(q.sd_mm, p.sd_mm)
    assert scaled_problem(p, {"tie": 4.0}).lines is p.lines


def _demo_with_lines(tmp_path: Path, declared_mm: float) -> Path:
    """The demo survey plus 8 roof lines through its true tie points, measured at the true orientation
    (truth/) with 3 um noise and written with sd *declared_mm*; the lines exact, declared 0.1 mm across,
    so that the image sds are the group's whole noise."""
    import csv

    from lidarcat.geometry.collinearity import project
    from lidarcat.survey.lines import LINE_COLUMNS
    from lidarcat.synthetic import write_synthetic_survey
    from lidarcat.synthetic.survey import demo_camera

    demo = write_synthetic_survey(tmp_path / "s", lidar_density_m2=0.2)

    def table(name):
        with open(demo.path / "truth" / name, encoding="utf-8") as fh:
            return list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))

    eop = table("eop.csv")
    eo = np.array([[float(r[c]) for c in ("X0", "Y0", "Z0", "omega", "phi", "kappa")] for r in eop])
    eo[:, 3:] = np.radians(eo[:, 3:])
    pids = [r["photo"] for r in eop]
    pts = np.array([[float(r[c]) for c in ("E", "N", "h")] for r in table("points.csv") if r["kind"] == "tie"])
    f = float(demo_camera().focal_length_mm)
    lo = np.array([0.45 * demo_camera().columns_px, 0.45 * demo_camera().rows_px]) * demo_camera().pixel_size_x_mm
    rows = []
    rng, noise = np.random.default_rng(5), np.random.default_rng(6)
    for k in range(8):
        c = pts[rng.integers(len(pts))]
        d = np.array([np.cos(np.pi * k / 8), np.sin(np.pi * k / 8), 0.0])
        a, b = c - 6 * d, c + 6 * d
        rows.append(f"R{k},,{a[0]},{a[1]},{a[2]},{b[0]},{b[1]},{b[2]},0.0001,0.2,,,,,,,,,,")
        for i, pid in enumerate(pids):
            ends = np.stack([a + 0.2 * (b - a), a + 0.8 * (b - a)])
            xy, u3 = project(np.broadcast_to(eo[i], (2, 6)), ends, np.full(2, f))
            if np.all(u3 < 0) and np.all(np.abs(xy) < lo):
                xy = xy + noise.normal(0.0, 0.003, (2, 2))
                rows.append(f"R{k},{pid},,,,,,,,,{xy[0, 0]},{xy[0, 1]},{xy[1, 0]},{xy[1, 1]},{declared_mm},,,,,")
    (demo.path / "line_control.csv").write_text(",".join(LINE_COLUMNS) + "\n" + "\n".join(rows) + "\n")
    toml = demo.path / "survey.toml"
    toml.write_text(toml.read_text().replace('extraction_jobs = "jobs.csv"',
                                             'extraction_jobs = "jobs.csv"\nline_control = "line_control.csv"'))
    return demo.path


@pytest.mark.slow
def test_adjust_reports_the_line_factor(tmp_path):
    """`lidarcat adjust --variance-components` on a survey with line control measured to 3 um and declared
    6 um: summary.json and the text report carry the ``lines`` group, its factor 0.25 within its sd."""
    from click.testing import CliRunner

    from lidarcat.cli.main import cli

    folder = _demo_with_lines(tmp_path, 0.006)
    out = tmp_path / "vc"
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(out), "--variance-components"])
    assert r.exit_code == 0, r.output
    groups = {g["group"]: g for g in json.loads((out / "summary.json").read_text())["variance_components"]["groups"]}
    g = groups["lines"]
    assert g["estimated"] and g["redundancy"] > 10
    assert abs(g["factor"] - 0.25) < 3 * g["factor_sd"], g
    assert g["sd_scale"] == pytest.approx(math.sqrt(g["factor"]))
    row = next(ln for ln in r.output.splitlines() if ln.strip().startswith("lines "))
    assert f"{g['n']}" in row.split() and row.split()[-1] == f"{g['sd_scale']:.3f}"
