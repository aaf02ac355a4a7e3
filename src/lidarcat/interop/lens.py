r"""The camera an export writes: every camera of a block as a Brown (OpenCV) or fisheye model in pixels.

COLMAP (``OPENCV``, ``FULL_OPENCV``), OpenSfM (``brown``) and orthority (``brown``) project
ideal normalised coordinates ``(x, y) = (X_c/Z_c, Y_c/Z_c)`` (y down) *forward* through the
distortion (:func:`lidarcat.interop._distortion.distort`) and then
``u = f_x x_d + c_x``, ``v = f_y y_d + c_y`` (pixels, image corner at the origin).  The
cameras of a block come in three kinds:

source
    A Brown model read from COLMAP/OpenSfM (``block.source_models``): written back as it is.
exact
    A model that is algebraically a Brown model: a lidarcat camera without distortion
    (``K_i = P_i = eps45 = 0``: the pinhole ``f_x = c/t_x``, ``c_x = N_c/2 + dx/t_x``,
    ``f_y = c/t_y``, ``c_y = N_L/2 - dy/t_y``, eq. 01-02 with the corner origin), or a
    Metashape frame model with ``k4 = b2 = 0`` (Metashape's p1, p2 are OpenCV's p2, p1;
    ``f_x = f + b1``).
fitted
    lidarcat's camera with distortion (eq. 03-07) is the *inverse* kind of model: the
    correction is a polynomial of the distorted coordinate, ``x_c = x_fot - d(x_fot)``, and
    its inverse is no finite polynomial.  It is fitted: the pinhole is kept exact at the
    principal point (``f_x = c / (t_x (1 - eps45))``, the slope of eq. 07 there; ``c_x, c_y``
    as above) and on a grid of 41 x 31 pixel positions spanning the whole image (corners
    included) each pixel ``(u, v)`` is taken through eq. 01-07 to its ideal normalised
    coordinate ``(x_c/c, -y_c/c)``; the forward model is linear in ``k1, k2, k3, p1, p2``,
    which linear least squares in pixels gives.  The largest misfit over the grid, in
    pixels, travels with the model (``fit_max_px``) into the export's
    notes.  Metashape models with ``k4`` or skew ``b2`` are fitted the same way.

Fisheyes (:mod:`lidarcat.interop.cameras`): a ``fisheye`` source model (Kannala-Brandt, COLMAP
``OPENCV_FISHEYE``, OpenSfM ``fisheye_opencv``) is written as it is; a Metashape fisheye exactly as
one when it has no tangential (p1, p2) and skew (b2) terms, else with ``k1..k4`` fitted by linear
least squares in pixels over the grid (``theta_d`` is linear in them; :func:`fit_fisheye`).  A
target without a fisheye model (OPK camera files, ``fisheye=False``) gets the fisheye fitted as
Brown over the grid when the image lies within 90 deg of the axis, and a located refusal otherwise.

The observations an export writes (:func:`observed_pixels`) are the measured pixels for a
camera with a source model, and for a lidarcat camera the corrected photo coordinates the
adjustment used taken back to pixels through the camera
(:meth:`lidarcat.geometry.camera.Camera.photo_to_pixel`), so that the exported camera
reprojects them as lidarcat does (to within ``fit_max_px``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import FormatError
from ..geometry.camera import Camera
from ._distortion import distort

__all__ = ["ExportCamera", "export_camera", "export_cameras", "observed_pixels", "fit_brown", "fit_fisheye", "notes",
           "GRID"]

#: fitting grid: columns x rows of pixel positions over the whole image
GRID = (41, 31)

_BROWN = ("k1", "k2", "k3", "p1", "p2")


def _pinhole(cam: Camera) -> tuple[float, float, float, float]:
    fx, fy = cam.focal_length_mm / cam.pixel_size_x_mm, cam.focal_length_mm / cam.pixel_size_y_mm
    cx = cam.columns_px / 2 + cam.principal_point_x_mm / cam.pixel_size_x_mm
    cy = cam.rows_px / 2 - cam.principal_point_y_mm / cam.pixel_size_y_mm
    return fx, fy, cx, cy


def _has_distortion(cam: Camera) -> bool:
    return any(getattr(cam, k) != 0.0 for k in ("k1", "k2", "k3", "p1", "p2", "refraction_eps45"))


class ExportCamera(dict):
    """A Brown model in pixels (the keys of :func:`lidarcat.interop.block.pinhole_camera`'s dict:
    ``fx, fy, cx, cy, w, h, dist, kind="brown"``) plus ``how`` (``source``, ``exact`` or
    ``fitted``) and ``fit_max_px`` (0 unless fitted)."""


def _grid(w: int, h: int) -> np.ndarray:
    """(n, 2) corner-origin pixel positions spanning the image, its corners included."""
    u, v = np.meshgrid(np.linspace(0.0, w, GRID[0]), np.linspace(0.0, h, GRID[1]))
    return np.column_stack([u.ravel(), v.ravel()])


def fit_brown(corner_px: np.ndarray, ideal: np.ndarray, pinhole: tuple[float, float, float, float]
              ) -> tuple[dict[str, float], float]:
    """Brown distortion taking *ideal* (n, 2) normalised coordinates (y down) through the fixed
    *pinhole* (fx, fy, cx, cy) to *corner_px* (n, 2): linear least squares in pixels (the model is
    linear in k1, k2, k3, p1, p2); returns (dist, largest misfit px)."""
    fx, fy, cx, cy = pinhole
    x, y = ideal[:, 0], ideal[:, 1]
    r2 = x * x + y * y
    ax = np.column_stack([x * r2, x * r2**2, x * r2**3, 2 * x * y, r2 + 2 * x * x]) * fx
    ay = np.column_stack([y * r2, y * r2**2, y * r2**3, r2 + 2 * y * y, 2 * x * y]) * fy
    bx = corner_px[:, 0] - cx - fx * x
    by = corner_px[:, 1] - cy - fy * y
    sol, *_ = np.linalg.lstsq(np.vstack([ax, ay]), np.concatenate([bx, by]), rcond=None)
    dist = dict(zip(_BROWN, (float(v) for v in sol)))
    xd = distort(ideal, dist)
    r = xd * [fx, fy] + [cx, cy] - corner_px
    return dist, float(np.hypot(r[:, 0], r[:, 1]).max())


def _fit_source(source: dict, camera_id: str = "") -> ExportCamera:
    """A source-program model (Metashape's with k4/skew, a rational FULL_OPENCV one, a fisheye whose
    image lies within 90 deg of the axis) fitted as Brown over the image.

    Raises
    ------
    FormatError
        A fisheye whose image reaches 90 deg from the axis (no Brown camera sees it).
    """
    from .cameras import source_rays

    corner = _grid(source["w"], source["h"])
    rays = source_rays(corner, source, camera_id)
    if not (rays[:, 2] > 1e-6).all():
        raise FormatError(f"camera {camera_id!r}: its {source['kind']} image reaches "
                          f"{np.degrees(np.arccos(np.clip(rays[:, 2].min(), -1, 1))):.4g} deg from the optical axis; "
                          f"the target format has Brown (OpenCV) cameras only, which see less than 90 deg: export "
                          f"to COLMAP or OpenSfM, which carry the fisheye model")
    ideal = rays[:, :2] / rays[:, 2:]
    fx, fy, cx, cy = source["fx"], source["fy"], source["cx"], source["cy"]
    dist, worst = fit_brown(corner, ideal, (fx, fy, cx, cy))
    return ExportCamera(w=source["w"], h=source["h"], fx=fx, fy=fy, cx=cx, cy=cy, dist=dist, kind="brown",
                        how="fitted", fit_max_px=worst)


def fit_fisheye(source: dict, camera_id: str = "") -> ExportCamera:
    """A Metashape fisheye with tangential or skew terms as a Kannala-Brandt fisheye: ``fx, fy, cx, cy``
    kept, ``k1..k4`` by linear least squares in pixels over the image (``theta_d`` is linear in them);
    the largest misfit travels with the model."""
    from .cameras import source_rays

    corner = _grid(source["w"], source["h"])
    rays = source_rays(corner, source, camera_id)
    rho = np.hypot(rays[:, 0], rays[:, 1])
    theta = np.arctan2(rho, rays[:, 2])
    with np.errstate(all="ignore"):
        unit = np.where((rho > 0)[:, None], rays[:, :2] / np.where(rho > 0, rho, 1.0)[:, None], 0.0)
    fx, fy, cx, cy = source["fx"], source["fy"], source["cx"], source["cy"]
    powers = np.column_stack([theta ** (2 * i + 3) for i in range(4)])
    a = np.vstack([powers * (fx * unit[:, :1]), powers * (fy * unit[:, 1:])])
    b = np.concatenate([corner[:, 0] - cx - fx * theta * unit[:, 0], corner[:, 1] - cy - fy * theta * unit[:, 1]])
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    out = ExportCamera(w=source["w"], h=source["h"], fx=fx, fy=fy, cx=cx, cy=cy, kind="fisheye",
                       dist=dict(zip(("k1", "k2", "k3", "k4"), (float(v) for v in sol))), how="fitted")
    from .cameras import project_corner_px

    r = project_corner_px(rays, out, camera_id) - corner
    out["fit_max_px"] = float(np.hypot(r[:, 0], r[:, 1]).max())
    return out


def export_camera(cam: Camera, source: dict | None = None, *, rational: bool = True,
                  fisheye: bool = True) -> ExportCamera:
    """The model an export writes for *cam* (and its source-program model, if any).

    *rational* False: the target has no ``k4..k6`` (OpenSfM ``brown``), so a source model with
    them is fitted.  *fisheye* False: the target has no fisheye model (OPK camera files), so a
    fisheye is fitted as Brown (refused when its image reaches 90 deg from the axis).  A
    ``fisheye`` source model is written as it is; a Metashape fisheye exactly as a fisheye when it
    has no tangential and skew terms, else fitted (:func:`fit_fisheye`).
    """
    kind = None if source is None else source.get("kind")
    if kind in ("fisheye", "metashape_fisheye") and not fisheye:
        return _fit_source(source, cam.id)  # type: ignore[arg-type]
    if kind == "fisheye":
        return ExportCamera(source, how="source", fit_max_px=0.0)  # type: ignore[arg-type]
    if kind == "metashape_fisheye":
        d = source["dist"]  # type: ignore[index]
        if not (d.get("p1", 0.0) or d.get("p2", 0.0) or source.get("skew", 0.0)):  # type: ignore[union-attr]
            return ExportCamera({k: source[k] for k in ("fx", "fy", "cx", "cy", "w", "h")},  # type: ignore[index]
                                kind="fisheye", how="exact", fit_max_px=0.0,
                                dist={k: d.get(k, 0.0) for k in ("k1", "k2", "k3", "k4")})
        return fit_fisheye(source, cam.id)  # type: ignore[arg-type]
    if source is not None and source.get("kind") == "brown":
        if rational or not any(source["dist"].get(k, 0.0) for k in ("k4", "k5", "k6")):
            return ExportCamera(source, how="source", fit_max_px=0.0)
        return _fit_source(source, cam.id)
    if source is not None and source.get("kind") == "metashape":
        d = source["dist"]
        if not d.get("k4", 0.0) and not source.get("skew", 0.0):
            return ExportCamera({k: source[k] for k in ("fx", "fy", "cx", "cy", "w", "h")}, kind="brown",
                                how="exact", fit_max_px=0.0,
                                dist={"k1": d.get("k1", 0.0), "k2": d.get("k2", 0.0), "k3": d.get("k3", 0.0),
                                      "p1": d.get("p2", 0.0), "p2": d.get("p1", 0.0)})
        return _fit_source(source, cam.id)
    fx, fy, cx, cy = _pinhole(cam)
    base = {"w": int(cam.columns_px), "h": int(cam.rows_px), "kind": "brown"}
    if not _has_distortion(cam):
        return ExportCamera(base, fx=fx, fy=fy, cx=cx, cy=cy, dist={k: 0.0 for k in _BROWN}, how="exact",
                            fit_max_px=0.0)
    corner = _grid(cam.columns_px, cam.rows_px)
    xy_mm = np.asarray(cam.pixel_to_photo(corner - 0.5))
    ideal = np.column_stack([xy_mm[:, 0], -xy_mm[:, 1]]) / cam.focal_length_mm
    scale = 1.0 / (1.0 - cam.refraction_eps45)  # the slope of eq. 07 at the principal point
    fx, fy = fx * scale, fy * scale
    dist, worst = fit_brown(corner, ideal, (fx, fy, cx, cy))
    return ExportCamera(base, fx=fx, fy=fy, cx=cx, cy=cy, dist=dist, how="fitted", fit_max_px=worst)


def export_cameras(block: Any, *, rational: bool = True, fisheye: bool = True) -> dict[str, ExportCamera]:
    """Camera id -> :func:`export_camera` for every camera of *block*."""
    return {cid: export_camera(cam, block.source_models.get(cid), rational=rational, fisheye=fisheye)
            for cid, cam in block.cameras.items()}


def observed_pixels(block: Any) -> np.ndarray:
    """Pixels (n, 2) of every observation, corner origin (COLMAP, OpenSfM), in the camera an export
    writes: the measured pixels ``obs_px + 0.5`` for a camera with a source-program model; for a
    lidarcat camera the corrected photo coordinates ``obs_mm`` (what the adjustment used) taken
    back to pixels through the camera (:meth:`lidarcat.geometry.camera.Camera.photo_to_pixel`),
    else ``obs_px + 0.5``."""
    out = np.asarray(block.obs_px, dtype=float) + 0.5
    cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
    cams = np.array([cam_of[p] for p in block.obs_photo.tolist()], dtype=str)
    has_mm = np.isfinite(block.obs_mm).all(axis=1)
    for cid in np.unique(cams):
        rows = (cams == cid) & (has_mm if cid not in block.source_models else ~np.isfinite(out).all(axis=1))
        if rows.any():
            out[rows] = np.asarray(block.cameras[cid].photo_to_pixel(block.obs_mm[rows])).reshape(-1, 2) + 0.5
    return out


def notes(models: dict[str, ExportCamera]) -> list[str]:
    """One line per camera: how its model was carried over (and the fit's largest misfit)."""
    out = []
    for cid, m in models.items():
        name = "fisheye (Kannala-Brandt)" if m["kind"] == "fisheye" else "Brown (OpenCV)"
        if m["how"] == "fitted":
            out.append(f"camera {cid}: distortion model converted to {name} by a least-squares fit "
                       f"over a {GRID[0]}x{GRID[1]} pixel grid, largest misfit {m['fit_max_px']:.3g} px")
        elif m["how"] == "exact":
            out.append(f"camera {cid}: converted to {name} exactly")
        else:
            out.append(f"camera {cid}: the source program's {'fisheye' if m['kind'] == 'fisheye' else 'Brown'} model, "
                       f"unchanged")
    return out
