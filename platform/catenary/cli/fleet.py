"""``catenary push`` and ``catenary pull`` (runs to the central side, the register from it) and
``catenary reprocess`` (stored runs processed again on Dask)."""

from __future__ import annotations

import sys
import time
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import app_of
from catenary.domain import CODE_LENGTH
from catenary.errors import UserError
from catenary.plugins import database_option
from catenary.text import identifier_option, printable

if TYPE_CHECKING:
    from catenary.config import Settings

_CENTRAL = click.Path(path_type=Path, dir_okay=False)


def central_settings(path: Path) -> Settings:
    """The central side's settings: its config file alone (this machine's
    ``CATENARY_DATABASE_URL``, ``CATENARY_DATA_DIR`` and ``CATENARY_CONFIG`` name this side,
    not that one); it must name its database and its store (``[store] url``, or a shared
    ``[paths] data_dir``)."""
    from catenary.config import load_settings, read_config_file

    config = read_config_file(path)
    if "url" not in config.get("database", {}):
        raise UserError(f"{path}: [database] url is missing: name the central side's database")
    if "url" not in config.get("store", {}) and "data_dir" not in config.get("paths", {}):
        raise UserError(
            f"{path}: [store] url is missing: name the central side's store (or its shared "
            "[paths] data_dir)"
        )
    return load_settings(config_path=path, environ={})


def _megabytes(size: int) -> str:
    return f"{size / 1e6:.1f} MB"


@click.command("push")
@click.option("--to", "central_path", required=True, type=_CENTRAL, metavar="CENTRAL.toml",
              help="The central side's config: its [database] and [store].")  # fmt: skip
@click.option("--run-files", is_flag=True, help="Send the runs' recorded files too.")
@database_option
@click.pass_context
def push(ctx: click.Context, central_path: Path, run_files: bool) -> None:
    """Send every run and processing the central side lacks, then evaluate their alerts there.

    Idempotent and resumable: a run is sent once whatever pushes it, and a push cut short
    goes on where it stopped when it is run again.
    """
    from catenary.fleet.transfer import push as push_runs
    from catenary.maintenance.alerts import announce_alerts, evaluate_tracks, run_alerting
    from catenary.maintenance.notifications import notification_config
    from catenary.storage.database import open_database

    app = app_of(ctx)
    central = central_settings(central_path)
    alerting = run_alerting(central, app.registry)
    bar: list[Any] = []

    def plan(processings: int, total_bytes: int) -> None:
        click.echo(f"to push: {processings} processing(s), {_megabytes(total_bytes)} of samples")
        bar.append(
            click.progressbar(
                length=max(total_bytes, 1),
                label="pushing",
                file=sys.stderr,
                hidden=not sys.stderr.isatty(),
            )
        )
        bar[0].__enter__()

    try:
        result = push_runs(
            app.settings,
            central,
            run_files=run_files,
            progress=lambda size: bar[0].update(size),
            on_plan=plan,
        )
    finally:
        if bar:
            bar[0].__exit__(None, None, None)
    for run_uuid, processing_uuid, size in result.moved:
        click.echo(f"run {run_uuid}: processing {processing_uuid} ({_megabytes(size)})")
    click.echo(
        f"pushed {result.runs} new run(s), {result.processings} processing(s), "
        f"{result.objects} object(s) ({_megabytes(result.bytes)})"
        + (f"; {result.already} stored meanwhile by another push" if result.already else "")
    )
    if result.parts_found:
        click.echo(
            f"run files: {result.parts_sent} part(s) sent, {result.parts_found} found in place "
            "from a push cut short"
        )
    if not result.run_ids:
        return
    if alerting.policy is None:
        click.echo("alerts     not evaluated centrally: no [limits] policy in " + str(central_path))
        return
    with open_database(central, batch=True) as engine:
        evaluation = evaluate_tracks(
            engine,
            alerting.policy,
            alerting.wire_types,
            run_ids=result.run_ids,
            horizon_days=alerting.horizon_days,
            notifications=notification_config(central),
            line_speeds=alerting.line_speeds,
        )
        announce_alerts(engine, app.registry, evaluation.new)
    click.echo(f"alerts     {evaluation.summary()} (policy {evaluation.policy}, central)")
    if evaluation.failed:
        raise UserError(
            f"{central_path}: the pushed runs are stored but the alerts of "
            f"{len(evaluation.failed)} track(s) were not evaluated: catenary --config "
            f"{central_path} alerts evaluate --all tries again"
        )


@click.command("pull")
@click.option("--from", "central_path", required=True, type=_CENTRAL, metavar="CENTRAL.toml",
              help="The central side's config: its [database] and [limits].")  # fmt: skip
