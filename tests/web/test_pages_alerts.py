"""The alerts page: filters, paging, geometry wording, and a planner's acknowledge, resolve and
maintenance, done and audited as the signed-in user; a viewer's forged POST refused."""

from __future__ import annotations

import re
from html import unescape
from urllib.parse import parse_qs, urlsplit

from sqlalchemy import Engine, select

from catenary.storage.database import session_scope
from catenary.storage.models import Alert, AuditEntry, MaintenanceAction
from tests.maintenance.conftest import T0, Fleet
from tests.web.conftest import Web


def _alerts(engine: Engine, extra: int = 0) -> dict[str, int]:
    """On line L1 track 1: a critical threshold alert (masts M03 to M04), a plan geometry
    alert on the stagger, a resolved one; ``extra`` plan alerts more."""
    with session_scope(engine) as session:
        track = Fleet(session).track("L1", "1")

        def alert(key: str, **columns: object) -> Alert:
            values: dict[str, object] = {
                "track_id": track.id,
                "wire": 0,
                "mast_from": "M03",
                "mast_to": "M04",
                "start_chainage_m": 1150.0,
                "end_chainage_m": 1200.0,
                "rule": "db-ril-997#2",
                "level": "critical",
                "kind": "threshold",
                "value": 8.25,
                "threshold": 8.5,
                "raised_at": T0,
                "condition_key": key,
            }
            return Alert(**(values | columns))

        made = [
            alert("worn"),
            alert(
                "stagger",
                kind="geometry",
                level="plan",
                rule="db-ril-997#g1",
                mast_from="M05",
                mast_to="M06",
                start_chainage_m=1250.0,
                end_chainage_m=1300.0,
                wire=1,
                value=431.0,
                threshold=400.0,
                details={"check": "stagger", "action": "adjust the stagger"},
            ),
            alert("done", status="resolved", level="urgent", resolved_at=T0),
            *(
                alert(f"more{k}", level="plan", start_chainage_m=2000.0 + k, end_chainage_m=2100.0)
                for k in range(extra)
            ),
        ]
        session.add_all(made)
        session.flush()
        return {"worn": made[0].id, "stagger": made[1].id, "done": made[2].id}


def _ids(html: str) -> list[int]:
    return [int(i) for i in re.findall(r'<tr id="alert-(\d+)"', html)]


def test_a_viewer_reads_and_filters_the_alerts_without_forms(web: Web, engine: Engine) -> None:
    ids = _alerts(engine)
    client = web.client("vera")
    html = client.get("/alerts").text
    assert _ids(html) == [ids["worn"], ids["stagger"]]  # active, most severe first
    worn = html[
        html.index(f'id="alert-{ids["worn"]}"') : html.index(f'id="alert-{ids["stagger"]}"')
    ]
    assert "db-ril-997#2" in worn and "masts M03 to M04" in worn
    assert "minimum 8.25 mm, limit 8.50 mm" in worn and "1+150.0 – 1+200.0" in worn
    assert "/span?line=L1&amp;track=1&amp;mast=M03&amp;wire_position=0" in worn
    assert "stagger 431.0 mm, limit 400.0 mm" in html and "adjust the stagger" in html
    assert '<form method="post" action="/alerts/' not in html and "Acknowledge" not in html
    assert _ids(client.get("/alerts?status=all").text) == [ids["worn"], ids["done"], ids["stagger"]]
    assert _ids(client.get("/alerts?status=open&level=plan").text) == [ids["stagger"]]
    assert _ids(client.get("/alerts?kind=geometry&line=L1&track=1").text) == [ids["stagger"]]
    assert _ids(client.get("/alerts?line=L2").text) == []


def test_bad_filters_are_one_clear_line(web: Web, engine: Engine) -> None:
    client = web.client("vera")
    bad = client.get("/alerts?level=severe")
    assert (
        bad.status_code == 400
        and "level 'severe': not one of plan, urgent, critical" in unescape(bad.text)
    )
    assert "Traceback" not in unescape(bad.text)
    assert "give the line as well" in unescape(client.get("/alerts?track=1").text)
    assert client.get("/alerts?page=0").status_code == 400


def test_alerts_come_a_page_at_a_time(web: Web, engine: Engine) -> None:
    _alerts(engine, extra=55)
    client = web.client("vera")
    first = client.get("/alerts?status=open&level=plan").text
    assert len(_ids(first)) == 50
    assert 'href="/alerts?status=open&amp;level=plan&amp;page=2" rel="next"' in first
    second = client.get("/alerts?status=open&level=plan&page=2").text
    assert len(_ids(second)) == 6 and 'rel="prev"' in second and 'rel="next"' not in second
    assert not set(_ids(first)) & set(_ids(second))


def _audit(engine: Engine, action: str) -> list[tuple[str, str, dict[str, object]]]:
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).where(AuditEntry.action == action))
        return [(e.actor, e.target, e.details) for e in entries]


