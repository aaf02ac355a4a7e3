r"""The albedo of the synthetic aerial scene: a deterministic, non-repeating function of ground position.

The rendered photos (:mod:`lidarcat.synthetic.aerial`) must show the same ground point with the
same albedo in every photo -- only the exposure differs -- so that features match across photos,
and they must carry detail at the ground sample distance, so that a feature detector finds
thousands of distinctive points.  Both follow from one construction: the albedo is sampled on a
*global lattice* of spacing ``s`` (the texel, about the GSD) whose node ``(i, j)`` lies at
``E = i s``, ``N = -j s`` and whose value depends on ``(i, j)`` and the seed only.  A photo
evaluates the lattice over the plan box of the ground it sees, and interpolates it bilinearly
at the ground point of each pixel: two photos that see a ground point use the same four nodes,
whatever the crop, so they see the same albedo.

Noise without repetition (integer hashing)
------------------------------------------
``hash(i, j, salt)`` is a 32-bit integer mixer (multiply-xorshift, as the finaliser of
MurmurHash3) of the node indices: white noise that never repeats within 2^32 nodes.  A
multi-octave noise (fractal sum) is built coarse to fine: level ``k`` has nodes every ``2^k``
texels, its value is the level above upsampled by 2 (cubic convolution) plus white noise of
amplitude ``a_k``.  Each level is evaluated on a crop padded by 2 nodes beyond what the finer
level needs (the cubic kernel reads 2 nodes each side), so the values do not depend on the crop.

Land cover (all seeded, all functions of position)
--------------------------------------------------
* **fields**: the Voronoi cells of one jittered seed point per ``field_m`` square (hash of the
  square); each field a kind (grass, soil, crop, stubble, orchard) with its colour, a row pattern
  ``1 + a sin(2 pi (E cos t + N sin t) / p)`` of its own direction ``t`` and period ``p``, grain
  (the fine octaves) and patches (the coarse ones); a darker strip ``|d2 - d1| / 2 < w`` along the
  boundaries (``d1 <= d2``: distances to the two nearest seeds);
* **roads**: asphalt strips with bright edge lines and a dashed centre line;
* **trees**: one candidate per 10 m square, kept with a probability of the field kind (orchards
  dense, ploughed soil bare); the crown a disc shaded as a hemisphere ``n = ((p - c) / r, sqrt(1 -
  rho^2))`` with leaf grain, its shadow the disc moved ``H cot(elevation)`` away from the sun
  (``H``: the crown centre, half the tree height);
* **buildings**: each roof face coloured by its material, with tile courses along the slope and
  the grain, and shaded ``ambient + (1 - ambient) max(0, n . sun) / sin(elevation)`` by its plane
  normal (:func:`roof_albedo`).  Roofs are *not* painted into the lattice: the renderer evaluates
  them per ray, at the hit point and for the face hit, so that a face boundary (ridge, hip) and
  an eave lie exactly where the geometry puts them in a photo, not up to a texel off (the grain is
  still the lattice's, interpolated at the hit; the courses are evaluated at the hit).  The
  building's shadow is the convex hull of its vertices moved the same way (a convex solid casts a
  convex shadow);
* **targets**: a black square with a white cross at each ground control point.

Values are linear reflectances (RGB, 0..1); a photo applies its own exposure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["LUMA", "hash2", "unit_hash", "fractal_noise", "albedo_lattice", "bilinear", "sun_vector",
           "building_planes", "roof_albedo", "FIELD_KINDS"]

_M1, _M2, _M3, _M4 = np.uint32(0x8DA6B343), np.uint32(0xD8163841), np.uint32(0x7FEB352D), np.uint32(0x846CA68B)

#: field kinds: name, linear RGB colour, grain (fine-octave amplitude), row amplitude, tree probability
FIELD_KINDS = (
    ("grass", (0.11, 0.17, 0.07), 0.35, 0.06, 0.10),
    ("soil", (0.20, 0.15, 0.10), 0.25, 0.30, 0.01),
    ("crop", (0.16, 0.20, 0.08), 0.25, 0.35, 0.02),
    ("stubble", (0.32, 0.27, 0.16), 0.30, 0.20, 0.04),
    ("orchard", (0.10, 0.14, 0.06), 0.35, 0.05, 0.80),
)
_AMBIENT = 0.4


def hash2(i: Any, j: Any, salt: int) -> np.ndarray:
    """32-bit hash of integer node indices (broadcast), uint32."""
    with np.errstate(over="ignore"):
        h = (np.asarray(i).astype(np.int64).astype(np.uint32) * _M1) ^ \
            (np.asarray(j).astype(np.int64).astype(np.uint32) * _M2) ^ np.uint32(salt & 0xFFFFFFFF)
        h ^= h >> np.uint32(16)
        h *= _M3
        h ^= h >> np.uint32(15)
        h *= _M4
        h ^= h >> np.uint32(16)
    return h


def unit_hash(i: Any, j: Any, salt: int) -> np.ndarray:
    """Uniform [0, 1) float32 from :func:`hash2`."""
    return (hash2(i, j, salt) >> np.uint32(8)).astype(np.float32) * np.float32(2.0 ** -24)


def fractal_noise(i0: int, j0: int, nx: int, ny: int, amplitudes: Sequence[float], salt: int) -> np.ndarray:
    """Multi-octave value noise on lattice nodes ``i0 .. i0+nx-1`` x ``j0 .. j0+ny-1`` (see the module docstring).

    Parameters
    ----------
    i0, j0 : int
        Global index of the first node (column, row).
    nx, ny : int
        Crop size, nodes.
    amplitudes : sequence of float
        ``a_k`` of level ``k`` (nodes every ``2^k`` texels); 0 skips the level's noise.
    salt : int

    Returns
    -------
    (ny, nx) float32 array, zero mean, sd about ``sqrt(sum a_k^2)``.
    """
    import cv2

    crops = [(i0, i0 + nx, j0, j0 + ny)]
    for _ in range(1, len(amplitudes)):
        ia, ib, ja, jb = crops[-1]
        crops.append((ia // 2 - 2, -(-ib // 2) + 2, ja // 2 - 2, -(-jb // 2) + 2))
    acc = None
    for k in range(len(amplitudes) - 1, -1, -1):
        ia, ib, ja, jb = crops[k]
        if acc is not None:
            pa, pb, qa, qb = crops[k + 1]
            up = cv2.resize(acc, (2 * (pb - pa), 2 * (qb - qa)), interpolation=cv2.INTER_CUBIC)
            acc = up[ja - 2 * qa:jb - 2 * qa, ia - 2 * pa:ib - 2 * pa]
        if amplitudes[k]:
            white = unit_hash(np.arange(ia, ib)[None, :], np.arange(ja, jb)[:, None], salt + 7919 * k)
            noise = (white - np.float32(0.5)) * np.float32(2 * math.sqrt(3) * amplitudes[k])
            acc = noise if acc is None else acc + noise
        elif acc is None:
            acc = np.zeros((jb - ja, ib - ia), np.float32)
    assert acc is not None
    return np.ascontiguousarray(acc, dtype=np.float32)


def sun_vector(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit vector towards the sun (E, N, up); azimuth clockwise from north."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])


def building_planes(b: Any, base_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The convex solid of a building as half-spaces ``n . (X - P0) <= c`` (world E, N, h).

    Returns
    -------
    normals : (F, 3) outward normals (not unit)
    offsets : (F,) ``c`` relative to ``P0 = (b.e_m, b.n_m, base_m)``
    kinds : (F,) int: 0 roof, 1 wall, 2 floor
    """
    t = 0.0 if b.kind == "flat" else math.tan(math.radians(b.slope_deg))
    L, W = b.length_m / 2, b.width_m / 2
    rows = []   # (a_u, a_v, a_z, c, kind) in the building frame (u, v, z')
    rows += [(1, 0, 0, L, 1), (-1, 0, 0, L, 1), (0, 1, 0, W, 1), (0, -1, 0, W, 1), (0, 0, -1, 3.0, 2)]
    if b.kind == "flat":
        rows.append((0, 0, 1, b.eave_m, 0))
    else:
        rows += [(0, t, 1, b.eave_m + t * W, 0), (0, -t, 1, b.eave_m + t * W, 0)]
        if b.kind in ("hip", "pyramid"):
            rows += [(t, 0, 1, b.eave_m + t * L, 0), (-t, 0, 1, b.eave_m + t * L, 0)]
    r = np.array(rows, dtype=float)
    ca, sa = math.cos(math.radians(b.azimuth_deg)), math.sin(math.radians(b.azimuth_deg))
    n = np.column_stack([r[:, 0] * ca - r[:, 1] * sa, r[:, 0] * sa + r[:, 1] * ca, r[:, 2]])
    return n, r[:, 3], r[:, 4].astype(int)


