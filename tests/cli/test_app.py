"""The CLI as a user meets it: help everywhere, one-line errors, non-zero exits."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click
import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.errors import UserError
from catenary.plugins import (
    Command,
    CommandContext,
    PluginFailure,
    PluginRegistry,
    hookimpl,
    pass_command_context,
)
from catenary.plugins.manager import plugin_errors


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


DATABASE_COMMANDS = [
    "process", "export", "compare", "report", "scheduler", "demo",
    "alerts evaluate", "alerts list", "alerts ack", "alerts resolve", "maintenance record",
    "db upgrade", "db downgrade", "db current", "db check", "notify deliver", "notify status",
]  # fmt: skip
"""The commands that touch the database."""


@pytest.mark.parametrize("path", DATABASE_COMMANDS)
def test_every_command_that_touches_the_database_takes_db(path: str) -> None:
    result = CliRunner().invoke(cli, [*path.split(), "--help"])
    assert result.exit_code == 0, result.output
    assert "--db URL" in result.output


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


class _Acme:
    """A third party's commands: one fails, one takes the command context."""

    @hookimpl
    def catenary_commands(self) -> list[Command]:
        @click.command("acme-broken")
        def broken() -> None:
            """Fails."""
            raise ZeroDivisionError("division by zero")

        @click.command("acme-count")
        @pass_command_context
        def count(context: CommandContext) -> None:
            """Counts the wire types."""
            click.echo(f"{len(context.registry.wire_types())} wire types")

        return [Command("acme-broken", broken), Command("acme-count", count)]


def test_a_plugin_command_fails_in_one_line_naming_its_plugin(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def registry(**kwargs: Any) -> PluginRegistry:
        return PluginRegistry(plugins=[("acme", _Acme())], **kwargs)

    monkeypatch.setattr("catenary.plugins.manager.PluginRegistry", registry)
    broken = CliRunner().invoke(cli, ["acme-broken"])
    assert broken.exit_code == 1
    assert broken.output == (
        "Error: command 'acme-broken' of plugin 'acme' failed: "
        "ZeroDivisionError: division by zero\n"
    )
    count = CliRunner().invoke(cli, ["acme-count"])
    assert count.exit_code == 0, count.output
    assert int(count.output.split()[0]) >= 13  # the built-in wire types, through the context


def test_the_boundary_lets_errors_a_user_can_act_on_through() -> None:
    with pytest.raises(UserError, match=r"^bad value$"), plugin_errors("source 'x'"):
        raise UserError("bad value")
    with pytest.raises(FileNotFoundError), plugin_errors("source 'x'"):
        raise FileNotFoundError(2, "No such file", "/data/run.h5")
    with pytest.raises(PluginFailure) as failure, plugin_errors("source 'x' of plugin 'p'"):
        raise ConnectionError("camera\nlost")
    assert str(failure.value) == "source 'x' of plugin 'p' failed: ConnectionError: camera lost"
    assert failure.value.detail == "ConnectionError: camera lost"
