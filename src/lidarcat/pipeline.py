"""The whole chain in one call: ``lidarcat run``.

A survey folder goes through the stages of the tool in pipeline order:

================  ==========================================================  ========================
stage             what it does                                                 output folder
================  ==========================================================  ========================
``camera``        interior orientation, pixel -> corrected photo coordinates   ``camera/``
                  (eq. 01-07); skipped when the survey has no pixel columns
``extract``       roof planes -> LiDAR control points, only when the survey    ``extract/``
                  has LiDAR tiles and extraction jobs; writes a derived
                  survey whose ground points include the extracted points
                  and a control set ``lidar`` of them
``adjust-SET``    bundle adjustment for every control set (eq. 08-22)          ``adjust-SET/``
``assess-SET``    check-point accuracy of that run (thesis section 3.3.4) and  ``assess-SET/``
                  its HTML report; map scale and contour interval are
                  parameters (default 1:2000 and 2 m, as the thesis)
``compare-A-B``   run A (the default control set) minus run B, for every       ``compare-A-B/``
                  other run: exterior orientations and the points free
                  (not control) in both runs (thesis section 4.4)
``report``        index.html / index.md / report.json: what ran, every run,    ``report/``
                  the comparison, links to the per-run HTML reports
================  ==========================================================  ========================

Every stage records the SHA-256 of its inputs (file contents, parameters,
lidarcat version and source code, and the outputs of the stages it depends on) in
``OUTDIR/.stages/<stage>.json``; a later run with unchanged inputs reuses the
stage (status ``reused``) instead of recomputing it, ``force=True`` recomputes
everything.  A stage writes its folder through :func:`lidarcat._io.atomic_dir`
and its record only afterwards, so an interrupted run (SIGINT) leaves no
half-written file and the next run redoes exactly the unfinished stages
(temporary ``.*.part`` leftovers of a killed run are removed first; two runs
must not share an output folder at the same time).
``OUTDIR/summary.json`` lists every stage with its status (``ran``, ``reused``,
``skipped`` or ``failed``), the reason and the key numbers, and
``OUTDIR/lidarcat.log`` keeps the log of every run.

The generic machinery (:class:`Stage`, :func:`run_stages`) does not know about
photogrammetry and can chain any stages.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from ._io import atomic_dir, dumps_json, folder_lock, write_json_atomic
from .errors import LidarcatError, SurveyError

__all__ = [
    "FROM_SURVEY",
    "Stage",
    "StageRecord",
    "PipelineResult",
    "ProgressCallback",
    "run_stages",
    "run_pipeline",
    "plan_pipeline",
    "STATUSES",
]

log = logging.getLogger(__name__)

#: the statuses a stage can end with
STATUSES = ("ran", "reused", "skipped", "failed")

#: ``progress(stage, done, total)``: called with ``done == 0`` when a stage
#: starts and ``done == total`` when it ends; stages that know their size call
#: it in between.
ProgressCallback = Callable[[str, int, int], None]

_RECORD_DIR = ".stages"
_HASH_CHUNK = 1 << 20


@dataclasses.dataclass(frozen=True, eq=False)
class Stage:
    """One step of a pipeline.

    Parameters
    ----------
    name : str
        Unique stage name (also the name of its record file).
    folder : str
        Output folder relative to the pipeline's output folder.
    run : callable
        ``run(ctx, tmpdir) -> dict``: writes the stage's files into *tmpdir*
        (moved into ``OUTDIR/folder`` only when it returns) and returns a
        JSON-serialisable dict of key numbers.  *ctx* is a :class:`_Context`
        giving access to the output folder and the results of earlier stages.
    requires : tuple of str
        Stages whose outputs this stage reads; when one of them did not
        succeed the stage is skipped.
    uses : tuple of str
        Optional upstream stages: their outputs enter the hash when they
        are available, and the stage runs without them otherwise.
    inputs : callable or None
        ``inputs(ctx) -> list of paths`` hashed by content (resolved when the
        stage is about to run, so it may depend on earlier stages).
    params : mapping
        JSON-serialisable parameters included in the hash.
    skip_reason : str or None
        When set the stage is not run and is reported as skipped with this
        reason (inputs absent).
    description : str
        One line for the report's table of stages.
    """

    name: str
    folder: str
    run: Callable[[Any, Path], dict]
    requires: tuple[str, ...] = ()
    uses: tuple[str, ...] = ()
    inputs: Callable[[Any], Iterable[os.PathLike | str]] | None = None
    params: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    skip_reason: str | None = None
    description: str = ""


@dataclasses.dataclass(frozen=True)
class StageRecord:
    """What happened to one stage in one run.

    Attributes
    ----------
    name, folder : str
        Stage name and its output folder (relative to the output folder).
    status : str
        ``ran``, ``reused`` (inputs unchanged, previous outputs kept),
        ``skipped`` (inputs absent or an upstream stage did not succeed) or
        ``failed``.
    reason : str
        Why a stage was skipped or failed ('' otherwise).
    seconds : float
        Wall time of this run of the stage (0 when reused or skipped).
    input_hash : str or None
        SHA-256 of the stage's inputs.
    outputs : tuple of str
        Files the stage wrote, relative to the output folder.
    result : dict
        Key numbers returned by the stage.
    """

    name: str
    folder: str
    status: str
    reason: str = ""
    seconds: float = 0.0
    input_hash: str | None = None
    outputs: tuple[str, ...] = ()
    result: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def done(self) -> bool:
        """True when the stage's outputs are available (ran or reused)."""
        return self.status in ("ran", "reused")

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name, "folder": self.folder, "status": self.status,
            "reason": self.reason, "seconds": round(self.seconds, 3),
            "input_hash": self.input_hash, "outputs": list(self.outputs),
            "result": dict(self.result),
        }


@dataclasses.dataclass(frozen=True, eq=False)
class PipelineResult:
    """The outcome of :func:`run_pipeline` (also written as ``OUTDIR/summary.json``).

    Attributes
    ----------
    outdir : Path
        The output folder.
    stages : tuple of StageRecord
        Every planned stage in pipeline order.
    summary : dict
        The content of ``summary.json``.
    """

    outdir: Path
    stages: tuple[StageRecord, ...]
    summary: Mapping[str, Any]

    @property
    def ok(self) -> bool:
        """True when no stage failed."""
        return not any(s.status == "failed" for s in self.stages)

    @property
    def failed(self) -> list[str]:
        """Names of the failed stages."""
        return [s.name for s in self.stages if s.status == "failed"]

    def stage(self, name: str) -> StageRecord:
        """The record of stage *name* (KeyError when not planned)."""
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(f"no stage {name!r}; stages: {', '.join(s.name for s in self.stages)}")

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)


