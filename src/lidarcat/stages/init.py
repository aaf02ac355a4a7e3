"""The action of ``lidarcat init``: a survey folder from a folder of photos (issue 28, the first step).

:func:`init_survey` lists the photos of a folder (``*.jpg, *.jpeg, *.png, *.tif, *.tiff``; the file
name without its suffix is the photo id), reads each one's header and EXIF tags
(:mod:`lidarcat.photos`), and writes

* ``camera.toml`` -- the camera given (``--camera FILE[:ID]``), or one built from the EXIF focal
  length and pixel size (:attr:`lidarcat.photos.exif.ExifInfo.pixel_size_mm`), no distortion, marked
  approximate: self-calibration is advised (``[self_calibration] parameters``);
* ``photos.csv`` -- one row per photo with its ``image`` (relative to the survey folder) and the
  approximate exterior orientation: from a GNSS/IMU file (``--gnss``, read by
  :func:`lidarcat.interop.gnss.read_gnss`) or else from the EXIF GNSS tags
  (:func:`lidarcat.photos.exif_orientations`), with ``sd_*`` columns (the file's sds where it gives
  them, else *position_sd_m* / *attitude_sd_deg*) so that ``lidarcat adjust --eo-constraints`` can
  weight them;
* ``image_points.csv`` -- the header only: no observation yet (``lidarcat match`` measures them);
* ``survey.toml`` -- the name, the CRS (``--crs``; else the GNSS file's projected CRS; else the
  WGS 84 / UTM zone of the photos' mean EXIF position; else a local frame) and the files, with the
  LiDAR tiles (``--lidar``) listed as paths relative to the folder.

Every photo is checked before anything is written (a file that is no whole JPEG/PNG/TIFF, two
photos of one id, a photo of another size than the camera, a photo missing from the GNSS file: one
line naming the file); the folder is then written at once (:func:`lidarcat._util.atomic_dir`), so a
failure leaves nothing half-written.  An existing folder holding anything but the photos, tiles and
files given is refused unless *overwrite*.
"""

from __future__ import annotations

import glob
import json
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, excerpt, write_csv_atomic, write_text_atomic
from ..errors import CRSError, SurveyError, location
from ..geometry.camera import Camera
from ..photos import IMAGE_SUFFIXES, ExifInfo, exif_orientations, read_exif
from ..photos.exif import utm_crs
from ..survey.cameras import load_camera
from ..survey.folder import relative_path

__all__ = ["init_survey", "InitResult", "list_photos", "camera_from_exif", "DEFAULT_POSITION_SD_M",
           "DEFAULT_ATTITUDE_SD_DEG"]

#: sd of an approximate position without its own sd (consumer GNSS in EXIF, a GNSS file without sds), m
DEFAULT_POSITION_SD_M = 5.0
#: sd of an approximate attitude without its own sd, degrees
DEFAULT_ATTITUDE_SD_DEG = 5.0
_LIDAR_SUFFIXES = (".las", ".laz", ".txt", ".xyz", ".csv")


@dataclass(frozen=True)
class InitResult:
    """What :func:`init_survey` wrote.

    Attributes
    ----------
    folder : Path
    crs : str
    camera : str
        Camera id; ``camera_source`` says where it came from.
    camera_source : str
    photos : tuple of str
        Photo ids, in file-name order.
    with_position, with_attitude : tuple of str
        Photos given an approximate position / attitude.
    without_position : tuple of str
        Photos without one (no EXIF GNSS tags): reported, not refused.
    lidar : tuple of str
        The tiles as written in survey.toml.
    notes : tuple of str
        What the user should know (an approximate camera, photos without position, the CRS chosen).
    """

    folder: Path
    crs: str
    camera: str
    camera_source: str
    photos: tuple[str, ...]
    with_position: tuple[str, ...]
    with_attitude: tuple[str, ...]
    without_position: tuple[str, ...]
    lidar: tuple[str, ...]
    notes: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"folder": str(self.folder), "crs": self.crs, "camera": self.camera,
                "camera_source": self.camera_source, "n_photos": len(self.photos), "photos": list(self.photos),
                "with_position": len(self.with_position), "with_attitude": len(self.with_attitude),
                "without_position": list(self.without_position), "lidar": list(self.lidar),
                "notes": list(self.notes)}


