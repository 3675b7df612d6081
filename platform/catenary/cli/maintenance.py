"""``catenary alerts`` (evaluate, list, ack, resolve) and ``catenary maintenance record``.

Each command is one transaction: an error leaves nothing written. The hooks
``catenary_alert_raised`` are called for each new alert once it is committed.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import app_of
from catenary.cli.listing import echo_json, format_option
from catenary.domain import (
    ALERT_STATUSES,
    CODE_LENGTH,
    MAINTENANCE_KINDS,
    NAME_LENGTH,
    REPAIR_KINDS,
)
from catenary.errors import UserError
from catenary.limits import LEVELS, LimitPolicy, choose_policy
from catenary.plugins import database_option
from catenary.plugins.context import CommandContext
from catenary.text import identifier_option, printable

if TYPE_CHECKING:
    from sqlalchemy.orm import Session

    from catenary.storage.models import Alert

__all__ = ["alerts", "maintenance"]


def _policy(app: CommandContext, name: str | None, policy_file: Path | None) -> LimitPolicy:
    """The policy named on the command line (a preset, or one of ``policy_file``), else the
    config's ``[limits]``, else the wire types' standard limits."""
    presets = app.registry.limit_policies()
    wire_types = app.registry.wire_types()
    policy = choose_policy(app.settings, presets, name, policy_file, wire_types=wire_types)
    if policy is None:
        raise UserError(
            'no wear-limit policy: set [limits] policy = "NAME" in the config, or give --policy '
            f"(presets: {', '.join(sorted(presets))})"
        )
    return policy


def _now() -> datetime:
    return datetime.now(UTC)


@click.group("alerts")
def alerts() -> None:
    """Maintenance alerts: evaluate the wear limits, list, acknowledge and resolve alerts."""


@alerts.command("evaluate")
@click.option(
    "--run",
    "run_reference",
    metavar="ID",
    help="The spans one run measured (its id, UUID or its prefix, or 'latest').",
)
@click.option("--all", "everything", is_flag=True, help="Every span of the fleet.")
@click.option(
    "--policy", "policy_name", metavar="NAME", help="Wear-limit policy (default: [limits])."
)
@click.option(
    "--policy-file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="A policy TOML file of your own (default: the presets).",
)
@database_option
@click.pass_context
def evaluate_command(
    ctx: click.Context,
    run_reference: str | None,
    everything: bool,
    policy_name: str | None,
    policy_file: Path | None,
) -> None:
    """Evaluate the wear limits and forecasts: raise, update and resolve alerts.

    Each track is evaluated in a transaction of its own: a track whose evaluation fails is
    named (its runs stay pending) and the others are still evaluated; the exit status is 1.
    """
    from catenary.maintenance.alerts import (
        announce_alerts,
        evaluate_tracks,
        horizon_days,
        line_speeds,
    )
    from catenary.storage.database import session_scope
    from catenary.storage.runs import find_run

    if (run_reference is None) == (not everything):
        raise click.UsageError("give --run ID or --all")
    app = app_of(ctx)
    policy = _policy(app, policy_name, policy_file)
    horizon, speeds = horizon_days(app.settings), line_speeds(app.settings)
    with app.database(batch=everything) as engine:
        run_ids = None
        if run_reference is not None:
            with session_scope(engine, read_only=True) as session:
                run_ids = [find_run(session, run_reference).id]
        result = evaluate_tracks(
            engine,
            policy,
            app.registry.wire_types(),
            run_ids=run_ids,
            now=_now(),
            horizon_days=horizon,
            line_speeds=speeds,
        )
        announce_alerts(engine, app.registry, result.new)
    scope = "every span" if run_ids is None else f"run {run_ids[0]}"
    click.echo(
        f"alerts     policy {policy.name}, {scope}: {result.spans} span-wires, "
        f"{result.sections} anchor sections, horizon {horizon:g} days"
    )
    click.echo(f"           {result.summary()}")
    if result.runs:
        click.echo(f"           {result.runs} run(s) evaluated for the first time")
    for note in result.notes:
        click.echo(printable(f"note       {note}"))
    for failure in result.failed:
        click.echo(printable(f"Error: {failure} (its runs stay pending)"), err=True)
    if result.failed:
        ctx.exit(1)


def _alerts_geojson(session: Session, found: list[Alert]) -> tuple[dict[str, Any], int]:
    """The alerts as GeoJSON features over their stretch, and how many were left out for
    want of mast coordinates (none on any of their tracks: a ``UserError``)."""
    from catenary.geojson import feature, feature_collection
    from catenary.maintenance.alerts.lifecycle import alert_json
    from catenary.measurement.export import track_positions

    positions = {t: track_positions(session, t)[0] for t in {a.track_id for a in found}}
    if found and all(p.empty for p in positions.values()):
        raise UserError(
            "no mast of the alerts' tracks has coordinates (latitude, longitude; FORMATS.md, "
            "Mast register): no GeoJSON"
        )
    features = []
    for alert in found:
        geometry = positions[alert.track_id].stretch(alert.start_chainage_m, alert.end_chainage_m)
        if geometry is not None:
            features.append(feature(geometry, alert_json(alert)))
    return feature_collection(features), len(found) - len(features)


@alerts.command("list")
@click.option(
    "--status",
    type=click.Choice(["active", *ALERT_STATUSES, "all"]),
    default="active",
    show_default=True,
    help="active: open and acknowledged.",
)
@click.option(
    "--line", metavar="L", help="Only this line.", callback=identifier_option(CODE_LENGTH)
)
@click.option(
    "--level", "levels", multiple=True, type=click.Choice(LEVELS), help="Only these levels."
)
@format_option("geojson")
@click.option(
    "-o",
    "--output",
    type=click.Path(path_type=Path, dir_okay=False),
    help="Write GeoJSON to FILE.geojson (as --format geojson) instead of printing.",
)
@database_option
@click.pass_context
def list_command(
    ctx: click.Context,
    status: str,
    line: str | None,
    levels: tuple[str, ...],
    output_format: str,
    output: Path | None,
) -> None:
    """List alerts, most severe first, then by line, track and chainage; and how many runs
    are waiting for their alerts to be evaluated (with --format json or geojson: on standard
    error).

    --format geojson (or -o FILE.geojson): each alert over its stretch, placed by the masts'
    coordinates; alerts beyond the masts with coordinates are left out (said on standard
    error)."""
    from catenary.geojson import geojson_text, write_geojson
    from catenary.maintenance.alerts import alert_stretch, alert_summary, list_alerts
    from catenary.maintenance.alerts.lifecycle import alert_json
    from catenary.storage.database import session_scope
    from catenary.storage.runs import pending_runs

    if output is not None:
        if output.suffix.lower() != ".geojson":
            raise UserError(f"{output}: the output's suffix must be .geojson")
        output_format = "geojson"
    with app_of(ctx).database() as engine, session_scope(engine, read_only=True) as session:
        found = list_alerts(session, status=status, line=line, levels=levels)
        pending = pending_runs(session, line=line)
        if output_format == "json":
            echo_json([alert_json(alert) for alert in found])
        elif output_format == "geojson":
            collection, left_out = _alerts_geojson(session, found)
            if output is None:
                click.echo(geojson_text(collection), nl=False)
            else:
                write_geojson(output, collection)
                click.echo(f"{len(collection['features'])} alert(s) written to {output}")
            if left_out:
                click.echo(f"{left_out} alert(s) left out: no mast coordinates there", err=True)
        else:
            for alert in found:
                section = (alert.details or {}).get("anchor_section")
                within = f" (section {section})" if section else ""
                click.echo(
                    printable(
                        f"{alert.id:>6}  {alert.level:<8} {alert.kind:<9} {alert.status:<12} "
                        f"{alert.track.line.code}/{alert.track.code}  {alert_stretch(alert)}"
                        f"{within}, wire position {alert.wire}: "
                        f"{alert_summary(alert)}; {(alert.details or {}).get('action', alert.rule)}"
                    )
                )
    machine = output_format != "text"
    if not machine:
        click.echo(f"{len(found)} alert(s)")
    if pending:
        where = "" if line is None else f" on line {line}"
        click.echo(
            printable(
                f"{len(pending)} run(s){where} not yet evaluated for alerts "
                f"({_ids(pending)}): catenary alerts evaluate --all"
            ),
            err=machine,
        )


def _ids(run_ids: list[int], shown: int = 10) -> str:
    """``runs 4, 7`` (the first ``shown`` of them, then how many more)."""
    more = f" and {len(run_ids) - shown} more" if len(run_ids) > shown else ""
    noun = "run" if len(run_ids) == 1 else "runs"
    return f"{noun} {', '.join(str(i) for i in run_ids[:shown])}{more}"


@alerts.command("evidence")
@click.argument("alert_id", metavar="ID", type=int)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="The PNG file to write.",
)
@database_option
@click.pass_context
def evidence_command(ctx: click.Context, alert_id: int, output: Path) -> None:
    """Write the line-scan crop at alert ID's point (every camera, a metre around it)."""
    from catenary.measurement.evidence import evidence_key
    from catenary.storage.database import session_scope
    from catenary.storage.models import Alert
    from catenary.storage.store import open_store

    if output.suffix.lower() != ".png":
        raise UserError(f"{output}: the crop is a PNG: give a .png file")
    app = app_of(ctx)
    with app.database() as engine, session_scope(engine, read_only=True) as session:
        alert = session.get(Alert, alert_id)
        if alert is None:
            raise UserError(f"no alert {alert_id} in the database")
        measured = alert.span_measurement
        if measured is None:
            raise UserError(f"alert {alert_id} is on no span measurement (its run was deleted)")
        point = "mast" if alert.kind == "geometry" else "minimum"  # where it was measured
        key = evidence_key(measured.processing.uuid, measured.span, measured.wire, point)
    store = open_store(app.settings)
    if not store.exists(key):
        raise UserError(
            f"alert {alert_id}: no crop at {store.describe(key)} (its run was processed before "
            "crops were kept: process it again with --replace)"
        )
    with store.open_input(key) as source:
        data = source.read()
    partial = output.with_name(f".{output.name}.partial")
    try:
        partial.write_bytes(data)
        partial.replace(output)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise UserError(f"{output}: cannot write ({exc.strerror})") from None
    click.echo(f"alert {alert_id}: crop of {store.describe(key)} written to {output}")


