"""Roofs shaded per ray (synthetic._photo, _texture.roof_albedo): face boundaries lie where the geometry puts them.

A roof edge (ridge, hip) seen with the *true* orientation must be found on its true projection: the
face a pixel's ray hits decides its shade, and supersampling at geometric edges anti-aliases the
boundary about its true position.  The edges are located here independently of photocontrol: the
grey-level gradient across the projected edge, its peak by a parabola through three samples.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.synthetic.aerial import AerialScene, Exposure, aerial_camera, project_to_pixels, render_photo
from lidarcat.synthetic.scene import Building

E0, N0 = 680_400.0, 7_184_200.0
CAM = aerial_camera((520, 400))


@pytest.fixture(scope="module")
def setup():
    blds = (Building("hip", E0 - 11, N0 + 5, 16, 9, 35, 6, 7.0), Building("gable", E0 + 10, N0 + 6, 14, 9, 30, 6, 0.0),
            Building("pyramid", E0 - 1, N0 - 9, 9, 9, 40, 5, 30.0))
    sc = AerialScene(buildings=blds, texel_m=0.1, seed=3, trees=False)
    eo = np.array([E0 + 1.5, N0 - 0.7, sc.base_height(0) + 0.1 * 35 / 0.03, 0.004, -0.006, 0.2])
    return sc, eo


def _edges(sc: AerialScene):
    """(start, end, kind) 3-D roof edges: ridges and hips, from the solids' geometry."""
    out = []
    for k, b in enumerate(sc.buildings):
        base = sc.base_height(k)
        top, L, W = base + b.top_m, b.length_m / 2, b.width_m / 2
        if b.kind in ("hip", "gable"):
            d = L - W if b.kind == "hip" else L
            e, n = b.to_world(np.array([-d, d]), np.zeros(2))
            out.append(((e[0], n[0], top), (e[1], n[1], top), "ridge"))
        if b.kind in ("hip", "pyramid"):
            d = L - W if b.kind == "hip" else 0.0
            for sx in (-1, 1):
                for sy in (-1, 1):
                    e, n = b.to_world(np.array([sx * d, sx * L]), np.array([0.0, sy * W]))
                    out.append(((e[0], n[0], top), (e[1], n[1], base + b.eave_m), "hip"))
    return out


def _edge_offsets(img: np.ndarray, eo: np.ndarray, a, b) -> tuple[np.ndarray, float]:
    """Offsets (px) of the image edge from the true projected edge, at stations 1 px apart, and the
    edge's contrast (grey levels between the means 2.5 px either side)."""
    import cv2

    tt = np.linspace(0.0, 1.0, 200)
    curve = project_to_pixels(CAM, eo, np.asarray(a)[None] * (1 - tt[:, None]) + np.asarray(b)[None] * tt[:, None])
    seg = np.cumsum(np.r_[0, np.hypot(*np.diff(curve, axis=0).T)])
    t = np.arange(3.0, seg[-1] - 3.0, 1.0)      # clear of the vertices where three faces meet
    p = np.column_stack([np.interp(t, seg, curve[:, 0]), np.interp(t, seg, curve[:, 1])])
    u = np.gradient(p, axis=0)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    nrm = np.column_stack([-u[:, 1], u[:, 0]])
    s = np.arange(-2.5, 2.51, 0.1)
    cols = (p[:, 0:1] + s[None] * nrm[:, 0:1]).astype(np.float32)
    rows = (p[:, 1:2] + s[None] * nrm[:, 1:2]).astype(np.float32)
    prof = cv2.remap(img.astype(np.float32), cols, rows, cv2.INTER_LINEAR)
    g = np.abs(np.gradient(prof, 0.1, axis=1))
    k = np.clip(np.argmax(g, axis=1), 1, len(s) - 2)
    i = np.arange(len(t))
    y0, y1, y2 = g[i, k - 1], g[i, k], g[i, k + 1]
    off = s[k] + 0.1 * 0.5 * (y0 - y2) / np.where(np.abs(y0 - 2 * y1 + y2) > 1e-9, y0 - 2 * y1 + y2, 1.0)
    return off, float(abs(np.mean(prof[:, -5:]) - np.mean(prof[:, :5])))


def test_roof_edges_lie_on_their_true_projection(setup):
    """With the true orientation, each ridge and hip between faces of clearly different shade (12 grey
    levels or more; the others drown in the tile courses) is found within 0.15 px of its projection
    (median over the edge), and in the mean over the edges within 0.08 px."""
    sc, eo = setup
    img = render_photo(sc, CAM, eo, exposure=Exposure(gain=1.1), truth=False, supersample=4).image
    means = []
    for a, b, kind in _edges(sc):
        off, contrast = _edge_offsets(img, eo, a, b)
        assert len(off) > 15, kind
        if contrast >= 12:
            means.append(float(np.median(off)))
    means = np.array(means)
    assert len(means) >= 6
    assert np.abs(means).max() < 0.15, np.round(means, 3)
    assert np.abs(means).mean() < 0.08, np.round(means, 3)


def test_supersampling_changes_only_pixels_at_geometric_edges(setup):
    """``supersample=4`` averages sub-rays where the hit surface (building and face, terrain) changes
    between neighbours, nowhere else; the truth maps keep the pixel centre's ray."""
    sc, eo = setup
    one = render_photo(sc, CAM, eo, truth=True, supersample=1)
    four = render_photo(sc, CAM, eo, truth=True, supersample=4)
    np.testing.assert_allclose(four.xyz, one.xyz, atol=1e-3)
    assert np.array_equal(four.building, one.building)
    diff = np.abs(one.image.astype(int) - four.image)
    # geometric edges (eaves, ridges, hips, walls) all lie on a building or next to one
    near = np.zeros_like(diff)
    b = one.building >= 0
    near[1:-1, 1:-1] = b[1:-1, 1:-1] | b[:-2, 1:-1] | b[2:, 1:-1] | b[1:-1, :-2] | b[1:-1, 2:]
    assert ((diff >= 5) & near).sum() > 200     # the eaves and ridges of three buildings
    # nothing changes on open ground but a rounding (the terrain hit converges to 0.1 mm from a start
    # that depends on the tile's 1 px margin)
    assert diff[~near].max() <= 1


def test_supersample_must_be_positive(setup):
    from lidarcat.errors import LidarcatError

    sc, eo = setup
    with pytest.raises(LidarcatError, match="supersample must be 1 or more, got 0"):
        render_photo(sc, CAM, eo, supersample=0)
