r"""Camera models as a family: frame (thesis eq. 01-07), normalised Brown, fisheye (Kannala-Brandt).

Every model maps a *ray in the camera frame* to a *pixel* and back.  Camera frame (OpenCV,
COLMAP, OpenSfM): x right, y down, z forward along the optical axis.  Pixels: column ``u``
right, row ``v`` down, (0, 0) the *centre* of the top-left pixel (as
:mod:`lidarcat.geometry.camera` and OpenCV; COLMAP's and Metashape's corner origin is half a
pixel off, handled in :mod:`lidarcat.geometry.conversion`).

Normalised Brown (OpenCV ``OPENCV``/``FULL_OPENCV`` with k4..k6 = 0, OpenSfM/ODM ``brown``,
Metashape ``frame`` with its k4, b1, b2)::

    x = X / Z,  y = Y / Z,  r^2 = x^2 + y^2                                      (Z > 0)
    q(r^2) = 1 + k1 r^2 + k2 r^4 + k3 r^6 + k4 r^8
    x' = x q + 2 p1 x y + p2 (r^2 + 2 x^2)
    y' = y q + p1 (r^2 + 2 y^2) + 2 p2 x y
    u  = fx x' + skew y' + cx,     v = fy y' + cy

(Metashape writes ``u = w/2 + cx + x'(f + b1) + y' b2``: ``fx = f + b1``, ``skew = b2`` and
its P1, P2 are OpenCV's p2, p1.)  With ``q' = dq/d(r^2) = k1 + 2 k2 r^2 + 3 k3 r^4 + 4 k4 r^6``
the 2 x 2 Jacobian of the distortion is::

    dx'/dx = q + 2 x^2 q' + 2 p1 y + 6 p2 x      dx'/dy = 2 x y q' + 2 p1 x + 2 p2 y
    dy'/dx = 2 x y q' + 2 p1 x + 2 p2 y          dy'/dy = q + 2 y^2 q' + 6 p1 y + 2 p2 x

and ``d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]``.  The parameters enter
linearly: ``du/dfx = x'``, ``dv/dfy = y'``, ``du/dskew = y'``, ``du/dcx = dv/dcy = 1``,
``d(x', y')/dk_i = (x, y) r^(2i)``, ``d(x', y')/dp1 = (2 x y, r^2 + 2 y^2)``,
``d(x', y')/dp2 = (r^2 + 2 x^2, 2 x y)``, each mapped through ``[[fx, skew], [0, fy]]``.

Fisheye, equidistant Kannala-Brandt (OpenCV ``cv::fisheye``, COLMAP ``OPENCV_FISHEYE``,
OpenSfM ``fisheye_opencv``)::

    rho = sqrt(X^2 + Y^2),   theta = atan2(rho, Z)       (angle from the optical axis, 0..180 deg)
    theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)
    x' = theta_d X / rho,    y' = theta_d Y / rho
    u  = fx x' + cx,         v = fy y' + cy

``atan2`` instead of ``atan(rho / Z)`` carries the model past 90 deg (lenses of more than 180 deg
field); COLMAP's and OpenCV's ``atan(r)`` of ``X/Z`` agree for Z > 0.  With ``s = theta_d / rho``,
``dtheta/d(X, Y, Z) = (Z X / rho, Z Y / rho, -rho) / (rho^2 + Z^2)`` and
``ds = theta_d'(theta) dtheta / rho - theta_d drho / rho^2``, ``x' = s X``, ``y' = s Y``; on the
axis (rho -> 0) the limit is the pinhole ``s = 1 / Z``, ``ds/dZ = -1 / Z^2``.

Frame (:class:`FrameModel`): the thesis camera (:class:`lidarcat.geometry.camera.Camera`)
unchanged: the corrected photo coordinate of a ray is ``(x_fotc, y_fotc) = c (X/Z, -Y/Z)`` (mm,
y up) and the pixel is :meth:`Camera.photo_to_pixel` of it.  Its Jacobians follow from the
implicit function ``F(px, theta) = x_fotc(px; theta) - c (X/Z, -Y/Z) = 0`` of eq. 01-07:
``dpx/d(.) = -(dF/dpx)^-1 dF/d(.)`` with ``dF/dpx`` = :meth:`Camera.pixel_to_photo_jacobian`.

Inverse (pixel -> ray).  Brown: Newton's method on ``distort(x, y) = (x', y')`` with the 2 x 2
Jacobian above, vectorised, from ``(x, y) = (x', y')``; fisheye: Newton on the scalar
``theta_d(theta) = |(x', y')|``; both stop when the forward residual, in pixels (``f`` times the
normalised residual), is at most ``tol_px`` (default 1e-11 px) on every point, and raise a
:class:`~lidarcat.errors.CameraError` naming the camera and the pixel otherwise.  Frame: eq. 01-07
are the inverse in closed form.

Valid range.  A model is accepted only if its distortion is invertible over the image: the
radial map ``r -> r q(r^2)`` (Brown) or ``theta -> theta_d(theta)`` (fisheye) must increase
from the axis out to the image corners (else the image folds over).  The *valid field* is the
part of the increasing branch (and, for the fisheye, at most 180 deg from the axis); a ray
outside it (or behind a Brown/frame camera, Z <= 0) is refused with the camera and the ray
named.  Checks sample the radial map densely (4097 points from the axis to the bound).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..errors import CameraError
from .brown import BrownCamera
from .camera import Camera
from .fisheye import FisheyeCamera
from .modelbase import TOL_PX, CameraModel, as_pixels, as_rays, check_front

__all__ = ["CameraModel", "BrownCamera", "FisheyeCamera", "FrameModel", "MODELS", "camera_model",
           "as_rays", "as_pixels", "TOL_PX"]


# ---------------------------------------------------------------------------------------
# frame: the thesis camera
# ---------------------------------------------------------------------------------------

#: the frame model's parameters and the Camera fields they are
_FRAME_FIELDS = {"c": "focal_length_mm", "x0": "principal_point_x_mm", "y0": "principal_point_y_mm",
                 "k1": "k1", "k2": "k2", "k3": "k3", "p1": "p1", "p2": "p2"}


@dataclass(frozen=True)
class FrameModel(CameraModel):
    """The thesis frame camera (:class:`~lidarcat.geometry.camera.Camera`, unchanged) as a model.

    Parameters
    ----------
    camera : Camera
        The calibration; the model's parameters are ``c, x0, y0, k1, k2, k3, p1, p2``
        (mm, mm^-2.., mm^-1; refraction and pixel pitch stay as calibrated).
    """

    KIND: ClassVar[str] = "frame"
    PARAMETERS: ClassVar[tuple[str, ...]] = tuple(_FRAME_FIELDS)

    camera: Camera

    def __post_init__(self) -> None:
        if not isinstance(self.camera, Camera):
            raise CameraError(f"a frame model wraps a Camera, got {type(self.camera).__name__}")

    @property
    def id(self) -> str:  # type: ignore[override]
        return self.camera.id

    @property
    def width_px(self) -> int:  # type: ignore[override]
        return self.camera.columns_px

    @property
    def height_px(self) -> int:  # type: ignore[override]
        return self.camera.rows_px

    def params(self) -> np.ndarray:
        return np.array([getattr(self.camera, f) for f in _FRAME_FIELDS.values()], dtype=float)

    def with_params(self, values: Any) -> FrameModel:
        v = np.asarray(values, dtype=float).ravel()
        if v.shape != (len(self.PARAMETERS),):
            raise CameraError(f"camera {self.id!r}: {len(self.PARAMETERS)} parameters expected "
                              f"({', '.join(self.PARAMETERS)}), got {v.size}")
        return FrameModel(dataclasses.replace(self.camera, **dict(zip(_FRAME_FIELDS.values(), map(float, v)))))

    def _photo(self, rays: Any) -> np.ndarray:
        r = as_rays(rays)
        check_front(self, r, math.inf)
        c = self.camera.focal_length_mm
        return np.column_stack([c * r[:, 0] / r[:, 2], -c * r[:, 1] / r[:, 2]])

    def project(self, rays: Any) -> np.ndarray:
        """Rays (N, 3) -> pixels (N, 2) through eq. 01-07 inverted (Newton, 1e-12 mm)."""
        return np.asarray(self.camera.photo_to_pixel(self._photo(rays), tol_mm=1e-12)).reshape(-1, 2)

    def project_jacobians(self, rays: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixels (N, 2), d px / d ray (N, 2, 3), d px / d (c, x0, y0, k1, k2, k3, p1, p2) (N, 2, 8)."""
        r = as_rays(rays)
        cam = self.camera
        px = self.project(r)
        jinv = np.linalg.inv(np.asarray(cam.pixel_to_photo_jacobian(px)).reshape(-1, 2, 2))  # d px / d x_fotc
        X, Y, Z = r[:, 0], r[:, 1], r[:, 2]
        c = cam.focal_length_mm
        dphoto = np.zeros((len(r), 2, 3))
        dphoto[:, 0, 0], dphoto[:, 0, 2] = c / Z, -c * X / Z**2
        dphoto[:, 1, 1], dphoto[:, 1, 2] = -c / Z, c * Y / Z**2
        j_ray = jinv @ dphoto
        fot = np.asarray(cam.pixel_to_fot(px)).reshape(-1, 2)
        x, y = fot[:, 0], fot[:, 1]
        r2 = x * x + y * y
        dF = np.zeros((len(r), 2, 8))                        # dF/dtheta, F = x_fotc(px; theta) - target
        dF[:, 0, 0], dF[:, 1, 0] = -X / Z, Y / Z             # target = c (X/Z, -Y/Z)
        e = cam.refraction_eps45
        if e:                                                # refraction term depends on c too
            dF[:, 0, 0] += 2 * x * r2 * e / c**3
            dF[:, 1, 0] += 2 * y * r2 * e / c**3
        # d x_fotc / d x_fot = (d x_fotc / d px) (d px / d x_fot), d x_fot / d px = diag(t_x, -t_y) (eq. 01)
        jd = np.asarray(cam.pixel_to_photo_jacobian(px)).reshape(-1, 2, 2) / np.array(
            [cam.pixel_size_x_mm, -cam.pixel_size_y_mm])[None, None, :]
        dF[:, :, 1] = -jd[:, :, 0]                           # x_fot = pfid - x0
        dF[:, :, 2] = -jd[:, :, 1]
        for i in range(3):
            p = r2 ** (i + 1)
            dF[:, 0, 3 + i], dF[:, 1, 3 + i] = -x * p, -y * p
        dF[:, 0, 6], dF[:, 1, 6] = -(r2 + 2 * x * x), -2 * x * y
        dF[:, 0, 7], dF[:, 1, 7] = -2 * x * y, -(r2 + 2 * y * y)
        return px, j_ray, -jinv @ dF

    def unproject(self, px: Any, *, tol_px: float = TOL_PX, max_iter: int = 50,
                  on_fail: str = "raise") -> np.ndarray:
        """Pixels (N, 2) -> unit rays (N, 3): eq. 01-07 in closed form (the tolerances are unused)."""
        xy = np.asarray(self.camera.pixel_to_photo(as_pixels(px))).reshape(-1, 2)
        rays = np.column_stack([xy[:, 0], -xy[:, 1], np.full(len(xy), self.camera.focal_length_mm)])
        return rays / np.linalg.norm(rays, axis=1)[:, None]


#: model name -> class
MODELS: dict[str, type] = {"frame": FrameModel, "brown": BrownCamera, "fisheye": FisheyeCamera}


def camera_model(kind: str, *args: Any, **kwargs: Any) -> CameraModel:
    """Build a camera model by name (``frame``, ``brown``, ``fisheye``).

    >>> camera_model("brown", "c", 100, 80, fx=90.0, fy=90.0, cx=49.5, cy=39.5).project([0, 0, 1])
    array([[49.5, 39.5]])

    Raises
    ------
    CameraError
        An unknown model name (with the known ones), or invalid parameters.
    """
    if kind not in MODELS:
        raise CameraError(f"unknown camera model {kind!r}; known: {', '.join(MODELS)}")
    return MODELS[kind](*args, **kwargs)

