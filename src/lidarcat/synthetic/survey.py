"""A synthetic survey with known truth: ``lidarcat demo synthetic``.

:func:`write_synthetic_survey` writes a complete survey folder, the end-to-end
test of the whole tool:

* ``camera.toml`` -- a 36 x 24 mm frame camera (6000 x 4000 px of 6 um,
  c = 35 mm) with radial and decentering distortion, so that the interior
  orientation (eq. 01-07) matters;
* ``photos.csv`` -- a block of one or two strips at 60 % forward and 30 % side
  overlap, 700 m above a rolling terrain (the second strip flown the other way,
  kappa ~ 180 deg); the true orientations are in ``truth/eop.csv``;
* ``image_points.csv`` -- pixel measurements (noise ``image_sd_px``) of tie
  points, GPS points and roof vertices, projected by the collinearity equations
  (eq. 08) and the camera's inverse distortion model;
* ``ground_points.csv`` -- the GPS points with their standard deviations (the
  coordinates carry that noise); ``control_sets.csv`` -- the ``gps`` run:
  corner and centre points are control, and in a long block also chains
  across the strips every 4 bases; the others check;
* ``lidar/*.laz`` -- airborne-LiDAR tiles sampled from the terrain and the
  buildings of :mod:`lidarcat.synthetic.roofs` (pyramid and hip roofs, known vertices);
* ``jobs.csv`` -- extraction jobs: one roof vertex per building, at an
  approximate position ``approx_error_m`` (1 m, from 0.5x to 1.5x) off in plan,
  in a random direction, as an operator would click it, with the noise of the
  LiDAR points (``sd_en_m``, ``sd_h_m``) that weights the plane fits;
* ``survey.toml`` -- ties it together (observations in pixels, image sd);
* ``truth/`` -- true exterior orientations, true coordinates of every point
  (tie, gps, roof) and the true roof vertices, with a README.

``lidarcat run DIR`` then extracts the roof vertices, adjusts the block once
with GPS control and once with the extracted LiDAR control, and assesses both
on the GPS check points: the orientations and points must agree with
``truth/`` within the precision the adjustment reports.

Every random draw comes from ``numpy.random.default_rng(seed)``: the same seed
writes byte-identical CSV files.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, write_csv_atomic, write_text_atomic
from ..geometry.collinearity import project
from ..geometry.camera import Camera
from ..errors import LidarcatError
from . import roofs as _roofs  # the roof generator of the roof-extraction issue
from ._photo import AerialScene, Exposure, render_photo
from .scene import DEMO_GROUND_M, DEMO_ORIGIN_EN, Building, demo_terrain

__all__ = ["DemoSurvey", "write_synthetic_survey", "compare_with_truth", "demo_camera", "project_points",
           "DEMO_CRS"]

log = logging.getLogger(__name__)

#: SIRGAS 2000 / UTM zone 22 S, the CRS of the synthetic survey (and its tiles)
DEMO_CRS = "EPSG:31982"

_E0, _N0 = DEMO_ORIGIN_EN
#: above this many LiDAR points the terrain is sampled around the buildings only
_MAX_BLOCK_POINTS = 12_000_000
_GROUND_M = DEMO_GROUND_M
#: plan noise of the LiDAR points (m); written with the height noise into jobs.csv,
#: so that the plane fits weight the points by the noise they really carry
_LIDAR_PLAN_SD_M = 0.03


@dataclasses.dataclass(frozen=True)
class DemoSurvey:
    """What :func:`write_synthetic_survey` wrote.

    Attributes
    ----------
    path : Path
        The survey folder (``lidarcat run PATH``).
    n_photos, n_tie, n_gps, n_roofs, n_lidar_points : int
        Sizes of the block.
    seed : int
        Seed of the random generator.
    image_sd_px, gps_sd_m : float
        Noise levels used (pixel measurements; GPS E, N and h).
    files : tuple of str
        Every file written, relative to *path*.
    """

    path: Path
    n_photos: int
    n_tie: int
    n_gps: int
    n_roofs: int
    n_lidar_points: int
    seed: int
    image_sd_px: float
    gps_sd_m: float
    files: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["path"] = str(self.path)
        return d


def demo_camera() -> Camera:
    """The camera of the synthetic survey: c = 35 mm, 6000 x 4000 px of 6 um.

    >>> cam = demo_camera()
    >>> cam.frame_size_mm
    (36.0, 24.0)
    """
    return Camera(
        "demo", 35.0, 0.012, -0.018,
        -2.5e-5, 1.0e-8, 0.0, 2.0e-6, -1.0e-6, 0.0,
        0.006, 0.006, 6000, 4000,
        model="synthetic 36 x 24 mm frame camera",
        source="lidarcat.synthetic.survey (synthetic, known truth)",
    )


def project_points(points_m: np.ndarray, eo: Sequence[float], focal_length_mm: float) -> np.ndarray:
    """Collinearity equations (eq. 08): ground points -> corrected photo coordinates.

    Parameters
    ----------
    points_m : (N, 3) array
        E, N, h of the points, m.
    eo : sequence of 6 floats
        X0, Y0, Z0 (m), omega, phi, kappa (rad); M = R3(kappa) R2(phi) R1(omega).
    focal_length_mm : float
        Principal distance c, mm.

    Returns
    -------
    (N, 2) array
        x, y in mm (x right, y up; origin at the principal point); NaN for
        points behind the camera.

    >>> xy = project_points(np.array([[10.0, 0.0, 0.0]]), [0, 0, 1000.0, 0, 0, 0], 50.0)
    >>> np.round(xy, 6)
    array([[0.5, 0. ]])
    """
    p = np.asarray(points_m, dtype=float).reshape(-1, 3)
    eo_rows = np.broadcast_to(np.asarray(eo, dtype=float), (len(p), 6))
    with np.errstate(divide="ignore", invalid="ignore"):
        xy, u3 = project(eo_rows, p, np.full(len(p), float(focal_length_mm)))
    xy[u3 >= 0] = np.nan  # behind (or in the plane of) the projection centre
    return xy


def _layout(n_photos: int, cam: Camera, height_m: float, rng: np.random.Generator):
    """True exterior orientations of a block of one or two strips."""
    width_m, depth_m = (s * height_m / cam.focal_length_mm for s in cam.frame_size_mm)
    base = 0.4 * width_m
    spacing = 0.7 * depth_m
    n_strips = 1 if n_photos < 6 else 2
    sizes = [n_photos - n_photos // 2, n_photos // 2] if n_strips == 2 else [n_photos]
    rows = []
    for s, size in enumerate(sizes):
        order = range(size) if s % 2 == 0 else range(size - 1, -1, -1)
        for i in order:
            kappa = 0.0 if s % 2 == 0 else math.pi
            rows.append([
                _E0 + i * base + rng.normal(0, 3.0),
                _N0 + s * spacing + rng.normal(0, 3.0),
                _GROUND_M + height_m + rng.normal(0, 3.0),
                math.radians(rng.normal(0, 1.0)),
                math.radians(rng.normal(0, 1.0)),
                kappa + math.radians(rng.normal(0, 1.5)),
            ])
    eo = np.array(rows)
    box = (_E0 - width_m / 2, _N0 - depth_m / 2,
           _E0 + (max(sizes) - 1) * base + width_m / 2, _N0 + (n_strips - 1) * spacing + depth_m / 2)
    return eo, box, base, spacing, n_strips


def _visibility(points: np.ndarray, eo: np.ndarray, cam: Camera, margin_px: float):
    """(n_photos, N) photo coordinates and a mask of points inside each frame."""
    xy = np.stack([project_points(points, e, cam.focal_length_mm) for e in eo])
    seen = np.zeros(xy.shape[:2], dtype=bool)
    px = np.full(xy.shape, np.nan)
    for k in range(len(eo)):
        ok = np.isfinite(xy[k]).all(axis=1)
        # the distortion model is only valid near the frame: test the ideal position first
        w, h = cam.frame_size_mm
        ok &= (np.abs(xy[k, :, 0]) < w / 2) & (np.abs(xy[k, :, 1]) < h / 2)
        if ok.any():
            px[k, ok] = cam.photo_to_pixel(xy[k, ok])
            seen[k, ok] = cam.contains(px[k, ok], margin_px=-margin_px)
    return px, seen


def write_synthetic_survey(
    outdir: str | os.PathLike,
    *,
    n_photos: int = 6,
    seed: int = 1,
    height_m: float = 700.0,
    image_sd_px: float = 0.5,
    gps_sd_m: float = 0.03,
    gps_sd_h_m: float = 0.05,
    lidar_density_m2: float = 4.0,
    lidar_noise_m: float = 0.05,
    approx_error_m: float = 1.0,
    n_roofs: int | None = None,
    images: bool = False,
    image_downsample: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> DemoSurvey:
    """Write a synthetic survey folder with known truth (see the module docstring).

    Parameters
    ----------
    outdir : path
        Folder to write (created; files already there are replaced).
    n_photos : int
        Photos in the block (>= 2; one strip below 6, two strips from 6 on).
    seed : int
        Seed of ``numpy.random.default_rng``.
    height_m : float
        Flying height above the mean terrain, m.
    image_sd_px : float
        Standard deviation of the pixel measurements, px.
    gps_sd_m, gps_sd_h_m : float
        Standard deviation of the GPS coordinates (plan, height), m.
    lidar_density_m2 : float
        Point density of the LiDAR survey, points per m^2.
    lidar_noise_m : float
        Height noise of the LiDAR points, m.
    approx_error_m : float
        Plan error of the approximate positions in the extraction jobs, m
        (each drawn between 0.5x and 1.5x, in a random direction).
    n_roofs : int, optional
        Number of buildings (default: 1 + n_photos, at most 12).
    images : bool
        Also render the photos of the block (:func:`lidarcat.synthetic.aerial.render_photo`:
        fields, roads, trees and shadows, the buildings' roofs shaded by the sun, an exposure per
        photo) into ``images/<photo>.png``, for ``lidarcat monoplot``, ``ortho`` and ``match``.
    image_downsample : int
        Render at 1/k of the resolution and upsample (faster; blurrier photos
        with the same geometry).
    progress : callable, optional
        ``progress(done, total)`` over the writing steps.

    Returns
    -------
    DemoSurvey

    Raises
    ------
    LidarcatError
        Invalid sizes (fewer than 2 photos, non-positive noise levels).
    """
    if n_photos < 2:
        raise LidarcatError(f"--photos must be at least 2 (got {n_photos})")
    if n_photos > 200:
        raise LidarcatError(f"--photos must be at most 200 for the demo (got {n_photos})")
    for name, v in (("image_sd_px", image_sd_px), ("gps_sd_m", gps_sd_m), ("gps_sd_h_m", gps_sd_h_m),
                    ("lidar_density_m2", lidar_density_m2), ("lidar_noise_m", lidar_noise_m),
                    ("height_m", height_m)):
        if not v > 0:
            raise LidarcatError(f"{name} must be positive (got {v})")
    steps = 5 + (n_photos if images else 0)   # one step per rendered photo (about a minute each at 24 MP)
    tick = (lambda i: progress(i, steps)) if progress else (lambda i: None)
    rng = np.random.default_rng(seed)
    cam = demo_camera()
    eo, box, base, spacing, n_strips = _layout(n_photos, cam, height_m, rng)
    photo_ids = [f"{k + 1}" for k in range(len(eo))]
    n_first = n_photos - n_photos // 2 if n_strips == 2 else n_photos
    margin = 60.0

    # ---- tie points: a jittered grid over the block, seen on >= 2 photos
    step = base / 2
    ge = np.arange(box[0] + step / 2, box[2], step)
    gn = np.arange(box[1] + step / 2, box[3], step)
    ee, nn = np.meshgrid(ge, gn)
    tie = np.column_stack([ee.ravel(), nn.ravel()]) + rng.uniform(-step / 4, step / 4, (ee.size, 2))
    tie = np.column_stack([tie, demo_terrain(tie[:, 0], tie[:, 1])])

    # ---- GPS points: under the photo centres and between them, in every overlap
    nadir = eo[:n_first, 0]
    es = np.sort(np.concatenate([nadir, (nadir[:-1] + nadir[1:]) / 2]))
    strip_n = [_N0 + s * spacing for s in range(n_strips)]
    ns = [strip_n[0] - 0.3 * spacing] + [(a + b) / 2 for a, b in zip(strip_n, strip_n[1:])] + \
         [strip_n[-1] + 0.3 * spacing]
    if n_strips == 1:
        ns = [strip_n[0] - 0.3 * spacing, strip_n[0] + 0.3 * spacing]
    ge2, gn2 = np.meshgrid(es, ns)
    gps = np.column_stack([ge2.ravel(), gn2.ravel()]) + rng.normal(0, 10.0, (ge2.size, 2))
    gps = np.column_stack([gps, demo_terrain(gps[:, 0], gps[:, 1])])

    # ---- buildings: between the GPS points
    n_b = n_roofs if n_roofs is not None else min(1 + n_photos, 12)
    be = (es[:-1] + es[1:]) / 2
    bn = [(a + b) / 2 for a, b in zip(ns, ns[1:])] if len(ns) > 1 else ns
    cand = np.array([(e, n) for n in bn for e in be])
    cand += rng.normal(0, 8.0, cand.shape)
    buildings = _place_buildings(cand, n_b, rng, _roofs, lidar_density_m2, lidar_noise_m)

    roof_pts = np.array([b["vertex"] for b in buildings]).reshape(-1, 3)
    tick(1)

    # ---- image measurements
    kinds = [("T", tie), ("G", gps), ("R", roof_pts)]
    ids: list[str] = []
    xyz: list[np.ndarray] = []
    kind_of: list[str] = []
    for prefix, pts in kinds:
        px, seen = _visibility(pts, eo, cam, margin)
        keep = seen.sum(axis=0) >= 2
        if prefix == "R" and not keep.all():
            bad = np.flatnonzero(~keep)
            raise LidarcatError(f"demo: building(s) {bad.tolist()} not seen on 2 photos (seed {seed})")
        kept = np.flatnonzero(keep)
        for j, i in enumerate(kept, start=1):
            ids.append(f"{prefix}{j:02d}" if prefix != "R" else f"R{i + 1:02d}")
            xyz.append(pts[i])
            kind_of.append({"T": "tie", "G": "gps", "R": "roof"}[prefix])
    xyz_a = np.array(xyz)
    px, seen = _visibility(xyz_a, eo, cam, margin)
    noise = rng.normal(0, image_sd_px, px.shape)
    obs_rows = []
    for k, pid in enumerate(photo_ids):
        for i in np.flatnonzero(seen[k]):
            c, r = px[k, i] + noise[k, i]
            obs_rows.append((pid, ids[i], round(float(c), 3), round(float(r), 3)))
    tick(2)

    gps_idx = [i for i, k in enumerate(kind_of) if k == "gps"]
    gps_true = xyz_a[gps_idx]
    gps_meas = gps_true + rng.normal(0, 1.0, gps_true.shape) * [gps_sd_m, gps_sd_m, gps_sd_h_m]
    gps_ids = [ids[i] for i in gps_idx]
    control = _pick_control(gps_true[:, :2], base)

    outdir = Path(outdir)
    with atomic_dir(outdir) as tmp:
        write_text_atomic(tmp / "camera.toml",
                          "# Synthetic camera of lidarcat.synthetic.survey (known truth).\n" + cam.to_toml())
        write_csv_atomic(tmp / "photos.csv", ["photo", "camera"] + (["image"] if images else []),
                         [(p, cam.id) + ((f"images/{p}.png",) if images else ()) for p in photo_ids],
                         comments=["Synthetic block written by lidarcat.synthetic.survey; "
                                   "true orientations in truth/eop.csv."]
                         + (["image: the rendered photo (lidarcat demo synthetic --images)"] if images else []))
        write_csv_atomic(tmp / "image_points.csv", ["photo", "point", "col_px", "row_px"], obs_rows,
                         comments=[f"Pixel measurements, noise sd {image_sd_px} px (seed {seed}); "
                                   "T* tie, G* GPS, R* roof vertices."])
        write_csv_atomic(
            tmp / "ground_points.csv", ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
            [(pid, *np.round(p, 4), gps_sd_m, gps_sd_m, gps_sd_h_m, "gps")
             for pid, p in zip(gps_ids, gps_meas)],
            comments=[f"GPS points: true coordinates (truth/points.csv) plus noise of sd "
                      f"{gps_sd_m} m (E, N) and {gps_sd_h_m} m (h)."])
        write_csv_atomic(
            tmp / "control_sets.csv", ["set", "point", "role", "sd_E", "sd_N", "sd_h"],
            [("gps", pid, "control" if i in control else "check", "", "", "")
             for i, pid in enumerate(gps_ids)],
            comments=["gps: corner and centre GPS points are control (in a block longer than "
                      f"{_CONTROL_EVERY_BASES} bases also the outermost points of every {_CONTROL_EVERY_BASES} "
                      "bases along the strips), the others check. "
                      "lidarcat run adds the set 'lidar' from the extracted roof vertices."])
        jobs = []
        for b in buildings:
            r = approx_error_m * rng.uniform(0.5, 1.5)
            a = rng.uniform(0, 2 * np.pi)
            approx = b["vertex"][:2] + r * np.array([np.cos(a), np.sin(a)])
            jobs.append((b["id"], round(float(approx[0]), 2), round(float(approx[1]), 2),
                         _LIDAR_PLAN_SD_M, lidar_noise_m))
        write_csv_atomic(tmp / "jobs.csv", ["point", "E", "N", "sd_en_m", "sd_h_m"], jobs,
                         comments=[f"Roof vertices to extract; approximate positions off by "
                                   f"~{approx_error_m} m (0.5x-1.5x) from truth/roofs.csv; "
                                   f"sd_en_m, sd_h_m: noise of the LiDAR points (m)."])
        tick(3)
        n_lidar = _write_lidar(tmp / "lidar", box, buildings, lidar_density_m2, lidar_noise_m, rng,
                               _roofs)
        tick(4)
        if images:
            _render_photos(tmp / "images", buildings, cam, eo, photo_ids, image_downsample,
                           lambda k: tick(4 + k))
        (tmp / "truth").mkdir()
        write_csv_atomic(
            tmp / "truth" / "eop.csv",
            ["photo", "X0", "Y0", "Z0", "omega", "phi", "kappa"],
            [(pid, *e[:3], *np.degrees(e[3:])) for pid, e in zip(photo_ids, eo)],
            comments=["True exterior orientation: metres and degrees, M = R3(kappa) R2(phi) R1(omega)."])
        write_csv_atomic(tmp / "truth" / "points.csv", ["point", "E", "N", "h", "kind"],
                         [(pid, *p, k) for pid, p, k in zip(ids, xyz_a, kind_of)],
                         comments=["True coordinates of every measured point, metres."])
        write_csv_atomic(tmp / "truth" / "roofs.csv", ["point", "E", "N", "h", "roof", "n_planes"],
                         [(b["id"], *b["vertex"], b["kind"], b["n_planes"]) for b in buildings],
                         comments=["True roof vertices (the extraction targets)."])
        write_text_atomic(tmp / "survey.toml",
                          _survey_toml(seed, n_photos, image_sd_px * cam.pixel_size_x_mm))
        write_text_atomic(tmp / "truth" / "README.md", _TRUTH_README.format(
            seed=seed, image_sd_px=image_sd_px, gps_sd_m=gps_sd_m, gps_sd_h_m=gps_sd_h_m,
            approx_error_m=approx_error_m, lidar_density_m2=lidar_density_m2, lidar_noise_m=lidar_noise_m))
        files = tuple(sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file()))
    # tiles of an earlier demo in the same folder would be read as part of this survey
    for old in (outdir / "lidar").glob("*.laz"):
        if f"lidar/{old.name}" not in files:
            old.unlink()
    tick(steps)
    log.info("demo survey written to %s: %d photos, %d observations", outdir, len(eo), len(obs_rows))
    return DemoSurvey(outdir, len(eo), kind_of.count("tie"), len(gps_ids), len(buildings), n_lidar,
                      seed, image_sd_px, gps_sd_m, files)


#: along a strip, full control at least every this many photo bases: the usual layout of a bundle
#: block (planimetric control along the perimeter every few bases, height-control chains across the
#: strips every few bases; see any photogrammetry textbook on block control)
_CONTROL_EVERY_BASES = 4


def _pick_control(en: np.ndarray, base_m: float | None = None) -> set[int]:
    """Indices of the GPS control: the four corners and the point nearest the centre, and, in a block
    longer than ``_CONTROL_EVERY_BASES`` bases (``base_m``), the outermost points (lowest and highest
    N) of every stretch of that length along E: chains across the strips at both block edges, which a
    long block needs against the bending (the corners alone leave metres of height error in the middle
    of a 200-photo block)."""
    c = en.mean(axis=0)
    d = en - c
    chosen = {int(np.argmax(d[:, 0] + d[:, 1])), int(np.argmax(d[:, 0] - d[:, 1])),
              int(np.argmax(-d[:, 0] + d[:, 1])), int(np.argmax(-d[:, 0] - d[:, 1]))}
    order = np.argsort(np.hypot(*d.T))
    for i in order:
        if int(i) not in chosen:
            chosen.add(int(i))
            break
    if base_m is not None and np.ptp(en[:, 0]) > (_CONTROL_EVERY_BASES + 1) * base_m:
        stretch = np.floor((en[:, 0] - en[:, 0].min()) / (_CONTROL_EVERY_BASES * base_m)).astype(int)
        for s in np.unique(stretch):
            idx = np.flatnonzero(stretch == s)
            chosen.update({int(idx[np.argmin(en[idx, 1])]), int(idx[np.argmax(en[idx, 1])])})
    return chosen


_TRUTH_README = """# Truth of the synthetic survey (lidarcat demo synthetic, seed {seed})

