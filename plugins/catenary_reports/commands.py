"""The reporting plugin's command, ``catenary history`` (its work in
``catenary_reports.history``, imported when it runs so that ``catenary --help`` stays quick)."""

from __future__ import annotations

from pathlib import Path

import click

from catenary.domain import CODE_LENGTH
from catenary.plugins import CommandContext, database_option, pass_command_context
from catenary.text import identifier_option

__all__ = ["history"]


@click.command("history")
@click.option(
    "--line",
    metavar="CODE",
    required=True,
    callback=identifier_option(CODE_LENGTH),
    help="Line code.",
)
@click.option(
    "--track",
    metavar="CODE",
    required=True,
    callback=identifier_option(CODE_LENGTH),
    help="Track code.",
)
@click.option("--mast", metavar="CODE", help="The span that starts at this mast.")
@click.option(
    "--from-m",
    "from_m",
    type=float,
    metavar="M",
    help="Spans from this chainage [m] (with --to-m).",
)
@click.option(
    "--to-m", "to_m", type=float, metavar="M", help="Spans to this chainage [m] (with --from-m)."
)
@click.option(
    "--policy",
    "policy_name",
    metavar="NAME",
    help="Wear-limit preset (default: the config's [limits]).",
)
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Plot to this .png or .svg file.",
)
@database_option
@pass_command_context
def history(
    context: CommandContext,
    line: str,
    track: str,
    mast: str | None,
    from_m: float | None,
    to_m: float | None,
    policy_name: str | None,
    output: Path | None,
) -> None:
    """A span's measurements over runs, wear rate and limit forecasts (--mast CODE, or
    --from-m M --to-m M for the spans of a stretch); -o FILE.png|.svg plots them."""
    from catenary_reports.history import show_history

    show_history(context, line, track, mast, from_m, to_m, policy_name, output)
