"""``catenary record``: a run file from a scan source and, optionally, a vehicle sensor source
(how they combine, how recording stops and the ``[record]`` section:
:mod:`catenary.measurement.recording`)."""

from __future__ import annotations

import sys
import time
import tomllib
from collections.abc import Callable, Iterable, Mapping
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import click

from catenary.cli.app import INTERRUPTED_EXIT_CODE, TERMINATED_EXIT_CODE, app_of
from catenary.domain import DEFAULT_BLOCK_SCANS
from catenary.errors import UserError

if TYPE_CHECKING:
    from catenary.plugins import PluginRegistry, Source, VehicleSource, VehicleStream

__all__ = ["parse_options", "record"]

RECORD_KEYS: Final = {
    "source",
    "source_options",
    "vehicle_source",
    "vehicle_options",
    "max_scans",
    "block_scans",
}


def parse_options(pairs: Iterable[str], option: str) -> dict[str, Any]:
    """``KEY=VALUE`` strings to a settings mapping (values as TOML, else plain strings)."""
    settings: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise click.BadParameter(f"expected KEY=VALUE, got {pair!r}", param_hint=option)
        try:
            value: Any = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            value = text
        settings[key] = value
    return settings


def _record_section(section: Any, config_path: Path | None) -> dict[str, Any]:
    where = f"{config_path}: " if config_path is not None else ""
    if section is None:
        return {}
    if not isinstance(section, dict):
        raise UserError(f"{where}[record] must be a table")
    unknown = sorted(set(section) - RECORD_KEYS)
    if unknown:
        raise UserError(
            f"{where}unknown key record.{unknown[0]} (known: {', '.join(sorted(RECORD_KEYS))})"
        )
    for key in ("source", "vehicle_source"):
        if key in section and not isinstance(section[key], str):
            raise UserError(f"{where}record.{key} must be a source name")
    for key in ("source_options", "vehicle_options"):
        if key in section and not isinstance(section[key], dict):
            raise UserError(f"{where}record.{key} must be a table")
    for key in ("max_scans", "block_scans"):
        value = section.get(key)
        if value is not None and (
            isinstance(value, bool) or not isinstance(value, int) or value < 1
        ):
            raise UserError(f"{where}record.{key} must be a positive integer")
    return dict(section)


def _settings_for(
    name: str, config: Mapping[str, Any], name_key: str, options_key: str, cli: dict[str, Any]
) -> dict[str, Any]:
    """The config's options for ``name`` (if it is the configured source), then the CLI's."""
    settings: dict[str, Any] = {}
    if config.get(name_key) == name:
        settings.update(config.get(options_key, {}))
    settings.update(cli)
    return settings


def _open_source(
    registry: PluginRegistry, name: str, settings: Mapping[str, Any], kind: str
) -> tuple[Any, str]:
    """Open the scan source (``kind`` "source") or vehicle source ("vehicle source") ``name``."""
    sources: Mapping[str, Source | VehicleSource] = (
        registry.sources() if kind == "source" else registry.vehicle_sources()
    )
    source = sources.get(name)
    if source is None:
        other = registry.vehicle_sources() if kind == "source" else registry.sources()
        hint = ""
        if name in other:
            other_kind, option = (
                ("vehicle source", "--vehicle-source")
                if kind == "source"
                else ("source", "--source")
            )
            hint = f"; {name!r} is a {other_kind}: use {option}"
        known = ", ".join(sorted(sources)) or "none"
        raise UserError(f"unknown {kind} {name!r} (known: {known}){hint}")
    with registry.boundary(kind, name):
        stream = source.open(settings)
    return stream, registry.describe(kind, name)


LIVE_STATUS_INTERVAL_S: Final = 1.0
"""How often the live line of a source without a known length is shown [s]."""


def _live_status(status: Callable[[], str]) -> Callable[[int], None]:
    """A progress callback that shows a live source's ``status()`` line on standard error
    at most every :data:`LIVE_STATUS_INTERVAL_S` (rewritten in place on a terminal, one line
    every ten intervals in a log)."""
    tty = sys.stderr.isatty()
    interval_s = LIVE_STATUS_INTERVAL_S if tty else 10 * LIVE_STATUS_INTERVAL_S
    shown = time.monotonic()
    scans = 0

    def show(n: int) -> None:
        nonlocal shown, scans
        scans += n
        now = time.monotonic()
        if now - shown < interval_s:
            return
        shown = now
        line = f"{scans:,} scans | {status()}"
        click.echo(f"\r{line}\x1b[K" if tty else line, err=True, nl=not tty)

    return show


def _close(stream: object) -> None:
    close = getattr(stream, "close", None)
    if callable(close):
        close()


