"""The scheduler in-process (a ``BackgroundScheduler`` on the same job store and executor):
jobs kept, rescheduled and removed from the store as the config says; each kind of job; runs,
errors and missed runs logged."""

from __future__ import annotations

import logging
import pickle
import re
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from datetime import UTC, datetime, timedelta
from functools import partial
from typing import Any

import pytest
from apscheduler.events import EVENT_JOB_ERROR, EVENT_JOB_EXECUTED, JobExecutionEvent
from apscheduler.schedulers.background import BackgroundScheduler
from sqlalchemy import Engine, select, text

from catenary.config import Settings
from catenary.errors import UserError
from catenary.maintenance import jobs
from catenary.maintenance.jobs import JobContext, run_job
from catenary.maintenance.scheduler import (
    LeasedScheduler,
    log_job_event,
    make_scheduler,
    scheduler_config,
    sync_jobs,
)
from catenary.plugins import PluginFailure, PluginRegistry
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AlertNotification, Line, Run, Track

FIRE = datetime(2024, 5, 6, 22, 30, tzinfo=UTC)


def job(id: str, kind: str, **fields: Any) -> dict[str, Any]:
    return {"id": id, "job": kind, **fields}


def report(id: str = "r", **fields: Any) -> dict[str, Any]:
    values = {"reporter": "fake", "output": "reports/{line}-{date}.txt", "line": "L1"}
    return job(id, "report", **(values | fields))


@pytest.fixture
def started(
    engine: Engine, registry: PluginRegistry
) -> Iterator[Callable[..., BackgroundScheduler]]:
    """``started(settings, paused=True)``: a scheduler as the service makes it, running in the
    background; shut down at the end of the test."""
    running: list[BackgroundScheduler] = []

    def start(settings: Settings, *, paused: bool = True) -> BackgroundScheduler:
        config = scheduler_config(settings)
        context = JobContext(settings, registry, engine, config.timezone)
        scheduler, store = make_scheduler(engine, config, context, BackgroundScheduler)
        sync_jobs(scheduler, store, config)
        scheduler.start(paused=paused)
        running.append(scheduler)
        return scheduler

    yield start
    for scheduler in running:
        if scheduler.running:
            scheduler.shutdown()


def stored(engine: Engine) -> dict[str, dict[str, Any]]:
    with engine.connect() as connection:
        rows = connection.execute(text("SELECT id, job_state FROM apscheduler_jobs")).all()
    return {row.id: pickle.loads(row.job_state) for row in rows}


def wait_for(condition: Callable[[], Any], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.05)


def test_a_restart_keeps_a_job_and_its_next_fire_time(
    make_settings: Any, started: Any, engine: Engine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "catenary.maintenance.scheduler")
    settings = make_settings(
        {
            "scheduler": {
                "jobs": [report(interval_minutes=60), job("d", "evaluate-alerts", cron="0 6 * * 1")]
            }
        }
    )
    first = started(settings)
    before = {j.id: j.next_run_time for j in first.get_jobs()}
    first.shutdown()
    time.sleep(0.05)

    second = started(settings)
    assert {j.id: j.next_run_time for j in second.get_jobs()} == before
    assert "job r: report every 60 min (kept)" in caplog.messages
    assert "job d: evaluate-alerts at cron '0 6 * * 1' (UTC) (kept)" in caplog.messages
    second.shutdown()

    # the store holds the job's kind and options, nothing of the service
    state = stored(engine)["r"]
    assert state["func"] == "catenary.maintenance.jobs:run_job"
    options = {"reporter": "fake", "output": "reports/{line}-{date}.txt", "line": "L1"}
    assert state["kwargs"] == {"job": "report", "options": options}
    assert (state["coalesce"], state["max_instances"], state["misfire_grace_time"]) == (
        True,
        1,
        6 * 3600,
    )


