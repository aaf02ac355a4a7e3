"""One format to another through :class:`~lidarcat.interop.block.Block`, without adjusting.

:func:`read_block` reads a whole block (COLMAP model, OpenSfM reconstruction, Metashape chunk, or a
lidarcat survey folder with, optionally, the output folder of ``lidarcat adjust``);
:func:`write_block` writes one (COLMAP, OpenSfM, OPK text, or a survey folder).  What each format
keeps and loses is in ``docs/formats/``; the cameras travel as
:mod:`lidarcat.interop.lens` describes.  A block with orientations but no tie points (an
orientation-only OpenSfM reconstruction as OpenDroneMap writes, a Metashape chunk) converts to
every format; as a survey folder its ``image_points.csv`` is the header only (``lidarcat match``
measures the tie points).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import FormatError
from .block import Block

__all__ = ["read_block", "write_block", "convert", "READ_FORMATS", "WRITE_FORMATS"]

#: format -> what IN is
READ_FORMATS = {
    "colmap": "COLMAP model folder (text or binary)",
    "opensfm": "OpenSfM reconstruction.json (tracks.csv beside it, or --tracks)",
    "metashape": "Metashape chunk doc.xml (marker measurements: --frame)",
    "survey": "lidarcat survey folder (its orientations, or those of --adjustment)",
}
#: format -> what OUT is
WRITE_FORMATS = {
    "colmap": "COLMAP text model folder",
    "opensfm": "OpenSfM reconstruction.json + tracks.csv folder",
    "opk": "omega-phi-kappa text file (--flavour, --angle-unit)",
    "survey": "lidarcat survey folder",
}


def read_block(fmt: str, path: str | Path, *, crs: str | None = None, pixel_size_mm: float | None = None,
               tracks: str | Path | None = None, frame: str | Path | None = None,
               adjustment: str | Path | None = None) -> Block:
    """The block of *path* in *fmt* (:data:`READ_FORMATS`).

    Raises
    ------
    FormatError
        Unknown format, or the reader's located errors.
    """
    from ._checks import check_crs

    check_crs(crs, local=fmt == "colmap")
    if fmt == "colmap":
        from .colmap import LOCAL_CRS, read_colmap
        from .colmap_binary import read_colmap_binary

        binary = (Path(path) / "cameras.bin").is_file() and not (Path(path) / "cameras.txt").is_file()
        return (read_colmap_binary if binary else read_colmap)(path, pixel_size_mm=pixel_size_mm, crs=crs or LOCAL_CRS)
    if fmt == "opensfm":
        from .opensfm import read_opensfm

        return read_opensfm(path, tracks, pixel_size_mm=pixel_size_mm)
    if fmt == "metashape":
        from .metashape import read_metashape

        return read_metashape(path, frame, crs=crs, pixel_size_mm=pixel_size_mm)
    if fmt == "survey":
        from .block import block_from_survey

        return block_from_survey(path, adjustment)
    raise FormatError(f"cannot read format {fmt!r}: give one of {', '.join(READ_FORMATS)}")


def write_block(fmt: str, block: Block, out: str | Path, *, angle_unit: str = "deg", flavour: str = "pix4d",
                overwrite: bool = False) -> Path:
    """Write *block* to *out* in *fmt* (:data:`WRITE_FORMATS`), atomically.

    Raises
    ------
    FormatError
        Unknown format, a photo without orientation (colmap, opensfm, opk), a block without
        photos (survey), *out* holding a survey (survey, unless *overwrite*).
    """
    if fmt == "colmap":
        from .colmap import write_colmap

        return write_colmap(block, out)
    if fmt == "opensfm":
        from .opensfm import write_opensfm

        return write_opensfm(block, out)
    if fmt == "opk":
        from .opk import write_opk

        return write_opk(block, out, angle_unit=angle_unit, flavour=flavour)
    if fmt == "survey":
        from .block import write_survey

        return write_survey(block, out, overwrite=overwrite)
    raise FormatError(f"cannot write format {fmt!r}: give one of {', '.join(WRITE_FORMATS)}")


def convert(fmt_in: str, path_in: str | Path, fmt_out: str, path_out: str | Path, *,
            read: dict[str, Any] | None = None, write: dict[str, Any] | None = None) -> Block:
    """Read *path_in* in *fmt_in* and write it to *path_out* in *fmt_out*; returns the block.

    >>> import tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "thesis"
    >>> convert("survey", None, "survey", out).n_photos    # the embedded thesis block
    6
    """
    block = read_block(fmt_in, path_in, **(read or {}))
    write_block(fmt_out, block, path_out, **(write or {}))
    return block
