r"""The source programs' camera models in a block: lidarcat's stand-in camera, ideal observations, projection.

A block imported from COLMAP, OpenSfM, ODM or Metashape keeps two things per camera
(:class:`~lidarcat.interop.block.Block`): lidarcat's frame camera *without distortion* (the
stand-in the bundle works with, :func:`pinhole_camera`) and the source program's model, a dict in
pixels (``block.source_models``, ``source_cameras.json`` in the survey folder) that an export writes
back unchanged.  The measured pixels are made *ideal* on import -- taken through the source model
to the ray they see and from there to the stand-in's image plane -- so that the bundle's pinhole
sees exactly what the source camera saw.

Source-model kinds (``model["kind"]``; ``fx, fy, cx, cy`` in pixels with the image *corner* at
the origin, ``w, h`` the image size, ``dist`` the distortion coefficients):

``brown``
    COLMAP ``SIMPLE_RADIAL`` .. ``FULL_OPENCV``, OpenSfM ``perspective``/``brown``: the forward
    distortion of :mod:`lidarcat.interop._distortion` on ``(X/Z, Y/Z)``, with optional ``skew``.
``metashape``
    Metashape's frame model (k1..k4, its p1, p2 swapped, ``skew`` = b2).
``fisheye``
    Equidistant Kannala-Brandt (COLMAP ``OPENCV_FISHEYE``, ``RADIAL_FISHEYE``,
    ``SIMPLE_RADIAL_FISHEYE``; OpenSfM ``fisheye_opencv``, ``fisheye``; ODM; Metashape fisheye
    without tangential terms): ``theta = atan2(sqrt(X^2 + Y^2), Z)``,
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``,
    ``u = fx theta_d X / rho + cx`` (``rho = sqrt(X^2 + Y^2)``), ``v = fy theta_d Y / rho + cy``.
    Projection and its inverse are those of :class:`lidarcat.geometry.models.FisheyeCamera`
    (pixel-centre origin: ``cx - 0.5``; the conversion is :func:`lidarcat.geometry.conversion.from_colmap`'s).
``metashape_fisheye``
    Metashape's fisheye (manual, appendix "Camera models"): the equidistant mapping
    ``(x, y) = theta (X, Y) / rho`` followed by Metashape's frame distortion of ``(x, y)``
    (k1..k4, p1, p2, b1, b2).  Its inverse undistorts ``(x', y')`` to ``(x, y)``
    (:func:`lidarcat.interop._distortion.undistort`), then ``theta = |(x, y)|`` and the ray is
    ``(sin theta (x, y) / theta, cos theta)``.

Ideal observations (:func:`ideal_observations`).  The stand-in camera is the pinhole with the
source's ``fx, fy, cx, cy``: a ray ``(X, Y, Z)`` meets its image plane at ``n = (X/Z, Y/Z)`` and the
corrected photo coordinate is ``x_mm = c n_x``, ``y_mm = -c n_y`` (``c`` the focal length in mm).
A fisheye sees rays at 90 deg from the axis and beyond, which meet no image plane; near 90 deg the
plane coordinate ``tan theta`` runs off (its sensitivity to the angle is ``1/cos^2 theta``).
Rays farther than :data:`MAX_RAY_ANGLE_DEG` (85 deg) from the optical axis are therefore *skipped*:
left out of the block with a warning that names the file, the camera, how many and the angles
(the export writes the measured pixels of the observations it has).  The others get their own sd
(``Block.obs_sd_mm``, written as ``sd_x_mm, sd_y_mm`` of ``image_points.csv``): a measured pixel's
sd (:data:`FISHEYE_SD_PX`, the survey's default 0.75 px) carried through the derivative of the
image-plane point by the pixel, which grows as ``1/cos^2 theta`` away from the axis.  With a pixel
pitch ``t`` the sd is about ``t sd_px / cos^2 theta``: at 85 deg and the default pitches
(``t <= 0.1`` mm) below the survey's 10 mm bound.
"""

from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from ..errors import CameraError, FormatError
from ..geometry.camera import Camera

__all__ = ["pinhole_camera", "undistorted_mm", "ideal_observations", "project_corner_px", "fisheye_model",
           "source_rays", "check_source_model", "default_pixel_size_mm", "FISHEYE_KINDS", "FISHEYE_SD_PX",
           "SOURCE_KINDS", "MAX_RAY_ANGLE_DEG"]

log = logging.getLogger(__name__)

