"""Batch roof extraction: job files, tiles, output tables, operator figures.

A **job file** is either the thesis's text format (section 4.2.2), one roof per
line, whitespace separated::

    faixa.xyz P704 677757.8 7183482.0 0.15 5.0

(point-cloud file, point name, approximate E and N, residual threshold in m,
clip radius in m), or a CSV file with a header and the columns ``point, E, N``
plus optional ``threshold_m, radius_m, file, sd_en_m, sd_h_m`` (the last two: the
random noise of the points in plan and height, m, which sets the weights of the
plane fits -- see :class:`~lidarcat.control.params.ExtractionParams`).  Relative file names are
relative to the job file's folder.  ``#`` starts a comment line.

:func:`extract_batch` runs :func:`lidarcat.control.vertices.extract_roof` on every job;
a degenerate roof gives a falsy :class:`~lidarcat.control.vertices.ControlPoint` with a
status and a reason, and the batch goes on.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .._util import atomic_dir, parse_float, read_csv_table, write_csv_atomic, write_json_atomic
from .vertices import ROW_FIELDS, Candidate, ControlPoint, extract_roof
from ..errors import ClipError, ExtractionError, LidarcatError, location
from .params import ExtractionParams, get_params

__all__ = [
    "Job", "read_jobs", "extract_batch", "write_control_csv", "write_planes_csv",
    "write_candidates", "plot_control_point", "write_figures", "PLANE_FIELDS",
]

log = logging.getLogger(__name__)

PLANE_FIELDS = ["point", "plane", "a", "b", "c", "d", "sd_a", "sd_b", "sd_c", "sd_offset_m",
                "n_used", "n_rejected", "rms_m", "slope_deg", "aspect_deg"]


@dataclass(frozen=True)
class Job:
    """One roof to extract: name, approximate position, threshold, radius, point file."""

    point: str
    e_m: float
    n_m: float
    threshold_m: float | None = None
    radius_m: float | None = None
    file: Path | None = None
    line: int = 0
    sd_en_m: float | None = None
    sd_h_m: float | None = None


def read_jobs(path: str | os.PathLike) -> list[Job]:
    """Read a thesis job file (whitespace) or a CSV job file.

    Raises
    ------
    ExtractionError
        Missing file, wrong number of fields, non-numeric value (names file and line).
    """
    from .._util import read_text

    path = Path(path)
    text = read_text(path, ExtractionError)
    first = next((ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")), "")
    # CSV: a header with a "point" column; a thesis line has 6 fields and may use decimal commas
    if "," in first and ("point" in [c.strip() for c in first.split(",")] or len(first.split()) != 6):
        try:
            t = read_csv_table(path, required=("point", "E", "N"),
                               optional=("threshold_m", "radius_m", "file", "sd_en_m", "sd_h_m"))
            e, n = t.floats("E"), t.floats("N")
            thr = t.floats("threshold_m", required=False)
            rad = t.floats("radius_m", required=False)
            sde = t.floats("sd_en_m", required=False)
            sdh = t.floats("sd_h_m", required=False)
        except LidarcatError as ex:
            raise ExtractionError(str(ex)) from ex
        for col, vals in (("threshold_m", thr), ("radius_m", rad), ("sd_en_m", sde), ("sd_h_m", sdh)):
            bad = np.flatnonzero(~(np.isnan(vals) | (vals > 0)))
            if len(bad):
                raise ExtractionError(f"{location(path, t.lines[bad[0]], col)}: must be positive "
                                      f"(got {vals[bad[0]]:g}); leave it empty for the default")
        for i, (pid, line) in enumerate(zip(t.column("point"), t.lines)):
            if not pid:
                raise ExtractionError(f"{location(path, line, 'point')}: empty point id; name the point")
            for col, v in (("E", e[i]), ("N", n[i])):
                _check_coordinate(path, line, col, float(v))
        files = t.column("file") if t.has("file") else [""] * len(t.rows)
        return [Job(p, float(e[i]), float(n[i]),
                    None if math.isnan(thr[i]) else float(thr[i]),
                    None if math.isnan(rad[i]) else float(rad[i]),
                    (path.parent / files[i]) if files[i] else None, t.lines[i],
                    None if math.isnan(sde[i]) else float(sde[i]),
                    None if math.isnan(sdh[i]) else float(sdh[i]))
                for i, p in enumerate(t.column("point"))]
    jobs = []
    names = ("file", "point", "E", "N", "threshold", "radius")
    for lineno, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip() or raw.lstrip().startswith("#"):
            continue
        f = raw.split()
        if len(f) != 6:
            raise ExtractionError(f"{location(path, lineno)}: {len(f)} fields, expected 6 "
                                  f"(file point E N threshold radius, e.g. "
                                  f"'faixa.xyz P704 677757.8 7183482.0 0.15 5.0')")
        vals = []
        for k in (2, 3, 4, 5):
            try:
                v = parse_float(f[k], decimal_comma=True)
            except ValueError as ex:
                raise ExtractionError(f"{location(path, lineno, names[k])}: {ex}") from None
            if not math.isfinite(v):
                raise ExtractionError(f"{location(path, lineno, names[k])}: {f[k]!r} is not a finite number")
            if k in (2, 3):
                _check_coordinate(path, lineno, names[k], v)
            vals.append(v)
        for k, v in ((4, vals[2]), (5, vals[3])):
            if not v > 0:
                raise ExtractionError(f"{location(path, lineno, names[k])}: must be positive (got {v:g})")
        jobs.append(Job(f[1], vals[0], vals[1], vals[2], vals[3], path.parent / f[0], lineno))
    if not jobs:
        raise ExtractionError(f"{path}: no jobs (expected lines like "
                              f"'faixa.xyz P704 677757.8 7183482.0 0.15 5.0')")
    return jobs


def _check_coordinate(path: Path, line: int, name: str, value: float) -> None:
    """A job position beyond the sane range of the point readers (+-1e9 m) is a located error."""
    from ..lidar.readers import MAX_ABS_COORD_M

    if abs(value) > MAX_ABS_COORD_M:
        raise ExtractionError(f"{location(path, line, name)}: {value!r} is outside the sane range "
                              f"+-{MAX_ABS_COORD_M:g} m")


class _Source:
    """Points for a job: a tile index over --lidar paths, or the job's own file."""

    def __init__(self, lidar: Sequence[str | os.PathLike] | None, crs: Any,
                 index_cache: str | os.PathLike | None = None) -> None:
        self.crs = crs
        self.lidar = list(lidar or [])
        self.index_cache = index_cache
        self._index = None
        self._per_file: dict[Path, Any] = {}

    def query(self, job: Job, radius_m: float, clip_m: float | None = None):
        """The points within *radius_m* of the job's position; *clip_m* (m) is the clip radius the user
        asked for, named by the metres check when the points are loaded farther out (the radius-stability
        check's larger clips)."""
        from ..lidar import TileIndex
        from ..lidar.crs import require_metres

        if self.lidar:
            if self._index is None:
                self._index = TileIndex.build(self.lidar, crs=self.crs, cache_path=self.index_cache)
            idx = self._index
        else:
            if job.file is None:
                raise ExtractionError(f"job {job.point}: no point file in the job and no --lidar given")
            if job.file not in self._per_file:
                if not job.file.exists():
                    raise ExtractionError(f"job {job.point} (line {job.line}): point file {job.file} not found")
                self._per_file[job.file] = TileIndex.build([job.file], crs=self.crs)
            idx = self._per_file[job.file]
        if clip_m is not None and clip_m != radius_m:
            require_metres(idx.crs, f"a clip radius of {clip_m:g} m", str(idx.tiles[0].path) if idx.tiles else "")
        return idx.query_radius((job.e_m, job.n_m), radius_m)


