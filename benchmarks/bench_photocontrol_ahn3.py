"""LiDAR roof vertices measured in photos rendered over the real AHN3 roofs, against truth (issue 29, step 5).

The AHN3 tiles of ``tests/data/lidar`` (CC0) and the 14 vertices of
``tests/data/extract/ahn3_vertices.csv``: each vertex is extracted again from the LiDAR within
30 m (:func:`lidarcat.control.vertices.extract_roof`, as ``lidarcat measure-control`` does),
its fitted planes become an exact roof patch of the scene (:mod:`lidarcat.synthetic.lidarphoto`;
the rest is the TIN of the first returns with the intensity as albedo), and synthetic flights
(2 strips x 3 photos, 800 x 600 px, c = 100 mm, over four clusters of vertices, GSD 5-15 cm, exposure and sun per photo, the
approximate orientation 2 m / 0.5 deg off) photograph it.  Each vertex is predicted
(:func:`lidarcat.photocontrol.predict_points`, occlusion on the DSM of the LiDAR as the stage
builds it), measured (:func:`lidarcat.photocontrol.measure_photo`), tested on its photo
(:func:`lidarcat.photocontrol.check_photo`), in the block (:func:`lidarcat.photocontrol.check_block`:
one adjustment with the tie points, the vertex observations snooped) and across the photos
(:func:`lidarcat.photocontrol.check_consistency`, a vertex accepted on one photo rejected); the
accepted measurements are scored against the vertex projected with the true orientation, and
against the occlusion truth (the ray from the camera to the vertex on the rendered surface).

The tie points are those ``lidarcat match`` finds (:func:`block_ties`: SIFT, ``match_block``
guided by the approximate orientations on a 2 m LiDAR DSM, least-squares refinement), scored
against the renderer's truth (:func:`score_ties`: each track's reference ray, true orientation,
meets the rendered surface; the hit projected into the track's other photos); ``--ties true``
uses true ties + 0.3 px noise instead (the fallback, labelled).

    PYTHONPATH=src python benchmarks/bench_photocontrol_ahn3.py [--flights F1 F2 F3 F4] [--gsd 0.05 0.10 0.15]
        [--seeds 0 1] [--compare] [--occlusion-photos 6] [--cache DIR] [--out FILE.jsonl]
    PYTHONPATH=src python benchmarks/bench_photocontrol_ahn3.py --pool FILE.jsonl ...   # the pooled table

``--compare`` also scores each block without the per-photo test and the block check (``(none)``
rows), with the per-photo test only (``(photo)``) and with the measurements alone on their photo
rejected (``(alone)``), from the same renders; a GSD given alone renders the same block (seed) as
in the full run.  Renders (and ties) are cached as npz under ``--cache`` (default
/tmp/ahn3b/cache), named by a hash of what they depend on, so reruns only measure.

Prints one row per block (flight, GSD, seed) and the pooled figures.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import math
import pickle
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
    key: str = ""


def load_ahn3(bounds: tuple[float, float, float, float] | None = None, *, cell_m: float = 0.1,
              only: list[str] | None = None, extraction: Any = None) -> Ahn3:
    """Read the tiles, extract the listed vertices inside *bounds* again (*extraction*: ExtractionParams, default
    the default's; the stability check off), build the rendered surface."""
    from lidarcat.control.params import get_params
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
        # the truth scene renders every listed vertex: no radius-stability refusal (lidarcat.control.stability)
        cp = extract_roof(clip, [e, n], point_id=pid, params=get_params(extraction, stability_scales=()))
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
    h = hashlib.sha1(np.ascontiguousarray(surf.height).tobytes())
    h.update(np.ascontiguousarray(surf.albedo).tobytes())
    h.update(repr([pid for pid, _, _ in found]).encode())
    # the exact roof patches are not in the rasters: their vertex and normals go into the key too (without
    # them a changed extraction reused renders of the old roof geometry, scored against the new vertex)
    for _, cp, _ in found:
        h.update(np.ascontiguousarray(cp.enh_m, dtype=np.float64).tobytes())
        h.update(np.ascontiguousarray([p.n for p in cp.planes], dtype=np.float64).tobytes())
    return Ahn3(xyz, found, surf, ground, h.hexdigest()[:12])


CACHE = Path("/tmp/ahn3b/cache")


def render_cached(data: Ahn3, camera: Any, eo: np.ndarray, *, exposure: Any, sun_azimuth_deg: float,
                  sun_elevation_deg: float, supersample: int, cache: Path | None, tag: str = "") -> np.ndarray:
    """The rendered photo (uint8), from *cache* when rendered before (npz named by *tag* and a hash of
    everything the render depends on: the scene, camera, orientation, exposure, sun, supersampling)."""
    from lidarcat.synthetic.lidarphoto import render_lidar_photo

    path = None
    if cache is not None and data.key:
        h = hashlib.sha1(repr((data.key, camera.columns_px, camera.rows_px, float(camera.focal_length_mm),
                               np.round(np.asarray(eo, float), 9).tolist(), repr(exposure),
                               round(float(sun_azimuth_deg), 9), round(float(sun_elevation_deg), 9),
                               int(supersample))).encode()).hexdigest()[:16]
        path = Path(cache) / f"{tag}{'_' if tag else ''}{h}.npz"
        if path.exists():
            with np.load(path) as z:
                return z["image"]
    img = render_lidar_photo(data.surface, camera, eo, exposure=exposure, sun_azimuth_deg=sun_azimuth_deg,
                             sun_elevation_deg=sun_elevation_deg, supersample=supersample).image
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".part.npz")
        np.savez_compressed(tmp, image=img)
        tmp.replace(path)
    return img


