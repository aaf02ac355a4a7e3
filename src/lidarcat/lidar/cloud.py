"""The :class:`PointCloud` value type: coordinates, named attributes and a CRS.

Coordinates are an (N, 3) float64 array of easting, northing and height in
metres (E, N, h), in the cloud's :attr:`PointCloud.crs` (a :class:`pyproj.CRS`,
or ``None`` when neither the file nor the user said).  Attributes are named
1-D arrays of length N; the standard names and their dtypes are in
:data:`STANDARD_ATTRIBUTES`.
"""

from __future__ import annotations

import logging
import types
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .._util.frozen import frozen_array

__all__ = ["PointCloud", "Bounds", "STANDARD_ATTRIBUTES"]

log = logging.getLogger(__name__)

#: standard attribute name -> dtype used by the readers and writers
STANDARD_ATTRIBUTES: dict[str, np.dtype] = {
    "intensity": np.dtype(np.uint16),
    "return_number": np.dtype(np.uint8),
    "number_of_returns": np.dtype(np.uint8),
    "classification": np.dtype(np.uint8),
    "point_source_id": np.dtype(np.uint16),
    "gps_time": np.dtype(np.float64),
}


class Bounds(NamedTuple):
    """Axis-aligned bounds in metres; the first four follow ``(xmin, ymin, xmax, ymax)``."""

    xmin: float
    ymin: float
    xmax: float
    ymax: float
    zmin: float
    zmax: float

    @property
    def area_m2(self) -> float:
        """Plan area of the bounding box, m^2."""
        return max(self.xmax - self.xmin, 0.0) * max(self.ymax - self.ymin, 0.0)

    def intersects_box(self, xmin: float, ymin: float, xmax: float, ymax: float) -> bool:
        """True if the plan box overlaps these bounds (edges count as overlap)."""
        return not (xmax < self.xmin or xmin > self.xmax or ymax < self.ymin or ymin > self.ymax)

    @classmethod
    def from_minmax(cls, lo: Any, hi: Any) -> Bounds:
        """From the (3,) minima and maxima of E, N, h; all NaN when *lo* is None (no points)."""
        if lo is None:
            return cls(*([float("nan")] * 6))
        return cls(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), float(lo[2]), float(hi[2]))

    @classmethod
    def union(cls, bounds: Iterable[Iterable[float]]) -> Bounds:
        """Smallest bounds holding every one of *bounds* (each in field order); NaN when none.

        >>> Bounds.union([(0, 0, 1, 1, 5, 6), (2, -1, 3, 0, 4, 5)])
        Bounds(xmin=0.0, ymin=-1.0, xmax=3.0, ymax=1.0, zmin=4.0, zmax=6.0)
        """
        bs = np.array([list(b) for b in bounds], dtype=np.float64).reshape(-1, 6)
        if len(bs) == 0:
            return cls.from_minmax(None, None)
        return cls.from_minmax(bs[:, [0, 1, 4]].min(axis=0), bs[:, [2, 3, 5]].max(axis=0))


def _attribute(name: str, values: Any, n: int) -> np.ndarray:
    """*values* as an (n,) array of the attribute's standard dtype (float intensity allowed)."""
    arr = np.asarray(values)
    want = STANDARD_ATTRIBUTES.get(name)
    if want is not None and arr.dtype != want and not (name == "intensity" and arr.dtype.kind == "f"):
        arr = arr.astype(want)
    if arr.shape != (n,):
        raise ValueError(f"attribute {name!r} has shape {arr.shape}, expected ({n},)")
    return arr


