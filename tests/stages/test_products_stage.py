"""The ``products`` stage of ``lidarcat run``: survey.toml ``[products]`` -> ground, DTM, DSM, contours, sheets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.lidar import PointCloud, read_points, resolve_crs, write_points
from lidarcat.pipeline.plan import plan_pipeline
from lidarcat.pipeline.runner import run_stages
from lidarcat.stages import products
from lidarcat.synthetic.scene import demo_scene
from lidarcat.survey.folder import Survey

from ortho_scene import CAM, MODEL_BOUNDS  # noqa: I001  (the synthetic scene's camera and area)

CRS = "EPSG:31982"
BASE = (f'[survey]\nname = "products"\ncrs = "{CRS}"\n\n[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\n'
        f'image_points = "image_points.csv"\nlidar = ["lidar/*.laz"]\n\n[lidar]\ncrs = "{CRS}"\n')


def _raster(path):
    """Grid, GeoTransform and EPSG code of a GeoTIFF (read by rasterio: a COG)."""
    from lidarcat.lidar.raster import GeoTransform

    import rasterio

    with rasterio.open(path) as ds:
        return (ds.read(1), GeoTransform(ds.transform.c, ds.transform.f, ds.transform.a),
                ds.crs.to_epsg() if ds.crs else None)


def _work(root, tmp_path, toml):
    """A copy of the fixture survey (files linked) whose survey.toml is *toml*."""
    work = tmp_path / "s"
    work.mkdir()
    for p in root.iterdir():
        if p.name != "survey.toml":
            (work / p.name).symlink_to(p)
    (work / "survey.toml").write_text(toml)
    return work


def run_products(root, tmp_path, toml):
    """The products stage of a copy of the survey at *root* with *toml*, run into ``tmp_path/out``;
    returns (stage record, products folder), the stage asserted to have run."""
    s = Survey.load(_work(root, tmp_path, toml))
    stage = next(st for st in plan_pipeline(s) if st.name == "products")
    rec = run_stages([stage], tmp_path / "out", values={"survey": s})[0]
    assert rec.status == "ran", rec.reason
    return rec, tmp_path / "out" / "products"


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """A survey with two LiDAR tiles of the synthetic scene whose classes are all 1 (unclassified)."""
    root = tmp_path_factory.mktemp("products_survey")
    scene = demo_scene()
    (root / "camera.toml").write_text(CAM.to_toml())
    (root / "photos.csv").write_text("photo,camera\nA,small\nB,small\n")
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\nA,T1,600,400\nB,T1,610,390\n")
    (root / "survey.toml").write_text(BASE)
    pts = scene.lidar_points(MODEL_BOUNDS, 2.0, noise_m=0.05, seed=3)
    (root / "lidar").mkdir()
    xmid = 0.5 * (MODEL_BOUNDS[0] + MODEL_BOUNDS[2])
    truth = {}
    for name, sel in (("west", pts["xyz"][:, 0] < xmid), ("east", pts["xyz"][:, 0] >= xmid)):
        attrs = {"classification": np.ones(int(sel.sum()), np.uint8),   # the filter must find the ground
                 "intensity": pts["intensity"][sel], "return_number": pts["return_number"][sel],
                 "number_of_returns": pts["number_of_returns"][sel]}
        write_points(root / "lidar" / f"{name}.laz", PointCloud(pts["xyz"][sel], attrs, crs=resolve_crs(CRS)))
        truth[name] = pts["classification"][sel] == 2
    return root, scene, truth


def test_without_products_table_the_plan_is_unchanged(survey, tmp_path):
    root, _, _ = survey
    without = [st.name for st in plan_pipeline(Survey.load(root))]
    assert "products" not in without
    with_table = [st.name for st in plan_pipeline(Survey.load(_work(root, tmp_path, BASE + "\n[products]\n")))]
    assert [n for n in with_table if n != "products"] == without
    assert with_table.index("products") == len(with_table) - 2          # before the report


@pytest.mark.parametrize("extra, message", [
    ("dtm = true\ncontour_step = 2\n",
     r"survey\.toml:\d+: .*unknown key 'contour_step' in \[products\]; allowed: ground, filter, dtm"),
    ('filter = "tin"\n', r"survey\.toml:\d+: field 'filter': 'tin' is not one of 'ptd', 'smrf', 'csf'"),
    ("cell_m = 0\n", r"survey\.toml:\d+: field 'cell_m': must be positive \(metres\), got 0"),
    ("max_edge_m = inf\n", r"survey\.toml:\d+: field 'max_edge_m': must be a finite number, got inf"),
    ("sheet_size_m = nan\n", r"survey\.toml:\d+: field 'sheet_size_m': must be a finite number, got nan"),
    ("dtm = false\nndsm = true\n", r"survey\.toml:\d+: field 'ndsm': needs dtm = true and dsm = true"),
    ('sheet_index = "brazil-1000"\n', r"survey\.toml:\d+: field 'sheet_index': 'brazil-1000' is not one of 'grid', "),
    ('sheet_index = "brazil-5000"\nsheet_size_m = 500\n',
     r"survey\.toml:\d+: field 'sheet_size_m': applies to sheet_index = 'grid' only"),
    ('vector_format = "shp"\n', r"survey\.toml:\d+: field 'vector_format': 'shp' is not 'geojson' or 'gpkg'"),
])
def test_bad_products_table_is_a_located_error(survey, tmp_path, extra, message):
    root, _, _ = survey
    work = _work(root, tmp_path, BASE + "\n[products]\n" + extra)
    with pytest.raises(SurveyError, match=message):
        plan_pipeline(Survey.load(work))


def test_products_stage_writes_what_is_asked_with_crs(survey, tmp_path):
    """ground + DTM + DSM + nDSM + contours + sheets on two tiles; checked against the scene's truth."""
    root, scene, truth = survey
    work = _work(root, tmp_path, BASE + "\n[products]\ncell_m = 2.0\nndsm = true\ncontour_interval_m = 1.0\n"
                                  "master_every = 5\nhypsometry = true\nhypsometry_cell_m = 2.0\n"
                                  "sheet_size_m = 100\n")
    s = Survey.load(work)
    stage = next(st for st in plan_pipeline(s) if st.name == "products")
    assert stage.skip_reason is None
    assert stage.description == "LiDAR products (ground, dtm, dsm, ndsm, contours, hypsometry) ([products])"
    out = tmp_path / "out"
    rec = run_stages([stage], out, values={"survey": s})[0]
    assert rec.status == "ran", rec.reason
    folder = out / "products"
    res = rec.result
    # ground: classified copies, never the inputs; judged against the scene's own classes
    assert res["ground"]["tiles"] == ["ground/east.laz", "ground/west.laz"]
    for name, ref in truth.items():
        got = np.asarray(read_points(folder / "ground" / f"{name}.laz").attributes["classification"]) == 2
        assert got.shape == ref.shape
        assert np.mean(got != ref) < 0.01, name     # total error below 1 % (0.0 on this scene, 2026-11-24)
        assert np.all(np.asarray(read_points(root / "lidar" / f"{name}.laz")
                                 .attributes["classification"]) == 1)  # inputs untouched
    assert not list((folder / "ground").glob("*.json"))
    # DTM against the scene's terrain at the cell centres, DSM against its surface; CRS on each
    for what, tol in (("dtm", 0.06), ("dsm", 0.3)):          # DTM RMSE measured 0.035 m
        grid, t, epsg = _raster(folder / f"{what}.tif")
        assert epsg == 31982
        rows, cols = np.nonzero(np.isfinite(grid))
        e, n = t.xy(rows, cols)
        ref = scene.terrain(e, n) if what == "dtm" else scene.surface(e, n)[0]
        diff = grid[rows, cols] - ref
        inner = np.abs(diff) < 2.0        # building edges in the DSM: a 2 m cell straddles wall and ground
        assert inner.mean() > 0.95
        assert np.sqrt(np.mean(diff[inner] ** 2)) < tol, what
    dtm, dsm, nd = (_raster(folder / f"{w}.tif")[0] for w in ("dtm", "dsm", "ndsm"))
    np.testing.assert_allclose(nd, dsm - dtm, atol=1e-4)
    assert res["dtm"]["gap_cells"] == int(np.isnan(dtm).sum())
    # contours: levels on the interval, master every 5th, CRS; a vertex lies on the scene's terrain
    fc = json.loads((folder / "contours.geojson").read_text())
    assert fc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::31982"
    assert len(fc["features"]) == res["contours"]["lines"] > 0
    for f in fc["features"]:
        lv = f["properties"]["level_m"]
        assert lv == pytest.approx(round(lv), abs=1e-9)
        assert f["properties"]["type"] == ("master" if round(lv) % 5 == 0 else "intermediate")
    xy = np.vstack([np.asarray(f["geometry"]["coordinates"]) for f in fc["features"]])
    lv = np.concatenate([[f["properties"]["level_m"]] * len(f["geometry"]["coordinates"]) for f in fc["features"]])
    assert np.median(np.abs(scene.terrain(xy[:, 0], xy[:, 1]) - lv)) < 0.1
    assert json.loads((folder / "spot_heights.geojson").read_text())["features"]
    assert (folder / "hypsometry.png").stat().st_size > 0
    # sheets of 100 m: the index names each sheet with data; each holds the models cut to it
    idx = json.loads((folder / "sheets.geojson").read_text())
    names = [f["properties"]["name"] for f in idx["features"]]
    assert names == res["sheets"]["sheets"] and len(names) >= 6
    for nm in names:
        g, t, epsg = _raster(folder / "sheets" / nm / "dtm.tif")
        e0, n0 = (float(v) for v in nm[1:].split("_N"))     # sheet E<west>_N<south>, 100 m: the cut inside it
        assert epsg == 31982 and np.isfinite(g).any()
        assert e0 - 1e-6 <= t.x0 and t.x0 + g.shape[1] * t.cell_m <= e0 + 100 + 1e-6
        assert n0 + 100 + 1e-6 >= t.y0 and t.y0 - g.shape[0] * t.cell_m >= n0 - 1e-6
    # the same inputs and [products]: reused, not redone
    plan = plan_pipeline(Survey.load(work))
    again, report = run_stages([st for st in plan if st.name in ("products", "report")], out,
                               values={"survey": Survey.load(work), "plan": plan})
    assert again.status == "reused" and report.status == "ran", report.reason
    md = (out / "report" / "index.md").read_text()
    assert ("## LiDAR products\n\nIn ../products/ (CRS EPSG:31982): ground/east.laz, ground/west.laz, dtm.tif, "
            "dsm.tif, ndsm.tif, contours.geojson, spot_heights.geojson, hypsometry.png") in md


