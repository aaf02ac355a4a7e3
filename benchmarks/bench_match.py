"""lidarcat match against pycolmap on the same rendered photos and threads; pairs of a large block.

Run:  python benchmarks/bench_match.py [--size 1200x900] [--threads 2] [--big 200] [--contrast 0.0175]

Part 1 renders a block of 2 strips x 3 photos (60 % / 30 % overlap, orientations 2 m / 0.5 deg off,
lidarcat.synthetic.textured) and matches it

* with lidarcat (``stages.match.match``: SIFT, footprint pairs, guided matching, MAGSAC++, tracks),
  once with the distribution control (the default) and once keeping every verified track;
* with pycolmap: its SIFT extraction (``extract_features``, one camera, 8,000 features) and
  exhaustive matching with its geometric verification (``match_exhaustive``); its verified
  inlier matches are read from the database and joined into tracks by the same union-find.

A fourth row gives pycolmap's own tracks and 3-D points: ``pycolmap.triangulate_points`` with the
true poses (keypoints made distortion-free in its database, a PINHOLE camera; its matches
unchanged; two-view tracks kept), scored the same way, its RMS the reprojection of its own points.

Each method runs in a child process (its peak RSS is the child's ``VmHWM``, imports included)
with the same number of threads; the CPU seconds (user + system of all the child's threads) are
printed beside the wall seconds: on a machine shared with other work they are the steadier ratio.  Every observation is scored against the truth: its distance from
the projection of its track's true point (``synthetic.textured.observation_errors``); "wrong" is an
observation more than 3 px off.  The reprojection RMS is that of each track triangulated with the
true orientations (least squares of its rays), the same computation for both methods.

Part 2 lays out blocks of 4 strips of 12 ... 100 photos and counts the pairs chosen by footprints
(they grow linearly), then renders a block of ``--big`` small photos (256 x 192 px) and matches it
with footprint pairs in a child process: pairs, tie points, seconds, peak memory.

Part 3 (``--schedulers synchronous,threads,processes``) runs ``stages.match.match`` on each
scheduler of :func:`lidarcat.lidar.jobs.map_tasks` with ``--threads`` workers, in a child process
per run: a block of 2 strips of ``--sched-block`` rendered photos (``--sched-size``), then blocks of
4 strips of ``--sched-big`` small photos (256 x 192 px).  Per run: wall and CPU seconds (the child
and, for ``processes``, its Dask worker processes: ``RUSAGE_CHILDREN`` after the cluster closed),
the peak RSS of the child (``VmHWM``: ``ru_maxrss`` would keep the benchmark's own peak across
``fork + exec``) and of its largest worker process (sampled every 0.1 s), and the SHA-256 of the tie-point table (the same for every scheduler).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import sqlite3  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cpu_s() -> float:
    """CPU seconds of this process, all its threads (user + system): steadier than wall time on a loaded machine."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _truth(folder: Path):
    import pickle

    from types import SimpleNamespace

    from lidarcat.survey.cameras import load_cameras

    with open(folder / "truth.pkl", "rb") as fh:
        d = pickle.load(fh)
    return SimpleNamespace(camera=next(iter(load_cameras(folder / "camera.toml").values())), **d)


def _triangulated_rms(ts, track: np.ndarray, photo: np.ndarray, xy: np.ndarray) -> float:
    """RMS (px) of the observations reprojected from their track triangulated with the true orientations."""
    r = _residuals(ts, track, photo, xy)
    return float(np.sqrt(np.mean(r[np.isfinite(r)] ** 2)))   # a track of near-parallel rays may not triangulate


def _residuals(ts, track, photo, xy) -> np.ndarray:
    """Reprojection residual (px) of each observation, its track triangulated with the given orientations."""
    from lidarcat.match.rays import project_to_pixel, ray_directions

    n_t = int(track.max()) + 1
    d = np.empty((len(track), 3))
    for p in np.unique(photo):
        sel = photo == p
        d[sel] = ray_directions(ts.camera, ts.true_eo[p], xy[sel])
    d /= np.linalg.norm(d, axis=1)[:, None]
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    a = np.zeros((n_t, 3, 3))
    b = np.zeros((n_t, 3))
    np.add.at(a, track, proj)
    np.add.at(b, track, np.einsum("nij,nj->ni", proj, ts.true_eo[photo, :3]))
    x = np.linalg.solve(a + 1e-9 * np.eye(3)[None], b[:, :, None])[:, :, 0]
    res = np.empty(len(track))
    for p in np.unique(photo):
        sel = photo == p
        px, _ = project_to_pixel(ts.camera, ts.true_eo[p], x[track[sel]])
        res[sel] = np.hypot(*(px - xy[sel]).T)
    return res


