"""The in-memory block every reader fills and every writer drains, and its survey folder.

A :class:`Block` holds what the formats have in common: cameras
(:class:`lidarcat.geometry.camera.Camera`), photos with exterior orientations in
lidarcat's convention (:mod:`lidarcat.interop.rotations`), image observations
(pixels with the origin at the centre of the top-left pixel, and/or corrected
photo coordinates in mm, x right, y up), object points and ground control.

:func:`write_survey` turns a block into a survey folder (``docs/survey-format.md``),
atomically; :func:`block_from_survey` builds a block from a survey folder and,
optionally, the output folder of ``lidarcat adjust`` (``eop.csv``, ``points.csv``),
which is what the exporters write out.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._util.frozen import frozen_array
from .._util import atomic_dir, read_csv_table, write_csv_atomic, write_json_atomic, write_text_atomic
from ..geometry.camera import Camera
from ..errors import FormatError
from .cameras import pinhole_camera, undistorted_mm
from ._checks import (EO_KINDS, ENH_KINDS, PHOTO_COLUMNS_EO, check_area, check_block, check_crs, check_values,
                      read_source_models)

__all__ = ["Block", "Orientations", "GroundControl", "apply_orientations", "apply_ground_control",
           "write_survey", "block_from_survey",
           "photo_coordinates_mm", "reprojection_residuals_mm", "reprojection_residuals_px",
           "pinhole_camera", "undistorted_mm", "require_orientations", "SOURCE_CAMERAS", "copy_survey_files",
           "check_values", "check_crs", "PHOTO_COLUMNS_EO"]  # the last three re-exported from _checks

log = logging.getLogger(__name__)

#: file of a survey folder keeping the source programs' camera models (see Block.source_models)
SOURCE_CAMERAS = "source_cameras.json"


def _arr(a: Any, shape_tail: tuple[int, ...], dtype: Any = float) -> np.ndarray:
    out = frozen_array(a, dtype=dtype)
    return out.reshape((-1, *shape_tail)) if shape_tail else out.reshape(-1)


@dataclass(frozen=True, eq=False)
class Block:
    """A photogrammetric block read from (or to be written to) another program's files.

    Attributes
    ----------
    name : str
        Survey name.
    crs : str
        CRS of the object coordinates (pyproj string), or a description of a local frame.
    height_system : str
        ``ellipsoidal``, ``orthometric`` or a description (reported in every output).
    cameras : dict[str, Camera]
    photo_ids, photo_camera : ndarray (P,) of str
    eo : ndarray (P, 6)
        X0, Y0, Z0 (m), omega, phi, kappa (rad, ``M = R3 R2 R1`` object to image);
        NaN where unknown.
    obs_photo, obs_point : ndarray (n,) of str
    obs_px : ndarray (n, 2)
        Pixel column, row; origin at the centre of the top-left pixel; NaN if unknown.
    obs_mm : ndarray (n, 2)
        Corrected photo coordinates x, y (mm, x right, y up, principal point origin,
        distortion removed); NaN if unknown (then derived from ``obs_px`` by the camera).
    point_ids : ndarray (Q,) of str
    points_m : ndarray (Q, 3)
        Object coordinates of the points (NaN if unknown).
    ground_ids : ndarray (G,) of str
    ground_m, ground_sd_m : ndarray (G, 3)
        Reference coordinates of control/check points and their sds (m).
    ground_source : ndarray (G,) of str
    eo_sd : ndarray (P, 6) or None
        Sds of ``eo`` (m, rad) when they are measurements (GNSS/IMU) to be used as
        weighted constraints.
    description : str
        Provenance (source program and file), conventions applied.
    source_models : dict[str, dict]
        Camera id -> the source program's model in pixels (:func:`pinhole_camera`):
        ``fx, fy, cx, cy`` (pixels, origin at the image *corner*), ``w, h``,
        ``dist`` (k1..k6, p1, p2) and ``kind`` (``"brown"`` or ``"metashape"``).
        Kept in the survey folder as ``source_cameras.json`` so that an export
        writes the distortion model back.  A fisheye (``kind`` ``"fisheye"``,
        ``"metashape_fisheye"``) the same way (:mod:`lidarcat.interop.cameras`).
    obs_sd_mm : ndarray (n, 2) or None
        Sds of ``obs_mm`` where the source camera gives them their own (a fisheye's image-plane
        observations, :func:`lidarcat.interop.cameras.ideal_observations`); NaN: the survey's default.
    rigs : RigSet or None
        Multi-camera rigs and their exposures (:mod:`lidarcat.interop.rigs`), kept in the
        survey folder as ``rigs.json``.
    """

    name: str
    crs: str
    height_system: str
    cameras: dict[str, Camera]
    photo_ids: np.ndarray
    photo_camera: np.ndarray
    eo: np.ndarray
    obs_photo: np.ndarray
    obs_point: np.ndarray
    obs_px: np.ndarray
    obs_mm: np.ndarray
    point_ids: np.ndarray = field(default_factory=lambda: np.empty(0, str))
    points_m: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    ground_ids: np.ndarray = field(default_factory=lambda: np.empty(0, str))
    ground_m: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    ground_sd_m: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    ground_source: np.ndarray = field(default_factory=lambda: np.empty(0, str))
    eo_sd: np.ndarray | None = None
    description: str = ""
    source_models: dict[str, dict] = field(default_factory=dict)
    rigs: Any = None
    obs_sd_mm: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("photo_ids", "photo_camera", "obs_photo", "obs_point", "point_ids",
                     "ground_ids", "ground_source"):
            object.__setattr__(self, name, _arr(getattr(self, name), (), str))
        for name, tail in (("eo", (6,)), ("obs_px", (2,)), ("obs_mm", (2,)), ("points_m", (3,)),
                           ("ground_m", (3,)), ("ground_sd_m", (3,))):
            object.__setattr__(self, name, _arr(getattr(self, name), tail))
        if self.eo_sd is not None:
            object.__setattr__(self, "eo_sd", _arr(self.eo_sd, (6,)))
        if self.obs_sd_mm is not None:
            object.__setattr__(self, "obs_sd_mm", _arr(self.obs_sd_mm, (2,)))
            if len(self.obs_sd_mm) != len(self.obs_photo):
                raise ValueError("Block: obs_* need one row per observation (obs_sd_mm)")
        if len(self.eo) != len(self.photo_ids) or len(self.photo_camera) != len(self.photo_ids):
            raise ValueError("Block: eo and photo_camera need one row per photo")
        n = len(self.obs_photo)
        if not (len(self.obs_point) == len(self.obs_px) == len(self.obs_mm) == n):
            raise ValueError("Block: obs_* need one row per observation")
        if len(self.points_m) != len(self.point_ids):
            raise ValueError("Block: points_m needs one row per point id")

    @property
    def n_photos(self) -> int:
        return len(self.photo_ids)

    def photo_index(self) -> dict[str, int]:
        return {p: i for i, p in enumerate(self.photo_ids.tolist())}

    def point(self, ids: np.ndarray) -> np.ndarray:
        """Object coordinates (k, 3) of point ids (NaN for points without coordinates)."""
        pos = {p: i for i, p in enumerate(self.point_ids.tolist())}
        pts = np.vstack([self.points_m, np.full((1, 3), np.nan)])
        return pts[np.array([pos.get(p, -1) for p in np.asarray(ids).tolist()], dtype=np.intp)]

    def with_(self, **changes: Any) -> Block:
        """A copy with some fields replaced."""
        return replace(self, **changes)


def _photo_eo(photos) -> tuple[np.ndarray, np.ndarray]:
    """(P, 6) orientations and sds (m, rad; NaN where absent) of survey photos."""
    eo = np.full((len(photos), 6), np.nan)
    esd = np.full((len(photos), 6), np.nan)
    for k, ph in enumerate(photos):
        for arr, pos, att in ((eo, ph.position_m, ph.attitude_deg), (esd, ph.sd_position_m, ph.sd_attitude_deg)):
            if pos is not None:
                arr[k, :3] = pos
            if att is not None:
                arr[k, 3:] = np.radians(att)
    return eo, esd


def require_orientations(block: Block, program: str) -> None:
    """Raise :class:`FormatError` naming the first photo without a complete orientation."""
    missing = [p for p, e in zip(block.photo_ids.tolist(), block.eo) if not np.isfinite(e).all()]
    if missing:
        raise FormatError(f"photo {missing[0]!r} has no complete orientation, which {program} needs "
                          f"(export an adjusted block: lidarcat adjust, then export its output folder)")


def photo_coordinates_mm(block: Block) -> np.ndarray:
    """Corrected photo coordinates (n, 2), mm, of every observation: ``obs_mm`` where given,
    else ``obs_px`` through the photo's camera (eq. 01-07)."""
    out = np.array(block.obs_mm, dtype=float)
    need = ~np.isfinite(out).all(axis=1)
    if need.any():
        cam_of = dict(zip(block.photo_ids.tolist(), block.photo_camera.tolist()))
        cams = np.array([cam_of[p] for p in block.obs_photo.tolist()], dtype=str)
        for cid in np.unique(cams[need]):
            rows = need & (cams == cid)
            out[rows] = block.cameras[cid].pixel_to_photo(block.obs_px[rows])
    return out