def test_settings_defaults_and_skip_without_tiles(survey, tmp_path):
    root, _, _ = survey
    work = _work(root, tmp_path, BASE.replace('lidar = ["lidar/*.laz"]\n', "") + "\n[products]\n")
    s = Survey.load(work)
    assert products.settings(s) == products.PRODUCTS_KEYS
    stage = next(st for st in plan_pipeline(s) if st.name == "products")
    assert stage.skip_reason == "the survey has no LiDAR tiles ([files] lidar)"


def test_ground_false_uses_the_tiles_classes(survey, tmp_path):
    """ground = false: no classification; a DTM then needs class 2 in the tiles (these have none)."""
    root, _, _ = survey
    work = _work(root, tmp_path, BASE + "\n[products]\nground = false\ncontours = false\ncell_m = 4.0\n")
    s = Survey.load(work)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], tmp_path / "out",
                     values={"survey": s})[0]
    assert rec.status == "failed"
    assert rec.reason == (f"{work / 'survey.toml'}: [products] dtm/contours need ground points (class 2) and "
                          "the tiles have none; set ground = true")
    assert not (tmp_path / "out" / "products").exists()                  # nothing half-written
    (work / "survey.toml").write_text(BASE + "\n[products]\nground = false\ndtm = false\ncontours = false\n"
                                             "cell_m = 4.0\n")
    s = Survey.load(work)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], tmp_path / "out",
                     values={"survey": s})[0]
    assert rec.status == "ran" and rec.result["files"] == ["dsm.tif"] and "ground" not in rec.result


