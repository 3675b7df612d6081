"""The maintenance service's commands: ``catenary notify deliver|status|requeue`` and
``catenary scheduler``."""

from __future__ import annotations

import logging
import sys
from datetime import datetime
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import app_of
from catenary.cli.listing import echo_json, format_option
from catenary.domain import NAME_LENGTH
from catenary.plugins import database_option
from catenary.text import identifier_option, printable

if TYPE_CHECKING:
    from catenary.maintenance.notifications import (
        Attempt,
    )
    from catenary.storage.models import AlertNotification


def _when(moment: datetime | None) -> str:
    return "-" if moment is None else moment.strftime("%Y-%m-%d %H:%M:%S UTC")


@click.group("notify")
def notify() -> None:
    """Alert notifications: deliver those due, list those not sent, queue again those that gave
    up ([notifications])."""


def _describe(attempt: Attempt) -> str:
    where = f"alert {attempt.alert_id} to {attempt.channel}"
    if attempt.sent:
        return f"sent     {where}"
    if attempt.gave_up:
        return f"gave up  {where} after {attempt.attempts} attempts: {attempt.error}"
    return (
        f"failed   {where} (attempt {attempt.attempts}, next at "
        f"{_when(attempt.next_attempt_at)}): {attempt.error}"
    )


@notify.command("deliver")
@database_option
@click.pass_context
def deliver_command(ctx: click.Context) -> None:
    """One delivery pass: queue what is missing, send what is due, retry failures later."""
    from catenary.maintenance.notifications import deliver_pending, notification_config
    from catenary.storage.database import open_database, session_scope

    app = app_of(ctx)
    settings = app.settings
    if not notification_config(settings, app.registry).channels:
        click.echo("no notification channels configured ([[notifications.channels]])")
        return
    with open_database(settings) as engine:
        report = deliver_pending(lambda: session_scope(engine), app.registry, settings)
    for channel, reason in report.unavailable.items():
        click.echo(printable(f"channel {channel}: {reason}; its notifications wait"), err=True)
    for attempt in report.attempts:
        click.echo(printable(_describe(attempt)))
    sent = sum(attempt.sent for attempt in report.attempts)
    gave_up = sum(attempt.gave_up for attempt in report.attempts)
    failed = len(report.attempts) - sent - gave_up
    click.echo(
        f"{report.queued} queued, {sent} sent, {failed} failed (retried later), {gave_up} gave up"
    )


def _status_line(row: AlertNotification, configured: set[str]) -> str:
    alert = row.alert
    masts = f"masts {alert.mast_from}-{alert.mast_to}" if alert.mast_from else "no masts"
    if row.next_attempt_at is not None:
        due = f"next at {_when(row.next_attempt_at)}"
    else:
        due = "due" if row.status == "pending" else "gave up"
    unknown = "" if row.notifier in configured else " (channel not configured)"
    error = f": {row.last_error}" if row.last_error else ""
    return (
        f"{row.id:>6}  alert {alert.id} {alert.level} line {alert.track.line.code} track "
        f"{alert.track.code} {masts} wire position {alert.wire} -> {row.notifier}{unknown}: "
        f"{row.status}, {row.attempts} attempt(s), {due}{error}"
    )


def _status_record(row: AlertNotification, configured: set[str]) -> dict[str, Any]:
    """A notification not sent, as ``--format json`` shows it."""
    alert = row.alert
    return {
        "id": row.id,
        "alert_id": alert.id,
        "level": alert.level,
        "line": alert.track.line.code,
        "track": alert.track.code,
        "mast_from": alert.mast_from,
        "mast_to": alert.mast_to,
        "wire_position": alert.wire,
        "channel": row.notifier,
        "channel_configured": row.notifier in configured,
        "status": row.status,
        "attempts": row.attempts,
        "next_attempt_at": row.next_attempt_at,
        "last_error": row.last_error,
        "updated_at": row.updated_at,
    }


@notify.command("status")
@format_option()
@database_option
@click.pass_context
def status_command(ctx: click.Context, output_format: str) -> None:
    """List the notifications not sent (pending or failed), with their last error."""
    from catenary.maintenance.notifications import notification_config, undelivered
    from catenary.storage.database import open_database, session_scope

    settings = app_of(ctx).settings
    configured = {channel.name for channel in notification_config(settings).channels}
    with (
        open_database(settings) as engine,
        session_scope(engine, read_only=True) as session,
    ):
        rows = undelivered(session)
        if output_format == "json":
            echo_json([_status_record(row, configured) for row in rows])
            return
        lines = [_status_line(row, configured) for row in rows]
    if not lines:
        click.echo("every notification is sent")
        return
    for line in lines:
        click.echo(printable(line))
    failed = sum(row.status == "failed" for row in rows)
    click.echo(f"{len(rows) - failed} pending, {failed} failed")


@notify.command("requeue")
@click.option(
    "--channel",
    metavar="NAME",
    callback=identifier_option(NAME_LENGTH),
    help="Only this channel's.",
)
@click.option(
    "--alert", "alert_id", type=click.IntRange(min=1), metavar="ID", help="Only this alert's."
)
@database_option
@click.pass_context
def requeue_command(ctx: click.Context, channel: str | None, alert_id: int | None) -> None:
    """Queue again the notifications that gave up (failed max_attempts times), from their first
    attempt: the next delivery pass sends them. Fix the channel's settings first."""
    from catenary.config import did_you_mean
    from catenary.errors import UserError
    from catenary.maintenance.notifications import notification_config, requeue_failed
    from catenary.storage.database import open_database, session_scope

    app = app_of(ctx)
    settings = app.settings
    names = {c.name for c in notification_config(settings, app.registry).channels}
    if channel is not None and channel not in names:
        hint = did_you_mean(channel, names)
        raise UserError(f"--channel {channel}: no such notification channel{hint}")
    with open_database(settings) as engine, session_scope(engine) as session:
        count = requeue_failed(session, channel=channel, alert_id=alert_id)
    click.echo(f"{count} failed notification(s) queued again")


LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


@click.command("scheduler")
@database_option
@click.pass_context
def scheduler(ctx: click.Context) -> None:
    """Run the scheduled jobs of [scheduler] as a service, until SIGTERM or Ctrl-C."""
    from catenary.maintenance.notifications import notification_config
    from catenary.maintenance.scheduler import serve  # APScheduler is loaded by the service only

    app = app_of(ctx)
    notification_config(app.settings, app.registry)  # a wrong channel: refused at start
    logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
    # the service logs runs, errors and missed runs itself
    # (catenary.maintenance.scheduler.log_job_event)
    logging.getLogger("apscheduler").setLevel(logging.WARNING)
    logging.getLogger("apscheduler.executors").setLevel(logging.CRITICAL)
    logging.getLogger("alembic").setLevel(logging.WARNING)  # its revision checks at start
    serve(app.settings, app.registry)
