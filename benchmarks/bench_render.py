"""Rendering synthetic aerial photos: the new renderer (synthetic.aerial) beside the old one (synthetic.scene).

    python benchmarks/bench_render.py              # 3000 x 2000 px photos of the demo scene
    python benchmarks/bench_render.py --size 6000 4000   # 24 MP (the old renderer takes ~1 min)
    python benchmarks/bench_render.py --quick      # 1200 x 800 px

Both renderers draw the same scene -- the demo's terrain, its six buildings and two roads
(:func:`lidarcat.synthetic.scene.demo_scene`) -- through the same camera (36 mm frame, c = 35 mm,
distortion) from the same orientation, in the same process, alternately (``--repeat`` rounds; the
best time of each is kept, so a noisy machine hurts both alike).  Columns: seconds per photo,
seconds per megapixel, the speed-up of the new renderer, the keypoints OpenCV's SIFT finds on the
photo, and on a pair of overlapping photos (60 % forward overlap, kappa 3 deg apart) the ratio-test
matches that a fundamental matrix verifies (RANSAC, 1 px) and the share of those within 1 px of
their true position (the true ground point of the keypoint on the first photo, projected into the
second).  A last row renders
a photo of the aerial block of :func:`lidarcat.synthetic.aerial.aerial_survey` (a village, ~25
buildings) at the same size, and the truth map alone (geometry, no shading).  BLAS is pinned to one
thread.  Note ``uptime`` next to the figures.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from lidarcat.geometry.camera import Camera  # noqa: E402
from lidarcat.synthetic.aerial import (AerialScene, Exposure, aerial_scene, ground_points, render_photo,  # noqa: E402
                                      truth_map)
from lidarcat.synthetic.scene import demo_scene  # noqa: E402

E0, N0 = 680_400.0, 7_184_200.0


def _pair(img_a: np.ndarray, img_b: np.ndarray, truth_xyz, cam: Camera, eo_b: np.ndarray) -> tuple[int, int, float]:
    """SIFT on two overlapping photos: keypoints on A, ratio-test matches verified by a fundamental
    matrix (RANSAC, 1 px), and the share of those within 1 px of their true position on B."""
    import cv2

    from lidarcat.synthetic.aerial import project_to_pixels

    sift = cv2.SIFT_create()
    ka, da = sift.detectAndCompute(img_a, None)
    kb, db = sift.detectAndCompute(img_b, None)
    if da is None or db is None or len(ka) < 8 or len(kb) < 8:
        return len(ka), 0, float("nan")
    good = [m[0] for m in cv2.BFMatcher().knnMatch(da, db, k=2) if len(m) == 2 and m[0].distance < 0.8 * m[1].distance]
    if len(good) < 8:
        return len(ka), len(good), float("nan")
    pa = np.array([ka[g.queryIdx].pt for g in good])
    pb = np.array([kb[g.trainIdx].pt for g in good])
    _, inl = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.0, 0.999)
    inl = inl.ravel().astype(bool) if inl is not None else np.zeros(len(pa), bool)
    err = np.linalg.norm(project_to_pixels(cam, eo_b, truth_xyz(pa[inl])) - pb[inl], axis=1)
    return len(ka), int(inl.sum()), float(np.mean(err < 1.0))


def main() -> None:
    import cv2

    cv2.setNumThreads(1)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, nargs=2, default=(3000, 2000), metavar=("COLS", "ROWS"))
    ap.add_argument("--quick", action="store_true", help="1200 x 800 px")
    ap.add_argument("--repeat", type=int, default=2, help="alternate rounds; the best time of each is kept")
    ap.add_argument("--no-sift", action="store_true")
    args = ap.parse_args()
    cols, rows = (1200, 800) if args.quick else args.size
    pix = 36.0 / cols
    cam = Camera("bench", 35.0, 0.01, -0.02, -2.5e-5, 1e-8, 0.0, 2e-6, -1e-6, 0.0, pix, pix, cols, rows)
    gsd = 0.15
    height = gsd * 35.0 / pix
    eo = np.array([E0 - 20, N0 + 10, 905 + height, math.radians(1.0), math.radians(-0.8), math.radians(8.0)])
    old = demo_scene()
    new = AerialScene(buildings=old.buildings, roads=old.roads, texel_m=gsd, seed=0)
    eo_b = eo + np.array([0.4 * cam.frame_size_mm[0] * height / 35.0, 0, 0, 0, 0, math.radians(-3.0)])
    mp = cols * rows / 1e6
    best = {"old": math.inf, "new": math.inf}
    imgs = {}
    for _ in range(max(1, args.repeat)):
        t = time.perf_counter()
        imgs["old"] = old.render(cam, eo)
        best["old"] = min(best["old"], time.perf_counter() - t)
        t = time.perf_counter()
        imgs["new"] = render_photo(new, cam, eo, exposure=Exposure.random(1), truth=False).image
        best["new"] = min(best["new"], time.perf_counter() - t)
    width = cam.frame_size_mm[0] * height / 35.0
    village = aerial_scene((E0 - width, N0 - width, E0 + 2 * width, N0 + width), texel_m=gsd, seed=0)
    t = time.perf_counter()
    imgs["village"] = render_photo(village, cam, eo, exposure=Exposure.random(2), truth=False).image
    t_village = time.perf_counter() - t
    t = time.perf_counter()
    truth_map(village, cam, eo)
    t_truth = time.perf_counter() - t

    def old_truth(px: np.ndarray) -> np.ndarray:
        from lidarcat.mapping.monoplot import ray_directions

        d = ray_directions(cam, eo, px)
        return eo[:3] + old.hit(eo[:3], d)[:, 0:1] * d

    pairs = {}
    if not args.no_sift:
        pairs["old"] = _pair(imgs["old"], old.render(cam, eo_b), old_truth, cam, eo_b)
        pairs["new"] = _pair(imgs["new"], render_photo(new, cam, eo_b, exposure=Exposure.random(3), truth=False).image,
                             lambda px: ground_points(new, cam, eo, px), cam, eo_b)
        pairs["village"] = _pair(imgs["village"], render_photo(village, cam, eo_b, exposure=Exposure.random(4),
                                                               truth=False).image,
                                 lambda px: ground_points(village, cam, eo, px), cam, eo_b)

    print(f"# {cols} x {rows} px ({mp:.1f} MP), GSD {gsd} m, load {os.getloadavg()[0]:.2f} (1 min), "
          f"pair: 60 % forward overlap, kappa 3 deg apart")
    print("| renderer | scene | s/photo | s/MP | speed-up | SIFT keypoints | verified matches | within 1 px of truth |")
    print("|---|---|---:|---:|---:|---:|---:|---:|")
    rows_out = [("scene.Scene.render (old)", "demo", best["old"], "old"),
                ("aerial.render_photo (new)", "demo", best["new"], "new"),
                ("aerial.render_photo (new)", f"village ({len(village.buildings)} buildings)", t_village, "village")]
    for name, sc, dt, key in rows_out:
        kp, nm, share = pairs.get(key, (0, 0, float("nan")))
        print(f"| {name} | {sc} | {dt:.2f} | {dt / mp:.2f} | {best['old'] / dt:.1f}x | {kp} | {nm} | "
              f"{100 * share:.1f} % |")
    print(f"| aerial.truth_map (geometry only) | village | {t_truth:.2f} | {t_truth / mp:.2f} | | | | |")


if __name__ == "__main__":
    main()
