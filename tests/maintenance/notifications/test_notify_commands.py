"""``catenary notify deliver|status`` as a user meets them, with a real webhook server."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import tomli_w
from click.testing import CliRunner, Result
from sqlalchemy import Engine, select

from catenary.cli import cli
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AlertNotification


def catenary(config: Path, database_url: str, *args: str) -> Result:
    return CliRunner().invoke(cli, ["--config", str(config), "--db", database_url, *args])


def write_config(path: Path, document: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(document))
    return path


def test_deliver_retry_and_status(
    engine: Engine, alerts: Any, http_server: Any, tmp_path: Path, database_url: str
) -> None:
    alert_id = alerts("a")
    http_server.statuses = [500]
    channel = {"name": "hook", "notifier": "webhook", "settings": {"url": http_server.url}}
    config = write_config(
        tmp_path / "c.toml",
        {"notifications": {"retry_minutes": 0.001, "channels": [channel]}},
    )

    result = catenary(config, database_url, "notify", "deliver")
    assert result.exit_code == 0, result.output
    first, summary = result.output.splitlines()
    assert first.startswith(f"failed   alert {alert_id} to hook (attempt 1, next at 20")
    assert first.endswith(
        f"UTC): RuntimeError: {http_server.origin} answered HTTP 500 Internal Server Error"
    )
    assert summary == "1 queued, 0 sent, 1 failed (retried later), 0 gave up"

    result = catenary(config, database_url, "notify", "status")
    assert result.exit_code == 0, result.output
    row, summary = result.output.splitlines()
    expected = f"alert {alert_id} urgent line L100 track 1 masts M1-M2 wire position 0 -> hook: "
    assert f"{expected}failed, " in row
    assert "1 attempt(s), next at 20" in row
    assert row.endswith("answered HTTP 500 Internal Server Error")
    assert summary == "0 pending, 1 failed"

    time.sleep(0.2)  # past the backoff
    result = catenary(config, database_url, "notify", "deliver")
    assert result.exit_code == 0, result.output
    assert result.output.splitlines() == [
        f"sent     alert {alert_id} to hook",
        "0 queued, 1 sent, 0 failed (retried later), 0 gave up",
    ]
    result = catenary(config, database_url, "notify", "status")
    assert result.output == "every notification is sent\n"


def test_channels_of_a_removed_config_are_still_listed(
    engine: Engine, alerts: Any, tmp_path: Path, database_url: str
) -> None:
    alerts("a")
    channel = {"name": "sms", "notifier": "pager"}  # not installed: waits
    config = write_config(tmp_path / "c.toml", {"notifications": {"channels": [channel]}})
    result = catenary(config, database_url, "notify", "deliver")
    assert result.exit_code == 0, result.output
    assert "channel sms: notifier 'pager' is not installed (known: " in result.output
    assert "1 queued, 0 sent" in result.output

    empty = write_config(tmp_path / "empty.toml", {})
    result = catenary(empty, database_url, "notify", "deliver")
    assert result.output == "no notification channels configured ([[notifications.channels]])\n"
    result = catenary(empty, database_url, "notify", "status")
    assert "-> sms (channel not configured): pending, 0 attempt(s), due" in result.output


def test_errors_are_one_line(engine: Engine, tmp_path: Path, database_url: str) -> None:
    bad = write_config(tmp_path / "bad.toml", {"notifications": {"max_attempts": "many"}})
    result = catenary(bad, database_url, "notify", "deliver")
    assert result.exit_code == 1
    assert result.output == (
        f"Error: {bad}: notifications.max_attempts must be a positive integer, not 'many'\n"
    )

    channel = {"notifier": "webhook", "settings": {"url": "http://127.0.0.1:9/x"}}
    good = write_config(tmp_path / "good.toml", {"notifications": {"channels": [channel]}})
    (tmp_path / "other.sqlite").touch()
    unmigrated = f"sqlite:///{tmp_path / 'other.sqlite'}"
    result = catenary(good, unmigrated, "notify", "status")
    assert result.exit_code == 1
    assert "is not migrated" in result.output
    assert len(result.output.splitlines()) == 1


def test_status_escapes_control_characters_of_stored_names(
    engine: Engine, alerts: Any, tmp_path: Path, database_url: str
) -> None:
    alerts("a", mast_from="M1\x1b[2J", mast_to="M2\r\n")
    config = write_config(tmp_path / "c.toml", {})
    with session_scope(engine) as session:
        (alert,) = session.scalars(select(Alert)).all()
        session.add(AlertNotification(alert=alert, notifier="hook", status="pending"))
    result = catenary(config, database_url, "notify", "status")
    assert result.exit_code == 0, result.output
    row, _summary = result.output.splitlines()
    assert "masts M1\\x1b[2J-M2\\r\\n wire position 0 -> hook" in row


def test_requeue_queues_again_those_that_gave_up(
    engine: Engine, alerts: Any, http_server: Any, tmp_path: Path, database_url: str
) -> None:
    """A channel that failed until it gave up, then fixed: requeue, and the next pass sends."""
    first, second = alerts("a"), alerts("b")
    http_server.statuses = [500, 500]
    channel = {"name": "hook", "notifier": "webhook", "settings": {"url": http_server.url}}
    config = write_config(
        tmp_path / "c.toml", {"notifications": {"max_attempts": 1, "channels": [channel]}}
    )
    result = catenary(config, database_url, "notify", "deliver")
    assert result.output.splitlines()[-1] == "2 queued, 0 sent, 0 failed (retried later), 2 gave up"

    result = catenary(config, database_url, "notify", "requeue", "--alert", str(first))
    assert result.exit_code == 0, result.output
    assert result.output == "1 failed notification(s) queued again\n"
    with session_scope(engine) as session:
        rows = {r.alert_id: r for r in session.scalars(select(AlertNotification))}
    assert (rows[first].status, rows[first].attempts, rows[first].last_error) == (
        "pending",
        0,
        None,
    )
    assert (rows[second].status, rows[second].attempts) == ("failed", 1)

    result = catenary(config, database_url, "notify", "deliver")
    assert result.output.splitlines() == [
        f"sent     alert {first} to hook",
        "0 queued, 1 sent, 0 failed (retried later), 0 gave up",
    ]
    result = catenary(config, database_url, "notify", "requeue", "--channel", "hook")
    assert result.output == "1 failed notification(s) queued again\n"
    result = catenary(config, database_url, "notify", "requeue")
    assert result.output == "0 failed notification(s) queued again\n"


def test_requeue_refuses_a_channel_not_configured(
    engine: Engine, tmp_path: Path, database_url: str
) -> None:
    channel = {"name": "hook", "notifier": "webhook", "settings": {"url": "http://127.0.0.1:9/"}}
    config = write_config(tmp_path / "c.toml", {"notifications": {"channels": [channel]}})
    result = catenary(config, database_url, "notify", "requeue", "--channel", "hookk")
    assert result.exit_code == 1
    assert (
        result.output
        == "Error: --channel hookk: no such notification channel (did you mean hook?)\n"
    )


def test_a_wrong_channel_is_refused_when_a_command_starts(
    engine: Engine, alerts: Any, tmp_path: Path, database_url: str
) -> None:
    """One line naming the channel and the key, before anything is queued or sent."""
    alerts("a")
    channel = {"name": "ops", "notifier": "webhook", "settings": {"url": "file:///tmp/x"}}
    config = write_config(tmp_path / "c.toml", {"notifications": {"channels": [channel]}})
    expected = (
        f"Error: {config}: notification channel 'ops': webhook settings: url must be an "
        "http(s) URL, not 'file://'\n"
    )
    for command in (["notify", "deliver"], ["notify", "requeue"], ["scheduler"]):
        result = catenary(config, database_url, *command)
        assert result.exit_code == 1, result.output
        assert result.output == expected
    with session_scope(engine) as session:
        assert session.scalars(select(AlertNotification)).all() == []
