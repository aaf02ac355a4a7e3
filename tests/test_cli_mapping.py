"""``lidarcat monoplot`` and ``lidarcat ortho`` on a small survey of the rendered synthetic scene."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat._collinearity import project
from lidarcat.cli.main import cli
from lidarcat.lidar import PointCloud, resolve_crs, write_points
from lidarcat.lidar.raster import write_geotiff
from lidarcat.scene import demo_scene

from test_ortho import CAM, E0, EO_A, EO_B, MODEL_BOUNDS, N0  # noqa: I001  (same camera and photos)

CRS = "EPSG:31982"


def _px(points: np.ndarray, eo: np.ndarray) -> np.ndarray:
    xy, _ = project(np.broadcast_to(eo, (len(points), 6)), points, np.full(len(points), CAM.focal_length_mm))
    return CAM.photo_to_pixel(xy)


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """Camera, two photos with images, adjusted orientations, LiDAR tiles and a DSM GeoTIFF."""
    root = tmp_path_factory.mktemp("mapping_survey")
    scene = demo_scene()
    (root / "camera.toml").write_text(CAM.to_toml())
    (root / "photos.csv").write_text("photo,camera\nA,small\nB,small\n")
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\nA,T1,600,400\nB,T1,610,390\n")
    (root / "survey.toml").write_text(f'[survey]\nname = "mapping"\ncrs = "{CRS}"\n\n[files]\ncamera = '
                                      f'"camera.toml"\nphotos = "photos.csv"\nimage_points = '
                                      f'"image_points.csv"\nlidar = ["lidar/*.laz"]\n\n[lidar]\ncrs = "{CRS}"\n')
    (root / "images").mkdir()
    for pid, eo in (("A", EO_A), ("B", EO_B)):
        cv2.imwrite(str(root / "images" / f"{pid}.png"), scene.render(CAM, eo))
    eop = root / "out" / "adjust-gps"
    eop.mkdir(parents=True)
    rows = ["photo,X0,Y0,Z0,omega,phi,kappa,sd_X0,sd_Y0,sd_Z0,sd_omega,sd_phi,sd_kappa"]
    for pid, eo in (("A", EO_A), ("B", EO_B)):
        rows.append(",".join([pid, *(f"{v:.6f}" for v in eo[:3]), *(f"{v:.8f}" for v in np.degrees(eo[3:])),
                              "0.05", "0.05", "0.05", "0.001", "0.001", "0.001"]))
    (eop / "eop.csv").write_text("\n".join(rows) + "\n")
    (root / "eop_only_a.csv").write_text("\n".join(rows[:2]) + "\n")
    pts = scene.lidar_points(MODEL_BOUNDS, 4.0, noise_m=0.05, seed=2)
    (root / "lidar").mkdir()
    write_points(root / "lidar" / "tile.laz",
                 PointCloud(pts["xyz"], {"classification": pts["classification"]}, crs=resolve_crs(CRS)))
    grid, t = scene.grid(MODEL_BOUNDS, 0.25, "dsm")
    write_geotiff(root / "dsm.tif", grid, t, CRS)
    verts = np.vstack([b.vertices(scene.base_height(i)) for i, b in enumerate(scene.buildings)])
    return root, scene, verts


def test_monoplot_cli_lidar_tin_geojson_within_1_5_pixels(survey, tmp_path):
    root, scene, verts = survey
    px = _px(verts, EO_A)
    feats = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"id": f"V{i}", "class": "roof"},
         "geometry": {"type": "Point", "coordinates": p.tolist()}} for i, p in enumerate(px)]
        + [{"type": "Feature", "properties": {"id": "off", "class": "road"},
            "geometry": {"type": "LineString", "coordinates": [[300.0, 300.0], [-20.0, 10.0]]}}]}
    (tmp_path / "f.geojson").write_text(json.dumps(feats))
    out = tmp_path / "m.geojson"
    r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "A", "--features", str(tmp_path / "f.geojson"),
                                 "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output)
    assert summary["status"] == {"ok": len(verts) + 1, "outside_photo": 1}
    doc = json.loads(out.read_text())
    assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31982"
    assert doc["lidarcat"]["interpolator"] == "tin"
    got = np.array([f["geometry"]["coordinates"] for f in doc["features"][:-1]])
    gsd = CAM.pixel_size_x_mm * 250 / CAM.focal_length_mm
    assert np.hypot(*(got[:, :2] - verts[:, :2]).T).max() < 1.5 * gsd
    last = doc["features"][-1]
    assert last["geometry"] is None and last["properties"]["status"] == "outside_photo"
    assert last["properties"]["vertex_status"] == ["ok", "outside_photo"]


def test_monoplot_cli_dsm_csv_and_located_errors(survey, tmp_path):
    root, scene, verts = survey
    px = _px(verts[:2], EO_B)
    (tmp_path / "f.csv").write_text("feature,class,col_px,row_px\n"
                                    + "".join(f"P{i},roof,{c},{r}\n" for i, (c, r) in enumerate(px)))
    out = tmp_path / "m.csv"
    r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "B", "--features", str(tmp_path / "f.csv"),
                                 "--surface", str(root / "dsm.tif"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "2 features (2 vertices) on photo B: ok 2" in r.output
    lines = out.read_text().splitlines()
    assert lines[0] == "feature,class,vertex,col_px,row_px,E,N,h,sd_E,sd_N,sd_h,status"
    vals = np.array([[float(v) for v in ln.split(",")[5:8]] for ln in lines[1:]])
    assert np.hypot(*(vals[:, :2] - verts[:2, :2]).T).max() < 0.3
    # B was not adjusted in this orientation file: one line, exit 2, nothing written
    out2 = tmp_path / "m2.csv"
    r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "B", "--features", str(tmp_path / "f.csv"),
                                 "--surface", str(root / "dsm.tif"), "--eop", str(root / "eop_only_a.csv"),
                                 "-o", str(out2)])
    assert r.exit_code == 2
    assert f"{root / 'eop_only_a.csv'}: photo 'B' was not adjusted (it is not in this file); " \
           f"adjusted photos: A" in r.output
    assert not out2.exists()
    (tmp_path / "bad.csv").write_text("feature,col_px,row_px\nP1,10,x\n")
    r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "A", "--features", str(tmp_path / "bad.csv"),
                                 "--surface", str(root / "dsm.tif"), "-o", str(out2)])
    assert r.exit_code == 2 and f"{tmp_path / 'bad.csv'}:2: field 'row_px': 'x' is not a number" in r.output
    r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "Z", "--features", str(tmp_path / "f.csv"),
                                 "--surface", str(root / "dsm.tif"), "-o", str(out2)])
    assert r.exit_code == 2 and "no photo 'Z' in the survey (photos: A, B)" in r.output


def test_ortho_cli_true_orthos_and_mosaic(survey, tmp_path):
    rasterio = pytest.importorskip("rasterio")
    root, scene, _ = survey
    out = tmp_path / "o"
    b = [E0 - 60, N0 - 40, E0 + 60, N0 + 40]
    r = CliRunner().invoke(cli, ["ortho", str(root), "--all", "--dsm", str(root / "dsm.tif"), "--gsd", "0.5",
                                 "--bounds", *map(str, b), "--mosaic", "-o", str(out), "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads(r.output)
    assert [o["photo"] for o in summary["orthophotos"]] == ["A", "B"]
    assert all(o["true_ortho"] and o["n_occluded"] > 0 for o in summary["orthophotos"])
    assert sorted(p.name for p in out.iterdir()) == ["mosaic.png", "mosaic.tif", "ortho_A.png", "ortho_A.tif",
                                                    "ortho_B.png", "ortho_B.tif", "seamlines.geojson"]
    ref, _ = scene.grid(b, 0.5, "texture")
    with rasterio.open(out / "mosaic.tif") as src:
        assert src.crs.to_epsg() == 31982 and src.transform.c == b[0] and src.transform.f == b[3]
        m = src.read(1)
    assert np.nanmedian(np.abs(m - ref)) < 2.0
    r = CliRunner().invoke(cli, ["ortho", str(root), "--photo", "A", "--dtm", str(root / "dsm.tif"),
                                 "--images", str(tmp_path), "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and f"{tmp_path}: no image of photo 'A'" in r.output
    r = CliRunner().invoke(cli, ["ortho", str(root), "--photo", "A", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and "give one of --dtm (standard orthophoto) or --dsm (true orthophoto)" in r.output
    assert not (tmp_path / "x").exists()
    assert math.isfinite(float(np.nanmax(m)))
