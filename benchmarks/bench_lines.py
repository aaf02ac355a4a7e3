"""Issue 29 step 3 figures: line control in the bundle adjustment over seeds (docs/figures.md, docs/lines.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_lines.py [--seeds 20]
    PYTHONPATH=src python benchmarks/bench_lines.py --measured [--seeds 2] [--size 1000 750] [--keep DIR]
    PYTHONPATH=src python benchmarks/bench_lines.py --cache DIR [--calibrate 1,2,3,4] [--validate 5,6,7,8]
    PYTHONPATH=src python benchmarks/bench_lines.py --correlation

On :func:`lidarcat.synthetic.lines.line_block` (2 strips x 6 photos, f = 50 mm, 1000 m, image sd
5 um, 12 roof lines seen on 2-3 photos each, GNSS 2 m / IMU 0.5 deg as weak constraints) prints per
configuration, pooled over the seeds: rms errors of the camera positions (m) and rotations (mrad),
of the tie points (plan, height, m), the sd of the normalised orientation errors, the share within
3 sd, and the mean of the line tests' chi2(2) statistic; then the data-snooping hit rate of one line
observation moved 3 px (18 um) across its edge.  The tests (tests/bundle/test_line_control.py)
assert the same quantities on fewer seeds.

``--measured``: the lines *measured automatically* in rendered photos (``lidarcat measure-control``)
instead of simulated observations.  Per seed the block of ``benchmarks/bench_measured_control.py``
(two strips of three photos, 0.1 m GSD, GNSS/IMU 2 m / 0.5 deg, the LiDAR vertices from ``lidarcat
extract --find``), ``lidarcat match``, then three variants of ``measure-control`` into copies of the
survey, each adjusted with ``lidarcat adjust --control lidar --eo-constraints --snooping remove``:
``--lines none`` (the vertices as points only), ``--lines add`` (plus the roof edges of the photos
where a vertex's point was not measured: the block's roofs give few usable corners) and ``--lines
only`` (every photo's edges as lines, no point).  Printed per variant, pooled over the seeds: the
orientation's rms errors (position m, attitude deg) against truth, the sd and max of the normalised
errors, the line observations written and their errors against the true projection of the LiDAR
line (median px across, rms of the normalised error: honest near 1).

``--cache DIR [--calibrate 1,2,3,4] [--validate 5,6,7,8] [--adjust cal|val|both] [--floors
default|cal|both]`` (issue 29 session 5, docs/lines.md, docs/figures.md): the same blocks kept under
``DIR/seedN`` (rendered and matched once), ``measure-control`` once per mode with every edge fit recorded,
so that the two line floors (``MeasureParams.line_sd_px``, ``line_direction_sd_deg``) can be applied
afterwards; the floors of greatest likelihood on the calibration seeds' edges against truth, the line
rms z of both seed sets under the default and the calibrated floors, then every seed adjusted with
``--lines none | add | only`` x floors x without / with ``--variance-components``: orientation rms
errors and rms z (position, attitude), line rms z, check points, the line factor.

``--correlation``: the neglected cross-photo correlation of one 3-D line's observations, measured on
``line_block`` with the lines' sd across raised from 3 cm to 40 cm (docs/lines.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np

from lidarcat.bundle import adjust
from lidarcat.bundle.line_tests import line_tests, snoop_lines
from lidarcat.synthetic.lines import line_block

PIXEL_MM = 0.006
CONFIGS = {
    "GNSS/IMU only (2 m, 0.5 deg)": dict(n_control_points=0, lines=False),
    "+ 3 control points": dict(n_control_points=3, lines=False),
    "+ 3 control points + 12 lines": dict(n_control_points=3, lines=True),
    "+ 12 lines (no control point)": dict(n_control_points=0, lines=True),
}


def _run(seed: int, n_control_points: int, lines: bool):
    b = line_block(seed=seed, n_control_points=n_control_points)
    p = b.problem if lines else dataclasses.replace(b.problem, lines=None)
    r = adjust(p, initial=(b.initial_eo, None))
    d = r.eo_params - b.true_eo
    d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
    z = (d / r.eo_sd).ravel()
    dpos = d[:, :3]
    drot = d[:, 3:] * 1e3
    dpt = r.points_m - b.true_points_m
    t = line_tests(r).w ** 2 if lines else np.zeros(0)
    return dpos, drot, dpt, z, t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"{'configuration':34s} {'pos m':>7s} {'rot mrad':>8s} {'tie E,N m':>9s} {'tie h m':>8s} "
          f"{'sd(z)':>6s} {'|z|<3':>6s} {'mean T':>7s}")
    for name, cfg in CONFIGS.items():
        out = [_run(s, **cfg) for s in range(args.seeds)]
        pos = np.concatenate([o[0] for o in out])
        rot = np.concatenate([o[1] for o in out])
        pt = np.concatenate([o[2] for o in out])
        z = np.concatenate([o[3] for o in out])
        t = np.concatenate([o[4] for o in out])
        print(f"{name:34s} {np.sqrt(np.mean(pos**2)):7.3f} {np.sqrt(np.mean(rot**2)):8.3f} "
              f"{np.sqrt(np.mean(pt[:, :2]**2)):9.3f} {np.sqrt(np.mean(pt[:, 2]**2)):8.3f} {z.std():6.3f} "
              f"{np.mean(np.abs(z) < 3):6.3f} {np.mean(t) if len(t) else float('nan'):7.2f}")
    hits, first = 0, 0
    for s in range(args.seeds):
        b = line_block(seed=s)
        L = b.problem.lines
        k = int(np.flatnonzero(L.line_index == np.argmax(np.bincount(L.line_index)))[0])
        d = L.xy2_mm[k] - L.xy1_mm[k]
        n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
        xy1, xy2 = L.xy1_mm.copy(), L.xy2_mm.copy()
        xy1[k] += 3 * PIXEL_MM * n
        xy2[k] += 3 * PIXEL_MM * n
        bad = dataclasses.replace(b.problem, lines=dataclasses.replace(L, xy1_mm=xy1, xy2_mm=xy2))
        label = L.observation_labels(b.problem.photo_ids)[k]
        res = adjust(bad, initial=(b.initial_eo, None))
        out = snoop_lines(res)
        hits += label in out.removed
        if label not in out.removed:
            t = line_tests(res)
            print(f"  seed {s}: {label} not named: w {t.w[k]:.2f} (critical {t.critical_w:.2f}), "
                  f"redundancy {t.redundancy[k].round(2)}, largest w {np.nanmax(t.w):.2f}")
        first += bool(out.removed) and out.removed[0] == label
    print(f"snooping, one line observation 3 px off: named in {hits}/{args.seeds} seeds, "
          f"first in {first}/{args.seeds}")
    print(f"{time.perf_counter() - t0:.1f} s")


def _line_errors(s, root) -> tuple[np.ndarray, np.ndarray]:
    """Per written line observation of *root*/line_control.csv: the true projections of its 3-D end points'
    distances from the measured image line (px) and over their sds (normalised)."""
    import csv

    with open(root / "line_control.csv", newline="") as fh:
        rows = list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))
    lines = {r["line"]: np.array([[float(r[c]) for c in ("e1_m", "n1_m", "h1_m")],
                                  [float(r[c]) for c in ("e2_m", "n2_m", "h2_m")]]) for r in rows if not r["photo"]}
    dist, z = [], []
    for r in rows:
        if not r["photo"]:
            continue
        p1 = np.array([float(r["col1_px"]), float(r["row1_px"])])
        p2 = np.array([float(r["col2_px"]), float(r["row2_px"])])
        sd = float(r["sd_px"])
        t = (p2 - p1) / np.linalg.norm(p2 - p1)
        n = np.array([-t[1], t[0]])
        for x in s.project(r["photo"], lines[r["line"]]):
            sa = float((x - p1) @ t) / float(np.linalg.norm(p2 - p1))
            d = float((x - p1) @ n)
            dist.append(d)
            z.append(d / (sd * np.sqrt((1 - sa) ** 2 + sa**2)))
    return np.array(dist), np.array(z)


def measured(seeds: list[int], size: tuple[int, int], keep=None) -> None:
    """The ``--measured`` rows (module docstring)."""
    import json
    import os
    import shutil
    import sys
    import tempfile
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_measured_control as mc

    base = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="bench_lines_measured_"))
    load0 = os.getloadavg()[0]
    variants = {"points (vertices measured), no lines": "none",
                "+ roof edges where the vertex's point was not measured": "add",
                "roof edges instead of points": "only"}
    acc: dict[str, dict[str, list]] = {v: {"d": [], "z": [], "ld": [], "lz": [], "n": []} for v in variants}
    for seed in seeds:
        d = base / f"seed{seed}"
        shutil.rmtree(d, ignore_errors=True)
        s, _ = mc.build(d / "survey", seed, size)
        r = mc._cli("match", str(d / "survey"), "-o", str(d / "match"))
        assert r.returncode == 0, r.stderr[-2000:]
        for name, mode in variants.items():
            root = d / f"survey-{mode}"
            shutil.copytree(d / "survey", root)
            r = mc._cli("measure-control", str(root), "--lines", mode, "--no-gallery", "-o", str(d / f"mc-{mode}"))
            assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
            r = mc._cli("adjust", str(root), "--control", "lidar", "--eo-constraints", "--snooping", "remove",
                        "-o", str(d / f"adjust-{mode}"))
            assert r.returncode in (0, 3), r.stdout[-2000:] + r.stderr[-2000:]
            sc = mc.score(s, root / "truth" / "points.csv", d / f"adjust-{mode}")
            eop = {q["photo"]: q for q in mc._rows(d / f"adjust-{mode}" / "eop.csv")}
            truth = np.asarray(s.true_eo, float).copy()
            truth[:, 3:] = np.degrees(truth[:, 3:])
            est = np.array([[float(eop[p][c]) for c in mc.EO_NAMES] for p in s.photo_ids])
            sd = np.array([[float(eop[p]["sd_" + c]) for c in mc.EO_NAMES] for p in s.photo_ids])
            dd = est - truth
            dd[:, 3:] = (dd[:, 3:] + 180.0) % 360.0 - 180.0
            acc[name]["d"].append(dd)
            acc[name]["z"].append((dd / sd).ravel())
            acc[name]["n"].append(sc["line_observations"])
            if (root / "line_control.csv").is_file():
                ld, lz = _line_errors(s, root)
                acc[name]["ld"].append(ld)
                acc[name]["lz"].append(lz)
            print(json.dumps({"seed": seed, "variant": mode, **sc}, default=float), flush=True)
    print(f"{'variant':56s} {'pos m':>6s} {'att deg':>7s} {'rms z':>6s} {'max|z|':>6s} {'lines':>5s} "
          f"{'line px':>7s} {'line z':>6s}")
    for name, a in acc.items():
        dd = np.concatenate(a["d"])
        z = np.concatenate(a["z"])
        ld = np.abs(np.concatenate(a["ld"])) if a["ld"] else np.zeros(0)
        lz = np.concatenate(a["lz"]) if a["lz"] else np.zeros(0)
        print(f"{name:56s} {np.sqrt(np.mean(dd[:, :3] ** 2)):6.3f} {np.sqrt(np.mean(dd[:, 3:] ** 2)):7.4f} "
              f"{np.sqrt(np.mean(z**2)):6.2f} {np.abs(z).max():6.2f} {sum(a['n']):5d} "
              f"{np.median(ld) if len(ld) else float('nan'):7.2f} "
              f"{np.sqrt(np.mean(lz**2)) if len(lz) else float('nan'):6.2f}")
    print(f"# seeds {seeds}, load {load0:.1f} -> {os.getloadavg()[0]:.1f}; folders in {base}")


# ---------------------------------------------------------------------------
# --cache: the rendered, matched blocks kept; the line floors calibrated on some seeds, validated on others
# ---------------------------------------------------------------------------

MODES = ("none", "add", "only")


def _record_edges():
    """Wrap :func:`lidarcat.photocontrol.measure._edge_line` to keep the free fit of every edge turned into a
    line observation (origin, u, coef, cov in px): its sds under other floors are then recomputed exactly.
    Returns (records, undo)."""
    from lidarcat.photocontrol import measure as M

    recs: list[dict] = []
    orig = M._edge_line

    def wrapped(planes, origin, u, free, ratio, line_sd_px, direction_sd_deg):
        el = orig(planes, origin, u, free, ratio, line_sd_px, direction_sd_deg)
        if el is not None:
            recs.append({"origin": np.array(origin, float), "u": np.array(u, float),
                         "coef": np.array(free[0], float)[:2], "cov": np.array(free[1], float)[:2, :2],
                         "p1": np.array(el.p1_px, float), "p2": np.array(el.p2_px, float)})
        return el

    M._edge_line = wrapped
    return recs, lambda: setattr(M, "_edge_line", orig)


def _read_line_rows(path) -> tuple[list[str], list[list[str]], list[str]]:
    import csv

    with open(path, newline="") as fh:
        text = fh.read().splitlines()
    rows = list(csv.reader(ln for ln in text if not ln.startswith("#")))
    return rows[0], rows[1:], [ln for ln in text if ln.startswith("#")]


def _record_of(recs: list[dict], colrow: np.ndarray) -> dict:
    """The recorded edge fit whose two-point equivalent is the written (col1, row1, col2, row2)."""
    keys = np.array([np.r_[r["p1"], r["p2"]] for r in recs]).reshape(-1, 4)
    dev = np.abs(keys - colrow).max(axis=1)
    k = int(np.argmin(dev))
    if dev[k] > 0.01:
        raise RuntimeError(f"no recorded edge fit for the observation at {colrow}")
    return recs[k]


def _floored(rec: dict, off_px: float, dir_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """The two-point equivalent (p1, p2 px, sd px) of a recorded free edge fit under the floors given
    (:class:`lidarcat.photocontrol.measure.EdgeLine`)."""
    from lidarcat.photocontrol.measure import _edge_line

    el = _edge_line((0, 1), rec["origin"], rec["u"], (rec["coef"], rec["cov"]), 1.0, off_px, dir_deg)
    return np.asarray(el.p1_px), np.asarray(el.p2_px), float(el.sd_px)


def _rewrite_lines(src, dst, recs: list[dict], off_px: float, dir_deg: float) -> int:
    """line_control.csv *src* -> *dst* with every observation's two points and sd recomputed under the
    floors; returns the observations rewritten."""
    import csv

    head, body, comments = _read_line_rows(src)
    ix = {c: k for k, c in enumerate(head)}
    n = 0
    for row in body:
        if not row[ix["photo"]]:
            continue
        w = np.array([float(row[ix[c]]) for c in ("col1_px", "row1_px", "col2_px", "row2_px")])
        p1, p2, sd = _floored(_record_of(recs, w), off_px, dir_deg)
        for c, v in zip(("col1_px", "row1_px", "col2_px", "row2_px", "sd_px"), (*p1, *p2, sd)):
            row[ix[c]] = f"{v:.6f}"
        n += 1
    with open(dst, "w", newline="") as fh:
        fh.write("".join(c + "\n" for c in comments))
        csv.writer(fh).writerows([head, *body])
    return n


def _line_truth(survey_dir, recs: list[dict], s) -> list[dict]:
    """Per line observation of the control set ``lidar`` in *survey_dir* what the floors' calibration needs
    (px): the true projections of the 3-D line's ends A, B, their offsets ``e`` from the free edge fit at
    their positions ``t`` along the fit's direction, the fit's covariance of (offset, slope), and the 3-D
    line's share of the residuals' covariance (at the true orientation)."""
    import dataclasses as dc

    from lidarcat.bundle.lines import line_terms
    from lidarcat.survey.adjustment import problem_from_survey
    from lidarcat.survey.folder import Survey

    sv = Survey.load(survey_dir)
    pr = problem_from_survey(sv, control="lidar")
    L = pr.lines
    if L is None:
        return []
    head, body, _ = _read_line_rows(sv.files["line_control"])
    ix = {c: k for k, c in enumerate(head)}
    colrow = {(r[ix["line"]], r[ix["photo"]]): np.array([float(r[ix[c]]) for c in ("col1_px", "row1_px", "col2_px",
                                                                                      "row2_px")])
              for r in body if r[ix["photo"]]}
    pix = float(s.camera.pixel_size_x_mm)
    eo = np.array([s.true_eo[s.index(str(p))] for p in pr.photo_ids])
    full = line_terms(L, eo, pr.focal_length_mm, jacobians=False)
    img = line_terms(dc.replace(L, cov_m2=np.zeros_like(L.cov_m2)), eo, pr.focal_length_mm, jacobians=False)
    out = []
    for k in range(len(L.line_index)):
        lid, pid = str(L.line_ids[L.line_index[k]]), str(pr.photo_ids[L.photo_index[k]])
        rec = _record_of(recs, colrow[(lid, pid)])
        xy = s.project(pid, np.stack([L.a_m[L.line_index[k]], L.b_m[L.line_index[k]]]))
        o, u = rec["origin"], rec["u"]
        nv = np.array([-u[1], u[0]])
        t = (xy - o) @ u
        e = (xy - o) @ nv - (rec["coef"][0] + rec["coef"][1] * t)
        out.append({"line": lid, "photo": pid, "t": t, "e": e, "cov": rec["cov"],
                    "line_px2": (full.cov[k] - img.cov[k]) / pix**2})
    return out


def line_z2(obs: list[dict], off_px: float, dir_deg: float) -> np.ndarray:
    """``e^T Sigma^-1 e`` (chi2(2) when honest) of every observation under the floors: ``Sigma = J C' J^T +``
    the 3-D line's share, ``J = [[1, t_A], [1, t_B]]``, ``C'`` the free fit's covariance plus
    ``diag(off^2, tan^2 dir)`` (:class:`lidarcat.photocontrol.measure.EdgeLine`)."""
    import math

    out = np.empty(len(obs))
    for k, o in enumerate(obs):
        c = o["cov"] + np.diag([off_px**2, math.tan(math.radians(dir_deg)) ** 2])
        J = np.stack([np.ones(2), o["t"]], axis=1)
        S = J @ c @ J.T + o["line_px2"]
        out[k] = o["e"] @ np.linalg.solve(S, o["e"])
    return out


def calibrate_floors(obs: list[dict], off_px: float | None = None) -> tuple[float, float]:
    """The floors (offset px, direction deg) of greatest likelihood of the observations' errors
    (2-D Gaussian per observation, :func:`line_z2`); with *off_px* given only the direction floor."""
    import math

    from scipy.optimize import minimize

    def nll(x):
        off, dd = (abs(x[0]), abs(x[1])) if off_px is None else (off_px, abs(x[0]))
        tot = 0.0
        for o in obs:
            c = o["cov"] + np.diag([off**2, math.tan(math.radians(dd)) ** 2])
            J = np.stack([np.ones(2), o["t"]], axis=1)
            S = J @ c @ J.T + o["line_px2"]
            tot += o["e"] @ np.linalg.solve(S, o["e"]) + np.linalg.slogdet(S)[1]
        return tot

    starts = ([0.25, 0.5], [0.1, 0.2], [0.05, 1.0]) if off_px is None else ([0.5], [0.2], [1.0])
    best = min((minimize(nll, x0, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-6}) for x0 in starts),
               key=lambda r: r.fun)
    if off_px is not None:
        return float(off_px), float(abs(best.x[0]))
    return float(abs(best.x[0])), float(abs(best.x[1]))


def cached_block(cache, seed: int) -> None:
    """``CACHE/seedN/survey``: the block of ``bench_measured_control.build`` rendered and matched (``lidarcat
    match``), ``CACHE/seedN/DONE`` written when complete; nothing when it is there."""
    import shutil
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_measured_control as mc

    d = Path(cache) / f"seed{seed}"
    if (d / "DONE").is_file():
        return
    shutil.rmtree(d, ignore_errors=True)
    mc.build(d / "survey", seed, (1000, 750))
    r = mc._cli("match", str(d / "survey"), "-o", str(d / "match"))
    if r.returncode != 0:
        raise RuntimeError(f"seed {seed}: lidarcat match failed: {r.stderr[-2000:]}")
    (d / "DONE").write_text("rendered and matched\n")


def cached_measure(cache, seeds: list[int]) -> None:
    """Per seed (:func:`cached_block`): ``measure-control --lines MODE`` into ``survey-MODE`` with the edge
    fits recorded (``edges-MODE.pkl``); skipped when done."""
    import pickle
    import shutil
    from pathlib import Path

    from lidarcat.stages.measure_control import measure_control

    for seed in seeds:
        d = Path(cache) / f"seed{seed}"
        cached_block(cache, seed)
        for mode in MODES:
            root = d / f"survey-{mode}"
            if (d / f"edges-{mode}.pkl").is_file():
                continue
            shutil.rmtree(root, ignore_errors=True)
            shutil.copytree(d / "survey", root)
            recs, undo = _record_edges()
            try:
                measure_control(root, d / f"mc-{mode}", lines=mode, gallery=False)
            finally:
                undo()
            with open(d / f"edges-{mode}.pkl", "wb") as fh:
                pickle.dump(recs, fh)
            print(f"seed {seed} {mode}: {len(recs)} edge fits recorded", flush=True)


def cached_adjust(cache, seeds: list[int], floors: dict[str, tuple[float, float]], vc_modes=(False, True)) -> list:
    """Adjust every cached seed x mode x floors x (without, with variance components); rows of scores."""
    import json
    import pickle
    import shutil
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_measured_control as mc

    from lidarcat.synthetic.aerial import load_aerial_survey

    out = []
    for seed in seeds:
        d = Path(cache) / f"seed{seed}"
        s = load_aerial_survey(d / "survey")
        for mode in MODES:
            if mode != "none" and not (d / f"survey-{mode}" / "line_control.csv").is_file():
                print(f"seed {seed} {mode}: no roof edge measured, no line control", flush=True)
                continue
            recs = pickle.loads((d / f"edges-{mode}.pkl").read_bytes())
            for fname, (off, dd) in (floors.items() if mode != "none" else [("-", (math.nan, math.nan))]):
                root = d / f"survey-{mode}-{fname}" if mode != "none" else d / "survey-none"
                if mode != "none" and not root.is_dir():
                    shutil.copytree(d / f"survey-{mode}", root)
                    _rewrite_lines(d / f"survey-{mode}" / "line_control.csv", root / "line_control.csv", recs, off, dd)
                lz = np.zeros(0)
                if mode != "none":
                    lz = line_z2(_line_truth(root, recs, s), off, dd)
                for vc in vc_modes:
                    adj = d / f"adj-{mode}-{fname}-{'vc' if vc else 'w'}"
                    if not (adj / "summary.json").is_file():
                        shutil.rmtree(adj, ignore_errors=True)
                        # --max-iter 300: a block held by one or two lines and the GNSS/IMU converges slowly
                        # (seed 3: more than the default 50 iterations)
                        r = mc._cli("adjust", str(root), "--control", "lidar", "--eo-constraints", "--snooping",
                                    "remove", "--variance-components" if vc else "--no-variance-components",
                                    "--max-iter", "300", "-o", str(adj))
                        if r.returncode not in (0, 3):
                            print(f"seed {seed} {mode} {fname} vc={vc}: exit {r.returncode} {r.stdout[-800:]}"
                                  f"{r.stderr[-800:]}", flush=True)
                            continue
                    summ = json.loads((adj / "summary.json").read_text())
                    if not summ.get("converged"):
                        print(f"seed {seed} {mode} {fname} vc={vc}: not converged", flush=True)
                        continue
                    sc = mc.score(s, root / "truth" / "points.csv", adj)
                    dd_, z = mc.eo_errors(s, adj)
                    fac = {g["group"]: g for g in (summ.get("variance_components") or {}).get("groups", [])}
                    row = {"seed": seed, "mode": mode, "floors": fname, "vc": vc, "d": dd_, "z": z, "lz2": lz,
                           "chi2_photo": _photo_chi2(s, adj, dd_),
                           "check": sc["check_rmse_m"], "sigma0_sq": sc["sigma0_sq"],
                           "lines": sc["line_observations"],
                           "line_factor": (fac.get("lines") or {}).get("factor"),
                           "line_estimated": (fac.get("lines") or {}).get("estimated"),
                           "factors": {g: (v["factor"], v["estimated"]) for g, v in fac.items()}}
                    out.append(row)
                    brief = {k: v for k, v in row.items() if k not in ("d", "z", "lz2", "chi2_photo")}
                    print(json.dumps(brief, default=float)
                          + f" pos {np.sqrt(np.mean(dd_[:, :3]**2)):.3f} zpos {np.sqrt(np.mean(z[:, :3]**2)):.2f}"
                          f" zatt {np.sqrt(np.mean(z[:, 3:]**2)):.2f}"
                          f" lz {np.sqrt(np.mean(lz) / 2) if len(lz) else 0:.2f}",
                          flush=True)
    return out


def _photo_chi2(s, adj, d: np.ndarray) -> np.ndarray:
    """Per photo ``d^T C^-1 d`` (chi2(6) when honest) of its orientation error *d* (m, deg) against its 6 x 6
    covariance in *adj*/eop_covariance.csv (m, rad)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_measured_control as mc

    names = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
    rows = {r["photo"]: r for r in mc._rows(adj / "eop_covariance.csv")}
    out = []
    for k, pid in enumerate(s.photo_ids):
        C = np.zeros((6, 6))
        for i in range(6):
            for j in range(i, 6):
                key = next(c for c in rows[pid] if c.startswith(f"c_{names[i]}_{names[j]}_"))
                C[i, j] = C[j, i] = float(rows[pid][key])
        dk = np.r_[d[k, :3], np.radians(d[k, 3:])]
        out.append(float(dk @ np.linalg.solve(C, dk)))
    return np.array(out)


