"""``lidarcat run``: the whole pipeline on a survey folder."""

from __future__ import annotations

import sys
from typing import Any

import click

from ..survey.folder import DEFAULT_CONTOUR_INTERVAL_M, DEFAULT_SCALE
from .options import echo_json, json_opt, output_option

__all__ = ["run"]


def _help(doc: str) -> str:
    """The docstring of :func:`run` with the stage table of :data:`lidarcat.stages.REGISTRY`."""
    import inspect

    from ..stages import REGISTRY

    width = max(len(n) for n, _ in REGISTRY) + 2
    table = "\b\nStages, in order (each skipped when its inputs are absent):\n" + "\n".join(
        f"  {name:<{width}}{what}" for name, what in REGISTRY) + "\n"
    return inspect.cleandoc(doc).replace("{stages}", table)


def _with_stages(f: Any) -> Any:
    f.__doc__ = _help(f.__doc__ or "")
    return f


@click.command("run")
@click.argument("survey", required=False, type=click.Path(exists=True, file_okay=False),
                metavar="[SURVEY]")
@output_option(outdir=True, type=click.Path(file_okay=False), default=None,
              help="Output folder (created; every file written atomically). "
                   "Default: SURVEY/out, or ./lidarcat-out for the embedded thesis block.")
@click.option("--force", is_flag=True,
              help="Recompute every stage even when its inputs are unchanged "
                   "(default: reuse stages whose input hashes match OUTDIR/.stages).")
