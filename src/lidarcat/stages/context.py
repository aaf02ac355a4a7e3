"""What a stage sees when ``lidarcat run`` runs it: :class:`StageContext`.

The stages know this small type only; the generic runner
(:mod:`lidarcat.pipeline.runner`) builds it and fills in the records of the
stages that ran, so the imports go ``pipeline -> stages``, never back.
A stage record is anything with ``folder``, ``status``, ``done``, ``result``
and ``reason`` (:class:`lidarcat.pipeline.runner.StageRecord`); a stage
(``ctx.stage``) anything with ``name``, ``folder`` and ``params``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

__all__ = ["StageContext", "ProgressCallback", "failed_tests"]

#: ``progress(stage, done, total)``: called with ``done == 0`` when a stage
#: starts and ``done == total`` when it ends; stages that know their size call
#: it in between.
ProgressCallback = Callable[[str, int, int], None]


def failed_tests(records: Iterable[Any]) -> list[str]:
    """``"stage: test"`` of every ``failed_tests`` entry in the results of the done *records*."""
    return [f"{r.name}: {t}" for r in records if r.done for t in r.result.get("failed_tests", ())]


class StageContext:
    """What a stage sees: output folder, earlier records, shared values.

    Parameters
    ----------
    outdir : Path
        The pipeline's output folder.
    values : mapping, optional
        Shared values (``ctx["survey"]``, ``ctx["plan"]``).
    progress : callable, optional
        ``progress(stage, done, total)``.
    """

    def __init__(self, outdir: Path, values: Mapping[str, Any] | None = None,
                 progress: ProgressCallback | None = None):
        self.outdir = outdir
        self.records: dict[str, Any] = {}
        self.values: dict[str, Any] = dict(values or {})
        self.progress_callback = progress
        self.current: str | None = None
        self.stage: Any = None

    def folder(self, stage: str) -> Path:
        """Final output folder of an earlier stage."""
        return self.outdir / self.records[stage].folder

    @property
    def params(self) -> Mapping[str, Any]:
        """Parameters of the running stage (``Stage.params``)."""
        assert self.stage is not None
        return self.stage.params

    def result(self, stage: str) -> Mapping[str, Any]:
        """The result dict of an earlier stage."""
        return self.records[stage].result

    def done(self, stage: str) -> bool:
        """True when *stage* ran or was reused in this run."""
        return stage in self.records and self.records[stage].done

    def progress(self, done: int, total: int) -> None:
        """Report progress of the current stage."""
        if self.progress_callback is not None and self.current is not None:
            self.progress_callback(self.current, done, total)

    def __getitem__(self, key: str) -> Any:
        return self.values[key]
