"""A migrated database with alerts, real SMTP and HTTP servers on 127.0.0.1, and settings.

The servers are started by the tests on the loopback interface and record what they receive;
nothing leaves the machine. Each binds port 0 and reads back the port the system gave it: a
port probed free and bound later could be taken in between by another test (pytest -n).
"""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from email import message_from_bytes, policy
from email.message import EmailMessage
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import pytest
from aiosmtpd.controller import Controller
from aiosmtpd.smtp import AuthResult
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session

from catenary.storage.database import session_scope
from catenary.storage.models import Alert, Line, Track

T0 = datetime(2024, 5, 6, 7, 8, 9, tzinfo=UTC)


class Clock:
    """A clock the test moves by hand."""

    def __init__(self, now: datetime = T0) -> None:
        self.now = now

    def __call__(self) -> datetime:
        return self.now


@pytest.fixture
def clock() -> Clock:
    return Clock()


@pytest.fixture
def alert_in(build: Any) -> Callable[..., Alert]:
    """``alert_in(session, key, **columns)``: an open alert on line L100 track 1 (made on
    first use) added to ``session`` and flushed, not committed."""

    def add(session: Session, key: str, **columns: Any) -> Alert:
        track = session.scalars(select(Track).join(Line).where(Line.code == "L100")).one_or_none()
        if track is None:
            track = Track(line=Line(code="L100", name="Test line"), code="1")
        alert = build.alert(track, key, **columns)
        session.add(alert)
        session.flush()
        return alert

    return add


@pytest.fixture
def alerts(engine: Engine, alert_in: Callable[..., Alert]) -> Callable[..., int]:
    """``alerts(key, **columns)`` commits an alert and returns its id."""

    def make(key: str, **columns: Any) -> int:
        with session_scope(engine) as session:
            return alert_in(session, key, **columns).id

    return make


# --- an SMTP server ---------------------------------------------------------------------------


@dataclass
class Received:
    sender: str
    recipients: list[str]
    message: EmailMessage


@dataclass
class SmtpServer:
    host: str
    port: int
    received: list[Received] = field(default_factory=list)
    logins: list[tuple[str, str]] = field(default_factory=list)


class _Handler:
    def __init__(self, server: SmtpServer) -> None:
        self.server = server

    async def handle_DATA(self, smtp: Any, session: Any, envelope: Any) -> str:
        self.server.received.append(
            Received(
                envelope.mail_from,
                list(envelope.rcpt_tos),
                message_from_bytes(envelope.content, policy=policy.default),
            )
        )
        return "250 OK"


class _PortZeroController(Controller):
    """aiosmtpd's ``Controller`` given port 0: ``port`` is the one bound, read back before
    ``start()`` returns (and before the controller connects to its own server)."""

    def _create_server(self) -> Any:
        created = super()._create_server()

        async def bound() -> Any:
            server = await created
            self.port = int(server.sockets[0].getsockname()[1])
            return server

        return bound()


@pytest.fixture
def start_smtp_server() -> Iterator[Callable[..., SmtpServer]]:
    """``start_smtp_server(**options)``: an SMTP server on a port of 127.0.0.1 the system
    chose (options: aiosmtpd's ``Controller``); it accepts the login ``catenary`` /
    ``s3cret``."""
    controllers: list[Controller] = []

    def start(**options: Any) -> SmtpServer:
        server = SmtpServer("127.0.0.1", 0)

        def authenticate(smtp: Any, session: Any, envelope: Any, mechanism: str, auth: Any) -> Any:
            login = auth.login.decode(), auth.password.decode()
            server.logins.append(login)
            return AuthResult(success=login == ("catenary", "s3cret"), handled=False)

        controller = _PortZeroController(
            _Handler(server),
            hostname=server.host,
            port=0,
            authenticator=authenticate,
            **options,
        )
        controller.start()
        controllers.append(controller)
        server.port = controller.port
        return server

    yield start
    for controller in controllers:
        controller.stop()


@pytest.fixture
def smtp_server(start_smtp_server: Callable[..., SmtpServer]) -> SmtpServer:
    """A plain SMTP server (AUTH allowed without TLS)."""
    return start_smtp_server(auth_require_tls=False)


@pytest.fixture
def unused_port() -> Iterator[int]:
    """A port of 127.0.0.1 nothing listens on: held by a bound socket that does not listen
    (a connection is refused) for the whole test, so no other test can start a server on it."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        yield int(held.getsockname()[1])


# --- an HTTP server ---------------------------------------------------------------------------


@dataclass
class HttpServer:
    url: str
    statuses: list[int]
    """Status codes to answer, one per request; 200 once they run out."""
    requests: list[dict[str, Any]] = field(default_factory=list)
    delay_s: float = 0.0

    @property
    def origin(self) -> str:
        """``http://127.0.0.1:PORT``."""
        return self.url.rsplit("/", 1)[0]


@pytest.fixture
def http_server() -> Iterator[HttpServer]:
    """An HTTP server on 127.0.0.1 recording each POST (path, headers, JSON body)."""
    release = threading.Event()

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers["Content-Length"]))
            state.requests.append(
                {"path": self.path, "headers": dict(self.headers), "json": json.loads(body)}
            )
            if state.delay_s:
                release.wait(state.delay_s)
            status = state.statuses.pop(0) if state.statuses else 200
            self.send_response(status)
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, format: str, *args: Any) -> None:
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    server.daemon_threads = True
    state = HttpServer(f"http://127.0.0.1:{server.server_address[1]}/hook", [])
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield state
    release.set()
    server.shutdown()
    server.server_close()
