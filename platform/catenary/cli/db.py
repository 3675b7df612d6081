"""``catenary db``: migrate the database and check its schema."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import click

from catenary.cli.app import app_of
from catenary.cli.listing import echo_json, format_option
from catenary.plugins import database_option

if TYPE_CHECKING:
    from sqlalchemy import Engine


@contextmanager
def _engine(ctx: click.Context, *, create: bool = False) -> Iterator[Engine]:
    """The engine of the invocation's database (``--db``), disposed of on exit; a SQLite file
    that does not exist is refused unless ``create``."""
    from catenary.storage.database import open_database

    with open_database(app_of(ctx).settings, migrated=False, create=create) as engine:
        yield engine


def _describe_revision(revision: str | None) -> str:
    from catenary.storage import migrate

    if revision is None:
        return "base (no schema)"
    head = migrate.head_revision()
    if revision == head:
        return f"{revision} (head)"
    if migrate.is_known_revision(revision):
        return f"{revision} (head is {head})"
    return f"{revision} (unknown to this version of catenary; head is {head})"


@click.group("db")
def db() -> None:
    """Create and migrate the database schema (SQLite file by default, or --db URL)."""


def _migrate(ctx: click.Context, move: Callable[[Engine, str], str | None], revision: str) -> None:
    """Run ``move`` (``migrate.upgrade`` or ``downgrade``) and say where the database is."""
    from catenary.storage import migrate
    from catenary.storage.database import mask_url

    with _engine(ctx, create=move is migrate.upgrade) as engine:
        before = migrate.current_revision(engine)
        after = move(engine, revision)
        where = mask_url(engine.url)
        if after == before:
            click.echo(f"database {where} is already at {_describe_revision(after)}")
        else:
            verb = "upgraded" if move is migrate.upgrade else "downgraded"
            click.echo(f"database {where} {verb} to {_describe_revision(after)}")


@db.command("upgrade")
@click.argument("revision", default="head")
@database_option
@click.pass_context
def upgrade_command(ctx: click.Context, revision: str) -> None:
    """Migrate the database up to REVISION (default: head, what this catenary needs)."""
    from catenary.storage import migrate

    _migrate(ctx, migrate.upgrade, revision)


@db.command("downgrade")
@click.argument("revision")
@database_option
@click.pass_context
def downgrade_command(ctx: click.Context, revision: str) -> None:
    """Migrate the database down to REVISION ('base' drops every table and its data)."""
    from catenary.storage import migrate

    _migrate(ctx, migrate.downgrade, revision)


@db.command("current")
@format_option()
@database_option
@click.pass_context
def current_command(ctx: click.Context, output_format: str) -> None:
    """Show the database's revision and whether it is the one this catenary needs.

    --format json: one object {"database", "revision", "head", "at_head", "known"}."""
    from catenary.storage import migrate
    from catenary.storage.database import mask_url

    with _engine(ctx) as engine:
        revision = migrate.current_revision(engine)
        where = mask_url(engine.url)
        if output_format == "json":
            echo_json(
                {
                    "database": where,
                    "revision": revision,
                    "head": migrate.head_revision(),
                    "at_head": revision == migrate.head_revision(),
                    "known": revision is None or migrate.is_known_revision(revision),
                }
            )
        elif revision is None:
            click.echo(f"database {where} is not migrated: run 'catenary db upgrade'")
        elif revision != migrate.head_revision() and migrate.is_known_revision(revision):
            click.echo(
                f"database {where} is at {_describe_revision(revision)}: run 'catenary db upgrade'"
            )
        else:
            click.echo(f"database {where} is at {_describe_revision(revision)}")


@db.command("check")
@database_option
@click.pass_context
def check_command(ctx: click.Context) -> None:
    """Check that the database's schema is what the models describe and that no stored
    identifier holds a control character (exit 1 if not)."""
    from catenary.storage import migrate
    from catenary.storage.database import mask_url, require_migrated

    with _engine(ctx) as engine:
        require_migrated(engine)
        differences = migrate.check_models_match(engine)
        where = mask_url(engine.url)
        if differences:
            click.echo(f"database {where} differs from the models:", err=True)
            for difference in differences:
                click.echo(f"    {difference}", err=True)
            ctx.exit(1)
        unprintable = migrate.identifiers_with_control_characters(engine)
    if unprintable:
        click.echo(
            f"database {where} holds identifiers with control characters "
            "(stored before they were refused; rename them):",
            err=True,
        )
        for problem in unprintable:
            click.echo(f"    {problem}", err=True)
        ctx.exit(1)
    click.echo(
        f"database {where} matches the models at {_describe_revision(migrate.head_revision())}"
    )
