"""Who is asking: signed session cookies, CSRF tokens, rate-limited sign-in, API tokens, roles.

A person signs in with a name and password (``catenary.storage.users``, Argon2) and gets a
session cookie: signed and time-stamped (``itsdangerous``), HttpOnly, SameSite=Lax, Secure
when the request came over TLS (behind a reverse proxy, uvicorn's ``--proxy-headers`` tells).
The cookie holds the user's id, a digest of their password hash (so a new password or a
disabled user ends every session) and the session's CSRF token, which every form sends back
(``checked_form``) and the API's cookie-authenticated writes send as ``X-CSRF-Token``. A
program sends ``Authorization: Bearer <token>`` instead and needs no CSRF token.

Failed sign-ins are counted per user name and per client address (``SignInLimiter``, in the
database: every process of the service sees the same count); past the limit, sign-in answers
429 with ``Retry-After`` until the window has passed.

Roles are ordered: a viewer reads, a planner also changes alerts and records maintenance, an
admin also manages users (``requires``).
"""

from __future__ import annotations

import hashlib
import secrets
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any

from fastapi import Depends, HTTPException, Request
from itsdangerous import BadSignature, URLSafeTimedSerializer
from sqlalchemy import delete, select
from sqlalchemy.orm import Session
from starlette.datastructures import FormData
from starlette.responses import Response

from catenary.storage.database import session_scope
from catenary.storage.models import SIGN_IN_KEY_LENGTH, USER_ROLES, SignInFailure, User
from catenary.storage.users import authenticate_token

__all__ = [
    "CSRF_FIELD",
    "CSRF_HEADER",
    "SESSION_COOKIE",
    "Principal",
    "SessionData",
    "Sessions",
    "SignInLimiter",
    "SignInRequired",
    "api_user",
    "checked_form",
    "page_user",
    "password_generation",
    "requires",
]

SESSION_COOKIE = "catenary_session"
CSRF_FIELD = "csrf_token"
CSRF_HEADER = "X-CSRF-Token"
ROLE_RANK = {role: rank for rank, role in enumerate(("viewer", "planner", "admin"))}
assert set(ROLE_RANK) == set(USER_ROLES)


