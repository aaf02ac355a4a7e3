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
