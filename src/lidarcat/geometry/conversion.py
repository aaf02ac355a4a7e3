r"""Conversions between camera models: exact where the algebra allows, fitted (with the residual) where not.

Exact conversions
-----------------
* frame <-> Brown, when the frame camera has no distortion (k = p = eps45 = 0) and the Brown
  camera neither (k = p = skew = 0): the pinhole of eq. 01-02 is
  ``u = (N_c - 1)/2 + (c X/Z + x0) / t_x``, ``v = (N_L - 1)/2 + (c Y/Z - y0) / t_y`` (y up in
  mm, down in pixels), so ``fx = c / t_x``, ``fy = c / t_y``, ``cx = (N_c - 1)/2 + x0 / t_x``,
  ``cy = (N_L - 1)/2 - y0 / t_y``; the way back chooses ``t_x`` (a pixel pitch COLMAP-like
  programs do not know) and sets ``c = fx t_x``, ``t_y = c / fy``.  With distortion the two
  are *different functions*: the thesis polynomial corrects the measured (distorted) point,
  ``x_fotc = x - D(x)``, the Brown polynomial distorts the ideal one, ``x' = x + D'(x)``;
  the inverse of a polynomial is no polynomial, so only a fit is possible.
* COLMAP (:func:`from_colmap`, :func:`to_colmap`): ``SIMPLE_PINHOLE``, ``PINHOLE``,
  ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV`` and ``FULL_OPENCV`` with ``k4 = k5 = k6 = 0`` (the
  rational denominator) are Brown cameras; ``SIMPLE_RADIAL_FISHEYE``, ``RADIAL_FISHEYE`` and
  ``OPENCV_FISHEYE`` fisheye cameras.  COLMAP's pixel origin is the image *corner*:
  ``cx = cx_colmap - 0.5``.
* Metashape (:func:`from_metashape`, :func:`to_metashape`): ``f, cx, cy, b1, b2, k1..k4, P1, P2``
  (``cx, cy`` offsets from the image centre, corner origin) is a Brown camera with
  ``fx = f + b1``, ``fy = f``, ``skew = b2``, ``cx = W/2 + cx_ms - 0.5``, ``p1 = P2``, ``p2 = P1``.

Fitted conversion (:func:`convert`)
-----------------------------------
Everything else (frame with distortion -> Brown, Brown <-> fisheye, FULL_OPENCV with a
rational part -> Brown, ...) is a least-squares fit: the source unprojects an n x n grid of
pixels over the whole image (border included) to rays; the target's parameters minimise
``sum |target.project(ray) - pixel|^2`` by Levenberg-Marquardt with the analytic
parameter Jacobians of :mod:`lidarcat.geometry.models` (columns scaled to unit norm), starting
from the source's pinhole.  The result carries its residual: the largest and the rms pixel
difference on a denser check grid (101 x 101), so a caller can refuse a conversion that is not
good enough.

Observations (:func:`image_plane_observations`): measured pixels of any model as ideal
image-plane coordinates ``n = (X/Z, Y/Z)`` with their derivatives by the intrinsics and by the
pixel, the form in which the bundle (photo coordinates ``c_ref (n_x, -n_y)``) can take them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CameraError
from .camera import Camera
from .models import MODELS, TOL_PX, BrownCamera, CameraModel, FisheyeCamera, FrameModel

__all__ = ["Conversion", "convert", "exact_conversion", "from_colmap", "to_colmap", "from_metashape",
           "to_metashape", "COLMAP_MODEL_PARAMETERS", "image_plane_observations"]

#: COLMAP model name -> its parameter names (COLMAP src/colmap/sensor/models.h)
COLMAP_MODEL_PARAMETERS: dict[str, tuple[str, ...]] = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "SIMPLE_RADIAL_FISHEYE": ("f", "cx", "cy", "k1"),
    "RADIAL_FISHEYE": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV_FISHEYE": ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"),
}


@dataclass(frozen=True)
class Conversion:
    """A camera converted to another model.

    Attributes
    ----------
    model : CameraModel
        The converted camera.
    exact : bool
        True when the conversion is algebraically exact (then the residuals are rounding).
    max_residual_px, rms_residual_px : float
        Largest and rms pixel difference source -> target over a 101 x 101 grid of the image.
    """

    model: CameraModel
    exact: bool
    max_residual_px: float
    rms_residual_px: float


def from_colmap(camera_id: str, model: str, width_px: int, height_px: int, params: Any) -> CameraModel:
    """A COLMAP camera as a Brown or fisheye model, exactly.

    >>> from_colmap("1", "OPENCV", 640, 480, [500, 500, 320, 240, 0.1, 0, 0, 0]).cx
    319.5

    Raises
    ------
    CameraError
        An unknown model (with the known ones), a wrong parameter count, a FULL_OPENCV with a
        rational part (k4..k6 not 0: use :func:`convert` on a fit instead), invalid values.
    """
    if model not in COLMAP_MODEL_PARAMETERS:
        raise CameraError(f"camera {camera_id!r}: unknown COLMAP camera model {model!r}; known: "
                          + ", ".join(COLMAP_MODEL_PARAMETERS))
    names = COLMAP_MODEL_PARAMETERS[model]
    vals = np.asarray(params, dtype=float).ravel()
    if vals.size != len(names):
        raise CameraError(f"camera {camera_id!r}: COLMAP model {model} has {len(names)} parameters "
                          f"({' '.join(names)}), got {vals.size}")
    p = dict(zip(names, map(float, vals)))
    fx, fy = p.get("fx", p.get("f")), p.get("fy", p.get("f"))
    common = dict(fx=fx, fy=fy, cx=p["cx"] - 0.5, cy=p["cy"] - 0.5)
    ks = {k: p[k] for k in ("k1", "k2", "k3", "k4") if k in p}
    if model.endswith("FISHEYE"):  # RADIAL_FISHEYE: theta_d = theta (1 + k1 theta^2 + k2 theta^4)
        return FisheyeCamera(camera_id, width_px, height_px, **common, **ks)
    if model == "FULL_OPENCV":
        rational = {k: p[k] for k in ("k4", "k5", "k6") if p[k] != 0.0}
        if rational:
            raise CameraError(f"camera {camera_id!r}: FULL_OPENCV with a rational part ("
                              + ", ".join(f"{k} = {v:.6g}" for k, v in rational.items())
                              + ") has no exact Brown equivalent; fit one with geometry.conversion.convert")
        ks.pop("k4")
    return BrownCamera(camera_id, width_px, height_px, **common, **ks, p1=p.get("p1", 0.0), p2=p.get("p2", 0.0))


def to_colmap(model: CameraModel) -> tuple[str, list[float]]:
    """The COLMAP model name and parameters of a Brown or fisheye camera, exactly.

    Brown: ``OPENCV`` (k3 = 0) or ``FULL_OPENCV``; fisheye: ``OPENCV_FISHEYE``.

    Raises
    ------
    CameraError
        A frame model, or a Brown camera with ``skew`` or ``k4`` (COLMAP has neither).
    """
    if isinstance(model, FisheyeCamera):
        m = model
        return "OPENCV_FISHEYE", [m.fx, m.fy, m.cx + 0.5, m.cy + 0.5, m.k1, m.k2, m.k3, m.k4]
    if not isinstance(model, BrownCamera):
        raise CameraError(f"camera {model.id!r}: a {model.KIND} camera has no exact COLMAP model; "
                          f"convert it to brown first")
    b = model
    for name in ("skew", "k4"):
        if getattr(b, name) != 0.0:
            raise CameraError(f"camera {b.id!r}: field {name!r}: COLMAP has no {name} term "
                              f"({name} = {getattr(b, name):.6g}); fit a COLMAP-representable model instead")
    head = [b.fx, b.fy, b.cx + 0.5, b.cy + 0.5, b.k1, b.k2, b.p1, b.p2]
    if b.k3 == 0.0:
        return "OPENCV", head
    return "FULL_OPENCV", head + [b.k3, 0.0, 0.0, 0.0]


def from_metashape(camera_id: str, width_px: int, height_px: int, *, f: float, cx: float = 0.0,
                   cy: float = 0.0, b1: float = 0.0, b2: float = 0.0, k1: float = 0.0, k2: float = 0.0,
                   k3: float = 0.0, k4: float = 0.0, p1: float = 0.0, p2: float = 0.0) -> BrownCamera:
    """A Metashape frame calibration (pixels; ``cx, cy`` from the image centre) as a Brown camera.

    >>> cam = from_metashape("m", 100, 80, f=90.0, b1=1.0, p1=1e-3)
    >>> cam.fx, cam.p2
    (91.0, 0.001)
    """
    return BrownCamera(camera_id, width_px, height_px, fx=f + b1, fy=f, cx=width_px / 2 + cx - 0.5,
                       cy=height_px / 2 + cy - 0.5, k1=k1, k2=k2, k3=k3, k4=k4, p1=p2, p2=p1, skew=b2)


def to_metashape(model: BrownCamera) -> dict[str, float]:
    """The Metashape parameters (f, cx, cy, b1, b2, k1..k4, p1, p2) of a Brown camera, exactly."""
    if not isinstance(model, BrownCamera):
        raise CameraError(f"camera {model.id!r}: a {model.KIND} camera is no Metashape frame camera")
    m = model
    return {"f": m.fy, "cx": m.cx + 0.5 - m.width_px / 2, "cy": m.cy + 0.5 - m.height_px / 2,
            "b1": m.fx - m.fy, "b2": m.skew, "k1": m.k1, "k2": m.k2, "k3": m.k3, "k4": m.k4,
            "p1": m.p2, "p2": m.p1}


def _pinhole_frame(model: CameraModel, pixel_size_mm: float) -> Camera | None:
    """A distortion-free frame camera equal to a distortion-free Brown, else None."""
    if not isinstance(model, BrownCamera):
        return None
    if any(getattr(model, k) != 0.0 for k in ("k1", "k2", "k3", "k4", "p1", "p2", "skew")):
        return None
    t = float(pixel_size_mm)
    c = model.fx * t
    ty = c / model.fy
    return Camera(model.id, focal_length_mm=c,
                  principal_point_x_mm=(model.cx - (model.width_px - 1) / 2) * t,
                  principal_point_y_mm=-(model.cy - (model.height_px - 1) / 2) * ty,
                  k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0, refraction_eps45=0.0,
                  pixel_size_x_mm=t, pixel_size_y_mm=ty, columns_px=model.width_px, rows_px=model.height_px,
                  source=f"converted exactly from the brown camera {model.id!r}")


def _pinhole_brown(model: CameraModel) -> BrownCamera | None:
    """The Brown camera of a distortion-free frame camera (module docstring), else None."""
    if not isinstance(model, FrameModel):
        return None
    cam = model.camera
    if any(getattr(cam, k) != 0.0 for k in ("k1", "k2", "k3", "p1", "p2", "refraction_eps45")):
        return None
    return BrownCamera(cam.id, cam.columns_px, cam.rows_px,
                       fx=cam.focal_length_mm / cam.pixel_size_x_mm, fy=cam.focal_length_mm / cam.pixel_size_y_mm,
                       cx=(cam.columns_px - 1) / 2 + cam.principal_point_x_mm / cam.pixel_size_x_mm,
                       cy=(cam.rows_px - 1) / 2 - cam.principal_point_y_mm / cam.pixel_size_y_mm)


def exact_conversion(model: CameraModel, kind: str, *, pixel_size_mm: float = 0.001) -> CameraModel | None:
    """The exact *kind* equivalent of *model*, or None where there is none (module docstring).

    Raises
    ------
    CameraError
        An unknown model name.
    """
    if kind not in MODELS:
        raise CameraError(f"unknown camera model {kind!r}; known: {', '.join(MODELS)}")
    if model.KIND == kind:
        return model
    if kind == "brown":
        return _pinhole_brown(model)
    if kind == "frame":
        cam = _pinhole_frame(model, pixel_size_mm)
        return None if cam is None else FrameModel(cam)
    return None


def _start(model: CameraModel, kind: str, pixel_size_mm: float) -> CameraModel:
    """The starting point of a fit: the source's pinhole as a *kind* camera."""
    if isinstance(model, FrameModel):
        cam = model.camera
        fx, fy = cam.focal_length_mm / cam.pixel_size_x_mm, cam.focal_length_mm / cam.pixel_size_y_mm
        cx = (cam.columns_px - 1) / 2 + cam.principal_point_x_mm / cam.pixel_size_x_mm
        cy = (cam.rows_px - 1) / 2 - cam.principal_point_y_mm / cam.pixel_size_y_mm
    else:
        fx, fy, cx, cy = model.fx, model.fy, model.cx, model.cy  # type: ignore[attr-defined]
    pin = BrownCamera(model.id, model.width_px, model.height_px, fx=fx, fy=fy, cx=cx, cy=cy)
    if kind == "brown":
        return pin
    if kind == "fisheye":
        return FisheyeCamera(model.id, model.width_px, model.height_px, fx=fx, fy=fy, cx=cx, cy=cy)
    return FrameModel(dataclasses.replace(_pinhole_frame(pin, pixel_size_mm),  # type: ignore[arg-type]
                                          source=f"fitted to the {model.KIND} camera {model.id!r}"))


