"""Fuzz every command that reads user files (issue 24): seeded, reproducible, one subprocess a case.

The corpus is the commands' real inputs -- the thesis block (``thesis_survey_path()``), its
adjustment and an OPK/GNSS/geo.txt export of it, the interop files of ``tests/data/interop``
(COLMAP, OpenSfM, Metashape, Borea, ODM), the LiDAR files of ``tests/data/lidar``, the synthetic
demo survey (photos rendered, LiDAR tiles) and the products made from it (DTM, DSM, contours).
Each case copies the inputs of one command into a fresh folder, mutates ONE of its files and runs
the command in a subprocess with a time limit.  Mutations by kind of file:

- CSV / text: a cell replaced by a nasty value (NaN, inf, 1e308, -1e10, a 400-digit number,
  Arabic-Indic digits, a decimal comma, quotes, separators, a path, random text), two cells
  swapped, a column deleted, a line deleted or duplicated;
- TOML: a value replaced (nasty number, a string for a number and back), a key deleted,
  deep nesting (``x = [[[[...]]]]``, 100,000 levels);
- JSON: a node replaced (wrong type, NaN/Infinity, 1e308, None), a key deleted, deep nesting;
- XML: an attribute value replaced, an element deleted, an entity bomb (billion laughs),
  deep nesting;
- every file: byte flips (biased to the first 400 bytes), truncation, random bytes.

Outcomes: ``exit-0``; ``clean`` (exit 1, 2 or 3 and no traceback); ``traceback`` (a
"Traceback" in the output, or any other exit status -- 70 is the CLI's internal error);
``hang`` (still running at ``--timeout``).  An exit 0 is also checked where that is cheap:
an ``import`` must write a survey that ``Survey.load`` accepts; a raster, image or layer
must stay under 100 MB (``wrong`` when the check fails).  Every failing case (traceback,
hang, wrong) is written to ``--failures`` as a folder with the mutated inputs and a
``repro.sh`` line.  The subprocess runs under ``ulimit -v`` (``--memory-gb``) so that an
allocation bomb ends in a MemoryError (a traceback) instead of the OOM killer.

    python benchmarks/fuzz_commands.py --seed 0 --cases 1300 --timeout 60 --jobs 2
    python benchmarks/fuzz_commands.py --seed 0 --cases 130 --only "import colmap"   # one command

The same generator feeds ``tests/test_fuzz_commands.py`` (a small slice run in-process, in CI).
Case ``k`` of a run with seed ``s`` is ``(command k mod n, random.Random(f"{s}:{k}"))``: the
same seed gives the same cases on every machine, and any one case can be re-run alone
(``--case K``).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import math
import os
import random
import re
import resource
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTDATA = ROOT / "tests" / "data"

OUTCOMES = ("exit-0", "clean", "traceback", "hang", "wrong")

# --------------------------------------------------------------------------- mutations
NASTY = ["", " ", "nan", "NaN", "inf", "-inf", "Infinity", "1e308", "-1e308", "1e-300", "-1e10", "1e10",
         "0", "-1", "-0", "1,5", "1.5.3", "\u0661\u0662\u0663", "\u0967\u0968", "\uff11\uff12", "1_000", "0x10",
         "++1", "e5", "9" * 400, "1e29", "\"", ",", ";", "#", "\t", "P 1", "\u00e9", "[", "=", "\\",
         "x/../../pwn", "../" * 6 + "etc/passwd", "/proc/self/environ", "a" * 300, "\x00", "true", "None"]


def nasty(rng: random.Random) -> str:
    if rng.random() < 0.15:
        return "".join(rng.choice("0123456789.-e+,x ;\"'\u0663") for _ in range(rng.randint(1, 8)))
    return rng.choice(NASTY)


def byte_flips(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    if not b:
        return bytes(rng.randrange(256) for _ in range(rng.randint(1, 64)))
    for _ in range(rng.randint(1, 8)):
        p = rng.randrange(min(len(b), 400)) if rng.random() < 0.6 else rng.randrange(len(b))
        b[p] = rng.randrange(256)
    return bytes(b)


def truncate(data: bytes, rng: random.Random) -> bytes:
    return data[:rng.randrange(len(data) + 1)] if data else data


def random_bytes(data: bytes, rng: random.Random) -> bytes:
    n = rng.choice([0, 1, 16, 512, max(1, len(data))])
    return bytes(rng.randrange(256) for _ in range(min(n, 200_000)))


def _lines(data: bytes) -> list[str]:
    return data.decode("utf-8", errors="surrogateescape").split("\n")


def _join(lines: list[str]) -> bytes:
    return "\n".join(lines).encode("utf-8", errors="surrogateescape")


def _sep(line: str) -> str:
    for s in (",", "\t", ";", "="):
        if s in line:
            return s
    return " "


def _data_line(lines: list[str], rng: random.Random) -> int:
    idx = [i for i, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith("#")]
    return rng.choice(idx) if idx else 0


def text_cell(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    k = _data_line(lines, rng)
    sep = _sep(lines[k])
    cells = lines[k].split(sep)
    op = rng.random()
    if op < 0.6 or len(cells) < 2:
        cells[rng.randrange(len(cells))] = nasty(rng)
    elif op < 0.8:
        i, j = rng.sample(range(len(cells)), 2)
        cells[i], cells[j] = cells[j], cells[i]
    else:                                               # a type change: a number becomes text or grows
        i = rng.randrange(len(cells))
        cells[i] = rng.choice(["abc", cells[i] + "e400", "-" + cells[i], cells[i] * 3])
    lines[k] = sep.join(cells)
    return _join(lines)


def text_lines(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    op = rng.random()
    if op < 0.4:                                        # delete a column from every line that has it
        sep = _sep(lines[_data_line(lines, rng)])
        col = rng.randrange(8)
        lines = [sep.join(c[:col] + c[col + 1:]) if len(c := ln.split(sep)) > col else ln for ln in lines]
    elif op < 0.7:
        del lines[_data_line(lines, rng)]
    else:
        k = _data_line(lines, rng)
        lines.insert(k, lines[k])
    return _join(lines)


def toml_mutation(data: bytes, rng: random.Random) -> bytes:
    lines = _lines(data)
    keyed = [i for i, ln in enumerate(lines) if re.match(r"\s*[A-Za-z0-9_.\"-]+\s*=", ln)]
    if not keyed:
        return byte_flips(data, rng)
    k = rng.choice(keyed)
    key, _, value = lines[k].partition("=")
    op = rng.random()
    if op < 0.5:
        v = nasty(rng)
        lines[k] = f"{key}= {rng.choice([v, json.dumps(v)])}"
    elif op < 0.65:                                     # type change
        v = value.split("#")[0].strip()
        lines[k] = f"{key}= " + (v.strip('"') if v.startswith('"') else json.dumps(v))
    elif op < 0.85:
        del lines[k]
    else:                                               # deep nesting
        depth = rng.choice([1000, 100_000])
        lines[k] = f"{key}= " + "[" * depth + "]" * depth
    return _join(lines)


def _json_nodes(obj, path=()):
    yield path, obj
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _json_nodes(v, path + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj[:50]):
            yield from _json_nodes(v, path + (i,))


def json_mutation(data: bytes, rng: random.Random) -> bytes:
    try:
        obj = json.loads(data)
    except ValueError:
        return byte_flips(data, rng)
    nodes = [p for p, _ in _json_nodes(obj) if p]
    if not nodes:
        return byte_flips(data, rng)
    path = rng.choice(nodes)
    parent = obj
    for p in path[:-1]:
        parent = parent[p]
    op = rng.random()
    depth = rng.choice([1000, 100_000])
    if op < 0.2 and isinstance(parent, dict):
        del parent[path[-1]]
    elif op < 0.3:
        text = json.dumps(obj)
        return (text[:1] + "[" * depth + "]" * depth + "," + text[1:]).encode() if text.startswith("[") \
            else ("[" * depth + "]" * depth).encode()
    else:
        parent[path[-1]] = rng.choice([None, True, "x", "", [], {}, math.nan, math.inf, -math.inf, 1e308, -1e10,
                                       10 ** 400, -1, 0, "\u0661\u0662", [1, 2], {"a": 1}, nasty(rng)])
    try:
        return json.dumps(obj).encode()
    except (ValueError, OverflowError):
        return json.dumps(obj, default=str).encode()


def xml_mutation(data: bytes, rng: random.Random) -> bytes:
    text = data.decode("utf-8", errors="surrogateescape")
    op = rng.random()
    if op < 0.5:
        attrs = list(re.finditer(r'(\w+)="([^"]*)"', text))
        if attrs:
            m = rng.choice(attrs)
            v = nasty(rng).replace('"', "&quot;").replace("<", "&lt;").replace("&", "&amp;")
            text = text[:m.start(2)] + v + text[m.end(2):]
    elif op < 0.7:
        elems = list(re.finditer(r"<(\w+)[^<>]*/>", text))
        if elems:
            m = rng.choice(elems)
            text = text[:m.start()] + text[m.end():]
    elif op < 0.85:                                     # billion laughs before the root element
        decl = ('<!DOCTYPE lolz [<!ENTITY lol "lol">'
                + "".join(f'<!ENTITY lol{i} "{("&lol" + (str(i - 1) if i > 1 else "") + ";") * 10}">'
                          for i in range(1, 10)) + "]>")
        start = text.find("<", text.find("?>") + 2 if "?>" in text else 0)
        m = re.search(r'(\w+)="[^"]*"', text[start:])
        text = text[:start] + decl + text[start:]
        if m:
            s = start + len(decl) + m.start()
            text = text[:s] + re.sub(r'"[^"]*"', '"&lol9;"', text[s:s + len(m.group(0))], count=1) \
                + text[s + len(m.group(0)):]
    else:                                               # deep nesting inside the root element
        depth = rng.choice([1000, 100_000])
        end = text.rfind("</")
        if end > 0:
            text = text[:end] + "<a>" * depth + "</a>" * depth + text[end:]
    return text.encode("utf-8", errors="surrogateescape")


MUTATIONS = {
    "text": [("cell", text_cell, 5), ("lines", text_lines, 2), ("flip", byte_flips, 1),
             ("truncate", truncate, 1), ("random", random_bytes, 0.3)],
    "toml": [("toml", toml_mutation, 5), ("cell", text_cell, 1), ("flip", byte_flips, 1),
             ("truncate", truncate, 1), ("random", random_bytes, 0.3)],
    "json": [("json", json_mutation, 5), ("flip", byte_flips, 1), ("truncate", truncate, 1),
             ("random", random_bytes, 0.3)],
    "xml": [("xml", xml_mutation, 5), ("flip", byte_flips, 1), ("truncate", truncate, 1),
            ("random", random_bytes, 0.3)],
    "binary": [("flip", byte_flips, 6), ("truncate", truncate, 2), ("random", random_bytes, 0.5)],
}


def kind_of(path: str) -> str:
    suffix = Path(path).suffix.lower()
    if suffix == ".toml":
        return "toml"
    if suffix in (".json", ".geojson"):
        return "json"
    if suffix == ".xml":
        return "xml"
    if suffix in (".las", ".laz", ".tif", ".png", ".gpkg"):
        return "binary"
    return "text"


def mutate(data: bytes, kind: str, rng: random.Random) -> tuple[str, bytes]:
    names, fns, weights = zip(*MUTATIONS[kind])
    i = rng.choices(range(len(names)), weights=weights)[0]
    return names[i], fns[i](data, rng)


# --------------------------------------------------------------------------- the commands
@dataclass(frozen=True)
class Target:
    """One command: the corpus entries it needs, the files that are mutated, its arguments.

    ``inputs`` are copied from the corpus into the case folder (same relative names);
    ``mutable`` are relative paths inside the case folder (one is mutated per case);
    ``argv`` is the command line, relative to the case folder (the subprocess's cwd);
    ``output`` (if any) is the path an exit 0 must leave valid: ``survey`` or ``product``.
    """
    name: str
    inputs: tuple[str, ...]
    mutable: tuple[str, ...]
    argv: tuple[str, ...]
    output: tuple[str, str] | None = None


S = ("survey.toml", "camera.toml", "photos.csv", "ground_points.csv", "image_points.csv", "control_sets.csv")
THESIS = tuple(f"thesis/{n}" for n in S)
DEMO = tuple(f"demo/{n}" for n in S)
ADJ = ("adj/eop.csv", "adj/points.csv", "adj/check_covariance.csv", "adj/summary.json")
CRS = ("--crs", "EPSG:7415")

TARGETS: tuple[Target, ...] = (
    Target("import colmap", ("colmap",), ("colmap/cameras.txt", "colmap/images.txt", "colmap/points3D.txt"),
           ("import", "colmap", "colmap", "-o", "out", "--control-sd-m", "0.05"), ("survey", "out")),
    Target("import opensfm", ("opensfm",), ("opensfm/reconstruction.json", "opensfm/tracks.csv"),
           ("import", "opensfm", "opensfm/reconstruction.json", "--tracks", "opensfm/tracks.csv", "-o", "out"),
           ("survey", "out")),
    Target("import metashape", ("metashape",), ("metashape/chunk.doc.xml", "metashape/frame.doc.xml"),
           ("import", "metashape", "metashape/chunk.doc.xml", "--frame", "metashape/frame.doc.xml", "-o", "out"),
           ("survey", "out")),
    Target("import borea", ("borea",), ("borea/test.OPK", "borea/Camera1.txt", "borea/GCP_test.app",
                                        "borea/terrain_test.mes"),
           ("import", "borea", "borea/test.OPK", "--camera", "borea/Camera1.txt", "--camera", "borea/Camera2.txt",
            "--points", "borea/GCP_test.app", "--measurements", "borea/terrain_test.mes", "--measurements",
            "borea/liaisons_test.mes", "--crs", "EPSG:2154", "-o", "out"), ("survey", "out")),
    Target("import opk", ("thesis", "thesis.opk"), ("thesis.opk",) + THESIS[:3],
           ("import", "opk", "thesis.opk", "--survey", "thesis", "-o", "out"), ("survey", "out")),
    Target("import gnss", ("thesis", "gnss.csv"), ("gnss.csv", "thesis/survey.toml", "thesis/photos.csv"),
           ("import", "gnss", "gnss.csv", "--survey", "thesis", "--file-crs", "EPSG:29192", "-o", "out"),
           ("survey", "out")),
    Target("import odm-geo", ("thesis", "geo.txt"), ("geo.txt", "thesis/photos.csv"),
           ("import", "odm-geo", "geo.txt", "--survey", "thesis", "-o", "out"), ("survey", "out")),
    Target("import odm-gcp", ("thesis", "gcp_list.txt"), ("gcp_list.txt", "thesis/ground_points.csv"),
           ("import", "odm-gcp", "gcp_list.txt", "--survey", "thesis", "-o", "out"), ("survey", "out")),
    Target("import opensfm-gcp", ("osfm_survey", "ground_control_points.json"),
           ("ground_control_points.json", "osfm_survey/survey.toml", "osfm_survey/image_points.csv"),
           ("import", "opensfm-gcp", "ground_control_points.json", "--survey", "osfm_survey", "-o", "out"),
           ("survey", "out")),
    Target("import heights", ("thesis",), ("thesis/survey.toml", "thesis/ground_points.csv"),
           ("import", "heights", "thesis", "--to", "orthometric", "-o", "out"), ("survey", "out")),
    Target("camera info", ("thesis",), ("thesis/camera.toml",), ("camera", "info", "thesis/camera.toml")),
    Target("camera correct", ("thesis", "px.csv"), ("px.csv", "thesis/camera.toml", "thesis/survey.toml",
                                                    "thesis/image_points.csv"),
           ("camera", "correct", "thesis", "-o", "corrected.csv")),
    Target("lidar info", ("house.laz", "sample_c.las", "house.xyz"), ("house.laz", "sample_c.las", "house.xyz"),
           ("lidar", "info", "house.laz", "sample_c.las", "house.xyz", *CRS)),
    Target("lidar index", ("house.laz", "sample_c.las"), ("house.laz", "sample_c.las"),
           ("lidar", "index", "house.laz", "sample_c.las", *CRS, "--index-file", "index.json")),
    Target("lidar clip", ("house.laz", "house.xyz"), ("house.laz", "house.xyz"),
           ("lidar", "clip", "house.laz", "house.xyz", *CRS, "--at", "85006", "447472", "--radius", "5",
            "--min-points", "1")),
    Target("lidar raster", ("house.laz", "house.xyz"), ("house.laz", "house.xyz"),
           ("lidar", "raster", "house.laz", "house.xyz", *CRS, "--what", "dsm", "--cell", "0.5", "-o", "r.tif"),
           ("product", "r.tif")),
    Target("lidar ground", ("sample_c.las",), ("sample_c.las",),
           ("lidar", "ground", "sample_c.las", *CRS, "-o", "g.las")),
    Target("lidar dtm", ("ground.laz",), ("ground.laz",),
           ("lidar", "dtm", "ground.laz", *CRS, "-o", "dtm.tif"), ("product", "dtm.tif")),
    Target("lidar dsm", ("ground.laz", "sample_c.las"), ("ground.laz", "sample_c.las"),
           ("lidar", "dsm", "ground.laz", *CRS, "-o", "dsm.tif"), ("product", "dsm.tif")),
    Target("lidar contours", ("ground.laz",), ("ground.laz",),
           ("lidar", "contours", "ground.laz", *CRS, "-o", "c.geojson"), ("product", "c.geojson")),
    Target("lidar hypsometry", ("ground.laz",), ("ground.laz",),
           ("lidar", "hypsometry", "ground.laz", *CRS, "-o", "h.tif"), ("product", "h.tif")),
    Target("lidar sheets", ("dtm.tif", "contours.geojson"), ("dtm.tif", "contours.geojson"),
           ("lidar", "sheets", "dtm.tif", "contours.geojson", "-o", "sheets", "--size-m", "20", *CRS)),
    Target("extract", ("jobs.csv", "house.laz", "house.xyz"), ("jobs.csv", "house.laz", "house.xyz"),
           ("extract", "jobs.csv", *CRS, "-o", "cp.csv")),
    Target("extract (demo)", ("demo",), ("demo/jobs.csv", "demo/lidar/tile_0_0.laz", "demo/survey.toml"),
           ("extract", "demo/jobs.csv", *(f"demo/lidar/tile_{i}_{j}.laz" for i in (0, 1) for j in (0, 1)),
            "--crs", "EPSG:31982", "-o", "cp.csv")),
    Target("extract --find", ("house.laz",), ("house.laz",),
           ("extract", "--find", "--lidar", "house.laz", *CRS, "-o", "found.geojson")),
    Target("adjust", ("thesis",), THESIS, ("adjust", "thesis", "-o", "adj_out", "--snooping", "off")),
    Target("assess", ("adj", "thesis"), ("adj/points.csv", "adj/check_covariance.csv", "thesis/ground_points.csv",
                                         "thesis/survey.toml"),
           ("assess", "adj", "thesis", "--scale", "2000", "--contour-interval", "2")),
    Target("export colmap", ("adj", "thesis"), ADJ[:2] + ("thesis/camera.toml", "thesis/image_points.csv"),
           ("export", "colmap", "adj", "--survey", "thesis", "-o", "colmap_out")),
    Target("export opk", ("adj", "thesis"), ADJ[:1] + ("thesis/survey.toml",),
           ("export", "opk", "adj", "--survey", "thesis", "-o", "out.opk")),
    Target("export gis", ("adj", "thesis"), ADJ + ("thesis/ground_points.csv",),
           ("export", "gis", "adj", "--survey", "thesis", "-o", "gis", "--format", "geojson")),
    Target("monoplot", ("demo", "demo_adj", "features.csv", "dsm_demo.tif"),
           ("features.csv", "dsm_demo.tif", "demo_adj/eop.csv", "demo/camera.toml", "demo/survey.toml"),
           ("monoplot", "demo", "--photo", "1", "--features", "features.csv", "--surface", "dsm_demo.tif",
            "--eop", "demo_adj/eop.csv", "-o", "m.csv")),
    Target("ortho", ("demo", "demo_adj", "dsm_demo.tif"),
           ("dsm_demo.tif", "demo_adj/eop.csv", "demo/images/1.png", "demo/camera.toml", "demo/photos.csv"),
           ("ortho", "demo", "--photo", "1", "--dsm", "dsm_demo.tif", "--eop", "demo_adj/eop.csv", "--gsd", "2",
            "-o", "ortho_out"), ("product", "ortho_out")),
    Target("run", ("thesis",), THESIS, ("run", "thesis", "-o", "run_out")),
    # round 3: the commands of issues 25, 26 and 28
    Target("init", ("demo", "init_gnss.csv"), ("demo/images/1.png", "demo/camera.toml", "init_gnss.csv"),
           ("init", "new_survey", "--images", "demo/images", "--camera", "demo/camera.toml", "--gnss",
            "init_gnss.csv", "--gnss-crs", "EPSG:31982"), ("survey", "new_survey")),
    Target("match", ("demo",), ("demo/images/1.png", "demo/images/2.png", "demo/photos.csv", "demo/camera.toml",
                                "demo/survey.toml", "demo/ground_points.csv"),
           ("match", "demo", "--max-side", "1000"), ("survey", "demo")),
    Target("convert", ("colmap",), ("colmap/cameras.txt", "colmap/images.txt", "colmap/points3D.txt"),
           ("convert", "colmap", "colmap", "opensfm", "osfm_out"), ("product", "osfm_out")),
    Target("deliver", ("dtm.tif", "contours.geojson", "contours_spots.geojson"),
           ("dtm.tif", "contours.geojson", "contours_spots.geojson"),
           ("deliver", "dtm.tif", "contours.geojson", "contours_spots.geojson", "-o", "delivery", "--format", "tfw",
            "--format", "shp", "--format", "dxf", *CRS), ("product", "delivery")),
    Target("chart", ("ortho_demo.tif", "contours_demo.geojson"), ("ortho_demo.tif", "contours_demo.geojson"),
           ("chart", "ortho_demo.tif", "contours_demo.geojson", "-o", "charts", "--size-m", "500", "--dpi", "30"),
           ("product", "charts")),
    Target("lidar check", ("ground.laz", "checkpoints.csv"), ("ground.laz", "checkpoints.csv"),
           ("lidar", "check", "ground.laz", "--checkpoints", "checkpoints.csv", "-o", "check.json", *CRS,
            "--classes", "all", "--scale", "1000", "--contour-interval-m", "1")),
)



# --------------------------------------------------------------------------- the corpus
def _cli(*args: str, cwd: Path) -> None:
    """Run lidarcat in ``cwd`` (a subprocess), failing on a non-zero exit."""
    subprocess.run([sys.executable, "-m", "lidarcat.cli.main", "-q", *args], cwd=cwd, check=True,
                   env=_env(), stdout=subprocess.DEVNULL)


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src")] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep)
                                                               if p])
    env.setdefault("OMP_NUM_THREADS", "1")
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


def _csv_rows(path: Path) -> list[list[str]]:
    return [ln.split(",") for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


def build_corpus(root: Path, cli=None) -> Path:
    """Write the unmutated inputs of every target into ``root`` (once; reused when complete).

    ``cli(*args, cwd=...)`` runs lidarcat (default: a subprocess; the CI test runs it in-process)."""
    run = cli or _cli
    done = root / ".complete"
    if done.exists():
        return root
    root.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT / "src"))
    import numpy as np

    from lidarcat.lidar import read_points, write_points
    from lidarcat.survey import thesis_survey_path

    shutil.copytree(thesis_survey_path(), root / "thesis", dirs_exist_ok=True)
    shutil.rmtree(root / "thesis" / "published", ignore_errors=True)
    shutil.copytree(TESTDATA / "interop" / "colmap" / "kapture_maupertuis", root / "colmap", dirs_exist_ok=True)
    (root / "colmap" / "kapture_records_gnss.txt").unlink(missing_ok=True)
    osfm = root / "opensfm"
    osfm.mkdir(exist_ok=True)
    shutil.copy(TESTDATA / "interop/opensfm/berlin_reconstruction_example.json", osfm / "reconstruction.json")
    shutil.copy(TESTDATA / "interop/opensfm/berlin_tracks_example.csv", osfm / "tracks.csv")
    shutil.copy(TESTDATA / "interop/opensfm/berlin_ground_control_points.json", root / "ground_control_points.json")
    ms = root / "metashape"
    ms.mkdir(exist_ok=True)
    shutil.copy(TESTDATA / "interop/metashape/easyidp_wheat_tanashi_chunk.doc.xml", ms / "chunk.doc.xml")
    shutil.copy(TESTDATA / "interop/metashape/easyidp_wheat_tanashi_frame.doc.xml", ms / "frame.doc.xml")
    borea = root / "borea"
    borea.mkdir(exist_ok=True)
    for src in (TESTDATA / "interop" / "opk").glob("borea_*"):
        shutil.copy(src, borea / src.name.removeprefix("borea_").replace("23FD1305_alt_", ""))

    ahn = read_points(TESTDATA / "lidar" / "ahn3_cropped_2.laz", crs="EPSG:7415")
    house = ahn.select((ahn.x >= 85000) & (ahn.x <= 85012) & (ahn.y >= 447462) & (ahn.y <= 447482))
    write_points(root / "house.laz", house)
    write_points(root / "house.xyz", house.select(slice(0, 400)))
    shutil.copy(TESTDATA / "lidar" / "pdal_sample_c.las", root / "sample_c.las")
    (root / "jobs.csv").write_text("point,E,N,threshold_m,radius_m,file\nP1,85006.0,447472.0,0.15,6,house.laz\n"
                                   "P2,85003.0,447470.0,,5,house.xyz\n")
    (root / "px.csv").write_text("# two measurements\nphoto,point,col_px,row_px,comment,\n"
                                 "1,701,1715.7,636.9,a,\n5,662,2021.6,111.23,b,\n")

    run("adjust", "thesis", "-o", "adj", "--snooping", "off", cwd=root)
    run("export", "opk", "adj", "--survey", "thesis", "-o", "thesis.opk", cwd=root)
    eop = _csv_rows(root / "adj" / "eop.csv")
    (root / "gnss.csv").write_text("photo,E,N,h,omega,phi,kappa,sd_E,sd_N,sd_h\n" + "".join(
        ",".join(r[:7]) + ",0.1,0.1,0.2\n" for r in eop[1:]))
    gp = {r[0]: r[1:4] for r in _csv_rows(root / "thesis" / "ground_points.csv")[1:]}
    (root / "gcp_list.txt").write_text("EPSG:29192\n" + "".join(
        f"{' '.join(gp[r[1]])} {r[2]} {r[3]} {r[0]} G{r[1]}\n"
        for r in _csv_rows(root / "thesis" / "image_points.csv")[1:] if r[1] in gp))
    (root / "geo.txt").write_text("EPSG:29192\n" + "".join(
        f"{r[0]} {r[1]} {r[2]} {r[3]} 0 0 0 0.1 0.2\n" for r in eop[1:]))
    run("import", "opensfm", "opensfm/reconstruction.json", "--tracks", "opensfm/tracks.csv", "-o", "osfm_survey",
         cwd=root)

    run("demo", "synthetic", "-o", "demo", "--photos", "2", "--images", "--image-downsample", "8",
         "--density", "2", cwd=root)
    run("adjust", "demo", "-o", "demo_adj", "--snooping", "off", cwd=root)
    run("lidar", "raster", "demo/lidar/*.laz", "--what", "dsm", "--cell", "1", "-o", "dsm_demo.tif",
         "--no-preview", cwd=root)
    (root / "features.csv").write_text("feature,class,col_px,row_px\nP0,roof,300,300\nP1,roof,310,320\n"
                                       "P2,road,100,400\n")
    run("lidar", "ground", "house.laz", *CRS, "-o", "ground.laz", cwd=root)
    run("lidar", "dtm", "ground.laz", *CRS, "-o", "dtm.tif", cwd=root)
    run("lidar", "contours", "ground.laz", *CRS, "-o", "contours.geojson", "--interval-m", "0.5", cwd=root)
    # round 3: init (the demo's photos with a GNSS/IMU file), lidar check, chart (an orthophoto of the demo)
    eop = _csv_rows(root / "demo_adj" / "eop.csv")
    (root / "init_gnss.csv").write_text("photo,E,N,h,omega,phi,kappa\n" + "".join(
        ",".join(r[:7]) + "\n" for r in eop[1:]))
    g = read_points(root / "ground.laz", crs="EPSG:7415")
    from scipy.spatial import Delaunay
    hull = Delaunay(np.c_[g.x, g.y])                     # check points inside the ground triangulation, 0.2 m in
    near = np.c_[g.x, g.y] + np.array([[0.2, 0.2], [0.2, -0.2], [-0.2, 0.2], [-0.2, -0.2]])[:, None]
    inner = np.flatnonzero((hull.find_simplex(near.reshape(-1, 2)).reshape(4, -1) >= 0).all(axis=0))
    inner = inner[:: max(1, len(inner) // 12)][:12]
    (root / "checkpoints.csv").write_text("id,E,N,H,vegetated\n" + "".join(
        f"c{k},{g.x[i]:.3f},{g.y[i]:.3f},{g.z[i] + 0.02 * (-1) ** k:.3f},{k % 2}\n" for k, i in enumerate(inner)))
    run("ortho", "demo", "--photo", "1", "--dsm", "dsm_demo.tif", "--eop", "demo_adj/eop.csv", "--gsd", "2",
        "-o", "ortho_c", cwd=root)
    shutil.copy(next((root / "ortho_c").glob("*.tif")), root / "ortho_demo.tif")
    run("lidar", "ground", "demo/lidar/tile_0_0.laz", "-o", "ground_demo.laz", cwd=root)
    run("lidar", "contours", "ground_demo.laz", "-o", "contours_demo.geojson", "--interval-m", "2", cwd=root)
    done.write_text("ok\n")
    return root


# --------------------------------------------------------------------------- one case
@dataclass
class Case:
    seed: int
    index: int
    target: Target
    file: str = ""
    mutation: str = ""
    data: bytes = field(default=b"", repr=False)


def targets(only: str | None = None) -> tuple[Target, ...]:
    return tuple(t for t in TARGETS if only is None or t.name == only)


def make_case(seed: int, index: int, corpus: Path, pool: tuple[Target, ...] = TARGETS,
              target: str | None = None) -> Case:
    """Case ``index`` of seed ``seed``: a target (round robin, or the one named *target*) and one
    mutated file (seeded by seed and index alone, so a case numbered in a smaller pool of an
    earlier round is re-made exactly by naming its target)."""
    if target is None:
        target = pool[index % len(pool)]
    else:
        named = [t for t in TARGETS if t.name == target]
        if not named:
            raise ValueError(f"no fuzz target {target!r}")
        target = named[0]
    rng = random.Random(f"{seed}:{index}")
    rel = rng.choice(target.mutable)
    name, data = mutate((corpus / rel).read_bytes(), kind_of(rel), rng)
    return Case(seed, index, target, rel, name, data)


def stage_case(case: Case, corpus: Path, work: Path) -> Path:
    """Copy the target's inputs into ``work`` and write the mutated file."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    for rel in case.target.inputs:
        src = corpus / rel
        if src.is_dir():
            shutil.copytree(src, work / rel)
        else:
            (work / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(src, work / rel)
    (work / case.file).write_bytes(case.data)
    return work


def classify(exit_code: int | None, output: str) -> str:
    """exit-0, clean (exit 1-3, no traceback), traceback (any other status or a traceback), hang (None)."""
    if exit_code is None:
        return "hang"
    if "Traceback (most recent call last)" in output:
        return "traceback"
    if exit_code == 0:
        return "exit-0"
    return "clean" if exit_code in (1, 2, 3) else "traceback"


MAX_PRODUCT_BYTES = 100_000_000


def check_output(case: Case, work: Path) -> str | None:
    """Why an exit-0 output is clearly wrong, or None (cheap checks only)."""
    if case.target.output is None:
        return None
    kind, rel = case.target.output
    path = work / rel
    if kind == "survey":
        sys.path.insert(0, str(ROOT / "src"))
        from lidarcat.errors import LidarcatError
        from lidarcat.survey.folder import Survey
        try:
            Survey.load(path)
        except LidarcatError as e:
            return f"import exited 0 but Survey.load refuses its survey: {str(e)[:300]}"
        except Exception as e:                               # noqa: BLE001 -- a crash of the reader is wrong too
            return f"import exited 0 but Survey.load crashed: {type(e).__name__}: {str(e)[:300]}"
        return None
    size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file()) if path.is_dir() else \
        (path.stat().st_size if path.exists() else 0)
    if size > MAX_PRODUCT_BYTES:
        return f"{rel}: {size / 1e6:.0f} MB from a {sum(1 for _ in case.target.inputs)}-file input"
    return None


def _limit_memory(gb: float):
    def apply():
        lim = int(gb * 2 ** 30)
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    return apply


def run_case(case: Case, corpus: Path, work: Path, timeout: float, memory_gb: float) -> dict:
    stage_case(case, corpus, work)
    argv = [sys.executable, "-m", "lidarcat.cli.main", *case.target.argv]
    t0 = time.monotonic()
    try:
        p = subprocess.run(argv, cwd=work, env=_env(), capture_output=True, timeout=timeout,
                           preexec_fn=_limit_memory(memory_gb))
        code, out = p.returncode, (p.stdout + p.stderr).decode("utf-8", errors="replace")
    except subprocess.TimeoutExpired as e:
        code, out = None, ((e.stdout or b"") + (e.stderr or b"")).decode("utf-8", errors="replace")
    seconds = time.monotonic() - t0
    outcome = classify(code, out)
    why = check_output(case, work) if outcome == "exit-0" else None
    if why:
        outcome = "wrong"
    return {"command": case.target.name, "index": case.index, "file": case.file, "mutation": case.mutation,
            "outcome": outcome, "exit": code, "seconds": round(seconds, 2), "why": why,
            "tail": out.strip().splitlines()[-3:] if out.strip() else []}


def save_failure(case: Case, result: dict, work: Path, failures: Path) -> None:
    dest = failures / f"{case.seed}_{case.index:05d}_{case.target.name.replace(' ', '_')}"
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(work, dest, ignore=shutil.ignore_patterns("out", "*_out", "work"))
    cmd = " ".join(_quote(a) for a in case.target.argv)
    (dest / "repro.sh").write_text(f"# {json.dumps(result)}\ncd \"$(dirname \"$0\")\" && lidarcat {cmd}\n")


def _quote(a: str) -> str:
    return a if re.fullmatch(r"[\w./:=,+-]+", a) else "'" + a.replace("'", "'\\''") + "'"


# --------------------------------------------------------------------------- the run
def table(results: list[dict]) -> str:
    names = list(dict.fromkeys(r["command"] for r in results))
    rows = ["| command | cases | exit-0 | clean error | traceback | hang | wrong exit-0 | median s |",
            "|---|---:|---:|---:|---:|---:|---:|---:|"]
    tot = {o: 0 for o in OUTCOMES}
    for n in names:
        rs = [r for r in results if r["command"] == n]
        c = {o: sum(r["outcome"] == o for r in rs) for o in OUTCOMES}
        for o in OUTCOMES:
            tot[o] += c[o]
        med = sorted(r["seconds"] for r in rs)[len(rs) // 2]
        rows.append(f"| `{n}` | {len(rs)} | {c['exit-0']} | {c['clean']} | {c['traceback']} | {c['hang']} | "
                    f"{c['wrong']} | {med:.1f} |")
    rows.append(f"| **all** | {len(results)} | {tot['exit-0']} | {tot['clean']} | {tot['traceback']} | "
                f"{tot['hang']} | {tot['wrong']} | |")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=int, default=1300)
    ap.add_argument("--case", type=int, action="append", help="run only this case index (repeat)")
    ap.add_argument("--only", help="one command, e.g. 'import colmap'")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds a case may run (then: a hang)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--memory-gb", type=float, default=3.0, help="address-space limit of each case")
    ap.add_argument("--corpus", type=Path, default=ROOT / "benchmarks" / "out" / "fuzz_corpus")
    ap.add_argument("--work", type=Path, default=ROOT / "benchmarks" / "out" / "fuzz_work")
    ap.add_argument("--failures", type=Path, default=ROOT / "benchmarks" / "out" / "fuzz_failures")
    ap.add_argument("--json", type=Path, help="write every result to this JSON file")
    args = ap.parse_args(argv)

    pool = targets(args.only)
    if not pool:
        ap.error(f"--only: no command {args.only!r}; one of: {', '.join(t.name for t in TARGETS)}")
    corpus = build_corpus(args.corpus)
    indices = args.case or list(range(args.cases))
    args.failures.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()

    def one(k: int) -> dict:
        case = make_case(args.seed, k, corpus, pool)
        work = args.work / f"case_{k:05d}"
        result = run_case(case, corpus, work, args.timeout, args.memory_gb)
        if result["outcome"] in ("traceback", "hang", "wrong"):
            save_failure(case, result, work, args.failures)
        shutil.rmtree(work, ignore_errors=True)
        return result

    results = []
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as ex:
        for r in ex.map(one, indices):
            results.append(r)
            if r["outcome"] in ("traceback", "hang", "wrong"):
                print(f"[{r['index']}] {r['command']} {r['file']} ({r['mutation']}): {r['outcome']} "
                      f"exit {r['exit']}: {r['why'] or (r['tail'][-1] if r['tail'] else '')}"[:240], flush=True)
    wall = time.monotonic() - t0
    print(table(results))
    print(f"\n{len(results)} cases in {wall:.0f} s wall ({len(results) / wall * 60:.1f} cases/min, "
          f"--jobs {args.jobs}, seed {args.seed}); failures in {args.failures}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 1 if any(r["outcome"] in ("traceback", "hang", "wrong") for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
