"""Reusable click options and arguments shared by the commands."""

from __future__ import annotations

import contextlib
import math
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

import click

from .._util import dumps_json

F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["json_opt", "json_option", "output_option", "crs_option", "overwrite_option", "survey_arg", "echo_json",
           "progress_bar", "workers_option", "scheduler_option", "tile_sources", "FiniteRange", "POSITIVE",
           "NON_NEGATIVE"]

# The one option registry: ``-o/--output``, ``--crs``, ``--json`` and ``--overwrite`` are spelled here only;
# a command passes its own help (what it writes) and click settings.


def output_option(*, outdir: bool = False, **kw: Any) -> Callable[[F], F]:
    """``-o/--output``: what the command writes.

    With *outdir* the parameter is ``outdir`` and ``--outdir`` is accepted too
    (the commands that write a folder: adjust, ortho, run, demo).
    """
    names = ("-o", "--output", "--outdir", "outdir") if outdir else ("-o", "--output", "output")
    return click.option(*names, **kw)


def json_option(help: str = "Print results as one JSON object (sorted keys) instead of text.") -> Callable[[F], F]:
    """``--json``: print the result as JSON (parameter ``as_json``)."""
    return click.option("--json", "as_json", is_flag=True, help=help)


def crs_option(help: str = ("CRS of files that carry none, e.g. EPSG:7415 (RD New + NAP, the AHN3 tiles) or "
                            "EPSG:31982 (SIRGAS 2000 / UTM 22S). Default: the file's own, or the survey's "
                            "[lidar] crs."), **kw: Any) -> Callable[[F], F]:
    """``--crs``: the CRS of inputs that carry none (parameter ``crs``)."""
    return click.option("--crs", default=None, metavar="CRS", help=help, **kw)


def overwrite_option(help: str = "Replace existing outputs.") -> Callable[[F], F]:
    """``--overwrite`` (also ``--force``): replace what is there (parameter ``force``)."""
    return click.option("--overwrite", "--force", "force", is_flag=True, help=help)


json_opt = json_option()


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


def tile_sources(paths: Sequence[str], crs: str | None) -> tuple[list[Path], str | None, Path | None]:
    """Expand TILE/PATH arguments; a survey folder contributes its tiles and [lidar] crs.

    Returns (tile paths, CRS: *crs* or the survey's, the survey's root or None).
    """
    from ..lidar import expand_paths

    out: list[Path] = []
    survey_root: Path | None = None
    plain: list[str] = []
    for p in paths:
        if Path(p).is_dir() and (Path(p) / "survey.toml").is_file():
            files, survey_crs, survey_root = _survey_lidar(Path(p))
            out.extend(files)
            crs = crs or survey_crs
        else:
            plain.append(p)
    if plain:
        out.extend(expand_paths(plain))
    if not out:
        raise click.UsageError("no LiDAR files given")
    return out, crs, survey_root


def _survey_lidar(folder: Path) -> tuple[list[Path], str | None, Path]:
    """(tile paths, [lidar] crs, root) of a survey folder."""
    from ..errors import SurveyError
    from ..lidar.readers import ASCII_SUFFIXES, LAS_SUFFIXES
    from ..survey.folder import Survey

    s = Survey.load(folder)
    files = [f for f in s.lidar_paths if Path(f).suffix.lower() in LAS_SUFFIXES + ASCII_SUFFIXES]
    if not files:
        raise SurveyError(f"{folder / 'survey.toml'}: no LiDAR tiles; add lidar = [\"lidar/*.laz\"] "
                          "to [files]")
    return files, s.lidar_crs, Path(s.root)