def _residual(src: CameraModel, dst: CameraModel, n: int) -> tuple[float, float]:
    px = src.grid_px(n)
    d = dst.project(src.unproject(px)) - px
    e = np.hypot(d[:, 0], d[:, 1])
    return float(e.max()), float(math.sqrt(np.mean(e * e)))


def convert(model: CameraModel, kind: str, *, grid: int = 33, pixel_size_mm: float = 0.001,
            max_iter: int = 100) -> Conversion:
    """Convert *model* to the model *kind*: exactly where possible, else by a fit (module docstring).

    Parameters
    ----------
    model : CameraModel
        The source camera.
    kind : {"frame", "brown", "fisheye"}
        The target model.
    grid : int
        The fit uses a grid x grid lattice of pixels over the image.
    pixel_size_mm : float
        Pixel pitch of a frame target, mm (the pixel geometry does not depend on it).
    max_iter : int
        Levenberg-Marquardt iterations.

    Returns
    -------
    Conversion
        The target camera, whether exact, and its residual over the image.

    Raises
    ------
    CameraError
        An unknown model name, or a source whose field a Brown/frame target cannot see (rays at
        90 deg or more from the axis).
    """
    exact = exact_conversion(model, kind, pixel_size_mm=pixel_size_mm)
    if exact is not None:
        return Conversion(exact, True, *_residual(model, exact, 101))
    px = model.grid_px(grid)
    rays = model.unproject(px)
    if kind != "fisheye" and not (rays[:, 2] > 1e-6).all():
        raise CameraError(f"camera {model.id!r}: its image reaches {math.degrees(np.arccos(rays[:, 2].min())):.4g} deg "
                          f"from the optical axis; a {kind} camera sees less than 90 deg")
    cur = _start(model, kind, pixel_size_mm)
    target = px.ravel()

    def cost_of(m: CameraModel) -> float:
        try:
            return float(np.sum((m.project(rays).ravel() - target) ** 2))
        except CameraError:
            return math.inf

    cost, lam = cost_of(cur), 1e-3
    for _ in range(max_iter):
        pred, _, jp = cur.project_jacobians(rays)
        r = pred.ravel() - target
        J = jp.reshape(-1, jp.shape[2])
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        Js = J / scale
        A, g = Js.T @ Js, Js.T @ r
        improved = False
        while lam < 1e12:
            step = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), g) / scale
            try:
                cand = cur.with_params(cur.params() + step)
            except CameraError:
                lam *= 10
                continue
            c_new = cost_of(cand)
            if c_new < cost:
                small = cost - c_new <= 1e-14 * cost + 1e-30
                cur, cost, lam, improved = cand, c_new, max(lam / 10, 1e-12), True
                break
            lam *= 10
        if not improved or small:
            break
    return Conversion(cur, False, *_residual(model, cur, 101))


