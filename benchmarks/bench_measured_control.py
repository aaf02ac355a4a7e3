"""Issue 29, the end-to-end acceptance: ``lidarcat run`` with LiDAR point and line control measured
automatically, beside the same block with hand-measured control (docs/figures.md, docs/photocontrol.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_measured_control.py [--seeds 1,2,3,4] [--size 1000 750] [--keep DIR]
    PYTHONPATH=src python benchmarks/bench_measured_control.py --seeds 1,2,3,4 --keep DIR --rescore

Per seed, a rendered block (:func:`lidarcat.synthetic.aerial.aerial_survey`: two strips of three
photos at 0.1 m GSD, roofs shaded per ray and anti-aliased, the approximate orientation 2 m / 0.5 deg
off with those sds in photos.csv as the GNSS/IMU, LiDAR tiles of 10 points/m^2 with 3 cm noise, 4 GPS
targets) gets its LiDAR control vertices from ``lidarcat extract --find`` on its own tiles (ground
points of source ``lidar`` with the extraction's sds; control set ``lidar`` = those vertices as
control, the GPS targets as check points).  Then, with no image coordinate of them given by hand:

* **automatic**: ``lidarcat run`` (match -> measure_control: vertices as points, the roof edges of
  photos where a vertex is not measured as lines -> adjust-gps, adjust-lidar -> assess -> report);
* **hand** (the reference): the vertices "measured by hand" -- their true projection (of the true
  roof vertex nearest the extracted one) plus 0.5 px noise, sd 0.5 px, on every photo where the
  vertex is visible -- written into image_points.csv; ``lidarcat run`` (measure_control not planned).

The truth scores only: adjust-lidar's orientation against the true one (rms position m, rms
attitude deg, max |error|/sd), the GPS check points' RMSE E, N, h (m; the thesis's accuracy class is
read from assess-lidar's PEC), sigma0^2 and the chi-square test, and the run's exit status.  The
automatic run passes (:func:`verdict`) when it exits 0, its orientation is within 3 sd, its RMS errors
within 1.5 x the hand run's and its check points in PEC 1:2000 class A (planimetric and altimetric)
(tests/photocontrol/test_end_to_end.py asserts that, slow).  Also counted: measure_control's
decisions (vertex-photo pairs measured / rejected by its tests, roof edges written as lines) and the
LiDAR observations the adjustment's data snooping named or removed.

Printed: one JSON line per seed, a pooled line (rms over every photo of every seed, the largest
|error|/sd, the check points of all seeds with their PEC class), and the markdown table of
docs/figures.md.  ``--rescore`` scores kept folders again without running (the exit status and
seconds of each run are kept beside its folder, ``run-auto.exit``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_photos_to_block import eo_errors  # noqa: E402  (the orientation scored as the tie-point benchmark does)


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    return subprocess.run([sys.executable, "-m", "lidarcat.cli.main", *args], capture_output=True, text=True,
                          env=env)


def build(root: Path, seed: int = 1, size: tuple[int, int] = (1000, 750), *, n_strips: int = 2,
          photos_per_strip: int = 3) -> tuple[Any, dict[str, np.ndarray]]:
    """The rendered block with its LiDAR vertices from ``lidarcat extract --find`` as ground points of source
    lidar and the control set ``lidar``; returns (AerialSurvey, {vertex id: true vertex})."""
    from lidarcat.synthetic.aerial import aerial_survey

    s = aerial_survey(root, n_strips=n_strips, photos_per_strip=photos_per_strip, gsd_m=0.1, image_size_px=size,
                      lidar_density_m2=10, lidar_noise_m=0.03, n_gps_points=4, seed=seed, supersample=4)
    cands = root.parent / f"{root.name}_candidates.csv"
    r = _cli("extract", "--find", "--lidar", str(root / "lidar"), "-o", str(cands))
    if r.returncode != 0:
        raise RuntimeError(f"extract --find failed: {r.stdout[-500:]} {r.stderr[-1000:]}")
    found = [c for c in _rows(cands) if c["status"] == "ok"]
    sc = s.scene
    true = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    gp = root / "ground_points.csv"
    truth: dict[str, np.ndarray] = {}
    rows = []
    for c in found:
        enh = np.array([float(c["E"]), float(c["N"]), float(c["h"])])
        k = int(np.argmin(np.linalg.norm(true - enh, axis=1)))
        if np.linalg.norm(true[k] - enh) > 0.5:     # not a vertex of the scene's roofs: not used
            continue
        truth[c["point"]] = true[k]
        rows.append(f"{c['point']},{c['E']},{c['N']},{c['h']},{c['sd_E']},{c['sd_N']},{c['sd_h']},lidar\n")
    gp.write_text(gp.read_text().rstrip("\n") + "\n" + "".join(rows))
    cs = root / "control_sets.csv"
    gps = [ln.split(",")[1] for ln in cs.read_text().splitlines()[1:] if ln.startswith("gps,")]
    cs.write_text(cs.read_text().rstrip("\n") + "\n" + "".join(f"lidar,{v},control,,,\n" for v in truth)
                  + "".join(f"lidar,{g},check,,,\n" for g in gps))
    return s, truth


def hand_measure(s: Any, root: Path, truth: dict[str, np.ndarray], sd_px: float = 0.5, seed: int = 0) -> int:
    """The vertices "measured by hand": true projection + *sd_px* noise where visible (the photo's first hit
    there is the vertex), into image_points.csv with their sds; returns the number of rows."""
    rng = np.random.default_rng(seed + 4242)
    ip = root / "image_points.csv"
    old = _rows(ip)
    pix = float(s.camera.pixel_size_x_mm)
    out = [[r["photo"], r["point"], r["col_px"], r["row_px"], r.get("sd_x_mm", ""), r.get("sd_y_mm", "")]
           for r in old]
    n = 0
    w, h = s.camera.columns_px, s.camera.rows_px
    for pid in s.photo_ids:
        for vid, v in truth.items():
            px = s.project(pid, v[None])[0]
            if not (np.isfinite(px).all() and 20 <= px[0] < w - 20 and 20 <= px[1] < h - 20):
                continue
            hit = s.ground_point(pid, px[None])[0]
            if not np.isfinite(hit).all() or np.linalg.norm(hit - v) > 0.3:    # hidden behind another roof
                continue
            m = px + rng.normal(0.0, sd_px, 2)
            out.append([pid, vid, f"{m[0]:.3f}", f"{m[1]:.3f}", f"{sd_px * pix:.6f}", f"{sd_px * pix:.6f}"])
            n += 1
    with open(ip, "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["photo", "point", "col_px", "row_px", "sd_x_mm", "sd_y_mm"])
        wr.writerows(out)
    return n



def _lidar_points(survey: Path) -> set[str]:
    """Ids of the survey's ground points of source ``lidar`` (the extracted vertices)."""
    return {r["point"] for r in _rows(survey / "ground_points.csv") if r.get("source") == "lidar"}


