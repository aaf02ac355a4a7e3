"""Coordinate reference systems for LiDAR tiles and query points.

A tile's CRS comes from its LAS WKT or GeoTIFF-key VLRs when present; files
without one (the AHN3 samples, most ASCII strips) take the CRS the user or the
survey gives (``[lidar] crs`` in survey.toml, ``--crs`` on the command line).
Two CRSs are *compatible* when their horizontal parts are the same and, if both
have a vertical part, those are the same too: a tile labelled EPSG:28992 (RD
New) and one labelled EPSG:7415 (RD New + NAP) may be merged, EPSG:29192
(SAD69 / UTM 22S) and EPSG:31982 (SIRGAS 2000 / UTM 22S) may not.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import Any

import numpy as np
import pyproj
from pyproj.exceptions import CRSError as _PyprojCRSError

from ..errors import CRSError

__all__ = ["resolve_crs", "crs_compatible", "common_crs", "transform_points", "crs_label", "horizontal_unit",
           "units_are_metres", "require_metres", "check_area_of_use", "geojson_crs_member",
           "add_las_crs"]


def resolve_crs(value: Any, *, what: str = "CRS") -> pyproj.CRS | None:
    """Turn a user value (``"EPSG:7415"``, ``28992``, WKT, a ``pyproj.CRS``) into a CRS.

    ``None`` and ``""`` give ``None``.

    Raises
    ------
    CRSError
        The string is not a CRS pyproj knows; the message names it.

    Examples
    --------
    >>> resolve_crs("EPSG:28992").to_epsg()
    28992
    >>> resolve_crs("EPSG:999999")
    Traceback (most recent call last):
    ...
    lidarcat.errors.CRSError: unknown CRS 'EPSG:999999' ...
    """
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    if isinstance(value, pyproj.CRS):
        return value
    try:
        return _cached_crs(value if not isinstance(value, str) else value.strip())
    except (_PyprojCRSError, TypeError, ValueError) as ex:
        raise CRSError(f"unknown {what} {value!r} (pyproj: {str(ex).splitlines()[0]}); "
                       "give an EPSG code such as 'EPSG:28992', a PROJ string or WKT") from ex


@functools.lru_cache(maxsize=64)
def _cached_crs(value: Any) -> pyproj.CRS:
    return pyproj.CRS.from_user_input(value)


def _parts(crs: pyproj.CRS) -> tuple[pyproj.CRS | None, pyproj.CRS | None]:
    """(horizontal, vertical) components of *crs*."""
    if crs.is_compound:
        horiz = vert = None
        for sub in crs.sub_crs_list:
            if sub.is_vertical:
                vert = sub
            elif horiz is None:
                horiz = sub
        return horiz, vert
    if crs.is_vertical:
        return None, crs
    return crs, None


def crs_compatible(a: pyproj.CRS | None, b: pyproj.CRS | None) -> bool:
    """True if points in *a* and *b* may be merged without transformation.

    ``None`` (unknown) is compatible only with ``None``.

    >>> crs_compatible(resolve_crs("EPSG:7415"), resolve_crs("EPSG:28992"))
    True
    >>> crs_compatible(resolve_crs("EPSG:29192"), resolve_crs("EPSG:31982"))
    False
    """
    if a is None or b is None:
        return a is None and b is None
    if a is b or a == b:
        return True
    ha, va = _parts(a)
    hb, vb = _parts(b)
    if (ha is None) != (hb is None):
        return False
    if ha is not None and not ha.equals(hb, ignore_axis_order=True):
        return False
    if va is not None and vb is not None and not va.equals(vb, ignore_axis_order=True):
        return False
    return True


def _richer(a: pyproj.CRS, b: pyproj.CRS) -> pyproj.CRS:
    # prefer the CRS that also says the height system
    return b if (b.is_compound and not a.is_compound) else a


def common_crs(labelled: Iterable[tuple[str, pyproj.CRS | None]]) -> pyproj.CRS | None:
    """The CRS shared by every ``(label, crs)`` pair (a compound one if any is).

    Raises
    ------
    CRSError
        Two entries differ, or some have a CRS and some have none; the message
        names both.
    """
    result: pyproj.CRS | None = None
    first_label = ""
    seen = False
    for label, crs in labelled:
        if not seen:
            result, first_label, seen = crs, label, True
            continue
        if not crs_compatible(result, crs):
            raise CRSError(f"cannot mix coordinate systems: {first_label} is {crs_label(result)} "
                           f"but {label} is {crs_label(crs)}; transform the tiles first or give "
                           "--crs only for tiles that carry none")
        if result is not None and crs is not None:
            result = _richer(result, crs)
    return result


def crs_label(crs: pyproj.CRS | None) -> str:
    """Short human label: ``'EPSG:7415 (Amersfoort / RD New + NAP height)'`` or ``'no CRS'``."""
    if crs is None:
        return "no CRS"
    code = crs.to_epsg(min_confidence=90)
    return f"EPSG:{code} ({crs.name})" if code else repr(crs.name)


def geojson_crs_member(crs: Any) -> dict[str, Any] | None:
    """The GeoJSON (2008) ``crs`` member naming *crs* (anything :func:`resolve_crs` takes),
    which GDAL, QGIS and GeoPandas read: ``{"type": "name", "properties": {"name":
    "urn:ogc:def:crs:EPSG::29192"}}``, the WKT when the CRS has no EPSG code; None without a CRS.

    >>> geojson_crs_member("EPSG:29192")["properties"]["name"]
    'urn:ogc:def:crs:EPSG::29192'
    """
    c = resolve_crs(crs)
    if c is None:
        return None
    code = c.to_epsg(min_confidence=90)
    return {"type": "name", "properties": {"name": f"urn:ogc:def:crs:EPSG::{code}" if code else c.to_wkt()}}


def add_las_crs(header: Any, crs: Any) -> bool:
    """Give a laspy header that carries no readable CRS the CRS *crs*; True when added.

    A header with a readable CRS record keeps it (the file's CRS wins, as on
    reading); without *crs* nothing changes.  laspy writes GeoTIFF keys for
    LAS 1.0-1.3 and point formats 0-5 (EPSG:7415 as keys 28992 + 5709, read
    back as the compound code) and a WKT record for point formats 6-10; a CRS
    GeoTIFF keys cannot express (no EPSG code) goes into a WKT record there too.
    """
    c = resolve_crs(crs)
    if c is None:
        return False
    try:
        if header.parse_crs() is not None:
            return False
    except Exception:  # an unreadable record: replaced by the given CRS, as reading ignores it
        pass
    try:
        header.add_crs(c)
    except Exception:  # GeoTIFF keys cannot hold this CRS (laspy: "custom CRS"): a WKT record
        from laspy.vlrs.known import WktCoordinateSystemVlr

        header.vlrs.append(WktCoordinateSystemVlr(c.to_wkt()))
    return True


@functools.lru_cache(maxsize=32)
def _transformer(src_wkt: str, dst_wkt: str) -> pyproj.Transformer:
    return pyproj.Transformer.from_crs(pyproj.CRS.from_wkt(src_wkt), pyproj.CRS.from_wkt(dst_wkt),
                                       always_xy=True)


def transform_points(xy: Any, from_crs: Any, to_crs: Any) -> np.ndarray:
    """Transform points between coordinate systems (pyproj, ``always_xy``).

    Parameters
    ----------
    xy : array_like, shape (2,), (3,), (N, 2) or (N, 3)
        Easting, northing [, height] in metres (degrees for geographic CRSs:
        longitude, latitude).
    from_crs, to_crs : CRS-like
        Anything :func:`resolve_crs` accepts.

    Returns
    -------
    ndarray
        Same shape as *xy*, float64.

    Raises
    ------
    CRSError
        A CRS is unknown or missing, or the transformation fails (point outside
        the area of use).

    Examples
    --------
    >>> e, n = transform_points([677757.8, 7183482.0], "EPSG:29192", "EPSG:31982")
    >>> round(e - 677757.8), round(n - 7183482.0)  # SAD69 -> SIRGAS 2000 shift, m
    (-50, -44)
    """
    src = resolve_crs(from_crs, what="source CRS")
    dst = resolve_crs(to_crs, what="target CRS")
    if src is None or dst is None:
        raise CRSError("transform_points needs both a source and a target CRS "
                       f"(got {crs_label(src)} -> {crs_label(dst)})")
    pts = np.array(xy, dtype=np.float64)
    single = pts.ndim == 1
    pts = np.atleast_2d(pts)
    if pts.shape[1] not in (2, 3):
        raise ValueError(f"xy must have 2 or 3 columns, got shape {pts.shape}")
    if src == dst:
        return pts[0] if single else pts
    tr = _transformer(src.to_wkt(), dst.to_wkt())
    try:
        if pts.shape[1] == 3:
            out = np.column_stack(tr.transform(pts[:, 0], pts[:, 1], pts[:, 2], errcheck=True))
        else:
            out = np.column_stack(tr.transform(pts[:, 0], pts[:, 1], errcheck=True))
    except pyproj.exceptions.ProjError as ex:
        raise CRSError(f"cannot transform points from {crs_label(src)} to {crs_label(dst)}: {ex}") from ex
    return out[0] if single else out


# --------------------------------------------------------------------------- units and area of use
def horizontal_unit(crs: pyproj.CRS | None) -> tuple[str, float]:
    """Name and size in metres of the horizontal unit of *crs* (``("metre", 1.0)`` when None).

    Geographic CRSs give ``("degree", nan)``: a degree has no fixed length in metres.

    >>> horizontal_unit(resolve_crs("EPSG:2236"))   # NAD83 / Florida East (ftUS)
    ('US survey foot', 0.30480060960121924)
    >>> horizontal_unit(resolve_crs("EPSG:4326"))
    ('degree', nan)
    """
    if crs is None:
        return "metre", 1.0
    horiz, _ = _parts(crs)
    if horiz is None:
        return "metre", 1.0
    if horiz.is_geographic:
        return "degree", float("nan")
    axes = horiz.axis_info
    if not axes:
        return "metre", 1.0
    return axes[0].unit_name, float(axes[0].unit_conversion_factor)


def units_are_metres(crs: pyproj.CRS | None) -> bool:
    """True when the horizontal coordinates of *crs* are metres (None: assumed metres)."""
    return horizontal_unit(crs)[1] == 1.0


def require_metres(crs: pyproj.CRS | None, what: str, where: str = "") -> None:
    """Refuse a CRS whose horizontal unit is not the metre for a method that needs metres.

    Raises
    ------
    CRSError
        Naming *where* (a file), the CRS, its unit and *what* needs metres.
    """
    name, factor = horizontal_unit(crs)
    if factor == 1.0:
        return
    prefix = f"{where}: " if where else ""
    raise CRSError(f"{prefix}{what} needs coordinates in metres but {crs_label(crs)} uses the unit {name!r}"
                   + ("" if factor != factor else f" (1 {name} = {factor:.10g} m)")
                   + "; reproject the data to a projected CRS in metres (e.g. the UTM zone) first")


def check_area_of_use(crs: pyproj.CRS | None, en: Any, where: str = "", *, margin_deg: float = 1.0,
                      ids: Any = None) -> None:
    """Refuse plan coordinates that lie far outside the area of use of *crs*.

    The points are transformed to longitude/latitude and compared with the
    CRS's area of use widened by *margin_deg* degrees (projections stay usable
    a little beyond their official area).  A CRS with no area of use is not
    checked.

    Parameters
    ----------
    crs : pyproj.CRS or None
    en : array_like, shape (N, 2)
        E, N in the units of *crs* (lon, lat for a geographic CRS).
    where : str
        Prefix of the message (file, line, point).
    ids : sequence, optional
        Names of the points, for the message.

    Raises
    ------
    CRSError
        The first point outside, with its coordinates and the area of use.
    """
    if crs is None:
        return
    aou = crs.area_of_use
    pts = np.atleast_2d(np.asarray(en, dtype=np.float64))[:, :2]
    if aou is None or len(pts) == 0:
        return
    horiz, _ = _parts(crs)
    horiz = horiz or crs
    prefix = f"{where}: " if where else ""
    if horiz.is_geographic:
        lon, lat = pts[:, 0], pts[:, 1]
    else:
        geo = horiz.geodetic_crs
        tr = _transformer(horiz.to_wkt(), geo.to_wkt())
        with np.errstate(all="ignore"):
            lon, lat = tr.transform(pts[:, 0], pts[:, 1])
        lon, lat = np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
    m = margin_deg
    west, east = aou.west - m, aou.east + m
    if aou.west > aou.east:  # crosses the antimeridian
        lon_ok = (lon >= west) | (lon <= east)
    else:
        lon_ok = (lon >= west) & (lon <= east)
    ok = np.isfinite(lon) & np.isfinite(lat) & lon_ok & (lat >= aou.south - m) & (lat <= aou.north + m)
    if ok.all():
        return
    i = int(np.flatnonzero(~ok)[0])
    geo_txt = (f"lon {lon[i]:.4f}, lat {lat[i]:.4f}" if np.isfinite(lon[i]) and np.isfinite(lat[i])
               else "not a place on Earth")
    who = f"point {str(ids[i])!r}: " if ids is not None else ""
    raise CRSError(f"{prefix}{who}coordinates {pts[i, 0]:.3f}, {pts[i, 1]:.3f} ({geo_txt}) lie outside the "
                   f"area of use of {crs_label(crs)} ({aou.name[:60]}: lon {aou.west:g}..{aou.east:g}, "
                   f"lat {aou.south:g}..{aou.north:g}); wrong CRS, or easting/northing swapped?")
