"""The vertex asked for (issue 29, step 0): more faces in the clip than the corner needs.

Two defects found on the AHN3 tiles, rebuilt here on synthetic roofs with known
vertices: at the default 8 m clip a small corner's faces fall below the
``max_planes`` largest faces of the neighbours, so extraction either finds no
vertex within 4 m (``no_vertex``) or returns, as ``ok``, another vertex metres
away.  Retrying at smaller clip radii (``scales``) finds the corner asked for;
a vertex far from the position, or two equally near, is said so.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarcat.control.params import get_params
from lidarcat.control.vertices import extract_roof
from lidarcat.synthetic.roofs import synthetic_roof
from roof_monte_carlo import monte_carlo_roofs

O = np.array([85000.0, 447000.0, 0.0])
#: small pyramids and hips around a hip roof with a dormer (E, N offset, length, width, azimuth, kind)
NEIGHBOURS = [(-2, 10.5, 10, 6, 17, "pyramid"), (5, 11, 6, 6, 17, "pyramid"), (-8, 9, 6, 6, 17, "pyramid")]
#: the extraction before the fix: one clip, no ambiguity test -- and no radius-stability check (session 7), which
#: since session 8 repeats the request at 4-12 m and refuses such a far vertex as unstable (the other radii find
#: other corners); without it the defect shows as found
OLD = dict(scales=(), ambiguity_m=0.0, stability_scales=())


def _town(neighbours, seed, **main_kw):
    main = synthetic_roof("hip", dormer=True, density_m2=16, noise_h_m=0.03, origin=tuple(O), ground=False,
                          seed=seed, **main_kw)
    xs = [main.xyz]
    for k, (dx, dy, L, W, az, kind) in enumerate(neighbours):
        xs.append(synthetic_roof(kind, length_m=L, width_m=W, azimuth_deg=az, density_m2=16, noise_h_m=0.03,
                                 origin=tuple(O + [dx, dy, 0]), ground=False, seed=seed + k + 1).xyz)
    return main, np.vstack(xs)


def test_small_corner_among_many_faces_is_found_not_no_vertex():
    """AHN3 84886.0 447427.6: ``no_vertex`` at 8 m (the corner's faces not among the 12 largest)."""
    main, xyz = _town(NEIGHBOURS, seed=1, length_m=20)
    v = main.vertices[2]  # the dormer's valley vertex: 3 small faces
    at = v[:2] + [0.5, -0.4]
    old = extract_roof(xyz, at, params=get_params(**OLD))
    assert old.status == "no_vertex" and "no three of them meet within 4 m" in old.reason
    cp = extract_roof(xyz, at)
    assert cp.status == "ok" and cp.reason == ""
    np.testing.assert_allclose(cp.enh_m, v, atol=0.10)
    assert cp.offset_m == pytest.approx(np.hypot(0.5, 0.4), abs=0.1)


def test_far_vertex_is_not_returned_silently_when_the_near_one_exists():
    """AHN3 84941.7 447430.4: ``ok`` for a vertex 3.17 m away; the one asked for is returned now."""
    main, xyz = _town(NEIGHBOURS + [(11, 4, 9, 6, 107, "hip"), (-12, 2, 9, 6, 107, "hip")], seed=1)
    v = main.vertices[2]
    at = v[:2] + [0.5, -0.4]
    old = extract_roof(xyz, at, params=get_params(**OLD))
    assert old.status == "ok" and np.linalg.norm(old.enh_m - v) > 3.0  # the defect, as found
    # even without the retries, an ok vertex metres away now says so
    assert old.reason == (f"the nearest vertex found is {old.offset_m:.2f} m from the position (more than "
                          f"near_m = 1.5 m): check it is the one meant") and old.offset_m > 2.5
    cp = extract_roof(xyz, at)
    assert cp.status == "ok" and cp.reason == ""
    np.testing.assert_allclose(cp.enh_m, v, atol=0.10)


def test_midway_between_two_vertices_is_ambiguous_with_both_listed():
    s = synthetic_roof("hip", length_m=14, width_m=9, density_m2=10, noise_h_m=0.03, seed=2)
    a, b = s.vertices[0], s.vertices[1]  # the ridge ends, 5 m apart
    cp = extract_roof(s.xyz, (a[:2] + b[:2]) / 2, radius_m=8, params=get_params(max_offset_m=3.0))
    assert cp.status == "ambiguous" and not cp
    assert cp.reason.startswith("2 vertices about equally near the position")
    for v in (a, b):
        assert f"{v[0]:.1f}"[:-1] in cp.reason and f"{v[1]:.1f}"[:-1] in cp.reason
    # nearer to one end: that end, with no note (2.5 m - 1.2 m = 1.3 m away)
    near = extract_roof(s.xyz, a[:2] + 0.2 * (b[:2] - a[:2]) / np.linalg.norm(b[:2] - a[:2]) * 1.0,
                        radius_m=8)
    assert near.status == "ok" and near.reason == ""
    np.testing.assert_allclose(near.enh_m, a, atol=0.10)


@pytest.mark.parametrize("kw,msg", [(dict(near_m=0.0), "near_m must be positive"),
                                    (dict(scales=(0.5, 1.0)), "scales must be fractions in"),
                                    (dict(ambiguity_m=-1.0), "ambiguity_m must be >= 0")])
def test_parameters_are_checked(kw, msg):
    with pytest.raises(ValueError, match=msg):
        get_params(**kw)


# ------------------------------------------------------------------ the two AHN3 positions of the issue
AHN3 = [Path(__file__).resolve().parents[1] / "data" / "lidar" / f"ahn3_cropped_{k}.laz" for k in (1, 2)]
#: (--at E N, the vertex meant: E N h as `--radius 5` gives it, issue 29 / docs/extraction.md).  Since the
#: break-line buffer (lidarcat.control.segment, session 6; the default since session 7) both are 3.8 / 3.9 cm
#: lower than before (9.669 / 9.581 m, about 3 sd_h): the points within 0.2 m of the ridges and hips, left out
#: of the fits now, lie above the planes of the faces' interiors (ridge and hip tiles, footprints across the
#: break line) and lifted the vertex; the plan position moved by 4-8 mm.  Both pass the radius-stability
#: check (lidarcat.control.stability): `ok` at the default radius, not `unstable`. With the tested buffer
#: (lidarcat.control.segment, session 7) its pooled test drops every band in both clips: the blanket
#: buffer's vertices (tests/control/test_break_buffer.py).
AHN3_POSITIONS = {"hip_end": ((84886.0, 447427.6), (84886.588, 447429.228, 9.631)),
                  "small_corner": ((84941.7, 447430.4), (84941.741, 447430.359, 9.542))}


@pytest.fixture(scope="module")
def ahn3_default():
    """`lidarcat extract --lidar ahn3_cropped_1.laz --lidar ahn3_cropped_2.laz --at E N --crs EPSG:7415` (default radius)."""
    pytest.importorskip("laspy")
    from lidarcat.control.batch import Job, extract_batch

    jobs = [Job(name, *at) for name, (at, _) in AHN3_POSITIONS.items()]
    cps = extract_batch(jobs, lidar=AHN3, crs="EPSG:7415")
    from lidarcat.lidar import TileIndex

    idx = TileIndex.build(AHN3, crs="EPSG:7415")
    clips = {name: idx.query_radius(at, 8.0).xyz for name, (at, _) in AHN3_POSITIONS.items()}
    return dict(zip(AHN3_POSITIONS, cps)), clips


@pytest.mark.parametrize("name", list(AHN3_POSITIONS))
def test_ahn3_positions_of_the_issue_give_the_vertex_asked_for_at_the_default_radius(ahn3_default, name):
    """Both positions of issue 29 on the real tiles: the default radius (8 m) returns the vertex `--radius 5` finds.

    Before the fix (one clip, no retries: ``scales=()``), the hip end gave ``no_vertex`` and the small corner a
    vertex 3.17 m away and 0.73 m lower with ``status: ok`` (asserted below, so the test sees the mechanism).
    """
    cps, clips = ahn3_default
    at, meant = AHN3_POSITIONS[name]
    cp = cps[name]
    assert get_params().radius_m == 8.0 and cp.status == "ok" and cp.n_planes == 3
    np.testing.assert_allclose(cp.enh_m, meant, atol=0.02)  # the published --radius 5 vertex, 3 decimals + noise
    r5 = extract_roof(clips[name], at, radius_m=5.0)
    sd = float(np.sqrt(np.linalg.eigvalsh(cp.cov_m2)[-1]))
    assert r5.status == "ok" and np.linalg.norm(cp.enh_m - r5.enh_m) < sd  # same corner, within its sd
    old = extract_roof(clips[name], at, params=get_params(**OLD), clipped=True)
    if name == "hip_end":  # 1.72 m from the --at: ok, with the far-vertex note
        assert old.status == "no_vertex"
        assert cp.offset_m == pytest.approx(1.72, abs=0.02) and "check it is the one meant" in cp.reason
    else:
        assert old.status == "ok" and np.linalg.norm(old.enh_m[:2] - meant[:2]) > 3.0 and old.enh_m[2] < meant[2] - 0.5
        assert cp.offset_m < 0.1 and cp.reason == ""


def test_a_pyramid_apex_is_not_ambiguous_with_the_triples_of_its_own_faces():
    """Four faces meet at the apex; on a sparse noisy roof their four triples scatter by their sd (0.6-0.7 m here),
    and were listed as rivals: run 56 of the Monte Carlo was ``ambiguous`` with a triple of the 3.9 m clip 0.68 m
    from the apex.  A triple of the chosen vertex's own faces is that corner: ``ok``, within 3 sd of the apex."""
    from lidarcat.control.vertices import _extract_clip

    # run 56 of the Monte Carlo's sparsest pyramid (tests/control/test_control.py): 2 pts/m2, 0.15 m height noise
    [(_, s, at)] = monte_carlo_roofs("pyramid", 2.0, 0.15, [56])
    p = get_params(sd_en_m=0.03, sd_h_m=0.15, radius_m=6)
    cp = extract_roof(s.xyz, at, params=p)
    assert cp.status == "ok", cp.reason
    assert np.all(np.abs(cp.enh_m - s.vertices[0]) < 3 * cp.sd_m), (cp.enh_m - s.vertices[0]) / cp.sd_m
    # one clip of the apex alone: the ambiguity test is given the chosen vertex and no triple of its faces
    clip = s.xyz[np.hypot(*(s.xyz[:, :2] - at).T) <= 3.9]
    others: list = []
    one = _extract_clip(clip, at, p.replace(radius_m=3.9, max_offset_m=3.0), "V", others)
    assert one.status == "ok" and one.n_planes == 4
    assert len(others) == 1 and np.array_equal(others[0][:3], one.enh_m)