def score(s: Any, truth_points: Path, adjust_dir: Path, assess_dir: Path | None = None,
          lidar_points: set[str] | None = None) -> dict[str, Any]:
    """Orientation against truth (rms position m, attitude deg, max and rms |error|/sd), GPS check points'
    RMSE E, N, h (m) and their discrepancies, sigma0^2, the chi-square test, line observations, the
    adjustment's snooping of the control observations, the PEC class when assessed."""
    d, z = eo_errors(s, adjust_dir)
    tp = {r["point"]: np.array([float(r[c]) for c in ("E", "N", "h")]) for r in _rows(truth_points)}
    chk = [r for r in _rows(adjust_dir / "points.csv") if r["role"] == "check" and r["point"] in tp]
    e = np.array([[float(r["E"]), float(r["N"]), float(r["h"])] - tp[r["point"]] for r in chk]).reshape(-1, 3)
    summ = json.loads((adjust_dir / "summary.json").read_text())
    lid = lidar_points if lidar_points is not None else set()
    res = _rows(adjust_dir / "residuals.csv")
    bl = _rows(adjust_dir / "blunders.csv") if (adjust_dir / "blunders.csv").is_file() else []
    bl_lidar = [r for r in bl if r.get("kind") == "image" and r["point"] in lid]
    lc = summ.get("line_control") or {}
    out = {"pos_rms_m": float(np.sqrt(np.mean(d[:, :3] ** 2))), "att_rms_deg": float(np.sqrt(np.mean(d[:, 3:] ** 2))),
           "max_z": float(np.abs(z).max()), "rms_z": float(np.sqrt(np.mean(z**2))),
           "check_rmse_m": np.sqrt(np.mean(e**2, axis=0)).tolist() if len(e) else [np.nan] * 3,
           "sigma0_sq": summ.get("sigma0_sq"), "chi2_pass": summ.get("chi2_pass"),
           "line_observations": lc.get("observations", 0),
           "lines_rejected_by_snooping": len(lc.get("rejected") or []) if isinstance(lc.get("rejected"), list)
           else int(lc.get("rejected") or 0),
           "lidar_observations": sum(1 for r in res if r.get("kind") == "image" and r["point"] in lid),
           "lidar_named_by_snooping": len(bl_lidar),
           "lidar_removed_by_snooping": sum(1 for r in bl_lidar if r.get("removed") == "True"),
           "_d": d, "_z": z, "_check_d": e}
    if assess_dir is not None and (assess_dir / "assessment.json").is_file():
        a = json.loads((assess_dir / "assessment.json").read_text())
        pec = a["standards"]["pec"]
        out["pec"] = {"planimetric": pec["class"]["planimetric"], "altimetric": pec["class"]["altimetric"],
                      "label": pec.get("label", "")}
        st = a.get("settings") or {}
        out["_pec_settings"] = (st.get("scale"), st.get("contour_interval_m"))
    return out