def test_brazilian_sheets_and_geopackage_index(survey, tmp_path):
    """sheet_index = "brazil-2000", vector_format = "gpkg": the DSM cut along the Brazilian 1:2,000 sheets
    (named as the index names its cells' centres), the index layer a GeoPackage with the survey CRS."""
    gpd = pytest.importorskip("geopandas")
    from pyproj import Transformer

    from lidarcat.production.mapindex import sheet_names

    root, _, _ = survey
    work = _work(root, tmp_path, BASE + '\n[products]\nground = false\ndtm = false\ncontours = false\ncell_m = 4.0\n'
                                        'sheet_index = "brazil-2000"\nvector_format = "gpkg"\n')
    s = Survey.load(work)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], tmp_path / "out",
                     values={"survey": s})[0]
    assert rec.status == "ran", rec.reason
    folder = tmp_path / "out" / "products"
    assert rec.result["files"] == ["dsm.tif", "sheets.gpkg"] and rec.result["sheets"]["index"] == "brazil-2000"
    grid, t, _ = _raster(folder / "dsm.tif")
    rows, cols = np.nonzero(np.isfinite(grid))
    e, n = t.xy(rows, cols)
    lon, lat = Transformer.from_crs(CRS, "EPSG:4674", always_xy=True).transform(e, n)
    expected = sorted(set(sheet_names(lon, lat, 2000).tolist()))
    assert sorted(rec.result["sheets"]["sheets"]) == expected
    idx = gpd.read_file(folder / "sheets.gpkg", layer="sheets")
    assert idx.crs.to_epsg() == 31982 and sorted(idx["name"]) == expected
    cells = 0
    for nm in expected:
        g, _, epsg = _raster(folder / "sheets" / nm / "dsm.tif")
        assert epsg == 31982
        cells += int(np.isfinite(g).sum())
    assert cells == len(rows)                    # every DSM cell in exactly one sheet
