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
component.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ..geometry.camera import Camera
from ..errors import LidarcatError

__all__ = ["IO_PARAMETERS", "IO_UNITS", "SelfCalibration", "GnssLineOffsets", "parse_parameters",
           "AdditionalParameterError"]


class AdditionalParameterError(LidarcatError, ValueError):
    """An additional parameter that cannot be set up (named)."""


#: interior-orientation parameters that can be switched on, in this order
IO_PARAMETERS: tuple[str, ...] = ("c", "x0", "y0", "k1", "k2", "k3", "p1", "p2")
#: their units (corrections to the calibration certificate)
IO_UNITS: dict[str, str] = {"c": "mm", "x0": "mm", "y0": "mm", "k1": "mm^-2", "k2": "mm^-4",
                            "k3": "mm^-6", "p1": "mm^-1", "p2": "mm^-1"}
#: the Camera field of each parameter
_FIELD: dict[str, str] = {"c": "focal_length_mm", "x0": "principal_point_x_mm",
                          "y0": "principal_point_y_mm", "k1": "k1", "k2": "k2", "k3": "k3",
                          "p1": "p1", "p2": "p2"}


def parse_parameters(text: str | Sequence[str]) -> tuple[str, ...]:
    """Parameter names from ``"c,x0,y0,k1,k2"`` (or a sequence), validated, in :data:`IO_PARAMETERS` order.

    ``"all"`` switches on every parameter.

    >>> parse_parameters("k1, c,x0")
    ('c', 'x0', 'k1')

    Raises
    ------
    AdditionalParameterError
        An unknown name (named, with the allowed ones), or an empty list.
    """
    items = [s.strip().lower() for s in (text.split(",") if isinstance(text, str) else text)]
    items = [s for s in items if s]
    if items == ["all"]:
        return IO_PARAMETERS
    bad = [s for s in items if s not in IO_PARAMETERS]
    if bad:
        raise AdditionalParameterError(f"unknown self-calibration parameter {bad[0]!r}; allowed: "
                                       + ", ".join(IO_PARAMETERS) + " (or 'all')")
    if not items:
        raise AdditionalParameterError("no self-calibration parameter named; give e.g. c,x0,y0,k1")
    return tuple(p for p in IO_PARAMETERS if p in items)


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

    def bind(self, problem) -> _BoundIO:
        """The parameters of this switch for *problem* (see the module's component protocol)."""
        return _BoundIO(self, problem)


class _BoundIO:
    """Self-calibration bound to a problem: m parameters per camera used by its photos."""

    group_kind = "camera"

    def __init__(self, spec: SelfCalibration, problem):
        if len(spec.photo_camera) != problem.n_photos:
            raise AdditionalParameterError(f"self-calibration: {len(spec.photo_camera)} photo camera(s) given "
                                           f"for {problem.n_photos} photos")
        used = list(dict.fromkeys(spec.photo_camera))
        self.cams: list[Camera] = [spec.cameras[c] for c in used]
        cam_of_photo = np.array([used.index(c) for c in spec.photo_camera], dtype=np.int64)
        self.cam_of_obs = cam_of_photo[problem.photo_index]
        self.params = spec.parameters
        m = len(self.params)
        self.m = m
        self.names = [f"{cam.id}.{q}" for cam in self.cams for q in self.params]
        self.units = [IO_UNITS[q] for _ in self.cams for q in self.params]
        self.groups = [f"camera {cam.id}" for cam in self.cams for _ in self.params]
        sd = []
        for cam in self.cams:
            for q in self.params:
                s = cam.sd.get(f"sd_{_FIELD[q]}", 0.0) if spec.use_priors else 0.0
                sd.append(s if s > 0 else np.inf)
        self.prior_sd = np.array(sd, dtype=float)
        self.calibrated = np.array([getattr(cam, _FIELD[q]) for cam in self.cams for q in self.params])
        self.n = m * len(self.cams)
        self.cols = (self.cam_of_obs * m)[:, None] + np.arange(m)[None, :]     # (n, m) local columns
        # x_fot of every observation under the certificate
        self.fot0 = np.empty_like(np.asarray(problem.xy_mm))
        for k, cam in enumerate(self.cams):
            sel = self.cam_of_obs == k
            self.fot0[sel] = cam.photo_to_fot(problem.xy_mm[sel])
        self.cam_of_photo = cam_of_photo

    def _camera(self, k: int, theta: np.ndarray) -> Camera:
        """Camera k with the corrections (refraction keeps the calibrated c)."""
        cam = self.cams[k]
        d = theta[k * self.m:(k + 1) * self.m]
        changes = {_FIELD[q]: getattr(cam, _FIELD[q]) + v for q, v in zip(self.params, d)
                   if q not in ("c", "x0", "y0")}
        return dataclasses.replace(cam, **changes) if changes else cam

    def _fot(self, theta: np.ndarray) -> np.ndarray:
        shift = np.zeros((len(self.cams), 2))
        for k in range(len(self.cams)):
            for a, q in enumerate(("x0", "y0")):
                if q in self.params:
                    shift[k, a] = theta[k * self.m + self.params.index(q)]
        return self.fot0 - shift[self.cam_of_obs]

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        fot = self._fot(theta)
        xy = np.empty_like(fot)
        focal = np.array(fields["focal_length_mm"], dtype=float)
        for k in range(len(self.cams)):
            sel = self.cam_of_obs == k
            xy[sel] = fot[sel] - self._camera(k, theta)._total_distortion(fot[sel])
            if "c" in self.params:
                focal[self.cam_of_photo == k] = self.cams[k].focal_length_mm + theta[k * self.m
                                                                                   + self.params.index("c")]
        fields["xy_mm"] = xy
        fields["focal_length_mm"] = focal

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
                e = 0 if q == "x0" else 1
                J[:, :, a] = np.eye(2)[None, :, e] - jd[:, :, e]
            elif q in ("k1", "k2", "k3"):
                power = r2 ** int(q[1])
                J[:, 0, a], J[:, 1, a] = x * power, y * power
            elif q == "p1":
                J[:, 0, a], J[:, 1, a] = r2 + 2 * x * x, 2 * x * y
            else:  # p2
                J[:, 0, a], J[:, 1, a] = 2 * x * y, r2 + 2 * y * y
        return [("obs", np.arange(n), J, self.cols)]


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