@dataclasses.dataclass(frozen=True)
class Ties:
    """Tie observations of a block by photo index and track (:class:`lidarcat.photocontrol.TieObservations`
    takes them by id)."""

    photo: np.ndarray       # (n,) index into the block's photos
    point: np.ndarray       # (n,) tie point index
    px: np.ndarray          # (n, 2) column, row
    sd_px: np.ndarray       # (n,)


def lidar_dsm_surface(data: Ahn3, cell_m: float = 2.0) -> Any:
    """The guided search's height surface as ``lidarcat match`` builds it from the tiles: the highest
    LiDAR point per 2 m cell (:data:`lidarcat.stages.match.SURFACE_CELL_M`), north-up, sd 1 m."""
    from lidarcat.match import HeightSurface

    xyz = data.xyz
    x0, y1 = math.floor(xyz[:, 0].min()), math.ceil(xyz[:, 1].max())
    col = ((xyz[:, 0] - x0) // cell_m).astype(np.int64)
    row = ((y1 - xyz[:, 1]) // cell_m).astype(np.int64)
    g = np.full((row.max() + 1, col.max() + 1), -np.inf)
    np.maximum.at(g, (row, col), xyz[:, 2])
    g[~np.isfinite(g)] = np.nan
    return HeightSurface(float(np.nanmean(g)), g, float(x0), float(y1), float(cell_m), sd_m=1.0)


def block_ties(data: Ahn3, camera: Any, approx: np.ndarray, images: list[np.ndarray], *,
               refine: bool = True, cache: Path | None = None) -> tuple[Ties, dict]:
    """Tie points of the rendered photos as ``lidarcat match`` (stages/match.py) finds them.

    SIFT features (:func:`lidarcat.match.features.detect`), :func:`lidarcat.match.match_block` guided
    by the approximate orientations on the LiDAR DSM, least-squares refinement and the observation
    sds (:func:`lidarcat.match.refine.refine_with_precision`, :func:`~lidarcat.match.refine.observation_sds`);
    the sd of an observation is the larger of its column/row sds.  Returns the ties and a report
    (tracks, observations, pairs verified, seconds).  Cached under *cache* by a hash of the images
    and orientations.
    """
    from lidarcat.match import FeatureOptions, MatchOptions, match_block
    from lidarcat.match.features import detect, grey8
    from lidarcat.match.refine import observation_sds, refine_with_precision

    path = None
    if cache is not None:
        h = hashlib.sha1(np.round(np.asarray(approx, float), 9).tobytes())
        for im in images:
            h.update(np.ascontiguousarray(im).tobytes())
        h.update(repr((camera.columns_px, camera.rows_px, float(camera.focal_length_mm), refine)).encode())
        path = Path(cache) / f"ties_{h.hexdigest()[:16]}.npz"
        if path.exists():
            with np.load(path) as z:
                return Ties(z["photo"], z["point"], z["px"], z["sd_px"]), json.loads(str(z["report"]))
    t = time.perf_counter()
    feats = [detect(im, FeatureOptions()) for im in images]
    res = match_block([camera] * len(images), list(approx), lambda i: feats[i], surface=lidar_dsm_surface(data),
                      options=MatchOptions())
    tr = res.tracks
    xy = res.xy_px
    ref_sd = None
    if refine and len(tr.track):
        ref = refine_with_precision(tr.track, tr.photo, xy, lambda i: grey8(images[i]), half_px=7)
        xy, ref_sd = ref.xy_px, ref.sd_px
    sd = observation_sds(tr.track, tr.photo, ref_sd).max(axis=1)
    ties = Ties(np.asarray(tr.photo, np.int64), np.asarray(tr.track, np.int64), np.asarray(xy, float), sd)
    rep = dict(tracks=int(len(np.unique(tr.track))), observations=int(len(tr.track)),
               pairs=sum(1 for r in res.pairs if r.n_inliers > 0), pairs_tried=len(res.pairs),
               seconds=time.perf_counter() - t)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".part.npz")
        np.savez_compressed(tmp, photo=ties.photo, point=ties.point, px=ties.px, sd_px=ties.sd_px,
                            report=json.dumps(rep))
        tmp.replace(path)
    return ties, rep


def true_ties(data: Ahn3, camera: Any, eo: np.ndarray, images: list[np.ndarray], *, noise_px: float = 0.3,
              per_photo: int = 200, seed: int = 0) -> Ties:
    """The fallback: tie points on a grid of each photo, the true ray's hit on the rendered surface
    projected into the other photos with the true orientations, plus *noise_px* normal noise."""
    from lidarcat.photocontrol.predict import pixel_positions
    from lidarcat.synthetic.lidarphoto import cast_rays, vertex_visible
    from lidarcat.geometry.collinearity import rotation_matrix

    rng = np.random.default_rng(seed)
    W, H = camera.columns_px, camera.rows_px
    photo, point, px = [], [], []
    n_pt = 0
    for k in range(len(eo)):
        cr = np.column_stack([rng.uniform(20, W - 20, per_photo), rng.uniform(20, H - 20, per_photo)])
        m = rotation_matrix(eo[k][3:6])
        d = np.column_stack([camera.pixel_to_photo(cr), np.full(len(cr), -camera.focal_length_mm)]) @ m
        X, _ = cast_rays(data.surface, eo[k][:3], d)
        for j in range(len(eo)):
            q = pixel_positions(camera, eo[j], X)
            ok = np.isfinite(q).all(axis=1) & (q[:, 0] > 5) & (q[:, 1] > 5) & (q[:, 0] < W - 5) & (q[:, 1] < H - 5)
            if j != k:
                ok &= vertex_visible(data.surface, eo[j], np.where(np.isfinite(X), X, 0.0))
            if j != k:
                q = q + rng.normal(0, noise_px, q.shape)
            photo.append(np.full(int(ok.sum()), j))
            point.append(n_pt + np.flatnonzero(ok))
            px.append(q[ok])
        n_pt += len(cr)
    photo, point, px = np.concatenate(photo), np.concatenate(point), np.vstack(px)
    keep = np.isin(point, np.flatnonzero(np.bincount(point, minlength=n_pt) >= 2))
    return Ties(photo[keep], point[keep], px[keep], np.full(int(keep.sum()), noise_px))


def score_ties(data: Ahn3, camera: Any, eo: np.ndarray, ties: Ties, *, gross_px: float = 3.0) -> dict:
    """The ties against the renderer's truth: each observation's true ray (true orientation) meets
    the rendered surface; the hit of a track's first observation (its reference) is projected into
    the track's other photos.  Returns the transfer errors (px) of the other observations and the
    tracks with one more than *gross_px* off."""
    from lidarcat.photocontrol.predict import pixel_positions
    from lidarcat.synthetic.lidarphoto import cast_rays
    from lidarcat.geometry.collinearity import rotation_matrix

    if not len(ties.point):
        return dict(errors=np.empty(0), tracks=0, gross_tracks=0, observations=0)
    order = np.lexsort((ties.photo, ties.point))
    pt, ph, xy = ties.point[order], ties.photo[order], ties.px[order]
    first = np.r_[True, pt[1:] != pt[:-1]]
    ref_of = np.maximum.accumulate(np.where(first, np.arange(len(pt)), 0))
    X = np.full((len(pt), 3), np.nan)
    for k in np.unique(ph[first]):
        sel = np.flatnonzero(first & (ph == k))
        m = rotation_matrix(eo[k][3:6])
        d = np.column_stack([camera.pixel_to_photo(xy[sel]), np.full(len(sel), -camera.focal_length_mm)]) @ m
        X[sel] = cast_rays(data.surface, eo[k][:3], d)[0]
    err = np.full(len(pt), np.nan)
    for k in np.unique(ph):
        sel = np.flatnonzero(~first & (ph == k))
        q = pixel_positions(camera, eo[k], X[ref_of[sel]])
        err[sel] = np.hypot(*(q - xy[sel]).T)
    e = err[~first]
    bad = np.zeros(len(pt), bool)
    bad[~first] = ~(e <= gross_px)
    gross = np.unique(pt[bad])
    return dict(errors=e[np.isfinite(e)], tracks=int(first.sum()), gross_tracks=int(len(gross)),
                observations=int(len(pt)), no_hit=int(np.sum(~np.isfinite(e))))


def score_block(data: Ahn3, centre: tuple[float, float], heading_deg: float, gsd: float, seed: int, *,
                size: tuple[int, int] = (800, 600), n_strips: int = 2, per_strip: int = 3,
                focal_mm: float = 100.0, supersample: int = 4, params: Any = None,
                min_photos: int = 2, keep_photos: bool = False, photo_test: bool = True,
                block_test: bool = True, compare: bool = False, alone: str = "keep",
                ties: str = "match", cache: Path | None = CACHE, tag: str = "") -> dict:
    """Render one flight, measure every vertex on every photo as ``measure-control`` does, score.

    Returns a dict: ``errors`` (px) and ``normalised`` (dx/sd, dy/sd) of the accepted
    measurements, ``statuses`` (counts), ``occluded_accepted`` (accepted where the truth says
    occluded), ``occluded_pairs`` (vertex-photo pairs in the frame but occluded), ``n_photos``.
    ``photo_test``: each photo's measurements tested against their common displacement
    (:func:`lidarcat.photocontrol.check_photo`) before the multi-photo test, as the stage does;
    ``block_test``: then the block check (:func:`check_block`: one adjustment of the block with the
    tie points, the vertex observations snooped); ``ties``: ``"match"`` (the matcher on the
    renders, scored against truth under ``tie_score``), ``"true"`` (true + 0.3 px, the fallback) or
    ``"none"``; ``compare``: also the figures without the per-photo test and the block check
    (``without_photo_test``), with the per-photo test only (``photo_test_only``) and with the
    measurements alone on their photo rejected (``alone_rejected``), from the same renders;
    ``alone``: check_photo's choice for those.  Renders are cached under *cache* (None: not).
    ``lists``: the per-photo measurements (``raw``, ``checked``), the photos rendered (``used``), the true
    orientation of every photo of the flight (``true_eo``, (n, 6) m, rad),
    the ties and what the block check is called with.
    """
    from lidarcat.photocontrol import VertexTarget, check_photo, measure_photo, predict_points
    from lidarcat.stages.measure_control import dsm_of_points
    from lidarcat.synthetic.aerial import Exposure, project_to_pixels
    from lidarcat.synthetic.aerial import aerial_camera
    from lidarcat.synthetic.lidarphoto import flight_poses, vertex_visible

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
    t_render = 0.0

    truth, vis_truth, photos = {}, {}, {}
    occluded_pairs = 0
    used, images, raw, checked, checked_alone = [], [], [], [], []
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
        t0 = time.perf_counter()
        img = render_cached(data, cam, eo[k], exposure=Exposure.random(100 * seed + k, noise_sd=1.0),
                            sun_azimuth_deg=sun_az + rng.normal(0, 1), sun_elevation_deg=sun_el + rng.normal(0, 1),
                            supersample=supersample, cache=cache, tag=f"{tag}{'_' if tag else ''}s{seed}_p{k}")
        t_render += time.perf_counter() - t0
        if keep_photos:
            photos[pid] = img
        targets = [VertexTarget(cp.enh_m, cp.planes, clip, pr) for (_, cp, clip), pr in zip(data.vertices, prs)]
        ms = measure_photo(img, cam, approx[k], targets, params) if params else \
            measure_photo(img, cam, approx[k], targets)
        # as the stage: each photo's measurements against their common displacement
        used.append(k)
        images.append(img)
        raw.append(list(ms))
        checked.append(check_photo(ms, cam, approx[k], eo_cov, V, covs, alone=alone))
        checked_alone.append(check_photo(ms, cam, approx[k], eo_cov, V, covs, alone="reject"))
        for i in range(len(ms)):
            truth[(i, k)] = tp[i]
            vis_truth[(i, k)] = bool(vis[i])

    t0 = time.perf_counter()
    tie_obs, tie_report, tie_score = None, {}, {}
    if ties != "none" and len(used) >= 2:
        if ties == "match":
            try:
                tie_obs, tie_report = block_ties(data, cam, approx[used], images, cache=cache)
            except Exception as exc:          # noqa: BLE001 -- reported, then the labelled fallback
                tie_report = dict(failed=f"{type(exc).__name__}: {exc}")
        if tie_obs is None:
            tie_obs = true_ties(data, cam, eo[used], images, seed=seed)
            tie_report = dict(tie_report, source="true + 0.3 px (fallback)")
        else:
            tie_report = dict(tie_report, source="match_block")
        tie_score = score_ties(data, cam, eo[used], tie_obs)
    t_ties = time.perf_counter() - t0
    t0 = time.perf_counter()
    blocked = checked
    block_info: dict = {}
    if block_test and tie_obs is not None:
        blocked, block_info = run_check_block(checked, cam, approx[used], eo_cov, V, covs, tie_obs,
                                              [f"p{k}" for k in used], ids)
    t_block = time.perf_counter() - t0

    def decide(per_photo: list) -> dict:
        pv: dict[int, list] = {}
        for k, ms in zip(used, per_photo):
            for i, m in enumerate(ms):
                pv.setdefault(i, []).append((k, m))
        return _decide(pv, cam, approx, eo_cov, V, covs, ids, truth, vis_truth, min_photos)

    main_set = blocked if (photo_test and block_test and tie_obs is not None) else checked if photo_test else raw
    out = decide(main_set)
    if compare:
        out["without_photo_test"] = decide(raw)
        out["photo_test_only"] = decide(checked)
        out["alone_rejected"] = decide(checked_alone)
    return dict(out, occluded_pairs=occluded_pairs, n_photos=len(eo), photos=photos, ties=tie_report,
                tie_score=tie_score, block=block_info,
                seconds=dict(render=t_render, ties=t_ties, block=t_block),
                lists=dict(raw=raw, checked=checked, used=used, ties=tie_obs, approx=approx[used], true_eo=eo,
                           camera=cam, eo_cov=eo_cov, vertices=V, vertex_covs=covs, ids=ids))


def run_check_block(per_photo: list, camera: Any, eos: np.ndarray, eo_cov: np.ndarray, V: np.ndarray,
                    covs: np.ndarray, ties: Ties, photo_ids: list, point_ids: list) -> tuple[list, dict]:
    """:func:`lidarcat.photocontrol.check_block` on the block (per photo lists of measurements, one per
    vertex; *photo_ids* of the photos, *point_ids* of the vertices), as the stage calls it after
    ``check_photo``: returns the measurements (per photo) and a report of the check."""
    from lidarcat.photocontrol import TieObservations, check_block

    flat = [m for ms in per_photo for m in ms]
    pids = np.array(photo_ids, dtype=object)
    t = TieObservations(pids[ties.photo], np.array([f"t{v}" for v in ties.point], dtype=object), ties.px, ties.sd_px)
    bc = check_block(flat, {p: camera for p in photo_ids}, dict(zip(photo_ids, eos)),
                     {p: eo_cov for p in photo_ids}, dict(zip(point_ids, V)), dict(zip(point_ids, covs)), t)
    out, j = [], 0
    for ms in per_photo:
        out.append(list(bc.measurements[j:j + len(ms)]))
        j += len(ms)
    return out, dict(source="check_block", status=bc.status, tested=bc.tested, rejected=len(bc.rejected),
                     untestable=len(bc.untestable), ties_used=bc.ties_used, ties_rejected=bc.ties_rejected,
                     message=bc.message)


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


def _row(label: str, g: str, seed: str, e: np.ndarray, nz: np.ndarray, extra: str = "") -> str:
    n, med, p95, mx, sd = summary(e, nz)
    return (f"{label:>8} {g:>5} {seed:>4} {n:3d} {med:7.2f} {p95:6.2f} {mx:6.2f} {sd:7.2f} "
            f"{int(np.sum(e > 3.0)):4d} {extra}")


def pool_table(files: list[str]) -> None:
    """The per-block rows and the pooled figures of the JSON-lines files of ``--out`` (markdown)."""
    recs = [json.loads(line) for f in files for line in Path(f).read_text().splitlines() if line.strip()]
    recs = list({(r["flight"], r["gsd"], r["seed"]): r for r in recs}.values())    # a block run twice: once
    recs.sort(key=lambda r: (r["flight"], r["gsd"], r["seed"]))
    print("| flight | GSD | seed | n | median px | 95 % px | max px | norm. sd | > 3 px | occl | occ. acc. "
          "| without block check: n / max / > 3 px | ties: tracks / > 3 px |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|")

    def fmt(v: float) -> str:
        return "-" if not np.isfinite(v) else f"{v:.2f}"

    pools: dict[str, list] = {}
    for r in recs:
        e, nz = np.array(r["main"]["errors"]), np.array(r["main"]["normalised"])
        n, med, p95, mx, sd = summary(e, nz)
        po = r.get("photo_test_only")
        other = "-"
        if po is not None:
            pe = np.array(po["errors"])
            other = f"{len(pe)} / {fmt(pe.max() if len(pe) else math.nan)} / {int(np.sum(pe > 3))}"
        print(f"| {r['flight']} | {r['gsd']:.2f} | {r['seed']} | {n} | {fmt(med)} | {fmt(p95)} | {fmt(mx)} | "
              f"{fmt(sd)} | {int(np.sum(e > 3))} | {r['occluded_pairs']} | {r['occluded_accepted']} | {other} | "
              f"{r['tie_tracks']} / {r['tie_gross']} |")
        for key in ("main", "without_photo_test", "photo_test_only", "alone_rejected"):
            if key in r:
                pools.setdefault(key, []).append((r[key]["errors"], r[key]["normalised"]))
    for key, lab in (("main", "pooled (block check)"), ("photo_test_only", "pooled, per-photo test only"),
                     ("without_photo_test", "pooled, neither"), ("alone_rejected", "pooled, alone rejected")):
        if key not in pools:
            continue
        e = np.concatenate([np.asarray(x, float) for x, _ in pools[key]])
        nz = np.concatenate([np.asarray(x, float) for _, x in pools[key]])
        n, med, p95, mx, sd = summary(e, nz)
        print(f"{lab}: n {n}, median {fmt(med)}, 95 % {fmt(p95)}, max {fmt(mx)}, normalised sd {fmt(sd)}, "
              f"> 3 px {int(np.sum(e > 3))}")
    st: dict[str, int] = {}
    for r in recs:
        for k, v in r["statuses"].items():
            st[k] = st.get(k, 0) + v
    te = np.concatenate([np.asarray(r["tie_errors"], float) for r in recs]) if recs else np.empty(0)
    print(f"statuses: {st}; hidden pairs {sum(r['occluded_pairs'] for r in recs)}, accepted "
          f"{sum(r['occluded_accepted'] for r in recs)}")
    if len(te):
        print(f"ties: {sum(r['tie_tracks'] for r in recs)} tracks, {sum(r['tie_gross'] for r in recs)} with an "
              f"observation > 3 px off; transfer error median {np.median(te):.2f} px, 95 % {np.percentile(te, 95):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", nargs="+", default=list(FLIGHTS), choices=list(FLIGHTS))
    ap.add_argument("--gsd", type=float, nargs="+", default=list(GSDS))
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1],
                    help="the block's seed is 100 seed + 10 flight + GSD index")
    ap.add_argument("--supersample", type=int, default=4, help="rays per pixel side at edges")
    ap.add_argument("--size", type=int, nargs=2, default=[800, 600], help="photo columns, rows")
    ap.add_argument("--per-strip", type=int, default=3, help="photos per strip (2 strips)")
    ap.add_argument("--occlusion-photos", type=int, default=6, help="oblique photos of hidden vertices (0: none)")
    ap.add_argument("--ties", choices=["match", "true", "none"], default="match",
                    help="tie points of the block check: the matcher on the renders, true + 0.3 px, none")
    ap.add_argument("--no-block-check", action="store_true", help="the per-photo test only (as before the block check)")
    ap.add_argument("--cache", default=str(CACHE), help="folder of the rendered photos (npz); '' : none")
    ap.add_argument("--fit-radius", type=float, default=None, metavar="M",
                    help="the extraction's local clip (m; 0: the search clip's whole faces; default: the default's)")
    ap.add_argument("--scene", default="", help="pickle of the loaded scene: read when there, else written")
    ap.add_argument("--out", default="", help="append each block's figures to this JSON-lines file")
    ap.add_argument("--pool", nargs="+", default=[], help="print the pooled table of these JSON-lines files, nothing run")
    ap.add_argument("--compare", action="store_true",
                    help="also print each block without the per-photo test and the block check, with the per-photo "
                         "test only, and with the measurements alone on their photo rejected (same renders)")
    a = ap.parse_args()
    if a.fit_radius is not None and a.fit_radius < 0:
        ap.error(f"--fit-radius must be >= 0 m (0: the search clip's whole faces), got {a.fit_radius:g}")
    if a.pool:
        pool_table(a.pool)
        return
    cache = Path(a.cache) if a.cache else None
    t = time.perf_counter()
    if a.scene and Path(a.scene).exists():
        data = pickle.loads(Path(a.scene).read_bytes())
    else:
        from lidarcat.control.params import get_params

        ext = None if a.fit_radius is None else get_params().replace(fit_radius_m=a.fit_radius or None)
        data = load_ahn3(extraction=ext)
        if a.scene:
            Path(a.scene).write_bytes(pickle.dumps(data))
    print(f"scene: {len(data.vertices)} vertices extracted, surface {data.surface.height.shape} cells "
          f"({time.perf_counter() - t:.0f} s)")
    head = f"{'flight':>8} {'gsd':>5} {'seed':>4} {'n':>3} {'median':>7} {'p95':>6} {'max':>6} {'norm sd':>7} {'>3px':>4}"
    print(head + " occl occ.acc     s  ties | statuses")
    pools: dict[str, list] = {"main": [], "without_photo_test": [], "photo_test_only": [], "alone_rejected": []}
    occ_acc, occ, tie_e, tie_tr, tie_gross = 0, 0, [], 0, 0
    statuses: dict[str, int] = {}
    for f in a.flights:
        centre, heading = FLIGHTS[f]
        for gi, g in enumerate(a.gsd):
            for s0 in a.seeds:
                # the GSD's index in the default list, so that one GSD alone renders the same block
                gk = GSDS.index(g) if g in GSDS else gi
                seed = 100 * s0 + 10 * list(FLIGHTS).index(f) + gk
                t = time.perf_counter()
                r = score_block(data, centre, heading, g, seed, supersample=a.supersample, compare=a.compare,
                                size=tuple(a.size), per_strip=a.per_strip, ties=a.ties,
                                block_test=not a.no_block_check, cache=cache, tag=f"{f}_g{g:.2f}")
                if a.compare:
                    for key, lab in (("without_photo_test", "(none)"), ("photo_test_only", "(photo)"),
                                     ("alone_rejected", "(alone)")):
                        w = r[key]
                        pools[key].append((w["errors"], w["normalised"]))
                        print(_row(lab, "", str(seed), w["errors"], w["normalised"],
                                   f"{'':>4} {w['occluded_accepted']:7d}"), flush=True)
                pools["main"].append((r["errors"], r["normalised"]))
                occ_acc += r["occluded_accepted"]
                occ += r["occluded_pairs"]
                for k2, v in r["statuses"].items():
                    statuses[k2] = statuses.get(k2, 0) + v
                ts = r["tie_score"]
                tinfo = ""
                if ts:
                    tie_e.append(ts["errors"])
                    tie_tr += ts["tracks"]
                    tie_gross += ts["gross_tracks"]
                    te = ts["errors"]
                    tinfo = (f"{r['ties'].get('source', '')}: {ts['tracks']} tracks {ts['observations']} obs, "
                             f"median {np.median(te) if len(te) else math.nan:.2f} px, "
                             f"{ts['gross_tracks']} tracks > 3 px; block {r['block']}")
                if r["ties"].get("failed"):
                    tinfo += f" [match failed: {r['ties']['failed']}]"
                sec = r["seconds"]
                print(_row(f, f"{g:.2f}", str(seed), r["errors"], r["normalised"],
                           f"{r['occluded_pairs']:4d} {r['occluded_accepted']:7d} {time.perf_counter() - t:5.0f}"
                           f" (render {sec['render']:.0f} ties {sec['ties']:.0f} block {sec['block']:.0f}) | "
                           f"{r['statuses']}"), flush=True)
                if tinfo:
                    print(f"{'':>8} ties {tinfo}", flush=True)
                if a.out:
                    rec = dict(flight=f, gsd=g, seed=seed, statuses=r["statuses"], occluded_pairs=r["occluded_pairs"],
                               occluded_accepted=r["occluded_accepted"], ties=r["ties"], block=r["block"],
                               tie_errors=ts.get("errors", np.empty(0)).tolist() if ts else [],
                               tie_tracks=ts.get("tracks", 0) if ts else 0,
                               tie_gross=ts.get("gross_tracks", 0) if ts else 0,
                               rows=[(pid, k, e, px.tolist(), tp.tolist(), sd.tolist())
                                     for pid, k, e, px, tp, sd in r["rows"]])
                    for key in ("main", "without_photo_test", "photo_test_only", "alone_rejected"):
                        w = r if key == "main" else r.get(key)
                        if w is not None:
                            rec[key] = dict(errors=w["errors"].tolist(), normalised=w["normalised"].tolist(),
                                            occluded_accepted=w["occluded_accepted"])
                    with open(a.out, "a") as fh:
                        fh.write(json.dumps(rec, default=str) + "\n")
                e = np.concatenate([x for x, _ in pools["main"]])
                nz = np.concatenate([x for _, x in pools["main"]])
                print(_row("so far", "", "", e, nz), flush=True)
    print(head)
    for key, lab in (("without_photo_test", "none"), ("photo_test_only", "photo"), ("alone_rejected", "alone"),
                     ("main", "pooled")):
        if pools[key]:
            e = np.concatenate([x for x, _ in pools[key]])
            nz = np.concatenate([x for _, x in pools[key]])
            print(_row(lab, "", "", e, nz))
    te = np.concatenate(tie_e) if tie_e else np.empty(0)
    if len(te):
        print(f"ties: {tie_tr} tracks, transfer error median {np.median(te):.2f} px, 95 % {np.percentile(te, 95):.2f} "
              f"px; {tie_gross} tracks with an observation > 3 px off")
    print(f"statuses (all blocks): {statuses}")
    print(f"occluded vertex-photo pairs {occ}, of them accepted {occ_acc}")
    t = time.perf_counter()
    o = occlusion_block(data, max_photos=a.occlusion_photos) if a.occlusion_photos > 0 else None
    if o is not None:
        print(f"occlusion: {o['views']} hidden views found (60 deg off nadir, GSD 0.10 at the vertex), {o['hidden']} "
              f"hidden vertex-photo pairs on {a.occlusion_photos} photos, measured {o['measured_hidden']} "
              f"({o['statuses']}; {time.perf_counter() - t:.0f} s)")


if __name__ == "__main__":
    main()
