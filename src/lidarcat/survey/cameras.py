"""``camera.toml`` files: the survey's cameras read, every error located (file:line and key).

A camera file holds one table per camera id (docs/survey-format.md); each table becomes a
:class:`~lidarcat.geometry.camera.Camera` through :meth:`~lidarcat.geometry.camera.Camera.from_dict`, whose
:class:`~lidarcat.errors.CameraError` (naming the field) becomes a :class:`~lidarcat.errors.SurveyError`
naming the file, the line of the key (or of the table) and the camera.  Reading the file is survey
I/O, so it lives here and not in the engine (:mod:`lidarcat.geometry` takes tables and values); the text
of a table is :meth:`~lidarcat.geometry.camera.Camera.to_toml`.
"""

from __future__ import annotations

from pathlib import Path

from .._util import read_toml, toml_line
from ..errors import CameraError, SurveyError, location
from ..geometry.camera import Camera

__all__ = ["load_cameras", "load_camera"]


def _short(name: str) -> str:
    """A key or id from a file, cut for a message."""
    return name if len(name) <= 60 else name[:60] + "..."


def load_cameras(path: str | Path) -> dict[str, Camera]:
    """Read a ``camera.toml``: one table per camera id (format: docs/survey-format.md).

    Parameters
    ----------
    path : str or Path
        The TOML file.

    Returns
    -------
    dict[str, Camera]
        Cameras by id, in file order.

    Raises
    ------
    SurveyError
        Missing, unreadable or non-UTF-8 file, invalid TOML, no camera table, an
        unknown or missing key, or an invalid value: the message names the file,
        the line and the key.
    """
    path = Path(path)
    data, text = read_toml(path)
    cameras: dict[str, Camera] = {}
    for cam_id, table in data.items():
        if not isinstance(table, dict):
            raise SurveyError(f"{location(path, toml_line(text, None, cam_id), _short(cam_id))}: "
                              f"top-level key outside a camera table; put each camera under "
                              f"a [camera_id] header")
        try:
            cameras[cam_id] = Camera.from_dict(cam_id, table)
        except CameraError as ex:
            fld = getattr(ex, "field", None)
            line = toml_line(text, cam_id, fld if fld in table else None)
            msg = getattr(ex, "detail", str(ex))
            raise SurveyError(f"{location(path, line, None if fld is None else _short(fld))}: "
                              f"camera [{_short(cam_id)}]: {msg}") from ex
    if not cameras:
        raise SurveyError(f"{path}: no camera defined; add a [camera_id] table "
                          f"(see docs/survey-format.md)")
    return cameras


def load_camera(spec: str | Path) -> Camera:
    """Load one camera from ``FILE`` or ``FILE:ID`` (ID needed when FILE holds several).

    Raises
    ------
    SurveyError
        The file is invalid, the id is unknown, or no id was given for a file
        with several cameras.
    """
    text = str(spec)
    path, cam_id = Path(text), None
    if not path.exists() and ":" in text:
        head, _, tail = text.rpartition(":")
        path, cam_id = Path(head), tail
    cameras = load_cameras(path)
    if cam_id is None:
        if len(cameras) > 1:
            raise SurveyError(f"{path}: holds cameras {', '.join(cameras)}; name one as "
                              f"{path}:ID")
        return next(iter(cameras.values()))
    if cam_id not in cameras:
        raise SurveyError(f"{path}: no camera {cam_id!r}; defined: {', '.join(cameras)}")
    return cameras[cam_id]


