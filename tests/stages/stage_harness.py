"""What the one-code-path tests share: a stage context as the runner builds it, a folder's files."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarcat.stages.context import StageContext


@dataclass
class StageStub:
    """The planned stage as the runner hands it to a stage: name, output folder, parameters."""
    name: str
    folder: str
    params: dict[str, Any] = field(default_factory=dict)


@dataclass
class RecordStub:
    """A finished earlier stage whose output folder a stage reads."""
    folder: str
    status: str = "ran"
    result: dict[str, Any] = field(default_factory=dict)

    @property
    def done(self) -> bool:
        return True


def stage_context(outdir: Path, stage: StageStub, survey: Any, records: dict[str, str] | None = None) -> StageContext:
    """The :class:`StageContext` the runner would give *stage* of a run into *outdir*."""
    ctx = StageContext(outdir, {"survey": survey})
    ctx.stage, ctx.current = stage, stage.name
    ctx.records = {k: RecordStub(v) for k, v in (records or {}).items()}
    return ctx


def folder_files(folder: Path, skip: tuple[str, ...] = (), skip_suffix: tuple[str, ...] = ()) -> dict[str, bytes]:
    """Every file below *folder* (relative path -> bytes), less the names in *skip* and those ending in *skip_suffix*."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in skip and not (skip_suffix and p.name.endswith(skip_suffix))}

