r"""A synthetic aerial block from photos: realistic rendered photos, approximate GNSS/IMU, GPS control, truth.

:func:`aerial_survey` writes the survey folder that issue 28's acceptance starts from -- photos and
an approximate orientation, no tie point -- and keeps everything a test needs to score the
matcher and the adjustment against truth:

* ``images/<photo>.png`` -- photos rendered by :func:`render_photo` (:mod:`lidarcat.synthetic._photo`:
  exact ray casting of a terrain with buildings; the albedo of :mod:`lidarcat.synthetic._texture`:
  fields with boundaries, roads, trees and their shadows, roof materials shaded by their plane
  normal, grain at several octaves, ground control targets), each with an exposure of its own
  (gain, gamma, black level), vignetting and noise;
* ``photos.csv`` -- the *approximate* orientation as weighted GNSS/IMU observations: the true one
  plus Gaussian errors of ``approx_position_sd_m`` and ``approx_angle_sd_deg``, with those sds in
  ``sd_X0 .. sd_kappa_deg`` (honest weights);
* ``ground_points.csv`` + ``control_sets.csv`` -- ``n_gps_points`` GPS control points (painted
  targets on the ground, in the side overlap near the block ends) with their noise sds;
  ``image_points.csv`` -- their image measurements only (noise ``image_sd_px``), where the
  target is on the photo and not hidden: the tie points come from ``lidarcat match``;
* ``lidar/*.laz`` -- LiDAR tiles of the same scene (ground class 2, buildings class 6, intensity
  from the albedo), unless ``lidar_density_m2 = 0``;
* ``truth/`` -- ``eop.csv`` (true orientations), ``points.csv`` (true control coordinates),
  ``scene.json`` (everything needed to rebuild the scene: :func:`load_aerial_survey`) and, with
  ``write_xyz``, ``xyz/<photo>.npy`` (the true E, N, h of every pixel, float64).

The block: ``n_strips`` strips of ``photos_per_strip`` photos along E (every other strip flown
back, kappa ~ 180 deg), base ``(1 - forward_overlap)`` x the frame's ground width, strip spacing
``(1 - side_overlap)`` x its depth, flown at the height that gives ``gsd_m`` at nadir with a
36 mm-wide frame of ``image_size_px`` behind a 35 mm lens (radial and decentering distortion).
The true orientations scatter like a real flight (3 m, 1 deg, kappa 1.5 deg).

Scoring a match: :meth:`AerialSurvey.ground_point` casts the exact ray of any sub-pixel position
(the true surface point seen there), :meth:`AerialSurvey.transfer` carries it into another photo
(NaN where it is hidden or off the frame): a tie-point observation ``(photo b, px_b)`` of a track
first seen at ``(photo a, px_a)`` is off by ``|px_b - transfer(a, px_a, b)|``.

Every random draw comes from ``numpy.random.default_rng(seed)`` and the albedo is a function of
the seed: the same arguments write the same files.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, atomic_write, write_csv_atomic, write_text_atomic
from ..geometry.camera import Camera
from ..geometry.collinearity import rotation_matrix
from ..errors import LidarcatError
from ._texture import road_distance
from ._photo import SURFACE, AerialScene, Exposure, RenderedPhoto, building_windows, project_to_pixels, render_photo
from .scene import DEMO_GROUND_M, DEMO_ORIGIN_EN, Building, Road, demo_terrain

__all__ = ["AerialScene", "Exposure", "RenderedPhoto", "render_photo", "project_to_pixels", "SURFACE",
           "AerialSurvey", "aerial_survey", "aerial_camera", "aerial_scene", "load_aerial_survey",
           "photo_images", "ground_points", "truth_map", "AERIAL_CRS"]

#: SIRGAS 2000 / UTM zone 22 S: the CRS of the block (the demo's)
AERIAL_CRS = "EPSG:31982"
_E0, _N0 = DEMO_ORIGIN_EN


def aerial_camera(image_size_px: tuple[int, int] = (1000, 750)) -> Camera:
    """A frame camera 36 mm wide of ``image_size_px`` (columns, rows), c = 35 mm, with distortion.

    >>> cam = aerial_camera((1000, 750))
    >>> [round(v, 9) for v in cam.frame_size_mm], cam.columns_px, cam.rows_px
    ([36.0, 27.0], 1000, 750)
    """
    cols, rows = (int(v) for v in image_size_px)
    if cols < 16 or rows < 16:
        raise LidarcatError(f"image_size_px must be at least 16 x 16, got {cols} x {rows}")
    px = 36.0 / cols
    return Camera("aerial", 35.0, 0.012, -0.018, -2.5e-5, 1.0e-8, 0.0, 2.0e-6, -1.0e-6, 0.0, px, px, cols, rows,
                  model=f"synthetic 36 mm frame camera, {cols} x {rows} px",
                  source="lidarcat.synthetic.aerial (synthetic, known truth)")


def _directions(camera: Camera, eo: np.ndarray, colrow: np.ndarray) -> np.ndarray:
    xy = camera.pixel_to_photo(np.asarray(colrow, dtype=np.float64).reshape(-1, 2))
    m = rotation_matrix(np.asarray(eo, dtype=np.float64)[3:6])
    v = np.column_stack([xy, np.full(len(xy), -camera.focal_length_mm)])
    return v[:, 0:1] * m[0] + v[:, 1:2] * m[1] + v[:, 2:3] * m[2]


def ground_points(scene: AerialScene, camera: Camera, eo: Sequence[float], colrow_px: Any) -> np.ndarray:
    """The true surface point (E, N, h, m) seen at sub-pixel positions: the exact first hit of their rays.

    Parameters
    ----------
    scene : AerialScene
    camera : Camera
    eo : (6,) X0, Y0, Z0 (m), omega, phi, kappa (rad)
    colrow_px : (N, 2) column, row, px

    Returns
    -------
    (N, 3) float64; NaN where the ray meets nothing.
    """
    eo = np.asarray(eo, dtype=np.float64)
    colrow = np.asarray(colrow_px, dtype=np.float64).reshape(-1, 2)
    d = _directions(camera, eo, colrow)
    t = scene._terrain_hit(eo[:3], d)
    bidx = np.full(len(d), -1, np.int32)
    face = np.full(len(d), -1, np.int16)
    for k, x0, x1, y0, y1 in building_windows(scene, camera, eo):
        idx = np.flatnonzero((colrow[:, 0] >= x0) & (colrow[:, 0] <= x1) & (colrow[:, 1] >= y0) & (colrow[:, 1] <= y1))
        scene._building_hit(k, eo[:3], d, idx, t, bidx, face)
    return eo[:3] + t[:, None] * d


def truth_map(scene: AerialScene, camera: Camera, eo: Sequence[float], *, tile_px: int = 512) -> np.ndarray:
    """(H, W, 3) float64 true E, N, h of every pixel centre (NaN where nothing): the geometry of
    :func:`render_photo` without the shading."""
    return render_photo(scene, camera, eo, truth=True, tile_px=tile_px, shade=False).xyz


@dataclasses.dataclass(frozen=True, eq=False)
class AerialSurvey:
    """What :func:`aerial_survey` wrote, with the truth (see the module docstring).

    Attributes
    ----------
    path : Path
        The survey folder.
    scene : AerialScene
    camera : Camera
    photo_ids : tuple of str
    true_eo : (P, 6) float64
        True X0, Y0, Z0 (m), omega, phi, kappa (rad).
    approx_eo : (P, 6) float64
        The approximate orientation written to photos.csv (same units).
    position_sd_m, angle_sd_deg : float
        Its sds (also in photos.csv).
    exposures : tuple of Exposure
        Radiometry of each photo.
    gps_ids : tuple of str
    gps_true : (G, 3) float64
        True E, N, h of the control targets, m.
    gsd_m : float
        Ground sample distance at nadir, m.
    seed : int
    files : tuple of str
        Every file written, relative to *path*.
    """

    path: Path
    scene: AerialScene
    camera: Camera
    photo_ids: tuple[str, ...]
    true_eo: np.ndarray
    approx_eo: np.ndarray
    position_sd_m: float
    angle_sd_deg: float
    exposures: tuple[Exposure, ...]
    gps_ids: tuple[str, ...]
    gps_true: np.ndarray
    gsd_m: float
    seed: int
    files: tuple[str, ...] = ()

    def index(self, photo: str) -> int:
        try:
            return self.photo_ids.index(str(photo))
        except ValueError:
            raise LidarcatError(f"{self.path}: no photo {photo!r} in the synthetic block") from None

    def image_paths(self) -> dict[str, Path]:
        """{photo id: path of its image file} (``images/<photo>.png``)."""
        return photo_images(self.path, self.photo_ids)

    def ground_point(self, photo: str, colrow_px: Any) -> np.ndarray:
        """(N, 3) true surface points seen at sub-pixel positions of *photo* (:func:`ground_points`)."""
        return ground_points(self.scene, self.camera, self.true_eo[self.index(photo)], colrow_px)

    def project(self, photo: str, xyz_m: Any) -> np.ndarray:
        """(N, 2) true pixel positions of ground points on *photo* (NaN behind or far off the frame)."""
        return project_to_pixels(self.camera, self.true_eo[self.index(photo)], xyz_m)

    def transfer(self, photo_a: str, colrow_a: Any, photo_b: str, *, tol_m: float = 0.05) -> np.ndarray:
        """Where the surface point seen at *colrow_a* on *photo_a* truly appears on *photo_b* (N, 2) px.

        NaN where it is off *photo_b*'s frame or hidden there (the first hit of *photo_b*'s ray
        through the projected position lies more than *tol_m* from the point).
        """
        xyz = self.ground_point(photo_a, colrow_a)
        px = self.project(photo_b, xyz)
        ok = np.isfinite(px).all(axis=1)
        ok[ok] = self.camera.contains(px[ok])
        if ok.any():
            back = self.ground_point(photo_b, px[ok])
            seen = np.linalg.norm(back - xyz[ok], axis=1) <= tol_m
            idx = np.flatnonzero(ok)
            ok[idx[~seen]] = False
        px[~ok] = np.nan
        return px

    def observation_errors(self, photo: Sequence[str], point: Sequence[str], colrow_px: Any) -> np.ndarray:
        """Distance (px) of tie-point observations from their truth, track by track.

        Each track's reference is its first observation (in the given order): its true ground point
        (:meth:`ground_point`) is projected into the track's other photos; an observation's error is
        its distance from that projection (0 for the reference; NaN where the point is hidden there
        or off the frame).

        Parameters
        ----------
        photo, point : (N,) photo and point ids of the observations
        colrow_px : (N, 2) column, row, px

        Returns
        -------
        (N,) float64, px
        """
        photo = np.asarray(photo, dtype=str)
        point = np.asarray(point, dtype=str)
        px = np.asarray(colrow_px, dtype=np.float64).reshape(-1, 2)
        _, first, inverse = np.unique(point, return_index=True, return_inverse=True)
        ref = first[inverse]                                   # index of each observation's reference
        xyz = np.full((len(px), 3), np.nan)
        for ph in np.unique(photo[first]):
            sel = first[photo[first] == ph]
            xyz[sel] = self.ground_point(str(ph), px[sel])
        err = np.full(len(px), np.nan)
        for ph in np.unique(photo):
            sel = np.flatnonzero(photo == ph)
            X = xyz[ref[sel]]
            pred = self.project(str(ph), X)
            ok = np.isfinite(pred).all(axis=1)
            ok[ok] = self.camera.contains(pred[ok])
            if ok.any():   # hidden on this photo: its own ray meets something else first
                back = self.ground_point(str(ph), pred[ok])
                ok[np.flatnonzero(ok)[np.linalg.norm(back - X[ok], axis=1) > 0.05]] = False
            err[sel[ok]] = np.linalg.norm(pred[ok] - px[sel[ok]], axis=1)
        err[ref == np.arange(len(px))] = 0.0
        return err

    def xyz(self, photo: str) -> np.ndarray:
        """(H, W, 3) true E, N, h of every pixel of *photo* (recomputed: :func:`truth_map`)."""
        return truth_map(self.scene, self.camera, self.true_eo[self.index(photo)])

    def render(self, photo: str, *, truth: bool = False, rgb: bool = False) -> RenderedPhoto:
        """Render *photo* again (the same image as its file, for a grey survey)."""
        k = self.index(photo)
        return render_photo(self.scene, self.camera, self.true_eo[k], exposure=self.exposures[k], rgb=rgb,
                            truth=truth)


def photo_images(folder: str | os.PathLike, photo_ids: Sequence[str]) -> dict[str, Path]:
    """{photo id: path} of the images of a synthetic block: ``images/<photo>.png`` by convention.

    The hook for the ``image`` column of photos.csv: the paths are relative to nothing but the
    survey folder, so that ``path.relative_to(folder)`` is the column's value.
    """
    folder = Path(folder)
    return {str(p): folder / "images" / f"{p}.png" for p in photo_ids}


def _flight(n_strips: int, per_strip: int, cam: Camera, height_m: float, forward: float, side: float,
            rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
    width_m, depth_m = (s * height_m / cam.focal_length_mm for s in cam.frame_size_mm)
    base = (1 - forward) * width_m
    spacing = (1 - side) * depth_m
    rows = []
    for s in range(n_strips):
        order = range(per_strip) if s % 2 == 0 else range(per_strip - 1, -1, -1)
        kappa = 0.0 if s % 2 == 0 else math.pi
        for i in order:
            rows.append([_E0 + i * base + rng.normal(0, 3.0), _N0 + s * spacing + rng.normal(0, 3.0),
                         DEMO_GROUND_M + height_m + rng.normal(0, 3.0), math.radians(rng.normal(0, 1.0)),
                         math.radians(rng.normal(0, 1.0)), kappa + math.radians(rng.normal(0, 1.5))])
    return np.array(rows), base, spacing


def aerial_scene(bounds: Sequence[float], *, texel_m: float, seed: int = 0,
                 targets: Sequence[tuple[float, float]] = (), building_density: float = 1.0) -> AerialScene:
    """A countryside with a village: roads, buildings along them, farms, fields, trees (seeded).

    Parameters
    ----------
    bounds : (xmin, ymin, xmax, ymax), m
    texel_m : float
        Albedo lattice spacing (about the GSD), m.
    seed : int
    targets : sequence of (E, N)
        Control targets: buildings keep 15 m away from them.
    building_density : float
        Scales the number of buildings (1: a building every ~25 m along the roads, 60 % of the plots).
    """
    rng = np.random.default_rng([seed, 28])
    xmin, ymin, xmax, ymax = (float(v) for v in bounds)
    w, h = xmax - xmin, ymax - ymin
    roads = []
    nm = ymin + h * rng.uniform(0.35, 0.65)
    roads.append(Road(xmin - 50, nm + rng.uniform(-10, 10), xmax + 50, nm + rng.uniform(-10, 10), 7.0))
    for _ in range(max(1, int(round(w / 400.0)))):
        e = xmin + w * rng.uniform(0.1, 0.9)
        roads.append(Road(e + rng.uniform(-30, 30), ymin - 50, e + rng.uniform(-30, 30), ymax + 50,
                          float(rng.uniform(5.0, 7.0))))
    blds: list[Building] = []
    circles: list[tuple[float, float, float]] = []

    def free(e: float, n: float, r: float) -> bool:
        if not (xmin + r < e < xmax - r and ymin + r < n < ymax - r):
            return False
        for te, tn in targets:
            if math.hypot(e - te, n - tn) < r + 15.0:
                return False
        for rd in roads:
            if float(road_distance(rd, np.array([e]), np.array([n]))[0]) < rd.width_m / 2 + r + 2.0:
                return False
        return all(math.hypot(e - ce, n - cn) > r + cr + 3.0 for ce, cn, cr in circles)

    def add(e: float, n: float, az: float) -> None:
        kind = ("hip", "gable", "pyramid", "flat", "gable")[int(rng.integers(5))]
        width = float(rng.uniform(8, 12))
        length = float(rng.uniform(width + 2, 22)) if kind != "pyramid" else width
        b = Building(kind, e, n, length_m=length, width_m=width, slope_deg=float(rng.uniform(22, 38)),
                     eave_m=float(rng.uniform(3, 7)), azimuth_deg=az + float(rng.normal(0, 3)))
        r = math.hypot(b.length_m, b.width_m) / 2
        if free(e, n, r):
            blds.append(b)
            circles.append((e, n, r))

    for rd in roads:
        a = np.array([rd.e0_m, rd.n0_m])
        ab = np.array([rd.e1_m, rd.n1_m]) - a
        L = float(np.hypot(*ab))
        u = ab / L
        nrm = np.array([-u[1], u[0]])
        az = math.degrees(math.atan2(u[1], u[0]))
        s = float(rng.uniform(0, 25))
        while s < L:
            for side in (-1, 1):
                if rng.uniform() < 0.6 * building_density:
                    off = rd.width_m / 2 + float(rng.uniform(9, 16))
                    p = a + s * u + side * off * nrm
                    add(float(p[0]), float(p[1]), az)
            s += float(rng.uniform(20, 32))
    for _ in range(int(round(building_density * w * h / 40_000.0))):   # farms
        add(float(rng.uniform(xmin, xmax)), float(rng.uniform(ymin, ymax)), float(rng.uniform(0, 180)))
    return AerialScene(demo_terrain, tuple(blds), tuple(roads), tuple(targets), texel_m=texel_m, seed=seed)


def _scene_to_json(scene: AerialScene) -> dict[str, Any]:
    return {
        "terrain": "demo",
        "texel_m": scene.texel_m, "seed": scene.seed, "field_m": scene.field_m, "trees": scene.trees,
        "sun_azimuth_deg": scene.sun_azimuth_deg, "sun_elevation_deg": scene.sun_elevation_deg,
        "targets": [list(t) for t in scene.targets],
        "roads": [dataclasses.asdict(r) for r in scene.roads],
        "buildings": [dataclasses.asdict(b) for b in scene.buildings],
    }


def _scene_from_json(d: dict[str, Any]) -> AerialScene:
    if d.get("terrain") != "demo":
        raise LidarcatError(f"scene.json: unknown terrain {d.get('terrain')!r} (expected 'demo')")
    return AerialScene(demo_terrain, tuple(Building(**b) for b in d["buildings"]),
                       tuple(Road(**r) for r in d["roads"]), tuple(tuple(t) for t in d["targets"]),
                       texel_m=d["texel_m"], seed=d["seed"], field_m=d["field_m"], trees=d["trees"],
                       sun_azimuth_deg=d["sun_azimuth_deg"], sun_elevation_deg=d["sun_elevation_deg"])


def _gps_positions(eo: np.ndarray, n_strips: int, per_strip: int, base: float, spacing: float, depth_m: float,
                   n: int) -> np.ndarray:
    """Plan positions of the control targets: in the side overlap (one strip: across the strip), from
    a base inside the first photo to a base inside the last (half a base in strips of 4 photos or
    fewer), alternating sides."""
    inset = 1.0 if per_strip > 4 else 0.5   # a base in: three photos of each strip see the target
    e_a, e_b = _E0 + inset * base, _E0 + (per_strip - 1 - inset) * base
    mid = _N0 + (n_strips - 1) * spacing / 2
    half = 0.07 * depth_m if n_strips > 1 else 0.25 * depth_m
    ne = max(1, -(-n // 2))
    es = np.linspace(e_a, e_b, ne) if ne > 1 else np.array([(e_a + e_b) / 2])
    pts = [(es[k // 2], mid + (half if k % 2 == 0 else -half)) for k in range(n)]
    return np.array(pts, dtype=float).reshape(-1, 2)


def aerial_survey(
    out_dir: str | os.PathLike,
    *,
    n_strips: int = 2,
    photos_per_strip: int = 12,
    forward_overlap: float = 0.6,
    side_overlap: float = 0.3,
    gsd_m: float = 0.2,
    image_size_px: tuple[int, int] = (1000, 750),
    approx_position_sd_m: float = 2.0,
    approx_angle_sd_deg: float = 0.5,
    n_gps_points: int = 4,
    gps_sd_m: float = 0.02,
    gps_sd_h_m: float = 0.03,
    image_sd_px: float = 0.3,
    lidar_density_m2: float = 1.0,
    lidar_noise_m: float = 0.05,
    noise_sd: float = 1.0,
    vignetting: float = 0.15,
    rgb: bool = False,
    write_xyz: bool = False,
    image_column: bool = True,
    seed: int = 0,
    supersample: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> AerialSurvey:
    """Write a synthetic aerial block with rendered photos and its truth (see the module docstring).

    Parameters
    ----------
    out_dir : path
        Survey folder (created; built in a temporary sibling and moved into place).
    n_strips, photos_per_strip : int
        Block layout.
    forward_overlap, side_overlap : float
        Overlaps along and across the strips (0 .. 1).
    gsd_m : float
        Ground sample distance at nadir, m (sets the flying height).
    image_size_px : (columns, rows)
        Photo size (6000 x 4000 for a 24 MP benchmark).
    approx_position_sd_m, approx_angle_sd_deg : float
        Errors (and written sds) of the approximate GNSS/IMU orientation.
    n_gps_points : int
        Control targets (>= 0).
    gps_sd_m, gps_sd_h_m : float
        Noise and sds of their coordinates, m.
    image_sd_px : float
        Noise of their image measurements, px.
    lidar_density_m2 : float
        LiDAR points per m^2 (0: no LiDAR tiles).
    lidar_noise_m : float
        Height noise of the LiDAR, m.
    noise_sd, vignetting : float
        Photo noise (grey values) and vignetting of every photo.
    rgb : bool
        RGB photos (default grey).
    write_xyz : bool
        Also write ``truth/xyz/<photo>.npy`` (24 bytes per pixel).
    image_column : bool
        Write the ``image`` column of photos.csv (path of the photo's file relative to the folder,
        read by :meth:`lidarcat.Survey.image_path`); off: the ``images/<photo>.png`` rule finds them.
    seed : int
    supersample : int
        Rays per pixel side at geometric edges (eaves, ridges, hips; :func:`render_photo`).
    progress : callable, optional
        ``progress(done, total)`` over the photos rendered.

    Returns
    -------
    AerialSurvey
    """
    if n_strips < 1 or photos_per_strip < 2:
        raise LidarcatError(f"a block needs at least 1 strip of 2 photos, got {n_strips} x {photos_per_strip}")
    for name, v in (("forward_overlap", forward_overlap), ("side_overlap", side_overlap)):
        if not 0 <= v < 1:
            raise LidarcatError(f"{name} must be in [0, 1), got {v}")
    for name, v in (("gsd_m", gsd_m), ("approx_position_sd_m", approx_position_sd_m),
                    ("approx_angle_sd_deg", approx_angle_sd_deg), ("gps_sd_m", gps_sd_m),
                    ("gps_sd_h_m", gps_sd_h_m), ("image_sd_px", image_sd_px)):
        if not v > 0:
            raise LidarcatError(f"{name} must be positive, got {v}")
    if n_gps_points < 0:
        raise LidarcatError(f"n_gps_points must be >= 0, got {n_gps_points}")
    rng = np.random.default_rng(seed)
    cam = aerial_camera(image_size_px)
    height = gsd_m * cam.focal_length_mm / cam.pixel_size_x_mm
    eo, base, spacing = _flight(n_strips, photos_per_strip, cam, height, forward_overlap, side_overlap, rng)
    width_m, depth_m = (s * height / cam.focal_length_mm for s in cam.frame_size_mm)
    ids = tuple(f"{s + 1}{i + 1:02d}" for s in range(n_strips) for i in range(photos_per_strip))
    approx = eo.copy()
    approx[:, :3] += rng.normal(0, approx_position_sd_m, (len(eo), 3))
    approx[:, 3:] += np.radians(rng.normal(0, approx_angle_sd_deg, (len(eo), 3)))
    exposures = tuple(Exposure.random(int(s), vignetting=vignetting, noise_sd=noise_sd)
                      for s in rng.integers(0, 2**31, len(eo)))
    gps_en = _gps_positions(eo, n_strips, photos_per_strip, base, spacing, depth_m, n_gps_points)
    gps_true = np.column_stack([gps_en, demo_terrain(gps_en[:, 0], gps_en[:, 1])]) if len(gps_en) else np.zeros((0, 3))
    gps_ids = tuple(f"G{k + 1}" for k in range(len(gps_true)))
    bounds = (_E0 - width_m / 2 - 20, _N0 - depth_m / 2 - 20,
              _E0 + (photos_per_strip - 1) * base + width_m / 2 + 20, _N0 + (n_strips - 1) * spacing + depth_m / 2 + 20)
    scene = aerial_scene(bounds, texel_m=gsd_m, seed=seed, targets=[tuple(p) for p in gps_en])

    # control: measured where the target is on the frame and seen (not hidden by a building)
    obs = []
    for k, pid in enumerate(ids):
        if not len(gps_true):
            break
        px = project_to_pixels(cam, eo[k], gps_true)
        ok = np.isfinite(px).all(axis=1)
        ok[ok] = cam.contains(px[ok], margin_px=-5.0)
        for g in np.flatnonzero(ok):
            back = ground_points(scene, cam, eo[k], px[g:g + 1])[0]
            if np.linalg.norm(back - gps_true[g]) > 0.05:
                continue
            c, r = px[g] + rng.normal(0, image_sd_px, 2)
            obs.append((pid, gps_ids[g], round(float(c), 3), round(float(r), 3)))
    gps_meas = gps_true + rng.normal(0, 1.0, gps_true.shape) * [gps_sd_m, gps_sd_m, gps_sd_h_m]

    out_dir = Path(out_dir)
    total = len(ids) + 1
    with atomic_dir(out_dir) as tmp:
        write_text_atomic(tmp / "camera.toml",
                          "# Synthetic camera of lidarcat.synthetic.aerial (known truth).\n" + cam.to_toml())
        header = ["photo", "camera", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg",
                  "sd_X0", "sd_Y0", "sd_Z0", "sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"]
        rows = []
        for pid, a in zip(ids, approx):
            ang = np.degrees(a[3:])
            ang[2] = (ang[2] + 180.0) % 360.0 - 180.0
            rows.append([pid, cam.id, *np.round(a[:3], 3), *np.round(ang, 5),
                         approx_position_sd_m, approx_position_sd_m, approx_position_sd_m,
                         approx_angle_sd_deg, approx_angle_sd_deg, approx_angle_sd_deg])
        if image_column:
            header.append("image")
            for row, pid in zip(rows, ids):
                row.append(f"images/{pid}.png")
        write_csv_atomic(tmp / "photos.csv", header, rows,
                         comments=[f"Approximate GNSS/IMU orientation: the truth (truth/eop.csv) plus errors of sd "
                                   f"{approx_position_sd_m} m and {approx_angle_sd_deg} deg (seed {seed})."])
        write_csv_atomic(tmp / "image_points.csv", ["photo", "point", "col_px", "row_px"], obs,
                         comments=[f"Control targets only (noise sd {image_sd_px} px); tie points: lidarcat match."])
        write_csv_atomic(tmp / "ground_points.csv", ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                         [(g, *np.round(p, 4), gps_sd_m, gps_sd_m, gps_sd_h_m, "gps")
                          for g, p in zip(gps_ids, gps_meas)],
                         comments=[f"GPS control targets: truth/points.csv plus noise of sd {gps_sd_m} m (E, N), "
                                   f"{gps_sd_h_m} m (h)."])
        write_csv_atomic(tmp / "control_sets.csv", ["set", "point", "role", "sd_E", "sd_N", "sd_h"],
                         [("gps", g, "control", "", "", "") for g in gps_ids],
                         comments=["gps: every control target is control."])
        n_lidar = 0
        if lidar_density_m2 > 0:
            n_lidar = _write_lidar(tmp / "lidar", scene, bounds, lidar_density_m2, lidar_noise_m, rng)
        write_text_atomic(tmp / "survey.toml", _survey_toml(seed, ids, image_sd_px * cam.pixel_size_x_mm,
                                                            bool(gps_ids), n_lidar > 0))
        (tmp / "truth").mkdir()
        write_csv_atomic(tmp / "truth" / "eop.csv", ["photo", "X0", "Y0", "Z0", "omega", "phi", "kappa"],
                         [(p, *e[:3], *np.degrees(e[3:])) for p, e in zip(ids, eo)],
                         comments=["True exterior orientation: metres and degrees, M = R3(kappa) R2(phi) R1(omega)."])
        write_csv_atomic(tmp / "truth" / "points.csv", ["point", "E", "N", "h", "kind"],
                         [(g, *p, "gps") for g, p in zip(gps_ids, gps_true)],
                         comments=["True coordinates of the control targets, metres."])
        write_csv_atomic(tmp / "truth" / "exposure.csv", ["photo", "gain", "gamma", "offset", "vignetting",
                                                          "noise_sd", "seed"],
                         [(p, x.gain, x.gamma, x.offset, x.vignetting, x.noise_sd, x.seed)
                          for p, x in zip(ids, exposures)],
                         comments=["Radiometry of each photo (lidarcat.synthetic.aerial.Exposure)."])
        meta = {"scene": _scene_to_json(scene), "camera": cam.to_dict(), "photos": list(ids),
                "true_eo": eo.tolist(), "approx_eo": approx.tolist(), "position_sd_m": approx_position_sd_m,
                "angle_sd_deg": approx_angle_sd_deg, "exposures": [dataclasses.asdict(x) for x in exposures],
                "gps_ids": list(gps_ids), "gps_true": gps_true.tolist(), "gsd_m": gsd_m, "seed": seed,
                "rgb": rgb}
        write_text_atomic(tmp / "truth" / "scene.json", json.dumps(meta, indent=1))
        write_text_atomic(tmp / "truth" / "README.md", _TRUTH_README)
        if progress:
            progress(1, total)
        import cv2

        (tmp / "images").mkdir()
        for k, pid in enumerate(ids):
            ph = render_photo(scene, cam, eo[k], exposure=exposures[k], rgb=rgb, truth=write_xyz,
                              supersample=supersample)
            ok, buf = cv2.imencode(".png", ph.image[..., ::-1] if rgb else ph.image)
            if not ok:
                raise LidarcatError(f"{out_dir}: could not encode photo {pid}")
            with atomic_write(tmp / "images" / f"{pid}.png", "wb") as fh:
                fh.write(buf.tobytes())
            if write_xyz:
                (tmp / "truth" / "xyz").mkdir(exist_ok=True)
                with atomic_write(tmp / "truth" / "xyz" / f"{pid}.npy", "wb") as fh:
                    np.save(fh, ph.xyz)
            if progress:
                progress(k + 2, total)
        files = tuple(sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file()))
    return AerialSurvey(out_dir, scene, cam, ids, eo, approx, approx_position_sd_m, approx_angle_sd_deg, exposures,
                        gps_ids, gps_true, gsd_m, seed, files)


def load_aerial_survey(path: str | os.PathLike) -> AerialSurvey:
    """The :class:`AerialSurvey` of a folder written by :func:`aerial_survey` (from ``truth/scene.json``)."""
    path = Path(path)
    f = path / "truth" / "scene.json"
    if not f.is_file():
        raise LidarcatError(f"{path}: no truth/scene.json; not a folder written by lidarcat.synthetic.aerial")
    d = json.loads(f.read_text(encoding="utf-8"))
    cam_d = dict(d["camera"])
    cam = Camera.from_dict(cam_d.pop("id"), cam_d)
    files = tuple(sorted(str(p.relative_to(path)) for p in path.rglob("*") if p.is_file()))
    return AerialSurvey(path, _scene_from_json(d["scene"]), cam, tuple(d["photos"]), np.array(d["true_eo"]),
                        np.array(d["approx_eo"]), d["position_sd_m"], d["angle_sd_deg"],
                        tuple(Exposure(**x) for x in d["exposures"]), tuple(d["gps_ids"]),
                        np.array(d["gps_true"]).reshape(-1, 3), d["gsd_m"], d["seed"], files)


def _write_lidar(folder: Path, scene: AerialScene, bounds: Sequence[float], density_m2: float, noise_m: float,
                 rng: np.random.Generator) -> int:
    """LiDAR of the scene: uniform plan positions, the visible surface + noise, class 2 / 6, intensity
    from the albedo; tiles of at most 500 m."""
    from ..lidar import PointCloud, resolve_crs, write_points

    xmin, ymin, xmax, ymax = bounds
    nx, ny = max(1, math.ceil((xmax - xmin) / 500.0)), max(1, math.ceil((ymax - ymin) / 500.0))
    ex, ey = np.linspace(xmin, xmax, nx + 1), np.linspace(ymin, ymax, ny + 1)
    folder.mkdir(parents=True, exist_ok=True)
    total = 0
    crs = resolve_crs(AERIAL_CRS)
    for i in range(nx):
        for j in range(ny):
            area = (ex[i + 1] - ex[i]) * (ey[j + 1] - ey[j])
            m = int(rng.poisson(density_m2 * area))
            if m == 0:
                continue
            e = rng.uniform(ex[i], ex[i + 1], m)
            n = rng.uniform(ey[j], ey[j + 1], m)
            h, b = scene.surface(e, n)
            alb = scene.albedo(e, n)
            lum = alb[:, 0] * 0.2126 + alb[:, 1] * 0.7152 + alb[:, 2] * 0.0722
            inten = np.clip(np.rint(lum * 8000.0 * rng.normal(1.0, 0.05, m)), 1, 65535).astype(np.uint16)
            ones = np.ones(m, dtype=np.uint8)
            cloud = PointCloud(np.column_stack([e, n, h + rng.normal(0, noise_m, m)]),
                               {"classification": np.where(b >= 0, 6, 2).astype(np.uint8), "intensity": inten,
                                "return_number": ones, "number_of_returns": ones.copy()}, crs=crs)
            write_points(folder / f"tile_{i}_{j}.laz", cloud)
            total += m
    return total


_TRUTH_README = """# Truth of the synthetic aerial block (lidarcat.synthetic.aerial)