def test_a_changed_job_is_rescheduled_and_a_removed_one_removed(
    make_settings: Any, started: Any, engine: Engine
) -> None:
    first = started(
        make_settings(
            {
                "scheduler": {
                    "jobs": [
                        report(interval_minutes=60),
                        job("d", "evaluate-alerts", cron="0 6 * * 1"),
                    ]
                }
            }
        )
    )
    before = first.get_job("r").next_run_time
    first.shutdown()

    second = started(make_settings({"scheduler": {"jobs": [report(interval_minutes=600)]}}))
    assert [j.id for j in second.get_jobs()] == ["r"]
    assert second.get_job("r").next_run_time - before > timedelta(hours=8)
    second.shutdown()
    assert set(stored(engine)) == {"r"}

    third = started(
        make_settings({"scheduler": {"jobs": [report(interval_minutes=600, line="L2")]}})
    )
    assert third.get_job("r").kwargs["options"]["line"] == "L2"  # options changed: replaced
    third.shutdown()

    started(make_settings({})).shutdown()
    assert stored(engine) == {}


def test_a_report_job_runs_with_its_fire_time(
    make_settings: Any, started: Any, fakes: Any, tmp_path: Any
) -> None:
    settings = make_settings(
        {"scheduler": {"timezone": "Asia/Tokyo", "jobs": [report(interval_minutes=60)]}}
    )
    scheduler = started(settings, paused=False)
    fire = datetime.now(UTC).replace(microsecond=0) - timedelta(seconds=1)
    scheduler.modify_job("r", next_run_time=fire)
    scheduler.wakeup()
    wait_for(lambda: fakes.reports)
    wait_for(lambda: scheduler.get_job("r").next_run_time > fire)
    assert scheduler.get_job("r").next_run_time == fire + timedelta(hours=1)

    ((request, path),) = fakes.reports
    date = fire.astimezone(scheduler.timezone).date().isoformat()
    assert path == settings.data_dir / "reports" / f"L1-{date}.txt"
    assert path.parent.is_dir()
    assert (request.line, request.track, request.runs) == ("L1", None, ())
    assert request.settings is settings


def test_job_errors_and_missed_runs_are_logged(
    make_settings: Any, started: Any, fakes: Any, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "catenary.maintenance.scheduler")
    settings = make_settings(
        {
            "scheduler": {
                "misfire_grace_minutes": 0.05,
                "jobs": [
                    report("boom", interval_minutes=60),
                    report("unknown", interval_minutes=60, reporter="nope"),
                    report("late", interval_minutes=600),
                ],
            }
        }
    )
    fakes.error = RuntimeError("disk\nfull")
    scheduler = started(settings, paused=False)
    now = datetime.now(UTC)
    scheduler.modify_job("boom", next_run_time=now)
    scheduler.modify_job("unknown", next_run_time=now)
    scheduler.modify_job("late", next_run_time=now - timedelta(hours=1))
    scheduler.wakeup()

    def logged(start: str) -> list[logging.LogRecord]:
        return [r for r in caplog.records if r.getMessage().startswith(start)]

    wait_for(
        lambda: logged("job 'boom' failed") and logged("job 'unknown'") and logged("job 'late'")
    )
    (boom,) = logged("job 'boom' failed")
    assert boom.levelno == logging.ERROR
    first_line, trace = boom.getMessage().split("\n", 1)
    assert first_line == (
        f"job 'boom' failed for {now.isoformat()}: reporter 'fake' of plugin 'fakes' failed: "
        "RuntimeError: disk full"
    )
    assert "in write" in trace  # the traceback of an unexpected error
    (unknown,) = logged("job 'unknown'")
    assert unknown.getMessage() == (
        f"job 'unknown' failed for {now.isoformat()}: unknown reporter 'nope' (known: fake)"
    )
    (late,) = logged("job 'late'")
    assert late.levelno == logging.WARNING
    assert late.getMessage() == (
        f"job 'late' missed its run at {(now - timedelta(hours=1)).isoformat()} "
        "(later than the misfire grace time)"
    )
    assert fakes.reports == []


def test_one_instance_at_a_time(
    make_settings: Any, started: Any, fakes: Any, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, "catenary.maintenance.scheduler")
    scheduler = started(
        make_settings({"scheduler": {"jobs": [report(interval_minutes=60)]}}), paused=False
    )
    fakes.hold = threading.Event()
    first = datetime.now(UTC)
    scheduler.modify_job("r", next_run_time=first)
    scheduler.wakeup()
    wait_for(lambda: scheduler.get_job("r").next_run_time > first)  # running, held
    second = datetime.now(UTC)
    scheduler.modify_job("r", next_run_time=second)
    scheduler.wakeup()
    wait_for(lambda: any("still running" in m for m in caplog.messages))
    assert f"job 'r' is still running: its run at {second.isoformat()} is skipped" in (
        caplog.messages
    )
    fakes.hold.set()
    wait_for(lambda: any(m.startswith("job 'r' ran for") for m in caplog.messages))
    assert len(fakes.reports) == 1


