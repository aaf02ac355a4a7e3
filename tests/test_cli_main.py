from click.testing import CliRunner

from lidarcat.cli.main import COMMANDS, cli


def test_help_lists_commands_in_pipeline_order():
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0, result.output
    positions = [result.output.index(f"  {name} ") for name, _, _ in COMMANDS]
    assert positions == sorted(positions)
    for _, _, summary in COMMANDS:
        assert summary in result.output


def test_library_error_is_one_line_exit_2(tmp_path):
    # a folder without survey.toml: SurveyError from the library -> one line, exit code 2
    result = CliRunner().invoke(cli, ["adjust", str(tmp_path), "-o", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("Error: ") and "survey.toml" in lines[0]
    assert not (tmp_path / "out").exists()
