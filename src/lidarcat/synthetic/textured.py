r"""Small photos of a textured, gently rolling ground with the true 3-D point behind every pixel.

The test and benchmark block of :mod:`lidarcat.match`: a ground texture that does not repeat
(value noise summed over octaves from 64 m down to 0.5 m, plus fields: random rectangles of
uniform tone and roads: bright lines), a smooth terrain ``h = h0 + a sin(E / L1) cos(N / L2)``,
and frame photos along strips with an exposure of their own (gain and offset) and sensor noise.

A pixel's ray is met with the terrain by the fixed-point iteration of
:func:`lidarcat.match.rays.ray_to_surface` (exact to micrometres on this relief), the texture
is sampled bilinearly there; the intersection is the pixel's true object point, so a matched
observation is scored by projecting the true point of its partner into its photo.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry.camera import Camera

__all__ = ["TexturedGround", "TexturedSurvey", "small_camera", "strip_layout", "render_photo", "true_points",
           "write_textured_survey", "observation_errors"]


def small_camera(columns_px: int = 800, rows_px: int = 600, *, focal_mm: float = 20.0, pixel_mm: float = 0.01,
                 k1: float = -2e-5) -> Camera:
    """A small frame camera (default 800 x 600 px of 10 um, c = 20 mm, mild barrel distortion)."""
    return Camera("small", focal_mm, 0.005, -0.004, k1, 0.0, 0.0, 1e-6, 0.0, 0.0, pixel_mm, pixel_mm,
                  int(columns_px), int(rows_px), model="synthetic small frame", source="lidarcat.synthetic.textured")


@dataclass(frozen=True, eq=False)
class TexturedGround:
    """Texture raster and terrain of a rectangular area (see the module docstring).

    Attributes
    ----------
    x0_m, y0_m : float
        West and north edge of the texture raster.
    cell_m : float
    texture : ndarray (rows, cols) float32, 0..1
    h0_m, relief_m : float
        Mean height and amplitude of the terrain.
    """

    x0_m: float
    y0_m: float
    cell_m: float
    texture: np.ndarray
    h0_m: float = 100.0
    relief_m: float = 8.0

    @classmethod
    def make(cls, bounds: Sequence[float], *, cell_m: float = 0.2, seed: int = 0, h0_m: float = 100.0,
             relief_m: float = 8.0) -> TexturedGround:
        """Texture over *bounds* (E min, N min, E max, N max; m)."""
        import cv2

        rng = np.random.default_rng(seed)
        xmin, ymin, xmax, ymax = (float(v) for v in bounds)
        cols, rows = int(math.ceil((xmax - xmin) / cell_m)), int(math.ceil((ymax - ymin) / cell_m))
        tex = np.zeros((rows, cols), np.float32)
        wavelength, amp = 64.0, 1.0
        while wavelength >= 4 * cell_m:
            n_r, n_c = max(2, int(rows * cell_m / wavelength) + 2), max(2, int(cols * cell_m / wavelength) + 2)
            g = rng.standard_normal((n_r, n_c)).astype(np.float32)
            tex += amp * cv2.resize(g, (cols, rows), interpolation=cv2.INTER_CUBIC)
            wavelength /= 2
            amp *= 0.75
        for _ in range(int((xmax - xmin) * (ymax - ymin) / 2500)):   # fields: one per 50 x 50 m
            w, h = rng.uniform(10, 60, 2) / cell_m
            c0, r0 = rng.uniform(0, cols), rng.uniform(0, rows)
            tone = rng.normal(0, 1.5)
            tex[int(r0):int(r0 + h), int(c0):int(c0 + w)] = 0.5 * tex[int(r0):int(r0 + h), int(c0):int(c0 + w)] + tone
        for _ in range(max(1, int((xmax - xmin) / 150))):            # roads
            p = rng.uniform([0, 0], [cols, rows])
            a = rng.uniform(0, np.pi)
            d = np.array([np.cos(a), np.sin(a)]) * 4 * max(rows, cols)
            cv2.line(tex, tuple(int(v) for v in p - d), tuple(int(v) for v in p + d), 4.0, max(1, int(6 / cell_m)))
        lo, hi = np.percentile(tex, [1, 99])
        tex = np.clip((tex - lo) / (hi - lo), 0, 1).astype(np.float32)
        return cls(xmin, ymax, cell_m, tex, h0_m, relief_m)

    def height(self, e_m: np.ndarray, n_m: np.ndarray) -> np.ndarray:
        """Terrain height, m."""
        return self.h0_m + self.relief_m * np.sin(np.asarray(e_m) / 90.0) * np.cos(np.asarray(n_m) / 70.0)

    def surface(self, cell_m: float = 2.0, margin_m: float = 0.0):
        """The terrain as a :class:`lidarcat.match.rays.HeightSurface` grid (as a LiDAR DTM would give it)."""
        from ..match.rays import HeightSurface

        rows, cols = self.texture.shape
        w, h = cols * self.cell_m + 2 * margin_m, rows * self.cell_m + 2 * margin_m
        nc, nr = int(w / cell_m) + 1, int(h / cell_m) + 1
        e = self.x0_m - margin_m + (np.arange(nc) + 0.5) * cell_m
        n = self.y0_m + margin_m - (np.arange(nr) + 0.5) * cell_m
        grid = self.height(e[None, :], n[:, None])
        return HeightSurface(self.h0_m, grid, self.x0_m - margin_m, self.y0_m + margin_m, cell_m, sd_m=0.2)

    def sample(self, e_m: np.ndarray, n_m: np.ndarray) -> np.ndarray:
        """Texture (0..1) at plan positions, bilinear."""
        import cv2

        e = np.asarray(e_m, dtype=np.float64).ravel()
        n = np.asarray(n_m, dtype=np.float64).ravel()
        pad = (-len(e)) % 1024      # remap wants maps under 32,767 a side: rows of 1,024
        mx = np.r_[(e - self.x0_m) / self.cell_m - 0.5, np.zeros(pad)].astype(np.float32).reshape(-1, 1024)
        my = np.r_[(self.y0_m - n) / self.cell_m - 0.5, np.zeros(pad)].astype(np.float32).reshape(-1, 1024)
        out = cv2.remap(self.texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        return out.ravel()[:len(e)].reshape(np.shape(e_m))


def strip_layout(n_strips: int, per_strip: int, camera: Camera, height_m: float, *, forward: float = 0.6,
                 side: float = 0.3, origin: Sequence[float] = (1000.0, 5000.0), h0_m: float = 100.0) -> np.ndarray:
    """Exterior orientations (n, 6; m, rad) of a block of strips flown east-west, alternating direction.

    The photo's columns lie along the flight line; *forward* / *side* are the overlaps.
    """
    scale = (height_m - h0_m) / camera.focal_length_mm
    w = camera.columns_px * camera.pixel_size_x_mm * scale
    h = camera.rows_px * camera.pixel_size_y_mm * scale
    base, spacing = w * (1 - forward), h * (1 - side)
    out = []
    for s in range(n_strips):
        for k in range(per_strip):
            kk = k if s % 2 == 0 else per_strip - 1 - k
            kappa = 0.0 if s % 2 == 0 else np.pi
            out.append([origin[0] + kk * base, origin[1] - s * spacing, height_m, 0.0, 0.0, kappa])
    return np.array(out, dtype=np.float64)


def true_points(ground: TexturedGround, camera: Camera, eo: Sequence[float], colrow_px: np.ndarray) -> np.ndarray:
    """The true object points (E, N, h; m) behind pixels, (n, 3)."""
    from ..match.rays import ray_directions

    eo = np.asarray(eo, dtype=np.float64)
    d = ray_directions(camera, eo, colrow_px)
    t = (ground.h0_m - eo[2]) / d[:, 2]
    for _ in range(50):      # the fixed point: stop at a micrometre of height
        e, n = eo[0] + t * d[:, 0], eo[1] + t * d[:, 1]
        t_new = (ground.height(e, n) - eo[2]) / d[:, 2]
        step = float(np.max(np.abs((t_new - t) * d[:, 2]))) if len(t) else 0.0
        t = t_new
        if step < 1e-6:
            break
    return np.column_stack([eo[0] + t * d[:, 0], eo[1] + t * d[:, 1], eo[2] + t * d[:, 2]])


def render_photo(ground: TexturedGround, camera: Camera, eo: Sequence[float], *, gain: float = 1.0,
                 offset: float = 0.0, noise: float = 2.0, seed: int = 0, supersample: int = 2) -> np.ndarray:
    """A grey uint8 photo (rows, cols) of *ground* from *eo* (m, rad).

    Each pixel averages ``supersample²`` rays (the sensor integrates over the pixel), then
    ``255 (gain * texture + offset)`` plus Gaussian noise of *noise* grey values.
    """
    s = int(supersample)
    c = (np.arange(camera.columns_px * s) + 0.5) / s - 0.5
    r = (np.arange(camera.rows_px * s) + 0.5) / s - 0.5
    img = np.empty((camera.rows_px, camera.columns_px), np.float32)
    band = max(1, 65536 // (camera.columns_px * s * s))
    for r0 in range(0, camera.rows_px, band):
        rr = r[r0 * s:(r0 + band) * s]
        cc, rg = np.meshgrid(c, rr)
        xyz = true_points(ground, camera, eo, np.column_stack([cc.ravel(), rg.ravel()]))
        v = ground.sample(xyz[:, 0], xyz[:, 1]).reshape(len(rr), -1)
        img[r0:r0 + band] = v.reshape(len(rr) // s, s, -1, s).mean(axis=(1, 3))
    rng = np.random.default_rng(seed)
    out = 255.0 * (gain * img + offset) + rng.normal(0, noise, img.shape)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class TexturedSurvey:
    """A survey folder of rendered photos (:func:`write_textured_survey`) and its truth.

    Attributes
    ----------
    folder : Path
    ground : TexturedGround
    camera : Camera
    ids : tuple of str
    true_eo, approx_eo : ndarray (n, 6)
        X0, Y0, Z0 (m), omega, phi, kappa (rad): the truth and what photos.csv says.
    """

    folder: Any
    ground: TexturedGround
    camera: Camera
    ids: tuple[str, ...]
    true_eo: np.ndarray
    approx_eo: np.ndarray


def write_textured_survey(folder: Any, *, n_strips: int = 2, per_strip: int = 3, columns_px: int = 640,
                          rows_px: int = 480, height_m: float = 600.0, sd_position_m: float = 2.0,
                          sd_angle_deg: float = 0.5, seed: int = 0, forward: float = 0.6, side: float = 0.3,
                          image_suffix: str = ".png") -> TexturedSurvey:
    """Write a survey folder of rendered photos with approximate orientations (no image observations yet).

    survey.toml (CRS ``local``), camera.toml, photos.csv with the ``image`` column and the true
    orientation perturbed by ``N(0, sd)`` (and those sds), an image_points.csv with its header only,
    ground_points.csv with four GPS points on the terrain (they give the mean ground height),
    ``images/<photo>.png`` with an exposure of their own.
    """
    import cv2
    from pathlib import Path

    root = Path(folder)
    (root / "images").mkdir(parents=True, exist_ok=True)
    cam = small_camera(columns_px, rows_px)
    eo = strip_layout(n_strips, per_strip, cam, height_m, forward=forward, side=side)
    rng = np.random.default_rng(seed)
    approx = eo + np.column_stack([rng.normal(0, sd_position_m, (len(eo), 3)),
                                   np.deg2rad(rng.normal(0, sd_angle_deg, (len(eo), 3)))])
    scale = (height_m - 100.0) / cam.focal_length_mm
    half = 0.5 * np.array([cam.columns_px * cam.pixel_size_x_mm, cam.rows_px * cam.pixel_size_y_mm]) * scale
    pad = float(np.hypot(*half)) + 60.0
    bounds = (eo[:, 0].min() - pad, eo[:, 1].min() - pad, eo[:, 0].max() + pad, eo[:, 1].max() + pad)
    ground = TexturedGround.make(bounds, seed=seed)
    ids = tuple(f"{k + 1:02d}" for k in range(len(eo)))
    rows = ["photo,camera,image,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0,sd_omega_deg,sd_phi_deg,"
            "sd_kappa_deg"]
    for k, pid in enumerate(ids):
        img = render_photo(ground, cam, eo[k], gain=float(rng.uniform(0.75, 1.0)), offset=float(rng.uniform(-0.05, 0.1)),
                           noise=2.0, seed=seed * 1000 + k)
        cv2.imwrite(str(root / "images" / f"{pid}{image_suffix}"), img)
        p, a = approx[k, :3], np.rad2deg(approx[k, 3:])
        rows.append(f"{pid},small,images/{pid}{image_suffix},{p[0]:.3f},{p[1]:.3f},{p[2]:.3f},{a[0]:.5f},{a[1]:.5f},"
                    f"{a[2]:.5f},{sd_position_m},{sd_position_m},{sd_position_m},{sd_angle_deg},{sd_angle_deg},"
                    f"{sd_angle_deg}")
    (root / "photos.csv").write_text("\n".join(rows) + "\n")
    (root / "camera.toml").write_text(cam.to_toml())
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\n")
    c = eo[:, :2].mean(axis=0)
    gp = ["point,E,N,h,sd_E,sd_N,sd_h,source"]
    for k, (de, dn) in enumerate([(-40, -30), (40, -30), (40, 30), (-40, 30)]):
        e, n = c[0] + de, c[1] + dn
        gp.append(f"G{k + 1},{e:.3f},{n:.3f},{float(ground.height(np.array(e), np.array(n))):.3f},0.05,0.05,0.05,gps")
    (root / "ground_points.csv").write_text("\n".join(gp) + "\n")
    (root / "survey.toml").write_text(
        '[survey]\nname = "textured"\ndescription = "rendered photos of a textured ground (lidarcat.synthetic.textured)"\n'
        'crs = "local: synthetic textured ground"\nheight_system = "ellipsoidal"\n\n[files]\ncamera = "camera.toml"\n'
        'photos = "photos.csv"\nimage_points = "image_points.csv"\nground_points = "ground_points.csv"\n\n'
        '[adjustment]\nobservations = "pixel"\n')
    return TexturedSurvey(root, ground, cam, ids, eo, approx)


def observation_errors(ground: TexturedGround, camera: Camera, true_eo: np.ndarray, track: np.ndarray,
                       photo: np.ndarray, xy_px: np.ndarray) -> np.ndarray:
    """Distance (px) of every observation from the truth of its track, (n,).

    Each observation's true object point is the ground behind its pixel (true orientation);
    the track's true point is the median of those (robust to one wrong ray of three and more;
    the mean of two), and an observation's error is its distance from that point's
    projection with the true orientation.  A wrong match of a two-ray track shows as both
    rays off by half the mismatch.
    """
    from ..match.rays import project_to_pixel

    track = np.asarray(track, np.int64)
    photo = np.asarray(photo, np.int64)
    xyz = np.empty((len(track), 3))
    for p in np.unique(photo):
        sel = photo == p
        xyz[sel] = true_points(ground, camera, true_eo[p], xy_px[sel])
    order = np.argsort(track, kind="stable")
    ts = track[order]
    starts = np.flatnonzero(np.r_[True, ts[1:] != ts[:-1]])
    centre = np.empty((len(starts), 3))
    for k, (a, b) in enumerate(zip(starts, np.r_[starts[1:], len(ts)])):
        centre[k] = np.median(xyz[order[a:b]], axis=0)
    tid = np.empty(len(track), np.int64)
    tid[order] = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(ts)]))
    err = np.empty(len(track))
    for p in np.unique(photo):
        sel = photo == p
        px, _ = project_to_pixel(camera, true_eo[p], centre[tid[sel]])
        err[sel] = np.hypot(*(px - xy_px[sel]).T)
    return err
