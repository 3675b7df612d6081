"""The commands on runs: ``catenary process``, ``catenary export`` and ``catenary compare``."""

from __future__ import annotations

import sys
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import Interruptions, app_of, interrupted_exit_code
from catenary.cli.listing import echo_json, format_option, utc_text
from catenary.domain import CODE_LENGTH
from catenary.errors import UserError
from catenary.plugins import database_option
from catenary.text import identifier_option, printable

if TYPE_CHECKING:
    from catenary.domain import RunHeader
    from catenary.storage.models import Run

__all__ = ["compare", "export", "process", "runs"]


@click.command("process")
@click.argument("run_path", metavar="RUN.h5", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--rig",
    "rig_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig calibration TOML (catenary calibrate).",
)
@click.option(
    "--masts",
    "register_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Mast register CSV: spans cut at its masts, chainage aligned to them.",
)
@click.option("--wire-type", help="Wire type of the whole run (default: the register's).")
@click.option(
    "--line", help="Line code (default: the run file's).", callback=identifier_option(CODE_LENGTH)
)
@click.option(
    "--track", help="Track code (default: the run file's).", callback=identifier_option(CODE_LENGTH)
)
@click.option(
    "--processor",
    default="linescan-stereo",
    show_default=True,
    help="Processing method (catenary plugins lists them).",
)
@click.option(
    "--replace",
    is_flag=True,
    help="Process a run already stored again: a new processing, which becomes the one seen.",
)
@click.option(
    "--workers",
    type=click.IntRange(min=0),
    default=0,
    help="Processes staging blocks at once (default 0: one per core this process may run "
    "on; 1: all in this process). The results are the same whatever the number.",
)
@database_option
@click.pass_context
def process(
    ctx: click.Context,
    run_path: Path,
    rig_path: Path,
    register_path: Path | None,
    wire_type: str | None,
    line: str | None,
    track: str | None,
    processor: str,
    replace: bool,
    workers: int,
) -> None:
    """Process a recorded run into per-span wear in the database."""
    from catenary.maintenance.alerts import evaluate_stored_run, run_alerting, run_alerts_lines
    from catenary.maintenance.notifications import notification_config
    from catenary.measurement.parallel import default_workers
    from catenary.measurement.process import ProcessRequest, StoredThenInterrupted, process_run
    from catenary.storage.database import open_database

    app = app_of(ctx)
    settings = app.settings
    request = ProcessRequest(
        run_path=run_path,
        rig_path=rig_path,
        register_path=register_path,
        wire_type=wire_type,
        line=line,
        track=track,
        processor=processor,
        replace=replace,
        workers=default_workers() if workers == 0 else workers,
    )
    alerting = run_alerting(settings, app.registry)
    if alerting.policy is not None:  # its alerts queue notifications: a wrong channel, now
        notification_config(settings, app.registry)
    interruptions = Interruptions()

    def progress(scans: int) -> None:
        interruptions.check()
        bar[0].update(scans)

    with interruptions.handled():
        try:
            with ExitStack() as stack:
                bar: list[Any] = []

                def start(header: RunHeader) -> None:
                    bar.append(
                        stack.enter_context(
                            click.progressbar(
                                length=header.scans,
                                label="processing",
                                file=sys.stderr,
                                hidden=not sys.stderr.isatty(),  # no bar in logs
                            )
                        )
                    )

                result = process_run(
                    request,
                    settings,
                    app.registry,
                    progress=progress,
                    on_start=start,
                )
        except StoredThenInterrupted as stopped:
            _interrupted_once_stored(ctx, stopped.run_id, stopped.interruption)
        except KeyboardInterrupt as interruption:
            click.echo(f"interrupted: {run_path} not stored (nothing of it kept)", err=True)
            ctx.exit(interrupted_exit_code(interruption))
        if interruptions.received is not None and not result.already_stored:
            _interrupted_once_stored(ctx, result.run_id, interruptions.received)
        stored = (
            f"{run_path} is already stored with this rig calibration as run {result.run_id} "
            f"(UUID {result.run_uuid})"
        )
        if result.already_stored and not (result.alerts_pending and alerting.policy is not None):
            click.echo(f"{stored}: nothing done (--replace processes it again)")
            return
        try:
            with open_database(settings, batch=True) as engine:
                alerts = evaluate_stored_run(
                    alerting, engine, settings, app.registry, result.run_id
                )
        except KeyboardInterrupt as interruption:
            _interrupted_once_stored(ctx, result.run_id, interruption)
    if result.already_stored:
        lines = [f"{stored}; its alerts were not evaluated yet: evaluated now"]
    else:
        lines = result.summary_lines()
    for text in [*lines, *run_alerts_lines(alerts)]:
        click.echo(printable(text))
    if not result.already_stored:
        click.echo(
            f"stored as run {result.run_id} (UUID {result.run_uuid}), "
            f"processing {result.processing_uuid}"
        )
        warning = result.warning(run_path)
        if warning is not None:
            click.echo(printable(warning), err=True)
    if alerts is not None and alerts.failed:
        (failure,) = alerts.failed
        raise UserError(
            f"run {result.run_id} is stored but its alerts were not evaluated "
            f"({printable(str(failure))}): "
            "catenary alerts evaluate --all tries again"
        )


