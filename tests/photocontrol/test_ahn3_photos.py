"""LiDAR roof vertices measured in photos rendered over the real AHN3 roofs (issue 29, step 5).

The scene, the flights and the scoring are benchmarks/bench_photocontrol_ahn3.py's: the vertices
of tests/data/extract/ahn3_vertices.csv extracted again from tests/data/lidar (as
``measure-control`` does), rendered as exact roof patches in the TIN of the first returns
(lidarcat.synthetic.lidarphoto), predicted, measured, tested on each photo, in the block
(tie points from ``match_block`` on the renders) and across photos, scored against the true
projection and the occlusion truth.
"""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_photocontrol_ahn3 import load_ahn3, run_check_block, score_block, summary  # noqa: E402


@pytest.fixture(scope="module")
def crop():
    """A 50 x 40 m crop of both tiles about the vertices A01 and A11 (the hip roofs at the tile boundary)."""
    return load_ahn3((84980.0, 447455.0, 85030.0, 447495.0), only=["A01", "A11"])


@pytest.fixture(scope="module")
def pair(crop):
    # one pair: a vertex measured on one photo counts here (the stage would reject it for want of a check).
    # 480 x 400 px (480 x 360 before session 7): with the break-line buffer on by default, A01's ridge is
    # supported over 3.63 m instead of 3.40 m, so on the second 480 x 360 photo, where A01 lies 46 px above the
    # bottom border, its edges (41 px + the 3.5 px band + 2) reached past the border and it was `near_border`
    # (it measured 0.07 px off without the buffer). The border rule, not the measurement: the taller frame
    # puts A01 81 px inside, and the pair measures A01 on photo 1 and A11 on photo 0 again, as it did before.
    return score_block(crop, (85003.0, 447474.0), 0.0, 0.10, 0, size=(480, 400), n_strips=1, per_strip=2,
                       min_photos=1, cache=None)


def test_the_crop_has_both_vertices_as_exact_patches(crop):
    assert [pid for pid, _, _ in crop.vertices] == ["A01", "A11"]
    for (pid, cp, _), p in zip(crop.vertices, crop.surface.patches):
        assert np.array_equal(p.vertex_m, cp.enh_m)
        h, face = p.height(cp.enh_m[:1] + 0.3, cp.enh_m[1:2])
        assert face[0] >= 0 and abs(h[0] - cp.enh_m[2]) < 0.3 * 1.1     # a roof face next to the vertex (<= 48 deg)


def test_a_photo_pair_over_real_roofs(pair):
    # A01 on photo 1 (0.08 px off); A11 on photo 0 is not measured (the test below), nor A01 on photo 0 and A11
    # on photo 1 (two edges, one weak)
    n, med, p95, mx, sd = summary(pair["errors"], pair["normalised"])
    assert pair["n_photos"] == 2
    assert [(r[0], r[1]) for r in pair["rows"]] == [("A01", 1)], pair["statuses"]
    assert mx < 1.0, pair["rows"]
    assert pair["occluded_accepted"] == 0


def test_a_wide_band_corner_the_narrow_band_does_not_confirm_is_not_measured(crop, pair):
    """A11 on photo 0 (measure step 2, tests/photocontrol/test_measure_confirm.py): the coarse shift lands 6 px off,
    the wide band (3.5 px) reaches the far edge of the ridge cap (a bright stripe of the intensity beside the
    ridge) and three lines meet 4 px from the true vertex, within their chi2 check, with an sd of 0.2-0.5 px.
    Until session 9 that point was accepted; the narrow band (1.5 px) about it finds two edges only, one weak,
    so now the pair is not measured, and the reason gives the point that was not confirmed."""
    import re

    from lidarcat.synthetic.aerial import project_to_pixels

    m = next(m for m in pair["lists"]["raw"][0] if m.point == "A11")
    assert m.status == "no_edges" and np.isnan(m.px).all() and m.edge_lines == ()
    got = re.match(r"the vertex found in the 3\.5 px band \(column ([\d.]+), row ([\d.]+)\) is not found again "
                   r"from it in the 1\.5 px band: two edges only", m.reason)
    assert got, m.reason
    L = pair["lists"]
    true_px = project_to_pixels(L["camera"], L["true_eo"][L["used"][0]], crop.vertices[1][1].enh_m[None])[0]
    assert np.hypot(*(np.array([float(got[1]), float(got[2])]) - true_px)) > 3.0