class _Context:
    """What a stage sees: output folder, earlier records, shared values."""

    def __init__(self, outdir: Path, values: Mapping[str, Any] | None = None,
                 progress: ProgressCallback | None = None):
        self.outdir = outdir
        self.records: dict[str, StageRecord] = {}
        self.values: dict[str, Any] = dict(values or {})
        self._progress = progress
        self.current: str | None = None
        self.stage: Stage | None = None

    def folder(self, stage: str) -> Path:
        """Final output folder of an earlier stage."""
        return self.outdir / self.records[stage].folder

    def result(self, stage: str) -> Mapping[str, Any]:
        return self.records[stage].result

    def done(self, stage: str) -> bool:
        return stage in self.records and self.records[stage].done

    def progress(self, done: int, total: int) -> None:
        """Report progress of the current stage."""
        if self._progress is not None and self.current is not None:
            self._progress(self.current, done, total)

    def __getitem__(self, key: str) -> Any:
        return self.values[key]


# --------------------------------------------------------------------------- hashing

_DIGESTS: dict[tuple[str, int, int], str] = {}


def _file_digest(path: Path) -> str:
    st = path.stat()
    key = (str(path), st.st_size, st.st_mtime_ns)
    if key in _DIGESTS:
        return _DIGESTS[key]
    _DIGESTS[key] = digest = _file_digest_uncached(path)
    return digest