#: widest angle from the optical axis an observation may see to become an image-plane observation, deg
MAX_RAY_ANGLE_DEG = 85.0
#: sd of a measured pixel a fisheye observation's image-plane sd is propagated from (the survey's default,
#: :data:`lidarcat.survey.schema.DEFAULT_SD_PIXELS`)
FISHEYE_SD_PX = 0.75
#: source-model kinds that are fisheyes
FISHEYE_KINDS = ("fisheye", "metashape_fisheye")
#: every source-model kind
SOURCE_KINDS = ("brown", "metashape") + FISHEYE_KINDS
_FISHEYE_K = ("k1", "k2", "k3", "k4")


def default_pixel_size_mm(fx: float) -> float:
    """The pixel pitch given to a camera that has none (COLMAP, OpenSfM): 0.001 mm, or 0.01, 0.1 mm when
    the focal length would otherwise be under lidarcat's 0.5 mm (a fisheye of 285 px).  Any pitch gives
    the same geometry.

    >>> default_pixel_size_mm(1200.0), default_pixel_size_mm(284.5)
    (0.001, 0.01)
    """
    t = 0.001
    while fx * t < 0.5 and t < 0.1:
        t *= 10
    return round(t, 6)


def pinhole_camera(camera_id: str, fx: float, fy: float, cx: float, cy: float, w: int, h: int, *,
                   pixel_size_mm: float | None, model: str, source: str, dist: dict | None = None,
                   kind: str = "brown") -> tuple[Camera, dict]:
    """lidarcat's camera for a source-program camera given in pixels, and its source-model dict.

    ``fx, fy`` focal lengths (px), ``cx, cy`` principal point (px, origin at the upper-left image
    *corner*), ``w, h`` image size.  With pixel pitch ``t``: ``focal_length_mm = fx t``,
    ``pixel_size_y_mm = t fx / fy``, ``dx = t (cx - w/2)``, ``dy = -t_y (cy - h/2)`` (eq. 01-02);
    *pixel_size_mm* None: :func:`default_pixel_size_mm`.
    The lidarcat camera has no distortion: the source distortion stays in the dict (for a fisheye
    the pinhole is that of the ideal image plane ``(X/Z, Y/Z)``).

    >>> cam, _ = pinhole_camera("c", 1000.0, 1000.0, 50.0, 40.0, 100, 80, pixel_size_mm=0.01,
    ...                         model="m", source="s")
    >>> cam.focal_length_mm, cam.principal_point_x_mm, cam.principal_point_y_mm
    (10.0, 0.0, -0.0)
    """
    t = default_pixel_size_mm(fx) if pixel_size_mm is None else float(pixel_size_mm)
    cam = Camera(camera_id, focal_length_mm=fx * t, principal_point_x_mm=t * (cx - w / 2),
                 principal_point_y_mm=-(t * fx / fy) * (cy - h / 2), k1=0.0, k2=0.0, k3=0.0,
                 p1=0.0, p2=0.0, refraction_eps45=0.0, pixel_size_x_mm=t, pixel_size_y_mm=t * fx / fy,
                 columns_px=int(w), rows_px=int(h), model=model, source=source)
    return cam, {"fx": float(fx), "fy": float(fy), "cx": float(cx), "cy": float(cy), "w": int(w),
                 "h": int(h), "dist": {k: float(v) for k, v in (dist or {}).items()}, "kind": kind}


def fisheye_model(camera_id: str, model: dict) -> Any:
    """The :class:`~lidarcat.geometry.models.FisheyeCamera` of a ``fisheye`` source model (pixel-centre
    origin), validated.

    Raises
    ------
    CameraError
        Parameters out of the model's valid range (the polynomial folds over inside the image, or
        the image corners lie beyond 180 deg from the axis), naming the camera and the field.
    """
    from ..geometry.models import FisheyeCamera

    d = model["dist"]
    return FisheyeCamera(camera_id, int(model["w"]), int(model["h"]), fx=model["fx"], fy=model["fy"],
                         cx=model["cx"] - 0.5, cy=model["cy"] - 0.5, **{k: float(d.get(k, 0.0)) for k in _FISHEYE_K})


def check_source_model(camera_id: str, model: dict, where: str) -> None:
    """Refuse a fisheye source model out of range as a :class:`FormatError` located at *where*
    (``FILE:LINE`` or ``FILE: byte N``): ``WHERE: camera 'ID': field 'k1': ...``."""
    if model["kind"] == "fisheye":
        try:
            fisheye_model(camera_id, model)
        except CameraError as ex:
            raise FormatError(f"{where}: {ex}") from None
    elif model["kind"] == "metashape_fisheye":
        problem = _metashape_fisheye_problem(model)
        if problem is None:
            try:
                _metashape_fisheye_rays(_grid(model), model)
            except CameraError as ex:
                problem = str(ex)
        if problem:
            raise FormatError(f"{where}: camera {camera_id!r}: {problem}")


