"""``catenary push`` and ``catenary pull``: runs to the central side, the register from it."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import app_of
from catenary.errors import UserError
from catenary.plugins import database_option

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
