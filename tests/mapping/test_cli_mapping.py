"""``lidarcat monoplot`` and ``lidarcat ortho`` on a small survey of the rendered synthetic scene."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.geometry.collinearity import project
from lidarcat.cli.main import cli
from lidarcat.lidar import PointCloud, resolve_crs, write_points
from lidarcat.lidar.geotiff import write_geotiff
from lidarcat.synthetic.scene import demo_scene

from ortho_scene import CAM, E0, EO_A, EO_B, MODEL_BOUNDS, N0, rendered  # noqa: I001  (same camera and photos)

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
        cv2.imwrite(str(root / "images" / f"{pid}.png"), rendered(pid))
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
    for extra, msg in ((["--surface", str(root / "dsm.tif"), "--interpolator", "tin"],
                        "--interpolator tin triangulates LiDAR points (--lidar); a --surface grid takes nearest "
                        "or bilinear"),
                       (["--interpolator", "bilinear"],
                        "--interpolator bilinear interpolates a grid (--surface DSM.tif); LiDAR points take tin "
                        "or nearest")):
        r = CliRunner().invoke(cli, ["monoplot", str(root), "--photo", "A", "--features", str(tmp_path / "f.csv"),
                                     *extra, "-o", str(out2)])
        assert r.exit_code == 2 and msg in " ".join(r.output.replace("│", " ").split()), r.output
    assert not out2.exists()


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
    r = CliRunner().invoke(cli, ["ortho", str(root), "--photo", "A", "--dsm", str(root / "dsm.tif"), "--feather",
                                 "2", "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and "--feather blends the mosaic's seamlines: give it with --mosaic" in r.output
    assert not (tmp_path / "x").exists()
    r = CliRunner().invoke(cli, ["ortho", str(root), "--photo", "A", "--photo", "B", "--dsm", str(root / "dsm.tif"),
                                 "--eop", str(root / "eop_only_a.csv"), "-o", str(tmp_path / "x")])
    assert r.exit_code == 2 and f"{root / 'eop_only_a.csv'}: photo 'B' was not adjusted" in r.output
    assert not (tmp_path / "x").exists()
    assert math.isfinite(float(np.nanmax(m)))


@pytest.mark.parametrize("name, text, message", [
    ("a.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"id": "r1"}, '
                  '"geometry": {"type": "MultiPoint", "coordinates": [[1, 2]]}}]}',
     "a.geojson: feature 'r1': geometry type 'MultiPoint'; use Point, LineString or Polygon (one part per feature)"),
    ("b.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"id": "L"}, '
                  '"geometry": {"type": "LineString", "coordinates": [[1, 2]]}}]}',
     "b.geojson: feature 'L': a line needs at least 2 vertices"),
    ("c.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"id": "p"}, '
                  '"geometry": {"type": "Point", "coordinates": ["x", 2]}}]}',
     "c.geojson: feature 'p': coordinates are not [col_px, row_px] numbers"),
    ("d.geojson", '{"type": "Feature"', "d.geojson:1: invalid JSON"),
    ("e.csv", "feature,col_px,row_px\nA,1,2\nB,3,4\nA,5,6\n", "e.csv:4: field 'feature': rows of feature 'A' are not consecutive"),
    ("f.csv", "feature,col_px,row_px,geometry\nA,1,2,polygon\nA,3,4,polygon\n",
     "f.csv:2: field 'feature': feature 'A' is a polygon with 2 vertices"),
    ("g.txt", "x", "g.txt: unknown feature file type '.txt'; use .geojson or .csv"),
    ("h.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {"id": "p"}, '
                  '"geometry": {"type": "Point", "coordinates": [1, 2]}}, null]}',
     "h.geojson: feature 2 is not a GeoJSON Feature object (with object 'properties' and 'geometry')"),
    ("i.geojson", '{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": ["p"], '
                  '"geometry": {"type": "Point", "coordinates": [1, 2]}}]}',
     "i.geojson: feature 1 is not a GeoJSON Feature object (with object 'properties' and 'geometry')"),
])
def test_feature_file_errors_are_located(tmp_path, name, text, message):
    from lidarcat.mapping.features import FeatureError, read_features

    (tmp_path / name).write_text(text)
    with pytest.raises(FeatureError) as ei:
        read_features(tmp_path / name)
    assert str(ei.value).startswith(f"{tmp_path}/{message}")      # file (and line) first, exact text


def _run_mapping_stage(work, tmp_path):
    """Plan the survey at *work* (the mapping stage waits for an adjustment), then run the stage itself on
    the fixture's adjustment folder out/adjust-gps; (result, output folder)."""
    from types import SimpleNamespace

    from lidarcat.pipeline.plan import plan_pipeline
    from lidarcat.pipeline.runner import Context
    from lidarcat.stages import mapping
    from lidarcat.survey.folder import Survey

    s = Survey.load(work)
    stage = next(st for st in plan_pipeline(s) if st.name == "mapping")
    assert stage.skip_reason == "no adjustment (control set) to take the orientations from"
    ctx = Context(work, values={"survey": s})
    ctx.records["adjust-gps"] = SimpleNamespace(folder="out/adjust-gps")
    ctx.stage = SimpleNamespace(params={"adjust": "adjust-gps"})
    out = tmp_path / "mapping"
    out.mkdir()
    return mapping.run(ctx, out), out


