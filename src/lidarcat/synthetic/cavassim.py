r"""The experiment of Cavassim (2005) on a synthetic town: three mapping products against known truth.

The paper's three products on a synthetic scene
of the paper's scale and density: a 1:6000 metric photo (c = 153.73 mm,
scanned at 25.4 um: 0.15 m pixels, 922 m above ground) and first-return
LiDAR of 2 points/m^2 (ALTM 2050: 1-4 points/m^2, 0.15 m height noise).  The
features are the outline corners of large flat-roofed buildings (eave height
6-12 m, up to 330 m from the nadir) and points on road edges; the reference
is their true plan position (the paper's 1:2000 map base).  The paper states
neither the buildings' heights nor where they lie in the photo: they are
arguments (``eave_m``, ``max_corner_radius_m``, building sizes).  A corner
at eave height h and horizontal distance r from the nadir leans
``L = h r / (H - h)`` (H = 922 m); a ray that leaves the roof there and is
not held by the surface lands L further out, so the paper's building
resultants (Tables 06-08: 0.24-0.44 m mean, 0.15 m sd; the largest of 36
near mean + 3 sd, 0.7-0.9 m) bound ``h r`` to about 630 m^2 -- eaves of
3-6 m within 100 m of the nadir (docs/mapping.md derives it and runs it;
``benchmarks/bench_cavassim.py`` sweeps h and r).

* *monorestitution* -- each point projected into the photo, pointing noise
  0.5 px, intersected (first hit) with the paper's surface, a DSM of the
  highest first return per cell (1 m cells,
  :func:`lidarcat.lidar.rasterize`), by the nearest neighbour (``nearest``:
  the cell's value) or the triangular plane (``tin``: a TIN of the cell
  centres); the photo's orientation carries the errors of an adjustment
  (0.05 m, 10 arc seconds), drawn once per photo.  The same on the LiDAR
  points themselves (``nearest_points``, ``tin_points``) shows why the paper's
  gridded first-return DSM matters for roof outlines: a TIN of the points
  ramps down from the last roof point to the first ground point, and a ray
  through a roof corner that moves outwards as it descends (3 of the 4
  corners of a roof seen off-nadir) runs off that ramp to the ground,
  eave height x tan(off-nadir) away; the highest-return grid widens the roof
  by up to a cell instead, so that such rays still meet the roof top;
* *digitising on the LiDAR images* -- the operator clicks on images
  rasterised at the point spacing (``1/sqrt(density)``): building corners on
  the first-pulse altimetry image (the paper's Table 03: the highest first
  return per cell; the roof cells are those above halfway between the lowest
  and the highest cell within 3 m), road edges on the first-pulse intensity
  image (Table 04: cells whose mean intensity is below the midpoint of
  asphalt and ground); a building corner is the cell corner of the roof
  region farthest out along the building's diagonal within 3 m of the true
  corner, a road edge point is the cell edge where the road region ends along
  the road's normal; then a pointing noise of 0.3 cell.  The image is
  orthogonal but its edges are only as sharp as its cells: the paper's
  explanation of why it is worse.

Also returned, per outline corner (``corners``, ``diagnosis``): whether its
ray leaves the roof as it descends (it then meets the roof only if the
surface holds the roof at the corner, else it falls to the ground one *lean*
= eave height x tan(off-nadir) further out), the lean, the off-nadir angle,
the plan and height errors of every product -- why the building figures are
what they are (docs/mapping.md).  The paper's iteration is run too, from the
ground below the camera (``*_iterate``) and from the top of the surface
(``*_iterate_top``).

The statistics of each product are
:func:`lidarcat.mapping.accuracy.assess_features`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import AssessmentError
from ..geometry.camera import Camera
from ..geometry.collinearity import project
from ..lidar import PointCloud
from ..lidar.raster import rasterize
from ..mapping.accuracy import assess_features
from ..mapping.monoplot import GridSurface, PointSurface, monoplot
from .scene import Building, Road, Scene

__all__ = ["cavassim_experiment", "CAVASSIM_TABLE_09", "CAVASSIM_TABLES_06_08", "paper_camera"]

#: Cavassim (2005) Table 09: r90 (m) by product and class
CAVASSIM_TABLE_09 = {
    "intensity_image": {"building": 0.88, "road": 0.77},
    "nearest": {"building": 0.60, "road": 0.38},
    "tin": {"building": 0.43, "road": 0.29},
}

#: Cavassim (2005) Tables 06 (image), 07 (nearest neighbour), 08 (triangular plane), m: per product and
#: class the mean and sd of dE, dN and of the resultant over the 36 building and 27 road points
CAVASSIM_TABLES_06_08 = {
    "intensity_image": {
        "building": {"mean_E": -0.093, "sd_E": 0.314, "mean_N": -0.205, "sd_N": 0.499,
                     "mean_resultant": 0.594, "sd_resultant": 0.194},
        "road": {"mean_E": -0.048, "sd_E": 0.449, "mean_N": -0.023, "sd_N": 0.405,
                 "mean_resultant": 0.564, "sd_resultant": 0.198}},
    "nearest": {
        "building": {"mean_E": 0.030, "sd_E": 0.329, "mean_N": 0.030, "sd_N": 0.331,
                     "mean_resultant": 0.437, "sd_resultant": 0.151},
        "road": {"mean_E": 0.007, "sd_E": 0.182, "mean_N": -0.015, "sd_N": 0.189,
                 "mean_resultant": 0.182, "sd_resultant": 0.120}},
    "tin": {
        "building": {"mean_E": -0.015, "sd_E": 0.207, "mean_N": 0.020, "sd_N": 0.199,
                     "mean_resultant": 0.244, "sd_resultant": 0.147},
        "road": {"mean_E": 0.019, "sd_E": 0.138, "mean_N": -0.016, "sd_N": 0.160,
                 "mean_resultant": 0.115, "sd_resultant": 0.100}},
}


def paper_camera() -> Camera:
    """The paper's photo: RC10, c = 153.73 mm, 23 x 23 cm scanned at 1000 dpi (25.4 um)."""
    return Camera("rc10", 153.73, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0254, 0.0254, 9055, 9055,
                  model="Wild RC10 (Cavassim 2005), scanned at 1000 dpi", source="Cavassim (2005) section 5")


