"""Time and memory of the bundle adjustment (issue 3).

Run:  python benchmarks/bench_bundle.py [--photos 500] [--repeat 3]

Cases: the thesis block (6 photos, GPS and LiDAR control, from computed
approximations) and seeded synthetic blocks (``lidarcat.synthetic.block``) up
to 500 photos.  For each case: wall time of the approximations and of the whole
``adjust`` call (iterations + covariance blocks), iterations, peak Python/numpy
memory traced by ``tracemalloc`` during ``adjust`` and the process max RSS.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import resource  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402


def _case(name, problem, repeat):
    from lidarcat.bundle.approx import approximations
    from lidarcat.bundle import adjust

    best_a, best_t = float("inf"), float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        approximations(problem)
        best_a = min(best_a, time.perf_counter() - t0)
        t0 = time.perf_counter()
        r = adjust(problem)
        best_t = min(best_t, time.perf_counter() - t0)
    from lidarcat.bundle import NormalSystem, covariance_blocks

    system = NormalSystem(problem, r.eo_params, r.points_m)
    t0 = time.perf_counter()
    covariance_blocks(system)
    cov_s = time.perf_counter() - t0
    from lidarcat.bundle import joint_point_covariance

    k = min(200, problem.n_points)  # the joint covariance of 200 points (a check-point set)
    t0 = time.perf_counter()
    joint_point_covariance(r, list(r.point_ids[:: max(1, problem.n_points // k)][:k]))
    joint_s = time.perf_counter() - t0
    tracemalloc.start()
    r = adjust(problem)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {"case": name, "photos": problem.n_photos, "points": problem.n_points,
            "obs": problem.n_observations, "dof": problem.dof, "approx_s": best_a, "adjust_s": best_t,
            "cov_s": cov_s, "joint_s": joint_s, "joint_k": k,
            "iter": r.n_iter, "status": r.status, "sigma0_sq": r.sigma0_sq, "peak_mb": peak / 2**20,
            "maxrss_mb": rss}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photos", type=int, default=500, help="photos of the largest synthetic block (20 strips)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()

    from lidarcat.synthetic.block import synthetic_block
    from lidarcat.survey import problem_from_survey
    from lidarcat.survey.folder import Survey

    survey = Survey.load()
    rows = [_case("thesis gps", problem_from_survey(survey, "gps"), args.repeat),
            _case("thesis lidar", problem_from_survey(survey, "lidar"), args.repeat)]
    for strips, per in ((4, 25), (10, 25), (20, max(2, args.photos // 20))):
        b = synthetic_block(strips, per, seed=1)
        rows.append(_case(f"synthetic {strips}x{per}", b.problem, 1 if strips * per > 200 else args.repeat))
    head = (f"{'case':<18}{'photos':>7}{'points':>8}{'obs':>8}{'dof':>8}{'approx s':>10}{'adjust s':>10}{'cov s':>8}"
            f"{'joint s':>9}{'iter':>6}{'sigma0^2':>10}{'peak MB':>9}{'maxRSS MB':>11}  status")
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['case']:<18}{r['photos']:>7}{r['points']:>8}{r['obs']:>8}{r['dof']:>8}{r['approx_s']:>10.3f}"
              f"{r['adjust_s']:>10.3f}{r['cov_s']:>8.3f}{r['joint_s']:>9.3f}{r['iter']:>6}{r['sigma0_sq']:>10.3f}{r['peak_mb']:>9.1f}"
              f"{r['maxrss_mb']:>11.1f}  {r['status']}")
    print("adjust s: approximations + iterations + covariance blocks (best of --repeat); cov s: the "
          "covariance blocks alone; joint s: joint_point_covariance of up to 200 points (3k x 3k, "
          "cross-covariances included); peak MB: tracemalloc during one adjust; maxRSS: whole process so far.")
    print("load average at the end:", " ".join(f"{v:.2f}" for v in os.getloadavg()))


if __name__ == "__main__":
    main()
