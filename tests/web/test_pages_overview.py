"""The fleet overview: tracks and their latest runs, the worst spans, open alerts by level and
the wire due within the horizon; HTML escaped."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta

from sqlalchemy import Engine

from catenary.storage.database import session_scope
from catenary.storage.overview import track_summaries, worst_spans
from tests.maintenance.conftest import T0, YEAR, Fleet
from tests.web.conftest import Web

NOW = datetime.now(UTC)


def _fleet(engine: Engine) -> dict[str, int]:
    """Line L1 track 1 (two runs, the latest with spans 3 and 7 thinnest), line ``<script>``
    track 2 (one run); a critical and a plan threshold alert, a forecast due within the
    horizon and one beyond it, and a resolved alert."""
    with session_scope(engine) as session:
        fleet = Fleet(session)
        one = fleet.track("L1", "1")
        fleet.run(one, T0, {3: 9.0})
        latest = fleet.run(one, T0 + YEAR, {3: 8.25, 7: 8.5})
        two = fleet.track("<script>alert(1)</script>", "2", masts=5)
        other = fleet.run(two, T0 + YEAR, {1: 11.0})
        session.flush()
        fleet.session.add_all(
            [
                _alert(one.id, "a", level="critical", value=8.25, mast_from="M03", mast_to="M04"),
                _alert(one.id, "b", level="plan", value=8.5),
                _alert(
                    one.id,
                    "c",
                    kind="forecast",
                    level="urgent",
                    details={
                        "reach_at": (NOW + timedelta(days=40)).isoformat(timespec="seconds"),
                        "reach_earliest": (NOW + timedelta(days=10)).isoformat(timespec="seconds"),
                        "reach_latest": None,
                        "wear_rate_mm_per_year": 0.75,
                    },
                    mast_from="M07",
                    mast_to="M08",
                ),
                _alert(
                    one.id,
                    "d",
                    kind="forecast",
                    level="plan",
                    details={"reach_at": (NOW + timedelta(days=900)).isoformat()},
                    mast_from="M09",
                    mast_to="M10",
                ),
                _alert(one.id, "e", level="critical", status="resolved"),
            ]
        )
        return {"latest": latest.id, "other": other.id}


def _alert(track_id: int, key: str, **columns: object) -> object:
    from catenary.storage.models import Alert

    values: dict[str, object] = {
        "track_id": track_id,
        "wire": 0,
        "mast_from": "M01",
        "mast_to": "M02",
        "start_chainage_m": 1050.0,
        "end_chainage_m": 1100.0,
        "rule": "db-ril-997#1",
        "kind": "threshold",
        "value": 9.0,
        "threshold": 9.5,
        "raised_at": T0 + YEAR,
        "condition_key": key,
    }
    return Alert(**(values | columns))


def _row(html: str, marker: str) -> str:
    """The table row of ``html`` holding ``marker``."""
    at = html.index(marker)
    return html[html.rindex("<tr", 0, at) : html.index("</tr>", at)]


def test_the_overview_shows_tracks_runs_worst_spans_alerts_and_what_is_due(
    web: Web, engine: Engine
) -> None:
    runs = _fleet(engine)
    page = web.client("vera").get("/")
    assert page.status_code == 200
    html = page.text
    tracks = html[html.index('id="tracks"') : html.index('id="worst"')]
    row = _row(tracks, "/track?line=L1&amp;track=1")
    assert f'href="/runs/{runs["latest"]}"' in row and "2021-01-05" in row  # T0 + a year
    assert '<td class="num">11</td>' in row and '<td class="num">10</td>' in row  # masts, spans
    worst = html[html.index('id="worst"') : html.index('id="due"')]
    first, second = worst.index("8.25 mm"), worst.index("8.50 mm")
    assert first < second < worst.index("11.00 mm")
    assert "9.00 mm" not in worst  # the earlier run's minimum is not the latest
    assert "/span?line=L1&amp;track=1&amp;mast=M03&amp;wire_position=0" in worst
    counts = html[html.index('id="alerts"') : html.index('id="tracks"')]
    shown = dict(re.findall(r'level=(\w+)">.*?class="figure">(\d+)<', counts, re.S))
    assert shown == {"critical": "1", "urgent": "1", "plan": "2"}  # not the resolved one
    due = html[html.index('id="due"') :]
    assert ": 1." in due and "masts M07 to M08" in due and "M09" not in due
    assert "0.750 mm/year" in due and "never" in due


def test_the_overview_escapes_what_the_database_holds(web: Web, engine: Engine) -> None:
    _fleet(engine)
    html = web.client("vera").get("/").text
    assert "<script>alert(1)</script>" not in html
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    assert "/track?line=%3Cscript%3Ealert%281%29%3C/script%3E&amp;track=2" in html


def test_an_empty_fleet_says_so(web: Web) -> None:
    html = web.client("vera").get("/").text
    assert "No track in the database yet" in html and "No measured span yet" in html


def test_the_worst_spans_are_the_thinnest_of_the_latest_runs_across_tracks(engine: Engine) -> None:
    """Each latest processing's thinnest rows are merged (on PostgreSQL a lateral join gives
    ``limit`` per processing): the three thinnest come from both tracks."""
    _fleet(engine)
    with session_scope(engine, read_only=True) as session:
        worst = worst_spans(session, 3)
        assert [(line, track, s.mast_from) for line, track, s in worst] == [
            ("L1", "1", "M03"),
            ("L1", "1", "M07"),
            ("<script>alert(1)</script>", "2", "M01"),
        ]
        assert [s.min_residual_thickness_mm for _, _, s in worst] == [8.25, 8.5, 11.0]
        summaries = {(t.line, t.track): (t.masts, t.spans) for t in track_summaries(session)}
        assert summaries == {("L1", "1"): (11, 10), ("<script>alert(1)</script>", "2"): (5, 4)}