def _town(rng: np.random.Generator, e0: float, n0: float, n_buildings: int, n_roads: int, *,
          eave_m: tuple[float, float] = (6.0, 12.0), length_m: tuple[float, float] = (30.0, 60.0),
          width_m: tuple[float, float] = (15.0, 25.0), max_corner_radius_m: float | None = None,
          nadir_en: tuple[float, float] | None = None, gap_m: float = 10.0) -> Any:
    """The synthetic town: *n_roads* straight roads through (e0, n0) and flat-roofed buildings off them.

    ``max_corner_radius_m`` None (the default experiment): building centres
    uniform in the 600 m square around (e0, n0), centres more than 45 m +
    the mean of the two lengths apart.  A number: every footprint corner
    within that distance of *nadir_en* (the camera's plan position), the
    footprints at least *gap_m* apart (separating-axis test: a lower bound of
    the distance between two rectangles).
    """
    roads = []
    for k in range(n_roads):
        a = math.radians(rng.uniform(0, 180))
        off = (k - (n_roads - 1) / 2) * 150.0
        c = np.array([e0 - off * math.sin(a), n0 + off * math.cos(a)])
        dvec = 350.0 * np.array([math.cos(a), math.sin(a)])
        roads.append(Road(*(c - dvec), *(c + dvec), float(rng.uniform(7, 12))))
    if max_corner_radius_m is not None and math.hypot(length_m[0], width_m[0]) / 2 > max_corner_radius_m:
        raise AssessmentError(f"no building of {length_m[0]:g}-{length_m[1]:g} x {width_m[0]:g}-{width_m[1]:g} m "
                              f"fits within {max_corner_radius_m:g} m of the nadir (half its diagonal is "
                              f"{math.hypot(length_m[0], width_m[0]) / 2:.1f} m at least)")
    cx, cy = nadir_en if nadir_en is not None else (e0, n0)
    buildings: list[Any] = []
    tries = 0
    # within a radius, random placement can jam (no room left for the last building): start again
    restarts = 0 if max_corner_radius_m is None else 20
    while len(buildings) < n_buildings and (tries < 5000 or restarts > 0):
        if tries == 5000:
            buildings, tries, restarts = [], 0, restarts - 1
        tries += 1
        if max_corner_radius_m is None:
            e, n = e0 + rng.uniform(-300, 300), n0 + rng.uniform(-300, 300)
        else:
            e = cx + rng.uniform(-max_corner_radius_m, max_corner_radius_m)
            n = cy + rng.uniform(-max_corner_radius_m, max_corner_radius_m)
        b = Building("flat", e, n, length_m=float(rng.uniform(*length_m)), width_m=float(rng.uniform(*width_m)),
                     eave_m=float(rng.uniform(*eave_m)), azimuth_deg=float(rng.uniform(0, 90)))
        fp = b.footprint()
        if max_corner_radius_m is not None:
            if np.hypot(fp[:, 0] - cx, fp[:, 1] - cy).max() > max_corner_radius_m:
                continue
            # a road must not pass under the building, at its corners, centre or between its corners
            edge = fp[[0, 1, 2, 3, 0]]
            t = np.linspace(0, 1, 41)[:, None, None]
            probe = np.vstack([(edge[:-1] + t * (edge[1:] - edge[:-1])).reshape(-1, 2), [[e, n]]])
            if any(r.contains(probe[:, 0], probe[:, 1]).any() for r in roads):
                continue
            # footprints gap_m apart (centres far enough apart for any orientation, or separated)
            if all(math.hypot(e - o.e_m, n - o.n_m) >= (math.hypot(b.length_m, b.width_m) + math.hypot(
                    o.length_m, o.width_m)) / 2 + gap_m or _rect_gap(fp, o.footprint()) >= gap_m for o in buildings):
                buildings.append(b)
            continue
        near_road = any(r.contains(fp[:, 0], fp[:, 1]).any() or r.contains(np.array([e]), np.array([n]))[0]
                        for r in roads)
        far = all(math.hypot(e - o.e_m, n - o.n_m) > 45 + (b.length_m + o.length_m) / 2 for o in buildings)
        if far and not near_road and not any(
                np.hypot(*(fp - np.array([r.e0_m, r.n0_m])).T).min() < 0 for r in roads):
            buildings.append(b)
    if max_corner_radius_m is not None and len(buildings) < n_buildings:
        raise AssessmentError(f"the town holds only {len(buildings)} of {n_buildings} buildings of "
                              f"{length_m[0]:g}-{length_m[1]:g} x {width_m[0]:g}-{width_m[1]:g} m within "
                              f"{max_corner_radius_m:g} m of the nadir, {gap_m:g} m apart, off the roads: "
                              "smaller buildings or a larger radius")
    return Scene(tuple(buildings), tuple(roads), seed=int(rng.integers(2**31)))