def _file_digest_uncached(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


_CODE_DIGEST: list[str] = []


def _code_digest() -> str:
    """SHA-256 of lidarcat's own source and data files: a code change invalidates every stage.

    The version number alone does not change between development builds.
    """
    if not _CODE_DIGEST:
        root = Path(__file__).resolve().parent
        h = hashlib.sha256()
        for p in sorted(root.rglob("*")):
            if p.is_file() and p.suffix in (".py", ".json", ".csv", ".toml") and "__pycache__" not in p.parts:
                h.update(str(p.relative_to(root)).encode())
                h.update(p.read_bytes())
        _CODE_DIGEST.append(h.hexdigest())
    return _CODE_DIGEST[0]


def _input_hash(stage: Stage, files: Sequence[Path], upstream: Mapping[str, Any]) -> tuple[str, dict]:
    """SHA-256 over the stage's parameters, input files and upstream outputs."""
    file_digests = {}
    for p in sorted({Path(f).resolve() for f in files}):
        file_digests[str(p)] = _file_digest(p) if p.is_file() else "absent"
    doc = {
        "stage": stage.name,
        "lidarcat": __version__,
        "code": _code_digest(),
        "params": json.loads(dumps_json(dict(stage.params))),
        "files": file_digests,
        "upstream": upstream,
    }
    text = dumps_json(doc, indent=None)
    return hashlib.sha256(text.encode()).hexdigest(), doc


def _record_path(outdir: Path, name: str) -> Path:
    return outdir / _RECORD_DIR / f"{_safe(name)}.json"


def _load_record(outdir: Path, name: str) -> dict | None:
    path = _record_path(outdir, name)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _outputs_intact(outdir: Path, record: Mapping[str, Any]) -> bool:
    digests = record.get("output_digests") or {}
    for rel, digest in digests.items():
        p = outdir / rel
        if not p.is_file() or _file_digest(p) != digest:
            return False
    return True


# --------------------------------------------------------------------------- runner

def run_stages(
    stages: Sequence[Stage],
    outdir: str | os.PathLike,
    *,
    force: bool = False,
    progress: ProgressCallback | None = None,
    values: Mapping[str, Any] | None = None,
) -> list[StageRecord]:
    """Run *stages* in order with content-hash caching and atomic outputs.

    Parameters
    ----------
    stages : sequence of Stage
        In execution order; ``requires`` may only name earlier stages.
    outdir : path
        Output folder (created).  Stage records go to ``outdir/.stages``.
    force : bool
        Recompute every stage even when its inputs are unchanged.
    progress : callable, optional
        ``progress(stage, done, total)``.
    values : mapping, optional
        Shared values available to the stages as ``ctx[key]``.

    Returns
    -------
    list of StageRecord
        One per stage, in order.  A failing stage does not stop the others;
        stages that require it are skipped.  ``KeyboardInterrupt`` propagates
        (the interrupted stage's outputs are discarded).
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    _DIGESTS.clear()  # file digests are memoised within one run only
    ctx = _Context(outdir, values, progress)
    records: list[StageRecord] = []
    names = [s.name for s in stages]
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate stage names in {names}")
    # leftovers of a run that was killed (no cleanup possible after SIGKILL or a power cut)
    for st in stages:
        _remove_parts((outdir / st.folder).parent, f"{Path(st.folder).name}.")
    _remove_parts(outdir / _RECORD_DIR, "")
    _remove_parts(outdir, "summary.json.")
    for stage in stages:
        rec = _run_one(stage, ctx, force)
        ctx.records[stage.name] = rec
        records.append(rec)
    return records


def _run_one(stage: Stage, ctx: _Context, force: bool) -> StageRecord:
    outdir = ctx.outdir
    ctx.current = stage.name
    ctx.stage = stage
    if stage.skip_reason:
        log.info("stage %s: skipped (%s)", stage.name, stage.skip_reason)
        return StageRecord(stage.name, stage.folder, "skipped", stage.skip_reason)
    missing = [r for r in stage.requires if not ctx.done(r)]
    if missing:
        why = "; ".join(f"{r} {ctx.records[r].status if r in ctx.records else 'not planned'}"
                        for r in missing)
        reason = f"needs {', '.join(missing)} ({why})"
        log.info("stage %s: skipped (%s)", stage.name, reason)
        return StageRecord(stage.name, stage.folder, "skipped", reason)
    try:
        files = [Path(f) for f in (stage.inputs(ctx) if stage.inputs else [])]
        upstream = {}
        for r in (*stage.requires, *stage.uses):
            rec = _load_record(outdir, r) if ctx.done(r) else None
            upstream[r] = rec.get("output_digests", {}) if rec else ctx.records[r].status \
                if r in ctx.records else "not planned"
        digest, _doc = _input_hash(stage, files, upstream)
    except LidarcatError as ex:
        log.error("stage %s: failed (%s)", stage.name, ex)
        return StageRecord(stage.name, stage.folder, "failed", str(ex))

    old = _load_record(outdir, stage.name)
    if (not force and old and old.get("input_hash") == digest
            and old.get("status") in ("ran", "reused") and _outputs_intact(outdir, old)):
        log.info("stage %s: reused (inputs unchanged, %s)", stage.name, digest[:12])
        if ctx._progress:
            ctx._progress(stage.name, 1, 1)
        return StageRecord(stage.name, stage.folder, "reused", "inputs unchanged", 0.0, digest,
                           tuple(old.get("outputs", ())), old.get("result", {}))

    # invalidate the old record first: an interruption below must not leave a
    # record that claims the (partly replaced) outputs are complete
    with contextlib.suppress(FileNotFoundError):
        _record_path(outdir, stage.name).unlink()
    log.info("stage %s: running", stage.name)
    if ctx._progress:
        ctx._progress(stage.name, 0, 1)
    t0 = time.perf_counter()
    target = outdir / stage.folder
    written: list[str] = []
    try:
        with atomic_dir(target) as tmp:
            result = stage.run(ctx, tmp) or {}
            written = sorted(str(p.relative_to(tmp)) for p in tmp.rglob("*") if p.is_file())
            json.loads(dumps_json(result))  # serialisable before anything moves
    except KeyboardInterrupt:
        # the interrupt may land before atomic_dir's own cleanup is armed
        _remove_parts(target.parent, f"{target.name}.")
        log.warning("stage %s: interrupted after %.2f s; its outputs were discarded (run again "
                    "to finish)", stage.name, time.perf_counter() - t0)
        raise
    except Exception as ex:  # a failing stage (or a bug in one) must not stop the others
        seconds = time.perf_counter() - t0
        if isinstance(ex, LidarcatError):
            reason = str(ex)
            log.error("stage %s: failed after %.2f s: %s", stage.name, seconds, ex)
        else:
            reason = f"{type(ex).__name__}: {ex}"
            log.error("stage %s: failed after %.2f s: %s\n%s", stage.name, seconds, reason,
                      traceback.format_exc())
        # results of an earlier run no longer match the inputs: remove them
        if stage.folder not in ("", "."):
            _clear_folder(target, keep=())
        return StageRecord(stage.name, stage.folder, "failed", reason, seconds, digest)
    seconds = time.perf_counter() - t0
    # files of an earlier run of this stage that this run did not write
    if stage.folder not in ("", "."):
        _clear_folder(target, keep=set(written))
    outputs = _rel(stage.folder, written)
    digests = {rel: _file_digest(outdir / rel) for rel in outputs}
    rec = StageRecord(stage.name, stage.folder, "ran", "", seconds, digest, tuple(outputs), result)
    write_json_atomic(_record_path(outdir, stage.name),
                      {**rec.to_dict(), "output_digests": digests, "lidarcat": __version__})
    log.info("stage %s: ran in %.2f s", stage.name, seconds)
    if ctx._progress:
        ctx._progress(stage.name, 1, 1)
    return rec


def _remove_parts(parent: Path, prefix: str) -> None:
    """Remove temporary ``.<prefix>*.part`` files and folders in *parent* (see lidarcat._io)."""
    import shutil

    if not parent.is_dir():
        return
    for p in parent.glob(f".{prefix}*.part"):
        if p.is_dir():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()


def _clear_folder(folder: Path, keep: Iterable[str]) -> None:
    """Remove files under *folder* (a stage's own output folder) except *keep* (relative paths)."""
    if not folder.is_dir() or folder.name in ("", ".", ".."):
        return
    keep = set(keep)
    for p in sorted(folder.rglob("*"), reverse=True):
        rel = str(p.relative_to(folder))
        if p.is_file() and rel not in keep and ".part" not in p.name:
            p.unlink()
        elif p.is_dir() and not any(p.iterdir()):
            p.rmdir()
    if not keep and folder.is_dir() and not any(folder.iterdir()):
        folder.rmdir()


def _rel(folder: str, names: Iterable[str]) -> list[str]:
    return [str(Path(folder) / n) if folder not in ("", ".") else n for n in names]


# --------------------------------------------------------------------------- logging

@contextlib.contextmanager
def _log_to(path: Path):
    handler = logging.FileHandler(path, encoding="utf-8")
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    handler.setLevel(logging.INFO)
    root = logging.getLogger("lidarcat")
    old_level = root.level
    old_handler_levels = [(h, h.level) for h in root.handlers]
    effective = root.getEffectiveLevel()
    if effective > logging.INFO:
        # the file gets INFO; the other handlers keep their previous threshold
        for h in root.handlers:
            if h.level < effective:
                h.setLevel(effective)
        root.setLevel(logging.INFO)
    root.addHandler(handler)
    try:
        yield
    finally:
        root.removeHandler(handler)
        handler.close()
        root.setLevel(old_level)
        for h, level in old_handler_levels:
            h.setLevel(level)


# =========================================================================== the lidarcat stages

_COMPONENTS = ("E", "N", "h")


def _survey_files(survey: Any, *, lidar: bool = True) -> list[Path]:
    """survey.toml and every file it names (LiDAR tiles when *lidar*), for hashing."""
    return [survey.toml_path, *survey.files.values(), *(survey.lidar_paths if lidar else ())]


def _safe(name: str) -> str:
    """A control-set name usable in a folder name."""
    import re

    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip(".") or "set"


#: default of ``scale`` / ``contour_interval_m``: take them from survey.toml [assessment]
FROM_SURVEY = "survey"


def plan_pipeline(survey: Any, *, extracted_set: str = "lidar", scale: float | None | str = FROM_SURVEY,
                  contour_interval_m: float | None | str = FROM_SURVEY, figures: bool = False) -> list[Stage]:
    """The stages ``lidarcat run`` executes for a loaded survey, in order.

    Parameters
    ----------
    survey : lidarcat.Survey
    extracted_set : str
        Name of the control set made of the extracted LiDAR points (renamed
        ``<name>-extracted`` when the survey already has a set of that name).
    scale, contour_interval_m : float, None or FROM_SURVEY
        Map scale denominator and contour interval (m) of the check-point
        classification (PEC, the chi-square sigma0, the CE90 limit); default:
        survey.toml ``[assessment]`` (1:2000 and 2 m, as the thesis, when the
        table does not say); None: not applicable.
    figures : bool
        The extract stage also draws one figure per roof (``extract/figures/``:
        points by face, fitted planes, the vertex; thesis Figure 19).

    Returns
    -------
    list of Stage
        camera, extract, one adjust-SET and assess-SET per control set, one
        compare stage per pair (default set vs each other set), report.

    Raises
    ------
    SurveyError
        Two control sets whose names map to the same output folder.
    """
    files = _survey_files(survey, lidar=False)  # only the extraction reads the tiles
    judged = survey.assessment
    if scale == FROM_SURVEY:
        scale = judged.scale
    if contour_interval_m == FROM_SURVEY:
        contour_interval_m = judged.contour_interval_m
    files_lidar = _survey_files(survey)
    stages: list[Stage] = []

    has_pixels = bool(np.isfinite(survey.image_points.pixel_px).all(axis=1).any())
    stages.append(Stage(
        "camera", "camera", _stage_camera, inputs=lambda ctx: files,
        skip_reason=None if has_pixels else "image_points has no pixel coordinates (col_px, row_px)",
        description="interior orientation (eq. 01-07)"))

    can_extract = bool(survey.lidar_paths) and survey.extraction_jobs is not None
    if not can_extract:
        why = ("the survey has no LiDAR tiles ([files] lidar) and no extraction jobs"
               if not survey.lidar_paths and survey.extraction_jobs is None else
               "the survey has no LiDAR tiles ([files] lidar)" if not survey.lidar_paths else
               "the survey has no extraction jobs ([files] extraction_jobs)")
    set_names = list(survey.control_sets)
    default = survey.default_control or (set_names[0] if set_names else None)
    if default in set_names:
        set_names.remove(default)
        set_names.insert(0, default)
    ext_name = extracted_set if extracted_set not in survey.control_sets else f"{extracted_set}-extracted"
    stages.append(Stage(
        "extract", "extract", _stage_extract, inputs=lambda ctx: files_lidar,
        params={"set": ext_name, "figures": bool(figures)},
        skip_reason=None if can_extract else why,
        description="LiDAR roof vertices -> control points"))

    runs: list[tuple[str, bool]] = [(name, False) for name in set_names]
    if can_extract:
        runs.append((ext_name, True))
    folder_of: dict[str, str] = {}
    for name, _ in runs:  # every run needs folders (and stage records) of its own
        other = folder_of.setdefault(_safe(name), name)
        if other != name:
            raise SurveyError(f"{survey.files.get('control_sets', survey.toml_path)}: control sets "
                              f"{other!r} and {name!r} would share the output folder "
                              f"adjust-{_safe(name)}; rename one (letters, digits, _ . - are kept)")
    if not runs:
        stages.append(Stage("adjust", "adjust", _stage_adjust,
                            skip_reason="the survey defines no control set (control_sets.csv)"))
    for name, derived in runs:
        stages.append(Stage(
            f"adjust-{name}", f"adjust-{_safe(name)}", _stage_adjust,
            requires=("extract",) if derived else (),
            inputs=lambda ctx: files,
            params={"control": name, "derived": derived},
            description=f"bundle adjustment, control set {name}"))
    for name, derived in runs:
        n_check = None if derived else len(survey.control_sets[name].check)
        stages.append(Stage(
            f"assess-{name}", f"assess-{_safe(name)}", _stage_assess,
            requires=(f"adjust-{name}",) + (("extract",) if derived else ()),
            inputs=lambda ctx: files,
            params={"control": name, "derived": derived, "scale": scale,
                    "contour_interval_m": contour_interval_m, "alpha": judged.alpha,
                    "pec_class": judged.pec_class},
            skip_reason=f"control set {name} has no check points" if n_check == 0 else None,
            description=f"check-point accuracy, control set {name}"))
    pairs = [(runs[0][0], other) for other, _ in runs[1:]]
    for a, b in pairs:
        stages.append(Stage(
            f"compare-{a}-{b}", f"compare-{_safe(a)}-{_safe(b)}", _stage_compare,
            requires=(f"adjust-{a}", f"adjust-{b}"), params={"first": a, "second": b},
            description=f"differences of the runs {a} and {b}"))
    if len(runs) < 2:
        stages.append(Stage("compare", "compare", _stage_compare,
                            skip_reason="needs two control sets (runs) to compare; the survey has "
                                        f"{len(runs)}"))
    upstream = tuple(s.name for s in stages)
    stages.append(Stage("report", "report", _stage_report, uses=upstream,
                        inputs=lambda ctx: files, description="HTML / Markdown / JSON report"))
    return stages


def run_pipeline(
    survey_path: str | os.PathLike | None = None,
    outdir: str | os.PathLike | None = None,
    *,
    force: bool = False,
    progress: ProgressCallback | None = None,
    scale: float | None | str = FROM_SURVEY,
    contour_interval_m: float | None | str = FROM_SURVEY,
    figures: bool = False,
) -> PipelineResult:
    """Run the whole pipeline on a survey folder (``lidarcat run``).

    Parameters
    ----------
    survey_path : path or None
        The survey folder; None runs the embedded thesis block.
    outdir : path or None
        Output folder; default ``Survey.output_dir()`` (``SURVEY/out``, or
        ``./lidarcat-out`` for the embedded block).
    force : bool
        Recompute every stage even when its inputs are unchanged.
    progress : callable, optional
        ``progress(stage, done, total)``.
    scale, contour_interval_m : float, None or FROM_SURVEY
        Map scale denominator and contour interval (m) for the classification
        of the check points; default: survey.toml ``[assessment]`` (1:2000 and
        2 m, as the thesis, when it does not say); None: not applicable.
    figures : bool
        Write one extraction figure per roof into ``OUTDIR/extract/figures/``.

    Returns
    -------
    PipelineResult
        ``result.ok`` is False when a stage failed; ``OUTDIR/summary.json``
        holds ``result.summary``.

    Raises
    ------
    SurveyError
        The survey folder is invalid (nothing is run).
    """
    from .survey import Survey

    survey = Survey.load(survey_path)
    out = Path(survey.output_dir(outdir))
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "lidarcat.log").touch()
    except OSError as ex:
        raise LidarcatError(f"{out}: cannot write the output folder ({ex.strerror or ex}); "
                            f"choose another with -o/--outdir") from ex
    with folder_lock(out), _log_to(out / "lidarcat.log"):
        log.info("lidarcat %s run: survey %r (%s) -> %s%s", __version__, survey.name, survey.root,
                 out, " (forced)" if force else "")
        stages = plan_pipeline(survey, scale=scale, contour_interval_m=contour_interval_m, figures=figures)
        t0 = time.perf_counter()
        records = run_stages(stages, out, force=force, progress=progress,
                             values={"survey": survey, "plan": stages})
        summary = _summary(survey, out, records, time.perf_counter() - t0)
        write_json_atomic(out / "summary.json", summary)
        failed = [r.name for r in records if r.status == "failed"]
        if failed:
            log.error("run finished with failed stage(s): %s", ", ".join(failed))
        else:
            log.info("run finished: %s", ", ".join(f"{r.name} {r.status}" for r in records))
    return PipelineResult(out, tuple(records), summary)


def _results(records: Iterable[StageRecord]) -> dict[str, Any]:
    """``runs``, ``comparison`` and ``extraction`` of the done stages (summary.json and the report)."""
    runs: dict[str, Any] = {}
    comparison: dict[str, Any] = {}
    extraction = None
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
    return {"runs": runs, "comparison": comparison, "extraction": extraction}


def _summary(survey: Any, out: Path, records: Sequence[StageRecord], seconds: float) -> dict:
    report = next((r.result.get("index") for r in records if r.name == "report" and r.done), None)
    return {
        "lidarcat_version": __version__,
        "survey": {"name": survey.name, "root": str(survey.root), "crs": survey.crs,
                   "embedded": bool(survey.embedded)},
        "outdir": str(out),
        "ok": not any(r.status == "failed" for r in records),
        "failed": [r.name for r in records if r.status == "failed"],
        "stages": [r.to_dict() for r in records],
        "stages_ran": [r.name for r in records if r.status == "ran"],
        "stages_reused": [r.name for r in records if r.status == "reused"],
        "stages_skipped": [r.name for r in records if r.status == "skipped"],
        "seconds": round(seconds, 3),
        **_results(records),
        "report": report,
    }


# --------------------------------------------------------------------------- stage bodies

def _params(ctx: _Context) -> Mapping[str, Any]:
    assert ctx.stage is not None
    return ctx.stage.params


def _stage_camera(ctx: _Context, tmp: Path) -> dict:
    """Interior orientation of every pixel measurement (eq. 01-07) -> camera/corrected.csv."""
    from .survey import correct_measurements

    survey = ctx["survey"]
    corrected = correct_measurements(survey.toml_path)
    corrected.write_csv(tmp / "corrected.csv")
    result = dict(corrected.to_dict())
    # where the survey also gives corrected coordinates (the thesis prints them), compare
    ip = survey.image_points
    given = {(str(a), str(b)): xy for a, b, xy in zip(ip.photo, ip.point, ip.xy_mm)
             if np.isfinite(xy).all()}
    diffs = [np.abs(xy - given[(str(a), str(b))])
             for a, b, xy in zip(corrected.photo, corrected.point, corrected.xy_mm)
             if (str(a), str(b)) in given]
    if diffs:
        d = np.array(diffs)
        result["n_compared_with_file"] = len(d)
        result["max_abs_diff_file_mm"] = float(d.max())
    ctx.progress(1, 1)
    return result


def _stage_adjust(ctx: _Context, tmp: Path) -> dict:
    """Bundle adjustment of one control set -> eop.csv, points.csv, residuals.csv, summary.json."""
    from .bundle import adjust, problem_from_survey, write_adjustment
    from .survey import Survey

    par = _params(ctx)
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]
    problem = problem_from_survey(survey, control=par["control"])

    def prog(iteration: int, vtpv: float) -> None:
        ctx.progress(min(iteration, 49), 50)

    result = adjust(problem, variance_factor=survey.settings.variance_factor,
                    chi2_level=survey.settings.chi2_level, progress=prog)
    write_adjustment(result, tmp, extra={"crs": survey.crs, "survey": survey.name,
                                         "control_set": par["control"],
                                         "observations": survey.settings.observations})
    summ = result.summary()
    if not result.success:
        raise LidarcatError(f"adjustment with control set {par['control']!r} did not converge: "
                            f"{result.status} ({result.message}) after {result.n_iter} iterations")
    keys = ("dof", "vtpv", "sigma0_sq", "chi2_lower", "chi2_upper", "chi2_pass", "n_iterations",
            "converged", "n_photos", "n_points", "n_observations", "n_constraints", "status")
    return {"adjustment": {k: summ.get(k) for k in keys}, "control": par["control"],
            "derived_survey": bool(par.get("derived"))}


