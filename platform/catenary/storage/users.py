"""Users, their API tokens and the audit trail (the web service's, and the CLI's changes).

Passwords are hashed with Argon2 (``argon2.PasswordHasher``'s defaults: argon2id, 64 MiB, 3
passes) and never kept or shown in clear; an API token is shown once, when it is created,
and kept as the SHA-256 of it (hex: a token is 32 random bytes, so no slow hash is needed).
Every change is one ``AuditEntry`` in the caller's transaction, naming the actor: a user's
name, or ``system_actor()`` for a change made on the command line.

The functions work in the caller's session and flush; the caller commits. Errors a user can
cause (an unknown user, a duplicate name, a short password, a bad role) are ``UserError``.
"""

from __future__ import annotations

import getpass
import hashlib
import os
import secrets
import socket
from datetime import datetime, timedelta
from functools import cache
from typing import Any

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import select
from sqlalchemy.orm import Session

from catenary.domain import NAME_LENGTH
from catenary.errors import UserError
from catenary.storage.models import USER_ROLES, ApiToken, AuditEntry, User, utc_now
from catenary.text import identifier_problem

__all__ = [
    "MIN_PASSWORD_LENGTH",
    "TOKEN_PREFIX",
    "add_user",
    "audit_entries",
    "authenticate_password",
    "authenticate_token",
    "create_token",
    "disable_user",
    "find_user",
    "list_tokens",
    "list_users",
    "record_audit",
    "revoke_token",
    "set_password",
    "system_actor",
    "token_hash",
    "token_status",
]

MIN_PASSWORD_LENGTH = 12
"""The shortest password accepted [characters]."""

TOKEN_PREFIX = "cat_"
"""What every API token starts with (so a leaked one is recognised by secret scanners)."""

_HASHER = PasswordHasher()


@cache
def _unknown_user_hash() -> str:
    """A hash verified against when the user is unknown, so the answer takes as long."""
    return _HASHER.hash(secrets.token_urlsafe(16))


def system_actor() -> str:
    """The actor of a command-line change: ``system:<os user>@<host>``."""
    try:
        who = getpass.getuser()
    except OSError:  # no login name and no passwd entry (a container's arbitrary uid)
        who = f"uid{os.getuid()}"
    return f"system:{who}@{socket.gethostname()}"[:NAME_LENGTH]


def record_audit(
    session: Session,
    actor: str,
    action: str,
    target: str,
    details: dict[str, Any] | None = None,
    *,
    at: datetime | None = None,
) -> AuditEntry:
    """Add an audit entry: ``actor`` did ``action`` (``alert.acknowledge``) to ``target``
    (``alert 12``) at ``at`` (default: now), with ``details`` (JSON)."""
    entry = AuditEntry(
        at=at or utc_now(),
        actor=actor[:NAME_LENGTH],
        action=action,
        target=target[:NAME_LENGTH],
        details=details or {},
    )
    session.add(entry)
    session.flush()
    return entry


def audit_entries(
    session: Session,
    *,
    since: datetime | None = None,
    actor: str | None = None,
    limit: int = 100,
) -> list[AuditEntry]:
    """The audit trail, newest first: at most ``limit`` entries, from ``since`` on (aware),
    of ``actor`` only when given."""
    query = select(AuditEntry).order_by(AuditEntry.at.desc(), AuditEntry.id.desc())
    if since is not None:
        query = query.where(AuditEntry.at >= since)
    if actor is not None:
        query = query.where(AuditEntry.actor == actor)
    return list(session.scalars(query.limit(limit)))


def token_hash(token: str) -> str:
    """The SHA-256 of ``token`` as kept in ``api_tokens.token_hash`` (64 hex digits)."""
    return hashlib.sha256(token.encode()).hexdigest()


def _checked_name(field: str, name: str) -> str:
    problem = identifier_problem(field, name, NAME_LENGTH)
    if problem is not None:
        raise UserError(problem)
    if not name.strip() or name != name.strip():
        raise UserError(f"{field} = {name!r}: give a name without leading or trailing spaces")
    return name


def _checked_role(role: str) -> str:
    if role not in USER_ROLES:
        raise UserError(f"role {role!r}: not one of {', '.join(USER_ROLES)}")
    return role


def _password_hash(password: str) -> str:
    if len(password) < MIN_PASSWORD_LENGTH:
        what = "empty" if not password else f"{len(password)} characters long"
        raise UserError(f"the password is {what} (at least {MIN_PASSWORD_LENGTH} characters)")
    return _HASHER.hash(password)


def find_user(session: Session, name: str) -> User:
    """The user called ``name``; a ``UserError`` if there is none."""
    user = session.scalars(select(User).where(User.name == name)).one_or_none()
    if user is None:
        raise UserError(f"no user {name!r}")
    return user


