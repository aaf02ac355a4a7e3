"""Which line goes when a vertex's lines do not meet at one point (measure step 3c, ``_weak_edge.worst_line``).

With one redundancy (three lines) every line's w is the same: the data cannot tell which line is off, and the
largest raw offset (the rule before) depends on the three edge directions only.  The weakest line goes
instead (prior reliability, as in step 3b).  With two or more redundancies the largest w goes.

The photos are test_measure_weak_edge's: three faces, the weak edge of planes 1-3 planted 1.2-2.5 px across.
In the cases below the planted edge came out *strong* (gradient 3.5-4.7 x the texture's), so step 3b did not
test it. The chi2 check fired and, before 3c, dropped a strong edge: the point from the planted edge and
one strong edge was 4.7-7.4 sd off, and in the second pass the vertex was often lost (``no_edges``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from lidarcat.photocontrol._along import intersect_lines
from lidarcat.photocontrol._weak_edge import worst_line
from lidarcat.photocontrol.measure import MeasureParams
from test_measure_weak_edge import CHI2_2_999, _m2, _measure

WEAKEST = "edge of planes 1-3: does not meet the other edges at one point ("


@pytest.mark.parametrize("off_px, seed, before", [
    (1.2, 113, "measured 4.7 sd off: the second pass dropped edge 2-3"),
    (1.2, 117, "measured 5.3 sd off: the first pass dropped edge 2-3"),
    (2.5, 110, "first pass 7.4 sd off (edge 2-3 dropped), second pass no_edges"),
    (2.5, 117, "first pass 6.8 sd off (edge 2-3 dropped), second pass no_edges"),
    (2.5, 138, "first pass 6.8 sd off (edge 2-3 dropped), second pass no_edges"),
])
def test_the_chi2_check_drops_the_planted_edge_as_the_weakest_of_three(off_px, seed, before):
    first, second = _measure(off_px, seed)
    assert first.status == "measured" and second.status == "measured", (first.reason, second.reason)
    # the final point (seed 113's first pass keeps the three lines, chi2 10.80 < 10.83, 4.2 sd off)
    assert _m2(second) < CHI2_2_999, (second.px, second.cov_px2)
    reasons = first.reason + " | " + second.reason
    assert WEAKEST in reasons, reasons
    assert "; the weakest of three, gradient " in reasons.split(WEAKEST)[1].split(")")[0] + ")", reasons
    # no strong edge goes
    assert "edge of planes 1-2: does not meet" not in reasons and "edge of planes 2-3: does not meet" not in reasons


def test_without_the_weak_edge_test_the_check_now_drops_the_weak_planted_edge():
    # (1.6 px, seed 1) with step 3b off: before 3c the check dropped a strong edge and the vertex was lost
    # (no_edges, test_measure_weak_edge); now the weak planted edge goes as the weakest of three
    first, _ = _measure(1.6, 1, replace(MeasureParams(), weak_edge_w=math.inf))
    assert first.status == "measured", first.reason
    assert len(first.lines) == 2
    assert first.reason.startswith(WEAKEST), first.reason
    assert _m2(first) < CHI2_2_999


def _lines(normals, offsets, ratios):
    """Hand-built lines m^T x = c through `_refine`'s fit tuples, with no fit covariance (the offset variance
    is then sd_px^2 + (texture_px / ratio)^2 exactly, wherever the point)."""
    mm = np.array(normals, dtype=float)
    mm /= np.linalg.norm(mm, axis=1)[:, None]
    fits = [(np.array([m[1], -m[0]]), (np.zeros(2), np.zeros((2, 2)), np.arange(5.0), r)) for m, r in zip(mm, ratios)]
    covs = [(np.zeros((2, 2)), 0.0)] * len(mm)
    return fits, mm, np.array(offsets, dtype=float), covs


KW = dict(sd_px=0.1, texture_px=1.0)


def _var(ratio):
    return 1e-8 + 0.1**2 + (1.0 / ratio) ** 2


@pytest.mark.parametrize("ratios, weakest", [((10.0, 8.0, 5.0), 2), ((4.0, 8.0, 5.0), 0), ((10.0, 3.7, 12.0), 1)])
def test_of_three_lines_the_weakest_goes_and_its_w_is_the_misclosure_s(ratios, weakest):
    # x = 0, y = 0 and the diagonal (x + y) / sqrt 2 = 1.5: raw offsets 2.1 px for x = 0 and y = 0 (the old
    # rule's choice whatever the strengths), 1.5 px for the diagonal
    fits, mm, cc, covs = _lines([(1, 0), (0, 1), (1, 1)], [0.0, 0.0, 1.5], ratios)
    i, off, w = worst_line(fits, mm, cc, covs, [0, 1, 2], np.zeros(2), **KW)
    assert i == weakest
    _, _, chi2 = intersect_lines(fits, mm, cc, covs, np.zeros(2), **KW)
    assert w * w == pytest.approx(chi2, rel=1e-9)       # one redundancy: every |w| is sqrt(chi2)
    # the offset: from the other two lines' point, exact
    rest = [j for j in range(3) if j != i]
    x = np.linalg.solve(mm[rest], cc[rest])
    assert off == pytest.approx(float(mm[i] @ x - cc[i]), abs=1e-12)


def test_of_four_lines_the_largest_w_goes_not_the_largest_offset():
    # three strong lines (10 x the texture: sd 0.14 px) x = 0.6, y = 0, x + y = 0 and a weak one (1 x: sd 1.0 px)
    # (x - y) / sqrt 2 = 2: the largest raw offset is the weak line's (1.6 px), the largest |w| a strong line's
    ratios = (10.0, 10.0, 10.0, 1.0)
    fits, mm, cc, covs = _lines([(1, 0), (0, 1), (1, 1), (1, -1)], [0.6, 0.0, 0.0, 2.0], ratios)
    i, off, w = worst_line(fits, mm, cc, covs, [0, 1, 2, 3], np.zeros(2), **KW)
    # by hand: each line against the weighted point of the three others
    ws, offs = [], []
    for k in range(4):
        rest = [j for j in range(4) if j != k]
        wt = np.array([1.0 / _var(ratios[j]) for j in rest])
        n = (mm[rest] * wt[:, None]).T @ mm[rest]
        x = np.linalg.solve(n, (mm[rest] * wt[:, None]).T @ cc[rest])
        offs.append(float(mm[k] @ x - cc[k]))
        ws.append(offs[-1] / math.sqrt(float(mm[k] @ np.linalg.solve(n, mm[k])) + _var(ratios[k])))
    assert int(np.argmax(np.abs(offs))) == 3 and abs(offs[3]) == pytest.approx(1.58, abs=0.01)   # the old rule's
    assert i == int(np.argmax(np.abs(ws))) == 1 and abs(ws[1]) == pytest.approx(2.38, abs=0.01)
    assert (off, w) == (pytest.approx(offs[1], rel=1e-9), pytest.approx(ws[1], rel=1e-9))
