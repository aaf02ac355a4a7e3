"""Stage ``match`` and the action of ``lidarcat match``: tie points from the photos into the survey.

:func:`match` reads the survey (cameras, photos with their approximate orientation and image
files, the LiDAR tiles when there are any), builds the height surface of the footprints and
the guided search (a DSM of the tiles, else the mean height of the ground points, else
``height_m``), runs :func:`lidarcat.match.match_block` and writes

* the tie-point observations into the survey's ``image_points.csv``: the rows of earlier
  automatic tie points (ids ``<prefix><number>``) are replaced, every other row is kept as it
  was; pixel coordinates ``col_px, row_px`` always, corrected photo coordinates ``x_mm, y_mm``
  (eq. 01-07) too when the file has them or the survey adjusts corrected coordinates, and each
  observation's a priori sd ``sd_x_mm, sd_y_mm`` (:func:`lidarcat.match.refine.observation_sds`:
  the least-squares-matching precision of a refined observation, else the SIFT sd); the
  provenance (inputs with SHA-256, options) in the sidecar ``image_points.csv.json``;
* a matching report into the output folder: ``match_report.json`` (counts, options, seconds),
  ``match_pairs.csv`` (per pair: overlap, matches, candidates, inliers, why rejected) and
  ``match_photos.csv`` (per photo: keypoints, tie points, observations, grid coverage).

Nothing is half-written: every file is written atomically, the report first and
``image_points.csv`` last, and the new table is checked by loading the survey from a copy
before it replaces the old one.  Features are cached in ``<outdir>/features/`` (``.npz`` per
photo): a rerun with other matching options does not detect again.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._util import provenance, write_csv_atomic, write_json_atomic
from ..errors import SurveyError, location
from .context import StageContext as Context

__all__ = ["match", "run", "MatchResult", "planned", "default_options", "image_files", "survey_with", "task_mapper",
           "MIN_TIE_POINTS_PER_PHOTO", "DEFAULT_PREFIX"]

log = logging.getLogger(__name__)

#: ``lidarcat run`` plans the match stage when the survey has fewer tie points than this per photo
MIN_TIE_POINTS_PER_PHOTO = 10
#: id prefix of the automatic tie points (``tp000001`` ...)
DEFAULT_PREFIX = "tp"
#: DSM cell of the surface of the guided search, m
SURFACE_CELL_M = 2.0


@dataclass(frozen=True)
class MatchResult:
    """What :func:`match` wrote.

    Attributes
    ----------
    image_points : Path
        The survey's image_points.csv (rewritten).
    outdir : Path
        The report folder.
    n_photos, n_pairs, n_pairs_verified, n_tie_points, n_observations, n_replaced : int
        Photos, matched pairs, pairs with verified matches, tie points and their observations
        written, earlier automatic rows replaced.
    surface : str
        Where the heights came from ("lidar dsm", "ground points", "height_m").
    seconds : dict
    summary : dict
        The report (``match_report.json``).
    """

    image_points: Path
    outdir: Path
    n_photos: int
    n_pairs: int
    n_pairs_verified: int
    n_tie_points: int
    n_observations: int
    n_replaced: int
    surface: str
    seconds: dict[str, float] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)


def planned(survey: Any) -> str | None:
    """Why ``lidarcat run`` skips the match stage for *survey* (None: it is planned)."""
    if not getattr(survey, "has_images", False):
        return "the photos have no image files (photos.csv column image, or images/<photo>.png)"
    n_tie = len(survey.tie_points)
    if n_tie >= MIN_TIE_POINTS_PER_PHOTO * len(survey.photos):
        return (f"the survey has {n_tie} tie points (>= {MIN_TIE_POINTS_PER_PHOTO} per photo); "
                f"`lidarcat match SURVEY` matches again")
    return None


def image_files(survey: Any) -> list[Path]:
    """The image file of every photo that has one (the inputs of the match stage)."""
    out = []
    for pid in survey.photo_ids:
        try:
            out.append(survey.image_path(pid))
        except SurveyError:
            pass
    return out


def default_options(survey: Any) -> Any:
    """The engine's MatchOptions, with the search sds the largest of photos.csv when every photo gives them."""
    import dataclasses

    from ..match import MatchOptions

    photos = survey.photos
    sdp = [float(np.max(p.sd_position_m)) for p in photos if p.sd_position_m is not None]
    sda = [float(np.max(p.sd_attitude_deg)) for p in photos if p.sd_attitude_deg is not None]
    options = MatchOptions()
    if len(sdp) == len(photos) and len(sda) == len(photos) and max(sdp) > 0 and max(sda) > 0:
        options = dataclasses.replace(options, sd_position_m=max(sdp), sd_angle_deg=max(sda))
    return options


