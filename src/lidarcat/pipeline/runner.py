"""The generic stage runner: content-hash caching, atomic outputs, records, log file.

A :class:`Stage` names an output folder, a ``run(ctx, tmpdir) -> dict``
function, the stages it requires or uses, its input files and parameters.
:func:`run_stages` runs a sequence of them in order.  Every stage records the
SHA-256 of its inputs (file contents, parameters, lidarcat version and source
code, and the output digests of the stages it depends on) in
``OUTDIR/.stages/<stage>.json``; a later run with unchanged inputs reuses the
stage (status ``reused``), ``force=True`` recomputes everything.  A stage
writes its folder through :func:`lidarcat._util.atomic_dir` and its record only
afterwards, so an interrupted run leaves no half-written file and the next run
redoes exactly the unfinished stages (``.*.part`` leftovers of a killed run are
removed first).  A failing stage does not stop the others; the stages that
require it are skipped.  The output folder is a boundary: a stage folder, the
records or the summary that is a symbolic link stops the run before anything is
written, every write of a stage is checked to stay inside the folder
(:func:`lidarcat._util.output_root`), and stale outputs are removed without
following links (:func:`lidarcat._util.remove_below`).

Nothing here knows about photogrammetry: the lidarcat stages are in
:mod:`lidarcat.stages` and their order in :mod:`lidarcat.pipeline.plan`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import re
import time
import traceback
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from .. import __version__
from .._util import atomic_dir, dumps_json, inside, output_root, remove_below, write_json_atomic
from ..errors import LidarcatError
from ..stages.context import ProgressCallback, failed_tests
from ..stages.context import StageContext as Context

__all__ = ["STATUSES", "ProgressCallback", "Stage", "StageRecord", "PipelineResult", "Context",
           "run_stages", "safe_name", "log_to", "failed_tests"]

log = logging.getLogger(__name__)

#: the statuses a stage can end with
STATUSES = ("ran", "reused", "skipped", "failed")


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
        JSON-serialisable dict of key numbers; its list ``failed_tests``
        (one line each) names statistical tests the outputs fail.  *ctx* is a :class:`Context`
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
        """True when no stage failed and no statistical test of a stage failed (see :attr:`status`)."""
        return self.status == "ok"

    @property
    def failed(self) -> list[str]:
        """Names of the failed stages."""
        return [s.name for s in self.stages if s.status == "failed"]

    @property
    def tests_failed(self) -> list[str]:
        """``"stage: what failed"`` for every statistical test a done stage reports as failed
        (its result's ``failed_tests``): the stage ran, its outputs exist, but they fail a test."""
        return failed_tests(self.stages)

    @property
    def status(self) -> str:
        """``ok``, ``test failed`` (every stage ran or was skipped, a statistical test failed) or
        ``stage failed``."""
        return "stage failed" if self.failed else "test failed" if self.tests_failed else "ok"

    def stage(self, name: str) -> StageRecord:
        """The record of stage *name* (KeyError when not planned)."""
        for s in self.stages:
            if s.name == name:
                return s
        raise KeyError(f"no stage {name!r}; stages: {', '.join(s.name for s in self.stages)}")

    def to_dict(self) -> dict[str, Any]:
        return dict(self.summary)


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
        root = Path(__file__).resolve().parent.parent  # the lidarcat package
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
    return outdir / _RECORD_DIR / f"{safe_name(name)}.json"


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
        try:
            inside(outdir, p)  # a record shipped with the survey may name files elsewhere: not ours
        except LidarcatError:
            return False
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

    Raises
    ------
    ProductError
        A stage folder, ``.stages`` or ``summary.json`` is a symbolic link (or lies outside *outdir*):
        nothing is run.
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    _DIGESTS.clear()  # file digests are memoised within one run only
    ctx = Context(outdir, values, progress)
    names = [s.name for s in stages]
    if len(set(names)) != len(names):
        raise ValueError(f"duplicate stage names in {names}")
    # the output folder is a boundary: no stage folder (nor the records) may leave it or be a link
    # (a survey that ships out/<stage> as a link to elsewhere would have its target cleared)
    for p in (*(outdir / st.folder for st in stages), outdir / _RECORD_DIR, outdir / "summary.json"):
        inside(outdir, p)
    with output_root(outdir):
        return _run_all(stages, outdir, ctx, force)


def _run_all(stages: Sequence[Stage], outdir: Path, ctx: Context, force: bool) -> list[StageRecord]:
    records: list[StageRecord] = []
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


def _run_one(stage: Stage, ctx: Context, force: bool) -> StageRecord:
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
        if ctx.progress_callback:
            ctx.progress_callback(stage.name, 1, 1)
        return StageRecord(stage.name, stage.folder, "reused", "inputs unchanged", 0.0, digest,
                           tuple(old.get("outputs", ())), old.get("result", {}))

    # invalidate the old record first: an interruption below must not leave a
    # record that claims the (partly replaced) outputs are complete
    with contextlib.suppress(FileNotFoundError):
        _record_path(outdir, stage.name).unlink()
    log.info("stage %s: running", stage.name)
    if ctx.progress_callback:
        ctx.progress_callback(stage.name, 0, 1)
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
            with contextlib.suppress(LidarcatError):  # a link planted meanwhile: refused, never followed
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
    if ctx.progress_callback:
        ctx.progress_callback(stage.name, 1, 1)
    return rec


def _remove_parts(parent: Path, prefix: str) -> None:
    """Remove temporary ``.<prefix>*.part`` files and folders in *parent* (see lidarcat._util)."""
    import shutil

    if parent.is_symlink() or not parent.is_dir():
        return  # a link is refused by run_stages' check; never glob through one
    for p in parent.glob(f".{prefix}*.part"):
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:  # a file, or a link (removed as a name: its target is left alone)
            with contextlib.suppress(FileNotFoundError):
                p.unlink()


def _clear_folder(folder: Path, keep: Iterable[str]) -> None:
    """Remove files under *folder* (a stage's own output folder) except *keep* (relative paths)."""
    if folder.name in ("", ".", ".."):
        return
    remove_below(folder, keep)  # checked against the output root; never follows a link


def _rel(folder: str, names: Iterable[str]) -> list[str]:
    return [str(Path(folder) / n) if folder not in ("", ".") else n for n in names]


# --------------------------------------------------------------------------- logging

@contextlib.contextmanager
def log_to(path: Path):
    inside(Path(path).parent, path)  # the log of an output folder: never appended through a link
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


def safe_name(name: str) -> str:
    """A control-set name usable in a folder name."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip(".") or "set"