def test_a_leased_scheduler_starts_no_job_while_its_process_does_not_hold_the_lease(
    make_settings: Any, engine: Engine, registry: PluginRegistry, fakes: Any
) -> None:
    holds = threading.Event()  # what the service's Leadership.holds says
    settings = make_settings({"scheduler": {"jobs": [report(interval_minutes=60)]}})
    config = scheduler_config(settings)
    context = JobContext(settings, registry, engine, config.timezone)
    leased = partial(LeasedScheduler, holds.is_set, 0.05)
    scheduler, store = make_scheduler(engine, config, context, leased)
    sync_jobs(scheduler, store, config)
    scheduler.start()
    try:
        due = datetime.now(UTC)
        scheduler.modify_job("r", next_run_time=due)
        scheduler.wakeup()
        time.sleep(0.5)
        assert fakes.reports == []
        assert scheduler.get_job("r").next_run_time == due  # still due, for the holder
        holds.set()
        wait_for(lambda: fakes.reports)
    finally:
        scheduler.shutdown()


@pytest.fixture
def context(engine: Engine, registry: PluginRegistry, make_settings: Any) -> JobContext:
    settings = make_settings({"notifications": {"channels": [{"notifier": "fake"}]}})
    return JobContext(settings, registry, engine, UTC, clock=lambda: FIRE + timedelta(seconds=2))


def test_evaluate_alerts_skips_without_a_policy_nor_wire_types(
    context: JobContext, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.WARNING, "catenary.maintenance.jobs"):
        run_job("evaluate-alerts", {}, context, FIRE)
    assert caplog.messages == [
        "evaluate-alerts: no wear-limit policy ([limits]) nor wire types; skipped"
    ]


def test_evaluate_alerts_without_a_policy_uses_the_standard_limits(
    context: JobContext, fakes: Any, fleet_of: Any, caplog: pytest.LogCaptureFixture
) -> None:
    context = replace(context, registry=PluginRegistry(plugins=[("fakes", fakes)]))
    with session_scope(context.engine) as session:
        fleet = fleet_of(session)
        # CTA120 has no published minimum: the 30 % rule, 8.75 mm; one span at 8.6 mm
        fleet.run(fleet.track(), FIRE - timedelta(days=1), {3: 8.6, 4: 8.9})
    with caplog.at_level(logging.INFO, "catenary.maintenance.jobs"):
        run_job("evaluate-alerts", {}, context, FIRE)
    assert caplog.messages == ["evaluate-alerts: 1 new (1 critical), 0 updated, 0 resolved"]
    with session_scope(context.engine) as session:
        (alert,) = session.scalars(select(Alert)).all()
        assert (alert.level, alert.kind) == ("critical", "threshold")
        assert alert.details["policy"] == "standard-limits"
        assert alert.threshold == pytest.approx(8.75, abs=0.01)


