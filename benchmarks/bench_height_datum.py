"""Issue 29, seed 6 of ``bench_measured_control.py``: what fixes the block's height (docs/figures.md, "Seed 6's
height: a control vertex on one photo is a ray").

Usage::

    PYTHONPATH=src python benchmarks/bench_height_datum.py DIR/seed6 [--out /tmp/height_datum]

*DIR/seed6* is a folder kept by ``bench_measured_control.py --keep DIR`` (``auto``, ``hand``, ``run-auto``).
Part 1 adjusts the automatic run's observations as the stage does (the debug recipe of docs/figures.md:
``adjust_survey(control="lidar", eo_constraints=True, snooping="remove", variance_components=True)`` on the
kept survey with ``run-auto/measure_control``'s image_points.csv and line_control.csv), then variants of
them: without a vertex's along-one-edge point or its edges, with the hand reference's measurement in
their place, with the hand reference's observations of the vertex-photo pairs the automatic run lost, with
the GNSS heights set to the truth.  Printed per variant: the photos' Z0 error, the check points' height
error and the adjustment's sd of it.

Part 2 is the block as a rigid body (its shape held by the ties; only its 7 similarity parameters float):
each control vertex measured on a photo fixes the two across-ray components of its displacement (sd =
the image sd at the vertex's distance), each photo's GNSS (2 m) its centre and the IMU (0.5 deg) the
rotation.  The check points' height sd of this model beside the adjustment's shows which observations fix
the height; the mode that carries it is printed per 1 m at the check points.

Part 3 (``--second-pass``) predicts the pairs the automatic run did not measure again, from the
orientation of part 1's stage adjustment (with its sds: ties + GNSS/IMU + the measured control, no GPS
target), measures them with ``MeasureParams(border="fit")`` (``measure_control`` on the debug survey: the
pairs measured in the first pass are kept), scores each against the true projection and adjusts the
survey with them as part 1 does; the orientation is scored as ``bench_measured_control.py`` scores it.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import tomllib
from pathlib import Path

import numpy as np


def _rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(ln for ln in fh if not ln.startswith("#")))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True)


def debug_survey(kept: Path, dest: Path) -> Path:
    """The automatic survey with the stage's image_points.csv and line_control.csv (e2e29's recipe)."""
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(kept / "auto", dest)
    for fn in ("image_points.csv", "line_control.csv"):
        shutil.copy(kept / "run-auto" / "measure_control" / fn, dest / fn)
    toml = (dest / "survey.toml").read_text()
    if "line_control" not in toml:
        toml = toml.replace("[files]\n", '[files]\nline_control = "line_control.csv"\n', 1)
    (dest / "survey.toml").write_text(toml)
    return dest


def adjust_variant(base: Path, out: Path, name: str, points=None, lines=None, photos=None) -> dict:
    """Adjust *base* edited by the callables (list of csv lines -> list) as the stage does; score the heights."""
    from lidarcat.survey.adjustment import adjust_survey
    from lidarcat.survey.folder import Survey

    d = out / "surveys" / name
    if d.exists():
        shutil.rmtree(d)
    shutil.copytree(base, d)
    for fn, edit in (("image_points.csv", points), ("line_control.csv", lines), ("photos.csv", photos)):
        if edit is not None:
            (d / fn).write_text("".join(edit(_lines(d / fn))))
    res_dir = out / "adjust" / name
    if res_dir.exists():
        shutil.rmtree(res_dir)
    adjust_survey(Survey.load(d), control="lidar", eo_constraints=True, snooping="remove",
                  variance_components=True, outdir=res_dir)
    truth = {r["photo"]: r for r in _rows(d / "truth" / "eop.csv")}
    eop = {r["photo"]: r for r in _rows(res_dir / "eop.csv")}
    pts = {r["point"]: r for r in _rows(res_dir / "points.csv")}
    gt = {r["point"]: r for r in _rows(d / "ground_points.csv")}
    checks = [r["point"] for r in _rows(d / "control_sets.csv") if r["set"] == "lidar" and r["role"] == "check"]
    dh = np.array([float(pts[g]["h"]) - float(gt[g]["h"]) for g in checks])
    sd = np.array([float(pts[g]["sd_h"]) for g in checks])
    return {"variant": name, "dZ0_m": [round(float(eop[p]["Z0"]) - float(truth[p]["Z0"]), 2) for p in sorted(truth)],
            "check_dh_m": np.round(dh, 3).tolist(), "check_sd_h_m": np.round(sd, 2).tolist(),
            "check_rmse_h_m": round(float(np.sqrt(np.mean(dh ** 2))), 3),
            "sigma0_sq": round(json.loads((res_dir / "summary.json").read_text())["sigma0_sq"], 3)}


def _pairs(path: Path, vertices: set[str]) -> dict[tuple[str, str], str]:
    return {(ln.split(",")[0], ln.split(",")[1]): ln for ln in _lines(path)[1:] if ln.split(",")[1] in vertices}


def variants(kept: Path, out: Path) -> list[dict]:
    base = debug_survey(kept, out / "debug")
    vertices = {r["point"] for r in _rows(base / "ground_points.csv") if r.get("source") == "lidar"}
    auto = _pairs(base / "image_points.csv", vertices)
    hand = _pairs(kept / "hand" / "image_points.csv", vertices)
    along = {k for k, ln in auto.items() if ln.strip().split(",")[4] == ln.strip().split(",")[5]}   # one sd: along
    tr = {r["photo"]: r for r in _rows(base / "truth" / "eop.csv")}

    def truth_z(lines: list[str]) -> list[str]:
        hdr = lines[0].strip().split(",")
        iz = hdr.index("Z0")
        body = [ln.rstrip("\n").split(",") for ln in lines[1:]]
        for f in body:
            f[iz] = f"{float(tr[f[0]]['Z0']):.3f}"
        return [lines[0]] + [",".join(f) + "\n" for f in body]

    def drop_pts(keys):
        return lambda L: [ln for ln in L if tuple(ln.split(",")[:2]) not in keys]

    def drop_lines(keys):       # the image line observations of the vertex on that photo
        return lambda L: [ln for ln in L if not any(ln.startswith(f"{v}/") and ln.split(",")[1] == p
                                                    for p, v in keys)]

    lost = {k: ln for k, ln in hand.items() if k not in auto}
    out_rows = [adjust_variant(base, out, "automatic (as the stage)")]
    if along:
        out_rows.append(adjust_variant(base, out, "without the along-one-edge points", points=drop_pts(along)))
        out_rows.append(adjust_variant(base, out, "without their edges", lines=drop_lines(along)))
        out_rows.append(adjust_variant(base, out, "without both", points=drop_pts(along), lines=drop_lines(along)))
        out_rows.append(adjust_variant(base, out, "hand's 0.5 px point in their place, no edges",
                                       points=lambda L: drop_pts(along)(L) + [hand[k] for k in along if k in hand],
                                       lines=drop_lines(along)))
    if lost:
        out_rows.append(adjust_variant(base, out, "+ hand's lost pairs " + " ".join(f"{v}/{p}" for p, v in lost),
                                       points=lambda L: L + list(lost.values())))
    out_rows.append(adjust_variant(base, out, "GNSS heights = truth", photos=truth_z))
    return out_rows


def rigid_block(kept: Path, rays: list[tuple[str, str, float]], gnss_sd_m: float = 2.0,
                imu_sd_deg: float = 0.5) -> dict:
    """The check points' height sd of the block as a rigid body held by *rays* (vertex, photo, sd px)."""
    s = kept / "auto"
    gp = {r["point"]: np.array([float(r["E"]), float(r["N"]), float(r["h"])]) for r in _rows(s / "ground_points.csv")}
    cam = {r["photo"]: np.array([float(r["X0"]), float(r["Y0"]), float(r["Z0"])])
           for r in _rows(s / "truth" / "eop.csv")}
    cfg = next(iter(tomllib.loads((s / "camera.toml").read_text()).values()))
    px_rad = cfg["pixel_size_x_mm"] / cfg["focal_length_mm"]
    checks = [r["point"] for r in _rows(s / "control_sets.csv") if r["set"] == "lidar" and r["role"] == "check"]
    c = np.mean(list(cam.values()), axis=0)
    c[2] = np.mean([gp[g][2] for g in checks])

    def dmat(x):                    # displacement of x per (t_E, t_N, t_h, rotation x3 (rad), scale): 3 x 7
        r = x - c
        return np.hstack([np.eye(3), np.array([[0, r[2], -r[1]], [-r[2], 0, r[0]], [r[1], -r[0], 0]]), r[:, None]])

    A = []
    for v, p, sd_px in rays:
        u = cam[p] - gp[v]
        dist = np.linalg.norm(u)
        u /= dist
        across = np.linalg.svd(np.eye(3) - np.outer(u, u))[0][:, :2].T
        A.append(across @ dmat(gp[v]) / (sd_px * px_rad * dist))
    rot = np.zeros((3, 7))
    rot[:, 3:6] = np.eye(3)
    for p in cam:
        A += [dmat(cam[p]) / gnss_sd_m, rot / np.radians(imu_sd_deg)]
    A = np.vstack(A)
    Q = np.linalg.inv(A.T @ A)
    g = np.mean([dmat(gp[x])[2] for x in checks], axis=0)
    sd = float(np.sqrt(g @ Q @ g))
    m = Q @ g / (g @ Q @ g)         # the parameters' change that goes with +1 m at the check points
    return {"rays": [f"{v}/{p} {sd_px} px" for v, p, sd_px in rays], "check_sd_h_m": round(sd, 2),
            "mode_per_1m": {"t_h_m": round(float(m[2]), 2), "scale_ppm": round(float(m[6]) * 1e6),
                            "cameras_dZ_mean_m": round(float(np.mean([(dmat(cam[p]) @ m)[2] for p in cam])), 2),
                            **{f"{v}_moves_m": np.round(dmat(gp[v]) @ m, 2).tolist() for v, _, _ in rays}},
            "off_nadir_deg": {f"{v}/{p}": round(float(np.degrees(np.arccos((cam[p] - gp[v])[2]
                                                                             / np.linalg.norm(cam[p] - gp[v])))), 1)
                              for v, p, _ in rays}}


