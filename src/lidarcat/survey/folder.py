"""The survey folder: load, validate and locate a photogrammetric project.

A survey folder is a ``survey.toml`` plus CSV files (cameras in TOML, photos,
image measurements, ground points, control sets, LiDAR tile paths); the format
is specified in ``docs/survey-format.md``.  :meth:`Survey.load` reads and
validates everything at once; every problem is a :class:`~lidarcat.errors.SurveyError`
whose message starts with ``file:line: field 'name':`` and says what to fix.

Point ids that are measured on photos but are no ground point are *tie points*
(legal).  An id is "defined nowhere" -- an error -- when it

* is measured on a single photo only and is neither a ground point nor named in
  the extraction-jobs file (it can be no tie point: most likely a typo), or
* appears in ``control_sets.csv`` but not in ``ground_points.csv``, or
* is listed in ``[adjustment] exclude_points`` but measured on no photo and
  defined in no ground point.

The embedded thesis block (Fierro Sanhueza 2007) is the default survey:

>>> s = Survey.load()
>>> len(s.photos), len(s.image_points), len(s.ground_points)
(6, 153, 39)
>>> s.control_set("lidar").control.tolist()
['701', '703', '705', '706', '707', '712', '719', '721']
"""

from __future__ import annotations

import glob
import importlib.resources
import logging
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._util import excerpt, read_csv_table, write_csv_atomic
from ..geometry.camera import Camera
from ..errors import SurveyError, location
from ._tables import (
    PHOTO_COLUMNS,
    ControlSet,
    GroundPoints,
    ImagePoints,
    Photo,
    check_single_photo_points,
    column_ids,
    job_tokens,
    load_control_sets,
    load_ground_points,
    load_image_points,
    load_photos,
)
from .cameras import load_camera, load_cameras
from .decisions import ControlDecisions, read_control_decisions
from .lines import photo_cameras, read_line_control
from .rigs import check_rig_exposures
from .schema import (
    DEFAULT_CONTOUR_INTERVAL_M,
    DEFAULT_SCALE,
    DEFAULT_SD_PIXELS,
    OBSERVATION_KINDS,
    PEC_CLASSES,
    PLOTTING_POSITIONS,
    SD_BOUNDS,
    SURVEY_KEYS,
    AdjustmentSettings,
    AssessmentSettings,
    SurveyConfig,
    check_photo_ids,
    parse_survey_toml,
)

__all__ = [
    "AssessmentSettings",
    "Survey",
    "Photo",
    "ImagePoints",
    "GroundPoints",
    "ControlSet",
    "AdjustmentSettings",
    "CorrectedMeasurements",
    "thesis_survey_path",
    "relative_path",
    "example_camera_path",
    "correct_measurements",
    "cameras_of",
    "SURVEY_KEYS",
    "SurveyConfig",
    "is_local_crs",
    "DEFAULT_SD_PIXELS",
    "DEFAULT_SCALE",
    "DEFAULT_CONTOUR_INTERVAL_M",
    "PEC_CLASSES",
    "PLOTTING_POSITIONS",
    "SD_BOUNDS",
    "MAX_IMAGE_PLANE_ANGLE_DEG",
]

log = logging.getLogger(__name__)

#: a ray of a Brown or fisheye camera farther than this from the optical axis is refused as an observation:
#: the bundle observes image-plane coordinates c (X/Z, -Y/Z), which grow as tan(angle) and whose sd grows as
#: 1 / cos^2(angle) (sd x 33 at 80 deg); at 90 deg there is none (docs/cameras.md, "Cameras in the survey")
MAX_IMAGE_PLANE_ANGLE_DEG = 80.0


