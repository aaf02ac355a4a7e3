"""LiDAR roof vertices measured in rendered photos against truth (issue 29, docs/photocontrol.md).

For each GSD and seed: a :func:`lidarcat.synthetic.aerial.aerial_survey` block (1 strip of 4
photos, 1200 x 900 px, the approximate orientation 2 m / 0.5 deg off), LiDAR sampled from the
scene (12 points/m^2, 3 cm noise) around each true roof vertex, the vertex extracted, predicted,
measured (:func:`lidarcat.photocontrol.measure_photo`) and tested across the photos
(:func:`lidarcat.photocontrol.check_consistency`); the accepted measurements are scored against
the true vertex projected with the true orientation.  Prints one row per block and the pooled
figures.

    PYTHONPATH=src python benchmarks/bench_photocontrol.py [--gsd 0.10 0.15] [--seeds 0 1 2] [--supersample 4]

The photos are rendered with roofs shaded per ray and ``supersample`` rays per pixel side at
geometric edges (1: one ray per pixel).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np


def block_errors(gsd: float, seed: int, folder: Path, supersample: int = 4) -> tuple[np.ndarray, np.ndarray, dict]:
    import cv2

    from lidarcat.control.vertices import extract_roof
    from lidarcat.photocontrol import VertexTarget, check_consistency, measure_photo, predict_points
    from lidarcat.synthetic.aerial import aerial_survey

    s = aerial_survey(folder, n_strips=1, photos_per_strip=4, gsd_m=gsd, image_size_px=(1200, 900),
                      lidar_density_m2=0, n_gps_points=0, seed=seed, supersample=supersample)
    sc = s.scene
    rng = np.random.default_rng(1)
    eo_cov = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
    found = []
    for v in [v for k, b in enumerate(sc.buildings) for v in b.vertices(sc.base_height(k))]:
        e, n = v[0] + rng.uniform(-9, 9, 3900), v[1] + rng.uniform(-9, 9, 3900)
        xyz = np.column_stack([e, n, sc.surface(e, n)[0] + rng.normal(0, 0.03, len(e))])
        cp = extract_roof(xyz, v[:2] + rng.normal(0, 0.3, 2))
        if cp:
            found.append((v, cp, xyz))
    images = {p: cv2.imread(str(path), cv2.IMREAD_UNCHANGED) for p, path in s.image_paths().items()}
    per_vertex: dict[int, list] = {}
    for k, pid in enumerate(s.photo_ids):
        prs = predict_points(s.camera, s.approx_eo[k], eo_cov, np.array([f[1].enh_m for f in found]),
                             np.array([f[1].cov_m2 for f in found]), photo=pid,
                             dsm=lambda e, n: sc.surface(e, n)[0])
        ms = measure_photo(images[pid], s.camera, s.approx_eo[k],
                           [VertexTarget(f[1].enh_m, f[1].planes, f[2], pr) for f, pr in zip(found, prs)])
        for i, m in enumerate(ms):
            per_vertex.setdefault(i, []).append((k, m))
    errs, norm, counts = [], [], {}
    for i, lst in per_vertex.items():
        v, cp, _ = found[i]
        ks = [k for k, _ in lst]
        out = check_consistency([m for _, m in lst], [s.camera] * len(ks), s.approx_eo[ks],
                                np.repeat(eo_cov[None], len(ks), axis=0), cp.enh_m, cp.cov_m2)
        for k, m in zip(ks, out):
            counts[m.status] = counts.get(m.status, 0) + 1
            if m:
                d = np.asarray(m.px) - s.project(s.photo_ids[k], v[None])[0]
                errs.append(float(np.hypot(*d)))
                norm.extend(d / m.sd_px)
    return np.array(errs), np.array(norm), counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gsd", type=float, nargs="+", default=[0.10, 0.15])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--supersample", type=int, default=4, help="rays per pixel side at geometric edges")
    a = ap.parse_args()
    all_e, all_n = [], []
    print(f"{'gsd':>5} {'seed':>4} {'n':>3} {'median':>7} {'p95':>6} {'max':>6} {'norm sd':>7} {'s':>5}  statuses")
    with tempfile.TemporaryDirectory() as tmp:
        for g in a.gsd:
            for seed in a.seeds:
                t = time.perf_counter()
                e, nz, counts = block_errors(g, seed, Path(tmp) / f"b_{g}_{seed}", a.supersample)
                all_e.append(e)
                all_n.append(nz)
                fmt = (lambda q: f"{q:7.2f}") if len(e) else (lambda q: f"{'-':>7}")
                print(f"{g:5.2f} {seed:4d} {len(e):3d} {fmt(np.median(e) if len(e) else 0)}"
                      f" {fmt(np.percentile(e, 95) if len(e) else 0)[1:]} {fmt(e.max() if len(e) else 0)[1:]}"
                      f" {fmt(np.std(nz) if len(nz) else 0)} {time.perf_counter() - t:5.1f}  {counts}")
    e, nz = np.concatenate(all_e), np.concatenate(all_n)
    if len(e):
        print(f"pooled: {len(e)} measurements, median {np.median(e):.2f} px, 95 % {np.percentile(e, 95):.2f} px, "
              f"max {e.max():.2f} px, normalised sd {np.std(nz):.2f}")


if __name__ == "__main__":
    main()
