"""``catenary db`` as a user meets it: what was done, one-line errors, non-zero exits."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import sqlalchemy as sa
from click.testing import CliRunner, Result
from sqlalchemy.engine import make_url

from catenary.cli import cli
from catenary.storage import migrate

HEAD = migrate.head_revision()
Catenary = Callable[..., Result]


@pytest.fixture
def catenary(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Catenary:
    """Run ``catenary ARGS...`` in-process, away from the user's config and data."""
    config = tmp_path / "config.toml"
    config.write_text("")
    monkeypatch.setenv("CATENARY_CONFIG", str(config))
    monkeypatch.setenv("CATENARY_DATA_DIR", str(tmp_path / "data"))
    monkeypatch.delenv("CATENARY_DATABASE_URL", raising=False)

    def run(*args: str) -> Result:
        return CliRunner().invoke(cli, list(args))

    return run


def shown(url: str) -> str:
    return make_url(url).render_as_string(hide_password=True)


def empty_sqlite_file(url: str) -> None:
    file = Path(str(make_url(url).database))
    file.parent.mkdir(parents=True, exist_ok=True)
    file.touch()


def assert_one_line_error(result: Result) -> None:
    assert result.exit_code == 1, result.output
    assert isinstance(result.exception, SystemExit)  # not an uncaught exception
    assert "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1, result.output
    assert result.output.startswith("Error: ")


@pytest.mark.parametrize("place", ["global", "command"])
def test_upgrade_current_check_downgrade(catenary: Catenary, database_url: str, place: str) -> None:
    """The database given before ``db`` (the global option) or after its command alike."""
    where = shown(database_url)

    def run(*args: str) -> Result:
        if place == "global":
            return catenary("--db", database_url, *args)
        return catenary(*args, "--db", database_url)

    if database_url.startswith("sqlite"):  # a file that does not exist is not created
        result = run("db", "current")
        assert_one_line_error(result)
        assert f"{where} does not exist: run 'catenary db upgrade'" in result.output
        empty_sqlite_file(database_url)  # a database not migrated

    result = run("db", "current")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} is not migrated: run 'catenary db upgrade'\n"

    result = run("db", "upgrade")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} upgraded to {HEAD} (head)\n"

    result = run("db", "upgrade")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} is already at {HEAD} (head)\n"

    result = run("db", "current")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} is at {HEAD} (head)\n"

    result = run("db", "check")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} matches the models at {HEAD} (head)\n"

    result = run("db", "downgrade", "base")
    assert result.exit_code == 0, result.output
    assert result.output == f"database {where} downgraded to base (no schema)\n"


def test_check_on_a_database_that_is_not_migrated(catenary: Catenary, database_url: str) -> None:
    if database_url.startswith("sqlite"):
        empty_sqlite_file(database_url)
    result = catenary("--db", database_url, "db", "check")
    assert_one_line_error(result)
    assert result.output == (
        f"Error: database {shown(database_url)} is not migrated "
        f"(revision: none, needed: {HEAD}): run 'catenary db upgrade'\n"
    )


def test_check_reports_differences_and_fails(catenary: Catenary, database_url: str) -> None:
    assert catenary("--db", database_url, "db", "upgrade").exit_code == 0
    engine = sa.create_engine(database_url)
    with engine.begin() as connection:
        connection.execute(sa.text("DROP INDEX ix_runs_line_id_track_id_started_at"))
    engine.dispose()
    result = catenary("--db", database_url, "db", "check")
    assert result.exit_code == 1
    assert "differs from the models" in result.stderr
    assert "add_index Index ix_runs_line_id_track_id_started_at" in result.stderr