def _lens_observations(cam: Camera, px: np.ndarray, sd_mm: np.ndarray, path: Any, line: np.ndarray,
                       photo: str) -> tuple[np.ndarray, np.ndarray]:
    """Photo coordinates and their per-axis sds of the pixels *px* of a Brown/fisheye photo.

    The sd (mm at the pixel, the pitch times the pixel sd) is carried through the model
    (:meth:`~lidarcat.geometry.camera.Camera.photo_sd`: the per-axis sds of ``J Sigma_px J^T``).
    """
    xy = np.asarray(cam.pixel_to_photo(px)).reshape(-1, 2)
    n = xy / cam.focal_length_mm
    with np.errstate(all="ignore"):
        angle = np.degrees(np.arctan(np.hypot(n[:, 0], n[:, 1])))
    far = ~(angle <= MAX_IMAGE_PLANE_ANGLE_DEG)
    if far.any():
        i = int(np.flatnonzero(far)[0])
        seen = "at 90 deg or more" if not np.isfinite(angle[i]) else f"{angle[i]:.1f} deg"
        raise SurveyError(
            f"{location(path, int(line[i]), 'col_px')}: photo {excerpt(photo)}: {int(far.sum())} measurement(s) "
            f"of camera {excerpt(cam.id)} ({cam.model}) see rays more than {MAX_IMAGE_PLANE_ANGLE_DEG:g} deg from "
            f"the optical axis (this one {seen}): the bundle observes image-plane coordinates, which do not "
            f"exist at 90 deg and are too weak beyond; exclude those points ([adjustment] exclude_points) or "
            f"crop the measurements to the central field")
    return xy, cam.photo_sd(px, sd_mm / np.array([cam.pixel_size_x_mm, cam.pixel_size_y_mm]))


def relative_path(path: str | Path, folder: str | Path) -> str:
    """*path* as written into a file of *folder*: relative to it (``../photos/a.jpg``, '/' separators) when
    both are on one drive, else absolute.

    >>> relative_path("/data/flight/photos/a.jpg", "/data/flight/survey")
    '../photos/a.jpg'
    """
    p, f = Path(os.path.abspath(path)), Path(os.path.abspath(folder))
    try:
        return Path(os.path.relpath(p, f)).as_posix()
    except ValueError:   # another drive (Windows)
        return p.as_posix()


def _data_dir(name: str) -> Path:
    """``lidarcat/_data/<name>`` in a wheel, else ``<repo>/data/<name>`` in a source checkout."""
    try:
        res = importlib.resources.files("lidarcat") / "_data" / name
        if res.is_dir():
            return Path(str(res))
    except (ModuleNotFoundError, OSError):  # pragma: no cover - defensive
        pass
    repo = Path(__file__).resolve().parents[3] / "data" / name
    if repo.is_dir():
        return repo
    raise SurveyError(f"embedded data {name!r} not found: neither lidarcat/_data/{name} (wheel) "
                      f"nor {repo} (source checkout) exists; reinstall lidarcat")


def thesis_survey_path() -> Path:
    """Folder of the embedded thesis survey (Fierro Sanhueza 2007, 6 photos).

    Shipped inside the wheel as package data ``lidarcat/_data/thesis``; in an
    editable install or a source checkout it is ``<repo>/data/thesis``.

    >>> (thesis_survey_path() / "survey.toml").is_file()
    True
    """
    return _data_dir("thesis")


def example_camera_path(name: str = "lactec_dcs14n_2008") -> Path:
    """A shipped example calibration, ``lidarcat/_data/cameras/<name>.toml``.

    >>> example_camera_path().name
    'lactec_dcs14n_2008.toml'

    Raises
    ------
    SurveyError
        No such example (lists the available ones).
    """
    folder = _data_dir("cameras")
    path = folder / (name if name.endswith(".toml") else f"{name}.toml")
    if not path.is_file():
        avail = ", ".join(sorted(p.stem for p in folder.glob("*.toml")))
        raise SurveyError(f"no example camera {name!r}; available: {avail}")
    return path


def is_local_crs(crs: str) -> bool:
    """True for a survey CRS declared as a local (not georeferenced) frame: ``"local"`` or
    ``"local: <description>"`` (what ``lidarcat import`` writes for a COLMAP or OpenSfM model
    without georeference).  Such a frame is taken to be in metres; products that need a real CRS
    (GIS layers, LiDAR control) refuse it.

    >>> is_local_crs("local: COLMAP model frame"), is_local_crs("EPSG:31983")
    (True, False)
    """
    s = crs.strip().lower()
    return s == "local" or s.startswith(("local:", "local "))


