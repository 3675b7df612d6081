"""One clear error per failure: ``{"error": "..."}`` with a 4xx status for the API, an error
page for a person; never a traceback. Unexpected failures are logged with their traceback and
answered 500 without it."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from urllib.parse import quote

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response

from catenary.errors import UserError
from catenary.web.auth import SignInRequired
from catenary.web.templating import render

__all__ = ["NotFound", "install_error_handlers", "validation_message"]

LOG = logging.getLogger("catenary.web")


class NotFound(UserError):
    """Something named in the request does not exist (answered 404)."""


def _is_api(request: Request) -> bool:
    return request.url.path.startswith("/api/")


def _answer(
    request: Request, status: int, message: str, headers: Mapping[str, str] | None = None
) -> Response:
    if _is_api(request):
        return JSONResponse({"error": message}, status_code=status, headers=headers)
    return render(request, "error.html", {"status": status, "message": message}, status, headers)


def validation_message(exc: RequestValidationError) -> str:
    """The first problem of a request's parameters, in one line: where, what, the value."""
    problems = []
    for error in exc.errors()[:3]:
        where = " ".join(str(part) for part in error.get("loc", ()))
        value = error.get("input")
        shown = "" if value is None or isinstance(value, dict) else f" (got {value!r})"
        problems.append(f"{where}: {error.get('msg', 'invalid')}{shown}")
    return "; ".join(problems) or "invalid request"


def install_error_handlers(app: FastAPI) -> None:
    """Answer every error of ``app`` as the module says."""

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Response:
        message = exc.detail if isinstance(exc.detail, str) else "request refused"
        if exc.status_code == 404 and message == "Not Found":
            message = f"no such address: {request.url.path}"
        if exc.status_code == 405 and message == "Method Not Allowed":
            message = f"{request.method} is not allowed on {request.url.path}"
        return _answer(request, exc.status_code, message, getattr(exc, "headers", None))

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError) -> Response:
        return _answer(request, 422 if _is_api(request) else 400, validation_message(exc))

    @app.exception_handler(NotFound)
    async def not_found(request: Request, exc: NotFound) -> Response:
        return _answer(request, 404, str(exc))

    @app.exception_handler(UserError)
    async def refused(request: Request, exc: UserError) -> Response:
        return _answer(request, 400, str(exc))

    @app.exception_handler(SignInRequired)
    async def sign_in(request: Request, exc: SignInRequired) -> Response:
        target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
        return RedirectResponse(f"/sign-in?next={quote(target, safe='/')}", status_code=303)

    @app.exception_handler(Exception)
    async def failed(request: Request, exc: Exception) -> Response:
        LOG.exception("%s %s failed", request.method, request.url.path)
        return _answer(request, 500, "internal error: the server's log has the details")
