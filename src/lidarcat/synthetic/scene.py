r"""A textured synthetic scene and aerial photos of it, rendered with known truth.

Monorestitution and orthophotos are tested against truth without real photos:
the scene is analytic, so every quantity a test compares with (the height of
any position, the texture seen from above, the plan outline of every roof) is
exact.

The scene
---------
* terrain ``h = T(E, N)`` -- by default the rolling terrain of
  :mod:`lidarcat.synthetic.survey` (smooth, slopes below 5 %);
* buildings -- the roofs of :mod:`lidarcat.synthetic.roofs` (``pyramid``, ``hip``,
  ``gable``, ``flat``) on a rectangular footprint, vertical walls from the
  terrain to the eaves, the footprint standing at the terrain height of its
  centre;
* texture -- a band-limited grey pattern on the ground (a sum of 24 plane
  waves of 1.5-12 m wavelength: phase correlation locks onto it), dark roads
  (straight strips), bright roof faces shaded by a light from the north-west
  (each face its own grey) with a faint tile pattern, grey walls.

Rendering (inverse mapping, exact first hit)
--------------------------------------------
For every pixel the ray ``X0 + t d`` (``d = M^T (x, y, -c)`` with the camera's
distortion removed, :func:`lidarcat.mapping.monoplot.ray_directions`) first meets the
terrain where the fixed-point iteration ``t_{k+1} = (T(E(t_k), N(t_k)) - Z0) / d_z``
converges (the terrain is smooth: 8 iterations reach far below a millimetre).
Then, building by building, the rays whose plan track crosses the footprint
rectangle above the terrain hit (slab test in the building frame) are marched
with a 5 cm plan step and the first sample below the roof is bisected: the
ray's first hit among terrain, walls and roofs, so that buildings hide what is
behind them.  The pixel takes the texture at that hit (one sample at the pixel
centre).  Cost: O(pixels) for the terrain plus O(rays near buildings x steps).

The LiDAR of the scene (:meth:`Scene.lidar_points`) samples the same surface:
uniform random plan positions, height noise, class 2 (ground) / 6 (building),
first of one return, and an intensity that shows the materials (dark roads,
mid-grey ground, bright roofs) -- the image an operator digitises on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from ..errors import LidarcatError
from .roofs import roof_height

__all__ = ["Building", "Road", "Scene", "demo_scene", "demo_terrain", "DEMO_ORIGIN_EN", "DEMO_GROUND_M", "LABELS"]

#: surface labels of the scene
LABELS = {"ground": 0, "road": 1, "roof": 2, "wall": 3}

_LIGHT = np.array([-0.5, 0.5, 1.0]) / math.sqrt(1.5)   # from the north-west, 55 deg high


@dataclass(frozen=True)
class Building:
    """A building of the scene (see :func:`lidarcat.synthetic.roofs.synthetic_roof` for the roof kinds).

    Attributes
    ----------
    kind : {"pyramid", "hip", "gable", "flat"}
    e_m, n_m : float
        Centre of the footprint, m.
    length_m, width_m : float
        Footprint along the building's u and v axes, m (pyramid: width x width).
    slope_deg : float
        Slope of the roof faces, deg.
    eave_m : float
        Eave height above the terrain at the centre, m.
    azimuth_deg : float
        Rotation of the u axis from East, counter-clockwise, deg.
    """

    kind: str
    e_m: float
    n_m: float
    length_m: float = 16.0
    width_m: float = 10.0
    slope_deg: float = 30.0
    eave_m: float = 6.0
    azimuth_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("pyramid", "hip", "gable", "flat"):
            raise LidarcatError(f"building kind must be pyramid, hip, gable or flat, got {self.kind!r}")
        if self.kind == "pyramid":
            object.__setattr__(self, "length_m", float(self.width_m))
        if self.kind == "hip" and self.length_m <= self.width_m:
            raise LidarcatError("a hip roof needs length_m > width_m")

    @property
    def _frame(self) -> tuple[float, float]:
        a = math.radians(self.azimuth_deg)
        return math.cos(a), math.sin(a)

    def to_local(self, e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plan position -> building frame (u along the length, v across), m."""
        ca, sa = self._frame
        de, dn = e - self.e_m, n - self.n_m
        return ca * de + sa * dn, -sa * de + ca * dn

    def to_world(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Building frame -> plan position, m."""
        ca, sa = self._frame
        return self.e_m + ca * u - sa * v, self.n_m + sa * u + ca * v

    @property
    def _t(self) -> float:
        return 0.0 if self.kind == "flat" else math.tan(math.radians(self.slope_deg))

    def roof(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Roof height above the footprint's base (m); NaN outside the footprint."""
        u, v = self.to_local(np.asarray(e, float), np.asarray(n, float))
        return roof_height(self.kind, u, v, self.length_m, self.width_m, self._t, self.eave_m)

    @property
    def top_m(self) -> float:
        """Highest roof point above the base, m."""
        return self.eave_m + self._t * self.width_m / 2

    def footprint(self) -> np.ndarray:
        """(4, 2) plan corners of the footprint (counter-clockwise), m."""
        L, W = self.length_m / 2, self.width_m / 2
        u = np.array([-L, L, L, -L])
        v = np.array([-W, -W, W, W])
        return np.column_stack(self.to_world(u, v))

    def vertices(self, base_h: float) -> np.ndarray:
        """(V, 3) roof vertices where three or more faces meet (apex, ridge ends), m."""
        h = base_h + self.top_m
        if self.kind == "pyramid":
            uv = [(0.0, 0.0)]
        elif self.kind == "hip":
            d = self.length_m / 2 - self.width_m / 2
            uv = [(-d, 0.0), (d, 0.0)]
        else:
            return np.zeros((0, 3))
        e, n = self.to_world(np.array([p[0] for p in uv]), np.array([p[1] for p in uv]))
        return np.column_stack([e, n, np.full(len(uv), h)])

    def eave_corners(self, base_h: float) -> np.ndarray:
        """(4, 3) corners of the roof outline at eave height, m."""
        fp = self.footprint()
        return np.column_stack([fp, np.full(4, base_h + self.eave_m)])


@dataclass(frozen=True)
class Road:
    """A straight road: centre line from (e0, n0) to (e1, n1), width in m."""

    e0_m: float
    n0_m: float
    e1_m: float
    n1_m: float
    width_m: float = 7.0

    def contains(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        a = np.array([self.e0_m, self.n0_m])
        ab = np.array([self.e1_m, self.n1_m]) - a
        L2 = float(ab @ ab)
        s = np.clip(((e - a[0]) * ab[0] + (n - a[1]) * ab[1]) / L2, 0, 1)
        return np.hypot(e - a[0] - s * ab[0], n - a[1] - s * ab[1]) <= self.width_m / 2


#: plan origin (E, N, m) of the demo's terrain (and of the synthetic survey's block)
DEMO_ORIGIN_EN = (680_000.0, 7_184_000.0)
#: mean height of the demo's terrain, m
DEMO_GROUND_M = 900.0


def demo_terrain(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Height of the rolling synthetic terrain of the demo (and of the synthetic survey), m."""
    de, dn = np.asarray(e) - DEMO_ORIGIN_EN[0], np.asarray(n) - DEMO_ORIGIN_EN[1]
    return (DEMO_GROUND_M + 6.0 * np.sin(2 * np.pi * de / 900.0) + 4.0 * np.cos(2 * np.pi * dn / 700.0)
            + 0.002 * de)


@dataclass(frozen=True, eq=False)
class Scene:
    """Terrain, buildings, roads and texture (see the module docstring).

    Attributes
    ----------
    buildings : tuple of Building
    roads : tuple of Road
    terrain : callable
        ``terrain(e, n) -> h`` (m), vectorised; default the demo's terrain.
    seed : int
        Seed of the ground texture's waves.
    """

    buildings: tuple[Building, ...] = ()
    roads: tuple[Road, ...] = ()
    terrain: Callable[[np.ndarray, np.ndarray], np.ndarray] = demo_terrain
    seed: int = 0
    _waves: np.ndarray = field(init=False, repr=False)
    _base: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        k = 24
        lam = np.exp(rng.uniform(math.log(1.5), math.log(12.0), k))
        ang = rng.uniform(0, 2 * np.pi, k)
        waves = np.column_stack([2 * np.pi / lam * np.cos(ang), 2 * np.pi / lam * np.sin(ang),
                                 rng.uniform(0, 2 * np.pi, k), rng.uniform(0.5, 1.0, k)])
        object.__setattr__(self, "buildings", tuple(self.buildings))
        object.__setattr__(self, "roads", tuple(self.roads))
        object.__setattr__(self, "_waves", waves)
        base = np.array([float(self.terrain(np.array([b.e_m]), np.array([b.n_m]))[0]) for b in self.buildings])
        object.__setattr__(self, "_base", base)

    # ------------------------------------------------------------------ geometry
    def base_height(self, i: int) -> float:
        """Terrain height at the centre of building *i* (its base), m."""
        return float(self._base[i])

    def surface(self, e: Any, n: Any) -> tuple[np.ndarray, np.ndarray]:
        """Visible surface from above: height (m) and label (:data:`LABELS`) at plan positions."""
        e = np.asarray(e, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        h = np.asarray(self.terrain(e, n), dtype=np.float64).copy()
        lab = np.zeros(e.shape, dtype=np.int8)
        for r in self.roads:
            lab[r.contains(e, n)] = LABELS["road"]
        for i, b in enumerate(self.buildings):
            z = b.roof(e, n) + self._base[i]
            on = np.isfinite(z) & (z > h)
            h = np.where(on, z, h)
            lab[on] = LABELS["roof"]
        return h, lab

    def dsm(self, e: Any, n: Any) -> np.ndarray:
        """Surface height (m): terrain or roof."""
        return self.surface(e, n)[0]

    def grid(self, bounds: Sequence[float], cell_m: float, what: str = "dsm") -> tuple[np.ndarray, Any]:
        """A north-up grid of the scene sampled at cell centres.

        Parameters
        ----------
        bounds : (xmin, ymin, xmax, ymax), m
        cell_m : float
        what : {"dsm", "dtm", "texture", "label"}

        Returns
        -------
        grid : (rows, cols) float32 array
        transform : lidarcat.lidar.GeoTransform
        """
        from ..lidar.raster import GeoTransform

        xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        cols = int(round((xmax - xmin) / cell_m))
        rows = int(round((ymax - ymin) / cell_m))
        t = GeoTransform(xmin, ymax, float(cell_m))
        e, n = t.xy(np.arange(rows)[:, None], np.arange(cols)[None, :])
        e, n = np.broadcast_arrays(e, n)
        if what == "dtm":
            g = self.terrain(e, n)
        elif what == "dsm":
            g = self.dsm(e, n)
        elif what == "texture":
            g = self.ortho_texture(e, n)
        elif what == "label":
            g = self.surface(e, n)[1]
        else:
            raise LidarcatError(f"what must be dsm, dtm, texture or label, got {what!r}")
        return np.asarray(g, dtype=np.float32), t

    # ------------------------------------------------------------------ texture
    def _ground_texture(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        w = self._waves
        acc = np.zeros(e.shape)
        for kx, ky, ph, amp in w:
            acc += amp * np.sin(kx * e + ky * n + ph)
        return 120.0 + 55.0 * acc / math.sqrt(0.5 * np.sum(w[:, 3] ** 2)) / 2.2

    def _shade(self, e: np.ndarray, n: np.ndarray, i: int) -> np.ndarray:
        b = self.buildings[i]
        s = 0.05
        gx = (b.roof(e + s, n) - b.roof(e - s, n)) / (2 * s)
        gy = (b.roof(e, n + s) - b.roof(e, n - s)) / (2 * s)
        gx = np.where(np.isfinite(gx), gx, 0.0)
        gy = np.where(np.isfinite(gy), gy, 0.0)
        nrm = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
        lam = nrm @ _LIGHT
        tiles = 6.0 * np.sin(2 * np.pi * (e + n) / 0.9)
        return 150.0 + 90.0 * lam + tiles

    def texture(self, e: np.ndarray, n: np.ndarray, label: np.ndarray,
                building: np.ndarray | None = None) -> np.ndarray:
        """Grey value (0-255) of surface points with their labels (and building index for roofs)."""
        out = self._ground_texture(e, n)
        road = label == LABELS["road"]
        out[road] = 55.0 + 0.15 * (out[road] - 120.0)
        out[label == LABELS["wall"]] = 95.0
        if building is not None:
            for i in range(len(self.buildings)):
                on = (label == LABELS["roof"]) & (building == i)
                if on.any():
                    out[on] = self._shade(e[on], n[on], i)
        return np.clip(out, 0, 255)

    def ortho_texture(self, e: Any, n: Any) -> np.ndarray:
        """The texture seen straight from above: the reference of a true orthophoto."""
        e = np.asarray(e, dtype=np.float64)
        n = np.asarray(n, dtype=np.float64)
        h, lab = self.surface(e, n)
        bidx = np.full(e.shape, -1)
        for i, b in enumerate(self.buildings):
            z = b.roof(e, n) + self._base[i]
            bidx[np.isfinite(z) & (lab == LABELS["roof"]) & np.isclose(z, h)] = i
        return self.texture(e, n, lab, bidx)

    # ------------------------------------------------------------------ LiDAR
    def lidar_points(self, bounds: Sequence[float], density_m2: float, *, noise_m: float = 0.05,
                     seed: int = 0) -> dict[str, np.ndarray]:
        """Airborne-LiDAR-like points of the visible surface.

        Returns
        -------
        dict
            ``xyz`` (N, 3) m; ``classification`` (2 ground, 6 building);
            ``intensity`` (uint16: roads dark, ground mid, roofs bright, with
            10 % noise); ``return_number`` and ``number_of_returns`` (1: one
            return per pulse on these opaque surfaces).
        """
        rng = np.random.default_rng(seed)
        xmin, ymin, xmax, ymax = bounds
        m = rng.poisson(density_m2 * (xmax - xmin) * (ymax - ymin))
        e = rng.uniform(xmin, xmax, m)
        n = rng.uniform(ymin, ymax, m)
        h, lab = self.surface(e, n)
        base = {LABELS["ground"]: 900.0, LABELS["road"]: 250.0, LABELS["roof"]: 2200.0}
        inten = np.vectorize(base.get)(lab) if m else np.zeros(0)
        inten = inten * (1 + 0.1 * rng.standard_normal(m)) + 100.0 * (lab == 0) * np.sin(0.7 * e)
        return {
            "xyz": np.column_stack([e, n, h + rng.normal(0, noise_m, m)]),
            "classification": np.where(lab == LABELS["roof"], 6, 2).astype(np.uint8),
            "intensity": np.clip(inten, 1, 65535).astype(np.uint16),
            "return_number": np.ones(m, dtype=np.uint8),
            "number_of_returns": np.ones(m, dtype=np.uint8),
        }

    # ------------------------------------------------------------------ rendering
    def render(self, camera: Camera, eo_params: Sequence[float], *, rows: slice | None = None) -> np.ndarray:
        """Render an aerial photo of the scene (see the module docstring).

        Parameters
        ----------
        camera : Camera
        eo_params : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad)
        rows : slice, optional
            Render only these image rows (memory: ~100 bytes per pixel of the band).

        Returns
        -------
        (rows, columns) uint8 array
        """
        from ..mapping.monoplot import ray_directions

        eo = np.asarray(eo_params, dtype=np.float64)
        rs = range(camera.rows_px)[rows] if rows is not None else range(camera.rows_px)
        band = 256
        out = np.empty((len(rs), camera.columns_px), dtype=np.uint8)
        for k in range(0, len(rs), band):
            rr = np.arange(rs[k], rs[min(k + band, len(rs)) - 1] + 1)
            cc, r2 = np.meshgrid(np.arange(camera.columns_px, dtype=float), rr.astype(float))
            d = ray_directions(camera, eo, np.column_stack([cc.ravel(), r2.ravel()]))
            out[k:k + len(rr)] = self._shade_rays(eo[:3], d).reshape(len(rr), -1)
        return out

    def _shade_rays(self, c: np.ndarray, d: np.ndarray) -> np.ndarray:
        t = self.hit(c, d)
        e = c[0] + t[:, 0] * d[:, 0]
        n = c[1] + t[:, 0] * d[:, 1]
        lab = np.where(t[:, 1] >= 0, LABELS["roof"], LABELS["ground"]).astype(np.int8)
        lab[t[:, 2] > 0] = LABELS["wall"]
        ground = lab == LABELS["ground"]
        for r in self.roads:
            lab[ground & r.contains(e, n)] = LABELS["road"]
        val = self.texture(e, n, lab, t[:, 1].astype(int))
        val[~np.isfinite(t[:, 0])] = 0
        return np.round(val).astype(np.uint8)

    def hit(self, c: np.ndarray, d: np.ndarray) -> np.ndarray:
        """First hit of rays ``c + t d``: (N, 3) array of t, building index (-1: terrain), wall flag."""
        n = len(d)
        dz = d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            h = np.full(n, float(np.mean(self.terrain(np.array([c[0]]), np.array([c[1]])))))
            for _ in range(12):
                t = (h - c[2]) / dz
                h = self.terrain(c[0] + t * d[:, 0], c[1] + t * d[:, 1])
            t = (h - c[2]) / dz
        t[dz >= 0] = np.nan
        bidx = np.full(n, -1.0)
        wall = np.zeros(n)
        for i, b in enumerate(self.buildings):
            base = self._base[i]
            top = base + b.top_m + 0.01
            ca, sa = b._frame
            u0 = ca * (c[0] - b.e_m) + sa * (c[1] - b.n_m)
            v0 = -sa * (c[0] - b.e_m) + ca * (c[1] - b.n_m)
            du = ca * d[:, 0] + sa * d[:, 1]
            dv = -sa * d[:, 0] + ca * d[:, 1]
            with np.errstate(divide="ignore", invalid="ignore"):
                t_top = (top - c[2]) / dz
                lo = np.maximum(t_top, 0.0)
                hi = t.copy()
                for p0, dp, half in ((u0, du, b.length_m / 2), (v0, dv, b.width_m / 2)):
                    ta = (-half - p0) / dp
                    tb = (half - p0) / dp
                    lo = np.maximum(lo, np.where(dp == 0, np.where(abs(p0) <= half, -np.inf, np.inf),
                                                 np.minimum(ta, tb)))
                    hi = np.minimum(hi, np.where(dp == 0, np.where(abs(p0) <= half, np.inf, -np.inf),
                                                 np.maximum(ta, tb)))
            cand = np.flatnonzero(np.isfinite(t) & (hi > lo))
            if cand.size == 0:
                continue
            plan = np.hypot(d[cand, 0], d[cand, 1])
            k = int(np.ceil(np.max((hi[cand] - lo[cand]) * plan) / 0.05)) + 2
            for part in np.array_split(cand, max(1, cand.size * k // 2_000_000 + 1)):
                s = np.linspace(1e-4, 1, k)   # start just inside the footprint (no NaN at its edge)
                tt = lo[part, None] + (hi[part] - lo[part])[:, None] * s
                pe = c[0] + tt * d[part, 0:1]
                pn = c[1] + tt * d[part, 1:2]
                z = b.roof(pe, pn) + base
                f = c[2] + tt * d[part, 2:3] - z
                below = f <= 0
                has = below.any(axis=1)
                if not has.any():
                    continue
                rid = part[has]
                j = np.argmax(below[has], axis=1)
                t_hi = tt[has, j]
                t_lo = tt[has, np.maximum(j - 1, 0)]
                is_wall = j == 0
                for _ in range(30):
                    mid = 0.5 * (t_lo + t_hi)
                    zm = b.roof(c[0] + mid * d[rid, 0], c[1] + mid * d[rid, 1]) + base
                    under = (c[2] + mid * d[rid, 2]) <= zm
                    t_hi = np.where(under & ~is_wall, mid, t_hi)
                    t_lo = np.where(under | is_wall, t_lo, mid)
                closer = t_hi < t[rid]
                t[rid[closer]] = t_hi[closer]
                bidx[rid[closer]] = i
                wall[rid[closer]] = is_wall[closer]
        return np.column_stack([t, bidx, wall])


def demo_scene(center_e: float = 680_400.0, center_n: float = 7_184_200.0, *, seed: int = 0) -> Scene:
    """A small town block: six buildings (pyramid, hip, gable, flat) along two crossing roads.

    >>> s = demo_scene()
    >>> len(s.buildings), len(s.roads)
    (6, 2)
    """
    e, n = center_e, center_n
    b = (
        Building("pyramid", e - 40, n + 25, width_m=12, slope_deg=30, eave_m=6, azimuth_deg=10),
        Building("hip", e + 30, n + 28, length_m=20, width_m=11, slope_deg=28, eave_m=7, azimuth_deg=-15),
        Building("gable", e - 35, n - 30, length_m=18, width_m=10, slope_deg=32, eave_m=5, azimuth_deg=35),
        Building("flat", e + 35, n - 25, length_m=22, width_m=14, eave_m=9, azimuth_deg=5),
        Building("hip", e + 75, n + 5, length_m=17, width_m=10, slope_deg=30, eave_m=6, azimuth_deg=80),
        Building("pyramid", e - 80, n - 22, width_m=11, slope_deg=33, eave_m=8, azimuth_deg=-25),
    )
    roads = (Road(e - 150, n + 2, e + 150, n - 1, 8.0), Road(e + 3, n - 120, e - 2, n + 120, 7.0))
    return Scene(b, roads, seed=seed)
