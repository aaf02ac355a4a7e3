"""The repository holds no file named like a command-line option (issue 16: a tracked '--help')."""

from __future__ import annotations

import shutil
import subprocess

import pytest
from conftest import ROOT, _named_like_an_option


def test_no_tracked_file_is_named_like_an_option():
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    files = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    bad = [f for f in files.decode().split("\0") if f and any(part.startswith("-") for part in f.split("/"))]
    assert bad == []


def test_the_session_check_finds_a_file_named_like_an_option(tmp_path):
    (tmp_path / "--help").write_text("usage")
    (tmp_path / "ok.txt").write_text("")
    assert _named_like_an_option(tmp_path) == ["--help"]
