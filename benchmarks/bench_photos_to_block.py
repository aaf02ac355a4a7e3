"""From photos to an oriented block, end to end (issue 28, the first acceptance line): one command, one table.

Run:  python benchmarks/bench_photos_to_block.py [--seeds 0,1,2] [--per-strip 12] [--size 1000 750]
      [--init] [--workers 1] [--keep DIR] [--variance-components]
      python benchmarks/bench_photos_to_block.py --rescore DIR/seed0 DIR/seed1 ...   (score kept folders)

Per seed, a realistic synthetic block (:func:`lidarcat.synthetic.aerial.aerial_survey`: two strips,
60 %/30 % overlap, rendered photos, approximate orientation 2 m / 0.5 deg off with those sds in
photos.csv, 4 GPS points, LiDAR tiles) goes through the real commands, each a subprocess of
``python -m lidarcat.cli.main`` (PYTHONPATH=src), with no hand-made observation file:

1. (``--init``) ``lidarcat init NEW --images S/images --camera S/camera.toml --gnss gnss.csv
   --gnss-crs EPSG:31982 --lidar 'S/lidar/*.laz'`` (the GNSS/IMU file holds photos.csv's approximate
   orientation and sds); the GPS survey (ground_points.csv, control_sets.csv and the 4 points'
   image measurements) is then added to the new folder as a user adds a GPS survey. Without
   ``--init`` the aerial_survey folder is used directly.
2. ``lidarcat match S -o OUT/match`` (tie points into S/image_points.csv).
3. ``lidarcat adjust S --eo-constraints --snooping remove -o OUT/adjust`` (GNSS/IMU constraints and
   the control set "gps").

Truth is used only to score (never as a starting value):

* an observation's error: the tie point's track is scored against its *reference* observation --
  the one whose true ground point (:meth:`AerialSurvey.ground_point`), projected into the other
  photos (:meth:`AerialSurvey.project`), agrees within 1 px with the most of the track's other
  observations (ties: the smaller median). Every other observation's error is its distance to that
  projection; the reference's own error is its distance to the projection of its best partner's
  ground point. A two-ray mismatch thus counts both its observations as off.
* "kept": the tie-point observations in the final adjustment (residuals.csv, minus blunders.csv
  rows removed), scored by the same rule among the kept observations of their track (the point the
  adjustment sees is that of its kept rays: a track that joined two ground points, two rays each,
  keeps one consistent pair when snooping names the other); ">3 px not named": kept, more than
  3 px off so scored and not in blunders.csv.
* residual RMS: per coordinate over the kept tie-point observations, px.
* EO: |adjusted - true| / sd per element (6 per photo) with the written sds (a priori variance
  factor 1, as ``lidarcat adjust`` writes them) and with them times sigma0 (what
  ``--variance-factor a_posteriori`` writes); "rms z" is the root mean square of the normalised
  errors, the empirical / predicted ratio (honest: 0.8-1.25).

* with ``--variance-components`` the matched block is adjusted a second time with
  ``lidarcat adjust ... --variance-components`` (row "vce": one variance factor per observation group,
  :mod:`lidarcat.bundle.variance`); the summary line of each variant gives the rms z of the
  orientations pooled over the seeds, per element, and of the adjusted tie points against the true
  ground point behind their reference observation (E, N, h), the median sd that ``match`` wrote and
  the sd factors the variance components applied.
* :func:`plant_gross` moves matched observations as real matching goes wrong (a two-ray point
  mismatched across its epipolar line, one wrong ray of a multi-ray point; 3.5-50 px) for the
  tests of tests/test_photos_to_block.py.

Columns: photos, tie points, observations, share within 1 px (all matched), kept share within
1 px, kept > 3 px not named, named (blunders), residual RMS px, sigma0, max |z| and rms z
(a priori / a posteriori), seconds per stage, load (``uptime``'s 1-minute average before/after).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

__all__ = ["eo_errors", "run_block", "score_tracks", "score_block", "format_table", "rescore", "plant_gross",
           "MISMATCH_PX", "WRONG_RAY_PX", "pooled_honesty", "P_OVER_3"]

#: planted mismatches of two-ray points, px (across the epipolar line: the part two rays can reveal)
MISMATCH_PX = (3.5, 5.0, 8.0, 12.0, 20.0, 35.0, 50.0)
#: planted wrong rays of points with three or more rays, px (a random direction)
WRONG_RAY_PX = (3.5, 6.0, 10.0, 25.0, 50.0)

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
EO_NAMES = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
#: P(|z| > 3) of a standard normal z: the share of honest orientation errors beyond 3 sd
P_OVER_3 = 0.0026997960632601866


def pooled_honesty(z: Any, alpha: float = 0.001) -> dict[str, Any]:
    """"Every orientation within 3 sd" and "sds honest" as statistics pooled over seeds.

    With honest sds every normalised error ``z = (adjusted - true) / sd`` is N(0, 1), so a share
    :data:`P_OVER_3` of them lies beyond 3 sd *whatever their correlation* (the expectation of a count
    is the sum of the marginals): over ``n`` elements the count of ``|z| > 3`` has expectation
    ``n P_OVER_3``; for independent z it is binomial, and its ``1 - alpha`` quantile is the bound
    (a count above it rejects honesty at level *alpha*; correlated z -- one roll shared by a block's
    photos -- widen the count's spread, so the level is then larger than *alpha*).  The pooled rms z
    is the empirical / predicted sd ratio.

    Parameters
    ----------
    z : sequence of arrays
        Normalised errors (any shape), e.g. one (P, 6) array per seed.
    alpha : float
        Level of the bound.

    Returns
    -------
    dict with n, rms_z, over3 (count of |z| > 3), expected_over3, bound_over3
    """
    from scipy.stats import binom

    zz = np.concatenate([np.asarray(a, dtype=np.float64).ravel() for a in z])
    n = len(zz)
    return {"n": n, "rms_z": float(np.sqrt(np.mean(zz ** 2))), "over3": int(np.sum(np.abs(zz) > 3.0)),
            "expected_over3": n * P_OVER_3, "bound_over3": int(binom.ppf(1.0 - alpha, n, P_OVER_3))}


def _load() -> float:
    return os.getloadavg()[0]


def cli(*args: str) -> tuple[float, str]:
    """Run ``python -m lidarcat.cli.main ARGS``; (seconds, stdout). Raises on a non-zero exit but 3."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")])}
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "lidarcat.cli.main", *args], capture_output=True, text=True,
                       env=env, cwd=ROOT)
    dt = time.perf_counter() - t0
    if p.returncode not in (0, 3):   # 3: converged, global test rejected (reported in the table)
        raise RuntimeError(f"lidarcat {' '.join(args)} exited {p.returncode}:\n{p.stdout[-3000:]}\n"
                           f"{p.stderr[-3000:]}")
    return dt, p.stdout


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def score_tracks(s: Any, photo: np.ndarray, point: np.ndarray, colrow_px: np.ndarray) -> np.ndarray:
    """Truth error (px) of every tie-point observation (see the module docstring); inf = sees nothing.

    Parameters
    ----------
    s : AerialSurvey
    photo, point : (N,) str
        Photo and tie-point id of each observation.
    colrow_px : (N, 2) float
        Observed pixel (col, row).

    Returns
    -------
    (N,) float
    """
    n = len(photo)
    ground = np.full((n, 3), np.nan)
    for p in np.unique(photo):
        k = photo == p
        ground[k] = s.ground_point(str(p), colrow_px[k])
    _, track = np.unique(point, return_inverse=True)
    order = np.argsort(track, kind="stable")
    # every ordered pair (i, j) of observations of one track, i != j: i scored from j's ground point
    ii, jj = [], []
    starts = np.flatnonzero(np.r_[True, np.diff(track[order]) != 0])
    ends = np.r_[starts[1:], n]
    sizes = ends - starts
    for m in np.unique(sizes):
        blocks = order[starts[sizes == m][:, None] + np.arange(m)]          # (T, m)
        a, b = np.nonzero(~np.eye(m, dtype=bool))
        ii.append(blocks[:, a].ravel())
        jj.append(blocks[:, b].ravel())
    i = np.concatenate(ii)
    j = np.concatenate(jj)
    e = np.full(len(i), np.inf)
    for p in np.unique(photo[i]):
        k = photo[i] == p
        proj = s.project(str(p), ground[j[k]])
        d = np.hypot(*(proj - colrow_px[i[k]]).T)
        e[k] = np.where(np.isfinite(d), d, np.inf)
    # the reference of each track: most partners within 1 px, then the smallest median
    agree = np.bincount(j, weights=(e <= 1.0), minlength=n)
    med = np.full(n, np.inf)
    srt = np.lexsort((e, j))
    js, es = j[srt], e[srt]
    first = np.searchsorted(js, np.arange(n))
    cnt = np.bincount(js, minlength=n)
    has = cnt > 0
    med[has] = es[first[has] + (cnt[has] - 1) // 2]
    key = np.lexsort((med, -agree, track))                                  # best first within a track
    ref_of_track = np.full(track.max() + 1, -1)
    ref_of_track[track[key][::-1]] = key[::-1]                              # first occurrence wins
    ref = ref_of_track[track]
    err = np.full(n, np.inf)
    from_ref = j == ref[i]
    err[i[from_ref]] = e[from_ref]
    is_ref = np.arange(n) == ref
    best = np.full(n, np.inf)
    np.minimum.at(best, i, e)
    err[is_ref] = best[is_ref]
    return err


def plant_gross(s: Any, folder: Path, seed: int = 0, prefix: str = "tp", mismatch_px=MISMATCH_PX,
                wrong_ray_px=WRONG_RAY_PX) -> set[tuple[str, str]]:
    """Plant gross matches into a matched survey's image_points.csv, of the kinds real matching makes:
    a two-ray point mismatched (its second ray moved across the epipolar line by each of *mismatch_px*)
    and one wrong ray of a point with three or more rays (moved by each of *wrong_ray_px* in a random
    direction); the rows keep their sd columns.  Returns the (photo, point) of the moved observations.
    """
    path = Path(folder) / "image_points.csv"
    with open(path, newline="", encoding="utf-8") as f:
        lines = f.read().splitlines(keepends=True)
    comments = [ln for ln in lines if ln.startswith("#")]
    rows = list(csv.reader([ln for ln in lines if not ln.startswith("#")]))
    head, body = rows[0], rows[1:]
    ic, ir, iph, ipt = head.index("col_px"), head.index("row_px"), head.index("photo"), head.index("point")
    pts: dict[str, list[int]] = {}
    for k, r in enumerate(body):
        if r[ipt].startswith(prefix):
            pts.setdefault(r[ipt], []).append(k)
    rng = np.random.default_rng(seed)
    names = sorted(pts)
    two = [q for q in names if len(pts[q]) == 2]
    multi = [q for q in names if len(pts[q]) >= 3]
    planted: set[tuple[str, str]] = set()
    order = {p: i for i, p in enumerate(s.photo_ids)}
    for q, e in zip(rng.choice(two, len(mismatch_px), replace=False), mismatch_px):
        a, b = sorted(pts[str(q)], key=lambda k: order[body[k][iph]])
        pa = np.array([[float(body[a][ic]), float(body[a][ir])]])
        x = s.ground_point(body[a][iph], pa)
        c = np.asarray(s.true_eo, float)[order[body[a][iph]], :3]
        u = s.project(body[b][iph], x + 0.05 * (c - x))[0] - s.project(body[b][iph], x)[0]   # epipolar line
        n = np.array([-u[1], u[0]]) / np.hypot(*u)
        body[b][ic] = f"{float(body[b][ic]) + e * n[0]:.3f}"
        body[b][ir] = f"{float(body[b][ir]) + e * n[1]:.3f}"
        planted |= {(body[a][iph], str(q)), (body[b][iph], str(q))}
    for q, e in zip(rng.choice(multi, len(wrong_ray_px), replace=False), wrong_ray_px):
        k = int(rng.choice(pts[str(q)]))
        t = rng.uniform(0, 2 * np.pi)
        body[k][ic] = f"{float(body[k][ic]) + e * np.cos(t):.3f}"
        body[k][ir] = f"{float(body[k][ir]) + e * np.sin(t):.3f}"
        planted.add((body[k][iph], str(q)))
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.writelines(comments)
        csv.writer(f, lineterminator="\n").writerows([head, *body])
    return planted


def _gps_into(init_dir: Path, survey_dir: Path) -> None:
    """Add the GPS survey of an aerial_survey folder to a folder that ``lidarcat init`` wrote."""
    for name in ("ground_points.csv", "control_sets.csv"):
        shutil.copy(survey_dir / name, init_dir / name)
    ctrl = _rows(survey_dir / "image_points.csv")
    with open(init_dir / "image_points.csv", "a", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        for r in ctrl:
            w.writerow([r["photo"], r["point"], r["col_px"], r["row_px"]])
    toml = (init_dir / "survey.toml").read_text(encoding="utf-8")
    toml = toml.replace('[files]\n', '[files]\nground_points = "ground_points.csv"\n'
                        'control_sets = "control_sets.csv"\n', 1)
    toml = toml.replace('[survey]\n', '[survey]\ndefault_control = "gps"\n', 1)
    adj = (survey_dir / "survey.toml").read_text(encoding="utf-8")
    sd = [ln for ln in adj.splitlines() if ln.startswith("image_sd_mm")]
    toml += '\n[adjustment]\nobservations = "pixel"\n' + "".join(ln + "\n" for ln in sd)
    (init_dir / "survey.toml").write_text(toml, encoding="utf-8")


def run_block(work: Path, seed: int, *, per_strip: int = 12, size: tuple[int, int] = (1000, 750),
              via_init: bool = False, match_args: tuple[str, ...] = (),
              adjust_args: tuple[str, ...] = (), variance_components: bool = False) -> Any:
    """Render, (init), match, adjust and score one block; one table row (dict), or two (a list: the
    adjustment as given, then with ``--variance-components``) with *variance_components*."""
    from lidarcat.synthetic.aerial import aerial_survey

    work = Path(work)
    row: dict[str, Any] = {"seed": seed, "variant": "", "load_before": _load()}
    t0 = time.perf_counter()
    s = aerial_survey(work / "survey", n_strips=2, photos_per_strip=per_strip, forward_overlap=0.6,
                      side_overlap=0.3, image_size_px=size, approx_position_sd_m=2.0,
                      approx_angle_sd_deg=0.5, n_gps_points=4, seed=seed)
    row["s_render"] = time.perf_counter() - t0
    folder = work / "survey"
    if via_init:
        ph = _rows(folder / "photos.csv")
        gnss = work / "gnss.csv"
        with open(gnss, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(["photo", "E", "N", "h", "omega", "phi", "kappa", "sd_E", "sd_N", "sd_h",
                        "sd_omega", "sd_phi", "sd_kappa"])
            for r in ph:
                w.writerow([r[c] for c in ("photo", "X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg",
                                           "sd_X0", "sd_Y0", "sd_Z0", "sd_omega_deg", "sd_phi_deg",
                                           "sd_kappa_deg")])
        new = work / "block"
        row["s_init"], _ = cli("init", str(new), "--images", str(folder / "images"), "--camera",
                               str(folder / "camera.toml"), "--gnss", str(gnss), "--gnss-crs", "EPSG:31982",
                               "--lidar", str(folder / "lidar" / "*.laz"))
        _gps_into(new, folder)
        folder = new
    row["s_match"], _ = cli("match", str(folder), "-o", str(work / "match"), *match_args)
    row["s_adjust"], _ = cli("adjust", str(folder), "--eo-constraints", "--snooping", "remove",
                             "--no-variance-components", "-o", str(work / "adjust"), *adjust_args)
    row["load_after"] = _load()
    row.update(score_block(s, folder, work / "adjust"))
    if variance_components:     # the same matched block adjusted with --variance-components
        vc = dict(row, variant="vce")
        vc["s_adjust"], _ = cli("adjust", str(folder), "--eo-constraints", "--snooping", "remove",
                                "--variance-components", "-o", str(work / "adjust_vc"), *adjust_args)
        vc.update(score_block(s, folder, work / "adjust_vc"))
        vc["load_after"] = _load()
        return [row, vc]
    return row


def eo_errors(s: Any, adjust_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(adjusted - true, (adjusted - true) / sd) of every photo's orientation in *adjust_dir*'s eop.csv,
    shape (n_photos, 6): X0, Y0, Z0 in metres, omega, phi, kappa in degrees (wrapped to +-180)."""
    eop = {r["photo"]: r for r in _rows(adjust_dir / "eop.csv")}
    truth = np.asarray(s.true_eo, float).copy()
    truth[:, 3:] = np.degrees(truth[:, 3:])
    est = np.array([[float(eop[p][c]) for c in EO_NAMES] for p in s.photo_ids])
    sd = np.array([[float(eop[p]["sd_" + c]) for c in EO_NAMES] for p in s.photo_ids])
    d = est - truth
    d[:, 3:] = (d[:, 3:] + 180.0) % 360.0 - 180.0
    return d, d / sd


def score_block(s: Any, folder: Path, adjust_dir: Path, prefix: str = "tp") -> dict[str, Any]:
    """The table's scores of one matched and adjusted block (see the module docstring)."""
    obs = [r for r in _rows(folder / "image_points.csv") if r["point"].startswith(prefix)]
    sd_obs = np.array([[float(r["sd_x_mm"]), float(r["sd_y_mm"])] for r in obs if r.get("sd_x_mm")]).reshape(-1, 2)
    pixel_sd = float(next(ln.split("=")[1] for ln in (folder / "camera.toml").read_text().splitlines()
                          if ln.startswith("pixel_size_x_mm")))
    sd_obs = sd_obs / pixel_sd
    photo = np.array([r["photo"] for r in obs])
    point = np.array([r["point"] for r in obs])
    colrow = np.array([[float(r["col_px"]), float(r["row_px"])] for r in obs])
    err = score_tracks(s, photo, point, colrow)
    key = np.char.add(np.char.add(photo, "\t"), point)
    res = [r for r in _rows(adjust_dir / "residuals.csv") if r["kind"] == "image" and r["point"].startswith(prefix)]
    named_rows = [r for r in _rows(adjust_dir / "blunders.csv") if r["kind"] == "image"] \
        if (adjust_dir / "blunders.csv").exists() else []
    named = {f"{r['photo']}\t{r['point']}" for r in named_rows}
    removed = {f"{r['photo']}\t{r['point']}" for r in named_rows if r["removed"] == "True"}
    res_key = np.array([f"{r['photo']}\t{r['point']}" for r in res])
    kept = np.isin(key, res_key) & ~np.isin(key, list(removed))
    # the kept observations scored among themselves: the point the adjustment sees is that of its kept rays
    # (a track that joined two points, two rays each, keeps one consistent pair when the other is named)
    err_kept = np.full(len(err), np.inf)
    if kept.any():
        err_kept[kept] = score_tracks(s, photo[kept], point[kept], colrow[kept])
    pixel_mm = s.camera.pixel_size_x_mm if hasattr(s.camera, "pixel_size_x_mm") else None
    if pixel_mm is None:
        pixel_mm = float(next(ln.split("=")[1] for ln in (folder / "camera.toml").read_text().splitlines()
                              if ln.startswith("pixel_size_x_mm")))
    keep_res = np.array([[float(r["vx_mm"]), float(r["vy_mm"])] for r in res
                         if f"{r['photo']}\t{r['point']}" not in removed]) / pixel_mm
    summary = json.loads((adjust_dir / "summary.json").read_text(encoding="utf-8"))
    vcs = {g["group"]: g for g in (summary.get("variance_components") or {}).get("groups", [])}
    d, z = eo_errors(s, adjust_dir)
    sigma0 = float(np.sqrt(summary["sigma0_sq"]))
    return {
        "photos": len(s.photo_ids), "tie_points": len(np.unique(point)), "observations": len(obs),
        "within1": float(np.mean(err <= 1.0)), "over3": int(np.sum(err > 3.0)),
        "kept": int(kept.sum()), "kept_within1": float(np.mean(err_kept[kept] <= 1.0)),
        "kept_over3_unnamed": int(np.sum(kept & (err_kept > 3.0) & ~np.isin(key, list(named)))),
        "named": len(named_rows), "named_over3": int(np.sum(np.isin(key, list(named)) & (err > 3.0))),
        "rms_px": float(np.sqrt(np.mean(keep_res ** 2))), "sigma0": sigma0,
        "status": summary["status"], "chi2_pass": bool(summary["chi2_pass"]),
        "z_apriori": z, "z_aposteriori": z / sigma0,
        "max_z": float(np.abs(z).max()), "rms_z": float(np.sqrt(np.mean(z ** 2))),
        "max_z_post": float(np.abs(z / sigma0).max()), "rms_z_post": float(np.sqrt(np.mean((z / sigma0) ** 2))),
        "max_d_m": float(np.abs(d[:, :3]).max()), "max_d_deg": float(np.abs(d[:, 3:]).max()),
        "sd_scale": {k: v["sd_scale"] for k, v in vcs.items() if v["estimated"]},
        "tie_sd_px": float(np.median(np.hypot(*sd_obs.T) / np.sqrt(2))) if len(sd_obs) else float("nan"),
        "z_points": _point_z(s, photo, point, colrow, adjust_dir),
    }


def _point_z(s: Any, photo: np.ndarray, point: np.ndarray, colrow: np.ndarray, adjust_dir: Path) -> np.ndarray:
    """(k, 3) errors / sds (E, N, h) of the adjusted tie points against the true ground point behind
    their reference observation (the one on the photo listed first: the refinement's reference)."""
    pts = {r["point"]: r for r in _rows(adjust_dir / "points.csv") if r["role"] == "tie"}
    order = {p: i for i, p in enumerate(s.photo_ids)}
    rank = np.array([order[str(p)] for p in photo])
    o = np.lexsort((rank, point))
    first = o[np.r_[True, point[o][1:] != point[o][:-1]]]
    first = first[np.isin(point[first], list(pts))]
    truth = np.full((len(first), 3), np.nan)
    for p in np.unique(photo[first]):
        k = photo[first] == p
        truth[k] = s.ground_point(str(p), colrow[first[k]])
    est = np.array([[float(pts[q][c]) for c in "ENh"] for q in point[first]]).reshape(-1, 3)
    sd = np.array([[float(pts[q]["sd_" + c]) for c in "ENh"] for q in point[first]]).reshape(-1, 3)
    z = (est - truth) / sd
    return z[np.isfinite(z).all(axis=1)]


def format_table(rows: list[dict[str, Any]]) -> str:
    """The per-seed rows and the pooled row as a Markdown table."""
    head = ("| seed | variant | photos | tie pts | obs | within 1 px | kept | kept within 1 px | kept >3 px not named "
            "| named | RMS px | sigma0 | max abs z / rms z (a priori) | (a posteriori) | s render | s init "
            "| s match | s adjust | load |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['seed']} | {r['variant'] or '-'} | {r['photos']} | {r['tie_points']} | {r['observations']} "
            f"| {100 * r['within1']:.2f} % "
            f"| {r['kept']} | {100 * r['kept_within1']:.2f} % | {r['kept_over3_unnamed']} | {r['named']} "
            f"| {r['rms_px']:.3f} | {r['sigma0']:.3f} | {r['max_z']:.2f} / {r['rms_z']:.2f} "
            f"| {r['max_z_post']:.2f} / {r['rms_z_post']:.2f} | {r['s_render']:.0f} | {r.get('s_init', 0):.0f} "
            f"| {r['s_match']:.0f} | {r['s_adjust']:.0f} | {r['load_before']:.1f}/{r['load_after']:.1f} |")
    for variant in dict.fromkeys(r["variant"] for r in rows):
        rs = [r for r in rows if r["variant"] == variant]
        if len(rs) < 2:
            continue
        za = np.concatenate([r["z_apriori"].ravel() for r in rs])
        zp = np.concatenate([r["z_aposteriori"].ravel() for r in rs])
        obs = sum(r["observations"] for r in rs)
        kept = sum(r["kept"] for r in rs)
        w1 = sum(r["within1"] * r["observations"] for r in rs) / obs
        k1 = sum(r["kept_within1"] * r["kept"] for r in rs) / kept
        rms = np.sqrt(sum(r["rms_px"] ** 2 * r["kept"] for r in rs) / kept)
        lines.append(
            f"| pooled | {variant or '-'} | {sum(r['photos'] for r in rs)} | {sum(r['tie_points'] for r in rs)} "
            f"| {obs} | {100 * w1:.2f} % | {kept} | {100 * k1:.2f} % | {sum(r['kept_over3_unnamed'] for r in rs)} "
            f"| {sum(r['named'] for r in rs)} | {rms:.3f} | - | {np.abs(za).max():.2f} / "
            f"{np.sqrt(np.mean(za ** 2)):.2f} | {np.abs(zp).max():.2f} / {np.sqrt(np.mean(zp ** 2)):.2f} "
            f"| {sum(r['s_render'] for r in rs):.0f} | {sum(r.get('s_init', 0) for r in rs):.0f} "
            f"| {sum(r['s_match'] for r in rs):.0f} | {sum(r['s_adjust'] for r in rs):.0f} | - |")
    for variant in dict.fromkeys(r["variant"] for r in rows):
        rs = [r for r in rows if r["variant"] == variant]
        za = np.concatenate([r["z_apriori"] for r in rs])
        per = np.sqrt(np.mean(za ** 2, axis=0))
        zq = np.concatenate([r["z_points"] for r in rs])
        per_seed = ", ".join(f"{r['rms_z']:.2f}" for r in rs)
        h = pooled_honesty([r["z_apriori"] for r in rs])
        lines.append(f"\n{variant or 'as given'}: rms z of the orientations (empirical / predicted sd) "
                     f"{h['rms_z']:.2f} over {len(rs)} seed(s) (per seed {per_seed}); |z| > 3: {h['over3']} of "
                     f"{h['n']} (expected {h['expected_over3']:.1f}, binomial 99.9 % bound {h['bound_over3']}); "
                     f"per element "
                     + ", ".join(f"{n} {v:.2f}" for n, v in zip(EO_NAMES, per))
                     + (f"; tie points E, N, h {', '.join(f'{v:.2f}' for v in np.sqrt(np.mean(zq ** 2, axis=0)))}"
                        f" ({len(zq)} points)" if len(zq) else "")
                     + f"; median tie sd written {np.nanmedian([r['tie_sd_px'] for r in rs]):.3f} px"
                     + "".join(f"; {g} sd x {np.mean([r['sd_scale'][g] for r in rs if g in r['sd_scale']]):.3f}"
                               for g in sorted({g for r in rs for g in r["sd_scale"]})))
    return "\n".join(lines)


def rescore(dirs: list[Path]) -> list[dict[str, Any]]:
    """The table rows of seed folders kept by ``--keep`` (seconds and load not known: 0)."""
    from lidarcat.synthetic.aerial import load_aerial_survey

    rows = []
    for d in dirs:
        s = load_aerial_survey(d / "survey")
        for variant, sub in (("", "adjust"), ("vce", "adjust_vc")):
            if (d / sub / "summary.json").is_file():
                seed = int("".join(ch for ch in d.name if ch.isdigit()) or -1)
                row = {"seed": seed, "variant": variant, "load_before": 0.0, "load_after": 0.0, "s_render": 0.0,
                       "s_match": 0.0, "s_adjust": 0.0}
                row.update(score_block(s, d / "survey", d / sub))
                rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--per-strip", type=int, default=12)
    ap.add_argument("--size", type=int, nargs=2, default=(1000, 750))
    ap.add_argument("--init", action="store_true", help="go through `lidarcat init` (else the folder directly)")
    ap.add_argument("--workers", type=int, default=1, help="lidarcat match --workers")
    ap.add_argument("--keep", type=Path, default=None, help="keep the folders here")
    ap.add_argument("--variance-components", action="store_true",
                    help="adjust each matched block a second time with --variance-components")
    ap.add_argument("--rescore", type=Path, nargs="+", default=None, metavar="SEED_DIR",
                    help="only score folders kept by --keep (their adjust/ and adjust_vc/) and print the table")
    a = ap.parse_args()
    if a.rescore:
        print(format_table(rescore(a.rescore)))
        return
    print(f"uptime: {os.popen('uptime').read().strip()}")
    rows = []
    for seed in (int(x) for x in a.seeds.split(",")):
        work = (a.keep / f"seed{seed}") if a.keep else Path(tempfile.mkdtemp(prefix=f"p2b{seed}-"))
        if work.exists():
            shutil.rmtree(work)
        work.mkdir(parents=True)
        try:
            out = run_block(work, seed, per_strip=a.per_strip, size=tuple(a.size), via_init=a.init,
                            match_args=("--workers", str(a.workers)), variance_components=a.variance_components)
            rows.extend(out if isinstance(out, list) else [out])
        finally:
            if a.keep is None:
                shutil.rmtree(work, ignore_errors=True)
        this = out if isinstance(out, list) else [out]
        r = rows[-1]
        print(f"seed {seed}: {r['status']}, chi2 {'accepted' if r['chi2_pass'] else 'rejected'}, "
              f"max |d| {r['max_d_m']:.3f} m {r['max_d_deg']:.4f} deg, matched >3 px {r['over3']}, "
              f"named of them {r['named_over3']}", flush=True)
        print("\n".join(format_table(this).splitlines()[2:2 + len(this)]), flush=True)   # the rows now
    print(format_table(rows))
    print(f"uptime: {os.popen('uptime').read().strip()}")


if __name__ == "__main__":
    main()
