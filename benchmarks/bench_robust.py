"""An adjustment that survives real matches (issue 28, part 3): one command, one table.

Run:  python benchmarks/bench_robust.py [--only ngi,berlin,synthetic]

Rows:

* **NGI frames** (``../shared/data/frames/ngi``, evaluation only: read when present, skipped when
  absent, never copied): 4 real DMC frames, 723 OpenCV-SIFT tie points (1,493 observations, 17
  gross), the published EO as weighted observations (sd 1 m / 0.01 deg, photos.csv), no control
  set.  A survey is built in a temporary folder (pixel observations through a pinhole camera of
  0.144-mm pixels, f 120 mm, the default image sd of 3/4 pixel) and adjusted as ``lidarcat adjust
  S --eo-constraints --snooping remove`` does, with ``--start plain`` (least squares from the
  start, the behaviour before) and ``--start robust``: converged?, iterations of the final
  adjustment, the gross observations named (points), the largest deviation from the published EO
  (m, deg), the median image residual (px), seconds.
* **OpenSfM Berlin** (``tests/data/interop/opensfm``: 3 photos, 1,430 points, 3,082 observations,
  imported with control sd 0.05 m): the default ``lidarcat adjust`` (snooping report), CPU and wall
  seconds, adjustments, blunders.  Only :func:`lidarcat.stages.adjust.adjust` is called, so the same
  command measures an older checkout: ``git worktree add /tmp/before 0100a24`` and
  ``PYTHONPATH=/tmp/before/src python benchmarks/bench_robust.py --only berlin``.
* **Synthetic matches** (:func:`lidarcat.synthetic.matches.matched_block`: 8 mismatched two-ray
  points 3.5-700 px and a 242-px wrong ray, GNSS/INS 1 m / 0.01 deg as the only datum): plain and
  robust start, planted gross observations named exactly?, largest |EO - truth| / sd.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

NGI = Path(__file__).resolve().parents[2] / "shared" / "data" / "frames" / "ngi"
if not NGI.is_dir():
    NGI = Path("/work/shared/data/frames/ngi")
BERLIN = Path(__file__).resolve().parents[1] / "tests" / "data" / "interop" / "opensfm"


def build_ngi_survey(folder: Path) -> Path:
    """The NGI frames as a survey folder (no image is read: the tie points and the EO)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "survey.toml").write_text(
        '[survey]\nname = "ngi"\ncrs = "local: NGI tmerc lon_0=25 WGS84 (../shared/data/frames/ngi)"\n'
        '[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\nimage_points = "image_points.csv"\n'
        '[adjustment]\nobservations = "pixel"\n', encoding="utf-8")
    (folder / "camera.toml").write_text(
        "[dmc]\nfocal_length_mm = 120.0\nprincipal_point_x_mm = 0.0\nprincipal_point_y_mm = 0.0\nk1 = 0.0\n"
        "k2 = 0.0\nk3 = 0.0\np1 = 0.0\np2 = 0.0\nrefraction_eps45 = 0.0\npixel_size_x_mm = 0.144\n"
        "pixel_size_y_mm = 0.144\ncolumns_px = 640\nrows_px = 1152\n", encoding="utf-8")
    rows = [line.split() for line in (NGI / "camera_pos_ori.txt").read_text().splitlines() if line.strip()]
    lines = ["photo,camera,X0,Y0,Z0,omega_deg,phi_deg,kappa_deg,sd_X0,sd_Y0,sd_Z0,sd_omega_deg,sd_phi_deg,"
             "sd_kappa_deg"]
    lines += [",".join([r[0], "dmc", *r[1:7], "1", "1", "1", "0.01", "0.01", "0.01"]) for r in rows]
    (folder / "photos.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (folder / "image_points.csv").write_text((NGI / "sift_tiepoints_with_8_gross.csv").read_text(),
                                             encoding="utf-8")
    return folder


def _published() -> dict[str, np.ndarray]:
    return {r[0]: np.array(r[1:7], dtype=float) for r in
            (line.split() for line in (NGI / "camera_pos_ori.txt").read_text().splitlines() if line.strip())}


