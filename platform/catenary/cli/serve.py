"""``catenary serve``: the web service (``catenary.web``) on uvicorn."""

from __future__ import annotations

import click

from catenary.cli.app import app_of
from catenary.plugins import database_option

__all__ = ["serve"]


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on.")
@click.option("--port", default=8000, show_default=True, type=click.IntRange(1, 65535))
@click.option(
    "--forwarded-allow-ips",
    default="127.0.0.1",
    show_default=True,
    metavar="ADDRESSES",
    help="Reverse proxies whose X-Forwarded-Proto/-For headers are trusted (comma-separated).",
)
@click.option(
    "--workers",
    default=1,
    show_default=True,
    type=click.IntRange(1, 64),
    help="Processes serving requests (about one per core).",
)
@database_option
@click.pass_context
def serve(ctx: click.Context, host: str, port: int, forwarded_allow_ips: str, workers: int) -> None:
    """Serve the planners' pages and the REST API (/api/v1) until stopped (Ctrl-C)."""
    import os

    import uvicorn

    from catenary.web.app import create_app

    context = app_of(ctx)
    # checks the settings and the database, and makes the cookie key, before any worker starts
    application = create_app(context.settings, context.registry)
    options = {
        "host": host,
        "port": port,
        "proxy_headers": True,
        "forwarded_allow_ips": forwarded_allow_ips,
        "server_header": False,
        "log_level": "info",
    }
    click.echo(
        f"catenary serves http://{host}:{port}/ (API: /api/v1; {workers} process(es); Ctrl-C stops)"
    )
    if workers == 1:
        uvicorn.run(application, **options)  # type: ignore[arg-type]
        return
    application.state.web.engine.dispose()
    settings = context.settings
    os.environ["CATENARY_DATABASE_URL"] = settings.database_url
    if settings.config_path is not None:
        os.environ["CATENARY_CONFIG"] = str(settings.config_path.resolve())
    os.environ["CATENARY_DATA_DIR"] = str(settings.data_dir)
    uvicorn.run(
        "catenary.web.app:app_from_environment",
        factory=True,
        workers=workers,
        **options,  # type: ignore[arg-type]
    )
