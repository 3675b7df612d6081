"""``catenary report NAME``: a report or export written by a registered reporter.

Reporters come from plugins (hook ``catenary_reporters``; the built-ins are in
``catenary_reports``), so a third party's reporter is run exactly like the built-ins. The
command builds a request, calls ``Reporter.write(request, output)`` inside an error boundary
and prints the path written. The request (``report_request``, also for scheduled report jobs)
is a mapping with the keys:

- ``settings``: the ``Settings`` of the invocation (database URL, data directory, sections);
- ``registry``: the ``PluginRegistry`` (wire types, limit policies);
- ``policy``: the wear-limit ``LimitPolicy`` (``--policy NAME``, else the config's
  ``[limits]``), or None without one;
- ``runs``: the run references given (ids or ``latest``), a tuple of str;
- ``line``, ``track``: codes, or None;
- ``options``: the ``--set KEY=VALUE`` pairs, a dict of str.

A reporter chooses its output's format by the file's suffix and refuses, in one line, what it
does not take.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import click

from catenary.config import Settings
from catenary.errors import UserError
from catenary.limits import LimitPolicy, policy_from_config, select_policy
from catenary.plugins import PluginRegistry
from catenary.run_commands import database_option

__all__ = ["report", "report_request"]


def _policy(settings: Settings, registry: PluginRegistry, name: str | None) -> LimitPolicy | None:
    presets = registry.limit_policies()
    if name is not None:
        return select_policy(presets, name, origin="wear-limit presets")
    return policy_from_config(
        settings.sections.get("limits"), presets=presets, config_path=settings.config_path
    )


def report_request(
    settings: Settings,
    registry: PluginRegistry,
    *,
    runs: tuple[str, ...] = (),
    line: str | None = None,
    track: str | None = None,
    policy: str | None = None,
    options: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """The request a reporter's ``write`` takes (module docstring); ``policy`` names a preset
    (default: the config's ``[limits]``)."""
    return {
        "settings": settings,
        "registry": registry,
        "policy": _policy(settings, registry, policy),
        "runs": tuple(runs),
        "line": line,
        "track": track,
        "options": dict(options or {}),
    }


def _options(pairs: tuple[str, ...]) -> dict[str, str]:
    found: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise UserError(f"--set {pair!r}: expected KEY=VALUE")
        found[key.strip()] = value.strip()
    return found


def _list(registry: PluginRegistry) -> None:
    reporters = registry.reporters()
    if not reporters:
        click.echo("no reporters registered (catenary plugins shows load errors)")
    for name, reporter in sorted(reporters.items()):
        click.echo(f"{name}  (plugin {registry.owner('reporter', name)})")
        click.echo(f"    {reporter.description}")


@click.command("report")
@click.argument("name", required=False)
@click.argument("runs", nargs=-1, metavar="[RUN]...")
@click.option("--run", "more_runs", multiple=True, metavar="RUN", help="A run id or 'latest'.")
@click.option("--latest", is_flag=True, help="The last processed run (as RUN 'latest').")
@click.option("--line", metavar="CODE", help="Line code.")
@click.option("--track", metavar="CODE", help="Track code (with --line).")
@click.option(
    "--policy",
    "policy_name",
    metavar="NAME",
    help="Wear-limit preset (default: the config's [limits]; catenary wire-types lists them).",
)
@click.option(
    "--set",
    "pairs",
    multiple=True,
    metavar="KEY=VALUE",
    help="An option of the reporter (--list says which it takes).",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path, dir_okay=False),
    help="The file to write; its suffix chooses the format (.html, .csv, .parquet).",
)
@click.option("--list", "list_reporters", is_flag=True, help="List the reporters and exit.")
@database_option
@click.pass_context
def report(
    ctx: click.Context,
    name: str | None,
    runs: tuple[str, ...],
    more_runs: tuple[str, ...],
    latest: bool,
    line: str | None,
    track: str | None,
    policy_name: str | None,
    pairs: tuple[str, ...],
    output: Path | None,
    list_reporters: bool,
    database_url: str | None,
) -> None:
    """Write report NAME to OUTPUT (RUN: a run id or 'latest'; --list: the reporters).

    \b
    catenary report run RUN -o run.html
    catenary report maintenance --line L -o plan.html|plan.csv
    catenary report linear-events [--line L] [--run RUN|--latest] -o events.csv|.parquet
    catenary report repeatability RUN_A RUN_B -o repeat.html|histogram.csv
    """
    from catenary.cli import app_of  # the CLI module imports this one

    app = app_of(ctx)
    settings = app.settings
    if database_url:
        settings = dataclasses.replace(settings, database_url=database_url)
    registry = app.registry
    if list_reporters:
        _list(registry)
        return
    if name is None:
        raise click.UsageError("name a reporter (catenary report --list shows them)")
    if output is None:
        raise click.UsageError("give the output file with -o/--output")
    reporters = registry.reporters()
    reporter = reporters.get(name)
    if reporter is None:
        known = ", ".join(sorted(reporters)) or "none"
        raise UserError(f"unknown reporter {name!r} (known: {known})")
    if track is not None and line is None:
        raise click.UsageError("--track needs --line")
    request = report_request(
        settings,
        registry,
        runs=(*runs, *more_runs, *(("latest",) if latest else ())),
        line=line,
        track=track,
        policy=policy_name,
        options=_options(pairs),
    )
    try:
        written = reporter.write(request, output)
    except (UserError, OSError):
        raise
    except Exception as exc:
        text = " ".join(str(exc).split())
        raise UserError(
            f"reporter {name!r} of plugin {registry.owner('reporter', name)!r} failed: "
            f"{type(exc).__name__}{': ' + text if text else ''}"
        ) from None
    click.echo(f"{name} report written to {written}")
