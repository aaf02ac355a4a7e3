"""The quality report of a run: what Pix4D's and OpenDroneMap's quality reports taught users to expect.

:func:`quality_report` reads a run's output folder (the adjustment tables,
the check-point discrepancies, the products and orthophotos) and the survey,
and returns a one-line verdict and the Markdown of its sections with their
figures (PNG bytes, :mod:`lidarcat.report.quality_figures`).  The ``report``
stage puts the verdict at the top of ``index.md``/``index.html`` and the
sections below the runs; the HTML page embeds the figures (data URIs).

Sections (``## title`` -> HTML id), each present when its inputs exist:

==========================  ==============================  ==================================================
section                     id                              from
==========================  ==============================  ==================================================
Verdict                     ``verdict``                     stages, chi-square, blunders, check RMSE, CE90/LE90
Image residuals             ``image-residuals``             residuals.csv, eop.csv, points.csv: vectors by image
                                                            position (the residual of each observation at the
                                                            projection of its adjusted point), histograms
Precision                   ``precision``                   eop_covariance.csv (else eop.csv sds), points.csv
Overlap                     ``overlap``                     footprints on the mean height of the points: photos
                                                            per ground cell
Control and check points    ``control-and-check-points``    residuals.csv (control), discrepancies.csv (check)
Camera distortion           ``camera-distortion``           the survey's cameras
Accuracy standards          ``accuracy-standards``          PEC / ASPRS / NSSDA of each run, CE90 / LE90
Tie points                  ``tie-points``                  points.csv roles, residuals.csv (track lengths)
LiDAR density               ``lidar-density``               the survey's LiDAR tiles (X, Y of every point)
Products and orthophotos    ``products-and-orthophotos``    products/*.tif, mapping/*.tif (thumbnails)
==========================  ==============================  ==================================================

The image position of an observation is the projection of its adjusted point
through the adjusted orientation (the corrected photo coordinates, x right, y
up, mm): what the residual vector is drawn at.  CE90/LE90 are those of
:func:`lidarcat.accuracy.standards.ce90_le90`.
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._util.formatting import format_number as num
from . import quality_figures as qf

__all__ = ["QualityReport", "quality_report", "SECTION_IDS", "MAX_DENSITY_POINTS"]

log = logging.getLogger(__name__)

#: the ids of the sections, in order (tests and docs check them)
SECTION_IDS = ("verdict", "image-residuals", "precision", "overlap", "control-and-check-points",
               "camera-distortion", "accuracy-standards", "tie-points", "lidar-density", "products-and-orthophotos")
#: above this many LiDAR points the density map counts each tile's header points over its box
MAX_DENSITY_POINTS = 60_000_000
_THUMB_PX = 320


@dataclass(frozen=True)
class QualityReport:
    """The verdict line, the Markdown lines of the sections and their figures ``{file name: PNG}``."""

    verdict: str
    lines: list[str] = field(default_factory=list)
    figures: dict[str, bytes] = field(default_factory=dict)


def _rows(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _f(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def quality_report(outdir: str | Path, survey: Any, runs: Mapping[str, Any], *, stages: Sequence[Mapping[str, Any]],
                   tests_failed: Sequence[str] = (), products: Mapping[str, Any] | None = None,
                   mapping: Mapping[str, Any] | None = None, fig_dir: str = "quality",
                   progress: Callable[[int, int], None] | None = None) -> QualityReport:
    """The quality report of the run in *outdir* (see the module docstring).

    Parameters
    ----------
    outdir : path
        The run's output folder (``adjust-<set>/``, ``assess-<set>/``, ``products/``, ``mapping/``).
    survey : lidarcat.survey.Survey
    runs : mapping
        ``runs`` of :func:`lidarcat.stages.report.results` (set -> adjustment, check, standards).
    stages : sequence of mapping
        ``stage``, ``state`` of every planned stage.
    tests_failed : sequence of str
    products, mapping : mapping, optional
        Results of the products and mapping stages.
    fig_dir : str
        Folder of the figures relative to the page (the Markdown links ``fig_dir/name.png``).
    progress : callable, optional
        ``progress(done, total)`` per section.
    """
    outdir = Path(outdir)
    tick = progress or (lambda i, n: None)
    figs: dict[str, bytes] = {}
    lines: list[str] = []
    name = survey.default_control if survey.default_control in runs else next(iter(runs), None)
    adj = outdir / f"adjust-{name}" if name else None
    steps: list[Callable[[], list[str]]] = []
    if adj is not None and (adj / "eop.csv").is_file():
        data = _Adjustment.read(adj, survey)
        steps += [lambda: _residuals(data, name, figs, fig_dir), lambda: _precision(data, name, figs, fig_dir),
                  lambda: _overlap(data, figs, fig_dir),
                  lambda: _control_map(data, outdir / f"assess-{name}" / "discrepancies.csv", name, figs, fig_dir)]
    else:
        data = None
    steps += [lambda: _distortion(survey, figs, fig_dir), lambda: _standards(outdir, runs)]
    if data is not None:
        steps.append(lambda: _tie_points(data, figs, fig_dir))
    steps += [lambda: _density(survey, figs, fig_dir), lambda: _thumbnails(outdir, products, mapping, figs, fig_dir)]
    for k, step in enumerate(steps):
        try:
            lines += step()
        except Exception as ex:  # a figure that cannot be drawn must not lose the report
            log.warning("quality report: a section could not be made (%s: %s)", type(ex).__name__, ex)
        tick(k + 1, len(steps))
    verdict = _verdict(runs, stages, tests_failed, products, mapping, name)
    return QualityReport(verdict, lines, figs)


# ----------------------------------------------------------------------------- data
@dataclass(frozen=True)
class _Adjustment:
    photos: list[str]
    eo: np.ndarray            # (P, 6) m, rad
    eo_cov: np.ndarray        # (P, 6, 6) (diagonal when no eop_covariance.csv)
    full_cov: bool
    points: list[str]
    xyz: np.ndarray           # (Q, 3)
    point_sd: np.ndarray      # (Q, 3)
    roles: list[str]
    obs_photo: np.ndarray     # (n,) photo index
    obs_point: np.ndarray     # (n,) point index
    v_mm: np.ndarray          # (n, 2)
    control: list[tuple[str, np.ndarray]]
    cameras: dict[str, Any]   # photo id -> Camera

    @classmethod
    def read(cls, folder: Path, survey: Any) -> _Adjustment:
        eop = _rows(folder / "eop.csv")
        photos = [r["photo"] for r in eop]
        eo = np.array([[_f(r[k]) for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")] for r in eop])
        eo[:, 3:] = np.radians(eo[:, 3:])
        full = (folder / "eop_covariance.csv").is_file()
        if full:
            from ..survey.covariance import read_eop_covariance

            by = read_eop_covariance(folder / "eop_covariance.csv")
            cov = np.array([by.get(p, np.full((6, 6), np.nan)) for p in photos])
        else:
            sd = np.array([[_f(r.get(f"sd_{k}")) for k in ("X0", "Y0", "Z0", "omega", "phi", "kappa")] for r in eop])
            sd[:, 3:] = np.radians(sd[:, 3:])
            cov = np.einsum("ij,jk->ijk", sd ** 2, np.eye(6))
        pts = _rows(folder / "points.csv")
        ids = [r["point"] for r in pts]
        xyz = np.array([[_f(r[k]) for k in ("E", "N", "h")] for r in pts]).reshape(-1, 3)
        psd = np.array([[_f(r.get(k)) for k in ("sd_E", "sd_N", "sd_h")] for r in pts]).reshape(-1, 3)
        pidx = {p: i for i, p in enumerate(photos)}
        qidx = {q: i for i, q in enumerate(ids)}
        res = _rows(folder / "residuals.csv")
        img = [r for r in res if r["kind"] == "image" and r["photo"] in pidx and r["point"] in qidx]
        control = [(r["point"], np.array([_f(r["vE_m"]), _f(r["vN_m"]), _f(r["vh_m"])]))
                   for r in res if r["kind"] == "control" and r["point"] in qidx]
        cams = {p.id: survey.cameras[p.camera] for p in survey.photos if p.camera in survey.cameras}
        return cls(photos, eo, cov, full, ids, xyz, psd, [r.get("role", "") for r in pts],
                   np.array([pidx[r["photo"]] for r in img], dtype=int),
                   np.array([qidx[r["point"]] for r in img], dtype=int),
                   np.array([[_f(r["vx_mm"]), _f(r["vy_mm"])] for r in img]).reshape(-1, 2), control, cams)

    def image_xy_mm(self) -> np.ndarray:
        """(n, 2) projection of each observation's adjusted point through its adjusted orientation, mm."""
        from ..geometry.collinearity import project

        f = np.array([self.cameras[self.photos[i]].focal_length_mm if self.photos[i] in self.cameras else np.nan
                      for i in self.obs_photo])
        xy, _ = project(self.eo[self.obs_photo], self.xyz[self.obs_point], f)
        return xy

    def camera(self) -> Any:
        return next(iter(self.cameras.values()), None)


