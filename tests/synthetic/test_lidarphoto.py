"""Photos rendered over a LiDAR surface (lidarcat.synthetic.lidarphoto): the roof vertex is an exact corner."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lidarcat.synthetic.aerial import Exposure, project_to_pixels
from lidarcat.synthetic.aerial import aerial_camera
from lidarcat.synthetic.lidarphoto import (cast_rays, flight_poses, lidar_surface, render_lidar_photo,
                                           roof_patch, vertex_visible)

V = np.array([10.0, 20.0, 8.0])
#: a ridge along N ending (at V) in a hip facing N: faces W, E, N, slopes 40-45 deg
NORMALS = np.array([[-math.sin(math.radians(40)), 0, math.cos(math.radians(40))],
                    [math.sin(math.radians(45)), 0, math.cos(math.radians(45))],
                    [0, math.sin(math.radians(42)), math.cos(math.radians(42))]])


def _roof_points(spacing: float = 0.3, seed: int = 0):
    """LiDAR-like points: the hip roof (the lowest of its planes) on a 6 x 10 m house, ground at 0, a 12 m tree."""
    rng = np.random.default_rng(seed)
    g = np.mgrid[-10:30:spacing, 0:40:spacing].reshape(2, -1).T + rng.uniform(-0.1, 0.1, (1, 2))
    e, n = g[:, 0], g[:, 1]
    h_planes = V[2] - (NORMALS[:, 0:1] * (e - V[0]) + NORMALS[:, 1:2] * (n - V[1])) / NORMALS[:, 2:3]
    roof = h_planes.min(axis=0)
    house = (np.abs(e - V[0]) < 3.0) & (n > V[1] - 10.0) & (n < V[1] + 3.0)
    tree = np.hypot(e - 2.0, n - 30.0) < 2.5
    h = np.where(house, roof, np.where(tree, 12.0, 0.0))
    xyz = np.column_stack([e, n, h])
    inten = 50 + 30 * np.sin(e) * np.cos(n) + rng.normal(0, 5, len(e))
    lab = np.where(house, np.argmin(h_planes, axis=0), -1)
    return xyz, inten, lab


@pytest.fixture(scope="module")
def scene():
    xyz, inten, lab = _roof_points()
    near = np.hypot(xyz[:, 0] - V[0], xyz[:, 1] - V[1]) <= 6.0
    patch = roof_patch(V, NORMALS, [xyz[near & (lab == i)] for i in range(3)])
    surf = lidar_surface(xyz, inten, (-5.0, 5.0, 25.0, 35.0), patches=[patch])
    return xyz, surf


def test_surface_of_points_on_a_plane_is_the_plane():
    """The TIN raster (production.terrain.tin_grid, rows turned to run from the south) at the cell
    centres of the surface's own origin: exact on a plane."""
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 20, (400, 2))
    z = 2.0 + 0.3 * xy[:, 0] - 0.7 * xy[:, 1]
    surf = lidar_surface(np.column_stack([xy, z]), np.ones(400), (2.03, 2.07, 18.0, 18.0), cell_m=0.5)
    ny, nx = surf.height.shape
    e = surf.origin_m[0] + (np.arange(nx) + 0.5) * 0.5
    n = surf.origin_m[1] + (np.arange(ny) + 0.5) * 0.5
    assert surf.origin_m[0] <= 2.03 and surf.origin_m[1] <= 2.07
    assert np.allclose(surf.height, 2.0 + 0.3 * e[None, :] - 0.7 * n[:, None], atol=1e-4)


def test_patch_is_continuous_across_its_edges(scene):
    _, surf = scene
    p = surf.patches[0]
    # points on both sides of each sector boundary, 0.5-3 m from the vertex, 1e-6 rad apart
    for b in p.bounds_rad:
        r = np.linspace(0.5, 3.0, 11)
        hs = [p.height(V[0] + r * np.cos(b + s), V[1] + r * np.sin(b + s)) for s in (-1e-6, 1e-6)]
        assert (hs[0][1] != hs[1][1]).all()                       # two faces
        assert np.allclose(hs[0][0], hs[1][0], atol=1e-5)         # one height: the planes' intersection line


def test_the_vertex_is_an_exact_corner_in_the_photo(scene):
    _, surf = scene
    cam = dataclasses.replace(aerial_camera((240, 180)), focal_length_mm=100.0)
    eo = np.array([V[0] + 3.0, V[1] - 2.0, 75.0, 0.02, -0.03, 0.3])
    ph = render_lidar_photo(surf, cam, eo, exposure=Exposure(noise_sd=0.0), supersample=4)
    px = project_to_pixels(cam, eo, V[None])[0]
    assert vertex_visible(surf, eo, V[None])[0]
    # the ray through the vertex's projection meets the surface at the vertex
    from lidarcat.geometry.collinearity import rotation_matrix

    m = rotation_matrix(eo[3:])
    xy = cam.pixel_to_photo(px[None])
    hit, lab = cast_rays(surf, eo[:3], np.column_stack([xy, [-cam.focal_length_mm]]) @ m)
    assert np.linalg.norm(hit[0] - V) < 1e-4
    # all three faces meet within a pixel of it; the truth map projects back onto its pixels
    c, r = (int(round(v)) for v in px)
    labels = set(ph.building[r - 1:r + 2, c - 1:c + 2].ravel().tolist())
    assert labels == {0, 1, 2}
    rr, cc = np.mgrid[0:cam.rows_px:7, 0:cam.columns_px:7]
    back = project_to_pixels(cam, eo, ph.xyz[rr, cc].reshape(-1, 3))
    assert np.nanmax(np.abs(back - np.column_stack([cc.ravel(), rr.ravel()]))) < 0.01
    # the faces are shaded apart: the photo has its roof edges
    faces = [float(np.median(ph.image[ph.building == k])) for k in range(3)]
    assert max(faces) - min(faces) > 10


def test_a_tree_hides_the_vertex(scene):
    _, surf = scene
    # from the north, low: the 12 m tree at (2, 30) stands on the ray to the vertex
    c = np.array([2.0, 30.0]) + 1.6 * (np.array([2.0, 30.0]) - V[:2])
    eo = np.array([c[0], c[1], 8.0 + 1.6 * (12.5 - 8.0) + 4.0, 0, 0, 0])
    d = V - eo[:3]
    hit, _ = cast_rays(surf, eo[:3], d[None])
    assert not vertex_visible(surf, eo, V[None])[0]
    assert hit[0, 2] == pytest.approx(12.0, abs=0.01)
    assert vertex_visible(surf, np.array([V[0], V[1] - 5.0, 80.0, 0, 0, 0]), V[None])[0]


def test_flight_poses_give_the_gsd():
    cam = aerial_camera((800, 600))
    eo = flight_poses((100.0, 200.0), 5.0, 0.1, cam, n_strips=2, per_strip=3, heading_deg=90.0, seed=1)
    assert eo.shape == (6, 6)
    height = 0.1 * cam.focal_length_mm / cam.pixel_size_x_mm
    assert np.allclose(eo[:, 2], 5.0 + height, atol=4 * 0.01 * height)
    # strips along E: photos 40 % of 600 rows * 0.1 m apart, strips 70 % of 800 columns * 0.1 m
    assert np.allclose(np.diff(eo[:3, 0]), 24.0, atol=3.0)
    assert np.allclose(eo[3:, 1] - eo[:3, 1], -56.0, atol=3.0)
