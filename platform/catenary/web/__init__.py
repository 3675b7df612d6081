"""The planners' web service: server-rendered pages and the REST API (``/api/v1``), over the
platform's database and store, with users, roles and an audit trail.

FastAPI on uvicorn (``catenary serve``): FastAPI writes the API's OpenAPI description from the
same typed functions that answer it, and its dependencies carry authentication and roles.
Handlers are plain (synchronous) functions run in uvicorn's thread pool, each with one short
SQLAlchemy session: the queries are the CLI's and the reports' own functions.

- ``app``: ``create_app(settings)``, the application and what it shares (``WebState``);
- ``auth``: signed session cookies, CSRF tokens, rate-limited sign-in, bearer tokens, roles;
- ``errors``: one clear error per failure (JSON for the API, a page for a person);
- ``api``: the REST API's routers; ``pages``: the pages' routers; ``templates``, ``static``:
  Jinja2 templates (auto-escaped) and the assets, all shipped in the package (no CDN).
"""
