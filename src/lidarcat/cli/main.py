"""The ``lidarcat`` command group.

Subcommands are listed in pipeline order and imported lazily, so that
``lidarcat --help`` is fast and a broken optional stage never prevents the
others from running.  The CLI never shows a traceback: library errors
(:class:`lidarcat.errors.LidarcatError`) become one line ``Error: ...`` with exit
code 2 (bad input); an ``OSError`` the library did not wrap (disk full, permission
denied, a read-only output folder) becomes one line ``Error: FILE: reason`` with
exit code 2, FILE being the output the command was writing (never its temporary
``.NAME.*.part`` sibling: outputs are written atomically, so nothing half-written
remains and an earlier output of that name is intact); any other exception (a bug:
a data condition must raise a LidarcatError) becomes one line ``Error: internal
error ...`` with exit code 70, its traceback only in the debug log (``-vv``).
Exit codes: 0 done, 1 stage or solver failed, 2 bad input or an unusable file
(unreadable, unwritable, disk full), 3 statistical test rejected, 70 internal error.
"""

from __future__ import annotations

import importlib
import logging
import os
import re
import sys

# Small dense factorisations stall under OpenBLAS threading on 2-core machines;
# pin BLAS to one thread before numpy is imported by any subcommand.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import click  # noqa: E402

__all__ = ["cli", "main", "COMMANDS", "one_line", "os_error_line"]

#: (name, "module:attribute", one-line summary), in pipeline order.
COMMANDS: list[tuple[str, str, str]] = [
    ("init", "lidarcat.cli.init:init", "A survey folder from a folder of photos (+ GNSS/IMU file, LiDAR tiles)."),
    ("import", "lidarcat.cli.interop:import_cmd", "Read COLMAP, OpenSfM, Metashape, ODM, OPK, GNSS files into a survey."),
    ("match", "lidarcat.cli.match:match", "Tie points from the photos: SIFT, footprint pairs, guided matching."),
    ("camera", "lidarcat.cli.camera:camera", "Interior orientation: pixel to corrected photo coordinates."),
    ("lidar", "lidarcat.cli.lidar:lidar", "LiDAR tiles: info, index, clip, raster views; ground, DTM/DSM, contours."),
    ("extract", "lidarcat.cli.extract:extract", "Roof planes to control points (Delaunay facets + plane intersection)."),
    ("measure-control", "lidarcat.cli.measure_control:measure_control",
     "LiDAR roof vertices found and measured in the photos, into image_points.csv."),
    ("adjust", "lidarcat.cli.adjust:adjust", "Bundle adjustment with weighted position constraints."),
    ("assess", "lidarcat.cli.assess:assess", "Check-point accuracy: Filliben, t, chi-square, PEC, ASPRS, NSSDA."),
    ("monoplot", "lidarcat.cli.monoplot:monoplot", "Monorestitution: features on one photo to the LiDAR surface."),
    ("ortho", "lidarcat.cli.ortho:ortho", "Orthophotos (standard or true) and a mosaic of adjusted photos."),
    ("chart", "lidarcat.cli.chart:chart", "Orthophoto charts: mosaic, contours, grid, legend, title block per sheet."),
    ("deliver", "lidarcat.cli.deliver:deliver", "Products as TIFF + TFW world files, Shapefiles and DXF for CAD."),
    ("run", "lidarcat.cli.run:run", "The whole pipeline on a survey folder (default: the thesis block)."),
    ("export", "lidarcat.cli.interop:export_cmd", "Write an adjusted block as COLMAP, OpenSfM, OPK or GIS layers."),
    ("convert", "lidarcat.cli.convert:convert", "Convert a block between COLMAP, OpenSfM, Metashape, OPK and survey folders."),
    ("demo", "lidarcat.cli.demo:demo", "Write demonstration surveys (synthetic block with known truth)."),
]


class CliLibraryError(click.ClickException):
    """A library error shown as one line, exit code 2."""

    exit_code = 2


class CliInternalError(click.ClickException):
    """An unexpected exception (a bug: every data condition is a LidarcatError) shown as one line,
    exit code 70 (EX_SOFTWARE: outside the table of 0 done, 1 failed, 2 bad input, 3 test rejected)."""

    exit_code = 70


class CliInterrupted(click.ClickException):
    """Ctrl-C: outputs are written atomically, so nothing half-written remains."""

    exit_code = 130

    def show(self, file=None) -> None:  # no "Error:" prefix for an interrupt
        click.echo(self.message, err=True)


