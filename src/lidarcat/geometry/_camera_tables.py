"""The ``camera.toml`` table of a camera: its keys, a camera built from a table, and a camera as a table.

Private to :mod:`lidarcat.geometry`: :class:`CameraTables` is the base of
:class:`~lidarcat.geometry.camera.Camera` that holds its table forms -- :meth:`~CameraTables.from_dict`
(a parsed ``camera.toml`` table in, the camera out, every bad key or value a
:class:`~lidarcat.errors.CameraError` naming the field), :meth:`~CameraTables.to_dict`,
:meth:`~CameraTables.to_toml` (the text of the table, which round-trips) and :meth:`~CameraTables.summary`
-- so that ``camera.py`` keeps the interior orientation (eq. 01-07) and its validation.  Its methods use
only what ``Camera`` defines (``cls(...)``, ``cls.from_model``, the fields and the eq. 01-07 methods).
Nothing here reads or writes a file: ``camera.toml`` files are read by :mod:`lidarcat.survey.cameras`
(the engine knows no survey folder), and the callers write the text of :meth:`~CameraTables.to_toml`.

A frame camera's table holds :data:`CAMERA_KEYS` (the thesis's calibration, eq. 01-07), any of
:data:`SD_KEYS` and :data:`MOTION_KEYS`; a ``model = "brown"`` / ``"fisheye"`` table holds the model's
``PARAMETERS`` in pixels (``width_px, height_px, fx, fy, cx, cy``, the distortion), ``pixel_size_mm``
(:data:`LENS_PIXEL_SIZE_MM` by default) and ``sd_<parameter>`` (docs/survey-format.md, docs/cameras.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from .._util import excerpt
from ..errors import CameraError
from .brown import BrownCamera
from .fisheye import FisheyeCamera

__all__ = ["CameraTables", "camera_error", "toml_str", "FLOAT_KEYS", "INT_KEYS", "STR_KEYS", "CAMERA_KEYS",
           "SD_KEYS", "MOTION_KEYS", "LENS_MODELS", "LENS_PIXEL_SIZE_MM", "LENS_ONLY_KEYS", "MODEL_NAMES"]

#: numeric calibration keys of a camera table, in file order
FLOAT_KEYS = (
    "focal_length_mm", "principal_point_x_mm", "principal_point_y_mm",
    "k1", "k2", "k3", "p1", "p2", "refraction_eps45",
    "pixel_size_x_mm", "pixel_size_y_mm",
)
#: the image size keys, pixels
INT_KEYS = ("columns_px", "rows_px")
#: the free-text keys
STR_KEYS = ("model", "source")
#: every key a camera table may hold (besides the ``sd_*`` keys)
CAMERA_KEYS: tuple[str, ...] = STR_KEYS + FLOAT_KEYS + INT_KEYS
#: the optional standard-deviation keys: ``sd_`` + a calibration key
SD_KEYS: tuple[str, ...] = tuple(f"sd_{k}" for k in FLOAT_KEYS)
#: optional keys of the camera's motion during an exposure (issue 27): the rolling shutter's read-out
#: time from the top to the bottom row, ms (0: a global shutter, the default)
MOTION_KEYS: tuple[str, ...] = ("readout_time_ms",)
#: camera models a camera table may name besides the frame camera (``model = "brown"``)
LENS_MODELS: dict[str, type] = {"brown": BrownCamera, "fisheye": FisheyeCamera}
#: the nominal pixel pitch of a Brown or fisheye camera (mm): the unit of its photo coordinates only
LENS_PIXEL_SIZE_MM = 0.005
#: keys only a Brown or fisheye table holds (a frame table with one of them names no known model)
LENS_ONLY_KEYS = ("width_px", "height_px", "fx", "fy", "cx", "cy", "skew", "k4", "pixel_size_mm")
#: the names a table's ``model`` may give a camera model by
MODEL_NAMES = ("frame",) + tuple(LENS_MODELS)


def _short(name: str) -> str:
    """A key or id from a file, cut for a message (the whole name stays in ``err.field``)."""
    return name if len(name) <= 60 else name[:60] + "..."


def camera_error(field_name: str, message: str) -> CameraError:
    """The error of a bad field of a camera: ``field 'NAME': message``, with ``err.field`` and ``err.detail``."""
    err = CameraError(f"field {_short(field_name)!r}: {message}")
    err.field = field_name  # type: ignore[attr-defined]
    err.detail = message  # type: ignore[attr-defined]
    return err


def toml_str(s: str) -> str:
    """A TOML basic string (json's escaping is valid TOML for these characters)."""
    return json.dumps(s, ensure_ascii=False)


class CameraTables:
    """The table forms of :class:`~lidarcat.geometry.camera.Camera` (module docstring): a base class with
    no state of its own."""

    def to_dict(self) -> dict[str, Any]:
        """All parameters as a flat dict (the keys of a ``camera.toml`` table plus ``id``)."""
        if self.lens is not None:
            return {"id": self.id, **self._lens_dict()}
        out: dict[str, Any] = {"id": self.id}
        for name in CAMERA_KEYS:
            out[name] = getattr(self, name)
        out.update(self.sd)
        if self.readout_time_ms:
            out["readout_time_ms"] = self.readout_time_ms
        return out

    @classmethod
    def _lens_from_dict(cls, camera_id: str, kind: str, table: Mapping[str, Any]) -> Any:
        """A ``model = "brown"`` / ``"fisheye"`` table (module docstring)."""
        model_cls = LENS_MODELS[kind]
        params = model_cls.PARAMETERS
        keys = ("model", "source", "width_px", "height_px", "pixel_size_mm") + params + tuple(
            f"sd_{q}" for q in params) + MOTION_KEYS
        for key in table:
            if key not in keys:
                raise camera_error(key, f"unknown key of a {kind} camera; allowed: " + ", ".join(keys))
        required = ("width_px", "height_px") + tuple(f for f in model_cls.__dataclass_fields__
                                                     if f in params and model_cls.__dataclass_fields__[f].default
                                                     is dataclasses.MISSING)
        for key in required:
            if key not in table:
                raise camera_error(key, f"missing (required for a {kind} camera)")
        source = table.get("source", "")
        if not isinstance(source, str):
            raise camera_error("source", f"must be text, got {excerpt(source)}")
        try:
            lens = model_cls(camera_id, **{k: table[k] for k in ("width_px", "height_px") + params if k in table})
        except CameraError as ex:
            m = re.search(r"field '(\w+)': (.*)$", str(ex), re.S)
            if m is None:
                raise camera_error("model", str(ex)) from ex
            raise camera_error(m.group(1), m.group(2)) from ex
        sd = {k: table[k] for k in table if k.startswith("sd_")}
        return cls.from_model(lens, pixel_size_mm=table.get("pixel_size_mm", LENS_PIXEL_SIZE_MM), source=source,
                              sd=sd, readout_time_ms=table.get("readout_time_ms", 0.0))

    def _lens_dict(self) -> dict[str, Any]:
        """The table of a Brown or fisheye camera (``model``, size, parameters, pitch, sds)."""
        lens = self.lens
        assert lens is not None
        out: dict[str, Any] = {"model": lens.KIND}
        if self.source:
            out["source"] = self.source
        out.update({"width_px": lens.width_px, "height_px": lens.height_px})
        out.update({q: getattr(lens, q) for q in lens.PARAMETERS})
        out["pixel_size_mm"] = self.pixel_size_x_mm
        out.update(self.sd)
        if self.readout_time_ms:
            out["readout_time_ms"] = self.readout_time_ms
        return out

    @classmethod
    def from_dict(cls, camera_id: str, table: Mapping[str, Any]) -> Any:
        """Build a camera from a ``camera.toml`` table (flat ``sd_*`` keys).

        ``model = "brown"`` or ``"fisheye"`` makes a camera of that model (module docstring);
        any other ``model`` text describes a frame camera (``"Kodak DCS Pro 14n"``).

        Raises
        ------
        CameraError
            Unknown or missing key, or an invalid value (names the field); a table with the keys
            of a Brown/fisheye camera (``fx``, ``width_px``, ...) whose ``model`` is no known model.
        """
        kind = table.get("model")
        if isinstance(kind, str) and kind.strip().lower() in LENS_MODELS:
            return cls._lens_from_dict(camera_id, kind.strip().lower(), table)
        lens_keys = [k for k in LENS_ONLY_KEYS if k in table]
        if lens_keys and not any(k in table for k in FLOAT_KEYS + INT_KEYS):
            if kind is None:
                raise camera_error(lens_keys[0], "a camera with " + ", ".join(lens_keys) + " needs model = "
                                    "\"brown\" or \"fisheye\" (a frame camera has focal_length_mm, ...)")
            raise camera_error("model", f"unknown camera model {excerpt(kind)}; known: " + ", ".join(MODEL_NAMES))
        known = set(CAMERA_KEYS) | set(SD_KEYS) | set(MOTION_KEYS)
        for key in table:
            if key not in known:
                raise camera_error(key, "unknown key; allowed: " + ", ".join(CAMERA_KEYS + SD_KEYS + MOTION_KEYS))
        for key in FLOAT_KEYS + INT_KEYS:
            if key not in table:
                raise camera_error(key, "missing (required)")
        kwargs = {k: table[k] for k in CAMERA_KEYS if k in table}
        sd = {k: table[k] for k in SD_KEYS if k in table}
        return cls(camera_id, sd=sd, **kwargs, **{k: table[k] for k in MOTION_KEYS if k in table})

    def to_toml(self) -> str:
        """The camera as a ``camera.toml`` table (round-trips through :func:`lidarcat.survey.cameras.load_cameras`).

        >>> from lidarcat.geometry.camera import Camera
        >>> cam = Camera("a", 50.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01, 10, 20)
        >>> print(cam.to_toml().splitlines()[0])
        [a]
        """
        key = self.id if re.fullmatch(r"[A-Za-z0-9_-]+", self.id) else toml_str(self.id)
        lines = [f"[{key}]"]
        if self.lens is not None:
            for name, v in self._lens_dict().items():
                lines.append(f"{name} = {toml_str(v) if isinstance(v, str) else repr(v)}")
            return "\n".join(lines) + "\n"
        for name in STR_KEYS:
            if getattr(self, name):
                lines.append(f"{name} = {toml_str(getattr(self, name))}")
        for name in FLOAT_KEYS:
            lines.append(f"{name} = {getattr(self, name)!r}")
        for name in INT_KEYS:
            lines.append(f"{name} = {getattr(self, name)}")
        for name in SD_KEYS:
            if name in self.sd:
                lines.append(f"{name} = {self.sd[name]!r}")
        if self.readout_time_ms:
            lines.append(f"readout_time_ms = {self.readout_time_ms!r}")
        return "\n".join(lines) + "\n"

    def summary(self) -> dict[str, Any]:
        """Parameters plus derived figures: frame size (mm), half diagonal, and the
        largest correction (eq. 03-06) over the frame border, mm and px.

        >>> from lidarcat.geometry.camera import Camera
        >>> cam = Camera("a", 50.0, 0.0, 0.0, -1e-4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.01, 0.01, 2001, 1001)
        >>> round(cam.summary()["max_correction_mm"], 6)  # at the corner, r^2 = 125 mm^2
        0.139754
        """
        border = np.concatenate([
            np.column_stack([np.linspace(0, self.columns_px - 1, 201), np.zeros(201)]),
            np.column_stack([np.linspace(0, self.columns_px - 1, 201),
                             np.full(201, self.rows_px - 1.0)]),
            np.column_stack([np.zeros(201), np.linspace(0, self.rows_px - 1, 201)]),
            np.column_stack([np.full(201, self.columns_px - 1.0), np.linspace(0, self.rows_px - 1, 201)]),
        ])
        fot = np.asarray(self.pixel_to_fot(border))
        corr = fot - np.asarray(self.pixel_to_photo(border))
        mag = np.hypot(corr[:, 0], corr[:, 1])
        w, h = self.frame_size_mm
        if self.lens is None:
            out = self.to_dict()
        else:                                  # the pinhole's frame keys, the model's table under "lens"
            out = {"id": self.id, **{name: getattr(self, name) for name in CAMERA_KEYS}, "lens": self._lens_dict()}
        out.update({
            "frame_width_mm": w, "frame_height_mm": h,
            "half_diagonal_mm": math.hypot(w, h) / 2,
            "max_correction_mm": float(mag.max()),
            "max_correction_px": float(mag.max() / min(self.pixel_size_x_mm, self.pixel_size_y_mm)),
        })
        return out