def extract_batch(
    jobs: Iterable[Job],
    *,
    lidar: Sequence[str | os.PathLike] | None = None,
    points: Any = None,
    crs: Any = None,
    params: ExtractionParams | str | None = None,
    spec_sd: tuple[float, float] | None = None,
    progress: Callable[[int], None] | None = None,
    index_cache: str | os.PathLike | None = None,
) -> list[ControlPoint]:
    """Extract every job; failures are rows with a status, never exceptions.

    Parameters
    ----------
    jobs : iterable of Job
    lidar : paths, optional
        Tiles for all jobs (default: each job's own file).
    points : (N, 3) array or PointCloud, optional
        Points for all jobs (instead of files).
    crs : CRS-like, optional
        CRS of tiles that carry none (e.g. ``"EPSG:7415"`` for AHN3).
    params : ExtractionParams or preset name
        The job's threshold, radius and point sds override the preset's.
    spec_sd : (plan, height), optional
        Replace every point's covariance by these specification sds (m).
    progress : callable(int), optional
        Called with 1 after each job (an increment, like ``click.progressbar.update``).
    index_cache : path, optional
        JSON cache of the tile index of *lidar* (bounds, counts and the block
        index that lets a clip decode only the parts of a LAZ tile it needs;
        see :meth:`lidarcat.lidar.TileIndex.build`), reused and updated.
    """
    p0 = get_params(params)
    src = None if points is not None else _Source(lidar, crs, index_cache)
    out = []
    for job in jobs:
        p = p0.replace(**{k: v for k, v in (("residual_threshold_m", job.threshold_m),
                                             ("radius_m", job.radius_m), ("sd_en_m", job.sd_en_m),
                                             ("sd_h_m", job.sd_h_m)) if v is not None})
        try:
            # the radius-stability check clips up to max(stability_scales) x radius_m about the vertex,
            # which lies within max_offset_m (default radius_m / 2) of the position
            reach = p.radius_m
            if p.stability_scales:
                reach = p.radius_m * max((1.0, *p.stability_scales)) + (
                    p.max_offset_m if p.max_offset_m is not None else 0.5 * p.radius_m)
            cloud = points if points is not None else src.query(job, reach, clip_m=p.radius_m)
            cp = extract_roof(cloud, (job.e_m, job.n_m), params=p, point_id=job.point,
                              clipped=points is None and reach == p.radius_m)
        except ClipError as ex:
            cp = ControlPoint.failed(job.point, (job.e_m, job.n_m), "too_few_points", str(ex))
        if spec_sd is not None and cp:
            cp = cp.with_specification(*spec_sd)
        out.append(cp)
        if progress is not None:
            progress(1)
    return out


