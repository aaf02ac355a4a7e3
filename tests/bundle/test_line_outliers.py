"""Line observations in the same outlier machinery as image points and GNSS/INS groups (issue 29).

The case of seed 4 of the measured-control benchmark, synthetic with known truth: a block held by
weak GNSS/IMU (2 m / 0.5 deg), a few roof lines, ONE correct LiDAR vertex measured on one photo,
and one line observation 60 px across its line on another photo.  Before, the point snooping ran
first with the gross line in and untested: over seeds 0-3 (two lines each) it removed the correct
vertex in all 8 trials (first in 7, w 10-51) and the GNSS/INS groups of 6-12 of the 12 photos, the
photos ending 5-137 m off; the line snooping came after.
Now the line observation is a group of the one worst-first loop (its 2-D test at the block's level)
and of the robust re-weightings, so it is named first and alone.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle import adjust
from lidarcat.bundle.redundancy import reliability
from lidarcat.bundle.reliability import snoop
from lidarcat.bundle.robust import robust_start
from lidarcat.synthetic.lines import line_block

PIXEL_MM = 0.006


def _case(seed: int, off_px: float = 60.0, which: int = 0):
    """line_block with 4 lines and one control point kept on ONE of its photos (sd 5 cm); a line
    observation on another photo moved *off_px* across.  Returns (block, problem, label, vertex photo)."""
    b = line_block(4, seed=seed, n_control_points=1)
    p = b.problem
    j = int(p.constraint_point_index[0])
    rays = np.flatnonzero(p.point_index == j)
    keep = np.ones(len(p.photo_index), bool)
    keep[rays[1:]] = False
    vertex_photo = str(p.photo_ids[p.photo_index[rays[0]]])
    p = dataclasses.replace(p, photo_index=p.photo_index[keep], point_index=p.point_index[keep],
                            xy_mm=p.xy_mm[keep], sd_mm=p.sd_mm[keep], constraint_sd_m=np.full((1, 3), 0.05))
    L = p.lines
    cand = [k for k in range(len(L.line_index)) if p.photo_ids[L.photo_index[k]] != vertex_photo]
    k = cand[which % len(cand)]
    d = L.xy2_mm[k] - L.xy1_mm[k]
    n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    xy1, xy2 = L.xy1_mm.copy(), L.xy2_mm.copy()
    xy1[k] += off_px * PIXEL_MM * n
    xy2[k] += off_px * PIXEL_MM * n
    p = dataclasses.replace(p, lines=dataclasses.replace(L, xy1_mm=xy1, xy2_mm=xy2))
    return b, p, L.observation_labels(p.photo_ids)[k], vertex_photo


def _without(p, label):
    L = p.lines
    keep = np.array([lab != label for lab in L.observation_labels(p.photo_ids)])
    return dataclasses.replace(p, lines=L.select(keep))


@pytest.mark.parametrize("seed,which", [(0, 0), (1, 3), (3, 0)])
def test_a_gross_line_is_removed_alone_and_the_vertex_and_gnss_stay(seed, which):
    b, p, label, vertex_photo = _case(seed, which=which)
    sres = snoop(p, mode="remove")
    assert [(bl.kind, f"line {bl.point} on photo {bl.photo}", bl.removed) for bl in sres.blunders] == [
        ("line", label, True)]
    bl = sres.blunders[0]
    rel = sres.reliability
    assert bl.w > 50 and bl.w_critical == pytest.approx(rel.w_critical[(rel.kind == "image") & (rel.q == 2)][0])
    res = sres.result
    # the vertex's ray and control point and every GNSS/INS group are in the final adjustment
    assert len(res.problem.photo_index) == len(p.photo_index)
    assert len(res.problem.constraint_point_index) == 1
    assert len(res.problem.eo_constraint_photo_index) == p.n_photos
    assert res.problem.lines.n_observations == p.lines.n_observations - 2
    # = the adjustment without that one observation; no test rejects
    ref = adjust(_without(p, label), initial=(b.initial_eo, None))
    assert res.vtpv == pytest.approx(ref.vtpv, rel=1e-6)
    np.testing.assert_allclose(res.eo_params, ref.eo_params, atol=1e-5)
    assert sres.reliability.n_rejected == 0
    z = (res.eo_params[:, :3] - b.true_eo[:, :3]) / res.eo_sd[:, :3]
    assert np.abs(z).max() < 3


def test_the_line_rows_of_reliability_are_the_2d_line_tests():
    """A line observation is a 2-D group like an image point: its w is line_tests' e^T Q_vv^-1 e, at the
    same critical value as the image points' 2-D tests; the 60 px line is the worst group of the block."""
    from lidarcat.bundle.line_tests import line_tests

    b, p, label, _ = _case(0)
    res = adjust(p, initial=(b.initial_eo, None))
    rel = reliability(res)
    on = rel.kind == "line"
    t = line_tests(res, level=rel.alpha)
    np.testing.assert_allclose(rel.w[on], t.w, rtol=1e-9)
    np.testing.assert_allclose(rel.redundancy[on, :2], t.redundancy, atol=1e-12)
    assert rel.q[on].tolist() == [2] * int(on.sum())
    two = (rel.kind == "image") & (rel.q == 2)
    assert np.all(rel.w_critical[on] == rel.w_critical[two][0]) and t.critical_w == rel.w_critical[on][0]
    g = rel.worst()
    assert (rel.kind[g], f"line {rel.point[g]} on photo {rel.photo[g]}") == ("line", label)
    # the row reported like the points' rows (reliability.csv)
    rows = [r for r in rel.rows() if r[0] == "line"]
    assert len(rows) == 2 * int(on.sum()) and {r[3] for r in rows} == {"a", "b"} and {r[4] for r in rows} == {"mm"}


