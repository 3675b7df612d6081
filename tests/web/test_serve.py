"""``catenary serve``: the real server on a free port, its settings, and its refusals."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx2
import pytest
from click.testing import CliRunner
from sqlalchemy import Engine

from catenary.cli import cli
from catenary.config import load_settings
from catenary.errors import UserError
from catenary.web.settings import MIN_SECRET_LENGTH, SECRET_FILE, web_settings


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_serve_answers_on_its_port_and_stops_on_sigterm(engine: Engine, database_url: str) -> None:
    port = free_port()
    command = [
        sys.executable,
        "-m",
        "catenary.cli",
        "--db",
        database_url,
        "serve",
        "--port",
        str(port),
    ]
    server = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 30.0
        while True:
            try:
                answer = httpx2.get(f"http://127.0.0.1:{port}/health", timeout=2.0)
                break
            except httpx2.TransportError:
                assert server.poll() is None, server.communicate()[0]
                assert time.monotonic() < deadline, "the server did not start in 30 s"
                time.sleep(0.2)
        assert answer.json() == {"status": "ok"}
        assert "server" not in answer.headers
        for _ in range(4):  # whichever process answers
            assert httpx2.get(f"http://127.0.0.1:{port}/api/v1/runs").status_code == 401
    finally:
        server.terminate()
        output = server.communicate(timeout=30)[0]
    # uvicorn shuts down cleanly, then ends by the signal it was sent (systemd's clean stop)
    assert server.returncode in (0, -signal.SIGTERM), output
    assert "Application shutdown complete" in output
    assert f"http://127.0.0.1:{port}/" in output


@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)
def test_serve_refuses_a_database_that_is_not_there(database_url: str) -> None:
    result = CliRunner().invoke(cli, ["--db", database_url, "serve"])
    assert result.exit_code == 1
    assert "catenary db upgrade" in result.output and len(result.output.strip().splitlines()) == 1


def test_the_cookie_key_is_made_once_and_kept_private(tmp_path: Path) -> None:
    settings = load_settings(database_url="sqlite://")
    first, second = web_settings(settings), web_settings(settings)
    assert first.secret_key == second.secret_key and len(first.secret_key) >= MIN_SECRET_LENGTH
    assert (settings.data_dir / SECRET_FILE).stat().st_mode & 0o077 == 0


def test_web_settings_are_checked(tmp_path: Path) -> None:
    config = tmp_path / "catenary.toml"
    config.write_text('[web]\nsecret_key_env = "WEB_KEY"\nsession_hours = 8\n')
    settings = load_settings(config_path=config, database_url="sqlite://")
    with pytest.raises(UserError, match="WEB_KEY must hold a key of at least 32"):
        web_settings(settings, environ={"WEB_KEY": "short"})
    web = web_settings(settings, environ={"WEB_KEY": "k" * 40})
    assert (web.secret_key, web.session_s) == ("k" * 40, 8 * 3600.0)
    config.write_text("[web]\nsesion_hours = 8\n")
    settings = load_settings(config_path=config, database_url="sqlite://")
    with pytest.raises(UserError, match=r"unknown key 'sesion_hours' \(did you mean session_hours"):
        web_settings(settings)
    config.write_text("[web]\nsign_in_attempts = 0\n")
    settings = load_settings(config_path=config, database_url="sqlite://")
    with pytest.raises(UserError, match="sign_in_attempts must be a number from 1 to 1000, not 0"):
        web_settings(settings)