@alerts.command("ack")
@click.argument("alert_id", metavar="ID", type=int)
@click.option(
    "--by",
    "by",
    required=True,
    metavar="NAME",
    help="Who acknowledges it.",
    callback=identifier_option(NAME_LENGTH),
)
@database_option
@click.pass_context
def ack_command(ctx: click.Context, alert_id: int, by: str) -> None:
    """Acknowledge alert ID (open -> acknowledged)."""
    from catenary.maintenance.alerts import acknowledge_alert
    from catenary.storage.database import session_scope
    from catenary.storage.users import system_actor

    with app_of(ctx).database() as engine, session_scope(engine) as session:
        alert = acknowledge_alert(session, alert_id, by, _now(), actor=system_actor())
    click.echo(printable(f"alert {alert.id} acknowledged by {alert.acknowledged_by}"))


@alerts.command("resolve")
@click.argument("alert_id", metavar="ID", type=int)
@click.option(
    "--by",
    "by",
    required=True,
    metavar="NAME",
    help="Who resolves it.",
    callback=identifier_option(NAME_LENGTH),
)
@click.option("--note", help="Why (kept in the alert's details).")
@database_option
@click.pass_context
def resolve_command(ctx: click.Context, alert_id: int, by: str, note: str | None) -> None:
    """Resolve alert ID by hand (a later run showing the condition raises a new alert)."""
    from catenary.maintenance.alerts import resolve_alert
    from catenary.storage.database import session_scope
    from catenary.storage.users import system_actor

    with app_of(ctx).database() as engine, session_scope(engine) as session:
        alert = resolve_alert(session, alert_id, by, _now(), note=note, actor=system_actor())
    click.echo(f"alert {alert.id} resolved by {by}")


