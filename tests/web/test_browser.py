"""The web service in a real browser, used as a planner would use it.

A real uvicorn server on a free port of 127.0.0.1 serves a database holding two processed runs
of the demo line (``small_run`` and ``second_small_run``: masts, spans and samples) with an
open alert on the latest run's most worn span, and the users of ``tests/web/conftest.py``.
Playwright drives Debian's Chromium headless (``/usr/bin/chromium``; ``.ci/run`` installs it,
and a machine without it fails here rather than skipping). Any console message of level
error, uncaught script error, failed request or answer of 400 or more fails the test. Each
page's screenshot is saved in the test's folder, ``screenshots/NAME.png`` (``pytest --basetemp
DIR`` keeps them to be looked at).
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import pytest
import uvicorn
from click.testing import CliRunner
from playwright.sync_api import (
    Browser,
    ConsoleMessage,
    Page,
    Playwright,
    Request,
    Response,
    sync_playwright,
)
from sqlalchemy import Engine, select
from sqlalchemy.orm import Session

from catenary.cli import cli
from catenary.config import load_settings
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, Run, SpanMeasurement
from catenary.storage.users import add_user
from catenary.web.app import create_app
from tests.conftest import Build, SmallRun
from tests.web.conftest import PASSWORD, USERS

pytestmark = [
    pytest.mark.slow,
    pytest.mark.parametrize("database_url", ["sqlite"], indirect=True),  # pages, not backends
]

CHROMIUM = Path("/usr/bin/chromium")
FLAGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
VIEWPORT = {"width": 1280, "height": 900}


@dataclass(frozen=True)
class Site:
    """The served database: its address, and the worn span and its alert."""

    base: str
    line: str
    track: str
    mast: str
    wire_position: int
    alert_id: int


def _worn_span_alert(session: Session) -> tuple[SpanMeasurement, int]:
    """An open alert on the latest run's most worn span; the span and the alert's id."""
    latest = session.scalars(select(Run).order_by(Run.started_at.desc(), Run.id.desc())).first()
    assert latest is not None
    worn = session.scalars(
        select(SpanMeasurement)
        .where(
            SpanMeasurement.processing_id == latest.processing_id,
            SpanMeasurement.min_residual_thickness_mm.is_not(None),
        )
        .order_by(SpanMeasurement.min_residual_thickness_mm)
    ).first()
    assert worn is not None
    alert = Build.alert(  # an alert's wire is the wire position
        latest.track,
        f"browser-test:{worn.id}",
        wire=worn.wire_position,
        mast_from=worn.mast_from,
        mast_to=worn.mast_to,
        start_chainage_m=worn.start_chainage_m,
        end_chainage_m=worn.end_chainage_m,
        span_measurement_id=worn.id,
        value=worn.min_residual_thickness_mm,
        threshold=worn.min_residual_thickness_mm + 0.2,
        raised_at=latest.started_at,
    )
    session.add(alert)
    session.flush()
    return worn, alert.id


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@pytest.fixture
def site(
    engine: Engine, database_url: str, small_run: SmallRun, second_small_run: SmallRun
) -> Iterator[Site]:
    """Both runs processed, the users, the worn span's alert, and the server running."""
    for run in (small_run, second_small_run):
        result = CliRunner().invoke(cli, run.process_args(database_url), catch_exceptions=False)
        assert result.exit_code == 0, result.output
    now = datetime.now(UTC)
    with session_scope(engine) as session:
        for name, role in USERS.items():
            add_user(session, name, role, PASSWORD, actor="test", now=now)
        worn, alert_id = _worn_span_alert(session)
        line, track = worn.run.line.code, worn.run.track.code
        mast, position = worn.mast_from, worn.wire_position
    assert mast is not None
    app = create_app(load_settings(database_url=database_url))
    port = _free_port()
    server = uvicorn.Server(
        uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", lifespan="on")
    )
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    for _ in range(200):
        if server.started or not thread.is_alive():
            break
        threading.Event().wait(0.05)
    assert server.started, "uvicorn did not start"
    yield Site(f"http://127.0.0.1:{port}", line, track, mast, position, alert_id)
    server.should_exit = True
    thread.join(timeout=30)


@pytest.fixture(scope="module")
def playwright() -> Iterator[Playwright]:
    with sync_playwright() as running:
        yield running


@pytest.fixture
def browser(playwright: Playwright) -> Iterator[Browser]:
    if not CHROMIUM.is_file():
        pytest.fail(
            f"{CHROMIUM} is missing: the browser tests need Debian's chromium "
            "(apt-get install chromium; .ci/run installs it)"
        )
    launched = playwright.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=FLAGS)
    yield launched
    launched.close()


@dataclass
class Visit:
    """A page of the browser, every problem it met (``problems``) and its screenshots."""

    page: Page
    shots: Path
    problems: list[str] = field(default_factory=list)

    def watch(self) -> None:
        def console(message: ConsoleMessage) -> None:
            if message.type == "error":
                where = message.location.get("url") or self.page.url
                self.problems.append(f"console: {message.text} ({where})")

        def answered(response: Response) -> None:
            if response.status >= 400:
                self.problems.append(f"{response.status} {response.url}")

        self.page.on("console", console)
        self.page.on("pageerror", lambda error: self.problems.append(f"script: {error}"))

        def failed(request: Request) -> None:
            # a request the next navigation cut short (the favicon on sign-out) did not fail
            if request.failure != "net::ERR_ABORTED":
                self.problems.append(f"failed: {request.url} {request.failure}")

        self.page.on("requestfailed", failed)
        self.page.on("response", answered)

    def shot(self, name: str) -> None:
        """Save a screenshot of the whole page as ``NAME.png``; no problem so far."""
        self.page.screenshot(path=self.shots / f"{name}.png", full_page=True)
        assert self.problems == [], "\n".join(self.problems)

    def path(self) -> str:
        return urlsplit(self.page.url).path


