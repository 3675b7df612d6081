"""Who may do what: sign-in and sign-out, sessions, CSRF, the sign-in limit, tokens, roles."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest
from sqlalchemy import Engine, select

from catenary.storage.database import session_scope
from catenary.storage.models import AuditEntry, SignInFailure
from catenary.storage.users import disable_user, set_password
from catenary.web.auth import SESSION_COOKIE, SignInLimiter
from tests.web.conftest import PASSWORD, Web, csrf_of


def test_public_addresses_need_no_user(web: Web) -> None:
    client = web.anonymous()
    assert client.get("/health").json() == {"status": "ok"}
    spec = client.get("/api/v1/openapi.json")
    assert spec.status_code == 200 and spec.json()["info"]["title"] == "catenary"
    assert client.get("/sign-in").status_code == 200


def test_a_page_without_a_session_sends_to_sign_in_and_back(web: Web) -> None:
    client = web.anonymous()
    answer = client.get("/alerts?status=open")
    assert answer.status_code == 303
    assert answer.headers["location"] == "/sign-in?next=/alerts%3Fstatus%3Dopen"
    page = client.get(answer.headers["location"])
    assert 'name="next" value="/alerts?status=open"' in page.text
    signed = client.post(
        "/sign-in",
        data={
            "name": "vera",
            "password": PASSWORD,
            "next": "/alerts?status=open",
            "csrf_token": csrf_of(page.text),
        },
    )
    assert signed.status_code == 303 and signed.headers["location"] == "/alerts?status=open"
    cookie = signed.headers["set-cookie"]
    assert "HttpOnly" in cookie and "SameSite=lax" in cookie and "Secure" not in cookie


def test_sign_in_never_redirects_off_site(web: Web) -> None:
    client = web.anonymous()
    page = client.get("/sign-in")
    for target in ("https://evil.example/", "//evil.example/", "/\\evil.example"):
        answer = client.post(
            "/sign-in",
            data={
                "name": "vera",
                "password": PASSWORD,
                "next": target,
                "csrf_token": csrf_of(page.text),
            },
        )
        assert answer.headers["location"] == "/"
        page = client.get("/sign-in")


def test_a_cookie_over_tls_is_secure(web: Web) -> None:
    client = web.anonymous()
    client.base_url = "https://127.0.0.1"  # type: ignore[assignment]
    assert "Secure" in client.get("/sign-in").headers["set-cookie"]


def test_a_wrong_password_or_a_missing_csrf_token_is_refused(web: Web) -> None:
    client = web.anonymous()
    token = csrf_of(client.get("/sign-in").text)
    wrong = client.post("/sign-in", data={"name": "vera", "password": "nope", "csrf_token": token})
    assert wrong.status_code == 401 and "wrong password" in wrong.text
    assert SESSION_COOKIE in client.cookies
    forged = client.post("/sign-in", data={"name": "vera", "password": PASSWORD})
    assert forged.status_code == 403 and "reload" in forged.text
    other = web.anonymous()  # a form from another session
    stolen = other.post(
        "/sign-in", data={"name": "vera", "password": PASSWORD, "csrf_token": token}
    )
    assert stolen.status_code == 403


def test_sign_in_is_rate_limited_per_name(web: Web) -> None:
    client = web.anonymous()
    for _ in range(5):
        token = csrf_of(client.get("/sign-in").text)
        client.post("/sign-in", data={"name": "pat", "password": "guess", "csrf_token": token})
    token = csrf_of(client.get("/sign-in").text)
    blocked = client.post(
        "/sign-in", data={"name": "pat", "password": PASSWORD, "csrf_token": token}
    )
    assert blocked.status_code == 429 and int(blocked.headers["retry-after"]) > 800
    assert "too many failed sign-ins" in blocked.text
    web.client("vera")  # another user is not blocked by pat's failures from another client


def test_the_limiter_forgets_after_its_window_and_counts_addresses(engine: Engine) -> None:
    start = datetime(2026, 1, 1, tzinfo=UTC)
    now = [start]
    limiter = SignInLimiter(3, 60.0, clock=lambda: now[0])
    with session_scope(engine) as session:
        for _ in range(3):
            assert limiter.retry_after_s(session, "Pat", "10.0.0.1") == 0
            limiter.failed(session, "Pat", "10.0.0.1")
            now[0] += timedelta(seconds=10)
        # names fold case; the first failure (t=0) leaves the window at t=60
        assert limiter.retry_after_s(session, "pat", "10.0.0.2") == pytest.approx(30.0)
        assert limiter.retry_after_s(session, "vera", "10.0.0.1") == 0
        for name in ("a", "b", "c", "d", "e", "f", "g", "h", "i"):
            limiter.failed(session, name, "10.0.0.1")
        assert limiter.retry_after_s(session, "vera", "10.0.0.1") > 0  # 12 from one address
        now[0] = start + timedelta(seconds=60)
        assert limiter.retry_after_s(session, "pat", "10.0.0.2") == 0
        limiter.failed(session, "x", "10.0.0.3")  # forgets what left the window: t=0's pair
        kept = session.scalars(select(SignInFailure.at)).all()
        assert len(kept) == 2 * 2 + 9 * 2 + 2 and min(kept) == start + timedelta(seconds=10)


def test_sign_out_ends_the_session(web: Web) -> None:
    client = web.client("vera")
    assert client.get("/").status_code == 200
    answer = web.post_form(client, "/", "/sign-out")
    assert answer.status_code == 303
    assert client.get("/").status_code == 303


def test_a_new_password_or_a_disabled_user_ends_sessions(web: Web, engine: Engine) -> None:
    vera, pat = web.client("vera"), web.client("pat")
    now = datetime.now(UTC)
    with session_scope(engine) as session:
        set_password(session, "vera", "another long password", actor="test", now=now)
        disable_user(session, "pat", actor="test", now=now)
    assert vera.get("/").status_code == 303
    assert pat.get("/").status_code == 303
    assert web.api("pat").get("/api/v1/runs").status_code == 401


def test_the_api_needs_a_user_and_says_how(web: Web) -> None:
    client = web.anonymous()
    answer = client.get("/api/v1/runs")
    assert answer.status_code == 401
    assert answer.headers["www-authenticate"] == "Bearer"
    assert "Bearer" in answer.json()["error"]
    client.headers["Authorization"] = "Bearer cat_not-a-token"
    assert "unknown, revoked or expired" in client.get("/api/v1/runs").json()["error"]
    client.headers["Authorization"] = "Basic dmVyYTpwdw=="
    assert client.get("/api/v1/runs").status_code == 401
    assert web.api("vera").get("/api/v1/runs").status_code == 200


def test_a_cookie_write_to_the_api_needs_the_csrf_header(web: Web) -> None:
    client = web.client("pat")
    answer = client.post("/api/v1/alerts/1/acknowledge")
    assert answer.status_code == 403 and "X-CSRF-Token" in answer.json()["error"]


def test_sign_in_is_in_the_audit_trail(web: Web, engine: Engine) -> None:
    web.client("ada")
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).where(AuditEntry.action == "user.sign_in"))
        assert [(e.actor, e.target) for e in entries] == [("ada", "user ada")]


def test_unknown_addresses_and_bad_parameters_are_one_clear_error(web: Web) -> None:
    api = web.api("vera")
    missing = api.get("/api/v1/nothing-here")
    assert missing.status_code == 404
    assert missing.json() == {"error": "no such address: /api/v1/nothing-here"}
    page = web.client("vera").get("/nothing-here")
    assert page.status_code == 404 and "no such address" in page.text
    assert "Traceback" not in page.text


def test_every_answer_carries_the_security_headers(web: Web) -> None:
    for answer in (
        web.anonymous().get("/sign-in"),
        web.anonymous().get("/api/v1/runs"),
        web.client("vera").get("/"),
        web.anonymous().get("/static/catenary.css"),
    ):
        policy = answer.headers["content-security-policy"]
        assert "script-src 'self';" in policy and "frame-ancestors 'none'" in policy
        assert answer.headers["x-content-type-options"] == "nosniff"
