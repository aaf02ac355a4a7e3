"""The block test of a point located along one edge (photocontrol.check_block, "Along one edge"): its edges
stand for it across the line (tested as line control), its position *along* the line is tested on the final
block with the covariance it carries (loose along, tight across).

The block is tests/photocontrol/test_block_check.py's (6 photos at GSD 0.15 m, tie points from the truth +
0.3 px, the approximate orientation 2 m / 0.5 deg off).  Vertex A2 on photo p3 is measured along one edge: its two
roof edges leave it on either side and bend by 10 deg (in the ground), both given as edges; its point's
covariance is 2.0 px along the image line and 0.3 px across it.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from lidarcat.photocontrol import Measurement, pixel_positions

from test_block_check import CAM, VERTS, block, edges, run

A2 = VERTS["A2"]
#: A2's two edges on either side of it, 10 deg apart in the ground (8 m each)
OWN = {"A2/1-2": ("A2", A2, A2 + [0.0, 8.0, 0.0]),
       "A2/2-3": ("A2", A2, A2 + 8.0 * np.array([math.sin(math.radians(10.0)), -math.cos(math.radians(10.0)), 0.0]))}
SD_ALONG, SD_ACROSS = 2.0, 0.3


def _along_block(seed: int, along_px: float, across_px: float = 0.0):
    """The block with A2 on p3 an along-one-edge point *along_px* along its image line (and *across_px* across)
    from its true projection; its two edges (the true lines + 0.3 px) given."""
    ms, approx, truth, ties = block(seed)
    es = [e for e in edges(seed, truth, lines=OWN) if e.photo == "p3"]
    assert len(es) == 2
    t = pixel_positions(CAM, truth["p3"], np.array([A2, OWN["A2/1-2"][2]]))
    u = (t[1] - t[0]) / np.hypot(*(t[1] - t[0]))                # the image line's direction at the vertex
    n = np.array([-u[1], u[0]])
    cov = SD_ALONG**2 * np.outer(u, u) + SD_ACROSS**2 * np.outer(n, n)
    k = next(i for i, m in enumerate(ms) if (m.point, m.photo) == ("A2", "p3"))
    m = ms[k]
    ms[k] = Measurement("A2", "p3", t[0] + along_px * u + across_px * n, cov, "measured", "located along one edge",
                        predicted_px=m.predicted_px, predicted_cov_px2=m.predicted_cov_px2, along_line=True)
    return ms, approx, ties, es


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_right_along_position_is_kept_and_tested(seed):
    ms, approx, ties, es = _along_block(seed, along_px=0.5 * SD_ALONG)
    bc = run(ms, approx, ties, lines=es)
    assert bc.status == "ok", bc.message
    assert all(m.status == "measured" for m in bc.measurements), [m.reason for m in bc.measurements]
    assert bc.rejected == () and bc.lines_rejected == () and bc.untestable == ()
    assert bc.tested == len(ms)          # the point on p3 is tested along its line (its edges stand for it across)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_wrong_along_position_is_rejected_with_its_offset(seed):
    """Planted 6 sd (12 px) along the line: its edges agree with the block, its position along them does not."""
    ms, approx, ties, es = _along_block(seed, along_px=6 * SD_ALONG)
    bc = run(ms, approx, ties, lines=es)
    assert bc.status == "ok", bc.message
    assert bc.lines_rejected == ()                     # the edges are right
    st = {(m.point, m.photo): m for m in bc.measurements}
    assert [k for k, m in st.items() if m.status != "measured"] == [("A2", "p3")]
    got = re.fullmatch(r"inconsistent with the block along its edge \((\d+) tie points on its photo\): ([0-9.]+) px "
                       r"along the line from the vertex projected with the block, w = ([0-9.]+) \(critical 3\.29\)",
                       st[("A2", "p3")].reason)
    assert got, st[("A2", "p3")].reason
    assert float(got.group(2)) == pytest.approx(12.0, abs=1.0)
    assert 5.5 < float(got.group(3)) < 6.5            # 12 px over sqrt(2.0^2 + the block's share): 5.8-6.1
    assert [r[:2] for r in bc.rejected] == [("A2", "p3")] and bc.tested == len(ms)


def test_across_the_line_the_point_is_left_to_its_edges():
    """3 px across (10 sd of the point, the edges right): not the along test's business (the point is on its
    edges' line by construction; the edges are tested across as line control)."""
    ms, approx, ties, es = _along_block(0, along_px=0.0, across_px=3.0)
    bc = run(ms, approx, ties, lines=es)
    assert all(m.status == "measured" for m in bc.measurements) and bc.rejected == ()


def test_without_its_edges_the_point_is_adjusted_as_before():
    """No edge given: the along-one-edge point is an ordinary vertex observation of the block (its covariance's
    dominating diagonal), the 12 px off one rejected by the worst-first rounds."""
    ms, approx, ties, _ = _along_block(0, along_px=6 * SD_ALONG)
    bc = run(ms, approx, ties)
    st = {(m.point, m.photo): m for m in bc.measurements}
    assert [k for k, m in st.items() if m.status != "measured"] == [("A2", "p3")]
    assert re.fullmatch(r"inconsistent with the block \(\d+ tie points on its photo and \d+ other vertex "
                        r"observations\): [0-9.]+ px, w = [0-9.]+ \(critical 3\.42\)", st[("A2", "p3")].reason)
