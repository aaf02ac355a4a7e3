"""Stage ``report``: the pipeline report ``report/index.html``, ``index.md``, ``report.json``.

What ran (every planned stage with its state and reason), the extracted
LiDAR control, every run (adjustment test, check-point statistics, the
consistency test) with a link to its own HTML report, and every comparison.
:func:`results` also gives ``summary.json`` its ``runs``, ``comparison`` and
``extraction``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any


from .._util import atomic_write, write_json_atomic, write_text_atomic
from .._util.formatting import format_number
from ..report.quality import quality_report
from ..report.render import markdown_to_html
from .context import StageContext as Context
from .context import failed_tests
from .compare import EOP_DIFF, read_photo_rows

__all__ = ["run", "results", "num", "QUALITY_DIR"]

#: folder of the quality report's figures in OUTDIR/report/
QUALITY_DIR = "quality"


def results(records: Iterable[Any]) -> dict[str, Any]:
    """``runs``, ``comparison``, ``extraction`` and ``thesis`` of the done stages (summary.json, report)."""
    runs: dict[str, Any] = {}
    comparison: dict[str, Any] = {}
    extraction = thesis = selfcal = lidar_products = mapping = None
    for r in records:
        if not r.done:
            continue
        if r.name.startswith("adjust-"):
            runs.setdefault(r.name[7:], {})["adjustment"] = r.result.get("adjustment", {})
            runs[r.name[7:]]["folder"] = r.folder
        elif r.name.startswith("assess-"):
            run = runs.setdefault(r.name[7:], {})
            run["check"] = r.result.get("check", {})
            run["tests_passed"] = r.result.get("tests_passed", {})
            run["standards"] = r.result.get("standards", {})
            run["report"] = f"{r.folder}/report.html"
        elif r.name.startswith("compare-"):
            comparison[r.name[8:]] = dict(r.result)
        elif r.name == "extract":
            extraction = dict(r.result)
        elif r.name == "thesis":
            thesis = dict(r.result)
        elif r.name == "selfcal":
            selfcal = dict(r.result)
        elif r.name == "products":
            lidar_products = dict(r.result)
        elif r.name == "mapping":
            mapping = dict(r.result)
    return {"runs": runs, "comparison": comparison, "extraction": extraction, "thesis": thesis,
            **({"selfcal": selfcal} if selfcal else {}),
            **({"products": lidar_products} if lidar_products else {}),
            **({"mapping": mapping} if mapping else {})}


def run(ctx: Context, tmp: Path) -> dict:
    """The pipeline report: index.html / index.md / report.json (+ per-run reports)."""
    survey = ctx["survey"]
    plan: list[Any] = ctx["plan"]
    rows = []
    for st in plan:
        if st.name == "report":
            continue
        rec = ctx.records.get(st.name)
        state = "done" if rec and rec.done else rec.status if rec else "not run"
        rows.append({"stage": st.name, "what": st.description, "state": state,
                     "reason": rec.reason if rec and not rec.done else ""})
    from ..survey.folder import DEFAULT_CONTOUR_INTERVAL_M, DEFAULT_SCALE

    judged = next((st.params for st in plan if st.name.startswith("assess-")), None)
    settings = None
    if judged is not None:
        overridden = (judged["scale"] != survey.assessment.scale
                      or judged["contour_interval_m"] != survey.assessment.contour_interval_m)
        settings = {k: judged[k] for k in ("scale", "contour_interval_m", "alpha", "pec_class",
                                           "plotting_position")}
        settings.update(source="the command line" if overridden else "survey.toml [assessment]",
                        default_scale=DEFAULT_SCALE, default_contour_interval_m=DEFAULT_CONTOUR_INTERVAL_M)
    doc = {"survey": survey.name, "stages": rows, "settings": settings,
           "tests_failed": failed_tests(ctx.records[st.name] for st in plan if st.name in ctx.records),
           **results(ctx.records[st.name] for st in plan if st.name in ctx.records)}
    doc["reports"] = {name: f"../{run['report']}" for name, run in doc["runs"].items()
                      if "report" in run and (ctx.outdir / run["report"]).is_file()}
    for run in doc["runs"].values():
        if "report" in run:
            figs = ctx.outdir / Path(run["report"]).parent / "report_figures"
            run["figures_dir"] = figs.relative_to(ctx.outdir).as_posix()
            run["figures"] = sorted(p.name for p in figs.glob("*.png")) if figs.is_dir() else []
    for name, cmp_ in doc["comparison"].items():
        eo_path = ctx.folder(f"compare-{name}") / "eop_differences.csv"
        if eo_path.is_file() and cmp_.get("n_photos", 0) <= 50:
            cmp_["eop_per_photo"] = {p: v.tolist() for p, v in read_photo_rows(eo_path, EOP_DIFF).items()}
    if doc.get("thesis") and ctx.done("thesis"):
        doc["thesis_detail"] = json.loads((ctx.folder("thesis") / "thesis_4_4.json").read_text(encoding="utf-8"))
    quality = quality_report(ctx.outdir, survey, doc["runs"], stages=rows, tests_failed=doc["tests_failed"],
                             products=doc.get("products"), mapping=doc.get("mapping"), fig_dir=QUALITY_DIR,
                             progress=lambda i, n: ctx.progress(i, n + 1))
    doc["verdict"] = quality.verdict
    if quality.figures:
        (tmp / QUALITY_DIR).mkdir(exist_ok=True)
    for fname, png in quality.figures.items():
        with atomic_write(tmp / QUALITY_DIR / fname, "wb") as fh:
            fh.write(png)
    write_json_atomic(tmp / "report.json", doc)
    md = _report_markdown(doc, quality.lines)
    write_text_atomic(tmp / "index.md", md)
    # figure paths in index.md are relative to OUTDIR/report; tmp is its sibling in OUTDIR
    write_text_atomic(tmp / "index.html", markdown_to_html(md, f"lidarcat report: {survey.name}", base=tmp))
    return {"index": "report/index.html", "n_stages_done": sum(r["state"] == "done" for r in rows)}


def _report_markdown(doc: Mapping[str, Any], quality: Sequence[str] = ()) -> str:
    lines = [f"# lidarcat report: {doc['survey']}", ""]
    if doc.get("verdict"):
        lines += ["## Verdict", "", doc["verdict"], ""]
    if doc.get("tests_failed"):
        lines += ["**Statistical test failed** (every stage ran; read the results with care): "
                  + "; ".join(doc["tests_failed"]), ""]
    lines += ["## Stages", "",
             "| stage | what | state | reason |", "|---|---|---|---|"]
    for r in doc["stages"]:
        lines.append(f"| {r['stage']} | {r['what']} | {r['state']} | {r['reason']} |")
    st = doc.get("settings")
    if st:
        scale = f"1:{st['scale']:g}" if st["scale"] else "none (not applicable)"
        ci = f"{st['contour_interval_m']:g} m" if st["contour_interval_m"] else "none (not applicable)"
        lines += ["", f"Check points judged at map scale {scale} with a contour interval of "
                      f"{ci}, PEC class {st['pec_class']}, every test at alpha "
                      f"{st['alpha']:g}, Filliben positions {st['plotting_position']} (from "
                      f"{st['source']}; `lidarcat assess` and `lidarcat run` share the defaults "
                      f"1:{st['default_scale']:g} and {st['default_contour_interval_m']:g} m)."]
    ext = doc.get("extraction")
    if ext:
        lines += ["", "## LiDAR control points", "",
                  f"{ext['n_ok']} of {ext['n_jobs']} roof vertices extracted; control set "
                  f"{ext['control_set']} (every other ground point is its check point). "
                  "Details: ../extract/control.csv, planes.csv.", "",
                  "| point | status | planes | sd E (m) | sd N (m) | sd h (m) |", "|---|---|---|---|---|---|"]
        for pid, e in ext.get("points", {}).items():
            sd = e.get("sd_m") or [None] * 3
            lines.append(f"| {pid} | {e['status']} | {e['n_planes']} | "
                         + " | ".join(num(v, 3) for v in sd) + " |")
    prod = doc.get("products")
    if prod:
        lines += ["", "## LiDAR products", "",
                  f"In ../products/ (CRS {prod['crs']}): " + ", ".join(prod["files"]) + "."]
    if doc.get("mapping"):
        from .mapping import markdown as mapping_markdown

        lines += mapping_markdown(doc["mapping"])
    if doc.get("reports"):
        lines += ["", "## Accuracy reports", ""]
        lines += [f"- [control set {k}]({v})" for k, v in doc["reports"].items()]
    for name, run in doc["runs"].items():
        adj = run.get("adjustment") or {}
        lines += ["", f"## Run {name}", "",
                  f"dof {adj.get('dof')}, v'Pv {num(adj.get('vtpv'), 2)}, "
                  f"sigma0^2 {num(adj.get('sigma0_sq'), 3)}, chi-square test "
                  f"[{num(adj.get('chi2_lower'), 2)}, {num(adj.get('chi2_upper'), 2)}]: "
                  f"{'passed' if adj.get('chi2_pass') else 'failed'}"]
        for fig, caption in _RUN_FIGURES:
            if fig in run.get("figures", ()):
                lines += ["", f"![Run {name}: {caption}](../{run['figures_dir']}/{fig})"]
        if adj.get("blunders"):
            lines += ["", "| blunder (data snooping, kept) | photo | point | w | redundancy |", "|---|---|---|---|---|"]
            lines += [f"| {b['kind']} | {b.get('photo') or ''} | {b.get('point') or ''} | {num(b['w'], 2)} | "
                      f"{num(b['redundancy'], 2)} |" for b in adj["blunders"]]
        chk = run.get("check")
        if chk:
            lines += ["", "| check points, reference minus adjusted (m) | mean | std | RMSE | max abs |",
                      "|---|---|---|---|---|"]
            for c in ("E", "N", "h", "planimetric"):
                lines.append(f"| {c} (n={chk.get('n')}) | {num(chk.get(f'mean_{c}_m'), 3)} | "
                             f"{num(chk.get(f'std_{c}_m'), 3)} | {num(chk.get(f'rmse_{c}_m'), 3)} | "
                             f"{num(chk.get(f'max_abs_{c}_m'), 3)} |")
            cons = chk.get("consistency")
            if chk.get("consistency_not_computed"):
                lines += ["", "Discrepancies against the precision the adjustment claims (d'C^-1 d): "
                              + chk["consistency_not_computed"] + "."]
            if cons:
                lines += ["", f"Discrepancies against the precision the adjustment claims (joint "
                              f"covariance of the check points + their reference sds): d'C^-1 d = "
                              f"{num(cons['chi2'], 1)} on {cons['df']} degrees of freedom, "
                              f"{1 - cons['alpha']:.0%} interval [{num(cons['lower'], 1)}, "
                              f"{num(cons['upper'], 1)}]: {'passed' if cons['passed'] else 'failed'}"
                              + {"below": " (smaller discrepancies than claimed: the precision is pessimistic).",
                                 "above": " (larger discrepancies than claimed: look for blunders, model "
                                          "errors or optimistic control sds)."}.get(cons.get("side"), ".")]
    lines += list(quality)
    if doc.get("selfcal"):
        from .selfcal import markdown as selfcal_markdown

        lines += selfcal_markdown(doc["selfcal"])
    for pair, cmp_ in doc["comparison"].items():
        pts = cmp_.get("points", {})
        lines += ["", f"## Comparison {cmp_.get('sign', pair)}", "",
                  f"{cmp_.get('n_photos')} photos, {cmp_.get('n_points')} points free in both runs. "
                  "Metres for positions, degrees for angles.", "",
                  "| difference | mean | RMSE | max abs |", "|---|---|---|---|"]
        for k, v in cmp_.get("eop", {}).items():
            lines.append(f"| {k} | {num(v['mean'], 4)} | {num(v['rmse'], 4)} | {num(v['max_abs'], 4)} |")
        for c in ("E", "N", "h"):
            if f"mean_{c}_m" in pts:
                lines.append(f"| d{c} (points) | {num(pts[f'mean_{c}_m'], 3)} | "
                             f"{num(pts[f'rmse_{c}_m'], 3)} | {num(pts[f'max_abs_{c}_m'], 3)} |")
        per_photo = cmp_.get("eop_per_photo")
        if per_photo:
            lines += ["", "| photo | dX0 (m) | dY0 (m) | dZ0 (m) | domega (deg) | dphi (deg) "
                      "| dkappa (deg) |",
                      "|---|---|---|---|---|---|---|"]
            for ph, d in per_photo.items():
                lines.append(f"| {ph} | " + " | ".join(num(v, 3) for v in d[:3]) + " | "
                             + " | ".join(num(v, 4) for v in d[3:]) + " |")
    lines += _thesis_markdown(doc.get("thesis_detail"))
    return "\n".join(lines) + "\n"


#: figures of each run's own report shown in the index (file in report_figures/, caption)
_RUN_FIGURES = (("block_layout.png", "block layout (photo footprints, control, check and tie points)"),
                ("planimetric_vectors.png", "planimetric discrepancies of the check points"),
                ("height_discrepancies.png", "height discrepancies of the check points"))


def _thesis_markdown(det: Mapping[str, Any] | None) -> list[str]:
    """Section "Thesis section 4.4": the printed values beside the recomputed ones, errata marked."""
    if not det:
        return []
    lines = ["", "## Thesis section 4.4", "",
             "Fierro Sanhueza (2007), the LiDAR-controlled run and the comparison of the two runs. "
             "Statistics of sections 4.4.4.1-4.4.4.4 on Table 13 (the 21 GPS points triangulated with "
             "LiDAR control): printed, recomputed from the printed Table 13 (agreement at the printed "
             "precision), and from this run's adjustment. Filliben with the positions (i-0.5)/n, "
             "alpha 0.10, PEC 1:2000 class A, contour interval 2 m. A mark [E] names a misprint of "
             "errata.json (listed below with its evidence).", "",
             "| statistic | printed | from printed Table 13 | this run | agrees | erratum |",
             "|---|---|---|---|---|---|"]
    for r in det["statistics"]:
        nd = r["decimals"] + 1
        lines.append(f"| {r['label']} | {num(r['printed'], r['decimals'])} | "
                     + " | ".join(num(v, nd) for v in r["values"])
                     + f" | {'yes' if r['agrees'] else 'NO'} | {('[E] ' + r['erratum']) if r['erratum'] else ''} |")
    printed14 = det.get("tables_14_15") or {}
    for key, what in (("table14", "Table 14: normality test of the planimetric discrepancies X"),
                      ("table15", "Table 15: normality test of the height discrepancies")):
        if key not in printed14:
            continue
        a, b = det["table13_from_printed"][key], det["table13_this_run"][key]
        lines += ["", f"{what}, sorted, with the cumulative probability (i-0.5)/n and its normal score Z: "
                      "printed (the point of the printed row), recomputed from the printed Table 13, and "
                      "this run's own sorted values (its order of points may differ), m.", "",
                  "| i | point | X printed | X recomputed | X this run | (i-0.5)/n | Z printed | Z |",
                  "|---|---|---|---|---|---|---|---|"]
        for r, ra, rb in zip(printed14[key], a, b):
            lines.append(f"| {r['pos']} | {r['point']} | {num(r['X'], 3)} | {num(ra['X'], 3)} | {num(rb['X'], 3)} | "
                         f"{num(ra['prob_acum'], 3)} | {num(r['Z'], 2)} | {num(ra['Z'], 3)} |")
    lines += ["", "Tables 8-13 and Appendices 2.2 / 3.2 against this run: largest difference "
                  "(this run minus printed, errata applied) and its tolerance (printed precision, or the "
                  "GPS run's where the rounding of the published photo coordinates limits the reproduction).", "",
              "| table | quantity | values | max abs difference | tolerance | agrees | erratum |",
              "|---|---|---|---|---|---|---|"]
    for r in det["tables"]:
        unit = f" {r['unit']}" if r["unit"] and r["unit"] != "relative" else ""
        diff = (f"{100 * r['max_abs_diff']:.2f} %" if r["unit"] == "relative" else num(r["max_abs_diff"], 4) + unit)
        tol = f"{100 * r['tolerance']:.0f} %" if r["unit"] == "relative" else f"{r['tolerance']:g}{unit}"
        lines.append(f"| {r['table']} | {r['what']} | {r['n']} | {diff} | {tol} | "
                     f"{'yes' if r['agrees'] else 'NO'} | {('[E] ' + r['erratum']) if r['erratum'] else ''} |")
    if det.get("errata"):
        lines += ["", "Errata met above (errata.json):", ""]
        for where, e in det["errata"].items():
            lines.append(f"- [E] {where}: printed {e['printed']}, corrected {e['corrected']}. {e['evidence']}")
    return lines


def num(v: Any, nd: int) -> str:
    """*v* with *nd* decimals, ``-`` when missing (:func:`lidarcat._util.formatting.format_number`)."""
    return format_number(v, nd)

