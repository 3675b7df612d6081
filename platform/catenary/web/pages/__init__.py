"""The pages: each module a router of one part of the site; ``router`` holds them all."""

from fastapi import APIRouter

from catenary.web.pages import admin, alerts, overview, runs, session, spans, track

__all__ = ["router"]

router = APIRouter(include_in_schema=False)
for _module in (session, overview, track, spans, alerts, runs, admin):
    router.include_router(_module.router)
