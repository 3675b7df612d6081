"""The administration page (``/admin``, admins only): users (add, disable, set a password), API
tokens (create, shown once on the answer page; revoke) and the latest audit entries; every
change through ``catenary.storage.users`` as the signed-in admin."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from typing import Annotated
from urllib.parse import urlencode

from fastapi import APIRouter, Depends, Request
from fastapi.responses import RedirectResponse
from sqlalchemy.orm import Session
from starlette.datastructures import FormData
from starlette.responses import Response

from catenary.errors import UserError
from catenary.storage.database import session_scope
from catenary.storage.models import USER_ROLES
from catenary.storage.users import (
    MIN_PASSWORD_LENGTH,
    add_user,
    audit_entries,
    create_token,
    disable_user,
    list_tokens,
    list_users,
    revoke_token,
    set_password,
    token_status,
)
from catenary.web.app import state
from catenary.web.auth import Principal, checked_form, page_user, requires
from catenary.web.templating import render

__all__ = ["AUDIT_SHOWN", "router"]

router = APIRouter()

AUDIT_SHOWN = 50
"""The latest audit entries the page shows."""

Admin = Annotated[Principal, requires("admin", page_user)]
Form = Annotated[FormData, Depends(checked_form)]

_NOTICES = {
    "user_added": "User {name} added.",
    "user_disabled": "User {name} disabled: their sessions and tokens are refused.",
    "password_set": "The password of {name} is set.",
    "token_revoked": "Token {name} revoked.",
}


def _page(
    request: Request,
    *,
    error: str | None = None,
    token: tuple[str, str, str] | None = None,
    status: int = 200,
) -> Response:
    """The page, with a one-line ``error`` or a new ``token`` (user, name, token) if any."""
    now = datetime.now(UTC)
    query: Mapping[str, str] = request.query_params
    template = _NOTICES.get(query.get("done", ""))
    with session_scope(state(request).engine, read_only=True) as session:
        tokens = [(t, token_status(t, now)) for t in list_tokens(session)]
        context = {
            "users": list_users(session),
            "tokens": tokens,
            "audit": audit_entries(session, limit=AUDIT_SHOWN),
            "roles": USER_ROLES,
            "min_password": MIN_PASSWORD_LENGTH,
            "error": error,
            "new_token": token,
            "notice": template.format(name=query.get("name", "")) if template else None,
        }
        response = render(request, "admin.html", context, status)
    if token is not None:
        response.headers["Cache-Control"] = "no-store"  # the token is shown this once
    return response


def _change(request: Request, change: Callable[[Session, datetime], Mapping[str, str]]) -> Response:
    """Make ``change`` (it returns the notice's ``done`` and ``name``) and answer 303 to the
    page; a ``UserError`` is the page with its line, 400."""
    try:
        with session_scope(state(request).engine) as session:
            done = change(session, datetime.now(UTC))
    except UserError as exc:
        return _page(request, error=str(exc), status=400)
    return RedirectResponse("/admin?" + urlencode(done), status_code=303)


def _field(form: FormData, name: str) -> str:
    value = form.get(name, "")
    return value if isinstance(value, str) else ""


def _password(form: FormData) -> str:
    """The password typed twice; a ``UserError`` when the two differ."""
    password = _field(form, "password")
    if password != _field(form, "password_again"):
        raise UserError("the two passwords differ: type the same one twice")
    return password


@router.get("/admin")
def admin(request: Request, user: Admin) -> Response:
    return _page(request)


@router.post("/admin/users")
def add(request: Request, user: Admin, form: Form) -> Response:
    def change(session: Session, now: datetime) -> Mapping[str, str]:
        name = _field(form, "name").strip()
        added = add_user(
            session, name, _field(form, "role"), _password(form), actor=user.name, now=now
        )
        return {"done": "user_added", "name": added.name}

    return _change(request, change)


@router.post("/admin/users/disable")
def disable(request: Request, user: Admin, form: Form) -> Response:
    def change(session: Session, now: datetime) -> Mapping[str, str]:
        name = _field(form, "name")
        if name == user.name:
            raise UserError(f"{name} cannot disable themselves: another admin can")
        disable_user(session, name, actor=user.name, now=now)
        return {"done": "user_disabled", "name": name}

    return _change(request, change)


@router.post("/admin/users/password")
def password(request: Request, user: Admin, form: Form) -> Response:
    def change(session: Session, now: datetime) -> Mapping[str, str]:
        name = _field(form, "name")
        set_password(session, name, _password(form), actor=user.name, now=now)
        return {"done": "password_set", "name": name}

    return _change(request, change)


def _expires_days(text: str) -> float | None:
    if not text.strip():
        return None
    try:
        return float(text)
    except ValueError:
        raise UserError(f"expires in {text[:40]!r} days: give a number of days") from None


@router.post("/admin/tokens")
def token(request: Request, user: Admin, form: Form) -> Response:
    """Create a token and show it on the answer page, the only time it is shown."""
    owner, name = _field(form, "user"), _field(form, "name").strip()
    try:
        expires = _expires_days(_field(form, "expires_days"))
        with session_scope(state(request).engine) as session:
            _, secret = create_token(
                session, owner, name, actor=user.name, now=datetime.now(UTC), expires_days=expires
            )
    except UserError as exc:
        return _page(request, error=str(exc), status=400)
    return _page(request, token=(owner, name, secret))


@router.post("/admin/tokens/{token_id}/revoke")
def revoke(request: Request, token_id: int, user: Admin, form: Form) -> Response:
    def change(session: Session, now: datetime) -> Mapping[str, str]:
        revoked = revoke_token(session, token_id, actor=user.name, now=now)
        return {"done": "token_revoked", "name": f"{revoked.name} of {revoked.user.name}"}

    return _change(request, change)
