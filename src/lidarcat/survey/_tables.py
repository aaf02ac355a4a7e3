"""The CSV tables of a survey folder: their value types and readers (used by :meth:`lidarcat.Survey.load`).

Every reader checks its file and raises a :class:`~lidarcat.errors.SurveyError` naming
``file:line: field 'name':`` and what to fix.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._util import CsvTable, excerpt, read_csv_table, read_text
from .._util.frozen import frozen_array as _frozen
from ..errors import SurveyError, location
from ..geometry.camera import Camera
from .schema import SD_BOUNDS

__all__ = ["Photo", "ImagePoints", "GroundPoints", "ControlSet", "PHOTO_COLUMNS", "column_ids", "no_duplicates",
           "optional_triple", "check_sds", "job_tokens", "load_photos", "load_image_points", "load_ground_points",
           "load_control_sets", "check_single_photo_points", "check_images"]


# ---------------------------------------------------------------------- value types
@dataclass(frozen=True, eq=False)
class Photo:
    """One photo: its camera and optional approximate / GNSS-INS exterior orientation.

    Attributes
    ----------
    id, camera : str
        Photo id and camera id.
    position_m : ndarray (3,) or None
        Projection centre X0, Y0, Z0 in the survey CRS, m.
    attitude_deg : ndarray (3,) or None
        omega, phi, kappa, degrees; M = R3(kappa) R2(phi) R1(omega).
    sd_position_m, sd_attitude_deg : ndarray (3,) or None
        Standard deviations when the values may act as weighted constraints.
    line : int
        Line of photos.csv.
    image : Path or None
        The photo's image file (photos.csv column ``image``, resolved against the survey folder);
        None when the row names none (:meth:`lidarcat.Survey.image_path` then looks in ``images/``).
    time_s : float or None
        Exposure time (photos.csv ``time_s``, s, any origin): the velocity of a rolling-shutter
        camera from its neighbouring exposures (:mod:`lidarcat.survey.motion`).
    rig_exposure : str or None
        The rig exposure the photo belongs to (photos.csv ``rig_exposure``;
        :mod:`lidarcat.survey.rigs`).
    """

    id: str
    camera: str
    position_m: np.ndarray | None = None
    attitude_deg: np.ndarray | None = None
    sd_position_m: np.ndarray | None = None
    sd_attitude_deg: np.ndarray | None = None
    line: int = 0
    image: Path | None = None
    time_s: float | None = None
    rig_exposure: str | None = None

    def __post_init__(self) -> None:
        for name in ("position_m", "attitude_deg", "sd_position_m", "sd_attitude_deg"):
            v = getattr(self, name)
            if v is not None:
                arr = _frozen(v)
                if arr.shape != (3,):
                    raise SurveyError(f"photo {self.id!r}: {name} must have 3 values, got {arr.shape}")
                object.__setattr__(self, name, arr)


@dataclass(frozen=True, eq=False)
class ImagePoints:
    """Image measurements, one row per (photo, point).

    Attributes
    ----------
    photo, point : ndarray (n,) of str
        Ids.
    pixel_px : ndarray (n, 2)
        Column, row in pixels; NaN where not given.
    xy_mm : ndarray (n, 2)
        Corrected photo coordinates x_fotc, y_fotc, mm; NaN where not given.
    sd_mm : ndarray (n, 2)
        Standard deviation of x and y, mm; NaN where not given.
    line : ndarray (n,) of int
        Line in the source file (0 for rows not from a file).
    path : Path or None
        Source file (for error messages).
    """

    photo: np.ndarray
    point: np.ndarray
    pixel_px: np.ndarray
    xy_mm: np.ndarray
    sd_mm: np.ndarray
    line: np.ndarray
    path: Path | None = None

    def __post_init__(self) -> None:
        n = len(self.photo)
        object.__setattr__(self, "photo", _frozen(self.photo, str))
        object.__setattr__(self, "point", _frozen(self.point, str))
        object.__setattr__(self, "line", _frozen(self.line, np.int64))
        for name in ("pixel_px", "xy_mm", "sd_mm"):
            object.__setattr__(self, name, _frozen(getattr(self, name)).reshape(-1, 2))
        for name in ("point", "pixel_px", "xy_mm", "sd_mm", "line"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"ImagePoints.{name} has {len(getattr(self, name))} rows, expected {n}")

    def __len__(self) -> int:
        return len(self.photo)

    def select(self, mask: Any) -> ImagePoints:
        """The rows selected by a boolean mask or an index array."""
        m = np.asarray(mask)
        return ImagePoints(self.photo[m], self.point[m], self.pixel_px[m], self.xy_mm[m],
                           self.sd_mm[m], self.line[m], self.path)

    def where(self, line_index: int) -> str:
        """``file:line`` of row *line_index*, for messages."""
        return location(self.path or "image points", int(self.line[line_index]) or None)

    def to_dict(self) -> dict[str, Any]:
        return {"n": len(self), "photos": sorted(set(self.photo.tolist())),
                "points": len(set(self.point.tolist()))}


@dataclass(frozen=True, eq=False)
class GroundPoints:
    """Ground points with per-axis standard deviations.

    Attributes
    ----------
    point : ndarray (m,) of str
    enh_m : ndarray (m, 3)
        E, N, h in the survey CRS, m.
    sd_m : ndarray (m, 3)
        Standard deviations of E, N, h, m.
    source : ndarray (m,) of str
        ``gps``, ``lidar``, ...
    line : ndarray (m,) of int
    path : Path or None
    """

    point: np.ndarray
    enh_m: np.ndarray
    sd_m: np.ndarray
    source: np.ndarray
    line: np.ndarray | None = None
    path: Path | None = None

    def __post_init__(self) -> None:
        m = len(self.point)
        object.__setattr__(self, "point", _frozen(self.point, str))
        object.__setattr__(self, "source", _frozen(self.source, str))
        object.__setattr__(self, "enh_m", _frozen(self.enh_m).reshape(m, 3))
        object.__setattr__(self, "sd_m", _frozen(self.sd_m).reshape(m, 3))
        line = np.zeros(m, np.int64) if self.line is None else self.line
        object.__setattr__(self, "line", _frozen(line, np.int64))
        object.__setattr__(self, "_pos", {p: i for i, p in enumerate(self.point.tolist())})

    def __len__(self) -> int:
        return len(self.point)

    def __contains__(self, point_id: object) -> bool:
        return point_id in self._pos  # type: ignore[attr-defined]

    def index(self, ids: Any) -> np.ndarray:
        """Row indices of the point ids *ids* (str or sequence of str).

        Raises
        ------
        SurveyError
            An id is not a ground point (names it).
        """
        single = isinstance(ids, str)
        seq = [ids] if single else [str(i) for i in np.asarray(ids, dtype=str).ravel()]
        pos = self._pos  # type: ignore[attr-defined]
        missing = [i for i in seq if i not in pos]
        if missing:
            where = f"{self.path}: " if self.path else ""
            raise SurveyError(f"{where}point(s) {', '.join(missing)} not among the ground points")
        return np.array([pos[i] for i in seq], dtype=np.intp)

    def select(self, mask: Any) -> GroundPoints:
        m = np.asarray(mask)
        return GroundPoints(self.point[m], self.enh_m[m], self.sd_m[m], self.source[m],
                            self.line[m], self.path)

    def to_dict(self) -> dict[str, Any]:
        return {"n": len(self), "sources": dict(Counter(self.source.tolist()))}


@dataclass(frozen=True, eq=False)
class ControlSet:
    """A named choice of control (weighted constraints) and check points.

    Attributes
    ----------
    name : str
    control : ndarray (k,) of str
        Control point ids, file order.
    check : ndarray (j,) of str
        Check point ids, file order.
    sd_m : ndarray (k, 3)
        Standard deviations of E, N, h for each control point: the set's override
        when given, else the ground point's own.
    check_sd_m : ndarray (j, 3)
        Same for the check points (the reference accuracy of the checks).
    """

    name: str
    control: np.ndarray
    check: np.ndarray
    sd_m: np.ndarray
    check_sd_m: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "control", _frozen(self.control, str))
        object.__setattr__(self, "check", _frozen(self.check, str))
        object.__setattr__(self, "sd_m", _frozen(self.sd_m).reshape(len(self.control), 3))
        csd = np.full((len(self.check), 3), np.nan) if self.check_sd_m is None else self.check_sd_m
        object.__setattr__(self, "check_sd_m", _frozen(csd).reshape(len(self.check), 3))

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "control": self.control.tolist(),
                "check": self.check.tolist()}


def column_ids(table: CsvTable, name: str) -> list[str]:
    out = table.column(name)
    for v, line in zip(out, table.lines):
        if v == "":
            raise SurveyError(f"{location(table.path, line, name)}: empty id")
    return out


def no_duplicates(table: CsvTable, keys: Sequence[str], what: str) -> None:
    seen: dict[tuple[str, ...], int] = {}
    cols = [table.column(k) for k in keys]
    for i, line in enumerate(table.lines):
        key = tuple(c[i] for c in cols)
        if key in seen:
            shown = ", ".join(f"{k}={excerpt(v)}" for k, v in zip(keys, key))
            raise SurveyError(f"{location(table.path, line, keys[-1])}: duplicate {what} ({shown}); "
                              f"first defined on line {seen[key]}")
        seen[key] = line


def optional_triple(table: CsvTable, names: Sequence[str], what: str) -> np.ndarray:
    """(n, 3) from three optional columns: all or none present; per row all or none filled."""
    present = [table.has(n) for n in names]
    if not any(present):
        return np.full((len(table.rows), 3), np.nan)
    if not all(present):
        missing = [n for n, p in zip(names, present) if not p]
        raise SurveyError(f"{location(table.path, 1, missing[0])}: missing column {missing[0]!r}; "
                          f"{what} needs all of {', '.join(names)}")
    arr = np.column_stack([table.floats(n, required=False) for n in names])
    for i, line in enumerate(table.lines):
        filled = np.isfinite(arr[i])
        if filled.any() and not filled.all():
            n = names[int(np.flatnonzero(~filled)[0])]
            raise SurveyError(f"{location(table.path, line, n)}: empty; fill all of "
                              f"{', '.join(names)} or none")
    return arr


def check_sds(table: CsvTable, arr: np.ndarray, names: Sequence[str], unit: str = "m") -> None:
    """Refuse standard deviations that are not positive or lie outside :data:`SD_BOUNDS` of *unit*
    (NaN entries are absent values and pass); the message names file, line, field and the row's id."""
    lo, hi = SD_BOUNDS[unit]
    for j, n in enumerate(names):
        col = arr[:, j]
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~np.isnan(col) & ~((col >= lo) & (col <= hi)))
        if bad.size:
            i = int(bad[0])
            who = next((f" ({key} {excerpt(table.rows[i][table.header.index(key)])})"
                        for key in ("point", "photo") if table.has(key)), "")
            what = "must be positive" if not col[i] > 0 else "is outside the sane range"
            raise SurveyError(f"{location(table.path, table.lines[i], n)}{who}: standard deviation "
                              f"{what}, got {float(col[i])!r} {unit}; sane values lie in {lo:g}..{hi:g} {unit}")


