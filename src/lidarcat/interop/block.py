"""The in-memory block every reader fills and every writer drains, and its survey folder.

A :class:`Block` holds what the formats have in common: cameras
(:class:`lidarcat.geometry.camera.Camera`), photos with exterior orientations in
lidarcat's convention (:mod:`lidarcat.interop.rotations`), image observations
(pixels with the origin at the centre of the top-left pixel, and/or corrected
photo coordinates in mm, x right, y up), object points and ground control.

:func:`write_survey` turns a block into a survey folder (``docs/survey-format.md``),
atomically; :func:`block_from_survey` builds a block from a survey folder and,
optionally, the output folder of ``lidarcat adjust`` (``eop.csv``, ``points.csv``),
which is what the exporters write out.  The source programs' cameras (stand-in pinhole, ideal
observations) are in :mod:`lidarcat.interop.cameras`, the rigs in :mod:`lidarcat.interop.rigs`, the
merging of orientation and GCP files into a survey in :mod:`lidarcat.interop.merge` (their names
re-exported here).
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .._util import atomic_dir, read_csv_table, write_csv_atomic, write_json_atomic, write_text_atomic
from ..geometry.camera import Camera
from ..errors import FormatError
from .cameras import pinhole_camera, undistorted_mm
from ._checks import (PHOTO_COLUMNS_EO, check_block, check_crs, check_values, frozen_rows, photo_eo,
                      read_source_models, toml_string)
from .merge import (GroundControl, Orientations, apply_ground_control, apply_orientations,
                    copy_survey_files)

__all__ = ["Block", "Orientations", "GroundControl", "apply_orientations", "apply_ground_control",
           "write_survey", "block_from_survey",
           "photo_coordinates_mm", "reprojection_residuals_mm", "reprojection_residuals_px",
           "pinhole_camera", "undistorted_mm", "require_orientations", "SOURCE_CAMERAS", "copy_survey_files",
           "check_values", "check_crs", "PHOTO_COLUMNS_EO"]  # the last three re-exported from _checks; Orientations,
# GroundControl, apply_orientations, apply_ground_control, copy_survey_files from .merge

log = logging.getLogger(__name__)

#: file of a survey folder keeping the source programs' camera models (see Block.source_models)
SOURCE_CAMERAS = "source_cameras.json"


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
            object.__setattr__(self, name, frozen_rows(getattr(self, name), (), str))
        for name, tail in (("eo", (6,)), ("obs_px", (2,)), ("obs_mm", (2,)), ("points_m", (3,)),
                           ("ground_m", (3,)), ("ground_sd_m", (3,))):
            object.__setattr__(self, name, frozen_rows(getattr(self, name), tail))
        if self.eo_sd is not None:
            object.__setattr__(self, "eo_sd", frozen_rows(self.eo_sd, (6,)))
        if self.obs_sd_mm is not None:
            object.__setattr__(self, "obs_sd_mm", frozen_rows(self.obs_sd_mm, (2,)))
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
        toml = (f"# written by lidarcat import\n[survey]\nname = {toml_string(block.name)}\n"
                f"description = {toml_string(block.description)}\ncrs = {toml_string(block.crs)}\n"
                f"height_system = {toml_string(block.height_system)}\n{survey_extra}\n"
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
    eo, _ = photo_eo(survey.photos)
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
