"""Regenerate t265_points/ from t265_kapture/ (kapture's real T265 fisheye cameras and poses).

Real: the two OPENCV_FISHEYE cameras and the six image poses (three exposures of the stereo rig) of
naver/kapture samples/t265/colmap (BSD-3-Clause).  Added here: 80 object points (seed 265) 1.5-6 m
in front of the left camera of the first exposure, up to 80 deg from its axis, their pixels projected
by pycolmap's own OPENCV_FISHEYE (``Camera.img_from_cam``; kept when inside the image), and the rig
(camera 1 the reference, camera 2's sensor_from_rig from the first exposure's poses) as COLMAP 3.12
rigs.txt / frames.txt.  Run from the repository root:

    PYTHONPATH=src python tests/data/interop/colmap/make_t265_points.py
"""

from pathlib import Path

import numpy as np
import pycolmap

from lidarcat.interop.colmap import read_colmap
from lidarcat.interop.rotations import matrix_to_quaternion_wxyz, opk_to_world_to_cv

HERE = Path(__file__).parent
src = read_colmap(HERE / "t265_kapture")
cams = {}
for line in (HERE / "t265_kapture" / "cameras.txt").read_text().splitlines():
    if line and not line.startswith("#"):
        f = line.split()
        cams[f[0]] = pycolmap.Camera(model=f[1], width=int(f[2]), height=int(f[3]), params=[float(v) for v in f[4:]])
ids = {p: i for i, p in enumerate(src.photo_ids.tolist(), start=1)}
r_all = opk_to_world_to_cv(src.eo[:, 3:])
pose = {p: (r_all[i], -r_all[i] @ src.eo[i, :3]) for i, p in enumerate(src.photo_ids.tolist())}
rng = np.random.default_rng(265)
n = 80
theta = np.radians(80.0) * np.sqrt(rng.uniform(0, 1, n))
phi = rng.uniform(0, 2 * np.pi, n)
depth = rng.uniform(1.5, 6.0, n)
d = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]) * depth[:, None]
r0, t0 = pose["leftraw/frame_000000001.jpg"]
world = (d - t0) @ r0                      # X = R^T (x_cam - t)
obs = {p: [] for p in src.photo_ids.tolist()}
tracks = {k: [] for k in range(n)}
for p, cid in zip(src.photo_ids.tolist(), src.photo_camera.tolist()):
    r, t = pose[p]
    xc = world @ r.T + t
    cam = cams[cid]
    for k in range(n):
        if xc[k, 2] <= 0:
            continue
        uv = np.asarray(cam.img_from_cam(xc[k]), dtype=float)
        if 0 <= uv[0] <= cam.width and 0 <= uv[1] <= cam.height:
            tracks[k].append((ids[p], len(obs[p])))
            obs[p].append((float(uv[0]), float(uv[1]), k + 1))
out = HERE / "t265_points"
out.mkdir(exist_ok=True)
(out / "cameras.txt").write_text((HERE / "t265_kapture" / "cameras.txt").read_text() + "\n")
lines = ["# Image list with two lines of data per image:", "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
         "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
for p, cid in zip(src.photo_ids.tolist(), src.photo_camera.tolist()):
    r, t = pose[p]
    lines.append(" ".join([str(ids[p]), *(repr(float(v)) for v in matrix_to_quaternion_wxyz(r)),
                           *(repr(float(v)) for v in t), cid, p]))
    lines.append(" ".join(f"{u!r} {v!r} {k}" for u, v, k in obs[p]))
(out / "images.txt").write_text("\n".join(lines) + "\n")
pts = ["# 3D point list with one line of data per point:",
       "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
for k in range(n):
    if len(tracks[k]) >= 2:
        pts.append(" ".join([str(k + 1), *(repr(float(v)) for v in world[k]), "128 128 128 0",
                             *(f"{a} {b}" for a, b in tracks[k])]))
(out / "points3D.txt").write_text("\n".join(pts) + "\n")
# the rig: camera 1 (left) the reference; camera 2's sensor_from_rig = right * left^-1 of exposure 1
rl, tl = pose["leftraw/frame_000000001.jpg"]
rr, tr = pose["rightraw/frame_000000001.jpg"]
rs = rr @ rl.T
ts = tr - rs @ tl
(out / "rigs.txt").write_text(
    "# Rig calib list with one line of data per calib:\n"
    "#   RIG_ID, NUM_SENSORS, REF_SENSOR_TYPE, REF_SENSOR_ID, SENSORS[] as (SENSOR_TYPE, SENSOR_ID, HAS_POSE, "
    "[QW, QX, QY, QZ, TX, TY, TZ])\n"
    "1 2 CAMERA 1 CAMERA 2 1 " + " ".join(repr(float(v)) for v in (*matrix_to_quaternion_wxyz(rs), *ts)) + "\n")
fr = ["# Frame list with one line of data per frame:",
      "#   FRAME_ID, RIG_ID, RIG_FROM_WORLD[QW, QX, QY, QZ, TX, TY, TZ], NUM_DATA_IDS, DATA_IDS[] as "
      "(SENSOR_TYPE, SENSOR_ID, DATA_ID)"]
for k in (1, 2, 3):
    left, right = f"leftraw/frame_00000000{k}.jpg", f"rightraw/frame_00000000{k}.jpg"
    r, t = pose[left]
    fr.append(" ".join([str(k), "1", *(repr(float(v)) for v in (*matrix_to_quaternion_wxyz(r), *t)), "2",
                        "CAMERA", "1", str(ids[left]), "CAMERA", "2", str(ids[right])]))
(out / "frames.txt").write_text("\n".join(fr) + "\n")
print({p: len(o) for p, o in obs.items()}, sum(len(tr) >= 2 for tr in tracks.values()))
