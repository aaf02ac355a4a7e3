r"""Additional parameters of the bundle: camera self-calibration and GNSS line offsets.

An *additional parameter* is a global unknown shared by many observations: the
interior orientation of a camera (every ray of its photos), the antenna offset
of a GNSS flight line (every camera-position constraint of the line), or the
frame offset of a control source (:mod:`.frame_offset`).  Each family here is a
*component*: it knows its parameters (name, unit, prior sd), how they change
the observations of the :class:`~lidarcat.bundle.BundleProblem` (an *effective
problem*), and the Jacobian of the residuals ``v = f(x) - l`` with respect to
them.  :mod:`.selfcal` borders the normal equations with them.

Self-calibration (thesis eq. 01-07)
-----------------------------------
The problem's observations are corrected photo coordinates ``x_fotc`` computed
with the calibration certificate ``theta_0`` (:mod:`lidarcat.geometry.camera`).  With
corrections ``delta`` to the calibration -- ``c`` (focal length, mm), ``x0, y0``
(principal point dx, dy of eq. 02, mm), ``k1, k2, k3`` (mm^-2, mm^-4, mm^-6),
``p1, p2`` (mm^-1) -- the measured point gives

    x_fot(delta)  = x_fot0 - (dx0, dy0)                      (eq. 02; x_fot0 from theta_0)
    x_fotc(delta) = x_fot - D(x_fot; K + dK, P + dP)          (eq. 03-07)

with ``D`` the radial + decentering (+ refraction, kept at its calibration
value) distortion, and the collinearity prediction is ``x = -(c + dc) u / w``.
The residual ``v = x(eo, X, c + dc) - x_fotc(delta)`` has the derivatives

    dv/dc       = x / (c + dc)                 (= -u / w)
    dv/d(x0)    = (I - dD/dx_fot) e_x          dv/d(y0) = (I - dD/dx_fot) e_y
    dv/dK1      = x_fot r^2,   dv/dK2 = x_fot r^4,   dv/dK3 = x_fot r^6
    dv/dP1      = (r^2 + 2 x^2, 2 x y),        dv/dP2 = (2 x y, r^2 + 2 y^2)

(``r^2 = x_fot^2 + y_fot^2``, everything at the current ``x_fot(delta)``); the
test suite checks them against finite differences.  ``x_fot0`` is recovered
once from the problem's ``x_fotc`` by :meth:`lidarcat.geometry.camera.Camera.photo_to_fot`
(Newton, 1e-10 mm).  Each switched-on parameter carries the calibration
certificate's standard deviation as a weighted prior ``delta = 0 +- sd``; a
parameter with no sd (or sd 0) is free.

Named parameter sets (issue 27)
-------------------------------
``parameters`` may name a set of :mod:`lidarcat.geometry.apsets` (``thesis``, ``brown``,
``ebner``, ``gruen``; alone or beside IO names, ``"c,x0,y0,ebner"``).  Its IO part is the above;
its *extra* terms ``theta_e`` add a correction linear in them, ``A(x_fot; theta_e) = sum_i
theta_i f_i(x_fot / b)`` (``b`` from the frame size), subtracted beside ``D``::

    x_fotc = x_fot - D(x_fot) - A(x_fot; theta_e)
    dv/dtheta_i = f_i(x_fot / b)
    dv/d(x0)    = (I - dD/dx_fot - dA/dx_fot) e_x          (likewise y0)

The terms ``f_i`` are evaluated at the measured ``x_fot``, whose noise the residual shares:
errors in variables, which biased the least-squares estimate of ``gruen``'s terms odd in ``u``
(docs/cameras.md); :meth:`_BoundIO.score_bias` gives the expected gradient at the truth,
``-sum tr(G_i^T P M Sigma_e)``, and :mod:`.selfcal` removes the bias after convergence (its
standardised errors then have mean -0.03 and rms 0.98 over 20 seeds, so the set carries no
warning).  ``explain`` gives the
reason a parameter cannot be told from its most correlated partner (the relief ratio for ``c``
against ``Z0``, the part of the set's grid the measurements span for two polynomial terms).

Brown and fisheye cameras (issue 27)
------------------------------------
A camera of another model (:attr:`lidarcat.geometry.camera.Camera.lens`, a
:class:`~lidarcat.geometry.brown.BrownCamera` or :class:`~lidarcat.geometry.fisheye.FisheyeCamera`)
enters the problem as image-plane observations: the measured pixel ``px`` of a ray ``(n, 1)``,
``project((n, 1); theta) = px``, is observed as ``x_fotc = c_ref (n_x, -n_y)`` with the camera's
fixed reference focal length ``c_ref`` (:meth:`Camera.from_model`) and the collinearity
prediction ``x = -c_ref u / w``.  Its parameters ``theta`` (``fx, fy, cx, cy, k1 ..``, named as
in the model's ``PARAMETERS``; corrections to the calibration) move ``n``; by the implicit
function (:func:`lidarcat.geometry.conversion.image_plane_observations`)::

    dn/dtheta = -(d px / d n)^-1 d px / d theta
    dv/dtheta = -d x_fotc / d theta = c_ref diag(1, -1) (d px / d n)^-1 d px / d theta

with the model's analytic Jacobians at the current ``theta`` (exact for the fixed measured
pixel; ``apply`` re-unprojects every pixel with the current parameters).  The weights stay those
of the calibration (the pixel sd carried through the model once).  The names a camera takes are
those of the switched-on list in its model's ``PARAMETERS``; ``all`` (and a model's own name,
``fisheye``) switches on every parameter of its model.  Priors: ``sd_<parameter>`` of the camera
table.  One self-calibration holds frame cameras or Brown/fisheye cameras, not both.

GNSS flight-line offsets
------------------------
Where camera positions are constrained by GNSS (``eo_constraint_*``), a line
``l`` of photos may carry an antenna offset ``a_l`` (E, N, h, m) and a drift
``b_l`` (m per km along the line): the constraint becomes
``X0_i + a_l + b_l tau_i = X0_GNSS,i`` with ``tau_i`` the distance (km) of the
photo along the line from the line's centre (the principal axis of the line's
GNSS positions, growing in photo order; centred, so offset and drift are
uncorrelated for evenly spaced photos); ``dv/da = I``, ``dv/db = tau I``.

Component protocol (used by :mod:`.selfcal`)
--------------------------------------------
``bind(problem) -> bound``; a bound component has ``names``, ``units``,
``prior_sd`` (inf: free), ``group``; ``apply(theta, fields)`` updates the
effective-problem fields (a dict of arrays) for parameter values ``theta``;
``jacobians(theta, state)`` returns ``(kind, rows, J)`` with ``kind`` one of
``"obs"`` (image rows, J (r, 2, m)), ``"con"`` (point-constraint rows, (r, 3,
m)) or ``"eo"`` (camera-constraint rows, (r, 6, m)), columns local to the
component.  Optional: ``explain(name, partner, eo, points_m, eo_params) -> str | None`` and
``notes`` (warnings of the component itself).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..geometry.apsets import PARAMETER_SETS, ParameterSet
from ..geometry.brown import BrownCamera
from ..geometry.camera import Camera
from ..errors import CameraError, LidarcatError

__all__ = ["IO_PARAMETERS", "IO_UNITS", "LENS_PARAMETERS", "SelfCalibration", "GnssLineOffsets",
           "parse_parameters", "extra_parameter_set", "lens_parameters", "AdditionalParameterError"]


class AdditionalParameterError(LidarcatError, ValueError):
    """An additional parameter that cannot be set up (named)."""


#: interior-orientation parameters that can be switched on, in this order
IO_PARAMETERS: tuple[str, ...] = ("c", "x0", "y0", "k1", "k2", "k3", "p1", "p2")
#: their units (corrections to the calibration certificate)
IO_UNITS: dict[str, str] = {"c": "mm", "x0": "mm", "y0": "mm", "k1": "mm^-2", "k2": "mm^-4",
                            "k3": "mm^-6", "p1": "mm^-1", "p2": "mm^-1"}
#: units of the Brown and fisheye parameters
_LENS_UNITS: dict[str, str] = {"fx": "px", "fy": "px", "cx": "px", "cy": "px", "skew": "px"}
#: the Camera field of each parameter
_FIELD: dict[str, str] = {"c": "focal_length_mm", "x0": "principal_point_x_mm",
                          "y0": "principal_point_y_mm", "k1": "k1", "k2": "k2", "k3": "k3",
                          "p1": "p1", "p2": "p2"}


#: the set each extra (non-IO) parameter belongs to: k4, b1, b2 (brown), e1-e12 (ebner), g1-g44 (gruen)
_EXTRA_SET: dict[str, str] = {q: s.name for s in PARAMETER_SETS.values() for q in s.extra}
#: the parameters of the Brown and fisheye models beyond the frame names (k1.., p1, p2 are shared, and k4
#: with the ``brown`` set's), in the models' order (:attr:`lidarcat.geometry.brown.BrownCamera.PARAMETERS`)
LENS_PARAMETERS: tuple[str, ...] = tuple(q for q in BrownCamera.PARAMETERS
                                         if q not in IO_PARAMETERS and q not in _EXTRA_SET)


def parse_parameters(text: str | Sequence[str]) -> tuple[str, ...]:
    """Parameter names from ``"c,x0,y0,k1,k2"``, set names (``"ebner"``, ``"c,x0,y0,ebner"``) or a sequence.

    A set name of :data:`lidarcat.geometry.apsets.PARAMETER_SETS` (``thesis``, ``brown``,
    ``ebner``, ``gruen``) stands for all its parameters; single extra parameters (``e3``,
    ``k4``) are allowed too, all from one set.  The result is validated, the IO parameters in
    :data:`IO_PARAMETERS` order, then the extras in their set's order.  ``"all"`` switches on
    every IO parameter (the ``thesis`` set).

    >>> parse_parameters("k1, c,x0")
    ('c', 'x0', 'k1')
    >>> parse_parameters("c,x0,y0,ebner")[:5]
    ('c', 'x0', 'y0', 'e1', 'e2')

    Raises
    ------
    AdditionalParameterError
        An unknown name (named, with the allowed names and sets), extras of two sets, or an
        empty list.
    """
    items = [s.strip().lower() for s in (text.split(",") if isinstance(text, str) else text)]
    items = [s for s in items if s]
    if items == ["all"]:
        return IO_PARAMETERS
    names: list[str] = []
    lens: list[str] = []
    for s in items:
        if s in PARAMETER_SETS:
            names += PARAMETER_SETS[s].parameters
        elif s in IO_PARAMETERS or s in _EXTRA_SET:
            names.append(s)
        elif s in LENS_PARAMETERS:
            lens.append(s)
        elif s == "fisheye":
            lens += ["fx", "fy", "cx", "cy"]
            names += ["k1", "k2", "k3", "k4"]
        else:
            raise AdditionalParameterError(
                f"unknown self-calibration parameter {s!r}; allowed: " + ", ".join(IO_PARAMETERS)
                + " (or 'all'), the sets " + ", ".join(PARAMETER_SETS) + ", or single terms of a set "
                "(k4, b1, b2; e1-e12; g1-g44)")
    if lens:                                              # Brown/fisheye names: checked per camera at bind
        return (tuple(p for p in IO_PARAMETERS if p in names) + tuple(q for q in ("k4",) if q in names)
                + tuple(q for q in LENS_PARAMETERS if q in lens)
                + tuple(q for q in names if q not in IO_PARAMETERS and q != "k4"))
    if not names:
        raise AdditionalParameterError("no self-calibration parameter named; give e.g. c,x0,y0,k1 or ebner")
    sets = list(dict.fromkeys(_EXTRA_SET[q] for q in names if q in _EXTRA_SET))
    if len(sets) > 1:
        raise AdditionalParameterError(f"self-calibration: the sets {sets[0]!r} and {sets[1]!r} cannot be "
                                       "combined (their corrections overlap); choose one")
    extra = PARAMETER_SETS[sets[0]].extra if sets else ()
    return tuple(p for p in IO_PARAMETERS if p in names) + tuple(q for q in extra if q in names)


def lens_parameters(parameters: Sequence[str], kind_parameters: Sequence[str]) -> tuple[str, ...]:
    """The names among *parameters* (parsed) a Brown/fisheye camera with *kind_parameters* takes.

    ``all`` (the parsed :data:`IO_PARAMETERS`) stands for every parameter of the model.

    >>> lens_parameters(("k1", "k2", "p1", "p2", "fx", "cx", "cy"), ("fx", "fy", "cx", "cy", "k1", "k2"))
    ('fx', 'cx', 'cy', 'k1', 'k2')
    """
    if tuple(parameters) == IO_PARAMETERS:
        return tuple(kind_parameters)
    return tuple(q for q in kind_parameters if q in parameters)


def extra_parameter_set(parameters: Sequence[str]) -> ParameterSet | None:
    """The :class:`~lidarcat.geometry.apsets.ParameterSet` of the extra parameters among
    *parameters* (parsed), reduced to those switched on; None when there are none."""
    extra = [q for q in parameters if q in _EXTRA_SET]
    if not extra:
        return None
    full = PARAMETER_SETS[_EXTRA_SET[extra[0]]]
    idx = [full.extra.index(q) for q in extra]
    return dataclasses.replace(full, extra=tuple(extra), coef=full.coef[idx],
                               units={q: full.units[q] for q in extra})


# ---------------------------------------------------------------------------
# self-calibration
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class SelfCalibration:
    """Switch on interior-orientation parameters of the cameras of a block.

    Parameters
    ----------
    cameras : mapping of str to Camera
        Calibration of every camera (values and ``sd_*`` of the certificate).
    photo_camera : sequence of str, (P,)
        Camera id of every photo of the problem, in its photo order.
    parameters : str or sequence of str
        Names among :data:`IO_PARAMETERS` (``"c,x0,y0,k1"``), the same for every
        camera.
    use_priors : bool
        Weight every parameter by its certificate sd (``sd_focal_length_mm``,
        ``sd_principal_point_x_mm``, ``sd_k1``, ...); False leaves all free.
    """

    cameras: Mapping[str, Camera]
    photo_camera: Sequence[str]
    parameters: str | Sequence[str] = "c,x0,y0,k1,k2"
    use_priors: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "parameters", parse_parameters(self.parameters))
        object.__setattr__(self, "photo_camera", tuple(str(c) for c in self.photo_camera))
        object.__setattr__(self, "cameras", dict(self.cameras))
        missing = sorted(set(self.photo_camera) - set(self.cameras))
        if missing:
            raise AdditionalParameterError(f"self-calibration: camera {missing[0]!r} of a photo has no "
                                           "calibration")

    def bind(self, problem) -> _BoundIO | _BoundLens:
        """The parameters of this switch for *problem* (see the module's component protocol).

        Raises
        ------
        AdditionalParameterError
            Frame and Brown/fisheye cameras in one block, or a name no camera of the block has.
        """
        used = list(dict.fromkeys(self.photo_camera))
        lens = [c for c in used if self.cameras[c].lens is not None]
        if not lens:
            odd = [q for q in self.parameters if q in LENS_PARAMETERS]
            if odd:
                raise AdditionalParameterError(
                    f"self-calibration parameter {odd[0]!r} belongs to Brown/fisheye cameras; camera {used[0]!r} is "
                    f"a frame camera ({', '.join(IO_PARAMETERS)}, or a set)")
            return _BoundIO(self, problem)
        if len(lens) < len(used):
            frame = next(c for c in used if c not in lens)
            raise AdditionalParameterError(
                f"self-calibration of frame camera {frame!r} beside {self.cameras[lens[0]].model} camera "
                f"{lens[0]!r} is not supported in one adjustment; calibrate one kind (the other fixed) at a time")
        return _BoundLens(self, problem)



def _scale_note(q: str, points_m: np.ndarray, eo_params: np.ndarray) -> str:
    """Why a focal length (*q*: c, fx, fy) and the camera heights cannot be told apart."""
    h = points_m[:, 2]
    rel = float(np.std(h) / max(np.mean(eo_params[:, 2]) - np.mean(h), 1e-9))
    return (f"{q} scales the image as the flying height does and the terrain relief (sd of the point "
            f"heights) is {rel:.1%} of the flying height: flat terrain and near-nadir photos cannot "
            "separate them; GNSS camera heights or more relief can")


def _shift_note(partner: str) -> str:
    """Why a principal-point shift and the camera's shift/tilt (*partner*) cannot be told apart."""
    return (f"a shift of the principal point moves the image as a shift or tilt of the camera "
            f"({partner}) does; camera positions/attitudes (GNSS/INS) or cross strips separate them")


def _cameras_of_observations(spec: SelfCalibration, problem) -> tuple[list[Camera], np.ndarray, np.ndarray]:
    """The cameras the photos of *problem* use (in order of first use), each photo's and each observation's
    index into them."""
    if len(spec.photo_camera) != problem.n_photos:
        raise AdditionalParameterError(f"self-calibration: {len(spec.photo_camera)} photo camera(s) given "
                                       f"for {problem.n_photos} photos")
    used = list(dict.fromkeys(spec.photo_camera))
    cam_of_photo = np.array([used.index(c) for c in spec.photo_camera], dtype=np.int64)
    return [spec.cameras[c] for c in used], cam_of_photo, cam_of_photo[problem.photo_index]


class _BoundIO:
    """Self-calibration bound to a problem: m parameters per camera used by its photos."""

    group_kind = "camera"

    def __init__(self, spec: SelfCalibration, problem):
        self.cams, cam_of_photo, self.cam_of_obs = _cameras_of_observations(spec, problem)
        self.params = spec.parameters
        m = len(self.params)
        self.m = m
        # the named set's own parameters (Ebner, Grün, Brown's k4/b1/b2): A(x_fot; theta) subtracted
        self.aps = extra_parameter_set(self.params)
        self.n_io = m - (len(self.aps.extra) if self.aps else 0)
        self.b_mm = [self.aps.scale_mm(*cam.frame_size_mm) if self.aps else 1.0 for cam in self.cams]
        self.notes: list[str] = []
        units = {**IO_UNITS, **(self.aps.units if self.aps else {})}
        self.names = [f"{cam.id}.{q}" for cam in self.cams for q in self.params]
        self.units = [units[q] for _ in self.cams for q in self.params]
        self.groups = [f"camera {cam.id}" for cam in self.cams for _ in self.params]
        sd = []
        for cam in self.cams:
            for q in self.params:
                s = cam.sd.get(f"sd_{_FIELD[q]}", 0.0) if spec.use_priors and q in _FIELD else 0.0
                sd.append(s if s > 0 else np.inf)
        self.prior_sd = np.array(sd, dtype=float)
        self.calibrated = np.array([getattr(cam, _FIELD[q]) if q in _FIELD else 0.0
                                    for cam in self.cams for q in self.params])
        self.n = m * len(self.cams)
        self.cols = (self.cam_of_obs * m)[:, None] + np.arange(m)[None, :]     # (n, m) local columns
        # x_fot of every observation under the certificate
        self.fot0 = np.empty_like(np.asarray(problem.xy_mm))
        for k, cam in enumerate(self.cams):
            sel = self.cam_of_obs == k
            self.fot0[sel] = cam.photo_to_fot(problem.xy_mm[sel])
        self.cam_of_photo = cam_of_photo
        # the measured extent of every camera's photo coordinates (for the correlation "why")
        self.extent_mm = [(self.fot0[self.cam_of_obs == k].min(axis=0), self.fot0[self.cam_of_obs == k].max(axis=0))
                          if np.any(self.cam_of_obs == k) else (np.zeros(2), np.zeros(2)) for k in range(len(self.cams))]

    def explain(self, name: str, partner: str, eo: bool, points_m: np.ndarray, eo_params: np.ndarray) -> str | None:
        """Why parameter *name* of this component cannot be told from *partner* (an exterior-orientation
        parameter when *eo*, else another additional parameter's name): one clause, or None if not ours."""
        if name not in self.names:
            return None
        k, q = divmod(self.names.index(name), self.m)
        q = self.params[q]
        cam = self.cams[k]
        lo, hi = self.extent_mm[k]
        if eo and q == "c" and partner == "Z0":
            return _scale_note(q, points_m, eo_params)
        if eo and q in ("x0", "y0"):
            return _shift_note(partner)
        if eo:
            return (f"over the measured area (x {lo[0]:.1f} .. {hi[0]:.1f}, y {lo[1]:.1f} .. {hi[1]:.1f} mm) its "
                    f"correction looks like a change of {partner}")
        other = partner.split(".")[-1] if partner in self.names else None
        if other is None:
            return None
        if self.aps is not None and self.aps.grid and (q in self.aps.extra or other in self.aps.extra):
            b = self.b_mm[k]
            w, hgt = cam.frame_size_mm
            g = (self.aps.grid - 1) // 2
            return (f"the {self.aps.name} polynomials are orthogonal over the grid u, v in [-{g}, {g}] "
                    f"(b = {b:.2f} mm), "
                    f"but the measured photo coordinates span u {lo[0] / b:+.2f} .. {hi[0] / b:+.2f}, "
                    f"v {lo[1] / b:+.2f} .. {hi[1] / b:+.2f} (frame {w:.1f} x {hgt:.1f} mm): over that area "
                    f"{q} and {other} nearly coincide; fix one of them or measure points to the frame's edges")
        r_max = float(np.hypot(np.maximum(np.abs(lo), np.abs(hi))[0], np.maximum(np.abs(lo), np.abs(hi))[1]))
        corner = float(np.hypot(*cam.frame_size_mm)) / 2
        return (f"over the measured photo coordinates (up to {r_max:.1f} mm from the centre; the frame corner is at "
                f"{corner:.1f} mm) the corrections of {q} and {other} are nearly proportional; fix one of them"
                + (" or measure points nearer the corners" if r_max < 0.8 * corner else ""))

    def _camera(self, k: int, theta: np.ndarray) -> Camera:
        """Camera k with the corrections (refraction keeps the calibrated c)."""
        cam = self.cams[k]
        d = theta[k * self.m:(k + 1) * self.m]
        changes = {_FIELD[q]: getattr(cam, _FIELD[q]) + v for q, v in zip(self.params, d)
                   if q in _FIELD and q not in ("c", "x0", "y0")}
        return dataclasses.replace(cam, **changes) if changes else cam

    def _fot(self, theta: np.ndarray) -> np.ndarray:
        shift = np.zeros((len(self.cams), 2))
        for k in range(len(self.cams)):
            for a, q in enumerate(("x0", "y0")):
                if q in self.params:
                    shift[k, a] = theta[k * self.m + self.params.index(q)]
        return self.fot0 - shift[self.cam_of_obs]

    def _extra(self, k: int, theta: np.ndarray) -> np.ndarray:
        """The set's extra parameters of camera k."""
        return theta[k * self.m + self.n_io:(k + 1) * self.m]

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        fot = self._fot(theta)
        xy = np.empty_like(fot)
        focal = np.array(fields["focal_length_mm"], dtype=float)
        for k in range(len(self.cams)):
            sel = self.cam_of_obs == k
            xy[sel] = fot[sel] - self._camera(k, theta)._total_distortion(fot[sel])
            if self.aps is not None:
                xy[sel] -= self.aps.corrections(fot[sel], self._extra(k, theta), self.b_mm[k])
            if "c" in self.params:
                focal[self.cam_of_photo == k] = self.cams[k].focal_length_mm + theta[k * self.m
                                                                                   + self.params.index("c")]
        fields["xy_mm"] = xy
        fields["focal_length_mm"] = focal

    def score_bias(self, theta: np.ndarray, problem, weight: np.ndarray) -> np.ndarray | None:
        """The expected gradient at the truth of the set's extra terms (errors in variables).

        The terms ``f_i`` are evaluated at the measured ``x_fot``, which carries the noise ``e`` the
        residual carries (``v = -M e``, ``M = I - dD/dx - dA/dx``), so ``E[f_i(x + e)^T P v] =
        -tr(G_i^T P M Sigma_e)`` per observation, ``G_i = d f_i / d x_fot``, ``Sigma_e = diag(sd^2)``,
        ``P`` = *weight* (n, 2, 2): the weight less the part the observation's own point absorbs
        (``W - W a V^-1 a^T W``, :mod:`.selfcal`).  None without a named set (the thesis terms are
        left as they are).  :mod:`.selfcal` removes its effect from the converged estimate
        (docs/cameras.md, "The cause").
        """
        if self.aps is None:
            return None
        fot = self._fot(theta)
        sd2 = np.asarray(problem.sd_mm, dtype=float) ** 2
        out = np.zeros(self.n)
        n_extra = len(self.aps.extra)
        for k in range(len(self.cams)):
            sel = self.cam_of_obs == k
            if not sel.any():
                continue
            f, extra = fot[sel], self._extra(k, theta)
            mm = (np.eye(2)[None] - self._camera(k, theta)._distortion_jacobian(f)
                  - self.aps.jacobian_xy(f, extra, self.b_mm[k]))
            wms = (weight[sel] @ mm) * sd2[sel][:, None, :]                  # P M Sigma_e
            for q in range(n_extra):
                unit = np.zeros(n_extra)
                unit[q] = 1.0
                g = self.aps.jacobian_xy(f, unit, self.b_mm[k])                # d f_q / d x_fot (the set is linear)
                out[k * self.m + self.n_io + q] = -float(np.einsum("nab,nab->", g, wms))
        return out

    def jacobians(self, theta: np.ndarray, state) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
        fot = self._fot(theta)
        x, y = fot[:, 0], fot[:, 1]
        r2 = x * x + y * y
        n = len(x)
        J = np.zeros((n, 2, self.m))
        for a, q in enumerate(self.params):
            if q == "c":
                focal = state.focal_length_mm[state.photo_index]
                J[:, :, a] = state.xy_pred / focal[:, None]
            elif q in ("x0", "y0"):
                jd = np.empty((n, 2, 2))
                for k in range(len(self.cams)):
                    sel = self.cam_of_obs == k
                    jd[sel] = self._camera(k, theta)._distortion_jacobian(fot[sel])
                    if self.aps is not None:
                        jd[sel] += self.aps.jacobian_xy(fot[sel], self._extra(k, theta), self.b_mm[k])
                e = 0 if q == "x0" else 1
                J[:, :, a] = np.eye(2)[None, :, e] - jd[:, :, e]
            elif q in ("k1", "k2", "k3"):
                power = r2 ** int(q[1])
                J[:, 0, a], J[:, 1, a] = x * power, y * power
            elif q == "p1":
                J[:, 0, a], J[:, 1, a] = r2 + 2 * x * x, 2 * x * y
            elif q == "p2":
                J[:, 0, a], J[:, 1, a] = 2 * x * y, r2 + 2 * y * y
        if self.aps is not None:                          # dv/dtheta_i = f_i(x_fot / b)
            for k in range(len(self.cams)):
                sel = self.cam_of_obs == k
                J[sel, :, self.n_io:] = self.aps.jacobian(fot[sel], self.b_mm[k])
        return [("obs", np.arange(n), J, self.cols)]


class _BoundLens:
    """Self-calibration of Brown/fisheye cameras bound to a problem (module docstring)."""

    group_kind = "camera"

    def __init__(self, spec: SelfCalibration, problem):
        self.cams, cam_of_photo, self.cam_of_obs = _cameras_of_observations(spec, problem)
        self.params = [lens_parameters(spec.parameters, cam.lens.PARAMETERS) for cam in self.cams]
        for q in spec.parameters:
            if tuple(spec.parameters) != IO_PARAMETERS and not any(q in ps for ps in self.params):
                kinds = "; ".join(f"{cam.id!r} ({cam.model}): {', '.join(cam.lens.PARAMETERS)}" for cam in self.cams)
                raise AdditionalParameterError(f"self-calibration parameter {q!r} is no parameter of the block's "
                                               f"cameras ({kinds}), or 'all'")
        self.offsets = np.cumsum([0] + [len(ps) for ps in self.params])
        self.n = int(self.offsets[-1])
        self.names = [f"{cam.id}.{q}" for cam, ps in zip(self.cams, self.params) for q in ps]
        self.units = [_LENS_UNITS.get(q, "1") for ps in self.params for q in ps]
        self.groups = [f"camera {cam.id}" for cam, ps in zip(self.cams, self.params) for _ in ps]
        sd = [cam.sd.get(f"sd_{q}", 0.0) if spec.use_priors else 0.0
              for cam, ps in zip(self.cams, self.params) for q in ps]
        self.prior_sd = np.array([s if s > 0 else np.inf for s in sd], dtype=float)
        self.calibrated = np.array([getattr(cam.lens, q) for cam, ps in zip(self.cams, self.params) for q in ps])
        self.notes: list[str] = []
        # the measured pixels, recovered from the problem's photo coordinates under the calibration
        self.rows = [np.flatnonzero(self.cam_of_obs == k) for k in range(len(self.cams))]
        self.px = np.empty_like(np.asarray(problem.xy_mm, dtype=float))
        for k, cam in enumerate(self.cams):
            self.px[self.rows[k]] = cam.photo_to_pixel(problem.xy_mm[self.rows[k]])

    def explain(self, name: str, partner: str, eo: bool, points_m: np.ndarray, eo_params: np.ndarray) -> str | None:
        """Why parameter *name* cannot be told from *partner* (see :meth:`_BoundIO.explain`), or None."""
        if name not in self.names:
            return None
        k = next(i for i in range(len(self.cams)) if self.offsets[i] <= self.names.index(name) < self.offsets[i + 1])
        cam, q = self.cams[k], name.split(".")[-1]
        if eo and q in ("fx", "fy") and partner == "Z0":
            return _scale_note(q, points_m, eo_params)
        if eo and q in ("cx", "cy"):
            return _shift_note(partner)
        other = partner.split(".")[-1] if partner in self.names else None
        radial = ("k1", "k2", "k3", "k4")
        if not eo and q in radial and other in radial:
            rays = cam.lens.unproject(self.px[self.rows[k]])
            seen = float(np.degrees(np.arccos(np.clip(rays[:, 2], -1, 1))).max())
            corner = float(np.degrees(np.arccos(np.clip(cam.lens.unproject(cam.lens.corners_px())[:, 2], -1, 1))).max())
            return (f"over the measured rays (up to {seen:.1f} deg from the axis; the image corner at {corner:.1f} deg) the "
                    f"radial terms {q} and {other} change the image nearly in proportion; fix one of them, give it a prior "
                    "sd" + (" or measure points nearer the corners" if seen < 0.9 * corner else ""))
        return None

    def _lens(self, k: int, theta: np.ndarray):
        cam = self.cams[k]
        lens = cam.lens
        d = theta[self.offsets[k]:self.offsets[k + 1]]
        if not len(d):
            return lens
        values = lens.params()
        idx = [lens.PARAMETERS.index(q) for q in self.params[k]]
        values[idx] += d
        try:
            return lens.with_params(values)
        except CameraError as ex:
            raise AdditionalParameterError(f"self-calibration of camera {cam.id!r}: the corrected parameters left "
                                           f"the model's valid range: {ex}") from ex

    def _plane(self, k: int, theta: np.ndarray) -> tuple[np.ndarray, Any]:
        lens = self._lens(k, theta)
        rays = lens.unproject(self.px[self.rows[k]])
        return rays[:, :2] / rays[:, 2:], lens

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        xy = np.array(fields["xy_mm"], dtype=float)
        for k, cam in enumerate(self.cams):
            n, _ = self._plane(k, theta)
            c = cam.focal_length_mm
            xy[self.rows[k]] = np.column_stack([c * n[:, 0], -c * n[:, 1]])
        fields["xy_mm"] = xy

    def jacobians(self, theta: np.ndarray, state) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
        out = []
        for k, cam in enumerate(self.cams):
            if not len(self.params[k]) or not len(self.rows[k]):
                continue
            n, lens = self._plane(k, theta)
            _, j_ray, j_par = lens.project_jacobians(np.column_stack([n, np.ones(len(n))]))
            idx = [lens.PARAMETERS.index(q) for q in self.params[k]]
            J = np.linalg.solve(j_ray[:, :, :2], j_par[:, :, idx])         # -dn/dtheta
            J *= np.array([cam.focal_length_mm, -cam.focal_length_mm])[None, :, None]
            cols = np.broadcast_to(self.offsets[k] + np.arange(len(idx)), (len(n), len(idx)))
            out.append(("obs", self.rows[k], J, cols))
        return out


# ---------------------------------------------------------------------------
# GNSS flight-line offsets
# ---------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True, eq=False)
class GnssLineOffsets:
    """Antenna offset (and drift) of every GNSS flight line, where camera positions are constrained.

    Parameters
    ----------
    line_of_photo : sequence, (P,)
        Flight-line label of every photo (None or "" for a photo in no line).
    drift : bool
        Also a linear drift along each line (m per km).
    sd_offset_m, sd_drift_m_per_km : float
        Prior sds (inf: free, the default).
    """

    line_of_photo: Sequence[Any]
    drift: bool = False
    sd_offset_m: float = np.inf
    sd_drift_m_per_km: float = np.inf

    def bind(self, problem) -> _BoundGnss:
        """The parameters of this switch for *problem* (see the module's component protocol)."""
        return _BoundGnss(self, problem)


class _BoundGnss:
    """GNSS line offsets bound to a problem: 3 (or 6) parameters per line with constrained positions."""

    group_kind = "gnss"

    def __init__(self, spec: GnssLineOffsets, problem):
        if len(spec.line_of_photo) != problem.n_photos:
            raise AdditionalParameterError(f"GNSS line offsets: {len(spec.line_of_photo)} line label(s) for "
                                           f"{problem.n_photos} photos")
        if problem.eo_constraint_photo_index is None or not len(problem.eo_constraint_photo_index):
            raise AdditionalParameterError("GNSS line offsets need constrained camera positions "
                                           "(eo constraints); the problem has none")
        labels = [None if v is None or str(v) == "" else str(v) for v in spec.line_of_photo]
        k = problem.eo_constraint_photo_index
        pos_ok = np.isfinite(problem.eo_constraint_sd[:, :3]).all(axis=1)
        lines = list(dict.fromkeys(labels[i] for i, ok in zip(k, pos_ok) if ok and labels[i] is not None))
        if not lines:
            raise AdditionalParameterError("GNSS line offsets: no photo with a constrained position is in a line")
        per = 6 if spec.drift else 3
        self.m = per
        self.n = per * len(lines)
        comp = ("E", "N", "h")
        self.names, self.units, self.groups = [], [], []
        for ln in lines:
            self.names += [f"gnss.{ln}.offset_{c}" for c in comp]
            self.units += ["m"] * 3
            if spec.drift:
                self.names += [f"gnss.{ln}.drift_{c}" for c in comp]
                self.units += ["m/km"] * 3
            self.groups += [f"gnss line {ln}"] * per
        sd = [spec.sd_offset_m] * 3 + ([spec.sd_drift_m_per_km] * 3 if spec.drift else [])
        self.prior_sd = np.tile(np.where(np.asarray(sd, float) > 0, sd, np.inf), len(lines))
        rows, line_idx = [], []
        for r, (i, ok) in enumerate(zip(k, pos_ok)):
            if ok and labels[i] in lines:
                rows.append(r)
                line_idx.append(lines.index(labels[i]))
        self.rows = np.array(rows, dtype=np.int64)
        self.line_idx = np.array(line_idx, dtype=np.int64)
        # along-line distance (km) from the line centre, on the principal axis of the positions
        gnss = problem.eo_constraint_params[self.rows, :2]
        tau = np.zeros(len(self.rows))
        for li in range(len(lines)):
            sel = self.line_idx == li
            d = gnss[sel] - gnss[sel].mean(axis=0)
            if len(d) > 1:
                axis = np.linalg.svd(d, full_matrices=False)[2][0]
                if (d[-1] - d[0]) @ axis < 0:                  # tau grows in photo order
                    axis = -axis
                tau[sel] = d @ axis / 1000.0
        self.tau_km = tau
        self.drift = spec.drift

    def _design(self) -> np.ndarray:
        J = np.zeros((len(self.rows), 6, self.m))
        J[:, :3, :3] = np.eye(3)
        if self.drift:
            J[:, :3, 3:] = np.eye(3)[None] * self.tau_km[:, None, None]
        return J

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        e = np.array(fields["eo_constraint_params"], dtype=float)
        th = theta.reshape(-1, self.m)[self.line_idx]                   # (r, m)
        e[self.rows, :3] -= np.einsum("rij,rj->ri", self._design()[:, :3, :], th)
        fields["eo_constraint_params"] = e

    def jacobians(self, theta: np.ndarray, state):
        cols = (self.line_idx * self.m)[:, None] + np.arange(self.m)[None, :]
        return [("eo", self.rows, self._design(), cols)]
