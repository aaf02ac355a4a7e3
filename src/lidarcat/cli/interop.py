"""``lidarcat import`` and ``lidarcat export``: other programs' files in and out (docs/formats/)."""

from __future__ import annotations

from pathlib import Path

import click

from .options import crs_option, echo_json, json_opt, output_option, overwrite_option

__all__ = ["import_cmd", "export_cmd", "IMPORT_FORMATS", "EXPORT_FORMATS"]

#: format -> what SOURCE is
IMPORT_FORMATS = {
    "colmap": "COLMAP model folder (cameras, images, points3D as .txt or .bin; rigs, frames when present)",
    "opensfm": "OpenSfM reconstruction.json (tracks.csv beside it or --tracks)",
    "metashape": "Metashape chunk doc.xml (marker measurements: --frame frame doc.xml)",
    "borea": "IGN Borea .OPK with --camera files, --points .app and --measurements .mes",
    "opk": "omega-phi-kappa text (IGN .OPK, Pix4D/Metashape layout) into --survey",
    "gnss": "GNSS/IMU text (photo E N h + omega/phi/kappa or roll/pitch/yaw) into --survey",
    "odm-geo": "OpenDroneMap geo.txt into --survey",
    "odm-gcp": "OpenDroneMap/OpenSfM gcp_list.txt into --survey",
    "opensfm-gcp": "OpenSfM ground_control_points.json into a survey imported from OpenSfM (--survey)",
    "heights": "a survey folder: ground-point heights converted to one system (--to, --geoid)",
}
EXPORT_FORMATS = {
    "colmap": "COLMAP text model folder",
    "opensfm": "OpenSfM reconstruction.json + tracks.csv folder",
    "opk": "omega-phi-kappa text file (+ .json sidecar with CRS and height system)",
    "gis": "GIS layer set: GeoPackage (pyogrio installed) or GeoJSON files",
    "odm-cameras": "OpenDroneMap cameras.json (the cameras, fisheyes included, for odm --cameras)",
}


def _fmt_help(table: dict[str, str]) -> str:
    """The format table for a ``{formats}`` placeholder indented by 4 in a raw docstring."""
    return "\n    ".join(f"  {k:12} {v}" for k, v in table.items())


@click.command("import", short_help="Read COLMAP, OpenSfM, Metashape, ODM, OPK, GNSS files into a survey.")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(list(IMPORT_FORMATS)))
@click.argument("source", type=click.Path(exists=True))
@output_option(required=True, type=click.Path(file_okay=False),
              help="Survey folder to write (atomically; refused if it holds a survey.toml, see --force).")
@click.option("--survey", "base", type=click.Path(exists=True), default=None,
              help="Survey the orientations/GCPs are merged into (opk, gnss, odm-*, opensfm-gcp; default: "
                   "the embedded thesis block).")
@crs_option(help="Target CRS of the coordinates (pyproj string, e.g. EPSG:31982); needed when the file is in lon/lat.")
@click.option("--file-crs", default=None, help="gnss: CRS of the coordinates in the file.")
@click.option("--height-system", default="unspecified", show_default=True,
              help="What the file's heights are: ellipsoidal or orthometric (reported in every output).")
@click.option("--pixel-size-mm", type=float, default=None,
              help="Pixel pitch given to cameras that have none (COLMAP, OpenSfM, Borea; default 0.001 mm, "
                   "0.01 mm for a COLMAP/OpenSfM focal length under 500 px).")
@click.option("--control-sd-m", type=float, default=None,
              help="colmap/opensfm: model points become control with this sd (model units) so the "
                   "re-adjustment keeps the model's datum.")
@click.option("--tracks", type=click.Path(exists=True), default=None, help="opensfm: tracks.csv.")
@click.option("--odm-cameras", "odm_cameras", type=click.Path(exists=True, dir_okay=False), default=None,
              help="opensfm: an OpenDroneMap cameras.json whose cameras replace the reconstruction's.")
@click.option("--frame", type=click.Path(exists=True), default=None, help="metashape: frame doc.xml.")
@click.option("--camera", "cameras", multiple=True, type=click.Path(exists=True), help="borea: camera file (repeat).")
@click.option("--points", type=click.Path(exists=True), default=None, help="borea: ground points .app.")
@click.option("--measurements", multiple=True, type=click.Path(exists=True), help="borea: .mes file (repeat).")
@click.option("--angle-unit", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True,
              help="opk, gnss: unit of the angles.")