def _metashape_fisheye_problem(model: dict) -> str | None:
    """Why a Metashape fisheye's radial map ``theta -> theta (1 + k1 theta^2 + ... + k4 theta^8)`` does not
    reach the image corners while increasing (within 180 deg), or None."""
    k = [float(model["dist"].get(n, 0.0)) for n in _FISHEYE_K]
    t = np.linspace(0.0, math.pi, 4097)
    u = t * t
    slope = 1 + u * (3 * k[0] + u * (5 * k[1] + u * (7 * k[2] + u * 9 * k[3])))
    stop = int(np.argmax(slope <= 0)) if (slope <= 0).any() else len(t) - 1
    reach = float((t * (1 + u * (k[0] + u * (k[1] + u * (k[2] + u * k[3])))))[stop])
    c = np.array([[0.0, 0.0], [model["w"], 0.0], [0.0, model["h"]], [model["w"], model["h"]]])
    yd = (c[:, 1] - model["cy"]) / model["fy"]
    rd = np.hypot((c[:, 0] - model["cx"] - model.get("skew", 0.0) * yd) / model["fx"], yd)
    i = int(np.argmax(rd))
    if rd[i] < reach:
        return None
    if stop == len(t) - 1:
        return (f"field 'f': the image corner ({c[i, 0]:g}, {c[i, 1]:g}) px lies beyond 180 deg from the optical axis "
                f"(theta_d = {rd[i]:.4g} rad, the model reaches {reach:.4g} rad at 180 deg); check f (px per "
                f"radian) and k1..k4")
    culprit = max(_FISHEYE_K, key=lambda n: abs(model["dist"].get(n, 0.0)) * t[stop] ** (2 * int(n[1])))
    return (f"field {culprit!r}: the fisheye polynomial folds over at {math.degrees(t[stop]):.4g} deg from the "
            f"optical axis (theta_d stops increasing at {reach:.4g} rad) before the image corner "
            f"({c[i, 0]:g}, {c[i, 1]:g}) px (theta_d = {rd[i]:.4g} rad)")


def _grid(model: dict, n: int = 21) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0.0, model["w"], n), np.linspace(0.0, model["h"], n))
    return np.column_stack([u.ravel(), v.ravel()])


def _metashape_fisheye_rays(corner_px: np.ndarray, model: dict) -> np.ndarray:
    """Unit rays (n, 3) of corner-origin pixels through a Metashape fisheye (module docstring)."""
    from ._distortion import undistort

    yd = (corner_px[:, 1] - model["cy"]) / model["fy"]
    xd = np.column_stack([(corner_px[:, 0] - model["cx"] - model.get("skew", 0.0) * yd) / model["fx"], yd])
    xy = undistort(xd, model["dist"], metashape=True)
    theta = np.hypot(xy[:, 0], xy[:, 1])
    if not (theta < math.pi).all():
        i = int(np.argmax(np.where(np.isfinite(theta), theta, np.inf)))
        raise CameraError(f"field 'f': pixel ({corner_px[i, 0]:g}, {corner_px[i, 1]:g}) lies "
                          f"{math.degrees(theta[i]):.4g} "
                          f"deg from the optical axis, beyond 180 deg; check f (px per radian) and k1..k4")
    with np.errstate(all="ignore"):
        unit = np.where((theta > 0)[:, None], xy / np.where(theta > 0, theta, 1.0)[:, None], 0.0)
    return np.column_stack([np.sin(theta)[:, None] * unit, np.cos(theta)])


def source_rays(corner_px: np.ndarray, model: dict, camera_id: str) -> np.ndarray:
    """Unit rays (n, 3), camera frame (x right, y down, z forward), of corner-origin pixels."""
    if model["kind"] == "fisheye":
        return fisheye_model(camera_id, model).unproject(corner_px - 0.5)
    if model["kind"] == "metashape_fisheye":
        return _metashape_fisheye_rays(corner_px, model)
    from ._distortion import undistort

    yd = (corner_px[:, 1] - model["cy"]) / model["fy"]
    xd = np.column_stack([(corner_px[:, 0] - model["cx"] - model.get("skew", 0.0) * yd) / model["fx"], yd])
    xu = undistort(xd, model["dist"], metashape=model.get("kind") == "metashape")
    ray = np.column_stack([xu, np.ones(len(xu))])
    return ray / np.linalg.norm(ray, axis=1)[:, None]


def undistorted_mm(xy_corner_px: np.ndarray, cam: Camera, model: dict) -> np.ndarray:
    """Corrected photo coordinates (n, 2), mm, of source pixels (origin at the image corner) of a
    frame (``brown``, ``metashape``) source model."""
    from ._distortion import undistort

    yd = (xy_corner_px[:, 1] - model["cy"]) / model["fy"]
    xd = np.column_stack([(xy_corner_px[:, 0] - model["cx"] - model.get("skew", 0.0) * yd) / model["fx"], yd])
    xu = undistort(xd, model["dist"], metashape=model.get("kind") == "metashape")
    return cam.focal_length_mm * xu * [1.0, -1.0]


