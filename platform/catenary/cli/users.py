"""``catenary users`` (add, list, disable, set-password) and ``catenary tokens`` (create,
list, revoke): the people and programs the web service lets in (``catenary.storage.users``);
``catenary audit list``: who changed what, and when.

Each command is one transaction, and each change is in the audit trail with the system user
(``system:<os user>@<host>``) as its actor. Passwords are read from the terminal (twice,
hidden) or, with ``--password-stdin``, from the first line of standard input; they are never
printed. A token is printed once, when it is created.
"""

from __future__ import annotations

import sys
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import click

from catenary.cli.app import app_of
from catenary.cli.listing import echo_json, format_option, utc_text
from catenary.plugins import database_option
from catenary.text import printable

if TYPE_CHECKING:
    from catenary.storage.models import ApiToken, User

__all__ = ["audit", "tokens", "users"]

_password_stdin = click.option(
    "--password-stdin",
    is_flag=True,
    help="Read the password from the first line of standard input (else: the terminal).",
)


def _now() -> datetime:
    return datetime.now(UTC)


def _password(from_stdin: bool) -> str:
    """The new password: the first line of standard input, or typed twice on the terminal."""
    if from_stdin:
        return sys.stdin.readline().rstrip("\r\n")
    return str(click.prompt("Password", hide_input=True, confirmation_prompt=True))


@click.group("users")
def users() -> None:
    """Users of the web service: add, list, disable, set a password."""


@users.command("add")
@click.argument("name")
@click.option(
    "--role", required=True, metavar="ROLE", help="viewer, planner or admin (README, Users)."
)
@_password_stdin
@database_option
@click.pass_context
def add_command(ctx: click.Context, name: str, role: str, password_stdin: bool) -> None:
    """Add user NAME with ROLE and a password (at least 12 characters)."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import add_user, system_actor

    password = _password(password_stdin)
    with app_of(ctx).database() as engine, session_scope(engine) as session:
        user = add_user(session, name, role, password, actor=system_actor(), now=_now())
        done = f"user {user.name} added ({user.role})"
    click.echo(printable(done))


def _user_record(user: User) -> dict[str, Any]:
    return {
        "id": user.id,
        "name": user.name,
        "role": user.role,
        "disabled": user.disabled,
        "created_at": utc_text(user.created_at),
        "updated_at": utc_text(user.updated_at),
    }


@users.command("list")
@format_option()
@database_option
@click.pass_context
def list_users_command(ctx: click.Context, output_format: str) -> None:
    """List the users by name (never their passwords)."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import list_users

    with app_of(ctx).database() as engine, session_scope(engine, read_only=True) as session:
        found = list_users(session)
        if output_format == "json":
            echo_json([_user_record(user) for user in found])
            return
        for user in found:
            state = "disabled" if user.disabled else "active"
            created = utc_text(user.created_at)
            click.echo(printable(f"{user.name:<24} {user.role:<8} {state:<9} created {created}"))
        click.echo(f"{len(found)} user(s)")


@users.command("disable")
@click.argument("name")
@database_option
@click.pass_context
def disable_command(ctx: click.Context, name: str) -> None:
    """Disable user NAME: their password and API tokens are refused from now on."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import disable_user, system_actor

    with app_of(ctx).database() as engine, session_scope(engine) as session:
        disable_user(session, name, actor=system_actor(), now=_now())
    click.echo(printable(f"user {name} disabled"))


@users.command("set-password")
@click.argument("name")
@_password_stdin
@database_option
@click.pass_context
def set_password_command(ctx: click.Context, name: str, password_stdin: bool) -> None:
    """Set a new password for user NAME (at least 12 characters)."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import find_user, set_password, system_actor

    with app_of(ctx).database() as engine:
        with session_scope(engine, read_only=True) as session:
            find_user(session, name)  # before asking for a password
        password = _password(password_stdin)
        with session_scope(engine) as session:
            set_password(session, name, password, actor=system_actor(), now=_now())
    click.echo(printable(f"password of user {name} set"))


@click.group("tokens")
def tokens() -> None:
    """API tokens (Authorization: Bearer): create, list, revoke."""