@click.command("record")
@click.argument("out", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--source",
    "source_name",
    metavar="NAME",
    help="Scan source (e.g. simulator; default: [record] source).",
)
@click.option(
    "--source-option",
    "source_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="A setting of the scan source (repeatable), e.g. length_m=20.",
)
@click.option(
    "--vehicle-source",
    "vehicle_name",
    metavar="NAME",
    help="Vehicle sensor source (e.g. can; default: [record] vehicle_source, else the scan "
    "source's own sensor samples).",
)
@click.option(
    "--vehicle-option",
    "vehicle_options",
    multiple=True,
    metavar="KEY=VALUE",
    help="A setting of the vehicle sensor source (repeatable), e.g. log=run.blf or "
    "interface=socketcan.",
)
@click.option(
    "--no-vehicle-source",
    is_flag=True,
    help="Ignore [record] vehicle_source: use the scan source's sensor samples.",
)
@click.option(
    "--max-scans",
    type=click.IntRange(min=1),
    help="Stop after this many scans (default: [record] max_scans, else the source's end).",
)
@click.option(
    "--block-scans",
    type=click.IntRange(min=1),
    help=f"Scans per block (default: [record] block_scans, else {DEFAULT_BLOCK_SCANS}).",
)
@click.option("--overwrite", is_flag=True, help="Replace an existing OUT.")
@click.pass_context
def record(
    ctx: click.Context,
    out: Path,
    source_name: str | None,
    source_options: tuple[str, ...],
    vehicle_name: str | None,
    vehicle_options: tuple[str, ...],
    no_vehicle_source: bool,
    max_scans: int | None,
    block_scans: int | None,
    overwrite: bool,
) -> None:
    """Record a run file OUT.h5 from a scan source and, optionally, a vehicle sensor source.

    Ctrl-C stops cleanly: the scans recorded so far are kept in a complete run file.
    """
    from catenary.measurement.recording import record_run

    app = app_of(ctx)
    config = _record_section(app.settings.sections.get("record"), app.settings.config_path)
    scan_cli = parse_options(source_options, "--source-option")
    vehicle_cli = parse_options(vehicle_options, "--vehicle-option")
    source_name = source_name or config.get("source")
    if not source_name:
        raise click.UsageError("no scan source: give --source NAME or [record] source")
    if no_vehicle_source:
        if vehicle_name or vehicle_cli:
            raise click.UsageError("--no-vehicle-source with --vehicle-source/--vehicle-option")
    else:
        vehicle_name = vehicle_name or config.get("vehicle_source")
    if vehicle_cli and not vehicle_name:
        raise click.UsageError("--vehicle-option needs --vehicle-source NAME")
    max_scans = max_scans if max_scans is not None else config.get("max_scans")
    block_scans = block_scans or config.get("block_scans") or DEFAULT_BLOCK_SCANS
    registry = app.registry

    with ExitStack() as stack:
        scan_settings = _settings_for(source_name, config, "source", "source_options", scan_cli)
        scan_stream, scan_label = _open_source(registry, source_name, scan_settings, "source")
        stack.callback(_close, scan_stream)
        vehicle_stream: VehicleStream | None = None
        vehicle_label = "vehicle source"
        if vehicle_name:
            settings = _settings_for(
                vehicle_name, config, "vehicle_source", "vehicle_options", vehicle_cli
            )
            vehicle_stream, vehicle_label = _open_source(
                registry, vehicle_name, settings, "vehicle source"
            )
            stack.callback(_close, vehicle_stream)

        header = scan_stream.header
        total = header.scans if header.scans > 0 else None
        if max_scans is not None:
            total = max_scans if total is None else min(total, max_scans)
        progress: Callable[[int], None] | None = None
        if total:
            bar = stack.enter_context(
                click.progressbar(
                    length=total,
                    label=f"recording {out.name}",
                    show_pos=True,
                    file=sys.stderr,
                    hidden=not sys.stderr.isatty(),  # no bar in logs
                )
            )
            progress = bar.update
        elif callable(getattr(scan_stream, "status", None)):
            progress = _live_status(scan_stream.status)
        result = record_run(
            out,
            scan_stream,
            vehicle=vehicle_stream,
            max_scans=max_scans,
            block_scans=block_scans,
            overwrite=overwrite,
            progress=progress,
            scan_source=scan_label,
            vehicle_source=vehicle_label,
        )
    for stream in (scan_stream, vehicle_stream):
        summary = getattr(stream, "summary", None)
        if callable(summary):
            click.echo(str(summary()))
    if result.interrupted:
        how = "terminated" if result.terminated else "interrupted"
        click.echo(
            f"{how}: kept {result.scans} scans in {result.path} (complete up to the last block)"
            if result.scans
            else f"{how} before the first block: nothing recorded",
            err=True,
        )
        ctx.exit(TERMINATED_EXIT_CODE if result.terminated else INTERRUPTED_EXIT_CODE)
    click.echo(
        "; ".join(
            [
                f"recorded {result.path}: {result.scans} scans, {result.vehicle_samples} "
                f"vehicle samples ({result.flagged_vehicle_samples} flagged)",
                *result.details(),
            ]
        )
    )
