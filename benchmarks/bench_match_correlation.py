"""Where the correlation of matched observations' errors comes from (issue 28, "sds honest").

Run:  python benchmarks/bench_match_correlation.py grid [--seed 0] [--half 4 7 10] [--box 3]
      python benchmarks/bench_match_correlation.py block DIR/seed10 [DIR/seed11 ...]

``grid``: a rendered strip of three 1000 x 750 photos (:func:`lidarcat.synthetic.aerial.aerial_survey`,
kept in a temporary folder); points every 4 px on the first photo, their true positions on the second
(:meth:`AerialSurvey.transfer`), started ``U(-0.6, 0.6)`` px off and refined against the first
photo by :func:`lidarcat.match.refine.refine_with_precision` (the matcher's refinement, template
``2 half + 1`` px).  Printed per template size: rms truth error and rms written sd of the refined
points, and the correlation of the truth errors of two points ``d`` px apart on the grid
(x with x, y with y).  ``--box N`` also renders the two photos integrated over ``N x N`` rays per pixel
(a camera of N times the pixels, averaged back): if the renderer's one ray per pixel (a point-sampled
texture) made the correlation, the box-integrated photos would not show it.

``block``: folders kept by ``bench_photos_to_block.py --keep`` (a matched 24-photo block): the truth error
vector of every refined observation (its position minus the projection of the true ground point of
its track's reference, the observation on the photo listed first), and

* the pairs of observations at < 0.05 px on one photo (twin tracks through one image point);
* the inflation of the variance of a photo-wide mean by the errors' correlation,
  ``F(r) = 1 + sum_{i != j, |x_i - x_j| < r} e_i e_j / sum_i e_i^2`` over the observations of each
  photo (x and y): the factor by which sds that treat the observations as independent understate
  the variance of what the photo's observations determine together (its orientation);
* the correlation of the errors of two partners of one reference (they were matched to one template).
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import csv  # noqa: E402
import dataclasses  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

__all__ = ["grid_correlation", "block_errors", "variance_inflation"]

_STEP = 4
_DISTANCES = (1, 2, 3, 4, 6, 8)         # grid steps


def _box_image(s, k: int, n: int) -> np.ndarray:
    from lidarcat.synthetic._photo import render_photo

    cam = s.camera
    big = dataclasses.replace(cam, pixel_size_x_mm=cam.pixel_size_x_mm / n, pixel_size_y_mm=cam.pixel_size_y_mm / n,
                              columns_px=cam.columns_px * n, rows_px=cam.rows_px * n)
    ex = dataclasses.replace(s.exposures[k], noise_sd=0.0)
    img = render_photo(s.scene, big, s.true_eo[k], exposure=ex, truth=False).image.astype(np.float64)
    return img.reshape(cam.rows_px, n, cam.columns_px, n).mean(axis=(1, 3)).astype(np.float32)


def grid_correlation(s, half_px: int, box: int = 1) -> dict:
    """Refinement errors of a 4-px grid of photo 0 on photo 1 (module docstring)."""
    from lidarcat.match.features import grey8, read_image
    from lidarcat.match.refine import refine_with_precision

    cache: dict[int, np.ndarray] = {}

    def image(k: int) -> np.ndarray:
        if k not in cache:
            cache[k] = (grey8(read_image(s.image_paths()[s.photo_ids[k]], RuntimeError)) if box == 1
                        else _box_image(s, k, box))
        return cache[k]

    a, b = s.photo_ids[0], s.photo_ids[1]
    cols, rows = s.camera.columns_px, s.camera.rows_px
    g = np.stack(np.meshgrid(np.arange(20, cols - 20, _STEP, dtype=float),
                             np.arange(20, rows - 20, _STEP, dtype=float)), -1).reshape(-1, 2)
    tb = s.transfer(a, g, b)
    ok = np.isfinite(tb).all(1) & (tb[:, 0] > 20) & (tb[:, 0] < cols - 20) & (tb[:, 1] > 20) & (tb[:, 1] < rows - 20)
    g, tb = g[ok], tb[ok]
    start = tb + np.random.default_rng(1).uniform(-0.6, 0.6, tb.shape)
    n = len(g)
    xy = np.empty((2 * n, 2))
    xy[0::2], xy[1::2] = g, start
    r = refine_with_precision(np.repeat(np.arange(n), 2), np.tile([0, 1], n), xy, image, half_px=half_px)
    mv = r.moved[1::2]
    e = r.xy_px[1::2] - tb
    sd = r.sd_px[1::2]
    gi = np.round((g - 20) / _STEP).astype(np.int64)
    index = np.full((gi[:, 0].max() + 1 + max(_DISTANCES), gi[:, 1].max() + 1), -1)
    index[gi[:, 0], gi[:, 1]] = np.arange(n)
    corr = {}
    for d in _DISTANCES:
        j = index[gi[:, 0] + d, gi[:, 1]]
        use = (j >= 0) & mv & mv[np.maximum(j, 0)]
        i, j = np.flatnonzero(use), j[use]
        corr[d * _STEP] = tuple(float(np.corrcoef(e[i, c], e[j, c])[0, 1]) for c in (0, 1))
    return {"half": half_px, "box": box, "points": n, "refined": float(mv.mean()),
            "rms_err": np.sqrt(np.mean(e[mv] ** 2, axis=0)), "rms_sd": np.sqrt(np.nanmean(sd[mv] ** 2, axis=0)),
            "corr": corr}


def block_errors(folder: Path) -> dict:
    """Truth error vectors of the matched observations of a kept bench folder (module docstring)."""
    from lidarcat.synthetic.aerial import load_aerial_survey

    s = load_aerial_survey(folder / "survey")
    with open(folder / "survey" / "image_points.csv", newline="", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["point"].startswith("tp")]
    photo = np.array([r["photo"] for r in rows])
    xy = np.array([[float(r["col_px"]), float(r["row_px"])] for r in rows])
    rank = np.array([s.photo_ids.index(p) for p in photo])
    _, track = np.unique(np.array([r["point"] for r in rows]), return_inverse=True)
    order = np.lexsort((rank, track))
    first = order[np.r_[True, track[order][1:] != track[order][:-1]]]
    ref_of = np.full(track.max() + 1, -1)
    ref_of[track[first]] = first
    ref = ref_of[track]
    ground = np.full((len(xy), 3), np.nan)
    for p in np.unique(photo[first]):
        k = first[photo[first] == p]
        ground[k] = s.ground_point(str(p), xy[k])
    e = np.full((len(xy), 2), np.nan)
    for p in np.unique(photo):
        k = np.flatnonzero(photo == p)
        e[k] = xy[k] - s.project(str(p), ground[ref[k]])
    good = (ref != np.arange(len(xy))) & np.isfinite(e).all(1) & (np.hypot(*e.T) < 1.0)
    return {"e": e, "xy": xy, "photo": rank, "track": track, "good": good}


def variance_inflation(b: dict, radii=(0.05, 12.0, 24.0, 40.0)) -> dict:
    """``F(r)`` (x, y) per radius, the count of twin pairs (< 0.05 px) and the partner correlation."""
    from scipy.spatial import cKDTree

    e, xy, photo, good, track = b["e"], b["xy"], b["photo"], b["good"], b["track"]
    mean = e[good].mean(axis=0)
    out: dict = {"observations": int(good.sum())}
    for r in radii:
        num, den, pairs = np.zeros(2), np.zeros(2), 0
        for p in np.unique(photo):
            k = np.flatnonzero((photo == p) & good)
            ek = e[k] - mean
            den += (ek ** 2).sum(axis=0)
            pr = cKDTree(xy[k]).query_pairs(r, output_type="ndarray")
            pairs += len(pr)
            if len(pr):
                num += 2.0 * (ek[pr[:, 0]] * ek[pr[:, 1]]).sum(axis=0)
        out[r] = (1.0 + num / den, pairs)
    g = np.flatnonzero(good)
    o = g[np.argsort(track[g], kind="stable")]
    same = track[o][1:] == track[o][:-1]
    i, j = o[:-1][same], o[1:][same]
    out["partners"] = (len(i), tuple(float(np.corrcoef(e[i, c], e[j, c])[0, 1]) for c in (0, 1)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    g = sub.add_parser("grid")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--half", type=int, nargs="+", default=[4, 7, 10])
    g.add_argument("--box", type=int, default=3)
    b = sub.add_parser("block")
    b.add_argument("dirs", type=Path, nargs="+")
    a = ap.parse_args()
    print(f"uptime: {os.popen('uptime').read().strip()}")
    if a.what == "grid":
        from lidarcat.synthetic.aerial import aerial_survey

        with tempfile.TemporaryDirectory() as tmp:
            s = aerial_survey(Path(tmp) / "s", n_strips=1, photos_per_strip=3, image_size_px=(1000, 750), seed=a.seed)
            runs = [(h, 1) for h in a.half] + ([(7, a.box)] if a.box > 1 else [])
            print("| template px | rays per pixel | points | refined | rms error x / y px | rms sd x / y px | "
                  + " | ".join(f"corr at {d * _STEP} px x / y" for d in _DISTANCES) + " |")
            print("|" + "---|" * (6 + len(_DISTANCES)))
            for h, box in runs:
                r = grid_correlation(s, h, box)
                print(f"| {2 * h + 1} | {box * box} | {r['points']} | {100 * r['refined']:.1f} % | "
                      f"{r['rms_err'][0]:.3f} / {r['rms_err'][1]:.3f} | {r['rms_sd'][0]:.3f} / {r['rms_sd'][1]:.3f} | "
                      + " | ".join(f"{cx:.2f} / {cy:.2f}" for cx, cy in r["corr"].values()) + " |", flush=True)
    else:
        print("| folder | observations | twin pairs (< 0.05 px) | F(0.05 px) x / y | F(12 px) | F(24 px) | F(40 px) "
              "| partners of one reference: pairs, corr x / y |")
        print("|---|---|---|---|---|---|---|---|")
        for d in a.dirs:
            v = variance_inflation(block_errors(d))
            f = {r: v[r][0] for r in (0.05, 12.0, 24.0, 40.0)}
            print(f"| {d} | {v['observations']} | {v[0.05][1]} | "
                  + " | ".join(f"{f[r][0]:.2f} / {f[r][1]:.2f}" for r in f)
                  + f" | {v['partners'][0]}, {v['partners'][1][0]:.2f} / {v['partners'][1][1]:.2f} |", flush=True)
    print(f"uptime: {os.popen('uptime').read().strip()}")


if __name__ == "__main__":
    main()