def job_tokens(path: Path) -> set[str]:
    """Every word of an extraction-jobs file (and the word without a leading 'P')."""
    words: set[str] = set()
    for raw in read_text(path).splitlines():
        if raw.lstrip().startswith("#"):
            continue
        for w in raw.replace(",", " ").split():
            words.add(w)
            if w[:1] in "Pp" and len(w) > 1:
                words.add(w[1:])
    return words


# ---------------------------------------------------------------------- file readers
PHOTO_COLUMNS = ("photo", "camera", "image", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg",
               "sd_X0", "sd_Y0", "sd_Z0", "sd_omega_deg", "sd_phi_deg", "sd_kappa_deg", "time_s", "rig_exposure")


def load_photos(path: Path, cameras: dict[str, Camera], camera_path: Path, root: Path | None = None
                ) -> tuple[Photo, ...]:
    """The photos of photos.csv; with an ``image`` column each named file is checked
    (:func:`check_images`; paths relative to *root*, default the folder of *path*)."""
    t = read_csv_table(path, required=("photo",), optional=PHOTO_COLUMNS[1:])
    ids = column_ids(t, "photo")
    no_duplicates(t, ("photo",), "photo id")
    if t.has("camera"):
        cams = t.column("camera")
        for c, line in zip(cams, t.lines):
            if c not in cameras:
                raise SurveyError(f"{location(path, line, 'camera')}: camera {excerpt(c)} is not defined "
                                  f"in {camera_path.name} (defined: {excerpt(', '.join(cameras), 200, quote=False)})")
    else:
        if len(cameras) > 1:
            raise SurveyError(f"{location(path, 1, 'camera')}: missing column 'camera'; "
                              f"{camera_path.name} defines {len(cameras)} cameras "
                              f"({excerpt(', '.join(cameras), 200, quote=False)}), so each photo must name one")
        cams = [next(iter(cameras))] * len(ids)
    pos = optional_triple(t, ("X0", "Y0", "Z0"), "a position")
    att = optional_triple(t, ("omega_deg", "phi_deg", "kappa_deg"), "an attitude")
    sdp = optional_triple(t, ("sd_X0", "sd_Y0", "sd_Z0"), "a position sd")
    sda = optional_triple(t, ("sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"), "an attitude sd")
    check_sds(t, sdp, ("sd_X0", "sd_Y0", "sd_Z0"), "m")
    check_sds(t, sda, ("sd_omega_deg", "sd_phi_deg", "sd_kappa_deg"), "deg")
    base = path.parent if root is None else root
    images = [(base / v if v and not Path(v).is_absolute() else Path(v)) if v else None
              for v in (t.column("image") if t.has("image") else [""] * len(ids))]
    times = t.floats("time_s", required=False) if t.has("time_s") else np.full(len(ids), np.nan)
    rig_ex = t.column("rig_exposure") if t.has("rig_exposure") else [""] * len(ids)
    photos = []
    for i, line in enumerate(t.lines):
        def opt(a: np.ndarray) -> np.ndarray | None:
            return a[i] if np.isfinite(a[i]).all() else None
        photos.append(Photo(ids[i], cams[i], opt(pos), opt(att), opt(sdp), opt(sda), line, images[i],
                            float(times[i]) if np.isfinite(times[i]) else None, rig_ex[i].strip() or None))
    if not photos:
        raise SurveyError(f"{path}: no photos")
    check_images(photos, cameras, path, t.column("image") if t.has("image") else None)
    return tuple(photos)