def _range_m(name: str, value: Any) -> tuple[float, float]:
    """*value* as a range (low, high) of lengths in m, 0 < low <= high; else an error naming *name*."""
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise AssessmentError(f"{name} must be a range (low, high) of finite lengths in m with 0 < low <= high, "
                              f"got {value!r}")
    return lo, hi


def _rect_gap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest gap (m) between the projections of two convex polygons on their edge normals.

    Zero or negative when they overlap; otherwise a lower bound of their
    distance (the separating-axis theorem), exact when an edge faces the other
    polygon.
    """
    gap = -math.inf
    for p in (a, b):
        d = np.roll(p, -1, axis=0) - p
        nrm = np.column_stack([-d[:, 1], d[:, 0]]) / np.hypot(d[:, 0], d[:, 1])[:, None]
        pa, pb = a @ nrm.T, b @ nrm.T
        gap = max(gap, float(np.max(np.maximum(pb.min(axis=0) - pa.max(axis=0), pa.min(axis=0) - pb.max(axis=0)))))
    return gap


def _road_points(scene: Any, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Points on road edges away from buildings and crossings, with the edge's outward normal."""
    pts, normals = [], []
    while len(pts) < n:
        r = scene.roads[int(rng.integers(len(scene.roads)))]
        a = np.array([r.e0_m, r.n0_m])
        u = np.array([r.e1_m, r.n1_m]) - a
        u /= np.linalg.norm(u)
        nrm = np.array([-u[1], u[0]]) * (1 if rng.uniform() < 0.5 else -1)
        p = a + rng.uniform(150, 550) * u + nrm * r.width_m / 2
        # keep edges whose neighbourhood (6 m) is this road and bare ground only
        probe = p + np.outer(np.linspace(-6, 6, 13), nrm)
        _, lab = scene.surface(probe[:, 0], probe[:, 1])
        if lab.max() > 1 or sum(o.contains(probe[:, 0], probe[:, 1]).any() for o in scene.roads) > 1:
            continue
        pts.append(p)
        normals.append(nrm)
    return np.array(pts), np.array(normals)


