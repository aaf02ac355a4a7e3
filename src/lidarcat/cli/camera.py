"""``lidarcat camera``: interior orientation from the command line."""

from __future__ import annotations

import sys

import click

from .options import echo_json, json_opt, output_option

__all__ = ["camera", "correct", "info"]


@click.group(short_help="Interior orientation: pixel to corrected photo coordinates.")
def camera() -> None:
    """Interior orientation of a non-metric camera (Fierro 2007, eq. 01-07).

    A pixel (column C, row L; origin at the centre of the top-left pixel) goes
    to image-centre millimetres (eq. 01), is shifted by the principal point
    (eq. 02) and corrected for radial (eq. 03) and decentering (eq. 05)
    distortion and refraction (eq. 06), giving photo coordinates x_fotc,
    y_fotc in mm, x right, y up (eq. 07).
    """


@camera.command()
@click.argument("source", metavar="SURVEY_OR_CSV", type=click.Path(exists=True))
@click.option("--camera", "camera_spec", metavar="FILE[:ID]",
              help="Camera calibration TOML (and the camera id when the file holds several). "
                   "Required for a CSV; for a survey folder it replaces the survey's own camera.")
@output_option(type=click.Path(dir_okay=False), default=None,
              help="Write the table to this CSV (atomically). Default: print CSV on stdout.")
@json_opt
def correct(source: str, camera_spec: str | None, output: str | None, as_json: bool) -> None:
    """Correct pixel measurements to photo coordinates (mm).

    SURVEY_OR_CSV is a survey folder (its image_points.csv rows with col_px,
    row_px are corrected with each photo's camera) or a CSV with columns
    photo, point, col_px, row_px (then --camera is required).

    The output has columns photo, point, x_mm, y_mm (corrected photo
    coordinates, mm), then col_px, row_px, x_fot_mm, y_fot_mm (eq. 02) and the
    distortions dx_ra_mm, dy_ra_mm, dx_des_mm, dy_des_mm, dx_ref_mm, dy_ref_mm
    that eq. 07 subtracts, and camera.

    \b
    Examples:
      lidarcat camera correct data/thesis -o corrected.csv
      lidarcat camera correct points.csv --camera data/cameras/lactec_dcs14n_2008.toml
      lidarcat camera correct points.csv --camera cams.toml:dcs14n --json
    """
    from ..survey.folder import correct_measurements

    table = correct_measurements(source, camera_spec)
    if output is not None:
        table.write_csv(output)
    if as_json:
        out = table.to_dict()
        out["output"] = output
        if output is None:
            out["points"] = table.records()
        echo_json(out)
    elif output is None:
        from .._util import write_csv

        write_csv(sys.stdout, table.columns, table.rows())
    else:
        s = table.to_dict()
        click.echo(f"{s['n_points']} measurements corrected (camera {', '.join(s['cameras'])}, "
                   f"largest correction {s['max_correction_mm']:.4f} mm) -> {output}")


@camera.command()
@click.argument("source", metavar="[SURVEY_OR_TOML]", required=False, type=click.Path(exists=False))
@json_opt
def info(source: str | None, as_json: bool) -> None:
    """Show camera calibrations and their largest distortion correction.

    SURVEY_OR_TOML is a survey folder, a survey.toml, or a camera TOML
    (FILE or FILE:ID); default: the embedded thesis block.  Lengths in mm,
    k1 [mm^-2], k2 [mm^-4], k3 [mm^-6], p1, p2 [mm^-1]; the largest
    correction (eq. 03-06) is taken over the frame border, in mm and pixels.

    \b
    Examples:
      lidarcat camera info
      lidarcat camera info data/cameras/lactec_dcs14n_2008.toml --json
    """
    from ..survey.folder import cameras_of

    cams = cameras_of(source)
    summaries = {k: c.summary() for k, c in cams.items()}
    if as_json:
        echo_json(summaries)
        return
    for cam_id, s in summaries.items():
        click.echo(f"[{cam_id}] {s['model'] or '(no model)'}")
        if s["source"]:
            click.echo(f"  source: {s['source']}")
        click.echo(f"  focal length c          {s['focal_length_mm']:.4f} mm")
        click.echo(f"  principal point dx, dy  {s['principal_point_x_mm']:+.4f}, "
                   f"{s['principal_point_y_mm']:+.4f} mm")
        if s.get("lens"):                      # a Brown/fisheye camera: its model's parameters (px, normalised)
            lens = s["lens"]
            click.echo(f"  {lens['model'] + ' model':<24}" + ", ".join(
                f"{k} {v:.6g}" for k, v in lens.items() if k not in ("model", "source", "pixel_size_mm")
                and not k.startswith("sd_")))
        else:
            click.echo(f"  k1, k2, k3              {s['k1']:.6e}, {s['k2']:.6e}, {s['k3']:.6e}")
            click.echo(f"  p1, p2                  {s['p1']:.6e}, {s['p2']:.6e}")
        click.echo(f"  refraction eps45        {s['refraction_eps45']:g}")
        click.echo(f"  image                   {s['columns_px']} x {s['rows_px']} px of "
                   f"{s['pixel_size_x_mm'] * 1000:g} x {s['pixel_size_y_mm'] * 1000:g} um = "
                   f"{s['frame_width_mm']:.2f} x {s['frame_height_mm']:.2f} mm")
        click.echo(f"  largest correction      {s['max_correction_mm']:.4f} mm "
                   f"({s['max_correction_px']:.1f} px) on the frame border")