def ideal_observations(xy_corner_px: np.ndarray, cam: Camera, model: dict, *, where: str = "",
                       max_angle_deg: float = MAX_RAY_ANGLE_DEG, sd_px: float = FISHEYE_SD_PX
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corrected photo coordinates (n, 2), mm, of source pixels (corner origin), which to keep, and
    their sds.

    Parameters
    ----------
    xy_corner_px : ndarray, (n, 2)
        Measured pixels, the image corner at the origin.
    cam : Camera
        The stand-in camera (:func:`pinhole_camera`).
    model : dict
        The source model.
    where : str
        File (and line) of the camera, for the warning.
    max_angle_deg : float
        Rays farther from the optical axis are skipped (module docstring).
    sd_px : float
        Sd of a measured pixel (px) that a fisheye observation's sd is propagated from.

    Returns
    -------
    mm : ndarray, (n, 2)
        ``c (X/Z, -Y/Z)``; NaN where skipped.
    keep : ndarray of bool, (n,)
        False for the skipped observations (logged: count, widest angle, the reason).
    sd_mm : ndarray, (n, 2)
        For a fisheye, the sd of ``mm`` from *sd_px* per pixel axis through the derivative of the
        image-plane point by the pixel (central differences of the unprojection over 1e-3 px):
        ``sd_x = c sd_px sqrt((dn_x/du)^2 + (dn_x/dv)^2)``, as ``y``; the plane stretches a pixel by
        up to ``1/cos^2 theta`` (11.5 times at 85 deg, whence :data:`MAX_RAY_ANGLE_DEG`).  NaN for a
        frame model (the survey's default sd applies).
    """
    px = np.asarray(xy_corner_px, dtype=float).reshape(-1, 2)
    sd = np.full((len(px), 2), np.nan)
    if model["kind"] not in FISHEYE_KINDS:
        mm = undistorted_mm(px, cam, model)
        return mm, np.ones(len(mm), dtype=bool), sd
    rays = source_rays(px, model, cam.id)
    theta = np.degrees(np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]))
    keep = theta <= max_angle_deg
    mm = np.full((len(rays), 2), np.nan)
    mm[keep] = cam.focal_length_mm * rays[keep, :2] / rays[keep, 2:] * [1.0, -1.0]
    if keep.any():
        h = 1e-3
        jac = np.empty((int(keep.sum()), 2, 2))
        for j, step in enumerate(([h, 0.0], [0.0, h])):
            ra, rb = source_rays(px[keep] + step, model, cam.id), source_rays(px[keep] - step, model, cam.id)
            jac[:, :, j] = (ra[:, :2] / ra[:, 2:] - rb[:, :2] / rb[:, 2:]) / (2 * h)
        sd[keep] = cam.focal_length_mm * sd_px * np.sqrt((jac ** 2).sum(axis=2))
    if (~keep).any():
        log.warning("%s: camera %r: %d observation(s) skipped: their rays lie %.4g-%.4g deg from the optical "
                    "axis, beyond the %.4g deg an image-plane (pinhole) observation of lidarcat's bundle can hold",
                    where or "import", cam.id, int((~keep).sum()), float(theta[~keep].min()),
                    float(theta[~keep].max()), max_angle_deg)
    return mm, keep, sd


def project_corner_px(rays: np.ndarray, model: dict, camera_id: str) -> np.ndarray:
    """Pixels (n, 2), corner origin, of camera-frame rays (n, 3) through a source model."""
    from ._distortion import distort

    r = np.asarray(rays, dtype=float).reshape(-1, 3)
    kind = model["kind"]
    if kind == "fisheye":
        return fisheye_model(camera_id, model).project(r) + 0.5
    if kind == "metashape_fisheye":
        rho = np.hypot(r[:, 0], r[:, 1])
        theta = np.arctan2(rho, r[:, 2])
        with np.errstate(all="ignore"):
            xy = np.where((rho > 0)[:, None], r[:, :2] * (theta / np.where(rho > 0, rho, 1.0))[:, None], 0.0)
        xd = distort(xy, model["dist"], metashape=True)
    else:
        xd = distort(r[:, :2] / r[:, 2:], model["dist"], metashape=kind == "metashape")
    proj = xd * [model["fx"], model["fy"]] + [model["cx"], model["cy"]]
    proj[:, 0] += model.get("skew", 0.0) * xd[:, 1]
    return proj
