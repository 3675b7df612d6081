"""The API's runs: ``GET /runs`` (filters: line, track)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query, Request
from pydantic import BaseModel

from catenary.storage.database import session_scope
from catenary.storage.models import Run
from catenary.storage.runs import list_runs
from catenary.web.app import state
from catenary.web.auth import Principal, requires

__all__ = ["RunOut", "router"]

router = APIRouter(tags=["runs"])


class RunOut(BaseModel):
    """A stored run and its latest processing (``catenary runs list --format json``)."""

    id: int
    uuid: str
    line: str
    track: str | None
    direction: str
    vehicle: str
    started_at: datetime
    scans: int | None
    status: str
    processing_uuid: str | None
    processed_at: datetime | None
    length_m: float | None

    @classmethod
    def of(cls, run: Run) -> RunOut:
        processing = run.processing
        return cls(
            id=run.id,
            uuid=run.uuid,
            line=run.line.code,
            track=run.track.code if run.track else None,
            direction=run.direction,
            vehicle=run.vehicle.name,
            started_at=run.started_at,
            scans=run.scans,
            status=run.status,
            processing_uuid=processing.uuid if processing else None,
            processed_at=processing.processed_at if processing else None,
            length_m=processing.length_m if processing else None,
        )


@router.get("/runs")
def runs(
    request: Request,
    user: Annotated[Principal, requires("viewer")],
    line: Annotated[str | None, Query(max_length=64, description="Only this line's runs.")] = None,
    track: Annotated[str | None, Query(max_length=64, description="Only this track's.")] = None,
) -> list[RunOut]:
    """The stored runs, oldest first."""
    with session_scope(state(request).engine, read_only=True) as session:
        return [RunOut.of(run) for run in list_runs(session, line=line, track=track)]
