"""The CLI never shows a traceback: a bad input is one ``Error: ...`` line; ``run --help`` lists every stage."""

from __future__ import annotations

import pkgutil

import laspy
import numpy as np
import pytest
from click.testing import CliRunner

from lidarcat.cli.main import cli


@pytest.fixture(scope="module")
def no_ground(tmp_path_factory):
    """A small LAS tile with no class-2 point."""
    path = tmp_path_factory.mktemp("bad") / "no_ground.las"
    h = laspy.LasHeader(point_format=1, version="1.2")
    h.scales = [0.01, 0.01, 0.01]
    h.offsets = [500000.0, 7000000.0, 0.0]
    las = laspy.LasData(h)
    rng = np.random.default_rng(1)
    las.x = 500000 + rng.uniform(0, 20, 200)
    las.y = 7000000 + rng.uniform(0, 20, 200)
    las.z = 100 + rng.uniform(0, 1, 200)
    las.classification = np.full(200, 1, np.uint8)
    las.write(path)
    return path


def _one_line_error(args, code=2):
    r = CliRunner().invoke(cli, [str(a) for a in args])
    assert "Traceback" not in r.output, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: "), r.output
    assert r.exit_code == code, (r.exit_code, r.output)
    return lines[0]


def test_lidar_dtm_on_a_tile_without_ground_is_one_line(no_ground, tmp_path):
    # a data condition (ProductError): one line naming the tile, exit 2
    line = _one_line_error(["lidar", "dtm", no_ground, "--crs", "EPSG:31982", "-o", tmp_path / "dtm.tif"])
    assert line == f"Error: {no_ground}: no ground points (class 2); classify the ground first (lidarcat lidar ground)"


@pytest.mark.parametrize("args", [
    ["adjust", "{bad}"],
    ["run", "{bad}", "-o", "{tmp}/out"],
    ["camera", "info", "{bad}"],
    ["assess", "{tmp}/points.csv", "{tmp}/points.csv"],
    ["extract", "{tmp}/jobs.txt", "{tmp}/broken.laz"],
    ["ortho", "{bad}", "--all", "--dtm", "{tmp}/points.csv", "-o", "{tmp}/o"],
    ["monoplot", "{bad}", "--photo", "1", "--features", "{tmp}/points.csv", "--surface", "{tmp}/points.csv",
     "-o", "{tmp}/m.geojson"],
    ["export", "opk", "{bad}", "-o", "{tmp}/x.opk"],
    ["lidar", "info", "{tmp}/points.csv"],
    ["lidar", "ground", "{tmp}/broken.laz", "-o", "{tmp}/g"],
    ["lidar", "dsm", "{tmp}/broken.laz", "-o", "{tmp}/d.tif"],
])
def test_every_command_on_a_bad_input_is_one_line(args, tmp_path):
    bad = tmp_path / "bad_survey"
    bad.mkdir()
    (bad / "survey.toml").write_text("[survey]\nname = 3\n")   # wrong type
    (tmp_path / "points.csv").write_text("not,a,table\n1\n")
    (tmp_path / "jobs.txt").write_text("garbage\n")
    (tmp_path / "broken.laz").write_bytes(b"LASF" + b"\0" * 50)
    _one_line_error([a.format(bad=bad, tmp=tmp_path) for a in args])


def test_run_help_lists_every_stage():
    import lidarcat.stages as stages
    from lidarcat.stages import REGISTRY

    r = CliRunner().invoke(cli, ["run", "--help"])
    assert r.exit_code == 0
    names = [n for n, _ in REGISTRY]
    for name, what in REGISTRY:
        assert f"{name}" in r.output and what in r.output, name
    modules = [m.name for m in pkgutil.iter_modules(stages.__path__)
               if not m.name.startswith("_") and hasattr(getattr(stages, m.name), "run")]
    assert sorted(modules) == sorted(n.replace("-SET", "") for n in names)


