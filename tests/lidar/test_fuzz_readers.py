"""Fuzzing the readers and the CLI commands with mutated files (issue 12 part 2).

Every reader and command is run on mutations of a small corpus of real files (the
PDAL sample, AHN3 crops re-written as LAS/LAZ, the thesis survey, job files, a text
point file): random byte flips (biased towards the LAS header and its records),
truncation at a random length, and, for text files, a cell replaced by a nasty value
(empty, NaN, inf, 1e308, Arabic-Indic digits, a decimal comma...).  Each case must end
either normally or with a :class:`~lidarcat.errors.LidarcatError` (for the CLI: exit
status 0, 1 or 2 and no traceback) -- 0 tracebacks -- within a per-case time bound
(:data:`CASE_SECONDS`, enforced with a timer signal) -- 0 hangs.

CI runs a fixed, derandomised set of examples (about 30 s single-core in all); set
``LIDARCAT_FUZZ_LONG=1`` for a long random run (50 times as many examples per test,
new random ones each run).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
from pathlib import Path

import laspy
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import LIDAR_DATA, THESIS_SURVEY
from lidarcat._util import read_csv_table
from lidarcat.survey.cameras import load_cameras
from lidarcat.cli.main import cli
from lidarcat.errors import LidarcatError
from lidarcat.control.batch import read_jobs
from lidarcat.lidar import TileIndex, clip, read_header, read_points, write_points
from lidarcat.lidar.info import describe_file
from lidarcat.survey.folder import Survey

LONG = os.environ.get("LIDARCAT_FUZZ_LONG", "") not in ("", "0")
#: a case taking longer than this is a hang (seconds of wall time)
CASE_SECONDS = 20.0


def _settings(n: int):
    return settings(max_examples=n * (50 if LONG else 1), deadline=None, derandomize=not LONG,
                    database=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                          HealthCheck.too_slow, HealthCheck.data_too_large])


class Hang(BaseException):
    """Raised by the timer in a case that runs longer than CASE_SECONDS."""


@contextlib.contextmanager
def _time_bound(what: str):
    """Fail the case if it runs longer than CASE_SECONDS.  The timer raises :class:`Hang` and
    also sets a flag checked afterwards: the readers turn decoder failures (BaseException
    included) into located errors, which would otherwise hide a Hang raised inside laspy."""
    fired: list[bool] = []

    def on_alarm(signum, frame):
        fired.append(True)
        raise Hang(f"{what}: still running after {CASE_SECONDS:g} s (a hang)")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, CASE_SECONDS)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if fired:
            raise AssertionError(f"{what}: still running after {CASE_SECONDS:g} s (a hang)")


def _survives(fn, *args, **kwargs):
    """Run a reader: a normal end or a LidarcatError; anything else fails the test."""
    with _time_bound(getattr(fn, "__name__", str(fn))):
        try:
            return fn(*args, **kwargs)
        except LidarcatError:
            return None


def _cli_survives(*args: str) -> None:
    with _time_bound("lidarcat " + " ".join(args[:2])):
        r = CliRunner().invoke(cli, list(args))
    assert r.exit_code in (0, 1, 2), (args, r.exit_code, r.output)
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        raise AssertionError(f"lidarcat {' '.join(args)}: {type(r.exception).__name__}: {r.exception}") \
            from r.exception
    assert "Traceback" not in r.output, r.output


# --------------------------------------------------------------------------- corpus
@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("corpus")
    ahn = read_points(LIDAR_DATA / "ahn3_cropped_2.laz", crs="EPSG:7415")
    house = ahn.select((ahn.x >= 85000) & (ahn.x <= 85012) & (ahn.y >= 447462) & (ahn.y <= 447482))
    out = {
        "laz": write_points(d / "house.laz", house),             # LAZ 1.2 + WKT record, one chunk
        "las": write_points(d / "house.las", house),
        "pdal": Path(shutil.copy(LIDAR_DATA / "pdal_sample_c.las", d / "sample_c.las")),  # format 3
        "xyz": write_points(d / "house.xyz", house.select(slice(0, 400))),
    }
    h = laspy.LasHeader(point_format=6, version="1.4")     # LAS 1.4 with the 64-bit counts
    h.scales, h.offsets = [0.001] * 3, [85000, 447000, 0]
    las = laspy.LasData(h)
    las.x, las.y, las.z = house.xyz[:300].T
    las.return_number = np.full(300, 1, np.uint8)
    las.number_of_returns = np.full(300, 1, np.uint8)
    las.write(d / "f6.laz")
    out["las14"] = d / "f6.laz"
    jobs = d / "jobs.csv"
    jobs.write_text("point,E,N,threshold_m,radius_m,file\nP1,85006.0,447472.0,0.15,6,house.laz\n"
                    "P2,85003.0,447470.0,,5,house.xyz\n")
    out["jobs_csv"] = jobs
    thesis = d / "jobs.txt"
    thesis.write_text("# file point E N threshold radius\nhouse.xyz P704 85006.0 447472.0 0.15 5.0\n")
    out["jobs_txt"] = thesis
    survey = d / "survey"
    shutil.copytree(THESIS_SURVEY, survey)
    out["survey"] = survey
    return out


# --------------------------------------------------------------------------- mutations
NASTY = ["", " ", "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e-300", "0", "-1", "1,5", "1.5.3",
         "\u0661\u0662\u0663", "\u0967", "1_000", "0x10", "++1", "e5", "99999999999999999999999",
         "\"", ",", ";", "#", "\t", "P 1", "\u00e9", "[", "=", "\\"]


@st.composite
def byte_mutations(draw, size: int):
    """(truncate_at or None, [(position, byte)]): flips biased towards the first 400 bytes."""
    pos = st.one_of(st.integers(0, min(size, 400) - 1), st.integers(0, size - 1))
    flips = draw(st.lists(st.tuples(pos, st.integers(0, 255)), min_size=0, max_size=6))
    trunc = draw(st.one_of(st.none(), st.integers(0, size)))
    if not flips and trunc is None:
        flips = [(draw(pos), draw(st.integers(0, 255)))]
    return trunc, flips


def _mutate_bytes(data: bytes, mutation) -> bytes:
    trunc, flips = mutation
    b = bytearray(data)
    for p, v in flips:
        if p < len(b):
            b[p] = v
    return bytes(b[:trunc] if trunc is not None else b)


@st.composite
def text_mutations(draw):
    """('cell', line, cell, value) | ('truncate', fraction) | ('bytes', [(fraction, byte)])."""
    kind = draw(st.sampled_from(["cell", "cell", "cell", "truncate", "bytes"]))
    if kind == "cell":
        return ("cell", draw(st.integers(0, 400)), draw(st.integers(0, 12)),
                draw(st.one_of(st.sampled_from(NASTY), st.text(max_size=6))))
    if kind == "truncate":
        return ("truncate", draw(st.floats(0, 1)))
    return ("bytes", draw(st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=4)))


def _mutate_text(data: bytes, mutation) -> bytes:
    if mutation[0] == "truncate":
        return data[:int(len(data) * mutation[1])]
    if mutation[0] == "bytes":
        b = bytearray(data)
        for f, v in mutation[1]:
            if b:
                b[min(int(f * len(b)), len(b) - 1)] = v
        return bytes(b)
    _, line, cell, value = mutation
    lines = data.decode("utf-8").split("\n")
    k = line % len(lines)
    text = lines[k]
    sep = "," if "," in text else ("=" if "=" in text else " ")
    cells = text.split(sep)
    cells[cell % len(cells)] = value
    lines[k] = sep.join(cells)
    return "\n".join(lines).encode("utf-8", errors="surrogatepass")


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


# --------------------------------------------------------------------------- point files
@pytest.mark.parametrize("seed", ["laz", "las", "pdal", "las14"])
def test_fuzz_las_readers(corpus, tmp_path_factory, seed):
    src = corpus[seed]
    data = src.read_bytes()
    work = tmp_path_factory.mktemp(f"fuzz_{seed}") / src.name

    @_settings(80)
    @given(byte_mutations(len(data)))
    def run(mutation):
        p = _write(work, _mutate_bytes(data, mutation))
        _survives(read_header, p, crs="EPSG:7415")
        _survives(read_points, p, crs="EPSG:7415")
        _survives(describe_file, p, crs="EPSG:7415")
        idx = _survives(TileIndex.build, [p], crs="EPSG:7415")
        if idx is not None:
            _survives(clip, idx, (85006.0, 447472.0), 5.0, min_points=1)

    run()


def test_fuzz_text_points(corpus, tmp_path_factory):
    data = corpus["xyz"].read_bytes()
    work = tmp_path_factory.mktemp("fuzz_xyz") / "pts.xyz"

    @_settings(60)
    @given(text_mutations())
    def run(mutation):
        p = _write(work, _mutate_text(data, mutation))
        _survives(read_points, p, crs="EPSG:7415")
        _survives(describe_file, p, crs="EPSG:7415")

    run()


# --------------------------------------------------------------------------- job, camera, survey files
@pytest.mark.parametrize("seed", ["jobs_csv", "jobs_txt"])
def test_fuzz_job_files(corpus, tmp_path_factory, seed):
    data = corpus[seed].read_bytes()
    work = tmp_path_factory.mktemp(f"fuzz_{seed}") / corpus[seed].name

    @_settings(50)
    @given(text_mutations())
    def run(mutation):
        _survives(read_jobs, _write(work, _mutate_text(data, mutation)))

    run()


@pytest.mark.parametrize("name", ["camera.toml", "ground_points.csv", "photos.csv", "survey.toml",
                                  "control_sets.csv", "image_points.csv"])
def test_fuzz_survey_files(corpus, tmp_path_factory, name):
    work = tmp_path_factory.mktemp(f"fuzz_{name.split('.')[0]}") / "survey"
    shutil.copytree(corpus["survey"], work)
    data = (corpus["survey"] / name).read_bytes()

    @_settings(12 if name == "image_points.csv" else 20)
    @given(text_mutations())
    def run(mutation):
        p = _write(work / name, _mutate_text(data, mutation))
        if name == "camera.toml":
            _survives(load_cameras, p)
        elif name.endswith(".csv") and name != "image_points.csv":
            _survives(read_csv_table, p, allow_extra=True)
        _survives(Survey.load, work)

    run()


# --------------------------------------------------------------------------- CLI commands
def test_fuzz_cli_commands(corpus, tmp_path_factory):
    work = tmp_path_factory.mktemp("fuzz_cli")
    laz = corpus["laz"].read_bytes()
    jobs = corpus["jobs_csv"].read_bytes()
    shutil.copy(corpus["xyz"], work / "house.xyz")

    @_settings(40)
    @given(byte_mutations(len(laz)), text_mutations())
    def run(las_mutation, job_mutation):
        tile = _write(work / "house.laz", _mutate_bytes(laz, las_mutation))
        _cli_survives("lidar", "info", str(tile), "--crs", "EPSG:7415")
        _cli_survives("lidar", "clip", str(tile), "--crs", "EPSG:7415", "--at", "85006", "447472",
                      "--radius", "5", "--min-points", "1")
        _cli_survives("lidar", "index", str(tile), "--crs", "EPSG:7415", "--index-file",
                      str(work / "index.json"))
        j = _write(work / "jobs.csv", _mutate_text(jobs, job_mutation))
        _cli_survives("extract", str(j), "--crs", "EPSG:7415")

    run()


def test_corpus_reads_cleanly(corpus):
    """The unmutated corpus (real files and files other software wrote) stays green."""
    for key in ("laz", "las", "pdal", "las14", "xyz"):
        assert len(read_points(corpus[key], crs="EPSG:7415")) > 0
    assert len(read_jobs(corpus["jobs_csv"])) == 2 and len(read_jobs(corpus["jobs_txt"])) == 1
    assert len(Survey.load(corpus["survey"]).photos) > 0
    r = CliRunner().invoke(cli, ["extract", str(corpus["jobs_csv"]), "--crs", "EPSG:7415", "--json"])
    assert r.exit_code in (0, 1), r.output