class LazyGroup(click.Group):
    """A group whose subcommands are imported on first use, listed in pipeline order."""

    def __init__(self, *args, lazy: list[tuple[str, str, str]] | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self._lazy = {name: (target, summary) for name, target, summary in (lazy or [])}
        self._order = [name for name, _, _ in (lazy or [])]

    def list_commands(self, ctx: click.Context) -> list[str]:
        extra = sorted(set(super().list_commands(ctx)) - set(self._order))
        return self._order + extra

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        if name in self._lazy:
            target, summary = self._lazy[name]
            modname, attr = target.split(":")
            try:
                cmd = getattr(importlib.import_module(modname), attr)
            except ImportError as ex:  # stage not available in this build
                reason = str(ex)  # `ex` is unbound once the except block ends

                @click.command(name=name, help=f"{summary}\n\n(unavailable: {reason})")
                def cmd() -> None:
                    raise click.ClickException(f"'{name}' is not available: {reason}")
            if not cmd.short_help:
                cmd.short_help = summary
            return cmd
        return super().get_command(ctx, name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        # Summaries come from the table, so --help never imports the stages.
        rows = [(name, self._lazy[name][1]) for name in self._order]
        with formatter.section("Commands (in pipeline order)"):
            formatter.write_dl(rows)

    def invoke(self, ctx: click.Context):
        from ..errors import LidarcatError

        try:
            return super().invoke(ctx)
        except (click.exceptions.ClickException, click.exceptions.Exit, click.exceptions.Abort):
            raise
        except LidarcatError as ex:
            raise CliLibraryError(one_line(ex)) from ex
        except OSError as ex:  # an unreadable/unwritable file the library did not wrap: one line naming it
            logging.getLogger("lidarcat").debug("OS error", exc_info=True)
            raise CliLibraryError(os_error_line(ex)) from ex
        except KeyboardInterrupt:
            # click would print "Aborted!" and exit 1; say what state the output is in.
            raise CliInterrupted("Interrupted; no partial output was kept.") from None
        except Exception as ex:  # a bug: one line, the traceback in the debug log only
            logging.getLogger("lidarcat").debug("internal error", exc_info=True)
            raise CliInternalError(f"internal error ({type(ex).__name__}: {one_line(ex)}); please report it "
                                   "(-vv shows the traceback)") from ex


def one_line(ex: BaseException) -> str:
    """The message of *ex* on one line (an OSError with its file name)."""
    if isinstance(ex, OSError) and not str(ex).strip():
        return type(ex).__name__
    text = str(ex) if str(ex).strip() else type(ex).__name__
    return " ".join(text.split())


#: functions whose ``path`` local is the output being written (lidarcat's atomic writers)
_WRITERS = ("atomic_write", "atomic_dir", "_atomic_target", "write_text_atomic")
_PART = re.compile(r"^\.(.+)\.[A-Za-z0-9_]+\.part$")   # a temporary sibling: .NAME.<random>.part


def _final_name(name: str) -> str:
    """*name* with every temporary ``.NAME.<random>.part`` component mapped back to ``NAME``."""
    parts = [(_PART.match(c).group(1) if _PART.match(c) else c) for c in name.split(os.sep)]
    return os.sep.join(parts)


def _file_being_written(tb: object) -> str | None:
    """The ``path`` of the innermost atomic writer on the traceback, else of the innermost frame with one."""
    frames = []
    while tb is not None:
        frames.append(tb.tb_frame)      # type: ignore[attr-defined]
        tb = tb.tb_next                 # type: ignore[attr-defined]
    found = None
    for f in reversed(frames):
        value = f.f_locals.get("path")
        if isinstance(value, (str, os.PathLike)):
            if f.f_code.co_name in _WRITERS:
                return os.fspath(value)
            found = found or os.fspath(value)
    return found


def os_error_line(ex: OSError) -> str:
    """``FILE: reason`` for an OSError: the file it names (or the output being written), the reason
    without the errno noise, on one line."""
    name = ex.filename if isinstance(ex.filename, (str, os.PathLike)) else None
    written = _file_being_written(ex.__traceback__)
    if name is None or (written is not None and _PART.match(os.path.basename(os.fspath(name)))):
        name = written or name
    reason = ex.strerror or one_line(ex)
    if ex.filename2 is not None and name is not None:
        reason = f"{reason} ({_final_name(os.fspath(ex.filename))} -> {_final_name(os.fspath(ex.filename2))})"
    text = f"{_final_name(os.fspath(name))}: {reason}" if name is not None else reason
    return " ".join(text.split())


def configure_logging(verbosity: int) -> None:
    """Map -v/-q counts to a logging level for the ``lidarcat`` logger."""
    level = max(logging.DEBUG, min(logging.ERROR, logging.WARNING - 10 * verbosity))
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(levelname)s %(name)s: %(message)s"))
    log = logging.getLogger("lidarcat")
    log.handlers[:] = [handler]
    log.setLevel(level)


@click.group(cls=LazyGroup, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("-v", "--verbose", count=True, help="More log output (repeat for debug).")
@click.option("-q", "--quiet", count=True, help="Less log output.")
@click.version_option(package_name="lidarcat")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: int) -> None:
    """lidarcat: LiDAR-controlled aerial triangulation.

    Orient a block of aerial photos with ground control taken from airborne
    LiDAR roofs (planes intersected into points), from a GPS survey, or both,
    and judge the result by check points against mapping standards.

    \b
    Quick start (the embedded thesis block, Fierro 2007):
      lidarcat run -o out/
      lidarcat adjust --control gps -o out/gps
    A survey folder holds survey.toml plus CSV files; see docs/survey-format.md.
    Units: metres and degrees on the ground, millimetres and pixels in the image.
    """
    ctx.ensure_object(dict)
    ctx.obj["verbosity"] = verbose - quiet
    configure_logging(verbose - quiet)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    cli.main(args=argv, prog_name="lidarcat")


if __name__ == "__main__":  # pragma: no cover
    main()