def test_run_mapping_stage_when_the_survey_asks(survey, tmp_path):
    """The [mapping] table: parsed with located errors, planned as a stage of lidarcat run,
    and the stage writes the surface model, the true orthophotos and the mosaic."""
    import shutil

    from lidarcat.errors import SurveyError
    from lidarcat.pipeline.plan import plan_pipeline
    from lidarcat.stages import mapping
    from lidarcat.survey.folder import Survey

    root, scene, _ = survey
    s0 = Survey.load(root)
    assert "mapping" not in [st.name for st in plan_pipeline(s0)]      # no [mapping] table: no stage
    work = tmp_path / "s"
    shutil.copytree(root, work)
    toml = work / "survey.toml"
    base = toml.read_text()
    toml.write_text(base + '\n[mapping]\northophotos = true\nsurface = "dsn"\n')
    with pytest.raises(SurveyError, match=r"survey\.toml:\d+: field 'surface': 'dsn' is not 'dsm' \(true "
                                          r"orthophotos\) or 'dtm'"):
        mapping.settings(Survey.load(work))
    toml.write_text(base + '\n[mapping]\northophotos = true\ngsd_m = 1.0\ncell_m = 0.5\n')
    res, out = _run_mapping_stage(work, tmp_path)
    assert sorted(p.name for p in out.iterdir()) == [
        "dsm.png", "dsm.tif", "mosaic.png", "mosaic.tif", "ortho_A.png", "ortho_A.tif", "ortho_B.png",
        "ortho_B.tif", "seamlines.geojson"]
    assert [o["photo"] for o in res["orthophotos"]] == ["A", "B"] and res["mosaic"]["gsd_m"] == 1.0
    assert all(o["true_ortho"] for o in res["orthophotos"])


