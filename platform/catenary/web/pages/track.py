"""The track view (``/track?line&track[&from_m&to_m]``): a track along its chainage.

The page holds the frame (the track, its runs, the toolbar and a JSON block of what the
script needs); ``static/track.js`` draws residual thickness, height and stagger with uPlot
(``static/vendor/``) from ``GET /api/v1/tracks/profile``, fetched again for each window.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Request
from starlette.responses import Response

from catenary.storage.database import session_scope
from catenary.web.api.track import track_of, track_runs
from catenary.web.app import API_PREFIX, state
from catenary.web.auth import Principal, page_user, requires
from catenary.web.templating import render

__all__ = ["router"]

router = APIRouter()


@router.get("/track")
def track_page(
    request: Request,
    user: Annotated[Principal, requires("viewer", page_user)],
    line: Annotated[str, Query(max_length=64)],
    track: Annotated[str, Query(max_length=64)],
    from_m: Annotated[float | None, Query(allow_inf_nan=False)] = None,
    to_m: Annotated[float | None, Query(allow_inf_nan=False)] = None,
) -> Response:
    with session_scope(state(request).engine, read_only=True) as session:
        found = track_of(session, line, track)
        latest, previous = track_runs(session, found)
        backwards = from_m is not None and to_m is not None and from_m >= to_m
        view = {  # what track.js needs; a window that is no window is the whole track
            "line": line,
            "track": track,
            "from_m": None if backwards else from_m,
            "to_m": None if backwards else to_m,
            "profile_url": f"{API_PREFIX}/tracks/profile",
            "span_url": "/span",
        }
        return render(
            request,
            "track.html",
            {"line": line, "track": track, "latest": latest, "previous": previous, "view": view},
        )