def add_user(
    session: Session, name: str, role: str, password: str, *, actor: str, now: datetime
) -> User:
    """Add user ``name`` with ``role`` (``USER_ROLES``) and ``password`` (at least
    ``MIN_PASSWORD_LENGTH`` characters), created by ``actor`` at ``now``."""
    _checked_name("user name", name)
    _checked_role(role)
    if session.scalars(select(User.id).where(User.name == name)).first() is not None:
        raise UserError(f"user {name!r} exists already")
    user = User(
        name=name,
        role=role,
        password_hash=_password_hash(password),
        disabled=False,
        created_at=now,
        updated_at=now,
    )
    session.add(user)
    session.flush()
    record_audit(session, actor, "user.add", f"user {name}", {"role": role}, at=now)
    return user


def set_password(session: Session, name: str, password: str, *, actor: str, now: datetime) -> User:
    """Replace the password of user ``name`` (the audit entry holds no trace of it)."""
    user = find_user(session, name)
    user.password_hash, user.updated_at = _password_hash(password), now
    session.flush()
    record_audit(session, actor, "user.set_password", f"user {name}", at=now)
    return user


def disable_user(session: Session, name: str, *, actor: str, now: datetime) -> User:
    """Disable user ``name``: their password and tokens are refused from now on."""
    user = find_user(session, name)
    if user.disabled:
        raise UserError(f"user {name!r} is already disabled")
    user.disabled, user.updated_at = True, now
    session.flush()
    record_audit(session, actor, "user.disable", f"user {name}", at=now)
    return user


def list_users(session: Session) -> list[User]:
    """Every user, by name."""
    return list(session.scalars(select(User).order_by(User.name)))


def create_token(
    session: Session,
    user_name: str,
    name: str,
    *,
    actor: str,
    now: datetime,
    expires_days: float | None = None,
) -> tuple[ApiToken, str]:
    """A new API token ``name`` of user ``user_name``, valid for ``expires_days`` days from
    ``now`` (None: until revoked), and the token itself: the only time it is known."""
    _checked_name("token name", name)
    if expires_days is not None and not expires_days > 0:
        raise UserError(f"--expires-days {expires_days:g}: give a positive number of days")
    user = find_user(session, user_name)
    if user.disabled:
        raise UserError(f"user {user_name!r} is disabled")
    taken = select(ApiToken.id).where(ApiToken.user_id == user.id, ApiToken.name == name)
    if session.scalars(taken).first() is not None:
        raise UserError(f"user {user_name!r} has a token {name!r} already")
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    expires_at = None if expires_days is None else now + timedelta(days=expires_days)
    row = ApiToken(
        user=user, name=name, token_hash=token_hash(token), created_at=now, expires_at=expires_at
    )
    session.add(row)
    session.flush()
    details = {"user": user_name, "name": name, "expires_at": _iso(expires_at)}
    record_audit(session, actor, "token.create", f"token {row.id}", details, at=now)
    return row, token


def _iso(moment: datetime | None) -> str | None:
    return None if moment is None else moment.isoformat()


def token_status(token: ApiToken, now: datetime) -> str:
    """``revoked``, ``expired`` or ``active`` at ``now``."""
    if token.revoked_at is not None:
        return "revoked"
    if token.expires_at is not None and token.expires_at <= now:
        return "expired"
    return "active"


def list_tokens(session: Session, user_name: str | None = None) -> list[ApiToken]:
    """The API tokens (of user ``user_name``, else of everyone), by user and creation."""
    query = select(ApiToken).join(User).order_by(User.name, ApiToken.created_at, ApiToken.id)
    if user_name is not None:
        query = query.where(ApiToken.user_id == find_user(session, user_name).id)
    return list(session.scalars(query))


def revoke_token(session: Session, token_id: int, *, actor: str, now: datetime) -> ApiToken:
    """Revoke API token ``token_id`` at ``now``."""
    token = session.get(ApiToken, token_id)
    if token is None:
        raise UserError(f"no API token {token_id}")
    if token.revoked_at is not None:
        raise UserError(f"API token {token_id} is already revoked (at {_iso(token.revoked_at)})")
    token.revoked_at = now
    session.flush()
    details = {"user": token.user.name, "name": token.name}
    record_audit(session, actor, "token.revoke", f"token {token_id}", details, at=now)
    return token


def authenticate_password(session: Session, name: str, password: str) -> User | None:
    """The user ``name`` if ``password`` is theirs and they are not disabled, else None (the
    same time is spent on an unknown name). A hash made with older parameters is renewed."""
    user = session.scalars(select(User).where(User.name == name)).one_or_none()
    try:
        _HASHER.verify(_unknown_user_hash() if user is None else user.password_hash, password)
    except (VerificationError, InvalidHashError):
        return None
    if user is None or user.disabled:
        return None
    if _HASHER.check_needs_rehash(user.password_hash):
        user.password_hash = _HASHER.hash(password)
        session.flush()
    return user


def authenticate_token(session: Session, token: str, *, now: datetime) -> User | None:
    """The user of API token ``token`` if it is neither revoked nor expired at ``now`` and its
    user is not disabled (its ``last_used_at`` set to ``now``), else None."""
    if not token.startswith(TOKEN_PREFIX):
        return None
    row = session.scalars(
        select(ApiToken).where(ApiToken.token_hash == token_hash(token))
    ).one_or_none()
    if row is None or token_status(row, now) != "active" or row.user.disabled:
        return None
    row.last_used_at = now
    session.flush()
    return row.user