def pooled_table(rows: list, title: str) -> None:
    """Print the pooled table of :func:`cached_adjust` rows, one line per (mode, floors, vc)."""
    print(f"\n{title}")
    print(f"{'mode':5s} {'floors':>8s} {'vc':>3s} {'seeds':>5s} {'pos m':>6s} {'att deg':>7s} {'z pos':>5s} "
          f"{'z att':>5s} {'photo':>5s} {'max|z|':>6s} {'lines':>5s} {'line z':>6s} {'check E/N/h m':>20s} "
          f"{'line factor':>11s}")
    keys = sorted({(r["mode"], r["floors"], r["vc"]) for r in rows}, key=lambda k: (MODES.index(k[0]), k[1], k[2]))
    for mode, fl, vc in keys:
        g = [r for r in rows if (r["mode"], r["floors"], r["vc"]) == (mode, fl, vc)]
        d = np.concatenate([r["d"] for r in g])
        z = np.concatenate([r["z"] for r in g])
        lz = np.concatenate([r["lz2"] for r in g])
        ck = np.array([r["check"] for r in g], float)
        lf = [r["line_factor"] for r in g if r["line_estimated"]]
        print(f"{mode:5s} {fl:>8s} {'yes' if vc else 'no':>3s} {len(g):5d} {np.sqrt(np.mean(d[:, :3]**2)):6.3f} "
              f"{np.sqrt(np.mean(d[:, 3:]**2)):7.4f} {np.sqrt(np.mean(z[:, :3]**2)):5.2f} "
              f"{np.sqrt(np.mean(z[:, 3:]**2)):5.2f} "
              f"{np.sqrt(np.mean(np.concatenate([r['chi2_photo'] for r in g])) / 6):5.2f} {np.abs(z).max():6.2f} "
              f"{sum(r['lines'] for r in g):5d} "
              f"{np.sqrt(np.mean(lz) / 2) if len(lz) else float('nan'):6.2f} "
              f"{' / '.join(f'{v:.3f}' for v in np.sqrt(np.nanmean(ck**2, axis=0))):>20s} "
              f"{(f'{np.median(lf):.2f} ({len(lf)})' if lf else '-'):>11s}")


