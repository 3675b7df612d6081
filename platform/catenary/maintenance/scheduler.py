"""The scheduler service (``catenary scheduler``): the config's jobs on APScheduler 3.

Jobs are declared in the config::

    [scheduler]
    timezone = "Europe/Berlin"         # default UTC; cron times are in this zone
    misfire_grace_minutes = 360        # a run late by more is skipped (logged as missed)
    lease_seconds = 30                 # 1 to 45: a standby takes over this long after a crash
    heartbeat_seconds = 10             # 0.1 to lease_seconds / 3 (default: a third of it)

    [[scheduler.jobs]]
    id = "weekly-maintenance-report"   # fixed: the job's key in the job store
    job = "report"                     # evaluate-alerts | deliver-notifications | report
    cron = "0 6 * * 1"                 # or interval_minutes = 15
    reporter = "maintenance"           # report jobs: reporter, output; line, track, policy,
    line = "L1"                        #   runs, options as `catenary report` takes them
    output = "/srv/reports/{line}-{date}.html"

The lease's holder runs a ``BackgroundScheduler`` whose job store is the platform database
(table ``apscheduler_jobs``, made by ``catenary db upgrade``). When it takes the lease every
configured job is written to the store under its id (``replace_existing``): one whose kind,
options and schedule are unchanged keeps its stored trigger and next fire time, so a restart
neither repeats a run nor loses one that fell due while the service was down (it runs once at
start, coalesced, unless later than the grace time); a changed one starts afresh; a job no
longer configured is removed. Every job is coalesced and runs one instance at a time. Runs,
errors and missed runs are logged.

Only one scheduler of a database runs jobs: the holder of its lease (``lease_seconds``, default
30, renewed every ``heartbeat_seconds``, default a third of it; see
``catenary.maintenance.leadership``). Another one started on the same database is a standby: it
logs the holder's host and process and when the lease expires, never writes the job store, and
takes over once the lease expires or is released. A holder that loses its lease pauses its jobs
and becomes a standby. SIGTERM and SIGINT stop the service: no job starts any more, the running
ones finish (the lease still renewed), then the lease is released.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime
from functools import partial
from types import FrameType
from typing import Any
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from apscheduler.events import (
    EVENT_JOB_ERROR,
    EVENT_JOB_EXECUTED,
    EVENT_JOB_MAX_INSTANCES,
    EVENT_JOB_MISSED,
    EVENT_SCHEDULER_RESUMED,
    EVENT_SCHEDULER_STARTED,
)
from apscheduler.executors.pool import ThreadPoolExecutor
from apscheduler.job import Job
from apscheduler.jobstores.sqlalchemy import SQLAlchemyJobStore
from apscheduler.schedulers.background import BackgroundScheduler
from apscheduler.schedulers.base import STATE_RUNNING, BaseScheduler
from apscheduler.triggers.cron import CronTrigger
from apscheduler.triggers.interval import IntervalTrigger
from sqlalchemy import Engine

from catenary.config import Settings
from catenary.errors import UserError
from catenary.maintenance.jobs import JOBS, JobContext, check_options, run_job
from catenary.maintenance.leadership import (
    HEARTBEATS_PER_LEASE,
    LEASE_SECONDS_RANGE,
    MIN_HEARTBEAT_SECONDS,
    Leadership,
    LeaseTiming,
)
from catenary.plugins import PluginFailure, PluginRegistry
from catenary.storage.database import DATABASE_ERRORS, one_line, open_database
from catenary.storage.models import utc_now
from catenary.text import printable

log = logging.getLogger(__name__)

JOB_TABLE = "apscheduler_jobs"
ID_LENGTH = 191  # the job store's id column
DEFAULT_TIMEZONE = "UTC"
DEFAULT_MISFIRE_GRACE_MINUTES = 360.0
WORKERS = 4
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)

_SECTION_KEYS = {"timezone", "misfire_grace_minutes", "lease_seconds", "heartbeat_seconds", "jobs"}
_JOB_KEYS = {"id", "job", "cron", "interval_minutes"}


@dataclass(frozen=True)
class JobSpec:
    """One configured job: its fixed id, kind, options and schedule (cron or interval)."""

    id: str
    job: str
    options: Mapping[str, Any]
    cron: str | None = None
    interval_minutes: float | None = None

    def trigger(self, timezone: ZoneInfo) -> CronTrigger | IntervalTrigger:
        if self.cron is not None:
            return CronTrigger.from_crontab(self.cron, timezone=timezone)
        return IntervalTrigger(minutes=self.interval_minutes, timezone=timezone)

    def description(self, timezone: ZoneInfo) -> str:
        """The kind and schedule in words; a stored job with another is rescheduled."""
        if self.cron is not None:
            return f"{self.job} at cron '{self.cron}' ({timezone.key})"
        return f"{self.job} every {self.interval_minutes:g} min"

    def kwargs(self) -> dict[str, Any]:
        """``run_job``'s stored keywords."""
        return {"job": self.job, "options": dict(self.options)}