def _stats(d: np.ndarray) -> dict[str, float]:
    """mean, sample sd, RMSE and max |.| of the columns E, N, h (and planimetric resultant)."""
    out: dict[str, float] = {"n": int(len(d))}
    if not len(d):
        return out
    cols = {"E": d[:, 0], "N": d[:, 1], "h": d[:, 2], "planimetric": np.hypot(d[:, 0], d[:, 1])}
    for k, v in cols.items():
        out[f"mean_{k}_m"] = float(v.mean())
        out[f"std_{k}_m"] = float(v.std(ddof=1)) if len(v) > 1 else float("nan")
        out[f"rmse_{k}_m"] = float(np.sqrt(np.mean(v ** 2)))
        out[f"max_abs_{k}_m"] = float(np.abs(v).max())
    return out



def _stage_assess(ctx: _Context, tmp: Path) -> dict:
    """Check points of one run against the survey's ground points -> assessment.json, discrepancies.csv."""
    from ._io import write_csv_atomic
    from .accuracy import assess, read_points
    from .survey import Survey

    par = _params(ctx)
    name = par["control"]
    survey = Survey.load(ctx.folder("extract") / "survey") if par.get("derived") else ctx["survey"]
    cset = survey.control_set(name)
    gp = survey.ground_points
    reference = {"point": [str(p) for p in gp.point], "E": gp.enh_m[:, 0], "N": gp.enh_m[:, 1],
                 "h": gp.enh_m[:, 2], "sd_E": gp.sd_m[:, 0], "sd_N": gp.sd_m[:, 1], "sd_h": gp.sd_m[:, 2]}
    adjusted = ctx.folder(f"adjust-{name}") / "points.csv"
    adjusted_ids = set(read_points(adjusted).ids)
    checks = [str(c) for c in cset.check if str(c) in adjusted_ids]
    missing = [str(c) for c in cset.check if str(c) not in adjusted_ids]
    if not checks:
        raise LidarcatError(f"control set {name!r}: none of its check points was adjusted "
                            f"(measured on no photo): {', '.join(missing)}")
    cov_path = ctx.folder(f"adjust-{name}") / "check_covariance.csv"
    cov = None
    if cov_path.is_file():
        from .bundle import read_point_covariance

        cov = read_point_covariance(cov_path)
    a = assess(adjusted, reference, points=checks, scale=par.get("scale"),
               contour_interval_m=par.get("contour_interval_m"), alpha=par.get("alpha", 0.10),
               pec_class=par.get("pec_class", "A"), adjusted_cov=cov)
    doc = a.to_dict()
    doc["control_set"] = name
    doc["check_points_not_adjusted"] = missing
    write_json_atomic(tmp / "assessment.json", doc)
    rows = a.point_rows()
    cols = ["point", "E_ref", "N_ref", "h_ref", "E_adj", "N_adj", "h_adj", "dE", "dN", "dh", "dP"]
    write_csv_atomic(tmp / "discrepancies.csv", cols, [[r[c] for c in cols] for r in rows],
                     comments=[f"Check points of control set {name}: discrepancies reference minus "
                               "adjusted (thesis Table 7 convention), metres."])
    from .report import write_report

    write_report(tmp / "report.html", assessment=a, adjustment_dir=ctx.folder(f"adjust-{name}"),
                 survey=survey, title=f"lidarcat: {survey.name}, control set {name}")
    # the assessment's own summary, under the key names of _stats
    check: dict[str, Any] = {"n": len(checks)}
    for c in ("E", "N", "h", "planimetric"):
        check.update({f"{k}_{c}_m": a.summary[c][k] for k in ("mean", "std", "rmse", "max_abs")})
    cons = a.tests.get("consistency", {}).get("ENh")
    if cons is not None and cons.applicable:
        check["consistency"] = {"chi2": cons.statistic, "df": cons.details["df"], "alpha": cons.alpha,
                                "lower": cons.details["lower"], "upper": cons.details["upper"],
                                "passed": cons.passed, "side": cons.details["side"]}
    tests = {t: {c: r.get("passed") for c, r in comps.items()} for t, comps in doc["tests"].items()}
    classes = {k: v.get("class", v.get("classes")) for k, v in doc["standards"].items()}
    return {"check": check, "tests_passed": tests, "standards": classes, "control": name,
            "n_missing": len(missing)}