def bilinear(lattice: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a (ny, nx[, C]) float32 lattice at fractional node positions.

    Explicit weights (no fixed-point positions, unlike ``cv2.remap``): the same plan position gives
    the same value whatever lattice crop holds it (to float32 rounding).  Positions outside the
    lattice give 0.
    """
    ny, nx = lattice.shape[:2]
    flat = lattice.reshape(ny * nx, -1)
    col = np.asarray(col, dtype=np.float32)
    row = np.asarray(row, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        c0 = np.floor(col)
        r0 = np.floor(row)
        valid = (c0 >= 0) & (c0 < nx - 1) & (r0 >= 0) & (r0 < ny - 1)
    fc = np.where(valid, col - c0, np.float32(0))
    fr = np.where(valid, row - r0, np.float32(0))
    idx = np.where(valid, r0.astype(np.int64) * nx + c0.astype(np.int64), 0)
    if flat.shape[1] == 1:
        v = flat[:, 0]
        top = v[idx] + (v[idx + 1] - v[idx]) * fc
        bottom = v[idx + nx] + (v[idx + nx + 1] - v[idx + nx]) * fc
        out = top + (bottom - top) * fr
        out[~valid] = 0
        return out.reshape(col.shape + lattice.shape[2:])
    fc, fr = fc[..., None], fr[..., None]
    top = flat[idx] * (1 - fc) + flat[idx + 1] * fc
    bottom = flat[idx + nx] * (1 - fc) + flat[idx + nx + 1] * fc
    out = top * (1 - fr) + bottom * fr
    out[~valid] = 0
    return out.reshape(col.shape + lattice.shape[2:])


def _parcels(e: np.ndarray, n: np.ndarray, field_m: float, salt: int):
    """Voronoi fields at plan positions (broadcast): (cell i, cell j) of the nearest seed, d1, d2 (m).

    The seeds of the cells around the positions are hashed once into a small table; each position
    reads the 3 x 3 cells around its own.
    """
    fe, fn = e / field_m, n / field_m
    ce, cn = np.floor(fe), np.floor(fn)
    fx, fy = (fe - ce).astype(np.float32), (fn - cn).astype(np.float32)
    ce, cn = ce.astype(np.int64), cn.astype(np.int64)
    ia, ja = int(ce.min()) - 1, int(cn.min()) - 1
    ti = np.arange(ia, int(ce.max()) + 2)[None, :]
    tj = np.arange(ja, int(cn.max()) + 2)[:, None]
    jx_t = 0.1 + 0.8 * unit_hash(ti, tj, salt)
    jy_t = 0.1 + 0.8 * unit_hash(ti, tj, salt + 1)
    li, lj = ce - ia, cn - ja
    shape = np.broadcast_shapes(fx.shape, fy.shape)
    d1 = np.full(shape, np.inf, np.float32)
    d2 = np.full(shape, np.inf, np.float32)
    best = np.zeros(shape, np.int8)
    for k, (dx, dy) in enumerate((dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)):
        jx = jx_t[lj + dy, li + dx]
        jy = jy_t[lj + dy, li + dx]
        d = (fx - dx - jx) ** 2 + (fy - dy - jy) ** 2
        closer = d < d1
        d2 = np.where(closer, d1, np.minimum(d2, d))
        d1 = np.where(closer, d, d1)
        best = np.where(closer, np.int8(k), best)
    bx = best // 3 - 1
    by = best % 3 - 1
    return ce + bx, cn + by, np.sqrt(d1) * field_m, np.sqrt(d2) * field_m


#: Rec. 709 luminance of linear RGB: the grey albedo
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


def _col(rgb: Any, nch: int) -> np.ndarray:
    """A colour (..., 3) as *nch* channels: itself (3) or its luminance (1)."""
    c = np.asarray(rgb, np.float32)
    return c if nch == 3 else (c @ LUMA)[..., None].astype(np.float32)


def albedo_lattice(scene: Any, i0: int, j0: int, nx: int, ny: int, *, rgb: bool = True,
                   with_grain: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Linear RGB albedo (with the fixed sun's shading and shadows) at lattice nodes (see module docstring).

    The ground only: roofs are evaluated per point by :func:`roof_albedo` (the lattice holds the
    ground under them).

    Parameters
    ----------
    scene : lidarcat.synthetic.aerial.AerialScene
    i0, j0, nx, ny : int
        Global index of the first node and crop size; node ``(i, j)`` is at ``E = i s, N = -j s``.

    rgb : bool
        Linear RGB (3 channels) or its luminance (1 channel: the same values as ``LUMA @ rgb``,
        a third of the work).

    with_grain : bool
        Also return the grain (fine fractal noise) lattice (ny, nx) that :func:`roof_albedo` reads.

    Returns
    -------
    (ny, nx, 3 or 1) float32 array [, (ny, nx) float32 grain]
    """
    s = scene.texel_m
    seed = int(scene.seed) * 1000003
    e1 = (np.arange(i0, i0 + nx, dtype=np.float64) * s)[None, :]
    n1 = (-np.arange(j0, j0 + ny, dtype=np.float64) * s)[:, None]
    # local float32 plan coordinates of the nodes (metres from the first node)
    x = ((np.arange(nx, dtype=np.float32)) * np.float32(s))[None, :]
    y = (-(np.arange(ny, dtype=np.float32)) * np.float32(s))[:, None]
    e0, n0 = float(e1[0, 0]), float(n1[0, 0])

    levels = max(5, int(math.ceil(math.log2(max(scene.field_m / 2, 4 * s) / s))))
    # one fractal sum: grain at 1-8 texels, patches above
    grain = fractal_noise(i0, j0, nx, ny, [0.25, 0.18, 0.12, 0.08] + [0.06] * (levels - 4), seed + 11)

    # the fields on a lattice 4x coarser (node centred on its 4 x 4 fine nodes), upsampled: the
    # field's colour, rows and boundary width by nearest neighbour, the distance to the boundary linearly
    import cv2

    f = 4
    ci0, cj0 = i0 // f - 1, j0 // f - 1   # one node of padding: the linear upsampling reads it
    nxc, nyc = -(-(i0 + nx) // f) + 1 - ci0, -(-(j0 + ny) // f) + 1 - cj0
    ec = ((np.arange(ci0, ci0 + nxc) * f + (f - 1) / 2) * s)[None, :]
    nc = (-(np.arange(cj0, cj0 + nyc) * f + (f - 1) / 2) * s)[:, None]
    bi, bj, d1, d2 = _parcels(ec, nc, scene.field_m, seed + 17)
    kind = (hash2(bi, bj, seed + 19) % np.uint32(len(FIELD_KINDS))).astype(np.intp)
    nch = 3 if rgb else 1
    table = _col([k[1] for k in FIELD_KINDS], nch)
    tint = 0.6 + 0.8 * unit_hash(bi, bj, seed + 23)
    ang = np.float32(math.pi) * unit_hash(bi, bj, seed + 29)
    period = np.maximum(np.float32(3 * s), 0.6 + 1.6 * unit_hash(bi, bj, seed + 31))
    ca, sa = np.cos(ang), np.sin(ang)
    # row phase at the first fine node (float64), so that the fine phase is float32-exact
    phase0 = np.mod((e0 * ca.astype(np.float64) + n0 * sa.astype(np.float64)) / period, 1.0)
    oi, oj = i0 - ci0 * f, j0 - cj0 * f

    def up(a: np.ndarray, interp: int = cv2.INTER_NEAREST) -> np.ndarray:
        big = cv2.resize(np.ascontiguousarray(a, dtype=np.float32), (nxc * f, nyc * f), interpolation=interp)
        return big[oj:oj + ny, oi:oi + nx]

    row_amp = up(np.array([k[3] for k in FIELD_KINDS], np.float32)[kind])
    phase = x * up(ca / period) + y * up(sa / period) + up(phase0)
    edge = up(((d2 - d1) / 2).astype(np.float32), cv2.INTER_LINEAR) < up(0.6 + 0.8 * unit_hash(bi, bj, seed + 37))
    col = up(table[kind] * tint[..., None]).reshape(ny, nx, nch)   # cv2 drops a single channel
    del bi, bj, d1, d2, kind, tint, ang, period, ca, sa, phase0
    lum = (1.0 + grain) * (1.0 + row_amp * np.sin(np.float32(2 * math.pi) * phase))
    lum[edge] *= 0.55 * (1 + 1.2 * grain[edge])
    np.clip(lum, 0.05, None, out=lum)
    alb = col * lum[..., None]
    del row_amp, phase, edge, lum, col

    ext = (e0, e0 + (nx - 1) * s, n0 - (ny - 1) * s, n0)
    for road in scene.roads:
        _paint_road(alb, road, e0, n0, s, grain)
    trees = _trees(scene, ext, seed)
    sun = sun_vector(scene.sun_azimuth_deg, scene.sun_elevation_deg)
    cot = 1.0 / math.tan(math.radians(scene.sun_elevation_deg))
    off = -cot * sun[:2] / np.hypot(*sun[:2])
    # shadows: a node in any shadow is lit by the ambient light only (shadows do not darken twice)
    lit = np.ones((ny, nx), bool)
    for te, tn, r, h in trees:   # shadows first, crowns over them
        w = _window(te + off[0] * h * 0.5, tn + off[1] * h * 0.5, r, e0, n0, s, (ny, nx))
        if w is not None:
            rs, cs, de, dn = w
            lit[rs, cs] &= (de ** 2 + dn ** 2) >= r ** 2
    for k, b in enumerate(scene.buildings):
        _building_shadow(lit, b, off, e0, n0, s)
    alb[~lit] *= np.float32(_AMBIENT)
    for te, tn, r, h in trees:
        _paint_crown(alb, te, tn, r, e0, n0, s, sun, grain, seed)
    for te, tn in scene.targets:
        _paint_target(alb, te, tn, e0, n0, s)
    return (alb, grain) if with_grain else alb


def _window(ce: float, cn: float, half: float, e0: float, n0: float, s: float, shape: tuple[int, int]):
    """Row and column slices of the nodes within ``half`` m of (ce, cn), and their local offsets (m)."""
    c0 = max(0, int(math.floor((ce - half - e0) / s)))
    c1 = min(shape[1], int(math.ceil((ce + half - e0) / s)) + 1)
    r0 = max(0, int(math.floor((n0 - cn - half) / s)))
    r1 = min(shape[0], int(math.ceil((n0 - cn + half) / s)) + 1)
    if c0 >= c1 or r0 >= r1:
        return None
    de = (e0 - ce + np.arange(c0, c1) * s)[None, :]
    dn = (n0 - cn - np.arange(r0, r1) * s)[:, None]
    return slice(r0, r1), slice(c0, c1), de, dn


def _trees(scene: Any, ext: tuple[float, float, float, float], seed: int) -> list[tuple[float, float, float, float]]:
    """Trees (E, N, crown radius, height) whose crown or shadow may reach the plan box."""
    if not scene.trees:
        return []
    cell = 10.0
    pad = 25.0
    ci = np.arange(math.floor((ext[0] - pad) / cell), math.floor((ext[1] + pad) / cell) + 1)
    cj = np.arange(math.floor((ext[2] - pad) / cell), math.floor((ext[3] + pad) / cell) + 1)
    gi, gj = np.meshgrid(ci, cj)
    gi, gj = gi.ravel(), gj.ravel()
    te = (gi + 0.15 + 0.7 * unit_hash(gi, gj, seed + 51)) * cell
    tn = (gj + 0.15 + 0.7 * unit_hash(gi, gj, seed + 53)) * cell
    r = 1.5 + 2.5 * unit_hash(gi, gj, seed + 57)
    h = r * (2.0 + 1.5 * unit_hash(gi, gj, seed + 59))
    bi, bj, d1, d2 = _parcels(te, tn, scene.field_m, seed + 17)
    kind = (hash2(bi, bj, seed + 19) % np.uint32(len(FIELD_KINDS))).astype(np.intp)
    p = np.array([k[4] for k in FIELD_KINDS])[kind]
    p = np.where((d2 - d1) / 2 < 4.0, np.maximum(p, 0.5), p)
    keep = unit_hash(gi, gj, seed + 61) < p
    for road in scene.roads:
        keep &= road_distance(road, te, tn) > road.width_m / 2 + r + 1.0
    for b in scene.buildings:
        u, v = b.to_local(te, tn)
        keep &= (np.abs(u) > b.length_m / 2 + r + 1.0) | (np.abs(v) > b.width_m / 2 + r + 1.0)
    return list(zip(te[keep].tolist(), tn[keep].tolist(), r[keep].tolist(), h[keep].tolist()))


def _paint_crown(alb, te, tn, r, e0, n0, s, sun, grain, seed) -> None:
    w = _window(te, tn, r, e0, n0, s, alb.shape[:2])
    if w is None:
        return
    rs, cs, de, dn = w
    rho2 = (de ** 2 + dn ** 2) / r ** 2
    inside = rho2 < 1
    if not inside.any():
        return
    nz = np.sqrt(np.clip(1 - rho2, 0, 1))
    lam = np.clip((de / r * sun[0] + dn / r * sun[1] + nz * sun[2]), 0, None)
    light = _AMBIENT + (1 - _AMBIENT) * lam / sun[2]
    tone = 0.8 + 0.4 * float(unit_hash(int(te * 10), int(tn * 10), seed + 63))
    leaf = 1.0 + 2.5 * grain[rs, cs]
    col = _col([0.05, 0.10, 0.04], alb.shape[-1]) * np.float32(tone)
    val = col[None, None, :] * (light * leaf)[..., None]
    alb[rs, cs] = np.where(inside[..., None], val, alb[rs, cs])


def road_distance(road: Any, e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Plan distance (m) of points to the centre line of a road (a segment)."""
    a = np.array([road.e0_m, road.n0_m])
    ab = np.array([road.e1_m, road.n1_m]) - a
    L2 = float(ab @ ab)
    t = np.clip(((e - a[0]) * ab[0] + (n - a[1]) * ab[1]) / L2, 0, 1)
    return np.hypot(e - a[0] - t * ab[0], n - a[1] - t * ab[1])


def _paint_road(alb, road, e0, n0, s, grain) -> None:
    ny, nx = alb.shape[:2]
    lo_e, hi_e = sorted((road.e0_m, road.e1_m))
    lo_n, hi_n = sorted((road.n0_m, road.n1_m))
    half = road.width_m / 2 + 1.0
    c0 = max(0, int(math.floor((lo_e - half - e0) / s)))
    c1 = min(nx, int(math.ceil((hi_e + half - e0) / s)) + 1)
    r0 = max(0, int(math.floor((n0 - hi_n - half) / s)))
    r1 = min(ny, int(math.ceil((n0 - lo_n + half) / s)) + 1)
    if c0 >= c1 or r0 >= r1:
        return
    # local coordinates relative to the road's start (small numbers: float64 then distances)
    de = (e0 + np.arange(c0, c1) * s - road.e0_m)[None, :]
    dn = (n0 - np.arange(r0, r1) * s - road.n0_m)[:, None]
    ab = np.array([road.e1_m - road.e0_m, road.n1_m - road.n0_m])
    L = float(np.hypot(*ab))
    u = (de * ab[0] + dn * ab[1]) / L          # along, m
    v = (-de * ab[1] + dn * ab[0]) / L         # across, m
    w2 = road.width_m / 2
    on = (np.abs(v) <= w2) & (u >= -w2) & (u <= L + w2)
    if not on.any():
        return
    g = grain[r0:r1, c0:c1]
    lum = 0.09 * (1 + 0.6 * g)
    edge = (np.abs(np.abs(v) - (w2 - 0.35)) < 0.1)
    dash = (np.abs(v) < 0.08) & (np.mod(u, 9.0) < 3.0)
    lum = np.where(edge | dash, 0.55 + 0.2 * g, lum)
    shoulder = (np.abs(v) > w2 - 0.15)
    lum = np.where(shoulder, 0.16 * (1 + 1.2 * g), lum)
    val = lum[..., None].astype(np.float32) * _col([1.0, 1.0, 0.97], alb.shape[-1])
    alb[r0:r1, c0:c1] = np.where(on[..., None], val, alb[r0:r1, c0:c1])


def _building_shadow(lit, b, off, e0, n0, s) -> None:
    """Clear *lit* inside the shadow of building *b*: the convex hull of its vertices moved along the sun."""
    import cv2

    fp = b.footprint()
    pts = [np.column_stack([fp, np.zeros(4)]), np.column_stack([fp, np.full(4, b.eave_m)])]
    v = b.vertices(0.0)
    if len(v):
        pts.append(v)
    elif b.kind == "gable":
        L = b.length_m / 2
        ends = np.column_stack(b.to_world(np.array([-L, L]), np.zeros(2)))
        pts.append(np.column_stack([ends, np.full(2, b.top_m)]))
    p = np.vstack(pts)
    sh = p[:, :2] + off[None, :] * p[:, 2:3]
    cx, cy = (sh[:, 0] - e0) / s, (n0 - sh[:, 1]) / s
    c0, c1 = max(0, int(math.floor(cx.min())) - 1), min(lit.shape[1], int(math.ceil(cx.max())) + 2)
    r0, r1 = max(0, int(math.floor(cy.min())) - 1), min(lit.shape[0], int(math.ceil(cy.max())) + 2)
    if c0 >= c1 or r0 >= r1:
        return
    hull = cv2.convexHull(np.column_stack([cx - c0, cy - r0]).astype(np.float32))
    mask = np.zeros((r1 - r0, c1 - c0), np.uint8)
    cv2.fillConvexPoly(mask, np.round(hull * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4)
    lit[r0:r1, c0:c1] &= mask == 0


_ROOF_MATERIALS = (((0.30, 0.10, 0.06), 0.25), ((0.18, 0.18, 0.19), 0.15), ((0.09, 0.09, 0.11), 0.2),
                   ((0.40, 0.40, 0.38), 0.10), ((0.25, 0.12, 0.08), 0.3))


def roof_albedo(b: Any, base_m: float, scene_seed: int, k: int, texel_m: float, e: np.ndarray, n: np.ndarray,
                grain: np.ndarray, sun: np.ndarray, nch: int) -> np.ndarray:
    """Linear albedo (N, nch) of roof points of building *b* (index *k*) at plan positions (E, N).

    The face of a point is the lowest roof plane above it (the roof of a convex solid is the lower
    envelope of its planes), so a point of the roof surface takes the face it lies on: the face a
    ray hits.  Its value: the material's colour times the face's sun shading times the tile courses
    ``1 + a/2 sin(2 pi |v| / p)`` (``v`` across the ridge) plus half the *grain* given at the points.
    """
    s_seed = int(scene_seed) * 1000003 + 41 * int(k)
    de = np.asarray(e, np.float64) - b.e_m
    dn = np.asarray(n, np.float64) - b.n_m
    ca, sa = math.cos(math.radians(b.azimuth_deg)), math.sin(math.radians(b.azimuth_deg))
    v = -sa * de + ca * dn
    normals, offsets, kinds = building_planes(b, base_m)
    roof = np.flatnonzero(kinds == 0)
    if len(roof) == 1:
        face = np.zeros(de.shape, np.intp)
    else:
        z = np.stack([(offsets[f] - normals[f, 0] * de - normals[f, 1] * dn) / normals[f, 2] for f in roof])
        face = np.argmin(z, axis=0)
    nn = normals[roof] / np.linalg.norm(normals[roof], axis=1, keepdims=True)
    lam = np.clip(nn @ sun, 0, None)
    light = (_AMBIENT + (1 - _AMBIENT) * lam / sun[2]).astype(np.float32)[face]
    h = hash2(int(round(b.e_m)), int(round(b.n_m)), s_seed)
    col, amp = _ROOF_MATERIALS[int(h) % len(_ROOF_MATERIALS)]
    period = max(4 * texel_m, 0.35 + 0.5 * ((int(h) >> 8) % 100) / 100)
    pattern = 1 + 0.5 * amp * np.sin(2 * np.pi * (np.abs(v) / period)) + 0.5 * np.asarray(grain, np.float64)
    return (_col(col, nch)[None, :] * (light * pattern)[:, None]).astype(np.float32)


def _paint_target(alb, te, tn, e0, n0, s) -> None:
    half = 1.5
    w = _window(te, tn, half, e0, n0, s, alb.shape[:2])
    if w is None:
        return
    rs, cs, de, dn = w
    sq = (np.abs(de) <= half) & (np.abs(dn) <= half)
    cross = ((np.abs(de) < 0.2) | (np.abs(dn) < 0.2)) & sq
    lum = np.where(cross, 0.8, 0.03)
    alb[rs, cs] = np.where(sq[..., None], lum[..., None].astype(np.float32), alb[rs, cs])
