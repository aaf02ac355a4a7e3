"""``lidarcat demo``: write demonstration surveys with known truth."""

from __future__ import annotations

import math
from typing import Any

import click

from .options import echo_json, json_opt, output_option, progress_bar

__all__ = ["demo"]


@click.group("demo")
def demo() -> None:
    """Write demonstration surveys (synthetic block with known truth).

    \b
    Example:
      lidarcat demo synthetic -o demo/ && lidarcat run demo/ -o demo-out/
    """


@demo.command("synthetic")
@output_option(outdir=True, required=True, type=click.Path(file_okay=False),
              help="Survey folder to write (created; files written atomically).")
@click.option("--photos", "n_photos", type=click.IntRange(2, 200), default=6, show_default=True,
              help="Number of photos: one strip below 6, two strips (the second flown back) from 6.")
@click.option("--seed", type=int, default=1, show_default=True,
              help="Seed of the random generator; the same seed writes the same survey.")
@click.option("--image-sd", "image_sd_px", type=click.FloatRange(min=0, min_open=True), default=0.5,
              show_default=True, help="Noise of the pixel measurements, px.")
@click.option("--gps-sd", "gps_sd_m", type=click.FloatRange(min=0, min_open=True), default=0.03,
              show_default=True, help="Noise of the GPS coordinates E and N, m (height: 0.05 m).")
@click.option("--density", "lidar_density_m2", type=click.FloatRange(min=0, min_open=True), default=4.0,
              show_default=True, help="LiDAR point density, points per m^2.")
@click.option("--images", is_flag=True,
              help="Also render the photos (textured terrain, shaded roofs) into OUTDIR/images/<photo>.png "
                   "for `lidarcat ortho` and `lidarcat monoplot` (about a minute per 24 MP photo).")
@click.option("--image-downsample", "image_downsample", type=click.IntRange(1, 20), default=1,
              show_default=True, help="Render the photos at 1/k resolution and upsample them (faster, blurrier).")
@json_opt
def synthetic(outdir: str, n_photos: int, seed: int, image_sd_px: float, gps_sd_m: float,
              lidar_density_m2: float, images: bool, image_downsample: int, as_json: bool) -> None:
    """Write a synthetic survey folder with known truth to OUTDIR.

    A camera with distortion, a block of photos 700 m above a rolling terrain
    with buildings, pixel measurements of tie points, GPS points and roof
    vertices, LiDAR tiles (LAZ), extraction jobs at approximate positions
    (~1 m off), survey.toml, and truth/ (true orientations and coordinates).
    Large blocks (more than 12 million LiDAR points) get terrain points only
    around the buildings.
    `lidarcat run OUTDIR` extracts the roof vertices and adjusts the block with
    GPS and with LiDAR control; compare its results with OUTDIR/truth/.

    \b
    Example:
      lidarcat demo synthetic -o demo/ --photos 6 --seed 1
      lidarcat demo synthetic -o demo/ --images     # photos in demo/images/
      lidarcat run demo/ -o demo/out                # orientations: adjust-gps/eop.csv
      lidarcat ortho demo/ --all --dsm dsm.tif --gsd 0.2 -o demo/ortho --mosaic
    The photos are used by ortho and monoplot, and by run once survey.toml
    has a [mapping] table (orthophotos = true: orthophotos and a mosaic in
    OUTDIR/mapping/; docs/mapping.md).
    """
    from ..synthetic.survey import write_synthetic_survey

    with progress_bar(5, "demo survey", enabled=not as_json) as bar:
        result = write_synthetic_survey(
            outdir, n_photos=n_photos, seed=seed, image_sd_px=image_sd_px, gps_sd_m=gps_sd_m,
            lidar_density_m2=lidar_density_m2, images=images, image_downsample=image_downsample,
            progress=(lambda done, total: _advance(bar, done, total)) if bar is not None else None)
    if as_json:
        echo_json(result.to_dict())
        return
    click.echo(f"synthetic survey written to {result.path}: {result.n_photos} photos, "
               f"{result.n_tie} tie points, {result.n_gps} GPS points, {result.n_roofs} roofs, "
               f"{result.n_lidar_points} LiDAR points (seed {result.seed})")
    click.echo(f"next: lidarcat run {result.path}")


@demo.command("compare")
@click.argument("survey", type=click.Path(exists=True, file_okay=False))
@click.argument("outdir", required=False, type=click.Path(exists=True, file_okay=False))
@json_opt
def compare(survey: str, outdir: str | None, as_json: bool) -> None:
    """Compare `lidarcat run SURVEY` output in OUTDIR (default SURVEY/out) with SURVEY/truth/.

    Prints, per run, the largest and the RMS normalised error z = error / sd of
    the exterior orientations and of the free points (RMS near 1 when the
    reported standard deviations are honest), the check-point statistic
    d'C^-1d (C: joint covariance of the adjusted check points + GPS variances;
    chi-square with 3 x check points degrees of freedom) beside the sum
    d^2 / (sd_adjusted^2 + sd_gps^2) that ignores the correlations, and the
    error of every extracted roof vertex (m, and in units of its sd).

    \b
    Example:
      lidarcat demo synthetic -o demo/ && lidarcat run demo/ && lidarcat demo compare demo/
    """
    from pathlib import Path

    from ..synthetic.survey import compare_with_truth

    result = compare_with_truth(survey, outdir or Path(survey) / "out")
    if as_json:
        echo_json(result)
        return
    for run, r in result["runs"].items():
        joint = r["check_chi2_joint"]
        if math.isfinite(joint):
            joint_txt = f"{joint:.1f}"
        else:  # never a bare nan: say why
            why = r.get("check_chi2_joint_not_computed") or "no joint covariance"
            joint_txt = why if why.startswith("not computed") else f"not computed ({why})"
        click.echo(f"run {run}: orientations max |z| {r['eo_max_abs_z']:.2f}, RMS z {r['eo_rms_z']:.2f}; "
                   f"free points max |z| {r['points_max_abs_z']:.2f}, RMS z {r['points_rms_z']:.2f}; "
                   f"check points d'C^-1d {joint_txt} on {r['check_dof']} dof "
                   f"(correlations ignored: {r['check_chi2']:.1f})")
    for pid, e in result["extraction"].items():
        err = ", ".join(f"{v:+.3f}" for v in e["error_m"])
        z = ", ".join(f"{v:+.1f}" for v in e["z"])
        click.echo(f"roof {pid}: {e['status']}, error E, N, h ({err}) m, z ({z})")


def _advance(bar: Any, done: int, total: int) -> None:
    """Move *bar* to *done* of *total* (the total grows by one step per photo with --images)."""
    bar.length = total
    bar.update(done - bar.pos)