def _eo(photo: Any) -> np.ndarray | None:
    if photo.position_m is None or photo.attitude_deg is None:
        return None
    return np.r_[np.asarray(photo.position_m, float), np.deg2rad(np.asarray(photo.attitude_deg, float))]


def _surface(survey: Any, eos: list[np.ndarray | None], height_m: float | None, dem: Any = None,
             height_sd_m: float | None = None) -> tuple[Any, str]:
    """The height surface: a DEM/DSM GeoTIFF when given, else the LiDAR DSM over the footprints, else
    *height_m*, else the mean height of the ground points."""
    from ..match import HeightSurface, footprint

    if dem is not None:
        from ..lidar.geotiff import read_geotiff

        grid, t, _ = read_geotiff(dem)
        g = np.asarray(grid if grid.ndim == 2 else grid[..., 0], float)
        if not np.isfinite(g).any():
            raise SurveyError(f"{dem}: the height model has no value")
        return HeightSurface(float(np.nanmean(g)), g, float(t.x0), float(t.y0), float(t.cell_m),
                             sd_m=height_sd_m if height_sd_m is not None else 2.0), f"dem {Path(dem).name}"

    gp = survey.ground_points
    if height_m is not None:
        mean, sd, source = float(height_m), 10.0 if height_sd_m is None else float(height_sd_m), "height_m"
    elif len(gp):
        h = np.asarray(gp.enh_m[:, 2], float)
        mean, sd, source = float(np.mean(h)), max(float(np.std(h)), 2.0), "ground points"
    else:
        mean, sd, source = float("nan"), 0.0, ""
    if survey.lidar_paths and all(e is not None for e in eos):
        from ..lidar import TileIndex
        from ..lidar.raster import rasterize

        index = TileIndex.build([str(p) for p in survey.lidar_paths], crs=survey.lidar_crs)
        b = index.bounds
        mid = HeightSurface(0.5 * (b.zmin + b.zmax), sd_m=0.5 * (b.zmax - b.zmin))
        fps = np.vstack([footprint(survey.camera_of(p.id), e, mid) for p, e in zip(survey.photos, eos)])
        area = (max(fps[:, 0].min() - 50, b.xmin), max(fps[:, 1].min() - 50, b.ymin),
                min(fps[:, 0].max() + 50, b.xmax), min(fps[:, 1].max() + 50, b.ymax))
        if area[0] < area[2] and area[1] < area[3]:
            grid, t = rasterize(index.query_box(*area), SURFACE_CELL_M, "dsm", bounds=area)
            g = np.asarray(grid, float)
            if np.isfinite(g).any():
                return HeightSurface(float(np.nanmean(g)), g, float(t.x0), float(t.y0), float(t.cell_m),
                                     sd_m=1.0), "lidar dsm"
    if not source:
        if all(e is None for e in eos):
            return HeightSurface(0.0, sd_m=0.0), "none (no orientations)"
        raise SurveyError(f"{survey.toml_path}: no LiDAR tiles and no ground points to tell the ground height "
                          f"under the photos; give it with --height (m)")
    return HeightSurface(mean, sd_m=sd), source


def _photo_image(survey: Any, photo: Any) -> Any:
    """What the feature cache needs to read *photo*'s image and check it (:class:`PhotoImage`)."""
    from ._feature_cache import PhotoImage

    cam = survey.camera_of(photo.id)
    where = location(survey.files.get("photos", survey.toml_path), photo.line, "image")
    return PhotoImage(photo.id, Path(survey.image_path(photo.id)), int(cam.columns_px), int(cam.rows_px),
                      str(cam.id), where)