@pytest.fixture
def visit(browser: Browser, tmp_path: Path) -> Iterator[Visit]:
    context = browser.new_context(viewport=VIEWPORT)  # type: ignore[arg-type]
    shots = tmp_path / "screenshots"
    shots.mkdir()
    made = Visit(context.new_page(), shots)
    made.watch()
    yield made
    context.close()
    assert made.problems == [], "\n".join(made.problems)


def sign_in(visit: Visit, name: str, password: str = PASSWORD) -> None:
    """Fill in and send the sign-in form the browser shows."""
    page = visit.page
    page.get_by_label("User name").fill(name)
    page.get_by_label("Password").fill(password)
    page.get_by_role("button", name="Sign in").click()
    page.wait_for_load_state()


def query(url: str) -> dict[str, str]:
    """The query parameters of an address, decoded."""
    return {k: v[0] for k, v in parse_qs(urlsplit(url).query).items()}


def test_a_planner_signs_in_and_out(site: Site, visit: Visit) -> None:
    page = visit.page
    page.goto(site.base + "/")
    assert visit.path() == "/sign-in"  # the overview asks for a user first
    visit.shot("sign-in")
    sign_in(visit, "pat")
    assert visit.path() == "/"
    assert page.locator("header .who").inner_text().startswith("pat")
    visit.shot("overview")
    page.get_by_role("button", name="Sign out").click()
    page.wait_for_load_state()
    assert visit.path() == "/sign-in"
    page.goto(site.base + "/")
    assert visit.path() == "/sign-in"  # the cookie is gone: the overview redirects again


def links(page: Page, path: str) -> list[str]:
    """The addresses of the page's links to ``path`` (with their query)."""
    hrefs: list[str] = page.eval_on_selector_all(
        f"main a[href^='{path}']", "found => found.map(a => a.getAttribute('href'))"
    )
    return hrefs


def test_a_planner_follows_a_worn_span_to_its_alert_and_acknowledges_it(
    site: Site, visit: Visit, engine: Engine
) -> None:
    page = visit.page
    page.goto(site.base + "/")
    sign_in(visit, "pat")
    assert visit.path() == "/"
    visit.shot("overview")

    # the worn span is in the overview's worst spans; its link leads to its history
    spans = [
        href
        for href in links(page, "/span?")
        if query(href)
        == {
            "line": site.line,
            "track": site.track,
            "mast": site.mast,
            "wire_position": str(site.wire_position),
        }
    ]
    assert spans, f"no link to the span at mast {site.mast} on the overview"
    page.locator(f"main a[href='{spans[0]}']").first.click()
    page.wait_for_load_state()
    assert visit.path() == "/span"
    text = page.locator("main").inner_text()
    assert site.mast in text and "open" in page.locator("main table.alerts").inner_text()
    visit.shot("span")

    # from the span to its alert
    to_alerts = links(page, "/alerts")
    assert to_alerts, "the span page has no link to its alerts"
    page.locator(f"main a[href='{to_alerts[0]}']").first.click()
    page.wait_for_load_state()
    assert visit.path() == "/alerts"
    visit.shot("alerts")

    form = page.locator(f"form[action$='/alerts/{site.alert_id}/acknowledge']")
    assert form.count() == 1, f"no acknowledge form of alert {site.alert_id}"
    form.locator("button").click()
    page.wait_for_load_state()
    assert visit.path() == "/alerts"
    text = page.locator("main").inner_text()
    assert f"Alert {site.alert_id} acknowledged" in text and "acknowledged by pat" in text
    visit.shot("alert-acknowledged")
    with session_scope(engine, read_only=True) as session:
        alert = session.get_one(Alert, site.alert_id)
        assert (alert.status, alert.acknowledged_by) == ("acknowledged", "pat")

    page.get_by_role("button", name="Sign out").click()
    page.wait_for_load_state()
    assert visit.path() == "/sign-in"
    page.goto(site.base + "/")
    assert visit.path() == "/sign-in"


def test_the_track_view_draws_its_chart(site: Site, visit: Visit) -> None:
    page = visit.page
    page.goto(f"{site.base}/track?line={site.line}&track={site.track}")
    sign_in(visit, "vera")
    assert visit.path() == "/track"
    # a 60 m run is below a kilometre: the view reads the raw samples
    page.locator("#track-resolution:not(:empty)").wait_for()
    assert page.locator("#track-resolution").inner_text() == "raw samples"
    charts = page.locator("#track-charts canvas")
    assert charts.count() == 3  # residual thickness, height, stagger
    for k in range(3):
        box = charts.nth(k).bounding_box()
        assert box is not None and box["width"] > 800 and box["height"] > 100, box
        # drawn: a few thousand pixels of lines, not an empty canvas
        inked: int = charts.nth(k).evaluate(
            """canvas => {
                const data = canvas.getContext("2d")
                    .getImageData(0, 0, canvas.width, canvas.height).data;
                let inked = 0;
                for (let i = 3; i < data.length; i += 4) if (data[i] > 0) inked++;
                return inked;
            }"""
        )
        assert inked > 2000, inked
    visit.shot("track")
