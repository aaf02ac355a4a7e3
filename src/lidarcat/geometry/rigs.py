r"""Camera rigs: cameras with fixed relative poses, moved as one body per exposure (engine side).

A rig has a reference sensor (its frame is the rig's) and further sensors with their pose
relative to it, ``sensor_from_rig``: ``x_s = R_s x_rig + t_s`` (COLMAP's ``rigs.txt``/``rigs.bin``
convention, :func:`lidarcat.interop.colmap_binary.read_colmap_rigs_binary`).  An exposure (a
COLMAP *frame*) places the rig in the world: ``x_rig = R_r (X - C_r)`` with ``R_r`` world-to-rig
and ``C_r`` the rig origin in the world.  A point ``X`` seen by sensor ``s`` of exposure ``f``::

    x_s = R_s R_r (X - C_r) + t_s,        px = camera_s.project(x_s)

so the unknowns of a rig block are 6 per exposure (not per image) plus 6 per non-reference
sensor (when estimated).  Jacobians (increments ``R <- exp([d]x) R`` on the left, as
:mod:`lidarcat.geometry.rolling`), with ``J`` the camera's ``d px / d ray``::

    d px / dX          = J R_s R_r               d px / dC_r       = -J R_s R_r
    d px / d(delta_r)  = -J R_s [x_rig]x         d px / d(eps_s)   = -J [R_s x_rig]x
    d px / dt_s        = J

(``[a]x b = a x b``; a rotation ``exp([d]x)`` turns ``x`` into ``x + d x x = x - [x]x d``).  The
reference sensor has ``R_s = I``, ``t_s = 0`` by definition and no sensor unknowns.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import CameraError
from .models import CameraModel

__all__ = ["Rig", "project_rig"]


def _skew(a: np.ndarray) -> np.ndarray:
    z = np.zeros(a.shape[:-1])
    return np.stack([np.stack([z, -a[..., 2], a[..., 1]], -1), np.stack([a[..., 2], z, -a[..., 0]], -1),
                     np.stack([-a[..., 1], a[..., 0], z], -1)], -2)


@dataclass(frozen=True, eq=False)
class Rig:
    """A rig of cameras with fixed relative poses.

    Parameters
    ----------
    id : str
        Rig id (named in errors).
    cameras : sequence of CameraModel, (S,)
        The sensors; the first is the reference.
    rotation : array_like, (S, 3, 3)
        ``R_s`` of ``sensor_from_rig`` (the first the identity).
    translation_m : array_like, (S, 3)
        ``t_s`` of ``sensor_from_rig``, m (the first zero).

    Raises
    ------
    CameraError
        Shapes that do not match the sensors, a rotation that is not one, a reference sensor
        that is not the rig frame, a camera id used twice (names the rig and the sensor).
    """

    id: str
    cameras: Sequence[CameraModel]
    rotation: Any
    translation_m: Any

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        s = len(cams)
        r = np.asarray(self.rotation, dtype=float)
        t = np.asarray(self.translation_m, dtype=float)
        if s < 1 or r.shape != (s, 3, 3) or t.shape != (s, 3):
            raise CameraError(f"rig {self.id!r}: {s} sensor(s) need rotations (S, 3, 3) and translations (S, 3), "
                              f"got {r.shape} and {t.shape}")
        ids = [c.id for c in cams]
        for k, c in enumerate(cams):
            if ids.index(c.id) != k:
                raise CameraError(f"rig {self.id!r}: camera {c.id!r} is sensor {ids.index(c.id)} and {k}")
            if not (np.isfinite(r[k]).all() and np.isfinite(t[k]).all()):
                raise CameraError(f"rig {self.id!r}: sensor {k} (camera {c.id!r}): pose is not finite")
            dev = np.abs(r[k] @ r[k].T - np.eye(3)).max()
            if dev > 1e-9 or np.linalg.det(r[k]) < 0:
                raise CameraError(f"rig {self.id!r}: sensor {k} (camera {c.id!r}): rotation is no rotation "
                                  f"(|R R^T - I| = {dev:.3g}, det {np.linalg.det(r[k]):.3g})")
        if np.abs(r[0] - np.eye(3)).max() > 1e-12 or np.abs(t[0]).max() > 0:
            raise CameraError(f"rig {self.id!r}: the reference sensor (camera {cams[0].id!r}) is the rig frame: "
                              f"its sensor_from_rig must be the identity")
        object.__setattr__(self, "cameras", cams)
        r.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation_m", t)

    def check_image_sizes(self, sizes: Mapping[str, tuple[str, int, int]]) -> None:
        """Refuse images whose size disagrees with their sensor's camera.

        Parameters
        ----------
        sizes : mapping of str to (str, int, int)
            ``{image name: (camera id, width_px, height_px)}`` of the rig's images.

        Raises
        ------
        CameraError
            An image of a camera that is not in the rig, or of another size than its camera
            (names the rig, the image and both sizes).
        """
        by_id = {c.id: c for c in self.cameras}
        for image, (cam_id, w, h) in sizes.items():
            if cam_id not in by_id:
                raise CameraError(f"rig {self.id!r}: image {image!r} is of camera {cam_id!r}, which is not in the "
                                  f"rig (cameras: {', '.join(by_id)})")
            c = by_id[cam_id]
            if (int(w), int(h)) != (c.width_px, c.height_px):
                raise CameraError(f"rig {self.id!r}: image {image!r} is {int(w)} x {int(h)} px, its camera "
                                  f"{cam_id!r} {c.width_px} x {c.height_px} px: the rig's cameras disagree in size")


def project_rig(rig: Rig, sensor: Any, rig_rotation: Any, rig_position_m: Any, points_m: Any
                ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Pixels of object points seen by the sensors of a rig, and their Jacobians (module docstring).

    Parameters
    ----------
    rig : Rig
    sensor : array_like of int, (N,)
        Sensor index of every observation.
    rig_rotation : array_like, (N, 3, 3)
        World-to-rig rotation ``R_r`` of the observation's exposure.
    rig_position_m : array_like, (N, 3)
        Rig origin ``C_r`` of the exposure, m.
    points_m : array_like, (N, 3)
        Object points, m.

    Returns
    -------
    px : ndarray, (N, 2)
    jac : dict of ndarray, each (N, 2, 3)
        ``point``, ``rig_position``, ``rig_rotation``, ``sensor_rotation``, ``sensor_translation``
        (the last two zero for the reference sensor).

    Raises
    ------
    CameraError
        A sensor index outside the rig, or a ray the sensor's model refuses.
    """
    s = np.asarray(sensor).ravel()
    X = np.asarray(points_m, dtype=float).reshape(-1, 3)
    n = len(X)
    rr = np.broadcast_to(np.asarray(rig_rotation, dtype=float), (n, 3, 3))
    cr = np.broadcast_to(np.asarray(rig_position_m, dtype=float), (n, 3))
    if s.shape != (n,) or not np.issubdtype(s.dtype, np.integer) or (s < 0).any() or (s >= len(rig.cameras)).any():
        raise CameraError(f"rig {rig.id!r}: sensor indices must be {n} integers 0..{len(rig.cameras) - 1}")
    x_rig = np.einsum("nij,nj->ni", rr, X - cr)
    rs, ts = rig.rotation[s], rig.translation_m[s]
    x_s = np.einsum("nij,nj->ni", rs, x_rig) + ts
    px = np.empty((n, 2))
    j_ray = np.empty((n, 2, 3))
    for k, cam in enumerate(rig.cameras):
        sel = s == k
        if sel.any():
            px[sel], j_ray[sel], _ = cam.project_jacobians(x_s[sel])
    m = rs @ rr
    ref = (s == 0)[:, None, None]
    jac = {
        "point": j_ray @ m,
        "rig_position": -(j_ray @ m),
        "rig_rotation": -(j_ray @ rs @ _skew(x_rig)),
        "sensor_rotation": np.where(ref, 0.0, -(j_ray @ _skew(np.einsum("nij,nj->ni", rs, x_rig)))),
        "sensor_translation": np.where(ref, 0.0, j_ray),
    }
    return px, jac
