"""Issue 25: ``adjust`` and ``run`` give the same exit code for the same block.

Decision: exit 3 means the global chi-square test rejected; blunders that data
snooping (report mode) finds but keeps are named on the last line and, alone,
exit 0 -- in both commands.  The quick-start block (the embedded thesis block)
passes its global test and keeps one blunder (photo 3, point 407).
"""

from __future__ import annotations

import pytest
from click.testing import CliRunner

from lidarcat.cli.adjust import exit_status
from lidarcat.cli.main import cli


def test_exit_status_is_three_for_the_global_test_only():
    kept = {"converged": True, "chi2_pass": True, "snooping": {"blunders_remain": True},
            "blunders": [{"removed": False}, {"removed": True}]}
    assert exit_status(kept) == (0, "1 blunder(s) remain in the adjustment")
    assert exit_status({**kept, "chi2_pass": False}) == (
        3, "the global chi-square test of the variance factor REJECTED; 1 blunder(s) remain in the adjustment")
    assert exit_status({"converged": True, "chi2_pass": True}) == (0, "")
    assert exit_status({"converged": False, "status": "max_iter"})[0] == 1


@pytest.mark.slow
def test_thesis_block_adjust_and_run_exit_alike(tmp_path):
    r_adj = CliRunner().invoke(cli, ["adjust", "-o", str(tmp_path / "adj")])
    assert r_adj.exit_code == 0, r_adj.output
    assert "photo 3 point 407" in r_adj.output and "KEPT" in r_adj.output
    assert r_adj.output.endswith("Warning: 1 blunder(s) remain in the adjustment.\n")
    r_run = CliRunner().invoke(cli, ["run", "-o", str(tmp_path / "run")])
    assert r_run.exit_code == r_adj.exit_code == 0, r_run.output
    assert "blunder(s) remain (w-test)" in r_run.output