def _score(ts, track, photo, xy) -> dict:
    from lidarcat.synthetic.textured import observation_errors

    if ts.ground is not None:
        err = observation_errors(ts.ground, ts.camera, ts.true_eo, track, photo, xy)
    else:   # real photos: the published orientation is the reference
        err = _residuals(ts, track, photo, xy)
    n_photos = len(ts.ids)
    per_photo = np.array([len(np.unique(track[photo == p])) for p in range(n_photos)])
    return {"tie_points_per_photo": float(per_photo.mean()), "observations": int(len(track)),
            "tracks": int(len(np.unique(track))), "within_1px": float(np.mean(err < 1.0)),
            "wrong_3px": float(np.mean(err > 3.0)), "rms_px": _triangulated_rms(ts, track, photo, xy)}


# ---------------------------------------------------------------------- children
def child_lidarcat(folder: Path, threads: int, per_cell: int, dem: str | None = None,
                   contrast: float | None = None) -> dict:
    import dataclasses

    import cv2

    cv2.setNumThreads(threads)
    from lidarcat.stages.match import default_options, match
    from lidarcat.survey.folder import Survey

    s = Survey.load(folder)
    from lidarcat.match import FeatureOptions

    opts = dataclasses.replace(default_options(s), per_cell=per_cell)
    feats = FeatureOptions() if contrast is None else FeatureOptions(contrast_threshold=contrast)
    t0, c0 = time.perf_counter(), _cpu_s()
    res = match(s, folder / f"out-{per_cell}", options=opts, features=feats, workers=threads, cache=False, dem=dem,
                table=folder / f"tie-{per_cell}.csv")
    seconds, cpu = time.perf_counter() - t0, _cpu_s() - c0
    from lidarcat._util import read_csv_table

    t = read_csv_table(folder / f"tie-{per_cell}.csv", required=("photo", "point", "col_px", "row_px"))
    ids = {p.id: i for i, p in enumerate(s.photos)}
    photo = np.array([ids[p] for p in t.column("photo")])
    track = np.unique(np.array(t.column("point")), return_inverse=True)[1]
    xy = np.column_stack([t.floats("col_px"), t.floats("row_px")])
    return {"seconds": seconds, "cpu_s": cpu, "peak_mb": _hwm_mb(), "pairs": res.n_pairs, "steps": res.seconds,
            **_score(_truth(folder), track, photo, xy)}