def image_plane_observations(model: CameraModel, px: Any, *, tol_px: float = TOL_PX
                             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Measured pixels as ideal image-plane coordinates, with their derivatives (the bundle's hook).

    The bundle observes ideal (undistorted) coordinates ``n = (X/Z, Y/Z)`` of the ray of each
    measured pixel; with a model's intrinsics ``theta`` adjusted, ``n`` moves.  From
    ``project((n, 1); theta) = px`` (implicit function)::

        dn/dtheta = -(d px / d n)^-1 d px / d theta,     dn/dpx = (d px / d n)^-1

    with ``d px / d n`` the first two columns of the model's ray Jacobian at the ray ``(n, 1)``.
    The bundle's photo coordinates (mm, y up) are ``c_ref (n_x, -n_y)`` for any fixed ``c_ref``.

    Parameters
    ----------
    model : CameraModel
    px : array_like, (N, 2)
        Measured pixels.

    Returns
    -------
    n : ndarray, (N, 2)
        Ideal image-plane coordinates (dimensionless).
    dn_dtheta : ndarray, (N, 2, m)
        Their derivatives by the model's :attr:`PARAMETERS`.
    dn_dpx : ndarray, (N, 2, 2)
        Their derivatives by the pixel (to carry a pixel sd to ``n``).

    Raises
    ------
    CameraError
        A pixel whose ray is not in front of the camera (a fisheye beyond 90 deg has no image
        plane: such observations need a bundle on rays), or that does not converge.
    """
    rays = model.unproject(px, tol_px=tol_px)
    behind = ~(rays[:, 2] > 1e-9)
    if behind.any():
        i = int(np.flatnonzero(behind)[0])
        raise CameraError(f"camera {model.id!r}: pixel index {i} sees a ray "
                          f"{math.degrees(math.acos(max(-1.0, min(1.0, rays[i, 2])))):.4g} deg from the optical "
                          f"axis; the image plane holds rays within 90 deg only")
    n = rays[:, :2] / rays[:, 2:]
    _, j_ray, j_par = model.project_jacobians(np.column_stack([n, np.ones(len(n))]))
    inv = np.linalg.inv(j_ray[:, :, :2])
    return n, -inv @ j_par, inv
