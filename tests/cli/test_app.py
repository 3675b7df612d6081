"""The CLI as a user meets it: help everywhere, one-line errors, non-zero exits."""

from __future__ import annotations

from pathlib import Path

import click
import pytest
from click.testing import CliRunner

from catenary.cli import cli


def _all_command_paths() -> list[list[str]]:
    """Every subcommand path of ``catenary``, plugins' commands included."""
    paths: list[list[str]] = [[]]
    with click.Context(cli, info_name="catenary") as ctx:

        def walk(group: click.Group, ctx: click.Context, prefix: list[str]) -> None:
            for name in group.list_commands(ctx):
                command = group.get_command(ctx, name)
                assert command is not None, name
                paths.append([*prefix, name])
                if isinstance(command, click.Group):
                    with click.Context(command, info_name=name, parent=ctx) as sub:
                        walk(command, sub, [*prefix, name])

        walk(cli, ctx, [])
    return paths


@pytest.mark.parametrize("path", _all_command_paths(), ids=lambda p: " ".join(p) or "catenary")
def test_help_everywhere(path: list[str]) -> None:
    result = CliRunner().invoke(cli, [*path, "--help"])
    assert result.exit_code == 0, result.output
    assert "Usage:" in result.output


def test_plugins_lists_builtins_and_what_they_register() -> None:
    result = CliRunner().invoke(cli, ["plugins", "--strict"])
    assert result.exit_code == 0, result.output
    assert "wiretypes" in result.output
    assert "wire type:" in result.output


def test_bad_config_is_one_line_without_traceback(tmp_path: Path) -> None:
    config = tmp_path / "broken.toml"
    config.write_text("[database\n")
    result = CliRunner().invoke(cli, ["--config", str(config), "plugins"])
    assert result.exit_code == 1
    assert "broken.toml: invalid TOML" in result.output
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_unknown_command_is_a_usage_error() -> None:
    result = CliRunner().invoke(cli, ["frobnicate"])
    assert result.exit_code == 2
    assert "No such command" in result.output
