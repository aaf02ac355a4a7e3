"""One code path for ``extract``, ``ortho`` and ``lidar dtm|dsm``: the command and the ``lidarcat run`` stage
write the same bytes.

On the synthetic demo survey (:func:`lidarcat.synthetic.survey.write_synthetic_survey`: two photos with
images, four LiDAR tiles, one extraction job per building):

* ``lidarcat extract jobs.csv --lidar TILES`` and the stage ``extract``: ``control.csv``, ``planes.csv``;
* ``lidarcat ortho --all --dsm dsm.tif --mosaic`` and the ``mapping`` stage's orthophotos, the command given
  the stage's own surface model ``dsm.tif`` and orientations: every orthophoto, preview, the mosaic and its
  seamlines;
* ``lidarcat lidar dtm|dsm GROUND_TILES -o X.tif`` and the ``products`` stage: the DTM, DSM, nDSM,
  hillshades and text grids, all mosaicked from the four tiles.

Nothing is left out of these comparisons.  A further test shows that the one-file model of one tile is,
byte for byte, the tile engine's own output for that tile, and that the mosaic of four tiles takes every
cell of each tile's own area from that tile.
"""

from __future__ import annotations

import json
import shutil
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.stages import extract as extract_stage
from lidarcat.stages import lidar as lidar_actions
from lidarcat.stages import mapping as mapping_stage
from lidarcat.stages import products as products_stage
from lidarcat.survey.folder import Survey
from lidarcat.synthetic.survey import write_synthetic_survey
from stage_harness import StageStub as _Stage, folder_files as _files, stage_context as _ctx  # noqa: I001

CRS = "EPSG:31982"


def _spy(monkeypatch: Any, module: Any, name: str) -> list[str]:
    """Replace ``module.name`` by a wrapper recording each call; the list of calls."""
    calls: list[str] = []
    real = getattr(module, name)

    def wrapper(*a: Any, **kw: Any) -> Any:
        calls.append(name)
        return real(*a, **kw)

    monkeypatch.setattr(module, name, wrapper)
    return calls


def _invoke(*args: Any) -> Any:
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exit_code == 0, r.output
    return r


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    root = tmp_path_factory.mktemp("one_path_demo") / "survey"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=1.0, images=True, image_downsample=4)
    return root


def test_extract_cli_and_stage_write_the_same_files(demo, tmp_path, monkeypatch):
    calls = _spy(monkeypatch, extract_stage, "extract")
    survey = Survey.load(demo)
    out = tmp_path / "run" / "extract"
    out.mkdir(parents=True)
    res = extract_stage.run(_ctx(tmp_path / "run", _Stage("extract", "extract", {"set": "lidar"}), survey), out)
    assert res["n_ok"] > 0
    tiles = sorted((demo / "lidar").glob("*.laz"))
    _invoke("extract", demo / "jobs.csv", *tiles, "--crs", CRS, "-o", tmp_path / "cli" / "control.csv",
            "--planes", tmp_path / "cli" / "planes.csv")
    cli_files = _files(tmp_path / "cli")
    assert sorted(cli_files) == ["control.csv", "control.csv.json", "planes.csv", "planes.csv.json"]  # + sidecars
    for name, data in cli_files.items():
        assert data == (out / name).read_bytes(), name
    assert calls == ["extract", "extract"]                    # the stage, then the command
    assert json.loads(cli_files["control.csv.json"])["notes"] == [
        "Roof vertices extracted by lidarcat (preset default) at the jobs of jobs.csv; metres, sds propagated "
        "from the planes."]


def test_ortho_cli_and_mapping_stage_write_the_same_files(demo, tmp_path, monkeypatch):
    calls = _spy(monkeypatch, mapping_stage, "orthophotos")
    work = tmp_path / "s"
    shutil.copytree(demo, work, ignore=shutil.ignore_patterns("lidar"))
    (work / "lidar").symlink_to(demo / "lidar")
    with open(work / "survey.toml", "a", encoding="utf-8") as f:
        f.write("\n[mapping]\northophotos = true\ngsd_m = 2.0\ncell_m = 2.0\n")
    survey = Survey.load(work)
    adj = tmp_path / "run" / "adjust-gps"
    adj.mkdir(parents=True)
    shutil.copyfile(demo / "truth" / "eop.csv", adj / "eop.csv")   # the true orientations stand for an adjustment
    out = tmp_path / "run" / "mapping"
    out.mkdir()
    res = mapping_stage.run(_ctx(tmp_path / "run", _Stage("mapping", "mapping", {"adjust": "adjust-gps"}), survey,
                                 {"adjust-gps": "adjust-gps"}), out)
    assert [o["photo"] for o in res["orthophotos"]] == ["1", "2"] and res["surface"] == "dsm.tif"
    _invoke("ortho", work, "--all", "--dsm", out / "dsm.tif", "--gsd", 2, "--eop", adj / "eop.csv",
            "--images", work / "images", "--mosaic", "-o", tmp_path / "cli")
    cli_files, stage_files = _files(tmp_path / "cli"), _files(out)
    assert sorted(cli_files) == ["mosaic.png", "mosaic.tif", "ortho_1.png", "ortho_1.tif", "ortho_2.png",
                                 "ortho_2.tif", "seamlines.geojson"]
    assert sorted(stage_files) == sorted([*cli_files, "dsm.png", "dsm.tif"])
    for name, data in cli_files.items():
        assert data == stage_files[name], name
    assert calls == ["orthophotos", "orthophotos"]