def _interrupted_once_stored(
    ctx: click.Context, run_id: int, interruption: KeyboardInterrupt
) -> None:
    """Say that the run is stored and what is left to do, and exit as interrupted."""
    click.echo(
        f"interrupted: stored as run {run_id}, its alerts not evaluated "
        f"(catenary alerts evaluate --run {run_id})",
        err=True,
    )
    ctx.exit(interrupted_exit_code(interruption))


@click.command("export")
@click.argument("run_reference", metavar="RUN")
@click.option(
    "--what",
    type=click.Choice(["samples", "spans"]),
    required=True,
    help="Full-resolution samples, or one row per span and wire.",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="FILE.csv, FILE.xlsx, FILE.parquet, FILE.geojson (spans, with mast coordinates) or "
    "'-' (CSV to standard output).",
)
@database_option
@click.pass_context
def export(ctx: click.Context, run_reference: str, what: str, output: Path) -> None:
    """Export a run's samples or spans as CSV, .xlsx or Parquet, or its spans as GeoJSON
    (RUN: a run id, UUID or its prefix, or 'latest')."""
    from catenary.measurement.export import export_run

    done = export_run(app_of(ctx).settings, run_reference, what, output)
    to_stdout = str(output) == "-"  # the CSV is standard output: the message goes aside
    where = "standard output" if to_stdout else str(output)
    click.echo(f"{done.rows} {what} of run {done.run_id} written to {where}", err=to_stdout)
    if done.left_out:
        click.echo(f"{done.left_out} {what} left out: their masts have no coordinates", err=True)


@click.command("compare")
@click.argument("run_a", metavar="RUN_A")
@click.argument("run_b", metavar="RUN_B")
@database_option
@click.pass_context
def compare(ctx: click.Context, run_a: str, run_b: str) -> None:
    """Repeatability: the residual thickness of two runs over the same section, point by point."""
    from catenary.measurement.compare import compare_profiles
    from catenary.measurement.samples import run_profile
    from catenary.storage.database import open_database, session_scope
    from catenary.storage.runs import find_run
    from catenary.storage.store import open_store

    settings = app_of(ctx).settings
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        a, b = find_run(session, run_a), find_run(session, run_b)
        if a.track_id != b.track_id:
            raise UserError(f"runs {a.id} and {b.id} are on different tracks")
        store = open_store(settings)
        profiles = run_profile(store, a), run_profile(store, b)
    try:
        comparison = compare_profiles(*profiles)
    except UserError as exc:
        raise UserError(f"runs {a.id} and {b.id}: {exc}") from None
    click.echo(f"run {a.id} against run {b.id}")
    for text in comparison.summary_lines():
        click.echo(text)


@click.group("runs")
def runs() -> None:
    """The stored runs."""


def _run_record(run: Run) -> dict[str, Any]:
    """A run as ``catenary runs list`` shows it (its latest processing's, if any)."""
    processing = run.processing
    return {
        "id": run.id,
        "uuid": run.uuid,
        "line": run.line.code,
        "track": run.track.code if run.track else None,
        "direction": run.direction,
        "vehicle": run.vehicle.name,
        "started_at": utc_text(run.started_at),
        "scans": run.scans,
        "status": run.status,
        "processing_uuid": processing.uuid if processing else None,
        "processed_at": utc_text(processing.processed_at) if processing else None,
        "length_m": processing.length_m if processing else None,
    }


@runs.command("list")
@click.option(
    "--line", metavar="CODE", help="Only this line.", callback=identifier_option(CODE_LENGTH)
)
@click.option(
    "--track",
    metavar="CODE",
    help="Only this track (with --line).",
    callback=identifier_option(CODE_LENGTH),
)
@format_option()
@database_option
@click.pass_context
def list_runs(ctx: click.Context, line: str | None, track: str | None, output_format: str) -> None:
    """List the stored runs, oldest first: id, UUID, line, track, direction, vehicle, start,
    scans, status, and the latest processing's UUID, time and length."""
    from catenary.storage.database import session_scope
    from catenary.storage.runs import list_runs as stored_runs

    if track is not None and line is None:
        raise click.UsageError("--track needs --line")
    with app_of(ctx).database() as engine, session_scope(engine, read_only=True) as session:
        records = [_run_record(run) for run in stored_runs(session, line=line, track=track)]
    if output_format == "json":
        echo_json(records)
        return

    def minute(text: str | None) -> str:
        return "-" if text is None else f"{text[:16].replace('T', ' ')} UTC"

    for r in records:
        length = "-" if r["length_m"] is None else f"{r['length_m']:.1f} m"
        click.echo(
            printable(
                f"{r['id']:>6}  {r['uuid'][:8]}  {r['line']}/{r['track'] or '-'}  "
                f"{r['direction']:<10} {r['vehicle']}  {minute(r['started_at'])}  "
                f"{r['scans']} scans  {r['status']:<10} {length}  processing "
                f"{(r['processing_uuid'] or '-')[:8]} at {minute(r['processed_at'])}"
            )
        )
    click.echo(f"{len(records)} run(s)")
