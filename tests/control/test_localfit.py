"""The local extraction (lidarcat.control.localfit): the vertex is the corner's, not the search clip's.

A synthetic pyramid 20 m wide whose faces bend down beyond 5 m from the apex (3 cm per metre: a bell-cast
or sagging roof, the largest class of the radius sweep's moving vertices on the AHN3 tiles,
docs/extraction.md).  With the search clip's whole faces the apex sinks with the radius (the faces tilt
with their outer parts); with the local extraction every search radius gives the same vertex, that of the
5 m clip about the apex, where the faces are exact planes.
"""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.control.localfit import CENTRE_TOL_M, extract_locally
from lidarcat.control.params import get_params
from lidarcat.control.vertices import ControlPoint, extract_roof
from lidarcat.synthetic.roofs import synthetic_roof

RADII = (5.0, 6.0, 8.0, 10.0, 12.0)


@pytest.fixture(scope="module")
def bent():
    """Pyramid points with the faces bent down 0.03 m per m beyond 5 m (plan) from the apex; the apex (m)."""
    s = synthetic_roof("pyramid", width_m=20, density_m2=8, noise_h_m=0.03, seed=3, slope_deg=30)
    xyz = s.xyz.copy()
    apex = s.vertices[0]
    d = np.hypot(*(xyz[:, :2] - apex[:2]).T)
    roof = xyz[:, 2] > xyz[:, 2].min() + 6.5  # above the 6 m eaves: the roof, not the walls and ground
    bend = roof & (d > 5.0)
    xyz[bend, 2] -= 0.03 * (d[bend] - 5.0)
    return xyz, apex


def _sweep(xyz, apex, fit_radius_m):
    p = get_params(stability_scales=()).replace(fit_radius_m=fit_radius_m)
    return [extract_roof(xyz, apex[:2] + [0.3, -0.2], params=p.replace(radius_m=r)) for r in RADII]


def test_whole_faces_move_with_the_radius_on_a_bent_roof(bent):
    """The mechanism: the bent outer parts tilt the search clip's whole faces and lift the apex as the clip grows."""
    xyz, apex = bent
    cps = _sweep(xyz, apex, None)
    assert all(cp.status == "ok" for cp in cps)
    dh = np.array([cp.enh_m[2] - apex[2] for cp in cps])
    sd_h = np.array([cp.sd_h_m for cp in cps])
    # 5 m: inside the exact part; 12 m: the bent rim tilts every face and lifts the apex by several sd
    assert abs(dh[0]) < 3 * sd_h[0]
    assert dh[-1] > 0.05 and dh[-1] > 5 * sd_h[-1], (dh, sd_h)


def test_local_vertex_is_the_same_at_every_search_radius_and_unbiased(bent):
    xyz, apex = bent
    cps = _sweep(xyz, apex, 5.0)
    assert all(cp.status == "ok" and cp.reason == "" for cp in cps), [(cp.status, cp.reason) for cp in cps]
    enh = np.array([cp.enh_m for cp in cps])
    # one fixed point: the centres agree to the iteration's tolerance, so the vertices to about it
    assert np.ptp(enh, axis=0).max() < 2 * CENTRE_TOL_M, np.ptp(enh, axis=0)
    cp = cps[-1]
    assert np.all(np.abs(cp.enh_m - apex) < 3 * cp.sd_m), (cp.enh_m - apex, cp.sd_m)
    # its faces are the 5 m clip's: their points lie within 5 m of the vertex
    xyz_c, lab = cp.labels
    used = lab >= 0
    assert used.sum() > 100 and np.hypot(*(xyz_c[used, :2] - cp.enh_m[:2]).T).max() <= 5.0 + 1e-9


def test_local_clip_without_a_vertex_keeps_the_search_vertex_and_says_why(bent):
    xyz, apex = bent
    p = get_params(stability_scales=(), radius_m=8.0)
    whole = extract_roof(xyz, apex[:2], params=p.replace(fit_radius_m=None))
    cp = extract_roof(xyz, apex[:2], params=p.replace(fit_radius_m=0.5))
    assert cp.status == "ok"
    np.testing.assert_array_equal(cp.enh_m, whole.enh_m)
    assert cp.reason.startswith("the clip of 0.5 m about the vertex gives too_few_points (")
    assert cp.reason.endswith("; so do the clips of 0.65-0.8 m: the vertex of the search clip is kept")


def _cp(e, n, h=10.0, status="ok", reason=""):
    return ControlPoint("V", np.array([e, n, h]), np.eye(3) * 1e-4, n_planes=3, status=status, reason=reason,
                        approx_en=np.array([0.0, 0.0]))