def test_a_planner_acknowledges_and_resolves_as_themselves(web: Web, engine: Engine) -> None:
    ids = _alerts(engine)
    client = web.client("pat")
    page = "/alerts?status=open&level=critical"
    html = client.get(page).text
    assert f'action="/alerts/{ids["worn"]}/acknowledge"' in html
    answer = web.post_form(
        client, page, f"/alerts/{ids['worn']}/acknowledge", back="status=open&level=critical"
    )
    assert answer.status_code == 303
    target = urlsplit(answer.headers["location"])
    assert target.path == "/alerts"
    assert parse_qs(target.query) == {
        "status": ["open"],
        "level": ["critical"],
        "done": ["acknowledged"],
        "alert": [str(ids["worn"])],
    }
    listed = client.get(answer.headers["location"]).text
    assert f"Alert {ids['worn']} acknowledged." in listed
    acknowledged = client.get("/alerts?status=acknowledged").text
    assert "acknowledged by pat" in acknowledged
    assert _audit(engine, "alert.acknowledge") == [
        ("pat", f"alert {ids['worn']}", {"by": "pat", "status": "acknowledged"})
    ]
    again = web.post_form(client, page, f"/alerts/{ids['worn']}/acknowledge")
    assert again.status_code == 400 and "already acknowledged (by pat" in unescape(again.text)
    resolved = web.post_form(
        client, page, f"/alerts/{ids['stagger']}/resolve", note="stagger < 400 mm <b>now</b>"
    )
    assert resolved.status_code == 303 and "done=resolved" in resolved.headers["location"]
    with session_scope(engine, read_only=True) as session:
        alert = session.get(Alert, ids["stagger"])
        assert alert is not None and alert.status == "resolved"
        assert alert.details is not None and alert.details["resolved_by"] == "pat"
    [(actor, _, details)] = _audit(engine, "alert.resolve")
    assert actor == "pat" and details["note"] == "stagger < 400 mm <b>now</b>"
    shown = client.get("/alerts?status=resolved").text
    assert "<b>now</b>" not in shown  # the note is not shown raw anywhere
    assert web.post_form(client, page, "/alerts/999999/resolve").status_code == 404


def test_a_planner_records_maintenance_on_the_alerts_stretch(web: Web, engine: Engine) -> None:
    ids = _alerts(engine)
    client = web.client("pat")
    answer = web.post_form(
        client,
        "/alerts",
        f"/alerts/{ids['worn']}/maintenance",
        kind="wire_replaced",
        performed_at="2024-03-01",
        note="new wire",
        back="status=active",
    )
    assert answer.status_code == 303
    query = parse_qs(urlsplit(answer.headers["location"]).query)
    assert query["done"] == ["maintenance"] and query["resolved"] == ["1"]
    assert "1 alert(s) resolved" in client.get(answer.headers["location"]).text
    with session_scope(engine, read_only=True) as session:
        [action] = session.scalars(select(MaintenanceAction))
        assert (action.from_chainage_m, action.to_chainage_m) == (1150.0, 1200.0)
        assert (action.mast_from, action.mast_to, action.wire) == ("M03", "M04", 0)
        assert action.recorded_by == "pat" and action.note == "new wire"
        assert action.performed_at.isoformat() == "2024-03-01T12:00:00+00:00"
        worn = session.get(Alert, ids["worn"])
        assert worn is not None and worn.status == "resolved"
    [(actor, _, details)] = _audit(engine, "maintenance.record")
    assert actor == "pat" and details["by"] == "pat" and details["resolved_alerts"] == [ids["worn"]]
    for fields, message in (
        ({"kind": "painted", "performed_at": "2024-03-01"}, "unknown maintenance kind 'painted'"),
        ({"kind": "inspected", "performed_at": "yesterday"}, "give a date YYYY-MM-DD"),
        ({"kind": "inspected", "performed_at": "2999-01-01"}, "in the future"),
    ):
        refused = web.post_form(
            client, "/alerts", f"/alerts/{ids['stagger']}/maintenance", **fields
        )
        assert refused.status_code == 400 and message in unescape(refused.text)


def test_a_viewer_or_a_forged_form_cannot_change_alerts(web: Web, engine: Engine) -> None:
    ids = _alerts(engine)
    vera = web.client("vera")
    for action in ("acknowledge", "resolve", "maintenance"):
        forged = web.post_form(vera, "/alerts", f"/alerts/{ids['worn']}/{action}")
        assert forged.status_code == 403
    pat = web.client("pat")
    no_token = pat.post(f"/alerts/{ids['worn']}/acknowledge", data={"back": ""})
    assert no_token.status_code == 403 and "reload" in no_token.text
    with session_scope(engine, read_only=True) as session:
        alert = session.get(Alert, ids["worn"])
        assert alert is not None and alert.status == "open"
    assert _audit(engine, "alert.acknowledge") == []


def test_the_redirect_keeps_only_the_filters(web: Web, engine: Engine) -> None:
    ids = _alerts(engine)
    client = web.client("pat")
    answer = web.post_form(
        client,
        "/alerts",
        f"/alerts/{ids['worn']}/acknowledge",
        back="status=open&next=https://evil.example/&done=resolved",
    )
    assert (
        answer.headers["location"] == f"/alerts?status=open&done=acknowledged&alert={ids['worn']}"
    )