def password_generation(user: User) -> str:
    """A digest of the user's password hash: changes when the password does."""
    return hashlib.sha256(user.password_hash.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class SessionData:
    """What the session cookie holds: the signed-in user (None before sign-in), the digest of
    their password hash, and the session's CSRF token."""

    user_id: int | None
    generation: str
    csrf: str

    @classmethod
    def anonymous(cls) -> SessionData:
        return cls(None, "", secrets.token_urlsafe(32))

    @classmethod
    def signed_in(cls, user: User) -> SessionData:
        """A new session (a new CSRF token: nothing of the anonymous one carries over)."""
        return cls(user.id, password_generation(user), secrets.token_urlsafe(32))


class Sessions:
    """Reads and writes the signed session cookie; ``max_age_s`` after it was written it is
    refused."""

    def __init__(self, secret_key: str, max_age_s: float) -> None:
        self._serializer = URLSafeTimedSerializer(secret_key, salt="catenary-session")
        self.max_age_s = max_age_s

    def read(self, request: Request) -> SessionData | None:
        value = request.cookies.get(SESSION_COOKIE)
        if not value:
            return None
        try:
            data = self._serializer.loads(value, max_age=int(self.max_age_s))
            return SessionData(data["u"], str(data["g"]), str(data["c"]))
        except (BadSignature, KeyError, TypeError):
            return None

    def write(self, response: Response, request: Request, data: SessionData) -> None:
        value = self._serializer.dumps({"u": data.user_id, "g": data.generation, "c": data.csrf})
        response.set_cookie(
            SESSION_COOKIE,
            value,
            max_age=int(self.max_age_s),
            httponly=True,
            samesite="lax",
            secure=request.url.scheme == "https",
            path="/",
        )

    def clear(self, response: Response, request: Request) -> None:
        response.delete_cookie(
            SESSION_COOKIE,
            httponly=True,
            samesite="lax",
            secure=request.url.scheme == "https",
            path="/",
        )


class SignInLimiter:
    """Failed sign-ins in a sliding window of ``window_s``: at most ``attempts`` per user name,
    and ``ADDRESS_FACTOR`` times as many per client address (colleagues behind one proxy
    share an address; a guesser trying many names is still stopped).

    The failures are rows of the database (``SignInFailure``), so every process of the
    service counts the same; ``clock`` gives the time (UTC).
    """

    ADDRESS_FACTOR = 4

    def __init__(
        self,
        attempts: int,
        window_s: float,
        clock: Callable[[], datetime] = lambda: datetime.now(UTC),
    ) -> None:
        self.attempts, self.window_s, self._clock = attempts, window_s, clock

    def _keys(self, name: str, address: str) -> tuple[tuple[str, int], ...]:
        return (
            (f"user:{name.casefold()}"[:SIGN_IN_KEY_LENGTH], self.attempts),
            (f"address:{address}"[:SIGN_IN_KEY_LENGTH], self.attempts * self.ADDRESS_FACTOR),
        )

    def retry_after_s(self, session: Session, name: str, address: str) -> float:
        """0 if ``name`` may try to sign in from ``address``, else the seconds until it may."""
        now = self._clock()
        since = now - timedelta(seconds=self.window_s)
        wait = 0.0
        for key, attempts in self._keys(name, address):
            recent = session.scalars(
                select(SignInFailure.at)
                .where(SignInFailure.key == key, SignInFailure.at > since)
                .order_by(SignInFailure.at.desc())
                .limit(attempts)
            ).all()
            if len(recent) >= attempts:
                wait = max(wait, (recent[-1] - since).total_seconds())
        return wait

    def failed(self, session: Session, name: str, address: str) -> None:
        """Count a failure against the name and the address (and forget those that left the
        window)."""
        now = self._clock()
        since = now - timedelta(seconds=self.window_s)
        session.execute(delete(SignInFailure).where(SignInFailure.at <= since))
        session.add_all(SignInFailure(key=key, at=now) for key, _ in self._keys(name, address))
        session.flush()

    def succeeded(self, session: Session, name: str) -> None:
        """Forget the user name's failures (not the address's)."""
        key = self._keys(name, "")[0][0]
        session.execute(delete(SignInFailure).where(SignInFailure.key == key))


@dataclass(frozen=True)
class Principal:
    """The user a request acts for; ``csrf`` is the session's token (None for a bearer token,
    which needs none)."""

    user_id: int
    name: str
    role: str
    csrf: str | None

    def may(self, role: str) -> bool:
        """Whether this user has ``role`` or a higher one."""
        return ROLE_RANK[self.role] >= ROLE_RANK[role]


class SignInRequired(Exception):
    """A page was asked for without a valid session: the answer is the sign-in page."""


def _state(request: Request) -> Any:
    return request.app.state.web


def _from_session(request: Request) -> Principal | None:
    state = _state(request)
    data = state.sessions.read(request)
    if data is None or data.user_id is None:
        return None
    with session_scope(state.engine, read_only=True) as session:
        user = session.get(User, data.user_id)
        if user is None or user.disabled or password_generation(user) != data.generation:
            return None
        return Principal(user.id, user.name, user.role, data.csrf)


def _from_token(request: Request, token: str) -> Principal | None:
    state = _state(request)
    with session_scope(state.engine) as session:
        user = authenticate_token(session, token, now=datetime.now(UTC))
        return None if user is None else Principal(user.id, user.name, user.role, None)


def _unauthorised(message: str) -> HTTPException:
    return HTTPException(401, message, headers={"WWW-Authenticate": "Bearer"})


def api_user(request: Request) -> Principal:
    """The API's caller: a bearer token, else a session cookie; 401 without either. A write
    (not GET or HEAD) made with a session cookie must carry the session's CSRF token in
    ``X-CSRF-Token`` (403 without it)."""
    header = request.headers.get("Authorization")
    if header is not None:
        scheme, _, token = header.partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise _unauthorised("the Authorization header must be 'Bearer <API token>'")
        principal = _from_token(request, token.strip())
        if principal is None:
            raise _unauthorised("the API token is unknown, revoked or expired")
        return principal
    principal = _from_session(request)
    if principal is None:
        raise _unauthorised("sign in, or send 'Authorization: Bearer <API token>'")
    if request.method not in ("GET", "HEAD"):
        sent = request.headers.get(CSRF_HEADER, "")
        if principal.csrf is None or not secrets.compare_digest(sent, principal.csrf):
            raise HTTPException(
                403, f"a write with a session cookie needs the {CSRF_HEADER} header"
            )
    return principal


def page_user(request: Request) -> Principal:
    """The signed-in person of a page; without one, ``SignInRequired`` (the sign-in page)."""
    principal = _from_session(request)
    if principal is None:
        raise SignInRequired
    request.state.principal = principal
    return principal


def requires(role: str, user: Callable[[Request], Principal] = api_user) -> Any:
    """A dependency: the caller (``user``: ``api_user`` or ``page_user``), 403 unless they have
    ``role`` or a higher one."""
    if role not in ROLE_RANK:
        raise ValueError(f"unknown role {role!r}")

    def dependency(principal: Principal = Depends(user)) -> Principal:  # noqa: B008
        if not principal.may(role):
            raise HTTPException(403, f"{principal.name} is a {principal.role}; this needs a {role}")
        return principal

    return Depends(dependency)


async def checked_form(request: Request) -> FormData:
    """The posted form of a page, refused (403) unless its ``csrf_token`` is the session's."""
    form = await request.form()
    data = _state(request).sessions.read(request)
    sent = form.get(CSRF_FIELD)
    if data is None or not isinstance(sent, str) or not secrets.compare_digest(sent, data.csrf):
        raise HTTPException(403, "the form has expired or did not come from this site: reload it")
    return form