def check_images(photos: Sequence[Photo], cameras: dict[str, Camera], path: Path,
                 written: Sequence[str] | None = None) -> None:
    """The image files that photos.csv names: each exists, is a whole JPEG/PNG/TIFF (its header and end,
    :func:`lidarcat.photos.read_header`, nothing decoded), has its camera's size, and belongs to one
    photo only.  The first problem is a SurveyError ``photos.csv:LINE: field 'image': ...``."""
    from ..errors import FormatError
    from ..photos import read_header

    seen: dict[Path, Photo] = {}
    for k, p in enumerate(photos):
        if p.image is None:
            continue
        shown = excerpt(written[k] if written is not None else str(p.image))
        where = location(path, p.line, "image")
        try:
            is_file = "\x00" not in str(p.image) and p.image.is_file()
            key = p.image.resolve()
        except OSError as ex:
            raise SurveyError(f"{where}: photo {excerpt(p.id)}: image {shown} cannot be used: "
                              f"{ex.strerror or ex}") from None
        if not is_file:
            raise SurveyError(f"{where}: photo {excerpt(p.id)}: image {shown} not found "
                              f"({excerpt(str(p.image), 200, quote=False)})")
        if key in seen:
            raise SurveyError(f"{where}: photo {excerpt(p.id)}: image {shown} is also the image of photo "
                              f"{excerpt(seen[key].id)} (line {seen[key].line}); each photo has its own file")
        seen[key] = p
        try:
            head = read_header(p.image)
        except FormatError as ex:
            raise SurveyError(f"{where}: photo {excerpt(p.id)}: {ex}") from None
        cam = cameras[p.camera]
        if (head.columns_px, head.rows_px) != (cam.columns_px, cam.rows_px):
            raise SurveyError(f"{where}: photo {excerpt(p.id)}: image {shown} is {head.columns_px} x "
                              f"{head.rows_px} px but camera {excerpt(cam.id)} is {cam.columns_px} x "
                              f"{cam.rows_px} px; fix the camera of this photo or the image")