_EOP = ("X0", "Y0", "Z0", "omega", "phi", "kappa")
_EOP_DIFF = ("dX0", "dY0", "dZ0", "domega", "dphi", "dkappa")


def _read_photo_rows(path: Path, names: Sequence[str]) -> dict[str, np.ndarray]:
    """``{photo: values of the columns *names*}`` of a per-photo CSV (eop.csv, eop_differences.csv)."""
    from ._io import read_csv_table

    t = read_csv_table(path, required=("photo", *names), allow_extra=True)
    cols = np.column_stack([t.floats(c) for c in names])
    return {p: cols[i] for i, p in enumerate(t.column("photo"))}


def _stage_compare(ctx: _Context, tmp: Path) -> dict:
    """Differences between two runs (thesis section 4.4): first minus second."""
    from ._io import write_csv_atomic
    from .accuracy import read_points

    par = _params(ctx)
    a, b = par["first"], par["second"]
    fa, fb = ctx.folder(f"adjust-{a}"), ctx.folder(f"adjust-{b}")
    ea, eb = _read_photo_rows(fa / "eop.csv", _EOP), _read_photo_rows(fb / "eop.csv", _EOP)
    photos = [p for p in ea if p in eb]
    d_eo = np.array([ea[p] - eb[p] for p in photos]).reshape(-1, 6)
    eo_names = list(_EOP_DIFF)
    write_csv_atomic(tmp / "eop_differences.csv", ["photo"] + eo_names,
                     [[p, *d] for p, d in zip(photos, d_eo)],
                     comments=[f"Exterior orientation of run {a} minus run {b}: metres and degrees."])
    pa, pb = read_points(fa / "points.csv"), read_points(fb / "points.csv")
    ra = dict(zip(pa.ids, pa.roles or [""] * len(pa.ids)))
    rb = dict(zip(pb.ids, pb.roles or [""] * len(pb.ids)))
    ia, ib = pa.index(), pb.index()
    free = [q for q in pa.ids if q in ib and ra[q] != "control" and rb[q] != "control"]
    d_pt = np.array([pa.xyz[ia[q]] - pb.xyz[ib[q]] for q in free]).reshape(-1, 3)
    write_csv_atomic(tmp / "point_differences.csv",
                     ["point", f"role_{a}", f"role_{b}", "dE", "dN", "dh", "dP"],
                     [[q, ra[q], rb[q], *d, float(np.hypot(d[0], d[1]))]
                      for q, d in zip(free, d_pt)],
                     comments=[f"Points free (not control) in both runs: run {a} minus run {b}, metres."])
    eo_stats = {}
    for k, nm in enumerate(eo_names):
        v = d_eo[:, k]
        if len(v):
            eo_stats[nm] = {"mean": float(v.mean()), "rmse": float(np.sqrt(np.mean(v ** 2))),
                            "max_abs": float(np.abs(v).max())}
    result = {"first": a, "second": b, "sign": f"{a} minus {b}", "n_photos": len(photos),
              "eop": eo_stats, "points": _stats(d_pt), "n_points": len(free)}
    write_json_atomic(tmp / "comparison.json", result)
    return result