def control_counts(run: Path) -> dict[str, Any]:
    """What measure_control decided (decisions.csv, line_decisions.csv): statuses and the reasons of the
    rejected vertex-photo pairs; empty when the stage did not run."""
    mc = run / "measure_control"
    if not (mc / "decisions.csv").is_file():
        return {}
    dec = _rows(mc / "decisions.csv")
    status: dict[str, int] = {}
    for r in dec:
        status[r["status"]] = status.get(r["status"], 0) + 1
    rejected = [f"{r['point']}@{r['photo']}: {r['reason']}" for r in dec if r["status"] == "rejected"]
    out: dict[str, Any] = {"accepted": sum(r["decision"] == "accept" for r in dec), "status": status,
                           "rejected": rejected}
    if (mc / "line_decisions.csv").is_file():
        ls: dict[str, int] = {}
        for r in _rows(mc / "line_decisions.csv"):
            ls[r["status"]] = ls.get(r["status"], 0) + 1
        out["line_status"] = ls
    return out


def run_variant(s: Any, root: Path, out: Path) -> dict[str, Any]:
    """``lidarcat run`` on *root* into *out*, scored (:func:`rescore`); the exit status kept in ``out.exit``."""
    t0 = time.perf_counter()
    r = _cli("run", str(root), "-o", str(out))
    secs = round(time.perf_counter() - t0, 1)
    out.with_suffix(".exit").write_text(f"{r.returncode} {secs}\n")
    res = rescore(s, root, out)
    if "error" in res:
        res["error"] = (r.stdout + r.stderr)[-1500:]
    return res


def rescore(s: Any, root: Path, out: Path) -> dict[str, Any]:
    """The scores of a kept run *out* of survey *root* (exit status and seconds from ``out.exit``)."""
    ex = out.with_suffix(".exit")
    code, secs = (ex.read_text().split() + ["nan"])[:2] if ex.is_file() else ("nan", "nan")
    res: dict[str, Any] = {"exit": int(code) if code.lstrip("-").isdigit() else None, "seconds": float(secs)}
    if not (out / "adjust-lidar" / "eop.csv").is_file():
        log = out / "lidarcat.log"
        failed = [ln.split("failed after", 1)[1].split(":", 1)[1].strip() for ln in
                  (log.read_text().splitlines() if log.is_file() else []) if "stage adjust-lidar: failed" in ln]
        res["error"] = "adjust-lidar failed: " + (failed[0] if failed else "no adjust-lidar/eop.csv")
        return res
    res.update(score(s, root / "truth" / "points.csv", out / "adjust-lidar", out / "assess-lidar",
                     _lidar_points(root)))
    mc = out / "measure_control" / "measure_control.json"
    if mc.is_file():
        j = json.loads(mc.read_text())
        res["measured"] = {"points": j.get("accepted"), "line_observations": j.get("line_observations"),
                           "counts": j.get("counts"), **control_counts(out)}
    return res


#: the acceptance's limits: orientation within MAX_Z sd of truth, rms errors within RATIO x the hand run's
MAX_Z, RATIO = 3.0, 1.5


