"""Self-calibration and frame offset (issue 13): acceptance figures, Monte Carlo, thesis block, timing.

Run: python benchmarks/bench_selfcal.py [--seeds 50] [--skip-thesis]   (BLAS pinned to one thread)

1. The acceptance block (:func:`lidarcat.synthetic.block.selfcal_block`, seed 1, 24 photos): every
   parameter's truth, estimate, sd and t; v'Pv, sigma0^2 and RMS image residuals with the parameters
   off and on; the radial residual pattern (t of the regression of the image residuals on x r^2).
2. Monte Carlo over ``--seeds`` seeds (default 50) of the same geometry with fresh noise: the
   empirical sd of each estimate against the mean predicted sd (ratio; acceptance 0.8 - 1.25).
3. The thesis block: the joint GPS + LiDAR adjustment with the LiDAR frame offset (3 and 7
   parameters) beside Table 12's means, and the LiDAR-controlled run's GPS discrepancies with the
   LiDAR control uncorrected (Table 13) and corrected by the estimated shift.
4. Time of the adjustment with and without the additional parameters for growing blocks (the
   bordering costs k + 1 extra solves against the factor of the camera system per iteration).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import logging  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.synthetic.block import selfcal_block  # noqa: E402
from lidarcat.bundle import SelfCalibration, adjust, adjust_with_parameters, frame_offset_from_sources
from lidarcat.survey import problem_from_survey

NAMES = ("cam.c", "cam.x0", "cam.y0", "cam.k1", "frame.lidar:gps.dE", "frame.lidar:gps.dN", "frame.lidar:gps.dh")


def _components(b, similarity=False):
    p = b.problem
    return [SelfCalibration({"cam": b.camera}, ["cam"] * p.n_photos, "c,x0,y0,k1"),
            frame_offset_from_sources(p, b.control_source, "lidar", "gps", similarity=similarity)]


def _truth(b):
    return np.r_[[b.true_corrections[k] for k in ("c", "x0", "y0", "k1")], b.shift_m]


def _radial_t(b, residuals):
    fot = b.camera.photo_to_fot(np.asarray(b.problem.xy_mm))
    a = (fot * (fot**2).sum(axis=1)[:, None]).ravel()
    v = np.asarray(residuals).ravel()
    beta = a @ v / (a @ a)
    return beta / np.sqrt(np.sum((v - beta * a) ** 2) / (len(v) - 1) / (a @ a))


def acceptance() -> None:
    b = selfcal_block(1)
    res = adjust_with_parameters(b.problem, _components(b))
    print(f"1. acceptance block: {b.problem.n_photos} photos, {b.problem.n_points} points, "
          f"{len(b.problem.photo_index)} rays; {res.bundle.message}")
    print(f"{'parameter':<20} {'unit':<6} {'truth':>11} {'estimate':>11} {'sd':>10} {'|e-T|/sd':>8} {'t':>7}")
    for name, true in zip(NAMES, _truth(b)):
        i = res.index(name)
        print(f"{name:<20} {res.units[i]:<6} {true:>11.4g} {res.estimates[i]:>11.4g} {res.sd[i]:>10.3g} "
              f"{abs(res.estimates[i] - true) / res.sd[i]:>8.2f} {res.estimates[i] / res.sd[i]:>7.1f}")
    fo = res.frame_offset_summary()[0]
    print(f"frame offset joint chi2 = {fo['test']['statistic']:.1f} (3 dof), p = {fo['test']['p_value']:.1e}")
    for label, r in (("off", res.without), ("on", res.bundle)):
        rms = np.sqrt(np.mean(np.asarray(r.residuals_mm) ** 2, axis=0)) * 1000
        print(f"parameters {label:<3}: v'Pv {r.vtpv:9.1f}  dof {r.dof}  sigma0^2 {r.sigma0_sq:6.3f}  chi2 test "
              f"{'passed' if r.chi2['passed'] else 'REJECTED'}  RMS image residual x {rms[0]:.2f} y {rms[1]:.2f} um  "
              f"radial pattern t {_radial_t(b, r.residuals_mm):+.1f}")


def monte_carlo(n_seeds: int) -> None:
    est, sd = [], []
    t0 = time.perf_counter()
    for seed in range(n_seeds):
        b = selfcal_block(1000 + seed)
        res = adjust_with_parameters(b.problem, _components(b))
        est.append(res.estimates - _truth(b))
        sd.append(res.sd)
    est, sd = np.array(est), np.array(sd)
    print(f"\n2. Monte Carlo, {n_seeds} seeds ({time.perf_counter() - t0:.1f} s)")
    print(f"{'parameter':<20} {'mean error':>11} {'empirical sd':>13} {'predicted sd':>13} {'ratio':>6}")
    for i, name in enumerate(NAMES):
        emp, pred = est[:, i].std(ddof=1), np.sqrt(np.mean(sd[:, i] ** 2))
        print(f"{name:<20} {est[:, i].mean():>11.3g} {emp:>13.4g} {pred:>13.4g} {emp / pred:>6.2f}")


def thesis() -> None:
    import json
    from pathlib import Path

    from lidarcat.survey.selfcal import combined_control_set, components_from_survey, SelfCalSettings
    from lidarcat.survey.folder import Survey

    s = Survey.load()
    t12 = json.loads((Path(__file__).parents[1] / "tests/data/thesis/table12_free_points.json").read_text())
    mean = t12["text_line_1354"]
    print("\n3. thesis block, control gps+lidar (0.25 m; 0.50/0.50/0.15 m), LiDAR frame offset")
    print(f"{'':24}{'E':>16} {'N':>16} {'h':>16}  joint test")
    print(f"{'Table 12 mean (text)':<24}{mean['mean_shift_E']:>16.2f} {mean['mean_shift_N']:>16.2f} "
          f"{mean['mean_shift_h']:>16.2f}")
    p = problem_from_survey(s, control=combined_control_set(s, "gps+lidar"))
    shift3 = None
    for sim in (False, True):
        comps = components_from_survey(s, p, SelfCalSettings(frame_offset=("lidar", "gps"), similarity=sim))
        res = adjust_with_parameters(p, comps)
        fo = res.frame_offset_summary()[0]
        cells = " ".join(f"{v:+8.3f} +-{e:5.3f}" for v, e in zip(fo["shift_m"], fo["sd_m"]))
        print(f"{'estimated, ' + ('7 par.' if sim else '3 par.'):<24}{cells}  {fo['test']['test']} "
              f"{fo['test']['statistic']:.2f} ({fo['test']['dof']} dof) p = {fo['test']['p_value']:.2f}")
        if sim:
            print(f"{'':24}scale {fo['scale_ppm']['estimate']:+.0f} +- {fo['scale_ppm']['sd']:.0f} ppm, rotations "
                  + ", ".join(f"{v:+.0f} +- {e:.0f}" for v, e in zip(fo["rotation_urad"]["estimate"],
                                                                    fo["rotation_urad"]["sd"])) + " urad")
        else:
            shift3 = np.array(fo["shift_m"])
            print(f"{'':24}v'Pv {res.without.vtpv:.2f} (dof {res.without.dof}) -> {res.bundle.vtpv:.2f} "
                  f"(dof {res.bundle.dof})")
    print("\n   self-calibration of the Kodak DCS Pro 14n (c, x0, y0, k1, k2, p1) with the frame offset, gps+lidar")
    print(f"   {'parameter':<12}{'certificate priors':>40}   {'free (no priors)':>52}")
    both = []
    for pri in (True, False):
        comps = components_from_survey(s, p, SelfCalSettings(parameters=("c", "x0", "y0", "k1", "k2", "p1"),
                                                              use_priors=pri, frame_offset=("lidar", "gps")))
        both.append(adjust_with_parameters(p, comps))
    for i, name in enumerate(both[0].names[:6]):
        cells = []
        for res in both:
            t = res.tests()[i]
            e, a = t["max_correlation_eo"], t["max_correlation_additional"]
            r, w = (e["r"], f"{e['parameter']} {e['photo']}")
            if abs(a["r"]) > abs(r):
                r, w = a["r"], a["parameter"].split(".")[-1]
            cells.append(f"{t['estimate']:+10.3g} +- {t['sd']:8.2g} t {t['t']:+5.2f} r {r:+.3f} ({w})")
        print(f"   {name.split('.')[-1]:<12}" + "   ".join(cells))
    for res, label in zip(both, ("priors", "free")):
        print(f"   {label}: v'Pv {res.bundle.vtpv:.2f} (dof {res.bundle.dof}); warnings: "
              + ("; ".join(w.split(":")[0] for w in res.warnings()) or "none"))
    import csv
    with open(Path(__file__).parents[1] / "tests/data/thesis/table13_gps_points_lidar_run.csv",
              encoding="utf-8") as fh:
        rows = list(csv.DictReader(line for line in fh if not line.startswith("#")))
    ids = [r["point"] for r in rows]
    t13 = np.array([[float(r[c]) for c in ("dE", "dN", "dh")] for r in rows])
    pl = problem_from_survey(s, control="lidar")
    ref = s.ground_points.enh_m[s.ground_points.index(ids)]
    r0 = adjust(pl, precision="none")
    r1 = adjust(dataclasses.replace(pl, constraint_enh_m=np.asarray(pl.constraint_enh_m) + shift3), precision="none")
    d0 = ref - np.array([r0.point(i) for i in ids])
    d1 = ref - np.array([r1.point(i) for i in ids])
    print("\n   LiDAR-controlled run, 21 GPS points, reference minus adjusted (m)")
    print(f"   {'':34}{'mean E':>8} {'mean N':>8} {'mean h':>8} {'RMS E':>8} {'RMS N':>8} {'RMS h':>8}")
    for label, d in (("Table 13 (printed)", t13), ("this run, LiDAR control as given", d0),
                     ("LiDAR control + estimated shift", d1)):
        m, r = d.mean(axis=0), np.sqrt((d**2).mean(axis=0))
        print(f"   {label:<34}" + " ".join(f"{v:+8.3f}" for v in m) + " " + " ".join(f"{v:8.3f}" for v in r))


def timing() -> None:
    print(f"\n4. time of one adjustment (s), load {os.getloadavg()[0]:.1f}")
    print(f"{'photos':>7} {'points':>7} {'rays':>7} {'plain':>7} {'+7 param':>9} {'iterations':>11}")
    for ns, npp in ((3, 8), (6, 15), (10, 30)):
        b = selfcal_block(2, n_strips=ns, photos_per_strip=npp)
        t0 = time.perf_counter()
        r0 = adjust(b.problem, precision="all")
        t1 = time.perf_counter()
        res = adjust_with_parameters(b.problem, _components(b), without=r0)
        t2 = time.perf_counter()
        print(f"{b.problem.n_photos:>7} {b.problem.n_points:>7} {len(b.problem.photo_index):>7} {t1 - t0:>7.2f} "
              f"{t2 - t1:>9.2f} {res.bundle.n_iter:>11}")


def main() -> None:
    logging.basicConfig(level=logging.ERROR)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--skip-thesis", action="store_true")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} (2 cores)")
    acceptance()
    monte_carlo(args.seeds)
    if not args.skip_thesis:
        thesis()
    timing()


if __name__ == "__main__":
    main()
