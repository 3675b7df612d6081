"""The web service over a migrated database (each backend), with three users and their
clients: ``web.client("vera")`` is signed in as the viewer, ``web.api("pat")`` sends the
planner's API token, ``web.anonymous()`` is nobody."""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import UTC, datetime
from typing import Any

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from catenary.config import load_settings
from catenary.storage.database import session_scope
from catenary.storage.users import add_user, create_token
from catenary.web.app import create_app

PASSWORD = "correct horse battery staple"
USERS = {"vera": "viewer", "pat": "planner", "ada": "admin"}
BASE_URL = "http://127.0.0.1"


def csrf_of(html: str) -> str:
    """The CSRF token of the first form of a page."""
    found = re.search(r'name="csrf_token" value="([^"]+)"', html)
    assert found is not None, "the page has no form with a CSRF token"
    return found.group(1)


class Web:
    """The application and its users' API tokens (``tokens[name]``)."""

    def __init__(self, app: FastAPI, tokens: dict[str, str]) -> None:
        self.app, self.tokens = app, tokens

    def anonymous(self) -> TestClient:
        return TestClient(self.app, base_url=BASE_URL, follow_redirects=False)

    def client(self, name: str, password: str = PASSWORD) -> TestClient:
        """A browser-like client signed in as ``name``."""
        client = self.anonymous()
        page = client.get("/sign-in")
        answer = client.post(
            "/sign-in",
            data={"name": name, "password": password, "csrf_token": csrf_of(page.text)},
        )
        assert answer.status_code == 303, answer.text
        return client

    def api(self, name: str) -> TestClient:
        """A program's client sending ``name``'s API token."""
        client = self.anonymous()
        client.headers["Authorization"] = f"Bearer {self.tokens[name]}"
        return client

    def post_form(self, client: TestClient, page: str, action: str, **fields: Any) -> Any:
        """Post ``fields`` to ``action`` as the form of ``page`` would (its CSRF token)."""
        token = csrf_of(client.get(page).text)
        return client.post(action, data={"csrf_token": token, **fields})


@pytest.fixture
def web(engine: Engine, database_url: str) -> Iterator[Web]:
    """The web service over ``engine``'s database, with users vera (viewer), pat (planner) and
    ada (admin), each with an API token."""
    now = datetime.now(UTC)
    tokens = {}
    with session_scope(engine) as session:
        for name, role in USERS.items():
            add_user(session, name, role, PASSWORD, actor="test", now=now)
            tokens[name] = create_token(session, name, "test", actor="test", now=now)[1]
    app = create_app(load_settings(database_url=database_url))
    yield Web(app, tokens)
    app.state.web.engine.dispose()