| file | content |
|---|---|
| eop.csv | true exterior orientation of every photo (m, deg; M = R3(kappa) R2(phi) R1(omega)) |
| points.csv | true E, N, h of the control targets |
| exposure.csv | radiometry of each photo (gain, gamma, black level, vignetting, noise) |
| scene.json | everything needed to rebuild the scene and the block: `lidarcat.synthetic.aerial.load_aerial_survey` |
| xyz/<photo>.npy | (with write_xyz) true E, N, h of every pixel centre, float64 (H, W, 3), NaN where nothing |

photos.csv holds the *approximate* orientation (the GNSS/IMU observations), not this truth.
"""


def _survey_toml(seed: int, ids: Sequence[str], image_sd_mm: float, control: bool, lidar: bool) -> str:
    lines = [f"# Synthetic aerial block written by lidarcat.synthetic.aerial.aerial_survey (seed {seed}).",
             "# Known truth in truth/. Format: docs/survey-format.md.", "",
             "[survey]", f'name = "aerial-{len(ids)}photos-seed{seed}"',
             'description = "Synthetic aerial block with rendered photos and known truth"',
             f'crs = "{AERIAL_CRS}"', 'height_system = "ellipsoidal"']
    if control:
        lines.append('default_control = "gps"')
    lines += ["", "[files]", 'camera = "camera.toml"', 'photos = "photos.csv"', 'image_points = "image_points.csv"']
    if control:
        lines += ['ground_points = "ground_points.csv"', 'control_sets = "control_sets.csv"']
    if lidar:
        lines.append('lidar = ["lidar/*.laz"]')
    lines += ["", "[adjustment]", 'observations = "pixel"', f"image_sd_mm = {image_sd_mm!r}",
              'variance_factor = "a_priori"', "chi2_level = 0.05"]
    if lidar:
        lines += ["", "[lidar]", f'crs = "{AERIAL_CRS}"']
    return "\n".join(lines) + "\n"
