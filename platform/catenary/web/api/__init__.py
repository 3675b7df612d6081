"""The REST API (``/api/v1``): each module a router of one resource; ``router`` holds them
all. JSON field names are the export columns of FORMATS.md."""

from fastapi import APIRouter

from catenary.web.api import alerts, maintenance, runs, samples, spans, track

__all__ = ["router"]

router = APIRouter()
for _module in (runs, spans, samples, track, alerts, maintenance):
    router.include_router(_module.router)
