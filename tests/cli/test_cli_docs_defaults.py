"""Issue 25: docs/cli.md shows no click sentinel as a default."""

from __future__ import annotations

from lidarcat.cli.docs import render_cli_reference


def test_reference_shows_no_unset_sentinel_and_keeps_real_defaults():
    text = render_cli_reference()
    assert "UNSET" not in text and "Sentinel" not in text
    assert "| `-o`, `--output` |  |" in text        # required or optional without default: blank
    assert "| `--cell-m` | `1.0` |" in text