def _image_digitise(scene: Any, lidar: dict, corners: np.ndarray, outward: np.ndarray, road_pts: np.ndarray,
                    road_nrm: np.ndarray, cell: float, rng: np.random.Generator) -> np.ndarray:
    """Positions an operator digitises on the LiDAR images (module docstring), (N, 2)."""
    xyz, inten = lidar["xyz"], lidar["intensity"].astype(np.float64)
    x0, y0 = xyz[:, 0].min(), xyz[:, 1].max()
    col = np.floor((xyz[:, 0] - x0) / cell).astype(np.int64)
    row = np.floor((y0 - xyz[:, 1]) / cell).astype(np.int64)
    shape = (row.max() + 1, col.max() + 1)
    flat = row * shape[1] + col
    s = np.bincount(flat, inten, shape[0] * shape[1])
    c = np.bincount(flat, None, shape[0] * shape[1])
    with np.errstate(invalid="ignore"):
        img = (s / c).reshape(shape)
    # the first-pulse altimetry image (highest first return per cell; Table 03: large buildings are
    # digitised on it, "aparencia clara em relacao a vizinhanca")
    top = np.full(shape[0] * shape[1], -np.inf)
    np.maximum.at(top, flat, xyz[:, 2])
    top = top.reshape(shape)
    road = img < (250.0 + 900.0) / 2            # dark on the first-pulse intensity image: asphalt (Table 04)
    out = []
    for p, o in zip(corners, outward):
        r0, c0 = int((y0 - p[1]) / cell), int((p[0] - x0) / cell)
        k = int(math.ceil(3.0 / cell))
        rr, cc = np.mgrid[r0 - k:r0 + k + 1, c0 - k:c0 + k + 1]
        win = top[np.clip(rr, 0, shape[0] - 1), np.clip(cc, 0, shape[1] - 1)]
        seen = win[np.isfinite(win)]
        # bright = higher than halfway between the lowest and the highest cell around the corner
        m = win > 0.5 * (seen.min() + seen.max()) if seen.size else np.zeros(win.shape, dtype=bool)
        # the corners of the roof cells; the operator's corner: farthest out along the diagonal
        ce = np.concatenate([x0 + (cc[m] + dx) * cell for dx in (0, 1, 0, 1)])
        cn = np.concatenate([y0 - (rr[m] + dy) * cell for dy in (0, 0, 1, 1)])
        if ce.size == 0:
            out.append([np.nan, np.nan])
            continue
        score = (ce - p[0]) * o[0] + (cn - p[1]) * o[1]
        best = np.flatnonzero(score >= score.max() - 1e-9)
        j = best[np.argmin(np.hypot(ce[best] - p[0], cn[best] - p[1]))]
        out.append([ce[j], cn[j]])
    for p, nrm in zip(road_pts, road_nrm):
        t = np.arange(-4.0, 4.0, cell / 8)
        q = p + np.outer(t, nrm)
        r = np.floor((y0 - q[:, 1]) / cell).astype(np.int64)
        cidx = np.floor((q[:, 0] - x0) / cell).astype(np.int64)
        on = road[np.clip(r, 0, shape[0] - 1), np.clip(cidx, 0, shape[1] - 1)]
        # the last road sample going outwards from inside the road, before the first non-road one
        inside = np.flatnonzero(on & (t < 0))
        if inside.size == 0:
            out.append([np.nan, np.nan])
            continue
        j = inside[-1]
        while j + 1 < len(on) and on[j + 1]:
            j += 1
        out.append(q[j] + nrm * cell / 16)
    return np.asarray(out) + rng.normal(0, 0.3 * cell, (len(out), 2))


