"""``[products] charts``: one orthophoto chart (PDF + PNG) per sheet holding data, from ``lidarcat run``."""

from __future__ import annotations

import numpy as np
import pytest

from lidarcat.errors import SurveyError
from lidarcat.lidar import PointCloud, resolve_crs, write_points
from lidarcat.lidar.geotiff import GeoTransform, write_geotiff
from lidarcat.pipeline.plan import plan_pipeline
from lidarcat.pipeline.runner import run_stages
from lidarcat.synthetic.scene import demo_scene
from lidarcat.survey.folder import Survey

from ortho_scene import CAM, MODEL_BOUNDS  # noqa: I001
from pdf_text import pdf_text

CRS = "EPSG:31982"
BASE = (f'[survey]\nname = "charts"\ncrs = "{CRS}"\n\n[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\n'
        f'image_points = "image_points.csv"\nlidar = ["lidar/*.laz"]\n\n[lidar]\ncrs = "{CRS}"\n')
CHARTS = ('\n[products]\nground = false\ndtm = false\ndsm = false\ncontour_interval_m = 1.0\nsheet_size_m = 200\n'
          'charts = true\nchart_scale = 2000\nchart_dpi = 20\nchart_date = "2026-11-28"\n'
          'chart_declination_deg = -22.5\nchart_declination_date = "2026-01-01"\n')


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    """One LiDAR tile of the synthetic scene with its true classes, and an RGB mosaic over it."""
    root = tmp_path_factory.mktemp("charts_survey")
    scene = demo_scene()
    (root / "camera.toml").write_text(CAM.to_toml())
    (root / "photos.csv").write_text("photo,camera\nA,small\nB,small\n")
    (root / "image_points.csv").write_text("photo,point,col_px,row_px\nA,T1,600,400\nB,T1,610,390\n")
    pts = scene.lidar_points(MODEL_BOUNDS, 0.5, noise_m=0.05, seed=3)
    (root / "lidar").mkdir()
    write_points(root / "lidar" / "tile.laz", PointCloud(pts["xyz"], {"classification": pts["classification"]},
                                                         crs=resolve_crs(CRS)))
    rows, cols = 90, 130   # 2 m cells over the 260 x 180 m model area
    img = np.zeros((rows, cols, 3), np.uint8)
    img[..., 0] = np.linspace(30, 220, cols).astype(np.uint8)[None, :]
    img[..., 1] = 120
    img[..., 2] = np.linspace(220, 30, rows).astype(np.uint8)[:, None]
    write_geotiff(root / "mosaic.tif", img, GeoTransform(MODEL_BOUNDS[0], MODEL_BOUNDS[3], 2.0), CRS)
    return root


def _load(root, tmp_path, toml):
    work = tmp_path / "s"
    work.mkdir()
    for p in root.iterdir():
        (work / p.name).symlink_to(p)
    (work / "survey.toml").write_text(toml)
    return Survey.load(work)


def test_run_writes_one_chart_per_sheet_with_title_block_and_grid(survey, tmp_path):
    s = _load(survey, tmp_path, BASE + CHARTS + 'chart_mosaic = "mosaic.tif"\n')
    stage = next(st for st in plan_pipeline(s) if st.name == "products")
    assert stage.description == "LiDAR products (contours, charts) ([products])"
    rec = run_stages([stage], tmp_path / "out", values={"survey": s})[0]
    assert rec.status == "ran", rec.reason
    res = rec.result["charts"]
    # the 260 x 180 m area (E 680270..680530, N 7184110..7184290) meets 2 x 2 sheets of 200 m
    names = [f"E{e}_N{n}" for n in (7184200, 7184000) for e in (680200, 680400)]
    assert res["sheets"] == names and res["scale"] == 2000
    folder = tmp_path / "out" / "products"
    assert sorted(p.name for p in (folder / "charts").iterdir()) == sorted(
        f"{n}.{x}" for n in names for x in ("pdf", "png"))
    text = pdf_text(folder / "charts" / "E680400_N7184200.pdf")
    for line in ("ORTHOPHOTO CHART (ortofotocarta)", "charts", "Sheet: E680400_N7184200", "Scale 1:2,000",
                 "Datum and projection: EPSG:31982 (SIRGAS 2000 / UTM zone 22S)",
                 "Magnetic declination: 22°30' W (2026-01-01)", "Date: 2026-11-28"):
        assert line in text, line
    for label in ("680450", "680500", "680550", "7184250", "7184300", "7184350"):
        assert text.count(label) == 2, label     # 50 m grid on a 200 m sheet, labelled on both sides
    assert set(names) <= set(text)               # the index map names every sheet of the block


