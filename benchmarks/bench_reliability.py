"""Blunder detection: seeded trials on the thesis block and a corrupted 1,000-photo block (issue 12).

Run:  python benchmarks/bench_reliability.py [--trials 100] [--level family|both|ALPHA]
                                             [--robust none|danish] [--counts 1,3,5]
                                             [--strips 20 --per-strip 50]
                                             [--large danish:multiple,none:multiple]
                                             [--skip-trials] [--skip-large]

Part 1 -- the thesis geometry (6 photos, 151 image observations, 8 GPS control points): the
observations are simulated from the adjusted thesis solution (the truth) with Gaussian noise of
the stated sigmas, so every observation except the injected ones is good by construction.  Each
trial puts 1, 3 or 5 blunders of 10-50 sigma in random directions on random image observations
and runs ``snoop(mode="remove")`` (``--level``: family-wise 0.05 by default, power 0.80).
Printed per blunder count: share of the trials in which every injected blunder was named, the
same over the trials in which every blunder is above its minimal detectable bias in its
direction (lambda >= lambda0 of the level; below it no test can see it), the identification
ceiling over those trials (:class:`_Identification`: the Monte Carlo probability, with the
dense Q_vv, that the max-ratio rule names each blunder; product over the blunders), and the
mean number of good observations named per trial.

Part 2 -- a synthetic block (``lidarcat.synthetic.block``, default 20 strips x 50 photos) with
1 % of its image observations corrupted by 10-50 sigma: the clean adjustment, then
``snoop(mode="remove", robust=..., multiple=..., backward=False)`` at the family-wise level 0.05
for each ``--large`` run, timed beside the clean adjustment; printed: the largest
|orientation - truth| / sd (sd of the clean run), the share of the 6 P parameters within 3 sd
(99.73 % expected) and the RMS of those normalised deviations (1 expected) for the clean, the
corrupted and the cleaned run; blunders found / injected (and among those above their MDB),
good observations removed, adjustments and snooping rounds.
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402


def _truth_sim(p, truth, rng):
    from lidarcat.synthetic.block import resimulated

    return resimulated(p, np.asarray(truth.eo_params), np.asarray(truth.points_m), rng)


def _whitened_qvv(p, res):
    from lidarcat.geometry.collinearity import project_with_jacobians
    from lidarcat.bundle.model import NormalSystem
    from lidarcat.bundle.precision import observation_blocks

    eo, pts = np.asarray(res.eo_params), np.asarray(res.points_m)
    S = observation_blocks(NormalSystem(p, eo, pts))
    _, ae, ap, _ = project_with_jacobians(eo, pts[p.point_index], p.focal_length_mm[p.photo_index],
                                          p.photo_index)
    A = np.concatenate([ae, ap], axis=2)
    qvv = np.einsum("ni,ij->nij", p.sd_mm**2, np.eye(2)) - A @ S @ np.transpose(A, (0, 2, 1))
    return qvv / (p.sd_mm[:, :, None] * p.sd_mm[:, None, :])


class _Identification:
    """Probability that one-at-a-time snooping names a single blunder first (its own test has the
    largest ratio and rejects; for a two-ray point either ray), by Monte Carlo over the noise:
    e ~ N(Q_vv P C nabla, Q_vv) with the dense Q_vv of the thesis block.  The max-ratio rule is the
    maximum-likelihood choice among the single-blunder alternatives, so this is the ceiling of the
    found-rate for that blunder; with several blunders the product over them is used as an
    approximate ceiling (it ignores their interaction)."""

    def __init__(self, p, res, level, power, draws=2000, seed=99):
        from lidarcat.bundle.redundancy import MIN_REDUNDANCY, _dense_cofactor, critical_values

        self.p, self.draws = p, draws
        self.qvv, self.qll = _dense_cofactor(res)
        w, v = np.linalg.eigh(self.qvv)
        self.L = v * np.sqrt(np.clip(w, 0, None))
        self.n, self.k = n, k = len(p.photo_index), len(p.constraint_point_index)
        # whitened blocks P^1/2 Q_vv,a P^1/2 = U diag(lam) U^T; tested span lam > MIN_REDUNDANCY
        # (as redundancy._group_tests); the same for every draw, so computed once
        sd = np.r_[p.sd_mm.ravel(), p.constraint_sd_m.ravel()]
        self.sd = sd
        idx = [np.arange(2 * a, 2 * a + 2) for a in range(n)] + [2 * n + np.arange(3 * c, 3 * c + 3) for c in range(k)]
        self.groups = []
        for g in idx:
            lam, U = np.linalg.eigh(self.qvv[np.ix_(g, g)] / np.outer(sd[g], sd[g]))
            keep = lam > MIN_REDUNDANCY
            q = int(keep.sum())
            crit = critical_values(level, power, q)[1] if q else np.inf
            self.groups.append((g, U[:, keep] / np.sqrt(lam[keep]), crit))
        self.rng = np.random.default_rng(seed)
        rays = np.bincount(p.point_index)
        self.partner = np.full(n, -1)
        for a in range(n):
            if rays[p.point_index[a]] == 2:
                self.partner[a] = next(b for b in np.flatnonzero(p.point_index == p.point_index[a]) if b != a)

    def probability(self, a, nabla_mm):
        d = np.zeros(len(self.qll))
        d[2 * a:2 * a + 2] = nabla_mm
        mean = self.qvv @ (d / self.qll)
        ew = (mean + self.rng.standard_normal((self.draws, len(self.qll))) @ self.L.T) / self.sd
        ratio = np.column_stack([np.sum((ew[:, g] @ W) ** 2, axis=1) / crit for g, W, crit in self.groups])
        best = np.argmax(ratio, axis=1)
        hit = (best == a) | ((self.partner[a] >= 0) & (best == self.partner[a]))
        return float(np.mean(hit & (ratio[np.arange(self.draws), best] > 1)))


def thesis_trials(n_trials: int, level: float | None = None, robust: str = "none",
                  counts: tuple[int, ...] = (1, 3, 5)) -> list[dict]:
    from lidarcat.bundle import adjust
    from lidarcat.survey import problem_from_survey
    from lidarcat.bundle.reliability import reliability, snoop
    from lidarcat.survey.folder import Survey

    p = problem_from_survey(Survey.load(), control="gps", observations="corrected")
    truth = adjust(p)
    wq = _whitened_qvv(p, truth)
    rel = reliability(truth, level=level)        # None: the family-wise level of the block's 159 tests
    lam0 = rel.lam0
    ident = _Identification(p, truth, rel.alpha, rel.power)
    rows = []
    for n_bl in counts:
        rng = np.random.default_rng(1000 + n_bl)
        found = found_det = n_det = wrong = 0
        ceiling = []
        t0 = time.perf_counter()
        for _ in range(n_trials):
            q = _truth_sim(p, truth, rng)
            idx = rng.choice(len(q.photo_index), n_bl, replace=False)
            size = rng.uniform(10, 50, n_bl)
            ang = rng.uniform(0, 2 * np.pi, n_bl)
            d = size[:, None] * np.c_[np.cos(ang), np.sin(ang)]        # in sigmas
            detectable = all(float(v @ wq[i] @ v) >= lam0 for i, v in zip(idx, d))
            if detectable:
                ceiling.append(np.prod([ident.probability(int(i), v * q.sd_mm[i]) for i, v in zip(idx, d)]))
            xy = np.array(q.xy_mm)
            xy[idx] += d * q.sd_mm[idx]
            sr = snoop(dataclasses.replace(q, xy_mm=xy), mode="remove", level=level, robust=robust)
            injected = {(q.photo_ids[q.photo_index[i]], q.point_ids[q.point_index[i]]) for i in idx}
            named = {(b.photo, b.point) for b in sr.blunders}
            ok = injected <= named
            found += ok
            n_det += detectable
            found_det += ok and detectable
            wrong += len(named - injected)
        rows.append({"level": f"{rel.alpha:.3g}", "robust": robust, "blunders": n_bl, "trials": n_trials,
                     "all_named_%": 100 * found / n_trials,
                     "detectable_trials": n_det, "named_if_detectable_%": 100 * found_det / max(n_det, 1),
                     "identification_ceiling_%": 100 * float(np.mean(ceiling)) if ceiling else float("nan"),
                     "good_named_per_trial": wrong / n_trials, "s_per_trial": (time.perf_counter() - t0) / n_trials})
    return rows


def large_block(strips: int, per_strip: int, share: float = 0.01, *, robust: str = "danish",
                multiple: bool = True, max_rejections: int = 1000, clean_run: dict | None = None) -> dict:
    from lidarcat.synthetic.block import synthetic_block
    from lidarcat.bundle import adjust
    from lidarcat.bundle.reliability import snoop

    b = synthetic_block(strips, per_strip, seed=1)
    p = b.problem
    n = len(p.photo_index)
    if clean_run is None or not clean_run:
        t0 = time.perf_counter()
        clean = adjust(p, precision="photos")
        t_clean = time.perf_counter() - t0
        if clean_run is not None:
            clean_run.update(result=clean, seconds=t_clean)
    else:
        clean, t_clean = clean_run["result"], clean_run["seconds"]
    rng = np.random.default_rng(7)
    idx = rng.choice(n, int(round(share * n)), replace=False)
    ang = rng.uniform(0, 2 * np.pi, len(idx))
    size = rng.uniform(10, 50, len(idx))
    xy = np.array(p.xy_mm)
    xy[idx] += size[:, None] * np.c_[np.cos(ang), np.sin(ang)] * p.sd_mm[idx]
    bad = dataclasses.replace(p, xy_mm=xy)
    t0 = time.perf_counter()
    raw = adjust(bad, precision="photos")
    t_raw = time.perf_counter() - t0
    t0 = time.perf_counter()
    sr = snoop(bad, mode="remove", robust=robust, precision="photos", max_rejections=max_rejections,
               backward=False, multiple=multiple)
    t_snoop = time.perf_counter() - t0
    level = sr.reliability.alpha
    injected = {(p.photo_ids[p.photo_index[i]], p.point_ids[p.point_index[i]]) for i in idx}
    removed = {(x.photo, x.point) for x in sr.blunders if x.removed}

    def dev(res):
        d = np.asarray(res.eo_params) - np.asarray(b.true_eo)
        d[:, 3:] = (d[:, 3:] + np.pi) % (2 * np.pi) - np.pi          # kappa near +-pi on return strips
        return np.abs(d) / np.asarray(clean.eo_sd)

    # detectable: the blunder is above its MDB in its direction (lambda >= lambda0 at this level)
    from lidarcat.bundle.reliability import noncentrality

    wq = _whitened_qvv(p, clean)
    d = size[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    det = np.einsum("ni,nij,nj->n", d, wq[idx], d) >= noncentrality(level)
    det_ids = {(p.photo_ids[p.photo_index[i]], p.point_ids[p.point_index[i]]) for i in idx[det]}
    row = {"robust": robust, "multiple": multiple, "photos": p.n_photos, "image_obs": n, "corrupted": len(idx),
           "detectable": int(det.sum()), "level": level, "clean_s": t_clean, "corrupted_plain_s": t_raw,
           "snoop_s": t_snoop, "adjustments": sr.n_adjustments,
           "rounds": max((x.iteration for x in sr.blunders), default=0), "found": len(injected & removed),
           "found_detectable": len(det_ids & removed), "good_removed": len(removed - injected)}
    for name, res in (("clean", clean), ("plain", raw), ("cleaned", sr.result)):
        x = dev(res)
        row[f"{name}_max_dev_sd"] = float(x.max())
        row[f"{name}_within_3sd_%"] = float(100 * np.mean(x < 3))
        row[f"{name}_rms_dev_sd"] = float(np.sqrt(np.mean(x**2)))
    row["chi2_pass_cleaned"] = bool(sr.result.chi2["passed"])
    return row


def _table(rows: list[dict]) -> str:
    keys = list(rows[0])
    cells = [[f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k]) for k in keys] for r in rows]
    width = [max(len(k), *(len(c[i]) for c in cells)) for i, k in enumerate(keys)]
    out = ["  ".join(k.rjust(w) for k, w in zip(keys, width))]
    out += ["  ".join(c.rjust(w) for c, w in zip(row, width)) for row in cells]
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--strips", type=int, default=20)
    ap.add_argument("--per-strip", type=int, default=50)
    ap.add_argument("--skip-trials", action="store_true")
    ap.add_argument("--skip-large", action="store_true")
    ap.add_argument("--level", default="family",
                    help="alpha_1 of the w-tests of the thesis trials, or 'family' (family-wise 0.05, default), "
                         "or 'both' (family and 0.001 side by side)")
    ap.add_argument("--robust", default="none", help="robust start of the thesis trials (none, danish, huber)")
    ap.add_argument("--counts", default="1,3,5", help="numbers of blunders per trial")
    ap.add_argument("--large", default="danish:multiple,none:multiple",
                    help="runs of the large block, comma list of ROBUST:multiple|single")
    a = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    if not a.skip_trials:
        levels = {"family": [None], "both": [None, 0.001]}.get(a.level) or [float(a.level)]
        counts = tuple(int(c) for c in a.counts.split(","))
        print("\nThesis geometry, simulated noise, blunders of 10-50 sigma (snoop remove):")
        print(_table([r for lv in levels for r in thesis_trials(a.trials, lv, a.robust, counts)]), flush=True)
    if not a.skip_large:
        print(f"\nSynthetic block {a.strips} x {a.per_strip}, 1 % of the image observations corrupted "
              "(family-wise level 0.05):", flush=True)
        clean: dict = {}
        rows = []
        for spec in a.large.split(","):
            robust, multiple = spec.split(":")
            rows.append(large_block(a.strips, a.per_strip, robust=robust, multiple=multiple == "multiple",
                                    clean_run=clean))
            print(_table(rows[-1:]), flush=True)
        print(_table(rows))
    print(f"load average at end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