def child_pycolmap(folder: Path, threads: int) -> dict:
    import pycolmap

    from lidarcat.match import build_tracks

    ts = _truth(folder)
    db = folder / "colmap.db"
    db.unlink(missing_ok=True)
    names = list(ts.names)
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = threads
    ext.sift.max_num_features = 8000
    t0, c0 = time.perf_counter(), _cpu_s()
    pycolmap.extract_features(db, ts.image_dir, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    t1 = time.perf_counter()
    mopt = pycolmap.FeatureMatchingOptions()
    mopt.num_threads = threads
    pycolmap.match_exhaustive(db, matching_options=mopt, device=pycolmap.Device.cpu)
    t2 = time.perf_counter()
    con = sqlite3.connect(db)
    img = {name: iid for iid, name in con.execute("SELECT image_id, name FROM images")}
    index = {img[n]: k for k, n in enumerate(names)}
    kps = {}
    for iid, rows, cols, data in con.execute("SELECT image_id, rows, cols, data FROM keypoints"):
        kps[index[iid]] = np.frombuffer(data, np.float32).reshape(rows, cols)[:, :2].astype(np.float64) - 0.5
    pairs, matches = [], []
    for pair_id, rows, data in con.execute("SELECT pair_id, rows, data FROM two_view_geometries"):
        if not rows or data is None:
            continue
        i2 = pair_id % 2147483647
        i1 = (pair_id - i2) // 2147483647
        m = np.frombuffer(data, np.uint32).reshape(rows, 2).astype(np.int64)
        pairs.append([index[i1], index[i2]])
        matches.append((m[:, 0], m[:, 1]))
    tr = build_tracks([len(kps[k]) for k in range(len(names))], np.array(pairs), matches)
    seconds, cpu = time.perf_counter() - t0, _cpu_s() - c0
    xy = np.array([kps[p][k] for p, k in zip(tr.photo, tr.keypoint)])
    out = {"seconds": seconds, "cpu_s": cpu, "peak_mb": _hwm_mb(), "pairs": len(pairs),
           "steps": {"features": t1 - t0, "matching": t2 - t1, "tracks": seconds - (t2 - t0)},
           **_score(ts, tr.track, tr.photo, xy)}
    con.close()
    if ts.ground is not None:
        out["triangulated"] = _pycolmap_triangulate(ts, db, names, index, kps, threads)
    return out


def _pycolmap_triangulate(ts, db: Path, names: list[str], index: dict, kps: dict, threads: int) -> dict:
    """pycolmap's own tracks and points: ``triangulate_points`` with the true poses.

    lidarcat's camera has a principal-point offset and distortion that COLMAP's models spell
    differently; so the keypoints in the database become distortion-free pixels of a PINHOLE
    camera (lidarcat's ``ideal_pixels`` + the frame centre; the matches are pycolmap's, unchanged),
    and the true orientation ``M = R3(kappa) R2(phi) R1(omega)`` (object -> photo, photo z
    backwards) becomes ``cam_from_world = diag(1, -1, -1) M``, ``t = -R X0``.  pycolmap builds,
    completes and merges its tracks and filters them (reprojection 4 px, angle 1.5 deg; two-view
    tracks kept).  Its observations are scored against the truth like lidarcat's; its RMS is the
    reprojection of its own 3-D points.
    """
    import pycolmap

    from lidarcat.geometry.collinearity import rotation_matrix
    from lidarcat.match.rays import project_to_pixel
    from lidarcat.match.verify import ideal_pixels

    cam = ts.camera
    w, h = cam.columns_px, cam.rows_px
    f_px = cam.focal_length_mm / cam.pixel_size_x_mm
    con = sqlite3.connect(db)
    for iid, rows, cols, data in list(con.execute("SELECT image_id, rows, cols, data FROM keypoints")):
        k = np.frombuffer(data, np.float32).reshape(rows, cols).copy()
        k[:, :2] = ideal_pixels(cam, kps[index[iid]]) + [0.5 * w, 0.5 * h]
        con.execute("UPDATE keypoints SET data = ? WHERE image_id = ?", (k.astype(np.float32).tobytes(), iid))
    params = np.array([f_px, f_px * cam.pixel_size_x_mm / cam.pixel_size_y_mm, 0.5 * w, 0.5 * h])
    con.execute("UPDATE cameras SET model = ?, params = ?", (int(pycolmap.CameraModelId.PINHOLE), params.tobytes()))
    con.commit()
    img = {name: iid for iid, name in con.execute("SELECT image_id, name FROM images")}
    con.close()
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=w, height=h, camera_id=1,
                                                    params=params))
    for k, name in enumerate(names):
        r = np.diag([1.0, -1.0, -1.0]) @ rotation_matrix(ts.true_eo[k, 3:6])
        pose = pycolmap.Rigid3d(np.column_stack([r, -r @ ts.true_eo[k, :3]]))
        rec.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=img[name],
                                                        keypoints=kps[k] * 0.0), pose)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    opts.triangulation.ignore_two_view_tracks = False
    t0 = time.perf_counter()
    out_dir = db.parent / "colmap_tri"
    out_dir.mkdir(exist_ok=True)
    rec = pycolmap.triangulate_points(rec, db, ts.image_dir, out_dir, options=opts)
    seconds = time.perf_counter() - t0
    inv = {iid: k for k, (name, iid) in enumerate((n, img[n]) for n in names)}
    track, photo, kp, xyz = [], [], [], []
    for t_id, (pid, p3d) in enumerate(rec.points3D.items()):
        for el in p3d.track.elements:
            track.append(t_id)
            photo.append(inv[el.image_id])
            kp.append(el.point2D_idx)
        xyz.append(p3d.xyz)
    track, photo, kp, xyz = np.array(track), np.array(photo), np.array(kp), np.array(xyz)
    xy = np.array([kps[p][k] for p, k in zip(photo, kp)])
    res = np.empty(len(track))
    for p in np.unique(photo):
        sel = photo == p
        px, _ = project_to_pixel(cam, ts.true_eo[p], xyz[track[sel]])
        res[sel] = np.hypot(*(px - xy[sel]).T)
    sc = _score(ts, track, photo, xy)
    sc["rms_px"] = float(np.sqrt(np.mean(res ** 2)))
    sc["seconds"] = seconds
    return sc


