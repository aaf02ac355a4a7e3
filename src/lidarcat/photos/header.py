"""The size and format of a photo file from its header, and a cheap check that the file is whole.

A survey may name hundreds of photos of 100+ MP each; :meth:`lidarcat.Survey.load` checks every one at
every load, so nothing here decodes pixels.  Pillow's ``Image.open`` reads the header only (the size
and the format); whether the file is *complete* is told by its end, without decoding:

* JPEG: the last marker is EOI (``FF D9``); a transfer cut short ends in entropy-coded data instead
  (trailing ``00`` padding some writers add is skipped; a file with something after its image -- a
  motion-photo video -- is whole when an EOI follows its first scan);
* PNG: the last chunk is ``IEND``;
* TIFF: every strip (tags 273/279) or tile (324/325) lies inside the file: ``max(offset + count) <=
  size``.

A file that passes may still hold corrupt data inside (a bit flip in a JPEG's entropy-coded segment);
only decoding finds that, and the stages that decode (matching, orthophotos) report it with the file.

>>> import io, tempfile, pathlib
>>> from PIL import Image
>>> p = pathlib.Path(tempfile.mkdtemp()) / "a.png"
>>> Image.new("L", (30, 20)).save(p)
>>> h = read_header(p)
>>> h.format, h.columns_px, h.rows_px
('PNG', 30, 20)
>>> _ = p.write_bytes(p.read_bytes()[:-20])
>>> read_header(p)  # doctest: +ELLIPSIS
Traceback (most recent call last):
...
lidarcat.errors.FormatError: .../a.png: truncated PNG image: no IEND chunk at its end (the file was cut short; copy it again)
"""

from __future__ import annotations

import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

from ..errors import FormatError

__all__ = ["IMAGE_SUFFIXES", "ImageHeader", "read_header", "open_image"]

#: file suffixes of photos (lower case; matched case-insensitively)
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff")
#: formats read (Pillow's names)
FORMATS = ("JPEG", "PNG", "TIFF", "MPO")

_LOCK = threading.Lock()


@dataclass(frozen=True)
class ImageHeader:
    """What a photo file's header says.

    Attributes
    ----------
    path : Path
    format : str
        ``"JPEG"``, ``"PNG"`` or ``"TIFF"`` (an MPO, a JPEG with embedded previews, is ``"JPEG"``).
    columns_px, rows_px : int
        Width and height of the stored image, pixels (the EXIF orientation tag is not applied:
        the camera's ``columns_px`` are the stored width).
    mode : str
        Pillow's pixel mode (``"L"``, ``"RGB"``, ``"I;16"``, ...).
    """

    path: Path
    format: str
    columns_px: int
    rows_px: int
    mode: str


def open_image(path: Path):
    """``Image.open`` without Pillow's decompression-bomb limit (nothing is decoded here; aerial
    photos exceed the 89-MP default)."""
    from PIL import Image

    with _LOCK, warnings.catch_warnings():
        warnings.simplefilter("ignore", Image.DecompressionBombWarning)
        old, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
        try:
            return Image.open(path)
        finally:
            Image.MAX_IMAGE_PIXELS = old


def _tail(path: Path, n: int) -> bytes:
    with open(path, "rb") as fh:
        fh.seek(0, 2)
        size = fh.tell()
        fh.seek(max(0, size - n))
        return fh.read()


def _jpeg_has_eoi(path: Path) -> bool:
    """An end-of-image marker after the first scan: the photo is whole even though something follows it
    (a phone's motion-photo video, a maker's trailer).  Read only when the file's end is not FF D9.

    Entropy-coded data never holds ``FF D9`` (a data byte FF is stuffed with 00, and only the restart
    markers FF D0-D7 may appear), so the first ``FF D9`` after the first start-of-scan (``FF DA``) is the
    primary image's end; the segments before the scan (APPn with an embedded thumbnail and its own EOI,
    tables) are skipped by their lengths."""
    data = path.read_bytes()
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return False
        m = data[i + 1]
        if m == 0xFF:           # fill byte
            i += 1
            continue
        if m == 0xDA:           # start of scan
            return data.find(b"\xff\xd9", i) >= 0
        if 0xD0 <= m <= 0xD8 or m == 0x01:   # markers without a length
            i += 2
            continue
        i += 2 + int.from_bytes(data[i + 2:i + 4], "big")
    return False


def _check_whole(path: Path, fmt: str, im) -> str | None:
    """Why the file is cut short, or None."""
    if fmt == "JPEG":
        tail = _tail(path, 4096).rstrip(b"\x00")
        if not tail.endswith(b"\xff\xd9") and not _jpeg_has_eoi(path):
            return "truncated JPEG image: it does not end with the end-of-image marker FF D9"
    elif fmt == "PNG":
        if b"IEND" not in _tail(path, 64):
            return "truncated PNG image: no IEND chunk at its end"
    elif fmt == "TIFF":
        tags = getattr(im, "tag_v2", {})
        size = path.stat().st_size
        for off_tag, cnt_tag in ((273, 279), (324, 325)):
            offs, cnts = tags.get(off_tag), tags.get(cnt_tag)
            if offs is None or cnts is None:
                continue
            offs = offs if isinstance(offs, tuple) else (offs,)
            cnts = cnts if isinstance(cnts, tuple) else (cnts,)
            end = max((int(o) + int(c) for o, c in zip(offs, cnts)), default=0)
            if end > size:
                return (f"truncated TIFF image: its data runs to byte {end} but the file has {size} bytes")
    return None


def read_header(path: str | Path) -> ImageHeader:
    """Size and format of a JPEG, PNG or TIFF photo, its end checked (see the module docstring).

    Parameters
    ----------
    path : path

    Returns
    -------
    ImageHeader

    Raises
    ------
    FormatError
        The file cannot be opened, is no image Pillow identifies, is of another format, or is
        truncated: one line ``PATH: reason``.
    """
    from PIL import UnidentifiedImageError

    path = Path(path)
    try:
        im = open_image(path)
    except UnidentifiedImageError:
        raise FormatError(f"{path}: not a readable image (no JPEG, PNG or TIFF header)") from None
    except OSError as ex:
        raise FormatError(f"{path}: cannot read the image: {ex.strerror or ex}") from None
    try:
        fmt = "JPEG" if im.format == "MPO" else str(im.format)
        if fmt not in FORMATS:
            raise FormatError(f"{path}: a {im.format} image; photos must be JPEG, PNG or TIFF")
        why = _check_whole(path, fmt, im)
        if why is not None:
            raise FormatError(f"{path}: {why} (the file was cut short; copy it again)")
        w, h = im.size
        return ImageHeader(path, fmt, int(w), int(h), str(im.mode))
    finally:
        im.close()
