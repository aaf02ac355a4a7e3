"""Reusable click options and arguments shared by the commands."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from typing import Any

import click

from .._io import dumps_json

__all__ = ["json_opt", "survey_arg", "echo_json", "progress_bar"]

json_opt = click.option("--json", "as_json", is_flag=True,
                        help="Print results as one JSON object (sorted keys) instead of text.")


survey_arg = click.argument("survey", required=False, type=click.Path(exists=True),
                            metavar="[SURVEY]")


def echo_json(obj) -> None:
    """Print *obj* as sorted, indented JSON on stdout."""
    click.echo(dumps_json(obj))


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