def cavassim_experiment(*, seed: int = 0, density_m2: float = 2.0, n_buildings: int = 9, n_road_points: int = 27,
                        image_sd_px: float = 0.5, inward_px: float = 0.0, lidar_noise_m: float = 0.15,
                        lidar_plan_sd_m: float = 0.0,
                        dsm_cell_m: float | None = 1.0, scale: float = 2000.0,
                        e0: float = 680_400.0, n0: float = 7_184_200.0,
                        eave_m: tuple[float, float] = (6.0, 12.0), max_corner_radius_m: float | None = None,
                        building_length_m: tuple[float, float] = (30.0, 60.0),
                        building_width_m: tuple[float, float] = (15.0, 25.0),
                        building_gap_m: float = 10.0, all_products: bool = True) -> dict[str, Any]:
    """The paper's comparison on a synthetic town (module docstring).

    Parameters
    ----------
    seed : int
    density_m2 : float
        LiDAR points per m^2.
    n_buildings : int
        Buildings (4 outline corners each: the paper has 36 building points).
    n_road_points : int
        Road edge points (the paper: 27).
    image_sd_px : float
        Pointing sd on the photo, px.
    inward_px : float
        The operator's click on a building corner moved this far (px) into the
        roof along the corner's diagonal (0: on the corner; docs/mapping.md
        shows how much the building figures depend on it).
    lidar_noise_m : float
        LiDAR height noise, m.
    lidar_plan_sd_m : float
        LiDAR planimetric error (m, the sd of the horizontal position error,
        sd / sqrt(2) per axis, independent per point): the point is recorded
        this far from where its height was measured (Table 01 states "50 cm
        na planimetria" for the ALTM 2050; default 0: docs/mapping.md shows
        the sensitivity).
    scale : float
        Map scale of the PEC class.
    dsm_cell_m : float, optional
        Cell of the first-return DSM (default 1 m; None: the point spacing).
    e0, n0 : float
        Centre of the synthetic town, m.
    eave_m : (float, float)
        Range of the buildings' eave heights above their base, m (uniform;
        default 6-12 m).
    max_corner_radius_m : float, optional
        Largest horizontal distance (m) of a building outline corner from the
        photo's nadir (the camera's plan position).  None (default): building
        centres uniform in the 600 m square around (e0, n0), whose corners lie
        up to ~330 m from the nadir.  A number: the camera is drawn first and
        every corner placed within this radius of its nadir (a building's
        lean at a corner, eave height x radius / flying height, is bounded by
        ``eave_m[1] * max_corner_radius_m / (922 - eave_m[1])``).
    building_length_m, building_width_m : (float, float)
        Ranges of the flat roofs' footprint length and width, m.
    building_gap_m : float
        With *max_corner_radius_m*: the least distance between two footprints, m.
    all_products : bool
        False: only the paper's three products (``intensity_image``,
        ``nearest``, ``tin``; the same figures, in about a fifth of the time).

    Returns
    -------
    dict
        ``tables``: ``{product: assess_features(...)}`` for ``intensity_image``,
        ``nearest``, ``tin``, ``nearest_points``, ``tin_points``,
        ``nearest_iterate``, ``tin_iterate``, ``nearest_iterate_top``,
        ``tin_iterate_top``; ``r90``: ``{product: {class: r90}}`` (Table 09);
        ``status``: monoplot status counts per product; ``corners``: per
        building corner ``leaving`` (bool), ``lean_m``, ``off_nadir_deg``,
        ``error_m`` and ``h_error_m`` (m, per product; NaN where not placed),
        ``eave_m`` (the building's eave height) and ``radius_m`` (horizontal
        distance from the nadir);
        ``diagnosis``: per product and corner kind (``leaving``,
        ``entering``) n, median and max plan error (m) and the corners whose
        hit is within 1 m of the roof height (``on_roof``); ``setup``: the
        numbers used.

    Raises
    ------
    AssessmentError
        *n_buildings* buildings do not fit within *max_corner_radius_m* of
        the nadir (the message names the sizes, radius and gap); a scene
        parameter is not as documented (a range reversed, not positive or
        not finite; a radius <= 0; a gap < 0): the message names it.
    """
    town = {"eave_m": _range_m("eave_m", eave_m), "length_m": _range_m("building_length_m", building_length_m),
            "width_m": _range_m("building_width_m", building_width_m), "gap_m": float(building_gap_m)}
    if not (math.isfinite(town["gap_m"]) and town["gap_m"] >= 0):
        raise AssessmentError(f"building_gap_m must be a finite distance >= 0 m, got {building_gap_m!r}")
    if max_corner_radius_m is not None and not (math.isfinite(max_corner_radius_m) and max_corner_radius_m > 0):
        raise AssessmentError(f"max_corner_radius_m must be a finite distance > 0 m (or None), "
                              f"got {max_corner_radius_m!r}")
    rng = np.random.default_rng(seed)
    cam = paper_camera()
    h_ground = float(Scene().terrain(np.array([e0]), np.array([n0]))[0])

    def camera() -> np.ndarray:
        return np.array([e0 + rng.normal(0, 20), n0 + rng.normal(0, 20), h_ground + 922.0,
                         math.radians(rng.normal(0, 1)), math.radians(rng.normal(0, 1)), rng.uniform(0, 2 * np.pi)])

    if max_corner_radius_m is None:            # the default experiment: the town first (its draws unchanged)
        scene = _town(rng, e0, n0, n_buildings, 3, **town)
        eo_true = camera()
    else:                                      # the camera first, the buildings around its nadir
        eo_true = camera()
        scene = _town(rng, e0, n0, n_buildings, 3, max_corner_radius_m=max_corner_radius_m,
                      nadir_en=(float(eo_true[0]), float(eo_true[1])), **town)
    eo_err = np.concatenate([rng.normal(0, 0.05, 3), rng.normal(0, math.radians(10 / 3600), 3)])
    # features: building outline corners (eave height) and road edge points
    corners, outward, cls = [], [], []
    for i, b in enumerate(scene.buildings):
        c = b.eave_corners(scene.base_height(i))
        ctr = np.array([b.e_m, b.n_m])
        for p in c:
            corners.append(p)
            o = p[:2] - ctr
            outward.append(o / np.linalg.norm(o))
            cls.append("building")
    corners_a, outward_a = np.array(corners), np.array(outward)
    road_pts, road_nrm = _road_points(scene, rng, n_road_points)
    road_h = scene.terrain(road_pts[:, 0], road_pts[:, 1])
    truth = np.vstack([corners_a, np.column_stack([road_pts, road_h])])
    cls += ["road"] * len(road_pts)
    # LiDAR in 50 m squares around the features (the surface is only needed there)
    parts = [scene.lidar_points((p[0] - 25, p[1] - 25, p[0] + 25, p[1] + 25), density_m2, noise_m=lidar_noise_m,
                                seed=seed + 1 + k) for k, p in enumerate(truth)]
    lidar = {key: np.concatenate([q[key] for q in parts]) for key in parts[0]}
    if lidar_plan_sd_m:
        lidar["xyz"][:, :2] += rng.normal(0, lidar_plan_sd_m / math.sqrt(2), (len(lidar["xyz"]), 2))
    xy, _ = project(np.broadcast_to(eo_true, (len(truth), 6)), truth, np.full(len(truth), cam.focal_length_mm))
    px = cam.photo_to_pixel(xy)
    # the operator clicks on the roof: building corners inward along their diagonal by inward_px
    if inward_px:
        inner = truth[:len(corners_a)].copy()
        inner[:, :2] -= outward_a * 0.01
        xy_in, _ = project(np.broadcast_to(eo_true, (len(inner), 6)), inner, np.full(len(inner), cam.focal_length_mm))
        dirn = px[:len(inner)] - cam.photo_to_pixel(xy_in)
        dirn /= np.linalg.norm(dirn, axis=1, keepdims=True)
        px[:len(inner)] -= inward_px * dirn
    px = px + rng.normal(0, image_sd_px, (len(truth), 2))
    eo_used = eo_true + eo_err
    cov = np.diag(np.r_[np.full(3, 0.05), np.full(3, math.radians(10 / 3600))] ** 2)
    tables, r90, measured = {}, {}, {}
    cell = 1.0 / math.sqrt(density_m2)
    # the paper's surface: a DSM of the highest first return per cell (cell = point spacing)
    cloud = PointCloud(lidar["xyz"], {k: lidar[k] for k in ("intensity", "return_number", "number_of_returns",
                                                               "classification")})
    grid, gt = rasterize(cloud, dsm_cell_m or cell, "dsm", fill="small")
    rr, cc = np.nonzero(np.isfinite(grid))
    ce, cn = gt.xy(rr, cc)
    dsm_points = np.column_stack([ce, cn, grid[rr, cc]])
    surfaces = {
        "nearest": GridSurface(grid, gt, "nearest", sd_m=lidar_noise_m),          # paper: vizinho mais proximo
        "tin": PointSurface(dsm_points, "tin", sd_m=lidar_noise_m),               # paper: superficie plana
    }
    if all_products:
        surfaces["nearest_points"] = PointSurface(lidar["xyz"], "nearest", sd_m=lidar_noise_m)
        surfaces["tin_points"] = PointSurface(lidar["xyz"], "tin", sd_m=lidar_noise_m)
    status, heights = {}, {}
    runs = [(name, surf, "exact", "nadir") for name, surf in surfaces.items()]
    runs += [(f"{name}_iterate{'_top' if start == 'top' else ''}", surfaces[name], "iterate", start)
             for start in ("nadir", "top") for name in ("nearest", "tin") if all_products]
    for name, surf, method, start in runs:
        res = monoplot(px, cam, eo_used, surf, method=method, image_sd_px=image_sd_px, eo_cov=cov, start=start)
        measured[name] = res.enh[:, :2]
        heights[name] = res.enh[:, 2]
        status[name] = res.counts()
    measured["intensity_image"] = _image_digitise(scene, lidar, corners_a, outward_a, road_pts, road_nrm, cell, rng)
    products = ("intensity_image", *(r[0] for r in runs))
    for prod in products:
        d = truth[:, :2] - measured[prod]
        tables[prod] = assess_features(d, cls, scale=scale)
        r90[prod] = {c: t["r90_m"] for c, t in tables[prod].items()}
    corners_info = _corner_geometry(scene, eo_true, corners_a)
    nb = len(corners_a)
    diagnosis = {}
    for prod in products:
        err = np.hypot(*(truth[:nb, :2] - measured[prod][:nb]).T)
        on_roof = (np.abs(heights[prod][:nb] - truth[:nb, 2]) < 1.0) if prod in heights else None
        diagnosis[prod] = {}
        for key, sel in (("leaving", corners_info["leaving"]), ("entering", ~corners_info["leaving"])):
            e = err[sel]
            e = e[np.isfinite(e)]                   # corners the product placed
            diagnosis[prod][key] = {
                "n": int(sel.sum()), "median_error_m": float(np.median(e)) if e.size else math.nan,
                "max_error_m": float(np.max(e)) if e.size else math.nan,
                "on_roof": None if on_roof is None else int(on_roof[sel].sum())}
    gsd = cam.pixel_size_x_mm * 922.0 / cam.focal_length_mm
    return {"tables": tables, "r90": r90, "status": status, "diagnosis": diagnosis, "corners": {
        "leaving": corners_info["leaving"], "lean_m": corners_info["lean_m"], "off_nadir_deg":
        corners_info["off_nadir_deg"], "error_m": {p: np.hypot(*(truth[:nb, :2] - measured[p][:nb]).T)
                                                  for p in products},
        "h_error_m": {p: heights[p][:nb] - truth[:nb, 2] for p in heights},
        "eave_m": np.repeat([b.eave_m for b in scene.buildings], 4),
        "radius_m": np.hypot(corners_a[:, 0] - eo_true[0], corners_a[:, 1] - eo_true[1])}, "setup": {
        "seed": seed, "density_m2": density_m2, "lidar_noise_m": lidar_noise_m, "n_buildings": len(scene.buildings),
        "n_building_points": int(len(corners_a)), "n_road_points": int(len(road_pts)), "photo_gsd_m": gsd,
        "image_sd_px": image_sd_px, "intensity_cell_m": cell, "flying_height_m": 922.0, "scale": scale,
        "lidar_plan_sd_m": lidar_plan_sd_m, "eave_m": town["eave_m"], "max_corner_radius_m": max_corner_radius_m,
        "building_length_m": town["length_m"], "building_width_m": town["width_m"],
        "building_gap_m": town["gap_m"]}}


def _corner_geometry(scene: Any, eo: np.ndarray, corners: np.ndarray) -> dict[str, np.ndarray]:
    """Per roof-outline corner: does the ray leave the roof below the corner, the lean, the off-nadir angle.

    ``leaving``: 0.5 m below the corner along the ray from the projection
    centre the ray is outside the building's footprint -- it can only meet the
    roof AT the corner and otherwise falls to the ground ``lean_m`` further
    out (eave height above the base x the ray's horizontal / vertical ratio);
    ``entering``: it passes under the roof and meets the (visible) wall.
    """
    out_leave, lean, off = [], [], []
    for k, p in enumerate(corners):
        b = scene.buildings[k // 4]
        d = p - eo[:3]
        ratio = math.hypot(d[0], d[1]) / abs(d[2])
        q = p + d * (0.5 / abs(d[2]))
        u, v = b.to_local(np.array([q[0]]), np.array([q[1]]))
        out_leave.append(not (abs(u[0]) < b.length_m / 2 and abs(v[0]) < b.width_m / 2))
        lean.append(b.eave_m * ratio)
        off.append(math.degrees(math.atan(ratio)))
    return {"leaving": np.array(out_leave), "lean_m": np.array(lean), "off_nadir_deg": np.array(off)}