def _toml_str(s: str) -> str:
    import json

    return json.dumps(s, ensure_ascii=False)


def write_survey(block: Block, folder: str | Path, *, image_sd_mm: float | None = None,
                 control_sd_m: float | None = None, overwrite: bool = False) -> Path:
    """Write *block* as a survey folder (``docs/survey-format.md``), atomically.

    ``photos.csv`` gets the orientations as approximations (and their sds when
    ``block.eo_sd`` is given: weighted constraints with ``lidarcat adjust
    --eo-constraints``); ``image_points.csv`` gets ``col_px, row_px`` and/or
    ``x_mm, y_mm`` (then ``observations = "corrected"``); ground points, when
    present, go to ``ground_points.csv`` and a control set ``imported`` (all of
    them as control).  A block without ground points (COLMAP, OpenSfM models) can
    give its model points as control with ``control_sd_m`` (sd of E, N and h, in
    model units): the re-adjustment then keeps the model's datum.  Observations of
    points seen on a single photo that are no
    ground point are dropped (the survey format refuses them; logged).  A block
    without any observation (an orientation-only OpenSfM reconstruction as
    OpenDroneMap writes it, a Metashape chunk without markers, a Borea block
    without ``.mes``) is written with a header-only ``image_points.csv``, the state
    ``lidarcat init`` leaves: it loads, exports, and ``lidarcat adjust`` asks for
    ``lidarcat match`` first.

    Raises
    ------
    FormatError
        *folder* exists and holds a survey.toml while *overwrite* is False, the
        block has no photo, or it has observations but none usable (of a ground
        point or of a point on two photos).
    """
    folder = Path(folder)
    if control_sd_m is not None and len(block.ground_ids) == 0:
        if not control_sd_m > 0:
            raise FormatError(f"control_sd_m must be positive, got {control_sd_m!r}")
        ok = np.isfinite(block.points_m).all(axis=1)
        block = block.with_(ground_ids=block.point_ids[ok], ground_m=block.points_m[ok],
                            ground_sd_m=np.full((int(ok.sum()), 3), float(control_sd_m)),
                            ground_source=np.full(int(ok.sum()), "model"))
    if (folder / "survey.toml").exists() and not overwrite:
        raise FormatError(f"{folder}: already holds a survey.toml; choose another folder or "
                          f"pass overwrite (--force)")
    if block.n_photos == 0:
        raise FormatError(f"{block.name}: nothing to write: no photos; give the file that holds the photos' "
                          f"orientations")
    check_block(block)
    if block.crs.strip() in ("", "unspecified"):  # survey.toml needs a CRS or a local frame
        log.warning("%s: no CRS given; the survey's frame is written as local (give --crs to georeference)",
                    block.name)
        block = block.with_(crs="local: unspecified frame (no CRS given on import)")
    ground = set(block.ground_ids.tolist())
    counts = Counter(block.obs_point.tolist())
    keep = np.array([counts[p] >= 2 or p in ground for p in block.obs_point.tolist()], dtype=bool)
    if (~keep).any():
        log.info("%d observation(s) of points seen on one photo only dropped", int((~keep).sum()))
    if len(keep) and not keep.any():
        raise FormatError(f"{block.name}: no measurements: none of its {len(keep)} image measurement(s) is of a "
                          f"ground point or of a point seen on two photos; give the complete measurement file")
    has_mm = bool(np.isfinite(block.obs_mm[keep]).all(axis=1).any())
    # no observation at all (an orientation-only model): the header of `lidarcat init`, pixel columns
    has_px = bool(np.isfinite(block.obs_px[keep]).all(axis=1).any()) or not keep.any()
    has_sd = block.obs_sd_mm is not None and bool(np.isfinite(block.obs_sd_mm[keep]).any())
    cols = (["photo", "point"] + (["col_px", "row_px"] if has_px else []) + (["x_mm", "y_mm"] if has_mm else [])
            + (["sd_x_mm", "sd_y_mm"] if has_sd else []))
    rows = []
    for i in np.flatnonzero(keep):
        r: list[Any] = [block.obs_photo[i], block.obs_point[i]]
        if has_px:
            r += list(block.obs_px[i])
        if has_mm:
            r += list(block.obs_mm[i])
        if has_sd:
            r += list(block.obs_sd_mm[i])  # type: ignore[index]
        rows.append(r)
    with atomic_dir(folder) as tmp:
        write_text_atomic(tmp / "camera.toml", "\n".join(c.to_toml() for c in block.cameras.values()))
        if block.source_models:
            write_json_atomic(tmp / SOURCE_CAMERAS, block.source_models)
        exposure_of: dict[str, str] = {}
        rig_toml = False
        if block.rigs is not None:
            from .rigs import RIGS_FILE, RIGS_TOML, check_rigs, rigs_to_json, survey_reads_rig_files, survey_rig_file

            check_rigs(block.rigs, block, block.name)
            write_json_atomic(tmp / RIGS_FILE, rigs_to_json(block.rigs))
            if survey_reads_rig_files():
                made = survey_rig_file(block.rigs)
                if isinstance(made, str):
                    log.warning("%s: the rigs are kept in %s only, not as the survey's rig file: %s", block.name,
                                RIGS_FILE, made)
                else:
                    write_text_atomic(tmp / RIGS_TOML, made[0])
                    exposure_of, rig_toml = made[1], True
        pcols = ["photo", "camera"]
        known = np.isfinite(block.eo)
        if known[:, :3].any():
            pcols += ["X0", "Y0", "Z0"]
        if known[:, 3:].any():
            pcols += ["omega_deg", "phi_deg", "kappa_deg"]
        if block.eo_sd is not None:
            pcols += ["sd_X0", "sd_Y0", "sd_Z0", "sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"]
        if rig_toml:
            pcols.append("rig_exposure")
        prow = []
        for i, pid in enumerate(block.photo_ids.tolist()):
            r = [pid, block.photo_camera[i]]
            if "X0" in pcols:
                r += list(block.eo[i, :3])
            if "omega_deg" in pcols:
                r += list(np.degrees(block.eo[i, 3:]))
            if block.eo_sd is not None:
                r += list(block.eo_sd[i, :3]) + list(np.degrees(block.eo_sd[i, 3:]))
            if rig_toml:
                r.append(exposure_of.get(pid, ""))
            prow.append(r)
        write_csv_atomic(tmp / "photos.csv", pcols, prow)
        write_csv_atomic(tmp / "image_points.csv", cols, rows)
        files = ['camera = "camera.toml"', 'photos = "photos.csv"', 'image_points = "image_points.csv"']
        if rig_toml:
            files.append('rigs = "rigs.toml"')
        survey_extra = ""
        if len(block.ground_ids):
            write_csv_atomic(tmp / "ground_points.csv",
                             ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                             [[p, *x, *s, src] for p, x, s, src in zip(
                                 block.ground_ids, block.ground_m, block.ground_sd_m, block.ground_source)])
            write_csv_atomic(tmp / "control_sets.csv", ["set", "point", "role"],
                             [["imported", p, "control"] for p in block.ground_ids])
            files += ['ground_points = "ground_points.csv"', 'control_sets = "control_sets.csv"']
            survey_extra = 'default_control = "imported"\n'
        adj = [f'observations = "{"corrected" if has_mm else "pixel"}"']
        if image_sd_mm is not None:
            adj.append(f"image_sd_mm = {float(image_sd_mm)!r}")
        toml = (f"# written by lidarcat import\n[survey]\nname = {_toml_str(block.name)}\n"
                f"description = {_toml_str(block.description)}\ncrs = {_toml_str(block.crs)}\n"
                f"height_system = {_toml_str(block.height_system)}\n{survey_extra}\n"
                "[files]\n" + "\n".join(files) + "\n\n[adjustment]\n" + "\n".join(adj) + "\n")
        write_text_atomic(tmp / "survey.toml", toml)
    log.info("wrote survey %s: %d photos, %d observations", folder, block.n_photos, len(rows))
    return folder


