r"""Aerial photos rendered over a real LiDAR surface, with the exact projection of its roof vertices as truth.

Used to score the image measurement of LiDAR roof vertices (:mod:`lidarcat.photocontrol`) on real
roofs: the AHN3 tiles of ``tests/data/lidar`` (issue 29, step 5).  Arrays in (points, intensities,
fitted planes, poses), image arrays and truth out; no files.

What "truth" means here (the design)
------------------------------------
A TIN of first returns has jagged roof edges: with the AHN3 spacing of 0.25-0.3 m a ridge or hip
of the TIN zig-zags by 2-6 px at 5 cm GSD, so on it "the true image position of the vertex" is not
defined to a tenth of a pixel.  The scene is therefore a *composite*:

* **roof patches** (:class:`RoofPatch`): around each vertex the photo measurement is scored at,
  its fitted planes (the planes the extractor fits, shifted by their misclosure to pass exactly
  through the vertex :math:`V`, mm for four planes, 0 for three) are rendered as exact planes.  In
  plan, about :math:`V`, the faces are sorted by the mean direction of their LiDAR points; between
  consecutive faces *a*, *b* the boundary is the plan direction of their intersection line
  :math:`n_a \times n_b` (the sign that lies between the two faces), so the height is continuous
  across it and the ridge/hip lies exactly on the planes' intersection.  A face reaches as far as
  its own points, dilated by ``reach_m`` (0.4 m, more than the point spacing: the gap at the ridge
  and at the vertex is closed; an eave moves out by up to that much, a chimney or dormer on the
  face is flattened).  The vertex is thus an exact corner of the scene and its projection with
  the true orientation is the truth (up to the ray casting's 1e-6 m);
* **everything else** (ground, walls, trees, the roofs away from the vertices): the TIN of the
  first returns (Delaunay, linear), sampled on a raster of ``cell_m`` (0.1 m) and read
  bilinearly; cells outside the points' hull take the nearest cell's value.

Rendering a pixel (first hit on a height field)
-----------------------------------------------
The ray :math:`X(t) = X_0 + t\,d`, :math:`d = M^T (x, y, -c)` (the corrected photo coordinates
of the camera, :meth:`lidarcat.geometry.camera.Camera.pixel_to_photo`), is parameterised by its
height :math:`z` and marched down from the scene's top in steps of ``step_m`` (0.2 m) in plan
(:math:`\Delta z = \text{step}\,|d_z| / |d_{EN}|`) until :math:`g(z) = z - H(E(z), N(z)) \le 0`;
while the ray is above the maximum of the surface over the 3 x 3 blocks of 0.8 m about it, it
steps a block at a time (it cannot meet the surface there).  The bracket is then solved by
regula falsi (Illinois) to 1e-7 m: exact on a plane in one step.  :math:`g` is
continuous across a ridge (the planes meet there), so the hit on a roof patch lies on the exact
planes; at a wall (a step of :math:`H`) bisection converges to the step.  Features thinner than
``step_m`` in plan may be stepped over.

Shading: the linear radiance is ``albedo x (a + (1 - a) max(0, n . s) / s_z)`` (ambient
``a = 0.35``, sun unit vector ``s`` from :func:`lidarcat.synthetic._texture.sun_vector`), with
the albedo from the LiDAR intensity (interpolated on the TIN, scaled between its 2nd and 98th
percentiles to 0.06-0.4) and the normal of the exact plane on a patch, of the raster's gradient
elsewhere.  No cast shadows.  Anti-aliasing as in :mod:`lidarcat.synthetic._photo`: a pixel
whose hit surface (patch face or TIN) differs from a 4-neighbour's, or whose hit height differs
by more than 0.3 m, averages ``s x s`` sub-rays over the pixel; then the photo's
:class:`~lidarcat.synthetic._photo.Exposure` maps radiance to grey values (gain, gamma, black
level, vignetting, noise).

Consequences: roof edges *at the scored vertices* are exact and anti-aliased; other roof edges,
eaves and walls are the TIN's (jagged, as in a true orthophoto from LiDAR); texture is the
intensity's (smooth at the point spacing, no tile courses); no cast shadows, so a face in the
shadow of a taller roof is lit.  The occlusion truth (:func:`vertex_visible`) is the ray from the
camera to the vertex on this same surface (trees and taller roofs included).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import LidarcatError
from ..geometry.camera import Camera
from ..geometry.collinearity import rotation_matrix
from ..production.terrain import tin_grid
from ._photo import Exposure, RenderedPhoto
from ._texture import sun_vector

__all__ = ["RoofPatch", "LidarSurface", "roof_patch", "lidar_surface", "cast_rays", "render_lidar_photo",
           "vertex_visible", "flight_poses", "AMBIENT"]

#: ambient share of the shading
AMBIENT = 0.35
_FACES = 8          # labels: patch * _FACES + face


@dataclasses.dataclass(frozen=True, eq=False)
class RoofPatch:
    """The exact planes of one roof vertex, each clipped to its sector about the vertex and its points.

    Attributes
    ----------
    vertex_m : (3,) E, N, h (m): every plane passes through it.
    normals : (k, 3) unit normals (up).
    bounds_rad : (k,) plan angle (from E, counter-clockwise) where face ``faces[i]`` begins; it
        ends at the next bound.
    faces : (k,) int, face of each sector.
    origin_m : (2,) E, N of the lower-left corner of the reach masks.
    cell_m : float
    reach : (k, ny, nx) bool, where each face reaches (its points dilated).
    """

    vertex_m: np.ndarray
    normals: np.ndarray
    bounds_rad: np.ndarray
    faces: np.ndarray
    origin_m: np.ndarray
    cell_m: float
    reach: np.ndarray

    @property
    def top_m(self) -> float:
        """The highest point of the patch (m)."""
        f, j, i = np.nonzero(self.reach)
        e = self.origin_m[0] + (i + 0.5) * self.cell_m
        n = self.origin_m[1] + (j + 0.5) * self.cell_m
        nrm = self.normals[f]
        h = self.vertex_m[2] - (nrm[:, 0] * (e - self.vertex_m[0]) + nrm[:, 1] * (n - self.vertex_m[1])) / nrm[:, 2]
        return float(h.max() + self.cell_m * np.max(np.hypot(nrm[:, 0], nrm[:, 1]) / nrm[:, 2]))

    def height(self, e: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Height (m; NaN off the patch) and face (-1 off the patch) at plan positions (N,)."""
        v = self.vertex_m
        de, dn = e - v[0], n - v[1]
        ang = np.mod(np.arctan2(dn, de) - self.bounds_rad[0], 2 * math.pi)
        rel = np.mod(self.bounds_rad - self.bounds_rad[0], 2 * math.pi)
        sector = np.searchsorted(rel, ang, side="right") - 1
        face = self.faces[np.clip(sector, 0, len(self.faces) - 1)]
        i = np.floor((e - self.origin_m[0]) / self.cell_m).astype(np.int64)
        j = np.floor((n - self.origin_m[1]) / self.cell_m).astype(np.int64)
        ny, nx = self.reach.shape[1:]
        inside = (i >= 0) & (j >= 0) & (i < nx) & (j < ny)
        on = np.zeros(len(e), bool)
        on[inside] = self.reach[face[inside], j[inside], i[inside]]
        nrm = self.normals[face]
        h = v[2] - (nrm[:, 0] * de + nrm[:, 1] * dn) / nrm[:, 2]
        return np.where(on, h, np.nan), np.where(on, face, -1)