# ------------------------------------------------------------------ writers
def write_control_csv(path: str | os.PathLike, points: Sequence[ControlPoint], comments: Sequence[str] = ()) -> Path:
    """Control points, one row each (columns :data:`~lidarcat.control.vertices.ROW_FIELDS`)."""
    rows = [[cp.to_row()[k] for k in ROW_FIELDS] for cp in points]
    return write_csv_atomic(path, ROW_FIELDS, rows, comments=comments)


def write_planes_csv(path: str | os.PathLike, points: Sequence[ControlPoint]) -> Path:
    """Planes of every point: a, b, c, d (unit normal), sds, counts, RMS, slope, aspect."""
    rows = []
    for cp in points:
        for k, pl in enumerate(cp.planes, start=1):
            d = pl.to_dict()
            rows.append([cp.point_id, k] + [d[f] for f in PLANE_FIELDS[2:]])
    return write_csv_atomic(path, PLANE_FIELDS, rows,
                            comments=["a E + b N + c h + d = 0 with (a, b, c) the unit normal (up); "
                                      "sd_a..sd_c with d held fixed (thesis Table 4 datum); metres, degrees"])


def write_candidates(path: str | os.PathLike, candidates: Sequence[Candidate], crs: Any = None) -> Path:
    """Candidates as GeoJSON (``.geojson``/``.json``) or CSV (anything else).

    With a CRS (the tiles' own, or the one given), the GeoJSON carries a
    ``"crs"`` member naming it (``urn:ogc:def:crs:EPSG::7415``; GDAL, QGIS and
    GeoPandas read it) and a ``.prj`` file with its WKT is written next to
    the output (both atomically), so the metres are never read as WGS 84.
    """
    from ..lidar.crs import resolve_crs

    path = Path(path)
    crs_obj = resolve_crs(crs)
    if path.suffix.lower() in (".geojson", ".json"):
        fc: dict[str, Any] = {"type": "FeatureCollection",
                              "features": [c.to_feature() for c in candidates]}
        if crs_obj is not None:
            from ..lidar.crs import geojson_crs_member

            fc["crs"] = geojson_crs_member(crs_obj)
            from .._util import write_text_atomic

            write_text_atomic(path.with_suffix(".prj"), _esri_wkt(crs_obj))
        return write_json_atomic(path, fc)
    fields = ROW_FIELDS + ["score"]
    rows = [[c.point.to_row()[k] for k in ROW_FIELDS] + [c.score] for c in candidates]
    return write_csv_atomic(path, fields, rows)