def test_the_robust_start_weights_the_gross_line_down_and_keeps_the_vertex():
    """The Cauchy re-weighting of the robust start (what seed 4's adjustment ran): the line observations
    are re-weighted with the image points (weight matrix x factor), the 60 px one falls below 0.01,
    the vertex's ray keeps its weight."""
    b, p, label, vertex_photo = _case(0)
    rs = robust_start(p, initial=(b.initial_eo, None), loss="cauchy")
    labels = p.lines.observation_labels(p.photo_ids)
    assert [labels[k] for k in np.flatnonzero(~rs.keep_lines)] == [label]
    assert rs.keep.all() and rs.n_rejected == 1
    assert rs.line_weight[labels.index(label)] < 0.01
    assert np.delete(rs.line_weight, labels.index(label)).min() > 0.5
    sres = snoop(p, mode="remove", loss="cauchy")
    assert [(bl.kind, bl.found_by, bl.removed) for bl in sres.blunders] == [("line", "cauchy", True)]
    assert len(sres.result.problem.eo_constraint_photo_index) == p.n_photos
    rep = snoop(p, mode="report", loss="cauchy")
    assert [(bl.kind, bl.removed) for bl in rep.blunders] == [("line", False)]
    assert rep.result.problem.lines.n_observations == p.lines.n_observations


@pytest.mark.parametrize("robust", ["danish", "huber"])
def test_danish_and_huber_weight_the_gross_line_down(robust):
    b, p, label, _ = _case(1, which=3)
    sres = snoop(p, mode="remove", robust=robust)
    assert [(bl.kind, f"line {bl.point} on photo {bl.photo}", bl.found_by) for bl in sres.blunders] == [
        ("line", label, robust)]
    assert len(sres.result.problem.eo_constraint_photo_index) == p.n_photos
    assert len(sres.result.problem.constraint_point_index) == 1


def test_a_line_observation_that_passes_at_the_solution_is_put_back():
    """A correct line observation the robust start rejected (here: forced by a zero weight) goes back in
    when its residual pair at the solution passes the 2-D test."""
    from lidarcat.bundle.robust import put_back_lines

    b, p, label, _ = _case(0, off_px=0.0)
    res = adjust(p, initial=(b.initial_eo, None))
    w2 = reliability(res).w_critical[0]
    rej = np.ones(len(p.lines.line_index), bool)
    assert put_back_lines(p, rej, res.eo_params, w2).all()
    _, bad, label, _ = _case(0)
    labels = bad.lines.observation_labels(bad.photo_ids)
    back = put_back_lines(bad, rej, res.eo_params, w2)
    assert [labels[k] for k in np.flatnonzero(~back)] == [label]
