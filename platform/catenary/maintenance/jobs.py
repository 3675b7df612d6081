"""What scheduled jobs do: evaluate the alert rules, deliver notifications, write a report.

Each kind is a plain function of a ``JobContext`` (settings, plugins, a unit of work on the
platform database, a clock), the fire time it was scheduled for, and the job's options from
the config. ``run_job`` is the one callable the scheduler's job store refers to
(``catenary.maintenance.jobs:run_job``, with the kind and options as keywords); the scheduler
service's
executor adds the context and the fire time to each run (``catenary.maintenance.scheduler``), so a
stored job holds no settings, secrets or connections. Names and errors in their log lines go
through ``printable`` (``%r`` for names quoted as such).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass
from datetime import datetime, tzinfo
from pathlib import Path
from typing import Any

from sqlalchemy import Engine
from sqlalchemy.orm import Session

from catenary.config import Settings
from catenary.errors import UserError
from catenary.maintenance.alerts import announce_alerts, evaluate_all
from catenary.maintenance.notifications import deliver_pending
from catenary.maintenance.reports import report_request
from catenary.plugins import PluginRegistry
from catenary.storage.database import session_scope
from catenary.storage.models import utc_now
from catenary.text import printable

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JobContext:
    """What a job needs of the running service."""

    settings: Settings
    registry: PluginRegistry
    engine: Engine
    timezone: tzinfo
    clock: Callable[[], datetime] = utc_now

    def session(self) -> AbstractContextManager[Session]:
        """A unit of work on the platform database (``session_scope``)."""
        return session_scope(self.engine)


def evaluate_alerts(context: JobContext, fire_time: datetime, options: Mapping[str, Any]) -> None:
    """Evaluate the alert rules over the fleet, a track at a time with the new alerts'
    notifications queued in its transaction, then announce the new alerts
    (``catenary_alert_raised``). A track whose evaluation fails is logged by name and left
    pending for the next run; the others are evaluated."""
    evaluation = evaluate_all(context.engine, context.settings, context.registry, context.clock())
    if evaluation is None:
        log.warning("evaluate-alerts: no wear-limit policy ([limits]) nor wire types; skipped")
        return
    announce_alerts(context.engine, context.registry, evaluation.new)
    for failure in evaluation.failed:
        log.error("evaluate-alerts: %s (its runs stay pending)", printable(str(failure)))
    log.info("evaluate-alerts: %s", evaluation.summary())


def deliver_notifications(
    context: JobContext, fire_time: datetime, options: Mapping[str, Any]
) -> None:
    """One delivery pass (``catenary notify deliver``), logged."""
    report = deliver_pending(context.session, context.registry, context.settings, context.clock)
    for channel, reason in report.unavailable.items():
        log.warning(
            "notification channel %r: %s; its notifications wait", channel, printable(reason)
        )
    for attempt in report.attempts:
        if attempt.error is not None:
            retry = "gave up" if attempt.gave_up else f"retry at {attempt.next_attempt_at}"
            log.warning(
                "alert %s to %r: attempt %d failed (%s): %s",
                attempt.alert_id,
                attempt.channel,
                attempt.attempts,
                retry,
                printable(attempt.error),
            )
    sent = sum(attempt.sent for attempt in report.attempts)
    log.info("notifications: %d sent, %d failed", sent, len(report.attempts) - sent)


REPORT_PLACEHOLDERS = ("date", "line")


def output_path(template: str, *, line: str | None, date: str, data_dir: Path) -> Path:
    """A report job's file: ``template`` with ``{line}`` and ``{date}`` filled in, relative to
    the data directory unless absolute."""
    path = Path(template.format(line=line or "all", date=date)).expanduser()
    return path if path.is_absolute() else data_dir / path


def write_report(context: JobContext, fire_time: datetime, options: Mapping[str, Any]) -> None:
    """Write the report ``options["reporter"]`` to ``options["output"]`` (``{date}``: the
    fire time's date in the scheduler's time zone)."""
    reporters = context.registry.reporters()
    name = options["reporter"]
    if name not in reporters:
        known = ", ".join(sorted(reporters)) or "none"
        raise UserError(f"unknown reporter {name!r} (known: {known})")
    line = options.get("line")
    path = output_path(
        options["output"],
        line=line,
        date=fire_time.astimezone(context.timezone).date().isoformat(),
        data_dir=context.settings.data_dir,
    )
    request = report_request(
        context.settings,
        context.registry,
        runs=tuple(options.get("runs", ())),
        line=line,
        track=options.get("track"),
        policy=options.get("policy"),
        options=options.get("options"),
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    with context.registry.boundary("reporter", name):
        written = reporters[name].write(request, path)
    log.info("report %r written to %s", name, printable(str(written)))


JobFunction = Callable[[JobContext, datetime, Mapping[str, Any]], None]

JOBS: dict[str, JobFunction] = {
    "evaluate-alerts": evaluate_alerts,
    "deliver-notifications": deliver_notifications,
    "report": write_report,
}

JOB_OPTIONS: dict[str, tuple[set[str], set[str]]] = {
    "evaluate-alerts": (set(), set()),
    "deliver-notifications": (set(), set()),
    "report": ({"reporter", "output"}, {"line", "track", "policy", "runs", "options"}),
}
"""Each kind's options in ``[[scheduler.jobs]]``: (required, optional)."""


def check_options(kind: str, options: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The options of a job of ``kind``, checked; ``where`` names the job in errors."""
    required, optional = JOB_OPTIONS[kind]
    unknown = sorted(set(options) - required - optional)
    if unknown:
        known = ", ".join(sorted(required | optional))
        takes = f"known for {kind} jobs: {known}" if known else f"{kind} jobs take no options"
        raise UserError(f"{where}: unknown key {unknown[0]} ({takes})")
    missing = sorted(required - set(options))
    if missing:
        raise UserError(f"{where}: {kind} jobs need {missing[0]}")
    for key in ("reporter", "output", "line", "track", "policy"):
        if key in options and (not isinstance(options[key], str) or not options[key]):
            raise UserError(f"{where}: {key} must be a non-empty string, not {options[key]!r}")
    runs = options.get("runs", [])
    if not isinstance(runs, list) or not all(isinstance(run, str) for run in runs):
        raise UserError(f"{where}: runs must be a list of run ids or 'latest', not {runs!r}")
    extra = options.get("options", {})
    if not isinstance(extra, dict) or not all(isinstance(v, str) for v in extra.values()):
        raise UserError(f"{where}: options must be a table of strings, not {extra!r}")
    if "output" in options:
        try:
            output_path(options["output"], line="L", date="2000-01-01", data_dir=Path("."))
        except (KeyError, IndexError, ValueError) as exc:
            known = ", ".join(f"{{{name}}}" for name in REPORT_PLACEHOLDERS)
            raise UserError(
                f"{where}: output {options['output']!r} has a bad placeholder "
                f"({type(exc).__name__}: {exc}; known: {known})"
            ) from None
    return dict(options)


def run_job(
    job: str,
    options: Mapping[str, Any],
    context: JobContext | None = None,
    fire_time: datetime | None = None,
) -> None:
    """Run one scheduled job of kind ``job``: the callable every stored job refers to.

    ``context`` and ``fire_time`` are given by the service's executor at each run, never stored.
    """
    if context is None or fire_time is None:
        raise RuntimeError("catenary.maintenance.jobs.run_job runs under `catenary scheduler` only")
    JOBS[job](context, fire_time, options)
