"""The REST API over a built fleet (SQLite and PostgreSQL): every endpoint, the roles, paging
and bad input."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

import numpy as np
import pytest
from sqlalchemy import Engine, select

from catenary.config import Settings
from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AuditEntry, Run
from catenary.storage.users import add_user, create_token
from catenary.web.app import create_app
from tests.maintenance.conftest import T0, YEAR, Fleet
from tests.web.conftest import PASSWORD, USERS, Web, csrf_of

WORN_MM = (12.0, 11.65, 11.15, 10.8)  # span 3's minimum over four yearly runs
SLOPE_MM_PER_YEAR, START_MM = np.polyfit(np.arange(4.0), WORN_MM, 1)  # -0.41 mm/year
L1_1 = {"line": "L1", "track": "1"}
PATHS = (
    "/runs",
    "/runs/{run}",
    "/spans",
    "/spans/history",
    "/samples",
    "/alerts",
    "/alerts/{alert_id}/acknowledge",
    "/alerts/{alert_id}/resolve",
    "/maintenance-actions",
)


@pytest.fixture
def api(engine: Engine, make_settings: Callable[[dict[str, Any]], Settings]) -> Iterator[Web]:
    """The web service with a wear-limit policy over track L1/1 (masts M00..M10, four yearly
    runs, span 3 wearing), track L1/2 (one run) and an urgent alert on span 3."""
    now = datetime.now(UTC)
    tokens = {}
    with session_scope(engine) as session:
        for name, role in USERS.items():
            add_user(session, name, role, PASSWORD, actor="test", now=now)
            tokens[name] = create_token(session, name, "test", actor="test", now=now)[1]
        fleet = Fleet(session)
        one, two = fleet.track("L1", "1"), fleet.track("L1", "2", masts=4)
        for year, worn in enumerate(WORN_MM):
            fleet.run(one, T0 + year * YEAR, {3: worn, 7: 12.2})
        fleet.run(two, T0, {1: 11.9})
        session.add(fleet_alert(one.id))
    app = create_app(make_settings({"limits": {"policy": "china-maintenance-rules"}}))
    yield Web(app, tokens)
    app.state.web.engine.dispose()


def fleet_alert(track_id: int, **columns: Any) -> Alert:
    values: dict[str, Any] = {
        "track_id": track_id,
        "wire": 0,
        "mast_from": "M03",
        "mast_to": "M04",
        "start_chainage_m": 1150.0,
        "end_chainage_m": 1200.0,
        "rule": "test",
        "level": "urgent",
        "kind": "threshold",
        "value": 10.8,
        "threshold": 11.0,
        "raised_at": T0 + 3 * YEAR,
        "condition_key": f"test:{track_id}:M03",
    }
    return Alert(**(values | columns))


def test_the_openapi_description_lists_every_path_and_its_parameters(api: Web) -> None:
    answer = api.anonymous().get("/api/v1/openapi.json")
    assert answer.status_code == 200
    paths = answer.json()["paths"]
    assert {f"/api/v1{p}" for p in PATHS} <= set(paths)
    spans = {p["name"] for p in paths["/api/v1/spans"]["get"]["parameters"]}
    assert {"line", "track", "from_m", "to_m", "run", "order", "limit", "offset"} <= spans
    errors = paths["/api/v1/spans"]["get"]["responses"]
    for status in ("401", "404", "422"):
        schema = errors[status]["content"]["application/json"]["schema"]
        assert schema == {"$ref": "#/components/schemas/ErrorOut"}
    fields = answer.json()["components"]["schemas"]["SpanOut"]["properties"]
    assert {"min_residual_thickness_mm", "wire_position", "mast_from", "samples"} <= set(fields)


@pytest.mark.parametrize(
    "path",
    [
        "/runs/1",
        "/spans",
        "/spans/history?line=L1&track=1&mast=M03",
        "/samples?run=1&from_m=0&to_m=1",
        "/alerts",
        "/maintenance-actions",
    ],
)
def test_reads_need_a_user(api: Web, path: str) -> None:
    answer = api.anonymous().get(f"/api/v1{path}")
    assert answer.status_code == 401 and "error" in answer.json()


@pytest.mark.parametrize(
    ("path", "body"),
    [
        ("/alerts/1/acknowledge", None),
        ("/alerts/1/resolve", {"note": "x"}),
        (
            "/maintenance-actions",
            {"line": "L1", "track": "1", "kind": "inspected", "from_m": 0, "to_m": 1,
             "performed_at": "2024-01-01T00:00:00Z"},
        ),
    ],
)  # fmt: skip
def test_writes_need_a_planner(api: Web, path: str, body: Any) -> None:
    assert api.anonymous().post(f"/api/v1{path}", json=body).status_code == 401
    answer = api.api("vera").post(f"/api/v1{path}", json=body)
    assert answer.status_code == 403 and "needs a planner" in answer.json()["error"]


def test_a_run_by_id_uuid_prefix_or_latest(api: Web, engine: Engine) -> None:
    client = api.api("vera")
    with session_scope(engine, read_only=True) as session:
        runs = list(session.scalars(select(Run).order_by(Run.id)))
        first, uuid = runs[0].id, runs[0].uuid
    for reference in (str(first), uuid, uuid[:8]):
        answer = client.get(f"/api/v1/runs/{reference}")
        assert answer.status_code == 200, answer.text
        run = answer.json()
        assert run["id"] == first and run["line"] == "L1" and run["track"] == "1"
        assert run["vehicle_geometry"]["roof_height_mm"] == 3900.0
        assert [p["latest"] for p in run["processings"]] == [True]
        assert run["calibration"]["version"] == 1
    assert client.get("/api/v1/runs/latest").status_code == 200
    for unknown in ("999999", "zzzz-not-a-run", "ab"):
        answer = client.get(f"/api/v1/runs/{unknown}")
        assert answer.status_code == 404 and "run" in answer.json()["error"]


def test_spans_of_the_latest_runs_worst_first(api: Web) -> None:
    client = api.api("vera")
    answer = client.get("/api/v1/spans", params={"line": "L1", "track": "1", "order": "worst"})
    assert answer.status_code == 200, answer.text
    page = answer.json()
    assert page["total"] == 10  # the latest run's ten spans, not the earlier runs'
    worst = page["spans"][0]
    assert (worst["mast_from"], worst["wire_position"]) == ("M03", 0)
    assert worst["min_residual_thickness_mm"] == pytest.approx(WORN_MM[-1], abs=1e-9)
    values = [s["min_residual_thickness_mm"] for s in page["spans"]]
    assert values == sorted(values)
    assert page["next"] is None
    # every track's latest run, along the chainage; a chainage range
    both = client.get("/api/v1/spans").json()
    assert both["total"] == 13 and {s["track"] for s in both["spans"]} == {"1", "2"}
    ranged = client.get("/api/v1/spans", params=L1_1 | {"from_m": 1160, "to_m": 1240}).json()
    assert [s["mast_from"] for s in ranged["spans"]] == ["M03", "M04"]
    # one run's spans
    first = client.get("/api/v1/runs").json()[0]
    mine = client.get("/api/v1/spans", params={"run": first["uuid"], "order": "worst"}).json()
    assert mine["spans"][0]["min_residual_thickness_mm"] == pytest.approx(WORN_MM[0], abs=1e-9)
    assert {s["run_id"] for s in mine["spans"]} == {first["id"]}


@pytest.mark.parametrize("order", ["worst", "chainage"])
def test_span_pages_join_up_to_the_whole(api: Web, order: str) -> None:
    client = api.api("vera")
    whole = client.get("/api/v1/spans", params={"order": order, "limit": 1000}).json()
    seen, address = [], f"/api/v1/spans?order={order}&limit=4"
    while address:
        page = client.get(address).json()
        seen += page["spans"]
        address = page["next"]
        assert page["total"] == whole["total"]
    assert seen == whole["spans"]
    assert len({(s["run_id"], s["span"], s["wire"]) for s in seen}) == whole["total"] == 13


@pytest.mark.parametrize(
    ("query", "status", "words"),
    [
        ({"from_m": 2000, "to_m": 1000}, 422, "must not exceed"),
        ({"limit": 0}, 422, "limit"),
        ({"limit": 1001}, 422, "limit"),
        ({"offset": -1}, 422, "offset"),
        ({"from_m": "abc"}, 422, "from_m"),
        ({"from_m": "nan"}, 422, "from_m"),
        ({"order": "best"}, 422, "order"),
        ({"track": "1"}, 422, "line"),
        ({"line": "L1", "track": "9"}, 404, "no track"),
        ({"run": "999999"}, 404, "no run"),
    ],
)
def test_bad_span_queries_are_one_clear_error(
    api: Web, query: dict[str, Any], status: int, words: str
) -> None:
    answer = api.api("vera").get("/api/v1/spans", params=query)
    assert answer.status_code == status
    assert list(answer.json()) == ["error"] and words in answer.json()["error"]
    assert "Traceback" not in answer.text


def test_a_span_history_wear_rate_and_forecast(api: Web) -> None:
    client = api.api("vera")
    answer = client.get("/api/v1/spans/history", params=L1_1 | {"mast": "M03"})
    assert answer.status_code == 200, answer.text
    history = answer.json()
    assert history["policy"] == "china-maintenance-rules"
    (wire,) = history["wires"]
    assert (wire["mast_from"], wire["mast_to"], wire["wire_position"]) == ("M03", "M04", 0)
    assert [r["min_residual_thickness_mm"] for r in wire["runs"]] == pytest.approx(WORN_MM)
    assert wire["runs"][0]["stagger_min_mm"] == pytest.approx(-200.0)
    # the least-squares line through the four runs, to rounding; its interval around it
    rate = -SLOPE_MM_PER_YEAR
    assert wire["wear_rate_mm_per_year"] == pytest.approx(rate, abs=1e-6)
    assert wire["wear_rate_low_mm_per_year"] < rate < wire["wear_rate_high_mm_per_year"]
    assert wire["forecasts"], "the policy's limits are forecast"
    for forecast in wire["forecasts"]:
        # where the fitted line reaches the threshold, to the month
        assert forecast["threshold_mm"] < WORN_MM[-1]
        years = (forecast["threshold_mm"] - START_MM) / SLOPE_MM_PER_YEAR
        expected = (T0 + years * YEAR).date().isoformat()
        assert forecast["reaches"][:7] == expected[:7]  # to the month
        assert forecast["low"] <= forecast["reaches"] <= forecast["high"]
    assert history["maintenance_actions"] == []
    # a stretch by chainage; a wire position that is not there
    ranged = client.get("/api/v1/spans/history", params=L1_1 | {"from_m": 1150, "to_m": 1250})
    assert [w["mast_from"] for w in ranged.json()["wires"]] == ["M03", "M04"]
    none = client.get("/api/v1/spans/history", params=L1_1 | {"mast": "M03", "wire_position": 1})
    assert none.json()["wires"] == []


@pytest.mark.parametrize(
    ("query", "status", "words"),
    [
        ({"line": "L1", "track": "1"}, 422, "mast"),
        ({"line": "L1", "track": "1", "mast": "M03", "from_m": 1}, 422, "mast"),
        ({"line": "L1", "track": "1", "from_m": 5, "to_m": 1}, 422, "must not exceed"),
        ({"line": "L1", "track": "1", "mast": "M99"}, 400, "no mast 'M99'"),
        ({"line": "L1", "track": "1", "from_m": 9000, "to_m": 9100}, 400, "no span measured"),
        ({"line": "L1", "track": "7", "mast": "M03"}, 404, "no track"),
        ({"track": "1", "mast": "M03"}, 422, "line"),
    ],
)
def test_bad_history_queries_are_one_clear_error(
    api: Web, query: dict[str, Any], status: int, words: str
) -> None:
    answer = api.api("vera").get("/api/v1/spans/history", params=query)
    assert answer.status_code == status
    assert list(answer.json()) == ["error"] and words in answer.json()["error"]


def test_alerts_listed_acknowledged_and_resolved_by_the_user(api: Web, engine: Engine) -> None:
    vera, pat = api.api("vera"), api.api("pat")
    listed = vera.get("/api/v1/alerts", params={"level": "urgent", "track": "1"}).json()
    (alert,) = listed["alerts"]
    assert (alert["mast_from"], alert["wire_position"], alert["status"]) == ("M03", 0, "open")
    assert vera.get("/api/v1/alerts", params={"level": "critical"}).json()["alerts"] == []
    assert vera.get("/api/v1/alerts", params={"kind": "forecast"}).json()["alerts"] == []
    number = alert["id"]
    answer = pat.post(f"/api/v1/alerts/{number}/acknowledge")
    assert answer.status_code == 200, answer.text
    assert answer.json()["status"] == "acknowledged" and answer.json()["acknowledged_by"] == "pat"
    again = pat.post(f"/api/v1/alerts/{number}/acknowledge")
    assert again.status_code == 409 and "already acknowledged" in again.json()["error"]
    resolved = pat.post(f"/api/v1/alerts/{number}/resolve", json={"note": "checked on site"})
    assert resolved.status_code == 200 and resolved.json()["status"] == "resolved"
    assert resolved.json()["details"]["note"] == "checked on site"
    assert vera.get("/api/v1/alerts").json()["alerts"] == []
    assert len(vera.get("/api/v1/alerts", params={"status": "all"}).json()["alerts"]) == 1
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).where(AuditEntry.target == f"alert {number}"))
        assert [(e.actor, e.action, e.details["by"]) for e in entries] == [
            ("pat", "alert.acknowledge", "pat"),
            ("pat", "alert.resolve", "pat"),
        ]


def test_alert_writes_with_a_session_cookie_and_its_csrf_header(api: Web) -> None:
    client = api.client("pat")
    number = api.api("vera").get("/api/v1/alerts").json()["alerts"][0]["id"]
    assert client.post(f"/api/v1/alerts/{number}/acknowledge").status_code == 403
    headers = {"X-CSRF-Token": csrf_of(client.get("/").text)}
    answer = client.post(f"/api/v1/alerts/{number}/acknowledge", headers=headers)
    assert answer.status_code == 200 and answer.json()["acknowledged_by"] == "pat"


@pytest.mark.parametrize(
    ("path", "status"),
    [
        ("/alerts/999999/acknowledge", 404),
        ("/alerts/999999/resolve", 404),
        ("/alerts/abc/acknowledge", 422),
        ("/alerts/0/acknowledge", 422),
    ],
)
def test_unknown_alerts_are_one_clear_error(api: Web, path: str, status: int) -> None:
    answer = api.api("pat").post(f"/api/v1{path}")
    assert answer.status_code == status and list(answer.json()) == ["error"]


@pytest.mark.parametrize(
    ("query", "status"),
    [
        ({"status": "closed"}, 422),
        ({"level": "bad"}, 422),
        ({"limit": 5000}, 422),
    ],
)
def test_bad_alert_queries(api: Web, query: dict[str, Any], status: int) -> None:
    assert api.api("vera").get("/api/v1/alerts", params=query).status_code == status


def test_alert_pages_join_up(api: Web, engine: Engine) -> None:
    with session_scope(engine) as session:
        track_id = session.scalars(select(Alert.track_id)).one()
        session.add_all(
            fleet_alert(track_id, condition_key=f"more:{k}", start_chainage_m=1000.0 + k)
            for k in range(6)
        )
    client = api.api("vera")
    whole = client.get("/api/v1/alerts").json()["alerts"]
    seen, address = [], "/api/v1/alerts?limit=3"
    while address:
        page = client.get(address).json()
        seen += page["alerts"]
        address = page["next"]
    assert [a["id"] for a in seen] == [a["id"] for a in whole] and len(
        set(a["id"] for a in seen)
    ) == 7


def test_a_repair_recorded_by_masts_resolves_its_alert_and_restarts_the_history(
    api: Web, engine: Engine
) -> None:
    pat, vera = api.api("pat"), api.api("vera")
    body = {
        "line": "L1", "track": "1", "kind": "wire_replaced", "from_mast": "M03",
        "to_mast": "M04", "performed_at": "2023-06-01T08:00:00Z", "note": "new wire",
    }  # fmt: skip
    answer = pat.post("/api/v1/maintenance-actions", json=body)
    assert answer.status_code == 201, answer.text
    recorded = answer.json()
    assert recorded["action"]["recorded_by"] == "pat"
    assert (recorded["action"]["from_chainage_m"], recorded["action"]["to_chainage_m"]) == (
        1150.0,
        1200.0,
    )
    assert len(recorded["resolved_alerts"]) == 1
    listed = vera.get("/api/v1/maintenance-actions", params=L1_1 | {"from_m": 1160, "to_m": 1170})
    assert [a["id"] for a in listed.json()] == [recorded["action"]["id"]]
    elsewhere = vera.get(
        "/api/v1/maintenance-actions", params=L1_1 | {"from_m": 1300, "to_m": 1400}
    )
    assert elsewhere.json() == []
    history = vera.get("/api/v1/spans/history", params=L1_1 | {"mast": "M03"}).json()
    assert [a["kind"] for a in history["maintenance_actions"]] == ["wire_replaced"]
    assert [r["since_repair"] for r in history["wires"][0]["runs"]] == [False] * 4
    assert history["wires"][0]["wear_rate_mm_per_year"] is None
    with session_scope(engine, read_only=True) as session:
        (entry,) = session.scalars(
            select(AuditEntry).where(AuditEntry.action == "maintenance.record")
        )
        assert entry.actor == "pat" and entry.details["by"] == "pat"


@pytest.mark.parametrize(
    ("change", "status", "words"),
    [
        ({"from_m": 1150.0, "to_m": 1200.0}, 422, "from_mast and to_mast"),
        ({"from_mast": None}, 422, "from_mast and to_mast"),
        ({"from_mast": "M99"}, 400, "no mast 'M99'"),
        ({"kind": "painted"}, 422, "kind"),
        ({"performed_at": "yesterday"}, 422, "performed_at"),
        ({"performed_at": "2023-06-01T08:00:00"}, 422, "performed_at"),  # no time zone
        ({"track": "9"}, 404, "no track"),
        ({"wire_position": -1}, 422, "wire_position"),
    ],
)
def test_bad_maintenance_records_are_one_clear_error(
    api: Web, change: dict[str, Any], status: int, words: str
) -> None:
    body = {
        "line": "L1", "track": "1", "kind": "inspected", "from_mast": "M03", "to_mast": "M04",
        "performed_at": "2023-06-01T08:00:00Z",
    } | change  # fmt: skip
    answer = api.api("pat").post("/api/v1/maintenance-actions", json=body)
    assert answer.status_code == status, answer.text
    assert list(answer.json()) == ["error"] and words in answer.json()["error"]
