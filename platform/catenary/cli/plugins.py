"""``catenary plugins``: the plugins loaded, what each registers, and load errors."""

from __future__ import annotations

import click

from catenary.cli.app import app_of
from catenary.cli.listing import echo_json, format_option

__all__ = ["plugins_command"]


@click.command("plugins")
@click.option("--strict", is_flag=True, help="Exit with status 1 if any plugin failed.")
@format_option()
@click.pass_context
def plugins_command(ctx: click.Context, strict: bool, output_format: str) -> None:
    """List the plugins loaded, what each registers, and load errors (on standard error).

    --format json: a list of {"plugin", "registers": {kind: [names]}}."""
    registry = app_of(ctx).registry
    registrations = registry.registrations()
    if output_format == "json":
        echo_json([{"plugin": p, "registers": kinds} for p, kinds in registrations.items()])
    else:
        for plugin, kinds in registrations.items():
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