def second_pass(kept: Path, out: Path) -> list[dict]:
    """Part 3: the lost pairs measured again with the first adjustment's orientation as the approximate one."""
    import sys

    from lidarcat.photocontrol.measure import MeasureParams
    from lidarcat.stages.measure_control import measure_control
    from lidarcat.synthetic.aerial import load_aerial_survey

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_measured_control import score

    base = out / "debug"
    first = out / "adjust" / "automatic (as the stage)"
    s2 = out / "pass2" / "survey"
    if s2.exists():
        shutil.rmtree(s2)
    shutil.copytree(base, s2)
    adj = {r["photo"]: r for r in _rows(first / "eop.csv")}
    rows = _rows(s2 / "photos.csv")
    for r in rows:
        a = adj[r["photo"]]
        for k in ("X0", "Y0", "Z0"):
            r[k], r["sd_" + k] = a[k], a["sd_" + k]
        for k in ("omega", "phi", "kappa"):          # eop.csv: degrees
            r[k + "_deg"], r["sd_" + k + "_deg"] = a[k], a["sd_" + k]
    with open(s2 / "photos.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    res = out / "pass2" / "measure_control"
    if res.exists():
        shutil.rmtree(res)
    measure_control(s2, res, params=MeasureParams(border="fit"), gallery=False)
    aerial = load_aerial_survey(base)
    sc = aerial.scene
    true = np.array([v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))])
    gp = {r["point"]: np.array([float(r["E"]), float(r["N"]), float(r["h"])]) for r in _rows(base / "ground_points.csv")
          if r.get("source") == "lidar"}
    report, new = [], []
    for r in _rows(res / "decisions.csv"):
        if r["status"] == "not_visible":
            continue
        item = {"pair": f"{r['point']}/{r['photo']}", "status": r["status"],
                "predicted_sd_px": float(r["pred_sd_px"]), "reason": r["reason"][:160]}
        if r["status"] == "measured":
            tv = true[int(np.argmin(np.linalg.norm(true - gp[r["point"]], axis=1)))]
            m = np.array([float(r["col_px"]), float(r["row_px"])])
            item["error_px"] = round(float(np.linalg.norm(m - aerial.project(r["photo"], tv[None])[0])), 2)
            item["sd_px"] = [float(r["sd_col_px"]), float(r["sd_row_px"])]
            new.append(r)
        report.append(item)
    pix = float(next(iter(tomllib.loads((base / "camera.toml").read_text()).values()))["pixel_size_x_mm"])
    added = [f"{r['photo']},{r['point']},{r['col_px']},{r['row_px']},{float(r['sd_col_px']) * pix:.6f},"
             f"{float(r['sd_row_px']) * pix:.6f}\n" for r in new]
    if added:
        row = adjust_variant(base, out, "+ the second pass's measurements", points=lambda L: L + added)
        sc_ = score(aerial, base / "truth" / "points.csv", out / "adjust" / "+ the second pass's measurements")
        hand = score(aerial, base / "truth" / "points.csv", kept / "run-hand" / "adjust-lidar")
        row.update({"pos_rms_m": round(sc_["pos_rms_m"], 3), "att_rms_deg": round(sc_["att_rms_deg"], 4),
                    "max_z": round(sc_["max_z"], 2), "check_rmse_vs_truth_m": np.round(sc_["check_rmse_m"], 3).tolist(),
                    "auto_over_hand": [round(sc_["pos_rms_m"] / hand["pos_rms_m"], 2),
                                       round(sc_["att_rms_deg"] / hand["att_rms_deg"], 2)]})
        report.append(row)
    return report


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kept", type=Path, help="DIR/seedN kept by bench_measured_control.py --keep DIR")
    ap.add_argument("--out", type=Path, default=Path("/tmp/height_datum"))
    ap.add_argument("--second-pass", action="store_true", help="part 3 (module docstring)")
    a = ap.parse_args()
    for r in variants(a.kept, a.out):
        print(json.dumps(r), flush=True)
    pix = float(next(iter(tomllib.loads((a.kept / "auto" / "camera.toml").read_text()).values()))["pixel_size_x_mm"])
    vertices = {r["point"] for r in _rows(a.kept / "auto" / "ground_points.csv") if r.get("source") == "lidar"}

    def rays(path: Path) -> list[tuple[str, str, float]]:     # (vertex, photo, sd px: geometric mean of the two)
        return [(r["point"], r["photo"], round(float(np.sqrt(float(r["sd_x_mm"]) * float(r["sd_y_mm"]))) / pix, 2))
                for r in _rows(path) if r["point"] in vertices]

    auto = rays(a.kept / "run-auto" / "measure_control" / "image_points.csv")
    hand = rays(a.kept / "hand" / "image_points.csv")
    seen = {(v, p) for v, p, _ in auto}
    for sub in ([], auto, [h for h in hand if (h[0], h[1]) in seen], hand):
        print(json.dumps(rigid_block(a.kept, sub)))
    if a.second_pass:
        for r in second_pass(a.kept, a.out):
            print(json.dumps(r), flush=True)


if __name__ == "__main__":
    main()
