"""Roof edges as line control (issue 29): the 3-D line of two fitted planes with its covariance, the
edge fit as a two-point line observation, line_control.csv's ``point`` and ``cov_m2`` columns, and
line control counted in the datum check."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lidarcat.bundle import check_datum
from lidarcat.bundle.lines import LineObservation
from lidarcat.control.planes import Plane
from lidarcat.errors import DatumError, SurveyError
from lidarcat.photocontrol import edge_line_m, measure
from lidarcat.survey.lines import LINE_COLUMNS, LINE_EXTRA_COLUMNS, cov6_cell, read_line_control
from lidarcat.synthetic.lines import line_block


def _plane(n, centroid, sd_n, sd_d):
    """A plane through *centroid* whose fit covariance is sd_n across the normal (it stays unit) and sd_d of
    the offset at the centroid, in the absolute frame of Plane.cov."""
    n = np.asarray(n, float) / np.linalg.norm(n)
    c_local = np.zeros((4, 4))
    c_local[:3, :3] = sd_n**2 * (np.eye(3) - np.outer(n, n))
    c_local[3, 3] = sd_d**2
    k_inv = np.eye(4)
    k_inv[3, :3] = -np.asarray(centroid, float)        # cov_at(centroid) = K cov K^T, K[3, :3] = centroid
    return Plane(n=n, d=-float(n @ centroid), cov=k_inv @ c_local @ k_inv.T, centroid_m=centroid)


def test_edge_line_covariance_matches_monte_carlo():
    """The 6 x 6 covariance of the end points (plane fits independent, each shared by both ends)
    against 3000 perturbed plane pairs intersected again: within 10 % across the line, A-B terms included."""
    rng = np.random.default_rng(3)
    pi = _plane([0.0, 0.5, 0.866], np.array([100.0, 201.5, 12.0]), 0.004, 0.01)
    pj = _plane([0.0, -0.5, 0.866], np.array([101.0, 195.5, 12.0]), 0.006, 0.015)
    ends = np.array([[98.0, 198.5, 13.0], [104.0, 198.5, 13.0]])
    a, b, cov = edge_line_m(pi, pj, ends)
    assert abs(float(pi.distance(a[None])[0])) < 1e-9 and abs(float(pj.distance(b[None])[0])) < 1e-9
    samples = []
    for _ in range(3000):
        di = rng.multivariate_normal(np.zeros(4), pi.cov_at(pi.centroid_m))
        dj = rng.multivariate_normal(np.zeros(4), pj.cov_at(pj.centroid_m))
        qi = Plane(n=pi.n + di[:3], d=pi.offset_at(pi.centroid_m) + di[3] - float((pi.n + di[:3]) @ pi.centroid_m),
                   cov=pi.cov, centroid_m=pi.centroid_m)
        qj = Plane(n=pj.n + dj[:3], d=pj.offset_at(pj.centroid_m) + dj[3] - float((pj.n + dj[:3]) @ pj.centroid_m),
                   cov=pj.cov, centroid_m=pj.centroid_m)
        qa, qb, _ = edge_line_m(qi, qj, np.array([a, b]))
        samples.append(np.r_[qa, qb])
    emp = np.cov(np.array(samples).T)
    t = (b - a) / np.linalg.norm(b - a)
    across = np.linalg.svd(np.eye(3) - np.outer(t, t))[0][:, :2]       # two directions across the line
    g = np.zeros((6, 4))
    g[:3, :2] = g[3:, 2:] = across
    np.testing.assert_allclose(g.T @ emp @ g, g.T @ cov @ g, rtol=0.1, atol=0.05 * float(np.max(np.diag(cov))))
    assert float(np.max(np.abs(cov @ np.r_[t, np.zeros(3)]))) < 1e-12     # nothing along the line


def test_edge_line_two_points_carry_the_fits_offset_variance():
    """EdgeLine's two points: for every position t along the edge the across-variance of the line
    through them equals the free fit's v(t) plus the floors (exact equivalence)."""
    cov = np.array([[0.04, -0.0012], [-0.0012, 1e-4]])
    u = np.array([0.6, 0.8])
    origin = np.array([300.0, 200.0])
    el = measure._edge_line((0, 2), origin, u, (np.array([0.3, 0.01]), cov), 5.0, 0.25, 0.5)
    c = cov + np.diag([0.25**2, np.tan(np.radians(0.5)) ** 2])
    nvec = np.array([-u[1], u[0]])
    p1, p2 = np.asarray(el.p1_px), np.asarray(el.p2_px)
    # both points on the fitted line s = 0.3 + 0.01 t
    for p in (p1, p2):
        t = float((p - origin) @ u)
        assert float((p - origin) @ nvec) == pytest.approx(0.3 + 0.01 * t, abs=1e-9)
    t1, t2 = float((p1 - origin) @ u), float((p2 - origin) @ u)
    for t in (-40.0, 0.0, 25.0, 90.0):
        s = (t - t1) / (t2 - t1)
        v_two = el.sd_px**2 * ((1 - s) ** 2 + s**2)
        v_fit = c[0, 0] + 2 * c[0, 1] * t + c[1, 1] * t * t
        assert v_two == pytest.approx(v_fit, rel=1e-9)
    assert el.planes == (0, 2) and el.ratio == 5.0


HEADER = ",".join(LINE_COLUMNS + LINE_EXTRA_COLUMNS)


