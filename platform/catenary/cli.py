"""The ``catenary`` command line: core subcommands plus those plugins add.

Errors a user can cause (``UserError`` and its kinds, unreadable files, values outside a
profile) are printed as one line without a traceback, with exit status 1; usage errors exit 2.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from catenary.config import Settings, load_settings
from catenary.errors import UserError
from catenary.plugins import PluginRegistry
from catenary.wiretype import ProfileRangeError

F = TypeVar("F", bound=Callable[..., Any])


class App:
    """What one invocation shares: its settings and plugin registry, both made on first use."""

    def __init__(self, config_path: Path | None, database_url: str | None) -> None:
        self._config_path = config_path
        self._database_url = database_url
        self._settings: Settings | None = None
        self._registry: PluginRegistry | None = None

    @property
    def settings(self) -> Settings:
        if self._settings is None:
            self._settings = load_settings(
                config_path=self._config_path, database_url=self._database_url
            )
        return self._settings

    @property
    def registry(self) -> PluginRegistry:
        if self._registry is None:
            self._registry = PluginRegistry(disabled=self.settings.disabled_plugins)
        return self._registry


def app_of(ctx: click.Context) -> App:
    """The invocation's ``App``, kept on the root context."""
    root = ctx.find_root()
    if not isinstance(root.obj, App):
        root.obj = App(root.params.get("config_path"), root.params.get("database_url"))
    return root.obj


def one_line_errors(call: Callable[[], Any]) -> Any:
    """Run ``call``, turning errors a user can cause into a one-line ``ClickException``."""
    try:
        return call()
    except (UserError, ProfileRangeError) as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        raise click.ClickException(f"{where}{exc.strerror or exc}") from None


class CatenaryGroup(click.Group):
    """A group whose commands include the plugins' and whose errors are one line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        names = set(super().list_commands(ctx))
        if self is cli:
            names |= set(one_line_errors(lambda: app_of(ctx).registry.commands()))
        return sorted(names)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None and self is cli:
            found = one_line_errors(lambda: app_of(ctx).registry.commands()).get(cmd_name)
            command = None if found is None else found.command
        return command

    def invoke(self, ctx: click.Context) -> Any:
        return one_line_errors(lambda: super(CatenaryGroup, self).invoke(ctx))


@click.group(cls=CatenaryGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "--config",
    "config_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="TOML config file (default: $CATENARY_CONFIG, else config.toml in the user config dir).",
)
@click.option(
    "--db",
    "database_url",
    metavar="URL",
    help="Database URL (default: $CATENARY_DATABASE_URL, else a SQLite file in the data dir).",
)
@click.version_option(package_name="catenary")
@click.pass_context
def cli(ctx: click.Context, config_path: Path | None, database_url: str | None) -> None:
    """Contact wire wear from line-scan stereovision: measure, store, maintain."""
    app_of(ctx)


@cli.command("plugins")
@click.option("--strict", is_flag=True, help="Exit with status 1 if any plugin failed.")
@click.pass_context
def plugins_command(ctx: click.Context, strict: bool) -> None:
    """List the plugins loaded, what each registers, and load errors."""
    registry = app_of(ctx).registry
    for plugin, kinds in registry.registrations().items():
        click.echo(plugin)
        if not kinds:
            click.echo("    (registers nothing)")
        for kind, names in sorted(kinds.items()):
            click.echo(f"    {kind}: {', '.join(names)}")
    if registry.errors:
        click.echo("errors:", err=True)
        for error in registry.errors:
            click.echo(f"    {error}", err=True)
        if strict:
            ctx.exit(1)


@cli.command("wire-types")
@click.pass_context
def wire_types_command(ctx: click.Context) -> None:
    """List the wire types with their nominal geometry."""
    registry = app_of(ctx).registry
    click.echo(f"{'name':<10} {'standard':<16} {'A mm':>6} {'B mm':>6} {'area mm2':>9}  plugin")
    for name, wire in sorted(registry.wire_types().items()):
        legacy = " (legacy)" if wire.legacy else ""
        click.echo(
            f"{name:<10} {wire.standard:<16} {wire.height_mm:6.2f} {wire.width_mm:6.2f} "
            f"{wire.area_mm2:9.1f}  {registry.owner('wire type', name)}{legacy}"
        )


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    cli.main(args=argv, prog_name="catenary")


if __name__ == "__main__":  # pragma: no cover
    main()