@click.group("maintenance")
def maintenance() -> None:
    """Maintenance actions on the wire: record work done (resolves the alerts it covers)."""


def _moment(text: str | None) -> datetime:
    if text is None:
        return _now()
    try:
        moment = datetime.fromisoformat(text)
    except ValueError:
        raise UserError(f"--at {text!r}: not an ISO 8601 time (e.g. 2025-03-14T09:30Z)") from None
    moment = moment if moment.tzinfo is not None else moment.replace(tzinfo=UTC)
    if moment > _now():
        raise UserError(f"--at {text!r}: in the future")
    return moment


@maintenance.command("record")
@click.option(
    "--line", required=True, metavar="L", help="Line code.", callback=identifier_option(CODE_LENGTH)
)
@click.option(
    "--track",
    required=True,
    metavar="T",
    help="Track code.",
    callback=identifier_option(CODE_LENGTH),
)
@click.option(
    "--from-mast",
    metavar="M1",
    help="First mast of the stretch.",
    callback=identifier_option(CODE_LENGTH),
)
@click.option(
    "--to-mast",
    metavar="M2",
    help="Last mast of the stretch.",
    callback=identifier_option(CODE_LENGTH),
)
@click.option("--from-m", type=float, metavar="X", help="Start chainage [m] (without masts).")
@click.option("--to-m", type=float, metavar="Y", help="End chainage [m].")
@click.option(
    "--kind",
    required=True,
    metavar="KIND",
    help=f"What was done: {', '.join(MAINTENANCE_KINDS)} ({', '.join(REPAIR_KINDS)} resolve "
    "the alerts on the stretch, adjusted its geometry alerts).",
)
@click.option(
    "--by",
    "by",
    required=True,
    metavar="NAME",
    help="Who did or records the work.",
    callback=identifier_option(NAME_LENGTH),
)
@click.option("--wire", type=int, metavar="N", help="Wire position in the spans (default: all).")
@click.option("--at", "at", metavar="ISO8601", help="When the work was done (default: now; UTC).")
@click.option("--note", help="A note kept with the action.")
@database_option
@click.pass_context
def record_command(
    ctx: click.Context,
    line: str,
    track: str,
    from_mast: str | None,
    to_mast: str | None,
    from_m: float | None,
    to_m: float | None,
    kind: str,
    by: str,
    wire: int | None,
    at: str | None,
    note: str | None,
) -> None:
    """Record maintenance work on a stretch of wire (masts M1 to M2, or chainages X to Y)."""
    from catenary.maintenance.actions import mast_stretch, record_maintenance
    from catenary.storage.database import session_scope
    from catenary.storage.runs import find_track
    from catenary.storage.users import system_actor

    by_masts = from_mast is not None or to_mast is not None
    by_chainage = from_m is not None or to_m is not None
    if (
        by_masts == by_chainage
        or (by_masts and None in (from_mast, to_mast))
        or (by_chainage and None in (from_m, to_m))
    ):
        raise click.UsageError("give --from-mast and --to-mast, or --from-m and --to-m")
    performed = _moment(at)
    with app_of(ctx).database() as engine, session_scope(engine) as session:
        found = find_track(session, line, track)
        if by_masts:
            assert from_mast is not None and to_mast is not None
            low, high, masts = mast_stretch(session, found, from_mast, to_mast)
        else:
            assert from_m is not None and to_m is not None
            low, high = sorted((from_m, to_m))
            masts = (None, None)
        recorded = record_maintenance(
            session,
            found,
            kind,
            low,
            high,
            performed,
            by,
            now=_now(),
            mast_from=masts[0],
            mast_to=masts[1],
            wire=wire,
            note=note,
            actor=system_actor(),
        )
    where = f"masts {masts[0]} to {masts[1]} " if masts[0] else ""
    wires = "all wires" if wire is None else f"wire position {wire}"
    resolved = ", ".join(str(i) for i in recorded.resolved)
    click.echo(
        f"recorded {kind} on line {line} track {track}, {where}({low:.1f} to {high:.1f} m), "
        f"{wires}, by {by.strip()} at {performed.isoformat(timespec='seconds')} "
        f"(action {recorded.action.id}): "
        + (f"resolved alert(s) {resolved}" if resolved else "no alert resolved")
    )
