"""``lidarcat init``: a survey folder from a folder of photos (:func:`lidarcat.stages.init.init_survey`)."""

from __future__ import annotations

import click

from .options import POSITIVE, crs_option, echo_json, json_opt, overwrite_option, progress_bar

__all__ = ["init"]


@click.command("init")
@click.argument("survey", type=click.Path(file_okay=False), metavar="SURVEY")
@click.option("--images", required=True, type=click.Path(exists=True, file_okay=False), metavar="DIR",
              help="Folder of the photos (*.jpg, *.jpeg, *.png, *.tif, *.tiff; the file name without its suffix "
                   "is the photo id).")
@click.option("--camera", "camera", default=None, metavar="FILE[:ID]",
              help="Camera TOML (docs/survey-format.md). Default: an approximate camera from the EXIF focal "
                   "length and 35 mm equivalent (no distortion; self-calibration advised).")
@click.option("--gnss", default=None, type=click.Path(exists=True, dir_okay=False), metavar="FILE",
              help="GNSS/IMU file: a header line, then photo, E, N, h [, omega, phi, kappa | roll, pitch, yaw] "
                   "[, sd_E, ...] per photo (as `lidarcat import gnss`). Default: the EXIF GNSS tags.")
@click.option("--gnss-crs", default="EPSG:4326", show_default=True, metavar="CRS",
              help="CRS of the --gnss coordinates (EPSG:4326: longitude, latitude).")
@click.option("--lidar", multiple=True, metavar="TILES",
              help="LiDAR tiles: a file, a folder or a glob pattern (quote it); repeat for more.")
@crs_option(help="CRS of the survey (projected, metres). Default: the --gnss CRS when projected, else the "
                 "WGS 84 / UTM zone of the photos' positions.")
@click.option("--name", default=None, help="Survey name (default: the folder's name).")
@click.option("--height-system", default=None, metavar="TEXT",
              help="What the heights are: ellipsoidal (default with --gnss) or orthometric.")
@click.option("--position-sd", type=POSITIVE, default=5.0, show_default=True, metavar="M",
              help="sd of an approximate position that comes without one, m.")
@click.option("--attitude-sd", type=POSITIVE, default=5.0, show_default=True, metavar="DEG",
              help="sd of an approximate attitude that comes without one, degrees.")
@overwrite_option(help="Write into a folder that holds other files (replaces survey.toml, camera.toml, photos.csv, "
                       "image_points.csv).")
@json_opt
def init(survey, images, camera, gnss, gnss_crs, lidar, crs, name, height_system, position_sd, attitude_sd, force,
         as_json):
    """Create the survey folder SURVEY from a folder of photos: the first step.

    Writes survey.toml, camera.toml (given, or approximate from the EXIF),
    photos.csv (one row per photo: its image file and the approximate
    orientation from --gnss or the EXIF GNSS tags, with sds), an empty
    image_points.csv and the LiDAR tile list. Every photo is checked first
    (unreadable or truncated, another size than the camera, two files of
    one photo): nothing is written on an error.

    \b
    Example (photos with a GNSS/IMU file and LiDAR tiles):
      lidarcat init block --images flight/photos --gnss flight/gnss.txt \\
          --lidar 'lidar/*.laz' --crs EPSG:31982
      lidarcat match block        # tie points from the photos
      lidarcat run block -o out   # orient the block
    """
    from ..stages.init import init_survey, list_photos

    with progress_bar(len(list_photos(images)), "reading photos", enabled=not as_json) as bar:
        def tick(done: int, total: int) -> None:
            if bar is not None:
                bar.update(done - bar.pos)

        res = init_survey(survey, images, camera=camera, gnss=gnss, gnss_crs=gnss_crs, lidar=lidar, crs=crs,
                          name=name, height_system=height_system, position_sd_m=position_sd,
                          attitude_sd_deg=attitude_sd, overwrite=force, progress=tick)
    if as_json:
        echo_json(res.to_dict())
        return
    click.echo(f"Survey {res.folder}: {len(res.photos)} photos, camera {res.camera} ({res.camera_source}), "
               f"CRS {res.crs}, {len(res.with_position)} with approximate position, "
               f"{len(res.with_attitude)} with attitude, {len(res.lidar)} LiDAR tile(s)")
    for note in res.notes:
        click.echo(f"  note: {note}")
    click.echo(f"Next: lidarcat match {res.folder}")