def roof_patch(vertex_m: Any, normals: Any, face_xyz: Sequence[Any], *, reach_m: float = 0.4,
               cell_m: float = 0.05) -> RoofPatch:
    """The exact roof patch of a vertex (see the module docstring).

    Parameters
    ----------
    vertex_m : (3,) the vertex E, N, h (m)
    normals : (k, 3) the fitted planes' normals (k >= 3; oriented up or not)
    face_xyz : k arrays (Ni, 3) of each face's LiDAR points (m)
    reach_m : float
        A face reaches this far beyond its points (m).
    cell_m : float
        Cell of the reach masks (m).

    Examples
    --------
    >>> n = np.array([[0.6, 0, 0.8], [-0.6, 0, 0.8], [0, 0.6, 0.8]])   # a ridge along N ending in a hip
    >>> v = np.zeros(3)
    >>> g = np.mgrid[-3:3:0.3, -3:3:0.3].reshape(2, -1).T
    >>> side = [g[(g[:, 0] < 0) & (g[:, 1] < -g[:, 0])], g[(g[:, 0] > 0) & (g[:, 1] < g[:, 0])],
    ...         g[(g[:, 1] > np.abs(g[:, 0]))]]
    >>> p = roof_patch(v, [n[1], n[0], n[2]], [np.column_stack([s, np.zeros(len(s))]) for s in side])
    >>> h, f = p.height(np.array([-1.0, 1.0, 0.0]), np.array([-2.0, -2.0, 1.0]))
    >>> np.round(h, 6).tolist(), f.tolist()     # on the W face, the E face, the hip face
    ([-0.75, -0.75, -0.75], [0, 1, 2])
    """
    v = np.asarray(vertex_m, dtype=np.float64).reshape(3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    nrm = np.where(nrm[:, 2:3] < 0, -nrm, nrm)
    k = len(nrm)
    if k < 3 or k > _FACES or len(face_xyz) != k:
        raise LidarcatError(f"a roof patch needs 3-{_FACES} planes with their points, got {k} planes and "
                            f"{len(face_xyz)} point sets")
    pts = [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in face_xyz]
    if min(len(p) for p in pts) == 0:
        raise LidarcatError("a roof patch needs points on every face")
    mean_dir = np.array([math.atan2(*np.mean(_unit(p[:, :2] - v[:2]), axis=0)[::-1]) for p in pts])
    order = np.argsort(np.mod(mean_dir, 2 * math.pi))
    bounds = []
    for a, b in zip(order, np.roll(order, -1)):
        lo, arc = mean_dir[a], float(np.mod(mean_dir[b] - mean_dir[a], 2 * math.pi)) or 2 * math.pi
        d = np.cross(nrm[a], nrm[b])[:2]
        best = lo + arc / 2                         # no intersection direction between them: the bisector
        for s in (1.0, -1.0):
            ang = math.atan2(s * d[1], s * d[0])
            if np.hypot(*d) > 1e-6 and 0 < np.mod(ang - lo, 2 * math.pi) < arc:
                best = ang
        bounds.append(best)
    # sector i (from bounds[i-1] to bounds[i]) belongs to face order[i]; store as start angles
    starts = np.mod(np.array(np.roll(bounds, 1)), 2 * math.pi)
    srt = np.argsort(np.mod(starts - starts[0], 2 * math.pi))
    starts, faces = starts[srt], order[srt]
    # reach masks: each face's points plus its two boundary rays' first metre, dilated by reach_m
    allp = np.vstack([p[:, :2] for p in pts] + [v[None, :2]])
    lo = allp.min(axis=0) - reach_m - 2 * cell_m
    hi = allp.max(axis=0) + reach_m + 2 * cell_m
    nx, ny = (int(x) for x in np.ceil((hi - lo) / cell_m))
    import cv2

    r = int(math.ceil(reach_m / cell_m))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    reach = np.zeros((k, ny, nx), bool)
    ray_t = np.linspace(0.0, 1.0, 41)
    for i in range(k):
        si = int(np.flatnonzero(faces == i)[0])
        b0, b1 = starts[si], starts[(si + 1) % k]
        extra = np.vstack([v[:2] + ray_t[:, None] * np.array([math.cos(b), math.sin(b)])[None] for b in (b0, b1)])
        q = np.vstack([pts[i][:, :2], extra])
        ij = np.floor((q - lo) / cell_m).astype(np.int64)
        occ = np.zeros((ny, nx), np.uint8)
        occ[np.clip(ij[:, 1], 0, ny - 1), np.clip(ij[:, 0], 0, nx - 1)] = 1
        reach[i] = cv2.dilate(occ, disc).astype(bool)
    return RoofPatch(v, nrm, starts, faces.astype(np.int64), lo, float(cell_m), reach)


def _unit(a: np.ndarray) -> np.ndarray:
    return a / np.maximum(np.linalg.norm(a, axis=1, keepdims=True), 1e-9)


@dataclasses.dataclass(frozen=True, eq=False)
class LidarSurface:
    """The composite surface of the module docstring: a TIN raster with albedo, and exact roof patches.

    Attributes
    ----------
    origin_m : (2,) E, N of the raster's lower-left corner (m)
    cell_m : float
    height : (ny, nx) float32, the TIN's height at the cell centres (m)
    albedo : (ny, nx) float32, linear albedo from the intensity
    grad : (2, ny, nx) float32, dH/dE, dH/dN of the raster
    patches : tuple of RoofPatch
    top_m, bottom_m : float, the highest and lowest surface height (m)
    """

    origin_m: np.ndarray
    cell_m: float
    height: np.ndarray
    albedo: np.ndarray
    grad: np.ndarray
    patches: tuple
    top_m: float
    bottom_m: float
    block_m: float = 0.8
    _bmax: np.ndarray = dataclasses.field(init=False, repr=False)

    def __post_init__(self) -> None:
        # the highest height within a block and its 8 neighbours (raster and patches): a ray above
        # it over a plan step of one block cannot have met the surface
        k = max(1, int(round(self.block_m / self.cell_m)))
        object.__setattr__(self, "block_m", k * self.cell_m)
        ny, nx = self.height.shape
        by, bx = -(-ny // k), -(-nx // k)
        pad = np.full((by * k, bx * k), -np.inf, np.float32)
        pad[:ny, :nx] = self.height
        bmax = pad.reshape(by, k, bx, k).max(axis=(1, 3)).astype(np.float64)
        for p in self.patches:
            ij = np.floor((p.vertex_m[:2] - self.origin_m) / (k * self.cell_m)).astype(int)
            lo = np.floor((p.origin_m - self.origin_m) / (k * self.cell_m)).astype(int)
            hi = np.ceil((p.origin_m + p.cell_m * np.array(p.reach.shape[:0:-1]) - self.origin_m)
                         / (k * self.cell_m)).astype(int)
            sl = (slice(max(0, lo[1]), max(0, hi[1] + 1)), slice(max(0, lo[0]), max(0, hi[0] + 1)))
            bmax[sl] = np.maximum(bmax[sl], p.top_m + 0.01)
        from scipy.ndimage import maximum_filter

        object.__setattr__(self, "_bmax", maximum_filter(bmax, size=3, mode="nearest") + 0.01)

    def block_max(self, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        """An upper bound of the surface within one block (``block_m``) of each plan position (m)."""
        s = self.block_m
        by, bx = self._bmax.shape
        i = np.clip(np.floor((e - self.origin_m[0]) / s).astype(np.int64), 0, bx - 1)
        j = np.clip(np.floor((n - self.origin_m[1]) / s).astype(np.int64), 0, by - 1)
        return self._bmax[j, i]

    def _bilinear(self, grid: np.ndarray, e: np.ndarray, n: np.ndarray) -> np.ndarray:
        ny, nx = grid.shape
        fx = np.clip((e - self.origin_m[0]) / self.cell_m - 0.5, 0, nx - 1.000001)
        fy = np.clip((n - self.origin_m[1]) / self.cell_m - 0.5, 0, ny - 1.000001)
        i, j = fx.astype(np.int64), fy.astype(np.int64)
        a, b = fx - i, fy - j
        flat = grid.ravel()
        k = j * nx + i
        return ((flat[k] * (1 - a) + flat[k + 1] * a) * (1 - b)
                + (flat[k + nx] * (1 - a) + flat[k + nx + 1] * a) * b)

    def surface(self, e: Any, n: Any) -> tuple[np.ndarray, np.ndarray]:
        """Height (m) and label (``patch * 8 + face``; -1 the TIN) at plan positions."""
        e = np.asarray(e, dtype=np.float64).ravel()
        n = np.asarray(n, dtype=np.float64).ravel()
        h = self._bilinear(self.height, e, n).astype(np.float64)
        lab = np.full(len(e), -1, np.int64)
        for k, p in enumerate(self.patches):
            lo, hi = p.origin_m, p.origin_m + p.cell_m * np.array(p.reach.shape[:0:-1])
            sel = np.flatnonzero((e >= lo[0]) & (e < hi[0]) & (n >= lo[1]) & (n < hi[1]))
            if len(sel) == 0:
                continue
            hp, fp = p.height(e[sel], n[sel])
            on = fp >= 0
            h[sel[on]] = hp[on]
            lab[sel[on]] = k * _FACES + fp[on]
        return h, lab

    def radiance(self, xyz: np.ndarray, label: np.ndarray, sun: np.ndarray) -> np.ndarray:
        """Linear radiance (N,) of surface points with their labels under the sun unit vector."""
        e, n = xyz[:, 0], xyz[:, 1]
        alb = self._bilinear(self.albedo, e, n)
        nrm = np.column_stack([-self._bilinear(self.grad[0], e, n), -self._bilinear(self.grad[1], e, n),
                               np.ones(len(e))])
        on = label >= 0
        if on.any():
            nrm[on] = np.vstack([p.normals for p in self.patches])[_patch_face_index(self.patches, label[on])]
        nrm = _unit(nrm)
        light = AMBIENT + (1 - AMBIENT) * np.clip(nrm @ sun, 0, None) / sun[2]
        return np.where(np.isfinite(xyz[:, 2]), alb * light, 0.0)


def _patch_face_index(patches: Sequence[RoofPatch], label: np.ndarray) -> np.ndarray:
    first = np.cumsum([0] + [len(p.normals) for p in patches])[:-1]
    return first[label // _FACES] + label % _FACES


def lidar_surface(xyz_m: Any, intensity: Any, bounds: Sequence[float], *, cell_m: float = 0.1,
                  patches: Sequence[RoofPatch] = ()) -> LidarSurface:
    """The TIN of *xyz_m* (first returns) on a raster over *bounds*, with the albedo from *intensity*.

    Parameters
    ----------
    xyz_m : (N, 3) first returns E, N, h (m)
    intensity : (N,) their intensities (any unit)
    bounds : (E0, N0, E1, N1) the raster's extent (m); points up to 2 m beyond it make the TIN
    cell_m : float
    patches : RoofPatch sequence, the exact roof patches

    Returns
    -------
    LidarSurface
    """
    from scipy.ndimage import distance_transform_edt

    e0, n0, e1, n1 = (float(b) for b in bounds)
    xyz = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
    inten = np.asarray(intensity, dtype=np.float64).ravel()
    near = (xyz[:, 0] > e0 - 2) & (xyz[:, 0] < e1 + 2) & (xyz[:, 1] > n0 - 2) & (xyz[:, 1] < n1 + 2)
    if near.sum() < 3:
        raise LidarcatError(f"fewer than 3 LiDAR points within {bounds}")
    xyz, inten = xyz[near], inten[near]
    lo, hi = np.percentile(inten, [2, 98])
    alb = 0.06 + 0.34 * np.clip((inten - lo) / max(hi - lo, 1e-9), 0, 1)
    # the production TIN gridder (rows from the north, bounds snapped to the cell), flipped to rows from the south
    hgrid = tin_grid(xyz, cell_m, (e0, n0, e1, n1), max_edge_m=None)
    agrid = tin_grid(np.column_stack([xyz[:, :2], alb]), cell_m, (e0, n0, e1, n1), max_edge_m=None)
    vals = np.stack([hgrid.grid[::-1], agrid.grid[::-1]], axis=-1).astype(np.float64)
    e0, n0 = hgrid.transform.x0, hgrid.transform.y0 - hgrid.grid.shape[0] * cell_m
    bad = ~np.isfinite(vals[..., 0])
    if bad.any():
        idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
        vals = vals[idx[0], idx[1]]
    height = vals[..., 0].astype(np.float32)
    albedo = vals[..., 1].astype(np.float32)
    gy, gx = np.gradient(height.astype(np.float64), cell_m)
    top = float(height.max())
    bottom = float(height.min())
    for p in patches:
        top = max(top, p.top_m)
    return LidarSurface(np.array([e0, n0]), float(cell_m), height, albedo,
                        np.stack([gx, gy]).astype(np.float32), tuple(patches), top + 0.05, bottom - 0.05)


def cast_rays(surf: LidarSurface, centre_m: Any, d: np.ndarray, *, step_m: float = 0.2,
              iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """First hits of rays ``centre + t d`` on the surface (module docstring).

    Parameters
    ----------
    surf : LidarSurface
    centre_m : (3,) projection centre (m)
    d : (N, 3) ray directions (any length; pointing down)
    step_m : float
        Marching step in plan (m).
    iterations : int
        At most this many regula-falsi (Illinois) steps on the bracket; they stop when the hit
        moves less than 1e-7 m in height.

    Returns
    -------
    xyz : (N, 3) hits (NaN: none)
    label : (N,) int, ``patch * 8 + face`` or -1 (TIN)
    """
    c = np.asarray(centre_m, dtype=np.float64).reshape(3)
    d = np.asarray(d, dtype=np.float64).reshape(-1, 3)
    N = len(d)
    down = d[:, 2] < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        plan = np.hypot(d[:, 0], d[:, 1]) / np.where(down, -d[:, 2], np.nan)   # plan metres per metre down
    span = surf.top_m - surf.bottom_m
    dz = np.minimum(step_m / np.maximum(plan, 1e-9), span)

    def at(z: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = (z - c[2]) / d[k, 2]
        return c[0] + s * d[k, 0], c[1] + s * d[k, 1]

    # march: a coarse step (one block in plan) while the ray stays above the block maximum about
    # it (then it cannot have met the surface), else a fine step tested on the surface
    bm = surf.block_m
    dzc = np.minimum(bm / np.maximum(plan, 1e-9), span)
    hi = np.full(N, np.nan)             # first sample below the surface
    active = np.flatnonzero(down)
    z = np.full(len(active), surf.top_m)
    floor = surf.bottom_m - 0.01
    while len(active):
        zc = z - dzc[active]
        e, n = at(zc, active)
        clear = zc > surf.block_max(e, n)
        fine = np.flatnonzero(~clear)
        z = np.where(clear, zc, z)
        if len(fine):
            zf = np.maximum(z[fine] - dz[active[fine]], floor)
            e, n = at(zf, active[fine])
            below = zf <= surf.surface(e, n)[0]
            hi[active[fine[below]]] = zf[below]
            z[fine] = zf
            clear[fine[below]] = False
        done = np.isfinite(hi[active]) | (z <= floor + 1e-12)
        active, z = active[~done], z[~done]
    ok = np.flatnonzero(np.isfinite(hi))
    zb = hi[ok]
    za = np.minimum(zb + dz[ok], surf.top_m)
    e, n = at(zb, ok)
    gb = zb - surf.surface(e, n)[0]
    e, n = at(za, ok)
    ga = za - surf.surface(e, n)[0]
    zm = zb.copy()
    live = np.arange(len(ok))
    side = np.zeros(len(ok), np.int8)
    for _ in range(iterations):    # Illinois: g(za) > 0 >= g(zb)
        if not len(live):
            break
        a, b, fa, fb = za[live], zb[live], ga[live], gb[live]
        with np.errstate(divide="ignore", invalid="ignore"):
            zn = np.where(fa - fb > 0, b + (a - b) * (-fb) / (fa - fb), 0.5 * (a + b))
        zn = np.clip(zn, np.minimum(a, b), np.maximum(a, b))
        e, n = at(zn, ok[live])
        fn = zn - surf.surface(e, n)[0]
        moved = np.abs(zn - zm[live])
        zm[live] = zn
        below = fn <= 0
        # replace the endpoint on the same side; halve the other's value when one side repeats
        za[live] = np.where(below, a, zn)
        zb[live] = np.where(below, zn, b)
        ga[live] = np.where(below, np.where(side[live] == -1, fa / 2, fa), fn)
        gb[live] = np.where(below, fn, np.where(side[live] == 1, fb / 2, fb))
        side[live] = np.where(below, -1, 1)
        live = live[(moved > 1e-7) & (np.abs(fn) > 1e-9)]
    e, n = at(zm, ok)
    _, lab = surf.surface(e, n)
    xyz = np.full((N, 3), np.nan)
    xyz[ok] = np.column_stack([e, n, zm])
    label = np.full(N, -1, np.int64)
    label[ok] = lab
    return xyz, label


def _rays(camera: Camera, m: np.ndarray, colrow: np.ndarray) -> np.ndarray:
    xy = camera.pixel_to_photo(colrow)
    return np.column_stack([xy, np.full(len(xy), -camera.focal_length_mm)]) @ m


def render_lidar_photo(surf: LidarSurface, camera: Camera, eo: Any, *, exposure: Exposure | None = None,
                       sun_azimuth_deg: float = 225.0, sun_elevation_deg: float = 45.0, supersample: int = 4,
                       tile_px: int = 256, step_m: float = 0.2) -> RenderedPhoto:
    """A grey photo of the surface from orientation *eo* (module docstring).

    Parameters
    ----------
    surf : LidarSurface
    camera : Camera
    eo : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad)
    exposure : Exposure, optional (default gain 1, gamma 2.2, no noise)
    sun_azimuth_deg, sun_elevation_deg : float
    supersample : int
        Sub-rays per pixel side at edges (1: one ray per pixel).
    tile_px : int
    step_m : float
        Marching step in plan (m).

    Returns
    -------
    RenderedPhoto
        ``image`` (H, W) uint8; ``xyz`` the hit of each pixel centre; ``surface`` 1 on a roof patch,
        0 the TIN, -1 none; ``building`` the label (``patch * 8 + face``, -1 TIN).
    """
    exposure = exposure or Exposure()
    eo = np.asarray(eo, dtype=np.float64)
    ss = int(supersample)
    if ss < 1:
        raise LidarcatError(f"supersample must be 1 or more, got {supersample}")
    W, H = camera.columns_px, camera.rows_px
    m = rotation_matrix(eo[3:6])
    c = eo[:3]
    sun = sun_vector(sun_azimuth_deg, sun_elevation_deg)
    lin = np.zeros((H, W))
    xyz_map = np.full((H, W, 3), np.nan)
    lab_map = np.full((H, W), -1, np.int64)
    o = (np.arange(ss) + 0.5) / ss - 0.5
    oc, orow = (a.ravel() for a in np.meshgrid(o, o))
    for r0 in range(0, H, tile_px):
        r1 = min(H, r0 + tile_px)
        for c0 in range(0, W, tile_px):
            c1 = min(W, c0 + tile_px)
            cc, rr = np.meshgrid(np.arange(c0 - 1, c1 + 1, dtype=np.float64), np.arange(r0 - 1, r1 + 1, dtype=np.float64))
            colrow = np.column_stack([cc.ravel(), rr.ravel()])
            xyz, lab = cast_rays(surf, c, _rays(camera, m, colrow), step_m=step_m)
            rad = surf.radiance(xyz, lab, sun)
            th, tw = r1 - r0 + 2, c1 - c0 + 2
            key = np.where(np.isfinite(xyz[:, 2]), lab, -2).reshape(th, tw)
            z = np.nan_to_num(xyz[:, 2], nan=-1e9).reshape(th, tw)
            mid, zm = key[1:-1, 1:-1], z[1:-1, 1:-1]
            edge = np.zeros(mid.shape, bool)
            for sl in ((slice(None, -2), slice(1, -1)), (slice(2, None), slice(1, -1)),
                       (slice(1, -1), slice(None, -2)), (slice(1, -1), slice(2, None))):
                edge |= (mid != key[sl]) | (np.abs(zm - z[sl]) > 0.3)
            rad = rad.reshape(th, tw)[1:-1, 1:-1].copy()
            if ss > 1 and edge.any():
                er, ec = np.nonzero(edge)
                sub = np.column_stack([((ec + c0)[:, None] + oc[None]).ravel(), ((er + r0)[:, None] + orow[None]).ravel()])
                sx, sl_ = cast_rays(surf, c, _rays(camera, m, sub.astype(np.float64)), step_m=step_m)
                rad[er, ec] = surf.radiance(sx, sl_, sun).reshape(len(er), ss * ss).mean(axis=1)
            lin[r0:r1, c0:c1] = rad
            xyz_map[r0:r1, c0:c1] = xyz.reshape(th, tw, 3)[1:-1, 1:-1]
            lab_map[r0:r1, c0:c1] = lab.reshape(th, tw)[1:-1, 1:-1]
    vig = 1.0
    if exposure.vignetting:
        rc2 = ((W - 1) / 2) ** 2 + ((H - 1) / 2) ** 2
        r2 = (((np.arange(W) - (W - 1) / 2) ** 2)[None, :] + ((np.arange(H) - (H - 1) / 2) ** 2)[:, None]) / rc2
        vig = (1.0 - exposure.vignetting * r2).astype(np.float32)
    val = exposure.apply(lin.astype(np.float32), vig)
    if exposure.noise_sd > 0:
        val = val + np.random.default_rng(exposure.seed).standard_normal(val.shape).astype(np.float32) \
            * np.float32(exposure.noise_sd)
    val[~np.isfinite(xyz_map[..., 2])] = 0
    img = np.clip(np.rint(val), 0, 255).astype(np.uint8)
    code = np.where(np.isfinite(xyz_map[..., 2]), np.where(lab_map >= 0, 1, 0), -1).astype(np.int8)
    return RenderedPhoto(img, xyz_map, code, lab_map.astype(np.int32))


def vertex_visible(surf: LidarSurface, eo: Any, vertex_m: Any, *, tol_m: float = 0.05) -> np.ndarray:
    """(N,) bool: the ray from the projection centre to each vertex meets the surface no sooner than
    *tol_m* before the vertex (a ray that only touches the roof at the vertex -- a silhouette -- and
    goes on sees it)."""
    v = np.asarray(vertex_m, dtype=np.float64).reshape(-1, 3)
    c = np.asarray(eo, dtype=np.float64)[:3]
    xyz, _ = cast_rays(surf, c, v - c, step_m=0.05)
    dist = np.linalg.norm(v - c, axis=1)
    along = np.einsum("ij,ij->i", xyz - c, (v - c) / dist[:, None])
    return ~(along < dist - tol_m)     # no hit (NaN) or a hit at or beyond the vertex


def flight_poses(centre_en: Any, ground_m: float, gsd_m: float, camera: Camera, *, n_strips: int = 2,
                 per_strip: int = 3, forward: float = 0.6, side: float = 0.3, heading_deg: float = 0.0,
                 attitude_sd_deg: float = 1.0, seed: int = 0) -> np.ndarray:
    """(n_strips * per_strip, 6) true orientations of a flight over *centre_en* (strips along *heading_deg*).

    The height above *ground_m* gives *gsd_m* at the nadir (``gsd * c / pixel``); photos along a
    strip ``(1 - forward)`` of the footprint apart, strips ``(1 - side)`` apart, flown alternately
    both ways (kappa turns by 180 deg); omega, phi and kappa jitter with *attitude_sd_deg*, the
    position with 1 % of the height.
    """
    rng = np.random.default_rng(seed)
    z = float(ground_m) + gsd_m * camera.focal_length_mm / camera.pixel_size_x_mm
    along = (1 - forward) * gsd_m * camera.rows_px
    across = (1 - side) * gsd_m * camera.columns_px
    hd = math.radians(heading_deg)
    u = np.array([math.sin(hd), math.cos(hd)])           # along the strip (heading from north)
    w = np.array([u[1], -u[0]])
    out = []
    for s in range(n_strips):
        for k in range(per_strip):
            kk = k if s % 2 == 0 else per_strip - 1 - k
            p = np.asarray(centre_en, dtype=np.float64) + (kk - (per_strip - 1) / 2) * along * u \
                + (s - (n_strips - 1) / 2) * across * w
            # the image's row axis (y up) along the flight: kappa = -heading (+ 180 on the way back)
            kappa = -hd + (math.pi if s % 2 else 0.0)
            att = np.radians(rng.normal(0, attitude_sd_deg, 3))
            pos = np.array([p[0], p[1], z]) + rng.normal(0, 0.01 * (z - ground_m), 3)
            out.append([*pos, att[0], att[1], kappa + att[2]])
    return np.array(out)
