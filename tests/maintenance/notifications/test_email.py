"""The ``email`` notifier against a real SMTP server (aiosmtpd) on 127.0.0.1, through the
delivery: the message received and read, a password from the environment, STARTTLS with the
server's certificate verified, and failures recorded for a retry."""

from __future__ import annotations

import shutil
import ssl
import subprocess
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from sqlalchemy import Engine, select

from catenary.errors import UserError
from catenary.maintenance.notifications import deliver_pending
from catenary.plugins import PluginRegistry
from catenary.storage.database import session_scope
from catenary.storage.models import AlertNotification


@pytest.fixture
def registry() -> PluginRegistry:
    return PluginRegistry()  # the built-ins, email among them


def email_config(server: Any, **settings: Any) -> dict[str, Any]:
    channel_settings = {
        "host": server.host,
        "port": server.port,
        "security": "none",
        "from": "catenary@example.org",
        "to": ["overhead-line@example.org", "planner@example.org"],
        "timeout": 5,
        **settings,
    }
    channel = {"name": "mail", "notifier": "email", "settings": channel_settings}
    return {"notifications": {"channels": [channel]}}


def deliver(engine: Engine, registry: PluginRegistry, settings: Any) -> Any:
    return deliver_pending(lambda: session_scope(engine), registry, settings)


def only_row(engine: Engine) -> AlertNotification:
    with session_scope(engine) as session:
        return session.scalars(select(AlertNotification)).one()


