"""The ``webhook`` notifier against a real HTTP server on 127.0.0.1, through the delivery: the
JSON body, a 500 retried until a 200, a server that is down or too slow, and a redirect."""

from __future__ import annotations

import time
from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import Engine, select

from catenary.errors import UserError
from catenary.maintenance.notifications import deliver_pending
from catenary.plugins import PluginRegistry
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AlertNotification


@pytest.fixture
def registry() -> PluginRegistry:
    return PluginRegistry()


def hook_config(url: str, **settings: Any) -> dict[str, Any]:
    channel = {"name": "hook", "notifier": "webhook", "settings": {"url": url, **settings}}
    return {"notifications": {"channels": [channel], "retry_minutes": 1}}


def deliver(engine: Engine, registry: PluginRegistry, settings: Any, clock: Any) -> Any:
    return deliver_pending(lambda: session_scope(engine), registry, settings, clock)


def only_row(engine: Engine) -> AlertNotification:
    with session_scope(engine) as session:
        return session.scalars(select(AlertNotification)).one()


def test_the_alert_is_posted_as_json(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    http_server: Any,
    registry: PluginRegistry,
    clock: Any,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("TEST_HOOK_TOKEN", "Bearer t0ken")
    alert_id = alerts("a", kind="forecast", level="plan", details={"date": "2025-03-01"})
    settings = make_settings(
        hook_config(
            http_server.url,
            headers={"X-Source": "catenary-test"},
            headers_env={"Authorization": "TEST_HOOK_TOKEN"},
        )
    )
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.sent, attempt.error

    (request,) = http_server.requests
    assert request["path"] == "/hook"
    assert request["headers"]["Content-Type"] == "application/json; charset=utf-8"
    assert request["headers"]["X-Source"] == "catenary-test"
    assert request["headers"]["Authorization"] == "Bearer t0ken"
    body = request["json"]
    assert body["event"] == "alert"
    assert body["text"] == (
        "PLAN (forecast): line L100 track 1, masts M1 to M2, wire position 0: 9.900 vs threshold "
        "10.000 (db-ril-997#1)"
    )
    assert body["alert"] == {
        "id": alert_id,
        "level": "plan",
        "kind": "forecast",
        "status": "open",
        "line": "L100",
        "track": "1",
        "wire_position": 0,
        "mast_from": "M1",
        "mast_to": "M2",
        "start_chainage_m": 1000.0,
        "end_chainage_m": 1050.0,
        "value": 9.9,
        "threshold": 10.0,
        "rule": "db-ril-997#1",
        "condition_key": "a",
        "raised_at": "2024-05-06T07:08:09+00:00",
        "details": {"date": "2025-03-01"},
    }


def test_a_500_is_retried_until_a_200(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    http_server: Any,
    registry: PluginRegistry,
    clock: Any,
) -> None:
    alerts("a")
    http_server.statuses = [500]
    settings = make_settings(hook_config(http_server.url))
    t0 = clock.now

    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.error == (
        f"RuntimeError: {http_server.origin} answered HTTP 500 Internal Server Error"
    )
    row = only_row(engine)
    assert (row.status, row.attempts, row.next_attempt_at) == (
        "failed",
        1,
        t0 + timedelta(minutes=1),
    )

    assert deliver(engine, registry, settings, clock).attempts == []  # not yet due
    assert len(http_server.requests) == 1

    clock.now = t0 + timedelta(minutes=1)
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.sent
    row = only_row(engine)
    assert (row.status, row.attempts, row.last_error) == ("sent", 2, None)
    assert len(http_server.requests) == 2
    assert http_server.requests[0]["json"] == http_server.requests[1]["json"]


def test_a_server_that_is_down_keeps_the_alert(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    clock: Any,
    unused_port: int,
) -> None:
    alert_id = alerts("a")
    settings = make_settings(hook_config(f"http://127.0.0.1:{unused_port}/secret-path?key=k"))
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert attempt.error.startswith(f"ConnectionError: http://127.0.0.1:{unused_port}: ")
    assert "refused" in attempt.error
    assert "secret" not in attempt.error and "key=k" not in attempt.error
    row = only_row(engine)
    assert (row.status, row.attempts) == ("failed", 1)
    assert row.last_error == attempt.error
    with session_scope(engine) as session:
        assert session.get(Alert, alert_id) is not None


def test_a_slow_server_is_bounded_by_the_timeout(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    http_server: Any,
    registry: PluginRegistry,
    clock: Any,
) -> None:
    alerts("a")
    http_server.delay_s = 10
    settings = make_settings(hook_config(http_server.url, timeout=0.3))
    started = time.monotonic()
    (attempt,) = deliver(engine, registry, settings, clock).attempts
    assert time.monotonic() - started < 5
    assert attempt.error == f"TimeoutError: {http_server.origin}: no answer within 0.3 s"
    assert only_row(engine).status == "failed"


@pytest.mark.parametrize(
    ("status", "error"),
    [(302, "answered HTTP 302"), (404, "answered HTTP 404 Not Found")],
)
def test_any_answer_but_2xx_fails(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    http_server: Any,
    registry: PluginRegistry,
    clock: Any,
    status: int,
    error: str,
) -> None:
    alerts("a")
    http_server.statuses = [status]
    (attempt,) = deliver(
        engine, registry, make_settings(hook_config(http_server.url)), clock
    ).attempts
    assert error in attempt.error
    assert len(http_server.requests) == 1


@pytest.mark.parametrize(
    ("settings", "error"),
    [
        ({"url_env": "X"}, "webhook settings: give url or url_env (one of them)"),
        ({"url": "ftp://host/x"}, "webhook settings: url must be an http(s) URL, not 'ftp://host'"),
        (
            {"url": "file:///etc/passwd"},
            "webhook settings: url must be an http(s) URL, not 'file://'",
        ),
        (
            {"url": "http://127.0.0.1:http/x"},
            "webhook settings: url has a port that is not 1-65535",
        ),
        (
            {"url": "http://127.0.0.1:70000/"},
            "webhook settings: url has a port that is not 1-65535",
        ),
        ({"headers": {"X-N": 1}}, "webhook settings: headers must be a table of strings"),
        ({"headers_env": {"X-N": ""}}, "webhook settings: headers_env must name an environment"),
        ({"timeout": 0}, "webhook settings: timeout must be a positive number, not 0"),
    ],
)
def test_settings_errors_are_refused_before_any_attempt(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    http_server: Any,
    registry: PluginRegistry,
    clock: Any,
    settings: dict[str, Any],
    error: str,
) -> None:
    """Found when the configuration is read, not at every send: no attempt is used up."""
    alerts("a")
    config = make_settings(hook_config(**({"url": http_server.url} | settings)))
    with pytest.raises(UserError) as caught:
        deliver(engine, registry, config, clock)
    assert str(caught.value).startswith(f"{config.config_path}: notification channel 'hook': ")
    assert error in str(caught.value)
    assert http_server.requests == []
    with session_scope(engine) as session:
        assert session.scalars(select(AlertNotification)).all() == []


def test_a_url_from_the_environment_is_read_at_send_time(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    clock: Any,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The variable is the sending service's: a wrong value is a failed attempt, retried."""
    monkeypatch.setenv("TEST_HOOK_URL", "file:///etc/passwd")
    alerts("a")
    channel = {"name": "hook", "notifier": "webhook", "settings": {"url_env": "TEST_HOOK_URL"}}
    config = make_settings({"notifications": {"channels": [channel]}})
    (attempt,) = deliver(engine, registry, config, clock).attempts
    assert attempt.error == (
        "SettingsError: webhook settings: url (url_env) must be an http(s) URL, not 'file://'"
    )
    assert only_row(engine).next_attempt_at is not None
