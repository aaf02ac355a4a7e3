"""Stage ``selfcal``: the adjustment with the additional parameters of survey.toml ``[self_calibration]``.

Planned only when the survey switches something on (self-calibration
parameters and/or a frame offset between two control sources, see
:mod:`lidarcat.survey.selfcal`).  Writes the usual adjustment folder
(eop.csv, points.csv, residuals.csv, check_covariance.csv, summary.json with
``additional_parameters``, ``frame_offset`` and ``warnings``); the report
shows the estimates, their tests and the determinability warnings
(:func:`markdown`).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .context import StageContext as Context

__all__ = ["run", "markdown", "planned"]


def planned(survey: Any) -> bool:
    """True when the survey's ``[self_calibration]`` switches an additional parameter on."""
    from ..survey.selfcal import self_calibration_settings

    return self_calibration_settings(survey).active


def run(ctx: Context, tmp: Path) -> dict:
    """Adjustment with additional parameters -> the adjustment folder; the result keeps the tests.

    On a matched survey (image observations with sds of their own, the automatic tie points of
    ``lidarcat match``) the rule of the ``adjust-SET`` stages applies
    (:func:`lidarcat.stages.adjust.auto_variance_components`): data snooping in ``remove`` mode with
    the group variance factors, before the parameters are estimated -- a gross automatic match would
    otherwise pull the additional parameters (``blunders.csv`` and the summary's ``snooping`` say what
    was removed).  Hand-measured blocks (the thesis's) are adjusted with every observation, as before.
    Photos with GNSS/IMU sds (photos.csv ``sd_X0`` ..) are weighted constraints, as in the ``adjust-SET``
    stages (the plan's ``eo_constraints``).
    """
    from ..survey.selfcal import selfcal_snooped, write_selfcal
    from .adjust import auto_variance_components

    matched = auto_variance_components(ctx["survey"])
    sc = selfcal_snooped(ctx["survey"], snooping="remove" if matched else "off", variance_components=matched,
                         eo_constraints=bool(ctx.params.get("eo_constraints")))   # photos.csv sd_X0..: GNSS/IMU
    survey, res = sc.survey, sc.result
    extra: dict[str, Any] = {"crs": survey.crs, "height_system": survey.height_system}
    if sc.variance_components is not None:
        extra["variance_components"] = sc.variance_components.summary()
    summary = write_selfcal(res, tmp, extra=extra, snooping=sc.snooping)
    keep = ("additional_parameters", "frame_offset", "parameter_groups", "parameters_off", "parameters_on",
            "warnings", "control_set", "status")
    out = {k: summary.get(k) for k in keep}
    if sc.snooping is not None:
        out["blunders_removed"] = len(summary.get("blunders") or [])
    return out


def markdown(sc: Mapping[str, Any]) -> list[str]:
    """Report lines (Markdown) of a ``selfcal`` stage result."""
    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    off, on = sc.get("parameters_off") or {}, sc.get("parameters_on") or {}
    lines = ["", "## Additional parameters", "",
             f"Control set {sc.get('control_set')}; v'Pv {f(off.get('vtpv'), '.2f')} (dof {off.get('dof')}) "
             f"without the parameters, {f(on.get('vtpv'), '.2f')} (dof {on.get('dof')}) with them "
             f"({sc.get('status')}). Details: ../selfcal/summary.json."]
    ap = sc.get("additional_parameters") or {}
    if ap:
        lines += ["", "| parameter | unit | correction | sd | t | significant | largest correlation |",
                  "|---|---|---|---|---|---|---|"]
        for name, t in ap.items():
            e = t.get("max_correlation_eo") or {}
            lines.append(f"| {name} | {t['unit']} | {f(t['estimate'], '.4g')} | {f(t['sd'], '.2g')} | "
                         f"{f(t['t'], '.2f')} | {'yes' if t['significant'] else 'no'} | "
                         f"{f(e.get('r'), '+.3f')} ({e.get('parameter')}, photo {e.get('photo')}) |")
    fos = sc.get("frame_offset")
    for fo in ([fos] if isinstance(fos, dict) else fos or []):
        lines += ["", f"Frame offset {fo['source']} -> {fo['reference']} (added to {fo['source']} "
                      "coordinates):", "", "| | E (m) | N (m) | h (m) |", "|---|---|---|---|",
                  "| shift | " + " | ".join(f(v, "+.3f") for v in fo["shift_m"]) + " |",
                  "| sd | " + " | ".join(f(v, ".3f") for v in fo["sd_m"]) + " |",
                  "| t | " + " | ".join(f(v, "+.2f") for v in fo["t"]) + " |", "",
                  f"Joint {fo['test']['test']} test ({fo['test']['dof']} dof): statistic "
                  f"{f(fo['test']['statistic'], '.2f')}, p = {f(fo['test']['p_value'], '.2g')}: "
                  + ("significant" if fo["significant"] else "not significant") + f" at {100 * fo['alpha']:g} %."]
    for w in sc.get("warnings") or []:
        lines += ["", f"**Warning:** {w}"]
    return lines