def test_evaluate_alerts_queues_the_new_alerts_in_the_same_transaction(
    context: JobContext, fakes: Any, fleet_of: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    registry = PluginRegistry(plugins=[("fakes", fakes)])  # the built-in wire types too
    settings = replace(
        context.settings,
        sections={**context.settings.sections, "limits": {"policy": "manufacturer-30pct"}},
    )
    context = replace(context, settings=settings, registry=registry)
    with session_scope(context.engine) as session:
        fleet = fleet_of(session)
        fleet.run(fleet.track(), FIRE - timedelta(days=1), {3: 8.6})  # below 8.75 mm
    announced: list[list[int]] = []
    monkeypatch.setattr(
        jobs, "announce_alerts", lambda engine, registry, ids: announced.append(ids)
    )
    run_job("evaluate-alerts", {}, context, FIRE)
    with session_scope(context.engine) as session:
        (row,) = session.scalars(select(AlertNotification)).all()
        assert (row.notifier, row.status) == ("fake", "pending")
        (evaluated_at,) = session.scalars(select(Run.alerts_evaluated_at)).all()
    assert evaluated_at == FIRE + timedelta(seconds=2)  # the context's clock
    assert announced == [[row.alert_id]]


def add_alert(engine: Engine) -> None:
    with session_scope(engine) as session:
        session.add(
            Alert(
                track=Track(line=Line(code="L1"), code="1"),
                wire=0,
                start_chainage_m=0.0,
                end_chainage_m=50.0,
                rule="r",
                level="plan",
                kind="forecast",
                value=9.0,
                threshold=8.5,
                condition_key="k",
            )
        )


def test_deliver_notifications_job(
    context: JobContext, fakes: Any, caplog: pytest.LogCaptureFixture
) -> None:
    add_alert(context.engine)
    with caplog.at_level(logging.INFO, "catenary.maintenance.jobs"):
        run_job("deliver-notifications", {}, context, FIRE)
    assert [alert.condition_key for alert in fakes.sent] == ["k"]
    assert caplog.messages == ["notifications: 1 sent, 0 failed"]


HOSTILE = "L\x1b]0;owned\x07\r\n2024-05-06 INFO forged\x9b2J"
ESCAPED = "L\\x1b]0;owned\\x07\\r\\n2024-05-06 INFO forged\\x9b2J"


CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")


def test_the_jobs_escape_names_and_errors_in_their_log_lines(
    context: JobContext, fakes: Any, caplog: pytest.LogCaptureFixture
) -> None:
    add_alert(context.engine)
    fakes.send_error = RuntimeError(f"no route to {HOSTILE}")
    with caplog.at_level(logging.INFO, "catenary.maintenance.jobs"):
        run_job("deliver-notifications", {}, context, FIRE)
        run_job("report", {"reporter": "fake", "output": f"{HOSTILE}.txt"}, context, FIRE)
    failed, summary, written = caplog.messages
    assert failed.startswith("alert 1 to 'fake': attempt 1 failed (retry at ")
    # the delivery's error is one line already (its CR LF a space); its other controls escaped
    assert failed.endswith("no route to " + ESCAPED.replace(r"\r\n", " "))
    assert summary == "notifications: 0 sent, 1 failed"
    assert written == f"report 'fake' written to {context.settings.data_dir}/{ESCAPED}.txt"
    assert not any(CONTROL.search(message) for message in caplog.messages)


def test_job_events_escape_the_names_and_errors_they_log(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def failed(exception: BaseException) -> JobExecutionEvent:
        trace = '  File "x\x1b]0;owned\x07.py", line 1\n    f()\n'  # its lines are kept
        return JobExecutionEvent(
            EVENT_JOB_ERROR, f"j{HOSTILE}", "default", FIRE, exception=exception, traceback=trace
        )

    caplog.set_level(logging.INFO, "catenary.maintenance.scheduler")
    log_job_event(JobExecutionEvent(EVENT_JOB_EXECUTED, f"j{HOSTILE}", "default", FIRE))
    log_job_event(failed(UserError(f"unknown line {HOSTILE}")))
    log_job_event(failed(PluginFailure("reporter 'fake'", f"OSError: {HOSTILE}")))
    log_job_event(failed(RuntimeError(HOSTILE)))
    ran, user, plugin, other = caplog.messages
    job = repr(f"j{HOSTILE}")
    assert ran == f"job {job} ran for {FIRE.isoformat()}"
    assert user == f"job {job} failed for {FIRE.isoformat()}: unknown line {ESCAPED}"
    assert plugin == (
        f"job {job} failed for {FIRE.isoformat()}: reporter 'fake' failed: OSError: {ESCAPED}\n"
        '  File "x\\x1b]0;owned\\x07.py", line 1\n    f()'
    )
    assert other.startswith(f"job {job} failed for {FIRE.isoformat()}: RuntimeError: L\\x1b")
    for message in caplog.messages:
        first, *trace = message.split("\n")
        assert not CONTROL.search(first), first
        assert all(not CONTROL.search(line) for line in trace), trace


def test_run_job_needs_the_service() -> None:
    with pytest.raises(RuntimeError, match="runs under `catenary scheduler` only"):
        run_job("report", {})


def test_an_unknown_reporter_is_a_user_error(context: JobContext) -> None:
    with pytest.raises(UserError, match=r"^unknown reporter 'nope' \(known: fake\)$"):
        run_job("report", {"reporter": "nope", "output": "x"}, context, FIRE)
