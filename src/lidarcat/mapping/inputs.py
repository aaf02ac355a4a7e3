"""What the mapping products need from an adjusted survey: orientations, photo files, surfaces.

* adjusted orientations -- ``eop.csv`` of ``lidarcat adjust``/``lidarcat run``
  (default ``<survey output>/adjust-<default control set>/eop.csv``) and their
  full covariance, ``eop_covariance.csv`` beside it; a photo
  of the survey that is not in it was not adjusted: a located error;
* photo files -- ``<images>/<photo id>.<png|tif|tiff|jpg|jpeg>`` (default
  ``images/`` in the survey folder; ``lidarcat demo synthetic --images`` writes
  them there), grey or RGB, the size of the photo's camera;
* surfaces -- a DSM/DTM GeoTIFF (``lidarcat lidar raster``) or the LiDAR points
  around the area (:class:`lidarcat.mapping.monoplot.PointSurface`; first returns only,
  the paper's surface model: a last return under a tree or through a roof edge
  is not what the photo shows), the area being where the rays of the
  digitised pixels cross the tiles' height range (:func:`ray_area`).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import SurveyError

__all__ = ["read_orientations", "default_eop_path", "adjusted_orientation", "adjusted_orientations",
           "photo_image", "IMAGE_SUFFIXES", "lidar_surface", "ray_area"]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg")


def read_orientations(path: str | os.PathLike) -> Mapping[str, Any]:
    """Read the adjusted exterior orientations of an ``eop.csv`` (``lidarcat adjust``/``run``).

    Parameters
    ----------
    path : path-like
        ``eop.csv``: photo, X0, Y0, Z0 (m), omega, phi, kappa (deg) and
        optionally ``sd_*`` of each (m, deg).

    Returns
    -------
    dict[str, lidarcat.bundle.ExteriorOrientation]
        By photo id; ``cov`` is the full 6 x 6 covariance (m^2, m rad, rad^2)
        of ``eop_covariance.csv`` beside the file when it is there (written
        by the adjustment since issue 25; :mod:`lidarcat.survey.covariance`),
        else diagonal (``sd**2``: an older folder holds standard deviations
        only, the correlations taken as zero, which overstates the plan sd of
        a monoplotted point many times).  Without either ``cov`` is None.

    Raises
    ------
    SurveyError
        Missing file, missing column, non-numeric value, a photo given twice
        (file, line, field).
    """
    from .._util import read_csv_table
    from ..bundle import ExteriorOrientation
    from ..errors import location

    path = Path(path)
    if not path.is_file():
        raise SurveyError(f"{path}: no such orientation file (eop.csv of `lidarcat adjust` or `lidarcat run`)")
    keys = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    t = read_csv_table(path, required=("photo",) + keys, allow_extra=True)
    vals = np.column_stack([t.floats(k) for k in keys])
    has_sd = all(t.has(f"sd_{k}") for k in keys)
    sds = np.column_stack([t.floats(f"sd_{k}") for k in keys]) if has_sd else None
    full = _full_covariance(path)
    out: dict[str, Any] = {}
    for i, pid in enumerate(t.column("photo")):
        if pid in out:
            raise SurveyError(f"{location(path, t.lines[i], 'photo')}: photo {pid!r} is given twice")
        p = vals[i].copy()
        p[3:] = np.radians(p[3:])
        cov = full.get(pid)
        if cov is None and sds is not None:
            s = sds[i].copy()
            s[3:] = np.radians(s[3:])
            cov = np.diag(np.where(np.isfinite(s), s, 0.0) ** 2)
        out[pid] = ExteriorOrientation.from_params(p, photo=pid, cov=cov)
    return out


def _full_covariance(eop_path: Path) -> dict[str, np.ndarray]:
    """The 6 x 6 blocks of ``eop_covariance.csv`` beside *eop_path*, by photo ({} when absent)."""
    from ..survey.covariance import EOP_COVARIANCE_FILE, read_eop_covariance

    side = eop_path.with_name(EOP_COVARIANCE_FILE)
    if not side.is_file():
        log.info("%s: no %s beside it; orientation correlations taken as zero", eop_path, EOP_COVARIANCE_FILE)
        return {}
    return read_eop_covariance(side)


def default_eop_path(survey: Any) -> Path:
    """``<output dir>/adjust-<default control set>/eop.csv`` of a survey (may not exist)."""
    name = survey.default_control or (next(iter(survey.control_sets)) if survey.control_sets else "gps")
    return survey.output_dir() / f"adjust-{name}" / "eop.csv"


def adjusted_orientations(survey: Any, photo_ids: Sequence[str],
                          eop_path: str | os.PathLike | None = None) -> dict[str, Any]:
    """The adjusted :class:`~lidarcat.bundle.ExteriorOrientation` of photos of the survey, by photo id.

    The orientation file is read once, however many photos are asked for.

    Parameters
    ----------
    survey : lidarcat.survey.folder.Survey
    photo_ids : sequence of str
    eop_path : path-like, optional
        ``eop.csv`` of an adjustment (default :func:`default_eop_path`).

    Raises
    ------
    SurveyError
        A photo is not in the survey, the orientation file is missing, or a
        photo is not in it (not adjusted); the first such photo is named.
    """
    known = set(survey.photo_ids)
    for pid in photo_ids:
        if pid not in known:
            raise SurveyError(f"{survey.root / 'photos.csv'}: no photo {pid!r} in the survey (photos: "
                              f"{', '.join(survey.photo_ids[:10])}{' ...' if len(survey.photo_ids) > 10 else ''})")
    path = Path(eop_path) if eop_path is not None else default_eop_path(survey)
    if not path.is_file():
        raise SurveyError(f"{path}: no adjusted orientations; run `lidarcat run {survey.root}` first or "
                          f"give the eop.csv of an adjustment (--eop)")
    eos = read_orientations(path)
    for pid in photo_ids:
        if pid not in eos:
            raise SurveyError(f"{path}: photo {pid!r} was not adjusted (it is not in this file); "
                              f"adjusted photos: {', '.join(list(eos)[:10])}")
    return {pid: eos[pid] for pid in photo_ids}


def adjusted_orientation(survey: Any, photo_id: str, eop_path: str | os.PathLike | None = None) -> Any:
    """The adjusted orientation of one photo (:func:`adjusted_orientations`)."""
    return adjusted_orientations(survey, [photo_id], eop_path)[photo_id]


def photo_image(photo_id: str, images_dir: str | os.PathLike, camera: Any) -> np.ndarray:
    """Read ``<images_dir>/<photo_id>.<suffix>`` as a grey (rows, cols) or RGB (rows, cols, 3) uint8/uint16 array.

    Raises
    ------
    SurveyError
        No such file, an unreadable image, or a size that is not the camera's.
    """
    import cv2

    folder = Path(images_dir)
    cands = [folder / f"{photo_id}{s}" for s in IMAGE_SUFFIXES]
    path = next((p for p in cands if p.is_file()), None)
    if path is None:
        raise SurveyError(f"{folder}: no image of photo {photo_id!r} (looked for {photo_id}.png, .tif, "
                          f".jpg); write them with `lidarcat demo synthetic --images` or give --images DIR")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SurveyError(f"{path}: cannot read the image (not a PNG/TIFF/JPEG OpenCV can decode)")
    if img.ndim == 3:
        img = img[:, :, 2::-1] if img.shape[2] >= 3 else img[:, :, 0]   # BGR(A) -> RGB
    if img.shape[:2] != (camera.rows_px, camera.columns_px):
        raise SurveyError(f"{path}: image is {img.shape[1]} x {img.shape[0]} px but camera {camera.id!r} "
                          f"is {camera.columns_px} x {camera.rows_px} px")
    return np.ascontiguousarray(img)


def ray_area(camera: Any, eo_params: Any, colrow_px: Any, zmin_m: float, zmax_m: float,
             margin_m: float = 5.0) -> tuple[float, float, float, float]:
    """Box (E min, N min, E max, N max; m) the rays of *colrow_px* cross between two heights.

    The heights are widened by *margin_m* (the LiDAR's height range: every
    first hit lies in it); pixels outside the frame are ignored (their status
    says so), the photo centre stands in when none is inside.
    """
    from .monoplot import ray_directions

    px = np.asarray(colrow_px, dtype=np.float64).reshape(-1, 2)
    inside = np.asarray(camera.contains(px), dtype=bool)
    d = ray_directions(camera, eo_params, px[inside] if inside.any() else np.array([[0.0, 0.0]]))
    p = np.asarray(eo_params, dtype=np.float64)
    ends = np.vstack([p[:2] + ((h - p[2]) / d[:, 2])[:, None] * d[:, :2]
                      for h in (zmin_m - margin_m, zmax_m + margin_m)])
    return (float(ends[:, 0].min() - margin_m), float(ends[:, 1].min() - margin_m),
            float(ends[:, 0].max() + margin_m), float(ends[:, 1].max() + margin_m))


def lidar_surface(index: Any, bounds: Sequence[float], interpolator: str = "tin", sd_m: float = 0.15,
                  first_returns: bool = True) -> Any:
    """A :class:`~lidarcat.mapping.monoplot.PointSurface` of the LiDAR points in *bounds* (m).

    *index* is the :class:`~lidarcat.lidar.TileIndex` of the tiles (the caller
    builds it once: its height range also gives :func:`ray_area`).  With
    *first_returns* (default) only first (or only) returns: the surface the
    photo sees (Cavassim 2005, section 6.2: a DSM of the first return).

    Raises
    ------
    SurveyError
        No LiDAR point in the area.
    """
    from .monoplot import PointSurface

    cloud = index.query_box(*bounds)
    xyz = np.asarray(cloud.xyz)
    if first_returns:
        xyz = xyz[cloud.first_returns()]
    if len(xyz) < 3:
        raise SurveyError(f"no LiDAR points in E {bounds[0]:.1f}..{bounds[2]:.1f}, N {bounds[1]:.1f}.."
                          f"{bounds[3]:.1f} (tiles: {', '.join(str(t.path) for t in index.tiles)[:200]})")
    log.info("%d LiDAR points in the area for the surface", len(xyz))
    return PointSurface(xyz, interpolator, sd_m)