def _line(lid, point="", cov=""):
    return f"{lid},,100.0,200.0,10.0,112.0,200.0,10.5,0.03,,,,,,,,,,,,{point},{cov}"


def _obs(lid, photo):
    return f"{lid},{photo},,,,,,,,,-1.0,2.0,3.0,2.5,0.004,,,,,,,"


def test_point_column_keeps_a_line_to_the_sets_where_its_vertex_is_control(tmp_path):
    cov = np.diag([1e-4, 1e-4, 4e-4, 1e-4, 1e-4, 4e-4])
    cov[0, 3] = cov[3, 0] = 5e-5
    p = tmp_path / "line_control.csv"
    p.write_text("\n".join([HEADER, _line("L1/1-2", "L1", f'"{cov6_cell(cov)}"'), _line("R9"),
                            _obs("L1/1-2", "a"), _obs("R9", "a"), _obs("R9", "b")]) + "\n")
    lines, obs = read_line_control(p, ["a", "b"])
    assert [ln.line for ln in lines] == ["L1/1-2", "R9"] and len(obs) == 3
    np.testing.assert_allclose(lines[0].cov_m2, cov, rtol=1e-7)      # the full covariance, cross terms kept
    lines, obs = read_line_control(p, ["a", "b"], control_points=["G1", "G2"])   # L1 not control: left out
    assert [ln.line for ln in lines] == ["R9"] and [o.line for o in obs] == ["R9", "R9"]
    lines, obs = read_line_control(p, ["a", "b"], control_points=["L1"])
    assert len(lines) == 2 and len(obs) == 3


@pytest.mark.parametrize("cell, message", [
    ("1 2 3", "line_control.csv:2: field 'cov_m2': 21 numbers (the upper triangle of the 6 x 6 covariance, row "
              "by row) separated by spaces, got 3"),
    (" ".join(["-1"] + ["0"] * 20), "line_control.csv:2: field 'cov_m2': not a covariance (not positive "
                                    "semi-definite)"),
    (" ".join(["x"] + ["0"] * 20), "line_control.csv:2: field 'cov_m2'"),
])
def test_bad_covariance_cell_is_located(tmp_path, cell, message):
    p = tmp_path / "line_control.csv"
    p.write_text("\n".join([HEADER, _line("L1/1-2", "L1", f'"{cell}"'), _obs("L1/1-2", "a")]) + "\n")
    with pytest.raises(SurveyError) as ex:
        read_line_control(p, ["a"])
    assert message in str(ex.value)


def test_line_control_counts_in_the_datum_check():
    """A block with lines and no control point or GNSS/IMU: its datum is fixed by 12 lines in many
    directions (was: 'no control'); with the lines of one direction only, or none, it is not."""
    blk = line_block(12, seed=0)
    p = dataclasses.replace(blk.problem, eo_constraint_photo_index=None, eo_constraint_params=None,
                            eo_constraint_sd=None)
    check_datum(p)
    with pytest.raises(DatumError, match="no control in the block"):
        check_datum(dataclasses.replace(p, lines=None))
    L = p.lines
    one_dir = dataclasses.replace(L, b_m=L.a_m + (L.b_m - L.a_m)[:1])      # every line parallel to the first
    with pytest.raises(DatumError, match="no control in the block"):
        check_datum(dataclasses.replace(p, lines=one_dir))


def test_edge_line_observation_is_a_line_observation():
    el = measure.EdgeLine((0, 1), [10.0, 20.0], [30.0, 40.0], 0.4, 4.0)
    o = LineObservation("L1/1-2", "a", el.p1_px * 0.006, el.p2_px * 0.006, el.sd_px * 0.006, 0.006)
    assert o.sd_mm == pytest.approx(0.0024)


def test_line_table_keeps_other_lines_and_replaces_the_measured_vertex(tmp_path):
    """measure-control's line_control.csv: a hand-made line and the lines of vertices not measured now are kept,
    the re-measured vertex's rows replaced; survey.toml gets [files] line_control once."""
    from lidarcat.stages import _control_tables as mc

    p = tmp_path / "line_control.csv"
    p.write_text("\n".join([HEADER, _line("R9"), _obs("R9", "a"), _line("L1/1-2", "L1"), _obs("L1/1-2", "a"),
                            _line("L2/1-3", "L2"), _obs("L2/1-3", "b")]) + "\n")
    el = measure.EdgeLine((0, 1), [10.0, 20.0], [30.0, 40.0], 0.4, 4.0)
    cov = np.eye(6) * 1e-4
    header, rows = mc.line_control_rows(None, p, {"L1/1-2": ("L1", [0.0, 0, 0], [1.0, 0, 0], cov)},
                                        [("L1/1-2", "b", el)], {"L1"})
    got = [(r[0], r[1]) for r in rows]
    assert got == [("R9", ""), ("R9", "a"), ("L2/1-3", ""), ("L2/1-3", "b"), ("L1/1-2", ""), ("L1/1-2", "b")]
    assert header[-2:] == ["point", "cov_m2"] and rows[-2][-2] == "L1"
    toml = tmp_path / "survey.toml"
    toml.write_text('[survey]\nname = "x"\n\n[files]\ncamera = "camera.toml"\n\n[lidar]\ncrs = "EPSG:1"\n')
    mc.add_line_control_key(toml, tmp_path / "line_control.csv")
    import tomllib

    assert tomllib.loads(toml.read_text())["files"] == {"line_control": "line_control.csv", "camera": "camera.toml"}
