"""`lidarcat match` + `lidarcat adjust` on four real aerial frames (NGI), no control set: the issue-28 acceptance.

Run:  python benchmarks/bench_ngi_match.py [--threads 2] [--per-cell 10 0] [--no-variance-components]
                                           [--self-calibrate thesis] [--two-step]

The four NGI frames (``../shared/data/frames/ngi``, evaluation only: read in place when present,
the benchmark prints "skipped" when absent; nothing is copied) become a survey in a temporary
folder: the DMC camera of ``ngi_int_param.yaml`` (640 x 1152 px of 0.144 mm, c = 120 mm), the
published orientation of ``camera_pos_ori.txt`` with sds of 1 m / 0.01 deg, the images named in
photos.csv's ``image`` column (the files in ../shared), pixel observations, no control set.  Then,
for each ``--per-cell`` (10: the default distribution control; 0: every verified track):

1. ``lidarcat match S --dem ngi/dem.tif --per-cell N`` (the action ``stages.match.match``);
2. ``lidarcat adjust S --eo-constraints`` (``stages.adjust.adjust``): on a matched survey the default
   is the rule of ``lidarcat run`` -- variance components (one factor per observation group, the
   weighted orientations of four photos too few to be estimated) and ``--snooping remove``;
   ``--no-variance-components``: the sds ``match`` wrote, as they are.
3. (``--two-step`` only) ``lidarcat adjust S2 --eo-constraints --self-calibrate PARAMS`` on the observations
   step 2 kept, with its tie-point sds (written x the estimated factor): the principal point and distortion
   the frames' camera (``ngi_int_param.yaml``: principal point at the centre, no distortion) does not model.
4. (``--self-calibrate PARAMS``, default ``thesis`` = c, x0, y0, k1, k2, k3, p1, p2; ``''`` to skip) the one
   command ``lidarcat adjust S --eo-constraints --self-calibrate PARAMS`` on the matched survey: snooping
   ``remove`` and the variance components (the default of a matched survey) on the adjustment without the
   parameters, then the parameters from the observations kept, the factors re-estimated with them
   (:mod:`lidarcat.survey.selfcal`).  The published values enter only as the weighted observations.  The
   acceptance line printed is step 4's (step 2's with ``--self-calibrate ''``).

Acceptance of issue 28 ("NGI frames"): the adjustment converges, names every matched observation
more than 2 px off, and every orientation stays within 1 m / 0.01 deg of the published one.  "Off"
is measured against the published orientation: each observation's distance from the reprojection of
its track triangulated with the published orientation (least squares of the rays; a track whose
rays meet nowhere sensible, e.g. behind the cameras, counts as off).  "Named": the observation is
among the adjustment's blunders (screened by the robust start or rejected by data snooping).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

#: the NGI frames (evaluation only, never copied): ../shared/data/frames/ngi beside the repository
NGI = next((p / "shared" / "data" / "frames" / "ngi" for p in Path(__file__).resolve().parents[1:]
            if (p / "shared" / "data" / "frames" / "ngi").is_dir()), Path("/work/shared/data/frames/ngi"))
PIXEL_MM = 0.144


def published() -> dict[str, np.ndarray]:
    """Published EO per photo: X, Y, Z (m), omega, phi, kappa (deg)."""
    return {r[0]: np.array(r[1:7], dtype=float) for r in
            (line.split() for line in (NGI / "camera_pos_ori.txt").read_text().splitlines() if line.strip())}


def build_survey(folder: Path, image_sd_px: float | None = None) -> Path:
    """The NGI frames as a survey folder: images read in place, published EO with 1 m / 0.01 deg, no tie point;
    *image_sd_px*: survey.toml's ``image_sd_mm`` in pixels (None: the survey default, 3/4 px)."""
    folder.mkdir(parents=True, exist_ok=True)
    sd = f"image_sd_mm = {image_sd_px * PIXEL_MM:.6f}\n" if image_sd_px else ""
    (folder / "survey.toml").write_text(
        '[survey]\nname = "ngi"\ncrs = "local: NGI tmerc lon_0=25 WGS84 (../shared/data/frames/ngi)"\n'
        '[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\nimage_points = "image_points.csv"\n'
        '[adjustment]\nobservations = "pixel"\n' + sd, encoding="utf-8")
    (folder / "camera.toml").write_text(
        "[dmc]\nfocal_length_mm = 120.0\nprincipal_point_x_mm = 0.0\nprincipal_point_y_mm = 0.0\nk1 = 0.0\n"
        "k2 = 0.0\nk3 = 0.0\np1 = 0.0\np2 = 0.0\nrefraction_eps45 = 0.0\npixel_size_x_mm = 0.144\n"
        "pixel_size_y_mm = 0.144\ncolumns_px = 640\nrows_px = 1152\n", encoding="utf-8")
    lines = ["photo,camera,image,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0,sd_omega_deg,sd_phi_deg,"
             "sd_kappa_deg"]
    for pid, eo in published().items():
        lines.append(",".join([pid, "dmc", str(NGI / f"{pid}.tif"), *(f"{v:.6f}" for v in eo),
                               "1", "1", "1", "0.01", "0.01", "0.01"]))
    (folder / "photos.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (folder / "image_points.csv").write_text("photo,point,col_px,row_px\n", encoding="utf-8")
    return folder


def residuals_to_published(survey, photo: np.ndarray, point: np.ndarray, xy_px: np.ndarray) -> np.ndarray:
    """Distance (px) of each observation from its track triangulated with the published orientation."""
    from lidarcat.match.rays import project_to_pixel, ray_directions

    pub = published()
    track = np.unique(point, return_inverse=True)[1]
    pids = sorted(set(photo.tolist()))
    eo = {p: np.r_[pub[p][:3], np.deg2rad(pub[p][3:])] for p in pids}
    d = np.empty((len(track), 3))
    c = np.empty((len(track), 3))
    for p in pids:
        sel = photo == p
        d[sel] = ray_directions(survey.camera_of(p), eo[p], xy_px[sel])
        c[sel] = eo[p][:3]
    d /= np.linalg.norm(d, axis=1)[:, None]
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    n_t = int(track.max()) + 1
    a = np.zeros((n_t, 3, 3))
    b = np.zeros((n_t, 3))
    np.add.at(a, track, proj)
    np.add.at(b, track, np.einsum("nij,nj->ni", proj, c))
    x = np.linalg.solve(a + 1e-9 * np.eye(3)[None], b[:, :, None])[:, :, 0]
    res = np.full(len(track), np.inf)
    for p in pids:
        sel = np.flatnonzero(photo == p)
        px, front = project_to_pixel(survey.camera_of(p), eo[p], x[track[sel]])
        r = np.hypot(*(px - xy_px[sel]).T)
        res[sel] = np.where(front & np.isfinite(r), r, np.inf)
    return res


def self_calibrated(folder: Path, sres, self_calibrate: str, scale: float) -> dict:
    """Step 3: the survey *folder* without the observations *sres* removed, tie sds scaled by its estimated
    factor, adjusted with the additional parameters *self_calibrate*; max deviations from the published EO
    and the parameters (px)."""
    import csv
    import shutil

    from lidarcat.survey.folder import Survey
    from lidarcat.survey.selfcal import selfcal_adjust

    out = folder.parent / (folder.name + "-selfcal")
    shutil.copytree(folder, out, ignore=shutil.ignore_patterns("out"))
    gone = {(str(b.photo), str(b.point)) for b in sres.blunders if b.kind == "image" and b.removed}
    with open(folder / "image_points.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    with open(out / "image_points.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            if (r["photo"], r["point"]) in gone:
                continue
            for k in ("sd_x_mm", "sd_y_mm"):
                if r.get(k):
                    r[k] = f"{float(r[k]) * scale:.6f}"
            w.writerow(r)
    _, res = selfcal_adjust(Survey.load(out), self_calibrate=self_calibrate, eo_constraints=True)
    r = res.bundle
    pub = published()
    eo = np.asarray(r.eo_params)
    pars = {k.split(".", 1)[-1]: (v["estimate"] / PIXEL_MM if v["unit"] == "mm" else v["estimate"], v["t"],
                                  "px" if v["unit"] == "mm" else v["unit"])
            for k, v in res.summary()["additional_parameters"].items()}
    return {"sc_success": bool(r.success),
            "sc_dev_m": max(float(np.abs(eo[i, :3] - pub[str(ph)][:3]).max()) for i, ph in enumerate(r.photo_ids)),
            "sc_dev_deg": max(float(np.abs(np.degrees(eo[i, 3:]) - pub[str(ph)][3:]).max())
                              for i, ph in enumerate(r.photo_ids)),
            "sc_params": pars, "sc_tie_scale": scale}


def one_command(folder: Path, self_calibrate: str, variance_components: bool, gross: dict) -> dict:
    """Step 4: ``lidarcat adjust S --eo-constraints --self-calibrate PARAMS`` on the matched survey, one
    command (``survey.selfcal.adjust_survey_with_parameters``, what the CLI calls): snooping ``remove`` and the
    variance components of a matched survey on the adjustment without the parameters, then the parameters
    from the observations kept, the factors re-estimated with them.  Max deviations from the published EO,
    the observations > 2 px off (*gross*) not named, the parameters (px)."""
    import csv

    from lidarcat.survey.folder import Survey
    from lidarcat.survey.selfcal import adjust_survey_with_parameters

    t0 = time.perf_counter()
    res, out = adjust_survey_with_parameters(
        Survey.load(folder), self_calibrate=self_calibrate, eo_constraints=True, outdir=folder / "out" / "one",
        snooping="remove", variance_components=variance_components)
    t = time.perf_counter() - t0
    r = res.bundle
    pub = published()
    eo = np.asarray(r.eo_params)
    with open(out / "blunders.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    named = {(b["photo"], b["point"]) for b in rows if b["kind"] == "image" and b["removed"] == "True"}
    summary = json.loads((out / "summary.json").read_text())
    tie = next((g["sd_scale"] for g in (summary.get("variance_components") or {}).get("groups", [])
                if g["group"] == "tie"), 1.0)
    pars = {k.split(".", 1)[-1]: (v["estimate"] / PIXEL_MM if v["unit"] == "mm" else v["estimate"], v["t"],
                                  "px" if v["unit"] == "mm" else v["unit"])
            for k, v in res.summary()["additional_parameters"].items()}
    # "off" again, with the calibrated camera: the observations > 2 px from the published orientation then
    field = {"c": "focal_length_mm", "x0": "principal_point_x_mm", "y0": "principal_point_y_mm"}
    cal = {field.get(k.split(".", 1)[-1], k.split(".", 1)[-1]): v["value"]
           for k, v in res.summary()["additional_parameters"].items() if v.get("value") is not None}
    folder2 = folder.parent / (folder.name + "-calibrated")
    folder2.mkdir(exist_ok=True)
    for f in ("survey.toml", "photos.csv", "image_points.csv"):
        (folder2 / f).write_bytes((folder / f).read_bytes())
    cam = (folder / "camera.toml").read_text().splitlines()
    cam = [f"{line.split('=')[0].strip()} = {cal[line.split('=')[0].strip()]!r}"
           if line.split("=")[0].strip() in cal else line for line in cam]
    (folder2 / "camera.toml").write_text("\n".join(cam) + "\n")
    s2 = Survey.load(folder2)
    ip = s2.image_points
    auto = np.char.startswith(ip.point.astype(str), "tp")
    photo, point = ip.photo[auto].astype(str), ip.point[auto].astype(str)
    off2 = residuals_to_published(s2, photo, point, ip.pixel_px[auto])
    gross2 = {(p, q): e for p, q, e in zip(photo, point, off2) if e > 2.0}
    return {"one_success": bool(r.success), "one_t": t, "one_named": len(named), "one_tie_scale": tie,
            "one_over_2px_cal": len(gross2),
            "one_missed_cal": sorted((p, q, e) for (p, q), e in gross2.items() if (p, q) not in named),
            "one_missed": sorted((p, q, e) for (p, q), e in gross.items() if (p, q) not in named),
            "one_chi2": bool(summary["chi2_pass"]), "one_sigma0": float(np.sqrt(summary["sigma0_sq"])),
            "one_dev_m": max(float(np.abs(eo[i, :3] - pub[str(ph)][:3]).max()) for i, ph in enumerate(r.photo_ids)),
            "one_dev_deg": max(float(np.abs(np.degrees(eo[i, 3:]) - pub[str(ph)][3:]).max())
                               for i, ph in enumerate(r.photo_ids)), "one_params": pars}


def run_one(tmp: Path, per_cell: int, threads: int, image_sd_px: float | None = None,
            threshold_px: float | None = None, variance_components: bool | None = None,
            self_calibrate: str = "", two_step: bool = False) -> dict:
    import dataclasses

    import cv2

    cv2.setNumThreads(threads)
    from lidarcat.stages.adjust import adjust, auto_variance_components
    from lidarcat.stages.match import default_options, match
    from lidarcat.survey.folder import Survey

    folder = build_survey(tmp / f"ngi-{per_cell}-{image_sd_px}-{threshold_px}", image_sd_px)
    s = Survey.load(folder)
    opts = dataclasses.replace(default_options(s), per_cell=per_cell)
    if threshold_px:
        opts = dataclasses.replace(opts, threshold_px=threshold_px)
    t0 = time.perf_counter()
    mres = match(s, folder / "out" / "match", options=opts, workers=threads, dem=NGI / "dem.tif", cache=False)
    t_match = time.perf_counter() - t0
    s = Survey.load(folder)
    ip = s.image_points
    auto = np.char.startswith(ip.point.astype(str), "tp")
    photo, point, xy = ip.photo[auto].astype(str), ip.point[auto].astype(str), ip.pixel_px[auto]
    off = residuals_to_published(s, photo, point, xy)
    t0 = time.perf_counter()
    vc = auto_variance_components(s) if variance_components is None else variance_components  # as the CLI
    sres = adjust(s, folder / "out" / "adjust", eo_constraints=True, snooping="remove", variance_components=vc)
    t_adj = time.perf_counter() - t0
    comps = (json.loads((folder / "out" / "adjust" / "summary.json").read_text()).get("variance_components")
             or {}).get("groups", [])
    tie_scale = next((g["sd_scale"] for g in comps if g["group"] == "tie"), 1.0)
    r = sres.result
    pub = published()
    named = {(str(b.photo), str(b.point)) for b in sres.blunders if b.kind == "image" and b.removed}
    gross = {(p, q): e for p, q, e in zip(photo, point, off) if e > 2.0}
    missed = sorted((p, q, gross[p, q], int((point == q).sum())) for p, q in set(gross) - named)
    eo = np.asarray(r.eo_params)
    dev_m = max(float(np.abs(eo[i, :3] - pub[str(ph)][:3]).max()) for i, ph in enumerate(r.photo_ids))
    dev_deg = max(float(np.abs(np.degrees(eo[i, 3:]) - pub[str(ph)][3:]).max()) for i, ph in enumerate(r.photo_ids))
    res_px = np.hypot(*(np.asarray(r.residuals_mm) / PIXEL_MM).T)
    sc = self_calibrated(folder, sres, self_calibrate, tie_scale) if two_step and self_calibrate and r.success else {}
    if self_calibrate:
        sc.update(one_command(folder, self_calibrate, vc, gross))
    return {**sc, "vc": vc, "tie_scale": tie_scale, "groups": {g["group"]: (round(g["redundancy"], 1), g["estimated"])
                                                              for g in comps},
            "per_cell": per_cell, "image_sd_px": image_sd_px, "tie_points": mres.n_tie_points, "observations": mres.n_observations,
            "pairs": f"{mres.n_pairs_verified}/{mres.n_pairs}", "over_2px": len(gross),
            "within_1px": float(np.mean(off < 1.0)), "named": len(named), "missed": missed,
            "status": f"{r.status}, {r.n_iter} it.", "success": bool(r.success), "dev_m": dev_m, "dev_deg": dev_deg,
            "median_px": float(np.median(res_px)), "rms_px": float(np.sqrt(np.mean(res_px ** 2))),
            "sigma0": float(np.sqrt(r.sigma0_sq)) if hasattr(r, "sigma0_sq") else float("nan"),
            "t_match": t_match, "t_adjust": t_adj, "adjustments": sres.n_adjustments}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--per-cell", type=int, nargs="+", default=[10, 0],
                    help="distribution control of each run (0: every verified track)")
    ap.add_argument("--threshold", type=float, nargs="+", default=[0.0],
                    help="match --threshold (epipolar Sampson distance, px) of each run (0: the default, 0.5 px)")
    ap.add_argument("--image-sd-px", type=float, nargs="+", default=[0.0],
                    help="survey.toml image_sd_mm of each run, in px (0: the survey default, 3/4 px)")
    vc = ap.add_mutually_exclusive_group()
    vc.add_argument("--variance-components", dest="vc", action="store_const", const=True, default=None,
                    help="adjust with --variance-components (the default of a matched survey)")
    vc.add_argument("--no-variance-components", dest="vc", action="store_const", const=False,
                    help="adjust with the sds match wrote, as they are")
    ap.add_argument("--self-calibrate", default="thesis", metavar="PARAMS",
                    help="step 4 (and 3): the one command `lidarcat adjust S --eo-constraints --self-calibrate "
                         "PARAMS` ('' to skip)")
    ap.add_argument("--two-step", action="store_true",
                    help="also step 3: the parameters on the observations step 2 kept, as a second command")
    a = ap.parse_args()
    load = os.getloadavg()
    print(f"load: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; threads {a.threads}; frames {NGI}")
    if not (NGI / "camera_pos_ori.txt").is_file():
        print("skipped: the NGI frames (../shared/data/frames/ngi) are absent")
        return
    print("\n| match | tie points | observations | obs. > 2 px off (published EO) | within 1 px | adjust | status | "
          "named (removed) | > 2 px not named | max \\|EO - published\\| | image residual median / RMS | "
          f"two steps, --self-calibrate {a.self_calibrate or '-'}: max \\|EO - published\\|, parameters (t) | s match | "
          "s adjust |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    ok = True
    ones = []
    with tempfile.TemporaryDirectory() as tmp:
        for th, pc, sd in ((th, pc, sd) for th in a.threshold for pc in a.per_cell for sd in a.image_sd_px):
            r = run_one(Path(tmp), pc, a.threads, sd or None, th or None, a.vc, a.self_calibrate, a.two_step)
            if "one_success" in r:      # the acceptance: one command
                ok &= r["one_success"] and r["one_dev_m"] <= 1.0 and r["one_dev_deg"] <= 0.01 and not r["one_missed"]
            else:
                ok &= r["success"] and r["dev_m"] <= 1.0 and r["dev_deg"] <= 0.01 and not r["missed"]
            groups = ", ".join(f"{g} r {rr:g}{'' if est else ' (not estimated)'}"
                               for g, (rr, est) in r["groups"].items() if g != "tie")
            how = (f"variance components: tie sd x {r['tie_scale']:.2f}; {groups}" if r["vc"] else "sds as written")
            match = (f"per cell {pc if pc else 'all'}" + (f", threshold {th:g} px" if th else "")
                     + (f", image_sd {sd:g} px" if sd else ""))
            sc = (f"{r['sc_dev_m']:.3f} m / {r['sc_dev_deg']:.4f} deg; "
                  + ", ".join(f"{k} {v:+.3g} {u} (t {t:+.1f})" for k, (v, t, u) in r["sc_params"].items())
                  if r.get("sc_success") else "-")
            print(f"| {match} | {r['tie_points']:,} | {r['observations']:,} | "
                  f"{r['over_2px']} | {100 * r['within_1px']:.2f} % | {how} | {r['status']} | {r['named']} | "
                  f"{len(r['missed'])}{': ' + ', '.join(f'{q} on {p[-8:]} {e:.1f} px ({k} rays)' for p, q, e, k in r['missed'][:4]) if r['missed'] else ''} | "
                  f"{r['dev_m']:.3f} m / {r['dev_deg']:.4f} deg | {r['median_px']:.3f} / {r['rms_px']:.3f} px | "
                  f"{sc} | {r['t_match']:.1f} | {r['t_adjust']:.1f} |", flush=True)
            if "one_success" in r:
                ones.append((match, r))
    if ones:
        print(f"\nOne command: `lidarcat adjust S --eo-constraints --self-calibrate {a.self_calibrate}` (snooping remove, "
              "variance components re-estimated with the parameters)\n")
        print("| match | converged | named (removed) | > 2 px not named | with the calibrated camera: > 2 px, "
              "not named | max \\|EO - published\\| | tie sd x | "
              "sigma0, global test | parameters (t) | s |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for match, r in ones:
            print(f"| {match} | {r['one_success']} | {r['one_named']} | {len(r['one_missed'])}"
                  f"{': ' + ', '.join(f'{q} on {p[-8:]} {e:.1f} px' for p, q, e in r['one_missed'][:4]) if r['one_missed'] else ''} | "
                  f"{r['one_over_2px_cal']}, {len(r['one_missed_cal'])}"
                  f"{': ' + ', '.join(f'{q} on {p[-8:]} {e:.1f} px' for p, q, e in r['one_missed_cal'][:4]) if r['one_missed_cal'] else ''} | "
                  f"{r['one_dev_m']:.3f} m / {r['one_dev_deg']:.4f} deg | {r['one_tie_scale']:.2f} | "
                  f"{r['one_sigma0']:.3f}, {'accepted' if r['one_chi2'] else 'rejected'} | "
                  + ", ".join(f"{k} {v:+.3g} {u} (t {t:+.1f})" for k, (v, t, u) in r["one_params"].items())
                  + f" | {r['one_t']:.1f} |", flush=True)
    print(f"\nacceptance ({'the one command' if ones else 'step 2'}: converges, every obs. > 2 px named, EO within "
          f"1 m / 0.01 deg): {'met' if ok else 'NOT met'}")
    print(f"load after: {os.getloadavg()[0]:.2f}")
    sys.exit(0)


if __name__ == "__main__":
    main()