def test_the_message_names_the_alert(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    smtp_server: Any,
    registry: PluginRegistry,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("TEST_SMTP_PASSWORD", "s3cret")
    alert_id = alerts(
        "a",
        level="critical",
        mast_from="M17",
        mast_to="M18",
        start_chainage_m=12345.5,
        end_chainage_m=12398.0,
        wire=1,
        value=8.62,
        threshold=8.7,
        rule="db-ril-997#3",
    )
    settings = make_settings(
        email_config(
            smtp_server,
            username="catenary",
            password_env="TEST_SMTP_PASSWORD",
            allow_plain_auth=True,
        )
    )

    (attempt,) = deliver(engine, registry, settings).attempts
    assert attempt.sent, attempt.error
    assert smtp_server.logins == [("catenary", "s3cret")]
    (received,) = smtp_server.received
    assert received.sender == "catenary@example.org"
    assert received.recipients == ["overhead-line@example.org", "planner@example.org"]
    mail = received.message
    assert mail["Subject"] == (
        "[catenary] CRITICAL: line L100 track 1, masts M17 to M18, wire position 1: 8.620 vs "
        "threshold 8.700 (db-ril-997#3)"
    )
    assert mail["To"] == "overhead-line@example.org, planner@example.org"
    assert mail.get_content_type() == "text/plain"
    body = mail.get_content()
    for line in (
        "Level:     critical",
        "Line:      L100",
        "Track:     1",
        "Masts:     M17 to M18",
        "Chainage:  12345.5 m to 12398.0 m",
        "Position:  1",
        "Value:     8.620 (threshold 8.700)",
        "Rule:      db-ril-997#3",
        f"Alert:     {alert_id} (open)",
    ):
        assert line in body.splitlines(), body
    assert only_row(engine).status == "sent"


@pytest.mark.parametrize(
    ("settings", "error"),
    [
        (
            {"username": "catenary", "password": "s3cret"},
            "email settings: password may not be written in the config file; name the "
            "environment variable that holds it in password_env",
        ),
        (
            {"username": "catenary", "password_env": "TEST_SMTP_PASSWORD"},
            'email settings: security = "none" with a username would send the password in clear',
        ),
        (
            {"username": "catenary", "password_env": "TEST_SMTP_PASSWORD", "allow_plain_auth": 1},
            "email settings: allow_plain_auth must be true or false, not 1",
        ),
        ({"username": "catenary"}, "email settings: password_env must name an environment var"),
        (
            {"hots": "smtp"},
            "email settings: unknown key 'hots' (known: allow_plain_auth, ca_file, ",
        ),
        ({"security": "tls"}, "email settings: security must be one of starttls, ssl, none"),
        ({"to": "ops@example.org"}, "email settings: to must be a list of addresses"),
        ({"port": "25"}, "email settings: port must be a port number, not '25'"),
        ({"port": 70000}, "email settings: port must be a port number, not 70000"),
        ({"host": ""}, "email settings: host must be a non-empty string, not ''"),
    ],
)
def test_settings_errors_are_refused_before_any_attempt(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    smtp_server: Any,
    registry: PluginRegistry,
    monkeypatch: pytest.MonkeyPatch,
    settings: dict[str, Any],
    error: str,
) -> None:
    """Found when the configuration is read, not at every send: no attempt is used up."""
    monkeypatch.setenv("TEST_SMTP_PASSWORD", "s3cret")
    alerts("a")
    config = make_settings(email_config(smtp_server, **settings))
    with pytest.raises(UserError) as caught:
        deliver(engine, registry, config)
    assert str(caught.value).startswith(f"{config.config_path}: notification channel 'mail': ")
    assert error in str(caught.value)
    assert smtp_server.received == []
    with session_scope(engine) as session:
        assert session.scalars(select(AlertNotification)).all() == []


@pytest.mark.parametrize(
    ("password", "error"),
    [
        (None, "email settings: environment variable TEST_SMTP_PASSWORD (password_env) is not set"),
        ("wrong", "SMTPAuthenticationError: (535, "),
    ],
)
def test_failures_at_send_time_are_recorded_and_nothing_is_sent(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    smtp_server: Any,
    registry: PluginRegistry,
    monkeypatch: pytest.MonkeyPatch,
    password: str | None,
    error: str,
) -> None:
    """The password is the sending service's (its environment): read, and wrong, at send time."""
    if password is None:
        monkeypatch.delenv("TEST_SMTP_PASSWORD", raising=False)
    else:
        monkeypatch.setenv("TEST_SMTP_PASSWORD", password)
    alerts("a")
    settings = {"username": "catenary", "password_env": "TEST_SMTP_PASSWORD"}
    config = email_config(smtp_server, allow_plain_auth=True, **settings)
    (attempt,) = deliver(engine, registry, make_settings(config)).attempts
    assert not attempt.sent
    assert error in attempt.error
    assert smtp_server.received == []
    row = only_row(engine)
    assert (row.status, row.attempts) == ("failed", 1)
    assert row.next_attempt_at is not None  # retried later


def test_a_server_that_is_down(
    engine: Engine, alerts: Any, make_settings: Any, registry: PluginRegistry, unused_port: int
) -> None:
    alerts("a")
    down = SimpleNamespace(host="127.0.0.1", port=unused_port)
    (attempt,) = deliver(engine, registry, make_settings(email_config(down))).attempts
    assert attempt.error.startswith("ConnectionRefusedError: ")
    assert only_row(engine).status == "failed"


@pytest.fixture
def tls_files(tmp_path: Path) -> Iterator[tuple[Path, Path]]:
    """A self-signed certificate for 127.0.0.1 and its key (openssl)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    command = "openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=127.0.0.1"
    san = "subjectAltName=IP:127.0.0.1"
    subprocess.run(
        [*command.split(), "-addext", san, "-keyout", str(key), "-out", str(cert)],
        check=True,
        capture_output=True,
    )
    yield cert, key


def test_starttls_verifies_the_server(
    engine: Engine,
    alerts: Any,
    make_settings: Any,
    registry: PluginRegistry,
    tls_files: tuple[Path, Path],
    start_smtp_server: Any,
) -> None:
    cert, key = tls_files
    context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    context.load_cert_chain(cert, key)
    server = start_smtp_server(tls_context=context, require_starttls=True)
    alerts("a")
    untrusted = make_settings(email_config(server, security="starttls"))
    (attempt,) = deliver(engine, registry, untrusted).attempts
    assert "CERTIFICATE_VERIFY_FAILED" in attempt.error
    assert server.received == []

    trusted = make_settings(email_config(server, security="starttls", ca_file=str(cert)))
    with session_scope(engine) as session:  # due again at once
        session.scalars(select(AlertNotification)).one().next_attempt_at = None
    (attempt,) = deliver(engine, registry, trusted).attempts
    assert attempt.sent, attempt.error
    assert len(server.received) == 1