@database_option
@click.pass_context
def pull(ctx: click.Context, central_path: Path) -> None:
    """Copy the central register (lines, tracks, masts) and wear-limit policy file here."""
    from catenary.fleet.transfer import pull as pull_register

    app = app_of(ctx)
    result = pull_register(
        app.settings, central_settings(central_path), sorted(app.registry.wire_types())
    )
    click.echo(
        f"pulled {result.tracks} track(s): {result.masts_changed} mast(s) added or changed, "
        f"{result.masts_removed} removed"
    )
    if result.policy_file is not None:
        click.echo(
            f"policy     copied to {result.policy_file} (name it in [limits] file of this "
            "side's config)"
        )
    if result.missing_wire_types:
        click.echo(
            "warning: the register names wire types not installed here: "
            + ", ".join(result.missing_wire_types)
            + " (install the plugin that provides them)",
            err=True,
        )


@click.command("reprocess")
@click.argument("references", metavar="[RUN]...", nargs=-1)
@click.option("--line", help="Runs of this line.", callback=identifier_option(CODE_LENGTH))
@click.option("--track", help="Runs of this track.", callback=identifier_option(CODE_LENGTH))
@click.option("--since", type=click.DateTime(["%Y-%m-%d"]), metavar="YYYY-MM-DD",
              help="Runs started on this day (UTC) or later.")  # fmt: skip
@click.option("--until", type=click.DateTime(["%Y-%m-%d"]), metavar="YYYY-MM-DD",
              help="Runs started on this day (UTC) or earlier.")  # fmt: skip
@click.option("--vehicle", help="Runs this vehicle measured.")
@click.option("--stale", is_flag=True,
              help="Only runs whose latest processing is not what reprocessing makes now (another "
                   "rig calibration, catenary version, processor or settings).")  # fmt: skip
@click.option("--rig", "rig_path", type=click.Path(path_type=Path, dir_okay=False),
              help="Rig calibration TOML (default: each vehicle's latest stored one).")  # fmt: skip
@click.option("--processor", default="linescan-stereo", show_default=True,
              help="Processing method (catenary plugins lists them).")  # fmt: skip
@click.option("--scheduler", metavar="tcp://HOST:8786",
              help="An existing Dask cluster's scheduler (default: a local cluster).")  # fmt: skip
@click.option("--workers", type=click.IntRange(min=1), metavar="N",
              help="Worker processes of the local cluster (default: the cores).")  # fmt: skip
@database_option
@click.pass_context
def reprocess(
    ctx: click.Context,
    references: tuple[str, ...],
    line: str | None,
    track: str | None,
    since: datetime | None,
    until: datetime | None,
    vehicle: str | None,
    stale: bool,
    rig_path: Path | None,
    processor: str,
    scheduler: str | None,
    workers: int | None,
) -> None:
    """Process stored runs again from their run files, each into a new processing, on Dask.

    Runs whose latest processing is already what this would make are skipped, so running it
    again goes on where it stopped. A run whose file is neither where it was recorded nor in
    the store (push --run-files) is skipped, saying so.
    """
    from catenary.fleet.reprocess import Outcome, Selection
    from catenary.fleet.reprocess import reprocess as reprocess_runs

    if since is not None and until is not None and until < since:
        raise UserError(f"--until {until:%Y-%m-%d} is before --since {since:%Y-%m-%d}")
    if scheduler is not None and workers is not None:
        raise UserError(
            "--workers is for the local cluster: an existing one (--scheduler) has its own"
        )
    settings = app_of(ctx).settings
    selection = Selection(
        references=references,
        line=line,
        track=track,
        since=None if since is None else since.date(),
        until=None if until is None else until.date(),
        vehicle=vehicle,
        stale=stale,
    )
    started = time.monotonic()
    where = scheduler or "a local cluster"

    def selected(runs: int) -> None:
        click.echo(f"reprocessing {runs} run(s) on {where}" if runs else "no run to reprocess")

    def finished(outcome: Outcome) -> None:
        click.echo(printable(outcome.line()))

    outcomes = reprocess_runs(
        settings,
        selection,
        rig_path=rig_path,
        processor=processor,
        scheduler=scheduler,
        workers=workers,
        on_selected=selected,
        on_outcome=finished,
    )
    if not outcomes:
        return
    counts = {s: sum(o.status == s for o in outcomes) for s in ("stored", "skipped", "failed")}
    click.echo(
        f"reprocessed {len(outcomes)} run(s) in {time.monotonic() - started:.1f} s: "
        + ", ".join(f"{n} {status}" for status, n in counts.items())
    )
    if counts["stored"]:
        click.echo(
            f"alerts     {counts['stored']} run(s) pending: catenary alerts evaluate --all "
            "evaluates them"
        )
    if counts["failed"]:
        raise UserError(f"{counts['failed']} run(s) failed (above)")
