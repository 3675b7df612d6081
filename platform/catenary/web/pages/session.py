"""Public pages: sign-in, sign-out and the health check."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, RedirectResponse
from sqlalchemy import text
from sqlalchemy.exc import SQLAlchemyError
from starlette.datastructures import FormData
from starlette.responses import Response

from catenary.storage.database import session_scope
from catenary.storage.users import authenticate_password, record_audit
from catenary.web.app import state
from catenary.web.auth import SessionData, checked_form
from catenary.web.templating import render

__all__ = ["router"]

router = APIRouter()


def _local(target: str | None) -> str:
    """``target`` if it is a path of this site, else the overview (no open redirect)."""
    if target and target.startswith("/") and not target.startswith("//") and "\\" not in target:
        return target
    return "/"


def _sign_in_page(request: Request, target: str, message: str | None, status: int) -> Response:
    shared = state(request)
    data = shared.sessions.read(request)
    if data is None or data.user_id is not None:
        data = SessionData.anonymous()
    response = render(
        request,
        "sign_in.html",
        {"next": target, "message": message, "csrf_token": data.csrf},
        status,
    )
    shared.sessions.write(response, request, data)
    return response


@router.get("/sign-in")
def sign_in_form(request: Request, next: str | None = None) -> Response:
    return _sign_in_page(request, _local(next), None, 200)


@router.post("/sign-in")
def sign_in(request: Request, form: Annotated[FormData, Depends(checked_form)]) -> Response:
    shared = state(request)
    name = str(form.get("name", "")).strip()
    password = str(form.get("password", ""))
    target = _local(str(form.get("next", "/")))
    client = request.client.host if request.client else "unknown"
    now = datetime.now(UTC)
    with session_scope(shared.engine) as session:
        wait_s = shared.limiter.retry_after_s(session, name, client)
        if wait_s > 0:
            user = None
        else:
            user = authenticate_password(session, name, password) if name and password else None
            if user is None:
                shared.limiter.failed(session, name, client)
            else:
                shared.limiter.succeeded(session, name)
                details = {"from": client}
                record_audit(
                    session, user.name, "user.sign_in", f"user {user.name}", details, at=now
                )
                data = SessionData.signed_in(user)
    if wait_s > 0:
        minutes = max(1, round(wait_s / 60))
        message = f"too many failed sign-ins: try again in {minutes} minute(s)"
        response = _sign_in_page(request, target, message, 429)
        response.headers["Retry-After"] = str(int(wait_s) + 1)
        return response
    if user is None:
        return _sign_in_page(request, target, "unknown user name or wrong password", 401)
    response = RedirectResponse(target, status_code=303)
    shared.sessions.write(response, request, data)
    return response


@router.post("/sign-out")
def sign_out(request: Request, form: Annotated[FormData, Depends(checked_form)]) -> Response:
    response = RedirectResponse("/sign-in", status_code=303)
    state(request).sessions.clear(response, request)
    return response


@router.get("/health")
def health(request: Request) -> Response:
    """``{"status": "ok"}`` when the database answers, else 503."""
    try:
        with state(request).engine.connect() as connection:
            connection.execute(text("SELECT 1"))
    except SQLAlchemyError as exc:
        message = " ".join(str(exc).split())[:200]
        return JSONResponse({"status": "unavailable", "error": message}, status_code=503)
    return JSONResponse({"status": "ok"})