def ngi_rows() -> list[list[str]]:
    if not (NGI / "sift_tiepoints_with_8_gross.csv").is_file():
        return [["NGI frames", "skipped: ../shared/data/frames/ngi absent", "", "", "", "", ""]]
    from lidarcat.stages.adjust import adjust
    from lidarcat.survey import Survey

    pub = _published()
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        survey = Survey.load(build_ngi_survey(Path(tmp) / "ngi"))
        for start in ("plain", "robust"):
            t0 = time.perf_counter()
            sres = adjust(survey, Path(tmp) / f"out-{start}", eo_constraints=True, snooping="remove", start=start)
            dt = time.perf_counter() - t0
            r = sres.result
            dev_m = max(np.abs(np.asarray(r.eo_params)[i, :3] - pub[str(ph)][:3]).max()
                        for i, ph in enumerate(r.photo_ids))
            dev_deg = max(np.abs(np.degrees(np.asarray(r.eo_params)[i, 3:]) - pub[str(ph)][3:]).max()
                          for i, ph in enumerate(r.photo_ids))
            med = float(np.median(np.hypot(*(np.asarray(r.residuals_mm) / 0.144).T)))
            named = sorted({b.point for b in sres.blunders if b.removed}, key=lambda q: int(q[1:]))
            n_obs = sum(b.removed for b in sres.blunders)
            out.append([f"NGI, --start {start}", f"{r.status}, {r.n_iter} it.",
                        f"{n_obs} obs.: {', '.join(named)}" if named else "none",
                        f"{dev_m:.3f} m / {dev_deg:.4f} deg" if r.success else "-",
                        f"{med:.3f} px" if r.success else "-", f"{dt:.1f} s", f"{sres.n_adjustments} adj."])
    return out


def berlin_rows() -> list[list[str]]:
    from lidarcat.interop.block import write_survey
    from lidarcat.interop.opensfm import read_opensfm
    from lidarcat.stages.adjust import adjust
    from lidarcat.survey import Survey

    with tempfile.TemporaryDirectory() as tmp:
        write_survey(read_opensfm(BERLIN / "berlin_reconstruction_example.json", BERLIN / "berlin_tracks_example.csv"),
                     Path(tmp) / "s", control_sd_m=0.05)
        survey = Survey.load(Path(tmp) / "s")
        c0, t0 = time.process_time(), time.perf_counter()
        sres = adjust(survey, Path(tmp) / "out")
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    r = sres.result
    return [["OpenSfM Berlin, default adjust", f"{r.status}, {r.n_iter} it.", f"{len(sres.blunders)} blunders",
             "", "", f"{cpu:.1f} s CPU, {wall:.1f} s wall", f"{sres.n_adjustments} adj."]]


def synthetic_rows() -> list[list[str]]:
    from lidarcat.bundle.reliability import snoop
    from lidarcat.synthetic.matches import matched_block

    p, truth, planted = matched_block()
    out = []
    for start in ("plain", "robust"):
        t0 = time.perf_counter()
        sr = snoop(p, mode="remove", start=start)
        dt = time.perf_counter() - t0
        r = sr.result
        named = {(b.photo, b.point) for b in sr.blunders if b.removed}
        dev = (np.abs(np.asarray(r.eo_params) - np.asarray(truth.true_eo)) / np.asarray(r.eo_sd)).max()
        out.append([f"synthetic matches, start {start}", f"{r.status}, {r.n_iter} it.",
                    f"{len(named & planted)}/{len(planted)} planted named, {len(named - planted)} others",
                    f"max |EO - truth| / sd {dev:.2f}" if r.success else "-", "", f"{dt:.1f} s",
                    f"{sr.n_adjustments} adj."])
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="ngi,berlin,synthetic", help="comma list of ngi, berlin, synthetic")
    args = ap.parse_args(argv)
    parts = {"ngi": ngi_rows, "berlin": berlin_rows, "synthetic": synthetic_rows}
    rows = []
    for name in args.only.split(","):
        rows += parts[name.strip()]()
    head = ["case", "status", "gross named", "EO vs reference", "median residual", "time", "adjustments"]
    widths = [max(len(str(r[i])) for r in [head, *rows]) for i in range(len(head))]
    print(f"load: {os.getloadavg()[0]:.2f} (1 min)")
    for r in [head, ["-" * w for w in widths], *rows]:
        print(" | ".join(str(c).ljust(w) for c, w in zip(r, widths)))


if __name__ == "__main__":
    main()
