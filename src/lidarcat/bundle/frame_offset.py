r"""Frame offset between two sources of control, estimated jointly with the bundle.

When control comes from two sources -- GPS and LiDAR, or two LiDAR strips --
their coordinates may refer to frames with different origins (the thesis,
section 4.4: LiDAR-controlled minus GPS-controlled solution -0.32 / -0.20 /
+0.37 m in E / N / h, left unmodelled).  The points of the adjustment are in
the *reference* frame; an observed control coordinate ``X_s`` of the *source*
is mapped into it by

    X_ref = X_s + t                                             (3 parameters)
    X_ref = X_s + t + 1e-6 (s dX + eps x dX)                    (7 parameters)

with the shift ``t = (tE, tN, th)`` in metres, ``dX = X_s - Xbar`` relative to
the centroid ``Xbar`` of the source's control (so that the shift does not
correlate with scale and rotation through the lever arm), the scale change
``s`` in ppm and the small rotation vector ``eps = (eps_E, eps_N, eps_h)`` in
microradians (a linearised Helmert / Bursa-Wolf similarity: exact to
``(1e-6 |eps|)^2``, far below any survey's precision).  The control constraint
``X_j = X_ref +- sd`` of a source point becomes the residual

    v = X_j - X_s - t - 1e-6 (s dX + eps x dX),     dv/dt = -I,
    dv/ds = -1e-6 dX,   dv/d eps = 1e-6 [dX]_x   (since eps x dX = -[dX]_x eps).

So ``shift_m`` is what to *add* to the source's coordinates to put them in the
reference frame: ``--frame-offset lidar:gps`` estimates ``X_gps - X_lidar``,
the sign of the thesis's Table 12 (App. 3.1 GPS run minus App. 3.2 LiDAR run).
The reference source needs control too (it fixes the datum); with the source
alone the shift is a datum defect.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from .additional import AdditionalParameterError

__all__ = ["FrameOffset", "frame_offset_from_sources"]

_SHIFT = ("dE", "dN", "dh")
_SIMILARITY = ("scale", "rot_E", "rot_N", "rot_h")


@dataclasses.dataclass(frozen=True, eq=False)
class FrameOffset:
    """A shift (optionally a 7-parameter similarity) of one control source's frame.

    Parameters
    ----------
    source, reference : str
        Names of the shifted source and of the reference (e.g. ``"lidar"``, ``"gps"``).
    rows : sequence of int
        Rows of ``problem.constraint_point_index`` whose control comes from *source*.
    similarity : bool
        Also scale (ppm) and three small rotations (microradians).
    """

    source: str
    reference: str
    rows: Sequence[int]
    similarity: bool = False

    def __post_init__(self) -> None:
        rows = np.unique(np.asarray(self.rows, dtype=np.int64))
        rows.setflags(write=False)
        object.__setattr__(self, "rows", rows)
        if not len(rows):
            raise AdditionalParameterError(f"frame offset {self.source}:{self.reference}: the source "
                                           f"{self.source!r} has no control point in the adjustment")

    def bind(self, problem) -> _BoundFrame:
        """The parameters of this offset for *problem* (see :mod:`.additional`, component protocol)."""
        return _BoundFrame(self, problem)


def frame_offset_from_sources(problem, point_source: Sequence[str], source: str, reference: str,
                              similarity: bool = False) -> FrameOffset:
    """The :class:`FrameOffset` of *source* relative to *reference* from the source of every control row.

    Parameters
    ----------
    problem : BundleProblem
    point_source : sequence of str, (k,)
        Source name of every control row (``problem.constraint_point_index`` order).
    source, reference : str

    Raises
    ------
    AdditionalParameterError
        Either source has no control point (names the sources present).
    """
    src = np.asarray([str(s) for s in point_source], dtype=object)
    present = sorted(set(src.tolist()))
    for name in (source, reference):
        if name not in present:
            raise AdditionalParameterError(f"frame offset {source}:{reference}: no control point from source "
                                           f"{name!r} in the adjustment (control sources: "
                                           f"{', '.join(present) or 'none'}); use a control set holding both")
    if source == reference:
        raise AdditionalParameterError(f"frame offset {source}:{reference}: source and reference must differ")
    return FrameOffset(source, reference, np.flatnonzero(src == source), similarity)


class _BoundFrame:
    """A frame offset bound to a problem: 3 or 7 parameters acting on the source's control rows."""

    group_kind = "frame"

    def __init__(self, spec: FrameOffset, problem):
        if spec.rows.max() >= len(problem.constraint_point_index):
            raise AdditionalParameterError(f"frame offset {spec.source}:{spec.reference}: control row "
                                           f"{int(spec.rows.max())} out of range")
        self.spec = spec
        self.rows = spec.rows
        x = np.asarray(problem.constraint_enh_m)[self.rows]
        self.dX = x - x.mean(axis=0)
        comps = _SHIFT + (_SIMILARITY if spec.similarity else ())
        self.m = self.n = len(comps)
        tag = f"frame.{spec.source}:{spec.reference}"
        self.names = [f"{tag}.{c}" for c in comps]
        self.units = ["m"] * 3 + (["ppm", "urad", "urad", "urad"] if spec.similarity else [])
        self.groups = [f"frame offset {spec.source}:{spec.reference}"] * self.m
        self.prior_sd = np.full(self.m, np.inf)

    def _design(self) -> np.ndarray:
        """d(X_ref)/d(theta), (r, 3, m)."""
        r = len(self.rows)
        D = np.zeros((r, 3, self.m))
        D[:, :, :3] = np.eye(3)
        if self.m == 7:
            dx, dy, dz = (self.dX[:, i] * 1e-6 for i in range(3))
            D[:, :, 3] = self.dX * 1e-6
            zero = np.zeros(r)
            # d(eps x dX)/d eps_E, eps_N, eps_h
            D[:, :, 4] = np.stack([zero, -dz, dy], axis=1)
            D[:, :, 5] = np.stack([dz, zero, -dx], axis=1)
            D[:, :, 6] = np.stack([-dy, dx, zero], axis=1)
        return D

    def apply(self, theta: np.ndarray, fields: dict[str, Any]) -> None:
        c = np.array(fields["constraint_enh_m"], dtype=float)
        c[self.rows] += np.einsum("rij,j->ri", self._design(), theta)
        fields["constraint_enh_m"] = c

    def jacobians(self, theta: np.ndarray, state):
        cols = np.broadcast_to(np.arange(self.m), (len(self.rows), self.m))
        return [("con", self.rows, -self._design(), cols)]