def _load_image(survey: Any, photo: Any) -> np.ndarray:
    """The photo's image, decoded; a located SurveyError for a file that cannot be decoded or has another size."""
    from ._feature_cache import load_photo_image

    return load_photo_image(_photo_image(survey, photo), SurveyError)


def task_mapper(workers: int = 1, scheduler: str | None = None, client: Any = None) -> Any:
    """The engine's task mapper (:data:`lidarcat.match.TaskMap`) on the runner of :mod:`lidarcat.lidar.jobs`.

    *scheduler*: ``threads`` (default; *workers* threads), ``synchronous``, ``processes`` (a local
    Dask cluster of *workers* processes) or the address of a running Dask scheduler; *client* one
    :func:`lidarcat.lidar.jobs.dask_client` for all calls.
    """
    from ..lidar.jobs import map_tasks

    sched = scheduler or "threads"

    def mapper(task: Any, shared: Any, items: Any, progress: Any = None) -> list:
        return map_tasks(task, shared, items, workers=workers, scheduler=sched, client=client, progress=progress)

    return mapper


def _table(survey: Any, new_photo: np.ndarray, new_point: np.ndarray, new_px: np.ndarray, prefix: str,
           new_sd_px: np.ndarray | None = None) -> tuple[list[str], list[list[Any]], int]:
    """The rows of the new image_points.csv: kept rows, then the tie points; (header, rows, replaced).

    *new_sd_px* (n, 2): the tie points' sds in pixels, written as ``sd_x_mm, sd_y_mm`` (times the
    pixel size of each photo's camera); the kept rows without sd stay empty (the survey's
    ``image_sd_mm``)."""
    ip = survey.image_points
    auto = np.array([bool(re.fullmatch(re.escape(prefix) + r"\d+", p)) for p in ip.point.tolist()], bool)
    auto &= ~np.isin(ip.point, survey.ground_points.point)
    keep = ~auto
    clash = set(new_point.tolist()) & (set(ip.point[keep].tolist()) | set(survey.ground_points.point.tolist()))
    if clash:
        raise SurveyError(f"{ip.path}: point id {sorted(clash)[0]!r} of the new tie points is already used; "
                          f"choose another --prefix")
    with_xy = bool(np.isfinite(ip.xy_mm).any()) or survey.settings.observations == "corrected" and len(ip) > 0
    with_sd = bool(np.isfinite(ip.sd_mm).any()) or new_sd_px is not None
    header = ["photo", "point", "col_px", "row_px"] + (["x_mm", "y_mm"] if with_xy else []) + (
        ["sd_x_mm", "sd_y_mm"] if with_sd else [])
    rows: list[list[Any]] = []

    def num(v: float) -> Any:
        return "" if not np.isfinite(v) else float(v)

    for i in np.flatnonzero(keep):
        r = [ip.photo[i], ip.point[i], num(ip.pixel_px[i, 0]), num(ip.pixel_px[i, 1])]
        if with_xy:
            r += [num(ip.xy_mm[i, 0]), num(ip.xy_mm[i, 1])]
        if with_sd:
            r += [num(ip.sd_mm[i, 0]), num(ip.sd_mm[i, 1])]
        rows.append(r)
    xy = np.full((len(new_px), 2), np.nan)
    sd_mm = np.full((len(new_px), 2), np.nan)
    for pid in np.unique(new_photo):
        sel = new_photo == pid
        cam = survey.camera_of(str(pid))
        if with_xy:
            xy[sel] = cam.pixel_to_photo(new_px[sel])
        if new_sd_px is not None:
            sd_mm[sel] = np.asarray(new_sd_px, float)[sel] * [cam.pixel_size_x_mm, cam.pixel_size_y_mm]
    for k in range(len(new_px)):
        r = [new_photo[k], new_point[k], round(float(new_px[k, 0]), 3), round(float(new_px[k, 1]), 3)]
        if with_xy:
            r += [round(float(xy[k, 0]), 6), round(float(xy[k, 1]), 6)]
        if with_sd:
            r += [num(float(f"{sd_mm[k, 0]:.3g}")), num(float(f"{sd_mm[k, 1]:.3g}"))]
        rows.append(r)
    return header, rows, int(auto.sum())