def child_big(folder: Path, threads: int) -> dict:
    from lidarcat.stages.match import match

    t0 = time.perf_counter()
    res = match(folder, folder / "out", workers=threads, cache=True)
    return {"seconds": time.perf_counter() - t0, "peak_mb": _hwm_mb(), "photos": res.n_photos, "pairs": res.n_pairs,
            "pairs_verified": res.n_pairs_verified, "tie_points": res.n_tie_points,
            "observations": res.n_observations, "steps": res.seconds}


def _hwm_mb() -> float:
    """Peak RSS of this process since its ``exec`` (``VmHWM``; ``ru_maxrss`` keeps the parent's peak
    across ``fork + exec``, so a child would report the RSS of the benchmark that rendered the photos)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return float(line.split()[1]) / 1024.0
    return _peak_mb()


class _TreeWatch:
    """Samples the RSS of this process's descendants (the Dask workers) every 0.1 s: the largest one."""

    def __init__(self) -> None:
        import threading

        import psutil

        self.me, self.peak_mb, self.stop = psutil.Process(), 0.0, threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        import psutil

        while not self.stop.wait(0.1):
            for c in self.me.children(recursive=True):
                try:
                    self.peak_mb = max(self.peak_mb, c.memory_info().rss / 2 ** 20)
                except psutil.Error:
                    pass

    def close(self) -> float:
        self.stop.set()
        self.thread.join()
        return self.peak_mb


def child_sched(folder: Path, scheduler: str, workers: int) -> dict:
    """One run of ``match`` on *scheduler* (part 3): seconds, CPU, peaks, the table's hash."""
    import hashlib

    import cv2

    cv2.setNumThreads(1)        # the workers are the parallelism (every scheduler alike)
    from lidarcat.stages.match import match

    tag = f"{scheduler}-{workers}"
    watch = _TreeWatch()
    t0, c0 = time.perf_counter(), _cpu_s()
    res = match(folder, folder / f"out-{tag}", workers=workers, scheduler=scheduler, cache=False,
                table=folder / f"tie-{tag}.csv")
    seconds = time.perf_counter() - t0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"seconds": seconds, "cpu_s": _cpu_s() - c0, "cpu_workers_s": kids.ru_utime + kids.ru_stime,
            "peak_mb": _hwm_mb(), "peak_worker_mb": watch.close(), "photos": res.n_photos,
            "pairs": res.n_pairs, "tie_points": res.n_tie_points, "observations": res.n_observations,
            "steps": res.seconds,
            "sha256": hashlib.sha256((folder / f"tie-{tag}.csv").read_bytes()).hexdigest()[:12]}