@dataclass(frozen=True)
class SchedulerConfig:
    """The ``[scheduler]`` section."""

    timezone: ZoneInfo
    misfire_grace_minutes: float = DEFAULT_MISFIRE_GRACE_MINUTES
    jobs: tuple[JobSpec, ...] = ()
    lease: LeaseTiming = field(default_factory=LeaseTiming)


def _positive(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or value <= 0:
        raise UserError(f"{where}: {key} must be a positive number, not {value!r}")
    return float(value)


def _within(where: str, key: str, value: Any, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not low <= value <= high:
        raise UserError(f"{where}: {key} must be a number from {low:g} to {high:g}, not {value!r}")
    return float(value)


def _lease_timing(where: str, section: Mapping[str, Any]) -> LeaseTiming:
    lease = section.get("lease_seconds", LeaseTiming.lease_s)
    lease = _within(where, "scheduler.lease_seconds", lease, *LEASE_SECONDS_RANGE)
    most = lease / HEARTBEATS_PER_LEASE
    heartbeat = section.get("heartbeat_seconds", most)
    heartbeat = _within(
        where,
        "scheduler.heartbeat_seconds (lease_seconds / 3 at most)",
        heartbeat,
        MIN_HEARTBEAT_SECONDS,
        most,
    )
    return LeaseTiming(lease, heartbeat)


def _job(where: str, number: int, item: Any, timezone: ZoneInfo) -> JobSpec:
    label = f"scheduler.jobs[{number}]"
    if not isinstance(item, dict):
        raise UserError(f"{where}: {label} must be a table ([[scheduler.jobs]])")
    job_id = item.get("id")
    if not isinstance(job_id, str) or not 0 < len(job_id) <= ID_LENGTH:
        raise UserError(
            f"{where}: {label}.id must be a string of 1 to {ID_LENGTH} characters, not {job_id!r}"
        )
    label = f"scheduler job {job_id!r}"
    kind = item.get("job")
    if kind not in JOBS:
        raise UserError(f"{where}: {label}: unknown job {kind!r} (known: {', '.join(JOBS)})")
    options = {key: value for key, value in item.items() if key not in _JOB_KEYS}
    options = check_options(kind, options, f"{where}: {label}")
    cron, interval = item.get("cron"), item.get("interval_minutes")
    if (cron is None) == (interval is None):
        raise UserError(f"{where}: {label}: give cron or interval_minutes (one of them)")
    if cron is not None:
        if not isinstance(cron, str):
            raise UserError(f"{where}: {label}: cron must be a string, not {cron!r}")
        try:
            CronTrigger.from_crontab(cron, timezone=timezone)
        except ValueError as exc:
            raise UserError(f"{where}: {label}: invalid cron {cron!r}: {exc}") from None
        return JobSpec(job_id, kind, options, cron=cron)
    minutes = _positive(where, f"{label}: interval_minutes", interval)
    return JobSpec(job_id, kind, options, interval_minutes=minutes)


def scheduler_config(settings: Settings) -> SchedulerConfig:
    """The ``[scheduler]`` section of ``settings``; a malformed one is a one-line
    ``UserError`` naming the config file, the job and the key."""
    where = str(settings.config_path or "config")
    section = settings.sections.get("scheduler", {})
    if not isinstance(section, dict):
        raise UserError(f"{where}: [scheduler] must be a table")
    unknown = sorted(set(section) - _SECTION_KEYS)
    if unknown:
        known = ", ".join(sorted(_SECTION_KEYS))
        raise UserError(f"{where}: unknown key scheduler.{unknown[0]} (known: {known})")
    name = section.get("timezone", DEFAULT_TIMEZONE)
    try:
        timezone = ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError, TypeError):
        raise UserError(f"{where}: scheduler.timezone: unknown time zone {name!r}") from None
    grace = section.get("misfire_grace_minutes", DEFAULT_MISFIRE_GRACE_MINUTES)
    grace = _positive(where, "scheduler.misfire_grace_minutes", grace)
    items = section.get("jobs", [])
    if not isinstance(items, list):
        raise UserError(f"{where}: scheduler.jobs must be an array of tables")
    jobs = tuple(_job(where, number, item, timezone) for number, item in enumerate(items, 1))
    ids = [job.id for job in jobs]
    for job_id in ids:
        if ids.count(job_id) > 1:
            raise UserError(f"{where}: two scheduler jobs have the id {job_id!r}")
    return SchedulerConfig(timezone, grace, jobs, _lease_timing(where, section))


class ServiceExecutor(ThreadPoolExecutor):  # type: ignore[misc]
    """Runs each job with the service's context and the fire time it was scheduled for.

    The stored job keeps only its kind and options; the context and fire time are added to a
    copy of it at each submission. Jobs are coalesced: one run per submission, for the latest
    fire time due.
    """

    def __init__(self, context: JobContext) -> None:
        super().__init__(max_workers=WORKERS)
        self._context = context

    def _do_submit_job(self, job: Job, run_times: list[datetime]) -> None:
        fire_time = run_times[-1]
        timed = Job.__new__(Job)
        state = job.__getstate__()
        state["kwargs"] = {**job.kwargs, "context": self._context, "fire_time": fire_time}
        timed.__setstate__(state)
        timed._scheduler = job._scheduler
        timed._jobstore_alias = job._jobstore_alias
        super()._do_submit_job(timed, [fire_time])


def _traceback(text: str) -> str:
    """A job's traceback for the log: its lines kept, control characters in them escaped."""
    return "\n".join(printable(line) for line in text.rstrip("\n").split("\n"))


def log_job_event(event: Any) -> None:
    """Log a run, an error, a missed run or a skipped one (an APScheduler listener).

    Job ids are logged with ``%r`` and error messages through ``printable``: a name from the
    config or the database cannot forge a log line or reach a terminal as an escape sequence.
    """
    if event.code == EVENT_JOB_MAX_INSTANCES:
        times = ", ".join(t.isoformat() for t in event.scheduled_run_times)
        log.warning("job %r is still running: its run at %s is skipped", event.job_id, times)
        return
    fire_time = event.scheduled_run_time.isoformat()
    if event.code == EVENT_JOB_EXECUTED:
        log.info("job %r ran for %s", event.job_id, fire_time)
    elif event.code == EVENT_JOB_MISSED:
        log.warning(
            "job %r missed its run at %s (later than the misfire grace time)",
            event.job_id,
            fire_time,
        )
    elif isinstance(event.exception, PluginFailure):  # a plugin's own error: where it was
        log.error(
            "job %r failed for %s: %s\n%s",
            event.job_id,
            fire_time,
            printable(str(event.exception)),
            _traceback(event.traceback),
        )
    elif isinstance(event.exception, UserError):
        log.error(
            "job %r failed for %s: %s", event.job_id, fire_time, printable(str(event.exception))
        )
    else:
        text = " ".join(str(event.exception).split())
        log.error(
            "job %r failed for %s: %s: %s\n%s",
            event.job_id,
            fire_time,
            type(event.exception).__name__,
            printable(text),
            _traceback(event.traceback),
        )


class LeasedScheduler(BackgroundScheduler):  # type: ignore[misc]
    """A background scheduler that looks for due jobs only while ``holds()`` says this process
    holds the lease; otherwise it looks again ``recheck_s`` later (nothing in the store is
    touched meanwhile, so a run due then stays due for the holder)."""

    def __init__(self, holds: Callable[[], bool], recheck_s: float, **options: Any) -> None:
        self._holds = holds
        self._recheck_s = recheck_s
        self._processing = threading.Lock()  # held by a pass looking for due jobs
        super().__init__(**options)

    def _process_jobs(self) -> float | None:
        if not self._holds():
            return self._recheck_s
        with self._processing:
            if self.state != STATE_RUNNING:  # paused, or stopped by a shutdown under way
                return None
            wait_s: float | None = super()._process_jobs()
        return wait_s

    def pause(self) -> None:
        """Pause, and return once a pass that was already looking for due jobs has submitted
        them (else a shutdown right after could close the executor under it). A pass that
        starts later submits nothing: ``shutdown`` marks the scheduler stopped before it
        closes the executor, and a pass looks at that under the same lock."""
        super().pause()
        with self._processing:
            pass


def make_scheduler(
    engine: Engine,
    config: SchedulerConfig,
    context: JobContext,
    scheduler_class: Callable[..., BaseScheduler] = BackgroundScheduler,
) -> tuple[BaseScheduler, SQLAlchemyJobStore]:
    """A scheduler with its job store in ``engine``'s database, not started."""
    store = SQLAlchemyJobStore(engine=engine, tablename=JOB_TABLE)
    scheduler = scheduler_class(
        jobstores={"default": store},
        executors={"default": ServiceExecutor(context)},
        job_defaults={
            "coalesce": True,
            "max_instances": 1,
            "misfire_grace_time": max(1, round(config.misfire_grace_minutes * 60)),
        },
        timezone=config.timezone,
    )
    scheduler.add_listener(
        log_job_event,
        EVENT_JOB_EXECUTED | EVENT_JOB_ERROR | EVENT_JOB_MISSED | EVENT_JOB_MAX_INSTANCES,
    )
    return scheduler, store


def sync_jobs(scheduler: BaseScheduler, store: SQLAlchemyJobStore, config: SchedulerConfig) -> None:
    """Write the configured jobs to the store and remove the others.

    Call before ``scheduler.start()`` (or ``resume()``). A stored job of the same name (id, kind
    and schedule) and options keeps its trigger and next fire time.
    """
    stored = {job.id: job for job in store.get_all_jobs()}
    for spec in config.jobs:
        name = f"{spec.id}: {spec.description(config.timezone)}"
        kwargs = spec.kwargs()
        old = stored.pop(spec.id, None)
        kept = (
            old is not None
            and (old.name, old.kwargs, old.func) == (name, kwargs, run_job)
            and old.next_run_time is not None
        )
        if kept:
            trigger, extra = old.trigger, {"next_run_time": old.next_run_time}
        else:
            trigger, extra = spec.trigger(config.timezone), {}
        scheduler.add_job(
            run_job, trigger, id=spec.id, name=name, kwargs=kwargs, replace_existing=True, **extra
        )
        log.info("job %s (%s)", printable(name), "kept" if kept else "scheduled afresh")
    for job_id in stored:
        store.remove_job(job_id)
        log.info("job %r removed: it is no longer in the config", job_id)


class _StopSignal:
    """SIGTERM or SIGINT, received: the handler only sets an event, so the service's loop is
    never interrupted halfway through a transaction."""

    def __init__(self) -> None:
        self.received = threading.Event()
        self.name = "a signal"

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.name = signal.Signals(signum).name
        self.received.set()

    @contextmanager
    def handled(self) -> Iterator[None]:
        previous = {sig: signal.signal(sig, self._handle) for sig in STOP_SIGNALS}
        try:
            yield
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


def _log_start(scheduler: BaseScheduler, config: SchedulerConfig) -> Callable[[Any], None]:
    def log_start(event: Any) -> None:  # in start() or resume(), before any job is looked at
        verb = "started" if event.code == EVENT_SCHEDULER_STARTED else "resumed"
        zone = config.timezone.key
        log.info("scheduler %s: %d job(s), time zone %s", verb, len(config.jobs), zone)
        for job in scheduler.get_jobs():
            log.info("job %r next runs at %s", job.id, job.next_run_time.isoformat())

    return log_start


def _start_jobs(
    scheduler: BaseScheduler, store: SQLAlchemyJobStore, config: SchedulerConfig
) -> None:
    sync_jobs(scheduler, store, config)
    if scheduler.running:
        scheduler.resume()
    else:
        scheduler.start()


def _lead(
    scheduler: BaseScheduler,
    store: SQLAlchemyJobStore,
    config: SchedulerConfig,
    leadership: Leadership,
    stop: threading.Event,
) -> None:
    """Run the jobs while this process holds the lease, renewing it at each heartbeat, until
    ``stop`` is set or the lease is lost (then the jobs are paused)."""
    started = False
    while True:
        if not started:
            try:
                _start_jobs(scheduler, store, config)
                started = True
            except DATABASE_ERRORS as exc:
                log.warning(
                    "jobs not started (%s): trying again at the next heartbeat",
                    printable(one_line(exc)),
                )
        if stop.wait(leadership.next_beat_s()):
            return
        if not leadership.renew():
            if scheduler.running:
                scheduler.pause()
            return


def _finish(scheduler: BaseScheduler, leadership: Leadership) -> None:
    """Stop the scheduler: no job starts any more; the running ones finish while the lease is
    still renewed (a standby cannot start them a second time meanwhile)."""
    scheduler.pause()
    finishing = threading.Thread(target=scheduler.shutdown, name="scheduler-finish")
    finishing.start()
    while finishing.is_alive():
        finishing.join(leadership.next_beat_s())
        if finishing.is_alive():
            leadership.renew()


def _check_reporters(config: SchedulerConfig, registry: PluginRegistry) -> None:
    reporters = registry.reporters()
    for spec in config.jobs:
        if spec.job == "report" and spec.options["reporter"] not in reporters:
            log.warning(
                "job %r: unknown reporter %r (known: %s): it fails until one is installed",
                spec.id,
                spec.options["reporter"],
                ", ".join(sorted(reporters)) or "none",
            )


def serve(
    settings: Settings, registry: PluginRegistry, *, clock: Callable[[], datetime] = utc_now
) -> None:
    """Run the scheduler until SIGTERM or SIGINT: the body of ``catenary scheduler``.

    A standby until this process holds the lease, then the jobs' runner until it loses the lease
    (a standby again) or a signal stops it.
    """
    config = scheduler_config(settings)
    # jobs are batch work: no statement timeout, whatever database a job opens
    settings = dataclasses.replace(settings, statement_timeout_s=None)
    with open_database(settings) as engine:
        context = JobContext(settings, registry, engine, config.timezone, clock)
        leadership = Leadership(engine, config.lease)
        scheduler_class = partial(LeasedScheduler, leadership.holds, config.lease.heartbeat_s)
        scheduler, store = make_scheduler(engine, config, context, scheduler_class)
        if not config.jobs:
            where = printable(str(settings.config_path))
            log.warning("no jobs configured ([[scheduler.jobs]] in %s)", where)
        _check_reporters(config, registry)
        scheduler.add_listener(
            _log_start(scheduler, config), EVENT_SCHEDULER_STARTED | EVENT_SCHEDULER_RESUMED
        )
        stop = _StopSignal()
        with stop.handled():
            while leadership.wait_for_lease(stop.received):
                _lead(scheduler, store, config, leadership, stop.received)
                if stop.received.is_set():
                    break
            log.info("%s received: stopping once the running jobs finish", stop.name)
            if scheduler.running:
                _finish(scheduler, leadership)
            leadership.release()
    log.info("scheduler stopped")