def _coverage(xy: np.ndarray, cols: int, rows: int, grid: tuple[int, int]) -> float:
    """Share of the grid cells of a photo holding at least one observation."""
    if len(xy) == 0:
        return 0.0
    gr, gc = grid
    c = np.clip((xy[:, 0] + 0.5) / cols * gc, 0, gc - 1).astype(int)
    r = np.clip((xy[:, 1] + 0.5) / rows * gr, 0, gr - 1).astype(int)
    return float(len(np.unique(r * gc + c)) / (gr * gc))


def match(survey_dir: Any, outdir: str | Path | None = None, *, options: Any = None, features: Any = None,
          workers: int = 1, scheduler: str | None = None, height_m: float | None = None,
          prefix: str = DEFAULT_PREFIX, cache: bool = True,
          table: str | Path | None = None, refine: bool = True, dem: str | Path | None = None,
          height_sd_m: float | None = None,
          progress: Callable[[str, int, int], None] | None = None) -> MatchResult:
    """Tie points of a survey's photos into its image_points.csv (module docstring).

    Parameters
    ----------
    survey_dir : path or lidarcat.Survey
    outdir : path or None
        Report (and feature cache) folder; default ``<survey>/out/match``.
    options : lidarcat.match.MatchOptions or None
        Matching options; default: the engine's, with ``sd_position_m`` / ``sd_angle_deg`` the largest
        sds of photos.csv when it gives them.
    features : lidarcat.match.FeatureOptions or None
    workers : int
        Threads (or worker processes) for the photos and the pairs.
    scheduler : str or None
        ``threads`` (default), ``synchronous``, ``processes`` (a local Dask cluster of *workers*
        single-threaded processes) or the address of a running Dask scheduler (``tcp://host:8786``;
        every worker must see the survey's images and *outdir*): :func:`lidarcat.lidar.jobs.map_tasks`.
        The tie points do not depend on it.
    height_m : float or None
        Mean ground height, m, when the survey has no LiDAR tiles (default: mean of the ground points).
    dem : path or None
        A DEM/DSM GeoTIFF in the survey CRS: the surface instead of the LiDAR tiles or a mean height.
    height_sd_m : float or None
        Sd of a height read on the surface, m (default: 2 for a DEM, 10 for *height_m*, the spread of
        the ground points for their mean): the search ellipse grows with it along the base.
    prefix : str
        Id prefix of the tie points.
    cache : bool
        Keep the features in ``<outdir>/features/``.
    refine : bool
        Refine every observation to a fraction of a pixel against its track's first one
        (:func:`lidarcat.match.refine_observations`: correlation peak, 15 x 15 px templates).
    table : path or None
        Where the new image_points table goes; default the survey's own ``image_points.csv``
        (``lidarcat run`` writes it into its stage folder instead: it writes nothing outside OUTDIR).
    progress : callable, optional
        ``progress(step, done, total)``, steps ``features``, ``pairs``.

    Raises
    ------
    SurveyError
        A photo without image, an image that cannot be decoded or has another size than its camera, no
        height for the surface; the message names photos.csv's line.
    lidarcat.match.MatchError
        No two photos overlap, or no pair verifies.  Nothing is written in either case.
    """
    import dataclasses

    from ..match import FeatureOptions, match_block
    from ._feature_cache import FeatureCache, PhotoFeatures
    from ..survey.folder import Survey

    t_all = time.perf_counter()
    survey = survey_dir if isinstance(survey_dir, Survey) else Survey.load(survey_dir)
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_-]*", prefix):
        raise SurveyError(f"tie point prefix {prefix!r}: use letters, digits, _ and - (starting with a letter)")
    out = Path(outdir) if outdir is not None else survey.output_dir() / "match"
    photos = list(survey.photos)
    if len(photos) < 2:
        raise SurveyError(f"{survey.files.get('photos', survey.toml_path)}: {len(photos)} photo; matching needs two")
    paths = [survey.image_path(p.id) for p in photos]           # a photo without image: located error first
    eos = [_eo(p) for p in photos]
    options = default_options(survey) if options is None else options
    features = features or FeatureOptions()
    surface, surface_source = _surface(survey, eos, height_m, dem, height_sd_m)
    store = FeatureCache(out / "features" if cache else None, features, spill_in=out)
    cams = [survey.camera_of(p.id) for p in photos]
    feats = PhotoFeatures(store, [_photo_image(survey, p) for p in photos], SurveyError)
    sched = scheduler or "threads"
    from ..lidar.jobs import dask_client

    try:
        with dask_client(workers, sched) as client:
            res = match_block(cams, eos, feats, surface=surface, options=options, workers=workers,
                              ids=[p.id for p in photos], progress=progress,
                              mapper=task_mapper(workers, sched, client))
    finally:
        store.close()       # the spilled features of --no-cache (a kept cache stays)
    tr = res.tracks
    xy_obs = res.xy_px
    n_refined = 0
    t_ref = time.perf_counter()
    refined_sd = None
    if refine and len(tr):
        from functools import lru_cache

        from ..match.features import grey8
        from ..match.refine import refine_with_precision

        @lru_cache(maxsize=4)
        def grey(i: int) -> np.ndarray:
            return grey8(_load_image(survey, photos[i]))

        ref = refine_with_precision(tr.track, tr.photo, res.xy_px, grey, half_px=7)
        xy_obs, refined_sd = ref.xy_px, ref.sd_px
        n_refined = int(ref.moved.sum())
        grey.cache_clear()
    t_ref = time.perf_counter() - t_ref
    from ..match.refine import observation_sds

    sd_px = observation_sds(tr.track, tr.photo, refined_sd)
    ids = np.array([p.id for p in photos], dtype=object)
    new_photo = ids[tr.photo].astype(str)
    width = max(6, len(str(tr.n_tracks)))
    new_point = np.array([f"{prefix}{t + 1:0{width}d}" for t in tr.track.tolist()], dtype=str)
    header, rows, replaced = _table(survey, new_photo, new_point, xy_obs, prefix, sd_px)

    # the report
    per_photo = []
    n_kp = list(res.n_keypoints)
    for i, p in enumerate(photos):
        sel = tr.photo == i
        per_photo.append({"photo": p.id, "keypoints": n_kp[i], "tie_points": int(len(np.unique(tr.track[sel]))),
                          "observations": int(sel.sum()),
                          "coverage": round(_coverage(xy_obs[sel], cams[i].columns_px, cams[i].rows_px,
                                                      options.grid), 3)})
    pairs = [{"photo_a": photos[r.a].id, "photo_b": photos[r.b].id,
              "overlap": None if not np.isfinite(r.overlap) else round(r.overlap, 3), "matches": r.n_matches,
              "candidates": r.n_candidates, "inliers": r.n_inliers, "rejected": r.reason,
              "seconds": round(r.seconds, 3)} for r in res.pairs]
    rays = tr.rays()
    seconds = {k: round(v, 3) for k, v in res.seconds.items()}
    seconds["refine"] = round(t_ref, 3)
    seconds["total"] = round(time.perf_counter() - t_all, 3)
    summary = {
        "survey": str(survey.root), "photos": len(photos), "pairs": len(res.pairs),
        "pairs_verified": sum(r.n_inliers > 0 for r in res.pairs),
        "tie_points": int(tr.n_tracks), "observations": int(len(tr)),
        "rays": {str(k): int(v) for k, v in enumerate(np.bincount(rays)) if v},
        "inconsistent_tracks_dropped": int(tr.n_inconsistent),
        "tracks_before_distribution": int(res.n_tracks_before),
        "refined_observations": n_refined,
        "sd_px": {"median": round(float(np.median(sd_px)), 4) if len(sd_px) else None,
                  "p90": round(float(np.percentile(sd_px, 90)), 4) if len(sd_px) else None},
        "replaced_rows": replaced, "prefix": prefix, "surface": surface_source,
        "pairing": "footprints" if all(e is not None for e in eos) else "exhaustive",
        "options": dataclasses.asdict(options), "features": dataclasses.asdict(features),
        "workers": int(workers), "scheduler": sched, "refine": bool(refine), "seconds": seconds,
        "per_photo": per_photo,
        "image_points": str(survey.files.get("image_points", survey.root / "image_points.csv")),
    }
    out.mkdir(parents=True, exist_ok=True)
    write_csv_atomic(out / "match_pairs.csv", list(pairs[0]) if pairs else ["photo_a", "photo_b"],
                     [list(r.values()) for r in pairs])
    write_csv_atomic(out / "match_photos.csv", list(per_photo[0]), [list(r.values()) for r in per_photo])
    write_json_atomic(out / "match_report.json", summary)
    if table is None:
        ip_path = Path(survey.files.get("image_points", survey.root / survey.config.files.image_points))
        _check_then_write(survey, ip_path, header, rows, summary, paths)
    else:
        ip_path = Path(table)
        write_csv_atomic(ip_path, header, rows)
    log.info("match: %d tie points, %d observations on %d photos (%d pairs verified of %d) -> %s",
             tr.n_tracks, len(tr), len(photos), summary["pairs_verified"], len(res.pairs), ip_path)
    return MatchResult(Path(ip_path), out, len(photos), len(res.pairs), summary["pairs_verified"], int(tr.n_tracks),
                       int(len(tr)), replaced, surface_source, seconds, summary)


