"""The lidarcat exception hierarchy.

Every error raised on purpose by the library derives from :class:`LidarcatError`.
Messages say *where* (file, line, field, photo or point id) and *what to fix*.
Subclasses mix in the matching builtin so callers may also catch ``ValueError``
or ``OSError``.  Non-convergence of an adjustment is **not** an error: it is a
status on the result object.
"""

from __future__ import annotations

__all__ = [
    "LidarcatError",
    "SurveyError",
    "CameraError",
    "LidarFormatError",
    "TileIOError",
    "CRSError",
    "ClipError",
    "DatumError",
    "ExtractionError",
    "AssessmentError",
    "FormatError",
    "ProductError",
    "location",
]


class LidarcatError(Exception):
    """Root of every error lidarcat raises on purpose."""


class SurveyError(LidarcatError, ValueError):
    """A survey folder or one of its files is invalid (names file, line, field)."""


class CameraError(LidarcatError, ValueError):
    """A camera calibration is invalid or a coordinate lies outside its domain."""


class LidarFormatError(LidarcatError, ValueError):
    """A LiDAR point file cannot be parsed (names the file and, for text, the line)."""


class TileIOError(LidarcatError, OSError):
    """A LiDAR tile cannot be opened or read."""


class CRSError(LidarcatError, ValueError):
    """A coordinate reference system is unknown, missing or inconsistent."""


class ClipError(LidarcatError, ValueError):
    """A LiDAR clip is empty or too small (names the position)."""


class DatumError(LidarcatError, ValueError):
    """The adjustment is singular: datum defect, weak photo or point (names it)."""


class ExtractionError(LidarcatError, ValueError):
    """A roof extraction job is malformed (names the job file and line)."""


class AssessmentError(LidarcatError, ValueError):
    """Accuracy-assessment inputs are inconsistent (names the file or point)."""


class FormatError(LidarcatError, ValueError):
    """A file of another program (COLMAP, OpenSfM, ODM, Metashape, OPK, GNSS) is malformed
    or cannot be represented (names the file, line and field)."""


class ProductError(LidarcatError, ValueError):
    """A product (raster, DTM, map sheets) cannot be made from the data or as asked: a tile
    without ground points, an empty cloud, a grid too large, an area outside the sheet index
    (names the tile, area or output)."""


def location(path: object, line: int | None = None, field: str | None = None) -> str:
    """Format a ``file:line: field`` prefix for error messages.

    >>> location("photos.csv", 3, "photo")
    "photos.csv:3: field 'photo'"
    >>> location("survey.toml")
    'survey.toml'
    """
    text = str(path)
    if line is not None:
        text += f":{line}"
    if field is not None:
        text += f": field {field!r}"
    return text