@click.option("--sd-position-m", type=float, default=None,
              help="opk, gnss, odm-geo: sd of X0, Y0, Z0 (m): the positions become weighted constraints.")
@click.option("--sd-attitude-deg", type=float, default=None,
              help="opk, gnss, odm-geo: sd of omega, phi, kappa (deg).")
@click.option("--gcp-sd-m", type=float, default=0.05, show_default=True,
              help="odm-gcp, opensfm-gcp: sd of E, N, h (opensfm-gcp: config.yaml beside the file may set "
                   "gcp_horizontal_sd, gcp_vertical_sd).")
@click.option("--set", "set_name", default="gcp", show_default=True, help="odm-gcp, opensfm-gcp: control-set name.")
@click.option("--to", "to_system", type=click.Choice(["ellipsoidal", "orthometric"]), default=None,
              help="heights: target height system (default: the survey's).")
@click.option("--geoid", type=click.Path(exists=True, dir_okay=False), default=None,
              help="heights: geoid grid file (GTX, GeoTIFF...; overrides [heights] geoid_grid).")
@overwrite_option(help="Replace the files of an existing survey in OUTPUT.")
@json_opt
def import_cmd(fmt, source, output, base, crs, file_crs, height_system, pixel_size_mm, control_sd_m, tracks,
               odm_cameras, frame, cameras, points, measurements, angle_unit, sd_position_m, sd_attitude_deg, gcp_sd_m,
               set_name, to_system, geoid, force, as_json):
    """Read SOURCE in FORMAT and write the survey folder OUTPUT.

    \b
    Formats:
    {formats}

    Full models (colmap, opensfm, metashape, borea) become a new survey; orientation
    and control files (opk, gnss, odm-geo, odm-gcp, opensfm-gcp) are merged into a copy
    of --survey. Angle conventions, pixel origins and what is lost are in
    docs/formats/<format>.md.

    \b
    Examples:
      lidarcat import colmap sparse/0 -o my_survey --control-sd-m 0.01
      lidarcat import metashape chunk/doc.xml --frame frame/doc.xml -o ms_survey
      lidarcat import gnss imu.csv --survey my_survey --file-crs EPSG:4326 --crs EPSG:31982 \\
          --sd-position-m 0.1 --height-system ellipsoidal -o my_survey_gnss
      lidarcat import heights my_survey --to orthometric --geoid hBR.tif -o my_survey_H
    """
    from ..interop import block as B

    px = pixel_size_mm if pixel_size_mm is not None else 0.001
    report: dict = {"format": fmt, "source": source, "survey": output}
    B.check_crs(crs, local=fmt in ("colmap", "borea", "opk"))
    if fmt == "borea" and not crs:
        raise click.UsageError("borea needs --crs: the CRS of the .OPK and .app coordinates (IGN blocks: "
                               "EPSG:2154, Lambert-93), or 'local: <description>' for a local frame")
    if fmt in ("colmap", "opensfm", "metashape", "borea"):
        if fmt == "colmap":
            from ..interop.colmap import LOCAL_CRS, read_colmap
            from ..interop.colmap_binary import read_colmap_binary

            binary = (Path(source) / "cameras.bin").is_file() and not (Path(source) / "cameras.txt").is_file()
            blk = (read_colmap_binary if binary else read_colmap)(
                source, pixel_size_mm=pixel_size_mm, crs=crs or LOCAL_CRS,
                height_system=height_system if crs else "unspecified (model frame)")
        elif fmt == "opensfm":
            from ..interop.opensfm import read_opensfm

            blk = read_opensfm(source, tracks, pixel_size_mm=pixel_size_mm, cameras=odm_cameras)
        elif fmt == "metashape":
            from ..interop.metashape import read_metashape

            blk = read_metashape(source, frame, crs=crs, pixel_size_mm=pixel_size_mm)
        else:
            from ..interop.opk import read_borea

            if not cameras:
                raise click.UsageError("borea needs at least one --camera file")
            blk = read_borea(source, list(cameras), points=points, measurements=list(measurements),
                             crs=crs or "unspecified", height_system=height_system, pixel_size_mm=px)
        B.write_survey(blk, output, control_sd_m=control_sd_m, overwrite=force)
        report.update(photos=int(blk.n_photos), observations=int(len(blk.obs_photo)),
                      points=int(len(blk.point_ids)), ground_points=int(len(blk.ground_ids)),
                      crs=blk.crs, height_system=blk.height_system)
        fisheyes = sorted(c for c, m in blk.source_models.items() if m.get("kind", "").endswith("fisheye"))
        if fisheyes:
            report["fisheye_cameras"] = fisheyes
        if "skipped" in blk.description:
            report["skipped"] = blk.description.split("; ", 1)[1]
        if blk.rigs is not None:
            report["rigs"] = len(blk.rigs.rigs)
            report["exposures"] = len(blk.rigs.exposures)
        report["next"] = _next_step(fmt, blk, output, control_sd_m)
    elif fmt in ("opk", "gnss", "odm-geo"):
        if fmt == "opk":
            from ..interop.opk import read_opk

            ori = read_opk(source, angle_unit=angle_unit, crs=crs or "unspecified", height_system=height_system)
        elif fmt == "gnss":
            from ..interop.gnss import read_gnss

            if not file_crs:
                raise click.UsageError("gnss needs --file-crs (the CRS of the file's coordinates)")
            ori = read_gnss(source, file_crs=file_crs, crs=crs, height_system=height_system, angle_unit=angle_unit)
        else:
            from ..interop.odm import read_geo_txt

            ori = read_geo_txt(source, crs=crs, height_system=height_system)
        B.apply_orientations(base, ori, output, sd_position_m=sd_position_m, sd_attitude_deg=sd_attitude_deg,
                             overwrite=force)
        report.update(photos=int(len(ori)), crs=ori.crs, height_system=ori.height_system, conventions=ori.source)
    elif fmt in ("odm-gcp", "opensfm-gcp"):
        if fmt == "odm-gcp":
            from ..interop.odm import read_gcp_list

            gcp = read_gcp_list(source, crs=crs, height_system=height_system)
        else:
            from ..interop.opensfm import read_opensfm_gcp

            if base is None:
                raise click.UsageError("opensfm-gcp needs --survey, a survey imported from the same OpenSfM "
                                       "reconstruction: lidarcat import opensfm reconstruction.json -o SURVEY, "
                                       "then --survey SURVEY")
            gcp = read_opensfm_gcp(source, B.block_from_survey(base))
        sd = (gcp_sd_m,) * 3
        config = Path(source).with_name("config.yaml")
        if fmt == "opensfm-gcp" and config.is_file():  # the dataset's gcp_horizontal_sd / gcp_vertical_sd
            from ..interop.opensfm import gcp_sd_from_config, read_opensfm_config

            sd = gcp_sd_from_config(read_opensfm_config(config), gcp_sd_m)
        B.apply_ground_control(base, gcp, output, sd_m=sd, set_name=set_name, overwrite=force)
        report.update(ground_points=int(len(gcp.point)), measurements=int(len(gcp.obs_point)), crs=gcp.crs,
                      height_system=gcp.height_system)
    else:
        from ..interop.heights import json_report, write_harmonised_survey

        _, rep = write_harmonised_survey(source, output, to_system=to_system, geoid_grid=geoid, overwrite=force)
        report.update(heights=rep)
        if not as_json:
            click.echo(json_report(rep))
    if as_json:
        echo_json(report)
    elif fmt != "heights":
        click.echo(f"wrote survey {output} from {fmt} {source}: "
                   + ", ".join(f"{k} {v}" for k, v in report.items()
                               if k not in ("format", "source", "survey", "next")))
        if report.get("next"):
            click.echo(f"next: {report['next']}")