@tokens.command("create")
@click.argument("name")
@click.option("--user", "user_name", required=True, metavar="USER", help="Whose token it is.")
@click.option(
    "--expires-days",
    type=float,
    metavar="N",
    help="Valid for N days (default: until revoked).",
)
@database_option
@click.pass_context
def create_command(
    ctx: click.Context, name: str, user_name: str, expires_days: float | None
) -> None:
    """Create API token NAME of USER and print it: the only time it is shown."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import create_token, system_actor

    with app_of(ctx).database() as engine, session_scope(engine) as session:
        row, token = create_token(
            session,
            user_name,
            name,
            actor=system_actor(),
            now=_now(),
            expires_days=expires_days,
        )
        expires = utc_text(row.expires_at) or "never"
        note = (
            f"token {row.id} {row.name!r} of user {user_name} (expires {expires}): "
            "copy it now, it is not shown again"
        )
    click.echo(printable(note), err=True)
    click.echo(token)


def _token_record(token: ApiToken, now: datetime) -> dict[str, Any]:
    from catenary.storage.users import token_status

    return {
        "id": token.id,
        "user": token.user.name,
        "name": token.name,
        "status": token_status(token, now),
        "created_at": utc_text(token.created_at),
        "last_used_at": utc_text(token.last_used_at),
        "expires_at": utc_text(token.expires_at),
        "revoked_at": utc_text(token.revoked_at),
    }


@tokens.command("list")
@click.option("--user", "user_name", metavar="USER", help="Only this user's tokens.")
@format_option()
@database_option
@click.pass_context
def list_tokens_command(ctx: click.Context, user_name: str | None, output_format: str) -> None:
    """List the API tokens (never the tokens themselves): user, name, status, times."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import list_tokens

    now = _now()
    with app_of(ctx).database() as engine, session_scope(engine, read_only=True) as session:
        records = [_token_record(token, now) for token in list_tokens(session, user_name)]
    if output_format == "json":
        echo_json(records)
        return
    for r in records:
        click.echo(
            printable(
                f"{r['id']:>5} {r['user']:<20} {r['name']:<20} {r['status']:<8} "
                f"created {r['created_at']}, last used {r['last_used_at'] or 'never'}, "
                f"expires {r['expires_at'] or 'never'}"
            )
        )
    click.echo(f"{len(records)} token(s)")


@tokens.command("revoke")
@click.argument("token_id", metavar="ID", type=int)
@database_option
@click.pass_context
def revoke_command(ctx: click.Context, token_id: int) -> None:
    """Revoke API token ID (its id in 'catenary tokens list')."""
    from catenary.storage.database import session_scope
    from catenary.storage.users import revoke_token, system_actor

    with app_of(ctx).database() as engine, session_scope(engine) as session:
        token = revoke_token(session, token_id, actor=system_actor(), now=_now())
        done = f"token {token.id} {token.name!r} of user {token.user.name} revoked"
    click.echo(printable(done))


@click.group("audit")
def audit() -> None:
    """The audit trail: every change, who made it and when."""


@audit.command("list")
@click.option("--since", metavar="ISO8601", help="Only changes from then on (UTC if no zone).")
@click.option("--actor", metavar="NAME", help="Only this user's (or system user's) changes.")
@click.option(
    "--limit", type=click.IntRange(1, 100_000), default=100, show_default=True, help="At most."
)
@format_option()
@database_option
@click.pass_context
def audit_list_command(
    ctx: click.Context, since: str | None, actor: str | None, limit: int, output_format: str
) -> None:
    """List the audit trail, newest first."""
    from catenary.errors import UserError
    from catenary.storage.database import session_scope
    from catenary.storage.users import audit_entries

    start = None
    if since is not None:
        try:
            start = datetime.fromisoformat(since.replace("Z", "+00:00"))
        except ValueError:
            raise UserError(
                f"--since {since!r}: give an ISO 8601 time (2026-12-01T06:00)"
            ) from None
        start = start if start.tzinfo is not None else start.replace(tzinfo=UTC)
    with app_of(ctx).database() as engine, session_scope(engine, read_only=True) as session:
        records = [
            {
                "id": e.id,
                "at": utc_text(e.at),
                "actor": e.actor,
                "action": e.action,
                "target": e.target,
                "details": dict(e.details or {}),
            }
            for e in audit_entries(session, since=start, actor=actor, limit=limit)
        ]
    if output_format == "json":
        echo_json(records)
        return
    for r in records:
        click.echo(
            printable(
                f"{r['at']}  {r['actor']:<28} {r['action']:<20} {r['target']}  {r['details']}"
            )
        )
    click.echo(f"{len(records)} change(s)")