def block_from_survey(survey: Any = None, adjustment: str | Path | None = None) -> Block:
    """The block of a survey folder, with the adjusted orientations and points of *adjustment*.

    Parameters
    ----------
    survey : Survey, path or None
        The survey (None: the embedded thesis block).
    adjustment : path, optional
        Output folder of ``lidarcat adjust`` (``eop.csv`` and ``points.csv``);
        without it the orientations of ``photos.csv`` and the ground points are used.

    Raises
    ------
    SurveyError
        Invalid survey or adjustment files (located).
    """
    from ..survey.folder import Survey

    if not isinstance(survey, Survey):
        survey = Survey.load(survey)
    ip = survey.image_points
    excluded = np.isin(ip.point, list(survey.settings.exclude_points))
    photo_ids = np.array([p.id for p in survey.photos], dtype=str)
    eo, _ = _photo_eo(survey.photos)
    gp = survey.ground_points
    point_ids, points = gp.point, gp.enh_m
    if adjustment is not None:
        adj = Path(adjustment)
        t = read_csv_table(adj / "eop.csv", required=("photo", "X0", "Y0", "Z0", "omega", "phi", "kappa"),
                           allow_extra=True)
        pos = {p: i for i, p in enumerate(photo_ids.tolist())}
        vals = np.column_stack([t.floats(c) for c in ("X0", "Y0", "Z0", "omega", "phi", "kappa")])
        for pid, v in zip(t.column("photo"), vals):
            if pid in pos:
                eo[pos[pid]] = np.concatenate([v[:3], np.radians(v[3:])])
        tp = read_csv_table(adj / "points.csv", required=("point", "E", "N", "h"), allow_extra=True)
        point_ids = np.array(tp.column("point"), dtype=str)
        points = np.column_stack([tp.floats(c) for c in ("E", "N", "h")])
    obs_mm = np.full((len(ip), 2), np.nan)
    if survey.settings.observations == "corrected":
        obs_mm = np.array(ip.xy_mm, dtype=float)
    keep = ~excluded
    source_models = {}
    side = survey.root / SOURCE_CAMERAS
    if side.is_file():
        source_models = read_source_models(side, survey.cameras)
    rigs = None
    from .rigs import RIGS_FILE

    if (survey.root / RIGS_FILE).is_file():
        from .rigs import read_rigs_json

        rigs = read_rigs_json(survey.root / RIGS_FILE)
    else:  # a survey's own rig file (survey.toml [files] rigs), made by hand
        from .rigs import rigs_from_survey

        rigs = rigs_from_survey(survey)
    blk = Block(
        name=survey.name, crs=survey.crs, height_system=survey.height_system,
        cameras=dict(survey.cameras), photo_ids=photo_ids,
        photo_camera=np.array([p.camera for p in survey.photos], dtype=str), eo=eo,
        obs_photo=ip.photo[keep], obs_point=ip.point[keep], obs_px=ip.pixel_px[keep],
        obs_mm=obs_mm[keep], point_ids=point_ids, points_m=points,
        ground_ids=gp.point, ground_m=gp.enh_m, ground_sd_m=gp.sd_m, ground_source=gp.source,
        description=survey.description, source_models=source_models, rigs=rigs)
    if rigs is not None:
        from .rigs import check_rigs

        check_rigs(rigs, blk, str(survey.root / RIGS_FILE))
    return blk