def _esri_wkt(crs: Any) -> str:
    """The ESRI WKT a ``.prj`` holds (the horizontal part), or WKT2 when pyproj cannot write it."""
    parts = [crs] + [c for c in (crs.sub_crs_list or []) if not c.is_vertical]
    for c in parts:
        try:
            text = c.to_wkt("WKT1_ESRI")
        except Exception:  # pyproj.exceptions.CRSError for CRSs ESRI WKT cannot express
            text = None
        if text:
            return text
    return crs.to_wkt()


# ------------------------------------------------------------------ figures
def plot_control_point(cp: ControlPoint, path: str | os.PathLike, *, ellipse_k: float = 2.4477) -> Path:
    """Operator view like thesis Figure 19: the clip from above, faces in colour,
    rejected points in grey crosses, the vertex and its 95 % error ellipse (x 10)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    fig, ax = plt.subplots(figsize=(6, 6), dpi=100)
    try:
        if cp.labels is not None:
            xyz, lab = cp.labels
            o = cp.approx_en
            rej = lab < 0
            ax.scatter(xyz[rej, 0] - o[0], xyz[rej, 1] - o[1], s=6, c="0.6", marker="x", label="rejected")
            used_ids = sorted({int(v) for v in lab[lab >= 0]})
            inter = {pl.label for pl in cp.planes}
            others = [k for k in used_ids if k not in inter]
            if others:
                m = np.isin(lab, others)
                ax.scatter(xyz[m, 0] - o[0], xyz[m, 1] - o[1], s=5, c="0.8", label="other faces")
            for k in sorted(inter):
                m = lab == k
                pl = next(p for p in cp.planes if p.label == k)
                ax.scatter(xyz[m, 0] - o[0], xyz[m, 1] - o[1], s=8,
                           label=f"face {k + 1}: {pl.slope_deg:.0f} deg / {pl.aspect_deg:.0f}")
        else:
            o = cp.approx_en
        ax.plot(0, 0, "k+", ms=14, label="approximate position")
        if np.all(np.isfinite(cp.enh_m)):
            x, y = cp.enh_m[0] - o[0], cp.enh_m[1] - o[1]
            ax.plot(x, y, "r*", ms=14, label="intersection")
            if np.all(np.isfinite(cp.cov_m2)):
                a, b, az = cp.error_ellipse(ellipse_k)
                ax.add_patch(Ellipse((x, y), 2 * a * 10, 2 * b * 10, angle=90 - az, fill=False,
                                     color="r", lw=1.5, label="95 % ellipse x 10"))
        ax.set_aspect("equal")
        ax.set_xlabel("E - E0 (m)")
        ax.set_ylabel("N - N0 (m)")
        title = f"{cp.point_id}: {cp.status}, {cp.n_planes} planes"
        if cp:
            title += f"\nh = {cp.enh_m[2]:.3f} m, sd E/N/h = {cp.sd_e_m:.3f}/{cp.sd_n_m:.3f}/{cp.sd_h_m:.3f} m"
        else:
            title += f"\n{cp.reason[:80]}"
        ax.set_title(title, fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
        fig.tight_layout()
        path = Path(path)
        fig.savefig(path)
    finally:
        plt.close(fig)
    return path


def write_figures(folder: str | os.PathLike, points: Sequence[ControlPoint]) -> list[Path]:
    """One PNG per point (``<point>.png``) into *folder*, written atomically."""
    out = []
    folder = Path(folder)
    with atomic_dir(folder) as tmp:
        for cp in points:
            name = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in cp.point_id) or "point"
            plot_control_point(cp, tmp / f"{name}.png")
            out.append(folder / f"{name}.png")
    return out
