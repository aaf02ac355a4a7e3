"""``lidarcat convert``: one format to another through the interop block, without adjusting."""

from __future__ import annotations

import click

from .options import crs_option, echo_json, json_opt, overwrite_option

__all__ = ["convert"]


def _table(formats: dict[str, str]) -> str:
    return "\n    ".join(f"  {k:10} {v}" for k, v in formats.items())


@click.command("convert", short_help="Convert a block between COLMAP, OpenSfM, Metashape, OPK and survey folders.")
@click.argument("fmt_in", metavar="FORMAT", type=click.Choice(["colmap", "opensfm", "metashape", "survey"]))
@click.argument("source", metavar="IN", type=click.Path(exists=True))
@click.argument("fmt_out", metavar="FORMAT_OUT", type=click.Choice(["colmap", "opensfm", "opk", "survey"]))
@click.argument("dest", metavar="OUT", type=click.Path())
@crs_option(help="metashape: projected target CRS (default: the UTM zone); colmap: the CRS the model was "
                 "aligned to (default: a local frame).")
@click.option("--pixel-size-mm", type=float, default=None,
              help="Pixel pitch given to cameras that have none (COLMAP, OpenSfM; default 0.001 mm).")
@click.option("--tracks", type=click.Path(exists=True), default=None, help="opensfm: tracks.csv.")
@click.option("--frame", type=click.Path(exists=True), default=None, help="metashape: frame doc.xml.")
@click.option("--adjustment", type=click.Path(exists=True, file_okay=False), default=None,
              help="survey: the output folder of lidarcat adjust (its orientations and points).")
@click.option("--angle-unit", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True,
              help="opk: unit of omega, phi, kappa.")
@click.option("--flavour", type=click.Choice(["pix4d", "ign", "orthority"]), default="pix4d", show_default=True,
              help="opk: header layout (see lidarcat export --help).")
@overwrite_option(help="survey: replace the files of an existing survey in OUT.")
@json_opt
def convert(fmt_in, source, fmt_out, dest, crs, pixel_size_mm, tracks, frame, adjustment, angle_unit, flavour,
            force, as_json):
    """Read IN in FORMAT and write it to OUT in FORMAT_OUT, without adjusting.

    \b
    Input formats:
    {read}
    Output formats:
    {write}

    The cameras travel with their distortion (a fitted conversion reports its largest
    misfit in the output's notes); a block with orientations but no tie points (an
    orientation-only OpenSfM reconstruction, a Metashape chunk) converts to every format
    but a survey folder.

    \b
    Examples:
      lidarcat convert opensfm odm/opensfm/reconstruction.json colmap sparse_txt
      lidarcat convert metashape chunk/doc.xml opk cams.csv --frame frame/doc.xml --flavour orthority
      lidarcat convert survey my_survey opensfm osfm --adjustment out/gps
    """
    from ..interop.convert import convert as run

    blk = run(fmt_in, source, fmt_out, dest,
              read={"crs": crs, "pixel_size_mm": pixel_size_mm, "tracks": tracks, "frame": frame,
                    "adjustment": adjustment},
              write={"angle_unit": angle_unit, "flavour": flavour, "overwrite": force})
    report = {"from": fmt_in, "to": fmt_out, "source": source, "output": dest, "photos": int(blk.n_photos),
              "observations": int(len(blk.obs_photo)), "crs": blk.crs, "height_system": blk.height_system}
    if as_json:
        echo_json(report)
    else:
        click.echo(f"wrote {fmt_out} {dest} from {fmt_in} {source}: {report['photos']} photos, "
                   f"{report['observations']} observations, CRS {blk.crs}, heights {blk.height_system}")


def _help() -> None:
    from ..interop.convert import READ_FORMATS, WRITE_FORMATS

    convert.help = convert.help.replace("{read}", _table(READ_FORMATS)).replace("{write}", _table(WRITE_FORMATS))


_help()
