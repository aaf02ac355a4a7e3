r"""GNSS/IMU text files: photo positions and attitudes as approximations or weighted constraints.

Generic layout (:func:`read_gnss`)
----------------------------------
A header line naming the columns, then one photo per line (separated by commas,
semicolons, tabs or blanks; ``#`` lines are comments)::

    photo, E, N, h, omega, phi, kappa, sd_E, sd_N, sd_h, sd_omega, sd_phi, sd_kappa
    photo  E  N  h  roll  pitch  yaw

Position columns: ``E``/``X``/``easting``, ``N``/``Y``/``northing``,
``h``/``Z``/``height``/``altitude``; attitude either ``omega, phi, kappa``
(lidarcat's convention, :mod:`lidarcat.interop.rotations`) or ``roll, pitch, yaw``
(aircraft body angles, converted with :func:`~lidarcat.interop.rotations.ypr_to_opk`:
the Pix4D formula for a nadir camera, no boresight, no lever arm, no meridian
convergence -- say so in the sds); sds optional, per column (``sd_<name>``).
Angles in degrees (``angle_unit``).  Coordinates in a geographic CRS
(lon/lat) are projected to the target ``crs``.

ODM's ``geo.txt`` is read by :func:`lidarcat.interop.odm.read_geo_txt`;
kapture's ``records_gnss.txt`` (timestamp, device, lon, lat, alt, utc, dop) by
:func:`read_kapture_gnss`.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import FormatError
from ._text import TextLines, format_error
from .merge import Orientations
from .opk import ANGLE_UNITS
from .rotations import ypr_to_opk

__all__ = ["read_gnss", "read_kapture_gnss"]

log = logging.getLogger(__name__)

_POS = {"E": ("e", "x", "easting", "east", "x0", "lon", "longitude"),
        "N": ("n", "y", "northing", "north", "y0", "lat", "latitude"),
        "h": ("h", "z", "height", "altitude", "alt", "z0")}
_OPK = ("omega", "phi", "kappa")
#: sane range of each position column (lidarcat._util.values.VALUE_RANGES)
_KIND = {"E": "coordinate_m", "N": "coordinate_m", "h": "height_m"}
_YPR = ("roll", "pitch", "yaw")


def _project(e: np.ndarray, n: np.ndarray, crs_in: str, crs: str | None, path: Path):
    from pyproj import CRS, Transformer

    src = CRS.from_user_input(crs_in)
    if crs is None:
        if src.is_geographic:
            raise FormatError(f"{path}: coordinates are geographic ({src.name}); give a projected "
                              f"target CRS (crs=, --crs EPSG:nnnn)")
        return e, n, crs_in
    if CRS.from_user_input(crs) == src:
        return e, n, crs
    ee, nn = Transformer.from_crs(src, CRS.from_user_input(crs), always_xy=True).transform(e, n)
    return np.asarray(ee), np.asarray(nn), crs


def read_gnss(path: str | Path, *, file_crs: str, crs: str | None = None, height_system: str = "unspecified",
              angle_unit: str = "deg") -> Orientations:
    """Read a GNSS/IMU text file with a header line (see the module docstring).

    Parameters
    ----------
    path : path
    file_crs : str
        CRS of the coordinates in the file (pyproj string; lon/lat allowed).
    crs : str, optional
        Target projected CRS (default: *file_crs*, which must then be projected).
    height_system : str
        ``ellipsoidal`` (GNSS) or ``orthometric``: what the heights are.
    angle_unit : {"deg", "rad", "gon"}

    Returns
    -------
    Orientations
        ``source`` names the attitude convention used (omega/phi/kappa as given,
        or roll/pitch/yaw converted).

    Raises
    ------
    FormatError
        Missing position column, both or half an attitude triple, a non-numeric
        cell, a non-positive sd, a duplicate photo (``FILE:LINE: field``).
    """
    if angle_unit not in ANGLE_UNITS:
        raise FormatError(f"angle unit {angle_unit!r} is not one of {', '.join(ANGLE_UNITS)}")
    tl = TextLines(path, comment="#")
    rows = list(tl.rows())
    if not rows:
        raise FormatError(f"{tl.path}: empty file, expected a header line (photo, E, N, h, ...)")
    head = rows[0]
    low = [h.lower().removesuffix("_deg").removesuffix("_m") for h in head.fields]
    if low[0] not in ("photo", "image", "name", "imagename", "label", "filename"):
        raise format_error(tl.path, head.line, head.fields[0], "the first column must be the photo "
                           "(photo, image, name)")
    col: dict[str, int] = {}
    for key, names in _POS.items():
        hit = [i for i, h in enumerate(low) if h in names]
        if not hit:
            raise format_error(tl.path, head.line, key, f"no position column for {key} "
                               f"(header {' '.join(head.fields)!r})")
        col[key] = hit[0]
    for name in _OPK + _YPR:
        if name in low:
            col[name] = low.index(name)
    has_opk = [n in col for n in _OPK]
    has_ypr = [n in col for n in _YPR]
    for names, has in ((_OPK, has_opk), (_YPR, has_ypr)):
        if any(has) and not all(has):
            miss = names[has.index(False)]
            raise format_error(tl.path, head.line, miss, f"missing: {', '.join(names)} come together")
    if all(has_opk) and all(has_ypr):
        raise format_error(tl.path, head.line, "roll", "give omega/phi/kappa or roll/pitch/yaw, not both")
    sds = {k: low.index(f"sd_{k.lower()}") for k in list(_POS) + list(_OPK + _YPR) if f"sd_{k.lower()}" in low}
    unit = ANGLE_UNITS[angle_unit]
    photo, eo, sd, lines = [], [], [], []
    seen: dict[str, int] = {}
    for r in rows[1:]:
        if len(r.fields) != len(head.fields):
            raise r.error(None, f"{len(r.fields)} fields, expected {len(head.fields)} ({' '.join(head.fields)})")
        name = r.fields[0]
        if name in seen:
            raise r.error(head.fields[0], f"photo {name!r} already on line {seen[name]}")
        seen[name] = r.line
        v = np.full(6, np.nan)
        s = np.full(6, np.nan)
        v[:3] = [r.number(col[k], head.fields[col[k]], _KIND[k]) for k in _POS]
        names = _OPK if all(has_opk) else _YPR if all(has_ypr) else ()
        if names:
            a = np.array([r.angle(col[k], head.fields[col[k]], unit) for k in names])
            v[3:] = a if names == _OPK else ypr_to_opk(a[::-1])
        for k, i in sds.items():
            j = list(_POS).index(k) if k in _POS else 3 + (_OPK.index(k) if k in _OPK else _YPR.index(k))
            s[j] = (r.sd(i, head.fields[i], "m") if k in _POS
                    else np.radians(r.sd(i, head.fields[i], "deg", unit * 180 / np.pi)))
        if all(has_ypr) and np.isfinite(s[3:]).any():
            s[3:] = np.nanmax(s[3:])  # roll/pitch/yaw sds mix into omega/phi/kappa: keep the largest
        photo.append(name)
        eo.append(v)
        sd.append(s)
        lines.append(r.line)
    if not photo:
        raise FormatError(f"{tl.path}: no photo after the header line")
    eo_a = np.array(eo)
    e, n, crs_out = _project(eo_a[:, 0], eo_a[:, 1], file_crs, crs, tl.path)
    eo_a[:, 0], eo_a[:, 1] = e, n
    conv = ("omega/phi/kappa as given" if all(has_opk) else
            "roll/pitch/yaw -> omega/phi/kappa by the Pix4D nadir-camera formula (no boresight, no "
            "meridian convergence)" if all(has_ypr) else "positions only")
    return Orientations(np.array(photo, dtype=str), eo_a, np.array(sd), crs_out, height_system,
                        f"{tl.path} (GNSS/IMU, {file_crs}, {conv}, angles in {angle_unit})",
                        line=np.array(lines))


def read_kapture_gnss(path: str | Path, *, crs: str | None = None,
                      height_system: str = "ellipsoidal") -> Orientations:
    """kapture ``records_gnss.txt`` (``timestamp, device_id, x, y, z, utc, dop``; EPSG:4326 lon/lat).

    Photos are named by timestamp (kapture links them to images through
    ``records_camera.txt``); sd of E, N, h = ``dop`` (m, a rough stand-in).

    Raises
    ------
    FormatError
        A line with fewer than 7 fields or a non-numeric value (``FILE:LINE: field``).
    """
    tl = TextLines(path, comment="#")
    names = ("timestamp", "device_id", "x", "y", "z", "utc", "dop")
    photo, eo, sd, lines = [], [], [], []
    for r in tl.rows():
        r.need(7, names)
        v = np.full(6, np.nan)
        v[:3] = [r.number(k, names[k], kind) for k, kind in ((2, "coordinate_m"), (3, "coordinate_m"),
                                                               (4, "height_m"))]
        dop = r.sd(6, "dop", "m")
        photo.append(r.fields[0])
        eo.append(v)
        sd.append([dop, dop, dop, np.nan, np.nan, np.nan])
        lines.append(r.line)
    if not photo:
        raise FormatError(f"{tl.path}: no record")
    eo_a = np.array(eo)
    e, n, crs_out = _project(eo_a[:, 0], eo_a[:, 1], "EPSG:4326", crs, tl.path)
    eo_a[:, 0], eo_a[:, 1] = e, n
    return Orientations(np.array(photo, dtype=str), eo_a, np.array(sd), crs_out, height_system,
                        f"{tl.path} (kapture GNSS records, EPSG:4326)", line=np.array(lines))
