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
    result = CliRunner().invoke(cli, ["adjust", str(tmp_path)])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