def test_charts_without_a_mosaic_fail_with_the_reason(survey, tmp_path):
    s = _load(survey, tmp_path, BASE + CHARTS)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], tmp_path / "out",
                     values={"survey": s})[0]
    assert rec.status == "failed"
    assert rec.reason.endswith("[products] charts need the orthomosaic: the mapping stage's mosaic.tif "
                               "([mapping] orthophotos = true, mosaic = true) or chart_mosaic = FILE.tif")
    assert not (tmp_path / "out" / "products").exists()


@pytest.mark.parametrize("extra, message", [
    ("contours = false\n", r"field 'charts': an orthophoto chart shows the contours: needs contours = true"),
    ("sheet_size_m = 0\n", r"field 'charts': one chart per sheet: give the sheet index"),
    ("chart_scale = 0\n", r"field 'chart_scale': must be a positive scale denominator, got 0"),
    ("chart_declination_deg = 200\n", r"field 'chart_declination_deg': must be -180 to 180 degrees"),
])
def test_bad_chart_keys_are_located_errors(survey, tmp_path, extra, message):
    key = extra.split(" = ")[0]
    lines = [ln for ln in CHARTS.splitlines(keepends=True) if not ln.startswith(key + " = ")]
    toml = BASE + "".join(lines) + extra
    with pytest.raises(SurveyError, match=r"survey\.toml:\d+: " + message):
        _load(survey, tmp_path, toml)


@pytest.mark.slow
def test_lidarcat_run_on_the_synthetic_demo_charts_every_sheet(tmp_path):
    """The demo with photos: mapping makes the mosaic, products the contours and one chart per sheet."""
    from click.testing import CliRunner

    from lidarcat.cli.main import cli
    from lidarcat.synthetic.survey import write_synthetic_survey

    root = tmp_path / "demo"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=1.0, images=True, image_downsample=4)
    with open(root / "survey.toml", "a") as fh:
        fh.write('\n[mapping]\northophotos = true\ngsd_m = 1.0\ncell_m = 1.0\n\n[products]\ndsm = false\n'
                 'sheet_size_m = 500\ncharts = true\nchart_dpi = 30\nchart_date = "2026-11-28"\n')
    r = CliRunner().invoke(cli, ["run", str(root), "-o", str(tmp_path / "out")])
    assert "products           ran" in r.output, r.output
    import json

    res = json.loads((tmp_path / "out" / ".stages" / "products.json").read_text())["result"]["charts"]
    assert res["mosaic"].endswith("mapping/mosaic.tif") and len(res["sheets"]) >= 1
    for name in res["sheets"]:
        text = pdf_text(tmp_path / "out" / "products" / "charts" / f"{name}.pdf")
        assert f"Sheet: {name}" in text and "Scale 1:5,000" in text and "Magnetic declination: not given" in text
        assert (tmp_path / "out" / "products" / "charts" / f"{name}.png").stat().st_size > 0


def test_delivery_formats_of_the_run(survey, tmp_path):
    ezdxf = pytest.importorskip("ezdxf")
    toml = BASE + ('\n[products]\nground = false\ndtm = true\ndsm = false\ncell_m = 2.0\nsheet_size_m = 200\n'
                   'delivery = ["tfw", "shp", "dxf"]\n')
    s = _load(survey, tmp_path, toml)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], tmp_path / "out",
                     values={"survey": s})[0]
    assert rec.status == "ran", rec.reason
    folder = tmp_path / "out" / "products"
    files = rec.result["delivery"]["files"]
    tifs = sorted(str(p.relative_to(folder)) for p in folder.rglob("*.tif"))
    assert len(tifs) == 5       # dtm.tif and its cut for each of the 2 x 2 sheets
    assert sorted(f for f in files if f.endswith(".tfw")) == sorted(t[:-4] + ".tfw" for t in tifs)
    assert {"shp/contours.shp", "shp/spot_heights.shp", "shp/sheets.shp", "contours.dxf"} <= set(files)
    assert all((folder / f).is_file() for f in files) and set(files) <= set(rec.result["files"])
    doc = ezdxf.readfile(folder / "contours.dxf")
    assert len(doc.modelspace().query('LWPOLYLINE[layer=="Prancha"]')) == 4
    (tmp_path / "b").mkdir()
    with pytest.raises(SurveyError, match=r"field 'delivery': 'dwg': use tfw, shp, dxf"):
        _load(survey, tmp_path / "b", BASE + '\n[products]\ndelivery = ["dwg"]\n')