def reprojection_residuals_mm(block: Block) -> np.ndarray:
    """Image residuals (n, 2), projected minus observed photo coordinates, mm (x right, y up).

    Every observation is projected with its photo's orientation ``block.eo`` and
    its point's ``block.points_m`` through the collinearity equations
    (:mod:`lidarcat.geometry.collinearity`); NaN where a photo or point is unknown.
    """
    from ..geometry.collinearity import project

    idx = block.photo_index()
    pi = np.array([idx[p] for p in block.obs_photo.tolist()], dtype=np.intp)
    focal = np.array([block.cameras[c].focal_length_mm for c in block.photo_camera.tolist()])[pi]
    xy, _ = project(block.eo[pi], block.point(block.obs_point), focal)
    return xy - photo_coordinates_mm(block)


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
        object.__setattr__(self, "photo", _arr(self.photo, (), str))
        object.__setattr__(self, "eo", _arr(self.eo, (6,)))
        object.__setattr__(self, "eo_sd", _arr(self.eo_sd, (6,)))
        cam = np.full(n, "") if self.camera is None else self.camera
        object.__setattr__(self, "camera", _arr(cam, (), str))
        line = np.zeros(n, np.int64) if self.line is None else self.line
        object.__setattr__(self, "line", _arr(line, (), np.int64))

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
    eo, esd = _photo_eo(survey.photos)
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
            object.__setattr__(self, name, _arr(getattr(self, name), (), str))
        object.__setattr__(self, "enh_m", _arr(self.enh_m, (3,)))
        object.__setattr__(self, "obs_px", _arr(self.obs_px, (2,)))
        line = np.zeros(len(self.obs_point), np.int64) if self.obs_line is None else self.obs_line
        object.__setattr__(self, "obs_line", _arr(line, (), np.int64))


