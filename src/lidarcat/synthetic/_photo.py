r"""Aerial photos of a synthetic scene by ray casting, with the true ground point of every pixel.

The scene (:class:`AerialScene`): a terrain ``h = T(E, N)`` (smooth, a callable), buildings
(:class:`lidarcat.synthetic.scene.Building`: a rectangular box with a pyramid, hip, gable or flat
roof -- a *convex* solid), and the albedo of :mod:`lidarcat.synthetic._texture` (fields, roads,
trees, roofs, shadows of a fixed sun), a deterministic function of plan position.

Rendering a pixel (inverse mapping, exact first hit)
----------------------------------------------------
The pixel (C, L) gives the corrected photo coordinates (eq. 01-07, closed form) and the ray
``X(t) = X0 + t d``, ``d = M^T (x, y, -c)``.

* **terrain**: the fixed point ``t_{k+1} = (T(E(t_k), N(t_k)) - Z0) / d_z`` converges with the
  rate ``|grad T| tan(off-nadir angle)`` (< 0.05 here): iterated until the hit moves less than
  0.1 mm;
* **buildings**: a convex solid is the intersection of half-spaces ``n_f . X <= c_f`` (4 walls, a
  floor 3 m under the base, 1, 2 or 4 roof planes).  Along the ray each plane gives
  ``t_f = (c_f - n_f . X0) / (n_f . d)``; the ray enters the solid at ``max t_f`` over the planes
  it enters (``n_f . d < 0``) and leaves at ``min t_f`` over the others; it hits when entry <=
  exit, at the face of the entry (Kay and Kajiya's slabs, generalised).  Only the pixels inside
  the projected bounding box of a building are tested;
* the first hit among the terrain and the buildings is the pixel's ground point ``X(t)``: the
  truth map.  It lies on the ray by construction, so it projects back onto the pixel centre
  exactly (up to the camera's Newton inverse, far below 0.01 px).

Shading: the ground takes the albedo lattice bilinearly at the hit's (E, N); a roof is shaded per
ray (:func:`lidarcat.synthetic._texture.roof_albedo`: its material, the tile courses and the
lattice's grain at the hit, times the sun shading of the face the ray hits), so a ridge, a hip or
an eave lies in the photo exactly where the geometry puts it, not up to a texel off as a roof
painted into the lattice would; walls a plaster colour shaded by their normal, with windows.
With ``supersample = s > 1`` a pixel whose hit surface (building and face, terrain, nothing)
differs from one of its 4 neighbours' averages the radiance of ``s x s`` rays on a regular grid
over the pixel (the sensor integrates over it): geometric edges are anti-aliased about their true
position, while pixels inside a surface keep their one ray (a texture's aliasing is the lattice's,
bounded by the texel ~ the GSD).  The photo's exposure then maps the linear radiance ``L`` to grey values:
``255 (o + (1 - o) min(1, g k L v(r))^(1/gamma))`` with gain ``g``, black level ``o``, gamma,
vignetting ``v(r) = 1 - a (r / r_corner)^2`` and optional Gaussian noise; ``k = 1.2`` puts a
mid-grey field near grey value 120 at ``g = 1``, ``gamma = 2.2``.

The image is rendered in tiles (``tile_px`` square): memory is bounded by the tile, not the photo.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from ..geometry.collinearity import project, rotation_matrix
from ..errors import LidarcatError
from ._texture import LUMA, albedo_lattice, bilinear, building_planes, roof_albedo, sun_vector
from .scene import Building, Road, demo_terrain

__all__ = ["AerialScene", "Exposure", "RenderedPhoto", "render_photo", "project_to_pixels", "building_windows",
           "SURFACE"]

#: surface codes of :attr:`RenderedPhoto.surface`
SURFACE = {"none": -1, "terrain": 0, "roof": 1, "wall": 2}
_K = 1.2


@dataclasses.dataclass(frozen=True, eq=False)
class AerialScene:
    """Terrain, buildings, roads, ground targets and the seeded albedo (see the module docstring).

    Attributes
    ----------
    terrain : callable
        ``terrain(e, n) -> h`` (m), vectorised, smooth (default the demo's rolling terrain).
    buildings : tuple of Building
    roads : tuple of Road
    targets : tuple of (E, N)
        Ground control targets painted on the ground (black square, white cross, 2 m).
    texel_m : float
        Spacing of the albedo lattice, m: about the ground sample distance of the photos.
    seed : int
        Seed of the albedo.
    field_m : float
        Mean size of the fields, m.
    trees : bool
        Paint trees (crowns and shadows).
    sun_azimuth_deg, sun_elevation_deg : float
        Direction of the sun (azimuth clockwise from north).
    """

    terrain: Callable[[np.ndarray, np.ndarray], np.ndarray] = demo_terrain
    buildings: tuple[Building, ...] = ()
    roads: tuple[Road, ...] = ()
    targets: tuple[tuple[float, float], ...] = ()
    texel_m: float = 0.1
    seed: int = 0
    field_m: float = 70.0
    trees: bool = True
    sun_azimuth_deg: float = 315.0
    sun_elevation_deg: float = 50.0
    _base: np.ndarray = dataclasses.field(init=False, repr=False)
    _solids: tuple = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not self.texel_m > 0:
            raise LidarcatError(f"texel_m must be positive, got {self.texel_m}")
        object.__setattr__(self, "buildings", tuple(self.buildings))
        object.__setattr__(self, "roads", tuple(self.roads))
        object.__setattr__(self, "targets", tuple((float(e), float(n)) for e, n in self.targets))
        base = np.array([float(np.asarray(self.terrain(np.array([b.e_m]), np.array([b.n_m]))).ravel()[0])
                         for b in self.buildings])
        object.__setattr__(self, "_base", base)
        solids = []
        for b, h in zip(self.buildings, base):
            n, c, kinds = building_planes(b, h)
            fp = b.footprint()
            box = np.array([[*fp.min(axis=0), h - 3.0], [*fp.max(axis=0), h + b.top_m + 0.01]])
            solids.append((np.array([b.e_m, b.n_m, h]), n, c, kinds, box))
        object.__setattr__(self, "_solids", tuple(solids))

    def base_height(self, i: int) -> float:
        """Terrain height at the centre of building *i* (its base), m."""
        return float(self._base[i])

    # ------------------------------------------------------------------ surface
    def surface(self, e: Any, n: Any) -> tuple[np.ndarray, np.ndarray]:
        """Visible surface from above at plan positions: height (m) and building index (-1 terrain)."""
        e = np.asarray(e, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        h = np.asarray(self.terrain(e, n), dtype=np.float64).copy()
        idx = np.full(e.shape, -1, dtype=np.int32)
        for k, b in enumerate(self.buildings):
            z = b.roof(e, n) + self._base[k]
            on = np.isfinite(z) & (z > h)
            h = np.where(on, z, h)
            idx[on] = k
        return h, idx

    def albedo(self, e: Any, n: Any, *, rgb: bool = True) -> np.ndarray:
        """Linear albedo (N, 3) RGB, or (N,) grey, seen from above at plan positions (roofs and ground).

        The same lattice, interpolated the same way, and the same roofs (:func:`roof_albedo` at the
        face below the point) as :func:`render_photo`: a pixel of ground or roof shows exactly this
        value at its ground point (before the exposure; pixels supersampled at a geometric edge
        average it over their sub-rays).
        """
        e = np.asarray(e, dtype=np.float64).ravel()
        n = np.asarray(n, dtype=np.float64).ravel()
        if e.size == 0:
            return np.zeros((0, 3) if rgb else (0,), np.float32)
        out = self._albedo_points(e, n, self.surface(e, n)[1], rgb)
        return out if rgb else out[:, 0]

    def _albedo_points(self, e: np.ndarray, n: np.ndarray, building: np.ndarray, rgb: bool) -> np.ndarray:
        """Albedo (N, 3 or 1) at plan positions (NaN: none, albedo 0); *building* >= 0: a roof point of it."""
        s = self.texel_m
        nch = 3 if rgb else 1
        ok = np.isfinite(e) & np.isfinite(n)
        if not ok.any():
            return np.zeros((len(e), nch), np.float32)
        ev, nv = e[ok], n[ok]
        i0 = int(math.floor(ev.min() / s)) - 1
        i1 = int(math.ceil(ev.max() / s)) + 2
        j0 = int(math.floor(-nv.max() / s)) - 1
        j1 = int(math.ceil(-nv.min() / s)) + 2
        if (i1 - i0) * (j1 - j0) > 60_000_000:
            raise LidarcatError(f"albedo: a plan box of {(i1 - i0) * s:.0f} x {(j1 - j0) * s:.0f} m at "
                                f"{s} m texels is too large for one lattice; render in smaller tiles")
        lat, grain = albedo_lattice(self, i0, j0, i1 - i0, j1 - j0, rgb=rgb, with_grain=True)
        col = np.where(ok, (e - i0 * s) / s, -10.0)
        row = np.where(ok, (-n - j0 * s) / s, -10.0)
        out = bilinear(lat, col, row).reshape(len(e), nch)
        roof = ok & (building >= 0)
        if roof.any():
            sun = sun_vector(self.sun_azimuth_deg, self.sun_elevation_deg)
            g = bilinear(grain, col[roof], row[roof])
            bk = building[roof]
            vals = np.empty((len(bk), nch), np.float32)
            for k in np.unique(bk):
                sel = bk == k
                vals[sel] = roof_albedo(self.buildings[int(k)], float(self._base[int(k)]), self.seed, int(k),
                                        s, e[roof][sel], n[roof][sel], g[sel], sun, nch)
            out[roof] = vals
        return out

    # ------------------------------------------------------------------ rays
    def hit(self, c: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of rays ``c + t d`` (d: (N, 3)).

        Returns
        -------
        t : (N,) ray parameter (NaN: no hit)
        building : (N,) int32 building index (-1 terrain)
        face : (N,) int16 face of the building's solid (:func:`building_planes` order), -1 terrain
        """
        c = np.asarray(c, dtype=np.float64)
        t = self._terrain_hit(c, d)
        bidx = np.full(len(d), -1, np.int32)
        face = np.full(len(d), -1, np.int16)
        for k in range(len(self.buildings)):
            self._building_hit(k, c, d, np.arange(len(d)), t, bidx, face)
        return t, bidx, face

    def _terrain_hit(self, c: np.ndarray, d: np.ndarray, t0: np.ndarray | None = None,
                     check_every: int = 1) -> np.ndarray:
        """Ray parameter of the terrain hit (fixed point, see the module docstring), from *t0* if given.

        Iterates until no ray's hit moves 0.1 mm.  With a start *t0* one iteration from convergence
        (the terrain is smooth, so is the remaining move over a tile), ``check_every = k`` measures
        the remaining move on every k-th ray only: one terrain evaluation per ray instead of two.
        """
        dz = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            if t0 is None:
                h0 = float(np.asarray(self.terrain(np.array([c[0]]), np.array([c[1]]))).ravel()[0])
                t = (h0 - c[2]) / dz
            else:
                t = np.asarray(t0, dtype=np.float64)
            # the hit moves |dt| |d| (d is not a unit vector)
            scale = float(np.nanmax(np.linalg.norm(d[:: max(1, len(d) // 1000)], axis=1))) * 1.01 if len(d) else 0.0
            step = max(1, int(check_every))
            for _ in range(40):
                t_new = (self.terrain(c[0] + t * d[:, 0], c[1] + t * d[:, 1]) - c[2]) / dz
                if step == 1:
                    moved = float(np.nanmax(np.abs(t_new - t))) * scale if len(t) else 0.0
                else:   # the remaining move of the new hits, on a sample
                    ts = t_new[::step]
                    again = (self.terrain(c[0] + ts * d[::step, 0], c[1] + ts * d[::step, 1]) - c[2]) / dz[::step]
                    moved = float(np.nanmax(np.abs(again - ts))) * scale if len(ts) else 0.0
                t = t_new
                if moved < 1e-4:
                    break
        t[~(dz < 0)] = np.nan
        return t

    def _building_hit(self, k: int, c: np.ndarray, d: np.ndarray, idx: np.ndarray, t: np.ndarray,
                      bidx: np.ndarray, face: np.ndarray) -> None:
        """Update t, bidx, face in place for the rays *idx* that hit building *k* first."""
        p0, normals, offsets, _, _ = self._solids[k]
        if idx.size == 0:
            return
        dd = d[idx]
        rel = c - p0
        denom = dd[:, 0:1] * normals[:, 0] + dd[:, 1:2] * normals[:, 1] + dd[:, 2:3] * normals[:, 2]   # (m, F)
        num = offsets - normals @ rel                # (F,)
        with np.errstate(divide="ignore", invalid="ignore"):
            tf = num[None, :] / denom
        entering = denom < 0
        leaving = denom > 0
        t_in = np.where(entering, tf, -np.inf)
        f_in = np.argmax(t_in, axis=1)
        t_enter = t_in[np.arange(len(idx)), f_in]
        t_exit = np.min(np.where(leaving, tf, np.inf), axis=1)
        parallel_out = ((denom == 0) & (num[None, :] < 0)).any(axis=1)
        cur = t[idx]
        hit = (t_enter <= t_exit) & (t_enter > 0) & ~parallel_out & ~(t_enter >= cur)
        sel = idx[hit]
        t[sel] = t_enter[hit]
        bidx[sel] = k
        face[sel] = f_in[hit].astype(np.int16)

    def _face_kind(self, bidx: np.ndarray, face: np.ndarray) -> np.ndarray:
        """Kind of each hit face (0 roof, 1 wall, 2 floor; -1 terrain)."""
        out = np.full(len(bidx), -1, np.int8)
        for k in np.unique(bidx[bidx >= 0]):
            sel = bidx == k
            out[sel] = self._solids[int(k)][3][face[sel]]
        return out

    def wall_albedo(self, k: int, face: np.ndarray, xyz: np.ndarray) -> np.ndarray:
        """Linear RGB (N, 3) of wall points of building *k* (plaster shaded by the wall normal, windows)."""
        b = self.buildings[k]
        p0, normals, _, _, _ = self._solids[k]
        sun = sun_vector(self.sun_azimuth_deg, self.sun_elevation_deg)
        nn = normals[face] / np.linalg.norm(normals[face], axis=1, keepdims=True)
        light = 0.4 + 0.6 * np.clip(nn @ sun, 0, None) / sun[2]
        u, v = b.to_local(xyz[:, 0], xyz[:, 1])
        along = np.where(np.abs(normals[face, 0] * math.cos(math.radians(b.azimuth_deg))
                                + normals[face, 1] * math.sin(math.radians(b.azimuth_deg))) > 0.5, v, u)
        z = xyz[:, 2] - p0[2]
        window = (np.mod(along, 3.0) > 1.0) & (np.mod(along, 3.0) < 2.0) & (np.mod(z, 3.0) > 1.0) & \
                 (np.mod(z, 3.0) < 2.2) & (z < b.eave_m - 0.5) & (z > 0.5)
        tone = np.where(window, 0.05, 0.35 + 0.1 * ((k * 7919) % 5) / 5)
        return (np.array([1.0, 0.95, 0.85])[None, :] * (tone * light)[:, None]).astype(np.float32)


@dataclasses.dataclass(frozen=True)
class Exposure:
    """The radiometry of one photo (see the module docstring).

    Attributes
    ----------
    gain : float
        Exposure gain ``g`` (1: a mid-grey field near grey value 120).
    gamma : float
        Encoding gamma (output ``~ L^(1/gamma)``).
    offset : float
        Black level, fraction of 255.
    vignetting : float
        Fall-off ``a`` at the frame corner (0: none).
    noise_sd : float
        Gaussian noise, grey values (0: none).
    seed : int
        Seed of the noise.
    """

    gain: float = 1.0
    gamma: float = 2.2
    offset: float = 0.0
    vignetting: float = 0.0
    noise_sd: float = 0.0
    seed: int = 0

    @classmethod
    def random(cls, seed: int, *, vignetting: float = 0.15, noise_sd: float = 1.0) -> "Exposure":
        """A plausible exposure drawn from ``default_rng(seed)``: gain 0.7-1.4, gamma 1.8-2.6, black level 0-4 %."""
        rng = np.random.default_rng(seed)
        return cls(float(rng.uniform(0.7, 1.4)), float(rng.uniform(1.8, 2.6)), float(rng.uniform(0.0, 0.04)),
                   vignetting, noise_sd, int(rng.integers(2**31)))

    def lut(self, size: int = 65536) -> np.ndarray:
        """Grey value (float32) of ``g k L`` at ``size`` steps over [0, 1]: :meth:`apply` as a table,
        read at the nearest step (1/65535: within 0.15 grey value of the curve above ``g k L = 1e-4``)."""
        x = np.linspace(0.0, 1.0, size, dtype=np.float64)
        return (255.0 * (self.offset + (1.0 - self.offset) * x ** (1.0 / self.gamma))).astype(np.float32)

    def apply(self, radiance: np.ndarray, vignette: np.ndarray | float = 1.0) -> np.ndarray:
        """Linear radiance -> grey values (float32, 0..255, before noise and rounding)."""
        x = np.clip(radiance * np.float32(self.gain * _K) * vignette, 0.0, 1.0)
        return np.float32(255.0) * (np.float32(self.offset)
                                    + np.float32(1.0 - self.offset) * x ** np.float32(1.0 / self.gamma))


@dataclasses.dataclass(frozen=True, eq=False)
class RenderedPhoto:
    """A rendered photo and its truth.

    Attributes
    ----------
    image : (H, W) or (H, W, 3) uint8
        Grey or RGB (RGB channel order; ``cv2.imwrite`` wants BGR).
    xyz : (H, W, 3) float64 or None
        True E, N, h (m, the scene's CRS) of the surface point seen at each pixel centre; NaN where
        the ray meets nothing.
    surface : (H, W) int8 or None
        :data:`SURFACE` code of that point.
    building : (H, W) int32 or None
        Building index of roof and wall pixels, -1 elsewhere.
    """

    image: np.ndarray
    xyz: np.ndarray | None
    surface: np.ndarray | None
    building: np.ndarray | None


def project_to_pixels(camera: Camera, eo: Sequence[float], xyz_m: np.ndarray) -> np.ndarray:
    """Ground points -> pixel (column, row) by the collinearity equations and the camera's distortion.

    Parameters
    ----------
    camera : Camera
    eo : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad)
    xyz_m : (N, 3) E, N, h, m

    Returns
    -------
    (N, 2) float64, px; NaN behind the camera or where the distortion model cannot be inverted
    (far outside the frame).
    """
    p = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    out = np.full((len(p), 2), np.nan)
    if len(p) == 0:
        return out
    eo_rows = np.broadcast_to(np.asarray(eo, dtype=np.float64), (len(p), 6))
    with np.errstate(divide="ignore", invalid="ignore"):
        xy, u3 = project(eo_rows, p, np.full(len(p), float(camera.focal_length_mm)))
    w, h = camera.frame_size_mm
    ok = (u3 < 0) & np.isfinite(xy).all(axis=1) & (np.abs(xy[:, 0]) < w) & (np.abs(xy[:, 1]) < h)
    if ok.any():
        out[ok] = camera.photo_to_pixel(xy[ok], on_fail="nan")
    return out


def building_windows(scene: AerialScene, camera: Camera, eo: np.ndarray) -> list[tuple[int, float, float, float, float]]:
    """(building, col0, col1, row0, row1) pixel boxes of the buildings' bounding boxes on the frame.

    The box corners are projected by the ideal pinhole (closed form) and the box widened by the
    largest distortion on the frame (+ 3 px); buildings off the frame are dropped.
    """
    W, H = camera.columns_px, camera.rows_px
    edge = np.array([[c, r] for c in np.linspace(0, W - 1, 9) for r in np.linspace(0, H - 1, 7)])
    fot = camera.pixel_to_fot(edge)
    dist_px = float(np.max(np.abs(fot - camera.pixel_to_photo(edge)) / camera.pixel_size_x_mm)) + 3.0
    out = []
    for k, (_, _, _, _, box) in enumerate(scene._solids):
        corners = np.array([[x, y, z] for x in box[:, 0] for y in box[:, 1] for z in box[:, 2]])
        with np.errstate(divide="ignore", invalid="ignore"):
            xy, u3 = project(np.broadcast_to(eo, (8, 6)), corners, np.full(8, camera.focal_length_mm))
        if not (u3 < 0).all():
            out.append((k, -1, W + 1, -1, H + 1))   # a corner behind the camera: test every pixel
            continue
        col = (xy[:, 0] + camera.principal_point_x_mm) / camera.pixel_size_x_mm + (W - 1) / 2
        row = -(xy[:, 1] + camera.principal_point_y_mm) / camera.pixel_size_y_mm + (H - 1) / 2
        c0, c1 = col.min() - dist_px, col.max() + dist_px
        r0, r1 = row.min() - dist_px, row.max() + dist_px
        if c1 < -1 or r1 < -1 or c0 > W or r0 > H:
            continue
        out.append((k, max(-1.0, c0), min(W + 1.0, c1), max(-1.0, r0), min(H + 1.0, r1)))
    return out


def _directions(camera: Camera, m: np.ndarray, colrow: np.ndarray) -> np.ndarray:
    """Ray directions ``d = M^T (x, y, -c)`` (N, 3) of pixels (elementwise: no BLAS thread pool)."""
    xy = camera.pixel_to_photo(colrow)
    x, y, c = xy[:, 0], xy[:, 1], camera.focal_length_mm
    return np.column_stack([x * m[0, 0] + y * m[1, 0] - c * m[2, 0],
                            x * m[0, 1] + y * m[1, 1] - c * m[2, 1],
                            x * m[0, 2] + y * m[1, 2] - c * m[2, 2]])


def _initial_t(scene: AerialScene, camera: Camera, m: np.ndarray, c: np.ndarray,
               c0: int, c1: int, r0: int, r1: int, step: int = 16) -> np.ndarray:
    """Terrain ray parameters of a tile from a coarse grid of pixels, interpolated: a start one
    iteration from convergence (the terrain is smooth), so that the fine rays need two evaluations."""
    import cv2

    gc = np.unique(np.append(np.arange(c0, c1, step), c1 - 1)).astype(np.float64)
    gr = np.unique(np.append(np.arange(r0, r1, step), r1 - 1)).astype(np.float64)
    cc, rr = np.meshgrid(gc, gr)
    d = _directions(camera, m, np.column_stack([cc.ravel(), rr.ravel()]))
    tc = scene._terrain_hit(c, d).reshape(len(gr), len(gc))
    if not np.isfinite(tc).all():
        return np.full((r1 - r0) * (c1 - c0), np.nanmean(tc) if np.isfinite(tc).any() else np.nan)
    # bilinear in pixel position: the coarse nodes sit at gc, gr
    fc = np.interp(np.arange(c0, c1), gc, np.arange(len(gc)))
    fr = np.interp(np.arange(r0, r1), gr, np.arange(len(gr)))
    fcm, frm = np.meshgrid(fc.astype(np.float32), fr.astype(np.float32))
    return cv2.remap(tc, fcm, frm, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64).ravel()


def _tile_directions(camera: Camera, m: np.ndarray, c0: int, c1: int, r0: int, r1: int) -> np.ndarray:
    """Ray directions ``d = M^T (x, y, -c)`` (N, 3) float32, row-major, of the pixels of a tile.

    The corrected photo coordinates of eq. 01-07 (:meth:`Camera.pixel_to_photo`) evaluated on the
    grid: ``x_fot`` depends on the column only and ``y_fot`` on the row only, so the affine part is
    computed once per column and row (float64) and only the distortion terms per pixel, in float32
    (1e-6 mm on an 18 mm half frame: 1e-4 px; the truth-map test projects every pixel's hit back
    through :meth:`Camera.photo_to_pixel` within 0.01 px).  A direction good to 1e-7 rad puts a hit 0.1 mm off its ray at
    1 km: the truth still projects back onto the pixel within 1e-3 px.
    """
    cam = camera
    f32 = np.float32
    x = ((((np.arange(c0, c1, dtype=np.float64) - (cam.columns_px - 1) / 2.0) * cam.pixel_size_x_mm)
          - cam.principal_point_x_mm)[None, :]).astype(f32)
    y = ((((-(np.arange(r0, r1, dtype=np.float64) - (cam.rows_px - 1) / 2.0) * cam.pixel_size_y_mm))
          - cam.principal_point_y_mm)[:, None]).astype(f32)
    x2, y2 = x * x, y * y
    r2 = x2 + y2
    radial = r2 * (f32(cam.k1) + r2 * (f32(cam.k2) + r2 * f32(cam.k3)))
    if cam.refraction_eps45:
        radial = radial + (f32(1.0) + r2 / f32(cam.focal_length_mm ** 2)) * f32(cam.refraction_eps45)
    xy = x * y
    xc = x - (x * radial + f32(cam.p1) * (r2 + 2 * x2) + f32(2 * cam.p2) * xy)
    yc = y - (y * radial + f32(cam.p2) * (r2 + 2 * y2) + f32(2 * cam.p1) * xy)
    del x2, y2, r2, radial, xy
    fc = cam.focal_length_mm
    d = np.empty((xc.size, 3), f32)
    for k in range(3):
        d[:, k] = (xc * f32(m[0, k]) + (yc * f32(m[1, k]) - f32(fc * m[2, k]))).ravel()
    return d


def _cast_tile(scene: AerialScene, camera: Camera, m: np.ndarray, c: np.ndarray, windows: list,
               c0: int, c1: int, r0: int, r1: int):
    """Rays of the pixels of a tile and their first hits: d (N, 3), t, building, face (row-major)."""
    d = _tile_directions(camera, m, c0, c1, r0, r1)
    t = scene._terrain_hit(c, d, _initial_t(scene, camera, m, c, c0, c1, r0, r1), check_every=7)
    bidx = np.full(len(d), -1, np.int32)
    face = np.full(len(d), -1, np.int16)
    tw = c1 - c0
    for k, x0, x1, y0, y1 in windows:
        a0, a1 = max(c0, math.floor(x0)), min(c1, math.ceil(x1) + 1)
        b0, b1 = max(r0, math.floor(y0)), min(r1, math.ceil(y1) + 1)
        if a0 >= a1 or b0 >= b1:
            continue
        idx = ((np.arange(b0, b1) - r0)[:, None] * tw + (np.arange(a0, a1) - c0)[None, :]).ravel()
        scene._building_hit(k, c, d, idx, t, bidx, face)
    return d, t, bidx, face


def _shade_rays(scene: AerialScene, c: np.ndarray, d: np.ndarray, t: np.ndarray, bidx: np.ndarray,
                face: np.ndarray, rgb: bool) -> np.ndarray:
    """Linear radiance (N, 3 or 1) of rays with their hits: ground and roofs by
    :meth:`AerialScene._albedo_points` (a roof by the face under its hit, i.e. the face hit), walls
    by :meth:`AerialScene.wall_albedo`."""
    kind = np.full(len(bidx), -1, np.int8)
    onb = bidx >= 0
    if onb.any():
        kind[onb] = scene._face_kind(bidx[onb], face[onb])
    e = c[0] + t * d[:, 0]
    n = c[1] + t * d[:, 1]
    lin = scene._albedo_points(e, n, np.where(kind == 0, bidx, -1), rgb)
    wall = kind == 1
    if wall.any():
        p = c + t[wall, None] * d[wall]
        for k in np.unique(bidx[wall]):
            sel = bidx[wall] == k
            a = scene.wall_albedo(int(k), face[wall][sel], p[sel])
            lin[np.flatnonzero(wall)[sel]] = a if rgb else (a @ LUMA)[:, None]
    return lin


def _edge_pixels(t: np.ndarray, bidx: np.ndarray, face: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Interior pixels (flat indices into the tile without its 1 px margin) whose hit surface --
    building and face, terrain, or none -- differs from a 4-neighbour's: the geometric edges."""
    th, tw = shape
    key = np.where(np.isfinite(t), bidx.astype(np.int64) * 64 + face, -(1 << 40)).reshape(th + 2, tw + 2)
    mid = key[1:-1, 1:-1]
    edge = (mid != key[:-2, 1:-1]) | (mid != key[2:, 1:-1]) | (mid != key[1:-1, :-2]) | (mid != key[1:-1, 2:])
    return np.flatnonzero(edge.ravel())


def _supersample(scene: AerialScene, camera: Camera, m: np.ndarray, c: np.ndarray, windows: list,
                 cols: np.ndarray, rows: np.ndarray, t0: np.ndarray, s: int):
    """Sub-rays of pixels (cols, rows): ``s x s`` per pixel on a regular grid over the pixel,
    their first hits: d (N s^2, 3), t, building, face, pixel-major."""
    o = (np.arange(s) + 0.5) / s - 0.5
    oc, orow = np.meshgrid(o, o)
    colrow = np.column_stack([(cols[:, None] + oc.ravel()[None, :]).ravel(),
                              (rows[:, None] + orow.ravel()[None, :]).ravel()])
    d = _directions(camera, m, colrow)
    start = np.repeat(np.where(np.isfinite(t0), t0, np.nanmean(t0) if np.isfinite(t0).any() else 0.0), s * s)
    t = scene._terrain_hit(c, d, start)
    bidx = np.full(len(d), -1, np.int32)
    face = np.full(len(d), -1, np.int16)
    for k, x0, x1, y0, y1 in windows:
        idx = np.flatnonzero((colrow[:, 0] >= x0 - 1) & (colrow[:, 0] <= x1 + 1)
                             & (colrow[:, 1] >= y0 - 1) & (colrow[:, 1] <= y1 + 1))
        scene._building_hit(k, c, d, idx, t, bidx, face)
    return d, t, bidx, face


def render_photo(scene: AerialScene, camera: Camera, eo: Sequence[float], *,
                 exposure: Exposure | None = None, rgb: bool = False, truth: bool = True,
                 tile_px: int = 512, shade: bool = True, supersample: int = 1) -> RenderedPhoto:
    """Render an aerial photo of *scene* (see the module docstring).

    Parameters
    ----------
    scene : AerialScene
    camera : Camera
    eo : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad); M = R3(kappa) R2(phi) R1(omega)
    exposure : Exposure, optional
        Default ``Exposure()`` (gain 1, gamma 2.2, no vignetting, no noise).
    rgb : bool
        RGB (H, W, 3) instead of grey (H, W).
    truth : bool
        Also return the truth maps (``xyz``: 24 bytes per pixel).
    tile_px : int
        Tile size; memory ~ 300 bytes x tile_px^2.
    shade : bool
        False: the geometry only (the image stays black; for the truth maps).
    supersample : int
        ``s > 1``: a pixel whose hit surface (building and face, terrain) differs from a
        neighbour's -- an eave, a ridge, a hip, a wall's edge -- averages the radiance of ``s x s``
        rays spread over it (the sensor integrates over the pixel), so that geometric edges are
        anti-aliased where they lie; other pixels keep their one ray (the truth maps always hold
        the pixel centre's ray).  1: one ray per pixel.

    Returns
    -------
    RenderedPhoto
    """
    exposure = exposure or Exposure()
    eo = np.asarray(eo, dtype=np.float64)
    W, H = camera.columns_px, camera.rows_px
    nch = 3 if rgb else 1
    img = np.zeros((H, W, 3) if rgb else (H, W), np.uint8)
    xyz = np.full((H, W, 3), np.nan) if truth else None
    surf = np.full((H, W), -1, np.int8) if truth else None
    bmap = np.full((H, W), -1, np.int32) if truth else None
    m = rotation_matrix(eo[3:6])
    c = eo[:3]
    windows = building_windows(scene, camera, eo)
    rng = np.random.default_rng(exposure.seed) if exposure.noise_sd > 0 else None
    lut = exposure.lut()
    rc2 = ((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2
    ss = int(supersample)
    if ss < 1:
        raise LidarcatError(f"supersample must be 1 or more, got {supersample}")
    for r0 in range(0, H, tile_px):
        r1 = min(H, r0 + tile_px)
        for c0 in range(0, W, tile_px):
            c1 = min(W, c0 + tile_px)
            th, tw = r1 - r0, c1 - c0
            mg = 1 if ss > 1 and shade else 0
            d, t, bidx, face = _cast_tile(scene, camera, m, c, windows, c0 - mg, c1 + mg, r0 - mg, r1 + mg)
            if mg:
                edges = _edge_pixels(t, bidx, face, (th, tw))
                keep = ((np.arange(th) + 1)[:, None] * (tw + 2) + (np.arange(tw) + 1)[None, :]).ravel()
                d, t, bidx, face = d[keep], t[keep], bidx[keep], face[keep]
            wall = bidx >= 0
            if wall.any():
                wall[wall] = scene._face_kind(bidx[wall], face[wall]) == 1
            if truth:
                xyz[r0:r1, c0:c1] = (c + t[:, None] * d).reshape(th, tw, 3)
                code = np.where(np.isfinite(t), np.where(bidx < 0, SURFACE["terrain"],
                                                         np.where(wall, SURFACE["wall"], SURFACE["roof"])),
                                SURFACE["none"])
                surf[r0:r1, c0:c1] = code.reshape(th, tw)
                bmap[r0:r1, c0:c1] = bidx.reshape(th, tw)
            if not shade:
                continue
            if mg and len(edges):
                sd, st, sb, sf = _supersample(scene, camera, m, c, windows, (c0 + edges % tw).astype(np.float64),
                                              (r0 + edges // tw).astype(np.float64), t[edges], ss)
                lin_all = _shade_rays(scene, c, np.vstack([d.astype(np.float64), sd]), np.concatenate([t, st]),
                                      np.concatenate([bidx, sb]), np.concatenate([face, sf]), rgb)
                lin = lin_all[:len(t)]
                lin[edges] = lin_all[len(t):].reshape(len(edges), ss * ss, nch).mean(axis=1)
            else:
                lin = _shade_rays(scene, c, d, t, bidx, face, rgb)
            if exposure.vignetting:
                r2 = (((np.arange(c0, c1, dtype=np.float32) - (W - 1) / 2) ** 2)[None, :]
                      + ((np.arange(r0, r1, dtype=np.float32) - (H - 1) / 2) ** 2)[:, None]) / np.float32(rc2)
                lin = lin * (1.0 - np.float32(exposure.vignetting) * r2).reshape(-1, 1)
            val = lut[np.clip(lin * np.float32(exposure.gain * _K * (len(lut) - 1)) + np.float32(0.5), 0,
                              len(lut) - 1).astype(np.int32)]
            if rng is not None:
                val = val + rng.standard_normal(val.shape, dtype=np.float32) * np.float32(exposure.noise_sd)
            val[~np.isfinite(t)] = 0
            out = np.clip(np.rint(val), 0, 255).astype(np.uint8)
            img[r0:r1, c0:c1] = out.reshape(th, tw, 3) if rgb else out.reshape(th, tw)
    return RenderedPhoto(img, xyz, surf, bmap)