def _next_step(fmt: str, blk, output: str, control_sd_m: float | None) -> str | None:
    """What the user does next with an imported block that `lidarcat adjust` cannot take as it is."""
    from collections import Counter

    counts = Counter(blk.obs_point.tolist())
    ties = sum(1 for p, n in counts.items() if n >= 2 and p not in set(blk.ground_ids.tolist()))
    if len(blk.obs_photo) == 0:
        return (f"the {fmt} file holds oriented photos but no image observations, so the block cannot be "
                f"adjusted yet; export it as it is (lidarcat export colmap|opensfm|opk|gis {output} -o OUT), "
                f"or give photos.csv an image column (each photo's image file) and run lidarcat match "
                f"{output} first")
    if fmt == "metashape" and ties == 0:
        return (f"the Metashape XML holds no tie points (Metashape keeps them in binary point clouds), so "
                f"the block cannot be adjusted; export it as it is (lidarcat export colmap|opensfm|opk|gis "
                f"{output} -o OUT) or add tie points before lidarcat adjust")
    if len(blk.ground_ids) == 0 and control_sd_m is None:
        return (f"the model has no control, which lidarcat adjust needs to fix its datum: import again with "
                f"--control-sd-m 0.01 (the model points become control) or add ground control "
                f"(lidarcat import odm-gcp gcp_list.txt --survey {output} -o {output}_gcp)")
    return None


