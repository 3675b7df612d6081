"""What a plugin's command receives: the invocation's settings, plugin registry and database.

A command a plugin adds (hook ``catenary_commands``) takes it with ``@pass_command_context``
instead of importing the CLI::

    @click.command("hello")
    @pass_command_context
    def hello(context: CommandContext) -> None:
        click.echo(f"{len(context.registry.wire_types())} wire types")
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import click

from catenary.config import Settings, load_settings

if TYPE_CHECKING:
    from sqlalchemy import Engine

    from catenary.plugins.manager import PluginRegistry

__all__ = ["CommandContext", "database_option", "pass_command_context"]


class CommandContext:
    """One invocation's settings (``--config``, ``--db``), plugin registry and database, each
    made on first use.

    ``settings`` are checked against the sections the core and the plugins read
    (``PluginRegistry.check_settings``): a command that uses them refuses an unknown section or
    key. ``registry`` alone (``catenary --help``, ``catenary plugins``) does not check them, so
    a user can still list the plugins that would declare a section.
    """

    def __init__(self, config_path: Path | None = None, database_url: str | None = None) -> None:
        self._config_path = config_path
        self._database_url = database_url
        self._loaded: Settings | None = None
        self._settings: Settings | None = None
        self._registry: PluginRegistry | None = None

    def _load(self) -> Settings:
        if self._loaded is None:
            self._loaded = load_settings(
                config_path=self._config_path, database_url=self._database_url
            )
        return self._loaded

    @property
    def settings(self) -> Settings:
        if self._settings is None:
            loaded = self._load()
            self.registry.check_settings(loaded)
            self._settings = loaded
        return self._settings

    @property
    def registry(self) -> PluginRegistry:
        if self._registry is None:
            from catenary.plugins.manager import PluginRegistry

            self._registry = PluginRegistry(disabled=self._load().disabled_plugins)
        return self._registry

    def use_database(self, database_url: str) -> None:
        """Use ``database_url`` as the global ``--db`` does (a command's own ``--db URL``)."""
        self._database_url = database_url
        self._loaded = self._settings = None

    @contextmanager
    def database(
        self, *, migrated: bool = True, create: bool = False, batch: bool = False
    ) -> Iterator[Engine]:
        """The invocation's database (an engine, disposed of on exit); ``migrated``: refuse, in
        one line, a database whose schema is not at the head revision; ``create``: make a
        SQLite file that does not exist (else refused); ``batch``: a batch command, which the
        statement timeout (``[database] statement_timeout_s``) of interactive commands does not
        bound."""
        from catenary.storage.database import open_database

        with open_database(self.settings, migrated=migrated, create=create, batch=batch) as engine:
            yield engine


pass_command_context = click.make_pass_decorator(CommandContext, ensure=True)
"""Pass the invocation's ``CommandContext`` to a command as its first argument."""


F = TypeVar("F", bound=Callable[..., Any])


def database_option(command: F) -> F:
    """``--db URL`` on a command, a plugin's as the core's: the invocation's database
    (``CommandContext.settings``), exactly as the global ``--db`` sets it; the command takes no
    parameter for it."""

    def use(ctx: click.Context, param: click.Parameter, url: str | None) -> None:
        if url is not None:
            ctx.ensure_object(CommandContext).use_database(url)

    return click.option(
        "--db",
        metavar="URL",
        expose_value=False,
        callback=use,
        help="Database URL (default: the global --db, $CATENARY_DATABASE_URL, the config).",
    )(command)