def _check_then_write(survey: Any, ip_path: Path, header: list[str], rows: list[list[Any]],
                      summary: dict[str, Any], images: list[Path]) -> None:
    """Replace image_points.csv atomically, then load the survey; when it does not load, put the old
    file (and its sidecar) back, atomically too, and raise the load's located error."""
    from .._util import atomic_write, csv_sidecar_path
    from ..survey.folder import Survey

    prov = provenance({"survey.toml": survey.toml_path, **{f"image {p.name}": p for p in images}},
                      {k: summary[k] for k in ("options", "features", "prefix", "surface", "pairing", "refine")},
                      root=survey.root)
    side = csv_sidecar_path(ip_path)
    old = ip_path.read_bytes() if ip_path.is_file() else None
    old_side = side.read_bytes() if side.is_file() else None
    write_csv_atomic(ip_path, header, rows, comments=[
        f"tie points {summary['prefix']}N: lidarcat match (automatic SIFT tie points, pixels col_px, row_px)"],
        provenance=prov)
    try:
        Survey.load(survey.root if not survey.embedded else survey.toml_path)
    except SurveyError:
        for path, data in ((ip_path, old), (side, old_side)):
            if data is None:
                path.unlink(missing_ok=True)
            else:
                with atomic_write(path, "wb") as fh:
                    fh.write(data)
        raise


