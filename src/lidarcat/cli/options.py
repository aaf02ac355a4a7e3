"""Reusable click options and arguments shared by the commands."""

from __future__ import annotations

import click

from .._io import dumps_json

__all__ = ["json_opt", "survey_arg", "echo_json"]

json_opt = click.option("--json", "as_json", is_flag=True,
                        help="Print results as one JSON object (sorted keys) instead of text.")


survey_arg = click.argument("survey", required=False, type=click.Path(exists=True),
                            metavar="[SURVEY]")


def echo_json(obj) -> None:
    """Print *obj* as sorted, indented JSON on stdout."""
    click.echo(dumps_json(obj))