def test_the_matched_ties_of_the_pair_against_the_renderers_truth(pair):
    # match_block on the two renders (as `lidarcat match`): hundreds of tracks, transferred through
    # the true rays onto the rendered surface within a few tenths of a pixel, almost none gross
    assert pair["ties"]["source"] == "match_block", pair["ties"]
    ts = pair["tie_score"]
    assert ts["tracks"] >= 100
    assert np.median(ts["errors"]) < 0.5
    assert ts["gross_tracks"] <= 0.02 * ts["tracks"]


def test_the_block_check_of_the_pair_keeps_its_good_measurements(pair):
    # the block check (photocontrol.check_block: one adjustment with the matched ties, the vertex
    # observations snooped) runs on the pair and rejects none of its measurements (all < 1 px, above);
    # its power against gross values is tested in tests/photocontrol/test_block_check.py, and on the
    # whole benchmark (docs/figures.md)
    L = pair["lists"]
    assert L["ties"] is not None
    out, info = run_check_block(L["checked"], L["camera"], L["approx"], L["eo_cov"], L["vertices"],
                                L["vertex_covs"], L["ties"], [f"p{j}" for j in L["used"]], L["ids"])
    assert info["source"] == "check_block" and info["status"] == "ok", info
    assert info["ties_used"] >= 100, info
    assert [[m.status for m in x] for x in out] == [[m.status for m in x] for x in L["checked"]]


@pytest.mark.slow
def test_acceptance_on_blocks_f1_f4_and_hidden_vertices():
    """Issue 29's acceptance numbers on two blocks of the benchmark with the block check on (tie points
    from ``match_block`` on the renders): F1 / GSD 0.10 m / seed 1 (6 photos of 800 x 600 px over A01
    A11 ...) and F4 / GSD 0.15 m / seed 132, where a fit locked onto another corner (63 px off) is
    alone on its photo: the per-photo test keeps it, the block check rejects it; and no hidden
    vertex measured on oblique photos (~15 min quiet).  The pooled benchmark: docs/figures.md.
    (Seed 32 was the gross case until session 9: its A13 lock, 47 px off, is no longer measured since the
    narrow band must confirm the wide band's vertex, tests/photocontrol/test_measure_confirm.py.)"""
    from bench_photocontrol_ahn3 import FLIGHTS, occlusion_block

    data = load_ahn3()
    errs, norm = [], []
    for f, gsd, seed in (("F1", 0.10, 1), ("F4", 0.15, 132)):
        centre, heading = FLIGHTS[f]
        r = score_block(data, centre, heading, gsd, seed, cache=None, compare=True)
        assert r["ties"]["source"] == "match_block" and r["block"]["source"] == "check_block", (r["ties"], r["block"])
        assert r["occluded_accepted"] == 0
        errs.append(r["errors"])
        norm.append(r["normalised"])
        if f == "F1":
            n, med, p95, mx, sd = summary(r["errors"], r["normalised"])
            assert n >= 5, r["statuses"]
            assert 0.8 <= sd <= 1.25, r["rows"]
        else:   # the gross lone value: kept by the per-photo test, rejected by the block check
            assert r["photo_test_only"]["errors"].max() > 3.0
    n, med, p95, mx, sd = summary(np.concatenate(errs), np.concatenate(norm))
    assert n >= 8
    assert med <= 0.3 and p95 <= 1.0 and mx <= 3.0
    o = occlusion_block(data, max_photos=2)
    assert o["hidden"] >= 1
    assert o["measured_hidden"] == 0, o["statuses"]
