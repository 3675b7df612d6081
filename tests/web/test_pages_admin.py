"""The administration page: admins only; users added, disabled and given a password, tokens
created (shown once) and revoked, each in the audit trail under the admin's name; bad input
one clear line with 400."""

from __future__ import annotations

import re
from html import unescape

from sqlalchemy import Engine, select

from catenary.storage.database import session_scope
from catenary.storage.models import ApiToken, AuditEntry, User
from tests.web.conftest import PASSWORD, Web

NEW_PASSWORD = "a long enough new password"


def _audit(engine: Engine, action: str) -> list[tuple[str, str]]:
    with session_scope(engine, read_only=True) as session:
        entries = session.scalars(select(AuditEntry).where(AuditEntry.action == action))
        return [(e.actor, e.target) for e in entries]


def test_only_an_admin_may_open_or_post_to_it(web: Web) -> None:
    assert web.client("pat").get("/admin").status_code == 403
    assert web.client("vera").get("/admin").status_code == 403
    pat = web.client("pat")
    forged = web.post_form(
        pat,
        "/",
        "/admin/users",
        name="eve",
        role="admin",
        password=PASSWORD,
        password_again=PASSWORD,
    )
    assert forged.status_code == 403
    assert "Administration" not in web.client("pat").get("/").text  # not in the navigation
    page = web.client("ada").get("/admin")
    assert page.status_code == 200
    users = page.text[page.text.index('id="users"') : page.text.index('id="tokens"')]
    assert [unescape(n) for n in re.findall(r"<tr id=\"user-\d+\">\s*<td>([^<]+)</td>", users)] == [
        "ada",
        "pat",
        "vera",
    ]
    assert "test" in page.text  # the tokens made by the fixture's actor, in the audit list


def test_an_admin_adds_a_user_who_can_sign_in(web: Web, engine: Engine) -> None:
    ada = web.client("ada")
    answer = web.post_form(
        ada,
        "/admin",
        "/admin/users",
        name="<i>eve</i>",
        role="planner",
        password=NEW_PASSWORD,
        password_again=NEW_PASSWORD,
    )
    assert answer.status_code == 303 and answer.headers["location"].startswith(
        "/admin?done=user_added"
    )
    page = ada.get(answer.headers["location"]).text
    assert "User &lt;i&gt;eve&lt;/i&gt; added." in page and "<i>eve</i>" not in page
    assert _audit(engine, "user.add")[-1] == ("ada", "user <i>eve</i>")
    assert web.client("<i>eve</i>", NEW_PASSWORD).get("/alerts").status_code == 200


def test_bad_input_is_one_line_with_400(web: Web) -> None:
    ada = web.client("ada")
    same = {"password": NEW_PASSWORD, "password_again": NEW_PASSWORD}
    for fields, message in (
        ({"name": "pat", **same}, "user 'pat' exists already"),
        (
            {"name": "eve", "password": "short", "password_again": "short"},
            "the password is 5 characters long (at least 12 characters)",
        ),
        (
            {"name": "eve", "password": NEW_PASSWORD, "password_again": "something else"},
            "the two passwords differ: type the same one twice",
        ),
    ):
        answer = web.post_form(ada, "/admin", "/admin/users", role="viewer", **fields)
        assert answer.status_code == 400
        errors = re.findall(r'<p class="error" role="alert">([^<]*)</p>', answer.text)
        assert [unescape(e) for e in errors] == [message]
        assert "Traceback" not in answer.text and 'id="users"' in answer.text
    role = web.post_form(
        ada,
        "/admin",
        "/admin/users",
        name="eve",
        role="god",
        password=NEW_PASSWORD,
        password_again=NEW_PASSWORD,
    )
    assert role.status_code == 400 and "role 'god': not one of viewer, planner, admin" in unescape(
        role.text
    )
    myself = web.post_form(ada, "/admin", "/admin/users/disable", name="ada")
    assert myself.status_code == 400 and "ada cannot disable themselves" in myself.text


def test_an_admin_disables_a_user_and_sets_a_password(web: Web, engine: Engine) -> None:
    ada, vera = web.client("ada"), web.client("vera")
    answer = web.post_form(ada, "/admin", "/admin/users/disable", name="vera")
    assert answer.status_code == 303
    assert "User vera disabled" in ada.get(answer.headers["location"]).text
    assert vera.get("/").status_code == 303  # her session has ended
    with session_scope(engine, read_only=True) as session:
        assert session.scalars(select(User.disabled).where(User.name == "vera")).one()
    assert _audit(engine, "user.disable") == [("ada", "user vera")]
    again = web.post_form(ada, "/admin", "/admin/users/disable", name="vera")
    assert again.status_code == 400 and "already disabled" in again.text
    changed = web.post_form(
        ada,
        "/admin",
        "/admin/users/password",
        name="pat",
        password=NEW_PASSWORD,
        password_again=NEW_PASSWORD,
    )
    assert changed.status_code == 303
    assert _audit(engine, "user.set_password") == [("ada", "user pat")]
    web.client("pat", NEW_PASSWORD)


def test_a_new_token_is_shown_once_and_works_until_revoked(web: Web, engine: Engine) -> None:
    ada = web.client("ada")
    answer = web.post_form(
        ada, "/admin", "/admin/tokens", user="pat", name="maximo", expires_days="30"
    )
    assert answer.status_code == 200 and answer.headers["cache-control"] == "no-store"
    [token] = re.findall(r'<p class="token">(cat_[^<]+)</p>', answer.text)
    page = ada.get("/admin").text
    assert token not in page and "maximo" in page  # listed, never shown again
    with session_scope(engine, read_only=True) as session:
        row = session.scalars(select(ApiToken).where(ApiToken.name == "maximo")).one()
        assert row.expires_at is not None and token not in (row.token_hash,)
        token_id = row.id
    client = web.anonymous()
    client.headers["Authorization"] = f"Bearer {token}"
    assert client.get("/api/v1/runs").status_code == 200
    row_html = page[page.index(f'id="token-{token_id}"') :]
    assert "active" in row_html[: row_html.index("</tr>")]
    assert _audit(engine, "token.create")[-1] == ("ada", f"token {token_id}")
    revoked = web.post_form(ada, "/admin", f"/admin/tokens/{token_id}/revoke")
    assert revoked.status_code == 303
    assert "Token maximo of pat revoked." in ada.get(revoked.headers["location"]).text
    assert client.get("/api/v1/runs").status_code == 401
    assert _audit(engine, "token.revoke") == [("ada", f"token {token_id}")]
    for fields, message in (
        ({"user": "pat", "name": "maximo"}, "user 'pat' has a token 'maximo' already"),
        ({"user": "pat", "name": "sap", "expires_days": "soon"}, "expires in 'soon' days"),
        ({"user": "nobody", "name": "sap"}, "nobody"),
    ):
        refused = web.post_form(ada, "/admin", "/admin/tokens", **fields)
        assert refused.status_code == 400 and message in unescape(refused.text)
        assert '<p class="token">' not in refused.text
