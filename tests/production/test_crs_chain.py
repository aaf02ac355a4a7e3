"""Acceptance of issue 25: the production chain of docs/production.md, ``--crs`` given once, carries the CRS.

The commands are read from the first code block of docs/production.md and run
as written on AHN3 tile 2 (which carries no CRS), with the block's
``--crs EPSG:31983`` replaced by the tile's EPSG:7415 (RD New + NAP height, a
compound CRS) on the first command only and the hypsometry range set to the
tile's heights.  The Brazilian-index line needs a Brazilian CRS and is left
out.  Every output is opened by the library a user would open it with
(laspy, rasterio, geopandas) and must say EPSG:7415: the compound code kept.
"""

from __future__ import annotations

import glob
import re
import shlex
import shutil
import warnings
from pathlib import Path

import laspy
import pytest
from click.testing import CliRunner

from conftest import LIDAR_DATA
from lidarcat.cli.main import cli

ROOT = Path(__file__).resolve().parents[2]


def _doc_commands() -> list[list[str]]:
    text = (ROOT / "docs" / "production.md").read_text()
    block = re.search(r"```\n(lidarcat lidar ground.*?)```", text, re.S).group(1)
    out = []
    for line in block.splitlines():
        line = line.split("#")[0].strip()
        if not line or "brazil" in line:
            continue
        args = shlex.split(line)
        assert args[:2] == ["lidarcat", "lidar"], line
        out.append(args[2:])
    return out


def _expand(args: list[str], cwd: Path) -> list[str]:
    """The shell's globbing of the docs' ``dtm/*.tif`` (the quoted ``'tiles/*.laz'`` stays a pattern)."""
    out = []
    for a in args:
        if "*" in a and not a.startswith("tiles/"):
            out.extend(sorted(glob.glob(a, root_dir=cwd)))
        else:
            out.append(a)
    return out


def test_production_chain_of_the_docs_keeps_epsg_7415(tmp_path, monkeypatch):
    laspy_crs = laspy.read(str(LIDAR_DATA / "ahn3_cropped_2.laz")).header.parse_crs()
    assert laspy_crs is None                       # the tile carries no CRS: --crs is what gives it one
    (tmp_path / "tiles").mkdir()
    shutil.copy(LIDAR_DATA / "ahn3_cropped_2.laz", tmp_path / "tiles")
    monkeypatch.chdir(tmp_path)
    commands = _doc_commands()
    assert [c[0] for c in commands] == ["ground", "dtm", "dsm", "contours", "hypsometry", "sheets", "contours"]
    assert sum("--crs" in c for c in commands) == 1 and "--crs" in commands[0]
    for args in commands:
        args = ["EPSG:7415" if a == "EPSG:31983" else a for a in args]
        if args[0] == "hypsometry":   # the docs' range is the LACTEC block's; AHN3 Delft lies at -10..40 m
            args[args.index("--h-min-m") + 1], args[args.index("--h-max-m") + 1] = "-10", "40"
        result = CliRunner().invoke(cli, ["lidar", *_expand(args, tmp_path)], catch_exceptions=False)
        assert result.exit_code == 0, (args, result.output)

    import geopandas
    import rasterio

    found: dict[str, int | None] = {}
    for f in sorted(tmp_path.rglob("*")):
        rel = str(f.relative_to(tmp_path))
        if rel.startswith("tiles/") or not f.is_file():
            continue
        if f.suffix == ".laz":
            crs = laspy.read(str(f)).header.parse_crs()
            found[rel] = crs.to_epsg() if crs else None
        elif f.suffix == ".tif":
            with rasterio.open(f) as ds:
                found[rel] = ds.crs.to_epsg() if ds.crs else None
        elif f.suffix in (".geojson", ".gpkg"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                g = geopandas.read_file(f)
            found[rel] = g.crs.to_epsg() if g.crs is not None else None
    kinds = {Path(k).suffix for k in found}
    assert kinds == {".laz", ".tif", ".geojson", ".gpkg"}
    assert len([k for k in found if k.endswith(".tif")]) == 7      # dtm, hillshade, dsm, ndsm, hipso, 2 per sheet
    assert {k: v for k, v in found.items() if v != 7415} == {}