def _stage_extract(ctx: _Context, tmp: Path) -> dict:
    """Extract the roof vertices of the survey's jobs; write control.csv and a derived survey.

    The derived survey (``extract/survey/``) is the original one plus the
    extracted points as ground points (source ``lidar``, their propagated
    standard deviations) and a control set of them, in which every other
    ground point is a check point.
    """
    from .extraction import write_control_csv, write_figures, write_planes_csv

    survey = ctx["survey"]
    par = _params(ctx)
    name = par["set"]
    points = _extract_jobs(survey, ctx)
    write_control_csv(tmp / "control.csv", points, comments=[
        f"Roof vertices extracted from the LiDAR tiles of survey {survey.name} "
        f"({survey.extraction_jobs.name}); metres, sds propagated from the planes."])
    write_planes_csv(tmp / "planes.csv", points)
    ok = [cp for cp in points if cp and np.all(np.isfinite(cp.sd_m)) and np.all(cp.sd_m > 0)]
    if not ok:
        raise LidarcatError(f"no roof vertex could be extracted from {survey.extraction_jobs} "
                            f"({len(points)} jobs; see {ctx.stage.folder}/control.csv for the reasons)"
                            if points else f"{survey.extraction_jobs}: no extraction job")
    unmeasured = _write_derived_survey(survey, ok, name, tmp / "survey")
    if unmeasured:
        log.warning("extracted point(s) %s: measured on no photo (%s), so they cannot control the "
                    "block; check the ids in %s", ", ".join(unmeasured), survey.files["image_points"],
                    survey.extraction_jobs)
    if par.get("figures"):
        write_figures(tmp / "figures", points)
    status: dict[str, int] = {}
    for cp in points:
        status[cp.status] = status.get(cp.status, 0) + 1
    return {"n_jobs": len(points), "n_ok": len(ok), "statuses": status, "control_set": name,
            "not_measured": unmeasured,
            "points": {cp.point_id: {"status": cp.status, "n_planes": int(cp.n_planes),
                                     "sd_m": [float(v) for v in cp.sd_m]} for cp in points}}


