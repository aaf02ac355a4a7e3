"""Reusable click options and arguments shared by the commands."""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Iterator
from typing import Any

import click

from .._util import dumps_json

__all__ = ["json_opt", "survey_arg", "echo_json", "progress_bar", "workers_option", "scheduler_option",
           "FiniteRange", "POSITIVE", "NON_NEGATIVE"]

json_opt = click.option("--json", "as_json", is_flag=True,
                        help="Print results as one JSON object (sorted keys) instead of text.")


survey_arg = click.argument("survey", required=False, type=click.Path(exists=True),
                            metavar="[SURVEY]")


def echo_json(obj) -> None:
    """Print *obj* as sorted, indented JSON on stdout."""
    click.echo(dumps_json(obj))


class FiniteRange(click.FloatRange):
    """A click FloatRange that also refuses nan and inf (FloatRange lets nan through every bound)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        rv = super().convert(value, param, ctx)
        if not math.isfinite(rv):
            self.fail(f"{rv} is not a finite number.", param, ctx)
        return rv


#: option type of sizes, distances and thresholds that must be > 0 (cells, windows, intervals), finite
POSITIVE = FiniteRange(min=0, min_open=True)
#: option type of finite values >= 0 (overlaps, margins)
NON_NEGATIVE = FiniteRange(min=0)


@contextlib.contextmanager
def progress_bar(length: int, label: str, *, enabled: bool = True, **kw: Any) -> Iterator[Any]:
    """A click progress bar on stderr, or None when stderr is not a terminal (or not *enabled*).

    Yields the bar (``bar.update(n)``, ``bar.pos``); it is finished on exit,
    also when the command fails or is interrupted.
    """
    if not (enabled and sys.stderr.isatty()):
        yield None
        return
    with click.progressbar(length=max(int(length), 1), label=label, file=sys.stderr, **kw) as bar:
        yield bar


# Dask options of the tile-parallel commands (lidar ground/dtm/dsm, extract --find)
workers_option = click.option(
    "--workers", type=click.IntRange(1), default=None, metavar="N",
    help="Run tile by tile (--find: block by block) on a local Dask cluster of N worker processes (pip install "
         "'lidarcat[cluster]'). Default: serial, in this process. Results are identical.")
scheduler_option = click.option(
    "--scheduler", default=None, metavar="ADDRESS",
    help="Run on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 (every worker must see the "
         "same paths). Wins over --workers.")
