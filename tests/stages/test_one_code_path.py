"""One code path per stage: the CLI command and the ``lidarcat run`` stage call the same action.

For ``adjust``, ``assess`` and ``lidar ground`` the command (through click's CliRunner) and the
stage's ``run`` (as the pipeline runner calls it, with a :class:`StageContext`) are run on the same
inputs and their output files compared byte for byte.  Left out of the byte comparison, and why:

* ``summary.json`` of an adjustment records the wall time (``elapsed_s``, ``elapsed_total_s``):
  compared as JSON without those two keys;
* ``report.html`` / ``report.md`` / ``report.json`` / ``report_figures/`` of an assessment carry a title that names the
  inputs as given (the CLI: the file names; the stage: the survey and control set), and its
  ``assessment.json`` records where the reference came from (``settings.reference_source``: the
  CLI's file path, the stage's survey columns): compared as JSON without that key;
* the ``<tile>.done.json`` resume markers of the tile engine record the output path (the stage
  deletes them: they are no products).

A second test replaces each action by a recording wrapper and shows that both paths call it.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli
from lidarcat.lidar import PointCloud, resolve_crs, write_points
from lidarcat.stages import adjust as adjust_stage
from lidarcat.stages import assess as assess_stage
from lidarcat.stages import lidar as lidar_actions
from lidarcat.stages import products as products_stage
from lidarcat.survey.folder import Survey, thesis_survey_path
from stage_harness import StageStub as _Stage, folder_files, stage_context as _ctx  # noqa: I001

TIMING = ("elapsed_s", "elapsed_total_s")


def _files(folder: Path, skip: tuple[str, ...] = ()) -> dict[str, bytes]:
    return folder_files(folder, skip, skip_suffix=(".done.json",))


def _invoke(*args: Any) -> Any:
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert r.exception is None or isinstance(r.exception, SystemExit), r.output
    assert r.exit_code in (0, 3), r.output
    return r


@pytest.fixture(scope="module")
def thesis_runs(tmp_path_factory):
    """The thesis block adjusted with control set gps by ``lidarcat adjust`` and by the stage."""
    root = tmp_path_factory.mktemp("one_path")
    _invoke("adjust", thesis_survey_path(), "--control", "gps", "-o", root / "cli")
    survey = Survey.load(thesis_survey_path())
    (root / "run" / "adjust-gps").mkdir(parents=True)
    adjust_stage.run(_ctx(root / "run", _Stage("adjust-gps", "adjust-gps", {"control": "gps"}), survey),
                     root / "run" / "adjust-gps")
    return root, survey


def test_adjust_cli_and_stage_write_the_same_files(thesis_runs):
    root, _ = thesis_runs
    cli_files = _files(root / "cli", skip=("summary.json",))
    stage_files = _files(root / "run" / "adjust-gps", skip=("summary.json",))
    assert sorted(cli_files) == sorted(stage_files)
    assert {"eop.csv", "points.csv", "residuals.csv", "blunders.csv", "reliability.csv"} <= set(cli_files)
    for name in cli_files:
        assert cli_files[name] == stage_files[name], name
    a, b = (json.loads((f / "summary.json").read_text()) for f in (root / "cli", root / "run" / "adjust-gps"))
    for k in TIMING:
        assert a.pop(k) >= 0 and b.pop(k) >= 0
    assert a == b


def test_assess_cli_and_stage_write_the_same_files(thesis_runs, tmp_path):
    root, survey = thesis_runs
    cset = survey.control_set("gps")
    checks = [str(c) for c in cset.check]
    out = tmp_path / "assess-gps"
    out.mkdir()
    assess_stage.run(_ctx(root / "run", _Stage("assess-gps", "assess-gps", {
        "control": "gps", "scale": 2000.0, "contour_interval_m": 2.0, "alpha": 0.10, "pec_class": "A",
        "plotting_position": "filliben"}), survey, {"adjust-gps": "adjust-gps"}), out)
    _invoke("assess", root / "run" / "adjust-gps" / "points.csv", thesis_survey_path(), "--points", ",".join(checks),
            "--scale", 2000, "--contour-interval", 2, "-o", tmp_path / "cli")
    report = ("report.html", "report.md", "report.json", "assessment.json")
    a, b = _files(tmp_path / "cli", skip=report), _files(out, skip=report)
    a, b = ({k: v for k, v in d.items() if not k.startswith("report_figures")} for d in (a, b))
    assert sorted(a) == sorted(b)
    assert "discrepancies.csv" in a
    for name in a:
        assert a[name] == b[name], name
    x, y = (json.loads((f / "assessment.json").read_text()) for f in (tmp_path / "cli", out))
    assert x["settings"].pop("reference_source") == str(thesis_survey_path() / "ground_points.csv")
    assert y["settings"].pop("reference_source") == "reference"
    assert x == y and x["control_set"] == "gps"


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    """Two small unclassified tiles of a slope with a block building (EPSG:31982)."""
    root = tmp_path_factory.mktemp("tiles")
    rng = np.random.default_rng(5)
    n = 6000
    xy = rng.uniform(0, 120, size=(n, 2)) + [500000.0, 7000000.0]
    z = 100 + 0.05 * (xy[:, 0] - 500000) + rng.normal(0, 0.03, n)
    inside = (np.abs(xy[:, 0] - 500060) < 12) & (np.abs(xy[:, 1] - 7000060) < 12)
    z[inside] += 8.0
    ones = np.ones(n, np.uint8)
    for name, sel in (("west", xy[:, 0] < 500060), ("east", xy[:, 0] >= 500060)):
        attrs = {"classification": ones[sel], "return_number": ones[sel], "number_of_returns": ones[sel],
                 "intensity": np.full(int(sel.sum()), 100, np.uint16)}
        write_points(root / f"{name}.laz", PointCloud(np.column_stack([xy, z])[sel], attrs,
                                                     crs=resolve_crs("EPSG:31982")))
    return sorted(root.glob("*.laz"))


def test_lidar_ground_cli_and_products_stage_write_the_same_tiles(tiles, tmp_path):
    _invoke("lidar", "ground", *tiles, "-o", tmp_path / "cli")
    # the products stage's ground step, as the stage calls it
    lidar_actions.ground(tiles, tmp_path / "stage", crs="EPSG:31982", method="smrf",
                         params=lidar_actions.ground_parameters("smrf"), resume=False)
    a, b = _files(tmp_path / "cli"), _files(tmp_path / "stage")
    assert sorted(a) == ["east.laz", "west.laz"] == sorted(b)
    for name in a:
        assert a[name] == b[name], name


def test_lidar_dtm_dsm_go_through_the_action(tiles, tmp_path, monkeypatch):
    calls = []
    real = lidar_actions.terrain_model

    def spy(kind, *a, **kw):
        calls.append(kind)
        return real(kind, *a, **kw)

    monkeypatch.setattr(lidar_actions, "terrain_model", spy)
    _invoke("lidar", "ground", tiles[0], "-o", tmp_path / "g.laz")
    for kind in ("dtm", "dsm"):
        _invoke("lidar", kind, tmp_path / "g.laz", "-o", tmp_path / f"{kind}.tif")
        assert (tmp_path / f"{kind}.tif").is_file()
    assert calls == ["dtm", "dsm"]


def test_one_function_is_what_both_paths_call(thesis_runs, tiles, tmp_path, monkeypatch):
    """Each action replaced by a recording wrapper: the command and the stage both go through it."""
    root, survey = thesis_runs
    seen: list[str] = []

    def recording(module: Any, name: str) -> None:
        real = getattr(module, name)

        def wrapper(*a: Any, **kw: Any) -> Any:
            seen.append(f"{module.__name__}.{name}")
            return real(*a, **kw)

        monkeypatch.setattr(module, name, wrapper)

    recording(adjust_stage, "adjust")
    recording(assess_stage, "assess")
    recording(lidar_actions, "ground")
    _invoke("adjust", thesis_survey_path(), "--control", "gps", "-o", tmp_path / "a")
    (tmp_path / "run" / "adjust-gps").mkdir(parents=True)
    adjust_stage.run(_ctx(tmp_path / "run", _Stage("adjust-gps", "adjust-gps", {"control": "gps"}), survey),
                     tmp_path / "run" / "adjust-gps")
    assert seen == ["lidarcat.stages.adjust.adjust"] * 2
    seen.clear()
    _invoke("assess", tmp_path / "a" / "points.csv", thesis_survey_path())
    (tmp_path / "s").mkdir()
    assess_stage.run(_ctx(tmp_path / "run", _Stage("assess-gps", "assess-gps", {"control": "gps"}), survey,
                          {"adjust-gps": "adjust-gps"}), tmp_path / "s")
    assert seen == ["lidarcat.stages.assess.assess"] * 2
    seen.clear()
    _invoke("lidar", "ground", tiles[0], "-o", tmp_path / "g.laz")
    work = tmp_path / "survey"
    work.mkdir()
    (work / "lidar").mkdir()
    (work / "lidar" / tiles[0].name).symlink_to(tiles[0])
    for f in ("camera.toml", "photos.csv", "image_points.csv"):
        (work / f).write_text((Path(thesis_survey_path()) / f).read_text())
    (work / "survey.toml").write_text('[survey]\nname = "t"\ncrs = "EPSG:31982"\n\n[files]\ncamera = "camera.toml"\n'
                                      'photos = "photos.csv"\nimage_points = "image_points.csv"\n'
                                      'lidar = ["lidar/*.laz"]\n\n[products]\ndtm = false\ndsm = false\n'
                                      'contours = false\n')
    s = Survey.load(work)
    cfg = products_stage.settings(s)
    (tmp_path / "p").mkdir()
    products_stage.run(_ctx(tmp_path / "run", _Stage("products", "products", cfg), s), tmp_path / "p")
    assert seen == ["lidarcat.stages.lidar.ground"] * 2
