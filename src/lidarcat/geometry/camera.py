r"""Interior orientation of a non-metric digital camera (thesis section 2.1.1, eq. 01-07).

A measured pixel position (column ``C``, row ``L``; origin at the *centre* of the
top-left pixel, rows growing downwards) becomes a *corrected photo coordinate*
in millimetres, x to the right and y up, in four steps:

eq. 01, pixel -> image centre (no rotation between the two systems)::

    x_pfid =  t_px * (C - (N_c - 1) / 2)
    y_pfid = -t_py * (L - (N_L - 1) / 2)

eq. 02, image centre -> photogrammetric system (principal-point offset dx, dy)::

    x_fot = x_pfid - dx
    y_fot = y_pfid - dy

eq. 03-06, systematic errors, all evaluated at (x_fot, y_fot) with
``r^2 = x_fot^2 + y_fot^2`` (eq. 04)::

    dx_ra  = x_fot (K1 r^2 + K2 r^4 + K3 r^6)                  radial (03)
    dx_des = P1 (r^2 + 2 x_fot^2) + 2 P2 x_fot y_fot             decentering (05)
    dy_des = P2 (r^2 + 2 y_fot^2) + 2 P1 x_fot y_fot
    dx_ref = x_fot (1 + r^2 / c^2) eps45                          refraction (06)

eq. 07, the corrected photo coordinate::

    x_fotc = x_fot - dx_ra - dx_des - dx_ref

The thesis prints eq. 05 as ``P1 (r^2 + 2 x)``; its own Appendix 1 follows the
usual Brown-Conrady form with ``2 x^2`` (153 of 153 rows agree with it, 65 disagree
with the printed form), which is what is implemented here; the LACTEC calibration
certificate of the same camera model (report P129, annex, section 5.0) prints
``2 x^2`` too.  The corrections
``dx_ra`` ... are the *distortion* values, subtracted in eq. 07; their signs are
those printed in Appendix 1.

The inverse, corrected photo coordinates -> pixel (:meth:`Camera.photo_to_pixel`),
has no closed form: it solves ``x_fot - d(x_fot) = x_fotc`` by Newton's method with
the analytic 2 x 2 Jacobian, vectorised over all points.

A calibration is accepted only if this inverse exists over the image format.  With
``u = r^2`` and ``R`` the distance from the principal point to the farthest frame
corner, the radial part (eq. 03 with the radial refraction of eq. 06) maps a radius
``r`` to the corrected radius::

    rho(r) = r (1 - g(u)),   g(u) = eps45 + (K1 + eps45 / c^2) u + K2 u^2 + K3 u^3
    rho'(r) = 1 - eps45 - 3 (K1 + eps45 / c^2) u - 5 K2 u^2 - 7 K3 u^3

``rho'`` must stay positive on ``[0, R]`` (the corrected radius strictly increases:
no fold-over) and on to ``rho(R)`` (Newton's method starts from the corrected
coordinate, so it must not meet a second pre-image there), and ``|g|``, the radial correction as a share of the radius, at most
:data:`MAX_RADIAL_SHARE` (a point is not moved by more than half its distance from
the principal point: beyond that the polynomial no longer describes a lens, as
``k3 = -1`` mm^-6, 604 km at the corner).  Both are cubics in ``u``: their extremes
are found exactly (end points and roots of the derivative).  The decentering
Jacobian (eq. 05) is symmetric and linear in ``x, y``; its largest eigenvalue
magnitude over the frame (at a corner) must stay below half of ``min rho'``, so
that the whole Jacobian ``I - d(d)/d(x, y)`` stays invertible.

Example
-------
>>> cam = Camera("c", focal_length_mm=50.0, principal_point_x_mm=0.0,
...              principal_point_y_mm=0.0, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
...              refraction_eps45=0.0, pixel_size_x_mm=0.01, pixel_size_y_mm=0.01,
...              columns_px=101, rows_px=51)
>>> cam.pixel_to_photo([[50.0, 25.0], [100.0, 0.0]])
array([[0.  , 0.  ],
       [0.5 , 0.25]])

Cameras of other models (issue 27)
----------------------------------
A camera table with ``model = "brown"`` or ``model = "fisheye"`` holds a
:class:`~lidarcat.geometry.brown.BrownCamera` or
:class:`~lidarcat.geometry.fisheye.FisheyeCamera` (pixels: ``width_px, height_px, fx, fy, cx, cy``
and the distortion, named as in the model's ``PARAMETERS``; ``sd_<parameter>`` beside them).
The :class:`Camera` built from it (:meth:`Camera.from_model`) keeps the model as :attr:`Camera.lens`
and is, for everything else, a frame camera without distortion -- the model's *pinhole*: with a
nominal pixel pitch ``t`` (``pixel_size_mm``, default :data:`LENS_PIXEL_SIZE_MM`; only the unit
of the photo coordinates, it changes no result) ::

    c = fx t,   t_x = t,   t_y = c / fy,
    dx = (cx - (N_c - 1)/2) t_x,   dy = -(cy - (N_L - 1)/2) t_y

so ``x_fot`` of eq. 01-02 is the pixel's linear part.  Its "distortion" is the model's whole
departure from that pinhole: the corrected photo coordinate of a pixel is the image-plane
coordinate of its ray, ``x_fotc = c (X/Z, -Y/Z)`` with ``(X, Y, Z)`` = ``lens.unproject(pixel)``,
so ``D(x_fot) = x_fot - x_fotc`` and ``dD/dx_fot = I - c diag(1, -1) (d px / d n)^-1 diag(1/t_x, -1/t_y)``
(``n = (X/Z, Y/Z)``, ``d px / d n`` from the model's analytic ray Jacobian); the inverse
(:meth:`Camera.photo_to_pixel`) is the model's projection of the ray ``(x/c, -y/c, 1)``.  The
bundle, the mapping and every other user of :class:`Camera` so work on the model's exact
geometry; :meth:`Camera.distortion_corrections` gives the whole correction as ``dx_ra, dy_ra``
(decentering and refraction columns 0).  A ray at 90 deg or more from the axis (a fisheye's
outer field) has no image-plane coordinate: its photo coordinate is NaN.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from .._util import excerpt
from ..errors import CameraError
from ._camera_tables import (CAMERA_KEYS, FLOAT_KEYS, INT_KEYS, LENS_MODELS, LENS_PIXEL_SIZE_MM, MOTION_KEYS, SD_KEYS,
                             STR_KEYS, CameraTables, camera_error)
from ._distortion_limits import MAX_RADIAL_SHARE, distortion_fault
from .brown import BrownCamera
from .fisheye import FisheyeCamera

__all__ = ["Camera", "CAMERA_KEYS", "SD_KEYS", "MOTION_KEYS", "MAX_RADIAL_SHARE", "LENS_MODELS",
           "LENS_PIXEL_SIZE_MM"]

log = logging.getLogger(__name__)

_POSITIVE = ("focal_length_mm", "pixel_size_x_mm", "pixel_size_y_mm")
#: sane ranges of interior orientation values (anything outside is a typo or a unit mix-up):
#: focal lengths from phone cameras (a few mm) to long aerial lenses, pixels from 0.1 um to
#: 1 mm, frames up to a million pixels a side, the principal point within the frame
SANE_RANGES: dict[str, tuple[float, float]] = {
    "focal_length_mm": (0.5, 5000.0),
    "pixel_size_x_mm": (1e-4, 1.0),
    "pixel_size_y_mm": (1e-4, 1.0),
    "columns_px": (1, 1_000_000),
    "rows_px": (1, 1_000_000),
}


def _as_points(a: Any, name: str) -> tuple[np.ndarray, bool]:
    """Return *a* as a float64 (N, 2) array and whether the input was a single (2,) point."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == 2:
        return arr.reshape(1, 2), True
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise CameraError(f"{name} must have shape (N, 2) or (2,), got {arr.shape}")
    return arr, False