def _truth_obs(cache, seeds: list[int]) -> list[dict]:
    import pickle
    from pathlib import Path

    from lidarcat.synthetic.aerial import load_aerial_survey

    obs = []
    for seed in seeds:
        d = Path(cache) / f"seed{seed}"
        recs = pickle.loads((d / "edges-only.pkl").read_bytes())
        obs += [{**o, "seed": seed} for o in _line_truth(d / "survey-only", recs, load_aerial_survey(d / "survey"))]
    return obs


def cached(cache, calibrate: list[int], validate: list[int], adjust: str = "both", which: str = "both") -> None:
    """``--cache``: measure (once), calibrate the line floors on the *calibrate* seeds' line observations
    (``--lines only``) against truth -- both floors, and the direction floor alone at ``line_sd_px`` (which
    the vertex measurement shares) --, then adjust the seeds of *adjust* (``cal``, ``val``, ``both``) with the
    default and the calibrated floors, with and without variance components; tables per seed set."""
    import os
    import time
    from pathlib import Path

    from lidarcat.photocontrol.measure import MeasureParams

    load0 = os.getloadavg()[0]
    mine = {"cal": calibrate, "val": validate}.get(adjust, calibrate + validate)
    cached_measure(cache, mine)
    while not all((Path(cache) / f"seed{k}" / "edges-only.pkl").is_file() for k in calibrate):
        time.sleep(20)          # measured by the process adjusting the calibration seeds
    mp = MeasureParams()
    allobs = _truth_obs(cache, calibrate)
    # gross errors out (as the adjustment's line snooping would at the default floors): chi2(2) 99.9 % = 13.8
    obs = [o for o, t in zip(allobs, line_z2(allobs, mp.line_sd_px, mp.line_direction_sd_deg)) if t < 13.8]
    print(f"calibration: {len(allobs) - len(obs)} of {len(allobs)} line observations gross at the default floors "
          "(chi2(2) > 13.8), left out", flush=True)
    both = calibrate_floors(obs)
    cal = calibrate_floors(obs, off_px=mp.line_sd_px)
    for name, seeds in (("calibration", calibrate), ("validation", validate)):
        if name == "validation" and adjust == "cal":
            continue
        o = obs if seeds == calibrate else _truth_obs(cache, seeds)
        o = [x for x, t in zip(o, line_z2(o, mp.line_sd_px, mp.line_direction_sd_deg)) if t < 13.8]
        print(f"{name} seeds {seeds}: {len(o)} line observations ('only'), line rms z = sqrt(mean chi2(2) / 2): "
              + "; ".join(f"floors {a:.3f} px / {b:.3f} deg: {np.sqrt(np.mean(line_z2(o, a, b)) / 2):.2f}"
                          for a, b in ((mp.line_sd_px, mp.line_direction_sd_deg), both, cal)), flush=True)
    floors = {"default": (mp.line_sd_px, mp.line_direction_sd_deg), "cal": cal}
    if which != "both":
        floors = {which: floors[which]}
    for name, seeds in (("calibration", calibrate), ("validation", validate)):
        if adjust not in ("both", name[:3]):
            continue
        rows = cached_adjust(cache, seeds, floors)
        pooled_table(rows, f"{name} seeds {seeds} (floors: default {floors['default']}, cal "
                           f"({cal[0]:.3f}, {cal[1]:.3f}))")
    print(f"# load {load0:.1f} -> {os.getloadavg()[0]:.1f}")


