"""The Alembic environment of catenary.

Users never run Alembic themselves: ``catenary db upgrade`` (``catenary.storage.migrate``)
builds the configuration in code and passes its connection in ``config.attributes
["connection"]``. Developers may run ``alembic`` from the repository root (``alembic.ini``);
the database is then ``-x db=URL``, else ``sqlalchemy.url`` of the ini file, else catenary's
own setting (``--db``'s default: ``$CATENARY_DATABASE_URL``, the config file, the SQLite file in
the data directory).
"""

from __future__ import annotations

from alembic import context
from sqlalchemy.engine import Connection

from catenary.storage import migrate

config = context.config
if config.config_file_name is not None:  # the alembic command line: log as alembic.ini says
    from logging.config import fileConfig

    fileConfig(config.config_file_name, disable_existing_loggers=False)


def database_url() -> str:
    url = context.get_x_argument(as_dictionary=True).get("db") or config.get_main_option(
        "sqlalchemy.url"
    )
    if url:
        return url
    from catenary.config import load_settings

    return load_settings().database_url


def run_migrations(connection: Connection) -> None:
    context.configure(connection=connection, **migrate.context_options(connection.dialect.name))
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_offline() -> None:
    """Write the SQL to standard output (``alembic upgrade --sql``)."""
    url = database_url()
    dialect = url.split(":", 1)[0].split("+", 1)[0]
    context.configure(
        url=url,
        literal_binds=True,
        dialect_opts={"paramstyle": "named"},
        **migrate.context_options(dialect),
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        run_migrations(connection)
        return
    # the alembic command line: same engine set-up and SQLite safeguards as `catenary db`
    from catenary.storage.database import make_engine

    engine = make_engine(database_url())
    try:
        with (
            engine.connect() as connection,
            migrate.suspended_foreign_keys(connection),
            connection.begin(),
        ):
            run_migrations(connection)
            migrate.check_foreign_keys(connection)
    finally:
        engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