| file | content |
|---|---|
| eop.csv | true exterior orientation of every photo (m, deg; M = R3(kappa) R2(phi) R1(omega)) |
| points.csv | true E, N, h of every measured point (tie, gps, roof) |
| roofs.csv | true roof vertices: the targets of the extraction jobs |

Noise used: pixel measurements {image_sd_px} px; GPS {gps_sd_m} m (E, N), {gps_sd_h_m} m (h);
LiDAR {lidar_density_m2} points/m^2 with {lidar_noise_m} m height noise; approximate
positions of the extraction jobs {approx_error_m} m off in plan (0.5x to 1.5x, random direction).
"""


def _survey_toml(seed: int, n_photos: int, image_sd_mm: float) -> str:
    return f"""# Synthetic survey written by `lidarcat demo synthetic --photos {n_photos} --seed {seed}`.
# Known truth in truth/. Format: docs/survey-format.md.

[survey]
name = "synthetic-{n_photos}photos-seed{seed}"
description = "Synthetic block with known truth (lidarcat.synthetic.survey)"
crs = "{DEMO_CRS}"
height_system = "ellipsoidal"
default_control = "gps"

[files]
camera = "camera.toml"
photos = "photos.csv"
image_points = "image_points.csv"
ground_points = "ground_points.csv"
control_sets = "control_sets.csv"
lidar = ["lidar/*.laz"]
extraction_jobs = "jobs.csv"

