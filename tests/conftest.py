"""Shared paths (import them: ``from conftest import ROOT``). BLAS is pinned to one thread
before numpy loads."""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
DATA = TESTS / "data"
THESIS_TABLES = DATA / "thesis"
THESIS_SURVEY = ROOT / "data" / "thesis"
LIDAR_DATA = DATA / "lidar"


def _named_like_an_option(folder: Path) -> list[str]:
    """Files or folders in *folder* (not recursive) whose name starts with '-': a CLI that took an
    option for its output path (the tracked file '--help' of issue 16)."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("-"))


def pytest_sessionfinish(session, exitstatus):
    """After the suite: no file named like an option in the repository root, tests/ or docs/, or
    the working directory (the run fails otherwise; see tests/test_repo_files.py)."""
    stray = {str(d): _named_like_an_option(d) for d in {ROOT, TESTS, ROOT / "docs", Path.cwd()} if d.is_dir()}
    stray = {d: names for d, names in stray.items() if names}
    if stray:
        session.config.get_terminal_writer().line(f"files named like an option after the tests: {stray}", red=True)
        session.exitstatus = 1


def assert_one_line_error(result, *fragments: str) -> None:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("Error: "), result.output
    for f in fragments:
        assert f in lines[0], (f, lines[0])