# ----------------------------------------------------------------------------- sections
def _fig(figs: dict[str, bytes], fig_dir: str, name: str, png: bytes, caption: str) -> list[str]:
    figs[name] = png
    return ["", f"![{caption}]({fig_dir}/{name})"]


def _residuals(d: _Adjustment, run: str, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    cam = d.camera()
    if cam is None or not len(d.v_mm):
        return []
    xy = d.image_xy_mm()
    ok = np.isfinite(xy).all(axis=1) & np.isfinite(d.v_mm).all(axis=1)
    pix = float(cam.pixel_size_x_mm)
    v_px = d.v_mm[ok] / pix
    rms = np.sqrt(np.mean(v_px ** 2, axis=0))
    per_photo = np.sqrt(np.bincount(d.obs_photo[ok], (v_px ** 2).sum(axis=1), len(d.photos))
                        / np.maximum(np.bincount(d.obs_photo[ok], minlength=len(d.photos)), 1) / 2)
    worst = int(np.argmax(per_photo))
    lines = ["", "## Image residuals", "",
             f"Run {run}: {int(ok.sum())} image observations, RMS x {num(rms[0], 3)} px, y {num(rms[1], 3)} px "
             f"(pixel {pix * 1000:g} um); largest photo RMS {num(per_photo[worst], 3)} px (photo "
             f"{d.photos[worst]}). Residual = adjusted minus observed, at the image position of the "
             "observation. A systematic pattern by position (a swirl, a radial trend) points at the camera "
             "model; random vectors are the pointing noise."]
    frame = cam.frame_size_mm
    lines += _fig(figs, fig_dir, "residual_vectors.png",
                  qf.residual_vectors_figure(xy[ok], d.v_mm[ok], frame, pix), "Image residuals by image position")
    lines += _fig(figs, fig_dir, "residual_histograms.png", qf.residual_histograms_figure(v_px),
                  "Histograms of the image residuals")
    return lines


def _precision(d: _Adjustment, run: str, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    c_cov = d.eo_cov[:, :2, :2]
    free = np.array([r != "control" for r in d.roles]) & np.isfinite(d.point_sd[:, :2]).all(axis=1)
    p_cov = np.einsum("ij,jk->ijk", d.point_sd[free, :2] ** 2, np.eye(2))
    ab_c, _ = qf.ellipse_axes(c_cov)
    ab_p, _ = qf.ellipse_axes(p_cov) if len(p_cov) else (np.zeros((0, 2)), None)
    src = ("the full 6 x 6 covariance of each orientation (eop_covariance.csv)" if d.full_cov
           else "the sds of eop.csv (no eop_covariance.csv: correlations unknown)")
    sd_h = d.point_sd[free, 2]
    lines = ["", "## Precision", "",
             f"Run {run}: 1-sigma plan ellipses of the projection centres from {src}, and of the "
             f"{int(free.sum())} points not used as control (their E, N sds).", "",
             "| what | n | median major semi-axis (m) | largest (m) | median sd h (m) |", "|---|---|---|---|---|",
             f"| projection centres | {len(d.photos)} | {num(np.median(ab_c[:, 0]), 3)} | "
             f"{num(np.max(ab_c[:, 0]), 3)} | {num(np.median(np.sqrt(d.eo_cov[:, 2, 2])), 3)} |"]
    if len(ab_p):
        lines.append(f"| object points | {len(ab_p)} | {num(np.median(ab_p[:, 0]), 3)} | {num(np.max(ab_p[:, 0]), 3)}"
                     f" | {num(np.median(sd_h), 3)} |")
    lines += _fig(figs, fig_dir, "precision_ellipses.png",
                  qf.ellipses_figure(d.eo[:, :2], c_cov, d.xyz[free, :2], p_cov, d.photos),
                  "Precision ellipses of the projection centres and the points")
    return lines


def _overlap(d: _Adjustment, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    from .document import footprints

    cams = {pid: {"focal_length_mm": c.focal_length_mm, "width_mm": c.frame_size_mm[0],
                  "height_mm": c.frame_size_mm[1]} for pid, c in d.cameras.items()}
    eop = [{"photo": p, "X0": e[0], "Y0": e[1], "Z0": e[2], "omega": np.degrees(e[3]), "phi": np.degrees(e[4]),
            "kappa": np.degrees(e[5])} for p, e in zip(d.photos, d.eo)]
    h = float(np.nanmean(d.xyz[:, 2])) if len(d.xyz) else 0.0
    fps = footprints(eop, cams, h)
    if not fps:
        return []
    from matplotlib.path import Path as MPath

    allxy = np.vstack(list(fps.values()))
    xmin, ymin = allxy.min(axis=0)
    xmax, ymax = allxy.max(axis=0)
    cell = max(xmax - xmin, ymax - ymin) / 150
    cols, rows = int(np.ceil((xmax - xmin) / cell)), int(np.ceil((ymax - ymin) / cell))
    gx, gy = np.meshgrid(xmin + (np.arange(cols) + 0.5) * cell, ymax - (np.arange(rows) + 0.5) * cell)
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    count = np.zeros(len(pts), dtype=int)
    for poly in fps.values():
        count += MPath(poly).contains_points(pts)
    count = count.reshape(rows, cols)
    covered = count > 0
    frac = [float((count[covered] >= k).mean()) if covered.any() else 0.0 for k in (2, 3, 5)]
    lines = ["", "## Overlap", "",
             f"Photos per ground cell of {num(cell, 1)} m: the footprints of the adjusted photos on the "
             f"mean height of the points ({num(h, 1)} m). Of the area seen by at least one photo, "
             f"{100 * frac[0]:.0f} % is seen by 2 or more, {100 * frac[1]:.0f} % by 3 or more, "
             f"{100 * frac[2]:.0f} % by 5 or more (red: one photo, no stereo)."]
    lines += _fig(figs, fig_dir, "overlap.png", qf.coverage_figure(count, (xmin, xmin + cols * cell,
                                                                          ymax - rows * cell, ymax), d.eo[:, :2]),
                  "Overlap: photos per ground cell")
    return lines


def _control_map(d: _Adjustment, disc_path: Path, run: str, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    idx = {q: i for i, q in enumerate(d.points)}
    groups: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    rows: list[str] = []
    if d.control:
        en = np.array([d.xyz[idx[q], :2] for q, _ in d.control])
        v = np.array([v for _, v in d.control])
        groups["control"] = (en, v[:, :2], v[:, 2])
        rms = np.sqrt(np.nanmean(v ** 2, axis=0))
        rows.append(f"| control (adjusted minus observed) | {len(v)} | {num(rms[0], 3)} | {num(rms[1], 3)} | "
                    f"{num(rms[2], 3)} |")
    disc = _rows(disc_path)
    if disc:
        en = np.array([[_f(r["E_adj"]), _f(r["N_adj"])] for r in disc])
        dd = np.array([[_f(r["dE"]), _f(r["dN"]), _f(r["dh"])] for r in disc])
        groups["check"] = (en, dd[:, :2], dd[:, 2])
        rms = np.sqrt(np.nanmean(dd ** 2, axis=0))
        rows.append(f"| check (reference minus adjusted) | {len(dd)} | {num(rms[0], 3)} | {num(rms[1], 3)} | "
                    f"{num(rms[2], 3)} |")
    if not groups:
        return []
    lines = ["", "## Control and check points", "",
             f"Run {run}: where the control and the check points are and how far they moved (plan vectors, "
             "height in cm beside each point).", "",
             "| points | n | RMS E (m) | RMS N (m) | RMS h (m) |", "|---|---|---|---|---|", *rows]
    lines += _fig(figs, fig_dir, "control_check_map.png", qf.control_map_figure(groups),
                  "Control and check points with their residuals")
    return lines


def _distortion(survey: Any, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    lines = ["", "## Camera distortion", "",
             "Radial, decentering and refraction corrections of each camera over its frame (what eq. 07 "
             "subtracts from the photo coordinates)."]
    rows = []
    for k, (cid, cam) in enumerate(survey.cameras.items()):
        w, h = cam.frame_size_mm
        gx, gy = np.meshgrid(np.linspace(-w / 2, w / 2, 13), np.linspace(-h / 2, h / 2, 9))
        xy = np.column_stack([gx.ravel(), gy.ravel()])
        c = cam.distortion_corrections(xy)
        dvec = np.column_stack([c["dx_ra"] + c["dx_des"] + c["dx_ref"], c["dy_ra"] + c["dy_des"] + c["dy_ref"]])
        rmax = float(np.hypot(w, h) / 2)
        r = np.linspace(0, rmax, 200)
        rc = cam.distortion_corrections(np.column_stack([r, np.zeros_like(r)]))
        pix = float(cam.pixel_size_x_mm)
        rows.append(f"| {cid} | {num(cam.focal_length_mm, 3)} | {num(np.hypot(*dvec.T).max() / pix, 2)} | "
                    f"{num(np.abs(rc['dx_ra']).max() / pix, 2)} |")
        lines += _fig(figs, fig_dir, f"distortion_{k}.png",
                      qf.distortion_figure(xy, dvec, r, rc["dx_ra"], (w, h), pix, f"camera {cid}"),
                      f"Distortion of camera {cid}")
    if not rows:
        return []
    return lines + ["", "| camera | focal length (mm) | largest correction (px) | largest radial (px) |",
                    "|---|---|---|---|", *rows]


def _standards(outdir: Path, runs: Mapping[str, Any]) -> list[str]:
    from ..accuracy.standards import ce90_le90

    rows = []
    for name, run in runs.items():
        disc = _rows(outdir / f"assess-{name}" / "discrepancies.csv")
        if not disc:
            continue
        d = np.array([[_f(r["dE"]), _f(r["dN"]), _f(r["dh"])] for r in disc])
        d = d[np.isfinite(d).all(axis=1)]
        if not len(d):
            continue
        ce = ce90_le90(d)
        st = run.get("standards") or {}

        def cls(key: str, part: str) -> str:
            return str((st.get(key) or {}).get(part, "-"))

        rows.append(f"| {name} | {len(d)} | {cls('pec', 'planimetric')} / {cls('pec', 'altimetric')} | "
                    f"{cls('asprs2014', 'planimetric')} / {cls('asprs2014', 'altimetric')} | "
                    f"{cls('nssda', 'planimetric')} / {cls('nssda', 'altimetric')} | "
                    f"{num(ce['ce90_m'], 3)} / {num(ce['le90_m'], 3)} | "
                    f"{num(ce['ce90_empirical_m'], 3)} / {num(ce['le90_empirical_m'], 3)} |")
    if not rows:
        return []
    return ["", "## Accuracy standards", "",
            "Check points of each run by the standards (plan / height): the PEC class, the ASPRS 2014 "
            "class, the NSSDA accuracy at 95 %, and CE90 / LE90 (the radius and the height error holding "
            "90 % of the errors: from the RMSE under normal errors, and the 90th percentile of the "
            "errors themselves).", "",
            "| run | check points | PEC | ASPRS 2014 | NSSDA 95 % | CE90 / LE90 (m) | empirical CE90 / LE90 (m) |",
            "|---|---|---|---|---|---|---|", *rows]


def _tie_points(d: _Adjustment, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    tie = np.array([r == "tie" for r in d.roles], dtype=bool)
    if not tie.any():
        return []
    on_tie = tie[d.obs_point]
    track = np.bincount(d.obs_point[on_tie], minlength=len(d.points))[tie]
    track = track[track > 0]
    per_photo = np.bincount(d.obs_photo[on_tie], minlength=len(d.photos))
    per = {p: int(n) for p, n in zip(d.photos, per_photo)}
    low = [p for p, n in per.items() if n < 6]
    lines = ["", "## Tie points", "",
             f"{int(tie.sum())} tie points, {int(on_tie.sum())} image observations; track length (photos per "
             f"point) mean {num(track.mean() if len(track) else 0, 2)}, median {num(np.median(track) if len(track) else 0, 1)}"
             f", {int((track >= 3).sum())} seen by 3 or more; tie points per photo from {min(per.values())} to "
             f"{max(per.values())}" + (f" (fewer than 6 on photo {', '.join(low[:10])})" if low else "") + "."]
    lines += _fig(figs, fig_dir, "tie_points.png", qf.track_length_figure(track, per),
                  "Tie points: track lengths and tie points per photo")
    return lines


def _density(survey: Any, figs: dict[str, bytes], fig_dir: str) -> list[str]:
    paths = list(getattr(survey, "lidar_paths", ()) or ())
    if not paths:
        return []
    from ..lidar import read_header

    heads = [read_header(p, crs=survey.lidar_crs) for p in paths]
    b = np.array([[h.bounds.xmin, h.bounds.ymin, h.bounds.xmax, h.bounds.ymax] for h in heads])
    xmin, ymin = b[:, 0].min(), b[:, 1].min()
    xmax, ymax = b[:, 2].max(), b[:, 3].max()
    total = sum(int(h.count) for h in heads)
    cell = max(1.0, float(np.ceil(max(xmax - xmin, ymax - ymin) / 200)))
    cols, rows = max(1, int(np.ceil((xmax - xmin) / cell))), max(1, int(np.ceil((ymax - ymin) / cell)))
    counts = np.zeros(rows * cols)
    how = "every point"
    if total <= MAX_DENSITY_POINTS:
        from ..lidar import iter_points

        for p in paths:
            for chunk in iter_points(p, crs=survey.lidar_crs):
                c = np.clip(((chunk.xyz[:, 0] - xmin) / cell).astype(int), 0, cols - 1)
                r = np.clip(((ymax - chunk.xyz[:, 1]) / cell).astype(int), 0, rows - 1)
                counts += np.bincount(r * cols + c, minlength=rows * cols)
    else:   # too many points to read for a figure: each tile's count spread over its box
        how = "each tile's point count over its box"
        for h in heads:
            c0, c1 = int((h.bounds.xmin - xmin) / cell), int(np.ceil((h.bounds.xmax - xmin) / cell))
            r0, r1 = int((ymax - h.bounds.ymax) / cell), int(np.ceil((ymax - h.bounds.ymin) / cell))
            grid = counts.reshape(rows, cols)
            grid[r0:r1, c0:c1] += h.count / max(1, (r1 - r0) * (c1 - c0))
    dens = counts.reshape(rows, cols) / cell ** 2
    seen = dens[dens > 0]
    lines = ["", "## LiDAR density", "",
             f"{len(paths)} tile(s), {total:,} points ({how}); points per m2 in cells of {cell:g} m: median "
             f"{num(np.median(seen) if seen.size else 0, 2)}, 5th percentile {num(np.percentile(seen, 5) if seen.size else 0, 2)}"
             f", {100 * (dens == 0).mean():.0f} % of the box empty."]
    lines += _fig(figs, fig_dir, "lidar_density.png",
                  qf.density_figure(dens, (xmin, xmin + cols * cell, ymax - rows * cell, ymax), cell),
                  "LiDAR point density")
    return lines


def _thumb(path: Path) -> np.ndarray | None:
    import rasterio
    from rasterio.enums import Resampling

    with rasterio.open(path) as ds:
        k = max(1, int(np.ceil(max(ds.width, ds.height) / _THUMB_PX)))
        shape = (ds.count, max(1, ds.height // k), max(1, ds.width // k))
        a = ds.read(out_shape=shape, resampling=Resampling.average, masked=True)   # no aliasing of texture
    a = np.ma.filled(a.astype(np.float32), np.nan) if a.dtype.kind == "f" else np.ma.filled(a, 0)
    if a.shape[0] >= 3:
        return np.moveaxis(a[:3], 0, 2).astype(np.uint8)
    return a[0]


def _thumbnails(outdir: Path, products: Mapping[str, Any] | None, mapping: Mapping[str, Any] | None,
                figs: dict[str, bytes], fig_dir: str) -> list[str]:
    items: list[tuple[str, Path, str]] = []
    pdir, mdir = outdir / "products", outdir / "mapping"
    if products:
        for name, kind in (("dtm.tif", "heights"), ("dsm.tif", "heights"), ("ndsm.tif", "heights"),
                           ("dtm_hillshade.tif", "shade"), ("hypsometry.tif", "rgb")):
            if (pdir / name).is_file():
                items.append((f"products/{name}", pdir / name, kind))
    if mapping:
        for p in [mdir / "mosaic.tif"] + sorted(mdir.glob("ortho_*.tif")):
            if p.is_file():
                items.append((f"mapping/{p.name}", p, "rgb"))
    items = items[:12]
    if not items:
        return []
    imgs = []
    for title, path, kind in items:
        a = _thumb(path)
        if a is not None:
            imgs.append((title, a, kind if not (kind == "rgb" and a.ndim == 2) else "photo"))
    extra = []
    if products:
        extra.append(f"Products in ../products/: {', '.join(products.get('files', []))}.")
    lines = ["", "## Products and orthophotos", "",
             f"Thumbnails of {len(imgs)} product(s) and orthophoto(s), left to right: "
             f"{', '.join(t for t, _, _ in imgs)} (full resolution GeoTIFFs in ../)."
             + (" " + extra[0] if extra else "")]
    lines += _fig(figs, fig_dir, "thumbnails.png", qf.thumbnails_figure(imgs), "Products and orthophotos")
    return lines


def _verdict(runs: Mapping[str, Any], stages: Sequence[Mapping[str, Any]], tests_failed: Sequence[str],
             products: Mapping[str, Any] | None, mapping: Mapping[str, Any] | None, name: str | None) -> str:
    failed = [s["stage"] for s in stages if s.get("state") == "failed"]
    run = runs.get(name) if name else None
    adj = (run or {}).get("adjustment") or {}
    chk = (run or {}).get("check") or {}
    kept = [b for b in adj.get("blunders") or [] if not b.get("removed")]
    parts = []
    if run:
        parts.append(f"run {name}: sigma0^2 {num(adj.get('sigma0_sq'), 2)}, chi-square "
                     f"{'passed' if adj.get('chi2_pass') else 'FAILED'}")
        if chk.get("n"):
            parts.append(f"check RMSE plan {num(chk.get('rmse_planimetric_m'), 3)} m, h {num(chk.get('rmse_h_m'), 3)} m "
                         f"({chk['n']} points)")
        if kept:
            parts.append(f"{len(kept)} blunder(s) kept")
    if products:
        parts.append(f"{len(products.get('files', []))} LiDAR product file(s)")
    if mapping and mapping.get("orthophotos"):
        parts.append(f"{len(mapping['orthophotos'])} orthophoto(s)")
    if failed:
        head = f"FAILED: stage(s) {', '.join(failed)} failed"
    elif tests_failed:
        head = "STATISTICAL TEST FAILED"
    elif kept:
        head = "PASSED with warnings"
    else:
        head = "PASSED"
    return f"**{head}**" + (": " + "; ".join(parts) if parts else "") + "."