def _out(arr: np.ndarray, single: bool) -> np.ndarray:
    return arr[0] if single else arr


@dataclass(frozen=True, eq=False)
class Camera(CameraTables):
    """Calibration of a frame camera: the interior orientation parameters.

    Its table forms (:meth:`from_dict`, :meth:`to_dict`, :meth:`to_toml`, :meth:`summary`) come from
    :class:`~lidarcat.geometry._camera_tables.CameraTables`; ``camera.toml`` files are read by
    :func:`lidarcat.survey.cameras.load_cameras`.

    Parameters
    ----------
    id : str
        Camera id (the table name in ``camera.toml``).
    focal_length_mm : float
        Calibrated focal length c, mm (> 0).
    principal_point_x_mm, principal_point_y_mm : float
        Principal-point offset dx, dy of eq. 02 (``x_fot = x_pfid - dx``), mm.
    k1, k2, k3 : float
        Radial distortion coefficients, mm^-2, mm^-4, mm^-6 (eq. 03).
    p1, p2 : float
        Decentering distortion coefficients, mm^-1 (eq. 05).
    refraction_eps45 : float
        Photogrammetric refraction parameter eps45 (eq. 06), dimensionless.
    pixel_size_x_mm, pixel_size_y_mm : float
        Pixel pitch along columns and rows, mm (> 0).
    columns_px, rows_px : int
        Image size N_c (columns, along x) and N_L (rows, along y), pixels.
    model, source : str
        Free text: camera/lens model; citation of the calibration.
    sd : Mapping[str, float]
        Standard deviations of the calibration, keyed ``sd_<field>`` (e.g.
        ``sd_focal_length_mm``, ``sd_k1``); all optional, each >= 0.  With a
        *lens*: ``sd_<parameter>`` of the model (``sd_fx``, ``sd_k1``, ...).
    lens : BrownCamera or FisheyeCamera, optional
        A camera of another model (see "Cameras of other models" in the module
        docstring; build it with :meth:`from_model`).  None: the thesis camera.
    readout_time_ms : float
        Rolling shutter: time to read the image out from the top to the bottom row, ms
        (0, the default: a global shutter; :mod:`lidarcat.bundle.rolling`).

    Raises
    ------
    CameraError
        A value is not finite, a length that must be positive is not, an image
        size is not a positive integer, an ``sd`` key is unknown, or the
        distortion cannot be inverted over the frame or is no lens distortion
        (see the module docstring).  The message names the field; ``err.field``
        holds it.
    """

    id: str
    focal_length_mm: float
    principal_point_x_mm: float
    principal_point_y_mm: float
    k1: float
    k2: float
    k3: float
    p1: float
    p2: float
    refraction_eps45: float
    pixel_size_x_mm: float
    pixel_size_y_mm: float
    columns_px: int
    rows_px: int
    model: str = ""
    source: str = ""
    sd: Mapping[str, float] = field(default_factory=dict)
    readout_time_ms: float = 0.0
    lens: BrownCamera | FisheyeCamera | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not self.id.strip():
            raise camera_error("id", f"camera id must be a non-empty string, got {excerpt(self.id)}")
        for name in FLOAT_KEYS:
            raw = getattr(self, name)
            if isinstance(raw, bool) or not isinstance(raw, (int, float, np.integer, np.floating)):
                raise camera_error(name, f"must be a number, got {excerpt(raw)} ({type(raw).__name__})")
            v = float(raw)
            if not math.isfinite(v):
                raise camera_error(name, f"must be finite, got {v!r}")
            if name in _POSITIVE and v <= 0:
                raise camera_error(name, f"must be positive, got {v!r}")
            if name in SANE_RANGES and not SANE_RANGES[name][0] <= v <= SANE_RANGES[name][1]:
                lo, hi = SANE_RANGES[name]
                raise camera_error(name, f"{v!r} is outside the sane range {lo:g}..{hi:g} (mm); "
                                          "check the value and its unit")
            object.__setattr__(self, name, v)
        for name in INT_KEYS:
            raw = getattr(self, name)
            if isinstance(raw, bool) or not isinstance(raw, (int, np.integer)):
                if isinstance(raw, float) and raw.is_integer():
                    raw = int(raw)
                else:
                    raise camera_error(name, f"must be a whole number of pixels, got {excerpt(raw)}")
            if raw < 1:
                raise camera_error(name, f"must be at least 1 pixel, got {excerpt(raw)}")
            if raw > SANE_RANGES[name][1]:
                raise camera_error(name, f"{excerpt(raw)} pixels is outside the sane range 1..{SANE_RANGES[name][1]:,}")
            object.__setattr__(self, name, int(raw))
        w, h = self.columns_px * self.pixel_size_x_mm, self.rows_px * self.pixel_size_y_mm
        for name, half in (("principal_point_x_mm", w / 2), ("principal_point_y_mm", h / 2)):
            if abs(getattr(self, name)) > half:
                raise camera_error(name, f"{getattr(self, name)!r} mm lies outside the frame "
                                          f"(+-{half:g} mm from its centre); check the value and its unit")
        for name in STR_KEYS:
            if not isinstance(getattr(self, name), str):
                raise camera_error(name, f"must be text, got {excerpt(getattr(self, name))}")
        sd: dict[str, float] = {}
        sd_keys = SD_KEYS
        if self.lens is not None:
            if not isinstance(self.lens, (BrownCamera, FisheyeCamera)):
                raise camera_error("model", f"a lens must be a BrownCamera or FisheyeCamera, got "
                                             f"{type(self.lens).__name__}")
            sd_keys = tuple(f"sd_{q}" for q in self.lens.PARAMETERS)
        for key, raw in dict(self.sd).items():
            if key not in sd_keys:
                raise camera_error(key, f"unknown standard-deviation key; allowed: {', '.join(sd_keys)}")
            if isinstance(raw, bool) or not isinstance(raw, (int, float, np.integer, np.floating)):
                raise camera_error(key, f"must be a number, got {excerpt(raw)}")
            v = float(raw)
            if not math.isfinite(v) or v < 0:
                raise camera_error(key, f"must be a finite number >= 0, got {v!r}")
            sd[key] = v
        object.__setattr__(self, "sd", MappingProxyType(sd))
        raw = self.readout_time_ms
        if isinstance(raw, bool) or not isinstance(raw, (int, float, np.integer, np.floating)) \
                or not (math.isfinite(float(raw)) and 0 <= float(raw) <= 1000):
            raise camera_error("readout_time_ms", f"read-out time must be a number of ms in 0..1000 "
                                                   f"(0: a global shutter), got {excerpt(raw)}")
        object.__setattr__(self, "readout_time_ms", float(raw))
        with np.errstate(all="ignore"):  # coefficients near the float maximum: inf/nan, refused below
            self._check_distortion()

    def _check_distortion(self) -> None:
        """Refuse a distortion model that cannot be inverted over the frame (module docstring)."""
        fault = distortion_fault(self.frame_size_mm, (self.principal_point_x_mm, self.principal_point_y_mm),
                                 self.focal_length_mm, self.k1, self.k2, self.k3, self.p1, self.p2,
                                 self.refraction_eps45)
        if fault is not None:
            raise camera_error(*fault)

    # ------------------------------------------------------------------ repr
    def __repr__(self) -> str:
        return (f"Camera(id={self.id!r}, focal_length_mm={self.focal_length_mm}, "
                f"{self.columns_px}x{self.rows_px} px of {self.pixel_size_x_mm} mm)")

    @property
    def frame_size_mm(self) -> tuple[float, float]:
        """Sensor extent (width along x, height along y), mm."""
        return self.columns_px * self.pixel_size_x_mm, self.rows_px * self.pixel_size_y_mm

    @classmethod
    def from_model(cls, lens: BrownCamera | FisheyeCamera, *, pixel_size_mm: float = LENS_PIXEL_SIZE_MM,
                   source: str = "", sd: Mapping[str, float] | None = None,
                   readout_time_ms: float = 0.0) -> Camera:
        """The camera of a Brown or fisheye model: its pinhole as a frame camera, the model as :attr:`lens`.

        Parameters
        ----------
        lens : BrownCamera or FisheyeCamera
        pixel_size_mm : float
            The nominal pixel pitch ``t`` (module docstring): the unit of the photo coordinates.
        source : str
            Citation of the calibration.
        sd : mapping, optional
            ``sd_<parameter>`` of the model (pixels, dimensionless), the priors of a self-calibration.
        readout_time_ms : float
            Rolling-shutter read-out time, ms (0: a global shutter).

        >>> cam = Camera.from_model(BrownCamera("b", 4000, 3000, fx=3000.0, fy=3000.0, cx=1999.5, cy=1499.5))
        >>> cam.focal_length_mm, cam.pixel_to_photo([2999.5, 1499.5])
        (15.0, array([5., 0.]))
        """
        if not isinstance(lens, (BrownCamera, FisheyeCamera)):
            raise camera_error("model", f"a lens must be a BrownCamera or FisheyeCamera, got {type(lens).__name__}")
        t = pixel_size_mm
        if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not (
                math.isfinite(float(t)) and float(t) > 0):
            raise camera_error("pixel_size_mm", f"must be a positive number, got {excerpt(t)}")
        t = float(t)
        c = lens.fx * t
        ty = c / lens.fy
        return cls(lens.id, focal_length_mm=c,
                   principal_point_x_mm=(lens.cx - (lens.width_px - 1) / 2.0) * t,
                   principal_point_y_mm=-(lens.cy - (lens.height_px - 1) / 2.0) * ty,
                   k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0, refraction_eps45=0.0,
                   pixel_size_x_mm=t, pixel_size_y_mm=ty, columns_px=lens.width_px, rows_px=lens.height_px,
                   model=lens.KIND, source=source, sd=dict(sd or {}), lens=lens, readout_time_ms=readout_time_ms)

    # ------------------------------------------------------------------ eq. 01-07
    def pixel_to_image_centre(self, colrow_px: Any) -> np.ndarray:
        """Eq. 01: pixel (column C, row L) -> image-centre coordinates x_pfid, y_pfid.

        Parameters
        ----------
        colrow_px : array_like, shape (N, 2) or (2,)
            Column and row, pixels; (0, 0) is the centre of the top-left pixel.

        Returns
        -------
        ndarray, shape (N, 2) or (2,)
            x_pfid (right), y_pfid (up), mm, origin at the geometric image centre.
        """
        cr, single = _as_points(colrow_px, "colrow_px")
        out = np.empty_like(cr)
        out[:, 0] = self.pixel_size_x_mm * (cr[:, 0] - (self.columns_px - 1) / 2.0)
        out[:, 1] = self.pixel_size_y_mm * ((self.rows_px - 1) / 2.0 - cr[:, 1])
        return _out(out, single)

    def image_centre_to_pixel(self, xy_pfid_mm: Any) -> np.ndarray:
        """Inverse of eq. 01: image-centre coordinates (mm) -> column, row (px)."""
        xy, single = _as_points(xy_pfid_mm, "xy_pfid_mm")
        out = np.empty_like(xy)
        out[:, 0] = xy[:, 0] / self.pixel_size_x_mm + (self.columns_px - 1) / 2.0
        out[:, 1] = -xy[:, 1] / self.pixel_size_y_mm + (self.rows_px - 1) / 2.0
        return _out(out, single)

    def pixel_to_fot(self, colrow_px: Any) -> np.ndarray:
        """Eq. 01-02: pixel -> photogrammetric coordinates x_fot, y_fot (mm), uncorrected."""
        xy = np.asarray(self.pixel_to_image_centre(colrow_px))
        return xy - np.array([self.principal_point_x_mm, self.principal_point_y_mm])

    def distortion_corrections(self, xy_fot_mm: Any) -> dict[str, np.ndarray]:
        """Eq. 03-06: the systematic errors at photogrammetric coordinates x_fot, y_fot.

        Parameters
        ----------
        xy_fot_mm : array_like, shape (N, 2) or (2,)
            x_fot, y_fot (eq. 02), mm.

        Returns
        -------
        dict of ndarray, each shape (N,) (or scalar arrays for a single point)
            ``dx_ra, dy_ra`` radial (eq. 03), ``dx_des, dy_des`` decentering
            (eq. 05, with ``2 x^2``), ``dx_ref, dy_ref`` refraction (eq. 06), mm;
            the values subtracted in eq. 07, signs as printed in Appendix 1.
        """
        xy, single = _as_points(xy_fot_mm, "xy_fot_mm")
        if self.lens is not None:                          # the model's whole correction (module docstring)
            d = self._total_distortion(xy)
            z = np.zeros(len(xy))
            out = {"dx_ra": d[:, 0], "dy_ra": d[:, 1], "dx_des": z, "dy_des": z.copy(), "dx_ref": z.copy(),
                   "dy_ref": z.copy()}
            return {k: v[0] for k, v in out.items()} if single else out
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        ref = (1.0 + r2 / self.focal_length_mm**2) * self.refraction_eps45
        out = {
            "dx_ra": x * radial,
            "dy_ra": y * radial,
            "dx_des": self.p1 * (r2 + 2 * x * x) + 2 * self.p2 * x * y,
            "dy_des": self.p2 * (r2 + 2 * y * y) + 2 * self.p1 * x * y,
            "dx_ref": x * ref,
            "dy_ref": y * ref,
        }
        for v in out.values():  # no -0.0 in tables (in place: the inverse calls this per iteration)
            v += 0.0
        if single:
            out = {k: v[0] for k, v in out.items()}
        return out

    # -------------------------------------------------- a Brown or fisheye lens (module docstring)
    def _fot_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        pfid = xy + np.array([self.principal_point_x_mm, self.principal_point_y_mm])
        return np.asarray(self.image_centre_to_pixel(pfid)).reshape(-1, 2)

    def _lens_plane(self, xy: np.ndarray) -> np.ndarray:
        """Image-plane coordinates n = (X/Z, Y/Z) of the rays of the pixels at x_fot *xy*; NaN at or beyond 90 deg."""
        assert self.lens is not None
        rays = self.lens.unproject(self._fot_to_pixel(xy), on_fail="nan")
        with np.errstate(all="ignore"):
            n = rays[:, :2] / rays[:, 2:]
        n[~(rays[:, 2] > 1e-9)] = np.nan
        return n

    def _total_distortion(self, xy: np.ndarray) -> np.ndarray:
        if self.lens is not None:
            n = self._lens_plane(xy)
            c = self.focal_length_mm
            return xy - np.column_stack([c * n[:, 0], -c * n[:, 1]])
        d = self.distortion_corrections(xy)
        return np.column_stack([d["dx_ra"] + d["dx_des"] + d["dx_ref"],
                                d["dy_ra"] + d["dy_des"] + d["dy_ref"]])

    def _distortion_jacobian(self, xy: np.ndarray) -> np.ndarray:
        """d(total distortion)/d(x_fot, y_fot), shape (N, 2, 2)."""
        if self.lens is not None:
            n = self._lens_plane(xy)
            ok = np.isfinite(n).all(axis=1)
            jac = np.full((len(xy), 2, 2), np.nan)
            if ok.any():
                _, j_ray, _ = self.lens.project_jacobians(np.column_stack([n[ok], np.ones(int(ok.sum()))]))
                dn_dpx = np.linalg.inv(j_ray[:, :, :2])
                c = self.focal_length_mm
                d = (np.array([c, -c])[None, :, None] * dn_dpx
                     * np.array([1 / self.pixel_size_x_mm, -1 / self.pixel_size_y_mm])[None, None, :])
                jac[ok] = np.eye(2)[None] - d
            return jac
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        radial = r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial = self.k1 + r2 * (2 * self.k2 + 3 * self.k3 * r2)  # d radial / d r2
        c2 = self.focal_length_mm**2
        e = self.refraction_eps45
        p1, p2 = self.p1, self.p2
        jac = np.empty((len(x), 2, 2))
        jac[:, 0, 0] = (radial + 2 * x * x * dradial + 6 * p1 * x + 2 * p2 * y
                        + e * (1 + r2 / c2 + 2 * x * x / c2))
        jac[:, 0, 1] = 2 * x * y * dradial + 2 * p1 * y + 2 * p2 * x + e * 2 * x * y / c2
        jac[:, 1, 0] = 2 * x * y * dradial + 2 * p2 * x + 2 * p1 * y + e * 2 * x * y / c2
        jac[:, 1, 1] = (radial + 2 * y * y * dradial + 6 * p2 * y + 2 * p1 * x
                        + e * (1 + r2 / c2 + 2 * y * y / c2))
        return jac

    def pixel_to_photo(self, colrow_px: Any) -> np.ndarray:
        """Eq. 01, 02, 07: pixel -> corrected photo coordinates x_fotc, y_fotc.

        Parameters
        ----------
        colrow_px : array_like, shape (N, 2) or (2,)
            Column C and row L, pixels (origin: centre of the top-left pixel).

        Returns
        -------
        ndarray, shape (N, 2) or (2,)
            x_fotc (right), y_fotc (up), mm, corrected for radial and decentering
            distortion and refraction.
        """
        cr, single = _as_points(colrow_px, "colrow_px")
        fot = self.pixel_to_fot(cr)
        return _out(fot - self._total_distortion(fot), single)

    def pixel_to_photo_jacobian(self, colrow_px: Any) -> np.ndarray:
        """d(x_fotc, y_fotc)/d(C, L), shape (N, 2, 2), mm per pixel.

        Use it to propagate a pixel measurement sd to photo coordinates:
        ``J @ diag(sd_px**2) @ J.T``.
        """
        cr, _ = _as_points(colrow_px, "colrow_px")
        fot = self.pixel_to_fot(cr)
        j = np.eye(2)[None] - self._distortion_jacobian(fot)
        return j * np.array([self.pixel_size_x_mm, -self.pixel_size_y_mm])[None, None, :]

    def photo_sd(self, colrow_px: Any, sd_px: Any) -> np.ndarray:
        """Per-axis sds (mm) of the corrected photo coordinates of pixels measured with sds *sd_px*.

        ``Sigma_xy = J diag(sd_px^2) J^T`` with ``J`` = :meth:`pixel_to_photo_jacobian`; the square
        roots of its diagonal (the bundle weighs per axis; the x-y correlation, which a Brown or
        fisheye camera's anisotropic stretch brings in, is left out).

        Parameters
        ----------
        colrow_px : array_like, (N, 2)
        sd_px : array_like, (N, 2) or scalar
            Column and row sds of the measurements, pixels.

        Returns
        -------
        ndarray, (N, 2)
        """
        cr, _ = _as_points(colrow_px, "colrow_px")
        j = np.asarray(self.pixel_to_photo_jacobian(cr)).reshape(-1, 2, 2)
        s = np.broadcast_to(np.asarray(sd_px, dtype=float), (len(cr), 2))
        return np.sqrt(np.einsum("nij,nj->ni", j * j, s * s))

    def photo_to_fot(self, xy_mm: Any, *, tol_mm: float = 1e-10, max_iter: int = 50,
                     on_fail: str = "raise") -> np.ndarray:
        """Invert eq. 07: corrected photo coordinates -> x_fot, y_fot (Newton, vectorised).

        Parameters
        ----------
        xy_mm : array_like, shape (N, 2) or (2,)
            Corrected photo coordinates x_fotc, y_fotc, mm.
        tol_mm : float
            Convergence: ``|x_fot - d(x_fot) - x_fotc| <= tol_mm`` on both axes
            (default 1e-10 mm, far below the required 1e-6 mm).
        max_iter : int
            Newton iterations before giving up.
        on_fail : {"raise", "nan"}
            What to do with points that do not converge (far outside the frame,
            where the distortion polynomial folds over): raise, or return NaN.

        Raises
        ------
        CameraError
            A point does not converge (names its index and coordinates).
        """
        if on_fail not in ("raise", "nan"):
            raise ValueError("on_fail must be 'raise' or 'nan'")
        target, single = _as_points(xy_mm, "xy_mm")
        if self.lens is not None:
            return _out(self._lens_photo_to_fot(target, on_fail), single)
        fot = target.copy()
        todo = np.isfinite(target).all(axis=1)
        done = ~todo
        with np.errstate(all="ignore"):
            for _ in range(max_iter):
                if not todo.any():
                    break
                idx = np.flatnonzero(todo)
                cur = fot[idx]
                resid = cur - self._total_distortion(cur) - target[idx]
                ok = np.all(np.abs(resid) <= tol_mm, axis=1)
                done[idx[ok]] = True
                todo[idx[ok]] = False
                if ok.all():
                    break
                idx, cur, resid = idx[~ok], cur[~ok], resid[~ok]
                j = np.eye(2)[None] - self._distortion_jacobian(cur)
                det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]  # explicit 2 x 2 solve
                step = np.column_stack([j[:, 1, 1] * resid[:, 0] - j[:, 0, 1] * resid[:, 1],
                                        j[:, 0, 0] * resid[:, 1] - j[:, 1, 0] * resid[:, 0]])
                step /= det[:, None]
                fot[idx] = cur - step
                bad = ~np.isfinite(fot[idx]).all(axis=1)
                todo[idx[bad]] = False
        failed = ~done & np.isfinite(target).all(axis=1)
        if failed.any():
            if on_fail == "raise":
                i = int(np.flatnonzero(failed)[0])
                raise CameraError(
                    f"camera {self.id!r}: photo coordinate point index {i} "
                    f"({target[i, 0]:.6g}, {target[i, 1]:.6g}) mm did not converge to the pixel "
                    f"grid within {max_iter} iterations ({int(failed.sum())} point(s) failed); "
                    f"it probably lies far outside the {self.frame_size_mm[0]:.3g} x "
                    f"{self.frame_size_mm[1]:.3g} mm frame")
            fot[failed] = np.nan
        fot[~np.isfinite(target).all(axis=1)] = np.nan
        return _out(fot, single)

    def _lens_photo_to_fot(self, xy: np.ndarray, on_fail: str) -> np.ndarray:
        """x_fot of corrected photo coordinates through the lens's projection of the ray (x/c, -y/c, 1)."""
        assert self.lens is not None
        c = self.focal_length_mm
        rays = np.column_stack([xy[:, 0] / c, -xy[:, 1] / c, np.ones(len(xy))])
        good = np.isfinite(xy).all(axis=1)
        px = np.full((len(xy), 2), np.nan)
        try:
            px[good] = self.lens.project(rays[good])
        except CameraError:
            if on_fail == "raise":
                raise
            for i in np.flatnonzero(good):                 # the rare failing call: point by point
                try:
                    px[i] = self.lens.project(rays[i])[0]
                except CameraError:
                    pass
        return np.asarray(self.pixel_to_fot(px)).reshape(-1, 2)

    def photo_to_pixel(self, xy_mm: Any, *, tol_mm: float = 1e-10, max_iter: int = 50,
                       on_fail: str = "raise") -> np.ndarray:
        """Corrected photo coordinates -> pixel column, row: the inverse of :meth:`pixel_to_photo`.

        Parameters
        ----------
        xy_mm : array_like, shape (N, 2) or (2,)
            Corrected photo coordinates x_fotc, y_fotc, mm.
        tol_mm, max_iter, on_fail
            See :meth:`photo_to_fot`; the default tolerance 1e-10 mm gives a round
            trip pixel -> photo -> pixel far inside 1e-6 px.

        Returns
        -------
        ndarray, shape (N, 2) or (2,)
            Column C and row L, pixels (may lie outside the frame; see
            :meth:`contains`).

        Raises
        ------
        CameraError
            Newton's method does not converge for a point (names its index).

        Examples
        --------
        >>> cam = Camera("c", 50.0, 0.01, -0.02, -4e-5, 1e-8, 0.0, -4e-6, 0.0, 0.0,
        ...              0.008, 0.008, 3000, 2000)
        >>> px = cam.photo_to_pixel(cam.pixel_to_photo([[10.0, 20.0]]))
        >>> bool(np.all(np.abs(px - [[10.0, 20.0]]) < 1e-9))
        True
        """
        xy, single = _as_points(xy_mm, "xy_mm")
        fot = self.photo_to_fot(xy, tol_mm=tol_mm, max_iter=max_iter, on_fail=on_fail)
        pfid = fot + np.array([self.principal_point_x_mm, self.principal_point_y_mm])
        return _out(self.image_centre_to_pixel(pfid), single)

    def contains(self, colrow_px: Any, margin_px: float = 0.0) -> np.ndarray:
        """Boolean (N,): the pixel position lies on the sensor (pixel centres 0 .. N-1, +- 0.5 px + margin)."""
        cr, single = _as_points(colrow_px, "colrow_px")
        lo = -0.5 - margin_px
        inside = ((cr[:, 0] >= lo) & (cr[:, 0] <= self.columns_px - 0.5 + margin_px)
                  & (cr[:, 1] >= lo) & (cr[:, 1] <= self.rows_px - 0.5 + margin_px))
        return _out(inside, single)
