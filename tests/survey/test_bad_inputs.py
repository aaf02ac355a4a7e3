"""The last bad inputs of the survey reader (issue 24): each reproducer ends in one located
``Error:`` line (exit 2), never a traceback, and no error echoes a file beyond a short escaped excerpt.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from click.testing import CliRunner

from conftest import THESIS_SURVEY, assert_one_line_error
from lidarcat._util import TOML_MAX_BYTES, TOML_MAX_DEPTH, excerpt, read_csv_table, read_toml
from lidarcat.cli.main import cli
from lidarcat.errors import SurveyError
from lidarcat.survey.folder import Survey


def _copy(tmp_path: Path) -> Path:
    dest = tmp_path / "survey"
    shutil.copytree(THESIS_SURVEY, dest, ignore=shutil.ignore_patterns("out", "published"))
    return dest


def _edit(folder: Path, name: str, old: str, new: str) -> str:
    p = folder / name
    text = p.read_text(encoding="utf-8")
    assert old in text
    text = text.replace(old, new, 1)
    p.write_text(text, encoding="utf-8")
    return text


def _lines(path: Path) -> int:
    return len(path.read_text(encoding="utf-8").splitlines())


# ---------------------------------------------------------------------- nested TOML
@pytest.mark.parametrize("name, value", [
    ("survey.toml", "[" * 5000 + "]" * 5000),            # the reproducer: RecursionError in tomllib
    ("camera.toml", "{a=" * 5000 + "1" + "}" * 5000),
])
def test_deeply_nested_toml_is_a_located_error(tmp_path, name, value):
    folder = _copy(tmp_path)
    path = folder / name
    path.write_text(path.read_text(encoding="utf-8") + f"\nx = {value}\n", encoding="utf-8")
    line = _lines(path)
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(out)])
    assert_one_line_error(r, f"{path}:{line}: arrays or inline tables nested more than {TOML_MAX_DEPTH} deep")
    assert not out.exists()


def test_toml_depth_limit_counts_brackets_outside_strings_and_comments(tmp_path):
    p = tmp_path / "a.toml"
    ok = "[" * TOML_MAX_DEPTH + "]" * TOML_MAX_DEPTH
    p.write_text(f'# {"[" * 100}\ns = "{"[" * 100}"\nm = """\n{"{" * 100}\n"""\nl = \'{"[" * 100}\'\n'
                 f"x = {ok}\n[t]\n[[u]]\n", encoding="utf-8")
    data, _ = read_toml(p)
    assert data["s"] == "[" * 100 and "u" in data
    p.write_text(f"\n\nx = [{ok}]\n", encoding="utf-8")
    with pytest.raises(SurveyError, match=rf"a.toml:3: arrays or inline tables nested more than {TOML_MAX_DEPTH} deep"):
        read_toml(p)


def test_toml_size_limit_and_not_a_regular_file(tmp_path):
    p = tmp_path / "big.toml"
    p.write_text("# padding\n" * (TOML_MAX_BYTES // 10 + 1), encoding="utf-8")
    with pytest.raises(SurveyError, match=r"big.toml: 1,000,010 bytes is too large for a TOML settings file "
                                          r"\(at most 1,000,000\)$"):
        read_toml(p)
    fifo = tmp_path / "camera.toml"
    os.mkfifo(fifo)  # reading it would block for ever
    with pytest.raises(SurveyError, match=r"camera.toml: not a regular file \(a pipe or a device\)"):
        read_toml(fifo)


# ---------------------------------------------------------------------- file contents in messages
@pytest.mark.skipif(not Path("/proc/self/environ").is_file(), reason="needs Linux /proc")
def test_proc_environ_as_a_table_does_not_print_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("LIDARCAT_TEST_SECRET", "hunter2")
    folder = _copy(tmp_path)
    _edit(folder, "survey.toml", 'photos = "photos.csv"', 'photos = "/proc/self/environ"')
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(tmp_path / "out")])
    assert_one_line_error(r, "/proc/self/environ:1: a NUL byte: this is not a CSV text file")
    assert "hunter2" not in r.output and "LIDARCAT_TEST_SECRET" not in r.output and "PATH=" not in r.output


def test_a_long_or_binary_header_is_quoted_as_a_short_escaped_excerpt(tmp_path):
    folder = _copy(tmp_path)
    secret = "\x1b]0;owned\x07" + "TOKEN=s3cr3t;" * 1000  # a terminal escape, then a long line
    (folder / "photos.csv").write_text(secret + "\n1\n", encoding="utf-8")
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(tmp_path / "out")])
    assert_one_line_error(r, f"{folder / 'photos.csv'}:1: missing column 'photo' (header is \\x1b]0;owned\\x07TOKEN=")
    assert "\x1b" not in r.output and "\x07" not in r.output
    assert f"... ({len(secret)} characters))" in r.output
    assert r.output.count("s3cr3t") <= 5 and len(r.output) < 300


def test_cells_and_ids_are_quoted_as_excerpts(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("point,E\n" + "x" * 500 + ",1e\x015\n", encoding="utf-8")
    with pytest.raises(SurveyError) as ei:
        read_csv_table(p, ("point", "E")).floats("E")
    assert str(ei.value) == f"{p}:2: field 'E': '1e\\x015' is not a number"
    folder = _copy(tmp_path)
    text = (folder / "control_sets.csv").read_text(encoding="utf-8")
    long_id = "P" * 1000
    (folder / "control_sets.csv").write_text(text.replace(",601,", f",{long_id},", 1), encoding="utf-8")
    with pytest.raises(SurveyError, match=r"point 'P{60}'\.\.\. \(1000 characters\) is defined nowhere") as ei:
        Survey.load(folder)
    assert len(str(ei.value)) < 300


def test_excerpt():
    assert excerpt("701") == "'701'"
    assert excerpt("a\x00b\nc\u200bd") == "'a\\x00b\\nc\\u200bd'"  # a zero-width space is escaped too
    assert excerpt("it's") == "'it\\'s'"
    assert excerpt("é" * 61) == "'" + "é" * 60 + "'... (61 characters)"
    assert excerpt(1e308) == "1e+308" and excerpt(["a"]) == "['a']"


def test_long_toml_keys_and_values_are_cut(tmp_path):
    folder = _copy(tmp_path)
    _edit(folder, "survey.toml", "[adjustment]\n", "[adjustment]\n" + "k" * 5000 + " = 1\n")
    with pytest.raises(SurveyError, match=r"field 'k{60}\.\.\.': unknown key 'k{60}'\.\.\. \(5000 characters\) "
                                          r"in \[adjustment\]") as ei:
        Survey.load(folder)
    assert len(str(ei.value)) < 500
    folder = _copy(tmp_path / "b")
    _edit(folder, "survey.toml", 'observations = "corrected"', 'observations = "' + "c" * 5000 + '"')
    with pytest.raises(SurveyError, match=r"field 'observations': 'c{60}'\.\.\. \(5000 characters\) is not one of"):
        Survey.load(folder)


# ---------------------------------------------------------------------- file names
def test_a_300_character_file_name_names_the_key(tmp_path):
    folder = _copy(tmp_path)
    name = "p" * 300 + ".csv"
    text = _edit(folder, "survey.toml", 'photos = "photos.csv"', f'photos = "{name}"')
    line = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("photos ="))
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["adjust", str(folder), "-o", str(out)])
    assert_one_line_error(r, f"{folder / 'survey.toml'}:{line}: field 'photos': file '{'p' * 60}'... "
                             f"(304 characters) cannot be used: File name too long")
    assert not out.exists()


def test_a_300_character_lidar_file_name_names_the_key(tmp_path):
    folder = _copy(tmp_path)
    _edit(folder, "survey.toml", 'control_sets = "control_sets.csv"',
          'control_sets = "control_sets.csv"\nlidar = ["' + "t" * 300 + '.laz"]')
    with pytest.raises(SurveyError, match=r"field 'lidar': file 't{60}'\.\.\. \(304 characters\) cannot be used: "
                                          r"File name too long$"):
        Survey.load(folder)