def load_image_points(path: Path, photo_ids: set[str], photos_path: Path) -> tuple[ImagePoints, bool]:
    t = read_csv_table(path, required=("photo", "point"),
                       optional=("col_px", "row_px", "x_mm", "y_mm", "sd_x_mm", "sd_y_mm"))
    for a, b in (("col_px", "row_px"), ("x_mm", "y_mm"), ("sd_x_mm", "sd_y_mm")):
        if t.has(a) != t.has(b):
            missing = b if t.has(a) else a
            raise SurveyError(f"{location(path, 1, missing)}: missing column {missing!r}; "
                              f"columns {a}, {b} come as a pair")
    has_px, has_xy = t.has("col_px"), t.has("x_mm")
    if not (has_px or has_xy):
        raise SurveyError(f"{location(path, 1, 'col_px')}: missing columns: give col_px, row_px "
                          f"(pixels) and/or x_mm, y_mm (corrected photo coordinates)")
    photo = column_ids(t, "photo")
    point = column_ids(t, "point")
    no_duplicates(t, ("photo", "point"), "measurement of this point on this photo")
    for ph, line in zip(photo, t.lines):
        if ph not in photo_ids:
            raise SurveyError(f"{location(path, line, 'photo')}: photo {excerpt(ph)} is not in "
                              f"{photos_path.name}; add it there or fix the id")
    n = len(t.rows)

    def pair(a: str, b: str) -> np.ndarray:
        if not t.has(a):
            return np.full((n, 2), np.nan)
        arr = np.column_stack([t.floats(a, required=False), t.floats(b, required=False)])
        for i, line in enumerate(t.lines):
            f = np.isfinite(arr[i])
            if f.any() and not f.all():
                raise SurveyError(f"{location(path, line, b if f[0] else a)}: empty; "
                                  f"fill both {a} and {b} or neither")
        return arr

    px, xy, sd = pair("col_px", "row_px"), pair("x_mm", "y_mm"), pair("sd_x_mm", "sd_y_mm")
    for i, line in enumerate(t.lines):
        if not (np.isfinite(px[i]).all() or np.isfinite(xy[i]).all()):
            fld = "x_mm" if has_xy else "col_px"
            raise SurveyError(f"{location(path, line, fld)}: no coordinates; give col_px, row_px "
                              f"or x_mm, y_mm")
    check_sds(t, sd, ("sd_x_mm", "sd_y_mm"), "mm")
    # n == 0 is a valid state: a survey of photos without observations yet (`lidarcat init`); the
    # adjustment refuses it (`lidarcat match SURVEY` first)
    return ImagePoints(np.array(photo, dtype=str), np.array(point, dtype=str), px, xy, sd,
                       np.array(t.lines), path), has_xy


