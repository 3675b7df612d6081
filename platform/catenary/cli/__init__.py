"""The ``catenary`` command line: click commands only, one module per command group.

``app`` holds what one invocation shares (settings, plugin registry) and prints the errors a
user can cause in one line; the root group adds the plugins' commands. A command imports the
numerical modules it needs when it runs, so ``catenary --help`` stays quick. Nothing outside
this package imports it: plugins add commands through the ``catenary_commands`` hook.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import click

from catenary.cli import app
from catenary.cli.db import db
from catenary.cli.fleet import pull, push, reprocess
from catenary.cli.maintenance import alerts, maintenance
from catenary.cli.plugins import plugins_command
from catenary.cli.record import record
from catenary.cli.report import report
from catenary.cli.runs import compare, export, process, runs
from catenary.cli.serve import serve
from catenary.cli.services import notify, scheduler
from catenary.cli.users import audit, tokens, users
from catenary.cli.wiretypes import wire_types_command

__all__ = ["cli", "main"]


@click.group(cls=app.CatenaryGroup, context_settings={"help_option_names": ["-h", "--help"]})
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
    app.app_of(ctx)


for _command in (
    plugins_command,
    wire_types_command,
    db,
    record,
    process,
    export,
    compare,
    runs,
    push,
    pull,
    reprocess,
    notify,
    scheduler,
    report,
    alerts,
    maintenance,
    users,
    tokens,
    audit,
    serve,
):
    cli.add_command(_command)


def __getattr__(name: str) -> Any:
    """``catenary.cli.app_of``, the 0.1 way a plugin's command reached the settings:
    deprecated (a command takes ``catenary.plugins.CommandContext`` instead)."""
    if name == "app_of":
        from catenary.deprecated import moved

        moved("catenary.cli.app_of", "catenary.plugins.pass_command_context")
        return app.app_of
    raise AttributeError(f"module 'catenary.cli' has no attribute {name!r}")


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    cli.main(args=argv, prog_name="catenary")


if __name__ == "__main__":  # pragma: no cover
    main()