@dataclass(frozen=True, eq=False)
class PointCloud:
    """LiDAR points: (N, 3) E, N, h in metres plus named per-point attributes.

    Parameters
    ----------
    xyz : array_like, shape (N, 3)
        Easting, northing, height in metres (float64).
    attributes : mapping of str to array_like, each shape (N,)
        Per-point attributes such as ``intensity``, ``return_number``,
        ``number_of_returns``, ``classification``, ``point_source_id``,
        ``gps_time`` (see :data:`STANDARD_ATTRIBUTES`).
    crs : pyproj.CRS, CRS-like or None
        Coordinate reference system of *xyz* (a string such as
        ``"EPSG:7415"`` is resolved); ``None`` when unknown.

    Raises
    ------
    ValueError
        *xyz* is not (N, 3) or an attribute has the wrong length.
    CRSError
        *crs* is not a CRS pyproj knows.

    Examples
    --------
    >>> pc = PointCloud(np.array([[0.0, 0.0, 1.0], [2.0, 1.0, 3.0]]), {"intensity": [10, 20]})
    >>> len(pc), pc.bounds.xmax, pc.attributes["intensity"].tolist()
    (2, 2.0, [10, 20])
    >>> len(pc.select(pc.z > 2.0))
    1
    """

    xyz: np.ndarray
    attributes: Mapping[str, np.ndarray] = field(default_factory=dict)
    crs: Any = None

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz, dtype=np.float64)
        if xyz.ndim == 1 and xyz.size == 0:
            xyz = xyz.reshape(0, 3)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
        attrs = {name: frozen_array(_attribute(name, values, len(xyz)), dtype=None)
                 for name, values in dict(self.attributes).items()}
        object.__setattr__(self, "xyz", frozen_array(xyz))
        object.__setattr__(self, "attributes", types.MappingProxyType(attrs))
        if self.crs is not None:
            from .crs import resolve_crs

            object.__setattr__(self, "crs", resolve_crs(self.crs))

    @classmethod
    def _owned(cls, xyz: np.ndarray, attributes: dict[str, np.ndarray], crs: Any) -> PointCloud:
        """Wrap freshly made arrays without copying them (internal: callers give up the arrays)."""
        xyz = np.ascontiguousarray(xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
        attrs = {}
        for name, values in attributes.items():
            arr = _attribute(name, values, len(xyz))
            if arr.base is not None or arr.flags.writeable is False:
                arr = arr.copy()  # a view of someone else's buffer: take our own copy
            arr.setflags(write=False)
            attrs[name] = arr
        if xyz.base is not None:
            xyz = xyz.copy()
        xyz.setflags(write=False)
        obj = object.__new__(cls)
        object.__setattr__(obj, "xyz", xyz)
        object.__setattr__(obj, "attributes", types.MappingProxyType(attrs))
        object.__setattr__(obj, "crs", crs)
        return obj

    # -- sizes and views -------------------------------------------------
    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    def __repr__(self) -> str:
        crs = self.crs.name if self.crs is not None else "no CRS"
        return f"PointCloud({len(self)} points, attributes={list(self.attributes)}, crs={crs!r})"

    @property
    def x(self) -> np.ndarray:
        """Easting, m, shape (N,)."""
        return self.xyz[:, 0]

    @property
    def y(self) -> np.ndarray:
        """Northing, m, shape (N,)."""
        return self.xyz[:, 1]

    @property
    def z(self) -> np.ndarray:
        """Height, m, shape (N,)."""
        return self.xyz[:, 2]

    @property
    def bounds(self) -> Bounds:
        """:class:`Bounds` of the points (NaN for an empty cloud)."""
        if len(self) == 0:
            return Bounds.from_minmax(None, None)
        return Bounds.from_minmax(self.xyz.min(axis=0), self.xyz.max(axis=0))

    def has(self, name: str) -> bool:
        """True if attribute *name* is present."""
        return name in self.attributes

    def first_returns(self) -> np.ndarray:
        """Boolean mask of first (or only) returns; all True without ``return_number``."""
        if "return_number" not in self.attributes:
            return np.ones(len(self), dtype=bool)
        return self.attributes["return_number"] <= 1

    def last_returns(self) -> np.ndarray:
        """Boolean mask of last (or only) returns; all True without return information."""
        a = self.attributes
        if "return_number" not in a or "number_of_returns" not in a:
            return np.ones(len(self), dtype=bool)
        return a["return_number"] >= a["number_of_returns"]

    def select(self, mask: Any) -> PointCloud:
        """A new cloud holding the points selected by a boolean mask, an index array or a slice."""
        if not isinstance(mask, slice):
            mask = np.asarray(mask)
            if mask.dtype == bool and mask.shape != (len(self),):
                raise ValueError(f"mask has shape {mask.shape}, expected ({len(self)},)")
        return PointCloud._owned(self.xyz[mask], {k: v[mask] for k, v in self.attributes.items()}, self.crs)

    def with_crs(self, crs: Any) -> PointCloud:
        """The same points labelled with *crs* (no transformation; a string such as
        ``"EPSG:7415"`` is resolved).

        Raises
        ------
        CRSError
            *crs* is not a CRS pyproj knows.
        """
        from .crs import resolve_crs

        obj = object.__new__(PointCloud)
        object.__setattr__(obj, "xyz", self.xyz)
        object.__setattr__(obj, "attributes", self.attributes)
        object.__setattr__(obj, "crs", resolve_crs(crs))
        return obj

    @classmethod
    def empty(cls, attributes: Iterable[str] = (), crs: Any = None) -> PointCloud:
        """A cloud with no points and the given (standard) attribute names."""
        return cls(np.empty((0, 3)), {k: np.empty(0, STANDARD_ATTRIBUTES.get(k, np.float64))
                                      for k in attributes}, crs)

    @classmethod
    def concat(cls, clouds: Iterable[PointCloud]) -> PointCloud:
        """Concatenate clouds in order.

        Attributes present in every cloud are kept (others are dropped, with a
        debug log).  The CRS of the result is the common CRS.

        Raises
        ------
        CRSError
            Two clouds carry different coordinate reference systems.
        """
        clouds = list(clouds)
        if not clouds:
            return cls.empty()
        from .crs import common_crs

        crs = common_crs([(f"cloud {i}", c.crs) for i, c in enumerate(clouds)])
        if len(clouds) == 1:
            return clouds[0] if clouds[0].crs is crs else clouds[0].with_crs(crs)
        names = [k for k in clouds[0].attributes if all(k in c.attributes for c in clouds[1:])]
        dropped = {k for c in clouds for k in c.attributes} - set(names)
        if dropped:
            log.debug("concat drops attributes not present in every cloud: %s", sorted(dropped))
        xyz = np.concatenate([c.xyz for c in clouds], axis=0)
        attrs = {k: np.concatenate([c.attributes[k] for c in clouds]) for k in names}
        return cls._owned(xyz, attrs, crs)

    def to_dict(self) -> dict[str, Any]:
        """Summary (not the points) for JSON output."""
        b = self.bounds
        return {"points": len(self), "bounds": b._asdict(), "attributes": list(self.attributes),
                "crs": None if self.crs is None else self.crs.to_string()}