def _toml_with_files(text: str, keys: dict[str, str]) -> str:
    """survey.toml text with ``key = "value"`` lines added to ``[files]`` where missing."""
    import tomllib

    have = tomllib.loads(text).get("files", {})
    add = [f"{k} = {_toml_str(v)}" for k, v in keys.items() if k not in have]
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


def reprojection_residuals_px(block: Block) -> np.ndarray:
    """Image residuals (n, 2) in the source program's pixels: projected minus observed column,
    row (y down), the projection going through the source camera model (distortion included, a
    fisheye's too: :func:`lidarcat.interop.cameras.project_corner_px`) where ``block.source_models``
    has one, else through lidarcat's pinhole (``obs_mm`` in pixels).
    """
    from .cameras import project_corner_px
    from .rotations import opk_to_world_to_cv

    idx = block.photo_index()
    pi = np.array([idx[p] for p in block.obs_photo.tolist()], dtype=np.intp)
    cams = block.photo_camera[pi]
    r = opk_to_world_to_cv(block.eo[:, 3:])[pi]
    v = np.einsum("nij,nj->ni", r, block.point(block.obs_point) - block.eo[pi, :3])
    out = np.full((len(pi), 2), np.nan)
    mm = photo_coordinates_mm(block)
    for cid in np.unique(cams):
        rows = cams == cid
        m = block.source_models.get(str(cid))
        if m is None:
            c = block.cameras[str(cid)]
            fx, fy = c.focal_length_mm / c.pixel_size_x_mm, c.focal_length_mm / c.pixel_size_y_mm
            xn = v[rows, :2] / v[rows, 2:3]
            out[rows] = xn * [fx, fy] - mm[rows] / [c.pixel_size_x_mm, -c.pixel_size_y_mm]
            continue
        out[rows] = project_corner_px(v[rows], m, str(cid)) - (block.obs_px[rows] + 0.5)
    return out