def _check_crs(t: SurveyConfig, table: str, crs: str, coords: Sequence[tuple[Path | None, np.ndarray, np.ndarray]]
               ) -> None:
    """``[table] crs`` must be a CRS pyproj knows, in metres, and hold the coordinates of
    *coords* ((file, (n, 2) E N, ids) triples) inside its area of use."""
    from ..errors import CRSError
    from ..lidar.crs import check_area_of_use, require_metres, resolve_crs

    if table == "survey" and is_local_crs(crs):
        return  # a local model frame (e.g. an imported SfM model): metres by declaration, no area of use
    try:
        c = resolve_crs(crs)
        require_metres(c, "the adjustment" if table == "survey" else "LiDAR control")
    except CRSError as ex:
        raise t.error(table, "crs", str(ex)) from None
    for path, en, ids in coords:
        en = np.asarray(en, dtype=np.float64).reshape(-1, 2)
        if path is None or len(en) == 0:
            continue
        try:
            check_area_of_use(c, en, ids=ids)
        except CRSError as ex:
            raise t.error(table, "crs", f"{path}: {ex}") from None


def _is_file(t: SurveyConfig, key: str, rel: str, p: Path) -> bool:
    """``p.is_file()``, with a path the system refuses (a name over 255 bytes, a NUL) as a
    located error naming ``[files] key`` instead of an OSError."""
    try:
        return "\x00" not in str(p) and p.is_file()
    except OSError as ex:
        raise t.error("files", key, f"file {excerpt(rel)} cannot be used: {ex.strerror or ex}") from None


def _expand_lidar(t: SurveyConfig, root: Path) -> tuple[Path, ...]:
    out: set[Path] = set()
    for item in t.files.lidar:
        pattern = item if Path(item).is_absolute() else str(root / item)
        if glob.has_magic(item):
            matches = [Path(p) for p in glob.glob(pattern, recursive=True) if _is_file(t, "lidar", item, Path(p))]
            if not matches:
                raise t.error("files", "lidar", f"pattern {excerpt(item)} matches no file in {root}")
            out.update(matches)
        else:
            p = Path(pattern)
            if not _is_file(t, "lidar", item, p):
                raise t.error("files", "lidar", f"LiDAR file {excerpt(item)} not found "
                                                f"({excerpt(str(p), 200, quote=False)})")
            out.add(p)
    return tuple(sorted(out))