def test_run_mapping_stage_monoplots_and_judges_features_per_interpolator(survey, tmp_path):
    """[mapping] features + reference: the stage monorestitutes by each interpolator, writes the paper's
    Tables 07-09 (accuracy.csv, the stage result for summary.json) and the run report shows one table per
    interpolator and the r90 table; vertices not ok or without reference are counted, not judged."""
    import shutil

    from lidarcat.errors import SurveyError
    from lidarcat.pipeline.runner import StageRecord
    from lidarcat.stages import mapping, report
    from lidarcat.survey.folder import Survey

    root, scene, verts = survey
    work = tmp_path / "s"
    shutil.copytree(root, work)
    g = np.array([[E0 + e, N0 + n] for e in (-10.0, 0.0, 10.0) for n in (-8.0, 8.0)])
    ground = np.column_stack([g, scene.terrain(g[:, 0], g[:, 1])])
    # a ground point is kept only where no building stands on it
    _, lab = scene.surface(ground[:, 0], ground[:, 1])
    ground = ground[lab <= 1]
    truth = {}
    for pid, eo in (("A", EO_A), ("B", EO_B)):
        pv, pg = _px(verts, eo), _px(ground, eo)
        feats = [{"type": "Feature", "properties": {"id": f"{pid}V{i}", "class": "building"},
                  "geometry": {"type": "Point", "coordinates": p.tolist()}} for i, p in enumerate(pv)]
        feats.append({"type": "Feature", "properties": {"id": f"{pid}G", "class": "road"},
                      "geometry": {"type": "LineString", "coordinates": pg.tolist()}})
        truth.update({(f"{pid}V{i}", 0): v[:2] for i, v in enumerate(verts)})
        truth.update({(f"{pid}G", k): v[:2] for k, v in enumerate(ground)})
        if pid == "A":   # one vertex outside the photo (status), one feature the reference does not list
            k_in = int(np.flatnonzero(CAM.contains(pg))[0])
            feats.append({"type": "Feature", "properties": {"id": "off", "class": "road"},
                          "geometry": {"type": "LineString", "coordinates": [pg[k_in].tolist(), [-20.0, 10.0]]}})
            truth.update({("off", 0): ground[k_in, :2], ("off", 1): ground[k_in, :2]})
            feats.append({"type": "Feature", "properties": {"id": "free", "class": "road"},
                          "geometry": {"type": "Point", "coordinates": [500.0, 400.0]}})
        (work / f"f{pid}.geojson").write_text(json.dumps({"type": "FeatureCollection", "features": feats}))
    (work / "ref.csv").write_text("feature,vertex,E,N\n" + "".join(
        f"{f},{v},{p[0]:.4f},{p[1]:.4f}\n" for (f, v), p in truth.items()))
    toml = work / "survey.toml"
    base = toml.read_text()
    cfg = ('\n[mapping]\nfeatures = { A = "fA.geojson", B = "fB.geojson" }\nreference = "ref.csv"\n'
           'interpolators = ["nearest", "tin", "bilinear"]\ncell_m = 0.25\n')
    for bad, msg in (('interpolators = ["idw"]', r"field 'interpolators': idw: use nearest, tin, bilinear"),
                     ('features = { Z = "fA.geojson" }', r"field 'features': photo\(s\) Z are not in the survey"),
                     ('method = "newton"', r"field 'method': 'newton' is not 'exact' \(first hit\) or 'iterate'")):
        toml.write_text(base + "\n[mapping]\n" + bad + ("" if "features" in bad else '\nfeatures = { A = "f.csv" }')
                        + "\n")
        with pytest.raises(SurveyError, match=r"survey\.toml:\d+: " + msg):
            mapping.settings(Survey.load(work))
    toml.write_text(base + cfg)
    res, out = _run_mapping_stage(work, tmp_path)     # planned without orthophotos
    assert sorted(p.name for p in out.iterdir()) == ["accuracy.csv", "accuracy.csv.json"] + sorted(
        f"monoplot_{p}_{i}.geojson" for p in "AB" for i in ("bilinear", "nearest", "tin"))
    assert "orthophotos" not in res
    gsd = CAM.pixel_size_x_mm * 250 / CAM.focal_length_mm
    nv = 2 * len(verts)
    # vertices outside a photo's frame (status outside_photo, not judged): roofs, ground points
    out_b, out_g = (sum(int((~np.asarray(CAM.contains(_px(p, eo)))).sum()) for eo in (EO_A, EO_B))
                    for p in (verts, ground))
    for interp in ("nearest", "tin", "bilinear"):
        a = res["accuracy"][interp]
        assert (a["n_vertices"], a["n_not_ok"], a["n_no_reference"]) == (nv + 2 * len(ground) + 3,
                                                                          1 + out_b + out_g, 1), res["photos"]
        assert a["classes"]["building"]["n"] == nv - out_b and a["classes"]["road"]["n"] == 2 * len(ground) + 1 - out_g
        # r90 recomputed from the written GeoJSON files against the truth: the smallest radius holding 90 %
        radii = {"building": [], "road": []}
        for pid in "AB":
            doc = json.loads((out / f"monoplot_{pid}_{interp}.geojson").read_text())
            assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31982"
            for f in doc["features"]:
                fid, geom = f["properties"]["id"], f["geometry"]
                if geom is None or fid == "free":
                    continue
                pts = [geom["coordinates"]] if geom["type"] == "Point" else geom["coordinates"]
                radii[f["properties"]["class"]] += [float(np.hypot(*(truth[(fid, k)] - np.array(p[:2]))))
                                                    for k, p in enumerate(pts)]
        road_a = json.loads((out / f"monoplot_A_{interp}.geojson").read_text())["features"]
        assert [f["properties"]["status"] for f in road_a if f["properties"]["id"] == "off"] == ["outside_photo"]
        # the 'off' line's first vertex is ok and judged (rounded to 0.1 mm in the file)
        for c in ("building", "road"):
            r = np.sort(radii[c])
            want = a["classes"][c]["r90_m"]
            if c == "road":
                assert len(r) == 2 * len(ground) - out_g and want >= r[int(np.ceil(0.9 * len(r))) - 1] - 1e-3
            else:
                assert want == pytest.approx(r[int(np.ceil(0.9 * len(r))) - 1], abs=2e-4)
        assert res["table_09"][interp] == {c: t["r90_m"] for c, t in a["classes"].items()}
    # the acceptance of issue 14: TIN of the LiDAR within 1.5 ground pixels on roof vertices and ground
    assert res["table_09"]["tin"]["building"] < 1.5 * gsd and res["table_09"]["tin"]["road"] < 1.5 * gsd
    rows = (out / "accuracy.csv").read_text().splitlines()
    assert rows[0] == ",".join(mapping.ACCURACY_COLUMNS) and len(rows) == 1 + 3 * 2
    # summary.json and the report: the stage's result goes in as it is
    rec = StageRecord("mapping", "mapping", "ran", result=res)
    doc = report.results([rec])
    assert doc["mapping"]["table_09"] == res["table_09"]
    md = report._report_markdown({"survey": "s", "stages": [], **doc})
    for interp in ("nearest", "tin", "bilinear"):
        assert f"### Interpolator {interp} (" in md
        assert (f"| {interp} | {res['table_09'][interp]['building']:.2f} | {res['table_09'][interp]['road']:.2f} |"
                in md)
    t = res["accuracy"]["tin"]["classes"]["building"]
    assert f"| building | {nv - out_b} | {t['mean_E']:.3f} | {t['sd_E']:.3f} |" in md
    assert "Radius holding 90 % of the points, m (Cavassim Table 09)" in md


