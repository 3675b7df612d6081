"""The fleet overview (``/``)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Request
from starlette.responses import Response

from catenary.web.auth import Principal, page_user, requires
from catenary.web.templating import render

__all__ = ["router"]

router = APIRouter()


@router.get("/")
def overview(
    request: Request, user: Annotated[Principal, requires("viewer", page_user)]
) -> Response:
    return render(request, "overview.html")