def load_ground_points(path: Path) -> GroundPoints:
    cols = ("point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source")
    t = read_csv_table(path, required=cols)
    point = column_ids(t, "point")
    no_duplicates(t, ("point",), "ground point id")
    enh = np.column_stack([t.floats(c) for c in ("E", "N", "h")])
    sd = np.column_stack([t.floats(c) for c in ("sd_E", "sd_N", "sd_h")])
    check_sds(t, sd, ("sd_E", "sd_N", "sd_h"))
    source = t.column("source")
    for s, line in zip(source, t.lines):
        if not s:
            raise SurveyError(f"{location(path, line, 'source')}: empty; name the source "
                              f"(gps, lidar, total_station, ...)")
    return GroundPoints(np.array(point, dtype=str), enh, sd, np.array(source, dtype=str),
                        np.array(t.lines), path)


def load_control_sets(path: Path, ground: GroundPoints, exclude: set[str]) -> dict[str, ControlSet]:
    t = read_csv_table(path, required=("set", "point", "role"), optional=("sd_E", "sd_N", "sd_h"))
    names = column_ids(t, "set")
    points = column_ids(t, "point")
    roles = t.column("role")
    no_duplicates(t, ("set", "point"), "point in this control set")
    sd_cols = ("sd_E", "sd_N", "sd_h")
    over = optional_triple(t, sd_cols, "an sd override")
    check_sds(t, over, sd_cols, "m")
    gp_file = ground.path.name if ground.path else "ground_points.csv"
    for p, r, line in zip(points, roles, t.lines):
        if r not in ("control", "check"):
            raise SurveyError(f"{location(path, line, 'role')}: {excerpt(r)} is not 'control' or 'check'")
        if p not in ground:
            raise SurveyError(f"{location(path, line, 'point')}: point {excerpt(p)} is defined nowhere: "
                              f"not in {gp_file}; add its coordinates there or fix the id")
        if p in exclude:
            raise SurveyError(f"{location(path, line, 'point')}: point {excerpt(p)} is excluded by "
                              f"survey.toml [adjustment] exclude_points; drop one of the two")
    out: dict[str, ControlSet] = {}
    for name in dict.fromkeys(names):
        rows = [i for i, n in enumerate(names) if n == name]
        ctrl = [i for i in rows if roles[i] == "control"]
        chk = [i for i in rows if roles[i] == "check"]

        def sds(idx: list[int]) -> np.ndarray:
            if not idx:
                return np.empty((0, 3))
            own = ground.sd_m[ground.index([points[i] for i in idx])]
            o = over[idx]
            return np.where(np.isfinite(o), o, own)

        out[name] = ControlSet(name, np.array([points[i] for i in ctrl], dtype=str),
                               np.array([points[i] for i in chk], dtype=str), sds(ctrl), sds(chk))
    return out


def check_single_photo_points(ip: ImagePoints, ground: GroundPoints, job_words: set[str],
                               exclude: set[str]) -> None:
    counts = Counter(ip.point.tolist())
    for i, p in enumerate(ip.point.tolist()):
        if counts[p] == 1 and p not in ground and p not in job_words and p not in exclude:
            raise SurveyError(
                f"{location(ip.path, int(ip.line[i]), 'point')}: {excerpt(p)} is measured on photo "
                f"{excerpt(str(ip.photo[i]))} only and defined nowhere (no ground point, no extraction job), "
                f"so it is no tie point either (a tie point needs two photos); fix the id, "
                f"add the point to ground_points.csv, or exclude it")
