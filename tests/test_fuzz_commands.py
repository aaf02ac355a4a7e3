"""The CI slice of the command fuzz run (issue 24): 0 tracebacks, 0 hangs, 0 wrong exit-0 outputs.

The cases are those of ``benchmarks/fuzz_commands.py`` (the full run, one subprocess a case):
seed :data:`SEED`, case indices ``0 .. CASES-1`` -- the first ones of the run, two per command
(round robin over every command that reads user files), not a selection of passing cases.  Here
they run in-process (click's CliRunner, the working directory set to the case folder) under a
timer: a case running longer than :data:`CASE_SECONDS` is a hang.  A case that fails on main
for a known cause of issue 24 that another change is fixing is an ``xfail(strict=True)`` naming
the cause: it turns into a failure (XPASS) when the fix lands, and the mark goes.

Re-run one case as the benchmark does (subprocess, reproducer folder)::

    python benchmarks/fuzz_commands.py --seed 0 --case K
    python benchmarks/fuzz_commands.py --seed 0 --case 958 --only "import opensfm"   # a regression of REGRESSIONS
"""

from __future__ import annotations

import contextlib
import os
import resource
import signal
import sys
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import ROOT

sys.path.insert(0, str(ROOT / "benchmarks"))
import fuzz_commands as fz  # noqa: E402

from lidarcat.cli.main import cli  # noqa: E402

SEED = 0
CASES = 2 * len(fz.TARGETS)
#: a case running longer than this is a hang (wall seconds, as in the full run: `run` takes ~25 s at load 9)
CASE_SECONDS = 60.0
#: extra address space a case may take
MEMORY_BYTES = 2 * 2 ** 30

#: case index -> the known cause (issue 24) that another change is fixing
KNOWN: dict[int, str] = {
    # every known cause of the CI slice is fixed (nested TOML/JSON, one far point in `lidar ground`)
}


class Hang(BaseException):
    """Raised by the timer in a case that runs longer than CASE_SECONDS."""


@contextlib.contextmanager
def _time_bound(seconds: float):
    fired: list[bool] = []

    def on_alarm(signum, frame):
        fired.append(True)
        raise Hang(f"still running after {seconds:g} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield fired
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextlib.contextmanager
def _memory_bound():
    """At most MEMORY_BYTES more address space while a case runs (an allocation bomb becomes a
    MemoryError, as under the full run's ``ulimit -v``, instead of taking the shared machine)."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    with open("/proc/self/statm") as f:
        used = int(f.read().split()[0]) * resource.getpagesize()
    limit = used + MEMORY_BYTES
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _invoke(args, cwd: Path, seconds: float = CASE_SECONDS):
    """Run lidarcat in ``cwd`` in-process: (exit code or None for a hang, output + traceback text)."""
    old = os.getcwd()
    os.chdir(cwd)
    try:
        with _time_bound(seconds) as fired, _memory_bound():
            try:
                r = CliRunner().invoke(cli, [str(a) for a in args])
            except Hang:
                return None, "hang"
        if fired:
            return None, "hang"
    finally:
        os.chdir(old)
    text = r.output
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        import traceback
        text += "Traceback (most recent call last):\n" + "".join(traceback.format_exception(r.exception))
    return r.exit_code, text


def _corpus_cli(*args, cwd):
    code, text = _invoke(["-q", *args], Path(cwd), seconds=600)
    assert code == 0, (args, text)


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    return fz.build_corpus(tmp_path_factory.mktemp("fuzz_corpus"), cli=_corpus_cli)


#: cases of the same seed beyond the slice that the full run found failing once, kept as regressions:
#: 100 (10^400 in reconstruction.json), 115 (`lidar ground` on a byte-flipped tile: a far point),
#: 120 (a byte-flipped text tag of dtm.tif: UnicodeDecodeError in `lidar sheets`), 600 (`import odm-geo` wrote a
#: photo outside the area of use of the survey CRS, which `Survey.load` refuses), 898 and 964 (`import odm-gcp`
#: wrote a point measured twice on one photo), 958 (`import opensfm` with a truncated tracks.csv wrote
#: image_points.csv without measurement columns).  Numbered in the round-2 pool of 33 commands, so each keeps
#: the name of its command (the round-3 commands appended to the pool shift the round robin).
REGRESSIONS = {100: "import opensfm", 115: "lidar ground", 120: "lidar sheets", 600: "import odm-geo",
               898: "import odm-gcp", 958: "import opensfm", 964: "import odm-gcp"}


@pytest.mark.parametrize("index,target", [
    pytest.param(k, t, marks=pytest.mark.xfail(strict=True, reason=KNOWN[k])) if k in KNOWN else (k, t)
    for k, t in [*((k, None) for k in range(CASES)), *REGRESSIONS.items()]])
def test_fuzz_command_case(corpus, tmp_path, index, target):
    case = fz.make_case(SEED, index, corpus, target=target)
    work = fz.stage_case(case, corpus, tmp_path / "case")
    code, text = _invoke(case.target.argv, work)
    outcome = fz.classify(code, text)
    what = f"case {index}: lidarcat {' '.join(case.target.argv)} with {case.file} mutated ({case.mutation})"
    assert outcome in ("exit-0", "clean"), f"{what}: {outcome} (exit {code})\n{text[-3000:]}"
    if outcome == "exit-0":
        why = fz.check_output(case, work)
        assert why is None, f"{what}: {why}"


@pytest.mark.slow
def test_unmutated_inputs_run(corpus, tmp_path):
    """The corpus itself is valid: every command ends normally (extract of the house tile finds no
    roof corner: exit 1 with its reasons) -- so the mutations, not the setup, make the errors."""
    for t in fz.TARGETS:
        case = fz.Case(SEED, -1, t, t.mutable[0], "none", (corpus / t.mutable[0]).read_bytes())
        work = fz.stage_case(case, corpus, tmp_path / t.name.replace(" ", "_"))
        code, text = _invoke(t.argv, work)
        assert code == (1 if t.name == "extract" else 0), (t.name, text[-2000:])
        assert fz.check_output(case, work) is None, t.name
