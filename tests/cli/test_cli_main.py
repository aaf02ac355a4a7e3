from click.testing import CliRunner

from lidarcat.cli.main import COMMANDS, cli


def test_help_lists_commands_in_pipeline_order():
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0, result.output
    positions = [result.output.index(f"  {name} ") for name, _, _ in COMMANDS]
    assert positions == sorted(positions)
    flat = " ".join(result.output.split())          # summaries wrap at the terminal width
    for _, _, summary in COMMANDS:
        assert summary in flat


def test_library_error_is_one_line_exit_2(tmp_path):
    # a folder without survey.toml: SurveyError from the library -> one line, exit code 2
    result = CliRunner().invoke(cli, ["adjust", str(tmp_path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("Error: ") and "survey.toml" in lines[0]
    assert not (tmp_path / "out").exists()


def test_unavailable_stage_reports_the_import_error(monkeypatch):
    import lidarcat.cli.main as m

    monkeypatch.setattr(m.cli, "_lazy", {**m.cli._lazy, "demo": ("lidarcat.cli.no_such_module:demo", "x")})
    result = CliRunner().invoke(m.cli, ["demo"])
    assert result.exit_code == 1
    assert "Error: 'demo' is not available: No module named 'lidarcat.cli.no_such_module'" in result.output


def test_command_summaries_match_the_lazy_table():
    """``lidarcat --help`` shows COMMANDS' summaries without importing the stages; the
    one-liners the commands declare themselves (``short_help``) must say the same."""
    import importlib

    import click

    for name, target, summary in COMMANDS:
        modname, attr = target.split(":")
        cmd = getattr(importlib.import_module(modname), attr)
        assert cmd.short_help in (None, summary), name
        assert cli.get_command(click.Context(cli), name).short_help == summary
