"""LiDAR roof vertices measured in photos rendered over the real AHN3 roofs, against truth (issue 29, step 5).

The AHN3 tiles of ``tests/data/lidar`` (CC0) and the 14 vertices of
``tests/data/extract/ahn3_vertices.csv``: each vertex is extracted again from the LiDAR within
30 m (:func:`lidarcat.control.vertices.extract_roof`, as ``lidarcat measure-control`` does),
its fitted planes become an exact roof patch of the scene (:mod:`lidarcat.synthetic.lidarphoto`;
the rest is the TIN of the first returns with the intensity as albedo), and synthetic flights
(2 strips x 3 photos, 800 x 600 px, c = 100 mm, over four clusters of vertices, GSD 5-15 cm, exposure and sun per photo, the
approximate orientation 2 m / 0.5 deg off) photograph it.  Each vertex is predicted
(:func:`lidarcat.photocontrol.predict_points`, occlusion on the DSM of the LiDAR as the stage
builds it), measured (:func:`lidarcat.photocontrol.measure_photo`) and tested across the
photos (:func:`lidarcat.photocontrol.check_consistency`); the accepted measurements are scored
against the vertex projected with the true orientation, and against the occlusion truth (the
ray from the camera to the vertex on the rendered surface).

    PYTHONPATH=src python benchmarks/bench_photocontrol_ahn3.py [--flights F1 F2 F3 F4] [--gsd 0.05 0.10 0.15] [--seeds 0]
        [--compare] [--occlusion-photos 6]

``--compare`` also scores each block without the per-photo test (:func:`lidarcat.photocontrol.check_photo`)
and with the measurements alone on their photo rejected (``(alone rej.)`` rows), from the same renders; a GSD given alone renders the same block (seed) as in the full run.

Prints one row per block (flight, GSD, seed) and the pooled figures.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TILES = [ROOT / "tests" / "data" / "lidar" / f"ahn3_cropped_{i}.laz" for i in (1, 2)]
VERTICES = ROOT / "tests" / "data" / "extract" / "ahn3_vertices.csv"
#: flights: centre (E, N) and strip heading (deg from north), over clusters of the listed vertices
GSDS = (0.05, 0.10, 0.15)
FLIGHTS = {
    "F1": ((85003.0, 447474.0), 90.0),     # A01 A11 (A10 A14 and more at the larger GSDs)
    "F2": ((84910.0, 447468.0), 90.0),     # A03 A04
    "F3": ((85038.0, 447500.0), 0.0),      # A10 A14
    "F4": ((85006.0, 447541.0), 0.0),      # A06 A09 A13
}


@dataclasses.dataclass
class Ahn3:
    """The AHN3 points, the vertices extracted again (id, control point, the 30 m clip) and the scene."""

    xyz: np.ndarray
    vertices: list
    surface: Any
    ground_m: float


def load_ahn3(bounds: tuple[float, float, float, float] | None = None, *, cell_m: float = 0.1,
              only: list[str] | None = None) -> Ahn3:
    """Read the tiles, extract the listed vertices inside *bounds* again, build the rendered surface."""
    from lidarcat.control.vertices import extract_roof
    from lidarcat.lidar.readers import read_points
    from lidarcat.photocontrol import face_labels
    from lidarcat.synthetic.lidarphoto import lidar_surface, roof_patch

    pcs = [read_points(p, crs="EPSG:7415") for p in TILES]
    xyz = np.vstack([p.xyz for p in pcs])
    inten = np.concatenate([p.attributes["intensity"] for p in pcs]).astype(np.float64)
    first = np.concatenate([p.attributes["return_number"] for p in pcs]) == 1
    if bounds is None:
        bounds = (*np.floor(xyz[:, :2].min(axis=0)), *np.ceil(xyz[:, :2].max(axis=0)))
    e0, n0, e1, n1 = bounds
    keep = (xyz[:, 0] > e0 - 32) & (xyz[:, 0] < e1 + 32) & (xyz[:, 1] > n0 - 32) & (xyz[:, 1] < n1 + 32)
    xyz, inten, first = xyz[keep], inten[keep], first[keep]
    rows = list(csv.DictReader(line for line in VERTICES.open() if not line.startswith("#")))
    found, patches = [], []
    for r in rows:
        pid, e, n = r["point"], float(r["approx_E"]), float(r["approx_N"])
        if (only and pid not in only) or not (e0 + 6 < e < e1 - 6 and n0 + 6 < n < n1 - 6):
            continue
        clip = xyz[np.hypot(xyz[:, 0] - e, xyz[:, 1] - n) <= 30.0]
        cp = extract_roof(clip, [e, n], point_id=pid)
        if not cp:
            continue
        v = cp.enh_m
        near = clip[np.hypot(clip[:, 0] - v[0], clip[:, 1] - v[1]) <= 6.0]
        lab = face_labels(cp.planes, near, 0.15)
        if min(int(np.sum(lab == i)) for i in range(len(cp.planes))) < 3:
            continue
        patches.append(roof_patch(v, [p.n for p in cp.planes], [near[lab == i] for i in range(len(cp.planes))]))
        found.append((pid, cp, clip))
    surf = lidar_surface(xyz[first], inten[first], bounds, cell_m=cell_m, patches=patches)
    ground = float(np.percentile(xyz[first, 2], 10))
    return Ahn3(xyz, found, surf, ground)


def score_block(data: Ahn3, centre: tuple[float, float], heading_deg: float, gsd: float, seed: int, *,
                size: tuple[int, int] = (800, 600), n_strips: int = 2, per_strip: int = 3,
                focal_mm: float = 100.0, supersample: int = 4, params: Any = None,
                min_photos: int = 2, keep_photos: bool = False, photo_test: bool = True,
                compare: bool = False, alone: str = "keep") -> dict:
    """Render one flight, measure every vertex on every photo as ``measure-control`` does, score.

    Returns a dict: ``errors`` (px) and ``normalised`` (dx/sd, dy/sd) of the accepted
    measurements, ``statuses`` (counts), ``occluded_accepted`` (accepted where the truth says
    occluded), ``occluded_pairs`` (vertex-photo pairs in the frame but occluded), ``n_photos``.
    ``photo_test``: each photo's measurements tested against their common displacement
    (:func:`lidarcat.photocontrol.check_photo`) before the multi-photo test, as the stage does;
    ``compare``: also the figures of the other choice, under ``without_photo_test`` (or
    ``with_photo_test``), and with the measurements alone on their photo rejected
    (``alone_rejected``), from the same renders; ``alone``: check_photo's choice for those.
    """
    from lidarcat.photocontrol import VertexTarget, check_photo, measure_photo, predict_points
    from lidarcat.stages.measure_control import dsm_of_points
    from lidarcat.synthetic.aerial import Exposure, project_to_pixels
    from lidarcat.synthetic.aerial import aerial_camera
    from lidarcat.synthetic.lidarphoto import flight_poses, render_lidar_photo, vertex_visible

    cam = dataclasses.replace(aerial_camera(size), focal_length_mm=float(focal_mm))
    eo = flight_poses(centre, data.ground_m, gsd, cam, n_strips=n_strips, per_strip=per_strip,
                      heading_deg=heading_deg, seed=seed)
    rng = np.random.default_rng(1000 + seed)
    approx = eo + np.column_stack([rng.normal(0, 2.0, (len(eo), 3)), np.radians(rng.normal(0, 0.5, (len(eo), 3)))])
    eo_cov = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
    sun_az, sun_el = rng.uniform(120, 240), rng.uniform(30, 55)
    V = np.array([cp.enh_m for _, cp, _ in data.vertices])
    covs = np.array([cp.cov_m2 for _, cp, _ in data.vertices])
    ids = [pid for pid, _, _ in data.vertices]
    dsms = [dsm_of_points(clip) for _, _, clip in data.vertices]      # as the stage: the DSM of the 30 m clip
    per_vertex: dict[int, list] = {}
    per_vertex_checked: dict[int, list] = {}
    per_vertex_alone: dict[int, list] = {}

    def decide(pv: dict) -> dict:
        return _decide(pv, cam, approx, eo_cov, V, covs, ids, truth, vis_truth, min_photos)

    truth, vis_truth, photos = {}, {}, {}
    occluded_pairs = 0
    for k in range(len(eo)):
        pid = f"p{k}"
        tp = project_to_pixels(cam, eo[k], V)
        inside = np.isfinite(tp).all(axis=1) & (tp[:, 0] >= 0) & (tp[:, 1] >= 0) \
            & (tp[:, 0] <= cam.columns_px - 1) & (tp[:, 1] <= cam.rows_px - 1)
        prs = [predict_points(cam, approx[k], eo_cov, V[i:i + 1], covs[i:i + 1], points=ids[i:i + 1], photo=pid,
                              dsm=dsms[i])[0] for i in range(len(V))]
        if not (inside.any() or any(bool(p) for p in prs)):
            continue
        vis = vertex_visible(data.surface, eo[k], V)
        occluded_pairs += int(np.sum(inside & ~vis))
        ph = render_lidar_photo(data.surface, cam, eo[k],
                                exposure=Exposure.random(100 * seed + k, noise_sd=1.0),
                                sun_azimuth_deg=sun_az + rng.normal(0, 1), sun_elevation_deg=sun_el + rng.normal(0, 1),
                                supersample=supersample)
        if keep_photos:
            photos[pid] = ph.image
        targets = [VertexTarget(cp.enh_m, cp.planes, clip, pr) for (_, cp, clip), pr in zip(data.vertices, prs)]
        ms = measure_photo(ph.image, cam, approx[k], targets, params) if params else \
            measure_photo(ph.image, cam, approx[k], targets)
        # as the stage: each photo's measurements against their common displacement
        checked = check_photo(ms, cam, approx[k], eo_cov, V, covs, alone=alone)
        checked_alone = check_photo(ms, cam, approx[k], eo_cov, V, covs, alone="reject")
        for i, m in enumerate(ms):
            per_vertex.setdefault(i, []).append((k, m))
            per_vertex_checked.setdefault(i, []).append((k, checked[i]))
            per_vertex_alone.setdefault(i, []).append((k, checked_alone[i]))
            truth[(i, k)] = tp[i]
            vis_truth[(i, k)] = bool(vis[i])
    out = decide(per_vertex_checked if photo_test else per_vertex)
    if compare:
        out["without_photo_test" if photo_test else "with_photo_test"] = \
            decide(per_vertex if photo_test else per_vertex_checked)
        out["alone_rejected"] = decide(per_vertex_alone)
    return dict(out, occluded_pairs=occluded_pairs, n_photos=len(eo), photos=photos)


def _decide(per_vertex: dict, cam: Any, approx: np.ndarray, eo_cov: np.ndarray, V: np.ndarray, covs: np.ndarray,
            ids: list, truth: dict, vis_truth: dict, min_photos: int) -> dict:
    """The multi-photo test and the one-photo rule of the stage, scored against truth."""
    from lidarcat.photocontrol import check_consistency

    errs, norm, counts, occ_acc, rows, decisions = [], [], {}, 0, [], []
    for i, lst in per_vertex.items():
        ks = [k for k, _ in lst]
        out = check_consistency([m for _, m in lst], [cam] * len(ks), approx[ks],
                                np.repeat(eo_cov[None], len(ks), axis=0), V[i], covs[i])
        n_ok = sum(bool(m) for m in out)
        if 0 < n_ok < min_photos:      # as the stage: a vertex accepted on one photo only is rejected
            out = [m.failed("rejected", f"measured on {n_ok} photo(s) only") if m else m for m in out]
        for k, m in zip(ks, out):
            counts[m.status] = counts.get(m.status, 0) + 1
            decisions.append((ids[i], k, m.status, m.reason, np.asarray(m.px), truth[(i, k)], vis_truth[(i, k)]))
            if m:
                if not vis_truth[(i, k)]:
                    occ_acc += 1
                d = np.asarray(m.px) - truth[(i, k)]
                errs.append(float(np.hypot(*d)))
                norm.extend((d / np.sqrt(np.diag(m.cov_px2))).tolist())
                rows.append((ids[i], k, float(np.hypot(*d)), np.asarray(m.px), truth[(i, k)], np.sqrt(np.diag(m.cov_px2))))
    return dict(errors=np.array(errs), normalised=np.array(norm), statuses=counts, occluded_accepted=occ_acc,
                rows=rows, decisions=decisions)


def look_at(centre_m: np.ndarray, target_m: np.ndarray, kappa: float = 0.0) -> np.ndarray:
    """(6,) orientation at *centre_m* whose camera axis points at *target_m* (omega, phi solved, kappa given)."""
    from lidarcat.geometry.collinearity import rotation_matrix

    u = (target_m - centre_m) / np.linalg.norm(target_m - centre_m)
    for om, ph in [(math.atan2(u[1], -u[2]), math.asin(-u[0])), (math.atan2(-u[1], -u[2]), math.asin(u[0]))]:
        eo = np.array([*centre_m, om, ph, kappa])
        m = rotation_matrix(eo[3:])
        if np.allclose(m.T @ np.array([0.0, 0.0, -1.0]), u, atol=1e-9):
            return eo
    raise AssertionError("no look-at solution")


def occlusion_block(data: Ahn3, gsd: float = 0.10, off_nadir_deg: float = 60.0, seed: int = 0, *,
                    size: tuple[int, int] = (800, 600), focal_mm: float = 100.0, max_photos: int = 6) -> dict:
    """Oblique photos aimed at the vertices from azimuths where the real surface hides them.

    For each vertex, cameras at *off_nadir_deg* from 12 azimuths (the distance giving *gsd* at
    the vertex) are tested with :func:`~lidarcat.synthetic.lidarphoto.vertex_visible`; up to
    *max_photos* of the hidden views are rendered and every vertex is predicted (approximate
    orientation, the stage's DSM) and measured on them.  Returns ``hidden`` (vertex-photo
    pairs in the frame but hidden), ``measured_hidden`` (of them measured by ``measure_photo``,
    before any test across photos), ``statuses`` of the hidden pairs.
    """
    from lidarcat.photocontrol import VertexTarget, measure_photo, predict_points
    from lidarcat.stages.measure_control import dsm_of_points
    from lidarcat.synthetic.aerial import Exposure, project_to_pixels
    from lidarcat.synthetic.aerial import aerial_camera
    from lidarcat.synthetic.lidarphoto import render_lidar_photo, vertex_visible

    cam = dataclasses.replace(aerial_camera(size), focal_length_mm=float(focal_mm))
    dist = gsd * cam.focal_length_mm / cam.pixel_size_x_mm
    rng = np.random.default_rng(2000 + seed)
    V = np.array([cp.enh_m for _, cp, _ in data.vertices])
    covs = np.array([cp.cov_m2 for _, cp, _ in data.vertices])
    ids = [pid for pid, _, _ in data.vertices]
    dsms = [dsm_of_points(clip) for _, _, clip in data.vertices]
    eo_cov = np.diag([2.0**2] * 3 + [math.radians(0.5) ** 2] * 3)
    views = []
    for i, v in enumerate(V):
        for az in np.radians(np.arange(0, 360, 30) + rng.uniform(0, 30)):
            off = math.radians(off_nadir_deg)
            c = v + dist * np.array([math.sin(off) * math.sin(az), math.sin(off) * math.cos(az), math.cos(off)])
            eo = look_at(c, v, kappa=float(rng.uniform(-math.pi, math.pi)))
            if not vertex_visible(data.surface, eo, v[None])[0]:
                views.append((i, eo))
    rng.shuffle(views)
    hidden, measured_hidden, statuses = 0, 0, {}
    for k, (i0, eo) in enumerate(views[:max_photos]):
        tp = project_to_pixels(cam, eo, V)
        inside = np.isfinite(tp).all(axis=1) & (tp[:, 0] >= 0) & (tp[:, 1] >= 0) \
            & (tp[:, 0] <= cam.columns_px - 1) & (tp[:, 1] <= cam.rows_px - 1)
        vis = vertex_visible(data.surface, eo, V)
        approx = eo + np.r_[rng.normal(0, 2.0, 3), np.radians(rng.normal(0, 0.5, 3))]
        prs = [predict_points(cam, approx, eo_cov, V[i:i + 1], covs[i:i + 1], points=ids[i:i + 1], photo=f"o{k}",
                              dsm=dsms[i])[0] for i in range(len(V))]
        img = render_lidar_photo(data.surface, cam, eo, exposure=Exposure.random(300 + k, noise_sd=1.0),
                                 sun_azimuth_deg=float(rng.uniform(120, 240)), sun_elevation_deg=40.0).image
        ms = measure_photo(img, cam, approx, [VertexTarget(cp.enh_m, cp.planes, clip, pr)
                                              for (_, cp, clip), pr in zip(data.vertices, prs)])
        for i, m in enumerate(ms):
            if inside[i] and not vis[i]:
                hidden += 1
                measured_hidden += int(m.status == "measured")
                statuses[m.status] = statuses.get(m.status, 0) + 1
    return dict(hidden=hidden, measured_hidden=measured_hidden, statuses=statuses, views=len(views))


def summary(e: np.ndarray, nz: np.ndarray) -> tuple[int, float, float, float, float]:
    """n, median, 95 %, max (px), sd of the normalised errors."""
    if not len(e):
        return 0, math.nan, math.nan, math.nan, math.nan
    return len(e), float(np.median(e)), float(np.percentile(e, 95)), float(e.max()), float(np.std(nz))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", nargs="+", default=list(FLIGHTS), choices=list(FLIGHTS))
    ap.add_argument("--gsd", type=float, nargs="+", default=list(GSDS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0],
                    help="the block's seed is 100 seed + 10 flight + GSD index")
    ap.add_argument("--supersample", type=int, default=4, help="rays per pixel side at edges")
    ap.add_argument("--occlusion-photos", type=int, default=6, help="oblique photos of hidden vertices (0: none)")
    ap.add_argument("--compare", action="store_true",
                    help="also print each block without the per-photo test (check_photo), from the same renders")
    a = ap.parse_args()
    t = time.perf_counter()
    data = load_ahn3()
    print(f"scene: {len(data.vertices)} vertices extracted, surface {data.surface.height.shape} cells "
          f"({time.perf_counter() - t:.0f} s)")
    print(f"{'flight':>6} {'gsd':>5} {'seed':>4} {'n':>3} {'median':>7} {'p95':>6} {'max':>6} {'norm sd':>7} "
          f"{'occl':>4} {'occ.acc':>7} {'s':>5}  statuses")
    all_e, all_n, occ_acc, occ, all_w, all_a = [], [], 0, 0, [], []
    for fi, f in enumerate(a.flights):
        centre, heading = FLIGHTS[f]
        for gi, g in enumerate(a.gsd):
            for s0 in a.seeds:
                # the GSD's index in the default list, so that one GSD alone renders the same block
                gk = GSDS.index(g) if g in GSDS else gi
                seed = 100 * s0 + 10 * list(FLIGHTS).index(f) + gk
                t = time.perf_counter()
                r = score_block(data, centre, heading, g, seed, supersample=a.supersample, compare=a.compare)
                if a.compare:
                    w = r["without_photo_test"]
                    n, med, p95, mx, sd = summary(w["errors"], w["normalised"])
                    print(f"{'(w/o':>6} {'ph.)':>5} {seed:4d} {n:3d} {med:7.2f} {p95:6.2f} {mx:6.2f} {sd:7.2f} "
                          f"{'':>4} {w['occluded_accepted']:7d} {'':>5}  {w['statuses']}", flush=True)
                    all_w.append(w["errors"])
                    w = r["alone_rejected"]
                    n, med, p95, mx, sd = summary(w["errors"], w["normalised"])
                    print(f"{'(alone':>6} {'rej.)':>5} {seed:4d} {n:3d} {med:7.2f} {p95:6.2f} {mx:6.2f} {sd:7.2f} "
                          f"{'':>4} {w['occluded_accepted']:7d} {'':>5}  {w['statuses']}", flush=True)
                    all_a.append(w["errors"])
                all_e.append(r["errors"])
                all_n.append(r["normalised"])
                occ_acc += r["occluded_accepted"]
                occ += r["occluded_pairs"]
                n, med, p95, mx, sd = summary(r["errors"], r["normalised"])
                print(f"{f:>6} {g:5.2f} {seed:4d} {n:3d} {med:7.2f} {p95:6.2f} {mx:6.2f} {sd:7.2f} "
                      f"{r['occluded_pairs']:4d} {r['occluded_accepted']:7d} {time.perf_counter() - t:5.0f}  "
                      f"{r['statuses']}", flush=True)
                n, med, p95, mx, sd = summary(np.concatenate(all_e), np.concatenate(all_n))
                print(f"{'so far':>6} {'':>5} {'':>4} {n:3d} {med:7.2f} {p95:6.2f} {mx:6.2f} {sd:7.2f}", flush=True)
    n, med, p95, mx, sd = summary(np.concatenate(all_e), np.concatenate(all_n))
    if a.compare:
        w = np.concatenate(all_w)
        print(f"without the per-photo test: {len(w)} measurements, max {w.max() if len(w) else math.nan:.2f} px, "
              f"{int(np.sum(w > 3.0))} more than 3 px off")
    print(f"with it: {n} measurements, {int(np.sum(np.concatenate(all_e) > 3.0))} more than 3 px off")
    if a.compare:
        w = np.concatenate(all_a)
        print(f"with it, those alone on their photo rejected: {len(w)} measurements, "
              f"max {w.max() if len(w) else math.nan:.2f} px, {int(np.sum(w > 3.0))} more than 3 px off")
    t = time.perf_counter()
    o = occlusion_block(data, max_photos=a.occlusion_photos) if a.occlusion_photos > 0 else None
    if o is not None:
        print(f"occlusion: {o['views']} hidden views found (60 deg off nadir, GSD 0.10 at the vertex), {o['hidden']} "
              f"hidden vertex-photo pairs on {a.occlusion_photos} photos, measured {o['measured_hidden']} "
              f"({o['statuses']}; {time.perf_counter() - t:.0f} s)")
    print(f"pooled: {n} measurements, median {med:.2f} px, 95 % {p95:.2f} px, max {mx:.2f} px, normalised sd "
          f"{sd:.2f}; occluded vertex-photo pairs {occ}, of them accepted {occ_acc}")


if __name__ == "__main__":
    main()
