"""Photo files: their headers (size, format, truncation) and their EXIF tags (focal length, GNSS position).

==========  ============================================================
``header``  the size and format of a JPEG/PNG/TIFF photo from its header, without decoding; truncation checks
``exif``    EXIF focal length (and 35 mm equivalent), focal-plane resolution, GNSS latitude/longitude/altitude and
            image direction, projected with pyproj into a survey CRS
==========  ============================================================

An engine: paths in, value types out; it knows no survey folder (``Survey.load`` checks the survey's
images with :func:`read_header`, ``lidarcat init`` reads their EXIF).
"""

from __future__ import annotations

from .exif import ExifInfo, exif_orientations, read_exif  # noqa: F401
from .header import IMAGE_SUFFIXES, ImageHeader, read_header  # noqa: F401

__all__ = ["IMAGE_SUFFIXES", "ImageHeader", "read_header", "ExifInfo", "read_exif", "exif_orientations"]
