r"""Rays of pixels onto a height surface and back into another photo (the geometry of guided matching).

A pixel ``(C, L)`` of a photo with exterior orientation ``(X0, Y0, Z0, omega, phi, kappa)``
becomes corrected photo coordinates ``(x, y)`` (eq. 01-07, :meth:`Camera.pixel_to_photo`).
With ``M = R3(kappa) R2(phi) R1(omega)`` (:func:`lidarcat.geometry.collinearity.rotation_matrix`)
the collinearity equations ``x = -c u1/u3``, ``y = -c u2/u3``, ``u = M (X - X0)`` are solved
for the ray: every object point ``X = X0 + t d`` with ::

    d = M^T (x, y, -c)^T,   t > 0,

projects to ``(x, y)`` (substitute: ``u = t (x, y, -c)``, so ``-c u1/u3 = x``).

The ray meets a height surface ``Z = h(E, N)`` where ``Z0 + t d_Z = h(X0 + t d_E, Y0 + t d_N)``.
It is solved by the fixed-point iteration ::

    t_{k+1} = (h(E_k, N_k) - Z0) / d_Z,     (E_k, N_k) = (X0, Y0) + t_k (d_E, d_N),

started at the surface's mean height; for a constant height the first step is exact,
for a terrain/roof grid it converges when the surface slope seen along the ray is below the
ray's steepness (``|dh/ds| < |d_Z| / |d_EN|``: every near-nadir photo over terrain; a wall
seen sideways is not, and its few points keep the last iterate -- the guided search's
uncertainty covers them or they are simply not found).

The point is then projected into photo ``B`` with the collinearity equations and
:meth:`Camera.photo_to_pixel`.  Everything is vectorised over the pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import LidarcatError
from ..geometry.camera import Camera
from ..geometry.collinearity import project, rotation_matrix

__all__ = ["MatchError", "HeightSurface", "ray_directions", "ray_to_surface", "project_to_pixel", "transfer"]


class MatchError(LidarcatError, ValueError):
    """Photos that cannot be matched: no overlap, no orientation on a large block, no verified pair, no surface."""


@dataclass(frozen=True, eq=False)
class HeightSurface:
    """A height model: a constant height, or a north-up grid (a LiDAR DSM/DTM).

    Parameters
    ----------
    mean_m : float
        Height where the grid has no value (and the whole surface without a grid), m.
    heights_m : ndarray (rows, cols) or None
        Cell-centre heights, NaN = no data.
    x0_m, y0_m, cell_m : float
        West edge, north edge and cell size of the grid, m.
    sd_m : float
        Standard deviation of a height read here, m (a DSM: the LiDAR noise plus what
        the cell smooths away; a mean height: the relief).
    """

    mean_m: float
    heights_m: np.ndarray | None = None
    x0_m: float = 0.0
    y0_m: float = 0.0
    cell_m: float = 1.0
    sd_m: float = 1.0
    _filled: np.ndarray | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        if self.heights_m is not None:
            g = np.asarray(self.heights_m, dtype=np.float64)
            if g.ndim != 2:
                raise MatchError(f"a height grid must be 2-D (rows, cols), got shape {g.shape}")
            object.__setattr__(self, "_filled", np.where(np.isfinite(g), g, self.mean_m))

    def height(self, e_m: Any, n_m: Any) -> np.ndarray:
        """Bilinear height at plan positions (the mean height off the grid), m."""
        e = np.asarray(e_m, dtype=np.float64)
        n = np.asarray(n_m, dtype=np.float64)
        if self._filled is None:
            return np.full(e.shape, float(self.mean_m))
        g = self._filled
        fc = (e - self.x0_m) / self.cell_m - 0.5
        fr = (self.y0_m - n) / self.cell_m - 0.5
        ok = np.isfinite(fc) & np.isfinite(fr) & (fc >= 0) & (fr >= 0) & (fc <= g.shape[1] - 1) & (fr <= g.shape[0] - 1)
        c0 = np.clip(np.floor(np.where(ok, fc, 0)).astype(np.int64), 0, max(g.shape[1] - 2, 0))
        r0 = np.clip(np.floor(np.where(ok, fr, 0)).astype(np.int64), 0, max(g.shape[0] - 2, 0))
        c1 = np.minimum(c0 + 1, g.shape[1] - 1)
        r1 = np.minimum(r0 + 1, g.shape[0] - 1)
        u = np.clip(np.where(ok, fc, 0) - c0, 0, 1)
        v = np.clip(np.where(ok, fr, 0) - r0, 0, 1)
        h = ((1 - u) * (1 - v) * g[r0, c0] + u * (1 - v) * g[r0, c1] + (1 - u) * v * g[r1, c0] + u * v * g[r1, c1])
        return np.where(ok, h, float(self.mean_m))


def ray_directions(camera: Camera, eo: Any, colrow_px: Any) -> np.ndarray:
    """Object-space directions ``d = M^T (x, y, -c)`` (not normalised) of pixels, shape (n, 3)."""
    xy = camera.pixel_to_photo(np.asarray(colrow_px, dtype=np.float64).reshape(-1, 2))
    m = rotation_matrix(np.asarray(eo, dtype=np.float64)[3:6])
    img = np.column_stack([xy, np.full(len(xy), -camera.focal_length_mm)])
    return img @ m      # rows: (M^T v)^T = v^T M


def ray_to_surface(camera: Camera, eo: Any, colrow_px: Any, surface: HeightSurface, *,
                   iterations: int = 8) -> np.ndarray:
    """Object points (E, N, h; m) where the rays of pixels meet *surface*, shape (n, 3).

    The fixed-point iteration of the module docstring, *iterations* steps.
    """
    eo = np.asarray(eo, dtype=np.float64)
    d = ray_directions(camera, eo, colrow_px)
    dz = np.where(np.abs(d[:, 2]) < 1e-12, -1e-12, d[:, 2])
    h = np.full(len(d), float(surface.mean_m))
    for _ in range(max(1, iterations) if surface.heights_m is not None else 1):
        t = (h - eo[2]) / dz
        e, n = eo[0] + t * d[:, 0], eo[1] + t * d[:, 1]
        h = surface.height(e, n)
    t = (h - eo[2]) / dz
    return np.column_stack([eo[0] + t * d[:, 0], eo[1] + t * d[:, 1], eo[2] + t * d[:, 2]])


def project_to_pixel(camera: Camera, eo: Any, xyz_m: Any) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (C, L) of object points in a photo and whether each lies in front of it.

    Returns
    -------
    colrow_px : ndarray (n, 2)
        NaN where the point is behind the camera or the distortion cannot be inverted.
    front : ndarray (n,) of bool
    """
    xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    xy, u3 = project(np.asarray(eo, dtype=np.float64).reshape(1, 6), xyz,
                     np.full(len(xyz), camera.focal_length_mm), np.zeros(len(xyz), dtype=np.int64))
    front = u3 < 0
    xy[~front] = np.nan
    px = camera.photo_to_pixel(xy, on_fail="nan") if len(xy) else np.empty((0, 2))
    return px, front & np.isfinite(px).all(axis=1)


def transfer(camera_a: Camera, eo_a: Any, colrow_a_px: Any, camera_b: Camera, eo_b: Any,
             surface: HeightSurface, *, dh_m: float = 0.0) -> np.ndarray:
    """Where pixels of photo A appear in photo B: ray of A -> surface (+ *dh_m*) -> B, shape (n, 2)."""
    xyz = ray_to_surface(camera_a, eo_a, colrow_a_px, surface)
    if dh_m:
        # move the point along A's ray by a height change dh (the ray, not the vertical)
        eo_a = np.asarray(eo_a, dtype=np.float64)
        ray = xyz - eo_a[:3]
        xyz = xyz + ray * (dh_m / np.where(np.abs(ray[:, 2:3]) < 1e-12, -1e-12, ray[:, 2:3]))
    return project_to_pixel(camera_b, eo_b, xyz)[0]
