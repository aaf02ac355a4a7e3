"""``[products] workers`` / ``scheduler``: where the products stage runs its tile work.

What the stage hands to the tile runner is checked (not timing): ``lidar.jobs.run_jobs`` (the stats
tiles here) and ``lidar.jobs.run_tasks`` (one chart per sheet) are wrapped to record their
``workers`` / ``scheduler`` and then run serially; ``lidar.jobs.dask_client`` is replaced by a
stand-in with an address, so no cluster starts.
"""

from __future__ import annotations

import contextlib
from types import SimpleNamespace

import pytest

from lidarcat.errors import SurveyError
from lidarcat.lidar import jobs
from lidarcat.pipeline.plan import plan_pipeline
from lidarcat.pipeline.runner import run_stages
from lidarcat.stages import products

from test_products_charts import BASE, CHARTS, _load, survey  # noqa: F401,I001  (the module's fixture)

TOML = BASE + CHARTS + 'chart_mosaic = "mosaic.tif"\nstats = true\ncell_m = 4.0\n'
FAKE = "tcp://127.0.0.1:1"   # the stand-in cluster's address


@pytest.fixture()
def handed(monkeypatch):
    """The runner keywords every run_jobs / run_tasks call got, and the clusters started."""
    calls: dict[str, list] = {"run_jobs": [], "run_tasks": [], "clusters": []}
    real_jobs, real_tasks = jobs.run_jobs, jobs.run_tasks

    def run_jobs(js, *, workers=None, scheduler=None, **kw):
        calls["run_jobs"].append((workers, scheduler))
        return real_jobs(js, **kw)

    def run_tasks(func, tasks, *, workers=None, scheduler=None, **kw):
        calls["run_tasks"].append((workers, scheduler))
        return real_tasks(func, tasks, **kw)

    @contextlib.contextmanager
    def dask_client(workers=1, scheduler="threads"):
        calls["clusters"].append((workers, scheduler))
        yield SimpleNamespace(scheduler=SimpleNamespace(address=FAKE))

    monkeypatch.setattr(jobs, "run_jobs", run_jobs)
    monkeypatch.setattr(jobs, "run_tasks", run_tasks)
    monkeypatch.setattr(jobs, "dask_client", dask_client)
    return calls


def _run(root, tmp_path, toml, out):
    s = _load(root, tmp_path, toml)
    rec = run_stages([st for st in plan_pipeline(s) if st.name == "products"], out, values={"survey": s})[0]
    assert rec.status in ("ran", "reused"), rec.reason
    return s, rec


def test_default_runs_the_tiles_and_charts_in_the_process(survey, tmp_path, handed):
    s, rec = _run(survey, tmp_path, TOML, tmp_path / "out")
    assert products.runner(products.settings(s)) == {"workers": None, "scheduler": None}
    assert handed["clusters"] == []
    assert handed["run_jobs"] == [(None, None)]            # stats.tif
    assert handed["run_tasks"] == [(None, None)]           # the 4 charts
    assert len(rec.result["charts"]["sheets"]) == 4


def test_workers_start_one_cluster_for_every_action(survey, tmp_path, handed):
    out = tmp_path / "out"
    s, rec = _run(survey, tmp_path, TOML + "workers = 2\n", out)
    assert rec.status == "ran"
    assert s.config.products.workers == 2
    assert products.runner(products.settings(s)) == {"workers": 2, "scheduler": None}
    assert handed["clusters"] == [(2, "processes")]        # one local cluster of 2 processes
    assert handed["run_jobs"] == [(None, FAKE)]            # handed on by its address
    assert handed["run_tasks"] == [(None, FAKE)]
    assert len(rec.result["charts"]["sheets"]) == 4


def test_a_scheduler_address_goes_straight_to_the_runner(survey, tmp_path, handed):
    _run(survey, tmp_path, TOML + 'workers = 3\nscheduler = "tcp://10.0.0.5:8786"\n', tmp_path / "out")
    assert handed["clusters"] == []                        # wins over workers: no local cluster
    assert handed["run_jobs"] == [(None, "tcp://10.0.0.5:8786")]
    assert handed["run_tasks"] == [(None, "tcp://10.0.0.5:8786")]


@pytest.mark.parametrize("extra, message", [
    ("workers = 0\n", r"field 'workers': must be 1 \(in the run's process\) or more \(Dask worker processes\), "
                      r"got 0"),
    ("workers = 2.5\n", r"field 'workers': in \[products\], expected int, got 2\.5"),
    ("workers = true\n", r"field 'workers': in \[products\], expected int, got True"),
    ('scheduler = "10.0.0.5:8786"\n', r"field 'scheduler': expected the address of a Dask scheduler such as "
                                      r"'tcp://10\.0\.0\.5:8786', got '10\.0\.0\.5:8786'"),
    ('scheduler = ""\n', r"field 'scheduler': must not be empty"),
])
def test_bad_runner_keys_are_located_errors(survey, tmp_path, extra, message):
    with pytest.raises(SurveyError, match=r"survey\.toml:(\d+): " + message) as ei:
        _load(survey, tmp_path, TOML + extra)
    line = int(ei.value.args[0].split("survey.toml:")[1].split(":")[0])
    assert line == len((TOML + extra).splitlines())        # the key's own line


@pytest.mark.slow
def test_a_real_cluster_of_two_draws_the_same_charts_and_stats(survey, tmp_path):
    """workers = 2 for real: a LocalCluster of 2 processes, its address handed on; the same bytes."""
    outs = {}
    for w in (1, 2):
        (tmp_path / f"w{w}").mkdir()
        _, rec = _run(survey, tmp_path / f"w{w}", TOML + f"workers = {w}\n", tmp_path / f"out{w}")
        assert rec.status == "ran"
        outs[w] = tmp_path / f"out{w}" / "products"
    names = sorted(str(p.relative_to(outs[1])) for p in outs[1].rglob("*") if p.is_file())
    assert names == sorted(str(p.relative_to(outs[2])) for p in outs[2].rglob("*") if p.is_file())
    assert len([n for n in names if n.startswith("charts/")]) == 8 and "stats.tif" in names
    for n in names:
        assert (outs[1] / n).read_bytes() == (outs[2] / n).read_bytes(), n
