r"""EXIF tags of a photo: focal length, sensor pixel size, GNSS position and image direction.

Read with Pillow (``Image.getexif()``: IFD0, the Exif IFD ``0x8769`` and the GPS IFD ``0x8825``)
from the header only, nothing decoded.  The tags used (EXIF 2.32):

=================================  ======  =======================================================
tag                                id      use
=================================  ======  =======================================================
Make, Model                        0x010F  camera name (IFD0)
FocalLength                        0x920A  focal length f, mm
FocalLengthIn35mmFilm              0xA405  f35: f of a 36 x 24 mm frame with the same field of view
FocalPlaneX/YResolution, Unit      0xA20E  pixels per unit on the sensor (unit 2 inch, 3 cm, 4 mm)
GPSLatitude(Ref), GPSLongitude     0x0002  degrees, minutes, seconds; ``S`` / ``W`` negative
GPSAltitude, GPSAltitudeRef        0x0006  metres above (ref 0) or below (ref 1) sea level
GPSImgDirection(Ref)               0x0011  direction of the image's top, degrees clockwise from
                                           true (``T``) or magnetic (``M``) north
=================================  ======  =======================================================

**Pixel size.**  From the focal-plane resolution ``r`` (pixels per unit ``u`` mm): ``p = u / r``.
Without it, from the 35 mm equivalent: the field of view over the diagonal is the same, so the
sensor diagonal is ``d = 43.267 mm * f / f35`` (43.267 mm = the diagonal of 36 x 24 mm) and
``p = d / sqrt(W^2 + H^2)`` for a photo of W x H pixels with square pixels.  Both are approximate
(f35 is rounded to a whole mm, and the sensor area a camera maps may differ from its nominal
size): a camera built from them needs self-calibration.

**Position.**  Latitude and longitude are on WGS 84 (the EXIF standard's ``GPSMapDatum`` is almost
always WGS-84); :func:`exif_orientations` projects them with pyproj into the survey CRS.  The
altitude is kept as written (the standard says "above sea level"; many drones write ellipsoidal
heights: say which in ``[survey] height_system``).

**Attitude.**  A nadir photo whose top points to azimuth ``a`` (GPSImgDirection) has
``omega = phi = 0`` and ``kappa = -a``: with ``M = R3(kappa)``, the image y axis (the top) is the
second row of M, ``(-sin kappa, cos kappa) = (sin a, cos a)`` in (E, N) -- the same as
:func:`lidarcat.interop.rotations.ypr_to_opk` with yaw ``a`` and pitch = roll = 0.  Magnetic
directions are taken as true (declination not applied) and grid convergence is not applied:
approximate values, weighted by generous sds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CRSError, FormatError
from .header import open_image, read_header

__all__ = ["ExifInfo", "read_exif", "exif_orientations", "utm_crs", "DIAGONAL_35MM_MM"]

#: diagonal of the 36 x 24 mm frame that FocalLengthIn35mmFilm refers to, mm
DIAGONAL_35MM_MM = math.hypot(36.0, 24.0)
#: FocalPlaneResolutionUnit -> mm per unit (EXIF: 2 inch, 3 cm; 4 mm and 5 um are common extensions)
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}


@dataclass(frozen=True)
class ExifInfo:
    """The EXIF tags of one photo that lidarcat uses (None where the photo has no such tag).

    Attributes
    ----------
    path : Path
    columns_px, rows_px : int
        Stored image size (from the header).
    has_exif : bool
        The file has EXIF tags at all.
    make, model : str or None
    focal_length_mm : float or None
    focal_length_35mm_mm : float or None
    focal_plane_pixel_mm : float or None
        Pixel size from the focal-plane resolution, mm.
    lon_deg, lat_deg : float or None
        WGS 84 longitude and latitude, degrees (east and north positive).
    alt_m : float or None
        GPSAltitude, m (negative below sea level).
    direction_deg : float or None
        GPSImgDirection, degrees clockwise from north.
    direction_ref : str or None
        ``"T"`` (true) or ``"M"`` (magnetic).
    """

    path: Path
    columns_px: int
    rows_px: int
    has_exif: bool = False
    make: str | None = None
    model: str | None = None
    focal_length_mm: float | None = None
    focal_length_35mm_mm: float | None = None
    focal_plane_pixel_mm: float | None = None
    lon_deg: float | None = None
    lat_deg: float | None = None
    alt_m: float | None = None
    direction_deg: float | None = None
    direction_ref: str | None = None

    @property
    def has_position(self) -> bool:
        """Latitude, longitude and altitude are all given."""
        return None not in (self.lon_deg, self.lat_deg, self.alt_m)

    @property
    def pixel_size_mm(self) -> float | None:
        """Approximate pixel size, mm: the focal-plane resolution, else from the 35 mm equivalent
        (module docstring); None when neither is given."""
        if self.focal_plane_pixel_mm is not None:
            return self.focal_plane_pixel_mm
        if self.focal_length_mm and self.focal_length_35mm_mm:
            diag = DIAGONAL_35MM_MM * self.focal_length_mm / self.focal_length_35mm_mm
            return diag / math.hypot(self.columns_px, self.rows_px)
        return None

    @property
    def camera_name(self) -> str:
        return " ".join(s for s in (self.make, self.model) if s) or "unknown camera"


def _num(v: Any) -> float | None:
    """A finite float of an EXIF rational/number, else None (0/0 rationals are NaN)."""
    try:
        f = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if math.isfinite(f) else None


def _text(v: Any) -> str | None:
    if isinstance(v, bytes):
        v = v.decode("ascii", "replace")
    if v is None:
        return None
    s = str(v).strip("\x00 ").strip()
    return s or None


def _dms(v: Any) -> float | None:
    """Degrees of an EXIF (degrees, minutes, seconds) triple (a single number is degrees)."""
    if isinstance(v, (tuple, list)):
        parts = [_num(x) for x in v]
        if not parts or None in parts:
            return None
        return sum(p / 60.0 ** i for i, p in enumerate(parts[:3]))  # type: ignore[operator]
    return _num(v)


def read_exif(path: str | Path) -> ExifInfo:
    """The EXIF tags of one photo (header only, nothing decoded).

    Parameters
    ----------
    path : path
        A JPEG, PNG or TIFF photo.

    Returns
    -------
    ExifInfo
        ``has_exif`` False and every tag None for a photo without EXIF.

    Raises
    ------
    FormatError
        An unreadable or truncated image (:func:`~lidarcat.photos.header.read_header`), or a GPS
        latitude/longitude out of range (names the file and the tag).
    """
    head = read_header(path)
    path = head.path
    im = open_image(path)
    try:
        if head.format == "PNG" and "exif" not in im.info:
            # Pillow would decode the whole PNG looking for an eXIf chunk after the pixel data; writers put it
            # before (PNG 1.2 extensions: "should appear before IDAT"): none there is no EXIF
            return ExifInfo(path, head.columns_px, head.rows_px)
        ex = im.getexif()
        exif_ifd = ex.get_ifd(0x8769) if ex else {}
        gps = ex.get_ifd(0x8825) if ex else {}
    except Exception as e:  # noqa: BLE001 - Pillow raises many types on a malformed EXIF block
        raise FormatError(f"{path}: malformed EXIF block ({type(e).__name__}: {e})") from None
    finally:
        im.close()
    if not ex and not exif_ifd and not gps:
        return ExifInfo(path, head.columns_px, head.rows_px)
    f = _num(exif_ifd.get(0x920A))
    f35 = _num(exif_ifd.get(0xA405))
    res, unit = _num(exif_ifd.get(0xA20E)), exif_ifd.get(0xA210)
    fp_pixel = _UNIT_MM[int(unit)] / res if res and res > 0 and unit in _UNIT_MM else None
    lat, lon = _dms(gps.get(2)), _dms(gps.get(4))
    if lat is not None and _text(gps.get(1)) in ("S", "s"):
        lat = -lat
    if lon is not None and _text(gps.get(3)) in ("W", "w"):
        lon = -lon
    if lat is not None and not -90.0 <= lat <= 90.0:
        raise FormatError(f"{path}: EXIF GPSLatitude {lat!r} is not a latitude (-90..90 degrees)")
    if lon is not None and not -180.0 <= lon <= 180.0:
        raise FormatError(f"{path}: EXIF GPSLongitude {lon!r} is not a longitude (-180..180 degrees)")
    alt = _num(gps.get(6))
    ref = gps.get(5)
    if alt is not None and (ref in (1, b"\x01") or (isinstance(ref, bytes) and ref[:1] == b"\x01")):
        alt = -alt
    direction = _num(gps.get(17))
    return ExifInfo(path, head.columns_px, head.rows_px, True, _text(ex.get(0x010F)), _text(ex.get(0x0110)),
                    f if f and f > 0 else None, f35 if f35 and f35 > 0 else None, fp_pixel, lon, lat, alt,
                    None if direction is None else direction % 360.0, _text(gps.get(16)))


def utm_crs(lon_deg: float, lat_deg: float) -> str:
    """``EPSG:326zz`` / ``EPSG:327zz``: the WGS 84 / UTM zone of a point (pyproj's database).

    >>> utm_crs(-49.27, -25.43)   # Curitiba
    'EPSG:32722'
    """
    from pyproj.aoi import AreaOfInterest
    from pyproj.database import query_utm_crs_info

    hits = query_utm_crs_info(datum_name="WGS 84", area_of_interest=AreaOfInterest(lon_deg, lat_deg, lon_deg, lat_deg))
    if not hits:
        raise CRSError(f"no UTM zone for longitude {lon_deg:g}, latitude {lat_deg:g}; give --crs")
    return f"{hits[0].auth_name}:{hits[0].code}"


def exif_orientations(infos: list[ExifInfo] | tuple[ExifInfo, ...], crs: str) -> tuple[np.ndarray, np.ndarray]:
    """Approximate exterior orientations from the EXIF GNSS tags, in *crs*.

    Parameters
    ----------
    infos : sequence of ExifInfo
    crs : str
        Target CRS (pyproj string, projected, metres).

    Returns
    -------
    position_m : ndarray (n, 3)
        E, N (projected from WGS 84 longitude/latitude) and the EXIF altitude, m; NaN rows for
        photos without a GNSS position.
    attitude_deg : ndarray (n, 3)
        omega = phi = 0, kappa = -GPSImgDirection (module docstring), degrees; NaN rows for photos
        without a direction.
    """
    from pyproj import CRS, Transformer

    n = len(infos)
    pos = np.full((n, 3), np.nan)
    att = np.full((n, 3), np.nan)
    has = np.array([i.has_position for i in infos], dtype=bool)
    if has.any():
        lon = np.array([infos[k].lon_deg for k in np.flatnonzero(has)], dtype=float)
        lat = np.array([infos[k].lat_deg for k in np.flatnonzero(has)], dtype=float)
        try:
            tr = Transformer.from_crs(CRS.from_epsg(4326), CRS.from_user_input(crs), always_xy=True)
        except Exception as ex:  # noqa: BLE001 - pyproj.exceptions.CRSError and friends
            raise CRSError(f"CRS {crs!r}: {ex}") from None
        e, nn = tr.transform(lon, lat)
        pos[has, 0], pos[has, 1] = e, nn
        pos[has, 2] = [infos[k].alt_m for k in np.flatnonzero(has)]
    for k, i in enumerate(infos):
        if i.direction_deg is not None:
            kappa = -i.direction_deg
            att[k] = (0.0, 0.0, (kappa + 180.0) % 360.0 - 180.0)
    return pos, att