def _extract_jobs(survey: Any, ctx: _Context) -> list:
    """ControlPoints of every extraction job of *survey* (failed jobs included, falsy)."""
    from .extraction import extract_batch, read_jobs

    jobs = read_jobs(survey.extraction_jobs)
    done = [0]

    def tick(n: int = 1) -> None:
        done[0] += n
        ctx.progress(done[0], len(jobs) + 1)

    ctx.progress(0, len(jobs) + 1)
    # the tile index (with the block index of each LAZ tile) persists across runs
    return list(extract_batch(jobs, lidar=list(survey.lidar_paths),
                              crs=survey.lidar_crs or survey.crs, progress=tick,
                              index_cache=ctx.outdir / ".lidar_index.json"))


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} to TOML")


def _write_derived_survey(survey: Any, points: Sequence[Any], set_name: str, folder: Path) -> list[str]:
    """A copy of *survey* whose ground points and control sets include the extracted points.

    Returns the ids of extracted points that no photo measures (they cannot control the block).
    """
    import shutil
    import tomllib

    from ._io import read_csv_table, write_csv_atomic, write_text_atomic

    folder.mkdir(parents=True, exist_ok=True)
    data = tomllib.loads(survey.toml_path.read_text(encoding="utf-8-sig"))
    new_files: dict[str, str] = {}
    for key in ("camera", "photos", "image_points"):
        src = survey.files[key]
        shutil.copyfile(src, folder / f"{key}{src.suffix}")
        new_files[key] = f"{key}{src.suffix}"
    measured = set(survey.image_points.point.tolist())
    ids = []
    for cp in points:
        pid = str(cp.point_id)
        if pid not in measured and pid[:1] in "Pp" and pid[1:] in measured:
            pid = pid[1:]  # thesis job files name point 704 "P704"
        ids.append(pid)
    extracted = dict(zip(ids, points))
    gp = survey.ground_points
    rows = [[str(q), *enh, *sd, str(src)] for q, enh, sd, src in
            zip(gp.point, gp.enh_m, gp.sd_m, gp.source) if str(q) not in extracted]
    for pid, cp in extracted.items():
        rows.append([pid, *cp.enh_m, *cp.sd_m, "lidar"])
    write_csv_atomic(folder / "ground_points.csv", ["point", "E", "N", "h", "sd_E", "sd_N", "sd_h", "source"],
                     rows, comments=[f"Ground points of {survey.name} plus the roof vertices extracted "
                                     "by lidarcat run (source lidar)."])
    cs_rows = []
    if "control_sets" in survey.files:
        t = read_csv_table(survey.files["control_sets"], required=("set", "point", "role"),
                           optional=("sd_E", "sd_N", "sd_h"))
        for row in t.rows:
            d = dict(zip(t.header, row))
            cs_rows.append([d["set"], d["point"], d["role"], d.get("sd_E", ""), d.get("sd_N", ""),
                            d.get("sd_h", "")])
    exclude = survey.settings.exclude_points
    for pid in extracted:
        cs_rows.append([set_name, pid, "control", "", "", ""])
    for r in rows:
        if r[0] not in extracted and r[0] not in exclude:
            cs_rows.append([set_name, r[0], "check", "", "", ""])
    write_csv_atomic(folder / "control_sets.csv", ["set", "point", "role", "sd_E", "sd_N", "sd_h"],
                     cs_rows, comments=[f"Control sets of {survey.name}; set {set_name}: the extracted "
                                        "roof vertices as control, every other ground point as check."])
    new_files["ground_points"] = "ground_points.csv"
    new_files["control_sets"] = "control_sets.csv"
    sv = dict(data.get("survey", {}))
    sv["description"] = (sv.get("description", "")
                         + " [with the LiDAR control extracted by lidarcat run]").strip()
    lines = ["# Derived by lidarcat run: the survey plus the extracted LiDAR control points.", "", "[survey]"]
    lines += [f"{k} = {_toml_value(v)}" for k, v in sv.items()]
    lines += ["", "[files]"] + [f"{k} = {_toml_value(v)}" for k, v in new_files.items()]
    for table in ("adjustment", "assessment"):  # [lidar] is left out with the tiles
        if data.get(table):
            lines += ["", f"[{table}]"] + [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    write_text_atomic(folder / "survey.toml", "\n".join(lines) + "\n")
    return [pid for pid in extracted if pid not in measured]


def _stage_report(ctx: _Context, tmp: Path) -> dict:
    """The pipeline report: index.html / index.md / report.json (+ per-run reports)."""
    survey = ctx["survey"]
    plan: list[Stage] = ctx["plan"]
    rows = []
    for st in plan:
        if st.name == "report":
            continue
        rec = ctx.records.get(st.name)
        state = "done" if rec and rec.done else rec.status if rec else "not run"
        rows.append({"stage": st.name, "what": st.description, "state": state,
                     "reason": rec.reason if rec and not rec.done else ""})
    doc = {"survey": survey.name, "stages": rows,
           **_results(ctx.records[st.name] for st in plan if st.name in ctx.records)}
    doc["reports"] = {name: f"../{run['report']}" for name, run in doc["runs"].items()
                      if "report" in run and (ctx.outdir / run["report"]).is_file()}
    for name, cmp_ in doc["comparison"].items():
        eo_path = ctx.folder(f"compare-{name}") / "eop_differences.csv"
        if eo_path.is_file() and cmp_.get("n_photos", 0) <= 50:
            cmp_["eop_per_photo"] = {p: v.tolist() for p, v in _read_photo_rows(eo_path, _EOP_DIFF).items()}
    write_json_atomic(tmp / "report.json", doc)
    md = _report_markdown(doc)
    from ._io import write_text_atomic

    write_text_atomic(tmp / "index.md", md)
    write_text_atomic(tmp / "index.html", _markdown_to_html(md, f"lidarcat report: {survey.name}"))
    return {"index": "report/index.html", "n_stages_done": sum(r["state"] == "done" for r in rows)}


def _report_markdown(doc: Mapping[str, Any]) -> str:
    lines = [f"# lidarcat report: {doc['survey']}", "", "## Stages", "",
             "| stage | what | state | reason |", "|---|---|---|---|"]
    for r in doc["stages"]:
        lines.append(f"| {r['stage']} | {r['what']} | {r['state']} | {r['reason']} |")
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
                         + " | ".join(_num(v, 3) for v in sd) + " |")
    if doc.get("reports"):
        lines += ["", "## Accuracy reports", ""]
        lines += [f"- [control set {k}]({v})" for k, v in doc["reports"].items()]
    for name, run in doc["runs"].items():
        adj = run.get("adjustment") or {}
        lines += ["", f"## Run {name}", "",
                  f"dof {adj.get('dof')}, v'Pv {_num(adj.get('vtpv'), 2)}, "
                  f"sigma0^2 {_num(adj.get('sigma0_sq'), 3)}, chi-square test "
                  f"[{_num(adj.get('chi2_lower'), 2)}, {_num(adj.get('chi2_upper'), 2)}]: "
                  f"{'passed' if adj.get('chi2_pass') else 'failed'}"]
        chk = run.get("check")
        if chk:
            lines += ["", "| check points, reference minus adjusted (m) | mean | std | RMSE | max abs |",
                      "|---|---|---|---|---|"]
            for c in ("E", "N", "h", "planimetric"):
                lines.append(f"| {c} (n={chk.get('n')}) | {_num(chk.get(f'mean_{c}_m'), 3)} | "
                             f"{_num(chk.get(f'std_{c}_m'), 3)} | {_num(chk.get(f'rmse_{c}_m'), 3)} | "
                             f"{_num(chk.get(f'max_abs_{c}_m'), 3)} |")
            cons = chk.get("consistency")
            if cons:
                lines += ["", f"Discrepancies against the precision the adjustment claims (joint "
                              f"covariance of the check points + their reference sds): d'C^-1 d = "
                              f"{_num(cons['chi2'], 1)} on {cons['df']} degrees of freedom, "
                              f"{1 - cons['alpha']:.0%} interval [{_num(cons['lower'], 1)}, "
                              f"{_num(cons['upper'], 1)}]: {'passed' if cons['passed'] else 'failed'}"
                              + {"below": " (smaller discrepancies than claimed: the precision is pessimistic).",
                                 "above": " (larger discrepancies than claimed: look for blunders, model "
                                          "errors or optimistic control sds)."}.get(cons.get("side"), ".")]
    for pair, cmp_ in doc["comparison"].items():
        pts = cmp_.get("points", {})
        lines += ["", f"## Comparison {cmp_.get('sign', pair)}", "",
                  f"{cmp_.get('n_photos')} photos, {cmp_.get('n_points')} points free in both runs. "
                  "Metres for positions, degrees for angles.", "",
                  "| difference | mean | RMSE | max abs |", "|---|---|---|---|"]
        for k, v in cmp_.get("eop", {}).items():
            lines.append(f"| {k} | {_num(v['mean'], 4)} | {_num(v['rmse'], 4)} | {_num(v['max_abs'], 4)} |")
        for c in ("E", "N", "h"):
            if f"mean_{c}_m" in pts:
                lines.append(f"| d{c} (points) | {_num(pts[f'mean_{c}_m'], 3)} | "
                             f"{_num(pts[f'rmse_{c}_m'], 3)} | {_num(pts[f'max_abs_{c}_m'], 3)} |")
        per_photo = cmp_.get("eop_per_photo")
        if per_photo:
            lines += ["", "| photo | dX0 (m) | dY0 (m) | dZ0 (m) | domega (deg) | dphi (deg) "
                      "| dkappa (deg) |",
                      "|---|---|---|---|---|---|---|"]
            for ph, d in per_photo.items():
                lines.append(f"| {ph} | " + " | ".join(_num(v, 3) for v in d[:3]) + " | "
                             + " | ".join(_num(v, 4) for v in d[3:]) + " |")
    return "\n".join(lines) + "\n"


def _num(v: Any, nd: int) -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{nd}f}"


def _markdown_to_html(md: str, title: str) -> str:
    """A tiny Markdown subset (headings, tables, paragraphs) as self-contained HTML."""
    import html
    import re

    def inline(text: str) -> str:
        return re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r"<a href='\2'>\1</a>", html.escape(text, quote=False))

    out = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto}"
           "table{border-collapse:collapse}td,th{border:1px solid #999;padding:2px 8px}</style>",
           "</head><body>"]
    in_table = False
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            if not in_table:
                out.append("<table>")
                in_table = True
                out.append("<tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("#"):
            level = len(line) - len(line.lstrip("#"))
            out.append(f"<h{level}>{html.escape(line[level:].strip())}</h{level}>")
        elif line.startswith("- "):
            out.append(f"<ul><li>{inline(line[2:])}</li></ul>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    if in_table:
        out.append("</table>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"