import_cmd.help = import_cmd.help.replace("{formats}", _fmt_help(IMPORT_FORMATS))


@click.command("export", short_help="Write an adjusted block as COLMAP, OpenSfM, OPK or GIS layers.")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(list(EXPORT_FORMATS)))
@click.argument("adjustment", type=click.Path(exists=True, file_okay=False))
@click.option("--survey", type=click.Path(exists=True), default=None,
              help="The survey that was adjusted (default: the embedded thesis block).")
@output_option(required=True, type=click.Path(),
              help="Output folder (colmap, opensfm, gis) or file (opk, odm-cameras); written atomically.")
@click.option("--angle-unit", type=click.Choice(["deg", "rad", "gon"]), default="deg", show_default=True,
              help="opk: unit of omega, phi, kappa.")
@click.option("--flavour", type=click.Choice(["pix4d", "ign", "orthority"]), default="pix4d", show_default=True,
              help="opk: header 'imageName X Y Z Omega Phi Kappa' (Pix4D, Metashape), "
                   "'NOM X Y Z O P K CAMERA' (IGN) or orthority's CSV 'filename,x,y,z,omega,phi,kappa,camera' "
                   "with a .prj (OUTPUT ending in .csv or .txt).")
@click.option("--format", "gis_format", type=click.Choice(["auto", "gpkg", "geojson"]), default="auto",
              show_default=True, help="gis: GeoPackage (needs pyogrio) or GeoJSON.")
@click.option("--ellipse-scale", type=float, default=1.0, show_default=True,
              help="gis: magnification of the error ellipses.")
@click.option("--vector-scale", type=float, default=1.0, show_default=True,
              help="gis: magnification of residual and discrepancy vectors.")
@json_opt
def export_cmd(fmt, adjustment, survey, output, angle_unit, flavour, gis_format, ellipse_scale, vector_scale,
               as_json):
    """Write the adjusted block of ADJUSTMENT (a `lidarcat adjust` output folder) in FORMAT.

    ADJUSTMENT may also be a survey folder (it holds a survey.toml): its own orientations
    are written, unadjusted (a block imported from Metashape, which has no tie points).

    \b
    Formats:
    {formats}

    Orientations are lidarcat's M = R3(kappa) R2(phi) R1(omega) (object to image, y up);
    COLMAP/OpenSfM get R = diag(1,-1,-1) M (world to camera, y down, z forward). The
    CRS and height system go into every output (header comment, sidecar or layer field).

    \b
    Examples:
      lidarcat adjust --control gps -o out/gps
      lidarcat export opk out/gps -o out/gps.opk
      lidarcat export colmap out/gps -o out/colmap
      lidarcat export gis out/gps -o out/gis --ellipse-scale 1000
    """
    from ..interop.block import block_from_survey

    report = {"format": fmt, "adjustment": adjustment, "output": output}
    adj: str | None = adjustment
    if (Path(adjustment) / "survey.toml").is_file():  # a survey folder: its own orientations
        if survey is not None:
            raise click.UsageError(f"{adjustment} is a survey folder; give either it or --survey with the "
                                   f"output folder of lidarcat adjust")
        survey, adj = adjustment, None
    if fmt == "gis":
        from ..interop.gis import gis_layers, write_gis

        layers, crs, hs = gis_layers(survey, adj, ellipse_scale=ellipse_scale, vector_scale=vector_scale)
        write_gis(layers, crs, output, fmt=gis_format)
        report.update(layers=[lay.name for lay in layers], crs=crs, height_system=hs)
    else:
        blk = block_from_survey(survey, adj)
        if fmt == "colmap":
            from ..interop.colmap import write_colmap

            write_colmap(blk, output)
        elif fmt == "opensfm":
            from ..interop.opensfm import write_opensfm

            write_opensfm(blk, output)
        elif fmt == "odm-cameras":
            from ..interop.odm import write_odm_cameras

            write_odm_cameras(blk, output)
        else:
            from ..interop.opk import write_opk

            write_opk(blk, output, angle_unit=angle_unit, flavour=flavour)
        report.update(photos=int(blk.n_photos), crs=blk.crs, height_system=blk.height_system)
    if as_json:
        echo_json(report)
    else:
        click.echo(f"wrote {fmt} {output}: CRS {report['crs']}, heights {report['height_system']}")


export_cmd.help = export_cmd.help.replace("{formats}", _fmt_help(EXPORT_FORMATS))