def verdict(auto: dict[str, Any], hand: dict[str, Any]) -> list[str]:
    """The acceptance items *auto* fails (empty: passes)."""
    if "error" in auto or "error" in hand:
        return ["no adjustment"]
    bad = []
    if auto["exit"] != 0:
        bad.append(f"exit {auto['exit']}")
    if auto["max_z"] > MAX_Z:
        bad.append(f"max \\|error\\|/sd {auto['max_z']:.2f} > {MAX_Z}")
    for k in ("pos_rms_m", "att_rms_deg"):
        if auto[k] > RATIO * hand[k]:
            bad.append(f"{k} {auto[k] / hand[k]:.2f} x hand > {RATIO}")
    if (hand.get("measured") or {}).get("accepted"):     # the reference must be by hand only
        bad.append(f"the hand run measured {hand['measured']['accepted']} observations itself")
    pec = auto.get("pec") or {}
    if not (pec.get("planimetric") == pec.get("altimetric") == "A"):
        bad.append(f"PEC {pec.get('planimetric')}/{pec.get('altimetric')} (not A/A)")
    return bad


def pooled(results: list[dict[str, Any]], variant: str) -> dict[str, Any]:
    """The pooled scores of *variant* over the seeds where both runs adjusted (paired): rms over every
    photo, the largest |error|/sd, check-point RMSE over every check point and their PEC class."""
    ok = [r[variant] for r in results if "error" not in r["auto"] and "error" not in r["hand"]]   # paired
    if not ok:
        return {}
    d = np.vstack([r["_d"] for r in ok])
    z = np.vstack([r["_z"] for r in ok])
    e = np.vstack([r["_check_d"] for r in ok])
    out = {"seeds": len(ok), "pos_rms_m": float(np.sqrt(np.mean(d[:, :3] ** 2))),
           "att_rms_deg": float(np.sqrt(np.mean(d[:, 3:] ** 2))), "max_z": float(np.abs(z).max()),
           "rms_z": float(np.sqrt(np.mean(z**2))), "check_rmse_m": np.sqrt(np.mean(e**2, axis=0)).tolist(),
           "exits": [r["exit"] for r in ok]}
    sets = [r.get("_pec_settings") for r in ok if r.get("_pec_settings")]
    if sets and sets[0][0]:
        from lidarcat.accuracy.standards import classify_pec

        out["pec"] = classify_pec(e, sets[0][0], sets[0][1]).classes
    for k in ("lidar_observations", "line_observations", "lidar_removed_by_snooping"):
        out[k] = sum(r.get(k, 0) for r in ok)
    st = [(r.get("measured") or {}).get("status") or {} for r in ok]
    n_meas, n_rej = sum(x.get("measured", 0) for x in st), sum(x.get("rejected", 0) for x in st)
    n_vis = sum(x.get("not_visible", 0) for x in st)
    out["measured_total"] = (f"{n_meas} / {n_rej} ({sum(sum(x.values()) for x in st) - n_meas - n_rej - n_vis}, "
                             f"{n_vis})") if any(st) else "-"
    return out


def _public(r: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in r.items() if not k.startswith("_")}