# --------------------------------------------------------------------------- disk full, permission denied, read-only
# Issue 24: an OSError while writing (disk full, permission denied, a read-only output folder) is one
# ``Error: FILE: reason`` line (exit 2) naming the output, nothing half-written stays (no .part file),
# and the outputs of an earlier run are intact.  The tests run as root, where chmod does not stop a
# write: EACCES and EROFS are simulated by monkeypatching the creation of the temporary sibling every
# atomic write starts with (tempfile.mkstemp / mkdtemp), ENOSPC by a failing fsync / rename (the end
# of every atomic write; GDAL writes the GeoTIFFs itself, so its disk-full is the rename of the file).
import errno  # noqa: E402
import os  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

from conftest import DATA, THESIS_SURVEY  # noqa: E402

_CRS = "EPSG:31982"


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """Inputs, and every writing command run once successfully into OUT (the outputs to keep intact)."""
    from lidarcat.synthetic.survey import write_synthetic_survey

    root = tmp_path_factory.mktemp("oserror")
    demo = root / "demo"
    write_synthetic_survey(demo, n_photos=2, lidar_density_m2=1.0, images=True, image_downsample=4)
    out = root / "out"
    tiles = sorted((demo / "lidar").glob("*.laz"))
    # ground and contours of a 150 m x 120 m corner of a tile (13 k points, not 121 k): what is asserted,
    # a failing write being one error line that loses nothing, does not depend on the size, and each of
    # the six failing runs of these two commands redoes the whole classification or triangulation
    import laspy

    las = laspy.read(tiles[0])
    small = laspy.LasData(las.header)
    small.points = las.points[(las.x < las.x.min() + 150) & (las.y < las.y.min() + 120)]
    small.write(root / "small.laz")
    (root / "f.csv").write_text("feature,class,col_px,row_px\nF1,roof,100,100\nF1,roof,120,100\n")
    ok = {
        "lidar dsm": ["lidar", "dsm", *tiles, "--crs", _CRS, "-o", out / "dsm.tif"],
        "lidar dtm": ["lidar", "dtm", *tiles, "--crs", _CRS, "-o", out / "dtm.tif", "--text"],
        "lidar ground": ["lidar", "ground", root / "small.laz", "--crs", _CRS, "-o", out / "g", "--no-resume"],
        "lidar contours": ["lidar", "contours", out / "g" / "small.laz", "--crs", _CRS, "-o", out / "c.geojson"],
        "lidar sheets": ["lidar", "sheets", out / "dtm.tif", "-o", out / "sheets", "--size-m", "200"],
        "lidar raster": ["lidar", "raster", tiles[0], "--crs", _CRS, "-o", out / "r.tif"],
        "extract": ["extract", demo / "jobs.csv", *tiles, "--crs", _CRS, "-o", out / "control.csv"],
        "ortho": ["ortho", demo, "--photo", "1", "--dsm", out / "dsm.tif", "--gsd", "2", "--eop",
                  demo / "truth" / "eop.csv", "--images", demo / "images", "-o", out / "ortho"],
        "monoplot": ["monoplot", demo, "--photo", "1", "--features", root / "f.csv", "--surface", out / "dsm.tif",
                     "--eop", demo / "truth" / "eop.csv", "-o", out / "m.geojson"],
        "adjust": ["adjust", THESIS_SURVEY, "-o", out / "adj", "--snooping", "off"],
        "assess": ["assess", DATA / "report" / "points.csv", THESIS_SURVEY, "-o", out / "report.html"],
        "export": ["export", "opk", out / "adj", "-o", out / "t.opk"],
        "import": ["import", "opk", out / "t.opk", "--crs", "EPSG:29192", "--sd-position-m", "0.1",
                   "-o", out / "imp", "--overwrite"],
        "run": ["run", THESIS_SURVEY, "-o", out / "run"],
    }
    for name, args in ok.items():
        r = CliRunner().invoke(cli, [str(a) for a in args])
        assert r.exit_code == 0, (name, r.output)
    return root, out, {k: [str(a) for a in v] for k, v in ok.items()}