@pytest.mark.parametrize("text, message", [
    ("feature,vertex,E\nA,0,1\n", "ref.csv:1: missing column 'N' (header is feature, vertex, E)"),
    ("feature,vertex,E,N\nA,x,1,2\n", "ref.csv:2: field 'vertex': 'x' is not a vertex number (0, 1, ...)"),
    ("feature,vertex,E,N\nA,0,1,2\nA,0,3,4\n", "ref.csv:3: field 'feature': feature 'A' vertex 0 is given twice"),
])
def test_reference_file_errors_are_located(tmp_path, text, message):
    from lidarcat.errors import SurveyError
    from lidarcat.mapping.accuracy import read_reference

    (tmp_path / "ref.csv").write_text(text)
    with pytest.raises(SurveyError) as ei:
        read_reference(tmp_path / "ref.csv")
    assert str(ei.value).startswith(f"{tmp_path}/{message}")


def test_lidar_surface_of_an_empty_area_names_the_area_and_the_tiles(survey):
    from lidarcat.errors import SurveyError
    from lidarcat.lidar import TileIndex
    from lidarcat.mapping.inputs import lidar_surface

    root, _, _ = survey
    index = TileIndex.build([str(root / "lidar" / "tile.laz")], crs=CRS)
    s = lidar_surface(index, (E0 - 5, N0 - 5, E0 + 5, N0 + 5), "nearest")
    assert s.interpolator == "nearest"
    with pytest.raises(SurveyError) as ei:
        lidar_surface(index, (0.0, 0.0, 10.0, 10.0))
    assert str(ei.value) == f"no LiDAR points in E 0.0..10.0, N 0.0..10.0 (tiles: {root / 'lidar' / 'tile.laz'})"


def test_run_mapping_stage_a_missing_reference_stops_it_before_any_monoplot(survey, tmp_path):
    import shutil

    from lidarcat.errors import SurveyError

    root, _, _ = survey
    work = tmp_path / "s"
    shutil.copytree(root, work)
    (work / "f.csv").write_text("feature,col_px,row_px\np,600,400\n")
    with open(work / "survey.toml", "a", encoding="utf-8") as f:
        f.write('\n[mapping]\nfeatures = { A = "f.csv" }\nreference = "nowhere.csv"\n')
    with pytest.raises(SurveyError) as ei:
        _run_mapping_stage(work, tmp_path)
    assert str(ei.value) == f"{work / 'nowhere.csv'}: file not found"
    assert list((tmp_path / "mapping").iterdir()) == []
