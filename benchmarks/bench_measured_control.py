"""Issue 29, the end-to-end acceptance: ``lidarcat run`` with LiDAR point and line control measured
automatically, beside the same block with hand-measured control (docs/figures.md, docs/photocontrol.md).

Usage::

    PYTHONPATH=src python benchmarks/bench_measured_control.py [--seeds 1] [--size 1000 750] [--keep DIR]

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
automatic run passes when its orientation is within 3 sd and its RMS errors within 1.5 x the hand
run's (tests/photocontrol/test_end_to_end.py asserts that, slow).
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


def score(s: Any, truth_points: Path, adjust_dir: Path, assess_dir: Path | None = None) -> dict[str, Any]:
    """Orientation against truth (rms position m, attitude deg, max and rms |error|/sd), GPS check points'
    RMSE E, N, h (m), sigma0^2, the chi-square test, line observations, the PEC class when assessed."""
    d, z = eo_errors(s, adjust_dir)
    tp = {r["point"]: np.array([float(r[c]) for c in ("E", "N", "h")]) for r in _rows(truth_points)}
    chk = [r for r in _rows(adjust_dir / "points.csv") if r["role"] == "check" and r["point"] in tp]
    e = np.array([[float(r["E"]), float(r["N"]), float(r["h"])] - tp[r["point"]] for r in chk]).reshape(-1, 3)
    summ = json.loads((adjust_dir / "summary.json").read_text())
    out = {"pos_rms_m": float(np.sqrt(np.mean(d[:, :3] ** 2))), "att_rms_deg": float(np.sqrt(np.mean(d[:, 3:] ** 2))),
           "max_z": float(np.abs(z).max()), "rms_z": float(np.sqrt(np.mean(z**2))),
           "check_rmse_m": np.sqrt(np.mean(e**2, axis=0)).tolist() if len(e) else [np.nan] * 3,
           "sigma0_sq": summ.get("sigma0_sq"), "chi2_pass": summ.get("chi2_pass"),
           "line_observations": (summ.get("line_control") or {}).get("observations", 0),
           "lidar_observations": sum(1 for r in _rows(adjust_dir / "residuals.csv")
                                     if r.get("kind") == "image" and r["point"].startswith("C"))}
    if assess_dir is not None and (assess_dir / "assessment.json").is_file():
        pec = json.loads((assess_dir / "assessment.json").read_text())["standards"]["pec"]
        out["pec"] = {"planimetric": pec["class"]["planimetric"], "altimetric": pec["class"]["altimetric"],
                      "label": pec.get("label", "")}
    return out


def run_variant(s: Any, root: Path, out: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    r = _cli("run", str(root), "-o", str(out))
    res = {"exit": r.returncode, "seconds": round(time.perf_counter() - t0, 1)}
    if not (out / "adjust-lidar" / "eop.csv").is_file():
        res["error"] = (r.stdout + r.stderr)[-1500:]
        return res
    res.update(score(s, root / "truth" / "points.csv", out / "adjust-lidar", out / "assess-lidar"))
    mc = out / "measure_control" / "measure_control.json"
    if mc.is_file():
        j = json.loads(mc.read_text())
        res["measured"] = {"points": j.get("accepted"), "line_observations": j.get("line_observations")}
    return res


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--size", nargs=2, type=int, default=(1000, 750))
    ap.add_argument("--keep", type=Path, default=None)
    a = ap.parse_args(argv)
    import tempfile

    base = a.keep or Path(tempfile.mkdtemp(prefix="bench_mc_"))
    load0 = os.getloadavg()[0]
    for seed in [int(x) for x in a.seeds.split(",")]:
        d = base / f"seed{seed}"
        shutil.rmtree(d, ignore_errors=True)
        s, truth = build(d / "auto", seed, tuple(a.size))
        shutil.copytree(d / "auto", d / "hand")
        n_hand = hand_measure(s, d / "hand", truth, seed=seed)
        auto = run_variant(s, d / "auto", d / "run-auto")
        hand = run_variant(s, d / "hand", d / "run-hand")
        print(json.dumps({"seed": seed, "vertices": len(truth), "hand_rows": n_hand, "auto": auto, "hand": hand},
                         default=float))
    print(f"# load {load0:.1f} -> {os.getloadavg()[0]:.1f}; folders in {base}")


if __name__ == "__main__":
    main()