def survey_with(survey: Any, table: str | Path) -> Any:
    """*survey* with its image observations taken from *table* (an image_points.csv :func:`match` wrote).

    The table holds the survey's own rows plus the tie points, so the survey's settings stay valid.
    """
    import dataclasses

    from .._util import read_csv_table
    from ..survey.folder import ImagePoints

    path = Path(table)
    if Path(survey.files.get("image_points", "")) == path:
        return survey
    t = read_csv_table(path, required=("photo", "point", "col_px", "row_px"),
                       optional=("x_mm", "y_mm", "sd_x_mm", "sd_y_mm"))
    n = len(t.rows)

    def pair(a: str, b: str) -> np.ndarray:
        if not t.has(a):
            return np.full((n, 2), np.nan)
        return np.column_stack([t.floats(a, required=False), t.floats(b, required=False)])

    ip = ImagePoints(np.array(t.column("photo"), dtype=str), np.array(t.column("point"), dtype=str),
                     pair("col_px", "row_px"), pair("x_mm", "y_mm"), pair("sd_x_mm", "sd_y_mm"),
                     np.array(t.lines), path)
    return dataclasses.replace(survey, image_points=ip, files={**survey.files, "image_points": path})


def run(ctx: Context, tmp: Path) -> dict:
    """Tie points of the photos into ``match/image_points.csv`` (the survey's rows plus the tie points) and the
    report; the later stages adjust that table (:func:`lidarcat.pipeline.plan` puts it into ``ctx["survey"]``)."""
    survey = ctx["survey"]
    res = match(survey, tmp, progress=lambda step, done, total: ctx.progress(done, total) if step == "pairs" else None,
                cache=False, table=tmp / "image_points.csv")
    return {k: res.summary[k] for k in ("photos", "pairs", "pairs_verified", "tie_points", "observations",
                                         "replaced_rows", "surface", "pairing")}