def correlation(seeds: int = 20, line_sds_m=(0.03, 0.1, 0.2, 0.4)) -> None:
    """``--correlation``: the neglected correlation of one 3-D line's observations on different photos (the
    common A, B) measured on :func:`lidarcat.synthetic.lines.line_block` with lines only (no control point):
    the 3-D lines' sd across grows from 3 cm to 40 cm (0.3-4 um projected at the block's 1:20,000, against
    the edges' 4 um) and the orientation errors over their sds show what treating the photos as independent
    costs: sd(z) and the share within 3 sd, pooled over the seeds."""
    print(f"{'line sd across m':>16s} {'projected um':>12s} {'sd(z) pos':>9s} {'sd(z) rot':>9s} {'|z|<3':>6s} "
          f"{'mean T':>7s} {'pos m':>6s}")
    for sd in line_sds_m:
        zs, ts, dp = [], [], []
        for seed in range(seeds):
            b = line_block(seed=seed, line_sd_m=sd)
            r = adjust(b.problem, initial=(b.initial_eo, None))
            d = r.eo_params - b.true_eo
            d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi
            zs.append(d / r.eo_sd)
            dp.append(d[:, :3])
            ts.append(line_tests(r).w ** 2)
        z = np.concatenate(zs)
        print(f"{sd:16.2f} {sd / 1000.0 * 50.0 * 1e3:12.1f} {z[:, :3].std():9.3f} {z[:, 3:].std():9.3f} "
              f"{np.mean(np.abs(z) < 3):6.3f} {np.mean(np.concatenate(ts)):7.2f} "
              f"{np.sqrt(np.mean(np.concatenate(dp) ** 2)):6.3f}", flush=True)


if __name__ == "__main__":
    import sys as _sys

    if "--correlation" in _sys.argv:
        correlation()
    elif "--cache" in _sys.argv:
        _ap = argparse.ArgumentParser()
        _ap.add_argument("--cache", required=True)
        _ap.add_argument("--calibrate", default="1,2,3,4")
        _ap.add_argument("--validate", default="5,6,7,8")
        _ap.add_argument("--adjust", default="both", choices=("cal", "val", "both"))
        _ap.add_argument("--floors", default="both", choices=("default", "cal", "both"))
        _a = _ap.parse_args()
        cached(_a.cache, [int(x) for x in _a.calibrate.split(",")], [int(x) for x in _a.validate.split(",")],
               _a.adjust, _a.floors)
    elif "--measured" in _sys.argv:
        _ap = argparse.ArgumentParser()
        _ap.add_argument("--measured", action="store_true")
        _ap.add_argument("--seeds", default="1")
        _ap.add_argument("--size", nargs=2, type=int, default=(1000, 750))
        _ap.add_argument("--keep", default=None)
        _a = _ap.parse_args()
        measured([int(x) for x in str(_a.seeds).split(",")], tuple(_a.size), _a.keep)
    else:
        main()