def list_photos(folder: str | os.PathLike) -> list[tuple[str, Path]]:
    """(photo id, path) of the photos in *folder* (not recursive, hidden files skipped), sorted by name.

    Raises
    ------
    SurveyError
        No such folder, no photo in it, or two files of one id (``a.jpg`` and ``a.png``).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise SurveyError(f"{folder}: no such folder of photos")
    files = sorted(p for p in folder.iterdir()
                   if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file())
    if not files:
        raise SurveyError(f"{folder}: no photos in this folder (files ending in "
                          f"{', '.join(IMAGE_SUFFIXES)})")
    seen: dict[str, Path] = {}
    out = []
    for p in files:
        if p.stem in seen:
            raise SurveyError(f"{p}: photo {excerpt(p.stem)} is listed twice: {seen[p.stem].name} and {p.name} "
                              f"have the same name; keep one or rename it")
        seen[p.stem] = p
        out.append((p.stem, p))
    return out


def camera_from_exif(infos: Sequence[ExifInfo], camera_id: str = "camera") -> Camera:
    """An approximate camera from the EXIF of the first photo that gives its focal length and pixel size.

    Principal point at the centre, no distortion; ``source`` says it is approximate and
    self-calibration is advised; ``sd_focal_length_mm`` is 2 % of the focal length (EXIF focal lengths
    are nominal, rounded to 0.1-1 mm).

    Raises
    ------
    SurveyError
        No photo gives a focal length with a 35 mm equivalent or a focal-plane resolution.
    """
    for info in infos:
        if info.focal_length_mm and info.pixel_size_mm:
            pix = float(info.pixel_size_mm)
            how = ("focal-plane resolution" if info.focal_plane_pixel_mm is not None else
                   f"35 mm equivalent {info.focal_length_35mm_mm:g} mm")
            return Camera(camera_id, float(info.focal_length_mm), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, pix, pix,
                          info.columns_px, info.rows_px, model=info.camera_name,
                          source=(f"approximate, from the EXIF of {info.path.name} (focal length "
                                  f"{info.focal_length_mm:g} mm, pixel size from the {how}); no distortion: "
                                  f"self-calibration is advised ([self_calibration] parameters = \"all\")"),
                          sd={"sd_focal_length_mm": round(0.02 * float(info.focal_length_mm), 6)})
    raise SurveyError(f"{infos[0].path.parent}: no photo has an EXIF focal length with a 35 mm equivalent or a "
                      f"focal-plane resolution, so the camera cannot be guessed; give it with --camera FILE[:ID]")


def _is_projected(crs: str) -> bool:
    from pyproj import CRS

    try:
        return CRS.from_user_input(crs).is_projected
    except Exception as ex:  # noqa: BLE001 - pyproj.exceptions.CRSError
        raise CRSError(f"CRS {crs!r}: {ex}") from None


def _transform(en: np.ndarray, src: str, dst: str) -> np.ndarray:
    from pyproj import CRS, Transformer

    if CRS.from_user_input(src) == CRS.from_user_input(dst):
        return en
    tr = Transformer.from_crs(CRS.from_user_input(src), CRS.from_user_input(dst), always_xy=True)
    e, n = tr.transform(en[:, 0], en[:, 1])
    return np.column_stack([e, n])


def _gnss_orientations(path: Path, gnss_crs: str, ids: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                             np.ndarray, str]:
    """(position (n,3), attitude deg (n,3), sd position (n,3), sd attitude deg (n,3), source) of the photos
    *ids* from a GNSS/IMU file in *gnss_crs* (positions in that CRS); a photo missing from it is an error."""
    from ..interop.gnss import read_gnss

    o = read_gnss(path, file_crs=gnss_crs, crs=gnss_crs)
    row: dict[str, int] = {}
    for k, name in enumerate(o.photo.tolist()):
        row.setdefault(name, k)
        row.setdefault(Path(name).stem, k)   # DSC_0001.JPG in the file names photo DSC_0001
    missing = [i for i in ids if i not in row]
    if missing:
        raise SurveyError(f"{path}: photo {excerpt(missing[0])} is not in this GNSS/IMU file"
                          + (f" (nor {len(missing) - 1} other photo(s))" if len(missing) > 1 else "")
                          + "; its first column must name each photo (its file name, with or without suffix)")
    k = np.array([row[i] for i in ids], dtype=np.intp)
    from pyproj import CRS

    if CRS.from_user_input(gnss_crs).is_geographic:   # E, N are longitude, latitude: refuse metres read as degrees
        lon, lat = o.eo[k, 0], o.eo[k, 1]
        bad = np.flatnonzero(~((np.abs(lon) <= 180) & (np.abs(lat) <= 90)))
        if bad.size:
            j = int(k[bad[0]])
            raise SurveyError(f"{location(path, int(o.line[j]))}: photo {excerpt(str(o.photo[j]))}: {lon[bad[0]]:g}, "
                              f"{lat[bad[0]]:g} is no longitude, latitude of {gnss_crs}; give the file's CRS with "
                              f"--gnss-crs (e.g. EPSG:31982)")
    eo, sd = o.eo[k], o.eo_sd[k]
    return eo[:, :3].copy(), np.degrees(eo[:, 3:]), sd[:, :3].copy(), np.degrees(sd[:, 3:]), o.source


def _expand_lidar(items: Sequence[str | os.PathLike]) -> list[Path]:
    out: list[Path] = []
    for item in items:
        s = os.fspath(item)
        if Path(s).is_dir():
            hits = sorted(p for p in Path(s).iterdir() if p.suffix.lower() in _LIDAR_SUFFIXES and p.is_file())
            if not hits:
                raise SurveyError(f"{s}: no LiDAR tiles in this folder (.las, .laz, .txt, .xyz, .csv)")
        elif glob.has_magic(s):
            hits = sorted(Path(p) for p in glob.glob(s, recursive=True) if Path(p).is_file())
            if not hits:
                raise SurveyError(f"{s}: this pattern matches no LiDAR tile")
        else:
            if not Path(s).is_file():
                raise SurveyError(f"{s}: LiDAR tile not found")
            hits = [Path(s)]
        out.extend(hits)
    return list(dict.fromkeys(p.resolve() for p in out))


def _check_target(folder: Path, inputs: Sequence[Path], overwrite: bool) -> None:
    """Refuse a folder that holds a survey.toml or files other than the inputs, unless *overwrite*."""
    if not folder.exists():
        return
    if not folder.is_dir():
        raise SurveyError(f"{folder}: exists and is no folder; choose another survey folder")
    if overwrite:
        return
    if (folder / "survey.toml").exists():
        raise SurveyError(f"{folder}: already holds a survey (survey.toml); choose another folder or pass --overwrite")
    keep = [p.resolve() for p in inputs]
    for entry in sorted(folder.iterdir()):
        e = entry.resolve()
        if not any(k == e or e in k.parents for k in keep):
            raise SurveyError(f"{folder}: is not empty ({excerpt(entry.name)}); choose another folder or pass "
                              f"--overwrite")


def _toml(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)


def init_survey(folder: str | os.PathLike, images: str | os.PathLike, *, camera: str | os.PathLike | None = None,
                gnss: str | os.PathLike | None = None, gnss_crs: str = "EPSG:4326",
                lidar: Sequence[str | os.PathLike] = (), crs: str | None = None, name: str | None = None,
                height_system: str | None = None, position_sd_m: float = DEFAULT_POSITION_SD_M,
                attitude_sd_deg: float = DEFAULT_ATTITUDE_SD_DEG, overwrite: bool = False,
                progress: Callable[[int, int], None] | None = None) -> InitResult:
    """Write a survey folder from a folder of photos (the module docstring says what goes where).

    Parameters
    ----------
    folder : path
        The survey folder to write.
    images : path
        Folder of the photos.
    camera : path, optional
        ``FILE`` or ``FILE:ID`` of a camera TOML (default: an approximate camera from the EXIF).
    gnss : path, optional
        GNSS/IMU file (``photo, E, N, h[, omega, phi, kappa | roll, pitch, yaw][, sd_*]``), coordinates in
        *gnss_crs* (default EPSG:4326 longitude/latitude).
    lidar : sequence of paths
        LiDAR tiles, folders of tiles or glob patterns.
    crs : str, optional
        Survey CRS (projected, metres).  Default: the GNSS file's CRS when projected, else the WGS 84 /
        UTM zone of the photos' mean position, else a local frame (no position at all, no tiles).
    name, height_system : str, optional
        ``[survey]`` name (default: the folder's name) and height system (default: ``ellipsoidal`` for a
        GNSS file, ``unspecified`` otherwise: EXIF altitudes are often either).
    position_sd_m, attitude_sd_deg : float
        sd of an approximate position / attitude where the source gives none, m / degrees.
    overwrite : bool
        Write into a folder that holds other files (a survey) too.
    progress : callable(done, total), optional
        Called after each photo is read.

    Returns
    -------
    InitResult

    Raises
    ------
    SurveyError, FormatError, CRSError
        One line naming the file: no photos, an unreadable or truncated photo, two photos of one id, a
        photo of another size than the camera, a photo missing from the GNSS file, no EXIF camera and no
        *camera*, a CRS that is not projected, a missing LiDAR tile, a folder that is not empty.
    """
    folder, images = Path(folder), Path(images)
    if not 0 < position_sd_m <= 1000 or not 0 < attitude_sd_deg <= 90:
        raise SurveyError(f"position sd {position_sd_m!r} m and attitude sd {attitude_sd_deg!r} degrees must lie in "
                          f"(0, 1000] m and (0, 90] degrees")
    photos = list_photos(images)
    ids = [i for i, _ in photos]
    tiles = _expand_lidar(lidar)
    given = [images, *tiles] + [Path(p) for p in (gnss,) if p is not None]
    _check_target(folder, given, overwrite)

    infos: list[ExifInfo] = []
    for k, (_, p) in enumerate(photos):
        infos.append(read_exif(p))
        if progress is not None:
            progress(k + 1, len(photos))
    notes: list[str] = []
    if camera is not None:
        cam = load_camera(camera)
        cam_source = f"{camera}"
    else:
        cam = camera_from_exif(infos)
        cam_source = "EXIF (approximate)"
        notes.append(f"camera {cam.id!r} is approximate (EXIF focal length {cam.focal_length_mm:g} mm, pixel "
                     f"{cam.pixel_size_x_mm * 1000:.4g} um, no distortion): self-calibration is advised")
        focals = Counter(i.focal_length_mm for i in infos if i.focal_length_mm)
        if len(focals) > 1:
            notes.append(f"the photos give {len(focals)} different EXIF focal lengths "
                         f"({', '.join(f'{f:g}' for f in sorted(focals))} mm): a zoom lens or several cameras")
    for info in infos:
        if (info.columns_px, info.rows_px) != (cam.columns_px, cam.rows_px):
            raise SurveyError(f"{info.path}: image is {info.columns_px} x {info.rows_px} px but camera {cam.id!r} "
                              f"({cam_source}) is {cam.columns_px} x {cam.rows_px} px; a photo of another camera "
                              f"(give that camera, or leave the photo out)")

    n = len(ids)
    pos = np.full((n, 3), np.nan)
    att = np.full((n, 3), np.nan)
    sdp = np.full((n, 3), np.nan)
    sda = np.full((n, 3), np.nan)
    if gnss is not None:
        pos, att, sdp, sda, source = _gnss_orientations(Path(gnss), gnss_crs, ids)
        src_crs = gnss_crs
        if crs is None:
            crs = gnss_crs if _is_projected(gnss_crs) else utm_crs(*np.nanmean(pos[:, :2], axis=0))
        pos[:, :2] = _transform(pos[:, :2], src_crs, crs)
        if not np.isfinite(pos).all():
            i = int(np.flatnonzero(~np.isfinite(pos).all(axis=1))[0])
            raise CRSError(f"{gnss}: photo {excerpt(ids[i])}: its position in {src_crs} has no place in {crs}; "
                           f"check --gnss-crs and --crs")
        hsys = height_system or "ellipsoidal"
        notes.append(f"approximate orientation from {source}")
    else:
        has = [i.has_position for i in infos]
        if crs is None and any(has):
            mean = np.mean([[i.lon_deg, i.lat_deg] for i in infos if i.has_position], axis=0)
            crs = utm_crs(float(mean[0]), float(mean[1]))
            notes.append(f"CRS {crs}: the WGS 84 / UTM zone of the photos' EXIF positions (give --crs for another)")
        if any(has):
            pos, att = exif_orientations(infos, crs)  # type: ignore[arg-type]
            notes.append("approximate positions from the EXIF GNSS tags (altitudes as written; say in survey.toml "
                         "[survey] height_system whether they are ellipsoidal)")
        hsys = height_system or "unspecified"
    if crs is None:
        if tiles:
            raise SurveyError(f"{images}: the photos carry no position and no --crs was given; give the CRS of the "
                              f"LiDAR tiles with --crs")
        crs = "local: no georeference (lidarcat init: photos without positions)"
        notes.append("no photo has a position and no --crs was given: the survey's frame is local")
    elif not crs.lower().startswith("local"):
        _check_crs(crs, pos, ids)
    has_pos = np.isfinite(pos).all(axis=1)
    has_att = np.isfinite(att).all(axis=1)
    sdp = np.where(has_pos[:, None] & ~np.isfinite(sdp), position_sd_m, sdp)
    sda = np.where(has_att[:, None] & ~np.isfinite(sda), attitude_sd_deg, sda)
    without = tuple(i for i, h in zip(ids, has_pos) if not h)
    if without and has_pos.any():
        notes.append(f"{len(without)} photo(s) without EXIF GNSS position, left without approximate orientation: "
                     f"{', '.join(without[:10])}{' ...' if len(without) > 10 else ''}")

    name = name or folder.resolve().name
    lidar_rel = tuple(relative_path(t, folder) for t in tiles)
    with atomic_dir(folder) as tmp:
        write_text_atomic(tmp / "camera.toml", f"# written by lidarcat init; camera from {cam_source}\n"
                          + cam.to_toml())
        cols = ["photo", "camera", "image"]
        if has_pos.any():
            cols += ["X0", "Y0", "Z0"]
        if has_att.any():
            cols += ["omega_deg", "phi_deg", "kappa_deg"]
        if has_pos.any():
            cols += ["sd_X0", "sd_Y0", "sd_Z0"]
        if has_att.any():
            cols += ["sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"]
        rows = []
        for k, (pid, p) in enumerate(photos):
            r: list[Any] = [pid, cam.id, relative_path(p, folder)]
            for arr, ok, what, digits in ((pos, has_pos, "X0", 4), (att, has_att, "omega_deg", 7),
                                          (sdp, has_pos, "sd_X0", 0), (sda, has_att, "sd_omega_deg", 0)):
                if what in cols:   # 0.1 mm, 1e-7 degree (sds: 6 digits)
                    r += [(round(float(v), digits) + 0.0 if digits else float(f"{v:.6g}")) for v in arr[k]] \
                        if ok[k] else ["", "", ""]
            rows.append(r)
        write_csv_atomic(tmp / "photos.csv", cols, rows, comments=[
            "written by lidarcat init: image relative to this folder; X0..kappa_deg the approximate orientation "
            "(m, degrees, M = R3(kappa) R2(phi) R1(omega)) with its sds"])
        write_csv_atomic(tmp / "image_points.csv", ["photo", "point", "col_px", "row_px"], [], comments=[
            "no observation yet: `lidarcat match` measures the tie points"])
        files = ['camera = "camera.toml"', 'photos = "photos.csv"', 'image_points = "image_points.csv"']
        if lidar_rel:
            files.append("lidar = [" + ", ".join(_toml(t) for t in lidar_rel) + "]")
        write_text_atomic(tmp / "survey.toml", (
            f"# written by lidarcat init from {_toml(str(images))}\n[survey]\nname = {_toml(name)}\n"
            f"crs = {_toml(crs)}\nheight_system = {_toml(hsys)}\n\n[files]\n" + "\n".join(files) + "\n"))
    return InitResult(folder, crs, cam.id, cam_source, tuple(ids),
                      tuple(i for i, h in zip(ids, has_pos) if h), tuple(i for i, h in zip(ids, has_att) if h),
                      without, lidar_rel, tuple(notes))


def _check_crs(crs: str, pos: np.ndarray, ids: list[str]) -> None:
    """The survey CRS must be projected, in metres, and hold the positions in its area of use (as
    ``Survey.load`` checks)."""
    from ..lidar.crs import check_area_of_use, require_metres, resolve_crs

    c = resolve_crs(crs)
    require_metres(c, "the adjustment")
    ok = np.isfinite(pos[:, :2]).all(axis=1)
    if ok.any():
        check_area_of_use(c, pos[ok, :2], ids=np.array(ids)[ok])
