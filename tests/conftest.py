"""Shared fixtures and paths. BLAS is pinned to one thread before numpy loads."""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from pathlib import Path  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")

import pytest  # noqa: E402

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
DATA = TESTS / "data"
THESIS_TABLES = DATA / "thesis"
THESIS_SURVEY = ROOT / "data" / "thesis"
LIDAR_DATA = DATA / "lidar"


@pytest.fixture(scope="session")
def thesis_survey_dir() -> Path:
    """The embedded thesis survey folder (read-only: copy it before writing)."""
    return THESIS_SURVEY


@pytest.fixture(scope="session")
def thesis_tables() -> Path:
    """Folder of the published thesis tables the tests compare with."""
    return THESIS_TABLES
