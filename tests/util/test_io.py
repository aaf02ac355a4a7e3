"""lidarcat._util: atomic output, located reading, JSON."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from lidarcat._util import (
    atomic_dir,
    atomic_write,
    dumps_json,
    folder_lock,
    read_csv_table,
    read_toml,
    write_csv_atomic,
)
from lidarcat.errors import LidarcatError, SurveyError


class Boom(Exception):
    pass


# ------------------------------------------------------------------ atomic output
def test_atomic_write_failure_keeps_the_old_file(tmp_path):
    target = tmp_path / "a.csv"
    target.write_text("old\n", encoding="utf-8")
    with pytest.raises(Boom):
        with atomic_write(target) as fh:
            fh.write("half of the new")
            raise Boom
    assert target.read_text(encoding="utf-8") == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv"]  # no .part left
    with atomic_write(target) as fh:
        fh.write("new\n")
    assert target.read_text(encoding="utf-8") == "new\n"
    assert oct(target.stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_atomic_dir_all_or_nothing(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine", encoding="utf-8")
    (out / "a.txt").write_text("old a", encoding="utf-8")
    with pytest.raises(Boom):
        with atomic_dir(out) as tmp:
            (tmp / "a.txt").write_text("new a", encoding="utf-8")
            raise Boom
    assert (out / "a.txt").read_text(encoding="utf-8") == "old a"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the temporary sibling is gone
    with atomic_dir(out) as tmp:
        (tmp / "a.txt").write_text("new a", encoding="utf-8")
        (tmp / "sub").mkdir()
        (tmp / "sub" / "b.txt").write_text("b", encoding="utf-8")
    assert (out / "a.txt").read_text(encoding="utf-8") == "new a"
    assert (out / "sub" / "b.txt").read_text(encoding="utf-8") == "b"
    assert (out / "keep.txt").read_text(encoding="utf-8") == "mine"  # files it does not write stay


def test_folder_lock_refuses_a_second_run_and_is_removed(tmp_path):
    with folder_lock(tmp_path) as lock:
        assert lock.read_text().startswith(f"pid={os.getpid()} ")
        with pytest.raises(LidarcatError, match=rf"in use by another lidarcat run \(pid {os.getpid()} "):
            with folder_lock(tmp_path):
                pass
    assert not lock.exists()


# ------------------------------------------------------------------ CSV
def test_csv_round_trip_is_bit_identical(tmp_path):
    rng = np.random.default_rng(3)
    x = rng.normal(size=50) * 10.0 ** rng.integers(-12, 12, 50)
    p = write_csv_atomic(tmp_path / "x.csv", ["id", "x"], [[f"p{i}", v] for i, v in enumerate(x)]
                         + [["nan", math.nan]], comments=["a comment", "another"])
    text = p.read_text(encoding="utf-8")
    assert text.startswith("id,x\n") and text.endswith("nan,\n")
    t = read_csv_table(p, required=("id", "x"))
    assert t.lines[0] == 2  # line numbers as an editor shows them (header = line 1)
    back = t.floats("x", required=False)
    np.testing.assert_array_equal(back[:-1], x)  # repr floats: no digit lost
    assert np.isnan(back[-1])


@pytest.mark.parametrize("text, message", [
    ("a,b\n1,2,3\n", r"x.csv:2: 3 fields, expected 2 \(a, b\)$"),
    ("a,b,a\n1,2,3\n", r"x.csv:1: duplicate column\(s\) a$"),
    ("# c\na,b,\n1,2,\n", r"x.csv:2: column 3 has no name \(a trailing comma\?\); name it or delete it$"),
    ("a\n1\n", r"x.csv:1: missing column 'b' \(header is a\)$"),
    ("a,b,c\n1,2,3\n", r"x.csv:1: unknown column\(s\) c; allowed: a, b$"),
    ("# only a comment\n", r"x.csv: empty file, expected a header line$"),
])
def test_read_csv_table_errors(tmp_path, text, message):
    p = tmp_path / "x.csv"
    p.write_text(text, encoding="utf-8")
    with pytest.raises(SurveyError, match=message):
        read_csv_table(p, required=("a", "b"))


def test_read_csv_table_bom_and_extra_columns(tmp_path):
    p = tmp_path / "x.csv"
    p.write_bytes("\ufeffa, b ,c,\n 1 ,2,3,\n".encode("utf-8"))  # a spreadsheet's BOM and padding
    t = read_csv_table(p, required=("a", "b"), allow_extra=True)
    assert t.header == ("a", "b", "c", "") and t.rows == (("1", "2", "3", ""),)
    with pytest.raises(SurveyError, match=r"x.csv:2: field 'b': '2x' is not a number$"):
        p.write_text("a,b\n1,2x\n", encoding="utf-8")
        read_csv_table(p, required=("a", "b")).floats("b")


# ------------------------------------------------------------------ TOML, JSON
def test_read_toml_invalid_names_the_line(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text("[a]\nx = 1\ny = = 2\n", encoding="utf-8")
    with pytest.raises(SurveyError, match=r"s.toml:3: invalid TOML"):
        read_toml(p)
    p.write_text("[a]\nx = 1\n", encoding="utf-8")
    assert read_toml(p) == ({"a": {"x": 1}}, "[a]\nx = 1\n")


def test_dumps_json_is_valid_json_without_nan():
    doc = {"b": np.float64(math.nan), "a": np.arange(3), "c": [math.inf, np.int64(4)]}
    text = dumps_json(doc, indent=None)
    assert text == '{"a": [0, 1, 2], "b": null, "c": [null, 4]}'
    assert json.loads(text)["c"] == [None, 4]


def test_csv_header_is_the_first_line_and_notes_go_to_a_sidecar(tmp_path):
    import pandas as pd

    from lidarcat._util import csv_sidecar_path

    path = tmp_path / "eop.csv"
    write_csv_atomic(path, ["photo", "X0"], [["1", 1.5], ["2", 2.5]], comments=["X0 in metres"])
    assert path.read_text().splitlines()[0] == "photo,X0"
    df = pd.read_csv(path)  # default arguments: the first line is the header
    assert list(df.columns) == ["photo", "X0"] and df["X0"].tolist() == [1.5, 2.5]
    side = json.loads(csv_sidecar_path(path).read_text())
    assert side["file"] == "eop.csv" and side["notes"] == ["X0 in metres"]
    # rewritten without notes: the stale sidecar goes
    write_csv_atomic(path, ["photo", "X0"], [["1", 1.5]])
    assert not csv_sidecar_path(path).exists()


def test_old_csv_files_with_comment_lines_still_read(tmp_path):
    path = tmp_path / "old.csv"
    path.write_text("# written by lidarcat 0.1\n# X0 in metres\nphoto,X0\n1,1.5\n")
    table = read_csv_table(path, required=["photo", "X0"])
    assert table.column("X0") == ["1.5"]


def test_cli_docs_generator_prints_help_instead_of_writing_a_file(tmp_path, monkeypatch, capsys):
    from lidarcat.cli import docs

    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        docs.main(["--help"])
    assert exc.value.code == 0
    assert "Regenerate the Markdown reference" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []
