"""Three ``catenary notify deliver`` at once, against a webhook receiver on 127.0.0.1 with a
channel that answers, one that fails (HTTP 500) and one that hangs (accepts, never answers:
the channel's timeout applies): every notification is sent once, never twice, the failed and
hung ones are retried later, and no pass prints a traceback. On SQLite and PostgreSQL."""

from __future__ import annotations

import json
import threading
from collections import Counter
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from sqlalchemy import Engine, select, update

from catenary.storage.database import session_scope
from catenary.storage.models import AlertNotification, Line, Track

from .conftest import assert_succeeded, catenary, finished, start_catenary

ALERTS = 3
HANG_TIMEOUT_S = 2


class Receiver:
    """Webhooks at ``/ok`` (200), ``/fail`` (500) and ``/hang`` (no answer while ``hanging``
    is set); ``received`` counts (path, alert id)."""

    def __init__(self) -> None:
        self.received: Counter[tuple[str, int]] = Counter()
        self.hanging = threading.Event()
        self.hanging.set()
        self._released = threading.Event()
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                body = json.loads(self.rfile.read(int(self.headers["Content-Length"])))
                receiver.received[(self.path, int(body["alert"]["id"]))] += 1
                if self.path == "/hang" and receiver.hanging.is_set():
                    receiver._released.wait(60)
                    return
                self.send_response(500 if self.path == "/fail" else 200)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, format: str, *args: Any) -> None:
                pass

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self.origin = f"http://127.0.0.1:{self._server.server_address[1]}"
        threading.Thread(target=self._server.serve_forever, daemon=True).start()

    def count(self, path: str) -> Counter[int]:
        return Counter({alert: n for (p, alert), n in self.received.items() if p == path})

    def close(self) -> None:
        self._released.set()
        self._server.shutdown()
        self._server.server_close()


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    receiver = Receiver()
    yield receiver
    receiver.close()


@pytest.fixture
def alert_ids(engine: Engine, build: Any) -> list[int]:
    with session_scope(engine) as session:
        track = Track(line=Line(code="L7", name="Line 7"), code="1")
        alerts = [build.alert(track, f"c{k}") for k in range(ALERTS)]
        session.add_all(alerts)
        session.flush()
        return sorted(alert.id for alert in alerts)


def config(tmp_path: Path, receiver: Receiver) -> Path:
    channels = [
        {"name": name, "notifier": "webhook", "settings": {"url": f"{receiver.origin}/{name}"}}
        for name in ("ok", "fail", "hang")
    ]
    channels[2]["timeout_seconds"] = HANG_TIMEOUT_S
    path = tmp_path / "config.toml"
    # a long backoff: a failure is retried by a later pass, never by one of these three
    path.write_text(tomli_w.dumps({"notifications": {"retry_minutes": 60, "channels": channels}}))
    return path


def test_three_passes_at_once_send_each_notification_once(
    engine: Engine, database_url: str, alert_ids: list[int], receiver: Receiver, tmp_path: Path
) -> None:
    command = ["--config", config(tmp_path, receiver), "notify", "deliver", "--db", database_url]
    passes = [start_catenary(*command) for _ in range(3)]
    results = [finished(process) for process in passes]
    for result in results:
        assert_succeeded(result)
    once = Counter(dict.fromkeys(alert_ids, 1))
    assert receiver.count("/ok") == once
    assert receiver.count("/fail") == once
    assert receiver.count("/hang") == once
    timed_out = sum(
        result.stdout.count("timed out: 'webhook' had not returned after 2 s") for result in results
    )
    assert timed_out == ALERTS, results

    # later: the server answers again and the backoff has elapsed
    receiver.hanging.clear()
    with session_scope(engine) as session:
        session.execute(
            update(AlertNotification)
            .where(AlertNotification.status == "failed")
            .values(next_attempt_at=datetime.now(UTC) - timedelta(seconds=1))
        )
    again = catenary(
        "--config", tmp_path / "config.toml", "notify", "deliver", "--db", database_url
    )
    assert_succeeded(again)
    assert receiver.count("/ok") == once  # sent ones are never sent again
    assert receiver.count("/hang") == once + once  # the hung ones, retried and sent
    with session_scope(engine, read_only=True) as session:
        rows = session.execute(
            select(AlertNotification.notifier, AlertNotification.status, AlertNotification.attempts)
        ).all()
    assert Counter(rows) == Counter(
        {("ok", "sent", 1): ALERTS, ("hang", "sent", 2): ALERTS, ("fail", "failed", 2): ALERTS}
    )