def test_extract_locally_iterates_to_the_fixed_point():
    """A fake clip extraction whose vertex is halfway between the centre and (1, 2): centres converge there."""
    target = np.array([1.0, 2.0])
    calls = []

    def extract(c, r):
        assert r == 5.0
        calls.append(np.array(c))
        x = c + 0.5 * (target - c) if len(calls) < 3 else target  # the third clip is centred near enough
        return _cp(*x)

    got = extract_locally(_cp(0.9, 1.9, reason="far note"), 5.0, extract, apart_m=0.5)
    assert got.status == "ok" and got.reason == "far note"  # an ok vertex keeps the search's note
    np.testing.assert_allclose(got.enh_m[:2], target)
    assert len(calls) == 4  # the fourth clip is centred on the third vertex, which it returns again
    np.testing.assert_array_equal(got.approx_en, [0.0, 0.0])


def test_extract_locally_refuses_another_corner():
    radii = []

    def extract(c, r):
        radii.append(r)
        return _cp(2.0, 0.0)

    got = extract_locally(_cp(0.0, 0.0), 5.0, extract, apart_m=0.5)
    np.testing.assert_array_equal(got.enh_m, [0.0, 0.0, 10.0])
    assert radii == [5.0, 6.5, 8.0]  # LADDER: each clip centred on the vertex, none finds it
    assert got.reason == ("the clip of 5 m about the vertex finds another corner 2.00 m away; "
                          "so do the clips of 6.5-8 m: the vertex of the search clip is kept")


def test_extract_locally_climbs_the_ladder_to_the_first_clip_that_finds_the_corner():
    def extract(c, r):
        if r == 5.0:
            return _cp(0.0, 0.0, status="no_vertex", reason="x")
        return _cp(0.01, 0.0, 9.0)  # the same corner, 1 cm away

    got = extract_locally(_cp(0.0, 0.0), 5.0, extract, apart_m=0.5)
    np.testing.assert_array_equal(got.enh_m, [0.01, 0.0, 9.0])
    assert got.status == "ok" and got.reason == ""


def test_fit_radius_parameter_and_presets():
    assert get_params().fit_radius_m == 5.0  # the default since session 9 (docs/extraction.md, "Local extraction")
    assert get_params("thesis").fit_radius_m is None  # the published method: one clip about the position
    with pytest.raises(ValueError, match=r"^fit_radius_m must be positive \(m\) or None, got -1$"):
        get_params(fit_radius_m=-1)


def test_cli_fit_radius_and_stability_switches(monkeypatch, tmp_path, bent):
    from lidarcat.cli.main import cli
    import lidarcat.control.batch as batch

    seen = []

    def fake(jobs, **kw):
        seen.append(kw["params"])
        return [ControlPoint.failed(j.point, [j.e_m, j.n_m], "no_planes", "fake") for j in jobs]

    monkeypatch.setattr(batch, "extract_batch", fake)
    tile = tmp_path / "roof.xyz"
    np.savetxt(tile, bent[0][:50], fmt="%.3f")
    r = CliRunner()
    out = r.invoke(cli, ["extract", "--at", "0", "0", str(tile), "--fit-radius", "0", "--no-stability-check"])
    assert out.exit_code == 1, out.output
    assert seen[-1].fit_radius_m is None and seen[-1].stability_scales == ()
    out = r.invoke(cli, ["extract", "--at", "0", "0", str(tile)])
    assert seen[-1].fit_radius_m == 5.0
    out = r.invoke(cli, ["extract", "--at", "0", "0", str(tile), "--fit-radius", "4.5", "--preset", "thesis",
                         "--stability-check"])
    assert seen[-1].fit_radius_m == 4.5 and seen[-1].stability_scales == get_params().stability_scales
    out = r.invoke(cli, ["extract", "--at", "0", "0", str(tile)])
    assert seen[-1] == get_params()
    out = r.invoke(cli, ["extract", "--at", "0", "0", str(tile), "--fit-radius", "-2"])
    assert out.exit_code == 2
    assert "Error: Invalid value for --fit-radius: must be positive (m), or 0 for whole faces, got -2" in out.output


def test_the_check_repeats_the_request_with_the_local_extraction_and_centres_on_the_vertex_without(monkeypatch, bent):
    """Local extraction: the check's clips are centred on the position asked (what is left to depend on the radius is
    where the search finds the corner); whole faces: on the vertex, as in session 7 (lidarcat.control.vertices)."""
    import lidarcat.control.vertices as vertices
    from lidarcat.control.stability import StabilityResult

    centres = []

    def spy(cp, p, extract):
        centres.append(np.asarray(extract(4.0).approx_en))
        return StabilityResult(True, 4.03, 0.01)

    monkeypatch.setattr(vertices, "check_stability", spy)
    xyz, apex = bent
    at = apex[:2] + [0.6, -0.4]
    local = extract_roof(xyz, at)
    whole = extract_roof(xyz, at, params=get_params().replace(fit_radius_m=None))
    assert local.status == whole.status == "ok"
    np.testing.assert_array_equal(centres[0], at)
    np.testing.assert_array_equal(centres[1], whole.enh_m[:2])