def test_check_lists_identifiers_with_control_characters(
    catenary: Catenary, database_url: str
) -> None:
    assert catenary("--db", database_url, "db", "upgrade").exit_code == 0
    engine = sa.create_engine(database_url)
    with engine.begin() as connection:
        connection.execute(
            sa.text("INSERT INTO lines (code) VALUES ('L1'), (:bad)"), {"bad": "L2\x1b]0;x\x07"}
        )
    engine.dispose()
    result = catenary("--db", database_url, "db", "check")
    assert result.exit_code == 1
    assert result.stderr.splitlines()[1:] == [
        "    lines.code = 'L2\\x1b]0;x\\x07' holds a control character "
        "(identifiers are printable text)"
    ]
    assert "\x1b" not in result.stderr


def test_upgrade_to_an_unknown_revision(catenary: Catenary, database_url: str) -> None:
    result = catenary("--db", database_url, "db", "upgrade", "nosuchrev")
    assert_one_line_error(result)
    assert "nosuchrev" in result.output


@pytest.mark.parametrize(
    ("url", "message"),
    [
        ("nonsense://x", "Error: unknown database driver 'nonsense' in nonsense://x"),
        ("nonsense", "Error: malformed database URL 'nonsense'"),
        (
            "postgresql+psycopg://fleet:s3cret@127.0.0.1:1/catenary",
            "Error: cannot connect to database "
            "postgresql+psycopg://fleet:***@127.0.0.1:1/catenary: ",
        ),
    ],
)
@pytest.mark.parametrize("command", [["current"], ["upgrade"], ["check"], ["downgrade", "base"]])
def test_bad_database_is_one_line(
    catenary: Catenary, url: str, message: str, command: list[str]
) -> None:
    result = catenary("--db", url, "db", *command)
    assert_one_line_error(result)
    assert result.output.startswith(message)
    assert "s3cret" not in result.output


def test_default_database_is_a_sqlite_file_in_the_data_directory(
    catenary: Catenary, tmp_path: Path
) -> None:
    result = catenary("db", "upgrade")
    assert result.exit_code == 0, result.output
    path = tmp_path / "data" / "catenary.sqlite"
    assert result.output == f"database sqlite:///{path} upgraded to {HEAD} (head)\n"
    assert path.is_file()


def test_database_from_the_environment(
    catenary: Catenary, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "fleet" / "fleet.sqlite"
    monkeypatch.setenv("CATENARY_DATABASE_URL", f"sqlite:///{path}")
    result = catenary("db", "upgrade")
    assert result.exit_code == 0, result.output
    assert path.is_file()


def test_notify_status_takes_the_database_option(
    catenary: Catenary, database_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CATENARY_DATA_DIR", str(tmp_path / "elsewhere"))  # the default database
    assert catenary("db", "upgrade", "--db", database_url).exit_code == 0
    result = catenary("notify", "status", "--db", database_url)
    assert (result.exit_code, result.output) == (0, "every notification is sent\n")
    assert_one_line_error(catenary("notify", "status"))  # not migrated


@pytest.fixture
def silent_server() -> Iterator[int]:
    """The port of a TCP server on 127.0.0.1 that accepts connections and never answers."""
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        listener.settimeout(0.1)
        while not stop.is_set():
            try:
                accepted.append(listener.accept()[0])
            except TimeoutError:
                continue

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield listener.getsockname()[1]
    finally:
        stop.set()
        thread.join()
        for connection in accepted:
            connection.close()
        listener.close()


def test_a_silent_server_times_out_in_one_line(
    catenary: Catenary, silent_server: int, tmp_path: Path
) -> None:
    url = f"postgresql+psycopg://fleet:s3cret@127.0.0.1:{silent_server}/catenary"
    config = tmp_path / "silent.toml"
    config.write_text(f'[database]\nurl = "{url}"\nconnect_timeout_s = 1\n')
    started = time.monotonic()
    result = catenary("--config", str(config), "db", "current")
    assert time.monotonic() - started < 10
    assert_one_line_error(result)
    assert f"cannot connect to database {shown(url)}" in result.output
    assert "timeout" in result.output
    assert "s3cret" not in result.output
