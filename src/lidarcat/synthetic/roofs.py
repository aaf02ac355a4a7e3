"""Synthetic buildings with known roof vertices, sampled like an airborne scanner.

Roof types (building frame: *u* along the length, *v* across, origin at the
centre of the footprint; the frame is rotated by ``azimuth_deg`` and moved to
``origin``):

===========  ===================================================================
``gable``    two faces and a ridge along *u*; no 3-plane vertex
``hip``      four faces; two vertices at the ridge ends, 3 planes each
``pyramid``  square hip roof; one apex of 4 planes
``lgable``   L-shaped gable: two wings whose ridges meet over the corner in a
             vertex of 4 planes with valleys between the wings
``flat``     horizontal roof (degenerate case)
===========  ===================================================================

Optional details: a **chimney** (0.8 m box, 1 m above the roof, flat top),
a **dormer** (small gable standing out of a face, whose ridge meets the main
face in a 3-plane valley vertex), **walls** (sampled on the facades facing the
scanner with density ``density * tan(scan angle)``), an **overhanging tree**
(ellipsoid canopy; 70 % of its rays return from the canopy) and **ground**.

The scanner: scan lines across the flight (heading = building *v* axis by
default) with the nominal point spacing ``1 / sqrt(density)``, a per-line
random shift and jitter; the nadir line is 150 m to the side (scan angle ~ 9
deg at 1000 m).  Heights get Gaussian noise ``noise_h_m`` and positions
``noise_plan_m``; a second strip (``strips=2``) comes from the other side with
a systematic offset ``strip_offset_m`` (E, N, h).

Everything is seeded: the same arguments give the same points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._util.frozen import frozen_array

__all__ = ["SyntheticScene", "synthetic_roof", "roof_height", "LABELS", "KINDS"]

#: point labels of a scene
LABELS = {"ground": 0, "roof": 1, "wall": 2, "chimney": 3, "tree": 4, "dormer": 5}
KINDS = ("gable", "hip", "pyramid", "lgable", "flat")


@dataclass(frozen=True, eq=False)
class SyntheticScene:
    """Points of a synthetic building with its true vertices.

    Attributes
    ----------
    xyz : (N, 3) float
        E, N, h (m).
    label : (N,) int
        :data:`LABELS` code of every point.
    strip : (N,) int
        Strip number (0 or 1).
    vertices : (V, 3) float
        True roof vertices where 3+ planes meet (E, N, h), main vertex first.
    vertex_planes : (V,) int
        Number of planes meeting at each vertex.
    kind : str
    slope_deg : float
    """

    xyz: np.ndarray
    label: np.ndarray
    strip: np.ndarray
    vertices: np.ndarray
    vertex_planes: np.ndarray
    kind: str
    slope_deg: float

    def __post_init__(self) -> None:
        for name in ("xyz", "label", "strip", "vertices", "vertex_planes"):
            object.__setattr__(self, name, frozen_array(getattr(self, name), dtype=None))


def roof_height(kind: str, u: np.ndarray, v: np.ndarray, L: float, W: float, t: float, eave: float):
    """Main roof height in the building frame; NaN outside the footprint."""
    z = np.full(u.shape, np.nan)
    if kind == "lgable":
        a = (u >= -W / 2) & (u <= L - W / 2) & (np.abs(v) <= W / 2)
        b = (v >= -W / 2) & (v <= L - W / 2) & (np.abs(u) <= W / 2)
        za = np.where(a, eave + t * (W / 2 - np.abs(v)), -np.inf)
        zb = np.where(b, eave + t * (W / 2 - np.abs(u)), -np.inf)
        zz = np.maximum(za, zb)
        z[a | b] = zz[a | b]
        return z
    inside = (np.abs(u) <= L / 2) & (np.abs(v) <= W / 2)
    if kind == "gable":
        zz = eave + t * (W / 2 - np.abs(v))
    elif kind in ("hip", "pyramid"):
        zz = eave + t * np.minimum(W / 2 - np.abs(v), L / 2 - np.abs(u))
    elif kind == "flat":
        zz = np.full(u.shape, eave)
    else:
        raise ValueError(f"unknown roof kind {kind!r}; choose one of {', '.join(KINDS)}")
    z[inside] = zz[inside]
    return z


def _footprint_edges(kind: str, L: float, W: float) -> list[tuple[np.ndarray, np.ndarray]]:
    if kind == "lgable":
        pts = [(-W / 2, -W / 2), (L - W / 2, -W / 2), (L - W / 2, W / 2), (W / 2, W / 2),
               (W / 2, L - W / 2), (-W / 2, L - W / 2)]
    else:
        pts = [(-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, W / 2), (-L / 2, W / 2)]
    pts = [np.array(p, dtype=float) for p in pts]
    return [(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]


def synthetic_roof(
    kind: str = "hip",
    *,
    slope_deg: float = 30.0,
    length_m: float = 14.0,
    width_m: float = 9.0,
    eave_m: float = 6.0,
    azimuth_deg: float = 17.0,
    density_m2: float = 4.0,
    noise_h_m: float = 0.05,
    noise_plan_m: float = 0.03,
    origin: Any = (677000.0, 7183000.0, 900.0),
    chimney: bool = False,
    dormer: bool = False,
    walls: bool = True,
    tree: bool = False,
    ground: bool = True,
    strips: int = 1,
    strip_offset_m: Any = (0.10, -0.05, 0.05),
    margin_m: float = 3.0,
    seed: int | None = 0,
) -> SyntheticScene:
    """Sample one synthetic building like an airborne laser scanner.

    Parameters
    ----------
    kind : {"gable", "hip", "pyramid", "lgable", "flat"}
    slope_deg : float
        Slope of every main face (deg).
    length_m, width_m : float
        Footprint (pyramid: ``length_m`` is ignored, the footprint is square).
        ``lgable``: each wing is ``length_m`` long and ``width_m`` wide.
    eave_m : float
        Eave height above the ground (m).
    azimuth_deg : float
        Rotation of the building's *u* axis from East, counter-clockwise (deg).
    density_m2 : float
        Nominal point density (points / m^2), 1-16 typical.
    noise_h_m, noise_plan_m : float
        Gaussian noise of heights and of plan positions (m).
    origin : (3,) float
        E, N, h of the footprint centre at ground level.
    chimney, dormer, walls, tree, ground : bool
        Details to include.
    strips : {1, 2}
        Second strip from the other side, shifted by ``strip_offset_m``.
    margin_m : float
        Ground margin around the footprint (m).
    seed : int or None

    Returns
    -------
    SyntheticScene

    Raises
    ------
    ValueError
        Unknown *kind*, non-positive density, *strips* not 1 or 2, a hip roof
        not longer than wide.

    Examples
    --------
    >>> s = synthetic_roof("pyramid", width_m=10, slope_deg=30, origin=(0, 0, 0), seed=3)
    >>> np.round(s.vertices, 3).tolist(), s.vertex_planes.tolist()
    ([[0.0, 0.0, 8.887]], [4])
    >>> bool(3.0 < (s.label == 1).sum() / 100.0 < 5.0)   # ~4 pts/m2 on 100 m2 of roof
    True
    """
    if kind not in KINDS:
        raise ValueError(f"unknown roof kind {kind!r}; choose one of {', '.join(KINDS)}")
    if density_m2 <= 0:
        raise ValueError("density_m2 must be positive")
    if strips not in (1, 2):
        raise ValueError(f"strips must be 1 or 2, got {strips!r}")
    rng = np.random.default_rng(seed)
    W = float(width_m)
    L = W if kind == "pyramid" else float(length_m)
    if kind == "hip" and L <= W:
        raise ValueError("a hip roof needs length_m > width_m (equal sides make a pyramid)")
    t = 0.0 if kind == "flat" else math.tan(math.radians(slope_deg))
    eave = float(eave_m)
    ox, oy, oz = (float(v) for v in origin)
    ca, sa = math.cos(math.radians(azimuth_deg)), math.sin(math.radians(azimuth_deg))

    def to_world(u, v):
        return ox + ca * u - sa * v, oy + sa * u + ca * v

    def to_local(x, y):
        dx, dy = x - ox, y - oy
        return ca * dx + sa * dy, -sa * dx + ca * dy

    # ------------------------------------------------------------ details
    chim = None
    if chimney:
        cu = -0.25 * L if kind != "lgable" else 0.5 * L
        cv = -0.3 * W
        chim = (cu, cv, 0.4, float(roof_height(kind, np.array([cu]), np.array([cv]), L, W, t, eave)[0]) + 1.0)
    dorm = None
    if dormer:
        # on the long face of the +v side (hip, pyramid: the middle of it, clear of the hips)
        du = {"gable": 0.22 * L, "lgable": 0.55 * L}.get(kind, 0.0)
        dw = 2.4  # dormer width (m)
        v0 = 0.25 * W  # the dormer ridge joins the main face here
        zr = eave + t * (W / 2 - v0)
        td = math.tan(math.radians(max(slope_deg, 25.0)))
        dorm = (du, dw, v0, zr, td)

    vertices: list[tuple[float, float, float, int]] = []
    if kind == "hip":
        zt = eave + t * W / 2
        for s in (-1, 1):
            vertices.append((s * (L / 2 - W / 2), 0.0, zt, 3))
    elif kind == "pyramid":
        vertices.append((0.0, 0.0, eave + t * W / 2, 4))
    elif kind == "lgable":
        vertices.append((0.0, 0.0, eave + t * W / 2, 4))
    if dorm is not None:
        du, dw, v0, zr, td = dorm
        vertices.append((du, v0, zr, 3))

    def height(u, v):
        z = roof_height(kind, u, v, L, W, t, eave)
        lab = np.where(np.isfinite(z), LABELS["roof"], LABELS["ground"])
        if dorm is not None:
            du, dw, v0, zr, td = dorm
            inb = (np.abs(u - du) <= dw / 2) & (v >= v0) & (v <= W / 2 - 0.3) & np.isfinite(z)
            zd = zr - td * np.abs(u - du)
            up = inb & (zd > z)
            z = np.where(up, zd, z)
            lab = np.where(up, LABELS["dormer"], lab)
        if chim is not None:
            cu, cv, hw, zc = chim
            inc = (np.abs(u - cu) <= hw) & (np.abs(v - cv) <= hw)
            z = np.where(inc, zc, z)
            lab = np.where(inc, LABELS["chimney"], lab)
        return z, lab

    # ------------------------------------------------------------ scan
    spacing = 1.0 / math.sqrt(density_m2)
    edges = _footprint_edges(kind, L, W)
    corners = np.array([e[0] for e in edges])
    wx, wy = to_world(corners[:, 0], corners[:, 1])
    xmin, xmax = wx.min() - margin_m, wx.max() + margin_m
    ymin, ymax = wy.min() - margin_m, wy.max() + margin_m
    flying_h = 1000.0
    all_xyz, all_lab, all_strip = [], [], []
    for k in range(strips):
        side = 1.0 if k == 0 else -1.0
        nadir_x = (ox + side * 150.0)  # flight along N, nadir line at this E
        ys = np.arange(ymin, ymax, spacing)
        ys = ys + rng.uniform(0, spacing, size=len(ys))[0]
        xs0 = np.arange(xmin, xmax, spacing)
        gx = xs0[None, :] + rng.uniform(0, spacing, size=(len(ys), 1))
        gy = ys[:, None] + 0.0 * gx
        # zig-zag scan lines: the along-track position drifts across the swath
        gy = gy + 0.5 * spacing * ((gx - xmin) / (xmax - xmin + 1e-9))
        gx = gx + rng.normal(0, 0.08 * spacing, gx.shape)
        gy = gy + rng.normal(0, 0.08 * spacing, gy.shape)
        x = gx.ravel()
        y = gy.ravel()
        keep = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        x, y = x[keep], y[keep]
        u, v = to_local(x, y)
        z, lab = height(u, v)
        z = np.where(np.isfinite(z), z, 0.0)
        if not ground:
            sel = lab != LABELS["ground"]
            x, y, z, lab = x[sel], y[sel], z[sel], lab[sel]
        if tree:
            tu, tv, rad = (L / 2 if kind != "lgable" else L - W / 2), W / 2 + 0.5, 3.0
            tx, ty = to_world(np.array([tu]), np.array([tv]))
            r2 = (x - tx[0]) ** 2 + (y - ty[0]) ** 2
            inside = r2 < rad**2
            ztop = eave + 2.5 + 1.5 * np.sqrt(np.maximum(1 - r2 / rad**2, 0.0))
            hit = inside & (rng.uniform(size=len(x)) < 0.7)
            depth = rng.uniform(0, 1.5, size=len(x))
            z = np.where(hit, np.maximum(ztop - depth, z), z)
            lab = np.where(hit, LABELS["tree"], lab)
        pts = [np.column_stack([x, y, z])]
        labs = [lab]
        if walls:
            # facades facing the scanner receive density * tan(scan angle) points per m2
            segs = list(edges)
            if chim is not None:
                cu, cv, hw, _ = chim
                c4 = [np.array(p) for p in ((cu - hw, cv - hw), (cu + hw, cv - hw),
                                            (cu + hw, cv + hw), (cu - hw, cv + hw))]
                segs += [(c4[i], c4[(i + 1) % 4]) for i in range(4)]
            for si, (a_l, b_l) in enumerate(segs):
                ax, ay = to_world(np.array([a_l[0]]), np.array([a_l[1]]))
                bx, by = to_world(np.array([b_l[0]]), np.array([b_l[1]]))
                a_w = np.array([ax[0], ay[0]])
                b_w = np.array([bx[0], by[0]])
                seg = b_w - a_w
                length = float(np.hypot(*seg))
                normal = np.array([seg[1], -seg[0]]) / length  # outward for ccw polygons
                mid = 0.5 * (a_w + b_w)
                to_scan = np.array([nadir_x - mid[0], 0.0])
                facing = float(normal @ to_scan) > 0
                if not facing:
                    continue
                tan_th = abs(mid[0] - nadir_x) / flying_h
                cos_inc = abs(normal[0])
                dens = density_m2 * tan_th * cos_inc
                s = rng.uniform(0, 1, size=max(1, int(rng.poisson(dens * length * (eave + 2.0)))))
                pw = a_w[None, :] + s[:, None] * seg[None, :]
                # the wall top follows the roof edge just inside the footprint
                inward = pw - 0.02 * normal[None, :]
                ui, vi = to_local(inward[:, 0], inward[:, 1])
                ztop, _ = height(ui, vi)
                ztop = np.where(np.isfinite(ztop), ztop, eave)
                zb = 0.0
                if si >= len(edges):  # chimney sides stand on the roof
                    zb = ztop - 1.0
                zw = zb + rng.uniform(0, 1, size=len(s)) * (ztop - zb)
                pw = pw + 0.01 * normal[None, :]
                pts.append(np.column_stack([pw, zw]))
                labs.append(np.full(len(s), LABELS["wall"]))
        xyz = np.vstack(pts)
        lab = np.concatenate(labs)
        xyz[:, 2] += oz + rng.normal(0, noise_h_m, len(xyz))
        xyz[:, :2] += rng.normal(0, noise_plan_m, (len(xyz), 2))
        if k == 1:
            xyz += np.asarray(strip_offset_m, dtype=float)
        all_xyz.append(xyz)
        all_lab.append(lab)
        all_strip.append(np.full(len(xyz), k))
    if vertices:
        va = np.array(vertices)
        vx, vy = to_world(va[:, 0], va[:, 1])
        verts = np.column_stack([vx, vy, va[:, 2] + oz])
        vp = va[:, 3].astype(int)
    else:
        verts = np.zeros((0, 3))
        vp = np.zeros(0, dtype=int)
    return SyntheticScene(np.vstack(all_xyz), np.concatenate(all_lab), np.concatenate(all_strip),
                          verts, vp, kind, float(slope_deg))