def _tree(folder):
    """Every file and folder under *folder* with its bytes; the hidden ``.<model>.tif.tiles`` folders
    of the one-file DTM/DSM are left out: they keep the finished tiles for a resumed run (by design)."""
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(folder.rglob("*")) if ".tif.tiles" not in str(p.relative_to(folder))}


def _full_disk(monkeypatch):
    def fail(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")   # as a write() or fsync(): no file name

    monkeypatch.setattr(os, "fsync", fail)
    monkeypatch.setattr(os, "replace", fail)
    return "No space left on device"


def _refusing(code, text):
    def patch(monkeypatch):
        real_mkstemp, real_mkdtemp = tempfile.mkstemp, tempfile.mkdtemp

        def fail(suffix=None, prefix=None, dir=None, *a, **k):
            if dir is None:      # not an output: a scratch file of a library
                return (real_mkstemp if patch.kind == "file" else real_mkdtemp)(suffix, prefix, dir, *a, **k)
            raise OSError(code, text, os.path.join(dir, f"{prefix or ''}x1y2z3{suffix or ''}"))

        def mkstemp(*a, **k):
            patch.kind = "file"
            return fail(*a, **k)

        def mkdtemp(*a, **k):
            patch.kind = "dir"
            return fail(*a, **k)

        monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
        monkeypatch.setattr(tempfile, "mkdtemp", mkdtemp)
        return text
    return patch


@pytest.mark.parametrize("failure", [_full_disk, _refusing(errno.EACCES, "Permission denied"),
                                     _refusing(errno.EROFS, "Read-only file system")],
                         ids=["ENOSPC", "EACCES", "EROFS"])
@pytest.mark.parametrize("command", ["lidar dsm", "lidar dtm", "lidar ground", "lidar contours", "lidar sheets",
                                     "lidar raster", "extract", "ortho", "monoplot", "adjust", "assess", "export",
                                     "import", "run"])
def test_a_failing_write_is_one_error_line_and_loses_nothing(written, command, failure, monkeypatch):
    root, out, commands = written
    before = _tree(root)
    reason = failure(monkeypatch)
    r = CliRunner().invoke(cli, commands[command])
    monkeypatch.undo()
    assert r.exit_code == 2, (r.exit_code, r.output)
    assert "Traceback" not in r.output and "internal error" not in r.output
    line = [ln for ln in r.output.splitlines() if ln.startswith("Error: ")]
    assert len(line) == 1, r.output
    assert line[0].startswith(f"Error: {out}") and reason in line[0], line[0]
    assert ".part" not in line[0] and "x1y2z3" not in line[0]
    after = _tree(root)
    assert [k for k in after if ".part" in k] == []          # nothing half-written
    for log in [k for k in before if k.endswith("lidarcat.log")]:   # run's log records the failed run too
        assert after.pop(log).startswith(before.pop(log))
    assert after == before                                   # the earlier outputs intact


def test_os_error_line_names_the_output_not_its_temporary_sibling(tmp_path):
    from lidarcat.cli.main import os_error_line

    part = tmp_path / ".out.k3j2h1.part" / "sub" / ".dtm.tif.abc_123.part"
    assert os_error_line(OSError(errno.EACCES, "Permission denied", str(part))) == \
        f"{tmp_path / 'out' / 'sub' / 'dtm.tif'}: Permission denied"
    assert os_error_line(OSError(errno.ENOSPC, "No space left on device")) == "No space left on device"
    ex = OSError(errno.EXDEV, "Invalid cross-device link", str(tmp_path / "a"), None, str(tmp_path / "b"))
    assert os_error_line(ex) == (f"{tmp_path / 'a'}: Invalid cross-device link ({tmp_path / 'a'} -> "
                                 f"{tmp_path / 'b'})")

    def atomic_write(path):   # the name of lidarcat's writers: their ``path`` is the file named
        raise OSError(errno.ENOSPC, "No space left on device")

    try:
        atomic_write(tmp_path / "x.csv")
    except OSError as caught:
        assert os_error_line(caught) == f"{tmp_path / 'x.csv'}: No space left on device"