@click.option("--scale", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Map scale denominator for classifying the check points (PEC classes, the "
                   "chi-square sigma0, the CE90 limit). Default: survey.toml [assessment] scale, "
                   f"else {DEFAULT_SCALE:g} (the thesis's 1:{DEFAULT_SCALE:g}; the same default as "
                   "`lidarcat assess`).")
@click.option("--contour-interval", "contour_interval_m", type=click.FloatRange(min=0, min_open=True),
              default=None,
              help="Contour interval for the altimetric classes, metres. Default: survey.toml "
                   f"[assessment] contour_interval_m, else {DEFAULT_CONTOUR_INTERVAL_M:g} m (the thesis's; the "
                   "same default as `lidarcat assess`).")
@click.option("--figures", is_flag=True,
              help="Also draw one figure per extracted roof (points by face, planes, vertex; thesis "
                   "Figure 19) into OUTDIR/extract/figures/.")
@json_opt
@click.pass_context
@_with_stages
def run(ctx: click.Context, survey: str | None, outdir: str | None, force: bool, scale: float | None,
        contour_interval_m: float | None, figures: bool, as_json: bool) -> None:
    """Run the whole pipeline on SURVEY (default: the embedded thesis block).

    {stages}
    OUTDIR gets one folder per stage, summary.json (status ran / reused /
    skipped / failed of every stage and the key numbers) and lidarcat.log.
    Stages whose inputs (file contents, parameters, lidarcat version) did not
    change since the last run are reused. One run at a time per OUTDIR
    (OUTDIR/.lidarcat.lock).

    \b
    Exit code and last line:
      0  ok
      1  FAILED: a stage failed (its reason is on its line)
      2  invalid survey or an OUTDIR in use (nothing is run)
      3  STATISTICAL TEST FAILED: every stage ran, but an adjustment
         failed its chi-square test of the variance factor (image or
         control sds, the model, or a blunder); summary.json has
         status "test failed" and the test in tests_failed
     70  internal error (a bug): one line; the traceback with lidarcat -vv

    \b
    Examples:
      lidarcat run -o out/                    # the thesis block
      lidarcat demo synthetic -o demo/ && lidarcat run demo/ -o demo-out/
      lidarcat run demo/ -o demo-out/ --figures   # + one figure per roof
    The mapping, products and selfcal stages run when survey.toml has a
    [mapping] (orthophotos = true, features; photos in SURVEY/images/, e.g.
    from `lidarcat demo synthetic --images`), [products] or
    [self_calibration] table (docs/survey-format.md).
    """
    from ..pipeline import FROM_SURVEY, run_pipeline

    bars: dict[str, Any] = {}  # the open bar of every started stage (removed when it ends)
    ended: set[str] = set()
    show = sys.stderr.isatty() and not as_json

    def progress(stage: str, done: int, total: int) -> None:
        if not show or stage in ended:
            return
        bar = bars.get(stage)
        if bar is None:
            bar = click.progressbar(length=max(total, 1), label=f"{stage:<18}", file=sys.stderr,
                                    show_eta=False, show_percent=True)
            bar.__enter__()
            bars[stage] = bar
        if done >= total:  # the stage ended
            bar.update(max(0, bar.length - bar.pos))
            bar.render_finish()
            del bars[stage]
            ended.add(stage)
            return
        if total != bar.length:  # the stage now knows its size
            bar.length = max(total, 1)
        bar.update(max(0, done - bar.pos))

    try:
        result = run_pipeline(survey, outdir, force=force, progress=progress,
                              scale=FROM_SURVEY if scale is None else scale,
                              contour_interval_m=FROM_SURVEY if contour_interval_m is None else contour_interval_m,
                              figures=figures)
    finally:
        for bar in bars.values():  # stages interrupted mid-way
            bar.render_finish()
    if as_json:
        echo_json(result.to_dict())
    else:
        click.echo(_text(result))
    if result.failed:
        ctx.exit(1)
    if result.tests_failed:
        ctx.exit(3)


def _text(result) -> str:
    from ..stages.report import (
        num as _f,  # the report's number format: '-' for a missing value
    )

    lines = [f"lidarcat run: {result.summary.get('survey', {}).get('name', '?')} -> {result.outdir}"]
    for s in result.stages:
        if s.status in ("skipped", "failed"):
            extra = s.reason
        else:
            extra = f"{s.seconds:.2f} s" if s.status == "ran" else ""
        lines.append(f"  {s.name:<18} {s.status:<8} {extra}".rstrip())
    ext = result.summary.get("extraction")
    if ext:
        lines.append(f"  extraction: {ext['n_ok']} of {ext['n_jobs']} roof vertices -> control set "
                     f"{ext['control_set']}")
        if ext.get("not_measured"):
            lines.append(f"  extraction: measured on no photo, no effect on the block: "
                         f"{', '.join(ext['not_measured'])} (check the ids in the jobs file)")
    for name, run in (result.summary.get("runs") or {}).items():
        adj = run.get("adjustment", {})
        chk = run.get("check", {})
        parts = [f"dof {adj.get('dof')}", f"v'Pv {_f(adj.get('vtpv'), 2)}",
                 f"sigma0^2 {_f(adj.get('sigma0_sq'), 3)}",
                 f"chi2 {'pass' if adj.get('chi2_pass') else 'FAILED'}"]
        if adj.get("blunders"):
            gone = sum(bool(b.get("removed")) for b in adj["blunders"])
            verb = "named and removed" if gone == len(adj["blunders"]) else "remain"
            parts.append(f"{len(adj['blunders'])} blunder(s) {verb} (w-test): " + "; ".join(
                f"{b['kind']} {'photo ' + b['photo'] + ' ' if b.get('photo') else ''}point {b['point']}"
                if b.get("point") else f"{b['kind']} photo {b['photo']}" for b in adj["blunders"][:5])
                + (" ..." if len(adj["blunders"]) > 5 else ""))
        if chk:
            parts.append("check RMSE E/N/h " + "/".join(_f(chk.get(f"rmse_{a}_m"), 3) for a in "ENh") + " m")
            cons = chk.get("consistency")
            if cons:
                verdict = {"below": "below its interval: precision pessimistic",
                           "above": "above its interval: errors larger than claimed"}.get(cons.get("side"), "pass")
                parts.append(f"d'C^-1d {_f(cons['chi2'], 1)} on {cons['df']} dof {verdict}")
            elif chk.get("consistency_not_computed"):
                parts.append(f"d'C^-1d {chk['consistency_not_computed']}")
        lines.append(f"  run {name}: " + ", ".join(parts))
    th = result.summary.get("thesis")
    if th:
        for src, label in (("printed", "recomputed from its printed values"), ("this_run", "from this run")):
            s = th["table13"][src]
            lines.append(f"  thesis Table 13, {label}: Filliben r plan/h {_f(s['r_plan'], 3)}/"
                         f"{_f(s['r_altim'], 3)} (critical {_f(s['r_tab'], 3)}), t E/N/h "
                         + "/".join(_f(s[f"t_{a}"], 2) for a in "ENh"))
        odd = th["statistics_discrepant"] + th["tables_discrepant"]
        lines.append(f"  thesis section 4.4: {th['statistics_agree']} of {th['statistics']} statistics and "
                     f"{th['tables_agree']} of {th['tables']} table comparisons reproduced"
                     + (f"; not reproduced (errata, see the report): {', '.join(odd)}" if odd else ""))
    report = result.summary.get("report")
    if report:
        lines.append(f"  report: {report}")
    if result.failed:
        lines.append(f"FAILED: {', '.join(result.failed)}")
    elif result.tests_failed:
        lines += [f"  statistical test failed, {t}" for t in result.tests_failed]
        lines.append("STATISTICAL TEST FAILED: every stage ran, but " + ", ".join(
            t.split(":")[0] for t in result.tests_failed) + " failed its chi-square test (exit code 3)")
    else:
        lines.append("ok")
    return "\n".join(lines)
