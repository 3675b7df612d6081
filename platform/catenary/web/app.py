"""The web application: ``create_app(settings)`` and what its handlers share (``WebState``,
``state(request)``)."""

from __future__ import annotations

import importlib.metadata
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from dataclasses import dataclass
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.staticfiles import StaticFiles
from sqlalchemy import Engine

from catenary.config import Settings, load_settings
from catenary.plugins import PluginRegistry
from catenary.storage.database import make_engine, require_exists, require_migrated
from catenary.storage.store import Store, open_store
from catenary.web.auth import Sessions, SignInLimiter
from catenary.web.errors import install_error_handlers
from catenary.web.headers import SecurityHeaders
from catenary.web.settings import WebSettings, web_settings

__all__ = ["WebState", "app_from_environment", "create_app", "state"]

API_PREFIX = "/api/v1"


@dataclass
class WebState:
    """What every request shares: the settings, the database, the store, the plugins, the
    session cookies and the sign-in limiter."""

    settings: Settings
    web: WebSettings
    engine: Engine
    store: Store
    registry: PluginRegistry
    sessions: Sessions
    limiter: SignInLimiter


def state(request: Request) -> WebState:
    """The application's ``WebState``."""
    shared: WebState = request.app.state.web
    return shared


def create_app(settings: Settings, registry: PluginRegistry | None = None) -> FastAPI:
    """The web service over ``settings``' database (which must exist and be migrated: else a
    ``UserError``) and store."""
    from catenary.web import api, pages

    registry = registry or PluginRegistry(disabled=settings.disabled_plugins)
    registry.check_settings(settings)
    web = web_settings(settings)
    engine = make_engine(
        settings.database_url,
        connect_timeout_s=settings.connect_timeout_s,
        statement_timeout_s=settings.statement_timeout_s,
    )
    try:
        require_exists(engine)
        require_migrated(engine)
        shared = WebState(
            settings=settings,
            web=web,
            engine=engine,
            store=open_store(settings),
            registry=registry,
            sessions=Sessions(web.secret_key, web.session_s),
            limiter=SignInLimiter(web.sign_in_attempts, web.sign_in_window_s),
        )
    except BaseException:
        engine.dispose()
        raise

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        yield
        engine.dispose()

    app = FastAPI(
        title="catenary",
        version=importlib.metadata.version("catenary"),
        summary="Contact wire wear, geometry and condition-based maintenance of a fleet.",
        openapi_url=f"{API_PREFIX}/openapi.json",
        docs_url=None,  # Swagger UI and ReDoc load scripts from a CDN: the service is offline
        redoc_url=None,
        lifespan=lifespan,
    )
    app.state.web = shared
    app.add_middleware(SecurityHeaders)
    install_error_handlers(app)
    app.mount("/static", StaticFiles(directory=Path(__file__).parent / "static"), name="static")
    app.include_router(api.router, prefix=API_PREFIX)
    app.include_router(pages.router)
    return app


def app_from_environment() -> FastAPI:
    """``create_app`` over the settings of the environment (``CATENARY_CONFIG``,
    ``CATENARY_DATABASE_URL``...): what each worker process of ``catenary serve --workers N``
    runs."""
    return create_app(load_settings())
