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
@database_option
@click.pass_context
def serve(ctx: click.Context, host: str, port: int, forwarded_allow_ips: str) -> None:
    """Serve the planners' pages and the REST API (/api/v1) until stopped (Ctrl-C)."""
    import uvicorn

    from catenary.web.app import create_app

    context = app_of(ctx)
    application = create_app(context.settings, context.registry)
    click.echo(f"catenary serves http://{host}:{port}/ (API: /api/v1, Ctrl-C stops)")
    uvicorn.run(
        application,
        host=host,
        port=port,
        proxy_headers=True,
        forwarded_allow_ips=forwarded_allow_ips,
        server_header=False,
        log_level="info",
    )
