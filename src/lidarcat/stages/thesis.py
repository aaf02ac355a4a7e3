"""Stage ``thesis``: the thesis's section 4.4 beside this run (Fierro Sanhueza 2007).

Planned when the survey folder holds the printed tables of the thesis in
``published/`` (the embedded block does; see ``data/thesis/published/README.md``)
and has the control sets ``gps`` and ``lidar``.  It writes ``thesis_4_4.json``
with two comparisons:

* **Table 13 statistics** (sections 4.4.4.1-4.4.4.4, Tables 14/15) recomputed
  from the *printed* Table 13 (so the thesis's formulas are checked to the
  printed precision) and from *this run* (the GPS points triangulated with
  the LiDAR control).  With the n = 21 discrepancies ``d`` of a component,
  ``X = sqrt(dE^2 + dN^2)`` for the planimetric one, ``s`` the sample sd:

  - Filliben r: correlation of the sorted sample with ``Phi^-1((i - 0.5)/n)``
    (Hazen positions, the thesis's Z_i), critical value 0.961 (10 %, n = 21);
  - trend: ``t = mean / (s / sqrt(n))`` per axis (eq. 43, 44);
  - upper bound of the mean: ``mu <= mean + t_{1-alpha, n-1} s / sqrt(n)``;
  - PEC test of the mean: ``t = (mean - PEC) / (s / sqrt(n))``;
  - precision: ``chi2 = (n - 1) s^2 / EP^2`` (eq. 46) with EP 0.6 m (plan) and
    Eq/3 = 2/3 m (height, Decreto 89.817 class A at 1:2000, Eq 2 m), and the
    bound ``sigma <= sqrt((n - 1) s^2 / chi2_{alpha, n-1})`` (eq. 45 as the
    thesis computed it, see errata).

* **Tables 8-13 and Appendix 2.2 / 3.2** against this run: the largest
  difference per table with the tolerance of the printed precision or, where
  the rounding of the published photo coordinates limits the reproduction, of
  the GPS run (EOP 0.10 m / 0.005 deg, points 0.03 m E/N and 0.12 m h, sds 2 %).

Every known misprint that a comparison meets is named by its ``errata.json``
entry instead of being hidden; ``mu_plan <= 0.441`` (4.4.4.3) is not
reproducible (0.411 with t = 1.33) and is reported as that discrepancy.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._util import write_json_atomic
from ..accuracy.checkpoints import filliben_test, read_points
from ..errors import LidarcatError
from .context import StageContext as Context
from .compare import EOP, read_photo_rows

__all__ = ["PUBLISHED", "RUNS", "STATISTICS", "run", "published_files", "table13_statistics",
           "compare_statistics"]

#: folder of a survey holding the printed thesis tables
PUBLISHED = "published"
#: the control sets of the two runs of the thesis: GPS-controlled, LiDAR-controlled
RUNS = ("gps", "lidar")

#: (key, label, decimals printed, erratum or "") of every printed statistic of 4.4.4.x, in order
STATISTICS: tuple[tuple[str, str, int, str], ...] = (
    ("filliben.r_plan", "Filliben r, planimetric X (4.4.4.1)", 3, ""),
    ("filliben.r_altim", "Filliben r, height (4.4.4.1)", 3, ""),
    ("filliben.r_tab", "Filliben critical r, 10 %, n = 21", 3, ""),
    ("t_alpha", "t_{0.90, 20} (4.4.4.2)", 2, "t_alpha = 1.33 'for n = 21'"),
    ("trend_t.t_E", "trend t, E (4.4.4.2)", 2, ""),
    ("trend_t.t_N", "trend t, N (4.4.4.2)", 2, ""),
    ("trend_t.t_h", "trend t, h (4.4.4.2)", 2, ""),
    ("table14_mean_X", "mean of X, planimetric (Table 14)", 3, ""),
    ("table14_std_X", "sd of X, planimetric (Table 14)", 3, ""),
    ("table15_mean_X", "mean of dh (Table 15)", 3, ""),
    ("table15_std_X", "sd of dh (Table 15)", 3, ""),
    ("mu_upper.mu_plan_le", "mean bound mu_plan <= (4.4.4.3)", 3, "section 4.4.4.3, mu_plan <= 0.441"),
    ("mu_upper.mu_altim_le", "mean bound mu_altim <= (4.4.4.3)", 3, ""),
    ("pec_t.t_plan", "PEC t, planimetric (4.4.4.3)", 2, ""),
    ("pec_t.t_altim", "PEC t, height (4.4.4.3)", 2, ""),
    ("chi2_tab.chi2_alpha", "chi2_{0.10, 20}", 3, "eq. 45 (upper bound of sigma)"),
    ("chi2_tab.chi2_1_minus_alpha", "chi2_{0.90, 20}", 3, ""),
    ("chi2_computed.chi2_plan", "chi-square, planimetric (4.4.4.4)", 3, ""),
    ("chi2_computed.chi2_altim", "chi-square, height (4.4.4.4)", 3, "section 4.4.4.4, chi2_altim"),
    ("sigma_upper.sigma_plan_le", "sigma bound, planimetric (4.4.4.4)", 3, "eq. 45 (upper bound of sigma)"),
    ("sigma_upper.sigma_altim_le", "sigma bound, height (4.4.4.4)", 3, "eq. 45 (upper bound of sigma)"),
)


def published_files(folder: Path) -> dict[str, Path]:
    """The printed tables in *folder* (``published/`` of the survey), by short name."""
    names = {"table8": "eop_lidar.csv", "table6": "eop_gps.csv", "app3_1": "app3_gps.csv",
             "app3_2": "app3_lidar.csv", "app2": "app2.json", "table9": "table9_check_lidar.csv",
             "table10": "table10.csv", "table11": "table11_eop_diff.csv", "table12": "table12.json",
             "table13": "table13.csv", "stats": "stats_expected.json", "errata": "errata.json"}
    return {k: folder / v for k, v in names.items()}


# --------------------------------------------------------------------------- statistics of 4.4.4

def table13_statistics(d: Any, *, plani: Any = None, alpha: float = 0.10, t_alpha: float | None = None,
                       plan_pec_m: float = 1.0, plan_ep_m: float = 0.6, alt_pec_m: float = 1.0,
                       alt_ep_m: float = 2.0 / 3.0) -> dict[str, Any]:
    """The statistics of sections 4.4.4.1-4.4.4.4 of discrepancies *d*.

    Parameters
    ----------
    d : array (n, 3)
        dE, dN, dh reference minus adjusted, m.
    plani : array (n,), optional
        Planimetric resultants X, m; default ``hypot(dE, dN)``.  A printed
        table gives its own rounded column (Table 13 'plani'), which the
        thesis's statistics used.
    alpha : float
        Level of every test (thesis 0.10).
    t_alpha : float, optional
        t of the mean bounds; default ``t_{1-alpha, n-1}`` (1.325 at n = 21;
        the thesis used it rounded to 1.33).
    plan_pec_m, plan_ep_m, alt_pec_m, alt_ep_m : float
        PEC and EP (m), planimetric and altimetric; default Decreto 89.817
        class A at 1:2000 with a 2 m contour interval (the thesis's).

    Returns
    -------
    dict
        Keys as ``stats_expected.json`` (``filliben.r_plan``, ``trend_t.t_E``...
        nested), plus ``table14`` / ``table15`` rows (point order not kept:
        X sorted, cumulative probability (i - 0.5)/n, Z).
    """
    from scipy import stats

    d = np.asarray(d, dtype=float).reshape(-1, 3)
    n = len(d)
    x_plan = np.hypot(d[:, 0], d[:, 1]) if plani is None else np.asarray(plani, dtype=float).ravel()
    rt = math.sqrt(n)

    def mean_sd(v: np.ndarray) -> tuple[float, float]:
        return float(v.mean()), float(v.std(ddof=1))

    t_alpha = float(stats.t.ppf(1 - alpha, n - 1)) if t_alpha is None else float(t_alpha)
    chi_lo, chi_hi = float(stats.chi2.ppf(alpha, n - 1)), float(stats.chi2.ppf(1 - alpha, n - 1))
    f_plan = filliben_test(x_plan, alpha, "hazen")
    f_alt = filliben_test(d[:, 2], alpha, "hazen")
    (mp, sp), (mh, sh) = mean_sd(x_plan), mean_sd(d[:, 2])
    trend = {f"t_{c}": mean_sd(d[:, k])[0] / (mean_sd(d[:, k])[1] / rt) for k, c in enumerate("ENh")}
    probs = (np.arange(1, n + 1) - 0.5) / n
    z = stats.norm.ppf(probs)
    return {
        "n": n, "alpha": alpha, "t_alpha": t_alpha, "trend_t": trend,
        "filliben": {"r_plan": f_plan.statistic, "r_altim": f_alt.statistic, "r_tab": f_plan.critical},
        "table14_mean_X": mp, "table14_std_X": sp, "table15_mean_X": mh, "table15_std_X": sh,
        "mu_upper": {"mu_plan_le": mp + t_alpha * sp / rt, "mu_altim_le": mh + t_alpha * sh / rt},
        "pec_t": {"t_plan": (mp - plan_pec_m) / (sp / rt), "t_altim": (mh - alt_pec_m) / (sh / rt)},
        "chi2_tab": {"chi2_alpha": chi_lo, "chi2_1_minus_alpha": chi_hi},
        "chi2_computed": {"chi2_plan": (n - 1) * sp ** 2 / plan_ep_m ** 2,
                          "chi2_altim": (n - 1) * sh ** 2 / alt_ep_m ** 2},
        "sigma_upper": {"sigma_plan_le": math.sqrt((n - 1) * sp ** 2 / chi_lo),
                        "sigma_altim_le": math.sqrt((n - 1) * sh ** 2 / chi_lo)},
        "table14": [{"pos": i + 1, "X": float(v), "prob_acum": float(p), "Z": float(q)}
                    for i, (v, p, q) in enumerate(zip(np.sort(x_plan), probs, z))],
        "table15": [{"pos": i + 1, "X": float(v), "prob_acum": float(p), "Z": float(q)}
                    for i, (v, p, q) in enumerate(zip(np.sort(d[:, 2]), probs, z))],
    }


def _get(doc: Mapping[str, Any], key: str) -> Any:
    for part in key.split("."):
        doc = doc[part]
    return doc


def compare_statistics(printed: Mapping[str, Any], *columns: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per :data:`STATISTICS` entry: printed value, each column's value, agreement.

    ``agrees`` compares the *first* column with the printed value at the
    printed precision (1.5 units of the last printed decimal: 0.0015 for 3
    decimals, the project's rule for values rounded twice).
    """
    rows = []
    for key, label, nd, erratum in STATISTICS:
        p = float(_get(printed, key))
        vals = [float(_get(c, key)) for c in columns]
        tol = 1.5 * 10.0 ** -nd + 1e-9
        rows.append({"key": key, "label": label, "decimals": nd, "printed": p, "values": vals,
                     "tolerance": tol, "agrees": bool(abs(vals[0] - p) <= tol), "erratum": erratum})
    return rows


# --------------------------------------------------------------------------- tables 8-13 vs this run

def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#")))


def _row(table: str, what: str, diffs: Sequence[float], tol: float, unit: str,
         erratum: str = "") -> dict[str, Any]:
    m = float(np.max(np.abs(diffs))) if len(diffs) else float("nan")
    return {"table": table, "what": what, "n": len(diffs), "max_abs_diff": m, "tolerance": tol,
            "unit": unit, "agrees": bool(m <= tol), "erratum": erratum}


def _sd_row(table: str, what: str, mine: np.ndarray, printed: np.ndarray) -> dict[str, Any]:
    rel = np.abs(mine / printed - 1)
    return _row(table, what, rel, 0.02, "relative")


def _eop_rows(table: str, mine: Mapping[str, np.ndarray], sds: Mapping[str, np.ndarray],
              rows: list[dict[str, str]], erratum: str, fix: Mapping[tuple[str, str], float]) -> list[dict]:
    val_cols = ("X0", "Y0", "Z0", "omega_deg", "phi_deg", "kappa_deg")
    sd_cols = ("sX0", "sY0", "sZ0", "somega_deg", "sphi_deg", "skappa_deg")
    pv = np.array([[fix.get((r["photo"], c), float(r[c])) for c in val_cols] for r in rows])
    ps = np.array([[float(r[c]) for c in sd_cols] for r in rows])
    mv = np.array([mine[r["photo"]] for r in rows])
    ms = np.array([sds[r["photo"]] for r in rows])
    return [_row(table, "X0, Y0, Z0", (mv - pv)[:, :3].ravel(), 0.10, "m", erratum),
            _row(table, "omega, phi, kappa", (mv - pv)[:, 3:].ravel(), 0.005, "deg", erratum),
            _sd_row(table, "standard deviations", ms, ps)]


def _table_rows(ctx: Context, pub: Mapping[str, Path], survey: Any) -> list[dict[str, Any]]:
    fg, fl = ctx.folder("adjust-gps"), ctx.folder("adjust-lidar")
    sd_eop = tuple(f"sd_{c}" for c in EOP)
    eg, el = read_photo_rows(fg / "eop.csv", EOP), read_photo_rows(fl / "eop.csv", EOP)
    sl = read_photo_rows(fl / "eop.csv", sd_eop)
    out = _eop_rows("Table 8", el, sl, _csv(pub["table8"]),
                    "Table 8 (EOP, LiDAR run), photo 5, kappa", {("5", "kappa_deg"): 67.98952})
    pl, pg = read_points(fl / "points.csv"), read_points(fg / "points.csv")
    il, ig = pl.index(), pg.index()
    app = _csv(pub["app3_2"])
    xyz = np.array([pl.xyz[il[r["name"]]] for r in app])
    pxyz = np.array([[float(r[c]) for c in ("E", "N", "h")] for r in app])
    out += [_row("Appendix 3.2", "E, N of 54 points", (xyz - pxyz)[:, :2].ravel(), 0.03, "m"),
            _row("Appendix 3.2", "h of 54 points", (xyz - pxyz)[:, 2], 0.12, "m")]
    if pl.sd is not None:
        sd = np.array([pl.sd[il[r["name"]]] for r in app])
        out.append(_sd_row("Appendix 3.2", "standard deviations", sd,
                           np.array([[float(r[c]) for c in ("sE", "sN", "sh")] for r in app])))
    summ = json.loads((fl / "summary.json").read_text(encoding="utf-8"))
    a22 = json.loads(pub["app2"].read_text(encoding="utf-8"))["2.2_lidar"]
    out += [_row("Appendix 2.2", "degrees of freedom", [summ["dof"] - a22["dof"]], 0, ""),
            _row("Appendix 2.2", "v'Pv (printed 149.12)", [summ["vtpv"] - a22["chi2_computed"]], 0.5, ""),
            _row("Appendix 2.2", "sigma0^2 a posteriori", [summ["sigma0_sq"] - a22["variance_a_posteriori"]],
                 0.01, ""),
            _row("Appendix 2.2", "chi-square range (Fisher approximation)",
                 [summ["chi2_lower_fisher"] - a22["chi2_range_5pct"][0],
                  summ["chi2_upper_fisher"] - a22["chi2_range_5pct"][1]], 0.005, "",
                 "Appendix 2 chi-square range (5%)")]
    gp = survey.ground_points
    ref = {str(p): e for p, e in zip(gp.point, gp.enh_m)}

    def disc(rows: list[dict[str, str]], pts: Any, idx: Mapping[str, int]) -> tuple[np.ndarray, np.ndarray]:
        mine = np.array([ref[r["point"]] - pts.xyz[idx[r["point"]]] for r in rows])
        printed = np.array([[float(r[c]) for c in ("dE", "dN", "dh")] for r in rows])
        return mine, printed

    for table, key, pts, idx, what in (("Table 9", "table9", pl, il, "LiDAR check points, LiDAR run"),
                                       ("Table 13", "table13", pl, il, "GPS points, LiDAR run")):
        m, p = disc(_csv(pub[key]), pts, idx)
        out += [_row(table, f"dE, dN: {what}", (m - p)[:, :2].ravel(), 0.03, "m"),
                _row(table, f"dh: {what}", (m - p)[:, 2], 0.12, "m")]
    # Table 10: the LiDAR points adjusted in the GPS run minus their LiDAR values (Table 5)
    rows10 = _csv(pub["table10"])
    m10 = np.array([pg.xyz[ig[r["point"]]] - ref[r["point"]] for r in rows10])
    p10 = np.array([[float(r[c]) for c in ("dE", "dN", "dh")] for r in rows10])
    ok10 = np.array([r["point"] != "705" for r in rows10])  # dN of 705 is an unresolved misprint
    out += [_row("Table 10", "dE, dN: GPS run minus LiDAR values", (m10 - p10)[ok10, :2].ravel(), 0.03, "m",
                 "Table 10, point 705, dN"),
            _row("Table 10", "dh: GPS run minus LiDAR values", (m10 - p10)[:, 2], 0.12, "m")]
    # Table 11: EOP of the GPS run minus the LiDAR run
    rows11 = _csv(pub["table11"])
    cols11 = ("dX0", "dY0", "dZ0", "domega_deg", "dphi_deg", "dkappa_deg")
    p11 = np.array([[0.03474 if (r["photo"], c) == ("5", "domega_deg") else float(r[c]) for c in cols11]
                    for r in rows11])
    m11 = np.array([eg[r["photo"]] - el[r["photo"]] for r in rows11])
    out += [_row("Table 11", "dX0, dY0, dZ0", (m11 - p11)[:, :3].ravel(), 0.10, "m"),
            _row("Table 11", "domega, dphi, dkappa", (m11 - p11)[:, 3:].ravel(), 0.005, "deg",
                 "Table 11, photo 5, domega")]
    # Table 12: App. 3.1 - App. 3.2 over the points free in both runs, per group (first digit)
    t12 = json.loads(pub["table12"].read_text(encoding="utf-8"))["groups"]
    roles_g = dict(zip(pg.ids, pg.roles or [""] * len(pg.ids)))
    roles_l = dict(zip(pl.ids, pl.roles or [""] * len(pl.ids)))
    free = [q for q in pg.ids if q in il and roles_g[q] != "control" and roles_l[q] != "control"]
    dm, dp = [], []
    for group, prefix in (("lidar_700", "7"), ("pass_400", "4"), ("gps_600", "6")):
        d = np.array([pg.xyz[ig[q]] - pl.xyz[il[q]] for q in free if q.startswith(prefix)])
        d = np.c_[d, np.hypot(d[:, 0], d[:, 1])]
        for k, c in enumerate(("dE", "dN", "dh", "plani")):
            for stat, v in (("mean", d[:, k].mean()), ("std", d[:, k].std(ddof=1))):
                (dp if c == "dh" else dm).append(v - t12[group][stat][c])
    out += [_row("Table 12", "means and sds of dE, dN, plani per group", dm, 0.03, "m"),
            _row("Table 12", "means and sds of dh per group", dp, 0.12, "m")]
    return out


# --------------------------------------------------------------------------- the stage

def run(ctx: Context, tmp: Path) -> dict:
    """Thesis section 4.4 beside this run -> thesis_4_4.json."""
    survey = ctx["survey"]
    par = ctx.params
    pub = published_files(survey.root / PUBLISHED)
    printed = json.loads(pub["stats"].read_text(encoding="utf-8"))
    rows13 = _csv(pub["table13"])
    d_printed = np.array([[float(r[c]) for c in ("dE", "dN", "dh")] for r in rows13])
    gp = survey.ground_points
    ref = {str(p): e for p, e in zip(gp.point, gp.enh_m)}
    pl = read_points(ctx.folder("adjust-lidar") / "points.csv")
    il = pl.index()
    d_run = np.array([ref[r["point"]] - pl.xyz[il[r["point"]]] for r in rows13])
    kw = {"alpha": par.get("alpha", 0.10)}
    # the thesis's own arithmetic: its rounded 'plani' column and t = 1.33
    from_printed = table13_statistics(d_printed, plani=[float(r["plani"]) for r in rows13],
                                      t_alpha=printed["t_alpha"], **kw)
    this_run = table13_statistics(d_run, **kw)
    stats_rows = compare_statistics(printed, from_printed, this_run)
    tables = _table_rows(ctx, pub, survey)
    errata = {e["where"]: e for e in json.loads(pub["errata"].read_text(encoding="utf-8"))}
    used = sorted({r["erratum"] for r in (*stats_rows, *tables) if r["erratum"]})
    missing = [u for u in used if u not in errata]
    if missing:  # a misprint named here must be one of errata.json (its evidence is shown)
        raise LidarcatError(f"{pub['errata']}: no entry for the erratum {missing}")
    doc = {"statistics": stats_rows, "tables": tables,
           "tables_14_15": {k: printed[k] for k in ("table14", "table15")},
           "errata": {u: errata[u] for u in used},
           "table13_from_printed": from_printed, "table13_this_run": this_run,
           "settings": {"alpha": kw["alpha"], "plotting_position": "hazen", "scale": 2000,
                        "pec_class": "A", "contour_interval_m": 2.0}}
    write_json_atomic(tmp / "thesis_4_4.json", doc)
    fp, tr = from_printed, this_run
    return {
        "statistics_agree": sum(r["agrees"] for r in stats_rows), "statistics": len(stats_rows),
        "statistics_discrepant": [r["key"] for r in stats_rows if not r["agrees"]],
        "tables_agree": sum(r["agrees"] for r in tables), "tables": len(tables),
        "tables_discrepant": [f"{r['table']}: {r['what']}" for r in tables if not r["agrees"]],
        "table13": {src: {"r_plan": s["filliben"]["r_plan"], "r_altim": s["filliben"]["r_altim"],
                          "r_tab": s["filliben"]["r_tab"], **s["trend_t"]}
                    for src, s in (("printed", fp), ("this_run", tr))},
    }