[adjustment]
observations = "pixel"
image_sd_mm = {image_sd_mm!r}
variance_factor = "a_priori"
chi2_level = 0.05

[lidar]
crs = "{DEMO_CRS}"
"""


def _place_buildings(cand: np.ndarray, n: int, rng: np.random.Generator, roofs: Any,
                     density_m2: float, noise_m: float) -> list[dict]:
    """Pick *n* of the candidate positions and sample a building (pyramid or hip roof) at each."""
    if len(cand) == 0:
        raise LidarcatError("demo: the block is too small for buildings; use more photos")
    order = np.arange(len(cand))
    if n < len(cand):
        order = np.sort(rng.choice(len(cand), size=n, replace=False))
    out = []
    for k, i in enumerate(order):
        e, nn = (float(v) for v in cand[i])
        kind = ("pyramid", "hip")[k % 2]
        params = {"slope_deg": float(rng.uniform(25, 35)), "length_m": float(rng.uniform(15, 18)),
                  "width_m": float(rng.uniform(9, 11)), "eave_m": float(rng.uniform(5, 7)),
                  "azimuth_deg": float(rng.uniform(0, 90))}
        scene = roofs.synthetic_roof(
            kind, **params, density_m2=density_m2, noise_h_m=noise_m,
            noise_plan_m=_LIDAR_PLAN_SD_M, origin=(e, nn, float(demo_terrain(e, nn))), seed=int(rng.integers(2**31)))
        out.append({"id": f"R{k + 1:02d}", "kind": kind, "vertex": np.array(scene.vertices[0]),
                    "n_planes": int(scene.vertex_planes[0]), "scene": scene, "params": {**params, "e": e, "n": nn}})
    return out


def _write_lidar(folder: Path, box, buildings: list[dict], density_m2: float, noise_m: float,
                 rng: np.random.Generator, roofs: Any) -> int:
    """Terrain + buildings sampled at *density_m2*, written as 2 x 2 LAZ tiles."""
    from ..lidar import PointCloud, resolve_crs, write_points

    clouds, footprints = [], []
    for b in buildings:
        scene = b["scene"]
        xyz = np.asarray(scene.xyz)
        clouds.append((xyz, np.where(np.asarray(scene.label) == roofs.LABELS["ground"], 2, 6)))
        footprints.append((xyz[:, 0].min(), xyz[:, 1].min(), xyz[:, 0].max(), xyz[:, 1].max()))
    area = (box[2] - box[0]) * (box[3] - box[1])
    if density_m2 * area <= _MAX_BLOCK_POINTS:
        m = rng.poisson(density_m2 * area)
        en = np.column_stack([rng.uniform(box[0], box[2], m), rng.uniform(box[1], box[3], m)])
    else:  # a large block: terrain only in 100 m squares around the buildings (bounded memory)
        log.info("demo: %.0f million LiDAR points would cover the block; sampling the terrain "
                 "around the buildings only", density_m2 * area / 1e6)
        patches = []
        for b in buildings:
            e0, n0 = b["vertex"][:2]
            m = rng.poisson(density_m2 * 100.0 * 100.0)
            patches.append(np.column_stack([rng.uniform(e0 - 50, e0 + 50, m),
                                            rng.uniform(n0 - 50, n0 + 50, m)]))
        en = np.vstack(patches)
    keep = np.ones(len(en), dtype=bool)
    for x0, y0, x1, y1 in footprints:
        keep &= ~((en[:, 0] >= x0) & (en[:, 0] <= x1) & (en[:, 1] >= y0) & (en[:, 1] <= y1))
    en = en[keep]
    ground = np.column_stack([en, demo_terrain(en[:, 0], en[:, 1]) + rng.normal(0, noise_m, len(en))])
    xyz = np.vstack([ground] + [c[0] for c in clouds])
    cls = np.concatenate([np.full(len(ground), 2, np.uint8)] + [c[1].astype(np.uint8) for c in clouds])
    attrs = _lidar_attributes(xyz, np.concatenate([np.full(len(ground), roofs.LABELS["ground"])]
                                                  + [np.asarray(b["scene"].label) for b in buildings]), roofs)
    folder.mkdir(parents=True, exist_ok=True)
    emid, nmid = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    total = 0
    for i, (elo, ehi) in enumerate(((-np.inf, emid), (emid, np.inf))):
        for j, (nlo, nhi) in enumerate(((-np.inf, nmid), (nmid, np.inf))):
            sel = (xyz[:, 0] >= elo) & (xyz[:, 0] < ehi) & (xyz[:, 1] >= nlo) & (xyz[:, 1] < nhi)
            if not sel.any():
                continue
            cloud = PointCloud(xyz[sel], {"classification": cls[sel], **{k: v[sel] for k, v in attrs.items()}},
                               crs=resolve_crs(DEMO_CRS))
            write_points(folder / f"tile_{i}_{j}.laz", cloud)
            total += int(sel.sum())
    return total


def _lidar_attributes(xyz: np.ndarray, label: np.ndarray, roofs: Any) -> dict[str, np.ndarray]:
    """Intensity and returns of the demo's LiDAR points (issue 16: they were all 0, an invalid LAS).

    One return per pulse (opaque ground and roofs: return 1 of 1).  Intensity by
    material, so that the intensity image shows the roofs: ground 900 with a
    +-150 pattern of 40 m, walls 1300, roofs 2200, chimneys and dormers 2000,
    trees 600; 8 % noise from a generator of its own (the survey's random stream
    is left as it was).
    """
    lab = np.asarray(label)
    base = np.full(len(lab), 900.0)
    for name, value in (("wall", 1300.0), ("roof", 2200.0), ("chimney", 2000.0), ("dormer", 2000.0),
                        ("tree", 600.0)):
        base[lab == roofs.LABELS[name]] = value
    ground = lab == roofs.LABELS["ground"]
    base[ground] += 150.0 * np.sin(2 * np.pi * xyz[ground, 0] / 40.0) * np.cos(2 * np.pi * xyz[ground, 1] / 40.0)
    noise = np.random.default_rng(len(lab)).normal(1.0, 0.08, len(lab))
    ones = np.ones(len(lab), dtype=np.uint8)
    return {"intensity": np.clip(np.rint(base * noise), 1, 65535).astype(np.uint16),
            "return_number": ones, "number_of_returns": ones.copy()}


def demo_scene_of(buildings: Sequence[dict], texel_m: float = 0.12) -> Any:
    """The :class:`lidarcat.synthetic.aerial.AerialScene` of the demo's terrain and buildings (for rendering
    photos): fields, trees and shadows around them, albedo texels of *texel_m*."""
    return AerialScene(demo_terrain, tuple(Building(b["kind"], b["params"]["e"], b["params"]["n"], **{
        k: v for k, v in b["params"].items() if k not in ("e", "n")}) for b in buildings), texel_m=texel_m)


def _render_photos(folder: Path, buildings: Sequence[dict], cam: Camera, eo: np.ndarray, ids: Sequence[str],
                   downsample: int, done: Callable[[int], None] = lambda k: None) -> None:
    """Render every photo into ``folder/<id>.png`` (at 1/downsample resolution, upsampled bilinearly).

    :func:`lidarcat.synthetic.aerial.render_photo`: an aerial-looking photo (fields, trees, shaded
    roofs) with an exposure of its own per photo, seeded by the photo's position in the block (the
    survey's random stream is left as it was: the other files do not change); ``done(k)`` after the k-th photo.
    """
    import cv2

    from .._util import atomic_write

    if cam.columns_px % downsample or cam.rows_px % downsample:
        raise LidarcatError(f"--image-downsample {downsample} must divide the image size "
                            f"{cam.columns_px} x {cam.rows_px}")
    small = Camera(cam.id, cam.focal_length_mm, cam.principal_point_x_mm, cam.principal_point_y_mm, cam.k1,
                   cam.k2, cam.k3, cam.p1, cam.p2, cam.refraction_eps45, cam.pixel_size_x_mm * downsample,
                   cam.pixel_size_y_mm * downsample, cam.columns_px // downsample, cam.rows_px // downsample)
    gsd = float(np.mean(eo[:, 2]) - _GROUND_M) * small.pixel_size_x_mm / small.focal_length_mm
    scene = demo_scene_of(buildings, texel_m=gsd)
    folder.mkdir(parents=True, exist_ok=True)
    for k, (pid, e) in enumerate(zip(ids, eo)):
        img = render_photo(scene, small, e, exposure=Exposure.random(1000 + k, vignetting=0.1, noise_sd=1.0),
                           truth=False).image
        if downsample > 1:   # pixel centres stay aligned: dst x <-> src (x + 0.5) / k - 0.5
            img = cv2.resize(img, (cam.columns_px, cam.rows_px), interpolation=cv2.INTER_LINEAR)
        ok, buf = cv2.imencode(".png", img)
        with atomic_write(folder / f"{pid}.png", "wb") as fh:
            fh.write(buf.tobytes())
        done(k + 1)


def compare_with_truth(survey_dir: str | os.PathLike, outdir: str | os.PathLike) -> dict[str, Any]:
    """Compare the output of ``lidarcat run`` on a synthetic survey with its ``truth/``.

    Parameters
    ----------
    survey_dir : path
        Folder written by :func:`write_synthetic_survey`.
    outdir : path
        Output folder of ``lidarcat run survey_dir``.

    Returns
    -------
    dict
        ``extraction``: for every roof vertex the error (m) and the error in
        units of its standard deviation (z); ``runs``: for each run, the
        largest |z| of the exterior orientation and of the free points, the RMS
        of those z (1 for honest standard deviations), and the check-point
        statistics ``check_chi2_joint`` = d' C^-1 d (C: joint covariance of the
        adjusted check points + GPS variances; chi-square with ``check_dof``
        degrees of freedom) and ``check_chi2`` = sum d^2 / (sd_adjusted^2 +
        sd_gps^2) (correlations ignored: same mean, wider spread).

    Raises
    ------
    LidarcatError
        A folder lacks the expected files, *outdir* holds no run, or a point or
        photo of the run is not in the survey's truth (the output of another survey).
    """
    from .._util import read_csv_table

    survey_dir, outdir = Path(survey_dir), Path(outdir)
    runs = sorted(outdir.glob("adjust-*"))
    if not runs:
        raise LidarcatError(f"{outdir}: no adjust-* folder; run `lidarcat run {survey_dir} -o {outdir}` "
                            "first")

    def table(path: Path, key: str, cols: Sequence[str]) -> dict[str, np.ndarray]:
        if not path.is_file():
            raise LidarcatError(f"{path}: not found (is this a demo survey and its run output?)")
        t = read_csv_table(path, required=(key, *cols), allow_extra=True)
        arr = np.column_stack([t.floats(c) for c in cols])
        return {k: arr[i] for i, k in enumerate(t.column(key))}

    def row(rows: dict[str, np.ndarray], key: str, where: Path, source: Path) -> np.ndarray:
        if key not in rows:
            raise LidarcatError(f"{source}: {key!r} is not in {where}; is {outdir} the output of "
                                f"`lidarcat run {survey_dir}`?")
        return rows[key]

    enh, sds = ("E", "N", "h"), ("sd_E", "sd_N", "sd_h")
    eo_keys = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    truth_pts = table(survey_dir / "truth" / "points.csv", "point", enh)
    truth_eo = table(survey_dir / "truth" / "eop.csv", "photo", eo_keys)
    ground = table(survey_dir / "ground_points.csv", "point", enh + sds)
    out: dict[str, Any] = {"extraction": {}, "runs": {}}
    ctl = outdir / "extract" / "control.csv"
    if ctl.is_file():
        roofs = table(survey_dir / "truth" / "roofs.csv", "point", enh)
        t = read_csv_table(ctl, required=("point", "status") + enh + sds, allow_extra=True)
        vals = np.column_stack([t.floats(c, required=False) for c in enh + sds])
        for pid, st, v in zip(t.column("point"), t.column("status"), vals):
            err = v[:3] - row(roofs, pid, survey_dir / "truth" / "roofs.csv", ctl)
            out["extraction"][pid] = {"status": st, "error_m": err.tolist(), "z": (err / v[3:]).tolist()}
    for folder in runs:
        run = folder.name[len("adjust-"):]
        eo = table(folder / "eop.csv", "photo", eo_keys + tuple(f"sd_{k}" for k in eo_keys))
        z_eo = []
        for ph, v in eo.items():
            d = v[:6] - row(truth_eo, ph, survey_dir / "truth" / "eop.csv", folder / "eop.csv")
            d[3:] = (d[3:] + 180) % 360 - 180
            z_eo.extend(d / v[6:])
        pts_t = read_csv_table(folder / "points.csv", required=("point", "role") + enh + sds,
                               allow_extra=True)
        pv = np.column_stack([pts_t.floats(c) for c in enh + sds])
        z_pt, stat, n_chk = [], 0.0, 0
        checks = set()
        disc = outdir / f"assess-{run}" / "discrepancies.csv"
        if disc.is_file():
            checks = set(read_csv_table(disc, required=("point",), allow_extra=True).column("point"))
        for pid, role, v in zip(pts_t.column("point"), pts_t.column("role"), pv):
            if role != "control" and pid in truth_pts:
                z_pt.extend((v[:3] - truth_pts[pid]) / v[3:])
            if pid in checks:
                g = row(ground, pid, survey_dir / "ground_points.csv", disc)
                stat += float(np.sum((g[:3] - v[:3]) ** 2 / (v[3:] ** 2 + g[3:] ** 2)))
                n_chk += 1
        joint, joint_why = math.nan, "no check point" if not checks else "no joint covariance"
        cov_path = folder / "check_covariance.csv"
        cons_path = folder / "consistency.json"  # lidarcat run above the check_covariance.csv limit
        if checks and not cov_path.is_file() and cons_path.is_file():
            cons = json.loads(cons_path.read_text(encoding="utf-8"))
            joint = float(cons["statistic"]) if cons["applicable"] else math.nan
            joint_why = "" if cons["applicable"] else str(cons["reason"])
        if checks and cov_path.is_file():
            from ..accuracy.statistics import covariance_consistency_test
            from ..survey import read_point_covariance

            order = [q for q in pts_t.column("point") if q in checks]
            _, C = read_point_covariance(cov_path, points=order)
            adj = {q: v for q, v in zip(pts_t.column("point"), pv)}
            d = np.concatenate([ground[q][:3] - adj[q][:3] for q in order])
            C = C + np.diag(np.concatenate([ground[q][3:] ** 2 for q in order]))
            test = covariance_consistency_test(d, C, source=str(cov_path))
            joint = float(test.statistic) if test.applicable else math.nan
            joint_why = "" if test.applicable else str(test.reason)
        z_eo_a, z_pt_a = np.abs(z_eo), np.abs(z_pt)
        out["runs"][run] = {
            "eo_max_abs_z": float(z_eo_a.max()), "eo_rms_z": float(np.sqrt(np.mean(z_eo_a ** 2))),
            "points_max_abs_z": float(z_pt_a.max()) if len(z_pt_a) else math.nan,
            "points_rms_z": float(np.sqrt(np.mean(z_pt_a ** 2))) if len(z_pt_a) else math.nan,
            "n_check": n_chk, "check_chi2": stat, "check_chi2_joint": joint,
            "check_chi2_joint_not_computed": joint_why if not math.isfinite(joint) else "",
            "check_dof": 3 * n_chk}
    return out
