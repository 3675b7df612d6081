"""A PostgreSQL server that goes silent or vanishes, through a proxy on 127.0.0.1 the test
freezes or cuts (the shared server itself is never touched): one line, a bounded wait, nothing
half-written, no password printed, and the next command working."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import tomli_w
from sqlalchemy import Engine, create_engine, func, select, text
from sqlalchemy.engine import make_url

from catenary.storage.models import Run, SpanMeasurement

from ..conftest import SmallRun
from .conftest import assert_refused, assert_succeeded, catenary
from .proxy_support import Proxy, proxy_for

pytestmark = pytest.mark.parametrize("database_url", ["postgresql"], indirect=True)

PASSWORD = "s3cret-pw"
# what a loaded machine adds to a timeout beyond the command's own start: 2 s, or once more
# that start where the machine is slow enough that its start took longer (a command that hung
# instead would take the 60 s of the TCP user timeout, or for ever)
MARGIN_S = 2.0


@pytest.fixture
def startup_s(engine: Engine, database_url: str) -> float:
    """How long ``catenary alerts list`` takes here when the database answers (its start:
    the interpreter, the plugins, connecting, the schema check), the base of its timeouts;
    counted twice beyond ``MARGIN_S`` (a loaded machine slows what follows the start too)."""
    start = time.monotonic()
    assert_succeeded(catenary("alerts", "list", "--db", database_url))
    elapsed = time.monotonic() - start
    return elapsed + max(0.0, elapsed - MARGIN_S)


@pytest.fixture
def proxy(engine: Engine, database_url: str) -> Iterator[Proxy]:
    """A proxy in front of the test's migrated database."""
    with proxy_for(database_url) as proxy:
        yield proxy


def proxied(proxy: Proxy, database_url: str) -> str:
    """The test's database through ``proxy``, with a password in the URL (trust auth ignores
    it) that no message may print."""
    url = make_url(proxy.url(database_url)).set(password=PASSWORD)
    return url.render_as_string(hide_password=False)


def alerts_list(
    tmp_path: Path, url: str, **database: float
) -> tuple[subprocess.CompletedProcess[str], float]:
    """``catenary alerts list`` on ``url`` with these ``[database]`` settings: what it did, and
    how long it took."""
    config = tmp_path / "config.toml"
    config.write_text(tomli_w.dumps({"database": database}))
    start = time.monotonic()
    result = catenary("--config", config, "alerts", "list", "--db", url)
    return result, time.monotonic() - start


def stored(database_url: str) -> tuple[int, int]:
    """Runs and span rows in the database (read past the proxy)."""
    engine = create_engine(database_url)
    try:
        with engine.connect() as connection:
            runs = connection.scalar(select(func.count()).select_from(Run))
            spans = connection.scalar(select(func.count()).select_from(SpanMeasurement))
            return int(runs or 0), int(spans or 0)
    finally:
        engine.dispose()


def test_a_silent_server_at_connect(
    proxy: Proxy, database_url: str, tmp_path: Path, startup_s: float
) -> None:
    proxy.freeze()
    result, elapsed = alerts_list(tmp_path, proxied(proxy, database_url), connect_timeout_s=2)
    assert_refused(result, "cannot connect", f"127.0.0.1:{proxy.port}", secrets=[PASSWORD])
    assert elapsed < startup_s + 2 + MARGIN_S, (elapsed, startup_s)


def test_the_database_cut_in_the_middle_of_process(
    proxy: Proxy, database_url: str, small_run: SmallRun, isolated_environment: Path
) -> None:
    url = proxied(proxy, database_url)
    proxy.cut_on(b"INSERT INTO span_measurements")  # the run's row is in, uncommitted
    result = catenary(*small_run.process_args(url))
    assert_refused(result, "lost the connection to database", secrets=[PASSWORD])
    assert stored(database_url) == (0, 0)
    samples = isolated_environment / "samples"
    assert list(samples.iterdir()) == []  # no samples file, no scratch file

    proxy.restore()
    assert_succeeded(catenary(*small_run.process_args(url)))
    runs, spans = stored(database_url)
    assert runs == 1 and spans > 0
    assert len(list(samples.iterdir())) == 1


def test_a_server_silent_mid_transaction_is_bounded_by_the_statement_timeout(
    proxy: Proxy, database_url: str, tmp_path: Path, startup_s: float
) -> None:
    proxy.freeze_on(b"FROM alerts")  # after connecting and checking the schema
    result, elapsed = alerts_list(tmp_path, proxied(proxy, database_url), statement_timeout_s=1)
    assert_refused(result, "did not answer within the statement timeout (1 s", secrets=[PASSWORD])
    # the timeout and its grace for a silent server
    assert elapsed < startup_s + 1 + 2 + MARGIN_S, (elapsed, startup_s)


def test_a_statement_waiting_on_a_lock_is_cancelled_by_the_server(
    engine: Engine, database_url: str, tmp_path: Path, startup_s: float
) -> None:
    with engine.connect() as holder:
        holder.execute(text("LOCK TABLE alerts IN ACCESS EXCLUSIVE MODE"))
        result, elapsed = alerts_list(tmp_path, database_url, statement_timeout_s=1)
    assert_refused(result, "did not answer within the statement timeout (1 s")
    assert elapsed < startup_s + 1 + MARGIN_S, (elapsed, startup_s)
