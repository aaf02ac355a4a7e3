"""Issue 25: orthority reads lidarcat's exports as a user would -- the OPK export in orthority's CSV
flavour (with its .prj) and the OpenSfM export (cameras, reference_lla) -- and projects the block's
points where lidarcat does.  orthority is an optional, test-only dependency (AGPL-3.0); the tests skip
without it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.interop.block import block_from_survey, reprojection_residuals_px
from lidarcat.interop.lens import export_camera

oty = pytest.importorskip("orthority")
param_io = pytest.importorskip("orthority.param_io")

D = Path(__file__).parents[1] / "data" / "interop"
THESIS_ADJ = Path(__file__).parents[1] / "data" / "report"
pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # orthority: "sensor_size not specified"


def _export(tmp_path: Path, *src: str) -> tuple[Path, Path]:
    for args in (["opensfm", *src, "-o", tmp_path / "osfm"], ["opk", *src, "--flavour", "orthority",
                                                                "-o", tmp_path / "ext.csv"]):
        res = CliRunner().invoke(cli, ["export", *[str(a) for a in args]])
        assert res.exit_code == 0, res.output
    return tmp_path / "osfm" / "reconstruction.json", tmp_path / "ext.csv"


def _orthority_pixels(block, rec: Path, csv: Path) -> tuple[np.ndarray, object]:
    """orthority's projection (pixel centre origin) of every observed point of *block*."""
    reader = param_io.CsvReader(csv)
    cams = oty.FrameCameras(param_io.read_oty_int_param(csv.with_name(csv.stem + "_int_param.yaml")),
                            reader.read_ext_param())
    out = np.array([cams.get(ph).world_to_pixel(block.point([pt])[0].reshape(3, 1)).ravel()
                    for ph, pt in zip(block.obs_photo.tolist(), block.obs_point.tolist())])
    return out, reader.crs


def test_metashape_block_through_orthority(tmp_path):
    """A Metashape block (exact camera conversion) exported and read by orthority: its projection
    of the markers equals lidarcat's (Metashape's camera model) to 1e-6 px; the CRS comes from the .prj."""
    out = tmp_path / "ms"
    res = CliRunner().invoke(cli, ["import", "metashape", str(D / "metashape" / "easyidp_wheat_tanashi_chunk.doc.xml"),
                                   "--frame", str(D / "metashape" / "easyidp_wheat_tanashi_frame.doc.xml"),
                                   "-o", str(out)])
    assert res.exit_code == 0, res.output
    rec, csv = _export(tmp_path, out)
    b = block_from_survey(out)
    px, crs = _orthority_pixels(b, rec, csv)
    mine = reprojection_residuals_px(b) + b.obs_px  # projected, pixel centre origin
    assert crs.to_epsg() == 32654 and len(px) == 23
    assert np.abs(px - mine).max() <= 1e-6
    # the OpenSfM export's cameras read by orthority give the same (a landscape image: orthority
    # normalises an OpenSfM focal by the width, OpenSfM by max(w, h))
    cams = oty.FrameCameras(param_io.read_osfm_int_param(rec), param_io.CsvReader(csv).read_ext_param())
    px2 = np.array([cams.get(ph).world_to_pixel(b.point([pt])[0].reshape(3, 1)).ravel()
                    for ph, pt in zip(b.obs_photo.tolist(), b.obs_point.tolist())])
    assert np.abs(px2 - mine).max() <= 1e-6


def test_adjusted_thesis_block_through_orthority(tmp_path):
    """The adjusted thesis block (a distorted camera, fitted): orthority projects the adjusted points
    within the fit's largest misfit of lidarcat's own projection (eq. 01-08)."""
    from lidarcat.geometry.collinearity import project

    rec, csv = _export(tmp_path, THESIS_ADJ)
    b = block_from_survey(None, THESIS_ADJ)
    px, crs = _orthority_pixels(b, rec, csv)
    assert crs.to_epsg() == 29192
    cam = b.cameras["dcs14n"]
    idx = b.photo_index()
    eo = b.eo[[idx[p] for p in b.obs_photo.tolist()]]
    xy, _ = project(eo, b.point(b.obs_point), cam.focal_length_mm)
    mine = np.asarray(cam.photo_to_pixel(xy))
    ok = np.isfinite(mine).all(axis=1) & np.isfinite(px).all(axis=1)
    assert ok.sum() > 100
    assert np.abs(px[ok] - mine[ok]).max() <= export_camera(cam, rational=False)["fit_max_px"] + 1e-6


def test_opensfm_export_georeferenced_for_orthority(tmp_path):
    """import opensfm -> export opensfm keeps reference_lla, so orthority's OpenSfM reader places the
    shots in a world CRS where lidarcat's topocentric centres, taken through PROJ, are."""
    from pyproj import Transformer

    out = tmp_path / "s"
    res = CliRunner().invoke(cli, ["import", "opensfm", str(D / "opensfm" / "berlin_reconstruction_example.json"),
                                   "--tracks", str(D / "opensfm" / "berlin_tracks_example.csv"),
                                   "--control-sd-m", "0.01", "-o", str(out)])
    assert res.exit_code == 0, res.output
    res = CliRunner().invoke(cli, ["export", "opensfm", str(out), "-o", str(tmp_path / "o")])
    assert res.exit_code == 0, res.output
    rec = tmp_path / "o" / "reconstruction.json"
    assert "reference_lla" in json.loads(rec.read_text())[0]
    ext = param_io.OsfmReader(rec, crs="EPSG:32633").read_ext_param()
    b = block_from_survey(out)
    to_ll = Transformer.from_pipeline(b.crs.split(": ", 1)[1]).transform
    to_utm = Transformer.from_crs("EPSG:4979", "EPSG:32633", always_xy=True).transform
    for pid, e in zip(b.photo_ids.tolist(), b.eo):
        lon, lat, h = to_ll(*e[:3], direction="INVERSE")
        assert np.allclose(ext[pid]["xyz"], to_utm(lon, lat, h), atol=1e-3)


def test_fisheye_camera_through_orthority():
    """The real T265 fisheye cameras (kapture, tests/data/README.md) in orthority's interior parameters: a
    ``fisheye`` (OpenCV k1..k4) camera whose projection of every observed point equals lidarcat's (the
    COLMAP model's, pycolmap-projected pixels) to 1e-6 px."""
    from orthority.camera import create_camera

    from lidarcat.interop.colmap import read_colmap
    from lidarcat.interop.opk import orthority_int_param

    b = read_colmap(D / "colmap" / "t265_points")
    par = json.loads(orthority_int_param(b))
    assert par["1"]["type"] == "fisheye" and (par["1"]["k3"], par["1"]["k4"]) == (-0.03, 0.005)
    mine = reprojection_residuals_px(b) + b.obs_px  # projected, pixel centre origin
    idx = b.photo_index()
    px = []
    for ph, pt in zip(b.obs_photo.tolist(), b.obs_point.tolist()):
        e = b.eo[idx[ph]]
        p = dict(par[b.photo_camera[idx[ph]]])
        cam = create_camera(p.pop("type"), **p, xyz=tuple(e[:3]), opk=tuple(e[3:]))
        px.append(cam.world_to_pixel(b.point([pt])[0].reshape(3, 1)).ravel())
    assert len(px) == 480 and np.abs(np.array(px) - mine).max() <= 1e-6
