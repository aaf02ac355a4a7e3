"""Issue 25: ``export colmap|opensfm`` carries the camera exactly -- pycolmap's own projection of the
exported camera against lidarcat's camera (eq. 01-07): <= 1e-6 px where the models are algebraically
equivalent, within the fit's reported largest misfit where lidarcat's correction polynomial is fitted;
the OpenSfM export keeps reference_lla."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from lidarcat.interop.block import block_from_survey
from lidarcat.interop.colmap import write_colmap
from lidarcat.interop.lens import export_camera
from lidarcat.interop.metashape import read_metashape
from lidarcat.interop.opensfm import read_opensfm, reference_lla, write_opensfm
from lidarcat.survey.folder import Survey
from lidarcat.synthetic.survey import demo_camera

pycolmap = pytest.importorskip("pycolmap")

D = Path(__file__).parents[1] / "data" / "interop"
THESIS_ADJ = Path(__file__).parents[1] / "data" / "report"


def _grid(w: int, h: int, n: int = 23) -> np.ndarray:
    """Corner-origin pixels over the whole image, off the fitting grid (n x n, inset 0.3 px)."""
    u, v = np.meshgrid(np.linspace(0.3, w - 0.3, n), np.linspace(0.3, h - 0.3, n))
    return np.column_stack([u.ravel(), v.ravel()])


def _colmap_camera(folder: Path):
    line = next(ln for ln in (folder / "cameras.txt").read_text().splitlines() if not ln.startswith("#"))
    f = line.split()
    return f[1], pycolmap.Camera(model=f[1], width=int(f[2]), height=int(f[3]), params=[float(x) for x in f[4:]])


def _lidarcat_rays(cam, corner: np.ndarray) -> np.ndarray:
    """Camera-frame rays (n, 3), y down, z forward, of corner-origin pixels through eq. 01-07."""
    mm = np.asarray(cam.pixel_to_photo(corner - 0.5))
    return np.column_stack([mm[:, 0], -mm[:, 1], np.full(len(mm), cam.focal_length_mm)])


@pytest.mark.parametrize("which", ["thesis", "demo", "pinhole"])
def test_colmap_export_projects_as_lidarcat(tmp_path, which):
    blk = block_from_survey(None, THESIS_ADJ)
    cam = blk.cameras["dcs14n"]
    if which == "demo":  # the demo camera's distortion (35 px at the corners) in the thesis block's frame
        d = demo_camera()
        cam = dataclasses.replace(cam, k1=d.k1, k2=d.k2, k3=d.k3, p1=d.p1, p2=d.p2)
    elif which == "pinhole":
        cam = dataclasses.replace(cam, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0, refraction_eps45=0.0)
    blk = blk.with_(cameras={"dcs14n": cam})
    write_colmap(blk, tmp_path / "m")
    model, pc = _colmap_camera(tmp_path / "m")
    corner = _grid(cam.columns_px, cam.rows_px)
    proj = pc.img_from_cam(_lidarcat_rays(cam, corner))
    miss = np.hypot(*(proj - corner).T).max()
    fit = export_camera(cam)
    header = (tmp_path / "m" / "cameras.txt").read_text()
    if which == "pinhole":
        assert model == "SIMPLE_PINHOLE" and fit["how"] == "exact" and miss <= 1e-6
        assert "# camera dcs14n: converted to Brown (OpenCV) exactly" in header
    else:
        assert model == "FULL_OPENCV" and fit["how"] == "fitted"
        assert miss <= fit["fit_max_px"] + 1e-9 and fit["fit_max_px"] < 0.02, (miss, fit["fit_max_px"])
        assert (f"# camera dcs14n: distortion model converted to Brown (OpenCV) by a least-squares fit over a "
                f"41x31 pixel grid, largest misfit {fit['fit_max_px']:.3g} px") in header
        # without the distortion the export would miss by many pixels: the test can fail
        raw = np.asarray(cam.pixel_to_fot(corner - 0.5))
        assert np.abs(np.asarray(cam.pixel_to_photo(corner - 0.5)) - raw).max() / cam.pixel_size_x_mm > 5.0


def test_metashape_camera_exported_exactly(tmp_path):
    """Metashape's frame model with k4 = b2 = 0 is OpenCV's with p1, p2 swapped: pycolmap projects the
    exported camera as Metashape's formula does, to 1e-6 px."""
    from lidarcat.interop._distortion import distort

    b = read_metashape(D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml",
                       D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml")
    write_colmap(b, tmp_path / "m")
    model, pc = _colmap_camera(tmp_path / "m")
    m = b.source_models["0"]
    x = np.random.default_rng(1).uniform(-0.45, 0.45, (500, 2))
    xd = distort(x, m["dist"], metashape=True)
    expect = xd * [m["fx"], m["fy"]] + [m["cx"], m["cy"]]
    proj = pc.img_from_cam(np.column_stack([x, np.ones(len(x))]))
    assert model == "FULL_OPENCV" and np.abs(proj - expect).max() <= 1e-6


def test_opensfm_export_keeps_reference_lla(tmp_path):
    rec = D / "opensfm" / "berlin_reconstruction_example.json"
    b = read_opensfm(rec, D / "opensfm" / "berlin_tracks_example.csv")
    write_opensfm(b, tmp_path / "o")
    out = json.loads((tmp_path / "o" / "reconstruction.json").read_text())[0]
    assert out["reference_lla"] == json.loads(rec.read_text())[0]["reference_lla"]
    back = read_opensfm(tmp_path / "o" / "reconstruction.json")
    assert back.crs == b.crs and back.height_system == "ellipsoidal"
    assert reference_lla("EPSG:31982") is None


def test_opensfm_export_of_a_distorted_camera(tmp_path):
    """lidarcat's distorted camera goes to OpenSfM as a fitted brown camera whose projection of the
    lidarcat rays (OpenSfM's formula, doc/source/geometry.rst) lands within the reported misfit."""
    blk = block_from_survey(None, THESIS_ADJ)
    cam = blk.cameras["dcs14n"]
    write_opensfm(blk, tmp_path / "o")
    c = json.loads((tmp_path / "o" / "reconstruction.json").read_text())[0]["cameras"]["dcs14n"]
    assert c["projection_type"] == "brown"
    corner = _grid(cam.columns_px, cam.rows_px)
    ray = _lidarcat_rays(cam, corner)
    x, y = ray[:, 0] / ray[:, 2], ray[:, 1] / ray[:, 2]
    r2 = x * x + y * y
    rad = 1 + c["k1"] * r2 + c["k2"] * r2**2 + c["k3"] * r2**3
    xd = x * rad + 2 * c["p1"] * x * y + c["p2"] * (r2 + 2 * x * x)
    yd = y * rad + c["p1"] * (r2 + 2 * y * y) + 2 * c["p2"] * x * y
    s = max(c["width"], c["height"])
    proj = np.column_stack([c["focal_x"] * xd + c["c_x"], c["focal_y"] * yd + c["c_y"]]) * s \
        + [c["width"] / 2, c["height"] / 2]
    fit = export_camera(cam, rational=False)
    assert np.hypot(*(proj - corner).T).max() <= fit["fit_max_px"] + 1e-9
    notes = (tmp_path / "o" / "lidarcat_export.txt").read_text()
    assert f"largest misfit {fit['fit_max_px']:.3g} px" in notes
    assert "coordinates converted from EPSG:29192 to OpenSfM's topocentric frame at reference_lla" in notes
    assert "the block's heights (orthometric) were taken as ellipsoidal" in notes


def test_map_crs_block_goes_to_opensfm_with_reference_lla(tmp_path):
    """A block in a map CRS (Metashape -> UTM 54N) is written in OpenSfM's topocentric frame with a
    reference_lla: the shot centres come back to UTM through PROJ to 1e-6 m, and with a scale-free
    map CRS (transverse Mercator with k = 1 through the block) every marker reprojects as before to
    0.05 px (the rotation follows the meridian convergence and the tangent-plane tilt)."""
    from pyproj import Transformer

    from lidarcat.interop.block import reprojection_residuals_px

    tm = "+proj=tmerc +lat_0=35.7378 +lon_0=139.5404 +k=1 +x_0=0 +y_0=0 +ellps=WGS84 +units=m +no_defs"
    for crs, name in (("EPSG:32654", "utm"), (tm, "tm")):
        b = read_metashape(D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml",
                           D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml", crs=crs)
        write_opensfm(b, tmp_path / name)
        rec = json.loads((tmp_path / name / "reconstruction.json").read_text())[0]
        assert set(rec["reference_lla"]) == {"latitude", "longitude", "altitude"}
        back = read_opensfm(tmp_path / name / "reconstruction.json")
        idx = b.photo_index()
        order = [idx[p] for p in back.photo_ids.tolist()]
        lon, lat, h = Transformer.from_pipeline(back.crs.split(": ", 1)[1]).transform(
            *back.eo[:, :3].T, direction="INVERSE")
        grid = np.column_stack(Transformer.from_crs("EPSG:4979", crs, always_xy=True).transform(lon, lat, h))
        assert np.abs(grid - b.eo[order, :3]).max() < 1e-6
        if name == "tm":
            r0 = dict(zip(zip(b.obs_photo.tolist(), b.obs_point.tolist()), reprojection_residuals_px(b)))
            r1 = dict(zip(zip(back.obs_photo.tolist(), back.obs_point.tolist()), reprojection_residuals_px(back)))
            assert len(r1) == 23 and max(np.abs(r0[k] - r1[k]).max() for k in r1) < 0.05