@pytest.fixture(scope="module")
def ground_tiles(demo):
    """The demo tiles: classified (ground class 2, roofs class 6) by the synthetic scene."""
    return sorted((demo / "lidar").glob("*.laz"))


def test_lidar_dtm_dsm_cli_and_products_stage_write_the_same_files(demo, ground_tiles, tmp_path, monkeypatch):
    calls = _spy(monkeypatch, lidar_actions, "terrain_model")
    work = tmp_path / "s"
    work.mkdir()
    for name in ("camera.toml", "photos.csv", "image_points.csv"):
        shutil.copyfile(demo / name, work / name)
    if (demo / "images").is_dir():   # photos.csv names its image files (the demo's image column)
        (work / "images").symlink_to(demo / "images")
    (work / "ground").symlink_to(ground_tiles[0].parent)
    (work / "survey.toml").write_text(
        f'[survey]\nname = "t"\ncrs = "{CRS}"\n\n[files]\ncamera = "camera.toml"\nphotos = "photos.csv"\n'
        f'image_points = "image_points.csv"\nlidar = ["ground/*.laz"]\n\n[products]\nground = false\n'
        f'cell_m = 4.0\nndsm = true\nhillshade = true\ntext_grid = true\ncontours = false\n')
    survey = Survey.load(work)
    out = tmp_path / "run" / "products"
    out.mkdir(parents=True)
    res = products_stage.run(_ctx(tmp_path / "run", _Stage("products", "products", products_stage.settings(survey)),
                                  survey), out)
    assert res["files"] == ["dtm.tif", "dtm_hillshade.tif", "dtm.txt", "dtm.prj", "dsm.tif", "dsm_hillshade.tif",
                            "dsm.txt", "dsm.prj", "ndsm.tif", "ndsm.txt", "ndsm.prj"]
    cli = tmp_path / "cli"
    _invoke("lidar", "dtm", *ground_tiles, "-o", cli / "dtm.tif", "--cell-m", 4, "--text", "--hillshade")
    _invoke("lidar", "dsm", *ground_tiles, "-o", cli / "dsm.tif", "--cell-m", 4, "--text", "--hillshade", "--ndsm")
    assert sorted(_files(cli)) == ["dsm.prj", "dsm.tif", "dsm.txt", "dsm_hillshade.tif", "dsm_ndsm.tif", "dtm.prj",
                                   "dtm.tif", "dtm.txt", "dtm_hillshade.tif"]   # the tile grids are gone
    assert calls == ["terrain_model"] * 4                     # dtm, dsm by the stage, then by the commands
    stage_files = _files(out)
    for name, data in _files(cli).items():
        assert data == stage_files[name.replace("dsm_ndsm", "ndsm")], name
    # over the four tiles: 1008 x 480 m in 4 m cells
    dtm, t = lidar_actions.read_grid(out / "dtm.tif")
    assert dtm.shape == (res["dtm"]["rows"], res["dtm"]["cols"]) == (120, 252)
    assert np.isfinite(dtm).mean() > 0.99


def test_one_tile_model_is_the_tile_engines_output(ground_tiles, tmp_path):
    from lidarcat.lidar.jobs import run_jobs
    from lidarcat.production.tiles import product_jobs as tile_jobs

    params = {"cell_m": 4.0, "max_edge_m": 50.0, "text": True, "hillshade": True, "ndsm": True}
    jobs = tile_jobs("dsm", ground_tiles, tmp_path / "engine", crs=CRS, params=params, overlap_m=50.0,
                     suffix=".tif")
    run_jobs(jobs)
    own = ground_tiles[0]
    lidar_actions.terrain_model("dsm", [own], tmp_path / "one" / "dsm.tif", crs=CRS, cell_m=4.0, text=True,
                                hillshade=True, ndsm=True)
    engine_one = tile_jobs("dsm", [own], tmp_path / "single" / "dsm.tif", crs=CRS, params=params, overlap_m=50.0,
                           suffix=".tif")
    run_jobs(engine_one)
    for name in ("dsm.tif", "dsm_hillshade.tif", "dsm_ndsm.tif", "dsm.txt"):
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "single" / name).read_bytes(), name
    # the four-tile model: every cell whose centre is in a tile's own area is that tile's cell
    lidar_actions.terrain_model("dsm", ground_tiles, tmp_path / "all.tif", crs=CRS, cell_m=4.0)
    whole, t = lidar_actions.read_grid(tmp_path / "all.tif")
    for j in jobs:
        g, tt = lidar_actions.read_grid(j.output)
        r0, c0 = round((t.y0 - tt.y0) / 4.0), round((tt.x0 - t.x0) / 4.0)
        e = tt.x0 + (np.arange(g.shape[1]) + 0.5) * 4.0
        n = tt.y0 - (np.arange(g.shape[0]) + 0.5) * 4.0
        xmin, ymin, xmax, ymax = j.bounds
        rows, cols = np.flatnonzero((n >= ymin) & (n <= ymax)), np.flatnonzero((e >= xmin) & (e <= xmax))
        np.testing.assert_array_equal(whole[r0 + rows[:, None], c0 + cols[None, :]], g[rows[:, None], cols[None, :]])
    assert not list(tmp_path.glob(".*.tiles"))
