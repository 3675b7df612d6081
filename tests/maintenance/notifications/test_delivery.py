"""The delivery of alert notifications: queued once, sent when due, retried with backoff, never
lost, with notifiers that fail, raise or hang (fake notifiers registered as a plugin)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import Engine, select

from catenary.config import Settings
from catenary.errors import UserError
from catenary.maintenance.notifications import (
    deliver_pending,
    notification_config,
    queue_notifications,
)
from catenary.plugins import AlertRecord, PluginRegistry, hookimpl
from catenary.plugins.types import Notifier
from catenary.storage.database import make_engine, session_scope
from catenary.storage.models import Alert, AlertNotification


class Fake:
    """Notifiers ``fake`` (fails while ``failures`` > 0) and ``hang`` (waits for ``release``)."""

    def __init__(self) -> None:
        self.sent: list[tuple[dict[str, Any], dict[str, Any]]] = []
        self.failures = 0
        self.release = threading.Event()
        self.during_send: Callable[[], None] | None = None

    def send(self, alert: AlertRecord, settings: Mapping[str, Any]) -> None:
        if self.during_send is not None:
            self.during_send()
        if self.failures > 0:
            self.failures -= 1
            raise RuntimeError("relay\nunavailable")
        self.sent.append((alert.as_json(), dict(settings)))

    def hang(self, alert: AlertRecord, settings: Mapping[str, Any]) -> None:
        self.release.wait(30)

    @hookimpl
    def catenary_notifiers(self) -> list[Notifier]:
        return [Notifier("fake", "records", self.send), Notifier("hang", "hangs", self.hang)]


@pytest.fixture
def fake() -> Any:
    notifiers = Fake()
    yield notifiers
    notifiers.release.set()


@pytest.fixture
def registry(fake: Fake) -> PluginRegistry:
    return PluginRegistry(autoload=False, plugins=[("fakes", fake)])


def config(*channels: dict[str, Any], **section: Any) -> dict[str, Any]:
    return {"notifications": {**section, "channels": list(channels)}}


def rows(engine: Engine) -> list[AlertNotification]:
    with session_scope(engine) as session:
        return list(session.scalars(select(AlertNotification).order_by(AlertNotification.id)))


def deliver(engine: Engine, registry: PluginRegistry, settings: Settings, clock: Any) -> Any:
    return deliver_pending(lambda: session_scope(engine), registry, settings, clock)


def test_queue_is_idempotent_and_follows_levels(
    engine: Engine, alerts: Any, make_settings: Any
) -> None:
    urgent = alerts("a", level="urgent")
    critical = alerts("b", level="critical")
    alerts("c", level="critical", status="acknowledged")  # someone already knows
    alerts("d", level="plan", status="resolved")
    settings = make_settings(
        config(
            {"name": "pager", "notifier": "fake", "levels": ["critical"]},
            {"name": "mail", "notifier": "fake"},
        )
    )
    channels = notification_config(settings)
    with session_scope(engine) as session:
        assert queue_notifications(session, channels) == 3
    with session_scope(engine) as session:
        assert queue_notifications(session, channels) == 0
    found = sorted((row.alert_id, row.notifier, row.status, row.attempts) for row in rows(engine))
    assert found == sorted(
        [
            (critical, "pager", "pending", 0),
            (urgent, "mail", "pending", 0),
            (critical, "mail", "pending", 0),
        ]
    )


def test_queue_in_the_alerts_transaction(engine: Engine, make_settings: Any, alert_in: Any) -> None:
    """Deliveries are queued in the transaction that raises the alerts, and go with it."""
    channels = notification_config(make_settings(config({"notifier": "fake"})))
    with session_scope(engine) as session:
        alert_in(session, "same-transaction")
        assert queue_notifications(session, channels) == 1
        session.rollback()  # the alert goes, and its delivery with it
    assert rows(engine) == []


def test_sent_once_with_the_alert_and_the_channel_settings(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    fake: Fake,
    clock: Any,
) -> None:
    alert_id = alerts("a", details={"forecast_date": "2025-01-31"})
    settings = make_settings(config({"notifier": "fake", "settings": {"to": "ops"}}))

    report = deliver(engine, registry, settings, clock)
    assert report.queued == 1
    assert [(a.alert_id, a.channel, a.sent) for a in report.attempts] == [(alert_id, "fake", True)]
    (row,) = rows(engine)
    assert (row.status, row.attempts, row.last_error, row.next_attempt_at) == (
        "sent",
        1,
        None,
        None,
    )
    ((alert, channel_settings),) = fake.sent
    assert channel_settings == {"to": "ops"}
    assert alert["line"] == "L100" and alert["track"] == "1"
    assert (alert["mast_from"], alert["mast_to"], alert["wire_position"]) == ("M1", "M2", 0)
    assert (alert["value"], alert["threshold"]) == (9.9, 10.0)
    assert alert["raised_at"] == "2024-05-06T07:08:09+00:00"
    assert alert["details"] == {"forecast_date": "2025-01-31"}

    clock.now += timedelta(days=1)
    assert deliver(engine, registry, settings, clock).attempts == []
    assert len(fake.sent) == 1


def test_backoff_then_give_up_and_stay_visible(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    fake: Fake,
    clock: Any,
) -> None:
    alert_id = alerts("a")
    settings = make_settings(config({"notifier": "fake"}, max_attempts=3, retry_minutes=1))
    fake.failures = 5
    t0 = clock.now

    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.error == "RuntimeError: relay unavailable"  # one line
    assert attempt.next_attempt_at == t0 + timedelta(minutes=1)
    clock.now = t0 + timedelta(seconds=59)
    assert deliver(engine, registry, settings, clock).attempts == []  # backing off
    clock.now = t0 + timedelta(minutes=1)
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.next_attempt_at == clock.now + timedelta(minutes=2)  # doubled
    clock.now += timedelta(minutes=2)
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.gave_up and attempt.attempts == 3
    clock.now += timedelta(days=30)
    assert deliver(engine, registry, settings, clock).attempts == []

    (row,) = rows(engine)
    assert (row.status, row.attempts, row.next_attempt_at) == ("failed", 3, None)
    assert row.last_error == "RuntimeError: relay unavailable"
    with session_scope(engine) as session:
        assert session.get(Alert, alert_id) is not None

    # more attempts allowed: due again, and sent once the channel works
    fake.failures = 0
    settings = make_settings(config({"notifier": "fake"}, max_attempts=4))
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.sent and attempt.attempts == 4
    assert rows(engine)[0].status == "sent"


def test_retry_delay_doubles_up_to_a_day(make_settings: Any) -> None:
    channels = notification_config(make_settings(config(retry_minutes=2)))
    delays = [channels.retry_delay(n) for n in (1, 2, 3, 12, 60)]
    assert delays[:3] == [timedelta(minutes=2), timedelta(minutes=4), timedelta(minutes=8)]
    assert delays[3:] == [timedelta(days=1), timedelta(days=1)]


def test_a_hanging_notifier_is_bounded_by_its_timeout(
    engine: Engine, alerts: Any, make_settings: Any, registry: PluginRegistry, clock: Any
) -> None:
    alerts("a")
    settings = make_settings(config({"notifier": "hang", "timeout_seconds": 0.3}))
    started = time.monotonic()
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert time.monotonic() - started < 5
    assert attempt.error == "timed out: 'hang' had not returned after 0.3 s"
    assert rows(engine)[0].status == "failed"


def test_a_concurrent_pass_does_not_send_a_claimed_delivery(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    fake: Fake,
    clock: Any,
) -> None:
    alerts("a")
    settings = make_settings(config({"notifier": "fake"}))
    inner: list[Any] = []
    fake.during_send = lambda: inner.append(deliver(engine, registry, settings, clock))
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.sent
    assert inner[0].attempts == []  # the other pass found it claimed
    assert len(fake.sent) == 1


def test_a_channel_without_its_notifier_waits(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    fake: Fake,
    clock: Any,
) -> None:
    alerts("a")
    settings = make_settings(
        config({"name": "sms", "notifier": "pager"}, {"name": "mail", "notifier": "fake"})
    )
    report = deliver(engine, registry, settings, clock)
    assert report.unavailable == {"sms": "notifier 'pager' is not installed (known: fake, hang)"}
    assert [(a.channel, a.sent) for a in report.attempts] == [("mail", True)]
    waiting = [row for row in rows(engine) if row.notifier == "sms"]
    assert [(row.status, row.attempts) for row in waiting] == [("pending", 0)]


@pytest.mark.parametrize(
    ("section", "message"),
    [
        ({"retries": 3}, "unknown key notifications.retries (known: channels, max_attempts, "),
        ({"max_attempts": 0}, "notifications.max_attempts must be a positive integer, not 0"),
        ({"max_attempts": 2.5}, "notifications.max_attempts must be a positive integer, not 2.5"),
        ({"retry_minutes": "1"}, "notifications.retry_minutes must be a positive number, not '1'"),
        ({"channels": {"notifier": "x"}}, "notifications.channels must be an array of tables"),
        ({"channels": [{"name": "x"}]}, "notifications.channels[1].notifier must name a notifier"),
        (
            {"channels": [{"notifier": "email", "level": ["urgent"]}]},
            "unknown key notifications.channels[1].level (known: levels, name, notifier, ",
        ),
        (
            {"channels": [{"notifier": "email", "levels": ["severe"]}]},
            "notifications.channels[1].levels must be a list of plan, urgent, critical, "
            "not ['severe']",
        ),
        (
            {"channels": [{"notifier": "email"}, {"notifier": "email"}]},
            "two notification channels are named 'email': give each a name",
        ),
        (
            {"channels": [{"notifier": "email", "timeout_seconds": -1}]},
            "notifications.channels[1].timeout_seconds must be a positive number, not -1",
        ),
    ],
)
def test_config_errors_are_one_line(
    make_settings: Any, section: dict[str, Any], message: str
) -> None:
    settings = make_settings({"notifications": section})
    with pytest.raises(UserError) as raised:
        notification_config(settings)
    text = str(raised.value)
    assert text.startswith(f"{settings.config_path}: ")
    assert message in text
    assert "\n" not in text


def test_no_section_means_no_channels(make_settings: Any) -> None:
    assert notification_config(make_settings({})).channels == ()


def test_concurrent_passes_send_each_delivery_once(
    engine: Engine,
    database_url: str,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    fake: Fake,
    clock: Any,
) -> None:
    """Three passes at once, each on its own connections (as three processes would be): no
    error, and every delivery sent exactly once."""
    keys = [alerts(f"a{n}") for n in range(6)]
    settings = make_settings(config({"notifier": "fake"}))
    fake.during_send = lambda: time.sleep(0.05)  # widen the window between claim and record
    start = threading.Barrier(3, timeout=30)

    def one_pass() -> Any:
        own = make_engine(database_url)
        try:
            start.wait()
            return deliver(own, registry, settings, clock)
        finally:
            own.dispose()

    with ThreadPoolExecutor(3) as pool:
        futures = [pool.submit(one_pass) for _ in range(3)]
        reports = [future.result(timeout=60) for future in futures]
    assert sum(len(report.attempts) for report in reports) == len(keys)
    assert sorted(alert["id"] for alert, _ in fake.sent) == sorted(keys)
    assert {row.status for row in rows(engine)} == {"sent"}