def _schedulers(tmp: Path, a: argparse.Namespace) -> None:
    """Part 3: every scheduler on a block of rendered photos and on growing blocks of small photos."""
    scheds = a.schedulers.split(",")
    cols, rows = (int(v) for v in a.sched_size.split("x"))
    blocks = [(f"{2 * a.sched_block} photos of {cols} x {rows} px (2 strips)",
               dict(n_strips=2, per_strip=a.sched_block, columns_px=cols, rows_px=rows, seed=7))]
    for n in (int(v) for v in a.sched_big.split(",") if v):
        blocks.append((f"{4 * max(2, n // 4)} photos of 256 x 192 px (4 strips)",
                       dict(n_strips=4, per_strip=max(2, n // 4), columns_px=256, rows_px=192, seed=5)))
    print(f"\n## Part 3: schedulers ({a.threads} workers each; cv2 one thread)\n")
    print("| block | scheduler | pairs | tie points | seconds (features + matching) | CPU s (child + workers) | "
          "peak MB child | peak MB largest worker | table SHA-256 | load |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, (label, kw) in enumerate(blocks):
        folder = tmp / f"sched-{k}"
        _render(folder, **kw)
        for sched in scheds:
            r = _child("sched", str(folder), sched, str(a.threads))
            st = r["steps"]
            worker = f"{r['peak_worker_mb']:.0f}" if sched == "processes" else "-"
            print(f"| {label} | {sched} | {r['pairs']} | {r['tie_points']} | {r['seconds']:.1f} "
                  f"({st['features']:.1f} + {st['matching']:.1f}) | {r['cpu_s']:.1f} + {r['cpu_workers_s']:.1f} | "
                  f"{r['peak_mb']:.0f} | {worker} | {r['sha256']} | {os.getloadavg()[0]:.1f} |", flush=True)


def _child(kind: str, *args: str) -> dict:
    out = subprocess.run([sys.executable, __file__, "--child", kind, *args], capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    if out.returncode:
        raise SystemExit(f"child {kind} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _render(folder: Path, **kw):
    import pickle

    from lidarcat.synthetic.textured import write_textured_survey

    ts = write_textured_survey(folder, **kw)
    with open(folder / "truth.pkl", "wb") as fh:   # the camera is rebuilt from its size (small_camera)
        pickle.dump({"ground": ts.ground, "true_eo": ts.true_eo, "ids": ts.ids, "image_dir": str(folder / "images"),
                     "names": [f"{p}.png" for p in ts.ids]}, fh)
    return ts


#: the NGI frames (evaluation only, never copied): ../shared/data/frames/ngi of the repository or of a parent folder
NGI = next((p / "shared" / "data" / "frames" / "ngi" for p in Path(__file__).resolve().parents[1:]
            if (p / "shared" / "data" / "frames" / "ngi").is_dir()), Path("../shared/data/frames/ngi"))


def _ngi_survey(folder: Path, src: Path) -> None:
    """A survey of the four NGI frames (read in place; published orientation with 1 m / 0.01 deg); dem.tif is the surface."""
    import pickle

    from lidarcat.geometry.camera import Camera

    folder.mkdir(parents=True)
    cam = Camera("dmc", 120.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 92.16 / 640, 165.888 / 1152, 640, 1152,
                 model="Intergraph DMC (NGI, downsampled)", source="ngi_int_param.yaml")
    (folder / "camera.toml").write_text(cam.to_toml())
    lines = (src / "ngi_xyz_opk.csv").read_text().split()
    rows = ["photo,camera,image,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0,sd_omega_deg,sd_phi_deg,"
            "sd_kappa_deg"]
    ids, eo = [], []
    for line in lines[1:]:
        f = line.split(",")
        ids.append(f[0])
        eo.append([float(v) for v in f[1:7]])
        rows.append(f"{f[0]},dmc,{src / (f[0] + '.tif')},{','.join(f[1:7])},1,1,1,0.01,0.01,0.01")
    (folder / "photos.csv").write_text("\n".join(rows) + "\n")
    (folder / "image_points.csv").write_text("photo,point,col_px,row_px\n")
    (folder / "survey.toml").write_text(
        '[survey]\nname = "ngi"\ndescription = "four NGI frames"\ncrs = "local: tmerc lon_0=25 WGS84"\n'
        'height_system = "orthometric"\n\n[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\n'
        'image_points = "image_points.csv"\n')
    eo = np.array(eo)
    eo[:, 3:] = np.deg2rad(eo[:, 3:])
    with open(folder / "truth.pkl", "wb") as fh:
        pickle.dump({"ground": None, "true_eo": eo, "ids": tuple(ids), "image_dir": str(src),
                     "names": [f"{p}.tif" for p in ids]}, fh)


def _compare(folder: Path, threads: int, ref: str, height: str = "-", contrast: float | None = None) -> None:
    extra = [height] + ([str(contrast)] if contrast is not None else [])
    rows_out = [("lidarcat (distribution 10/cell)", _child("lidarcat", str(folder), str(threads), "10", *extra)),
                ("lidarcat (every verified track)", _child("lidarcat", str(folder), str(threads), "0", *extra)),
                ("pycolmap (SIFT + exhaustive + verification)", _child("pycolmap", str(folder), str(threads)))]
    tri = rows_out[-1][1].get("triangulated")
    if tri:
        rows_out.append(("pycolmap, its tracks from `triangulate_points` with the true poses "
                         f"(+{tri['seconds']:.1f} s)", {**rows_out[-1][1], **tri, "seconds": rows_out[-1][1]["seconds"]}))
    print("| method | pairs | tie points / photo | observations | within 1 px | wrong (> 3 px) | "
          f"RMS ({ref}) px | seconds (features + matching) | CPU s | peak MB |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, r in rows_out:
        st = r["steps"]
        print(f"| {name} | {r['pairs']} | {r['tie_points_per_photo']:.0f} | {r['observations']} | "
              f"{100 * r['within_1px']:.2f} % | {100 * r['wrong_3px']:.2f} % | {r['rms_px']:.3f} | "
              f"{r['seconds']:.1f} ({st['features']:.1f} + {st['matching']:.1f}) | {r['cpu_s']:.1f} | "
              f"{r['peak_mb']:.0f} |", flush=True)
    lc, pc = rows_out[1][1], rows_out[2][1]
    print(f"\nlidarcat (every track) / pycolmap: time {lc['seconds'] / pc['seconds']:.2f}x, CPU "
          f"{lc['cpu_s'] / pc['cpu_s']:.2f}x; tie points per photo {lc['tie_points_per_photo'] / pc['tie_points_per_photo']:.2f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1200x900", help="photo size COLSxROWS of part 1")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--big", type=int, default=200, help="photos of the large block (0: skip)")
    ap.add_argument("--contrast", type=float, default=None, help="lidarcat's SIFT contrast threshold "
                    "(default: FeatureOptions' default)")
    ap.add_argument("--no-peer", action="store_true", help="skip part 1 (the comparison with pycolmap)")
    ap.add_argument("--schedulers", default="", help="part 3: comma-separated schedulers of lidar.jobs.map_tasks "
                    "(synchronous,threads,processes); empty: skip")
    ap.add_argument("--sched-block", type=int, default=12, help="part 3: photos per strip of the rendered block")
    ap.add_argument("--sched-size", default="640x480", help="part 3: photo size of the rendered block")
    ap.add_argument("--sched-big", default="48,100,200", help="part 3: photos of the blocks of small photos")
    ap.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        kind, folder, *rest = a.child
        fn = {"lidarcat": lambda: child_lidarcat(Path(folder), int(rest[0]), int(rest[1]),
                                                 rest[2] if len(rest) > 2 and rest[2] != "-" else None,
                                                 float(rest[3]) if len(rest) > 3 else None),
              "pycolmap": lambda: child_pycolmap(Path(folder), int(rest[0])),
              "big": lambda: child_big(Path(folder), int(rest[0])),
              "sched": lambda: child_sched(Path(folder), rest[0], int(rest[1]))}[kind]
        print(json.dumps(fn()))
        return
    cols, rows = (int(v) for v in a.size.split("x"))
    print(f"load: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}; threads {a.threads}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "block"
        t0 = time.perf_counter()
        if not a.no_peer:
            _render(folder, columns_px=cols, rows_px=rows, seed=3)
        if not a.no_peer:
            print(f"\n## Part 1: 6 rendered photos of {cols} x {rows} px (rendered in {time.perf_counter() - t0:.0f} s)\n")
            _compare(folder, a.threads, "true poses", "-", a.contrast)
            if NGI.is_dir():
                ngi = Path(tmp) / "ngi"
                _ngi_survey(ngi, NGI)
                print(f"\n## Part 1b: the four NGI frames ({NGI}, 640 x 1152 px), published orientation as reference\n")
                print("(\"within 1 px\" and \"wrong\": reprojection residual of the track triangulated with the "
                      "published orientation, not truth)\n")
                _compare(ngi, a.threads, "published EO", str(NGI / "dem.tif"), a.contrast)
        if a.schedulers:
            _schedulers(Path(tmp), a)
            if a.no_peer and not a.big:
                print(f"\nload after: {os.getloadavg()[0]:.2f}")
                return
        from lidarcat.match import HeightSurface, footprint, footprint_pairs
        from lidarcat.synthetic.textured import small_camera, strip_layout

        print("\n## Part 2: pairs chosen by footprints (4 strips, 60 % / 30 %, min overlap 10 %)\n")
        print("| photos | pairs | pairs / photo | all pairs |")
        print("|---|---|---|---|")
        cam = small_camera(256, 192)
        for per_strip in (12, 25, 50, 100):
            eo = strip_layout(4, per_strip, cam, 600.0)
            fps = [footprint(cam, e, HeightSurface(100.0)) for e in eo]
            n = len(eo)
            p = len(footprint_pairs(fps)[0])
            print(f"| {n} | {p} | {p / n:.2f} | {n * (n - 1) // 2} |")
        if a.big:
            per_strip = max(2, a.big // 4)
            big = Path(tmp) / "big"
            t0 = time.perf_counter()
            _render(big, n_strips=4, per_strip=per_strip, columns_px=256, rows_px=192, seed=5)
            r = _child("big", str(big), str(a.threads))
            print(f"\nA block of {r['photos']} photos of 256 x 192 px (rendered in {time.perf_counter() - t0 - r['seconds']:.0f} s): "
                  f"{r['pairs']} pairs by footprints, {r['pairs_verified']} verified, {r['tie_points']} tie points, "
                  f"{r['observations']} observations; {r['seconds']:.1f} s "
                  f"(features {r['steps']['features']:.1f} s, matching {r['steps']['matching']:.1f} s), "
                  f"peak memory {r['peak_mb']:.0f} MB")
    print(f"\nload after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
