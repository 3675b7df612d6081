"""The API's runs: ``GET /runs`` (filters: line, track) and ``GET /runs/{run}`` (a run with
its processings, alignment quality, vehicle and calibration)."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import datetime
from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request
from pydantic import BaseModel
from sqlalchemy.orm import Session

from catenary.errors import UserError
from catenary.storage.database import session_scope
from catenary.storage.models import Processing, Run, Track
from catenary.storage.runs import find_run, find_track, list_runs
from catenary.web.app import state
from catenary.web.auth import Principal, requires
from catenary.web.errors import NotFound

__all__ = ["ErrorOut", "RunDetailOut", "RunOut", "errors", "router", "run_of", "track_of"]

RunReference = Annotated[
    str,
    Path(
        max_length=64,
        description="A run id, its UUID, a prefix of it (4 characters or more) or 'latest'.",
    ),
]


def run_of(session: Session, reference: str) -> Run:
    """The run ``reference`` names (``find_run``); ``NotFound`` (404) when none does."""
    try:
        return find_run(session, reference)
    except UserError as exc:
        raise NotFound(str(exc)) from None


def track_of(session: Session, line: str, track: str) -> Track:
    """Track ``track`` of line ``line`` (``find_track``); ``NotFound`` (404) when unknown."""
    try:
        return find_track(session, line, track)
    except UserError as exc:
        raise NotFound(str(exc)) from None


class ErrorOut(BaseModel):
    """Every error's answer: one line saying what is wrong (never a traceback)."""

    error: str


def errors(described: Mapping[int, str] | None = None) -> dict[int | str, dict[str, Any]]:
    """The OpenAPI responses of the errors every endpoint may answer (401, 403, 422) and the
    ``described`` ones (status -> description), each an ``ErrorOut``."""
    common = {401: "No user: sign in or send a bearer token.", 403: "Not allowed.",
              422: "A bad parameter or body."}  # fmt: skip
    return {
        status: {"model": ErrorOut, "description": text}
        for status, text in (common | dict(described or {})).items()
    }


router = APIRouter(tags=["runs"], responses=errors())

MAX_RUNS = 1000
"""The most runs one ``GET /runs`` answers."""


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
    limit: Annotated[int, Query(ge=1, le=MAX_RUNS, description="At most this many.")] = MAX_RUNS,
    offset: Annotated[int, Query(ge=0, description="After the first this many.")] = 0,
) -> list[RunOut]:
    """The stored runs, oldest first (a page of ``limit`` from ``offset``)."""
    with session_scope(state(request).engine, read_only=True) as session:
        found = list_runs(session, line=line, track=track, limit=limit, offset=offset)
        return [RunOut.of(run) for run in found]


class ProcessingOut(BaseModel):
    """One processing of a run: its processor, when, and how its chainage was aligned."""

    uuid: str
    processor: str
    package_version: str
    processed_at: datetime
    wire_type: str | None
    length_m: float
    chainage_aligned: bool | None
    chainage_offset_m: float | None
    encoder_scale: float | None
    alignment_matched: int | None
    alignment_rms_m: float | None
    samples_key: str | None
    latest: bool

    @classmethod
    def of(cls, processing: Processing, latest: bool) -> ProcessingOut:
        return cls(
            uuid=processing.uuid,
            processor=processing.processor,
            package_version=processing.package_version,
            processed_at=processing.processed_at,
            wire_type=processing.wire_type,
            length_m=processing.length_m,
            chainage_aligned=processing.chainage_aligned,
            chainage_offset_m=processing.chainage_offset_m,
            encoder_scale=processing.encoder_scale,
            alignment_matched=processing.alignment_matched,
            alignment_rms_m=processing.alignment_rms_m,
            samples_key=processing.samples_key,
            latest=latest,
        )


class VehicleOut(BaseModel):
    """The vehicle's geometry (FORMATS.md, vehicle geometry)."""

    name: str
    roof_height_mm: float
    sensor_height_mm: float
    sensor_baseline_mm: float


class CalibrationOut(BaseModel):
    """The rig calibration the run was measured with."""

    name: str
    version: int
    created_at: datetime
    sha256: str


class RunDetailOut(RunOut):
    """A run, its processings (oldest first; ``latest`` marks the one that counts), vehicle
    and rig calibration."""

    source_file: str
    source_sha256: str
    rig_sha256: str
    error: str | None
    alerts_evaluated_at: datetime | None
    processings: list[ProcessingOut]
    vehicle_geometry: VehicleOut
    calibration: CalibrationOut


@router.get("/runs/{run}", responses=errors({404: "No such run."}))
def run_detail(
    request: Request, run: RunReference, user: Annotated[Principal, requires("viewer")]
) -> RunDetailOut:
    """A run with its processings, alignment quality, vehicle and rig calibration."""
    with session_scope(state(request).engine, read_only=True) as session:
        found = run_of(session, run)
        vehicle, calibration = found.vehicle, found.rig_calibration
        return RunDetailOut(
            **RunOut.of(found).model_dump(),
            source_file=found.source_file,
            source_sha256=found.source_sha256,
            rig_sha256=found.rig_sha256,
            error=found.error,
            alerts_evaluated_at=found.alerts_evaluated_at,
            processings=[
                ProcessingOut.of(p, p.id == found.processing_id) for p in found.processings
            ],
            vehicle_geometry=VehicleOut(
                name=vehicle.name,
                roof_height_mm=vehicle.roof_height_mm,
                sensor_height_mm=vehicle.sensor_height_mm,
                sensor_baseline_mm=vehicle.sensor_baseline_mm,
            ),
            calibration=CalibrationOut(
                name=calibration.name,
                version=calibration.version,
                created_at=calibration.created_at,
                sha256=calibration.sha256,
            ),
        )
