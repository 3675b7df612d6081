"""``catenary report NAME``: a report or export written by a registered reporter.

The command builds a request (:mod:`catenary.maintenance.reports`), calls
``Reporter.write(request, output)`` inside an error boundary and prints the path written.
"""

from __future__ import annotations

from pathlib import Path

import click

from catenary.cli.app import app_of
from catenary.domain import CODE_LENGTH
from catenary.errors import UserError
from catenary.plugins import PluginRegistry, database_option
from catenary.text import identifier_option

__all__ = ["report"]


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
@click.option(
    "--run",
    "more_runs",
    multiple=True,
    metavar="RUN",
    help="A run id, UUID (or its prefix) or 'latest'.",
)
@click.option("--latest", is_flag=True, help="The last processed run (as RUN 'latest').")
@click.option("--line", metavar="CODE", help="Line code.", callback=identifier_option(CODE_LENGTH))
@click.option(
    "--track",
    metavar="CODE",
    help="Track code (with --line).",
    callback=identifier_option(CODE_LENGTH),
)
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
    help="The file to write; its suffix chooses the format (.html, .csv, .xlsx, .parquet; "
    "'-': CSV to standard output).",
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
) -> None:
    """Write report NAME to OUTPUT (RUN: a run id, UUID or its prefix, or 'latest'; --list:
    the reporters).

    \b
    catenary report run RUN -o run.html
    catenary report maintenance --line L -o plan.html|plan.csv|plan.xlsx
    catenary report linear-events [--line L] [--run RUN|--latest] -o events.csv|.xlsx|-
    catenary report repeatability RUN_A RUN_B -o repeat.html|histogram.csv
    """
    from catenary.maintenance.reports import report_request

    app = app_of(ctx)
    settings = app.settings
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
    with registry.boundary("reporter", name):
        written = reporter.write(request, output)
    to_stdout = str(written) == "-"  # the CSV is standard output: the message goes aside
    where = "standard output" if to_stdout else str(written)
    click.echo(f"{name} report written to {where}", err=to_stdout)
