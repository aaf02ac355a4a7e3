"""Merging orientation and ground-control files into a copy of a survey folder.

:class:`Orientations` (photo orientations of an OPK, GNSS/IMU or ODM ``geo.txt`` file) and
:class:`GroundControl` (ground points with image measurements of an ODM ``gcp_list.txt`` or OpenSfM
``ground_control_points.json``) are what those readers give; :func:`apply_orientations` and
:func:`apply_ground_control` write a copy of a survey folder with them merged in, atomically, with
every value checked as :func:`lidarcat.interop.block.write_survey` checks it.  (Split from
:mod:`lidarcat.interop.block`, which re-exports these names.)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, read_csv_table, write_csv_atomic, write_text_atomic
from ..errors import FormatError
from ._checks import (EO_KINDS, ENH_KINDS, PHOTO_COLUMNS_EO, check_area, check_values, frozen_rows, photo_eo,
                      toml_string)

__all__ = ["Orientations", "GroundControl", "apply_orientations", "apply_ground_control", "copy_survey_files"]

log = logging.getLogger(__name__)


# ---------------------------------------------------------------------- orientation files
@dataclass(frozen=True, eq=False)
class Orientations:
    """Photo orientations read from an orientation or GNSS/IMU file.

    Attributes
    ----------
    photo : ndarray (P,) of str
        Photo names as in the file.
    eo : ndarray (P, 6)
        X0, Y0, Z0 (m, in ``crs``), omega, phi, kappa (rad, lidarcat convention);
        NaN where the file gives no value (e.g. no attitude).
    eo_sd : ndarray (P, 6)
        Standard deviations (m, rad) when the file gives them, else NaN.
    crs, height_system : str
    source : str
        File and conventions applied (angle unit, yaw/pitch/roll conversion).
    camera : ndarray (P,) of str
        Camera name per photo when the file gives one (else empty strings).
    line : ndarray (P,) of int
        Line of each photo in the file (for messages).
    """

    photo: np.ndarray
    eo: np.ndarray
    eo_sd: np.ndarray
    crs: str
    height_system: str
    source: str
    camera: np.ndarray | None = None
    line: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.photo)
        object.__setattr__(self, "photo", frozen_rows(self.photo, (), str))
        object.__setattr__(self, "eo", frozen_rows(self.eo, (6,)))
        object.__setattr__(self, "eo_sd", frozen_rows(self.eo_sd, (6,)))
        cam = np.full(n, "") if self.camera is None else self.camera
        object.__setattr__(self, "camera", frozen_rows(cam, (), str))
        line = np.zeros(n, np.int64) if self.line is None else self.line
        object.__setattr__(self, "line", frozen_rows(line, (), np.int64))

    def __len__(self) -> int:
        return len(self.photo)


def _match_photos(names: list[str], survey_ids: list[str]) -> dict[str, str]:
    """File photo name -> survey photo id: exact, else the same name without extension."""
    ids = set(survey_ids)
    stem = {}
    for s in survey_ids:
        stem.setdefault(Path(s).stem, s)
    out = {}
    for n in names:
        if n in ids:
            out[n] = n
        elif Path(n).stem in ids:
            out[n] = Path(n).stem
        elif Path(n).stem in stem:
            out[n] = stem[Path(n).stem]
    return out


def apply_orientations(survey: Any, orientations: Orientations, folder: str | Path, *,
                       sd_position_m: float | None = None, sd_attitude_deg: float | None = None,
                       overwrite: bool = False) -> Path:
    """Copy a survey folder to *folder* with the orientations written into its photos.csv.

    The values become approximations; with standard deviations (from the file or
    *sd_position_m* / *sd_attitude_deg*, which take precedence) they become weighted
    constraints for ``lidarcat adjust --eo-constraints``.  Photos are matched by
    id, else by name without extension; survey photos absent from the file keep
    their old values.  The survey CRS must equal ``orientations.crs`` unless that
    is unspecified.

    Raises
    ------
    FormatError
        No photo of the file is in the survey (names the first), CRS mismatch, or
        *folder* holds a survey and *overwrite* is False.
    """
    survey = _load_target(survey, folder, overwrite)
    if orientations.crs not in ("", "unspecified") and orientations.crs != survey.crs:
        raise FormatError(f"{orientations.source}: coordinates are in {orientations.crs}, the survey "
                          f"{survey.root} in {survey.crs}; convert them first (give --crs {survey.crs})")
    ids = [p.id for p in survey.photos]
    match = _match_photos(orientations.photo.tolist(), ids)
    if not match:
        raise FormatError(f"{orientations.source}: none of its {len(orientations)} photos "
                          f"({orientations.photo[0]!r}, ...) is a photo of {survey.files.get('photos')}")
    unmatched = [p for p in orientations.photo.tolist() if p not in match]
    if unmatched:
        log.warning("%s: %d photo(s) not in the survey, ignored: %s", orientations.source,
                    len(unmatched), ", ".join(unmatched[:5]))
    sd = np.array(orientations.eo_sd, dtype=float)
    if sd_position_m is not None:
        sd[:, :3] = sd_position_m
    if sd_attitude_deg is not None:
        sd[:, 3:] = np.radians(sd_attitude_deg)
    where = orientations.source.split(" (", 1)[0]
    check_values(where, "photo", orientations.photo,
                 np.column_stack([orientations.eo[:, :3], np.degrees(orientations.eo[:, 3:])]), EO_KINDS,
                 PHOTO_COLUMNS_EO, orientations.line)
    check_values(where, "photo", orientations.photo,
                 np.column_stack([sd[:, :3], np.degrees(sd[:, 3:])]), ("sd_m",) * 3 + ("sd_deg",) * 3,
                 tuple(f"sd_{n}" for n in PHOTO_COLUMNS_EO), orientations.line)
    check_area(where, "photo", survey.crs, orientations.photo, orientations.eo[:, :2], orientations.line)
    row_of = {match[p]: i for i, p in enumerate(orientations.photo.tolist()) if p in match}
    eo, esd = photo_eo(survey.photos)
    for k, ph in enumerate(survey.photos):
        if ph.id in row_of:
            i = row_of[ph.id]
            have = np.isfinite(orientations.eo[i])
            eo[k, have] = orientations.eo[i, have]
            esd[k, :] = np.where(np.isfinite(sd[i]), sd[i], esd[k])
    photos_path = survey.files["photos"]
    photos_rel = photos_path.relative_to(survey.root) if photos_path.is_relative_to(survey.root) else None
    if photos_rel is None:
        raise FormatError(f"{survey.files['photos']}: photos.csv lies outside the survey folder; "
                          f"copy it in first")
    images = any(ph.image is not None for ph in survey.photos)   # the photos.csv image column, kept
    cols = ["photo", "camera"] + (["image"] if images else [])
    groups = [(["X0", "Y0", "Z0"], eo[:, :3], 1.0), (["omega_deg", "phi_deg", "kappa_deg"], eo[:, 3:], None),
              (["sd_X0", "sd_Y0", "sd_Z0"], esd[:, :3], 1.0),
              (["sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"], esd[:, 3:], None)]
    used = [g for g in groups if np.isfinite(g[1]).all(axis=1).any()]
    for names, _, _ in used:
        cols += names
    # photos.csv's other columns (a rig exposure, an exposure time) stay as they are
    old = read_csv_table(photos_path, required=("photo",), allow_extra=True)
    written = {"photo", "camera", "image", *PHOTO_COLUMNS_EO} | {f"sd_{n}" for n in PHOTO_COLUMNS_EO}
    keep_cols = [c for c in old.header if c not in written]
    kept = {pid: [old.column(c)[i] for c in keep_cols] for i, pid in enumerate(old.column("photo"))}
    cols += keep_cols
    rows = []
    for k, ph in enumerate(survey.photos):
        r: list[Any] = [ph.id, ph.camera]
        if images:
            from ..survey.folder import relative_path

            r.append("" if ph.image is None else relative_path(ph.image, Path(folder) / photos_rel.parent))
        for _, vals, unit in used:
            v = vals[k] if np.isfinite(vals[k]).all() else np.full(3, np.nan)
            r += list(v if unit else np.degrees(v))
        r += kept.get(ph.id, [""] * len(keep_cols))
        rows.append(r)
    with atomic_dir(folder) as tmp:
        copy_survey_files(survey, tmp, skip={photos_rel})
        write_csv_atomic(tmp / photos_rel, cols, rows,
                         comments=[f"orientations from {orientations.source}; CRS {orientations.crs}, "
                                   f"heights {orientations.height_system}; omega, phi, kappa in degrees, "
                                   f"M = R3(kappa) R2(phi) R1(omega)"])
    log.info("wrote %s: orientations of %d photo(s) from %s", folder, len(row_of), orientations.source)
    return folder


def _load_target(survey: Any, folder: str | Path, overwrite: bool):
    from ..survey.folder import Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    if (Path(folder) / "survey.toml").exists() and not overwrite:
        raise FormatError(f"{folder}: already holds a survey.toml; choose another folder or "
                          f"pass overwrite (--force)")
    return survey


def copy_survey_files(survey: Any, tmp: Path, skip: set[Path]) -> None:
    """Copy the files of *survey*'s folder (not its ``out/``) into *tmp*, except *skip*.

    Parameters
    ----------
    survey : Survey
        The survey whose folder is copied.
    tmp : Path
        The new folder (the temporary of an :func:`~lidarcat._util.atomic_dir`).
    skip : set of Path
        Paths relative to the survey folder that the caller writes itself.
    """
    import shutil

    for item in survey.root.rglob("*"):
        rel = item.relative_to(survey.root)
        if item.is_file() and rel.parts[0] != "out" and rel not in skip:
            dest = tmp / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(item, dest)


@dataclass(frozen=True, eq=False)
class GroundControl:
    """Ground control points and their image measurements read from a GCP file.

    Attributes
    ----------
    point : ndarray (G,) of str
    enh_m : ndarray (G, 3)
        Coordinates in ``crs`` (m; NaN row for a point without a position).
    crs, height_system : str
    obs_point, obs_photo : ndarray (n,) of str
    obs_px : ndarray (n, 2)
        Pixel column, row, origin at the centre of the top-left pixel.
    source : str
    obs_line : ndarray (n,) of int or None
        Line of each measurement in the file (0: unknown), for messages.
    """

    point: np.ndarray
    enh_m: np.ndarray
    crs: str
    height_system: str
    obs_point: np.ndarray
    obs_photo: np.ndarray
    obs_px: np.ndarray
    source: str
    obs_line: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("point", "obs_point", "obs_photo"):
            object.__setattr__(self, name, frozen_rows(getattr(self, name), (), str))
        object.__setattr__(self, "enh_m", frozen_rows(self.enh_m, (3,)))
        object.__setattr__(self, "obs_px", frozen_rows(self.obs_px, (2,)))
        line = np.zeros(len(self.obs_point), np.int64) if self.obs_line is None else self.obs_line
        object.__setattr__(self, "obs_line", frozen_rows(line, (), np.int64))


def _toml_with_files(text: str, keys: dict[str, str]) -> str:
    """survey.toml text with ``key = "value"`` lines added to ``[files]`` where missing."""
    import tomllib

    have = tomllib.loads(text).get("files", {})
    add = [f"{k} = {toml_string(v)}" for k, v in keys.items() if k not in have]
    if not add:
        return text
    lines = text.splitlines()
    i = next(k for k, ln in enumerate(lines) if ln.strip().startswith("[files]"))
    return "\n".join(lines[:i + 1] + add + lines[i + 1:]) + "\n"


def _check_duplicate_measurements(survey: Any, gcp: GroundControl, keep: np.ndarray, match: dict[str, str],
                                  where: str) -> None:
    """Raise :class:`FormatError` for a point measured twice on one photo: twice in the GCP file
    (two image names of one survey photo count as one photo) or once there and once in the survey."""
    def at(i: int) -> str:
        line = int(gcp.obs_line[i])
        return f"{where}:{line}" if line > 0 else where

    first: dict[tuple[str, str], int] = {}
    for i in np.flatnonzero(keep).tolist():
        key = (match[str(gcp.obs_photo[i])], str(gcp.obs_point[i]))
        if key in first:
            j = first[key]
            also = f"line {int(gcp.obs_line[j])}" if gcp.obs_line[j] > 0 else f"measurement {j + 1}"
            raise FormatError(f"{at(i)}: point {key[1]!r} is measured twice on photo {key[0]!r} (also on "
                              f"{also}); keep one measurement per photo and point, then import again")
        first[key] = i
    ip = survey.image_points
    have = set(zip(ip.photo.tolist(), ip.point.tolist()))
    for key, i in first.items():
        if key in have:
            raise FormatError(f"{at(i)}: point {key[1]!r} is already measured on photo {key[0]!r} in "
                              f"{survey.files.get('image_points')}; remove one of the two measurements, "
                              f"then import again")


def apply_ground_control(survey: Any, gcp: GroundControl, folder: str | Path, *,
                         sd_m: tuple[float, float, float] = (0.05, 0.05, 0.05),
                         set_name: str = "gcp", role: str = "control", source: str = "gcp",
                         overwrite: bool = False) -> Path:
    """Copy a survey folder to *folder* adding ground points, their image measurements and a
    control set *set_name* (all points with *role*), atomically.

    Measurements are matched to photos by id, else by name without extension;
    measurements on other images are dropped (logged).  When the survey's image
    points carry ``x_mm, y_mm`` the new rows get them from the pixels through the
    photo's camera (eq. 01-07).

    Raises
    ------
    FormatError
        CRS mismatch, a GCP id that is already a ground point, no measurement on a
        survey photo, a point measured twice on one photo (in the file, or in the file
        and the survey), or *folder* holds a survey and *overwrite* is False.
    """
    survey = _load_target(survey, folder, overwrite)
    if gcp.crs not in ("", "unspecified") and gcp.crs != survey.crs:
        raise FormatError(f"{gcp.source}: coordinates are in {gcp.crs}, the survey {survey.root} in "
                          f"{survey.crs}; give the survey CRS as target (--crs {survey.crs})")
    clash = sorted(set(gcp.point.tolist()) & set(survey.ground_points.point.tolist()))
    if clash:
        raise FormatError(f"{gcp.source}: point {clash[0]!r} is already a ground point of {survey.root}")
    clash = sorted(set(gcp.point.tolist()) & set(survey.image_points.point.tolist()))
    if clash:
        raise FormatError(f"{gcp.source}: point id {clash[0]!r} is already a measured (tie) point of "
                          f"{survey.root}; rename the GCP")
    ids = [p.id for p in survey.photos]
    match = _match_photos(sorted(set(gcp.obs_photo.tolist())), ids)
    keep = np.array([p in match for p in gcp.obs_photo.tolist()], dtype=bool)
    if not keep.any():
        raise FormatError(f"{gcp.source}: no measurement is on a photo of {survey.root} "
                          f"(first image: {gcp.obs_photo[0] if len(gcp.obs_photo) else '-'!r})")
    if (~keep).any():
        log.warning("%s: %d measurement(s) on images not in the survey dropped", gcp.source, int((~keep).sum()))
    where = gcp.source.split(" (", 1)[0]
    check_values(where, "point", gcp.point, gcp.enh_m, ENH_KINDS, ("E", "N", "h"))
    check_area(where, "point", survey.crs, gcp.point, gcp.enh_m[:, :2])
    check_values(where, "measurement of point", gcp.obs_point, gcp.obs_px, ("pixel_px",) * 2, ("col_px", "row_px"))
    _check_duplicate_measurements(survey, gcp, keep, match, where)
    check_values(where, "point", np.array(["(all)"]), np.array([sd_m], dtype=float), ("sd_m",) * 3,
                 ("sd_E", "sd_N", "sd_h"))
    has_pos = np.isfinite(gcp.enh_m).all(axis=1)
    ip = survey.image_points
    has_mm = bool(np.isfinite(ip.xy_mm).all(axis=1).any())
    cam_of = {p.id: p.camera for p in survey.photos}
    new_photo = np.array([match[p] for p in gcp.obs_photo[keep].tolist()], dtype=str)
    new_px = gcp.obs_px[keep]
    new_mm = np.full_like(new_px, np.nan)
    if has_mm:
        for k, ph in enumerate(new_photo.tolist()):
            new_mm[k] = survey.cameras[cam_of[ph]].pixel_to_photo(new_px[k])
    cols = ["photo", "point", "col_px", "row_px"] + (["x_mm", "y_mm"] if has_mm else [])
    rows = [[a, b, *px] + (list(mm) if has_mm else []) for a, b, px, mm in
            zip(ip.photo.tolist(), ip.point.tolist(), ip.pixel_px, ip.xy_mm)]
    rows += [[a, b, *px] + (list(mm) if has_mm else []) for a, b, px, mm in
             zip(new_photo.tolist(), gcp.obs_point[keep].tolist(), new_px, new_mm)]
    gp = survey.ground_points
    g_rows = [[p, *x, *s, src] for p, x, s, src in zip(gp.point.tolist(), gp.enh_m, gp.sd_m, gp.source.tolist())]
    g_rows += [[p, *x, *sd_m, source] for p, x in zip(gcp.point[has_pos].tolist(), gcp.enh_m[has_pos])]
    c_rows = []
    for name, cs in survey.control_sets.items():
        c_rows += [[name, p, "control", *s] for p, s in zip(cs.control.tolist(), cs.sd_m)]
        c_rows += [[name, p, "check", *s] for p, s in zip(cs.check.tolist(), cs.check_sd_m)]
    if set_name in survey.control_sets:
        raise FormatError(f"{survey.root}: control set {set_name!r} exists already; choose another name")
    c_rows += [[set_name, p, role, np.nan, np.nan, np.nan] for p in gcp.point[has_pos].tolist()]
    rel = {k: (survey.files[k].relative_to(survey.root) if k in survey.files else Path(f"{k}.csv"))
           for k in ("image_points", "ground_points", "control_sets")}
    for k, p in rel.items():
        if p.is_absolute():
            raise FormatError(f"{p}: {k} lies outside the survey folder; copy it in first")
    with atomic_dir(folder) as tmp:
        copy_survey_files(survey, tmp, skip=set(rel.values()) | {Path("survey.toml")})
        write_csv_atomic(tmp / rel["image_points"], cols, rows)
        write_csv_atomic(tmp / rel["ground_points"], ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                         g_rows, comments=[f"ground points; {gcp.source}: CRS {gcp.crs}, heights {gcp.height_system}"])
        write_csv_atomic(tmp / rel["control_sets"], ["set", "point", "role", "sd_E", "sd_N", "sd_h"], c_rows)
        text = survey.toml_path.read_text(encoding="utf-8")
        write_text_atomic(tmp / "survey.toml", _toml_with_files(text, {
            "ground_points": rel["ground_points"].as_posix(), "control_sets": rel["control_sets"].as_posix()}))
    log.info("wrote %s: %d ground points, %d measurements from %s", folder, int(has_pos.sum()),
             int(keep.sum()), gcp.source)
    return folder
