"""The block test of the vertex measurements (photocontrol.check_block) on a synthetic block with
known truth: 2 strips x 3 photos at GSD 0.15 m, the approximate orientation 2 m / 0.5 deg off, tie
points projected with the true orientation plus 0.3 px noise, each vertex measured on a few photos
(true projection + 0.3 px); one photo has a single measurement (as the gross ones over the AHN3
roofs)."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from lidarcat.errors import LidarcatError
from lidarcat.photocontrol import BlockCheck, Measurement, TieObservations, check_block, check_photo, pixel_positions
from lidarcat.synthetic.aerial import aerial_camera

CAM = aerial_camera((1000, 750))                   # c = 35 mm, 0.036 mm pixels
H = 146.0                                          # GSD 0.15 m
EO_COV = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
CENTRES = [(-60.0, -30.0), (0.0, -30.0), (60.0, -30.0), (-60.0, 30.0), (0.0, 30.0), (60.0, 30.0)]
PHOTOS = [f"p{k}" for k in range(6)]
#: vertices (E, N, h) and the photos each is measured on; p0 has A1 alone, p5 has A4 alone
VERTS = {"A1": np.array([-70.0, -10.0, 9.0]), "A2": np.array([-10.0, 0.0, 7.5]),
         "A3": np.array([20.0, 5.0, 11.0]), "A4": np.array([70.0, 15.0, 8.0])}
MEASURED = {"A1": ["p0", "p3"], "A2": ["p1", "p3", "p4"], "A3": ["p1", "p2", "p4"], "A4": ["p5", "p2"]}
VCOV = {v: np.diag([0.01**2, 0.01**2, 0.03**2]) for v in VERTS}


def block(seed: int, moved: dict[tuple[str, str], tuple[float, float]] | None = None, gross_ties: int = 0,
          n_ground: int = 250):
    """(measurements, eos, truth eos, ties) of one seed."""
    rng = np.random.default_rng(seed)
    truth = {p: np.array([e, n, H, *np.radians(rng.normal(0, 1.0, 3))]) for p, (e, n) in zip(PHOTOS, CENTRES)}
    approx = {p: truth[p] + np.r_[rng.normal(0, 2.0, 3), np.radians(rng.normal(0, 0.5, 3))] for p in PHOTOS}
    ground = np.column_stack([rng.uniform(-130, 130, n_ground), rng.uniform(-100, 100, n_ground),
                              rng.uniform(0, 12, n_ground)])
    photo, point, px = [], [], []
    for p in PHOTOS:
        uv = pixel_positions(CAM, truth[p], ground)
        inside = np.isfinite(uv).all(axis=1) & (uv[:, 0] > 5) & (uv[:, 1] > 5) & (uv[:, 0] < 995) & (uv[:, 1] < 745)
        for j in np.flatnonzero(inside):
            photo.append(p)
            point.append(f"T{j}")
            px.append(uv[j] + rng.normal(0, 0.3, 2))
    px = np.array(px)
    if gross_ties:
        bad = rng.choice(len(px), gross_ties, replace=False)
        ang = rng.uniform(0, 2 * np.pi, gross_ties)
        px[bad] += 20.0 * np.column_stack([np.cos(ang), np.sin(ang)])
    ties = TieObservations(photo, point, px, np.full(len(px), 0.3))
    ms = []
    for v, photos in MEASURED.items():
        for p in photos:
            t = pixel_positions(CAM, truth[p], VERTS[v][None])[0]
            assert np.isfinite(t).all() and 0 < t[0] < 1000 and 0 < t[1] < 750, (v, p, t)
            m = t + rng.normal(0, 0.3, 2) + np.asarray((moved or {}).get((v, p), (0.0, 0.0)))
            pred = pixel_positions(CAM, approx[p], VERTS[v][None])[0]
            ms.append(Measurement(v, p, m, np.eye(2) * 0.3**2, "measured", predicted_px=pred,
                                  predicted_cov_px2=np.eye(2) * 20.0**2))
    return ms, approx, truth, ties


def run(ms, approx, ties, **kw) -> BlockCheck:
    return check_block(ms, {p: CAM for p in PHOTOS}, approx, {p: EO_COV for p in PHOTOS}, VERTS, VCOV, ties, **kw)


def test_the_planted_block_has_lone_measurements_and_a_20_px_prediction():
    ms, approx, truth, ties = block(0)
    on = {p: sum(m.photo == p for m in ms) for p in PHOTOS}
    assert on["p0"] == 1 and on["p5"] == 1
    assert len(ties) > 400
    # the approximate orientation puts the vertices 5-40 px off
    d = [float(np.hypot(*(np.asarray(m.px) - np.asarray(m.predicted_px)))) for m in ms]
    assert max(d) > 10.0


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_clean_block_rejects_nothing_and_orients_the_photos(seed):
    ms, approx, truth, ties = block(seed)
    bc = run(ms, approx, ties)
    assert bc.status == "ok", bc.message
    assert [m.status for m in bc.measurements] == ["measured"] * len(ms), [m.reason for m in bc.measurements]
    assert bc.rejected == () and bc.untestable == ()
    assert bc.tested == len(ms) and bc.ties_rejected == 0
    # the adjusted orientations agree with the truth within their covariance (from the block, not the 2 m
    # prior): chi-square(6) 99.9 % point; over seeds 5-24 the mean of this statistic was 5.1 (6 expected)
    for p in PHOTOS:
        err = bc.eo[p] - truth[p]
        assert err @ np.linalg.solve(bc.eo_cov[p], err) < 22.46, p
        assert np.sqrt(bc.eo_cov[p][0, 0]) < 0.5                # far below the prior's 2 m


def test_a_lone_measurement_30_px_off_is_rejected_by_the_block():
    ms, approx, truth, ties = block(0, moved={("A1", "p0"): (30.0, 0.0)})
    # check_photo cannot test it: alone on its photo
    p0 = [m for m in ms if m.photo == "p0"]
    assert [m.status for m in check_photo(p0, CAM, approx["p0"], EO_COV, [VERTS["A1"]], [VCOV["A1"]])] == ["measured"]
    bc = run(ms, approx, ties)
    st = {(m.point, m.photo): m for m in bc.measurements}
    assert st[("A1", "p0")].status == "rejected"
    assert [k for k, m in st.items() if m.status != "measured"] == [("A1", "p0")]
    reason = st[("A1", "p0")].reason
    got = re.fullmatch(r"inconsistent with the block \((\d+) tie points on its photo and 9 other vertex "
                       r"observations\): ([0-9.]+) px, w = ([0-9.]+) \(critical 3\.42\)", reason)
    assert got, reason
    assert 40 < int(got.group(1)) <= sum(ties.photo == "p0")      # those whose point has another ray
    assert float(got.group(2)) == pytest.approx(30.0, abs=1.5)
    assert float(got.group(3)) > 20.0
    assert bc.rejected[0][:2] == ("A1", "p0")


def test_a_measurement_moved_on_a_shared_photo_is_rejected_and_the_others_kept():
    ms, approx, truth, ties = block(1, moved={("A3", "p2"): (-12.0, 16.0)})
    bc = run(ms, approx, ties)
    bad = [(m.point, m.photo) for m in bc.measurements if m.status == "rejected"]
    assert bad == [("A3", "p2")]


def test_gross_ties_reject_no_good_measurement():
    # (over seeds 0-29 with 8 gross ties: 1 good measurement of 300 rejected, 1.4 px at w 4.1 -- the level's
    # false alarms, 0.84 expected at alpha_2 = 0.0028; seed 1 is that one)
    for seed in (0, 2, 3):
        ms, approx, truth, ties = block(seed, gross_ties=8)
        bc = run(ms, approx, ties)
        assert bc.status == "ok", bc.message
        assert all(m.status == "measured" for m in bc.measurements), [m.reason for m in bc.measurements]
        assert bc.ties_rejected >= 8
    # and the lone gross one is still found
    ms, approx, truth, ties = block(0, moved={("A4", "p5"): (0.0, -32.0)}, gross_ties=8)
    bc = run(ms, approx, ties)
    assert [(m.point, m.photo) for m in bc.measurements if m.status == "rejected"] == [("A4", "p5")]


def test_ties_in_corrected_photo_coordinates_give_the_same_test_as_in_pixels():
    """A survey's tie observations go in as its adjustment uses them (xy_mm, sd_mm): the same block test as the
    pixels they come from (the camera's pixel_to_photo and photo_sd are what check_block applies to pixels)."""
    ms, approx, truth, ties = block(0, moved={("A1", "p0"): (30.0, 0.0)})
    in_mm = TieObservations(ties.photo, ties.point, xy_mm=CAM.pixel_to_photo(ties.px),
                            sd_mm=CAM.photo_sd(ties.px, np.repeat(ties.sd_px[:, None], 2, axis=1)))
    assert in_mm.px is None and in_mm.xy_mm.shape == (len(ties), 2)
    a, b = run(ms, approx, ties), run(ms, approx, in_mm)
    assert [(m.status, m.reason) for m in a.measurements] == [(m.status, m.reason) for m in b.measurements]
    assert [m.status for m in b.measurements].count("rejected") == 1
    assert (a.ties_used, a.ties_rejected, a.rounds) == (b.ties_used, b.ties_rejected, b.rounds)
    for p in a.eo:
        np.testing.assert_allclose(b.eo[p], a.eo[p], rtol=0, atol=1e-9)
    with pytest.raises(LidarcatError, match=r"^tie observations: give px with sd_px, or xy_mm with sd_mm$"):
        TieObservations(ties.photo, ties.point, ties.px, ties.sd_px, xy_mm=in_mm.xy_mm, sd_mm=in_mm.sd_mm)
    with pytest.raises(LidarcatError, match=r"^tie observations: give px with sd_px, or xy_mm with sd_mm$"):
        TieObservations(ties.photo, ties.point, xy_mm=in_mm.xy_mm)
    sd = np.array(in_mm.sd_mm)
    sd[2, 1] = 0.0
    with pytest.raises(LidarcatError, match=rf"^tie observation of point '{ties.point[2]}' on photo "
                                            rf"'{ties.photo[2]}': xy_mm and sd_mm must be finite and sd_mm > 0"):
        TieObservations(ties.photo, ties.point, xy_mm=in_mm.xy_mm, sd_mm=sd)


def test_without_ties_a_lone_measurement_is_untestable_and_kept():
    ms, approx, truth, ties = block(0, moved={("A1", "p0"): (30.0, 0.0)})
    bc = run(ms, approx, None)
    assert bc.status == "ok" and bc.ties_used == 0
    assert all(m.status == "measured" for m in bc.measurements)
    assert ("A1", "p0") in bc.untestable and ("A4", "p5") in bc.untestable
    assert bc.tested == len(ms) - 2


def test_without_ties_two_that_disagree_on_a_photo_are_both_rejected():
    # ties=None: the block test is check_photo's per-photo test, all photos at once; p4 has A2 and A3 only
    for seed in (0, 1):
        ms, approx, truth, ties = block(seed, moved={("A2", "p4"): (25.0, 10.0)})
        bc = run(ms, approx, None)
        out = {(m.point, m.photo): m for m in bc.measurements}
        assert [k for k, m in out.items() if m.status == "rejected"] == [("A2", "p4"), ("A3", "p4")]
        first, second = sorted([out[("A2", "p4")].reason, out[("A3", "p4")].reason], key=len)
        assert re.fullmatch(r"inconsistent with the block \(no tie points on its photo; 9 other vertex "
                            r"observations\): [0-9.]+ px, w = [0-9.]+ \(critical 3\.42\)", first), first
        assert "which of the two is off cannot be told" in second
        # with the tie points the block tells which: A2 alone
        bc = run(ms, approx, ties)
        assert [(m.point, m.photo) for m in bc.measurements if m.status == "rejected"] == [("A2", "p4")]
        assert check_photo([m for m in ms if m.photo == "p4"], CAM, approx["p4"], EO_COV,
                           [VERTS["A2"], VERTS["A3"]], [VCOV["A2"], VCOV["A3"]])[1].status == "rejected"


def test_a_measurement_on_an_unknown_photo_is_a_located_error():
    ms, approx, truth, ties = block(0)
    ms = ms + [Measurement("A1", "p9", np.array([10.0, 10.0]), np.eye(2) * 0.09, "measured")]
    with pytest.raises(LidarcatError, match=r"^photo 'p9': a measurement of point 'A1' but no camera for it"):
        run(ms, approx, ties)
    cams = {p: CAM for p in PHOTOS + ["p9"]}
    with pytest.raises(LidarcatError, match=r"^photo 'p9': a measurement of point 'A1' but no approximate "):
        check_block(ms, cams, approx, {p: EO_COV for p in PHOTOS}, VERTS, VCOV, ties)
    bad = TieObservations(list(ties.photo[:3]) + ["p7"], list(ties.point[:4]), ties.px[:4], 0.3)
    with pytest.raises(LidarcatError, match=r"^photo 'p7': tie observations but no camera for it"):
        run(block(0)[0], approx, bad)
    with pytest.raises(LidarcatError, match=r"^point 'B9': measured on photo 'p0' but no vertex coordinates"):
        run([Measurement("B9", "p0", np.array([10.0, 10.0]), np.eye(2) * 0.09, "measured")], approx, ties)
    with pytest.raises(LidarcatError, match=r"^photo 'p2': the covariance of its approximate orientation has a zero or "):
        check_block(block(0)[0], {p: CAM for p in PHOTOS}, approx,
                    {**{p: EO_COV for p in PHOTOS}, "p2": np.zeros((6, 6))}, VERTS, VCOV, ties)


# --- roof edges as line control in the block test (lines=, issue 29 session 5) ------------------------------
#: 3-D roof lines (end points A, B; E, N, h) of vertices that have no point measurement ("R*")
LINES = {"R1/0-1": ("R1", [-40.0, -20.0, 6.0], [-40.0, -12.0, 6.5]), "R2/0-1": ("R2", [30.0, 20.0, 9.0], [37.0, 20.0, 9.0]),
         "R3/1-2": ("R3", [5.0, -25.0, 7.0], [10.0, -20.0, 7.0]), "R4/0-2": ("R4", [-20.0, 30.0, 8.0], [-20.0, 36.0, 10.0])}
LCOV = np.diag([0.01**2] * 6)


def edges(seed: int, truth: dict, moved: dict[tuple[str, str], float] | None = None, sd_px: float = 0.3,
          lines: dict | None = None) -> list:
    """Every line of LINES on every photo that sees both its ends: the true projection's points at 20 % and
    80 % of the segment plus *sd_px* noise across, *moved* px across (the edge's normal, +90 deg in pixels)."""
    from lidarcat.photocontrol import EdgeObservation

    rng = np.random.default_rng(1000 + seed)
    out = []
    for lid, (pt, a, b) in (lines or LINES).items():
        for p in PHOTOS:
            ab = pixel_positions(CAM, truth[p], np.array([a, b]))
            if not (np.isfinite(ab).all() and (ab > 20).all() and (ab[:, 0] < 980).all() and (ab[:, 1] < 730).all()):
                continue
            t = (ab[1] - ab[0]) / np.hypot(*(ab[1] - ab[0]))
            n = np.array([-t[1], t[0]])
            shift = (moved or {}).get((lid, p), 0.0)
            p1 = ab[0] + 0.2 * (ab[1] - ab[0]) + n * (rng.normal(0, sd_px) + shift)
            p2 = ab[0] + 0.8 * (ab[1] - ab[0]) + n * (rng.normal(0, sd_px) + shift)
            out.append(EdgeObservation(lid, pt, p, p1, p2, sd_px, a, b, LCOV))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_clean_edges_are_never_rejected(seed):
    ms, approx, truth, ties = block(seed)
    es = edges(seed, truth)
    assert len(es) >= 8 and len({e.photo for e in es}) >= 5
    bc = run(ms, approx, ties, lines=es)
    assert bc.status == "ok", bc.message
    assert bc.lines_rejected == () and bc.line_reasons == {} and bc.rejected == ()
    assert bc.lines_tested == len(es) and bc.lines_untestable == ()
    assert all(m.status == "measured" for m in bc.measurements)
    assert bc.summary()["lines_tested"] == len(es)
    for p in PHOTOS:        # the orientations still agree with the truth within their covariance
        err = bc.eo[p] - truth[p]
        assert err @ np.linalg.solve(bc.eo_cov[p], err) < 22.46, p


@pytest.mark.parametrize("seed,shift", [(0, 50.0), (1, -40.0), (2, 60.0)])
def test_an_edge_moved_across_its_line_is_rejected_with_its_offset(seed, shift):
    ms, approx, truth, ties = block(seed)
    es = edges(seed, truth, moved={("R1/0-1", "p3"): shift})
    assert ("R1/0-1", "p3") in {(e.line, e.photo) for e in es}
    assert not any(m.photo == "p3" and m.point == "R1" for m in ms)      # no vertex point of R1 anywhere
    bc = run(ms, approx, ties, lines=es)
    assert bc.status == "ok", bc.message
    assert [(ln, p) for ln, p, *_ in bc.lines_rejected] == [("R1/0-1", "p3")]
    assert list(bc.line_reasons) == [("R1/0-1", "p3")]
    reason = bc.line_reasons[("R1/0-1", "p3")]
    n_ties = sum(ties.photo == "p3")
    got = re.fullmatch(r"roof edge inconsistent with the block \((\d+) tie points on its photo, 10 vertex "
                       rf"observations and {len(es) - 1} other edges\): ([0-9.]+) px off its LiDAR line, "
                       r"w = ([0-9.]+) \(critical 3\.42\)", reason)
    assert got, reason
    assert 40 < int(got.group(1)) <= n_ties
    assert float(got.group(2)) == pytest.approx(abs(shift), abs=1.5)
    assert float(got.group(3)) > 20.0
    assert bc.lines_rejected[0][3] == pytest.approx(float(got.group(2)), abs=0.05)
    assert all(m.status == "measured" for m in bc.measurements)        # no vertex point indicted


#: one short roof line (2.5 m), the block's only ground control besides the GNSS/IMU orientations
SHORT = {"S1/0-1": ("S1", [-5.0, 0.0, 8.0], [-3.0, 1.5, 8.2])}


@pytest.mark.parametrize("seed, photos, bad, instead", [
    (1, ("p0", "p1", "p4"), "p0", None), (1, ("p1", "p3", "p5"), "p5", None),
    (0, ("p1", "p3", "p5"), "p3", "p5"), (0, ("p0", "p4", "p2"), "p2", "p4")])
def test_one_short_line_alone_the_gross_edge_goes_and_no_good_one(seed, photos, bad, instead):
    """The short line's edges on three photos, one 50 px off, no vertex point: the three tests are nearly equal
    and worst first took a good edge first (the first two cases: the good one on p4 / p3 went, then the gross
    one) or left the gross one untestable beside a good one (the last two: only the good one on *instead*
    went).  The backward step puts the good edge back, or rejects the gross one instead of it (lower v'Pv)."""
    ms, approx, truth, ties = block(seed)
    es = [e for e in edges(seed, truth, moved={("S1/0-1", bad): 50.0}, lines=SHORT) if e.photo in photos]
    assert sorted(e.photo for e in es) == sorted(photos)
    bc = run([], approx, ties, lines=es)
    assert bc.status == "ok", bc.message
    assert [(ln, p) for ln, p, *_ in bc.lines_rejected] == [("S1/0-1", bad)]
    assert list(bc.line_reasons) == [("S1/0-1", bad)] and bc.lines_tested + len(bc.lines_untestable) == 3
    assert ("S1/0-1", bad) not in bc.lines_untestable
    got = re.fullmatch(r"roof edge inconsistent with the block \((\d+) tie points on its photo, 0 vertex observations "
                       r"and 2 other edges\): ([0-9.]+) px off its LiDAR line, (w = ([0-9.]+) \(critical 3\.42\)|"
                       r"untestable beside the other edge)(; rejected instead of its line's edge on photo (p\d) "
                       r"\(lower v'Pv\))?", bc.line_reasons[("S1/0-1", bad)])
    assert got, bc.line_reasons[("S1/0-1", bad)]
    assert 40 < int(got.group(1)) <= sum(ties.photo == bad)
    assert float(got.group(2)) == pytest.approx(50.0, abs=3.0)        # from the block without it
    assert bc.lines_rejected[0][3] == pytest.approx(float(got.group(2)), abs=0.05)
    assert got.group(6) == instead
    if got.group(4) is not None:
        assert float(got.group(4)) > 3.42


def test_an_edge_stands_for_its_vertex_point_on_that_photo_and_indicts_it():
    # A2 is measured on p1, p3, p4; its edges on p3 are given: the point on p3 is not adjusted, the edges are;
    # one of them 45 px off rejects the point on p3 with it (the same fits)
    ms, approx, truth, ties = block(0)
    a2 = VERTS["A2"]
    own = {"A2/0-1": ("A2", a2, a2 + [0.0, 8.0, 0.0]), "A2/1-2": ("A2", a2, a2 + [7.0, 0.0, 1.0])}
    es = [e for e in edges(0, truth, moved={("A2/0-1", "p3"): 45.0}, lines=own) if e.photo == "p3"]
    assert len(es) == 2
    bc = run(ms, approx, ties, lines=es)
    assert [(ln, p) for ln, p, *_ in bc.lines_rejected] == [("A2/0-1", "p3")]
    assert bc.rejected == ()                 # the point was not tested itself
    st = {(m.point, m.photo): m for m in bc.measurements}
    assert st[("A2", "p3")].status == "rejected"
    assert re.fullmatch(r"inconsistent with the block: its roof edge A2/0-1 on this photo is ([0-9.]+) px off its "
                        r"LiDAR line \(w = [0-9.]+\)", st[("A2", "p3")].reason)
    assert [k for k, m in st.items() if m.status != "measured"] == [("A2", "p3")]
    # clean: the point on p3 is kept (not tested twice), its edges tested
    es = [e for e in edges(0, truth, lines=own) if e.photo == "p3"]
    bc = run(ms, approx, ties, lines=es)
    assert bc.lines_rejected == () and bc.lines_tested == 2 and bc.tested == len(ms) - 1
    assert all(m.status == "measured" for m in bc.measurements)


def test_a_bad_edge_observation_is_a_located_error():
    from lidarcat.photocontrol import EdgeObservation

    with pytest.raises(LidarcatError, match=r"^edge R1/0-1 on photo 'p0': points, line, covariance and sd_px must"):
        EdgeObservation("R1/0-1", "R1", "p0", [1.0, 2.0], [5.0, 6.0], 0.0, [0, 0, 0], [1, 0, 0], LCOV)
    ms, approx, truth, ties = block(0)
    e = EdgeObservation("R1/0-1", "R1", "p8", [1.0, 2.0], [5.0, 6.0], 0.3, [0, 0, 0], [1, 0, 0], LCOV)
    with pytest.raises(LidarcatError, match=r"^photo 'p8': an edge of line 'R1/0-1' but no camera for it"):
        run(ms, approx, ties, lines=[e])


@pytest.mark.parametrize("with_points", [True, False])
def test_measure_control_does_not_write_an_edge_the_block_test_rejects(tmp_path, monkeypatch, with_points):
    """The stage's wiring (lines=add): the roof edges of a vertex whose point was not measured go into the block
    test; the one moved 50 px is not written to line_control.csv and line_decisions.csv says why.  The photos are
    never looked at: extraction, roof edges, the 3-D line and the measurement are replaced by the truth.  Without
    the vertex points the short line alone holds the block: worst first took the good edge on 102 first (w 70), and
    the backward step puts it back."""
    import csv
    import types

    import lidarcat.control.vertices as cv
    import lidarcat.lidar.clipping as lc
    import lidarcat.match as lm
    import lidarcat.photocontrol as pc
    from lidarcat.photocontrol import EdgeLine
    from lidarcat.photocontrol.predict import RoofEdge
    from lidarcat.stages.measure_control import line_id, measure_control
    from lidarcat.synthetic.aerial import aerial_survey

    root = tmp_path / "s"
    s = aerial_survey(root, n_strips=2, photos_per_strip=3, gsd_m=0.15, image_size_px=(320, 240), side_overlap=0.6,
                      lidar_density_m2=0.05, n_gps_points=4, seed=3)
    rng = np.random.default_rng(0)
    eo = s.true_eo
    ground = float(np.mean(eo[:, 2])) - 0.15 * s.camera.focal_length_mm / s.camera.pixel_size_x_mm
    centre = np.r_[np.mean(eo[:, :2], axis=0), ground + 8.0]
    ends = np.array([centre + [-1.2, -0.4, 0.0], centre + [1.2, 0.4, 0.2]])    # the roof line of vertex R1
    # vertex points measured as in tests/stages/test_measure_control_block.py (they hold the block's datum); or none
    pts = {"V1": ["101", "203"], "V2": ["102", "103", "202"], "V3": ["103", "201"], "V4": ["202", "203"]} \
        if with_points else {}
    verts = {v: np.r_[np.mean([eo[s.index(p), :2] for p in ph], axis=0) + rng.normal(0, 1.0, 2), ground + 8.0]
             for v, ph in pts.items()}
    verts["R1"] = ends[0]
    with open(root / "ground_points.csv", "a") as fh:
        for v, x in verts.items():
            fh.write(f"{v},{x[0]:.4f},{x[1]:.4f},{x[2]:.4f},0.01,0.01,0.03,lidar\n")
    lo, hi = eo[:, :2].min(axis=0) - 20, eo[:, :2].max(axis=0) + 20
    g = np.column_stack([rng.uniform(lo[0], hi[0], 400), rng.uniform(lo[1], hi[1], 400), ground + rng.uniform(0, 6, 400)])
    px = {p: s.project(p, g) for p in s.photo_ids}
    ok = {p: np.isfinite(x).all(axis=1) & (x[:, 0] > 2) & (x[:, 1] > 2) & (x[:, 0] < 317) & (x[:, 1] < 237)
          for p, x in px.items()}
    two = np.sum(list(ok.values()), axis=0) >= 2
    with open(root / "image_points.csv", "a") as fh:
        for p in s.photo_ids:
            for j in np.flatnonzero(ok[p] & two):
                c, r = px[p][j] + rng.normal(0, 0.3, 2)
                fh.write(f"{p},T{j:04d},{c:.3f},{r:.3f}\n")
    seen = [p for p in s.photo_ids if ((s.project(p, ends) > 4) & (s.project(p, ends) < [316, 236])).all()]
    assert len(seen) >= 3, seen
    moved = seen[1]

    class Vertex:
        cov_m2, planes, status, reason = np.diag([0.01**2, 0.01**2, 0.03**2]), [0, 1], "ok", ""

        def __init__(self, enh):
            self.enh_m = np.asarray(enh, float)

        def __bool__(self):
            return True

    def measure_photo(img, cam, eo_, targets, params=None):
        out = []
        for t in targets:
            pr = t.prediction
            els = ()
            if pr.photo in pts.get(pr.point, []):
                out.append(Measurement(pr.point, pr.photo, s.project(pr.photo, verts[pr.point][None])[0]
                                       + rng.normal(0, 0.3, 2), np.eye(2) * 0.09, "measured", predicted_px=pr.px,
                                       predicted_cov_px2=pr.cov_px2))
                continue
            if pr.point == "R1" and pr.photo in seen:
                ab = s.project(pr.photo, ends)
                n = np.array([-(ab[1] - ab[0])[1], (ab[1] - ab[0])[0]]) / np.hypot(*(ab[1] - ab[0]))
                off = n * (50.0 if pr.photo == moved else 0.0)
                els = (EdgeLine((0, 1), ab[0] + 0.2 * (ab[1] - ab[0]) + off + n * rng.normal(0, 0.3),
                                ab[0] + 0.8 * (ab[1] - ab[0]) + off + n * rng.normal(0, 0.3), 0.3, 5.0),)
            out.append(Measurement(pr.point, pr.photo, np.full(2, np.nan), np.full((2, 2), np.nan), "no_edges",
                                   "1 of 2 edges found", predicted_px=pr.px, predicted_cov_px2=pr.cov_px2,
                                   edge_lines=els))
        return out

    monkeypatch.setattr(lc, "clip", lambda *a, **k: types.SimpleNamespace(xyz=np.zeros((10, 3))))
    monkeypatch.setattr(cv, "extract_roof", lambda xyz, en, point_id=None: Vertex(verts[point_id]))
    monkeypatch.setattr(pc, "roof_edges", lambda enh, *a, **k: [RoofEdge((0, 1), ends[0], ends[1], 50)]
                        if np.allclose(enh, ends[0]) else [])
    monkeypatch.setattr(pc, "edge_line_m", lambda pi, pj, e: (ends[0], ends[1], np.eye(6) * 0.01**2))
    monkeypatch.setattr(pc, "measure_photo", measure_photo)
    monkeypatch.setattr(lm, "read_image", lambda *a, **k: np.zeros((240, 320), np.uint8))
    out = tmp_path / "mc"
    measure_control(root, out, gallery=False, lines="add", table=tmp_path / "ip.csv",
                    line_table=tmp_path / "lines.csv")

    def rows(path):
        with open(path, newline="") as fh:
            return list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))

    lid = line_id("R1", (0, 1))
    dec = {r["photo"]: r for r in rows(out / "line_decisions.csv") if r["line"] == lid}
    assert [p for p, r in dec.items() if r["status"] == "written"] == [p for p in seen if p != moved], (seen, [(p, r["reason"]) for p, r in dec.items()])
    assert dec[moved]["status"] == "not_written" and dec[moved]["decision"] == "reject"
    n_v = 9 if with_points else 0
    got = re.fullmatch(rf"roof edge inconsistent with the block \(\d+ tie points on its photo, {n_v} vertex "
                       rf"observations and {len(seen) - 1} other edges\): ([0-9.]+) px off its LiDAR line, "
                       r"w = ([0-9.]+) "
                       r"\(critical 3\.42\)", dec[moved]["reason"])
    assert got, dec[moved]["reason"]
    assert float(got.group(1)) == pytest.approx(50.0, abs=2.0) and float(got.group(2)) > (20.0 if with_points else 10.0)
    assert sorted(r["photo"] for r in rows(tmp_path / "lines.csv") if r["photo"]) == sorted(p for p in seen if p != moved)
    info = json.loads((out / "measure_control.json").read_text())["block_check"]
    assert info["lines_rejected"] == 1 and info["lines_tested"] == len(seen) and info["tested"] == n_v
    assert info["rejected"] == 0