# ---------------------------------------------------------------------- Survey
@dataclass(frozen=True, eq=False)
class Survey:
    """A loaded and validated survey folder (see ``docs/survey-format.md``).

    Use :meth:`Survey.load`.  All attributes are read-only.

    Attributes
    ----------
    root : Path
        The survey folder.
    toml_path : Path
        Its survey.toml.
    name, description, crs, height_system : str
    default_control : str or None
    cameras : dict[str, Camera]
    photos : tuple[Photo, ...]
    image_points : ImagePoints
        Every measurement as in the file (excluded points included).
    ground_points : GroundPoints
    control_sets : dict[str, ControlSet]
    lidar_paths : tuple[Path, ...]
        LiDAR tiles, globs expanded, sorted.
    lidar_crs : str or None
    extraction_jobs : Path or None
    settings : AdjustmentSettings
    assessment : AssessmentSettings
        The ``[assessment]`` table (map scale, contour interval, test level).
    embedded : bool
        True for the embedded thesis block (``Survey.load()``).
    files : dict[str, Path]
        The input files named in ``[files]`` (``camera``, ``photos``, ...; the
        LiDAR tiles are ``lidar_paths``), resolved against the folder.
    config : SurveyConfig
        survey.toml parsed and checked (:mod:`lidarcat.survey.schema`), read once: every table,
        e.g. ``config.mapping.gsd_m``; the stages read their tables here.
    control_decisions : ControlDecisions
        control_decisions.csv (``[files] control_decisions``): the user's review of the LiDAR control
        measured in the photos (:mod:`lidarcat.survey.decisions`); empty without the key.
    """

    root: Path
    toml_path: Path
    name: str
    description: str
    crs: str
    height_system: str
    default_control: str | None
    cameras: dict[str, Camera]
    photos: tuple[Photo, ...]
    image_points: ImagePoints
    ground_points: GroundPoints
    control_sets: dict[str, ControlSet]
    lidar_paths: tuple[Path, ...]
    lidar_crs: str | None
    extraction_jobs: Path | None
    settings: AdjustmentSettings
    assessment: AssessmentSettings = field(default_factory=AssessmentSettings)
    embedded: bool = False
    files: dict[str, Path] = field(default_factory=dict)
    config: SurveyConfig = field(default=None, repr=False)  # type: ignore[assignment]
    control_decisions: ControlDecisions = field(default_factory=ControlDecisions)

    # ------------------------------------------------------------ load
    @classmethod
    def load(cls, path: str | Path | None = None) -> Survey:
        """Load and validate a survey folder.

        Parameters
        ----------
        path : str or Path or None
            The folder, or its ``survey.toml``; None loads the embedded thesis block.

        Raises
        ------
        SurveyError
            Any problem in any file; the message names the file, the line and
            the field, and says what to fix.
        """
        embedded = path is None
        root = thesis_survey_path() if path is None else Path(path)
        if root.is_file():
            toml_path, root = root, root.parent
        else:
            if not root.exists():
                raise SurveyError(f"{root}: survey folder not found")
            toml_path = root / "survey.toml"
            if not toml_path.is_file():
                raise SurveyError(f"{root}: no survey.toml in this folder (a survey folder "
                                  f"holds survey.toml plus CSV files; see docs/survey-format.md)")
        t = parse_survey_toml(toml_path)   # the one read of survey.toml: every table typed and checked
        sv = t.survey
        name, description, crs, height_system, default_control = (
            sv.name, sv.description, sv.crs, sv.height_system, sv.default_control)

        files: dict[str, Path] = {}

        def file_of(key: str) -> Path | None:
            rel = getattr(t.files, key)
            if rel is None:
                return None
            p = Path(rel) if Path(rel).is_absolute() else root / rel
            if not _is_file(t, key, rel, p):
                raise t.error("files", key, f"file {excerpt(rel)} not found ({excerpt(str(p), 200, quote=False)})")
            files[key] = p
            return p

        camera_path = file_of("camera")
        assert camera_path is not None
        cameras = load_cameras(camera_path)
        photos_path = file_of("photos")
        photos = load_photos(photos_path, cameras, camera_path, root)  # type: ignore[arg-type]
        photo_ids = {p.id for p in photos}

        gp_path = file_of("ground_points")
        ground = load_ground_points(gp_path) if gp_path else GroundPoints(
            np.empty(0, str), np.empty((0, 3)), np.empty((0, 3)), np.empty(0, str))
        ip_path = file_of("image_points")
        image_points, has_xy = load_image_points(ip_path, photo_ids, photos_path)  # type: ignore[arg-type]

        rigs_path = file_of("rigs")
        if rigs_path is not None or any(p.rig_exposure for p in photos):
            check_rig_exposures(photos, rigs_path, cameras, photos_path)  # type: ignore[arg-type]
        lines_path = file_of("line_control")
        control_lines = read_line_control(lines_path, photo_ids, photo_cameras(photos, cameras))[0] \
            if lines_path is not None else []   # located errors at load
        dec_path = file_of("control_decisions")   # the user's review of the LiDAR control (survey.decisions)
        decisions = read_control_decisions(dec_path, photo_ids, ground.point, [c.line for c in control_lines]) \
            if dec_path is not None else ControlDecisions()
        jobs_path = file_of("extraction_jobs")
        job_words = job_tokens(jobs_path) if jobs_path else set()

        # settings: [adjustment] with the defaults that depend on the data
        adj = t.adjustment
        obs = adj.observations if adj.observations is not None else "corrected" if has_xy else "pixel"
        image_sd = adj.image_sd_mm if adj.image_sd_mm is not None else DEFAULT_SD_PIXELS * max(
            max(c.pixel_size_x_mm, c.pixel_size_y_mm) for c in cameras.values())
        measured = set(image_points.point.tolist())
        for pid in adj.exclude_points:
            if pid not in measured and pid not in ground:
                raise t.error("adjustment", "exclude_points",
                              f"point {excerpt(pid)} is defined nowhere (measured on no photo, not in "
                              f"ground points); remove it or fix the id")
        exclude = set(adj.exclude_points)
        settings = AdjustmentSettings(obs, float(image_sd), frozenset(exclude), adj.variance_factor,
                                      adj.chi2_level)
        assessment = t.assessment
        check_photo_ids(t, photo_ids)

        check_single_photo_points(image_points, ground, job_words, exclude)

        cs_path = file_of("control_sets")
        control_sets = load_control_sets(cs_path, ground, exclude) if cs_path else {}
        if default_control is not None and default_control not in control_sets:
            avail = excerpt(", ".join(control_sets), 200, quote=False) or "none defined"
            raise t.error("survey", "default_control",
                          f"control set {default_control!r} is not in control_sets ({avail})")

        lidar_paths = _expand_lidar(t, root)
        lidar_crs = t.lidar.crs
        _check_crs(t, "survey", crs, [(gp_path, ground.enh_m[:, :2], ground.point)]
                   + [(photos_path, np.array([p.position_m[:2] for p in photos if p.position_m is not None]),
                       np.array([p.id for p in photos if p.position_m is not None]))])
        if lidar_crs is not None:
            _check_crs(t, "lidar", lidar_crs, [])

        survey = cls(root=root, toml_path=toml_path, name=name, description=description,
                     crs=crs, height_system=height_system, default_control=default_control,
                     cameras=cameras, photos=photos, image_points=image_points,
                     ground_points=ground, control_sets=control_sets, lidar_paths=lidar_paths,
                     lidar_crs=lidar_crs, extraction_jobs=jobs_path, settings=settings,
                     assessment=assessment, embedded=embedded, files=files, config=t,
                     control_decisions=decisions)
        log.info("loaded survey %r: %d photos, %d measurements, %d ground points, control sets %s",
                 name, len(photos), len(image_points), len(ground), ", ".join(control_sets) or "-")
        return survey

    # ------------------------------------------------------------ queries
    @property
    def photo_ids(self) -> tuple[str, ...]:
        return tuple(p.id for p in self.photos)

    def photo(self, photo_id: str) -> Photo:
        """The photo with id *photo_id* (SurveyError if unknown)."""
        for p in self.photos:
            if p.id == photo_id:
                return p
        raise SurveyError(f"{self.root}: no photo {excerpt(photo_id)}; photos are {excerpt(', '.join(self.photo_ids), 200, quote=False)}")

    def image_path(self, photo_id: str) -> Path:
        """The image file of photo *photo_id*.

        The ``image`` cell of its photos.csv row (relative to the survey folder); a row without one
        falls back to the folder convention of the orthophoto stage, ``images/<photo>.<png|tif|tiff|
        jpg|jpeg>`` (``[mapping] images``, default ``images``) -- the layout ``lidarcat demo synthetic
        --images`` wrote before the column existed.

        Raises
        ------
        SurveyError
            Unknown photo; or the photo has no image, or its file is gone since the load:
            ``photos.csv:LINE: field 'image': ...``.
        """
        p = self.photo(photo_id)
        where = location(self.files.get("photos", self.root / "photos.csv"), p.line, "image")
        if p.image is not None:
            if not p.image.is_file():
                raise SurveyError(f"{where}: photo {excerpt(p.id)}: image {excerpt(str(p.image), 200, quote=False)} "
                                  f"not found")
            return p.image
        from ..photos import IMAGE_SUFFIXES

        folder = Path(self.config.mapping.images if self.config is not None and self.config.mapping is not None
                      else "images")
        folder = folder if folder.is_absolute() else self.root / folder
        for suffix in IMAGE_SUFFIXES:
            for name in (f"{p.id}{suffix}", f"{p.id}{suffix.upper()}"):
                if (folder / name).is_file():
                    return folder / name
        raise SurveyError(f"{where}: photo {excerpt(p.id)} has no image: give its file in the column 'image' "
                          f"(relative to the survey folder) or put it in {excerpt(str(folder), 200, quote=False)} "
                          f"as {p.id}.jpg/.png/.tif")

    def copy_photos_csv(self, dest: str | Path) -> Path:
        """Copy photos.csv to *dest* (a derived survey elsewhere) with its ``image`` cells rewritten relative
        to the folder of *dest*, so that the copy names the same files; written atomically.

        A plain copy would break the relative paths (``../photos/IMG_1.jpg``) of ``lidarcat init``.
        """
        import shutil

        dest = Path(dest)
        src = self.files.get("photos", self.root / "photos.csv")
        if not any(p.image is not None for p in self.photos):
            dest.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, dest)
            return dest
        t = read_csv_table(src, required=("photo",), optional=PHOTO_COLUMNS[1:])
        k = t.header.index("image")
        rows = [list(r) for r in t.rows]
        for r, p in zip(rows, self.photos):
            if p.image is not None:
                r[k] = relative_path(p.image, dest.parent)
        return write_csv_atomic(dest, t.header, rows)

    @property
    def has_images(self) -> bool:
        """Every photo has an image file (:meth:`image_path` finds one)."""
        try:
            for pid in self.photo_ids:
                self.image_path(pid)
        except SurveyError:
            return False
        return True

    def camera_of(self, photo_id: str) -> Camera:
        """The camera of photo *photo_id*."""
        return self.cameras[self.photo(photo_id).camera]

    @property
    def tie_points(self) -> tuple[str, ...]:
        """Ids measured on photos that are no ground point (excluded points left out), sorted."""
        ids = set(self.image_points.point.tolist()) - set(self.ground_points.point.tolist())
        return tuple(sorted(ids - self.settings.exclude_points))

    def photo_observations(self, kind: str | None = None) -> ImagePoints:
        """The image observations an adjustment uses.

        Parameters
        ----------
        kind : {"corrected", "pixel"} or None
            "corrected": the file's x_mm, y_mm; "pixel": col_px, row_px run
            through each photo's camera (eq. 01-07).  None: ``settings.observations``.

        Returns
        -------
        ImagePoints
            Rows of excluded points removed; ``xy_mm`` filled; ``sd_mm`` filled
            from ``settings.image_sd_mm`` where the file gives none.

        Raises
        ------
        SurveyError
            Bad *kind*, or a row lacks the requested coordinates (names file and line).
        """
        kind = self.settings.observations if kind is None else kind
        if kind not in OBSERVATION_KINDS:
            raise SurveyError(f"observations kind {kind!r} is not one of "
                              f"{', '.join(map(repr, OBSERVATION_KINDS))}")
        ip = self.image_points
        keep = ~np.isin(ip.point, list(self.settings.exclude_points))
        ip = ip.select(keep)
        if kind == "corrected":
            xy = ip.xy_mm.copy()
            bad = ~np.isfinite(xy).all(axis=1)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise SurveyError(f"{location(ip.path, int(ip.line[i]), 'x_mm')}: no corrected photo "
                                  f"coordinates (x_mm, y_mm) for photo {excerpt(str(ip.photo[i]))} point "
                                  f"{excerpt(str(ip.point[i]))}; give them or use observations = \"pixel\"")
        else:
            bad = ~np.isfinite(ip.pixel_px).all(axis=1)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise SurveyError(f"{location(ip.path, int(ip.line[i]), 'col_px')}: no pixel "
                                  f"coordinates (col_px, row_px) for photo {excerpt(str(ip.photo[i]))} point "
                                  f"{excerpt(str(ip.point[i]))}; give them or use observations = \"corrected\"")
            xy = np.empty((len(ip), 2))
            for p in self.photos:
                rows = ip.photo == p.id
                if rows.any() and self.cameras[p.camera].lens is None:
                    xy[rows] = self.cameras[p.camera].pixel_to_photo(ip.pixel_px[rows])
        sd = ip.sd_mm.copy()
        sd[~np.isfinite(sd)] = self.settings.image_sd_mm
        if kind == "pixel":                                 # Brown/fisheye photos: through the model
            for p in self.photos:
                rows = np.flatnonzero(ip.photo == p.id)
                if len(rows) and self.cameras[p.camera].lens is not None:
                    xy[rows], sd[rows] = _lens_observations(self.cameras[p.camera], ip.pixel_px[rows], sd[rows],
                                                            ip.path, ip.line[rows], p.id)
        return ImagePoints(ip.photo, ip.point, ip.pixel_px, xy, sd, ip.line, ip.path)

    def control_set(self, name: str | None = None) -> ControlSet:
        """The control set *name* (default: ``default_control``).

        Raises
        ------
        SurveyError
            Unknown name, or no name and no default (lists the available sets).
        """
        avail = excerpt(", ".join(self.control_sets), 200, quote=False) or "none defined"
        if name is None:
            name = self.default_control
            if name is None:
                raise SurveyError(f"{self.toml_path}: no control set named and no "
                                  f"[survey] default_control; available: {avail}")
        if name not in self.control_sets:
            raise SurveyError(f"{self.toml_path}: no control set {name!r}; available: {avail}")
        return self.control_sets[name]

    def output_dir(self, outdir: str | Path | None = None) -> Path:
        """Where results go: *outdir* if given, else ``<root>/out``.

        For the embedded thesis block (which may live read-only inside the
        installed package) the default is ``./lidarcat-out`` in the current
        directory instead.  The folder is not created here.
        """
        if outdir is not None:
            return Path(outdir)
        if self.embedded:
            return Path.cwd() / "lidarcat-out"
        return self.root / "out"

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able summary (counts, CRS, control sets, settings)."""
        return {
            "name": self.name, "description": self.description, "root": str(self.root),
            "crs": self.crs, "height_system": self.height_system,
            "default_control": self.default_control,
            "cameras": {k: c.to_dict() for k, c in self.cameras.items()},
            "photos": [p.id for p in self.photos],
            "n_images": sum(p.image is not None for p in self.photos),
            "n_image_points": len(self.image_points),
            "n_observations": len(self.image_points) - int(
                np.isin(self.image_points.point, list(self.settings.exclude_points)).sum()),
            "n_ground_points": len(self.ground_points),
            "ground_point_sources": dict(Counter(self.ground_points.source.tolist())),
            "tie_points": list(self.tie_points),
            "control_sets": {k: {"control": len(v.control), "check": len(v.check)}
                             for k, v in self.control_sets.items()},
            "lidar_paths": [str(p) for p in self.lidar_paths], "lidar_crs": self.lidar_crs,
            "extraction_jobs": str(self.extraction_jobs) if self.extraction_jobs else None,
            "settings": self.settings.to_dict(),
            "assessment": self.assessment.to_dict(),
        }


def cameras_of(source: str | Path | None = None) -> dict[str, Camera]:
    """The cameras of a survey folder (or its survey.toml), of a camera TOML file
    (``FILE`` or ``FILE:ID``), or of the embedded thesis block (None).

    Raises
    ------
    SurveyError
        Invalid survey or camera file, or unknown camera id.
    """
    if source is None:
        return dict(Survey.load().cameras)
    src = Path(source)
    if src.is_dir() or src.name == "survey.toml":
        return dict(Survey.load(src).cameras)
    if not src.exists() and ":" in str(source):
        cam = load_camera(source)
        return {cam.id: cam}
    return load_cameras(src)


# ---------------------------------------------------------------------- camera correct
_CORRECTION_COLUMNS = ("photo", "point", "x_mm", "y_mm", "col_px", "row_px", "x_fot_mm",
                       "y_fot_mm", "dx_ra_mm", "dy_ra_mm", "dx_des_mm", "dy_des_mm",
                       "dx_ref_mm", "dy_ref_mm", "camera")


@dataclass(frozen=True, eq=False)
class CorrectedMeasurements:
    """Pixel measurements run through eq. 01-07, one row per measurement.

    Attributes
    ----------
    photo, point, camera : ndarray (n,) of str
    pixel_px : ndarray (n, 2)
        Column, row.
    fot_mm : ndarray (n, 2)
        x_fot, y_fot (eq. 02), mm.
    corrections_mm : dict of ndarray (n,)
        dx_ra, dy_ra, dx_des, dy_des, dx_ref, dy_ref (eq. 03-06), mm.
    xy_mm : ndarray (n, 2)
        Corrected photo coordinates x_fotc, y_fotc (eq. 07), mm.
    """

    photo: np.ndarray
    point: np.ndarray
    camera: np.ndarray
    pixel_px: np.ndarray
    fot_mm: np.ndarray
    corrections_mm: dict[str, np.ndarray]
    xy_mm: np.ndarray

    def __len__(self) -> int:
        return len(self.photo)

    @property
    def columns(self) -> tuple[str, ...]:
        return _CORRECTION_COLUMNS

    def rows(self) -> list[list[Any]]:
        c = self.corrections_mm
        return [[self.photo[i], self.point[i], self.xy_mm[i, 0], self.xy_mm[i, 1],
                 self.pixel_px[i, 0], self.pixel_px[i, 1], self.fot_mm[i, 0], self.fot_mm[i, 1],
                 c["dx_ra"][i], c["dy_ra"][i], c["dx_des"][i], c["dy_des"][i],
                 c["dx_ref"][i], c["dy_ref"][i], self.camera[i]] for i in range(len(self))]

    def records(self) -> list[dict[str, Any]]:
        return [dict(zip(_CORRECTION_COLUMNS, r)) for r in self.rows()]

    def write_csv(self, path: str | Path) -> Path:
        """Write the table atomically (header: photo, point, x_mm, y_mm, ...)."""
        return write_csv_atomic(path, _CORRECTION_COLUMNS, self.rows(), comments=[
            "lidarcat camera correct: x_mm, y_mm = corrected photo coordinates x_fotc, y_fotc "
            "(Fierro 2007 eq. 01-07), mm, x right, y up",
            "d*_ra radial, d*_des decentering, d*_ref refraction: distortions subtracted in eq. 07"])

    def to_dict(self) -> dict[str, Any]:
        mag = np.hypot(self.xy_mm[:, 0] - self.fot_mm[:, 0], self.xy_mm[:, 1] - self.fot_mm[:, 1])
        return {"n_points": len(self), "cameras": sorted(set(self.camera.tolist())),
                "max_correction_mm": float(mag.max()) if len(self) else 0.0}


def correct_measurements(source: str | Path | Survey, camera: str | Path | Camera | None = None
                         ) -> CorrectedMeasurements:
    """Correct pixel measurements to photo coordinates (``lidarcat camera correct``).

    Parameters
    ----------
    source : str, Path or Survey
        A survey folder (or its survey.toml, or a loaded Survey): every image_points row with
        col_px, row_px is corrected with its photo's camera; or a CSV with
        columns photo, point, col_px, row_px (other columns are ignored).
    camera : str, Path, Camera or None
        ``FILE`` or ``FILE:ID`` of a camera TOML, or a Camera.  Required for a
        CSV; for a survey it replaces the survey's own camera(s).

    Raises
    ------
    SurveyError
        Unreadable input, no pixel coordinates, or a CSV without *camera*.
    """
    loaded = source if isinstance(source, Survey) else None
    src = loaded.toml_path if loaded is not None else Path(source)  # type: ignore[union-attr]
    cam_obj: Camera | None
    if camera is None or isinstance(camera, Camera):
        cam_obj = camera
    else:
        cam_obj = load_camera(camera)
    if src.is_dir() or src.suffix.lower() == ".toml":
        survey = loaded or Survey.load(src)
        ip = survey.image_points
        has = np.isfinite(ip.pixel_px).all(axis=1)
        if not has.any():
            raise SurveyError(f"{ip.path}: no row has col_px, row_px; nothing to correct")
        if (~has).any():
            log.warning("%s: %d row(s) without pixel coordinates skipped", ip.path, int((~has).sum()))
        ip = ip.select(has)
        photo, point, px = ip.photo, ip.point, ip.pixel_px
        if cam_obj is None:
            cameras = survey.cameras
            camera_of = {p.id: p.camera for p in survey.photos}
            cam_ids = np.array([camera_of[p] for p in photo.tolist()], dtype=str)
    else:
        if cam_obj is None:
            raise SurveyError(f"{src}: a CSV of pixel measurements needs --camera FILE[:ID] "
                              f"(a survey folder brings its own camera)")
        t = read_csv_table(src, required=("photo", "point", "col_px", "row_px"), allow_extra=True)
        photo = np.array(column_ids(t, "photo"), dtype=str)
        point = np.array(column_ids(t, "point"), dtype=str)
        px = np.column_stack([t.floats("col_px"), t.floats("row_px")])
        if len(photo) == 0:
            raise SurveyError(f"{src}: no measurements")
    if cam_obj is not None:
        cameras = {cam_obj.id: cam_obj}
        cam_ids = np.full(len(photo), cam_obj.id)
    n = len(photo)
    fot = np.empty((n, 2))
    xy = np.empty((n, 2))
    corr = {k: np.empty(n) for k in ("dx_ra", "dy_ra", "dx_des", "dy_des", "dx_ref", "dy_ref")}
    for cam_id in dict.fromkeys(cam_ids.tolist()):
        rows = cam_ids == cam_id
        cam = cameras[cam_id]
        fot[rows] = cam.pixel_to_fot(px[rows])
        xy[rows] = cam.pixel_to_photo(px[rows])
        d = cam.distortion_corrections(fot[rows])
        for k in corr:
            corr[k][rows] = d[k]
    return CorrectedMeasurements(photo, point, cam_ids, px, fot, corr, xy)
