"""The output folder is a boundary (issue 24): a name from input data becomes a path only as one plain file
name (:func:`safe_component`), and no write, rename or delete leaves the output folder or goes through a
symbolic link in it (:func:`inside`, checked by every atomic writer and by the stage-folder cleaner).

The reproducers of the issue: a photo id ``x/../../pwn`` made ``lidarcat ortho`` write ``../pwn.tif`` next
to the output folder; a survey that ships ``out/<stage>`` as a link made ``lidarcat run`` delete every file
in the link's target (also ``OUT/<stage>`` with ``-o OUT``).  The hostile-survey tests snapshot the whole
``tmp_path`` tree (names, sizes, mtimes, contents, link targets) before and after and assert that nothing
outside the output folder changed.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import assert_one_line_error
from lidarcat._util import atomic_dir, atomic_write, inside, output_root, remove_below, safe_component, \
    write_text_atomic
from lidarcat.cli.main import cli
from lidarcat.errors import ProductError, SurveyError
from lidarcat.pipeline.runner import Stage, run_stages

HOSTILE_ID = "x/../../pwn"


# --------------------------------------------------------------------------- the tree around a run

def snapshot(top: Path, exclude: Path | None = None) -> dict[str, tuple]:
    """Every entry under *top* (links not followed): kind, size, mtime, content hash, link target.

    Folder mtimes are left out (creating the output folder changes its parent's), entries below *exclude*
    (the output folder) too; the links *in* the output folder are kept (they must not be followed, and they
    point outside).
    """
    out: dict[str, tuple] = {}
    ex = os.path.abspath(exclude) if exclude is not None else None
    for dirpath, dirnames, filenames in os.walk(top, followlinks=False):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            st = os.lstat(p)
            rel = os.path.relpath(p, top)
            if os.path.islink(p):
                out[rel] = ("link", os.readlink(p))
            elif ex is not None and (os.path.abspath(p) == ex or os.path.abspath(p).startswith(ex + os.sep)):
                continue
            elif os.path.isdir(p):
                out[rel] = ("dir",)
            else:
                with open(p, "rb") as fh:
                    out[rel] = ("file", st.st_size, st.st_mtime_ns, hashlib.sha256(fh.read()).hexdigest())
        dirnames[:] = [d for d in dirnames if not os.path.islink(os.path.join(dirpath, d))
                       and not (ex is not None and os.path.abspath(os.path.join(dirpath, d)) == ex)]
    return out


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory) -> Path:
    from lidarcat.synthetic import write_synthetic_survey

    root = tmp_path_factory.mktemp("boundary") / "survey"
    write_synthetic_survey(root, n_photos=2, lidar_density_m2=0.5)
    return root


def copy_survey(src: Path, dst: Path, hostile_ids: bool = False) -> Path:
    import shutil

    shutil.copytree(src, dst)
    if hostile_ids:  # photo 1 becomes x/../../pwn everywhere it is named
        for name in ("photos.csv", "image_points.csv", "truth/eop.csv"):
            p = dst / name
            lines = p.read_text().splitlines(keepends=True)
            p.write_text("".join(f"{HOSTILE_ID}," + ln[2:] if ln.startswith("1,") else ln for ln in lines))
    return dst


def sibling_with_files(tmp_path: Path) -> Path:
    sib = tmp_path / "sibling"
    sib.mkdir()
    (sib / "precious.txt").write_text("keep me\n")
    (sib / "eop.csv").write_text("photo,X0\n")
    (sib / "sub").mkdir()
    (sib / "sub" / "deep.txt").write_text("keep me too\n")
    return sib


# --------------------------------------------------------------------------- safe_component

@pytest.mark.parametrize("name, why", [
    (HOSTILE_ID, "it holds '/'"), ("..", "it is '..'"), (".", "it is '.'"), ("", "it is empty"),
    ("a\\b", "it holds '\\\\'"), ("a\x00b", "it holds '\\x00'"), ("a\nb", "it holds '\\n'"),
    (".stages", "it starts with '.'"), ("/etc/passwd", "it holds '/'"), ("é" * 81, "longer than 160 bytes"),
])
def test_safe_component_refuses_what_is_not_one_plain_name(name, why):
    with pytest.raises(SurveyError) as ex:
        safe_component(name, "photo id", "photos.csv")
    msg = str(ex.value)
    assert msg.startswith("photos.csv: photo id ") and why in msg, msg
    assert len(msg) < 200  # a short, escaped excerpt, never the whole input


@pytest.mark.parametrize("name", ["1", "IMG_0042", "foto 3", "faixa-2.foto-7", "Praça", "a..b", "e" * 160])
def test_safe_component_passes_plain_names_unchanged(name):
    assert safe_component(name, "photo id") == name


# --------------------------------------------------------------------------- inside / the writers

def test_inside_refuses_a_path_outside_and_a_link_on_the_way(tmp_path):
    out, sib = tmp_path / "out", sibling_with_files(tmp_path)
    out.mkdir()
    assert inside(out, out / "a" / "b.tif") == out / "a" / "b.tif"
    with pytest.raises(ProductError, match=r"outside the output folder"):
        inside(out, out / "ortho_x" / ".." / ".." / "pwn.tif")
    (out / "stage").symlink_to(sib, target_is_directory=True)
    for p in (out / "stage", out / "stage" / "precious.txt", out / "stage" / "new" / "f.txt"):
        with pytest.raises(ProductError, match=r"out/stage: a symbolic link in the output folder .* \(to "):
            inside(out, p)
    link_root = tmp_path / "via-link"
    link_root.symlink_to(out, target_is_directory=True)
    assert inside(link_root, link_root / "f.txt")  # the root itself may be a link: the user chose it


def test_the_atomic_writers_stay_inside_the_output_root(tmp_path):
    out, sib = tmp_path / "out", sibling_with_files(tmp_path)
    out.mkdir()
    (out / "stage").symlink_to(sib, target_is_directory=True)
    (out / "eop.csv").symlink_to(sib / "eop.csv")
    before = snapshot(tmp_path, exclude=out)
    with output_root(out):
        with pytest.raises(ProductError, match="outside the output folder"):
            write_text_atomic(out / "ortho_x/../../pwn.tif", "pwn")
        with pytest.raises(ProductError, match="a symbolic link"):
            write_text_atomic(out / "stage" / "precious.txt", "overwritten")
        with pytest.raises(ProductError, match="a symbolic link"):
            with atomic_write(out / "eop.csv") as fh:
                fh.write("overwritten")
        with pytest.raises(ProductError, match="a symbolic link"):
            with atomic_dir(out / "stage") as tmp:
                (tmp / "new.txt").write_text("x")
        with pytest.raises(ProductError, match="a symbolic link"):
            remove_below(out / "stage")
        write_text_atomic(out / "fine" / "f.txt", "ok")  # an ordinary write still works
    assert (out / "fine" / "f.txt").read_text() == "ok"
    assert snapshot(tmp_path, exclude=out) == before
    assert not (tmp_path / "pwn.tif").exists()


def test_remove_below_removes_links_as_names_never_their_targets(tmp_path):
    out, sib = tmp_path / "out", sibling_with_files(tmp_path)
    (out / "stage" / "d").mkdir(parents=True)
    (out / "stage" / "old.txt").write_text("old")
    (out / "stage" / "new.txt").write_text("new")
    (out / "stage" / "d" / "to-dir").symlink_to(sib, target_is_directory=True)
    (out / "stage" / "to-file").symlink_to(sib / "precious.txt")
    before = snapshot(tmp_path, exclude=out)
    with output_root(out):
        remove_below(out / "stage", keep={"new.txt"})
    assert sorted(p.name for p in (out / "stage").iterdir()) == ["new.txt"]
    after = snapshot(tmp_path, exclude=out)
    assert after == before


def test_the_stage_runner_refuses_a_stage_folder_that_is_a_link(tmp_path):
    out, sib = tmp_path / "out", sibling_with_files(tmp_path)
    out.mkdir()
    (out / "stage").symlink_to(sib, target_is_directory=True)
    before = snapshot(tmp_path, exclude=out)

    def run(ctx, tmp):
        (tmp / "result.txt").write_text("r")
        return {}

    with pytest.raises(ProductError, match=r"out/stage: a symbolic link in the output folder"):
        run_stages([Stage("s", "stage", run)], out)
    (out / ".stages").symlink_to(sib, target_is_directory=True)
    with pytest.raises(ProductError, match=r"out/\.stages: a symbolic link in the output folder"):
        run_stages([Stage("t", "other", run)], out)
    assert snapshot(tmp_path, exclude=out) == before


# --------------------------------------------------------------------------- the reproducers of the issue

def test_ortho_refuses_a_path_like_photo_id_and_writes_nothing(tmp_path, synthetic):
    survey = copy_survey(synthetic, tmp_path / "survey", hostile_ids=True)
    (tmp_path / "dtm.tif").write_bytes(b"")  # never read: the id is refused first
    before = snapshot(tmp_path)
    res = CliRunner().invoke(cli, ["ortho", str(survey), "--photo", HOSTILE_ID, "--dtm", str(tmp_path / "dtm.tif"),
                                   "--eop", str(survey / "truth" / "eop.csv"), "-o", str(tmp_path / "out")])
    assert_one_line_error(res, repr(HOSTILE_ID))
    assert "photo" in res.output
    after = snapshot(tmp_path, exclude=tmp_path / "out")
    assert after == before and not (tmp_path / "pwn.tif").exists()
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*"))


def test_ortho_all_refuses_the_hostile_id_too(tmp_path, synthetic):
    survey = copy_survey(synthetic, tmp_path / "survey", hostile_ids=True)
    (tmp_path / "dtm.tif").write_bytes(b"")
    before = snapshot(tmp_path)
    res = CliRunner().invoke(cli, ["ortho", str(survey), "--all", "--dtm", str(tmp_path / "dtm.tif"),
                                   "--eop", str(survey / "truth" / "eop.csv"), "-o", str(tmp_path / "out")])
    assert_one_line_error(res, repr(HOSTILE_ID))
    assert snapshot(tmp_path, exclude=tmp_path / "out") == before


@pytest.mark.parametrize("with_o", [False, True], ids=["SURVEY-out", "-o OUT"])
def test_run_refuses_a_stage_folder_shipped_as_a_link(tmp_path, synthetic, with_o):
    survey = copy_survey(synthetic, tmp_path / "survey")
    sib = sibling_with_files(tmp_path)
    out = tmp_path / "OUT" if with_o else survey / "out"
    out.mkdir()
    (out / "adjust-gps").symlink_to(os.path.relpath(sib, out), target_is_directory=True)
    before = snapshot(tmp_path, exclude=out)
    res = CliRunner().invoke(cli, ["run", str(survey), *(["-o", str(out)] if with_o else [])])
    assert_one_line_error(res, "adjust-gps: a symbolic link in the output folder", "remove it")
    assert snapshot(tmp_path, exclude=out) == before
    assert sorted(p.name for p in sib.rglob("*")) == ["deep.txt", "eop.csv", "precious.txt", "sub"]


def test_run_refuses_a_survey_whose_out_folder_is_a_link(tmp_path, synthetic):
    survey = copy_survey(synthetic, tmp_path / "survey")
    sib = sibling_with_files(tmp_path)
    (survey / "out").symlink_to(os.path.relpath(sib, survey), target_is_directory=True)
    before = snapshot(tmp_path)
    res = CliRunner().invoke(cli, ["run", str(survey)])
    assert_one_line_error(res, "out: a symbolic link in the output folder")
    assert snapshot(tmp_path) == before


def test_run_refuses_a_log_file_shipped_as_a_link(tmp_path, synthetic):
    survey = copy_survey(synthetic, tmp_path / "survey")
    sib = sibling_with_files(tmp_path)
    (survey / "out").mkdir()
    (survey / "out" / "lidarcat.log").symlink_to(sib / "precious.txt")
    before = snapshot(tmp_path, exclude=survey / "out")
    res = CliRunner().invoke(cli, ["run", str(survey)])
    assert_one_line_error(res, "lidarcat.log: a symbolic link in the output folder")
    assert snapshot(tmp_path, exclude=survey / "out") == before


def test_a_hostile_survey_changes_nothing_outside_its_output_folder(tmp_path, synthetic):
    """Path-like photo ids, and links in out/ to a sibling folder with files: ``run`` then ``ortho``."""
    survey = copy_survey(synthetic, tmp_path / "survey", hostile_ids=True)
    sib = sibling_with_files(tmp_path)
    out = survey / "out"
    out.mkdir()
    for stage in ("adjust-gps", "mapping", "report", ".stages"):
        (out / stage).symlink_to(os.path.relpath(sib, out), target_is_directory=True)
    (out / "summary.json").symlink_to(os.path.relpath(sib / "eop.csv", out))
    (tmp_path / "dtm.tif").write_bytes(b"")
    before = snapshot(tmp_path, exclude=out)
    runner = CliRunner()
    res = runner.invoke(cli, ["run", str(survey)])
    assert res.exit_code == 2 and "Traceback" not in res.output, res.output
    res = runner.invoke(cli, ["ortho", str(survey), "--all", "--dtm", str(tmp_path / "dtm.tif"), "--eop",
                              str(survey / "truth" / "eop.csv"), "-o", str(out / "ortho")])
    assert_one_line_error(res, repr(HOSTILE_ID))
    assert snapshot(tmp_path, exclude=out) == before
    assert not (tmp_path / "pwn.tif").exists() and not (survey / "pwn.tif").exists()


def test_run_with_a_path_like_photo_id_keeps_every_write_inside(tmp_path, synthetic):
    """No links: the stages run; whatever refuses the id (the survey reader or the mapping stage), nothing
    is written outside the output folder and no output file is named after the hostile id."""
    survey = copy_survey(synthetic, tmp_path / "survey", hostile_ids=True)
    out = tmp_path / "OUT"
    before = snapshot(tmp_path)
    res = CliRunner().invoke(cli, ["run", str(survey), "-o", str(out)])
    assert "Traceback" not in res.output, res.output
    assert snapshot(tmp_path, exclude=out) == before
    assert not any("pwn" in p.name for p in tmp_path.rglob("*") if out not in p.parents and p != out)


def test_the_mapping_stage_of_run_refuses_a_path_like_photo_id(tmp_path):
    """The reproducer of ``run``: with [mapping] orthophotos the stage wrote ``tmp/ortho_x/../../pwn.tif``,
    i.e. ``OUT/pwn.tif`` beside the stage folders (one more ``../`` and it leaves OUT)."""
    import json

    from lidarcat.synthetic import write_synthetic_survey

    survey = tmp_path / "survey"
    write_synthetic_survey(survey, n_photos=2, lidar_density_m2=0.5, images=True, image_downsample=20)
    for name in ("photos.csv", "image_points.csv"):
        p = survey / name
        # the photo's image cell emptied: the hostile id then names its file by the images/<photo> rule
        p.write_text("".join(f"{HOSTILE_ID}," + ln[2:].replace(",images/1.png", ",") if ln.startswith("1,") else ln
                             for ln in p.read_text().splitlines(keepends=True)))
    (survey / "images" / "x").mkdir()  # so that images/x/../../pwn.png is found: the old code read it
    os.replace(survey / "images" / "1.png", survey / "pwn.png")
    with open(survey / "survey.toml", "a", encoding="utf-8") as f:
        f.write("\n[mapping]\northophotos = true\ngsd_m = 2.0\ncell_m = 2.0\n")
    out = tmp_path / "OUT"
    before = snapshot(tmp_path)
    res = CliRunner().invoke(cli, ["run", str(survey), "-o", str(out)])
    assert "Traceback" not in res.output, res.output
    assert snapshot(tmp_path, exclude=out) == before
    assert not [p for p in out.rglob("*") if "pwn" in p.name]
    summary = json.loads((out / "summary.json").read_text())
    mapping = next(s for s in summary["stages"] if s["name"] == "mapping")
    assert mapping["status"] == "failed"
    assert mapping["reason"] == (f"{survey / 'photos.csv'}: photo id {HOSTILE_ID!r} cannot name an output file: "
                                 f"it holds '/'; use letters, digits, '_', '-', '.' (not first)")


def test_run_refuses_a_lock_file_shipped_as_a_link(tmp_path, synthetic):
    survey = copy_survey(synthetic, tmp_path / "survey")
    sib = sibling_with_files(tmp_path)
    (sib / "lock").write_text(f"pid={os.getpid()} host=elsewhere SECRET=do-not-print\n")
    (survey / "out").mkdir()
    (survey / "out" / ".lidarcat.lock").symlink_to(sib / "lock")
    before = snapshot(tmp_path, exclude=survey / "out")
    res = CliRunner().invoke(cli, ["run", str(survey)])
    assert_one_line_error(res, ".lidarcat.lock: a symbolic link in the output folder")
    assert "SECRET" not in res.output
    assert snapshot(tmp_path, exclude=survey / "out") == before
    assert (survey / "out" / ".lidarcat.lock").is_symlink()


def test_a_stage_record_naming_files_outside_is_not_trusted(tmp_path):
    """A record in out/.stages (shipped with a survey) whose outputs lie outside: the stage runs again."""
    import json

    from lidarcat.pipeline import runner

    out, sib = tmp_path / "out", sibling_with_files(tmp_path)
    calls = []

    def run(ctx, tmp):
        calls.append(1)
        (tmp / "r.txt").write_text("r")
        return {}

    stage = Stage("s", "stage", run)
    run_stages([stage], out)
    rec_path = out / ".stages" / "s.json"
    rec = json.loads(rec_path.read_text())
    rel = os.path.relpath(sib / "precious.txt", out)
    rec["output_digests"] = {rel: runner._file_digest_uncached(sib / "precious.txt")}
    rec_path.write_text(json.dumps(rec))
    before = snapshot(tmp_path, exclude=out)
    assert [r.status for r in run_stages([stage], out)] == ["ran"] and len(calls) == 2
    assert snapshot(tmp_path, exclude=out) == before