def table(results: list[dict[str, Any]]) -> str:
    """The markdown table of docs/figures.md: per seed and pooled, auto beside hand."""
    head = ("| seed | control | exit | vertex obs. | measure_control: measured / rejected (not measured, not visible) "
            "| line obs. | removed by snooping | position rms (m) | attitude rms (deg) | auto/hand pos. / att. "
            "| max \\|error\\|/sd | check RMSE E / N / h (m) | PEC 1:2000 | acceptance |\n"
            "|---|---|---|---:|---|---:|---:|---:|---:|---|---:|---|---|---|")
    rows = [head]

    def fmt(seed: Any, name: str, v: dict[str, Any], ratio: str, acc: str) -> str:
        exits = ", ".join(str(x) for x in v["exits"]) if "exits" in v else str(v.get("exit"))
        if "error" in v:
            return f"| {seed} | {name} | {exits} | | {v['error'].split(' (')[0][:110]} | | | | | | | | | {acc} |"
        m = v.get("measured") or {}
        st = dict(m.get("status") or {})
        if "measured_total" in v:
            meas = v["measured_total"]
        elif st:
            n_meas, n_rej, n_vis = st.pop("measured", 0), st.pop("rejected", 0), st.pop("not_visible", 0)
            meas = f"{n_meas} / {n_rej} ({sum(st.values())}, {n_vis})"
        else:
            meas = "-"
        pec = v.get("pec") or {}
        pec_s = f"{pec.get('planimetric', '-')} / {pec.get('altimetric', '-')}"
        return (f"| {seed} | {name} | {exits} | {v['lidar_observations']} | {meas} | {v['line_observations']} | "
                f"{v.get('lidar_removed_by_snooping', 0)} | {v['pos_rms_m']:.3f} | {v['att_rms_deg']:.4f} | {ratio} | "
                f"{v['max_z']:.2f} | {' / '.join(f'{x:.3f}' for x in v['check_rmse_m'])} | {pec_s} | {acc} |")

    for r in results:
        a, h = r["auto"], r["hand"]
        ratio = (f"{a['pos_rms_m'] / h['pos_rms_m']:.2f} / {a['att_rms_deg'] / h['att_rms_deg']:.2f}"
                 if "error" not in a and "error" not in h else "-")
        bad = verdict(a, h)
        rows.append(fmt(f"{r['seed']} ({r['visible_vertices']} of {r['vertices']} vertices in view)", "by hand", h, "",
                        ""))
        rows.append(fmt(r["seed"], "automatic", a, ratio, "pass" if not bad else "**fail**: " + "; ".join(bad)))
    pa, ph = pooled(results, "auto"), pooled(results, "hand")
    if pa and ph and len(results) > 1:
        ratio = f"{pa['pos_rms_m'] / ph['pos_rms_m']:.2f} / {pa['att_rms_deg'] / ph['att_rms_deg']:.2f}"
        pa["pec"], ph["pec"] = pa.get("pec") or {}, ph.get("pec") or {}
        rows.append(fmt("pooled", "by hand", ph, "", ""))
        rows.append(fmt("pooled", "automatic", pa, ratio, ""))
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--size", nargs=2, type=int, default=(1000, 750))
    ap.add_argument("--keep", type=Path, default=None)
    ap.add_argument("--rescore", action="store_true", help="score the kept folders of --keep again, run nothing")
    a = ap.parse_args(argv)
    import tempfile

    if a.rescore and a.keep is None:
        ap.error("--rescore needs --keep DIR")
    base = a.keep or Path(tempfile.mkdtemp(prefix="bench_mc_"))
    load0 = os.getloadavg()[0]
    results = []
    for seed in [int(x) for x in a.seeds.split(",")]:
        d = base / f"seed{seed}"
        if a.rescore:
            from lidarcat.synthetic.aerial import load_aerial_survey

            s = load_aerial_survey(d / "auto")
            n_truth = len(_lidar_points(d / "auto"))
            auto = rescore(s, d / "auto", d / "run-auto")
            hand = rescore(s, d / "hand", d / "run-hand")
        else:
            shutil.rmtree(d, ignore_errors=True)
            s, truth = build(d / "auto", seed, tuple(a.size))
            n_truth = len(truth)
            shutil.copytree(d / "auto", d / "hand")
            hand_measure(s, d / "hand", truth, seed=seed)
            auto = run_variant(s, d / "auto", d / "run-auto")
            hand = run_variant(s, d / "hand", d / "run-hand")
        lid = _lidar_points(d / "hand")
        hand_obs = [x["point"] for x in _rows(d / "hand" / "image_points.csv") if x["point"] in lid]
        r = {"seed": seed, "vertices": n_truth, "hand_rows": len(hand_obs), "visible_vertices": len(set(hand_obs)),
             "auto": auto, "hand": hand}
        if "error" not in auto and "error" not in hand:
            r["ratio"] = {"position": auto["pos_rms_m"] / hand["pos_rms_m"],
                          "attitude": auto["att_rms_deg"] / hand["att_rms_deg"]}
        r["failed"] = verdict(auto, hand)
        results.append(r)
        print(json.dumps({**r, "auto": _public(auto), "hand": _public(hand)}, default=float), flush=True)
    if len(results) > 1:
        pa, ph = pooled(results, "auto"), pooled(results, "hand")
        if pa and ph:
            pa["ratio"] = {"position": pa["pos_rms_m"] / ph["pos_rms_m"],
                           "attitude": pa["att_rms_deg"] / ph["att_rms_deg"]}
        print(json.dumps({"pooled": {"auto": pa, "hand": ph}}, default=float))
    print(table(results))
    print(f"# load {load0:.1f} -> {os.getloadavg()[0]:.1f}; folders in {base}")


if __name__ == "__main__":
    main()
